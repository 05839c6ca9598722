"""Fitting reflectance models to a BTF: ``btfrs.fit.<model>(btf, ...)``.

Each function fits only the pairs present in ``btf`` (its mask), so fitting the train half of a
split never sees the held-out pairs, and returns a model with ``evaluate``, ``error``, ``nbytes``
and ``save`` (see :mod:`btfrs.models`).

Every function goes through :func:`fit`, which fits any registered model by name
(``btfrs.fit.fit("lpca", btf, clusters=8)``); the named functions add documentation and checks
of their options. A model registered in Rust without a function here is still reachable as
``btfrs.fit.<kind>`` (its options are checked by the model itself).

**Out of core.** Every fit reads the values in place, so a memory-mapped BTF
(``Btf.load(path, mmap=True)``) stays on disk but for the pages being read, which the kernel's
page cache holds and evicts as it needs, and a BTF larger than memory can be fitted. Every fit
takes ``memory_limit`` (bytes, or ``"64MB"``, ``"2GB"``, ``"512MiB"``): the anonymous memory it
may allocate besides the model it returns. The fits that work texel by texel (or view slot by
view slot over all texels: PTM, HSH, SRF, Lafortune) need a fixed 16 MB; double SH (8-bit), RBF
and bilinear hold every texel's float coefficients before quantizing them (and RBF and bilinear
one view slot's resampled data), so their least limit grows with the texels; LPCA sizes its
chunks by the limit (:func:`lpca`). A limit below what a fit needs raises
:class:`~btfrs.exceptions.InvalidArgumentError` naming ``memory_limit`` and the least it needs,
before any work.
"""

from __future__ import annotations

import json
import time
from typing import Union

from . import _native
from ._checks import boolean, choice, instance, integer, memory_size, real
from ._checks import seed as check_seed
from ._progress import Progress, callback
from .btf import Btf
from .exceptions import InvalidArgumentError
from .models import Bilinear, Hsh, Lafortune, LafortuneView, Lpca, Model, Ptm, Rbf, Sh, Srf, model_kinds, wrap

__all__ = ["fit", "ptm", "hsh", "srf", "lafortune", "lafortune_view", "sh", "lpca", "rbf", "bilinear"]


def _bits(bits) -> int:
    bits = integer("bits", bits)
    if bits not in (8, 32):
        raise InvalidArgumentError(f"bits: expected 8 (8-bit planes) or 32 (floats), got {bits}")
    return bits


def _check_btf(btf) -> Btf:
    return instance("btf", btf, Btf, "a btfrs.Btf")


MemoryLimit = Union[None, int, str]


def fit(model: str, btf: Btf, /, *, progress: Progress = None, memory_limit: MemoryLimit = None, **options) -> Model:
    """Fit the registered model ``model`` (a name of :func:`btfrs.models.model_kinds`) to the
    present pairs of ``btf``. ``options`` are the model's own (an unknown name or a wrong type
    raises :class:`~btfrs.exceptions.InvalidArgumentError` naming it); ``memory_limit`` is as
    for every fit (:func:`lpca`)."""
    return _fit(model, btf, f"{model} fit", progress, options, memory_limit)


def _fit(kind: str, btf: Btf, label: str, progress: Progress, options: dict, memory_limit: MemoryLimit = None) -> Model:
    b = _check_btf(btf)
    kind = choice("model", kind, tuple(model_kinds()))
    limit = memory_size("memory_limit", memory_limit)
    if limit is not None:
        options = {**options, "memory_limit": limit}
    t0 = time.perf_counter()
    m = _native.fit_model(kind, b.data, b.views, b.lights, b.mask, json.dumps(options), callback(progress, label))
    b._check_unchanged(label)
    return wrap(m, fit_seconds=time.perf_counter() - t0)


def __getattr__(name: str):
    # A model registered in Rust without a documented function here.
    if name in model_kinds():
        return lambda btf, /, *, progress=None, **options: fit(name, btf, progress=progress, **options)
    raise AttributeError(f"module 'btfrs.fit' has no attribute {name!r}")


def ptm(btf: Btf, *, kind: str = "rgb", rcond: float = 1e-6, on_degenerate: str = "reduce", bits: int = 8,
        memory_limit: MemoryLimit = None, progress: Progress = None) -> Ptm:
    """Fit a Polynomial Texture Map per view slot (paper 000, section 3.1).

    One SVD pseudo-inverse of the 6-column light design matrix per view slot, applied to every
    texel (float64 accumulation), so the fit costs one pass over the data.

    Parameters
    ----------
    kind: ``"rgb"`` (6 coefficients per channel) or ``"lrgb"`` (6 for the luminance + a base colour).
    rcond: singular values below ``rcond * s_max`` count as zero.
    on_degenerate: what a view slot with fewer than 6 lights or degenerate (e.g. collinear)
        lights gets. ``"reduce"`` (the default): the plane ``a3 lu + a4 lv + a5`` of its own
        lights, else the biquadratic of its lights pooled with the nearest views' lights; the same
        for a slot whose biquadratic would extrapolate (a prediction above 4 times its samples'
        range anywhere on the light directions); ``model.report["degenerate_slots"]`` lists each
        such slot, why and what was done. ``"raise"``: :class:`~btfrs.exceptions.DegenerateDataError`
        naming the slot. ``"clamp"``: the minimum-norm solution.
    bits: 8 (the default) stores the coefficients as 8-bit planes as a ``.ptm`` file does (per
        slot and coefficient index a scale and an integer bias shared by the channels; colours
        ``c / 255``), so ``nbytes`` is what a viewer holds and ``save_ptm`` writes these bytes;
        32 keeps the float32 coefficients.
    progress: None, True for a progress bar, or a callable ``(done, total)``.
    """
    b = _check_btf(btf)
    kind = choice("kind", kind, ("rgb", "lrgb"))
    rcond = real("rcond", rcond, min=0.0)
    on_degenerate = choice("on_degenerate", on_degenerate, ("reduce", "raise", "clamp"))
    bits = _bits(bits)
    return _fit("ptm", b, f"PTM-{kind.upper()} fit", progress,
                dict(kind=kind, rcond=rcond, on_degenerate=on_degenerate, bits=bits), memory_limit)


def hsh(btf: Btf, *, order: int = 3, lambda_: float = 1e-6, rcond: float = 1e-6, on_degenerate: str = "reduce",
        bits: int = 8, memory_limit: MemoryLimit = None, progress: Progress = None) -> Hsh:
    """Fit hemispherical harmonics per view slot (Gautron et al. 2004), the basis of ``.rti`` HSH
    files that RTIViewer and relight open, fitted like the PTM (paper 000, section 3.1): one
    regularised pseudo-inverse of the ``order**2``-column light design matrix per view slot,
    applied to every texel.

    The basis (term ``j = l (l + 1) + m``, ``x = cos(theta) = l_z``, ``s = sqrt(x - x^2)``,
    ``phi = atan2(l_y, l_x)``): ``1/sqrt(2 pi)``; ``sqrt(6/pi) s cos(phi)``,
    ``sqrt(3/(2 pi)) (2x - 1)``, ``sqrt(6/pi) s sin(phi)``; ``sqrt(30/pi) (x^2 - x) cos(2 phi)``, ... up to
    order 4, orthonormal on the hemisphere, with the RTI viewers' signs (full list in
    ``rust/btfrs-fit/src/hsh.rs``).

    Parameters
    ----------
    order: 1 to 4 (1, 4, 9 or 16 coefficients per channel).
    lambda_: ridge weight relative to the largest squared singular value of a slot's design
        matrix (0 = plain least squares).
    rcond: singular values below ``rcond * s_max`` count as zero.
    on_degenerate: as for :func:`ptm`; ``"reduce"`` fits a slot with too few or degenerate lights
        by a lower order of its own lights, else pools the nearest views' lights, and lists the
        slot in ``model.report["degenerate_slots"]``.
    bits: 8 (the default): 8-bit planes, the three channels of a slot and term sharing scale and
        bias (as a ``.rti`` file); 32 keeps float32.
    progress: None, True for a progress bar, or a callable ``(done, total)``.
    """
    b = _check_btf(btf)
    order = integer("order", order, min=1, max=4)
    lambda_ = real("lambda_", lambda_, min=0.0)
    rcond = real("rcond", rcond, min=0.0)
    on_degenerate = choice("on_degenerate", on_degenerate, ("reduce", "raise", "clamp"))
    bits = _bits(bits)
    return _fit("hsh", b, f"HSH-{order} fit", progress,
                dict(order=order, **{"lambda": lambda_}, rcond=rcond, on_degenerate=on_degenerate, bits=bits), memory_limit)


def srf(btf: Btf, *, memory_limit: MemoryLimit = None, progress: Progress = None) -> Srf:
    """Fit Phong + a spatially-varying residual function (paper 003, sections 4 and 5).

    One Blinn-Phong (kd, ks per channel, one shininess n) is fitted by Levenberg-Marquardt to
    the material's mean BRDF; the residual ``BTF - Phong`` is fitted per texel and channel as
    ``s(P) . H`` by linear least squares over the halfway vectors (one shared pseudo-inverse).
    ``model.report`` gives the relative error of Phong alone and of Phong + SRF on the fitted
    pairs.
    """
    b = _check_btf(btf)
    return _fit("srf", b, "SRF fit", progress, {}, memory_limit)


def lafortune(btf: Btf, *, kind: str = "lum", lobes: int = 2, diffuse: bool = True, max_iter: int = 60,
              densify: int = 0, memory_limit: MemoryLimit = None, progress: Progress = None) -> Lafortune:
    """Fit per-texel Lafortune lobes by Levenberg-Marquardt (paper 000, section 3.2).

    One fit per texel over all its present (view, light) samples (``kind="lum"``: the
    luminance with 1 to 7 lobes, times a base colour; ``kind="rgb"``: 1 to 3 lobes per
    channel), analytic Jacobians, bounds that keep the lobes physical. Paper 000 reports LM
    artifacts under sparse or uneven sampling: fits that diverge get a damped restart, then fewer
    lobes, then the diffuse-only closed form; ``model.report`` counts converged / fell back /
    failed fits and ``model.arrays["status"]`` flags each. ``densify=n`` adds an ``n x n``
    equal-area grid of view and light directions whose values are interpolated from the present
    pairs before fitting (the paper's remedy).
    """
    b = _check_btf(btf)
    kind = choice("kind", kind, ("lum", "rgb"))
    # The per-kind lobe limits (7 and 3) are checked in Rust, with the same message style.
    lobes = integer("lobes", lobes, min=1)
    diffuse = boolean("diffuse", diffuse)
    max_iter = integer("max_iter", max_iter, min=1)
    densify = integer("densify", densify, min=0)
    return _fit("lafortune", b, f"Lafortune-{kind} fit", progress,
                dict(kind=kind, lobes=lobes, diffuse=diffuse, max_iter=max_iter, densify=densify), memory_limit)


def lafortune_view(btf: Btf, *, kind: str = "lum", lobes: int = 2, diffuse: bool = True, max_iter: int = 60,
                   memory_limit: MemoryLimit = None, progress: Progress = None) -> LafortuneView:
    """Fit Lafortune lobes per texel and view slot, as paper 000 (section 3.2) does: "like the
    PTM", one lobe set per measured view, a function of the light, blended between the nearest
    view slots when rendered.

    The same Levenberg-Marquardt fit as :func:`lafortune` (kernels, initialisation, bounds,
    fallbacks, ``status`` and ``report`` counts) fed with one slot's samples at a time:
    ``kind="lum"`` (1 to 7 lobes on the luminance times a base colour per texel and slot) or
    ``kind="rgb"`` (1 to 3 lobes per channel). About ``V`` times the parameters of the global
    model (81 for the UBO sampling), and it follows how the reflectance changes with the view
    (parallax, masking) that one lobe set per texel cannot. A view slot with fewer present
    lights than a fit's unknowns borrows the lobes of the nearest fitted slot;
    ``model.report["borrowed_slots"]`` lists them and ``model.arrays["source"]`` maps each slot
    to the slot it uses.
    """
    b = _check_btf(btf)
    kind = choice("kind", kind, ("lum", "rgb"))
    # The per-kind lobe limits (7 and 3) are checked in Rust, with the same message style.
    lobes = integer("lobes", lobes, min=1)
    diffuse = boolean("diffuse", diffuse)
    max_iter = integer("max_iter", max_iter, min=1)
    return _fit("lafortune_view", b, f"per-view Lafortune-{kind} fit", progress,
                dict(kind=kind, lobes=lobes, diffuse=diffuse, max_iter=max_iter), memory_limit)


def sh(btf: Btf, *, light_coeffs: int = 25, view_coeffs: int = 25, cls: bool = True, quantize: bool = True,
       chunk_texels: int = 1024, memory_limit: MemoryLimit = None, progress: Progress = None) -> Sh:
    """Fit double spherical harmonics by constrained least squares (paper 002, section 3.1 and
    appendix).

    Real SH of ``light_coeffs`` and ``view_coeffs`` terms (perfect squares up to 64: 16, 25,
    36, ...). The CLS keeps each fit's coefficient energy within the function's (lambda found
    by bisection), which makes the coefficients robust to the 8-bit quantization that follows
    (``quantize=False`` keeps float32; ``cls=False`` is plain least squares, for comparison).
    Texels are processed ``chunk_texels`` at a time, so a memory-mapped BTF
    (``btfrs.Btf.load(path, mmap=True)``) streams through.
    """
    b = _check_btf(btf)
    # Perfect squares up to 64 are checked in Rust; here the type and the lower bound.
    light_coeffs = integer("light_coeffs", light_coeffs, min=1)
    view_coeffs = integer("view_coeffs", view_coeffs, min=1)
    cls = boolean("cls", cls)
    quantize = boolean("quantize", quantize)
    chunk_texels = integer("chunk_texels", chunk_texels, min=1)
    return _fit("sh", b, "double SH fit", progress, dict(light_coeffs=light_coeffs, view_coeffs=view_coeffs,
                                                         cls=cls, quantize=quantize, chunk_texels=chunk_texels), memory_limit)


def lpca(btf: Btf, *, clusters: int = 32, components: int = 4, seed: int = 0, kmeans_iterations: int = 25,
         refine_iterations: int = 2, reduced_dims: int = 64, memory_limit: MemoryLimit = None, progress: Progress = None) -> Lpca:
    """Fit Local PCA (paper 004, section 3): k-means++ (seeded) over the texels' ABRDFs, PCA per
    cluster with ``components`` Eigen-BRDFs, then 8-bit Eigen-BRDFs with the scales folded into
    the per-texel weights (section 6.3).

    k-means runs in a ``reduced_dims``-dimensional randomized PCA projection of the ABRDFs
    (0 = the full space) and is refined by ``refine_iterations`` passes that reassign each texel
    to the cluster whose subspace reconstructs it best (the LPCA objective itself).

    memory_limit: ``None`` (no limit), a number of bytes, or a size such as ``"64MB"`` or
        ``"2GB"`` (decimal units; ``"MiB"``, ``"GiB"`` are binary): the anonymous memory the fit
        may allocate besides the model it returns. Every fit takes it (see the module doc). Here
        the range finder's texel sample and every cluster too large for the limit are streamed
        through chunks sized by it, one cluster at a time, by randomized subspace iteration
        (clusters that fit keep the exact PCA), so the result is within a tolerance of the
        unlimited fit, not equal to it; the clustering itself (principal coordinates, k-means,
        refinement) grows with the texels, not with the values per texel, and is counted in
        the least limit the error message names.
    """
    b = _check_btf(btf)
    # "At most the texels" and "at most the pairs" are checked in Rust, which knows the counts.
    clusters = integer("clusters", clusters, min=1)
    components = integer("components", components, min=1)
    kmeans_iterations = integer("kmeans_iterations", kmeans_iterations, min=1)
    refine_iterations = integer("refine_iterations", refine_iterations, min=0)
    reduced_dims = integer("reduced_dims", reduced_dims, min=0)
    seed = check_seed(seed)
    return _fit("lpca", b, "LPCA fit", progress, dict(clusters=clusters, components=components,
                                                      kmeans_iterations=kmeans_iterations,
                                                      refine_iterations=refine_iterations,
                                                      reduced_dims=reduced_dims, seed=seed), memory_limit)


def _light_pca_options(components, colour, chroma_components, resolution, seed) -> dict:
    components = integer("components", components, min=1, max=64)
    colour = choice("colour", colour, ("rgb", "ycc"))
    if chroma_components is not None:
        chroma_components = integer("chroma_components", chroma_components, min=0, max=64)
    resolution = integer("resolution", resolution, min=2, max=32)
    return dict(components=components, colour=colour, chroma_components=chroma_components,
                resolution=resolution, seed=check_seed(seed))


def rbf(btf: Btf, *, components: int = 18, colour: str = "rgb", chroma_components=None, resolution: int = 12,
        width: float = 2.5, regularization: float = 0.1, seed: int = 0, memory_limit: MemoryLimit = None, progress: Progress = None) -> Rbf:
    """Fit relight's RBF light basis per view slot (the RTI default of relight).

    Per view slot and texel, the values under the slot's lights are interpolated by Gaussian
    radial basis functions (``f(l) = mu + sum_j a_j exp(-|l - l_j|^2 / 2 sigma^2)`` with
    ``(K + regularization I) a = y - mu``, ``mu`` the samples' mean), ``sigma = width`` times the
    light spacing (``sqrt(cap solid angle / lights)``). The interpolant is resampled on a
    ``resolution x resolution`` grid of the concentric square (btfrs-hemimap) and the grid
    functions of all texels are compressed by PCA into ``components`` planes, stored 8-bit
    with a scale and bias per plane, next to a float32 table of the principal functions on the
    grid (counted in :attr:`~btfrs.models.Model.nbytes`). A light is evaluated by bilinear
    lookup of the table and one dot product per channel. Between view slots the three nearest are
    blended, as for the PTM.

    Parameters
    ----------
    components: planes per slot (``colour="rgb"``), or luminance planes (``"ycc"``), 1 to 64.
    colour: ``"rgb"`` (one PCA of the three channels) or ``"ycc"`` (luminance ``Y = mean(rgb)``
        and chroma ``(b - Y, r - Y)`` compressed apart).
    chroma_components: chroma planes for ``"ycc"`` (default ``max(1, components // 4)``).
    resolution: light grid nodes per side (2 to 32).
    width: kernel width in units of the light spacing (> 0).
    regularization: ridge on the kernel matrix's unit diagonal (>= 0; 0 with duplicate lights
        raises :class:`~btfrs.exceptions.DegenerateDataError`).
    seed: seed of the randomized PCA (vectors longer than 768 values only).

    A slot with one light gets the constant; a view slot of a multi-view BTF with fewer than 6
    present lights (none included) borrows the lights of the nearest views, and
    ``model.report["pooled_slots"]`` lists each such slot and where its lights came from.
    """
    b = _check_btf(btf)
    o = _light_pca_options(components, colour, chroma_components, resolution, seed)
    o["width"] = real("width", width, min=0.0, min_open=True)
    o["regularization"] = real("regularization", regularization, min=0.0)
    return _fit("rbf", b, f"RBF-{o['components']} fit", progress, o, memory_limit)


def bilinear(btf: Btf, *, components: int = 18, colour: str = "rgb", chroma_components=None, resolution: int = 8,
             regularization: float = 0.3, seed: int = 0, memory_limit: MemoryLimit = None, progress: Progress = None) -> Bilinear:
    """Fit relight's bilinear light basis per view slot.

    Per view slot and texel, values on a ``resolution x resolution`` grid of the concentric
    square are fitted by regularised least squares so that their bilinear interpolation at each
    light's square point matches its sample (``min |B g - y|^2 + lambda |D g|^2``, ``D`` the
    second differences of the grid, which vanish on ``a + b s + c t + d s t``;
    ``lambda = regularization * tr(B^T B) / tr(D^T D)``; a tiny ridge towards the samples' mean
    decides nodes nothing else does, so one light gives the constant). A slot whose fit would
    amplify its samples more than 6 times at some light direction (lights on one side, a
    decimated sampling) is fitted with first differences instead (bounded by its samples), and
    ``model.report["fallback_slots"]`` lists it; a slot of a multi-view BTF with fewer than 6
    lights borrows the nearest views' (``report["pooled_slots"]``, as for :func:`rbf`). The grid functions are
    then compressed by PCA into 8-bit planes exactly as for :func:`rbf` (same ``components``,
    ``colour``, ``chroma_components``, ``resolution`` and ``seed``).
    """
    b = _check_btf(btf)
    o = _light_pca_options(components, colour, chroma_components, resolution, seed)
    o["regularization"] = real("regularization", regularization, min=0.0)
    return _fit("bilinear", b, f"Bilinear-{o['components']} fit", progress, o, memory_limit)
