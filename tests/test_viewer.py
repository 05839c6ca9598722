"""The browser viewer (python/btfrs/viewer) in headless Chromium with WebGPU on SwiftShader: every
model kind's frame against the CPU reference renderer, the light disc, the single-file export,
and a console free of errors.

Needs Debian's chromium at /usr/bin/chromium and the playwright package (Playwright never
downloads a browser here); without them the tests are skipped, unless CI is set. The frames read
back and their CPU references are written as PNGs under a temporary folder, or under
$BTFRS_VIEWER_PNGS when set, to look at.
"""
from __future__ import annotations

import base64
import gc
import json
import functools
import http.server
import os
import shutil
import threading
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest

import btfrs
import btfrs.web

from conftest import in_ci

CHROMIUM = "/usr/bin/chromium"
LAUNCH_ARGS = ["--no-sandbox", "--enable-unsafe-webgpu", "--use-webgpu-adapter=swiftshader"]
SIZE = 96
MIN_PSNR = 35.0
KINDS = list(btfrs.model_kinds())  # every registered kind
# This checkout's viewer (the one under test), wherever btfrs itself is imported from.
VIEWER_SRC = Path(__file__).resolve().parents[1] / "python" / "btfrs" / "viewer"


def _missing() -> str:
    if not os.path.exists(CHROMIUM):
        return f"{CHROMIUM} is not installed (Debian's chromium package)"
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "the playwright package is not installed (pip install playwright; no browser download needed)"
    return ""


_why = _missing()
if _why:
    if in_ci():
        raise RuntimeError(f"the viewer tests cannot run: {_why}")
    pytest.skip(_why, allow_module_level=True)

from playwright.sync_api import sync_playwright  # noqa: E402


# --- helpers --------------------------------------------------------------------------------


def display(img: np.ndarray, exposure: float = 1.0) -> np.ndarray:
    """The viewer's display transform of a linear [H, W, 3] image: exposure, clamp, the
    piecewise sRGB curve, 8 bits."""
    x = np.clip(img.astype(np.float64) * exposure, 0.0, 1.0)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.round(s * 255.0).astype(np.uint8)


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return float("inf") if mse == 0 else 10 * np.log10(255.0**2 / mse)


def write_png(path: Path, rgb: np.ndarray) -> None:
    h, w, _ = rgb.shape
    raw = b"".join(b"\x00" + rgb[y].astype(np.uint8).tobytes() for y in range(h))

    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")
    path.write_bytes(png)


def save_web(model, path, **kw):
    """btfrs.web.save_web; the garbage collection brings out any file it left open (a
    ResourceWarning, an error under the suite's warning filter)."""
    out = btfrs.web.save_web(model, path, **kw)
    gc.collect()
    return out


def reference(model, camera: dict, light, intensity=1.0, scene="plane", size=SIZE, exposure=1.0,
              renderer=None, **surface) -> np.ndarray:
    """The CPU reference of what the viewer should show, 8-bit RGB (``surface``: coords=,
    tiles= and layout=, uv_scale= as btfrs.render takes them)."""
    make, args = btfrs.web.SCENES[scene]
    cam = btfrs.Camera.look_at(camera["eye"], camera["target"], camera["fov"], up=camera["up"])
    img = btfrs.render(model, getattr(btfrs.Scene, make)(*args), cam, [btfrs.DirectionalLight(light, intensity)],
                       size=(size, size), backend="cpu", renderer=renderer, **surface)
    return display(img, exposure)


def frame(page) -> np.ndarray:
    """The viewer's last frame as 8-bit RGB."""
    p = page.evaluate("window.btfrsViewer.readPixels()")
    data = np.frombuffer(base64.b64decode(p["data"]), dtype=np.uint8)
    return data.reshape(p["height"], p["width"], 4)[..., :3].copy()


class Server:
    """A static file server on a free localhost port, in a thread."""

    def __init__(self, root: Path):
        self.root = Path(root)
        handler = functools.partial(_QuietHandler, directory=str(root))
        self.httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
        self.url = f"http://localhost:{self.httpd.server_address[1]}"
        self.thread = threading.Thread(target=self.httpd.serve_forever, daemon=True)
        self.thread.start()

    def close(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()


class _QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args) -> None:
        pass


class Page:
    """A browser page collecting its console errors."""

    def __init__(self, browser, **options):
        self.page = browser.new_page(viewport={"width": 1000, "height": 800}, **options)
        self.errors = []
        self.page.on("console", lambda m: self.errors.append(f"console: {m.text}") if m.type == "error" else None)
        self.page.on("pageerror", lambda e: self.errors.append(f"pageerror: {e}"))

    def open(self, url: str) -> None:
        self.page.goto(url)
        self.page.evaluate("window.btfrsViewer.ready.catch(() => {})")
        self.page.wait_for_function("window.btfrsViewer && (window.btfrsViewer.frames > 0 || window.btfrsViewer.error)",
                                    timeout=60000)
        err = self.page.evaluate("window.btfrsViewer.error")
        assert err is None, f"the viewer failed: {err}"

    def close(self) -> None:
        self.page.close()

    def __enter__(self) -> "Page":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# --- fixtures -------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def viewer_files():
    """Export with this checkout's viewer."""
    old = btfrs.web.VIEWER_DIR
    if VIEWER_SRC.is_dir():
        btfrs.web.VIEWER_DIR = str(VIEWER_SRC)
    yield
    btfrs.web.VIEWER_DIR = old


@pytest.fixture(scope="module")
def browser():
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=LAUNCH_ARGS)
        yield b
        b.close()


@pytest.fixture(scope="module")
def sample():
    return btfrs.materials.make("bumps", size=16, seed=1)


@pytest.fixture(scope="module")
def models(sample):
    """One small fitted model per kind (neural on a single view, few steps)."""
    out = {}
    for kind in KINDS:
        if kind == "neural":
            one = btfrs.materials.make("bumps", size=16, seed=1, views=[[0.0, 0.0, 1.0]])
            out[kind] = btfrs.fit.neural(one, steps=200, hidden=16)
        else:
            out[kind] = getattr(btfrs.fit, kind)(sample)
    return out


@pytest.fixture(scope="module")
def served(tmp_path_factory, viewer_files, models):
    """Every kind exported under one server: /<kind>/index.html."""
    root = tmp_path_factory.mktemp("web")
    for kind, m in models.items():
        save_web(m, root / kind, force=True)
    save_web(models["lpca"], root / "lpca_3d", force=True, renderer="3d")
    server = Server(root)
    yield server
    server.close()


@pytest.fixture(scope="module")
def pngs(tmp_path_factory):
    d = Path(os.environ.get("BTFRS_VIEWER_PNGS") or tmp_path_factory.mktemp("frames"))
    d.mkdir(parents=True, exist_ok=True)
    return d


def _camera() -> dict:
    return dict(btfrs.web.DEFAULT_CAMERA)


# --- tests ----------------------------------------------------------------------------------


# lpca_3d: LPCA's "3d" renderer, the one with the 3D texture.
@pytest.mark.parametrize("kind", KINDS + ["lpca_3d"])
def test_every_kind_matches_the_cpu_reference(kind, browser, served, models, pngs):
    with Page(browser) as page:
        page.open(f"{served.url}/{kind}/index.html")
        light = [0.3, -0.4, 0.87]
        # On the plane (a single-view model opens in the 2D view: tests/test_viewer_rti.py).
        page.page.evaluate("(s) => window.btfrsViewer.set(s)", {"light": light, "size": [SIZE, SIZE], "scene": "plane"})
        got = frame(page.page)
        model = models["lpca" if kind == "lpca_3d" else kind]
        want = reference(model, _camera(), light, renderer="3d" if kind == "lpca_3d" else None)
        write_png(pngs / f"{kind}.viewer.png", got)
        write_png(pngs / f"{kind}.cpu.png", want)
        info = page.page.evaluate("window.btfrsViewer.info()")
        assert info["kind"] == model.kind
        value = psnr(got, want)
        print(f"{kind}: {value:.2f} dB")
        assert got.max() > 20, "the frame is black"
        assert value >= MIN_PSNR, f"{kind}: PSNR {value:.2f} dB against the CPU reference"
        assert page.errors == []


def _surface_frame(browser, url: str, light) -> tuple:
    with Page(browser) as page:
        page.open(url)
        page.page.evaluate("(s) => window.btfrsViewer.set(s)", {"light": light, "size": [SIZE, SIZE]})
        got = frame(page.page)
        facts = page.page.locator("#facts").inner_text()
        assert page.errors == []
    return got, facts


def _check_surface(pngs: Path, name: str, got, facts: str, want, other, says: str) -> None:
    """The frame matches the CPU reference of its surface, not that of another surface (the
    sample alone, another layout), and the page names what it draws."""
    write_png(pngs / f"{name}.viewer.png", got)
    write_png(pngs / f"{name}.cpu.png", want)
    assert says in facts, facts
    assert psnr(got, want) >= MIN_PSNR, psnr(got, want)
    assert psnr(got, other) < psnr(got, want) - 6, f"{name}: another surface looks the same"


def test_a_synthesized_coordinate_map_is_drawn_as_the_cpu_reference_draws_it(browser, viewer_files, models,
                                                                           tmp_path, pngs):
    # A coordinate map ([H, W, 2] uint16 (x, y) into the sample) of a size other than the
    # sample's, made as k-coherence makes them: patches of the sample, each copied from a
    # random place; repeated 1.5 times across. (Nearest lookups: a texel edge that falls on a
    # pixel centre may go either way in f32, so the map's texels span several pixels.)
    rng = np.random.default_rng(11)
    yy, xx = np.mgrid[0:18, 0:26]
    patch = (yy // 6) * 5 + xx // 6
    offset = rng.integers(0, 16, (patch.max() + 1, 2))
    coords = np.stack([(xx + offset[patch, 0]) % 16, (yy + offset[patch, 1]) % 16], axis=-1).astype(np.uint16)
    model = models["hsh"]
    save_web(model, tmp_path / "c", coords=coords, uv_scale=(1.5, 1.0))
    server = Server(tmp_path)
    try:
        light = [0.25, -0.35, 0.9]
        got, facts = _surface_frame(browser, f"{server.url}/c/index.html", light)
    finally:
        server.close()
    want = reference(model, _camera(), light, coords=coords, uv_scale=(1.5, 1.0))
    plain = reference(model, _camera(), light, uv_scale=(1.5, 1.0))
    _check_surface(pngs, "coords", got, facts, want, plain, "synthesized texture of 26 x 18 texels")


def test_a_wang_tiling_is_drawn_as_the_cpu_reference_draws_it(browser, viewer_files, tmp_path, pngs):
    # A tile set of the PTM of a 32^2 sample, drawn through its BTFel model with a 4 x 3 layout.
    ptm = btfrs.fit.ptm(btfrs.materials.make("bumps", size=32, seed=2))
    ts = btfrs.tiles.wang(ptm, tile=16, edge_height=4, colors=2, seed=3, progress=False)
    layout = ts.tiling(4, 3, seed=4)
    save_web(ts.model, tmp_path / "t.html", single_file=True, tiles=ts, layout=layout)
    light = [-0.3, 0.2, 0.93]
    got, facts = _surface_frame(browser, (tmp_path / "t.html").as_uri(), light)
    want = reference(ts.model, _camera(), light, tiles=ts, layout=layout)
    other = reference(ts.model, _camera(), light, tiles=ts, layout=ts.tiling(4, 3, seed=5))
    _check_surface(pngs, "tiles", got, facts, want, other, "Wang tiling of 4 x 3 tiles of 16^2")


def test_the_sky_lights_the_model_as_the_sampled_environment_does(browser, served, models, pngs):
    # The "Sky light" switch: the built-in sky's importance-sampled lights plus the disc's light,
    # what btfrs.render(environment=sky, lighting="sampled", samples=64, seed=0) draws.
    with Page(browser) as page:
        page.open(f"{served.url}/hsh/index.html")
        light = [0.2, 0.3, 0.93]
        page.page.click("#sky")
        page.page.evaluate("(s) => window.btfrsViewer.set(s)", {"light": light, "size": [SIZE, SIZE]})
        assert page.page.evaluate("window.btfrsViewer.state().sky") is True
        got = frame(page.page)
        make, args = btfrs.web.SCENES["plane"]
        cam = _camera()
        img = btfrs.render(models["hsh"], getattr(btfrs.Scene, make)(*args),
                           btfrs.Camera.look_at(cam["eye"], cam["target"], cam["fov"], up=cam["up"]),
                           [btfrs.DirectionalLight(light, 1.0)], size=(SIZE, SIZE), backend="cpu",
                           environment=btfrs.Environment.sky(), lighting="sampled",
                           samples=btfrs.web.SKY_SAMPLES, seed=0)
        want = display(img)
        write_png(pngs / "hsh.sky.viewer.png", got)
        value = psnr(got, want)
        assert value >= MIN_PSNR, f"sky: PSNR {value:.2f} dB against the CPU reference"
        # and it is not the disc's light alone
        assert psnr(got, reference(models["hsh"], cam, light)) < value - 3
        assert page.errors == []


def test_light_disc_drag_moves_the_light(browser, served, models, pngs):
    with Page(browser) as page:
        page.open(f"{served.url}/ptm/index.html")
        page.page.evaluate("(s) => window.btfrsViewer.set(s)", {"size": [SIZE, SIZE]})
        before = frame(page.page)
        old = page.page.evaluate("window.btfrsViewer.state().light")
        box = page.page.locator("#light-disc").bounding_box()
        cx, cy = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
        m = page.page.mouse
        m.move(cx, cy)
        m.down()
        m.move(cx - 0.2 * box["width"], cy - 0.1 * box["height"], steps=5)
        m.move(cx - 0.3 * box["width"], cy + 0.15 * box["height"], steps=5)
        m.up()
        page.page.evaluate("window.btfrsViewer.settled()")
        light = page.page.evaluate("window.btfrsViewer.state().light")
        assert light[0] < -0.3 and light[1] < -0.1, light  # left and down on the disc
        assert abs(np.linalg.norm(light) - 1) < 1e-5 and not np.allclose(light, old)
        after = frame(page.page)
        want = reference(models["ptm"], _camera(), light)
        write_png(pngs / "drag.viewer.png", after)
        write_png(pngs / "drag.cpu.png", want)
        assert psnr(after, want) >= MIN_PSNR, psnr(after, want)
        assert psnr(after, before) < 30, "the frame did not change"
        assert page.errors == []


def test_single_file_export_opens_from_disk(browser, viewer_files, models, tmp_path, pngs):
    path = tmp_path / "x.html"
    save_web(models["hsh"], path, single_file=True)
    with Page(browser) as page:
        page.open(path.as_uri())
        light = [-0.2, 0.5, 0.84]
        page.page.evaluate("(s) => window.btfrsViewer.set(s)", {"light": light, "size": [SIZE, SIZE]})
        got = frame(page.page)
        want = reference(models["hsh"], _camera(), light)
        write_png(pngs / "single.viewer.png", got)
        assert psnr(got, want) >= MIN_PSNR, psnr(got, want)
        assert page.errors == []


def test_scenes_and_exposure(browser, served, models, pngs):
    with Page(browser) as page:
        page.open(f"{served.url}/lafortune/index.html")
        light = [0.5, 0.2, 0.84]
        for scene in ("sphere", "cylinder"):
            cam = {"eye": [2.2, -2.6, 1.8], "target": [0.0, 0.0, 0.0], "up": [0.0, 0.0, 1.0], "fov": 45.0}
            page.page.evaluate("(s) => window.btfrsViewer.set(s)",
                               {"light": light, "size": [SIZE, SIZE], "scene": scene, "camera": cam, "exposure": 1.7})
            got = frame(page.page)
            want = reference(models["lafortune"], cam, light, scene=scene, exposure=1.7)
            write_png(pngs / f"{scene}.viewer.png", got)
            assert psnr(got, want) >= MIN_PSNR, (scene, psnr(got, want))
        assert page.errors == []


def test_drags_on_the_image_orbit_pan_zoom_and_move_the_light(browser, served, models):
    with Page(browser) as page:
        # A model of many views orbits: the eye moves around the target at the same distance.
        page.open(f"{served.url}/ptm/index.html")
        pg = page.page
        pg.evaluate("(s) => window.btfrsViewer.set(s)", {"size": [SIZE, SIZE]})
        box = pg.locator("#view").bounding_box()
        cx, cy = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
        before = pg.evaluate("window.btfrsViewer.state().camera")
        pg.mouse.move(cx, cy)
        pg.mouse.down()
        pg.mouse.move(cx + 60, cy - 20, steps=4)
        pg.mouse.up()
        pg.evaluate("window.btfrsViewer.settled()")
        cam = pg.evaluate("window.btfrsViewer.state().camera")
        dist = lambda c: np.linalg.norm(np.subtract(c["eye"], c["target"]))  # noqa: E731
        assert not np.allclose(cam["eye"], before["eye"]) and np.allclose(cam["target"], before["target"])
        assert dist(cam) == pytest.approx(dist(before), rel=1e-5)
        light = pg.evaluate("window.btfrsViewer.state().light")
        got = frame(pg)
        assert psnr(got, reference(models["ptm"], cam, light)) >= MIN_PSNR
        # The wheel zooms.
        pg.mouse.move(cx, cy)
        pg.mouse.wheel(0, 300)
        pg.evaluate("window.btfrsViewer.settled()")
        zoomed = pg.evaluate("window.btfrsViewer.state().camera")
        assert dist(zoomed) > dist(cam) * 1.1
        # L held: a drag on the image moves the light instead (image corner = disc edge).
        pg.keyboard.down("l")
        pg.mouse.move(cx, cy)
        pg.mouse.down()
        pg.mouse.move(box["x"] + 0.25 * box["width"], box["y"] + 0.5 * box["height"], steps=3)
        pg.mouse.up()
        pg.keyboard.up("l")
        pg.evaluate("window.btfrsViewer.settled()")
        moved = pg.evaluate("window.btfrsViewer.state()")
        assert moved["camera"] == zoomed
        assert moved["light"] == pytest.approx([-0.5, 0.0, np.sqrt(0.75)], abs=0.03)
        assert page.errors == []
    with Page(browser) as page:
        # A single-view model on the plane pans: eye and target move together.
        page.open(f"{served.url}/neural/index.html")
        pg = page.page
        assert pg.evaluate("window.btfrsViewer.info().views") == 1
        pg.evaluate("(s) => window.btfrsViewer.set(s)", {"scene": "plane"})
        before = pg.evaluate("window.btfrsViewer.state().camera")
        box = pg.locator("#view").bounding_box()
        cx, cy = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
        pg.mouse.move(cx, cy)
        pg.mouse.down()
        pg.mouse.move(cx + 40, cy + 10, steps=3)
        pg.mouse.up()
        pg.evaluate("window.btfrsViewer.settled()")
        cam = pg.evaluate("window.btfrsViewer.state().camera")
        shift = np.subtract(cam["target"], before["target"])
        assert np.linalg.norm(shift) > 0.01
        assert np.allclose(np.subtract(cam["eye"], before["eye"]), shift, atol=1e-5)
        assert page.errors == []


def _export_with_manifest(src: Path, dst: Path, change) -> None:
    shutil.copytree(src, dst)
    path = dst / "model" / "manifest.json"
    manifest = json.loads(path.read_text())
    change(manifest)
    path.write_text(json.dumps(manifest))


def test_an_unknown_format_version_or_kind_is_said_in_the_page(browser, served, tmp_path):
    def version(m):
        m["version"] = 99

    def kind(m):
        m["model"]["kind"] = "mystery"

    def fmt(m):
        m["format"] = "something-else"

    cases = {"version": (version, "version 99"), "kind": (kind, "unknown model kind \"mystery\""),
             "format": (fmt, "not a btfrs web export")}
    for name, (change, _) in cases.items():
        _export_with_manifest(served.root / "srf", tmp_path / name, change)
    server = Server(tmp_path)
    with Page(browser) as page:
        for name, (_, text) in cases.items():
            page.page.goto(f"{server.url}/{name}/index.html")
            page.page.wait_for_function("window.btfrsViewer && window.btfrsViewer.error", timeout=30000)
            assert text in page.page.evaluate("window.btfrsViewer.error")
            assert text in page.page.locator("#message").inner_text()
        assert page.errors == []
        server.close()


@pytest.mark.parametrize("how,text", [
    ("delete Navigator.prototype.gpu;", "WebGPU is not available"),
    ("Object.defineProperty(GPU.prototype, 'requestAdapter', {value: async () => null});", "no GPU adapter"),
])
def test_without_webgpu_the_page_says_so(browser, served, how, text):
    with Page(browser) as page:
        page.page.add_init_script(how)
        page.page.goto(f"{served.url}/ptm/index.html")
        page.page.wait_for_function("window.btfrsViewer && window.btfrsViewer.error", timeout=30000)
        assert text in page.page.evaluate("window.btfrsViewer.error")
        assert page.page.locator("#message").is_visible()
        assert text in page.page.locator("#message").inner_text()
        assert page.errors == []


def test_a_canvas_that_cannot_be_presented_falls_back_to_read_back(browser, served, models):
    """Told it is not headless, the viewer presents on the WebGPU canvas, which headless Chromium
    cannot do (it loses the device): the viewer starts again, reading frames back into a 2D
    canvas. In a browser of its own, as Chromium refuses WebGPU after a few lost devices."""
    b = browser.browser_type.launch(executable_path=CHROMIUM, headless=True, args=LAUNCH_ARGS)
    try:
        ua = b.new_page().evaluate("navigator.userAgent").replace("HeadlessChrome", "Chrome")
        page = Page(b, user_agent=ua)
        page.open(f"{served.url}/ptm/index.html")
        assert page.page.evaluate("window.btfrsViewer.info().presentation") == "2d"
        light = [0.1, 0.6, 0.79]
        page.page.evaluate("(s) => window.btfrsViewer.set(s)", {"light": light, "size": [SIZE, SIZE]})
        assert psnr(frame(page.page), reference(models["ptm"], _camera(), light)) >= MIN_PSNR
        assert page.errors == []
    finally:
        b.close()
