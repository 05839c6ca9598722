//! Bindings of `btfrs-wang` (graph-cut Wang tile sets): features of a model, synthesis, the
//! BTFel table, tilings and the seam measure. Translation only.

use crate::arrays::{borrow, check_shape};
use crate::errors::arg;
use crate::models::PyModel;
use crate::run::{detach, monitored};
use btfrs_wang::{features, seams, table, tiles, tiling, Features, Table, WangOptions};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArray3, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;

fn features_of(sample: &Bound<'_, PyAny>) -> PyResult<Features> {
    let a = borrow::<f32>("sample", sample)?;
    check_shape("sample", a.shape(), &[None, None, None])?;
    let (h, w, d) = (a.shape()[0], a.shape()[1], a.shape()[2]);
    let data = a.as_slice().map_err(|e| arg("sample", e))?.to_vec();
    Features::new(h, w, d, data).map_err(crate::errors::to_py)
}

/// The synthesis features of a model, `[H, W, D]`, and the name of the domain used
/// (`domain`: "auto", "coefficients" or "decoded").
#[pyfunction]
pub fn wang_model_features<'py>(
    py: Python<'py>,
    model: &PyModel,
    domain: &str,
) -> PyResult<(Bound<'py, PyArray3<f32>>, String)> {
    let (f, name) = detach(py, || features::model_features(model.inner.as_ref(), domain))?;
    let (h, w, d) = (f.height, f.width, f.dim);
    Ok((f.data.into_pyarray(py).reshape([h, w, d])?, name.to_string()))
}

/// What a synthesis returns: sample texels `[n, w, w]`, colours `[n, 4]`, the BTFel table
/// `[N]`, its per-tile indices `[n, w, w]`, the canonical atlas `[A w, A w]`, the report (JSON).
type Synthesized<'py> = (
    Bound<'py, PyArray3<u32>>,
    Bound<'py, PyArray2<u8>>,
    Bound<'py, PyArray1<u32>>,
    Bound<'py, PyArray3<u32>>,
    Bound<'py, PyArray2<u32>>,
    String,
);

/// Synthesize a complete Wang tile set over a `[H, W, D]` feature sample.
#[pyfunction]
#[pyo3(signature = (sample, options, progress=None))]
pub fn wang_synthesize<'py>(
    py: Python<'py>,
    sample: &Bound<'py, PyAny>,
    options: &Bound<'py, PyDict>,
    progress: Option<&Bound<'py, PyAny>>,
) -> PyResult<Synthesized<'py>> {
    let f = features_of(sample)?;
    let o = crate::values::options(Some(options))?;
    let opts: WangOptions = btfrs_fit::options::from_serde(&o.values).map_err(|e| crate::errors::to_py(o.spell(e)))?;
    let (set, tab) = monitored(py, progress, |mon| {
        let set = tiles::synthesize(&f, &opts, mon)?;
        let tab = Table::new(&set);
        Ok((set, tab))
    })?;
    let (n, w) = (set.texels.len(), set.tile);
    let report = serde_json::json!({
        "steps": set.steps,
        "pair_scale": set.pair_scale,
        "matching_variance": set.matching_variance,
        "options": opts,
    });
    let side = tab.atlas_tiles * w;
    Ok((
        set.texels.concat().into_pyarray(py).reshape([n, w, w])?,
        set.codes.concat().into_pyarray(py).reshape([n, 4])?,
        tab.btfels.into_pyarray(py),
        tab.tiles.concat().into_pyarray(py).reshape([n, w, w])?,
        tab.atlas.into_pyarray(py).reshape([side, side])?,
        report.to_string(),
    ))
}

/// A stochastic valid Wang tiling `[rows, cols]` of tile ids.
#[pyfunction]
#[pyo3(signature = (colors, rows, cols, seed, wrap_cols=false, wrap_rows=false, allowed=None))]
#[allow(clippy::too_many_arguments)]
pub fn wang_tiling<'py>(
    py: Python<'py>,
    colors: usize,
    rows: usize,
    cols: usize,
    seed: u64,
    wrap_cols: bool,
    wrap_rows: bool,
    allowed: Option<Vec<usize>>,
) -> PyResult<Bound<'py, PyArray2<u32>>> {
    let t = detach(py, || tiling::tiling(colors, rows, cols, seed, (wrap_cols, wrap_rows), allowed.as_deref()))?;
    t.into_pyarray(py).reshape([rows, cols])
}

/// Check a layout `[rows, cols]` of tile ids: raises naming the first mismatching cell.
#[pyfunction]
#[pyo3(signature = (colors, layout, wrap_cols=false, wrap_rows=false))]
pub fn wang_check(
    py: Python<'_>,
    colors: usize,
    layout: &Bound<'_, PyAny>,
    wrap_cols: bool,
    wrap_rows: bool,
) -> PyResult<()> {
    let a = borrow::<u32>("layout", layout)?;
    check_shape("layout", a.shape(), &[None, None])?;
    let (r, c) = (a.shape()[0], a.shape()[1]);
    let v = a.as_slice().map_err(|e| arg("layout", e))?.to_vec();
    detach(py, || tiling::check(colors, r, c, &v, (wrap_cols, wrap_rows)))
}

/// Atlas (row, column) in tiles of every tile id of a `colors` set, `[colors^4, 2]`.
#[pyfunction]
pub fn wang_atlas_positions<'py>(py: Python<'py>, colors: usize) -> PyResult<Bound<'py, PyArray2<u32>>> {
    if !(2..=8).contains(&colors) {
        return Err(arg("colors", format!("expected 2 to 8, got {colors}")));
    }
    let n = colors.pow(4);
    let v: Vec<u32> = (0..n)
        .flat_map(|i| {
            let (r, c) = table::atlas_position(i, colors);
            [r as u32, c as u32]
        })
        .collect();
    v.into_pyarray(py).reshape([n, 2])
}

/// Edge and interior window errors of a tiled output `[H, W]` of sample texels.
#[pyfunction]
#[pyo3(signature = (sample, output, tile, window=5, windows=600, seed=0))]
pub fn wang_seam_errors(
    py: Python<'_>,
    sample: &Bound<'_, PyAny>,
    output: &Bound<'_, PyAny>,
    tile: usize,
    window: usize,
    windows: usize,
    seed: u64,
) -> PyResult<(f64, f64)> {
    let f = features_of(sample)?;
    let o = borrow::<u32>("output", output)?;
    check_shape("output", o.shape(), &[None, None])?;
    let (h, w) = (o.shape()[0], o.shape()[1]);
    let v = o.as_slice().map_err(|e| arg("output", e))?.to_vec();
    detach(py, || seams::edge_interior_error(&f, &v, h, w, tile, window, windows, seed))
}

/// Plain tiling of random `tile x tile` crops of a `(height, width)` sample: `[rows tile, cols tile]` texels.
#[pyfunction]
pub fn wang_random_crops<'py>(
    py: Python<'py>,
    height: usize,
    width: usize,
    tile: usize,
    rows: usize,
    cols: usize,
    seed: u64,
) -> PyResult<Bound<'py, PyArray2<u32>>> {
    if tile == 0 || tile > height || tile > width || rows == 0 || cols == 0 {
        return Err(arg("tile", format!("expected 1..={} and a non-empty grid", height.min(width))));
    }
    let v = seams::random_crops((height, width), tile, rows, cols, seed);
    v.into_pyarray(py).reshape([rows * tile, cols * tile])
}
