"""Independent NumPy decoder for NeuralRTI web models (info.json + plane_*.jpg), the test suite's
reference for btfrs's NeuralRTI export.

Written from the format's description (NeuralRTI's save_web writer and OpenLIME's neural layer
and shader as they read it), not from btfrs's code; it reproduces the
per-pixel arithmetic of OpenLIME's neural shader (in float64 instead of the
GPU's float32, and without texture filtering / tile resampling).
"""
import json
import os

import numpy as np
from PIL import Image


def _swizzle(colorspace):
    # GLSL swizzle such as ".bgr" -> channel indices into an RGB triple
    return [("rgb", "xyz")[ch in "xyz"].index(ch) for ch in colorspace.lower()]


def _plane_paths(folder, info):
    """Files holding latents 3k..3k+2. NeuralRTI writes plane_0..; OpenLIME reads plane_1.."""
    nimg = info["planes"] // 3
    exts = [info.get("format", "jpg"), "jpg", "png"]
    for first in (0, 1):
        for ext in exts:
            paths = [os.path.join(folder, f"plane_{first + k}.{ext}") for k in range(nimg)]
            if all(os.path.exists(p) for p in paths):
                return paths
    raise FileNotFoundError(f"no plane_*.{{jpg,png}} set in {folder}")


def _elu(a):
    return np.where(a > 0.0, a, np.expm1(np.minimum(a, 0.0)))


def decode(folder: str, light_xy: tuple) -> np.ndarray:
    """Relit image [H, W, 3] (float64, RGB, display-referred, unclamped)."""
    with open(os.path.join(folder, "info.json")) as f:
        info = json.load(f)
    sw = _swizzle(info.get("colorspace", "rgb"))
    mn = np.asarray(info["min"], np.float64).ravel()   # one value per latent
    mx = np.asarray(info["max"], np.float64).ravel()

    # 1. latents: byte/255 rescaled to [min, max]; image channels swizzled by colorspace
    imgs = [np.asarray(Image.open(p).convert("RGB"), np.float64)[..., sw] for p in _plane_paths(folder, info)]
    t = np.concatenate(imgs, axis=-1) / 255.0            # [H, W, planes]
    latent = mn + t * (mx - mn)

    # 2. network input: latents first, then raw light x, y, zero-padded to a multiple of 4
    H, W, P = latent.shape
    x = np.concatenate([latent, np.broadcast_to(np.asarray(light_xy, np.float64), (H, W, 2))], axis=-1)

    # 3. layers: weights flattened row-major as [out][in] (both padded to multiples of 4)
    nlayers = len(info["weights"])
    for i, (w, b) in enumerate(zip(info["weights"], info["biases"])):
        b = np.asarray(b, np.float64)
        w = np.asarray(w, np.float64).reshape(len(b), -1)    # [out, in_padded]
        x = np.pad(x, [(0, 0), (0, 0), (0, w.shape[1] - x.shape[-1])])
        x = x @ w.T + b
        if i < nlayers - 1:
            x = _elu(x)                                        # hidden layers: ELU(alpha=1)
    # 4. output layer is linear; reorder channels with the same swizzle (bgr -> rgb)
    return x[..., sw]


def to_bytes(img: np.ndarray) -> np.ndarray:
    """WebGL unorm8 store: clamp to [0,1], scale by 255, round to nearest."""
    return np.floor(np.clip(img, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
