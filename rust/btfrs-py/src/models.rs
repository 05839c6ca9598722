//! Bindings of the fitted models other than PTM: one Python class (`_native.Model`) over an enum,
//! so evaluation, error, storage and rendering are written once for every model.
//!
//! Each model converts to and from named numpy arrays (`arrays` / `from_arrays`): that is what
//! `btfrs.models` saves into a `.btfrs` container, and what a user inspects.

use crate::arrays::{borrow, check_shape};
use crate::core::BtfArgs;
use crate::errors::{arg, IntoPy};
use crate::fit::{error_py, evaluate_py};
use crate::run::monitored;
use btfrs_fit::lafortune::{FitReport, LafortuneOptions};
use btfrs_fit::lpca::LpcaOptions;
use btfrs_fit::sh::ShOptions;
use btfrs_fit::{Lafortune, LafortuneKind, Lpca, Phong, Sh, ShCoeffs, Srf};
use numpy::{IntoPyArray, PyArrayDyn, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// Every fitted model behind `_native.Model`.
#[derive(Debug)]
pub enum AnyModel {
    /// Phong + spatially-varying residual.
    Srf(Srf),
    /// Per-texel Lafortune lobes.
    Lafortune(Lafortune),
    /// Double spherical harmonics.
    Sh(Sh),
    /// Local PCA.
    Lpca(Lpca),
}

/// Run `$body` with `$m` bound to the concrete model.
macro_rules! with_model {
    ($any:expr, $m:ident => $body:expr) => {
        match $any {
            AnyModel::Srf($m) => $body,
            AnyModel::Lafortune($m) => $body,
            AnyModel::Sh($m) => $body,
            AnyModel::Lpca($m) => $body,
        }
    };
}
pub(crate) use with_model;

impl AnyModel {
    pub(crate) fn kind(&self) -> &'static str {
        match self {
            AnyModel::Srf(_) => "srf",
            AnyModel::Lafortune(_) => "lafortune",
            AnyModel::Sh(_) => "sh",
            AnyModel::Lpca(_) => "lpca",
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

pub(crate) type Arrays<'py> = Bound<'py, PyDict>;

pub(crate) fn put<'py, T: numpy::Element>(d: &Arrays<'py>, name: &str, v: Vec<T>, shape: Vec<usize>) -> PyResult<()> {
    d.set_item(name, v.into_pyarray(d.py()).reshape(shape)?)
}

/// A named array of `dict`, borrowed, with its shape checked.
pub(crate) fn get<'py, T: numpy::Element + Copy>(
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
        with_model!(&self.inner, m => evaluate_py(py, m, view, light))
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
        with_model!(&self.inner, m => error_py(py, m, data, views, lights, mask))
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
            AnyModel::Lafortune(m) => {
                let p = m.params_per_fit();
                let (h, w) = (m.height, m.width);
                match m.kind {
                    LafortuneKind::Lum => put(&d, "params", m.params.clone(), vec![h, w, p])?,
                    LafortuneKind::Rgb => put(&d, "params", m.params.clone(), vec![h, w, 3, p])?,
                }
                if let Some(rgb) = &m.rgb {
                    put(&d, "rgb", rgb.clone(), vec![h, w, 3])?;
                }
                if !m.status.is_empty() {
                    let n = m.status.len() / (h * w);
                    let shape = if n == 1 { vec![h, w] } else { vec![h, w, n] };
                    put(&d, "status", m.status.clone(), shape)?;
                }
            }
            AnyModel::Sh(m) => {
                let shape = vec![m.height, m.width, 3, m.view_coeffs, m.light_coeffs];
                match &m.coeffs {
                    ShCoeffs::Quantized { q, scale, bias } => {
                        put(&d, "q", q.clone(), shape)?;
                        put(&d, "scale", scale.to_vec(), vec![3])?;
                        put(&d, "bias", bias.to_vec(), vec![3])?;
                    }
                    ShCoeffs::Float(c) => put(&d, "coeffs", c.clone(), shape)?,
                }
            }
            AnyModel::Lpca(m) => {
                let (k, c1) = (m.clusters, m.components + 1);
                let (nv, nl) = (m.views.len(), m.lights.len());
                put(&d, "ids", m.ids.iter().map(|&x| x as i32).collect::<Vec<i32>>(), vec![m.height, m.width])?;
                put(&d, "weights", m.weights.clone(), vec![m.height, m.width, c1 + 1])?;
                put(&d, "basis", m.basis.clone(), vec![k, c1, nv, nl, 4])?;
                put(&d, "scale", m.scale.clone(), vec![k, c1])?;
                put(&d, "bias", m.bias.clone(), vec![k, c1])?;
                put(&d, "views", m.views.iter().flatten().copied().collect::<Vec<f64>>(), vec![nv, 3])?;
                put(&d, "lights", m.lights.iter().flatten().copied().collect::<Vec<f64>>(), vec![nl, 3])?;
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
            "lafortune" => {
                let (params, sh) = get::<f32>(arrays, "params", &[None, None, None])
                    .or_else(|_| get::<f32>(arrays, "params", &[None, None, Some(3), None]))?;
                let kind = if sh.len() == 3 { LafortuneKind::Lum } else { LafortuneKind::Rgb };
                let p = *sh.last().unwrap_or(&0);
                if p < 5 || (p - 1) % 4 != 0 {
                    return Err(arg("params", format!("expected 1 + 4 * lobes values per fit, got {p}")));
                }
                let rgb = match kind {
                    LafortuneKind::Lum => Some(get::<f32>(arrays, "rgb", &[Some(sh[0]), Some(sh[1]), Some(3)])?.0),
                    LafortuneKind::Rgb => None,
                };
                let status = match arrays.get_item("status")? {
                    Some(_) => {
                        get::<u8>(arrays, "status", &[Some(sh[0]), Some(sh[1])])
                            .or_else(|_| get::<u8>(arrays, "status", &[Some(sh[0]), Some(sh[1]), Some(3)]))?
                            .0
                    }
                    None => Vec::new(),
                };
                let m = Lafortune {
                    kind,
                    height: sh[0],
                    width: sh[1],
                    lobes: (p - 1) / 4,
                    params,
                    rgb,
                    status,
                    report: FitReport::default(),
                };
                m.validate().py()?;
                AnyModel::Lafortune(m)
            }
            "sh" => {
                let shape = [None, None, Some(3), None, None];
                let (coeffs, sh) = if arrays.get_item("q")?.is_some() {
                    let (q, sh) = get::<u8>(arrays, "q", &shape)?;
                    let (scale, _) = get::<f32>(arrays, "scale", &[Some(3)])?;
                    let (bias, _) = get::<f32>(arrays, "bias", &[Some(3)])?;
                    finite("scale", &scale)?;
                    finite("bias", &bias)?;
                    let q = ShCoeffs::Quantized {
                        q,
                        scale: [scale[0], scale[1], scale[2]],
                        bias: [bias[0], bias[1], bias[2]],
                    };
                    (q, sh)
                } else {
                    let (c, sh) = get::<f32>(arrays, "coeffs", &shape)?;
                    finite("coeffs", &c)?;
                    (ShCoeffs::Float(c), sh)
                };
                let m = Sh {
                    height: sh[0],
                    width: sh[1],
                    view_coeffs: sh[3],
                    light_coeffs: sh[4],
                    coeffs,
                    constrained_fraction: 0.0,
                    mean_lambda: 0.0,
                };
                m.validate().py()?;
                AnyModel::Sh(m)
            }
            "lpca" => {
                let (ids, sh) = get::<i32>(arrays, "ids", &[None, None])?;
                let (weights, ws) = get::<f32>(arrays, "weights", &[Some(sh[0]), Some(sh[1]), None])?;
                let (basis, bs) = get::<u8>(arrays, "basis", &[None, None, None, None, Some(4)])?;
                let (scale, _) = get::<f32>(arrays, "scale", &[Some(bs[0]), Some(bs[1])])?;
                let (bias, _) = get::<f32>(arrays, "bias", &[Some(bs[0]), Some(bs[1])])?;
                let (views, _) = get::<f64>(arrays, "views", &[Some(bs[2]), Some(3)])?;
                let (lights, _) = get::<f64>(arrays, "lights", &[Some(bs[3]), Some(3)])?;
                if ws[2] != bs[1] + 1 {
                    return Err(arg("weights", format!("expected {} values per texel, got {}", bs[1] + 1, ws[2])));
                }
                if let Some(i) = ids.iter().position(|&x| x < 0 || x as usize >= bs[0]) {
                    return Err(arg("ids", format!("entry {i} is {}, not a cluster in [0, {})", ids[i], bs[0])));
                }
                for (n, x) in [("weights", &weights), ("scale", &scale), ("bias", &bias)] {
                    finite(n, x)?;
                }
                let m = Lpca {
                    height: sh[0],
                    width: sh[1],
                    views: views.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
                    lights: lights.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
                    clusters: bs[0],
                    components: bs[1] - 1,
                    ids: ids.into_iter().map(|x| x as u32).collect(),
                    weights,
                    basis,
                    scale,
                    bias,
                };
                m.validate().py()?;
                AnyModel::Lpca(m)
            }
            o => return Err(arg("kind", format!("expected \"srf\", \"lafortune\", \"sh\" or \"lpca\", got {o:?}"))),
        };
        Ok(PyModel { inner })
    }
}

/// Borrow the BTF arguments, check the values are finite, and run `fit` on a worker thread with
/// progress and Ctrl-C (what every `fit_*_native` shares).
fn run_fit<'py, M: Send>(
    py: Python<'py>,
    data: &Bound<'py, PyAny>,
    views: &Bound<'py, PyAny>,
    lights: &Bound<'py, PyAny>,
    mask: Option<&Bound<'py, PyAny>>,
    progress: Option<&Bound<'py, PyAny>>,
    fit: impl FnOnce(&btfrs_core::BtfRef<'_>, &btfrs_core::Monitor) -> btfrs_core::Result<M> + Send,
) -> PyResult<M> {
    let args = BtfArgs::new(data, views, lights, mask)?;
    let b = args.btf()?;
    monitored(py, progress, |mon| {
        btfrs_core::btf::check_finite("data", b.data)?;
        fit(&b, mon)
    })
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
    let (m, r) = run_fit(py, data, views, lights, mask, progress, btfrs_fit::fit_srf)?;
    let d = PyDict::new(py);
    d.set_item("phong_relative", r.phong_relative)?;
    d.set_item("srf_relative", r.srf_relative)?;
    d.set_item("iterations", r.iterations)?;
    Ok((PyModel { inner: AnyModel::Srf(m) }, d))
}

/// Fit per-texel Lafortune lobes; returns the model and its report dict.
#[pyfunction]
#[pyo3(signature = (data, views, lights, mask=None, kind="lum", lobes=2, diffuse=true, max_iter=60, densify=0, progress=None))]
#[allow(clippy::too_many_arguments)]
pub fn fit_lafortune_native<'py>(
    py: Python<'py>,
    data: &Bound<'py, PyAny>,
    views: &Bound<'py, PyAny>,
    lights: &Bound<'py, PyAny>,
    mask: Option<&Bound<'py, PyAny>>,
    kind: &str,
    lobes: usize,
    diffuse: bool,
    max_iter: usize,
    densify: usize,
    progress: Option<&Bound<'py, PyAny>>,
) -> PyResult<(PyModel, Bound<'py, PyDict>)> {
    let kind = match kind {
        "lum" => LafortuneKind::Lum,
        "rgb" => LafortuneKind::Rgb,
        o => return Err(arg("kind", format!("expected \"lum\" or \"rgb\", got {o:?}"))),
    };
    let opts = LafortuneOptions { kind, lobes, diffuse, max_iter, densify };
    let m = run_fit(py, data, views, lights, mask, progress, |b, mon| btfrs_fit::fit_lafortune(b, &opts, mon))?;
    let r = m.report;
    let d = PyDict::new(py);
    d.set_item("fits", r.fits)?;
    d.set_item("converged", r.converged)?;
    d.set_item("fell_back", r.fell_back)?;
    d.set_item("failed", r.failed)?;
    d.set_item("mean_iterations", r.mean_iterations)?;
    d.set_item("rms_residual", r.rms_residual)?;
    Ok((PyModel { inner: AnyModel::Lafortune(m) }, d))
}

/// Fit double SH by constrained (or plain) least squares; returns the model and a report dict.
#[pyfunction]
#[pyo3(signature = (data, views, lights, mask=None, light_coeffs=25, view_coeffs=25, cls=true, quantize=true, chunk_texels=1024, progress=None))]
#[allow(clippy::too_many_arguments)]
pub fn fit_sh_native<'py>(
    py: Python<'py>,
    data: &Bound<'py, PyAny>,
    views: &Bound<'py, PyAny>,
    lights: &Bound<'py, PyAny>,
    mask: Option<&Bound<'py, PyAny>>,
    light_coeffs: usize,
    view_coeffs: usize,
    cls: bool,
    quantize: bool,
    chunk_texels: usize,
    progress: Option<&Bound<'py, PyAny>>,
) -> PyResult<(PyModel, Bound<'py, PyDict>)> {
    let opts = ShOptions { light_coeffs, view_coeffs, cls, quantize, chunk_texels };
    let m = run_fit(py, data, views, lights, mask, progress, |b, mon| btfrs_fit::fit_sh(b, &opts, mon))?;
    let d = PyDict::new(py);
    d.set_item("constrained_fraction", m.constrained_fraction)?;
    d.set_item("mean_lambda", m.mean_lambda)?;
    Ok((PyModel { inner: AnyModel::Sh(m) }, d))
}

/// Fit Local PCA; returns the model and a report dict.
#[pyfunction]
#[pyo3(signature = (data, views, lights, mask=None, clusters=32, components=4, kmeans_iterations=25, refine_iterations=2, reduced_dims=64, seed=0, progress=None))]
#[allow(clippy::too_many_arguments)]
pub fn fit_lpca_native<'py>(
    py: Python<'py>,
    data: &Bound<'py, PyAny>,
    views: &Bound<'py, PyAny>,
    lights: &Bound<'py, PyAny>,
    mask: Option<&Bound<'py, PyAny>>,
    clusters: usize,
    components: usize,
    kmeans_iterations: usize,
    refine_iterations: usize,
    reduced_dims: usize,
    seed: u64,
    progress: Option<&Bound<'py, PyAny>>,
) -> PyResult<(PyModel, Bound<'py, PyDict>)> {
    let opts = LpcaOptions { clusters, components, kmeans_iterations, refine_iterations, reduced_dims, seed };
    let m = run_fit(py, data, views, lights, mask, progress, |b, mon| btfrs_fit::fit_lpca(b, &opts, mon))?;
    let d = PyDict::new(py);
    d.set_item("clusters", m.clusters)?;
    d.set_item("components", m.components)?;
    Ok((PyModel { inner: AnyModel::Lpca(m) }, d))
}
