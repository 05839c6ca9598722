//! Randomized PCA: the randomized range finder of Halko, Martinsson and Tropp ("Finding
//! structure with randomness: probabilistic algorithms for constructing approximate matrix
//! decompositions", SIAM Review 53(2), 2011), for the matrices too big for an exact
//! eigenproblem.
//!
//! A Gaussian test matrix `Omega` (from the seed) is multiplied into the data, `Y = A Omega`; the
//! orthonormalised columns of `Y` span, with high probability, nearly all of the leading
//! `l = r + oversampling` directions of `A`'s column space. Steps of subspace iteration
//! (`Q <- orth(A orth(A^T Q))`, their algorithm 4.4) sharpen the subspace towards the leading
//! singular vectors when the spectrum decays slowly, as the ABRDFs of a BTF do. The principal
//! directions are then those of the small projected problem (a Rayleigh-Ritz step). Every step is
//! a GEMM over the data, read in place (see `dense.rs`).
//!
//! Used by:
//!
//! * the local PCA fit (paper 004, sections 3 and 6.3; `btfrs_fit::lpca`): step 1, the principal
//!   coordinates the clustering works in (`coordinates_map`), and the final PCA of large clusters
//!   (`top_directions`);
//! * the texture synthesis (paper 000, section 4.1: the textons are compared "by a PCA projection
//!   of them"), through [`principal_coordinates`].

use crate::dense::{self, cols, cols_t, gaussian, gemm, gram_t, orthonormalize, sym_eigen_desc, view, view_t};
use btfrs_core::{ensure_arg, rng::Rng, Monitor, Result};
use nalgebra::DMatrix;
use rayon::prelude::*;

/// Extra columns of every randomized range finder.
pub const OVERSAMPLE: usize = 10;
/// Subspace iterations of [`top_directions`].
const POWER_ITERS: usize = 2;
/// Points the range finder of [`coordinates_map`] samples.
const RANGE_SAMPLE: usize = 2048;
/// Progress units of [`coordinates_map`] and [`principal_coordinates`] (one per pass over the data).
pub const PROGRESS_UNITS: u64 = 4;

/// `[n, r']` principal coordinates (`r' <= r`, texel-major) of the `n` points of dimension `d`
/// stored point-major in `data`, by the randomized PCA of the LPCA fit's first step (a random
/// range finder, see `coordinates_map`' notes). Distances between the
/// coordinates approximate the distances between the points, which is what the texton analysis
/// of the synthesis (paper 000 section 4.1, "a PCA projection of them") needs. `monitor`
/// advances by 4 (`PROGRESS_UNITS`). `chunk`: the most points whose values may be copied at
/// once (`None`: no bound; an out-of-core caller streams the range finder's sample through it).
/// `power_iterations` (0 or 1): steps of subspace iteration in the range finder, 1 as the LPCA
/// fit; 0 saves two of its three products over the sample (about 40% of the work for
/// a few thousand points) for a subspace that is a little less sharp, which is enough where the
/// coordinates only compare points (the texton analysis).
#[allow(clippy::too_many_arguments)] // the data, its shape, the options, the monitor
pub fn principal_coordinates(
    data: &[f32],
    d: usize,
    n: usize,
    r: usize,
    seed: u64,
    chunk: Option<usize>,
    power_iterations: usize,
    monitor: &Monitor,
) -> Result<(Vec<f32>, usize)> {
    ensure_arg!(d > 0 && n > 0 && data.len() == d * n, "data", "expected {n} x {d} values, got {}", data.len());
    ensure_arg!(r > 0, "dims", "expected at least 1 principal component, got 0");
    ensure_arg!(power_iterations <= 1, "power_iterations", "expected 0 or 1, got {power_iterations}");
    coordinates_map(data, d, n, r, seed, chunk, power_iterations, monitor).map(|(p, r, _)| (p, r))
}

/// The map [`coordinates_map`] applies to every texel, kept to apply to texels it did not see
/// (those a fit on a sample of texels streams afterwards): centre `mu`, subspace `q` (`d x l`)
/// and the rotation `vr` (`l x r'`) to the principal axes within it.
#[derive(Debug, Clone)]
pub struct CoordinateMap {
    pub mu: Vec<f32>,
    pub q: DMatrix<f32>,
    pub vr: DMatrix<f32>,
}

impl CoordinateMap {
    /// `[n, r']` coordinates (texel-major) of the `n` texels of `data` (`n x d`, texel-major),
    /// by the same two products as [`coordinates_map`]' own.
    pub fn apply(&self, data: &[f32], d: usize) -> Vec<f32> {
        let n = data.len() / d.max(1);
        if self.vr.ncols() == 0 || n == 0 {
            return Vec::new();
        }
        let z = centred_t_times(data, d, n, &self.mu, &self.q);
        axes_times(&self.vr, &z)
    }

    /// Coordinates of rows of already projected texels (`z`: `n x l`, as [`project_texels`]
    /// gives them): the rotation only.
    pub fn rotate(&self, z: &DMatrix<f32>) -> Vec<f32> {
        if self.vr.ncols() == 0 || z.nrows() == 0 {
            return Vec::new();
        }
        axes_times(&self.vr, z)
    }
}

/// `[T, r']` principal coordinates (`r' <= r`; 0 when all texels are equal) of the
/// columns of the `d x t` matrix over `data`, by a randomized PCA: the range finder with one step of subspace
/// iteration (Halko et al.'s algorithm 4.4 with `q = 1`), then the principal axes within the
/// subspace from a small eigenproblem. `monitor` advances by [`PROGRESS_UNITS`].
///
/// The subspace is found on a random subset of at most [`RANGE_SAMPLE`] texels (all of them in a
/// smaller sample), then every texel is projected on it: `3 s / t + 1` passes over the data
/// instead of 4, and the cost of the reduction stops growing with the sample size beyond one
/// projection pass. A few thousand ABRDFs pin down the leading principal directions of a
/// material well; the coordinates only steer the clustering, never the stored basis.
///
/// `chunk`: the most texels whose values may be copied at once (`None`: no bound). When the
/// sample does not fit, it is streamed through [`Gathered`] instead of copied: the same
/// subspace up to rounding, in bounded memory (an out-of-core fit of a memory-mapped BTF).
///
/// `power` (0 or 1): steps of subspace iteration in the range finder (1: the LPCA fit; 0: see
/// [`principal_coordinates`]). Returns the map too ([`CoordinateMap`]), to apply to texels the
/// call did not see.
#[allow(clippy::too_many_arguments)] // the data, its shape, the options, the monitor
pub fn coordinates_map(
    data: &[f32],
    d: usize,
    t: usize,
    r: usize,
    seed: u64,
    chunk: Option<usize>,
    power: usize,
    monitor: &Monitor,
) -> Result<(Vec<f32>, usize, CoordinateMap)> {
    let mut rng = Rng::new(seed);
    let s = t.min(RANGE_SAMPLE);
    let pick = pick_sample(&mut rng, t);
    let l = (r + OVERSAMPLE).min(s).min(d);
    // Centre on the subset's mean: any fixed centre gives the same clustering, and this one
    // costs no pass over the whole data.
    let (q, mu) = match &pick {
        Some(pick) if chunk.is_some_and(|c| c < s) => {
            // Streamed: the sample read chunk by chunk, never copied whole.
            let sub = Gathered { data, d, idx: pick, centre: None, chunk: chunk.unwrap_or(s) };
            let mu = dense::column_mean(data, d, Some(pick));
            (range_finder(&sub, &mu, l, power, &mut rng, monitor)?, mu)
        }
        Some(pick) => {
            let mut g = vec![0.0f32; s * d];
            g.par_chunks_mut(d).zip(pick.par_iter()).for_each(|(o, &j)| {
                o.copy_from_slice(&data[j as usize * d..(j as usize + 1) * d]);
            });
            let mu = dense::column_mean(&g, d, None);
            (range_finder(&Dense { data: &g, d, n: s }, &mu, l, power, &mut rng, monitor)?, mu)
        }
        None => {
            let mu = dense::column_mean(data, d, None);
            (range_finder(&Dense { data, d, n: s }, &mu, l, power, &mut rng, monitor)?, mu)
        }
    };
    let z = centred_t_times(data, d, t, &mu, &q);
    monitor.advance(1);
    let (p, keep, vr) = principal_axes_map(&z, r);
    Ok((p, keep, CoordinateMap { mu, q, vr }))
}

/// The range finder's sample of [`coordinates_map`]: `None` when it is every texel (at most
/// [`RANGE_SAMPLE`]), else [`RANGE_SAMPLE`] texels drawn by a partial Fisher-Yates shuffle from
/// `rng`, in texel order.
fn pick_sample(rng: &mut Rng, t: usize) -> Option<Vec<u32>> {
    let s = t.min(RANGE_SAMPLE);
    (s < t).then(|| {
        let mut idx: Vec<u32> = (0..t as u32).collect();
        for i in 0..s {
            idx.swap(i, i + rng.below(t - i));
        }
        let mut pick = idx[..s].to_vec();
        pick.sort_unstable();
        pick
    })
}

/// The texels (`None`: all `t`) whose ABRDFs [`coordinates_map`] with `seed` finds its subspace on:
/// the first stage of the blockwise LPCA fit (`btfrs_fit::lpca::staged`), which gathers them.
pub fn sample_texels(t: usize, seed: u64) -> Option<Vec<u32>> {
    pick_sample(&mut Rng::new(seed), t)
}

/// The centre and the orthonormal `d x l` subspace [`coordinates_map`] with `seed` finds on the
/// sample of [`sample_texels`], given that sample's values (`s x d`, texel-major, in the
/// sample's order): the same numbers as the in-memory path of [`coordinates_map`].
pub fn sample_subspace(
    sample: &[f32],
    d: usize,
    t: usize,
    r: usize,
    seed: u64,
    monitor: &Monitor,
) -> Result<(Vec<f32>, DMatrix<f32>)> {
    let mut rng = Rng::new(seed);
    let s = t.min(RANGE_SAMPLE);
    ensure_arg!(d > 0 && sample.len() == s * d, "sample", "expected {s} x {d} values, got {}", sample.len());
    ensure_arg!(r > 0, "reduced_dims", "expected at least 1 principal coordinate, got 0");
    let _ = pick_sample(&mut rng, t); // the same random stream as `coordinates_map`
    let l = (r + OVERSAMPLE).min(s).min(d);
    let mu = dense::column_mean(sample, d, None);
    let q = range_finder(&Dense { data: sample, d, n: s }, &mu, l, 1, &mut rng, monitor)?;
    Ok((mu, q))
}

/// `[n, l]` (column-major `n x l`) coordinates of the `n` texels of `data` (`n x d`,
/// texel-major) in the subspace `q` centred on `mu`: one block's share of [`coordinates_map`]'
/// projection pass; the rows of all blocks in texel order go to [`principal_axes`].
pub fn project_texels(data: &[f32], d: usize, mu: &[f32], q: &DMatrix<f32>) -> Result<DMatrix<f32>> {
    ensure_arg!(
        d > 0 && data.len().is_multiple_of(d) && mu.len() == d && q.nrows() == d,
        "data",
        "expected texels of {d} values for a {} x {} subspace, got {} values",
        q.nrows(),
        q.ncols(),
        data.len()
    );
    Ok(centred_t_times(data, d, data.len() / d, mu, q))
}

/// The range finder of [`coordinates_map`] on the sample `sub` (centred on `mu` inside the products):
/// `l` orthonormal columns spanning its leading principal directions, after one power iteration.
/// `monitor` advances by 3.
fn range_finder(
    sub: &impl Columns,
    mu: &[f32],
    l: usize,
    power: usize,
    rng: &mut Rng,
    monitor: &Monitor,
) -> Result<DMatrix<f32>> {
    let omega = gaussian(sub.shape().1, l, rng.next_u64());
    let mut y = sub.times(&omega);
    subtract_mean_outer(&mut y, mu, &omega);
    let q = orthonormalize(&y);
    drop(y); // each d x l intermediate goes as soon as it is used (the memory plans count two)
    monitor.advance(1);
    monitor.check()?;
    if power == 0 {
        monitor.advance(2);
        return Ok(q);
    }
    // One power iteration sharpens the subspace towards the leading singular vectors.
    let mut z = sub.t_times(&q);
    subtract_mu_q(&mut z, mu, &q);
    drop(q);
    let z = orthonormalize(&z);
    monitor.advance(1);
    monitor.check()?;
    let mut y = sub.times(&z);
    subtract_mean_outer(&mut y, mu, &z);
    let q = orthonormalize(&y);
    drop(y);
    monitor.advance(1);
    monitor.check()?;
    Ok(q)
}

/// The projected texels `z` (`t x l`) rotated to principal axes within the subspace, the `r`
/// strongest kept: `([t, r'], r')` texel-major, `r' = 0` when every texel projects the same.
pub fn principal_axes(z: &DMatrix<f32>, r: usize) -> (Vec<f32>, usize) {
    let (p, keep, _) = principal_axes_map(z, r);
    (p, keep)
}

/// [`principal_axes`] with the rotation (`l x r'`) it applied.
pub fn principal_axes_map(z: &DMatrix<f32>, r: usize) -> (Vec<f32>, usize, DMatrix<f32>) {
    let (vals, vecs) = sym_eigen_desc(gram_t(z));
    let top = vals.first().copied().unwrap_or(0.0);
    let keep = vals.iter().take(r).take_while(|&&v| top > 0.0 && v > 1e-10 * top).count();
    let vr = DMatrix::<f32>::from_fn(vecs.nrows(), keep, |i, j| vecs[(i, j)] as f32);
    if keep == 0 {
        return (Vec::new(), 0, vr);
    }
    (axes_times(&vr, z), keep, vr)
}

/// `(z vr)` texel-major: `[n, r']` for `z` (`n x l`) and `vr` (`l x r'`).
fn axes_times(vr: &DMatrix<f32>, z: &DMatrix<f32>) -> Vec<f32> {
    gemm(&view_t(vr), &view_t(z)).as_slice().to_vec()
}

/// `m -= u s^T` for a column vector `u` (rows) and the column sums `s` of `x`.
fn subtract_mean_outer(m: &mut DMatrix<f32>, u: &[f32], x: &DMatrix<f32>) {
    let s: Vec<f64> = x.column_iter().map(|c| c.iter().map(|&v| v as f64).sum()).collect();
    m.column_iter_mut().zip(s).for_each(|(mut col, sj)| {
        for (v, &ui) in col.iter_mut().zip(u) {
            *v -= (ui as f64 * sj) as f32;
        }
    });
}

/// `A_c^T q` for the centred data `A_c = A - mu 1^T` (`A` is `d x t` over `data`): `t x l`.
fn centred_t_times(data: &[f32], d: usize, t: usize, mu: &[f32], q: &DMatrix<f32>) -> DMatrix<f32> {
    let mut z = gemm(&cols_t(data, d, t), &view(q));
    subtract_mu_q(&mut z, mu, q);
    z
}

/// `z -= 1 (mu^T q)`: the same number from every row of a column (centring `A^T q` afterwards).
fn subtract_mu_q(z: &mut DMatrix<f32>, mu: &[f32], q: &DMatrix<f32>) {
    for (j, mut col) in z.column_iter_mut().enumerate() {
        let mq: f64 = q.column(j).iter().zip(mu).map(|(&a, &b)| a as f64 * b as f64).sum();
        col.iter_mut().for_each(|v| *v -= mq as f32);
    }
}

/// The (at most) `c` leading principal directions of the centred columns of `xc` (`dim x n`), as
/// orthonormal columns (`dim x c'`, `c' <= c`: directions whose eigenvalue is below `cut` times
/// the largest are dropped), by randomized subspace iteration (Halko et al., algorithm 4.4, with
/// [`POWER_ITERS`] iterations and [`OVERSAMPLE`] extra columns) and a Rayleigh-Ritz step on the
/// subspace found. For matrices too large for an exact eigenproblem in both dimensions; `xc` is
/// only ever multiplied, so it may be one streamed from a memory-mapped BTF ([`Gathered`]).
pub fn top_directions(xc: &impl Columns, c: usize, seed: u64, cut: f64) -> DMatrix<f32> {
    let (dim, n) = xc.shape();
    let l = (c + OVERSAMPLE).min(n).min(dim);
    let omega = gaussian(n, l, seed);
    let mut q = orthonormalize(&xc.times(&omega));
    for _ in 0..POWER_ITERS {
        let z = orthonormalize(&xc.t_times(&q));
        q = orthonormalize(&xc.times(&z));
    }
    let b = xc.t_times(&q).transpose();
    let s = gemm(&view(&b), &view_t(&b));
    let s = DMatrix::from_fn(s.nrows(), s.ncols(), |i, j| 0.5 * (s[(i, j)] as f64 + s[(j, i)] as f64));
    let (vals, vecs) = sym_eigen_desc(s);
    let keep = (0..c.min(vals.len())).take_while(|&j| vals[0] > 0.0 && vals[j] > cut * vals[0]).count();
    let u = DMatrix::<f32>::from_fn(q.ncols(), keep, |i, j| vecs[(i, j)] as f32);
    gemm(&view(&q), &view(&u))
}

/// A `d x n` matrix that the randomized PCA only multiplies: held in memory, or gathered chunk
/// by chunk from a larger one ([`Gathered`]) so that a fit of a memory-mapped BTF never holds
/// more than one chunk of its values.
pub trait Columns: Sync {
    /// `(d, n)`.
    fn shape(&self) -> (usize, usize);
    /// `A M` (`d x l`) for an `n x l` matrix `M`.
    fn times(&self, m: &DMatrix<f32>) -> DMatrix<f32>;
    /// `A^T Q` (`n x l`) for a `d x l` matrix `Q`.
    fn t_times(&self, q: &DMatrix<f32>) -> DMatrix<f32>;
}

impl Columns for DMatrix<f32> {
    fn shape(&self) -> (usize, usize) {
        self.shape()
    }
    fn times(&self, m: &DMatrix<f32>) -> DMatrix<f32> {
        gemm(&view(self), &view(m))
    }
    fn t_times(&self, q: &DMatrix<f32>) -> DMatrix<f32> {
        gemm(&view_t(self), &view(q))
    }
}

/// The `d x n` column-major matrix over `data`, borrowed (a sample copied whole, or all the data).
#[derive(Debug, Clone, Copy)]
pub struct Dense<'a> {
    pub data: &'a [f32],
    pub d: usize,
    pub n: usize,
}

impl Columns for Dense<'_> {
    fn shape(&self) -> (usize, usize) {
        (self.d, self.n)
    }
    fn times(&self, m: &DMatrix<f32>) -> DMatrix<f32> {
        gemm(&cols(self.data, self.d, self.n), &view(m))
    }
    fn t_times(&self, q: &DMatrix<f32>) -> DMatrix<f32> {
        gemm(&cols_t(self.data, self.d, self.n), &view(q))
    }
}

/// Columns `idx` of the `d x T` matrix over `data` (a BTF's texel-major values: one texel per
/// column), minus `centre` when given, gathered at most `chunk` columns at a time: the products
/// are summed (`A M`) or stacked (`A^T Q`) chunk by chunk, so the memory held is one `d x chunk`
/// block whatever the number of columns. Every product is the same sum of the same terms as over
/// the gathered matrix, only blocked.
#[derive(Debug, Clone, Copy)]
pub struct Gathered<'a> {
    pub data: &'a [f32],
    pub d: usize,
    pub idx: &'a [u32],
    pub centre: Option<&'a [f32]>,
    pub chunk: usize,
}

impl Gathered<'_> {
    /// Calls `f(first, block)` for each chunk: `block` is `d x s`, columns `first..first + s`.
    fn for_each_chunk(&self, mut f: impl FnMut(usize, &DMatrix<f32>)) {
        let chunk = self.chunk.max(1);
        let mut block = DMatrix::<f32>::zeros(self.d, chunk.min(self.idx.len()));
        for (ci, ids) in self.idx.chunks(chunk).enumerate() {
            if block.ncols() != ids.len() {
                // The last, shorter chunk: free the full block before allocating it.
                drop(std::mem::replace(&mut block, DMatrix::<f32>::zeros(0, 0)));
                block = DMatrix::<f32>::zeros(self.d, ids.len());
            }
            block.as_mut_slice().par_chunks_mut(self.d.max(1)).zip(ids.par_iter()).for_each(|(o, &j)| {
                let x = &self.data[j as usize * self.d..(j as usize + 1) * self.d];
                match self.centre {
                    Some(mu) => o.iter_mut().zip(x).zip(mu).for_each(|((o, &x), &m)| *o = x - m),
                    None => o.copy_from_slice(x),
                }
            });
            f(ci * chunk, &block);
        }
    }
}

impl Columns for Gathered<'_> {
    fn shape(&self) -> (usize, usize) {
        (self.d, self.idx.len())
    }
    fn times(&self, m: &DMatrix<f32>) -> DMatrix<f32> {
        let (n, l) = m.shape();
        if l == 0 {
            // No columns (a subspace of a constant cluster): nothing to sum, and no rows to view.
            return DMatrix::<f32>::zeros(self.d, 0);
        }
        // The chunks' products summed in f64 (a long fit sums thousands of them).
        let mut acc = DMatrix::<f64>::zeros(self.d, l);
        self.for_each_chunk(|first, x| {
            // Rows first..first + s of the column-major n x l matrix m.
            let s = x.ncols();
            let rows = crate::dense::View::from_slice_with_strides(&m.as_slice()[first..], s, l, 1, n);
            let p = gemm(&view(x), &rows);
            acc.iter_mut().zip(p.iter()).for_each(|(a, &v)| *a += v as f64);
        });
        acc.map(|v| v as f32)
    }
    fn t_times(&self, q: &DMatrix<f32>) -> DMatrix<f32> {
        let mut out = DMatrix::<f32>::zeros(self.idx.len(), q.ncols());
        self.for_each_chunk(|first, x| {
            out.rows_mut(first, x.ncols()).copy_from(&gemm(&view_t(x), &view(q)));
        });
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `d x n` matrix of columns `idx` of the `d x t` data minus `centre`, gathered at once.
    fn gathered(data: &[f32], d: usize, idx: &[u32], centre: &[f32]) -> DMatrix<f32> {
        DMatrix::from_fn(d, idx.len(), |i, j| data[idx[j] as usize * d + i] - centre[i])
    }

    #[test]
    fn streamed_products_equal_the_gathered_ones_for_every_chunk_size() {
        let (d, t) = (37, 90);
        let data = gaussian(d, t, 1);
        let idx: Vec<u32> = (0..t as u32).filter(|j| j % 3 != 1).collect();
        let centre: Vec<f32> = (0..d).map(|i| 0.1 * i as f32).collect();
        let full = gathered(data.as_slice(), d, &idx, &centre);
        let m = gaussian(idx.len(), 9, 2);
        let q = gaussian(d, 9, 3);
        let (am, atq) = (full.times(&m), full.t_times(&q));
        for chunk in [1, 5, 32, idx.len(), 1000] {
            let g = Gathered { data: data.as_slice(), d, idx: &idx, centre: Some(&centre), chunk };
            assert_eq!(g.shape(), (d, idx.len()));
            let close = |a: &DMatrix<f32>, b: &DMatrix<f32>| (a - b).abs().max() <= 1e-4 * b.abs().max();
            assert!(close(&g.times(&m), &am), "A M, chunk {chunk}");
            assert!(close(&g.t_times(&q), &atq), "A^T Q, chunk {chunk}");
        }
        // A product with no columns (the subspace of a constant cluster) is empty, not a panic.
        let g = Gathered { data: data.as_slice(), d, idx: &idx, centre: Some(&centre), chunk: 5 };
        assert_eq!(g.times(&DMatrix::zeros(idx.len(), 0)).shape(), (d, 0));
        assert_eq!(g.t_times(&DMatrix::zeros(d, 0)).shape(), (idx.len(), 0));
        // Without a centre the columns are the data's own.
        let g = Gathered { data: data.as_slice(), d, idx: &idx, centre: None, chunk: 4 };
        let zero = vec![0.0f32; d];
        let raw = gathered(data.as_slice(), d, &idx, &zero);
        assert!((g.t_times(&q) - raw.t_times(&q)).abs().max() <= 1e-4 * raw.t_times(&q).abs().max());
    }

    #[test]
    fn streamed_top_directions_span_the_same_subspace() {
        // Rank-3 data plus small noise: the three leading directions, found in memory and
        // streamed 7 columns at a time, span the same subspace (projector difference ~ 0).
        let (d, n) = (60, 200);
        let basis = orthonormalize(&gaussian(d, 3, 4));
        let coef = gaussian(3, n, 5) * 10.0;
        let x = &basis * coef + gaussian(d, n, 6) * 1e-3;
        let idx: Vec<u32> = (0..n as u32).collect();
        let zero = vec![0.0f32; d];
        let a = top_directions(&x, 3, 7, 1e-8);
        let g = Gathered { data: x.as_slice(), d, idx: &idx, centre: Some(&zero), chunk: 7 };
        let b = top_directions(&g, 3, 7, 1e-8);
        assert_eq!((a.ncols(), b.ncols()), (3, 3));
        let pa = &a * a.transpose();
        let pb = &b * b.transpose();
        let pt = &basis * basis.transpose();
        assert!((&pa - &pb).abs().max() < 1e-4, "{}", (&pa - &pb).abs().max());
        assert!((&pa - &pt).abs().max() < 1e-3, "{}", (&pa - &pt).abs().max());
    }

    #[test]
    fn streamed_coordinates_match_the_in_memory_ones() {
        // 3000 texels (above the 2048-texel range sample) streamed 100 at a time: the same
        // seeded sample and steps, so the same coordinates up to rounding and sign.
        let (d, t) = (24, 3000);
        let basis = gaussian(d, 4, 8);
        let data = &basis * gaussian(4, t, 9) + gaussian(d, t, 10) * 0.01;
        let m = Monitor::new();
        let (a, ra, _) = coordinates_map(data.as_slice(), d, t, 4, 11, None, 1, &m).unwrap();
        let (b, rb, _) = coordinates_map(data.as_slice(), d, t, 4, 11, Some(100), 1, &m).unwrap();
        assert_eq!((ra, rb), (4, 4));
        let scale = a.iter().fold(0.0f32, |s, v| s.max(v.abs()));
        for j in 0..4 {
            let col = |p: &[f32]| (0..t).map(|i| p[i * 4 + j]).collect::<Vec<f32>>();
            let (ca, cb) = (col(&a), col(&b));
            let sign = if ca.iter().zip(&cb).map(|(x, y)| x * y).sum::<f32>() < 0.0 { -1.0 } else { 1.0 };
            let worst = ca.iter().zip(&cb).map(|(x, y)| (x - sign * y).abs()).fold(0.0f32, f32::max);
            assert!(worst < 1e-3 * scale, "coordinate {j}: {worst} of {scale}");
        }
    }
}
