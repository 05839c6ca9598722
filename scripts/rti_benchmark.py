"""The RTI relighting benchmark on public captures: how well each model predicts lights it did
not see, by the protocol of the RTI papers (NeuralRTI, Dulecha et al. 2020; DisK-NeuralRTI).

Usage::

    python scripts/rti_benchmark.py DIR... [--out bench-results/rti] [--methods raw,ptm,...]
                                           [--sets GLOB] [--repeat-neural N]

Each ``DIR`` is searched for data sets (a folder holding one is enough):

* **SynthRTI** sets (GitHub ``Univr-RTI/SynthRTI``, e.g. ``Single/Object2/material3``): a folder
  with ``Dome/dirs.lp`` (the lights to fit) and ``Test/dirs.lp`` (the lights to predict);
* **plain captures** (GitHub ``Univr-RTI/RealRTI`` items, any folder with one ``.lp``): every
  5th light (the 5th, 10th, ... of the file) is held out and predicted from the others.

The images are read as their own values in [0, 1] (``btfrs.load(..., linear=True)``: 8-bit / 255,
no sRGB decoding), every model is fitted to those values, and each prediction, clipped to
[0, 1] as a display would, is scored against the held-out photograph: PSNR (peak 1), SSIM
(scikit-image's, on the RGB image, ``data_range=1``), the relative L2 error, with the model's
bytes (as stored for rendering) and its fit time. ``raw`` is the raw data's own prediction:
the inverse-distance weighted mean of the 4 measured lights nearest the held-out one (its
bytes: the training photographs as 8-bit RGB).

Writes ``results.json`` (every row; a rerun skips the rows already there, so an interrupted
run resumes), ``table.md`` (per set and method, and the mean over sets) and
``psnr_vs_bytes.png``. The data carries no licence: keep a local copy, never commit it.
"""

from __future__ import annotations

import argparse
import fnmatch
import json
import os
import sys
import time
from typing import Any, Callable, Dict, List, Optional, Tuple

import numpy as np

import btfrs

# (label, kind, options): what each method fits. "raw" is the measured data itself.
METHODS: List[Tuple[str, Optional[str], Dict[str, Any]]] = [
    ("raw", None, {}),
    ("PTM", "ptm", {"kind": "rgb"}),
    ("HSH-3", "hsh", {"order": 3}),
    ("RBF-18", "rbf", {"components": 18}),
    ("Bilinear-18", "bilinear", {"components": 18}),
    ("LPCA-32x8", "lpca", {"clusters": 32, "components": 8}),
    ("SVBRDF", "svbrdf", {}),
    ("Neural", "neural", {}),
    ("Neural-best", "neural", {"latents": 16}),
    # What the horizon map (the clearance inputs, shadows and relief) is worth: the defaults
    # without it, NeuralRTI's inputs.
    ("Neural-no-horizon", "neural", {"horizon": 0}),
]


# --- data sets ----------------------------------------------------------------------------------

def _lp(folder: str) -> Optional[str]:
    names = sorted(n for n in os.listdir(folder) if n.lower().endswith(".lp"))
    return os.path.join(folder, names[0]) if names else None


def find_sets(roots: List[str]) -> List[Tuple[str, str]]:
    """``(name, folder)`` of every data set under ``roots``: SynthRTI sets first found (a folder
    with ``Dome/`` and ``Test/``), else plain captures (a folder with an ``.lp``)."""
    found: List[Tuple[str, str]] = []
    for root in roots:
        root = os.path.abspath(root)
        if not os.path.isdir(root):
            sys.exit(f"rti_benchmark: {root} is not a folder")
        for here, dirs, _ in os.walk(root):
            dirs.sort()
            if {"Dome", "Test"} <= set(dirs) and _lp(os.path.join(here, "Dome")) and _lp(os.path.join(here, "Test")):
                found.append((os.path.relpath(here, os.path.dirname(root)), here))
                dirs[:] = []
            elif os.path.basename(here) not in ("Dome", "Test") and _lp(here):
                found.append((os.path.relpath(here, os.path.dirname(root)), here))
                dirs[:] = []
    return found


def load_set(folder: str) -> Tuple[btfrs.Btf, btfrs.Btf]:
    """(train, test) of a data set, both with one view, values in [0, 1]."""
    if os.path.isdir(os.path.join(folder, "Dome")):
        train = btfrs.load(_lp(os.path.join(folder, "Dome")), linear=True)
        test = btfrs.load(_lp(os.path.join(folder, "Test")), linear=True)
        if test.data.shape[:2] != train.data.shape[:2]:
            sys.exit(f"rti_benchmark: {folder}: Dome and Test images differ in size")
        return train, test
    cap = btfrs.load(_lp(folder), linear=True)
    n = cap.lights.shape[0]
    held = [i for i in range(n) if i % 5 == 4]
    kept = [i for i in range(n) if i % 5 != 4]
    return cap.select(lights=kept), cap.select(lights=held)


# --- predictions and scores ---------------------------------------------------------------------

def raw_predict(train: btfrs.Btf, light: np.ndarray, k: int = 4) -> np.ndarray:
    """The inverse-distance weighted mean of the ``k`` measured lights nearest ``light`` (an
    exact match is returned as measured)."""
    d = np.linalg.norm(train.lights - light[None, :], axis=1)
    near = np.argsort(d, kind="stable")[:k]
    if d[near[0]] < 1e-9:
        return train.data[:, :, 0, near[0]].astype(np.float64)
    w = 1.0 / d[near]
    w /= w.sum()
    return np.tensordot(train.data[:, :, 0, near].astype(np.float64), w, axes=([2], [0]))


def scores(pred: np.ndarray, gt: np.ndarray) -> Dict[str, float]:
    from skimage.metrics import structural_similarity

    p = np.clip(pred, 0.0, 1.0)
    mse = float(np.mean((p - gt) ** 2))
    return {"mse": mse, "ssim": float(structural_similarity(gt, p, channel_axis=-1, data_range=1.0)),
            "sse": float(np.sum((p - gt) ** 2)), "sgt": float(np.sum(gt ** 2))}


def run_method(label: str, kind: Optional[str], options: Dict[str, Any], train: btfrs.Btf,
               test: btfrs.Btf) -> Dict[str, Any]:
    t0 = time.perf_counter()
    if kind is None:
        predict: Callable[[np.ndarray], np.ndarray] = lambda l: raw_predict(train, l)
        nbytes = int(np.prod(train.data.shape[:2])) * 3 * train.lights.shape[0]
        report: Dict[str, Any] = {}
    else:
        model = btfrs.fit.fit(kind, train, **options)
        predict = lambda l: model.evaluate(view=[0.0, 0.0, 1.0], light=l).astype(np.float64)
        nbytes = model.nbytes
        report = {k: v for k, v in model.report.items() if isinstance(v, (int, float, bool, str))}
    fit_s = time.perf_counter() - t0
    per = [scores(predict(test.lights[i]), test.data[:, :, 0, i].astype(np.float64))
           for i in range(test.lights.shape[0])]
    mse = float(np.mean([p["mse"] for p in per]))
    return {"method": label, "kind": kind or "raw", "options": options, "bytes": nbytes,
            "fit_s": fit_s if kind is not None else 0.0,
            "psnr": float(10 * np.log10(1.0 / mse)) if mse > 0 else float("inf"),
            "psnr_per_image": float(np.mean([10 * np.log10(1.0 / p["mse"]) for p in per if p["mse"] > 0])),
            "ssim": float(np.mean([p["ssim"] for p in per])),
            "relative": float(np.sqrt(sum(p["sse"] for p in per) / sum(p["sgt"] for p in per))),
            "report": report}


# --- outputs ------------------------------------------------------------------------------------

def write_table(rows: List[Dict[str, Any]], labels: List[str], path: str) -> None:
    sets = sorted({r["set"] for r in rows})
    by = {(r["set"], r["method"]): r for r in rows}
    lines = ["PSNR dB / SSIM per set (bytes as a ratio to the raw photographs; fit seconds)", "",
             "| set | " + " | ".join(labels) + " |", "|---|" + "---|" * len(labels)]
    for s in sets:
        raw = by.get((s, "raw"))
        cells = []
        for lab in labels:
            r = by.get((s, lab))
            if r is None:
                cells.append("")
                continue
            ratio = f"1:{raw['bytes'] / r['bytes']:.0f}" if raw and r["method"] != "raw" else "1:1"
            fit = f", {r['fit_s']:.0f} s" if r["method"] != "raw" else ""
            cells.append(f"{r['psnr']:.2f} / {r['ssim']:.3f} ({ratio}{fit})")
        lines.append(f"| {s} | " + " | ".join(cells) + " |")
    means = []
    for lab in labels:
        rs = [by[(s, lab)] for s in sets if (s, lab) in by]
        if not rs:
            means.append("")
            continue
        gain = [by[(r["set"], lab)]["psnr"] - by[(r["set"], "raw")]["psnr"] for r in rs if (r["set"], "raw") in by]
        means.append(f"{np.mean([r['psnr'] for r in rs]):.2f} / {np.mean([r['ssim'] for r in rs]):.3f}"
                     + (f" ({np.mean(gain):+.2f} dB vs raw, min {min(gain):+.2f}; "
                        f"{np.mean([r['fit_s'] for r in rs]):.0f} s)" if gain and lab != "raw" else ""))
    lines.append(f"| **mean of {len(sets)}** | " + " | ".join(means) + " |")
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")


def write_chart(rows: List[Dict[str, Any]], labels: List[str], path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    by = {(r["set"], r["method"]): r for r in rows}
    fig, ax = plt.subplots(figsize=(8, 5))
    cmap = plt.get_cmap("tab10")
    for i, lab in enumerate(labels):
        pts = [(r["bytes"] / by[(r["set"], "raw")]["bytes"], r["psnr"] - by[(r["set"], "raw")]["psnr"])
               for r in rows if r["method"] == lab and (r["set"], "raw") in by]
        if not pts:
            continue
        x, y = np.array(pts).T
        ax.scatter(x, y, s=12, alpha=0.45, color=cmap(i % 10))
        ax.scatter([np.exp(np.mean(np.log(x)))], [np.mean(y)], s=90, color=cmap(i % 10), edgecolor="black",
                   label=f"{lab} ({np.mean(y):+.2f} dB)", zorder=3)
    ax.axhline(0.0, color="grey", lw=0.8)
    ax.set_xscale("log")
    ax.set_xlabel("bytes / bytes of the training photographs (log)")
    ax.set_ylabel("PSNR gain over raw interpolation (dB)")
    ax.set_title(f"Predicting unseen lights: {len({r['set'] for r in rows})} sets (large: means)")
    ax.legend(fontsize=8, loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("dirs", nargs="+", help="folders holding SynthRTI sets or RTI captures")
    ap.add_argument("--out", default="bench-results/rti", help="where results.json, table.md and the chart go")
    ap.add_argument("--methods", default=",".join(m[0] for m in METHODS),
                    help="comma-separated labels of the methods to run (default: all)")
    ap.add_argument("--sets", default="*", help="a glob the set names must match (default: all)")
    ap.add_argument("--fresh", action="store_true", help="recompute the rows of these methods and sets already in results.json "
                    "(one run at a time per --out folder: each rewrites results.json)")
    args = ap.parse_args(argv)
    try:
        import skimage  # noqa: F401
    except ImportError:
        sys.exit("rti_benchmark: needs scikit-image for SSIM: pip install scikit-image (or btfrs[bench])")
    wanted = args.methods.split(",")
    unknown = [w for w in wanted if w not in {m[0] for m in METHODS}]
    if unknown:
        sys.exit(f"rti_benchmark: unknown method(s) {unknown}; expected some of {[m[0] for m in METHODS]}")
    methods = [m for m in METHODS if m[0] in wanted]
    sets = [(n, f) for n, f in find_sets(args.dirs) if fnmatch.fnmatch(n, args.sets)]
    if not sets:
        sys.exit("rti_benchmark: no SynthRTI set or .lp capture found")
    os.makedirs(args.out, exist_ok=True)
    store = os.path.join(args.out, "results.json")
    rows: List[Dict[str, Any]] = []
    if os.path.exists(store):
        with open(store) as f:
            rows = json.load(f)
    if args.fresh:
        # Only the rows this run will recompute go: the other methods' and sets' stay.
        names = {n for n, _ in sets}
        rows = [r for r in rows if not (r["method"] in wanted and r["set"] in names)]
    done = {(r["set"], r["method"]) for r in rows}
    for name, folder in sets:
        todo = [m for m in methods if (name, m[0]) not in done]
        if not todo:
            continue
        train, test = load_set(folder)
        print(f"{name}: {train.height}x{train.width}, {train.lights.shape[0]} lights to fit, "
              f"{test.lights.shape[0]} to predict", flush=True)
        for label, kind, options in todo:
            r = run_method(label, kind, options, train, test)
            r["set"] = name
            rows = [x for x in rows if (x["set"], x["method"]) != (name, label)] + [r]
            print(f"  {label:<12} {r['psnr']:6.2f} dB  SSIM {r['ssim']:.3f}  rel {r['relative']:.4f}  "
                  f"{r['bytes'] / 1e3:9.1f} kB  {r['fit_s']:6.1f} s", flush=True)
            tmp = store + ".tmp"
            with open(tmp, "w") as f:
                json.dump(rows, f, indent=1)
            os.replace(tmp, store)
    labels = [m[0] for m in METHODS if any(r["method"] == m[0] for r in rows)]
    write_table(rows, labels, os.path.join(args.out, "table.md"))
    write_chart(rows, labels, os.path.join(args.out, "psnr_vs_bytes.png"))
    with open(os.path.join(args.out, "table.md")) as f:
        print(f.read())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
