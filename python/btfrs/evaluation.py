"""Speed against accuracy: ``btfrs.evaluate(btf, ...)`` charts every model against the others.

The users' question is "which representation, at what size and cost, for *this* material". For
every registered model and the sweep of its parameters its registry entry names (:func:`sweeps`),
and for the plain numpy / scipy / scikit-learn ways
and the raw measured data, one row of:

* ``fit_s``: wall seconds of the fit (on the train half of the pairs protocol);
* ``bytes``: the model as stored for rendering (``Model.nbytes``: what the GPU path uploads; for
  a baseline, its coefficients as float32; for raw interpolation, the float32 data);
* ``render_ms``: draw milliseconds of a 512² frame of :func:`reference_scene` on this process's
  adapter (lavapipe without a GPU; the first, pipeline-compiling frame is not counted);
* ``reconstruction``: relative error ``||pred - gt|| / ||gt||`` on the pairs the fit saw;
* ``heldout_pairs``: on random held-out (view, light) pairs (:meth:`btfrs.Btf.split`);
* ``heldout_directions``: with **whole directions** held out (:func:`split_directions`: every
  pair of some views and of some lights is removed, so the model is asked *between* its measured
  directions, as a renderer asks it);
* ``psnr_scene``: PSNR (dB) of the model's render of the reference scene against the render of
  the raw measured BTF (all pairs) of the same scene, over the pixels the surface covers.

:class:`EvaluationReport` holds the rows, prints them as markdown, finds Pareto fronts and draws
the charts (matplotlib): held-out error against bytes, render ms and fit seconds, log axes, the
front drawn, every point labelled.
"""

from __future__ import annotations

import json
import math
import os
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np
from numpy.typing import NDArray

from . import fit as fit_mod
from . import io, rendering
from ._checks import boolean, choice, instance, integer, real, size_hw
from ._checks import seed as check_seed
from ._progress import Progress, callback
from .btf import Btf
from .exceptions import ArgumentTypeError, BtfrsError, InvalidArgumentError
from .models import Model, model_kinds
from .rendering import Camera, PointLight, Scene

__all__ = ["evaluate", "EvaluationReport", "split_directions", "sweeps", "METRICS", "reference_scene",
           "pareto_front"]

#: A row of a report: the keys of :data:`METRICS` plus ``label``, ``kind``, ``options``, ``way``, ``note``...
_Row = Dict[str, Any]
#: The reference scene: (scene, camera, lights, uv_scale).
_SceneSpec = Tuple[Scene, Camera, List[PointLight], float]

def sweeps(sweep: str = "full") -> Dict[str, List[Tuple[str, Dict[str, Any]]]]:
    """The settings :func:`evaluate` fits per model kind: ``{kind: [(label, options), ...]}``,
    each model's registry sweep (``sweep="quick"``: the settings it marks quick, what the demo
    and the tests run)."""
    choice("sweep", sweep, ("full", "quick"))
    return {kind: [(label, dict(opts)) for label, opts, quick, _ in info["sweep"] if sweep == "full" or quick]
            for kind, info in model_kinds().items()}


#: The numbers of a row, and whether smaller is better (``psnr_scene`` is the one that is not).
METRICS = {"fit_s": True, "bytes": True, "render_ms": True, "reconstruction": True, "heldout_pairs": True,
           "heldout_directions": True, "heldout": True, "psnr_scene": False}

_BASELINES = ("numpy", "scipy", "sklearn", "raw")


def reference_scene() -> _SceneSpec:
    """The scene of the ``render_ms`` and ``psnr_scene`` columns: a unit sphere seen from
    ``(0, -3, 2)`` with a 40-degree field of view under one point light at ``(2, -2, 3)``
    (intensity 8), the sample repeated 4 times over the UV square (as ``python -m btfrs.bench``
    renders it)."""
    return (Scene.sphere(), Camera.look_at([0, -3, 2], [0, 0, 0], 40), [PointLight([2.0, -2.0, 3.0], 8.0)], 4.0)


def split_directions(btf: Btf, fraction: float = 0.1, *, seed: int = 0) -> tuple[Btf, Btf]:
    """The whole-directions held-out protocol: ``round(fraction * V)`` views and
    ``round(fraction * L)`` lights (at least one each, at most all but one; drawn with ``seed``)
    are removed. ``train`` holds the remaining directions only (a copy, complete where ``btf`` is);
    ``test`` is ``btf`` with every present pair that has a held-out view *or* a held-out light."""
    instance("btf", btf, Btf, "a btfrs.Btf")
    f = real("fraction", fraction, min=0.0, max=1.0, min_open=True, max_open=True)
    rng = np.random.default_rng(check_seed(seed))
    nv, nl = btf.n_views, btf.n_lights
    if nv < 2 or nl < 2:
        raise InvalidArgumentError(f"btf: holding out whole directions needs at least 2 views and 2 lights, "
                                   f"got {nv} x {nl}")
    hv = np.sort(rng.choice(nv, size=min(max(1, round(f * nv)), nv - 1), replace=False))
    hl = np.sort(rng.choice(nl, size=min(max(1, round(f * nl)), nl - 1), replace=False))
    keep_v = np.setdiff1d(np.arange(nv), hv)
    keep_l = np.setdiff1d(np.arange(nl), hl)
    present = np.ones((nv, nl), bool) if btf.mask is None else btf.mask
    out = np.zeros((nv, nl), bool)
    out[hv, :] = True
    out[:, hl] = True
    test_mask = out & present
    train = btf.select(views=keep_v, lights=keep_l)
    if train.mask is not None and not train.mask.any(axis=1).all():
        raise InvalidArgumentError("btf: a kept view has no present light after holding out directions; "
                                   "use a smaller fraction")
    return train, Btf(btf.data, btf.views, btf.lights, test_mask, check=False, meta=btf.meta)


def pareto_front(rows: Sequence[_Row], y: str = "heldout", x: str = "bytes") -> List[_Row]:
    """The rows not dominated in (``x``, ``y``): no other row is at least as good in both and
    better in one (smaller is better, except ``psnr_scene``). Rows missing either number are left
    out. Sorted by ``x``."""
    for m in (x, y):
        if m not in METRICS:
            raise InvalidArgumentError(f"metric: expected one of {', '.join(METRICS)}, got {m!r}")
    sx = 1.0 if METRICS[x] else -1.0
    sy = 1.0 if METRICS[y] else -1.0
    pts = [r for r in rows if _num(r.get(x)) is not None and _num(r.get(y)) is not None]
    front = []
    for r in pts:
        a, b = sx * r[x], sy * r[y]
        dominated = any((sx * o[x] <= a and sy * o[y] <= b) and (sx * o[x] < a or sy * o[y] < b) for o in pts)
        if not dominated:
            front.append(r)
    return sorted(front, key=lambda r: sx * r[x])


def _num(v: Any) -> Optional[float]:
    if v is None:
        return None
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


@dataclass
class EvaluationReport:
    """What :func:`evaluate` measured: ``rows`` (one dict per model and parameters, the keys of
    :data:`METRICS` plus ``label``, ``kind``, ``options``, ``way``, ``note``), and how
    (``info``: material shape, protocols, seed, adapter, seconds)."""
    rows: List[_Row]
    info: Dict[str, Any] = field(default_factory=dict)

    @property
    def primary(self) -> str:
        """The held-out column that ``"heldout"`` means: the first protocol asked for."""
        return "heldout_directions" if self.info.get("holdout") == "directions" else "heldout_pairs"

    def pareto(self, y: str = "heldout", x: str = "bytes") -> List[_Row]:
        """The rows on the Pareto front of (``x``, ``y``) (see :func:`pareto_front`)."""
        return pareto_front(self.rows, y, x)

    def table(self) -> str:
        """The rows as a markdown table (errors in %, bytes in KiB, a ``*`` on the rows of the
        held-out-against-bytes front)."""
        front = {id(r) for r in self.pareto("heldout", "bytes")}
        head = ["model", "way", "fit s", "KiB", "render ms", "recon. %", "held-out pairs %", "held-out dirs %",
                "scene PSNR dB", "note"]
        out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]

        def f(v: Any, fmt: str, scale: float = 1.0) -> str:
            v = _num(v)
            return "" if v is None else format(v * scale, fmt)

        for r in self.rows:
            out.append("| " + " | ".join([
                r["label"] + (" *" if id(r) in front else ""), r["way"], f(r.get("fit_s"), ".3g"),
                f(r.get("bytes"), ".1f", 1 / 1024), f(r.get("render_ms"), ".1f"),
                f(r.get("reconstruction"), ".2f", 100), f(r.get("heldout_pairs"), ".2f", 100),
                f(r.get("heldout_directions"), ".2f", 100), f(r.get("psnr_scene"), ".1f"), r.get("note", "")]) + " |")
        return "\n".join(out)

    def to_dict(self) -> Dict[str, Any]:
        return {"info": self.info, "rows": [_jsonable(r) for r in self.rows]}

    def chart(self, x: str, path: Union[str, "os.PathLike[str]"]) -> None:
        """One PNG: held-out error (each protocol measured: one panel each) against ``x``."""
        chart(self, x, path)

    def save(self, out: Union[str, "os.PathLike[str]"]) -> List[str]:
        """Write ``report.json``, ``report.md`` and the three charts
        (``heldout_vs_bytes.png``, ``heldout_vs_render_ms.png``, ``heldout_vs_fit_s.png``) into
        the folder ``out`` (made if missing), each atomically. Returns the paths written."""
        os.makedirs(out, exist_ok=True)
        paths = []
        p = os.path.join(out, "report.json")
        io.save_text(p, json.dumps(self.to_dict(), indent=2))
        paths.append(p)
        p = os.path.join(out, "report.md")
        io.save_text(p, self.summary() + "\n\n" + self.table() + "\n")
        paths.append(p)
        for x in ("bytes", "render_ms", "fit_s"):
            p = os.path.join(out, f"heldout_vs_{x}.png")
            self.chart(x, p)
            paths.append(p)
        return paths

    def summary(self) -> str:
        i = self.info
        lines = [f"# Speed against accuracy: {i.get('material', 'btf')} {i.get('shape')}",
                 f"held-out: {i.get('holdout')} (fraction {i.get('fraction')}, seed {i.get('seed')}); "
                 f"render: {i.get('adapter')}; {i.get('seconds', 0):.1f} s in all"]
        for note in i.get("notes", []):
            lines.append(f"- {note}")
        front = self.pareto("heldout", "bytes")
        if front:
            lines.append("front (held-out vs bytes): " + ", ".join(r["label"] for r in front))
        return "\n".join(lines)


def _jsonable(v: Any) -> Any:
    if isinstance(v, dict):
        return {str(k): _jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    if isinstance(v, (np.floating, float)):
        f = float(v)
        return f if math.isfinite(f) else None
    if isinstance(v, np.integer):
        return int(v)
    if isinstance(v, np.bool_):
        return bool(v)
    return v


_AXIS = {"bytes": "bytes as stored for rendering", "render_ms": "render ms per 512² frame",
         "fit_s": "fit seconds", "heldout_pairs": "held-out relative error (random pairs)",
         "heldout_directions": "held-out relative error (whole directions)"}


def chart(report: EvaluationReport, x: str, path: Union[str, "os.PathLike[str]"]) -> None:
    """Draw held-out error against ``x`` (log-log), one panel per held-out protocol measured.

    Each model kind has its colour (baselines: squares with a black edge); every point carries
    its number, and the key on the right gives the number's model, way and both held-out errors
    (labels written beside the points would overlap where points crowd). A point far above the
    others (more than 4x the upper quartile: e.g. plain least squares after quantization) is
    drawn as a triangle at the top edge and its value given in the key, so that it does not
    flatten the rest. The Pareto front is the dashed staircase. Written atomically as PNG.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt


    ys = [y for y in ("heldout_pairs", "heldout_directions") if any(_num(r.get(y)) is not None for r in report.rows)]
    if not ys:
        raise InvalidArgumentError("report: no row has a held-out error to chart")
    kinds = list(dict.fromkeys(r["kind"] for r in report.rows))
    # One colour per kind: tab10 while there are at most 10 kinds, tab20 beyond (with the
    # registry's 11 kinds, tab10 gave the 11th the first one's colour).
    cmap = plt.get_cmap("tab10" if len(kinds) <= 10 else "tab20")
    colour = {k: cmap(i % cmap.N) for i, k in enumerate(kinds)}
    number = {id(r): i + 1 for i, r in enumerate(report.rows)}
    fig = plt.figure(figsize=(6.2 * len(ys) + 4.6, 6.4))
    grid = fig.add_gridspec(1, len(ys) + 1, width_ratios=[6.2] * len(ys) + [4.6])
    off_scale: Dict[int, List[str]] = {}
    for j, y in enumerate(ys):
        ax = fig.add_subplot(grid[0, j])
        pts = [r for r in report.rows if _num(r.get(x)) is not None and _num(r.get(y)) is not None
               and r[x] > 0 and r[y] > 0]
        vals = np.array([r[y] for r in pts]) if pts else np.array([1.0])
        cap = 4.0 * float(np.percentile(vals, 75))
        top = min(float(vals.max()), cap) * 1.5
        seen = set()
        for r in pts:
            base = r["way"] != "btfrs"
            entry = (r["kind"], base)
            name = (f"{r['kind']} ({r['way'].split(' ')[0]})" if base else r["kind"])
            above = r[y] > cap
            yy = top / 1.25 if above else r[y]
            if above:
                off_scale.setdefault(id(r), []).append(y)
            ax.scatter(r[x], yy, s=50, marker="^" if above else ("s" if base else "o"), color=colour[r["kind"]],
                       edgecolors="black" if base else "none", linewidths=0.8, zorder=3,
                       label=None if entry in seen else name)
            seen.add(entry)
            ax.annotate(str(number[id(r)]), (r[x], yy), xytext=(4, 2), textcoords="offset points", fontsize=7.5,
                        zorder=4)
        front = pareto_front(pts, y, x)
        if front:
            fx, fy = [], []
            for i, r in enumerate(front):
                if i:
                    fx.append(r[x])
                    fy.append(min(front[i - 1][y], top / 1.25))
                fx.append(r[x])
                fy.append(min(r[y], top / 1.25))
            ax.plot(fx, fy, "--", color="0.35", lw=1.2, zorder=2, label="Pareto front")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_ylim(top=top)
        rs = report.info.get("render_size")
        ax.set_xlabel(f"render ms per {rs[0]}x{rs[1]} frame" if x == "render_ms" and rs else _AXIS.get(x, x))
        ax.set_ylabel(_AXIS[y])
        ax.grid(True, which="both", alpha=0.25)
        info = report.info
        ax.set_title(f"{info.get('material', 'btf')} {info.get('shape', '')}: {_AXIS[y].split('(')[1][:-1]} held out",
                     fontsize=10)
        handles, names = ax.get_legend_handles_labels()
    key = fig.add_subplot(grid[0, len(ys)])
    # The marker legend sits under the key, off the panels, where it can hide no point.
    key.legend(handles, names, fontsize=7, loc="lower left", ncol=2, framealpha=0.85)
    key.axis("off")
    lines = []
    for r in report.rows:
        errs = " / ".join("-" if _num(r.get(y)) is None else f"{100 * r[y]:.3g}%" for y in ys)
        tag = "" if r["way"] == "btfrs" else f" [{r['way'].split(' (')[0]}]"
        mark = " (off scale)" if id(r) in off_scale else ""
        lines.append((f"{number[id(r)]:>2}  {r['label']}{tag}: {errs}{mark}", colour[r["kind"]]))
    key.text(0.0, 1.0, "held-out error " + " / ".join(_AXIS[y].split("(")[1][:-1] for y in ys),
             fontsize=8, weight="bold", va="top", family="monospace", transform=key.transAxes)
    step = min(0.034, 0.72 / max(len(lines), 1))
    for n, (text, c) in enumerate(lines):
        key.text(0.0, 0.96 - n * step, text, fontsize=7, va="top", family="monospace", color=c,
                 transform=key.transAxes)
    fig.tight_layout()
    with io.atomic_write(path, "wb") as f:
        fig.savefig(f, format="png", dpi=110)
    plt.close(fig)


# --- evaluation ------------------------------------------------------------------------------

def _settings(models: Union[str, Sequence[Any]], sweep: str) -> List[Tuple[str, str, Dict[str, Any]]]:
    """``(label, kind, options)`` for ``models``: "all", a kind, a list of kinds, or of
    ``(label, kind, options)`` triples."""
    kinds = model_kinds()
    table = sweeps(sweep)
    if isinstance(models, str):
        models = list(kinds) if models == "all" else [models]
    if not isinstance(models, (list, tuple)) or not models:
        raise InvalidArgumentError(f"models: expected \"all\", a model name or a non-empty list of them, got {models!r}")
    out = []
    for m in models:
        if isinstance(m, (tuple, list)) and len(m) == 3:
            label, kind, opts = m
            choice("models", kind, tuple(kinds))
            out.append((str(label), kind, dict(opts)))
            continue
        kind = choice("models", m, tuple(kinds))
        out += [(label, kind, dict(opts)) for label, opts in table[kind]]
    return out


def _psnr(img: NDArray[np.float32], ref: NDArray[np.float32]) -> float:
    """PSNR over the pixels either image covers, the peak being the reference's largest value."""
    cover = (ref.max(axis=2) > 0) | (img.max(axis=2) > 0)
    if not cover.any():
        return float("nan")
    d = (img[cover].astype(np.float64) - ref[cover]) ** 2
    mse = float(d.mean())
    peak = float(ref[cover].max())
    if not math.isfinite(mse) or peak <= 0:
        return float("-inf")  # a render with Inf/NaN pixels: flagged in the row's note
    return float("inf") if mse == 0 else 10.0 * math.log10(peak * peak / mse)


def _timed_render(model: Union[Model, Btf], scene: _SceneSpec, size: Tuple[int, int]) -> Tuple[float, NDArray[np.float32]]:
    sc, cam, lights, uvs = scene
    # The first frame uploads the model and compiles its pipeline: not counted. One timed frame
    # after it (the slowest shaders take seconds per frame on lavapipe; repeats would dominate).
    rendering.render(model, sc, cam, lights, size=size, uv_scale=uvs)
    img = rendering.render(model, sc, cam, lights, size=size, uv_scale=uvs)
    timings = rendering.last_timings()
    assert timings is not None  # set by every GPU render
    return timings.draw_ms, img


def evaluate(btf: Btf, models: Union[str, Sequence[Any]] = "all", *, holdout: str = "both", fraction: float = 0.1,
             sweep: str = "full", baselines: Optional[Callable[..., List[_Row]]] = None, render: bool = True,
             render_size: Union[int, Tuple[int, int]] = 512, baseline_texels: int = 16, seed: int = 0,
             material: Optional[str] = None, progress: Progress = None) -> EvaluationReport:
    """Fit every model of ``models`` at every point of its sweep and measure speed against
    accuracy (the columns are described in :mod:`btfrs.evaluation`).

    Parameters
    ----------
    btf: the measured sample (complete or masked).
    models: ``"all"`` (every registered model), a model name, or a list of names and/or
        ``(label, kind, options)`` triples.
    holdout: ``"pairs"`` (random (view, light) pairs), ``"directions"`` (whole views and lights,
        :func:`split_directions`) or ``"both"``; ``"heldout"`` in :meth:`EvaluationReport.pareto`
        means the first of them.
    fraction: the share held out (of the pairs; of the views and of the lights).
    sweep: ``"full"`` or ``"quick"`` (:func:`sweeps`: each model's registry sweep).
    baselines: rows of other ways to do the same, on the same splits: a function
        ``(btf, splits, protocols, fit_split, texels, seed, notes) -> rows``, such as
        ``btfrs.tools.baselines.evaluation_rows`` (the numpy / scipy / scikit-learn ways and raw
        interpolation, which ``btfrs evaluate`` adds unless ``--no-baselines``); ``None``: none.
        ``baseline_texels`` bounds the texels a slow baseline fits (its time is per texel, times
        the texels; the table says so).
    render: measure ``render_ms`` and ``psnr_scene`` (:func:`reference_scene` at ``render_size``).
    seed: every random choice (the splits, LPCA's k-means, the scikit-learn baseline).
    material: a name for the report and the charts.
    progress: None, True or a callable ``(done, total)`` over the points.
    """
    b = instance("btf", btf, Btf, "a btfrs.Btf")
    holdout = choice("holdout", holdout, ("pairs", "directions", "both"))
    fraction = real("fraction", fraction, min=0.0, max=1.0, min_open=True, max_open=True)
    sweep = choice("sweep", sweep, ("full", "quick"))
    if baselines is not None and not callable(baselines):
        raise ArgumentTypeError("baselines: expected a function making baseline rows "
                                f"(btfrs.tools.baselines.evaluation_rows) or None, got {baselines!r}")
    use_baselines = baselines is not None
    render = boolean("render", render)
    baseline_texels = integer("baseline_texels", baseline_texels, min=1)
    seed = check_seed(seed)
    settings = _settings(models, sweep)
    t_start = time.perf_counter()
    protocols = ["pairs", "directions"] if holdout == "both" else [holdout]
    splits: Dict[str, Tuple[Btf, Btf]] = {}
    if "pairs" in protocols:
        splits["pairs"] = b.split(holdout=fraction, seed=seed)
    if "directions" in protocols:
        splits["directions"] = split_directions(b, fraction, seed=seed)
    fit_split = splits["pairs" if "pairs" in splits else "directions"]
    scene = reference_scene() if render else None

    size = size_hw("render_size", render_size, max=4096)
    ref_img = None
    adapter = None
    if render:
        full = b if b.mask is None or b.mask.all() else None
        adapter = rendering.gpu_info()
        if full is not None:
            assert scene is not None
            raw_ms, ref_img = _timed_render(full, scene, size)
    n_base = 5 if use_baselines else 0
    total = len(settings) + n_base
    cb = callback(progress, "evaluate")
    done = 0
    if cb is not None:
        cb(0, total)
    rows: List[_Row] = []
    notes: List[str] = []
    for label, kind, opts in settings:
        row: _Row = dict(label=label, kind=kind, options=opts, way="btfrs", note="")
        try:
            tr, te = fit_split
            t0 = time.perf_counter()
            m = fit_mod.fit(kind, tr, **opts)
            row["fit_s"] = time.perf_counter() - t0
            row["bytes"] = m.nbytes
            row["reconstruction"] = m.error(tr).relative
            for p in protocols:
                ptr, pte = splits[p]
                mm = m if (ptr is tr) else fit_mod.fit(kind, ptr, **opts)
                row[f"heldout_{p}"] = mm.error(pte).relative
            rep = m.report or {}
            row["note"] = _report_note(rep)
            note = next((n for lab, _, _, n in model_kinds()[kind]["sweep"] if lab == label and n), None)
            if note:
                row["note"] = note
            row["report"] = rep
            if render:
                assert scene is not None
                ms, img = _timed_render(m, scene, size)
                row["render_ms"] = ms
                row["finite_render"] = bool(np.isfinite(img).all())
                if not row["finite_render"]:
                    n_bad = int((~np.isfinite(img)).any(axis=2).sum())
                    row["note"] = (row["note"] + f"; {n_bad} non-finite pixels in the scene render").lstrip("; ")
                if ref_img is not None:
                    row["psnr_scene"] = _psnr(img, ref_img)
        except BtfrsError as e:
            row["error"] = f"{type(e).__name__}: {e}"
            row["note"] = f"failed: {type(e).__name__}"
        rows.append(row)
        done += 1
        if cb is not None:
            cb(done, total)
    if use_baselines:
        assert baselines is not None
        for row in baselines(b, splits, protocols, fit_split, baseline_texels, seed, notes):
            if render and row["kind"] == "raw":
                if ref_img is not None:
                    row["render_ms"] = raw_ms
                    row["note"] = (row.get("note", "") + "; scene render = the reference").lstrip("; ")
            rows.append(row)
            done += 1
            if cb is not None:
                cb(done, total)
    for r in rows:
        r["heldout"] = r.get("heldout_directions" if holdout == "directions" else "heldout_pairs")
        bad = [k for k in METRICS if r.get(k) is not None and isinstance(r.get(k), float) and math.isnan(r[k])]
        if bad:
            r["note"] = (r.get("note", "") + f"; NaN in {', '.join(bad)}").lstrip("; ")
    if render and ref_img is None:
        notes.append("the sample has a mask, so there is no raw render of the scene: psnr_scene left out")
    info = dict(material=material or "btf", shape=list(b.shape), holdout=holdout, fraction=fraction, seed=seed,
                sweep=sweep, adapter=adapter, render_size=list(size), seconds=time.perf_counter() - t_start,
                notes=notes)
    return EvaluationReport(rows, info)


def _report_note(rep: Dict[str, Any]) -> str:
    if "converged" in rep:
        s = f"{rep['converged']}/{rep['fell_back']}/{rep['failed']} converged/fell back/failed"
        if rep.get("extrapolated"):
            s += f", {rep['extrapolated']} extrapolated"
        return s
    if "phong_relative" in rep:
        return f"Phong alone {100 * rep['phong_relative']:.1f}% (train)"
    if rep.get("degenerate_slots"):
        return f"{len(rep['degenerate_slots'])} degenerate slots fell back"
    return ""


