"""A camera-sized tiled web export, timed: write a single-view PTM of WIDTH x HEIGHT texels (24
megapixels by default) as a tiled page (``btfrs.web.save_web(..., tiled=True)``: relight's layout,
Deep Zoom pyramids of 256-pixel tiles), read it back (``btfrs.load``), then open it in headless
Chromium (WebGPU on SwiftShader) as a visitor would: the time to the first frame (drawn from the
one-tile level 0), to the frame of the fitted view, and to a frame zoomed to 4 pixels a texel, with
the tiles fetched for each and the bytes they hold, against the pyramid's; then the frame of each
rendering mode at the zoomed view.

The PTM is a 128^2 fit of a built-in capture repeated over the image (the export and the page do
not care what the coefficients are; their sizes and the tiles' are what is measured).

    python scripts/tiled_viewer_bench.py [--width 6000 --height 4000] [--format jpg] [--canvas 1024x768]

Needs Debian's chromium and the playwright package (as tests/test_viewer.py); prints a table and
writes bench-results/tiled_viewer.json.
"""
from __future__ import annotations

import argparse
import functools
import http.server
import json
import os
import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

import btfrs
import btfrs.web

CHROMIUM = "/usr/bin/chromium"
LAUNCH_ARGS = ["--no-sandbox", "--enable-unsafe-webgpu", "--use-webgpu-adapter=swiftshader"]


class _Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args) -> None:
        pass


def big_ptm(width: int, height: int) -> btfrs.Model:
    cap = btfrs.materials.make("bumps", size=128, seed=2, views=[[0.0, 0.0, 1.0]])
    small = btfrs.fit.ptm(cap)
    a = dict(small.arrays)
    reps = (-(-height // 128), -(-width // 128), 1, 1, 1)
    a["coeffs_q"] = np.ascontiguousarray(np.tile(a["coeffs_q"], reps)[:height, :width])
    return btfrs.Model.from_arrays(a, kind="ptm")


def folder_bytes(path: Path) -> int:
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=6000)
    ap.add_argument("--height", type=int, default=4000)
    ap.add_argument("--format", choices=["jpg", "png"], default="jpg")
    ap.add_argument("--canvas", default="1024x768", help="the page's canvas, WIDTHxHEIGHT (default: 1024x768)")
    ap.add_argument("--out", default=None, help="where the site is written (default: a temporary folder)")
    ap.add_argument("--json", default="bench-results/tiled_viewer.json")
    args = ap.parse_args()
    cw, ch = (int(v) for v in args.canvas.split("x"))
    root = Path(args.out or tempfile.mkdtemp(prefix="btfrs-tiled-"))
    site = root / "site"
    if site.exists():
        shutil.rmtree(site)
    res: dict = {"width": args.width, "height": args.height, "format": args.format, "canvas": [cw, ch],
                 "date": time.strftime("%Y-%m-%d"), "cpus": os.cpu_count()}

    model = big_ptm(args.width, args.height)
    t = time.perf_counter()
    btfrs.web.save_web(model, site, tiled=True, tile_format=args.format)
    res["export_s"] = time.perf_counter() - t
    folder = site / "model"
    manifest = json.loads((folder / "manifest.json").read_text())
    images = len(manifest["tiles"]["images"])
    tiles = [p for p in folder.rglob(f"*.{args.format}") if "_files" in str(p)]
    res["levels"] = manifest["tiles"]["levels"]
    res["tiles"] = len(tiles)
    res["tile_bytes"] = sum(p.stat().st_size for p in tiles)
    res["site_bytes"] = folder_bytes(site)
    res["plane_bytes"] = args.width * args.height * 3 * images
    del model
    t = time.perf_counter()
    back = btfrs.load(folder)
    res["load_s"] = time.perf_counter() - t
    del back

    from playwright.sync_api import sync_playwright

    handler = functools.partial(_Quiet, directory=str(root))
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=httpd.serve_forever, daemon=True).start()
    url = f"http://localhost:{httpd.server_address[1]}/site/index.html#size={cw}x{ch}"
    sizes = {str(p.relative_to(folder)): p.stat().st_size for p in tiles}
    try:
        with sync_playwright() as p:
            b = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=LAUNCH_ARGS)
            page = b.new_page(viewport={"width": 1400, "height": 1000})
            errors: list = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            t0 = time.perf_counter()
            page.goto(url)
            page.wait_for_function("window.btfrsViewer && (window.btfrsViewer.frames > 0 || window.btfrsViewer.error)",
                                   timeout=600000)
            first = time.perf_counter() - t0
            api = page.evaluate("({f: window.btfrsViewer.firstFrameMs, e: window.btfrsViewer.error, "
                                "t: window.btfrsViewer.tiles()})")
            if api["e"]:
                raise SystemExit(f"the page failed: {api['e']}")
            res["first_frame_ms"] = api["f"]
            res["first_frame_level"] = api["t"]["first"]["level"]
            res["first_frame_tiles"] = images  # level 0: one tile per image
            page.evaluate("window.btfrsViewer.settled()")
            fit = time.perf_counter() - t0
            st = page.evaluate("window.btfrsViewer.state()")
            req = page.evaluate("window.btfrsViewer.tiles().requested")
            res["fit_s"] = fit
            res["fit_level"] = st["window"]["level"]
            res["fit_tiles"] = len(req)
            res["fit_bytes"] = sum(sizes[r] for r in req)
            t1 = time.perf_counter()
            page.evaluate("(s) => window.btfrsViewer.set(s)", {"zoom": 4.0, "center": [args.width * 0.37, args.height * 0.61]})
            page.evaluate("window.btfrsViewer.settled()")
            res["zoom_s"] = time.perf_counter() - t1
            req2 = page.evaluate("window.btfrsViewer.tiles().requested")
            st = page.evaluate("window.btfrsViewer.state()")
            res["zoom_level"] = st["window"]["level"]
            res["zoom_tiles"] = len(req2) - len(req)
            res["zoom_bytes"] = sum(sizes[r] for r in req2[len(req):])
            res["frame_ms"] = page.evaluate("window.btfrsViewer.frameMs")
            # Each mode at the zoomed view, its frame alone (the best of three).
            res["mode_ms"] = {}
            for mode in ("default", "diffuse_gain", "specular", "normals"):
                ms = []
                for i in range(3):
                    page.evaluate("(s) => window.btfrsViewer.set(s)", {"mode": mode, "exposure": 1.0 + 0.01 * i})
                    ms.append(page.evaluate("window.btfrsViewer.frameMs"))
                res["mode_ms"][mode] = min(ms)
            res["page_errors"] = errors
            res["first_frame_wall_s"] = first
            b.close()
    finally:
        httpd.shutdown()
        httpd.server_close()
        if args.out is None:
            shutil.rmtree(root, ignore_errors=True)

    mb = 1 << 20
    print(f"{args.width} x {args.height} single-view PTM, {images} plane images, {args.format} tiles:")
    print(f"  export (tiled page): {res['export_s']:.1f} s, {res['tiles']} tiles in {res['levels']} levels, "
          f"{res['tile_bytes'] / mb:.1f} MiB of tiles ({res['plane_bytes'] / mb:.0f} MiB of plane bytes)")
    print(f"  btfrs.load of the tiled folder (every tile decoded): {res['load_s']:.1f} s")
    print(f"  first frame: {res['first_frame_ms']:.0f} ms from navigation, level {res['first_frame_level']}, "
          f"{res['first_frame_tiles']} tiles")
    print(f"  fitted view ({cw} x {ch}): {res['fit_s']:.1f} s, level {res['fit_level']}, {res['fit_tiles']} tiles "
          f"fetched, {res['fit_bytes'] / mb:.2f} MiB")
    print(f"  zoomed to 4 px a texel: {res['zoom_s']:.1f} s more, level {res['zoom_level']}, {res['zoom_tiles']} "
          f"tiles, {res['zoom_bytes'] / mb:.2f} MiB; last frame {res['frame_ms']:.0f} ms")
    print("  frames at the zoomed view: " + ", ".join(f"{k} {v:.0f} ms" for k, v in res["mode_ms"].items()))
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
