"""Accuracy and speed of ``btfrs.calibrate`` on rendered captures whose lights are known.

Two steps (the captures of ``scripts/render_sphere_capture.py``, which writes ``scene.json``
with the true directions beside the photographs):

    # a camera-sized capture from a small render: every photograph enlarged (bicubic), cropped
    # to 6000 x 4000, given sensor noise (2 steps) and saved as JPEG quality 90
    .venv/bin/python scripts/bench_calibrate.py enlarge /tmp/sphere60 /tmp/big60 --size 6000 4000
    # calibrate, timed, and compared with the truth
    .venv/bin/python scripts/bench_calibrate.py run /tmp/big60 --repeat 2

``run`` prints the photographs, their size, the wall time of ``btfrs.calibrate`` per run, the
peak resident memory of the process, and the mean, median and largest angle between the lights
found and the true ones (with ``--fov`` for a perspective render).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import time
import warnings
from typing import List, Optional

import numpy as np


def enlarge(src: str, dst: str, width: int, height: int, quality: int, noise: float, seed: int) -> None:
    from PIL import Image  # noqa: PLC0415

    sc = json.load(open(os.path.join(src, "scene.json")))
    if sc["camera"] != "orthographic":
        sys.exit("enlarge: only orthographic renders (their sphere's circle scales with the image)")
    h0, w0 = sc["size"]
    k = width / w0
    hs = round(h0 * k)
    if hs < height:
        sys.exit(f"enlarge: a {w0} x {h0} render enlarged to {width} wide is {hs} high, under {height}")
    top = (hs - height) // 2
    os.makedirs(dst, exist_ok=True)
    rng = np.random.default_rng(seed)
    t0 = time.perf_counter()
    for i, name in enumerate(sc["files"]):
        with Image.open(os.path.join(src, name)) as im:
            big = im.resize((width, hs), Image.BICUBIC).crop((0, top, width, top + height))
        if noise > 0:
            # Sensor noise, so that the JPEGs hold as much as a camera's (an enlarged render
            # alone compresses 10x better and decodes faster than a photograph).
            px = np.asarray(big, dtype=np.float32)
            px += rng.normal(0.0, noise, px.shape).astype(np.float32)
            big = Image.fromarray(np.clip(np.rint(px), 0, 255).astype(np.uint8))
        big.save(os.path.join(dst, name), quality=quality)
        print(f"\r{i + 1}/{len(sc['files'])} ({time.perf_counter() - t0:.0f} s)", end="", file=sys.stderr)
    print(file=sys.stderr)
    cx, cy, r = sc["sphere_px"]
    sc.update(size=[height, width], jpeg_quality=quality, sphere_px=[cx * k, cy * k - top, r * k],
              target_rect=None, enlarged_from=os.path.abspath(src))
    with open(os.path.join(dst, "scene.json"), "w") as f:
        json.dump(sc, f, indent=1)


def run(folder: str, repeat: int, fov: Optional[float]) -> None:
    import btfrs  # noqa: PLC0415

    sc = json.load(open(os.path.join(folder, "scene.json")))
    truth = dict(zip(sc["files"], sc["directions"]))
    jpeg_bytes = sum(os.path.getsize(os.path.join(folder, f)) for f in sc["files"])
    times: List[float] = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            cal = btfrs.calibrate(folder, fov=fov)
        times.append(time.perf_counter() - t0)
    for w in caught:
        print(f"warning: {w.message}")
    h, w = cal.size
    found = cal.lights
    true = np.array([truth[os.path.basename(f)] for f in cal.files])
    err = np.degrees(np.arccos(np.clip(np.sum(found * true, axis=1), -1.0, 1.0)))
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # KiB on Linux
    n = len(cal.images)
    print(f"{n} photographs of {w} x {h} ({w * h / 1e6:.1f} MP, {jpeg_bytes / 1e6:.0f} MB of JPEG), "
          f"{os.cpu_count()} CPUs: " + ", ".join(f"{t:.2f} s" for t in times)
          + f" ({n * w * h / min(times) / 1e6:.0f} MP/s decoded); peak RSS {peak:.0f} MiB")
    cx, cy, r = cal.sphere
    print(f"sphere ({cx:.2f}, {cy:.2f}) r {r:.2f}" + (f"; true ({sc['sphere_px'][0]:.2f}, {sc['sphere_px'][1]:.2f}) "
                                                      f"r {sc['sphere_px'][2]:.2f}" if sc.get("sphere_px") else ""))
    print(f"{len(found)} of {n} calibrated; angle to the true lights: mean {err.mean():.3f}, median "
          f"{np.median(err):.3f}, max {err.max():.3f} degrees")


def main(argv: Optional[List[str]] = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="command", required=True)
    e = sub.add_parser("enlarge", help="a camera-sized capture from a rendered one")
    e.add_argument("src")
    e.add_argument("dst")
    e.add_argument("--size", type=int, nargs=2, default=[6000, 4000], metavar=("W", "H"))
    e.add_argument("--quality", type=int, default=90)
    e.add_argument("--noise", type=float, default=2.0, help="Gaussian noise in 8-bit steps (default: 2)")
    e.add_argument("--seed", type=int, default=0, help="seed of the noise (default: 0)")
    r = sub.add_parser("run", help="calibrate a rendered capture, timed, against its truth")
    r.add_argument("folder")
    r.add_argument("--repeat", type=int, default=1)
    r.add_argument("--fov", type=float, help="the render's field of view (perspective renders)")
    args = p.parse_args(argv)
    if args.command == "enlarge":
        enlarge(args.src, args.dst, args.size[0], args.size[1], args.quality, args.noise, args.seed)
    else:
        run(args.folder, args.repeat, args.fov)
    return 0


if __name__ == "__main__":
    sys.exit(main())
