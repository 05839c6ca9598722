#![allow(clippy::needless_range_loop)] // index loops mirror the formulas being checked
use super::*;
use crate::model::{model_error, ReflectanceModel};
use crate::rbf::tests::{scattered_lights, smooth_btf};
use btfrs_core::rng::Rng;

fn square_lights(n: usize, seed: u64) -> (Vec<[f64; 3]>, Vec<[f64; 2]>) {
    let mut rng = Rng::new(seed);
    let st: Vec<[f64; 2]> = (0..n).map(|_| [rng.next_f64(), rng.next_f64()]).collect();
    let l = st.iter().map(|p| btfrs_hemimap::square_to_hemisphere(p[0], p[1])).collect();
    // The square points of the directions (not st itself: the horizon folds a little).
    let st = st
        .iter()
        .map(|p| btfrs_hemimap::hemisphere_to_square(btfrs_hemimap::square_to_hemisphere(p[0], p[1])))
        .collect();
    (l, st)
}

#[test]
fn a_bilinear_function_of_the_square_is_recovered_at_any_regularization() {
    // f = a + b s + c t + d s t has zero second differences: the fit returns its node values.
    let n = 6;
    let (lights, _) = square_lights(50, 1);
    let f = |s: f64, t: f64| 0.3 + 0.5 * s - 0.2 * t + 0.7 * s * t;
    let y: Vec<f64> = lights
        .iter()
        .map(|&l| {
            let [s, t] = btfrs_hemimap::hemisphere_to_square(l);
            f(s, t)
        })
        .collect();
    for reg in [1e-3, 0.1, 10.0] {
        let w = bilinear_operator(&lights, n, reg, Penalty::Thin).unwrap();
        for node in 0..n * n {
            let (s, t) = ((node % n) as f64 / 5.0, (node / n) as f64 / 5.0);
            let g: f64 = (0..50).map(|j| w[(node, j)] * y[j]).sum();
            assert!((g - f(s, t)).abs() < 1e-5, "reg {reg} node {node}: {g} vs {}", f(s, t));
        }
    }
}

#[test]
fn any_grid_function_is_recovered_from_dense_samples_without_regularization() {
    // Exactly bilinear on the grid (arbitrary node values), sampled densely: lambda -> 0 gives
    // the node values back.
    let n = 5;
    let mut rng = Rng::new(7);
    let g: Vec<f64> = (0..n * n).map(|_| rng.next_f64()).collect();
    let (lights, _) = square_lights(2000, 2);
    let y: Vec<f64> =
        lights.iter().map(|&l| light_pca::grid_weights(n, l).iter().map(|&(k, w)| w * g[k]).sum()).collect();
    let w = bilinear_operator(&lights, n, 1e-10, Penalty::Thin).unwrap();
    for node in 0..n * n {
        let x: f64 = (0..lights.len()).map(|j| w[(node, j)] * y[j]).sum();
        assert!((x - g[node]).abs() < 1e-4, "node {node}: {x} vs {}", g[node]);
    }
}

#[test]
fn data_generated_from_the_model_is_fitted_to_quantization_error() {
    // Every texel a combination of 3 grid functions (plus a mean) on the model's own grid and
    // lights: the model family itself. With 3 components the error is the 8-bit quantization.
    let (n, tex) = (6, 40);
    let mut rng = Rng::new(3);
    let funcs: Vec<Vec<f64>> = (0..4).map(|_| (0..n * n).map(|_| rng.next_f64()).collect()).collect();
    let (lights, _) = square_lights(600, 4);
    let mut data = vec![0.0f32; tex * lights.len() * 3];
    for t in 0..tex {
        let a: Vec<f64> = (0..9).map(|_| rng.next_f64() - 0.5).collect();
        for (l, &d) in lights.iter().enumerate() {
            let wts = light_pca::grid_weights(n, d);
            let val = |f: &Vec<f64>| wts.iter().map(|&(k, w)| w * f[k]).sum::<f64>();
            for c in 0..3 {
                data[(t * lights.len() + l) * 3 + c] = (val(&funcs[0])
                    + a[3 * c] * val(&funcs[1])
                    + a[3 * c + 1] * val(&funcs[2])
                    + a[3 * c + 2] * val(&funcs[3])) as f32;
            }
        }
    }
    let view = [[0.0, 0.0, 1.0]];
    let btf = BtfRef::new(8, 5, &view, &lights, &data, None).unwrap();
    let o = BilinearOptions { components: 9, resolution: n, regularization: 1e-8, ..Default::default() };
    let m = fit_bilinear(&btf, &o, &Monitor::new()).unwrap();
    let e = model_error(&m, &btf).unwrap().relative();
    assert!(e < 0.01, "relative error {e}");
    // Too few components leave a clear error.
    let m = fit_bilinear(&btf, &BilinearOptions { components: 2, ..o }, &Monitor::new()).unwrap();
    assert!(model_error(&m, &btf).unwrap().relative() > 3.0 * e);
}

#[test]
fn held_out_lights_on_a_smooth_capture() {
    let lights = scattered_lights(180, 11);
    let data = smooth_btf(5, 5, &lights, 3);
    let view = [[0.0, 0.0, 1.0]];
    let (train, test) = btfrs_core::split::split_pairs(1, 180, None, 0.15, 1).unwrap();
    let btf = BtfRef::new(5, 5, &view, &lights, &data, Some(&train)).unwrap();
    let m =
        fit_bilinear(&btf, &BilinearOptions { components: 12, resolution: 10, ..Default::default() }, &Monitor::new())
            .unwrap();
    let held = BtfRef::new(5, 5, &view, &lights, &data, Some(&test)).unwrap();
    let e = model_error(&m, &held).unwrap().relative();
    assert!(e < 0.05, "held-out relative error {e} (fallbacks {:?})", m.0.fallback_slots);
}

#[test]
fn few_lights_fall_back_to_the_mean_and_bad_options_are_named() {
    let view = [[0.0, 0.0, 1.0]];
    let one = [[0.3, 0.1, (0.9f64).sqrt()]];
    let data = vec![0.2f32, 0.4, 0.6];
    let btf = BtfRef::new(1, 1, &view, &one, &data, None).unwrap();
    let m = fit_bilinear(&btf, &BilinearOptions { components: 1, ..Default::default() }, &Monitor::new()).unwrap();
    let v = m.eval(0, &m.query([0.0, 0.0, 1.0], [-0.6, 0.6, (0.28f64).sqrt()]));
    for c in 0..3 {
        assert!((v[c] - data[c]).abs() < 1e-4, "{v:?}");
    }
    let e = fit_bilinear(&btf, &BilinearOptions { regularization: f64::NAN, ..Default::default() }, &Monitor::new())
        .unwrap_err()
        .to_string();
    assert!(e.starts_with("regularization:"), "{e}");
    let e = fit_bilinear(&btf, &BilinearOptions { chroma_components: Some(2), ..Default::default() }, &Monitor::new())
        .unwrap_err()
        .to_string();
    assert!(e.starts_with("chroma_components:"), "{e}");
}

#[test]
fn one_sided_lights_fall_back_to_the_bounded_membrane() {
    // Lights on one azimuth half: the thin-plate grid extrapolates into the other half; the slot
    // falls back to the membrane, whose predictions are convex-like combinations (bounded).
    let all = btfrs_core::directions::ubo81();
    let half: Vec<[f64; 3]> = all.iter().copied().filter(|l| l[1] >= 0.0).collect();
    let (w, fell) = slot_operator(&half, 8, 0.1, &all).unwrap();
    let a = fell.expect("the one-sided slot falls back");
    assert!(a > K_AMP, "{a}");
    assert!(amplification(&w, 8, &all) < 3.0);
    // A membrane fit of a constant is the constant, and its weights sum to 1 at every query.
    let b = bilinear_operator(&half, 8, 1.0, Penalty::Membrane).unwrap();
    for l in &all {
        let s: f64 = (0..half.len())
            .map(|j| light_pca::grid_weights(8, *l).iter().map(|&(k, x)| x * b[(k, j)]).sum::<f64>())
            .sum();
        assert!((s - 1.0).abs() < 1e-6, "{s}");
    }
    // The full UBO sampling keeps the second differences.
    assert!(slot_operator(&all, 8, 0.1, &all).unwrap().1.is_none());
    // Through the model: the report lists the slot.
    let view = [[0.0, 0.0, 1.0]];
    let data = vec![0.5f32; 81 * 3];
    let mask: Vec<bool> = all.iter().map(|l| l[1] >= 0.0).collect();
    let btf = BtfRef::new(1, 1, &view, &all, &data, Some(&mask)).unwrap();
    let m = fit_bilinear(&btf, &BilinearOptions { components: 1, ..Default::default() }, &Monitor::new()).unwrap();
    assert_eq!(m.0.fallback_slots.len(), 1);
    assert_eq!(crate::model::Model::report(&m)["fallback_slots"][0]["slot"], 0);
}
