"""Render an RTI capture whose lights are known: a glossy black sphere beside a relief.

The check of ``btfrs.calibrate``: Mitsuba 3 path-traces a scene like a museum's RTI capture (a
near-mirror black sphere standing on a grey table, a carved relief beside it, a white target in a
corner), photographed straight down under one distant light at a time, and saved as sRGB JPEGs
the way a camera would (highlights clipped, 4:2:0 chroma). The true light directions are written
beside the photographs, so what calibration finds can be compared with what was rendered.

    .venv/bin/python scripts/render_sphere_capture.py --out /tmp/sphere50 --lights 50 --size 1536 1152
    .venv/bin/python scripts/render_sphere_capture.py --out /tmp/persp --camera perspective --fov 50

Writes into ``--out``: ``light_NNN.jpg`` (one photograph per light), ``truth.lp`` (the true
directions as an ``.lp`` file: ``btfrs.load("OUT/truth.lp")`` opens the capture with them) and
``scene.json`` (the directions, the lights' irradiances, the sphere's circle in pixels for the
orthographic camera, the white target's rectangle, the camera, the seed and Mitsuba's version).

Frame: btfrs's, x along the image columns (right), y up the image, z out of the table towards the
camera; the table is z = 0. The world is 4 units wide and 3 high whatever the image size, so a
larger ``--size`` is the same scene photographed with more pixels.

The sphere is Mitsuba's ``roughplastic`` with a black base (a dielectric coating, index 1.5, GGX
roughness ``--roughness``): its highlight is the light's mirror image, a few pixels wide, and
clipped in the JPEG (the peak is ~5x white), as in real captures. Each light is ``directional``
(infinitely far: one direction for the whole scene), its irradiance varied by +-30% (seeded) so
that a white target's per-light intensity can be checked.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from typing import Any, Dict, List, Tuple

import numpy as np

WORLD_W, WORLD_H = 4.0, 3.0
SPHERE_CENTRE = (-0.95, 0.35)
SPHERE_RADIUS = 0.85
# The white target: a flat Lambertian square on the table, bottom left (x0, x1, y0, y1).
TARGET = (-1.75, -1.15, -1.35, -0.85)
TARGET_ALBEDO = 0.6
# The relief: a heightfield patch on the right of the table (x0, x1, y0, y1), heights in world units.
RELIEF = (0.1, 1.9, -1.4, 1.4)


def light_directions(n: int, seed: int, min_elevation: float = 15.0, max_elevation: float = 85.0) -> np.ndarray:
    """``n`` unit directions spread evenly over the band of elevations (a golden-angle spiral, equal
    solid angle per light, as a dome's lights are), turned and jittered by ``seed``."""
    rng = np.random.default_rng(seed)
    z0, z1 = math.sin(math.radians(min_elevation)), math.sin(math.radians(max_elevation))
    i = np.arange(n)
    z = z0 + (i + 0.5) / n * (z1 - z0) + rng.uniform(-0.3, 0.3, n) * (z1 - z0) / n
    phi = i * math.pi * (3.0 - math.sqrt(5.0)) + rng.uniform(0, 2 * math.pi) + rng.uniform(-0.2, 0.2, n)
    s = np.sqrt(1.0 - z * z)
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], -1)


def relief_height(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """An asymmetric carved relief over RELIEF, zero at its border: two domes, a ridge and a groove."""
    x0, x1, y0, y1 = RELIEF
    u, v = (x - x0) / (x1 - x0), (y - y0) / (y1 - y0)
    border = np.clip(np.minimum.reduce([u, 1 - u, v, 1 - v]) / 0.08, 0, 1)
    h = (0.16 * np.exp(-((u - 0.3) ** 2 + (v - 0.7) ** 2) / 0.02)
         + 0.10 * np.exp(-((u - 0.7) ** 2 + (v - 0.35) ** 2) / 0.008)
         + 0.06 * np.exp(-((u + 0.6 * v - 0.75) ** 2) / 0.003)
         - 0.04 * np.exp(-((v - 0.15) ** 2) / 0.001) * (u > 0.2) * (u < 0.85))
    return np.maximum(h * border, 0.0)


def write_ply(path: str, v: np.ndarray, f: np.ndarray) -> None:
    head = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(v)}\nproperty float x\n"
            f"property float y\nproperty float z\nelement face {len(f)}\n"
            "property list uchar int vertex_indices\nend_header\n").encode()
    faces = np.zeros(len(f), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    faces["n"] = 3
    faces["i"] = f
    with open(path, "wb") as out:
        out.write(head)
        out.write(np.ascontiguousarray(v, "<f4").tobytes())
        out.write(faces.tobytes())


def relief_mesh(resolution: int = 160) -> Tuple[np.ndarray, np.ndarray]:
    x0, x1, y0, y1 = RELIEF
    nx, ny = resolution, int(resolution * (y1 - y0) / (x1 - x0))
    x, y = np.meshgrid(np.linspace(x0, x1, nx), np.linspace(y0, y1, ny))
    # A hair above the table so that the two surfaces never fight where the relief is flat.
    z = relief_height(x, y) + 1e-3
    v = np.stack([x, y, z], -1).reshape(-1, 3)
    i = np.arange(nx * ny).reshape(ny, nx)
    a, b, c, d = i[:-1, :-1], i[:-1, 1:], i[1:, 1:], i[1:, :-1]
    f = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return v.astype(np.float32), f.astype(np.uint32)


def srgb_bytes(linear: np.ndarray) -> np.ndarray:
    x = np.clip(linear, 0.0, 1.0)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.round(s * 255.0).astype(np.uint8)


def sensor(mi: Any, camera: str, width: int, height: int, fov: float, spp: int) -> Dict[str, Any]:
    T = mi.ScalarTransform4f
    film = {"type": "hdrfilm", "width": width, "height": height, "rfilter": {"type": "box"}, "pixel_format": "rgb"}
    sampler = {"type": "independent", "sample_count": spp}
    if camera == "orthographic":
        # Mitsuba's orthographic sensor sees [-1, 1] across the width (and the film's aspect up
        # the height), scaled by to_world: a scale of 2 frames the 4 x 3 world.
        return {"type": "orthographic", "film": film, "sampler": sampler,
                "to_world": T().look_at(origin=[0, 0, 10], target=[0, 0, 0], up=[0, 1, 0]) @ T().scale([2, 2, 1])}
    distance = 0.5 * WORLD_W / math.tan(math.radians(0.5 * fov))
    return {"type": "perspective", "film": film, "sampler": sampler, "fov_axis": "x", "fov": fov,
            "near_clip": 0.05, "to_world": T().look_at(origin=[0, 0, distance], target=[0, 0, 0], up=[0, 1, 0])}


def scene(mi: Any, relief_ply: str, direction: np.ndarray, irradiance: float, cam: Dict[str, Any],
          roughness: float, r: float) -> Any:
    T = mi.ScalarTransform4f
    cx, cy = SPHERE_CENTRE
    tx0, tx1, ty0, ty1 = TARGET
    return mi.load_dict({
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 3},
        "sensor": cam,
        "light": {"type": "directional", "direction": (-direction).tolist(),
                  "irradiance": {"type": "rgb", "value": irradiance}},
        "table": {"type": "rectangle", "to_world": T().scale([6, 6, 1]),
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.33, 0.32, 0.30]}}},
        "target": {"type": "rectangle",
                   "to_world": T().translate([0.5 * (tx0 + tx1), 0.5 * (ty0 + ty1), 5e-4])
                   @ T().scale([0.5 * (tx1 - tx0), 0.5 * (ty1 - ty0), 1]),
                   "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": TARGET_ALBEDO}}},
        "relief": {"type": "ply", "filename": relief_ply, "face_normals": False,
                   "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.62, 0.52, 0.40]}}},
        "sphere": {"type": "sphere", "center": [cx, cy, r], "radius": r,
                   "bsdf": {"type": "roughplastic", "distribution": "ggx", "alpha": roughness, "int_ior": 1.5,
                            "diffuse_reflectance": {"type": "rgb", "value": 0.0}}},
    })


def to_pixels(x: float, y: float, width: int, height: int) -> Tuple[float, float]:
    """World (x, y) on the table to pixel coordinates of the orthographic photograph (x right, y
    down, the image's top-left corner at (0, 0))."""
    s = width / WORLD_W
    return (x + 0.5 * WORLD_W) * s, (0.5 * WORLD_H - y) * s


def main(argv: List[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, help="output folder (made if missing)")
    p.add_argument("--lights", type=int, default=50, help="number of lights (default: 50)")
    p.add_argument("--size", type=int, nargs=2, default=[256, 192], metavar=("W", "H"),
                   help="image width and height in pixels, 4:3 (default: 256 192)")
    p.add_argument("--camera", choices=["orthographic", "perspective"], default="orthographic")
    p.add_argument("--fov", type=float, default=50.0, help="horizontal field of view of the perspective camera")
    p.add_argument("--spp", type=int, default=64, help="samples per pixel (default: 64)")
    p.add_argument("--roughness", type=float, default=0.03, help="GGX alpha of the sphere (default: 0.03)")
    p.add_argument("--sphere-radius", type=float, default=SPHERE_RADIUS,
                   help=f"the sphere's radius in world units (default: {SPHERE_RADIUS}; the world is 4 x 3)")
    p.add_argument("--irradiance", type=float, default=2.0, help="mean irradiance of the lights (default: 2)")
    p.add_argument("--quality", type=int, default=90, help="JPEG quality (default: 90)")
    p.add_argument("--seed", type=int, default=1, help="seed of the lights and the renders (default: 1)")
    args = p.parse_args(argv)
    w, h = args.size
    if abs(w * WORLD_H - h * WORLD_W) > WORLD_W:
        p.error(f"--size {w} {h}: expected a 4:3 image (the scene is 4 x 3 units)")

    import mitsuba as mi  # noqa: PLC0415  (optional dependency)
    from PIL import Image  # noqa: PLC0415

    try:
        mi.set_variant("llvm_ad_rgb")
    except (ImportError, AttributeError):
        mi.set_variant("scalar_rgb")
    os.makedirs(args.out, exist_ok=True)
    dirs = light_directions(args.lights, args.seed)
    rng = np.random.default_rng(args.seed + 1)
    irr = args.irradiance * (1.0 + rng.uniform(-0.3, 0.3, args.lights))
    cam = sensor(mi, args.camera, w, h, args.fov, args.spp)
    names = [f"light_{i:03d}.jpg" for i in range(args.lights)]
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="btfrs-sphere-") as tmp:
        ply = os.path.join(tmp, "relief.ply")
        write_ply(ply, *relief_mesh())
        for i, (d, e) in enumerate(zip(dirs, irr)):
            img = np.asarray(mi.render(scene(mi, ply, d, float(e), cam, args.roughness, args.sphere_radius),
                                        seed=args.seed * 1000 + i))
            Image.fromarray(srgb_bytes(img[..., :3])).save(os.path.join(args.out, names[i]), quality=args.quality)
            print(f"\r{i + 1}/{args.lights} rendered ({time.perf_counter() - t0:.0f} s)", end="", file=sys.stderr)
    print(file=sys.stderr)
    with open(os.path.join(args.out, "truth.lp"), "w") as f:
        f.write(f"{args.lights}\n")
        for n, d in zip(names, dirs):
            f.write(f"{n} {d[0]:.9f} {d[1]:.9f} {d[2]:.9f}\n")
    (cx, cy), r = SPHERE_CENTRE, args.sphere_radius
    px, py = to_pixels(cx, cy, w, h)
    tx0, tx1, ty0, ty1 = TARGET
    c0, r0 = to_pixels(tx0, ty1, w, h)
    c1, r1 = to_pixels(tx1, ty0, w, h)
    info = {
        "renderer": f"Mitsuba {mi.__version__} ({mi.variant()})",
        "camera": args.camera, "fov_deg": args.fov if args.camera == "perspective" else None,
        "size": [h, w], "spp": args.spp, "seed": args.seed, "jpeg_quality": args.quality,
        "sphere_roughness": args.roughness,
        "files": names, "directions": dirs.tolist(), "irradiance": irr.tolist(),
        "world": {"width": WORLD_W, "height": WORLD_H, "sphere_centre": [cx, cy, r], "sphere_radius": r,
                  "target": list(TARGET), "target_albedo": TARGET_ALBEDO},
        # Pixels: x right, y down, (0, 0) the top-left corner of the image.
        "sphere_px": [px, py, r * w / WORLD_W] if args.camera == "orthographic" else None,
        # As btfrs.load's crop: (row, col, rows, cols), the target's inner part (2 pixels in).
        "target_rect": [int(math.ceil(r0)) + 2, int(math.ceil(c0)) + 2,
                        int(math.floor(r1) - math.ceil(r0)) - 4, int(math.floor(c1) - math.ceil(c0)) - 4]
        if args.camera == "orthographic" else None,
    }
    with open(os.path.join(args.out, "scene.json"), "w") as f:
        json.dump(info, f, indent=1)
    print(f"{args.lights} photographs of {w} x {h} in {time.perf_counter() - t0:.0f} s -> {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
