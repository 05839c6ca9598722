#![allow(clippy::needless_range_loop)] // index loops mirror the formulas being checked
use super::*;
use crate::model::{evaluate_image, model_error};
use btfrs_core::directions::ubo81;
use btfrs_core::materials::{generate, MaterialSpec, Preset};
use btfrs_core::rng::Rng;
use btfrs_core::Btf;
use btfrs_numerics::kmeans::kmeans;
use nalgebra::DVector;

/// `n` texels drawn from `k` clusters, each an exact mean + `c` components (model data):
/// returns the `[n, D]` data and the true cluster of each texel. Means differ by O(1) per value
/// and the components are small, so the clusters are well apart.
fn model_data(n: usize, d: usize, k: usize, c: usize, seed: u64) -> (Vec<f32>, Vec<u32>) {
    let mut rng = Rng::new(seed);
    let means: Vec<Vec<f64>> = (0..k).map(|_| (0..d).map(|_| 0.1 + 0.8 * rng.next_f64()).collect()).collect();
    let comps: Vec<Vec<Vec<f64>>> =
        (0..k).map(|_| (0..c).map(|_| (0..d).map(|_| 0.1 * (rng.next_f64() - 0.5)).collect()).collect()).collect();
    let mut data = vec![0.0f32; n * d];
    let mut truth = vec![0u32; n];
    for t in 0..n {
        // Every cluster gets texels; the order is scrambled so labels and positions differ.
        let kk = (t * 7 + t / 3) % k;
        truth[t] = kk as u32;
        let a: Vec<f64> = (0..c).map(|_| 2.0 * rng.next_f64() - 1.0).collect();
        for p in 0..d {
            let v = means[kk][p] + (0..c).map(|j| a[j] * comps[kk][j][p]).sum::<f64>();
            data[t * d + p] = v as f32;
        }
    }
    (data, truth)
}

fn knit(size: usize) -> Btf {
    generate(&MaterialSpec::new(Preset::Knit, size, 1), &Monitor::new()).unwrap()
}

fn opts(clusters: usize, components: usize) -> LpcaOptions {
    LpcaOptions { clusters, components, ..Default::default() }
}

/// Largest principal angle (radians) between the column spaces of two `D x c` matrices.
fn subspace_angle(a: &DMatrix<f64>, b: &DMatrix<f64>) -> f64 {
    let qa = a.clone().qr().q();
    let qb = b.clone().qr().q();
    let s = (qa.transpose() * qb).singular_values();
    let smin = s.iter().copied().fold(f64::INFINITY, f64::min);
    smin.clamp(-1.0, 1.0).acos()
}

/// Each found cluster holds texels of one true cluster, and each true cluster maps to one.
fn assert_relabelling(found: &[u32], truth: &[u32], k: usize) {
    let mut map = vec![u32::MAX; k];
    for (&f, &t) in found.iter().zip(truth) {
        assert!(map[f as usize] == u32::MAX || map[f as usize] == t, "cluster {f} mixes true clusters");
        map[f as usize] = t;
    }
    let mut seen = map.clone();
    seen.sort();
    seen.dedup();
    assert_eq!(seen.len(), k, "clusters {map:?}");
}

#[test]
fn recovers_model_data_to_the_quantization_error() {
    let d = ubo81();
    let (h, w, k, c) = (16, 16, 4, 3);
    let (data, truth) = model_data(h * w, 81 * 81 * 3, k, c, 1);
    let btf = BtfRef::new(h, w, &d, &d, &data, None).unwrap();
    let m = fit_lpca(&btf, &opts(k, c), &Monitor::new()).unwrap();
    m.validate().unwrap();
    assert_eq!((m.clusters, m.components), (k, c));
    assert_relabelling(&m.ids, &truth, k);
    let e = model_error(&m, &btf).unwrap().relative();
    // 8 bits per Eigen-BRDF: a quantization step is 1/255 of its range.
    assert!(e < 0.01, "relative error {e}");
    assert!(m.weights.iter().chain(&m.scale).chain(&m.bias).all(|x| x.is_finite()));
}

#[test]
fn one_cluster_is_a_float64_pca() {
    // 8 views x 8 lights: D = 192, small enough for a D x D f64 covariance as the reference.
    let dirs: Vec<[f64; 3]> = ubo81()[..8].to_vec();
    let dd = 8 * 8 * 3;
    let c = 3;
    // A spectrum with clear gaps (sigma 1, 0.6, 0.35 then 0.02 noise in every direction).
    let mut rng = Rng::new(7);
    let mean: Vec<f64> = (0..dd).map(|_| rng.next_f64()).collect();
    let comps: Vec<Vec<f64>> = (0..c).map(|_| (0..dd).map(|_| rng.next_f64() - 0.5).collect()).collect();
    let sig = [1.0, 0.6, 0.35];
    let gauss = btfrs_numerics::dense::gaussian(dd + c, 600, 8);
    let make = |n: usize| -> Vec<f32> {
        let mut x = vec![0.0f32; n * dd];
        for t in 0..n {
            for p in 0..dd {
                let v = mean[p]
                    + (0..c).map(|j| sig[j] * gauss[(dd + j, t)] as f64 * comps[j][p]).sum::<f64>()
                    + 0.02 * gauss[(p, t)] as f64;
                x[t * dd + p] = v as f32;
            }
        }
        x
    };
    let reference = |x: &[f32], n: usize| -> DMatrix<f64> {
        let xm = DMatrix::<f64>::from_fn(dd, n, |p, t| x[t * dd + p] as f64);
        let mu = xm.column_mean();
        let xc = DMatrix::from_fn(dd, n, |p, t| xm[(p, t)] - mu[p]);
        let (_, vecs) = sym_eigen_desc(&xc * xc.transpose() / n as f64);
        vecs.columns(0, c).into_owned()
    };
    let as64 = |m: &DMatrix<f32>| m.map(|v| v as f64);
    // Covariance path (n >= D), Gram path (n < D) and the randomized path (forced by n > EXACT_MAX
    // with D > EXACT_MAX is too big for an f64 reference here, so call it on the Gram-sized case).
    for n in [256usize, 100] {
        let x = make(n);
        let all: Vec<u32> = (0..n as u32).collect();
        let want = reference(&x, n);
        let got = local_pca(&x, dd, &all, c, 0);
        let angle = subspace_angle(&as64(&got.basis), &want);
        assert!(angle < 1e-3, "n {n}: angle {angle}");
        // The same through the fit: one cluster, dequantized Eigen-BRDFs 1..c.
        let btf = BtfRef::new(n / 4, 4, &dirs, &dirs, &x, None).unwrap();
        let m = fit_lpca(&btf, &opts(1, c), &Monitor::new()).unwrap();
        let deq = DMatrix::<f64>::from_fn(dd, c, |p, j| {
            let (v, l, ch) = (p / 24, (p / 3) % 8, p % 3);
            m.basis_value(0, j + 1, v, l)[ch] as f64
        });
        // A constant bias is folded into the offset, so compare the centred basis span.
        let centred = DMatrix::from_fn(dd, c, |p, j| deq[(p, j)] - deq.column(j).mean());
        let want_c = DMatrix::from_fn(dd, c, |p, j| want[(p, j)] - want.column(j).mean());
        let angle = subspace_angle(&centred, &want_c);
        assert!(angle < 0.03, "n {n}: dequantized angle {angle}");
    }
    // Randomized subspace iteration, against the f64 covariance of the same centred data.
    let n = 600;
    let x = make(n);
    let (_, xc) = gather_centred(&x, dd, &(0..n as u32).collect::<Vec<_>>());
    let want = reference(&x, n);
    let xc_big = DMatrix::<f32>::from_fn(dd, n, |p, t| xc[(p, t)]);
    // top_components takes the randomized path when both sizes exceed EXACT_MAX: check it by
    // calling the path directly through a wide embedding (D padded with zero rows to 600).
    let pad = DMatrix::<f32>::from_fn(EXACT_MAX + 88, n, |p, t| if p < dd { xc_big[(p, t)] } else { 0.0 });
    let e = top_components(&pad, c, 3);
    let got = as64(&e.rows(0, dd).into_owned());
    let angle = subspace_angle(&got, &want);
    assert!(angle < 1e-3, "randomized: angle {angle}");
    assert!(e.rows(dd, EXACT_MAX + 88 - dd).iter().all(|&v| v.abs() < 1e-6));
}

#[test]
fn more_components_lower_the_error() {
    let b = knit(16);
    let r = b.as_ref();
    let mut last = (f64::INFINITY, 0usize);
    for c in [0usize, 1, 2, 4, 8] {
        let m = fit_lpca(&r, &opts(4, c), &Monitor::new()).unwrap();
        let e = model_error(&m, &r).unwrap().relative();
        assert!(e < last.0 && m.nbytes() > last.1, "c {c}: error {e}, previous {}", last.0);
        last = (e, m.nbytes());
    }
    assert!(last.0 < 0.2, "{}", last.0);
}

#[test]
fn refinement_never_increases_the_lpca_objective() {
    let b = knit(16);
    let (t, d) = (256, 81 * 81 * 3);
    // In the reduced space the fit clusters in, and in the full space (reduced_dims = 0).
    let (p, r, _) = btfrs_numerics::rpca::coordinates_map(&b.data, d, t, 32, 5, None, 1, &Monitor::new()).unwrap();
    for (points, dim) in [(&p[..], r), (&b.data[..], d)] {
        let km = kmeans(points, dim, 8, 25, 1, &Monitor::new()).unwrap();
        let (assign, hist) = refine(points, dim, km.assign.clone(), km.k(), 3, 6, 2, &Monitor::new()).unwrap();
        assert_eq!(assign.len(), t);
        for w in hist.windows(2) {
            assert!(w[1] <= w[0] * (1.0 + 1e-6), "dim {dim}: objective rose {hist:?}");
        }
        assert!(hist.last().unwrap() < &(hist[0] * 0.999), "dim {dim}: the refinement did nothing {hist:?}");
        // The first entry is the plain k-means + PCA objective, checked against a brute-force sum.
        let members = btfrs_numerics::kmeans::members_of(&km.assign, km.k());
        let brute: f64 = members
            .iter()
            .map(|m| {
                let lp = local_pca(points, dim, m, 3, 0);
                m.iter()
                    .map(|&i| {
                        let x = &points[i as usize * dim..(i as usize + 1) * dim];
                        let xc = DVector::<f64>::from_fn(dim, |q, _| x[q] as f64 - lp.mean[q] as f64);
                        let e = lp.basis.map(|v| v as f64);
                        let proj = e.transpose() * &xc;
                        xc.norm_squared() - proj.norm_squared()
                    })
                    .sum::<f64>()
            })
            .sum();
        assert!((hist[0] - brute).abs() < 1e-3 * brute, "dim {dim}: {} vs {brute}", hist[0]);
    }
}

#[test]
fn seeded_determinism() {
    let b = knit(16);
    let o = LpcaOptions { clusters: 6, components: 3, seed: 9, ..Default::default() };
    let a = fit_lpca(&b.as_ref(), &o, &Monitor::new()).unwrap();
    let c = fit_lpca(&b.as_ref(), &o, &Monitor::new()).unwrap();
    assert_eq!(a.ids, c.ids);
    assert_eq!(a.weights, c.weights);
    assert_eq!(a.basis, c.basis);
    assert_eq!((a.scale.clone(), a.bias.clone()), (c.scale.clone(), c.bias.clone()));
    // The same on one thread and on three: block splits follow the thread count, sums do not.
    let on = |n: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap();
        pool.install(|| fit_lpca(&b.as_ref(), &o, &Monitor::new()).unwrap())
    };
    let (one, three) = (on(1), on(3));
    assert_eq!((&one.ids, &one.weights, &one.basis), (&a.ids, &a.weights, &a.basis));
    assert_eq!((&three.ids, &three.weights, &three.basis), (&a.ids, &a.weights, &a.basis));
    // Another seed is a valid fit too (it may or may not cluster the same way).
    let e = fit_lpca(&b.as_ref(), &LpcaOptions { seed: 10, ..o }, &Monitor::new()).unwrap();
    e.validate().unwrap();
}

#[test]
fn held_out_pairs_are_never_read_and_are_filled() {
    let mut b = knit(8);
    let d = b.views.clone();
    let n = d.len();
    let (train, test) = btfrs_core::split::split_pairs(n, n, None, 0.2, 3).unwrap();
    let o = opts(4, 3);
    let fit = |data: &[f32]| fit_lpca(&BtfRef::new(8, 8, &d, &d, data, Some(&train)).unwrap(), &o, &Monitor::new());
    let a = fit(&b.data).unwrap();
    let clean = b.data.clone();
    for (i, x) in b.data.iter_mut().enumerate() {
        if test[(i / 3) % (n * n)] {
            // Large finite values: a non-finite one anywhere is refused (the fit scans every
            // value, as the caller's check would).
            *x = [1e6, -3e30, 7e20][i % 3];
        }
    }
    let g = fit(&b.data).unwrap();
    assert_eq!(a.ids, g.ids);
    assert_eq!(a.weights, g.weights);
    assert_eq!(a.basis, g.basis);
    // A held-out pair: the basis there is the interpolation of present pairs (to a rounding step).
    let hole = test.iter().position(|&x| x).unwrap();
    let (v, l) = (hole / n, hole % n);
    let w = directions::present_pair_weights(&d, &d, Some(&train), d[v], d[l]);
    assert!(w.iter().all(|&(pv, pl, _)| train[pv * n + pl]));
    for j in 0..=3 {
        let want: f64 = w.iter().map(|&(pv, pl, x)| x * a.basis_value(0, j, pv, pl)[0] as f64).sum();
        assert!((a.basis_value(0, j, v, l)[0] as f64 - want).abs() <= 0.51 / 255.0);
    }
    // Evaluating there gives finite values close to the (never seen) truth on average.
    let img = evaluate_image(&a, d[v], d[l]).unwrap();
    assert!(img.iter().all(|x| x.is_finite()));
    let truth: Vec<f32> = (0..64).flat_map(|t| clean[(t * n * n + hole) * 3..][..3].to_vec()).collect();
    let err = btfrs_core::metrics::compare(&img, &truth).relative();
    assert!(err < 0.6, "held-out pair relative error {err}");
}

#[test]
fn evaluation_follows_the_stored_formula() {
    let b = knit(8);
    let m = fit_lpca(&b.as_ref(), &opts(3, 2), &Monitor::new()).unwrap();
    let d = &b.views;
    // At a measured pair: offset + sum_j w_j q / 255, the texel's own cluster.
    let (v, l) = (17, 40);
    let img = evaluate_image(&m, d[v], d[l]).unwrap();
    for t in [0usize, 5, 63] {
        let w = &m.weights[t * 4..t * 4 + 4];
        let k = m.ids[t] as usize;
        for ch in 0..3 {
            let want: f32 = w[0] + (0..3).map(|j| w[1 + j] * m.basis_value(k, j, v, l)[ch]).sum::<f32>();
            assert!((img[t * 3 + ch] - want).abs() < 1e-4 * (1.0 + want.abs()));
        }
    }
    // Between directions: the 9-tap blend of the measured pairs' values, the light weights with
    // the measured cosine divided out (directions::cos_corrected).
    let (qv, ql) = (directions::from_theta_phi(0.5, 1.0), directions::from_theta_phi(0.9, 4.0));
    let img = evaluate_image(&m, qv, ql).unwrap();
    let (wv, mut wl) = (directions::interp_weights(d, qv, 3), directions::interp_weights(d, ql, 3));
    directions::cos_corrected(&mut wl, d, ql);
    assert_eq!(wv.len() * wl.len(), 9);
    let mut want = [0.0f64; 3];
    for &(vi, a) in &wv {
        for &(li, bw) in &wl {
            let px = evaluate_image(&m, d[vi], d[li]).unwrap();
            for ch in 0..3 {
                want[ch] += a * bw * px[9 * 3 + ch] as f64;
            }
        }
    }
    for ch in 0..3 {
        assert!((img[9 * 3 + ch] as f64 - want[ch]).abs() < 1e-4 * (1.0 + want[ch].abs()));
    }
}

#[test]
fn stored_arrays_have_their_documented_sizes_and_validate() {
    let b = knit(8);
    let m = fit_lpca(&b.as_ref(), &opts(5, 4), &Monitor::new()).unwrap();
    let k = m.clusters;
    assert_eq!(m.basis.len(), k * 5 * 81 * 81 * 4);
    assert_eq!(m.weights.len(), 64 * 6);
    // validate() catches a broken model.
    let mut bad = m.clone();
    bad.ids[3] = k as u32;
    assert!(bad.validate().unwrap_err().to_string().starts_with("ids:"));
    let mut bad = m.clone();
    bad.weights.pop();
    assert!(bad.validate().unwrap_err().to_string().starts_with("weights:"));
    let mut bad = m;
    bad.scale[0] = f32::NAN;
    assert!(bad.validate().unwrap_err().to_string().starts_with("scale:"));
}

#[test]
fn bad_arguments_name_the_parameter() {
    let b = knit(8);
    let r = b.as_ref();
    let err = |o: LpcaOptions| fit_lpca(&r, &o, &Monitor::new()).unwrap_err().to_string();
    let e = err(opts(65, 4));
    assert!(e.starts_with("clusters:") && e.contains("64") && e.contains("65"), "{e}");
    assert!(err(opts(0, 4)).starts_with("clusters:"));
    let e = err(opts(4, 17));
    assert!(e.starts_with("components:") && e.contains("16"), "{e}");
    assert!(err(LpcaOptions { kmeans_iterations: 0, ..opts(4, 2) }).starts_with("kmeans_iterations:"));
    let mut data = b.data.clone();
    let at = (5 * 81 * 81 + 2 * 81 + 7) * 3 + 1;
    data[at] = f32::NAN;
    let e = fit_lpca(&BtfRef::new(8, 8, &b.views, &b.lights, &data, None).unwrap(), &opts(2, 2), &Monitor::new())
        .unwrap_err()
        .to_string();
    assert_eq!(e, format!("data: value NaN at flat index {at} is not finite"));
    let m = Monitor::new();
    m.cancel();
    assert!(matches!(fit_lpca(&r, &opts(2, 2), &m), Err(Error::Interrupted)));
}

#[test]
fn black_and_repeated_texels() {
    let d = ubo81();
    // All black: one cluster, exact, no NaN.
    let zeros = vec![0.0f32; 4 * 4 * 81 * 81 * 3];
    let btf = BtfRef::new(4, 4, &d, &d, &zeros, None).unwrap();
    let m = fit_lpca(&btf, &opts(3, 2), &Monitor::new()).unwrap();
    m.validate().unwrap();
    assert_eq!(m.clusters, 1);
    assert_eq!(model_error(&m, &btf).unwrap().sse, 0.0);
    // Two distinct ABRDFs repeated: two clusters used out of five asked, reproduced exactly
    // up to the quantization of each mean.
    let (x, truth) = model_data(16, 81 * 81 * 3, 2, 0, 4);
    let btf = BtfRef::new(4, 4, &d, &d, &x, None).unwrap();
    for red in [64, 0] {
        let m = fit_lpca(&btf, &LpcaOptions { reduced_dims: red, ..opts(5, 3) }, &Monitor::new()).unwrap();
        assert_eq!(m.clusters, 2);
        assert_relabelling(&m.ids, &truth, 2);
        assert!(m.weights.iter().all(|w| w.is_finite()));
        assert!(model_error(&m, &btf).unwrap().relative() < 0.005);
    }
}

/// A texel's full ABRDF (`3 V L` values, pair-major) in f64, from the stored weights and basis.
fn abrdf(m: &Lpca, t: usize) -> Vec<f64> {
    let cc = m.components + 1;
    let w = &m.weights[t * (cc + 1)..(t + 1) * (cc + 1)];
    let k = m.ids[t] as usize;
    let vl = m.views.len() * m.lights.len();
    (0..3 * vl)
        .map(|p| {
            let (pair, ch) = (p / 3, p % 3);
            w[0] as f64
                + (0..cc)
                    .map(|j| w[1 + j] as f64 * m.basis[((k * cc + j) * vl + pair) * 4 + ch] as f64 / 255.0)
                    .sum::<f64>()
        })
        .collect()
}

#[test]
fn projected_mip_texels_are_the_best_representation_of_the_mean_in_one_cluster() {
    let btf = knit(8);
    let m = fit_lpca(&btf.as_ref(), &opts(4, 3), &Monitor::new()).unwrap();
    let n = m.height * m.width;
    // One group inside a cluster, one mixing clusters, one naming the new texels (a coarser level).
    let same: Vec<u32> = (0..n as u32).filter(|&t| m.ids[t as usize] == m.ids[0]).take(4).collect();
    assert!(same.len() >= 2);
    let mixed: Vec<u32> = vec![0, 1, 8, 9];
    assert!(mixed.iter().any(|&t| m.ids[t as usize] != m.ids[0]), "the 2x2 block should mix clusters");
    let eq = |ts: &[u32]| ts.iter().map(|&t| (t, 1.0 / ts.len() as f32)).collect::<Vec<_>>();
    let groups = vec![eq(&same), eq(&mixed), eq(&[n as u32, n as u32 + 1])];
    let out = m.mip_texels(&groups).unwrap();
    assert_eq!((out.width, out.height), (m.width, m.height + 1));
    assert_eq!(&out.ids[..n], &m.ids[..]);
    let mean = |ts: &[u32], model: &Lpca| {
        let parts: Vec<Vec<f64>> = ts.iter().map(|&t| abrdf(model, t as usize)).collect();
        (0..parts[0].len()).map(|p| parts.iter().map(|v| v[p]).sum::<f64>() / ts.len() as f64).collect::<Vec<f64>>()
    };
    let err = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f64>().sqrt();
    // Inside one cluster: exact (the average of the weights), to f32 rounding.
    let t0 = mean(&same, &m);
    assert_eq!(out.ids[n], m.ids[0]);
    let norm = t0.iter().map(|x| x * x).sum::<f64>().sqrt();
    assert!(err(&abrdf(&out, n), &t0) < 1e-5 * norm, "{}", err(&abrdf(&out, n), &t0) / norm);
    // Mixed: against an f64 least-squares reference in every candidate cluster's affine
    // subspace: the chosen one is the best, and it beats every member texel (a medoid's choice).
    let t1 = mean(&mixed, &m);
    let cc = m.components + 1;
    let vl = m.views.len() * m.lights.len();
    let mut best = f64::INFINITY;
    for &k in &mixed.iter().map(|&t| m.ids[t as usize]).collect::<Vec<_>>() {
        let k = k as usize;
        let a = DMatrix::<f64>::from_fn(3 * vl, cc + 1, |p, j| {
            if j == 0 {
                1.0
            } else {
                m.basis[((k * cc + j - 1) * vl + p / 3) * 4 + p % 3] as f64 / 255.0
            }
        });
        let x = a.clone().svd(true, true).solve(&DVector::from_vec(t1.clone()), 1e-12).unwrap();
        best = best.min(err((&a * x).as_slice(), &t1));
    }
    let got = err(&abrdf(&out, n + 1), &t1);
    assert!(got <= best * (1.0 + 1e-4) + 1e-6, "{got} vs {best}");
    for &t in &mixed {
        assert!(got <= err(&abrdf(&m, t as usize), &t1) + 1e-9);
    }
    // The coarser texel reads the new ones, and every stored value is finite.
    assert!(out.weights.iter().all(|x| x.is_finite()));
    assert!(m.mip_texels(&[vec![(n as u32, 1.0)]]).unwrap_err().to_string().starts_with("groups"));
}

#[test]
fn a_fit_under_a_memory_limit_streams_and_matches_the_unlimited_fit() {
    // knit 48^2 (2304 texels, above the 2048-texel range sample) with 81 x 81 pairs: 19683
    // values (79 kB) a texel. A limit leaving chunks of ~100 texels streams the sample and every
    // cluster; the clustering steers by the same coordinates, the reconstruction error stays
    // within 1 % of the unlimited fit's.
    let btf = knit(48);
    let b = btf.as_ref();
    let o = LpcaOptions { clusters: 6, components: 3, ..Default::default() };
    let free = fit_lpca(&b, &o, &Monitor::new()).unwrap();
    let d = 3 * 81 * 81;
    let t = b.texels();
    let fixed = memory_plan(Some(u64::MAX / 4), t, d, &o, false).unwrap().unwrap();
    assert_eq!(fixed, t, "an ample limit gathers everything");
    let m = Monitor::new();
    let least = match memory_plan(Some(1), t, d, &o, false) {
        Err(e) => e.to_string(),
        Ok(_) => panic!("a 1-byte limit was accepted"),
    };
    assert!(least.starts_with("memory_limit: expected at least "), "{least}");
    // Find the limit that leaves 100-texel chunks, from the plan itself.
    let mut limit = 1u64 << 20;
    while memory_plan(Some(limit), t, d, &o, false).map_or(true, |c| c.unwrap() < 100) {
        limit += 1 << 20;
    }
    let chunk = memory_plan(Some(limit), t, d, &o, false).unwrap().unwrap();
    assert!((100..200).contains(&chunk), "{chunk}");
    m.set_memory_limit(Some(limit));
    let tight = fit_lpca(&b, &o, &m).unwrap();
    let err = |l: &Lpca| model_error(l, &b).unwrap().relative();
    let (ef, et) = (err(&free), err(&tight));
    assert!((et - ef).abs() <= 0.01 * ef, "unlimited {ef}, under {limit} bytes {et}");
    let agree = free.ids.iter().zip(&tight.ids).filter(|(a, b)| a == b).count() as f64 / t as f64;
    assert!(agree > 0.95, "{agree}");
    // A limit too small for the fit is refused before any work, naming the least it needs.
    m.set_memory_limit(Some(limit / 4));
    assert!(fit_lpca(&b, &o, &m).unwrap_err().to_string().starts_with("memory_limit: expected at least"));
}

#[test]
fn a_fit_on_a_texel_sample_reports_its_error_and_equals_itself_under_a_memory_limit() {
    // knit 48^2 (2304 texels of 19683 values), clusters and Eigen-BRDFs found on 768 of them.
    let btf = knit(48);
    let b = btf.as_ref();
    let t = b.texels();
    let o = LpcaOptions { clusters: 6, components: 3, sample: 768, ..Default::default() };
    let m = fit_lpca(&b, &o, &Monitor::new()).unwrap();
    let f = m.sampled.expect("a sampled fit");
    assert_eq!(f.sample, 768);
    // The error the streaming pass summed is the stored model's, evaluated independently (its
    // 8-bit basis and f32 weights, through the renderer's evaluation at the measured pairs).
    let e = model_error(&m, &b).unwrap().relative();
    assert!((f.relative_error - e).abs() <= 1e-4 * e, "pass {} vs model {e}", f.relative_error);
    // Sample texels keep the cluster found for them; every cluster has sample members.
    let pick = sampled::pick(t, &o).unwrap();
    assert_eq!(pick.len(), 768);
    let mut seen = vec![false; m.clusters];
    for &i in &pick {
        seen[m.ids[i as usize] as usize] = true;
    }
    assert!(seen.iter().all(|&x| x));
    // Each texel outside the sample is in the cluster that reconstructs it best among those
    // its neighbours use, or no worse than 2% off the best: the pass's choice is made in the
    // principal coordinates, so check it against the full-space reconstruction of the model.
    // (A looser, independent property: the whole fit is close to the fit on every texel.)
    let all = fit_lpca(&b, &LpcaOptions { sample: 0, ..o }, &Monitor::new()).unwrap();
    assert!(all.sampled.is_none());
    let ea = model_error(&all, &b).unwrap().relative();
    assert!(e <= 1.03 * ea, "sampled {e} against every texel {ea}");
    // Under a memory limit that holds the sample and little more (large clusters of the sample
    // streamed): the same model, bit for bit.
    let mut limit = 1u64 << 20;
    let mon = Monitor::new();
    loop {
        mon.set_memory_limit(Some(limit));
        match fit_lpca(&b, &o, &mon) {
            Ok(tight) => {
                assert!(tight.ids == m.ids, "the clusters differ under {limit} bytes");
                assert!(tight.basis == m.basis, "the Eigen-BRDFs differ under {limit} bytes");
                assert!(tight.weights == m.weights, "the weights differ under {limit} bytes");
                break;
            }
            Err(e) => {
                let msg = e.to_string();
                assert!(msg.starts_with("memory_limit: expected at least"), "{msg}");
                assert!(msg.contains("a smaller `sample` needs less"), "{msg}");
                limit += 8 << 20;
            }
        }
    }
    // A non-finite value outside the sample (found by the pass) or in it (found by the sample's
    // read) fails as the caller's scan would, wherever it lies.
    let outside = (0..t as u32).rev().find(|i| pick.binary_search(i).is_err()).unwrap() as usize;
    for texel in [outside, pick[3] as usize] {
        let mut data = btf.data.clone();
        let at = texel * 19683 + 100;
        data[at] = f32::INFINITY;
        let mut bad = b;
        bad.data = &data;
        let e = fit_lpca(&bad, &o, &Monitor::new()).unwrap_err().to_string();
        assert_eq!(e, format!("data: value inf at flat index {at} is not finite"));
    }
    let sample_bytes = 768 * 19683 * 4;
    assert!(limit < sample_bytes + (300 << 20), "the plan wanted {limit} bytes");
}
