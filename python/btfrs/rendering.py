"""Rendering BTF models onto surfaces: ``btfrs.render(model, scene, camera, lights, ...)``.

The GPU path uses wgpu headless (a real GPU when there is one, otherwise Mesa's lavapipe;
``BTFRS_ADAPTER=gpu|cpu|<name>`` forces the choice) with one WGSL shader per model; the CPU
path (``backend="cpu"``) is the reference renderer in Rust, which shades the same points with
the same formulas, and which the GPU images are tested against.

Surfaces carry tangent frames that follow their UV parameterisation (paper 002, section 4.2):
the BTF's x axis runs along +u, its y axis along +v (v up the texture), z along the normal. A
coordinate map (paper 000, section 5; ``coords``, ``[Mh, Mw, 2]`` uint16 (x, y) texel
coordinates into the sample) adds one lookup, so a synthesised BTF of any size renders at the
memory cost of the sample plus the map.
"""

from __future__ import annotations

import os
import time
import weakref
from dataclasses import dataclass
from typing import Optional, Sequence, Union

import numpy as np

from . import _native
from .btf import Btf
from .exceptions import InvalidArgumentError
from .models import Lpca, Ptm, _Model

__all__ = ["Scene", "Camera", "PointLight", "DirectionalLight", "render", "RenderResult", "gpu_info"]

Scene = _native.Scene
Camera = _native.Camera


def _vec3(name: str, v) -> list:
    a = np.asarray(v, dtype=np.float64).reshape(-1)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise InvalidArgumentError(f"{name}: expected three finite numbers, got {v!r}")
    return [float(x) for x in a]


def _intensity(v) -> list:
    a = np.asarray(v, dtype=np.float64).reshape(-1)
    if a.size == 1:
        a = np.repeat(a, 3)
    if a.shape != (3,) or not np.all(np.isfinite(a)) or np.any(a < 0):
        raise InvalidArgumentError(f"intensity: expected a non-negative number or RGB triple, got {v!r}")
    return [float(x) for x in a]


@dataclass(frozen=True)
class PointLight:
    """A point light: irradiance ``intensity / distance^2`` (scalar or RGB)."""

    position: Sequence[float]
    intensity: Union[float, Sequence[float]] = 1.0

    def _native(self) -> tuple:
        return ("point", _vec3("position", self.position), _intensity(self.intensity))


@dataclass(frozen=True)
class DirectionalLight:
    """A distant light from ``direction`` (towards the light) with irradiance ``intensity``."""

    direction: Sequence[float]
    intensity: Union[float, Sequence[float]] = 1.0

    def _native(self) -> tuple:
        d = np.asarray(_vec3("direction", self.direction))
        n = float(np.linalg.norm(d))
        if n == 0:
            raise InvalidArgumentError("direction: expected a non-zero vector")
        return ("directional", [float(x) for x in d / n], _intensity(self.intensity))


@dataclass(frozen=True)
class RenderResult:
    """Timings of the last GPU frame (milliseconds), kept by :func:`last_timings`."""

    draw_ms: float
    readback_ms: float
    upload_ms: float


_uploads: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()
# Uploads live on the device of the process that made them: a forked child opens its own
# device (see btfrs_core::process) and uploads again (the parent's uploads, dropped here, are
# leaked rather than freed: see UploadedModel's Drop).
if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_uploads.clear)
_last: list = []


def gpu_info() -> str:
    """The adapter the GPU path uses: name, backend and type."""
    return _native.gpu_info()


def _upload(model, method: str):
    """The model's data on the device, uploaded once per model object and method."""
    t0 = time.perf_counter()
    per_model = _uploads.setdefault(model, {})
    up = per_model.get(method)
    if up is None:
        if isinstance(model, Ptm):
            up = _native.gpu_upload_ptm(model._m)
        elif isinstance(model, _Model):
            up = _native.gpu_upload_model(model._m, method)
        else:
            up = _native.gpu_upload_raw(model.data, model.views, model.lights)
        per_model[method] = up
    return up, (time.perf_counter() - t0) * 1e3


def _method(model, method: Optional[str]) -> str:
    """The renderer for ``model``: LPCA has two (paper 004): ``"3d"`` (the 3D-texture method,
    the default) and ``"9tap"`` (the original); the other models have one, ``"default"``."""
    if isinstance(model, Lpca):
        m = "3d" if method is None else method
        if m not in ("3d", "9tap"):
            raise InvalidArgumentError(f"method: expected \"3d\" or \"9tap\" for an Lpca model, got {method!r}")
        return m
    if method not in (None, "default"):
        raise InvalidArgumentError(f"method: the {type(model).__name__} model has one renderer; got {method!r}")
    return "default"


def _size(size) -> tuple:
    try:
        w, h = (int(size), int(size)) if np.isscalar(size) else (int(size[0]), int(size[1]))
    except (TypeError, ValueError, IndexError):
        raise InvalidArgumentError(f"size: expected (width, height), got {size!r}") from None
    if w <= 0 or h <= 0:
        raise InvalidArgumentError(f"size: expected positive (width, height), got {size!r}")
    return w, h


def render(model: Union[Ptm, _Model, Btf], scene, camera, lights, size=(512, 512), uv_scale=1.0,
           coords: Optional[np.ndarray] = None, backend: str = "gpu", method: Optional[str] = None) -> np.ndarray:
    """Render ``model`` (a fitted model, or a :class:`~btfrs.Btf` for the raw measured data)
    on ``scene`` seen by ``camera`` under ``lights``; returns ``[height, width, 3]`` float32
    linear radiance (0 where no surface is seen).

    Parameters
    ----------
    size: ``(width, height)`` in pixels.
    uv_scale: repetitions of the sample over the UV square (a number or ``(su, sv)``).
    coords: optional ``[Mh, Mw, 2]`` uint16 coordinate map (x, y into the sample), repeated
        ``uv_scale`` times instead of the sample itself.
    backend: ``"gpu"`` (wgpu) or ``"cpu"`` (the reference renderer).
    method: for :class:`~btfrs.Lpca`, ``"3d"`` (Eigen-BRDFs resampled on the elevated
        concentric map in one 3D texture: two trilinear fetches and a lerp, paper 004 section 6,
        the default) or ``"9tap"`` (three nearest views x three nearest lights, section 5).
    """
    if not isinstance(scene, Scene):
        raise TypeError(f"scene: expected a btfrs.Scene, got {type(scene).__name__}")
    if not isinstance(camera, Camera):
        raise TypeError(f"camera: expected a btfrs.Camera, got {type(camera).__name__}")
    if isinstance(lights, (PointLight, DirectionalLight)):
        lights = [lights]
    items = []
    for light in lights:
        if not isinstance(light, (PointLight, DirectionalLight)):
            raise TypeError(f"lights: expected PointLight or DirectionalLight, got {type(light).__name__}")
        items.append(light._native())
    if isinstance(model, Btf) and model.mask is not None and not model.mask.all():
        raise InvalidArgumentError("model: rendering the raw BTF needs every (view, light) pair; this sample has a "
                                   "mask (render the full sample, or a model fitted to the train half)")
    w, h = _size(size)
    us = np.broadcast_to(np.asarray(uv_scale, dtype=np.float64), (2,))
    uvs = [float(us[0]), float(us[1])]
    if coords is not None:
        c = np.asarray(coords)
        if c.dtype != np.uint16:
            raise TypeError(f"coords: expected a uint16 array [H, W, 2], got dtype {c.dtype}")
        coords = np.ascontiguousarray(c)
    if not isinstance(model, (Ptm, Btf, _Model)):
        raise TypeError(f"model: expected a btfrs model or Btf, got {type(model).__name__}")
    meth = _method(model, method)
    if backend == "gpu":
        up, up_ms = _upload(model, meth)
        img, draw, rb = _native.gpu_render(up, scene, camera, items, w, h, uvs, coords)
        _last[:] = [RenderResult(draw, rb, up_ms)]
        return img
    if backend == "cpu":
        if isinstance(model, Ptm):
            return _native.cpu_render_ptm(model._m, scene, camera, items, w, h, uvs, coords)
        if isinstance(model, _Model):
            return _native.cpu_render_model(model._m, scene, camera, items, w, h, uvs, coords, meth)
        return _native.cpu_render_raw(model.data, model.views, model.lights, scene, camera, items, w, h, uvs, coords)
    raise InvalidArgumentError(f"backend: expected \"gpu\" or \"cpu\", got {backend!r}")


def last_timings() -> Optional[RenderResult]:
    """Draw, read-back and upload times of the last GPU :func:`render` call."""
    return _last[0] if _last else None
