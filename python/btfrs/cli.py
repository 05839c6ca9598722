"""The ``btfrs`` command line.

Sizes of images and maps are given as numpy shapes give them, height first (``--out-size H W``);
every file is written atomically (see :func:`btfrs.io.atomic_write`). Progress goes to stderr:
bars on a terminal, one line per phase otherwise.
"""

from __future__ import annotations

import argparse
import sys
from typing import Optional, Sequence

from . import __version__


def main(argv: Optional[Sequence[str]] = None) -> int:
    p = argparse.ArgumentParser(prog="btfrs", description="Fit, synthesize and render BTFs.")
    p.add_argument("--version", action="version", version=f"btfrs {__version__}")
    sub = p.add_subparsers(dest="command", required=True)
    d = sub.add_parser("demo", help="the main job on a built-in material: fit, compare, summarise")
    d.add_argument("--out", default="demo", help="output folder (default: demo)")
    d.add_argument("--material", default="knit", help="built-in material (default: knit)")
    d.add_argument("--size", type=int, default=64, help="texels per side (default: 64)")
    d.add_argument("--seed", type=int, default=1, help="material seed (default: 1)")
    d.add_argument("--quiet", action="store_true", help="no progress bars")
    s = sub.add_parser("synth", help="synthesize a large BTF (or RGB texture) as a coordinate map")
    src = s.add_mutually_exclusive_group()
    src.add_argument("--material", default="knit", help="built-in material as the sample (default: knit)")
    src.add_argument("--texture", help="an RGB image (.png or .exr) as the sample instead")
    src.add_argument("--btf", help="a .btfrs BTF file as the sample instead")
    s.add_argument("--size", type=int, default=64, help="material sample texels per side (default: 64)")
    s.add_argument("--material-seed", type=int, default=1, help="material seed (default: 1)")
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
    s.add_argument("--quiet", action="store_true", help="no progress bars")
    e = sub.add_parser("evaluate", help="speed against accuracy of every model on one material: table + charts")
    _material_args(e, default="weave")
    e.add_argument("--models", default="all", help="'all' or a comma-separated list of model names (default: all)")
    e.add_argument("--holdout", choices=["pairs", "directions", "both"], default="both",
                   help="held-out protocol: random pairs, whole directions, or both (default: both)")
    e.add_argument("--fraction", type=float, default=0.1, help="share held out (default: 0.1)")
    e.add_argument("--sweep", choices=["full", "quick"], default="full", help="parameter sweep (default: full)")
    e.add_argument("--no-baselines", action="store_true", help="leave out the numpy / scipy / scikit-learn rows")
    e.add_argument("--no-render", action="store_true", help="leave out render ms and scene PSNR")
    e.add_argument("--eval-seed", type=int, default=0, help="seed of the splits and of seeded fits (default: 0)")
    e.add_argument("--out", default="evaluate", help="output folder (default: evaluate)")
    e.add_argument("--quiet", action="store_true", help="no progress bars")
    c = sub.add_parser("choose", help="the cheapest model that meets a tolerance on a scene's own directions")
    csrc = c.add_mutually_exclusive_group()
    csrc.add_argument("--material", default="weave", help="built-in material (default: weave)")
    csrc.add_argument("--btf", help="a .btfrs BTF file instead")
    c.add_argument("--size", type=int, default=32, help="material texels per side (default: 32)")
    c.add_argument("--material-seed", type=int, default=1, help="material seed (default: 1)")
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
    c.add_argument("--budget-bytes", type=int, help="largest model size in bytes")
    c.add_argument("--budget-ms", type=float, help="largest render time in ms")
    c.add_argument("--samples", type=int, default=256, help="(view, light) pairs scored (default: 256)")
    c.add_argument("--kinds", nargs="+", metavar="KIND",
                   help="only these candidates: registered model kinds and/or raw (default: all)")
    c.add_argument("--no-render", action="store_true", help="do not time the renders")
    c.add_argument("--seed", type=int, default=0, help="sampling seed (default: 0)")
    c.add_argument("--quiet", action="store_true", help="no progress bars")
    st = sub.add_parser("stability", help="every model in the regimes where methods fail: error curves, flags, charts")
    st.add_argument("--material", default="grooves", help="built-in material (default: grooves)")
    st.add_argument("--btf", help="a .btfrs BTF file instead of a built-in material")
    st.add_argument("--size", type=int, default=16, help="material texels per side (default: 16)")
    st.add_argument("--material-seed", type=int, default=0, help="material seed (default: 0)")
    st.add_argument("--seed", type=int, default=0, help="seed of the regimes: splits, noise, texels (default: 0)")
    st.add_argument("--models", nargs="+", default=None, help="model kinds (default: one cheap setting of each)")
    st.add_argument("--regimes", nargs="+", default=None, help="regimes (default: all)")
    st.add_argument("--out", default="stability", help="output folder (default: stability)")
    st.add_argument("--quiet", action="store_true", help="no progress bars")
    t = sub.add_parser("tiles", help="a graph-cut Wang tile set (paper 002): tiles, their picture, a rendered tiling")
    tsrc = t.add_mutually_exclusive_group()
    tsrc.add_argument("--material", default="bumps", help="built-in material (default: bumps)")
    tsrc.add_argument("--btf", help="a .btfrs BTF file instead")
    tsrc.add_argument("--texture", help="an RGB image (.png or .exr) instead: an RGB tile set")
    t.add_argument("--size", type=int, default=128, help="material texels per side (default: 128)")
    t.add_argument("--material-seed", type=int, default=3, help="material seed (default: 3)")
    t.add_argument("--model", default="sh",
                   help="the model whose domain the tiles are synthesized in (any registered kind, or raw; default: sh)")
    t.add_argument("--options", default=None,
                   help='fit options as JSON (default for sh: {"light_coeffs": 16, "view_coeffs": 16}; '
                        'lpca: {"clusters": 32, "components": 4})')
    t.add_argument("--tile", type=int, default=64, help="tile side in texels (default: 64)")
    t.add_argument("--edge-height", type=int, default=16, help="edge height h (default: 16)")
    t.add_argument("--colors", type=int, default=2, help="colours per edge direction (default: 2: 16 tiles)")
    t.add_argument("--layout", type=int, nargs=2, default=[3, 10], metavar=("ROWS", "COLS"),
                   help="the tiling rendered on a cylinder, columns around it (default: 3 10)")
    t.add_argument("--seed", type=int, default=5, help="synthesis and tiling seed (default: 5)")
    t.add_argument("--out", default="tiles", help="output folder (default: tiles)")
    t.add_argument("--quiet", action="store_true", help="no progress bars")
    args = p.parse_args(argv)

    from .exceptions import BtfrsError

    try:
        if args.command == "demo":
            from . import demo

            demo.run(args.out, material=args.material, size=args.size, seed=args.seed, progress=not args.quiet)
        elif args.command == "synth":
            synth_command(args)
        elif args.command == "evaluate":
            evaluate_command(args)
        elif args.command == "choose":
            choose_command(args)
        elif args.command == "stability":
            stability_command(args)
        elif args.command == "tiles":
            tiles_command(args)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except (BtfrsError, OSError) as e:
        print(f"btfrs: error: {e}", file=sys.stderr)
        return 2
    return 0


def _material_args(p: argparse.ArgumentParser, default: str) -> None:
    """``--material NAME --size N --seed S`` or ``--btf FILE``: the sample a command works on."""
    src = p.add_mutually_exclusive_group()
    src.add_argument("--material", default=default, help=f"built-in material (default: {default})")
    src.add_argument("--btf", help="a .btfrs BTF file instead")
    p.add_argument("--size", type=int, default=32, help="material texels per side (default: 32)")
    p.add_argument("--seed", type=int, default=1, help="material seed (default: 1)")


def _load_sample(args, progress: bool):
    """The Btf of :func:`_material_args` and its name."""
    import os

    from . import materials
    from .btf import Btf

    if args.btf:
        return Btf.load(args.btf), os.path.basename(args.btf)
    return materials.make(args.material, size=args.size, seed=args.seed, progress=progress), args.material


#: Fit options of ``btfrs tiles`` when ``--options`` is not given.
TILE_MODEL_DEFAULTS = {"sh": {"light_coeffs": 16, "view_coeffs": 16}, "lpca": {"clusters": 32, "components": 4}}


def tiles_command(args) -> None:
    """``btfrs tiles``: fit (or read) the sample, synthesize a Wang tile set in its domain, write
    the set, a picture of the tiles with their edge colours, a tiling and its rendering."""
    import json
    import os

    import numpy as np

    from . import fit as fitting
    from . import io, tiles
    from .btf import Btf
    from .rendering import Camera, PointLight, Scene, render

    progress = not args.quiet
    os.makedirs(args.out, exist_ok=True)
    written = []
    if args.texture:
        sample = io.load_image(args.texture)
        name, model = os.path.basename(args.texture), None
        source = sample
    else:
        btf = Btf.load(args.btf) if args.btf else None
        if btf is None:
            from . import materials

            btf = materials.make(args.material, size=args.size, seed=args.material_seed, progress=progress)
        name = os.path.basename(args.btf) if args.btf else args.material
        if args.model == "raw":
            model, source = btf, btf
        else:
            opts = json.loads(args.options) if args.options else TILE_MODEL_DEFAULTS.get(args.model, {})
            model = fitting.fit(args.model, btf, progress=progress, **opts)
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


def evaluate_command(args) -> None:
    """``btfrs evaluate``: :func:`btfrs.evaluate` on a material, the table on stdout, the report
    and charts in ``--out``."""
    from .evaluation import evaluate

    progress = not args.quiet
    btf, name = _load_sample(args, progress)
    models = args.models if args.models == "all" else [m.strip() for m in args.models.split(",") if m.strip()]
    rep = evaluate(btf, models, holdout=args.holdout, fraction=args.fraction, sweep=args.sweep,
                   baselines=False if args.no_baselines else None, render=not args.no_render, seed=args.eval_seed,
                   material=name, progress=progress)
    print(rep.summary())
    print()
    print(rep.table())
    paths = rep.save(args.out)
    print(f"\nwrote {', '.join(paths)}")


def synth_command(args) -> None:
    """``btfrs synth``: analyse (or load the analysis), synthesize, save the map and pictures."""
    import os

    import numpy as np

    from . import io, materials, synth
    from .btf import Btf

    progress = not args.quiet
    os.makedirs(args.out, exist_ok=True)
    if args.texture:
        sample = io.load_image(args.texture)
    elif args.btf:
        sample = Btf.load(args.btf)
    else:
        sample = materials.make(args.material, size=args.size, seed=args.material_seed, progress=progress)
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


def choose_command(args) -> None:
    """``btfrs choose``: what a scene needs of a material, and the cheapest model that gives it."""
    from . import materials
    from .btf import Btf
    from .choosing import SceneUse, choose
    from .exceptions import InvalidArgumentError
    from .rendering import Camera, DirectionalLight, Scene

    progress = not args.quiet
    btf = Btf.load(args.btf) if args.btf else materials.make(args.material, size=args.size, seed=args.material_seed,
                                                              progress=progress)
    cams = [Camera.look_at(eye, [0.0, 0.0, 0.0], args.fov) for eye in (args.camera or [[0.0, 0.0, 3.0]])]
    lights = [[DirectionalLight(d, 1.0)] for d in (args.light or [[0.3, -0.2, 1.0]])]
    surface = Scene.sphere() if args.scene == "sphere" else Scene.plane()
    use = SceneUse(camera=cams, lights=lights, size=tuple(args.image_size), scene=surface, uv_scale=args.uv_scale)
    cands = None
    if args.kinds:
        from .choosing import default_candidates

        known = default_candidates()
        cands = [c for c in known if c[0] in args.kinds]
        unknown = sorted(set(args.kinds) - {c[0] for c in known})
        if unknown:
            raise InvalidArgumentError(f"--kinds: unknown {', '.join(unknown)}; expected some of "
                                       f"{', '.join(sorted({c[0] for c in known}))}")
    pick = choose(btf, scene=use, tolerance=args.tolerance, budget_bytes=args.budget_bytes, budget_ms=args.budget_ms,
                  candidates=cands, samples=args.samples, measure_render=not args.no_render, seed=args.seed,
                  progress=progress)
    print(pick.explain())
def stability_command(args) -> None:
    """``btfrs stability``: run every model in every regime, write report.json, report.md and
    one chart per regime, print the table."""
    from . import materials, stability
    from .btf import Btf

    progress = not args.quiet
    if args.btf:
        btf, name = Btf.load(args.btf), args.btf
    else:
        btf = materials.make(args.material, size=args.size, seed=args.material_seed, progress=progress)
        name = f"{args.material} {args.size}x{args.size}, seed {args.material_seed}"
    rep = stability.run(btf, models=args.models or "all", regimes=args.regimes or "all", seed=args.seed,
                        progress=progress, name=name)
    paths = rep.save(args.out)
    print(rep.table())
    print(f"wrote {len(paths)} files to {args.out}/ (report.json, report.md, one chart per regime)")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
