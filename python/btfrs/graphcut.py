"""Max-flow / min-cut with the Boykov-Kolmogorov algorithm (PAMI 2004), in Rust.

Two entries, both returning ``(flow, source_side)``:

* :func:`min_cut` on a general graph given as an edge list;
* :func:`grid_min_cut` on a 4-connected ``H x W`` grid (the fast path: neighbours are implicit),
  the shape of seam problems (graph-cut textures) and of image segmentation.

Integer capacities (any integer dtype) run the exact int64 path and return a Python ``int``;
float capacities run in float64, or in float32 when every float input is float32, and return a
``float``. ``source_side`` is True for the nodes reachable from the source in the residual graph:
the source side of the minimum cut (the smallest one, when several cuts are minimal).

>>> import numpy as np, btfrs
>>> flow, side = btfrs.graphcut.min_cut(2, [[0, 1]], [3], [[5, 0], [0, 4]])
>>> flow, side.tolist()
(3, [True, False])
"""

from __future__ import annotations

from typing import Any, Dict, Tuple, Union

import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import _checks, _native
from .exceptions import ArgumentTypeError, InvalidArgumentError

__all__ = ["min_cut", "grid_min_cut"]

_INT64_MAX = np.iinfo(np.int64).max


def _array(name: str, x: ArrayLike) -> NDArray[Any]:
    a = np.asarray(x)
    if a.dtype.kind not in "iuf":
        raise ArgumentTypeError(f"{name}: expected a numeric array (integers or floats), got dtype {a.dtype}")
    return a


def _common_dtype(arrays: Dict[str, NDArray[Any]]) -> np.dtype[Any]:
    """int64 when every (non-empty) input is integer, else float32 when every float input is
    float32, else float64. Empty arrays do not vote (``[]`` is float64 in numpy)."""
    voting = [a for a in arrays.values() if a.size] or list(arrays.values())
    floats = [a.dtype for a in voting if a.dtype.kind == "f"]
    if not floats:
        return np.dtype(np.int64)
    return np.dtype(np.float32) if all(d == np.float32 for d in floats) else np.dtype(np.float64)


def _convert(name: str, a: NDArray[Any], dtype: np.dtype[Any]) -> NDArray[Any]:
    if dtype.kind == "i" and a.dtype.kind == "u" and a.size and int(a.max()) > _INT64_MAX:
        raise InvalidArgumentError(f"{name}: capacity {int(a.max())} does not fit in int64")
    return np.ascontiguousarray(a, dtype=dtype)


def _flow(f: Union[int, float, np.number[Any]]) -> Union[int, float]:
    return int(f) if isinstance(f, (int, np.integer)) else float(f)


def min_cut(n: int, edges: ArrayLike, capacities: ArrayLike,
            terminal_caps: ArrayLike) -> Tuple[Union[int, float], NDArray[np.bool_]]:
    """Minimum s-t cut of a graph of ``n`` nodes.

    ``edges`` ``[E, 2]`` integer node ids ``(a, b)`` (``a != b``; parallel edges add up);
    ``capacities`` ``[E, 2]`` (``a -> b``, ``b -> a``) or ``[E]`` (the same both ways);
    ``terminal_caps`` ``[n, 2]`` (source -> node, node -> sink). All capacities finite and >= 0.
    Returns ``(flow, source_side)``: the maximum flow (= the minimum cut's capacity) and a bool
    ``[n]`` array, True on the source side. Bad input raises
    :class:`~btfrs.exceptions.InvalidArgumentError` (or :class:`~btfrs.exceptions.ArgumentTypeError`)
    naming the argument.
    """
    n = _checks.integer("n", n, min=0)
    e = np.asarray(edges)
    if e.size == 0:
        e = e.reshape(0, 2) if e.ndim <= 1 or e.shape[-1] != 2 else e
    if e.dtype.kind not in "iu" and not (e.size == 0 and e.dtype.kind == "f"):
        raise ArgumentTypeError(f"edges: expected integer node ids, got dtype {e.dtype}")
    if e.ndim != 2 or e.shape[1] != 2:
        raise InvalidArgumentError(f"edges: expected shape (E, 2), got {e.shape}")
    if e.dtype.kind == "u" and e.size and int(e.max()) > _INT64_MAX:
        raise InvalidArgumentError(f"edges: node id {int(e.max())} but the graph has {n} nodes")
    e = np.ascontiguousarray(e, dtype=np.int64)
    c = _array("capacities", capacities)
    t = _array("terminal_caps", terminal_caps)
    if c.ndim == 1 and c.shape[0] == e.shape[0]:
        c = np.stack([c, c], axis=1)
    elif c.size == 0 and e.shape[0] == 0:
        c = c.reshape(0, 2)
    if c.ndim != 2 or c.shape != (e.shape[0], 2):
        raise InvalidArgumentError(f"capacities: expected shape ({e.shape[0]}, 2) or ({e.shape[0]},) "
                                   f"for {e.shape[0]} edges, got {c.shape}")
    if t.size == 0 and n == 0:
        t = t.reshape(0, 2)
    if t.shape != (n, 2):
        raise InvalidArgumentError(f"terminal_caps: expected shape ({n}, 2), got {t.shape}")
    dtype = _common_dtype({"capacities": c, "terminal_caps": t})
    c = _convert("capacities", c, dtype)
    t = _convert("terminal_caps", t, dtype)
    flow, side = _native.min_cut_native(n, e, c, t)
    return _flow(flow), side


def grid_min_cut(right: ArrayLike, down: ArrayLike,
                 terminal_caps: ArrayLike) -> Tuple[Union[int, float], NDArray[np.bool_]]:
    """Minimum s-t cut of a 4-connected ``H x W`` grid.

    ``right`` ``[H, W - 1, 2]``: capacities between ``(y, x)`` and ``(y, x + 1)``, (towards
    ``(y, x + 1)``, towards ``(y, x)``); ``down`` ``[H - 1, W, 2]``: between ``(y, x)`` and
    ``(y + 1, x)``, (towards ``(y + 1, x)``, towards ``(y, x)``); ``terminal_caps`` ``[H, W, 2]``
    (source, sink). Returns ``(flow, source_side)`` with ``source_side`` a bool ``[H, W]`` array.
    The same answer as :func:`min_cut` on the same graph, faster.
    """
    arrays = {"right": _array("right", right), "down": _array("down", down),
              "terminal_caps": _array("terminal_caps", terminal_caps)}
    dtype = _common_dtype(arrays)
    r, d, t = (_convert(k, a, dtype) for k, a in arrays.items())
    flow, side = _native.grid_min_cut_native(r, d, t)
    return _flow(flow), side
