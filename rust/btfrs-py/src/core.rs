//! Bindings of btfrs-core: direction sets, BTF checks, splits, built-in materials.

use crate::arrays::{borrow, check_shape, dirs};
use crate::errors::{arg, IntoPy};
use crate::run::{detach, guarded, monitored};
use btfrs_core::materials::{generate, MaterialSpec, Preset};
use btfrs_core::{btf, directions, split, BtfRef};
use numpy::{IntoPyArray, PyArray2, PyArrayDyn, PyArrayMethods, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;

/// The arrays of a Python `Btf`, borrowed.
pub struct BtfArgs<'py> {
    pub data: PyReadonlyArrayDyn<'py, f32>,
    pub views: PyReadonlyArrayDyn<'py, f64>,
    pub lights: PyReadonlyArrayDyn<'py, f64>,
    pub mask: Option<PyReadonlyArrayDyn<'py, bool>>,
}

impl<'py> BtfArgs<'py> {
    pub fn new(
        data: &Bound<'py, PyAny>,
        views: &Bound<'py, PyAny>,
        lights: &Bound<'py, PyAny>,
        mask: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Self> {
        Ok(BtfArgs {
            data: borrow("data", data)?,
            views: borrow("views", views)?,
            lights: borrow("lights", lights)?,
            mask: mask.map(|m| borrow("mask", m)).transpose()?,
        })
    }

    /// The borrowed BTF; sizes and directions are checked, values are not scanned.
    pub fn btf(&self) -> PyResult<BtfRef<'_>> {
        let v = dirs("views", &self.views)?;
        let l = dirs("lights", &self.lights)?;
        let sh = self.data.shape();
        check_shape("data", sh, &[None, None, Some(v.len()), Some(l.len()), Some(3)])?;
        let mask = match &self.mask {
            Some(m) => {
                check_shape("mask", m.shape(), &[Some(v.len()), Some(l.len())])?;
                Some(m.as_slice().map_err(|e| arg("mask", e))?)
            }
            None => None,
        };
        let data = self.data.as_slice().map_err(|e| arg("data", e))?;
        BtfRef::new(sh[0], sh[1], v, l, data, mask).py()
    }
}

/// The 81 UBO 2003 directions, `[81, 3]`.
#[pyfunction]
pub fn ubo81(py: Python<'_>) -> PyResult<Bound<'_, PyArray2<f64>>> {
    guarded(|| {
        let d = directions::ubo81();
        PyArray2::from_vec2(py, &d.iter().map(|x| x.to_vec()).collect::<Vec<_>>()).map_err(|e| arg("ubo81", e))
    })
}

/// Validate a BTF's arrays: shapes, unit directions with z >= 0, a non-empty mask and, when
/// `scan_values`, finite values (a parallel scan: the only part that reads the data).
#[pyfunction]
#[pyo3(signature = (data, views, lights, mask=None, scan_values=true))]
pub fn validate_btf(
    py: Python<'_>,
    data: &Bound<'_, PyAny>,
    views: &Bound<'_, PyAny>,
    lights: &Bound<'_, PyAny>,
    mask: Option<&Bound<'_, PyAny>>,
    scan_values: bool,
) -> PyResult<()> {
    guarded(|| {
        let args = BtfArgs::new(data, views, lights, mask)?;
        let b = args.btf()?;
        if scan_values {
            detach(py, || btf::check_finite("data", b.data))?;
        }
        Ok(())
    })
}

type MaskArray<'py> = Bound<'py, PyArrayDyn<bool>>;

/// Split the present (view, light) pairs into train and test masks, `[V, L]` each.
#[pyfunction]
#[pyo3(signature = (n_views, n_lights, holdout, seed, mask=None))]
pub fn split_pairs<'py>(
    py: Python<'py>,
    n_views: usize,
    n_lights: usize,
    holdout: f64,
    seed: u64,
    mask: Option<&Bound<'py, PyAny>>,
) -> PyResult<(MaskArray<'py>, MaskArray<'py>)> {
    guarded(|| {
        let m = mask.map(|m| borrow::<bool>("mask", m)).transpose()?;
        let ms = match &m {
            Some(m) => Some(m.as_slice().map_err(|e| arg("mask", e))?),
            None => None,
        };
        let (tr, te) = split::split_pairs(n_views, n_lights, ms, holdout, seed).py()?;
        let shape = [n_views, n_lights];
        let tr = tr.into_pyarray(py).reshape(shape.to_vec())?;
        let te = te.into_pyarray(py).reshape(shape.to_vec())?;
        Ok((tr, te))
    })
}

/// The names of the built-in materials.
#[pyfunction]
pub fn material_names() -> Vec<&'static str> {
    Preset::ALL.iter().map(|p| p.name()).collect()
}

/// Generate a built-in material: `[size, size, V, L, 3]` float32, or with `out` straight into
/// that `.btfrs` file (the values written into the memory-mapped file row by row, never held in
/// memory; atomic: nothing is left on an error or a Ctrl-C), returning None.
#[pyfunction]
#[pyo3(signature = (name, size, views, lights, seed, relief=1.0, subsurface=0.0, out=None, progress=None))]
#[allow(clippy::too_many_arguments)]
pub fn make_material<'py>(
    py: Python<'py>,
    name: &str,
    size: usize,
    views: &Bound<'py, PyAny>,
    lights: &Bound<'py, PyAny>,
    seed: u64,
    relief: f64,
    subsurface: f64,
    out: Option<std::path::PathBuf>,
    progress: Option<&Bound<'py, PyAny>>,
) -> PyResult<Option<Bound<'py, PyArrayDyn<f32>>>> {
    guarded(|| {
        let preset = Preset::from_name(name).py()?;
        let v = borrow::<f64>("views", views)?;
        let l = borrow::<f64>("lights", lights)?;
        let spec = MaterialSpec {
            preset,
            size,
            views: dirs("views", &v)?.to_vec(),
            lights: dirs("lights", &l)?.to_vec(),
            seed,
            relief,
            subsurface,
        };
        let Some(out) = out else {
            let btf = monitored(py, progress, |m| generate(&spec, m))?;
            let shape = [btf.height, btf.width, btf.views.len(), btf.lights.len(), 3];
            return Ok(Some(btf.data.into_pyarray(py).reshape(shape.to_vec())?));
        };
        let meta = serde_json::json!({"layout": "HWVL3"});
        monitored(py, progress, |m| {
            btfrs_io::capture::write_btf_streamed(&out, size, size, &spec.views, &spec.lights, None, meta, |values| {
                btfrs_core::materials::generate_into(&spec, values, m)
            })
        })?;
        Ok(None)
    })
}
