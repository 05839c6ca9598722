"""Benchmark a camera-sized RTI capture from photographs to fitted models (docs/scale.md, "A
24-megapixel capture"; BENCHMARKS.md).

    .venv/bin/python scripts/camera_capture.py --out /tmp/camera24          # the photographs
    .venv/bin/python scripts/camera_bench.py load /tmp/camera24/dirs.lp /tmp/camera24.btfrs --memory-limit 2GB
    .venv/bin/python scripts/camera_bench.py read /tmp/camera24.btfrs       # one read of the data
    .venv/bin/python scripts/camera_bench.py fit /tmp/camera24.btfrs ptm hsh rbf --memory-limit 2GB
    .venv/bin/python scripts/camera_bench.py fit /tmp/camera24.btfrs neural --memory-limit 2GB
    .venv/bin/python scripts/camera_bench.py disk /tmp                     # the disk's own speeds

Each measurement runs in a fresh interpreter (memory an earlier step freed stays with the
allocator and would hide the next one's growth) and prints one JSON line, also appended to
``--json`` (default ``bench-results/camera.json``):

* ``seconds`` (wall) and ``cpu`` (user + system seconds of the process), with the load average
  (``os.getloadavg``) before and after: the machine is shared, so CPU seconds are the stable figure;
* ``peak_anon``: the peak of the process's anonymous resident memory (``RssAnon``, sampled every
  2 ms) above its value before the step. The memory-mapped BTF's pages are file-backed page cache
  and not in it (``VmHWM`` and ``/usr/bin/time``'s maximum resident size count them);
* ``read_bytes`` / ``write_bytes``: what the process fetched from and sent to storage
  (``/proc/self/io``);
* ``gbps``: decoded float32 values (the BTF's bytes) per wall second.

``load``, ``read`` and ``fit`` first drop the files they read from the page cache
(``posix_fadvise(DONTNEED)``, which drops only clean pages of those files), so every figure
starts cold, as a capture larger than the free memory would; ``--warm`` keeps the cache.
``read`` sums every value of the file in float64, one pass in storage order: the time of one
read of the data, the yardstick of the fits.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import threading
import time
from typing import Any, Callable, Dict, List

import numpy as np


def _rss_anon() -> int:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("RssAnon:"):
                return int(line.split()[1]) * 1024
    return 0


def _io() -> Dict[str, int]:
    out = {}
    with open("/proc/self/io") as f:
        for line in f:
            k, v = line.split(":")
            out[k] = int(v)
    return out


def evict(path: str) -> None:
    """Drop the file's clean pages from the page cache (a folder: each file in it)."""
    paths = [os.path.join(path, n) for n in os.listdir(path)] if os.path.isdir(path) else [path]
    for p in paths:
        if os.path.isfile(p):
            fd = os.open(p, os.O_RDONLY)
            try:
                os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_DONTNEED)
            finally:
                os.close(fd)


def measured(work: Callable[[], Any]) -> Dict[str, Any]:
    """Run ``work`` in this process, sampling its anonymous memory; the figures of the module doc."""
    base = _rss_anon()
    peak = [base]
    stop = threading.Event()

    def sample() -> None:
        while not stop.is_set():
            peak[0] = max(peak[0], _rss_anon())
            stop.wait(0.002)

    th = threading.Thread(target=sample, daemon=True)
    io0, load0 = _io(), os.getloadavg()
    c0, t0 = os.times(), time.perf_counter()
    th.start()
    try:
        result = work()
    finally:
        stop.set()
        th.join()
    seconds = time.perf_counter() - t0
    c1, io1 = os.times(), _io()
    peak[0] = max(peak[0], _rss_anon())
    return {"result": result, "seconds": seconds, "cpu": (c1.user - c0.user) + (c1.system - c0.system),
            "user": c1.user - c0.user, "system": c1.system - c0.system, "peak_anon": peak[0] - base,
            "read_bytes": io1["read_bytes"] - io0["read_bytes"], "write_bytes": io1["write_bytes"] - io0["write_bytes"],
            "load_before": load0[0], "load_after": os.getloadavg()[0]}


def model_bytes(model: Any) -> int:
    """The model's arrays in memory (PTM and HSH also hold a float copy of their 8-bit planes)."""
    arrays = model.arrays
    n = sum(a.nbytes for a in arrays.values())
    if getattr(model, "kind", "") in ("ptm", "hsh"):
        n += 4 * sum(a.nbytes for name, a in arrays.items() if name.endswith("_q"))
    return int(n)


# --- the steps, each in its own interpreter -------------------------------------------------------

def step_load(capture: str, out: str, memory_limit: str, warm: bool) -> Dict[str, Any]:
    import btfrs
    if not warm:
        evict(os.path.dirname(os.path.abspath(capture)))
    m = measured(lambda: btfrs.load(capture, mmap_to=out, memory_limit=memory_limit, progress=True))
    btf = m.pop("result")
    h, w, v, l, _ = btf.shape
    m.update(step="load", capture=capture, out=out, memory_limit=memory_limit, shape=[h, w, v, l],
             data_bytes=int(btf.data.nbytes), gbps=btf.data.nbytes / m["seconds"] / 1e9,
             gbps_cpu=btf.data.nbytes / m["cpu"] / 1e9)
    return m


def step_read(path: str, warm: bool) -> Dict[str, Any]:
    import btfrs
    btf = btfrs.Btf.load(path, mmap=True)
    if not warm:
        evict(path)
    flat = btf.data.reshape(-1)
    chunk = 64 << 20  # values per step: 256 MB

    def run() -> float:
        total = 0.0
        for i in range(0, flat.size, chunk):
            total += float(np.add.reduce(flat[i:i + chunk], dtype=np.float64))
        return total

    m = measured(run)
    m.update(step="read", path=path, data_bytes=int(btf.data.nbytes), gbps=btf.data.nbytes / m["seconds"] / 1e9,
             sum=m.pop("result"))
    return m


def step_fit(path: str, kind: str, memory_limit: str, options: Dict[str, Any], warm: bool) -> Dict[str, Any]:
    import btfrs
    btf = btfrs.Btf.load(path, mmap=True)
    if not warm:
        evict(path)
    m = measured(lambda: btfrs.fit.fit(kind, btf, memory_limit=memory_limit, progress=True, **options))
    model = m.pop("result")
    report = getattr(model, "report", None) or {}
    m.update(step="fit", kind=kind, options=options, memory_limit=memory_limit, path=path,
             data_bytes=int(btf.data.nbytes), model_bytes=model_bytes(model),
             gbps=btf.data.nbytes / m["seconds"] / 1e9,
             report={k: v for k, v in report.items() if isinstance(v, (int, float, bool, str)) or k == "encoder"})
    return m


def disk(folder: str, gb: float) -> List[Dict[str, Any]]:
    """The disk's sequential write (with fdatasync) and cold read speeds, by dd."""
    path = os.path.join(folder, f".camera_bench_dd.{os.getpid()}")
    count = int(gb * 1024)
    out = []
    try:
        for what, cmd in (("write", ["dd", "if=/dev/zero", f"of={path}", "bs=1M", f"count={count}", "conv=fdatasync"]),
                          ("read", ["dd", f"if={path}", "of=/dev/null", "bs=1M"])):
            if what == "read":
                evict(path)
            load0 = os.getloadavg()[0]
            t0 = time.perf_counter()
            subprocess.run(cmd, check=True, capture_output=True)
            s = time.perf_counter() - t0
            out.append({"step": f"disk {what}", "bytes": count << 20, "seconds": s, "gbps": (count << 20) / s / 1e9,
                        "load_before": load0, "load_after": os.getloadavg()[0]})
    finally:
        if os.path.exists(path):
            os.unlink(path)
    return out


def _machine() -> Dict[str, Any]:
    cpu = ""
    with open("/proc/cpuinfo") as f:
        for line in f:
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    return {"cpu": cpu, "cores": os.cpu_count(), "memory_gib": os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30,
            "date": time.strftime("%Y-%m-%d %H:%M")}


def _child(args: List[str]) -> Dict[str, Any]:
    """Run one step in a fresh interpreter; its progress goes to stderr as it runs."""
    r = subprocess.run([sys.executable, os.path.abspath(__file__), "_step", *args], stdout=subprocess.PIPE, text=True)
    if r.returncode != 0:
        raise SystemExit(f"the step {args} failed (exit {r.returncode})")
    return json.loads(r.stdout.strip().splitlines()[-1])


def _record(row: Dict[str, Any], path: str) -> None:
    row = dict(row, machine=_machine())
    print(json.dumps(row), flush=True)
    os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
    with open(path, "a") as f:
        f.write(json.dumps(row) + "\n")


def main(argv: List[str]) -> int:
    if argv and argv[0] == "_step":
        what, rest = argv[1], argv[2:]
        if what == "load":
            row = step_load(rest[0], rest[1], rest[2], rest[3] == "1")
        elif what == "read":
            row = step_read(rest[0], rest[1] == "1")
        else:
            row = step_fit(rest[0], rest[1], rest[2], json.loads(rest[3]), rest[4] == "1")
        print(json.dumps(row))
        return 0
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--json", default=os.path.join("bench-results", "camera.json"), help="JSON lines appended here")
    p.add_argument("--warm", action="store_true", help="keep the page cache (default: drop the inputs' pages first)")
    p.add_argument("--repeat", type=int, default=1, help="runs of each step (report the minimum)")
    sub = p.add_subparsers(dest="cmd", required=True)
    a = sub.add_parser("load", help="decode the photographs into a memory-mapped .btfrs")
    a.add_argument("capture")
    a.add_argument("out")
    a.add_argument("--memory-limit", default="2GB")
    a = sub.add_parser("read", help="one read of a .btfrs: the sum of its values")
    a.add_argument("path")
    a = sub.add_parser("fit", help="fit models to a memory-mapped .btfrs")
    a.add_argument("path")
    a.add_argument("kinds", nargs="+")
    a.add_argument("--memory-limit", default="2GB")
    a.add_argument("--set", action="append", default=[], metavar="KIND.OPTION=JSON",
                   help='an option of one model, e.g. --set neural.steps=2000 or --set rbf.robust=false')
    a = sub.add_parser("disk", help="the disk's sequential write and read speeds (dd)")
    a.add_argument("folder")
    a.add_argument("--gb", type=float, default=4.0)
    args = p.parse_args(argv)
    warm = "1" if args.warm else "0"
    for _ in range(args.repeat):
        if args.cmd == "load":
            _record(_child(["load", args.capture, args.out, args.memory_limit, warm]), args.json)
        elif args.cmd == "read":
            _record(_child(["read", args.path, warm]), args.json)
        elif args.cmd == "fit":
            for kind in args.kinds:
                opts: Dict[str, Any] = {}
                for s in args.set:
                    key, _, val = s.partition("=")
                    k, _, name = key.partition(".")
                    if k == kind:
                        opts[name] = json.loads(val)
                _record(_child(["fit", args.path, kind, args.memory_limit, json.dumps(opts), warm]), args.json)
        else:
            for row in disk(args.folder, args.gb):
                _record(row, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
