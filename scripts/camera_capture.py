"""Make a camera-sized RTI capture: 60 JPEG photographs of 6000 x 4000 pixels and their `.lp`.

The benchmark input of ``scripts/camera_bench.py`` (and the "A 24-megapixel capture" section of
docs/scale.md): what a museum's dome gives, at the size of a 24-megapixel camera, made from
btfrs's built-in materials so that nothing third-party is needed.

    .venv/bin/python scripts/camera_capture.py --out /tmp/camera24
    .venv/bin/python scripts/camera_capture.py --out /tmp/small --size 1200 800 --period 200

**The surface.** Four built-in materials (``knit``, ``weave``, ``bumps``, ``grooves``) are each
rendered once at ``--period`` texels square (default 1000) for one view (straight down) and the
60 lights (:func:`btfrs.materials.make`, which renders a periodic sample of at most 1024 texels a
side). A material is periodic, so its render tiles seamlessly; the photograph is a 3 x 2 grid of
blocks (2000 x 2000 pixels at the default size), each a different material tiled to fill it. A
texel spans ``--scale`` pixels (2 by default: one render period fills a block), each pixel
interpolating the four texels around it, as a lens blurs what the sensor samples; JPEGs of
pixel-sharp texture would be twice the size a camera writes.

**The lights: a dome of five rings of twelve**, at elevations 12, 27, 42, 57 and 72 degrees, the
twelve of a ring 30 degrees apart in azimuth and every other ring turned by 15 degrees (no light
straight above: the camera is there). The ``.lp`` lists these directions in btfrs's frame (x to
the right of the image, y up it, z towards the camera), which is relight's and RTIBuilder's.

**The photographs.** A dome's lights are at a finite distance: each image's brightness falls off
across the frame as from a point light at the dome's radius (``--dome``, in frame widths; 3 by
default) in the light's direction (inverse square, 1 at the frame's centre; the shading itself
keeps the one direction). Then, as a camera does: sRGB-encoded, clipped at white, a little
sensor noise (``--noise``, in 8-bit steps, seeded), saved as JPEG (quality ``--quality``, 4:2:0
chroma). Each photograph is written under a temporary name and renamed; the ``.lp`` is written
last, so an interrupted run (Ctrl-C) leaves no ``.lp``.

Writes into ``--out``: ``light_NN.jpg``, ``dirs.lp`` and ``capture.json`` (the parameters).
Disk: about 8 to 9 MB per photograph at the default size (0.5 GB in all, what a 24-megapixel
camera's finest JPEGs take); decoded to float32 the capture is
24e6 x 60 x 3 x 4 bytes = 17.3 GB, so load it with ``btfrs.load(OUT/dirs.lp, mmap_to=...)``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from typing import List

import numpy as np

MATERIALS = ("knit", "weave", "bumps", "grooves")
ELEVATIONS = (12.0, 27.0, 42.0, 57.0, 72.0)
PER_RING = 12


def dome_lights() -> np.ndarray:
    """The 60 light directions: five rings of twelve (see the module's doc)."""
    out: List[List[float]] = []
    for r, el in enumerate(ELEVATIONS):
        e = math.radians(el)
        for k in range(PER_RING):
            az = math.radians(360.0 / PER_RING * k + (180.0 / PER_RING) * (r % 2))
            out.append([math.cos(e) * math.cos(az), math.cos(e) * math.sin(az), math.sin(e)])
    return np.asarray(out)


def srgb_encode(x: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1's sRGB encoding of linear values in [0, 1]."""
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4, dtype=np.float32) - 0.055)


def main(argv: List[str]) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, help="folder to write the photographs into (made if absent)")
    p.add_argument("--size", type=int, nargs=2, default=(6000, 4000), metavar=("WIDTH", "HEIGHT"),
                   help="photograph size in pixels (default: 6000 4000, 24 megapixels)")
    p.add_argument("--period", type=int, default=1000, help="texels a side of each material's render (default 1000)")
    p.add_argument("--scale", type=int, default=2, help="pixels a texel spans, interpolated (default 2)")
    p.add_argument("--quality", type=int, default=92, help="JPEG quality (default 92)")
    p.add_argument("--noise", type=float, default=1.0, help="sensor noise, standard deviation in 8-bit steps (default 1)")
    p.add_argument("--dome", type=float, default=3.0, help="the dome's radius in frame widths (default 3)")
    p.add_argument("--seed", type=int, default=0, help="seed of the materials and the noise (default 0)")
    args = p.parse_args(argv)

    import btfrs
    from PIL import Image

    width, height = args.size
    os.makedirs(args.out, exist_ok=True)
    lights = dome_lights()
    t0 = time.perf_counter()
    # Each material's render, light-major [L, P, P, 3] float16 (4 x 60 x 1000^2 x 3 x 2 bytes =
    # 1.4 GB at the defaults; float32 would double it for no visible difference after 8-bit JPEG).
    renders = []
    for i, name in enumerate(MATERIALS):
        print(f"rendering {name} at {args.period}^2 x {len(lights)} lights ({i + 1}/{len(MATERIALS)})", flush=True)
        btf = btfrs.materials.make(name, size=args.period, seed=args.seed, views=[[0.0, 0.0, 1.0]], lights=lights)
        renders.append(np.ascontiguousarray(btf.data[:, :, 0].transpose(2, 0, 1, 3)).astype(np.float16))
        del btf
    print(f"rendered in {time.perf_counter() - t0:.0f} s", flush=True)

    # Which material fills each pixel: a 3 x 2 grid of blocks. A texel spans `--scale` pixels: each
    # pixel interpolates the four texels around it (bilinear), as a lens blurs what it resolves.
    cols = np.minimum(np.arange(width) * 3 // width, 2)
    rows = np.minimum(np.arange(height) * 2 // height, 1)

    def taps(n: int) -> tuple:
        t = (np.arange(n) + 0.5) / args.scale - 0.5
        t0 = np.floor(t)
        return (t0.astype(np.int64) % args.period, (t0.astype(np.int64) + 1) % args.period,
                (t - t0).astype(np.float32))

    x0, x1, fx = taps(width)
    y0, y1, fy = taps(height)
    # Pixel positions on the table in frame widths, x right, y up, the frame's centre at 0.
    px = ((np.arange(width) + 0.5) / width - 0.5).astype(np.float32)
    py = ((height - np.arange(height) - 0.5) / width - 0.5 * height / width).astype(np.float32)
    rng = np.random.default_rng(args.seed)
    names = [f"light_{i:02d}.jpg" for i in range(len(lights))]
    band = 200
    for li, l in enumerate(lights):
        t1 = time.perf_counter()
        pos = args.dome * l
        img = np.empty((height, width, 3), np.uint8)
        for r0 in range(0, height, band):
            r1 = min(r0 + band, height)
            lin = np.zeros((r1 - r0, width, 3), np.float32)
            for by in range(2):
                rs = np.nonzero(rows[r0:r1] == by)[0]
                if len(rs) == 0:
                    continue
                r = r0 + rs
                for bx in range(3):
                    cs = np.nonzero(cols == bx)[0]
                    src = renders[(bx + 3 * by) % len(MATERIALS)][li]
                    wy, wx = fy[r][:, None, None], fx[cs][None, :, None]
                    top = src[np.ix_(y0[r], x0[cs])] * (1 - wx) + src[np.ix_(y0[r], x1[cs])] * wx
                    bot = src[np.ix_(y1[r], x0[cs])] * (1 - wx) + src[np.ix_(y1[r], x1[cs])] * wx
                    lin[rs[0]:rs[-1] + 1, cs[0]:cs[-1] + 1] = top * (1 - wy) + bot * wy
            d2 = (pos[0] - px[None, :]) ** 2 + (pos[1] - py[r0:r1, None]) ** 2 + pos[2] ** 2
            lin *= (args.dome ** 2 / d2)[..., None].astype(np.float32)
            np.clip(lin, 0.0, 1.0, out=lin)
            v = srgb_encode(lin) * np.float32(255.0)
            v += rng.normal(0.0, args.noise, v.shape).astype(np.float32)
            img[r0:r1] = np.clip(np.rint(v), 0, 255).astype(np.uint8)
        path = os.path.join(args.out, names[li])
        tmp = os.path.join(args.out, f".{names[li]}.{os.getpid()}.tmp")
        Image.fromarray(img).save(tmp, format="JPEG", quality=args.quality, subsampling="4:2:0")
        os.replace(tmp, path)
        print(f"{names[li]} ({li + 1}/{len(lights)}): {os.path.getsize(path) / 1e6:.1f} MB, "
              f"{time.perf_counter() - t1:.1f} s", flush=True)

    lp = os.path.join(args.out, "dirs.lp")
    with open(lp + ".tmp", "w") as f:
        f.write(f"{len(lights)}\n")
        for n, l in zip(names, lights):
            f.write(f"{n} {l[0]:.6f} {l[1]:.6f} {l[2]:.6f}\n")
    os.replace(lp + ".tmp", lp)
    with open(os.path.join(args.out, "capture.json"), "w") as f:
        json.dump({"size": [width, height], "period": args.period, "materials": MATERIALS, "quality": args.quality,
                   "noise": args.noise, "dome": args.dome, "seed": args.seed, "lights": lights.tolist(),
                   "btfrs": btfrs.__version__}, f, indent=1)
    total = sum(os.path.getsize(os.path.join(args.out, n)) for n in names)
    print(f"wrote {len(names)} photographs ({total / 1e9:.2f} GB) and {lp} in {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main(sys.argv[1:]))
    except KeyboardInterrupt:
        print("interrupted: no .lp written", file=sys.stderr)
        sys.exit(130)
