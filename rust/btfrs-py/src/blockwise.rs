//! Bindings of the blockwise contract ([`btfrs_fit::blockwise`]): what `btfrs.dask` calls on the
//! workers (per texel block) and on the client (reductions, finishing). Every call releases the
//! GIL, so a Dask worker's threads fit blocks in parallel.

use crate::arrays::{borrow, check_shape, dirs};
use crate::core::BtfArgs;
use crate::errors::{arg, to_py, IntoPy};
use crate::models::{named_arrays, PyModel};
use crate::run::{detach, guarded};
use crate::values;
use btfrs_fit::light_bases::Basis;
use btfrs_fit::light_pca::staged as lp;
use btfrs_fit::lpca::{staged, ClusterFit, LpcaOptions};
use btfrs_fit::{registry, srf};
use nalgebra::DMatrix;
use numpy::{IntoPyArray, PyArrayDyn, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;

type F32Array<'py> = Bound<'py, PyArrayDyn<f32>>;
/// One cluster's fit as `lpca_fit_cluster` returns it: `(q, scale, bias, weights)`.
type ClusterFitArgs<'py> = (Bound<'py, PyAny>, Bound<'py, PyAny>, Bound<'py, PyAny>, Bound<'py, PyAny>);

/// A vector as a 1-D numpy array (moved, not copied).
fn vec1<T: numpy::Element>(py: Python<'_>, v: Vec<T>) -> PyResult<Bound<'_, PyArrayDyn<T>>> {
    let n = v.len();
    v.into_pyarray(py).reshape(vec![n])
}

fn mask_of<'a>(
    m: &'a Option<numpy::PyReadonlyArrayDyn<'_, bool>>,
    nv: usize,
    nl: usize,
) -> PyResult<Option<&'a [bool]>> {
    match m {
        Some(m) => {
            check_shape("mask", m.shape(), &[Some(nv), Some(nl)])?;
            Ok(Some(m.as_slice().map_err(|e| arg("mask", e))?))
        }
        None => Ok(None),
    }
}

/// How model `kind` splits over texel blocks: `(strategy, detail, overrides, counts)`:
/// `("texels", "", overrides, report counts)`, `("staged", protocol, {}, [])` or
/// `("unsupported", reason, {}, [])`; `overrides` (a dict) are the options merged into the
/// user's for the per-block fits.
#[pyfunction]
pub fn blockwise_plan<'py>(py: Python<'py>, kind: &str) -> PyResult<BlockwisePlan<'py>> {
    let (strategy, detail, counts) = registry::lookup(kind).py()?.blockwise.describe();
    let (detail, overrides) = match strategy {
        "texels" => ("", btfrs_fit::options::parse_json(detail).py()?),
        _ => (detail, btfrs_fit::options::Values::new()),
    };
    let overrides = values::to_py(py, &serde_json::Value::Object(overrides))?;
    Ok((strategy, detail, overrides, counts))
}

/// What [`blockwise_plan`] returns.
type BlockwisePlan<'py> = (&'static str, &'static str, Bound<'py, PyAny>, &'static [&'static str]);

/// Model `kind` from the stitched arrays of its blocks, finished for the whole fit's options.
#[pyfunction]
pub fn finish_blocks(
    py: Python<'_>,
    kind: &str,
    arrays: &Bound<'_, PyDict>,
    options: &Bound<'_, PyDict>,
) -> PyResult<PyModel> {
    let entry = registry::lookup(kind).py()?;
    let a = named_arrays(arrays)?;
    let o = values::options(Some(options))?;
    let inner = detach(py, || (entry.finish_blocks)(&a, &o.values).map_err(|e| o.spell(e)))?;
    Ok(PyModel { inner, robust: serde_json::Value::Null })
}

/// SRF stage 1 on one block: the per-pair RGB sums of the present values, `[pairs, 3]` float64.
#[pyfunction]
#[pyo3(signature = (data, views, lights, mask=None))]
pub fn srf_sums<'py>(
    py: Python<'py>,
    data: &Bound<'py, PyAny>,
    views: &Bound<'py, PyAny>,
    lights: &Bound<'py, PyAny>,
    mask: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
    let args = BtfArgs::new(data, views, lights, mask)?;
    let b = args.btf()?;
    let s = detach(py, || {
        btfrs_core::btf::check_finite("data", b.data)?;
        srf::mean_sums(&b)
    })?;
    let n = s.len();
    s.into_flattened().into_pyarray(py).reshape(vec![n, 3])
}

/// SRF stage 2: `(phong [7], iterations)` from the sums of every block and their texel count.
#[pyfunction]
#[pyo3(signature = (views, lights, mask, sums, texels))]
pub fn srf_phong<'py>(
    py: Python<'py>,
    views: &Bound<'py, PyAny>,
    lights: &Bound<'py, PyAny>,
    mask: Option<&Bound<'py, PyAny>>,
    sums: &Bound<'py, PyAny>,
    texels: usize,
) -> PyResult<(Vec<f64>, usize)> {
    guarded(|| {
        let (v, l) = (borrow::<f64>("views", views)?, borrow::<f64>("lights", lights)?);
        let m = mask.map(|m| borrow::<bool>("mask", m)).transpose()?;
        let (v, l) = (dirs("views", &v)?, dirs("lights", &l)?);
        let mask = mask_of(&m, v.len(), l.len())?;
        let s = borrow::<f64>("sums", sums)?;
        check_shape("sums", s.shape(), &[None, Some(3)])?;
        let sums: Vec<[f64; 3]> = s.as_slice().map_err(|e| arg("sums", e))?.as_chunks::<3>().0.to_vec();
        let (phong, it) = detach(py, || {
            let geo = srf::PairGeometry::new(v, l, mask)?;
            srf::phong_of_mean(&geo, &sums, texels)
        })?;
        Ok((phong.kd.iter().chain(&phong.ks).chain([&phong.n]).copied().collect(), it))
    })
}

/// SRF stage 3 on one block: `(s [h, w, 3, 3] float32, [phong err², srf err², truth²])`.
#[pyfunction]
#[pyo3(signature = (data, views, lights, mask, phong))]
pub fn srf_residual<'py>(
    py: Python<'py>,
    data: &Bound<'py, PyAny>,
    views: &Bound<'py, PyAny>,
    lights: &Bound<'py, PyAny>,
    mask: Option<&Bound<'py, PyAny>>,
    phong: [f64; 7],
) -> PyResult<(F32Array<'py>, [f64; 3])> {
    let args = BtfArgs::new(data, views, lights, mask)?;
    let b = args.btf()?;
    let p = srf::Phong { kd: [phong[0], phong[1], phong[2]], ks: [phong[3], phong[4], phong[5]], n: phong[6] };
    let (s, sums) = detach(py, || {
        btfrs_core::btf::check_finite("data", b.data)?;
        let geo = srf::PairGeometry::new(b.views, b.lights, b.mask)?;
        srf::residual(&b, &geo, &p, &btfrs_core::Monitor::new())
    })?;
    Ok((s.into_pyarray(py).reshape(vec![b.height, b.width, 3, 3])?, sums))
}

fn lpca_options(options: &Bound<'_, PyDict>) -> PyResult<LpcaOptions> {
    let o = values::options(Some(options))?;
    staged::parse_options(&o.values).map_err(|e| to_py(o.spell(e)))
}

/// `[n, d]` float32 borrowed as a slice with `d`.
fn texel_rows<'a>(name: &str, a: &'a numpy::PyReadonlyArrayDyn<'_, f32>) -> PyResult<(&'a [f32], usize)> {
    check_shape(name, a.shape(), &[None, None])?;
    Ok((a.as_slice().map_err(|e| arg(name, e))?, a.shape()[1]))
}

/// LPCA stage 1a: the texels the range finder samples (uint32, texel order), None for all.
#[pyfunction]
pub fn lpca_sample<'py>(
    py: Python<'py>,
    height: usize,
    width: usize,
    options: &Bound<'_, PyDict>,
) -> PyResult<Option<Bound<'py, PyArrayDyn<u32>>>> {
    let o = lpca_options(options)?;
    let pick = detach(py, || staged::sample(height, width, &o))?;
    pick.map(|p| vec1(py, p)).transpose()
}

/// LPCA stage 1b: `(mu [d], q [l, d])` from the sample's ABRDFs `[s, d]`.
#[pyfunction]
pub fn lpca_subspace<'py>(
    py: Python<'py>,
    sample: &Bound<'py, PyAny>,
    height: usize,
    width: usize,
    options: &Bound<'_, PyDict>,
) -> PyResult<(F32Array<'py>, F32Array<'py>)> {
    let o = lpca_options(options)?;
    let s = borrow::<f32>("sample", sample)?;
    let (x, d) = texel_rows("sample", &s)?;
    let (mu, q) = detach(py, || {
        btfrs_core::btf::check_finite("sample", x)?;
        staged::subspace(x, d, height, width, &o, &btfrs_core::Monitor::new())
    })?;
    let l = q.ncols();
    Ok((vec1(py, mu)?, q.as_slice().to_vec().into_pyarray(py).reshape(vec![l, d])?))
}

/// LPCA stage 2 on one block: its texels' ABRDFs `[n, d]` projected, `[n, l]`.
#[pyfunction]
pub fn lpca_project<'py>(
    py: Python<'py>,
    block: &Bound<'py, PyAny>,
    mu: &Bound<'py, PyAny>,
    q: &Bound<'py, PyAny>,
) -> PyResult<F32Array<'py>> {
    let b = borrow::<f32>("block", block)?;
    let (x, d) = texel_rows("block", &b)?;
    let mu = borrow::<f32>("mu", mu)?;
    let q = borrow::<f32>("q", q)?;
    check_shape("q", q.shape(), &[None, Some(d)])?;
    let l = q.shape()[0];
    let qm = DMatrix::from_column_slice(d, l, q.as_slice().map_err(|e| arg("q", e))?);
    let mu = mu.as_slice().map_err(|e| arg("mu", e))?;
    let z = detach(py, || {
        btfrs_core::btf::check_finite("data", x)?;
        staged::project(x, d, mu, &qm)
    })?;
    let n = z.nrows();
    z.transpose().as_slice().to_vec().into_pyarray(py).reshape(vec![n, l])
}

/// LPCA stage 3: `(ids [T] uint32, [members of each cluster, uint32, texel order])` from the
/// projected texels of all blocks `[T, l]` in texel order.
#[allow(clippy::type_complexity)]
#[pyfunction]
pub fn lpca_cluster<'py>(
    py: Python<'py>,
    z: &Bound<'py, PyAny>,
    height: usize,
    width: usize,
    options: &Bound<'_, PyDict>,
) -> PyResult<(Bound<'py, PyArrayDyn<u32>>, Vec<Bound<'py, PyArrayDyn<u32>>>)> {
    let o = lpca_options(options)?;
    let z = borrow::<f32>("z", z)?;
    let (x, l) = texel_rows("z", &z)?;
    let zm = DMatrix::from_row_slice(x.len() / l.max(1), l, x);
    let (ids, members) = crate::run::monitored(py, None, |mon| staged::cluster(&zm, height, width, &o, mon))?;
    Ok((vec1(py, ids)?, members.into_iter().map(|m| vec1(py, m)).collect::<PyResult<_>>()?))
}

/// LPCA stage 4: cluster `index`'s fit from its members' ABRDFs `[n, d]` (texel order) and
/// their texel indices `[n]` (ascending) in a `height x width` BTF:
/// `(q [c + 1, d] uint8, scale [c + 1], bias [c + 1], weights [n, c + 2])`.
#[allow(clippy::type_complexity, clippy::too_many_arguments)]
#[pyfunction]
pub fn lpca_fit_cluster<'py>(
    py: Python<'py>,
    members: &Bound<'py, PyAny>,
    texels: &Bound<'py, PyAny>,
    height: usize,
    width: usize,
    index: usize,
    options: &Bound<'_, PyDict>,
) -> PyResult<(Bound<'py, PyArrayDyn<u8>>, F32Array<'py>, F32Array<'py>, F32Array<'py>)> {
    let o = lpca_options(options)?;
    let m = borrow::<f32>("members", members)?;
    let (x, d) = texel_rows("members", &m)?;
    let n = x.len() / d.max(1);
    let tx = borrow::<u32>("texels", texels)?;
    let tx = tx.as_slice().map_err(|e| arg("texels", e))?;
    let f = detach(py, || {
        btfrs_core::btf::check_finite("members", x)?;
        staged::fit_cluster_sampled(x, tx, d, height, width, index, &o)
    })?;
    let cc = f.scale.len();
    Ok((
        f.q.into_pyarray(py).reshape(vec![cc, d])?,
        vec1(py, f.scale)?,
        vec1(py, f.bias)?,
        f.weights.into_pyarray(py).reshape(vec![n, cc + 1])?,
    ))
}

/// LPCA stage 5: the model from the clusters and their fits (tuples of [`lpca_fit_cluster`]).
#[pyfunction]
#[pyo3(signature = (height, width, views, lights, mask, ids, members, fits, options))]
#[allow(clippy::too_many_arguments)]
pub fn lpca_assemble<'py>(
    py: Python<'py>,
    height: usize,
    width: usize,
    views: &Bound<'py, PyAny>,
    lights: &Bound<'py, PyAny>,
    mask: Option<&Bound<'py, PyAny>>,
    ids: &Bound<'py, PyAny>,
    members: Vec<Bound<'py, PyAny>>,
    fits: Vec<ClusterFitArgs<'py>>,
    options: &Bound<'_, PyDict>,
) -> PyResult<PyModel> {
    let o = lpca_options(options)?;
    let (v, l) = (borrow::<f64>("views", views)?, borrow::<f64>("lights", lights)?);
    let mk = mask.map(|m| borrow::<bool>("mask", m)).transpose()?;
    let (v, l) = (dirs("views", &v)?, dirs("lights", &l)?);
    let mask = mask_of(&mk, v.len(), l.len())?;
    let ids: Vec<u32> = borrow::<u32>("ids", ids)?.as_array().iter().copied().collect();
    let members: Vec<Vec<u32>> = members
        .iter()
        .map(|m| Ok(borrow::<u32>("members", m)?.as_array().iter().copied().collect()))
        .collect::<PyResult<_>>()?;
    let t = height * width;
    if let Some(bad) = members.iter().flatten().find(|&&i| i as usize >= t) {
        return Err(arg("members", format!("texel {bad} is outside the {height} x {width} BTF")));
    }
    let fits: Vec<ClusterFit> = fits
        .iter()
        .map(|(q, s, b, w)| {
            Ok(ClusterFit {
                q: borrow::<u8>("fits", q)?.as_array().iter().copied().collect(),
                scale: borrow::<f32>("fits", s)?.as_array().iter().copied().collect(),
                bias: borrow::<f32>("fits", b)?.as_array().iter().copied().collect(),
                weights: borrow::<f32>("fits", w)?.as_array().iter().copied().collect(),
            })
        })
        .collect::<PyResult<_>>()?;
    let m = detach(py, || staged::assemble(height, width, v, l, mask, ids, &members, &fits, &o))?;
    Ok(PyModel { inner: Box::new(m), robust: serde_json::Value::Null })
}

/// Moments as they cross into Python: `(n, mean [V, d] float64, m2 [V, d, d] float64)`.
type MomentsArgs<'py> = (u64, Bound<'py, PyArrayDyn<f64>>, Bound<'py, PyArrayDyn<f64>>);

fn basis_of(kind: &str, options: &Bound<'_, PyDict>) -> PyResult<Basis> {
    let o = values::options(Some(options))?;
    Basis::parse(kind, &o.values).map_err(|e| to_py(o.spell(e)))
}

fn moments_to_py(py: Python<'_>, m: lp::Moments) -> PyResult<MomentsArgs<'_>> {
    let nv = m.mean.len() / m.d.max(1);
    Ok((m.n, m.mean.into_pyarray(py).reshape(vec![nv, m.d])?, m.m2.into_pyarray(py).reshape(vec![nv, m.d, m.d])?))
}

fn moments_from_py(m: &MomentsArgs<'_>) -> PyResult<lp::Moments> {
    let (n, mean, m2) = m;
    let (mean, m2) = (mean.readonly(), m2.readonly());
    check_shape("moments", mean.shape(), &[None, None])?;
    let (nv, d) = (mean.shape()[0], mean.shape()[1]);
    check_shape("moments", m2.shape(), &[Some(nv), Some(d), Some(d)])?;
    Ok(lp::Moments {
        n: *n,
        d,
        mean: mean.as_array().iter().copied().collect(),
        m2: m2.as_array().iter().copied().collect(),
    })
}

/// The plan of `basis` for the directions and mask of a BTF given as arrays (stage 1, the GIL
/// released), with the view directions.
fn plan_of<'py>(
    py: Python<'py>,
    basis: &Basis,
    views: &Bound<'py, PyAny>,
    lights: &Bound<'py, PyAny>,
    mask: Option<&Bound<'py, PyAny>>,
) -> PyResult<(btfrs_fit::light_pca::Plan, Vec<[f64; 3]>)> {
    let (v, l) = (borrow::<f64>("views", views)?, borrow::<f64>("lights", lights)?);
    let mk = mask.map(|m| borrow::<bool>("mask", m)).transpose()?;
    let (v, l) = (dirs("views", &v)?, dirs("lights", &l)?);
    let mask = mask_of(&mk, v.len(), l.len())?;
    let plan = detach(py, || basis.plan(v, l, mask))?;
    Ok((plan, v.to_vec()))
}

/// RBF / bilinear stage 2 on one block: the moments of its resampled light functions.
#[pyfunction]
#[pyo3(signature = (kind, data, views, lights, mask, options))]
pub fn light_pca_moments<'py>(
    py: Python<'py>,
    kind: &str,
    data: &Bound<'py, PyAny>,
    views: &Bound<'py, PyAny>,
    lights: &Bound<'py, PyAny>,
    mask: Option<&Bound<'py, PyAny>>,
    options: &Bound<'_, PyDict>,
) -> PyResult<MomentsArgs<'py>> {
    let basis = basis_of(kind, options)?;
    let args = BtfArgs::new(data, views, lights, mask)?;
    let b = args.btf()?;
    let m = detach(py, || {
        btfrs_core::btf::check_finite("data", b.data)?;
        let plan = basis.plan(b.views, b.lights, b.mask)?;
        lp::moments(&b, &plan)
    })?;
    moments_to_py(py, m)
}

/// RBF / bilinear stage 3: two sets of moments as one.
#[pyfunction]
pub fn light_pca_merge<'py>(py: Python<'py>, a: MomentsArgs<'py>, b: MomentsArgs<'py>) -> PyResult<MomentsArgs<'py>> {
    let (a, b) = (moments_from_py(&a)?, moments_from_py(&b)?);
    let m = detach(py, || a.merge(&b))?;
    moments_to_py(py, m)
}

/// RBF / bilinear stage 4: the model's table `[V, n, n, R]` float32 from all texels' moments.
#[pyfunction]
#[pyo3(signature = (kind, moments, views, lights, mask, options))]
pub fn light_pca_table<'py>(
    py: Python<'py>,
    kind: &str,
    moments: MomentsArgs<'py>,
    views: &Bound<'py, PyAny>,
    lights: &Bound<'py, PyAny>,
    mask: Option<&Bound<'py, PyAny>>,
    options: &Bound<'_, PyDict>,
) -> PyResult<F32Array<'py>> {
    let basis = basis_of(kind, options)?;
    let m = moments_from_py(&moments)?;
    let (plan, v) = plan_of(py, &basis, views, lights, mask)?;
    let n_views = v.len();
    let (o, t) = detach(py, || {
        let o = basis.options()?;
        let t = lp::table(&m, &plan, &o)?;
        Ok((o, t))
    })?;
    let r = t.len() / (n_views * o.resolution * o.resolution).max(1);
    t.into_pyarray(py).reshape(vec![n_views, o.resolution, o.resolution, r])
}

/// RBF / bilinear stage 5 on one block: its coefficients `[h, w, V K]` float32.
#[pyfunction]
#[pyo3(signature = (kind, data, views, lights, mask, table, options))]
#[allow(clippy::too_many_arguments)]
pub fn light_pca_project<'py>(
    py: Python<'py>,
    kind: &str,
    data: &Bound<'py, PyAny>,
    views: &Bound<'py, PyAny>,
    lights: &Bound<'py, PyAny>,
    mask: Option<&Bound<'py, PyAny>>,
    table: &Bound<'py, PyAny>,
    options: &Bound<'_, PyDict>,
) -> PyResult<F32Array<'py>> {
    let basis = basis_of(kind, options)?;
    let args = BtfArgs::new(data, views, lights, mask)?;
    let b = args.btf()?;
    let tab = borrow::<f32>("table", table)?;
    let tab = tab.as_slice().map_err(|e| arg("table", e))?;
    let c = detach(py, || {
        btfrs_core::btf::check_finite("data", b.data)?;
        let plan = basis.plan(b.views, b.lights, b.mask)?;
        lp::project(&b, &plan, tab, &basis.options()?)
    })?;
    let per = c.len() / b.texels().max(1);
    c.into_pyarray(py).reshape(vec![b.height, b.width, per])
}

/// RBF / bilinear stage 6: the model from its table and every texel's coefficients `[H, W, V K]`.
#[pyfunction]
#[pyo3(signature = (kind, views, lights, mask, table, coeffs, options))]
#[allow(clippy::too_many_arguments)]
pub fn light_pca_assemble<'py>(
    py: Python<'py>,
    kind: &str,
    views: &Bound<'py, PyAny>,
    lights: &Bound<'py, PyAny>,
    mask: Option<&Bound<'py, PyAny>>,
    table: &Bound<'py, PyAny>,
    coeffs: &Bound<'py, PyAny>,
    options: &Bound<'_, PyDict>,
) -> PyResult<PyModel> {
    let basis = basis_of(kind, options)?;
    let (plan, v) = plan_of(py, &basis, views, lights, mask)?;
    let tab: Vec<f32> = borrow::<f32>("table", table)?.as_array().iter().copied().collect();
    let c = borrow::<f32>("coeffs", coeffs)?;
    check_shape("coeffs", c.shape(), &[None, None, None])?;
    let (h, w) = (c.shape()[0], c.shape()[1]);
    let c = c.as_slice().map_err(|e| arg("coeffs", e))?;
    let inner = detach(py, || {
        let m = lp::assemble(h, w, &v, plan, tab, c, &basis.options()?)?;
        Ok(basis.model(m))
    })?;
    Ok(PyModel { inner, robust: serde_json::Value::Null })
}

/// Check RBF / bilinear options and directions for the blockwise fit (before any task is sent).
#[pyfunction]
#[pyo3(signature = (kind, views, lights, mask, options))]
pub fn light_pca_check<'py>(
    py: Python<'py>,
    kind: &str,
    views: &Bound<'py, PyAny>,
    lights: &Bound<'py, PyAny>,
    mask: Option<&Bound<'py, PyAny>>,
    options: &Bound<'_, PyDict>,
) -> PyResult<()> {
    plan_of(py, &basis_of(kind, options)?, views, lights, mask).map(|_| ())
}

/// `robust_images`' answer: the floor, the spreads, the bad images.
type ImagesOut<'py> = (f32, Bound<'py, PyArrayDyn<f32>>, Vec<(usize, usize)>);
/// `robust_screen_block`'s answer: flat indices and replacements.
type FlagsOut<'py> = (Bound<'py, PyArrayDyn<u64>>, Bound<'py, PyArrayDyn<f32>>);

/// Robust screen, the texels that judge the images and set the floor (flat indices).
#[pyfunction]
pub fn robust_sample_texels(height: usize, width: usize) -> Vec<usize> {
    btfrs_fit::robust::sample_texels(height, width)
}

/// Robust screen on the client: `(floor, spread [V, L], bad images [(view, light)])` from the
/// sampled texels' ABRDFs (`samples`: `[n, 1, V, L, 3]`).
#[pyfunction]
#[pyo3(signature = (samples, views, lights, mask=None))]
pub fn robust_images<'py>(
    py: Python<'py>,
    samples: &Bound<'py, PyAny>,
    views: &Bound<'py, PyAny>,
    lights: &Bound<'py, PyAny>,
    mask: Option<&Bound<'py, PyAny>>,
) -> PyResult<ImagesOut<'py>> {
    let args = BtfArgs::new(samples, views, lights, mask)?;
    let b = args.btf()?;
    let (nv, nl) = (b.views.len(), b.lights.len());
    let all: Vec<usize> = (0..b.height * b.width).collect();
    let im = detach(py, || btfrs_fit::robust::screen_images(b.views, b.lights, b.mask, b.data, &all))?;
    Ok((im.floor, im.spread.into_pyarray(py).reshape(vec![nv, nl])?, im.bad_images))
}

/// Robust screen on the client: the images moved against their neighbours, `(view, light,
/// rows, columns)`, from the ABRDFs of the central patch (`patch`: `[rows, columns, V, L, 3]`,
/// where `robust_patch_window` says).
#[pyfunction]
#[pyo3(signature = (patch, views, lights, mask=None))]
pub fn robust_moved<'py>(
    py: Python<'py>,
    patch: &Bound<'py, PyAny>,
    views: &Bound<'py, PyAny>,
    lights: &Bound<'py, PyAny>,
    mask: Option<&Bound<'py, PyAny>>,
) -> PyResult<Vec<(usize, usize, i32, i32)>> {
    let args = BtfArgs::new(patch, views, lights, mask)?;
    let b = args.btf()?;
    detach(py, || {
        btfrs_fit::robust::moved_images(b.views, b.lights, b.mask, b.data, b.width, (0, 0, b.height, b.width))
    })
}

/// Robust screen, the central patch that judges registration: `(row, column, rows, columns)`.
#[pyfunction]
pub fn robust_patch_window(height: usize, width: usize) -> (usize, usize, usize, usize) {
    btfrs_fit::robust::patch_window(height, width)
}

/// Robust screen on a worker: the values of `block` (a texel tile with its one-texel halo)
/// flagged among rows `r0..r1` and columns `c0..c1`, as `(flat indices into block, replacements)`.
#[pyfunction]
#[pyo3(signature = (block, views, lights, mask, floor, r0, r1, c0, c1))]
#[allow(clippy::too_many_arguments)]
pub fn robust_screen_block<'py>(
    py: Python<'py>,
    block: &Bound<'py, PyAny>,
    views: &Bound<'py, PyAny>,
    lights: &Bound<'py, PyAny>,
    mask: Option<&Bound<'py, PyAny>>,
    floor: f32,
    r0: usize,
    r1: usize,
    c0: usize,
    c1: usize,
) -> PyResult<FlagsOut<'py>> {
    let args = BtfArgs::new(block, views, lights, mask)?;
    let b = args.btf()?;
    let flags =
        detach(py, || btfrs_fit::robust::screen_values(&b, floor, r0..r1, c0..c1, &btfrs_core::Monitor::new()))?;
    let (idx, vals): (Vec<u64>, Vec<f32>) = flags.into_iter().map(|(i, x)| (i as u64, x)).unzip();
    Ok((vec1(py, idx)?, vec1(py, vals)?))
}

/// The robust report of a blockwise fit, as JSON: the flagged values (flat indices into the
/// whole BTF, `[H, W, V, L, 3]`, and their replacements) and the images' judgement.
#[pyfunction]
#[pyo3(signature = (height, width, views, lights, mask, index, values, spread, bad_images, moved, floor, excluded))]
#[allow(clippy::too_many_arguments)]
pub fn robust_report(
    height: usize,
    width: usize,
    views: &Bound<'_, PyAny>,
    lights: &Bound<'_, PyAny>,
    mask: Option<&Bound<'_, PyAny>>,
    index: &Bound<'_, PyAny>,
    values: &Bound<'_, PyAny>,
    spread: &Bound<'_, PyAny>,
    bad_images: Vec<(usize, usize)>,
    moved: Vec<(usize, usize, i32, i32)>,
    floor: f32,
    excluded: bool,
) -> PyResult<String> {
    guarded(|| {
        let (v, l): (numpy::PyReadonlyArrayDyn<'_, f64>, numpy::PyReadonlyArrayDyn<'_, f64>) =
            (borrow("views", views)?, borrow("lights", lights)?);
        let (nv, nl) = (dirs("views", &v)?.len(), dirs("lights", &l)?.len());
        let m: Option<numpy::PyReadonlyArrayDyn<'_, bool>> = mask.map(|m| borrow("mask", m)).transpose()?;
        let m = mask_of(&m, nv, nl)?;
        let idx: numpy::PyReadonlyArrayDyn<'_, u64> = borrow("index", index)?;
        let val: numpy::PyReadonlyArrayDyn<'_, f32> = borrow("values", values)?;
        let sp: numpy::PyReadonlyArrayDyn<'_, f32> = borrow("spread", spread)?;
        check_shape("spread", sp.shape(), &[Some(nv), Some(nl)])?;
        let (idx, val) = (idx.as_slice().map_err(|e| arg("index", e))?, val.as_slice().map_err(|e| arg("values", e))?);
        if idx.len() != val.len() {
            return Err(arg("values", format!("expected one value per index ({}), got {}", idx.len(), val.len())));
        }
        let images = btfrs_fit::robust::Images {
            spread: sp.as_slice().map_err(|e| arg("spread", e))?.to_vec(),
            bad_images,
            floor,
        };
        let sc = btfrs_fit::robust::Screen::new(
            idx.iter().zip(val).map(|(&i, &x)| (i as usize, x)).collect(),
            images,
            moved,
        );
        let mut r = sc.report_for([height, width, nv, nl], m, true, excluded);
        r["robust"] = serde_json::json!(true);
        Ok(r.to_string())
    })
}
