//! The LPCA fit of a BTF of more texels than the `sample` option: two reads of the data instead
//! of the seven or so that steps 1 to 5 of [`super`] take over all texels (the finite-value scan,
//! the projection, then per cluster its mean, the randomized subspace iteration, the Rayleigh-Ritz
//! step and the weights' re-solve, in member order).
//!
//! 1. *Sample read*: `sample` texels drawn with the seed (in texel order) are copied whole.
//! 2. Steps 1 to 4 of the module doc run on the sample alone, as the in-memory fit of a BTF of
//!    that many texels: the principal coordinates (range finder on at most 2048 of them), k-means,
//!    the local-PCA refinement, each cluster's mean and Eigen-BRDFs, their quantization.
//! 3. *One streaming pass* over every texel in storage order, a block at a time (the next
//!    blocks read by a thread of their own while this one is computed): its
//!    values are checked finite; a texel outside the sample is projected on the sample's
//!    principal coordinates (the same map) and goes to the cluster whose affine subspace there
//!    reconstructs it best (the refinement's own criterion, against the clusters' final
//!    members); every texel's weights are solved against its cluster's dequantized Eigen-BRDFs
//!    (step 5's least squares); and the squared residual of that solve is summed, so the fit
//!    reports its reconstruction error without another pass ([`super::SampledFit`]).
//!
//! Sample texels keep their cluster from step 2, so each cluster's Eigen-BRDFs are those of its
//! sample members. Paper 004 (section 3) fits clustered PCA on all texels; a few thousand
//! ABRDFs per material already pin down its clusters and their leading directions, and the
//! texels outside the sample are still reconstructed by their best cluster and their own
//! least-squares weights. The blockwise fit ([`super::staged`]) follows the same stages.

use super::{
    cluster_basis, cluster_space, lpca_errors, mb, plan_parts, sub_seed, Basis, ClusterFit, LocalPca, Lpca,
    LpcaOptions, SampledFit, EXACT_MAX,
};
use btfrs_core::btf::{advise, stream_blocks, Access, TexelScan};
use btfrs_core::rng::{mix, Rng};
use btfrs_core::{BtfRef, Error, Monitor, Result};
use btfrs_numerics::dense::{cols, gemm, view_t};
use btfrs_numerics::rpca::{self, CoordinateMap};
use nalgebra::DMatrix;
use rayon::prelude::*;

/// Bytes of ABRDF values per block of the streaming pass (blocks are read ahead while one is
/// computed), at most: each block's texels are grouped by cluster for one product per cluster,
/// and a product costs a pass over the cluster's Eigen-BRDFs whatever its texels, so a block
/// must hold tens of texels of every cluster. Under a memory limit, an eighth of it.
const STREAM_BYTES: u64 = 256 << 20;

/// Blocks the streaming pass's reader thread keeps ahead of the one being computed.
const AHEAD: usize = 3;

/// Progress units of the streaming pass.
const STREAM_UNITS: u64 = 20;

/// The sample of a `t`-texel BTF (sorted texel indices), or `None` when the fit uses every texel:
/// `sample` is 0 or at least `t`, or the clustering runs in the full space (`reduced_dims = 0`,
/// which needs every texel's values at once anyway).
pub(crate) fn pick(t: usize, opts: &LpcaOptions) -> Option<Vec<u32>> {
    let s = opts.sample;
    if s == 0 || s >= t || opts.reduced_dims == 0 {
        return None;
    }
    // A partial Fisher-Yates shuffle: s distinct texels, uniformly, from the seed.
    let mut rng = Rng::new(sub_seed(opts.seed, 4));
    let mut idx: Vec<u32> = (0..t as u32).collect();
    for i in 0..s {
        idx.swap(i, i + rng.below(t - i));
    }
    idx.truncate(s);
    idx.sort_unstable();
    Some(idx)
}

/// Texels per block of the streaming pass for ABRDFs of `d` values.
fn block_texels(d: usize, t: usize, limit: Option<u64>) -> usize {
    let bytes = limit.map_or(STREAM_BYTES, |l| (l / 8).clamp(8 << 20, STREAM_BYTES));
    ((bytes / (4 * d.max(1) as u64)) as usize).clamp(64, 1 << 16).min(t)
}

/// The chunk the sample's own fit may stream its large clusters through, under `limit`, or an
/// error naming `memory_limit` (and `sample`) with the least the fit needs. Besides the sample's
/// fit ([`super::memory_plan`] for `s` texels): the sample, held whole; per texel of the BTF its
/// cluster, weights and the pass's ordering; the pass's block (a copy of its present pairs and one
/// grouped by cluster, its coordinates, distances and products); the clusters' dequantized
/// Eigen-BRDFs and means.
fn plan(limit: Option<u64>, t: usize, s: usize, d: usize, opts: &LpcaOptions, compact: bool) -> Result<Option<usize>> {
    let Some(limit) = limit else { return Ok(None) };
    let inner = plan_parts(s, d, opts, false)?;
    let (t64, s64, d64) = (t as u64, s as u64, d as u64);
    let (k, c) = (opts.clusters.min(s) as u64, opts.components as u64);
    let cc = c + 1;
    let l = (opts.reduced_dims.min(d) + rpca::OVERSAMPLE) as u64;
    let b = block_texels(d, t, Some(limit)) as u64;
    let whole = t64 * (8 + 12 * (c + 2) + 8); // ids, members; weights, per cluster, in the model
    let sample = s64 * d64 * 4;
    let block = b * (4 * d64 * (1 + u64::from(compact)) + 4 * 2 * l + 8 * k + 8 * (cc + 1) + 16);
    let bases = 4 * k * (cc + 1) * d64;
    let extra = whole + sample + block + bases;
    // Clusters of up to EXACT_MAX sample texels are always gathered for their exact PCA (a
    // larger one takes the randomized subspace iteration, gathered or streamed alike), so the fit
    // under a limit equals the unlimited fit.
    let least = extra + inner.fixed + inner.per_chunk + EXACT_MAX.min(s) as u64 * inner.per_texel_of_chunk;
    if limit < least {
        return Err(Error::arg(
            "memory_limit",
            format!(
                "expected at least {} for an LPCA fit of {t} texels of {d} values into {k} clusters on a sample of {s} \
                 texels ({} of it the sample, held whole: a smaller `sample` needs less), got {}",
                mb(least),
                mb(sample),
                mb(limit)
            ),
        ));
    }
    Ok(Some(inner.chunk(limit - extra, s)))
}

/// The fit (module doc) on the texels `pick` of `btf`.
pub(crate) fn fit(btf: &BtfRef<'_>, opts: &LpcaOptions, pick: &[u32], monitor: &Monitor) -> Result<Lpca> {
    let t = btf.texels();
    let s = pick.len();
    let (nv, nl) = (btf.views.len(), btf.lights.len());
    let vl = nv * nl;
    let pairs: Vec<usize> = (0..vl).filter(|&i| btf.has(i / nl, i % nl)).collect();
    let compact = pairs.len() < vl;
    let d = pairs.len() * 3;
    let chunk = plan(monitor.memory_limit(), t, s, d, opts, compact)?;
    let c = opts.components;
    let total =
        rpca::PROGRESS_UNITS + (opts.kmeans_iterations + opts.refine_iterations + opts.clusters) as u64 + STREAM_UNITS;
    monitor.start(total);

    // 1. The sample's present values, copied (its one read).
    let mut sample = vec![0.0f32; s * d];
    // Every value is checked as it is read (in the sample now, in the pass for the rest): the
    // caller does not scan first (`SCANS_VALUES`), and a bad value fails as its scan would.
    let scan = TexelScan::new();
    // Scattered reads: a fault reads its own pages, not the read-ahead window around them (which
    // would read most of a large file for a sample of a few percent of its texels).
    advise(btf.data, Access::Random);
    // Every sample texel's read queued at once (the storage serves them in its own order, many
    // at a time), then copied as they arrive.
    for &i in pick {
        advise(btf.texel(i as usize), Access::WillNeed);
    }
    sample.par_chunks_mut(d).zip(pick.par_iter()).for_each(|(o, &i)| {
        let x = btf.texel(i as usize);
        scan.check(x);
        present(x, &pairs, o);
    });
    advise(btf.data, Access::Normal);
    scan.finish("data", btf.data)?;
    monitor.check()?;

    // 2. Principal coordinates, clusters and their Eigen-BRDFs, on the sample alone.
    let (space, dim, map) =
        rpca::coordinates_map(&sample, d, s, opts.reduced_dims, sub_seed(opts.seed, 1), chunk, 1, monitor)?;
    monitor.check()?;
    let (ids_s, members) = cluster_space(&space, dim, s, opts, monitor)?;
    monitor.check()?;
    let pcas = reduced_pcas(&space, dim, &members, c, opts.seed);
    drop(space);
    let one = |(ci, m): (usize, &Vec<u32>)| -> Option<Basis> {
        if monitor.is_cancelled() {
            return None;
        }
        let (b, _) = cluster_basis(&sample, d, m, c, sub_seed(opts.seed, 1000 + ci as u64), chunk);
        monitor.advance(1);
        Some(b)
    };
    // Under a memory limit one cluster at a time (see the local fit).
    let bases: Vec<Option<Basis>> = match chunk {
        None => members.par_iter().enumerate().map(one).collect(),
        Some(_) => members.iter().enumerate().map(one).collect(),
    };
    monitor.check()?;
    let bases: Vec<Basis> = bases.into_iter().map(|b| b.expect("not cancelled")).collect();
    monitor.advance((opts.clusters - members.len()) as u64);
    drop(sample);

    // 3. Every texel: assigned (outside the sample), weights solved, residual summed.
    let mut ids = vec![u32::MAX; t];
    for (&i, &k) in pick.iter().zip(&ids_s) {
        ids[i as usize] = k;
    }
    let mut weights = vec![0.0f32; t * (c + 2)];
    let stream = Stream { btf, pairs: &pairs, compact, d, map: &map, dim, pcas: &pcas, bases: &bases };
    let (res, norm) = stream.run(&mut ids, &mut weights, monitor)?;

    let mut members_all: Vec<Vec<u32>> = vec![Vec::new(); bases.len()];
    for (i, &k) in ids.iter().enumerate() {
        members_all[k as usize].push(i as u32);
    }
    let fits: Vec<ClusterFit> = bases
        .into_iter()
        .zip(&members_all)
        .map(|(b, m)| {
            let mut w = Vec::with_capacity(m.len() * (c + 2));
            for &i in m {
                w.extend_from_slice(&weights[i as usize * (c + 2)..(i as usize + 1) * (c + 2)]);
            }
            ClusterFit { q: b.q, scale: b.scale, bias: b.bias, weights: w }
        })
        .collect();
    drop(weights);
    let mut lpca =
        super::assemble(btf.height, btf.width, btf.views, btf.lights, btf.mask, ids, &members_all, &fits, opts)?;
    let relative_error = if norm > 0.0 { (res.max(0.0) / norm).sqrt() } else { 0.0 };
    lpca.sampled = Some(SampledFit { sample: s, relative_error });
    Ok(lpca)
}

/// The present pairs of one texel's values (`x`: all `V L` pairs) into `out`.
fn present(x: &[f32], pairs: &[usize], out: &mut [f32]) {
    if out.len() == x.len() {
        out.copy_from_slice(x);
        return;
    }
    for (o, &pair) in out.chunks_exact_mut(3).zip(pairs) {
        o.copy_from_slice(&x[pair * 3..pair * 3 + 3]);
    }
}

/// Each cluster's affine subspace in the principal coordinates (`space`: `[s, dim]`), from its
/// final members: what the streaming pass assigns the other texels by.
pub(crate) fn reduced_pcas(
    space: &[f32],
    dim: usize,
    members: &[Vec<u32>],
    c: usize,
    seed: u64,
) -> Vec<Option<LocalPca>> {
    if dim == 0 {
        return Vec::new();
    }
    members
        .par_iter()
        .enumerate()
        .map(|(ci, m)| Some(super::local_pca(space, dim, m, c, mix(sub_seed(seed, 5) ^ ci as u64))))
        .collect()
}

/// The cluster of each texel of `coords` (`[n, dim]`): the one whose subspace reconstructs it
/// best (the lowest index on a tie); 0 for every texel when `dim` is 0 (all sample texels alike).
pub(crate) fn assign(coords: &[f32], dim: usize, pcas: &[Option<LocalPca>], c: usize) -> Vec<u32> {
    if dim == 0 {
        return vec![0; coords.len()];
    }
    let k = pcas.len();
    let err = lpca_errors(coords, dim, pcas, c);
    err.par_chunks(k).map(|e| (0..k).fold(0, |b, ci| if e[ci] < e[b] { ci } else { b }) as u32).collect()
}

/// Step 3 of the module doc.
struct Stream<'a, 'b> {
    btf: &'a BtfRef<'b>,
    pairs: &'a [usize],
    compact: bool,
    d: usize,
    map: &'a CoordinateMap,
    dim: usize,
    pcas: &'a [Option<LocalPca>],
    bases: &'a [Basis],
}

impl Stream<'_, '_> {
    /// Fill `ids` (where `u32::MAX`) and `weights` for every texel; returns the summed squared
    /// residual of the solves and the summed squared values.
    fn run(&self, ids: &mut [u32], weights: &mut [f32], monitor: &Monitor) -> Result<(f64, f64)> {
        let btf = self.btf;
        let (t, d) = (btf.texels(), self.d);
        let full = btf.data.len() / t.max(1);
        let c = self.bases.first().map_or(0, Basis::components);
        let block = block_texels(d, t, monitor.memory_limit());
        let (mut res, mut norm) = (0.0f64, 0.0f64);
        let mut copy = if self.compact { vec![0.0f32; block * d] } else { Vec::new() };
        let mut grouped = vec![0.0f32; block * d];
        let mut reported = 0u64;
        let out_of_core = monitor.memory_limit().is_some();
        stream_blocks(btf.data, full, block, AHEAD, |_, b0, n| {
            monitor.check()?;
            // The block's present values, in place or copied.
            let raw = &btf.data[b0 * full..(b0 + n) * full];
            let rows: &[f32] = if self.compact {
                copy[..n * d].par_chunks_mut(d).zip(raw.par_chunks(full)).for_each(|(o, x)| present(x, self.pairs, o));
                &copy[..n * d]
            } else {
                raw
            };
            if self.compact {
                // Absent pairs are checked too (as the caller's scan would); present values
                // below, as they are grouped.
                let scan = TexelScan::new();
                raw.par_chunks(full).for_each(|x| {
                    scan.check(x);
                });
                scan.finish("data", btf.data)?;
            }
            // Texels outside the sample go to their best cluster.
            if ids[b0..b0 + n].contains(&u32::MAX) {
                let coords = self.map.apply(rows, d);
                let best = assign(&coords, self.dim, self.pcas, c);
                for (id, &k) in ids[b0..b0 + n].iter_mut().zip(&best) {
                    if *id == u32::MAX {
                        *id = k;
                    }
                }
            }
            let ids_b = &ids[b0..b0 + n];
            // Grouped by cluster and centred on its mean, one product per cluster.
            let mut order: Vec<usize> = (0..n).collect();
            order.sort_by_key(|&i| ids_b[i]);
            // One read of each texel's values: checked, centred, their squared norms summed.
            let scan = TexelScan::new();
            let norms: Vec<(f64, f64)> = grouped[..n * d]
                .par_chunks_mut(d)
                .zip(order.par_iter())
                .map(|(o, &i)| {
                    let x = &rows[i * d..(i + 1) * d];
                    scan.check(x);
                    centre(x, &self.bases[ids_b[i] as usize].mean, o)
                })
                .collect();
            scan.finish("data", btf.data)?;
            let mut runs: Vec<(usize, usize)> = Vec::new();
            for (j, &i) in order.iter().enumerate() {
                match runs.last_mut() {
                    Some((start, end)) if ids_b[order[*start]] == ids_b[i] => *end = j + 1,
                    _ => runs.push((j, j + 1)),
                }
            }
            let solved: Vec<(Vec<f32>, f64, f64)> = runs
                .par_iter()
                .map(|&(a, z)| {
                    let basis = &self.bases[ids_b[order[a]] as usize];
                    solve(basis, &grouped[a * d..z * d], d, &norms[a..z])
                })
                .collect();
            let w_b = &mut weights[b0 * (c + 2)..(b0 + n) * (c + 2)];
            for (&(a, z), (w, r, x2)) in runs.iter().zip(solved) {
                for (j, &i) in order[a..z].iter().enumerate() {
                    w_b[i * (c + 2)..(i + 1) * (c + 2)].copy_from_slice(&w[j * (c + 2)..(j + 1) * (c + 2)]);
                }
                res += r;
                norm += x2;
            }
            if out_of_core {
                // Only out of core: on a BTF held in memory the advice would mark the caller's
                // own array as the first to swap out.
                advise(raw, Access::Done);
            }
            let done = ((b0 + n) as u64 * STREAM_UNITS) / t as u64;
            monitor.advance(done - reported);
            reported = done;
            Ok(())
        })?;
        Ok((res, norm))
    }
}

/// `out = x - mean`; returns `(|x|^2, |x - mean|^2)`, the squares summed in `f32` runs of 64
/// added in `f64`.
pub(crate) fn centre(x: &[f32], mean: &[f32], out: &mut [f32]) -> (f64, f64) {
    let (mut xx, mut cc) = (0.0f64, 0.0f64);
    for ((o, x), m) in out.chunks_mut(64).zip(x.chunks(64)).zip(mean.chunks(64)) {
        let (mut a, mut b) = (0.0f32, 0.0f32);
        for ((o, &x), &m) in o.iter_mut().zip(x).zip(m) {
            *o = x - m;
            a += x * x;
            b += *o * *o;
        }
        xx += a as f64;
        cc += b as f64;
    }
    (xx, cc)
}

/// The weights `[n, c + 2]` of `n` texels of one cluster (`xc`: their values minus the
/// cluster's mean, texel-major), their summed squared residual `|x - e~_0 - F a|^2` and summed
/// `|x|^2`; `norms`: per texel `(|x|^2, |xc|^2)` ([`centre`]).
pub(crate) fn solve(basis: &Basis, xc: &[f32], d: usize, norms: &[(f64, f64)]) -> (Vec<f32>, f64, f64) {
    let c = basis.components();
    let n = xc.len() / d;
    // One product gives F^T xc and delta^T xc, delta = mean - e~_0.
    let mut g = DMatrix::<f32>::zeros(d, c + 1);
    g.columns_mut(0, c).copy_from(&basis.deq.columns(1, c));
    for (o, (&m, &e0)) in g.column_mut(c).iter_mut().zip(basis.mean.iter().zip(basis.deq.column(0).iter())) {
        *o = m - e0;
    }
    let delta2: f64 = g.column(c).iter().map(|&v| v as f64 * v as f64).sum();
    let p = gemm(&view_t(&g), &cols(xc, d, n));
    let ftx = p.rows(0, c).into_owned();
    let (w, a) = basis.weights(&ftx);
    let mut res = 0.0f64;
    for i in 0..n {
        // |u|^2 - 2 a . F^T u + a^T F^T F a for u = x - e~_0 = xc + delta.
        let u2 = norms[i].1 + 2.0 * p[(c, i)] as f64 + delta2;
        let ai = a.column(i);
        let ftu: f64 = (0..c).map(|j| ai[j] * (ftx[(j, i)] as f64 + basis.shift[j])).sum();
        let afa = (ai.transpose() * &basis.ftf * ai)[(0, 0)];
        res += (u2 - 2.0 * ftu + afa).max(0.0);
    }
    (w, res, norms.iter().map(|n| n.0).sum())
}
