import numpy as np
import pytest

import btfrs
from btfrs import hemimap
from btfrs.directions import from_theta_phi, to_theta_phi, ubo81


def test_ubo81_rings():
    d = ubo81()
    theta, phi = to_theta_phi(d, degrees=True)
    rings, counts = np.unique(np.round(theta, 6), return_counts=True)
    np.testing.assert_allclose(rings, [0, 15, 30, 45, 60, 75])
    np.testing.assert_array_equal(counts, [1, 6, 12, 18, 20, 24])
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1, atol=1e-15)
    # Azimuths start at 0 on every ring and are evenly spaced.
    for r, n in zip(rings[1:], counts[1:]):
        np.testing.assert_allclose(np.sort(phi[np.isclose(theta, r)]), np.arange(n) * 360 / n, atol=1e-9)


def test_theta_phi_round_trip():
    rng = np.random.default_rng(0)
    t, p = rng.uniform(0, np.pi / 2, 1000), rng.uniform(0, 2 * np.pi, 1000)
    t2, p2 = to_theta_phi(from_theta_phi(t, p))
    np.testing.assert_allclose(t2, t, atol=1e-12)
    np.testing.assert_allclose(p2, p, atol=1e-12)


def reference_square_to_hemisphere(st):
    """float64 numpy transcription of paper 004, section 6.1 (Shirley-Chiu + elevation)."""
    a, b = 2 * st[..., 0] - 1, 2 * st[..., 1] - 1
    rho = np.where(np.abs(a) > np.abs(b), a, b)
    with np.errstate(divide="ignore", invalid="ignore"):
        phi = np.where(np.abs(a) > np.abs(b), np.pi / 4 * b / a, np.pi / 2 - np.pi / 4 * a / b)
    phi = np.where((a == 0) & (b == 0), 0.0, phi)
    r = rho * np.sqrt(2 - rho * rho)
    return np.stack([r * np.cos(phi), r * np.sin(phi), 1 - rho * rho], axis=-1)


def test_forward_map_matches_the_paper():
    g = np.linspace(0, 1, 101)
    st = np.stack(np.meshgrid(g, g, indexing="ij"), axis=-1)
    np.testing.assert_allclose(hemimap.square_to_hemisphere(st), reference_square_to_hemisphere(st), atol=1e-12)


@pytest.mark.parametrize("dtype, tol", [(np.float32, 1e-5), (np.float64, 1e-12)])
def test_round_trips(dtype, tol):
    g = np.linspace(0, 1, 257)
    st = np.stack(np.meshgrid(g, g, indexing="ij"), axis=-1).astype(dtype)
    d = hemimap.square_to_hemisphere(st)
    assert d.dtype == dtype and d.shape == (257, 257, 3)
    assert np.max(np.abs(hemimap.hemisphere_to_square(d) - st)) < tol
    xy = hemimap.square_to_disk(st)
    assert np.max(np.abs(hemimap.disk_to_square(xy) - st)) < tol


def test_equal_area():
    # Cell centres of a uniform grid land in equal-area bins of the hemisphere: bands of equal
    # height in z (area on the sphere is proportional to dz dphi) times equal azimuth sectors.
    n = 1024
    g = (np.arange(n) + 0.5) / n
    st = np.stack(np.meshgrid(g, g, indexing="ij"), axis=-1).reshape(-1, 2)
    d = hemimap.square_to_hemisphere(st)
    zb = np.minimum((d[:, 2] * 8).astype(int), 7)
    pb = np.minimum((np.mod(np.arctan2(d[:, 1], d[:, 0]), 2 * np.pi) / (2 * np.pi) * 16).astype(int), 15)
    counts = np.bincount(zb * 16 + pb, minlength=128)
    assert np.max(np.abs(counts / counts.mean() - 1)) < 0.02


def test_continuity_across_regions_and_centre():
    eps = 1e-7
    t = np.linspace(0.01, 0.99, 99)
    for a, b in [(np.c_[t, t], np.c_[t + eps, t]), (np.c_[t, 1 - t], np.c_[t + eps, 1 - t]),
                 (np.c_[[0.5], [0.5]], np.c_[[0.5 + eps], [0.5 - eps]])]:
        da, db = hemimap.square_to_hemisphere(a), hemimap.square_to_hemisphere(b)
        assert np.max(np.linalg.norm(da - db, axis=1)) < 10 * eps


def test_poles_and_horizon():
    np.testing.assert_array_equal(hemimap.hemisphere_to_square(np.array([0.0, 0.0, 1.0])), [0.5, 0.5])
    phi = np.linspace(0, 2 * np.pi, 73)
    st = hemimap.hemisphere_to_square(np.stack([np.cos(phi), np.sin(phi), np.zeros_like(phi)], -1))
    np.testing.assert_allclose(np.max(np.abs(2 * st - 1), axis=1), 1, atol=1e-6)
    np.testing.assert_allclose(hemimap.square_to_hemisphere(np.array([1.0, 0.5])), [1, 0, 0], atol=1e-15)


def test_bad_input():
    with pytest.raises(ValueError, match="st: expected shape"):
        hemimap.square_to_hemisphere(np.zeros((4, 3)))
    with pytest.raises(ValueError, match="not finite"):
        hemimap.hemisphere_to_square(np.array([[np.nan, 0, 1]]))
