"""scripts/rti_benchmark.py, the RTI relighting benchmark, on a capture written here as the public
sets are (8-bit images and an ``.lp`` file): its scores checked against an independent float64
numpy computation of the same protocol (every 5th light held out; raw interpolation by inverse
distance of the 4 nearest lights; a least-squares biquadratic PTM per texel; PSNR on the images'
own [0, 1] values, predictions clipped)."""

from __future__ import annotations

import importlib.util
import json
import os
from pathlib import Path

import numpy as np
import pytest

import btfrs

pytest.importorskip("skimage", reason="scikit-image (btfrs[test]) computes the benchmark's SSIM")
PIL = pytest.importorskip("PIL.Image")

ROOT = Path(__file__).resolve().parents[1]


def _script():
    spec = importlib.util.spec_from_file_location("rti_benchmark", ROOT / "scripts" / "rti_benchmark.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _write_capture(folder: Path) -> tuple[np.ndarray, np.ndarray]:
    """A 20 x 24 single-view capture of 30 lights as 8-bit PNGs + dirs.lp; returns the images as
    the benchmark reads them (value / 255) and the lights."""
    rng = np.random.default_rng(4)
    n = 30
    az = rng.uniform(0, 2 * np.pi, n)
    el = rng.uniform(np.radians(20), np.radians(85), n)
    lights = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], 1)
    btf = btfrs.materials.make("bumps", size=24, seed=1, views=[[0, 0, 1]], lights=lights, relief=0.3)
    data = np.asarray(btf.data)[:20, :, 0]                       # [h, w, lights, 3]
    data = data / max(float(data.max()), 1e-6)
    folder.mkdir()
    q = np.clip(np.round(data * 255), 0, 255).astype(np.uint8)
    lines = [str(n)]
    for i in range(n):
        name = f"image{i:02d}.png"
        PIL.fromarray(q[:, :, i]).save(folder / name)
        lines.append(f"{name} {lights[i, 0]:.7f} {lights[i, 1]:.7f} {lights[i, 2]:.7f}")
    (folder / "dirs.lp").write_text("\n".join(lines) + "\n")
    # The .lp's 7 decimals are what the benchmark reads.
    back = np.array([[float(x) for x in ln.split()[1:]] for ln in lines[1:]])
    return q.astype(np.float64) / 255.0, back / np.linalg.norm(back, axis=1, keepdims=True)


def _psnr(preds: list, truth: list) -> float:
    mse = np.mean([np.mean((np.clip(p, 0, 1) - t) ** 2) for p, t in zip(preds, truth)])
    return float(10 * np.log10(1.0 / mse))


def test_scores_match_an_independent_computation(tmp_path):
    images, lights = _write_capture(tmp_path / "cap")
    out = tmp_path / "out"
    assert _script().main([str(tmp_path / "cap"), "--methods", "raw,PTM", "--out", str(out)]) == 0
    rows = {r["method"]: r for r in json.loads((out / "results.json").read_text())}
    assert set(rows) == {"raw", "PTM"} and rows["raw"]["set"] == "cap"

    n = lights.shape[0]
    held = [i for i in range(n) if i % 5 == 4]
    kept = [i for i in range(n) if i % 5 != 4]
    truth = [images[:, :, i] for i in held]

    # Raw interpolation: inverse-distance weights of the 4 nearest kept lights.
    raw = []
    for i in held:
        d = np.linalg.norm(lights[kept] - lights[i], axis=1)
        near = np.argsort(d)[:4]
        w = 1 / d[near]
        raw.append(np.einsum("hwkc,k->hwc", images[:, :, [kept[j] for j in near]], w / w.sum()))
    assert rows["raw"]["psnr"] == pytest.approx(_psnr(raw, truth), abs=1e-6)
    sse = sum(np.sum((np.clip(p, 0, 1) - t) ** 2) for p, t in zip(raw, truth))
    assert rows["raw"]["relative"] == pytest.approx(np.sqrt(sse / sum(np.sum(t ** 2) for t in truth)), rel=1e-6)
    assert rows["raw"]["bytes"] == 20 * 24 * 3 * len(kept)

    # PTM (Malzbender 2001): per texel and channel, the least-squares biquadratic in the light's
    # (x, y). btfrs stores 8-bit coefficients: its images sit within a few hundredths of a dB.
    def basis(l):
        u, v = l[..., 0], l[..., 1]
        return np.stack([u * u, v * v, u * v, u, v, np.ones_like(u)], -1)

    a = basis(lights[kept])                                       # [k, 6]
    y = images[:, :, kept].transpose(2, 0, 1, 3).reshape(len(kept), -1)
    coef, *_ = np.linalg.lstsq(a, y, rcond=None)
    ptm = [(basis(lights[i]) @ coef).reshape(20, 24, 3) for i in held]
    ref = _psnr(ptm, truth)
    assert abs(rows["PTM"]["psnr"] - ref) < 0.05, (rows["PTM"]["psnr"], ref)
    # The two methods differ by more than that tolerance, so the check tells them apart.
    assert abs(ref - rows["raw"]["psnr"]) > 0.6
    assert 0 < rows["PTM"]["ssim"] <= 1 and rows["PTM"]["bytes"] < rows["raw"]["bytes"]

    table = (out / "table.md").read_text()
    assert "| cap |" in table and "**mean of 1**" in table
    assert (out / "psnr_vs_bytes.png").stat().st_size > 1000


def test_a_rerun_keeps_rows_and_fresh_recomputes_only_its_own(tmp_path):
    _write_capture(tmp_path / "cap")
    out = tmp_path / "out"
    mod = _script()
    mod.main([str(tmp_path / "cap"), "--methods", "raw,PTM", "--out", str(out)])
    store = out / "results.json"
    rows = json.loads(store.read_text())
    for r in rows:
        r["psnr"] = -1.0                      # a marker: a row recomputed loses it
    store.write_text(json.dumps(rows))
    mod.main([str(tmp_path / "cap"), "--methods", "raw,PTM", "--out", str(out)])
    assert all(r["psnr"] == -1.0 for r in json.loads(store.read_text()))
    mod.main([str(tmp_path / "cap"), "--methods", "PTM", "--out", str(out), "--fresh"])
    after = {r["method"]: r["psnr"] for r in json.loads(store.read_text())}
    assert after["raw"] == -1.0 and after["PTM"] > 10


def test_unknown_method_is_refused(tmp_path):
    _write_capture(tmp_path / "cap")
    with pytest.raises(SystemExit, match="unknown method"):
        _script().main([str(tmp_path / "cap"), "--methods", "raw,Nope", "--out", str(tmp_path / "o")])
