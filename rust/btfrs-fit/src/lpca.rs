//! Local PCA: clustered Eigen-BRDFs (Müller et al.), as paper 004 uses them (sections 3, 5, 6.3).
//!
//! Each texel's ABRDF `x` (its `V x L x 3` values) is approximated in the PCA basis of its
//! cluster `k`:
//!
//! ```text
//! x ~ mean_k + sum_{j=1..c} a_j E_{k,j}
//! ```
//!
//! **Storage** (section 6.3): every Eigen-BRDF, the cluster mean counting as `j = 0`, is quantized
//! separately to 8 bits. Eigen-BRDFs are signed, so besides the paper's scale we keep a bias:
//! `E_{k,j}[p] ~ bias[k][j] + scale[k][j] * q[k][j][p] / 255`. As in the paper the scales are folded
//! into the per-texel weights, and so are the biases, into one offset per texel:
//!
//! ```text
//! value_t[p] = offset_t + sum_{j=0..c} w_t[j] * q[k][j][p] / 255,
//!     w_t[j] = a_j scale[k][j],  offset_t = sum_j a_j bias[k][j],  a_0 = 1,
//! ```
//!
//! so a renderer needs one multiply-add per Eigen-BRDF and never rescales. After quantizing, each
//! texel's `a_j` (`j >= 1`) are re-solved by least squares against the *dequantized* basis (a
//! `c x c` system per cluster, applied to every member), which recovers most of what rounding the
//! basis lost.
//!
//! **Evaluation** between measured directions is the 9-tap interpolation of section 5 (three
//! nearest views times three nearest lights, [`directions::interp_weights`]), exactly as
//! [`crate::RawModel`] interpolates the raw data.
//!
//! **Fit.** Clustering ABRDFs of `D = 3 V L` values (19683 for UBO 81 x 81) must not cost `D` per
//! distance, and the clusters should minimise what LPCA actually stores, the reconstruction error
//! in the cluster's subspace, not the distance to a centre. So:
//!
//! 1. *Reduce*: a randomized PCA of the centred `texels x D` matrix ([`btfrs_numerics::rpca`]: Halko,
//!    Martinsson and Tropp's range finder, Gaussian test matrix from the seed, one power iteration,
//!    orthonormalisation, small eigenproblem) gives every texel `reduced_dims` principal
//!    coordinates. The subspace is found on at most 2048 texels drawn with the seed, then all
//!    texels are projected on it: about two and a half GEMM passes over the data for 64^2 texels,
//!    which is read in place.
//! 2. *k-means* ([`btfrs_numerics::kmeans`]: k-means++ seeding, Lloyd) on those coordinates.
//! 3. *Refine* (Kambhatla and Leen's local PCA, the objective of Müller et al.): per cluster PCA
//!    of `c` components, then every texel moves to the cluster whose affine subspace reconstructs it
//!    best, `|x - m_k|^2 - |E_k^T (x - m_k)|^2`; repeated `refine_iterations` times. Each half-step
//!    lowers (never raises) the summed reconstruction error, which is why, at equal size, the fit
//!    beats k-means followed by PCA.
//! 4. *Final PCA* of every cluster in the full space, on its member ABRDFs: exactly (eigenvectors of
//!    the member Gram matrix) for clusters of at most 512 texels, by randomized subspace iteration
//!    ([`btfrs_numerics::rpca`]) for larger ones. The `D x D` covariance is never formed.
//! 5. *Quantize and re-solve* as above.
//!
//! A BTF of more texels than the `sample` option is fitted on a seeded sample of them, then
//! streamed once ([`sampled`]): two reads of the data in all, whatever its size.
//!
//! Clusters that end up empty are dropped (`clusters` is the number used, which is also below the
//! requested one when the sample has fewer distinct ABRDFs). A cluster of `n <= c` texels has only
//! `n - 1` meaningful components; the others are zero Eigen-BRDFs (all `q = 0`, scale and bias 0).
//!
//! **Held-out pairs.** With a mask, the ABRDF vector is the present pairs only, so no absent
//! value enters the fit (each is only checked finite, as every value is); afterwards every Eigen-BRDF is filled at the absent pairs by
//! interpolating its present pairs ([`directions::present_pair_weights`]). That is linear, so it
//! equals interpolating the data, and the model answers every (view, light) pair.

use crate::gpu::{pack_u16, words, GpuLayout, Renderable, Shader};
use crate::model::{unknown_renderer, Bench, Mip, Model, ReflectanceModel, Sampling, Setting};
use crate::options::Spec;
use btfrs_core::{directions, ensure_arg, rng::mix, BtfRef, Error, Monitor, NamedArrays, Result};
use btfrs_numerics::dense::{cols, column_mean, gemm, gram_t, sym_eigen_desc, view, view_t};
use btfrs_numerics::kmeans::{kmeans, members_of};
use btfrs_numerics::rpca::{self, Columns};
use nalgebra::DMatrix;
use rayon::prelude::*;
use std::borrow::Cow;

mod sampled;
pub mod staged;

/// The most Eigen-BRDFs per cluster (besides the mean) a fit may ask for.
pub const MAX_COMPONENTS: usize = 16;

/// Clusters of at most this many texels (or spaces of at most this dimension) get an exact PCA
/// from a Gram or covariance matrix; an `n x n` symmetric eigenproblem of this size takes about
/// 0.1 s, and above it the randomized subspace iteration is cheaper.
const EXACT_MAX: usize = 512;

/// Points per block of the refinement's error matrix (`[block, K]` errors and `[block, K (c + 1)]`
/// dot products at a time).
const REFINE_BLOCK: usize = 8192;

/// Most clusters: the renderers store cluster ids as 16-bit values.
pub const MAX_CLUSTERS: usize = 65536;

/// Fit options.
#[derive(Debug, Clone, Copy, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LpcaOptions {
    /// Clusters asked for, 1 to the number of texels.
    pub clusters: usize,
    /// Eigen-BRDFs per cluster besides the mean, 0 to [`MAX_COMPONENTS`].
    pub components: usize,
    /// Most Lloyd iterations of the k-means (at least 1; stops earlier once stable).
    pub kmeans_iterations: usize,
    /// Local-PCA reassignment passes after the k-means (0 = plain k-means + PCA).
    pub refine_iterations: usize,
    /// Principal coordinates the clustering works in; 0 = cluster the full ABRDFs (slow).
    pub reduced_dims: usize,
    /// Texels the clusters and Eigen-BRDFs are found on when the BTF has more (a seeded sample;
    /// the others are then assigned and projected in one streaming pass, [`sampled`]); 0 = all.
    pub sample: usize,
    /// Seed of every random choice.
    pub seed: u64,
}

impl Default for LpcaOptions {
    /// The defaults of [`Lpca`]'s option schema.
    fn default() -> Self {
        crate::options::defaults(<Lpca as Model>::OPTIONS)
    }
}

/// A fitted local-PCA BTF (see the module doc for the formula).
#[derive(Debug, Clone)]
pub struct Lpca {
    /// Rows.
    pub height: usize,
    /// Columns.
    pub width: usize,
    /// View directions of the basis, `V`.
    pub views: Vec<[f64; 3]>,
    /// Light directions of the basis, `L`.
    pub lights: Vec<[f64; 3]>,
    /// Clusters used, `K`.
    pub clusters: usize,
    /// Eigen-BRDFs per cluster besides the mean, `c`.
    pub components: usize,
    /// `[H, W]` cluster of each texel.
    pub ids: Vec<u32>,
    /// `[H, W, c + 2]`: `[offset, w_0, w_1 .. w_c]` per texel.
    pub weights: Vec<f32>,
    /// `[K, c + 1, V, L, 4]`: quantized RGB and one zero pad byte per pair (one `u32` per pair
    /// for the GPU); Eigen-BRDF 0 is the cluster mean.
    pub basis: Vec<u8>,
    /// `[K, c + 1]` quantization scale of each Eigen-BRDF (folded into the weights already).
    pub scale: Vec<f32>,
    /// `[K, c + 1]` quantization bias of each Eigen-BRDF (folded into the offsets already).
    pub bias: Vec<f32>,
    /// What a fit on a texel sample measured in its streaming pass (`None`: fitted on every
    /// texel, or read from a file).
    pub sampled: Option<SampledFit>,
}

/// The figures of a fit on a texel sample ([`sampled`]), from its streaming pass.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SampledFit {
    /// Texels the clusters and Eigen-BRDFs were found on.
    pub sample: usize,
    /// `||model - data|| / ||data||` over every texel's present values, as the pass solved them.
    pub relative_error: f64,
}

/// Fit a local-PCA model to the present (view, light) pairs of `btf`.
///
/// `monitor` counts `4` units for the reduction (none with `reduced_dims = 0`), one per k-means
/// iteration, one per refinement pass, one per requested cluster for the final PCA and one for
/// the quantization; it can cancel between stages and between clusters.
pub fn fit_lpca(btf: &BtfRef<'_>, opts: &LpcaOptions, monitor: &Monitor) -> Result<Lpca> {
    let t = btf.texels();
    check_options(opts, btf.height, btf.width)?;
    if let Some(pick) = sampled::pick(t, opts) {
        return sampled::fit(btf, opts, &pick, monitor);
    }
    let (nv, nl) = (btf.views.len(), btf.lights.len());
    let pairs: Vec<usize> = (0..nv * nl).filter(|&i| btf.has(i / nl, i % nl)).collect();
    let d = pairs.len() * 3;
    let chunk = memory_plan(monitor.memory_limit(), t, d, opts, pairs.len() < nv * nl)?;
    let compact = (pairs.len() < nv * nl).then(|| gather_pairs(btf, &pairs));
    let data: &[f32] = compact.as_deref().unwrap_or(btf.data);
    // Every value, present or not, as the caller's scan would (`SCANS_VALUES`: it skips it, so a
    // BTF of more texels than the sample is read twice, not three times).
    btfrs_core::btf::check_finite("data", btf.data)?;

    let reduce_units = if opts.reduced_dims > 0 { rpca::PROGRESS_UNITS } else { 0 };
    let total = reduce_units + (opts.kmeans_iterations + opts.refine_iterations + opts.clusters + 1) as u64;
    monitor.start(total);

    // 1. The space the clustering works in: principal coordinates, or the ABRDFs themselves.
    let (space, dim): (Cow<'_, [f32]>, usize) = if opts.reduced_dims > 0 {
        let (p, r, _) =
            rpca::coordinates_map(data, d, t, opts.reduced_dims, sub_seed(opts.seed, 1), chunk, 1, monitor)?;
        (Cow::Owned(p), r)
    } else {
        (Cow::Borrowed(data), d)
    };
    monitor.check()?;

    // 2. + 3. k-means and the local-PCA refinement; clusters left empty dropped.
    let (ids, members) = cluster_space(&space, dim, t, opts, monitor)?;
    drop(space);
    monitor.check()?;

    // 4. + 5. Final PCA per cluster in the full space, quantization, weights.
    let c = opts.components;
    let one = |(ci, m): (usize, &Vec<u32>)| {
        if monitor.is_cancelled() {
            return ClusterFit::default();
        }
        let f = fit_cluster(data, d, m, c, sub_seed(opts.seed, 1000 + ci as u64), chunk);
        monitor.advance(1);
        f
    };
    // Under a memory limit one cluster at a time (each of its products parallel inside), so the
    // fit holds one chunk, not one per thread (nor more: rayon's work stealing would start
    // other clusters while a product waits).
    let fits: Vec<ClusterFit> = match chunk {
        None => members.par_iter().enumerate().map(one).collect(),
        Some(_) => members.iter().enumerate().map(one).collect(),
    };
    monitor.check()?;
    let lpca = assemble(btf.height, btf.width, btf.views, btf.lights, btf.mask, ids, &members, &fits, opts)?;
    monitor.advance((opts.clusters - members.len()) as u64 + 1);
    Ok(lpca)
}

/// The options' ranges for a `height x width` BTF.
fn check_options(opts: &LpcaOptions, height: usize, width: usize) -> Result<()> {
    let t = height * width;
    if opts.clusters == 0 || opts.clusters > t {
        return Err(Error::arg(
            "clusters",
            format!("expected 1 to {t} (the number of texels, {height} x {width}), got {}", opts.clusters),
        ));
    }
    if opts.components > MAX_COMPONENTS {
        return Err(Error::arg("components", format!("expected 0 to {MAX_COMPONENTS}, got {}", opts.components)));
    }
    ensure_arg!(opts.kmeans_iterations > 0, "kmeans_iterations", "expected at least 1, got 0");
    Ok(())
}

/// Steps 2 and 3 on the `dim`-dimensional points `space` (`t` texels, texel-major): k-means,
/// the local-PCA refinement, then the clusters left empty dropped (the others keep their order).
/// Returns every texel's cluster and each cluster's members in texel order. A space of
/// dimension 0 means every texel has the same ABRDF: one cluster.
fn cluster_space(
    space: &[f32],
    dim: usize,
    t: usize,
    opts: &LpcaOptions,
    monitor: &Monitor,
) -> Result<(Vec<u32>, Vec<Vec<u32>>)> {
    let (mut ids, k) = if dim == 0 {
        monitor.advance(opts.kmeans_iterations as u64);
        (vec![0u32; t], 1)
    } else {
        let km = kmeans(space, dim, opts.clusters, opts.kmeans_iterations, sub_seed(opts.seed, 2), monitor)?;
        let k = km.k();
        (km.assign, k)
    };
    if dim > 0 && opts.refine_iterations > 0 {
        let r = refine(space, dim, ids, k, opts.components, opts.refine_iterations, sub_seed(opts.seed, 3), monitor)?;
        ids = r.0;
    } else {
        monitor.advance(opts.refine_iterations as u64);
    }
    let mut members: Vec<Vec<u32>> = members_of(&ids, k).into_iter().filter(|m| !m.is_empty()).collect();
    members.shrink_to_fit();
    for (c, m) in members.iter().enumerate() {
        for &i in m {
            ids[i as usize] = c as u32;
        }
    }
    Ok((ids, members))
}

/// The model from the clusters' fits, in cluster order (step 5's weights scattered to the
/// texels, the quantized Eigen-BRDFs of the present pairs scattered into the
/// `[K, c + 1, V, L, 4]` layout and the absent pairs filled by interpolation). The last stage of
/// the blockwise fit too ([`staged`]).
#[allow(clippy::too_many_arguments)] // the model's dimensions and the stages' results, once
pub fn assemble(
    height: usize,
    width: usize,
    views: &[[f64; 3]],
    lights: &[[f64; 3]],
    mask: Option<&[bool]>,
    ids: Vec<u32>,
    members: &[Vec<u32>],
    fits: &[ClusterFit],
    opts: &LpcaOptions,
) -> Result<Lpca> {
    check_options(opts, height, width)?;
    let c = opts.components;
    let (nv, nl, t) = (views.len(), lights.len(), height * width);
    let vl = nv * nl;
    let has = |i: usize| mask.is_none_or(|m| m[i]);
    let pairs: Vec<usize> = (0..vl).filter(|&i| has(i)).collect();
    let d = pairs.len() * 3;
    let k = members.len();
    let cc = c + 1;
    ensure_arg!(fits.len() == k, "fits", "expected one fit per cluster ({k}), got {}", fits.len());
    ensure_arg!(ids.len() == t, "ids", "expected {t} cluster ids, got {}", ids.len());
    for (ci, (f, m)) in fits.iter().zip(members).enumerate() {
        ensure_arg!(
            f.q.len() == cc * d && f.scale.len() == cc && f.bias.len() == cc && f.weights.len() == m.len() * (c + 2),
            "fits",
            "cluster {ci}'s fit does not match its {} members, {c} components and {d} values",
            m.len()
        );
    }
    let mut weights = vec![0.0f32; t * (c + 2)];
    let mut scale = vec![0.0f32; k * cc];
    let mut bias = vec![0.0f32; k * cc];
    let mut basis = vec![0u8; k * cc * vl * 4];
    for (ci, (f, m)) in fits.iter().zip(members).enumerate() {
        scale[ci * cc..(ci + 1) * cc].copy_from_slice(&f.scale);
        bias[ci * cc..(ci + 1) * cc].copy_from_slice(&f.bias);
        for (slot, &texel) in m.iter().enumerate() {
            let w = texel as usize * (c + 2);
            weights[w..w + c + 2].copy_from_slice(&f.weights[slot * (c + 2)..(slot + 1) * (c + 2)]);
        }
    }
    // Scatter the present pairs into the [K, c + 1, V, L, 4] layout, then fill the absent ones.
    let absent: Vec<(usize, Vec<(usize, f64)>)> = (0..vl)
        .filter(|&i| !has(i))
        .collect::<Vec<_>>()
        .into_par_iter()
        .map(|i| {
            let w = directions::present_pair_weights(views, lights, mask, views[i / nl], lights[i % nl]);
            (i, w.into_iter().map(|(v, l, x)| (v * nl + l, x)).collect())
        })
        .collect();
    basis.par_chunks_mut(vl * 4).enumerate().for_each(|(kj, out)| {
        let q = &fits[kj / cc].q[(kj % cc) * d..(kj % cc + 1) * d];
        for (p, &pair) in pairs.iter().enumerate() {
            out[pair * 4..pair * 4 + 3].copy_from_slice(&q[p * 3..p * 3 + 3]);
        }
        for (pair, w) in &absent {
            for ch in 0..3 {
                let v: f64 = w.iter().map(|&(src, x)| x * out[src * 4 + ch] as f64).sum();
                out[pair * 4 + ch] = v.round().clamp(0.0, 255.0) as u8;
            }
        }
    });
    Ok(Lpca {
        height,
        width,
        views: views.to_vec(),
        lights: lights.to_vec(),
        clusters: k,
        components: c,
        ids,
        weights,
        basis,
        scale,
        bias,
        sampled: None,
    })
}

/// The chunk (texels of full-space ABRDFs copied at once) a fit under the memory limit `limit`
/// (bytes, `None`: no limit, and no chunking) works in, or an error naming `memory_limit` with
/// the least the fit needs.
///
/// Out of core (a memory-mapped BTF larger than memory): what grows with the texels whatever
/// the chunking is counted as it is: the principal coordinates and the projection that makes
/// them, the assignments, the refinement's gathered coordinates,
/// the per-cluster weights before they are scattered, and, with held-out pairs, the copy of the
/// present ones. What is left is one chunk: the range finder's sample, a large cluster's final
/// PCA and its weights' re-solve are streamed through it (`rpca::Gathered`), one cluster at a
/// time. The counts are upper bounds (every transient of a stage at once).
fn memory_plan(limit: Option<u64>, t: usize, d: usize, opts: &LpcaOptions, compact: bool) -> Result<Option<usize>> {
    let Some(limit) = limit else { return Ok(None) };
    let p = plan_parts(t, d, opts, compact)?;
    let least = p.least(t);
    if limit < least {
        let k = opts.clusters;
        return Err(Error::arg(
            "memory_limit",
            format!(
                "expected at least {} for an LPCA fit of {t} texels of {d} values into {k} clusters ({} of it grows with \
                 the texels), got {}",
                mb(least),
                mb(p.fixed),
                mb(limit)
            ),
        ));
    }
    Ok(Some(p.chunk(limit, t)))
}

/// [`memory_plan`]'s counts: bytes held whatever the chunk, per chunk, and per texel of a chunk.
#[derive(Debug, Clone, Copy)]
struct PlanParts {
    fixed: u64,
    per_chunk: u64,
    per_texel_of_chunk: u64,
}

impl PlanParts {
    /// The least limit: chunks of 32 texels (or all of them).
    fn least(&self, t: usize) -> u64 {
        self.fixed + self.per_chunk + 32.min(t as u64) * self.per_texel_of_chunk
    }

    /// The chunk a limit of at least [`PlanParts::least`] allows.
    fn chunk(&self, limit: u64, t: usize) -> usize {
        ((limit - self.fixed - self.per_chunk) / self.per_texel_of_chunk).min(t as u64) as usize
    }
}

fn plan_parts(t: usize, d: usize, opts: &LpcaOptions, compact: bool) -> Result<PlanParts> {
    if opts.reduced_dims == 0 {
        return Err(Error::arg(
            "memory_limit",
            "a fit under a memory limit clusters in principal coordinates: expected reduced_dims of at least 1, got 0",
        ));
    }
    let (t64, d64) = (t as u64, d as u64);
    let (k, cc) = (opts.clusters as u64, opts.components as u64 + 1);
    let r = opts.reduced_dims.min(d) as u64;
    let l = r + rpca::OVERSAMPLE as u64;
    let per_texel = 4 * (3 * r + 2 * l) // coordinates, the refinement's copies, the projection (and its bands)
        + 4 * 3 * l // a streamed cluster's [n, l] subspace products
        + 8 * (cc + 1) // the weights, per cluster and scattered
        + 4 * cc // the re-solve's right-hand sides
        + 56 // norms, distances, the seeding's CDF and potentials (f64); assignments, ids, members (u32)
        + 8 * (3 + (k as f64).ln() as u64); // k-means++'s distances to its candidates (f64)

    // Besides: k-means's and the refinement's blocks of distances, the copy of the present pairs
    // (held-out pairs), and 8 MiB for the allocator's and the threads' own.
    let present_copy = if compact { t64 * d64 * 4 } else { 0 };
    let blocks = 12 * (btfrs_numerics::kmeans::ASSIGN_BLOCK_VALUES as u64).min(t64 * k)
        + REFINE_BLOCK.min(t) as u64 * k * (4 * cc + 8);
    // The quantized Eigen-BRDFs of every cluster, kept until they are scattered into the basis.
    let quantized = k * cc * d64;
    let fixed = t64 * per_texel + blocks + present_copy + quantized + (8 << 20);
    // Per chunk: the range finder's d x l products (an f32 product, its row bands, the f64
    // sum, the subspace kept: 24 bytes per value), the mean, the quantized and dequantized
    // basis; then 4 bytes per value of each texel of the chunk.
    let per_chunk = d64 * (24 * l + 4 * (2 * cc + 2) + cc);
    let per_texel_of_chunk = 4 * d64;
    Ok(PlanParts { fixed, per_chunk, per_texel_of_chunk })
}

/// Bytes as decimal megabytes, as memory limits are written ("64MB").
fn mb(bytes: u64) -> String {
    format!("{:.1} MB", bytes as f64 / 1e6)
}

/// A seed for one stage of the fit, independent of the others.
fn sub_seed(seed: u64, stage: u64) -> u64 {
    mix(seed ^ mix(stage.wrapping_add(0x5EED)))
}

/// The present pairs of every texel, `[T, P, 3]` (only called when some pair is absent).
fn gather_pairs(btf: &BtfRef<'_>, pairs: &[usize]) -> Vec<f32> {
    let d = pairs.len() * 3;
    let mut out = vec![0.0f32; btf.texels() * d];
    out.par_chunks_mut(d).enumerate().for_each(|(t, o)| {
        let x = btf.texel(t);
        for (p, &pair) in pairs.iter().enumerate() {
            o[p * 3..p * 3 + 3].copy_from_slice(&x[pair * 3..pair * 3 + 3]);
        }
    });
    out
}

/// The mean of the member columns and the centred members as a `dim x n` matrix.
fn gather_centred(points: &[f32], dim: usize, members: &[u32]) -> (Vec<f32>, DMatrix<f32>) {
    let mean = column_mean(points, dim, Some(members));
    let mut xc = DMatrix::<f32>::zeros(dim, members.len());
    xc.as_mut_slice().par_chunks_mut(dim.max(1)).zip(members.par_iter()).for_each(|(o, &m)| {
        let x = &points[m as usize * dim..(m as usize + 1) * dim];
        for ((o, &x), &mu) in o.iter_mut().zip(x).zip(&mean) {
            *o = x - mu;
        }
    });
    (mean, xc)
}

/// The `c` leading principal directions (orthonormal columns, `dim x c`; zero columns where the
/// members span fewer) of the centred members `xc` (`dim x n`).
fn top_components(xc: &DMatrix<f32>, c: usize, seed: u64) -> DMatrix<f32> {
    let (dim, n) = xc.shape();
    let mut e = DMatrix::<f32>::zeros(dim, c);
    if c == 0 || n < 2 || dim == 0 {
        return e;
    }
    if dim <= EXACT_MAX && dim <= n {
        // Covariance (dim x dim).
        let cov = gemm(&view(xc), &view_t(xc));
        let cov = DMatrix::from_fn(dim, dim, |i, j| 0.5 * (cov[(i, j)] as f64 + cov[(j, i)] as f64));
        let (vals, vecs) = sym_eigen_desc(cov);
        for j in 0..c.min(dim) {
            if vals[j] > CUT * vals[0] && vals[0] > 0.0 {
                e.column_mut(j).iter_mut().zip(vecs.column(j).iter()).for_each(|(o, &v)| *o = v as f32);
            }
        }
    } else if n <= EXACT_MAX {
        // Gram (n x n): e_j = xc v_j / sqrt(lambda_j).
        let (vals, vecs) = sym_eigen_desc(gram_t(xc));
        let keep = (0..c.min(n)).take_while(|&j| vals[0] > 0.0 && vals[j] > CUT * vals[0]).count();
        let w = DMatrix::<f32>::from_fn(n, keep, |i, j| (vecs[(i, j)] / vals[j].sqrt()) as f32);
        let ek = gemm(&view(xc), &view(&w));
        e.columns_mut(0, keep).copy_from(&ek);
    } else {
        // Randomized subspace iteration then Rayleigh-Ritz.
        let ek = rpca::top_directions(xc, c, seed, CUT);
        e.columns_mut(0, ek.ncols()).copy_from(&ek);
    }
    e
}

/// Eigenvalues below this fraction of the largest are f32 rounding, not directions.
const CUT: f64 = 1e-8;

/// [`top_components`] of the members `m` of the `d x T` data, centred on `mean`, streamed `chunk`
/// texels at a time (a cluster too large for the memory limit): always by the randomized
/// subspace iteration, which only multiplies by the data.
fn streamed_components(
    data: &[f32],
    d: usize,
    m: &[u32],
    mean: &[f32],
    c: usize,
    chunk: usize,
    seed: u64,
) -> DMatrix<f32> {
    let mut e = DMatrix::<f32>::zeros(d, c);
    if c == 0 || m.len() < 2 || d == 0 {
        return e;
    }
    let x = rpca::Gathered { data, d, idx: m, centre: Some(mean), chunk };
    let ek = rpca::top_directions(&x, c, seed, CUT);
    e.columns_mut(0, ek.ncols()).copy_from(&ek);
    e
}

/// One cluster's affine subspace: mean and orthonormal (or zero) directions.
#[derive(Debug, Clone)]
pub(crate) struct LocalPca {
    pub(crate) mean: Vec<f32>,
    pub(crate) basis: DMatrix<f32>,
}

/// Mean and `c` principal directions of the member columns of the `dim x n` matrix `points`.
pub(crate) fn local_pca(points: &[f32], dim: usize, members: &[u32], c: usize, seed: u64) -> LocalPca {
    let (mean, xc) = gather_centred(points, dim, members);
    LocalPca { mean, basis: top_components(&xc, c, seed) }
}

/// The LPCA error `|x - m_k|^2 - |E_k^T (x - m_k)|^2` of every point (columns of `points`) for
/// every cluster, `[n, K]`; `+inf` for a cluster without a subspace (empty).
pub(crate) fn lpca_errors(points: &[f32], dim: usize, pcas: &[Option<LocalPca>], c: usize) -> Vec<f64> {
    let n = points.len() / dim;
    let k = pcas.len();
    let cc = c + 1;
    // All means and directions side by side: one GEMM gives every dot product needed.
    let mut w = DMatrix::<f32>::zeros(dim, k * cc);
    let mut consts = vec![(f64::INFINITY, vec![0.0f64; c]); k];
    for (ci, p) in pcas.iter().enumerate() {
        let Some(p) = p else { continue };
        w.column_mut(ci * cc).copy_from_slice(&p.mean);
        w.columns_mut(ci * cc + 1, c).copy_from(&p.basis);
        let mn: f64 = p.mean.iter().map(|&x| x as f64 * x as f64).sum();
        let em =
            (0..c).map(|j| p.basis.column(j).iter().zip(&p.mean).map(|(&a, &b)| a as f64 * b as f64).sum()).collect();
        consts[ci] = (mn, em);
    }
    let g = gemm(&view_t(&w), &cols(points, dim, n));
    let mut out = vec![0.0f64; n * k];
    out.par_chunks_mut(k).zip(g.as_slice().par_chunks(k * cc)).zip(points.par_chunks(dim)).for_each(|((o, gi), x)| {
        let xn: f64 = x.iter().map(|&v| v as f64 * v as f64).sum();
        for ci in 0..k {
            let (mn, em) = &consts[ci];
            if mn.is_infinite() {
                o[ci] = f64::INFINITY;
                continue;
            }
            let g = &gi[ci * cc..(ci + 1) * cc];
            let proj: f64 = (0..c).map(|j| (g[1 + j] as f64 - em[j]).powi(2)).sum();
            o[ci] = (xn - 2.0 * g[0] as f64 + mn - proj).max(0.0);
        }
    });
    out
}

/// Step 3: local-PCA reassignment passes. Returns the assignment and the objective (summed LPCA
/// error) before and after each reassignment: `[J(P_0, A_0), J(P_0, A_1), J(P_1, A_1), ...]`
/// where `P_i` is the PCA of assignment `A_i`; the sequence never increases. A point moves only
/// to a strictly better cluster, so ties (e.g. when `c` fills the reduced space) keep it in place.
#[allow(clippy::too_many_arguments)] // the fit's stage parameters, passed through once
pub(crate) fn refine(
    points: &[f32],
    dim: usize,
    mut assign: Vec<u32>,
    k: usize,
    c: usize,
    iterations: usize,
    seed: u64,
    monitor: &Monitor,
) -> Result<(Vec<u32>, Vec<f64>)> {
    let mut history = Vec::with_capacity(2 * iterations);
    for it in 0..iterations {
        monitor.check()?;
        let members = members_of(&assign, k);
        let pcas: Vec<Option<LocalPca>> = members
            .par_iter()
            .enumerate()
            .map(|(ci, m)| (!m.is_empty()).then(|| local_pca(points, dim, m, c, mix(seed ^ ci as u64))))
            .collect();
        // In blocks of points, so the [n, K] errors (and the GEMM behind them) are never held
        // for all points at once; the sums run in point order as over one block.
        let (mut before, mut after, mut moved) = (0.0f64, 0.0f64, 0usize);
        for (b, block) in assign.chunks_mut(REFINE_BLOCK).enumerate() {
            let pts = &points[b * REFINE_BLOCK * dim..(b * REFINE_BLOCK + block.len()) * dim];
            let err = lpca_errors(pts, dim, &pcas, c);
            for (a, e) in block.iter().zip(err.chunks(k)) {
                before += e[*a as usize];
            }
            moved += block
                .par_iter_mut()
                .zip(err.par_chunks(k))
                .map(|(a, e)| {
                    let best = (0..k).fold(*a as usize, |b, ci| if e[ci] < e[b] { ci } else { b });
                    let moved = best != *a as usize;
                    *a = best as u32;
                    usize::from(moved)
                })
                .sum::<usize>();
            for (a, e) in block.iter().zip(err.chunks(k)) {
                after += e[*a as usize];
            }
        }
        history.push(before);
        history.push(after);
        monitor.advance(1);
        if moved == 0 {
            monitor.advance((iterations - it - 1) as u64);
            break;
        }
    }
    Ok((assign, history))
}

/// One cluster's share of the model.
#[derive(Debug, Clone, Default)]
pub struct ClusterFit {
    /// `[c + 1, D]` quantized present values.
    pub q: Vec<u8>,
    /// `[c + 1]`.
    pub scale: Vec<f32>,
    /// `[c + 1]`.
    pub bias: Vec<f32>,
    /// `[n, c + 2]` per member, in member order.
    pub weights: Vec<f32>,
}

/// Steps 4 and 5 for the members `m` of one cluster of the `d x T` data. `chunk`: the most
/// texels whose values may be copied at once (`None`: any number); a larger cluster is streamed
/// ([`streamed_components`]).
fn fit_cluster(data: &[f32], d: usize, m: &[u32], c: usize, seed: u64, chunk: Option<usize>) -> ClusterFit {
    let (basis, xc) = cluster_basis(data, d, m, c, seed, chunk);
    let n = m.len();
    let weights = if c == 0 {
        basis.weights(&DMatrix::zeros(0, n)).0
    } else {
        let f = basis.deq.columns(1, c).into_owned();
        let ftx = match (&xc, chunk) {
            (Some(xc), _) => gemm(&view_t(&f), &view(xc)),
            (None, s) => {
                let x = rpca::Gathered { data, d, idx: m, centre: Some(&basis.mean), chunk: s.unwrap_or(n) };
                x.t_times(&f).transpose()
            }
        };
        basis.weights(&ftx).0
    };
    ClusterFit { q: basis.q, scale: basis.scale, bias: basis.bias, weights }
}

/// Step 4 for the members `m` of one cluster (their mean and principal directions) and the
/// quantization of step 5: the cluster's [`Basis`], and the centred members when they were
/// gathered (`None` when streamed).
fn cluster_basis(
    data: &[f32],
    d: usize,
    m: &[u32],
    c: usize,
    seed: u64,
    chunk: Option<usize>,
) -> (Basis, Option<DMatrix<f32>>) {
    let (mean, xc, e) = match chunk {
        Some(s) if m.len() > s => {
            let mean = column_mean(data, d, Some(m));
            let e = streamed_components(data, d, m, &mean, c, s, seed);
            (mean, None, e)
        }
        _ => {
            let (mean, xc) = gather_centred(data, d, m);
            let e = top_components(&xc, c, seed);
            (mean, Some(xc), e)
        }
    };
    (Basis::new(mean, &e, c), xc)
}

/// One cluster's quantized Eigen-BRDFs and the least-squares solve of a texel's weights against
/// their dequantized values (step 5).
#[derive(Debug, Clone)]
pub(crate) struct Basis {
    /// The members' mean (unquantized): texels are centred on it before [`Basis::weights`].
    pub(crate) mean: Vec<f32>,
    /// `[c + 1, D]` quantized Eigen-BRDFs, the mean first.
    pub(crate) q: Vec<u8>,
    pub(crate) scale: Vec<f32>,
    pub(crate) bias: Vec<f32>,
    /// `D x (c + 1)` dequantized Eigen-BRDFs `e~_j`.
    pub(crate) deq: DMatrix<f32>,
    /// Pseudo-inverse of `F^T F`, `F = e~_1..c`.
    pinv: DMatrix<f64>,
    /// `F^T F`.
    ftf: DMatrix<f64>,
    /// `F^T (mean - e~_0)`.
    shift: Vec<f64>,
}

impl Basis {
    /// Quantize each Eigen-BRDF (`mean`, then the columns of `e`) over its own range.
    fn new(mean: Vec<f32>, e: &DMatrix<f32>, c: usize) -> Basis {
        let d = mean.len();
        let cc = c + 1;
        let mut q = vec![0u8; cc * d];
        let mut scale = vec![0.0f32; cc];
        let mut bias = vec![0.0f32; cc];
        let mut deq = DMatrix::<f32>::zeros(d, cc);
        for j in 0..cc {
            let src: &[f32] = if j == 0 { &mean } else { &e.as_slice()[(j - 1) * d..j * d] };
            let (lo, hi) = src.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
            let s = hi - lo;
            bias[j] = lo;
            scale[j] = if s > 0.0 && s.is_finite() { s } else { 0.0 };
            let qj = &mut q[j * d..(j + 1) * d];
            let mut col = deq.column_mut(j);
            for p in 0..d {
                let level =
                    if scale[j] > 0.0 { ((src[p] - lo) / scale[j] * 255.0).round().clamp(0.0, 255.0) } else { 0.0 };
                qj[p] = level as u8;
                col[p] = lo + scale[j] * (level / 255.0);
            }
        }
        // Re-solve a_1..a_c against the dequantized basis: (F^T F) a = F^T (x - e~_0), F = e~_1..c.
        let f = deq.columns(1, c);
        let ftf = DMatrix::<f64>::from_fn(c, c, |i, j| {
            f.column(i).iter().zip(f.column(j).iter()).map(|(&x, &y)| x as f64 * y as f64).sum()
        });
        let (vals, vecs) = sym_eigen_desc(ftf.clone());
        let top = vals.first().copied().unwrap_or(0.0);
        // Pseudo-inverse: a zero Eigen-BRDF (or a degenerate pair) gets weight 0, never NaN.
        let mut pinv = DMatrix::<f64>::zeros(c, c);
        for (l, &lam) in vals.iter().enumerate() {
            if top > 0.0 && lam > 1e-9 * top {
                let v = vecs.column(l);
                pinv += (v * v.transpose()) / lam;
            }
        }
        // x - e~_0 = xc + (mean - e~_0).
        let shift: Vec<f64> = (0..c)
            .map(|j| {
                f.column(j)
                    .iter()
                    .zip(&mean)
                    .zip(deq.column(0).iter())
                    .map(|((&fv, &mu), &e0)| fv as f64 * (mu as f64 - e0 as f64))
                    .sum()
            })
            .collect();
        Basis { mean, q, scale, bias, deq, pinv, ftf, shift }
    }

    /// Eigen-BRDFs besides the mean.
    fn components(&self) -> usize {
        self.scale.len() - 1
    }

    /// The stored weights `[n, c + 2]` (`[offset, w_0 .. w_c]`) of `n` texels from `F^T (x -
    /// mean)` (`ftx`, `c x n`), and their coefficients `a` (`c x n`).
    fn weights(&self, ftx: &DMatrix<f32>) -> (Vec<f32>, DMatrix<f64>) {
        let c = self.components();
        let n = ftx.ncols();
        let mut a = DMatrix::<f64>::zeros(c, n);
        for i in 0..n {
            let rhs = nalgebra::DVector::<f64>::from_fn(c, |j, _| ftx[(j, i)] as f64 + self.shift[j]);
            a.column_mut(i).copy_from(&(&self.pinv * rhs));
        }
        let (scale, bias) = (&self.scale, &self.bias);
        let mut weights = vec![0.0f32; n * (c + 2)];
        for (i, w) in weights.chunks_mut(c + 2).enumerate() {
            let mut offset = bias[0] as f64;
            w[1] = scale[0];
            for j in 1..=c {
                let aj = a[(j - 1, i)];
                offset += aj * bias[j] as f64;
                w[1 + j] = (aj * scale[j] as f64) as f32;
            }
            w[0] = offset as f32;
        }
        (weights, a)
    }
}

/// A prepared query: the 9 (view, light) taps and their weights.
#[derive(Debug, Clone)]
pub struct LpcaQuery {
    /// (pair index `v * L + l`, interpolation weight).
    taps: Vec<(usize, f32)>,
}

impl Lpca {
    /// `V * L`.
    fn pairs(&self) -> usize {
        self.views.len() * self.lights.len()
    }

    /// Check that the arrays agree with the dimensions (for models built from loaded files).
    pub fn validate(&self) -> Result<()> {
        if self.height == 0 || self.width == 0 {
            return Err(Error::arg("ids", "the model has no texels"));
        }
        directions::validate("views", &self.views)?;
        directions::validate("lights", &self.lights)?;
        ensure_arg!(
            (1..=MAX_CLUSTERS).contains(&self.clusters),
            "clusters",
            "expected 1 to {MAX_CLUSTERS} clusters, got {}",
            self.clusters
        );
        if self.components > MAX_COMPONENTS {
            return Err(Error::arg("components", format!("expected 0 to {MAX_COMPONENTS}, got {}", self.components)));
        }
        let t = self.height * self.width;
        let cc = self.components + 1;
        let expect = |name: &str, got: usize, want: usize| {
            if got == want {
                Ok(())
            } else {
                Err(Error::arg(name, format!("expected {want} values, got {got}")))
            }
        };
        expect("ids", self.ids.len(), t)?;
        expect("weights", self.weights.len(), t * (cc + 1))?;
        expect("basis", self.basis.len(), self.clusters * cc * self.pairs() * 4)?;
        expect("scale", self.scale.len(), self.clusters * cc)?;
        expect("bias", self.bias.len(), self.clusters * cc)?;
        if let Some(i) = self.ids.iter().position(|&k| k as usize >= self.clusters) {
            return Err(Error::arg(
                "ids",
                format!("texel {i} has cluster {}, but there are {} clusters", self.ids[i], self.clusters),
            ));
        }
        for (name, v) in [("weights", &self.weights), ("scale", &self.scale), ("bias", &self.bias)] {
            if let Some(i) = v.iter().position(|x| !x.is_finite()) {
                return Err(Error::arg(name, format!("value {} at flat index {i} is not finite", v[i])));
            }
        }
        Ok(())
    }

    /// The quantized Eigen-BRDF `j` (0 = mean) of cluster `k` at pair (`v`, `l`), as `q / 255`.
    ///
    /// # Panics
    /// If an index is out of range (like slice indexing).
    pub fn basis_value(&self, k: usize, j: usize, v: usize, l: usize) -> [f32; 3] {
        assert!(k < self.clusters && j <= self.components && v < self.views.len() && l < self.lights.len());
        let o = ((k * (self.components + 1) + j) * self.pairs() + v * self.lights.len() + l) * 4;
        [0, 1, 2].map(|c| self.basis[o + c] as f32 / 255.0)
    }
}

impl ReflectanceModel for Lpca {
    type Query = LpcaQuery;

    fn dims(&self) -> (usize, usize) {
        (self.height, self.width)
    }

    fn query(&self, view: [f64; 3], light: [f64; 3]) -> LpcaQuery {
        let nl = self.lights.len();
        let mut lw = directions::interp_weights(&self.lights, light, 3);
        directions::cos_corrected(&mut lw, &self.lights, light);
        let taps = directions::interp_weights(&self.views, view, 3)
            .into_iter()
            .flat_map(|(v, wv)| lw.iter().map(move |&(l, wl)| (v * nl + l, (wv * wl) as f32)))
            .collect();
        LpcaQuery { taps }
    }

    #[inline]
    fn eval(&self, t: usize, q: &LpcaQuery) -> [f32; 3] {
        let cc = self.components + 1;
        let vl = self.pairs();
        let w = &self.weights[t * (cc + 1)..(t + 1) * (cc + 1)];
        let base = self.ids[t] as usize * cc * vl;
        let mut out = [0.0f32; 3];
        for &(pair, wt) in &q.taps {
            let mut s = [0.0f32; 3];
            for j in 0..cc {
                let o = ((base + j * vl) + pair) * 4;
                let b = &self.basis[o..o + 3];
                for ch in 0..3 {
                    s[ch] += w[1 + j] * b[ch] as f32;
                }
            }
            for ch in 0..3 {
                out[ch] += wt * (w[0] + s[ch] * (1.0 / 255.0));
            }
        }
        out
    }
}

crate::gpu_params! {
    /// Parameters of `lpca_9tap.wgsl`.
    pub struct Lpca9Params {
        /// Number of views V (directions `mdirs[0 .. V]`).
        pub n_views: u32,
        /// Number of lights L (directions `mdirs[V .. V + L]`).
        pub n_lights: u32,
        /// Offset of the views' candidate table in `tables`.
        pub view_table: u32,
        /// Offset of the lights' candidate table in `tables`.
        pub light_table: u32,
        /// Store offset of the cluster ids: u16, two per word.
        pub ids: u32,
        /// Store offset of the weights `[texel][c + 2]` f32 (offset, w_0 .. w_c).
        pub weights: u32,
        /// Store offset of the Eigen-BRDF words `[k][j][V][L]` (RGBA8, alpha unused).
        pub basis: u32,
        /// Components c (Eigen-BRDFs per cluster besides the mean).
        pub components: u32,
    }
}

impl Lpca {
    /// The model extended by the texels of a filtered mip pyramid, *projected* levels: texel
    /// `n + g` (n = the model's texel count) represents `sum w x appearance(t)` over `groups[g]`
    /// (which may name earlier new texels) as well as one cluster can: of the clusters of the
    /// group's texels, the one whose (dequantized, affine) subspace holds the most of that mean
    /// ABRDF, with the least-squares offset and weights in it. LPCA's weights cannot be averaged
    /// across clusters (each cluster has its own basis), but the mean appearance can be projected:
    /// exact when the group shares one cluster (the weights' average), the L2-best choice
    /// otherwise, far closer than a medoid (an existing texel) when a block mixes clusters.
    ///
    /// All inner products come from one Gram matrix of the `1 + K (c + 1)` basis functions over
    /// the `3 V L` values; each new texel then costs a few `(c + 2) x (c + 2)` solves. Layout as
    /// [`crate::registry::mip_texels`]: the width kept, `ceil(groups / width)` rows added (the
    /// last padded with copies of texel 0). Errors: a group naming a texel not defined before it.
    pub fn mip_texels(&self, groups: &[Vec<(u32, f32)>]) -> Result<Lpca> {
        let (h, w) = (self.height, self.width);
        let n = h * w;
        for (g, grp) in groups.iter().enumerate() {
            if let Some(&(bad, _)) = grp.iter().find(|(t, _)| *t as usize >= n + g) {
                return Err(Error::arg("groups", format!("group {g} names texel {bad}, not defined before it")));
            }
        }
        let cc = self.components + 1;
        let vl = self.pairs();
        let d = 3 * vl;
        let nf = 1 + self.clusters * cc;
        // Basis functions as columns: the constant, then q[k][j] / 255 for every cluster.
        let f = DMatrix::<f32>::from_fn(d, nf, |p, col| {
            if col == 0 {
                return 1.0;
            }
            let (k, j) = ((col - 1) / cc, (col - 1) % cc);
            let (pair, ch) = (p / 3, p % 3);
            self.basis[((k * cc + j) * vl + pair) * 4 + ch] as f32 / 255.0
        });
        let gram = gram_t(&f);
        let mut ids = self.ids.clone();
        let mut weights = self.weights.clone();
        let stride = cc + 1;
        for grp in groups {
            // The group's mean as sparse coefficients over the basis functions.
            let mut y: Vec<(usize, f64)> = Vec::new();
            let mut candidates: Vec<usize> = Vec::new();
            for &(t, wt) in grp {
                let (t, wt) = (t as usize, wt as f64);
                let k = ids[t] as usize;
                let wv = &weights[t * stride..(t + 1) * stride];
                y.push((0, wt * wv[0] as f64));
                y.extend((0..cc).map(|j| (1 + k * cc + j, wt * wv[1 + j] as f64)));
                if !candidates.contains(&k) {
                    candidates.push(k);
                }
            }
            let mut best: Option<(f64, usize, Vec<f64>)> = None;
            for &k in &candidates {
                let cols: Vec<usize> = std::iter::once(0).chain((0..cc).map(|j| 1 + k * cc + j)).collect();
                let m = cols.len();
                let rhs: Vec<f64> = cols.iter().map(|&a| y.iter().map(|&(b, v)| gram[(a, b)] * v).sum()).collect();
                // A tiny ridge: zero Eigen-BRDFs (clusters of few texels) make the system singular,
                // and their weights should then be 0.
                let trace: f64 = cols.iter().map(|&a| gram[(a, a)]).sum::<f64>().max(1e-300);
                let a = DMatrix::<f64>::from_fn(m, m, |i, j| {
                    gram[(cols[i], cols[j])] + if i == j { 1e-12 * trace } else { 0.0 }
                });
                let Some(chol) = a.cholesky() else { continue };
                let x = chol.solve(&nalgebra::DVector::from_vec(rhs.clone()));
                let captured: f64 = x.iter().zip(&rhs).map(|(a, b)| a * b).sum();
                if best.as_ref().is_none_or(|(c, _, _)| captured > *c) {
                    best = Some((captured, k, x.iter().copied().collect()));
                }
            }
            let (_, k, x) =
                best.ok_or_else(|| Error::Degenerate("lpca: a mip texel has no solvable cluster".into()))?;
            ids.push(k as u32);
            weights.extend(x.iter().map(|&v| v as f32));
        }
        let rows = h + groups.len().div_ceil(w.max(1));
        while ids.len() < rows * w {
            ids.push(ids[0]);
            weights.extend_from_within(0..stride);
        }
        let out = Lpca { height: rows, ids, weights, sampled: None, ..self.clone() };
        out.validate()?;
        Ok(out)
    }

    /// The cluster ids as the shaders read them: u16, two per word.
    pub fn id_words(&self) -> Vec<u32> {
        pack_u16(self.ids.iter().map(|&k| k as u16))
    }
}

impl GpuLayout for Lpca {
    type Params = Lpca9Params;
    const SHADER: Shader =
        Shader::new::<Lpca9Params>("lpca_9tap", include_str!("../../../shaders_wgsl/lpca_9tap.wgsl"));

    fn parts(&self) -> Vec<Cow<'_, [u32]>> {
        vec![Cow::Owned(self.id_words()), words(&self.weights), Cow::Borrowed(bytemuck::cast_slice(&self.basis))]
    }

    fn dir_sets(&self) -> Vec<&[[f64; 3]]> {
        vec![&self.views, &self.lights]
    }

    fn params(&self, offsets: &[u32], tables: &[u32]) -> Lpca9Params {
        Lpca9Params {
            n_views: self.views.len() as u32,
            n_lights: self.lights.len() as u32,
            view_table: tables[0],
            light_table: tables[1],
            ids: offsets[0],
            weights: offsets[1],
            basis: offsets[2],
            components: self.components as u32,
        }
    }
}

impl Model for Lpca {
    const KIND: &'static str = "lpca";
    const TEXEL_ARRAYS: &'static [&'static str] = &["ids", "weights"];
    const DOC: &'static str = "local PCA, clustered 8-bit Eigen-BRDFs (paper 004, sections 3 and 6)";
    const RENDERERS: &'static [&'static str] = &["9tap", "3d"];
    const ABOUT: &'static str = "\
k-means++ (seeded) over the texels' ABRDFs, a PCA per cluster with `components` Eigen-BRDFs
besides the mean, then 8-bit Eigen-BRDFs with their scales folded into the per-texel weights
(section 6.3). The k-means runs in a `reduced_dims`-dimensional randomized PCA projection of the
ABRDFs (0: the full space) and is refined by `refine_iterations` passes that reassign each texel
to the cluster whose subspace reconstructs it best (the LPCA objective itself). A BTF of more
than `sample` texels is fitted in two reads: the clusters and their Eigen-BRDFs are found on a
seeded sample of `sample` texels, then one streaming pass assigns every other texel to the
cluster whose subspace (in the principal coordinates) reconstructs it best and solves its
weights, and reports the reconstruction error it measured on the way. Under a `memory_limit` the
sample is held whole (the limit must hold it: a smaller `sample` needs less) and each cluster too
large for what is left is streamed through chunks sized by the limit, so a memory-mapped BTF
larger than memory fits, equal to the unlimited fit up to rounding. Two renderers: `\"9tap\"` (three nearest views x three nearest
lights, section 5) and `\"3d\"` (Eigen-BRDFs resampled on the elevated concentric map in one 3D
texture, section 6).";
    const OPTIONS: &'static [Spec] = &[
        Spec::int("clusters", 32, 1, None, "clusters asked for (at most the texels)"),
        Spec::int("components", 4, 0, Some(MAX_COMPONENTS as i64), "Eigen-BRDFs per cluster besides the mean"),
        Spec::int("kmeans_iterations", 25, 1, None, "most Lloyd iterations of the k-means (stops earlier once stable)"),
        Spec::int(
            "refine_iterations",
            2,
            0,
            None,
            "local-PCA reassignment passes after the k-means (0: plain k-means + PCA)",
        ),
        Spec::int(
            "reduced_dims",
            64,
            0,
            None,
            "principal coordinates the clustering works in (0: the full ABRDFs, slow)",
        ),
        Spec::int(
            "sample",
            16384,
            0,
            None,
            "texels the clusters and Eigen-BRDFs are found on when the BTF has more (drawn with the seed; the \
             others are assigned and projected in one streaming pass); 0: every texel",
        ),
        Spec::seed("seed of every random choice (k-means++ seeding, the randomized PCA, the texel sample)"),
    ];
    const EXAMPLES: &'static [(&'static str, &'static str)] =
        &[("LPCA 8x4", r#"{"clusters": 8, "components": 4}"#), ("LPCA 32x4", r#"{"clusters": 32, "components": 4}"#)];
    const SWEEP: &'static [Setting] = &[
        Setting::full("LPCA 8x2", r#"{"clusters": 8, "components": 2}"#),
        Setting::quick("LPCA 8x4", r#"{"clusters": 8, "components": 4}"#),
        Setting::full("LPCA 8x8", r#"{"clusters": 8, "components": 8}"#),
        Setting::full("LPCA 32x2", r#"{"clusters": 32, "components": 2}"#),
        Setting::full("LPCA 32x4", r#"{"clusters": 32, "components": 4}"#),
        Setting::full("LPCA 32x8", r#"{"clusters": 32, "components": 8}"#),
    ];
    const BENCH: &'static [Bench] = &[
        Bench::new("LPCA 32x4", r#"{"clusters": 32, "components": 4}"#, &["per_material", "models", "dask"])
            .peer("lpca_sklearn"),
        Bench::new("LPCA 32x2", r#"{"clusters": 32, "components": 2, "seed": 0}"#, &["models"]),
        Bench::new("LPCA 32x8", r#"{"clusters": 32, "components": 8, "seed": 0}"#, &["models"]).peer("lpca_sklearn"),
        Bench::new("LPCA 32x{components}", r#"{"clusters": 32, "components": [2, 4, 8], "seed": 0}"#, &["renderers"])
            .note("paper 004, Table 1: the 9-tap and the 3D-texture renderers"),
        Bench::new(
            "LPCA {clusters}x{components}",
            r#"{"clusters": [8, 16, 32, 64], "components": [2, 4, 8, 12, 16], "seed": 0}"#,
            &["reach"],
        )
        .note("paper 004: about 2% at 1:50 to 1:250"),
        Bench::new("LPCA 4x4", r#"{"clusters": 4, "components": 4, "seed": 0}"#, &["single_view"]),
        Bench::new("LPCA 8x4", r#"{"clusters": 8, "components": 4, "seed": 0}"#, &["single_view", "summary"])
            .note("btfrs LPCA 8x4 (before) 25.8%"),
        Bench::new("LPCA 8x8", r#"{"clusters": 8, "components": 8, "seed": 0}"#, &["single_view"]),
        Bench::new("LPCA 16x4", r#"{"clusters": 16, "components": 4, "seed": 0}"#, &["single_view"]),
        Bench::new("LPCA 64x8", r#"{"clusters": 64, "components": 8}"#, &["out_of_core"]),
    ];
    const SAMPLING: Sampling = Sampling::Any {
        note: "any sampling (per-texel ABRDFs, clustered)",
        one_view: "any sampling (per-texel ABRDFs, clustered)",
    };
    type Options = LpcaOptions;
    // Each value checked as it is read (the sample, then the streaming pass; or one scan).
    const SCANS_VALUES: bool = true;
    // The clustering spans all texels: run as stages (`staged`).
    const BLOCKWISE: crate::blockwise::Blockwise = crate::blockwise::Blockwise::Staged("clustered_pca");

    /// Not linear across clusters: the mean appearance projected ([`Lpca::mip_texels`]).
    const MIP: Mip = Mip::Projected;

    fn mip_texels(&self, groups: &[Vec<(u32, f32)>]) -> Result<Self> {
        Lpca::mip_texels(self, groups)
    }

    fn fit(btf: &BtfRef<'_>, options: &LpcaOptions, monitor: &Monitor) -> Result<Self> {
        if options.clusters > MAX_CLUSTERS {
            return Err(Error::arg("clusters", format!("expected 1 to {MAX_CLUSTERS}, got {}", options.clusters)));
        }
        fit_lpca(btf, options, monitor)
    }

    /// LPCA sizes its chunks by the limit and names the least it needs itself (`memory_plan`).
    fn least_memory(_btf: &BtfRef<'_>, _options: &LpcaOptions) -> u64 {
        0
    }

    /// `ids` `[H, W]` i32, `weights` `[H, W, c + 2]` f32, `basis` `[K, c + 1, V, L, 4]` u8,
    /// `scale` and `bias` `[K, c + 1]` f32, `views` `[V, 3]` and `lights` `[L, 3]` f64.
    fn to_arrays(&self) -> NamedArrays {
        let mut a = NamedArrays::new();
        let (k, c1) = (self.clusters, self.components + 1);
        let (nv, nl) = (self.views.len(), self.lights.len());
        a.put("ids", &[self.height, self.width], self.ids.iter().map(|&x| x as i32).collect::<Vec<i32>>());
        a.put("weights", &[self.height, self.width, c1 + 1], self.weights.clone());
        a.put("basis", &[k, c1, nv, nl, 4], self.basis.clone());
        a.put("scale", &[k, c1], self.scale.clone());
        a.put("bias", &[k, c1], self.bias.clone());
        a.put_directions("views", &self.views);
        a.put_directions("lights", &self.lights);
        a
    }

    fn from_arrays(a: &NamedArrays) -> Result<Self> {
        let (ids, sh) = a.get::<i32>("ids", &[None, None])?;
        let (basis, bs) = a.get::<u8>("basis", &[None, None, None, None, Some(4)])?;
        // An empty component axis would underflow `components` below.
        if bs[0] == 0 || bs[1] == 0 {
            return Err(Error::arg(
                "basis",
                format!("expected at least one cluster and one Eigen-BRDF, got shape {bs:?}"),
            ));
        }
        let (weights, _) = a.get::<f32>("weights", &[Some(sh[0]), Some(sh[1]), Some(bs[1] + 1)])?;
        let (scale, _) = a.get::<f32>("scale", &[Some(bs[0]), Some(bs[1])])?;
        let (bias, _) = a.get::<f32>("bias", &[Some(bs[0]), Some(bs[1])])?;
        let views = a.directions("views", Some(bs[2]))?;
        let lights = a.directions("lights", Some(bs[3]))?;
        if let Some(i) = ids.iter().position(|&x| x < 0 || x as usize >= bs[0]) {
            return Err(Error::arg("ids", format!("entry {i} is {}, not a cluster in [0, {})", ids[i], bs[0])));
        }
        let m = Lpca {
            height: sh[0],
            width: sh[1],
            views,
            lights,
            clusters: bs[0],
            components: bs[1] - 1,
            ids: ids.iter().map(|&x| x as u32).collect(),
            weights: weights.to_vec(),
            basis: basis.to_vec(),
            scale: scale.to_vec(),
            bias: bias.to_vec(),
            sampled: None,
        };
        m.validate()?;
        Ok(m)
    }

    fn report(&self) -> serde_json::Value {
        let mut r = serde_json::json!({"clusters": self.clusters, "components": self.components});
        if let Some(f) = self.sampled {
            r["sample"] = f.sample.into();
            r["relative_error"] = f.relative_error.into();
        }
        r
    }

    fn shaders() -> Vec<Shader> {
        vec![<Self as GpuLayout>::SHADER, <Lpca3d<'static> as GpuLayout>::SHADER]
    }

    fn renderer(&self, method: &str, max_3d: usize) -> Result<Box<dyn Renderable + '_>> {
        match method {
            "9tap" | "default" => Ok(Box::new(self)),
            "3d" => Ok(Box::new(Lpca3d::new(self, texture3d::DEFAULT_GRID, max_3d)?)),
            o => Err(unknown_renderer(Self::KIND, Self::RENDERERS, o)),
        }
    }
}

mod texture3d;
pub use texture3d::{Lpca3d, Lpca3dParams, DEFAULT_GRID};

#[cfg(test)]
mod tests;
