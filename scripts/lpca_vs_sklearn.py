"""btfrs's local PCA against scikit-learn's KMeans + PCA per cluster (the way of
``btfrs.tools.baselines.lpca_sklearn``) on the same training split: knit 64^2 x 81 x 81, 10% of
the pairs held out (seed 0), 32 clusters of 4 and of 8 components. btfrs best of 3 with its
defaults (the robust screen included), scikit-learn best of N (default 1), in the same run; the
held-out error of btfrs and the reconstruction error of both.
Usage: python scripts/lpca_vs_sklearn.py [N]"""
import sys
import time

from btfrs import fit, materials
from btfrs.tools import baselines

repeat = int(sys.argv[1]) if len(sys.argv) > 1 else 1
btf = materials.make("knit", size=64, seed=1)
train, test = btf.split(holdout=0.1, seed=0)
fit.lpca(train, clusters=8, components=1)  # warm-up (thread pool, first allocations)
for c in (4, 8):
    ours = float("inf")
    for _ in range(3):
        t0 = time.perf_counter()
        m = fit.lpca(train, clusters=32, components=c)
        ours = min(ours, time.perf_counter() - t0)
    sk = [baselines.lpca_sklearn(train, clusters=32, components=c, seed=0) for _ in range(repeat)]
    sk_s = min(r["seconds"] for r in sk)
    print(f"LPCA 32x{c}: btfrs {ours:.3f} s (held-out {100 * m.error(test).relative:.2f}%, reconstruction "
          f"{100 * m.error(train).relative:.2f}%), scikit-learn {sk_s:.2f} s (reconstruction "
          f"{100 * sk[0]['reconstruction']:.2f}%): {sk_s / ours:.1f}x", flush=True)
