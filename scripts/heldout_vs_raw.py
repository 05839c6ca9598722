"""Held-out error of the light-basis models against the raw-data baseline on every built-in
material: 10% of the pairs held out (seed 0), the raw data's prediction the inverse-angle
weighted mean of the 3 nearest present lights of the same view slot
(``btfrs.tools.baselines.nearest_lights_interpolation``, which stores the whole BTF), each
model's size ratio to the float32 BTF beside its error.
Usage: python scripts/heldout_vs_raw.py [SIZE]   (default 64)"""
import sys

from btfrs import fit, materials
from btfrs.tools import baselines

MODELS = [("rbf", {"components": 18}, "RBF-18"), ("rbf", {"components": 27}, "RBF-27"),
          ("bilinear", {"components": 18}, "Bilinear-18"), ("bilinear", {"components": 27}, "Bilinear-27"),
          ("hsh", {"order": 4}, "HSH-4")]

size = int(sys.argv[1]) if len(sys.argv) > 1 else 64
for name in materials.names():
    btf = materials.make(name, size=size, seed=1)
    train, test = btf.split(holdout=0.1, seed=0)
    raw, _ = baselines.nearest_lights_interpolation(train, test)
    cells = [f"{name:<8} raw {100 * raw:.2f}%"]
    best = None
    for kind, opts, label in MODELS:
        m = fit.fit(kind, train, **opts)
        err, ratio = m.error(test).relative, btf.nbytes / m.nbytes
        cells.append(f"{label} {100 * err:.2f}% (1:{ratio:.0f})")
        if ratio >= 10 and (best is None or err < best[0]):
            best = (err, label)
    verdict = f"best at >= 1:10: {best[1]}, {'below' if best[0] < raw else 'not below'} raw"
    print("  ".join(cells) + "  | " + verdict, flush=True)
