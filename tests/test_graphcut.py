"""btfrs.graphcut against scipy's maximum_flow (integer grids), brute force (tiny graphs), its own
cut capacities, the grid path against the general path, and every bad-input error."""

import itertools

import numpy as np
import pytest
import scipy.sparse
from scipy.sparse.csgraph import maximum_flow

import btfrs
from btfrs import graphcut
from btfrs.exceptions import ArgumentTypeError, InvalidArgumentError


def random_grid(rng, h, w, high=50, dtype=np.int64):
    right = rng.integers(0, high, size=(h, w - 1, 2)).astype(dtype)
    down = rng.integers(0, high, size=(h - 1, w, 2)).astype(dtype)
    term = rng.integers(0, high, size=(h, w, 2)).astype(dtype)
    term[rng.random((h, w)) < 0.6, 0] = 0
    term[rng.random((h, w)) < 0.6, 1] = 0
    return right, down, term


def grid_edges(right, down):
    """The grid as a general edge list and [E, 2] capacities."""
    h, w = right.shape[0], down.shape[1]
    ids = np.arange(h * w).reshape(h, w)
    edges = np.concatenate([np.stack([ids[:, :-1].ravel(), ids[:, 1:].ravel()], 1),
                            np.stack([ids[:-1, :].ravel(), ids[1:, :].ravel()], 1)])
    caps = np.concatenate([right.reshape(-1, 2), down.reshape(-1, 2)])
    return edges, caps


def cut_capacity(edges, caps, term, side):
    side = np.asarray(side).ravel()
    term = np.asarray(term).reshape(-1, 2)
    a, b = edges[:, 0], edges[:, 1]
    c = caps[:, 0][side[a] & ~side[b]].sum() + caps[:, 1][side[b] & ~side[a]].sum()
    return c + term[~side, 0].sum() + term[side, 1].sum()


def scipy_flow(n, edges, caps, term):
    """scipy.sparse.csgraph.maximum_flow on the graph with source n and sink n + 1."""
    src, snk = n, n + 1
    rows = np.concatenate([edges[:, 0], edges[:, 1], np.full(n, src), np.arange(n)])
    cols = np.concatenate([edges[:, 1], edges[:, 0], np.arange(n), np.full(n, snk)])
    data = np.concatenate([caps[:, 0], caps[:, 1], term[:, 0], term[:, 1]]).astype(np.int32)
    keep = data > 0
    m = scipy.sparse.csr_matrix((data[keep], (rows[keep], cols[keep])), shape=(n + 2, n + 2))
    m.sum_duplicates()
    return int(maximum_flow(m, src, snk).flow_value)


@pytest.mark.parametrize("seed", range(6))
def test_flow_matches_scipy_on_random_grids(seed):
    rng = np.random.default_rng(seed)
    h, w = int(rng.integers(2, 40)), int(rng.integers(2, 40))
    right, down, term = random_grid(rng, h, w)
    edges, caps = grid_edges(right, down)
    want = scipy_flow(h * w, edges, caps, term.reshape(-1, 2))
    flow, side = graphcut.min_cut(h * w, edges, caps, term.reshape(-1, 2))
    assert isinstance(flow, int) and flow == want
    assert side.dtype == np.bool_ and side.shape == (h * w,)
    assert cut_capacity(edges, caps, term, side) == flow
    gflow, gside = graphcut.grid_min_cut(right, down, term)
    assert gflow == flow and gside.shape == (h, w)
    # the residual-reachable set is the same for every maximum flow
    np.testing.assert_array_equal(gside.ravel(), side)


def test_brute_force_on_tiny_graphs():
    rng = np.random.default_rng(7)
    for _ in range(60):
        n = int(rng.integers(1, 8))
        m = int(rng.integers(0, 3 * n))
        a = rng.integers(0, n, m)
        b = (a + rng.integers(1, n, m)) % n if n > 1 else a
        edges = np.stack([a, b], 1) if n > 1 else np.zeros((0, 2), np.int64)
        caps = rng.random((len(edges), 2)) * 3
        term = rng.random((n, 2)) * 3 * (rng.random((n, 2)) < 0.5)
        best = min(cut_capacity(edges, caps, term, np.array(s, bool))
                   for s in itertools.product([False, True], repeat=n))
        flow, side = graphcut.min_cut(n, edges, caps, term)
        assert isinstance(flow, float)
        assert flow == pytest.approx(best, rel=1e-9, abs=1e-12)
        assert cut_capacity(edges, caps, term, side) == pytest.approx(best, rel=1e-9, abs=1e-12)


def test_float_grid_equals_general_and_cut_equals_flow():
    rng = np.random.default_rng(3)
    right, down, term = (x.astype(np.float64) / 7 for x in random_grid(rng, 30, 25))
    edges, caps = grid_edges(right, down)
    flow, side = graphcut.min_cut(30 * 25, edges, caps, term.reshape(-1, 2))
    gflow, gside = graphcut.grid_min_cut(right, down, term)
    assert gflow == pytest.approx(flow, rel=1e-12)
    assert cut_capacity(edges, caps, term, gside) == pytest.approx(gflow, rel=1e-12)
    # float32 in, float32 path (rounding of f32)
    f32, s32 = graphcut.grid_min_cut(right.astype(np.float32), down.astype(np.float32), term.astype(np.float32))
    assert isinstance(f32, float) and f32 == pytest.approx(flow, rel=1e-4)


def test_one_dimensional_capacities_and_small_cases():
    # s -5-> 0 -3-> 1 -4-> t, capacities the same both ways
    flow, side = graphcut.min_cut(2, [[0, 1]], [3], [[5, 0], [0, 4]])
    assert flow == 3 and side.tolist() == [True, False]
    flow, side = graphcut.min_cut(0, np.zeros((0, 2), int), [], np.zeros((0, 2)))
    assert flow == 0 and side.shape == (0,)
    flow, side = graphcut.min_cut(3, [], [], [[1, 0], [0, 0], [0, 2]])
    assert flow == 0 and side.tolist() == [True, False, False]
    # 1 x 1 and 1 x W grids
    flow, side = graphcut.grid_min_cut(np.zeros((1, 0, 2), int), np.zeros((0, 1, 2), int), [[[3, 2]]])
    assert flow == 2 and side.tolist() == [[True]]
    flow, side = graphcut.grid_min_cut([[[2, 0], [1, 0]]], np.zeros((0, 3, 2), int), [[[9, 0], [0, 0], [0, 9]]])
    assert flow == 1 and side.tolist() == [[True, True, False]]
    assert btfrs.graphcut is graphcut


@pytest.mark.parametrize("call, exc, words", [
    (lambda: graphcut.min_cut(-1, [], [], []), InvalidArgumentError, "n:"),
    (lambda: graphcut.min_cut(2.0, [[0, 1]], [1], [[0, 0], [0, 0]]), ArgumentTypeError, "n:"),
    (lambda: graphcut.min_cut(2, [[0.0, 1.0]], [1], [[0, 0], [0, 0]]), ArgumentTypeError, "edges:"),
    (lambda: graphcut.min_cut(2, [0, 1], [1], [[0, 0], [0, 0]]), InvalidArgumentError, "edges: expected shape"),
    (lambda: graphcut.min_cut(2, [[0, 2]], [1], [[0, 0], [0, 0]]), InvalidArgumentError,
     "edges: edge 0 names node 2 but the graph has 2 nodes"),
    (lambda: graphcut.min_cut(2, [[0, -1]], [1], [[0, 0], [0, 0]]), InvalidArgumentError, "edges: edge 0 names node -1"),
    (lambda: graphcut.min_cut(2, [[1, 1]], [1], [[0, 0], [0, 0]]), InvalidArgumentError, "edges: edge 0 connects"),
    (lambda: graphcut.min_cut(2, [[0, 1]], [1, 2], [[0, 0], [0, 0]]), InvalidArgumentError, "capacities: expected shape"),
    (lambda: graphcut.min_cut(2, [[0, 1]], ["a"], [[0, 0], [0, 0]]), ArgumentTypeError, "capacities:"),
    (lambda: graphcut.min_cut(2, [[0, 1]], [-1], [[0, 0], [0, 0]]), InvalidArgumentError,
     "capacities: capacity of edge 0 is -1; expected finite and >= 0"),
    (lambda: graphcut.min_cut(2, [[0, 1]], [[1.0, np.nan]], [[0, 0], [0, 0]]), InvalidArgumentError,
     "capacities: reverse capacity of edge 0 is NaN"),
    (lambda: graphcut.min_cut(2, [[0, 1]], [np.inf], [[0, 0], [0, 0]]), InvalidArgumentError,
     "capacities: capacity of edge 0 is inf"),
    (lambda: graphcut.min_cut(2, [[0, 1]], [1], [[0, 0]]), InvalidArgumentError, "terminal_caps: expected shape (2, 2)"),
    (lambda: graphcut.min_cut(2, [[0, 1]], [1], [[0, 0], [0, -3]]), InvalidArgumentError,
     "terminal_caps: sink capacity of node 1 is -3"),
    (lambda: graphcut.min_cut(2, [[0, 1]], [1], [[0, 0], [np.nan, 0]]), InvalidArgumentError,
     "terminal_caps: source capacity of node 1 is NaN"),
    (lambda: graphcut.min_cut(2, [[0, 1]], [1], [[True, False], [False, True]]), ArgumentTypeError, "terminal_caps:"),
    (lambda: graphcut.min_cut(2, [[0, 1]], np.array([2**64 - 1], np.uint64), [[0, 0], [0, 0]]), InvalidArgumentError,
     "capacities:"),
    (lambda: graphcut.min_cut(2, [[0, 1]], [[2**62, 2**62]], [[0, 0], [0, 0]]), InvalidArgumentError,
     "capacities: the two capacities of edge 0"),
    (lambda: graphcut.grid_min_cut(np.zeros((2, 2, 2)), np.zeros((1, 3, 2)), np.zeros((2, 2, 2))),
     InvalidArgumentError, "right: expected shape (2, 1, 2)"),
    (lambda: graphcut.grid_min_cut(np.zeros((2, 1, 2)), np.zeros((2, 2, 2)), np.zeros((2, 2, 2))),
     InvalidArgumentError, "down: expected shape (1, 2, 2)"),
    (lambda: graphcut.grid_min_cut(np.zeros((2, 1, 2)), np.zeros((1, 2, 2)), np.zeros((2, 2))),
     InvalidArgumentError, "terminal_caps: expected shape"),
    (lambda: graphcut.grid_min_cut(np.zeros((2, 1, 2)), np.full((1, 2, 2), -1.0), np.zeros((2, 2, 2))),
     InvalidArgumentError, "down: forward capacity at (0, 0) is -1.0"),
    (lambda: graphcut.grid_min_cut(np.full((2, 1, 2), np.nan), np.zeros((1, 2, 2)), np.zeros((2, 2, 2))),
     InvalidArgumentError, "right: forward capacity at (0, 0) is NaN"),
    (lambda: graphcut.grid_min_cut(np.zeros((2, 1, 2)), np.zeros((1, 2, 2)), np.full((2, 2, 2), np.inf)),
     InvalidArgumentError, "terminal_caps: source capacity at (0, 0) is inf"),
    (lambda: graphcut.grid_min_cut(np.zeros((2, 1, 2), "U1"), np.zeros((1, 2, 2)), np.zeros((2, 2, 2))),
     ArgumentTypeError, "right:"),
])
def test_bad_input_errors(call, exc, words):
    with pytest.raises(exc) as info:
        call()
    assert words in str(info.value)


def test_bench_maxflow_mode(tmp_path, capsys):
    import json

    from btfrs.tools import bench

    path = tmp_path / "mf.json"
    assert bench.main(["--maxflow-only", "--maxflow-size", "24", "--repeat", "1", "--json", str(path)]) == 0
    assert "scipy / btfrs" in capsys.readouterr().out
    rows = json.loads(path.read_text())["maxflow"]
    assert {r["case"] for r in rows} == {"kwatra", "segmentation"}
    assert all(r["size"] == 24 and r["flow"] > 0 for r in rows)
