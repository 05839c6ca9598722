"""End-to-end benchmarks: ``python -m btfrs.tools.bench [--size 64] [--json PATH]``.

Every btfrs figure is measured in the same run as the plain numpy way of doing the same work,
so the ratios do not depend on the machine's mood; the table goes to stdout and everything,
with the machine description, to a JSON file. ``--synth-only``, ``--maxflow-only`` and
``--accuracy``, ``--rti-only`` run one part alone (the synthesis figures; btfrs.graphcut against scipy's
``maximum_flow``; the per-material accuracy table of every model; every light basis on
single-view RTI captures against bytes). BENCHMARKS.md
gives the command of each of its tables.

The bench names no model: every model-specific setting is a registry fact, the model's
``BENCH`` settings (``btfrs.model_kinds()[kind]["bench"]``: label, options, roles, peer, note),
and each section loops over the settings of its role (``btfrs_fit::model::BENCH_ROLES`` says
what each role means). A new model is benched by declaring its settings; its peers (the numpy,
scipy and scikit-learn ways of the same work) are :data:`btfrs.tools.baselines.PEERS`.
"""

from __future__ import annotations

import argparse
import functools
import http.server
import json
import logging
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import threading
import time
import zipfile
from datetime import datetime, timezone
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple, TypeVar

import numpy as np
from numpy.typing import NDArray

from .. import __version__, evaluation, fit, graphcut, io, materials, photometric, rendering, stability, synth, web
from .. import dask as bd
from .. import directions as dirs
from .. import tiles as wang
from . import baselines
from .._checks import memory_size
from ..btf import Btf
from ..environment import Environment
from ..models import model_kinds
from ..rendering import Camera, PointLight, Scene, render
from . import groundtruth


T = TypeVar("T")


def best_of(fn: Callable[[], T], repeat: int) -> Tuple[float, T]:
    """Minimum wall time of ``repeat`` calls (at least one; the least disturbed run) and the last
    result."""
    best = float("inf")
    for _ in range(max(repeat, 1) - 1):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    t0 = time.perf_counter()
    out = fn()
    return min(best, time.perf_counter() - t0), out


#: A setting of the registry's bench facts: (label, kind, options, the fact).
_Setting = Tuple[str, str, Dict[str, Any], Dict[str, Any]]


def settings(role: str) -> List[_Setting]:
    """Every registered setting in ``role`` (``btfrs_fit::model::BENCH_ROLES``), in registry
    order: ``(label, kind, options, fact)``."""
    return [(b["label"], kind, dict(b["options"]), b) for kind, info in model_kinds().items()
            for b in info["bench"] if role in b["roles"]]


def reference() -> _Setting:
    """The setting every frame time is compared with (the registry's ``reference`` role)."""
    return settings("reference")[0]


def _fit(kind: str, options: Dict[str, Any]) -> Callable[[Btf], Any]:
    return lambda b: fit.fit(kind, b, **options)


def _timings() -> rendering.RenderResult:
    """The timings of the render that just ran."""
    t = rendering.last_timings()
    assert t is not None, "no render ran"
    return t


def machine() -> Dict[str, Any]:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return {"cpu": cpu, "cores": os.cpu_count(), "python": platform.python_version(), "numpy": np.__version__,
            "btfrs": __version__, "date": datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")}


def run(sizes: Sequence[int], repeat: int) -> List[Any]:
    """The foundation table: making the material, then every ``foundation`` setting's fit at each
    size, beside its peer's (timed the same way; the note compares their results)."""
    rows: List[Dict[str, Any]] = []
    for size in sizes:
        t_gen, btf = best_of(lambda: materials.make("knit", size=size, seed=1), repeat)
        rows.append(dict(task=f"material knit {size}^2 x 81 x 81", btfrs_s=t_gen, numpy_s=None,
                         target="64^2 < 5 s", note=f"{btf.nbytes / 2**20:.0f} MiB"))
        train, _ = btf.split(holdout=0.1, seed=0)
        for label, kind, opts, b in settings("foundation"):
            peer = baselines.PEERS[b["peer"]] if b["peer"] else baselines.Peer()
            t_np: Optional[float] = None
            ref: Any = None
            if peer.fit is not None:
                peer_fit = peer.fit
                t_np, ref = best_of(lambda: peer_fit(train), repeat)
            t, m = best_of(lambda: fit.fit(kind, train, **opts), repeat)
            note = peer.compare(m, ref) if peer.compare is not None else ""
            rows.append(dict(task=f"{label} fit {size}^2", btfrs_s=t, numpy_s=t_np, target=b["note"], note=note))
        # One pass over the same bytes: the floor a fit "bounded by reading the data once" is held to.
        t_read, _ = best_of(lambda: float(np.add.reduce(train.data, axis=None, dtype=np.float64)), repeat)
        rows.append(dict(task=f"numpy sum over the data {size}^2", btfrs_s=None, numpy_s=t_read, target="", note="read-once floor (numpy)"))
    return rows


def render_bench(repeat: int) -> List[Any]:
    """ms per frame on this machine's adapter: raw BTF and the reference setting, 512^2 and
    1024^2, with and without a coordinate map; draw and read-back timed separately (the first,
    pipeline-compiling frame is not counted)."""
    btf = materials.make("knit", size=64, seed=1)
    ref_label, ref_kind, ref_opts, _ = reference()
    ref = fit.fit(ref_kind, btf, **ref_opts)
    scene = rendering.Scene.sphere()
    cam = rendering.Camera.look_at([0, -3, 2], [0, 0, 0], 40)
    lights = [rendering.PointLight([2.0, -2.0, 3.0], 8.0)]
    rng = np.random.default_rng(0)
    cmap = rng.integers(0, 64, size=(256, 256, 2)).astype(np.uint16)
    rows: List[Dict[str, Any]] = []
    for name, model in (("raw", btf), (ref_label, ref)):
        for size in (512, 1024):
            for coords in (None, cmap):
                rendering.render(model, scene, cam, lights, size=size, uv_scale=4, coords=coords)  # warm-up
                best: Optional[rendering.RenderResult] = None
                for _ in range(max(repeat, 1)):
                    rendering.render(model, scene, cam, lights, size=size, uv_scale=4, coords=coords)
                    t = _timings()
                    best = t if best is None or t.draw_ms < best.draw_ms else best
                assert best is not None
                rows.append(dict(model=name, size=size, coords=coords is not None, draw_ms=best.draw_ms,
                                 readback_ms=best.readback_ms, adapter=rendering.gpu_info()))
    return rows


def render_table(rows: List[Dict[str, Any]]) -> str:
    out = [f"{'model':<8} {'size':>6} {'map':>4} {'draw ms':>9} {'read-back ms':>13}"]
    for r in rows:
        out.append(f"{r['model']:<8} {r['size']:>6} {'yes' if r['coords'] else 'no':>4} {r['draw_ms']:>9.1f} {r['readback_ms']:>13.1f}")
    return "\n".join(out)


def accuracy(size: int) -> List[Any]:
    """Held-out and reconstruction error of the foundation settings on every built-in material,
    beside the raw-data baseline (3 nearest measured lights of the same view slot)."""
    rows: List[Dict[str, Any]] = []
    for name in materials.names():
        btf = materials.make(name, size=size, seed=1)
        train, test = btf.split(holdout=0.1, seed=0)
        rel, _ = baselines.nearest_lights_interpolation(train, test)
        rows.append(dict(material=name, model="raw, 3 nearest lights", nbytes=btf.nbytes, reconstruction=None, held_out=rel))
        for label, kind, opts, _ in settings("foundation"):
            m = fit.fit(kind, train, **opts)
            rows.append(dict(material=name, model=label, nbytes=m.nbytes,
                             reconstruction=m.error(train).relative, held_out=m.error(test).relative))
    return rows


def accuracy_table(rows: List[Dict[str, Any]]) -> str:
    out = [f"{'material':<9} {'model':<22} {'MiB':>8} {'reconstruction':>15} {'held-out':>9}"]
    for r in rows:
        rec = "exact" if r["reconstruction"] is None else f"{100 * r['reconstruction']:.2f}%"
        out.append(f"{r['material']:<9} {r['model']:<22} {r['nbytes'] / 2**20:>8.2f} {rec:>15} {100 * r['held_out']:>8.2f}%")
    return "\n".join(out)


def _render_ms(model: Any, method: Optional[str] = None, size: int = 512,
               repeat: int = 2) -> Tuple[float, NDArray[np.float32]]:
    """Best draw time (ms) of a 512^2 sphere frame with one point light (the first frame, which
    compiles the pipeline, is not counted), and the frame."""
    scene = rendering.Scene.sphere()
    cam = rendering.Camera.look_at([0, -3, 2], [0, 0, 0], 40)
    lights = [rendering.PointLight([2.0, -2.0, 3.0], 8.0)]
    kw: Dict[str, Any] = dict(size=size, uv_scale=4, renderer=method)
    img = rendering.render(model, scene, cam, lights, **kw)
    best = float("inf")
    for _ in range(repeat):
        img = rendering.render(model, scene, cam, lights, **kw)
        best = min(best, _timings().draw_ms)
    return best, img


def rendering_info() -> str:
    return rendering.gpu_info()


def env_bench(size: int = 64, repeat: int = 2) -> List[Any]:
    """Frame times (ms) on this machine's adapter, one model per registered kind (its first
    ``env`` or ``reference`` setting, else its first example) on the knit at ``size``^2: a 512^2
    sphere with one point light (nearest), the same with trilinear lookups, and a 640 x 480 sphere
    under the built-in sky with 64 importance-sampled lights; the models that render under an
    environment by the SH method (``model.sh_lighting``) also by it (paper 002, section 4: 3.2 to
    4.5 minutes per 640 x 480 frame). Best of ``repeat`` after a warm-up frame."""
    btf = materials.make("knit", size=size, seed=1)
    env = Environment.sky(sun=[0.3, 0.2, 0.9], turbidity=3)
    scene = rendering.Scene.sphere()
    cam = rendering.Camera.look_at([0, -3, 2], [0, 0, 0], 40)
    light = [rendering.PointLight([2.0, -2.0, 3.0], 8.0)]

    def best(**kw: Any) -> float:
        rendering.render(**kw)
        t = float("inf")
        for _ in range(repeat):
            rendering.render(**kw)
            t = min(t, _timings().draw_ms)
        return t

    models: List[Tuple[str, Any]] = [("raw BTF", btf)]
    picks = {kind: (label, opts) for label, kind, opts, _ in settings("reference") + settings("env")}
    for kind, info in model_kinds().items():
        label, opts = picks.get(kind, info["examples"][0])
        models.append((label, fit.fit(kind, btf, **opts)))
    rows: List[Dict[str, Any]] = []
    for label, m in models:
        base = dict(model=m, scene=scene, camera=cam, uv_scale=4)
        r = dict(model=label, kind=getattr(m, "kind", "raw"), point_ms=best(lights=light, size=512, **base),
                 trilinear_ms=best(lights=light, size=512, filter="trilinear", **base),
                 env64_ms=best(environment=env, samples=64, size=(480, 640), **base))
        if getattr(m, "sh_lighting", False):
            r["env_sh_ms"] = best(environment=env, lighting="sh", size=(480, 640), **base)
        rows.append(r)
        print(f"  {label}: {r}", file=sys.stderr, flush=True)
    ref = next(r["point_ms"] for r in rows if r["model"] == reference()[0])
    for r in rows:
        r["vs_reference"] = r["point_ms"] / ref
    return rows


def frames_bench(size: int = 32, repeat: int = 2, frame: int = 512) -> List[Any]:
    """The "every model within 3x of the reference" check over every example option set of every
    registered model and each of its renderers (``env_bench`` takes one per model): a
    ``frame``^2 sphere under one point light on the knit at ``size``^2, best of ``repeat`` after
    a warm-up frame, as a ratio to the reference setting's frame in the same run."""
    btf = materials.make("knit", size=size, seed=1)
    scene = rendering.Scene.sphere()
    cam = rendering.Camera.look_at([0, -3, 2], [0, 0, 0], 40)
    light = [rendering.PointLight([2.0, -2.0, 3.0], 8.0)]

    def best(m: Any, method: str) -> float:
        kw: Dict[str, Any] = dict(size=frame, uv_scale=4, renderer=method)
        rendering.render(m, scene, cam, light, **kw)
        t = float("inf")
        for _ in range(repeat):
            rendering.render(m, scene, cam, light, **kw)
            t = min(t, _timings().draw_ms)
        return t

    rows: List[Dict[str, Any]] = []
    for kind, info in model_kinds().items():
        for label, opts in info["examples"]:
            m = fit.fit(kind, btf, **opts)
            for method in info["renderers"]:
                rows.append(dict(model=label, kind=kind, method=method, point_ms=best(m, method)))
    ref = next(r["point_ms"] for r in rows if r["model"] == reference()[0])
    for r in rows:
        r["vs_reference"] = r["point_ms"] / ref
    return rows


def viewer_bench(size: int = 64, repeat: int = 3, figures: Optional[str] = None) -> Dict[str, Any]:
    """The browser viewer against the native renderer, in one run on this machine's software
    adapters (Chromium's WebGPU on SwiftShader, wgpu on lavapipe): per model kind (its default
    options, knit ``size``^2 x 81 x 81), a 512^2 frame of the viewer's default plane, camera and
    light, best of ``repeat`` after a warm-up frame: the model's pass from its start to the GPU's
    completion in the page (``drawMs``) against the draw in native (``draw_ms``), and the page's
    whole frame with its display pass (``frameMs``); and the time from navigation to the first
    frame for each model's folder served from localhost. With ``figures``, a screenshot of the
    page with the reference setting's model (``viewer_knit.png``)."""
    from playwright.sync_api import sync_playwright

    class Quiet(http.server.SimpleHTTPRequestHandler):
        def log_message(self, format: str, *args: Any) -> None:
            pass

    btf = materials.make("knit", size=size, seed=1)
    cam_d = web.DEFAULT_CAMERA
    cam = rendering.Camera.look_at(cam_d["eye"], cam_d["target"], cam_d["fov"], up=cam_d["up"])
    light = [rendering.DirectionalLight(web.DEFAULT_LIGHT["direction"], web.DEFAULT_LIGHT["intensity"])]
    plane = rendering.Scene.plane(2.0)
    rows: List[Dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="btfrs-viewer-bench-") as root, sync_playwright() as p:
        browser = p.chromium.launch(executable_path="/usr/bin/chromium", headless=True,
                                    args=["--no-sandbox", "--enable-unsafe-webgpu", "--use-webgpu-adapter=swiftshader"])
        handler = functools.partial(Quiet, directory=root)
        httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
        threading.Thread(target=httpd.serve_forever, daemon=True).start()
        url = f"http://localhost:{httpd.server_address[1]}"
        try:
            for kind in model_kinds():
                m = fit.fit(kind, btf)
                rendering.render(m, plane, cam, light, size=512)
                native = float("inf")
                for _ in range(repeat):
                    rendering.render(m, plane, cam, light, size=512)
                    native = min(native, _timings().draw_ms)
                web.save_web(m, os.path.join(root, kind), force=True, name=f"knit {size}")
                page = browser.new_page(viewport={"width": 1100, "height": 760})
                page.goto(f"{url}/{kind}/index.html")
                first = float(page.evaluate("window.btfrsViewer.ready.then(() => window.btfrsViewer.firstFrameMs)"))
                loaded = float(page.evaluate("window.btfrsViewer.loadedMs"))
                err = page.evaluate("window.btfrsViewer.error")
                if err:
                    raise RuntimeError(f"the viewer failed on {kind}: {err}")
                page.evaluate("window.btfrsViewer.set({size: [512, 512]})")
                ms, frame_ms = float("inf"), float("inf")
                for _ in range(repeat):
                    page.evaluate("window.btfrsViewer.set({exposure: 1.0})")
                    ms = min(ms, float(page.evaluate("window.btfrsViewer.drawMs")))
                    frame_ms = min(frame_ms, float(page.evaluate("window.btfrsViewer.frameMs")))
                if figures and kind == reference()[1]:
                    os.makedirs(figures, exist_ok=True)
                    page.screenshot(path=os.path.join(figures, "viewer_knit.png"))
                page.close()
                rows.append(dict(kind=kind, native_ms=native, browser_ms=ms, frame_ms=frame_ms, ratio=ms / native,
                                 load_ms=loaded,
                                 first_frame_ms=first, model_bytes=int(m.nbytes)))
        finally:
            httpd.shutdown()
            httpd.server_close()
            browser.close()
    return {"size": size, "rows": rows}


def _chromium_version() -> str:
    try:
        out = subprocess.run(["/usr/bin/chromium", "--version"], capture_output=True, text=True, timeout=30).stdout
    except OSError:
        return "?"
    return out.split()[1] if len(out.split()) > 1 else out.strip()


def viewer_table(res: Dict[str, Any]) -> str:
    out = [f"{'model':<16} {'native draw':>12} {'browser draw':>13} {'x native':>9} {'whole frame':>12} "
           f"{'files loaded':>13} {'first frame':>12} {'bytes':>10}"]
    out += [f"{r['kind']:<16} {r['native_ms']:>10.1f}ms {r['browser_ms']:>11.1f}ms {r['ratio']:>9.2f} "
            f"{r['frame_ms']:>10.1f}ms {r['load_ms']:>11.0f}ms {r['first_frame_ms']:>10.0f}ms {r['model_bytes']:>10}"
            for r in res["rows"]]
    return "\n".join(out)


def frames_table(rows: List[Dict[str, Any]]) -> str:
    ref = "x " + reference()[0]
    out = [f"{'model':<24} {'renderer':<9} {'512^2 point':>12} {ref:>10}"]
    out += [f"{r['model']:<24} {r['method']:<9} {r['point_ms']:>10.1f}ms {r['vs_reference']:>10.2f}" for r in rows]
    return "\n".join(out)


def env_table(rows: List[Dict[str, Any]]) -> str:
    ref = "x " + reference()[0]
    out = [f"{'model':<22} {'512^2 point':>12} {ref:>10} {'trilinear':>10} {'640x480 env 64':>15} {'SH method':>10}"]
    for r in rows:
        by_sh = f"{r['env_sh_ms'] / 1e3:>9.2f}s" if "env_sh_ms" in r else f"{'':>10}"
        out.append(f"{r['model']:<22} {r['point_ms']:>10.0f}ms {r['vs_reference']:>10.1f} {r['trilinear_ms']:>8.0f}ms "
                   f"{r['env64_ms'] / 1e3:>14.2f}s {by_sh}")
    return "\n".join(out)


def model_settings() -> List[Tuple[str, str, Dict[str, Any]]]:
    """The models table's settings: every example option set of every registered model, then the
    ``models`` settings beyond them (the registry names them all; nothing here does)."""
    out = [(label, kind, dict(opts)) for kind, info in model_kinds().items() for label, opts in info["examples"]]
    seen = {label for label, _, _ in out}
    out += [(label, kind, opts) for label, kind, opts, _ in settings("models") if label not in seen]
    return out


def models_bench(size: int, material: str = "knit", lm_texels: int = 64) -> List[Any]:
    """Every model at several settings on one material: fit seconds, bytes, held-out RMSE and
    relative error, reconstruction error, render ms (512^2 sphere, each of its renderers); then
    the rows of each ``models`` setting's peer (:data:`btfrs.tools.baselines.PEERS`: the numpy,
    scipy or scikit-learn way of the same fit) in the same table."""
    btf = materials.make(material, size=size, seed=1)
    train, test = btf.split(holdout=0.1, seed=0)
    rows: List[Dict[str, Any]] = []
    kinds = model_kinds()
    for name, kind, opts in model_settings():
        t0 = time.perf_counter()
        m = fit.fit(kind, train, **opts)
        secs = time.perf_counter() - t0
        held, rec = m.error(test), m.error(train)
        ms: Dict[str, float] = {}
        for method in kinds[kind]["renderers"]:
            ms[method], _ = _render_ms(m, method)
        rows.append(dict(model=name, way="btfrs", fit_s=secs, nbytes=m.nbytes, held_out_rmse=held.rmse,
                         held_out=held.relative, reconstruction=rec.relative, render_ms=ms))
    for label, kind, opts, b in settings("models"):
        if b["peer"]:
            peer = baselines.PEERS[b["peer"]]
            assert peer.rows is not None, f"peer {b['peer']} has no rows for the models table"
            rows += peer.rows(train, test, label, opts, _fit(kind, opts), lm_texels)
    return rows


def models_table(rows: List[Dict[str, Any]]) -> str:
    out = [f"{'model':<21} {'way':<44} {'fit s':>9} {'MiB':>7} {'held-out':>9} {'recon.':>8}  render ms (512^2)"]
    for r in rows:
        fs = f"{r['fit_s']:.4f}" + ("/tx" if r.get("per_texel") else "")
        mib = "" if r["nbytes"] is None else f"{r['nbytes'] / 2**20:.2f}"
        ho = "" if r["held_out"] is None else f"{100 * r['held_out']:.2f}%"
        ms = ", ".join(f"{k} {v:.0f}" for k, v in r["render_ms"].items())
        out.append(f"{r['model']:<21} {r['way']:<44} {fs:>9} {mib:>7} {ho:>9} {100 * r['reconstruction']:>7.2f}%  {ms}")
        if "btfrs_same" in r:
            o = r["btfrs_same"]
            out.append(f"{'':<21} {'  btfrs on the same texels':<44} {o['fit_s']:.4f}/tx {'':>6} "
                       f"{100 * o['held_out']:>8.2f}% {100 * o['reconstruction']:>7.2f}%  speed-up {r['fit_s'] / o['fit_s']:.0f}x")
    return "\n".join(out)


def renderers_bench(size: int = 64, repeat: int = 2) -> List[Any]:
    """Each ``renderers`` setting (the registry's note says which paper table it is) drawn by
    each of its model's renderers at 512^2 and 1024^2, with the speed-up of the last over the
    first and the PSNR between their images."""
    btf = materials.make("knit", size=size, seed=1)
    rows: List[Dict[str, Any]] = []
    kinds = model_kinds()
    for label, kind, opts, b in settings("renderers"):
        m = fit.fit(kind, btf, **opts)
        names = kinds[kind]["renderers"]
        for px in (512, 1024):
            shots = {r: _render_ms(m, r, px, repeat) for r in names}
            (t0, a), (t1, c) = shots[names[0]], shots[names[-1]]
            mse = float(np.mean((a.astype(np.float64) - c) ** 2))
            peak = float(max(a.max(), c.max()))
            rows.append(dict(model=label, note=b["note"], size=px, ms={r: t for r, (t, _) in shots.items()},
                             speedup=t0 / t1, psnr=10 * np.log10(peak * peak / mse) if mse > 0 else float("inf")))
    return rows


def renderers_table(rows: List[Dict[str, Any]]) -> str:
    out = []
    for r in rows:
        first, last = list(r["ms"])[0], list(r["ms"])[-1]
        times = " ".join(f"{k} {v:8.1f} ms" for k, v in r["ms"].items())
        out.append(f"{r['model']:<12} {r['size']:>5} {times}  {last} {r['speedup']:5.2f}x faster, "
                   f"PSNR {first} vs {last} {r['psnr']:5.1f} dB")
    return "\n".join(out)


#: The reconstruction error the ``reach`` settings are searched for (paper 004).
REACH = 0.02


def reach_sweep(size: int) -> List[Any]:
    """Which ``reach`` setting of each model reaches :data:`REACH` reconstruction error on each
    built-in material with the fewest bytes, and at what compression (raw at one byte per value
    over the model's bytes)."""
    rows: List[Dict[str, Any]] = []
    grid = settings("reach")
    for name in materials.names():
        btf = materials.make(name, size=size, seed=1)
        for kind in dict.fromkeys(k for _, k, _, _ in grid):
            best: Optional[Dict[str, Any]] = None
            for label, k, opts, _ in grid:
                if k != kind:
                    continue
                m = fit.fit(kind, btf, **opts)
                e = m.error(btf).relative
                # Raw at one byte per value (as the measured data is stored) over the model's bytes.
                row = dict(material=name, kind=kind, model=label, reconstruction=e,
                           compression=btf.data.size / m.nbytes, nbytes=m.nbytes)
                rows.append(row)
                if e <= REACH and (best is None or m.nbytes < best["nbytes"]):
                    best = row
            rows.append(dict(material=name, kind=kind, best=best))
    return rows


def reach_table(rows: List[Dict[str, Any]]) -> str:
    out: List[Any] = []
    for r in rows:
        if "best" in r:
            b = r["best"]
            if b is None:
                errs = [x for x in rows if x.get("material") == r["material"] and x.get("kind") == r["kind"]
                        and "reconstruction" in x]
                lo = min(errs, key=lambda x: x["reconstruction"])
                out.append(f"{r['material']:<8} {100 * REACH:.0f}% not reached; best {100 * lo['reconstruction']:.2f}% "
                           f"by {lo['model']} (1:{lo['compression']:.0f})")
            else:
                out.append(f"{r['material']:<8} {100 * REACH:.0f}% reached by {b['model']}: "
                           f"{100 * b['reconstruction']:.2f}% at 1:{b['compression']:.0f}")
    return "\n".join(out)


def accuracy_models(size: int) -> List[Any]:
    """Reconstruction and held-out relative error of every ``per_material`` setting on every
    built-in material at ``size``^2, beside the raw-data baseline (3 nearest measured lights of
    the same view slot), with each model's bytes, its size ratio to the float32 BTF, its fit
    seconds and its fit report (a residual fit's base alone, converged / fell back / failed of
    a per-texel nonlinear fit)."""
    rows: List[Dict[str, Any]] = []
    for name in materials.names():
        btf = materials.make(name, size=size, seed=1)
        train, test = btf.split(holdout=0.1, seed=0)
        rel, _ = baselines.nearest_lights_interpolation(train, test)
        rows.append(dict(material=name, model="raw, 3 nearest lights", size=size, nbytes=btf.nbytes, ratio=1.0,
                         fit_s=None, reconstruction=None, held_out=rel, report={}))
        for model, kind, opts, _ in settings("per_material"):
            t0 = time.perf_counter()
            m = fit.fit(kind, train, **opts)
            secs = time.perf_counter() - t0
            rows.append(dict(material=name, model=model, size=size, nbytes=m.nbytes, ratio=btf.nbytes / m.nbytes,
                             fit_s=secs, reconstruction=m.error(train).relative, held_out=m.error(test).relative,
                             report=dict(getattr(m, "report", None) or {})))
    return rows


def _report_note(r: Dict[str, Any]) -> str:
    rep = r["report"]
    if "phong_relative" in rep:
        return f"Phong alone {100 * rep['phong_relative']:.2f}% (train)"
    if "converged" in rep:
        return f"{rep['converged']}/{rep['fell_back']}/{rep['failed']} converged/fell back/failed"
    return ""


def accuracy_models_table(rows: List[Dict[str, Any]]) -> str:
    out = [f"{'material':<9} {'model':<22} {'MiB':>8} {'1:x':>7} {'fit s':>7} {'recon.':>8} {'held-out':>9}  note"]
    for r in rows:
        rec = "exact" if r["reconstruction"] is None else f"{100 * r['reconstruction']:.2f}%"
        fs = "" if r["fit_s"] is None else f"{r['fit_s']:.2f}"
        out.append(f"{r['material']:<9} {r['model']:<22} {r['nbytes'] / 2**20:>8.3f} {r['ratio']:>7.1f} {fs:>7} "
                   f"{rec:>8} {100 * r['held_out']:>8.2f}%  {_report_note(r)}")
    # The two targets this table answers (BENCHMARKS.md, "Targets").
    for name in dict.fromkeys(r["material"] for r in rows):
        mine = [r for r in rows if r["material"] == name]
        raw = mine[0]["held_out"]
        below = [r["model"] for r in mine[1:] if r["held_out"] < raw and r["ratio"] >= 10]
        # A fit reporting its Phong base alone beside itself: is it below its base?
        based = "".join(f"; {r['model']} below Phong alone: "
                        f"{'yes' if r['report']['srf_relative'] < r['report']['phong_relative'] else 'no'}"
                        for r in mine if "phong_relative" in r["report"] and "srf_relative" in r["report"])
        out.append(f"{name}: held-out below raw interpolation ({100 * raw:.2f}%) at >= 1:10: "
                   f"{', '.join(below) or 'none'}{based}")
    return "\n".join(out)


# --- single-view RTI captures (relight's bases) ----------------------------------------------

#: The captures of ``--rti-only``: (material, lights), one view at the normal, ``RTI_SIZE``^2.
RTI_CAPTURES = (("bumps", 160), ("knit", 220), ("grooves", 120))
RTI_SIZE = 64
#: The share of the lights held out.
RTI_HOLDOUT = 0.15
def rti_lights(n: int, seed: int = 0, max_theta_deg: float = 80.0) -> np.ndarray:
    """``n`` light directions spread evenly over the hemisphere up to ``max_theta_deg`` (a
    Fibonacci spiral, equal-area in ``z``, with a little seeded jitter, as a dome's lights are
    spread), ``[n, 3]``."""
    rng = np.random.default_rng(seed)
    i = np.arange(n) + 0.5
    zmin = np.cos(np.radians(max_theta_deg))
    z = 1.0 - (1.0 - zmin) * i / n
    phi = i * np.pi * (3.0 - np.sqrt(5.0)) + rng.uniform(-0.15, 0.15, n)
    z = np.clip(z + rng.uniform(-0.3, 0.3, n) * (1.0 - zmin) / n, zmin, 1.0)
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def rti_settings() -> List[Any]:
    """``(label, kind, options)`` for the single-view comparison, iterating over the registry:
    each model's ``single_view`` settings, or its examples where it has none, except the models
    the registry leaves out (``no_single_view``: their note says why)."""
    out: List[Any] = []
    mine = settings("single_view")
    skip = {k for _, k, _, _ in settings("no_single_view")}
    for kind, info in model_kinds().items():
        if kind in skip:
            continue
        own = [(label, k, opts) for label, k, opts, _ in mine if k == kind]
        out += own or [(label, kind, dict(opts)) for label, opts in info["examples"]]
    return out


def rti_bench(captures: Sequence[Tuple[str, int]] = RTI_CAPTURES, size: int = RTI_SIZE, chart_dir: str = "docs/rti") -> List[Any]:
    """Every setting of :func:`rti_settings` on each single-view capture: held-out relative
    error (``RTI_HOLDOUT`` of the lights, seed 0) against bytes, via
    :func:`btfrs.evaluation.evaluate`; one chart per capture in ``chart_dir``."""
    out: List[Any] = []
    settings = rti_settings()
    for name, nl in captures:
        btf = materials.make(name, size=size, seed=1, views=np.array([[0.0, 0.0, 1.0]]), lights=rti_lights(nl, 1))
        label = f"{name} 1 view x {nl} lights"
        rep = evaluation.evaluate(btf, settings, holdout="pairs", fraction=RTI_HOLDOUT, baselines=None,
                                  render=False, material=label)
        path = os.path.join(chart_dir, f"rti_{name}.png")
        os.makedirs(chart_dir, exist_ok=True)
        rep.chart("bytes", path)
        out.append(dict(capture=label, material=name, lights=nl, size=size, chart=path,
                        rows=[{k: r.get(k) for k in ("label", "kind", "options", "bytes", "fit_s", "reconstruction",
                                                      "heldout_pairs", "error", "note")} for r in rep.rows],
                        table=rep.table()))
    return out


def _best(rows: List[Dict[str, Any]], pred: Callable[[Dict[str, Any]], bool]) -> Optional[Dict[str, Any]]:
    ok = [r for r in rows if r.get("heldout_pairs") is not None and r.get("bytes") and pred(r)]
    return min(ok, key=lambda r: r["heldout_pairs"]) if ok else None


def _labelled(label: str, row: Dict[str, Any]) -> bool:
    return bool(row["label"] == label)


def _within(budget: int, row: Dict[str, Any]) -> bool:
    return bool(row["bytes"] <= budget)


def rti_summary(res: List[Dict[str, Any]]) -> str:
    """Per capture: the best model within relight's byte budgets (26, 50, 85 KB) and under
    100 KB (all models; relight's bases alone, the kinds written in its format; the others
    alone), the reference setting and each ``summary`` setting, each with its ratio to the
    reference's held-out error (relight's own figures put its two PCA light bases at 0.70 and
    0.72 of its biquadratic's); then the peer tool's published figures (the summary settings'
    notes). KB = 1000 bytes, as relight's figures."""
    ref_label = reference()[0]
    summary = settings("summary")
    relight = {k for k, info in model_kinds().items() if "relight" in info["exports"]}
    lines = [f"{'capture':<28} {'model':<44} {'KB':>7} {'held-out':>9} {'/ ref':>6}"]
    for c in res:
        rows = c["rows"]
        ref = _best(rows, lambda r: r["label"] == ref_label)
        picks = [(f"best <= {b // 1000} KB", _best(rows, functools.partial(_within, b)))
                 for b in (26_000, 50_000, 85_000)]
        picks += [("best < 100 KB", _best(rows, lambda r: r["bytes"] < 100_000)),
                  ("best RTI basis < 100 KB", _best(rows, lambda r: r["bytes"] < 100_000 and r["kind"] in relight)),
                  ("best non-RTI < 100 KB", _best(rows, lambda r: r["bytes"] < 100_000 and r["kind"] not in relight)),
                  ("", ref)]
        picks += [("", _best(rows, functools.partial(_labelled, label)))
                  for label in dict.fromkeys(label for label, _, _, _ in summary) if label != ref_label]
        for what, r in picks:
            if r is None:
                continue
            rel = "" if ref is None else f"{r['heldout_pairs'] / ref['heldout_pairs']:.2f}"
            name = f"{r['label']}" + (f" ({what})" if what else "")
            lines.append(f"{c['capture']:<28} {name:<44} {r['bytes'] / 1000:>7.1f} "
                         f"{100 * r['heldout_pairs']:>8.2f}% {rel:>6}")
    lines.append("relight on its real 240-light capture (the targets): "
                 + "; ".join(b["note"] for _, _, _, b in summary if b["note"]))
    return "\n".join(lines)


def table(rows: List[Dict[str, Any]]) -> str:
    out = [f"{'task':<36} {'btfrs s':>9} {'numpy s':>9} {'speed-up':>9}  {'target':<24} note"]
    for r in rows:
        b = "" if r["btfrs_s"] is None else f"{r['btfrs_s']:.4f}"
        n = "" if r["numpy_s"] is None else f"{r['numpy_s']:.4f}"
        s = f"{r['numpy_s'] / r['btfrs_s']:.1f}x" if r["btfrs_s"] and r["numpy_s"] else ""
        out.append(f"{r['task']:<36} {b:>9} {n:>9} {s:>9}  {r['target']:<24} {r['note']}")
    return "\n".join(out)


#: Paper 000 Table 1 (3 levels, Pentium 4 2.4 GHz, analysis excluded): (size, k, neighbourhood, seconds).
TABLE1 = [(256, 1, 2, 1.9), (256, 3, 2, 2.7), (256, 6, 2, 3.7), (256, 6, 3, 13.6), (512, 6, 2, 13.4)]
#: The targets of BENCHMARKS.md ("Targets") for the synthesis rows (seconds).
SYNTH_TARGETS = {(256, 3, 2): 0.02, (512, 6, 2): 0.1}
#: The target for the texton analysis of a 64^2 x 81 x 81 sample (seconds).
ANALYSIS_TARGET_S = 0.5


def synth_bench(repeat: int, material: str = "knit", size: int = 64) -> Dict[str, Any]:
    """Paper 000 Table 1 settings, the jump map and the analysis of a size^2 x 81 x 81 sample,
    with the quality measures of every result beside plain tiling and random placement."""
    btf = materials.make(material, size=size, seed=1)
    t_an, an = best_of(lambda: synth.analyse(btf, textons=min(1024, size * size), seed=0), min(repeat, 2))
    an.prepare(3, 3)
    rows: List[Dict[str, Any]] = []
    settings = [(s, k, n, p) for (s, k, n, p) in TABLE1] + [(512, 1, 2, None), (512, 3, 2, None)]
    for (out, k, n, paper) in settings:
        t, cmap = best_of(lambda: synth.kcoherence(an, size=out, k=k, neighbourhood=n, levels=3, seed=7), repeat)
        q = synth.quality(an, cmap, neighbourhood=2)
        rows.append(dict(method="k-coherence", size=out, k=k, neighbourhood=n, seconds=t, paper_s=paper,
                         target_s=SYNTH_TARGETS.get((out, k, n)), **q.as_dict()))
    for out in (256, 512):
        t, cmap = best_of(lambda: synth.jump_map(an, size=out, neighbourhood=2, seed=7), repeat)
        rows.append(dict(method="jump map", size=out, k=None, neighbourhood=2, seconds=t, paper_s=None, target_s=None,
                         **synth.quality(an, cmap, neighbourhood=2).as_dict()))
    for name, cmap in [("plain tiling", synth.tiled((size, size), 512)),
                       ("random placement", synth.random_placement((size, size), 512, seed=1))]:
        rows.append(dict(method=name, size=512, k=None, neighbourhood=None, seconds=0.0, paper_s=None, target_s=None,
                         **synth.quality(an, cmap, neighbourhood=2).as_dict()))
    return dict(material=material, sample=size, analysis_s=t_an, analysis=repr(an), rows=rows)


def synth_table(res: Dict[str, Any]) -> str:
    out = [f"analysis of {res['material']} {res['sample']}^2 x 81 x 81: {res['analysis_s']:.2f} s "
           f"(target <= {ANALYSIS_TARGET_S} s)",
           f"{'method':<16} {'size':>5} {'k':>2} {'n':>2} {'seconds':>8} {'paper':>7} {'target':>7} "
           f"{'nn_dist':>8} {'coher':>6} {'seam':>7} {'seam_m':>7} {'repet':>6}"]
    for r in res["rows"]:
        def f(v: Any, fmt: str) -> str:
            return "-" if v is None else format(v, fmt)

        out.append(f"{r['method']:<16} {r['size']:>5} {f(r['k'], 'd'):>2} {f(r['neighbourhood'], 'd'):>2} "
                   f"{r['seconds']:>8.3f} {f(r['paper_s'], '.1f'):>7} {f(r['target_s'], '.2f'):>7} "
                   f"{r['nn_distance']:>8.4f} {r['coherence']:>6.3f} {r['seam']:>7.4f} {r['seam_mean']:>7.4f} "
                   f"{r['repetition']:>6.3f}")
    return "\n".join(out)


#: Grid sides of the max-flow figures (``--maxflow-size`` replaces them).
MAXFLOW_SIZES = (256, 512)


def robust_bench(size: int = 64, repeat: int = 2, material: str = "knit") -> List[Any]:
    """Every model's default stability setting fitted plain (``robust=False``) and robust on the
    same clean material, best of ``repeat`` each, interleaved; and the held-out error of both on
    clean data and with 0.1% of the training values times 1000."""

    btf = materials.make(material, size=size, seed=0)
    train, test = btf.split(holdout=0.1, seed=0)
    rng = np.random.default_rng(0)
    hot = Btf(np.where(rng.random(train.data.shape) < 0.001, train.data * 1000.0, train.data).astype(np.float32),
              train.views, train.lights, train.mask, check=False)
    rows: List[Any] = []
    for label, kind, opts in stability.default_models():
        times: Dict[bool, float] = {False: float("inf"), True: float("inf")}
        for _ in range(repeat):
            for rb in (False, True):
                t0 = time.perf_counter()
                fit.fit(kind, btf, robust=rb, **opts)
                times[rb] = min(times[rb], time.perf_counter() - t0)
        err = {f"{'robust' if rb else 'plain'}_{name}": fit.fit(kind, d, robust=rb, **opts).error(test).relative
               for rb in (False, True) for name, d in (("clean", train), ("hot", hot))}
        rows.append(dict(model=label, plain_s=times[False], robust_s=times[True],
                         ratio=times[True] / times[False], **err))
    return rows


def robust_table(rows: List[Dict[str, Any]]) -> str:
    out = ["| model | plain fit | robust fit | ratio | clean: plain / robust error | 0.1% hot: plain / robust error |",
           "|---|---:|---:|---:|---|---|"]
    for r in rows:
        out.append(f"| {r['model']} | {r['plain_s']:.3f} s | {r['robust_s']:.3f} s | {r['ratio']:.2f}x | "
                   f"{r['plain_clean']:.4f} / {r['robust_clean']:.4f} | {r['plain_hot']:.3f} / {r['robust_hot']:.4f} |")
    return "\n".join(out)


def _spiral(n: int, lo: float = 15.0, hi: float = 80.0) -> NDArray[np.float64]:
    """``n`` light directions on a golden-angle spiral, elevations ``lo`` to ``hi`` degrees."""
    el = np.radians(lo + (hi - lo) * np.arange(n) / n)
    az = 2.399963 * np.arange(n)
    return np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1)


def normals_bench(size: int = 512, lights: int = 240, repeat: int = 3) -> Dict[str, Any]:
    """Photometric stereo on one view of ``size``^2 texels under ``lights`` lights (the bumps
    material's true normals and albedo, shaded as a Lambertian surface with its cast shadows
    left out): btfrs's L2 and robust against numpy's float64 least squares of the grey values
    (``np.linalg.lstsq`` with every texel a right-hand side: the vectorised reference), best of
    ``repeat``, interleaved; then each method's mean angle to the truth on the material itself
    (shadows and highlights in)."""
    hf = materials.heightfield("bumps", size=size, seed=1)
    dirs = _spiral(lights)
    shade = np.maximum(np.einsum("hwc,lc->hwl", hf.normals, dirs.astype(np.float32)), 0.0)
    data = (shade[:, :, None, :, None] * hf.albedo[:, :, None, None, :]).astype(np.float32)
    btf = Btf(data, [[0.0, 0.0, 1.0]], dirs, check=False)
    del shade

    def numpy_l2() -> NDArray[np.float64]:
        grey = btf.data[:, :, 0].mean(axis=-1, dtype=np.float64).reshape(-1, lights)
        g = np.linalg.lstsq(dirs, grey.T, rcond=None)[0]
        n: NDArray[np.float64] = (g / np.linalg.norm(g, axis=0)).T.reshape(size, size, 3)
        return n

    times: Dict[str, float] = {"numpy": float("inf"), "l2": float("inf"), "robust": float("inf")}
    out: Dict[str, Any] = {}
    for _ in range(max(1, repeat)):
        for name, fn in (("numpy", numpy_l2), ("l2", lambda: photometric.normals(btf, method="l2").normals),
                         ("robust", lambda: photometric.normals(btf, method="robust").normals)):
            t0 = time.perf_counter()
            out[name] = fn()
            times[name] = min(times[name], time.perf_counter() - t0)
    agree = float(photometric.angular_error(out["l2"], out["numpy"]).max())
    del btf, data, out
    small = materials.make("bumps", size=64, seed=1, views=[[0.0, 0.0, 1.0]], lights=_spiral(96))
    truth = materials.heightfield("bumps", size=64, seed=1).normals
    err = {m: float(photometric.normals(small, method=m).angular_error(truth).mean()) for m in ("l2", "robust")}
    return {"size": size, "lights": lights, "seconds": times, "ratio_l2": times["numpy"] / times["l2"],
            "ratio_robust": times["numpy"] / times["robust"], "max_angle_l2_vs_numpy": agree,
            "bumps64_mean_angle": err}


def normals_table(r: Dict[str, Any]) -> str:
    s = r["seconds"]
    gb = r["size"] ** 2 * r["lights"] * 12 / 1e9
    return "\n".join([
        "| method | seconds | numpy / this | GB/s of values |", "|---|---:|---:|---:|",
        f"| numpy lstsq (float64, grey values) | {s['numpy']:.3f} | 1.00x | {gb / s['numpy']:.2f} |",
        f"| btfrs l2 | {s['l2']:.3f} | {r['ratio_l2']:.1f}x | {gb / s['l2']:.2f} |",
        f"| btfrs robust (IRLS) | {s['robust']:.3f} | {r['ratio_robust']:.1f}x | {gb / s['robust']:.2f} |",
        f"\nl2 against numpy: at most {r['max_angle_l2_vs_numpy']:.2e} degrees apart; mean angle to the true "
        f"normals of bumps 64^2 x 96 lights (shadows and highlights in): l2 {r['bumps64_mean_angle']['l2']:.2f}, "
        f"robust {r['bumps64_mean_angle']['robust']:.2f} degrees"])


def maxflow_problems(n: int, seed: int = 1) -> Dict[str, Any]:
    """Integer-capacity ``n x n`` grids as ``(right, down, terminal_caps)``, the same shapes the
    criterion bench of btfrs-graphcut uses: ``kwatra``, a seam problem (cutting between p and q
    costs ``|A(p) - B(p)| + |A(q) - B(q)|`` for two noise images, scaled by 1000; the two left
    columns tied to the source, the two right ones to the sink) and ``segmentation`` (unary
    terms around a smooth field, a constant smoothness weight 40)."""
    rng = np.random.default_rng(seed)
    d = np.abs(rng.random((n, n)) - rng.random((n, n)))
    r = (1000 * (d[:, :-1] + d[:, 1:])).astype(np.int64)
    dn = (1000 * (d[:-1] + d[1:])).astype(np.int64)
    tie = np.zeros((n, n, 2), np.int64)
    tie[:, :2, 0] = 10**9
    tie[:, -2:, 1] = 10**9
    y, x = np.mgrid[0:n, 0:n]
    field = np.sin(x / 23.0) * np.cos(y / 17.0) + 0.8 * (rng.random((n, n)) - 0.5)
    unary = np.stack([100 * np.maximum(1 + field, 0), 100 * np.maximum(1 - field, 0)], -1).astype(np.int64)
    lam = 40
    return {"kwatra": (np.stack([r, r], -1), np.stack([dn, dn], -1), tie),
            "segmentation": (np.full((n, n - 1, 2), lam, np.int64), np.full((n - 1, n, 2), lam, np.int64), unary)}


def _grid_csr(right: NDArray[Any], down: NDArray[Any], term: NDArray[Any]) -> Any:
    """The grid with a source node N and a sink node N + 1 as the int32 CSR matrix scipy takes."""
    import scipy.sparse  # optional (bench extra): only the max-flow comparison

    h, w = term.shape[:2]
    nn = h * w
    ids = np.arange(nn).reshape(h, w)
    rows = np.concatenate([ids[:, :-1].ravel(), ids[:, 1:].ravel(), ids[:-1].ravel(), ids[1:].ravel(),
                           np.full(nn, nn), ids.ravel()])
    cols = np.concatenate([ids[:, 1:].ravel(), ids[:, :-1].ravel(), ids[1:].ravel(), ids[:-1].ravel(),
                           ids.ravel(), np.full(nn, nn + 1)])
    data = np.concatenate([right[..., 0].ravel(), right[..., 1].ravel(), down[..., 0].ravel(), down[..., 1].ravel(),
                           term[..., 0].ravel(), term[..., 1].ravel()]).astype(np.int32)
    keep = data > 0
    m = scipy.sparse.csr_matrix((data[keep], (rows[keep], cols[keep])), shape=(nn + 2, nn + 2))
    m.sum_duplicates()
    return m


def maxflow_bench(repeat: int, sizes: Sequence[int] = MAXFLOW_SIZES) -> List[Any]:
    """btfrs.graphcut (grid path and general path, argument conversion included) against
    scipy.sparse.csgraph.maximum_flow (its default method, on a CSR matrix built beforehand, so
    the building is not timed for scipy) on the same integer grids, in the same run."""
    from scipy.sparse.csgraph import maximum_flow  # optional (bench extra): only the max-flow comparison

    rows: List[Dict[str, Any]] = []
    for n in sizes:
        for case, (right, down, term) in maxflow_problems(n).items():
            t_grid, (flow, side) = best_of(lambda: graphcut.grid_min_cut(right, down, term), repeat)
            ids = np.arange(n * n).reshape(n, n)
            edges = np.concatenate([np.stack([ids[:, :-1].ravel(), ids[:, 1:].ravel()], 1),
                                    np.stack([ids[:-1].ravel(), ids[1:].ravel()], 1)])
            caps = np.concatenate([right.reshape(-1, 2), down.reshape(-1, 2)])
            t_gen, (gflow, _) = best_of(lambda: graphcut.min_cut(n * n, edges, caps, term.reshape(-1, 2)), repeat)
            m = _grid_csr(right, down, term)
            t_sp, res = best_of(lambda: maximum_flow(m, n * n, n * n + 1), repeat)
            if not flow == gflow == int(res.flow_value):
                raise RuntimeError(f"max-flow {case} {n}^2: btfrs grid {flow}, general {gflow}, scipy {res.flow_value}")
            rows.append(dict(case=case, size=n, flow=flow, btfrs_grid_s=t_grid, btfrs_graph_s=t_gen, scipy_s=t_sp,
                             ratio_grid=t_sp / t_grid, ratio_graph=t_sp / t_gen, source_side=int(side.sum())))
    return rows


def maxflow_table(rows: List[Dict[str, Any]]) -> str:
    out = [f"{'case':<13} {'size':>9} {'flow':>9} {'grid s':>8} {'graph s':>8} {'scipy s':>8} "
           f"{'scipy/grid':>10} {'scipy/graph':>11}"]
    for r in rows:
        out.append(f"{r['case']:<13} {str(r['size']) + '^2':>9} {r['flow']:>9} {r['btfrs_grid_s']:>8.3f} "
                   f"{r['btfrs_graph_s']:>8.3f} {r['scipy_s']:>8.3f} {r['ratio_grid']:>10.1f} {r['ratio_graph']:>11.1f}")
    return "\n".join(out)


def figure6(out_dir: str, material: str = "bumps", size: int = 64, out: int = 192) -> str:
    """Paper 000 Figure 6 for a built-in material: rows (neighbourhood 1, one level),
    (neighbourhood 2, one level), (neighbourhood 2, three levels); columns k = 1 and k = 5, plus
    the tiled sample on the right of each row. Seen from above under a light at 45 degrees."""
    btf = materials.make(material, size=size, seed=1)
    an = synth.analyse(btf, textons=min(1024, size * size), neighbourhoods=(1, 2), seed=0)
    light = int(np.argmin(np.abs(btf.lights[:, 2] - np.cos(np.radians(45.0)))))
    img = btf.image(0, light)
    gap = np.full((out, 6, 3), 10.0, np.float32)
    rows: List[NDArray[Any]] = []
    for n, levels in [(1, 1), (2, 1), (2, 3)]:
        cells = [synth.apply(img, synth.kcoherence(an, size=out, k=k, neighbourhood=n, levels=levels, seed=7))
                 for k in (1, 5)]
        cells.append(synth.apply(img, synth.tiled((size, size), out)))
        rows.append(np.concatenate([cells[0], gap, cells[1], gap, cells[2]], axis=1))
        rows.append(np.full((6, rows[-1].shape[1], 3), 10.0, np.float32))
    path = os.path.join(out_dir, f"figure6_{material}.png")
    io.save_image(path, np.concatenate(rows[:-1], axis=0), exposure=0.8 / max(float(np.percentile(img, 99)), 1e-6))
    return path


#: Paper 002 Table III: (set, tile side, total synthesis minutes, referenced BTFels %, GPU MB).
TABLE3 = [("FLOORTILE", 128, 33, 37.86, 186.10), ("IMPALLA", 256, 51, 49.92, 61.36), ("WRINKLES", 64, 15, 76.92, 23.64),
          ("HOLES", 100, 25, 34.86, 10.72), ("REACTDIFFUSE", 64, 16, 55.01, 16.91)]
#: Target for 16 tiles of 64^2.
TILES_TARGET_S = 10.0


def tiles_bench(repeat: int) -> Dict[str, Any]:
    """Graph-cut Wang tile sets: synthesis of 16 tiles of 64^2, 128^2 and 256^2 in the domain of
    the ``tiles`` setting (bumps; 81 x 81 directions at 128^2, 25 x 25 at 256^2 to fit in
    memory), the tiling of a 1024 x 1024 layout, render ms with a tile map and without."""
    rows: List[Dict[str, Any]] = []
    label, kind, opts, _ = settings("tiles")[0]
    b128 = materials.make("bumps", size=128, seed=3)
    m128 = fit.fit(kind, b128, **opts)
    del b128
    d25 = np.ascontiguousarray(dirs.ubo81()[::3][:25])
    b256 = materials.make("bumps", size=256, seed=3, views=d25, lights=d25)
    m256 = fit.fit(kind, b256, **opts)
    del b256
    for model, tile, edge, sample in [(m128, 64, 16, "bumps 128^2 x 81 x 81"), (m256, 128, 32, "bumps 256^2 x 25 x 25"),
                                      (m256, 256, 64, "bumps 256^2 x 25 x 25")]:
        t, ts = best_of(lambda: wang.wang(model, tile=tile, edge_height=edge, colors=2, seed=5, progress=False),
                        repeat if tile <= 64 else 1)
        r = ts.report
        rows.append(dict(tile=tile, edge_height=edge, sample=sample, domain=r["domain"], seconds=t,
                         steps={s["step"]: s["seconds"] for s in r.steps}, referenced=r["referenced"],
                         mb=r["total_bytes"] / 2**20, target_s=TILES_TARGET_S if tile == 64 else None))
        if tile == 64:
            ts64 = ts
    t_tiling, _ = best_of(lambda: ts64.tiling(1024, 1024, seed=1), repeat)
    lay = ts64.tiling(8, 8, seed=1, wrap=(True, False))
    cam = Camera.look_at([0.0, -3.2, 1.6], [0.0, 0.0, 0.0], fov_deg=40.0)
    lights = [PointLight([2.0, -2.5, 3.0], 9.0)]
    scene = Scene.cylinder(radius=1.0, height=2.0)
    render_rows = []
    try:
        cases: List[Tuple[str, Dict[str, Any]]] = [("without (uv_scale 8)", dict(uv_scale=8.0)),
                                                   ("tile map 8 x 8", dict(tiles=ts64, layout=lay))]
        for label, kw in cases:
            m: Any = ts64.model if "tiles" in kw else m128
            render(m, scene, cam, lights, size=(512, 512), **kw)
            t, _ = best_of(lambda: render(m, scene, cam, lights, size=(512, 512), **kw), repeat)
            render_rows.append(dict(case=label, ms=1000 * t))
    except TypeError as e:  # a renderer without tile maps
        render_rows.append(dict(case=f"unavailable: {e}", ms=float("nan")))
    return dict(rows=rows, tiling_1024_s=t_tiling, render=render_rows, table3=TABLE3, model=label)


def tiles_table(res: Dict[str, Any]) -> str:
    out = [f"{'tile':>5} {'edge':>4} {'sample':<22} {'seconds':>8} {'target':>7} {'corner':>7} {'edges':>6} "
           f"{'interior':>8} {'referenced':>10} {'MiB':>7}"]
    for r in res["rows"]:
        st = r["steps"]
        tgt = "-" if r["target_s"] is None else f"{r['target_s']:.0f}"
        out.append(f"{r['tile']:>5} {r['edge_height']:>4} {r['sample']:<22} {r['seconds']:>8.2f} {tgt:>7} "
                   f"{st['corner sampling']:>7.2f} {st['edge synthesis']:>6.2f} {st['interior synthesis']:>8.2f} "
                   f"{100 * r['referenced']:>9.2f}% {r['mb']:>7.2f}")
    out.append("paper 002 Table III (Pentium IV 3.2 GHz, 96 tiles, 25x25 SH): " + "; ".join(
        f"{n} {t}^2 {m} min, {p:.2f}%, {mb:.2f} MB" for n, t, m, p, mb in res["table3"]))
    out.append(f"tiling of a 1024 x 1024 layout: {1000 * res['tiling_1024_s']:.1f} ms")
    for r in res["render"]:
        out.append(f"render 512^2 cylinder, {res['model']}, {r['case']}: {r['ms']:.1f} ms")
    return "\n".join(out)


def _relief_images(size: int, lights: np.ndarray, seed: int = 1) -> np.ndarray:
    """8-bit sRGB photographs [L, size, size, 3] of a random Lambertian relief under ``lights``:
    the content of an RTI capture (smooth shading, texture), for timing decoders."""
    rng = np.random.default_rng(seed)
    f = np.fft.rfft2(rng.normal(size=(size, size)))
    ky, kx = np.meshgrid(np.fft.fftfreq(size), np.fft.rfftfreq(size), indexing="ij")
    hgt = np.fft.irfft2(f / (1e-3 + (kx ** 2 + ky ** 2)), s=(size, size))
    hgt *= 4.0 / (np.abs(hgt).max() + 1e-12)
    n = np.stack([-np.gradient(hgt, axis=1), np.gradient(hgt, axis=0), np.ones_like(hgt)], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    alb = 0.4 + 0.5 * rng.random((size, size, 3)) ** 4
    out = np.empty((len(lights), size, size, 3), np.uint8)
    for k, l in enumerate(lights):
        lin = np.clip(alb * np.clip(n @ l, 0, None)[..., None], 0, 1)
        out[k] = np.round(255 * np.where(lin <= 0.0031308, 12.92 * lin, 1.055 * lin ** (1 / 2.4) - 0.055))
    return out


def load_bench(repeat: int) -> List[Any]:
    """Load throughput of the real-data readers: MB/s of decoded float32 data (and of files read)
    for a UBO2003-style archive (6561 JPEG / PNG images, folder and zip), an RTI capture (.lp +
    200 JPEG photographs of 512^2) and the same into a memory-mapped file (``mmap_to``)."""
    from PIL import Image  # optional (bench extra): only the RTI captures

    rows: List[Dict[str, Any]] = []
    tmp = tempfile.mkdtemp(prefix="btfrs-load-")
    try:
        ubo = dirs.ubo81()
        ang = [(round(float(np.degrees(np.arccos(d[2])))), round(float(np.degrees(np.arctan2(d[1], d[0]))) % 360))
               for d in ubo]
        btf = materials.make("bumps", size=64, seed=1)
        for ext in ("jpg", "png"):
            folder = os.path.join(tmp, f"ubo_{ext}")
            os.makedirs(folder)
            i = 0
            for v, (tv, pv) in enumerate(ang):
                for l, (tl, pl) in enumerate(ang):
                    i += 1
                    lin = np.clip(btf.data[:, :, v, l], 0, 1)
                    img = np.round(255 * np.where(lin <= 0.0031308, 12.92 * lin, 1.055 * lin ** (1 / 2.4) - 0.055))
                    Image.fromarray(img.astype(np.uint8)).save(
                        os.path.join(folder, f"Bumps64_{i:05d}_tl{tl:03d}_pl{pl:03d}_tv{tv:03d}_pv{pv:03d}.{ext}"),
                        **({"quality": 95} if ext == "jpg" else {}))  # type: ignore[arg-type]
            zpath = folder + ".zip"
            with zipfile.ZipFile(zpath, "w", compression=zipfile.ZIP_STORED if ext == "jpg" else zipfile.ZIP_DEFLATED) as z:
                for n in sorted(os.listdir(folder)):
                    z.write(os.path.join(folder, n), arcname=n)
            for label, src in ((f"UBO2003 folder, 6561 {ext.upper()} 64^2", folder),
                               (f"UBO2003 zip, 6561 {ext.upper()} 64^2", zpath)):
                files = (sum(os.path.getsize(os.path.join(folder, n)) for n in os.listdir(folder)))
                t, b = best_of(lambda: io.load(src), repeat)
                rows.append({"task": label, "seconds": t, "decoded_MB": b.nbytes / 1e6, "file_MB": files / 1e6,
                             "MB_per_s": b.nbytes / 1e6 / t, "file_MB_per_s": files / 1e6 / t})
        # RTI: 200 lights on a spiral over the hemisphere (theta 5 to 75 degrees), 512^2 JPEGs
        k = np.arange(200) + 0.5
        theta = np.radians(5 + 70 * k / 200)
        phi = k * np.pi * (3 - np.sqrt(5))
        L = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=1)
        cap = os.path.join(tmp, "rti")
        os.makedirs(cap)
        imgs = _relief_images(512, L)
        lines = [str(len(L))]
        for i, (img, l) in enumerate(zip(imgs, L)):
            Image.fromarray(img).save(os.path.join(cap, f"img_{i:03d}.jpg"), quality=95)
            lines.append(f"img_{i:03d}.jpg {l[0]:.6f} {l[1]:.6f} {l[2]:.6f}")
        with open(os.path.join(cap, "capture.lp"), "w") as f:
            f.write("\n".join(lines) + "\n")
        files = sum(os.path.getsize(os.path.join(cap, n)) for n in os.listdir(cap))
        lp = os.path.join(cap, "capture.lp")
        t, b = best_of(lambda: io.load(lp), repeat)
        rows.append({"task": "RTI .lp, 200 JPEG 512^2", "seconds": t, "decoded_MB": b.nbytes / 1e6,
                     "file_MB": files / 1e6, "MB_per_s": b.nbytes / 1e6 / t, "file_MB_per_s": files / 1e6 / t})
        # the same with Pillow + numpy, the way one would assemble it by hand: decode each photo,
        # sRGB to linear by a lookup table, stack and transpose to the texel-major layout
        lut = np.where(np.arange(256) / 255 <= 0.04045, np.arange(256) / 255 / 12.92,
                       ((np.arange(256) / 255 + 0.055) / 1.055) ** 2.4).astype(np.float32)

        def by_hand() -> NDArray[np.float32]:
            st = np.stack([lut[np.asarray(Image.open(os.path.join(cap, f"img_{i:03d}.jpg")))] for i in range(len(L))])
            return np.ascontiguousarray(st.transpose(1, 2, 0, 3))[:, :, None]

        tp, arr = best_of(by_hand, repeat)
        rows.append({"task": "the same with Pillow + numpy (one thread)", "seconds": tp,
                     "decoded_MB": arr.nbytes / 1e6, "file_MB": files / 1e6, "MB_per_s": arr.nbytes / 1e6 / tp,
                     "file_MB_per_s": files / 1e6 / tp})
        out = os.path.join(tmp, "rti.btfrs")
        t, b = best_of(lambda: io.load(lp, mmap_to=out), repeat)
        rows.append({"task": "RTI .lp, 200 JPEG 512^2, mmap_to a .btfrs", "seconds": t,
                     "decoded_MB": b.nbytes / 1e6, "file_MB": files / 1e6, "MB_per_s": b.nbytes / 1e6 / t,
                     "file_MB_per_s": files / 1e6 / t})
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return rows


def load_table(rows: List[Dict[str, Any]]) -> str:
    lines = ["| capture | seconds | decoded MB | MB/s decoded | file MB/s |", "|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['task']} | {r['seconds']:.3f} | {r['decoded_MB']:.0f} | {r['MB_per_s']:.0f} | "
                     f"{r['file_MB_per_s']:.1f} |")
    return "\n".join(lines)


def out_of_core_fits() -> Dict[str, Dict[str, Any]]:
    """The kinds ``--out-of-core`` fits by default, with their options: the ``out_of_core``
    settings."""
    return {kind: opts for _, kind, opts, _ in settings("out_of_core")}


def out_of_core_bench(path: str, size: int, limit: str, kinds: Optional[Sequence[str]] = None) -> Dict[str, Any]:
    """Fit a memory-mapped BTF larger than memory under ``memory_limit``.

    Makes ``knit`` at ``size``^2 x 81 x 81 straight into ``path`` (``materials.make(out=...)``,
    streamed; kept when a file of that size is already there), then fits each model in a fresh
    interpreter (``btfrs.tools.memprobe``): wall time, bytes read from storage, and the peak anonymous
    memory above the start, against the limit plus the model."""
    made = None
    want = size * size * 81 * 81 * 3 * 4
    have = Btf.load(path, mmap=True).data.nbytes if os.path.exists(path) else None
    if have != want:
        t0 = time.perf_counter()
        materials.make("knit", size=size, seed=1, out=path, progress=True)
        made = time.perf_counter() - t0
    rows: List[Dict[str, Any]] = []
    own = out_of_core_fits()
    for kind in (kinds or list(own)):
        opts = dict(own.get(kind, {}), memory_limit=limit)
        r = subprocess.run([sys.executable, "-m", "btfrs.tools.memprobe", path, kind, json.dumps(opts)],
                           capture_output=True, text=True, check=True)
        m = json.loads(r.stdout.strip().splitlines()[-1])
        m["options"] = opts
        rows.append(m)
    mem_total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    return {"path": path, "size": size, "data_bytes": want, "memory_bytes": mem_total, "made_seconds": made,
            "limit": limit, "rows": rows}


def out_of_core_table(res: Dict[str, Any]) -> str:
    gb = 1e9
    lines = [f"{res['size']}^2 x 81 x 81 knit, {res['data_bytes'] / gb:.1f} GB on disk, "
             f"{res['memory_bytes'] / 2**30:.1f} GiB of memory, memory_limit={res['limit']}"
             + (f" (made in {res['made_seconds']:.0f} s)" if res.get("made_seconds") else ""),
             "| fit | seconds | read from storage | GB/s (storage) | GB/s (data) | peak anonymous | limit + model |",
             "|---|---|---|---|---|---|---|"]
    for r in res["rows"]:
        bound = memory_size("limit", res["limit"]) + r["model"]
        lines.append(f"| {r['kind']} {json.dumps({k: v for k, v in r['options'].items() if k != 'memory_limit'})} | "
                     f"{r['seconds']:.0f} | {r['read_bytes'] / gb:.1f} GB | {r['read_bytes'] / gb / r['seconds']:.2f} | "
                     f"{r['data'] / gb / r['seconds']:.2f} | {r['growth'] / 1e6:.0f} MB | {bound / 1e6:.0f} MB |")
    return "\n".join(lines)


def dask_fits() -> List[Tuple[str, Dict[str, Any]]]:
    """``(kind, options)`` of the ``--dask`` fits: the ``dask`` settings."""
    return [(kind, opts) for _, kind, opts, _ in settings("dask")]



def light_basis_steps(m: Any, local: Any) -> float:
    """How far apart two fits of a light basis (the models whose stages follow the ``light_pca``
    protocol) are, in 8-bit quantisation steps.

    The principal functions of each view slot are compared up to sign (the table's columns, a
    sign per slot and component), then the decoded coefficients (``bias + scale * q``, signed
    alike) texel by texel: the result is the largest difference over the coarser of the two
    steps. Two fits of the same data in different float orders project to coefficients a
    rounding apart, which can land either side of a quantisation boundary: 1 step is the most
    rounding can do; a different fit is many steps off. ``inf`` when the tables disagree."""
    x, y = m.arrays, local.arrays
    if any(x[n].shape != y[n].shape for n in ("coeffs_q", "table")) or \
            not np.array_equal(x["layout"], y["layout"]):
        return float("inf")
    nv, k = y["coeffs_q"].shape[2:]
    colour, main, chroma = (int(v) for v in y["layout"])
    w = 3 if colour == 0 else 1
    # Table columns of each plane: the mean's three, then w per main component, 2 per chroma one.
    cols = [slice(3 + w * p, 3 + w * (p + 1)) for p in range(main)]
    cols += [slice(3 + w * main + 2 * j, 5 + w * main + 2 * j) for j in range(chroma)]
    tx, ty = x["table"].astype(np.float64), y["table"].astype(np.float64)
    tol = 1e-5 * max(1.0, float(np.abs(ty).max()))
    if np.abs(tx[..., :3] - ty[..., :3]).max() > tol:
        return float("inf")
    sign = np.ones((nv, k))
    for p, c in enumerate(cols):
        fx, fy = tx[..., c].reshape(nv, -1), ty[..., c].reshape(nv, -1)
        sign[:, p] = np.where((fx * fy).sum(axis=1) < 0, -1.0, 1.0)
        if np.abs(fx * sign[:, p, None] - fy).max() > tol:
            return float("inf")
    sx, bx = x["coeffs_scale"].reshape(nv, k), x["coeffs_bias"].reshape(nv, k)
    sy, by = y["coeffs_scale"].reshape(nv, k), y["coeffs_bias"].reshape(nv, k)
    cx = (bx + sx * x["coeffs_q"].astype(np.float64)) * sign
    cy = by + sy * y["coeffs_q"].astype(np.float64)
    step = np.maximum(np.maximum(sx, sy), 1e-12)
    return float((np.abs(cx - cy) / step).max())


def _dask_agrees(kind: str, m: Any, local: Any) -> bool:
    """The cluster fit against the local one: array for array, except the light bases (the
    models whose stages follow the ``light_pca`` protocol), whose principal functions may have
    the other sign and whose coefficients, projected in another float order, may round to the
    neighbouring 8-bit code (:func:`light_basis_steps`)."""
    info = model_kinds()[kind]
    if (info["blockwise"], info["blockwise_note"]) != ("staged", "light_pca"):
        return all(np.array_equal(m.arrays[k], v) for k, v in local.arrays.items())
    return light_basis_steps(m, local) <= 1.01


def dask_bench(size: int = 96, chunks: int = 32, workdir: str = "", repeat: int = 1) -> Dict[str, Any]:
    """The same fits locally and on a Dask LocalCluster of 1 and 2 workers.

    knit ``size``^2 x 81 x 81 is made into a memory-mapped ``.btfrs`` (the local fits read it in
    place, the page cache warm) and converted to zarr by :func:`btfrs.dask.save_zarr` (tiles of
    ``chunks``^2 texels, uncompressed as by default). Each worker is one process, one thread
    and one rayon thread (``RAYON_NUM_THREADS=1``: one core, as a cluster node's slot), so the 1-
    and 2-worker rows are 1 and 2 cores; the local fit uses every core of this machine. Every
    cluster fit is checked equal, array for array, to the local one."""
    from distributed import Client, LocalCluster  # optional (dask extra): only --dask

    work = workdir or tempfile.mkdtemp(prefix="btfrs-dask-bench-")
    os.makedirs(work, exist_ok=True)
    path, zpath = os.path.join(work, f"knit{size}.btfrs"), os.path.join(work, f"knit{size}.zarr")
    try:
        b = materials.make("knit", size=size, seed=1, out=path)
        t0 = time.perf_counter()
        bd.save_zarr(b, zpath, chunks=chunks, overwrite=True)
        save_s = time.perf_counter() - t0
        zbytes = sum(os.path.getsize(os.path.join(d, f)) for d, _, fs in os.walk(zpath) for f in fs)
        b = Btf.load(path, mmap=True)
        rows: List[Dict[str, Any]] = []
        local = {}
        fits = dask_fits()
        for kind, o in fits:
            fit.fit(kind, b, **o)  # warm the page cache
            secs, m = best_of(lambda: fit.fit(kind, b, **o), repeat)
            local[kind] = m
            rows.append({"kind": kind, "options": o, "local_s": secs})
        # The same local fits on one core (a fresh interpreter with one rayon thread): the
        # cluster's overhead at equal cores is dask1_s / local1_s.
        code = ("import json, sys, time; import btfrs; from btfrs import fit; from btfrs.btf import Btf; "
                "b = Btf.load(sys.argv[1], mmap=True); out = {}\n"
                "for kind, o in json.loads(sys.argv[2]):\n"
                "    fit.fit(kind, b, **o); best = 1e9\n"
                "    for _ in range(int(sys.argv[3])):\n"
                "        t0 = time.perf_counter(); fit.fit(kind, b, **o); best = min(best, time.perf_counter() - t0)\n"
                "    out[kind] = best\n"
                "print(json.dumps(out))")
        proc = subprocess.run([sys.executable, "-c", code, path, json.dumps(fits), str(repeat)], check=True,
                           capture_output=True, text=True, env={**os.environ, "RAYON_NUM_THREADS": "1"})
        one = json.loads(proc.stdout.strip().splitlines()[-1])
        for row in rows:
            row["local1_s"] = one[row["kind"]]
        for n in (1, 2):
            with LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                              silence_logs=logging.CRITICAL, env={"RAYON_NUM_THREADS": "1"}) as cluster, \
                    Client(cluster):
                arr = bd.open(zpath)
                warm_kind, warm_opts = fits[0]
                bd.fit(warm_kind, bd.from_btf(Btf(b.data[:8, :8].copy(), b.views, b.lights), chunks=8),
                       **warm_opts)  # warm the workers
                for r, (kind, o) in zip(rows, fits):
                    secs, m = best_of(lambda: bd.fit(kind, arr, **o), repeat)
                    same = _dask_agrees(kind, m, local[kind])
                    r[f"dask{n}_s"], r[f"dask{n}_equal"] = secs, bool(same)
        return {"size": size, "chunks": chunks, "data_bytes": b.data.nbytes, "zarr_bytes": zbytes,
                "save_zarr_s": save_s, "rows": rows}
    finally:
        if not workdir:
            shutil.rmtree(work, ignore_errors=True)


def dask_table(res: Dict[str, Any]) -> str:
    gb = res["data_bytes"] / 1e9
    lines = [f"knit {res['size']}^2 x 81 x 81, {gb:.2f} GB of values; zarr tiles {res['chunks']}^2 texels, "
             f"{res['zarr_bytes'] / 1e9:.2f} GB on disk, written by save_zarr in {res['save_zarr_s']:.1f} s "
             f"({gb / res['save_zarr_s']:.2f} GB/s)",
             "| fit | local, 1 core | local, 2 cores | Dask, 1 worker | Dask, 2 workers | GB/s: Dask 1 / 2 workers | "
             "1 -> 2 workers | Dask / local at 1 core | at 2 cores | equal to local |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in res["rows"]:
        l1, lo, d1, d2 = r["local1_s"], r["local_s"], r["dask1_s"], r["dask2_s"]
        lines.append(f"| {r['kind']} {json.dumps(r['options'])} | {l1:.2f} s | {lo:.2f} s | {d1:.2f} s | {d2:.2f} s | "
                     f"{gb / d1:.2f} / {gb / d2:.2f} | {d1 / d2:.2f}x | {d1 / l1:.2f}x | {d2 / lo:.2f}x | "
                     f"{'yes' if r['dask1_equal'] and r['dask2_equal'] else 'NO'} |")
    return "\n".join(lines)


# --- a model against every other model (the against_all settings) ----------------------------

def against_all_kinds() -> List[str]:
    """The kinds with an ``against_all`` setting: each has a ``--KIND-only`` mode."""
    return list(dict.fromkeys(kind for _, kind, _, _ in settings("against_all")))


def against_all_bench(kind: str, size: int = 64, materials_: Optional[Sequence[str]] = None) -> Dict[str, Any]:
    """Model ``kind``'s targets against every other registered model (BENCHMARKS.md), in one run:

    * per built-in material at ``size``^2 x 81 x 81, :func:`btfrs.evaluation.evaluate` of every
      registered model over its full sweep, 10% held out, both protocols (random pairs, whole
      directions): the best row of the other models per protocol, ``kind``'s rows, whether one of
      them is at most the best other error in at most 1/20 of its bytes, and whether its
      ``against_all`` setting is on the (bytes, held-out error) Pareto front;
    * single-view captures (each material seen from above under the 81 UBO lights, 20% of the
      lights held out): its ``against_all`` setting against the ``single_view_reference`` ones;
    * render: a 512^2 sphere, one light, every setting of its sweep against the reference."""
    names = list(materials_ or materials.names())
    info = model_kinds()[kind]
    default, _, own_opts, _ = next(x for x in settings("against_all") if x[1] == kind)
    out: Dict[str, Any] = {"kind": kind, "size": size, "materials": [], "single_view": [], "render": []}
    for name in names:
        btf = materials.make(name, size=size, seed=1)
        rep = evaluation.evaluate(btf, "all", holdout="both", fraction=0.1, sweep="full", render=False,
                                  material=f"{name} {size}^2")
        rows: List[Dict[str, Any]] = [{k: r.get(k) for k in ("label", "kind", "bytes", "fit_s", "reconstruction",
                                                              "heldout_pairs", "heldout_directions")} for r in rep.rows]
        res: Dict[str, Any] = {"material": name, "rows": rows}
        for proto in ("heldout_pairs", "heldout_directions"):
            ok = [r for r in rows if r.get(proto) is not None and r.get("bytes")]
            other = min((r for r in ok if r.get("kind") != kind), key=lambda r: float(r[proto]))
            mine = [r for r in ok if r.get("kind") == kind]
            within = [r for r in mine if r[proto] <= other[proto] and r["bytes"] * 20 <= other["bytes"]]
            front = {r["label"] for r in evaluation.pareto_front(ok, proto, "bytes")}
            res[proto] = {"best_other": other, "mine": mine, "met": [r["label"] for r in within],
                          "default_on_front": default in front}
        out["materials"].append(res)
        print(f"  {name}: done", file=sys.stderr)
    ubo = materials.make("knit", size=8, seed=1).lights
    pair = [(default, kind, own_opts)] + [(label, k, opts) for label, k, opts, _ in settings("single_view_reference")]
    for name in names:
        btf = materials.make(name, size=size, seed=1, views=np.array([[0.0, 0.0, 1.0]]), lights=ubo)
        train, test = btf.split(holdout=0.2, seed=0)
        row: Dict[str, Any] = {"material": name}
        for label, k, opts in pair:
            t0 = time.perf_counter()
            m = fit.fit(k, train, **opts)
            row[label] = {"bytes": m.nbytes, "fit_s": time.perf_counter() - t0,
                          "heldout": m.error(test).relative, "form": getattr(m, "directions", None)}
        out["single_view"].append(row)
    btf = materials.make("knit", size=size, seed=1)
    ref_label, ref_kind, ref_opts, _ = reference()
    ms, _ = _render_ms(fit.fit(ref_kind, btf, **ref_opts))
    out["render"].append({"label": ref_label, "ms": ms, "ratio": 1.0})
    for label, opts, _, _ in info["sweep"]:
        m = fit.fit(kind, btf, **opts)
        t, _ = _render_ms(m)
        out["render"].append({"label": label, "ms": t, "ratio": t / ms, "bytes": m.nbytes})
    out["adapter"] = rendering_info()
    return out


def _pct(x: float) -> str:
    return f"{100 * x:.2f}%"


def against_all_table(res: Dict[str, Any]) -> str:
    pct, kind = _pct, res["kind"]
    lines = [f"accuracy per byte at {res['size']}^2 x 81 x 81, 10% held out (seed 0):",
             f"| material | protocol | best other model | its bytes | {kind} rows (error, bytes) | "
             "<= its error in <= 1/20 bytes | default on the front |",
             "|---|---|---|---|---|---|---|"]
    for m in res["materials"]:
        for proto in ("heldout_pairs", "heldout_directions"):
            r = m[proto]
            c = r["best_other"]
            ns = "; ".join(f"{n['label']} {pct(n[proto])} {n['bytes'] / 1e3:.0f} KB" for n in r["mine"])
            lines.append(f"| {m['material']} | {proto.split('_')[1]} | {c['label']} {pct(c[proto])} | {c['bytes'] / 1e6:.2f} MB | "
                         f"{ns} | {', '.join(r['met']) or 'no'} | {'yes' if r['default_on_front'] else 'no'} |")
    labels = [k for k in (res["single_view"][0] if res["single_view"] else {}) if k != "material"]
    lines += ["", "single view (81 lights, 20% held out):", "| material | " + " | ".join(labels) + " |",
              "|---|" + "---|" * len(labels)]
    for r in res["single_view"]:
        cells = []
        for k, v in r.items():
            if k != "material":
                cells.append(f"{pct(v['heldout'])} in {v['bytes'] / 1e3:.1f} KB ({v['fit_s']:.1f} s)")
        lines.append(f"| {r['material']} | " + " | ".join(cells) + " |")
    ref = res["render"][0]["label"] if res["render"] else ""
    lines += ["", f"render, 512^2 sphere, one light, {res.get('adapter', '')}:"]
    lines += [f"  {r['label']:<10} {r['ms']:8.1f} ms  {r['ratio']:5.2f}x {ref}" for r in res["render"]]
    return "\n".join(lines)


def main(argv: Optional[Sequence[str]] = None) -> int:
    p = argparse.ArgumentParser(prog="python -m btfrs.tools.bench", description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--size", type=int, action="append", help="material sizes (default: 32 and 64; 32 with --accuracy)")
    p.add_argument("--repeat", type=int, default=3, help="runs per figure; the best is kept (default: 3)")
    p.add_argument("--json", help="where to write the JSON (default: bench.json, or accuracy.json with --accuracy, "
                                  "in the --figures directory or bench-results)")
    p.add_argument("--skip-models", action="store_true", help="only the foundation and renderer figures")
    big = settings("big")
    for label, kind, _, b in big:
        p.add_argument(f"--{kind.replace('_', '-')}-big", dest=f"big_{kind}", action="store_true",
                       help=f"also time {label} on a 128^2 x 81 x 81 sample ({b['note']})")
    p.add_argument("--synth-only", action="store_true", help="only the synthesis figures")
    p.add_argument("--robust-only", action="store_true",
                   help="only robust against plain fits of every model: time on clean data, error with 0.1%% hot values")
    p.add_argument("--maxflow-only", action="store_true",
                   help="only btfrs.graphcut against scipy's maximum_flow on integer grids")
    p.add_argument("--maxflow-size", type=int, action="append",
                   help=f"grid sides of the max-flow figures (default: {' and '.join(map(str, MAXFLOW_SIZES))})")
    p.add_argument("--tiles-only", action="store_true", help="only the Wang tile figures")
    p.add_argument("--load-only", action="store_true",
                   help="only the load throughput of the real-data readers (UBO archives, RTI .lp sets)")
    p.add_argument("--accuracy", action="store_true",
                   help="only the accuracy of every model on every material (at --size, default 32)")
    p.add_argument("--rti-only", action="store_true",
                   help="only the single-view RTI captures: every light basis against bytes (charts in docs/rti)")
    p.add_argument("--env-only", action="store_true",
                   help="only the per-model frame times: point light, trilinear, environment")
    ref_label = reference()[0]
    p.add_argument("--frames-only", action="store_true",
                   help="only the one-light frame of every example of every model and renderer, against "
                        f"{ref_label}'s (the 3x target)")
    mitsuba = [k for k, info in model_kinds().items() if "mitsuba" in info["exports"]]
    p.add_argument("--export-check", action="store_true",
                   help=f"only the Mitsuba export check: the {' or '.join(mitsuba)} model fitted to bumps (--size, "
                   "default 64), exported, rendered by Mitsuba 3 and by btfrs, compared (with --figures: "
                   "mitsuba_export.png)")
    p.add_argument("--ground-truth", action="store_true",
                   help="only the path-traced ground truth (Mitsuba 3): a BTF measured from a heightfield, "
                        "rendered on a plane, against the path trace of the heightfield")
    ooc = ",".join(out_of_core_fits())
    p.add_argument("--out-of-core", metavar="PATH",
                   help="only the out-of-core fits: make knit at --size (default 640)^2 x 81 x 81 into PATH "
                        "(32.2 GB at 640) unless it is there, fit --out-of-core-fits under --memory-limit")
    p.add_argument("--memory-limit", default="2GB", help="the out-of-core fits' memory_limit (default: 2GB)")
    p.add_argument("--out-of-core-fits", default=ooc, metavar="KINDS",
                   help=f"the models --out-of-core fits, comma-separated (default: {ooc})")
    p.add_argument("--dask", action="store_true",
                   help=f"only the Dask fits: {', '.join(dict.fromkeys(k for k, _ in dask_fits()))} locally and on "
                        "a LocalCluster of 1 and 2 workers, knit at --size (default 96)^2 x 81 x 81 from zarr "
                        "(needs btfrs[dask])")
    p.add_argument("--dask-chunks", type=int, default=32, help="the zarr tiles' side in texels (default: 32)")
    p.add_argument("--viewer-only", action="store_true",
                   help="only the browser viewer's frame and load times against the native renderer (needs "
                        "/usr/bin/chromium and playwright); --figures DIR also saves a screenshot")
    p.add_argument("--normals-only", action="store_true",
                   help="only photometric stereo (512^2 x 240 lights by default) against numpy's least squares")
    for kind in against_all_kinds():
        p.add_argument(f"--{kind.replace('_', '-')}-only", dest=f"only_{kind}", action="store_true",
                       help=f"only the {kind} model's figures: accuracy per byte against every model on every "
                            "material (both protocols), single-view captures, render time")
    p.add_argument("--figures", metavar="DIR", help="also write paper 000 Figure 6 style images into DIR")
    a = p.parse_args(argv)
    res: Any  # each mode's results
    if a.dask:
        res = dask_bench((a.size or [96])[0], a.dask_chunks, repeat=a.repeat)
        print(dask_table(res))
        if a.json is None:
            a.json = os.path.join("bench-results", "dask.json")
        _write_json(a.json, {"machine": machine(), "dask": res})
        print(f"\nwrote {a.json}", file=sys.stderr)
        return 0
    if a.out_of_core:
        res = out_of_core_bench(a.out_of_core, (a.size or [640])[0], a.memory_limit,
                                [k.strip() for k in a.out_of_core_fits.split(",") if k.strip()])
        print(out_of_core_table(res))
        if a.json is None:
            a.json = os.path.join("bench-results", "out_of_core.json")
        _write_json(a.json, {"machine": machine(), "out_of_core": res})
        print(f"\nwrote {a.json}", file=sys.stderr)
        return 0
    if a.json is None:
        a.json = os.path.join(a.figures or "bench-results", "accuracy.json" if a.accuracy else "bench.json")
    if a.ground_truth:
        res = groundtruth.check(progress=True)
        print(f"ground truth: woven heightfield measured by path tracing ({res['texels']}^2 texels, 81 x 81 "
              f"directions, {res['measure_spp']} spp) rendered by btfrs ({res['backend']}) on a plane at "
              f"uv_scale {res['uv_scale']}, against the path-traced heightfield ({res['size']}^2, "
              f"{res['render_spp']} spp):")
        print(groundtruth.table(res))
        print("seconds: " + ", ".join(f"{k} {v:.1f}" for k, v in res["seconds"].items()))
        if a.figures:
            os.makedirs(a.figures, exist_ok=True)
            print(f"wrote {groundtruth.figure(res, os.path.join(a.figures, 'ground_truth.png'))}")
        return _write_check(a.json, "ground_truth", res)
    if a.export_check:
        mat, size = "bumps", (a.size or [64])[0]
        btf = materials.make(mat, size=size, seed=0)
        t0 = time.perf_counter()
        model = fit.fit(mitsuba[0], btf)
        fit_s = time.perf_counter() - t0
        res = groundtruth.check_export(model, size=192, supersample=4, spp=512)
        print(f"Mitsuba 3 export: {mitsuba[0]} fitted to {mat} {size}^2 ({fit_s:.2f} s), exported as a Mitsuba scene and "
              f"rendered by Mitsuba ({res['spp']} spp, box filter) and by btfrs ({res['backend']}, "
              f"{res['supersample']}^2 pixel centres averaged), {res['size']}^2, maps looked up by nearest texel:")
        print("| light | sample | brightness (btfrs / Mitsuba) | PSNR |\n|---|---|---|---|")
        for r in res["rows"]:
            print(f"| {r['light']} | {r['case']} | {r['brightness']:.4f} | {r['psnr']:.1f} dB |")
        print("seconds: " + ", ".join(f"{k} {v:.2f}" for k, v in res["seconds"].items()))
        if a.figures:
            os.makedirs(a.figures, exist_ok=True)
            first = dirs.from_theta_phi(40.0, 60.0, degrees=True).reshape(3)
            top = int(np.argmax(btf.views[:, 2]))
            capture = btf.data[:, :, top, int(np.argmax(btf.lights @ first))]
            path = os.path.join(a.figures, "mitsuba_export.png")
            print(f"wrote {groundtruth.export_figure(res, model.arrays, path, capture=capture)}")
        return _write_check(a.json, "export_check", res)
    for kind in against_all_kinds():
        if getattr(a, f"only_{kind}"):
            res = against_all_bench(kind, size=(a.size or [64])[0])
            print(against_all_table(res))
            return _finish(a, {"machine": machine(), kind: res})
    if a.robust_only:
        size, rep = (a.size or [64])[0], max(1, a.repeat)
        res = robust_bench(size=size, repeat=rep)
        print(f"robust against plain fits (knit {size}^2 x 81 x 81, best of {rep}, interleaved; errors held out):")
        print(robust_table(res))
        return _finish(a, {"machine": machine(), "robust": res})
    if a.normals_only:
        res = normals_bench(size=(a.size or [512])[0], repeat=max(1, a.repeat))
        print(f"photometric stereo, {res['size']}^2 texels x {res['lights']} lights, one view, best of "
              f"{max(1, a.repeat)} (interleaved):")
        print(normals_table(res))
        return _finish(a, {"machine": machine(), "normals": res})
    if a.viewer_only:
        res = viewer_bench(size=(a.size or [64])[0], repeat=max(1, a.repeat), figures=a.figures)
        print(f"the browser viewer (Chromium {_chromium_version()}, WebGPU on SwiftShader) against the native "
              f"renderer ({rendering_info()}), knit {(a.size or [64])[0]}^2 x 81 x 81, best of {max(1, a.repeat)}:")
        print(viewer_table(res))
        return _finish(a, {"machine": machine(), "viewer": res})
    if a.frames_only:
        res = frames_bench(size=(a.size or [32])[0], repeat=max(1, a.repeat))
        print(f"frame times on {rendering_info()} (knit {(a.size or [32])[0]}^2, uv_scale 4, best of {max(1, a.repeat)}):")
        print(frames_table(res))
        return _finish(a, {"machine": machine(), "frames": res})
    if a.env_only:
        res = env_bench(size=(a.size or [64])[0], repeat=max(1, a.repeat))
        print(f"frame times on {rendering_info()} (knit {(a.size or [64])[0]}^2, uv_scale 4, best of {max(1, a.repeat)}):")
        print(env_table(res))
        return _finish(a, {"machine": machine(), "env": res})
    if a.rti_only:
        res = rti_bench(size=(a.size or [RTI_SIZE])[0])
        for c in res:
            print(f"\n{c['capture']} ({c['size']}^2, {100 * RTI_HOLDOUT:.0f}% of the lights held out, seed 0):")
            print(c["table"])
            print(f"chart: {c['chart']}")
        print()
        print(rti_summary(res))
        return _finish(a, {"machine": machine(), "rti": res})
    if a.accuracy:
        out: Dict[str, Any] = {"machine": machine(), "accuracy_models": []}
        for size in a.size or [32]:
            rows = accuracy_models(size)
            print(f"accuracy of every model at {size}^2, 10% of the pairs held out (seed 0):")
            print(accuracy_models_table(rows))
            out["accuracy_models"].extend(rows)
        return _finish(a, out)
    mf_sizes = a.maxflow_size or list(MAXFLOW_SIZES)
    mf_title = "\nmax-flow / min-cut on integer grids, btfrs.graphcut against scipy maximum_flow (ratio = scipy / btfrs):"
    if a.maxflow_only:
        mf = maxflow_bench(max(1, a.repeat), mf_sizes)
        print(mf_title.lstrip("\n"))
        print(maxflow_table(mf))
        return _finish(a, {"machine": machine(), "maxflow": mf})
    sizes = a.size or [32, 64]
    if a.load_only:
        ld = load_bench(max(1, a.repeat))
        print("loading measured data into a Btf (best of --repeat; decoded = float32 bytes of the Btf):")
        print(load_table(ld))
        return _finish(a, {"machine": machine(), "load": ld})
    if a.tiles_only:
        res = tiles_bench(max(1, a.repeat))
        print(f"graph-cut Wang tile sets, 16 tiles, 2 colours per edge direction, {settings('tiles')[0][0]} domain:")
        print(tiles_table(res))
        return _finish(a, {"machine": machine(), "tiles": res})
    if a.synth_only:
        res = synth_bench(max(1, a.repeat))
        print(f"synthesis (paper 000 Table 1 settings, 3 levels) on {res['material']} {res['sample']}^2:")
        print(synth_table(res))
        out = {"machine": machine(), "synthesis": res}
        return _finish(a, out)
    rows = run(sizes, max(1, a.repeat))
    print(table(rows))
    acc = accuracy(max(sizes))
    print(f"\naccuracy at {max(sizes)}^2, 10% of the pairs held out (seed 0):")
    print(accuracy_table(acc))
    ren = render_bench(max(1, a.repeat))
    print(f"\nrendering a sphere (64^2 knit, uv_scale 4, 1 point light) on {ren[0]['adapter']}:")
    print(render_table(ren))
    out = {"machine": machine(), "speed": rows, "accuracy": acc, "render": ren}
    if not a.skip_models:
        mb = models_bench(max(sizes))
        print(f"\nevery model on knit {max(sizes)}^2 (10% held out), beside the numpy / scipy / scikit-learn way:")
        print(models_table(mb))
        lr = renderers_bench(max(sizes), max(1, a.repeat))
        notes = "; ".join(dict.fromkeys(r["note"] for r in lr if r["note"]))
        print(f"\nrenderers of one model against each other ({notes}) on {ren[0]['adapter']}:")
        print(renderers_table(lr))
        sw = reach_sweep(min(max(sizes), 32))
        targets = "; ".join(dict.fromkeys(b["note"] for _, _, _, b in settings("reach") if b["note"]))
        print(f"\nreaching {100 * REACH:.0f}% reconstruction error ({min(max(sizes), 32)}^2 samples; {targets}):")
        print(reach_table(sw))
        am = accuracy_models(min(max(sizes), 32))
        print(f"\naccuracy of every model at {min(max(sizes), 32)}^2, 10% of the pairs held out (seed 0):")
        print(accuracy_models_table(am))
        out.update(models=mb, renderers=lr, reach=sw, accuracy_models=am)
    res = synth_bench(max(1, a.repeat))
    print(f"\nsynthesis (paper 000 Table 1 settings, 3 levels) on {res['material']} {res['sample']}^2:")
    print(synth_table(res))
    out["synthesis"] = res
    mf = maxflow_bench(max(1, a.repeat), mf_sizes)
    print(mf_title)
    print(maxflow_table(mf))
    out["maxflow"] = mf
    for label, kind, opts, b in big:
        if getattr(a, f"big_{kind}"):
            sample = materials.make("knit", size=128, seed=1)
            t, _ = best_of(lambda: fit.fit(kind, sample, **opts), 1)
            out[f"{kind}_big"] = {"task": f"{label}, 128^2 x 81 x 81", "seconds": t, "target": b["note"]}
            print(f"\n{label} on 128^2 x 81 x 81: {t:.2f} s ({b['note']})")
    return _finish(a, out)


def _finish(a: argparse.Namespace, out: Dict[str, Any]) -> int:
    """Write the Figure 6 images (``--figures``) and the JSON."""
    if a.figures and not a.accuracy:
        os.makedirs(a.figures, exist_ok=True)
        for mat in ("bumps", "knit"):
            print(f"wrote {figure6(a.figures, mat)}")  # io.save_image writes atomically
    _write_json(a.json, out)
    print(f"\nwrote {a.json}", file=sys.stderr)
    return 0


def _write_check(path: str, key: str, res: Dict[str, Any]) -> int:
    """Write a Mitsuba check's result (its images left out) as ``path``'s JSON under ``key``."""
    res.pop("images")
    _write_json(path, {"machine": machine(), key: res})
    print(f"\nwrote {path}", file=sys.stderr)
    return 0


def _write_json(path: str, obj: Any) -> None:
    """Write ``obj`` as JSON to ``path`` atomically: a temporary file in the same directory (so the
    rename cannot cross file systems), synced, then ``os.replace`` over ``path``. An interrupted or
    failing run leaves the previous results whole and no temporary file behind."""
    target = os.path.abspath(path)
    os.makedirs(os.path.dirname(target), exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=os.path.dirname(target), prefix=f".{os.path.basename(target)}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            json.dump(obj, f, indent=2, default=float)
            f.flush()
            os.fsync(f.fileno())
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes the file 0600; give it an ordinary file's mode
        os.replace(tmp, target)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


if __name__ == "__main__":
    sys.exit(main())
