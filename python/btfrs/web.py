"""The browser viewer: a fitted model written as a folder any web server can host (or as one
self-contained HTML file), drawn with WebGPU by the project's own WGSL.

The folder holds the viewer (``index.html`` and its ES modules, no build step) and ``model/``:
``manifest.json``, the shader assembled exactly as the native renderer assembles it
(``common.wgsl``, the model's generated ``Params`` struct, the model's file), and the buffers
the native renderer uploads, as little-endian binary files (parameters, store, measured
directions and their candidate tables, the optional 3D texture), with the scenes' meshes. Every
layout the page must agree on with the shader (uniform fields, bindings, vertex attributes) is
in the manifest, generated from the Rust structs.

:func:`save_web` writes it (``model.save_web(folder)`` is the same); ``btfrs export FILE --web OUT``
and ``btfrs view FILE`` use it.

A single-view model (an RTI capture's) is also shown as RTI viewers show it: straight on,
orthographic, filling the window, with bilinear magnification and RTIViewer's rendering modes
(:data:`RTI_MODES`, defined in :func:`rti_block`). With ``tiles=True`` the model is written in
relight's or NeuralRTI's tiled layout (Deep Zoom pyramids of its planes, as OpenLIME reads them)
and the page fetches the tiles it needs, coarsest level first: the manifest then describes the
store of a *window* of the image (:func:`btfrs._native.web_window`), which the page fills from
the tiles' bytes.
"""
from __future__ import annotations

import base64
import json
import os
import shutil
import tempfile
from typing import Any, Dict, List, Optional, Tuple

import numpy as np
from numpy.typing import ArrayLike

from . import _native
from ._checks import PathLike
from .environment import Environment
from .exceptions import InvalidArgumentError
from .models import Model, _slot_index, register_web_writer
from .rendering import Scene, TileMap, _surface as _rendering_surface, _uv_scale

#: The viewer's own files, shipped in the package.
VIEWER_DIR = os.path.join(os.path.dirname(__file__), "viewer")
#: The scenes the viewer can show: name -> how the renderer builds it.
SCENES = {"plane": ("plane", (2.0,)), "sphere": ("sphere", (1.0, 64, 32)), "cylinder": ("cylinder", (0.7, 2.0, 64))}
#: Where the page's camera starts: above the plane, looking down at it obliquely.
DEFAULT_CAMERA: Dict[str, Any] = {"eye": [0.0, -1.6, 2.4], "target": [0.0, 0.0, 0.0], "up": [0.0, 0.0, 1.0], "fov": 40.0,
                  "near": 0.01, "far": 100.0}
#: The environment the page offers (its "Sky light" switch): btfrs's built-in sky, as the
#: importance-sampled directional lights ``btfrs.render(..., environment=sky,
#: lighting="sampled", samples=SKY_SAMPLES, seed=0)`` draws.
SKY_SAMPLES = 64
#: The light the page starts with (towards the light) and its irradiance.
DEFAULT_LIGHT: Dict[str, Any] = {"direction": [0.35, 0.45, 0.82], "intensity": [1.0, 1.0, 1.0]}
#: The version of the manifest (and of the viewer that reads it).
WEB_VERSION = 2
#: The 2D view's rendering modes (RTIViewer's, Malzbender et al. 2001 section 5): the model as it
#: is; diffuse gain; specular enhancement; the normal map.
RTI_MODES = ("default", "diffuse_gain", "specular", "normals")
#: The modes' parameters as the page starts: diffuse gain's ``gain``, specular enhancement's
#: ``kd``, ``ks`` and ``exponent``.
RTI_DEFAULTS: Dict[str, float] = {"gain": 2.0, "kd": 0.6, "ks": 0.5, "exponent": 40.0}
#: Luminance of linear RGB (Rec. 709), the channel mix whose polynomial gives the normal.
LUMINANCE = (0.2126, 0.7152, 0.0722)
#: Texels a tiled page's window holds (its store is laid out for this many).
WINDOW_CAPACITY = 1536 * 1536
#: The probes a tiled page's window layout is found from: (height, width, seed).
PROBES = ((4, 4, 1), (4, 4, 2), (4, 8, 3))


def rti_fit_lights() -> np.ndarray:
    """The 17 light directions over which the enhancement modes fit each texel's biquadratic
    (PTM) polynomial: the normal, and rings of 8 at 30 and 60 degrees from it (the second turned
    by 22.5 degrees), a well-conditioned set over the light disc (float64 ``[17, 3]``)."""
    out = [[0.0, 0.0, 1.0]]
    for theta, turn in ((30.0, 0.0), (60.0, 22.5)):
        t = np.radians(theta)
        for k in range(8):
            p = np.radians(45.0 * k + turn)
            out.append([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])
    return np.asarray(out, dtype=np.float64)


def ptm_basis(lx: Any, ly: Any) -> np.ndarray:
    """The PTM basis at light (lx, ly): ``(lx^2, ly^2, lx ly, lx, ly, 1)`` (Malzbender et al.
    2001, eq. 2; the last axis)."""
    x, y = np.asarray(lx, dtype=np.float64), np.asarray(ly, dtype=np.float64)
    return np.stack([x * x, y * y, x * y, x, y, np.ones_like(x)], axis=-1)


def rti_block() -> Dict[str, Any]:
    """The manifest's ``rti`` block: the fit lights, the ``6 x K`` least-squares matrix taking a
    texel's values at them to its polynomial's coefficients, the luminance weights, the modes and
    their starting parameters.

    Per texel, the page evaluates the model at the fit lights and fits, per channel, the
    biquadratic ``P(lx, ly)`` of :func:`ptm_basis` (exact for a PTM, whose values are that
    polynomial; a PTM-like view of any other model). The luminance polynomial's stationary point
    ``(u0, v0)`` (its maximum when it is concave; ``(0, 0)`` when the quadratic part is
    singular), clamped to the unit disc, is RTIViewer's normal ``n = (u0, v0, sqrt(1 - u0^2 -
    v0^2))``. At light ``l``:

    * ``default``: the model's value ``f(l)``;
    * ``diffuse_gain``: ``f(l) + P'(l) - P(l)``, ``P'`` the polynomial with its quadratic terms
      times ``gain`` and its linear and constant terms changed so that its value and slope at
      ``(u0, v0)`` stay (Malzbender et al. section 5.1): the curvature about the maximum grows;
    * ``specular``: ``kd f(l) + ks (n . h)^exponent`` with ``h`` the half vector of ``l`` and the
      view ``(0, 0, 1)`` (section 5.2, a white highlight of peak ``ks``);
    * ``normals``: ``(n + 1) / 2`` shown as it is (no exposure, no sRGB curve).

    Every value is taken at the texels and bilinearly interpolated between them."""
    lights = rti_fit_lights()
    a = ptm_basis(lights[:, 0], lights[:, 1])
    m = np.linalg.pinv(a)
    return {"fit_lights": lights.tolist(), "fit_matrix": m.tolist(), "luminance": list(LUMINANCE),
            "modes": list(RTI_MODES), "defaults": dict(RTI_DEFAULTS)}


def _scene_buffers(name: str) -> Tuple[bytes, np.ndarray]:
    make, args = SCENES[name]
    scene = getattr(Scene, make)(*args)
    vertices, indices = scene.web_buffers()
    return bytes(vertices), np.ascontiguousarray(indices, dtype="<u4")


def bundle(model: Model, *, renderer: Optional[str] = None, name: Optional[str] = None,
           coords: Optional[ArrayLike] = None, tiles: Any = None, layout: Optional[ArrayLike] = None,
           tile_map: Optional[TileMap] = None, uv_scale: Any = 1.0) -> Dict[str, Any]:
    """The manifest and the binary files of ``model`` for the viewer: ``(manifest, {file name:
    bytes})`` as one dict ``{"manifest": ..., "files": ...}``. ``coords``, ``tiles`` with
    ``layout``, ``tile_map`` and ``uv_scale`` as for :func:`btfrs.render`."""
    if not isinstance(model, Model):
        raise InvalidArgumentError(f"model: expected a fitted btfrs model, got {type(model).__name__}")
    method = renderer or "default"
    uvs = list(_uv_scale(uv_scale))
    surface = _surface(model, coords, tiles, layout, tile_map)
    w = _native.web_model(model._m, method)
    files: Dict[str, bytes] = {
        "shader.wgsl": w["shader"].encode(),
        "params.bin": np.ascontiguousarray(w["params"], dtype="<u4").tobytes(),
        "store.bin": np.ascontiguousarray(w["store"], dtype="<u4").tobytes(),
        "dirs.bin": np.ascontiguousarray(w["dirs"], dtype="<f4").tobytes(),
        "tables.bin": np.ascontiguousarray(w["tables"], dtype="<u4").tobytes(),
    }
    volume = None
    if w["volume"] is not None:
        size, texels = w["volume"]
        files["volume.bin"] = bytes(texels)
        volume = {"file": "volume.bin", "size": list(size), "format": "rgba8unorm"}
    if surface is not None:
        files["map.bin"] = np.ascontiguousarray(surface["words"], dtype="<u4").tobytes()
        surface = {"file": "map.bin", "kind": surface["kind"], "map_size": list(surface["map_size"]),
                   "tiles": list(surface["tiles"]), "tile_atlas": list(surface["tile_atlas"])}
    manifest_views = _views(model)
    scenes = {}
    for scene in SCENES:
        vertices, indices = _scene_buffers(scene)
        files[f"{scene}.vertices.bin"] = vertices
        files[f"{scene}.indices.bin"] = indices.tobytes()
        scenes[scene] = {"vertices": f"{scene}.vertices.bin", "indices": f"{scene}.indices.bin",
                         "index_count": int(indices.size)}
    manifest = {
        "format": "btfrs-web",
        "version": WEB_VERSION,
        "model": {"kind": model.kind, "name": name or model.kind, "height": model.height, "width": model.width,
                  "views": manifest_views,
                  "nbytes": int(model.nbytes), "renderer": method},
        "layout": json.loads(_native.web_layout()),
        "files": {"shader": "shader.wgsl", "params": "params.bin", "store": "store.bin", "dirs": "dirs.bin",
                  "tables": "tables.bin"},
        "volume": volume,
        "map": surface,
        "uv_scale": uvs,
        "chunk_len": int(w["chunk_len"]),
        "scenes": scenes,
        "camera": DEFAULT_CAMERA,
        "light": DEFAULT_LIGHT,
        "environment": _sky(),
        "exposure": 1.0,
        "display": "linear value x exposure, clamped to [0, 1], sRGB-encoded, 8 bits",
        "rti": rti_block() if manifest_views == 1 and surface is None else None,
        "tiles": None,
    }
    return {"manifest": manifest, "files": files}


def tiled_format(model: Model) -> str:
    """The tiled layout ``model`` is written in: relight's (PTM, HSH, RBF, bilinear) or
    NeuralRTI's (the neural model in its form); an error naming ``tiled`` for another model."""
    for fmt in ("relight", "neuralrti"):
        if fmt in model.exports:
            return fmt
    raise InvalidArgumentError(f"tiled: the {model.kind} model has no tiled web layout (relight's PTM, HSH, RBF and "
                               "bilinear models and NeuralRTI's neural model have one)")


def bundle_tiled(folder: PathLike, *, name: Optional[str] = None,
                 capacity: int = WINDOW_CAPACITY) -> Dict[str, Any]:
    """The manifest and the files of a page drawing the tiled relight or NeuralRTI folder
    ``folder`` (its ``info.json`` and Deep Zoom pyramids, as :meth:`Model.export` writes them
    with ``tiled=True``): the shader and parameters of a window model of at most ``capacity``
    texels, the store words every window shares, and where each texel's bytes come from in the
    tiles. Found generically from models the folder's ``info.json`` makes from random planes
    (:data:`PROBES`)."""
    path = os.fspath(folder)
    # The index read and checked by btfrs's reader of untrusted files (regular file, size cap,
    # declared sizes in range), as btfrs.load reads it.
    images, nplanes, width, height, kind_of_index, tile_size, levels = _native.plane_images(path)
    probes = []
    for h, w, seed in PROBES:
        q = np.random.default_rng(seed).integers(0, 256, (h, w, nplanes), dtype=np.uint8)
        probes.append((_native.model_with_planes(path, q), q))
    kind = str(probes[0][0].kind)
    cap = int(min(capacity, width * height))
    win = _native.web_window(probes, cap)
    constants = [(int(o), np.ascontiguousarray(words, dtype="<u4")) for o, words in win["constants"]]
    texels: List[Dict[str, Any]] = [{"offset": int(o), "bytes": int(r), "from": [int(x) for x in frm]}
                                    for o, r, frm in win["texels"]]
    files: Dict[str, bytes] = {
        "shader.wgsl": win["shader"].encode(),
        "params.bin": np.ascontiguousarray(win["params"], dtype="<u4").tobytes(),
        "store.bin": b"".join(w.tobytes() for _, w in constants),
        "dirs.bin": np.ascontiguousarray(win["dirs"], dtype="<f4").tobytes(),
        "tables.bin": np.ascontiguousarray(win["tables"], dtype="<u4").tobytes(),
    }
    nbytes = width * height * sum(int(t["bytes"]) for t in texels) + 4 * sum(len(w) for _, w in constants)
    manifest = {
        "format": "btfrs-web",
        "version": WEB_VERSION,
        "model": {"kind": kind, "name": name or kind, "height": height, "width": width, "views": 1,
                  "nbytes": int(nbytes), "renderer": "default"},
        "layout": json.loads(_native.web_layout()),
        "files": {"shader": "shader.wgsl", "params": "params.bin", "store": "store.bin", "dirs": "dirs.bin",
                  "tables": "tables.bin"},
        "volume": None,
        "map": None,
        "uv_scale": [1.0, 1.0],
        "chunk_len": int(win["store_words"]),
        "scenes": {},
        "camera": DEFAULT_CAMERA,
        "light": DEFAULT_LIGHT,
        "environment": None,
        "exposure": 1.0,
        "display": "linear value x exposure, clamped to [0, 1], sRGB-encoded, 8 bits",
        "rti": rti_block(),
        "tiles": {
            "layout": "deepzoom",
            "index": "info.json",
            "type": kind_of_index or None,
            "images": [f"{n}.dzi" for n in images],
            "planes": int(nplanes),
            "tile_size": int(tile_size),
            "levels": int(levels),
            "capacity": int(win["capacity"]),
            "store_words": int(win["store_words"]),
            "constants": [{"offset": o, "words": int(len(w))} for o, w in constants],
            "texels": texels,
        },
    }
    return {"manifest": manifest, "files": files}


def _surface(model: Model, coords: Any, tiles: Any, layout: Any, tile_map: Optional[TileMap]) -> Optional[Dict[str, Any]]:
    """The map buffer and ``Globals`` fields of the texture over the surface (as
    :func:`btfrs.render` takes it); None for the sample itself."""
    c, tm = _rendering_surface(model, coords, tiles, layout, tile_map)
    if c is None and tm is None:
        return None
    out = _native.web_map(model._m, c, tm)
    out["kind"] = "coords" if c is not None else "tiles"
    return out


def _sky() -> Dict[str, Any]:
    """The built-in sky as the page's light list (see :data:`SKY_SAMPLES`)."""
    lights = [light._native() for light in Environment.sky().lights(SKY_SAMPLES, seed=0)]
    return {"name": "sky", "samples": SKY_SAMPLES, "seed": 0,
            "lights": [{"direction": d, "intensity": i} for _, d, i in lights]}


def _views(model: Model) -> int:
    """How the page moves the camera: the model's view slots where it has them, else 1 for a
    model whose appearance does not change with the view (a single-view capture's: the page pans
    over it) and 2 for one that does (the page orbits), found by evaluating it from two views."""
    views = getattr(model, "views", None)
    if views is not None:
        return int(len(views))
    light = [0.3, -0.2, 0.93]
    a = model.evaluate([0.0, 0.0, 1.0], light)
    b = model.evaluate([0.5, 0.3, 0.81], light)
    return 2 if float(np.abs(a - b).max()) > 1e-6 * max(float(np.abs(a).max()), 1e-12) else 1


def _viewer_files() -> Dict[str, bytes]:
    out = {}
    for root, _, names in os.walk(VIEWER_DIR):
        for n in names:
            if n.endswith((".html", ".js", ".css")):
                p = os.path.join(root, n)
                with open(p, "rb") as f:
                    out[os.path.relpath(p, VIEWER_DIR)] = f.read()
    if "index.html" not in out:
        raise InvalidArgumentError(f"the viewer's files are missing from {VIEWER_DIR} (a broken installation)")
    return out


def single_file_html(b: Dict[str, Any]) -> str:
    """One HTML file holding the viewer and the model (base64 in a JSON script element), which
    opens from disk (``file://``) with no server."""
    viewer = _viewer_files()
    data = {"manifest": b["manifest"], "files": {k: base64.b64encode(v).decode() for k, v in b["files"].items()}}
    html = viewer["index.html"].decode()
    # The modules, inlined in dependency order: each file's imports of the others are removed
    # (they share one module scope once inlined).
    order = [n for n in ("kinds.js", "math.js", "rti.js", "tiles.js", "gpu.js", "ui.js", "viewer.js") if n in viewer]
    code = []
    for n in order:
        lines = [ln for ln in viewer[n].decode().splitlines() if not ln.lstrip().startswith("import ")]
        code.append("\n".join(ln.replace("export ", "", 1) if ln.startswith("export ") else ln for ln in lines))
    script = ('<script type="application/json" id="btfrs-data">' + json.dumps(data).replace("</", "<\\/")
              + "</script>\n<script type=\"module\">\n" + "\n".join(code) + "\n</script>")
    marker = '<script type="module" src="viewer.js"></script>'
    if marker not in html:
        raise InvalidArgumentError("the viewer's index.html has no module script to replace (a broken installation)")
    return html.replace(marker, script)


def save_web(model: Model, folder: PathLike, *, single_file: bool = False, force: bool = False,
             renderer: Optional[str] = None, name: Optional[str] = None, coords: Optional[ArrayLike] = None,
             tiles: Any = None, layout: Optional[ArrayLike] = None, tile_map: Optional[TileMap] = None,
             uv_scale: Any = 1.0, tiled: bool = False, tile_format: str = "jpg", tile_size: int = 256,
             overlap: int = 0, quality: int = 95, view: ArrayLike = 0, progress: Any = None) -> str:
    """Write the viewer with ``model`` to ``folder`` (static files any web server hosts: open
    ``index.html`` through it), or with ``single_file=True`` to one self-contained HTML file at
    ``folder`` that opens from disk. An existing target is refused unless ``force``. Written
    into a temporary sibling and renamed, so an error leaves nothing half-written. Returns the
    page's path.

    The surface shows the sample repeated ``uv_scale`` times, or a synthesized texture: a
    coordinate map ``coords`` (``[H, W, 2]`` uint16 (x, y) into the sample, as
    :func:`btfrs.synth.kcoherence` makes), or a Wang tile set ``tiles`` with its ``layout`` (the
    model is then the set's BTFel model ``tiles.model`` or the model it was made from), or a
    general ``tile_map``, exactly as :func:`btfrs.render` draws them.

    With ``tiled=True`` (``btfrs export --web SITE --tiles``), view slot ``view`` of the model
    is written in its tiled layout under ``model/`` (:meth:`Model.export` with ``tiled=True``:
    relight's for PTM, HSH, RBF and bilinear models, NeuralRTI's for the neural model; Deep Zoom
    pyramids of ``tile_size`` tiles with ``overlap``, ``tile_format`` ``"jpg"`` (of
    ``quality``) or ``"png"``), which OpenLIME opens as it is (``model/info.json`` with its
    ``deepzoom`` layout) and the page reads tile by tile as the view needs them. ``progress``
    (``callable(done, total)``) counts the tiles written."""
    out = os.fspath(folder)
    if os.path.exists(out) and not force:
        raise InvalidArgumentError(f"folder: {out} exists; pass force=True (--force) to replace it")
    if tiled:
        if single_file:
            raise InvalidArgumentError("tiled: a tiled page fetches its tiles as it needs them; it cannot be one file "
                                       "(leave out single_file)")
        if coords is not None or tiles is not None or tile_map is not None or renderer is not None:
            raise InvalidArgumentError("tiled: a tiled page shows the image itself (no coords, tiles, tile_map or "
                                       "renderer)")
        fmt = tiled_format(model)
        slot = _slot_index(model, view)
        b: Dict[str, Any] = {"manifest": None, "files": {}}
    else:
        b = bundle(model, renderer=renderer, name=name, coords=coords, tiles=tiles, layout=layout,
                   tile_map=tile_map, uv_scale=uv_scale)
    parent = os.path.dirname(os.path.abspath(out)) or "."
    os.makedirs(parent, exist_ok=True)
    if single_file:
        fd, tmp = tempfile.mkstemp(dir=parent, prefix=".btfrs-web-", suffix=".html")
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(single_file_html(b))
        if os.path.isdir(out):
            shutil.rmtree(out)
        os.replace(tmp, out)
        return out
    tmp = tempfile.mkdtemp(dir=parent, prefix=".btfrs-web-")
    try:
        for rel, data in _viewer_files().items():
            p = os.path.join(tmp, rel)
            os.makedirs(os.path.dirname(p), exist_ok=True)
            with open(p, "wb") as f:
                f.write(data)
        if tiled:
            where = os.path.join(tmp, "model")
            model.export(where, format=fmt, view=slot, tiled=True, tile_format=tile_format, tile_size=tile_size,
                         overlap=overlap, quality=quality, progress=progress)
            b = bundle_tiled(where, name=name)
        else:
            os.makedirs(os.path.join(tmp, "model"))
        for n, data in b["files"].items():
            with open(os.path.join(tmp, "model", n), "wb") as f:
                f.write(data)
        with open(os.path.join(tmp, "model", "manifest.json"), "w") as f:
            json.dump(b["manifest"], f, indent=1)
        if os.path.lexists(out):
            if os.path.isdir(out) and not os.path.islink(out):
                shutil.rmtree(out)
            else:
                os.remove(out)
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return os.path.join(out, "index.html")


register_web_writer(save_web)
