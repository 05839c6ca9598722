//! k-means clustering (k-means++ seeding, Lloyd iterations) of points stored column-major.
//!
//! Used by the local PCA fit (`btfrs_fit::lpca`, paper 004 section 3: "k-means on ABRDFs, PCA per
//! cluster") and meant for texton analysis too. Points are the columns of a `dim x n` `f32`
//! matrix, i.e. point `i` is `points[i * dim..(i + 1) * dim]` (a BTF's texel-major data is such a
//! matrix of ABRDFs). Squared distances are computed as `|x|^2 - 2 x.c + |c|^2` with one GEMM per
//! iteration (a parallel `matrixmultiply` GEMM), so the cost is that of a matrix product even for long
//! vectors; points of at most four values (an RGB texture's pixels, for texton analysis) are
//! compared directly in `f64` instead, where the GEMM's table would cost more than its arithmetic;
//! sums are accumulated in `f64`, and every sum has a fixed order, so the result
//! depends only on the seed, never on the number of threads.
//!
//! * **Seeding**: greedy k-means++ (Arthur and Vassilvitskii 2007) as scikit-learn does it: each
//!   new centre is the best, by total potential, of `2 + ln k` candidates drawn with probability
//!   proportional to the squared distance to the nearest centre so far. When every point already
//!   coincides with a centre (fewer distinct points than `k`), seeding stops: fewer clusters are
//!   returned rather than duplicated centres.
//! * **Empty clusters** after an assignment are re-seeded with the point farthest from its own
//!   centre (taken from a cluster that keeps at least one member), the usual remedy: the point
//!   that is worst served moves to a centre of its own, which lowers the inertia.
//! * **Stopping**: after `iterations` Lloyd steps, or earlier when no point changes cluster.

use crate::dense::{cols, cols_t, gemm};
use btfrs_core::{rng::Rng, Error, Monitor, Result};
use rayon::prelude::*;

/// A k-means result.
#[derive(Debug, Clone)]
pub struct KMeans {
    /// Dimension of the points.
    pub dim: usize,
    /// `[k, dim]` centres (k may be below the requested count, see the module doc).
    pub centers: Vec<f32>,
    /// Cluster of each point.
    pub assign: Vec<u32>,
    /// Sum of squared distances of the points to their centres.
    pub inertia: f64,
    /// Lloyd iterations run.
    pub iterations: usize,
}

impl KMeans {
    /// Number of clusters.
    pub fn k(&self) -> usize {
        self.centers.len() / self.dim.max(1)
    }
}

/// Cluster the `n = points.len() / dim` points into (at most) `k` clusters.
///
/// `monitor` advances by one per Lloyd iteration (plus the skipped ones when it converges early,
/// so a caller that announced `iterations` units sees them all) and can cancel between iterations.
pub fn kmeans(points: &[f32], dim: usize, k: usize, iterations: usize, seed: u64, monitor: &Monitor) -> Result<KMeans> {
    if dim == 0 || points.is_empty() || !points.len().is_multiple_of(dim) {
        return Err(Error::arg(
            "points",
            format!("expected a non-empty [n, {dim}] array, got {} values", points.len()),
        ));
    }
    let n = points.len() / dim;
    if k == 0 || k > n {
        return Err(Error::arg("k", format!("expected 1 to {n} clusters (the number of points), got {k}")));
    }
    if iterations == 0 {
        return Err(Error::arg("iterations", "expected at least 1 iteration, got 0"));
    }
    let norms: Vec<f64> = points.par_chunks(dim).map(sq_norm).collect();
    let mut centers = seed_plus_plus(points, dim, &norms, k, seed);
    let k = centers.len() / dim;
    let mut assign = vec![u32::MAX; n];
    let mut dist = vec![0.0f64; n];
    let mut done = 0;
    for it in 0..iterations {
        monitor.check()?;
        let changed = assign_nearest(points, dim, &norms, &centers, &mut assign, &mut dist);
        done = it + 1;
        monitor.advance(1);
        if changed == 0 && it > 0 {
            break;
        }
        reseed_empty(points, dim, k, &mut assign, &mut dist, &mut centers);
        centers = means(points, dim, k, &assign);
    }
    monitor.advance((iterations - done) as u64);
    // Final assignment against the final centres, so that `assign` and `inertia` agree with them.
    assign_nearest(points, dim, &norms, &centers, &mut assign, &mut dist);
    reseed_empty(points, dim, k, &mut assign, &mut dist, &mut centers);
    let inertia = dist.iter().sum();
    Ok(KMeans { dim, centers, assign, inertia, iterations: done })
}

#[inline]
fn sq_norm(x: &[f32]) -> f64 {
    x.iter().map(|&v| v as f64 * v as f64).sum()
}

/// Squared distances `[m, n]` (column-major, point-major: entry (c, i) at `i * m + c`) of every
/// point to the `m` candidate centres `cand` (`[m, dim]`).
///
/// The GEMM form `|x|^2 - 2 x.c + |c|^2` cancels badly when `x` is close to `c` (an `f32` dot
/// product of `dim` terms is only good to about `sqrt(dim)` ulps of `|x| |c|`), so a distance
/// below `1e-4 (|x|^2 + |c|^2)` is recomputed directly in `f64`: duplicated points are then
/// exactly 0 apart (k-means++ must see them as one), at a cost only for near-coincident pairs.
fn distances(points: &[f32], dim: usize, norms: &[f64], cand: &[f32]) -> Vec<f64> {
    let m = cand.len() / dim;
    let n = norms.len();
    let dots = gemm(&cols_t(cand, dim, m), &cols(points, dim, n));
    let cn: Vec<f64> = cand.chunks(dim).map(sq_norm).collect();
    let mut out = vec![0.0f64; m * n];
    out.par_chunks_mut(m).zip(dots.as_slice().par_chunks(m)).zip(norms.par_iter()).enumerate().for_each(
        |(i, ((o, d), &xn))| {
            for c in 0..m {
                let g = xn - 2.0 * d[c] as f64 + cn[c];
                o[c] = if g > 1e-4 * (xn + cn[c]) {
                    g
                } else {
                    let (x, y) = (&points[i * dim..(i + 1) * dim], &cand[c * dim..(c + 1) * dim]);
                    x.iter().zip(y).map(|(&a, &b)| (a as f64 - b as f64).powi(2)).sum()
                };
            }
        },
    );
    out
}

/// Greedy k-means++ seeding; returns `[k', dim]` centres, `k' <= k`.
///
/// Each round scores every candidate against every point. Two things keep that cheap without
/// changing a bit of the result:
/// * very short vectors (an RGB texture's pixels) hold all the candidates in the lanes of one
///   vector ([`potentials`]);
/// * longer ones skip a point whose nearest centre `a` so far is far from the candidate `c`:
///   when `|c - a|^2 >= PRUNE |x - a|^2`, the triangle inequality puts `c` farther from `x` than
///   `a` is, so the point keeps its distance whatever `|x - c|` is. `PRUNE` is 4 (twice the
///   distance) with a margin far above the rounding of the `f32` sums, so a skipped point is
///   one whose computed distance would have lost too.
fn seed_plus_plus(points: &[f32], dim: usize, norms: &[f64], k: usize, seed: u64) -> Vec<f32> {
    let n = norms.len();
    let mut rng = Rng::new(seed);
    let first = rng.below(n);
    let mut centers: Vec<f32> = points[first * dim..(first + 1) * dim].to_vec();
    let mut closest: Vec<f64> = points.par_chunks(dim).map(|x| direct(x, &centers)).collect();
    // The centre `closest` measures, for the pruning bound.
    let mut near = vec![0u32; n];
    let trials = 2 + (k as f64).ln() as usize;
    let mut cdf = vec![0.0f64; n];
    let mut d = vec![0.0f64; n * trials];
    let parallel = n * trials * dim > SEED_SERIAL_WORK;
    let short = dim < 8 && trials <= LANES;
    // The centres coordinate-major (`columns[k][centre]`), for the bound's distances.
    let mut columns: Vec<Vec<f32>> = if short { Vec::new() } else { centers.iter().map(|&x| vec![x]).collect() };
    while centers.len() / dim < k {
        let Some(picks) = draw(&closest, &mut cdf, trials, &mut rng) else {
            // Every point sits on a centre already: there are no more distinct points to seed.
            break;
        };
        let cand: Vec<f32> = picks.iter().flat_map(|&p| points[p * dim..(p + 1) * dim].iter().copied()).collect();
        // The candidates' distances to the centres so far (`[candidate][centre]`), for the bound:
        // coordinate by coordinate across the centres, so the loop runs in vector lanes. Only
        // compared with a 1% margin, so any accurate order of the sums serves.
        let kc = centers.len() / dim;
        let cc: Vec<f64> = if short { Vec::new() } else { centre_distances(&cand, &columns, kc) };
        // Each point's distance to each candidate (`[block][candidate][point]`, infinite where
        // the bound skips it) and, per block of points, the potential each candidate would
        // leave; blocks are fixed and summed in order, so the result does not depend on the
        // threads. The distances are direct (x - c)^2 sums, exactly 0 between equal points,
        // which is what the seeding must see.
        let block = |b: usize, dd: &mut [f64], cl: &[f64], nr: &[u32]| -> Vec<f64> {
            let len = cl.len();
            let xs = &points[b * SEED_BLOCK * dim..][..len * dim];
            if short {
                return if trials <= LANES / 2 {
                    potentials::<{ LANES / 2 }>(xs, dim, cl, &cand, trials, dd)
                } else {
                    potentials::<LANES>(xs, dim, cl, &cand, trials, dd)
                };
            }
            // Point by point, every candidate's sum at once: each sum keeps its order (points in
            // turn), and the candidates' sums are independent chains the core overlaps. A skipped
            // point keeps its distance (the minimum below would choose it).
            let mut pot = [0.0f64; MAX_TRIALS];
            let pot = &mut pot[..trials];
            for ((x, &best), &a) in xs.chunks(dim).zip(cl).zip(nr) {
                let ca = &cc[a as usize..];
                for (c, p) in pot.iter_mut().enumerate() {
                    if ca[c * kc] >= PRUNE * best {
                        *p += best;
                        continue;
                    }
                    let o = direct(x, &cand[c * dim..(c + 1) * dim]);
                    // Not `f64::min`: no distance is NaN, and a plain comparison is one instruction.
                    *p += if o < best { o } else { best };
                }
            }
            pot.to_vec()
        };
        // A small round (a texture's few thousand pixels) costs less than waking the threads.
        let pots: Vec<Vec<f64>> = if parallel {
            d.par_chunks_mut(SEED_BLOCK * trials)
                .zip(closest.par_chunks(SEED_BLOCK))
                .zip(near.par_chunks(SEED_BLOCK))
                .enumerate()
                .map(|(b, ((dd, cl), nr))| block(b, dd, cl, nr))
                .collect()
        } else {
            d.chunks_mut(SEED_BLOCK * trials)
                .zip(closest.chunks(SEED_BLOCK))
                .zip(near.chunks(SEED_BLOCK))
                .enumerate()
                .map(|(b, ((dd, cl), nr))| block(b, dd, cl, nr))
                .collect()
        };
        let pots: Vec<f64> = (0..trials).map(|c| pots.iter().map(|p| p[c]).sum()).collect();
        // The candidate that leaves the smallest potential wins (first on ties: deterministic).
        let best = (0..trials).fold(0, |b, c| if pots[c] < pots[b] { c } else { b });
        // The winner's distances: from the table for short points, recomputed for the others
        // (the points the bound does not skip: a few percent once there are many centres).
        let winner = &cand[best * dim..(best + 1) * dim];
        let update = |(b, ((cl, nr), dd)): UpdateBlock<'_>| {
            let len = cl.len();
            let xs = &points[b * SEED_BLOCK * dim..][..len * dim];
            for (i, ((c, a), x)) in cl.iter_mut().zip(nr.iter_mut()).zip(xs.chunks(dim)).enumerate() {
                let o = if short {
                    dd[best * len + i]
                } else if cc[best * kc + *a as usize] >= PRUNE * *c {
                    continue;
                } else {
                    direct(x, winner)
                };
                if o < *c {
                    *c = o;
                    *a = kc as u32;
                }
            }
        };
        if parallel {
            closest
                .par_chunks_mut(SEED_BLOCK)
                .zip(near.par_chunks_mut(SEED_BLOCK))
                .zip(d.par_chunks(SEED_BLOCK * trials))
                .enumerate()
                .for_each(update);
        } else {
            closest
                .chunks_mut(SEED_BLOCK)
                .zip(near.chunks_mut(SEED_BLOCK))
                .zip(d.chunks(SEED_BLOCK * trials))
                .enumerate()
                .for_each(update);
        }
        centers.extend_from_slice(winner);
        if !short {
            columns.iter_mut().zip(winner).for_each(|(col, &x)| col.push(x));
        }
    }
    centers
}

/// Squared distances `[candidate][centre]` of the candidates `cand` (`[m, dim]`) to the `kc`
/// centres stored coordinate-major (`columns[k][centre]`), in `f32` per coordinate across the
/// centres (vector lanes), widened at the end.
fn centre_distances(cand: &[f32], columns: &[Vec<f32>], kc: usize) -> Vec<f64> {
    let dim = columns.len();
    let mut acc = vec![0.0f32; kc];
    let mut out = Vec::with_capacity(cand.len() / dim.max(1) * kc);
    for c in cand.chunks(dim) {
        acc.fill(0.0);
        for (&x, col) in c.iter().zip(columns) {
            for (a, &y) in acc.iter_mut().zip(col) {
                *a += (x - y) * (x - y);
            }
        }
        out.extend(acc.iter().map(|&a| a as f64));
    }
    out
}

/// `trials` candidate points drawn with probability proportional to `closest`, their squared
/// distances to the nearest centre (inverse CDF over the prefix sums, written to `cdf`); `None`
/// when every point sits on a centre.
fn draw(closest: &[f64], cdf: &mut [f64], trials: usize, rng: &mut Rng) -> Option<Vec<usize>> {
    let mut acc = 0.0;
    for (c, &x) in cdf.iter_mut().zip(closest) {
        acc += x;
        *c = acc;
    }
    if acc <= 0.0 {
        return None;
    }
    let last = closest.len() - 1;
    let pick = |u: f64| cdf.partition_point(|&c| c <= u).min(last);
    Some((0..trials).map(|_| pick(rng.next_f64() * acc)).collect())
}

/// The pruning bound's factor (see [`seed_plus_plus`]): 4, the squared triangle inequality,
/// widened by 1%, far above the relative rounding of a sum of squares in `f32` (about `1e-3`
/// for a BTF texel's twenty thousand values).
const PRUNE: f64 = 4.04;

/// One block of the seeding's update: its index, its points' nearest distances and centres, and
/// its slice of the distance table.
type UpdateBlock<'a> = (usize, ((&'a mut [f64], &'a mut [u32]), &'a [f64]));

/// Points per block of the seeding's parallel passes.
const SEED_BLOCK: usize = 256;

/// Most candidates held in the lanes of one vector by the seeding of very short vectors.
const LANES: usize = 16;

/// The potential each of `trials <= L` candidates (`cand`, `[trials, dim]`) would leave over the
/// points `xs` (fewer than 8 coordinates each) whose nearest squared distances so far are `cl`,
/// summed point after point; the distances go to `dd` (`[candidate][point]`). Each distance is
/// [`direct`]'s (for so few coordinates its sum is one `f32` chain over them): the candidates
/// sit in the lanes of one vector, coordinate by coordinate, and the lanes past `trials` are
/// computed and dropped.
fn potentials<const L: usize>(
    xs: &[f32],
    dim: usize,
    cl: &[f64],
    cand: &[f32],
    trials: usize,
    dd: &mut [f64],
) -> Vec<f64> {
    let len = cl.len();
    let ct: Vec<[f32; L]> =
        (0..dim).map(|k| std::array::from_fn(|c| if c < trials { cand[c * dim + k] } else { 0.0 })).collect();
    let mut pot = [0.0f64; L];
    for (i, (x, &best)) in xs.chunks_exact(dim).zip(cl).enumerate() {
        let mut s = [0.0f32; L];
        for (&xk, ck) in x.iter().zip(&ct) {
            for (s, &c) in s.iter_mut().zip(ck) {
                let e = xk - c;
                *s += e * e;
            }
        }
        for (c, (p, &o)) in pot.iter_mut().zip(&s).enumerate() {
            let o = o as f64;
            if c < trials {
                dd[c * len + i] = o;
            }
            // Not `f64::min`: no distance is NaN, and a plain comparison is one instruction.
            *p += if o < best { o } else { best };
        }
    }
    pot[..trials].to_vec()
}

/// Most candidates a seeding round draws (`2 + ln k` for `k` up to 2^32).
const MAX_TRIALS: usize = 24;

/// Largest seeding round (points x candidates x coordinates) run on the calling thread: below
/// it, a round is a few tens of microseconds, about what waking the pool costs, and a texton
/// analysis runs a thousand rounds.
const SEED_SERIAL_WORK: usize = 1 << 18;

/// `|x - c|^2`, the differences in `f32` (exact for equal points), summed in `f64`.
#[inline]
fn direct(x: &[f32], c: &[f32]) -> f64 {
    // Eight partial sums in f32 per run of 64 values vectorise; runs are added in f64.
    let mut total = 0.0f64;
    for (xs, cs) in x.chunks(64).zip(c.chunks(64)) {
        let mut acc = [0.0f32; 8];
        let mut xi = xs.chunks_exact(8);
        let mut ci = cs.chunks_exact(8);
        for (a, b) in (&mut xi).zip(&mut ci) {
            for l in 0..8 {
                let e = a[l] - b[l];
                acc[l] += e * e;
            }
        }
        let mut run: f32 = acc.iter().sum();
        for (&a, &b) in xi.remainder().iter().zip(ci.remainder()) {
            run += (a - b) * (a - b);
        }
        total += run as f64;
    }
    total
}

/// Assign every point to its nearest centre; returns how many changed. `dist` gets the squared
/// distances to the chosen centres.
fn assign_nearest(
    points: &[f32],
    dim: usize,
    norms: &[f64],
    centers: &[f32],
    assign: &mut [u32],
    dist: &mut [f64],
) -> usize {
    let k = centers.len() / dim;
    if dim <= SHORT_DIM {
        return assign_short(points, dim, centers, assign, dist);
    }
    // In blocks of points, so the [n, k] distances (and the GEMM behind them) are held for one
    // block at a time: a texton analysis with a thousand centres would otherwise hold 12 kB per
    // point. Each point's distances do not depend on the blocking.
    let block = (ASSIGN_BLOCK_VALUES / k.max(1)).max(1);
    let mut changed = 0;
    for (b, (a, dd)) in assign.chunks_mut(block).zip(dist.chunks_mut(block)).enumerate() {
        let (i0, len) = (b * block, a.len());
        let d = distances(&points[i0 * dim..(i0 + len) * dim], dim, &norms[i0..i0 + len], centers);
        changed += a
            .par_iter_mut()
            .zip(dd.par_iter_mut())
            .zip(d.par_chunks(k))
            .map(|((a, dd), row)| {
                let best = (0..k).fold(0, |b, c| if row[c] < row[b] { c } else { b });
                *dd = row[best];
                let changed = *a != best as u32;
                *a = best as u32;
                usize::from(changed)
            })
            .sum::<usize>();
    }
    changed
}

/// Longest points [`assign_nearest`] compares directly with every centre.
const SHORT_DIM: usize = 4;

/// [`assign_nearest`] for points of at most [`SHORT_DIM`] values (an RGB texture's pixels): the
/// distances directly in `f64`, every centre's in turn from a coordinate-major copy of the
/// centres, so they run in vector lanes. A GEMM over three-value vectors would spend more on
/// writing its `[n, k]` table than on the arithmetic.
fn assign_short(points: &[f32], dim: usize, centers: &[f32], assign: &mut [u32], dist: &mut [f64]) -> usize {
    let k = centers.len() / dim;
    let ct: Vec<Vec<f64>> = (0..dim).map(|j| centers.chunks(dim).map(|c| c[j] as f64).collect()).collect();
    assign
        .par_chunks_mut(SEED_BLOCK)
        .zip(dist.par_chunks_mut(SEED_BLOCK))
        .zip(points.par_chunks(SEED_BLOCK * dim))
        .map(|((a, dd), xs)| {
            let mut row = vec![0.0f64; k];
            let mut changed = 0;
            for ((a, dd), x) in a.iter_mut().zip(dd.iter_mut()).zip(xs.chunks_exact(dim)) {
                let x0 = x[0] as f64;
                for (o, &c) in row.iter_mut().zip(&ct[0]) {
                    *o = (x0 - c) * (x0 - c);
                }
                for (&xj, cj) in x.iter().zip(&ct).skip(1) {
                    let xj = xj as f64;
                    for (o, &c) in row.iter_mut().zip(cj) {
                        *o += (xj - c) * (xj - c);
                    }
                }
                let best = argmin(&row);
                *dd = row[best];
                changed += usize::from(*a != best as u32);
                *a = best as u32;
            }
            changed
        })
        .sum()
}

/// The first index of the smallest value (none is NaN), scanned in eight interleaved lanes so
/// that the comparisons do not wait on each other.
fn argmin(row: &[f64]) -> usize {
    let mut lanes = [(f64::INFINITY, usize::MAX); 8];
    let mut chunks = row.chunks_exact(8);
    for (b, ch) in (&mut chunks).enumerate() {
        for (l, (&v, lane)) in ch.iter().zip(lanes.iter_mut()).enumerate() {
            if v < lane.0 {
                *lane = (v, b * 8 + l);
            }
        }
    }
    let tail = row.len() - chunks.remainder().len();
    let mut best = (f64::INFINITY, usize::MAX);
    for (l, &v) in chunks.remainder().iter().enumerate() {
        if v < best.0 {
            best = (v, tail + l);
        }
    }
    // Each lane holds its first smallest; the smallest value's lowest index wins among them.
    for lane in lanes {
        if lane.0 < best.0 || (lane.0 == best.0 && lane.1 < best.1) {
            best = lane;
        }
    }
    if best.1 == usize::MAX {
        0
    } else {
        best.1
    }
}

/// Point-centre distances per block of [`assign_nearest`] (2^20: 12 MB of f64 distances and f32
/// dot products).
pub const ASSIGN_BLOCK_VALUES: usize = 1 << 20;

/// Give every empty cluster the point farthest from its centre (see the module doc).
fn reseed_empty(points: &[f32], dim: usize, k: usize, assign: &mut [u32], dist: &mut [f64], centers: &mut [f32]) {
    let mut count = vec![0usize; k];
    for &a in assign.iter() {
        count[a as usize] += 1;
    }
    for c in 0..k {
        if count[c] > 0 {
            continue;
        }
        let far =
            (0..assign.len()).filter(|&i| count[assign[i] as usize] > 1).fold(None, |b: Option<usize>, i| match b {
                Some(j) if dist[j] >= dist[i] => Some(j),
                _ => Some(i),
            });
        let Some(i) = far else { return };
        count[assign[i] as usize] -= 1;
        count[c] = 1;
        assign[i] = c as u32;
        dist[i] = 0.0;
        centers[c * dim..(c + 1) * dim].copy_from_slice(&points[i * dim..(i + 1) * dim]);
    }
}

/// Cluster means (`f64` sums in point order); an empty cluster keeps a zero centre (the callers
/// re-seed empty clusters before asking).
fn means(points: &[f32], dim: usize, k: usize, assign: &[u32]) -> Vec<f32> {
    let members = members_of(assign, k);
    let mut out = vec![0.0f32; k * dim];
    out.par_chunks_mut(dim).zip(members.par_iter()).for_each(|(c, m)| {
        let mut acc = vec![0.0f64; dim];
        for &i in m {
            for (a, &x) in acc.iter_mut().zip(&points[i as usize * dim..(i as usize + 1) * dim]) {
                *a += x as f64;
            }
        }
        let inv = 1.0 / m.len().max(1) as f64;
        for (o, a) in c.iter_mut().zip(acc) {
            *o = (a * inv) as f32;
        }
    });
    out
}

/// The members of each of `k` clusters, in increasing point order.
pub fn members_of(assign: &[u32], k: usize) -> Vec<Vec<u32>> {
    let mut m = vec![Vec::new(); k];
    for (i, &a) in assign.iter().enumerate() {
        m[a as usize].push(i as u32);
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dense::gaussian;

    /// `k` blobs of `per` points in `dim` dimensions around well separated centres.
    fn blobs(k: usize, per: usize, dim: usize, seed: u64) -> (Vec<f32>, Vec<u32>) {
        let c = gaussian(dim, k, seed);
        let noise = gaussian(dim, k * per, seed + 1);
        let mut pts = Vec::new();
        let mut truth = Vec::new();
        for i in 0..k * per {
            // Interleave the blobs so that cluster order and point order differ.
            let b = i % k;
            for d in 0..dim {
                pts.push(10.0 * c[(d, b)] + 0.1 * noise[(d, i)]);
            }
            truth.push(b as u32);
        }
        (pts, truth)
    }

    #[test]
    fn separated_blobs_are_found_exactly() {
        let (pts, truth) = blobs(6, 40, 5, 1);
        let km = kmeans(&pts, 5, 6, 50, 0, &Monitor::new()).unwrap();
        assert_eq!(km.k(), 6);
        // A relabelling of the truth: each found cluster maps to one true blob and back.
        let mut map = [u32::MAX; 6];
        for (&a, &t) in km.assign.iter().zip(&truth) {
            assert!(map[a as usize] == u32::MAX || map[a as usize] == t, "cluster {a} mixes blobs");
            map[a as usize] = t;
        }
        let mut seen = map.to_vec();
        seen.sort();
        assert_eq!(seen, vec![0, 1, 2, 3, 4, 5]);
        // Inertia equals the brute-force sum of squared distances to the returned centres.
        let brute: f64 = (0..pts.len() / 5)
            .map(|i| {
                let c = km.assign[i] as usize;
                (0..5).map(|d| (pts[i * 5 + d] as f64 - km.centers[c * 5 + d] as f64).powi(2)).sum::<f64>()
            })
            .sum();
        assert!((km.inertia - brute).abs() < 1e-3 * brute, "{} {brute}", km.inertia);
        // Each centre is the mean of its members (Lloyd's fixed point).
        let again = means(&pts, 5, 6, &km.assign);
        let worst = again.iter().zip(&km.centers).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
        assert!(worst < 1e-5, "{worst}");
    }

    /// Greedy k-means++ as the module doc states it, every distance computed: the reference the
    /// lanes and the pruning must reproduce bit for bit.
    fn seed_reference(points: &[f32], dim: usize, k: usize, seed: u64) -> Vec<f32> {
        let n = points.len() / dim;
        let mut rng = Rng::new(seed);
        let first = rng.below(n);
        let mut centers = points[first * dim..(first + 1) * dim].to_vec();
        let mut closest: Vec<f64> = points.chunks(dim).map(|x| direct(x, &centers)).collect();
        let trials = 2 + (k as f64).ln() as usize;
        while centers.len() / dim < k {
            let Some(picks) = draw(&closest, &mut vec![0.0; n], trials, &mut rng) else { break };
            let dist = |c: usize, i: usize| direct(&points[i * dim..(i + 1) * dim], &points[picks[c] * dim..][..dim]);
            // Potentials per block of points, the blocks added in order.
            let pots: Vec<f64> = (0..trials)
                .map(|c| {
                    (0..n)
                        .step_by(SEED_BLOCK)
                        .map(|b0| (b0..n.min(b0 + SEED_BLOCK)).fold(0.0, |p, i| p + closest[i].min(dist(c, i))))
                        .sum()
                })
                .collect();
            let best = (0..trials).fold(0, |b, c| if pots[c] < pots[b] { c } else { b });
            for (i, c) in closest.iter_mut().enumerate() {
                *c = c.min(dist(best, i));
            }
            centers.extend_from_slice(&points[picks[best] * dim..][..dim]);
        }
        centers
    }

    #[test]
    fn candidates_are_drawn_by_the_inverse_cdf_of_one_uniform_each() {
        // Points 0 and 2 sit on centres (never drawn); 1 and 3 hold a quarter and three quarters.
        let closest = [0.0, 1.0, 0.0, 3.0];
        let (mut rng, mut twin) = (Rng::new(5), Rng::new(5));
        let picks = draw(&closest, &mut [0.0; 4], 200, &mut rng).unwrap();
        for &p in &picks {
            let u = twin.next_f64() * 4.0;
            assert_eq!(p, if u < 1.0 { 1 } else { 3 });
        }
        let ones = picks.iter().filter(|&&p| p == 1).count();
        assert!((30..=70).contains(&ones), "{ones} of 200 draws of the point holding a quarter");
        assert_eq!(rng.next_f64(), twin.next_f64(), "one uniform per candidate");
        assert!(draw(&[0.0, 0.0], &mut [0.0; 2], 3, &mut rng).is_none());
    }

    #[test]
    fn seeding_skips_only_what_the_reference_would_not_change() {
        // Separated blobs (where the bound skips most points once each blob has a centre), in
        // vectors too long for the lanes and short ones, in serial and parallel rounds.
        for (k, per, dim) in [(8usize, 40usize, 12usize), (5, 90, 3), (12, 60, 70), (6, 300, 40)] {
            let (pts, _) = blobs(k, per, dim, 4);
            let norms: Vec<f64> = pts.chunks(dim).map(sq_norm).collect();
            for want in [k, 3 * k] {
                let got = seed_plus_plus(&pts, dim, &norms, want, 21);
                assert_eq!(got, seed_reference(&pts, dim, want, 21), "{k} blobs of {per} in {dim} dimensions");
            }
        }
    }

    #[test]
    fn lane_potentials_have_the_bits_of_the_direct_ones() {
        // Up to 7 coordinates, with as many candidates as lanes and fewer, one of them a point.
        for (dim, trials) in [(1usize, 3usize), (3, 8), (3, 16), (5, 11), (7, 2)] {
            let mut rng = Rng::new(dim as u64 * 31 + trials as u64);
            let n = 50;
            let xs: Vec<f32> = (0..n * dim).map(|_| rng.next_f64() as f32 * 2.0 - 1.0).collect();
            let mut cand: Vec<f32> = (0..trials * dim).map(|_| rng.next_f64() as f32).collect();
            cand[..dim].copy_from_slice(&xs[7 * dim..8 * dim]);
            let cl: Vec<f64> = (0..n).map(|_| rng.next_f64()).collect();
            let mut dd = vec![0.0f64; n * trials];
            let got = if trials <= 8 {
                potentials::<8>(&xs, dim, &cl, &cand, trials, &mut dd)
            } else {
                potentials::<16>(&xs, dim, &cl, &cand, trials, &mut dd)
            };
            for c in 0..trials {
                let mut want = 0.0f64;
                for (i, (x, &best)) in xs.chunks(dim).zip(&cl).enumerate() {
                    let o = direct(x, &cand[c * dim..(c + 1) * dim]);
                    assert_eq!(dd[c * n + i].to_bits(), o.to_bits());
                    want += best.min(o);
                }
                assert_eq!(got[c].to_bits(), want.to_bits(), "dim {dim}, candidate {c} of {trials}");
            }
        }
    }

    #[test]
    fn short_points_take_the_nearest_centre_by_a_float64_reference() {
        // Three-value points (an RGB texture's) and 37 centres, with ties: two centres equal,
        // so the lower index must win, and a point equal to a centre.
        let mut rng = Rng::new(9);
        let pts: Vec<f32> = (0..3 * 300).map(|_| (rng.below(16) as f32) / 15.0).collect();
        let mut centers: Vec<f32> = (0..3 * 37).map(|_| rng.next_f64() as f32).collect();
        centers.copy_within(3..6, 30);
        centers[..3].copy_from_slice(&pts[..3]);
        let (mut a, mut d) = (vec![u32::MAX; 300], vec![0.0f64; 300]);
        assign_short(&pts, 3, &centers, &mut a, &mut d);
        for i in 0..300 {
            let dist =
                |c: usize| -> f64 { (0..3).map(|j| (pts[3 * i + j] as f64 - centers[3 * c + j] as f64).powi(2)).sum() };
            let want = (0..37).fold(0, |b, c| if dist(c) < dist(b) { c } else { b });
            assert_eq!(a[i] as usize, want, "point {i}");
            assert!((d[i] - dist(want)).abs() <= 1e-15, "point {i}");
            assert_ne!(a[i], 10, "centre 10 equals centre 1, which comes first");
        }
        assert_eq!((a[0], d[0]), (0, 0.0));
        // The lanes of the argmin keep the first of equal values, wherever they fall.
        for len in [1usize, 7, 8, 9, 17, 40] {
            for at in 0..len {
                let mut row = vec![1.0f64; len];
                row[at] = 0.5;
                if at + 3 < len {
                    row[at + 3] = 0.5;
                }
                assert_eq!(argmin(&row), at, "len {len}, at {at}");
            }
            assert_eq!(argmin(&vec![2.0; len]), 0);
        }
    }

    #[test]
    fn fewer_distinct_points_than_clusters() {
        // Three distinct points, repeated: asking for 5 clusters gives 3, each exact.
        let base = [[0.0f32, 0.0], [1.0, 0.0], [0.0, 2.0]];
        let pts: Vec<f32> = (0..30).flat_map(|i| base[i % 3]).collect();
        let km = kmeans(&pts, 2, 5, 10, 3, &Monitor::new()).unwrap();
        assert_eq!(km.k(), 3);
        assert_eq!(km.inertia, 0.0);
        let zeros = vec![0.0f32; 40];
        let km = kmeans(&zeros, 4, 3, 10, 3, &Monitor::new()).unwrap();
        assert_eq!(km.k(), 1);
        assert!(km.assign.iter().all(|&a| a == 0));
    }

    #[test]
    fn seeded_and_argument_checks() {
        let (pts, _) = blobs(4, 30, 3, 5);
        let a = kmeans(&pts, 3, 7, 20, 11, &Monitor::new()).unwrap();
        let b = kmeans(&pts, 3, 7, 20, 11, &Monitor::new()).unwrap();
        assert_eq!(a.assign, b.assign);
        assert_eq!(a.centers, b.centers);
        let e = kmeans(&pts, 3, 121, 20, 0, &Monitor::new()).unwrap_err().to_string();
        assert!(e.starts_with("k:") && e.contains("120"), "{e}");
        assert!(kmeans(&pts, 3, 0, 20, 0, &Monitor::new()).is_err());
        assert!(kmeans(&pts, 3, 2, 0, 0, &Monitor::new()).unwrap_err().to_string().starts_with("iterations:"));
        let m = Monitor::new();
        m.cancel();
        assert!(matches!(kmeans(&pts, 3, 2, 5, 0, &m), Err(Error::Interrupted)));
    }
}
