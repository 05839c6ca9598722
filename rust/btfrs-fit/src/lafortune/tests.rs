#![allow(clippy::needless_range_loop)] // index loops mirror the formulas being checked
use super::kernels::{self, Geometry, Layout, Work, CH, MAXM};
use super::*;
use crate::model::model_error;
use btfrs_core::directions::ubo81;
use btfrs_core::materials::{generate, MaterialSpec, Preset};
use btfrs_core::rng::Rng;

/// The model at one sample in plain f64 with the standard library's `powf`: the reference that
/// the fast passes and the fit are checked against. `p = [kd, (Cx, Cy, Cz, n) x lobes]`.
pub(crate) fn reference(p: &[f64], lobes: usize, v: [f64; 3], l: [f64; 3]) -> f64 {
    let mut sum = p[0];
    for k in 0..lobes {
        let q = &p[1 + 4 * k..5 + 4 * k];
        let s = q[0] * l[0] * v[0] + q[1] * l[1] * v[1] + q[2] * l[2] * v[2];
        if s > 0.0 {
            sum += s.powf(q[3]);
        }
    }
    l[2].max(0.0) * sum
}

/// Random but well-conditioned lobes: a specular-like lobe and a broader retro or normal lobe.
pub(crate) fn random_params(rng: &mut Rng, lobes: usize, diffuse: bool) -> Vec<f64> {
    let mut p = vec![0.0; 1 + 4 * lobes];
    p[0] = if diffuse { 0.2 + 0.5 * rng.next_f64() } else { 0.0 };
    for k in 0..lobes {
        let q = &mut p[1 + 4 * k..5 + 4 * k];
        let (n, sign) = if k == 0 { (6.0 + 20.0 * rng.next_f64(), -1.0) } else { (2.0 + 3.0 * rng.next_f64(), 1.0) };
        // Peak amplitude a in [0.5, 2] goes into C as a^(1/n).
        let amp = (0.5 + 1.5 * rng.next_f64()).powf(1.0 / n);
        q[0] = sign * amp * (0.8 + 0.3 * rng.next_f64());
        q[1] = sign * amp * (0.8 + 0.3 * rng.next_f64());
        q[2] = amp * (0.9 + 0.2 * rng.next_f64());
        q[3] = n;
    }
    p
}

/// A BTF generated from the model: per texel its own parameters (and base colour for Lum); kd = 0
/// unless `diffuse`.
/// Returns (data, true params per fit, base colour per texel).
fn model_btf(
    texels: usize,
    views: &[[f64; 3]],
    lights: &[[f64; 3]],
    kind: LafortuneKind,
    lobes: usize,
    diffuse: bool,
    seed: u64,
) -> (Vec<f32>, Vec<Vec<f64>>, Vec<[f64; 3]>) {
    let mut rng = Rng::new(seed);
    let (nv, nl) = (views.len(), lights.len());
    let mut data = vec![0.0f32; texels * nv * nl * 3];
    let mut truth = Vec::new();
    let mut bases = Vec::new();
    for t in 0..texels {
        let fits: Vec<Vec<f64>> = match kind {
            LafortuneKind::Lum => vec![random_params(&mut rng, lobes, diffuse)],
            LafortuneKind::Rgb => (0..3).map(|_| random_params(&mut rng, lobes, diffuse)).collect(),
        };
        let base = [0.6 + 0.8 * rng.next_f64(), 0.6 + 0.8 * rng.next_f64(), 0.6 + 0.8 * rng.next_f64()];
        for v in 0..nv {
            for l in 0..nl {
                let o = ((t * nv + v) * nl + l) * 3;
                for c in 0..3 {
                    data[o + c] = match kind {
                        LafortuneKind::Lum => base[c] * reference(&fits[0], lobes, views[v], lights[l]),
                        LafortuneKind::Rgb => reference(&fits[c], lobes, views[v], lights[l]),
                    } as f32;
                }
            }
        }
        truth.extend(fits);
        bases.push(base);
    }
    (data, truth, bases)
}

/// Largest parameter error of `got` against `want` over the best matching of lobes (the lobe
/// order is arbitrary): (kd relative error, worst C error relative to |C|, worst n relative error).
fn param_errors(got: &[f32], want: &[f64], lobes: usize) -> (f64, f64, f64) {
    let kd = (got[0] as f64 - want[0]).abs() / want[0].abs().max(1e-3);
    let perms: Vec<Vec<usize>> = if lobes == 1 { vec![vec![0]] } else { vec![vec![0, 1], vec![1, 0]] };
    let mut best = (f64::INFINITY, f64::INFINITY);
    for perm in perms {
        let (mut ec, mut en) = (0.0f64, 0.0f64);
        for (k, &j) in perm.iter().enumerate() {
            let g = &got[1 + 4 * j..5 + 4 * j];
            let w = &want[1 + 4 * k..5 + 4 * k];
            let norm = (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt();
            for i in 0..3 {
                ec = ec.max((g[i] as f64 - w[i]).abs() / norm);
            }
            en = en.max((g[3] as f64 - w[3]).abs() / w[3]);
        }
        if ec.max(en) < best.0.max(best.1) {
            best = (ec, en);
        }
    }
    (kd, best.0, best.1)
}

/// Largest (exp relative, ln absolute-or-relative) error of the fast functions against the
/// standard library over the ranges the fit uses.
fn fast_math_errors<const F: bool>() -> (f64, f64) {
    let mut worst_exp = 0.0f64;
    let mut worst_ln = 0.0f64;
    let mut rng = Rng::new(9);
    for i in 0..200_000 {
        // exp over the whole clamped range, with many points near 0.
        let x = if i % 2 == 0 { -700.0 + 1400.0 * rng.next_f64() } else { 4.0 * (rng.next_f64() - 0.5) };
        let want = x.exp();
        worst_exp = worst_exp.max((kernels::exp_fast::<F>(x) - want).abs() / want);
        // ln over 1e-300..1e300, and densely around 1 where the absolute error matters.
        let y = if i % 2 == 0 { 10f64.powf(-300.0 + 600.0 * rng.next_f64()) } else { 0.5 + rng.next_f64() };
        let want = y.ln();
        worst_ln = worst_ln.max((kernels::ln_fast::<F>(y) - want).abs() / want.abs().max(1.0));
    }
    assert_eq!(kernels::ln_fast::<F>(1.0), 0.0);
    assert_eq!(kernels::exp_fast::<F>(0.0), 1.0);
    assert!(kernels::exp_fast::<F>(1e6).is_finite() && kernels::exp_fast::<F>(-1e6) >= 0.0);
    (worst_exp, worst_ln)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn fast_math_errors_fma() -> (f64, f64) {
    fast_math_errors::<true>()
}

#[test]
fn fast_exp_and_ln_match_the_standard_library() {
    let mut variants = vec![("plain", fast_math_errors::<false>())];
    #[cfg(target_arch = "x86_64")]
    if kernels::have_fma() {
        // SAFETY: AVX2 and FMA are available (checked just above).
        variants.push(("fma", unsafe { fast_math_errors_fma() }));
    }
    for (name, (e, l)) in variants {
        assert!(e < 1e-15, "{name}: exp relative error {e:e}");
        assert!(l < 1e-15, "{name}: ln error {l:e}");
    }
}

/// Model parameters (exponents n) from a theta with kd (exponents ln n).
fn to_params(th: &[f64]) -> Vec<f64> {
    th.iter().enumerate().map(|(i, &x)| if i > 0 && i % 4 == 0 { x.exp() } else { x }).collect()
}

/// (view, light) direction pairs.
type Pairs = Vec<([f64; 3], [f64; 3])>;

/// The UBO 81 x 81 geometry and theta of a 2-lobe fit with kd (exponents away from 1 so the model
/// is twice differentiable where a lobe's cosine crosses 0 and central differences are accurate).
fn jacobian_setup() -> (Pairs, Geometry, Vec<f64>, Vec<f64>) {
    let d = ubo81();
    let pairs: Vec<([f64; 3], [f64; 3])> = d.iter().flat_map(|&v| d.iter().map(move |&l| (v, l))).collect();
    let geo = Geometry::new(pairs.iter().copied());
    // theta holds ln n: exponents 7.3 and 3.7.
    let th = vec![0.3, -0.9, -1.1, 1.05, 7.3f64.ln(), 0.8, 0.6, 0.9, 3.7f64.ln()];
    let mut rng = Rng::new(4);
    let y: Vec<f64> =
        pairs.iter().map(|&(v, l)| reference(&to_params(&th), 2, v, l) * (0.8 + 0.4 * rng.next_f64())).collect();
    (pairs, geo, th, y)
}

#[test]
fn analytic_jacobian_matches_central_differences() {
    let (pairs, geo, th, y) = jacobian_setup();
    assert_eq!(geo.n, 6561);
    assert_eq!(geo.npad() % CH, 0);
    for diffuse in [true, false] {
        let lay = Layout { diffuse, lobes: 2 };
        let m = lay.m();
        // theta in the layout (without kd when not diffuse); full params for the reference.
        let th_l: Vec<f64> = if diffuse { th.clone() } else { th[1..].to_vec() };
        let full = |t: &[f64]| -> Vec<f64> { to_params(&if diffuse { t.to_vec() } else { [&[0.0], t].concat() }) };
        // Central differences of the reference model, per sample and parameter.
        let mut jfd = vec![vec![0.0; m]; pairs.len()];
        for q in 0..m {
            let h = 1e-5 * th_l[q].abs().max(1.0);
            let (mut tp, mut tm) = (th_l.clone(), th_l.clone());
            tp[q] += h;
            tm[q] -= h;
            let (fp, fm) = (full(&tp), full(&tm));
            for (p, &(v, l)) in pairs.iter().enumerate() {
                jfd[p][q] = (reference(&fp, 2, v, l) - reference(&fm, 2, v, l)) / (2.0 * h);
            }
        }
        let r: Vec<f64> = pairs.iter().zip(&y).map(|(&(v, l), &yy)| reference(&full(&th_l), 2, v, l) - yy).collect();
        let c_ref: f64 = r.iter().map(|x| x * x).sum();
        // Both kernels: the one this CPU dispatches to (AVX2 + FMA where available) and the
        // portable one every other CPU runs.
        for portable in [false, true] {
            let mut w = Work::new(geo.npad(), 2);
            w.y[..geo.n].copy_from_slice(&y);
            let (mut jtj, mut jtr) = (vec![0.0; MAXM * MAXM], vec![0.0; MAXM]);
            let c = if portable {
                let c = kernels::cost_impl::<false>(&geo, lay, &th_l, &mut w);
                kernels::normal_equations_impl::<false, false>(&geo, lay, &th_l, &mut w, &mut jtj, &mut jtr, None);
                c
            } else {
                let c = kernels::cost(&geo, lay, &th_l, &mut w);
                kernels::normal_equations(&geo, lay, &th_l, &mut w, &mut jtj, &mut jtr);
                c
            };
            let what = format!("diffuse {diffuse}, portable {portable}");
            assert!((c - c_ref).abs() < 1e-12 * c_ref, "{what}: cost {c} vs reference {c_ref}");
            let scale = (0..m).map(|q| jtj[q * m + q]).fold(0.0f64, f64::max);
            for q in 0..m {
                let want: f64 = (0..pairs.len()).map(|p| jfd[p][q] * r[p]).sum();
                assert!(
                    (jtr[q] - want).abs() <= 1e-5 * (want.abs() + 1e-6 * scale.sqrt() * c.sqrt()),
                    "{what}: J^T r [{q}]: {} vs {want}",
                    jtr[q]
                );
                for u in 0..m {
                    let want: f64 = (0..pairs.len()).map(|p| jfd[p][q] * jfd[p][u]).sum();
                    let got = jtj[q * m + u];
                    assert!(
                        (got - want).abs() <= 1e-5 * (want.abs() + 1e-6 * scale),
                        "{what}: J^T J [{q}, {u}]: {got} vs {want}"
                    );
                }
            }
        }
    }
}

/// The second-order term `S = sum_i r_i d^2 v_i / d theta^2` of the Newton steps against central
/// differences of the (separately tested) analytic gradient: `d(J^T r)/d theta = J^T J + S`.
/// Portable, AVX2 + FMA (where the CPU has them) and the dispatched kernel (AVX-512 here).
#[test]
fn second_order_term_matches_differences_of_the_gradient() {
    let (_, geo, th, y) = jacobian_setup();
    for diffuse in [true, false] {
        let lay = Layout { diffuse, lobes: 2 };
        let m = lay.m();
        let th_l: Vec<f64> = if diffuse { th.clone() } else { th[1..].to_vec() };
        let mut w = Work::new(geo.npad(), 2);
        w.y[..geo.n].copy_from_slice(&y);
        let grad = |t: &[f64], w: &mut Work| {
            let (mut jtj, mut jtr) = (vec![0.0; MAXM * MAXM], vec![0.0; MAXM]);
            kernels::cost_impl::<false>(&geo, lay, t, w);
            kernels::normal_equations_impl::<false, false>(&geo, lay, t, w, &mut jtj, &mut jtr, None);
            (jtj, jtr)
        };
        let (jtj, _) = grad(&th_l, &mut w);
        let mut want = vec![0.0; m * m];
        for u in 0..m {
            let h = 1e-5 * th_l[u].abs().max(1.0);
            let (mut tp, mut tm) = (th_l.clone(), th_l.clone());
            tp[u] += h;
            tm[u] -= h;
            let (gp, gm) = (grad(&tp, &mut w).1, grad(&tm, &mut w).1);
            for q in 0..m {
                want[q * m + u] = (gp[q] - gm[q]) / (2.0 * h) - jtj[q * m + u];
            }
        }
        let scale = (0..m).map(|q| jtj[q * m + q]).fold(0.0f64, f64::max);
        let mut kinds = vec!["portable", "dispatched"];
        #[cfg(target_arch = "x86_64")]
        if kernels::have_fma() {
            kinds.push("avx2");
        }
        for kind in kinds {
            let (mut jtj2, mut jtr2, mut sec) = (vec![0.0; MAXM * MAXM], vec![0.0; MAXM], vec![0.0; MAXM * MAXM]);
            match kind {
                "portable" => {
                    kernels::cost_impl::<false>(&geo, lay, &th_l, &mut w);
                    kernels::normal_equations_impl::<false, false>(
                        &geo,
                        lay,
                        &th_l,
                        &mut w,
                        &mut jtj2,
                        &mut jtr2,
                        Some(&mut sec),
                    );
                }
                "avx2" => {
                    kernels::cost_impl::<true>(&geo, lay, &th_l, &mut w);
                    kernels::normal_equations_impl::<true, false>(
                        &geo,
                        lay,
                        &th_l,
                        &mut w,
                        &mut jtj2,
                        &mut jtr2,
                        Some(&mut sec),
                    );
                }
                _ => {
                    kernels::cost(&geo, lay, &th_l, &mut w);
                    kernels::normal_equations_with(&geo, lay, &th_l, &mut w, &mut jtj2, &mut jtr2, Some(&mut sec));
                }
            }
            for q in 0..m {
                for u in 0..m {
                    let (got, want) = (sec[q * m + u], want[q * m + u]);
                    assert!(
                        (got - want).abs() <= 1e-5 * (want.abs() + 1e-4 * scale),
                        "diffuse {diffuse}, {kind}: S [{q}, {u}]: {got} vs {want}"
                    );
                }
                // The blocks between lobes and with kd are exactly zero (the model is a sum).
            }
            assert!((0..m).all(|q| (0..m).all(|u| jtj2[q * m + u] == jtj2[u * m + q])), "{kind}: J^T J not symmetric");
            // Every kernel's J^T J (AVX2's included, which the central differences above do not
            // see) against the portable one's, which those differences check: the same sums in
            // other orders.
            for (q, (&got, &want)) in jtj2[..m * m].iter().zip(&jtj[..m * m]).enumerate() {
                assert!((got - want).abs() <= 1e-12 * scale, "{kind}: J^T J [{}, {}]: {got} vs {want}", q / m, q % m);
            }
        }
    }
}

#[test]
fn recovers_lum_model_data() {
    let d = ubo81();
    for (lobes, diffuse) in [(1, true), (2, true), (2, false)] {
        let seed = 10 + lobes as u64 + u64::from(diffuse);
        let (data, truth, bases) = model_btf(4, &d, &d, LafortuneKind::Lum, lobes, diffuse, seed);
        let btf = BtfRef::new(2, 2, &d, &d, &data, None).unwrap();
        let opts = LafortuneOptions { lobes, diffuse, ..Default::default() };
        let m = fit_lafortune(&btf, &opts, &Monitor::new()).unwrap();
        m.validate().unwrap();
        let e = model_error(&m, &btf).unwrap();
        assert!(e.relative() < 1e-5, "{lobes} lobes: relative error {}", e.relative());
        assert_eq!(m.report.converged, 4, "{:?}", m.report);
        // The fitted luminance is mean(base) times the true model, and the fitted base colour is
        // base / mean(base) (its channels sum to 3): kd scales by mean(base), C by its 1/n-th power.
        let rgb = m.rgb.as_ref().unwrap();
        let pp = m.params_per_fit();
        for t in 0..4 {
            let mb = bases[t].iter().sum::<f64>() / 3.0;
            for c in 0..3 {
                assert!((rgb[3 * t + c] as f64 - bases[t][c] / mb).abs() < 1e-5, "base {:?}", &rgb[3 * t..]);
            }
            let mut want = truth[t].clone();
            want[0] *= mb;
            for k in 0..lobes {
                let f = mb.powf(1.0 / want[4 + 4 * k]);
                for i in 1..4 {
                    want[4 * k + i] *= f;
                }
            }
            let (ekd, ec, en) = param_errors(&m.params[t * pp..(t + 1) * pp], &want, lobes);
            println!(
                "Lum {lobes} lobes (diffuse {diffuse}), texel {t}: kd {ekd:.1e} C {ec:.1e} n {en:.1e}, rel. error {:.1e}",
                e.relative()
            );
            assert!(ekd < 1e-4 && ec < 1e-4 && en < 1e-4, "texel {t}: kd {ekd:e} C {ec:e} n {en:e}");
        }
    }
}

#[test]
fn recovers_rgb_model_data() {
    let d = ubo81();
    for lobes in [1, 2] {
        let (data, truth, _) = model_btf(2, &d, &d, LafortuneKind::Rgb, lobes, true, 20 + lobes as u64);
        let btf = BtfRef::new(2, 1, &d, &d, &data, None).unwrap();
        let opts = LafortuneOptions { kind: LafortuneKind::Rgb, lobes, ..Default::default() };
        let m = fit_lafortune(&btf, &opts, &Monitor::new()).unwrap();
        m.validate().unwrap();
        assert!(m.rgb.is_none() && m.status.len() == 6 && m.params.len() == 6 * (1 + 4 * lobes));
        let e = model_error(&m, &btf).unwrap();
        assert!(e.relative() < 1e-5, "{lobes} lobes: relative error {}", e.relative());
        assert_eq!(m.report.fits, 6);
        assert_eq!(m.report.converged, 6, "{:?}", m.report);
        assert!(m.report.rms_residual < 1e-3, "{:?}", m.report);
        let pp = m.params_per_fit();
        for f in 0..6 {
            let (ekd, ec, en) = param_errors(&m.params[f * pp..(f + 1) * pp], &truth[f], lobes);
            println!(
                "Rgb {lobes} lobes, fit {f}: kd {ekd:.1e} C {ec:.1e} n {en:.1e}, relative error {:.1e}",
                e.relative()
            );
            assert!(ekd < 1e-4 && ec < 1e-4 && en < 1e-4, "fit {f}: kd {ekd:e} C {ec:e} n {en:e}");
        }
    }
}

#[test]
fn held_out_pairs_do_not_influence_the_fit() {
    let d = ubo81();
    let (mut data, _, _) = model_btf(2, &d, &d, LafortuneKind::Lum, 2, true, 30);
    // Noise, so that the fit is not exact and any leak of the held-out values would show.
    let mut rng = Rng::new(31);
    data.iter_mut().for_each(|x| *x *= 0.8 + 0.4 * rng.next_f64() as f32);
    let (train, test) = btfrs_core::split::split_pairs(81, 81, None, 0.2, 0).unwrap();
    for densify in [0, 3] {
        for kind in [LafortuneKind::Lum, LafortuneKind::Rgb] {
            let opts = LafortuneOptions { kind, densify, ..Default::default() };
            let fit = |data: &[f32]| {
                fit_lafortune(&BtfRef::new(2, 1, &d, &d, data, Some(&train)).unwrap(), &opts, &Monitor::new()).unwrap()
            };
            let a = fit(&data);
            let mut garbage = data.clone();
            for (i, x) in garbage.iter_mut().enumerate() {
                if test[(i / 3) % (81 * 81)] {
                    *x = 1e6;
                }
            }
            let b = fit(&garbage);
            assert_eq!(a.params, b.params, "{kind:?}, densify {densify}");
            assert_eq!(a.rgb, b.rgb);
            assert_eq!(a.report, b.report);
            // And the held-out values do matter without the mask (the check above is not vacuous).
            let c = fit_lafortune(&BtfRef::new(2, 1, &d, &d, &garbage, None).unwrap(), &opts, &Monitor::new()).unwrap();
            assert_ne!(a.params, c.params);
        }
    }
}

/// The closed-form diffuse-only fit `kd = sum y lz / sum lz^2` of one channel (None = luminance)
/// of a texel over all pairs, in f64.
fn diffuse_only(texel: &[f32], lights: &[[f64; 3]], nv: usize, channel: Option<usize>) -> f64 {
    let nl = lights.len();
    let (mut num, mut den) = (0.0, 0.0);
    for i in 0..nv * nl {
        let lz = lights[i % nl][2].max(0.0);
        let y = match channel {
            Some(c) => texel[3 * i + c] as f64,
            None => (texel[3 * i] as f64 + texel[3 * i + 1] as f64 + texel[3 * i + 2] as f64) / 3.0,
        };
        num += y * lz;
        den += lz * lz;
    }
    (num / den).max(0.0)
}

#[test]
fn hard_texels_fall_back_with_finite_params() {
    let d = ubo81();
    let n = 81 * 81 * 3;
    let nt = 8;
    let (mut data, _, _) = model_btf(nt, &d, &d, LafortuneKind::Lum, 2, true, 40);
    let mut rng = Rng::new(41);
    // 0: black. 1: constant (saturated) 1.0. 2: white noise. 3: huge values. 4: tiny values.
    // 5: negative values. 6 and 7: model data, left as is. (An infinity is refused before any
    // fit: the pass checks each texel, SCANS_VALUES, with the error of check_finite.)
    data[..n].iter_mut().for_each(|x| *x = 0.0);
    data[n..2 * n].iter_mut().for_each(|x| *x = 1.0);
    data[2 * n..3 * n].iter_mut().for_each(|x| *x = rng.next_f64() as f32);
    data[3 * n..4 * n].iter_mut().for_each(|x| *x *= 1e30);
    data[4 * n..5 * n].iter_mut().for_each(|x| *x *= 1e-30);
    data[5 * n..6 * n].iter_mut().for_each(|x| *x = -*x);
    let mut inf = data.clone();
    inf[6 * n + 100] = f32::INFINITY;
    let e = fit_lafortune(&BtfRef::new(nt, 1, &d, &d, &inf, None).unwrap(), &Default::default(), &Monitor::new());
    let want = btfrs_core::btf::check_finite("data", &inf).unwrap_err().to_string();
    assert_eq!(e.unwrap_err().to_string(), want);
    let btf = BtfRef::new(nt, 1, &d, &d, &data, None).unwrap();
    for (kind, max_iter) in
        [(LafortuneKind::Lum, 60), (LafortuneKind::Lum, 1), (LafortuneKind::Rgb, 60), (LafortuneKind::Rgb, 1)]
    {
        let opts = LafortuneOptions { kind, max_iter, ..Default::default() };
        let m = fit_lafortune(&btf, &opts, &Monitor::new()).unwrap();
        m.validate().unwrap();
        let r = m.report;
        assert_eq!(r.converged + r.fell_back + r.failed, r.fits, "{r:?}");
        assert_eq!(r.fits, m.status.len());
        assert!(r.rms_residual.is_finite() && r.mean_iterations.is_finite(), "{r:?}");
        let nf = m.status.len() / nt;
        let pp = m.params_per_fit();
        // Black: zero params, converged.
        assert!(m.status[..nf].iter().all(|&s| s == 0));
        assert!(m.params[..nf * pp]
            .iter()
            .enumerate()
            .all(|(i, &x)| x == if (i % pp).is_multiple_of(4) && i % pp > 0 { 1.0 } else { 0.0 }));
        // Negative data: the best non-negative model is 0.
        for f in 5 * nf..6 * nf {
            assert!(m.params[f * pp] == 0.0, "kd {}", m.params[f * pp]);
        }
        // Every failed fit is exactly the closed-form diffuse-only fit, lobes zero.
        for (f, &s) in m.status.iter().enumerate() {
            if s != 2 {
                continue;
            }
            let p = &m.params[f * pp..(f + 1) * pp];
            let ch = if nf == 3 { Some(f % 3) } else { None };
            let kd = diffuse_only(btf.texel(f / nf), &d, 81, ch);
            assert!((p[0] as f64 - kd).abs() <= 1e-5 * kd, "fit {f}: kd {} vs {kd}", p[0]);
            assert!((0..m.lobes).all(|k| p[1 + 4 * k..4 + 4 * k] == [0.0; 3] && p[4 + 4 * k] == 1.0));
        }
        if max_iter == 1 {
            // One step is not enough for any LM run on the noisy texel.
            assert!(m.status[2 * nf..3 * nf].iter().all(|&s| s == 2), "{:?}", m.status);
        } else {
            // The model texel converges.
            assert!(m.status[7 * nf..].iter().all(|&s| s == 0), "{:?}", m.status);
        }
    }
}

#[test]
fn densify_adds_interpolated_samples() {
    let d = ubo81();
    // 13 lights spread over the hemisphere: the pole and 4 directions on each of the 30, 60 and
    // 75 degree rings.
    let idx = [0, 7, 10, 13, 16, 37, 42, 47, 52, 57, 63, 69, 75];
    let lights: Vec<[f64; 3]> = idx.iter().map(|&i| d[i]).collect();
    assert_eq!(lights.len(), 13);
    // Broad lobes (exponents 2 to 4), which interpolation between 13 lights can follow.
    let truth: Vec<Vec<f64>> = (0..4)
        .map(|t| {
            let f = 1.0 + 0.1 * t as f64;
            vec![0.3 * f, -0.8 * f, -0.7 * f, 0.9, 2.0 + 0.6 * t as f64]
        })
        .collect();
    let mut data = vec![0.0f32; 4 * 81 * 13 * 3];
    for t in 0..4 {
        for v in 0..81 {
            for l in 0..13 {
                let x = reference(&truth[t], 1, d[v], lights[l]) as f32;
                data[((t * 81 + v) * 13 + l) * 3..][..3].copy_from_slice(&[x, 0.5 * x, 0.25 * x]);
            }
        }
    }
    let btf = BtfRef::new(2, 2, &d, &lights, &data, None).unwrap();
    for densify in [0, 4] {
        let opts = LafortuneOptions { lobes: 1, densify, ..Default::default() };
        let lay = Layout { diffuse: true, lobes: 1 };
        let ctx = Context::new(&btf, &opts, lay);
        assert_eq!(ctx.geo.n, 81 * 13 + densify.pow(4));
        let m = fit_lafortune(&btf, &opts, &Monitor::new()).unwrap();
        m.validate().unwrap();
        let e = model_error(&m, &btf).unwrap();
        println!("densify {densify}: relative error {:.2e}, {:?}", e.relative(), m.report);
        // Interpolated samples of a lobe are not exactly the lobe, so densification trades a
        // little of the exact fit for a smoother one; the model is still recovered closely.
        assert!(e.relative() < if densify == 0 { 1e-3 } else { 3e-2 }, "densify {densify}: {}", e.relative());
        // Parameters, up to the base colour's mean (7/12): kd and the exponent.
        for t in 0..4 {
            let p = &m.params[5 * t..5 * t + 5];
            let (kd, n) = (p[0] as f64 / (7.0 / 12.0), p[4] as f64);
            println!("  texel {t}: kd {kd:.4} (true {:.4}), n {n:.3} (true {:.3})", truth[t][0], truth[t][4]);
            let tol = if densify == 0 { 1e-3 } else { 0.15 };
            assert!((kd - truth[t][0]).abs() < tol * truth[t][0] && (n - truth[t][4]).abs() < tol * truth[t][4]);
        }
    }
    // The interpolation weights only use present pairs and sum to 1.
    let opts = LafortuneOptions { densify: 2, ..Default::default() };
    let ctx = Context::new(&btf, &opts, Layout { diffuse: true, lobes: 2 });
    for k in 0..16 {
        let (s, e) = (ctx.extra.start[k], ctx.extra.start[k + 1]);
        assert!((ctx.extra.w[s..e].iter().sum::<f64>() - 1.0).abs() < 1e-12);
    }
}

#[test]
fn bad_arguments_name_the_argument() {
    let d = ubo81();
    let data = vec![0.5f32; 81 * 81 * 3];
    let btf = BtfRef::new(1, 1, &d, &d, &data, None).unwrap();
    let bad = |opts: LafortuneOptions| fit_lafortune(&btf, &opts, &Monitor::new()).unwrap_err();
    for (opts, name) in [
        (LafortuneOptions { lobes: 0, ..Default::default() }, "lobes"),
        (LafortuneOptions { lobes: 8, ..Default::default() }, "lobes"),
        (LafortuneOptions { kind: LafortuneKind::Rgb, lobes: 4, ..Default::default() }, "lobes"),
        (LafortuneOptions { max_iter: 0, ..Default::default() }, "max_iter"),
        (LafortuneOptions { densify: 33, ..Default::default() }, "densify"),
    ] {
        match bad(opts) {
            Error::InvalidArgument { name: n, msg, .. } => {
                assert_eq!(n, name);
                assert!(msg.contains("expected"), "{msg}");
            }
            e => panic!("{e}"),
        }
    }
    assert!(bad(LafortuneOptions { lobes: 8, ..Default::default() }).to_string().contains("1 to 7"));
    assert!(bad(LafortuneOptions { kind: LafortuneKind::Rgb, lobes: 4, ..Default::default() })
        .to_string()
        .contains("1 to 3"));
    // 8 present pairs cannot determine 9 parameters.
    let mut mask = vec![false; 81 * 81];
    mask[..8].iter_mut().for_each(|m| *m = true);
    let btf = BtfRef::new(1, 1, &d, &d, &data, Some(&mask)).unwrap();
    let e = fit_lafortune(&btf, &LafortuneOptions::default(), &Monitor::new()).unwrap_err();
    assert!(matches!(e, Error::Degenerate(_)) && e.to_string().contains("8 present"), "{e}");
    mask[8] = true;
    let btf = BtfRef::new(1, 1, &d, &d, &data, Some(&mask)).unwrap();
    assert!(fit_lafortune(&btf, &LafortuneOptions::default(), &Monitor::new()).is_ok());
    // Cancellation.
    let mon = Monitor::new();
    mon.cancel();
    assert!(matches!(fit_lafortune(&btf, &LafortuneOptions::default(), &mon), Err(Error::Interrupted)));
}

#[test]
fn validate_checks_loaded_models() {
    let m = Lafortune {
        kind: LafortuneKind::Rgb,
        height: 1,
        width: 2,
        lobes: 1,
        params: [0.1, -0.5, -0.5, 0.6, 8.0].repeat(6),
        rgb: None,
        status: Vec::new(),
        report: FitReport::default(),
    };
    m.validate().unwrap();
    assert_eq!(m.nbytes(), 4 * 30);
    assert_eq!(m.params_per_fit(), 5);
    // A query at the mirror direction of the view peaks: lz (kd + (C . p)^n).
    let v = btfrs_core::directions::from_theta_phi(0.5, 0.3);
    let l = [-v[0], -v[1], v[2]];
    let px = crate::model::evaluate_image(&m, v, l).unwrap();
    let s = 0.5 * (v[0] * v[0] + v[1] * v[1]) + 0.6 * v[2] * v[2];
    assert!((px[0] as f64 - v[2] * (0.1 + s.powi(8))).abs() < 1e-6);
    let mut bad = m.clone();
    bad.params[4] = 0.5;
    assert!(bad.validate().unwrap_err().to_string().contains("exponent"));
    let mut bad = m.clone();
    bad.params[2] = f32::NAN;
    assert!(bad.validate().unwrap_err().to_string().contains("not finite"));
    let mut bad = m.clone();
    bad.params.pop();
    assert!(bad.validate().is_err());
    let mut bad = m.clone();
    bad.rgb = Some(vec![1.0; 6]);
    assert!(bad.validate().unwrap_err().to_string().starts_with("rgb"));
    let mut bad = m;
    bad.status = vec![0, 3, 0, 0, 0, 0];
    assert!(bad.validate().is_err());
}

#[test]
fn beats_the_diffuse_fit_on_knit() {
    let btf = generate(&MaterialSpec::new(Preset::Knit, 16, 1), &Monitor::new()).unwrap();
    let r = btf.as_ref();
    let m = fit_lafortune(&r, &LafortuneOptions::default(), &Monitor::new()).unwrap();
    m.validate().unwrap();
    let e = model_error(&m, &r).unwrap();
    // Diffuse-only per channel, kd_c = sum x_c lz / sum lz^2, evaluated by brute force.
    let mut diffuse = btfrs_core::metrics::ErrorSums::default();
    for t in 0..r.texels() {
        let x = r.texel(t);
        let kd: Vec<f64> = (0..3).map(|c| diffuse_only(x, r.lights, 81, Some(c))).collect();
        for i in 0..81 * 81 {
            let lz = r.lights[i % 81][2].max(0.0);
            for c in 0..3 {
                diffuse.add(kd[c] * lz, x[3 * i + c] as f64);
            }
        }
    }
    println!(
        "knit 16x16 Lum 2 lobes: relative error {:.4} (diffuse only {:.4}), {:?}",
        e.relative(),
        diffuse.relative(),
        m.report
    );
    assert!(e.relative() < 0.95 * diffuse.relative(), "{} vs diffuse {}", e.relative(), diffuse.relative());
    assert!(m.report.converged > m.report.fits / 2, "{:?}", m.report);
}

/// Where the time of a Lafortune-Lum 2 fit goes, on the bench's window (knit 64^2, train split,
/// row 32, the first 64 texels), one thread: the shared setup, per texel the gather, the
/// initialisation and the LM runs, and one cost and one normal-equations pass on their own.
/// `cargo test --release -p btfrs-fit lafortune_profile -- --ignored --nocapture`.
#[test]
#[ignore]
fn lafortune_profile() {
    /// This thread's CPU time (the machine is shared: wall time would count the other jobs).
    #[derive(Clone, Copy)]
    struct Instant(f64);
    impl Instant {
        fn now() -> Self {
            #[repr(C)]
            struct Ts {
                s: i64,
                ns: i64,
            }
            unsafe extern "C" {
                fn clock_gettime(clk: i32, ts: *mut Ts) -> i32;
            }
            let mut t = Ts { s: 0, ns: 0 };
            // SAFETY: a valid pointer to a timespec; 3 is CLOCK_THREAD_CPUTIME_ID on Linux.
            unsafe { clock_gettime(3, &mut t) };
            Instant(t.s as f64 + t.ns as f64 * 1e-9)
        }
        fn elapsed(&self) -> std::time::Duration {
            std::time::Duration::from_secs_f64(Instant::now().0 - self.0)
        }
    }
    let size = 64;
    let btf = generate(&MaterialSpec::new(Preset::Knit, size, 1), &Monitor::new()).unwrap();
    let r = btf.as_ref();
    let (train, _) = btfrs_core::split::split_pairs(81, 81, None, 0.1, 0).unwrap();
    let per = 81 * 81 * 3;
    let t0 = 32 * size;
    let win = 64;
    let data = &r.data[t0 * per..(t0 + win) * per];
    let b = BtfRef::new(1, win, r.views, r.lights, data, Some(&train)).unwrap();
    let opts = LafortuneOptions::default();
    let lay = Layout { diffuse: true, lobes: 2 };
    let s = Instant::now();
    let ctx = Context::new(&b, &opts, lay);
    let setup = s.elapsed().as_secs_f64();
    let mut w = Work::new(ctx.geo.npad(), 2);
    let (mut tg, mut tf, mut it, mut st, mut sse_sum) = (0.0, 0.0, 0usize, [0usize; 3], 0.0f64);
    for t in 0..win {
        let s = Instant::now();
        ctx.gather(b.texel(t), None, &mut w.y);
        let mut rgb = [0.0f32; 3];
        base_colour(b.texel(t), &ctx.meas, &mut rgb);
        tg += s.elapsed().as_secs_f64();
        let s = Instant::now();
        let o = ctx.fit(&mut w);
        tf += s.elapsed().as_secs_f64();
        sse_sum += o.sse;
        it += o.iters;
        st[o.status as usize] += 1;
    }
    // One pass of each kernel at a typical theta.
    let th = init::initial_guesses(&ctx.basis, &ctx.basis.fty(&w.y), true, 2)[1];
    let reps = 2000;
    let s = Instant::now();
    let mut acc = 0.0;
    for _ in 0..reps {
        acc += kernels::cost(&ctx.geo, lay, &th, &mut w);
    }
    let tc = s.elapsed().as_secs_f64() / reps as f64;
    let (mut jtj, mut jtr) = ([0.0; MAXM * MAXM], [0.0; MAXM]);
    let s = Instant::now();
    for _ in 0..reps {
        kernels::normal_equations(&ctx.geo, lay, &th, &mut w, &mut jtj, &mut jtr);
    }
    let tn = s.elapsed().as_secs_f64() / reps as f64;
    let mut sec = [0.0; MAXM * MAXM];
    let s = Instant::now();
    for _ in 0..reps {
        kernels::normal_equations_with(&ctx.geo, lay, &th, &mut w, &mut jtj, &mut jtr, Some(&mut sec));
    }
    let tns = s.elapsed().as_secs_f64() / reps as f64;
    let s = Instant::now();
    for _ in 0..reps {
        let fty = ctx.basis.fty(&w.y);
        acc += init::initial_guesses(&ctx.basis, &fty, true, 2)[1][0];
    }
    let ti = s.elapsed().as_secs_f64() / reps as f64;
    println!(
        "sse {sse_sum:.6e} | samples {} | setup {:.2} ms | per texel: gather {:.1} us, fit {:.1} us, {:.1} LM steps, status {st:?} | \
         cost pass {:.1} us, normal equations {:.1} us (with S {:.1} us), init {:.1} us ({acc:.1e} {})",
        ctx.geo.n,
        setup * 1e3,
        tg / win as f64 * 1e6,
        tf / win as f64 * 1e6,
        it as f64 / win as f64,
        tc * 1e6,
        tn * 1e6,
        tns * 1e6,
        ti * 1e6,
        jtj[0],
    );
}
