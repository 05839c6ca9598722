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
    args = p.parse_args(argv)

    from .exceptions import BtfrsError

    try:
        if args.command == "demo":
            from . import demo

            demo.run(args.out, material=args.material, size=args.size, seed=args.seed, progress=not args.quiet)
        elif args.command == "synth":
            synth_command(args)
        elif args.command == "stability":
            stability_command(args)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except (BtfrsError, OSError) as e:
        print(f"btfrs: error: {e}", file=sys.stderr)
        return 2
    return 0


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
