"""The viewer's pictures in docs/viewer.md: a single-view capture's PTM in each rendering mode of
the 2D view, a view zoomed in to single texels, and a tiled page, each frame read back from the
page's own frame buffer (``window.btfrsViewer.readPixels()``) in headless Chromium and saved with
PIL; and one screenshot of the whole page.

    python scripts/viewer_figures.py [--out docs/viewer]

Needs Debian's chromium and the playwright package (as tests/test_viewer.py).
"""
from __future__ import annotations

import argparse
import base64
import functools
import http.server
import sys
import tempfile
import threading
from pathlib import Path

import numpy as np
from PIL import Image

import btfrs
import btfrs.web

CHROMIUM = "/usr/bin/chromium"
LAUNCH_ARGS = ["--no-sandbox", "--enable-unsafe-webgpu", "--use-webgpu-adapter=swiftshader"]
LIGHT = [-0.45, 0.35, float(np.sqrt(1 - 0.45**2 - 0.35**2))]


class _Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args) -> None:
        pass


def frame(page) -> Image.Image:
    p = page.evaluate("window.btfrsViewer.readPixels()")
    data = np.frombuffer(base64.b64decode(p["data"]), np.uint8).reshape(p["height"], p["width"], 4)
    return Image.fromarray(data[..., :3].copy())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="docs/viewer")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    root = Path(tempfile.mkdtemp(prefix="btfrs-figures-"))
    cap = btfrs.materials.make("bumps", size=96, seed=7, views=[[0.0, 0.0, 1.0]])
    ptm = btfrs.fit.ptm(cap)
    btfrs.web.save_web(ptm, root / "ptm", name="bumps PTM")
    # A tiled page: the PTM repeated over 1536 x 1024 texels, in 256-pixel JPEG tiles.
    # (a disc of the material on its flat ground, so that the level and the region show)
    a = dict(ptm.arrays)
    q = np.tile(a["coeffs_q"], (11, 16, 1, 1, 1))[:1024, :1536].astype(np.float32)
    yy, xx = np.mgrid[0:1024, 0:1536]
    disc = np.clip((430.0 - np.hypot(xx - 768, yy - 512)) / 6.0, 0, 1)[..., None, None, None]
    ground = np.median(a["coeffs_q"].reshape(-1, 3, 6), axis=0)[None, None, None]
    a["coeffs_q"] = np.ascontiguousarray(np.round(disc * q + (1 - disc) * ground).astype(np.uint8))
    big = btfrs.Model.from_arrays(a, kind="ptm")
    btfrs.web.save_web(big, root / "tiled", tiled=True, name="bumps PTM, tiled")
    handler = functools.partial(_Quiet, directory=str(root))
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=httpd.serve_forever, daemon=True).start()
    url = f"http://localhost:{httpd.server_address[1]}"
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=LAUNCH_ARGS)
        page = b.new_page(viewport={"width": 900, "height": 560})
        page.goto(f"{url}/ptm/index.html")
        page.wait_for_function("window.btfrsViewer && (window.btfrsViewer.frames > 0 || window.btfrsViewer.error)",
                               timeout=120000)
        set_ = functools.partial(page.evaluate, "(s) => window.btfrsViewer.set(s)")
        set_({"light": LIGHT, "mode": "specular", "ks": 0.6, "exponent": 30})
        page.evaluate("window.btfrsViewer.settled()")
        page.screenshot(path=str(out / "rti_page.png"))
        for mode, extra in (("default", {}), ("diffuse_gain", {"gain": 2.0}),
                            ("specular", {"kd": 0.6, "ks": 0.6, "exponent": 30.0}), ("normals", {})):
            set_({"light": LIGHT, "size": [384, 384], "mode": mode, "zoom": None, "center": None, **extra})
            frame(page).save(out / f"rti_{mode}.png")
            print(f"wrote {out / f'rti_{mode}.png'}")
        set_({"mode": "default", "zoom": 24.0, "center": [40.0, 52.0]})
        frame(page).save(out / "rti_zoom.png")
        page.goto(f"{url}/tiled/index.html#size=768x512&light={LIGHT[0]},{LIGHT[1]}")
        page.wait_for_function("window.btfrsViewer && (window.btfrsViewer.frames > 0 || window.btfrsViewer.error)",
                               timeout=120000)
        page.evaluate("window.btfrsViewer.settled()")
        fit = frame(page)
        n_fit = page.evaluate("window.btfrsViewer.tiles().requested.length")
        set_({"zoom": 3.0, "center": [1090.0, 330.0], "mode": "specular"})
        page.evaluate("window.btfrsViewer.settled()")
        zoom = frame(page)
        n_zoom = page.evaluate("window.btfrsViewer.tiles().requested.length") - n_fit
        both = Image.new("RGB", (fit.width + zoom.width + 8, fit.height), (17, 17, 17))
        both.paste(fit, (0, 0))
        both.paste(zoom, (fit.width + 8, 0))
        both.save(out / "tiled.png")
        print(f"{n_fit} tiles for the fitted view, {n_zoom} more for the zoomed one")
        b.close()
    httpd.shutdown()
    for n in ("rti_zoom", "tiled", "rti_page"):
        print(f"wrote {out / f'{n}.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
