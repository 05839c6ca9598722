"""The ``btfrs`` command line.

Sizes of images and maps are given as numpy shapes give them, height first (``--out-size H W``);
every file is written atomically (see :func:`btfrs.io.atomic_write`). Progress goes to stderr:
bars on a terminal, one line per phase otherwise.
"""

from __future__ import annotations

import argparse
import http.server
import json
import math
import os
import sys
import tempfile
import time
import warnings
import webbrowser
from typing import Any, Dict, List, NoReturn, Optional, Sequence, Tuple, Union

import numpy as np
from numpy.typing import ArrayLike

from . import __version__, _native, calibration, io, materials, photometric, rendering, stability, synth, tiles, web
from . import fit as fit_mod
from . import fit as fitting
from ._checks import memory_size
from .btf import Btf
from .choosing import SceneUse, choose, default_candidates
from .evaluation import evaluate
from .exceptions import BtfrsError, InvalidArgumentError
from .models import Model, model_kinds
from .rendering import Camera, DirectionalLight, PointLight, Scene, render
from .tools import baselines, demo


class _Parser(argparse.ArgumentParser):
    """argparse whose errors are one line on stderr (``btfrs fit: error: ...``) and exit code 2,
    like every other refusal of the command line."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {_one_line(message)} (see {self.prog} --help)\n")


def _one_line(text: str) -> str:
    """``text`` on one line (a message spanning lines joined with "; ")."""
    return "; ".join(line.strip() for line in str(text).splitlines() if line.strip())


def main(argv: Optional[Sequence[str]] = None) -> int:
    p = _Parser(prog="btfrs", description="Fit, synthesize and render BTFs.")
    p.add_argument("--version", action="version", version=f"btfrs {__version__}")
    sub = p.add_subparsers(dest="command", required=True)
    d = sub.add_parser("demo", help="the main job on a built-in material: fit, compare, render, synthesize, summarise")
    d.add_argument("--out", default="demo", help="output folder (default: demo)")
    d.add_argument("--full", action="store_true",
                   help="every example of every model, a second tile set and the full evaluation with both held-out "
                        "protocols and the numpy / scipy / scikit-learn ways: about 12 minutes of CPU on 2 cores, "
                        "where the default quick run of every part takes about 2")
    d.add_argument("--material", default="knit", help="built-in material (default: knit)")
    d.add_argument("--size", type=int, default=64, help="texels per side (default: 64)")
    d.add_argument("--seed", type=int, default=1, help="material seed (default: 1)")
    d.add_argument("--quiet", action="store_true", help="no progress bars")
    s = sub.add_parser("synth", help="synthesize a large BTF (or RGB texture) as a coordinate map")
    _sample_args(s, material="knit", size=64, seed=1, texture=True)
    s.add_argument("--analysis", help="a .btfrs analysis file: loaded if it exists, else written after analysing")
    s.add_argument("--textons", type=int, default=1024, help="textons (default: 1024)")
    s.add_argument("--out-size", type=int, nargs=2, default=[512, 512], metavar=("H", "W"),
                   help="output height then width, as numpy shapes (default: 512 512)")
    s.add_argument("--method", choices=["kcoherence", "jump"], default="kcoherence")
    s.add_argument("-k", type=int, default=3, help="k of k-coherence (default: 3)")
    s.add_argument("--neighbourhood", type=int, default=2, help="window radius (default: 2, a 5 x 5 window)")
    s.add_argument("--levels", type=int, default=3, help="pyramid levels (default: 3)")
    s.add_argument("--toroidal", action="store_true", help="a tileable output")
    s.add_argument("--seed", type=int, default=7, help="synthesis seed (default: 7)")
    s.add_argument("--out", default="synth", help="output folder (default: synth)")
    e = sub.add_parser("evaluate", help="speed against accuracy of every model on one material: table + charts")
    _sample_args(e, material="weave", size=32, seed=1)
    e.add_argument("--models", default="all", help="'all' or a comma-separated list of model names (default: all)")
    e.add_argument("--holdout", choices=["pairs", "directions", "both"], default="both",
                   help="held-out protocol: random pairs, whole directions, or both (default: both)")
    e.add_argument("--fraction", type=float, default=0.1, help="share held out (default: 0.1)")
    e.add_argument("--sweep", choices=["full", "quick"], default="full", help="parameter sweep (default: full)")
    e.add_argument("--no-baselines", action="store_true", help="leave out the numpy / scipy / scikit-learn rows")
    e.add_argument("--no-render", action="store_true", help="leave out render ms and scene PSNR")
    e.add_argument("--eval-seed", type=int, default=0, help="seed of the splits and of seeded fits (default: 0)")
    e.add_argument("--out", default="evaluate", help="output folder (default: evaluate)")
    c = sub.add_parser("choose", help="the cheapest model that meets a tolerance on a scene's own directions, or on held-out lights")
    _sample_args(c, material="weave", size=32, seed=1)
    c.add_argument("--scene", choices=["plane", "sphere"], default="plane", help="the surface (default: plane)")
    c.add_argument("--camera", type=float, nargs=3, action="append", metavar=("X", "Y", "Z"),
                   help="a camera eye looking at the origin; repeat for a camera path (default: 0 0 3)")
    c.add_argument("--fov", type=float, default=40.0, help="vertical field of view, degrees (default: 40)")
    c.add_argument("--light", type=float, nargs=3, action="append", metavar=("X", "Y", "Z"),
                   help="a directional light towards (X, Y, Z); repeat for a light range, one light per "
                        "frame (default: 0.3 -0.2 1)")
    c.add_argument("--image-size", type=int, nargs=2, default=[256, 256], metavar=("H", "W"),
                   help="rendered image height then width (default: 256 256)")
    c.add_argument("--uv-scale", type=float, default=1.0, help="repetitions of the sample (default: 1)")
    c.add_argument("--tolerance", type=float, default=0.05, help="largest weighted relative error (default: 0.05)")
    c.add_argument("--budget-bytes", help="largest model size: bytes, or a size such as 8MiB or 2MB")
    c.add_argument("--budget-ms", type=float, help="largest render time in ms")
    c.add_argument("--samples", type=int, default=256, help="(view, light) pairs scored (default: 256)")
    c.add_argument("--kinds", nargs="+", metavar="KIND",
                   help="only these candidates: registered model kinds and/or raw (default: all)")
    c.add_argument("--no-render", action="store_true", help="do not time the renders")
    c.add_argument("--seed", type=int, default=0, help="sampling seed (default: 0)")
    c.add_argument("--holdout", type=float, metavar="SHARE",
                   help="no scene: score each model on this share of the lights held out, e.g. 0.2 for a "
                        "single-view capture (the scene options then do not apply)")
    st = sub.add_parser("stability", help="every model in the regimes where methods fail: error curves, flags, charts")
    _sample_args(st, material="grooves", size=16, seed=0)
    st.add_argument("--seed", type=int, default=0, help="seed of the regimes: splits, noise, texels (default: 0)")
    st.add_argument("--models", nargs="+", default=None, help="model kinds (default: one cheap setting of each)")
    st.add_argument("--regimes", nargs="+", default=None, help="regimes (default: all)")
    st.add_argument("--out", default="stability", help="output folder (default: stability)")
    st.add_argument("--no-robust", action="store_true",
                    help="fit every value as measured (default: robust fits, robust=True)")
    t = sub.add_parser("tiles", help="a graph-cut Wang tile set (paper 002): tiles, their picture, a rendered tiling")
    _sample_args(t, material="bumps", size=128, seed=3, texture=True)
    t.add_argument("--model", default="sh", choices=[*_kinds(), "raw"], metavar="MODEL",
                   help="the model whose domain the tiles are synthesized in: " + ", ".join(_kinds())
                        + " or raw (default: sh, at its quick-sweep setting)")
    _option_args(t)
    t.add_argument("--tile", type=int, default=64, help="tile side in texels (default: 64)")
    t.add_argument("--edge-height", type=int, default=16, help="edge height h (default: 16)")
    t.add_argument("--colors", type=int, default=2, help="colours per edge direction (default: 2: 16 tiles)")
    t.add_argument("--layout", type=int, nargs=2, default=[3, 10], metavar=("ROWS", "COLS"),
                   help="the tiling rendered on a cylinder, columns around it (default: 3 10)")
    t.add_argument("--seed", type=int, default=5, help="synthesis and tiling seed (default: 5)")
    t.add_argument("--out", default="tiles", help="output folder (default: tiles)")
    _data_commands(sub)
    _calibrate_args(sub)
    args = p.parse_args(argv)
    try:
        _check_values(args)
        if args.command == "demo":
            demo.run(args.out, material=args.material, size=args.size, seed=args.seed, progress=not args.quiet,
                     full=args.full)
        else:
            commands = {"synth": synth_command, "evaluate": evaluate_command, "choose": choose_command,
                        "stability": stability_command, "tiles": tiles_command, "info": info_command,
                        "fit": fit_command, "export": export_command, "render": render_command,
                        "view": view_command, "normals": normals_command,
                        "calibrate": calibrate_command}
            commands[args.command](args)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except (BtfrsError, OSError) as e:
        print(f"btfrs: error: {_one_line(str(e))}", file=sys.stderr)
        return 2
    return 0


# --- values: every option checked for range before any work ----------------------------------

#: The range of every numeric option, by its destination: (flag, low, high, low open, high
#: open); ``None`` is unbounded. Integers and floats alike; a float must also be finite.
_RANGES: Dict[str, Tuple[str, Optional[float], Optional[float], bool, bool]] = {
    "size": ("--size", 8, 1024, False, False),  # the built-in materials' range
    "seed": ("--seed", 0, 2**64 - 1, False, False),
    "material_seed": ("--material-seed", 0, 2**64 - 1, False, False),
    "eval_seed": ("--eval-seed", 0, 2**64 - 1, False, False),
    "layout_seed": ("--layout-seed", 0, 2**64 - 1, False, False),
    "textons": ("--textons", 1, None, False, False),
    "out_size": ("--out-size", 1, None, False, False),
    "k": ("-k", 1, None, False, False),
    "neighbourhood": ("--neighbourhood", 0, None, False, False),
    "levels": ("--levels", 1, None, False, False),
    "fraction": ("--fraction", 0.0, 1.0, True, True),
    "fov": ("--fov", 0.0, 180.0, True, True),
    "image_size": ("--image-size", 1, None, False, False),
    "uv_scale": ("--uv-scale", 0.0, None, True, False),
    "tolerance": ("--tolerance", 0.0, None, True, False),
    "budget_ms": ("--budget-ms", 0.0, None, True, False),
    "samples": ("--samples", 1, None, False, False),
    "tile": ("--tile", 1, None, False, False),
    "edge_height": ("--edge-height", 1, None, False, False),
    "colors": ("--colors", 1, None, False, False),
    # A tiling of at most 4096 x 4096 tiles (64 MiB of tile ids).
    "layout": ("--layout", 1, 4096, False, False),
    "holdout": ("--holdout", 0.0, 1.0, False, True),
    "view": ("--view", 0, None, False, False),
    "port": ("--port", 0, 65535, False, False),
    "exposure": ("--exposure", 0.0, None, False, False),
    "camera": ("--camera", None, None, False, False),
    "light": ("--light", None, None, False, False),
    "crop": ("--crop", 0, None, False, False),
}


def _check_number(flag: str, v: Any, lo: Optional[float], hi: Optional[float], lo_open: bool, hi_open: bool) -> None:
    ok = not (isinstance(v, float) and not math.isfinite(v))
    if ok and lo is not None:
        ok = v > lo if lo_open else v >= lo
    if ok and hi is not None:
        ok = v < hi if hi_open else v <= hi
    if not ok:
        def n(x: float) -> str:
            return f"{x:g}" if isinstance(x, float) else str(x)
        if lo is not None and hi is not None:
            rng = f" in {'(' if lo_open else '['}{n(lo)}, {n(hi)}{')' if hi_open else ']'}"
        elif lo is not None:
            rng = f" {'>' if lo_open else '>='} {n(lo)}"
        elif hi is not None:
            rng = f" {'<' if hi_open else '<='} {n(hi)}"
        else:
            rng = ""
        what = "a finite number" if isinstance(v, float) else "an integer"
        raise InvalidArgumentError(f"{flag}: expected {what}{rng}, got {v}")


def _settle_defaults(args: argparse.Namespace) -> None:
    """Options whose default depends on what else is given are parsed with ``None``; record
    which were given (``args.given``) and fill in the defaults (``default_<name>``)."""
    given = set()
    for name, default in list(vars(args).items()):
        if name.startswith("default_") and name != "default_material":
            dest = name[len("default_"):]
            if getattr(args, dest, None) is None:
                setattr(args, dest, default)
            else:
                given.add(dest)
    args.given = given


def _check_values(args: argparse.Namespace) -> None:
    """Every option's value checked against its range before any work, each refusal naming
    the flag; and the options that only apply to some inputs refused with the others."""
    _settle_defaults(args)
    for dest, (flag, lo, hi, lo_open, hi_open) in _RANGES.items():
        v = getattr(args, dest, None)
        if v is None or isinstance(v, str):
            continue
        for x in (v if isinstance(v, list) else [v]):
            for y in (x if isinstance(x, list) else [x]):
                _check_number(flag, y, lo, hi, lo_open, hi_open)
    crop = getattr(args, "crop", None)
    if crop is not None and (crop[2] < 1 or crop[3] < 1):
        raise InvalidArgumentError(f"--crop: expected ROWS and COLS >= 1, got {crop[2]} and {crop[3]}")
    for flag, vec in (("--light", getattr(args, "light", None)), ("--camera", getattr(args, "camera", None))):
        for d in (vec or []) if flag == "--light" else ([vec] if vec else []):
            if not any(d):
                raise InvalidArgumentError(f"{flag}: expected a non-zero vector, got {' '.join(map(str, d))}")
    if getattr(args, "max_bytes", None) is not None:
        args.max_bytes = memory_size("--max-bytes", args.max_bytes)
    if getattr(args, "budget_bytes", None) is not None:
        args.budget_bytes = memory_size("--budget-bytes", args.budget_bytes)
    for name in ("views", "lights"):
        if hasattr(args, name):
            _indices(name, getattr(args, name))


def _facts() -> Dict[str, Dict[str, Any]]:
    """Every registered model's facts (the registry's)."""
    return model_kinds()


def _kinds() -> List[str]:
    """The registered model kinds (the registry's list)."""
    return list(_facts())


def _formats() -> List[Tuple[str, str, str, bool]]:
    """Other tools' model formats: ``(name, extension, doc, folder)`` (``folder``: written as a
    folder holding an index file, e.g. NeuralRTI's ``info.json``)."""
    return [(f.name, f.extension, f.doc, f.folder) for f in _native.model_formats()]


def _sample_args(p: argparse.ArgumentParser, material: Optional[str] = None, size: int = 32, seed: int = 1,
                 texture: bool = False, required: bool = False) -> None:
    """The input every command takes the same way: a positional path to any capture or btfrs
    file (what :func:`btfrs.load` opens), or ``--material NAME`` (with ``--size``,
    ``--material-seed``); ``texture``: or ``--texture IMAGE``, an RGB image."""
    p.add_argument("path", nargs=None if required else "?",
                   help="a capture (UBO .zip or folder, UBO2014 .btf, RTI .lp or folder, an image folder with "
                        "--directions) or a btfrs file (.btfrs, .ptm, .rti)"
                        + ("" if required or material is None else f"; default: --material {material}"))
    if not required:
        p.add_argument("--material", default=None, metavar="NAME",
                       help=f"a built-in material instead of a file (default: {material})" if material
                       else "a built-in material instead of a file")
        p.add_argument("--size", type=int, default=None, help=f"material texels per side (default: {size})")
        p.add_argument("--material-seed", type=int, default=None, help=f"material seed (default: {seed})")
        if texture:
            p.add_argument("--texture", help="an RGB image (.png or .exr) as the sample instead")
        p.set_defaults(default_material=material, default_size=size, default_material_seed=seed)
    p.add_argument("--directions", help="direction table (.csv or .json) of an image folder")
    p.add_argument("--crop", type=int, nargs=4, metavar=("ROW", "COL", "ROWS", "COLS"),
                   help="keep a rectangle of texels (row 0 at the top)")
    p.add_argument("--views", help="comma-separated view indices to keep")
    p.add_argument("--lights", help="comma-separated light indices to keep")
    p.add_argument("--linear", action="store_true", help="8/16-bit images are linear, not sRGB")
    p.add_argument("--max-bytes", metavar="SIZE",
                   help="the most memory a file may take to read, in bytes or as 256MB, 2GiB (default: half "
                        "the machine's memory); files from strangers beyond it are refused")
    p.add_argument("--quiet", action="store_true", help="no progress bars")


def _refuse(args: argparse.Namespace, flags: Sequence[Tuple[str, str]], why: str) -> None:
    """Refuse the first of ``flags`` ((dest, flag)) given on the command line: ``why`` says
    what it applies to."""
    for dest, flag in flags:
        v = getattr(args, dest, None)
        if dest in getattr(args, "given", ()) or (dest not in ("size", "material_seed") and v not in (None, False)):
            raise InvalidArgumentError(f"{flag}: {why}")


_FILE_ONLY = (("directions", "--directions"), ("linear", "--linear"), ("max_bytes", "--max-bytes"))
_MATERIAL_ONLY = (("size", "--size"), ("material_seed", "--material-seed"))
_SELECTION = (("views", "--views"), ("lights", "--lights"), ("crop", "--crop"))


def _load_sample(args: argparse.Namespace, progress: bool) -> Tuple[Any, str]:
    """The input of :func:`_sample_args`: ``(object, name)`` (a Btf for a material). Every
    option is checked against the input given: those that do not apply to it are refused."""
    given = [n for n, v in (("path", args.path), ("--material", getattr(args, "material", None)),
                            ("--texture", getattr(args, "texture", None))) if v]
    if len(given) > 1:
        raise InvalidArgumentError(f"{' and '.join(given)}: give one input, a path or --material"
                                   + (" or --texture" if hasattr(args, "texture") else ""))
    if args.path:
        _refuse(args, _MATERIAL_ONLY, "only applies to --material")
        return _open(args), os.path.basename(os.path.normpath(args.path))
    if getattr(args, "texture", None):
        _refuse(args, _MATERIAL_ONLY, "only applies to --material")
        _refuse(args, _FILE_ONLY + _SELECTION, "does not apply to --texture (an RGB image)")
        return io.load_image(args.texture), os.path.basename(args.texture)
    name = args.material or args.default_material
    if name is None:
        raise InvalidArgumentError("path: expected a capture or btfrs file, or --material NAME")
    _refuse(args, _FILE_ONLY, "only applies to a capture or file path, not to --material")
    btf = materials.make(name, size=args.size, seed=args.material_seed, progress=progress)
    return io._select_btf(btf, args.crop, _indices("views", args.views), _indices("lights", args.lights)), name


def _load_btf(args: argparse.Namespace, progress: bool) -> Tuple[Btf, str]:
    """:func:`_load_sample`, which must be measured data (a Btf)."""
    obj, name = _load_sample(args, progress)
    if not isinstance(obj, Btf):
        raise InvalidArgumentError(f"path: {args.path} holds a {type(obj).__name__}, not measured data (a BTF)")
    return obj, name


def _option_args(p: argparse.ArgumentParser) -> None:
    """``--options JSON`` and ``--set NAME=VALUE``: a fit's options, checked against the model's
    schema before any work."""
    p.add_argument("--options", default="{}", help='fit options as JSON, e.g. \'{"order": 3}\'')
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="one fit option, VALUE read as the option's type (see docs/cli.md); repeatable")


def tiles_command(args: argparse.Namespace) -> None:
    """``btfrs tiles``: fit (or read) the sample, synthesize a Wang tile set in its domain, write
    the set, a picture of the tiles with their edge colours, a tiling and its rendering."""
    _check_output("--out", args.out, args, folder=True)
    progress = not args.quiet
    opts = None if args.model == "raw" else _fit_options(args, args.model)
    os.makedirs(args.out, exist_ok=True)
    written = []
    sample, name = _load_sample(args, progress)
    model: Union[Model, Btf, None]
    if not isinstance(sample, Btf):
        model, source = None, sample
    elif args.model == "raw":
        model, source = sample, sample
    else:
        if not opts:
            # The model's quick setting: the one the evaluate and stability suites start from.
            opts = next(dict(o) for _, o, quick, _ in model_kinds()[args.model]["sweep"] if quick)
        model = fitting.fit(args.model, sample, progress=progress, **opts)
        source = model
    ts = tiles.wang(source, tile=args.tile, edge_height=args.edge_height, colors=args.colors, seed=args.seed,
                    progress=progress)
    print(ts.report)
    path = os.path.join(args.out, "tiles.btfrs")
    ts.save(path)
    written.append(path)
    pic = os.path.join(args.out, "tiles.png")
    io.save_image(pic, ts.picture())
    written.append(pic)
    rows, cols = args.layout
    layout = ts.tiling(rows, cols, seed=args.seed, wrap=(True, False))
    io.save_array(os.path.join(args.out, "layout.npy"), layout)
    written.append(os.path.join(args.out, "layout.npy"))
    flat = os.path.join(args.out, "tiling.png")
    img = ts.image(layout)
    io.save_image(flat, np.clip(img / max(float(np.percentile(img, 99.5)), 1e-6), 0, 1))
    written.append(flat)
    if model is not None:
        cam = Camera.look_at([0.0, -3.2, 1.6], [0.0, 0.0, 0.0], fov_deg=40.0)
        lights = [PointLight([2.0, -2.5, 3.0], 9.0)]
        scene = Scene.cylinder(radius=1.0, height=2.0)
        out = render(ts.model if ts.model is not None else model, scene, cam, lights, size=(512, 512),
                     tiles=ts, layout=layout)
        rp = os.path.join(args.out, "render.png")
        io.save_image(rp, out)
        written.append(rp)
    e = ts.seam_errors(ts.tiling(16, 16, seed=args.seed + 1), windows=300)
    line = (f"seams (16 x 16 tiling, 5 x 5 windows vs their best match in the sample): across tile edges "
            f"{e['edge']:.4f}, inside tiles {e['interior']:.4f}; plain tiling of random crops: across edges "
            f"{e['crops_edge']:.4f}, inside {e['crops_interior']:.4f}")
    print(line)
    rep = os.path.join(args.out, "report.txt")
    io.save_text(rep, f"{name}, {args.model if model is not None else 'rgb'}\n{ts.report}\n{line}\n")
    written.append(rep)
    print("wrote " + ", ".join(written))


def evaluate_command(args: argparse.Namespace) -> None:
    """``btfrs evaluate``: :func:`btfrs.evaluate` on a material, the table on stdout, the report
    and charts in ``--out``."""
    _check_output("--out", args.out, args, folder=True)
    progress = not args.quiet
    btf, name = _load_btf(args, progress)
    models = args.models if args.models == "all" else [m.strip() for m in args.models.split(",") if m.strip()]
    rep = evaluate(btf, models, holdout=args.holdout, fraction=args.fraction, sweep=args.sweep,
                   baselines=None if args.no_baselines or args.sweep == "quick" else baselines.evaluation_rows, render=not args.no_render, seed=args.eval_seed,
                   material=name, progress=progress)
    print(rep.summary())
    print()
    print(rep.table())
    paths = rep.save(args.out)
    print(f"\nwrote {', '.join(paths)}")


def synth_command(args: argparse.Namespace) -> None:
    """``btfrs synth``: analyse (or load the analysis), synthesize, save the map and pictures."""
    _check_output("--out", args.out, args, folder=True)
    progress = not args.quiet
    os.makedirs(args.out, exist_ok=True)
    sample, _ = _load_sample(args, progress)
    if not isinstance(sample, (Btf, np.ndarray)):
        raise InvalidArgumentError(f"path: {args.path} holds a {type(sample).__name__}, not a BTF or image")
    if args.analysis and os.path.exists(args.analysis):
        an = synth.Analysis.load(args.analysis)
        print(f"loaded {an}")
    else:
        an = synth.analyse(sample, textons=min(args.textons, sample.shape[0] * sample.shape[1]),
                           levels=args.levels, neighbourhoods=(args.neighbourhood,), progress=progress)
        print(f"analysed in {an.seconds:.2f} s: {an}")
        if args.analysis:
            an.save(args.analysis)
    size = tuple(args.out_size)
    if args.method == "jump":
        cmap = synth.jump_map(an, size=size, neighbourhood=args.neighbourhood, seed=args.seed, progress=progress)
    else:
        cmap = synth.kcoherence(an, size=size, k=args.k, neighbourhood=args.neighbourhood, levels=args.levels,
                                toroidal=args.toroidal, seed=args.seed, progress=progress)
    io.save_array(os.path.join(args.out, "coords.npy"), cmap)
    h, w = sample.shape[0], sample.shape[1]
    tiles = synth.tiled((h, w), size)
    if isinstance(sample, Btf):
        view, light = 0, int(np.argmin(np.abs(sample.lights[:, 2] - np.cos(np.radians(45)))))
        img = sample.image(view, light)
    else:
        img = sample
    exposure = 0.8 / max(float(np.percentile(img, 99)), 1e-6)
    io.save_image(os.path.join(args.out, "synthesized.png"), synth.apply(img, cmap), exposure=exposure)
    io.save_image(os.path.join(args.out, "tiled.png"), synth.apply(img, tiles), exposure=exposure)
    q = synth.quality(an, cmap, neighbourhood=args.neighbourhood)
    qt = synth.quality(an, tiles, neighbourhood=args.neighbourhood)
    print(f"{args.method}: {q}")
    print(f"plain tiling: {qt}")
    print(f"wrote {args.out}/coords.npy (uint16 [H, W, 2] (x, y)), synthesized.png, tiled.png")


def choose_command(args: argparse.Namespace) -> None:
    """``btfrs choose``: what a scene needs of a material, and the cheapest model that gives it."""
    progress = not args.quiet
    btf, _ = _load_btf(args, progress)
    cams = [Camera.look_at(eye, [0.0, 0.0, 0.0], args.fov) for eye in (args.camera or [[0.0, 0.0, 3.0]])]
    lights = [[DirectionalLight(d, 1.0)] for d in (args.light or [[0.3, -0.2, 1.0]])]
    surface = Scene.sphere() if args.scene == "sphere" else Scene.plane()
    use = SceneUse(camera=cams, lights=lights, size=tuple(args.image_size), scene=surface, uv_scale=args.uv_scale)
    cands = None
    if args.kinds:
        known = default_candidates()
        cands = [c for c in known if c[0] in args.kinds]
        unknown = sorted(set(args.kinds) - {c[0] for c in known})
        if unknown:
            raise InvalidArgumentError(f"--kinds: unknown {', '.join(unknown)}; expected some of "
                                       f"{', '.join(sorted({c[0] for c in known}))}")
    if args.holdout is not None:
        pick = choose(btf, tolerance=args.tolerance, budget_bytes=args.budget_bytes, candidates=cands,
                      seed=args.seed, holdout=args.holdout, progress=progress)
    else:
        pick = choose(btf, scene=use, tolerance=args.tolerance, budget_bytes=args.budget_bytes,
                      budget_ms=args.budget_ms, candidates=cands, samples=args.samples,
                      measure_render=not args.no_render, seed=args.seed, progress=progress)
    print(pick.explain())
def stability_command(args: argparse.Namespace) -> None:
    """``btfrs stability``: run every model in every regime, write report.json, report.md and
    one chart per regime, print the table."""
    _check_output("--out", args.out, args, folder=True)
    progress = not args.quiet
    btf, name = _load_btf(args, progress)
    if not args.path:
        name = f"{name} {args.size}x{args.size}, seed {args.material_seed}"
    rep = stability.run(btf, models=args.models or "all", regimes=args.regimes or "all", seed=args.seed,
                        robust=not args.no_robust,
                        progress=progress, name=name)
    paths = rep.save(args.out)
    print(rep.table())
    print(f"wrote {len(paths)} files to {args.out}/ (report.json, report.md, one chart per regime)")



# --- a user's own data: info, fit, export, render -------------------------------------------------

def _indices(name: str, text: Optional[str]) -> Optional[List[int]]:
    if text is None:
        return None
    try:
        out = [int(t) for t in text.split(",") if t.strip()]
    except ValueError:
        raise InvalidArgumentError(f"--{name}: expected comma-separated integers, got {text!r}") from None
    if not out or any(i < 0 for i in out):
        raise InvalidArgumentError(f"--{name}: expected comma-separated integers >= 0, got {text!r}")
    return out


def _open(args: argparse.Namespace) -> Any:
    return io.load(args.path, directions=args.directions, crop=args.crop, views=_indices("views", args.views),
                   lights=_indices("lights", args.lights), linear=args.linear, progress=not args.quiet,
                   max_bytes=args.max_bytes)


def _data_commands(sub: "argparse._SubParsersAction[_Parser]") -> None:
    i = sub.add_parser("info", help="what a capture or btfrs file holds: sizes, directions, values, what fits")
    _sample_args(i)
    f = sub.add_parser("fit", help="fit any model to a capture or BTF file and save it")
    _sample_args(f)
    f.add_argument("--model", required=True, choices=_kinds(), metavar="MODEL",
                   help="the model: " + ", ".join(_kinds()))
    _option_args(f)
    f.add_argument("--holdout", type=float, default=0.0,
                   help="share of (view, light) pairs held out to report the prediction error, in [0, 1) "
                        "(default: 0)")
    f.add_argument("--seed", type=int, default=0, help="seed of the held-out split (default: 0)")
    f.add_argument("--no-robust", action="store_true",
                   help="fit every value as measured (default: outliers such as hot pixels, dust and glints are "
                        "found and repaired before fitting, and bad images reported)")
    f.add_argument("--exclude-bad-images", action="store_true",
                   help="leave out of the fit the whole images found far from their neighbours (a misfired or "
                        "doubled flash, a moved sample)")
    f.add_argument("-o", "--out", required=True, help="the model file (.btfrs)")
    x = sub.add_parser("export", help="write a model or BTF for other tools: .ptm, .rti, relight, Mitsuba 3, glTF, "
                       "EXR maps, image stack")
    _sample_args(x)
    for name, ext, doc, folder in _formats():
        able = [k for k, info in _facts().items() if name in info["exports"]]
        x.add_argument(f"--{name}", metavar="FOLDER" if folder else f"FILE.{ext}",
                       help=f"write {doc} ({', '.join(able)} models)" + (", into a folder" if folder else ""))
    x.add_argument("--exr", help="write the per-texel coefficient maps as one multi-channel EXR (models)")
    x.add_argument("--stack", help="write a BTF as an image stack + directions.csv into this folder")
    x.add_argument("--format", choices=["exr", "png"], default=None, help="image format of --stack (default: exr)")
    x.set_defaults(default_format="exr")
    x.add_argument("--view", type=int, default=0, help="view slot written to .ptm / .rti (default: 0)")
    x.add_argument("--web", metavar="FOLDER",
                   help="write the browser viewer with the model as a static folder (any web server hosts it); "
                        "a BTF or capture gets a quick fit first (--model)")
    x.add_argument("--single-file", action="store_true",
                   help="with --web: one self-contained HTML file (data embedded) that opens from disk")
    x.add_argument("--model", default=None, choices=_kinds(), metavar="MODEL",
                   help=f"with --web on a BTF or capture: the model fitted first (default: {_kinds()[0]})")
    x.set_defaults(default_model=_kinds()[0])
    x.add_argument("--force", action="store_true",
                   help="with --web: replace an existing folder or file; with a folder format: write into a folder "
                   "that holds files")
    x.add_argument("--tiles", action="store_true",
                   help="with --web, --relight or --neuralrti: the tiled, multi-resolution layout (every plane a "
                        "Deep Zoom pyramid, as relight writes and OpenLIME reads; the page fetches the tiles it "
                        "shows)")
    x.add_argument("--tile-format", choices=["jpg", "png"], default=None, help="with --tiles: the tiles' format "
                   "(default: jpg)")
    x.add_argument("--tile-quality", type=int, default=None, help="with --tiles: JPEG quality, 1 to 100 (default: 95)")
    x.add_argument("--tile-size", type=int, default=None, help="with --tiles: tile side in pixels (default: 256)")
    x.add_argument("--tile-overlap", type=int, default=None,
                   help="with --tiles: pixels a tile shares with each neighbour (default: 0, as relight)")
    x.set_defaults(default_tile_format="jpg", default_tile_quality=95, default_tile_size=256, default_tile_overlap=0)
    _surface_args(x, "with --web: ")
    nm = sub.add_parser("normals", help="photometric stereo on one view slot: normals, albedo and height maps "
                                        "(EXR and 16-bit PNG)")
    _sample_args(nm)
    nm.add_argument("--view", type=int, default=0, help="the view slot (default: 0)")
    nm.add_argument("--method", choices=["robust", "l2"], default="robust",
                    help="robust: shadows and highlights down-weighted (IRLS); l2: least squares over every "
                         "light (default: robust)")
    nm.add_argument("--height", choices=["fft", "mirror", "none"], default="fft",
                    help="integrate the normals into a height: fft for a sample that tiles, mirror for a capture "
                         "that does not, none to skip (default: fft)")
    nm.add_argument("--out", default="normals", help="output folder (default: normals)")
    nm.add_argument("--force", action="store_true", help="write into an existing folder")
    w = sub.add_parser("view", help="look at a model, BTF, capture or tile set in the browser (WebGPU, served on "
                                    "localhost)")
    _sample_args(w)
    w.add_argument("--model", default=None, choices=_kinds(), metavar="MODEL",
                   help=f"for a BTF or capture: the model fitted first (default: {_kinds()[0]}, the first registered)")
    w.set_defaults(default_model=_kinds()[0])
    _surface_args(w, "")
    w.add_argument("--port", type=int, default=8000, help="localhost port (default: 8000; another if it is in use)")
    w.add_argument("--no-browser", action="store_true", help="print the address instead of opening a browser")
    r = sub.add_parser("render", help="render a model, BTF or capture on a plane, sphere or cylinder")
    _sample_args(r)
    r.add_argument("--scene", choices=["plane", "sphere", "cylinder"], default="plane")
    r.add_argument("--light", type=float, nargs=3, action="append", metavar=("X", "Y", "Z"),
                   help="a directional light towards (X, Y, Z) in the scene; repeatable (default: 0.3 0.2 0.93)")
    r.add_argument("--camera", type=float, nargs=3, metavar=("X", "Y", "Z"),
                   help="camera position looking at the origin (default: straight above a plane, oblique otherwise)")
    r.add_argument("--fov", type=float, default=40.0, help="vertical field of view, degrees (default: 40)")
    r.add_argument("--image-size", type=int, nargs=2, default=[512, 512], metavar=("H", "W"),
                   help="image height then width (default: 512 512)")
    r.add_argument("--uv-scale", type=float, default=1.0, help="repetitions of the sample (default: 1)")
    r.add_argument("--exposure", type=float, default=1.0, help="PNG exposure (default: 1)")
    r.add_argument("--backend", choices=["gpu", "cpu"], default="gpu", help="wgpu or the CPU reference (default: gpu)")
    r.add_argument("--renderer", help="the model's renderer (default: its first)")
    r.add_argument("-o", "--out", required=True, help="the image (.png or .exr)")


def _coverage(dirs: ArrayLike) -> str:
    """Theta range and the largest angular gap: the biggest angle from any direction of the
    hemisphere to its nearest sample (a fine Fibonacci set of 4000 directions)."""
    d = np.asarray(dirs, dtype=np.float64)
    theta = np.degrees(np.arccos(np.clip(d[:, 2], -1, 1)))
    n = 4000
    k = np.arange(n) + 0.5
    z = 1 - k / n
    phi = k * np.pi * (3 - np.sqrt(5))
    r = np.sqrt(1 - z * z)
    probe = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
    gap = np.degrees(np.arccos(np.clip((probe @ d.T).max(axis=1), -1, 1))).max()
    return f"{len(d)}, theta {theta.min():.1f} to {theta.max():.1f} deg, largest gap {gap:.1f} deg"


def info_command(args: argparse.Namespace) -> None:
    """``btfrs info``: print what the file holds and which models its sampling supports."""
    obj, name = _load_sample(args, not args.quiet)
    print(f"{args.path or name}")
    if isinstance(obj, Model):
        print(f"  model {obj.kind}: {obj.height} x {obj.width} texels, {obj.nbytes / 1024:.1f} KiB as stored")
        for name, a in obj.arrays.items():
            print(f"    {name}: {a.dtype} {list(a.shape)}")
        return
    if not isinstance(obj, Btf):
        print(f"  {type(obj).__name__}")
        return
    b = obj
    per_view = [int(b.mask[v].sum()) if b.mask is not None else b.n_lights for v in range(b.n_views)]
    def plural(n: int, word: str) -> str:
        return f"{n} {word}" + ("" if n == 1 else "s")

    print(f"  {b.height} x {b.width} texels, {plural(b.n_views, 'view')} x {plural(b.n_lights, 'light')}, "
          f"{b.pairs} pairs present, "
          f"{b.nbytes / 2**20:.1f} MiB as float32")
    print(f"  views: {_coverage(b.views)}")
    print(f"  lights: {_coverage(b.lights)}; per view {min(per_view)} to {max(per_view)}")
    data = np.asarray(b.data)
    print(f"  values: min {float(data.min()):.4g}, max {float(data.max()):.4g}, mean {float(data.mean()):.4g} "
          f"(linear RGB)")
    meta = b.meta
    made = meta.get("values")
    if isinstance(made, dict):
        print(f"  read as: cosine {made.get('cosine', '?')}; colour scale {made.get('scale_applied', '?')} applied; "
              f"transfer {made.get('transfer', '?')}")
    shown = {k: v for k, v in meta.items() if k not in ("values", "warnings", "xml") and v not in (None, "", [])}
    if shown:
        print("  file: " + "; ".join(f"{k} {v}" for k, v in shown.items()))
    fewest = min(per_view)
    # Each model's registry entry says what sampling it needs: per view slot models need enough
    # lights in every slot for their unknowns (the default options'); the others fit any
    # sampling, with what a single view cannot tell them noted.
    one = b.n_views == 1
    print("  what fits (default options):")
    for kind, info in model_kinds().items():
        s = info["sampling"]
        if s["per_view"]:
            n = s["min_lights"]
            ok = fewest >= n
            note = f"per view slot, needs >= {n} lights per view ({s['why']})" + ("" if ok else f": only {fewest}")
        else:
            ok, note = True, s["one_view"] if one else s["note"]
        print(f"    {'yes' if ok else 'no ':3s} {kind:15s} {note}")


def _fit_options(args: argparse.Namespace, kind: str) -> Dict[str, Any]:
    """The options of ``--options`` and ``--set`` for a ``kind`` fit, each ``--set`` value read
    as its schema's type says, all checked against the model's schema before any work."""
    try:
        opts = json.loads(args.options)
    except json.JSONDecodeError as e:
        raise InvalidArgumentError(f"--options: not valid JSON ({e})") from None
    except RecursionError:
        raise InvalidArgumentError("--options: nested too deeply; expected a JSON object of option values") from None
    if not isinstance(opts, dict):
        raise InvalidArgumentError("--options: expected a JSON object")
    schema = {o["name"]: o for o in model_kinds()[kind]["options"]}
    for item in args.set:
        if "=" not in item:
            raise InvalidArgumentError(f"--set: expected NAME=VALUE, got {item!r}")
        k, v = (t.strip() for t in item.split("=", 1))
        o = schema.get(k)
        if o is None:
            names = ", ".join(schema) or "none: this model takes no options"
            raise InvalidArgumentError(f"--set {k}: unknown option of the {kind} model; expected one of {names}")
        if o["type"] == "choice":
            opts[k] = v
        elif v.lower() in ("null", "none") and o["type"] == "optional_int":
            opts[k] = None
        elif o["type"] == "bool" and v.lower() in ("true", "false", "1", "0", "yes", "no"):
            opts[k] = v.lower() in ("true", "1", "yes")
        else:
            try:
                opts[k] = int(v) if o["type"] in ("int", "optional_int", "int_choice") else float(v)
            except ValueError:
                raise InvalidArgumentError(f"--set {k}: expected {o['allowed']}, got {v!r}") from None
    bad = [k for k, x in opts.items() if isinstance(x, float) and x != x or x in (float("inf"), float("-inf"))]
    if bad:
        raise InvalidArgumentError(f"--set {bad[0]}: expected {schema[bad[0]]['allowed']}, got {opts[bad[0]]}")
    _native.check_options(kind, opts)
    return opts


def _check_output(flag: str, path: str, args: argparse.Namespace, extensions: Sequence[str] = (),
                  folder: bool = False) -> None:
    """Refuse an output path before any work: its folder must exist and be writable, it must not
    be a folder (or, for ``folder``, a file), its extension must be one of ``extensions``, and
    it must not be the command's input."""
    out = os.path.abspath(path)
    parent = os.path.dirname(out)
    if not os.path.isdir(parent):
        raise InvalidArgumentError(f"{flag}: {path}: the folder {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise InvalidArgumentError(f"{flag}: {path}: the folder {parent} is not writable")
    if folder:
        if os.path.exists(out) and not os.path.isdir(out):
            raise InvalidArgumentError(f"{flag}: {path} is a file; expected a folder")
        return
    if os.path.isdir(out):
        raise InvalidArgumentError(f"{flag}: {path} is a folder; expected a file name")
    if extensions and not out.lower().endswith(tuple(extensions)):
        raise InvalidArgumentError(f"{flag}: {path}: expected a file name ending in {' or '.join(extensions)}")
    src = getattr(args, "path", None)
    if src and os.path.exists(src) and (os.path.abspath(src) == out or (os.path.exists(out) and os.path.samefile(src, out))):
        raise InvalidArgumentError(f"{flag}: {path} is the input; write to another file")


def fit_command(args: argparse.Namespace) -> None:
    """``btfrs fit``: load, fit, save; print time, size and errors."""
    opts = _fit_options(args, args.model)
    _check_output("-o", args.out, args, (".btfrs",))
    btf, _ = _load_btf(args, not args.quiet)
    train, test = (btf, None) if args.holdout <= 0 else btf.split(holdout=args.holdout, seed=args.seed)
    t0 = time.perf_counter()
    model = fit_mod.fit(args.model, train, progress=not args.quiet, robust=not args.no_robust,
                        exclude_bad_images=args.exclude_bad_images, **opts)
    secs = time.perf_counter() - t0
    model.save(args.out)
    rob = model.report.get("robust")
    if rob:
        where = ", ".join(f"view {p['view']} light {p['light']}"
                          + (f" moved {p['moved'][0]}, {p['moved'][1]} texels" if "moved" in p else "")
                          for p in rob["bad_images"][:5])
        values = (f"{rob['values_flagged']} outlying values ({rob['fraction_flagged']:.4%}) "
                  f"{'replaced' if rob['values_replaced'] else 'found'}" if rob["values_flagged"]
                  else "no outlying values")
        print(f"robust: {values}"
              + (f"; {len(rob['bad_images'])} bad images ({where})"
                 + (" excluded" if rob["bad_images_excluded"] else ", kept: --exclude-bad-images leaves them out")
                 if rob["bad_images"] else "")
              + (f"; {rob['not_repaired']}" if "not_repaired" in rob else ""))
    rec = model.error(train)
    print(f"{args.model} fitted to {btf} in {secs:.2f} s: {model.nbytes / 1024:.1f} KiB as stored "
          f"(1:{btf.nbytes / max(model.nbytes, 1):.0f}), reconstruction error {rec.relative:.2%}"
          + ("" if test is None else f", held-out error {model.error(test).relative:.2%}") + f" -> {args.out}")


def export_command(args: argparse.Namespace) -> None:
    """``btfrs export``: the formats other tools read."""
    formats = [(name, getattr(args, name)) for name, _, _, _ in _formats()]
    folders = {name for name, _, _, folder in _formats() if folder}
    if not any([path for _, path in formats] + [args.exr, args.stack, args.web]):
        flags = ", ".join(f"--{name}" for name, _ in formats)
        raise InvalidArgumentError(f"export: give at least one of {flags}, --exr, --stack, --web")
    if args.single_file and not args.web:
        raise InvalidArgumentError("--single-file: only with --web")
    if not args.web:
        for dest in ("model", "coords", "layout", "layout_seed", "uv_scale"):
            if dest in args.given or (dest == "coords" and args.coords):
                raise InvalidArgumentError(f"--{dest.replace('_', '-')}: only with --web")
    if "format" in args.given and not args.stack:
        raise InvalidArgumentError("--format: only with --stack")
    for dest in ("tile_format", "tile_quality", "tile_size", "tile_overlap"):
        if dest in args.given and not args.tiles:
            raise InvalidArgumentError(f"--{dest.replace('_', '-')}: only with --tiles")
    tiled = [name for name, path in formats if path and name in folders]
    if args.tiles and not (args.web or any(n in ("relight", "neuralrti") for n in tiled)):
        raise InvalidArgumentError("--tiles: only with --web, --relight or --neuralrti")
    if args.tiles and args.single_file:
        raise InvalidArgumentError("--tiles: a tiled page fetches its tiles; it cannot be one file (--single-file)")
    tiling = dict(tile_format=args.tile_format, quality=args.tile_quality, tile_size=args.tile_size,
                  overlap=args.tile_overlap, progress=not args.quiet) if args.tiles else {}
    if args.web:
        if args.single_file:
            _check_output("--web", args.web, args, (".html",))
        else:
            _check_output("--web", args.web, args, folder=True)
        if os.path.exists(args.web) and not args.force:
            raise InvalidArgumentError(f"--web: {args.web} exists; pass --force to replace it")
    for fmt, path in formats:
        if path:
            _check_output(f"--{fmt}", path, args, (f".{fmt}",), folder=fmt in folders)
            if fmt in folders and os.path.isdir(path) and os.listdir(path) and not args.force:
                raise InvalidArgumentError(f"--{fmt}: {path} exists and is not empty; pass --force to write into it")
    if args.exr:
        _check_output("--exr", args.exr, args, (".exr",))
    if args.stack:
        _check_output("--stack", args.stack, args, folder=True)
    obj, _ = _load_sample(args, not args.quiet)
    if args.stack:
        if not isinstance(obj, Btf):
            raise InvalidArgumentError(f"--stack: {args.path} holds a {type(obj).__name__}, not a BTF")
        print(f"wrote {io.save_stack(obj, args.stack, format=args.format)}")
    if args.web:
        model, surface = _viewable(obj, args)
        if args.tiles:
            surface = {"tiled": True, "view": args.view, **tiling}
        page = web.save_web(model, args.web, single_file=args.single_file, force=args.force,
                            name=os.path.basename(os.path.normpath(args.path or "")) or model.kind, **surface)
        print(f"wrote {page}" + ("" if args.single_file else " (serve the folder over HTTP, e.g. "
                                 f"python -m http.server -d {args.web}, and open it)"))
    if args.exr or any(path for _, path in formats):
        if not isinstance(obj, Model):
            raise InvalidArgumentError(f"export: {args.path} holds a {type(obj).__name__}, not a model")
    for fmt, path in formats:
        if path:
            if fmt not in obj.exports:
                able = [k for k, info in model_kinds().items() if fmt in info["exports"]]
                raise InvalidArgumentError(f"--{fmt}: a {obj.kind} model cannot be written as .{fmt} "
                                           f"(fit --model {' or '.join(able)})")
            if args.tiles and fmt in ("relight", "neuralrti"):
                obj.export(path, format=fmt, view=args.view, force=args.force, tiled=True, **tiling)
            else:
                obj.export(path, format=fmt, view=args.view, force=args.force)
            print(f"wrote {path}")
    if args.exr:
        names = io.save_coefficients(obj, args.exr)
        print(f"wrote {args.exr}: {len(names)} channels ({names[0]} ... {names[-1]})")


def _surface_args(p: argparse.ArgumentParser, prefix: str) -> None:
    """What the viewer's surface shows besides the sample: a synthesized coordinate map, the
    layout of a tile set, the repetitions."""
    p.add_argument("--coords", metavar="FILE.npy",
                   help=prefix + "draw a synthesized texture: a [H, W, 2] uint16 coordinate map into the sample "
                   "(btfrs synth writes coords.npy)")
    p.add_argument("--layout", type=int, nargs=2, default=None, metavar=("ROWS", "COLS"),
                   help=prefix + "for a tile set (btfrs tiles writes tiles.btfrs): the Wang tiling's size "
                   "(default: 8 8)")
    p.add_argument("--layout-seed", type=int, default=None, help=prefix + "the tiling's seed (default: 0)")
    p.add_argument("--uv-scale", type=float, default=None,
                   help=prefix + "repetitions of the texture across the surface (default: 1)")
    p.set_defaults(default_layout=[8, 8], default_layout_seed=0, default_uv_scale=1.0)


def _viewable(obj: Any, args: argparse.Namespace) -> Tuple[Model, Dict[str, Any]]:
    """A model for the viewer and what its surface shows (``btfrs.web.save_web``'s keywords):
    the model itself, a quick ``--model`` fit of a BTF, or a tile set's model with a tiling."""
    surface: Dict[str, Any] = {"uv_scale": args.uv_scale}
    if args.coords:
        if isinstance(obj, tiles.TileSet):
            raise InvalidArgumentError("--coords: a tile set draws its own tiling (--layout), not a coordinate map")
        surface["coords"] = io.load_array(args.coords)
    if not isinstance(obj, tiles.TileSet):
        for dest in ("layout", "layout_seed"):
            if dest in args.given:
                raise InvalidArgumentError(f"--{dest.replace('_', '-')}: only applies to a tile set (btfrs tiles "
                                           f"writes tiles.btfrs); {args.path or 'the input'} holds a "
                                           f"{type(obj).__name__}")
    if "model" in args.given and not isinstance(obj, Btf):
        raise InvalidArgumentError(f"--model: only applies to a BTF or capture (fitted first); "
                                   f"{args.path or 'the input'} holds a {type(obj).__name__}")
    if isinstance(obj, tiles.TileSet):
        if obj.model is None:
            raise InvalidArgumentError(f"path: {args.path} is a tile set of an image or a raw BTF; the viewer draws "
                                       "tile sets made in a model's domain (btfrs tiles --model KIND)")
        rows, cols = args.layout
        surface.update(tiles=obj, layout=obj.tiling(rows, cols, seed=args.layout_seed))
        return obj.model, surface
    if isinstance(obj, Model):
        return obj, surface
    if isinstance(obj, Btf):
        # A tiled page is written in the model's export formats: fit what they can hold.
        opts: Dict[str, Any] = dict(model_kinds()[args.model]["export_options"]) if args.tiles else {}
        if not args.quiet:
            print(f"fitting a {args.model} model for the viewer (--model to choose another) ...", flush=True)
        return fit_mod.fit(args.model, obj, **opts), surface
    raise InvalidArgumentError(f"path: {args.path} holds a {type(obj).__name__}; the viewer shows fitted models, "
                               f"BTFs, captures and tile sets")


def normals_command(args: argparse.Namespace) -> None:
    """``btfrs normals``: photometric stereo, its maps and the integrated height; for a built-in
    material, the angular error against its true normals."""
    _check_output("--out", args.out, args, folder=True)
    if os.path.exists(args.out) and os.listdir(args.out) and not args.force:
        raise InvalidArgumentError(f"--out: {args.out} exists and is not empty; pass --force to write into it")
    btf, name = _load_btf(args, not args.quiet)
    maps = photometric.normals(btf, args.view, method=args.method, progress=not args.quiet)
    written = list(maps.save(args.out).values())
    line = (f"{args.method} photometric stereo of {name}, view slot {args.view} ({btf.n_lights} lights): "
            f"{btf.height} x {btf.width} normals")
    if maps.dark_texels:
        line += f", {maps.dark_texels} texels black under every light (normal (0, 0, 1))"
    if args.height != "none":
        z = photometric.height(maps, method=args.height)
        for ext in (".exr", ".png"):
            path = os.path.join(args.out, "height" + ext)
            step = photometric.save_height(path, z)
            written.append(path)
        line += f"; height ({args.height}) from {float(z.min()):.3g} to {float(z.max()):.3g} texels (PNG step {step:.3g})"
    print(line)
    if not args.path and args.material:
        # A built-in material: its true surface is known.
        truth = materials.heightfield(args.material, size=args.size, seed=args.material_seed)
        err = maps.angular_error(truth.normals)
        print(f"against the true normals of {args.material}: mean {err.mean():.2f} degrees, "
              f"median {np.median(err):.2f}, 95th percentile {np.percentile(err, 95):.2f}")
    print("wrote " + ", ".join(written))


def view_command(args: argparse.Namespace) -> None:
    """``btfrs view``: export the viewer to a temporary folder, serve it on localhost and open a
    browser (or print the address), until Ctrl-C."""
    if not 0 <= args.port <= 65535:
        raise InvalidArgumentError(f"--port: expected 0 to 65535, got {args.port}")
    obj, name = _load_sample(args, not args.quiet)
    model, surface = _viewable(obj, args)
    with tempfile.TemporaryDirectory(prefix="btfrs-view-") as tmp:
        folder = os.path.join(tmp, "site")
        web.save_web(model, folder, name=name, **surface)

        class Handler(http.server.SimpleHTTPRequestHandler):
            def __init__(self, *a: Any, **k: Any) -> None:
                super().__init__(*a, directory=folder, **k)

            def log_message(self, format: str, *a: Any) -> None:  # quiet: one line per request is noise
                pass

        try:
            server = http.server.ThreadingHTTPServer(("127.0.0.1", args.port), Handler)
        except OSError as e:
            server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
            print(f"port {args.port} is not available ({e.strerror or e}); using port {server.server_address[1]}")
        url = f"http://127.0.0.1:{server.server_address[1]}/"
        print(f"serving the {model.kind} model of {name} at {url} (Ctrl-C to stop)", flush=True)
        if not args.no_browser:
            webbrowser.open_new_tab(url)
        try:
            server.serve_forever()
        finally:
            server.server_close()


def render_command(args: argparse.Namespace) -> None:
    """``btfrs render``: one image of a model, BTF or capture."""
    _check_output("-o", args.out, args, (".png", ".exr"))
    obj, _ = _load_sample(args, not args.quiet)
    if not isinstance(obj, (Model, Btf)):
        raise InvalidArgumentError(f"path: {args.path} holds a {type(obj).__name__}, not a model or BTF")
    scene = {"plane": lambda: rendering.Scene.plane(2.0), "sphere": rendering.Scene.sphere,
             "cylinder": rendering.Scene.cylinder}[args.scene]()
    eye = args.camera or ([0.0, -0.01, 3.2] if args.scene == "plane" else [0.0, -3.0, 2.0])
    cam = rendering.Camera.look_at(eye, [0, 0, 0], args.fov)
    lights = [rendering.DirectionalLight(l) for l in (args.light or [[0.3, 0.2, 0.93]])]
    img = rendering.render(obj, scene, cam, lights, size=tuple(args.image_size), uv_scale=args.uv_scale,
                           backend=args.backend, renderer=args.renderer)
    io.save_image(args.out, img, exposure=args.exposure)
    print(f"wrote {args.out} ({args.image_size[0]} x {args.image_size[1]}, mean {float(np.mean(img)):.4f})")


def _calibrate_args(sub: "argparse._SubParsersAction[_Parser]") -> None:
    c = sub.add_parser("calibrate", help="the light directions of photographs with a glossy sphere in the frame: an "
                                         ".lp file")
    c.add_argument("photos", nargs="+", metavar="PHOTOS",
                   help="a folder of photographs (every JPEG, PNG, TIFF, EXR in it, by name), or the photographs")
    c.add_argument("-o", "--out", required=True, help="the .lp file to write (e.g. PHOTOS/dirs.lp)")
    c.add_argument("--sphere", type=float, nargs=3, metavar=("CX", "CY", "R"),
                   help="the sphere's circle in pixels, x right and y down from the image's top-left corner "
                        "(default: found, as the darkest round region)")
    g = c.add_mutually_exclusive_group()
    g.add_argument("--fov", type=float, help="the camera's horizontal field of view in degrees, for a perspective "
                                             "correction (default: an orthographic camera)")
    g.add_argument("--focal", type=float, help="the camera's 35 mm-equivalent focal length in mm, for a perspective "
                                               "correction")
    c.add_argument("--white", type=int, nargs=4, metavar=("ROW", "COL", "ROWS", "COLS"),
                   help="a white matte target in the frame: each light's relative intensity, written to --report")
    c.add_argument("--report", metavar="FILE.json",
                   help="write everything found as JSON: sphere, camera, per photograph its highlight, light, status "
                        "and intensity")
    c.add_argument("--figure", metavar="FILE.png",
                   help="a picture of the sphere and the highlights on the first photograph, and the lights from above")
    c.add_argument("--linear", action="store_true", help="8- and 16-bit values are linear (TIFF from RAW), not sRGB")
    c.add_argument("--quiet", action="store_true", help="no progress bar")


def calibrate_command(args: argparse.Namespace) -> None:
    """``btfrs calibrate``: find the lights from the sphere, write the .lp (and the report, the
    picture); photographs left out are named on stderr."""
    _check_output("-o", args.out, args, (".lp",))
    if args.report:
        _check_output("--report", args.report, args, (".json",))
    if args.figure:
        _check_output("--figure", args.figure, args, (".png",))
    if args.white and not args.report:
        raise InvalidArgumentError("--white: the intensities go into the report; give --report FILE.json too")
    photos = args.photos[0] if len(args.photos) == 1 and os.path.isdir(args.photos[0]) else list(args.photos)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        cal = calibration.calibrate(photos, args.sphere, fov=args.fov, focal=args.focal, white=args.white,
                                    linear=args.linear, progress=not args.quiet)
        cal.save(args.out)
    for w in caught:
        print(f"btfrs: warning: {w.message}", file=sys.stderr)
    written = [args.out]
    if args.report:
        written.append(cal.save_report(args.report))
    if args.figure:
        written.append(cal.figure(args.figure))
    cx, cy, r = cal.sphere
    sph = cal.report["sphere"]
    how = (f"found at ({cx:.1f}, {cy:.1f}), radius {r:.1f} px, outline fitted to {sph['edge_rms_px']:.2f} px rms"
           if sph["detected"] else f"given at ({cx:.1f}, {cy:.1f}), radius {r:.1f} px")
    cam = cal.report["camera"]
    camera = "orthographic" if cam["projection"] == "orthographic" else f"perspective, focal {cam['focal_px']:.0f} px"
    elev = np.degrees(np.arcsin(np.clip(cal.lights[:, 2], -1, 1)))
    print(f"calibrated {len(cal.calibrated)} of {len(cal.images)} photographs ({camera} camera; sphere {how}); "
          f"light elevations {elev.min():.1f} to {elev.max():.1f} degrees")
    print("wrote " + ", ".join(written))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
