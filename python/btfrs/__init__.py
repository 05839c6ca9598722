"""btfrs: fit, synthesize and render Bidirectional Texture Functions, with a Rust core.

>>> import btfrs
>>> btf = btfrs.materials.make("knit", size=64, seed=1)
>>> train, test = btf.split(holdout=0.1, seed=0)
>>> ptm = btfrs.fit.ptm(train, kind="rgb")
>>> print(ptm.error(test), ptm.nbytes)
"""

from __future__ import annotations

from . import directions, exceptions, fit, hemimap, io, materials, synth
from ._native import __version__
from .btf import Btf, ExpandedBtf
from .exceptions import (
    ArgumentTypeError,
    BtfrsError,
    DegenerateDataError,
    DeviceError,
    FormatError,
    InternalError,
    InvalidArgumentError,
    OutOfRangeError,
)
from .models import ErrorReport, Lafortune, Lpca, Model, Ptm, Sh, Srf, load, model_kinds
from .rendering import Camera, DirectionalLight, PointLight, Scene, gpu_info, last_timings, render

__all__ = [
    "__version__",
    "Btf",
    "ExpandedBtf",
    "Model",
    "model_kinds",
    "Ptm",
    "Lafortune",
    "Srf",
    "Sh",
    "Lpca",
    "ErrorReport",
    "load",
    "render",
    "gpu_info",
    "last_timings",
    "Scene",
    "Camera",
    "PointLight",
    "DirectionalLight",
    "directions",
    "exceptions",
    "fit",
    "hemimap",
    "io",
    "materials",
    "synth",
    "BtfrsError",
    "DegenerateDataError",
    "DeviceError",
    "FormatError",
    "InternalError",
    "InvalidArgumentError",
    "ArgumentTypeError",
    "OutOfRangeError",
]
