use super::*;

/// `n` directions on a golden-angle spiral, elevations `lo` to `hi` degrees (the texel tests'
/// too).
pub(super) fn spiral(n: usize, lo: f64, hi: f64, turn: f64) -> Vec<[f64; 3]> {
    (0..n)
        .map(|i| {
            let el = (lo + (hi - lo) * i as f64 / n as f64).to_radians();
            let az = 2.399963 * i as f64 + turn;
            [el.cos() * az.cos(), el.cos() * az.sin(), el.sin()]
        })
        .collect()
}

/// A BTF made by a known model (3 x 4 texels), and the model.
fn made(views: &[[f64; 3]], lights: &[[f64; 3]]) -> (Svbrdf, Vec<f32>) {
    let (h, w) = (3, 4);
    let mut m = Svbrdf {
        height: h,
        width: w,
        diffuse: Vec::new(),
        specular: Vec::new(),
        roughness: Vec::new(),
        normal: Vec::new(),
        report: serde_json::Value::Null,
    };
    for t in 0..h * w {
        let f = t as f32 / 12.0;
        m.diffuse.extend([0.2 + 0.3 * f, 0.3, 0.4 - 0.2 * f]);
        m.specular.extend([0.1 + 0.2 * f; 3]);
        m.roughness.push(0.08 + 0.3 * f);
        let n = lobe::normal_of(0.3 * f as f64 - 0.1, 0.2 - 0.25 * f as f64);
        m.normal.extend(n.map(|x| x as f32));
    }
    let mut data = Vec::new();
    for t in 0..h * w {
        for v in views {
            for l in lights {
                data.extend(m.eval(t, &m.query(*v, *l)));
            }
        }
    }
    (m, data)
}

#[test]
fn a_btf_made_by_the_model_gives_the_model_back() {
    let views = spiral(6, 10.0, 70.0, 0.4);
    let mut views = views;
    views.insert(0, [0.0, 0.0, 1.0]);
    let lights = spiral(30, 15.0, 85.0, 1.3);
    let (truth, data) = made(&views, &lights);
    let b = BtfRef { height: 3, width: 4, views: &views, lights: &lights, data: &data, mask: None };
    let got =
        fit_svbrdf(&b, &SvbrdfOptions { max_pairs: 1024, seed: 0, normals: "fit".into() }, &Monitor::new()).unwrap();
    for t in 0..12 {
        assert!((got.roughness[t] - truth.roughness[t]).abs() < 1e-3 * truth.roughness[t], "texel {t}: {got:?}");
        for c in 0..3 {
            assert!((got.diffuse[3 * t + c] - truth.diffuse[3 * t + c]).abs() < 1e-4, "texel {t}");
            assert!((got.specular[3 * t + c] - truth.specular[3 * t + c]).abs() < 1e-3, "texel {t}");
            assert!((got.normal[3 * t + c] - truth.normal[3 * t + c]).abs() < 1e-4, "texel {t}");
        }
    }
    // The round trip through the arrays.
    let back = Svbrdf::from_arrays(&got.to_arrays()).unwrap();
    assert_eq!(back.normal, got.normal);
}

#[test]
fn a_coarse_texel_of_tilted_normals_is_rougher_toksvig() {
    let views = [[0.0, 0.0, 1.0]];
    let lights = spiral(10, 20.0, 80.0, 0.0);
    let (m, _) = made(&views, &lights);
    // Two texels with normals tilted apart: their average is shorter than 1.
    let coarse = m.mip_texels(&[vec![(0, 0.5), (11, 0.5)]]).unwrap();
    let t = 12;
    let (a0, a1) = (m.roughness[0] as f64, m.roughness[11] as f64);
    let n0: Vec<f64> = m.normal[0..3].iter().map(|&x| x as f64).collect();
    let n1: Vec<f64> = m.normal[33..36].iter().map(|&x| x as f64).collect();
    let mean: Vec<f64> = (0..3).map(|c| 0.5 * (n0[c] + n1[c])).collect();
    let len = mean.iter().map(|x| x * x).sum::<f64>().sqrt();
    let want = (0.5 * (a0 * a0 + a1 * a1) + (1.0 - len) / len).sqrt();
    assert!((coarse.roughness[t] as f64 - want).abs() < 1e-6, "{} vs {want}", coarse.roughness[t]);
    assert!(want > (0.5 * (a0 * a0 + a1 * a1)).sqrt() + 1e-3, "the tilt widens the lobe");
    assert_eq!(coarse.height, 4);
}
