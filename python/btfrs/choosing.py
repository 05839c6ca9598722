"""Model no more than a scene needs: ``btfrs.choose(btf, scene=SceneUse(...), tolerance=...)``.

A renderer asks a BTF model only for the (view, light) directions its scene produces: a fixed
camera looking straight down sees a few view slots, lights in a cone need only the measured
lights around them, and a distant surface shows a coarse mip level of the texture. So:

1. **What the scene asks.** :class:`SceneUse` rasterises the scene with the CPU reference
   pipeline (``btfrs._native.scene_directions``: the very points and tangent frames the renderers
   shade) for every camera of a path and every light of every light set, giving per covered pixel
   the local view direction, each light's local direction and irradiance, and the texel
   footprint. Each (pixel, light) pair weighs its irradiance (the rendered value, and so its
   error, scales with it), divided among the frames (cameras x light sets).
2. **Which slots.** Each view and light direction is mapped onto the measured ones with the
   renderers' interpolation weights (the three nearest, ``btfrs_core::directions::
   interp_weights``); a measured view or light with any weight is *used*.
3. **Candidates.** Every registered model (:func:`btfrs.model_kinds`) at its registry example
   settings is fitted on the used views x used lights (``"scene"``), on the used views x all
   lights (``"views"``) and on everything (``"full"``); the raw data of the used slots is a
   candidate too (kind ``"raw"``: the measured data themselves, rendered by interpolation; not
   on the full set, which is the reference itself).
   Per-view-slot models (PTM, per-view Lafortune) fitted on a few slots are small; models over
   all directions are not smaller for it, but may fit the region the scene uses better.
4. **Score.** ``samples`` (view, light) pairs drawn from the scene's distribution (seeded); each
   candidate's image at each pair against the raw measured data interpolated at the same
   directions (the raw renderer's weights over the full BTF), both box-filtered to the scene's mip
   level (the weighted median of log2 texels per pixel: a distant surface is seen coarser, and
   tolerates more). The error is the weighted relative L2 error ``||pred - ref|| / ||ref||``.
5. **Cost.** ``nbytes`` (bytes as stored for rendering) and the draw time of the scene's first
   frame (``btfrs.render`` on the GPU path, best of two after a warm-up frame), timed only for
   the candidates that can be chosen.

The choice is the cheapest candidate (bytes, then render ms) within the budgets whose error meets
the tolerance; if none does, the most accurate one within the budgets, flagged ``met=False``
(:meth:`Choice.explain` says so).

**Without a scene** (``scene=None``, the RTI question: *which model predicts the lights I did
not photograph?*), a share ``holdout`` of the measured lights is set aside (drawn with ``seed``),
every candidate is fitted on the others, and its error is the relative L2 error
``||pred - measured|| / ||measured||`` over the held-out lights (every view): the smallest
candidate in bytes that meets the tolerance wins, and each row carries its fit seconds. The raw
candidate is the training lights' raw interpolation (what a viewer without a model shows).
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np
from numpy.typing import NDArray

from . import _native
from ._checks import choice as check_choice
from ._checks import instance, integer, memory_size, real, size_hw
from ._checks import seed as check_seed
from ._progress import Progress, callback
from .btf import Btf
from .exceptions import ArgumentTypeError, BtfrsError, DegenerateDataError, InvalidArgumentError
from .models import Model, model_kinds
from .fit import fit as fit_model
from .rendering import Camera, DirectionalLight, PointLight, Scene, _uv_scale, last_timings, render

__all__ = ["SceneUse", "Choice", "choose", "default_candidates", "interp_weights", "SUBSETS"]

#: The direction subsets candidates are fitted on, cheapest first.
SUBSETS = ("scene", "views", "full")

_Light = Union[PointLight, DirectionalLight]


def _light_sets(lights: Any) -> Tuple[Tuple[_Light, ...], ...]:
    """A light, a list of lights (one set, lit together), or a list of such lists (a light range
    or animation: one set per frame), as a tuple of non-empty tuples."""
    def is_light(x: object) -> bool:
        return isinstance(x, (PointLight, DirectionalLight))

    if is_light(lights):
        return ((lights,),)
    if isinstance(lights, (str, bytes)) or not hasattr(lights, "__iter__"):
        raise ArgumentTypeError(f"lights: expected a light, a list of lights or a list of light sets, got {lights!r}")
    items = list(lights)
    if not items:
        raise InvalidArgumentError("lights: expected at least one light")
    if all(is_light(x) for x in items):
        return (tuple(items),)
    sets = []
    for k, s in enumerate(items):
        if is_light(s):
            s = [s]
        if isinstance(s, (str, bytes)) or not hasattr(s, "__iter__"):
            raise ArgumentTypeError(f"lights[{k}]: expected a light or a list of lights, got {s!r}")
        s = list(s)
        if not s:
            raise InvalidArgumentError(f"lights[{k}]: expected at least one light in each set")
        for j, x in enumerate(s):
            if not is_light(x):
                raise ArgumentTypeError(f"lights[{k}][{j}]: expected PointLight or DirectionalLight, "
                                        f"got {type(x).__name__}")
        sets.append(tuple(s))
    return tuple(sets)


@dataclass(frozen=True)
class SceneUse:
    """How a scene will use a BTF: camera(s), light set(s), image size, surface and uv scale.

    ``camera``: a :class:`~btfrs.Camera` or a list of them (a camera path: every frame counts);
    ``lights``: a light, a list of lights lit together, or a list of such sets (a light range or
    an animation: one set per frame); every camera is combined with every light set. ``size``:
    ``(height, width)`` or one int, as for :func:`btfrs.render`; ``scene``: the surface (default
    ``Scene.plane()``); ``uv_scale``: repetitions of the sample, as for :func:`btfrs.render`.
    """

    camera: Union[Camera, Sequence[Camera]]
    lights: Any
    size: Union[int, Tuple[int, int]] = (256, 256)
    scene: Optional[Scene] = None
    uv_scale: Union[float, Tuple[float, float]] = 1.0
    _cameras: Tuple[Camera, ...] = field(init=False, repr=False, compare=False)
    _sets: Tuple[Tuple[_Light, ...], ...] = field(init=False, repr=False, compare=False)
    _hw: Tuple[int, int] = field(init=False, repr=False, compare=False)
    _uvs: Tuple[float, float] = field(init=False, repr=False, compare=False)
    _scene: Scene = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        cams = self.camera
        if isinstance(cams, Camera):
            cams = [cams]
        elif isinstance(cams, (str, bytes)) or not hasattr(cams, "__iter__"):
            raise ArgumentTypeError(f"camera: expected a btfrs.Camera or a list of them, got {type(cams).__name__}")
        cams = list(cams)
        if not cams:
            raise InvalidArgumentError("camera: expected at least one camera")
        for k, c in enumerate(cams):
            instance(f"camera[{k}]", c, Camera, "a btfrs.Camera")
        scene = Scene.plane() if self.scene is None else instance("scene", self.scene, Scene, "a btfrs.Scene")
        # Frozen: the normalised forms are set once here, through object.__setattr__.
        object.__setattr__(self, "scene", scene)
        object.__setattr__(self, "_scene", scene)
        object.__setattr__(self, "_cameras", tuple(cams))
        object.__setattr__(self, "_sets", _light_sets(self.lights))
        object.__setattr__(self, "_hw", size_hw("size", self.size, max=16384))
        object.__setattr__(self, "_uvs", tuple(_uv_scale(self.uv_scale)))

    @property
    def cameras(self) -> Tuple[Camera, ...]:
        return self._cameras

    @property
    def light_sets(self) -> Tuple[Tuple[_Light, ...], ...]:
        return self._sets

    @property
    def frames(self) -> int:
        """Cameras x light sets."""
        return len(self._cameras) * len(self._sets)

    def directions(self, dims: Tuple[int, int]) -> Dict[str, Any]:
        """What the scene asks of a sample of ``dims`` = (height, width) texels, as flat arrays
        over every (frame, covered pixel, light): ``views [N, 3]``, ``lights [N, 3]`` (local
        tangent-frame directions), ``weights [N]`` (irradiance / frames; 0 for a light below the
        horizon, which the renderers skip), and per (frame, covered pixel) ``footprint [P]``
        (texels per pixel, NaN where unknown) with ``pixel_weights [P]`` and ``pixels``, the
        covered-pixel count of each camera."""
        h, w = self._hw
        views, lights, weights, foot, fw, pixels = [], [], [], [], [], []
        # All light sets at once per camera: a light's direction at a pixel does not depend on
        # the other lights, so one rasterisation per camera serves every set.
        flat = [light for s in self._sets for light in s]
        share = np.concatenate([np.full(len(s), 1.0 / self.frames) for s in self._sets])
        for cam in self._cameras:
            d = _native.scene_directions(self._scene, cam, [x._native() for x in flat], w, h, list(self._uvs),
                                         (int(dims[0]), int(dims[1])))
            n = len(d["pixels"])
            pixels.append(n)
            if n == 0:
                continue
            irr = d["irradiance"].astype(np.float64) * share[None, :]
            views.append(np.repeat(d["views"].astype(np.float64), len(flat), axis=0))
            lights.append(d["lights"].reshape(-1, 3).astype(np.float64))
            weights.append(irr.reshape(-1))
            foot.append(d["footprint"].astype(np.float64))
            fw.append(irr.sum(axis=1))
        if not views:
            z3 = np.zeros((0, 3))
            return dict(views=z3, lights=z3, weights=np.zeros(0), footprint=np.zeros(0), pixel_weights=np.zeros(0),
                        pixels=pixels)
        return dict(views=np.concatenate(views), lights=np.concatenate(lights), weights=np.concatenate(weights),
                    footprint=np.concatenate(foot), pixel_weights=np.concatenate(fw), pixels=pixels)


def interp_weights(dirs: np.ndarray, queries: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """Indices ``[N, 3]`` and weights ``[N, 3]`` of each query over its three angularly nearest
    ``dirs``: numpy mirror of ``btfrs_core::directions::interp_weights`` with k = 3 (weight
    ``1/d_i - 1/d_4``, normalised; a query within 1e-9 rad of a direction gets it alone), the
    weights the raw renderer and the per-view models blend with."""
    dirs = np.asarray(dirs, dtype=np.float64)
    q = np.asarray(queries, dtype=np.float64)
    n, m = len(q), len(dirs)
    k = min(3, m)
    idx = np.zeros((n, 3), dtype=np.intp)
    wts = np.zeros((n, 3))
    for a in range(0, n, 8192):  # chunks keep the [n, m] angle table small
        qa = q[a:a + 8192]
        # |q x d| by components (np.cross on broadcast arrays is several times slower).
        cx = qa[:, 1:2] * dirs[None, :, 2] - qa[:, 2:3] * dirs[None, :, 1]
        cy = qa[:, 2:3] * dirs[None, :, 0] - qa[:, 0:1] * dirs[None, :, 2]
        cz = qa[:, 0:1] * dirs[None, :, 1] - qa[:, 1:2] * dirs[None, :, 0]
        ang = np.arctan2(np.sqrt(cx * cx + cy * cy + cz * cz), qa @ dirs.T)
        # The k + 1 nearest, ordered by angle and then index (Rust's stable sort breaks ties by
        # index too); argpartition first, since a full sort of every row is the slow part.
        kk = min(k + 1, m)
        part = np.sort(np.argpartition(ang, kk - 1, axis=1)[:, :kk], axis=1) if kk < m else \
            np.broadcast_to(np.arange(m), (len(qa), m))
        pa = np.take_along_axis(ang, part, axis=1)
        o = np.argsort(pa, axis=1, kind="stable")
        order = np.take_along_axis(part, o, axis=1)
        d = np.take_along_axis(pa, o, axis=1)
        exact = d[:, 0] < 1e-9
        # Exact rows get their own weights below; 1 stands in for their zero distances here.
        d = np.where(exact[:, None], 1.0, d)
        cut = 1.0 / d[:, k] if m > k else np.zeros(len(qa))
        w = np.maximum(1.0 / d[:, :k] - cut[:, None], 0.0)
        tot = w.sum(axis=1)
        w = np.where(tot[:, None] > 0, w / np.where(tot > 0, tot, 1.0)[:, None], 1.0 / k)
        w[exact] = 0.0
        w[exact, 0] = 1.0
        idx[a:a + len(qa), :k] = order[:, :k]
        wts[a:a + len(qa), :k] = w
    return idx, wts


def _slot_weights(dirs: np.ndarray, queries: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Total weight each measured direction receives from the weighted queries."""
    # Directions repeat a lot (a directional light on a plane is one direction for every pixel):
    # interpolate each distinct direction once, rounded to 1e-5 (far below the 15-degree slot
    # spacing), found by one integer key per direction (np.unique over rows is ~10x slower).
    q = np.rint((np.asarray(queries, dtype=np.float64) + 1.0) * 1e5).astype(np.int64)
    key = (q[:, 0] * 200_001 + q[:, 1]) * 200_001 + q[:, 2]
    ukey, first, inv = np.unique(key, return_index=True, return_inverse=True)
    uw = np.bincount(inv.reshape(-1), weights=weights, minlength=len(ukey))
    idx, w = interp_weights(dirs, q[first] * 1e-5 - 1.0)
    return np.bincount(idx.reshape(-1), weights=(w * uw[:, None]).reshape(-1), minlength=len(dirs))


def _candidates(candidates: Optional[Sequence[Tuple[str, str, Dict[str, Any]]]]) -> List[Tuple[str, str, Dict[str, Any]]]:
    """The checked ``(kind, label, options)`` triples (default: :func:`default_candidates`)."""
    if candidates is None:
        return default_candidates()
    kinds = model_kinds()
    if isinstance(candidates, (str, bytes)) or not hasattr(candidates, "__iter__"):
        raise ArgumentTypeError(f"candidates: expected a list of (kind, label, options), got {candidates!r}")
    cands = []
    for k, c in enumerate(candidates):
        if not (isinstance(c, (tuple, list)) and len(c) == 3 and isinstance(c[1], str) and isinstance(c[2], dict)):
            raise ArgumentTypeError(f"candidates[{k}]: expected (kind, label, options dict), got {c!r}")
        cands.append((check_choice(f"candidates[{k}]", c[0], tuple(kinds) + ("raw",)), c[1], dict(c[2])))
    if not cands:
        raise InvalidArgumentError("candidates: expected at least one candidate")
    return cands


def _choose_heldout(btf: Btf, tol: float, bb: Optional[int], cands: List[Tuple[str, str, Dict[str, Any]]],
                    share: float, seed: int, progress: Progress) -> Choice:
    """:func:`choose` without a scene: each candidate fitted on the lights kept, scored on the
    lights held out (the module documentation says how)."""
    n = btf.n_lights
    held = int(round(share * n))
    if held < 1 or n - held < 2:
        raise InvalidArgumentError(f"holdout: {share:g} of {n} lights holds out {held}; expected at least one light "
                                   "held out and two kept")
    rng = np.random.default_rng(seed)
    test_l = np.sort(rng.choice(n, size=held, replace=False))
    train_l = np.setdiff1d(np.arange(n), test_l)
    train, test = btf.select(lights=train_l), btf.select(lights=test_l)
    pairs = [(v, l) for v in range(test.n_views) for l in range(test.n_lights)]
    truth = [np.asarray(test.data[:, :, v, l, :], dtype=np.float64) for v, l in pairs]
    energy = sum(float(np.sum(t * t)) for t in truth)

    def score(evaluate: Callable[[NDArray[Any], NDArray[Any]], Any]) -> float:
        err = 0.0
        for (v, l), t in zip(pairs, truth):
            d = np.asarray(evaluate(test.views[v], test.lights[l]), dtype=np.float64) - t
            err += float(np.sum(d * d))
        if not math.isfinite(err):
            return math.inf
        return math.sqrt(err / energy) if energy > 0 else (0.0 if err == 0 else math.inf)

    cb = callback(progress, f"choose ({len(cands)} candidates, {held} of {n} lights held out)")
    if cb is not None:
        cb(0, len(cands))
    rows: List[Dict[str, Any]] = []
    for j, (kind, label, options) in enumerate(cands):
        row: Dict[str, Any] = dict(label=label, kind=kind, options=options, subset="kept", views=train.n_views,
                                   lights=train.n_lights, error=None, nbytes=None, render_ms=math.nan, fit_s=None,
                                   status="", model=None)
        try:
            t0 = time.perf_counter()
            if kind == "raw":
                model: Any = train
                row["fit_s"] = time.perf_counter() - t0
                row["nbytes"] = int(train.data.nbytes)
                row["error"] = score(functools.partial(_raw_image, train))
            else:
                model = fit_model(kind, train, **options)
                row["fit_s"] = time.perf_counter() - t0
                row["nbytes"] = int(model.nbytes)
                row["error"] = score(model.evaluate)
            row["model"] = model
        except BtfrsError as e:
            row["status"] = f"failed: {type(e).__name__}: {str(e).splitlines()[0][:80]}"
        rows.append(row)
        if cb is not None:
            cb(j + 1, len(cands))
    fitted = [r for r in rows if r["model"] is not None]
    if not fitted:
        raise DegenerateDataError("candidates: no candidate could be fitted on the lights kept: "
                                  + "; ".join(f"{r['label']}: {r['status']}" for r in rows))
    within = [r for r in fitted if bb is None or r["nbytes"] <= bb]
    ok_rows = [r for r in within if r["error"] <= tol]
    met = bool(ok_rows)
    best = (min(ok_rows, key=lambda r: (r["nbytes"], r["error"])) if met
            else min(within or fitted, key=lambda r: (r["error"], r["nbytes"])))
    for r in fitted:
        r["status"] = ("over the byte budget " + str(bb) if bb is not None and r["nbytes"] > bb
                       else "meets the tolerance" if r["error"] <= tol else "error above tolerance")
        if not math.isfinite(r["error"]):
            r["status"] += "; non-finite values at the held-out lights"
    best["status"] += " (chosen)" if met else " (best available: tolerance not met)"
    rows.sort(key=lambda r: (1, 0, 0.0) if r["model"] is None else (0, r["nbytes"], r["error"]))
    return Choice(model=best["model"], kind=best["kind"], label=best["label"], options=best["options"],
                  subset="kept", error=float(best["error"]), nbytes=int(best["nbytes"]), render_ms=math.nan, met=met,
                  tolerance=tol, budget_bytes=bb, budget_ms=None,
                  candidates=[{k: v for k, v in r.items() if k != "model"} for r in rows],
                  views_used=np.arange(btf.n_views), lights_used=train_l, mip_level=0, samples=len(pairs),
                  n_views=btf.n_views, n_lights=btf.n_lights, lights_held=test_l)


def _raw_image(btf: Btf, view: np.ndarray, light: np.ndarray) -> np.ndarray:
    """The raw measured data interpolated at one (view, light), as the raw renderer does."""
    vi, vw = interp_weights(btf.views, view[None])
    li, lw = interp_weights(btf.lights, light[None])
    # The light blend divides the measured cosine out (btfrs_core::directions::cos_corrected).
    lw = lw * max(float(light[2]), 0.0) / np.maximum(btf.lights[li, 2], 0.02)
    out = np.zeros(btf.data.shape[:2] + (3,))
    for v, a in zip(vi[0], vw[0]):
        for l, b in zip(li[0], lw[0]):
            if a * b > 0:
                out += a * b * btf.data[:, :, v, l, :]
    return out


def _box(img: np.ndarray, level: int) -> np.ndarray:
    """Box-filter the texel axes by 2^level (the mip level a pixel footprint selects)."""
    if level <= 0:
        return img
    b = 1 << level
    h, w = (img.shape[0] // b) * b, (img.shape[1] // b) * b
    boxed: NDArray[Any] = img[:h, :w].reshape(h // b, b, w // b, b, 3).mean(axis=(1, 3))
    return boxed


@dataclass
class Choice:
    """What :func:`choose` decided: the chosen model and every candidate it weighed.

    ``model`` is a fitted :class:`~btfrs.Model` or, for kind ``"raw"``, the :class:`~btfrs.Btf` of
    the used slots (render it with :func:`btfrs.render` like any model). ``met`` is False when no
    candidate within the budgets met the tolerance (``model`` is then the most accurate one).
    ``candidates`` are dicts with ``label``, ``kind``, ``options``, ``subset``, ``views``,
    ``lights``, ``error``, ``nbytes``, ``render_ms``, ``fit_s`` and ``status``.
    """

    model: Any
    kind: str
    label: str
    options: Dict[str, Any]
    subset: str
    error: float
    nbytes: int
    render_ms: float
    met: bool
    tolerance: float
    budget_bytes: Optional[int]
    budget_ms: Optional[float]
    candidates: List[Dict[str, Any]]
    views_used: np.ndarray
    lights_used: np.ndarray
    mip_level: int
    samples: int
    n_views: int
    n_lights: int
    #: With ``scene=None``: the lights held out (``lights_used`` are those kept); None otherwise.
    lights_held: Optional[np.ndarray] = None

    def to_dict(self) -> Dict[str, Any]:
        """Everything but the model, as plain Python values (JSON-serialisable)."""
        return dict(kind=self.kind, label=self.label, options=dict(self.options), subset=self.subset,
                    error=self.error, nbytes=self.nbytes, render_ms=self.render_ms, met=self.met,
                    tolerance=self.tolerance, budget_bytes=self.budget_bytes, budget_ms=self.budget_ms,
                    views_used=[int(v) for v in self.views_used], lights_used=[int(v) for v in self.lights_used],
                    mip_level=self.mip_level, samples=self.samples,
                    lights_held=None if self.lights_held is None else [int(v) for v in self.lights_held],
                    candidates=[{k: v for k, v in c.items() if k != "model"} for c in self.candidates])

    def explain(self) -> str:
        """A readable account: what the scene uses, every candidate with its error and costs, and
        why the choice."""
        if self.lights_held is not None:
            head = (f"fitted on {len(self.lights_used)} of {self.n_lights} lights; error on the {len(self.lights_held)} "
                    f"held out ({self.samples} (view, light) pairs) against the measured images; "
                    f"tolerance {self.tolerance:g}")
        else:
            head = (f"scene uses {len(self.views_used)} of {self.n_views} views and {len(self.lights_used)} of "
                    f"{self.n_lights} lights; mip level {self.mip_level}; error on {self.samples} sampled "
                    f"(view, light) pairs against the raw data; tolerance {self.tolerance:g}")
        lines = [head
                 + (f", budget {self.budget_bytes} bytes" if self.budget_bytes is not None else "")
                 + (f", budget {self.budget_ms:g} ms" if self.budget_ms is not None else ""),
                 "",
                 f"  {'candidate':<24} {'fit on':<7} {'slots':>9} {'error':>8} {'bytes':>11} {'fit s':>7} {'render ms':>9}  status"]
        for c in self.candidates:
            chosen = "*" if c["label"] == self.label and c["subset"] == self.subset else " "
            err = "-" if c["error"] is None else f"{c['error']:.4f}"
            ms = "-" if c["render_ms"] is None or not math.isfinite(c["render_ms"]) else f"{c['render_ms']:.1f}"
            nb = "-" if c["nbytes"] is None else str(c["nbytes"])
            fs = "-" if c.get("fit_s") is None else f"{c['fit_s']:.1f}"
            lines.append(f"{chosen} {c['label']:<24} {c['subset']:<7} {c['views']:>4}x{c['lights']:<4} {err:>8} "
                         f"{nb:>11} {fs:>7} {ms:>9}  {c['status']}")
        lines.append("")
        ms = f"{self.render_ms:.1f} ms" if math.isfinite(self.render_ms) else "render time not measured"
        if self.lights_held is not None:
            fit = next((c["fit_s"] for c in self.candidates if c["label"] == self.label), None)
            took = "" if fit is None else f", fitted in {fit:.1f} s"
            if self.met:
                lines.append(f"chosen: {self.label} ({self.nbytes} bytes{took}): the smallest candidate whose held-out "
                             f"error {self.error:.4f} meets the tolerance {self.tolerance:g}")
            else:
                lines.append(f"NOT MET: no candidate within the budget meets the tolerance {self.tolerance:g}; returned "
                             f"the most accurate, {self.label} (held-out error {self.error:.4f}, {self.nbytes} bytes{took})")
        elif self.met:
            lines.append(f"chosen: {self.label} on the {self.subset} subset ({self.nbytes} bytes, {ms}): the cheapest "
                         f"candidate whose error {self.error:.4f} meets the tolerance {self.tolerance:g}")
        else:
            lines.append(f"NOT MET: no candidate within the budgets meets the tolerance {self.tolerance:g}; "
                         f"returned the most accurate available, {self.label} on the {self.subset} subset "
                         f"(error {self.error:.4f}, {self.nbytes} bytes, {ms})")
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.explain()


def default_candidates() -> List[Tuple[str, str, Dict[str, Any]]]:
    """``(kind, label, options)`` for every registered model at its registry examples, then the
    raw data of the used slots: the registry says which settings are worth trying, so a new
    model (``lafortune_view`` among them, once registered) takes part without an edit here."""
    out: List[Tuple[str, str, Dict[str, Any]]] = []
    for kind, info in model_kinds().items():
        for label, options in info.get("examples", []):
            out.append((kind, label, dict(options)))
    return out + [("raw", "raw data", {})]


def _render_ms(model: Any, use: SceneUse) -> float:
    """Draw milliseconds of the scene's first frame on the GPU path: a warm-up frame (upload and
    pipeline compilation), then the best of two."""
    def frame() -> None:
        render(model, use._scene, use.cameras[0], list(use.light_sets[0]), size=use._hw, uv_scale=list(use._uvs))

    frame()
    best = math.inf
    for _ in range(2):
        frame()
        t = last_timings()
        if t is not None:
            best = min(best, t.draw_ms)
    return best


def choose(btf: Btf, *, scene: Optional[SceneUse] = None, tolerance: float = 0.05,
           budget_bytes: Union[int, str, None] = None,
           budget_ms: Optional[float] = None, candidates: Optional[Sequence[Tuple[str, str, Dict[str, Any]]]] = None,
           subsets: Sequence[str] = SUBSETS, samples: int = 256, measure_render: bool = True, seed: int = 0,
           holdout: float = 0.2, progress: Progress = None) -> Choice:
    """The cheapest model, in bytes and then render ms, whose error on the scene's own direction
    distribution meets ``tolerance`` (see the module documentation for how).

    Parameters
    ----------
    btf: the measured sample (every pair present: the reference is its raw interpolation).
    scene: a :class:`SceneUse`; None scores each candidate on held-out lights instead (see
        ``holdout``; ``subsets``, ``samples``, ``budget_ms`` and ``measure_render`` do not apply).
    tolerance: the largest acceptable weighted relative error (> 0).
    budget_bytes, budget_ms: optional limits on ``nbytes`` (bytes, or a size such as ``"8MiB"``)
        and render ms; a candidate over one is not chosen (render ms are measured only when ``measure_render``).
    candidates: ``(kind, label, options)`` triples (``kind`` a registered model or ``"raw"``);
        default: :func:`default_candidates` (every registered model at its registry examples,
        plus ``"raw"``).
    subsets: which of ``"scene"`` (used views x used lights), ``"views"`` (used views x all
        lights) and ``"full"`` to fit on; a subset equal to a larger one is fitted once.
    samples: (view, light) pairs drawn from the scene's distribution for the score.
    measure_render: time the render of the scene (the GPU path; lavapipe without a GPU) for
        the candidates that can be chosen (error within the tolerance and bytes within the
        budget; when none is, the most accurate ones, until one is within the time budget);
        the others, and all without ``measure_render``, have ``render_ms`` NaN.
    seed: the seed of the direction sampling (with ``scene=None``: of the held-out lights).
    holdout: with ``scene=None``, the share of the lights held out, in (0, 1) (default 0.2: one
        in five, the RTI benchmarks' protocol).
    progress: None, True or a callable ``(done, total)`` over the candidates.
    """
    btf = instance("btf", btf, Btf, "a btfrs.Btf")
    if btf.mask is not None and not btf.mask.all():
        raise InvalidArgumentError("btf: choose scores against the raw data, which needs every (view, light) pair; "
                                   "this sample has a mask")
    tol = real("tolerance", tolerance, min=0.0, min_open=True)
    bb = memory_size("budget_bytes", budget_bytes)
    if scene is None:
        share = real("holdout", holdout, min=0.0, max=1.0, min_open=True, max_open=True)
        return _choose_heldout(btf, tol, bb, _candidates(candidates), share, check_seed(seed), progress)
    use = instance("scene", scene, SceneUse, "a btfrs.SceneUse")
    bm = None if budget_ms is None else real("budget_ms", budget_ms, min=0.0, min_open=True)
    n_samples = integer("samples", samples, min=1)
    rng = np.random.default_rng(check_seed(seed))
    if isinstance(subsets, str) or not hasattr(subsets, "__iter__"):
        raise ArgumentTypeError(f"subsets: expected a list of {', '.join(SUBSETS)}, got {subsets!r}")
    subs = [check_choice("subsets", s, SUBSETS) for s in subsets]
    if not subs:
        raise InvalidArgumentError("subsets: expected at least one of " + ", ".join(SUBSETS))
    if not isinstance(measure_render, (bool, np.bool_)):
        raise ArgumentTypeError(f"measure_render: expected True or False, got {measure_render!r}")
    cands = _candidates(candidates)

    # 1-2. What the scene asks, and which measured slots that touches.
    h, w = btf.shape[0], btf.shape[1]
    d = use.directions((h, w))
    live = d["weights"] > 0
    if not live.any():
        raise InvalidArgumentError("scene: no covered pixel is lit from above its surface (the camera sees nothing, "
                                   "or every light is below the horizon): there is nothing to choose for")
    qv, ql, qw = d["views"][live], d["lights"][live], d["weights"][live]
    views_used = np.flatnonzero(_slot_weights(btf.views, qv, qw) > 0)
    lights_used = np.flatnonzero(_slot_weights(btf.lights, ql, qw) > 0)
    fp, fw = d["footprint"], d["pixel_weights"]
    ok = np.isfinite(fp) & (fp > 0) & (fw > 0)
    if ok.any():
        lf = np.log2(fp[ok])
        order = np.argsort(lf)
        cum = np.cumsum(fw[ok][order])
        median = lf[order][np.searchsorted(cum, 0.5 * cum[-1])]
        mip = int(np.clip(math.floor(median), 0, int(math.log2(min(h, w)))))
    else:
        mip = 0

    # 4 (the reference half). Sampled pairs, weighted by how often they were drawn.
    draw = rng.choice(len(qw), size=n_samples, replace=True, p=qw / qw.sum())
    uniq, counts = np.unique(draw, return_counts=True)
    sv, sl, sw = qv[uniq], ql[uniq], counts.astype(np.float64)
    refs = [_box(_raw_image(btf, sv[k], sl[k]), mip) for k in range(len(uniq))]
    ref_energy = sum(sw[k] * float(np.sum(refs[k] ** 2)) for k in range(len(uniq)))

    def score(evaluate: Callable[[NDArray[Any], NDArray[Any]], Any]) -> float:
        err = 0.0
        for k in range(len(uniq)):
            pred = _box(np.asarray(evaluate(sv[k], sl[k]), dtype=np.float64), mip)
            err += sw[k] * float(np.sum((pred - refs[k]) ** 2))
        if not math.isfinite(err):
            return math.inf  # NaN would break the comparisons below; inf is "unusable"
        return math.sqrt(err / ref_energy) if ref_energy > 0 else (0.0 if err == 0 else math.inf)

    # 3. The subsets, each fitted once.
    all_v, all_l = np.arange(btf.n_views), np.arange(btf.n_lights)
    wanted = {"scene": (views_used, lights_used), "views": (views_used, all_l), "full": (all_v, all_l)}
    # A subset equal to a larger one carries the larger one's name (the scene using every view
    # and light is "full"), so a name always says what was fitted.
    subsets_fit: List[Tuple[str, NDArray[Any], NDArray[Any]]] = []
    for s in SUBSETS:
        if s not in subs:
            continue
        vv, ll = wanted[s]
        name = next(t for t in reversed(SUBSETS)
                    if np.array_equal(vv, wanted[t][0]) and np.array_equal(ll, wanted[t][1]))
        if all(name != n for n, _, _ in subsets_fit):
            subsets_fit.append((name, vv, ll))

    # The raw data of the full set is the reference itself (error 0 by construction): keeping
    # everything is not a choice this function makes; the raw data of the used slots is.
    jobs = [(c, s) for c in cands for s in subsets_fit if not (c[0] == "raw" and s[0] == "full")]
    if not jobs:
        raise InvalidArgumentError("candidates: only \"raw\" on the full set, which is the reference itself; "
                                   "add a model or a subset other than \"full\"")
    cb = callback(progress, f"choose ({len(jobs)} candidates)")
    if cb is not None:
        cb(0, len(jobs))
    rows: List[Dict[str, Any]] = []
    for j, ((kind, label, options), (sname, vv, ll)) in enumerate(jobs):
        row: Dict[str, Any] = dict(label=label, kind=kind, options=options, subset=sname, views=len(vv), lights=len(ll),
                         error=None, nbytes=None, render_ms=None, fit_s=None, status="", model=None)
        try:
            part = btf if sname == "full" else btf.select(views=vv, lights=ll)
            t0 = time.perf_counter()
            if kind == "raw":
                model: Any = part
                row["nbytes"] = int(part.data.nbytes)
                row["fit_s"] = time.perf_counter() - t0
                row["error"] = score(functools.partial(_raw_image, part))
            else:
                model = fit_model(kind, part, **options)
                row["nbytes"] = int(model.nbytes)
                row["fit_s"] = time.perf_counter() - t0
                row["error"] = score(model.evaluate)
            row["model"] = model
        except BtfrsError as e:
            # A model that cannot fit this subset (too few lights for a PTM, ...) is a candidate
            # that failed, not a failure of the choice.
            row["status"] = f"failed: {type(e).__name__}: {str(e).splitlines()[0][:80]}"
        row["render_ms"] = math.nan
        rows.append(row)
        if cb is not None:
            cb(j + 1, len(jobs))

    fitted = [r for r in rows if r["model"] is not None]
    if not fitted:
        raise DegenerateDataError("candidates: no candidate could be fitted and scored on this scene's subsets: "
                                  + "; ".join(f"{r['label']} ({r['subset']}): {r['status']}" for r in rows))

    def timed(r: Dict[str, Any]) -> float:
        # Renders are timed only for candidates that can be chosen: on lavapipe a frame of a
        # slow model costs seconds, and a candidate that misses the tolerance or the byte
        # budget is out whatever its speed.
        if measure_render and not math.isfinite(r["render_ms"]) and "render_note" not in r:
            try:
                r["render_ms"] = _render_ms(r["model"], use)
            except BtfrsError as e:
                # No adapter (or a device error): the choice still stands on bytes and error.
                r["render_note"] = f"render not timed: {type(e).__name__}: {str(e).splitlines()[0][:60]}"
        return float(r["render_ms"])

    def over_time(r: Dict[str, Any]) -> bool:
        return bm is not None and math.isfinite(r["render_ms"]) and r["render_ms"] > bm

    for r in fitted:
        r["meets"] = r["error"] <= tol
        r["bytes_ok"] = bb is None or r["nbytes"] <= bb
        if r["meets"] and r["bytes_ok"]:
            timed(r)

    def cost(r: Dict[str, Any]) -> Tuple[int, float, float]:
        ms = r["render_ms"]
        return (r["nbytes"], ms if ms is not None and math.isfinite(ms) else math.inf, r["error"])

    best: Optional[Dict[str, Any]]
    ok_rows = [r for r in fitted if r["meets"] and r["bytes_ok"] and not over_time(r)]
    met = bool(ok_rows)
    if met:
        best = min(ok_rows, key=cost)
    else:
        # The most accurate candidate within the budgets; its render time is measured on the way.
        best = None
        for r in sorted((r for r in fitted if r["bytes_ok"]), key=lambda r: (r["error"], cost(r))):
            timed(r)
            if not over_time(r):
                best = r
                break
        if best is None:
            best = min(fitted, key=lambda r: (r["error"], cost(r)))
    assert best is not None
    for r in fitted:
        over = []
        if not r.pop("bytes_ok"):
            over.append(f"over the byte budget {bb}")
        if over_time(r):
            over.append(f"over the time budget {bm:g} ms")
        meets = r.pop("meets")
        r["status"] = "; ".join(over) if over else ("meets the tolerance" if meets else "error above tolerance")
        if not math.isfinite(r["error"]):
            # Seen with Lafortune lobes queried beyond the measured 75 degrees (a sphere's
            # grazing views): say so rather than show a bare "inf".
            r["status"] += "; non-finite values at the scene's directions"
        if "render_note" in r:
            r["status"] += "; " + r.pop("render_note")
    best["status"] += " (chosen)" if met else " (best available: tolerance not met)"
    # Failed candidates last (in their order), the rest by cost.
    rows.sort(key=lambda r: (1, 0, 0.0, 0.0) if r["model"] is None else (0,) + cost(r))
    return Choice(model=best["model"], kind=best["kind"], label=best["label"], options=best["options"],
                  subset=best["subset"], error=float(best["error"]), nbytes=int(best["nbytes"]),
                  render_ms=float(best["render_ms"]), met=met, tolerance=tol, budget_bytes=bb, budget_ms=bm,
                  candidates=[{k: v for k, v in r.items() if k != "model"} for r in rows],
                  views_used=views_used, lights_used=lights_used, mip_level=mip, samples=n_samples,
                  n_views=btf.n_views, n_lights=btf.n_lights)
