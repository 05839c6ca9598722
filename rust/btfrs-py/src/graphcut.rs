//! Bindings of btfrs-graphcut: numpy arrays in, `(flow, source_side)` out. The capacity dtype
//! (int64, float64 or float32; `btfrs.graphcut` converts everything else) picks the Rust type.

use crate::arrays::{borrow, check_shape};
use crate::run::{detach, guarded};
use numpy::{IntoPyArray, PyArrayDyn, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::IntoPyObjectExt;

/// Borrow a C-contiguous `[..., 2]` array of `C` as pairs, checking its shape against `want`.
fn pairs<'a, C: numpy::Element + Copy>(
    name: &str,
    a: &'a numpy::PyReadonlyArrayDyn<'_, C>,
    want: &[Option<usize>],
) -> PyResult<&'a [[C; 2]]> {
    check_shape(name, a.shape(), want)?;
    let s = a.as_slice().map_err(|e| crate::errors::arg(name, e))?;
    Ok(s.as_chunks::<2>().0)
}

/// General graph: `edges` int64 `[E, 2]`, `capacities` `[E, 2]`, `terminal_caps` `[n, 2]` of the
/// same dtype (int64, float64 or float32). Returns `(flow, source_side bool [n])`.
#[pyfunction]
pub fn min_cut_native<'py>(
    py: Python<'py>,
    n: usize,
    edges: &Bound<'py, PyAny>,
    capacities: &Bound<'py, PyAny>,
    terminal_caps: &Bound<'py, PyAny>,
) -> PyResult<(Py<PyAny>, Bound<'py, PyAny>)> {
    guarded(|| {
        let e = borrow::<i64>("edges", edges)?;
        let ev = pairs("edges", &e, &[None, Some(2)])?;
        let mut idx = Vec::with_capacity(ev.len());
        for (k, &[a, b]) in ev.iter().enumerate() {
            let (Ok(a), Ok(b)) = (usize::try_from(a), usize::try_from(b)) else {
                return Err(crate::errors::arg(
                    "edges",
                    format!("edge {k} names node {}; expected ids >= 0", a.min(b)),
                ));
            };
            idx.push([a, b]);
        }
        macro_rules! go {
            ($t:ty) => {{
                let c = borrow::<$t>("capacities", capacities)?;
                let cv = pairs("capacities", &c, &[Some(ev.len()), Some(2)])?;
                let t = borrow::<$t>("terminal_caps", terminal_caps)?;
                let tv = pairs("terminal_caps", &t, &[Some(n), Some(2)])?;
                let (flow, side) = detach(py, || btfrs_graphcut::min_cut::<$t>(n, &idx, cv, tv))?;
                Ok((flow.into_py_any(py)?, side.into_pyarray(py).into_any()))
            }};
        }
        if capacities.cast::<PyArrayDyn<i64>>().is_ok() {
            go!(i64)
        } else if capacities.cast::<PyArrayDyn<f64>>().is_ok() {
            go!(f64)
        } else if capacities.cast::<PyArrayDyn<f32>>().is_ok() {
            go!(f32)
        } else {
            Err(crate::errors::arg_type("capacities", "expected a numpy array of int64, float64 or float32"))
        }
    })
}

/// 4-connected grid: `right` `[H, W - 1, 2]`, `down` `[H - 1, W, 2]`, `terminal_caps` `[H, W, 2]`,
/// all of one dtype (int64, float64 or float32). Returns `(flow, source_side bool [H, W])`.
#[pyfunction]
pub fn grid_min_cut_native<'py>(
    py: Python<'py>,
    right: &Bound<'py, PyAny>,
    down: &Bound<'py, PyAny>,
    terminal_caps: &Bound<'py, PyAny>,
) -> PyResult<(Py<PyAny>, Bound<'py, PyAny>)> {
    guarded(|| {
        macro_rules! go {
            ($t:ty) => {{
                let t = borrow::<$t>("terminal_caps", terminal_caps)?;
                check_shape("terminal_caps", t.shape(), &[None, None, Some(2)])?;
                let (h, w) = (t.shape()[0], t.shape()[1]);
                let tv = pairs("terminal_caps", &t, &[Some(h), Some(w), Some(2)])?;
                let r = borrow::<$t>("right", right)?;
                let rv = pairs("right", &r, &[Some(h), Some(w.saturating_sub(1)), Some(2)])?;
                let d = borrow::<$t>("down", down)?;
                let dv = pairs("down", &d, &[Some(h.saturating_sub(1)), Some(w), Some(2)])?;
                let (flow, side) = detach(py, || btfrs_graphcut::grid_min_cut::<$t>(h, w, rv, dv, tv))?;
                Ok((flow.into_py_any(py)?, side.into_pyarray(py).reshape([h, w])?.into_any()))
            }};
        }
        if terminal_caps.cast::<PyArrayDyn<i64>>().is_ok() {
            go!(i64)
        } else if terminal_caps.cast::<PyArrayDyn<f64>>().is_ok() {
            go!(f64)
        } else if terminal_caps.cast::<PyArrayDyn<f32>>().is_ok() {
            go!(f32)
        } else {
            Err(crate::errors::arg_type("terminal_caps", "expected a numpy array of int64, float64 or float32"))
        }
    })
}
