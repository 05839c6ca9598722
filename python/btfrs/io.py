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
    """Write an ``[H, W, 3]`` linear image, chosen by the extension: ``.png`` (8-bit sRGB, times
    ``exposure``, clipped to [0, 1]) or ``.exr`` (32-bit float OpenEXR, HDR values kept exactly,
    times ``exposure``). Written atomically."""
    p = os.fspath(path)
    ext = os.path.splitext(p)[1].lower()
    img = np.ascontiguousarray(image, dtype=np.float32)
    if ext == ".png":
        _native.write_png(p, img, float(exposure))
    elif ext == ".exr":
        _native.write_exr(p, img if exposure == 1.0 else np.ascontiguousarray(img * np.float32(exposure)))
    else:
        raise ValueError(f"path: expected a .png or .exr file name, got {ext or 'no extension'!r}")


def load_image(path: PathLike) -> np.ndarray:
    """Read an ``[H, W, 3]`` float32 linear image from an 8-bit PNG or an OpenEXR file."""
    p = os.fspath(path)
    if os.path.splitext(p)[1].lower() == ".exr":
        return _native.read_exr(p)
    return _native.read_png(p)
