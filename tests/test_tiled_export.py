"""The tiled, multi-resolution export (relight's and NeuralRTI's folders with every plane image a
Deep Zoom pyramid, as relight-cli's deepzoom output and OpenLIME's ``deepzoom`` layout have them):
read back into the model written (exactly with PNG tiles, within JPEG's steps with JPEG tiles),
the pyramid checked against Deep Zoom's and OpenLIME's conventions with an independent reader
(ElementTree and PIL), damaged pyramids refused by name, nothing half-written, and the command
line."""
from __future__ import annotations

import json
import math
import os
import shutil
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import btfrs
import btfrs.web
from btfrs.cli import main
from btfrs.exceptions import FormatError, InvalidArgumentError

H, W = 37, 52  # not a multiple of the tiles, not square
TILE = 16


@pytest.fixture(scope="module")
def capture():
    btf = btfrs.materials.make("weave", size=64, seed=3, views=[[0.0, 0.0, 1.0]])
    return btfrs.Btf(btf.data[:H, :W], btf.views, btf.lights)


@pytest.fixture(scope="module")
def models(capture):
    return {
        "ptm": btfrs.fit.ptm(capture),
        "ptm_lrgb": btfrs.fit.ptm(capture, kind="lrgb"),
        "hsh": btfrs.fit.hsh(capture),
        "rbf": btfrs.fit.rbf(capture),
        "bilinear": btfrs.fit.bilinear(capture),
        # NeuralRTI's form: no horizon map (OpenLIME's decoder reads the light alone).
        "neural": btfrs.fit.neural(capture, steps=60, hidden=8, seed=1, horizon=0),
    }


def _fmt(m) -> str:
    return "relight" if "relight" in m.exports else "neuralrti"


LIGHTS = [[0.0, 0.0, 1.0], [0.5, -0.3, 0.81], [-0.6, 0.1, 0.79]]


@pytest.mark.parametrize("kind", ["ptm", "ptm_lrgb", "hsh", "rbf", "bilinear", "neural"])
def test_every_basis_reads_back_from_its_png_pyramid_exactly(kind, models, tmp_path):
    m = models[kind]
    whole = tmp_path / "whole"
    tiled = tmp_path / "tiled"
    m.export(whole, format=_fmt(m))
    res = m.export(tiled, tiled=True, tile_format="png", tile_size=TILE, overlap=1)
    assert all(f.endswith((".dzi", "info.json")) for f in res["files"])
    assert not list(tiled.glob("plane_*.png")) and not list(tiled.glob("plane_*.jpg"))
    a, b = btfrs.load(whole), btfrs.load(tiled)
    assert a.kind == b.kind and (b.height, b.width) == (H, W)
    for k, v in a.arrays.items():
        np.testing.assert_array_equal(b.arrays[k], v, err_msg=k)
    for light in LIGHTS:
        got = b.evaluate([0, 0, 1], light)
        np.testing.assert_array_equal(got, a.evaluate([0, 0, 1], light))
        if kind in ("ptm", "hsh", "neural"):
            # These write the model's own 8-bit planes: the values are the model's.
            np.testing.assert_allclose(got, m.evaluate([0, 0, 1], light), rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("kind", ["ptm", "neural"])
def test_jpeg_tiles_stay_within_jpegs_steps(kind, models, tmp_path):
    # A woven texture's planes are JPEG's worst case (detail at every scale). Measured here:
    # quality 95 (relight's default) leaves bytes 2-3 steps off on average and relit images
    # 35-40 dB from the PNG pyramid's; quality 100 within a step and 46-49 dB.
    m = models[kind]
    m.export(tmp_path / "png", tiled=True, tile_format="png", tile_size=TILE)
    exact = btfrs.load(tmp_path / "png")
    q = next(k for k in exact.arrays if k.endswith("_q"))
    for quality, steps, worst, floor in ((95, 3.5, 32, 33.0), (100, 1.0, 8, 44.0)):
        m.export(tmp_path / f"jpg{quality}", tiled=True, tile_format="jpg", tile_size=TILE, quality=quality)
        lossy = btfrs.load(tmp_path / f"jpg{quality}")
        d = np.abs(lossy.arrays[q].astype(int) - exact.arrays[q].astype(int))
        assert d.mean() < steps and d.max() <= worst, (quality, d.mean(), d.max())
        for light in LIGHTS:
            a, b = exact.evaluate([0, 0, 1], light), lossy.evaluate([0, 0, 1], light)
            psnr = 10 * np.log10(float(a.max()) ** 2 / np.mean((a - b) ** 2))
            assert psnr > floor, (quality, psnr)


def _dzi(path: Path) -> dict:
    root = ET.parse(path).getroot()
    assert root.tag == "{http://schemas.microsoft.com/deepzoom/2008}Image"
    size = root.find("{http://schemas.microsoft.com/deepzoom/2008}Size")
    return {"format": root.get("Format"), "tile": int(root.get("TileSize")), "overlap": int(root.get("Overlap")),
            "width": int(size.get("Width")), "height": int(size.get("Height"))}


def test_the_pyramid_is_deep_zoom_as_openlime_and_relight_lay_it_out(models, tmp_path):
    m = models["hsh"]
    out = tmp_path / "t"
    m.export(out, tiled=True, tile_format="png", tile_size=TILE, overlap=1)
    info = json.loads((out / "info.json").read_text())
    levels = math.ceil(math.log2(max(W, H) / TILE)) + 1  # OpenLIME's LayoutTiles
    assert info["format"] == "png" and info["btfrs"]["tiles"] == {"layout": "deepzoom", "tilesize": TILE,
                                                                  "overlap": 1, "levels": levels}
    names = sorted(p.stem for p in out.glob("plane_*.dzi"))
    assert names == [f"plane_{i}" for i in range(9)]  # 27 planes, three to an image
    for name in names:
        d = _dzi(out / f"{name}.dzi")
        assert d == {"format": "png", "tile": TILE, "overlap": 1, "width": W, "height": H}
        assert sorted(int(p.name) for p in (out / f"{name}_files").iterdir()) == list(range(levels))
        finer = None
        for level in reversed(range(levels)):
            s = levels - 1 - level
            lw, lh = max(1, W >> s), max(1, H >> s)
            cols, rows = math.ceil(lw / TILE), math.ceil(lh / TILE)
            files = sorted(p.name for p in (out / f"{name}_files" / str(level)).iterdir())
            assert files == sorted(f"{c}_{r}.png" for c in range(cols) for r in range(rows))
            img = np.zeros((lh, lw, 3), np.uint8)
            for c in range(cols):
                for r in range(rows):
                    x0, y0 = max(0, c * TILE - 1), max(0, r * TILE - 1)
                    x1, y1 = min(lw, (c + 1) * TILE + 1), min(lh, (r + 1) * TILE + 1)
                    t = np.asarray(Image.open(out / f"{name}_files" / str(level) / f"{c}_{r}.png").convert("RGB"))
                    assert t.shape == (y1 - y0, x1 - x0, 3), (level, c, r)
                    # Overlapping pixels agree with the neighbours'.
                    if c > 0:
                        np.testing.assert_array_equal(t[:, :2], img[y0:y1, x0:x0 + 2])
                    img[y0:y1, x0:x1] = t
            if finer is not None:
                # Each pixel is the mean of the 2 x 2 under it one level finer (rounded).
                f = finer[: 2 * lh, : 2 * lw].astype(float)
                mean = (f[0::2, 0::2] + f[1::2, 0::2] + f[0::2, 1::2] + f[1::2, 1::2]) / 4
                assert np.abs(img - mean).max() <= 0.5
            finer = img
        # The last level is the whole plane image (as the whole-plane export writes it).
    whole = tmp_path / "w"
    m.export(whole, format="relight")
    plane = np.asarray(Image.open(whole / "plane_4.png").convert("RGB"))
    full = np.zeros_like(plane)
    for p in (out / "plane_4_files" / str(levels - 1)).iterdir():
        c, r = (int(v) for v in p.stem.split("_"))
        t = np.asarray(Image.open(p).convert("RGB"))
        x0, y0 = max(0, c * TILE - 1), max(0, r * TILE - 1)
        full[y0:y0 + t.shape[0], x0:x0 + t.shape[1]] = t
    np.testing.assert_array_equal(full, plane)


def test_relights_own_tiled_numbering_has_level_0_one_tile(models, tmp_path):
    # relight-cli (deepzoom.cpp) names tiles {col}_{row} and numbers levels from the one-tile root;
    # OpenLIME's deepzoom layout reads level 0 as that root. A 256-pixel tile: one level for a
    # small image, and the root of a larger one fits one tile.
    m = models["ptm"]
    m.export(tmp_path / "t", tiled=True, tile_format="png")
    assert sorted(p.name for p in (tmp_path / "t" / "plane_0_files").iterdir()) == ["0"]
    assert sorted(p.name for p in (tmp_path / "t" / "plane_0_files" / "0").iterdir()) == ["0_0.png"]


@pytest.fixture()
def tiled(models, tmp_path):
    out = tmp_path / "t"
    models["ptm"].export(out, tiled=True, tile_format="png", tile_size=TILE)
    return out


def test_a_missing_tile_is_named(tiled):
    victim = tiled / "plane_3_files" / "1" / "1_0.png"
    victim.unlink()
    with pytest.raises(FormatError, match=r"plane_3_files/1/1_0\.png.*missing"):
        btfrs.load(tiled)


@pytest.mark.parametrize("level", [0, 2])
def test_a_truncated_tile_is_named(tiled, level):
    victim = tiled / "plane_1_files" / str(level) / "0_0.png"
    data = victim.read_bytes()
    victim.write_bytes(data[: len(data) // 2])
    with pytest.raises(FormatError, match=rf"plane_1_files/{level}/0_0\.png"):
        btfrs.load(tiled)


def test_a_tile_of_another_size_is_named(tiled):
    victim = tiled / "plane_2_files" / "2" / "3_2.png"
    Image.new("RGB", (7, 5)).save(victim)
    with pytest.raises(FormatError, match=r"plane_2_files/2/3_2\.png.*7 x 5 pixels"):
        btfrs.load(tiled)


def test_an_index_whose_level_count_disagrees_with_the_tiles_is_named(tiled):
    info = json.loads((tiled / "info.json").read_text())
    info["btfrs"]["tiles"]["levels"] = 5
    (tiled / "info.json").write_text(json.dumps(info))
    with pytest.raises(FormatError, match=r"info\.json.*declares 5 levels.*makes 3 levels"):
        btfrs.load(tiled)


def test_a_pyramid_numbered_from_a_one_pixel_root_is_named(tiled):
    # Standard Deep Zoom numbers levels from a 1-pixel image: an extra level folder is refused
    # rather than read as the image.
    shutil.copytree(tiled / "plane_0_files" / "2", tiled / "plane_0_files" / "3")
    with pytest.raises(FormatError, match=r"plane_0_files/3.*a level 3"):
        btfrs.load(tiled)


def test_a_descriptor_that_disagrees_with_the_index_is_named(tiled):
    dzi = tiled / "plane_5.dzi"
    dzi.write_text(dzi.read_text().replace(f'Width="{W}"', f'Width="{W + 1}"'))
    with pytest.raises(FormatError, match=r"plane_5\.dzi.*Size is 53 x 37; .*info\.json.* declares 52 x 37"):
        btfrs.load(tiled)
    dzi.write_text("<Image TileSize='x'/>")
    with pytest.raises(FormatError, match=r"plane_5\.dzi"):
        btfrs.load(tiled)


def test_the_export_is_atomic_and_refuses_an_existing_folder(models, tmp_path):
    m = models["hsh"]
    out = tmp_path / "site"
    # Interrupted (Ctrl-C at the first progress report) while writing the tiles of a 768^2 PTM
    # in 16-pixel tiles: nothing is left, not even the temporary folder.
    a = dict(models["ptm"].arrays)
    a["coeffs_q"] = np.ascontiguousarray(np.tile(a["coeffs_q"], (21, 15, 1, 1, 1))[:768, :768])
    big = btfrs.Model.from_arrays(a, kind="ptm")
    calls = []

    def stop(done, total):
        calls.append((done, total))
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        big.export(out, tiled=True, tile_format="png", tile_size=TILE, progress=stop)
    assert calls and calls[0][0] < max(calls[0][1], 1), calls
    assert not out.exists() and os.listdir(tmp_path) == []
    m.export(out, tiled=True, tile_size=TILE)
    with pytest.raises(InvalidArgumentError, match="exists"):
        m.export(out, tiled=True, tile_size=TILE)
    (out / "stale.txt").write_text("x")
    m.export(out, tiled=True, tile_size=TILE, tile_format="png", force=True)
    assert not (out / "stale.txt").exists() and (out / "plane_0.dzi").exists()
    assert sorted(os.listdir(tmp_path)) == ["site"]


def test_options_and_models_without_a_tiled_layout_are_refused(models, capture, tmp_path):
    m = models["ptm"]
    with pytest.raises(InvalidArgumentError, match="tile_format"):
        m.export(tmp_path / "a", tiled=True, tile_format="webp")
    with pytest.raises(InvalidArgumentError, match="overlap"):
        m.export(tmp_path / "a", tiled=True, tile_size=16, overlap=8)
    with pytest.raises(InvalidArgumentError, match="tiled layout"):
        m.export(tmp_path / "a.ptm", format="ptm", tiled=True)
    lpca = btfrs.fit.lpca(capture, clusters=2, components=2)
    with pytest.raises(InvalidArgumentError, match="tiled"):
        btfrs.web.save_web(lpca, tmp_path / "b", tiled=True)
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_a_neural_model_with_a_horizon_map_is_refused_with_the_reason(capture, tmp_path, capsys):
    # Its decoder reads each texel's clearance above its horizon map, which NeuralRTI's folder
    # (and OpenLIME) cannot hold: refused as the whole-plane export refuses it, nothing written.
    m = btfrs.fit.neural(capture, steps=20, hidden=8, seed=1, horizon=4)
    assert m.horizon is not None
    why = r"^format: NeuralRTI's form .*clearance above its horizon map.*\(fit with horizon=0\)"
    with pytest.raises(InvalidArgumentError, match=why):
        m.export(tmp_path / "whole", format="neuralrti")
    with pytest.raises(InvalidArgumentError, match=why):
        m.export(tmp_path / "a", tiled=True, tile_size=TILE)
    with pytest.raises(InvalidArgumentError, match=why):
        btfrs.web.save_web(m, tmp_path / "site", tiled=True, tile_size=TILE)
    src = tmp_path / "m.btfrs"
    m.save(src)
    assert main(["export", "--quiet", str(src), "--web", str(tmp_path / "cli"), "--tiles"]) != 0
    assert "horizon=0" in capsys.readouterr().err
    assert sorted(os.listdir(tmp_path)) == ["m.btfrs"]


def test_the_command_lines_quick_neural_fit_of_a_tiled_page_is_in_neuralrtis_form(capture, tmp_path):
    # `export CAPTURE --web SITE --tiles --model neural` fits without a horizon map, so that the
    # tiled folder can be NeuralRTI's.
    src = tmp_path / "capture.btfrs"
    btfrs.Btf(capture.data[:12, :20], capture.views, capture.lights).save(src)  # small: the fit's 1000 steps
    site = tmp_path / "site"
    assert main(["export", "--quiet", str(src), "--web", str(site), "--tiles", "--model", "neural",
                 "--tile-size", "16", "--tile-format", "png"]) == 0
    back = btfrs.load(site / "model")
    assert back.kind == "neural" and back.horizon is None and back.directions == "light"
    assert json.loads((site / "model" / "info.json").read_text())["type"] == "neural"


def test_the_tiled_page_describes_the_window_store(models, tmp_path):
    import btfrs.web

    m = models["ptm"]
    btfrs.web.save_web(m, tmp_path / "site", tiled=True, tile_format="png", tile_size=TILE)
    model = tmp_path / "site" / "model"
    man = json.loads((model / "manifest.json").read_text())
    t = man["tiles"]
    assert man["version"] == btfrs.web.WEB_VERSION and man["scenes"] == {} and man["rti"] is not None
    assert t["images"] == [f"plane_{i}.dzi" for i in range(6)] and t["planes"] == 18 and t["levels"] == 3
    assert t["capacity"] == H * W and t["tile_size"] == TILE and t["type"] == "ptm"
    # One texel part: the 18 coefficient bytes of a texel, each one plane of the images, each
    # plane once.
    (part,) = t["texels"]
    assert part["bytes"] == 18 and sorted(part["from"]) == list(range(18))
    # The shared words: the store file; and the folder is what btfrs.load reads.
    assert (model / "store.bin").stat().st_size == 4 * sum(c["words"] for c in t["constants"])
    assert btfrs.load(model).kind == "ptm"


def test_the_page_reads_the_folders_index_as_btfrs_reads_untrusted_files(tiled):
    # The page's manifest is made from the folder's info.json through btfrs's reader: a size out
    # of range, or an index that is not a regular file (a FIFO would block a plain open), is
    # named rather than followed.
    info = json.loads((tiled / "info.json").read_text())
    btfrs.web.bundle_tiled(tiled)
    (tiled / "info.json").write_text(json.dumps(dict(info, width=1 << 20)))
    with pytest.raises(FormatError, match=r"info\.json.*width: expected a size in 1\.\.=32768, got 1048576"):
        btfrs.web.bundle_tiled(tiled)
    bad = dict(info)
    bad["btfrs"] = {"tiles": dict(info["btfrs"]["tiles"], tilesize=-3)}
    (tiled / "info.json").write_text(json.dumps(bad))
    with pytest.raises(FormatError, match=r"info\.json.*btfrs\.tiles\.tilesize"):
        btfrs.web.bundle_tiled(tiled)
    (tiled / "info.json").unlink()
    os.mkfifo(tiled / "info.json")
    with pytest.raises(FormatError, match=r"info\.json.*regular file"):
        btfrs.web.bundle_tiled(tiled)


def test_the_command_line_writes_a_tiled_page_and_a_tiled_folder(models, tmp_path, capsys):
    src = tmp_path / "m.btfrs"
    models["hsh"].save(src)
    site = tmp_path / "site"
    assert main(["export", "--quiet", str(src), "--web", str(site), "--tiles", "--tile-format", "png",
                 "--tile-size", "16"]) == 0
    assert (site / "index.html").exists() and (site / "model" / "plane_0.dzi").exists()
    assert btfrs.load(site / "model").kind == "hsh"
    rel = tmp_path / "rel"
    assert main(["export", "--quiet", str(src), "--relight", str(rel), "--tiles"]) == 0
    assert _dzi(rel / "plane_0.dzi")["format"] == "jpg"
    assert main(["export", "--quiet", str(src), "--ptm", str(tmp_path / "x.ptm"), "--tile-size", "64"]) != 0
    assert "--tile-size: only with --tiles" in capsys.readouterr().err
