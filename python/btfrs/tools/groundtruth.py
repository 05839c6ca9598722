"""Ground truth by path tracing: a BTF measured from a known heightfield, and the same heightfield
rendered as geometry, both with Mitsuba 3 (``pip install mitsuba``, an optional dependency).

Why: every other check of the renderers compares them with each other (GPU vs CPU) or with closed
forms on flat Lambertian samples. This one closes the loop physically, the way a BTF is made and
used: a periodic heightfield with a diffuse albedo is *measured* like a Bonn gonioreflectometer
would (orthographic view, one directional light, radiance at each texel of the reference plane,
occlusion, masking, shadows and interreflections included), that BTF is rendered by btfrs on a
plane with the sample repeated, and the result is compared with a path trace of the repeated
heightfield itself under the same camera and light (:func:`compare`). A renderer that blends the
measured values wrongly (the cosine of the light inside the blend) lands a few percent
too dark; one that reads the sample with a wrong convention (rows mirrored) lands in the wrong
place, which the structural error sees.

The same module renders the Mitsuba scenes btfrs exports (``model.export(folder,
format="mitsuba")``, :func:`render_scene`) and checks them against btfrs's own render of the
model (:func:`check_export`): the export's claim that Mitsuba draws what btfrs draws.

Units are btfrs's: a BTF value is pi x radiance under a light of irradiance 1 (a white
Lambertian plane reads cos(theta_l)); the geometry render is multiplied by pi to match.

Coordinates: the sample is one period of the heightfield over the tile square [0, 1]^2 of the
tangent frame (x along the columns, y up the rows, row 0 at the top, as in :mod:`btfrs.btf`),
the reference plane is z = 0 and heights are in units of the period.
"""

from __future__ import annotations

import math
import os
import tempfile
import time
from typing import Any, Callable, Dict, Optional, Sequence, Tuple, Union

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .. import directions, io
from .._checks import choice, integer, real
from .._checks import seed as check_seed
from .._progress import Progress, callback
from ..btf import Btf
from ..exceptions import BtfrsError, InvalidArgumentError
from ..models import Model, model_kinds
from ..rendering import Camera, DirectionalLight, Scene, render

__all__ = ["Heightfield", "available", "measure_btf", "render_geometry", "compare", "check", "table", "figure",
           "render_scene", "check_export", "export_figure"]

# Periods of the heightfield repeated around the measured tile: enough that the view ray through a
# reference-plane texel and the shadow ray of a light at 75 degrees (tan = 3.7, times the
# amplitude) always meet geometry, never the border of the mesh.
_MARGIN = 3


def available() -> bool:
    """Whether Mitsuba 3 with an LLVM variant can be used here."""
    try:
        _mitsuba()
    except BtfrsError:
        return False
    return True


def _mitsuba() -> Any:
    try:
        import mitsuba as mi  # noqa: PLC0415  (optional dependency)
    except ImportError as e:
        raise BtfrsError("btfrs.tools.groundtruth needs Mitsuba 3: pip install mitsuba") from e
    # Batches of rays need a vectorised (llvm) variant. Another one set earlier in the process
    # (a user's scalar_rgb) is switched, as Mitsuba allows: objects made under it keep working
    # with it, new ones are llvm's.
    if mi.variant() is None or not mi.variant().startswith("llvm"):
        try:
            mi.set_variant("llvm_ad_rgb")
        except (ImportError, AttributeError) as e:
            raise BtfrsError(f"Mitsuba's llvm_ad_rgb variant is unavailable (it needs libLLVM): {e}") from e
    return mi


class Heightfield:
    """A periodic heightfield ``z = h(x, y)`` over the tile square, with a grey diffuse albedo.

    The default is a woven, deliberately asymmetric profile: ridges across y with a steep and a
    gentle flank (so mirroring y changes which flanks face a light) and a weave modulation along
    x. ``amplitude`` is in periods; the default's steepest slopes are about 35 degrees.
    """

    def __init__(self, fn: Optional[Callable[[np.ndarray, np.ndarray], np.ndarray]] = None, *,
                 amplitude: float = 0.05, albedo: float = 0.8, resolution: int = 48) -> None:
        self.amplitude = real("amplitude", amplitude, min=0.0, max=0.5)
        self.albedo = real("albedo", albedo, min=0.0, max=1.0)
        self.resolution = integer("resolution", resolution, min=4, max=512)
        self._fn = fn or _woven

    def __call__(self, x: ArrayLike, y: ArrayLike) -> NDArray[np.float64]:
        return self.amplitude * np.asarray(self._fn(np.asarray(x, float), np.asarray(y, float)), float)

    def mesh(self, tiles_x: tuple[int, int], tiles_y: tuple[int, int], *, period: float = 1.0,
             origin: Tuple[float, float] = (0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
        """Vertices ``[N, 3]`` and faces ``[F, 3]`` of the tiles ``tiles_x[0] .. tiles_x[1] - 1``
        (and the same in y), scaled by ``period`` and shifted by ``origin``."""
        n = self.resolution
        nx = (tiles_x[1] - tiles_x[0]) * n + 1
        ny = (tiles_y[1] - tiles_y[0]) * n + 1
        gx = tiles_x[0] + np.arange(nx) / n
        gy = tiles_y[0] + np.arange(ny) / n
        x, y = np.meshgrid(gx, gy)
        z = self(np.mod(x, 1.0), np.mod(y, 1.0))
        v = np.stack([origin[0] + period * x, origin[1] + period * y, period * z], -1).reshape(-1, 3)
        i = np.arange(nx * ny).reshape(ny, nx)
        a, b, c, d = i[:-1, :-1], i[:-1, 1:], i[1:, 1:], i[1:, :-1]
        f = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
        return v.astype(np.float32), f.astype(np.uint32)


def _woven(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    ridge = np.sin(2 * np.pi * y) + 0.35 * np.sin(4 * np.pi * y)
    return ridge + 0.6 * np.sin(2 * np.pi * x) * np.cos(2 * np.pi * y)


def _scene(mi: Any, hf: Heightfield, direction: ArrayLike, *, tiles_x: Tuple[int, int], tiles_y: Tuple[int, int],
           period: float = 1.0, origin: Tuple[float, float] = (0.0, 0.0), sensor: Optional[Dict[str, Any]] = None,
           max_depth: int = 4) -> Any:
    v, f = hf.mesh(tiles_x, tiles_y, period=period, origin=origin)
    # Through a PLY file rather than mi.Mesh + traverse: that API differs between Mitsuba 3
    # releases, the PLY loader does not. The file is read by load_dict and can go at once.
    with tempfile.TemporaryDirectory(prefix="btfrs-gt-") as tmp:
        path = os.path.join(tmp, "heightfield.ply")
        _write_ply(path, v, f)
        mesh = mi.load_dict({"type": "ply", "filename": path, "face_normals": True,
                             "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [hf.albedo] * 3}}})
    d = np.asarray(direction, float)
    desc = {
        "type": "scene",
        "integrator": ({"type": "path", "max_depth": max_depth, "rr_depth": max_depth + 1} if max_depth > 2
                       else {"type": "direct", "emitter_samples": 1, "bsdf_samples": 0}),
        "light": {"type": "directional", "direction": (-d).tolist(), "irradiance": {"type": "rgb", "value": 1.0}},
        "surface": mesh,
    }
    if sensor is not None:
        desc["sensor"] = sensor
    return mi.load_dict(desc)


def _write_ply(path: str, v: np.ndarray, f: np.ndarray) -> None:
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


def measure_btf(hf: Heightfield, views: ArrayLike, lights: ArrayLike, *, texels: int = 16, spp: int = 32, seed: int = 0,
                max_depth: int = 4) -> Btf:
    """Measure the BTF of ``hf``: ``[texels, texels, V, L, 3]``, each value pi x the radiance
    towards each view direction at a texel of the reference plane (``spp`` rays jittered over
    the texel's square) under a directional light of irradiance 1 from each light direction.

    The view rays are orthographic (parallel), through the reference plane z = 0, as a
    measurement at a large distance sees the sample.
    """
    mi = _mitsuba()
    import drjit as dr  # noqa: PLC0415  (optional groundtruth extra, comes with Mitsuba)

    views = np.asarray(views, float)
    lights = np.asarray(lights, float)
    n = integer("texels", texels, min=1, max=256)
    spp = integer("spp", spp, min=1, max=4096)
    rng = np.random.default_rng(check_seed(seed))
    rows, cols = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    out = np.zeros((n, n, len(views), len(lights), 3), np.float32)
    # One batch per light: every view's rays for every texel, spp each.
    per_view = n * n * spp
    vi = np.repeat(np.arange(len(views)), per_view)
    tx = np.tile(np.repeat(cols.ravel(), spp), len(views))
    ty = np.tile(np.repeat(rows.ravel(), spp), len(views))
    m = _MARGIN
    for li, l in enumerate(lights):
        scene = _scene(mi, hf, l, tiles_x=(-m, m + 1), tiles_y=(-m, m + 1), max_depth=max_depth)
        jx, jy = rng.random(len(vi)), rng.random(len(vi))
        px = (tx + jx) / n
        py = 1.0 - (ty + jy) / n
        d = views[vi]
        far = 2.0
        o = np.stack([px, py, np.zeros_like(px)], -1) + far * d
        ray = mi.RayDifferential3f(o=mi.Point3f(*[mi.Float(o[:, k].astype(np.float32)) for k in range(3)]),
                                   d=mi.Vector3f(*[mi.Float((-d[:, k]).astype(np.float32)) for k in range(3)]))
        sampler = mi.load_dict({"type": "independent"})
        sampler.seed(int(rng.integers(0, 2**31 - 1)), len(vi))
        spec, _, _ = scene.integrator().sample(scene, sampler, ray)
        rgb = np.stack([np.asarray(spec[k]) for k in range(3)], -1)
        dr.eval()
        vals = rgb.reshape(len(views), n, n, spp, 3).mean(axis=3) * math.pi
        out[:, :, :, li, :] = np.transpose(vals, (1, 2, 0, 3))
    if not np.isfinite(out).all():
        raise BtfrsError("measure_btf: the path tracer returned non-finite values")
    return Btf(out, views, lights)


def render_geometry(hf: Heightfield, camera: Camera, light_direction: ArrayLike, *,
                    size: Union[int, Tuple[int, int]] = (256, 256), plane_size: float = 2.0,
                    uv_scale: int = 8, spp: int = 64, seed: int = 0, max_depth: int = 4) -> np.ndarray:
    """Path trace the heightfield repeated ``uv_scale`` x ``uv_scale`` times over btfrs's
    ``Scene.plane(plane_size)`` (uv (0, 0) at (-plane_size/2, -plane_size/2)), with margins, seen
    by ``camera`` (a :class:`btfrs.Camera`) under a directional light of irradiance 1;
    ``[height, width, 3]`` float32 in btfrs's unit (pi x radiance)."""
    mi = _mitsuba()
    h, w = (size, size) if isinstance(size, int) else size
    k = integer("uv_scale", uv_scale, min=1, max=256)
    period = plane_size / k
    half = 0.5 * plane_size
    sensor = {
        "type": "perspective",
        "fov_axis": "y",
        "fov": float(camera.fov_deg),
        "near_clip": 0.01,
        "to_world": mi.ScalarTransform4f().look_at(origin=camera.eye, target=camera.target, up=camera.up),
        "sampler": {"type": "independent", "sample_count": integer("spp", spp, min=1, max=65536)},
        "film": {"type": "hdrfilm", "width": w, "height": h, "rfilter": {"type": "box"}, "pixel_format": "rgb"},
    }
    m = _MARGIN
    scene = _scene(mi, hf, light_direction, tiles_x=(-m, k + m), tiles_y=(-m, k + m), period=period,
                   origin=(-half, -half), sensor=sensor, max_depth=max_depth)
    img = np.asarray(mi.render(scene, seed=check_seed(seed)), dtype=np.float32)[..., :3]
    return img * np.float32(math.pi)


def _blur(img: np.ndarray, sigma: float) -> np.ndarray:
    r = int(3 * sigma + 1)
    x = np.arange(-r, r + 1)
    k = np.exp(-0.5 * (x / sigma) ** 2)
    k /= k.sum()
    out = img
    for axis in (0, 1):
        out = np.apply_along_axis(lambda s: np.convolve(s, k, mode="same"), axis, out)
    return out


def compare(rendered: np.ndarray, reference: np.ndarray, *, sigma: float = 1.5, border: int = 4) -> Dict[str, Any]:
    """Brightness ratio (mean of ``rendered`` over mean of ``reference``) and structural error
    (RMS of the difference of both images blurred with a Gaussian of ``sigma`` pixels, over the
    reference's RMS, so Monte Carlo noise and texel size matter little), over the pixels where
    both see the surface, ``border`` pixels in from the image edges and from the edges of that
    common region (the blur is normalised by the blurred mask, so pixels outside it, which the
    path trace may show and btfrs leaves 0, do not leak in)."""
    a = np.asarray(rendered, np.float64).mean(-1)
    b = np.asarray(reference, np.float64).mean(-1)
    if a.shape != b.shape:
        raise InvalidArgumentError(f"rendered: expected the reference's shape {b.shape}, got {a.shape}")
    sigma = real("sigma", sigma, min=0.1, max=64.0)
    border = integer("border", border, min=0, max=min(a.shape) // 4)
    mask = ((a > 0) & (b > 0)).astype(np.float64)
    wm = _blur(mask, sigma)
    with np.errstate(invalid="ignore", divide="ignore"):
        ab, bb = _blur(a * mask, sigma) / wm, _blur(b * mask, sigma) / wm
    inner = mask > 0
    for _ in range(border):  # erode the common region by `border` pixels
        e = inner.copy()
        e[1:] &= inner[:-1]
        e[:-1] &= inner[1:]
        e[:, 1:] &= inner[:, :-1]
        e[:, :-1] &= inner[:, 1:]
        inner = e
    inner[:border], inner[-border or len(inner):] = False, False
    inner[:, :border], inner[:, -border or inner.shape[1]:] = False, False
    if inner.sum() < 16:
        raise InvalidArgumentError("rendered: the images share almost no surface pixels")
    ra, rb = ab[inner], bb[inner]
    return {
        "brightness": float(a[inner].mean() / b[inner].mean()),
        "structure": float(np.sqrt(np.mean((ra - rb) ** 2)) / np.sqrt(np.mean(rb**2))),
        "pixels": int(inner.sum()),
    }


def check(*, texels: int = 8, size: int = 160, measure_spp: int = 16, render_spp: int = 64,
          lights: Sequence[Tuple[float, float]] = ((40.0, 60.0), (55.0, 100.0)), uv_scale: int = 6, backend: str = "cpu", seed: int = 0,
          progress: Progress = None) -> Dict[str, Any]:
    """The whole ground-truth check: measure the default :class:`Heightfield`'s BTF on the Bonn
    directions (81 x 81, :func:`btfrs.directions.ubo81`), render it on ``Scene.plane(2)`` with
    ``uv_scale`` repetitions under directional lights between the measured rings and azimuths
    (``lights``: (theta, phi) in degrees), path trace the repeated heightfield under the same
    camera and light, and :func:`compare` them, for the nearest and bilinear filters and, as the
    control that must score worse, the sample with its rows mirrored (a wrong y convention).

    Returns ``{"rows": [{"light", "case", "filter", "brightness", "structure", "pixels"}],
    "images": {name: image}, "seconds": {...}}`` and the settings.
    """
    seed = check_seed(seed)
    size = integer("size", size, min=32, max=2048)
    pairs = [(real("lights", t, min=0.0, max=85.0), real("lights", p)) for t, p in lights]
    report = callback(progress, "ground truth")
    total = 1 + len(pairs)
    if report:
        report(0, total)
    t0 = time.perf_counter()
    hf = Heightfield()
    d = directions.ubo81()
    btf = measure_btf(hf, d, d, texels=texels, spp=measure_spp, seed=seed)
    mirrored = Btf(np.ascontiguousarray(btf.data[::-1]), btf.views, btf.lights)
    seconds = {"measure": time.perf_counter() - t0, "path trace": 0.0, "btfrs renders": 0.0}
    if report:
        report(1, total)
    # Seen from the side and above, the rows running across the image: mirroring y then moves
    # every flank, which the structural error sees.
    cam = Camera.look_at([0.0, -2.0, 2.4], [0.0, 0.0, 0.0], 40.0, up=[0.0, 0.0, 1.0])
    scene = Scene.plane(2.0)
    rows, images = [], {}
    for n, (th, ph) in enumerate(pairs):
        light = directions.from_theta_phi(th, ph, degrees=True).reshape(3)
        t = time.perf_counter()
        ref = render_geometry(hf, cam, light, size=(size, size), plane_size=2.0, uv_scale=uv_scale,
                              spp=render_spp, seed=seed + 1 + n)
        seconds["path trace"] += time.perf_counter() - t
        label = f"theta {th:g}, phi {ph:g}"
        images[f"{label}: path traced"] = ref
        t = time.perf_counter()
        for case, b in (("measured", btf), ("mirrored y", mirrored)):
            for filt in ("nearest", "bilinear"):
                img = render(b, scene, cam, [DirectionalLight([float(x) for x in light])], size=(size, size), uv_scale=uv_scale,
                             filter=filt, backend=backend)
                rows.append(dict(light=label, case=case, filter=filt, **compare(img, ref)))
                images[f"{label}: {case}, {filt}"] = img
        seconds["btfrs renders"] += time.perf_counter() - t
        if report:
            report(2 + n, total)
    return {"rows": rows, "images": images, "texels": texels, "size": size, "uv_scale": uv_scale,
            "measure_spp": measure_spp, "render_spp": render_spp, "backend": backend, "seed": seed,
            "seconds": seconds}


def table(result: Dict[str, Any]) -> str:
    """The rows of :func:`check` as a Markdown table."""
    out = ["| light | sample | filter | brightness | structural error |", "|---|---|---|---|---|"]
    for r in result["rows"]:
        out.append(f"| {r['light']} | {r['case']} | {r['filter']} | {r['brightness']:.4f} | {r['structure']:.4f} |")
    return "\n".join(out)


def figure(result: Dict[str, Any], path: Union[str, "os.PathLike[str]"]) -> str:
    """A PNG of :func:`check`'s images: per light, the path trace, btfrs's bilinear render of the
    measured sample, the same of the mirrored one, and both differences to the path trace (the
    grey of zero difference at mid scale); the structural errors in the titles. Written
    atomically (matplotlib, ``Agg``)."""
    import matplotlib  # noqa: PLC0415  (heavy: only for the figure)

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt  # noqa: PLC0415  (after use("Agg"); heavy)

    lights = list(dict.fromkeys(r["light"] for r in result["rows"]))
    err = {(r["light"], r["case"], r["filter"]): r for r in result["rows"]}
    fig, axes = plt.subplots(len(lights), 5, figsize=(15, 3.3 * len(lights)), squeeze=False)
    for i, light in enumerate(lights):
        ref = result["images"][f"{light}: path traced"]
        ok = result["images"][f"{light}: measured, bilinear"]
        bad = result["images"][f"{light}: mirrored y, bilinear"]
        seen = (ok.mean(-1) > 0)[..., None]
        panels = [
            (ref, f"{light}\npath-traced heightfield"),
            (ok, f"btfrs, measured sample\nbrightness {err[(light, 'measured', 'bilinear')]['brightness']:.3f}"),
            (bad, "btfrs, rows mirrored (wrong)"),
            (0.5 + 2.0 * (ok - ref) * seen,
             f"measured - path trace (x2)\nstructural error {err[(light, 'measured', 'bilinear')]['structure']:.3f}"),
            (0.5 + 2.0 * (bad - ref) * seen,
             f"mirrored - path trace (x2)\nstructural error {err[(light, 'mirrored y', 'bilinear')]['structure']:.3f}"),
        ]
        for ax, (img, title) in zip(axes[i], panels):
            ax.imshow(np.clip(img, 0.0, 1.0), interpolation="nearest")
            ax.set_title(title, fontsize=9)
            ax.axis("off")
    fig.tight_layout()
    with io.atomic_write(path, "wb") as f:
        fig.savefig(f, format="png", dpi=90)
    plt.close(fig)
    return str(path)


# --- exported scenes ---------------------------------------------------------------------------


def _vec(v: ArrayLike) -> str:
    return ", ".join(repr(float(x)) for x in np.asarray(v, float).reshape(3))


def render_scene(path: Union[str, "os.PathLike[str]"], camera: Camera, light_direction: ArrayLike, *,
                 size: Union[int, Tuple[int, int]] = (256, 256), spp: int = 256, seed: int = 0,
                 filter: str = "bilinear", uv_scale: float = 1.0) -> np.ndarray:
    """Render the Mitsuba scene btfrs wrote at ``path`` (its folder or ``scene.xml``) with
    Mitsuba 3, through ``camera`` (a :class:`btfrs.Camera`) under a directional light of
    irradiance 1 from ``light_direction`` (towards the light, as btfrs's lights); ``filter`` is
    the maps' lookup (``"nearest"`` or ``"bilinear"``). ``[height, width, 3]`` float32 in
    btfrs's unit (pi x radiance)."""
    mi = _mitsuba()
    p = os.fspath(path)
    if os.path.isdir(p):
        p = os.path.join(p, "scene.xml")
    if not os.path.isfile(p):
        raise InvalidArgumentError(f"path: {p} does not exist; expected a scene written by model.export(..., format=\"mitsuba\")")
    h, w = (size, size) if isinstance(size, int) else size
    d = np.asarray(light_direction, float).reshape(3)
    if not (np.isfinite(d).all() and d[2] > 0):
        raise InvalidArgumentError(f"light_direction: expected a direction above the surface (z > 0), got {d.tolist()}")
    d = d / np.linalg.norm(d)
    scene = mi.load_file(p, spp=integer("spp", spp, min=1, max=65536), width=integer("width", w, min=1, max=8192),
                         height=integer("height", h, min=1, max=8192), fov=repr(float(camera.fov_deg)),
                         origin=_vec(camera.eye), target=_vec(camera.target), up=_vec(camera.up),
                         light_direction=_vec(-d), filter=choice("filter", filter, ("nearest", "bilinear")),
                         uv_scale=repr(real("uv_scale", uv_scale, min=1e-6)))
    img = np.asarray(mi.render(scene, seed=check_seed(seed)), dtype=np.float32)[..., :3]
    return img * np.float32(math.pi)


def _psnr(a: np.ndarray, b: np.ndarray) -> Dict[str, Any]:
    """Brightness ratio and PSNR (peak: the reference's largest value) of ``a`` against ``b``
    over the pixels where both see the surface."""
    x, y = np.asarray(a, np.float64).mean(-1), np.asarray(b, np.float64).mean(-1)
    seen = (x > 0) & (y > 0)
    if seen.sum() < 16:
        raise InvalidArgumentError("rendered: the images share almost no surface pixels")
    mse = float(np.mean((x[seen] - y[seen]) ** 2))
    return {"brightness": float(x[seen].mean() / y[seen].mean()),
            "psnr": float(10 * np.log10(float(y[seen].max()) ** 2 / max(mse, 1e-30))),
            "pixels": int(seen.sum())}


def check_export(model: Any, *, lights: Sequence[Tuple[float, float]] = ((40.0, 60.0), (65.0, 200.0)),
                 size: int = 96, supersample: int = 4, spp: int = 512, seed: int = 0,
                 backend: str = "cpu") -> Dict[str, Any]:
    """Export ``model`` (one whose ``exports`` include ``"mitsuba"``) as a Mitsuba scene, render it with Mitsuba 3 and render
    the model with btfrs on ``Scene.plane(2)`` under the same camera and directional lights
    (``lights``: (theta, phi) in degrees), and compare them: brightness ratio and PSNR per
    light, and the same for the control, the model with its rows mirrored (a wrong texture
    orientation), which must score far worse.

    Both look the maps up by nearest texel. Mitsuba averages ``spp`` samples over each pixel
    (a box filter); btfrs renders ``supersample`` x ``supersample`` pixel centres per pixel and
    averages them, so both estimate the same pixel integral and the comparison does not hinge
    on which texel a pixel's centre falls in.
    """
    if not isinstance(model, Model) or "mitsuba" not in model.exports:
        can = [k for k, info in model_kinds().items() if "mitsuba" in info["exports"]]
        raise InvalidArgumentError(f"model: expected a model that can be written as a Mitsuba scene ({', '.join(can)}), "
                                   f"got {getattr(model, 'kind', type(model).__name__)!r}")
    size = integer("size", size, min=16, max=2048)
    k = integer("supersample", supersample, min=1, max=16)
    seed = check_seed(seed)
    cam = Camera.look_at([0.0, -2.0, 2.4], [0.0, 0.0, 0.0], 40.0, up=[0.0, 0.0, 1.0])
    plane = Scene.plane(2.0)
    mirrored = Model.from_arrays({n: np.ascontiguousarray(a[::-1]) for n, a in model.arrays.items()}, kind=model.kind)
    rows, images = [], {}
    t = {"mitsuba": 0.0, "btfrs": 0.0}
    with tempfile.TemporaryDirectory(prefix="btfrs-mitsuba-") as tmp:
        model.export(tmp, format="mitsuba", force=True)
        for n, (th, ph) in enumerate(lights):
            light = directions.from_theta_phi(real("lights", th, min=0.0, max=85.0), real("lights", ph),
                                              degrees=True).reshape(3)
            label = f"theta {th:g}, phi {ph:g}"
            t0 = time.perf_counter()
            ref = render_scene(tmp, cam, light, size=size, spp=spp, seed=seed + n, filter="nearest")
            t1 = time.perf_counter()
            ours = []
            for m in (model, mirrored):
                big = render(m, plane, cam, [DirectionalLight([float(x) for x in light])], size=(size * k, size * k),
                             filter="nearest", backend=backend)
                ours.append(big.reshape(size, k, size, k, 3).mean(axis=(1, 3)))
            t["mitsuba"] += t1 - t0
            t["btfrs"] += time.perf_counter() - t1
            rows.append(dict(light=label, case="exported", **_psnr(ours[0], ref)))
            rows.append(dict(light=label, case="rows mirrored", **_psnr(ours[1], ref)))
            images[f"{label}: mitsuba"], images[f"{label}: btfrs"] = ref, ours[0]
    return {"rows": rows, "images": images, "size": size, "supersample": k, "spp": spp, "seconds": t,
            "backend": backend, "seed": seed}


def export_figure(result: Dict[str, Any], maps: Dict[str, np.ndarray], path: Union[str, "os.PathLike[str]"],
                  capture: Optional[np.ndarray] = None) -> str:
    """A PNG of :func:`check_export`: the capture's image under the first light (if given), the
    model's maps (``model.arrays``: diffuse, specular, roughness, normal), and per light btfrs's
    render, Mitsuba's render of the exported scene and their difference. Written atomically."""
    import matplotlib  # noqa: PLC0415  (heavy: only for the figure)

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt  # noqa: PLC0415  (after use("Agg"); heavy)

    lights = list(dict.fromkeys(r["light"] for r in result["rows"]))
    score = {(r["light"], r["case"]): r for r in result["rows"]}
    top = ([(capture, "the capture (one of its images)")] if capture is not None else []) + [
        (maps["diffuse"], "diffuse colour"), (maps["specular"], "specular colour"),
        (np.repeat(maps["roughness"][..., None], 3, -1), "GGX roughness (alpha)"),
        (0.5 * maps["normal"] + 0.5, "normal (x, y, z as RGB)")]
    cols = max(len(top), 3)
    fig, axes = plt.subplots(1 + len(lights), cols, figsize=(3 * cols, 3.2 * (1 + len(lights))), squeeze=False)
    for ax in axes.ravel():
        ax.axis("off")
    for ax, (img, title) in zip(axes[0], top):
        ax.imshow(np.clip(img, 0.0, 1.0), interpolation="nearest")
        ax.set_title(title, fontsize=9)
    for i, light in enumerate(lights, 1):
        ours, ref = result["images"][f"{light}: btfrs"], result["images"][f"{light}: mitsuba"]
        r = score[(light, "exported")]
        panels = [(ours, f"btfrs render, {light}"),
                  (ref, f"Mitsuba 3, exported scene\nbrightness {r['brightness']:.4f}, {r['psnr']:.1f} dB"),
                  (0.5 + 4.0 * (ours - ref), "btfrs - Mitsuba (x4)")]
        for ax, (img, title) in zip(axes[i], panels):
            ax.imshow(np.clip(img, 0.0, 1.0), interpolation="nearest")
            ax.set_title(title, fontsize=9)
    fig.tight_layout()
    with io.atomic_write(path, "wb") as f:
        fig.savefig(f, format="png", dpi=90)
    plt.close(fig)
    return str(path)
