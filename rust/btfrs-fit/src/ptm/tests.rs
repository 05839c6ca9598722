#![allow(clippy::needless_range_loop)] // index loops mirror the formulas being checked
use super::*;
use crate::model::{evaluate_image, model_error};
use btfrs_core::directions::{from_theta_phi, ubo81};
use btfrs_core::rng::Rng;

/// A BTF whose every texel, view and channel is an exact biquadratic of the light.
fn polynomial_btf(h: usize, w: usize, seed: u64) -> (Vec<[f64; 3]>, Vec<f32>, Vec<f64>) {
    let d = ubo81();
    let mut rng = Rng::new(seed);
    let truth: Vec<f64> = (0..h * w * d.len() * 3 * NCOEF).map(|_| rng.next_f64() - 0.3).collect();
    let mut data = vec![0.0f32; h * w * d.len() * d.len() * 3];
    for t in 0..h * w {
        for v in 0..d.len() {
            for (l, ld) in d.iter().enumerate() {
                let b = basis(*ld);
                for c in 0..3 {
                    let a = &truth[((t * d.len() + v) * 3 + c) * NCOEF..][..NCOEF];
                    data[((t * d.len() + v) * d.len() + l) * 3 + c] =
                        (0..NCOEF).map(|k| a[k] * b[k]).sum::<f64>() as f32;
                }
            }
        }
    }
    (d, data, truth)
}

#[test]
fn recovers_a_biquadratic_exactly() {
    // Floats (bits 32): the least-squares fit itself is exact.
    let (d, data, truth) = polynomial_btf(3, 4, 1);
    let btf = BtfRef::new(3, 4, &d, &d, &data, None).unwrap();
    let ptm = fit_ptm(&btf, &PtmOptions { bits: 32, ..Default::default() }, &Monitor::new()).unwrap();
    assert!(ptm.quantized.is_none());
    let worst = ptm.coeffs.iter().zip(&truth).map(|(a, b)| (*a as f64 - b).abs()).fold(0.0, f64::max);
    assert!(worst < 2e-5, "largest coefficient error {worst}");
    let e = model_error(&ptm, &btf).unwrap();
    assert!(e.relative() < 1e-5, "relative error {}", e.relative());
}

#[test]
fn held_out_pairs_do_not_influence_the_fit() {
    let (d, mut data, _) = polynomial_btf(2, 2, 2);
    let (train, test) = btfrs_core::split::split_pairs(81, 81, None, 0.2, 0).unwrap();
    let a = fit_ptm(&BtfRef::new(2, 2, &d, &d, &data, Some(&train)).unwrap(), &PtmOptions::default(), &Monitor::new())
        .unwrap();
    for (i, x) in data.iter_mut().enumerate() {
        if test[(i / 3) % (81 * 81)] {
            *x = 1e6;
        }
    }
    let b = fit_ptm(&BtfRef::new(2, 2, &d, &d, &data, Some(&train)).unwrap(), &PtmOptions::default(), &Monitor::new())
        .unwrap();
    assert_eq!(a.coeffs, b.coeffs);
}

#[test]
// The exactness tests fit floats (bits 32); the 8-bit planes are tested on their own below.
fn lrgb_recovers_a_modulated_luminance() {
    // rgb(l) = L(l) * base with base's largest channel 1: LRGB must find both.
    let d = ubo81();
    let a = [0.1, -0.2, 0.05, 0.3, -0.1, 0.6];
    let base = [1.0, 0.5, 0.25];
    let mut data = vec![0.0f32; d.len() * d.len() * 3];
    for v in 0..d.len() {
        for (l, ld) in d.iter().enumerate() {
            let lum: f64 = basis(*ld).iter().zip(&a).map(|(b, a)| b * a).sum();
            for c in 0..3 {
                data[(v * d.len() + l) * 3 + c] = (lum * base[c]) as f32;
            }
        }
    }
    let btf = BtfRef::new(1, 1, &d, &d, &data, None).unwrap();
    let ptm =
        fit_ptm(&btf, &PtmOptions { kind: PtmKind::Lrgb, bits: 32, ..Default::default() }, &Monitor::new()).unwrap();
    for v in 0..d.len() {
        for k in 0..NCOEF {
            assert!((ptm.coeffs[v * NCOEF + k] as f64 - a[k]).abs() < 1e-5);
        }
        for c in 0..3 {
            assert!((ptm.rgb.as_ref().unwrap()[v * 3 + c] as f64 - base[c]).abs() < 1e-5);
        }
    }
}

#[test]
fn too_few_or_collinear_lights_are_errors() {
    let d = ubo81();
    let five: Vec<[f64; 3]> = d[..5].to_vec();
    let data = vec![0.5f32; 81 * 5 * 3];
    let btf = BtfRef::new(1, 1, &d, &five, &data, None).unwrap();
    let e = fit_ptm(&btf, &PtmOptions { on_degenerate: Degenerate::Raise, ..Default::default() }, &Monitor::new())
        .unwrap_err()
        .to_string();
    assert!(e.contains("has 5 lights") && e.contains("at least 6"), "{e}");
    // Twelve lights on the arc phi = 0: (lu, lv) all on the line lv = 0.
    let arc: Vec<[f64; 3]> =
        (0..12).map(|i| from_theta_phi(-1.2 + 0.2 * i as f64, 0.0)).map(|x| [x[0], x[1], x[2].abs()]).collect();
    let data = vec![0.5f32; 81 * 12 * 3];
    let btf = BtfRef::new(1, 1, &d, &arc, &data, None).unwrap();
    let e = fit_ptm(&btf, &PtmOptions { on_degenerate: Degenerate::Raise, ..Default::default() }, &Monitor::new())
        .unwrap_err()
        .to_string();
    assert!(e.contains("collinear") && e.contains("view slot 0"), "{e}");
    // Clamped, the same data gives the minimum-norm fit, which reproduces the constant.
    let ptm =
        fit_ptm(&btf, &PtmOptions { on_degenerate: Degenerate::Clamp, ..Default::default() }, &Monitor::new()).unwrap();
    let e = model_error(&ptm, &btf).unwrap();
    assert!(e.rmse() < 1e-5, "{}", e.rmse());
}

#[test]
fn evaluation_between_slots_blends_the_nearest() {
    let (d, data, _) = polynomial_btf(1, 1, 3);
    let btf = BtfRef::new(1, 1, &d, &d, &data, None).unwrap();
    let ptm = fit_ptm(&btf, &PtmOptions::default(), &Monitor::new()).unwrap();
    // At a measured view the image is that slot's polynomial.
    let l = from_theta_phi(0.3, 1.0);
    let img = evaluate_image(&ptm, d[7], l).unwrap();
    let b = basis(l);
    let want: f64 = (0..NCOEF).map(|k| ptm.coeffs[(7 * 3) * NCOEF + k] as f64 * b[k]).sum();
    assert!((img[0] as f64 - want).abs() < 1e-5);
    assert!(evaluate_image(&ptm, [0.0, 0.0, 2.0], l).is_err());
}

#[test]
fn a_view_slot_without_lights_is_an_error_or_zero() {
    let d = ubo81();
    let data = vec![0.5f32; 81 * 81 * 3];
    let mut mask = vec![true; 81 * 81];
    mask[5 * 81..6 * 81].iter_mut().for_each(|m| *m = false);
    let btf = BtfRef::new(1, 1, &d, &d, &data, Some(&mask)).unwrap();
    let e = fit_ptm(&btf, &PtmOptions { on_degenerate: Degenerate::Raise, ..Default::default() }, &Monitor::new())
        .unwrap_err()
        .to_string();
    assert!(e.contains("view slot 5") && e.contains("has 0 lights"), "{e}");
    let ptm =
        fit_ptm(&btf, &PtmOptions { on_degenerate: Degenerate::Clamp, ..Default::default() }, &Monitor::new()).unwrap();
    assert!(ptm.coeffs[5 * 18..6 * 18].iter().all(|&c| c == 0.0));
    assert!((ptm.coeffs[4 * 18 + 5] - 0.5).abs() < 1e-6);
}

#[test]
fn evaluation_is_continuous_between_slots() {
    // Sweep the view along a path that changes its set of three nearest slots many times; with
    // each slot's value fixed, the blended value must change by no more than a Lipschitz bound.
    let (d, data, _) = polynomial_btf(1, 1, 4);
    let btf = BtfRef::new(1, 1, &d, &d, &data, None).unwrap();
    let ptm = fit_ptm(&btf, &PtmOptions::default(), &Monitor::new()).unwrap();
    let l = from_theta_phi(0.2, 0.4);
    let steps = 4000;
    let mut prev: Option<f32> = None;
    let mut worst = 0.0f32;
    for i in 0..=steps {
        let theta = 1.3 * i as f64 / steps as f64;
        let v = from_theta_phi(theta, 0.17 + 0.8 * theta);
        let x = evaluate_image(&ptm, v, l).unwrap()[0];
        if let Some(p) = prev {
            worst = worst.max((x - p).abs());
        }
        prev = Some(x);
    }
    // The slots' values differ by O(1); a jump would show up as a step of that size, while a
    // continuous blend moves by about (value range) * (step / slot spacing) ~ 1e-2 per step.
    assert!(worst < 0.05, "largest step {worst}");
}

#[test]
fn a_view_slot_is_the_single_view_ptm_of_that_view() {
    // Each slot's polynomials reproduce the BTF at its view (an exact biquadratic here), and the
    // one-slot model built from it renders that view's images at the normal.
    let (h, w) = (2, 3);
    let (d, data, _) = polynomial_btf(h, w, 5);
    let (nv, nl) = (d.len(), d.len());
    let btf = BtfRef::new(h, w, &d, &d, &data, None).unwrap();
    let ptm = fit_ptm(&btf, &PtmOptions { bits: 32, ..Default::default() }, &Monitor::new()).unwrap();
    for v in [0, 40, nv - 1] {
        let slot = ptm.slot(v).unwrap();
        assert_eq!((slot.kind, slot.height, slot.width, slot.coeffs.len()), (PtmKind::Rgb, h, w, h * w * 18));
        assert!(slot.rgb.is_none());
        let one = Ptm::from_slot(slot.clone()).unwrap();
        assert_eq!(one.views, vec![[0.0, 0.0, 1.0]]);
        for l in [0, 17, nl - 1] {
            let b = basis(d[l]);
            let img = evaluate_image(&one, [0.0, 0.0, 1.0], d[l]).unwrap();
            for t in 0..h * w {
                for ch in 0..3 {
                    let want = data[((t * nv + v) * nl + l) * 3 + ch] as f64;
                    let got: f64 = (0..NCOEF).map(|k| slot.coeffs[(t * 3 + ch) * NCOEF + k] as f64 * b[k]).sum();
                    assert!((got - want).abs() < 1e-4, "view {v} light {l} texel {t}: {got} vs {want}");
                    assert!((img[t * 3 + ch] as f64 - want).abs() < 1e-4);
                }
            }
        }
    }
}

#[test]
fn an_lrgb_slot_keeps_its_base_colour() {
    // Texel t's luminance is a_t(l), its colour base_t: the slot must hold exactly those.
    let d = ubo81();
    let (h, w) = (1, 2);
    let a = [[0.1, -0.2, 0.05, 0.3, -0.1, 0.6], [0.0, 0.1, 0.0, -0.2, 0.2, 0.4]];
    let base = [[1.0, 0.5, 0.25], [0.2, 1.0, 0.6]];
    let n = d.len();
    let mut data = vec![0.0f32; h * w * n * n * 3];
    for t in 0..h * w {
        for v in 0..n {
            for (l, ld) in d.iter().enumerate() {
                let lum: f64 = basis(*ld).iter().zip(&a[t]).map(|(b, a)| b * a).sum();
                for c in 0..3 {
                    data[((t * n + v) * n + l) * 3 + c] = (lum * base[t][c]) as f32;
                }
            }
        }
    }
    let btf = BtfRef::new(h, w, &d, &d, &data, None).unwrap();
    let ptm =
        fit_ptm(&btf, &PtmOptions { kind: PtmKind::Lrgb, bits: 32, ..Default::default() }, &Monitor::new()).unwrap();
    let slot = ptm.slot(33).unwrap();
    let rgb = slot.rgb.as_ref().unwrap();
    assert_eq!((slot.coeffs.len(), rgb.len()), (h * w * NCOEF, h * w * 3));
    for t in 0..h * w {
        for k in 0..NCOEF {
            assert!((slot.coeffs[t * NCOEF + k] as f64 - a[t][k]).abs() < 1e-5);
        }
        for c in 0..3 {
            assert!((rgb[t * 3 + c] as f64 - base[t][c]).abs() < 1e-5);
        }
    }
    let one = Ptm::from_slot(slot).unwrap();
    assert_eq!(one.kind, PtmKind::Lrgb);
}

#[test]
fn slot_errors_name_the_argument() {
    let arg = |e: Error| match e {
        Error::InvalidArgument { name, .. } => name,
        other => panic!("expected InvalidArgument, got {other:?}"),
    };
    let (d, data, _) = polynomial_btf(1, 1, 6);
    let btf = BtfRef::new(1, 1, &d, &d, &data, None).unwrap();
    let ptm = fit_ptm(&btf, &PtmOptions::default(), &Monitor::new()).unwrap();
    let e = ptm.slot(81).unwrap_err();
    assert!(e.to_string().contains("[0, 81)"), "{e}");
    assert_eq!(arg(e), "view");
    let mut slot = ptm.slot(0).unwrap();
    slot.coeffs.pop();
    assert_eq!(arg(Ptm::from_slot(slot.clone()).unwrap_err()), "coeffs");
    slot.coeffs.push(0.0);
    slot.kind = PtmKind::Lrgb;
    assert!(Ptm::from_slot(slot).is_err());
    let broken = Ptm { kind: PtmKind::Lrgb, rgb: None, coeffs: vec![0.0; 81 * 6], ..ptm };
    assert_eq!(arg(broken.slot(0).unwrap_err()), "rgb");
}

/// A slot's samples: values `f(l)` of a known function at `lights` for 1 texel, 1 view.
fn one_slot(lights: &[[f64; 3]], f: impl Fn([f64; 3]) -> [f64; 3]) -> Vec<f32> {
    lights.iter().flat_map(|&l| f(l).map(|x| x as f32)).collect()
}

#[test]
fn reduce_fits_a_plane_exactly_from_four_lights() {
    // Four lights (fewer than the 6 biquadratic terms) and values on a plane of known form in
    // (lu, lv): the reduced basis (lu, lv, 1) reproduces it exactly, at the lights and between.
    let view = [[0.0, 0.0, 1.0]];
    let lights: Vec<[f64; 3]> =
        [(0.3, 0.0), (0.5, 1.7), (0.6, 3.5), (0.9, 5.0)].iter().map(|&(t, p)| from_theta_phi(t, p)).collect();
    let plane = |l: [f64; 3]| [0.4 + 0.3 * l[0] - 0.2 * l[1], 0.1 + 0.5 * l[0], 0.7 - 0.6 * l[1]];
    // LRGB models a luminance times a colour: its data are one plane times a colour.
    let grey = |l: [f64; 3]| plane(l)[0];
    let rgb_data = one_slot(&lights, plane);
    let lrgb_data = one_slot(&lights, |l| [0.5 * grey(l), grey(l), 0.8 * grey(l)]);
    for kind in [PtmKind::Rgb, PtmKind::Lrgb] {
        let data = if kind == PtmKind::Rgb { &rgb_data } else { &lrgb_data };
        let btf = BtfRef::new(1, 1, &view, &lights, data, None).unwrap();
        let ptm = fit_ptm(&btf, &PtmOptions { kind, bits: 32, ..Default::default() }, &Monitor::new()).unwrap();
        let got: Vec<(usize, usize, &str, &str)> =
            ptm.degenerate_slots.iter().map(|s| (s.slot, s.lights, s.reason, s.action)).collect();
        assert_eq!(got, vec![(0, 4, "few lights", "linear")], "{kind:?}");
        if kind == PtmKind::Rgb {
            // Exact plane coefficients: quadratic terms 0, then (lu, lv, 1).
            let want =
                [[0.0, 0.0, 0.0, 0.3, -0.2, 0.4], [0.0, 0.0, 0.0, 0.5, 0.0, 0.1], [0.0, 0.0, 0.0, 0.0, -0.6, 0.7]];
            for c in 0..3 {
                for k in 0..NCOEF {
                    assert!((ptm.coeffs[c * NCOEF + k] as f64 - want[c][k]).abs() < 1e-5, "{c} {k}: {:?}", ptm.coeffs);
                }
            }
            // Between the lights too (the plane is the truth everywhere).
            let l = from_theta_phi(0.7, 2.4);
            let img = evaluate_image(&ptm, view[0], l).unwrap();
            let p = plane(l);
            for c in 0..3 {
                assert!((img[c] as f64 - p[c]).abs() < 1e-5);
            }
        }
        assert!(model_error(&ptm, &btf).unwrap().rmse() < 1e-5, "{kind:?}");
        let r = Model::report(&ptm);
        assert_eq!(r["degenerate_slots"][0]["action"], "linear");
    }
    // The old behaviour stays available.
    let btf = BtfRef::new(1, 1, &view, &lights, &rgb_data, None).unwrap();
    let e = fit_ptm(&btf, &PtmOptions { on_degenerate: Degenerate::Raise, ..Default::default() }, &Monitor::new());
    assert!(e.unwrap_err().to_string().contains("has 4 lights"));
}

#[test]
fn reduce_pools_the_lights_of_the_nearest_views() {
    // Every view with the same exact biquadratic of the light (a view-independent texel); slot 5
    // keeps only 2 lights, slot 9 none, slot 12 six clustered lights whose biquadratic would
    // extrapolate: they pool the lights of their nearest views, which reproduces the truth
    // exactly, and the report says why and from where.
    let d = ubo81();
    let truth = [[0.3, -0.2, 0.1, 0.25, -0.15, 0.6], [0.1, 0.2, -0.1, 0.05, 0.3, 0.4], [-0.2, 0.1, 0.0, 0.2, 0.1, 0.5]];
    let data: Vec<f32> = (0..81 * 81)
        .flat_map(|i| {
            let b = basis(d[i % 81]);
            (0..3).map(move |c| (0..NCOEF).map(|k| truth[c][k] * b[k]).sum::<f64>() as f32)
        })
        .collect();
    let mut mask = vec![true; 81 * 81];
    mask[5 * 81 + 2..6 * 81].iter_mut().for_each(|m| *m = false);
    mask[9 * 81..10 * 81].iter_mut().for_each(|m| *m = false);
    // Slot 12: the normal and 5 lights of the 15-degree ring only.
    mask[12 * 81 + 6..13 * 81].iter_mut().for_each(|m| *m = false);
    let btf = BtfRef::new(1, 1, &d, &d, &data, Some(&mask)).unwrap();
    let ptm = fit_ptm(&btf, &PtmOptions { bits: 32, ..Default::default() }, &Monitor::new()).unwrap();
    let got: Vec<(usize, usize, &str, &str)> =
        ptm.degenerate_slots.iter().map(|s| (s.slot, s.lights, s.reason, s.action)).collect();
    assert_eq!(
        got,
        vec![(5, 2, "few lights", "pooled"), (9, 0, "few lights", "pooled"), (12, 6, "extrapolates", "pooled")],
        "{:?}",
        ptm.degenerate_slots
    );
    for s in &ptm.degenerate_slots {
        assert!(s.amplification <= K_AMP, "{s:?}");
        // The nearest view first.
        let dot = |u: usize| (0..3).map(|k| d[s.slot][k] * d[u][k]).sum::<f64>();
        let nearest = (0..81).filter(|&u| u != s.slot && u != 9).max_by(|&a, &b| dot(a).total_cmp(&dot(b))).unwrap();
        assert!((dot(s.from[0]) - dot(nearest)).abs() < 1e-12, "{s:?}");
    }
    for v in [5, 9, 12] {
        for c in 0..3 {
            for k in 0..NCOEF {
                let got = ptm.coeffs[(v * 3 + c) * NCOEF + k] as f64;
                assert!((got - truth[c][k]).abs() < 1e-4, "slot {v} channel {c} term {k}: {got}");
            }
        }
    }
    // The clamp policy keeps slot 12's own fit (full rank): only reduce checks extrapolation.
    let raw = fit_ptm(&btf, &PtmOptions { on_degenerate: Degenerate::Clamp, ..Default::default() }, &Monitor::new());
    let slots: Vec<usize> = raw.unwrap().degenerate_slots.iter().map(|s| s.slot).collect();
    assert_eq!(slots, vec![5, 9]);
}

#[test]
fn reduce_without_neighbours_keeps_the_least_amplifying_fit() {
    // One view, 12 collinear lights: neither the biquadratic nor the plane is determined and
    // there is nothing to pool: the minimum-norm fit, reported.
    let arc: Vec<[f64; 3]> =
        (0..12).map(|i| from_theta_phi(-1.2 + 0.2 * i as f64, 0.0)).map(|x| [x[0], x[1], x[2].abs()]).collect();
    let data = vec![0.5f32; 12 * 3];
    let view = [[0.0, 0.0, 1.0]];
    let btf = BtfRef::new(1, 1, &view, &arc, &data, None).unwrap();
    let ptm = fit_ptm(&btf, &PtmOptions::default(), &Monitor::new()).unwrap();
    let acts: Vec<(&str, &str)> = ptm.degenerate_slots.iter().map(|s| (s.reason, s.action)).collect();
    assert_eq!(acts, vec![("degenerate lights", "clamped")]);
    assert!(model_error(&ptm, &btf).unwrap().rmse() < 1e-6);
}

#[test]
fn eight_bit_planes_are_within_half_a_step_and_are_what_is_stored() {
    // The default (bits 8) quantizes the exact float fit: every coefficient within half its
    // plane's step, the GPU store is the planes (1 byte per coefficient + 8 bytes per plane),
    // and the arrays round-trip through the planes.
    let (h, w) = (3, 4);
    let (d, data, truth) = polynomial_btf(h, w, 1);
    let btf = BtfRef::new(h, w, &d, &d, &data, None).unwrap();
    for kind in [PtmKind::Rgb, PtmKind::Lrgb] {
        let exact = fit_ptm(&btf, &PtmOptions { kind, bits: 32, ..Default::default() }, &Monitor::new()).unwrap();
        let q = fit_ptm(&btf, &PtmOptions { kind, ..Default::default() }, &Monitor::new()).unwrap();
        let planes = q.quantized.as_ref().expect("bits 8 quantizes");
        let k = d.len() * if kind == PtmKind::Rgb { 18 } else { 6 };
        assert_eq!((planes.coeffs.texels, planes.coeffs.k), (h * w, k));
        for (i, (a, b)) in exact.coeffs.iter().zip(&q.coeffs).enumerate() {
            assert!((a - b).abs() <= planes.coeffs.scale[i % k] * 0.5 + 1e-6, "{kind:?} {i}: {a} vs {b}");
        }
        let mut want = h * w * k + 8 * k;
        if let Some(r) = &planes.rgb {
            want += h * w * d.len() * 3 + 8 * d.len() * 3;
            for (a, b) in exact.rgb.as_ref().unwrap().iter().zip(q.rgb.as_ref().unwrap()) {
                assert!((a - b).abs() <= r.scale.iter().cloned().fold(0.0, f32::max) * 0.5 + 1e-6);
            }
        }
        // words round up to 4 bytes per array
        assert!(q.nbytes() >= want && q.nbytes() < want + 16, "{kind:?}: nbytes {} vs {want}", q.nbytes());
        // 4 bytes per value as floats against 1 + 8 / texels (12 texels here)
        assert!(exact.nbytes() > 2 * q.nbytes());
        let a = q.to_arrays();
        assert!(a.contains("coeffs_q") && !a.contains("coeffs"));
        let back = Ptm::from_arrays(&a).unwrap();
        assert_eq!(back.coeffs, q.coeffs);
        assert_eq!(back.quantized, q.quantized);
        // RGB fits this data exactly, LRGB does not: the quantization adds at most 2% either way.
        let e = model_error(&q, &btf).unwrap().relative();
        let e0 = model_error(&exact, &btf).unwrap().relative();
        assert!((e - e0).abs() < 0.02 && e != e0, "{kind:?}: 8-bit relative error {e} against {e0}");
    }
    let _ = truth;
    let e = fit_ptm(&btf, &PtmOptions { bits: 16, ..Default::default() }, &Monitor::new()).unwrap_err().to_string();
    assert!(e.contains("bits") && e.contains("got 16"), "{e}");
}

#[test]
fn ptm_whitening_turns_coefficient_distance_into_hemisphere_l2() {
    // |L^T c|^2 must equal the mean over the hemisphere of (b(l) . c)^2, computed here by an
    // independent quadrature (a finer polar grid weighted by sin(theta)).
    let l = super::gram_factor();
    let c = [0.3, -0.2, 0.5, 0.1, -0.4, 0.7];
    let f: Vec<f64> = (0..6).map(|k| (0..6).map(|a| l[a][k] * c[a]).sum()).collect();
    let lhs: f64 = f.iter().map(|x| x * x).sum();
    let (nt, np) = (400, 400);
    let (mut num, mut den) = (0.0, 0.0);
    for i in 0..nt {
        let t = (i as f64 + 0.5) / nt as f64 * std::f64::consts::FRAC_PI_2;
        for j in 0..np {
            let p = (j as f64 + 0.5) / np as f64 * std::f64::consts::TAU;
            let b = super::basis([t.sin() * p.cos(), t.sin() * p.sin(), t.cos()]);
            let v: f64 = b.iter().zip(&c).map(|(x, y)| x * y).sum();
            num += v * v * t.sin();
            den += t.sin();
        }
    }
    assert!((lhs - num / den).abs() < 2e-3 * lhs, "{lhs} vs {}", num / den);
}
