"""Measure one fit of a memory-mapped ``.btfrs`` in this process: ``python -m btfrs.tools.memprobe
PATH MODEL OPTIONS_JSON`` prints one JSON line (``MODEL`` a registered model, or ``analyse`` for
:func:`btfrs.synth.analyse`).

What the out-of-core tests and ``python -m btfrs.tools.bench --out-of-core`` run in a fresh
interpreter per fit (memory an earlier fit freed stays with the allocator and would hide the next
fit's growth). The figures are the operating system's own:

* ``growth``: the peak of the anonymous resident memory (``RssAnon`` in ``/proc/self/status``,
  sampled every 2 ms on a thread while the fit runs, the GIL released) above its value before the
  fit. The mapped file's pages are file-backed and not in it (``VmHWM`` would count them).
* ``read_bytes``: bytes this process caused to be fetched from storage (``/proc/self/io``), i.e.
  what the page cache did not already hold.
* ``model``: the model's bytes in memory: its arrays, and for PTM and HSH, which evaluate from a
  float copy of their 8-bit planes, 4 more bytes per plane byte (0 for an analysis).
"""

from __future__ import annotations

import json
import sys
import threading
import time
from typing import Any, Dict

import btfrs


def rss_anon() -> int:
    """This process's anonymous resident memory, bytes."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("RssAnon:"):
                return int(line.split()[1]) * 1024
    raise RuntimeError("no RssAnon in /proc/self/status")


def read_bytes() -> int:
    """Bytes this process has caused to be read from storage."""
    with open("/proc/self/io") as f:
        for line in f:
            if line.startswith("read_bytes:"):
                return int(line.split()[1])
    raise RuntimeError("no read_bytes in /proc/self/io")


def model_bytes(kind: str, model: Any) -> int:
    if kind == "analyse":
        return 0
    arrays = model.arrays
    n = sum(a.nbytes for a in arrays.values())
    if kind in ("ptm", "hsh"):
        n += 4 * sum(a.nbytes for name, a in arrays.items() if name.endswith("_q"))
    return int(n)


def measure(path: str, kind: str, options: Dict[str, Any]) -> Dict[str, Any]:
    btf = btfrs.Btf.load(path, mmap=True)
    base = rss_anon()
    peak = [base]
    stop = threading.Event()

    def sample() -> None:
        while not stop.is_set():
            peak[0] = max(peak[0], rss_anon())
            stop.wait(0.002)

    th = threading.Thread(target=sample, daemon=True)
    r0, t0 = read_bytes(), time.perf_counter()
    th.start()
    try:
        if kind == "analyse":
            model: Any = btfrs.synth.analyse(btf, **options)
        else:
            model = btfrs.fit.fit(kind, btf, **options)
    finally:
        stop.set()
        th.join()
    seconds = time.perf_counter() - t0
    peak[0] = max(peak[0], rss_anon())
    report = getattr(model, "report", None) or {}
    # The fit's own scalar figures (steps, flags), beside the measurements.
    scalars = {k: v for k, v in report.items() if isinstance(v, (int, float, bool, str))} if isinstance(report, dict) else {}
    return {"kind": kind, "growth": peak[0] - base, "model": model_bytes(kind, model), "data": btf.data.nbytes,
            "seconds": seconds, "read_bytes": read_bytes() - r0, "report": scalars}


if __name__ == "__main__":
    print(json.dumps(measure(sys.argv[1], sys.argv[2], json.loads(sys.argv[3]))))
