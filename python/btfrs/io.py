"""Files: measured data in (UBO2003 / ATRIUM archives, UBO2014 ``.btf``, RTI ``.lp`` capture sets,
image stacks with a direction table), PTM and HSH ``.rti`` files for RTIViewer/relight, images, EXR coefficient
maps, the ``.btfrs`` container, and atomic writes.

:func:`load` opens any of them by its file type (see its docstring and the README's table of
formats and frame conventions).

Every file btfrs writes is written atomically: to a uniquely named temporary file in the target's
directory, synced, then renamed over the target, so an error or a Ctrl-C midway leaves the old
file (or none), never a half-written one. The Rust writers (containers, PTM, PNG, EXR) do it in
``btfrs-io``'s ``atomic.rs``; :func:`atomic_write` is the same procedure for what Python writes
(``.npy`` maps, text), and :func:`save_array` / :func:`save_text` use it.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import os
import stat
import warnings
from typing import IO, Any, Iterator, List, Optional, Sequence, Tuple, Union

import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import _native
from ._checks import memory_size, real
from ._progress import Progress, callback
from .btf import Btf
from .exceptions import FormatError, InvalidArgumentError
from .models import Model, wrap
from .models import load as load_btfrs

__all__ = ["load", "load_btfrs", "load_as_format", "save_image", "load_image", "save_stack", "save_coefficients",
           "capture_kind", "atomic_write", "save_array", "save_text"]

PathLike = Union[str, "os.PathLike[str]"]

_counter = itertools.count()

#: The suffix of btfrs's temporary files (``.{target}.{pid}.{n}.btfrs-tmp``), as btfrs-io names them.
TEMP_SUFFIX = ".btfrs-tmp"


def _temp_owner(name: str) -> Optional[int]:
    """The process id in a btfrs temporary file's name (or the ``.tmp`` of earlier versions)."""
    if not name.startswith("."):
        return None
    for suffix in (TEMP_SUFFIX, ".tmp"):
        if name.endswith(suffix):
            parts = name[: -len(suffix)].rsplit(".", 2)
            if len(parts) == 3 and len(parts[0]) >= 2 and parts[1].isdigit() and parts[2].isdigit():
                return int(parts[1])
    return None


def sweep_stale(directory: str) -> None:
    """Remove btfrs temporary files in ``directory`` left by writers that were killed (their
    process no longer runs). Only where the system lists running processes (``/proc``); files of
    running processes, this one included, are never touched; errors are ignored."""
    if not os.path.exists("/proc/self"):
        return
    try:
        names = os.listdir(directory or ".")
    except OSError:
        return
    for n in names:
        pid = _temp_owner(n)
        if pid is not None and pid != os.getpid() and not os.path.exists(f"/proc/{pid}"):
            with contextlib.suppress(OSError):
                os.unlink(os.path.join(directory, n))


@contextlib.contextmanager
def atomic_write(path: PathLike, mode: str = "wb") -> Iterator[IO[Any]]:
    """Open a temporary file next to ``path`` for writing; when the block ends without an error it
    is synced and renamed over ``path``, and on any exception (``KeyboardInterrupt`` included) it
    is removed and ``path`` is left as it was.

    >>> with atomic_write("coords.npy") as f:
    ...     np.save(f, cmap)
    """
    if mode not in ("wb", "w"):
        raise InvalidArgumentError(f"mode: expected \"wb\" or \"w\", got {mode!r}")
    p = os.fspath(path)
    directory, name = os.path.split(p)
    if not name:
        raise InvalidArgumentError(f"path: {p!r} does not name a file")
    # The same naming as btfrs-io: hidden, per process and call, never truncating another file,
    # and saying whose it is, so that the next write removes it if its writer was killed.
    sweep_stale(directory)
    for _ in range(100):
        tmp = os.path.join(directory, f".{name}.{os.getpid()}.{next(_counter)}{TEMP_SUFFIX}")
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666)
            break
        except FileExistsError:
            continue
    else:
        raise FileExistsError(f"{p}: could not create a temporary file next to it")
    try:
        with os.fdopen(fd, mode, encoding=None if "b" in mode else "utf-8") as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, p)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def save_array(path: PathLike, array: ArrayLike) -> None:
    """``numpy.save`` to ``path`` (a ``.npy`` file; the name is kept as given), atomically."""
    a = np.asanyarray(array)
    with atomic_write(path) as f:
        np.save(f, a, allow_pickle=False)


def load_array(path: PathLike) -> NDArray[Any]:
    """A ``.npy`` file written by :func:`save_array` (or ``numpy.save``), read without pickles:
    a file that is not one raises :class:`FormatError` naming it."""
    p = os.fspath(path)
    if os.path.exists(p):
        _check_regular(p)  # a FIFO would block np.load
    try:
        a = np.load(p, allow_pickle=False)
    except (ValueError, EOFError) as e:
        raise FormatError(f"{p}: not a .npy array ({e})") from None
    if not isinstance(a, np.ndarray):
        raise FormatError(f"{p}: a .npz archive, not one .npy array")
    return a


def save_text(path: PathLike, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path``, atomically."""
    with atomic_write(path, "w") as f:
        f.write(text)


def load_as_format(path: PathLike, cls: type = Model, *, max_bytes: Union[int, str, None] = None) -> Model:
    """Read another tool's model file (``.ptm``, ``.rti``: the formats of
    ``_native.model_formats()``, chosen by the extension) as a one-slot model, checking that it
    is a ``cls``. ``max_bytes`` (bytes, or a size such as ``"256MB"``) bounds what the reader
    allocates, as for :func:`load`. Values the reader changed (a roughness clamped to the
    model's range) are reported as one :class:`UserWarning` per kind."""
    raw, notes = _native.import_model(os.fspath(path), memory_size("max_bytes", max_bytes))
    for w in notes:
        warnings.warn(w, UserWarning, stacklevel=2)
    m = wrap(raw)
    if not isinstance(m, cls):
        raise FormatError(f"{os.fspath(path)}: holds a {type(m).__name__}, not a {cls.__name__}")
    return m


def save_image(path: PathLike, image: ArrayLike, *, exposure: float = 1.0) -> None:
    """Write an ``[H, W, 3]`` linear image, chosen by the extension: ``.png`` (8-bit sRGB, times
    ``exposure``, clipped to [0, 1]) or ``.exr`` (32-bit float OpenEXR, HDR values kept exactly,
    times ``exposure``). Written atomically."""
    p = os.fspath(path)
    ext = os.path.splitext(p)[1].lower()
    exposure = real("exposure", exposure, min=0.0)
    img = np.ascontiguousarray(image, dtype=np.float32)
    if ext == ".png":
        _native.write_png(p, img, exposure)
    elif ext == ".exr":
        _native.write_exr(p, img if exposure == 1.0 else np.ascontiguousarray(img * np.float32(exposure)))
    else:
        raise InvalidArgumentError(f"path: expected a .png or .exr file name, got {ext or 'no extension'!r}")


def load_image(path: PathLike) -> NDArray[np.float32]:
    """Read an ``[H, W, 3]`` float32 linear image from an 8-bit PNG or an OpenEXR file."""
    p = os.fspath(path)
    if os.path.splitext(p)[1].lower() == ".exr":
        return _native.read_exr(p)
    return _native.read_png(p)


# --- measured data in ---------------------------------------------------------------------------

_IMAGE_EXT = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".exr")


def _model_extensions() -> tuple[str, ...]:
    """The extensions of other tools' model files btfrs reads (``.ptm``, ``.rti``)."""
    return tuple("." + f.extension for f in _native.model_formats())


def _model_indexes() -> tuple[str, ...]:
    """The index files of other tools' model formats written as folders (``info.json``,
    ``material.gltf``, ``scene.xml``)."""
    return tuple(dict.fromkeys(f.index for f in _native.model_formats() if f.folder))


def _file_kind(path: str) -> Optional[str]:
    """``None`` for a regular file (links followed), else what it is in words (``"a FIFO"``),
    without opening it (a FIFO would block)."""
    mode = os.stat(path).st_mode
    if stat.S_ISREG(mode):
        return None
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISSOCK(mode):
        return "a socket"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    return "not a regular file"


def _check_regular(path: str) -> None:
    """A :class:`FormatError` naming ``path`` unless it is a regular file (links followed)."""
    what = _file_kind(path)
    if what is not None:
        raise FormatError(f"{path}: is {what}; expected a regular file")


def _model_index(folder: str) -> str:
    """The index file of the model format folder ``folder`` (a regular file)."""
    names = [n for n in _model_indexes() if os.path.exists(os.path.join(folder, n))]
    if not names:
        raise FormatError(f"{folder}: holds none of {', '.join(_model_indexes())}")
    if len(names) > 1:
        raise FormatError(f"{folder}: holds {' and '.join(names)}; pass the one to load")
    index = os.path.join(folder, names[0])
    _check_regular(index)
    return index


def capture_kind(path: PathLike, directions: Optional[PathLike] = None) -> str:
    """What :func:`load` takes ``path`` for: ``"btfrs"``, ``"model_file"`` (another tool's model
    file: ``.ptm``, ``.rti``, a relight / NeuralRTI web folder or its ``info.json``, a glTF asset or a Mitsuba scene written by btfrs), ``"ubo2014"``,
    ``"lp"`` (an RTI ``.lp`` file, or a folder holding exactly one), ``"table"`` (a folder with
    a ``directions=`` table, or holding ``directions.csv`` / ``.json``), ``"ubo2003"`` (a zip archive or a folder of images whose names carry
    the angles). Raises :class:`~btfrs.exceptions.FormatError` when it is none of these."""
    p = os.fspath(path)
    ext = os.path.splitext(p)[1].lower()
    if directions is not None:
        return "table"
    base = os.path.basename(os.path.normpath(p))
    if os.path.isdir(p) and (base in _model_indexes() or ext in (".lp", ".btfrs", ".btf") + _model_extensions()):
        raise FormatError(f"{p}: is a folder; expected a regular file")
    if os.path.isdir(p):
        names = sorted(os.listdir(p))
        lps = [n for n in names if n.lower().endswith(".lp")]
        if len(lps) == 1:
            return "lp"
        if len(lps) > 1:
            raise FormatError(f"{p}: holds several .lp files ({', '.join(lps)}); pass the one to load")
        if _default_table(p) is not None:
            return "table"
        if any(index in names for index in _model_indexes()):
            return "model_file"  # relight's or NeuralRTI's web format, a glTF asset, a Mitsuba scene
        if not any(n.lower().endswith(_IMAGE_EXT) for n in names):
            raise FormatError(f"{p}: the folder holds no images and no .lp file; expected an RTI capture "
                              f"(.lp + photos), a UBO-style image folder, or images with directions=")
        return "ubo2003"
    if not os.path.exists(p):
        raise FileNotFoundError(f"{p}: no such file or folder")
    _check_regular(p)
    table = {".btfrs": "btfrs", ".btf": "ubo2014", ".lp": "lp", ".zip": "ubo2003"}
    if ext in table:
        return table[ext]
    if ext in _model_extensions():
        return "model_file"
    with open(p, "rb") as f:
        head = f.read(16)
    if head.startswith(b"BTFRS01"):
        return "btfrs"
    if head.startswith(b"!"):
        return "ubo2014"
    raise FormatError(f"{p}: unknown file type {ext or '(no extension)'!r}; expected .btfrs, .btf (UBO2014), "
                      f".zip or a folder (UBO2003 / ATRIUM), .lp (RTI), .ptm, .rti, or a folder with directions=")


def _default_table(folder: str) -> Optional[str]:
    """The direction table :func:`save_stack` writes, if ``folder`` has one."""
    for n in ("directions.csv", "directions.json"):
        if os.path.isfile(os.path.join(folder, n)):
            return os.path.join(folder, n)
    return None


def _index_list(name: str, sel: object) -> Optional[List[int]]:
    if sel is None:
        return None
    if isinstance(sel, slice):
        raise InvalidArgumentError(f"{name}: expected a sequence of indices, got a slice (use list(range(...)))")
    try:
        out = [int(i) for i in np.asarray(sel).reshape(-1)]
    except (TypeError, ValueError):
        raise InvalidArgumentError(f"{name}: expected a sequence of non-negative integers, got {sel!r}") from None
    if any(i < 0 for i in out):
        raise InvalidArgumentError(f"{name}: expected non-negative indices, got {out}")
    return out


def _crop(crop: Optional[Sequence[int]]) -> Optional[Tuple[int, int, int, int]]:
    if crop is None:
        return None
    try:
        c = tuple(int(x) for x in crop)
    except (TypeError, ValueError):
        raise InvalidArgumentError(f"crop: expected (row, col, rows, cols), got {crop!r}") from None
    if len(c) != 4 or any(x < 0 for x in c):
        raise InvalidArgumentError(f"crop: expected four non-negative integers (row, col, rows, cols), got {crop!r}")
    return c


def _select_btf(btf: Btf, crop: Optional[Sequence[int]], views: Optional[Sequence[int]],
                lights: Optional[Sequence[int]]) -> Btf:
    """``crop``, ``views`` and ``lights`` of :func:`load` applied to a BTF in memory."""
    if views is None and lights is None and crop is None:
        return btf
    obj = btf.select(views=views, lights=lights)
    if crop is not None:
        rect = _crop(crop)
        assert rect is not None
        r, c, nr, nc = rect
        if r + nr > obj.height or c + nc > obj.width or nr == 0 or nc == 0:
            raise InvalidArgumentError(f"crop: {crop!r} lies outside the {obj.height} x {obj.width} BTF")
        obj = Btf(np.ascontiguousarray(obj.data[r:r + nr, c:c + nc]), obj.views, obj.lights, obj.mask,
                  check=False, meta=obj.meta)
    return obj


def load(path: PathLike, *, directions: Optional[PathLike] = None, crop: Optional[Sequence[int]] = None,
         views: Optional[Sequence[int]] = None, lights: Optional[Sequence[int]] = None,
         mmap_to: Optional[PathLike] = None, linear: bool = False, mmap: bool = False, progress: Progress = None,
         max_bytes: Union[int, str, None] = None, allow_outside: bool = False,
         memory_limit: Union[int, str, None] = None) -> Any:
    """Load any file btfrs reads, chosen by its type (:func:`capture_kind`): a measured capture,
    a ``.btfrs`` file (a BTF, a fitted model, a synthesis analysis, a Wang tile set), or another
    tool's model file (``.ptm``, ``.rti``). This is ``btfrs.load``.

    * ``WoolPKNT256.zip`` or a folder of images named ``..._tl015_pl000_tv015_pv120.jpg``
      (Bonn UBO2003 / ATRIUM; JPEG/PNG are sRGB-decoded, EXR kept linear);
    * ``carpet01_...L151xV151.btf`` (Bonn UBO2014, DFMF: decoded from its low-rank factors);
    * ``capture/dirs.lp`` or a folder holding one ``.lp`` (RTI: one view, the lights of the file);
    * a folder of images with ``directions="table.csv"`` (or ``.json``; a ``directions.csv`` or
      ``directions.json`` inside the folder is found without it): columns ``file`` and
      ``light_theta, light_phi`` (degrees) or ``lx, ly, lz``, optionally ``view_theta, view_phi``
      or ``vx, vy, vz``;
    * ``.btfrs``: a BTF (``mmap=True`` maps its values instead of reading them, so a BTF larger
      than memory opens at once), a fitted model, an analysis or a tile set;
    * ``.ptm`` (RGB and LRGB PTM 1.2) and ``.rti`` (HSH) files of RTIViewer and relight, as
      one-slot models.

    Captures come back as a :class:`~btfrs.Btf` in btfrs's frame (z the normal, x along the image
    columns, y up the image). ``crop=(row, col, rows, cols)`` keeps a rectangle (row 0 is the top
    of the images); ``views`` and ``lights`` keep subsets, as indices into the file's views and
    lights (UBO archives: sorted by theta, then phi; ``.lp``: the file's order); only what is kept
    is ever decoded. ``mmap_to="big.btfrs"`` decodes straight into that file (memory-mapped,
    written atomically) and returns it opened with ``mmap=True``, so a capture larger than memory
    loads. A capture of several photographs is decoded first (in parallel) and then written
    into the texel-major BTF once, band by band: the decoded photographs wait in memory up to
    ``memory_limit`` (bytes, or ``"2GB"``, ``"512MiB"``; default: a quarter of the physical
    memory) and beyond it in an unlinked temporary file in ``TMPDIR``, so a capture of 60
    photographs of 24 megapixels (4.3 GB of 8-bit samples) loads under ``memory_limit="2GB"``;
    a limit below one photograph's samples (and a third more) is an
    :class:`~btfrs.exceptions.InvalidArgumentError` naming it. ``linear=True`` reads 8/16-bit
    images as linear (e.g. TIFFs converted from RAW) instead of sRGB (captures only: it is refused for a ``.btfrs`` or model file). ``progress`` shows or reports decoding progress; Ctrl-C stops it and writes nothing.
    Light vectors of an ``.lp`` file or a table that are not unit length are normalised, and a
    light at most 0.02 below the horizon (as unit z) is moved onto it, each kind of repair
    reported in one :class:`UserWarning` per file (how many, the range, the first lines).

    Files from strangers (docs/real-data.md): only regular files are read (a folder, FIFO or
    device where a file is expected is a :class:`~btfrs.exceptions.FormatError` naming it); a
    capture or model needing more than ``max_bytes`` bytes (a number, or a size such as
    ``"256MB"`` or ``"2GiB"``: the in-memory BTF or model, any decoded image, an archive entry,
    an index file's parse; default: half the machine's physical memory), an image whose decoded
    size is implausible for its bytes on disk, or an index file over its format's cap is
    refused with :class:`~btfrs.exceptions.FormatError` before anything is allocated. Image
    paths in ``.lp`` files and direction tables must stay inside the capture's folder (symlinks
    resolved) unless ``allow_outside=True``.
    """
    p = os.fspath(path)
    max_bytes = memory_size("max_bytes", max_bytes)
    limit = memory_size("memory_limit", memory_limit)
    kind = capture_kind(p, directions)
    given = {k: v for k, v in dict(crop=crop, views=views, lights=lights, mmap_to=mmap_to,
                                   memory_limit=memory_limit).items() if v is not None}
    if kind in ("btfrs", "model_file"):
        if linear:
            raise InvalidArgumentError(f"linear: only applies to captures of 8/16-bit images ({p} is a "
                                       f"{'.btfrs file' if kind == 'btfrs' else 'model file'})")
        obj: Any
        if kind == "model_file":
            obj = load_as_format(_model_index(p) if os.path.isdir(p) else p, max_bytes=max_bytes)
        elif mmap and _native.read_container_header(p)[0] == "btf":
            obj = Btf.load(p, mmap=True)
        else:
            obj = load_btfrs(p)
        if given:
            if not isinstance(obj, Btf) or "mmap_to" in given or "memory_limit" in given:
                raise InvalidArgumentError(f"{', '.join(given)}: only apply to measured captures and BTFs"
                                           f" (this file holds a {type(obj).__name__})")
            obj = _select_btf(obj, crop, views, lights)
        return obj
    if kind == "table" and directions is None:
        directions = _default_table(p)
    if kind == "lp" and os.path.isdir(p):
        p = os.path.join(p, next(n for n in sorted(os.listdir(p)) if n.lower().endswith(".lp")))
    out = None if mmap_to is None else os.fspath(mmap_to)
    if out is not None and os.path.abspath(out) == os.path.abspath(p):
        raise InvalidArgumentError("mmap_to: must not be the file being loaded")
    data, vdirs, ldirs, mask, meta = _native.load_capture(
        kind, p, None if directions is None else os.fspath(directions), _crop(crop),
        _index_list("views", views), _index_list("lights", lights), bool(linear), out,
        callback(progress, f"loading {os.path.basename(p.rstrip(os.sep)) or p}"), max_bytes, bool(allow_outside),
        limit)
    info = json.loads(meta)
    for w in info.get("warnings", []):
        warnings.warn(w, UserWarning, stacklevel=2)
    if out is not None:
        return Btf.load(out, mmap=True)
    # The loaders check every value as they decode it, and the directions are unit by
    # construction: no second scan.
    assert data is not None
    return Btf(data, vdirs, ldirs, mask, check=False, meta=info)


# --- data out -----------------------------------------------------------------------------------

def save_stack(btf: Btf, folder: PathLike, *, format: str = "exr", exposure: float = 1.0) -> str:
    """Write a BTF as an image stack other tools read: one image per present (view, light) pair
    (``format="exr"``: 32-bit float, exact; ``"png"``: 8-bit sRGB times ``exposure``) named
    ``v{view:03d}_l{light:04d}.{format}``, and ``directions.csv`` beside them (columns ``file,
    vx, vy, vz, lx, ly, lz``), which :func:`load` reads back with ``directions=``. Every file is
    written atomically and the table last, so an interrupted export has no table. Returns the
    table's path."""
    if not isinstance(btf, Btf):
        raise InvalidArgumentError(f"btf: expected a btfrs.Btf, got {type(btf).__name__}")
    if format not in ("exr", "png"):
        raise InvalidArgumentError(f"format: expected \"exr\" or \"png\", got {format!r}")
    d = os.fspath(folder)
    os.makedirs(d, exist_ok=True)
    rows = ["file,vx,vy,vz,lx,ly,lz"]
    for v in range(btf.n_views):
        for l in range(btf.n_lights):
            if btf.mask is not None and not btf.mask[v, l]:
                continue
            name = f"v{v:03d}_l{l:04d}.{format}"
            save_image(os.path.join(d, name), btf.image(v, l), exposure=exposure)
            vv, ll = btf.views[v], btf.lights[l]
            rows.append(",".join([name] + [repr(float(x)) for x in (*vv, *ll)]))
    table = os.path.join(d, "directions.csv")
    save_text(table, "\n".join(rows) + "\n")
    return table


def coefficient_planes(model: Model) -> tuple[list[str], NDArray[np.float32]]:
    """Every per-texel array of ``model`` as named float32 planes ``[C, H, W]``: channel names
    ``{kind}.{array}.{index}`` with the trailing axes' indices joined by ``.``, the last axis of
    extent 3 taken for colour and named ``R``, ``G``, ``B`` (e.g. ``ptm.coeffs.0.R.5``: view
    slot 0, red, coefficient a5). 8-bit arrays keep their byte values
    (their scale and bias are in the model's other arrays)."""
    if not isinstance(model, Model):
        raise InvalidArgumentError(f"model: expected a fitted btfrs model, got {type(model).__name__}")
    h, w = model.height, model.width
    names, planes = [], []
    for name in _native.texel_arrays(model.kind):
        a = model.arrays.get(name)
        if a is None or a.ndim < 2 or a.shape[:2] != (h, w):
            continue
        rest = a.shape[2:]
        flat = np.asarray(a, dtype=np.float32).reshape(h, w, -1)
        colour = max((i for i, n in enumerate(rest) if n == 3), default=None)
        for k, idx in enumerate(np.ndindex(*rest) if rest else [()]):
            parts = [str(i) for i in idx]
            if colour is not None:
                parts[colour] = "RGB"[idx[colour]]
            names.append(".".join([model.kind, name] + parts))
            planes.append(flat[:, :, k])
    if not planes:
        raise InvalidArgumentError(f"model: the {model.kind} model has no per-texel arrays to export")
    return names, np.ascontiguousarray(np.stack(planes))


def save_coefficients(model: Model, path: PathLike) -> list[str]:
    """Write every per-texel array of ``model`` as one multi-channel OpenEXR file (32-bit float,
    lossless; channel names from :func:`coefficient_planes`, row 0 at the top), so other tools
    can use the coefficient maps. Returns the channel names. Written atomically."""
    names, planes = coefficient_planes(model)
    p = os.fspath(path)
    if not p.lower().endswith(".exr"):
        raise InvalidArgumentError(f"path: expected a .exr file name, got {p!r}")
    _native.write_exr_channels(p, names, planes)
    return names
