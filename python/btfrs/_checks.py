"""Argument checks shared by the public Python API.

The Rust side takes ``usize``/``u64``/``f64``; PyO3 would silently truncate nothing but would
turn ``-1`` into an ``OverflowError`` and ``2.9`` into a ``TypeError`` without the argument's
name, and ``int(2.9)`` in Python would silently make it 2. So every scalar argument of the
public API goes through one of these first: wrong types raise
:class:`~btfrs.exceptions.ArgumentTypeError`, values out of range
:class:`~btfrs.exceptions.InvalidArgumentError` (indices :class:`~btfrs.exceptions.OutOfRangeError`),
each message naming the argument and the accepted range.
"""

from __future__ import annotations

import math
import os
import re
from numbers import Integral, Real
from typing import Optional, Sequence, SupportsInt, Tuple, Type, TypeVar, Union, cast

import numpy as np

from .exceptions import ArgumentTypeError, InvalidArgumentError, OutOfRangeError

__all__ = ["integer", "index", "seed", "real", "boolean", "choice", "size_hw", "instance", "memory_size"]

# The largest integer every native parameter (usize, u64, i64) can hold on a 64-bit build.
INT_MAX = 2**63 - 1
SEED_MAX = 2**64 - 1

#: What the API takes as a file path.
PathLike = Union[str, "os.PathLike[str]"]


T = TypeVar("T")


def _is_int(value: object) -> bool:
    # bool is an int subclass, but `lobes=True` is a mistake, not a 1.
    return isinstance(value, (int, np.integer, Integral)) and not isinstance(value, (bool, np.bool_))


def _range_text(lo: Optional[float], hi: Optional[float], lo_open: bool = False, hi_open: bool = False) -> str:
    if lo is not None and hi is not None:
        return f"in {'(' if lo_open else '['}{lo}, {hi}{')' if hi_open else ']'}"
    if lo is not None:
        return f"{'>' if lo_open else '>='} {lo}"
    if hi is not None:
        return f"{'<' if hi_open else '<='} {hi}"
    return "any value"


def integer(name: str, value: object, *, min: Optional[int] = None, max: Optional[int] = INT_MAX) -> int:
    """``value`` as a Python int in ``[min, max]``: Python and numpy integers only (no bools, no
    floats, not even integral ones: ``2.0`` usually means a computation went wrong)."""
    # The implicit bound INT_MAX is only mentioned when it is what the value broke.
    shown_max = None if max == INT_MAX else max
    if not _is_int(value):
        raise ArgumentTypeError(f"{name}: expected an integer {_range_text(min, shown_max)}, "
                                f"got {type(value).__name__} {value!r}")
    v = int(cast(SupportsInt, value))  # an integer: _is_int said so
    if (min is not None and v < min) or (max is not None and v > max):
        rng = _range_text(min, max if max is not None and v > max else shown_max)
        raise InvalidArgumentError(f"{name}: expected an integer {rng}, got {v}")
    return v


def index(name: str, value: object, n: int) -> int:
    """An index into an axis of length ``n``: an integer in ``[0, n)``; negative indices are
    rejected (they would silently wrap to the end)."""
    if not _is_int(value):
        raise ArgumentTypeError(f"{name}: expected an integer index in [0, {n}), got {type(value).__name__} {value!r}")
    v = int(cast(SupportsInt, value))  # an integer: _is_int said so
    if not 0 <= v < n:
        raise OutOfRangeError(f"{name}: expected an index in [0, {n}), got {v}")
    return v


def seed(value: object, name: str = "seed") -> int:
    """A seed as the Rust side takes it: an integer in ``[0, 2**64)``."""
    if not _is_int(value):
        raise ArgumentTypeError(f"{name}: expected an integer in [0, 2**64), got {type(value).__name__} {value!r}")
    v = int(cast(SupportsInt, value))  # an integer: _is_int said so
    if not 0 <= v <= SEED_MAX:
        raise InvalidArgumentError(f"{name}: expected an integer in [0, 2**64), got {v}")
    return v


def real(name: str, value: object, *, min: Optional[float] = None, max: Optional[float] = None,
         min_open: bool = False, max_open: bool = False) -> float:
    """``value`` as a finite Python float within the bounds (``min_open``/``max_open`` exclude the
    bound itself). Integers are accepted (``exposure=2``), bools and complex numbers are not."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (Real, np.integer, np.floating)):
        raise ArgumentTypeError(f"{name}: expected a real number {_range_text(min, max, min_open, max_open)}, "
                                f"got {type(value).__name__} {value!r}")
    v = float(value)
    ok = math.isfinite(v)
    if ok and min is not None:
        ok = v > min if min_open else v >= min
    if ok and max is not None:
        ok = v < max if max_open else v <= max
    if not ok:
        rng = _range_text(min, max, min_open, max_open)
        raise InvalidArgumentError(f"{name}: expected a finite number{'' if rng == 'any value' else ' ' + rng}, got {v}")
    return v


def boolean(name: str, value: object) -> bool:
    """``True``/``False`` (Python or numpy bools only: ``cls="no"`` is not silently true)."""
    if not isinstance(value, (bool, np.bool_)):
        raise ArgumentTypeError(f"{name}: expected True or False, got {type(value).__name__} {value!r}")
    return bool(value)


def choice(name: str, value: object, options: Sequence[str]) -> str:
    """One of ``options`` (strings)."""
    if not isinstance(value, str) or value not in options:
        shown = ", ".join(f'"{o}"' for o in options)
        raise InvalidArgumentError(f"{name}: expected one of {shown}, got {value!r}")
    return value


def size_hw(name: str, value: object, *, min: int = 1, max: int = INT_MAX) -> Tuple[int, int]:
    """An image size as numpy shapes give it: ``(height, width)``, or one integer for a square."""
    if _is_int(value):
        s = integer(name, value, min=min, max=max)
        return s, s
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) != 2:
        raise ArgumentTypeError(f"{name}: expected an integer or a (height, width) pair, got {value!r}")
    h, w = cast(Sequence[object], value)
    return integer(f"{name}[0] (height)", h, min=min, max=max), integer(f"{name}[1] (width)", w, min=min, max=max)


def instance(name: str, value: object, cls: Union[Type[T], Tuple[Type[T], ...]], what: str) -> T:
    """``value`` itself when it is a ``cls``; else an ArgumentTypeError saying ``what`` was expected."""
    if not isinstance(value, cls):
        raise ArgumentTypeError(f"{name}: expected {what}, got {type(value).__name__}")
    return value


# Decimal units as dask and the operating system's tools write them ("2GB" = 2e9 bytes), and the
# binary ones for those who mean them.
_SIZE_UNITS = {"": 1, "b": 1, "kb": 10**3, "mb": 10**6, "gb": 10**9, "tb": 10**12,
               "kib": 2**10, "mib": 2**20, "gib": 2**30, "tib": 2**40}


def memory_size(name: str, value: object) -> Optional[int]:
    """``None``, a number of bytes, or a size such as ``"64MB"``, ``"2GB"``, ``"1.5GiB"`` as bytes."""
    if value is None:
        return None
    if _is_int(value):
        n = int(cast(SupportsInt, value))  # an integer: _is_int said so
    elif isinstance(value, str):
        m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*([A-Za-z]*)\s*", value)
        unit = m.group(2).lower() if m else None
        if m is None or unit not in _SIZE_UNITS:
            raise InvalidArgumentError(
                f"{name}: expected a number of bytes or a size such as '64MB', '2GB' or '512MiB', got {value!r}")
        n = int(float(m.group(1)) * _SIZE_UNITS[unit])
    else:
        raise ArgumentTypeError(
            f"{name}: expected a number of bytes or a size string such as '2GB', got {type(value).__name__}")
    if not 1 <= n <= INT_MAX:
        raise InvalidArgumentError(f"{name}: expected a positive size of at most {INT_MAX} bytes, got {value!r}")
    return n
