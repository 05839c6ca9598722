//! k-means clustering (k-means++ seeding, Lloyd iterations) of points stored column-major.
//!
//! Used by the local PCA fit (`btfrs_fit::lpca`, paper 004 section 3: "k-means on ABRDFs, PCA per
//! cluster") and meant for texton analysis too. Points are the columns of a `dim x n` `f32`
//! matrix, i.e. point `i` is `points[i * dim..(i + 1) * dim]` (a BTF's texel-major data is such a
//! matrix of ABRDFs). Squared distances are computed as `|x|^2 - 2 x.c + |c|^2` with one GEMM per
//! iteration (a parallel `matrixmultiply` GEMM), so the cost is that of a matrix product even for long
//! vectors; sums are accumulated in `f64`, and every sum has a fixed order, so the result
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
fn seed_plus_plus(points: &[f32], dim: usize, norms: &[f64], k: usize, seed: u64) -> Vec<f32> {
    let n = norms.len();
    let mut rng = Rng::new(seed);
    let first = rng.below(n);
    let mut centers: Vec<f32> = points[first * dim..(first + 1) * dim].to_vec();
    let mut closest: Vec<f64> = points.par_chunks(dim).map(|x| direct(x, &centers)).collect();
    let trials = 2 + (k as f64).ln() as usize;
    let mut cdf = vec![0.0f64; n];
    let mut d = vec![0.0f64; n * trials];
    while centers.len() / dim < k {
        // Draw candidates proportionally to the squared distance (inverse CDF over a prefix sum).
        let mut acc = 0.0;
        for (c, &x) in cdf.iter_mut().zip(&closest) {
            acc += x;
            *c = acc;
        }
        if acc <= 0.0 {
            // Every point sits on a centre already: there are no more distinct points to seed.
            break;
        }
        let picks: Vec<usize> = (0..trials)
            .map(|_| {
                let u = rng.next_f64() * acc;
                cdf.partition_point(|&c| c <= u).min(n - 1)
            })
            .collect();
        let cand: Vec<f32> = picks.iter().flat_map(|&p| points[p * dim..(p + 1) * dim].iter().copied()).collect();
        // Each point's distance to each candidate and, per block of points, the potential each
        // candidate would leave; blocks are fixed and summed in order, so the result does not
        // depend on the threads. The distances are direct (x - c)^2 sums, exactly 0 between
        // equal points, which is what the seeding must see.
        let pots: Vec<Vec<f64>> = d
            .par_chunks_mut(SEED_BLOCK * trials)
            .zip(closest.par_chunks(SEED_BLOCK))
            .zip(points.par_chunks(SEED_BLOCK * dim))
            .map(|((dd, cl), xs)| {
                let mut pot = vec![0.0f64; trials];
                for ((o, &best), x) in dd.chunks_mut(trials).zip(cl).zip(xs.chunks(dim)) {
                    for (c, (o, p)) in o.iter_mut().zip(pot.iter_mut()).enumerate() {
                        *o = direct(x, &cand[c * dim..(c + 1) * dim]);
                        *p += best.min(*o);
                    }
                }
                pot
            })
            .collect();
        let pots: Vec<f64> = (0..trials).map(|c| pots.iter().map(|p| p[c]).sum()).collect();
        // The candidate that leaves the smallest potential wins (first on ties: deterministic).
        let best = (0..trials).fold(0, |b, c| if pots[c] < pots[b] { c } else { b });
        closest.par_iter_mut().zip(d.par_chunks(trials)).for_each(|(c, dd)| *c = c.min(dd[best]));
        centers.extend_from_slice(&cand[best * dim..(best + 1) * dim]);
    }
    centers
}

/// Points per block of the seeding's parallel passes.
const SEED_BLOCK: usize = 256;

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
