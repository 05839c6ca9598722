"""The BTF container.

A :class:`Btf` holds images of a flat material sample under many (view, light) direction pairs,
stored **texel-major**: ``data[row, col, view, light, channel]``, float32 linear RGB, shape
``[H, W, V, L, 3]``. Each texel's apparent BRDF is contiguous (what fitting, LPCA and synthesis
read); :meth:`Btf.image` and :meth:`Btf.images` give image-major views without copying. Values
include the cos(theta_l) foreshortening, as measured BTFs do.

Row 0 is the top of the sample seen from above; in the tangent frame x runs along the columns and
y up the rows (see :mod:`btfrs.directions`). ``mask[v, l]`` (optional) says which pairs are
present: a train/test split is two masks over the same data, so nothing is copied.
"""

from __future__ import annotations

import json
import math
import os
from typing import Any, Dict, List, Optional, Sequence, Set, Tuple, Union

import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import _native
from ._checks import PathLike
from ._checks import index as check_index
from ._checks import instance, real
from ._checks import seed as check_seed
from .exceptions import ArgumentTypeError, FormatError, InvalidArgumentError, OutOfRangeError

__all__ = ["Btf", "ExpandedBtf"]

Index = Union[None, int, slice, Sequence[int], NDArray[Any]]


def _directions(name: str, d: ArrayLike) -> NDArray[np.float64]:
    a = np.asarray(d)
    if not np.issubdtype(a.dtype, np.floating) and not np.issubdtype(a.dtype, np.integer):
        raise ArgumentTypeError(f"{name}: expected an array of numbers, got dtype {a.dtype}")
    if a.ndim != 2 or a.shape[1] != 3:
        raise InvalidArgumentError(f"{name}: expected shape (N, 3), got {a.shape}")
    return np.ascontiguousarray(a, dtype=np.float64)


def _selection(name: str, sel: Index, n: int) -> Union[slice, NDArray[Any]]:
    """A view or light selection as a numpy index that keeps the axis: a slice, or an int array
    of indices in [0, n) (negative indices would wrap silently, so they are rejected)."""
    if sel is None:
        return slice(None)
    if isinstance(sel, slice):
        return sel
    a = np.asarray(sel)
    if a.size == 0 and a.ndim == 1:
        a = a.astype(np.intp)  # [] is float64 to numpy; an empty selection is reported by select
    if a.dtype == np.bool_:
        if a.shape != (n,):
            raise InvalidArgumentError(f"{name}: a bool mask must have shape ({n},), got {a.shape}")
        return np.flatnonzero(a)
    if not np.issubdtype(a.dtype, np.integer) or a.ndim > 1:
        raise ArgumentTypeError(f"{name}: expected indices (an int or a list of ints), a slice or a bool mask, "
                                f"got {type(sel).__name__} of dtype {a.dtype} and shape {a.shape}")
    a = a.reshape(-1)
    bad = (a < 0) | (a >= n)
    if bad.any():
        raise OutOfRangeError(f"{name}: expected indices in [0, {n}), got {int(a[bad][0])}")
    return a


class Btf:
    """A bidirectional texture function sample.

    Parameters
    ----------
    data:
        ``[H, W, V, L, 3]`` linear RGB. float32 is used as is (no copy when C-contiguous); other
        float dtypes are converted (a copy). Integer data is rejected: convert it to linear
        float yourself, since only you know its scale and transfer curve.
    views, lights:
        ``[V, 3]`` and ``[L, 3]`` unit directions with z >= 0.
    mask:
        Optional ``[V, L]`` bool, True where the pair is present.
    check:
        Scan the values for NaN/inf (a parallel pass over the data; on by default).
    meta:
        Optional JSON-serialisable dict describing where the values come from (see
        :attr:`meta`).
    """

    __slots__ = ("_data", "_views", "_lights", "_mask", "_source", "_meta", "__weakref__")

    def __init__(self, data: ArrayLike, views: ArrayLike, lights: ArrayLike, mask: Optional[ArrayLike] = None, *,
                 check: bool = True, meta: Optional[Dict[str, Any]] = None) -> None:
        a = data if isinstance(data, np.ndarray) else np.asarray(data)
        if not np.issubdtype(a.dtype, np.floating):
            raise ArgumentTypeError(f"data: expected a float array (float32 preferred), got dtype {a.dtype}")
        if a.ndim != 5 or a.shape[-1] != 3:
            raise InvalidArgumentError(f"data: expected shape (H, W, V, L, 3), got {a.shape}")
        if a.dtype != np.float32 or not a.flags.c_contiguous:
            a = np.ascontiguousarray(a, dtype=np.float32)
        self._data: NDArray[np.float32] = a
        # (path, size, mtime) of the file whose values are mapped (Btf.load with mmap=True).
        self._source: Optional[Tuple[str, int, int]] = None
        self._views = _directions("views", views)
        self._lights = _directions("lights", lights)
        self._mask: Optional[NDArray[np.bool_]] = None
        if mask is not None:
            m = np.asarray(mask)
            if m.dtype != np.bool_:
                raise ArgumentTypeError(f"mask: expected a bool array, got dtype {m.dtype}")
            # Normalise to bytes 0/1: a bool array viewed from other bytes may hold e.g. 2, which
            # numpy reads as True but Rust's bool may not.
            self._mask = np.ascontiguousarray(m.view(np.uint8) != 0) if m.ndim else m
        # Shapes, directions and the mask are always checked; `check` adds the value scan.
        _native.validate_btf(self._data, self._views, self._lights, self._mask, scan_values=check)
        if meta is None:
            meta = {}
        if not isinstance(meta, dict):
            raise ArgumentTypeError(f"meta: expected a dict, got {type(meta).__name__}")
        try:
            # A deep copy through JSON: what is kept is exactly what a .btfrs file can store.
            self._meta: Dict[str, Any] = json.loads(json.dumps(meta, allow_nan=False))
        except (TypeError, ValueError) as e:
            raise InvalidArgumentError(f"meta: expected a JSON-serialisable dict with finite numbers ({e})") from None

    # --- shape and access -------------------------------------------------------------------
    @property
    def data(self) -> np.ndarray:
        """``[H, W, V, L, 3]`` float32 values (texel-major)."""
        return self._data

    @property
    def views(self) -> np.ndarray:
        """``[V, 3]`` view directions."""
        return self._views

    @property
    def lights(self) -> np.ndarray:
        """``[L, 3]`` light directions."""
        return self._lights

    @property
    def mask(self) -> Optional[np.ndarray]:
        """``[V, L]`` bool mask of present pairs, or None when all are present."""
        return self._mask

    @property
    def meta(self) -> Dict[str, Any]:
        """Where the values come from (a copy): for a loaded capture, the file's format and
        header fields, and under ``"values"`` how its numbers were brought to btfrs's convention
        (linear RGB, the cosine of the light's polar angle included, the file's colour scale
        applied): ``cosine`` (in the data, or multiplied in by the reader), ``scale_applied``
        (per channel) and ``transfer``. Kept by :meth:`select`, :meth:`split` and crops, saved
        in ``.btfrs`` files and printed by ``btfrs info``."""
        copied: Dict[str, Any] = json.loads(json.dumps(self._meta))
        return copied

    @property
    def shape(self) -> Tuple[int, ...]:
        """``(H, W, V, L, 3)``."""
        return tuple(self._data.shape)

    @property
    def height(self) -> int:
        return int(self._data.shape[0])

    @property
    def width(self) -> int:
        return int(self._data.shape[1])

    @property
    def n_views(self) -> int:
        return int(self._data.shape[2])

    @property
    def n_lights(self) -> int:
        return int(self._data.shape[3])

    @property
    def pairs(self) -> int:
        """Number of present (view, light) pairs."""
        return int(self._mask.sum()) if self._mask is not None else self.n_views * self.n_lights

    @property
    def nbytes(self) -> int:
        """Bytes of the value array (the directions and mask are negligible)."""
        return int(self._data.nbytes)

    def image(self, view: int, light: int) -> np.ndarray:
        """The ``[H, W, 3]`` image of one (view, light) pair: a strided view, no copy.
        Indices outside ``[0, n)`` raise :class:`~btfrs.exceptions.OutOfRangeError`."""
        v = check_index("view", view, self.n_views)
        l = check_index("light", light, self.n_lights)
        return self._data[:, :, v, l, :]

    def images(self) -> np.ndarray:
        """Image-major view ``[V, L, H, W, 3]`` of the same memory (no copy)."""
        return self._data.transpose(2, 3, 0, 1, 4)

    def abrdf(self, row: int, col: int) -> np.ndarray:
        """The ``[V, L, 3]`` apparent BRDF of one texel (contiguous, no copy). Indices outside
        ``[0, height)`` / ``[0, width)`` raise :class:`~btfrs.exceptions.OutOfRangeError`."""
        texel: NDArray[np.float32] = self._data[check_index("row", row, self.height),
                                                check_index("col", col, self.width)]
        return texel

    # --- derived samples ---------------------------------------------------------------------
    def split(self, *, holdout: float = 0.1, seed: int = 0) -> tuple["Btf", "Btf"]:
        """Split the present (view, light) pairs into ``(train, test)``.

        ``test`` holds ``round(holdout * pairs)`` pairs drawn with ``seed``; both share this
        sample's data (nothing is copied) and differ only in their masks. ``holdout`` is in (0, 1).
        """
        h = real("holdout", holdout, min=0.0, max=1.0, min_open=True, max_open=True)
        tr, te = _native.split_pairs(self.n_views, self.n_lights, h, check_seed(seed), self._mask)
        return (Btf(self._data, self._views, self._lights, tr, check=False, meta=self._meta),
                Btf(self._data, self._views, self._lights, te, check=False, meta=self._meta))

    def select(self, *, views: Index = None, lights: Index = None) -> "Btf":
        """A sample restricted to some views and/or lights: an index, a list of indices (in
        ``[0, n)``; negative ones raise :class:`~btfrs.exceptions.OutOfRangeError` rather than
        wrap), a slice or a bool mask of length n.

        The result holds a C-contiguous copy of the selected part: the Rust core reads each
        texel's values as one contiguous block, which a strided view would not give.
        """
        vi = _selection("views", views, self.n_views)
        li = _selection("lights", lights, self.n_lights)
        vdirs = self._views[vi]
        ldirs = self._lights[li]
        if len(vdirs) == 0 or len(ldirs) == 0:
            raise InvalidArgumentError("views/lights: the selection must keep at least one view and one light")
        data = np.ascontiguousarray(self._data[:, :, vi][:, :, :, li])
        mask = None if self._mask is None else self._mask[vi][:, li]
        return Btf(data, vdirs, ldirs, mask, check=False, meta=self._meta)

    # --- files -------------------------------------------------------------------------------
    def save(self, path: PathLike) -> None:
        """Write to one ``.btfrs`` file (atomically: a temporary file, then a rename).

        The values are scanned first: NaN or infinite values raise
        :class:`~btfrs.exceptions.InvalidArgumentError` (naming ``data``) and nothing is
        written. The file's header then records that the data are finite (the container's
        per-array ``finite`` flag), which lets :meth:`load` with ``mmap=True`` skip its scan.
        """
        _native.validate_btf(self._data, self._views, self._lights, self._mask, scan_values=True)
        arrays: List[Tuple[str, NDArray[Any]]] = [("data", self._data), ("views", self._views), ("lights", self._lights)]
        if self._mask is not None:
            arrays.append(("mask", self._mask))
        meta = json.dumps({"layout": "HWVL3", "source": self._meta})
        _native.save_container(os.fspath(path), "btf", meta, arrays)

    @classmethod
    def load(cls, path: PathLike, mmap: bool = False) -> "Btf":
        """Read a ``.btfrs`` BTF; ``mmap=True`` maps the values instead of reading them.

        Without ``mmap`` the values are read and scanned: NaN or infinite values are a
        :class:`~btfrs.exceptions.FormatError`. With ``mmap`` the scan would read every page of
        the file, so a file whose header says its data were finite when written (every file
        :meth:`save` writes) is trusted and not scanned: loading reads only the header, the
        directions and the mask. The flag is only as true as the file: if the data section was
        edited or corrupted after writing, the load still succeeds and values may be non-finite
        (the fits and :func:`btfrs.synth.analyse` scan their input and raise then). Files
        written before the flag existed are scanned, as without ``mmap``.
        """
        kind, meta, arrays, finite = _read_container(path, mmap=mmap)
        if kind != "btf":
            raise FormatError(f"{os.fspath(path)}: holds a {kind!r}, not a BTF (use btfrs.load)")
        source = meta.get("source", {}) if isinstance(meta, dict) else {}
        btf = cls.from_arrays(path, arrays, check=not (mmap and "data" in finite),
                              meta=source if isinstance(source, dict) else {})
        if mmap:
            full = os.path.abspath(os.fspath(path))  # a later chdir must not look like a change
            btf._source = (full,) + _stamp(full)
        return btf

    def _check_unchanged(self, what: str) -> None:
        """For a memory-mapped Btf: a FormatError when its file changed on disk (size or
        modification time) since it was opened, so a fit or analysis that read it while another
        process rewrote it is not returned as if it had read one BTF."""
        if self._source is None:
            return
        path, size, mtime = self._source
        try:
            now = _stamp(path)
        except OSError:
            now = None
        if now != (size, mtime):
            raise FormatError(f"{path}: the file changed on disk during the {what} (its size or modification time "
                              f"is not what it was when opened); open it again and rerun")

    @classmethod
    def from_arrays(cls, path: PathLike, arrays: Dict[str, NDArray[Any]], *, check: bool = True,
                    meta: Optional[Dict[str, Any]] = None) -> "Btf":
        """Build from the arrays of a ``.btfrs`` file. A missing array, or arrays that do not
        make a valid BTF (dtypes, shapes, non-unit directions, an empty mask, and non-finite
        values when ``check``), are a FormatError naming the file."""
        p = os.fspath(path)
        try:
            return cls(arrays["data"], arrays["views"], arrays["lights"], arrays.get("mask"), check=check, meta=meta)
        except KeyError as e:
            raise FormatError(f"{p}: the BTF file has no array {e}") from None
        except (TypeError, ValueError) as e:  # InvalidArgumentError is a ValueError
            raise FormatError(f"{p}: not a valid BTF file ({e})") from None

    def expand(self, coords: ArrayLike) -> "ExpandedBtf":
        """A large BTF made of this sample and a coordinate map (from :mod:`btfrs.synth`),
        without copying the data: see :class:`ExpandedBtf`."""
        return ExpandedBtf(self, coords)

    def __repr__(self) -> str:
        h, w, v, l, _ = self.shape
        present = "" if self._mask is None else f", {self.pairs} of {v * l} pairs present"
        return f"Btf({h} x {w} texels, {v} views x {l} lights{present}, {self.nbytes / 2**20:.1f} MiB)"


class ExpandedBtf:
    """A synthesized BTF: a sample :class:`Btf` plus a coordinate map (paper 000, section 4,
    "Using large BTFs for rendering"). Texel ``(i, j)`` is the sample texel ``coords[i, j]``
    (``(x, y)``, uint16). Nothing is copied: the map costs 4 bytes per texel, so a 4096 x 4096
    BTF from a 64 x 64 sample is the sample plus 64 MiB. Images and ABRDFs are gathered on
    request; :meth:`to_btf` materialises the whole thing (the full size, explicitly).
    """

    def __init__(self, sample: Btf, coords: ArrayLike) -> None:
        instance("sample", sample, Btf, "a btfrs.Btf")
        c = np.asarray(coords)
        if c.dtype != np.uint16:
            raise ArgumentTypeError(f"coords: expected a uint16 array [H, W, 2], got dtype {c.dtype}")
        if c.ndim != 3 or c.shape[2] != 2 or c.shape[0] == 0 or c.shape[1] == 0:
            raise InvalidArgumentError(f"coords: expected a non-empty shape (H, W, 2), got {c.shape}")
        if int(c[..., 0].max()) >= sample.width or int(c[..., 1].max()) >= sample.height:
            raise InvalidArgumentError(
                f"coords: points outside the {sample.height} x {sample.width} sample "
                f"(max x {int(c[..., 0].max())}, max y {int(c[..., 1].max())})")
        self.sample = sample
        self.coords = np.ascontiguousarray(c)
        self.coords.flags.writeable = False

    views = property(lambda self: self.sample.views, doc="``[V, 3]`` view directions.")
    lights = property(lambda self: self.sample.lights, doc="``[L, 3]`` light directions.")
    mask = property(lambda self: self.sample.mask, doc="Optional ``[V, L]`` mask of present pairs.")
    height = property(lambda self: int(self.coords.shape[0]), doc="Rows.")
    width = property(lambda self: int(self.coords.shape[1]), doc="Columns.")

    @property
    def meta(self) -> Dict[str, Any]:
        """The sample's :attr:`Btf.meta`."""
        return self.sample.meta

    @property
    def shape(self) -> Tuple[int, ...]:
        """``(H, W, V, L, 3)`` of the expanded BTF."""
        _, _, v, l, c = self.sample.shape
        return (self.height, self.width, v, l, c)

    @property
    def nbytes(self) -> int:
        """Bytes held: the sample plus the map."""
        return self.sample.nbytes + self.coords.nbytes

    @property
    def nbytes_expanded(self) -> int:
        """Bytes the materialised BTF would take."""
        return int(np.prod(self.shape)) * 4

    def image(self, view: int, light: int) -> np.ndarray:
        """``[H, W, 3]`` image for one (view, light) pair (gathered from the sample)."""
        gathered: NDArray[np.float32] = self.sample.image(view, light)[self.coords[..., 1], self.coords[..., 0]]
        return gathered

    def abrdf(self, row: int, col: int) -> np.ndarray:
        """``[V, L, 3]`` apparent BRDF of one texel (a view into the sample)."""
        x, y = self.coords[check_index("row", row, self.height), check_index("col", col, self.width)]
        return self.sample.abrdf(int(y), int(x))

    def to_btf(self) -> Btf:
        """Materialise the full ``[H, W, V, L, 3]`` BTF (``nbytes_expanded`` bytes)."""
        data = self.sample.data[self.coords[..., 1], self.coords[..., 0]]
        return Btf(data, self.sample.views, self.sample.lights, self.sample.mask, check=False, meta=self.sample.meta)

    def __repr__(self) -> str:
        return (f"ExpandedBtf({self.height} x {self.width} texels from a {self.sample.height} x "
                f"{self.sample.width} sample, {self.nbytes / 2**20:.1f} MiB held, "
                f"{self.nbytes_expanded / 2**20:.0f} MiB expanded)")


_DTYPES = {"f32": np.float32, "f64": np.float64, "u8": np.uint8, "u16": np.uint16, "i32": np.int32,
           "bool": np.bool_}


def _stamp(path: str) -> Tuple[int, int]:
    st = os.stat(path)
    return (st.st_size, st.st_mtime_ns)


def _read_container(path: PathLike, mmap: bool = False) -> Tuple[str, Dict[str, Any], Dict[str, NDArray[Any]], Set[str]]:
    """:func:`read_container` plus the names of the float arrays whose header entry says they
    were finite when written (see :meth:`Btf.load`)."""
    p = os.fspath(path)
    # The Rust reader checks the header against the file: every array's size and extent fit the
    # file, names are unique and meta is a JSON object, so nothing below allocates more than
    # the file holds.
    kind, meta, infos = _native.read_container_header(p)
    arrays: Dict[str, NDArray[Any]] = {}
    finite: Set[str] = set()
    for name, dt, shape, offset, is_finite in infos:
        if dt not in _DTYPES:
            raise FormatError(f"{p}: array {name!r} has unknown dtype {dt!r}")
        shp = tuple(shape)
        count = math.prod(shp)
        if count == 0:
            a: NDArray[Any] = np.zeros(shp, dtype=_DTYPES[dt])  # numpy cannot map zero bytes
        elif mmap:
            a = np.asarray(np.memmap(p, dtype=_DTYPES[dt], mode="r", offset=offset, shape=shp))
        else:
            a = np.fromfile(p, dtype=_DTYPES[dt], count=count, offset=offset)
            if a.size != count:  # the file shrank since its header was read
                raise FormatError(f"{p}: array {name!r} is truncated")
            a = a.reshape(shp)
        arrays[name] = a
        if is_finite:
            finite.add(name)
    return kind, json.loads(meta), arrays, finite


def read_container(path: PathLike, mmap: bool = False) -> Tuple[str, Dict[str, Any], Dict[str, NDArray[Any]]]:
    """Read a ``.btfrs`` file: ``(kind, meta, {name: array})``. Arrays are read with one
    ``numpy.fromfile`` each (or memory-mapped), at the offsets the Rust writer recorded. A file
    that is not a valid container (bad magic, a header inconsistent with the file, truncated)
    raises :class:`~btfrs.exceptions.FormatError`."""
    kind, meta, arrays, _ = _read_container(path, mmap=mmap)
    return kind, meta, arrays
