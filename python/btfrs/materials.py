"""Built-in procedural materials: BTFs generated in Rust from periodic heightfields.

Each preset has a periodic heightfield (the sample tiles seamlessly), per-texel albedo and a
glossy Blinn-Phong lobe; masking, parallax and cast shadows come from marching the heightfield,
so the BTF has the hard shadows and occlusions of a measured one. Deterministic per ``seed``.

=========  =================================================================================
knit       stocking stitch: V-shaped yarn loops with fibre ridges, deep gaps, hard shadows
weave      plain weave of blue warp and beige weft going over and under, silky sheen
bumps      glossy pebbles on a matte ground, round cast shadows
grooves    brushed metal grooves along y: anisotropic and shiny
=========  =================================================================================

:func:`texture` makes photograph-like structured RGB textures (``"bricks"``), seeded and, by
default, cropped off their period like a photograph: plain tiling shows seams, which is what
synthesis is for, and what :func:`btfrs.synth.quality` must see.
"""

from __future__ import annotations

import os
from typing import Any, Dict, NamedTuple, Optional, Sequence, Union

import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import _native
from ._checks import PathLike, integer, real, size_hw
from ._checks import seed as check_seed
from ._progress import Progress, callback
from .btf import Btf
from .directions import ubo81
from .exceptions import ArgumentTypeError

__all__ = ["Heightfield", "heightfield", "make", "names", "texture", "texture_names"]


def names() -> list[str]:
    """The names of the built-in materials."""
    return list(_native.material_names())


def make(name: str = "knit", *, size: int = 64, seed: int = 0, views: Optional[ArrayLike] = None,
         lights: Optional[ArrayLike] = None, relief: float = 1.0, subsurface: float = 0.0,
         out: Optional[PathLike] = None, progress: Progress = None) -> Btf:
    """Generate a built-in material.

    Parameters
    ----------
    name: one of :func:`names`.
    size: texels per side (16 to 256 is the intended range; 8 to 1024 are accepted).
    seed: seed of the per-cell variation and the noise.
    views, lights: ``[N, 3]`` unit directions (default: the 81 UBO directions each).
    relief: multiplier of the preset's height, in [0, 4] (0 gives a flat, shadowless surface).
    subsurface: in [0, 1), mixes each texel's values with its neighbours' (a soft blur).
    out: None (the default) makes the BTF in memory (at most 8 GiB of values). A path
        (``"big.btfrs"``) writes it straight into that file instead, row by row into the
        memory-mapped file, with no size limit and without holding the values in memory (the
        generation keeps the surface, its visibility maps, ``V + L`` values per texel, and three
        texel rows), atomically (an error or Ctrl-C leaves nothing), and returns it opened with
        ``Btf.load(out, mmap=True)``: the same values as in memory, for a BTF larger than RAM.
    progress: None, True for a progress bar, or a callable ``(done, total)``.
    """
    if not isinstance(name, str):
        raise ArgumentTypeError(f"name: expected a material name (one of {', '.join(names())}), got {type(name).__name__}")
    size = integer("size", size, min=8, max=1024)
    seed = check_seed(seed)
    relief = real("relief", relief, min=0.0, max=4.0)
    subsurface = real("subsurface", subsurface, min=0.0, max=1.0, max_open=True)
    v = ubo81() if views is None else np.ascontiguousarray(views, dtype=np.float64)
    l = ubo81() if lights is None else np.ascontiguousarray(lights, dtype=np.float64)
    if out is not None:
        if not isinstance(out, (str, os.PathLike)):
            raise ArgumentTypeError(f"out: expected a file path (str or os.PathLike), got {type(out).__name__}")
        _native.make_material(name, size, v, l, seed, relief, subsurface, os.fspath(out),
                              callback(progress, f"material {name}"))
        return Btf.load(out, mmap=True)
    data = _native.make_material(name, size, v, l, seed, relief, subsurface, None,
                                 callback(progress, f"material {name}"))
    return Btf(data, v, l, check=False, meta=_meta(name, size, seed, relief, subsurface))


class Heightfield(NamedTuple):
    """A built-in material's surface (see :func:`heightfield`), row 0 at the top of the image."""

    #: ``[size, size]`` float32 heights, in texel widths.
    height: NDArray[np.float32]
    #: ``[size, size, 3]`` float32 unit normals (x right, y up the image, z out of the surface).
    normals: NDArray[np.float32]
    #: ``[size, size, 3]`` float32 diffuse albedo.
    albedo: NDArray[np.float32]


def heightfield(name: str = "knit", *, size: int = 64, seed: int = 0, relief: float = 1.0) -> Heightfield:
    """The true surface of the material :func:`make` generates with the same ``name``, ``size``,
    ``seed`` and ``relief``: the heights, the normals its shading uses at texel centres (central
    differences of the periodic heights) and the diffuse albedo. The ground truth for
    :func:`btfrs.normals` and :func:`btfrs.height`."""
    if not isinstance(name, str):
        raise ArgumentTypeError(f"name: expected a material name (one of {', '.join(names())}), got {type(name).__name__}")
    size = integer("size", size, min=8, max=1024)
    seed = check_seed(seed)
    relief = real("relief", relief, min=0.0, max=4.0)
    return Heightfield(*_native.material_heightfield(name, size, seed, relief))


def _meta(name: str, size: int, seed: int, relief: float, subsurface: float) -> Dict[str, Any]:
    """What a built-in material's :attr:`Btf.meta` says: how it was made, and that its values
    follow btfrs's convention by construction."""
    return {"format": "btfrs material", "material": name, "size": size, "seed": seed, "relief": relief,
            "subsurface": subsurface,
            "values": {"convention": "linear RGB, cosine of the light's polar angle included, colour scale applied",
                       "cosine": "in the data (rendered with it)", "scale_applied": [1.0, 1.0, 1.0],
                       "transfer": "linear, as rendered"}}


def texture_names() -> list[str]:
    """The names of the structured RGB textures of :func:`texture`."""
    return list(_native.texture_names())


def texture(name: str = "bricks", *, size: Union[int, Sequence[int]] = 128, seed: int = 0,
            period: Sequence[int] = (4, 2)) -> NDArray[np.float32]:
    """A photograph-like structured RGB texture, ``[H, W, 3]`` float32 in [0, 1].

    ``"bricks"``: running-bond brickwork, bricks of 38 x 17 pixels with 3-pixel light mortar
    joints, a colour per brick, darker top-left brick edges, smooth shading and per-pixel noise.

    ``size`` is ``(height, width)`` or one int. The pattern, colours and noise included, repeats
    exactly every ``period = (brick rows, bricks per row)`` (rows even), i.e. every
    ``17 * rows`` rows and ``38 * bricks`` columns (68 x 76 pixels by default); the image is a
    crop of it at an offset drawn from ``seed``. A size that is not a multiple of the period does
    not tile (plain tiling breaks the mortar lines at every tile boundary), while the map
    ``(x mod 76, y mod 68)`` tiles it seamlessly.
    """
    if not isinstance(name, str):
        raise ArgumentTypeError(f"name: expected a texture name (one of {', '.join(texture_names())}), "
                                f"got {type(name).__name__}")
    h, w = size_hw("size", size)
    if isinstance(period, (str, bytes)) or not hasattr(period, "__len__") or len(period) != 2:
        raise ArgumentTypeError(f"period: expected (brick rows, bricks per row), got {period!r}")
    period = (integer("period[0]", period[0], min=2), integer("period[1]", period[1], min=1))
    return _native.make_texture(name, h, w, check_seed(seed), period)
