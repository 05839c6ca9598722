//! Directions in the sample's local tangent frame.
//!
//! Convention: z is the surface normal, x the sample's u axis (image columns, to the
//! right), y its v axis (image rows, upwards). Directions are unit vectors pointing *away* from
//! the surface (z >= 0); theta is the elevation measured from z, phi the azimuth from x towards y.

use crate::{Error, Result};

/// The elevations of the UBO 2003 sampling of the Bonn BTF database, in degrees.
pub const UBO_THETAS_DEG: [f64; 6] = [0.0, 15.0, 30.0, 45.0, 60.0, 75.0];
/// The number of evenly spaced azimuths (starting at phi = 0) on each UBO elevation ring.
pub const UBO_PHI_COUNTS: [usize; 6] = [1, 6, 12, 18, 20, 24];

/// Unit vector for elevation `theta` and azimuth `phi`, both in radians.
#[inline]
pub fn from_theta_phi(theta: f64, phi: f64) -> [f64; 3] {
    let (st, ct) = theta.sin_cos();
    let (sp, cp) = phi.sin_cos();
    [st * cp, st * sp, ct]
}

/// (theta, phi) in radians of a direction (need not be unit length); phi in [0, 2 pi).
#[inline]
pub fn to_theta_phi(d: [f64; 3]) -> (f64, f64) {
    let r = (d[0] * d[0] + d[1] * d[1]).sqrt();
    let theta = r.atan2(d[2]);
    let mut phi = d[1].atan2(d[0]);
    if phi < 0.0 {
        phi += std::f64::consts::TAU;
    }
    // Points on the pole have no azimuth; report 0 rather than whatever atan2(0, 0) gives.
    if r == 0.0 {
        phi = 0.0;
    }
    (theta, phi)
}

/// The 81 UBO 2003 directions, ordered ring by ring from the pole, azimuth increasing.
pub fn ubo81() -> Vec<[f64; 3]> {
    let mut out = Vec::with_capacity(81);
    for (theta, &n) in UBO_THETAS_DEG.iter().zip(UBO_PHI_COUNTS.iter()) {
        for j in 0..n {
            let phi = std::f64::consts::TAU * j as f64 / n as f64;
            out.push(from_theta_phi(theta.to_radians(), phi));
        }
    }
    out
}

/// Tolerance on |d| - 1 accepted for a "unit" direction.
pub const UNIT_TOL: f64 = 1e-3;

/// Check that every direction is finite, unit length within [`UNIT_TOL`] and has z >= 0
/// (a tiny negative z from rounding is accepted). `name` is the argument name for the error.
pub fn validate(name: &str, dirs: &[[f64; 3]]) -> Result<()> {
    if dirs.is_empty() {
        return Err(Error::arg(name, "expected at least one direction, got none"));
    }
    for (i, d) in dirs.iter().enumerate() {
        if !d.iter().all(|x| x.is_finite()) {
            return Err(Error::arg(name, format!("direction {i} is not finite: {d:?}")));
        }
        let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        if (n - 1.0).abs() > UNIT_TOL {
            return Err(Error::arg(
                name,
                format!("direction {i} = {d:?} has length {n:.6}; expected unit vectors (normalise them first)"),
            ));
        }
        if d[2] < -UNIT_TOL {
            return Err(Error::arg(
                name,
                format!("direction {i} = {d:?} points below the surface (z < 0); expected z >= 0"),
            ));
        }
    }
    Ok(())
}

/// Angle in radians between two unit vectors, robust near 0 and pi.
#[inline]
pub fn angle_between(a: [f64; 3], b: [f64; 3]) -> f64 {
    let c = [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
    let s = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
    let d = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    s.atan2(d)
}

/// Smallest measured light cosine [`cos_corrected`] divides by (a light 88.9 degrees off the
/// normal): below it the measured value is ~0 anyway and the ratio would only amplify noise.
pub const COS_FLOOR: f64 = 0.02;

/// Light interpolation weights with the cosine divided out (issue: blending values that include
/// `cos(theta_l)` underestimates every light between measured ones, since cos is concave: x0.957
/// at 40 degrees, x0.934 at 70 on the UBO rings). Each measured value is divided by its own
/// cosine and the blend multiplied by the query's: `w_k <- w_k cos(q) / max(cos(d_k), COS_FLOOR)`,
/// so a Lambertian sample (value `rho cos(theta_l)`) is reproduced exactly at every light
/// direction. The weights then no longer sum to 1.
pub fn cos_corrected(weights: &mut [(usize, f64)], dirs: &[[f64; 3]], query: [f64; 3]) {
    let q = query[2].max(0.0);
    for (i, w) in weights.iter_mut() {
        *w *= q / dirs[*i][2].max(COS_FLOOR);
    }
}

/// Interpolation weights of `query` over the `k` angularly nearest of `dirs`.
///
/// The weight of the i-th nearest is `1/d_i - 1/d_(k+1)` (normalised to sum 1), where `d_(k+1)`
/// is the distance of the first direction *not* used: a direction's weight falls to zero just as
/// it leaves the neighbour set, so the weights, and every image blended with them, change
/// continuously as the query moves (plain inverse-distance weights over the k nearest would jump
/// when the k-th and (k+1)-th nearest swap). A query that coincides with a measured direction
/// (within 1e-9 rad) gets that direction alone with weight 1, so evaluating a model at a measured
/// direction reproduces exactly what was fitted there. Used wherever a model is stored per
/// measured view slot (PTM, per-view Lafortune) and queried at any direction.
pub fn interp_weights(dirs: &[[f64; 3]], query: [f64; 3], k: usize) -> Vec<(usize, f64)> {
    let mut dist: Vec<(usize, f64)> = dirs.iter().enumerate().map(|(i, &d)| (i, angle_between(d, query))).collect();
    dist.sort_by(|a, b| a.1.total_cmp(&b.1));
    if dist.is_empty() {
        return dist;
    }
    if dist[0].1 < 1e-9 {
        return vec![(dist[0].0, 1.0)];
    }
    let k = k.clamp(1, dist.len());
    let cut = dist.get(k).map_or(0.0, |x| 1.0 / x.1);
    dist.truncate(k);
    let mut w: Vec<(usize, f64)> = dist.iter().map(|&(i, a)| (i, (1.0 / a - cut).max(0.0))).collect();
    let total: f64 = w.iter().map(|x| x.1).sum();
    if total > 0.0 {
        w.iter_mut().for_each(|x| x.1 /= total);
    } else {
        // All k nearest tie with the (k+1)-th: any convex choice is continuous here; take equal.
        w.iter_mut().for_each(|x| x.1 = 1.0 / k as f64);
    }
    w.retain(|x| x.1 > 0.0);
    w
}

/// Interpolation weights of the BTF value at (`view`, `light`) over the *present* pairs of a
/// `[V, L]` mask (`None` = all present), as `(view index, light index, weight)`.
///
/// The 3 x 3 product of [`interp_weights`] over views and lights, restricted to the present pairs
/// and renormalised; where none of those is present (a held-out pair queried at its own
/// directions, or a hole in the mask), inverse-distance weights over the 4 present pairs nearest
/// in summed angle, excluding a pair at distance 0 (which is absent). Used to fill held-out
/// entries of a fitted basis (LPCA) and to densify the angular sampling before a non-linear fit
/// (Lafortune), so that neither ever reads a pair the mask excludes.
pub fn present_pair_weights(
    views: &[[f64; 3]],
    lights: &[[f64; 3]],
    mask: Option<&[bool]>,
    view: [f64; 3],
    light: [f64; 3],
) -> Vec<(usize, usize, f64)> {
    let nl = lights.len();
    let has = |v: usize, l: usize| mask.is_none_or(|m| m[v * nl + l]);
    let mut out = Vec::with_capacity(9);
    for (v, wv) in interp_weights(views, view, 3) {
        for &(l, wl) in &interp_weights(lights, light, 3) {
            if has(v, l) && wv * wl > 0.0 {
                out.push((v, l, wv * wl));
            }
        }
    }
    let total: f64 = out.iter().map(|x| x.2).sum();
    if total > 0.0 {
        out.iter_mut().for_each(|x| x.2 /= total);
        return out;
    }
    let dv: Vec<f64> = views.iter().map(|&d| angle_between(d, view)).collect();
    let dl: Vec<f64> = lights.iter().map(|&d| angle_between(d, light)).collect();
    let near = nearest_present(&dv, &dl, has);
    let total: f64 = near.iter().map(|x| 1.0 / x.2).sum();
    near.into_iter().map(|(v, l, d)| (v, l, (1.0 / d) / total)).collect()
}

/// The (at most) 4 present pairs `(v, l, dv[v] + dl[l])` of smallest summed angle above `1e-9`,
/// nearest first, ties in pair order (`v`, then `l`): what a stable sort of every present pair
/// by distance, truncated to 4, gives, in one pass without the list (a held-out basis entry of
/// a 81 x 81 sampling is filled per absent pair, each a scan of the 6561 pairs).
fn nearest_present(dv: &[f64], dl: &[f64], has: impl Fn(usize, usize) -> bool) -> Vec<(usize, usize, f64)> {
    let mut near: Vec<(usize, usize, f64)> = Vec::with_capacity(5);
    for (v, &a) in dv.iter().enumerate() {
        for (l, &b) in dl.iter().enumerate() {
            let d = a + b;
            // Strictly nearer than the fourth: a later pair at an equal distance sorts after it.
            if d <= 1e-9 || (near.len() == 4 && d.total_cmp(&near[3].2).is_ge()) || !has(v, l) {
                continue;
            }
            let at = near.partition_point(|x| x.2.total_cmp(&d).is_le());
            near.insert(at, (v, l, d));
            near.truncate(4);
        }
    }
    near
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ubo81_has_the_bonn_layout() {
        let d = ubo81();
        assert_eq!(d.len(), 81);
        assert_eq!(d[0], [0.0, 0.0, 1.0]);
        // Second ring: theta 15 deg, 6 azimuths starting at phi = 0.
        let (t, p) = to_theta_phi(d[1]);
        assert!((t.to_degrees() - 15.0).abs() < 1e-12 && p.abs() < 1e-12);
        let (t, p) = to_theta_phi(d[2]);
        assert!((t.to_degrees() - 15.0).abs() < 1e-12 && (p.to_degrees() - 60.0).abs() < 1e-9);
        let (t, _) = to_theta_phi(d[80]);
        assert!((t.to_degrees() - 75.0).abs() < 1e-12);
        validate("dirs", &d).unwrap();
    }

    #[test]
    fn theta_phi_round_trip() {
        for i in 0..50 {
            let theta = 1.5 * i as f64 / 50.0 + 0.01;
            let phi = 6.2 * ((i * 7) % 50) as f64 / 50.0;
            let (t, p) = to_theta_phi(from_theta_phi(theta, phi));
            assert!((t - theta).abs() < 1e-12 && (p - phi).abs() < 1e-12, "{theta} {phi} -> {t} {p}");
        }
    }

    #[test]
    fn validation_names_the_argument() {
        let e = validate("lights", &[[0.0, 0.0, 2.0]]).unwrap_err().to_string();
        assert!(e.starts_with("lights:") && e.contains("length 2.0"), "{e}");
        let e = validate("views", &[[0.0, 0.0, -1.0]]).unwrap_err().to_string();
        assert!(e.contains("z < 0"), "{e}");
        assert!(validate("views", &[[f64::NAN, 0.0, 1.0]]).is_err());
    }

    #[test]
    fn interp_weights_are_exact_on_measured_directions() {
        let d = ubo81();
        assert_eq!(interp_weights(&d, d[17], 3), vec![(17, 1.0)]);
        let q = from_theta_phi(0.4, 0.3);
        let w = interp_weights(&d, q, 3);
        assert_eq!(w.len(), 3);
        assert!((w.iter().map(|x| x.1).sum::<f64>() - 1.0).abs() < 1e-12);
        // The nearest direction gets the largest weight.
        assert!(w[0].1 >= w[1].1 && w[1].1 >= w[2].1);
    }
    #[test]
    fn nearest_present_is_the_stable_sort_truncated() {
        // Against the definition: every present pair sorted by distance (stable, so ties in
        // pair order), the first 4. Quantized distances make ties common.
        let mut rng = crate::rng::Rng::new(7);
        for case in 0..200 {
            let (nv, nl) = (1 + rng.below(9), 1 + rng.below(9));
            let q = |rng: &mut crate::rng::Rng| if case % 2 == 0 { rng.below(4) as f64 * 0.25 } else { rng.next_f64() };
            let dv: Vec<f64> = (0..nv).map(|_| q(&mut rng)).collect();
            let dl: Vec<f64> = (0..nl).map(|_| q(&mut rng)).collect();
            let mask: Vec<bool> = (0..nv * nl).map(|_| rng.below(5) != 0).collect();
            let has = |v: usize, l: usize| mask[v * nl + l];
            let mut all: Vec<(usize, usize, f64)> = (0..nv)
                .flat_map(|v| (0..nl).map(move |l| (v, l)))
                .filter(|&(v, l)| has(v, l))
                .map(|(v, l)| (v, l, dv[v] + dl[l]))
                .filter(|x| x.2 > 1e-9)
                .collect();
            all.sort_by(|a, b| a.2.total_cmp(&b.2));
            all.truncate(4);
            assert_eq!(nearest_present(&dv, &dl, has), all, "case {case}");
        }
    }

    #[test]
    fn present_pair_weights_avoid_absent_pairs() {
        let d = ubo81();
        let n = d.len();
        // Everything present: the plain 3 x 3 product, exact at measured pairs.
        assert_eq!(present_pair_weights(&d, &d, None, d[4], d[9]), vec![(4, 9, 1.0)]);
        // Pair (4, 9) held out: its value comes from other present pairs only, weights sum to 1.
        let mut mask = vec![true; n * n];
        mask[4 * n + 9] = false;
        let w = present_pair_weights(&d, &d, Some(&mask), d[4], d[9]);
        assert_eq!(w.len(), 4);
        assert!(w.iter().all(|&(v, l, x)| (v, l) != (4, 9) && x > 0.0));
        assert!((w.iter().map(|x| x.2).sum::<f64>() - 1.0).abs() < 1e-12);
        // Between measured directions with one of the 9 neighbours absent: renormalised over 8.
        let (q, r) = (from_theta_phi(0.4, 0.3), from_theta_phi(0.7, 2.0));
        let full = present_pair_weights(&d, &d, None, q, r);
        let (v0, l0, _) = full[0];
        mask[v0 * n + l0] = false;
        let part = present_pair_weights(&d, &d, Some(&mask), q, r);
        assert_eq!(part.len(), full.len() - 1);
        assert!((part.iter().map(|x| x.2).sum::<f64>() - 1.0).abs() < 1e-12);
    }
}
