"""Directions in the sample's tangent frame and the UBO 2003 sampling.

z is the surface normal, x the sample's u axis (image columns, to the right), y its v axis (image
rows, upwards). Directions are unit vectors pointing away from the surface (z >= 0); theta is the
elevation from z, phi the azimuth from x towards y.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from . import _native
from ._checks import boolean
from .exceptions import InvalidArgumentError

__all__ = ["ubo81", "from_theta_phi", "to_theta_phi"]


def ubo81() -> np.ndarray:
    """The 81 directions of the Bonn UBO 2003 sampling, ``[81, 3]`` float64.

    theta in {0, 15, 30, 45, 60, 75} degrees with {1, 6, 12, 18, 20, 24} evenly spaced azimuths
    starting at phi = 0, ordered ring by ring.
    """
    return _native.ubo81()


def from_theta_phi(theta: ArrayLike, phi: ArrayLike, *, degrees: bool = False) -> np.ndarray:
    """Unit vectors ``[..., 3]`` for elevations ``theta`` and azimuths ``phi`` (radians unless
    ``degrees``); the inputs broadcast against each other."""
    t = np.asarray(theta, dtype=np.float64)
    p = np.asarray(phi, dtype=np.float64)
    if boolean("degrees", degrees):
        t, p = np.radians(t), np.radians(p)
    t, p = np.broadcast_arrays(t, p)
    st = np.sin(t)
    return np.stack([st * np.cos(p), st * np.sin(p), np.cos(t)], axis=-1)


def to_theta_phi(d: ArrayLike, *, degrees: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(theta, phi) of directions ``[..., 3]``; phi in [0, 2 pi), 0 at the pole."""
    d = np.asarray(d, dtype=np.float64)
    if d.shape[-1:] != (3,):
        raise InvalidArgumentError(f"d: expected shape (..., 3), got {d.shape}")
    r = np.hypot(d[..., 0], d[..., 1])
    theta = np.arctan2(r, d[..., 2])
    phi = np.where(r == 0, 0.0, np.mod(np.arctan2(d[..., 1], d[..., 0]), 2 * np.pi))
    if boolean("degrees", degrees):
        return np.degrees(theta), np.degrees(phi)
    return theta, phi
