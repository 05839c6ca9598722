"""Files: PTM and HSH ``.rti`` files for RTIViewer/relight, images, the ``.btfrs`` container, and atomic writes.

Every file btfrs writes is written atomically: to a uniquely named temporary file in the target's
directory, synced, then renamed over the target, so an error or a Ctrl-C midway leaves the old
file (or none), never a half-written one. The Rust writers (containers, PTM, PNG, EXR) do it in
``btfrs-io``'s ``atomic.rs``; :func:`atomic_write` is the same procedure for what Python writes
(``.npy`` maps, text), and :func:`save_array` / :func:`save_text` use it.
"""

from __future__ import annotations

import contextlib
import itertools
import os
from typing import IO, Iterator, Union

import numpy as np

from . import _native
from ._checks import real
from .exceptions import InvalidArgumentError
from .models import Hsh, Ptm, load

__all__ = ["load_ptm", "load_rti", "save_image", "load_image", "load", "atomic_write", "save_array", "save_text"]

PathLike = Union[str, os.PathLike]

_counter = itertools.count()


@contextlib.contextmanager
def atomic_write(path: PathLike, mode: str = "wb") -> Iterator[IO]:
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
    # The same naming as btfrs-io: hidden, per process and call, never truncating another file.
    for _ in range(100):
        tmp = os.path.join(directory, f".{name}.{os.getpid()}.{next(_counter)}.tmp")
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


def save_array(path: PathLike, array) -> None:
    """``numpy.save`` to ``path`` (a ``.npy`` file; the name is kept as given), atomically."""
    a = np.asanyarray(array)
    with atomic_write(path) as f:
        np.save(f, a, allow_pickle=False)


def save_text(path: PathLike, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path``, atomically."""
    with atomic_write(path, "w") as f:
        f.write(text)


def load_ptm(path: PathLike) -> Ptm:
    """Read an uncompressed ``PTM_1.2`` (or 1.1) RGB or LRGB file, ours or another tool's, as a
    one-slot :class:`~btfrs.Ptm` (view = the normal). Values are in units where the viewer's
    white (byte 255) is 1.0. Compressed (JPEG) and LUM variants raise
    :class:`~btfrs.exceptions.FormatError`."""
    return Ptm(_native.read_ptm(os.fspath(path)))


def load_rti(path: PathLike) -> Hsh:
    """Read a ``.rti`` hemispherical-harmonics file (``#HSH1.2``, RTI type 3, 8-bit data, orders 1
    to 4) as a one-slot :class:`~btfrs.Hsh` (view = the normal), its 8-bit planes the file's
    bytes. The two float arrays are read as relight reads them (byte ``c`` of term ``j`` is
    ``bias[j] + scale[j] * c / 255``). Other RTI types raise :class:`~btfrs.exceptions.FormatError`
    naming the type."""
    return Hsh(_native.read_rti(os.fspath(path)))


def save_image(path: PathLike, image, *, exposure: float = 1.0) -> None:
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


def load_image(path: PathLike) -> np.ndarray:
    """Read an ``[H, W, 3]`` float32 linear image from an 8-bit PNG or an OpenEXR file."""
    p = os.fspath(path)
    if os.path.splitext(p)[1].lower() == ".exr":
        return _native.read_exr(p)
    return _native.read_png(p)
