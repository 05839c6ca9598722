"""Progress reporting for long calls: a callable, ``True`` for a report on stderr, or nothing.

``progress=True`` draws a bar (tqdm's when it is installed) when stderr is a terminal. When it is
not (a log file, CI, a pipe), a redrawn bar would write hundreds of ``\\r`` updates into the log,
so each phase writes one line when it finishes instead: its name, its final count and its time.
"""

from __future__ import annotations

import sys
import time
from typing import Callable, Optional, Union

from .exceptions import ArgumentTypeError

Progress = Union[None, bool, Callable[[int, int], object]]


def _stderr_is_terminal() -> bool:
    try:
        return bool(sys.stderr.isatty())
    except (AttributeError, ValueError):  # replaced by an object without isatty, or closed
        return False


class _Bar:
    """A small text progress bar redrawn in place (tqdm is used instead when it is installed)."""

    def __init__(self, desc: str) -> None:
        self.desc = desc
        self.t0 = time.perf_counter()
        self.last = -1

    def __call__(self, done: int, total: int) -> None:
        if total <= 0:
            return
        pct = int(100 * done / total)
        if pct == self.last:
            return
        self.last = pct
        filled = pct // 4
        el = time.perf_counter() - self.t0
        end = "\n" if done >= total else ""
        sys.stderr.write(f"\r{self.desc:<24} [{'#' * filled}{'.' * (25 - filled)}] {pct:3d}% {el:6.1f}s{end}")
        sys.stderr.flush()


class _Lines:
    """One line per phase, written when it finishes: for stderr that is not a terminal."""

    def __init__(self, desc: str) -> None:
        self.desc = desc
        self.t0 = time.perf_counter()
        self.finished = False

    def __call__(self, done: int, total: int) -> None:
        # The native runner reports the final count twice (last poll, then on return): write once.
        if self.finished or total <= 0 or done < total:
            return
        self.finished = True
        sys.stderr.write(f"{self.desc}: {done}/{total} in {time.perf_counter() - self.t0:.2f} s\n")
        sys.stderr.flush()


def callback(progress: Progress, desc: str) -> Optional[Callable[[int, int], object]]:
    """Turn the user's ``progress`` argument into a ``(done, total)`` callback or None.

    ``desc`` names the phase (one call of this function per phase)."""
    if progress is None or progress is False:
        return None
    if progress is True:
        if not _stderr_is_terminal():
            return _Lines(desc)
        try:
            from tqdm import tqdm  # optional extra (progress), only for a bar
        except ImportError:
            return _Bar(desc)
        bar = tqdm(desc=desc, total=1, leave=True)

        def update(done: int, total: int) -> None:
            if bar.total != total and total > 0:
                bar.total = total
            bar.n = done
            bar.refresh()
            if total and done >= total:
                bar.close()

        return update
    if callable(progress):
        return progress
    raise ArgumentTypeError(
        f"progress: expected None, a bool or a callable(done, total), got {type(progress).__name__}")
