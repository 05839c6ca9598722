"""Light calibration from a reflective sphere (btfrs.calibrate, btfrs calibrate).

The references: captures rendered by Mitsuba 3 with known lights (tests/fixtures/sphere/, made by
scripts/render_sphere_capture.py: a glossy black sphere beside a relief, JPEG, highlights
clipped), and synthetic photographs drawn here in closed form (a sphere whose highlight is a
lobe around the mirror direction of a chosen light), for the cases a renderer does not make on
purpose: a clipped plateau, two highlights, none, an overexposed sphere, a wrong size.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

import btfrs
from btfrs.cli import main
from btfrs.exceptions import ArgumentTypeError, DegenerateDataError, FormatError, InvalidArgumentError

FIXTURES = Path(__file__).resolve().parent / "fixtures" / "sphere"
ORTHO = FIXTURES / "orthographic"
PERSP = FIXTURES / "perspective"


def scene(folder: Path) -> dict:
    return json.loads((folder / "scene.json").read_text())


def angles(found: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Degrees between unit vectors, row by row (float64)."""
    c = np.sum(np.asarray(found, float) * np.asarray(truth, float), axis=1)
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def truth_of(cal: btfrs.Calibration, sc: dict) -> np.ndarray:
    by_name = dict(zip(sc["files"], sc["directions"]))
    return np.array([by_name[Path(f).name] for f in cal.files])


def direction(theta_deg: float, phi_deg: float) -> np.ndarray:
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])


CIRCLE = (70.3, 58.6, 40.2)


def sphere_photo(path: Path, lights, *, size=(120, 160), circle=CIRCLE, sigma_deg=1.5, peak=30.0,
                 background=0.3, sphere_level=0.01) -> None:
    """A photograph (orthographic) of a black sphere on a grey table whose highlights are
    Gaussian lobes (``sigma_deg`` of normal angle) around the normals that mirror each light
    into the camera, ``peak`` times white (clipped in the file), 4 x 4 samples per pixel."""
    h, w = size
    ss = 4
    y, x = (np.mgrid[0:h * ss, 0:w * ss] + 0.5) / ss
    cx, cy, r = circle
    nx, ny = (x - cx) / r, -(y - cy) / r
    q = nx * nx + ny * ny
    inside = q < 1.0
    nz = np.sqrt(np.clip(1.0 - q, 0.0, None))
    img = np.where(inside, sphere_level, background)
    for l in lights:
        hv = np.asarray(l, float) + [0.0, 0.0, 1.0]
        hv /= np.linalg.norm(hv)
        ang = np.degrees(np.arccos(np.clip(nx * hv[0] + ny * hv[1] + nz * hv[2], -1.0, 1.0)))
        img = img + inside * peak * np.exp(-0.5 * (ang / sigma_deg) ** 2)
    img = img.reshape(h, ss, w, ss).mean(axis=(1, 3))
    btfrs.io.save_image(path, np.repeat(np.clip(img, 0.0, 1.0)[..., None], 3, axis=2).astype(np.float32))


LIGHTS = [direction(65.0, 20.0), direction(40.0, 135.0), direction(15.0, 250.0), direction(55.0, 300.0)]


def synthetic(folder: Path, lights=LIGHTS, ext="png", **kw) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for k, l in enumerate(lights):
        sphere_photo(folder / f"img_{k:02d}.{ext}", [l], **kw)
    return folder


# --- Rendered captures -------------------------------------------------------------------------

def test_rendered_capture_lights_within_half_a_degree():
    """30 lights found within 0.5 degrees on average and 0.6 at most (measured: 0.13 and 0.22),
    the sphere found within a fifth of a pixel."""
    sc = scene(ORTHO)
    cal = btfrs.calibrate(ORTHO)
    assert len(cal.calibrated) == len(sc["files"]) == 30 and not cal.skipped
    err = angles(cal.lights, truth_of(cal, sc))
    assert err.mean() < 0.5 and err.max() < 0.6, (err.mean(), err.max())
    cx, cy, r = cal.sphere
    tx, ty, tr = sc["sphere_px"]
    assert abs(cx - tx) < 0.2 and abs(cy - ty) < 0.2 and abs(r - tr) < 0.3, (cal.sphere, sc["sphere_px"])
    assert cal.report["sphere"]["detected"] and cal.report["sphere"]["edge_rms_px"] < 0.5
    # Every highlight on this capture is clipped, and found anyway.
    assert all(i["clipped_pixels"] > 0 for i in cal.report["images"])


def test_the_true_circle_given_leaves_only_the_highlights_error():
    sc = scene(ORTHO)
    cal = btfrs.calibrate(ORTHO, sphere=sc["sphere_px"])
    err = angles(cal.lights, truth_of(cal, sc))
    # Measured 0.04 mean, 0.11 at most: the highlights' centres are good to a few hundredths of
    # a pixel on a 54-pixel sphere.
    assert err.mean() < 0.15 and err.max() < 0.3, (err.mean(), err.max())
    assert not cal.report["sphere"]["detected"] and tuple(cal.sphere) == tuple(sc["sphere_px"])


def test_written_lp_is_relights_format_and_btfrs_load_reads_the_true_lights(tmp_path):
    photos = tmp_path / "photos"
    shutil.copytree(ORTHO, photos, ignore=shutil.ignore_patterns("*.lp", "*.json"))
    cal = btfrs.calibrate(photos)
    lp = cal.save(photos / "dirs.lp")
    lines = Path(lp).read_text().splitlines()
    assert lines[0] == "30"
    assert all(len(line.split()) == 4 for line in lines[1:]) and len(lines) == 31
    assert lines[1].split()[0] == "light_000.jpg"  # relative to the .lp's folder, as relight reads
    btf = btfrs.load(photos / "dirs.lp")
    assert btf.n_lights == 30 and btf.n_views == 1
    # y up the image: btfrs.load's lights are the true ones, not mirrored.
    err = angles(btf.lights, np.array(scene(ORTHO)["directions"]))
    assert err.mean() < 0.5, err.mean()
    # A path outside the .lp's folder is written absolute.
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    first = Path(cal.save(elsewhere / "dirs.lp")).read_text().splitlines()[1].split()[0]
    assert Path(first).is_absolute() and Path(first).name == "light_000.jpg"


def test_perspective_capture_needs_the_field_of_view():
    sc = scene(PERSP)
    cal = btfrs.calibrate(PERSP, fov=sc["fov_deg"])
    err = angles(cal.lights, truth_of(cal, sc))
    # Measured 0.18 mean, 0.32 at most; read as orthographic the same photographs are 10 degrees
    # off (the sphere is seen 14 degrees off the axis).
    assert err.mean() < 0.5 and err.max() < 0.6, (err.mean(), err.max())
    assert cal.report["camera"]["projection"] == "perspective"
    with pytest.warns(UserWarning, match="below the horizon; moved onto it"):
        ortho = btfrs.calibrate(PERSP)
    assert angles(ortho.lights, truth_of(ortho, sc)).mean() > 5.0
    # The same camera by its 35 mm-equivalent focal length (the diagonal spans 43.27 mm).
    h, w = sc["size"]
    f_px = 0.5 * w / np.tan(np.radians(0.5 * sc["fov_deg"]))
    by_focal = btfrs.calibrate(PERSP, focal=f_px * np.hypot(36.0, 24.0) / np.hypot(w, h))
    assert np.allclose(by_focal.lights, cal.lights, atol=1e-9)


def test_white_target_gives_each_lights_intensity():
    """The target's colour over the light's cosine follows the rendered irradiances (+-30%)
    within 3%, for the lights whose direction the sphere does not shadow on the target."""
    sc = scene(ORTHO)
    with pytest.warns(UserWarning, match=r"the white target is dark \(in a shadow\?\) in 3 photographs \(light_007.jpg, "):
        cal = btfrs.calibrate(ORTHO, white=sc["target_rect"])
    irr = dict(zip(sc["files"], sc["irradiance"]))
    truth = np.array([irr[Path(f).name] for f in cal.files])
    # Shadowed: a ray from a corner or the centre of the target towards the light meets the sphere.
    x0, x1, y0, y1 = sc["world"]["target"]
    c = np.array(sc["world"]["sphere_centre"])
    rad = sc["world"]["sphere_radius"]
    pts = np.array([[x, y, 0.0] for x in (x0, 0.5 * (x0 + x1), x1) for y in (y0, 0.5 * (y0 + y1), y1)])
    lit = []
    for l in cal.lights:
        oc = pts - c
        b = oc @ l
        disc = b * b - (np.sum(oc * oc, axis=1) - rad * rad)
        lit.append(not np.any((disc > 0) & (-b + np.sqrt(np.clip(disc, 0, None)) > 0)))
    lit = np.array(lit)
    assert lit.sum() >= 20
    lum = cal.intensity @ np.array([0.2126, 0.7152, 0.0722])
    ratio = lum[lit] / truth[lit]
    spread = ratio / np.median(ratio) - 1.0
    assert np.abs(spread).max() < 0.03, np.round(spread, 4)
    # The white target is grey, so the channels agree.
    assert np.allclose(cal.intensity[lit, 0], cal.intensity[lit, 2], rtol=0.01)
    assert cal.intensity.shape == (30, 3)
    assert btfrs.calibrate(ORTHO).intensity is None


# --- Synthetic photographs: the rules --------------------------------------------------------

# The drawn highlights are evenly bright on the sphere (a mirror reflecting a lamp of finite
# size), 30 times white, clipped to a plateau about 8 degrees of normal across: the image centroid
# falls short of their centre towards the sphere's by up to 0.3 degree of light (the rule and its
# limit are in btfrs-calibrate's highlight.rs). Measured: 0.23 at most from PNG, 0.32 from EXR.
SYNTHETIC_MAX_DEG = 0.4


def test_clipped_highlights_are_found_at_their_centre(tmp_path):
    folder = synthetic(tmp_path / "s")
    cal = btfrs.calibrate(folder)
    err = angles(cal.lights, np.array(LIGHTS))
    assert err.max() < SYNTHETIC_MAX_DEG, err
    assert all(i["clipped_pixels"] >= 9 for i in cal.report["images"])  # a plateau, not a peak
    # The circle found: the true one within a tenth of a pixel.
    assert np.allclose(cal.sphere, CIRCLE, atol=0.1), cal.sphere


def test_float_photographs_take_the_other_decoder(tmp_path):
    # OpenEXR (linear floats) is read through btfrs-io's general decoder, not the 8-bit path.
    cal = btfrs.calibrate(synthetic(tmp_path / "exr", ext="exr"))
    assert angles(cal.lights, np.array(LIGHTS)).max() < SYNTHETIC_MAX_DEG
    assert np.allclose(cal.sphere, CIRCLE, atol=0.1), cal.sphere


def test_doubled_and_missing_highlights_are_flagged_and_left_out(tmp_path):
    folder = synthetic(tmp_path / "s")
    sphere_photo(folder / "img_10_two.png", [direction(30.0, 10.0), direction(50.0, 200.0)])
    sphere_photo(folder / "img_11_none.png", [])
    with pytest.warns(UserWarning, match=r"2 of 6 photographs not calibrated") as rec:
        cal = btfrs.calibrate(folder)
    text = str(rec[0].message)
    assert "img_10_two.png: two highlights" in text and "img_11_none.png: no highlight" in text
    assert {Path(f).name: i for f, i in cal.skipped.items()}.keys() == {"img_10_two.png", "img_11_none.png"}
    status = {Path(i.file).name: i.status for i in cal.images}
    assert status["img_10_two.png"] == "ambiguous" and status["img_11_none.png"] == "missing"
    two = next(i for i in cal.images if i.status == "ambiguous")
    assert len(two.spots) == 2  # both reported, for the user to look at
    assert angles(cal.lights, np.array(LIGHTS)).max() < SYNTHETIC_MAX_DEG
    lp = Path(cal.save(folder / "dirs.lp")).read_text().splitlines()
    assert lp[0] == "4" and not any("img_1" in line for line in lp)


def test_a_sphere_that_is_not_dark_is_overexposed(tmp_path):
    folder = synthetic(tmp_path / "s")
    sphere_photo(folder / "img_20_bright.png", [LIGHTS[0]], sphere_level=0.8)
    with pytest.warns(UserWarning, match=r"img_20_bright.png: overexposed"):
        cal = btfrs.calibrate(folder, sphere=CIRCLE)
    assert len(cal.calibrated) == 4


def test_nothing_to_calibrate_is_an_error_naming_the_photographs(tmp_path):
    folder = synthetic(tmp_path / "s", lights=[])
    for k in range(3):
        sphere_photo(folder / f"dark_{k}.png", [])
    with pytest.raises(DegenerateDataError, match=r"no photograph of .* could be calibrated.*dark_0.png: no highlight"):
        btfrs.calibrate(folder, sphere=CIRCLE)


def test_photographs_of_different_sizes_are_refused_naming_the_file(tmp_path):
    folder = synthetic(tmp_path / "s")
    sphere_photo(folder / "img_03b.png", [LIGHTS[0]], size=(120, 162))
    with pytest.raises(FormatError, match=r"img_03b.png.*162 x 120 pixels.*expected 160 x 120"):
        btfrs.calibrate(folder)
    # The command line: one line on stderr, exit 2, no .lp left behind.
    assert main(["calibrate", str(folder), "-o", str(folder / "dirs.lp"), "--quiet"]) == 2
    assert not (folder / "dirs.lp").exists() and not list(folder.glob(".*tmp"))


def test_no_sphere_is_a_clear_error(tmp_path):
    folder = tmp_path / "flat"
    folder.mkdir()
    rng = np.random.default_rng(0)
    for k in range(3):
        btfrs.io.save_image(folder / f"f{k}.png", rng.uniform(0.2, 0.4, (60, 80, 3)).astype(np.float32))
    with pytest.raises(DegenerateDataError, match=r"no sphere found in .*flat.*sphere=\(cx, cy, r\)"):
        btfrs.calibrate(folder)


def test_bad_arguments_name_themselves(tmp_path):
    folder = synthetic(tmp_path / "s", lights=LIGHTS[:1])
    with pytest.raises(ArgumentTypeError, match=r"sphere: expected a circle"):
        btfrs.calibrate(folder, sphere=(1.0, 2.0))
    with pytest.raises(InvalidArgumentError, match=r"sphere\[2\] \(r\)"):
        btfrs.calibrate(folder, sphere=(70.0, 60.0, 1.0))
    with pytest.raises(InvalidArgumentError, match=r"sphere: the circle .* outside"):
        btfrs.calibrate(folder, sphere=(700.0, 60.0, 40.0))
    with pytest.raises(InvalidArgumentError, match=r"fov"):
        btfrs.calibrate(folder, fov=0.0)
    with pytest.raises(InvalidArgumentError, match=r"not both"):
        btfrs.calibrate(folder, fov=40.0, focal=50.0)
    with pytest.raises(InvalidArgumentError, match=r"white: expected \(row, col, rows, cols\) inside"):
        btfrs.calibrate(folder, white=(100, 0, 30, 10))
    with pytest.raises(InvalidArgumentError, match=r"images: .* is a file"):
        btfrs.calibrate(folder / "img_00.png")
    with pytest.raises(FileNotFoundError):
        btfrs.calibrate(tmp_path / "nowhere")
    with pytest.raises(InvalidArgumentError, match=r"holds no photographs"):
        btfrs.calibrate(tmp_path)
    cal = btfrs.calibrate([folder / "img_00.png"])
    with pytest.raises(InvalidArgumentError, match=r"\.lp"):
        cal.save(tmp_path / "dirs.txt")
    # A name with a space: written (btfrs reads it), with a warning that relight would not.
    shutil.copy(folder / "img_00.png", folder / "img 01.png")
    spaced = btfrs.calibrate([folder / "img 01.png"])
    with pytest.warns(UserWarning, match=r"contain spaces .*relight and RTIBuilder read a name only up to"):
        spaced.save(folder / "dirs.lp")
    assert btfrs.load(folder / "dirs.lp").n_lights == 1


def test_progress_counts_every_photograph_read(tmp_path):
    seen = []
    btfrs.calibrate(ORTHO, progress=lambda d, t: seen.append((d, t)))
    # 30 photographs, and the 12 the coarse search reads first.
    assert seen[-1] == (42, 42)
    seen.clear()
    btfrs.calibrate(ORTHO, sphere=scene(ORTHO)["sphere_px"], progress=lambda d, t: seen.append((d, t)))
    assert seen[-1] == (30, 30)


def test_a_failing_progress_callback_stops_calibration(tmp_path):
    calls = []

    def stop(done, total):
        calls.append(done)
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        btfrs.calibrate(ORTHO, progress=stop)
    assert len(calls) == 1


def test_cli_writes_the_lp_the_report_and_the_picture(tmp_path, capsys):
    photos = tmp_path / "photos"
    shutil.copytree(ORTHO, photos, ignore=shutil.ignore_patterns("*.lp", "*.json"))
    sc = scene(ORTHO)
    row, col, rows, cols = sc["target_rect"]
    code = main(["calibrate", str(photos), "-o", str(photos / "dirs.lp"), "--report", str(tmp_path / "cal.json"),
                 "--figure", str(tmp_path / "cal.png"), "--white", str(row), str(col), str(rows), str(cols),
                 "--quiet"])
    out = capsys.readouterr().out
    assert code == 0 and "calibrated 30 of 30 photographs" in out and "orthographic" in out
    report = json.loads((tmp_path / "cal.json").read_text())
    assert len(report["images"]) == 30 and report["images"][0]["intensity"] is not None
    img = btfrs.io.load_image(tmp_path / "cal.png")
    assert img.shape[0] > 300 and img.std() > 0.05
    btf = btfrs.load(photos / "dirs.lp")
    assert angles(btf.lights, np.array(sc["directions"])).mean() < 0.5
    # --white needs somewhere to put the intensities.
    assert main(["calibrate", str(photos), "-o", str(tmp_path / "x.lp"), "--white", "1", "1", "5", "5"]) == 2
    assert "--report" in capsys.readouterr().err
