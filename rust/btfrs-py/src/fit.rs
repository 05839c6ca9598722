//! Bindings of btfrs-fit: the PTM fit and the fitted model as a Python object.

use crate::arrays::{borrow, check_shape, dirs, vec3};
use crate::core::BtfArgs;
use crate::errors::{arg, IntoPy};
use crate::run::{detach, monitored};
use btfrs_fit::{evaluate_image, fit_ptm, model_error, Degenerate, Ptm, PtmKind, PtmOptions, ReflectanceModel};
use numpy::{IntoPyArray, PyArrayDyn, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;

fn kind_name(k: PtmKind) -> &'static str {
    match k {
        PtmKind::Rgb => "rgb",
        PtmKind::Lrgb => "lrgb",
    }
}

fn parse_kind(kind: &str) -> PyResult<PtmKind> {
    match kind {
        "rgb" => Ok(PtmKind::Rgb),
        "lrgb" => Ok(PtmKind::Lrgb),
        _ => Err(arg("kind", format!("expected \"rgb\" or \"lrgb\", got {kind:?}"))),
    }
}

/// A fitted Polynomial Texture Map (the Rust model; `btfrs.Ptm` wraps it).
#[derive(Debug)]
#[pyclass(name = "PtmModel", module = "btfrs._native", frozen)]
pub struct PyPtm {
    pub inner: Ptm,
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

/// `[H, W, 3]` image of any model for one view and one light (GIL released).
pub fn evaluate_py<'py, M: ReflectanceModel>(
    py: Python<'py>,
    m: &M,
    view: [f64; 3],
    light: [f64; 3],
) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
    let (h, w) = m.dims();
    let img = detach(py, || evaluate_image(m, view, light))?;
    img.into_pyarray(py).reshape(vec![h, w, 3])
}

/// Error of any model against the present pairs of a BTF, as [`error_dict`] (GIL released).
pub fn error_py<'py, M: ReflectanceModel>(
    py: Python<'py>,
    m: &M,
    data: &Bound<'py, PyAny>,
    views: &Bound<'py, PyAny>,
    lights: &Bound<'py, PyAny>,
    mask: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyDict>> {
    let args = BtfArgs::new(data, views, lights, mask)?;
    let b = args.btf()?;
    let e = detach(py, || model_error(m, &b))?;
    error_dict(py, e)
}

#[pymethods]
impl PyPtm {
    /// Build from arrays (as saved): coeffs `[H, W, V, 3, 6]` (rgb) or `[H, W, V, 6]` (lrgb),
    /// rgb `[H, W, V, 3]` for lrgb, views `[V, 3]`.
    #[staticmethod]
    #[pyo3(signature = (kind, coeffs, views, rgb=None))]
    fn from_arrays(
        kind: &str,
        coeffs: &Bound<'_, PyAny>,
        views: &Bound<'_, PyAny>,
        rgb: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        let kind = parse_kind(kind)?;
        let c = borrow::<f32>("coeffs", coeffs)?;
        let v = borrow::<f64>("views", views)?;
        let views = dirs("views", &v)?.to_vec();
        let sh = c.shape().to_vec();
        match kind {
            PtmKind::Rgb => check_shape("coeffs", &sh, &[None, None, Some(views.len()), Some(3), Some(6)])?,
            PtmKind::Lrgb => check_shape("coeffs", &sh, &[None, None, Some(views.len()), Some(6)])?,
        }
        let rgb = match rgb {
            Some(r) => {
                let r = borrow::<f32>("rgb", r)?;
                check_shape("rgb", r.shape(), &[Some(sh[0]), Some(sh[1]), Some(views.len()), Some(3)])?;
                Some(r.as_slice().map_err(|e| arg("rgb", e))?.to_vec())
            }
            None => None,
        };
        let coeffs = c.as_slice().map_err(|e| arg("coeffs", e))?.to_vec();
        if let Some(i) = coeffs.iter().chain(rgb.iter().flatten()).position(|x| !x.is_finite()) {
            return Err(arg("coeffs", format!("value at flat index {i} is not finite")));
        }
        let inner = Ptm { kind, height: sh[0], width: sh[1], views, coeffs, rgb };
        inner.validate().py()?;
        Ok(PyPtm { inner })
    }

    /// "rgb" or "lrgb".
    #[getter]
    fn kind(&self) -> &'static str {
        kind_name(self.inner.kind)
    }

    /// (height, width).
    #[getter]
    fn dims(&self) -> (usize, usize) {
        (self.inner.height, self.inner.width)
    }

    /// Bytes as stored for rendering.
    #[getter]
    fn nbytes(&self) -> usize {
        self.inner.nbytes()
    }

    /// A copy of the coefficients.
    fn coeffs<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        let p = &self.inner;
        let nv = p.views.len();
        let shape: Vec<usize> = match p.kind {
            PtmKind::Rgb => vec![p.height, p.width, nv, 3, 6],
            PtmKind::Lrgb => vec![p.height, p.width, nv, 6],
        };
        p.coeffs.clone().into_pyarray(py).reshape(shape)
    }

    /// A copy of the LRGB base colours, or None.
    fn rgb<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyArrayDyn<f32>>>> {
        let p = &self.inner;
        match &p.rgb {
            Some(r) => Ok(Some(r.clone().into_pyarray(py).reshape(vec![p.height, p.width, p.views.len(), 3])?)),
            None => Ok(None),
        }
    }

    /// The view slots' directions `[V, 3]`.
    fn views<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let v: Vec<f64> = self.inner.views.iter().flatten().copied().collect();
        v.into_pyarray(py).reshape(vec![self.inner.views.len(), 3])
    }

    /// `[H, W, 3]` image for one view and one light.
    fn evaluate<'py>(
        &self,
        py: Python<'py>,
        view: &Bound<'py, PyAny>,
        light: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        evaluate_py(py, &self.inner, vec3("view", view)?, vec3("light", light)?)
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
        error_py(py, &self.inner, data, views, lights, mask)
    }
}

/// Fit a PTM to a BTF's present pairs.
#[pyfunction]
#[pyo3(signature = (data, views, lights, mask=None, kind="rgb", rcond=1e-6, on_degenerate="raise", progress=None))]
#[allow(clippy::too_many_arguments)]
pub fn fit_ptm_native<'py>(
    py: Python<'py>,
    data: &Bound<'py, PyAny>,
    views: &Bound<'py, PyAny>,
    lights: &Bound<'py, PyAny>,
    mask: Option<&Bound<'py, PyAny>>,
    kind: &str,
    rcond: f64,
    on_degenerate: &str,
    progress: Option<&Bound<'py, PyAny>>,
) -> PyResult<PyPtm> {
    let kind = parse_kind(kind)?;
    let on_degenerate = match on_degenerate {
        "raise" => Degenerate::Raise,
        "clamp" => Degenerate::Clamp,
        o => return Err(arg("on_degenerate", format!("expected \"raise\" or \"clamp\", got {o:?}"))),
    };
    let args = BtfArgs::new(data, views, lights, mask)?;
    let b = args.btf()?;
    let opts = PtmOptions { kind, rcond, on_degenerate };
    let inner = monitored(py, progress, |m| {
        btfrs_core::btf::check_finite("data", b.data)?;
        fit_ptm(&b, &opts, m)
    })?;
    Ok(PyPtm { inner })
}
