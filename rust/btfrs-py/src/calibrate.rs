//! Bindings of btfrs-calibrate: light calibration from a reflective sphere, and `.lp` files.

use crate::errors::arg;
use crate::run::{detach, guarded, monitored};
use btfrs_calibrate::{calibrate, lp, Input, Options, Projection};
use btfrs_io::decode::Transfer;
use pyo3::prelude::*;
use std::path::PathBuf;

/// Calibrate the photographs of `folder` (every image in it) or `files`: the report as JSON
/// (`btfrs_calibrate::Calibration`).
#[pyfunction]
#[pyo3(signature = (folder=None, files=None, sphere=None, fov=None, focal=None, white=None, linear=false, progress=None))]
#[allow(clippy::too_many_arguments)]
pub fn calibrate_sphere(
    py: Python<'_>,
    folder: Option<PathBuf>,
    files: Option<Vec<PathBuf>>,
    sphere: Option<(f64, f64, f64)>,
    fov: Option<f64>,
    focal: Option<f64>,
    white: Option<(usize, usize, usize, usize)>,
    linear: bool,
    progress: Option<Bound<'_, PyAny>>,
) -> PyResult<String> {
    let input = guarded(|| match (folder, files) {
        (Some(d), None) => Ok(Input::Folder(d)),
        (None, Some(f)) => Ok(Input::Files(f)),
        _ => Err(arg("images", "expected a folder or a list of files")),
    })?;
    let projection = match (fov, focal) {
        (None, None) => Projection::Orthographic,
        (Some(f), None) => Projection::FieldOfView(f),
        (None, Some(f)) => Projection::Focal35mm(f),
        (Some(_), Some(_)) => return Err(arg("fov", "give the field of view or the focal length, not both")),
    };
    let opts = Options {
        sphere: sphere.map(|(x, y, r)| [x, y, r]),
        projection,
        white: white.map(|(r, c, h, w)| [r, c, h, w]),
        transfer: if linear { Transfer::Linear } else { Transfer::Srgb },
    };
    let cal = monitored(py, progress.as_ref(), |m| calibrate(&input, &opts, m))?;
    guarded(|| serde_json::to_string(&cal).map_err(|e| crate::errors::InternalError::new_err(e.to_string())))
}

/// Write an `.lp` file (atomically): one `name lx ly lz` line per light after the count.
#[pyfunction]
pub fn write_lp(py: Python<'_>, path: PathBuf, names: Vec<String>, lights: Vec<(f64, f64, f64)>) -> PyResult<()> {
    if names.len() != lights.len() {
        return Err(arg(
            "lights",
            format!("{} names but {} lights; expected one light per name", names.len(), lights.len()),
        ));
    }
    let entries: Vec<(String, [f64; 3])> = names.into_iter().zip(lights).map(|(n, (x, y, z))| (n, [x, y, z])).collect();
    detach(py, || lp::write_lp(&path, &entries))
}
