"""Plain numpy baselines that btfrs is measured against (in the benchmark, the demo and tests).

These are written the way a careful numpy user would write them, in float64, so that speed
ratios and accuracy comparisons are against a fair reference rather than a straw man.
"""

from __future__ import annotations

import numpy as np

from .btf import Btf

__all__ = ["ptm_rgb_numpy", "nearest_lights_interpolation"]


def _basis(lights: np.ndarray) -> np.ndarray:
    lx, ly = lights[:, 0], lights[:, 1]
    return np.stack([lx * lx, ly * ly, lx * ly, lx, ly, np.ones_like(lx)], axis=1)


def ptm_rgb_numpy(btf: Btf) -> np.ndarray:
    """PTM-RGB the numpy way: ``numpy.linalg.pinv`` per view slot, applied to all texels with one
    BLAS contraction per slot. Returns ``[H, W, V, 3, 6]`` float64."""
    h, w, v, l, _ = btf.shape
    out = np.empty((h, w, v, 3, 6))
    for vi in range(v):
        ls = np.arange(l) if btf.mask is None else np.flatnonzero(btf.mask[vi])
        p = np.linalg.pinv(_basis(btf.lights[ls]))  # [6, n]
        x = btf.data[:, :, vi, ls, :]  # [h, w, n, 3]
        out[:, :, vi] = np.einsum("kn,hwnc->hwck", p, x, optimize=True)
    return out


def nearest_lights_interpolation(train: Btf, test: Btf, k: int = 3) -> tuple[float, float]:
    """Held-out relative error of the simplest predictor: for each test pair, the inverse-angle
    weighted mean of the ``k`` nearest present lights of the same view slot (raw data, no model).
    Returns ``(relative error ||pred - gt|| / ||gt||, RMSE)`` over all test values."""
    num = den = 0.0
    n = 0
    for v in range(test.n_views):
        ls_test = np.flatnonzero(test.mask[v]) if test.mask is not None else np.arange(test.n_lights)
        ls_train = np.flatnonzero(train.mask[v]) if train.mask is not None else np.arange(train.n_lights)
        if len(ls_test) == 0 or len(ls_train) == 0:
            continue
        ang = np.arccos(np.clip(test.lights[ls_test] @ train.lights[ls_train].T, -1, 1))  # [nt, ntr]
        near = np.argsort(ang, axis=1)[:, :k]
        wgt = 1.0 / np.maximum(np.take_along_axis(ang, near, 1), 1e-9)
        wgt /= wgt.sum(axis=1, keepdims=True)
        src = train.data[:, :, v][:, :, ls_train[near]]  # [h, w, nt, k, 3]
        pred = np.einsum("hwtkc,tk->hwtc", src.astype(np.float64), wgt)
        gt = test.data[:, :, v][:, :, ls_test].astype(np.float64)
        num += float(np.sum((pred - gt) ** 2))
        den += float(np.sum(gt**2))
        n += gt.size
    return float(np.sqrt(num / den)), float(np.sqrt(num / max(n, 1)))
