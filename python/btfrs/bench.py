"""End-to-end benchmarks: ``python -m btfrs.bench [--size 64] [--json PATH]``.

Every btfrs figure is measured in the same run as the plain numpy way of doing the same work,
so the ratios do not depend on the machine's mood; the table goes to stdout and everything,
with the machine description, to a JSON file.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from datetime import datetime, timezone
from typing import Callable

import numpy as np

from . import __version__, baselines, fit, materials


def best_of(fn: Callable[[], object], repeat: int) -> tuple[float, object]:
    """Minimum wall time of ``repeat`` calls (the least disturbed run) and the last result."""
    best, out = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def machine() -> dict:
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


def run(sizes: list, repeat: int) -> list:
    rows = []
    for size in sizes:
        t_gen, btf = best_of(lambda: materials.make("knit", size=size, seed=1), repeat)
        rows.append(dict(task=f"material knit {size}^2 x 81 x 81", btfrs_s=t_gen, numpy_s=None,
                         target="64^2 < 5 s", note=f"{btf.nbytes / 2**20:.0f} MiB"))
        train, _ = btf.split(0.1, seed=0)
        t_np, ref = best_of(lambda: baselines.ptm_rgb_numpy(train), repeat)
        t_rgb, ptm = best_of(lambda: fit.ptm(train, kind="rgb"), repeat)
        diff = float(np.max(np.abs(ptm.coeffs - ref)) / np.max(np.abs(ref)))
        rows.append(dict(task=f"PTM-RGB fit {size}^2", btfrs_s=t_rgb, numpy_s=t_np, target=">= 3x numpy, 1e-4 rel.",
                         note=f"max coeff diff {diff:.1e} (rel. to max)"))
        t_lrgb, _ = best_of(lambda: fit.ptm(train, kind="lrgb"), repeat)
        rows.append(dict(task=f"PTM-LRGB fit {size}^2", btfrs_s=t_lrgb, numpy_s=None, target="", note=""))
        # One pass over the same bytes: the floor a fit "bounded by reading the data once" is held to.
        t_read, _ = best_of(lambda: float(np.add.reduce(train.data, axis=None, dtype=np.float64)), repeat)
        rows.append(dict(task=f"numpy sum over the data {size}^2", btfrs_s=None, numpy_s=t_read, target="", note="read-once floor (numpy)"))
    return rows


def render_bench(repeat: int) -> list:
    """ms per frame on this machine's adapter: raw BTF and PTM-RGB, 512^2 and 1024^2, with and
    without a coordinate map; draw and read-back timed separately (the first, pipeline-compiling
    frame is not counted)."""
    from . import rendering

    btf = materials.make("knit", size=64, seed=1)
    ptm = fit.ptm(btf, kind="rgb")
    scene = rendering.Scene.sphere()
    cam = rendering.Camera.look_at([0, -3, 2], [0, 0, 0], 40)
    lights = [rendering.PointLight([2.0, -2.0, 3.0], 8.0)]
    rng = np.random.default_rng(0)
    cmap = rng.integers(0, 64, size=(256, 256, 2)).astype(np.uint16)
    rows = []
    for name, model in (("raw", btf), ("PTM-RGB", ptm)):
        for size in (512, 1024):
            for coords in (None, cmap):
                rendering.render(model, scene, cam, lights, size=size, uv_scale=4, coords=coords)  # warm-up
                best = None
                for _ in range(repeat):
                    rendering.render(model, scene, cam, lights, size=size, uv_scale=4, coords=coords)
                    t = rendering.last_timings()
                    best = t if best is None or t.draw_ms < best.draw_ms else best
                rows.append(dict(model=name, size=size, coords=coords is not None, draw_ms=best.draw_ms,
                                 readback_ms=best.readback_ms, adapter=rendering.gpu_info()))
    return rows


def render_table(rows: list) -> str:
    out = [f"{'model':<8} {'size':>6} {'map':>4} {'draw ms':>9} {'read-back ms':>13}"]
    for r in rows:
        out.append(f"{r['model']:<8} {r['size']:>6} {'yes' if r['coords'] else 'no':>4} {r['draw_ms']:>9.1f} {r['readback_ms']:>13.1f}")
    return "\n".join(out)


def accuracy(size: int) -> list:
    """Held-out and reconstruction error of every model on every built-in material, beside the
    raw-data baseline (3 nearest measured lights of the same view slot)."""
    rows = []
    for name in materials.names():
        btf = materials.make(name, size=size, seed=1)
        train, test = btf.split(0.1, seed=0)
        rel, _ = baselines.nearest_lights_interpolation(train, test)
        rows.append(dict(material=name, model="raw, 3 nearest lights", nbytes=btf.nbytes, reconstruction=None, held_out=rel))
        for kind in ("rgb", "lrgb"):
            m = fit.ptm(train, kind=kind)
            rows.append(dict(material=name, model=f"PTM-{kind.upper()}", nbytes=m.nbytes,
                             reconstruction=m.error(train).relative, held_out=m.error(test).relative))
    return rows


def accuracy_table(rows: list) -> str:
    out = [f"{'material':<9} {'model':<22} {'MiB':>8} {'reconstruction':>15} {'held-out':>9}"]
    for r in rows:
        rec = "exact" if r["reconstruction"] is None else f"{100 * r['reconstruction']:.2f}%"
        out.append(f"{r['material']:<9} {r['model']:<22} {r['nbytes'] / 2**20:>8.2f} {rec:>15} {100 * r['held_out']:>8.2f}%")
    return "\n".join(out)


def table(rows: list) -> str:
    out = [f"{'task':<36} {'btfrs s':>9} {'numpy s':>9} {'speed-up':>9}  {'target':<24} note"]
    for r in rows:
        b = "" if r["btfrs_s"] is None else f"{r['btfrs_s']:.4f}"
        n = "" if r["numpy_s"] is None else f"{r['numpy_s']:.4f}"
        s = f"{r['numpy_s'] / r['btfrs_s']:.1f}x" if r["btfrs_s"] and r["numpy_s"] else ""
        out.append(f"{r['task']:<36} {b:>9} {n:>9} {s:>9}  {r['target']:<24} {r['note']}")
    return "\n".join(out)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m btfrs.bench", description=__doc__)
    p.add_argument("--size", type=int, action="append", help="material sizes (default: 32 and 64)")
    p.add_argument("--repeat", type=int, default=3, help="runs per figure; the best is kept (default: 3)")
    p.add_argument("--json", default="bench-results/bench.json", help="where to write the JSON")
    a = p.parse_args(argv)
    sizes = a.size or [32, 64]
    rows = run(sizes, max(1, a.repeat))
    print(table(rows))
    acc = accuracy(max(sizes))
    print(f"\naccuracy at {max(sizes)}^2, 10% of the pairs held out (seed 0):")
    print(accuracy_table(acc))
    ren = render_bench(max(1, a.repeat))
    print(f"\nrendering a sphere (64^2 knit, uv_scale 4, 1 point light) on {ren[0]['adapter']}:")
    print(render_table(ren))
    os.makedirs(os.path.dirname(a.json) or ".", exist_ok=True)
    with open(a.json, "w") as f:
        json.dump({"machine": machine(), "speed": rows, "accuracy": acc, "render": ren}, f, indent=2)
    print(f"\nwrote {a.json}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
