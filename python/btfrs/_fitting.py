"""What every ``btfrs.fit.<kind>`` function does: send the options to the registry's fit.

The per-model functions in :mod:`btfrs.fit` are generated from the model registry; this module
is the hand-written part they share. Options are checked once, in Rust, against the model's
schema (``btfrs_fit::options``): an unknown name, a wrong type, a value out of range or not among
the choices raises :class:`~btfrs.exceptions.InvalidArgumentError` naming the option, the value
and what is allowed.
"""

from __future__ import annotations

import json
import keyword
import time
from typing import Any, Dict, Mapping, Union, cast

import numpy as np

from . import _native
from ._checks import instance, memory_size
from ._progress import Progress, callback
from .btf import Btf
from .exceptions import InvalidArgumentError
from .models import Model, model_kinds, wrap

__all__ = ["MemoryLimit", "fit", "fit_kind", "options_json"]

MemoryLimit = Union[None, int, str]

# The options every fit takes besides its own, with their defaults, from their Rust schema.
ROBUST_DEFAULTS: Dict[str, bool] = {o["name"]: bool(o["default"]) for o in json.loads(_native.fit_options())}


def _plain(name: str, v: Any) -> Any:
    """A JSON value of an option: numpy scalars become Python numbers; NaN and infinities are
    refused here, since JSON has no spelling for them."""
    if isinstance(v, np.bool_):
        return bool(v)
    if isinstance(v, np.integer):
        return int(v)
    if isinstance(v, (float, np.floating)):
        f = float(v)
        if not np.isfinite(f):
            raise InvalidArgumentError(f"{name}: expected a finite number, got {f}")
        return f
    return v


def options_json(kind: str, options: Mapping[str, Any], memory_limit: MemoryLimit = None) -> str:
    """The options of a ``kind`` fit as the JSON object its registry entry reads (the names as
    the schema spells them: ``lambda_`` is ``lambda``)."""
    o = {k[:-1] if k.endswith("_") else k: _plain(k, v) for k, v in options.items()}
    limit = memory_size("memory_limit", memory_limit)
    if limit is not None:
        o["memory_limit"] = limit
    try:
        return json.dumps(o)
    except TypeError as e:
        raise InvalidArgumentError(f"options: expected numbers, strings and booleans ({e})") from None


def fit_kind(kind: str, btf: Btf, options: Mapping[str, Any], memory_limit: MemoryLimit = None,
             progress: Progress = None, robust: bool = ROBUST_DEFAULTS["robust"],
             exclude_bad_images: bool = ROBUST_DEFAULTS["exclude_bad_images"]) -> Model:
    """Fit the registered model ``kind`` to the present pairs of ``btf`` (``robust`` and
    ``exclude_bad_images``: see :func:`btfrs.fit.fit`)."""
    b = instance("btf", btf, Btf, "a btfrs.Btf")
    if kind not in model_kinds():
        raise InvalidArgumentError(f"model: unknown model {kind!r}; expected one of {', '.join(model_kinds())}")
    o = options_json(kind, options, memory_limit)
    known = cast("_native._ModelKind", kind)  # checked against the registry above
    t0 = time.perf_counter()
    try:
        m = _native.fit_model(known, b.data, b.views, b.lights, b.mask, o, callback(progress, f"{kind} fit"),
                              flag("robust", robust), flag("exclude_bad_images", exclude_bad_images))
    except InvalidArgumentError as e:
        # The schema spells an option that is a Python keyword without its "_" (lambda_).
        msg = str(e)
        name = msg.split(":", 1)[0]
        if keyword.iskeyword(name):
            raise type(e)(f"{name}_:{msg.split(':', 1)[1]}") from None
        raise
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
        raise InvalidArgumentError(f"{name}: expected True or False, got {value!r}")
    return bool(value)
