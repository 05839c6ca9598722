//! Bindings of btfrs-hemimap: the (elevated) concentric map over numpy arrays of any batch shape.

use crate::arrays::check_shape;
use crate::errors::arg;
use crate::run::{detach, guarded};
use numpy::{IntoPyArray, PyArrayDyn, PyArrayMethods, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;

/// Apply `f` (an `IN`-to-`OUT` map) to every row of a `[..., IN]` array, keeping its dtype.
fn apply<'py, const IN: usize, const OUT: usize>(
    py: Python<'py>,
    name: &str,
    x: &Bound<'py, PyAny>,
    f32f: fn([f32; IN]) -> [f32; OUT],
    f64f: fn([f64; IN]) -> [f64; OUT],
) -> PyResult<Bound<'py, PyAny>> {
    macro_rules! go {
        ($t:ty, $f:expr) => {{
            let a: PyReadonlyArrayDyn<'py, $t> = x.cast::<PyArrayDyn<$t>>()?.readonly();
            let shape = a.shape().to_vec();
            if shape.last() != Some(&IN) {
                let mut want: Vec<Option<usize>> = shape.iter().map(|_| None).collect();
                if let Some(w) = want.last_mut() {
                    *w = Some(IN)
                } else {
                    want.push(Some(IN))
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
            if let Some(i) = s.iter().position(|v| !v.is_finite()) {
                return Err(arg(name, format!("value at flat index {i} is not finite")));
            }
            let out: Vec<$t> = detach(py, || {
                use rayon::prelude::*;
                Ok(s.as_chunks::<IN>().0.par_iter().flat_map_iter(|p| $f(*p)).collect())
            })?;
            let mut oshape = shape.clone();
            *oshape.last_mut().expect("non-empty shape") = OUT;
            Ok(out.into_pyarray(py).reshape(oshape)?.into_any())
        }};
    }
    if x.cast::<PyArrayDyn<f32>>().is_ok() {
        go!(f32, f32f)
    } else if x.cast::<PyArrayDyn<f64>>().is_ok() {
        go!(f64, f64f)
    } else {
        Err(pyo3::exceptions::PyTypeError::new_err(format!("{name}: expected a float32 or float64 numpy array")))
    }
}

use btfrs_hemimap as hm;

/// Concentric map, square `[..., 2]` in [0, 1]^2 -> unit disk `[..., 2]`.
#[pyfunction]
pub fn square_to_disk<'py>(py: Python<'py>, st: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyAny>> {
    guarded(|| apply::<2, 2>(py, "st", st, |p| hm::square_to_disk(p[0], p[1]), |p| hm::square_to_disk(p[0], p[1])))
}

/// Inverse concentric map, disk `[..., 2]` -> square `[..., 2]`.
#[pyfunction]
pub fn disk_to_square<'py>(py: Python<'py>, xy: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyAny>> {
    guarded(|| apply::<2, 2>(py, "xy", xy, |p| hm::disk_to_square(p[0], p[1]), |p| hm::disk_to_square(p[0], p[1])))
}

/// Elevated concentric map (paper 004, section 6.1), square `[..., 2]` -> hemisphere `[..., 3]`.
#[pyfunction]
pub fn square_to_hemisphere<'py>(py: Python<'py>, st: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyAny>> {
    guarded(|| {
        apply::<2, 3>(py, "st", st, |p| hm::square_to_hemisphere(p[0], p[1]), |p| hm::square_to_hemisphere(p[0], p[1]))
    })
}

/// Inverse elevated concentric map, directions `[..., 3]` -> square `[..., 2]`.
#[pyfunction]
pub fn hemisphere_to_square<'py>(py: Python<'py>, d: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyAny>> {
    guarded(|| apply::<3, 2>(py, "directions", d, hm::hemisphere_to_square, hm::hemisphere_to_square))
}
