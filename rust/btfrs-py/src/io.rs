//! Bindings of btfrs-io: the .btfrs container, PTM files and PNG images.

use crate::arrays::{borrow, check_shape};
use crate::errors::{arg, IntoPy};
use crate::models::PyModel;
use crate::run::detach;
use btfrs_io::container::{self, as_bytes, ArrayRef, Dtype};
use btfrs_io::formats;
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
            return Err(crate::errors::arg_type(
                name,
                "expected a C-contiguous numpy array of float32, float64, uint8, uint16, int32 or bool",
            ));
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
}

/// A container's header: (kind, meta JSON, [(name, dtype, shape, offset, finite)]); `finite` is
/// the writer's flag for float arrays (None for integer arrays and older files).
#[pyfunction]
#[allow(clippy::type_complexity)]
pub fn read_container_header(
    path: PathBuf,
) -> PyResult<(String, String, Vec<(String, String, Vec<usize>, u64, Option<bool>)>)> {
    let c = container::read_contents(&path).py()?;
    let arrays = c
        .arrays
        .into_iter()
        .map(|a| {
            let dt = serde_json::to_value(a.dtype).ok().and_then(|v| v.as_str().map(String::from)).unwrap_or_default();
            (a.name, dt, a.shape, a.offset, a.finite)
        })
        .collect();
    Ok((c.kind, c.meta.to_string(), arrays))
}

/// A file format of another tool (`btfrs_io::formats::Format`), by its fields.
#[derive(Debug)]
#[pyclass(name = "ModelFormat", module = "btfrs._native", frozen, get_all)]
pub struct ModelFormat {
    /// The format's name (`"ptm"`), as `model.export(format=...)` takes it.
    pub name: &'static str,
    /// The file extension, without the dot (`"ptm"`).
    pub extension: &'static str,
    /// One line saying what it is.
    pub doc: &'static str,
    /// Written as a folder holding an index file (NeuralRTI's `info.json`) rather than one file.
    pub folder: bool,
    /// The index file of a folder format (`"info.json"`; empty for a one-file format).
    pub index: &'static str,
}

#[pymethods]
impl ModelFormat {
    fn __repr__(&self) -> String {
        format!(
            "ModelFormat(name={:?}, extension={:?}, folder={}, index={:?})",
            self.name,
            self.extension,
            if self.folder { "True" } else { "False" },
            self.index
        )
    }
}

/// The file formats of other tools (btfrs_io::formats).
#[pyfunction]
pub fn model_formats() -> Vec<ModelFormat> {
    formats::FORMATS
        .iter()
        .map(|f| ModelFormat { name: f.name, extension: f.extension, doc: f.doc, folder: f.folder, index: f.index })
        .collect()
}

/// Write view slot `view` of a model as `format` (one of its registry exports); returns what
/// the writer chose (scales and biases) as JSON.
#[pyfunction]
#[pyo3(signature = (path, model, format, view, force=false))]
pub fn export_model(
    py: Python<'_>,
    path: PathBuf,
    model: &PyModel,
    format: &str,
    view: usize,
    force: bool,
) -> PyResult<String> {
    Ok(detach(py, || formats::export(model.inner.as_ref(), format, view, &path, force))?.to_string())
}

/// Write view slot `view` of a model as a format's tiled layout (Deep Zoom pyramids of its
/// images) into the folder `path`, atomically (a temporary folder renamed); `progress(done,
/// total)` counts tiles. Returns the writer's JSON.
#[pyfunction]
#[pyo3(signature = (path, model, format, view, force, tile_size, overlap, tile_format, quality, progress=None))]
#[allow(clippy::too_many_arguments)]
pub fn export_tiled(
    py: Python<'_>,
    path: PathBuf,
    model: &PyModel,
    format: &str,
    view: usize,
    force: bool,
    tile_size: usize,
    overlap: usize,
    tile_format: &str,
    quality: u8,
    progress: Option<Bound<'_, PyAny>>,
) -> PyResult<String> {
    let tiling = btfrs_io::deepzoom::Tiling { tile_size, overlap, format: tile_format.to_string(), quality };
    let out = crate::run::monitored(py, progress.as_ref(), |m| {
        formats::export_tiled(model.inner.as_ref(), format, view, &path, force, &tiling, m)
    })?;
    Ok(out.to_string())
}

/// The plane images of a relight or NeuralRTI folder (names without extension), the planes
/// they hold, and its index's facts: `(images, planes, width, height, type, tile_size,
/// levels)` (the last two 0 where the folder notes no pyramid).
#[pyfunction]
#[allow(clippy::type_complexity)]
pub fn plane_images(
    py: Python<'_>,
    path: PathBuf,
) -> PyResult<(Vec<String>, usize, usize, usize, String, usize, usize)> {
    let limits = btfrs_io::capture::Limits { max_bytes: btfrs_io::capture::default_max_bytes(), allow_outside: false };
    let f = detach(py, || btfrs_io::relight_file::plane_images(&path, &limits))?;
    Ok((f.images, f.planes, f.width, f.height, f.kind, f.tile_size, f.levels))
}

/// The model a relight or NeuralRTI folder's `info.json` makes with other plane bytes: `planes`
/// uint8 `[height, width, nplanes]` (the images' channels in order).
#[pyfunction]
pub fn model_with_planes(py: Python<'_>, path: PathBuf, planes: &Bound<'_, PyAny>) -> PyResult<PyModel> {
    let a = borrow::<u8>("planes", planes)?;
    check_shape("planes", a.shape(), &[None, None, None])?;
    let (h, w) = (a.shape()[0], a.shape()[1]);
    let q = a.as_slice().map_err(|e| arg("planes", e))?.to_vec();
    let limits = btfrs_io::capture::Limits { max_bytes: btfrs_io::capture::default_max_bytes(), allow_outside: false };
    let inner = detach(py, || btfrs_io::relight_file::with_planes(&path, w, h, q, &limits))?;
    Ok(PyModel { inner, robust: serde_json::Value::Null })
}

/// Read a file of another tool's format (by its extension) as a one-slot model, within
/// `max_bytes` (default: half the machine's memory): `(model, warnings)`, the warnings naming
/// values the reader changed.
#[pyfunction]
#[pyo3(signature = (path, max_bytes=None))]
pub fn import_model(py: Python<'_>, path: PathBuf, max_bytes: Option<u64>) -> PyResult<(PyModel, Vec<String>)> {
    let limits = btfrs_io::capture::Limits {
        max_bytes: max_bytes.unwrap_or_else(btfrs_io::capture::default_max_bytes),
        allow_outside: false,
    };
    let got = detach(py, || formats::import(&path, &limits))?;
    Ok((PyModel { inner: got.model, robust: serde_json::Value::Null }, got.warnings))
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

/// What a capture loader returns to Python: (data or None when written to a file, views,
/// lights, mask or None, meta JSON).
type Loaded<'py> = (
    Option<Bound<'py, PyArrayDyn<f32>>>,
    Bound<'py, PyArrayDyn<f64>>,
    Bound<'py, PyArrayDyn<f64>>,
    Option<Bound<'py, PyArrayDyn<bool>>>,
    String,
);

/// Open a measured capture (`kind`: "ubo2003", "lp", "table", "ubo2014") and decode it into
/// memory, or into the `.btfrs` file `mmap_to`. `crop` is (row, col, rows, cols); `memory_limit`
/// bounds the decoded photographs held in memory (the rest wait in a temporary file).
#[pyfunction]
#[pyo3(signature = (kind, path, table=None, crop=None, views=None, lights=None, linear=false, mmap_to=None, progress=None, max_bytes=None, allow_outside=false, memory_limit=None))]
#[allow(clippy::too_many_arguments)]
pub fn load_capture<'py>(
    py: Python<'py>,
    kind: &str,
    path: PathBuf,
    table: Option<PathBuf>,
    crop: Option<(usize, usize, usize, usize)>,
    views: Option<Vec<usize>>,
    lights: Option<Vec<usize>>,
    linear: bool,
    mmap_to: Option<PathBuf>,
    progress: Option<Bound<'py, PyAny>>,
    max_bytes: Option<u64>,
    allow_outside: bool,
    memory_limit: Option<u64>,
) -> PyResult<Loaded<'py>> {
    use btfrs_io::capture::{self, Crop, Limits, Selection, Source};
    let limits = Limits { max_bytes: max_bytes.unwrap_or_else(capture::default_max_bytes), allow_outside };
    let shown = path.display().to_string();
    use btfrs_io::decode::Transfer;
    let sel = Selection { crop: crop.map(|(row, col, rows, cols)| Crop { row, col, rows, cols }), views, lights };
    let transfer = if linear { Transfer::Linear } else { Transfer::Srgb };
    let kind = kind.to_string();
    let source: Box<dyn Source + Send> = detach(py, || -> btfrs_core::Result<Box<dyn Source + Send>> {
        Ok(match kind.as_str() {
            "ubo2003" => Box::new(btfrs_io::ubo2003::open_limited(&path, &sel, transfer, &limits)?),
            "lp" => Box::new(btfrs_io::rti::open_lp_limited(&path, &sel, transfer, &limits)?),
            "ubo2014" => Box::new(btfrs_io::ubo2014::Ubo2014::open(&path, &sel)?),
            "table" => {
                let t =
                    table.as_deref().ok_or_else(|| btfrs_core::Error::arg("directions", "expected a table file"))?;
                let folder = if path.is_dir() { Some(path.as_path()) } else { None };
                Box::new(btfrs_io::stack::open_table_limited(t, folder, &sel, transfer, &limits)?)
            }
            other => return Err(btfrs_core::Error::arg("kind", format!("unknown capture kind {other:?}"))),
        })
    })?;
    let cap = source.capture().clone();
    let data = match &mmap_to {
        Some(out) => {
            crate::run::monitored(py, progress.as_ref(), |m| {
                m.set_memory_limit(memory_limit);
                capture::load_to_file(source.as_ref(), out, m)
            })?;
            None
        }
        None => {
            let v = crate::run::monitored(py, progress.as_ref(), |m| {
                m.set_memory_limit(memory_limit);
                capture::load_within(source.as_ref(), &shown, limits.max_bytes, m)
            })?;
            let shape = [cap.height, cap.width, cap.views.len(), cap.lights.len(), 3];
            Some(v.into_pyarray(py).reshape(shape.to_vec())?)
        }
    };
    let d = |x: &[[f64; 3]]| -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        x.iter().flatten().copied().collect::<Vec<f64>>().into_pyarray(py).reshape(vec![x.len(), 3])
    };
    let mask = match &cap.mask {
        Some(m) => Some(m.clone().into_pyarray(py).reshape(vec![cap.views.len(), cap.lights.len()])?),
        None => None,
    };
    Ok((data, d(&cap.views)?, d(&cap.lights)?, mask, cap.meta.to_string()))
}

/// Write `[H, W]` or `[H, W, 3]` float32 values in [0, 1] as a 16-bit PNG (no sRGB curve).
#[pyfunction]
pub fn write_png16(py: Python<'_>, path: PathBuf, values: &Bound<'_, PyAny>) -> PyResult<()> {
    let a = borrow::<f32>("values", values)?;
    let sh = a.shape().to_vec();
    let channels = match sh.len() {
        2 => 1,
        3 if sh[2] == 3 => 3,
        _ => return Err(arg("values", format!("expected [H, W] or [H, W, 3], got shape {sh:?}"))),
    };
    let s = a.as_slice().map_err(|e| arg("values", e))?;
    detach(py, || btfrs_io::image::write_png16(&path, s, sh[1], sh[0], channels))
}

/// Write `[C, H, W]` float32 planes as one OpenEXR layer with channel names `names`.
#[pyfunction]
pub fn write_exr_channels(
    py: Python<'_>,
    path: PathBuf,
    names: Vec<String>,
    planes: &Bound<'_, PyAny>,
) -> PyResult<()> {
    let a = borrow::<f32>("planes", planes)?;
    check_shape("planes", a.shape(), &[Some(names.len()), None, None])?;
    let (h, w) = (a.shape()[1], a.shape()[2]);
    let s = a.as_slice().map_err(|e| arg("planes", e))?;
    let chans: Vec<(String, Vec<f32>)> =
        names.into_iter().enumerate().map(|(i, n)| (n, s[i * h * w..(i + 1) * h * w].to_vec())).collect();
    detach(py, || btfrs_io::image::write_exr_channels(&path, w, h, &chans))
}
