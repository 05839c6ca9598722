"""The before/after chart of robust fitting: every model's held-out error on grooves 16² as
0.01, 0.1 and 1% of the training values are multiplied by 1000, fitted plain (``robust=False``)
and robust (``robust=True``), from two runs of the stability suite's ``outliers`` regime.

    python scripts/robust_chart.py docs/charts/robust_outliers.png
"""

from __future__ import annotations

import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import btfrs  # noqa: E402
from btfrs import stability  # noqa: E402


def main(out: str) -> None:
    btf = btfrs.materials.make("grooves", size=16, seed=0)
    runs = {rb: stability.run(btf, regimes=["outliers"], seed=0, robust=rb, progress=True) for rb in (False, True)}
    models = [m[0] for m in runs[True].models]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), sharey=True)
    for ax, rb in zip(axes, (False, True)):
        for model in models:
            rs = [r for r in runs[rb].rows if r["model"] == model]
            xs = [max(r["level"], 1e-5) * 100 for r in rs]
            ax.plot(xs, [r["held_out"] for r in rs], marker="o", label=model)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("training values x1000 (%; 0% plotted at 0.001%)")
        ax.set_title("robust=False (plain least squares)" if not rb else "robust=True (the screen)")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel("held-out relative error")
    axes[1].legend(fontsize=7, loc="upper left")
    fig.suptitle("Hot pixels on grooves 16²: held-out error of every model")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "docs/charts/robust_outliers.png")
