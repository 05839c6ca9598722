//! Properties of the generated materials that can be checked in closed form.
#![allow(clippy::needless_range_loop)] // index loops mirror the formulas being checked

use super::*;
use crate::directions::from_theta_phi;

fn one(preset: Preset, relief: f64, views: Vec<[f64; 3]>, lights: Vec<[f64; 3]>) -> Btf {
    let spec = MaterialSpec { preset, size: 16, views, lights, seed: 3, relief, subsurface: 0.0 };
    generate(&spec, &Monitor::new()).unwrap()
}

#[test]
fn flat_surface_is_lambert_plus_blinn_phong() {
    // With no relief there is no shadow and no parallax: every value is the closed-form shading.
    let v = from_theta_phi(0.5, 0.3);
    let l = from_theta_phi(0.7, 2.0);
    let b = one(Preset::Weave, 0.0, vec![v], vec![l]);
    let s = presets::surface(Preset::Weave, 16, 3, 0.0);
    for t in 0..16 * 16 {
        let (row, col) = (t / 16, t % 16);
        let g = (15 - row) * 16 + col;
        let a = s.albedo[g];
        let (ks, e) = (s.ks[g] as f64, s.exponent[g] as f64);
        let h = [l[0] + v[0], l[1] + v[1], l[2] + v[2]];
        let hn = h[2] / (h[0] * h[0] + h[1] * h[1] + h[2] * h[2]).sqrt();
        let spec = ks * (e + 8.0) / 8.0 * hn.powf(e);
        for c in 0..3 {
            let want = l[2] * (a[c] as f64 + spec) + 0.04 * l[2] * a[c] as f64;
            let got = b.data[t * 3 + c] as f64;
            assert!((got - want).abs() < 1e-4 * (1.0 + want), "texel {t} channel {c}: {got} vs {want}");
        }
    }
}

#[test]
fn deterministic_per_seed_and_different_across_seeds() {
    let d = directions::ubo81();
    let mk = |seed| {
        let spec = MaterialSpec {
            preset: Preset::Knit,
            size: 16,
            views: d.clone(),
            lights: d.clone(),
            seed,
            relief: 1.0,
            subsurface: 0.0,
        };
        generate(&spec, &Monitor::new()).unwrap().data
    };
    let a = mk(1);
    assert_eq!(a, mk(1));
    assert_ne!(a, mk(2));
    assert!(a.iter().all(|x| x.is_finite() && *x >= 0.0));
}

#[test]
fn grazing_lights_cast_shadows_and_overhead_light_does_not() {
    // Under a light from the pole nothing is occluded, so the shadowed fraction is zero; at 75
    // degrees the relief of the knit must shadow a real part of the sample.
    let b_top = one(Preset::Knit, 1.0, vec![[0.0, 0.0, 1.0]], vec![[0.0, 0.0, 1.0]]);
    let s = presets::surface(Preset::Knit, 16, 3, 1.0);
    let sm = shade::shadow_maps(&s, &[[0.0, 0.0, 1.0], from_theta_phi(75f64.to_radians(), 0.0)], &Monitor::new());
    let dark_top = sm.chunks(2).filter(|v| v[0] < 0.5).count();
    let dark_low = sm.chunks(2).filter(|v| v[1] < 0.5).count();
    assert_eq!(dark_top, 0);
    assert!(dark_low > 16 * 16 / 10, "only {dark_low} of 256 texels in shadow at 75 degrees");
    assert!(b_top.data.iter().all(|&x| x > 0.0));
}

#[test]
fn the_sample_tiles_seamlessly() {
    // Heights across the wrap-around differ no more than heights between inner neighbours do.
    for p in Preset::ALL {
        let s = presets::surface(p, 32, 1, 1.0);
        let h = |x: usize, y: usize| s.height[y * 32 + x] as f64;
        let inner: f64 =
            (0..32).map(|y| (0..31).map(|x| (h(x + 1, y) - h(x, y)).abs()).fold(0.0, f64::max)).fold(0.0, f64::max);
        let wrap: f64 = (0..32).map(|y| (h(0, y) - h(31, y)).abs()).fold(0.0, f64::max);
        assert!(wrap <= inner * 1.5 + 1e-6, "{p:?}: jump {wrap} across the seam, {inner} inside");
    }
}

#[test]
fn bad_specs_are_rejected() {
    let mut spec = MaterialSpec::new(Preset::Bumps, 4, 0);
    assert!(generate(&spec, &Monitor::new()).unwrap_err().to_string().starts_with("size:"));
    spec.size = 16;
    spec.subsurface = 1.5;
    assert!(generate(&spec, &Monitor::new()).unwrap_err().to_string().starts_with("subsurface:"));
    assert!(Preset::from_name("velvet").unwrap_err().to_string().contains("knit, weave"));
}

#[test]
fn cancellation_stops_the_work() {
    let m = Monitor::new();
    m.cancel();
    let e = generate(&MaterialSpec::new(Preset::Knit, 16, 0), &m).unwrap_err();
    assert!(matches!(e, crate::Error::Interrupted));
}

/// A surface with height `amp * sin(2 pi x / size)`, constant along y, white and matte.
fn sine_surface(size: usize, amp: f64) -> presets::Surface {
    let n = size * size;
    let height = (0..n)
        .map(|g| (amp * (std::f64::consts::TAU * ((g % size) as f64 + 0.5) / size as f64).sin()) as f32)
        .collect();
    presets::Surface {
        size,
        height,
        normal: vec![[0.0, 0.0, 1.0]; n],
        albedo: vec![[1.0; 3]; n],
        ks: vec![0.0; n],
        exponent: vec![1.0; n],
    }
}

/// Periodic linear interpolation of the sine surface's samples along x (independent of shade.rs).
fn sine_height(s: &presets::Surface, x: f64) -> f64 {
    let n = s.size as f64;
    let f = (x - 0.5).rem_euclid(n);
    let (i, t) = (f.floor() as usize, f - f.floor());
    let a = s.height[i % s.size] as f64;
    let b = s.height[(i + 1) % s.size] as f64;
    a * (1.0 - t) + b * t
}

#[test]
fn masking_finds_the_first_surface_point_along_the_view_ray() {
    // A grazing view (75 degrees) over slopes steeper than the ray: the ray crosses the surface
    // several times, and the hit must be the first crossing seen from the camera.
    let s = sine_surface(32, 4.0);
    let v = from_theta_phi(75f64.to_radians(), 0.0);
    let hits = shade::hit_points(&s, &[v], &Monitor::new());
    let zref: f64 = s.height.iter().map(|&h| h as f64).sum::<f64>() / s.height.len() as f64;
    for g in 0..32 * 32 {
        let (cx, cy) = ((g % 32) as f64 + 0.5, (g / 32) as f64 + 0.5);
        let [px, py] = hits[0][g];
        assert!((py - cy).abs() < 1e-9, "the ray stays in its xz plane");
        let t = (px - cx) / v[0];
        let z = zref + t * v[2];
        assert!((z - sine_height(&s, px)).abs() < 1e-3, "texel {g}: hit not on the surface");
        // Every point of the ray before the hit (closer to the camera) is above the surface.
        let top = (4.0 - zref) / v[2];
        let mut u = top;
        while u > t + 0.05 {
            assert!(
                zref + u * v[2] > sine_height(&s, cx + u * v[0]) - 1e-6,
                "texel {g}: an earlier crossing at t = {u}"
            );
            u -= 0.05;
        }
    }
    // Seen from straight above there is no parallax at all.
    let top = shade::hit_points(&s, &[[0.0, 0.0, 1.0]], &Monitor::new());
    assert!(top[0].iter().enumerate().all(|(g, p)| p[0] == (g % 32) as f64 + 0.5));
}

#[test]
fn the_in_place_blur_equals_the_out_of_place_formula() {
    // Each texel mixed with the mean of its four periodic neighbours (up, down, left, right, in
    // that order of summation), computed here from an unblurred copy: the streaming generator's
    // row-by-row in-place blur must give exactly these values.
    let d = directions::ubo81();
    let mut spec = MaterialSpec::new(Preset::Weave, 12, 4);
    spec.views = d[..9].to_vec();
    spec.lights = d[..7].to_vec();
    let plain = generate(&spec, &Monitor::new()).unwrap().data;
    spec.subsurface = 0.35;
    let blurred = generate(&spec, &Monitor::new()).unwrap().data;
    let (n, per, a) = (12usize, 9 * 7 * 3, 0.35f32);
    for t in 0..n * n {
        let (r, c) = (t / n, t % n);
        let nb = [((r + n - 1) % n) * n + c, ((r + 1) % n) * n + c, r * n + (c + n - 1) % n, r * n + (c + 1) % n];
        for k in 0..per {
            let m: f32 = nb.iter().map(|&q| plain[q * per + k]).sum::<f32>() * 0.25;
            let want = (1.0 - a) * plain[t * per + k] + a * m;
            assert_eq!(blurred[t * per + k], want, "texel {t} value {k}");
        }
    }
    // And the values written into a buffer (a mapped file) are the same.
    let mut out = vec![0.0f32; spec.values()];
    generate_into(&spec, &mut out, &Monitor::new()).unwrap();
    assert_eq!(out, blurred);
    assert!(generate_into(&spec, &mut out[1..], &Monitor::new()).unwrap_err().to_string().starts_with("out:"));
}
