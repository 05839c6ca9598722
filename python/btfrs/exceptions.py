"""The exception hierarchy of btfrs.

Every error btfrs raises on purpose is a :class:`BtfrsError`; each subclass also derives from the
builtin a caller would catch anyway (``ValueError`` for bad arguments and unusable data), so
``except ValueError`` keeps working. Missing files raise the builtin ``FileNotFoundError``, Ctrl-C
raises ``KeyboardInterrupt``.
"""

from __future__ import annotations

__all__ = [
    "BtfrsError",
    "InvalidArgumentError",
    "DegenerateDataError",
    "FormatError",
    "InternalError",
    "DeviceError",
]


class BtfrsError(Exception):
    """Base class of every btfrs error."""


class InvalidArgumentError(BtfrsError, ValueError):
    """An argument has the wrong shape, range or value; the message names it."""


class DegenerateDataError(BtfrsError, ValueError):
    """The data cannot support the requested fit (too few or degenerate directions, ...)."""


class FormatError(BtfrsError, ValueError):
    """A file is not what it claims to be (bad header, truncated, unsupported variant)."""


class DeviceError(BtfrsError, RuntimeError):
    """No graphics adapter could be used, or the GPU device failed; the message says what to install."""


class InternalError(BtfrsError, RuntimeError):
    """A bug in btfrs (a Rust panic caught at the boundary); please report it."""
