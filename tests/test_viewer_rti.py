"""The viewer's 2D view of single-view models (RTI captures) and its tiled pages, in headless
Chromium (WebGPU on SwiftShader), each frame read back and compared with a numpy reference of
the same formula (tests/rti_reference.py): the straight-on view filling the canvas, bilinear
between texels down to single texels, RTIViewer's rendering modes (default, diffuse gain,
specular enhancement, normal map) for a PTM and for two other bases, the view in the page's
address, the pointer, and a 2048^2 tiled export fetched coarse level first and by region.

Skipped without Debian's chromium and the playwright package, as tests/test_viewer.py is. The
frames and their references are written as PNGs under $BTFRS_VIEWER_PNGS when set.
"""
from __future__ import annotations

import json
import os
import threading
from pathlib import Path

import numpy as np
import pytest

import btfrs
import btfrs.web
import rti_reference as ref
from test_viewer import Page, Server, browser, frame, psnr, save_web, viewer_files, write_png  # noqa: F401

W, H = 40, 32  # a capture that is not square, so a transposed view would show
SIZE = (120, 96)  # the canvas (width, height): the image fills it at zoom 3
LIGHT = [0.3, -0.4, float(np.sqrt(1 - 0.25))]
MIN_PSNR = 38.0
PARAMS = dict(btfrs.web.RTI_DEFAULTS, gain=2.5, kd=0.7, ks=0.6, exponent=25.0)


@pytest.fixture(scope="module")
def pngs(tmp_path_factory):
    d = Path(os.environ.get("BTFRS_VIEWER_PNGS") or tmp_path_factory.mktemp("rti_frames"))
    d.mkdir(parents=True, exist_ok=True)
    return d


@pytest.fixture(scope="module")
def capture():
    """A single-view capture of a built-in material (its lights the UBO set's)."""
    btf = btfrs.materials.make("bumps", size=48, seed=4, views=[[0.0, 0.0, 1.0]])
    return btfrs.Btf(btf.data[:H, :W], btf.views, btf.lights)


@pytest.fixture(scope="module")
def rti_models(capture):
    # A PTM, whose modes are RTIViewer's exactly; HSH and the neural model, for which the modes
    # fit the PTM polynomial to the model's values.
    return {"ptm": btfrs.fit.ptm(capture), "hsh": btfrs.fit.hsh(capture),
            "neural": btfrs.fit.neural(capture, steps=150, hidden=12, seed=1)}


@pytest.fixture(scope="module")
def served(tmp_path_factory, viewer_files, rti_models):  # noqa: F811
    root = tmp_path_factory.mktemp("rti_web")
    for kind, m in rti_models.items():
        save_web(m, root / kind)
    server = Server(root)
    yield server
    server.close()


def evaluator(model):
    return lambda light: model.evaluate([0.0, 0.0, 1.0], light)


def expected(model, state, mode="default", params=PARAMS, light=LIGHT) -> np.ndarray:
    fit = np.asarray(btfrs.web.rti_fit_lights())
    values = ref.texel_values(evaluator(model), mode, light, params, fit)
    img = ref.resample(values, state["size"], state["zoom"], state["center"], (model.width, model.height))
    return ref.display(img, state["exposure"], raw=mode == "normals")


def opened(browser, url):  # noqa: F811
    page = Page(browser)
    page.open(url)
    return page


def test_models_of_the_fixture_are_single_view(rti_models):
    for m in rti_models.values():
        assert (m.height, m.width) == (H, W) and btfrs.web._views(m) == 1


@pytest.mark.parametrize("kind", ["ptm", "hsh", "neural"])
def test_the_image_view_fills_the_canvas_and_is_bilinear_between_texels(kind, browser, served, rti_models, pngs):  # noqa: F811
    model = rti_models[kind]
    with opened(browser, f"{served.url}/{kind}/index.html") as page:
        pg = page.page
        assert pg.evaluate("window.btfrsViewer.state().scene") == "image"
        # Fit: the whole image, straight on, filling the canvas (same aspect: no background).
        pg.evaluate("(s) => window.btfrsViewer.set(s)", {"light": LIGHT, "size": list(SIZE), "zoom": None, "center": None})
        st = pg.evaluate("window.btfrsViewer.state()")
        assert st["zoom"] == pytest.approx(3.0) and st["center"] == [W / 2, H / 2]
        got = frame(pg)
        want = expected(model, st)
        write_png(pngs / f"image_{kind}_fit.viewer.png", got)
        write_png(pngs / f"image_{kind}_fit.cpu.png", want)
        assert psnr(got, want) >= MIN_PSNR, psnr(got, want)
        assert (got.reshape(-1, 3).max(axis=1) > 0).all(), "background inside the fitted view"
        # Zoomed in to 9.5 pixels a texel, off centre: bilinear, not blocks, and the image's edge.
        pg.evaluate("(s) => window.btfrsViewer.set(s)", {"zoom": 9.5, "center": [4.3, 27.6]})
        st = pg.evaluate("window.btfrsViewer.state()")
        got = frame(pg)
        want = expected(model, st)
        write_png(pngs / f"image_{kind}_zoom.viewer.png", got)
        write_png(pngs / f"image_{kind}_zoom.cpu.png", want)
        assert psnr(got, want) >= MIN_PSNR, psnr(got, want)
        # Nearest lookups would make blocks of 9.5 equal pixels; bilinear varies inside a texel.
        blocky = ref.display(ref.resample(np.repeat(np.repeat(
            ref.texel_values(evaluator(model), "default", LIGHT, PARAMS, btfrs.web.rti_fit_lights()), 1, 0), 1, 1),
            st["size"], st["zoom"], st["center"], (W, H)))
        assert got[40:60, 60:80].std() > 0 and psnr(got, blocky) >= MIN_PSNR
        assert (got[:, :10] == 0).all(), "left of the image is background"
        assert st["passes"] == 2  # magnified: each texel relit once, then interpolated
        # Minified (0.75 pixel a texel): each pixel relights its four texels itself.
        pg.evaluate("(s) => window.btfrsViewer.set(s)", {"size": [30, 24], "zoom": None, "center": None})
        st = pg.evaluate("window.btfrsViewer.state()")
        assert st["zoom"] == pytest.approx(0.75) and st["passes"] == 1
        got = frame(pg)
        assert psnr(got, expected(model, st)) >= MIN_PSNR, psnr(got, expected(model, st))
        assert page.errors == []


@pytest.mark.parametrize("kind", ["ptm", "hsh", "neural"])
def test_each_mode_matches_its_numpy_reference(kind, browser, served, rti_models, pngs):  # noqa: F811
    model = rti_models[kind]
    with opened(browser, f"{served.url}/{kind}/index.html") as page:
        pg = page.page
        for mode in ("diffuse_gain", "specular", "normals"):
            pg.evaluate("(s) => window.btfrsViewer.set(s)", {"light": LIGHT, "size": list(SIZE), "mode": mode,
                                                             "zoom": 5.0, "center": [21.0, 14.5], **PARAMS})
            st = pg.evaluate("window.btfrsViewer.state()")
            got = frame(pg)
            want = expected(model, st, mode)
            plain = expected(model, st, "default")
            write_png(pngs / f"mode_{kind}_{mode}.viewer.png", got)
            write_png(pngs / f"mode_{kind}_{mode}.cpu.png", want)
            value = psnr(got, want)
            print(f"{kind} {mode}: {value:.1f} dB")
            assert value >= MIN_PSNR, (mode, value)
            assert psnr(got, plain) < value - 6, f"{mode} changed nothing"
        assert page.errors == []


def test_a_ptms_normal_map_is_the_stationary_point_of_its_own_polynomial(browser, served, rti_models, pngs):  # noqa: F811
    # The modes fit a polynomial to the model's values; for a PTM that is its own polynomial, so
    # the normal map equals Malzbender's normal from the PTM's stored coefficients.
    m = rti_models["ptm"]
    a = m.arrays
    coeffs = a["coeffs_bias"] + a["coeffs_scale"] * a["coeffs_q"].reshape(H, W, 18).astype(np.float64)
    own = np.moveaxis(coeffs.reshape(H, W, 3, 6), 3, 0)  # [6, H, W, 3]
    normals = (ref.stationary_normals(own) + 1) / 2
    with opened(browser, f"{served.url}/ptm/index.html") as page:
        pg = page.page
        pg.evaluate("(s) => window.btfrsViewer.set(s)", {"size": list(SIZE), "mode": "normals"})
        st = pg.evaluate("window.btfrsViewer.state()")
        got = frame(pg)
    want = ref.display(ref.resample(normals, st["size"], st["zoom"], st["center"], (W, H)), raw=True)
    assert psnr(got, want) >= MIN_PSNR, psnr(got, want)
    # and the normals lean where the relief does: not all straight up
    assert np.abs(got[..., :2].astype(int) - 128).max() > 20


def test_the_view_is_in_the_address_and_a_shared_link_opens_it(browser, served, rti_models):  # noqa: F811
    with opened(browser, f"{served.url}/ptm/index.html") as page:
        pg = page.page
        pg.evaluate("(s) => window.btfrsViewer.set(s)", {"light": LIGHT, "size": list(SIZE), "mode": "specular",
                                                         "zoom": 6.0, "center": [10.5, 8.25], "kd": 0.5,
                                                         "ks": 0.8, "exponent": 12.0, "exposure": 1.5})
        url = pg.evaluate("window.location.href")
        first = frame(pg)
        state = pg.evaluate("window.btfrsViewer.state()")
    hash_ = url.split("#", 1)[1]
    assert "mode=specular" in hash_ and "zoom=6" in hash_ and "center=10.5,8.25" in hash_ and "ks=0.8" in hash_
    with opened(browser, f"{served.url}/ptm/index.html#{hash_}&size=120x96") as page:
        pg = page.page
        again = pg.evaluate("window.btfrsViewer.state()")
        for k in ("mode", "zoom", "center", "kd", "ks", "exponent", "exposure", "size"):
            assert again[k] == state[k], k
        assert np.allclose(again["light"], state["light"], atol=1e-4)
        assert psnr(frame(pg), first) >= 45
    # A bad address is said on the page and the view opens as it would without it.
    with opened(browser, f"{served.url}/ptm/index.html#mode=shiny") as page:
        assert "mode" in page.page.locator("#message").inner_text()
        assert page.page.evaluate("window.btfrsViewer.state().mode") == "default"


def test_drag_pans_and_the_wheel_zooms_about_the_pointer(browser, served):  # noqa: F811
    with opened(browser, f"{served.url}/hsh/index.html") as page:
        pg = page.page
        pg.evaluate("(s) => window.btfrsViewer.set(s)", {"size": [120, 96], "zoom": 4.0, "center": [20.0, 16.0]})
        box = pg.locator("#view").bounding_box()
        css = box["width"] / 120  # CSS pixels per canvas pixel
        cx, cy = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
        pg.mouse.move(cx, cy)
        pg.mouse.down()
        pg.mouse.move(cx + 40 * css, cy - 20 * css, steps=4)
        pg.mouse.up()
        pg.evaluate("window.btfrsViewer.settled()")
        st = pg.evaluate("window.btfrsViewer.state()")
        # The image moves with the pointer: 40 canvas pixels at 4 pixels a texel is 10 texels.
        assert st["center"] == pytest.approx([10.0, 21.0], abs=0.3)
        # The wheel over a point keeps the image point under it.
        px, py = 30, 70  # canvas pixels
        under = [st["center"][0] + (px - 60) / st["zoom"], st["center"][1] + (py - 48) / st["zoom"]]
        pg.mouse.move(box["x"] + px * css, box["y"] + py * css)
        pg.mouse.wheel(0, -400)
        pg.evaluate("window.btfrsViewer.settled()")
        z = pg.evaluate("window.btfrsViewer.state()")
        assert z["zoom"] > st["zoom"] * 1.2
        now = [z["center"][0] + (px - 60) / z["zoom"], z["center"][1] + (py - 48) / z["zoom"]]
        assert now == pytest.approx(under, abs=0.05)
        assert page.errors == []


# --- A tiled export ---------------------------------------------------------------------------

BIG = 2048
TILE_LIGHT = [-0.25, 0.35, float(np.sqrt(1 - 0.25**2 - 0.35**2))]


@pytest.fixture(scope="module")
def big_ptm(capture):
    """A 2048^2 single-view PTM: a fitted 40 x 32 PTM's planes enlarged, with a fine pattern so
    that every tile differs from its neighbours."""
    small = btfrs.fit.ptm(capture)
    a = small.arrays
    q = a["coeffs_q"].reshape(H, W, 18).astype(np.float64)
    yy, xx = np.mgrid[0:BIG, 0:BIG]
    big = q[(yy * H) // BIG, (xx * W) // BIG]
    fine = 12 * np.sin(xx / 7.0)[..., None] * np.cos(yy / 11.0)[..., None] * np.linspace(-1, 1, 18)
    arrays = dict(a)
    arrays["coeffs_q"] = np.clip(big + fine, 0, 255).astype(np.uint8).reshape(BIG, BIG, 1, 3, 6)
    return btfrs.Model.from_arrays(arrays, kind="ptm")


@pytest.fixture(scope="module")
def tiled_site(tmp_path_factory, viewer_files, big_ptm):  # noqa: F811
    root = tmp_path_factory.mktemp("tiled_web")
    save_web(big_ptm, root / "big", tiled=True, tile_format="png")
    server = Server(root)
    yield server
    server.close()


def _level_model(folder: Path, level: int, tmp: Path) -> btfrs.Model:
    """The model of one level of a tiled relight folder, assembled from its tiles with PIL (an
    independent reading of the layout): a whole-plane relight folder of that size, loaded."""
    from PIL import Image

    info = json.loads((folder / "info.json").read_text())
    out = tmp / f"level{level}"
    out.mkdir()
    size = None
    for dzi in sorted(folder.glob("plane_*.dzi")):
        name = dzi.stem
        tiles = sorted((folder / f"{name}_files" / str(level)).glob("*.png"))
        parts = {tuple(int(v) for v in t.stem.split("_")): np.asarray(Image.open(t).convert("RGB")) for t in tiles}
        cols = max(c for c, _ in parts) + 1
        rows = max(r for _, r in parts) + 1
        img = np.concatenate([np.concatenate([parts[(c, r)] for c in range(cols)], axis=1) for r in range(rows)], axis=0)
        size = img.shape[1], img.shape[0]
        Image.fromarray(img).save(out / f"{name}.png")
    info["width"], info["height"] = size
    info.get("btfrs", {}).pop("tiles", None)
    (out / "info.json").write_text(json.dumps(info))
    return btfrs.load(out)


def test_a_tiled_export_is_drawn_coarse_level_first_then_only_the_tiles_in_view(
        browser, tiled_site, big_ptm, tmp_path, pngs):  # noqa: F811
    site = Path(tiled_site.root) / "big"
    folder = site / "model"
    n_images = len(list(folder.glob("plane_*.dzi")))
    levels = json.loads((folder / "info.json").read_text())["btfrs"]["tiles"]["levels"]
    assert levels == 4  # 256, 512, 1024, 2048
    # Zoomed to 4 pixels a texel around (700.5, 1300.25) on a 256 x 256 canvas: 64 x 64 texels
    # of the last level, which lie in tiles (2, 4) and (2, 5).
    zoom, center = 4.0, [700.5, 1300.25]
    url = f"{tiled_site.url}/big/index.html#light={TILE_LIGHT[0]},{TILE_LIGHT[1]}&zoom={zoom}" \
          f"&center={center[0]},{center[1]}&size=256x256"
    page = Page(browser)
    held = []
    lock = threading.Lock()

    def hold(route):
        with lock:
            held.append(route)

    page.page.route("**/plane_*_files/3/**", hold)
    try:
        page.open(url)
        pg = page.page
        tiles = pg.evaluate("window.btfrsViewer.tiles()")
        # The first frame came from level 0, before any tile of the level in view had arrived.
        assert tiles["first"]["level"] == 0
        first = frame(pg)
        st = pg.evaluate("window.btfrsViewer.state()")
        assert st["window"]["level"] == 0
        coarse = _level_model(folder, 0, tmp_path)
        want0 = ref.display(ref.resample(coarse.evaluate([0, 0, 1], TILE_LIGHT), st["size"], st["zoom"], st["center"],
                                         (BIG, BIG), scale=BIG / coarse.width))
        write_png(pngs / "tiled_first.viewer.png", first)
        write_png(pngs / "tiled_first.cpu.png", want0)
        assert psnr(first, want0) >= MIN_PSNR, psnr(first, want0)
        # Now let the last level's tiles through.
        pg.wait_for_function(f"window.btfrsViewer.tiles().requested.length >= {n_images * 3}")
        with lock:
            for r in held:
                r.continue_()
        pg.unroute("**/plane_*_files/3/**")
        pg.evaluate("window.btfrsViewer.settled()")
        st = pg.evaluate("window.btfrsViewer.state()")
        assert st["window"]["level"] == 3
        got = frame(pg)
        fine = big_ptm.evaluate([0, 0, 1], TILE_LIGHT)
        want = ref.display(ref.resample(fine, st["size"], st["zoom"], st["center"], (BIG, BIG)))
        write_png(pngs / "tiled_zoom.viewer.png", got)
        write_png(pngs / "tiled_zoom.cpu.png", want)
        assert psnr(got, want) >= MIN_PSNR, psnr(got, want)
        requested = pg.evaluate("window.btfrsViewer.tiles().requested")
        want_tiles = {f"plane_{i}_files/{t}.png" for i in range(n_images) for t in ("0/0_0", "3/2_4", "3/2_5")}
        assert set(requested) == want_tiles and len(requested) == len(want_tiles)
        # of the pyramid's 85 tiles per image
        assert page.errors == []
    finally:
        page.close()


def test_jpeg_tiles_in_the_page_match_what_btfrs_reads_from_them(browser, viewer_files, rti_models, tmp_path, pngs):  # noqa: F811
    # The default tiles (JPEG, quality 95) decoded by the browser against btfrs's own decoding
    # of the same files: the two JPEG decoders may round differently, nothing more.
    a = dict(rti_models["hsh"].arrays)
    q = a["coeffs_q"]
    a["coeffs_q"] = np.ascontiguousarray(np.tile(q, (7, 6) + (1,) * (q.ndim - 2))[:210, :230])
    model = btfrs.Model.from_arrays(a, kind="hsh")
    save_web(model, tmp_path / "jpg", tiled=True, tile_size=64)
    folder = tmp_path / "jpg" / "model"
    assert {p.suffix for p in folder.rglob("*_files/*/*")} == {".jpg"}
    server = Server(tmp_path)
    try:
        with opened(browser, f"{server.url}/jpg/index.html#size=160x120&zoom=2.5&center=120,90"
                            f"&light={LIGHT[0]},{LIGHT[1]}") as page:
            pg = page.page
            pg.evaluate("window.btfrsViewer.settled()")
            st = pg.evaluate("window.btfrsViewer.state()")
            assert st["window"]["level"] == 2  # the last of 3 levels
            got = frame(pg)
            assert page.errors == []
    finally:
        server.close()
    back = btfrs.load(folder)
    want = ref.display(ref.resample(back.evaluate([0, 0, 1], st["light"]), st["size"], st["zoom"], st["center"],
                                    (230, 210)))
    write_png(pngs / "tiled_jpeg.viewer.png", got)
    write_png(pngs / "tiled_jpeg.cpu.png", want)
    assert psnr(got, want) >= MIN_PSNR, psnr(got, want)
