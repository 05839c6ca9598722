//! The synthesis domain: one feature vector per texel, compared by squared Euclidean distance.
//!
//! Paper 002 (section 3.2) synthesizes tiles in the compressed domain: the edge cost of its graph
//! cuts is "a weighted sum of square difference between the SH coefficient vectors". The weights
//! are what make a coefficient difference stand for a difference of the BTF itself, so each
//! domain here is built such that the squared distance of two feature vectors *is* (or
//! approximates) the squared L2 distance of the two texels' reflectance functions:
//!
//! * **SH coefficients** (`"coefficients"` for the `sh` model): the dequantized double-SH
//!   coefficients with weight 1. The real SH basis is orthonormal on the sphere, so by Parseval
//!   the coefficient distance equals the L2 distance of the reconstructions integrated over all
//!   (view, light) pairs of the two spheres.
//! * **PTM coefficients** (`"coefficients"` for RGB PTMs): per view slot and channel the six
//!   biquadratic coefficients multiplied by `L^T`, where `G = L L^T` is the Gram matrix of the
//!   basis averaged over the light hemisphere (uniform solid angle): then the distance is the
//!   L2 distance of the reconstructions averaged over the light hemisphere, summed over slots.
//! * **Decoded** (`"decoded"`, every model; the default for LPCA, Lafortune, SRF, per-view
//!   Lafortune and LRGB PTMs, whose parameters are not linear coefficients or, for LPCA, live
//!   in a different basis per cluster): the model evaluated at [`PROBES`] fixed (view, light)
//!   pairs over the hemisphere, scaled by `1 / sqrt(pairs)`: the distance is the mean squared
//!   RGB difference over those pairs.
//! * **RGB** images: the pixel values.
//!
//! Candidate matching uses a PCA reduction of these features ([`Features::reduced`]); the graph
//! cuts always use the full features.

use btfrs_core::rng::Rng;
use btfrs_core::{Error, Result};
use btfrs_fit::model::DynModel;
use rayon::prelude::*;

/// Per-texel feature vectors of a `height x width` sample, texel-major: the feature image of
/// the synthesis crate (`btfrs_kcoherence::Features`), with what tile synthesis adds to it in
/// [`FeatureOps`].
pub use btfrs_kcoherence::Features;

/// What tile synthesis needs of a feature image beyond storing it.
pub trait FeatureOps {
    /// The features of texel `t` (row-major index).
    fn at(&self, t: usize) -> &[f32];
    /// Number of texels.
    fn texels(&self) -> usize;
    /// Mean squared distance between random texel pairs (4096 pairs, seeded): the cost of a
    /// seam between unrelated texels, the unit of the fill thresholds.
    fn pair_scale(&self, seed: u64) -> f64;
    /// The projection onto the `k` leading principal components (centred), with the fraction
    /// of the variance kept. Distances between projected vectors approximate the full ones.
    fn reduced(&self, k: usize) -> (Features, f64);
}

impl FeatureOps for Features {
    #[inline]
    fn at(&self, t: usize) -> &[f32] {
        self.pixel(t)
    }

    fn texels(&self) -> usize {
        self.pixels()
    }

    fn pair_scale(&self, seed: u64) -> f64 {
        let mut rng = Rng::new(seed ^ 0x5ca1e);
        let n = self.texels();
        let mut s = 0.0f64;
        let pairs = 4096;
        for _ in 0..pairs {
            let (a, b) = (rng.below(n), rng.below(n));
            s += dist2(self.at(a), self.at(b));
        }
        (s / pairs as f64).max(f64::MIN_POSITIVE)
    }

    fn reduced(&self, k: usize) -> (Features, f64) {
        let d = self.dim;
        let n = self.texels();
        let k = k.clamp(1, d);
        let mean: Vec<f64> = {
            let mut m = vec![0.0f64; d];
            for t in 0..n {
                for (mi, &v) in m.iter_mut().zip(self.at(t)) {
                    *mi += v as f64;
                }
            }
            m.iter().map(|x| x / n as f64).collect()
        };
        if k == d {
            let data =
                self.data.chunks(d).flat_map(|x| x.iter().zip(&mean).map(|(v, m)| (*v as f64 - m) as f32)).collect();
            return (Features { height: self.height, width: self.width, dim: d, data }, 1.0);
        }
        // The components from at most 4096 texels (a regular subsample: the components of a
        // texture are well estimated from a few thousand texels).
        let stride = n.div_ceil(4096).max(1);
        let sub: Vec<f32> = if stride == 1 {
            self.data.clone()
        } else {
            (0..n).step_by(stride).flat_map(|t| self.at(t).iter().copied()).collect()
        };
        let (basis, kept, total) = if d <= EXACT_MAX_DIM {
            exact_components(&sub, &mean, d, k)
        } else {
            leading_components(&sub, &mean, d, k)
        };
        let data: Vec<f32> = self
            .data
            .par_chunks(d)
            .flat_map_iter(|v| {
                basis
                    .iter()
                    .map(|b| {
                        b.iter().zip(v).zip(&mean).map(|((bi, &vi), mi)| bi * (vi as f64 - mi)).sum::<f64>() as f32
                    })
                    .collect::<Vec<f32>>()
            })
            .collect();
        let frac = if total > 0.0 { kept / total } else { 1.0 };
        (Features { height: self.height, width: self.width, dim: k, data }, frac)
    }
}

/// Feature dimensions up to which [`FeatureOps::reduced`] solves the whole eigenproblem of the
/// covariance; above, it finds only the leading components (a coefficient domain has 6-16
/// values per view slot and channel: a PTM's 1,458, whose full eigenproblem took seconds).
const EXACT_MAX_DIM: usize = 128;

/// The `k` leading principal directions of the centred rows of `sub` (`d` values each) from
/// the f64 covariance's full eigenproblem, with the variance they keep and the total (both
/// unnormalised sums of squares).
fn exact_components(sub: &[f32], mean: &[f64], d: usize, k: usize) -> (Vec<Vec<f64>>, f64, f64) {
    let cov = sub
        .par_chunks(d * 256)
        .map(|chunk| {
            let mut c = vec![0.0f64; d * d];
            let mut x = vec![0.0f64; d];
            for v in chunk.chunks(d) {
                for ((xi, &vi), mi) in x.iter_mut().zip(v).zip(mean) {
                    *xi = vi as f64 - mi;
                }
                for i in 0..d {
                    let xi = x[i];
                    for j in i..d {
                        c[i * d + j] += xi * x[j];
                    }
                }
            }
            c
        })
        .reduce(
            || vec![0.0f64; d * d],
            |mut a, b| {
                a.iter_mut().zip(b).for_each(|(x, y)| *x += y);
                a
            },
        );
    let mut m = nalgebra::DMatrix::<f64>::zeros(d, d);
    for i in 0..d {
        for j in i..d {
            m[(i, j)] = cov[i * d + j];
            m[(j, i)] = cov[i * d + j];
        }
    }
    let eig = m.symmetric_eigen();
    let mut order: Vec<usize> = (0..d).collect();
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let total: f64 = eig.eigenvalues.iter().map(|v| v.max(0.0)).sum();
    let kept: f64 = order[..k].iter().map(|&i| eig.eigenvalues[i].max(0.0)).sum();
    let basis = order[..k].iter().map(|&i| eig.eigenvectors.column(i).iter().copied().collect()).collect();
    (basis, kept, total)
}

/// The same as [`exact_components`] for many dimensions: the leading directions by randomized
/// subspace iteration (`btfrs_numerics::rpca::top_directions`, Halko et al. 2011, with a fixed
/// seed), their variance from the Rayleigh quotients, the total from the sum of squares. A
/// direction the data do not have (fewer than `k`) is a zero vector, which adds nothing to a
/// distance.
fn leading_components(sub: &[f32], mean: &[f64], d: usize, k: usize) -> (Vec<Vec<f64>>, f64, f64) {
    let ns = sub.len() / d;
    let xc = nalgebra::DMatrix::<f32>::from_fn(d, ns, |i, j| (sub[j * d + i] as f64 - mean[i]) as f32);
    let total: f64 = xc.as_slice().par_chunks(d).map(|c| c.iter().map(|&x| x as f64 * x as f64).sum::<f64>()).sum();
    let q = btfrs_numerics::rpca::top_directions(&xc, k, 0x3a7c_5eed, 0.0);
    let proj = btfrs_numerics::rpca::Columns::t_times(&xc, &q);
    let kept: f64 = proj.as_slice().iter().map(|&x| x as f64 * x as f64).sum();
    let mut basis: Vec<Vec<f64>> = q.column_iter().map(|c| c.iter().map(|&x| x as f64).collect()).collect();
    basis.resize(k, vec![0.0; d]);
    (basis, kept, total)
}

/// Squared Euclidean distance, accumulated in f64.
#[inline]
pub fn dist2(a: &[f32], b: &[f32]) -> f64 {
    a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum()
}

/// Elevation and azimuth (degrees) of the probe views and lights of the decoded domain: the
/// zenith, a ring at 35 degrees and one at 65, offset against each other.
const PROBE_VIEWS: [(f64, f64); 5] = [(0.0, 0.0), (35.0, 0.0), (35.0, 120.0), (35.0, 240.0), (65.0, 60.0)];
const PROBE_LIGHTS: [(f64, f64); 8] =
    [(0.0, 0.0), (35.0, 60.0), (35.0, 180.0), (35.0, 300.0), (65.0, 0.0), (65.0, 90.0), (65.0, 180.0), (65.0, 270.0)];
/// Number of (view, light) probe pairs of the decoded domain.
pub const PROBES: usize = PROBE_VIEWS.len() * PROBE_LIGHTS.len();

fn dir(theta_deg: f64, phi_deg: f64) -> [f64; 3] {
    let (t, p) = (theta_deg.to_radians(), phi_deg.to_radians());
    [t.sin() * p.cos(), t.sin() * p.sin(), t.cos()]
}

/// The domain a model is synthesized in: `"auto"`, `"coefficients"` or `"decoded"`.
/// Returns the features and the name of the domain used.
pub fn model_features(model: &dyn DynModel, domain: &str) -> Result<(Features, &'static str)> {
    let (h, w) = model.dims();
    // Computed once: the model's linear coefficient domain, where it has one.
    let coefficients = match domain {
        "auto" => model.coefficient_features(),
        "coefficients" => Some(model.coefficient_features().ok_or_else(|| {
            Error::arg(
                "domain",
                format!("the {} model has no linear coefficient domain; use \"decoded\"", model.kind()),
            )
        })?),
        "decoded" => None,
        other => {
            return Err(Error::arg(
                "domain",
                format!("expected \"auto\", \"coefficients\" or \"decoded\", got {other:?}"),
            ))
        }
    };
    if let Some(f) = coefficients {
        let f = f?;
        return Ok((Features::new(h, w, f.dim, f.data)?, f.label));
    }
    let pairs: Vec<([f64; 3], [f64; 3])> = PROBE_VIEWS
        .iter()
        .flat_map(|&(tv, pv)| PROBE_LIGHTS.iter().map(move |&(tl, pl)| (dir(tv, pv), dir(tl, pl))))
        .collect();
    let images: Vec<Vec<f32>> =
        pairs.par_iter().map(|&(v, l)| model.evaluate_image(v, l)).collect::<Result<Vec<_>>>()?;
    let dim = 3 * pairs.len();
    let s = (1.0 / pairs.len() as f64).sqrt() as f32;
    let mut data = vec![0.0f32; h * w * dim];
    data.par_chunks_mut(dim).enumerate().for_each(|(t, out)| {
        for (p, img) in images.iter().enumerate() {
            for c in 0..3 {
                out[p * 3 + c] = img[t * 3 + c] * s;
            }
        }
    });
    Ok((Features::new(h, w, dim, data)?, "decoded at 40 probe pairs"))
}

#[cfg(test)]
#[allow(clippy::needless_range_loop)] // index loops mirror the set-ups being checked
mod tests {
    use super::*;

    #[test]
    fn pca_reduction_keeps_distances_of_low_rank_data() {
        // Rank-3 data in 12 dimensions: 3 components keep every distance and all the variance.
        let mut rng = Rng::new(4);
        let dirs: Vec<Vec<f32>> = (0..3).map(|_| (0..12).map(|_| rng.next_f64() as f32 - 0.5).collect()).collect();
        let mut data = Vec::new();
        for _ in 0..(16 * 16) {
            let a: Vec<f32> = (0..3).map(|_| rng.next_f64() as f32).collect();
            for k in 0..12 {
                data.push(1.0 + (0..3).map(|i| a[i] * dirs[i][k]).sum::<f32>());
            }
        }
        let f = Features::new(16, 16, 12, data).unwrap();
        let (r, kept) = f.reduced(3);
        assert!(kept > 0.999999, "{kept}");
        for (a, b) in [(0, 1), (5, 200), (17, 255)] {
            let (d0, d1) = (dist2(f.at(a), f.at(b)), dist2(r.at(a), r.at(b)));
            assert!((d0 - d1).abs() < 1e-4 * d0.max(1e-6), "{d0} vs {d1}");
        }
    }

    #[test]
    fn leading_components_of_many_dimensions_match_the_full_eigenproblem() {
        // 300 dimensions (above EXACT_MAX_DIM): a decaying spectrum of 20 directions plus noise,
        // as a coefficient domain has. The randomized leading components must keep the variance
        // the exact ones keep and span the same subspace (projected distances agree).
        let (d, n, k) = (300usize, 1200usize, 8usize);
        assert!(d > EXACT_MAX_DIM);
        let mut rng = Rng::new(7);
        let dirs: Vec<Vec<f64>> = (0..20).map(|_| (0..d).map(|_| rng.next_f64() - 0.5).collect()).collect();
        let mut sub = Vec::with_capacity(n * d);
        for _ in 0..n {
            let a: Vec<f64> = (0..20).map(|i| (rng.next_f64() - 0.5) * 0.7f64.powi(i)).collect();
            for j in 0..d {
                let noise = 1e-3 * (rng.next_f64() - 0.5);
                sub.push((2.0 + (0..20).map(|i| a[i] * dirs[i][j]).sum::<f64>() + noise) as f32);
            }
        }
        let mean: Vec<f64> = (0..d).map(|j| (0..n).map(|t| sub[t * d + j] as f64).sum::<f64>() / n as f64).collect();
        let (eb, ek, et) = exact_components(&sub, &mean, d, k);
        let (lb, lk, lt) = leading_components(&sub, &mean, d, k);
        assert!((lt - et).abs() <= 1e-5 * et, "total {lt} vs {et}");
        assert!((lk / lt - ek / et).abs() <= 1e-4, "kept {} vs {}", lk / lt, ek / et);
        assert!(ek / et < 0.999, "the test needs variance outside the k components: {}", ek / et);
        // Each exact direction lies in the randomized subspace (and both bases are orthonormal).
        for e in &eb {
            let inside: f64 = lb.iter().map(|l| l.iter().zip(e).map(|(a, b)| a * b).sum::<f64>().powi(2)).sum();
            assert!(inside > 1.0 - 1e-3, "an exact direction keeps only {inside} of itself in the subspace");
        }
    }

    #[test]
    fn bad_samples_are_named() {
        assert!(Features::new(2, 2, 1, vec![0.0; 3]).unwrap_err().to_string().contains("sample"));
        let e = Features::new(1, 2, 1, vec![0.0, f32::NAN]).unwrap_err().to_string();
        assert!(e.contains("column 1"), "{e}");
    }
}
