//! The surfaces of the built-in materials: periodic heightfields with albedo and gloss.
//!
//! Coordinates are in texels with y pointing up (row 0 of the image is the top, y = size there);
//! every pattern repeats a whole number of times over the sample, so the sample tiles seamlessly,
//! and per-cell random variation (seeded) keeps it from being a trivial repetition of one cell.

use crate::rng::hash01;
use std::f64::consts::{PI, TAU};

/// The built-in surfaces.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Preset {
    /// Stocking stitch: columns of V-shaped yarn loops with fibre ridges; deep gaps, hard shadows.
    Knit,
    /// Plain weave: two thread colours going over and under each other; silky sheen.
    Weave,
    /// Pebbles: jittered glossy bumps on a matte ground; round cast shadows.
    Bumps,
    /// Brushed metal grooves along y: strongly anisotropic, shiny.
    Grooves,
}

impl Preset {
    /// All presets, in a stable order.
    pub const ALL: [Preset; 4] = [Preset::Knit, Preset::Weave, Preset::Bumps, Preset::Grooves];

    /// The preset's name as the Python API spells it.
    pub fn name(self) -> &'static str {
        match self {
            Preset::Knit => "knit",
            Preset::Weave => "weave",
            Preset::Bumps => "bumps",
            Preset::Grooves => "grooves",
        }
    }

    /// Look a preset up by name.
    pub fn from_name(name: &str) -> crate::Result<Self> {
        Preset::ALL.iter().copied().find(|p| p.name() == name).ok_or_else(|| {
            let names: Vec<_> = Preset::ALL.iter().map(|p| p.name()).collect();
            crate::Error::arg("name", format!("unknown material {name:?}; expected one of {}", names.join(", ")))
        })
    }
}

/// A sampled surface: per-texel values on the `size x size` grid, stored with row 0 at the
/// *bottom* (y up) so that grid index (gx, gy) is the texel whose centre is (gx + .5, gy + .5).
#[derive(Debug, Clone)]
pub(crate) struct Surface {
    pub size: usize,
    pub height: Vec<f32>,
    pub normal: Vec<[f32; 3]>,
    pub albedo: Vec<[f32; 3]>,
    pub ks: Vec<f32>,
    pub exponent: Vec<f32>,
}

struct Sample {
    h: f64,
    albedo: [f64; 3],
    ks: f64,
    exponent: f64,
}

/// Periodic value noise: a lattice of `cells x cells` random values over the sample, smoothly
/// interpolated; `(x, y)` in units of the sample size ([0, 1) repeats).
fn value_noise(seed: u64, cells: i64, x: f64, y: f64) -> f64 {
    let fx = x * cells as f64;
    let fy = y * cells as f64;
    let (ix, iy) = (fx.floor() as i64, fy.floor() as i64);
    let (tx, ty) = (fx - ix as f64, fy - iy as f64);
    let s = |t: f64| t * t * (3.0 - 2.0 * t);
    let at = |a: i64, b: i64| hash01(seed, a.rem_euclid(cells), b.rem_euclid(cells));
    let (sx, sy) = (s(tx), s(ty));
    let top = at(ix, iy) * (1.0 - sx) + at(ix + 1, iy) * sx;
    let bot = at(ix, iy + 1) * (1.0 - sx) + at(ix + 1, iy + 1) * sx;
    top * (1.0 - sy) + bot * sy
}

/// Two octaves of periodic value noise in [0, 1].
fn fbm(seed: u64, cells: i64, x: f64, y: f64) -> f64 {
    0.65 * value_noise(seed, cells, x, y) + 0.35 * value_noise(seed ^ 0xABCD, cells * 2, x, y)
}

/// How many whole repetitions of a pattern of period `period` texels fit the sample.
fn repeats(size: usize, period: f64, even: bool) -> i64 {
    let n = (size as f64 / period).round().max(1.0) as i64;
    if even {
        (n + (n & 1)).max(2)
    } else {
        n
    }
}

fn cap(d2: f64) -> f64 {
    if d2 < 1.0 {
        (1.0 - d2).sqrt()
    } else {
        0.0
    }
}

fn knit(seed: u64, size: usize, x: f64, y: f64) -> Sample {
    let n = repeats(size, 16.0, false);
    let cell = size as f64 / n as f64;
    let (cu, cv) = (x / cell, y / cell);
    let (ci, cj) = (cu.floor(), cv.floor());
    let (u, v) = (cu - ci, cv - cj);
    // A stitch is two yarn legs leaning towards each other; legs reach into the cells above and
    // below, so the neighbours' legs are evaluated too.
    let mut best = (0.0f64, 0.0f64, 0.0f64); // (height, along, stitch key)
    for dj in -1..=1 {
        let vv = v - dj as f64;
        for (cx, ang) in [(0.3, -0.5f64), (0.7, 0.5f64)] {
            let (du, dv) = (u - cx, vv - 0.5);
            let (s, c) = ang.sin_cos();
            let across = c * du - s * dv;
            let along = s * du + c * dv;
            let r2 = (across / 0.2).powi(2) + (along / 0.5).powi(2);
            let key = hash01(seed, ci.rem_euclid(n as f64) as i64, (cj + dj as f64).rem_euclid(n as f64) as i64);
            let hh = cap(r2) * (0.85 + 0.3 * key);
            if hh > best.0 {
                best = (hh, along, key);
            }
        }
    }
    let (h0, along, key) = best;
    // Fibre twist: ridges running diagonally along each leg.
    let twist = 1.0 + 0.07 * (TAU * (along * 9.0 + h0 * 2.0)).sin();
    let h = 4.0 * h0 * twist;
    let fib = fbm(seed ^ 11, (size as i64 / 2).max(2), x / size as f64, y / size as f64);
    let tint = 0.8 + 0.35 * key;
    let shade = 0.55 + 0.45 * h0.min(1.0);
    let g = tint * shade * (0.8 + 0.4 * fib);
    Sample { h, albedo: [0.62 * g, 0.16 * g, 0.12 * g], ks: 0.035, exponent: 10.0 }
}

fn weave(seed: u64, size: usize, x: f64, y: f64) -> Sample {
    let n = repeats(size, 8.0, true);
    let p = size as f64 / n as f64;
    let (xt, yt) = (x / p, y / p);
    let prof = |d: f64| cap((d / 0.46).powi(2));
    let f = (PI * (xt - 0.5)).cos() * (PI * (yt - 0.5)).cos();
    let warp = prof(xt.fract() - 0.5) * (0.6 + 0.4 * f);
    let weft = prof(yt.fract() - 0.5) * (0.6 - 0.4 * f);
    let (ti, tj) = (xt.floor().rem_euclid(n as f64) as i64, yt.floor().rem_euclid(n as f64) as i64);
    let noise = fbm(seed ^ 7, (size as i64 / 2).max(2), x / size as f64, y / size as f64);
    if warp >= weft {
        let var = 0.9 + 0.2 * hash01(seed, ti, -1);
        let stripe = 1.0 + 0.06 * (TAU * (yt * 4.0 + xt * 1.5)).sin();
        let g = var * (0.85 + 0.3 * noise);
        Sample { h: 2.5 * warp * stripe, albedo: [0.12 * g, 0.22 * g, 0.52 * g], ks: 0.07, exponent: 28.0 }
    } else {
        let var = 0.9 + 0.2 * hash01(seed, -1, tj);
        let stripe = 1.0 + 0.06 * (TAU * (xt * 4.0 + yt * 1.5)).sin();
        let g = var * (0.85 + 0.3 * noise);
        Sample { h: 2.5 * weft * stripe, albedo: [0.78 * g, 0.7 * g, 0.5 * g], ks: 0.07, exponent: 28.0 }
    }
}

fn bumps(seed: u64, size: usize, x: f64, y: f64) -> Sample {
    let n = repeats(size, 12.0, false);
    let cell = size as f64 / n as f64;
    let (cu, cv) = (x / cell, y / cell);
    let (ci, cj) = (cu.floor() as i64, cv.floor() as i64);
    let mut best = (0.0f64, -1i64, -1i64);
    for dj in -1..=1 {
        for di in -1..=1 {
            let (a, b) = (ci + di, cj + dj);
            let (ka, kb) = (a.rem_euclid(n), b.rem_euclid(n));
            let cx = a as f64 + 0.25 + 0.5 * hash01(seed, ka, kb);
            let cy = b as f64 + 0.25 + 0.5 * hash01(seed ^ 1, ka, kb);
            let r = 0.32 + 0.2 * hash01(seed ^ 2, ka, kb);
            let amp = 0.6 + 0.4 * hash01(seed ^ 3, ka, kb);
            let hh = amp * cap(((cu - cx).powi(2) + (cv - cy).powi(2)) / (r * r)).powf(0.8);
            if hh > best.0 {
                best = (hh, ka, kb);
            }
        }
    }
    let ground = fbm(seed ^ 5, (size as i64 / 4).max(2), x / size as f64, y / size as f64);
    if best.0 > 0.0 {
        let k = hash01(seed ^ 4, best.1, best.2);
        let base = [0.45 + 0.25 * k, 0.4 + 0.15 * k, 0.33 + 0.05 * k];
        let g = 0.9 + 0.2 * ground;
        Sample { h: 4.0 * best.0 + 0.3 * ground, albedo: base.map(|c| c * g), ks: 0.09, exponent: 45.0 }
    } else {
        let g = 0.7 + 0.6 * ground;
        Sample { h: 0.3 * ground, albedo: [0.16 * g, 0.14 * g, 0.11 * g], ks: 0.01, exponent: 6.0 }
    }
}

fn grooves(seed: u64, size: usize, x: f64, y: f64) -> Sample {
    let n = repeats(size, 8.0, false);
    let p = size as f64 / n as f64;
    let ys = y / size as f64;
    let wobble = 0.08 * (TAU * ys * 2.0).sin() * (hash01(seed, 0, 0) - 0.5);
    let xt = x / p + wobble;
    let gi = xt.floor().rem_euclid(n as f64) as i64;
    let width = 1.2 + 0.6 * hash01(seed ^ 9, gi, 0);
    let c = (0.5 + 0.5 * (TAU * xt).cos()).powf(width);
    let brush = value_noise(seed ^ 3, (size as i64).max(2), x / size as f64 * 0.5, ys * 0.02 + x / size as f64);
    let h = 2.0 * c + 0.1 * brush;
    let g = 0.85 + 0.3 * brush;
    Sample { h, albedo: [0.34 * g, 0.32 * g, 0.29 * g], ks: 0.22, exponent: 60.0 }
}

/// Sample a preset on the texel grid and derive normals from the heights.
pub(crate) fn surface(preset: Preset, size: usize, seed: u64, relief: f64) -> Surface {
    use rayon::prelude::*;
    let f = match preset {
        Preset::Knit => knit,
        Preset::Weave => weave,
        Preset::Bumps => bumps,
        Preset::Grooves => grooves,
    };
    let samples: Vec<Sample> = (0..size * size)
        .into_par_iter()
        .map(|g| f(seed, size, (g % size) as f64 + 0.5, (g / size) as f64 + 0.5))
        .collect();
    let height: Vec<f32> = samples.iter().map(|s| (s.h * relief) as f32).collect();
    let at = |gx: isize, gy: isize| {
        let n = size as isize;
        height[(gy.rem_euclid(n) * n + gx.rem_euclid(n)) as usize] as f64
    };
    let normal = (0..size * size)
        .map(|g| {
            let (gx, gy) = ((g % size) as isize, (g / size) as isize);
            // Central differences on the periodic grid: the normal of the bilinear surface.
            let dx = 0.5 * (at(gx + 1, gy) - at(gx - 1, gy));
            let dy = 0.5 * (at(gx, gy + 1) - at(gx, gy - 1));
            let l = (dx * dx + dy * dy + 1.0).sqrt();
            [(-dx / l) as f32, (-dy / l) as f32, (1.0 / l) as f32]
        })
        .collect();
    Surface {
        size,
        height,
        normal,
        albedo: samples.iter().map(|s| s.albedo.map(|c| c as f32)).collect(),
        ks: samples.iter().map(|s| s.ks as f32).collect(),
        exponent: samples.iter().map(|s| s.exponent as f32).collect(),
    }
}
