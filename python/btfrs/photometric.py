"""Normals, albedo and height from a capture: photometric stereo and normal integration.

:func:`normals` runs photometric stereo (Woodham 1980) on one view slot of a BTF or capture:
per texel the unit normal and the Lambertian albedo that explain its values under the measured
lights, by least squares over every light (``method="l2"``) or by iteratively reweighted least
squares that stops shadows and highlights from pulling the normal (``method="robust"``; the
Rust module ``btfrs_fit::photometric`` documents both). :func:`height` integrates the normals
into a surface height by Frankot and Chellappa's projection onto integrable surfaces (1988):
``method="fft"`` for samples that tile (a periodic surface, as every BTF sample made to repeat),
``method="mirror"`` for captures that do not (the gradients mirrored at the borders first, the
Neumann boundary of a Poisson solve by the discrete cosine transform: no wrap-around slope
where the left and right edges differ).

**Convention** (tangent space, the one glTF, Blender and OpenGL use): x right, y up the image,
z out of the surface; row 0 of every map is the top of the image. Heights are in texel widths.
:func:`save_normals` writes normals as float32 OpenEXR (the vectors) or 16-bit PNG
(``0.5 n + 0.5``, what normal-map readers take); 8-bit normals step by 0.4 degrees and
stair-step when integrated, so none are written.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any, Dict, Optional, Union

import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import _native
from ._checks import PathLike, choice, instance, integer
from ._progress import Progress, callback
from .btf import Btf
from .exceptions import InvalidArgumentError

#: The methods of :func:`normals`.
METHODS = ("l2", "robust")
#: The methods of :func:`height`.
HEIGHT_METHODS = ("fft", "mirror")


@dataclass(frozen=True)
class NormalMaps:
    """What :func:`normals` found for one view slot."""

    #: ``[H, W, 3]`` float32 unit normals (x right, y up the image, z out of the surface).
    normals: NDArray[np.float32]
    #: ``[H, W, 3]`` float32 Lambertian albedo per channel (``I = albedo (n . l)``).
    albedo: NDArray[np.float32]
    #: ``[H, W]`` float32: the lights the fit used (their weights summed, for ``"robust"``).
    lights_used: NDArray[np.float32]
    #: The view slot and the method.
    view: int
    method: str
    #: Texels black under every light (their normal is (0, 0, 1), their albedo 0).
    dark_texels: int

    def angular_error(self, truth: ArrayLike) -> NDArray[np.float64]:
        """Per texel the angle in degrees between these normals and ``truth`` (``[H, W, 3]``)."""
        return angular_error(self.normals, truth)

    def save(self, folder: PathLike) -> Dict[str, str]:
        """Write ``normals.exr``, ``normals.png`` (16-bit), ``albedo.exr`` and ``albedo.png`` (8-bit
        sRGB) into ``folder``; returns the paths by name."""
        out = os.fspath(folder)
        os.makedirs(out, exist_ok=True)
        paths = {n: os.path.join(out, n) for n in ("normals.exr", "normals.png", "albedo.exr", "albedo.png")}
        save_normals(paths["normals.exr"], self.normals)
        save_normals(paths["normals.png"], self.normals)
        _native.write_exr(paths["albedo.exr"], np.ascontiguousarray(self.albedo))
        _native.write_png(paths["albedo.png"], np.ascontiguousarray(np.clip(self.albedo, 0.0, 1.0)), 1.0)
        return paths


def normals(btf: Btf, view: int = 0, *, method: str = "robust", progress: Any = None) -> NormalMaps:
    """Photometric stereo on view slot ``view`` of ``btf`` (see the module docs). Needs at least
    3 measured lights in the slot, not all in one plane through the surface point."""
    instance("btf", btf, Btf, "a btfrs.Btf (a loaded capture or BTF)")
    method = choice("method", method, METHODS)
    view = integer("view", view, min=0)
    if view >= btf.n_views:
        raise InvalidArgumentError(f"view: expected a view slot in 0..{btf.n_views - 1}, got {view}")
    n, a, used, dark = _native.photometric_normals(btf.data, btf.views, btf.lights, btf.mask, view, method,
                                                   callback(progress, f"photometric stereo ({method})"))
    return NormalMaps(n, a, used, view, method, int(dark))


def angular_error(a: ArrayLike, b: ArrayLike) -> NDArray[np.float64]:
    """Per texel the angle in degrees between the normals ``a`` and ``b`` (``[..., 3]``, any length)."""
    x = np.asarray(a, dtype=np.float64)
    y = np.asarray(b, dtype=np.float64)
    if x.shape != y.shape or x.shape[-1:] != (3,):
        raise InvalidArgumentError(f"normals: expected two [..., 3] arrays of one shape, got {x.shape} and {y.shape}")
    nx, ny = np.linalg.norm(x, axis=-1), np.linalg.norm(y, axis=-1)
    if not (np.all(nx > 0) and np.all(ny > 0)):
        raise InvalidArgumentError("normals: a normal of zero length has no direction")
    c = np.sum(x * y, axis=-1) / (nx * ny)
    out: NDArray[np.float64] = np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))
    return out


def _unit_normals(n: ArrayLike) -> NDArray[np.float64]:
    x = np.asarray(n, dtype=np.float64)
    if x.ndim != 3 or x.shape[2] != 3:
        raise InvalidArgumentError(f"normals: expected an [H, W, 3] array, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        bad = np.argwhere(~np.isfinite(x).all(axis=-1))[0]
        raise InvalidArgumentError(f"normals: the normal at row {bad[0]}, column {bad[1]} is not finite")
    length = np.linalg.norm(x, axis=-1)
    if np.any(length == 0):
        bad = np.argwhere(length == 0)[0]
        raise InvalidArgumentError(f"normals: the normal at row {bad[0]}, column {bad[1]} has zero length")
    unit: NDArray[np.float64] = x / length[..., None]
    return unit


def height(normal_map: Union[ArrayLike, NormalMaps], *, method: str = "fft") -> NDArray[np.float32]:
    """The height (in texel widths, mean 0) whose slopes best match ``normal_map`` (``[H, W, 3]``
    or a :class:`NormalMaps`) in the least-squares sense (Frankot and Chellappa 1988; see the
    module docs for the methods). Normals facing sideways or down (``n_z <= 0.05``) are
    clamped to a slope of 20 (87 degrees)."""
    method = choice("method", method, HEIGHT_METHODS)
    n = _unit_normals(normal_map.normals if isinstance(normal_map, NormalMaps) else normal_map)
    nz = np.maximum(n[..., 2], 0.05)
    # Slopes along x (right) and y (up the image); rows run down the image, so d/dy = -d/drow.
    p = np.clip(-n[..., 0] / nz, -20.0, 20.0)
    q = np.clip(-n[..., 1] / nz, -20.0, 20.0)
    h, w = p.shape
    if method == "mirror":
        # Even reflection of the height: dz/dx flips sign across a vertical mirror, dz/dy does
        # not, and the other way for a horizontal one.
        p = np.block([[p, -p[:, ::-1]], [p[::-1, :], -p[::-1, ::-1]]])
        q = np.block([[q, q[:, ::-1]], [-q[::-1, :], -q[::-1, ::-1]]])
    z = _frankot_chellappa(p, q)[:h, :w]
    return np.ascontiguousarray(z - z.mean(), dtype=np.float32)


#: The weight of the curvature penalty in :func:`_frankot_chellappa`: a small price on the
#: second difference, which vanishes at low frequencies (as w^4) and holds near Nyquist, where
#: the central difference cannot see the height (its odd and even texels would drift apart).
CURVATURE = 0.05


def _frankot_chellappa(p: NDArray[np.float64], q: NDArray[np.float64]) -> NDArray[np.float64]:
    """The periodic height whose central differences best match the slopes ``p`` (x) and ``q``
    (y up) in the least-squares sense, with a small curvature penalty, solved in frequency.

    The derivative is the central difference, ``j sin w``: normal maps are made from heights by
    central differences (the built-in materials' among them), and for those the result is their
    height to 1.5-4.5% of its spread (the penalty, :data:`CURVATURE`, and the checkerboard a
    central difference cannot see). The paper's continuous ``j w``, or a half-texel difference,
    misreads such normals by 9-15% of the spread and do no better on photometric-stereo normals
    (measured on the built-in materials)."""
    h, w = p.shape
    wx = 2.0 * np.pi * np.fft.fftfreq(w)[None, :]
    # y up the image: row r is at y = -r.
    wy = 2.0 * np.pi * np.fft.fftfreq(h)[:, None]
    dx = 1j * np.sin(wx)
    dy = -1j * np.sin(wy)
    pf, qf = np.fft.fft2(p), np.fft.fft2(q)
    den = np.abs(dx) ** 2 + np.abs(dy) ** 2 + CURVATURE * ((1 - np.cos(wx)) ** 2 + (1 - np.cos(wy)) ** 2)
    den[0, 0] = 1.0
    zf = (np.conj(dx) * pf + np.conj(dy) * qf) / den
    zf[0, 0] = 0.0
    return np.real(np.fft.ifft2(zf))


def encode_normals(normal_map: ArrayLike) -> NDArray[np.float32]:
    """``0.5 n + 0.5`` of unit normals: the [0, 1] encoding normal-map readers take."""
    return np.ascontiguousarray(0.5 * _unit_normals(normal_map) + 0.5, dtype=np.float32)


def save_normals(path: PathLike, normal_map: ArrayLike) -> None:
    """Write ``[H, W, 3]`` normals: ``.exr`` the unit vectors as float32 (R = x, G = y, B = z),
    ``.png`` 16-bit ``0.5 n + 0.5`` (no sRGB curve). Zero-length or non-finite normals are
    refused."""
    p = os.fspath(path)
    ext = os.path.splitext(p)[1].lower()
    if ext not in (".exr", ".png"):
        raise InvalidArgumentError(f"path: expected a .exr or .png file name, got {ext or 'no extension'!r}")
    n = _unit_normals(normal_map)
    if ext == ".exr":
        _native.write_exr(p, np.ascontiguousarray(n, dtype=np.float32))
    else:
        _native.write_png16(p, encode_normals(n))


def save_height(path: PathLike, z: ArrayLike, *, scale: Optional[float] = None) -> float:
    """Write an ``[H, W]`` height: ``.exr`` float32 as it is (channel ``Y``), ``.png`` 16-bit
    grey mapped from [min, max] (or [-scale, scale] when given) to [0, 1]. Returns the height
    that maps to a PNG step of 1 (0 for EXR)."""
    p = os.fspath(path)
    ext = os.path.splitext(p)[1].lower()
    a = np.asarray(z, dtype=np.float32)
    if a.ndim != 2 or not np.all(np.isfinite(a)):
        raise InvalidArgumentError(f"height: expected a finite [H, W] array, got shape {a.shape}")
    if ext == ".exr":
        _native.write_exr_channels(p, ["Y"], np.ascontiguousarray(a[None]))
        return 0.0
    if ext != ".png":
        raise InvalidArgumentError(f"path: expected a .exr or .png file name, got {ext or 'no extension'!r}")
    lo, hi = (float(a.min()), float(a.max())) if scale is None else (-float(scale), float(scale))
    span = max(hi - lo, 1e-12)
    _native.write_png16(p, np.ascontiguousarray(np.clip((a - lo) / span, 0.0, 1.0), dtype=np.float32))
    return span / 65535.0
