"""btfrs vs scipy LM on the bench window (knit 64^2, row 32, the first N texels, default 64): wall and
process CPU time per texel, both sides back to back. Usage: python scripts/lafortune_vs_scipy.py [N]"""
import sys
import time

from btfrs import fit, materials
from btfrs.tools import baselines

size = 64
n = int(sys.argv[1]) if len(sys.argv) > 1 else 64
btf = materials.make("knit", size=size, seed=1)
train, test = btf.split(holdout=0.1, seed=0)
w = slice(size // 2, size // 2 + 1), slice(0, n)
tr, te = baselines.crop(train, *w), baselines.crop(test, *w)
fit.lafortune(tr, kind="lum", lobes=2, robust=False)  # warm-up (pool start)
res = {}
def timed(f):
    w0, c0 = time.perf_counter(), time.process_time()
    r = f()
    return r, (time.perf_counter() - w0) / n, (time.process_time() - c0) / n
for rep in range(2):
    ours, ow, oc = timed(lambda: fit.lafortune(tr, kind="lum", lobes=2, robust=False))
    print(f"[{rep}] {n} texels btfrs: wall {ow*1e3:.3f} cpu {oc*1e3:.3f} ms/texel held {ours.error(te).relative:.5f} rec {ours.error(tr).relative:.5f} {dict((k, v) for k, v in ours.report.items() if k != 'robust')}", flush=True)
    for jac in ("2-point", "analytic"):
        r, sw, sc = timed(lambda: baselines.lafortune_scipy(tr, te, lobes=2, jac=jac))
        print(f"    scipy {jac}: wall {sw*1e3:.2f} cpu {sc*1e3:.2f} ms/texel held {r['held_out']:.5f} rec {r['reconstruction']:.5f} -> wall {sw/ow:.1f}x cpu {sc/oc:.1f}x", flush=True)
