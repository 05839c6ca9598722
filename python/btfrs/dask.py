"""BTFs on a Dask cluster: chunked zarr storage in btfrs's layout, and every fit it can split run
over texel tiles on the cluster (``pip install btfrs[dask]``).

>>> from dask.distributed import Client, LocalCluster
>>> client = Client(LocalCluster(n_workers=2, threads_per_worker=1))
>>> btfrs.dask.save_zarr(big, "floortile.zarr", chunks=64)   # convert, chunked by texel tiles
>>> arr = btfrs.dask.open("floortile.zarr")                  # a BtfArray: dask array + directions
>>> lp = btfrs.dask.fit("lpca", arr, clusters=64, components=8)   # the same Lpca as btfrs.fit.lpca

**Storage.** A zarr group (``zarr`` 3) holding ``data`` ``[H, W, V, L, 3]`` float32 in the
texel-major layout of :class:`~btfrs.Btf`, chunked by texel tiles ``(t, t, V, L, 3)`` (all views,
lights and RGB of a texel in one chunk, so one chunk is one block a fit reads whole; stored
uncompressed unless ``compress=True``),
``views`` ``[V, 3]`` and ``lights`` ``[L, 3]`` float64, optionally ``mask`` ``[V, L]`` bool, and
the attribute ``btfrs = "btf"`` with the layout version.

**Fits.** :func:`fit` runs the ordinary Rust fit per chunk on the workers (the GIL released, so a
worker's threads fit chunks in parallel), with the global steps as reductions on the client, as
the model declares in Rust (``rust/btfrs-fit/src/blockwise.rs``):

* per texel (PTM, HSH, Lafortune, per-view Lafortune, double SH): each tile fitted alone (8-bit
  models in floats), the per-texel arrays stitched, the 8-bit quantization done once over all
  texels on the client: **bit for bit the local fit**;
* SRF: the mean BRDF as a sum reduction over tiles, the Phong fit on the client, the residual
  per tile: equal to the local fit to rounding (the sums add in another order);
* LPCA (paper 004): the range finder's seeded 2048-texel sample gathered from the tiles, the
  projection per tile, k-means and refinement on the client over ``T x reduced_dims``
  coordinates, one task per cluster over its members' ABRDFs: **the same model as the local
  in-memory fit** (same seeds, same code);
* RBF and bilinear (relight's light bases): per tile and view slot the count, mean and centred
  second moment of the texels' samples under the slot's lights (``float64``), merged in pairs on
  the workers (Chan et al.'s update), the principal functions on the client (the eigenvectors of
  the resampled functions' covariance, which is the samples' through the resampling), the
  projection per tile, the 8-bit quantization on the client: **equal to the local fit to
  rounding** (each principal function possibly of the opposite sign, its coefficients with it).
  A tile's moments are ``8 V (3 m)^2`` bytes for ``m`` lights per view (81 views of 81 lights:
  38 MB). The eigenproblem per slot is the smaller of ``3 n^2`` (rgb; ``2 n^2`` ycc) and
  ``3 m``; above 768, a clear error.

The result is the model class of the local fit, saved like any other. ``model.report`` holds the
blocks' reports combined (the counts a model declares summed, means weighted by texels,
``rms_*`` as root mean squares; entries equal in every block kept as they are).

It runs on whichever scheduler is current: a ``dask.distributed`` client if one exists, else
dask's threads. Failures: an error raised by btfrs inside a task is raised as itself; a cluster
that fails (a worker killed, the scheduler gone) raises :class:`~btfrs.exceptions.ClusterError`.
A fit writes nothing, and :func:`save_zarr` writes into a temporary directory renamed into place
at the end, so a failed or interrupted run leaves nothing half-written and can simply be rerun.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import time
import uuid
from dataclasses import dataclass
from typing import Any, Callable, Dict, Iterator, List, Optional, Tuple, Union, overload

import numpy as np
from numpy.typing import ArrayLike, DTypeLike, NDArray

from . import _native
from ._checks import choice, instance, integer
from ._fitting import ROBUST_DEFAULTS, flag
from ._progress import Progress, callback
from .btf import Btf
from .exceptions import (ArgumentTypeError, BtfrsError, ClusterError, FormatError, InternalError,
                         InvalidArgumentError)
from .models import Model, model_kinds, wrap

__all__ = ["BtfArray", "save_zarr", "open", "from_btf", "fit", "LAYOUT_VERSION"]

LAYOUT_VERSION = 1

PathLike = Union[str, "os.PathLike[str]"]

# What a progress callback is once :func:`~btfrs._progress.callback` has made it.
_Callback = Optional[Callable[[int, int], object]]
# A tile of a BtfArray: (delayed block, row offset, column offset, rows, columns).
_Block = Tuple[Any, int, int, int, int]


def _dask() -> Tuple[Any, Any]:
    try:
        import dask
        import dask.array as da
    except ImportError as e:  # pragma: no cover - exercised only without the extra
        raise ImportError("btfrs.dask needs dask: pip install 'btfrs[dask]' (dask[array], distributed, zarr)") from e
    return dask, da


def _zarr() -> Any:
    try:
        import zarr
    except ImportError as e:  # pragma: no cover
        raise ImportError("btfrs.dask needs zarr: pip install 'btfrs[dask]' (dask[array], distributed, zarr)") from e
    return zarr


@dataclass(frozen=True)
class BtfArray:
    """A BTF as a dask array: ``data`` ``[H, W, V, L, 3]`` float32 chunked by texel tiles (every
    chunk holds all views, lights and RGB of its texels), with its directions and mask (numpy)."""

    data: Any
    views: NDArray[np.float64]
    lights: NDArray[np.float64]
    mask: Optional[NDArray[np.bool_]] = None

    def __post_init__(self) -> None:
        _, da = _dask()
        if not isinstance(self.data, da.Array):
            raise ArgumentTypeError(f"data: expected a dask array, got {type(self.data).__name__}")
        d = self.data
        if d.ndim != 5 or d.shape[-1] != 3:
            raise InvalidArgumentError(f"data: expected shape (H, W, V, L, 3), got {d.shape}")
        if d.dtype != np.float32:
            raise InvalidArgumentError(f"data: expected float32 values, got dtype {d.dtype}")
        v = np.ascontiguousarray(self.views, dtype=np.float64)
        li = np.ascontiguousarray(self.lights, dtype=np.float64)
        if v.shape != (d.shape[2], 3) or li.shape != (d.shape[3], 3):
            raise InvalidArgumentError(f"views, lights: expected [{d.shape[2]}, 3] and [{d.shape[3]}, 3] for data "
                                       f"of shape {d.shape}, got {v.shape} and {li.shape}")
        object.__setattr__(self, "views", v)
        object.__setattr__(self, "lights", li)
        if self.mask is not None:
            m = np.asarray(self.mask)
            if m.dtype != np.bool_ or m.shape != d.shape[2:4]:
                raise InvalidArgumentError(f"mask: expected a bool array of shape {d.shape[2:4]}, got {m.dtype} {m.shape}")
            object.__setattr__(self, "mask", np.ascontiguousarray(m))
        for axis, name in ((2, "views"), (3, "lights"), (4, "RGB")):
            if len(d.chunks[axis]) != 1:
                raise InvalidArgumentError(f"data: expected chunks that hold all {name} of a texel (chunks "
                                           f"(t, t, V, L, 3)), got chunks {d.chunksize}; rechunk with "
                                           f"data.rechunk((t, t, -1, -1, -1))")

    @property
    def shape(self) -> Tuple[int, ...]:
        return tuple(self.data.shape)

    @property
    def height(self) -> int:
        return int(self.data.shape[0])

    @property
    def width(self) -> int:
        return int(self.data.shape[1])

    @property
    def tiles(self) -> Tuple[Tuple[int, ...], ...]:
        """The texel tiles' rows and columns (``data.chunks[:2]``)."""
        return tuple(self.data.chunks[:2])

    def to_btf(self) -> Btf:
        """The whole BTF computed into memory."""
        return Btf(np.asarray(self.data.compute()), self.views, self.lights, self.mask)

    def __repr__(self) -> str:
        h, w, v, l, _ = self.shape
        return (f"BtfArray({h} x {w} texels, {v} views x {l} lights, {self.data.nbytes / 2**20:.1f} MiB, "
                f"tiles {self.data.chunksize[0]} x {self.data.chunksize[1]})")


def _tile(chunks: object) -> int:
    return integer("chunks", chunks, min=1)


def _read_tile(path: str, stamp: Tuple[int, int], r0: int, r1: int, c0: int, c1: int) -> NDArray[np.float32]:
    """One tile of a memory-mapped ``.btfrs`` file, read on the worker (the file is mapped, not
    loaded, so opening it per tile costs nothing); an error if the file changed since."""
    b = Btf.load(path, mmap=True)
    if b._source is None or b._source[1:] != stamp:
        raise FormatError(f"{path}: the file changed on disk since it was opened for the Dask fit; open it again and rerun")
    return np.array(b.data[r0:r1, c0:c1])


def from_btf(btf: Btf, *, chunks: int = 64) -> BtfArray:
    """A :class:`BtfArray` over ``btf``, chunked by ``chunks x chunks`` texel tiles. A
    memory-mapped Btf (``Btf.load(path, mmap=True)``) is read by path on the workers, tile by
    tile (they must see the same file system); an in-memory one is sent with the task graph."""
    _, da = _dask()
    b = instance("btf", btf, Btf, "a btfrs.Btf")
    t = _tile(chunks)
    h, w, v, l, _ = b.shape
    if b._source is not None:
        import dask

        path, size, mtime = b._source
        rows = []
        for r0 in range(0, h, t):
            r1 = min(h, r0 + t)
            row = []
            for c0 in range(0, w, t):
                c1 = min(w, c0 + t)
                blk = dask.delayed(_read_tile, pure=True)(path, (size, mtime), r0, r1, c0, c1)
                row.append(da.from_delayed(blk, shape=(r1 - r0, c1 - c0, v, l, 3), dtype=np.float32))
            rows.append(row)
        data = da.concatenate([da.concatenate(row, axis=1) for row in rows], axis=0)
    else:
        data = da.from_array(b.data, chunks=(t, t, v, l, 3))
    return BtfArray(data, b.views, b.lights, b.mask)


def save_zarr(btf: Union[Btf, BtfArray], path: PathLike, *, chunks: int = 64, compress: bool = False,
              overwrite: bool = False, progress: Progress = None) -> str:
    """Write ``btf`` (a :class:`~btfrs.Btf`, memory-mapped or not, or a :class:`BtfArray`) as a
    zarr group in btfrs's layout (module doc), chunked by ``chunks x chunks`` texel tiles, one
    band of tile rows at a time (memory: one band). Written into a temporary directory beside
    ``path`` and renamed into place at the end: an error or Ctrl-C leaves nothing. ``path`` must
    not exist unless ``overwrite``. Returns the path.

    compress: False (the default) stores the float32 values as they are; True compresses each
    chunk with zstd. Measured values (knit, BENCHMARKS.md "Dask") compress only to about 74 % and
    decode at about 0.3 GB/s per core against 1.3 GB/s uncompressed, which made the decoding
    most of a Dask PTM fit: compress when storage or network, not the cores, is short."""
    zarr = _zarr()
    t = _tile(chunks)
    if not isinstance(compress, bool):
        raise ArgumentTypeError(f"compress: expected a bool, got {type(compress).__name__}")
    if isinstance(btf, Btf):
        src, views, lights, mask = btf.data, btf.views, btf.lights, btf.mask
    elif isinstance(btf, BtfArray):
        src, views, lights, mask = btf.data, btf.views, btf.lights, btf.mask
    else:
        raise ArgumentTypeError(f"btf: expected a btfrs.Btf or a btfrs.dask.BtfArray, got {type(btf).__name__}")
    p = os.path.abspath(os.fspath(path))
    if os.path.exists(p) and not overwrite:
        raise InvalidArgumentError(f"path: {p} exists; pass overwrite=True to replace it")
    h, w, v, l, _ = src.shape
    tmp = f"{p}.tmp-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    cb = callback(progress, "save zarr")
    try:
        g = zarr.open_group(tmp, mode="w")
        g.attrs.update({"btfrs": "btf", "layout_version": LAYOUT_VERSION})
        codec = {} if compress else {"compressors": None}
        data = g.create_array("data", shape=(h, w, v, l, 3), chunks=(min(t, h), min(t, w), v, l, 3), dtype="float32",
                              **codec)
        g.create_array("views", shape=views.shape, dtype="float64")[...] = views
        g.create_array("lights", shape=lights.shape, dtype="float64")[...] = lights
        if mask is not None:
            g.create_array("mask", shape=mask.shape, dtype="bool")[...] = mask
        bands = range(0, h, t)
        for i, r0 in enumerate(bands):
            band = src[r0:r0 + t]
            band = np.asarray(band.compute() if hasattr(band, "compute") else band, dtype=np.float32)
            if not np.isfinite(band).all():
                raise InvalidArgumentError(f"btf: rows {r0} to {r0 + band.shape[0] - 1} hold values that are not finite")
            data[r0:r0 + band.shape[0]] = band
            if cb:
                cb(i + 1, len(bands))
        if os.path.exists(p):
            old = f"{p}.old-{uuid.uuid4().hex[:8]}"
            os.replace(p, old)
            os.replace(tmp, p)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, p)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return p


def open(path: PathLike) -> BtfArray:  # noqa: A001 - the module's verb, as btfrs.dask.open
    """The zarr group written by :func:`save_zarr` as a :class:`BtfArray` (nothing is read but
    the directions); a group in another layout or dtype raises
    :class:`~btfrs.exceptions.FormatError` saying what is wrong."""
    zarr = _zarr()
    _, da = _dask()
    p = os.fspath(path)
    if not os.path.exists(p):
        raise FileNotFoundError(p)
    try:
        g = zarr.open_group(p, mode="r")
    except Exception as e:
        raise FormatError(f"{p}: not a zarr group ({e})") from e
    if g.attrs.get("btfrs") != "btf":
        raise FormatError(f"{p}: not a btfrs BTF (attribute btfrs = {g.attrs.get('btfrs')!r}, expected 'btf'; "
                          f"write it with btfrs.dask.save_zarr)")
    if g.attrs.get("layout_version") != LAYOUT_VERSION:
        raise FormatError(f"{p}: layout version {g.attrs.get('layout_version')!r}, this btfrs reads {LAYOUT_VERSION}")
    names = set(g.array_keys())
    for need in ("data", "views", "lights"):
        if need not in names:
            raise FormatError(f"{p}: missing array {need!r}")
    z = g["data"]
    if z.dtype != np.float32:
        raise FormatError(f"{p}: data has dtype {z.dtype}, expected float32")
    if len(z.shape) != 5 or z.shape[-1] != 3:
        raise FormatError(f"{p}: data has shape {z.shape}, expected (H, W, V, L, 3)")
    if tuple(z.chunks[2:]) != tuple(z.shape[2:]):
        raise FormatError(f"{p}: data is chunked {z.chunks}: a chunk must hold all views, lights and RGB of its "
                          f"texels (t, t, {z.shape[2]}, {z.shape[3]}, 3)")
    views, lights = np.asarray(g["views"][...]), np.asarray(g["lights"][...])
    for name, a, n in (("views", views, z.shape[2]), ("lights", lights, z.shape[3])):
        if a.dtype != np.float64 or a.shape != (n, 3):
            raise FormatError(f"{p}: {name} is {a.dtype} {a.shape}, expected float64 ({n}, 3)")
    mask = None
    if "mask" in names:
        mask = np.asarray(g["mask"][...])
        if mask.dtype != np.bool_ or mask.shape != tuple(z.shape[2:4]):
            raise FormatError(f"{p}: mask is {mask.dtype} {mask.shape}, expected bool {tuple(z.shape[2:4])}")
    try:
        return BtfArray(da.from_zarr(z), views, lights, mask)
    except InvalidArgumentError as e:
        raise FormatError(f"{p}: {e}") from e


# --- fitting ---------------------------------------------------------------------------------

def _client() -> Any:
    try:
        from distributed import get_client
    except ImportError:
        return None
    try:
        return get_client()
    except ValueError:
        return None


def _is_cluster_failure(e: BaseException) -> bool:
    mod = type(e).__module__ or ""
    return (mod.split(".")[0] in ("distributed", "tornado", "asyncio", "concurrent")
            or isinstance(e, (OSError, TimeoutError)) and not isinstance(e, FileNotFoundError))


@contextlib.contextmanager
def _cluster_errors(stage: str) -> Iterator[None]:
    """A failure of the cluster inside becomes :class:`ClusterError`; btfrs's own errors and
    Ctrl-C pass as they are."""
    try:
        yield
    except (BtfrsError, KeyboardInterrupt):
        raise
    except Exception as e:
        if _is_cluster_failure(e):
            raise ClusterError(f"cluster: the Dask cluster failed during the {stage} ({type(e).__name__}: {e}); "
                               f"nothing was written; rerun once the cluster is healthy") from e
        raise


def _compute(tasks: List[Any], cb: _Callback, stage: str) -> List[Any]:
    """Compute ``tasks`` on the current scheduler, reporting each one finished; a failure of the
    cluster becomes :class:`ClusterError`, btfrs's own errors pass as they are."""
    dask, _ = _dask()
    client = _client()
    total = len(tasks)
    with _cluster_errors(stage):
        if client is None:
            out = list(dask.compute(*tasks))
            if cb:
                cb(total, total)
            return out
        from distributed import as_completed

        futures = client.compute(tasks)
        try:
            for done, _f in enumerate(as_completed(futures), 1):
                if cb:
                    cb(done, total)
            gathered: List[Any] = client.gather(futures)
            return gathered
        except BaseException:
            client.cancel(futures)
            raise


def _reduce(tasks: List[Any], merge: Callable[[Any, Any], Any], cb: _Callback, stage: str) -> Any:
    """``merge`` of all ``tasks``' results, merged in pairs on the workers (a tree, so the client
    never holds more than one result), reporting each task finished. With a distributed client
    the results are paired as they finish, so merging overlaps the remaining tasks; ``merge``
    must be associative and commutative (to rounding)."""
    dask, _ = _dask()
    client = _client()
    total = len(tasks)
    with _cluster_errors(stage):
        if client is None:
            level = list(tasks)
            while len(level) > 1:
                level = [dask.delayed(merge, pure=True)(level[i], level[i + 1]) if i + 1 < len(level) else level[i]
                         for i in range(0, len(level), 2)]
            (out,) = dask.compute(level[0])
            if cb:
                cb(total, total)
            return out
        from distributed import as_completed

        futures = client.compute(tasks)
        inputs = {f.key for f in futures}
        live = set(futures)
        ac = as_completed(futures)
        del futures  # merged results are released as soon as they are merged again
        try:
            pending, done = None, 0
            for f in ac:
                if f.status == "error":
                    f.result()  # raises the task's own error
                if f.key in inputs:
                    done += 1
                    if cb:
                        cb(done, total)
                if pending is None:
                    pending = f
                    continue
                m = client.submit(merge, pending, f, pure=False)
                live -= {pending, f}
                live.add(m)
                ac.add(m)
                pending = None
            assert pending is not None  # an odd count of results leaves the last merge pending
            return pending.result()
        except BaseException:
            client.cancel(list(live))
            raise


def _present(mask: Optional[NDArray[np.bool_]], v: int, l: int) -> Optional[NDArray[np.intp]]:
    return None if mask is None else np.flatnonzero(mask.reshape(-1))


def _abrdfs(block: NDArray[Any], present: Optional[NDArray[np.intp]]) -> NDArray[Any]:
    """The tile's texels' ABRDFs ``[n, d]`` (row-major texels), present pairs only."""
    h, w, v, l, _ = block.shape
    x = np.asarray(block, dtype=np.float32).reshape(h * w, v * l, 3)
    if present is not None:
        x = x[:, present]
    return _own(x.reshape(h * w, -1))


def _texel_index(r0: int, c0: int, h: int, w: int, width: int) -> NDArray[np.int_]:
    """The row-major indices in the whole BTF of a tile's texels (tile row-major)."""
    rr, cc = np.meshgrid(np.arange(r0, r0 + h), np.arange(c0, c0 + w), indexing="ij")
    return (rr * width + cc).reshape(-1)


@overload
def _own(a: None, dtype: Optional[DTypeLike] = None) -> None: ...
@overload
def _own(a: ArrayLike, dtype: Optional[DTypeLike] = None) -> NDArray[Any]: ...
@overload
def _own(a: Optional[ArrayLike], dtype: Optional[DTypeLike] = None) -> Optional[NDArray[Any]]: ...
def _own(a: Optional[ArrayLike], dtype: Optional[DTypeLike] = None) -> Optional[NDArray[Any]]:
    """An aligned C-contiguous array: what arrives on a worker may be a view of a message buffer
    (not aligned), which the native functions refuse."""
    return None if a is None else np.require(a, dtype=dtype, requirements=["C", "A"])


def _fit_block(block: NDArray[Any], views: NDArray[np.float64], lights: NDArray[np.float64],
               mask: Optional[NDArray[np.bool_]], kind: _native._ModelKind,
               options: Dict[str, Any]) -> Tuple[Dict[str, NDArray[Any]], Dict[str, Any], int]:
    m = _native.fit_model(kind, _own(block, np.float32), _own(views), _own(lights), _own(mask), options, None)
    return m.arrays(), m.report(), m.dims[0] * m.dims[1]


def _srf_sums(block: NDArray[Any], views: NDArray[np.float64], lights: NDArray[np.float64],
              mask: Optional[NDArray[np.bool_]]) -> NDArray[np.float64]:
    return _native.srf_sums(_own(block, np.float32), _own(views), _own(lights), _own(mask))


def _srf_residual(block: NDArray[Any], views: NDArray[np.float64], lights: NDArray[np.float64],
                  mask: Optional[NDArray[np.bool_]], phong: List[float]) -> Tuple[NDArray[np.float32], List[float]]:
    return _native.srf_residual(_own(block, np.float32), _own(views), _own(lights), _own(mask), phong)


def _gather_rows(block: NDArray[Any], present: Optional[NDArray[np.intp]], local: NDArray[np.intp]) -> NDArray[Any]:
    return _abrdfs(block, present)[local]


def _project(block: NDArray[Any], present: Optional[NDArray[np.intp]], mu: NDArray[np.float32],
             q: NDArray[np.float32]) -> NDArray[np.float32]:
    return _native.lpca_project(_abrdfs(block, present), _own(mu), _own(q))


def _split_clusters(block: NDArray[Any], present: Optional[NDArray[np.intp]], ids: NDArray[np.uint32],
                    k: int) -> Tuple[NDArray[Any], ...]:
    """The tile's ABRDFs split by cluster: ``k`` arrays (empty where no member is here)."""
    x = _abrdfs(block, present)
    return tuple(x[ids == c] for c in range(k))


def _lp_moments(block: NDArray[Any], views: NDArray[np.float64], lights: NDArray[np.float64],
                mask: Optional[NDArray[np.bool_]], kind: str, options: Dict[str, Any]) -> _native._Moments:
    return _native.light_pca_moments(kind, _own(block, np.float32), _own(views), _own(lights), _own(mask),
                                     options)


def _lp_merge(a: _native._Moments, b: _native._Moments) -> _native._Moments:
    own: Callable[[_native._Moments], _native._Moments] = lambda m: (m[0], _own(m[1]), _own(m[2]))
    return _native.light_pca_merge(own(a), own(b))


def _lp_project(block: NDArray[Any], views: NDArray[np.float64], lights: NDArray[np.float64],
                mask: Optional[NDArray[np.bool_]], kind: str, table: NDArray[np.float32],
                options: Dict[str, Any]) -> NDArray[np.float32]:
    return _native.light_pca_project(kind, _own(block, np.float32), _own(views), _own(lights), _own(mask),
                                     _own(table), options)


def _fit_cluster(index: int, height: int, width: int, options: Dict[str, Any],
                 *pieces: NDArray[Any]) -> Tuple[NDArray[np.uint8], NDArray[np.float32], NDArray[np.float32], NDArray[np.float32]]:
    # Pieces come in tile order; the members must be in texel order as the local fit has them.
    rows = [p for p in pieces[0::2] if len(p)]
    idx = np.concatenate([i for i in pieces[1::2] if len(i)])
    order = np.argsort(idx, kind="stable")
    x = np.concatenate(rows)[order]
    texels = np.ascontiguousarray(idx[order], dtype=np.uint32)
    return _native.lpca_fit_cluster(_own(x), texels, height, width, index, options)


def _merge_reports(reports: List[Dict[str, Any]], texels: List[int], counts: List[str]) -> Dict[str, Any]:
    """The blocks' reports as one (module doc): the model's ``counts`` summed, other entries
    equal in every block kept, differing numbers weighted by texels (``rms_*`` as root mean
    squares), differing lists concatenated."""
    if not reports:
        return {}
    total = float(sum(texels))
    out: Dict[str, Any] = {}
    for key in reports[0]:
        vals: List[Any] = [r.get(key) for r in reports]
        if key in counts:
            out[key] = sum(vals)
        elif all(v == vals[0] for v in vals):
            out[key] = vals[0]
        elif all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in vals):
            if key.startswith("rms"):
                out[key] = float(np.sqrt(sum(t * v * v for t, v in zip(texels, vals)) / total))
            else:
                out[key] = float(sum(t * v for t, v in zip(texels, vals)) / total)
        elif all(isinstance(v, list) for v in vals):
            out[key] = [x for v in vals for x in v]
        else:
            out[key] = vals
    return out


def fit(model: str, arr: Union[BtfArray, Btf], /, *, progress: Progress = None, chunks: int = 64, **options: Any) -> Model:
    """Fit the registered model ``model`` to ``arr`` (a :class:`BtfArray`; a
    :class:`~btfrs.Btf` is wrapped by :func:`from_btf` with ``chunks``) on the current Dask
    scheduler, texel tile by texel tile (module doc), with the options of the local fit
    (``btfrs.fit.<model>``). Returns the model class the local fit returns.

    ``memory_limit`` is not taken: on a cluster each worker's own ``memory_limit`` bounds it (a
    tile, or for LPCA one cluster's member ABRDFs, is what a task holds). ``progress`` reports
    the tasks finished per stage.

    ``robust`` (default True) and ``exclude_bad_images`` are those of :func:`btfrs.fit.fit`: the
    screen runs first, as a stage of its own (each tile with a one-texel halo, the images
    judged from the same texels as in memory), and repairs exactly the values the local fit
    repairs; ``model.report["robust"]`` is the local fit's."""
    kind = choice("model", model, tuple(model_kinds()))
    if isinstance(arr, Btf):
        arr = from_btf(arr, chunks=chunks)
    instance("arr", arr, BtfArray, "a btfrs.dask.BtfArray (btfrs.dask.open or from_btf) or a btfrs.Btf")
    if "memory_limit" in options:
        raise InvalidArgumentError("memory_limit: a Dask fit is bounded by its workers' memory_limit, not by a "
                                   "btfrs limit; for one machine use btfrs.fit." + kind + "(btf, memory_limit=...)")
    strategy, detail, overrides, counts = _native.blockwise_plan(kind)
    if strategy == "unsupported":
        raise InvalidArgumentError(f"model: the {kind} fit cannot run blockwise on a Dask cluster ({detail}); "
                                   f"fit it out of core with btfrs.fit.{kind}(btfrs.Btf.load(path, mmap=True), "
                                   f"memory_limit=...)")
    robust = flag("robust", options.pop("robust", ROBUST_DEFAULTS["robust"]))
    exclude = flag("exclude_bad_images", options.pop("exclude_bad_images", ROBUST_DEFAULTS["exclude_bad_images"]))
    t0 = time.perf_counter()
    robust_report = None
    if robust or exclude:
        arr, robust_report = _screen(kind, arr, robust, exclude, progress)
    if strategy == "texels":
        m = _fit_texels(kind, arr, options, overrides, list(counts), progress)
    elif detail in _STAGES:
        # The model's registry entry names the stage protocol its fit follows.
        m = _STAGES[detail](kind, arr, options, progress)
    else:  # pragma: no cover - a model declared staged needs its protocol here
        raise InternalError(f"model: {kind} is declared staged by {detail!r}, a protocol btfrs.dask does not know")
    if robust_report is not None:
        m.report["robust"] = robust_report
    m.fit_seconds = time.perf_counter() - t0
    return m


def _halo_block(data: Any, r0: int, r1: int, c0: int, c1: int) -> Tuple[Any, int, int]:
    """The tile ``[r0:r1, c0:c1]`` with a one-texel halo (inside the sample): the dask slice and
    the tile's offset in it."""
    hr0, hc0 = max(r0 - 1, 0), max(c0 - 1, 0)
    return data[hr0:min(r1 + 1, data.shape[0]), hc0:min(c1 + 1, data.shape[1])], r0 - hr0, c0 - hc0


def _screen_block(block: NDArray[Any], views: NDArray[np.float64], lights: NDArray[np.float64],
                  mask: Optional[NDArray[np.bool_]], floor: float, r0: int, r1: int, c0: int,
                  c1: int) -> Tuple[NDArray[np.uint64], NDArray[np.float32], Tuple[int, ...]]:
    idx, vals = _native.robust_screen_block(_own(block, np.float32), _own(views), _own(lights), _own(mask), floor,
                                            r0, r1, c0, c1)
    return idx, vals, tuple(block.shape)


def _repair(block: NDArray[Any], flags: Dict[Tuple[int, int], Tuple[NDArray[np.intp], NDArray[np.float32]]],
            block_id: Tuple[int, ...] = (0, 0)) -> NDArray[np.float32]:
    idx, vals = flags.get((block_id[0], block_id[1]), (None, None))
    if idx is None or not len(idx):
        return block
    out = np.array(block, dtype=np.float32, copy=True)
    out.reshape(-1)[idx] = vals
    return out


def _screen(kind: str, arr: BtfArray, robust: bool, exclude: bool,
            progress: Progress) -> Tuple[BtfArray, Dict[str, Any]]:
    """The robust screen of the local fit (``btfrs_fit::robust``), blockwise: the images judged
    and the floor set from the same sampled texels, then every tile's values screened with a
    one-texel halo (the spatial neighbours across its edges), so the same values are repaired as
    in memory. Returns the repaired array (lazily: each tile gets its few replacements as it is
    read) and the report."""
    dask, da = _dask()
    h, w, nv, nl = arr.height, arr.width, len(arr.views), len(arr.lights)
    pick = np.asarray(_native.robust_sample_texels(h, w), dtype=np.intp)
    with _cluster_errors(f"{kind} fit's robust screen"):
        samples = np.asarray(arr.data.vindex[pick // w, pick % w].compute(), dtype=np.float32)
        pr, pc, ph, pw = _native.robust_patch_window(h, w)
        patch = np.asarray(arr.data[pr:pr + ph, pc:pc + pw].compute(), dtype=np.float32)
    moved = _native.robust_moved(_own(patch, np.float32), _own(arr.views), _own(arr.lights), _own(arr.mask))
    del patch
    floor, spread, bad = _native.robust_images(_own(samples[:, None], np.float32), _own(arr.views),
                                               _own(arr.lights), _own(arr.mask))
    flags: Dict[Tuple[int, int], Tuple[NDArray[np.intp], NDArray[np.float32]]] = {}
    gidx: List[NDArray[np.uint64]] = []
    gval: List[NDArray[np.float32]] = []
    # The values are screened (and reported) either way; repaired only with robust.
    rows, cols = arr.data.chunks[0], arr.data.chunks[1]
    r0s, c0s = np.cumsum((0,) + rows[:-1]), np.cumsum((0,) + cols[:-1])
    keys, tasks = [], []
    for i, (r0, nr) in enumerate(zip(r0s, rows)):
        for j, (c0, nc) in enumerate(zip(c0s, cols)):
            halo, dr, dc = _halo_block(arr.data, int(r0), int(r0) + nr, int(c0), int(c0) + nc)
            keys.append((i, j, int(r0), int(c0), nr, nc, dr, dc))
            tasks.append(dask.delayed(_screen_block, pure=True)(halo, arr.views, arr.lights, arr.mask, floor,
                                                                  dr, dr + nr, dc, dc + nc))
    found = _compute(tasks, callback(progress, f"{kind} robust screen"), f"{kind} fit's robust screen")
    abrdf = nv * nl * 3
    for (i, j, r0, c0, nr, nc, dr, dc), (idx, vals, shape) in zip(keys, found):
        if not len(idx):
            continue
        bw = shape[1]
        t, k = idx.astype(np.intp) // abrdf, idx.astype(np.intp) % abrdf
        tr, tc = t // bw - dr, t % bw - dc  # within the tile
        if robust:
            flags[(i, j)] = ((tr * nc + tc) * abrdf + k, vals)
        gidx.append((((r0 + tr) * w + c0 + tc) * abrdf + k).astype(np.uint64))
        gval.append(vals)
    index = np.concatenate(gidx) if gidx else np.zeros(0, dtype=np.uint64)
    values = np.concatenate(gval) if gval else np.zeros(0, dtype=np.float32)
    mask = arr.mask
    if exclude and (bad or moved):
        mask = np.ones((nv, nl), dtype=bool) if mask is None else mask.copy()
        for v, l in list(bad) + [(m[0], m[1]) for m in moved]:
            mask[v, l] = False
        if not mask.any():
            raise InvalidArgumentError("exclude_bad_images: every image was found bad; nothing is left to fit")
    report = json.loads(_native.robust_report(h, w, arr.views, arr.lights, arr.mask, index, values, spread, bad,
                                              moved, floor, exclude))
    report["robust"] = robust
    if not robust:
        report["values_replaced"] = 0
    data = arr.data.map_blocks(_repair, flags, dtype=np.float32) if flags else arr.data
    return BtfArray(data, arr.views, arr.lights, mask), report


def _blocks(arr: BtfArray) -> List[_Block]:
    """``(delayed block, row offset, column offset, rows, columns)`` of every tile, row-major."""
    dl = arr.data.to_delayed()
    rows, cols = arr.data.chunks[0], arr.data.chunks[1]
    r0s, c0s = np.cumsum((0,) + rows[:-1]), np.cumsum((0,) + cols[:-1])
    return [(dl[i, j, 0, 0, 0], int(r0s[i]), int(c0s[j]), rows[i], cols[j])
            for i in range(len(rows)) for j in range(len(cols))]


def _fit_texels(kind: str, arr: BtfArray, options: Dict[str, Any], overrides: Dict[str, Any], counts: List[str],
                progress: Progress) -> Model:
    dask, _ = _dask()
    block = {**options, **overrides}
    blocks = _blocks(arr)
    tasks = [dask.delayed(_fit_block, pure=True)(b, arr.views, arr.lights, arr.mask, kind, block)
             for b, *_ in blocks]
    results = _compute(tasks, callback(progress, f"{kind} blocks"), f"{kind} fit")
    texel_names = set(_native.texel_arrays(kind))
    h, w = arr.height, arr.width
    stitched: Dict[str, NDArray[Any]] = {}
    first = results[0][0]
    for name, a in first.items():
        if name in texel_names:
            out = np.empty((h, w) + a.shape[2:], dtype=a.dtype)
            for (arrays, _, _), (_, r0, c0, nr, nc) in zip(results, blocks):
                out[r0:r0 + nr, c0:c0 + nc] = arrays[name]
            stitched[name] = out
        else:
            for arrays, _, _ in results[1:]:
                if name not in arrays or not np.array_equal(arrays[name], a):
                    raise InternalError(f"model: the {kind} array {name!r} differs between texel blocks, so the fit is "
                                        f"not separable as its blockwise contract says; please report it")
            stitched[name] = a
    native = _native.finish_blocks(kind, stitched, options)
    return wrap(native, report=_merge_reports([r for _, r, _ in results], [n for _, _, n in results], counts))


def _fit_mean_brdf(kind: str, arr: BtfArray, options: Dict[str, Any], progress: Progress) -> Model:
    dask, _ = _dask()
    if options:
        raise InvalidArgumentError(f"{next(iter(options))}: unknown option; the srf fit takes none")
    blocks = _blocks(arr)
    sums = _compute([dask.delayed(_srf_sums, pure=True)(b, arr.views, arr.lights, arr.mask) for b, *_ in blocks],
                    callback(progress, "SRF mean BRDF"), "SRF mean BRDF")
    total = np.sum(np.stack(sums), axis=0)
    phong, iterations = _native.srf_phong(arr.views, arr.lights, arr.mask, np.ascontiguousarray(total),
                                          arr.height * arr.width)
    res = _compute([dask.delayed(_srf_residual, pure=True)(b, arr.views, arr.lights, arr.mask, phong)
                    for b, *_ in blocks], callback(progress, "SRF residual"), "SRF residual")
    s = np.empty((arr.height, arr.width, 3, 3), dtype=np.float32)
    e = np.zeros(3)
    for (sb, eb), (_, r0, c0, nr, nc) in zip(res, blocks):
        s[r0:r0 + nr, c0:c0 + nc] = sb
        e += np.asarray(eb)
    native = _native.Model.from_arrays(kind, {"phong": np.asarray(phong, dtype=np.float64), "s": s})
    rel: Callable[[float], float] = (lambda x: float(np.sqrt(x / e[2])) if e[2] > 0 else 0.0)
    return wrap(native, report={"iterations": int(iterations), "phong_relative": rel(e[0]), "srf_relative": rel(e[1])})


def _fit_clustered_pca(kind: str, arr: BtfArray, options: Dict[str, Any], progress: Progress) -> Model:
    dask, _ = _dask()
    h, w = arr.height, arr.width
    present = _present(arr.mask, len(arr.views), len(arr.lights))
    blocks = _blocks(arr)
    index = [_texel_index(r0, c0, nr, nc, w) for _, r0, c0, nr, nc in blocks]
    # 1. The range finder's seeded sample, gathered from the tiles in texel order.
    pick = _native.lpca_sample(h, w, options)
    if pick is None:
        pick = np.arange(h * w, dtype=np.uint32)
    in_pick = np.zeros(h * w, dtype=bool)
    in_pick[pick] = True
    parts, where = [], []
    for (b, *_), idx in zip(blocks, index):
        local = np.flatnonzero(in_pick[idx])
        if len(local):
            parts.append(dask.delayed(_gather_rows, pure=True)(b, present, local))
            where.append(idx[local])
    rows = _compute(parts, callback(progress, "LPCA sample"), "LPCA sample")
    sample = np.concatenate(rows)[np.argsort(np.concatenate(where), kind="stable")]
    mu, q = _native.lpca_subspace(np.ascontiguousarray(sample), h, w, options)
    del sample, rows
    # 2. Every tile projected; the rows put back in texel order.
    mu_d, q_d = dask.delayed(mu), dask.delayed(q)
    zs = _compute([dask.delayed(_project, pure=True)(b, present, mu_d, q_d) for b, *_ in blocks],
                  callback(progress, "LPCA projection"), "LPCA projection")
    z = np.empty((h * w, q.shape[0]), dtype=np.float32)
    for zb, idx in zip(zs, index):
        z[idx] = zb
    del zs
    # 3. k-means and refinement on the client (on the texel sample's rows when the BTF has more
    #    texels than the `sample` option: the others go to their best cluster).
    ids, members = _native.lpca_cluster(z, h, w, options)
    del z
    k = len(members)
    # 4. One task per cluster over its members' ABRDFs, split from the tiles.
    split = [dask.delayed(_split_clusters, pure=True, nout=k)(b, present, ids[idx], k) for (b, *_), idx in zip(blocks, index)]
    tasks = []
    for c in range(k):
        pieces = []
        for s, idx in zip(split, index):
            mine = idx[ids[idx] == c]
            if len(mine):
                pieces += [s[c], mine]
        tasks.append(dask.delayed(_fit_cluster, pure=True)(c, h, w, options, *pieces))
    fits = _compute(tasks, callback(progress, "LPCA clusters"), "LPCA cluster fits")
    # 5. The model.
    native = _native.lpca_assemble(h, w, arr.views, arr.lights, arr.mask, ids, members, fits, options)
    return wrap(native)


def _fit_light_pca(kind: str, arr: BtfArray, options: Dict[str, Any], progress: Progress) -> Model:
    dask, _ = _dask()
    _native.light_pca_check(kind, _own(arr.views), _own(arr.lights), _own(arr.mask), options)
    blocks = _blocks(arr)
    name = kind
    # 1. Every tile's moments, merged in pairs on the workers.
    moments = _reduce([dask.delayed(_lp_moments, pure=True)(b, arr.views, arr.lights, arr.mask, kind, options)
                       for b, *_ in blocks], _lp_merge, callback(progress, f"{name} moments"), f"{name} moments")
    # 2. The principal functions on the client.
    table = _native.light_pca_table(kind, (moments[0], _own(moments[1]), _own(moments[2])), _own(arr.views),
                                    _own(arr.lights), _own(arr.mask), options)
    del moments
    # 3. Every tile projected; the coefficients stitched in texel order.
    table_d = dask.delayed(table)
    cs = _compute([dask.delayed(_lp_project, pure=True)(b, arr.views, arr.lights, arr.mask, kind, table_d, options)
                   for b, *_ in blocks], callback(progress, f"{name} projection"), f"{name} projection")
    coeffs = np.empty((arr.height, arr.width, cs[0].shape[2]), dtype=np.float32)
    for c, (_, r0, c0, nr, nc) in zip(cs, blocks):
        coeffs[r0:r0 + nr, c0:c0 + nc] = c
    del cs
    # 4. Quantized over all texels, as the local fit does.
    return wrap(_native.light_pca_assemble(kind, arr.views, arr.lights, arr.mask, table, coeffs, options))


# The stage protocols of staged fits (a registry entry's ``Blockwise::Staged(protocol)``).
_STAGES = {"mean_brdf": _fit_mean_brdf, "clustered_pca": _fit_clustered_pca, "light_pca": _fit_light_pca}
