//! Phong + spatially-varying residual function (SRF), paper 003, sections 4 and 5.
//!
//! The BTF is split into one parametric shading function for the whole material and a per-texel
//! residual (section 4, equation 2):
//!
//! ```text
//! BTF(P, V, L) = f_Phong(V, L) + delta(P, V, L)
//! f_Phong(V, L) = kd (N . L) + ks cos^n(N . H)        (Blinn-Phong, equation 3, per colour channel)
//! delta*(P, V, L) = s(P) . H                            (equation 5, one 3-vector s per texel and channel)
//! ```
//!
//! * `kd`, `ks` (per channel) and one shininess `n` are fitted by Levenberg-Marquardt to the
//!   material's mean BRDF (the average over texels of every present (view, light) pair), as the
//!   paper does for BTF input (section 4.1). The `N . L` factor is the cos(theta_l) that measured
//!   BTF values already include, so the Phong term is fitted to the values as they are.
//! * `s(P)` solves the linear least-squares system of section 4.3 over the halfway vectors of the
//!   present pairs. The design matrix `[H_1; H_2; ...]` is the same for every texel, so its
//!   pseudo-inverse is computed once and applied to each texel's residuals: one pass over the data.
//!
//! Storage: 7 global parameters plus 9 floats per texel. The residual is linear in H, so it
//! carries low-frequency shading (self-shadowing, shading variation) but blurs shadow boundaries
//! (section 5).

use crate::gpu::{words, GpuLayout, Shader};
use crate::model::{Bench, Model, NoOptions, ReflectanceModel, Sampling};
use crate::options::Spec;
use btfrs_core::btf::TexelScan;
use btfrs_core::{ensure_arg, BtfRef, Error, Monitor, NamedArrays, Result};
use rayon::prelude::*;
use std::borrow::Cow;

/// Bounds of the shininess exponent: below 1 the lobe is not a highlight, above 2000 it is
/// narrower than any UBO-sampled BTF can resolve (and `h_z^n` underflows).
pub const N_RANGE: (f64, f64) = (1.0, 2000.0);

/// The global Blinn-Phong part: `kd[c] * l_z + ks[c] * max(h_z, 0)^n`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Phong {
    /// Diffuse albedo per channel (times the cos(theta_l) the data includes).
    pub kd: [f64; 3],
    /// Specular coefficient per channel.
    pub ks: [f64; 3],
    /// Shininess.
    pub n: f64,
}

impl Phong {
    /// The value for one channel given `l_z` and the halfway vector's z.
    #[inline]
    pub fn eval(&self, c: usize, lz: f64, hz: f64) -> f64 {
        self.kd[c] * lz + self.ks[c] * spec(hz, self.n)
    }
}

#[inline]
fn spec(hz: f64, n: f64) -> f64 {
    if hz > 0.0 {
        hz.powf(n)
    } else {
        0.0
    }
}

/// The normalised halfway vector of two unit directions (the normal when they are opposite).
#[inline]
pub fn halfway(v: [f64; 3], l: [f64; 3]) -> [f64; 3] {
    let h = [v[0] + l[0], v[1] + l[1], v[2] + l[2]];
    let n = (h[0] * h[0] + h[1] * h[1] + h[2] * h[2]).sqrt();
    if n > 1e-12 {
        [h[0] / n, h[1] / n, h[2] / n]
    } else {
        [0.0, 0.0, 1.0]
    }
}

/// A fitted Phong + SRF model.
#[derive(Debug, Clone)]
pub struct Srf {
    /// Rows.
    pub height: usize,
    /// Columns.
    pub width: usize,
    /// The material's Phong fit.
    pub phong: Phong,
    /// `[H, W, 3, 3]`: s(P) per texel and channel (x, y, z in the tangent frame).
    pub s: Vec<f32>,
    /// The fit's statistics (zero for a model built from arrays).
    pub report: SrfReport,
}

/// Statistics of an SRF fit: how much the residual function adds to Phong alone.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct SrfReport {
    /// Relative error of Phong alone over the fitted pairs.
    pub phong_relative: f64,
    /// Relative error of Phong + SRF over the fitted pairs.
    pub srf_relative: f64,
    /// LM iterations of the Phong fit.
    pub iterations: usize,
}

impl SrfReport {
    /// The report from the sums of [`residual`] (over every texel) and the Phong fit's iterations.
    pub fn of_sums(sums: [f64; 3], iterations: usize) -> Self {
        let rel = |e: f64| if sums[2] > 0.0 { (e / sums[2]).sqrt() } else { 0.0 };
        SrfReport { phong_relative: rel(sums[0]), srf_relative: rel(sums[1]), iterations }
    }
}

/// Least-squares fit of `kd`, `ks`, `n` to `mean` (`[pairs][3]`) at `(l_z, h_z)` per pair.
///
/// Initialisation: for each exponent of a geometric grid, `kd` and `ks` per channel by 2 x 2
/// linear least squares (clamped to >= 0); the best becomes LM's start, so LM only polishes.
pub fn fit_phong(geom: &[(f64, f64)], mean: &[[f64; 3]]) -> (Phong, usize) {
    let cost = |p: &Phong| -> f64 {
        geom.iter()
            .zip(mean)
            .map(|(&(lz, hz), m)| (0..3).map(|c| (p.eval(c, lz, hz) - m[c]).powi(2)).sum::<f64>())
            .sum()
    };
    let linear = |n: f64| -> Phong {
        // Normal equations of [lz, hz^n] per channel.
        let (mut a11, mut a12, mut a22) = (0.0, 0.0, 0.0);
        let (mut b1, mut b2) = ([0.0f64; 3], [0.0f64; 3]);
        for (&(lz, hz), m) in geom.iter().zip(mean) {
            let s = spec(hz, n);
            a11 += lz * lz;
            a12 += lz * s;
            a22 += s * s;
            for c in 0..3 {
                b1[c] += lz * m[c];
                b2[c] += s * m[c];
            }
        }
        let det = a11 * a22 - a12 * a12;
        let mut p = Phong { kd: [0.0; 3], ks: [0.0; 3], n };
        for c in 0..3 {
            let (mut kd, mut ks) = if det.abs() > 1e-12 * (a11 * a22).max(1e-300) {
                ((a22 * b1[c] - a12 * b2[c]) / det, (a11 * b2[c] - a12 * b1[c]) / det)
            } else {
                (if a11 > 0.0 { b1[c] / a11 } else { 0.0 }, 0.0)
            };
            // Non-negativity: refit the other coefficient alone when one goes negative.
            if ks < 0.0 {
                ks = 0.0;
                kd = if a11 > 0.0 { b1[c] / a11 } else { 0.0 };
            }
            if kd < 0.0 {
                kd = 0.0;
                ks = if a22 > 0.0 { (b2[c] / a22).max(0.0) } else { 0.0 };
            }
            p.kd[c] = kd;
            p.ks[c] = ks;
        }
        p
    };
    let mut best = linear(N_RANGE.0);
    let mut best_cost = cost(&best);
    let mut n = N_RANGE.0;
    while n < N_RANGE.1 {
        n *= 1.5;
        let p = linear(n.min(N_RANGE.1));
        let c = cost(&p);
        if c < best_cost {
            best = p;
            best_cost = c;
        }
    }
    // Levenberg-Marquardt on the 7 parameters [kd x3, ks x3, n], analytic Jacobian, bounds by
    // projection (kd, ks >= 0, n in N_RANGE).
    let pack = |p: &Phong| [p.kd[0], p.kd[1], p.kd[2], p.ks[0], p.ks[1], p.ks[2], p.n];
    let unpack = |x: &[f64; 7]| Phong {
        kd: [x[0].max(0.0), x[1].max(0.0), x[2].max(0.0)],
        ks: [x[3].max(0.0), x[4].max(0.0), x[5].max(0.0)],
        n: x[6].clamp(N_RANGE.0, N_RANGE.1),
    };
    let mut x = pack(&best);
    let mut lambda = 1e-3;
    let mut iterations = 0;
    for _ in 0..100 {
        iterations += 1;
        let p = unpack(&x);
        let mut jtj = [[0.0f64; 7]; 7];
        let mut jtr = [0.0f64; 7];
        for (&(lz, hz), m) in geom.iter().zip(mean) {
            let s = spec(hz, p.n);
            let ln = if hz > 0.0 { hz.ln() } else { 0.0 };
            for c in 0..3 {
                let r = p.eval(c, lz, hz) - m[c];
                let mut j = [0.0f64; 7];
                j[c] = lz;
                j[3 + c] = s;
                j[6] = p.ks[c] * s * ln;
                for a in 0..7 {
                    if j[a] == 0.0 {
                        continue;
                    }
                    jtr[a] += j[a] * r;
                    for b in 0..7 {
                        jtj[a][b] += j[a] * j[b];
                    }
                }
            }
        }
        let mut improved = false;
        while lambda < 1e12 {
            let mut a = jtj;
            for (i, row) in a.iter_mut().enumerate() {
                row[i] += lambda * (jtj[i][i] + 1e-12);
            }
            let Some(step) = solve7(a, jtr) else {
                lambda *= 10.0;
                continue;
            };
            let mut xn = x;
            for i in 0..7 {
                xn[i] -= step[i];
            }
            let pn = unpack(&xn);
            let cn = cost(&pn);
            if cn.is_finite() && cn < best_cost {
                let rel = (best_cost - cn) / best_cost.max(1e-300);
                x = pack(&pn);
                best_cost = cn;
                lambda = (lambda * 0.3).max(1e-9);
                improved = rel > 1e-10;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    (unpack(&x), iterations)
}

/// Solve a symmetric positive-definite 7 x 7 system by Cholesky; None when not positive definite.
fn solve7(a: [[f64; 7]; 7], b: [f64; 7]) -> Option<[f64; 7]> {
    let mut l = [[0.0f64; 7]; 7];
    for i in 0..7 {
        for j in 0..=i {
            let s: f64 = a[i][j] - (0..j).map(|k| l[i][k] * l[j][k]).sum::<f64>();
            if i == j {
                if s <= 0.0 || !s.is_finite() {
                    return None;
                }
                l[i][i] = s.sqrt();
            } else {
                l[i][j] = s / l[j][j];
            }
        }
    }
    let mut y = [0.0f64; 7];
    for i in 0..7 {
        y[i] = (b[i] - (0..i).map(|k| l[i][k] * y[k]).sum::<f64>()) / l[i][i];
    }
    let mut x = [0.0f64; 7];
    for i in (0..7).rev() {
        x[i] = (y[i] - (i + 1..7).map(|k| l[k][i] * x[k]).sum::<f64>()) / l[i][i];
    }
    Some(x)
}

/// The present (view, light) pairs and what the fit needs of their directions.
#[derive(Debug, Clone)]
pub struct PairGeometry {
    /// `(view, light)` of every present pair, in pair order.
    pub pairs: Vec<(usize, usize)>,
    /// The halfway vector of each pair.
    pub hs: Vec<[f64; 3]>,
    /// `(l_z, h_z)` of each pair: what the Phong lobe depends on.
    pub geom: Vec<(f64, f64)>,
}

impl PairGeometry {
    /// The present pairs of `views` x `lights` under `mask` (`[V, L]`, None: all); an error when
    /// fewer than 3 are present (the residual's 3 unknowns).
    pub fn new(views: &[[f64; 3]], lights: &[[f64; 3]], mask: Option<&[bool]>) -> Result<Self> {
        let nl = lights.len();
        let pairs: Vec<(usize, usize)> = (0..views.len())
            .flat_map(|v| (0..nl).map(move |l| (v, l)))
            .filter(|&(v, l)| mask.is_none_or(|m| m[v * nl + l]))
            .collect();
        if pairs.len() < 3 {
            return Err(Error::Degenerate(format!(
                "the sample has {} present (view, light) pairs; the residual s(P) . H needs at least 3",
                pairs.len()
            )));
        }
        let hs: Vec<[f64; 3]> = pairs.iter().map(|&(v, l)| halfway(views[v], lights[l])).collect();
        let geom: Vec<(f64, f64)> = pairs.iter().zip(&hs).map(|(&(_, l), h)| (lights[l][2], h[2])).collect();
        Ok(PairGeometry { pairs, hs, geom })
    }

    fn of(btf: &BtfRef<'_>) -> Result<Self> {
        Self::new(btf.views, btf.lights, btf.mask)
    }
}

/// Fit Phong to the mean BRDF of `btf`'s present pairs, then s(P) per texel and channel.
/// `monitor` counts texel rows of the residual fit.
///
/// Three stages, public so that a blockwise driver (`btfrs.dask`, [`crate::blockwise`]) can run
/// the first as a reduction over texel blocks: [`mean_sums`] (per block, summed), then
/// [`phong_of_mean`] once, then [`residual`] (per block).
pub fn fit_srf(btf: &BtfRef<'_>, monitor: &Monitor) -> Result<(Srf, SrfReport)> {
    let geo = PairGeometry::of(btf)?;
    let sums = mean_sums(btf)?;
    monitor.check()?;
    let (phong, iterations) = phong_of_mean(&geo, &sums, btf.texels())?;
    let (s, sums) = residual(btf, &geo, &phong, monitor)?;
    let report = SrfReport::of_sums(sums, iterations);
    Ok((Srf { height: btf.height, width: btf.width, phong, s, report }, report))
}

/// Stage 1: the per-pair sums over `btf`'s texels of the present values (`[pairs]` RGB, pair
/// order of [`PairGeometry`]), f64 accumulation, parallel over texels.
pub fn mean_sums(btf: &BtfRef<'_>) -> Result<Vec<[f64; 3]>> {
    let geo = PairGeometry::of(btf)?;
    let (pairs, nl) = (&geo.pairs, btf.lights.len());
    // This pass reads every texel first, so it checks the values for the whole fit (the
    // residual's pass then reads only what was checked).
    let scan = TexelScan::new();
    let sums = (0..btf.texels())
        .into_par_iter()
        .fold(
            || vec![[0.0f64; 3]; pairs.len()],
            |mut acc, t| {
                let x = btf.texel(t);
                if scan.failed() || !scan.check(x) {
                    return acc;
                }
                for (a, &(v, l)) in acc.iter_mut().zip(pairs) {
                    let o = (v * nl + l) * 3;
                    for c in 0..3 {
                        a[c] += x[o + c] as f64;
                    }
                }
                acc
            },
        )
        .reduce(
            || vec![[0.0f64; 3]; pairs.len()],
            |mut a, b| {
                for (x, y) in a.iter_mut().zip(&b) {
                    for c in 0..3 {
                        x[c] += y[c];
                    }
                }
                a
            },
        );
    scan.finish("data", btf.data)?;
    Ok(sums)
}

/// Stage 2: the Phong lobe fitted to the mean BRDF, `sums` (of [`mean_sums`], summed over every
/// block) divided by the `texels` they cover; and the Levenberg-Marquardt iterations.
pub fn phong_of_mean(geo: &PairGeometry, sums: &[[f64; 3]], texels: usize) -> Result<(Phong, usize)> {
    ensure_arg!(
        sums.len() == geo.pairs.len(),
        "sums",
        "expected one RGB sum per present pair ({}), got {}",
        geo.pairs.len(),
        sums.len()
    );
    ensure_arg!(texels > 0, "texels", "expected at least one texel, got 0");
    ensure_arg!(sums.iter().flatten().all(|x| x.is_finite()), "sums", "expected finite sums");
    let mean: Vec<[f64; 3]> = sums.iter().map(|s| s.map(|x| x / texels as f64)).collect();
    Ok(fit_phong(&geo.geom, &mean))
}

/// Stage 3: `s(P)` (`[H, W, 3, 3]`) of every texel of `btf` given the Phong lobe, and the sums
/// behind the report (Phong error², Phong + SRF error², ground truth²).
pub fn residual(
    btf: &BtfRef<'_>,
    geo: &PairGeometry,
    phong: &Phong,
    monitor: &Monitor,
) -> Result<(Vec<f32>, [f64; 3])> {
    let (pairs, hs, nl) = (&geo.pairs, &geo.hs, btf.lights.len());
    // Pseudo-inverse of the shared H design matrix: (H^T H)^-1 H^T, 3 x n.
    let mut hth = [[0.0f64; 3]; 3];
    for h in hs {
        for a in 0..3 {
            for b in 0..3 {
                hth[a][b] += h[a] * h[b];
            }
        }
    }
    let inv = invert3(hth).ok_or_else(|| {
        Error::Degenerate(
            "the halfway vectors of the present pairs span fewer than 3 dimensions; s(P) . H is undetermined".into(),
        )
    })?;
    let pinv: Vec<[f64; 3]> =
        hs.iter().map(|h| std::array::from_fn(|a| (0..3).map(|b| inv[a][b] * h[b]).sum::<f64>())).collect();
    let phong_vals: Vec<[f64; 3]> =
        geo.geom.iter().map(|&(lz, hz)| std::array::from_fn(|c| phong.eval(c, lz, hz))).collect();

    let (h, w) = (btf.height, btf.width);
    let mut s = vec![0.0f32; btf.texels() * 9];
    monitor.start(h as u64);
    let sums = s
        .par_chunks_mut(w * 9)
        .enumerate()
        .map(|(row, out)| {
            let mut acc = [0.0f64; 3]; // phong error^2, srf error^2, gt^2
            if monitor.is_cancelled() {
                return acc;
            }
            for col in 0..w {
                let x = btf.texel(row * w + col);
                let mut sv = [[0.0f64; 3]; 3];
                for (i, &(v, l)) in pairs.iter().enumerate() {
                    let o = (v * nl + l) * 3;
                    for c in 0..3 {
                        let r = x[o + c] as f64 - phong_vals[i][c];
                        for a in 0..3 {
                            sv[c][a] += pinv[i][a] * r;
                        }
                    }
                }
                for (i, &(v, l)) in pairs.iter().enumerate() {
                    let o = (v * nl + l) * 3;
                    for c in 0..3 {
                        let gt = x[o + c] as f64;
                        let p = phong_vals[i][c];
                        let d = sv[c][0] * hs[i][0] + sv[c][1] * hs[i][1] + sv[c][2] * hs[i][2];
                        acc[0] += (p - gt).powi(2);
                        acc[1] += (p + d - gt).powi(2);
                        acc[2] += gt * gt;
                    }
                }
                for c in 0..3 {
                    for a in 0..3 {
                        out[col * 9 + c * 3 + a] = sv[c][a] as f32;
                    }
                }
            }
            monitor.advance(1);
            acc
        })
        .reduce(|| [0.0; 3], |a, b| [a[0] + b[0], a[1] + b[1], a[2] + b[2]]);
    monitor.check()?;
    Ok((s, sums))
}

fn invert3(m: [[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
    let c = |i: usize, j: usize| {
        let (r0, r1) = ((i + 1) % 3, (i + 2) % 3);
        let (c0, c1) = ((j + 1) % 3, (j + 2) % 3);
        m[r0][c0] * m[r1][c1] - m[r0][c1] * m[r1][c0]
    };
    let det = m[0][0] * c(0, 0) + m[0][1] * c(0, 1) + m[0][2] * c(0, 2);
    let scale = m.iter().flatten().map(|x| x.abs()).fold(0.0f64, f64::max);
    if !det.is_finite() || det.abs() <= 1e-12 * scale.powi(3) {
        return None;
    }
    Some(std::array::from_fn(|i| std::array::from_fn(|j| c(j, i) / det)))
}

impl Srf {
    /// Check the arrays and parameters (for models built from loaded files).
    pub fn validate(&self) -> Result<()> {
        if self.height == 0 || self.width == 0 {
            return Err(Error::arg("s", "the model has no texels"));
        }
        if self.s.len() != self.height * self.width * 9 {
            return Err(Error::arg(
                "s",
                format!("expected {} values, got {}", self.height * self.width * 9, self.s.len()),
            ));
        }
        if let Some(i) = self.s.iter().position(|x| !x.is_finite()) {
            return Err(Error::arg("s", format!("value at flat index {i} is not finite")));
        }
        let p = &self.phong;
        if !(p.kd.iter().chain(&p.ks).all(|x| x.is_finite() && *x >= 0.0)) {
            return Err(Error::arg("phong", format!("expected finite kd, ks >= 0, got {:?} {:?}", p.kd, p.ks)));
        }
        if !(p.n >= N_RANGE.0 && p.n <= N_RANGE.1) {
            return Err(Error::arg("phong", format!("expected n in {N_RANGE:?}, got {}", p.n)));
        }
        Ok(())
    }

    /// The same model without the residual: Phong alone (s = 0), for comparisons.
    pub fn phong_only(&self) -> Srf {
        Srf { s: vec![0.0; self.s.len()], ..self.clone() }
    }
}

/// A prepared SRF query: the Phong value per channel and the halfway vector.
#[derive(Debug, Clone, Copy)]
pub struct SrfQuery {
    phong: [f32; 3],
    h: [f32; 3],
}

impl ReflectanceModel for Srf {
    type Query = SrfQuery;

    fn dims(&self) -> (usize, usize) {
        (self.height, self.width)
    }

    fn query(&self, view: [f64; 3], light: [f64; 3]) -> SrfQuery {
        let h = halfway(view, light);
        SrfQuery { phong: std::array::from_fn(|c| self.phong.eval(c, light[2], h[2]) as f32), h: h.map(|x| x as f32) }
    }

    #[inline]
    fn eval(&self, t: usize, q: &SrfQuery) -> [f32; 3] {
        let s = &self.s[t * 9..t * 9 + 9];
        std::array::from_fn(|c| q.phong[c] + s[c * 3] * q.h[0] + s[c * 3 + 1] * q.h[1] + s[c * 3 + 2] * q.h[2])
    }
}

#[cfg(test)]
mod tests;

crate::gpu_params! {
    /// Parameters of `srf.wgsl`.
    pub struct SrfParams {
        /// Store offset of the 7 material words: kd rgb, ks rgb, n (f32).
        pub material: u32,
        /// Store offset of s(P): `[texel][channel][xyz]` f32.
        pub s: u32,
    }
}

impl GpuLayout for Srf {
    type Params = SrfParams;
    const SHADER: Shader = Shader::new::<SrfParams>("srf", include_str!("../../../shaders_wgsl/srf.wgsl"));

    fn parts(&self) -> Vec<Cow<'_, [u32]>> {
        let p = &self.phong;
        let material: Vec<u32> = p.kd.iter().chain(&p.ks).chain([&p.n]).map(|&x| (x as f32).to_bits()).collect();
        vec![Cow::Owned(material), words(&self.s)]
    }

    fn params(&self, offsets: &[u32], _tables: &[u32]) -> SrfParams {
        SrfParams { material: offsets[0], s: offsets[1] }
    }
}

impl Model for Srf {
    const KIND: &'static str = "srf";
    const TEXEL_ARRAYS: &'static [&'static str] = &["s"];
    const DOC: &'static str = "Phong + spatially-varying residual function (paper 003, sections 4 and 5)";
    const ABOUT: &'static str = "\
One Blinn-Phong lobe (kd, ks per channel, one shininess n) is fitted by Levenberg-Marquardt to
the material's mean BRDF (section 4); the residual `BTF - Phong` is fitted per texel and channel
as `s(P) . H` by linear least squares over the halfway vectors, one pseudo-inverse shared by
every texel (section 5). `model.report` gives the relative error of Phong alone and of
Phong + SRF on the fitted pairs.";
    const OPTIONS: &'static [Spec] = &[];
    const EXAMPLES: &'static [(&'static str, &'static str)] = &[("Phong+SRF", "{}")];
    const BENCH: &'static [Bench] = &[
        Bench::new("Phong+SRF", "{}", &["per_material"]),
        Bench::new("", "{}", &["no_single_view"]).note("its residual spans the views; on one view it is a Phong fit"),
    ];
    const SAMPLING: Sampling =
        Sampling::Any { note: "over all pairs", one_view: "one view: the lobes see no view dependence" };
    type Options = NoOptions;
    // The mean BRDF's pass (mean_sums) checks every texel's values (TexelScan).
    const SCANS_VALUES: bool = true;
    // One Phong for the material's mean BRDF: a sum over texels before the per-texel residual.
    const BLOCKWISE: crate::blockwise::Blockwise = crate::blockwise::Blockwise::Staged("mean_brdf");

    fn fit(btf: &BtfRef<'_>, _options: &NoOptions, monitor: &Monitor) -> Result<Self> {
        fit_srf(btf, monitor).map(|(m, _)| m)
    }

    /// `phong` `[7]` f64 (kd rgb, ks rgb, n) and `s` `[H, W, 3, 3]` f32.
    fn to_arrays(&self) -> NamedArrays {
        let mut a = NamedArrays::new();
        let p = &self.phong;
        a.put("phong", &[7], p.kd.iter().chain(&p.ks).chain([&p.n]).copied().collect::<Vec<f64>>());
        a.put("s", &[self.height, self.width, 3, 3], self.s.clone());
        a
    }

    fn from_arrays(a: &NamedArrays) -> Result<Self> {
        let (p, _) = a.get::<f64>("phong", &[Some(7)])?;
        let (s, sh) = a.get::<f32>("s", &[None, None, Some(3), Some(3)])?;
        let m = Srf {
            height: sh[0],
            width: sh[1],
            phong: Phong { kd: [p[0], p[1], p[2]], ks: [p[3], p[4], p[5]], n: p[6] },
            s: s.to_vec(),
            report: SrfReport::default(),
        };
        m.validate()?;
        Ok(m)
    }

    fn report(&self) -> serde_json::Value {
        serde_json::to_value(self.report).unwrap_or_default()
    }
}
