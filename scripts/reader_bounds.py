"""How long btfrs's readers take on adversarial index files at their size caps: a 4 MiB
``scene.xml`` (its cap) and a 4 MiB and a 16 MiB (its cap) ``info.json`` of each shape that costs a careless parser more than
linear time or memory (attributes on one element, namespaces, nesting, nodes, entities,
escapes, keys). Each file is loaded with ``btfrs.load`` (a Mitsuba scene beside valid maps, a
relight folder beside valid planes) and the wall time of the refusal or the read is printed,
the best of ``--repeat`` runs.

    .venv/bin/python scripts/reader_bounds.py [--repeat 3]

BENCHMARKS.md records the figures (the target: every file refused or read within 1 s).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
import time
from typing import Callable, List, Tuple

import numpy as np

import btfrs

SIZE = 4 << 20


def _fill(unit: Callable[[int], str], head: str = "", tail: str = "") -> str:
    """``head`` + ``unit(0)`` + ``unit(1)`` + ... + ``tail``, just under SIZE bytes."""
    parts, n, i = [head], len(head) + len(tail), 0
    while True:
        u = unit(i)
        if n + len(u) > SIZE - 1024:
            break
        parts.append(u)
        n += len(u)
        i += 1
    return "".join(parts) + tail


def xml_cases() -> List[Tuple[str, str]]:
    h = '<?xml version="1.0"?>\n<scene version="3.0.0">\n'
    return [
        ("one element, as many attributes as fit", _fill(lambda i: f' a{i}="1"', h + "<x", "/>\n</scene>\n")),
        ("elements of 64 attributes", _fill(lambda i: "<x" + "".join(f' a{j}="{i}"' for j in range(64)) + "/>\n",
                                            h, "</scene>\n")),
        ("elements of 64 namespace declarations",
         _fill(lambda i: "<x" + "".join(f' xmlns:p{j}="u{i}_{j}"' for j in range(64)) + "/>\n", h, "</scene>\n")),
        ("nesting 64 deep, 60 namespaces a level, repeated",
         _fill(lambda i: "".join(f'<p{j}:x' + "".join(f' xmlns:p{k}="u{j}_{k}"' for k in range(60)) + ">"
                                 for j in range(60)) + "".join(f"</p{j}:x>" for j in reversed(range(60))) + "\n",
               h, "</scene>\n")),
        ("nesting 64 deep, repeated", _fill(lambda i: "<a>" * 63 + "</a>" * 63 + "\n", h, "</scene>\n")),
        ("nesting as deep as fits", _fill(lambda i: "<a>", h) + "</scene>"),
        ("empty elements (the node cap)", _fill(lambda i: "<a/>", h, "</scene>\n")),
        ("character references", _fill(lambda i: "&#x41;&amp;", h + "<x>", "</x></scene>\n")),
        ("one 4 MiB attribute value", h + '<x a="' + "v" * (SIZE - 200) + '"/></scene>\n'),
        ("comments", _fill(lambda i: "<!-- a=b <x y=z> -->", h, "</scene>\n")),
    ]


def json_cases() -> List[Tuple[str, str]]:
    return [
        ("an unused array of zeros", _fill(lambda i: "0,", '{"type": "hsh", "pad": [', "0]}")),
        ("nesting as deep as fits", _fill(lambda i: "[")),
        ("nesting 120 deep, repeated", _fill(lambda i: "[" * 118 + "]" * 118 + ",", '{"pad": [', "0]}")),
        ("an object of short keys", _fill(lambda i: f'"k{i}":0,', '{"type": "hsh", "pad": {', '"z":0}}')),
        ("one key, repeated", _fill(lambda i: '"k":0,', '{"type": "hsh", "pad": {', '"k":0}}')),
        ("a string of escapes", _fill(lambda i: "\\u0041\\n", '{"type": "hsh", "pad": "', '"}')),
        ("numbers with long exponents", _fill(lambda i: "1e-00000000000000000001,", '{"pad": [', "0]}")),
    ]


def _mitsuba(base: str) -> str:
    rng = np.random.default_rng(7)
    n = np.concatenate([rng.uniform(-0.4, 0.4, (4, 5, 2)), np.ones((4, 5, 1))], -1)
    m = btfrs.Model.from_arrays({
        "diffuse": rng.uniform(0, 1, (4, 5, 3)).astype(np.float32),
        "specular": rng.uniform(0, 0.5, (4, 5, 3)).astype(np.float32),
        "roughness": rng.uniform(0.05, 0.9, (4, 5)).astype(np.float32),
        "normal": (n / np.linalg.norm(n, axis=-1, keepdims=True)).astype(np.float32)}, kind="svbrdf")
    d = os.path.join(base, "scene")
    m.export(d, format="mitsuba")
    return d


def _relight(base: str) -> str:
    btf = btfrs.materials.make("bumps", size=8, seed=1).select(views=[0])
    d = os.path.join(base, "web")
    btfrs.fit.hsh(btf, order=1).export(d, format="relight")
    return d


def _time(folder: str, index: str, text: str, repeat: int) -> Tuple[float, str]:
    with open(os.path.join(folder, index), "w") as f:
        f.write(text)
    best, what = float("inf"), ""
    for _ in range(repeat):
        t0 = time.perf_counter()
        try:
            btfrs.load(folder)
            what = "read"
        except btfrs.exceptions.FormatError as e:
            what = "refused: " + str(e).split(": ", 1)[1][:70]
        best = min(best, time.perf_counter() - t0)
    return best, what


def main() -> None:
    global SIZE
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    base = tempfile.mkdtemp(prefix="btfrs-bounds-")
    try:
        mitsuba, relight = _mitsuba(base), _relight(base)
        for name, folder, index, mib, cases in (("scene.xml", mitsuba, "scene.xml", 4, xml_cases),
                                                ("info.json", relight, "info.json", 4, json_cases),
                                                ("info.json", relight, "info.json", 16, json_cases)):
            SIZE = mib << 20
            for label, text in cases():
                assert len(text.encode()) <= SIZE, (label, len(text))
                secs, what = _time(folder, index, text, args.repeat)
                print(f"{name:9s} {len(text.encode()) / 2**20:4.2f} MiB  {secs * 1000:7.1f} ms  {label}: {what}")
    finally:
        shutil.rmtree(base)


if __name__ == "__main__":
    main()
