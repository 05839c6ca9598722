"""btfrs's readers and writers against the reference tools of their formats.

Every fixture under ``tests/fixtures/`` was made by the format's own reference tool
(``scripts/reference/`` regenerates them and names the versions): the files, and what that tool
decodes from them. These tests need none of the tools.

* UBO2014 DFMF ``.btf``: written and decoded by the University of Bonn's ``btflib`` in GNU
  Octave. btflib returns values without the light's cosine (it divides flagged files by
  cos(theta_light)) and never applies the RGB scale factors; btfrs's convention includes the
  cosine and applies the scale, so ``btfrs = btflib * cos(theta_light) * scale`` whatever the
  cosine flag.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import btfrs
from btfrs import io

FIXTURES = Path(__file__).parent / "fixtures"
UBO = sorted((FIXTURES / "ubo2014").glob("*.json"))


def test_every_ubo2014_fixture_is_here():
    # The fixtures are listed, so a lost file fails here instead of shrinking the check.
    assert len(UBO) == 14


@pytest.mark.parametrize("fixture", UBO, ids=[p.stem for p in UBO])
def test_ubo2014_decodes_as_btflib_does(fixture):
    ref = json.loads(fixture.read_text())
    b = io.load(fixture.parent / ref["btf"])
    nv, nl, h, w, _ = ref["decoded_shape"]
    assert b.shape == (h, w, nv, nl, 3)
    # Directions: btflib's sph2cart2 of the stored angles, in file order.
    np.testing.assert_allclose(b.views, ref["meta_V"], atol=2e-7)
    np.testing.assert_allclose(b.lights, ref["meta_L"], atol=2e-7)
    decoded = np.fromfile(fixture.parent / ref["decoded"], dtype="<f4").reshape(nv, nl, h, w, 3)
    cos_l = np.asarray(ref["meta_L"], np.float64)[:, 2]
    scale = np.asarray(ref["rgb_scale_factor"], np.float64)
    want = decoded.astype(np.float64) * cos_l[None, :, None, None, None] * scale
    got = b.images().astype(np.float64)  # [V, L, H, W, 3], row 0 = btflib's image row 1
    # Float32 rounding of a few products and the colour transform: a few ulps of the largest value.
    tol = 4e-7 * np.abs(want).max()
    assert np.abs(got - want).max() <= tol, (np.abs(got - want).max(), tol)
    values = b.meta["values"]
    assert values["scale_applied"] == pytest.approx(ref["rgb_scale_factor"])
    assert values["cosine"].startswith("in the file" if ref["cosine_flag"] else "multiplied in")
    assert b.meta["color_model"] == ref["color_model"]


def test_ubo2014_cosine_flag_and_scale_both_ways():
    # The same stored numbers with the flag off and on (btflib then divides by the cosine) and
    # with an RGB scale: the flag changes what they mean, the scale multiplies them.
    load = lambda n: io.load(FIXTURES / "ubo2014" / f"{n}.btf")  # noqa: E731
    off, on = load("rgb_cos0"), load("rgb_cos1")
    off_s, on_s = load("rgb_cos0_scale"), load("rgb_cos1_scale")
    cos_l = off.lights[:, 2].astype(np.float32)
    # Flag on: the numbers already hold the cosine and stay; flag off: the reader multiplies it in.
    np.testing.assert_allclose(on.data * cos_l[:, None], off.data, rtol=1e-6, atol=1e-7)
    raw = np.fromfile(FIXTURES / "ubo2014" / "rgb_cos0.btflib.f32", "<f4").reshape(off.n_views, off.n_lights,
                                                                                 off.height, off.width, 3)
    np.testing.assert_allclose(off.images(), raw * cos_l[None, :, None, None, None].astype(np.float32), rtol=1e-6,
                               atol=1e-7)
    np.testing.assert_allclose(off_s.data, off.data * np.float32([2, 0.5, 1.5]), rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(on_s.data * cos_l[:, None], off_s.data, rtol=1e-6, atol=1e-7)


def test_btf_meta_is_saved_and_shown(tmp_path, capsys):
    b = io.load(FIXTURES / "ubo2014" / "yuv_cos1_scale.btf")
    b.select(views=[0, 2]).save(tmp_path / "s.btfrs")
    back = btfrs.Btf.load(tmp_path / "s.btfrs")
    assert back.meta == b.meta and back.meta["values"]["scale_applied"] == [2.0, 0.5, 1.5]
    assert btfrs.Btf.load(tmp_path / "s.btfrs", mmap=True).meta == b.meta
    train, test = back.split(holdout=0.3, seed=1)
    assert train.meta == test.meta == b.meta
    from btfrs.cli import main
    main(["info", str(FIXTURES / "ubo2014" / "rgb_cos0_scale.btf")])
    out = capsys.readouterr().out
    assert "read as: cosine multiplied in by the reader" in out and "[2.0, 0.5, 1.5] applied" in out
