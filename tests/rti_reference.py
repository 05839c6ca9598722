"""A CPU (numpy, float64) reference of the viewer's 2D view of a single-view model, written from
the formulas (Malzbender et al. 2001, section 5; the docstring of ``btfrs.web.rti_block``), not
from the viewer's code: the per-texel value of each rendering mode, and the view (pan, zoom,
level of a pyramid) resampled bilinearly at the canvas's pixel centres."""
from __future__ import annotations

from typing import Callable, Dict, Sequence

import numpy as np

LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


def basis(lx, ly) -> np.ndarray:
    """(lx^2, ly^2, lx ly, lx, ly, 1)."""
    lx, ly = np.asarray(lx, float), np.asarray(ly, float)
    return np.stack([lx * lx, ly * ly, lx * ly, lx, ly, np.ones_like(lx)], axis=-1)


def fit_polynomials(evaluate: Callable[[Sequence[float]], np.ndarray], lights: np.ndarray) -> np.ndarray:
    """Per texel and channel, the least-squares biquadratic through the values at ``lights``:
    ``[6, H, W, 3]`` (``evaluate(light)`` gives ``[H, W, 3]``)."""
    values = np.stack([evaluate(tuple(l)).astype(np.float64) for l in lights])  # [K, H, W, 3]
    b = basis(lights[:, 0], lights[:, 1])  # [K, 6]
    k = values.shape[0]
    coef, *_ = np.linalg.lstsq(b, values.reshape(k, -1), rcond=None)
    return coef.reshape((6,) + values.shape[1:])


def stationary_normals(a: np.ndarray) -> np.ndarray:
    """RTIViewer's normal from per-texel coefficients ``a`` ``[6, H, W, 3]``: the stationary point
    of the luminance polynomial ((0, 0) where its quadratic part is singular), clamped to the
    unit disc, lifted onto the hemisphere: ``[H, W, 3]``."""
    lum = np.tensordot(a, LUMINANCE, axes=([3], [0]))  # [6, H, W]
    a0, a1, a2, a3, a4 = lum[:5]
    det = 4 * a0 * a1 - a2 * a2
    ok = np.abs(det) > 1e-6 * (a0 * a0 + a1 * a1 + a2 * a2)
    safe = np.where(ok, det, 1.0)
    u = np.where(ok, (a2 * a4 - 2 * a1 * a3) / safe, 0.0)
    v = np.where(ok, (a2 * a3 - 2 * a0 * a4) / safe, 0.0)
    r = np.hypot(u, v)
    scale = np.where(r > 1, 1 / np.maximum(r, 1e-300), 1.0)
    u, v = u * scale, v * scale
    return np.stack([u, v, np.sqrt(np.maximum(0.0, 1 - u * u - v * v))], axis=-1)


def texel_values(evaluate: Callable[[Sequence[float]], np.ndarray], mode: str, light: Sequence[float],
                 params: Dict[str, float], fit_lights: np.ndarray) -> np.ndarray:
    """The mode's value per texel, ``[H, W, 3]`` float64."""
    l = np.asarray(light, float)
    f = evaluate(tuple(l)).astype(np.float64)
    if mode == "default":
        return f
    a = fit_polynomials(evaluate, np.asarray(fit_lights, float))
    n = stationary_normals(a)
    if mode == "normals":
        return (n + 1) / 2
    if mode == "diffuse_gain":
        # P' keeps P's value and slope at (u0, v0) and scales its quadratic part by g.
        g = params["gain"]
        u0, v0 = n[..., 0:1], n[..., 1:2]
        a0, a1, a2, a3, a4, a5 = a
        b0, b1, b2 = g * a0, g * a1, g * a2
        b3 = (1 - g) * (2 * a0 * u0 + a2 * v0) + a3
        b4 = (1 - g) * (2 * a1 * v0 + a2 * u0) + a4
        b5 = (1 - g) * (a0 * u0**2 + a1 * v0**2 + a2 * u0 * v0) + (a3 - b3) * u0 + (a4 - b4) * v0 + a5
        x, y = l[0], l[1]
        p = a0 * x * x + a1 * y * y + a2 * x * y + a3 * x + a4 * y + a5
        q = b0 * x * x + b1 * y * y + b2 * x * y + b3 * x + b4 * y + b5
        return f + q - p
    if mode == "specular":
        h = l + np.array([0.0, 0.0, 1.0])
        h /= np.linalg.norm(h)
        nh = np.maximum(n @ h, 0.0)
        s = np.where(nh > 0, nh ** params["exponent"], 0.0)
        return params["kd"] * f + params["ks"] * s[..., None]
    raise ValueError(mode)


def resample(values: np.ndarray, size: Sequence[int], zoom: float, center: Sequence[float],
             image_size: Sequence[int], scale: float = 1.0, background: float = 0.0) -> np.ndarray:
    """Texel values of a level (``[Hl, Wl, 3]``, each level texel ``scale`` image texels) seen at
    ``zoom`` canvas pixels per image texel with image point ``center`` at the canvas centre, on a
    canvas of ``size`` (width, height): bilinear between texel centres, clamped at the edges;
    ``background`` outside the image. ``[height, width, 3]``."""
    w, h = size
    hl, wl = values.shape[:2]
    px = np.arange(w) + 0.5
    py = np.arange(h) + 0.5
    x = (center[0] + (px - w / 2) / zoom) / scale
    y = (center[1] + (py - h / 2) / zoom) / scale
    qx, qy = x - 0.5, y - 0.5
    ix, iy = np.floor(qx), np.floor(qy)
    fx, fy = qx - ix, qy - iy
    x0 = np.clip(ix, 0, wl - 1).astype(int)
    x1 = np.clip(ix + 1, 0, wl - 1).astype(int)
    y0 = np.clip(iy, 0, hl - 1).astype(int)
    y1 = np.clip(iy + 1, 0, hl - 1).astype(int)
    fx, fy = fx[None, :, None], fy[:, None, None]
    v = values
    out = ((1 - fx) * (1 - fy) * v[y0][:, x0] + fx * (1 - fy) * v[y0][:, x1]
           + (1 - fx) * fy * v[y1][:, x0] + fx * fy * v[y1][:, x1])
    inside = ((x >= 0) & (x < image_size[0] / scale))[None, :] & ((y >= 0) & (y < image_size[1] / scale))[:, None]
    return np.where(inside[..., None], out, background)


def display(img: np.ndarray, exposure: float = 1.0, raw: bool = False) -> np.ndarray:
    """The page's display: exposure, clamp, the sRGB curve, 8 bits (``raw``: clamp, 8 bits)."""
    if raw:
        return np.round(np.clip(img, 0, 1) * 255).astype(np.uint8)
    x = np.clip(img * exposure, 0.0, 1.0)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.round(s * 255.0).astype(np.uint8)
