"""Distant environment light (paper 002, section 4): ``btfrs.Environment``.

An environment is a latitude-longitude HDR image of the radiance arriving from every direction:
row 0 is the zenith (+z, the scenes' up), the last row the nadir; columns run in azimuth from +x
towards +y; the image is twice as wide as high. :func:`btfrs.render` lights a model with it in two
ways (``environment=``):

* ``lighting="sampled"`` (every model): ``samples`` directional lights drawn with probability
  proportional to luminance x solid angle (stratified, seeded), one pass through the model's
  ordinary light loop. The paper used a spherical Q^2-tree; here the distribution is piecewise
  constant over the pixels (see ``rust/btfrs-render/src/environment.rs``).
* ``lighting="sh"`` (double-SH models, :func:`btfrs.fit.sh`): the environment's SH vector rotated
  into each pixel's tangent frame, converted by the hemispherical autocorrelation matrix, one
  inner product with the texel's light coefficients (``rust/btfrs-render/src/sh_env.rs``).

Images read ``pi x radiance`` (see :func:`btfrs.render`): under a constant environment of
radiance 1 a white Lambertian surface reads pi.
"""

from __future__ import annotations

import os
from typing import List, Sequence, Tuple

import numpy as np

from . import _native
from ._checks import PathLike, integer, real
from .exceptions import ArgumentTypeError, InvalidArgumentError
from .io import load_image
from .rendering import DirectionalLight

__all__ = ["Environment"]


class Environment:
    """A lat-long environment of linear RGB radiance, ``data`` ``[H, 2H, 3]`` float32 (see the
    module docs for the conventions). Make one with :meth:`load`, :meth:`sky` or
    :meth:`from_array`."""

    __slots__ = ("data",)

    def __init__(self, data: np.ndarray):
        a = np.asarray(data)
        if not np.issubdtype(a.dtype, np.floating):
            raise ArgumentTypeError(f"environment: expected a float array [H, 2H, 3], got dtype {a.dtype}")
        a = np.ascontiguousarray(a, dtype=np.float32)
        if a.ndim != 3 or a.shape[2] != 3:
            raise InvalidArgumentError(f"environment: expected an array [H, 2H, 3], got shape {a.shape}")
        _native.env_check(a)
        a.setflags(write=False)
        self.data = a

    @classmethod
    def from_array(cls, data: np.ndarray) -> "Environment":
        """Wrap ``[H, 2H, 3]`` radiance (checked: finite, non-negative, 2:1, not all black)."""
        return cls(data)

    @classmethod
    def load(cls, path: PathLike) -> "Environment":
        """Read a lat-long image: OpenEXR (linear HDR) or PNG (sRGB-decoded to linear)."""
        p = os.fspath(path)
        try:
            img = load_image(p)
        except InvalidArgumentError as e:
            raise InvalidArgumentError(f"path: {e}") from None
        try:
            return cls(img)
        except InvalidArgumentError as e:
            raise InvalidArgumentError(f"{p}: {e}") from None

    @classmethod
    def sky(cls, sun: Sequence[float] = (0.3, 0.2, 0.9), turbidity: float = 3.0, *, height: int = 128,
            ground: float = 0.2) -> "Environment":
        """Preetham, Shirley and Smits' analytic daylight (SIGGRAPH 1999) for a sun direction
        ``sun`` (above the horizon; any length) and ``turbidity`` in [1.7, 10], as a
        ``[height, 2 height, 3]`` image normalised to zenith luminance 1. The sun disc is not
        included (add a :class:`~btfrs.DirectionalLight`). Below the horizon: a grey ground of
        albedo ``ground`` lit by the sky."""
        s = np.asarray(sun, dtype=np.float64).reshape(-1)
        if s.shape != (3,):
            raise InvalidArgumentError(f"sun: expected a direction of three numbers, got {sun!r}")
        t = real("turbidity", turbidity)
        h = integer("height", height, min=2, max=8192)
        gr = real("ground", ground, min=0.0, max=1.0)
        return cls(_native.env_sky([float(x) for x in s], t, h, gr))

    @property
    def shape(self) -> Tuple[int, int]:
        """(height, width) in pixels."""
        return self.data.shape[0], self.data.shape[1]

    def lights(self, samples: int = 64, *, seed: int = 0) -> List[DirectionalLight]:
        """``samples`` importance-sampled :class:`~btfrs.DirectionalLight` s whose sum estimates
        the lighting integral (what ``lighting="sampled"`` renders with)."""
        n = integer("samples", samples, min=1, max=65536)
        sd = integer("seed", seed, min=0)
        d, i = _native.env_sample(self.data, n, sd)
        return [DirectionalLight(tuple(map(float, a)), tuple(map(float, b))) for a, b in zip(d, i)]

    def quadrature(self) -> List[DirectionalLight]:
        """Every lit pixel as one :class:`~btfrs.DirectionalLight` at its centre carrying
        radiance x solid angle: the brute-force integral the sampled renders converge to."""
        d, i = _native.env_quadrature(self.data)
        return [DirectionalLight(tuple(map(float, a)), tuple(map(float, b))) for a, b in zip(d, i)]

    def sh(self, coefficients: int = 25) -> np.ndarray:
        """The projection on the first ``coefficients`` real orthonormal SH (the basis of
        :func:`btfrs.fit.sh`): ``[coefficients, 3]`` float64."""
        n = integer("coefficients", coefficients, min=1, max=64)
        return _native.env_sh(self.data, n)

    def __repr__(self) -> str:
        h, w = self.shape
        return f"Environment({h} x {w}, max {float(self.data.max()):.3g})"
