"""What every ``btfrs.fit.<kind>`` function does: send the options to the registry's fit.

The per-model functions in :mod:`btfrs.fit` are generated from the model registry; this module
is the hand-written part they share. The options cross into Rust as they are (a dict of Python
values, each converted once by the binding) and are checked once, there, against the model's
schema (``btfrs_fit::options``): an unknown name, a wrong type, a value out of range or not among
the choices raises :class:`~btfrs.exceptions.InvalidArgumentError` naming the option as the
caller spelled it (``lambda_``), with its ``argument``, ``value`` and ``allowed`` set.
"""

from __future__ import annotations

import time
from typing import Any, Dict, Mapping, Union, cast

import numpy as np

from . import _native
from ._checks import instance, memory_size
from ._progress import Progress, callback
from .btf import Btf
from .exceptions import InvalidArgumentError
from .models import Model, model_kinds, wrap

__all__ = ["MemoryLimit", "fit", "fit_kind", "native_options"]

MemoryLimit = Union[None, int, str]

# The options every fit takes besides its own, with their defaults, from their Rust schema.
ROBUST_DEFAULTS: Dict[str, bool] = {o["name"]: bool(o["default"]) for o in _native.fit_options()}


def native_options(options: Mapping[str, Any], memory_limit: MemoryLimit = None) -> Dict[str, Any]:
    """The options of a fit as the binding takes them: the caller's names and values as they
    are (the binding converts each value once, reads ``lambda_`` as the schema's ``lambda`` and
    names it ``lambda_`` in errors), with the memory limit in bytes."""
    o = dict(options)
    limit = memory_size("memory_limit", memory_limit)
    if limit is not None:
        o["memory_limit"] = limit
    return o


def fit_kind(kind: str, btf: Btf, options: Mapping[str, Any], memory_limit: MemoryLimit = None,
             progress: Progress = None, robust: bool = ROBUST_DEFAULTS["robust"],
             exclude_bad_images: bool = ROBUST_DEFAULTS["exclude_bad_images"]) -> Model:
    """Fit the registered model ``kind`` to the present pairs of ``btf`` (``robust`` and
    ``exclude_bad_images``: see :func:`btfrs.fit.fit`)."""
    b = instance("btf", btf, Btf, "a btfrs.Btf")
    if kind not in model_kinds():
        raise InvalidArgumentError(f"model: unknown model {kind!r}; expected one of {', '.join(model_kinds())}")
    o = native_options(options, memory_limit)
    known = cast("_native._ModelKind", kind)  # checked against the registry above
    t0 = time.perf_counter()
    m = _native.fit_model(known, b.data, b.views, b.lights, b.mask, o, callback(progress, f"{kind} fit"),
                          flag("robust", robust), flag("exclude_bad_images", exclude_bad_images))
    b._check_unchanged(f"{kind} fit")
    return wrap(m, fit_seconds=time.perf_counter() - t0)


def fit(model: str, btf: Btf, /, *, progress: Progress = None, memory_limit: MemoryLimit = None,
        robust: bool = ROBUST_DEFAULTS["robust"], exclude_bad_images: bool = ROBUST_DEFAULTS["exclude_bad_images"],
        **options: Any) -> Model:
    """Fit the registered model ``model`` (a name of :func:`btfrs.model_kinds`) to the present
    pairs of ``btf`` with its own ``options`` (those of ``btfrs.fit.<model>``).

    ``robust`` (the default) screens the values for outliers first: hot pixels, dust, glints,
    each far above both its light neighbours' and its spatial neighbours' median, are replaced
    by the light neighbours' median before the model's own fit runs (``robust=False``: every
    value as measured); ``model.report["robust"]`` says how many and where, and lists the whole
    images far from their neighbours (a misfired or doubled flash), which
    ``exclude_bad_images=True`` leaves out of the fit."""
    return fit_kind(model, btf, options, memory_limit, progress, robust, exclude_bad_images)


def flag(name: str, value: object) -> bool:
    """A boolean argument, checked."""
    if not isinstance(value, (bool, np.bool_)):
        raise InvalidArgumentError(f"{name}: expected True or False, got {value!r}", name, value, "True or False")
    return bool(value)
