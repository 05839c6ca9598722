//! Option values between Python and Rust, each converted once and directly: a Python dict of
//! options becomes the [`Values`] the registry checks against a model's schema (no text in
//! between), and the registry's facts, reports and an error's value come back as Python objects.
//!
//! A Python keyword cannot be a keyword argument, so an option the schema spells as one
//! (`lambda`) is passed with a trailing `_` (`lambda_`, as the generated `btfrs.fit.<kind>`
//! functions spell it); [`Options`] remembers the caller's spelling and reports errors with it.

use crate::errors::{arg_type, arg_value};
use btfrs_core::Error;
use btfrs_fit::options::Values;
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyFloat, PyInt, PyList, PyString};
use serde_json::Value;

/// Options by name as the Rust side reads them, with the caller's spellings.
#[derive(Debug, Default)]
pub struct Options {
    /// The values by the schema's names.
    pub values: Values,
    /// `(schema name, caller's name)` of the options given with a trailing `_`.
    spelled: Vec<(String, String)>,
}

impl Options {
    /// `e` naming its option as the caller spelled it (`lambda_` for the schema's `lambda`).
    pub fn spell(&self, e: Error) -> Error {
        let name = match e.argument() {
            Some((n, _)) => n.to_string(),
            None => return e,
        };
        match self.spelled.iter().find(|(schema, _)| *schema == name) {
            Some((_, given)) => e.renamed(given.clone()),
            None => e,
        }
    }
}

/// A dict of options (`None`: none given) as [`Options`]: string keys, each value a number, a
/// string, a boolean or `None` (numpy scalars included), floats finite.
pub fn options(d: Option<&Bound<'_, PyDict>>) -> PyResult<Options> {
    let mut out = Options::default();
    let Some(d) = d else { return Ok(out) };
    for (k, v) in d.iter() {
        let given: String = k.extract().map_err(|_| arg_type("options", "expected option names as strings"))?;
        let value = to_value(&given, &v)?;
        let name = match given.strip_suffix('_') {
            Some(stem) if !stem.is_empty() => {
                out.spelled.push((stem.to_string(), given.clone()));
                stem.to_string()
            }
            _ => given,
        };
        out.values.insert(name, value);
    }
    Ok(out)
}

/// One option's value, named `name` in errors.
pub fn to_value(name: &str, v: &Bound<'_, PyAny>) -> PyResult<Value> {
    if v.is_none() {
        return Ok(Value::Null);
    }
    // numpy's bool is no Python bool (nor an int), but extracts as one.
    if v.is_instance_of::<PyBool>() || v.get_type().name().is_ok_and(|n| n == "bool_" || n == "bool") {
        return Ok(Value::Bool(v.extract::<bool>()?));
    }
    if v.is_instance_of::<PyString>() {
        return Ok(Value::String(v.extract::<String>()?));
    }
    if v.is_instance_of::<PyFloat>()
        || (!v.is_instance_of::<PyInt>() && !v.hasattr("__index__")? && v.hasattr("__float__")?)
    {
        // A Python float, or a numpy floating scalar (float32 is no Python float).
        let x: f64 = v.extract()?;
        return match serde_json::Number::from_f64(x) {
            Some(n) if x.is_finite() => Ok(Value::Number(n)),
            _ => Err(arg_value(name, v, "a finite number")),
        };
    }
    if v.is_instance_of::<PyInt>() || v.hasattr("__index__")? {
        // A Python int or a numpy integer scalar.
        let i = v.call_method0("__index__")?;
        if let Ok(x) = i.extract::<i64>() {
            return Ok(Value::from(x));
        }
        if let Ok(x) = i.extract::<u64>() {
            return Ok(Value::from(x));
        }
        // Beyond 64 bits: as a float, which the schema refuses as no integer of its range.
        let x: f64 = i.extract()?;
        return serde_json::Number::from_f64(x).map(Value::Number).ok_or_else(|| arg_value(name, v, "a finite number"));
    }
    Err(arg_type(name, format!("expected a number, a string, a boolean or None, got {}", type_name(v))))
}

fn type_name(v: &Bound<'_, PyAny>) -> String {
    v.get_type().name().map_or_else(|_| "?".to_string(), |n| n.to_string())
}

/// A value as the Python object it spells: `None`, a bool, an int, a float, a str, a list or a
/// dict.
pub fn to_py<'py>(py: Python<'py>, v: &Value) -> PyResult<Bound<'py, PyAny>> {
    Ok(match v {
        Value::Null => py.None().into_bound(py),
        Value::Bool(b) => PyBool::new(py, *b).to_owned().into_any(),
        Value::Number(n) => {
            if let Some(i) = n.as_i64() {
                i.into_pyobject(py)?.into_any()
            } else if let Some(u) = n.as_u64() {
                u.into_pyobject(py)?.into_any()
            } else {
                n.as_f64().unwrap_or(f64::NAN).into_pyobject(py)?.into_any()
            }
        }
        Value::String(s) => PyString::new(py, s).into_any(),
        Value::Array(a) => {
            let items = a.iter().map(|x| to_py(py, x)).collect::<PyResult<Vec<_>>>()?;
            PyList::new(py, items)?.into_any()
        }
        Value::Object(o) => {
            let d = PyDict::new(py);
            for (k, x) in o {
                d.set_item(k, to_py(py, x)?)?;
            }
            d.into_any()
        }
    })
}
