"""The benchmark's per-material accuracy mode and its atomic JSON writes.

The accuracy figures are checked against an independent computation (PTM-RGB fitted the numpy
way, :func:`btfrs.baselines.ptm_rgb_numpy`, and its error computed here in float64), not
against the model's own ``error``.
"""

import json
import os

import numpy as np
import pytest

from btfrs import materials
from btfrs.tools import baselines
from btfrs.tools import bench


def _ptm_numpy_relative(train, test) -> tuple[float, float]:
    """(reconstruction, held-out) relative error of the numpy PTM-RGB fit of ``train``."""
    coeffs = baselines.ptm_rgb_numpy(train)  # [H, W, V, 3, 6]
    out = []
    for part in (train, test):
        num = den = 0.0
        for v in range(part.n_views):
            ls = np.flatnonzero(part.mask[v])
            lx, ly = part.lights[ls, 0], part.lights[ls, 1]
            basis = np.stack([lx * lx, ly * ly, lx * ly, lx, ly, np.ones_like(lx)], axis=1)  # [n, 6]
            pred = np.einsum("hwck,nk->hwnc", coeffs[:, :, v], basis)
            gt = part.data[:, :, v][:, :, ls].astype(np.float64)
            num += float(np.sum((pred - gt) ** 2))
            den += float(np.sum(gt**2))
        out.append(np.sqrt(num / den))
    return out[0], out[1]


def test_accuracy_mode_writes_every_model_on_every_material(tmp_path, capsys):
    path = tmp_path / "sub" / "accuracy.json"
    assert bench.main(["--accuracy", "--size", "8", "--json", str(path)]) == 0
    assert "held-out below raw interpolation" in capsys.readouterr().out
    res = json.loads(path.read_text())
    rows = res["accuracy_models"]
    assert {r["material"] for r in rows} == set(materials.names())
    per_material = [label for label, *_ in bench.settings("per_material")]
    assert {"PTM-RGB", "Phong+SRF", "Lafortune-Lum 2"} <= set(per_material)  # what is checked below
    assert [r["model"] for r in rows if r["material"] == "knit"] == ["raw, 3 nearest lights", *per_material]
    assert os.listdir(path.parent) == ["accuracy.json"]  # no temporary file left behind
    for name in materials.names():
        mine = {r["model"]: r for r in rows if r["material"] == name}
        btf = materials.make(name, size=8, seed=1)
        train, test = btf.split(holdout=0.1, seed=0)
        rec, held = _ptm_numpy_relative(train, test)
        # btfrs's PTM is stored as 8-bit planes (bits=8, what a viewer holds), numpy's is float64:
        # the same fit up to the quantization, well under 1% of the error here.
        assert mine["PTM-RGB"]["reconstruction"] == pytest.approx(rec, rel=5e-3)
        assert mine["PTM-RGB"]["held_out"] == pytest.approx(held, rel=5e-3)
        raw = mine["raw, 3 nearest lights"]
        assert raw["reconstruction"] is None and raw["ratio"] == 1.0 and raw["nbytes"] == btf.nbytes
        # PTM-RGB stores 18 bytes per texel and view slot and a float scale and bias per plane.
        assert mine["PTM-RGB"]["ratio"] == pytest.approx(btf.nbytes / (8 * 8 * btf.n_views * 18 + 8 * btf.n_views * 18))
        srf = mine["Phong+SRF"]["report"]
        assert 0 < srf["srf_relative"] < srf["phong_relative"]
        laf = mine["Lafortune-Lum 2"]["report"]
        assert laf["converged"] + laf["fell_back"] + laf["failed"] == laf["fits"] == 64
        for r in mine.values():
            assert np.isfinite(r["held_out"]) and 0 < r["held_out"] < 2


def test_json_write_is_atomic(tmp_path):
    path = tmp_path / "bench.json"
    bench._write_json(str(path), {"a": 1})
    assert json.loads(path.read_text()) == {"a": 1}
    umask = os.umask(0)
    os.umask(umask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~umask  # an ordinary file's mode, not mkstemp's 0600
    # A failure half-way through the dump leaves the previous file whole and nothing else.
    with pytest.raises(TypeError):
        bench._write_json(str(path), {"a": 2, "b": object()})
    assert json.loads(path.read_text()) == {"a": 1}
    assert os.listdir(tmp_path) == ["bench.json"]


def test_frames_mode_times_every_example_and_renderer_against_the_reference():
    # The 3x-of-the-reference check must cover what the registry lists, not a hand-kept subset:
    # every example of every model, once per renderer, with the reference's own ratio exactly 1.
    from btfrs.models import model_kinds

    # Small frames: what is checked is the table (every setting, the ratios), not the timings.
    rows = bench.frames_bench(size=8, repeat=1, frame=128)
    want = [(k, label, r) for k, info in model_kinds().items() for label, _ in info["examples"]
            for r in info["renderers"]]
    assert [(r["kind"], r["model"], r["method"]) for r in rows] == want
    assert all(np.isfinite(r["point_ms"]) and r["point_ms"] > 0 for r in rows)
    label, kind, _, _ = bench.reference()
    assert (label, kind) == ("PTM-RGB", "ptm")  # the registry's reference of the 3x target
    ref = [r for r in rows if r["model"] == label]
    assert len(ref) == 1 and ref[0]["vs_reference"] == 1.0
    for r in rows:
        assert r["vs_reference"] == pytest.approx(r["point_ms"] / ref[0]["point_ms"])
    table = bench.frames_table(rows).splitlines()
    assert len(table) == len(rows) + 1 and "x PTM-RGB" in table[0]


def test_every_bench_setting_names_a_known_peer_and_role():
    # The peers the registry names exist; every role a setting plays has a section that reads it
    # (the bench asks for it by name), and each single-role section has at least one setting.
    from btfrs.models import model_kinds

    from pathlib import Path

    source = Path(bench.__file__).read_text()
    roles = set()
    for info in model_kinds().values():
        for b in info["bench"]:
            assert not b["peer"] or b["peer"] in baselines.PEERS, b
            roles.update(b["roles"])
    for role in roles:
        assert f'"{role}"' in source, f"no bench section reads the role {role!r}"
    for role in ("foundation", "reference", "per_material", "tiles", "single_view_reference"):
        assert bench.settings(role), role


def test_help_and_the_quickest_mode_run(tmp_path, capsys):
    # --help lists the modes the registry's facts make (one per against_all or big setting).
    with pytest.raises(SystemExit) as e:
        bench.main(["--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    for label, kind, _, _ in bench.settings("against_all") + bench.settings("big"):
        assert f"--{kind.replace('_', '-')}-" in out
    # The foundation table at 8^2: every foundation setting timed, its peer beside it.
    rows = bench.run([8], 1)
    found = [r for r in rows if r["task"].endswith("fit 8^2")]
    assert [r["task"] for r in found] == [f"{label} fit 8^2" for label, *_ in bench.settings("foundation")]
    for r, (_, _, _, b) in zip(found, bench.settings("foundation")):
        assert r["btfrs_s"] > 0 and (r["numpy_s"] is not None) == bool(b["peer"])
        if b["peer"]:
            assert r["note"].startswith("max coeff diff") and float(r["note"].split()[3]) < 1e-2
