"""Fitting reflectance models to a BTF: ``btfrs.fit.<model>(btf, ...)``.

Each function fits only the pairs present in ``btf`` (its mask), so fitting the train half of a
split never sees the held-out pairs, and returns a model with ``evaluate``, ``error``, ``nbytes``
and ``save`` (see :mod:`btfrs.models`).
"""

from __future__ import annotations

import time

from . import _native
from ._progress import Progress, callback
from .btf import Btf
from .exceptions import InvalidArgumentError
from .models import Lafortune, Lpca, Ptm, Sh, Srf

__all__ = ["ptm", "srf", "lafortune", "sh", "lpca"]


def _check_btf(btf) -> Btf:
    if not isinstance(btf, Btf):
        raise TypeError(f"btf: expected a btfrs.Btf, got {type(btf).__name__}")
    return btf


def ptm(btf: Btf, kind: str = "rgb", rcond: float = 1e-6, on_degenerate: str = "raise",
        progress: Progress = None) -> Ptm:
    """Fit a Polynomial Texture Map per view slot (paper 000, section 3.1).

    One SVD pseudo-inverse of the 6-column light design matrix per view slot, applied to every
    texel (float64 accumulation), so the fit costs one pass over the data.

    Parameters
    ----------
    kind: ``"rgb"`` (6 coefficients per channel) or ``"lrgb"`` (6 for the luminance + a base colour).
    rcond: singular values below ``rcond * s_max`` count as zero.
    on_degenerate: a view slot with fewer than 6 lights or degenerate (e.g. collinear) lights
        raises :class:`~btfrs.exceptions.DegenerateDataError` (``"raise"``) or gets the
        minimum-norm solution (``"clamp"``).
    progress: None, True for a progress bar, or a callable ``(done, total)``.
    """
    b = _check_btf(btf)
    if kind not in ("rgb", "lrgb"):
        raise InvalidArgumentError(f"kind: expected \"rgb\" or \"lrgb\", got {kind!r}")
    t0 = time.perf_counter()
    m = _native.fit_ptm_native(b.data, b.views, b.lights, b.mask, kind=kind, rcond=float(rcond),
                               on_degenerate=on_degenerate, progress=callback(progress, f"PTM-{kind.upper()} fit"))
    return Ptm(m, fit_seconds=time.perf_counter() - t0)


def srf(btf: Btf, progress: Progress = None) -> Srf:
    """Fit Phong + a spatially-varying residual function (paper 003, sections 4 and 5).

    One Blinn-Phong (kd, ks per channel, one shininess n) is fitted by Levenberg-Marquardt to
    the material's mean BRDF; the residual ``BTF - Phong`` is fitted per texel and channel as
    ``s(P) . H`` by linear least squares over the halfway vectors (one shared pseudo-inverse).
    ``model.report`` gives the relative error of Phong alone and of Phong + SRF on the fitted
    pairs.
    """
    b = _check_btf(btf)
    t0 = time.perf_counter()
    m, report = _native.fit_srf_native(b.data, b.views, b.lights, b.mask, progress=callback(progress, "SRF fit"))
    return Srf(m, fit_seconds=time.perf_counter() - t0, report=report)
