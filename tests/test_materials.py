import numpy as np
import pytest

import btfrs
from btfrs.directions import from_theta_phi
from btfrs.exceptions import InvalidArgumentError


def test_presets_and_determinism():
    assert btfrs.materials.names() == ["knit", "weave", "bumps", "grooves"]
    a = btfrs.materials.make("bumps", size=16, seed=5)
    b = btfrs.materials.make("bumps", size=16, seed=5)
    c = btfrs.materials.make("bumps", size=16, seed=6)
    np.testing.assert_array_equal(a.data, b.data)
    assert not np.array_equal(a.data, c.data)
    assert a.shape == (16, 16, 81, 81, 3) and np.all(a.data >= 0) and np.all(np.isfinite(a.data))


def test_presets_differ_from_each_other():
    imgs = [btfrs.materials.make(n, size=32, seed=0).image(0, 40) for n in btfrs.materials.names()]
    for i in range(len(imgs)):
        for j in range(i + 1, len(imgs)):
            assert np.abs(imgs[i] - imgs[j]).mean() > 0.02


def test_flat_relief_is_shadowless_lambert_plus_lobe():
    # With relief 0 a light at normal incidence and one at 60 degrees differ only by the cosine
    # (and the lobe, which is negligible far from the mirror direction).
    v = from_theta_phi(np.radians(75), np.pi)[None]  # far from both lights' mirror directions
    lights = from_theta_phi(np.radians([0.0, 60.0]), [np.pi, np.pi])
    b = btfrs.materials.make("weave", size=16, relief=0.0, views=v, lights=lights)
    ratio = b.data[:, :, 0, 1] / b.data[:, :, 0, 0]
    np.testing.assert_allclose(ratio, 0.5, rtol=0.02)


def test_relief_casts_shadows_at_grazing_light():
    lights = from_theta_phi(np.radians([0.0, 75.0]), [0.0, 0.0])
    top = np.array([[0.0, 0.0, 1.0]])
    b = btfrs.materials.make("knit", size=32, views=top, lights=lights)
    flat = btfrs.materials.make("knit", size=32, views=top, lights=lights, relief=0.0)
    # Normalised by the overhead image, a grazing light leaves a large share of the relief dark.
    dark = np.mean(b.data[:, :, 0, 1].mean(-1) < 0.1 * b.data[:, :, 0, 0].mean(-1))
    dark_flat = np.mean(flat.data[:, :, 0, 1].mean(-1) < 0.1 * flat.data[:, :, 0, 0].mean(-1))
    assert dark > 0.15 and dark_flat == 0


def test_bad_arguments():
    with pytest.raises(InvalidArgumentError, match='name: unknown material "velvet"; expected one of knit, weave, bumps, grooves'):
        btfrs.materials.make("velvet")
    with pytest.raises(InvalidArgumentError, match=r"size: expected an integer in \[8, 1024\], got 4"):
        btfrs.materials.make("knit", size=4)
    with pytest.raises(TypeError, match="size"):
        btfrs.materials.make("knit", size=16.5)
    with pytest.raises(InvalidArgumentError, match="lights"):
        btfrs.materials.make("knit", size=16, lights=np.array([[0, 0, 3.0]]))


def test_progress_callback_sees_the_whole_job():
    seen = []
    btfrs.materials.make("grooves", size=16, progress=lambda d, t: seen.append((d, t)))
    assert seen and seen[-1][0] == seen[-1][1] > 0
