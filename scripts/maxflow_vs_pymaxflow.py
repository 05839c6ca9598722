"""btfrs.graphcut against PyMaxflow (Kolmogorov's own BK implementation, wrapped) on the integer
grids of ``python -m btfrs.tools.bench --maxflow-only``, the same run: wall time, best of 3, the
graph's construction timed on both sides. PyMaxflow is a measurement peer only (GPL; not a
btfrs dependency): ``pip install PyMaxflow`` first. Usage: python scripts/maxflow_vs_pymaxflow.py"""

import sys
import time

import numpy as np

import maxflow  # PyMaxflow

from btfrs import graphcut
from btfrs.tools.bench import maxflow_problems


def pymaxflow(right, down, term):
    """The grid as PyMaxflow builds it: each direction of each edge with its own capacity."""
    n = term.shape[0]
    g = maxflow.Graph[int]()
    nodes = g.add_grid_nodes((n, n))
    pad = np.zeros((n, n), np.int64)

    def edges(w, struct):
        g.add_grid_edges(nodes, weights=w, structure=np.array(struct), symmetric=False)

    r0, r1, d0, d1 = pad.copy(), pad.copy(), pad.copy(), pad.copy()
    r0[:, :-1], r1[:, 1:] = right[..., 0], right[..., 1]  # p -> right neighbour; right neighbour -> p
    d0[:-1], d1[1:] = down[..., 0], down[..., 1]
    edges(r0, [[0, 0, 0], [0, 0, 1], [0, 0, 0]])
    edges(r1, [[0, 0, 0], [1, 0, 0], [0, 0, 0]])
    edges(d0, [[0, 0, 0], [0, 0, 0], [0, 1, 0]])
    edges(d1, [[0, 1, 0], [0, 0, 0], [0, 0, 0]])
    g.add_grid_tedges(nodes, term[..., 0], term[..., 1])
    return g, nodes


def best(f, repeat=3):
    out, t = None, 1e9
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = f()
        t = min(t, time.perf_counter() - t0)
    return t, out


for n in (256, 512):
    for case, (right, down, term) in maxflow_problems(n).items():
        t_ours, (flow, side) = best(lambda: graphcut.grid_min_cut(right, down, term))

        def peer():
            g, nodes = pymaxflow(right, down, term)
            return g.maxflow(), g, nodes

        t_peer, (pflow, g, nodes) = best(peer)
        g, _ = pymaxflow(right, down, term)
        t0 = time.perf_counter()
        g.maxflow()
        t_solve = time.perf_counter() - t0
        if flow != pflow:
            sys.exit(f"{case} {n}^2: btfrs flow {flow}, PyMaxflow {pflow}")
        print(f"{case:<13} {n:>5}^2 flow {flow:>11}  btfrs {t_ours:.3f} s  PyMaxflow {t_peer:.3f} s "
              f"(its solve alone {t_solve:.3f} s)  PyMaxflow / btfrs {t_peer / t_ours:.2f}x", flush=True)
