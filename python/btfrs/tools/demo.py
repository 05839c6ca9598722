"""``btfrs demo``: the main job on a built-in material, written to a folder.

The demo is a list of steps (:data:`STEPS`) run in order over one :class:`Context`; each step
adds models, table rows, images or notes. Later features (more models, renders, synthesis,
charts) add steps here rather than growing one long function. Every file goes through an atomic
writer (:mod:`btfrs.io`), so an interrupted demo leaves no half-written file.

Two runs: the default shows every family in a few minutes (one setting of every registered
model, the registry's quick choice; compare, render, environment, synthesis, one Wang tile
set; the speed-against-accuracy chart from the demo's own fits); ``full=True`` (``btfrs demo
--full``) fits every example of every model, makes a second tile set to swap in, and runs
:func:`btfrs.evaluate` over every model's quick sweep with both held-out protocols and the
numpy / scipy / scikit-learn ways. The demo asks the registry for its models and names none.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Dict, List, Optional, Tuple, Union

import numpy as np
from numpy.typing import NDArray

from .. import __version__, _native, fit, io, materials, rendering, synth, tiles
from . import baselines
from ..btf import Btf
from ..directions import from_theta_phi
from ..environment import Environment
from ..evaluation import EvaluationReport, evaluate
from ..models import model_kinds

__all__ = ["Context", "STEPS", "run"]


@dataclass
class Context:
    out: Path
    material: str
    size: int
    seed: int
    progress: bool
    log: Callable[[str], None]
    # Every example of every model, a second tile set and the full evaluation (btfrs demo --full).
    full: bool = False
    # The sample and its halves: made by step_material, the first step.
    btf: Btf = field(init=False, repr=False)
    train: Btf = field(init=False, repr=False)
    test: Btf = field(init=False, repr=False)
    models: Dict[str, Any] = field(default_factory=dict)
    # The frame time of each model's sphere render (the quick chart's render ms).
    draw_ms: Dict[str, float] = field(default_factory=dict)
    rows: List[Dict[str, Any]] = field(default_factory=list)
    images: List[Tuple[str, str]] = field(default_factory=list)
    notes: List[str] = field(default_factory=list)
    gen_seconds: float = 0.0
    started: float = field(default_factory=time.perf_counter)


def _tile(images: List[NDArray[Any]], scale: int = 4, gap: int = 4) -> NDArray[Any]:
    """Images side by side, enlarged by pixel repetition, separated by white gaps."""
    big = [np.repeat(np.repeat(im, scale, 0), scale, 1) for im in images]
    h = big[0].shape[0]
    sep = np.ones((h, gap, 3), np.float32) * 10.0  # clips to white whatever the exposure
    parts = []
    for i, b in enumerate(big):
        if i:
            parts.append(sep)
        parts.append(b)
    return np.concatenate(parts, axis=1)


def _pct(x: Optional[float]) -> str:
    return "exact" if x is None else f"{100 * x:.2f}%"


def _draw_ms(timings: Optional[rendering.RenderResult]) -> float:
    """The draw milliseconds of a render that ran (its timings are never None then)."""
    assert timings is not None, "no render ran"
    return float(timings.draw_ms)


def step_material(ctx: Context) -> None:
    t0 = time.perf_counter()
    ctx.btf = materials.make(ctx.material, size=ctx.size, seed=ctx.seed, progress=ctx.progress)
    ctx.gen_seconds = time.perf_counter() - t0
    ctx.train, ctx.test = ctx.btf.split(holdout=0.1, seed=0)
    ctx.log(f"material {ctx.material} {ctx.size}^2: {ctx.btf} in {ctx.gen_seconds:.2f} s; "
            f"{ctx.test.pairs} of {ctx.btf.n_views * ctx.btf.n_lights} pairs held out")


def step_baseline(ctx: Context) -> None:
    t0 = time.perf_counter()
    rel, rmse = baselines.nearest_lights_interpolation(ctx.train, ctx.test)
    ctx.rows.append(dict(model="raw data, 3 nearest lights (numpy)", kind="raw", options={},
                         fit_s=time.perf_counter() - t0, nbytes=ctx.btf.nbytes, reconstruction=None, held_out=rel,
                         rmse=rmse))


def _settings(ctx: Context) -> List[Tuple[str, str, Dict[str, Any]]]:
    """``(label, kind, options)`` of the demo's fits: every registered model at the first setting
    of its quick sweep (the registry's quick choice), or, with ``full``, at each of its examples."""
    out: List[Tuple[str, str, Dict[str, Any]]] = []
    for kind, info in model_kinds().items():
        if ctx.full:
            out += [(label, kind, dict(options)) for label, options in info["examples"]]
        else:
            label, options, _, _ = next(s for s in info["sweep"] if s[2])
            out.append((label, kind, dict(options)))
    return out


def _slug(label: str) -> str:
    return label.lower().replace(" ", "_").replace("+", "_").replace("-", "_").replace("/", "_")


def step_models(ctx: Context) -> None:
    """Every registered model (:func:`btfrs.model_kinds`), each at the registry's quick setting
    (with ``full``: each of its example option sets), fitted on the same train half: PTM (000),
    per-texel Lafortune (000), Phong + SRF (003), double SH with CLS (002), Local PCA (004), and
    whatever is registered next. Each is saved, and written in the one-file formats of other
    tools it exports (the view from above)."""
    one_file = {f.name: f.extension for f in _native.model_formats() if not f.folder}
    written: List[str] = []
    for label, kind, options in _settings(ctx):
        m = fit.fit(kind, ctx.train, progress=ctx.progress, **options)
        ctx.models[label] = m
        held, rec = m.error(ctx.test), m.error(ctx.train)
        ctx.rows.append(dict(model=label, kind=kind, options=options, fit_s=m.fit_seconds, nbytes=m.nbytes,
                             reconstruction=rec.relative, held_out=held.relative, rmse=held.rmse))
        ctx.log(f"{label}: fit {m.fit_seconds:.2f} s, {m.nbytes / 2**20:.2f} MiB, held-out {held}")
        slug = _slug(label)
        m.save(ctx.out / f"model_{slug}.btfrs")
        for fmt in m.exports:
            if fmt in one_file:
                name = f"{slug}_top.{one_file[fmt]}"
                m.export(ctx.out / name, format=fmt, view=0)
                written.append(f"`{name}`")
        if m.report:
            shown = ", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in m.report.items()
                              if not isinstance(v, (dict, list)))
            if shown:
                ctx.notes.append(f"{label} fit report: {shown}.")
    ctx.notes.append("Every model is saved as `model_*.btfrs` (`btfrs.load`)"
                     + (f"; {', '.join(written)} hold the view-from-above slot in other tools' formats (open a "
                        "`.ptm` or `.rti` in RTIViewer or relight)." if written else "."))


def step_compare_images(ctx: Context) -> None:
    """Ground truth next to every model for a few held-out (view, light) pairs."""
    assert ctx.test is not None and ctx.test.mask is not None
    views_theta = np.degrees(np.arccos(np.clip(ctx.btf.views[:, 2], -1, 1)))
    picks = []
    for want in (0.0, 30.0, 60.0):
        v = int(np.argmin(np.abs(views_theta - want)))
        ls = np.flatnonzero(ctx.test.mask[v])
        if len(ls) == 0:
            continue
        # The held-out light of this view slot that is furthest from the pole: the hardest case.
        l = int(ls[np.argmin(ctx.btf.lights[ls, 2])])
        picks.append((v, l))
    names = list(ctx.models)
    for i, (v, l) in enumerate(picks):
        gt = ctx.btf.image(v, l)
        row = [gt] + [ctx.models[n].evaluate(ctx.btf.views[v], ctx.btf.lights[l]) for n in names]
        exposure = 0.9 / max(float(np.percentile(gt, 99)), 1e-6)
        name = f"compare_{i}_view{v}_light{l}.png"
        io.save_image(ctx.out / name, _tile(row), exposure=exposure)
        ctx.images.append((name, f"held-out view {v}, light {l}: ground truth | " + " | ".join(names)))


def step_render(ctx: Context) -> None:
    """The material on a sphere and a plane: the raw BTF (the reference) next to each model."""
    lights = [rendering.PointLight(position=[2.0, -2.0, 3.0], intensity=8.0)]
    shots = [("sphere", rendering.Scene.sphere(), rendering.Camera.look_at([0, -3, 2], [0, 0, 0], 40), 4.0),
             ("plane", rendering.Scene.plane(2.0), rendering.Camera.look_at([0, -2.2, 1.6], [0, 0, 0], 45), 3.0)]
    names = ["raw BTF"] + list(ctx.models)
    renders: List[List[NDArray[Any]]] = []
    times: Dict[Tuple[str, str], Optional[rendering.RenderResult]] = {}
    for scene_name, scene, cam, reps in shots:
        row: List[NDArray[Any]] = []
        for name, model in [("raw BTF", ctx.btf)] + list(ctx.models.items()):
            row.append(rendering.render(model, scene, cam, lights, size=(320, 320), uv_scale=reps))
            times[(scene_name, name)] = rendering.last_timings()
        renders.append(row)
    # One exposure for all, from the reference renders' lit pixels.
    ref = np.concatenate([r[0][r[0].sum(-1) > 0] for r in renders])
    exposure = 0.9 / max(float(np.percentile(ref, 99)), 1e-6)
    img = np.concatenate([_tile(row, scale=1, gap=6) for row in renders], axis=0)
    io.save_image(ctx.out / "render.png", img, exposure=exposure)
    ctx.images.append(("render.png", f"rendered with wgpu on {rendering.gpu_info()}: rows sphere, plane; columns "
                       + " | ".join(names)))
    ctx.draw_ms = {n: _draw_ms(times[("sphere", n)]) for n in names}
    draw = ", ".join(f"{n} {ms:.0f} ms" for n, ms in ctx.draw_ms.items())
    ctx.notes.append(f"Draw time per 320^2 sphere frame: {draw}.")
    ctx.log(f"rendered {len(shots) * len(names)} frames on {rendering.gpu_info()}")


def step_environment(ctx: Context) -> None:
    """Environment light (paper 002, section 4): the material on a sphere under the built-in
    sky, by the sampled method (64 importance-sampled lights, the first model) and by the SH
    method (the first model that renders by it: a double-SH expansion); then a slanted plane
    with nearest and trilinear lookups."""
    env = Environment.sky(sun=[0.3, 0.2, 0.9], turbidity=3)
    sphere, cam = rendering.Scene.sphere(), rendering.Camera.look_at([0, -3, 2], [0, 0, 0], 40)
    first, model = next(iter(ctx.models.items()))
    sh_name, sh = next(((n, m) for n, m in ctx.models.items() if m.sh_lighting), ("", None))
    shots, times = [], []
    img = rendering.render(model, sphere, cam, environment=env, samples=64, seed=ctx.seed, size=(320, 320), uv_scale=4)
    shots.append(img)
    times.append(f"sampled (64 lights, {first}) {_draw_ms(rendering.last_timings()):.0f} ms")
    if sh is not None:
        img = rendering.render(sh, sphere, cam, environment=env, lighting="sh", size=(320, 320), uv_scale=4)
        shots.append(img)
        times.append(f"SH method ({sh_name}) {_draw_ms(rendering.last_timings()):.0f} ms")
    exposure = 0.9 / max(float(np.percentile(shots[0][shots[0].sum(-1) > 0], 99)), 1e-6)
    io.save_image(ctx.out / "environment.png", _tile(shots, scale=1, gap=6), exposure=exposure)
    ctx.images.append(("environment.png", "the material on a sphere under the built-in Preetham sky (sun at "
                       f"[0.3, 0.2, 0.9], turbidity 3): sampled method ({first})"
                       + (f" | SH method ({sh_name})" if sh is not None else "")))
    ctx.notes.append("Environment frames (320^2): " + ", ".join(times) + ".")
    plane = rendering.Scene.plane(8.0)
    pcam = rendering.Camera.look_at([0, -3, 3], [0, 0.5, 0], 50)
    light = [rendering.DirectionalLight([0.4, -0.3, 0.8], 1.0)]
    row = [rendering.render(model, plane, pcam, light, size=(240, 320), uv_scale=24, filter=f)
           for f in ("nearest", "trilinear")]
    exposure = 0.9 / max(float(np.percentile(row[0][row[0].sum(-1) > 0], 99)), 1e-6)
    io.save_image(ctx.out / "filtering.png", _tile(row, scale=1, gap=6), exposure=exposure)
    ctx.images.append(("filtering.png", f"{first} on a plane seen at 45 degrees, the texture repeated 24 times: "
                       "nearest lookups (moire) | trilinear lookups over the box-filtered mip pyramid"))
    ctx.log("rendered the environment and filtering frames")


def step_materials_overview(ctx: Context) -> None:
    """Every built-in material under three lights (view from above), to see what they are."""
    lights = from_theta_phi(np.radians([0.0, 60.0, 75.0]), np.radians([0.0, 45.0, 200.0]))
    top = np.array([[0.0, 0.0, 1.0]])
    rows = []
    for name in materials.names():
        b = materials.make(name, size=min(ctx.size, 64), seed=ctx.seed, views=top, lights=lights)
        rows.append(_tile([b.image(0, i) for i in range(3)], scale=3))
    io.save_image(ctx.out / "materials.png", np.concatenate(rows, axis=0), exposure=1.2)
    ctx.images.append(("materials.png", "built-in materials (rows: " + ", ".join(materials.names()) +
                       "), lit from above, at 60 and at 75 degrees"))


def step_synthesis(ctx: Context) -> None:
    """A large BTF synthesized from the sample (paper 000 section 4): texton analysis,
    hierarchical k-coherence into a 512^2 coordinate map, rendered with the first model next to
    the plainly tiled sample, with the quality measures of both."""
    # Three levels as in the paper when the sample allows 5 x 5 windows at its coarsest level.
    levels = next(L for L in (3, 2, 1) if ((ctx.size >> (L - 1)) - 4) ** 2 - 25 >= 10)
    an = synth.analyse(ctx.btf, textons=min(1024, ctx.size * ctx.size), levels=levels, seed=0, progress=ctx.progress)
    an.save(ctx.out / "analysis.btfrs")
    t0 = time.perf_counter()
    size = 8 * ctx.size
    cmap = synth.kcoherence(an, size=size, k=3, neighbourhood=2, levels=levels, seed=7)
    t_syn = time.perf_counter() - t0
    io.save_array(ctx.out / "synth_coords.npy", cmap)
    tiles = synth.tiled((ctx.size, ctx.size), size)
    q, qt = synth.quality(an, cmap), synth.quality(an, tiles)
    big = ctx.btf.expand(cmap)
    first, model = next(iter(ctx.models.items()))
    lights = [rendering.PointLight(position=[1.2, -1.0, 1.5], intensity=3.0)]
    cam = rendering.Camera.look_at([0, -1.6, 2.2], [0, 0, 0], 50)
    scene = rendering.Scene.plane(2.0)
    shots = [rendering.render(model, scene, cam, lights, size=(384, 384), coords=c) for c in (cmap, tiles)]
    lit = np.concatenate([x[x.sum(-1) > 0] for x in shots])
    exposure = 0.9 / max(float(np.percentile(lit, 99)), 1e-6)
    io.save_image(ctx.out / "synthesis_render.png", _tile(shots, scale=1, gap=6), exposure=exposure)
    light = int(np.argmin(np.abs(ctx.btf.lights[:, 2] - np.cos(np.radians(45.0)))))
    flat = [big.image(0, light), synth.apply(ctx.btf.image(0, light), tiles)]
    e2 = 0.8 / max(float(np.percentile(flat[0], 99)), 1e-6)
    io.save_image(ctx.out / "synthesis_flat.png", _tile(flat, scale=1, gap=6), exposure=e2)
    ctx.images.append(("synthesis_render.png", f"a {size}^2 BTF synthesized by k-coherence (left) and the plainly "
                       f"tiled {ctx.size}^2 sample (right) on a plane, rendered with {first} through the coordinate map"))
    ctx.images.append(("synthesis_flat.png", "the same two maps seen from above, one light at 45 degrees"))
    ctx.notes.append(f"Synthesis: analysis {an.seconds:.2f} s ({an}); k-coherence {size}^2 (k=3, neighbourhood 2, "
                     f"{levels} levels) {t_syn:.3f} s; the expanded BTF holds {big.nbytes / 2**20:.1f} MiB instead of "
                     f"{big.nbytes_expanded / 2**20:.0f} MiB. Quality (lower is better but coherence) k-coherence: {q}; "
                     f"plain tiling: {qt}. The built-in materials tile by construction, so plain tiling has no "
                     "seams here; its flaw is the repetition.")
    ctx.log(f"synthesis: analysis {an.seconds:.2f} s, k-coherence {size}^2 in {t_syn:.3f} s; {q}")


def step_tiles(ctx: Context) -> None:
    """Graph-cut Wang tile sets (paper 002): 16 tiles of the default 64^2 with 16-texel edges, in
    the domain of the registry's tile-synthesis setting, dressing a sphere and a cylinder; with
    ``full``, a second material's set swapped in on the same layout, with no re-synthesis and no
    re-tiling; the sets' pictures with their edge colours."""
    t0 = time.perf_counter()
    label, kind, opts = next((b["label"], k, dict(b["options"])) for k, info in model_kinds().items()
                             for b in info["bench"] if "tiles" in b["roles"])
    tile = min(64, ctx.size)
    edge = max(2, min(16, (tile // 4) // 2 * 2))
    sets = [(ctx.material, tiles.wang(fit.fit(kind, ctx.btf, **opts), tile=tile, edge_height=edge, colors=2, seed=5,
                                      progress=ctx.progress))]
    if ctx.full:
        other = "bumps" if ctx.material != "bumps" else "weave"
        btf_b = materials.make(other, size=ctx.size, seed=3, progress=ctx.progress)
        sets.append((other, tiles.wang(fit.fit(kind, btf_b, **opts), tile=tile, edge_height=edge, colors=2, seed=5,
                                       progress=ctx.progress)))
    t_syn = time.perf_counter() - t0
    for name, ts in sets:
        ts.save(ctx.out / f"tiles_{name}.btfrs")
    set_a = sets[0][1]
    layout = set_a.tiling(4, 12, seed=1, wrap=(True, False))  # u runs around: wrap the columns
    io.save_array(ctx.out / "tiles_layout.npy", layout)
    lights = [rendering.PointLight(position=[2.0, -2.5, 3.0], intensity=9.0)]
    cam = rendering.Camera.look_at([0.0, -3.2, 1.6], [0.0, 0.0, 0.0], 40)
    shots = [(set_a, rendering.Scene.sphere()), (set_a, rendering.Scene.cylinder())]
    shots += [(ts, rendering.Scene.cylinder()) for _, ts in sets[1:]]
    imgs = []
    for ts, scene in shots:
        assert ts.model is not None  # a set made from a model keeps its BTFel model
        imgs.append(rendering.render(ts.model, scene, cam, lights, size=(320, 320), tiles=ts, layout=layout))
    ref = np.concatenate([im[im.sum(-1) > 0] for im in imgs])
    io.save_image(ctx.out / "tiles_render.png", _tile(imgs, scale=1, gap=6),
                  exposure=0.9 / max(float(np.percentile(ref, 99)), 1e-6))
    io.save_image(ctx.out / "tiles.png", _tile([ts.picture() for _, ts in sets], scale=2, gap=8))
    names = [n for n, _ in sets]
    ctx.images.append(("tiles_render.png", f"Wang tiles (paper 002): the {ctx.material} tile set on a sphere and a "
                       "cylinder, on a 4 x 12 layout" + (f", then the {names[1]} set on the same layout"
                                                        if len(names) > 1 else "")))
    ctx.images.append(("tiles.png", (f"the tile sets ({', '.join(names)}) with their edge colours" if len(names) > 1
                                     else f"the tile set ({names[0]}) with its edge colours")))
    e = set_a.seam_errors(set_a.tiling(16, 16, seed=2), windows=300)
    ra = set_a.report
    ctx.notes.append(f"Wang tiles: {len(sets)} set{'s' if len(sets) > 1 else ''} of 16 tiles of {tile}^2 (edge height "
                     f"{edge}, {label}) in {t_syn:.1f} s including the fits; {ctx.material}: "
                     f"{100 * ra['referenced']:.1f}% of the texels referenced, {ra['total_bytes'] / 2**20:.2f} MiB; "
                     f"window error across tile edges {e['edge']:.4f} vs inside tiles {e['interior']:.4f} (plain "
                     f"tiling of random crops: {e['crops_edge']:.4f} across edges).")
    ctx.log(f"tiles: {len(sets)} set(s) of {tile}^2 in {t_syn:.1f} s; seams edge {e['edge']:.4f} / "
            f"interior {e['interior']:.4f}")


def step_evaluate(ctx: Context) -> None:
    """Speed against accuracy: held-out error against bytes, render ms and fit seconds, the
    Pareto front dashed, in ``evaluate/``. The quick run charts the demo's own fits (random pairs
    held out; render ms of its 320^2 sphere frames); with ``full``, :func:`btfrs.evaluate` fits
    every model's quick sweep again under both held-out protocols beside the numpy / scipy /
    scikit-learn ways. ``btfrs evaluate`` runs the full sweep."""
    t0 = time.perf_counter()
    if ctx.full:
        rep = evaluate(ctx.btf, "all", holdout="both", sweep="quick", baselines=baselines.evaluation_rows,
                       baseline_texels=8, seed=0, material=ctx.material, progress=ctx.progress)
        what = "quick sweep, both held-out protocols"
    else:
        rows = []
        for r in ctx.rows:
            base = r["kind"] == "raw"
            rows.append(dict(label=r["model"].replace(" (numpy)", "") if base else r["model"], kind=r["kind"],
                             options=r["options"], way="numpy" if base else "btfrs",
                             fit_s=None if base else r["fit_s"], bytes=r["nbytes"], reconstruction=r["reconstruction"],
                             heldout_pairs=r["held_out"], heldout=r["held_out"],
                             render_ms=ctx.draw_ms.get("raw BTF" if base else r["model"]), note=""))
        rep = EvaluationReport(rows, dict(material=ctx.material, shape=list(ctx.btf.shape), holdout="pairs",
                                          fraction=0.1, seed=0, sweep="the demo's fits", adapter=rendering.gpu_info(),
                                          render_size=[320, 320], seconds=0.0,
                                          notes=["the demo's own fits; render ms of its 320^2 sphere frames"]))
        what = "the demo's fits, random pairs held out"
    paths = rep.save(ctx.out / "evaluate")
    front = ", ".join(r["label"] + ("" if r["way"] == "btfrs" else f" ({r['way']})") for r in rep.pareto("heldout", "bytes"))
    ctx.images.append(("evaluate/heldout_vs_bytes.png", "held-out error against bytes, render ms (`heldout_vs_render_ms.png`) "
                       "and fit seconds (`heldout_vs_fit_s.png`), Pareto front dashed"))
    ctx.notes.append(f"Speed against accuracy ({what}, {time.perf_counter() - t0:.0f} s; `evaluate/report.md`): "
                     f"the held-out-vs-bytes front is {front}.")
    ctx.log(f"evaluate: {len(rep.rows)} points in {time.perf_counter() - t0:.1f} s; wrote {', '.join(paths)}")


def step_summary(ctx: Context) -> None:
    raw = ctx.btf.nbytes
    lines = [
        f"# btfrs demo ({__version__})",
        "",
        f"Material **{ctx.material}**, {ctx.size}^2 texels, {ctx.btf.n_views} views x {ctx.btf.n_lights} lights, "
        f"seed {ctx.seed}; generated in {ctx.gen_seconds:.2f} s. Held-out: {ctx.test.pairs} random (view, light) pairs "
        f"(10%, seed 0); every model is fitted on the other {ctx.train.pairs}.",
        "",
        (f"The full run (`btfrs demo --full`): every example of every model, two tile sets and `btfrs.evaluate` "
         f"with both held-out protocols; {time.perf_counter() - ctx.started:.0f} s." if ctx.full else
         f"The quick run: every model at the registry's quick setting, {time.perf_counter() - ctx.started:.0f} s; "
         "`btfrs demo --full` fits every example, makes a second tile set and runs `btfrs.evaluate` with both "
         "held-out protocols (see the README for how long each takes)."),
        "",
        "| model | fit s | size | ratio | reconstruction rel. error | held-out rel. error | held-out RMSE |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for r in ctx.rows:
        lines.append(f"| {r['model']} | {r['fit_s']:.3f} | {r['nbytes'] / 2**20:.2f} MiB | 1:{raw / r['nbytes']:.1f} | "
                     f"{_pct(r['reconstruction'])} | {_pct(r['held_out'])} | {r['rmse']:.4f} |")
    lines += ["", "## Images", ""]
    lines += [f"- `{n}`: {d}" for n, d in ctx.images]
    if ctx.notes:
        lines += ["", "## Notes", ""] + [f"- {n}" for n in ctx.notes]
    io.save_text(ctx.out / "summary.md", "\n".join(lines) + "\n")
    ctx.log(f"wrote {ctx.out / 'summary.md'}")


STEPS: List[Callable[[Context], None]] = [
    step_material, step_baseline, step_models, step_compare_images, step_render, step_environment, step_synthesis,
    step_tiles, step_materials_overview, step_evaluate, step_summary]


def run(out: Union[str, "os.PathLike[str]"], *, material: str = "knit", size: int = 64, seed: int = 1, progress: bool = True,
        log: Callable[[str], None] = print, full: bool = False) -> Context:
    """Run every step into folder ``out`` (created if missing); returns the context. ``full``:
    every example of every model, a second tile set and the full evaluation (module doc)."""
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    ctx = Context(out=folder, material=material, size=size, seed=seed, progress=progress, log=log, full=full)
    log(f"btfrs demo, {'full' if full else 'quick'} run on {material} {size}^2, into {folder}/"
        + ("" if full else " (btfrs demo --full runs every example and the full evaluation)"))
    for step in STEPS:
        step(ctx)
    pngs = len(list(folder.glob("*.png"))) + len(list((folder / "evaluate").glob("*.png")))
    log(f"done in {time.perf_counter() - ctx.started:.0f} s: {len(ctx.models)} models, {pngs} images; "
        f"start with {folder / 'summary.md'}")
    return ctx


if __name__ == "__main__":  # pragma: no cover
    run(os.environ.get("BTFRS_DEMO_OUT", "demo"))
