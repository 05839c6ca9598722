"""Stability where methods fail: each model driven into the regimes the papers warn about.

``run(btf)`` builds, from one BTF and a seed, a series of *regimes*, each at a few *levels*
(level 0 is the clean case, later levels are harsher), fits every model to each, and records per
model x regime x level the held-out and reconstruction errors, the fit time, the model's own
report of its flags and fallbacks, whether every prediction is finite, and the error message if
the fit raised:

=====================  ==============================================================================
``decimation``         keep 90, 50, 25, 10, 5% of the pairs at random (paper 000, section 6: LM
                       fits of sparse samples "produce visual artifacts"); test on the rest
``uneven``             uneven subsets: lights in one azimuth half only, lights up to 45 degrees only,
                       views up to 30 degrees only (paper 000, section 6: uneven sampling)
``additive_noise``     Gaussian noise of 10, 30, 100% of the mean value on the training data
                       (paper 002, section 3.1: plain least squares of SH amplifies noise, CLS
                       bounds it); evaluated against the clean held-out data
``multiplicative``     ``x * (1 + s N)`` with s = 10, 30, 60%
``shadows``            hard shadows: a checkerboard of texel blocks black for lights below 30 or
                       45 degrees of elevation, or from one side (lx < 0)
``glossy``             a sharp Blinn-Phong spike (exponent 300) added to a quarter of the texels,
                       peaking at 1, 4, 16 times the mean value
``grazing``            training pairs with view and light both beyond 45 or 60 degrees from the
                       normal only; the held-out pairs are everywhere
``black``              5 or 25% of the texels all zero (their predictions must be finite zeros)
``saturated``          values clipped at the 99th, 95th, 80th percentile (a sensor's saturation)
``outliers``           0.01, 0.1, 1% of the training values times 1000 (hot pixels)
=====================  ==============================================================================

The held-out set is 10% of the pairs (``btf.split(holdout=0.1, seed=seed)``) except in the
``decimation`` regime, whose test set is every pair not kept. Where a regime changes the material
itself (shadows, glossy, black, saturated) the modified data are the truth for both halves;
noise and outliers touch only the training data and the test data stay clean.

>>> st = btfrs.stability.run(btf, models="all", seed=0)
>>> st.save("weave-stability/")        # report.json + one PNG chart per regime
>>> print(st.table())
"""

from __future__ import annotations

import json
import math
import os
import time
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np
from numpy.typing import NDArray

from . import fit as _fit
from ._checks import instance
from ._checks import seed as check_seed
from ._progress import Progress, callback
from .btf import Btf
from .exceptions import BtfrsError, InvalidArgumentError
from .io import atomic_write
from .models import model_kinds

__all__ = ["REGIMES", "StabilityReport", "default_models", "run"]

#: The regimes, in the order of the report.
REGIMES = ("decimation", "uneven", "additive_noise", "multiplicative", "shadows", "glossy", "grazing",
           "black", "saturated", "outliers")

_DESCRIPTION = {
    "decimation": "fraction of (view, light) pairs kept at random; test on the rest",
    "uneven": "training pairs from an uneven subset; test on 10% held out everywhere",
    "additive_noise": "Gaussian noise on the training data, sigma / mean value",
    "multiplicative": "training data x (1 + s N(0, 1))",
    "shadows": "hard shadows on a checkerboard of texel blocks",
    "glossy": "sharp specular spike (n = 300) on 25% of texels, peak / mean value",
    "grazing": "training pairs with theta_v and theta_l >= level only",
    "black": "fraction of texels all black",
    "saturated": "values clipped at a percentile (fraction of values clipped)",
    "outliers": "fraction of training values x 1000",
}

#: (label, kind, options) of one model setting.
_Setting = Tuple[str, str, Dict[str, Any]]
#: (level, label, train, test) of one regime level.
_Level = Tuple[float, str, Btf, Btf]
#: (view, light) query directions.
_Probe = Tuple[NDArray[np.float64], NDArray[np.float64]]

def default_models() -> List[_Setting]:
    """One cheap ``(label, kind, options)`` per registered kind: the first setting of its quick
    sweep (its registry entry chooses it; Lafortune's has two lobes, since one lobe hides the
    extrapolation of sparse fits that paper 000 warns about)."""
    out: List[_Setting] = []
    for kind, info in model_kinds().items():
        label, opts, _, _ = next(s for s in info["sweep"] if s[2])
        out.append((label, kind, dict(opts)))
    return out


def _models(models: Union[str, Sequence[Any]]) -> List[_Setting]:
    kinds = model_kinds()
    if isinstance(models, str):
        if models == "all":
            return default_models()
        models = [models]
    if not isinstance(models, (list, tuple)) or not models:
        raise InvalidArgumentError(f"models: expected \"all\", a list of model kinds or of (label, kind, options), "
                                   f"got {models!r}")
    defaults = {k: (lab, k, o) for lab, k, o in default_models()}
    out: List[_Setting] = []
    for m in models:
        if isinstance(m, str):
            if m not in kinds:
                raise InvalidArgumentError(f"models: unknown model kind {m!r}; expected one of {', '.join(kinds)}")
            out.append(defaults[m])
        elif isinstance(m, (tuple, list)) and len(m) == 3 and isinstance(m[0], str) and isinstance(m[2], dict):
            if m[1] not in kinds:
                raise InvalidArgumentError(f"models: unknown model kind {m[1]!r} in {m[0]!r}; "
                                           f"expected one of {', '.join(kinds)}")
            out.append((m[0], m[1], dict(m[2])))
        else:
            raise InvalidArgumentError(f"models: expected a model kind or a (label, kind, options) tuple, got {m!r}")
    labels = [m[0] for m in out]
    if len(set(labels)) != len(labels):
        raise InvalidArgumentError(f"models: labels must be distinct, got {labels}")
    return out


def _regimes(regimes: Union[str, Sequence[str]]) -> List[str]:
    if isinstance(regimes, str):
        regimes = list(REGIMES) if regimes == "all" else [regimes]
    if not isinstance(regimes, (list, tuple)) or not regimes:
        raise InvalidArgumentError(f"regimes: expected \"all\" or a list of {', '.join(REGIMES)}, got {regimes!r}")
    for r in regimes:
        if r not in REGIMES:
            raise InvalidArgumentError(f"regimes: unknown regime {r!r}; expected one of {', '.join(REGIMES)}")
    return list(regimes)


# ------------------------------------------------------------------------------------------------
# Regimes: each returns [(level, label, train, test), ...], level 0 (or the first) the clean case
# ------------------------------------------------------------------------------------------------


def _with(btf: Btf, data: NDArray[Any], mask: Optional[NDArray[np.bool_]]) -> Btf:
    return Btf(np.ascontiguousarray(data, dtype=np.float32), btf.views, btf.lights, mask, check=False)


def _theta_deg(d: NDArray[np.float64]) -> NDArray[np.float64]:
    theta: NDArray[np.float64] = np.degrees(np.arccos(np.clip(d[:, 2], -1.0, 1.0)))
    return theta


def _split(btf: Btf, seed: int) -> Tuple[Btf, Btf]:
    return btf.split(holdout=0.1, seed=seed)


def _decimation(btf: Btf, seed: int) -> List[_Level]:
    out: List[_Level] = []
    for keep in (0.9, 0.5, 0.25, 0.10, 0.05):
        tr, te = btf.split(holdout=1.0 - keep, seed=seed)
        out.append((keep, f"{100 * keep:g}%", tr, te))
    return out


def _subset(btf: Btf, train: Btf, keep: NDArray[np.bool_]) -> Btf:
    return _with(btf, btf.data, keep if train.mask is None else train.mask & keep)


def _uneven(btf: Btf, seed: int) -> List[_Level]:
    tr, te = _split(btf, seed)
    V, L = btf.n_views, btf.n_lights
    phi_l = np.degrees(np.arctan2(btf.lights[:, 1], btf.lights[:, 0])) % 360
    half = np.broadcast_to((phi_l < 180)[None, :], (V, L))  # lights in one azimuth half
    low_l = np.broadcast_to((_theta_deg(btf.lights) <= 45.0 + 1e-6)[None, :], (V, L))
    low_v = np.broadcast_to((_theta_deg(btf.views) <= 30.0 + 1e-6)[:, None], (V, L))
    return [(0, "all", tr, te),
            (1, "lights phi<180", _subset(btf, tr, half), te),
            (2, "lights theta<=45", _subset(btf, tr, low_l), te),
            (3, "views theta<=30", _subset(btf, tr, low_v), te)]


def _additive(btf: Btf, seed: int) -> List[_Level]:
    tr, te = _split(btf, seed)
    mean = float(btf.data.mean())
    rng = np.random.default_rng(seed)
    noise = rng.standard_normal(btf.data.shape, dtype=np.float32)
    return [(s, f"{100 * s:g}%", tr if s == 0 else _with(btf, btf.data + (s * mean) * noise, tr.mask), te)
            for s in (0.0, 0.1, 0.3, 1.0)]


def _multiplicative(btf: Btf, seed: int) -> List[_Level]:
    tr, te = _split(btf, seed)
    rng = np.random.default_rng(seed + 1)
    noise = rng.standard_normal(btf.data.shape, dtype=np.float32)
    return [(s, f"{100 * s:g}%", tr if s == 0 else _with(btf, btf.data * (1.0 + s * noise), tr.mask), te)
            for s in (0.0, 0.1, 0.3, 0.6)]


def _modified(btf: Btf, data: NDArray[Any], seed: int) -> Tuple[Btf, Btf]:
    """Train and test halves of a modified material (the modification is the truth)."""
    tr, te = _split(btf, seed)
    return _with(btf, data, tr.mask), _with(btf, data, te.mask)


def _blocks(btf: Btf, size: int = 4) -> NDArray[np.bool_]:
    """A checkerboard of ``size``-texel blocks: the texels a shadow falls on."""
    h, w = btf.height, btf.width
    r, c = np.meshgrid(np.arange(h) // size, np.arange(w) // size, indexing="ij")
    blocks: NDArray[np.bool_] = (r + c) % 2 == 1
    return blocks


def _shadows(btf: Btf, seed: int) -> List[_Level]:
    tr, te = _split(btf, seed)
    blk = _blocks(btf)
    out: List[_Level] = [(0, "none", tr, te)]
    theta_l = _theta_deg(btf.lights)
    for lvl, (label, dark) in enumerate([("lights theta>=60", theta_l >= 60 - 1e-6),
                                         ("lights theta>=45", theta_l >= 45 - 1e-6),
                                         ("lights lx<0", btf.lights[:, 0] < -1e-9)], start=1):
        d = btf.data.copy()
        sel = d[blk]                                   # [n, V, L, 3]
        sel[:, :, dark, :] = 0.0
        d[blk] = sel
        out.append((lvl, label, *_modified(btf, d, seed)))
    return out


def _glossy(btf: Btf, seed: int) -> List[_Level]:
    tr, te = _split(btf, seed)
    rng = np.random.default_rng(seed + 2)
    texels = rng.random((btf.height, btf.width)) < 0.25
    h = btf.views[:, None, :] + btf.lights[None, :, :]
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    spike = np.clip(h[..., 2], 0, 1) ** 300 * np.clip(btf.lights[None, :, 2], 0, 1)  # [V, L], peak 1
    mean = float(btf.data.mean())
    out: List[_Level] = [(0, "none", tr, te)]
    for a in (1.0, 4.0, 16.0):
        d = btf.data.copy()
        d[texels] += (a * mean * spike)[None, :, :, None].astype(np.float32)
        out.append((a, f"x{a:g}", *_modified(btf, d, seed)))
    return out


def _grazing(btf: Btf, seed: int) -> List[_Level]:
    tr, te = _split(btf, seed)
    out: List[_Level] = [(0, "all", tr, te)]
    for t in (45.0, 60.0):
        keep = (_theta_deg(btf.views)[:, None] >= t - 1e-6) & (_theta_deg(btf.lights)[None, :] >= t - 1e-6)
        out.append((t, f">={t:g} deg", _subset(btf, tr, keep), te))
    return out


def _black(btf: Btf, seed: int) -> List[_Level]:
    tr, te = _split(btf, seed)
    rng = np.random.default_rng(seed + 3)
    u = rng.random((btf.height, btf.width))
    out: List[_Level] = [(0.0, "0%", tr, te)]
    for f in (0.05, 0.25):
        d = btf.data.copy()
        d[u < f] = 0.0
        out.append((f, f"{100 * f:g}%", *_modified(btf, d, seed)))
    return out


def black_texels(train: Btf) -> NDArray[np.bool_]:
    """``[H, W]`` bool: texels whose every value is zero."""
    black: NDArray[np.bool_] = ~np.any(train.data != 0, axis=(2, 3, 4))
    return black


def _saturated(btf: Btf, seed: int) -> List[_Level]:
    tr, te = _split(btf, seed)
    out: List[_Level] = [(0.0, "none", tr, te)]
    for q in (99.0, 95.0, 80.0):
        c = float(np.percentile(btf.data, q))
        d = np.minimum(btf.data, c)
        out.append((1 - q / 100, f"{100 - q:g}% clipped", *_modified(btf, d, seed)))
    return out


def _outliers(btf: Btf, seed: int) -> List[_Level]:
    tr, te = _split(btf, seed)
    rng = np.random.default_rng(seed + 4)
    u = rng.random(btf.data.shape)
    out: List[_Level] = [(0.0, "0%", tr, te)]
    for f in (0.0001, 0.001, 0.01):
        d = np.where(u < f, btf.data * 1000.0, btf.data)
        out.append((f, f"{100 * f:g}%", _with(btf, d, tr.mask), te))
    return out


_BUILD: Dict[str, Callable[[Btf, int], List[_Level]]] = {
    "decimation": _decimation, "uneven": _uneven, "additive_noise": _additive, "multiplicative": _multiplicative,
    "shadows": _shadows, "glossy": _glossy, "grazing": _grazing, "black": _black, "saturated": _saturated,
    "outliers": _outliers,
}


def levels(btf: Btf, regime: str, seed: int = 0) -> List[_Level]:
    """The ``(level, label, train, test)`` of one regime (what :func:`run` fits)."""
    return _BUILD[_regimes(regime)[0]](instance("btf", btf, Btf, "a btfrs.Btf"), check_seed(seed))


# ------------------------------------------------------------------------------------------------
# Running
# ------------------------------------------------------------------------------------------------


def _probe_pairs(btf: Btf, seed: int, n: int = 24) -> List[_Probe]:
    """Query directions for the finiteness check: measured pairs and off-grid directions
    (between the measured ones, and near the horizon, where extrapolation shows first)."""
    rng = np.random.default_rng(seed + 99)
    out: List[_Probe] = []
    for _ in range(n // 2):
        out.append((btf.views[rng.integers(btf.n_views)], btf.lights[rng.integers(btf.n_lights)]))
    for _ in range(n - n // 2):
        th, ph = rng.uniform(0, np.radians(85), 2), rng.uniform(0, 2 * np.pi, 2)
        d = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=1)
        out.append((d[0], d[1]))
    return out


def flagged(report: Any) -> bool:
    """Whether a model's ``report`` says a fallback for bad data was taken: degenerate PTM slots,
    extrapolating or failed Lafortune fits (a few LM restarts, ``fell_back``, are routine)."""
    if not isinstance(report, dict):
        return False
    return bool(report.get("degenerate_slots")) or any(
        isinstance(report.get(k), (int, float)) and report[k] > 0 for k in ("extrapolated", "failed"))


def fallbacks(kind: str, report: Any) -> List[str]:
    """Short descriptions of the flags and fallbacks in a model's ``report``."""
    out: List[str] = []
    if not isinstance(report, dict):
        return out
    slots = report.get("degenerate_slots")
    if slots:
        acts: Dict[str, int] = {}
        for s in slots:
            acts[s.get("action", "?")] = acts.get(s.get("action", "?"), 0) + 1
        out.append(f"{len(slots)} degenerate slots (" + ", ".join(f"{k} {v}" for k, v in sorted(acts.items())) + ")")
    for key in ("extrapolated", "fell_back", "failed"):
        v = report.get(key)
        if isinstance(v, (int, float)) and v > 0:
            out.append(f"{key} {int(v)}/{report.get('fits', '?')}")
    return out


def _one(label: str, kind: str, options: Dict[str, Any], train: Btf, test: Btf,
         probes: List[_Probe], robust: bool = True) -> Dict[str, Any]:
    row: Dict[str, Any] = dict(model=label, kind=kind, options=options)
    t0 = time.perf_counter()
    try:
        m = _fit.fit(kind, train, robust=robust, **options)
    except BtfrsError as e:
        row.update(fit_seconds=time.perf_counter() - t0, error=f"{type(e).__name__}: {e}", held_out=None,
                   reconstruction=None, finite=True, report=None, fallbacks=[], flagged=False)
        return row
    row["fit_seconds"] = m.fit_seconds if m.fit_seconds is not None else time.perf_counter() - t0
    ho, rec = m.error(test), m.error(train)
    finite = all(math.isfinite(x) for x in (ho.rmse, ho.relative, rec.rmse, rec.relative))
    for v, l in probes:
        finite = finite and bool(np.all(np.isfinite(m.evaluate(v, l))))
    report = m.report
    row.update(held_out=ho.relative, held_out_rmse=ho.rmse, reconstruction=rec.relative, finite=finite,
               report=_jsonable(report), fallbacks=fallbacks(kind, report), flagged=flagged(report), error=None,
               nbytes=m.nbytes)
    row["_model"] = m
    return row


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (np.floating, float)):
        f = float(x)
        return f if math.isfinite(f) else str(f)
    return x


def run(btf: Btf, *, models: Union[str, Sequence[Any]] = "all", regimes: Union[str, Sequence[str]] = "all",
        seed: int = 0, progress: Progress = None, name: Optional[str] = None,
        keep_models: bool = False, robust: bool = True) -> "StabilityReport":
    """Fit every model in every regime at every level and collect the rows.

    Parameters
    ----------
    btf: the clean BTF the regimes are built from (a built-in material or measured data).
    models: ``"all"`` (one cheap setting of each registered kind, :func:`default_models`), a list
        of kinds, or of ``(label, kind, options)``.
    regimes: ``"all"`` or a list of :data:`REGIMES`.
    seed: every random choice (splits, noise, texels picked) follows from it.
    progress: None, True for a progress bar over the fits, or a callable ``(done, total)``.
    name: what the charts and the report call the material (default: the BTF's shape).
    keep_models: keep each fitted model in its row under ``"model_object"`` (for tests).
    robust: fit robustly (``robust=True`` of every fit; the suite's default); ``False`` shows
        what plain least squares does in the same regimes.
    """
    b = instance("btf", btf, Btf, "a btfrs.Btf")
    mods = _models(models)
    regs = _regimes(regimes)
    seed = check_seed(seed)
    report_progress: Optional[Callable[[int, int], object]] = callback(progress, "stability fits")
    probes = _probe_pairs(b, seed)
    built = [(r, _BUILD[r](b, seed)) for r in regs]
    total = sum(len(lv) for _, lv in built) * len(mods)
    done = 0
    if report_progress:
        report_progress(0, total)
    rows: List[Dict[str, Any]] = []
    # The clean level of most regimes is the same fit (the same data and split): fitted once.
    cache: Dict[Any, Dict[str, Any]] = {}
    for regime, lvls in built:
        for level, label, train, test in lvls:
            key_data = (id(train.data), _mask_bytes(train), id(test.data), _mask_bytes(test))
            for label_m, kind, options in mods:
                key = (label_m, key_data)
                if key not in cache:
                    cache[key] = _one(label_m, kind, options, train, test, probes, robust)
                row = dict(cache[key])
                m = row.pop("_model", None)
                if keep_models and m is not None:
                    row["model_object"] = m
                    row["train"], row["test"] = train, test
                rows.append(dict(regime=regime, level=level, level_label=label, **row))
                done += 1
                if report_progress:
                    report_progress(done, total)
    if name is None:
        h, w, v, l, _ = b.shape
        name = f"{h}x{w} texels, {v} x {l} directions"
    return StabilityReport(rows, material=str(name), seed=seed, models=mods, regimes=regs)


def _mask_bytes(btf: Btf) -> Optional[bytes]:
    return None if btf.mask is None else btf.mask.tobytes()


class StabilityReport:
    """The rows of :func:`run`: one dict per model x regime x level (``model``, ``kind``,
    ``regime``, ``level``, ``level_label``, ``held_out`` and ``reconstruction`` relative errors,
    ``fit_seconds``, ``report`` (the model's own flags), ``fallbacks`` (short descriptions),
    ``flagged`` (a fallback for bad data was taken), ``finite``, ``error`` (the message when the fit
    raised, else None))."""

    def __init__(self, rows: List[Dict[str, Any]], *, material: str, seed: int, models: List[_Setting],
                 regimes: List[str]) -> None:
        self.rows = rows
        self.material = material
        self.seed = seed
        self.models = models
        self.regimes = regimes

    def curve(self, model: str, regime: str) -> List[Tuple[float, Optional[float]]]:
        """``[(level, held_out), ...]`` of one model in one regime (None where the fit raised)."""
        return [(r["level"], r["held_out"]) for r in self.rows if r["model"] == model and r["regime"] == regime]

    def row(self, model: str, regime: str, level: float) -> Dict[str, Any]:
        for r in self.rows:
            if r["model"] == model and r["regime"] == regime and r["level"] == level:
                return r
        raise InvalidArgumentError(f"no row for model {model!r}, regime {regime!r}, level {level!r}")

    def to_dict(self) -> Dict[str, Any]:
        skip = ("model_object", "train", "test")
        return dict(material=self.material, seed=self.seed,
                    models=[dict(label=a, kind=k, options=o) for a, k, o in self.models],
                    regimes={r: _DESCRIPTION[r] for r in self.regimes},
                    rows=[_jsonable({k: v for k, v in r.items() if k not in skip}) for r in self.rows])

    def table(self) -> str:
        """A markdown table: per regime and level, each model's held-out relative error, with
        ``!`` for a fit that raised, ``NaN!`` for non-finite output and ``*`` for fallbacks taken."""
        labels = [m[0] for m in self.models]
        lines = ["| regime | level | " + " | ".join(labels) + " |", "|---|---|" + "---:|" * len(labels)]
        for regime in self.regimes:
            seen: List[str] = []
            for r in self.rows:
                if r["regime"] == regime and r["level_label"] not in seen:
                    seen.append(r["level_label"])
            for lab in seen:
                cells = []
                for m in labels:
                    hit = next((x for x in self.rows if x["regime"] == regime and x["level_label"] == lab
                              and x["model"] == m), None)
                    if hit is None:
                        cells.append("")
                    elif hit["error"]:
                        cells.append("raised!")
                    elif not hit["finite"]:
                        cells.append("NaN!")
                    else:
                        cells.append(f"{hit['held_out']:.3g}" + ("*" if hit["flagged"] else ""))
                lines.append(f"| {regime} | {lab} | " + " | ".join(cells) + " |")
        lines.append("")
        lines.append("Held-out relative error `||pred - gt|| / ||gt||`; `*` a fallback for bad data was taken (degenerate PTM slots, extrapolating or failed Lafortune fits: see report.json), "
                     "`raised!` the fit raised, `NaN!` a prediction was not finite.")
        return "\n".join(lines)

    def save(self, directory: Union[str, "os.PathLike[str]"]) -> List[str]:
        """Write ``report.json``, ``report.md`` and one chart ``<regime>.png`` per regime into
        ``directory`` (created); returns the paths written."""
        d = os.fspath(directory)
        os.makedirs(d, exist_ok=True)
        paths: List[str] = []
        p = os.path.join(d, "report.json")
        with atomic_write(p, "w") as f:
            json.dump(self.to_dict(), f, indent=1)
        paths.append(p)
        p = os.path.join(d, "report.md")
        with atomic_write(p, "w") as f:
            f.write(f"# Stability: {self.material}, seed {self.seed}\n\n" + self.table() + "\n")
        paths.append(p)
        for regime in self.regimes:
            p = os.path.join(d, f"{regime}.png")
            self._chart(regime, p)
            paths.append(p)
        return paths

    def _chart(self, regime: str, path: str) -> None:
        import matplotlib  # heavy (~0.5 s): only for the charts, so `import btfrs` stays light

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt  # after use("Agg"); heavy, charts only

        rows = [r for r in self.rows if r["regime"] == regime]
        labels: List[str] = []
        for r in rows:
            if r["level_label"] not in labels:
                labels.append(r["level_label"])
        x = {lab: i for i, lab in enumerate(labels)}
        fig, ax = plt.subplots(figsize=(7.5, 4.6), dpi=110)
        vals = [r["held_out"] for r in rows if r["held_out"] is not None and math.isfinite(r["held_out"])]
        vals = [v for v in vals if v > 0]
        log = bool(vals) and max(vals) / min(vals) > 20
        top = max(vals) * (3 if log else 1.15) if vals else 1.0
        markers = "osD^v<>ph*"
        for i, (name, _, _) in enumerate(self.models):
            mr = [r for r in rows if r["model"] == name]
            xs = [x[r["level_label"]] for r in mr if r["held_out"] is not None]
            ys = [r["held_out"] for r in mr if r["held_out"] is not None]
            line, = ax.plot(xs, ys, marker=markers[i % len(markers)], label=name)
            fb = [(x[r["level_label"]], r["held_out"]) for r in mr if r["held_out"] is not None and r["flagged"]]
            if fb:
                fx, fy = zip(*fb)
                ax.scatter(fx, fy, s=140, facecolors="none", edgecolors=line.get_color(), linewidths=1.5)
            bad = [x[r["level_label"]] for r in mr if r["error"] or not r["finite"]]
            if bad:
                ax.scatter(bad, [top] * len(bad), marker="x", s=80, color=line.get_color())
        if log:
            ax.set_yscale("log")
        ax.set_xticks(range(len(labels)))
        ax.set_xticklabels(labels, rotation=15 if max(len(s) for s in labels) > 8 else 0)
        ax.set_xlabel(_DESCRIPTION[regime])
        ax.set_ylabel("held-out relative error" + (" (log)" if log else ""))
        ax.set_title(f"{regime}: {self.material}", fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8, loc="best", title="ring: fallback taken; x: raised / non-finite",
                  title_fontsize=7)
        fig.tight_layout()
        with atomic_write(path, "wb") as f:
            fig.savefig(f, format="png")
        plt.close(fig)

    def __repr__(self) -> str:
        return f"StabilityReport({len(self.rows)} rows, {len(self.models)} models, regimes {', '.join(self.regimes)})"
