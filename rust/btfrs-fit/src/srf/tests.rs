use super::*;
use crate::model::model_error;
use btfrs_core::directions::ubo81;
use btfrs_core::materials::{generate, MaterialSpec, Preset};
use btfrs_core::rng::Rng;

/// Data made by the model itself: a Phong material plus s(P) . H residuals whose mean over the
/// texels is zero, so the mean BRDF is exactly the Phong part.
fn srf_data(h: usize, w: usize, phong: &Phong, seed: u64) -> (Vec<[f64; 3]>, Vec<f32>, Vec<[f64; 9]>) {
    let d = ubo81();
    let mut rng = Rng::new(seed);
    let mut s: Vec<[f64; 9]> = (0..h * w).map(|_| std::array::from_fn(|_| 0.05 * (rng.next_f64() - 0.5))).collect();
    let n = s.len() as f64;
    let mean: [f64; 9] = std::array::from_fn(|k| s.iter().map(|x| x[k]).sum::<f64>() / n);
    s.iter_mut().for_each(|x| (0..9).for_each(|k| x[k] -= mean[k]));
    let mut data = vec![0.0f32; h * w * d.len() * d.len() * 3];
    for (t, st) in s.iter().enumerate() {
        for (v, vd) in d.iter().enumerate() {
            for (l, ld) in d.iter().enumerate() {
                let hv = halfway(*vd, *ld);
                for c in 0..3 {
                    let r = st[c * 3] * hv[0] + st[c * 3 + 1] * hv[1] + st[c * 3 + 2] * hv[2];
                    data[((t * d.len() + v) * d.len() + l) * 3 + c] = (phong.eval(c, ld[2], hv[2]) + r) as f32;
                }
            }
        }
    }
    (d, data, s)
}

#[test]
fn recovers_phong_and_the_residual_of_model_data() {
    let truth = Phong { kd: [0.5, 0.3, 0.2], ks: [0.4, 0.4, 0.5], n: 35.0 };
    let (d, data, s) = srf_data(4, 5, &truth, 3);
    let btf = BtfRef::new(4, 5, &d, &d, &data, None).unwrap();
    let (m, report) = fit_srf(&btf, &Monitor::new()).unwrap();
    assert!((m.phong.n - truth.n).abs() < 0.05, "n {} vs {}", m.phong.n, truth.n);
    for c in 0..3 {
        assert!((m.phong.kd[c] - truth.kd[c]).abs() < 1e-4, "kd {:?}", m.phong.kd);
        assert!((m.phong.ks[c] - truth.ks[c]).abs() < 1e-3, "ks {:?}", m.phong.ks);
    }
    let worst = m.s.iter().zip(s.iter().flatten()).map(|(a, b)| (*a as f64 - b).abs()).fold(0.0, f64::max);
    assert!(worst < 1e-4, "largest s(P) error {worst}");
    assert!(report.srf_relative < 1e-4 && report.srf_relative < report.phong_relative, "{report:?}");
    let e = model_error(&m, &btf).unwrap().relative();
    assert!((e - report.srf_relative).abs() < 1e-5, "model_error {e} vs report {}", report.srf_relative);
}

#[test]
fn the_residual_improves_on_phong_alone_on_every_builtin_material() {
    for preset in [Preset::Knit, Preset::Weave, Preset::Bumps, Preset::Grooves] {
        let b = generate(&MaterialSpec::new(preset, 8, 1), &Monitor::new()).unwrap();
        let btf = b.as_ref();
        let (m, report) = fit_srf(&btf, &Monitor::new()).unwrap();
        let phong = model_error(&m.phong_only(), &btf).unwrap().relative();
        let srf = model_error(&m, &btf).unwrap().relative();
        assert!((phong - report.phong_relative).abs() < 1e-6 && (srf - report.srf_relative).abs() < 1e-6);
        assert!(srf < phong, "{preset:?}: Phong + SRF {srf} is not below Phong alone {phong}");
    }
}

#[test]
fn held_out_pairs_do_not_influence_the_fit() {
    let truth = Phong { kd: [0.5, 0.3, 0.2], ks: [0.4, 0.4, 0.5], n: 20.0 };
    let (d, mut data, _) = srf_data(2, 3, &truth, 5);
    let (train, test) = btfrs_core::split::split_pairs(81, 81, None, 0.2, 0).unwrap();
    let fit =
        |data: &[f32]| fit_srf(&BtfRef::new(2, 3, &d, &d, data, Some(&train)).unwrap(), &Monitor::new()).unwrap().0;
    let a = fit(&data);
    for (i, x) in data.iter_mut().enumerate() {
        if test[(i / 3) % (81 * 81)] {
            *x = 1e6;
        }
    }
    let b = fit(&data);
    assert_eq!(a.s, b.s);
    assert_eq!(a.phong, b.phong);
}

#[test]
fn degenerate_and_black_inputs() {
    // Two pairs cannot determine a 3-vector.
    let d = ubo81();
    let data = vec![0.5f32; 81 * 81 * 3];
    let mut mask = vec![false; 81 * 81];
    mask[0] = true;
    mask[1] = true;
    let e = fit_srf(&BtfRef::new(1, 1, &d, &d, &data, Some(&mask)).unwrap(), &Monitor::new()).unwrap_err();
    assert!(matches!(e, Error::Degenerate(_)), "{e}");
    // An all-black sample fits to zeros, not NaN.
    let black = vec![0.0f32; 2 * 81 * 81 * 3];
    let (m, r) = fit_srf(&BtfRef::new(1, 2, &d, &d, &black, None).unwrap(), &Monitor::new()).unwrap();
    assert!(m.s.iter().all(|x| *x == 0.0) && m.phong.kd == [0.0; 3] && m.phong.ks == [0.0; 3]);
    assert_eq!(r.srf_relative, 0.0);
    m.validate().unwrap();
}

#[test]
fn halfway_is_the_normalised_sum() {
    let h = halfway([0.0, 0.0, 1.0], [1.0, 0.0, 0.0]);
    let r = std::f64::consts::FRAC_1_SQRT_2;
    assert!((h[0] - r).abs() < 1e-15 && h[1] == 0.0 && (h[2] - r).abs() < 1e-15);
    assert_eq!(halfway([1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]), [0.0, 0.0, 1.0]);
}
