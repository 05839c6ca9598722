"""Rendering BTF models onto surfaces: ``btfrs.render(model, scene, camera, lights, ...)``.

The GPU path uses wgpu headless (a real GPU when there is one, otherwise Mesa's lavapipe;
``BTFRS_ADAPTER=gpu|cpu|<name>`` forces the choice) with one WGSL shader per model; the CPU
path (``backend="cpu"``) is the reference renderer in Rust, which shades the same points with
the same formulas, and which the GPU images are tested against.

Surfaces carry tangent frames that follow their UV parameterisation (paper 002, section 4.2):
the BTF's x axis runs along +u, its y axis along +v (v up the texture), z along the normal. A
coordinate map (paper 000, section 5; ``coords``, ``[Mh, Mw, 2]`` uint16 (x, y) texel
coordinates into the sample) adds one lookup, so a synthesised BTF of any size renders at the
memory cost of the sample plus the map. A Wang tile map (paper 002, section 4; ``tiles=`` a
:class:`btfrs.tiles.TileSet` and ``layout=`` its tile ids, or the general :class:`TileMap`) adds
two: the layout cell's atlas tile, then the atlas entry.
"""

from __future__ import annotations

import os
import time
import weakref
from dataclasses import dataclass
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union, cast

import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import _native
from ._checks import choice, instance, integer, real, size_hw
from ._progress import Progress, callback
from .btf import Btf
from .exceptions import ArgumentTypeError, InvalidArgumentError, NumericalError
from .models import Model, wrap

__all__ = ["Scene", "Camera", "PointLight", "DirectionalLight", "render", "RenderResult", "gpu_info", "TileMap"]

Scene = _native.Scene
Camera = _native.Camera

# A light as the native renderers take it: (kind, position or direction, RGB intensity).
_NativeLight = Tuple[str, List[float], List[float]]
# A tile map as the native renderers take it: (atlas, tile size, layout).
_NativeTileMap = Tuple[NDArray[np.uint32], int, NDArray[np.uint32]]


def _vec3(name: str, v: object) -> List[float]:
    a = np.asarray(v, dtype=np.float64).reshape(-1)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise InvalidArgumentError(f"{name}: expected three finite numbers, got {v!r}")
    return [float(x) for x in a]


def _intensity(v: object) -> List[float]:
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

    def _native(self) -> _NativeLight:
        return ("point", _vec3("position", self.position), _intensity(self.intensity))


@dataclass(frozen=True)
class DirectionalLight:
    """A distant light from ``direction`` (towards the light) with irradiance ``intensity``."""

    direction: Sequence[float]
    intensity: Union[float, Sequence[float]] = 1.0

    def _native(self) -> _NativeLight:
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


_uploads: "weakref.WeakKeyDictionary[Union[Model, Btf], Dict[str, _native.GpuModel]]" = weakref.WeakKeyDictionary()
# Uploads live on the device of the process that made them: a forked child opens its own
# device (see btfrs_core::process) and uploads again (the parent's uploads, dropped here, are
# leaked rather than freed: see UploadedModel's Drop).
if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_uploads.clear)
_last: List[RenderResult] = []


def gpu_info() -> str:
    """The adapter the GPU path uses: name, backend and type."""
    return _native.gpu_info()


def _upload(model: Union[Model, Btf], method: str) -> Tuple[_native.GpuModel, float]:
    """The model's data on the device, uploaded once per model object and method."""
    t0 = time.perf_counter()
    per_model = _uploads.setdefault(model, {})
    up = per_model.get(method)
    if up is None:
        if isinstance(model, Model):
            up = _native.gpu_upload_model(model._m, method)
        else:
            up = _native.gpu_upload_raw(model.data, model.views, model.lights)
        per_model[method] = up
    return up, (time.perf_counter() - t0) * 1e3


# What a filtered render draws, its mip chain, and how the chain was made (see _filtered).
_Filtered = Tuple[Union[Model, Btf], _native.MipChain, str]

# How a model's trilinear mip levels are made is the model's own fact (``model.mip``, from its
# registry entry): exact averages of its parameters, projections of the mean appearance, or
# appearance medoids. The raw BTF averages.
_filters: "weakref.WeakKeyDictionary[Union[Model, Btf], Dict[Tuple[Any, ...], _Filtered]]" = weakref.WeakKeyDictionary()
if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_filters.clear)


def _map_key(coords: Optional[NDArray[np.uint16]], tm: Optional[_NativeTileMap]) -> Tuple[Any, ...]:
    """A key for the texture a render shows (the map's bytes, hashed)."""
    if tm is not None:
        return ("tiles", hash(tm[0].tobytes()), tm[1], hash(tm[2].tobytes()))
    if coords is not None:
        return ("coords", coords.shape, hash(coords.tobytes()))
    return ("sample",)


def _filtered(model: Union[Model, Btf], filt: str, coords: Optional[NDArray[np.uint16]],
              tm: Optional[_NativeTileMap]) -> _Filtered:
    """What a filtered render draws and with which mip chain: ``(drawn, chain, how)``, ``how``
    being ``"average"`` (a box-filtered pyramid: the model extended by averaged texels, for
    models linear in their texel arrays and the raw BTF) or ``"medoid"`` (levels of existing
    texels chosen by appearance, for the others; see rust/btfrs-render/src/filter.rs). Cached
    per model, filter and map."""
    dims = (model.height, model.width)
    avg = filt == "trilinear" and (isinstance(model, Btf) or model.mip != "medoid")
    key = (filt, avg, _map_key(coords, tm))
    per_model = _filters.setdefault(model, {})
    hit = per_model.get(key)
    if hit is not None:
        return hit
    if avg:
        chain, idx, wts = _native.filter_build("average", dims, coords, tm)
        if isinstance(model, Btf):
            flat = model.data.reshape((dims[0] * dims[1],) + model.data.shape[2:])
            levels = np.empty((idx.shape[0],) + flat.shape[1:], dtype=np.float32)
            everything = np.concatenate([flat, levels])
            for g in range(idx.shape[0]):
                sel = idx[g] >= 0
                everything[flat.shape[0] + g] = np.tensordot(wts[g][sel], everything[idx[g][sel]], axes=1)
            extra = -(-idx.shape[0] // dims[1]) * dims[1] - idx.shape[0]
            rows = [everything, np.repeat(flat[:1], extra, axis=0)]
            data = np.concatenate(rows).reshape((-1, dims[1]) + flat.shape[1:])
            drawn: Union[Model, Btf] = Btf(data, model.views, model.lights, check=False)
        else:
            drawn = wrap(_native.mip_model(model._m, idx, wts))
        hit = (drawn, chain, "average" if isinstance(model, Btf) else model.mip)
    else:
        sig = None
        if filt == "trilinear":
            sig = _raw_signature(model) if isinstance(model, Btf) else _native.filter_signature(model._m)
        chain, _, _ = _native.filter_build("medoid", dims, coords, tm, sig)
        hit = (model, chain, "medoid")
    per_model[key] = hit
    return hit


def _raw_signature(btf: Btf) -> NDArray[np.float32]:
    """Per texel, the measured values at a few (view, light) pairs spread over the set."""
    v, l = btf.data.shape[2], btf.data.shape[3]
    pairs = [(0, 0), (v // 2, l // 3), (v - 1, (2 * l) // 3), (v // 3, l - 1), ((2 * v) // 3, l // 2), (v // 4, l // 5)]
    sig = np.stack([btf.data[:, :, a, b, :] for a, b in pairs], axis=2)
    return np.ascontiguousarray(sig.reshape(btf.data.shape[0] * btf.data.shape[1], -1), dtype=np.float32)


def _method(model: Union[Model, Btf], method: Optional[str]) -> str:
    """The renderer for ``model``: its first (``model.renderers[0]``) unless named. LPCA has two
    (paper 004): ``"9tap"`` (the original, the default) and ``"3d"`` (the 3D-texture method);
    the raw BTF has one, ``"default"``."""
    names = model.renderers if isinstance(model, Model) else ["default"]
    if method is None or method == "default":
        return names[0]
    return choice("renderer", method, tuple(names))


def _culprit(model: Union[Model, Btf]) -> str:
    """Where a non-finite GPU frame comes from: the model's array (or the BTF's data) holding its
    largest stored value (the GPU knows the model only as uploaded words)."""
    arrays = model.arrays if isinstance(model, Model) else {"data": model.data}
    sizes = {n: float(np.max(np.abs(a))) for n, a in arrays.items() if a.dtype.kind == "f" and a.size}
    if not sizes:
        return ""
    name = max(sizes, key=lambda n: sizes[n])
    return f"; its largest stored value is {sizes[name]:.3e}, in array {name!r}"


def _uv_scale(uv_scale: ArrayLike) -> List[float]:
    if np.ndim(uv_scale) == 0:
        s = real("uv_scale", uv_scale, min=0.0, min_open=True)
        return [s, s]
    if np.shape(uv_scale) != (2,):
        raise InvalidArgumentError(f"uv_scale: expected a number or a pair (su, sv), got {uv_scale!r}")
    pair = cast(Sequence[float], uv_scale)
    return [real("uv_scale[0]", pair[0], min=0.0, min_open=True),
            real("uv_scale[1]", pair[1], min=0.0, min_open=True)]


def _surface(model: Union[Model, Btf], coords: Any, tiles: Any, layout: Any,
             tile_map: Optional["TileMap"]) -> Tuple[Optional[NDArray[np.uint16]], Optional[_NativeTileMap]]:
    """What the surface shows, as the native renderer takes it: ``(coords, tile map)``, at most
    one of them, from a coordinate map, a Wang tile set with its layout, or a tile map."""
    if coords is not None:
        c = np.asarray(coords)
        if c.dtype != np.uint16:
            raise ArgumentTypeError(f"coords: expected a uint16 array [H, W, 2], got dtype {c.dtype}")
        coords = np.ascontiguousarray(c)
    if tiles is not None or layout is not None:
        if tiles is None or layout is None:
            raise InvalidArgumentError("tiles: give both tiles= (a tile set) and layout= (its tile ids)")
        if tile_map is not None:
            raise InvalidArgumentError("tile_map: give tiles= and layout=, or tile_map=, not both")
        # A TileSet (btfrs.tiles sits above this module: known by what it does).
        if not callable(getattr(tiles, "tile_map", None)):
            raise ArgumentTypeError(f"tiles: expected a btfrs.tiles.TileSet, got {type(tiles).__name__}")
        tile_map = tiles.tile_map(model, layout)
    tm = None
    if tile_map is not None:
        instance("tile_map", tile_map, TileMap, "a btfrs.rendering.TileMap")
        if coords is not None:
            raise InvalidArgumentError("tiles: give a coordinate map or a tile map, not both")
        tm = tile_map._native()
    return coords, tm


@dataclass(frozen=True)
class TileMap:
    """A tile map for :func:`render`: ``atlas`` uint32 ``[AH, AW]`` (AH, AW multiples of
    ``tile``) holds per atlas texel the model texel (row-major index) to shade, row 0 at the top;
    ``layout`` ``[R, C, 2]`` holds per cell the (row, column) of its atlas tile. ``uv`` in
    ``[0, 1]^2`` spans the whole layout (once per ``uv_scale`` repetition); the lookup is
    ``rust/btfrs-render/src/tilemap.rs``."""

    atlas: np.ndarray
    tile: int
    layout: np.ndarray

    def _native(self) -> _NativeTileMap:
        a = np.asarray(self.atlas)
        lay = np.asarray(self.layout)
        for name, x in (("atlas", a), ("layout", lay)):
            if not np.issubdtype(x.dtype, np.integer):
                raise ArgumentTypeError(f"tile_map: expected an integer {name}, got dtype {x.dtype}")
            if x.size and x.min() < 0:
                raise InvalidArgumentError(f"tile_map: negative {name} entry {int(x.min())}")
        t = int(self.tile)
        return (np.ascontiguousarray(a, dtype=np.uint32), t, np.ascontiguousarray(lay, dtype=np.uint32))


def render(model: Union[Model, Btf], scene: Scene, camera: Camera, lights: Any = None, *,
           size: Union[int, Tuple[int, int]] = (512, 512), uv_scale: ArrayLike = 1.0,
           coords: Optional[np.ndarray] = None, backend: str = "gpu", renderer: Optional[str] = None,
           tiles: Any = None, layout: Any = None, tile_map: Optional[TileMap] = None,
           environment: Any = None, lighting: str = "sampled", samples: int = 64, seed: int = 0,
           filter: str = "nearest", progress: Progress = None) -> np.ndarray:
    """Render ``model`` (a fitted model, or a :class:`~btfrs.Btf` for the raw measured data)
    on ``scene`` seen by ``camera`` under ``lights`` and/or an ``environment``; returns
    ``[height, width, 3]`` float32, 0 where no surface is seen.

    **Unit**: ``pi x radiance``. BTF values are measured as reflected radiance over the
    irradiance of a light at normal incidence, times pi (a white Lambertian sample reads
    ``cos(theta_l)``, not ``cos(theta_l) / pi``), and the renderer multiplies them by each light's
    irradiance: a white Lambertian plane under a light of intensity 1 straight above reads 1,
    under a constant environment of radiance 1 it reads pi. Divide by pi for radiance.

    Parameters
    ----------
    size: ``(height, width)`` in pixels, as numpy shapes (the result has shape ``size + (3,)``),
        or one int for a square.
    uv_scale: repetitions of the sample over the UV square (a positive number or ``(su, sv)``).
    coords: optional ``[Mh, Mw, 2]`` uint16 coordinate map (x, y into the sample), repeated
        ``uv_scale`` times instead of the sample itself.
    tiles, layout: a Wang tile set (:func:`btfrs.tiles.wang`) and a ``[rows, cols]`` array of its
        tile ids (:meth:`~btfrs.tiles.TileSet.tiling`): the layout covers the UV square once per
        ``uv_scale`` repetition; ``model`` is the set's BTFel model (``tiles.model``) or the
        model / Btf it was synthesized from.
    tile_map: the general form (:class:`TileMap`), exclusive with ``tiles`` and ``coords``.
    backend: ``"gpu"`` (wgpu) or ``"cpu"`` (the reference renderer).
    renderer: the model's renderer, one of ``model.renderers`` (``None``: the first, the
        default). For :class:`~btfrs.Lpca`: ``"9tap"`` (three nearest views x three nearest
        lights, section 5, the default) or ``"3d"`` (Eigen-BRDFs resampled on the elevated
        concentric map in one 3D texture: two trilinear fetches and a lerp, paper 004 section 6).
    environment: a :class:`btfrs.Environment` (distant light, paper 002 section 4).
    lighting: how an ``environment`` lights the model: ``"sampled"`` (the default, every model:
        ``samples`` importance-sampled directional lights, ``seed``, rendered in one pass;
        ``lights`` are added to them) or ``"sh"`` (models with a double-SH expansion,
        ``model.sh_lighting``: the SH-domain method, no ``lights``).
    filter: ``"nearest"`` (one texel, the default), ``"bilinear"`` (four) or ``"trilinear"``
        (mip-mapped, eight) lookups, in the texture the surface shows: through a coordinate map
        or a tile map each tap is resolved on its own, so filtering has no seams at the map's
        discontinuities. Trilinear levels are exact box-filtered averages for models linear in
        their texel arrays (PTM-RGB, HSH, SH, RBF, bilinear, the raw BTF), projections for
        LPCA (each coarse texel is the block's mean appearance in the best of the block's
        clusters, least squares: exact inside one cluster) and appearance medoids (the texel of
        each block nearest its mean appearance) for the others (Lafortune, per-view Lafortune,
        SRF, PTM-LRGB), whose parameters cannot be averaged. Built once per model and map and
        cached.
    progress: None, True or a callable ``(done, total)`` counting the phases: for the GPU the
        upload (immediate when the model is already on the device) and the draw with its
        read-back; for the CPU the frame.
    """
    instance("scene", scene, Scene, "a btfrs.Scene")
    instance("camera", camera, Camera, "a btfrs.Camera")
    env_method = None
    method = renderer
    lighting = choice("lighting", lighting, ("sampled", "sh"))
    if environment is not None:
        # An Environment (btfrs.environment builds this module's lights, so it is known by what
        # it does rather than imported here).
        if not (hasattr(environment, "lights") and hasattr(environment, "data")):
            raise ArgumentTypeError(f"environment: expected a btfrs.Environment, got {type(environment).__name__}")
        env_method = lighting
        if env_method == "sh":
            if lights is not None and (not hasattr(lights, "__len__") or len(lights)):
                raise InvalidArgumentError("lights: lighting=\"sh\" lights by the environment alone; use "
                                           "lighting=\"sampled\" to add lights")
            if not isinstance(model, Model) or not model.sh_lighting:
                what = "the raw BTF" if isinstance(model, Btf) else f"a {getattr(model, 'kind', type(model).__name__)} model"
                raise InvalidArgumentError(f"lighting: \"sh\" needs a double-SH model (btfrs.fit.sh), not {what}; "
                                           f"use lighting=\"sampled\", which renders every model")
            lights = []
        else:
            n = integer("samples", samples, min=1, max=65536)
            extra = [] if lights is None else ([lights] if isinstance(lights, (PointLight, DirectionalLight)) else lights)
            if isinstance(extra, (str, bytes)) or not hasattr(extra, "__iter__"):
                raise ArgumentTypeError(f"lights: expected a light or a list of PointLight/DirectionalLight, got {lights!r}")
            lights = environment.lights(n, seed=integer("seed", seed, min=0)) + list(extra)
    elif lighting != "sampled":
        raise InvalidArgumentError(f"lighting: {lighting!r} only with environment=")
    if lights is None:
        raise InvalidArgumentError("lights: expected a light, a list of lights or environment=")
    if isinstance(lights, (PointLight, DirectionalLight)):
        lights = [lights]
    if isinstance(lights, (str, bytes)) or not hasattr(lights, "__iter__"):
        raise ArgumentTypeError(f"lights: expected a light or a list of PointLight/DirectionalLight, got {lights!r}")
    items = []
    for light in lights:
        if not isinstance(light, (PointLight, DirectionalLight)):
            raise ArgumentTypeError(f"lights: expected PointLight or DirectionalLight, got {type(light).__name__}")
        items.append(light._native())
    if isinstance(model, Btf) and model.mask is not None and not model.mask.all():
        raise InvalidArgumentError("model: rendering the raw BTF needs every (view, light) pair; this sample has a "
                                   "mask (render the full sample, or a model fitted to the train half)")
    # (height, width) as numpy shapes; the native functions take width first, as wgpu does.
    # 16384 is the CPU renderer's limit and wgpu's usual one; a device with a lower one says so.
    h, w = size_hw("size", size, max=16384)
    uvs = _uv_scale(uv_scale)
    instance("model", model, (Model, Btf), "a btfrs model or Btf")
    coords, tm = _surface(model, coords, tiles, layout, tile_map)
    meth = _method(model, method)
    backend = choice("backend", backend, ("gpu", "cpu"))
    filt = choice("filter", filter, ("nearest", "bilinear", "trilinear"))
    fa = None
    if filt != "nearest":
        if isinstance(model, Model) and meth != model.renderers[0]:
            raise InvalidArgumentError(f"filter: filtered lookups use the default renderer; got renderer={meth!r}")
        model, chain, _ = _filtered(model, filt, coords, tm)
        fa = (filt, chain)
    if env_method == "sh":
        cb = callback(progress, f"render {h}x{w} (SH environment, {backend})")
        if cb is not None:
            cb(0, 1)
        assert isinstance(model, Model)  # checked above: lighting="sh" takes a double-SH model
        up, up_ms = _upload(model, meth) if backend == "gpu" else (None, 0.0)
        img, draw, rb = _native.render_env_sh(model._m, up, scene, camera, environment.data, w, h, uvs, coords, tm, fa)
        if backend == "gpu":
            _last[:] = [RenderResult(draw, rb, up_ms)]
        if cb is not None:
            cb(1, 1)
        return img
    if backend == "gpu":
        cb = callback(progress, f"render {h}x{w} (upload, draw + read-back)")
        if cb is not None:
            cb(0, 2)
        up, up_ms = _upload(model, meth)
        if cb is not None:
            cb(1, 2)
        try:
            img, draw, rb = _native.gpu_render(up, scene, camera, items, w, h, uvs, coords, tm, fa)
        except NumericalError as e:
            raise NumericalError(f"{e}{_culprit(model)}") from None
        _last[:] = [RenderResult(draw, rb, up_ms)]
        if cb is not None:
            cb(2, 2)
        return img
    cb = callback(progress, f"render {h}x{w} (cpu)")
    if cb is not None:
        cb(0, 1)
    if isinstance(model, Model):
        img = _native.cpu_render_model(model._m, scene, camera, items, w, h, uvs, coords, meth, tm, fa)
    else:
        img = _native.cpu_render_raw(model.data, model.views, model.lights, scene, camera, items, w, h, uvs, coords,
                                     tm, fa)
    if cb is not None:
        cb(1, 1)
    return img


def last_timings() -> Optional[RenderResult]:
    """Draw, read-back and upload times of the last GPU :func:`render` call."""
    return _last[0] if _last else None
