//! The one error type of btfrs.
//!
//! Every fallible function in the plain Rust crates returns [`Result`]. The PyO3 crate maps each
//! variant onto a Python exception class (see `python/btfrs/exceptions.py`), so the variant says
//! *what kind* of failure it is and the message says *which argument* and *what was expected*.
//! An argument error also carries its fields apart ([`Error::argument`], [`Detail`]: the value
//! given and what is allowed, where the check knows them), which the bindings set as attributes
//! of the Python exception, so no caller has to read them back out of the message.

use std::fmt;

/// What went wrong, with enough words for a user to fix it.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// An argument has the wrong shape, range or value. `name` is the argument as the user wrote it;
    /// `detail`, where the check knows them, the value given and what is allowed.
    #[error("{name}: {msg}")]
    InvalidArgument { name: String, msg: String, detail: Option<Box<Detail>> },
    /// An argument has the wrong type (a float where an integer is expected, ...): in Python a
    /// `btfrs.exceptions.ArgumentTypeError`, which is also an `InvalidArgumentError`.
    #[error("{name}: {msg}")]
    ArgumentType { name: String, msg: String, detail: Option<Box<Detail>> },
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

/// The value an argument error is about and what would have been allowed (an option checked
/// against its schema: `lobes`, `2.9`, "an integer from 1 to 7").
#[derive(Debug, Clone, PartialEq)]
pub struct Detail {
    /// The value given (as the caller gave it: a number, a string, `null`, ...).
    pub value: serde_json::Value,
    /// What is allowed, in words.
    pub allowed: String,
}

/// `Result` with btfrs's [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    /// An [`Error::InvalidArgument`] naming the argument.
    pub fn arg(name: impl Into<String>, msg: impl fmt::Display) -> Self {
        Error::InvalidArgument { name: name.into(), msg: msg.to_string(), detail: None }
    }

    /// An argument error with its fields: `value` is not among what `allowed` says (a type error
    /// when `wrong_type`: a float where an integer is expected). The message is
    /// `"{name}: expected {allowed}, got {value}"`.
    pub fn value(
        name: impl Into<String>,
        value: serde_json::Value,
        allowed: impl Into<String>,
        wrong_type: bool,
    ) -> Self {
        let allowed = allowed.into();
        let msg = format!("expected {allowed}, got {value}");
        let detail = Some(Box::new(Detail { value, allowed }));
        let name = name.into();
        if wrong_type {
            Error::ArgumentType { name, msg, detail }
        } else {
            Error::InvalidArgument { name, msg, detail }
        }
    }

    /// The argument an [`Error::InvalidArgument`] or [`Error::ArgumentType`] names, with its
    /// detail where known; `None` for the other variants.
    pub fn argument(&self) -> Option<(&str, Option<&Detail>)> {
        match self {
            Error::InvalidArgument { name, detail, .. } | Error::ArgumentType { name, detail, .. } => {
                Some((name, detail.as_deref()))
            }
            _ => None,
        }
    }

    /// The same error naming its argument `name` instead (the caller's spelling of an option,
    /// `lambda_` for the schema's `lambda`); other variants unchanged.
    pub fn renamed(self, name: impl Into<String>) -> Self {
        match self {
            Error::InvalidArgument { msg, detail, .. } => Error::InvalidArgument { name: name.into(), msg, detail },
            Error::ArgumentType { msg, detail, .. } => Error::ArgumentType { name: name.into(), msg, detail },
            other => other,
        }
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
