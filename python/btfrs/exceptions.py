"""The exception hierarchy of btfrs.

Every error btfrs raises on purpose is a :class:`BtfrsError`; each subclass also derives from the
builtin a caller would catch anyway, so ``except ValueError`` (or ``TypeError``, ``IndexError``)
keeps working:

========================  ===========================  ==============================================
class                     also a                       raised when
========================  ===========================  ==============================================
``InvalidArgumentError``  ``ValueError``               an argument has the wrong shape, range or value
``ArgumentTypeError``     ``InvalidArgumentError``,    an argument has the wrong type (a float or a
                          ``TypeError``                bool for an integer, a list for a Btf, ...)
``OutOfRangeError``       ``InvalidArgumentError``,    an index is outside its axis (negative indices
                          ``IndexError``               do not wrap)
``DegenerateDataError``   ``ValueError``               the data cannot support the requested fit
``FormatError``           ``ValueError``               a file is not what it claims to be
``NumericalError``        ``ArithmeticError``          a computation gave non-finite values (a model
                                                       whose stored values overflow when evaluated)
``DeviceError``           ``RuntimeError``             no usable graphics adapter, or the GPU failed
``ClusterError``          ``RuntimeError``             the Dask cluster of a :mod:`btfrs.dask` fit failed
                                                       (a worker died, the scheduler went away)
``InternalError``         ``RuntimeError``             a bug in btfrs (a Rust panic caught at the
                                                       boundary)
========================  ===========================  ==============================================

Every message starts with the argument's name and says what was expected. An
:class:`InvalidArgumentError` (and so an ``ArgumentTypeError``) also carries its fields apart:
``argument`` (the name, as the caller spelled it), ``value`` (the value given) and ``allowed`` (what
is allowed, in words), each ``None`` where the check does not know it::

    try:
        btfrs.fit.lafortune(btf, lobes=9)
    except btfrs.exceptions.InvalidArgumentError as e:
        print(e.argument, e.value, e.allowed)  # lobes 9 an integer from 1 to 7

Missing files raise the builtin ``FileNotFoundError``, other I/O failures ``OSError``, Ctrl-C
``KeyboardInterrupt``.
"""

from __future__ import annotations

from typing import Any, Optional, Tuple

__all__ = [
    "BtfrsError",
    "InvalidArgumentError",
    "ArgumentTypeError",
    "OutOfRangeError",
    "DegenerateDataError",
    "FormatError",
    "NumericalError",
    "InternalError",
    "DeviceError",
    "ClusterError",
]


class BtfrsError(Exception):
    """Base class of every btfrs error."""


class InvalidArgumentError(BtfrsError, ValueError):
    """An argument has the wrong shape, range or value; the message names it, and the fields
    ``argument``, ``value`` and ``allowed`` hold the name, the value given and what is allowed
    where they are known (else ``None``)."""

    def __init__(self, message: str = "", argument: Optional[str] = None, value: Any = None,
                 allowed: Optional[str] = None) -> None:
        super().__init__(message)
        self.argument = argument
        self.value = value
        self.allowed = allowed

    def __reduce__(self) -> Tuple[Any, ...]:
        # Pickled with its fields (a Dask worker's error reaches the client whole).
        return (type(self), (str(self), self.argument, self.value, self.allowed))


class ArgumentTypeError(InvalidArgumentError, TypeError):
    """An argument has the wrong type (also a ``TypeError``); the message names it."""


class OutOfRangeError(InvalidArgumentError, IndexError):
    """An index argument is outside its axis (also an ``IndexError``); the message names it and
    gives the valid range. Negative indices are rejected, not wrapped."""


class DegenerateDataError(BtfrsError, ValueError):
    """The data cannot support the requested fit (too few or degenerate directions, ...)."""


class FormatError(BtfrsError, ValueError):
    """A file is not what it claims to be (bad header, truncated, unsupported variant)."""


class NumericalError(BtfrsError, ArithmeticError):
    """A computation gave non-finite values: a model's stored values (finite, but huge: a file of
    unknown origin) overflow when it is evaluated or rendered. The message names the model and its
    array with the largest value."""


class DeviceError(BtfrsError, RuntimeError):
    """No graphics adapter could be used, or the GPU device failed; the message says what to install."""


class ClusterError(BtfrsError, RuntimeError):
    """The Dask cluster of a :mod:`btfrs.dask` call failed (a worker died, the scheduler went
    away); nothing was written, and the call can be rerun once the cluster is healthy."""


class InternalError(BtfrsError, RuntimeError):
    """A bug in btfrs (a Rust panic caught at the boundary); please report it."""
