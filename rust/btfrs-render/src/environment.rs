//! Distant environment light (paper 002, section 4 and Figure 13): a latitude-longitude HDR
//! image of the radiance arriving from every direction, and the two ways the paper lights a
//! BTF-dressed object with it.
//!
//! * **Sampled** ([`Environment::sample_lights`]): the environment becomes `n` directional
//!   lights, drawn with probability proportional to luminance x solid angle, each carrying
//!   `radiance x solid angle / (probability x n)`; the renderers shade them in one pass through
//!   their ordinary light loop. The paper used a spherical Q^2-tree; here the distribution is
//!   piecewise constant over the lat-long pixels (pbrt-v4's `PiecewiseConstant2D` flattened to
//!   one CDF) and inverted with *stratified* uniforms `(k + xi_k) / n`, so the samples spread
//!   over the CDF and the error falls faster than 1/sqrt(n) on smooth skies. Inside the chosen
//!   pixel the direction is uniform in solid angle, so the estimator is unbiased for the
//!   piecewise-constant environment.
//! * **Quadrature** ([`Environment::quadrature_lights`]): every pixel as one light at its centre
//!   with `radiance x solid angle`: the brute-force integral the sampled renders converge to
//!   (the reference of the tests).
//! * **Frequency domain** ([`Environment::sh_project`] and [`crate::sh_env`]): the environment as
//!   an SH vector, for double-SH models.
//!
//! Conventions: row 0 is the zenith (+z), row `h - 1` the nadir; column `c` spans azimuths
//! `[c, c + 1) * 2 pi / w`, measured from +x towards +y; width = 2 x height. Values are linear
//! RGB radiance. The renderers output `pi x radiance` (see `btfrs.render`): under a constant
//! environment of radiance 1 a white Lambertian surface reads pi.

use crate::scene::Light;
use btfrs_core::rng::Rng;
use btfrs_core::{Error, Result};
use std::f64::consts::PI;

/// Largest accepted environment height (rows); the width is twice it.
pub const MAX_HEIGHT: usize = 8192;
/// Most directional lights one sampled frame takes.
pub const MAX_SAMPLES: usize = 65536;

/// A lat-long environment: see the module docs.
#[derive(Debug, Clone, PartialEq)]
pub struct Environment {
    /// Columns (2 x rows).
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// `[height][width][3]` linear RGB radiance, row 0 the zenith.
    pub rgb: Vec<f32>,
}

/// Rec. 709 luminance of linear RGB.
pub fn luminance(c: [f32; 3]) -> f64 {
    0.2126 * c[0] as f64 + 0.7152 * c[1] as f64 + 0.0722 * c[2] as f64
}

impl Environment {
    /// Wrap `[height][width][3]` radiance, checking the shape (2:1, at least 2 x 4), that every
    /// value is finite and non-negative, and that something is lit (argument "environment").
    pub fn new(width: usize, height: usize, rgb: Vec<f32>) -> Result<Environment> {
        let bad = |m: String| Err(Error::arg("environment", m));
        if height < 2 || width != 2 * height || height > MAX_HEIGHT {
            return bad(format!(
                "expected a lat-long image twice as wide as high, 2 to {MAX_HEIGHT} rows, got {height} x {width}"
            ));
        }
        if rgb.len() != width * height * 3 {
            return bad(format!("expected {height} x {width} x 3 values, got {}", rgb.len()));
        }
        if let Some(i) = rgb.iter().position(|v| !v.is_finite() || *v < 0.0) {
            let p = i / 3;
            return bad(format!(
                "expected finite non-negative radiance; row {}, column {}, channel {} is {}",
                p / width,
                p % width,
                i % 3,
                rgb[i]
            ));
        }
        if rgb.iter().all(|&v| v == 0.0) {
            return bad("the environment is black everywhere (nothing to light with)".into());
        }
        Ok(Environment { width, height, rgb })
    }

    /// Polar angle range `(theta0, theta1)` of row `r`.
    fn row_theta(&self, r: usize) -> (f64, f64) {
        let h = self.height as f64;
        (PI * r as f64 / h, PI * (r + 1) as f64 / h)
    }

    /// Solid angle of one pixel of row `r`: `(2 pi / w) (cos theta0 - cos theta1)`.
    pub fn pixel_solid_angle(&self, r: usize) -> f64 {
        let (t0, t1) = self.row_theta(r);
        2.0 * PI / self.width as f64 * (t0.cos() - t1.cos())
    }

    /// The unit direction at fractional pixel position (`row + fy`, `col + fx`), with `fy`
    /// uniform in cos(theta) over the row (so uniform fractions are uniform in solid angle).
    pub fn direction(&self, row: usize, col: usize, fx: f64, fy: f64) -> [f64; 3] {
        let (t0, t1) = self.row_theta(row);
        let z = t0.cos() + fy * (t1.cos() - t0.cos());
        let phi = 2.0 * PI * (col as f64 + fx) / self.width as f64;
        let s = (1.0 - z * z).max(0.0).sqrt();
        [s * phi.cos(), s * phi.sin(), z]
    }

    /// The radiance of the pixel holding unit direction `d`.
    pub fn lookup(&self, d: [f64; 3]) -> [f32; 3] {
        let theta = d[2].clamp(-1.0, 1.0).acos();
        let phi = d[1].atan2(d[0]).rem_euclid(2.0 * PI);
        let r = ((theta / PI * self.height as f64) as usize).min(self.height - 1);
        let c = ((phi / (2.0 * PI) * self.width as f64) as usize).min(self.width - 1);
        let i = (r * self.width + c) * 3;
        [self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]]
    }

    fn pixel(&self, r: usize, c: usize) -> [f32; 3] {
        let i = (r * self.width + c) * 3;
        [self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]]
    }

    /// Every lit pixel as one directional light at its centre carrying radiance x solid angle
    /// (midpoint quadrature of the lighting integral; z-midpoint, i.e. the centre in cos(theta)).
    pub fn quadrature_lights(&self) -> Vec<Light> {
        let mut out = Vec::new();
        for r in 0..self.height {
            let omega = self.pixel_solid_angle(r) as f32;
            for c in 0..self.width {
                let p = self.pixel(r, c);
                if p.iter().all(|&v| v == 0.0) {
                    continue;
                }
                let d = self.direction(r, c, 0.5, 0.5);
                out.push(Light::Directional { direction: d.map(|x| x as f32), intensity: p.map(|v| v * omega) });
            }
        }
        out
    }

    /// `n` directional lights importance-sampled with probability proportional to luminance x
    /// solid angle (module docs), seeded. Errors: `n` outside 1..=[`MAX_SAMPLES`] ("samples"),
    /// an environment without luminance ("environment").
    pub fn sample_lights(&self, n: usize, seed: u64) -> Result<Vec<Light>> {
        if n == 0 || n > MAX_SAMPLES {
            return Err(Error::arg("samples", format!("expected 1 to {MAX_SAMPLES} samples, got {n}")));
        }
        let (w, h) = (self.width, self.height);
        // The flattened CDF over pixels (row-major), weights luminance x solid angle, in f64.
        let mut cdf = Vec::with_capacity(w * h + 1);
        cdf.push(0.0f64);
        let mut total = 0.0f64;
        for r in 0..h {
            let omega = self.pixel_solid_angle(r);
            for c in 0..w {
                total += luminance(self.pixel(r, c)).max(0.0) * omega;
                cdf.push(total);
            }
        }
        if total <= 0.0 || !total.is_finite() {
            return Err(Error::arg("environment", "has no luminance to sample (all pixels black in Y)"));
        }
        let mut rng = Rng::new(seed);
        let mut out = Vec::with_capacity(n);
        for k in 0..n {
            let u = (k as f64 + rng.next_f64()) / n as f64 * total;
            // First pixel whose cumulative weight exceeds u (zero-weight pixels are never chosen).
            let i = cdf.partition_point(|&x| x <= u).clamp(1, w * h) - 1;
            let (r, c) = (i / w, i % w);
            let weight = cdf[i + 1] - cdf[i];
            if weight <= 0.0 {
                continue; // only reachable by rounding at the very end of the CDF
            }
            let omega = self.pixel_solid_angle(r);
            let d = self.direction(r, c, rng.next_f64(), rng.next_f64());
            // radiance x omega / (p_i n), p_i = weight / total.
            let gain = (omega * total / (weight * n as f64)) as f32;
            out.push(Light::Directional {
                direction: d.map(|x| x as f32),
                intensity: self.pixel(r, c).map(|v| v * gain),
            });
        }
        Ok(out)
    }

    /// The projection on the first `n` real SH ([`btfrs_fit::sh_basis`]) per colour channel:
    /// `e_j = integral L(w) y_j(w) dw`, by 4 x 4 sub-pixel quadrature (uniform in solid angle).
    pub fn sh_project(&self, n: usize) -> Vec<[f64; 3]> {
        const SUB: usize = 4;
        let n = n.min(btfrs_fit::sh::MAX_COEFFS);
        let mut out = vec![[0.0f64; 3]; n];
        let mut y = vec![0.0f64; n];
        for r in 0..self.height {
            let omega = self.pixel_solid_angle(r) / (SUB * SUB) as f64;
            for c in 0..self.width {
                let p = self.pixel(r, c);
                if p.iter().all(|&v| v == 0.0) {
                    continue;
                }
                for sy in 0..SUB {
                    for sx in 0..SUB {
                        let fx = (sx as f64 + 0.5) / SUB as f64;
                        let fy = (sy as f64 + 0.5) / SUB as f64;
                        btfrs_fit::sh_basis(n, self.direction(r, c, fx, fy), &mut y);
                        for (o, &yj) in out.iter_mut().zip(&y) {
                            for ch in 0..3 {
                                o[ch] += p[ch] as f64 * yj * omega;
                            }
                        }
                    }
                }
            }
        }
        out
    }

    /// Preetham, Shirley and Smits' analytic daylight ("A Practical Analytic Model for
    /// Daylight", SIGGRAPH 1999): the Perez sky luminance and chromaticity distributions for
    /// `turbidity` in [1.7, 10] and a sun above the horizon (`sun` need not be unit), in linear
    /// Rec. 709 RGB normalised to zenith luminance 1. The sun disc itself is not included (it
    /// is a separate directional light). Below the horizon: a Lambertian ground of albedo
    /// `ground` lit by this sky, radiance `ground x E_horizontal / pi`.
    pub fn sky(sun: [f64; 3], turbidity: f64, height: usize, ground: f64) -> Result<Environment> {
        let len = (sun[0] * sun[0] + sun[1] * sun[1] + sun[2] * sun[2]).sqrt();
        if !sun.iter().all(|v| v.is_finite()) || len == 0.0 || sun[2] / len <= 0.0 {
            return Err(Error::arg(
                "sun",
                format!("expected a finite direction above the horizon (z > 0), got {sun:?}"),
            ));
        }
        if !(1.7..=10.0).contains(&turbidity) {
            return Err(Error::arg("turbidity", format!("expected 1.7 to 10 (the model's range), got {turbidity}")));
        }
        if !(0.0..=1.0).contains(&ground) {
            return Err(Error::arg("ground", format!("expected an albedo in [0, 1], got {ground}")));
        }
        if !(2..=MAX_HEIGHT).contains(&height) {
            return Err(Error::arg("height", format!("expected 2 to {MAX_HEIGHT} rows, got {height}")));
        }
        let s = sun.map(|v| v / len);
        let t = turbidity;
        let theta_s = s[2].acos();
        // Perez coefficients (A..E) for Y, x, y (Preetham 1999, appendix A.2).
        let perez_y = [
            0.1787 * t - 1.4630,
            -0.3554 * t + 0.4275,
            -0.0227 * t + 5.3251,
            0.1206 * t - 2.5771,
            -0.0670 * t + 0.3703,
        ];
        let perez_x = [
            -0.0193 * t - 0.2592,
            -0.0665 * t + 0.0008,
            -0.0004 * t + 0.2125,
            -0.0641 * t - 0.8989,
            -0.0033 * t + 0.0452,
        ];
        let perez_yc = [
            -0.0167 * t - 0.2608,
            -0.0950 * t + 0.0092,
            -0.0079 * t + 0.2102,
            -0.0441 * t - 1.6537,
            -0.0109 * t + 0.0529,
        ];
        let f = |c: &[f64; 5], cos_theta: f64, gamma: f64| {
            (1.0 + c[0] * (c[1] / cos_theta.max(1e-3)).exp())
                * (1.0 + c[2] * (c[3] * gamma).exp() + c[4] * gamma.cos().powi(2))
        };
        // Zenith values (appendix A.2); luminance is normalised away, chromaticity is kept.
        let (ts, ts2, ts3) = (theta_s, theta_s * theta_s, theta_s * theta_s * theta_s);
        let xz = t * t * (0.00166 * ts3 - 0.00375 * ts2 + 0.00209 * ts)
            + t * (-0.02903 * ts3 + 0.06377 * ts2 - 0.03202 * ts + 0.00394)
            + (0.11693 * ts3 - 0.21196 * ts2 + 0.06052 * ts + 0.25886);
        let yz = t * t * (0.00275 * ts3 - 0.00610 * ts2 + 0.00317 * ts)
            + t * (-0.04214 * ts3 + 0.08970 * ts2 - 0.04153 * ts + 0.00516)
            + (0.15346 * ts3 - 0.26756 * ts2 + 0.06670 * ts + 0.26688);
        let (f0y, f0x, f0c) = (f(&perez_y, 1.0, theta_s), f(&perez_x, 1.0, theta_s), f(&perez_yc, 1.0, theta_s));
        let width = 2 * height;
        let mut env = Environment { width, height, rgb: vec![0.0; width * height * 3] };
        let to_rgb = |x: f64, y: f64, lum: f64| -> [f32; 3] {
            let (cx, cz) = (x * lum / y, (1.0 - x - y) * lum / y);
            // XYZ to linear Rec. 709.
            let r = 3.2404542 * cx - 1.5371385 * lum - 0.4985314 * cz;
            let g = -0.9692660 * cx + 1.8760108 * lum + 0.0415560 * cz;
            let b = 0.0556434 * cx - 0.2040259 * lum + 1.0572252 * cz;
            [r.max(0.0) as f32, g.max(0.0) as f32, b.max(0.0) as f32]
        };
        let mut horizontal = [0.0f64; 3];
        for r in 0..height {
            let omega = env.pixel_solid_angle(r);
            for c in 0..width {
                let d = env.direction(r, c, 0.5, 0.5);
                if d[2] <= 0.0 {
                    continue;
                }
                let gamma = (d[0] * s[0] + d[1] * s[1] + d[2] * s[2]).clamp(-1.0, 1.0).acos();
                let lum = f(&perez_y, d[2], gamma) / f0y;
                let x = xz * f(&perez_x, d[2], gamma) / f0x;
                let y = yz * f(&perez_yc, d[2], gamma) / f0c;
                let p = to_rgb(x, y, lum);
                for ch in 0..3 {
                    horizontal[ch] += p[ch] as f64 * d[2] * omega;
                }
                env.rgb[(r * width + c) * 3..][..3].copy_from_slice(&p);
            }
        }
        let g = horizontal.map(|e| (ground * e / PI) as f32);
        for r in 0..height {
            for c in 0..width {
                if env.direction(r, c, 0.5, 0.5)[2] <= 0.0 {
                    env.rgb[(r * width + c) * 3..][..3].copy_from_slice(&g);
                }
            }
        }
        Environment::new(width, height, env.rgb)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn constant(h: usize, v: f32) -> Environment {
        Environment::new(2 * h, h, vec![v; 2 * h * h * 3]).unwrap()
    }

    #[test]
    fn pixels_tile_the_sphere() {
        let e = constant(16, 1.0);
        let total: f64 = (0..16).map(|r| e.pixel_solid_angle(r) * 32.0).sum();
        assert!((total - 4.0 * PI).abs() < 1e-12);
        // Directions are unit and land back in their own pixel.
        for (r, c) in [(0, 0), (5, 17), (15, 31), (8, 0)] {
            let d = e.direction(r, c, 0.3, 0.7);
            assert!(((d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() - 1.0).abs() < 1e-12);
            let theta = d[2].acos();
            let phi = d[1].atan2(d[0]).rem_euclid(2.0 * PI);
            assert_eq!(((theta / PI * 16.0) as usize, (phi / (2.0 * PI) * 32.0) as usize), (r, c));
        }
    }

    #[test]
    fn sampled_weights_integrate_the_environment() {
        // Sum of the light intensities = integral of the radiance over the sphere (sum of
        // pixel x solid angle), for any seed and sample count: the estimator of a constant
        // BTF is exact when every sample shares the luminance-proportional weight.
        let mut rgb = vec![0.0f32; 32 * 16 * 3];
        for (i, v) in rgb.iter_mut().enumerate() {
            *v = ((i * 7919) % 13) as f32 * 0.1 * (1 + i % 3) as f32;
        }
        let e = Environment::new(32, 16, rgb).unwrap();
        let mut exact = [0.0f64; 3];
        for l in e.quadrature_lights() {
            let Light::Directional { intensity, .. } = l else { unreachable!() };
            for ch in 0..3 {
                exact[ch] += intensity[ch] as f64;
            }
        }
        // Grey pixels make every sample's weight equal in luminance: the luminance sum is exact.
        let lum_exact = luminance(exact.map(|x| x as f32));
        for (n, seed) in [(1usize, 1u64), (7, 2), (64, 3), (1000, 4)] {
            let lights = e.sample_lights(n, seed).unwrap();
            assert_eq!(lights.len(), n);
            let mut lum = 0.0;
            for l in &lights {
                let Light::Directional { intensity, direction } = *l else { unreachable!() };
                lum += luminance(intensity);
                let len = direction.iter().map(|x| x * x).sum::<f32>().sqrt();
                assert!((len - 1.0).abs() < 1e-5);
            }
            assert!((lum / lum_exact - 1.0).abs() < 1e-4, "n {n}: {lum} vs {lum_exact}");
        }
        // Same seed, same lights; another seed, others.
        assert_eq!(e.sample_lights(16, 5).unwrap(), e.sample_lights(16, 5).unwrap());
        assert_ne!(e.sample_lights(16, 5).unwrap(), e.sample_lights(16, 6).unwrap());
    }

    #[test]
    fn samples_follow_the_luminance() {
        // Only the top-left pixel and one pixel of the equator are lit, in ratio 1 : 3 of
        // luminance x solid angle: every sample lands in one of them, in that proportion.
        let mut rgb = vec![0.0f32; 64 * 32 * 3];
        let (ra, rb) = (0usize, 16usize);
        let e0 = Environment::new(64, 32, vec![1.0; 64 * 32 * 3]).unwrap();
        let (oa, ob) = (e0.pixel_solid_angle(ra), e0.pixel_solid_angle(rb));
        rgb[(ra * 64) * 3..][..3].copy_from_slice(&[1.0; 3]);
        let vb = (3.0 * oa / ob) as f32;
        rgb[(rb * 64 + 5) * 3..][..3].copy_from_slice(&[vb; 3]);
        let e = Environment::new(64, 32, rgb).unwrap();
        let lights = e.sample_lights(4000, 11).unwrap();
        let in_b = lights
            .iter()
            .filter(|l| {
                let Light::Directional { direction, .. } = l else { unreachable!() };
                let d = direction.map(|x| x as f64);
                e.lookup(d)[0] == vb
            })
            .count();
        // Stratified: 3/4 of the samples exactly, up to the one stratum holding the boundary.
        assert!((2999..=3001).contains(&in_b), "{in_b} of 4000 in the brighter pixel");
    }

    #[test]
    fn sh_projection_of_known_functions() {
        // Constant radiance c: e_0 = c sqrt(4 pi), the rest 0. Radiance z (clamped >= 0 is not
        // linear; use 1 + z, non-negative): e_2 = integral z y_2 = sqrt(4 pi / 3).
        let h = 64;
        let e = constant(h, 2.0);
        let c = e.sh_project(9);
        assert!((c[0][1] - 2.0 * (4.0 * PI).sqrt()).abs() < 1e-6);
        // (Midpoint sub-samples: y_6 = (3 z^2 - 1) integrates to ~1e-4 of e_0 instead of 0.)
        assert!(c[1..].iter().all(|x| x[0].abs() < 1e-3), "{c:?}");
        let mut rgb = vec![0.0f32; 2 * h * h * 3];
        let e1 = constant(h, 1.0);
        for r in 0..h {
            for col in 0..2 * h {
                // The pixel's mean of 1 + z: z is linear in the row's cos range.
                let (t0, t1) = e1.row_theta(r);
                let z = 0.5 * (t0.cos() + t1.cos());
                rgb[(r * 2 * h + col) * 3..][..3].copy_from_slice(&[(1.0 + z) as f32; 3]);
            }
        }
        let c = Environment::new(2 * h, h, rgb).unwrap().sh_project(9);
        assert!((c[2][0] - (4.0 * PI / 3.0).sqrt()).abs() < 2e-3, "{}", c[2][0]);
        assert!((c[0][0] - (4.0 * PI).sqrt()).abs() < 1e-5);
        assert!(c[1][0].abs() < 1e-6 && c[3][0].abs() < 1e-6);
    }

    #[test]
    fn sky_is_brightest_near_the_sun_and_blue_overhead() {
        let sun = [0.6, 0.0, 0.8];
        let e = Environment::sky(sun, 3.0, 512, 0.2).unwrap();
        let zen = e.lookup([0.0, 0.0, 1.0]);
        assert!((luminance(zen) - 1.0).abs() < 0.01, "zenith luminance {}", luminance(zen));
        let near = e.lookup([0.62, 0.0, 0.78]);
        let away = e.lookup([-0.6, 0.0, 0.8]);
        assert!(luminance(near) > 3.0 * luminance(away));
        assert!(zen[2] > zen[0], "the zenith of a clear sky is blue: {zen:?}");
        // Hazier skies are whiter: the blue / red ratio overhead falls with turbidity.
        let hazy = Environment::sky(sun, 9.0, 64, 0.2).unwrap().lookup([0.0, 0.0, 1.0]);
        assert!(hazy[2] / hazy[0] < zen[2] / zen[0]);
        // The ground: uniform, below the horizon.
        let g = e.lookup([0.3, 0.2, -0.9]);
        assert_eq!(g, e.lookup([-0.5, 0.1, -0.2]));
    }

    #[test]
    fn bad_input_is_named() {
        let name = |r: Result<Environment>| match r {
            Err(Error::InvalidArgument { name, .. }) => name,
            other => panic!("{other:?}"),
        };
        assert_eq!(name(Environment::new(30, 16, vec![1.0; 30 * 16 * 3])), "environment");
        let mut nan = vec![1.0; 32 * 16 * 3];
        nan[77] = f32::NAN;
        assert_eq!(name(Environment::new(32, 16, nan)), "environment");
        let mut neg = vec![1.0; 32 * 16 * 3];
        neg[5] = -1.0;
        assert_eq!(name(Environment::new(32, 16, neg)), "environment");
        assert_eq!(name(Environment::new(32, 16, vec![0.0; 32 * 16 * 3])), "environment");
        assert_eq!(name(Environment::sky([0.0, 0.0, -1.0], 3.0, 16, 0.2)), "sun");
        assert_eq!(name(Environment::sky([0.0, 0.0, 1.0], 20.0, 16, 0.2)), "turbidity");
        match constant(4, 1.0).sample_lights(0, 1) {
            Err(Error::InvalidArgument { name, .. }) => assert_eq!(name, "samples"),
            other => panic!("{other:?}"),
        }
    }
}
