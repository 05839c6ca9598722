//! Texton analysis of a sample (paper 000 section 4.1).
//!
//! Each sample pixel is a long appearance vector (for a BTF, its whole ABRDF: about 6000 images
//! x 3 channels). k-means clustering assigns each pixel the index of its cluster, its *texton*,
//! and keeps the mean vector of every cluster, its *appearance vector*. Distances between pixels
//! then become distances between textons, precomputed once for every pair, so the synthesis
//! never touches the long vectors: `dist(p_i, p_j) = |t_i - t_j|^2 = t_i.t_i - 2 t_i.t_j + t_j.t_j`.
//!
//! The paper keeps the dot-product matrix `M` and evaluates that sum with three lookups; we
//! store the distance table `D_ij = |v_i - v_j|^2` itself (computed directly in `f64`, which
//! also avoids the cancellation of the three-term form when two textons are close), so a pixel
//! distance is one lookup. [`Textons::dots`] still gives `M`.
//!
//! The appearance vectors can be (the [`FeatureMode`]):
//! * **all** the images: the paper's choice ("about an hour" for a 64 x 64 sample in 2004);
//! * a **subset of representative images** (the paper's speed-up, after Tong et al.): images are
//!   clustered by their thumbnails and the image nearest each cluster centre is kept;
//! * a **PCA projection** of all the images (the default): the randomized PCA of the LPCA fit
//!   (paper 004) keeps the leading principal coordinates, whose distances approximate the
//!   distances of the full vectors. Gaussian filter banks (Tong et al.) are omitted, as the paper
//!   does: they blur the fine structure (its Figure 2).

use crate::pyramid::Features;
use btfrs_core::{BtfRef, Error, Monitor, Result};
use rayon::prelude::*;

/// Which per-pixel appearance vectors the analysis clusters.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FeatureMode {
    /// Every measured image, all three channels.
    All,
    /// `count` representative images (clustered by their thumbnails).
    Images { count: usize },
    /// The leading `dims` principal coordinates of all the measured images.
    Pca { dims: usize },
}

/// Size of the thumbnails that choose representative images (per side, at most).
const THUMB: usize = 8;

/// The measured (view, light) pairs of a BTF, as `view * L + light`.
fn measured_pairs(btf: &BtfRef<'_>) -> Vec<usize> {
    let (nv, nl) = (btf.views.len(), btf.lights.len());
    (0..nv * nl).filter(|&p| btf.has(p / nl, p % nl)).collect()
}

/// Gather, for every texel, the RGB values of the given pairs: `[texels, 3 * pairs.len()]`.
fn gather(btf: &BtfRef<'_>, pairs: &[usize]) -> Vec<f32> {
    let d = 3 * pairs.len();
    let mut out = vec![0.0f32; btf.texels() * d];
    out.par_chunks_mut(d).enumerate().for_each(|(t, o)| {
        let a = btf.texel(t);
        for (j, &p) in pairs.iter().enumerate() {
            o[3 * j..3 * j + 3].copy_from_slice(&a[3 * p..3 * p + 3]);
        }
    });
    out
}

/// The per-pixel appearance vectors of a BTF sample for the chosen mode. `monitor` advances by 4
/// for `Pca`, by `iterations` for `Images`, and by 1 for `All`.
pub fn btf_features(
    btf: &BtfRef<'_>,
    mode: FeatureMode,
    iterations: usize,
    seed: u64,
    monitor: &Monitor,
) -> Result<Features> {
    let pairs = measured_pairs(btf);
    if pairs.is_empty() {
        return Err(Error::Degenerate("the mask leaves no measured (view, light) pair".into()));
    }
    let (h, w, n) = (btf.height, btf.width, btf.texels());
    let all_present = pairs.len() == btf.views.len() * btf.lights.len();
    let chunk = feature_chunk(monitor.memory_limit(), n, 3 * pairs.len(), mode, all_present)?;
    match mode {
        FeatureMode::All => {
            let data = if all_present { btf.data.to_vec() } else { gather(btf, &pairs) };
            monitor.advance(1);
            Features::new(h, w, 3 * pairs.len(), data)
        }
        FeatureMode::Pca { dims } => {
            if dims == 0 {
                return Err(Error::arg("dims", "expected at least 1 principal component, got 0"));
            }
            let owned;
            let data: &[f32] = if all_present {
                btf.data
            } else {
                owned = gather(btf, &pairs);
                &owned
            };
            let (coords, r) =
                // No power iteration: the coordinates only compare pixels (paper 000 section 4.1,
                // "a PCA projection"), and it saves two of the range finder's three products.
                btfrs_numerics::principal_coordinates(data, 3 * pairs.len(), n, dims, seed, chunk, 0, monitor)?;
            if r == 0 {
                // Every pixel is the same: one coordinate of zeros keeps the shapes valid.
                return Features::new(h, w, 1, vec![0.0; n]);
            }
            Features::new(h, w, r, coords)
        }
        FeatureMode::Images { count } => {
            if count == 0 || count > pairs.len() {
                return Err(Error::arg(
                    "images",
                    format!("expected 1 to {} images (the measured pairs), got {count}", pairs.len()),
                ));
            }
            let chosen = representative_images(btf, &pairs, count, iterations, seed, monitor)?;
            Features::new(h, w, 3 * chosen.len(), gather(btf, &chosen))
        }
    }
}

/// Under a memory limit (`limit`, bytes; out-of-core analysis of a memory-mapped BTF): the most
/// texels of `d` values the PCA features may copy at once (its range finder's sample is streamed
/// through them), or an error naming `memory_limit` when the features themselves do not fit
/// ("all" and "images" copy values for every texel, as does a mask with absent pairs).
///
/// What the analysis holds whatever the chunking is estimated per texel: the features (16
/// bytes per feature: the principal coordinates and the projection making them), k-means's
/// per-point state and its blocks of distances, the pyramid's levels and each level's candidate
/// lists (`m` per pixel, a few radii): 2 kB per texel plus 16 bytes per feature plus 24 MB, and
/// the streamed range finder's `d x l` products. The per-texel figure is an upper bound checked
/// by the out-of-core tests' subprocess measurements, not derived term by term.
fn feature_chunk(
    limit: Option<u64>,
    n: usize,
    d: usize,
    mode: FeatureMode,
    all_present: bool,
) -> Result<Option<usize>> {
    let Some(limit) = limit else { return Ok(None) };
    let (n64, d64) = (n as u64, d as u64);
    let copied = match mode {
        FeatureMode::All => n64 * d64 * 4,
        FeatureMode::Images { count } => n64 * 3 * count as u64 * 4,
        FeatureMode::Pca { .. } if !all_present => n64 * d64 * 4,
        FeatureMode::Pca { .. } => 0,
    };
    let dims = match mode {
        FeatureMode::Pca { dims } => dims as u64,
        FeatureMode::Images { count } => 3 * count as u64,
        FeatureMode::All => d64,
    };
    // Per texel: 2 kB, and 16 bytes per feature (the features and the projection making them).
    let fixed = n64 * (2048 + 16 * dims) + (24 << 20) + copied;
    // The streamed range finder's d x l products (24 bytes per value, as in the LPCA plan).
    let per_chunk = 24 * d64 * (dims.min(d64) + 10);
    let least = fixed + per_chunk + 32 * d64 * 4;
    if limit < least {
        let mb = |b: u64| format!("{:.1} MB", b as f64 / 1e6);
        return Err(Error::arg(
            "memory_limit",
            format!(
                "expected at least {} for the analysis of {n} texels of {d} values ({} of it the features' copy), got {}",
                mb(least),
                mb(copied),
                mb(limit)
            ),
        ));
    }
    Ok(Some(((limit - fixed - per_chunk) / (d64 * 4)).min(n64) as usize))
}

/// `count` representative pairs: k-means over the images' thumbnails (block means of at most
/// `THUMB x THUMB` blocks), then the image nearest each centre (sorted, without repeats).
fn representative_images(
    btf: &BtfRef<'_>,
    pairs: &[usize],
    count: usize,
    iterations: usize,
    seed: u64,
    monitor: &Monitor,
) -> Result<Vec<usize>> {
    let (h, w) = (btf.height, btf.width);
    let (th, tw) = (h.min(THUMB), w.min(THUMB));
    let d = th * tw * 3;
    let np = btf.views.len() * btf.lights.len();
    // Thumbnails, image-major: thumb[i][(by * tw + bx) * 3 + c].
    let mut thumbs = vec![0.0f32; pairs.len() * d];
    thumbs.par_chunks_mut(d).zip(pairs.par_iter()).for_each(|(o, &p)| {
        let mut cnt = vec![0u32; th * tw];
        for y in 0..h {
            for x in 0..w {
                let b = (y * th / h) * tw + x * tw / w;
                let v = &btf.data[((y * w + x) * np + p) * 3..][..3];
                for c in 0..3 {
                    o[b * 3 + c] += v[c];
                }
                cnt[b] += 1;
            }
        }
        for (b, &c) in cnt.iter().enumerate() {
            for v in &mut o[b * 3..b * 3 + 3] {
                *v /= c.max(1) as f32;
            }
        }
    });
    let km = btfrs_numerics::kmeans(&thumbs, d, count, iterations, seed, monitor)?;
    let mut best = vec![(f64::INFINITY, usize::MAX); km.k()];
    for (i, &c) in km.assign.iter().enumerate() {
        let (x, y) = (&thumbs[i * d..(i + 1) * d], &km.centers[c as usize * d..(c as usize + 1) * d]);
        let dist: f64 = x.iter().zip(y).map(|(&a, &b)| (a as f64 - b as f64).powi(2)).sum();
        if dist < best[c as usize].0 {
            best[c as usize] = (dist, pairs[i]);
        }
    }
    let mut chosen: Vec<usize> = best.into_iter().filter(|b| b.1 != usize::MAX).map(|b| b.1).collect();
    chosen.sort_unstable();
    chosen.dedup();
    Ok(chosen)
}

/// Textons of one pyramid level: the cluster of every pixel and the distances between clusters.
#[derive(Debug, Clone)]
pub struct Textons {
    /// Length of an appearance vector.
    pub dim: usize,
    /// `[count, dim]` appearance vectors (the cluster means).
    pub centers: Vec<f32>,
    /// Texton of every pixel (row-major).
    pub assign: Vec<u16>,
    /// `[count, count]` squared distances between the appearance vectors.
    pub dist: Vec<f32>,
}

/// Most textons a level may have (they are stored as `u16`).
pub const MAX_TEXTONS: usize = u16::MAX as usize;

impl Textons {
    /// Cluster the pixels of `f` into `count` textons (k-means++ seeding, `iterations` Lloyd steps).
    /// With `count >= ` the number of pixels, every pixel is its own texton and the distances are
    /// exact. `monitor` advances by `iterations`.
    pub fn fit(f: &Features, count: usize, iterations: usize, seed: u64, monitor: &Monitor) -> Result<Self> {
        let n = f.pixels();
        if count == 0 || count > MAX_TEXTONS {
            return Err(Error::arg("textons", format!("expected 1 to {MAX_TEXTONS} textons, got {count}")));
        }
        if count >= n {
            monitor.advance(iterations as u64);
            return Self::from_parts(f.dim, f.data.clone(), (0..n as u16).collect());
        }
        let km = btfrs_numerics::kmeans(&f.data, f.dim, count, iterations, seed, monitor)?;
        Self::from_parts(f.dim, km.centers, km.assign.iter().map(|&a| a as u16).collect())
    }

    /// Rebuild from the appearance vectors and the assignment (a saved analysis), validating them
    /// and recomputing the distance table.
    pub fn from_parts(dim: usize, centers: Vec<f32>, assign: Vec<u16>) -> Result<Self> {
        if dim == 0 || centers.is_empty() || !centers.len().is_multiple_of(dim) {
            return Err(Error::arg(
                "centers",
                format!("expected a non-empty [T, {dim}] array, got {} values", centers.len()),
            ));
        }
        let t = centers.len() / dim;
        if t > MAX_TEXTONS {
            return Err(Error::arg("centers", format!("expected at most {MAX_TEXTONS} textons, got {t}")));
        }
        btfrs_core::btf::check_finite("centers", &centers)?;
        if let Some(bad) = assign.iter().find(|&&a| a as usize >= t) {
            return Err(Error::arg("textons", format!("texton index {bad} out of range for {t} textons")));
        }
        let mut dist = vec![0.0f32; t * t];
        dist.par_chunks_mut(t).enumerate().for_each(|(i, row)| {
            let a = &centers[i * dim..(i + 1) * dim];
            for (j, o) in row.iter_mut().enumerate() {
                let b = &centers[j * dim..(j + 1) * dim];
                *o = a.iter().zip(b).map(|(&x, &y)| (x as f64 - y as f64).powi(2)).sum::<f64>() as f32;
            }
        });
        Ok(Self { dim, centers, assign, dist })
    }

    /// Number of textons.
    pub fn count(&self) -> usize {
        self.centers.len() / self.dim
    }

    /// The dot-product matrix `M_ij = v_i . v_j` of the paper (`[count, count]`, `f64`).
    pub fn dots(&self) -> Vec<f64> {
        let (t, d) = (self.count(), self.dim);
        let c = &self.centers;
        (0..t * t)
            .into_par_iter()
            .map(|ij| {
                let (i, j) = (ij / t, ij % t);
                c[i * d..(i + 1) * d].iter().zip(&c[j * d..(j + 1) * d]).map(|(&a, &b)| a as f64 * b as f64).sum()
            })
            .collect()
    }

    /// Squared distance between two textons.
    #[inline]
    pub fn d(&self, a: u16, b: u16) -> f32 {
        self.dist[a as usize * self.count() + b as usize]
    }

    /// Mean distance between two pixels drawn at random from the sample (with replacement): the
    /// scale against which the quality measures are normalised.
    pub fn mean_pair_distance(&self) -> f64 {
        let t = self.count();
        let mut hist = vec![0.0f64; t];
        for &a in &self.assign {
            hist[a as usize] += 1.0;
        }
        let n = self.assign.len() as f64;
        let s: f64 = (0..t)
            .into_par_iter()
            .map(|i| {
                if hist[i] == 0.0 {
                    return 0.0;
                }
                let row = &self.dist[i * t..(i + 1) * t];
                hist[i] * row.iter().zip(&hist).map(|(&d, &h)| d as f64 * h).sum::<f64>()
            })
            .sum();
        s / (n * n)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distance_table_matches_the_dot_product_form() {
        // Three 2-D appearance vectors; D_ij = M_ii - 2 M_ij + M_jj (the paper's formula).
        let t = Textons::from_parts(2, vec![0.0, 1.0, 3.0, 4.0, -1.0, 2.0], vec![0, 1, 2, 2]).unwrap();
        let m = t.dots();
        for i in 0..3 {
            for j in 0..3 {
                let want = m[i * 3 + i] - 2.0 * m[i * 3 + j] + m[j * 3 + j];
                assert!((t.d(i as u16, j as u16) as f64 - want).abs() < 1e-6, "{i} {j}");
            }
        }
        assert_eq!(t.d(0, 1), 9.0 + 9.0);
        // Pixels 0, 1, 2, 2: mean over the 16 ordered pairs.
        let px = [0u16, 1, 2, 2];
        let want: f64 =
            px.iter().flat_map(|&a| px.iter().map(move |&b| (a, b))).map(|(a, b)| t.d(a, b) as f64).sum::<f64>() / 16.0;
        assert!((t.mean_pair_distance() - want).abs() < 1e-9);
    }

    #[test]
    fn textons_cluster_and_reject_bad_counts() {
        // Two well separated colours: 2 textons recover the split exactly.
        let data: Vec<f32> =
            (0..16).flat_map(|i| if i % 4 < 2 { [0.0, 0.0, 0.1 * (i % 2) as f32] } else { [5.0, 5.0, 5.0] }).collect();
        let f = Features::new(4, 4, 3, data).unwrap();
        let t = Textons::fit(&f, 2, 10, 1, &Monitor::new()).unwrap();
        for i in 0..16 {
            assert_eq!(t.assign[i] == t.assign[0], i % 4 < 2, "pixel {i}");
        }
        assert!(Textons::fit(&f, 0, 10, 1, &Monitor::new()).is_err());
        // As many textons as pixels: each pixel its own, exact distances.
        let t = Textons::fit(&f, 16, 10, 1, &Monitor::new()).unwrap();
        assert_eq!(t.count(), 16);
        assert_eq!(t.d(t.assign[0], t.assign[2]), 75.0);
    }
}
