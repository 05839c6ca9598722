//! Bindings of `btfrs-kcoherence`: the analysis as a Python object, the synthesis methods and
//! the quality measures. Coordinate maps cross as `[H, W, 2]` `uint16` `(x, y)` arrays.

use crate::arrays::{borrow, check_shape};
use crate::core::BtfArgs;
use crate::errors::{arg, IntoPy};
use crate::models::{arrays_dict, named_arrays};
use crate::run::{detach, monitored};
use btfrs_kcoherence::{
    jump_map, kcoherence, quality, textures, Analysis, AnalysisOptions, CoordMap, FeatureMode, Features, JumpOptions,
    Level, QualityOptions, SynthOptions,
};
use numpy::{IntoPyArray, PyArray3, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// A texton analysis of a sample (see `btfrs.synth.Analysis`).
#[derive(Debug)]
#[pyclass(name = "Analysis", module = "btfrs._native")]
pub struct PyAnalysis {
    inner: Analysis,
}

/// Similar-neighbourhood indices and distances, `[H, W, m]` each.
type Similar<'py> = (Bound<'py, PyArray3<i32>>, Bound<'py, PyArray3<f32>>);

fn map_to_py<'py>(py: Python<'py>, m: CoordMap) -> PyResult<Bound<'py, PyArray3<u16>>> {
    m.to_xy().into_pyarray(py).reshape([m.height, m.width, 2])
}

impl PyAnalysis {
    fn level(&self, level: usize) -> PyResult<&Level> {
        self.inner
            .levels
            .get(level)
            .ok_or_else(|| arg("level", format!("expected 0 to {}, got {level}", self.inner.levels.len() - 1)))
    }
}

#[pymethods]
impl PyAnalysis {
    /// Rows of the sample.
    #[getter]
    fn height(&self) -> usize {
        self.inner.size().0
    }

    /// Columns of the sample.
    #[getter]
    fn width(&self) -> usize {
        self.inner.size().1
    }

    /// Pyramid levels.
    #[getter]
    fn levels(&self) -> usize {
        self.inner.levels.len()
    }

    /// Textons per level, finest first.
    #[getter]
    fn textons(&self) -> Vec<usize> {
        self.inner.levels.iter().map(|l| l.textons.count()).collect()
    }

    /// Length of the appearance vectors.
    #[getter]
    fn dim(&self) -> usize {
        self.inner.levels[0].textons.dim
    }

    /// Similar neighbourhoods kept per pixel.
    #[getter]
    fn m(&self) -> usize {
        self.inner.m
    }

    /// `(radius, levels)` of every neighbourhood set computed so far.
    #[getter]
    fn neighbourhoods(&self) -> Vec<(usize, usize)> {
        let mut radii: Vec<usize> = self.inner.levels[0].neighbours.iter().map(|n| n.radius).collect();
        radii.sort_unstable();
        radii
            .into_iter()
            .map(|r| (r, self.inner.levels.iter().take_while(|l| l.neighbours(r).is_some()).count()))
            .collect()
    }

    /// The options the analysis was made with.
    fn options<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let o = &self.inner.options;
        let d = PyDict::new(py);
        d.set_item("textons", o.textons)?;
        d.set_item("levels", o.levels)?;
        d.set_item("m", o.m)?;
        d.set_item("iterations", o.iterations)?;
        d.set_item("seed", o.seed)?;
        Ok(d)
    }

    /// `[H, W]` texton of every pixel of a level.
    fn texton_map<'py>(&self, py: Python<'py>, level: usize) -> PyResult<Bound<'py, numpy::PyArray2<u16>>> {
        let lv = self.level(level)?;
        lv.textons.assign.clone().into_pyarray(py).reshape([lv.height, lv.width])
    }

    /// `[T, T]` texton dot products (the paper's matrix M) of a level.
    fn dots<'py>(&self, py: Python<'py>, level: usize) -> PyResult<Bound<'py, numpy::PyArray2<f64>>> {
        let lv = self.level(level)?;
        let t = lv.textons.count();
        // Parallel work: inside the per-process pool (a forked child has no global pool threads).
        let d = detach(py, || Ok(lv.textons.dots()))?;
        d.into_pyarray(py).reshape([t, t])
    }

    /// `[T, T]` texton squared distances of a level.
    fn distances<'py>(&self, py: Python<'py>, level: usize) -> PyResult<Bound<'py, numpy::PyArray2<f32>>> {
        let lv = self.level(level)?;
        let t = lv.textons.count();
        lv.textons.dist.clone().into_pyarray(py).reshape([t, t])
    }

    /// `([H, W, m] int32 indices (-1: none), [H, W, m] float32 distances)` of a level's similar
    /// neighbourhoods for a radius.
    fn similar<'py>(&self, py: Python<'py>, neighbourhood: usize, level: usize) -> PyResult<Similar<'py>> {
        let lv = self.level(level)?;
        let n = lv.neighbours(neighbourhood).ok_or_else(|| {
            arg("neighbourhood", format!("no similar neighbourhoods of radius {neighbourhood} at level {level}"))
        })?;
        let idx: Vec<i32> = n.index.iter().map(|&i| if i == u32::MAX { -1 } else { i as i32 }).collect();
        let shape = [lv.height, lv.width, n.m];
        Ok((idx.into_pyarray(py).reshape(shape)?, n.dist.clone().into_pyarray(py).reshape(shape)?))
    }

    /// Compute (once) the similar neighbourhoods of `neighbourhood` on levels `first..levels`.
    #[pyo3(signature = (neighbourhood, levels, progress=None, first=0))]
    fn ensure_neighbourhood(
        &mut self,
        py: Python<'_>,
        neighbourhood: usize,
        levels: usize,
        progress: Option<&Bound<'_, PyAny>>,
        first: usize,
    ) -> PyResult<()> {
        let an = &mut self.inner;
        an.check_levels_from(neighbourhood, first, levels).py()?;
        if an.neighbour_units_at(neighbourhood, first, levels) == 0 {
            return Ok(());
        }
        monitored(py, progress, |mon| {
            mon.start(an.neighbour_units_at(neighbourhood, first, levels));
            an.ensure_neighbours_at(neighbourhood, first, levels, mon)
        })
    }

    /// Hierarchical k-coherence synthesis; `[height, width, 2]` uint16 (x, y).
    #[pyo3(signature = (height, width, k, neighbourhood, coarse_neighbourhood, levels, toroidal, seed, progress=None))]
    #[allow(clippy::too_many_arguments)]
    fn kcoherence<'py>(
        &self,
        py: Python<'py>,
        height: usize,
        width: usize,
        k: usize,
        neighbourhood: usize,
        coarse_neighbourhood: usize,
        levels: usize,
        toroidal: bool,
        seed: u64,
        progress: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyArray3<u16>>> {
        let o = SynthOptions {
            height,
            width,
            k,
            radius: neighbourhood,
            coarse_radius: coarse_neighbourhood,
            levels,
            toroidal,
            seed,
        };
        let an = &self.inner;
        let m = monitored(py, progress, |mon| kcoherence(an, &o, mon))?;
        map_to_py(py, m)
    }

    /// Jump-map synthesis; `[height, width, 2]` uint16 (x, y). Progress counts output rows.
    #[pyo3(signature = (height, width, neighbourhood, jump, seed, progress=None))]
    #[allow(clippy::too_many_arguments)]
    fn jump_map<'py>(
        &self,
        py: Python<'py>,
        height: usize,
        width: usize,
        neighbourhood: usize,
        jump: f64,
        seed: u64,
        progress: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyArray3<u16>>> {
        let o = JumpOptions { height, width, radius: neighbourhood, jump, seed };
        let an = &self.inner;
        let m = monitored(py, progress, |mon| jump_map(an, &o, mon))?;
        map_to_py(py, m)
    }

    /// The quality measures of a coordinate map (a dict).
    #[pyo3(signature = (coords, neighbourhood, samples, seed, window=3, scales=3, windows=1024, progress=None))]
    #[allow(clippy::too_many_arguments)]
    fn quality<'py>(
        &self,
        py: Python<'py>,
        coords: &Bound<'py, PyAny>,
        neighbourhood: usize,
        samples: usize,
        seed: u64,
        window: usize,
        scales: usize,
        windows: usize,
        progress: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let c = borrow::<u16>("coords", coords)?;
        check_shape("coords", c.shape(), &[None, None, Some(2)])?;
        let (h, w) = (c.shape()[0], c.shape()[1]);
        let (sh, sw) = self.inner.size();
        let map = CoordMap::from_xy(h, w, c.as_slice().map_err(|e| arg("coords", e))?, sh, sw).py()?;
        drop(c);
        let an = &self.inner;
        let o = QualityOptions { radius: neighbourhood, samples, windows, seed, window, scales };
        let q = monitored(py, progress, |mon| quality(an, &map, &o, mon))?;
        let d = PyDict::new(py);
        d.set_item("structure", q.structure)?;
        d.set_item("structure_levels", q.structure_levels)?;
        d.set_item("seam_error", q.seam_error)?;
        d.set_item("seam_error_p90", q.seam_error_p90)?;
        d.set_item("straddling", q.straddling)?;
        d.set_item("nn_distance", q.nn_distance)?;
        d.set_item("coherence", q.coherence)?;
        d.set_item("seam", q.seam)?;
        d.set_item("seam_mean", q.seam_mean)?;
        d.set_item("repetition", q.repetition)?;
        d.set_item("samples", q.samples)?;
        Ok(d)
    }

    /// Copies of the analysis's arrays, by name (what `Analysis.save` writes; the layout is
    /// defined in btfrs-kcoherence).
    fn arrays<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        arrays_dict(py, self.inner.to_arrays())
    }

    /// Rebuild from `arrays()` and `options()` (validated).
    #[staticmethod]
    fn from_arrays(py: Python<'_>, arrays: &Bound<'_, PyDict>, options: &Bound<'_, PyDict>) -> PyResult<Self> {
        let opt = |k: &str| -> PyResult<u64> {
            let v = options.get_item(k)?.ok_or_else(|| arg("options", format!("missing {k:?}")))?;
            v.extract::<u64>().map_err(|_| arg("options", format!("{k:?} is {v}, not a non-negative integer")))
        };
        let o = AnalysisOptions {
            textons: opt("textons")? as usize,
            levels: opt("levels")? as usize,
            m: opt("m")? as usize,
            iterations: opt("iterations")? as usize,
            seed: opt("seed")?,
        };
        let a = named_arrays(arrays)?;
        // Parallel validation inside the per-process pool, panics caught.
        Ok(Self { inner: detach(py, || Analysis::from_arrays(&a, o))? })
    }
}

fn opts(textons: usize, levels: usize, m: usize, iterations: usize, seed: u64) -> AnalysisOptions {
    AnalysisOptions { textons, levels, m, iterations, seed }
}

/// Analyse a BTF sample.
#[pyfunction]
#[pyo3(signature = (data, views, lights, mask=None, textons=1024, features="pca", dims=48, images=150, levels=3, m=10, neighbourhoods=vec![2], iterations=20, seed=0, memory_limit=None, progress=None))]
#[allow(clippy::too_many_arguments)]
pub fn analyse_btf_native<'py>(
    py: Python<'py>,
    data: &Bound<'py, PyAny>,
    views: &Bound<'py, PyAny>,
    lights: &Bound<'py, PyAny>,
    mask: Option<&Bound<'py, PyAny>>,
    textons: usize,
    features: &str,
    dims: usize,
    images: usize,
    levels: usize,
    m: usize,
    neighbourhoods: Vec<usize>,
    iterations: usize,
    seed: u64,
    memory_limit: Option<u64>,
    progress: Option<&Bound<'py, PyAny>>,
) -> PyResult<PyAnalysis> {
    let mode = match features {
        "pca" => FeatureMode::Pca { dims },
        "all" => FeatureMode::All,
        "images" => FeatureMode::Images { count: images },
        other => return Err(arg("features", format!("expected \"pca\", \"all\" or \"images\", got {other:?}"))),
    };
    let args = BtfArgs::new(data, views, lights, mask)?;
    let b = args.btf()?;
    let o = opts(textons, levels, m, iterations, seed);
    let inner = monitored(py, progress, |mon| {
        mon.set_memory_limit(memory_limit);
        btfrs_core::btf::check_finite("data", b.data)?;
        Analysis::of_btf(&b, mode, o, &neighbourhoods, mon)
    })?;
    Ok(PyAnalysis { inner })
}

/// Analyse a sample given as `[H, W, D]` float32 feature vectors (an RGB texture: D = 3).
#[pyfunction]
#[pyo3(signature = (sample, textons=1024, levels=3, m=10, neighbourhoods=vec![2], iterations=20, seed=0, progress=None))]
#[allow(clippy::too_many_arguments)]
pub fn analyse_features_native<'py>(
    py: Python<'py>,
    sample: &Bound<'py, PyAny>,
    textons: usize,
    levels: usize,
    m: usize,
    neighbourhoods: Vec<usize>,
    iterations: usize,
    seed: u64,
    progress: Option<&Bound<'py, PyAny>>,
) -> PyResult<PyAnalysis> {
    let a = borrow::<f32>("sample", sample)?;
    check_shape("sample", a.shape(), &[None, None, None])?;
    let (h, w, d) = (a.shape()[0], a.shape()[1], a.shape()[2]);
    let data = a.as_slice().map_err(|e| arg("sample", e))?.to_vec();
    drop(a);
    let o = opts(textons, levels, m, iterations, seed);
    let inner = monitored(py, progress, |mon| {
        let f = Features::new(h, w, d, data)?;
        Analysis::of_features(f, o, &neighbourhoods, mon)
    })?;
    Ok(PyAnalysis { inner })
}

/// The names of the structured test textures.
#[pyfunction]
pub fn texture_names() -> Vec<&'static str> {
    textures::NAMES.to_vec()
}

/// A structured test texture, `[height, width, 3]` float32 RGB in [0, 1]; the pattern repeats
/// every `period = (brick rows, bricks per row)`.
#[pyfunction]
pub fn make_texture<'py>(
    py: Python<'py>,
    name: &str,
    height: usize,
    width: usize,
    seed: u64,
    period: (usize, usize),
) -> PyResult<Bound<'py, PyArray3<f32>>> {
    let t = textures::texture(name, height, width, seed, period).py()?;
    t.into_pyarray(py).reshape([height, width, 3])
}
