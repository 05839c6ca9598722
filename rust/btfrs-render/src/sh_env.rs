//! Environment light in the SH domain for double-SH models (paper 002, section 4): per pixel,
//! the environment's SH vector is rotated into the pixel's tangent frame, converted by the
//! hemispherical autocorrelation matrix `A`, and dotted with the texel's light coefficients at
//! the view direction:
//!
//! ```text
//! out_c = integral_{H} f_c(v, l) L_c(l) dl = b_c(v)^T A e_c^loc,   b_cj(v) = sum_i C_cij y_i(v),
//! A_ij = integral_{z > 0} y_i y_j,   e^loc = R e   (R: world -> tangent frame, per pixel)
//! ```
//!
//! `A` is needed because the BTF's light function is only meaningful over the upper hemisphere
//! (the fit constrains nothing below): the lighting integral runs over the hemisphere, where
//! the SH are not orthogonal.
//!
//! **Rotation** by band sampling (no Wigner-D recurrences): a band-`l` function is determined
//! by its values at `2l + 1` generic directions `d_k`, so with `M_l[j][k] = y_lj(d_k)`,
//!
//! ```text
//! e^loc_l = M_l^{-T} [ E_l(R^T d_k) ]_k ,   E_l(w) = sum_j e_lj y_lj(w)   (the band-l part)
//! ```
//!
//! since the rotated band-l function evaluated at `d_k` is the original at `R^T d_k` and
//! rotations keep bands. The `d_k` of each band are chosen once (deterministically) for a small
//! condition number of `M_l`. The per-pixel work is then `n` band evaluations at world
//! directions `R^T d_k` and one product with `G = A blockdiag(M_l^{-T})`, precomputed here; the
//! shader (`fs_env` of sh.wgsl) and the CPU reference ([`crate::cpu::render_cpu_env_sh`]) do
//! exactly that.

use crate::environment::Environment;
use btfrs_core::rng::Rng;
use btfrs_core::{Error, Result};
use btfrs_fit::sh_basis;

/// Inverse of the `n x n` row-major matrix `m` by Gauss-Jordan with partial pivoting; None if
/// singular.
fn invert(m: &[f64], n: usize) -> Option<Vec<f64>> {
    let mut a = m.to_vec();
    let mut inv: Vec<f64> = (0..n * n).map(|i| if i / n == i % n { 1.0 } else { 0.0 }).collect();
    for c in 0..n {
        let p = (c..n).max_by(|&x, &y| a[x * n + c].abs().total_cmp(&a[y * n + c].abs()))?;
        if a[p * n + c].abs() < 1e-12 {
            return None;
        }
        for k in 0..n {
            a.swap(c * n + k, p * n + k);
            inv.swap(c * n + k, p * n + k);
        }
        let d = a[c * n + c];
        for k in 0..n {
            a[c * n + k] /= d;
            inv[c * n + k] /= d;
        }
        for r in 0..n {
            if r != c {
                let f = a[r * n + c];
                if f != 0.0 {
                    for k in 0..n {
                        a[r * n + k] -= f * a[c * n + k];
                        inv[r * n + k] -= f * inv[c * n + k];
                    }
                }
            }
        }
    }
    Some(inv)
}

/// `M_l[j][k] = y_{l^2 + j}(d_k)`, row-major.
fn band_matrix(l: usize, dirs: &[[f64; 3]]) -> Vec<f64> {
    let m = 2 * l + 1;
    let n = (l + 1) * (l + 1);
    let mut y = vec![0.0; n];
    let mut out = vec![0.0; m * m];
    for (k, d) in dirs.iter().enumerate() {
        sh_basis(n, *d, &mut y);
        for j in 0..m {
            out[j * m + k] = y[l * l + j];
        }
    }
    out
}

/// The `2l + 1` sampling directions of band `l`: of 64 seeded random sets, the one whose `M_l`
/// has the smallest condition number (Frobenius), so rounding in f32 stays small.
pub fn band_directions(l: usize) -> Vec<[f64; 3]> {
    let m = 2 * l + 1;
    let mut best = (f64::INFINITY, Vec::new());
    for seed in 0..64u64 {
        let mut rng = Rng::new(0x5eed_0000 + 97 * l as u64 + seed);
        let dirs: Vec<[f64; 3]> = (0..m)
            .map(|_| {
                let z = 2.0 * rng.next_f64() - 1.0;
                let phi = 2.0 * std::f64::consts::PI * rng.next_f64();
                let s = (1.0 - z * z).sqrt();
                [s * phi.cos(), s * phi.sin(), z]
            })
            .collect();
        let mat = band_matrix(l, &dirs);
        let Some(inv) = invert(&mat, m) else { continue };
        let fro = |a: &[f64]| a.iter().map(|x| x * x).sum::<f64>().sqrt();
        let cond = fro(&mat) * fro(&inv);
        if cond < best.0 {
            best = (cond, dirs);
        }
    }
    best.1
}

/// `A_ij = integral over the upper hemisphere of y_i y_j` for the first `n` SH, row-major: by
/// Gauss-Legendre in z (24 nodes on [0, 1]) times 64 uniform azimuths, exact for these
/// polynomials up to degree 7 (products are trigonometric of degree <= 14 in phi, and the
/// terms that survive the phi integral are polynomials of degree <= 14 in z).
pub fn hemisphere_gram(n: usize) -> Vec<f64> {
    let (nodes, weights) = gauss_legendre(24);
    let n_phi = 64;
    let mut a = vec![0.0; n * n];
    let mut y = vec![0.0; n];
    for (x, w) in nodes.iter().zip(&weights) {
        let z = 0.5 * (x + 1.0);
        let wz = 0.5 * w * 2.0 * std::f64::consts::PI / n_phi as f64;
        let s = (1.0 - z * z).sqrt();
        for p in 0..n_phi {
            let phi = 2.0 * std::f64::consts::PI * (p as f64 + 0.5) / n_phi as f64;
            sh_basis(n, [s * phi.cos(), s * phi.sin(), z], &mut y);
            for i in 0..n {
                for j in 0..n {
                    a[i * n + j] += wz * y[i] * y[j];
                }
            }
        }
    }
    a
}

/// Nodes and weights of `m`-point Gauss-Legendre quadrature on [-1, 1] (Newton on P_m).
fn gauss_legendre(m: usize) -> (Vec<f64>, Vec<f64>) {
    let mut nodes = vec![0.0; m];
    let mut weights = vec![0.0; m];
    for i in 0..m {
        let mut x = (std::f64::consts::PI * (i as f64 + 0.75) / (m as f64 + 0.5)).cos();
        for _ in 0..100 {
            let (mut p0, mut p1) = (1.0, x);
            for k in 2..=m {
                let p2 = ((2 * k - 1) as f64 * x * p1 - (k - 1) as f64 * p0) / k as f64;
                p0 = p1;
                p1 = p2;
            }
            let dp = m as f64 * (x * p1 - p0) / (x * x - 1.0);
            let dx = p1 / dp;
            x -= dx;
            if dx.abs() < 1e-15 {
                let (mut q0, mut q1) = (1.0, x);
                for k in 2..=m {
                    let q2 = ((2 * k - 1) as f64 * x * q1 - (k - 1) as f64 * q0) / k as f64;
                    q0 = q1;
                    q1 = q2;
                }
                let dq = m as f64 * (x * q1 - q0) / (x * x - 1.0);
                weights[i] = 2.0 / ((1.0 - x * x) * dq * dq);
                break;
            }
        }
        nodes[i] = x;
    }
    (nodes, weights)
}

/// Everything per frame of the SH method: the environment's coefficients, the band sampling
/// directions and `G = A blockdiag(M_l^{-T})`.
#[derive(Debug, Clone)]
pub struct ShEnvironment {
    /// Coefficients, a perfect square (the model's light coefficients).
    pub n: usize,
    /// `d_k`, `n` directions, band by band.
    pub dirs: Vec<[f64; 3]>,
    /// The environment's SH projection, per coefficient RGB.
    pub coeffs: Vec<[f64; 3]>,
    /// `G`, `n x n` row-major.
    pub g: Vec<f64>,
}

impl ShEnvironment {
    /// Prepare `env` for a model with `n` light coefficients (a perfect square <= 64).
    pub fn new(env: &Environment, n: usize) -> Result<ShEnvironment> {
        let deg = (n as f64).sqrt().round() as usize;
        if n == 0 || deg * deg != n || n > btfrs_fit::sh::MAX_COEFFS {
            return Err(Error::arg(
                "method",
                format!("the SH method needs a square number of light coefficients up to 64, got {n}"),
            ));
        }
        let mut dirs = Vec::with_capacity(n);
        let mut minv_t = vec![0.0; n * n]; // blockdiag(M_l^{-T})
        for l in 0..deg {
            let d = band_directions(l);
            let m = 2 * l + 1;
            let inv = invert(&band_matrix(l, &d), m)
                .ok_or_else(|| Error::Degenerate(format!("no invertible sampling set for SH band {l}")))?;
            let o = l * l;
            for j in 0..m {
                for k in 0..m {
                    // (M^{-T})[j][k] = (M^{-1})[k][j]
                    minv_t[(o + j) * n + o + k] = inv[k * m + j];
                }
            }
            dirs.extend(d);
        }
        let a = hemisphere_gram(n);
        let mut g = vec![0.0; n * n];
        for i in 0..n {
            for k in 0..n {
                g[i * n + k] = (0..n).map(|j| a[i * n + j] * minv_t[j * n + k]).sum();
            }
        }
        Ok(ShEnvironment { n, dirs, coeffs: env.sh_project(n), g })
    }

    /// The band-wise values `f_k = E_{band(k)}(R^T d_k)` for the tangent frame (t, b, n) (world
    /// vectors, unit), the quantity the shader computes per pixel.
    #[allow(clippy::needless_range_loop)] // index arithmetic of the bands reads clearer
    pub fn band_values(&self, t: [f64; 3], b: [f64; 3], nrm: [f64; 3]) -> Vec<[f64; 3]> {
        let mut y = vec![0.0; self.n];
        let mut out = vec![[0.0; 3]; self.n];
        for (k, d) in self.dirs.iter().enumerate() {
            let l = (k as f64).sqrt().floor() as usize;
            let w = [0, 1, 2].map(|c| d[0] * t[c] + d[1] * b[c] + d[2] * nrm[c]);
            let len = (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt();
            sh_basis((l + 1) * (l + 1), w.map(|x| x / len), &mut y);
            for j in l * l..(l + 1) * (l + 1) {
                for ch in 0..3 {
                    out[k][ch] += self.coeffs[j][ch] * y[j];
                }
            }
        }
        out
    }

    /// The environment's coefficients in the tangent frame, `e^loc = blockdiag(M_l^{-T}) f`
    /// (what [`ShEnvironment::band_values`] stands for; tested against direct projection).
    pub fn rotated(&self, t: [f64; 3], b: [f64; 3], nrm: [f64; 3]) -> Vec<[f64; 3]> {
        let f = self.band_values(t, b, nrm);
        let mut out = vec![[0.0; 3]; self.n];
        let deg = (self.n as f64).sqrt().round() as usize;
        for l in 0..deg {
            let (o, m) = (l * l, 2 * l + 1);
            let inv = invert(&band_matrix(l, &self.dirs[o..o + m]), m).expect("checked in new");
            for j in 0..m {
                for k in 0..m {
                    for ch in 0..3 {
                        out[o + j][ch] += inv[k * m + j] * f[o + k][ch];
                    }
                }
            }
        }
        out
    }

    /// `h = G f`: the vector each texel's light coefficients are dotted with.
    pub fn converted(&self, f: &[[f64; 3]]) -> Vec<[f64; 3]> {
        (0..self.n)
            .map(|i| {
                let mut s = [0.0; 3];
                for (k, fk) in f.iter().enumerate() {
                    for ch in 0..3 {
                        s[ch] += self.g[i * self.n + k] * fk[ch];
                    }
                }
                s
            })
            .collect()
    }

    /// The GPU form: `[d_k (xyz, 0)] x n`, `[e_j (rgb, 0)] x n`, then `G` by rows of
    /// `ceil(n / 4)` vec4 (zero padded): what `fs_env` of sh.wgsl reads from `env`.
    pub fn gpu_words(&self) -> Vec<[f32; 4]> {
        let n = self.n;
        let rw = n.div_ceil(4);
        let mut out = Vec::with_capacity(2 * n + n * rw);
        out.extend(self.dirs.iter().map(|d| [d[0] as f32, d[1] as f32, d[2] as f32, 0.0]));
        out.extend(self.coeffs.iter().map(|c| [c[0] as f32, c[1] as f32, c[2] as f32, 0.0]));
        for i in 0..n {
            for w in 0..rw {
                let mut v = [0.0f32; 4];
                for (s, x) in v.iter_mut().enumerate() {
                    let k = 4 * w + s;
                    if k < n {
                        *x = self.g[i * n + k] as f32;
                    }
                }
                out.push(v);
            }
        }
        out
    }
}

#[cfg(test)]
#[allow(clippy::needless_range_loop)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    fn some_env() -> Environment {
        Environment::sky([0.5, -0.3, 0.7], 2.5, 32, 0.3).unwrap()
    }

    #[test]
    fn inverse_and_gram_are_right() {
        let m = [4.0, 1.0, 2.0, 0.5, 3.0, 1.0, 2.0, 1.0, 5.0];
        let inv = invert(&m, 3).unwrap();
        for i in 0..3 {
            for j in 0..3 {
                let p: f64 = (0..3).map(|k| m[i * 3 + k] * inv[k * 3 + j]).sum();
                assert!((p - (i == j) as u8 as f64).abs() < 1e-12);
            }
        }
        let a = hemisphere_gram(16);
        // Half the sphere: diagonal of the even-in-z functions is 1/2; A_00 = 1/2 exactly, and
        // A_02 = integral_H y0 y2 = sqrt(3)/(4 pi) * pi = sqrt(3) / 4.
        assert!((a[0] - 0.5).abs() < 1e-12);
        assert!((a[2] - 3f64.sqrt() / 4.0).abs() < 1e-12, "{}", a[2]);
        // Functions odd under (x, y) -> (-x, -y) against even ones: 0; symmetric.
        for i in 0..16 {
            for j in 0..16 {
                assert!((a[i * 16 + j] - a[j * 16 + i]).abs() < 1e-13);
            }
        }
        let (x, w) = gauss_legendre(24);
        assert!((w.iter().sum::<f64>() - 2.0).abs() < 1e-13);
        assert!((x.iter().zip(&w).map(|(x, w)| w * x.powi(10)).sum::<f64>() - 2.0 / 11.0).abs() < 1e-13);
        let _ = PI;
    }

    #[test]
    fn rotation_equals_projecting_the_rotated_environment() {
        // A tangent frame (t, b, n): the local coefficients must equal the projection of the
        // function w_local -> E(R^T w_local), computed by quadrature directly.
        let env = some_env();
        let n = 25;
        let sh = ShEnvironment::new(&env, n).unwrap();
        let nrm = [0.3f64, -0.5, 0.81];
        let len = nrm.iter().map(|x| x * x).sum::<f64>().sqrt();
        let nrm = nrm.map(|x| x / len);
        let t0 = [1.0, 0.0, 0.0];
        let d = t0[0] * nrm[0];
        let t = [t0[0] - d * nrm[0], -d * nrm[1], -d * nrm[2]];
        let tl = t.iter().map(|x| x * x).sum::<f64>().sqrt();
        let t = t.map(|x| x / tl);
        let b = [nrm[1] * t[2] - nrm[2] * t[1], nrm[2] * t[0] - nrm[0] * t[2], nrm[0] * t[1] - nrm[1] * t[0]];
        let got = sh.rotated(t, b, nrm);
        // Direct: the band-limited environment (its own SH series) rotated, projected again.
        let mut direct = vec![[0.0f64; 3]; n];
        let (nodes, weights) = gauss_legendre(24);
        let mut y = vec![0.0; n];
        let mut yw = vec![0.0; n];
        for (x, wz) in nodes.iter().zip(&weights) {
            let s = (1.0 - x * x).sqrt();
            for p in 0..64 {
                let phi = 2.0 * PI * (p as f64 + 0.5) / 64.0;
                let wl = [s * phi.cos(), s * phi.sin(), *x];
                let ww = [0, 1, 2].map(|c| wl[0] * t[c] + wl[1] * b[c] + wl[2] * nrm[c]);
                sh_basis(n, ww, &mut yw);
                sh_basis(n, wl, &mut y);
                let wgt = wz * 2.0 * PI / 64.0;
                for ch in 0..3 {
                    let e: f64 = (0..n).map(|j| sh.coeffs[j][ch] * yw[j]).sum();
                    for j in 0..n {
                        direct[j][ch] += wgt * e * y[j];
                    }
                }
            }
        }
        for j in 0..n {
            for ch in 0..3 {
                assert!((got[j][ch] - direct[j][ch]).abs() < 1e-9 * (1.0 + direct[0][ch].abs()), "coefficient {j}");
            }
        }
        // And the identity frame changes nothing.
        let same = sh.rotated([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]);
        for j in 0..n {
            assert!((same[j][1] - sh.coeffs[j][1]).abs() < 1e-10);
        }
    }

    #[test]
    fn not_square_is_an_error() {
        assert!(matches!(ShEnvironment::new(&some_env(), 10), Err(Error::InvalidArgument { .. })));
    }
}
