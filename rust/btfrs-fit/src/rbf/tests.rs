#![allow(clippy::needless_range_loop)] // index loops mirror the formulas being checked
use super::*;
use crate::model::{model_error, ReflectanceModel};
use btfrs_core::rng::Rng;

/// `n` lights spread over the hemisphere up to 75 degrees (uniform on the concentric square,
/// shrunk towards the pole), from a seed.
pub(crate) fn scattered_lights(n: usize, seed: u64) -> Vec<[f64; 3]> {
    let mut rng = Rng::new(seed);
    (0..n)
        .map(|_| {
            let (s, t) = (0.5 + 0.42 * (rng.next_f64() - 0.5) * 2.0, 0.5 + 0.42 * (rng.next_f64() - 0.5) * 2.0);
            btfrs_hemimap::square_to_hemisphere(s, t)
        })
        .collect()
}

#[test]
fn the_interpolant_reproduces_the_samples_as_regularization_vanishes() {
    // Closed form: with lambda -> 0 the RBF interpolant passes through every sample, and the
    // operator evaluated at the lights themselves is the identity.
    let lights = scattered_lights(40, 3);
    let w = rbf_operator(&lights, &lights, 1.0, 1e-12).unwrap();
    let eye = DMatrix::<f64>::identity(40, 40);
    assert!((&w - &eye).abs().max() < 1e-5, "{}", (&w - &eye).abs().max());
    // With a ridge it smooths: the operator at the lights is no longer the identity.
    let w = rbf_operator(&lights, &lights, 1.0, 0.5).unwrap();
    assert!((&w - &eye).abs().max() > 0.05);
    // Rows sum to 1 (a constant is reproduced at any target, any regularization).
    let far = vec![[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, -0.99, 0.141]];
    for r in [1e-9, 1e-3, 1.0] {
        let w = rbf_operator(&lights, &far, 1.3, r).unwrap();
        for i in 0..3 {
            assert!((w.row(i).sum() - 1.0).abs() < 1e-9);
        }
    }
}

#[test]
fn the_operator_matches_a_direct_solve() {
    // An independent evaluation of f(x) = mu + k(x)^T (K + lambda I)^-1 (y - mu) for one y,
    // through nalgebra's LU instead of the operator's Cholesky.
    let lights = scattered_lights(25, 9);
    let y: Vec<f64> = (0..25).map(|i| ((i * 37) % 11) as f64 * 0.1).collect();
    let x = [[0.1, 0.2, (1.0f64 - 0.05).sqrt()], [-0.5, 0.3, (1.0f64 - 0.34).sqrt()]];
    let sigma = 0.8 * light_spacing(&lights);
    let k = |a: [f64; 3], b: [f64; 3]| (-dist2(a, b) / (2.0 * sigma * sigma)).exp();
    let kk = DMatrix::from_fn(25, 25, |i, j| k(lights[i], lights[j]) + if i == j { 0.01 } else { 0.0 });
    let mu = y.iter().sum::<f64>() / 25.0;
    let rhs = nalgebra::DVector::from_iterator(25, y.iter().map(|v| v - mu));
    let a = kk.lu().solve(&rhs).unwrap();
    let w = rbf_operator(&lights, &x, 0.8, 0.01).unwrap();
    for (i, &p) in x.iter().enumerate() {
        let direct = mu + (0..25).map(|j| a[j] * k(p, lights[j])).sum::<f64>();
        let via = (0..25).map(|j| w[(i, j)] * y[j]).sum::<f64>();
        assert!((direct - via).abs() < 1e-9, "{direct} vs {via}");
    }
}

#[test]
fn the_spacing_is_the_side_of_each_lights_share_of_the_cap() {
    // Three distinct lights (one duplicated) down to z = 0.8: cap 2 pi (1 - 0.8), three shares.
    let l = [[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.1, 0.0, (0.99f64).sqrt()], [0.0, 0.6, 0.8]];
    let want = (std::f64::consts::TAU * 0.2 / 3.0).sqrt();
    assert!((light_spacing(&l) - want).abs() < 1e-12);
    assert_eq!(light_spacing(&l[..2]), 0.0);
}

/// A single-view BTF: `h x w` texels under `lights`, each texel a random smooth function.
pub(crate) fn smooth_btf(h: usize, w: usize, lights: &[[f64; 3]], seed: u64) -> Vec<f32> {
    let mut rng = Rng::new(seed);
    let mut data = vec![0.0f32; h * w * lights.len() * 3];
    for t in 0..h * w {
        let a: Vec<f64> = (0..9).map(|_| rng.next_f64()).collect();
        for (l, d) in lights.iter().enumerate() {
            let diffuse = d[2].max(0.0);
            let lobe = (-(((d[0] - 0.3 * a[6]).powi(2) + (d[1] - 0.3 * a[7]).powi(2)) / 0.15)).exp();
            for c in 0..3 {
                data[(t * lights.len() + l) * 3 + c] = (a[c] * diffuse + a[3 + c] * lobe * a[8]) as f32;
            }
        }
    }
    data
}

#[test]
fn fits_a_smooth_capture_and_predicts_held_out_lights() {
    let lights = scattered_lights(160, 1);
    let data = smooth_btf(6, 5, &lights, 2);
    let view = [[0.0, 0.0, 1.0]];
    let (train, test) = btfrs_core::split::split_pairs(1, 160, None, 0.15, 0).unwrap();
    let btf = BtfRef::new(6, 5, &view, &lights, &data, Some(&train)).unwrap();
    // This smooth data favours a wide kernel.
    let o = RbfOptions { components: 12, resolution: 16, width: 2.0, regularization: 1e-3, ..Default::default() };
    let m = fit_rbf(&btf, &o, &Monitor::new()).unwrap();
    let held = BtfRef::new(6, 5, &view, &lights, &data, Some(&test)).unwrap();
    let e = model_error(&m, &held).unwrap().relative();
    assert!(e < 0.045, "held-out relative error {e}");
    let e = model_error(&m, &btf).unwrap().relative();
    assert!(e < 0.03, "fitted relative error {e}");
    // ycc with as many luminance planes and 3 chroma planes is about as good.
    let o = RbfOptions { colour: Colour::Ycc, chroma_components: Some(3), ..o };
    let y = fit_rbf(&btf, &o, &Monitor::new()).unwrap();
    let ey = model_error(&y, &held).unwrap().relative();
    assert!(ey < 0.06, "{ey}");
    // A narrow kernel dips towards the mean between lights: worse on held-out lights.
    let narrow = fit_rbf(&btf, &RbfOptions { width: 0.5, ..o }, &Monitor::new()).unwrap();
    assert!(model_error(&narrow, &held).unwrap().relative() > 2.0 * ey);
    assert_eq!(y.0.stride(), 3 + 12 + 6);
}

#[test]
fn with_fine_grid_and_no_ridge_the_model_reproduces_the_samples() {
    // Closed form through the whole model: lambda ~ 0, a fine table and as many components as
    // texels: at a measured light the model returns the sample up to the bilinear lookup of a
    // smooth interpolant and the 8-bit quantization.
    let lights = scattered_lights(60, 4);
    let data = smooth_btf(2, 2, &lights, 5);
    let view = [[0.0, 0.0, 1.0]];
    let btf = BtfRef::new(2, 2, &view, &lights, &data, None).unwrap();
    let o = RbfOptions { components: 4, resolution: 32, regularization: 1e-9, width: 1.5, ..Default::default() };
    let m = fit_rbf(&btf, &o, &Monitor::new()).unwrap();
    let e = model_error(&m, &btf).unwrap().relative();
    assert!(e < 0.02, "relative error at the samples {e}");
}

#[test]
fn degenerate_inputs_are_documented_fallbacks_or_named_errors() {
    let view = [[0.0, 0.0, 1.0]];
    // One light: the constant.
    let one = [[0.3, 0.1, (0.9f64).sqrt()]];
    let data = vec![0.2f32, 0.4, 0.6, 1.0, 1.0, 1.0];
    let btf = BtfRef::new(1, 2, &view, &one, &data, None).unwrap();
    let m = fit_rbf(&btf, &RbfOptions { components: 2, ..Default::default() }, &Monitor::new()).unwrap();
    let q = m.query([0.0, 0.0, 1.0], [-0.7, 0.0, (0.51f64).sqrt()]);
    let v = m.eval(0, &q);
    for c in 0..3 {
        assert!((v[c] - data[c]).abs() < 1e-5, "{v:?}");
    }
    // A slot without lights borrows the nearest view's lights, and says so; so does a slot with
    // fewer than MIN_LIGHTS.
    let lights = scattered_lights(10, 1);
    let views = [[0.0, 0.0, 1.0], [0.5, 0.0, (0.75f64).sqrt()], [-0.6, 0.0, 0.8]];
    let data: Vec<f32> = (0..3 * 10 * 3).map(|i| 0.1 + (i / 30) as f32).collect();
    let mut mask = vec![true; 30];
    mask[10..20].iter_mut().for_each(|x| *x = false);
    mask[20..27].iter_mut().for_each(|x| *x = false);
    let btf = BtfRef::new(1, 1, &views, &lights, &data, Some(&mask)).unwrap();
    let m = fit_rbf(&btf, &RbfOptions { components: 1, ..Default::default() }, &Monitor::new()).unwrap();
    let slots: Vec<(usize, usize, Vec<usize>)> =
        m.0.pooled.iter().map(|p| (p.slot, p.lights, p.from.clone())).collect();
    assert_eq!(slots, vec![(1, 0, vec![0]), (2, 3, vec![0])]);
    // Slot 1 is the view 0 field (0.1 everywhere); slot 0 keeps its own.
    let q = m.query([0.5, 0.0, (0.75f64).sqrt()], [0.0, 0.0, 1.0]);
    assert!((m.eval(0, &q)[0] - 0.1).abs() < 1e-4);
    assert_eq!(crate::model::Model::report(&m)["pooled_slots"][0]["from"], serde_json::json!([0]));
    // (A BTF without any present pair is rejected by BtfRef::new already.)
    // Duplicate lights without a ridge: a singular kernel, named.
    let dup = [[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.6, 0.0, 0.8]];
    let e = rbf_operator(&dup, &dup, 1.0, 0.0).unwrap_err().to_string();
    assert!(e.contains("singular") && e.contains("positive regularization"), "{e}");
    assert!(rbf_operator(&dup, &dup, 1.0, 1e-3).is_ok());
    // Options.
    let btf1 = BtfRef::new(1, 2, &view, &one, &[0.0; 6], None).unwrap();
    let err = |o: RbfOptions| fit_rbf(&btf1, &o, &Monitor::new()).unwrap_err().to_string();
    assert!(err(RbfOptions { width: 0.0, ..Default::default() }).starts_with("width:"));
    assert!(err(RbfOptions { regularization: -1.0, ..Default::default() }).starts_with("regularization:"));
    assert!(err(RbfOptions { resolution: 40, ..Default::default() }).starts_with("resolution:"));
    assert!(err(RbfOptions { components: 0, ..Default::default() }).starts_with("components:"));
}

#[test]
fn nbytes_counts_the_planes_the_scales_and_the_table() {
    let lights = scattered_lights(30, 1);
    let data = smooth_btf(4, 4, &lights, 2);
    let view = [[0.0, 0.0, 1.0]];
    let btf = BtfRef::new(4, 4, &view, &lights, &data, None).unwrap();
    let m = fit_rbf(&btf, &RbfOptions { components: 5, resolution: 6, ..Default::default() }, &Monitor::new()).unwrap();
    // 16 texels x 5 bytes, 2 x 5 floats, 36 nodes x (3 + 15) floats.
    assert_eq!(crate::model::Model::nbytes(&m), 80 + 40 + 4 * 36 * 18);
    assert_eq!(m.0.planes.q.len(), 80);
}
