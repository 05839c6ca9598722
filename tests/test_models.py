"""The models beyond PTM (Phong + SRF, Lafortune, double SH, LPCA): each checked against an
independent numpy evaluation of its own arrays, a fit of data made by the model itself, its
stability behaviours, save/load, and its shader against the CPU reference renderer."""

import numpy as np
import pytest

import btfrs
from btfrs import baselines
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
        train, test = btf.split(0.1, seed=0)
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
    assert back.report == pytest.approx(m.report)
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
