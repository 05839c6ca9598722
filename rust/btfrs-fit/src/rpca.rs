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
//! * the local PCA fit (paper 004, sections 3 and 6.3; [`crate::lpca`]): step 1, the principal
//!   coordinates the clustering works in (`coordinates`), and the final PCA of large clusters
//!   (`top_directions`);
//! * the texture synthesis (paper 000, section 4.1: the textons are compared "by a PCA projection
//!   of them"), through [`principal_coordinates`].

use crate::dense::{self, cols, cols_t, gaussian, gemm, gram_t, orthonormalize, sym_eigen_desc, view, view_t};
use btfrs_core::{ensure_arg, rng::Rng, Monitor, Result};
use nalgebra::DMatrix;
use rayon::prelude::*;
use std::borrow::Cow;

/// Extra columns of every randomized range finder.
const OVERSAMPLE: usize = 10;
/// Subspace iterations of [`top_directions`].
const POWER_ITERS: usize = 2;
/// Points the range finder of [`coordinates`] samples.
const RANGE_SAMPLE: usize = 2048;
/// Progress units of [`coordinates`] and [`principal_coordinates`] (one per pass over the data).
pub(crate) const PROGRESS_UNITS: u64 = 4;

/// `[n, r']` principal coordinates (`r' <= r`, texel-major) of the `n` points of dimension `d`
/// stored point-major in `data`, by the randomized PCA of the LPCA fit's first step (a random
/// range finder with one power iteration, see `coordinates`' notes). Distances between the
/// coordinates approximate the distances between the points, which is what the texton analysis
/// of the synthesis (paper 000 section 4.1, "a PCA projection of them") needs. `monitor`
/// advances by 4 (`PROGRESS_UNITS`).
pub fn principal_coordinates(
    data: &[f32],
    d: usize,
    n: usize,
    r: usize,
    seed: u64,
    monitor: &Monitor,
) -> Result<(Vec<f32>, usize)> {
    ensure_arg!(d > 0 && n > 0 && data.len() == d * n, "data", "expected {n} x {d} values, got {}", data.len());
    ensure_arg!(r > 0, "dims", "expected at least 1 principal component, got 0");
    coordinates(data, d, n, r, seed, monitor)
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
pub(crate) fn coordinates(
    data: &[f32],
    d: usize,
    t: usize,
    r: usize,
    seed: u64,
    monitor: &Monitor,
) -> Result<(Vec<f32>, usize)> {
    let mut rng = Rng::new(seed);
    let s = t.min(RANGE_SAMPLE);
    let sub: Cow<'_, [f32]> = if s < t {
        // Partial Fisher-Yates: a uniform subset, kept in texel order.
        let mut idx: Vec<u32> = (0..t as u32).collect();
        for i in 0..s {
            idx.swap(i, i + rng.below(t - i));
        }
        let mut pick = idx[..s].to_vec();
        pick.sort_unstable();
        let mut g = vec![0.0f32; s * d];
        g.par_chunks_mut(d).zip(pick.par_iter()).for_each(|(o, &j)| {
            o.copy_from_slice(&data[j as usize * d..(j as usize + 1) * d]);
        });
        Cow::Owned(g)
    } else {
        Cow::Borrowed(data)
    };
    let l = (r + OVERSAMPLE).min(s).min(d);
    // Centre on the subset's mean: any fixed centre gives the same clustering, and this one
    // costs no pass over the whole data.
    let mu = dense::column_mean(&sub, d, None);
    let omega = gaussian(s, l, rng.next_u64());
    let mut y = gemm(&cols(&sub, d, s), &view(&omega));
    subtract_mean_outer(&mut y, &mu, &omega);
    let q = orthonormalize(&y);
    monitor.advance(1);
    monitor.check()?;
    // One power iteration sharpens the subspace towards the leading singular vectors.
    let z = centred_t_times(&sub, d, s, &mu, &q);
    let z = orthonormalize(&z);
    monitor.advance(1);
    monitor.check()?;
    let mut y = gemm(&cols(&sub, d, s), &view(&z));
    subtract_mean_outer(&mut y, &mu, &z);
    let q = orthonormalize(&y);
    drop(sub);
    monitor.advance(1);
    monitor.check()?;
    let z = centred_t_times(data, d, t, &mu, &q);
    monitor.advance(1);
    // Rotate to principal axes within the subspace and keep the r strongest.
    let (vals, vecs) = sym_eigen_desc(gram_t(&z));
    let top = vals.first().copied().unwrap_or(0.0);
    let keep = vals.iter().take(r).take_while(|&&v| top > 0.0 && v > 1e-10 * top).count();
    if keep == 0 {
        return Ok((Vec::new(), 0));
    }
    let vr = DMatrix::<f32>::from_fn(vecs.nrows(), keep, |i, j| vecs[(i, j)] as f32);
    let p = gemm(&view_t(&vr), &view_t(&z));
    Ok((p.as_slice().to_vec(), keep))
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
    // Subtract 1 (mu^T q): the same number from every row of a column.
    for (j, mut col) in z.column_iter_mut().enumerate() {
        let mq: f64 = q.column(j).iter().zip(mu).map(|(&a, &b)| a as f64 * b as f64).sum();
        col.iter_mut().for_each(|v| *v -= mq as f32);
    }
    z
}

/// The (at most) `c` leading principal directions of the centred columns of `xc` (`dim x n`), as
/// orthonormal columns (`dim x c'`, `c' <= c`: directions whose eigenvalue is below `cut` times
/// the largest are dropped), by randomized subspace iteration (Halko et al., algorithm 4.4, with
/// [`POWER_ITERS`] iterations and [`OVERSAMPLE`] extra columns) and a Rayleigh-Ritz step on the
/// subspace found. For matrices too large for an exact eigenproblem in both dimensions.
pub(crate) fn top_directions(xc: &DMatrix<f32>, c: usize, seed: u64, cut: f64) -> DMatrix<f32> {
    let (dim, n) = xc.shape();
    let l = (c + OVERSAMPLE).min(n).min(dim);
    let omega = gaussian(n, l, seed);
    let mut q = orthonormalize(&gemm(&view(xc), &view(&omega)));
    for _ in 0..POWER_ITERS {
        let z = orthonormalize(&gemm(&view_t(xc), &view(&q)));
        q = orthonormalize(&gemm(&view(xc), &view(&z)));
    }
    let b = gemm(&view_t(&q), &view(xc));
    let s = gemm(&view(&b), &view_t(&b));
    let s = DMatrix::from_fn(s.nrows(), s.ncols(), |i, j| 0.5 * (s[(i, j)] as f64 + s[(j, i)] as f64));
    let (vals, vecs) = sym_eigen_desc(s);
    let keep = (0..c.min(vals.len())).take_while(|&j| vals[0] > 0.0 && vals[j] > cut * vals[0]).count();
    let u = DMatrix::<f32>::from_fn(q.ncols(), keep, |i, j| vecs[(i, j)] as f32);
    gemm(&view(&q), &view(&u))
}
