//! Bindings of btfrs-hemimap: the (elevated) concentric map over numpy arrays of any batch shape.

use crate::arrays::check_shape;
use crate::run::detach;
use numpy::{IntoPyArray, PyArrayDyn, PyArrayMethods, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;

/// Apply `map` to every row of a `[..., IN]` array, keeping its dtype (the batch map and its
/// checks are `btfrs_hemimap::Map::apply`; this only translates the numpy shapes).
fn apply<'py>(py: Python<'py>, name: &str, x: &Bound<'py, PyAny>, map: hm::Map) -> PyResult<Bound<'py, PyAny>> {
    let (inp, outp) = (map.input_dim(), map.output_dim());
    macro_rules! go {
        ($t:ty) => {{
            let a: PyReadonlyArrayDyn<'py, $t> = x.cast::<PyArrayDyn<$t>>()?.readonly();
            let shape = a.shape().to_vec();
            if shape.last() != Some(&inp) {
                let mut want: Vec<Option<usize>> = shape.iter().map(|_| None).collect();
                if let Some(w) = want.last_mut() {
                    *w = Some(inp)
                } else {
                    want.push(Some(inp))
                }
                check_shape(name, &shape, &want)?;
            }
            let owned;
            let s: &[$t] = match a.as_slice() {
                Ok(s) => s,
                Err(_) => {
                    owned = a.as_array().iter().copied().collect::<Vec<$t>>();
                    &owned
                }
            };
            let out: Vec<$t> = detach(py, || map.apply(s).map_err(|e| btfrs_core::Error::arg(name, e)))?;
            let mut oshape = shape.clone();
            *oshape.last_mut().expect("non-empty shape") = outp;
            Ok(out.into_pyarray(py).reshape(oshape)?.into_any())
        }};
    }
    if x.cast::<PyArrayDyn<f32>>().is_ok() {
        go!(f32)
    } else if x.cast::<PyArrayDyn<f64>>().is_ok() {
        go!(f64)
    } else {
        Err(crate::errors::arg_type(name, "expected a float32 or float64 numpy array"))
    }
}

use btfrs_hemimap as hm;

/// Concentric map, square `[..., 2]` in [0, 1]^2 -> unit disk `[..., 2]`.
#[pyfunction]
pub fn square_to_disk<'py>(py: Python<'py>, st: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyAny>> {
    apply(py, "st", st, hm::Map::SquareToDisk)
}

/// Inverse concentric map, disk `[..., 2]` -> square `[..., 2]`.
#[pyfunction]
pub fn disk_to_square<'py>(py: Python<'py>, xy: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyAny>> {
    apply(py, "xy", xy, hm::Map::DiskToSquare)
}

/// Elevated concentric map (paper 004, section 6.1), square `[..., 2]` -> hemisphere `[..., 3]`.
#[pyfunction]
pub fn square_to_hemisphere<'py>(py: Python<'py>, st: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyAny>> {
    apply(py, "st", st, hm::Map::SquareToHemisphere)
}

/// Inverse elevated concentric map, directions `[..., 3]` -> square `[..., 2]`.
#[pyfunction]
pub fn hemisphere_to_square<'py>(py: Python<'py>, d: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyAny>> {
    apply(py, "directions", d, hm::Map::HemisphereToSquare)
}
