//! Bindings of the model contract: one Python class (`_native.Model`) over `Box<dyn DynModel>`
//! and one fit function over the registry, so no binding names a model.
//!
//! Options travel as a dict converted once to the values the registry checks against the
//! model's schema ([`crate::values`]); arrays travel as a dict of numpy arrays converted one for
//! one to the model's [`NamedArrays`]; reports and the registry's facts come back as Python
//! objects.

use crate::arrays::borrow;
use crate::core::BtfArgs;
use crate::errors::{arg, to_py, IntoPy};
use crate::run::{detach, monitored};
use crate::values;
use btfrs_core::arrays::{ArrayData, NamedArrays};
use btfrs_fit::registry;
use btfrs_fit::DynModel;
use numpy::{IntoPyArray, PyArrayDyn, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::PathBuf;

/// A fitted model (the Rust side of `btfrs.Ptm`, `btfrs.Lpca` and every other model class).
#[derive(Debug)]
#[pyclass(name = "Model", module = "btfrs._native", frozen)]
pub struct PyModel {
    pub inner: Box<dyn DynModel>,
    /// The robust fit's report (`Null`: not fitted here, or fitted with `robust=False`).
    pub robust: serde_json::Value,
}

/// Error sums as a dict: rmse, relative, psnr, samples.
pub fn error_dict<'py>(py: Python<'py>, e: btfrs_core::metrics::ErrorSums) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("rmse", e.rmse())?;
    d.set_item("relative", e.relative())?;
    d.set_item("psnr", e.psnr())?;
    d.set_item("samples", e.n)?;
    Ok(d)
}

/// A dict of numpy arrays as named arrays (copied: the model owns its data).
pub(crate) fn named_arrays(d: &Bound<'_, PyDict>) -> PyResult<NamedArrays> {
    let mut out = NamedArrays::new();
    for (k, v) in d.iter() {
        let name: String = k.extract().map_err(|_| arg("arrays", "expected string keys"))?;
        macro_rules! try_dtype {
            ($($t:ty => $var:ident),*) => {
                'found: {
                    $(
                        if let Ok(a) = borrow::<$t>(&name, &v) {
                            let data = a.as_array().iter().copied().collect::<Vec<$t>>();
                            break 'found Some((a.shape().to_vec(), ArrayData::$var(data)));
                        }
                    )*
                    None
                }
            };
        }
        let (shape, data) = try_dtype!(f32 => F32, f64 => F64, u8 => U8, u16 => U16, i32 => I32).ok_or_else(|| {
            arg(
                &name,
                format!("expected a numpy array of float32, float64, uint8, uint16 or int32, got {}", v.get_type()),
            )
        })?;
        out.insert_checked(&name, shape, data).py()?;
    }
    Ok(out)
}

/// Named arrays as a dict of numpy arrays.
pub(crate) fn arrays_dict<'py>(py: Python<'py>, a: NamedArrays) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    for (name, arr) in a.iter() {
        let shape = arr.shape.clone();
        let obj: Bound<'py, PyAny> = match arr.data.clone() {
            ArrayData::U8(v) => v.into_pyarray(py).reshape(shape)?.into_any(),
            ArrayData::U16(v) => v.into_pyarray(py).reshape(shape)?.into_any(),
            ArrayData::I32(v) => v.into_pyarray(py).reshape(shape)?.into_any(),
            ArrayData::F32(v) => v.into_pyarray(py).reshape(shape)?.into_any(),
            ArrayData::F64(v) => v.into_pyarray(py).reshape(shape)?.into_any(),
        };
        d.set_item(name, obj)?;
    }
    Ok(d)
}

#[pymethods]
impl PyModel {
    /// The model's registered name ("ptm", "lpca", ...).
    #[getter]
    fn kind(&self) -> &'static str {
        self.inner.kind()
    }

    /// (height, width).
    #[getter]
    fn dims(&self) -> (usize, usize) {
        self.inner.dims()
    }

    /// Bytes as stored for rendering (what the default renderer uploads).
    #[getter]
    fn nbytes(&self) -> usize {
        self.inner.nbytes()
    }

    /// Renderer names, the default first.
    /// How its mip levels are made: "average", "projected" or "medoid".
    #[getter]
    fn mip(&self) -> &'static str {
        self.inner.mip().name()
    }

    /// Whether it renders under an environment by the SH method (a double-SH expansion).
    #[getter]
    fn sh_lighting(&self) -> bool {
        self.inner.sh_expansion().is_some()
    }

    #[getter]
    fn renderers(&self) -> Vec<&'static str> {
        self.inner.renderers().to_vec()
    }

    /// The fit's statistics (a dict; empty for a model built from arrays).
    fn report<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let mut r = match self.inner.report() {
            serde_json::Value::Null => serde_json::json!({}),
            v => v,
        };
        if !self.robust.is_null() {
            r["robust"] = self.robust.clone();
        }
        values::to_py(py, &r)
    }

    /// `[H, W, 3]` image for one view and one light (unit vectors, z >= 0).
    fn evaluate<'py>(&self, py: Python<'py>, view: [f64; 3], light: [f64; 3]) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        let (h, w) = self.inner.dims();
        let img = detach(py, || self.inner.evaluate_image(view, light))?;
        img.into_pyarray(py).reshape(vec![h, w, 3])
    }

    /// Error against the present pairs of a BTF: dict of rmse, relative, psnr, samples.
    #[pyo3(signature = (data, views, lights, mask=None))]
    fn error<'py>(
        &self,
        py: Python<'py>,
        data: &Bound<'py, PyAny>,
        views: &Bound<'py, PyAny>,
        lights: &Bound<'py, PyAny>,
        mask: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let args = BtfArgs::new(data, views, lights, mask)?;
        let b = args.btf()?;
        let e = detach(py, || self.inner.error(&b))?;
        error_dict(py, e)
    }

    /// The model's arrays (copies), by name: what a file stores.
    fn arrays<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        arrays_dict(py, self.inner.to_arrays())
    }

    /// The parameters as a reader uses them (decoded, by role), by name; empty for most models.
    fn unpacked<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        arrays_dict(py, self.inner.unpacked())
    }

    /// The model of a subset of texels (row-major indices): dims `(1, len(texels))`, texel `k`
    /// of the result is `texels[k]` of this model (a tile set's BTFel table).
    fn select_texels(&self, py: Python<'_>, texels: Vec<u32>) -> PyResult<Self> {
        let inner = detach(py, || registry::select_texels(self.inner.as_ref(), &texels))?;
        Ok(PyModel { inner, robust: serde_json::Value::Null })
    }

    /// Rebuild model `kind` from `arrays()` output, validating every array.
    #[staticmethod]
    fn from_arrays(py: Python<'_>, kind: &str, arrays: &Bound<'_, PyDict>) -> PyResult<Self> {
        let a = named_arrays(arrays)?;
        let inner = detach(py, || registry::from_arrays(kind, &a))?;
        Ok(PyModel { inner, robust: serde_json::Value::Null })
    }

    /// Write the model to a `.btfrs` file (atomically); `meta_json` is a JSON object stored with
    /// the fit report.
    fn save(&self, py: Python<'_>, path: PathBuf, meta_json: &str) -> PyResult<()> {
        let meta: serde_json::Value = serde_json::from_str(meta_json).map_err(|e| arg("meta", e))?;
        detach(py, || btfrs_io::model_file::save_model(&path, self.inner.as_ref(), meta))
    }
}

/// Read a model file: (model, meta as JSON).
#[pyfunction]
pub fn load_model(py: Python<'_>, path: PathBuf) -> PyResult<(PyModel, String)> {
    let (inner, meta) = detach(py, || btfrs_io::model_file::load_model(&path))?;
    Ok((PyModel { inner, robust: serde_json::Value::Null }, meta.to_string()))
}

/// Every fact of every registered model (`btfrs_fit::registry::describe`), a list of dicts: what
/// the Python API, the CLI and the docs are built from.
#[pyfunction]
pub fn model_facts(py: Python<'_>) -> PyResult<Bound<'_, PyAny>> {
    values::to_py(py, &registry::describe())
}

/// The options every fit takes besides its own (robust fitting), as their schema: a list of dicts.
#[pyfunction]
pub fn fit_options(py: Python<'_>) -> PyResult<Bound<'_, PyAny>> {
    values::to_py(py, &btfrs_fit::options::schema_json(btfrs_fit::driver::OPTIONS))
}

/// Check fit options (a dict) for model `kind` as its fit would, without fitting.
#[pyfunction]
pub fn check_options(kind: &str, options: &Bound<'_, PyDict>) -> PyResult<()> {
    let o = values::options(Some(options))?;
    registry::check_options(kind, &o.values).map_err(|e| to_py(o.spell(e)))
}

/// The arrays of model `kind` that hold one entry per texel (shape `[H, W, ...]`).
#[pyfunction]
pub fn texel_arrays(kind: &str) -> PyResult<Vec<&'static str>> {
    Ok(registry::lookup(kind).py()?.texel_arrays.to_vec())
}

/// Fit model `kind` to a BTF's present pairs with its options (a dict by name, `None`: the
/// defaults); the GIL is released, progress reported, Ctrl-C honoured.
#[pyfunction]
#[pyo3(signature = (kind, data, views, lights, mask=None, options=None, progress=None, robust=false, exclude_bad_images=false))]
#[allow(clippy::too_many_arguments)]
pub fn fit_model<'py>(
    py: Python<'py>,
    kind: &str,
    data: &Bound<'py, PyAny>,
    views: &Bound<'py, PyAny>,
    lights: &Bound<'py, PyAny>,
    mask: Option<&Bound<'py, PyAny>>,
    options: Option<&Bound<'py, PyDict>>,
    progress: Option<&Bound<'py, PyAny>>,
    robust: bool,
    exclude_bad_images: bool,
) -> PyResult<PyModel> {
    let entry = registry::lookup(kind).py()?;
    let o = values::options(options)?;
    let ro = btfrs_fit::driver::RobustOptions { robust, exclude_bad_images };
    let args = BtfArgs::new(data, views, lights, mask)?;
    let b = args.btf()?;
    let (inner, robust) = monitored(py, progress, |mon| {
        // Models that check each texel in their own pass skip the scan: on a memory-mapped
        // file a scan is a second read of the whole data from storage. (The robust screen
        // ignores a NaN: no comparison with one flags it, and the fit then names it.)
        if !entry.scans_values {
            btfrs_core::btf::check_finite("data", b.data)?;
        }
        btfrs_fit::driver::fit(entry, &b, &o.values, ro, mon).map_err(|e| o.spell(e))
    })?;
    Ok(PyModel { inner, robust })
}
