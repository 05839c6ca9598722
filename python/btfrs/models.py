"""Fitted reflectance models and what they share.

Every model has the same contract: ``evaluate(view, light)`` gives an ``[H, W, 3]`` image at any
directions, ``error(btf)`` compares against the present pairs of a sample (use the test half of
:meth:`btfrs.Btf.split` for the held-out figure, the train half for reconstruction), ``nbytes``
is the storage as stored for rendering, and ``save``/``load`` round-trip through one file.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from typing import Optional, Union

import numpy as np

from . import _native
from .btf import Btf, read_container
from .exceptions import FormatError, InvalidArgumentError

__all__ = ["ErrorReport", "Ptm", "load"]

PathLike = Union[str, os.PathLike]


@dataclass(frozen=True)
class ErrorReport:
    """Accuracy of a model against a BTF (f64 accumulation over every present value).

    ``relative`` is ``||pred - gt|| / ||gt||``; ``psnr`` is in dB against the largest
    ground-truth value (``-inf`` when no ground-truth value is positive); ``samples`` counts
    compared values (texels x pairs x 3).
    """

    rmse: float
    relative: float
    psnr: float
    samples: int

    def __str__(self) -> str:
        return f"rmse {self.rmse:.5f}, relative {100 * self.relative:.2f}%, psnr {self.psnr:.1f} dB"


def _as_dir(name: str, d) -> list:
    """A query direction as a unit 3-vector: any non-zero vector with z >= 0 is normalised."""
    a = np.asarray(d, dtype=np.float64).reshape(-1)
    if a.shape != (3,):
        raise InvalidArgumentError(f"{name}: expected a direction of three numbers, got shape {np.shape(d)}")
    n = float(np.linalg.norm(a))
    if not np.isfinite(n) or n == 0.0:
        raise InvalidArgumentError(f"{name}: expected a finite, non-zero direction, got {a.tolist()}")
    return [float(x) for x in a / n]


class Ptm:
    """A Polynomial Texture Map per view slot (paper 000, section 3.1).

    ``kind="rgb"``: ``coeffs[H, W, V, 3, 6]``, one biquadratic in the light's (x, y) per channel.
    ``kind="lrgb"``: ``coeffs[H, W, V, 6]`` luminance polynomial times ``rgb[H, W, V, 3]``.
    Between view slots, :meth:`evaluate` blends the three nearest slots (inverse angular
    distance); at a slot's own direction it is exactly that slot's fit.
    """

    def __init__(self, native: "_native.PtmModel", fit_seconds: Optional[float] = None) -> None:
        self._m = native
        self.fit_seconds = fit_seconds

    @classmethod
    def from_arrays(cls, kind: str, coeffs, views, rgb=None) -> "Ptm":
        """Build a PTM from coefficient arrays (see the class docstring for the shapes)."""
        c = np.ascontiguousarray(coeffs, dtype=np.float32)
        v = np.ascontiguousarray(views, dtype=np.float64)
        r = None if rgb is None else np.ascontiguousarray(rgb, dtype=np.float32)
        return cls(_native.PtmModel.from_arrays(kind, c, v, r))

    @property
    def kind(self) -> str:
        """``"rgb"`` or ``"lrgb"``."""
        return self._m.kind

    @property
    def height(self) -> int:
        return self._m.dims[0]

    @property
    def width(self) -> int:
        return self._m.dims[1]

    @property
    def nbytes(self) -> int:
        """Bytes as stored for rendering (float32 coefficients and base colours)."""
        return self._m.nbytes

    @property
    def coeffs(self) -> np.ndarray:
        """A copy of the coefficients."""
        return self._m.coeffs()

    @property
    def rgb(self) -> Optional[np.ndarray]:
        """A copy of the LRGB base colours (largest channel 1), or None for RGB."""
        return self._m.rgb()

    @property
    def views(self) -> np.ndarray:
        """``[V, 3]`` directions of the view slots."""
        return self._m.views()

    def evaluate(self, view, light) -> np.ndarray:
        """The ``[H, W, 3]`` float32 image for one view and one light direction (any non-zero
        vectors; they are normalised)."""
        return self._m.evaluate(_as_dir("view", view), _as_dir("light", light))

    def error(self, btf: Btf) -> ErrorReport:
        """RMSE, relative error and PSNR against every present pair of ``btf``."""
        if not isinstance(btf, Btf):
            raise TypeError(f"btf: expected a btfrs.Btf, got {type(btf).__name__}")
        d = self._m.error(btf.data, btf.views, btf.lights, btf.mask)
        return ErrorReport(d["rmse"], d["relative"], d["psnr"], int(d["samples"]))

    def slot(self, view) -> int:
        """The index of the view slot for ``view``: an int index, or a direction within 0.5
        degrees of a slot's."""
        n = len(self.views)
        if isinstance(view, bool):
            raise TypeError("view: expected a slot index or a direction, got a bool")
        if isinstance(view, (int, np.integer)):
            if not 0 <= int(view) < n:
                raise InvalidArgumentError(f"view: expected a slot index in [0, {n}), got {view}")
            return int(view)
        d = np.asarray(_as_dir("view", view))
        ang = np.degrees(np.arccos(np.clip(self.views @ d / np.linalg.norm(d), -1, 1)))
        i = int(np.argmin(ang))
        if ang[i] > 0.5:
            raise InvalidArgumentError(f"view: {list(d)} is {ang[i]:.1f} degrees from the nearest view slot; pass a slot index")
        return i

    def save_ptm(self, path: PathLike, view=0) -> tuple[list, list]:
        """Write one view slot as an uncompressed ``PTM_1.2`` file (``PTM_FORMAT_RGB`` or
        ``PTM_FORMAT_LRGB``) that RTIViewer and relight open; returns the per-coefficient
        ``(scale, bias)`` of the 8-bit quantisation. Our value 1.0 is the viewer's white (255);
        multiply the data beforehand to choose another exposure."""
        return _native.write_ptm(os.fspath(path), self._m, self.slot(view))

    def save(self, path: PathLike) -> None:
        """Write the model to one ``.btfrs`` file (atomically)."""
        arrays = [("coeffs", self.coeffs), ("views", self.views)]
        if self.kind == "lrgb":
            arrays.append(("rgb", self.rgb))
        meta = {"kind": self.kind, "fit_seconds": self.fit_seconds}
        _native.save_container(os.fspath(path), "ptm", json.dumps(meta), arrays)

    @classmethod
    def load(cls, path: PathLike) -> "Ptm":
        """Read a model written by :meth:`save`."""
        m = load(path)
        if not isinstance(m, Ptm):
            raise FormatError(f"{os.fspath(path)}: holds a {type(m).__name__}, not a Ptm")
        return m

    def __repr__(self) -> str:
        return f"Ptm({self.kind}, {self.height} x {self.width} texels, {len(self.views)} view slots, {self.nbytes / 2**20:.2f} MiB)"


def load(path: PathLike):
    """Load any ``.btfrs`` file: a :class:`~btfrs.Btf` or a fitted model."""
    kind, meta, arrays = read_container(path)
    if kind == "btf":
        return Btf.from_arrays(path, arrays)
    if kind == "ptm":
        try:
            p = Ptm.from_arrays(meta["kind"], arrays["coeffs"], arrays["views"], arrays.get("rgb"))
        except KeyError as e:
            raise FormatError(f"{os.fspath(path)}: the PTM file has no entry {e}") from None
        p.fit_seconds = meta.get("fit_seconds")
        return p
    raise FormatError(f"{os.fspath(path)}: unknown content {kind!r}")
