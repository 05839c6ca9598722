"""btfrs: fit, synthesize and render Bidirectional Texture Functions, with a Rust core.

>>> import btfrs
>>> btf = btfrs.materials.make("knit", size=64, seed=1)
>>> train, test = btf.split(holdout=0.1, seed=0)
>>> ptm = btfrs.fit.ptm(train, kind="rgb")
>>> print(ptm.error(test), ptm.nbytes)
"""

from __future__ import annotations

import atexit
import importlib
import os
import shutil
import sys
import tempfile
import types

from . import (calibration, directions, evaluation, exceptions, fit, graphcut, hemimap, io, materials, photometric,
               stability, synth, tiles, web)
from ._native import __version__
from .btf import Btf, ExpandedBtf
from .exceptions import (
    ArgumentTypeError,
    BtfrsError,
    ClusterError,
    DegenerateDataError,
    DeviceError,
    FormatError,
    InternalError,
    InvalidArgumentError,
    NumericalError,
    OutOfRangeError,
)
from .models import (Bilinear, ErrorReport, Hsh, Lafortune, LafortuneView, Lpca, Model, Neural, Ptm, Rbf, Sh, Srf,
                     Svbrdf, model_kinds)
from .io import load
from .photometric import NormalMaps, height, normals
from .calibration import Calibration, calibrate
from .evaluation import EvaluationReport, evaluate
from .environment import Environment
from .rendering import Camera, DirectionalLight, PointLight, Scene, gpu_info, last_timings, render
# The module is `choosing`, not `choose`, so that `btfrs.choose` is the function, never shadowed
# by its submodule (importing a submodule sets the package attribute of its name).
from .choosing import Choice, SceneUse, choose


def _ensure_runtime_dir() -> None:
    """Give this process a private ``XDG_RUNTIME_DIR`` when it has none.

    Opening a Vulkan device (the GPU renderer, lavapipe included) makes Mesa probe for a Wayland
    display, and libwayland prints ``error: XDG_RUNTIME_DIR is invalid or not set in the
    environment.`` to stderr on every probe when the variable is unset or empty: the normal case
    on headless machines, in containers and in CI. An existing directory is left alone. The
    directory made here is empty, mode 0700, and removed when this process exits (not when a
    forked child does: the parent still uses it).
    """
    if os.name != "posix" or sys.platform == "darwin":
        return
    current = os.environ.get("XDG_RUNTIME_DIR")
    if current and os.path.isdir(current):
        return
    try:
        path = tempfile.mkdtemp(prefix="btfrs-runtime-")
    except OSError:
        return  # only a warning on stderr is at stake
    owner = os.getpid()
    os.environ["XDG_RUNTIME_DIR"] = path

    def _remove() -> None:
        if os.getpid() == owner:
            shutil.rmtree(path, ignore_errors=True)

    atexit.register(_remove)


_ensure_runtime_dir()

__all__ = [
    "Environment",
    "__version__",
    "Btf",
    "ExpandedBtf",
    "Model",
    "model_kinds",
    "Ptm",
    "Hsh",
    "Lafortune",
    "LafortuneView",
    "Srf",
    "Sh",
    "Lpca",
    "Rbf",
    "Bilinear",
    "Neural",
    "Svbrdf",
    "ErrorReport",
    "load",
    "render",
    "gpu_info",
    "last_timings",
    "Scene",
    "Camera",
    "PointLight",
    "DirectionalLight",
    "choose",
    "Choice",
    "SceneUse",
    "directions",
    "evaluate",
    "tiles",
    "web",
    "evaluation",
    "EvaluationReport",
    "exceptions",
    "fit",
    "graphcut",
    "hemimap",
    "io",
    "materials",
    "photometric",
    "normals",
    "height",
    "NormalMaps",
    "calibration",
    "calibrate",
    "Calibration",
    "stability",
    "synth",
    "BtfrsError",
    "ClusterError",
    "DegenerateDataError",
    "DeviceError",
    "FormatError",
    "InternalError",
    "InvalidArgumentError",
    "NumericalError",
    "ArgumentTypeError",
    "OutOfRangeError",
]


def __getattr__(name: str) -> types.ModuleType:
    # btfrs.dask needs the optional extra (dask, distributed, zarr): imported on first use, so
    # `import btfrs` works without it and `btfrs.dask.open(...)` works with it.
    if name == "dask":
        return importlib.import_module(".dask", __name__)
    raise AttributeError(f"module 'btfrs' has no attribute {name!r}")
