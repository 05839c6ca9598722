"""Ground truth by path tracing (btfrs.tools.groundtruth, issue 14 part 5): a BTF measured with
Mitsuba 3 from a known heightfield, rendered by btfrs on a plane, against the path trace of the
repeated heightfield under the same camera and light.

Mitsuba is an optional dependency that scripts/setup.sh installs; without it these tests skip,
except in CI (CI=true), where a missing Mitsuba is a failure, not a silent skip.
"""

import math

import numpy as np
import pytest

import btfrs
from btfrs.tools import groundtruth as gt
from btfrs.exceptions import InvalidArgumentError

from conftest import in_ci

if not gt.available():
    if in_ci():
        raise RuntimeError("CI: Mitsuba 3 (llvm_ad_rgb) must be installed for the ground-truth tests "
                           "(scripts/setup.sh installs it)")
    pytest.skip("Mitsuba 3 with an LLVM variant is not installed", allow_module_level=True)


def test_a_flat_heightfield_measures_albedo_times_cos():
    # Closed form: a flat diffuse plane of albedo a under irradiance 1 reads a * cos(theta_l)
    # (btfrs's unit, pi x radiance) at every texel and view, whatever the view.
    d = btfrs.directions.ubo81()
    lights = d[[0, 7, 30, 70]]
    b = gt.measure_btf(gt.Heightfield(amplitude=0.0, albedo=0.6), d[[0, 20, 60]], lights, texels=4, spp=4)
    assert b.shape == (4, 4, 3, 4, 3)
    expect = 0.6 * lights[:, 2]
    np.testing.assert_allclose(b.data, np.broadcast_to(expect[None, None, None, :, None], b.shape), rtol=2e-5)


def test_shadowing_only_removes_light_and_interreflections_only_add_it():
    # Property: for a heightfield seen from above, direct light averaged over the reference
    # plane is at most albedo * cos(theta_l) (all the flux through the plane lands on the
    # surface, and a tilted facet's footprint is smaller than its area), with equality only for
    # a flat sample; more bounces only add light.
    d = btfrs.directions.ubo81()
    low = d[[int(np.argmin(d[:, 2]))]]
    hf = gt.Heightfield(amplitude=0.08)
    direct = gt.measure_btf(hf, d[[0]], low, texels=8, spp=8, max_depth=2)
    full = gt.measure_btf(hf, d[[0]], low, texels=8, spp=8, max_depth=4)
    flat = 0.8 * low[0, 2]
    assert 0.3 * flat < direct.data.mean() < 0.97 * flat
    assert direct.data.min() < 0.2 * flat  # some texels lie in shadow
    assert full.data.mean() > direct.data.mean()


def test_the_geometry_render_of_a_flat_plane_is_lambertian():
    # The path-traced geometry in btfrs's unit: a flat albedo-a plane lit from theta reads a cos(theta).
    cam = btfrs.Camera.look_at([0.0, -1.5, 2.0], [0.0, 0.0, 0.0], 40.0, up=[0.0, 0.0, 1.0])
    light = btfrs.directions.from_theta_phi(50.0, 30.0, degrees=True)
    img = gt.render_geometry(gt.Heightfield(amplitude=0.0, albedo=0.5), cam, light, size=(24, 24), spp=4)
    np.testing.assert_allclose(img, 0.5 * math.cos(math.radians(50.0)), rtol=1e-4)


@pytest.fixture(scope="module")
def result():
    return gt.check(seed=0)


def test_the_raw_renderer_lands_within_2_percent_of_the_path_trace(result):
    # The bound: brightness within 2% for lights between the measured rings (the cosine
    # correction of the raw renderer's light blend; without it 4 to 7% too dark).
    for r in result["rows"]:
        if r["case"] == "measured":
            assert abs(r["brightness"] - 1.0) < 0.02, r
            assert r["structure"] < 0.06, r


def test_a_mirrored_sample_scores_clearly_worse(result):
    rows = {(r["light"], r["case"], r["filter"]): r for r in result["rows"]}
    for (light, case, filt), r in rows.items():
        if case == "measured":
            wrong = rows[(light, "mirrored y", filt)]
            assert wrong["structure"] > 2.5 * r["structure"], (r, wrong)


def test_compare_sees_a_shift_and_a_scale():
    # The metric itself: a scaled copy changes brightness only; a shifted one structure only.
    rng = np.random.default_rng(0)
    base = np.kron(rng.uniform(0.2, 1.0, (16, 16)), np.ones((4, 4)))[..., None].repeat(3, -1)
    same = gt.compare(0.9 * base, base)
    assert abs(same["brightness"] - 0.9) < 1e-9
    assert gt.compare(base, base)["structure"] < 1e-12
    shifted = gt.compare(np.roll(base, 4, axis=0), base)
    assert shifted["structure"] > 0.1
    with pytest.raises(InvalidArgumentError, match="rendered"):
        gt.compare(base[:8], base)


def test_the_docs_snippet_and_its_table(result, monkeypatch, tmp_path):
    # The docs' ground-truth snippet runs (on this module's result: check() is what the
    # fixture ran) and its table holds this run's figures.
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "docs" / "rendering.md").read_text()
    section = text[text.index("## Ground truth"):]
    block = re.search(r"```python \{\.skip\}\n(.*?)```", section, re.S).group(1)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(gt, "check", lambda **kw: result)
    exec(compile(block, "docs/rendering.md", "exec"), {})
    assert (tmp_path / "ground_truth.png").stat().st_size > 10_000
    rows = {(r["light"], r["case"]): r for r in result["rows"] if r["filter"] == "bilinear"}
    table = re.findall(r"^\| (theta [\d.]+, phi [\d.]+) \| (measured, bilinear|rows mirrored \(wrong y\)) \| "
                       r"([\d.]+) \| ([\d.]+) \|$", section, re.M)
    assert len(table) == 4
    for light, case, brightness, structure in table:
        r = rows[(light, "measured" if case.startswith("measured") else "mirrored y")]
        assert abs(r["brightness"] - float(brightness)) < 0.004, (light, case, r)
        assert abs(r["structure"] - float(structure)) < 0.01, (light, case, r)
