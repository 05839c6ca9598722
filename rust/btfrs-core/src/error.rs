//! The one error type of btfrs.
//!
//! Every fallible function in the plain Rust crates returns [`Result`]. The PyO3 crate maps each
//! variant onto a Python exception class (see `python/btfrs/exceptions.py`), so the variant says
//! *what kind* of failure it is and the message says *which argument* and *what was expected*.

use std::fmt;

/// What went wrong, with enough words for a user to fix it.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// An argument has the wrong shape, range or value. `name` is the argument as the user wrote it.
    #[error("{name}: {msg}")]
    InvalidArgument { name: String, msg: String },
    /// An argument has the wrong type (a float where an integer is expected, ...): in Python a
    /// `btfrs.exceptions.ArgumentTypeError`, which is also an `InvalidArgumentError`.
    #[error("{name}: {msg}")]
    ArgumentType { name: String, msg: String },
    /// The data make the requested fit impossible (too few or degenerate directions, ...).
    #[error("{0}")]
    Degenerate(String),
    /// A computation gave non-finite values (a model whose stored values overflow when
    /// evaluated, say): names what and why.
    #[error("{0}")]
    Numerical(String),
    /// A file exists but is not what it claims to be.
    #[error("{path}: {msg}")]
    Format { path: String, msg: String },
    /// An operating-system I/O error, with the path it concerned.
    #[error("{path}: {source}")]
    Io { path: String, source: std::io::Error },
    /// No usable graphics adapter, or the GPU device failed (out of memory, lost, invalid use).
    #[error("{0}")]
    Device(String),
    /// Long work was cancelled (Ctrl-C in Python, or a progress callback asked to stop).
    #[error("interrupted")]
    Interrupted,
}

/// `Result` with btfrs's [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    /// An [`Error::InvalidArgument`] naming the argument.
    pub fn arg(name: impl Into<String>, msg: impl fmt::Display) -> Self {
        Error::InvalidArgument { name: name.into(), msg: msg.to_string() }
    }

    /// An [`Error::Format`] naming the file.
    pub fn format(path: impl fmt::Display, msg: impl fmt::Display) -> Self {
        Error::Format { path: path.to_string(), msg: msg.to_string() }
    }

    /// An [`Error::Io`] naming the file.
    pub fn io(path: impl fmt::Display, source: std::io::Error) -> Self {
        Error::Io { path: path.to_string(), source }
    }
}

/// Return `Err(Error::InvalidArgument)` unless `cond` holds.
#[macro_export]
macro_rules! ensure_arg {
    ($cond:expr, $name:expr, $($fmt:tt)+) => {
        if !$cond {
            return Err($crate::Error::arg($name, format!($($fmt)+)));
        }
    };
}
