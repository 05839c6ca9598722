//! The per-texel microfacet lobe of the `svbrdf` model: a Lambertian diffuse colour plus a GGX
//! specular lobe (Walter et al. 2007) with Smith's separable shadowing-masking, about a
//! per-texel shading normal, in the BTF convention (values are pi times the BRDF times the
//! cosine of the light's angle to the shading normal, as the built-in materials and measured
//! BTFs hold them):
//!
//! ```text
//! value = rho_d (n.l) + rho_s pi D(n.h) G1(n.l) G1(n.v) / (4 n.v)
//! D(c)  = alpha^2 / (pi (c^2 (alpha^2 - 1) + 1)^2)
//! G1(c) = 2 c / (c + sqrt(alpha^2 + (1 - alpha^2) c^2))
//! ```
//!
//! zero where the light or the view is below the shading normal's horizon. This is Mitsuba 3's
//! `roughconductor` (GGX, `material="none"`: a Fresnel factor of 1) times `rho_s`, plus its
//! `diffuse`, the form the Mitsuba export writes exactly. For a fixed normal and roughness the
//! value is linear in `rho_d` and `rho_s`: [`basis`] gives the two functions.

/// Smallest roughness: below it the lobe is a near-mirror that sparse sampling cannot pin down.
pub const ALPHA_MIN: f64 = 0.02;
/// Largest roughness (GGX at alpha 1 is already wider than a Lambertian lobe's cosine).
pub const ALPHA_MAX: f64 = 1.0;

#[inline]
fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// GGX's normal distribution at `c` = cos(normal, half vector).
#[inline]
pub fn ggx_d(c: f64, alpha: f64) -> f64 {
    let a2 = alpha * alpha;
    let t = c * c * (a2 - 1.0) + 1.0;
    a2 / (std::f64::consts::PI * t * t)
}

/// Smith's GGX masking for a direction at `c` = cos(normal, direction), `c > 0`.
#[inline]
pub fn ggx_g1(c: f64, alpha: f64) -> f64 {
    let a2 = alpha * alpha;
    2.0 * c / (c + (a2 + (1.0 - a2) * c * c).sqrt())
}

/// The two basis functions at unit `view`, `light` and normal `n`: `(diffuse, specular)`, the
/// value being `rho_d * diffuse + rho_s * specular` per channel.
#[inline]
pub fn basis(n: [f64; 3], alpha: f64, view: [f64; 3], light: [f64; 3]) -> (f64, f64) {
    basis_of(geometry(n, view, light), alpha)
}

/// What [`basis`] needs of the directions: `[n.l, n.v, n.h]`, all 0 where the light or the
/// view is below the shading normal's horizon or the surface's (the value is 0 there). For a
/// fixed normal it is computed once per pair, the roughness varied over it.
#[inline]
pub fn geometry(n: [f64; 3], view: [f64; 3], light: [f64; 3]) -> [f64; 3] {
    let nl = dot(n, light);
    let nv = dot(n, view);
    if nl <= 0.0 || nv <= 0.0 || light[2] <= 0.0 || view[2] <= 0.0 {
        return [0.0; 3];
    }
    let h = [light[0] + view[0], light[1] + view[1], light[2] + view[2]];
    let hl = dot(h, h).sqrt();
    let nh = if hl > 0.0 { dot(n, h) / hl } else { 0.0 };
    [nl, nv, nh]
}

/// [`basis`] from [`geometry`].
#[inline]
pub fn basis_of(g: [f64; 3], alpha: f64) -> (f64, f64) {
    let [nl, nv, nh] = g;
    if nl <= 0.0 {
        return (0.0, 0.0);
    }
    if nh <= 0.0 {
        return (nl, 0.0);
    }
    let spec = std::f64::consts::PI * ggx_d(nh, alpha) * ggx_g1(nl, alpha) * ggx_g1(nv, alpha) / (4.0 * nv);
    (nl, spec)
}

/// The unit normal of slopes `(p, q)`: `(-p, -q, 1) / |.|`, the normal of a height whose
/// derivatives along x and y are `p` and `q`.
#[inline]
pub fn normal_of(p: f64, q: f64) -> [f64; 3] {
    let l = (p * p + q * q + 1.0).sqrt();
    [-p / l, -q / l, 1.0 / l]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_distribution_is_normalised_over_projected_area() {
        // int D(m) (n.m) dm over the hemisphere = 1, by the midpoint rule in cos(theta).
        for alpha in [0.05, 0.2, 0.6, 1.0] {
            let n = 200_000;
            let mut s = 0.0;
            for i in 0..n {
                let c = (i as f64 + 0.5) / n as f64;
                s += ggx_d(c, alpha) * c * 2.0 * std::f64::consts::PI / n as f64;
            }
            assert!((s - 1.0).abs() < 2e-3, "alpha {alpha}: {s}");
        }
    }

    #[test]
    fn a_white_rough_lobe_reflects_at_most_what_it_receives() {
        // The directional albedo of the specular lobe alone (rho_s = 1) is <= 1 (single
        // scattering loses energy to masking) and close to 1 for a smooth lobe at normal
        // incidence. At alpha 1, D = 1 / pi and G1(c) = 2c / (1 + c): the albedo at normal
        // incidence is int_0^1 v / (1 + v) dv = 1 - ln 2 in closed form.
        let n = [0.0, 0.0, 1.0];
        let closed = 1.0 - std::f64::consts::LN_2;
        for (alpha, lo) in [(0.05, 0.95), (0.3, 0.85), (1.0, closed - 1e-4)] {
            let light = [0.0, 0.0, 1.0];
            let (nt, np) = (400, 800);
            let mut s = 0.0;
            for i in 0..nt {
                let t = (i as f64 + 0.5) / nt as f64 * std::f64::consts::FRAC_PI_2;
                for j in 0..np {
                    let p = (j as f64 + 0.5) / np as f64 * 2.0 * std::f64::consts::PI;
                    let v = [t.sin() * p.cos(), t.sin() * p.sin(), t.cos()];
                    // value / pi is the BRDF times cos(light); reciprocity: integrate over views
                    let (_, spec) = basis(n, alpha, v, light);
                    s += spec / std::f64::consts::PI
                        * v[2]
                        * t.sin()
                        * (std::f64::consts::FRAC_PI_2 / nt as f64)
                        * (2.0 * std::f64::consts::PI / np as f64);
                }
            }
            assert!(s <= 1.0 + 1e-3 && s > lo, "alpha {alpha}: albedo {s}");
            if alpha == 1.0 {
                assert!((s - closed).abs() < 1e-4, "alpha 1: albedo {s}, closed form {closed}");
            }
        }
    }

    #[test]
    fn the_lobe_is_reciprocal_and_dark_below_the_horizon() {
        let n = normal_of(0.3, -0.2);
        let (a, b) = ([0.2, 0.1, 0.97], [-0.5, 0.3, 0.81]);
        let (da, sa) = basis(n, 0.25, a, b);
        let (db, sb) = basis(n, 0.25, b, a);
        // pi f cos(light): swapping view and light swaps the cosine only.
        let (na, nb) = (dot(n, a), dot(n, b));
        assert!((sa / nb - sb / na).abs() < 1e-12 * (sa / nb).abs().max(1.0));
        assert!((da - nb).abs() < 1e-15 && (db - na).abs() < 1e-15);
        assert_eq!(basis(n, 0.25, a, [0.9, 0.0, -0.1f64.sqrt()]), (0.0, 0.0));
    }
}
