"""Plain numpy baselines that btfrs is measured against (in the benchmark, the demo and tests).

These are written the way a careful numpy user would write them, in float64, so that speed
ratios and accuracy comparisons are against a fair reference rather than a straw man.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Callable, Dict, List, Optional, Tuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..btf import Btf

__all__ = ["ptm_rgb_numpy", "ptm_error", "nearest_lights_interpolation", "interp_weights", "present_pair_weights",
           "raw_interpolation", "crop", "lafortune_scipy", "real_sh", "sh_numpy_lstsq", "sh_error", "lpca_sklearn",
           "lpca_sklearn_fit", "Peer", "PEERS"]


def _basis(lights: np.ndarray) -> np.ndarray:
    lx, ly = lights[:, 0], lights[:, 1]
    return np.stack([lx * lx, ly * ly, lx * ly, lx, ly, np.ones_like(lx)], axis=1)


def ptm_rgb_numpy(btf: Btf) -> np.ndarray:
    """PTM-RGB the numpy way: ``numpy.linalg.pinv`` per view slot, applied to all texels with one
    BLAS contraction per slot. Returns ``[H, W, V, 3, 6]`` float64."""
    h, w, v, l, _ = btf.shape
    out = np.empty((h, w, v, 3, 6))
    for vi in range(v):
        ls = np.arange(l) if btf.mask is None else np.flatnonzero(btf.mask[vi])
        p = np.linalg.pinv(_basis(btf.lights[ls]))  # [6, n]
        x = btf.data[:, :, vi, ls, :]  # [h, w, n, 3]
        out[:, :, vi] = np.einsum("kn,hwnc->hwck", p, x, optimize=True)
    return out


def nearest_lights_interpolation(train: Btf, test: Btf, k: int = 3) -> tuple[float, float]:
    """Held-out relative error of the simplest predictor: for each test pair, the inverse-angle
    weighted mean of the ``k`` nearest present lights of the same view slot (raw data, no model).
    Returns ``(relative error ||pred - gt|| / ||gt||, RMSE)`` over all test values."""
    num = den = 0.0
    n = 0
    for v in range(test.n_views):
        ls_test = np.flatnonzero(test.mask[v]) if test.mask is not None else np.arange(test.n_lights)
        ls_train = np.flatnonzero(train.mask[v]) if train.mask is not None else np.arange(train.n_lights)
        if len(ls_test) == 0 or len(ls_train) == 0:
            continue
        ang = np.arccos(np.clip(test.lights[ls_test] @ train.lights[ls_train].T, -1, 1))  # [nt, ntr]
        near = np.argsort(ang, axis=1)[:, :k]
        wgt = 1.0 / np.maximum(np.take_along_axis(ang, near, 1), 1e-9)
        wgt /= wgt.sum(axis=1, keepdims=True)
        src = train.data[:, :, v][:, :, ls_train[near]]  # [h, w, nt, k, 3]
        pred = np.einsum("hwtkc,tk->hwtc", src.astype(np.float64), wgt)
        gt = test.data[:, :, v][:, :, ls_test].astype(np.float64)
        num += float(np.sum((pred - gt) ** 2))
        den += float(np.sum(gt**2))
        n += gt.size
    return float(np.sqrt(num / den)), float(np.sqrt(num / max(n, 1)))


def crop(btf: Btf, rows: slice, cols: slice) -> Btf:
    """A texel window of ``btf`` (a copy), same directions and mask."""
    return Btf(np.ascontiguousarray(btf.data[rows, cols]), btf.views, btf.lights, btf.mask)


def _present(btf: Btf) -> Tuple[NDArray[np.intp], NDArray[np.intp]]:
    """(view index, light index) of every present pair."""
    if btf.mask is None:
        v, l = np.meshgrid(np.arange(btf.n_views), np.arange(btf.n_lights), indexing="ij")
        return v.ravel(), l.ravel()
    v_idx, l_idx = np.nonzero(btf.mask)
    return v_idx, l_idx


def lafortune_scipy(train: Btf, test: Btf, lobes: int = 2, jac: str = "2-point") -> Dict[str, Any]:
    """The Lafortune luminance model fitted per texel with ``scipy.optimize.least_squares(method="lm")``,
    the way a scipy user writes it: a vectorised numpy residual over the texel's present samples,
    ``value = l_z (kd + sum_i max(Cx lx vx + Cy ly vy + Cz lz vz, 0)^n_i)`` times a base colour
    (least-squares modulation of the luminance), the exponent clipped to [1, 200] inside the
    model (MINPACK's LM has no bounds). ``jac="2-point"`` is scipy's default (finite differences);
    pass a callable-free ``"analytic"`` to give it the exact Jacobian.

    Returns ``{"seconds_per_texel", "held_out", "reconstruction", "texels"}`` (relative errors
    over all texels of the window, RGB)."""
    from scipy.optimize import least_squares  # optional (test/bench extras): only this baseline needs it

    vi, li = _present(train)
    tv, tl = _present(test)

    def geom(v_idx: NDArray[np.intp], l_idx: NDArray[np.intp], b: Btf) -> Tuple[NDArray[Any], NDArray[Any]]:
        vv, ll = b.views[v_idx], b.lights[l_idx]
        return vv * ll, ll[:, 2]

    p_tr, lz_tr = geom(vi, li, train)
    p_te, lz_te = geom(tv, tl, test)

    def model(x: NDArray[Any], p: NDArray[Any], lz: NDArray[Any]) -> NDArray[Any]:
        out = np.full(len(lz), x[0])
        for i in range(lobes):
            c = x[1 + 4 * i: 4 + 4 * i]
            n = np.clip(x[4 + 4 * i], 1.0, 200.0)
            s = np.maximum(p @ c, 0.0)
            out = out + s**n
        value: NDArray[Any] = lz * out
        return value

    def jacobian(x: NDArray[Any], p: NDArray[Any], lz: NDArray[Any], _y: NDArray[Any]) -> NDArray[Any]:
        j = np.zeros((len(lz), len(x)))
        j[:, 0] = lz
        for i in range(lobes):
            c = x[1 + 4 * i: 4 + 4 * i]
            n = np.clip(x[4 + 4 * i], 1.0, 200.0)
            s = p @ c
            pos = s > 0
            sp = np.where(pos, s, 1.0)
            sn = np.where(pos, sp**n, 0.0)
            j[:, 1 + 4 * i: 4 + 4 * i] = (lz * np.where(pos, n * sn / sp, 0.0))[:, None] * p
            j[:, 4 + 4 * i] = lz * np.where(pos, sn * np.log(sp), 0.0)
        return j

    h, w = train.height, train.width
    num_te = den_te = num_tr = den_tr = 0.0
    t0 = time.perf_counter()
    for r in range(h):
        for c in range(w):
            y_rgb = train.data[r, c][vi, li].astype(np.float64)  # [n, 3]
            y = y_rgb.mean(axis=1)
            den = float(np.sum(y * y))
            base = (y @ y_rgb) / den if den > 0 else np.zeros(3)
            x0 = [0.5 * float(np.mean(y / np.maximum(lz_tr, 1e-3)))]
            for i in range(lobes):
                x0 += [-0.8, -0.8, 0.9, 4.0 * 4**i]
            kw = {"jac": (lambda x, p=p_tr, lz=lz_tr, yy=y: jacobian(x, p, lz, yy))} if jac == "analytic" else {}
            fit = least_squares(lambda x: model(x, p_tr, lz_tr) - y, np.array(x0), method="lm", **kw)
            pred_tr = model(fit.x, p_tr, lz_tr)[:, None] * base
            pred_te = model(fit.x, p_te, lz_te)[:, None] * base
            gt_te = test.data[r, c][tv, tl].astype(np.float64)
            num_tr += float(np.sum((pred_tr - y_rgb) ** 2))
            den_tr += float(np.sum(y_rgb**2))
            num_te += float(np.sum((pred_te - gt_te) ** 2))
            den_te += float(np.sum(gt_te**2))
    secs = time.perf_counter() - t0
    return {"seconds_per_texel": secs / (h * w), "held_out": float(np.sqrt(num_te / den_te)),
            "reconstruction": float(np.sqrt(num_tr / den_tr)), "texels": h * w}


def real_sh(n: int, dirs: np.ndarray) -> np.ndarray:
    """``[len(dirs), n]`` real orthonormal spherical harmonics (n a perfect square) from scipy's
    complex ones (Condon-Shortley phase included, as btfrs's): ``sqrt(2) Re Y_L^M`` for M > 0,
    ``sqrt(2) Im Y_L^|M|`` for M < 0, index ``L(L+1)+M``. An independent construction of the
    basis btfrs computes by recurrences."""
    from scipy import special  # optional (test/bench extras): only this baseline needs it

    d = np.asarray(dirs, dtype=np.float64)
    theta = np.arccos(np.clip(d[:, 2], -1, 1))
    phi = np.arctan2(d[:, 1], d[:, 0])
    deg = int(round(np.sqrt(n))) - 1
    out = np.empty((len(d), n))
    for L in range(deg + 1):
        for M in range(-L, L + 1):
            y = special.sph_harm_y(L, abs(M), theta, phi)
            if M == 0:
                v = y.real
            elif M > 0:
                v = np.sqrt(2) * y.real
            else:
                v = np.sqrt(2) * y.imag
            out[:, L * (L + 1) + M] = v
    return out


def sh_numpy_lstsq(train: Btf, view_coeffs: int = 25, light_coeffs: int = 25) -> Dict[str, Any]:
    """Double SH by plain least squares the numpy way: the Kronecker design matrix over the
    present pairs and one ``numpy.linalg.lstsq`` for every texel and channel at once.
    Returns ``{"seconds", "coeffs" [H, W, 3, kv, kl], "predict": f(view_idx, light_idx) ...}``."""
    vi, li = _present(train)
    t0 = time.perf_counter()
    yv = real_sh(view_coeffs, train.views)
    yl = real_sh(light_coeffs, train.lights)
    a = (yv[vi][:, :, None] * yl[li][:, None, :]).reshape(len(vi), -1)  # [M, kv*kl]
    h, w = train.height, train.width
    b = train.data[:, :, vi, li, :].astype(np.float64)  # [h, w, M, 3]
    b = np.moveaxis(b, 2, 0).reshape(len(vi), -1)
    coef, *_ = np.linalg.lstsq(a, b, rcond=None)  # [kv*kl, h*w*3]
    secs = time.perf_counter() - t0
    c = coef.reshape(view_coeffs, light_coeffs, h, w, 3).transpose(2, 3, 4, 0, 1)
    return {"seconds": secs, "coeffs": c}


def sh_error(coeffs: np.ndarray, btf: Btf) -> float:
    """Relative error of double-SH coefficients ``[H, W, 3, kv, kl]`` against ``btf``'s present pairs."""
    kv, kl = coeffs.shape[3], coeffs.shape[4]
    vi, li = _present(btf)
    yv = real_sh(kv, btf.views)[vi]
    yl = real_sh(kl, btf.lights)[li]
    pred = np.einsum("hwcij,mi,mj->hwmc", coeffs, yv, yl, optimize=True)
    gt = btf.data[:, :, vi, li, :].astype(np.float64)
    return float(np.linalg.norm(pred - gt) / np.linalg.norm(gt))


def lpca_sklearn(btf: Btf, clusters: int = 32, components: int = 4, seed: int = 0) -> Dict[str, Any]:
    """Local PCA the scikit-learn way: ``KMeans(k-means++)`` over the texels' ABRDFs, then a
    ``PCA(components)`` per cluster, float32 throughout. Reconstruction error over all present
    samples (as paper 004 reports it); ``nbytes`` counts float32 Eigen-BRDFs and weights and a
    2-byte cluster id per texel. Returns ``{"seconds", "reconstruction", "nbytes"}``."""
    r = lpca_sklearn_fit(btf, clusters, components, seed)
    return {k: r[k] for k in ("seconds", "reconstruction", "nbytes")}


def _angles(dirs: ArrayLike, q: NDArray[np.float64]) -> NDArray[np.float64]:
    """Angles between each of ``dirs`` [n, 3] and ``q`` [3] (atan2 of |cross| and dot: accurate
    near 0, unlike arccos of the dot)."""
    d = np.asarray(dirs, dtype=np.float64)
    angles: NDArray[np.float64] = np.arctan2(np.linalg.norm(np.cross(d, q), axis=1), d @ q)
    return angles


def interp_weights(dirs: ArrayLike, query: ArrayLike, k: int = 3) -> List[Tuple[int, float]]:
    """Interpolation weights over the ``k`` nearest of ``dirs`` as ``[(index, weight)]``, in
    numpy: inverse angular distance minus that of the (k+1)-th nearest (continuous as the query
    moves), normalised; a query on a direction gets it alone. The same rule as
    ``btfrs_core::directions::interp_weights`` (what the PTM's slot blend and the raw renderer
    use), written independently."""
    ang = _angles(dirs, np.asarray(query, dtype=np.float64))
    order = np.argsort(ang, kind="stable")
    if ang[order[0]] < 1e-9:
        return [(int(order[0]), 1.0)]
    k = int(np.clip(k, 1, len(ang)))
    cut = 1.0 / ang[order[k]] if k < len(ang) else 0.0
    w = np.maximum(1.0 / ang[order[:k]] - cut, 0.0)
    w = w / w.sum() if w.sum() > 0 else np.full(k, 1.0 / k)
    return [(int(i), float(x)) for i, x in zip(order[:k], w) if x > 0]


def present_pair_weights(train: Btf, view: ArrayLike, light: ArrayLike) -> List[Tuple[int, int, float]]:
    """``[(view index, light index, weight)]`` interpolating ``train`` at (view, light) over its
    *present* pairs: the 3 x 3 product of :func:`interp_weights`, restricted to present pairs and
    renormalised; where none is present, inverse summed-angle weights over the 4 nearest present
    pairs at a non-zero distance (so a held-out pair is never read, even at its own directions)."""
    mask = np.ones((train.n_views, train.n_lights), bool) if train.mask is None else train.mask
    out = [(v, l, wv * wl) for v, wv in interp_weights(train.views, view) for l, wl in interp_weights(train.lights, light)
           if mask[v, l] and wv * wl > 0]
    tot = sum(x[2] for x in out)
    if tot > 0:
        return [(v, l, x / tot) for v, l, x in out]
    d = _angles(train.views, np.asarray(view, float))[:, None] + _angles(train.lights, np.asarray(light, float))[None, :]
    d = np.where(mask & (d > 1e-9), d, np.inf)
    near = np.argsort(d, axis=None)[:4]
    vv, ll = np.unravel_index(near, d.shape)
    keep = np.isfinite(d[vv, ll])
    inv = 1.0 / d[vv[keep], ll[keep]]
    return [(int(v), int(l), float(x)) for v, l, x in zip(vv[keep], ll[keep], inv / inv.sum())]


def raw_interpolation(train: Btf, test: Btf) -> float:
    """Held-out relative error ``||pred - gt|| / ||gt||`` of interpolating the measured values of
    ``train`` (:func:`present_pair_weights`) at every present pair of ``test`` (whose directions
    may differ from ``train``'s: the whole-directions protocol). float64 accumulation."""
    num = den = 0.0
    tmask = np.ones((test.n_views, test.n_lights), bool) if test.mask is None else test.mask
    for v, l in zip(*np.nonzero(tmask)):
        pred = np.zeros(test.data.shape[:2] + (3,))
        for tv, tl, wgt in present_pair_weights(train, test.views[v], test.lights[l]):
            pred += wgt * train.data[:, :, tv, tl]
        gt = test.data[:, :, v, l].astype(np.float64)
        num += float(np.sum((pred - gt) ** 2))
        den += float(np.sum(gt * gt))
    return float(np.sqrt(num / den)) if den > 0 else float("nan")


def ptm_error(coeffs: np.ndarray, fitted: Btf, test: Btf) -> float:
    """Relative error of PTM-RGB coefficients ``[H, W, V, 3, 6]`` (fitted on ``fitted``'s view
    slots) at the present pairs of ``test``; between slots, the :func:`interp_weights` blend of
    the 3 nearest slots, as btfrs's PTM does."""
    tmask = np.ones((test.n_views, test.n_lights), bool) if test.mask is None else test.mask
    num = den = 0.0
    for v in range(test.n_views):
        ls = np.flatnonzero(tmask[v])
        if len(ls) == 0:
            continue
        c = sum(w * coeffs[:, :, s] for s, w in interp_weights(fitted.views, test.views[v]))  # [H, W, 3, 6]
        pred = np.einsum("hwck,nk->hwnc", c, _basis(test.lights[ls]), optimize=True)
        gt = test.data[:, :, v][:, :, ls].astype(np.float64)
        num += float(np.sum((pred - gt) ** 2))
        den += float(np.sum(gt * gt))
    return float(np.sqrt(num / den))


def lpca_sklearn_fit(btf: Btf, clusters: int = 32, components: int = 4, seed: int = 0) -> Dict[str, Any]:
    """:func:`lpca_sklearn` on the present pairs of ``btf`` (masked or not), also returning the
    reconstruction as a Btf with ``btf``'s directions and mask (``"reconstructed"``), which
    :func:`raw_interpolation` fills in at held-out pairs (btfrs's LPCA fills its Eigen-BRDFs'
    held-out entries by the same interpolation)."""
    from sklearn.cluster import KMeans  # optional (test/bench extras), heavy: only this baseline
    from sklearn.decomposition import PCA  # optional (test/bench extras), heavy: only this baseline

    vi, li = _present(btf)
    x = btf.data[:, :, vi, li, :].reshape(btf.height * btf.width, -1)
    t0 = time.perf_counter()
    km = KMeans(n_clusters=clusters, init="k-means++", n_init=1, random_state=seed).fit(x)
    rec = np.empty_like(x)
    for k in range(clusters):
        idx = np.flatnonzero(km.labels_ == k)
        if len(idx) == 0:
            continue
        if len(idx) < 2:
            rec[idx] = x[idx].mean(axis=0)
            continue
        pca = PCA(n_components=min(components, len(idx) - 1), random_state=seed).fit(x[idx])
        rec[idx] = pca.inverse_transform(pca.transform(x[idx]))
    secs = time.perf_counter() - t0
    err = float(np.linalg.norm((rec - x).astype(np.float64)) / np.linalg.norm(x.astype(np.float64)))
    data = np.zeros_like(btf.data)
    data[:, :, vi, li, :] = rec.reshape(btf.height, btf.width, len(vi), 3)
    nbytes = 4 * clusters * (components + 1) * x.shape[1] + btf.height * btf.width * (2 + 4 * components)
    return {"seconds": secs, "reconstruction": err, "nbytes": nbytes,
            "reconstructed": Btf(data, btf.views, btf.lights, btf.mask, check=False)}


def evaluation_rows(b: Btf, splits: Dict[str, Tuple[Btf, Btf]], protocols: List[str], fit_split: Tuple[Btf, Btf],
                    texels: int, seed: int, notes: List[str]) -> List[Dict[str, Any]]:
    """The numpy / scipy / scikit-learn ways and raw interpolation as rows of
    :func:`btfrs.evaluate` (its ``baselines=``), on the same splits."""
    rows: List[Dict[str, Any]] = []
    h, w = b.height, b.width
    tr, _ = fit_split
    row: Dict[str, Any]

    # PTM-RGB by numpy pinv per view slot; between slots the same 3-nearest blend as btfrs.
    t0 = time.perf_counter()
    c = ptm_rgb_numpy(tr)
    row = dict(label="PTM-RGB", kind="ptm", options={"kind": "rgb"}, way="numpy pinv", fit_s=time.perf_counter() - t0,
               bytes=4 * c.size, reconstruction=ptm_error(c, tr, tr),
               note="float64 pinv per view slot, coefficients counted as float32")
    for p in protocols:
        ptr, pte = splits[p]
        cc = c if ptr is tr else ptm_rgb_numpy(ptr)
        row[f"heldout_{p}"] = ptm_error(cc, ptr, pte)
    rows.append(row)

    # Lafortune-Lum 2 by scipy's LM (analytic Jacobian) on a window of texels.
    rr, cc0 = h // 2, max(0, w // 2 - texels // 2)
    n = min(texels, w - cc0)
    win = (slice(rr, rr + 1), slice(cc0, cc0 + n))
    row = dict(label="Lafortune-Lum 2", kind="lafortune", options={"kind": "lum", "lobes": 2},
               way=f"scipy LM ({n} texels)", bytes=h * w * 12 * 4,
               note=f"scipy least_squares(method='lm', analytic Jacobian) on {n} texels of row {rr}; "
                    f"fit_s = seconds per texel x {h * w} texels; errors over those texels")
    for p in protocols:
        ptr, pte = splits[p]
        r = lafortune_scipy(crop(ptr, *win), crop(pte, *win), lobes=2, jac="analytic")
        row[f"heldout_{p}"] = r["held_out"]
        if ptr is tr:
            row["fit_s"] = r["seconds_per_texel"] * h * w
            row["reconstruction"] = r["reconstruction"]
    rows.append(row)
    notes.append(f"scipy Lafortune baseline: {n} texels fitted, its fit seconds scaled to all {h * w}")

    # LPCA by scikit-learn KMeans + PCA; held-out pairs filled by interpolating the reconstruction.
    row = dict(label="LPCA 32x4", kind="lpca", options={"clusters": 32, "components": 4},
               way="scikit-learn KMeans + PCA", note="held-out pairs interpolated from the reconstruction")
    k = min(32, h * w)
    for p in protocols:
        ptr, pte = splits[p]
        r = lpca_sklearn_fit(ptr, clusters=k, components=4, seed=seed)
        row[f"heldout_{p}"] = raw_interpolation(r["reconstructed"], pte)
        if ptr is tr:
            row.update(fit_s=r["seconds"], bytes=r["nbytes"], reconstruction=r["reconstruction"])
    rows.append(row)

    # Double SH 25x25 by numpy lstsq, on at most a 32 x 32 texel window (its time is linear in
    # the texels: scaled to all of them; bytes counted for all).
    sh_win = (slice(0, min(h, 32)), slice(0, min(w, 32)))
    nsh = min(h, 32) * min(w, 32)
    row = dict(label="SH-LS 25x25", kind="sh", options={"light_coeffs": 25, "view_coeffs": 25, "cls": False},
               way="numpy lstsq" + ("" if nsh == h * w else f" ({nsh} texels)"), bytes=4 * h * w * 3 * 625,
               note="float64 least squares, no CLS, coefficients counted as float32"
                    + ("" if nsh == h * w else f"; fitted on the top-left {min(h, 32)} x {min(w, 32)} texels, "
                                                f"fit_s scaled to all {h * w}"))
    for p in protocols:
        ptr, pte = splits[p]
        ctr, cte = (ptr, pte) if nsh == h * w else (crop(ptr, *sh_win), crop(pte, *sh_win))
        r = sh_numpy_lstsq(ctr, 25, 25)
        row[f"heldout_{p}"] = sh_error(r["coeffs"], cte)
        if ptr is tr:
            row.update(fit_s=r["seconds"] * h * w / nsh, reconstruction=sh_error(r["coeffs"], ctr))
    rows.append(row)
    if nsh < h * w:
        notes.append(f"numpy lstsq SH baseline: {nsh} texels fitted, its fit seconds scaled to all {h * w}")

    # Raw interpolation of the measured data (what the raw renderer does).
    row = dict(label="raw interpolation", kind="raw", options={}, way="raw", fit_s=None, bytes=b.nbytes,
               reconstruction=0.0, note="3 nearest views x 3 nearest lights of the measured data")
    for p in protocols:
        ptr, pte = splits[p]
        row[f"heldout_{p}"] = raw_interpolation(ptr, pte)
    rows.append(row)
    return rows


# --- the peers of the bench's settings ----------------------------------------------------------

#: The models table's rows of a peer: ``(train, test, label, options, fit_ours, lm_texels)``, with
#: ``fit_ours`` btfrs's fit of the same setting (for the rows that compare on the same texels).
PeerRows = Callable[[Btf, Btf, str, Dict[str, Any], Callable[[Btf], Any], int], List[Dict[str, Any]]]


@dataclass(frozen=True)
class Peer:
    """Another implementation of a btfrs fit, which a setting of the registry's bench facts names
    (``peer``): for the foundation table, ``fit`` (timed by the bench beside btfrs's fit) and
    ``compare`` (a note comparing btfrs's model with its result); for the models table, ``rows``."""

    fit: Optional[Callable[[Btf], Any]] = None
    compare: Optional[Callable[[Any, Any], str]] = None
    rows: Optional[PeerRows] = None


def _ptm_coeff_note(model: Any, ref: NDArray[np.float64]) -> str:
    diff = float(np.max(np.abs(model.coeffs - ref)) / np.max(np.abs(ref)))
    return f"max coeff diff {diff:.1e} (rel. to max)"


def _lafortune_rows(train: Btf, test: Btf, label: str, options: Dict[str, Any], fit_ours: Callable[[Btf], Any],
                    lm_texels: int) -> List[Dict[str, Any]]:
    """scipy's LM on a window of texels against btfrs on the same window. 64 texels (one row), so
    that btfrs's per-call setup (the candidate basis, the thread pool) is spread over as many
    texels as a real fit has, not 8; scipy's side is linear in texels (about 2-4 s here)."""
    size = train.height
    lm_texels = min(lm_texels, train.width)
    w = slice(size // 2, size // 2 + 1), slice(0, lm_texels)
    tr, te = crop(train, *w), crop(test, *w)
    t0 = time.perf_counter()
    ours = fit_ours(tr)
    ours_s = (time.perf_counter() - t0) / lm_texels
    rows = []
    for jac in ("2-point", "analytic"):
        r = lafortune_scipy(tr, te, lobes=int(options.get("lobes", 2)), jac=jac)
        rows.append(dict(model=label, way=f"scipy LM ({jac} Jacobian), {lm_texels} texels",
                         fit_s=r["seconds_per_texel"], per_texel=True, nbytes=None, held_out_rmse=None,
                         held_out=r["held_out"], reconstruction=r["reconstruction"], render_ms={},
                         btfrs_same=dict(fit_s=ours_s, held_out=ours.error(te).relative,
                                         reconstruction=ours.error(tr).relative)))
    return rows


def _lpca_rows(train: Btf, test: Btf, label: str, options: Dict[str, Any], fit_ours: Callable[[Btf], Any],
               lm_texels: int) -> List[Dict[str, Any]]:
    """scikit-learn KMeans + PCA at the same (clusters, components)."""
    r = lpca_sklearn(train, clusters=int(options["clusters"]), components=int(options["components"]),
                     seed=int(options.get("seed", 0)))
    return [dict(model=label, way="scikit-learn KMeans + PCA (float32)", fit_s=r["seconds"], nbytes=r["nbytes"],
                 held_out_rmse=None, held_out=None, reconstruction=r["reconstruction"], render_ms={})]


def _sh_rows(train: Btf, test: Btf, label: str, options: Dict[str, Any], fit_ours: Callable[[Btf], Any],
             lm_texels: int) -> List[Dict[str, Any]]:
    """numpy least squares for the double SH."""
    r = sh_numpy_lstsq(train, int(options["view_coeffs"]), int(options["light_coeffs"]))
    return [dict(model=label, way="numpy lstsq (float64, unquantized)", fit_s=r["seconds"],
                 nbytes=4 * r["coeffs"].size, held_out_rmse=None, held_out=sh_error(r["coeffs"], test),
                 reconstruction=sh_error(r["coeffs"], train), render_ms={})]


#: The peers by the names the registry's bench settings give them.
PEERS: Dict[str, Peer] = {
    "ptm_rgb_numpy": Peer(fit=ptm_rgb_numpy, compare=_ptm_coeff_note),
    "lafortune_scipy": Peer(rows=_lafortune_rows),
    "lpca_sklearn": Peer(rows=_lpca_rows),
    "sh_numpy_lstsq": Peer(rows=_sh_rows),
}
