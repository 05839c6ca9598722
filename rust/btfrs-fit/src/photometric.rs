//! Photometric stereo (Woodham 1980): per texel of one view slot, the surface normal and the
//! albedo that explain its values under the measured lights as a Lambertian surface,
//! `I_l = rho (n . l)`, BTF values including the light's cosine (paper 004, section 3).
//!
//! * **L2**: the least-squares `g = rho n` over every measured light, `g = (L^T L)^-1 L^T I`,
//!   the pseudo-inverse computed once for the slot; the grey value `(R + G + B) / 3` gives the
//!   normal `g / |g|`, each channel's own least-squares vector projected on it its albedo.
//! * **Robust**: iteratively reweighted least squares from the L2 solution. Lights the current
//!   normal faces away from (`g . l <= 0`, attached shadow: the linear model cannot hold there)
//!   get weight 0; the others Tukey's biweight of their residual over 4.685 robust scales
//!   (1.4826 times the median absolute residual), so cast shadows (values far below the
//!   Lambertian prediction) and highlights (far above) stop pulling the normal. Up to
//!   [`ROBUST_ITERATIONS`] rounds, each a weighted 3 x 3 solve; the last weights give the albedo.
//!
//! Light directions point from the surface to the light in the sample's frame (x right, y up
//! the image, z out of the surface), and so do the normals.

use btfrs_core::btf::BtfRef;
use btfrs_core::{Error, Monitor, Result};
use rayon::prelude::*;

/// Rounds of reweighting in the robust method (it stops earlier once the normal is still).
pub const ROBUST_ITERATIONS: usize = 12;
/// Tukey's biweight constant (95% efficiency under Gaussian residuals).
const TUKEY_C: f64 = 4.685;

/// How the normals are estimated.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    /// Least squares over every light.
    L2,
    /// Iteratively reweighted least squares, shadows and highlights down-weighted.
    Robust,
}

impl Method {
    /// `"l2"` or `"robust"`.
    pub fn from_name(name: &str) -> Result<Self> {
        match name {
            "l2" => Ok(Method::L2),
            "robust" => Ok(Method::Robust),
            o => Err(Error::arg("method", format!("expected \"l2\" or \"robust\", got {o:?}"))),
        }
    }
}

/// What photometric stereo found for one view slot.
#[derive(Debug, Clone)]
pub struct NormalMaps {
    /// Per texel (row-major, row 0 at the top) the unit normal; `(0, 0, 1)` where the texel is
    /// black under every light (no direction to find).
    pub normals: Vec<[f32; 3]>,
    /// Per texel the Lambertian albedo of each channel (`rho` in `I = rho (n . l)`).
    pub albedo: Vec<[f32; 3]>,
    /// Per texel the weight the fit gave the lights, summed (the number of lights used by L2).
    pub lights_used: Vec<f32>,
    /// Texels black under every light.
    pub dark_texels: usize,
}

/// The slot's lights as rows, after the checks: at least 3 measured, not all in one plane.
fn slot_lights(btf: &BtfRef<'_>, view: usize) -> Result<Vec<(usize, [f64; 3])>> {
    let (nv, nl) = (btf.views.len(), btf.lights.len());
    if view >= nv {
        return Err(Error::arg("view", format!("expected a view slot in 0..{nv}, got {view}")));
    }
    let lights: Vec<(usize, [f64; 3])> =
        (0..nl).filter(|&l| btf.mask.is_none_or(|m| m[view * nl + l])).map(|l| (l, btf.lights[l])).collect();
    if lights.len() < 3 {
        return Err(Error::Degenerate(format!(
            "photometric stereo needs at least 3 lights in view slot {view}, which has {}",
            lights.len()
        )));
    }
    // Coplanar lights (all in one plane through the origin) leave the normal's component
    // across that plane unknown: L^T L is singular.
    let a = normal_matrix(lights.iter().map(|(_, d)| (*d, 1.0)));
    let trace = a[0][0] + a[1][1] + a[2][2];
    if det3(&a) <= 1e-9 * trace * trace * trace {
        return Err(Error::Degenerate(format!(
            "the {} lights of view slot {view} lie in one plane through the surface point: the normal's \
             component across it cannot be found (photometric stereo needs lights in three independent directions)",
            lights.len()
        )));
    }
    Ok(lights)
}

/// `sum w l l^T` over `(l, w)`.
fn normal_matrix(items: impl Iterator<Item = ([f64; 3], f64)>) -> [[f64; 3]; 3] {
    let mut a = [[0.0; 3]; 3];
    for (d, w) in items {
        for i in 0..3 {
            for j in 0..3 {
                a[i][j] += w * d[i] * d[j];
            }
        }
    }
    a
}

fn det3(a: &[[f64; 3]; 3]) -> f64 {
    a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1]) - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
        + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0])
}

/// The inverse of a symmetric 3 x 3 matrix, None when it is (nearly) singular.
fn inv3(a: &[[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
    let d = det3(a);
    let trace = a[0][0] + a[1][1] + a[2][2];
    if !(d.is_finite() && d > 1e-12 * trace * trace * trace && trace > 0.0) {
        return None;
    }
    let c = |i: usize, j: usize| {
        let (r0, r1) = ((i + 1) % 3, (i + 2) % 3);
        let (c0, c1) = ((j + 1) % 3, (j + 2) % 3);
        a[r0][c0] * a[r1][c1] - a[r0][c1] * a[r1][c0]
    };
    let mut out = [[0.0; 3]; 3];
    for (i, row) in out.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = c(j, i) / d;
        }
    }
    Some(out)
}

fn mul3(a: &[[f64; 3]; 3], b: [f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|i| a[i][0] * b[0] + a[i][1] * b[1] + a[i][2] * b[2])
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Normals and albedo of view slot `view` (see the module docs). `monitor` counts texel rows.
pub fn photometric_stereo(btf: &BtfRef<'_>, view: usize, method: Method, monitor: &Monitor) -> Result<NormalMaps> {
    let lights = slot_lights(btf, view)?;
    let (nv, nl) = (btf.views.len(), btf.lights.len());
    let (h, w) = (btf.height, btf.width);
    let texels = h * w;
    if btf.data.len() != texels * nv * nl * 3 {
        return Err(Error::arg("data", format!("expected {} values, got {}", texels * nv * nl * 3, btf.data.len())));
    }
    // The L2 pseudo-inverse, once for the slot: P = (L^T L)^-1 L^T, 3 x n.
    let inv = inv3(&normal_matrix(lights.iter().map(|(_, d)| (*d, 1.0))))
        .ok_or_else(|| Error::Degenerate(format!("the lights of view slot {view} are degenerate")))?;
    let pinv: Vec<[f64; 3]> = lights.iter().map(|(_, d)| mul3(&inv, *d)).collect();
    monitor.start(h as u64);
    let mut normals = vec![[0.0f32, 0.0, 1.0]; texels];
    let mut albedo = vec![[0.0f32; 3]; texels];
    let mut used = vec![0.0f32; texels];
    let per_texel = nv * nl * 3;
    normals.par_chunks_mut(w).zip(albedo.par_chunks_mut(w)).zip(used.par_chunks_mut(w)).enumerate().try_for_each(
        |(row, ((n_row, a_row), u_row))| -> Result<()> {
            monitor.check()?;
            let mut scratch = Scratch::new(lights.len());
            for col in 0..w {
                let t = row * w + col;
                let vals = &btf.data[t * per_texel + view * nl * 3..t * per_texel + (view + 1) * nl * 3];
                let (n, a, u) = match method {
                    Method::L2 => l2_texel(vals, &lights, &pinv),
                    Method::Robust => robust_texel(vals, &lights, &pinv, &mut scratch),
                };
                n_row[col] = n;
                a_row[col] = a;
                u_row[col] = u;
            }
            monitor.advance(1);
            Ok(())
        },
    )?;
    let dark_texels = albedo.iter().zip(&normals).filter(|(a, n)| a.iter().all(|&v| v == 0.0) && n[2] == 1.0).count();
    if let Some(i) = normals.iter().position(|n| !n.iter().all(|v| v.is_finite())) {
        return Err(Error::Numerical(format!(
            "photometric stereo: the normal of texel (row {}, column {}) is not finite (non-finite values in the data?)",
            i / w,
            i % w
        )));
    }
    Ok(NormalMaps { normals, albedo, lights_used: used, dark_texels })
}

/// The normal of the grey least-squares vector and each channel's albedo along it.
fn finish(g: [[f64; 3]; 3]) -> ([f32; 3], [f32; 3]) {
    let grey = [0, 1, 2].map(|i| (g[0][i] + g[1][i] + g[2][i]) / 3.0);
    let len = dot(grey, grey).sqrt();
    if !(len > 0.0 && len.is_finite()) {
        return ([0.0, 0.0, 1.0], [0.0; 3]);
    }
    let n = grey.map(|v| v / len);
    (n.map(|v| v as f32), [0, 1, 2].map(|c| dot(g[c], n).max(0.0) as f32))
}

fn l2_texel(vals: &[f32], lights: &[(usize, [f64; 3])], pinv: &[[f64; 3]]) -> ([f32; 3], [f32; 3], f32) {
    let mut g = [[0.0f64; 3]; 3];
    for ((l, _), p) in lights.iter().zip(pinv) {
        for (c, gc) in g.iter_mut().enumerate() {
            let v = vals[l * 3 + c] as f64;
            gc[0] += p[0] * v;
            gc[1] += p[1] * v;
            gc[2] += p[2] * v;
        }
    }
    let (n, a) = finish(g);
    (n, a, lights.len() as f32)
}

struct Scratch {
    grey: Vec<f64>,
    weight: Vec<f64>,
    abs: Vec<f64>,
}

impl Scratch {
    fn new(n: usize) -> Self {
        Scratch { grey: vec![0.0; n], weight: vec![0.0; n], abs: Vec::with_capacity(n) }
    }
}

fn robust_texel(
    vals: &[f32],
    lights: &[(usize, [f64; 3])],
    pinv: &[[f64; 3]],
    s: &mut Scratch,
) -> ([f32; 3], [f32; 3], f32) {
    for (k, (l, _)) in lights.iter().enumerate() {
        s.grey[k] = (vals[l * 3] as f64 + vals[l * 3 + 1] as f64 + vals[l * 3 + 2] as f64) / 3.0;
    }
    // Start from the L2 solution of the grey values.
    let mut g = [0.0f64; 3];
    for (k, p) in pinv.iter().enumerate() {
        for i in 0..3 {
            g[i] += p[i] * s.grey[k];
        }
    }
    if dot(g, g) == 0.0 {
        return ([0.0, 0.0, 1.0], [0.0; 3], 0.0);
    }
    let peak = s.grey.iter().fold(0.0f64, |m, &v| m.max(v.abs()));
    s.weight.iter_mut().for_each(|w| *w = 1.0);
    for _ in 0..ROBUST_ITERATIONS {
        // Residuals of the lit lights and their robust scale.
        s.abs.clear();
        for (k, (_, d)) in lights.iter().enumerate() {
            let pred = dot(g, *d);
            if pred > 0.0 {
                s.abs.push((s.grey[k] - pred).abs());
            }
        }
        if s.abs.len() < 3 {
            break;
        }
        let mid = s.abs.len() / 2;
        let (_, med, _) = s.abs.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
        // A floor on the scale: a near-perfect fit must not make every small residual an outlier.
        let scale = (1.4826 * *med).max(1e-4 * peak).max(f64::MIN_POSITIVE);
        let cut = TUKEY_C * scale;
        for (k, (_, d)) in lights.iter().enumerate() {
            let pred = dot(g, *d);
            s.weight[k] = if pred > 0.0 {
                let u = (s.grey[k] - pred) / cut;
                if u.abs() < 1.0 {
                    (1.0 - u * u) * (1.0 - u * u)
                } else {
                    0.0
                }
            } else {
                0.0
            };
        }
        let a = normal_matrix(lights.iter().zip(&s.weight).map(|((_, d), w)| (*d, *w)));
        let Some(inv) = inv3(&a) else { break };
        let mut b = [0.0f64; 3];
        for (k, (_, d)) in lights.iter().enumerate() {
            for i in 0..3 {
                b[i] += s.weight[k] * s.grey[k] * d[i];
            }
        }
        let next = mul3(&inv, b);
        let change =
            dot([next[0] - g[0], next[1] - g[1], next[2] - g[2]], [next[0] - g[0], next[1] - g[1], next[2] - g[2]]);
        g = next;
        if change <= 1e-12 * dot(g, g) {
            break;
        }
    }
    // Each channel's weighted least squares with the final weights (L2's where they fail).
    let a = normal_matrix(lights.iter().zip(&s.weight).map(|((_, d), w)| (*d, *w)));
    let Some(inv) = inv3(&a) else {
        let (n, a, _) = l2_texel(vals, lights, pinv);
        return (n, a, lights.len() as f32);
    };
    let mut gc = [[0.0f64; 3]; 3];
    for (c, out) in gc.iter_mut().enumerate() {
        let mut b = [0.0f64; 3];
        for (k, (l, d)) in lights.iter().enumerate() {
            let v = s.weight[k] * vals[l * 3 + c] as f64;
            for i in 0..3 {
                b[i] += v * d[i];
            }
        }
        *out = mul3(&inv, b);
    }
    let (n, a) = finish(gc);
    (n, a, s.weight.iter().sum::<f64>() as f32)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dirs(n: usize) -> Vec<[f64; 3]> {
        // A spiral over the upper hemisphere, elevations 15 to 80 degrees.
        (0..n)
            .map(|i| {
                let t = i as f64 / n as f64;
                let el = (15.0 + 65.0 * t).to_radians();
                let az = 2.399963 * i as f64;
                [el.cos() * az.cos(), el.cos() * az.sin(), el.sin()]
            })
            .collect()
    }

    fn lambert(normals: &[[f64; 3]], albedo: [f64; 3], lights: &[[f64; 3]]) -> Vec<f32> {
        let mut out = Vec::new();
        for n in normals {
            for l in lights {
                let c = dot(*n, *l).max(0.0);
                out.extend(albedo.map(|a| (a * c) as f32));
            }
        }
        out
    }

    #[test]
    fn a_lambertian_texel_lit_from_its_front_gives_its_normal_and_albedo_exactly() {
        let n = [0.2f64, -0.1, 1.0];
        let len = dot(n, n).sqrt();
        let n = n.map(|v| v / len);
        // Lights within 60 degrees of the normal: every light is lit, so L2 is exact too.
        let lights: Vec<[f64; 3]> = dirs(40).into_iter().filter(|l| dot(*l, n) > 0.5).collect();
        let views = [[0.0, 0.0, 1.0]];
        let data = lambert(&[n], [0.5, 0.25, 0.125], &lights);
        let b = BtfRef { height: 1, width: 1, views: &views, lights: &lights, data: &data, mask: None };
        for m in [Method::L2, Method::Robust] {
            let r = photometric_stereo(&b, 0, m, &Monitor::new()).unwrap();
            for i in 0..3 {
                assert!((r.normals[0][i] as f64 - n[i]).abs() < 1e-5, "{m:?}: {:?} vs {n:?}", r.normals[0]);
            }
            assert!((r.albedo[0][0] - 0.5).abs() < 1e-5 && (r.albedo[0][2] - 0.125).abs() < 1e-5, "{:?}", r.albedo);
        }
    }

    #[test]
    fn robust_ignores_a_highlight_and_a_cast_shadow_that_l2_follows() {
        let n = [0.0f64, 0.0, 1.0];
        let lights = dirs(60);
        let views = [[0.0, 0.0, 1.0]];
        let mut data = lambert(&[n], [0.4, 0.4, 0.4], &lights);
        // A highlight on two lights and a cast shadow over six on one side.
        for l in [3usize, 4] {
            data[l * 3..l * 3 + 3].iter_mut().for_each(|v| *v += 2.0);
        }
        for l in lights.iter().enumerate().filter(|(_, d)| d[0] > 0.6).map(|(i, _)| i).take(6) {
            data[l * 3..l * 3 + 3].iter_mut().for_each(|v| *v = 0.0);
        }
        let b = BtfRef { height: 1, width: 1, views: &views, lights: &lights, data: &data, mask: None };
        let angle = |m| {
            let r = photometric_stereo(&b, 0, m, &Monitor::new()).unwrap();
            (r.normals[0][2] as f64).clamp(-1.0, 1.0).acos().to_degrees()
        };
        let (l2, robust) = (angle(Method::L2), angle(Method::Robust));
        assert!(robust < 0.01, "robust: {robust} degrees");
        assert!(l2 > 2.0, "l2: {l2} degrees (the outliers should move it)");
    }

    #[test]
    fn too_few_or_coplanar_lights_and_a_missing_slot_are_refused() {
        let views = [[0.0, 0.0, 1.0]];
        let two = dirs(2);
        let data = vec![0.5f32; 6];
        let b = BtfRef { height: 1, width: 1, views: &views, lights: &two, data: &data, mask: None };
        let e = photometric_stereo(&b, 0, Method::L2, &Monitor::new()).unwrap_err().to_string();
        assert!(e.contains("at least 3 lights"), "{e}");
        // Five lights in the x-z plane.
        let plane: Vec<[f64; 3]> = (0..5)
            .map(|i| {
                let a = (20.0 + 30.0 * i as f64).to_radians();
                [a.cos(), 0.0, a.sin()]
            })
            .collect();
        let data = vec![0.5f32; 15];
        let b = BtfRef { height: 1, width: 1, views: &views, lights: &plane, data: &data, mask: None };
        let e = photometric_stereo(&b, 0, Method::Robust, &Monitor::new()).unwrap_err().to_string();
        assert!(e.contains("lie in one plane"), "{e}");
        let e = photometric_stereo(&b, 1, Method::L2, &Monitor::new()).unwrap_err().to_string();
        assert!(e.starts_with("view: expected a view slot in 0..1"), "{e}");
    }
}
