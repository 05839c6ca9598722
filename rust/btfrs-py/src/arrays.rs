//! Taking numpy arrays without copying, with errors that name the argument.

use crate::errors::arg;
use numpy::{PyArrayDyn, PyArrayMethods, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;

/// A C-contiguous read-only borrow of a numpy array of `T`, or an error naming `name`.
pub fn borrow<'py, T: numpy::Element>(name: &str, obj: &Bound<'py, PyAny>) -> PyResult<PyReadonlyArrayDyn<'py, T>> {
    let a = obj.cast::<PyArrayDyn<T>>().map_err(|_| {
        let got = obj
            .getattr("dtype")
            .map(|d| d.to_string())
            .unwrap_or_else(|_| obj.get_type().name().map(|n| n.to_string()).unwrap_or_default());
        let want = numpy::dtype::<T>(obj.py()).to_string();
        crate::errors::arg_type(name, format!("expected a numpy array of {want}, got {got}"))
    })?;
    let r = a.readonly();
    if !r.is_c_contiguous() {
        return Err(arg(name, "expected a C-contiguous array (use numpy.ascontiguousarray)"));
    }
    Ok(r)
}

/// Check the array's shape against `want`, where `None` matches any extent.
pub fn check_shape(name: &str, shape: &[usize], want: &[Option<usize>]) -> PyResult<()> {
    let ok = shape.len() == want.len() && shape.iter().zip(want).all(|(s, w)| w.is_none_or(|w| *s == w));
    if ok {
        return Ok(());
    }
    let w: Vec<String> = want.iter().map(|w| w.map_or("*".into(), |x| x.to_string())).collect();
    Err(arg(name, format!("expected shape ({}), got {shape:?}", w.join(", "))))
}

/// Borrow a `[N, 3]` float64 array as direction triples.
pub fn dirs<'a>(name: &str, a: &'a PyReadonlyArrayDyn<'_, f64>) -> PyResult<&'a [[f64; 3]]> {
    check_shape(name, a.shape(), &[None, Some(3)])?;
    let s = a.as_slice().map_err(|e| arg(name, e))?;
    Ok(s.as_chunks::<3>().0)
}
