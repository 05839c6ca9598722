"""BTF synthesis into coordinate maps (paper 000, section 4).

A synthesized BTF is a **coordinate map**: ``[H, W, 2]`` uint16 ``(x, y)`` pairs, each output
texel naming the sample texel it shows. It costs 4 bytes per texel whatever the BTF's size, renders
through :func:`btfrs.render` (``coords=``), and expands lazily with :meth:`btfrs.Btf.expand`.

>>> import btfrs
>>> btf = btfrs.materials.make("knit", size=64, seed=1)
>>> an = btfrs.synth.analyse(btf, textons=1024, seed=0)        # reusable: an.save(...)
>>> cmap = btfrs.synth.kcoherence(an, size=(512, 512), k=3, neighbourhood=2, levels=3, seed=7)
>>> print(btfrs.synth.quality(an, cmap))

* :func:`analyse`: per-pixel appearance vectors (a PCA projection of all images, all images, or
  representative images), k-means textons, the texton distance table, and the ``m`` most similar
  neighbourhoods of every sample pixel, per pyramid level (section 4.1). Works on a
  :class:`~btfrs.Btf` or on a plain ``[H, W, 3]`` texture (the algorithm is data independent).
* :func:`kcoherence`: hierarchical k-coherence (section 4.2, Figures 3 and 4).
* :func:`jump_map`: the jump map (Zelinka and Garland 2002), faster, over the same analysis.
* :func:`quality`: multi-scale window distances to the best sample match (``structure``), the
  same over the windows straddling the map's seams (``seam_error``), and the older
  neighbourhood distance, coherence, pair seams, repetition; :func:`tiled` and
  :func:`random_placement` are the baselines.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import asdict, dataclass
from typing import Any, Dict, Optional, Sequence, Union

import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import _native
from ._checks import boolean, choice, index, instance, integer, memory_size, real, size_hw
from ._checks import seed as check_seed
from ._progress import Progress, callback
from .btf import Btf
from .exceptions import ArgumentTypeError, FormatError, InvalidArgumentError
from .models import load_as, register_container

__all__ = [
    "Analysis",
    "Quality",
    "analyse",
    "kcoherence",
    "jump_map",
    "quality",
    "tiled",
    "random_placement",
    "apply",
]

PathLike = Union[str, "os.PathLike[str]"]
SizeLike = Union[int, Sequence[int]]


def _size(size: SizeLike) -> tuple[int, int]:
    """An output size, ``(height, width)`` as numpy shapes (one int for a square)."""
    return size_hw("size", size)


def _shape2(name: str, shape: Sequence[int]) -> tuple[int, int]:
    """The ``(height, width)`` leading the shape of a sample or texture."""
    if isinstance(shape, (str, bytes)) or not hasattr(shape, "__len__") or len(shape) < 2:
        raise ArgumentTypeError(f"{name}: expected a shape (height, width, ...), got {shape!r}")
    return integer(f"{name}[0]", shape[0], min=1), integer(f"{name}[1]", shape[1], min=1)


class Analysis:
    """The texton analysis of a sample, reusable across syntheses (and savable).

    Attributes: ``height``, ``width`` (the sample), ``levels`` (pyramid levels), ``textons``
    (per level, finest first), ``dim`` (length of the appearance vectors), ``m`` (similar
    neighbourhoods per pixel), ``neighbourhoods`` (``(radius, levels)`` computed so far; others
    are computed on first use and kept), ``source`` (``"btf"`` or ``"texture"``), ``features``,
    ``seconds`` (analysis wall time).
    """

    def __init__(self, native: "_native.Analysis", source: str, features: str,
                 seconds: Optional[float] = None) -> None:
        self._a = native
        self.source = source
        self.features = features
        self.seconds = seconds

    height = property(lambda self: self._a.height, doc="Rows of the sample.")
    width = property(lambda self: self._a.width, doc="Columns of the sample.")
    levels = property(lambda self: self._a.levels, doc="Pyramid levels.")
    textons = property(lambda self: list(self._a.textons), doc="Textons per level, finest first.")
    dim = property(lambda self: self._a.dim, doc="Length of the appearance vectors.")
    m = property(lambda self: self._a.m, doc="Similar neighbourhoods kept per pixel.")
    neighbourhoods = property(lambda self: list(self._a.neighbourhoods),
                              doc="(radius, levels) of the similar-neighbourhood sets computed.")

    @property
    def options(self) -> Dict[str, Any]:
        """The options of the analysis (textons, levels, m, iterations, seed)."""
        return dict(self._a.options())

    # `level` and `neighbourhood` select what these accessors return (like Btf.image's indices),
    # so they stay positional; a level outside [0, levels) is an OutOfRangeError.
    def texton_map(self, level: int = 0) -> np.ndarray:
        """``[H, W]`` uint16 texton of every pixel of a pyramid level."""
        return self._a.texton_map(index("level", level, self.levels))

    def dots(self, level: int = 0) -> np.ndarray:
        """``[T, T]`` float64 dot products of the textons' appearance vectors (the paper's M)."""
        return self._a.dots(index("level", level, self.levels))

    def distances(self, level: int = 0) -> np.ndarray:
        """``[T, T]`` float32 squared distances between textons (what the synthesis looks up)."""
        return self._a.distances(index("level", level, self.levels))

    def similar(self, neighbourhood: int = 2, level: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """``([H, W, m] int32 flat pixel indices (-1 where none), [H, W, m] float32 distances)``:
        the most similar neighbourhoods of every sample pixel, best first."""
        return self._a.similar(integer("neighbourhood", neighbourhood, min=1), index("level", level, self.levels))

    def prepare(self, neighbourhood: int, levels: int, *, progress: Progress = None) -> None:
        """Compute the similar neighbourhoods of a radius now (synthesis does it on demand)."""
        self._a.ensure_neighbourhood(integer("neighbourhood", neighbourhood, min=1),
                                     integer("levels", levels, min=1), callback(progress, "neighbourhoods"))

    def save(self, path: PathLike) -> None:
        """Write the analysis to one ``.btfrs`` file (atomically); :func:`btfrs.load` reads it."""
        meta = {"options": self.options, "source": self.source, "features": self.features,
                "seconds": self.seconds}
        arrays = self._a.arrays()
        _native.save_container(os.fspath(path), "analysis", json.dumps(meta), list(arrays.items()))

    @classmethod
    def load(cls, path: PathLike) -> "Analysis":
        """Read an analysis written by :meth:`save`."""
        analysis: Analysis = load_as(path, cls)
        return analysis

    @classmethod
    def _from_container(cls, path: PathLike, meta: Dict[str, Any], arrays: Dict[str, NDArray[Any]]) -> "Analysis":
        try:
            native = _native.Analysis.from_arrays(arrays, meta["options"])
        except (KeyError, InvalidArgumentError, TypeError) as e:
            raise FormatError(f"{os.fspath(path)}: not a valid analysis ({e})") from None
        return cls(native, meta.get("source", "btf"), meta.get("features", "?"), meta.get("seconds"))

    def __repr__(self) -> str:
        return (f"Analysis({self.source} {self.height} x {self.width}, {self.features} features of "
                f"dim {self.dim}, textons {self.textons}, neighbourhoods {self.neighbourhoods})")


def _texture(sample: ArrayLike) -> NDArray[np.float32]:
    a = np.asarray(sample)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3:
        raise InvalidArgumentError(f"sample: expected a Btf or an [H, W, C] texture, got shape {a.shape}")
    if a.dtype == np.uint8:
        return np.ascontiguousarray(a, dtype=np.float32) / np.float32(255.0)
    if a.dtype == np.uint16:
        return np.ascontiguousarray(a, dtype=np.float32) / np.float32(65535.0)
    if not np.issubdtype(a.dtype, np.floating):
        raise ArgumentTypeError(f"sample: expected a float or uint8/uint16 texture, got dtype {a.dtype}")
    return np.ascontiguousarray(a, dtype=np.float32)


def analyse(sample: Union[Btf, np.ndarray], *, textons: int = 1024, features: str = "pca", dims: int = 48,
            images: int = 150, levels: int = 3, m: int = 10, neighbourhoods: Sequence[int] = (2,),
            iterations: int = 20, seed: int = 0, memory_limit: Union[None, int, str] = None,
            progress: Progress = None) -> Analysis:
    """Analyse a sample for synthesis (paper 000, section 4.1).

    Parameters
    ----------
    sample:
        A :class:`~btfrs.Btf`, or a texture ``[H, W, C]`` (uint8 / uint16 scaled to [0, 1], or
        float): each pixel's C values are its appearance vector.
    textons:
        k-means clusters of the finest level, 1 to the number of sample pixels (coarser levels use
        at most one per pixel, which makes their distances exact).
    features:
        For a Btf: ``"pca"`` (default: the leading ``dims`` principal coordinates of all measured
        images), ``"all"`` (every image, the paper's choice; slow, memory ``H*W*V*L*3`` floats),
        or ``"images"`` (``images`` representative images, clustered by their thumbnails).
    levels:
        Pyramid levels (each half the previous resolution). The coarsest must keep more than
        ``m`` pixels outside one window of the largest neighbourhood you will use.
    m:
        Most similar neighbourhoods kept per sample pixel (``k`` of :func:`kcoherence` is at most m).
    neighbourhoods:
        Window radii whose similar neighbourhoods are computed now (others on first use).
    seed:
        Seeds k-means++ and the PCA sketch: same seed, same analysis.
    memory_limit:
        For a Btf, as for the fits (``"64MB"``, ``"2GB"``, bytes; see :mod:`btfrs.fit`): the
        anonymous memory the analysis may allocate besides its result, so a memory-mapped BTF
        larger than memory can be analysed. With ``features="pca"`` the range finder's texel
        sample is streamed through chunks sized by the limit (the same coordinates up to
        rounding); ``"all"`` and ``"images"`` copy values for every texel, which must fit. A limit
        below the least the analysis needs raises InvalidArgumentError naming it.
    """
    textons = integer("textons", textons, min=1)
    levels = integer("levels", levels, min=1)
    m = integer("m", m, min=1)
    iterations = integer("iterations", iterations, min=1)
    seed = check_seed(seed)
    if isinstance(neighbourhoods, (str, bytes)) or not hasattr(neighbourhoods, "__iter__"):
        raise ArgumentTypeError(f"neighbourhoods: expected a sequence of window radii, got {neighbourhoods!r}")
    radii = [integer("neighbourhoods", r, min=1) for r in neighbourhoods]
    t0 = time.perf_counter()
    if isinstance(sample, Btf):
        features = choice("features", features, ("pca", "all", "images"))
        dims = integer("dims", dims, min=1)
        images = integer("images", images, min=1)
        limit = memory_size("memory_limit", memory_limit)
        native = _native.analyse_btf_native(sample.data, sample.views, sample.lights, sample.mask, textons,
                                            features, dims, images, levels, m, radii, iterations, seed, limit,
                                            callback(progress, "analysis"))
        sample._check_unchanged("analysis")
        name = features if features != "pca" else f"pca{dims}"
        return Analysis(native, "btf", name, time.perf_counter() - t0)
    if features != "pca":
        raise InvalidArgumentError(f"features: a texture's pixels are its features; got features={features!r}")
    if memory_limit is not None:
        raise InvalidArgumentError("memory_limit: applies to a Btf sample (a texture is in memory already)")
    tex = _texture(sample)
    native = _native.analyse_features_native(tex, textons, levels, m, radii, iterations, seed,
                                             callback(progress, "analysis"))
    return Analysis(native, "texture", f"{tex.shape[2]} channels", time.perf_counter() - t0)


def _analysis(an: object) -> Analysis:
    return instance("an", an, Analysis, "a btfrs.synth.Analysis (from btfrs.synth.analyse)")


def kcoherence(an: Analysis, *, size: SizeLike = (512, 512), k: int = 3, neighbourhood: int = 2,
               coarse_neighbourhood: Optional[int] = None, levels: int = 3, toroidal: bool = False,
               seed: int = 7, progress: Progress = None) -> np.ndarray:
    """Hierarchical k-coherence synthesis (paper 000, section 4.2) into a coordinate map.

    ``size`` is the output ``(height, width)`` (or one int), ``k`` the candidates per known
    neighbour (1 = Ashikhmin's coherent candidates only; at most ``an.m``), ``neighbourhood`` the
    window radius at the finest level (the paper's neighbourhood size: 2 means 5 x 5),
    ``coarse_neighbourhood`` the window radius at the coarser levels (at least ``neighbourhood``;
    None: the same): larger windows there keep the structure of regular textures (brick courses,
    tiles) that a small window cannot see (paper 000, Figure 6); its similar neighbourhoods are
    computed on the coarse levels only, on first use. ``levels`` the pyramid levels used (at most
    ``an.levels``), ``toroidal`` a tileable output. Returns ``[H, W, 2]`` uint16 ``(x, y)`` into
    the sample.
    """
    an = _analysis(an)
    h, w = _size(size)
    k = integer("k", k, min=1)
    neighbourhood = integer("neighbourhood", neighbourhood, min=1)
    coarse = neighbourhood if coarse_neighbourhood is None else integer(
        "coarse_neighbourhood", coarse_neighbourhood, min=neighbourhood)
    levels = integer("levels", levels, min=1)
    seed = check_seed(seed)
    toroidal = boolean("toroidal", toroidal)
    an._a.ensure_neighbourhood(neighbourhood, 1 if coarse != neighbourhood else levels,
                               callback(progress, "neighbourhoods"))
    if coarse != neighbourhood and levels > 1:
        an._a.ensure_neighbourhood(coarse, levels, callback(progress, "neighbourhoods"), first=1)
    return an._a.kcoherence(h, w, k, neighbourhood, coarse, levels, toroidal, seed,
                            callback(progress, "k-coherence"))


def jump_map(an: Analysis, *, size: SizeLike = (512, 512), neighbourhood: int = 2, jump: float = 0.05,
             seed: int = 7, progress: Progress = None) -> np.ndarray:
    """Jump-map synthesis (Zelinka and Garland 2002) over the finest level of the analysis: each
    pixel continues a neighbour's patch or, with probability ``jump`` (in [0, 1]), jumps to a
    similar pixel. ``size`` is the output ``(height, width)`` (or one int). Returns ``[H, W, 2]``
    uint16 ``(x, y)``; ``progress`` counts output rows."""
    an = _analysis(an)
    h, w = _size(size)
    neighbourhood = integer("neighbourhood", neighbourhood, min=1)
    jump = real("jump", jump, min=0.0, max=1.0)
    seed = check_seed(seed)
    an._a.ensure_neighbourhood(neighbourhood, 1, callback(progress, "neighbourhoods"))
    return an._a.jump_map(h, w, neighbourhood, jump, seed, callback(progress, "jump map"))


@dataclass(frozen=True)
class Quality:
    """Quality measures of a coordinate map (see :func:`quality`); lower is better except
    ``coherence``, which is descriptive.

    Headline (what a person sees; scores of output windows against their exact nearest window
    of the sample at several scales, per pixel, divided by twice the sample's variance at that
    scale, so 0 is "copied from the sample" and 1 "as different as random pixels"):

    * ``structure``: mean score of random output windows, averaged over the scales with equal
      weights; ``structure_levels`` the per-scale means, finest first (scale ``l`` is the
      image blurred ``l`` times with taps ``2**l`` apart: 7 x 7, 13 x 13, 25 x 25 pixel windows
      for ``window=3``). Broken structure (mortar lines ending in mid-brick) shows at the coarse
      scales.
    * ``seam_error``, ``seam_error_p90``: mean and 90th percentile of the scores of the windows
      that straddle a discontinuity of the map (neighbours whose sample pixels are not
      neighbours the same way, plain tiling's wrap-around included), averaged over the scales.
      Windows inside a copied patch score 0, so these see the seams alone.
    * ``straddling``: fraction of the finest-scale windows straddling a discontinuity.

    Older measures, kept for comparison (blind to broken structure; texton distances divided by
    the mean distance between two random sample pixels):

    * ``nn_distance``: per-pixel distance from output windows (radius ``neighbourhood``) to their
      best sample match, over ``samples`` output pixels: dominated by the copied windows;
    * ``coherence``: fraction of adjacent output pairs adjacent in the sample the same way;
    * ``seam``: median pair seam cost along the worst straight row or column, ``seam_mean`` over
      all pairs (plain tiling scores 0 wherever its edge pixels resemble some adjacent pair);
    * ``repetition``: largest fraction of pixels repeated at one translation (1 - sample/size
      for plain tiling);
    * ``samples``: output pixels used for ``nn_distance``.
    """

    structure: float
    structure_levels: tuple[float, ...]
    seam_error: float
    seam_error_p90: float
    straddling: float
    nn_distance: float
    coherence: float
    seam: float
    seam_mean: float
    repetition: float
    samples: int

    def as_dict(self) -> Dict[str, Any]:
        return asdict(self)

    def __str__(self) -> str:
        levels = " / ".join(f"{v:.4f}" for v in self.structure_levels)
        return (f"structure {self.structure:.4f} (per scale {levels}), seam_error {self.seam_error:.4f} "
                f"(p90 {self.seam_error_p90:.4f}, {self.straddling:.0%} of windows straddle a seam), "
                f"repetition {self.repetition:.3f}, coherence {self.coherence:.3f}; older: nn_distance "
                f"{self.nn_distance:.4f}, pair seam {self.seam:.4f} (mean {self.seam_mean:.4f})")


def _coords(name: str, coords: ArrayLike, an: Optional[Analysis] = None) -> NDArray[np.uint16]:
    c = np.asarray(coords)
    if c.dtype != np.uint16:
        raise ArgumentTypeError(f"{name}: expected a uint16 array [H, W, 2], got dtype {c.dtype}")
    if c.ndim != 3 or c.shape[2] != 2:
        raise InvalidArgumentError(f"{name}: expected shape (H, W, 2), got {c.shape}")
    return np.ascontiguousarray(c)


def quality(an: Analysis, coords: ArrayLike, *, neighbourhood: int = 2, samples: int = 4096, window: int = 3,
            scales: int = 3, windows: int = 1024, seed: int = 0, progress: Progress = None) -> Quality:
    """Measure a coordinate map against the analysed sample (see :class:`Quality` for each field).

    The headline measures (``structure``, ``seam_error``) score output windows of radius
    ``window`` at ``scales`` scales (as many as fit in the sample and the output), ``windows``
    random windows per scale and up to ``windows`` straddling ones, by an exact nearest-window
    search of the sample (every sample pixel whose window fits inside it, at every scale, so a
    coarse window is found at any phase); each output pixel shows its sample pixel's
    finest-level texton vector. A synthesized 384^2 map of a 128^2 sample takes 1-3 s on 2 cores
    (maps with no close matches, such as random placement, longer).
    The older ``nn_distance`` uses windows of radius ``neighbourhood`` over ``samples`` output
    pixels. ``seed`` chooses the windows.

    Caveat: a window across the wrap-around of a sample that is exactly one period of its
    texture is not in the sample, so tiling such a sample scores that window's best match; a
    sample holding a period plus a window scores 0 when tiled at its period.
    """
    an = _analysis(an)
    c = _coords("coords", coords)
    d = an._a.quality(c, integer("neighbourhood", neighbourhood, min=1), integer("samples", samples, min=1),
                      check_seed(seed), integer("window", window, min=1), integer("scales", scales, min=1),
                      integer("windows", windows, min=1), callback(progress, "quality"))
    d["structure_levels"] = tuple(d["structure_levels"])
    return Quality(**d)


def tiled(sample_shape: Sequence[int], size: SizeLike) -> np.ndarray:
    """The plain-tiling baseline: output ``(x, y)`` shows sample ``(x mod w, y mod h)``.
    ``sample_shape`` starts with the sample's ``(height, width)``; ``size`` is the output
    ``(height, width)`` (or one int)."""
    sh, sw = _shape2("sample_shape", sample_shape)
    h, w = _size(size)
    y, x = np.mgrid[0:h, 0:w]
    return np.stack([x % sw, y % sh], axis=-1).astype(np.uint16)


def random_placement(sample_shape: Sequence[int], size: SizeLike, *, seed: int = 0) -> np.ndarray:
    """The random-placement baseline: every output texel an independent random sample texel
    (shapes and sizes ``(height, width)``, as in :func:`tiled`)."""
    sh, sw = _shape2("sample_shape", sample_shape)
    h, w = _size(size)
    g = np.random.default_rng(check_seed(seed))
    return np.stack([g.integers(0, sw, (h, w)), g.integers(0, sh, (h, w))], axis=-1).astype(np.uint16)


def apply(texture: ArrayLike, coords: ArrayLike) -> NDArray[Any]:
    """Look a coordinate map up in a texture ``[h, w, ...]``: ``texture[y, x]`` per output pixel."""
    c = _coords("coords", coords)
    t = np.asarray(texture)
    if t.ndim < 2:
        raise InvalidArgumentError(f"texture: expected at least 2 dimensions, got shape {t.shape}")
    if c.size and (int(c[..., 0].max()) >= t.shape[1] or int(c[..., 1].max()) >= t.shape[0]):
        raise InvalidArgumentError(f"coords: point outside the {t.shape[0]} x {t.shape[1]} texture")
    looked_up: NDArray[Any] = t[c[..., 1], c[..., 0]]
    return looked_up


register_container("analysis", Analysis._from_container)
