use super::decoder::{Activation, Decoder, Directions, Shape};
use super::train::{chunk_grad, Pair, PAIRS};
use super::*;
use btfrs_core::directions::ubo81;
use btfrs_core::rng::Rng;
use btfrs_core::Btf;

fn random_decoder(shape: Shape, seed: u64, gain: f64) -> Decoder {
    let mut rng = Rng::new(seed);
    let n = shape.offsets().len;
    let params = (0..n).map(|_| ((2.0 * rng.next_f64() - 1.0) * gain) as f32).collect();
    Decoder::new(shape, params, "decoder").unwrap()
}

/// A BTF made by a decoder from random codes: what a perfect fit recovers.
fn decoded_btf(dec: &Decoder, size: usize, seed: u64) -> (Btf, Vec<f32>) {
    let views: Vec<[f64; 3]> = ubo81().into_iter().step_by(4).collect();
    let lights = ubo81();
    let k = dec.shape.latents;
    let mut rng = Rng::new(seed);
    let z: Vec<f32> = (0..size * size * k).map(|_| (2.0 * rng.next_f64() - 1.0) as f32).collect();
    let mut data = Vec::with_capacity(size * size * views.len() * lights.len() * 3);
    for t in 0..size * size {
        for &v in &views {
            for &l in &lights {
                // Positive values, as a BTF's: a constant reflectance lifts the decoder's output.
                let y = dec.eval(&z[t * k..(t + 1) * k], &[], v, l);
                let g = dec.shape.directions.gain(l);
                data.extend(y.iter().map(|x| x + g));
            }
        }
    }
    (Btf { height: size, width: size, views, lights, data }, z)
}

#[test]
fn evaluation_with_cached_parts_equals_the_plain_decoder() {
    for directions in [Directions::Light, Directions::Xy, Directions::Half] {
        let shape =
            Shape { latents: 5, directions, features: 3, grid: 4, hidden: 12, activation: Activation::Elu, horizon: 0 };
        let dec = random_decoder(shape, 3, 0.5);
        let z: Vec<f32> = (0..4 * 5).map(|i| (i as f32 * 0.37).sin()).collect();
        let planes = Planes::quantize(&z, 5).unwrap();
        let zq = planes.dequantize();
        // With the cache, and without it (a model too large to keep one: camera captures).
        let cached = Neural::new(2, 2, planes.clone(), None, dec.clone(), serde_json::Value::Null).unwrap();
        assert!(cached.cache.is_some());
        for m in [cached.clone(), cached.without_cache()] {
            let (v, l) = ([0.3, -0.2, (1.0f64 - 0.13).sqrt()], [-0.5, 0.1, (1.0f64 - 0.26).sqrt()]);
            let q = m.query(v, l);
            for t in 0..4 {
                let a = m.eval(t, &q);
                let b = dec.eval(&zq[t * 5..(t + 1) * 5], &[], v, l);
                for c in 0..3 {
                    assert!((a[c] - b[c]).abs() < 1e-5 * (1.0 + b[c].abs()), "{directions:?} {t} {c}: {a:?} vs {b:?}");
                }
            }
        }
    }
}

#[test]
fn gradients_match_central_differences() {
    // The loss of chunk_grad (sum of squared errors / norm) differenced in each decoder
    // parameter and each latent, against the backward pass; float64 differences of a float32
    // forward, so a step of 1e-2 and a loose tolerance on the larger entries.
    for activation in [Activation::Elu, Activation::Relu] {
        let shape =
            Shape { latents: 3, directions: Directions::Half, features: 2, grid: 3, hidden: 6, activation, horizon: 0 };
        let dec = random_decoder(shape, 11, 0.8);
        let (btf, _) = decoded_btf(&random_decoder(shape, 12, 0.8), 2, 5);
        let b = btf.as_ref();
        let nl = b.lights.len();
        let pairs: Vec<Pair> = (0..b.views.len())
            .flat_map(|v| (0..nl).map(move |l| (v, l)))
            .map(|(v, l)| Pair::new(&shape, b.views[v], b.lights[l], (v * nl + l) * 3))
            .collect();
        let texels = [0usize, 3];
        let z = vec![0.3f32, -0.7, 0.5, -0.2, 0.9, 0.1];
        let norm = (texels.len() * PAIRS * 3) as f32;
        let g = chunk_grad(&b, &pairs, &dec, &texels, &z, &[], 0.5, norm, 77, true);
        let loss =
            |d: &Decoder, z: &[f32]| chunk_grad(&b, &pairs, d, &texels, z, &[], 0.5, norm, 77, false).sse / norm as f64;
        let h = 1e-2f32;
        let mut checked = 0;
        let scale = g.dec.iter().fold(0.0f32, |m, x| m.max(x.abs()));
        for i in 0..dec.params.len() {
            let (mut p, mut m) = (dec.clone(), dec.clone());
            p.params[i] += h;
            m.params[i] -= h;
            let fd = (loss(&p, &z) - loss(&m, &z)) / (2.0 * h as f64);
            // ReLU kinks make a few differences meaningless: skip where the two sides disagree
            // with a linear model (second difference large).
            let c = loss(&dec, &z);
            if activation == Activation::Relu && (loss(&p, &z) + loss(&m, &z) - 2.0 * c).abs() > 1e-3 * c.abs() {
                continue;
            }
            assert!(
                (fd - g.dec[i] as f64).abs() < 0.02 * scale as f64 + 0.03 * fd.abs(),
                "{activation:?} param {i}: backward {} vs difference {fd}",
                g.dec[i]
            );
            checked += 1;
        }
        assert!(checked > dec.params.len() / 2, "{checked}");
        for i in 0..z.len() {
            let (mut zp, mut zm) = (z.clone(), z.clone());
            zp[i] += h;
            zm[i] -= h;
            let fd = (loss(&dec, &zp) - loss(&dec, &zm)) / (2.0 * h as f64);
            assert!(
                (fd - g.dz[i] as f64).abs() < 0.02 * scale as f64 + 0.05 * fd.abs(),
                "latent {i}: {} vs {fd}",
                g.dz[i]
            );
        }
    }
}

/// Data of `size^2` texels made by a small random decoder (4 latents, 16 hidden units, the
/// half-vector encoding with tables of 4 features) from random codes, and the options of a fit
/// of that shape.
fn small_decoded_fit(size: usize) -> (Btf, NeuralOptions) {
    let shape = Shape {
        latents: 4,
        directions: Directions::Half,
        features: 4,
        grid: 6,
        hidden: 16,
        activation: Activation::Elu,
        horizon: 0,
    };
    let (btf, _) = decoded_btf(&random_decoder(shape, 21, 0.6), size, 9);
    let o =
        NeuralOptions { latents: 4, hidden: 16, features: Some(4), grid: 6, steps: Some(1500), ..Default::default() };
    (btf, o)
}

#[test]
fn training_recovers_data_made_by_a_decoder() {
    // A BTF made by a random decoder of the same shape from random codes: the fit must explain
    // it far better than its mean does, with the 8-bit codes it stores, and on held-out pairs.
    let (btf, o) = small_decoded_fit(8);
    let b = btf.as_ref();
    let m = fit_neural(&b, &o, &Monitor::new()).unwrap();
    let e = crate::model::model_error(&m, &b).unwrap();
    let rel = (e.sse / e.sgt).sqrt();
    let mean = b.data.iter().map(|&x| x as f64).sum::<f64>() / b.data.len() as f64;
    let spread = (b.data.iter().map(|&x| (x as f64 - mean).powi(2)).sum::<f64>() / e.sgt).sqrt();
    assert!(rel < 0.1 * spread, "relative error {rel} vs the data's spread {spread}");
    let r = m.report();
    assert!(r["validation_error_8bit"].as_f64().unwrap() < 0.15 * spread, "{r}");
    assert_eq!(r["directions"], "half");
}

#[test]
fn a_seed_gives_one_model() {
    let btf = btfrs_core::materials::generate(
        &btfrs_core::materials::MaterialSpec::new(btfrs_core::materials::Preset::Bumps, 8, 1),
        &Monitor::new(),
    )
    .unwrap();
    let o = NeuralOptions { latents: 2, hidden: 8, steps: Some(60), ..Default::default() };
    let a = fit_neural(&btf.as_ref(), &o, &Monitor::new()).unwrap();
    let b = fit_neural(&btf.as_ref(), &o, &Monitor::new()).unwrap();
    assert_eq!(a, b);
    let c = fit_neural(&btf.as_ref(), &NeuralOptions { seed: 1, ..o }, &Monitor::new()).unwrap();
    assert_ne!(a, c);
}

#[test]
fn bad_arrays_and_options_are_named() {
    let shape = Shape {
        latents: 3,
        directions: Directions::Xy,
        features: 2,
        grid: 4,
        hidden: 8,
        activation: Activation::Relu,
        horizon: 0,
    };
    let z: Vec<f32> = (0..4 * 3).map(|i| i as f32).collect();
    let m = Neural::new(
        2,
        2,
        Planes::quantize(&z, 3).unwrap(),
        None,
        random_decoder(shape, 1, 1.0),
        serde_json::Value::Null,
    )
    .unwrap();
    let a = m.to_arrays();
    assert_eq!(Neural::from_arrays(&a).unwrap(), m);
    let mut short = a.clone();
    short.put("decoder", &[10], vec![0.0f32; 10]);
    let e = Neural::from_arrays(&short).unwrap_err().to_string();
    assert!(e.contains("decoder") && e.contains("expected"), "{e}");
    let mut nan = a.clone();
    let mut p = m.decoder().params.clone();
    p[4] = f32::NAN;
    nan.put("decoder", &[p.len()], p);
    assert!(Neural::from_arrays(&nan).unwrap_err().to_string().contains("not finite"));
    let mut arch = a.clone();
    arch.put("architecture", &[6], vec![3i32, 8, 7, 1, 2, 4]);
    assert!(Neural::from_arrays(&arch).unwrap_err().to_string().contains("direction encoding"));
    let mut wide = a;
    wide.put("architecture", &[6], vec![3i32, 12, 1, 1, 2, 4]);
    assert!(Neural::from_arrays(&wide).unwrap_err().to_string().contains("decoder"));

    // Options: fewer pairs than latents; "light" on a multi-view BTF; learning rate.
    let btf = btfrs_core::materials::generate(
        &btfrs_core::materials::MaterialSpec::new(btfrs_core::materials::Preset::Bumps, 8, 1),
        &Monitor::new(),
    )
    .unwrap();
    let b = btf.as_ref();
    let mut mask = vec![false; b.views.len() * b.lights.len()];
    mask[..5].iter_mut().for_each(|x| *x = true);
    let masked = BtfRef { mask: Some(&mask), ..b };
    let e = fit_neural(&masked, &NeuralOptions { latents: 8, ..Default::default() }, &Monitor::new()).unwrap_err();
    assert!(e.to_string().starts_with("latents: expected at most"), "{e}");
    let e = fit_neural(&b, &NeuralOptions { directions: "light".into(), ..Default::default() }, &Monitor::new())
        .unwrap_err();
    assert!(e.to_string().starts_with("directions: expected"), "{e}");
    let e = fit_neural(&b, &NeuralOptions { learning_rate: 0.5, ..Default::default() }, &Monitor::new()).unwrap_err();
    assert!(e.to_string().starts_with("learning_rate: expected"), "{e}");
}

/// A half's value (bits as `gpu_dense` and `gpu_tables` pack them, two to a word, low first).
fn half_at(words: &[u32], i: usize) -> f32 {
    half::f16::from_bits((words[i / 2] >> (16 * (i % 2))) as u16).to_f32()
}

#[test]
fn the_renderers_halves_hold_every_parameter_where_the_shader_reads_it() {
    // Decoded here from the layout neural.wgsl reads: rows of vectors of eight halves, the
    // output layer divided by the output scale, tables with each node padded to an even count.
    let shapes = [
        Shape {
            latents: 5,
            directions: Directions::Half,
            features: 3,
            grid: 4,
            hidden: 12,
            activation: Activation::Elu,
            horizon: 0,
        },
        Shape {
            latents: 2,
            directions: Directions::Light,
            features: 0,
            grid: 2,
            hidden: 4,
            activation: Activation::Elu,
            horizon: 0,
        },
        Shape {
            latents: MAX_LATENTS,
            directions: Directions::Half,
            features: MAX_FEATURES,
            grid: 3,
            hidden: MAX_HIDDEN,
            activation: Activation::Relu,
            horizon: 0,
        },
    ];
    for (si, sh) in shapes.into_iter().enumerate() {
        let mut dec = random_decoder(sh, 7 + si as u64, 0.7);
        let o = sh.offsets();
        // The output layer on a large scale, as a BTF of radiances.
        dec.params[o.w3..o.tables].iter_mut().for_each(|x| *x *= 3.0e6);
        let dec = Decoder::new(sh, dec.params, "decoder").unwrap();
        let (c, t) = (dec.gpu_dense(), dec.gpu_tables());
        let (n, h) = (sh.inputs(), sh.hidden);
        let (n8, h8) = (n.div_ceil(8), h.div_ceil(8));
        let s = dec.output_scale();
        let mut at = 0; // in halves
        let mut row = |len: usize, from: usize, scale: f32, padded: usize| {
            for i in 0..padded {
                let want = if i < len { dec.params[from + i] / scale } else { 0.0 };
                assert_eq!(half_at(&c, at + i), want, "shape {si}, parameter {} of a row", from + i);
            }
            at += padded;
        };
        (0..h).for_each(|j| row(n, o.w1 + j * n, 1.0, 8 * n8));
        row(h, o.b1, 1.0, 8 * h8);
        (0..h).for_each(|j| row(h, o.w2 + j * h, 1.0, 8 * h8));
        row(h, o.b2, 1.0, 8 * h8);
        (0..3).for_each(|j| row(h, o.w3 + j * h, s, 8 * h8));
        row(3, o.b3, s, 8);
        assert_eq!(2 * c.len(), at, "shape {si}");
        assert!(c.len() <= 4 * GPU_CONSTANTS, "shape {si}: {} words", c.len());
        if si == 2 {
            assert_eq!(c.len(), 4 * GPU_CONSTANTS, "the largest decoder fills the declared block");
        }
        let (f, fp) = (sh.features, sh.features.next_multiple_of(2));
        let nodes = sh.tables() * sh.grid * sh.grid;
        assert_eq!(2 * t.len(), nodes * fp, "shape {si}");
        for node in 0..nodes {
            for ch in 0..fp {
                let want = if ch < f { dec.params[o.tables + node * f + ch] } else { 0.0 };
                assert_eq!(half_at(&t, node * fp + ch), want, "shape {si}, node {node}, channel {ch}");
            }
        }
    }
}

#[test]
fn decoder_parameters_are_halves_and_the_output_layer_keeps_the_datas_scale() {
    let sh = Shape {
        latents: 3,
        directions: Directions::Xy,
        features: 2,
        grid: 3,
        hidden: 8,
        activation: Activation::Relu,
        horizon: 0,
    };
    let o = sh.offsets();
    let mut rng = Rng::new(5);
    let raw: Vec<f32> = (0..o.len)
        .map(|i| {
            let x = (2.0 * rng.next_f64() - 1.0) as f32;
            if (o.w3..o.tables).contains(&i) {
                x * 2.5e7
            } else {
                x
            }
        })
        .collect();
    let dec = Decoder::new(sh, raw.clone(), "decoder").unwrap();
    let s = dec.output_scale();
    assert_eq!(s, 2f32.powi(s.log2() as i32), "a power of two");
    let m = dec.params[o.w3..o.tables].iter().fold(0.0f32, |m, x| m.max(x.abs()));
    assert!((16384.0..32768.0).contains(&(m / s)), "largest output value {m} over {s}");
    for (i, (&r, &x)) in raw.iter().zip(&dec.params).enumerate() {
        let scale = if (o.w3..o.tables).contains(&i) { s } else { 1.0 };
        let y = x / scale;
        // Exactly a half, and the nearest one (within half a step of 2^-11 relative, or of the
        // subnormal step).
        assert_eq!(half::f16::from_f32(y).to_f32(), y, "parameter {i}");
        let tol = (r.abs() / scale * 2f32.powi(-11)).max(2f32.powi(-25)) * scale;
        assert!((r - x).abs() <= tol, "parameter {i}: {r} -> {x}");
    }
    // Rounding again changes nothing.
    assert_eq!(Decoder::new(sh, dec.params.clone(), "decoder").unwrap(), dec);
    let mut big = raw;
    big[o.w2] = 1.0e5;
    let e = Decoder::new(sh, big, "decoder").unwrap_err().to_string();
    assert!(e.contains(&format!("decoder parameter {} (100000)", o.w2)) && e.contains("half precision"), "{e}");
}

#[test]
fn fast_exp_is_within_its_stated_error() {
    // Every 1/64 from -87 to 88, and the elu of training against evaluation's.
    let mut worst = 0.0f64;
    let mut x = -87.0f32;
    while x <= 88.0 {
        let (a, b) = (super::decoder::exp_fast(x) as f64, (x as f64).exp());
        worst = worst.max((a - b).abs() / b);
        x += 1.0 / 64.0;
    }
    assert!(worst < 3e-7, "{worst}");
    let mut v: Vec<f32> = (-400..400).map(|i| i as f32 / 37.0).collect();
    let mut w = v.clone();
    Activation::Elu.apply_fast(&mut v);
    Activation::Elu.apply(&mut w);
    assert!(v.iter().zip(&w).all(|(a, b)| (a - b).abs() <= 3e-7 * (1.0 + b.abs())));
}

/// A small random relief's horizon map over `rows x cols` texels.
fn random_horizons(rows: usize, cols: usize, components: usize, seed: u64) -> crate::relief::HorizonMap {
    let mut rng = Rng::new(seed);
    let z = (0..rows * cols).map(|_| (rng.next_f64() * 3.0) as f32).collect();
    let h = crate::relief::Height { rows, cols, z };
    crate::relief::HorizonMap::build(&h, 1.0, components, &Monitor::new()).unwrap()
}

#[test]
fn evaluation_with_a_horizon_map_equals_the_plain_decoder() {
    // The cached evaluation (latent part per texel, query part per pair, clearances per texel)
    // against the reference form fed the texel's rebuilt horizon row.
    for directions in [Directions::Light, Directions::Half] {
        let shape = Shape {
            latents: 4,
            directions,
            features: if directions == Directions::Light { 0 } else { 3 },
            grid: 4,
            hidden: 12,
            activation: Activation::Elu,
            horizon: crate::relief::BINS,
        };
        assert_eq!(shape.clearances(), if directions == Directions::Light { 1 } else { 2 });
        let dec = random_decoder(shape, 4, 0.5);
        let z: Vec<f32> = (0..9 * 4).map(|i| (i as f32 * 0.41).cos()).collect();
        let planes = Planes::quantize(&z, 4).unwrap();
        let zq = planes.dequantize();
        let map = random_horizons(3, 3, 5, 8);
        let m = Neural::new(3, 3, planes, Some(map.clone()), dec.clone(), serde_json::Value::Null).unwrap();
        let mut row = vec![0.0f32; map.bins];
        for (v, l) in [([0.0, 0.0, 1.0], [0.6, 0.3, 0.74]), ([0.3, -0.2, 0.93], [-0.7, -0.5, 0.51])] {
            let (v, l) = (unit(v), unit(l));
            let q = m.query(v, l);
            for t in 0..9 {
                map.row(t, &mut row);
                let a = m.eval(t, &q);
                let b = dec.eval(&zq[t * 4..(t + 1) * 4], &row, v, l);
                for c in 0..3 {
                    assert!((a[c] - b[c]).abs() < 1e-5 * (1.0 + b[c].abs()), "{directions:?} {t}: {a:?} vs {b:?}");
                }
            }
        }
        // The clearances matter: a row raised far above every light darkens nothing only if
        // the decoder ignored them.
        let high = vec![1.5f32; map.bins];
        let (v, l) = ([0.0, 0.0, 1.0], unit([0.6, 0.3, 0.74]));
        assert_ne!(dec.eval(&zq[..4], &high, v, l), dec.eval(&zq[..4], &row, v, l));
        // The arrays round-trip, the map included.
        assert_eq!(Neural::from_arrays(&m.to_arrays()).unwrap(), m);
    }
}

fn unit(d: [f64; 3]) -> [f64; 3] {
    let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    d.map(|x| x / n)
}

#[test]
fn gradients_match_central_differences_with_clearances() {
    // As above, with horizon rows: the clearance columns of layer 1 get their gradients too.
    let shape = Shape {
        latents: 3,
        directions: Directions::Half,
        features: 2,
        grid: 3,
        hidden: 6,
        activation: Activation::Elu,
        horizon: crate::relief::BINS,
    };
    let dec = random_decoder(shape, 13, 0.8);
    let (btf, _) = decoded_btf(&random_decoder(Shape { horizon: 0, ..shape }, 14, 0.8), 2, 6);
    let b = btf.as_ref();
    let nl = b.lights.len();
    let pairs: Vec<Pair> = (0..b.views.len())
        .flat_map(|v| (0..nl).map(move |l| (v, l)))
        .map(|(v, l)| Pair::new(&shape, b.views[v], b.lights[l], (v * nl + l) * 3))
        .collect();
    let texels = [1usize, 2];
    let mut rng = Rng::new(3);
    let hz: Vec<f32> = (0..texels.len() * shape.horizon).map(|_| (rng.next_f64() * 0.8) as f32).collect();
    let z = vec![0.2f32, -0.5, 0.4, -0.3, 0.8, 0.2];
    let norm = (texels.len() * PAIRS * 3) as f32;
    let g = chunk_grad(&b, &pairs, &dec, &texels, &z, &hz, 0.5, norm, 91, true);
    let loss =
        |d: &Decoder, z: &[f32]| chunk_grad(&b, &pairs, d, &texels, z, &hz, 0.5, norm, 91, false).sse / norm as f64;
    let h = 1e-2f32;
    let scale = g.dec.iter().fold(0.0f32, |m, x| m.max(x.abs()));
    let ni = shape.inputs();
    let first = shape.latents + shape.directions.dims();
    let mut clearance_checked = 0;
    for i in 0..dec.params.len() {
        let (mut p, mut m) = (dec.clone(), dec.clone());
        p.params[i] += h;
        m.params[i] -= h;
        let fd = (loss(&p, &z) - loss(&m, &z)) / (2.0 * h as f64);
        assert!(
            (fd - g.dec[i] as f64).abs() < 0.02 * scale as f64 + 0.03 * fd.abs(),
            "param {i}: backward {} vs difference {fd}",
            g.dec[i]
        );
        let col = i % ni;
        if i < shape.hidden * ni && (first..first + 2).contains(&col) && fd.abs() > 1e-4 {
            clearance_checked += 1;
        }
    }
    assert!(clearance_checked >= 4, "{clearance_checked}");
    for i in 0..z.len() {
        let (mut zp, mut zm) = (z.clone(), z.clone());
        zp[i] += h;
        zm[i] -= h;
        let fd = (loss(&dec, &zp) - loss(&dec, &zm)) / (2.0 * h as f64);
        assert!((fd - g.dz[i] as f64).abs() < 0.02 * scale as f64 + 0.05 * fd.abs(), "latent {i}: {} vs {fd}", g.dz[i]);
    }
}

#[test]
fn a_sample_without_a_view_for_its_relief_fits_without_the_horizon_map() {
    // Grazing pairs only (view and light both at least 45 degrees off the normal): no view slot
    // keeps the lights photometric stereo needs near the top, as in the stability suite's
    // grazing regime. The default fits without clearances and says why; a horizon map asked for
    // explicitly is refused, naming the cause.
    let btf = btfrs_core::materials::generate(
        &btfrs_core::materials::MaterialSpec::new(btfrs_core::materials::Preset::Grooves, 8, 0),
        &Monitor::new(),
    )
    .unwrap();
    let b = btf.as_ref();
    let nl = b.lights.len();
    let grazing = |d: [f64; 3]| d[2] <= std::f64::consts::FRAC_PI_4.cos();
    let mask: Vec<bool> =
        (0..b.views.len() * nl).map(|i| grazing(b.views[i / nl]) && grazing(b.lights[i % nl])).collect();
    // The premise: every view slot with at least RELIEF_MIN_LIGHTS present lights is grazing,
    // and the frontal one has none.
    assert!(!mask[..nl].iter().any(|&x| x));
    let masked = BtfRef { mask: Some(&mask), ..b };
    let o = NeuralOptions { latents: 2, hidden: 8, steps: Some(60), ..Default::default() };
    match relief_view(&masked) {
        None => {
            let m = fit_neural(&masked, &o, &Monitor::new()).unwrap();
            assert!(m.horizon().is_none() && m.decoder().shape.horizon == 0);
            let why = m.report["horizon_skipped"].as_str().unwrap();
            assert!(why.contains("photometric stereo"), "{why}");
            assert_eq!(m.report["horizon"], 0);
        }
        Some(v) => assert!(grazing(masked.views[v]), "relief measured in a non-grazing slot {v}"),
    }
    // Explicitly asked for: an error, not a silent model without it.
    let all_off = vec![false; b.views.len() * nl];
    let mut few = all_off.clone();
    few[..4].iter_mut().for_each(|x| *x = true); // view 0, 4 lights
    let sparse = BtfRef { mask: Some(&few), ..b };
    let e =
        fit_neural(&sparse, &NeuralOptions { horizon: Some(8), latents: 2, ..o.clone() }, &Monitor::new()).unwrap_err();
    assert!(e.to_string().contains("present lights"), "{e}");
    let m = fit_neural(&sparse, &NeuralOptions { latents: 2, ..o }, &Monitor::new()).unwrap();
    assert!(m.horizon().is_none() && m.report["horizon_skipped"].is_string());
}

#[test]
fn a_fit_on_a_sample_encodes_the_texels_it_did_not_train_on() {
    // Data made by a decoder from random codes, fitted on a sample of half its texels:
    // the encoder's codes must explain the other texels nearly as well as the sample's, and the
    // whole capture nearly as well as a fit trained on every texel.
    let (btf, o) = small_decoded_fit(16);
    let b = btf.as_ref();
    let sampled = fit_neural(&b, &NeuralOptions { train_texels: Some(128), ..o.clone() }, &Monitor::new()).unwrap();
    let r = sampled.report();
    assert_eq!(r["sample_texels"], 128, "{r}");
    let sample = encoder::sample_texels(b.texels(), 128, o.seed);
    let error_of = |m: &Neural, texels: &mut dyn Iterator<Item = usize>| -> f64 {
        let (mut sse, mut sgt) = (0.0f64, 0.0f64);
        let nl = b.lights.len();
        for t in texels {
            for (v, &view) in b.views.iter().enumerate() {
                for (l, &light) in b.lights.iter().enumerate() {
                    let y = m.eval(t, &m.query(view, light));
                    let gt = &b.texel(t)[(v * nl + l) * 3..][..3];
                    for c in 0..3 {
                        sse += (y[c] as f64 - gt[c] as f64).powi(2);
                        sgt += (gt[c] as f64).powi(2);
                    }
                }
            }
        }
        (sse / sgt).sqrt()
    };
    let unseen = error_of(&sampled, &mut (0..b.texels()).filter(|t| sample.binary_search(t).is_err()).step_by(5));
    let seen = error_of(&sampled, &mut sample.iter().copied().step_by(5));
    let full = fit_neural(&b, &o, &Monitor::new()).unwrap();
    let all = error_of(&full, &mut (0..b.texels()).step_by(10));
    let mean = b.data.iter().map(|&x| x as f64).sum::<f64>() / b.data.len() as f64;
    let ss = b.data.iter().map(|&x| (x as f64).powi(2)).sum::<f64>();
    let spread = (b.data.iter().map(|&x| (x as f64 - mean).powi(2)).sum::<f64>() / ss).sqrt();
    // Measured: 0.090 on the texels not trained on, 0.083 on the sample, 0.071 for the fit on
    // every texel, against a spread of 0.86.
    assert!(unseen < 1.3 * seen.max(0.02 * spread), "texels not trained on {unseen} vs the sample's {seen}");
    assert!(unseen < 0.12 * spread, "texels not trained on {unseen} vs the data's spread {spread}");
    assert!(unseen < 1.6 * all.max(0.02 * spread), "sampled fit {unseen} vs a fit on every texel {all}");
    let e = &r["encoder"];
    assert!(e["error"].as_f64().unwrap() <= e["error_after_regression"].as_f64().unwrap() + 1e-12, "{e}");
}

#[test]
fn a_capture_beyond_train_texels_trains_on_a_sample_within_the_memory_limit() {
    let (views, lights) = (vec![[0.0, 0.0, 1.0]], ubo81());
    let data = vec![0.5f32; 10 * 20 * lights.len() * 3];
    let b = BtfRef::new(10, 20, &views, &lights, &data, None).unwrap();
    let o = NeuralOptions::default();
    assert_eq!(sample_size(&b, &o, &Monitor::new()), None);
    assert_eq!(sample_size(&b, &NeuralOptions { train_texels: Some(200), ..o.clone() }, &Monitor::new()), None);
    assert_eq!(sample_size(&b, &NeuralOptions { train_texels: Some(100), ..o.clone() }, &Monitor::new()), Some(100));
    // Fewer than a run: one run.
    assert_eq!(sample_size(&b, &NeuralOptions { train_texels: Some(10), ..o.clone() }, &Monitor::new()), Some(64));
    // Values beyond the memory limit alone do not make a sample (the fit reads them in place);
    // a sample holds a quarter of the limit at most.
    let limited = Monitor::new();
    let texel = lights.len() * 3 * 4;
    limited.set_memory_limit(Some((4 * 80 * texel) as u64));
    assert_eq!(sample_size(&b, &o, &limited), None);
    assert_eq!(sample_size(&b, &NeuralOptions { train_texels: Some(100), ..o.clone() }, &limited), Some(80));
}

#[test]
fn the_relief_of_blocks_gives_every_texel_its_blocks_horizons() {
    // grooves 24^2 from above under the UBO lights, measured on blocks of 2 x 2: the block
    // values are the texels' grey means, and the map is constant over each block.
    let spec = btfrs_core::materials::MaterialSpec {
        views: vec![[0.0, 0.0, 1.0]],
        ..btfrs_core::materials::MaterialSpec::new(btfrs_core::materials::Preset::Grooves, 24, 1)
    };
    let btf = btfrs_core::materials::generate(&spec, &Monitor::new()).unwrap();
    let b = btf.as_ref();
    let blocks = crate::relief::blocks_of(&b, 0, 2, &Monitor::new()).unwrap();
    assert_eq!((blocks.rows, blocks.cols), (12, 12));
    let nl = b.lights.len();
    for (br, bc, l) in [(0, 0, 0), (5, 7, 40), (11, 11, 80)] {
        let mut sum = 0.0f64;
        for (r, c) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
            let v = b.texel((2 * br + r) * 24 + 2 * bc + c);
            sum += (v[3 * l] as f64 + v[3 * l + 1] as f64 + v[3 * l + 2] as f64) / 3.0;
        }
        let got = &blocks.data[((br * 12 + bc) * nl + l) * 3..][..3];
        assert!(got.iter().all(|&g| (g as f64 - sum / 4.0).abs() < 1e-5), "{got:?} vs {}", sum / 4.0);
    }
    let mut extra = serde_json::Map::new();
    let map = relief_in_blocks(&b, &NeuralOptions::default(), &Monitor::new(), &mut extra, 2).unwrap().unwrap();
    assert_eq!(extra["horizon_block"], 2);
    assert_eq!(map.coeffs.texels, 24 * 24);
    let rows = map.rows(&(0..24 * 24).collect::<Vec<_>>());
    let bins = map.bins;
    for t in [0usize, 5 * 24 + 9, 24 * 24 - 1] {
        let (r, c) = (t / 24, t % 24);
        let first = ((r / 2 * 2) * 24 + c / 2 * 2) * bins;
        assert_eq!(&rows[t * bins..(t + 1) * bins], &rows[first..first + bins]);
    }
    // The grooves cast shadows: some block sees a horizon above the floor.
    assert!(rows.iter().any(|&h| h > 0.05), "{extra:?}");
}
