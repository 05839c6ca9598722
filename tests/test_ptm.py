import numpy as np
import pytest

import btfrs
from btfrs.exceptions import DegenerateDataError, InvalidArgumentError
from conftest import biquadratic_data

D = btfrs.directions.ubo81()


def numpy_ptm_rgb(btf):
    """The plain float64 numpy way: numpy.linalg.pinv per view slot, applied to every texel."""
    h, w, v, l, _ = btf.shape
    out = np.zeros((h, w, v, 3, 6))
    for vi in range(v):
        ls = np.arange(l) if btf.mask is None else np.flatnonzero(btf.mask[vi])
        lx, ly = btf.lights[ls, 0], btf.lights[ls, 1]
        a = np.stack([lx * lx, ly * ly, lx * ly, lx, ly, np.ones_like(lx)], axis=1)
        p = np.linalg.pinv(a)  # [6, n]
        out[:, :, vi] = np.einsum("kn,hwnc->hwck", p, btf.data[:, :, vi, ls].astype(np.float64))
    return out


def test_recovers_a_biquadratic_exactly():
    # Floats (bits=32): the fit itself is exact; the default 8-bit planes within half a step.
    data, coef = biquadratic_data(4, 5, D, D, seed=1)
    ptm = btfrs.fit.ptm(btfrs.Btf(data, D, D), bits=32)
    np.testing.assert_allclose(ptm.coeffs, coef, atol=3e-5)
    assert ptm.error(btfrs.Btf(data, D, D)).relative < 1e-5
    q = btfrs.fit.ptm(btfrs.Btf(data, D, D))
    step = q.arrays["coeffs_scale"].reshape(q.arrays["coeffs_q"].shape[2:])
    assert np.all(np.abs(q.coeffs - coef) <= step / 2 + 3e-5)
    assert q.error(btfrs.Btf(data, D, D)).relative < 0.01


def test_agrees_with_float64_numpy_on_a_material(knit):
    train, test = knit.split(holdout=0.1, seed=0)
    ours = btfrs.fit.ptm(train, bits=32).coeffs.astype(np.float64)
    ref = numpy_ptm_rgb(train)
    assert np.max(np.abs(ours - ref)) / np.max(np.abs(ref)) < 1e-5


def test_lrgb_matches_its_definition(knit):
    sub = knit.select(views=[0, 40])
    ptm = btfrs.fit.ptm(sub, kind="lrgb", bits=32)
    c, rgb = ptm.coeffs.astype(np.float64), ptm.rgb.astype(np.float64)
    assert c.shape == (32, 32, 2, 6) and rgb.shape == (32, 32, 2, 3)
    lx, ly = D[:, 0], D[:, 1]
    a = np.stack([lx * lx, ly * ly, lx * ly, lx, ly, np.ones_like(lx)], axis=1)
    x = sub.data.astype(np.float64)
    lum = x.mean(axis=-1)  # [h, w, v, l]
    ref = np.einsum("kl,hwvl->hwvk", np.linalg.pinv(a), lum)
    fitted = np.einsum("hwvk,lk->hwvl", ref, a)
    base = np.einsum("hwvl,hwvlc->hwvc", fitted, x) / np.einsum("hwvl,hwvl->hwv", fitted, fitted)[..., None]
    m = base.max(axis=-1, keepdims=True)
    np.testing.assert_allclose(rgb, base / m, atol=2e-5)
    np.testing.assert_allclose(c, ref * m, atol=2e-5 * np.abs(ref * m).max())
    # The model is luminance times base colour.
    img = ptm.evaluate(D[40], D[7])
    np.testing.assert_allclose(img, (np.einsum("hwk,k->hw", c[:, :, 1], a[7])[..., None] * rgb[:, :, 1]), atol=1e-5)


@pytest.mark.parametrize("name", btfrs.materials.names())
def test_held_out_error_on_every_material(name):
    # A biquadratic cannot model hard shadows or the shiny grooves' highlights: the held-out error
    # is large but bounded, and the reconstruction error (on the fitted pairs) is not above it.
    btf = btfrs.materials.make(name, size=24, seed=2)
    train, test = btf.split(holdout=0.1, seed=0)
    for kind in ("rgb", "lrgb"):
        ptm = btfrs.fit.ptm(train, kind=kind)
        held, rec = ptm.error(test), ptm.error(train)
        assert 0.01 < held.relative < (0.7 if name == "grooves" else 0.45), (name, kind, held)
        assert rec.relative < held.relative * 1.05
        assert held.samples == test.pairs * 24 * 24 * 3


def test_held_out_pairs_are_not_used(knit):
    train, test = knit.select(views=[0, 5]).split(holdout=0.2, seed=1)
    a = btfrs.fit.ptm(train).coeffs
    poisoned = train.data.copy()
    poisoned[:, :, ~train.mask] = 1e6
    b = btfrs.fit.ptm(btfrs.Btf(poisoned, train.views, train.lights, train.mask)).coeffs
    np.testing.assert_array_equal(a, b)


def test_evaluate_at_a_slot_is_the_polynomial(knit):
    ptm = btfrs.fit.ptm(knit.select(views=slice(0, 10)))
    light = np.array([0.3, 0.2, 0.93])
    img = ptm.evaluate(view=ptm.views[4], light=light)
    l = light / np.linalg.norm(light)
    basis = np.array([l[0] ** 2, l[1] ** 2, l[0] * l[1], l[0], l[1], 1.0])
    np.testing.assert_allclose(img, ptm.coeffs[:, :, 4] @ basis, rtol=1e-5, atol=1e-6)
    assert img.shape == (32, 32, 3) and img.dtype == np.float32
    with pytest.raises(InvalidArgumentError, match="view"):
        ptm.evaluate(view=[0, 0, 0], light=light)


def test_too_few_or_collinear_lights():
    data = np.ones((2, 2, 3, 5, 3), np.float32)
    with pytest.raises(DegenerateDataError, match="has 5 lights; a biquadratic PTM needs at least 6"):
        btfrs.fit.ptm(btfrs.Btf(data, D[:3], D[:5]), on_degenerate="raise")
    theta = np.radians(np.linspace(-70, 70, 12))
    arc = np.stack([np.sin(theta), np.zeros_like(theta), np.cos(theta)], axis=1)  # all in the xz plane
    data = np.ones((2, 2, 1, 12, 3), np.float32) * 0.5
    b = btfrs.Btf(data, D[:1], arc)
    with pytest.raises(DegenerateDataError, match="collinear"):
        btfrs.fit.ptm(b, on_degenerate="raise")
    clamped = btfrs.fit.ptm(b, on_degenerate="clamp", bits=32)
    assert clamped.error(b).rmse < 1e-6 and np.all(np.isfinite(clamped.coeffs))
    with pytest.raises(InvalidArgumentError, match="on_degenerate"):
        btfrs.fit.ptm(b, on_degenerate="ignore")
    with pytest.raises(InvalidArgumentError, match="kind"):
        btfrs.fit.ptm(b, kind="lum")


def test_save_load_and_nbytes(tmp_path, knit):
    for kind, per in (("rgb", 18), ("lrgb", 9)):
        ptm = btfrs.fit.ptm(knit.select(views=[0, 1, 2]), kind=kind)
        # 8-bit planes: one byte per value and a scale and a bias per plane (3 views x per)
        assert ptm.nbytes == 32 * 32 * 3 * per + 8 * 3 * per
        assert btfrs.fit.ptm(knit.select(views=[0, 1, 2]), kind=kind, bits=32).nbytes == 32 * 32 * 3 * per * 4
        ptm.save(tmp_path / f"{kind}.btfrs")
        back = btfrs.load(tmp_path / f"{kind}.btfrs")
        assert isinstance(back, btfrs.Ptm) and back.variant == kind
        np.testing.assert_array_equal(back.coeffs, ptm.coeffs)
        np.testing.assert_array_equal(back.evaluate(D[1], D[9]), ptm.evaluate(D[1], D[9]))


def test_black_texels_give_zero_coefficients_not_nan():
    data = np.zeros((2, 3, 2, 81, 3), np.float32)
    data[1, 2] = 0.25  # one lit texel
    b = btfrs.Btf(data, D[:2], D)
    for kind in ("rgb", "lrgb"):
        m = btfrs.fit.ptm(b, kind=kind)
        assert np.all(np.isfinite(m.coeffs))
        # 8-bit planes decode a zero as bias + scale * q: zero up to float rounding
        assert np.all(np.abs(m.coeffs[0, 0]) < 1e-6)
        assert np.all(btfrs.fit.ptm(b, kind=kind, bits=32).coeffs[0, 0] == 0)
        # the lit texel within half an 8-bit step (its a5 plane spans [0, 0.25])
        np.testing.assert_allclose(m.evaluate(D[1], D[30])[1, 2], 0.25, atol=0.25 / 510)
        if kind == "lrgb":
            np.testing.assert_array_equal(m.rgb[0, 0], 0)
            np.testing.assert_allclose(m.rgb[1, 2], 1.0, rtol=1e-6)


def test_between_slots_the_image_is_a_blend_of_the_nearest_slots(knit):
    # Between measured views, every pixel lies within the range of the nearest slots' values
    # (a convex combination), and a small move of the view moves the image a little.
    ptm = btfrs.fit.ptm(knit)
    light = D[30]
    theta = np.radians(37.0)
    v = np.array([np.sin(theta) * np.cos(0.3), np.sin(theta) * np.sin(0.3), np.cos(theta)])
    img = ptm.evaluate(v, light)
    ang = np.arccos(np.clip(D @ v, -1, 1))
    near = np.argsort(ang)[:3]
    slots = np.stack([ptm.evaluate(D[i], light) for i in near])
    assert np.all(img >= slots.min(0) - 1e-5) and np.all(img <= slots.max(0) + 1e-5)
    assert not np.allclose(img, slots[0])
    v2 = v + np.array([1e-4, 0, 0])
    assert np.max(np.abs(ptm.evaluate(v2, light) - img)) < 1e-2
