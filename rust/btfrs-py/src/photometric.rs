//! Bindings of btfrs-fit's photometric stereo and btfrs-core's material heightfields.

use crate::core::BtfArgs;
use crate::errors::IntoPy;
use crate::run::{detach, monitored};
use btfrs_core::materials::{heightfield, Preset};
use btfrs_fit::photometric::{photometric_stereo, Method};
use numpy::{IntoPyArray, PyArrayDyn, PyArrayMethods};
use pyo3::prelude::*;

type F32<'py> = Bound<'py, PyArrayDyn<f32>>;
type Maps<'py> = (F32<'py>, F32<'py>, F32<'py>, usize);

fn image<'py>(py: Python<'py>, v: Vec<[f32; 3]>, h: usize, w: usize) -> PyResult<F32<'py>> {
    v.into_flattened().into_pyarray(py).reshape(vec![h, w, 3])
}

/// Photometric stereo on view slot `view`: `(normals [H, W, 3], albedo [H, W, 3], lights used
/// [H, W], dark texels)` float32.
#[pyfunction]
#[pyo3(signature = (data, views, lights, mask, view, method, progress=None))]
#[allow(clippy::too_many_arguments)]
pub fn photometric_normals<'py>(
    py: Python<'py>,
    data: &Bound<'py, PyAny>,
    views: &Bound<'py, PyAny>,
    lights: &Bound<'py, PyAny>,
    mask: Option<&Bound<'py, PyAny>>,
    view: usize,
    method: &str,
    progress: Option<&Bound<'py, PyAny>>,
) -> PyResult<Maps<'py>> {
    let method = Method::from_name(method).py()?;
    let args = BtfArgs::new(data, views, lights, mask)?;
    let b = args.btf()?;
    let (h, w) = (b.height, b.width);
    let r = monitored(py, progress, |m| photometric_stereo(&b, view, method, m))?;
    let used = r.lights_used.into_pyarray(py).reshape(vec![h, w])?;
    Ok((image(py, r.normals, h, w)?, image(py, r.albedo, h, w)?, used, r.dark_texels))
}

/// A built-in material's surface: `(height [S, S], normals [S, S, 3], albedo [S, S, 3])`
/// float32, row 0 at the top.
#[pyfunction]
#[pyo3(signature = (name, size, seed, relief=1.0))]
pub fn material_heightfield<'py>(
    py: Python<'py>,
    name: &str,
    size: usize,
    seed: u64,
    relief: f64,
) -> PyResult<(F32<'py>, F32<'py>, F32<'py>)> {
    let hf = detach(py, || heightfield(Preset::from_name(name)?, size, seed, relief))?;
    let s = hf.size;
    Ok((hf.height.into_pyarray(py).reshape(vec![s, s])?, image(py, hf.normals, s, s)?, image(py, hf.albedo, s, s)?))
}
