//! Bindings of btfrs-io: the .btfrs container, PTM files and PNG images.

use crate::arrays::{borrow, check_shape};
use crate::errors::{arg, IntoPy};
use crate::fit::PyPtm;
use crate::run::{detach, guarded};
use btfrs_fit::PtmKind;
use btfrs_io::container::{self, as_bytes, ArrayRef, Dtype};
use btfrs_io::ptm_file::{self, PtmFormat, PtmImage};
use numpy::{IntoPyArray, PyArrayDyn, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::prelude::*;
use std::path::PathBuf;

/// Save named arrays and JSON metadata as one `.btfrs` file (atomically).
#[pyfunction]
pub fn save_container(
    py: Python<'_>,
    path: PathBuf,
    kind: &str,
    meta_json: &str,
    arrays: Vec<(String, Bound<'_, PyAny>)>,
) -> PyResult<()> {
    guarded(|| {
        let meta: serde_json::Value = serde_json::from_str(meta_json).map_err(|e| arg("meta", e))?;
        // Borrow every array as bytes (no copy) with its dtype.
        enum Held<'py> {
            F32(numpy::PyReadonlyArrayDyn<'py, f32>),
            F64(numpy::PyReadonlyArrayDyn<'py, f64>),
            U8(numpy::PyReadonlyArrayDyn<'py, u8>),
            U16(numpy::PyReadonlyArrayDyn<'py, u16>),
            I32(numpy::PyReadonlyArrayDyn<'py, i32>),
            Bool(numpy::PyReadonlyArrayDyn<'py, bool>),
        }
        let mut held = Vec::with_capacity(arrays.len());
        for (name, a) in &arrays {
            let h = if let Ok(x) = borrow::<f32>(name, a) {
                Held::F32(x)
            } else if let Ok(x) = borrow::<f64>(name, a) {
                Held::F64(x)
            } else if let Ok(x) = borrow::<u8>(name, a) {
                Held::U8(x)
            } else if let Ok(x) = borrow::<u16>(name, a) {
                Held::U16(x)
            } else if let Ok(x) = borrow::<i32>(name, a) {
                Held::I32(x)
            } else if let Ok(x) = borrow::<bool>(name, a) {
                Held::Bool(x)
            } else {
                return Err(pyo3::exceptions::PyTypeError::new_err(format!(
                    "{name}: expected a C-contiguous numpy array of float32, float64, uint8, uint16, int32 or bool"
                )));
            };
            held.push((name.as_str(), h));
        }
        let mut refs = Vec::with_capacity(held.len());
        for (name, h) in &held {
            macro_rules! r {
                ($a:expr, $d:expr) => {{
                    let s = $a.as_slice().map_err(|e| arg(name, e))?;
                    ArrayRef { name, dtype: $d, shape: $a.shape(), bytes: as_bytes(s) }
                }};
            }
            refs.push(match h {
                Held::F32(a) => r!(a, Dtype::F32),
                Held::F64(a) => r!(a, Dtype::F64),
                Held::U8(a) => r!(a, Dtype::U8),
                Held::U16(a) => r!(a, Dtype::U16),
                Held::I32(a) => r!(a, Dtype::I32),
                Held::Bool(a) => {
                    let s = a.as_slice().map_err(|e| arg(name, e))?;
                    // SAFETY: numpy bools are one byte holding 0 or 1.
                    let b = unsafe { std::slice::from_raw_parts(s.as_ptr() as *const u8, s.len()) };
                    ArrayRef { name, dtype: Dtype::Bool, shape: a.shape(), bytes: b }
                }
            });
        }
        detach(py, || container::write(&path, kind, meta, &refs))
    })
}

/// A container's header: (kind, meta JSON, [(name, dtype, shape, offset)]).
#[pyfunction]
#[allow(clippy::type_complexity)]
pub fn read_container_header(
    py: Python<'_>,
    path: PathBuf,
) -> PyResult<(String, String, Vec<(String, String, Vec<usize>, u64)>)> {
    let c = detach(py, || container::read_contents(&path))?;
    let arrays = c
        .arrays
        .into_iter()
        .map(|a| {
            let dt = serde_json::to_value(a.dtype).ok().and_then(|v| v.as_str().map(String::from)).unwrap_or_default();
            (a.name, dt, a.shape, a.offset)
        })
        .collect();
    Ok((c.kind, c.meta.to_string(), arrays))
}

/// Write one view slot of a PTM as a `.ptm` file; returns (scale, bias) per coefficient index.
#[pyfunction]
pub fn write_ptm(py: Python<'_>, path: PathBuf, model: &PyPtm, view: usize) -> PyResult<(Vec<f32>, Vec<i32>)> {
    guarded(|| {
        let p = &model.inner;
        let nv = p.views.len();
        if view >= nv {
            return Err(arg("view", format!("expected a view slot index in [0, {nv}), got {view}")));
        }
        let (h, w) = (p.height, p.width);
        let (format, coeffs, rgb) = match p.kind {
            PtmKind::Rgb => {
                let c: Vec<f32> =
                    (0..h * w).flat_map(|t| p.coeffs[(t * nv + view) * 18..][..18].iter().copied()).collect();
                (PtmFormat::Rgb, c, None)
            }
            PtmKind::Lrgb => {
                let c: Vec<f32> =
                    (0..h * w).flat_map(|t| p.coeffs[(t * nv + view) * 6..][..6].iter().copied()).collect();
                let r = p.rgb.as_ref().expect("validated");
                let b: Vec<f32> = (0..h * w).flat_map(|t| r[(t * nv + view) * 3..][..3].iter().copied()).collect();
                (PtmFormat::Lrgb, c, Some(b))
            }
        };
        let img = PtmImage { width: w, height: h, format, coeffs, rgb };
        let q = detach(py, || ptm_file::write_ptm(&path, &img))?;
        Ok((q.scale.to_vec(), q.bias.to_vec()))
    })
}

/// Read a `.ptm` file as a one-slot model (view = the normal).
#[pyfunction]
pub fn read_ptm(py: Python<'_>, path: PathBuf) -> PyResult<PyPtm> {
    let img = detach(py, || ptm_file::read_ptm(&path))?;
    let kind = match img.format {
        PtmFormat::Rgb => PtmKind::Rgb,
        PtmFormat::Lrgb => PtmKind::Lrgb,
    };
    let inner = btfrs_fit::Ptm {
        kind,
        height: img.height,
        width: img.width,
        views: vec![[0.0, 0.0, 1.0]],
        coeffs: img.coeffs,
        rgb: img.rgb,
    };
    inner.validate().py()?;
    Ok(PyPtm { inner })
}

/// Write a `[H, W, 3]` float32 linear image as an 8-bit sRGB PNG.
#[pyfunction]
#[pyo3(signature = (path, image, exposure=1.0))]
pub fn write_png(py: Python<'_>, path: PathBuf, image: &Bound<'_, PyAny>, exposure: f32) -> PyResult<()> {
    let a = borrow::<f32>("image", image)?;
    check_shape("image", a.shape(), &[None, None, Some(3)])?;
    let (h, w) = (a.shape()[0], a.shape()[1]);
    let s = a.as_slice().map_err(|e| arg("image", e))?;
    detach(py, || btfrs_io::image::write_png(&path, s, w, h, exposure))
}

/// Read an 8-bit PNG as a `[H, W, 3]` float32 linear image.
#[pyfunction]
pub fn read_png(py: Python<'_>, path: PathBuf) -> PyResult<Bound<'_, PyArrayDyn<f32>>> {
    let (v, w, h) = detach(py, || btfrs_io::image::read_png(&path))?;
    v.into_pyarray(py).reshape(vec![h, w, 3])
}

/// Write a `[H, W, 3]` float32 linear image as a float OpenEXR file.
#[pyfunction]
pub fn write_exr(py: Python<'_>, path: PathBuf, image: &Bound<'_, PyAny>) -> PyResult<()> {
    let a = borrow::<f32>("image", image)?;
    check_shape("image", a.shape(), &[None, None, Some(3)])?;
    let (h, w) = (a.shape()[0], a.shape()[1]);
    let s = a.as_slice().map_err(|e| arg("image", e))?;
    detach(py, || btfrs_io::image::write_exr(&path, s, w, h))
}

/// Read an OpenEXR file's first RGB(A) layer as a `[H, W, 3]` float32 image.
#[pyfunction]
pub fn read_exr(py: Python<'_>, path: PathBuf) -> PyResult<Bound<'_, PyArrayDyn<f32>>> {
    let (v, w, h) = detach(py, || btfrs_io::image::read_exr(&path))?;
    v.into_pyarray(py).reshape(vec![h, w, 3])
}
