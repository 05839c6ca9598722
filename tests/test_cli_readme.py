import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import btfrs
from btfrs.cli import main



def test_demo_writes_images_and_a_summary_with_numbers(tmp_path, capsys):
    # The quick demo (the default), every step, at 16^2.
    assert main(["demo", "--out", str(tmp_path), "--size", "16", "--quiet"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("btfrs demo, quick run on knit 16^2") and "done in" in out
    summary = (tmp_path / "summary.md").read_text()
    # One row per registered model, at the registry's quick setting, and the raw-data baseline.
    quick = {kind: next(s for s in info["sweep"] if s[2]) for kind, info in btfrs.model_kinds().items()}
    rows = {m.group(1): m for m in re.finditer(
        r"^\| ([^|]+) \| ([\d.]+) \| ([\d.]+) MiB \| 1:([\d.]+) \| ([\d.]+)% \| ([\d.]+)% \|", summary, re.M)}
    assert set(rows) == {s[0] for s in quick.values()}
    # The table's numbers are the saved models' own: their bytes, and their held-out error
    # measured again here on the demo's split (10% of the pairs, seed 0).
    btf = btfrs.materials.make("knit", size=16, seed=1)
    train, test = btf.split(holdout=0.1, seed=0)
    for label in rows:
        slug = label.lower().replace(" ", "_").replace("+", "_").replace("-", "_").replace("/", "_")
        m = btfrs.load(tmp_path / f"model_{slug}.btfrs")
        assert float(rows[label].group(3)) == pytest.approx(m.nbytes / 2**20, abs=0.006), label
        assert float(rows[label].group(6)) == pytest.approx(100 * m.error(test).relative, abs=0.006), label
    pngs = sorted(p.name for p in tmp_path.glob("*.png"))
    assert {"materials.png", "render.png", "environment.png", "filtering.png", "synthesis_render.png",
            "tiles.png", "tiles_render.png"} <= set(pngs)
    assert len([p for p in pngs if p.startswith("compare_")]) == 3
    img = btfrs.io.load_image(tmp_path / "materials.png")
    assert img.shape[0] == 4 * 16 * 3 and img.std() > 0.05  # four materials, not a blank image
    back = btfrs.load(tmp_path / "ptm_rgb_top.ptm")
    assert back.height == 16
    # One tile set at the default tile size (here the whole 16^2 sample).
    ts = btfrs.load(tmp_path / "tiles_knit.btfrs")
    assert ts.n_tiles == 16 and ts.tile == 16
    # The speed-against-accuracy chart and report, from the demo's own fits: a row per model.
    ev = json.loads((tmp_path / "evaluate" / "report.json").read_text())
    assert {r["kind"] for r in ev["rows"]} == set(btfrs.model_kinds()) | {"raw"}
    assert {p.name for p in (tmp_path / "evaluate").glob("*.png")} == {
        "heldout_vs_bytes.png", "heldout_vs_render_ms.png", "heldout_vs_fit_s.png"}
    assert "Speed against accuracy" in summary and "btfrs demo --full" in summary


def test_the_full_demo_fits_every_example():
    # --full (too long for the suite: README) fits every example of every model where the quick
    # run fits one setting per model; the steps are otherwise the same.
    from btfrs.tools import demo

    kinds = btfrs.model_kinds()
    ctx = demo.Context(out=Path("unused"), material="knit", size=16, seed=1, progress=False, log=print, full=True)
    assert [s[0] for s in demo._settings(ctx)] == [lab for info in kinds.values() for lab, _ in info["examples"]]
    ctx.full = False
    assert [(s[0], s[1]) for s in demo._settings(ctx)] == [
        (next(s for s in info["sweep"] if s[2])[0], kind) for kind, info in kinds.items()]


def test_cli_reports_errors_without_a_traceback(tmp_path):
    r = subprocess.run([sys.executable, "-m", "btfrs.cli", "demo", "--out", str(tmp_path), "--material", "velvet", "--quiet"],
                       capture_output=True, text=True)
    assert r.returncode == 2 and "unknown material" in r.stderr and "Traceback" not in r.stderr







def test_tiles_cli_writes_the_set_its_picture_and_a_render(tmp_path):
    out = tmp_path / "t"
    assert main(["tiles", "--material", "bumps", "--size", "48", "--model", "ptm", "--tile", "24",
                 "--edge-height", "6", "--out", str(out), "--quiet"]) == 0
    names = {p.name for p in out.iterdir()}
    assert {"tiles.btfrs", "tiles.png", "tiling.png", "render.png", "layout.npy", "report.txt"} <= names
    ts = btfrs.load(out / "tiles.btfrs")
    assert ts.model.kind == "ptm" and ts.n_tiles == 16
    ts.check(np.load(out / "layout.npy"), wrap=(True, False))
    pic = btfrs.io.load_image(out / "tiles.png")
    assert pic.std() > 0.05
    assert "seams" in (out / "report.txt").read_text()
