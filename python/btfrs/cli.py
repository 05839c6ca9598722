"""The ``btfrs`` command line."""

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
    args = p.parse_args(argv)

    from .exceptions import BtfrsError

    try:
        if args.command == "demo":
            from . import demo

            demo.run(args.out, material=args.material, size=args.size, seed=args.seed, progress=not args.quiet)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except (BtfrsError, OSError) as e:
        print(f"btfrs: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
