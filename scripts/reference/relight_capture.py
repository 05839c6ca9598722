#!/usr/bin/env python3
"""Write a small deterministic synthetic RTI capture for the relight reference fixtures.

Needs only numpy and Pillow (it does not import btfrs), so the fixtures do not
depend on the code they are meant to check.

Output folder layout:

    capture/
        capture.lp            N, then "filename lx ly lz" per line (unit vectors)
        img_00.jpg ...        8-bit sRGB-encoded JPEGs (quality 100, 4:4:4), the
                              files relight-cli fits (it only reads *.jpg)
    capture_png/
        img_00.png ...        the same JPEGs decoded to lossless 8-bit RGB PNG, so
                              a reader needs no JPEG decoder to see the exact bytes
    ground_truth/
        <name>.png            the analytic model rendered (no JPEG) at the test lights
    capture.json              the model parameters, the lights and the test lights

Conventions (relight's .lp convention, see src/sphere.cpp "lights coordinate
have y up (image y is down)"):
    x points to the image's right, y points UP the image (towards row 0),
    z points out of the surface towards the camera.  Pixel (col, row) has row 0 at
    the top of the image.

The surface: a colour-graded albedo (red grows to the right, blue grows towards
the bottom) on a height field with a round bump in the upper-left quadrant and a
ridge running down to the lower right, shaded with a Lambertian term, a small
ambient term and a Blinn-Phong gloss lobe (viewer at +z).  Values are computed
in [0, 1] and stored as round(255 * clamp(v)) with no gamma curve.
"""

import argparse
import json
import math
from pathlib import Path

import numpy as np
from PIL import Image

WIDTH = 24
HEIGHT = 18

# (label, light as given to relight before normalisation)
TEST_LIGHTS = [
    ("top", (0.0, 0.0, 1.0)),
    ("right_up", (0.5, 0.3, 0.81)),
    ("left_up", (-0.6, 0.2, 0.77)),
    ("down", (0.1, -0.7, 0.71)),
]

AMBIENT = 0.08
DIFFUSE = 0.80
SPECULAR = 0.30
SHININESS = 24.0


def light_directions():
    """37 unit directions: the zenith and rings at 72, 55, 38 and 20 degrees elevation."""
    rings = [(72.0, 6, 10.0), (55.0, 10, 5.0), (38.0, 10, 20.0), (20.0, 10, 0.0)]
    lights = [(0.0, 0.0, 1.0)]
    for elevation, count, offset in rings:
        e = math.radians(elevation)
        for k in range(count):
            a = math.radians(offset + 360.0 * k / count)
            lights.append((math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)))
    return np.array(lights, dtype=np.float64)


def surface():
    """Albedo (H, W, 3) and unit normals (H, W, 3) in the (x right, y up, z out) frame."""
    col = np.arange(WIDTH, dtype=np.float64)[None, :].repeat(HEIGHT, 0)
    row = np.arange(HEIGHT, dtype=np.float64)[:, None].repeat(WIDTH, 1)
    u = col / (WIDTH - 1)
    v = row / (HEIGHT - 1)

    albedo = np.stack([0.35 + 0.55 * u, 0.55 + 0.15 * np.sin(3.0 * u + 2.0 * v), 0.30 + 0.55 * v], axis=-1)

    # height in pixels: a bump centred in the upper-left quadrant plus a ridge
    # along the line from (11, 8) towards (22, 17) (col, row), fading in from its start.
    bump = 3.5 * np.exp(-((col - 6.0) ** 2 + (row - 5.0) ** 2) / (2 * 2.2**2))
    d = np.array([11.0, 9.0]) / math.hypot(11.0, 9.0)
    t = (col - 11.0) * d[0] + (row - 8.0) * d[1]
    dist = -(col - 11.0) * d[1] + (row - 8.0) * d[0]
    ridge = 2.2 * np.exp(-(dist**2) / (2 * 1.3**2)) * np.clip(t / 5.0, 0.0, 1.0)
    height = bump + ridge

    dh_dcol = np.gradient(height, axis=1)
    dh_drow = np.gradient(height, axis=0)
    # y points up the image, so dh/dy = -dh/drow
    n = np.stack([-dh_dcol, dh_drow, np.ones_like(height)], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    return albedo, n


def render(albedo, normals, light):
    light = np.asarray(light, dtype=np.float64)
    light = light / np.linalg.norm(light)
    half = light + np.array([0.0, 0.0, 1.0])
    half /= np.linalg.norm(half)
    ndl = np.clip(normals @ light, 0.0, None)
    ndh = np.clip(normals @ half, 0.0, None)
    spec = SPECULAR * ndh**SHININESS * (ndl > 0)
    value = albedo * (AMBIENT + DIFFUSE * ndl)[..., None] + spec[..., None]
    return np.clip(np.round(255.0 * np.clip(value, 0.0, 1.0)), 0, 255).astype(np.uint8)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("out", type=Path, help="fixture folder (tests/fixtures/relight)")
    args = parser.parse_args()

    out = args.out
    cap = out / "capture"
    cap_png = out / "capture_png"
    truth = out / "ground_truth"
    for d in (cap, cap_png, truth):
        d.mkdir(parents=True, exist_ok=True)
        for f in list(d.glob("*.jpg")) + list(d.glob("*.png")) + list(d.glob("*.lp")):
            f.unlink()

    albedo, normals = surface()
    lights = light_directions()
    names = [f"img_{i:02d}.jpg" for i in range(len(lights))]

    with open(cap / "capture.lp", "w", newline="\n") as f:
        f.write(f"{len(lights)}\n")
        for name, l in zip(names, lights):
            f.write(f"{name} {l[0]:.6f} {l[1]:.6f} {l[2]:.6f}\n")

    for name, l in zip(names, lights):
        img = Image.fromarray(render(albedo, normals, l), "RGB")
        img.save(cap / name, quality=100, subsampling=0, optimize=False)
        # decoded bytes, exactly as a libjpeg(-turbo) decoder returns them
        with Image.open(cap / name) as dec:
            dec.convert("RGB").save(cap_png / name.replace(".jpg", ".png"), optimize=True)

    for label, l in TEST_LIGHTS:
        Image.fromarray(render(albedo, normals, l), "RGB").save(truth / f"{label}.png", optimize=True)

    meta = {
        "width": WIDTH,
        "height": HEIGHT,
        "convention": "x right, y up the image (row 0 is the top), z out of the surface; lights are unit vectors",
        "model": {
            "value": "albedo*(ambient + diffuse*max(0,n.l)) + specular*max(0,n.h)^shininess (n.l>0), h=normalize(l+(0,0,1))",
            "encoding": "round(255*clamp(value,0,1)), no gamma",
            "ambient": AMBIENT,
            "diffuse": DIFFUSE,
            "specular": SPECULAR,
            "shininess": SHININESS,
        },
        "images": [{"file": n, "light": [round(float(c), 6) for c in l]} for n, l in zip(names, lights)],
        "test_lights": [{"name": label, "light": list(l)} for label, l in TEST_LIGHTS],
    }
    with open(out / "capture.json", "w", newline="\n") as f:
        json.dump(meta, f, indent=1)
        f.write("\n")


if __name__ == "__main__":
    main()
