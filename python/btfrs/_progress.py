"""Progress reporting for long calls: a callable, ``True`` for a bar on stderr, or nothing."""

from __future__ import annotations

import sys
import time
from typing import Callable, Optional, Union

Progress = Union[None, bool, Callable[[int, int], object]]


class _Bar:
    """A small text progress bar (tqdm is used instead when it is installed)."""

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


def callback(progress: Progress, desc: str) -> Optional[Callable[[int, int], object]]:
    """Turn the user's ``progress`` argument into a ``(done, total)`` callback or None."""
    if progress is None or progress is False:
        return None
    if progress is True:
        try:
            from tqdm import tqdm  # type: ignore[import-not-found]
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
    raise TypeError(f"progress: expected None, a bool or a callable(done, total), got {type(progress).__name__}")
