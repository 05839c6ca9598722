//! Solid-angle quadrature over a measured set of hemisphere directions.
//!
//! The constrained least squares of paper 002 (appendix) bounds the energy of the SH coefficients
//! by the energy of the sampled function, `E = integral of f^2` over the sphere of (view, light)
//! pairs. A BTF is sampled at a few scattered directions (UBO's 81), so the integral is a weighted
//! sum over the samples; the weights come from here. They are also the natural weights of any
//! other integral over a BTF's directions.

use rayon::prelude::*;

/// Grid cells per side of the equal-area hemisphere grid used by [`solid_angle_weights`].
const WEIGHT_GRID: usize = 256;

/// Solid-angle quadrature weights of a set of hemisphere directions, summing to 2 pi.
///
/// A uniform `256 x 256` grid of the unit square is mapped to the hemisphere by the equal-area
/// elevated concentric map (`btfrs_hemimap::square_to_hemisphere`), so every cell covers
/// `2 pi / 256^2` sr; each cell goes to its angularly nearest direction (a Voronoi partition of
/// the hemisphere). Identical directions share their cell's weight equally.
pub fn solid_angle_weights(dirs: &[[f64; 3]]) -> Vec<f64> {
    let n = dirs.len();
    if n == 0 {
        return Vec::new();
    }
    let g = WEIGHT_GRID;
    let counts = (0..g)
        .into_par_iter()
        .fold(
            || vec![0u64; n],
            |mut acc, r| {
                let t = (r as f64 + 0.5) / g as f64;
                for c in 0..g {
                    let s = (c as f64 + 0.5) / g as f64;
                    let p: [f64; 3] = btfrs_hemimap::square_to_hemisphere(s, t);
                    let (mut best, mut arg) = (f64::NEG_INFINITY, 0);
                    for (k, d) in dirs.iter().enumerate() {
                        let dot = p[0] * d[0] + p[1] * d[1] + p[2] * d[2];
                        if dot > best {
                            best = dot;
                            arg = k;
                        }
                    }
                    acc[arg] += 1;
                }
                acc
            },
        )
        .reduce(
            || vec![0u64; n],
            |mut a, b| {
                a.iter_mut().zip(&b).for_each(|(x, y)| *x += y);
                a
            },
        );
    let cell = std::f64::consts::TAU / (g * g) as f64;
    let mut w: Vec<f64> = counts.iter().map(|&k| k as f64 * cell).collect();
    // Ties go to the first of identical directions; spread each group's weight over its members.
    for i in 0..n {
        let same: Vec<usize> = (i..n).filter(|&j| dirs[j] == dirs[i]).collect();
        if same.len() > 1 && w[i] > 0.0 {
            let share = same.iter().map(|&j| w[j]).sum::<f64>() / same.len() as f64;
            same.iter().for_each(|&j| w[j] = share);
        }
    }
    w
}
