"""The models beyond PTM (Phong + SRF, Lafortune, double SH, LPCA): each checked against an
independent numpy evaluation of its own arrays, a fit of data made by the model itself, its
stability behaviours, save/load, and its shader against the CPU reference renderer."""

import numpy as np
import pytest

import btfrs
from btfrs.tools import baselines
from btfrs.exceptions import FormatError, InvalidArgumentError


def psnr(a, b):
    mse = float(np.mean((a.astype(np.float64) - b) ** 2))
    peak = float(max(a.max(), b.max()))
    return np.inf if mse == 0 else 10 * np.log10(peak * peak / mse)


def halfway(v, l):
    h = v + l
    return h / np.linalg.norm(h, axis=-1, keepdims=True)


@pytest.fixture(scope="module")
def bumps():
    return btfrs.materials.make("bumps", size=16, seed=4)


# --- Phong + SRF ---------------------------------------------------------------------------


def srf_numpy(m, view, light):
    """Phong + s(P) . H from the model's arrays, in float64."""
    p = m.phong
    v, l = np.asarray(view, float), np.asarray(light, float)
    h = halfway(v, l)
    phong = p[0:3] * l[2] + p[3:6] * max(h[2], 0.0) ** p[6]
    return phong + np.einsum("hwcx,x->hwc", m.s.astype(np.float64), h)


def test_srf_reduces_the_error_of_phong_alone_on_every_material():
    for name in btfrs.materials.names():
        btf = btfrs.materials.make(name, size=16, seed=1)
        train, test = btf.split(holdout=0.1, seed=0)
        m = btfrs.fit.srf(train)
        r = m.report
        assert r["srf_relative"] < r["phong_relative"], (name, r)
        assert m.error(train).relative == pytest.approx(r["srf_relative"], rel=1e-6)
        assert np.isfinite(m.error(test).relative)


def test_srf_evaluate_matches_numpy_and_round_trips(bumps, tmp_path):
    m = btfrs.fit.srf(bumps)
    v, l = [0.3, -0.2, 0.93], [-0.5, 0.4, 0.77]
    v, l = np.array(v) / np.linalg.norm(v), np.array(l) / np.linalg.norm(l)
    np.testing.assert_allclose(m.evaluate(v, l), srf_numpy(m, v, l), rtol=1e-5, atol=1e-6)
    m.save(tmp_path / "m.btfrs")
    back = btfrs.load(tmp_path / "m.btfrs")
    assert isinstance(back, btfrs.Srf) and back.nbytes == m.nbytes == 4 * (16 * 16 * 9 + 7)
    np.testing.assert_array_equal(back.evaluate(v, l), m.evaluate(v, l))
    # The fit's numbers to rounding, the robust screen's report (nested) as it was.
    plain = {k: v for k, v in m.report.items() if k != "robust"}
    assert {k: v for k, v in back.report.items() if k != "robust"} == pytest.approx(plain)
    assert back.report["robust"] == m.report["robust"] and m.report["robust"]["robust"] is True
    with pytest.raises(FormatError):
        btfrs.Lpca.load(tmp_path / "m.btfrs")


def test_srf_from_bad_arrays_is_a_clear_error(bumps):
    a = btfrs.fit.srf(bumps).arrays
    a["s"][0, 0, 0, 0] = np.nan
    with pytest.raises(InvalidArgumentError, match="s: value at flat index 0 is not finite"):
        btfrs.Srf.from_arrays(a)
    a = btfrs.fit.srf(bumps).arrays
    a["phong"][6] = 0.5
    with pytest.raises(InvalidArgumentError, match="phong"):
        btfrs.Srf.from_arrays(a)


# --- Lafortune -------------------------------------------------------------------------------


def lafortune_numpy(m, view, light):
    """l_z (kd + sum_i max(C . (l * v), 0)^n) from the model's arrays, in float64."""
    a = m.arrays
    p = a["params"].astype(np.float64)
    v, l = np.asarray(view, float), np.asarray(light, float)
    prod = v * l
    rho = p[..., 0].copy()
    for i in range((p.shape[-1] - 1) // 4):
        c = p[..., 1 + 4 * i: 4 + 4 * i]
        s = np.maximum(c @ prod, 0.0)
        rho += np.where(s > 0, s, 0.0) ** p[..., 4 + 4 * i]
    if "rgb" in a:
        return l[2] * rho[..., None] * a["rgb"]
    return l[2] * rho


def lafortune_data(h, w, lobes, seed):
    """A luminance Lafortune BTF with a base colour, made from known parameters."""
    rng = np.random.default_rng(seed)
    d = btfrs.directions.ubo81()
    kd = rng.uniform(0.1, 0.4, (h, w))
    c = np.stack([rng.uniform(-0.9, -0.6, (h, w, lobes)), rng.uniform(-0.9, -0.6, (h, w, lobes)),
                  rng.uniform(0.6, 0.9, (h, w, lobes))], -1)
    n = rng.uniform(3, 20, (h, w, lobes))
    prod = d[:, None, :] * d[None, :, :]  # [V, L, 3]
    s = np.maximum(np.einsum("hwix,vlx->hwvli", c, prod), 0)
    rho = kd[:, :, None, None] + np.sum(s ** n[:, :, None, None, :], -1)
    lum = d[None, None, None, :, 2] * rho
    base = rng.uniform(0.3, 1.0, (h, w, 3))
    data = (lum[..., None] * base[:, :, None, None, :]).astype(np.float32)
    return btfrs.Btf(data, d, d)


def test_lafortune_recovers_model_data_and_matches_numpy(tmp_path):
    btf = lafortune_data(2, 3, lobes=2, seed=1)
    m = btfrs.fit.lafortune(btf, kind="lum", lobes=2)
    assert m.error(btf).relative < 2e-3, m.error(btf)
    r = m.report
    assert r["converged"] + r["fell_back"] + r["failed"] == r["fits"] == 6
    v, l = np.array([0.2, 0.1, 0.97]), np.array([-0.4, 0.3, 0.87])
    v, l = v / np.linalg.norm(v), l / np.linalg.norm(l)
    np.testing.assert_allclose(m.evaluate(v, l), lafortune_numpy(m, v, l), rtol=1e-4, atol=1e-6)
    m.save(tmp_path / "laf.btfrs")
    back = btfrs.load(tmp_path / "laf.btfrs")
    assert isinstance(back, btfrs.Lafortune) and back.nbytes == m.nbytes
    np.testing.assert_array_equal(back.evaluate(v, l), m.evaluate(v, l))
    rgb = btfrs.fit.lafortune(btf, kind="rgb", lobes=2)
    assert rgb.arrays["params"].shape == (2, 3, 3, 9) and rgb.error(btf).relative < 0.05
    np.testing.assert_allclose(rgb.evaluate(v, l), lafortune_numpy(rgb, v, l), rtol=1e-4, atol=1e-6)


def test_lafortune_bad_input_is_a_clear_error():
    btf = lafortune_data(1, 2, lobes=1, seed=2)
    with pytest.raises(InvalidArgumentError, match="lobes"):
        btfrs.fit.lafortune(btf, lobes=8)
    with pytest.raises(InvalidArgumentError, match="kind"):
        btfrs.fit.lafortune(btf, kind="xyz")
    few = btf.select(views=[0], lights=[0, 1, 2])
    with pytest.raises(btfrs.DegenerateDataError):
        btfrs.fit.lafortune(few, lobes=2)
    black = btfrs.Btf(np.zeros_like(btf.data), btf.views, btf.lights)
    m = btfrs.fit.lafortune(black)
    p = m.arrays["params"]
    assert np.all(p[..., [0, 1, 2, 3, 5, 6, 7]] == 0) and np.all(np.isfinite(p))  # kd and every C; n stays in bounds
    assert np.all(m.evaluate([0, 0, 1], [0, 0, 1]) == 0)


def test_lafortune_held_out_error_is_no_worse_than_scipy_lm():
    knit = btfrs.materials.make("knit", size=16, seed=1)
    train, test = knit.split(holdout=0.1, seed=0)
    tr, te = baselines.crop(train, slice(4, 5), slice(4, 8)), baselines.crop(test, slice(4, 5), slice(4, 8))
    ref = baselines.lafortune_scipy(tr, te, lobes=2, jac="analytic")
    ours = btfrs.fit.lafortune(tr, kind="lum", lobes=2).error(te).relative
    assert ours <= ref["held_out"] * 1.02, (ours, ref)


# --- double SH -------------------------------------------------------------------------------


def sh_numpy(m, view, light):
    """The double sum with scipy's spherical harmonics (an independent basis) and the
    dequantized coefficients."""
    a = m.arrays
    c = a["q"].astype(np.float64) * a["scale"][None, None, :, None, None] + a["bias"][None, None, :, None, None]
    kv, kl = c.shape[3], c.shape[4]
    yv = baselines.real_sh(kv, np.asarray([view], float))[0]
    yl = baselines.real_sh(kl, np.asarray([light], float))[0]
    return np.einsum("hwcij,i,j->hwc", c, yv, yl)


def test_sh_evaluate_matches_scipy_harmonics_and_round_trips(bumps, tmp_path):
    m = btfrs.fit.sh(bumps, light_coeffs=16, view_coeffs=9)
    v, l = np.array([0.3, -0.2, 0.93]), np.array([-0.5, 0.4, 0.77])
    v, l = v / np.linalg.norm(v), l / np.linalg.norm(l)
    np.testing.assert_allclose(m.evaluate(v, l), sh_numpy(m, v, l), rtol=1e-4, atol=1e-5)
    # 8-bit coefficients in rows of whole words (16 light coefficients = 4 words), + scale, bias.
    assert m.nbytes == 16 * 16 * 3 * 9 * 16 + 24 == m.arrays["q"].nbytes + 24
    m.save(tmp_path / "sh.btfrs")
    back = btfrs.load(tmp_path / "sh.btfrs")
    np.testing.assert_array_equal(back.evaluate(v, l), m.evaluate(v, l))


def test_sh_plain_least_squares_equals_numpy_lstsq(bumps):
    small = baselines.crop(bumps, slice(0, 2), slice(0, 3))
    m = btfrs.fit.sh(small, light_coeffs=16, view_coeffs=9, cls=False, quantize=False)
    ref = baselines.sh_numpy_lstsq(small, view_coeffs=9, light_coeffs=16)["coeffs"]
    np.testing.assert_allclose(m.arrays["coeffs"], ref, rtol=1e-3, atol=1e-4 * np.abs(ref).max())


def test_sh_cls_survives_quantization_better_than_least_squares():
    """The paper's point (002, appendix): with noisy samples, 8-bit CLS coefficients
    reconstruct the clean function better than 8-bit plain least-squares ones."""
    clean = btfrs.materials.make("weave", size=8, seed=3)
    rng = np.random.default_rng(0)
    noisy = btfrs.Btf(clean.data + rng.normal(0, 0.05, clean.data.shape).astype(np.float32), clean.views, clean.lights)
    errs = {}
    for cls in (True, False):
        m = btfrs.fit.sh(noisy, light_coeffs=25, view_coeffs=25, cls=cls, quantize=True)
        errs[cls] = m.error(clean).relative
    assert errs[True] < errs[False], f"CLS {errs[True]:.4f} vs LS {errs[False]:.4f}"


def test_sh_streams_a_memory_mapped_btf(bumps, tmp_path):
    bumps.save(tmp_path / "b.btfrs")
    mm = btfrs.Btf.load(tmp_path / "b.btfrs", mmap=True)
    assert not mm.data.flags.owndata  # a view of the mapped file, not a copy
    a = btfrs.fit.sh(mm, light_coeffs=16, view_coeffs=16, chunk_texels=37)
    b = btfrs.fit.sh(bumps, light_coeffs=16, view_coeffs=16)
    np.testing.assert_array_equal(a.arrays["q"], b.arrays["q"])


def test_sh_bad_coefficient_counts_name_the_argument(bumps):
    with pytest.raises(InvalidArgumentError, match="light_coeffs"):
        btfrs.fit.sh(bumps, light_coeffs=24)
    with pytest.raises(InvalidArgumentError, match="view_coeffs"):
        btfrs.fit.sh(bumps, view_coeffs=81)


# --- Local PCA -------------------------------------------------------------------------------


def lpca_numpy(m, v, l):
    """offset + sum_j w_j q_kj(v, l) / 255 at a measured pair, from the arrays."""
    a = m.arrays
    ids, w = a["ids"], a["weights"].astype(np.float64)
    q = a["basis"][ids][:, :, :, v, l, :3].astype(np.float64) / 255  # [H, W, c+1, 3]
    return w[..., :1] + np.einsum("hwj,hwjc->hwc", w[..., 1:], q)


def test_lpca_matches_numpy_and_beats_sklearn_at_equal_size(tmp_path):
    knit = btfrs.materials.make("knit", size=16, seed=1)
    m = btfrs.fit.lpca(knit, clusters=8, components=4, seed=0)
    np.testing.assert_allclose(m.evaluate(knit.views[5], knit.lights[40]), lpca_numpy(m, 5, 40), rtol=1e-4, atol=1e-6)
    ref = baselines.lpca_sklearn(knit, clusters=8, components=4, seed=0)
    ours = m.error(knit).relative
    assert m.nbytes < ref["nbytes"] and ours < ref["reconstruction"], (ours, m.nbytes, ref)
    # Storage from the saved arrays (independent of the model's own count): u16 ids packed two to
    # a word, the float32 weights, the RGBA8 Eigen-BRDFs; scale and bias are folded in already.
    a = m.arrays
    assert m.nbytes == 4 * -(-a["ids"].size // 2) + a["weights"].nbytes + a["basis"].nbytes
    assert m.compression == pytest.approx(knit.data.size / m.nbytes)
    m.save(tmp_path / "l.btfrs")
    back = btfrs.load(tmp_path / "l.btfrs")
    np.testing.assert_array_equal(back.evaluate([0, 0, 1], [0.6, 0, 0.8]), m.evaluate([0, 0, 1], [0.6, 0, 0.8]))


def test_lpca_more_components_fit_better_and_seed_is_deterministic():
    b = btfrs.materials.make("grooves", size=16, seed=2)
    errs = [btfrs.fit.lpca(b, clusters=4, components=c, seed=1).error(b).relative for c in (1, 4, 8)]
    assert errs[0] > errs[1] > errs[2], errs
    a1 = btfrs.fit.lpca(b, clusters=4, components=2, seed=7).arrays
    a2 = btfrs.fit.lpca(b, clusters=4, components=2, seed=7).arrays
    for k in a1:
        np.testing.assert_array_equal(a1[k], a2[k])


def test_lpca_bad_input(bumps):
    with pytest.raises(InvalidArgumentError, match="clusters"):
        btfrs.fit.lpca(bumps, clusters=16 * 16 + 1)
    with pytest.raises(InvalidArgumentError, match="components"):
        btfrs.fit.lpca(bumps, components=99)
    bad = bumps.data.copy()
    bad[0, 0, 0, 0, 0] = np.nan
    with pytest.raises(InvalidArgumentError, match="data"):
        btfrs.fit.lpca(btfrs.Btf(bad, bumps.views, bumps.lights, check=False))


# --- Rendering: every model's shader against the CPU reference -------------------------------


def test_every_model_renders_like_its_cpu_reference(bumps):
    train, _ = bumps.split(holdout=0.1, seed=0)
    models = {"srf": btfrs.fit.srf(train), "lafortune": btfrs.fit.lafortune(train, lobes=1),
              "sh": btfrs.fit.sh(train, light_coeffs=16, view_coeffs=16),
              "lpca": btfrs.fit.lpca(train, clusters=4, components=2, seed=0)}
    scene, cam = btfrs.Scene.sphere(), btfrs.Camera.look_at([0, -3, 2], [0, 0, 0], 40)
    lights = [btfrs.PointLight([2, -2, 3], 8.0), btfrs.DirectionalLight([-1, -0.5, 1], 0.4)]
    for name, m in models.items():
        for method in (["9tap", "3d"] if name == "lpca" else [None]):
            kw = dict(size=(48, 64), uv_scale=2.0, renderer=method)
            g = btfrs.render(m, scene, cam, lights, **kw)
            c = btfrs.render(m, scene, cam, lights, backend="cpu", **kw)
            assert (c > 0).mean() > 0.2
            assert psnr(g, c) >= 40, (name, method, psnr(g, c))
    with pytest.raises(InvalidArgumentError, match="renderer"):
        btfrs.render(models["sh"], scene, cam, lights, renderer="3d")


def test_lpca_3d_texture_renderer_agrees_with_the_9tap_one():
    # Paper 004 Table 1 puts the two renderers >= 35 dB apart. The 3D texture carries the light
    # blend with the cosine divided out (its alpha channel: the weights' sum), as the 9-tap
    # renderer blends; without it they were 34 dB apart on knit. Measured here: 40.2 dB.
    btf = btfrs.materials.make("knit", size=32, seed=1)
    m = btfrs.fit.lpca(btf, clusters=8, components=3, seed=0)
    scene, cam = btfrs.Scene.sphere(), btfrs.Camera.look_at([0, -3, 2], [0, 0, 0], 40)
    lights = [btfrs.PointLight([2.0, -2.0, 3.0], 8.0)]
    kw = dict(size=160, uv_scale=4, backend="cpu")
    a = btfrs.render(m, scene, cam, lights, renderer="9tap", **kw)
    b = btfrs.render(m, scene, cam, lights, renderer="3d", **kw)
    assert (a > 0).mean() > 0.2
    assert psnr(a, b) >= 38, psnr(a, b)


def test_every_registered_model_uploads_exactly_its_nbytes_and_round_trips(tmp_path):
    # For every model of the registry (no model named here): the bytes the GPU actually allocated
    # for its store (measured from the wgpu buffers) equal nbytes; saving and loading gives the
    # same arrays and the same images; the generic Model API works on it.
    from btfrs import rendering

    btf = btfrs.materials.make("weave", size=8, seed=2)
    kinds = btfrs.model_kinds()
    assert set(kinds) >= {"ptm", "lafortune", "srf", "sh", "lpca"}
    for kind, info in kinds.items():
        label, options = info["examples"][0]
        m = btfrs.fit.fit(kind, btf, **options)
        assert m.kind == kind and isinstance(m, btfrs.Model) and m.renderers == info["renderers"]
        up, _ = rendering._upload(m, m.renderers[0])
        assert up.device_bytes == m.nbytes, (label, up.device_bytes, m.nbytes)
        m.save(tmp_path / f"{kind}.btfrs")
        back = btfrs.load(tmp_path / f"{kind}.btfrs")
        assert type(back) is type(m) and back.report == m.report and back.fit_seconds == m.fit_seconds
        for name, arr in m.arrays.items():
            np.testing.assert_array_equal(back.arrays[name], arr)
        again = btfrs.Model.from_arrays(m.arrays, kind=kind)
        v, l = [0.2, 0.1, 0.97], [-0.3, 0.5, 0.8]
        np.testing.assert_array_equal(again.evaluate(v, l), m.evaluate(v, l))
        assert getattr(btfrs.fit, kind) is not None


def test_fit_options_are_checked_by_the_model():
    btf = btfrs.materials.make("weave", size=8, seed=2)
    with pytest.raises(btfrs.InvalidArgumentError, match="lobez: unknown option; expected one of kind, lobes"):
        btfrs.fit.fit("lafortune", btf, lobez=2)
    with pytest.raises(btfrs.InvalidArgumentError, match="clusters: expected an integer >= 1, got -1"):
        btfrs.fit.fit("lpca", btf, clusters=-1)
    with pytest.raises(btfrs.InvalidArgumentError, match="model: unknown model .nope.; expected one of"):
        btfrs.fit.fit("nope", btf)
