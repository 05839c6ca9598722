import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np

import btfrs
from btfrs.cli import main

ROOT = Path(__file__).resolve().parents[1]


def test_demo_writes_images_and_a_summary_with_numbers(tmp_path):
    assert main(["demo", "--out", str(tmp_path), "--size", "24", "--quiet"]) == 0
    summary = (tmp_path / "summary.md").read_text()
    rows = {m.group(1): m for m in re.finditer(r"^\| (PTM-\w+) \| ([\d.]+) \| ([\d.]+) MiB \| 1:([\d.]+) \| ([\d.]+)% \| ([\d.]+)% \|", summary, re.M)}
    assert set(rows) == {"PTM-RGB", "PTM-LRGB"}
    # The table's numbers are the models' own: LRGB stores half of RGB; errors are percentages.
    assert abs(float(rows["PTM-LRGB"].group(4)) / float(rows["PTM-RGB"].group(4)) - 2.0) < 0.01
    assert 1.0 < float(rows["PTM-RGB"].group(6)) < 60.0
    pngs = sorted(p.name for p in tmp_path.glob("*.png"))
    assert "materials.png" in pngs and len([p for p in pngs if p.startswith("compare_")]) == 3
    img = btfrs.io.load_image(tmp_path / "materials.png")
    assert img.shape[0] == 4 * 24 * 3 and img.std() > 0.05  # four materials, not a blank image
    back = btfrs.load(tmp_path / "ptm_rgb_top.ptm")
    assert back.height == 24
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


def test_readme_python_snippet_runs():
    text = (ROOT / "README.md").read_text()
    block = re.search(r"## Python in a few lines\s+```python\n(.*?)```", text, re.S).group(1)
    ns: dict = {}
    exec(compile(block, "README.md", "exec"), ns)
    img, ptm, test = ns["img"], ns["ptm"], ns["test"]
    assert img.shape == (64, 64, 3) and img.dtype == np.float32 and np.all(np.isfinite(img))
    assert 0 < ptm.error(test).relative < 0.5


def test_readme_rendering_snippet_runs(tmp_path, monkeypatch):
    text = (ROOT / "README.md").read_text()
    block = re.search(r"## Rendering\s+```python\n(.*?)```", text, re.S).group(1)
    monkeypatch.chdir(tmp_path)
    ns: dict = {}
    exec(compile(block, "README.md", "exec"), ns)
    img, ref = ns["img"], ns["ref"]
    # size=(384, 512) is (height, width), as numpy shapes are.
    assert img.shape == (384, 512, 3) and ref.shape == img.shape and (img.sum(-1) > 0).mean() > 0.2
    mse = float(np.mean((img - ref) ** 2))
    assert 10 * np.log10(float(ref.max()) ** 2 / mse) > 40
    assert (tmp_path / "sphere.png").exists()


def test_readme_models_snippet_runs(monkeypatch, tmp_path):
    text = (ROOT / "README.md").read_text()
    block = re.search(r"## The other models[^\n]*\s+```python\n(.*?)```", text, re.S).group(1)
    monkeypatch.chdir(tmp_path)
    ns: dict = {}
    exec(compile(block, "README.md", "exec"), ns)
    img, test = ns["img"], ns["test"]
    assert img.shape == (512, 512, 3) and (img.sum(-1) > 0).mean() > 0.2
    for name in ("laf", "srf", "sh", "lp"):
        assert 0 < ns[name].error(test).relative < 0.6, name
    assert set(ns["laf"].report) >= {"converged", "fell_back", "failed"}


def test_readme_synthesis_snippet_runs(monkeypatch, tmp_path):
    text = (ROOT / "README.md").read_text()
    block = re.search(r"## Synthesis[^\n]*\s+```python\n(.*?)```", text, re.S).group(1)
    monkeypatch.chdir(tmp_path)
    ns: dict = {}
    exec(compile(block, "README.md", "exec"), ns)
    img, cmap, big = ns["img"], ns["cmap"], ns["big"]
    assert cmap.shape == (512, 512, 2) and big.shape[:2] == (512, 512)
    assert img.shape == (384, 384, 3) and (img.sum(-1) > 0).mean() > 0.2
    assert (tmp_path / "knit.analysis.btfrs").exists()


def test_readme_tiles_snippet_runs(tmp_path, monkeypatch):
    # The user code of the tile section, as written (issue 12's "what a user can do").
    text = (ROOT / "README.md").read_text()
    block = re.search(r"## Tileable BTFs[^\n]*\s+```python\n(.*?)```", text, re.S).group(1)
    monkeypatch.chdir(tmp_path)
    ns: dict = {}
    exec(compile(block, "README.md", "exec"), ns)
    img, tiles, layout = ns["img"], ns["tiles"], ns["layout"]
    assert img.shape == (512, 512, 3) and np.isfinite(img).all() and (img.sum(-1) > 0).mean() > 0.2
    tiles.check(layout)
    assert isinstance(btfrs.load(tmp_path / "bumps.tiles"), btfrs.tiles.TileSet)
    assert ns["tiles_lp"].model.kind == "lpca" and ns["rgb"].model is None
    assert ns["flow"] == 2 and list(ns["source_side"]) == [True, True, False]


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
