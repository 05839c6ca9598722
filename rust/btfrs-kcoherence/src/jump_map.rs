//! The jump map (Zelinka and Garland, "Towards real-time texture synthesis with the jump map",
//! 2002; paper 000's reference 19), over the same analysis as k-coherence.
//!
//! Every sample pixel's list of similar neighbourhoods, with probabilities from their distances,
//! is a *jump map* ("to support the Jump Map: calculate a probability for each q_1..q_m depending
//! on the distance"). Synthesis walks the output in scanline order and, for each pixel, continues
//! the patch of a known neighbour (left or above, chosen at random) — or, with probability
//! `jump`, or when the continuation leaves the sample, jumps to one of the similar pixels of
//! where it would have continued. No neighbourhood is compared at synthesis time, so it is much
//! faster than k-coherence; paper 000 found its results on BTFs too artefact-prone, which the
//! quality measures ([`crate::quality`]) show.
//!
//! The weights are `exp(-d_j / mean(d))` over the `m` entries of a pixel; all random choices are
//! hashes of (seed, pixel).

use crate::analysis::Analysis;
use crate::coordmap::CoordMap;
use crate::kcoherence::{check_size, neighbours_of, random_interior};
use btfrs_core::{rng, Error, Monitor, Result};

/// Parameters of a jump-map synthesis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JumpOptions {
    /// Output rows.
    pub height: usize,
    /// Output columns.
    pub width: usize,
    /// Window radius of the similar neighbourhoods used as jumps.
    pub radius: usize,
    /// Probability of a jump at each pixel (0 to 1).
    pub jump: f64,
    /// Seed of every random choice.
    pub seed: u64,
}

/// Synthesize a coordinate map with the jump map of the finest level.
pub fn jump_map(an: &Analysis, o: &JumpOptions, monitor: &Monitor) -> Result<CoordMap> {
    an.check_levels(o.radius, 1)?;
    if !(0.0..=1.0).contains(&o.jump) {
        return Err(Error::arg("jump", format!("expected a probability in [0, 1], got {}", o.jump)));
    }
    check_size(o.height, o.width, o.radius, 1)?;
    let nb = neighbours_of(an, o.radius, 1)?[0];
    let lv = &an.levels[0];
    let (sw, m, r) = (lv.width, nb.m, o.radius);
    let (h, w) = (o.height, o.width);
    let seed = rng::mix(o.seed ^ 0x1A11);
    monitor.start(h as u64);
    let mut src = vec![0u32; h * w];
    let pick = |base: usize, u: f64| -> u32 {
        let (idx, d) = (&nb.index[base * m..(base + 1) * m], &nb.dist[base * m..(base + 1) * m]);
        let valid = idx.iter().take_while(|&&i| i != u32::MAX).count();
        if valid == 0 {
            return base as u32;
        }
        let mean = d[..valid].iter().map(|&v| v as f64).sum::<f64>() / valid as f64;
        let wts: Vec<f64> =
            d[..valid].iter().map(|&v| if mean > 0.0 { (-(v as f64) / mean).exp() } else { 1.0 }).collect();
        let mut u = u * wts.iter().sum::<f64>();
        for (&i, &wt) in idx.iter().zip(&wts) {
            if u < wt {
                return i;
            }
            u -= wt;
        }
        idx[valid - 1]
    };
    for y in 0..h {
        monitor.check()?;
        for x in 0..w {
            let hx = |salt: u64| rng::hash01(seed ^ salt, x as i64, y as i64);
            let from = match (x > 0, y > 0) {
                (false, false) => None,
                (true, false) => Some((x - 1, y)),
                (false, true) => Some((x, y - 1)),
                (true, true) => Some(if hx(1) < 0.5 { (x - 1, y) } else { (x, y - 1) }),
            };
            let s = match from {
                None => random_interior(lv, r, seed, x, y),
                Some((nx, ny)) => {
                    let s = src[ny * w + nx] as usize;
                    let (dx, dy) = (x as isize - nx as isize, y as isize - ny as isize);
                    let (cx, cy) = ((s % sw) as isize + dx, (s / sw) as isize + dy);
                    let inside = lv.interior(cx, cy, r);
                    if inside && hx(2) >= o.jump {
                        (cy * sw as isize + cx) as u32
                    } else if inside {
                        pick((cy * sw as isize + cx) as usize, hx(3))
                    } else {
                        // The patch ran off the sample: continue from a pixel similar to the
                        // neighbour's source instead, shifted the same way when that stays inside.
                        let j = pick(s, hx(3)) as usize;
                        let (jx, jy) = ((j % sw) as isize + dx, (j / sw) as isize + dy);
                        if lv.interior(jx, jy, r) {
                            (jy * sw as isize + jx) as u32
                        } else {
                            j as u32
                        }
                    }
                }
            };
            src[y * w + x] = s;
        }
        monitor.advance(1);
    }
    let (h0, w0) = an.size();
    Ok(CoordMap { width: w, height: h, sample_width: w0, sample_height: h0, src })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::AnalysisOptions;
    use crate::pyramid::Features;

    #[test]
    fn jump_probability_controls_coherence() {
        let data = (0..24 * 24).map(|i| btfrs_core::rng::hash01(2, i as i64, 0) as f32).collect();
        let f = Features::new(24, 24, 1, data).unwrap();
        let opts = AnalysisOptions { textons: 64, levels: 1, m: 5, iterations: 5, seed: 0 };
        let an = Analysis::of_features(f, opts, &[1], &Monitor::new()).unwrap();
        let coherent = |jump: f64| {
            let o = JumpOptions { height: 40, width: 40, radius: 1, jump, seed: 4 };
            let m = jump_map(&an, &o, &Monitor::new()).unwrap();
            assert!(m.src.iter().all(|&s| an.levels[0].interior((s % 24) as isize, (s / 24) as isize, 1)));
            let mut c = 0;
            for y in 0..40 {
                for x in 0..39 {
                    let (a, b) = (m.source(x, y), m.source(x + 1, y));
                    c += (b == (a.0 + 1, a.1)) as usize;
                }
            }
            c as f64 / (40.0 * 39.0)
        };
        let (lo, hi) = (coherent(0.0), coherent(0.5));
        assert!(lo > hi + 0.2, "no jumps {lo} vs many {hi}");
        let o = JumpOptions { height: 40, width: 40, radius: 1, jump: 1.5, seed: 4 };
        assert!(jump_map(&an, &o, &Monitor::new()).unwrap_err().to_string().starts_with("jump:"));
    }
}
