#![allow(clippy::needless_range_loop)] // index loops mirror the formulas being checked
use super::*;
use crate::model::Model;
use crate::model::{evaluate_image, model_error};
use btfrs_core::directions::{from_theta_phi, ubo81};
use btfrs_core::materials::{generate, MaterialSpec, Preset};
use btfrs_core::rng::Rng;
use nalgebra::DVector;
use std::f64::consts::PI;

fn opts(kv: usize, kl: usize, cls: bool, quantize: bool) -> ShOptions {
    ShOptions { view_coeffs: kv, light_coeffs: kl, cls, quantize, ..Default::default() }
}

fn fit(btf: &BtfRef<'_>, o: &ShOptions, knobs: Knobs) -> (Sh, Detail) {
    let (sh, d) = fit_sh_with(btf, o, &Monitor::new(), &knobs, true).unwrap();
    (sh, d.unwrap())
}

fn floats(sh: &Sh) -> &[f32] {
    match &sh.coeffs {
        ShCoeffs::Float(c) => c,
        ShCoeffs::Quantized { .. } => panic!("expected float coefficients"),
    }
}

fn normal(rng: &mut Rng) -> f64 {
    // Box-Muller.
    let (u, v) = (rng.next_f64().max(1e-300), rng.next_f64());
    (-2.0 * u.ln()).sqrt() * (2.0 * PI * v).cos()
}

/// Data generated from the model: random `kt x kt` coefficients per texel and channel.
fn model_btf(t: usize, kt: usize, seed: u64) -> (Vec<[f64; 3]>, Vec<f32>, Vec<f64>) {
    let d = ubo81();
    let n = d.len();
    let mut rng = Rng::new(seed);
    let truth: Vec<f64> = (0..t * 3 * kt * kt).map(|_| rng.next_f64() - 0.5).collect();
    let y = basis_matrix(&d, kt);
    let mut data = vec![0.0f32; t * n * n * 3];
    for tx in 0..t {
        for v in 0..n {
            for l in 0..n {
                for ch in 0..3 {
                    let c = &truth[(tx * 3 + ch) * kt * kt..][..kt * kt];
                    let mut s = 0.0;
                    for i in 0..kt {
                        for j in 0..kt {
                            s += c[i * kt + j] * y[v * kt + i] * y[l * kt + j];
                        }
                    }
                    data[((tx * n + v) * n + l) * 3 + ch] = s as f32;
                }
            }
        }
    }
    (d, data, truth)
}

/// A smooth (analytic) ABRDF per texel and channel: diffuse, a view-dependent term and a broad
/// specular lobe, all times cos(theta_l); plus Gaussian noise of standard deviation `sigma`.
/// Returns (noisy, clean).
fn smooth_btf(t: usize, sigma: f64, seed: u64) -> (Vec<f32>, Vec<f32>) {
    let d = ubo81();
    let n = d.len();
    let mut rng = Rng::new(seed);
    let mut noisy = vec![0.0f32; t * n * n * 3];
    let mut clean = vec![0.0f32; t * n * n * 3];
    for tx in 0..t {
        let p: Vec<[f64; 3]> = (0..3).map(|_| [rng.next_f64(), rng.next_f64(), rng.next_f64()]).collect();
        for (v, dv) in d.iter().enumerate() {
            for (l, dl) in d.iter().enumerate() {
                let r = [-dl[0], -dl[1], dl[2]]; // mirror direction of the light
                let rv = r[0] * dv[0] + r[1] * dv[1] + r[2] * dv[2];
                for ch in 0..3 {
                    let [a, b, c] = p[ch];
                    let f = dl[2] * (0.3 + 0.5 * a + 0.3 * b * dv[2] + 0.4 * c * (-3.0 * (1.0 - rv)).exp());
                    let k = ((tx * n + v) * n + l) * 3 + ch;
                    clean[k] = f as f32;
                    noisy[k] = (f + sigma * normal(&mut rng)) as f32;
                }
            }
        }
    }
    (noisy, clean)
}

/// Relative L2 error of a model against the clean data.
fn rel_error(sh: &Sh, d: &[[f64; 3]], h: usize, w: usize, clean: &[f32]) -> f64 {
    model_error(sh, &BtfRef::new(h, w, d, d, clean, None).unwrap()).unwrap().relative()
}

#[test]
fn basis_matches_closed_forms() {
    // Real SH with the Condon-Shortley phase, degrees 0..2 (e.g. Sloan, "Stupid SH tricks").
    let mut rng = Rng::new(3);
    for _ in 0..50 {
        // Any direction of the sphere, lower hemisphere included.
        let d = from_theta_phi(PI * rng.next_f64(), 2.0 * PI * rng.next_f64());
        let [x, y, z] = d;
        let want = [
            0.282_094_791_773_878_1,
            -0.488_602_511_902_919_9 * y,
            0.488_602_511_902_919_9 * z,
            -0.488_602_511_902_919_9 * x,
            1.092_548_430_592_079 * x * y,
            -1.092_548_430_592_079 * y * z,
            0.315_391_565_252_520_05 * (3.0 * z * z - 1.0),
            -1.092_548_430_592_079 * x * z,
            0.546_274_215_296_039_5 * (x * x - y * y),
        ];
        let mut out = [0.0f64; 9];
        sh_basis(9, d, &mut out);
        for i in 0..9 {
            assert!((out[i] - want[i]).abs() < 1e-12, "y_{i} at {d:?}: {} vs {}", out[i], want[i]);
        }
        // The first n of a larger basis; n need not be a square; out may be short.
        let mut big = [7.0f64; 64];
        sh_basis(64, d, &mut big);
        assert_eq!(&big[..9], &out[..]);
        let mut five = [0.0f64; 5];
        sh_basis(64, d, &mut five);
        assert_eq!(&five[..], &out[..5]);
    }
    // Degree 3, m = 3 (a closed form with the (2m-1)!! = 15 factor): -0.5900436 x (x^2 - 3 y^2).
    let d = from_theta_phi(1.1, 0.7);
    let mut out = [0.0f64; 16];
    sh_basis(16, d, &mut out);
    let want = -0.590_043_589_926_643_5 * d[0] * (d[0] * d[0] - 3.0 * d[1] * d[1]);
    assert!((out[15] - want).abs() < 1e-12, "{} vs {want}", out[15]);
}

#[test]
fn basis_is_orthonormal_on_the_sphere() {
    // Midpoint rule in z = cos(theta) (error O(dz^2) on these polynomials in z) times a uniform
    // rule in phi (exact for the trigonometric degrees up to 2 * 7 < 32).
    let (nz, nphi, n) = (3000usize, 32usize, 64usize);
    let wq = (2.0 / nz as f64) * (2.0 * PI / nphi as f64);
    let mut gram = vec![0.0f64; n * n];
    let mut y = [0.0f64; 64];
    for iz in 0..nz {
        let z = -1.0 + (iz as f64 + 0.5) * 2.0 / nz as f64;
        let s = (1.0 - z * z).sqrt();
        for ip in 0..nphi {
            let phi = 2.0 * PI * (ip as f64 + 0.3) / nphi as f64;
            sh_basis(n, [s * phi.cos(), s * phi.sin(), z], &mut y);
            for i in 0..n {
                let wi = wq * y[i];
                for j in i..n {
                    gram[i * n + j] += wi * y[j];
                }
            }
        }
    }
    let mut worst = 0.0f64;
    for i in 0..n {
        for j in i..n {
            let want = if i == j { 1.0 } else { 0.0 };
            worst = worst.max((gram[i * n + j] - want).abs());
        }
    }
    assert!(worst < 1e-3, "largest deviation from the identity {worst}");
}

#[test]
fn quadrature_weights_integrate_the_hemisphere() {
    let d = ubo81();
    let w = solid_angle_weights(&d);
    assert!((w.iter().sum::<f64>() - 2.0 * PI).abs() < 1e-9);
    assert!(w.iter().all(|&x| x > 0.0));
    // The integral of cos(theta) over the hemisphere is pi; of cos^2, 2 pi / 3. UBO 81 stops at
    // 75 degrees, so its outer ring's cells reach the horizon: a few percent is what it can do.
    let i1: f64 = w.iter().zip(&d).map(|(w, d)| w * d[2]).sum();
    let i2: f64 = w.iter().zip(&d).map(|(w, d)| w * d[2] * d[2]).sum();
    assert!((i1 / PI - 1.0).abs() < 0.07, "{i1}");
    assert!((i2 / (2.0 * PI / 3.0) - 1.0).abs() < 0.07, "{i2}");
    // A dense, even set (a Fibonacci spiral of 1000 directions): well under 1 %.
    let fib: Vec<[f64; 3]> = (0..1000)
        .map(|i| {
            let z = 1.0 - (i as f64 + 0.5) / 1000.0;
            let phi = i as f64 * PI * (3.0 - 5f64.sqrt());
            let s = (1.0 - z * z).sqrt();
            [s * phi.cos(), s * phi.sin(), z]
        })
        .collect();
    let wf = solid_angle_weights(&fib);
    let j1: f64 = wf.iter().zip(&fib).map(|(w, d)| w * d[2]).sum();
    let j2: f64 = wf.iter().zip(&fib).map(|(w, d)| w * d[0] * d[0] * d[2]).sum();
    assert!((j1 / PI - 1.0).abs() < 0.005, "{j1}");
    assert!((j2 / (PI / 4.0) - 1.0).abs() < 0.01, "{j2}");
    // Duplicated directions share their weight.
    let mut dup = d.clone();
    dup.push(d[10]);
    let wd = solid_angle_weights(&dup);
    assert!((wd[10] - w[10] / 2.0).abs() < 1e-12 && (wd[81] - wd[10]).abs() < 1e-15);
}

#[test]
fn plain_ls_recovers_model_data_and_inactive_cls_equals_it() {
    // 9 x 9 random coefficients, fitted with 16 x 16: the extra coefficients must come out 0.
    let t = 6;
    let (d, data, truth) = model_btf(t, 9, 11);
    let btf = BtfRef::new(2, 3, &d, &d, &data, None).unwrap();
    let (ls, dls) = fit(&btf, &opts(16, 16, false, false), Knobs::default());
    let e = model_error(&ls, &btf).unwrap().relative();
    assert!(e < 1e-4, "relative reconstruction error {e}");
    assert!(dls.lambda.iter().all(|&l| l == 0.0) && ls.constrained_fraction == 0.0);
    let c = floats(&ls);
    let mut worst = 0.0f64;
    for tc in 0..t * 3 {
        for i in 0..16 {
            for j in 0..16 {
                let want = if i < 9 && j < 9 { truth[tc * 81 + i * 9 + j] } else { 0.0 };
                worst = worst.max((c[tc * 256 + i * 16 + j] as f64 - want).abs());
            }
        }
    }
    assert!(worst < 1e-3, "largest coefficient error {worst}");
    // With a bound the least-squares solution meets, CLS picks lambda = 0 and equals LS.
    let (big, dbig) = fit(&btf, &opts(16, 16, true, false), Knobs { energy_factor: 1e6, ..Default::default() });
    assert!(dbig.lambda.iter().all(|&l| l == 0.0));
    assert_eq!(floats(&big), c);
    // With the paper's bound the constraint is active here: the coefficient energy of a
    // function is its energy over the whole sphere of each direction, E only its energy over
    // the measured hemispheres, so ||c_true||^2 > E whenever the function lives below the horizon.
    let (cls, _) = fit(&btf, &opts(16, 16, true, false), Knobs::default());
    assert_eq!(cls.constrained_fraction, 1.0);
    assert!(cls.mean_lambda > 0.0);
}

/// Brute-force reference: Y over the present pairs (rows kron(yv, yl)), A = Y^T Y, b = Y^T beta,
/// all in f64 without any eigen-decomposition; returns c(lambda) by Cholesky.
struct Brute {
    a: DMatrix<f64>,
    b: Vec<DVector<f64>>,
}

impl Brute {
    /// `k` coefficients per direction.
    fn new(btf: &BtfRef<'_>, k: usize) -> Self {
        let (nv, nl, n) = (btf.views.len(), btf.lights.len(), k * k);
        let yv = basis_matrix(btf.views, k);
        let yl = basis_matrix(btf.lights, k);
        let mut a = DMatrix::<f64>::zeros(n, n);
        let mut b = vec![DVector::<f64>::zeros(n); btf.texels() * 3];
        let mut row = vec![0.0f64; n];
        for v in 0..nv {
            for l in 0..nl {
                if !btf.has(v, l) {
                    continue;
                }
                for i in 0..k {
                    for j in 0..k {
                        row[i * k + j] = yv[v * k + i] * yl[l * k + j];
                    }
                }
                for p in 0..n {
                    for q in 0..n {
                        a[(p, q)] += row[p] * row[q];
                    }
                }
                for t in 0..btf.texels() {
                    for ch in 0..3 {
                        let f = btf.texel(t)[(v * nl + l) * 3 + ch] as f64;
                        for p in 0..n {
                            b[t * 3 + ch][p] += row[p] * f;
                        }
                    }
                }
            }
        }
        Brute { a, b }
    }

    fn solve(&self, fit: usize, lambda: f64) -> DVector<f64> {
        let n = self.a.nrows();
        let m = &self.a + DMatrix::<f64>::identity(n, n) * lambda;
        m.cholesky().expect("positive definite").solve(&self.b[fit])
    }
}

/// Check every fit of `sh` (float coefficients, `k x k`) against the brute-force reference: the bound
/// holds, lambda is the smallest that meets it, and the coefficients are c(lambda).
fn check_cls(btf: &BtfRef<'_>, sh: &Sh, det: &Detail, k: usize) {
    let brute = Brute::new(btf, k);
    let c = floats(sh);
    let n = k * k;
    let mut active = 0;
    for f in 0..btf.texels() * 3 {
        let (lambda, e) = (det.lambda[f], det.energy[f]);
        let got = &c[f * n..(f + 1) * n];
        let norm2: f64 = got.iter().map(|&x| x as f64 * x as f64).sum();
        assert!(norm2 <= e * (1.0 + 1e-6), "fit {f}: ||c||^2 = {norm2} > E = {e}");
        if lambda > 0.0 {
            active += 1;
            let smaller = brute.solve(f, 0.99 * lambda).norm_squared();
            assert!(smaller > e, "fit {f}: lambda {lambda} is not the smallest ({smaller} <= {e})");
        }
        let want = brute.solve(f, lambda.max(1e-300));
        let scale = want.amax().max(1e-12);
        for p in 0..n {
            assert!(
                (got[p] as f64 - want[p]).abs() < 1e-5 * scale,
                "fit {f} coefficient {p}: {} vs brute force {} (lambda {lambda})",
                got[p],
                want[p]
            );
        }
    }
    assert!(active > 0, "the constraint was never active: the test would not test it");
}

#[test]
fn cls_meets_the_bound_with_the_smallest_lambda() {
    let d = ubo81();
    let (noisy, _) = smooth_btf(4, 0.02, 5);
    // Complete grid (separable path) and a masked one (general path, 15 % of the pairs held out).
    let btf = BtfRef::new(2, 2, &d, &d, &noisy, None).unwrap();
    let (sh, det) = fit(&btf, &opts(9, 9, true, false), Knobs::default());
    check_cls(&btf, &sh, &det, 9);
    let (train, _) = btfrs_core::split::split_pairs(81, 81, None, 0.15, 4).unwrap();
    let masked = BtfRef::new(2, 2, &d, &d, &noisy, Some(&train)).unwrap();
    let (shm, detm) = fit(&masked, &opts(9, 9, true, false), Knobs::default());
    check_cls(&masked, &shm, &detm, 9);
    // The energy bound: the quadrature sum over the present pairs, scaled up to the whole grid.
    let w = solid_angle_weights(&d);
    let (mut all, mut part, mut sum) = (0.0, 0.0, 0.0);
    for v in 0..81 {
        for l in 0..81 {
            all += w[v] * w[l];
            if train[v * 81 + l] {
                part += w[v] * w[l];
                let f = noisy[(v * 81 + l) * 3] as f64; // texel 0, red
                sum += w[v] * w[l] * f * f;
            }
        }
    }
    assert!((detm.energy[0] / (sum * all / part) - 1.0).abs() < 1e-12);
}

#[test]
fn separable_and_general_paths_agree() {
    let d = ubo81();
    let (noisy, _) = smooth_btf(3, 0.02, 6);
    let btf = BtfRef::new(1, 3, &d, &d, &noisy, None).unwrap();
    for (k, cls) in [(16, true), (9, false), (25, true)] {
        let o = opts(k, k, cls, false);
        let (a, da) = fit(&btf, &o, Knobs::default());
        let (b, db) = fit(&btf, &o, Knobs { force_general: true, ..Default::default() });
        let (ca, cb) = (floats(&a), floats(&b));
        let amax = ca.iter().fold(0.0f32, |m, x| m.max(x.abs()));
        let diff = ca.iter().zip(cb).fold(0.0f32, |m, (x, y)| m.max((x - y).abs()));
        assert!(diff <= 1e-5 * amax, "{k} x {k} cls {cls}: largest difference {diff} (largest coefficient {amax})");
        for (la, lb) in da.lambda.iter().zip(&db.lambda) {
            assert!((la - lb).abs() <= 1e-5 * la.max(*lb), "lambda {la} vs {lb}");
        }
    }
}

#[test]
fn held_out_pairs_do_not_influence_the_fit() {
    let d = ubo81();
    let (mut noisy, _) = smooth_btf(2, 0.02, 7);
    let (train, test) = btfrs_core::split::split_pairs(81, 81, None, 0.2, 1).unwrap();
    let o = opts(16, 16, true, true);
    let a = fit_sh(&BtfRef::new(1, 2, &d, &d, &noisy, Some(&train)).unwrap(), &o, &Monitor::new()).unwrap();
    for (i, x) in noisy.iter_mut().enumerate() {
        if test[(i / 3) % (81 * 81)] {
            // Large finite values: a non-finite one anywhere is refused (the fit scans every
            // value, as the caller's check would).
            *x = if i % 2 == 0 { 1e6 } else { -3e30 };
        }
    }
    let b = fit_sh(&BtfRef::new(1, 2, &d, &d, &noisy, Some(&train)).unwrap(), &o, &Monitor::new()).unwrap();
    assert_eq!(a.coeffs, b.coeffs);
    // A non-finite value is an error naming where it is, as check_finite names it.
    let present = train.iter().position(|&b| b).unwrap();
    let at = (81 * 81 + present) * 3 + 2;
    noisy[at] = f32::INFINITY;
    let e = fit_sh(&BtfRef::new(1, 2, &d, &d, &noisy, Some(&train)).unwrap(), &o, &Monitor::new()).unwrap_err();
    assert_eq!(e.to_string(), format!("data: value inf at flat index {at} is not finite"));
    // An all-true mask takes the separable path and gives the unmasked result.
    let (noisy, _) = smooth_btf(2, 0.02, 7);
    let all = vec![true; 81 * 81];
    let c = fit_sh(&BtfRef::new(1, 2, &d, &d, &noisy, Some(&all)).unwrap(), &o, &Monitor::new()).unwrap();
    let e = fit_sh(&BtfRef::new(1, 2, &d, &d, &noisy, None).unwrap(), &o, &Monitor::new()).unwrap();
    assert_eq!(c.coeffs, e.coeffs);
}

#[test]
fn cls_survives_quantization_better_than_plain_ls() {
    // Paper 002, section 3.1: CLS "noise-proves" the coefficients before 8-bit quantization.
    let d = ubo81();
    let (h, w) = (2, 2);
    let (noisy, clean) = smooth_btf(h * w, 0.02, 8);
    let btf = BtfRef::new(h, w, &d, &d, &noisy, None).unwrap();
    let cls = fit_sh(&btf, &opts(25, 25, true, true), &Monitor::new()).unwrap();
    let ls = fit_sh(&btf, &opts(25, 25, false, true), &Monitor::new()).unwrap();
    let (ec, el) = (rel_error(&cls, &d, h, w, &clean), rel_error(&ls, &d, h, w, &clean));
    let fc = fit_sh(&btf, &opts(25, 25, true, false), &Monitor::new()).unwrap();
    let fl = fit_sh(&btf, &opts(25, 25, false, false), &Monitor::new()).unwrap();
    println!(
        "noisy smooth data, 25 x 25, error against the noise-free function: CLS 8-bit {ec:.4}, LS 8-bit {el:.4}; \
         f32: CLS {:.4}, LS {:.4}",
        rel_error(&fc, &d, h, w, &clean),
        rel_error(&fl, &d, h, w, &clean)
    );
    assert!(ec < 0.5 * el, "8-bit CLS error {ec:.4} should be well below 8-bit LS error {el:.4}");
    assert!(ec < 0.1, "8-bit CLS error {ec:.4} against the noise-free function");
    assert!(cls.constrained_fraction > 0.0);
}

#[test]
fn quantization_round_trip() {
    let mut rng = Rng::new(9);
    let (kv, kl) = (4, 9);
    let c: Vec<f32> = (0..5 * 3 * kv * kl).map(|k| ((rng.next_f64() - 0.3) * (1 + k % 3) as f64) as f32).collect();
    let (q, scale, bias) = quantize(&c, kv * kl);
    for (k, (&x, &qk)) in c.iter().zip(&q).enumerate() {
        let ch = (k / (kv * kl)) % 3;
        let back = bias[ch] + scale[ch] * qk as f32;
        assert!((back - x).abs() <= scale[ch] * 0.5 * (1.0 + 1e-4), "{k}: {x} -> {back} (scale {})", scale[ch]);
    }
    // The extremes are exact ends of the range.
    assert!(q.contains(&0) && q.contains(&255));
    // All-equal coefficients: scale 0, no division, exact reconstruction.
    let flat = vec![0.25f32; 3 * kv * kl];
    let (q, scale, bias) = quantize(&flat, kv * kl);
    assert_eq!(scale, [0.0; 3]);
    assert_eq!(bias, [0.25; 3]);
    assert!(q.iter().all(|&x| x == 0));
    // A fitted model: the stored bytes dequantize to within scale/2 of the float fit, and the
    // quantized evaluation equals the float evaluation of the dequantized coefficients.
    let d = ubo81();
    let (noisy, _) = smooth_btf(2, 0.01, 10);
    let btf = BtfRef::new(1, 2, &d, &d, &noisy, None).unwrap();
    let f = fit_sh(&btf, &opts(9, 16, true, false), &Monitor::new()).unwrap();
    let qm = fit_sh(&btf, &opts(9, 16, true, true), &Monitor::new()).unwrap();
    let ShCoeffs::Quantized { scale, .. } = qm.coeffs else { panic!("expected quantized") };
    // As uploaded: the shader reads 8-bit rows of whole words (16 light coefficients = 4 words)
    // plus scale and bias; a float model is quantized for the GPU, so it uploads the same.
    assert_eq!(qm.nbytes(), 2 * 3 * 9 * 4 * 4 + 24);
    assert_eq!(f.nbytes(), qm.nbytes());
    let deq = qm.dequantized();
    for (k, (a, b)) in floats(&f).iter().zip(&deq).enumerate() {
        let ch = (k / 144) % 3;
        assert!((a - b).abs() <= scale[ch] * 0.5 * (1.0 + 1e-4), "{k}: {a} vs {b}");
    }
    let as_float = Sh { coeffs: ShCoeffs::Float(deq), ..qm.clone() };
    let (v, l) = (from_theta_phi(0.5, 1.0), from_theta_phi(0.9, 4.0));
    let (qa, qb) = (qm.query(v, l), as_float.query(v, l));
    for t in 0..2 {
        let (x, y) = (qm.eval(t, &qa), as_float.eval(t, &qb));
        for ch in 0..3 {
            assert!((x[ch] - y[ch]).abs() < 1e-4 * (1.0 + y[ch].abs()), "{x:?} vs {y:?}");
        }
    }
    qm.validate().unwrap();
    f.validate().unwrap();
}

#[test]
fn chunk_size_does_not_change_the_result() {
    let d = ubo81();
    let (noisy, _) = smooth_btf(30, 0.02, 12);
    let btf = BtfRef::new(5, 6, &d, &d, &noisy, None).unwrap();
    let mut o = opts(9, 9, true, true);
    let m = Monitor::new();
    let a = fit_sh(&btf, &o, &m).unwrap();
    assert_eq!(m.progress(), (30, 30));
    o.chunk_texels = 7;
    let b = fit_sh(&btf, &o, &Monitor::new()).unwrap();
    assert_eq!(a.coeffs, b.coeffs);
    assert_eq!((a.constrained_fraction, a.mean_lambda), (b.constrained_fraction, b.mean_lambda));
}

/// Error sums of the model over the present pairs, reconstructing each texel's whole ABRDF at
/// once as `Yv C Yl^T` in f64 (two GEMMs): an independent path to the per-pair `eval`.
fn gemm_error(sh: &Sh, btf: &BtfRef<'_>) -> btfrs_core::metrics::ErrorSums {
    let (kv, kl) = (sh.view_coeffs, sh.light_coeffs);
    let (nv, nl) = (btf.views.len(), btf.lights.len());
    let yv = basis_matrix(btf.views, kv);
    let yl = basis_matrix(btf.lights, kl);
    let c = sh.dequantized();
    let mut sums = btfrs_core::metrics::ErrorSums::default();
    let (mut g, mut f) = (vec![0.0f64; nv * kl], vec![0.0f64; nv * nl]);
    for t in 0..btf.texels() {
        for ch in 0..3 {
            let cc: Vec<f64> = c[(t * 3 + ch) * kv * kl..][..kv * kl].iter().map(|&x| x as f64).collect();
            gemm_into(&rows(&yv, nv, kv), &rows(&cc, kv, kl), &mut rows_mut(&mut g, nv, kl));
            gemm_into(&rows(&g, nv, kl), &rows_t(&yl, nl, kl), &mut rows_mut(&mut f, nv, nl));
            for v in 0..nv {
                for l in 0..nl {
                    if btf.has(v, l) {
                        sums.add(f[v * nl + l], btf.texel(t)[(v * nl + l) * 3 + ch] as f64);
                    }
                }
            }
        }
    }
    sums
}

#[test]
fn knit_reconstruction_improves_with_more_coefficients() {
    let btf = generate(&MaterialSpec::new(Preset::Knit, 16, 1), &Monitor::new()).unwrap();
    let r = btf.as_ref();
    let (sparse, _) = btfrs_core::split::split_pairs(81, 81, None, 0.97, 2).unwrap();
    let mut errs = Vec::new();
    for k in [9, 25] {
        let sh = fit_sh(&r, &opts(k, k, true, true), &Monitor::new()).unwrap();
        let e = gemm_error(&sh, &r).relative();
        let ls = fit_sh(&r, &opts(k, k, false, false), &Monitor::new()).unwrap();
        println!(
            "knit 16x16, {k} x {k}: relative reconstruction error CLS 8-bit {e:.4} (constrained {:.2}, {} bytes), \
             plain LS f32 {:.4}",
            sh.constrained_fraction,
            sh.nbytes(),
            gemm_error(&ls, &r).relative()
        );
        // The per-pair evaluation agrees with the whole-ABRDF reconstruction (on 3 % of the pairs).
        let on = BtfRef { mask: Some(&sparse), ..r };
        let (a, b) = (model_error(&sh, &on).unwrap().relative(), gemm_error(&sh, &on).relative());
        assert!((a - b).abs() < 1e-4 * b, "eval {a} vs GEMM reconstruction {b}");
        errs.push(e);
    }
    assert!(errs[1] < errs[0], "25 x 25 ({:.4}) should beat 9 x 9 ({:.4})", errs[1], errs[0]);
    assert!(errs[1] < 0.25, "25 x 25 error {:.4}", errs[1]);
}

#[test]
fn evaluation_is_the_double_sum() {
    let d = ubo81();
    let (noisy, _) = smooth_btf(2, 0.0, 13);
    let btf = BtfRef::new(1, 2, &d, &d, &noisy, None).unwrap();
    let sh = fit_sh(&btf, &opts(16, 9, true, false), &Monitor::new()).unwrap();
    let c = floats(&sh);
    let (v, l) = (from_theta_phi(0.4, 2.0), from_theta_phi(1.2, 5.5));
    let (mut yv, mut yl) = ([0.0f64; 16], [0.0f64; 9]);
    sh_basis(16, v, &mut yv);
    sh_basis(9, l, &mut yl);
    let img = evaluate_image(&sh, v, l).unwrap();
    for t in 0..2 {
        for ch in 0..3 {
            let mut s = 0.0f64;
            for i in 0..16 {
                for j in 0..9 {
                    s += c[(t * 3 + ch) * 144 + i * 9 + j] as f64 * yv[i] * yl[j];
                }
            }
            assert!((img[t * 3 + ch] as f64 - s).abs() < 1e-5 * (1.0 + s.abs()));
        }
    }
}

#[test]
fn bad_options_and_degenerate_inputs() {
    let d = ubo81();
    let data = vec![0.5f32; 81 * 81 * 3];
    let btf = BtfRef::new(1, 1, &d, &d, &data, None).unwrap();
    let m = Monitor::new();
    for (kv, kl, name) in [(25, 24, "light_coeffs"), (0, 25, "view_coeffs"), (81, 25, "view_coeffs")] {
        let e = fit_sh(&btf, &opts(kv, kl, true, true), &m).unwrap_err().to_string();
        assert!(e.starts_with(name) && e.contains("perfect square"), "{e}");
    }
    let e = fit_sh(&btf, &ShOptions { chunk_texels: 0, ..Default::default() }, &m).unwrap_err().to_string();
    assert!(e.starts_with("chunk_texels"), "{e}");
    // 5 views x 5 lights = 25 pairs for 9 x 9 = 81 coefficients: LS is impossible, CLS is fine.
    let few: Vec<[f64; 3]> = d[..5].to_vec();
    let data = vec![0.5f32; 2 * 25 * 3];
    let btf = BtfRef::new(1, 2, &few, &few, &data, None).unwrap();
    let e = fit_sh(&btf, &opts(9, 9, false, false), &m).unwrap_err();
    assert!(matches!(e, Error::Degenerate(_)), "{e}");
    let e = e.to_string();
    assert!(e.contains("81 coefficients") && e.contains("got 25"), "{e}");
    let sh = fit_sh(&btf, &opts(9, 9, true, false), &m).unwrap();
    assert!(floats(&sh).iter().all(|x| x.is_finite()));
    let err = model_error(&sh, &btf).unwrap().relative();
    assert!(err < 0.5, "a constant is well within reach: {err}");
    // Rank deficiency without a count problem: 36 x 25 on UBO 81 is beyond f64 for plain LS.
    let full = vec![0.5f32; 81 * 81 * 3];
    let btf = BtfRef::new(1, 1, &d, &d, &full, None).unwrap();
    let e = fit_sh(&btf, &opts(36, 25, false, false), &m).unwrap_err().to_string();
    assert!(e.contains("determine only"), "{e}");
    // All-black texels: zero coefficients, no NaN, lambda 0.
    let black = vec![0.0f32; 2 * 81 * 81 * 3];
    let btf = BtfRef::new(1, 2, &d, &d, &black, None).unwrap();
    for cls in [true, false] {
        let sh = fit_sh(&btf, &opts(9, 9, cls, false), &m).unwrap();
        assert!(floats(&sh).iter().all(|&x| x == 0.0));
        assert_eq!(sh.constrained_fraction, 0.0);
        let q = fit_sh(&btf, &opts(9, 9, cls, true), &m).unwrap();
        assert!(q.dequantized().iter().all(|&x| x == 0.0));
        q.validate().unwrap();
    }
    // Cancellation stops at the first chunk boundary.
    let m = Monitor::new();
    m.cancel();
    assert!(matches!(fit_sh(&btf, &ShOptions::default(), &m), Err(Error::Interrupted)));
    // Validation of loaded models.
    let mut bad = fit_sh(&btf, &opts(9, 9, true, false), &Monitor::new()).unwrap();
    bad.light_coeffs = 16;
    assert!(bad.validate().unwrap_err().to_string().starts_with("coeffs"));
}
