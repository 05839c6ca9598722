"""Files: PTM files for RTIViewer/relight, images, and the ``.btfrs`` container."""

from __future__ import annotations

import os
from typing import Union

import numpy as np

from . import _native
from .models import Ptm, load

__all__ = ["load_ptm", "save_image", "load_image", "load"]

PathLike = Union[str, os.PathLike]


def load_ptm(path: PathLike) -> Ptm:
    """Read an uncompressed ``PTM_1.2`` (or 1.1) RGB or LRGB file, ours or another tool's, as a
    one-slot :class:`~btfrs.Ptm` (view = the normal). Values are in units where the viewer's
    white (byte 255) is 1.0. Compressed (JPEG) and LUM variants raise
    :class:`~btfrs.exceptions.FormatError`."""
    return Ptm(_native.read_ptm(os.fspath(path)))


def save_image(path: PathLike, image, exposure: float = 1.0) -> None:
    """Write an ``[H, W, 3]`` linear image as an 8-bit sRGB PNG (``.png``), times ``exposure``,
    clipped to [0, 1]. Written atomically."""
    p = os.fspath(path)
    ext = os.path.splitext(p)[1].lower()
    if ext != ".png":
        raise ValueError(f"path: expected a .png file name, got {ext or 'no extension'!r}")
    img = np.ascontiguousarray(image, dtype=np.float32)
    _native.write_png(p, img, float(exposure))


def load_image(path: PathLike) -> np.ndarray:
    """Read an 8-bit RGB(A) PNG as an ``[H, W, 3]`` float32 linear image."""
    return _native.read_png(os.fspath(path))
