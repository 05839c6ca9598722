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
"""

from __future__ import annotations


import numpy as np

from . import _native
from ._checks import integer, real
from ._checks import seed as check_seed
from ._progress import Progress, callback
from .btf import Btf
from .directions import ubo81
from .exceptions import ArgumentTypeError

__all__ = ["make", "names"]


def names() -> list[str]:
    """The names of the built-in materials."""
    return list(_native.material_names())


def make(name: str = "knit", *, size: int = 64, seed: int = 0, views=None, lights=None,
         relief: float = 1.0, subsurface: float = 0.0, progress: Progress = None) -> Btf:
    """Generate a built-in material.

    Parameters
    ----------
    name: one of :func:`names`.
    size: texels per side (16 to 256 is the intended range; 8 to 1024 are accepted).
    seed: seed of the per-cell variation and the noise.
    views, lights: ``[N, 3]`` unit directions (default: the 81 UBO directions each).
    relief: multiplier of the preset's height, in [0, 4] (0 gives a flat, shadowless surface).
    subsurface: in [0, 1), mixes each texel's values with its neighbours' (a soft blur).
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
    data = _native.make_material(name, size, v, l, seed, relief, subsurface,
                                 callback(progress, f"material {name}"))
    return Btf(data, v, l, check=False)
