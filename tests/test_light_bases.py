"""The RTI light bases of relight (RBF, bilinear): their arrays evaluated independently in numpy,
their fits against float64 numpy references, single-view captures with held-out lights, save /
load, degenerate inputs and option errors."""

import numpy as np
import pytest

import btfrs
from btfrs import hemimap
from btfrs.exceptions import DegenerateDataError, InvalidArgumentError


def rti_lights(n, seed=0, reach=0.42):
    """``n`` lights spread over the hemisphere (jittered on the concentric square, up to ~75 deg)."""
    rng = np.random.default_rng(seed)
    st = 0.5 + reach * (2 * rng.random((n, 2)) - 1)
    return hemimap.square_to_hemisphere(st)


@pytest.fixture(scope="module")
def capture():
    """A single-view capture: 16^2 bumps, one view at the normal, 140 lights."""
    return btfrs.materials.make("bumps", size=16, seed=2, views=np.array([[0.0, 0.0, 1.0]]), lights=rti_lights(140, 1))


def numpy_eval(m, light):
    """The model at view (0, 0, 1) (a one-slot model) from its arrays, in float64."""
    a = m.arrays
    n = a["table"].shape[1]
    colour, km, kc = (int(x) for x in a["layout"])
    st = hemimap.hemisphere_to_square(np.asarray(light, float))
    x = np.clip(st * (n - 1), 0, n - 1)
    i = np.minimum(np.floor(x).astype(int), n - 2)
    f = x - i
    t = a["table"][0].astype(np.float64)
    row = ((1 - f[0]) * (1 - f[1]) * t[i[1], i[0]] + f[0] * (1 - f[1]) * t[i[1], i[0] + 1]
           + (1 - f[0]) * f[1] * t[i[1] + 1, i[0]] + f[0] * f[1] * t[i[1] + 1, i[0] + 1])
    c = m.coeffs[:, :, 0, :].astype(np.float64)
    if colour == 0:
        comp = row[3:].reshape(km, 3)
        return row[:3] + np.einsum("hwk,kc->hwc", c, comp)
    y = row[0] + c[..., :km] @ row[3:3 + km]
    ch = row[1:3] + np.einsum("hwk,kc->hwc", c[..., km:], row[3 + km:].reshape(kc, 2))
    cb, cr = ch[..., 0], ch[..., 1]
    return np.stack([y + cr, y - cb - cr, y + cb], axis=-1)


@pytest.mark.parametrize("kind,opts", [("rbf", {}), ("bilinear", {}), ("rbf", dict(colour="ycc", components=8)),
                                       ("bilinear", dict(colour="ycc", chroma_components=3, resolution=6))])
def test_arrays_evaluate_like_the_model(capture, kind, opts):
    m = btfrs.fit.fit(kind, capture, **opts)
    assert isinstance(m, btfrs.models.Rbf if kind == "rbf" else btfrs.models.Bilinear)
    assert m.coeffs.shape[:3] == (16, 16, 1) and m.arrays["coeffs_q"].dtype == np.uint8
    for light in ([0.0, 0.0, 1.0], [0.5, -0.3, np.sqrt(0.66)], [-0.8, 0.1, np.sqrt(0.35)]):
        got = m.evaluate([0, 0, 1], light)
        want = numpy_eval(m, light)
        assert np.abs(got - want).max() < 1e-4 * max(1.0, np.abs(want).max()), (kind, light)


def test_nbytes_is_planes_scales_and_table(capture):
    m = btfrs.fit.rbf(capture, components=9, resolution=8)
    k, g = 9, 64
    assert m.nbytes == 16 * 16 * k + 8 * k + 4 * g * (3 + 3 * k)
    y = btfrs.fit.rbf(capture, components=9, colour="ycc", chroma_components=2, resolution=8)
    assert y.nbytes == 16 * 16 * 11 + 8 * 11 + 4 * g * (3 + 9 + 4)
    assert y.planes == 11 and y.colour == "ycc" and y.resolution == 8


def rbf_numpy(lights, y, targets, width, reg):
    """The RBF interpolant of the module doc in float64 (independent of the Rust operator)."""
    zmin = lights[:, 2].min()
    spacing = np.sqrt(2 * np.pi * (1 - zmin) / len(lights))
    s2 = 2 * (width * spacing) ** 2
    k = np.exp(-((lights[:, None] - lights[None]) ** 2).sum(-1) / s2)
    mu = y.mean(0)
    a = np.linalg.solve(k + reg * np.eye(len(lights)), y - mu)
    kx = np.exp(-((targets[:, None] - lights[None]) ** 2).sum(-1) / s2)
    return mu + kx @ a


def grid_nodes(n):
    i = np.arange(n) / (n - 1)
    st = np.stack(np.meshgrid(i, i, indexing="xy"), -1).reshape(-1, 2)  # node j n + i
    return hemimap.square_to_hemisphere(st)


def bilinear_lookup(grid_vals, n, light):
    st = hemimap.hemisphere_to_square(np.asarray(light, float))
    x = np.clip(st * (n - 1), 0, n - 1)
    i = np.minimum(np.floor(x).astype(int), n - 2)
    f = x - i
    g = grid_vals.reshape(n, n, -1)
    return ((1 - f[0]) * (1 - f[1]) * g[i[1], i[0]] + f[0] * (1 - f[1]) * g[i[1], i[0] + 1]
            + (1 - f[0]) * f[1] * g[i[1] + 1, i[0]] + f[0] * f[1] * g[i[1] + 1, i[0] + 1])


def one_texel(lights, seed):
    rng = np.random.default_rng(seed)
    vals = np.abs(rng.normal(size=(len(lights), 3))).astype(np.float32) + 0.1 * lights[:, 2:3].astype(np.float32)
    return btfrs.Btf(vals.reshape(1, 1, 1, len(lights), 3), np.array([[0.0, 0.0, 1.0]]), lights)


def test_rbf_fit_matches_a_float64_numpy_reference():
    # One texel: the PCA keeps only the mean, so the model is the resampled interpolant itself.
    lights = rti_lights(30, 5)
    b = one_texel(lights, 1)
    n, width, reg = 10, 1.3, 1e-2
    m = btfrs.fit.rbf(b, components=2, resolution=n, width=width, regularization=reg)
    grid = rbf_numpy(lights, b.data[0, 0, 0].astype(np.float64), grid_nodes(n), width, reg)
    for light in ([0.1, 0.2, np.sqrt(0.95)], [-0.5, 0.4, np.sqrt(0.59)]):
        want = bilinear_lookup(grid, n, light)
        got = m.evaluate([0, 0, 1], light)[0, 0]
        assert np.abs(got - want).max() < 1e-4, (got, want)


def test_bilinear_fit_matches_a_float64_numpy_reference():
    lights = rti_lights(40, 6)
    b = one_texel(lights, 2)
    n, reg = 6, 0.3
    m = btfrs.fit.bilinear(b, components=1, resolution=n, regularization=reg)
    g = n * n
    bm = np.zeros((len(lights), g))
    for j, l in enumerate(lights):
        e = np.eye(g)
        bm[j] = bilinear_lookup(e, n, l)
    d = []
    for r in range(n):
        for c in range(1, n - 1):
            for idx in ((r * n + c - 1, r * n + c, r * n + c + 1), ((c - 1) * n + r, c * n + r, (c + 1) * n + r)):
                row = np.zeros(g)
                row[list(idx)] = [1, -2, 1]
                d.append(row)
    d = np.array(d)
    btb, dtd = bm.T @ bm, d.T @ d
    lam = reg * np.trace(btb) / np.trace(dtd)
    y = b.data[0, 0, 0].astype(np.float64)
    grid = np.linalg.solve(btb + lam * dtd, bm.T @ y)  # the tiny ridge of the Rust fit is negligible here
    for light in ([0.1, 0.2, np.sqrt(0.95)], [-0.5, 0.4, np.sqrt(0.59)]):
        want = bilinear_lookup(grid, n, light)
        got = m.evaluate([0, 0, 1], light)[0, 0]
        assert np.abs(got - want).max() < 1e-4, (got, want)


@pytest.mark.parametrize("kind", ["rbf", "bilinear"])
def test_held_out_lights_improve_with_components_and_beat_the_ptm_per_byte(capture, kind):
    tr, te = capture.split(holdout=0.15, seed=0)
    errs = [btfrs.fit.fit(kind, tr, components=k).error(te).relative for k in (2, 6, 18)]
    assert errs[0] > errs[1] > errs[2], errs
    ptm = btfrs.fit.ptm(tr)
    assert errs[2] < ptm.error(te).relative


@pytest.mark.parametrize("kind", ["rbf", "bilinear"])
def test_save_load_round_trip(capture, kind, tmp_path):
    m = btfrs.fit.fit(kind, capture, components=5)
    p = tmp_path / f"{kind}.btfrs"
    m.save(p)
    r = btfrs.load(p)
    assert r.kind == kind and r.nbytes == m.nbytes
    light = [0.3, 0.3, np.sqrt(0.82)]
    np.testing.assert_array_equal(r.evaluate([0, 0, 1], light), m.evaluate([0, 0, 1], light))


def test_multi_view_btfs_blend_slots():
    b = btfrs.materials.make("knit", size=8, seed=1)
    m = btfrs.fit.rbf(b, components=4, resolution=8)
    assert m.views.shape == (81, 3) and m.coeffs.shape == (8, 8, 81, 4)
    tr, te = b.split(holdout=0.1, seed=0)
    assert btfrs.fit.bilinear(tr, components=6).error(te).relative < 0.5


def test_degenerate_inputs():
    # One light: the constant.
    b = one_texel(rti_lights(1, 3), 3)
    m = btfrs.fit.rbf(b, components=1)
    np.testing.assert_allclose(m.evaluate([0, 0, 1], [0.5, 0.0, np.sqrt(0.75)])[0, 0], b.data[0, 0, 0, 0], atol=1e-5)
    m = btfrs.fit.bilinear(b, components=1)
    np.testing.assert_allclose(m.evaluate([0, 0, 1], [0.5, 0.0, np.sqrt(0.75)])[0, 0], b.data[0, 0, 0, 0], atol=1e-4)
    # Duplicate lights without regularization.
    lights = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.6, 0.0, 0.8]])
    with pytest.raises(DegenerateDataError, match="positive regularization"):
        btfrs.fit.rbf(one_texel(lights, 4), regularization=0.0)
    # A view slot without lights borrows the nearest view's lights, and the report says so.
    kn = btfrs.materials.make("knit", size=8, seed=1, views=np.array([[0, 0, 1.0], [0.6, 0, 0.8]]),
                              lights=rti_lights(20, 1))
    mask = np.ones((2, 20), bool)
    mask[1] = False
    m = btfrs.fit.bilinear(btfrs.Btf(kn.data, kn.views, kn.lights, mask))
    assert m.report["pooled_slots"] == [{"slot": 1, "lights": 0, "from": [0]}]
    np.testing.assert_allclose(m.evaluate([0.6, 0, 0.8], [0.3, 0.2, np.sqrt(0.87)]),
                               m.evaluate([0, 0, 1.0], [0.3, 0.2, np.sqrt(0.87)]), atol=1e-6)


@pytest.mark.parametrize("call,name", [
    (lambda b: btfrs.fit.rbf(b, components=0), "components"),
    (lambda b: btfrs.fit.rbf(b, colour="hsv"), "colour"),
    (lambda b: btfrs.fit.rbf(b, resolution=1), "resolution"),
    (lambda b: btfrs.fit.rbf(b, width=0), "width"),
    (lambda b: btfrs.fit.bilinear(b, regularization=-1), "regularization"),
    (lambda b: btfrs.fit.bilinear(b, chroma_components=2), "chroma_components"),
    (lambda b: btfrs.fit.fit("rbf", b, componentz=3), "componentz"),
])
def test_bad_options_name_the_argument(capture, call, name):
    with pytest.raises(InvalidArgumentError, match=f"^{name}"):
        call(capture)


def test_rti_bench_section(tmp_path):
    from btfrs.tools import bench
    from btfrs.models import model_kinds

    lights = bench.rti_lights(150, 0)
    assert lights.shape == (150, 3)
    np.testing.assert_allclose(np.linalg.norm(lights, axis=1), 1.0, atol=1e-12)
    assert lights[:, 2].min() >= np.cos(np.radians(80)) - 1e-12
    # Spread: no two lights closer than a third of the even spacing.
    d = np.linalg.norm(lights[:, None] - lights[None], axis=-1) + 10 * np.eye(150)
    assert d.min() > np.sqrt(2 * np.pi * (1 - np.cos(np.radians(80))) / 150) / 3
    kinds = {k for _, k, _ in bench.rti_settings()}
    assert kinds == set(model_kinds()) - {"lafortune", "srf"}
    res = bench.rti_bench(captures=(("bumps", 100),), size=8, chart_dir=str(tmp_path))
    assert (tmp_path / "rti_bumps.png").stat().st_size > 10_000
    rows = res[0]["rows"]
    assert all(r["heldout_pairs"] is not None for r in rows), [r for r in rows if r.get("error")]
    s = bench.rti_summary(res)
    assert "best < 100 KB" in s and "relight RBF, 18 planes 24.6% in 85 KB" in s
