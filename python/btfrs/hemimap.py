"""The concentric map and the elevated concentric map (paper 004, section 6.1).

Shirley and Chiu's concentric map takes the unit square ``[0, 1]^2`` to the unit disk, mapping
concentric squares to concentric circles; the elevation ``z = 1 - rho^2`` lifts the disk onto the
hemisphere preserving area. Together (``square_to_hemisphere``) they give a parameterisation of
directions in which a uniform grid of the square is a uniform sampling of the hemisphere, which
the LPCA renderer uses to store Eigen-BRDFs as a 3D texture.

All functions take float32 or float64 arrays of any batch shape ``[..., 2]`` or ``[..., 3]`` and
return the same dtype; the work runs in Rust with the GIL released.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import _native
from .exceptions import ArgumentTypeError

__all__ = ["square_to_disk", "disk_to_square", "square_to_hemisphere", "hemisphere_to_square"]


def _arr(name: str, x: ArrayLike) -> NDArray[Any]:
    a = np.asarray(x)
    if a.dtype.kind not in "fiu":
        raise ArgumentTypeError(f"{name}: expected real numbers, got dtype {a.dtype}")
    if a.dtype not in (np.float32, np.float64):
        a = a.astype(np.float64)
    # np.require keeps a 0-d input 0-d, so the shape error names what was passed.
    return np.require(a, requirements="C")


def square_to_disk(st: ArrayLike) -> np.ndarray:
    """``[..., 2]`` points of the unit square to ``[..., 2]`` points of the unit disk."""
    return _native.square_to_disk(_arr("st", st))


def disk_to_square(xy: ArrayLike) -> np.ndarray:
    """Inverse of :func:`square_to_disk`."""
    return _native.disk_to_square(_arr("xy", xy))


def square_to_hemisphere(st: ArrayLike) -> np.ndarray:
    """The elevated concentric map: ``[..., 2]`` square points to ``[..., 3]`` unit directions."""
    return _native.square_to_hemisphere(_arr("st", st))


def hemisphere_to_square(d: ArrayLike) -> np.ndarray:
    """Inverse of :func:`square_to_hemisphere`: ``[..., 3]`` directions (z >= 0) to the square."""
    return _native.hemisphere_to_square(_arr("directions", d))
