"""btfrs.stability: every model in every failure regime, each regime with a bound that can fail.

One full run (grooves 8^2, seed 0, the default models, the fitted models kept) is shared by the
module: every regime and bound below holds on it as on 16^2, in a third of the time. The CLS-vs-LS,
plain-vs-robust and same-seed checks fit their own models.
"""

import json
import math

import numpy as np
import pytest

import btfrs
import btfrs.stability as S
from btfrs.exceptions import InvalidArgumentError


@pytest.fixture(scope="module")
def btf():
    return btfrs.materials.make("grooves", size=8, seed=0)


@pytest.fixture(scope="module")
def report(btf):
    # The fitted models stay in the rows (the tests that evaluate them read them here instead of
    # fitting a regime a second time).
    return S.run(btf, models=S.default_models(), seed=0, name="grooves 8", keep_models=True)


def rows(report, regime, model=None):
    return [r for r in report.rows if r["regime"] == regime and (model is None or r["model"] == model)]


def models(report):
    return [m[0] for m in report.models]


@pytest.mark.parametrize("regime", S.REGIMES)
def test_no_fit_raises_and_nothing_is_ever_nan(report, regime):
    rs = rows(report, regime)
    assert len(rs) == len(models(report)) * len({r["level_label"] for r in rs}) and rs
    for r in rs:
        assert r["error"] is None, r
        assert r["finite"], r
        assert math.isfinite(r["held_out"]) and math.isfinite(r["reconstruction"]), r
        assert r["fit_seconds"] >= 0


def test_every_registered_kind_is_run(report):
    assert {m[1] for m in report.models} == set(btfrs.model_kinds())


def test_decimation_degrades_smoothly_and_stays_bounded(report):
    for m in models(report):
        curve = [e for _, e in sorted(report.curve(m, "decimation"), reverse=True)]  # 90% ... 5%
        # Roughly monotone: a level may beat the denser one by at most 10% (sampling noise).
        for a, b in zip(curve, curve[1:]):
            assert b >= 0.9 * a, (m, curve)
        # Bounded: below 1 (the error of predicting 0) at 10% and at 5%, and no jump: 5% within
        # 2x the 25% case (before the fixes: Lafortune 170 at 5%, PTM raised at 10% and, allowed
        # to fit, reached 5.9).
        assert curve[3] < 1.0 and curve[4] < 1.0, (m, curve)
        assert curve[4] < 2.0 * curve[2], (m, curve)


def test_ptm_at_10_percent_does_not_raise_and_reports_its_fallback_slots(report):
    r = report.row("PTM-RGB", "decimation", 0.10)
    slots = r["report"]["degenerate_slots"]
    assert r["error"] is None and slots and r["flagged"]
    for s in slots:
        assert s["action"] in ("linear", "pooled") and s["reason"] in ("few lights", "degenerate lights", "extrapolates")
        assert s["amplification"] <= 4.0 + 1e-9
        assert 0 <= s["slot"] < 81
    # With "raise" the same data still fail, naming a slot.
    train, _ = btfrs.materials.make("grooves", size=16, seed=0).split(holdout=0.9, seed=0)
    with pytest.raises(btfrs.DegenerateDataError, match="view slot"):
        btfrs.fit.ptm(train, on_degenerate="raise")


def test_lafortune_at_5_percent_is_flagged_and_bounded(report):
    r5 = report.row("Lafortune-Lum 2", "decimation", 0.05)
    r25 = report.row("Lafortune-Lum 2", "decimation", 0.25)
    r90 = report.row("Lafortune-Lum 2", "decimation", 0.9)
    assert r5["report"]["extrapolated"] > 0 and r5["flagged"]
    assert r5["held_out"] < 2.0 * r25["held_out"] and r5["held_out"] < 1.0
    # Dense sampling seldom trips the guard: only a few lobes that would overflow at grazing
    # directions beyond the measured 75 degrees (the guard's rings up to the horizon).
    assert r90["report"]["extrapolated"] <= 0.05 * r90["report"]["fits"]


def test_uneven_subsets_stay_bounded(report):
    # Lights in one azimuth half only: the other half is pure extrapolation. PTM is the worst
    # (every slot falls back to the plane, whose extrapolation is the least: about 1.0, the error
    # of predicting 0); its full biquadratic would go far beyond. HSH, the other light basis fitted
    # per slot, extrapolates likewise (HSH-2 0.85 with lights up to theta 45 only). Everything else
    # stays below 0.8.
    for r in rows(report, "uneven"):
        assert r["held_out"] < (1.2 if r["kind"] in ("ptm", "hsh") else 0.8), r
    r = report.row("PTM-RGB", "uneven", 1)
    assert r["flagged"] and {s["action"] for s in r["report"]["degenerate_slots"]} == {"linear"}


# Models trained by stochastic gradient descent (their registry entry says so): another seed
# (other minibatches) gives another error, so "the clean case is the best" holds within their
# spread over seeds. Measured for the neural model on this sample: 2.1% over seeds 0 to 3.
STOCHASTIC = {kind for kind, info in btfrs.model_kinds().items() if info["stochastic"]}


_SPREADS = {}


def seed_spread(btf, kind, options):
    # Computed once per model for the module (both noise regimes ask for it).
    key = (kind, json.dumps(options, sort_keys=True))
    if key not in _SPREADS:
        train, test = btf.split(holdout=0.1, seed=0)
        errs = [btfrs.fit.fit(kind, train, **dict(options, seed=s)).error(test).relative for s in range(3)]
        _SPREADS[key] = (max(errs) - min(errs)) / min(errs)
    return _SPREADS[key]


def noise_bound(report, regime, btf):
    for m, kind, options in report.models:
        curve = [e for _, e in sorted(report.curve(m, regime))]
        # Noise only on the training data: least squares averages it; no model may get worse
        # than predicting 0, and the clean case is the best within 2% (plus, for a model
        # trained by SGD, its spread over seeds).
        assert max(curve) < 1.0, (m, curve)
        tol = 0.02 + (2 * seed_spread(btf, kind, options) if kind in STOCHASTIC else 0.0)
        assert curve[0] <= (1 + tol) * min(curve), (m, curve, tol)


def test_additive_noise_is_averaged_out(report, btf):
    noise_bound(report, "additive_noise", btf)


def test_multiplicative_noise_is_averaged_out(report, btf):
    noise_bound(report, "multiplicative", btf)


def test_sh_cls_beats_plain_least_squares_under_noise_after_quantization(btf):
    # Paper 002, section 3.1: the constraint keeps the coefficient energy within the function's,
    # which is what 8-bit quantization needs. Both quantized; noisy training data, clean test.
    st = S.run(btf, models=[("SH-LS", "sh", dict(light_coeffs=16, view_coeffs=16, cls=False)),
                            ("SH-CLS", "sh", dict(light_coeffs=16, view_coeffs=16, cls=True))],
               regimes=["additive_noise"], seed=0)
    ls = dict(st.curve("SH-LS", "additive_noise"))
    cls = dict(st.curve("SH-CLS", "additive_noise"))
    # Measured: plain LS over the hemisphere extrapolates to the held-out pairs (12.3 clean, 16.9
    # at 100% noise, 16 x 16 coefficients); CLS stays at 0.40.
    for level in (0.0, 0.3, 1.0):
        assert cls[level] < 0.5 < 2.0 < ls[level], (level, cls, ls)


def test_hard_shadows_stay_bounded(report):
    for r in rows(report, "shadows"):
        assert r["held_out"] < 1.0, r


def test_glossy_texels_stay_bounded(report):
    for m in models(report):
        curve = [e for _, e in sorted(report.curve(m, "glossy"))]
        assert max(curve) < 1.0, (m, curve)


def test_grazing_only_training_stays_bounded(report):
    for r in rows(report, "grazing"):
        assert r["held_out"] < 1.0, r
    # PTM slots whose views are below 60 degrees have no lights: pooled from the grazing views;
    # the grazing views' own lights (two rings at 60 and 75 degrees) would make the biquadratic
    # extrapolate towards the normal: the plane or pooled. Every slot is reported.
    r = report.row("PTM-RGB", "grazing", 60.0)
    views = btfrs.directions.ubo81()
    slots = r["report"]["degenerate_slots"]
    assert r["flagged"] and len(slots) == 81
    for s in slots:
        if views[s["slot"], 2] > np.cos(np.radians(60)) + 1e-9:
            assert s["action"] == "pooled" and s["lights"] == 0, s
        else:
            assert s["action"] in ("linear", "pooled") and s["reason"] == "extrapolates", s


def test_black_texels_give_finite_zeros(report):
    r0 = [r for r in rows(report, "black") if r["level"] == 0.25]
    assert len(r0) == len(models(report)), [r["model"] for r in r0]
    for r in r0:
        m, train = r["model_object"], r["train"]
        black = S.black_texels(train)
        assert 0.15 * black.size < black.sum() < 0.35 * black.size
        for v, l in [(0, 0), (40, 17), (80, 66)]:
            img = m.evaluate(train.views[v], train.lights[l])
            assert np.all(np.isfinite(img))
            if r["kind"] == "srf":
                # A finding, not fixed here: Phong + SRF has one global Phong lobe and a per-texel
                # residual s(P) . H that cannot cancel it exactly, so a black texel shows a dim
                # remainder of the global lobe (0.14 here, the data reach 2.2). Bounded, finite.
                assert np.abs(img[black]).max() <= 0.25 * float(train.data.max())
                continue
            # Zero up to the 8-bit quantization of SH and LPCA (1/255 of the data's scale); the
            # PTM's 8-bit planes decode a zero coefficient as bias + scale * q, zero up to rounding.
            tol = {"lafortune": 0.0, "ptm": 1e-5 * float(train.data.max())}.get(r["kind"], 2e-2 * float(train.data.max()))
            assert np.abs(img[black]).max() <= tol, (r["model"], np.abs(img[black]).max())


def test_saturated_texels_stay_bounded(report):
    for r in rows(report, "saturated"):
        assert r["held_out"] < 1.0, r


def test_outliers_do_not_wreck_any_model(report):
    # 1000x outliers on 0.01%, 0.1% and 1% of the training values (test data clean): every
    # model's held-out error within 10% of its clean error at the first two levels and 25% at
    # the third (the robust screen; measured: identical at the first two, within 7% at 1%).
    for model in models(report):
        rs = {r["level_label"]: r["held_out"] for r in rows(report, "outliers", model)}
        clean = rs["0%"]
        for label, bound in (("0.01%", 1.10), ("0.1%", 1.10), ("1%", 1.25)):
            assert rs[label] <= bound * clean, (model, label, rs[label], clean)


def test_plain_least_squares_is_wrecked_by_the_same_outliers(btf):
    # What the screen prevents, so the bound above can fail: robust=False at 0.01% multiplies
    # PTM's and LPCA's held-out error by more than 3.
    levels = S.levels(btf, "outliers", seed=0)
    _, _, clean_train, test = levels[0]
    _, _, hot_train, _ = levels[1]
    for kind, opts in (("ptm", {}), ("lpca", {"clusters": 8, "components": 4})):
        clean = btfrs.fit.fit(kind, clean_train, robust=False, **opts).error(test).relative
        plain = btfrs.fit.fit(kind, hot_train, robust=False, **opts).error(test).relative
        robust = btfrs.fit.fit(kind, hot_train, robust=True, **opts).error(test).relative
        assert plain > 3 * clean and robust < 1.02 * clean, (kind, clean, plain, robust)


def test_on_clean_data_robust_and_plain_fits_agree(report, btf):
    # Within 1% in held-out error for every model (the screen flags a handful of clean values).
    train, test = btf.split(holdout=0.1, seed=0)
    for label, kind, opts in S.default_models():
        plain = btfrs.fit.fit(kind, train, robust=False, **opts).error(test).relative
        robust = btfrs.fit.fit(kind, train, robust=True, **opts).error(test).relative
        assert abs(robust - plain) <= 0.01 * plain, (label, plain, robust)


@pytest.mark.parametrize("name", btfrs.materials.names())
def test_no_clean_image_is_reported_bad(name):
    # No built-in material, at the full 81 x 81 sampling or at a sparse one (grazing pairs
    # far from every neighbour), has an image reported bad; and the values flagged on clean
    # data are a few in ten thousand.
    u = btfrs.directions.ubo81()
    for b in (btfrs.materials.make(name, size=32, seed=1),
              btfrs.materials.make(name, size=32, views=u[::6], lights=u[::3], seed=2)):
        r = btfrs.fit.ptm(b).report["robust"]
        assert r["bad_images"] == [], (name, r["bad_images"])
        assert r["fraction_flagged"] < 5e-4, (name, r["fraction_flagged"])


def test_the_report_finds_the_hot_values_and_the_bad_images():
    # Hot values planted at known places are the ones flagged and named; a misfired flash
    # (x0.2), a double flash (x3) and a moved sample are the images reported, and excluded on
    # request.
    knit = btfrs.materials.make("weave", size=16, seed=0)
    d = knit.data.copy()
    d[3, 4, 7, 11, 0] *= 1000.0
    d[3, 4, 7, 12, 1] *= 1000.0
    d[9, 1, 2, 30, 2] *= 1000.0
    d[:, :, 10, 20] *= 0.2
    d[:, :, 40, 5] *= 3.0
    # A moved sample: image (25, 50) shifted 5 texels along the rows (columns + 5).
    d[:, :, 25, 50] = np.roll(d[:, :, 25, 50], 5, axis=1)
    b = btfrs.Btf(d, knit.views, knit.lights)
    m = btfrs.fit.ptm(b, robust=True)
    r = m.report["robust"]
    assert r["values_replaced"] == r["values_flagged"] >= 3
    assert r["top_texels"][0] == {"row": 3, "col": 4, "values": 2}
    assert {(p["view"], p["light"]) for p in r["bad_images"]} == {(10, 20), (40, 5), (25, 50)}
    assert [p.get("moved") for p in r["bad_images"] if "moved" in p] == [[0, 5]]
    assert not r["bad_images_excluded"]
    plain = btfrs.fit.ptm(knit)
    ex = btfrs.fit.ptm(b, robust=True, exclude_bad_images=True)
    assert ex.report["robust"]["bad_images_excluded"]
    # Excluding the three images brings the fit back to the clean one's at those pairs.
    for v, l in ((10, 20), (40, 5), (25, 50)):
        want = plain.evaluate(knit.views[v], knit.lights[l])
        got = ex.evaluate(knit.views[v], knit.lights[l])
        kept = m.evaluate(knit.views[v], knit.lights[l])
        assert np.abs(got - want).mean() < 0.5 * np.abs(kept - want).mean()
    assert "robust" not in btfrs.fit.ptm(b, robust=False).report
    with pytest.raises(btfrs.InvalidArgumentError, match="robust: expected True or False"):
        btfrs.fit.ptm(b, robust="yes")


def test_report_saves_json_and_one_chart_per_regime(report, tmp_path):
    paths = report.save(tmp_path / "out")
    names = sorted(p.split("/")[-1] for p in paths)
    assert names == sorted(["report.json", "report.md"] + [f"{r}.png" for r in S.REGIMES])
    d = json.loads((tmp_path / "out" / "report.json").read_text())
    assert len(d["rows"]) == len(report.rows) and d["material"] == "grooves 8"
    for r in S.REGIMES:
        head = (tmp_path / "out" / f"{r}.png").read_bytes()[:8]
        assert head == b"\x89PNG\r\n\x1a\n"
    t = report.table()
    assert t.count("\n") > len(report.rows) // len(report.models) and "PTM-RGB" in t


def test_bad_arguments_name_the_argument(btf):
    with pytest.raises(InvalidArgumentError, match="regimes"):
        S.run(btf, regimes=["nope"])
    with pytest.raises(InvalidArgumentError, match="models"):
        S.run(btf, models=["nope"])
    with pytest.raises(InvalidArgumentError, match="models"):
        S.run(btf, models=[("a", "ptm", {}), ("a", "sh", {})], regimes=["black"])
    with pytest.raises(btfrs.exceptions.ArgumentTypeError, match="btf"):
        S.run("grooves")


def test_the_same_seed_gives_the_same_rows(btf):
    a = S.run(btf, models=["ptm"], regimes=["decimation", "outliers"], seed=3)
    b = S.run(btf, models=["ptm"], regimes=["decimation", "outliers"], seed=3)
    # Equal up to the order of the parallel error sums.
    assert np.allclose([r["held_out"] for r in a.rows], [r["held_out"] for r in b.rows], rtol=1e-12, atol=0)


def test_cli_writes_the_report(tmp_path, capsys):
    from btfrs.cli import main

    out = tmp_path / "st"
    assert main(["stability", "--material", "bumps", "--size", "8", "--out", str(out), "--quiet",
                 "--models", "ptm", "--regimes", "decimation", "black"]) == 0
    assert (out / "report.json").exists() and (out / "decimation.png").exists()
    assert "decimation" in capsys.readouterr().out


def test_cli_fit_reports_what_the_screen_found(tmp_path, capsys):
    from btfrs.cli import main

    weave = btfrs.materials.make("weave", size=16, seed=0)
    d = weave.data.copy()
    d[3, 4, 7, 11, 0] *= 1000.0
    d[:, :, 25, 50] = np.roll(d[:, :, 25, 50], 5, axis=1)
    src = tmp_path / "w.btfrs"
    btfrs.Btf(d, weave.views, weave.lights).save(src)
    assert main(["fit", str(src), "--model", "ptm", "-o", str(tmp_path / "m.btfrs"), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "robust: 1 outlying values" in out and "replaced" in out
    assert "1 bad images (view 25 light 50 moved 0, 5 texels), kept" in out
    assert main(["fit", str(src), "--model", "ptm", "-o", str(tmp_path / "p.btfrs"), "--quiet", "--no-robust"]) == 0
    assert "robust:" not in capsys.readouterr().out


def test_a_stochastic_model_with_a_tenth_of_the_pairs_is_not_worse_than_lpca(report):
    # Early stopping on held-back pairs and the PCA start keep a model trained by SGD from
    # overfitting sparse sampling: with 10% of the pairs it must do no worse than local PCA
    # (measured: 0.333 against 0.442).
    lpca = [m for m, kind, _ in report.models if kind == "lpca"]
    for m, kind, _ in report.models:
        if kind in STOCHASTIC:
            mine = dict(report.curve(m, "decimation"))
            for other in lpca:
                theirs = dict(report.curve(other, "decimation"))
                assert mine[0.1] <= theirs[0.1], (m, mine, other, theirs)
