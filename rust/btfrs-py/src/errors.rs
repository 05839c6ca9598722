//! Mapping of btfrs errors onto Python exceptions.
//!
//! The exception classes live in `python/btfrs/exceptions.py`, so they can inherit from both
//! `BtfrsError` and the matching builtin (`ValueError`, ...); this module imports them.

use btfrs_core::Error;
use pyo3::exceptions::{PyFileNotFoundError, PyKeyboardInterrupt, PyOSError};
use pyo3::PyErr;

pyo3::import_exception!(btfrs.exceptions, InvalidArgumentError);
pyo3::import_exception!(btfrs.exceptions, ArgumentTypeError);
pyo3::import_exception!(btfrs.exceptions, DegenerateDataError);
pyo3::import_exception!(btfrs.exceptions, FormatError);
pyo3::import_exception!(btfrs.exceptions, InternalError);
pyo3::import_exception!(btfrs.exceptions, DeviceError);
pyo3::import_exception!(btfrs.exceptions, NumericalError);

/// Convert a btfrs error into the Python exception a user should see.
pub fn to_py(e: Error) -> PyErr {
    let msg = e.to_string();
    match e {
        Error::InvalidArgument { .. } => InvalidArgumentError::new_err(msg),
        Error::ArgumentType { .. } => ArgumentTypeError::new_err(msg),
        Error::Degenerate(_) => DegenerateDataError::new_err(msg),
        Error::Numerical(_) => NumericalError::new_err(msg),
        Error::Format { .. } => FormatError::new_err(msg),
        Error::Io { source, .. } if source.kind() == std::io::ErrorKind::NotFound => PyFileNotFoundError::new_err(msg),
        Error::Io { .. } => PyOSError::new_err(msg),
        Error::Device(_) => DeviceError::new_err(msg),
        Error::Interrupted => PyKeyboardInterrupt::new_err("interrupted"),
    }
}

/// `?`-friendly conversion.
pub trait IntoPy<T> {
    /// Map the error side to a Python exception.
    fn py(self) -> pyo3::PyResult<T>;
}

impl<T> IntoPy<T> for btfrs_core::Result<T> {
    fn py(self) -> pyo3::PyResult<T> {
        self.map_err(to_py)
    }
}

/// An `ArgumentTypeError` (a btfrs `TypeError`) naming the argument: a wrong type was passed.
pub fn arg_type(name: &str, msg: impl std::fmt::Display) -> PyErr {
    ArgumentTypeError::new_err(format!("{name}: {msg}"))
}

/// An `InvalidArgumentError` naming the argument.
pub fn arg(name: &str, msg: impl std::fmt::Display) -> PyErr {
    InvalidArgumentError::new_err(format!("{name}: {msg}"))
}

/// A Rust panic turned into `InternalError` (it must never cross into Python as a panic).
pub fn panic_to_py(payload: Box<dyn std::any::Any + Send>) -> PyErr {
    let what = payload
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "unknown panic".into());
    InternalError::new_err(format!("internal error in btfrs (please report it): {what}"))
}
