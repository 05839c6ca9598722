"""btfrs.evaluate: the speed-against-accuracy report, its protocols, baselines and charts."""

import json

import numpy as np
import pytest

import btfrs
from btfrs.tools import baselines
from btfrs.evaluation import pareto_front, split_directions


@pytest.fixture(scope="module")
def weave():
    return btfrs.materials.make("weave", size=12, seed=2)


def test_split_directions_holds_out_every_pair_of_the_chosen_directions(weave):
    train, test = split_directions(weave, 0.1, seed=3)
    hv = np.setdiff1d(np.arange(81), [int(np.argmin(np.linalg.norm(weave.views - v, axis=1))) for v in train.views])
    hl = np.setdiff1d(np.arange(81), [int(np.argmin(np.linalg.norm(weave.lights - l, axis=1))) for l in train.lights])
    assert len(hv) == 8 and len(hl) == 8  # round(0.1 * 81)
    expect = np.zeros((81, 81), bool)
    expect[hv] = True
    expect[:, hl] = True
    assert np.array_equal(test.mask, expect)
    assert test.mask.sum() == 8 * 81 + 81 * 8 - 64
    # The train half holds the kept directions' values, and none of the held-out ones.
    assert train.shape == (12, 12, 73, 73, 3) and train.mask is None
    kv = np.setdiff1d(np.arange(81), hv)
    kl = np.setdiff1d(np.arange(81), hl)
    np.testing.assert_array_equal(train.data, weave.data[:, :, kv][:, :, :, kl])
    # Seeded: the same seed, the same split; another seed, another.
    assert np.array_equal(split_directions(weave, 0.1, seed=3)[1].mask, test.mask)
    assert not np.array_equal(split_directions(weave, 0.1, seed=4)[1].mask, test.mask)


def test_split_directions_rejects_bad_input(weave):
    with pytest.raises(btfrs.InvalidArgumentError, match="fraction"):
        split_directions(weave, 1.0)
    with pytest.raises(btfrs.ArgumentTypeError, match="btf"):
        split_directions(weave.data, 0.1)


def test_raw_interpolation_is_exact_where_it_should_be(weave):
    # Values constant over directions per texel: any convex interpolation reproduces them.
    data = np.broadcast_to(weave.data[:, :, :1, :1], weave.data.shape).copy()
    flat = btfrs.Btf(data, weave.views, weave.lights)
    for tr, te in (flat.split(holdout=0.2, seed=1), split_directions(flat, 0.2, seed=1)):
        assert baselines.raw_interpolation(tr, te) < 1e-6
    # Queried at pairs it holds, it returns the measured values.
    assert baselines.raw_interpolation(weave, weave.split(holdout=0.1, seed=0)[1]) < 1e-7
    # And between measured directions of real data the error is non-zero and moderate.
    tr, te = split_directions(weave, 0.1, seed=0)
    assert 0.01 < baselines.raw_interpolation(tr, te) < 1.0


def test_numpy_interp_weights_match_the_ptm_slot_blend(weave):
    # btfrs's PTM blends its view slots with the Rust interp_weights; the numpy baseline with its
    # own implementation: the same fit evaluated at held-out views must agree.
    tr, te = split_directions(weave, 0.15, seed=5)
    ptm = btfrs.fit.ptm(tr, kind="rgb", bits=32)  # floats: the blend, not the 8-bit planes, is tested
    coeffs = baselines.ptm_rgb_numpy(tr)
    assert baselines.ptm_error(coeffs, tr, te) == pytest.approx(ptm.error(te).relative, rel=1e-4)
    assert baselines.ptm_error(coeffs, tr, tr) == pytest.approx(ptm.error(tr).relative, rel=1e-4)


def _brute_front(pts):
    """The front by a sort-and-sweep (independent of pareto_front's pairwise test)."""
    best = np.inf
    out = []
    for x, y, i in sorted(pts):
        if y < best:
            out.append(i)
            best = y
    return out


def test_pareto_front_against_a_sweep():
    rng = np.random.default_rng(0)
    for trial in range(20):
        xs, ys = rng.uniform(1, 100, 30), rng.uniform(0.01, 1, 30)
        rows = [dict(bytes=float(x), heldout=float(y), i=i) for i, (x, y) in enumerate(zip(xs, ys))]
        rows.append(dict(bytes=None, heldout=0.001, i=99))  # missing a number: not on any front
        got = [r["i"] for r in pareto_front(rows, "heldout", "bytes")]
        assert got == _brute_front([(x, y, i) for i, (x, y) in enumerate(zip(xs, ys))])
    # psnr_scene is better when larger.
    rows = [dict(bytes=1.0, psnr_scene=20.0), dict(bytes=2.0, psnr_scene=30.0), dict(bytes=3.0, psnr_scene=25.0)]
    assert [r["bytes"] for r in pareto_front(rows, "psnr_scene", "bytes")] == [1.0, 2.0]
    with pytest.raises(btfrs.InvalidArgumentError, match="metric"):
        pareto_front(rows, "speed", "bytes")


@pytest.fixture(scope="module")
def report(weave):
    models = [("PTM-RGB", "ptm", {"kind": "rgb"}), ("Phong+SRF", "srf", {}),
              ("SH-CLS 9x9", "sh", {"light_coeffs": 9, "view_coeffs": 9})]
    return btfrs.evaluate(weave, models, holdout="both", baselines=baselines.evaluation_rows, baseline_texels=4, render_size=128, seed=0,
                          material="weave")


def test_evaluate_rows_match_independent_recomputation(report, weave):
    rows = {(r["label"], r["way"]): r for r in report.rows}
    ptm = rows[("PTM-RGB", "btfrs")]
    tr, te = weave.split(holdout=0.1, seed=0)
    m = btfrs.fit.ptm(tr, kind="rgb")
    assert ptm["heldout_pairs"] == pytest.approx(m.error(te).relative, rel=1e-6)
    assert ptm["reconstruction"] == pytest.approx(m.error(tr).relative, rel=1e-6)
    assert ptm["bytes"] == m.nbytes
    dtr, dte = split_directions(weave, 0.1, seed=0)
    assert ptm["heldout_directions"] == pytest.approx(btfrs.fit.ptm(dtr).error(dte).relative, rel=1e-6)
    # The numpy pinv PTM is the same method: the same held-out errors, up to btfrs's 8-bit planes
    # (bits=8, the default; well under 1% of the error).
    np_ptm = rows[("PTM-RGB", "numpy pinv")]
    for k in ("heldout_pairs", "heldout_directions", "reconstruction"):
        assert np_ptm[k] == pytest.approx(ptm[k], rel=5e-3), k
    for r in report.rows:
        assert np.isfinite(r["heldout_pairs"]) and np.isfinite(r["heldout_directions"]), r["label"]
    raw = rows[("raw interpolation", "raw")]
    assert raw["reconstruction"] == 0.0 and raw["bytes"] == weave.nbytes
    # Every btfrs row rendered, finite, and its scene PSNR against the raw render is sensible.
    for r in report.rows:
        if r["way"] == "btfrs":
            assert r["render_ms"] > 0 and r["finite_render"]
            assert 10 < r["psnr_scene"] < 80, (r["label"], r["psnr_scene"])
    assert report.info["holdout"] == "both" and report.primary == "heldout_pairs"
    assert all(r["heldout"] == r["heldout_pairs"] for r in report.rows)


def test_evaluate_table_pareto_and_save(report, tmp_path):
    t = report.table()
    assert t.count("\n") == len(report.rows) + 1 and "| PTM-RGB" in t
    front = report.pareto("heldout", "bytes")
    assert front and all(r in report.rows for r in front)
    # No row outside the front is better in both.
    for r in report.rows:
        if r in front or r.get("bytes") is None:
            continue
        assert any(f["bytes"] <= r["bytes"] and f["heldout"] <= r["heldout"] for f in front)
    paths = report.save(tmp_path / "ev")
    names = sorted(p.split("/")[-1] for p in paths)
    assert names == ["heldout_vs_bytes.png", "heldout_vs_fit_s.png", "heldout_vs_render_ms.png", "report.json",
                     "report.md"]
    data = json.loads((tmp_path / "ev" / "report.json").read_text())
    assert len(data["rows"]) == len(report.rows)
    import matplotlib.image

    img = matplotlib.image.imread(str(tmp_path / "ev" / "heldout_vs_bytes.png"))
    assert img.ndim == 3 and img.shape[1] > 1.5 * img.shape[0]  # two panels side by side
    # Not a blank canvas: points and text drawn.
    assert img[..., :3].std() > 0.05


def test_evaluate_rejects_bad_arguments(weave):
    with pytest.raises(btfrs.InvalidArgumentError, match="holdout"):
        btfrs.evaluate(weave, "ptm", holdout="views")
    with pytest.raises(btfrs.InvalidArgumentError, match="models"):
        btfrs.evaluate(weave, ["ptm", "nope"])
    with pytest.raises(btfrs.InvalidArgumentError, match="models"):
        btfrs.evaluate(weave, [])
    with pytest.raises(btfrs.InvalidArgumentError, match="sweep"):
        btfrs.evaluate(weave, "ptm", sweep="big")


def test_evaluate_records_a_failed_fit_instead_of_raising(weave):
    # 5 lights per view (4 after holding one out): a PTM needs 6, so with on_degenerate="raise"
    # the fit fails; the report says so in the row and goes on with the next model.
    few = weave.select(lights=[0, 10, 30, 50, 70])
    rep = btfrs.evaluate(few, [("PTM strict", "ptm", {"kind": "rgb", "on_degenerate": "raise"}),
                               ("Phong+SRF", "srf", {})], holdout="directions", render=False,
                         baselines=None)
    bad, ok = rep.rows
    assert "DegenerateDataError" in bad["error"] and bad.get("heldout") is None
    assert np.isfinite(ok["heldout"]) and ok["heldout"] == ok["heldout_directions"]
