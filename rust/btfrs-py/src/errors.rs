//! Mapping of btfrs errors onto Python exceptions.
//!
//! The exception classes live in `python/btfrs/exceptions.py`, so they can inherit from both
//! `BtfrsError` and the matching builtin (`ValueError`, ...); this module imports them. An
//! argument error is raised with its fields as well as its message: the exception's `argument`
//! (the name), `value` (the value given, as a Python object) and `allowed` (what is allowed, in
//! words) are set here from the Rust error's own fields ([`btfrs_core::Detail`]), so Python never
//! reads them back out of the message.

use btfrs_core::Error;
use pyo3::exceptions::{PyFileNotFoundError, PyKeyboardInterrupt, PyOSError};
use pyo3::prelude::*;
use pyo3::types::PyTuple;
use pyo3::PyErr;

pyo3::import_exception!(btfrs.exceptions, InvalidArgumentError);
pyo3::import_exception!(btfrs.exceptions, ArgumentTypeError);
pyo3::import_exception!(btfrs.exceptions, DegenerateDataError);
pyo3::import_exception!(btfrs.exceptions, FormatError);
pyo3::import_exception!(btfrs.exceptions, InternalError);
pyo3::import_exception!(btfrs.exceptions, DeviceError);
pyo3::import_exception!(btfrs.exceptions, NumericalError);

/// The constructor arguments of an argument error: `(message, argument, value, allowed)`, the
/// value converted to Python when the exception is made.
#[derive(Debug)]
pub struct ArgumentFields {
    /// The whole message (`"lobes: expected an integer from 1 to 7, got 9"`).
    pub message: String,
    /// The argument's name.
    pub argument: String,
    /// The value given, where known.
    pub value: Option<serde_json::Value>,
    /// What is allowed, where known.
    pub allowed: Option<String>,
}

impl<'py> IntoPyObject<'py> for ArgumentFields {
    type Target = PyTuple;
    type Output = Bound<'py, PyTuple>;
    type Error = PyErr;

    fn into_pyobject(self, py: Python<'py>) -> PyResult<Bound<'py, PyTuple>> {
        let value = match &self.value {
            Some(v) => crate::values::to_py(py, v)?,
            None => py.None().into_bound(py),
        };
        PyTuple::new(
            py,
            [
                self.message.into_pyobject(py)?.into_any(),
                self.argument.into_pyobject(py)?.into_any(),
                value,
                self.allowed.into_pyobject(py)?.into_any(),
            ],
        )
    }
}

/// Convert a btfrs error into the Python exception a user should see.
pub fn to_py(e: Error) -> PyErr {
    let msg = e.to_string();
    let fields = |name: String, detail: Option<Box<btfrs_core::Detail>>| {
        let (value, allowed) = detail.map_or((None, None), |d| (Some(d.value), Some(d.allowed)));
        ArgumentFields { message: msg.clone(), argument: name, value, allowed }
    };
    match e {
        Error::InvalidArgument { name, detail, .. } => InvalidArgumentError::new_err(fields(name, detail)),
        Error::ArgumentType { name, detail, .. } => ArgumentTypeError::new_err(fields(name, detail)),
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

/// The fields of an error naming `name` with no value or allowed values known.
fn named(name: &str, msg: impl std::fmt::Display) -> ArgumentFields {
    ArgumentFields { message: format!("{name}: {msg}"), argument: name.to_string(), value: None, allowed: None }
}

/// An `ArgumentTypeError` (a btfrs `TypeError`) naming the argument: a wrong type was passed.
pub fn arg_type(name: &str, msg: impl std::fmt::Display) -> PyErr {
    ArgumentTypeError::new_err(named(name, msg))
}

/// An `InvalidArgumentError` naming the argument.
pub fn arg(name: &str, msg: impl std::fmt::Display) -> PyErr {
    InvalidArgumentError::new_err(named(name, msg))
}

/// An `InvalidArgumentError` naming the argument, with the value given (a Python object) and
/// what is allowed.
pub fn arg_value(name: &str, value: &Bound<'_, PyAny>, allowed: &str) -> PyErr {
    let shown = value.repr().map_or_else(|_| "?".to_string(), |r| r.to_string());
    InvalidArgumentError::new_err((
        format!("{name}: expected {allowed}, got {shown}"),
        name.to_string(),
        value.clone().unbind(),
        allowed.to_string(),
    ))
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
