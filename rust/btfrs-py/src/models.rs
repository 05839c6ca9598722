//! Bindings of the fitted models other than PTM: one Python class (`_native.Model`) over an enum,
//! so evaluation, error, storage and rendering are written once for every model.
//!
//! Each model converts to and from named numpy arrays (`arrays` / `from_arrays`): that is what
//! `btfrs.models` saves into a `.btfrs` container, and what a user inspects.

use crate::arrays::{borrow, check_shape};
use crate::core::BtfArgs;
use crate::errors::{arg, IntoPy};
use crate::fit::error_dict;
use crate::run::{detach, monitored};
use btfrs_fit::{evaluate_image, model_error, Phong, Srf};
use numpy::{IntoPyArray, PyArrayDyn, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// Every fitted model behind `_native.Model`.
#[derive(Debug)]
pub enum AnyModel {
    /// Phong + spatially-varying residual.
    Srf(Srf),
}

/// Run `$body` with `$m` bound to the concrete model.
macro_rules! with_model {
    ($any:expr, $m:ident => $body:expr) => {
        match $any {
            AnyModel::Srf($m) => $body,
        }
    };
}
pub(crate) use with_model;

impl AnyModel {
    pub(crate) fn kind(&self) -> &'static str {
        match self {
            AnyModel::Srf(_) => "srf",
        }
    }

    fn dims(&self) -> (usize, usize) {
        with_model!(self, m => btfrs_fit::ReflectanceModel::dims(m))
    }

    fn nbytes(&self) -> usize {
        with_model!(self, m => m.nbytes())
    }
}

/// A fitted model (the Rust side of `btfrs.Srf` and the other model classes).
#[derive(Debug)]
#[pyclass(name = "Model", module = "btfrs._native", frozen)]
pub struct PyModel {
    pub inner: AnyModel,
}

type Arrays<'py> = Bound<'py, PyDict>;

fn put<'py, T: numpy::Element>(d: &Arrays<'py>, name: &str, v: Vec<T>, shape: Vec<usize>) -> PyResult<()> {
    d.set_item(name, v.into_pyarray(d.py()).reshape(shape)?)
}

/// A named array of `dict`, borrowed, with its shape checked.
fn get<'py, T: numpy::Element + Copy>(
    d: &Arrays<'py>,
    name: &str,
    shape: &[Option<usize>],
) -> PyResult<(Vec<T>, Vec<usize>)> {
    let a = d.get_item(name)?.ok_or_else(|| arg("arrays", format!("missing the array {name:?}")))?;
    let r = borrow::<T>(name, &a)?;
    check_shape(name, r.shape(), shape)?;
    Ok((r.as_slice().map_err(|e| arg(name, e))?.to_vec(), r.shape().to_vec()))
}

fn finite(name: &str, x: &[f32]) -> PyResult<()> {
    match x.iter().position(|v| !v.is_finite()) {
        Some(i) => Err(arg(name, format!("value at flat index {i} is not finite"))),
        None => Ok(()),
    }
}

#[pymethods]
impl PyModel {
    /// The model's name: "srf", "lafortune", "sh" or "lpca".
    #[getter]
    fn kind(&self) -> &'static str {
        self.inner.kind()
    }

    /// (height, width).
    #[getter]
    fn dims(&self) -> (usize, usize) {
        self.inner.dims()
    }

    /// Bytes as stored for rendering.
    #[getter]
    fn nbytes(&self) -> usize {
        self.inner.nbytes()
    }

    /// `[H, W, 3]` image for one view and one light.
    fn evaluate<'py>(&self, py: Python<'py>, view: [f64; 3], light: [f64; 3]) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        let (h, w) = self.inner.dims();
        let img = detach(py, || with_model!(&self.inner, m => evaluate_image(m, view, light)))?;
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
        let e = detach(py, || with_model!(&self.inner, m => model_error(m, &b)))?;
        error_dict(py, e)
    }

    /// The model's arrays (copies), by name.
    fn arrays<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        match &self.inner {
            AnyModel::Srf(m) => {
                let p = &m.phong;
                put(&d, "phong", p.kd.iter().chain(&p.ks).chain([&p.n]).copied().collect::<Vec<f64>>(), vec![7])?;
                put(&d, "s", m.s.clone(), vec![m.height, m.width, 3, 3])?;
            }
        }
        Ok(d)
    }

    /// Rebuild a model from `arrays()` output (as saved), validating every array.
    #[staticmethod]
    fn from_arrays(kind: &str, arrays: &Bound<'_, PyDict>) -> PyResult<Self> {
        let inner = match kind {
            "srf" => {
                let (p, _) = get::<f64>(arrays, "phong", &[Some(7)])?;
                let (s, sh) = get::<f32>(arrays, "s", &[None, None, Some(3), Some(3)])?;
                let m = Srf {
                    height: sh[0],
                    width: sh[1],
                    phong: Phong { kd: [p[0], p[1], p[2]], ks: [p[3], p[4], p[5]], n: p[6] },
                    s,
                };
                m.validate().py()?;
                AnyModel::Srf(m)
            }
            o => return Err(arg("kind", format!("expected \"srf\", \"lafortune\", \"sh\" or \"lpca\", got {o:?}"))),
        };
        let _ = finite;
        Ok(PyModel { inner })
    }
}

/// Fit Phong + SRF; returns the model and a report dict.
#[pyfunction]
#[pyo3(signature = (data, views, lights, mask=None, progress=None))]
pub fn fit_srf_native<'py>(
    py: Python<'py>,
    data: &Bound<'py, PyAny>,
    views: &Bound<'py, PyAny>,
    lights: &Bound<'py, PyAny>,
    mask: Option<&Bound<'py, PyAny>>,
    progress: Option<&Bound<'py, PyAny>>,
) -> PyResult<(PyModel, Bound<'py, PyDict>)> {
    let args = BtfArgs::new(data, views, lights, mask)?;
    let b = args.btf()?;
    let (m, r) = monitored(py, progress, |mon| {
        btfrs_core::btf::check_finite("data", b.data)?;
        btfrs_fit::fit_srf(&b, mon)
    })?;
    let d = PyDict::new(py);
    d.set_item("phong_relative", r.phong_relative)?;
    d.set_item("srf_relative", r.srf_relative)?;
    d.set_item("iterations", r.iterations)?;
    Ok((PyModel { inner: AnyModel::Srf(m) }, d))
}
