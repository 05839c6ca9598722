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


# --- relight: .ptm, .rti and relight's web format -------------------------------------------------
#
# tests/fixtures/relight holds a small capture (24 x 18 texels, 37 lights, 8-bit JPEGs and the
# .lp file), what relight-cli fitted from it (web folders, .ptm and .rti files), relight-cli's
# conversions of those files to its web format, btfrs's own models and exports of the same
# capture, and relight-cli's relit images of all of them at four lights. relight relights in the
# 8-bit display values it fitted (no transfer curve) and truncates to integers; btfrs's units
# are those values / 255, so btfrs's relighting is floor(255 x value).

REL = FIXTURES / "relight"
MANIFEST = json.loads((REL / "manifest.json").read_text()) if REL.exists() else {"relit": [], "btfrs_exports": []}


def _unit(v):
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


def _relit_by_btfrs(model, light):
    return np.clip(np.floor(np.asarray(model.evaluate([0, 0, 1], _unit(light)), np.float64) * 255 + 1e-4), 0, 255)


def _relit_by_relight(entry):
    from PIL import Image

    return np.asarray(Image.open(REL / entry["output"]).convert("RGB"), np.float64)


def _steps(model, entry):
    d = np.abs(_relit_by_btfrs(model, entry["light"]) - _relit_by_relight(entry))
    return float(d.mean()), float(d.max())


def _ids(entries):
    return [f"{e['source'].split('/')[-1]}-{e['light_name']}" for e in entries]


WEB = [e for e in MANIFEST["relit"] if e["kind"] == "relight_web"]
LEGACY = [e for e in MANIFEST["relit"] if e["kind"] == "relight_legacy"]
EXPORTS = MANIFEST["btfrs_exports"]

# (mean, max) |btfrs - relight| in 8-bit steps. PTM, HSH and bilinear folders are read exactly
# (the planes' bytes with relight's scale and bias), so only float rounding against relight's
# truncation remains (measured: mean <= 0.23, max 2). An RBF folder is relit by relight as a
# Gaussian blend of its basis at the capture's lights, which btfrs samples on its 32 x 32 light
# grid: measured mean <= 2.1, max 4.
WEB_TOLERANCE = {"ptm": (0.3, 2), "hsh": (0.3, 2), "bilinear": (0.3, 2), "rbf": (2.5, 5)}


def test_the_relight_fixtures_are_all_here():
    assert (len(WEB), len(LEGACY), len(EXPORTS)) == (24, 20, 36)


@pytest.mark.parametrize("entry", WEB, ids=_ids(WEB))
def test_relight_web_folders_relight_as_relight_does(entry):
    model = btfrs.load(REL / entry["source"])
    assert model.kind == {"ptm": "ptm", "hsh": "hsh", "rbf": "rbf", "bilinear": "bilinear"}[entry["basis"]]
    mean, worst = _steps(model, entry)
    tol = WEB_TOLERANCE[entry["basis"]]
    assert mean <= tol[0] and worst <= tol[1], (mean, worst)


@pytest.mark.parametrize("entry", LEGACY, ids=_ids(LEGACY))
def test_relight_ptm_and_rti_files_relight_as_relight_does(entry):
    # relight-cli relights .ptm and .rti files only after converting them to its web format,
    # which re-encodes every plane as a JPEG: its images carry that loss (measured: mean <= 0.99,
    # max 6 steps). The same file read by btfrs and by relight's converter agree closer, which
    # is checked on the converted folder (read exactly by btfrs, see above) against the file.
    model = btfrs.load(REL / entry["source"])
    mean, worst = _steps(model, entry)
    assert mean <= 1.2 and worst <= 7, (mean, worst)
    converted = btfrs.load(REL / entry["web_folder"])
    ours, theirs = (_relit_by_btfrs(m, entry["light"]) for m in (model, converted))
    assert np.abs(ours - theirs).mean() <= 1.2


def _export_model(entry):
    name = entry["source"].split("/")[-1]
    return REL / "btfrs_exports" / "input" / "models" / f"{name.rsplit('.', 1)[0]}.btfrs"


@pytest.mark.parametrize("entry", EXPORTS, ids=_ids(EXPORTS))
def test_btfrs_exports_relight_in_relight_as_in_btfrs(entry):
    # btfrs's models of the capture, written by btfrs (.ptm, .rti, web folders) and relit by
    # relight-cli, against btfrs's own evaluation of the model. The JPEG planes relight reads
    # (btfrs's for web folders, relight's own re-encoding for .ptm and .rti) cost about a step
    # on average; the PCA bases are also resampled on relight's octahedral light grid and
    # rounded to its 8-bit basis (measured: mean <= 1.2, max 7).
    model = btfrs.load(_export_model(entry))
    mean, worst = _steps(model, entry)
    assert mean <= 1.5 and worst <= 9, (mean, worst)


@pytest.mark.parametrize("source", sorted({e["source"] for e in EXPORTS}))
def test_btfrs_writes_the_exports_relight_was_given(source, tmp_path):
    # The committed exports are what btfrs writes today from the committed models: the files
    # relight relit above are this writer's.
    committed = REL / source
    model = btfrs.load(_export_model({"source": source}))
    name = committed.name
    out = tmp_path / name
    if committed.is_dir():
        model.export(out, format="relight")
        assert json.loads((out / "info.json").read_text()) == json.loads((committed / "info.json").read_text())
        from PIL import Image

        for png in sorted(committed.glob("plane_*.png")):
            np.testing.assert_array_equal(np.asarray(Image.open(out / png.name)), np.asarray(Image.open(png)))
    else:
        model.export(out, format=committed.suffix[1:])
        assert out.read_bytes() == committed.read_bytes()


def test_relight_captures_lights_lie_as_btfrs_reads_them():
    # The axes: the capture is an asymmetric relief lit from known directions (x to the right,
    # y up the image); a PTM that btfrs fits from it, relit at four lights, matches the relief's
    # closed-form images (ground_truth/) as read, and not with the light mirrored in x or y or
    # the rows flipped. relight's own images match them the same way (fixtures README).
    from PIL import Image

    btf = btfrs.load(REL / "capture", linear=True)
    model = btfrs.fit.ptm(btf)
    lights = {"right_up": [0.5, 0.3, 0.81], "left_up": [-0.6, 0.2, 0.77], "down": [0.1, -0.7, 0.71]}
    for name, light in lights.items():
        truth = np.asarray(Image.open(REL / "ground_truth" / f"{name}.png").convert("RGB"), np.float64)
        err = lambda img: float(np.abs(img * 255 - truth).mean())  # noqa: E731
        l = _unit(light)
        as_read = err(model.evaluate([0, 0, 1], l))
        for other in (model.evaluate([0, 0, 1], l * [-1, 1, 1]), model.evaluate([0, 0, 1], l * [1, -1, 1]),
                      model.evaluate([0, 0, 1], l)[::-1]):
            assert as_read < 0.8 * err(other), (name, as_read, err(other))


def test_relight_export_from_the_command_line_and_bad_folders(tmp_path):
    from btfrs.cli import main
    from btfrs.exceptions import FormatError, InvalidArgumentError

    capture = btfrs.load(REL / "capture", linear=True)
    btfrs.fit.hsh(capture, order=3).save(tmp_path / "h3.btfrs")
    main(["export", str(tmp_path / "h3.btfrs"), "--relight", str(tmp_path / "h3_web")])
    back, model = btfrs.load(tmp_path / "h3_web"), btfrs.load(tmp_path / "h3.btfrs")
    light = _unit([0.3, -0.2, 0.9])
    np.testing.assert_allclose(back.evaluate([0, 0, 1], light), model.evaluate([0, 0, 1], light), atol=1e-5)
    with pytest.raises(InvalidArgumentError, match="order 3"):
        btfrs.fit.hsh(capture, order=4).export(tmp_path / "h4", format="relight")
    with pytest.raises(InvalidArgumentError, match="relight"):
        btfrs.fit.lafortune(capture).export(tmp_path / "laf", format="relight")
    # Broken folders: the field or file is named.
    import shutil

    def broken(edit, name):
        d = tmp_path / name
        shutil.copytree(REL / "web" / "ptm_rgb", d)
        info = json.loads((d / "info.json").read_text())
        edit(d, info)
        (d / "info.json").write_text(json.dumps(info))
        return d

    cases = [
        (lambda d, i: i.update(type="sh"), "type"),
        (lambda d, i: i.update(nplanes=12), "expected 12 scales"),
        (lambda d, i: i.update(nplanes=12, materials=[{k: v[:12] for k, v in i["materials"][0].items()}]), "nplanes"),
        (lambda d, i: i["materials"][0]["scale"].pop(), "materials"),
        (lambda d, i: i.update(width=0), "width"),
        (lambda d, i: (d / "plane_5.jpg").unlink(), "plane_5"),
        (lambda d, i: i.update(width=i["width"] + 1), r"plane_0\.jpg.*pixels"),
    ]
    for k, (edit, match) in enumerate(cases):
        with pytest.raises(FormatError, match=match):
            btfrs.load(broken(edit, f"b{k}"))
