import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np

import btfrs
from btfrs.cli import main



def test_demo_writes_images_and_a_summary_with_numbers(tmp_path):
    # Every step of the demo, at 16^2 (87 s here; 24^2 took 150 s on CI).
    assert main(["demo", "--out", str(tmp_path), "--size", "16", "--quiet"]) == 0
    summary = (tmp_path / "summary.md").read_text()
    rows = {m.group(1): m for m in re.finditer(r"^\| (PTM-\w+) \| ([\d.]+) \| ([\d.]+) MiB \| 1:([\d.]+) \| ([\d.]+)% \| ([\d.]+)% \|", summary, re.M)}
    assert set(rows) == {"PTM-RGB", "PTM-LRGB"}
    # The table's numbers are the models' own: LRGB stores half of RGB; errors are percentages.
    assert abs(float(rows["PTM-LRGB"].group(4)) / float(rows["PTM-RGB"].group(4)) - 2.0) < 0.01
    assert 1.0 < float(rows["PTM-RGB"].group(6)) < 60.0
    pngs = sorted(p.name for p in tmp_path.glob("*.png"))
    assert "materials.png" in pngs and len([p for p in pngs if p.startswith("compare_")]) == 3
    img = btfrs.io.load_image(tmp_path / "materials.png")
    assert img.shape[0] == 4 * 16 * 3 and img.std() > 0.05  # four materials, not a blank image
    back = btfrs.load(tmp_path / "ptm_rgb_top.ptm")
    assert back.height == 16
    # The speed-against-accuracy charts and report, with a row per registered model.
    ev = json.loads((tmp_path / "evaluate" / "report.json").read_text())
    assert {r["kind"] for r in ev["rows"]} >= set(btfrs.model_kinds())
    assert all(r.get("heldout_directions") is not None for r in ev["rows"]), "every point has both protocols"
    assert {p.name for p in (tmp_path / "evaluate").glob("*.png")} == {
        "heldout_vs_bytes.png", "heldout_vs_render_ms.png", "heldout_vs_fit_s.png"}
    assert "Speed against accuracy" in summary


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
