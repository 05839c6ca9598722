#![allow(clippy::needless_range_loop)] // index loops mirror the formulas being checked
use super::*;
use crate::model::{evaluate_image, model_error};
use btfrs_core::directions::{from_theta_phi, ubo81};
use btfrs_core::rng::Rng;

/// Associated Legendre `P_l^m(t)` without the Condon-Shortley phase, by the standard recurrences
/// (independent of the closed forms in `hsh_basis`).
fn legendre(l: usize, m: usize, t: f64) -> f64 {
    let st = (1.0 - t * t).max(0.0).sqrt();
    // P_m^m = (2m - 1)!! (1 - t^2)^(m/2)
    let mut pmm = 1.0;
    for i in 0..m {
        pmm *= (2 * i + 1) as f64 * st;
    }
    if l == m {
        return pmm;
    }
    let mut pm1 = t * (2 * m + 1) as f64 * pmm;
    if l == m + 1 {
        return pm1;
    }
    let mut p = 0.0;
    for ll in m + 2..=l {
        p = ((2 * ll - 1) as f64 * t * pm1 - (ll + m - 1) as f64 * pmm) / (ll - m) as f64;
        pmm = pm1;
        pm1 = p;
    }
    p
}

fn factorial(n: usize) -> f64 {
    (1..=n).map(|i| i as f64).product()
}

/// Gautron et al.'s H_l^m with the RTI viewers' sign `(-1)^(|m| + 1)` for m != 0.
fn gautron(l: usize, m: i64, theta: f64, phi: f64) -> f64 {
    let am = m.unsigned_abs() as usize;
    let k = ((2 * l + 1) as f64 * factorial(l - am) / (2.0 * PI * factorial(l + am))).sqrt();
    let p = legendre(l, am, 2.0 * theta.cos() - 1.0);
    if m == 0 {
        return k * p;
    }
    let sign = if am % 2 == 1 { 1.0 } else { -1.0 };
    let trig = if m < 0 { (am as f64 * phi).cos() } else { (am as f64 * phi).sin() };
    sign * 2f64.sqrt() * k * p * trig
}

/// Gauss-Legendre nodes and weights on [0, 1].
fn gauss_legendre(n: usize) -> Vec<(f64, f64)> {
    (0..n)
        .map(|i| {
            let mut x = (PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
            let mut dp = 0.0;
            for _ in 0..100 {
                let (mut p0, mut p1) = (1.0, x);
                for k in 2..=n {
                    let p2 = ((2 * k - 1) as f64 * x * p1 - (k - 1) as f64 * p0) / k as f64;
                    p0 = p1;
                    p1 = p2;
                }
                dp = n as f64 * (x * p1 - p0) / (x * x - 1.0);
                let dx = p1 / dp;
                x -= dx;
                if dx.abs() < 1e-15 {
                    break;
                }
            }
            let w = 2.0 / ((1.0 - x * x) * dp * dp);
            ((x + 1.0) / 2.0, w / 2.0)
        })
        .collect()
}

#[test]
fn basis_is_orthonormal_on_the_hemisphere() {
    // Quadrature over x = cos(theta) in [0, 1] (Gauss-Legendre, exact for the polynomials in x
    // that products of same-|m| terms give) and phi (uniform, exact for trig degree < 2 * 32).
    let gl = gauss_legendre(24);
    let nphi = 64;
    let mut gram = [[0.0f64; 16]; 16];
    let mut b = [0.0f64; 16];
    for &(x, wx) in &gl {
        let st = (1.0 - x * x).sqrt();
        for p in 0..nphi {
            let phi = 2.0 * PI * p as f64 / nphi as f64;
            hsh_basis(4, [st * phi.cos(), st * phi.sin(), x], &mut b);
            let w = wx * 2.0 * PI / nphi as f64;
            for i in 0..16 {
                for j in 0..16 {
                    gram[i][j] += w * b[i] * b[j];
                }
            }
        }
    }
    for i in 0..16 {
        for j in 0..16 {
            let want = if i == j { 1.0 } else { 0.0 };
            assert!((gram[i][j] - want).abs() < 1e-10, "<H{i}, H{j}> = {}", gram[i][j]);
        }
    }
}

#[test]
fn basis_matches_gautron_and_closed_forms() {
    let mut rng = Rng::new(3);
    let mut b = [0.0f64; 16];
    for _ in 0..200 {
        let theta = rng.next_f64() * PI / 2.0;
        let phi = rng.next_f64() * 2.0 * PI - PI;
        hsh_basis(4, from_theta_phi(theta, phi), &mut b);
        for l in 0..4usize {
            for m in -(l as i64)..=l as i64 {
                let j = (l * (l + 1)) as i64 + m;
                let want = gautron(l, m, theta, phi);
                assert!((b[j as usize] - want).abs() < 1e-12, "H{j} at ({theta}, {phi}): {} vs {want}", b[j as usize]);
            }
        }
        // lower orders are prefixes
        let mut b3 = [0.0f64; 16];
        hsh_basis(3, from_theta_phi(theta, phi), &mut b3);
        assert_eq!(b3[..9], b[..9]);
    }
    // At the normal only the m = 0 terms are non-zero: sqrt((2l + 1) / (2 pi)).
    hsh_basis(4, [0.0, 0.0, 1.0], &mut b);
    for (j, &x) in b.iter().enumerate() {
        let want = match j {
            0 => (1.0 / (2.0 * PI)).sqrt(),
            2 => (3.0 / (2.0 * PI)).sqrt(),
            6 => (5.0 / (2.0 * PI)).sqrt(),
            12 => (7.0 / (2.0 * PI)).sqrt(),
            _ => 0.0,
        };
        assert!((x - want).abs() < 1e-12, "H{j} at the normal: {x}");
    }
    // The RTI viewers' terms 1 and 4 at theta 60, phi 30 degrees: x = 1/2, s = 1/2.
    hsh_basis(3, from_theta_phi(PI / 3.0, PI / 6.0), &mut b);
    assert!((b[1] - (6.0 / PI).sqrt() * (PI / 6.0).cos() * 0.5).abs() < 1e-12);
    assert!((b[4] - (30.0 / PI).sqrt() * (PI / 3.0).cos() * -0.25).abs() < 1e-12);
}

/// A BTF whose every texel, view and channel is an exact HSH of `order` in the light.
fn hsh_btf(order: usize, h: usize, w: usize, seed: u64) -> (Vec<[f64; 3]>, Vec<f32>, Vec<f64>) {
    let d = ubo81();
    let n2 = order * order;
    let mut rng = Rng::new(seed);
    let truth: Vec<f64> = (0..h * w * d.len() * 3 * n2).map(|_| rng.next_f64() - 0.4).collect();
    let mut data = vec![0.0f32; h * w * d.len() * d.len() * 3];
    let mut b = [0.0f64; 16];
    for t in 0..h * w {
        for v in 0..d.len() {
            for (l, ld) in d.iter().enumerate() {
                hsh_basis(order, *ld, &mut b);
                for c in 0..3 {
                    let a = &truth[((t * d.len() + v) * 3 + c) * n2..][..n2];
                    data[((t * d.len() + v) * d.len() + l) * 3 + c] = (0..n2).map(|k| a[k] * b[k]).sum::<f64>() as f32;
                }
            }
        }
    }
    (d, data, truth)
}

#[test]
fn recovers_an_hsh_exactly_and_within_quantization() {
    for order in 1..=4 {
        let (h, w) = (2, 3);
        let (d, data, truth) = hsh_btf(order, h, w, order as u64);
        let btf = BtfRef::new(h, w, &d, &d, &data, None).unwrap();
        let exact =
            fit_hsh(&btf, &HshOptions { order, bits: 32, lambda: 0.0, ..Default::default() }, &Monitor::new()).unwrap();
        assert!(exact.degenerate_slots.is_empty(), "order {order}: {:?}", exact.degenerate_slots.first());
        let worst = exact.coeffs.values.iter().zip(&truth).map(|(a, b)| (*a as f64 - b).abs()).fold(0.0, f64::max);
        assert!(worst < 1e-4, "order {order}: largest coefficient error {worst}");
        assert!(model_error(&exact, &btf).unwrap().relative() < 1e-5);

        let q = fit_hsh(&btf, &HshOptions { order, ..Default::default() }, &Monitor::new()).unwrap();
        let p = q.coeffs.planes.as_ref().expect("bits 8 is the default");
        let n2 = order * order;
        assert_eq!((p.texels, p.k), (h * w, d.len() * 3 * n2));
        for (i, (a, b)) in truth.iter().zip(&q.coeffs.values).enumerate() {
            // half a step of quantization plus the (tiny) default ridge
            assert!((a - *b as f64).abs() <= p.scale[i % p.k] as f64 * 0.5 + 1e-4, "order {order}, {i}: {a} vs {b}");
        }
        // the three channels of a (slot, term) share scale and bias, as in a .rti file
        for v in 0..d.len() {
            for j in 0..n2 {
                let at = |c: usize| v * 3 * n2 + c * n2 + j;
                assert!((1..3).all(|c| p.scale[at(c)] == p.scale[at(0)] && p.bias[at(c)] == p.bias[at(0)]));
                // 255 * scale is exact in f32 (what the file stores)
                let s = p.scale[at(0)];
                assert_eq!(((s * 255.0) as f64 / 255.0) as f32, s);
            }
        }
        let want = h * w * p.k + 8 * p.k;
        assert!(q.nbytes() >= want && q.nbytes() < want + 4, "nbytes {} vs {want}", q.nbytes());
        let e = model_error(&q, &btf).unwrap().relative();
        assert!(e < 0.02, "order {order}: 8-bit relative error {e}");
    }
}

#[test]
fn arrays_round_trip_and_bad_arrays_are_named() {
    let (d, data, _) = hsh_btf(2, 2, 2, 9);
    let btf = BtfRef::new(2, 2, &d, &d, &data, None).unwrap();
    for bits in [8, 32] {
        let m = fit_hsh(&btf, &HshOptions { order: 2, bits, ..Default::default() }, &Monitor::new()).unwrap();
        let a = m.to_arrays();
        assert_eq!(a.contains("coeffs_q"), bits == 8);
        let back = Hsh::from_arrays(&a).unwrap();
        assert_eq!((back.order, &back.coeffs), (2, &m.coeffs));
    }
    let mut a = NamedArrays::new();
    a.put("coeffs", &[2, 2, 81, 3, 5], vec![0.0f32; 2 * 2 * 81 * 3 * 5]);
    a.put_directions("views", &d);
    let e = Hsh::from_arrays(&a).unwrap_err().to_string();
    assert!(e.contains("coeffs") && e.contains("1, 4, 9 or 16"), "{e}");
}

#[test]
fn options_are_checked() {
    let (d, data, _) = hsh_btf(1, 1, 1, 1);
    let btf = BtfRef::new(1, 1, &d, &d, &data, None).unwrap();
    for (o, want) in [
        (HshOptions { order: 0, ..Default::default() }, "order"),
        (HshOptions { order: 5, ..Default::default() }, "order"),
        (HshOptions { bits: 7, ..Default::default() }, "bits"),
        (HshOptions { lambda: -1.0, ..Default::default() }, "lambda"),
        (HshOptions { rcond: 2.0, ..Default::default() }, "rcond"),
    ] {
        let e = fit_hsh(&btf, &o, &Monitor::new()).unwrap_err().to_string();
        assert!(e.contains(want), "{e}");
    }
    let e = crate::registry::lookup("hsh")
        .unwrap()
        .fit_json(&btf, r#"{"ordr": 2}"#, &Monitor::new())
        .unwrap_err()
        .to_string();
    assert!(e.contains("ordr"), "{e}");
}

#[test]
fn degenerate_slots_are_reduced_pooled_or_raised() {
    // One view slot keeps 5 lights (fewer than the 9 terms of order 3); the others keep all.
    let (d, data, _) = hsh_btf(1, 1, 2, 4);
    let (nv, nl) = (d.len(), d.len());
    let mut mask = vec![true; nv * nl];
    let keep = [0usize, 8, 20, 40, 60];
    for l in 0..nl {
        mask[3 * nl + l] = keep.contains(&l);
        mask[7 * nl + l] = false; // a slot without lights
    }
    let btf = BtfRef::new(1, 2, &d, &d, &data, Some(&mask)).unwrap();
    let m = fit_hsh(&btf, &HshOptions { bits: 32, ..Default::default() }, &Monitor::new()).unwrap();
    let got: Vec<(usize, usize, &str)> = m.degenerate_slots.iter().map(|s| (s.slot, s.lights, s.reason)).collect();
    assert!(got.contains(&(3, 5, "few lights")) && got.contains(&(7, 0, "few lights")), "{got:?}");
    let s3 = m.degenerate_slots.iter().find(|s| s.slot == 3).unwrap();
    assert!(["order 2", "order 1", "pooled"].contains(&s3.action), "{s3:?}");
    let s7 = m.degenerate_slots.iter().find(|s| s.slot == 7).unwrap();
    assert_eq!(s7.action, "pooled");
    // The data are order 1 (constant in the light): every fallback reproduces them.
    let e = model_error(&m, &btf).unwrap().relative();
    assert!(e < 1e-4, "relative error {e}");
    let img = evaluate_image(&m, d[7], d[0]).unwrap();
    assert!(img.iter().all(|x| x.is_finite()));
    let r = Model::report(&m);
    assert!(r["degenerate_slots"].as_array().unwrap().len() >= 2);

    let e = fit_hsh(&btf, &HshOptions { on_degenerate: Degenerate::Raise, ..Default::default() }, &Monitor::new())
        .unwrap_err()
        .to_string();
    assert!(e.contains("view slot 3") && e.contains("has 5 lights") && e.contains("at least 9"), "{e}");
    let c =
        fit_hsh(&btf, &HshOptions { on_degenerate: Degenerate::Clamp, ..Default::default() }, &Monitor::new()).unwrap();
    let acts: Vec<(usize, &str)> = c.degenerate_slots.iter().map(|s| (s.slot, s.action)).collect();
    assert!(acts.contains(&(3, "clamped")) && acts.contains(&(7, "zero")), "{acts:?}");
}

#[test]
fn a_view_slot_is_the_single_view_hsh_of_that_view() {
    let (h, w) = (2, 3);
    let (d, data, _) = hsh_btf(3, h, w, 5);
    let (nv, nl) = (d.len(), d.len());
    let btf = BtfRef::new(h, w, &d, &d, &data, None).unwrap();
    let m = fit_hsh(&btf, &HshOptions::default(), &Monitor::new()).unwrap();
    for v in [0, 40, nv - 1] {
        let slot = m.slot(v).unwrap();
        assert_eq!((slot.order, slot.height, slot.width, slot.coeffs.values.len()), (3, h, w, h * w * 27));
        let sp = slot.coeffs.planes.as_ref().unwrap();
        let mp = m.coeffs.planes.as_ref().unwrap();
        // the slot's planes are the model's own bytes, scales and biases
        assert_eq!(sp.scale[..], mp.scale[v * 27..(v + 1) * 27]);
        assert_eq!(sp.q[27..54], mp.q[mp.k + v * 27..mp.k + (v + 1) * 27]);
        let one = Hsh::from_slot(slot).unwrap();
        for l in [0, 17, nl - 1] {
            let a = evaluate_image(&one, [0.0, 0.0, 1.0], d[l]).unwrap();
            let b = evaluate_image(&m, d[v], d[l]).unwrap();
            for (x, y) in a.iter().zip(&b) {
                assert!((x - y).abs() < 1e-5, "view {v} light {l}: {x} vs {y}");
            }
        }
    }
    assert!(m.slot(nv).unwrap_err().to_string().contains("view"));
}
