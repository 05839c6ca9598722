//! Measures of a synthesized coordinate map against its sample, comparable across methods
//! (k-coherence, the jump map, plain tiling, random placement, other synthesizers' maps).
//!
//! **The headline measures** look at windows of the output image (each output pixel shows its
//! sample pixel's finest-level texton vector) at several scales ([`crate::windows`]: scale `l`
//! blurred `l` times, windows of radius `window` with taps `2^l` apart, so 7 x 7, 13 x 13 and
//! 25 x 25 pixels for `window = 3` over 3 scales), each scored by its exact nearest window of the
//! sample at the same scale, per pixel, divided by twice the sample's variance at that scale (1
//! is "as different as random pixels"). A window the output copied from the sample scores 0; a
//! window that exists nowhere in the sample (a mortar line ending in mid-brick, a brick cut in
//! two) scores what the closest real one differs from it:
//!
//! * `structure` (lower is better): the mean score of `windows` random output windows per scale,
//!   averaged over the scales with **equal weights** (`structure_levels` holds each scale's
//!   mean, finest first). Coarse scales see structure broken over tens of pixels.
//! * `seam_error`, `seam_error_p90` (lower is better): the mean and the 90th percentile of the
//!   scores of the windows that *straddle a discontinuity* of the coordinate map (adjacent output
//!   pixels whose sample pixels are not adjacent the same way, wrap-around of plain tiling
//!   included) within their footprint, up to `windows` of them per scale, each averaged over the
//!   scales with equal weights (a scale without such windows counts 0). Windows inside a patch
//!   copy the sample and score 0, so these look at the seams only: plain tiling of a crop that
//!   does not tile scores badly, tiling a periodic sample at its period (when the sample holds a
//!   whole period plus a window) scores 0. Caveat: a sample that is exactly one period has no
//!   window across its own wrap-around, so even a seamless tiling of it scores its best match.
//! * `straddling`: the fraction of the finest scale's output windows that straddle a
//!   discontinuity (how much of the output is near a seam).
//!
//! **The older pair and window measures**, kept for comparison (they are blind to broken
//! structure: the pair seam costs of plain tiling are 0 wherever its edge pixels look like some
//! adjacent pair of the sample, and `nn_distance` is dominated by the copied windows inside the
//! patches). Their distances are the analysis's texton distances at the finest level, divided by
//! the mean distance between two random sample pixels:
//!
//! * `nn_distance` (lower is better): for a set of output pixels, the distance per pixel from the
//!   output window (radius `r`) to the best matching window anywhere in the sample. It is what
//!   the synthesis minimises, measured exhaustively instead of over candidates.
//! * `coherence`: the fraction of adjacent output pixel pairs that are adjacent in the sample
//!   the same way (copied patches). Descriptive: tiling is almost fully coherent, random
//!   placement not at all.
//! * `seam_mean` and `seam` (lower is better): the cost of each adjacent pair `(p, q = p + e)` is
//!   0 when coherent, otherwise how far what was placed differs from what would have continued
//!   either side (`D(S[s(p) + e], S[s(q)])` and `D(S[s(p)], S[s(q) - e])`, averaged over the ones
//!   inside the sample: the seam cost of graph-cut texture synthesis; when neither is, the
//!   distance of the placed pair to the closest adjacent pair of the sample). `seam_mean` averages
//!   all pairs; `seam` is the *median* cost along the worst straight line of pairs (a row or
//!   column boundary): nonzero only where most of a whole line is broken, i.e. a visible seam
//!   line, the artefact of tiling. Scattered patch borders, however costly, leave it at 0.
//! * `repetition` (lower is better): the largest fraction of output pixels whose sample pixel
//!   reappears at one fixed translation `t` (`2r + 1 <= |t|` and `|t| <= ` the sample size, in
//!   the max norm): 1 - size/width for tiling, near 0 for random placement.

use crate::analysis::Analysis;
use crate::coordmap::CoordMap;
use crate::windows::{self, Img, Search};
use btfrs_core::{rng, Error, Monitor, Result};
use rayon::prelude::*;

/// Parameters of [`quality`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct QualityOptions {
    /// Window radius of the old `nn_distance` (texton windows).
    pub radius: usize,
    /// Output pixels measured by `nn_distance` (all of them when fewer).
    pub samples: usize,
    /// Output windows measured per scale, for `structure` and again for `seam_error` (all of
    /// them when fewer).
    pub windows: usize,
    /// Seed of the choice of windows.
    pub seed: u64,
    /// Window radius at every scale of `structure` and `seam_error` (3: 7 x 7 taps).
    pub window: usize,
    /// Scales of `structure` and `seam_error` (as many as fit in the sample and the output).
    pub scales: usize,
}

impl Default for QualityOptions {
    fn default() -> Self {
        Self { radius: 2, samples: 4096, windows: 1024, seed: 0, window: 3, scales: 3 }
    }
}

/// The quality measures of one coordinate map (see the module doc).
#[derive(Debug, Clone, PartialEq)]
pub struct Quality {
    /// Mean multi-scale window score (normalised), scales weighted equally.
    pub structure: f64,
    /// Mean window score per scale, finest first.
    pub structure_levels: Vec<f64>,
    /// Mean score of the windows straddling a coordinate-map discontinuity.
    pub seam_error: f64,
    /// 90th percentile of the scores of the straddling windows.
    pub seam_error_p90: f64,
    /// Fraction of the finest-scale output windows straddling a discontinuity.
    pub straddling: f64,
    /// Mean per-pixel distance of output windows to their best sample match (normalised).
    pub nn_distance: f64,
    /// Fraction of coherent adjacent pairs.
    pub coherence: f64,
    /// Median seam cost along the worst row or column boundary (normalised).
    pub seam: f64,
    /// Mean seam cost over all adjacent pairs (normalised).
    pub seam_mean: f64,
    /// Largest fraction of pixels repeated at one translation.
    pub repetition: f64,
    /// Output pixels used for `nn_distance`.
    pub samples: usize,
}

/// Measure `map` against the sample analysed in `an` (see [`QualityOptions`]). `monitor`
/// advances by one per 64 measured windows.
pub fn quality(an: &Analysis, map: &CoordMap, o: &QualityOptions, monitor: &Monitor) -> Result<Quality> {
    let (radius, samples, seed) = (o.radius, o.samples, o.seed);
    let lv = &an.levels[0];
    if (map.sample_height, map.sample_width) != (lv.height, lv.width) {
        return Err(Error::arg(
            "coords",
            format!(
                "the map points into a {} x {} sample, the analysis is of a {} x {} sample",
                map.sample_height, map.sample_width, lv.height, lv.width
            ),
        ));
    }
    an.check_levels(radius, 1)?;
    if samples == 0 {
        return Err(Error::arg("samples", "expected at least 1 output pixel to measure, got 0"));
    }
    let tex = &lv.textons;
    let norm = tex.mean_pair_distance();
    let norm = if norm > 0.0 { norm } else { 1.0 };
    let (h, w) = (map.height, map.width);
    let n = h * w;
    let pick: Vec<usize> = if samples >= n {
        (0..n).collect()
    } else {
        (0..samples).map(|i| (rng::hash01(seed, i as i64, 3) * n as f64) as usize).collect()
    };
    let ms = MultiScale::new(an, map, o)?;
    monitor.start(pick.len().div_ceil(64) as u64 + ms.units());
    let ms = ms.run(monitor)?;
    let t_out: Vec<u16> = map.src.iter().map(|&s| tex.assign[s as usize]).collect();
    let nn: Vec<f64> = pick
        .par_chunks(64)
        .map(|chunk| -> Result<Vec<f64>> {
            monitor.check()?;
            let v = chunk.iter().map(|&p| best_match(an, &t_out, w, h, p, radius)).collect();
            monitor.advance(1);
            Ok(v)
        })
        .collect::<Result<Vec<_>>>()?
        .into_iter()
        .flatten()
        .collect();
    let nn_distance = nn.iter().sum::<f64>() / nn.len() as f64 / norm;

    // Seams and coherence over all adjacent pairs.
    let (sw, sh) = (lv.width as isize, lv.height as isize);
    let cost = |p: usize, q: usize, ex: isize, ey: isize| -> (bool, f64) {
        let (a, b) = (map.src[p] as isize, map.src[q] as isize);
        let (ax, ay, bx, by) = (a % sw, a / sw, b % sw, b / sw);
        if bx == ax + ex && by == ay + ey {
            return (true, 0.0);
        }
        let inside = |x: isize, y: isize| x >= 0 && y >= 0 && x < sw && y < sh;
        let d = |i: isize, j: isize| tex.d(tex.assign[i as usize], tex.assign[j as usize]) as f64;
        let mut s = 0.0;
        let mut c = 0;
        if inside(ax + ex, ay + ey) {
            s += d((ay + ey) * sw + ax + ex, b);
            c += 1;
        }
        if inside(bx - ex, by - ey) {
            s += d(a, (by - ey) * sw + bx - ex);
            c += 1;
        }
        if c > 0 {
            return (false, s / c as f64);
        }
        // Neither patch continues inside the sample (both sources on its edge, as at the seams of
        // plain tiling): ask instead how close the placed pair is to any adjacent pair of the
        // sample. A periodic sample's wrap-around pair then costs what it should, nearly nothing.
        let mut best = f64::INFINITY;
        for uy in 0.max(-ey)..sh - 0.max(ey) {
            for ux in 0.max(-ex)..sw - 0.max(ex) {
                let u = uy * sw + ux;
                best = best.min(d(u, a) + d(u + ey * sw + ex, b));
            }
        }
        (false, 0.5 * best)
    };
    // Vertical boundaries (between columns x and x + 1) and horizontal ones (rows y, y + 1).
    // Per line: (coherent pairs, summed cost, median cost).
    let line = |costs: Vec<(bool, f64)>| -> (usize, f64, f64) {
        let coherent = costs.iter().filter(|c| c.0).count();
        let total = costs.iter().map(|c| c.1).sum();
        let mut v: Vec<f64> = costs.iter().map(|c| c.1).collect();
        let mid = v.len() / 2;
        let median = *v.select_nth_unstable_by(mid, f64::total_cmp).1;
        (coherent, total, median)
    };
    let vert: Vec<(usize, f64, f64)> = (0..w.saturating_sub(1))
        .into_par_iter()
        .map(|x| line((0..h).map(|y| cost(y * w + x, y * w + x + 1, 1, 0)).collect()))
        .collect();
    let horiz: Vec<(usize, f64, f64)> = (0..h.saturating_sub(1))
        .into_par_iter()
        .map(|y| line((0..w).map(|x| cost(y * w + x, (y + 1) * w + x, 0, 1)).collect()))
        .collect();
    let pairs = (vert.len() * h + horiz.len() * w).max(1) as f64;
    let coherent: usize = vert.iter().chain(&horiz).map(|v| v.0).sum();
    let total: f64 = vert.iter().chain(&horiz).map(|v| v.1).sum();
    let worst = vert.iter().chain(&horiz).map(|v| v.2).fold(0.0, f64::max);

    Ok(Quality {
        structure: ms.structure,
        structure_levels: ms.structure_levels,
        seam_error: ms.seam_error,
        seam_error_p90: ms.seam_error_p90,
        straddling: ms.straddling,
        nn_distance,
        coherence: coherent as f64 / pairs,
        seam: worst / norm,
        seam_mean: total / pairs / norm,
        repetition: repetition(map, 2 * radius + 1),
        samples: pick.len(),
    })
}

/// The multi-scale window measures, prepared: images per scale and the windows to score.
struct MultiScale {
    sample: Vec<Img>,
    out: Vec<Img>,
    r: usize,
    /// The map's sample pixels, output width, sample width.
    src: Vec<u32>,
    w: usize,
    sw: usize,
    /// Per scale: random centres (structure) and straddling centres (seams).
    random: Vec<Vec<(usize, usize)>>,
    straddle: Vec<Vec<(usize, usize)>>,
    straddling: f64,
}

struct MultiScaleResult {
    structure: f64,
    structure_levels: Vec<f64>,
    seam_error: f64,
    seam_error_p90: f64,
    straddling: f64,
}

impl MultiScale {
    fn new(an: &Analysis, map: &CoordMap, o: &QualityOptions) -> Result<Self> {
        let r = o.window;
        if r == 0 || r > crate::analysis::MAX_RADIUS {
            return Err(Error::arg(
                "window",
                format!("expected a window radius of 1 to {}, got {r}", crate::analysis::MAX_RADIUS),
            ));
        }
        if o.windows == 0 {
            return Err(Error::arg("windows", "expected at least 1 output window per scale, got 0"));
        }
        if o.scales == 0 || o.scales > 6 {
            return Err(Error::arg("scales", format!("expected 1 to 6 scales, got {}", o.scales)));
        }
        let tex = &an.levels[0].textons;
        let (sh, sw) = an.size();
        let d = tex.dim;
        let vec_of = |s: usize| &tex.centers[tex.assign[s] as usize * d..(tex.assign[s] as usize + 1) * d];
        let fits = |h: usize, w: usize, l: usize| {
            let m = windows::margin(r, l);
            h >= 2 * m + 4 && w >= 2 * m + 4
        };
        let (h, w) = (map.height, map.width);
        let levels = (0..o.scales).take_while(|&l| fits(sh, sw, l) && fits(h, w, l)).count();
        if levels == 0 {
            return Err(Error::arg(
                "window",
                format!(
                    "windows of radius {r} need a sample and an output of at least {0} x {0} pixels; the sample is \
                     {sh} x {sw}, the output {h} x {w}",
                    2 * r + 5
                ),
            ));
        }
        let sample = Img { h: sh, w: sw, d, data: (0..sh * sw).flat_map(vec_of).copied().collect() };
        let out = Img { h, w, d, data: map.src.iter().flat_map(|&s| vec_of(s as usize)).copied().collect() };
        let (sample, out) = (windows::scales(sample, levels), windows::scales(out, levels));
        // Discontinuities: horizontal pair (x, y)-(x+1, y) at hd[y][x], vertical (x, y)-(x, y+1)
        // at vd[y][x]; summed-area tables over them.
        let src_xy = |p: usize| ((map.src[p] as usize % sw) as isize, (map.src[p] as usize / sw) as isize);
        let sat = |f: &dyn Fn(usize, usize) -> bool| -> Vec<u32> {
            let mut t = vec![0u32; (h + 1) * (w + 1)];
            for y in 0..h {
                for x in 0..w {
                    t[(y + 1) * (w + 1) + x + 1] =
                        f(x, y) as u32 + t[y * (w + 1) + x + 1] + t[(y + 1) * (w + 1) + x] - t[y * (w + 1) + x];
                }
            }
            t
        };
        let hd = sat(&|x, y| {
            x + 1 < w && {
                let (a, b) = (src_xy(y * w + x), src_xy(y * w + x + 1));
                b != (a.0 + 1, a.1)
            }
        });
        let vd = sat(&|x, y| {
            y + 1 < h && {
                let (a, b) = (src_xy(y * w + x), src_xy((y + 1) * w + x));
                b != (a.0, a.1 + 1)
            }
        });
        // Sum of a table over x0..x1, y0..y1 (exclusive ends).
        let area = |t: &[u32], x0: usize, x1: usize, y0: usize, y1: usize| {
            t[y1 * (w + 1) + x1] + t[y0 * (w + 1) + x0] - t[y0 * (w + 1) + x1] - t[y1 * (w + 1) + x0]
        };
        let mut random = Vec::new();
        let mut straddle = Vec::new();
        let mut straddling = 0.0;
        for l in 0..levels {
            let m = windows::margin(r, l);
            let all: Vec<(usize, usize)> = (m..h - m).flat_map(|y| (m..w - m).map(move |x| (x, y))).collect();
            let cut: Vec<(usize, usize)> = all
                .iter()
                .copied()
                .filter(|&(x, y)| {
                    let (x0, x1, y0, y1) = (x - m, x + m + 1, y - m, y + m + 1);
                    area(&hd, x0, x1 - 1, y0, y1) + area(&vd, x0, x1, y0, y1 - 1) > 0
                })
                .collect();
            if l == 0 {
                straddling = cut.len() as f64 / all.len() as f64;
            }
            random.push(windows::draw(&all, o.windows, o.seed, 2 * l as i64 + 101));
            straddle.push(windows::draw(&cut, o.windows, o.seed, 2 * l as i64 + 102));
        }
        Ok(Self { sample, out, r, src: map.src.clone(), w, sw, random, straddle, straddling })
    }

    fn units(&self) -> u64 {
        self.random.iter().chain(&self.straddle).map(|v| v.len().div_ceil(64) as u64).sum()
    }

    fn run(self, monitor: &Monitor) -> Result<MultiScaleResult> {
        let levels = self.sample.len();
        let (mut structure_levels, mut seam, mut p90) = (Vec::new(), 0.0, 0.0);
        for l in 0..levels {
            let search = Search::new(&self.sample[l], self.r, l).expect("the scale fits (checked)");
            let hint = |x: usize, y: usize| {
                let s = self.src[y * self.w + x] as usize;
                (s % self.sw, s / self.sw)
            };
            let s = windows::score(&search, &self.out[l], &self.random[l], &hint, monitor)?;
            structure_levels.push(s.iter().sum::<f64>() / s.len().max(1) as f64);
            let mut c = windows::score(&search, &self.out[l], &self.straddle[l], &hint, monitor)?;
            if !c.is_empty() {
                seam += c.iter().sum::<f64>() / c.len() as f64;
                c.sort_unstable_by(f64::total_cmp);
                p90 += c[(0.9 * (c.len() - 1) as f64).round() as usize];
            }
        }
        Ok(MultiScaleResult {
            structure: structure_levels.iter().sum::<f64>() / levels as f64,
            structure_levels,
            seam_error: seam / levels as f64,
            seam_error_p90: p90 / levels as f64,
            straddling: self.straddling,
        })
    }
}

/// Per-pixel distance from the output window around `p` (clipped at the output edges) to the
/// best sample window of the same shape.
fn best_match(an: &Analysis, t_out: &[u16], w: usize, h: usize, p: usize, r: usize) -> f64 {
    let lv = &an.levels[0];
    let tex = &lv.textons;
    let t = tex.count();
    let (x, y) = ((p % w) as isize, (p / w) as isize);
    let ri = r as isize;
    // The window is clipped at the output edges; a sample window matches it wherever the
    // clipped window fits inside the sample.
    let (x0, x1) = ((-ri).max(-x), ri.min(w as isize - 1 - x));
    let (y0, y1) = ((-ri).max(-y), ri.min(h as isize - 1 - y));
    let mut known: Vec<(isize, usize)> = Vec::with_capacity((2 * r + 1).pow(2));
    for dy in y0..=y1 {
        for dx in x0..=x1 {
            known.push((dy * lv.width as isize + dx, t_out[((y + dy) * w as isize + x + dx) as usize] as usize * t));
        }
    }
    let mut best = f32::INFINITY;
    for sy in (-y0) as usize..(lv.height as isize - y1) as usize {
        for sx in (-x0) as usize..(lv.width as isize - x1) as usize {
            let c = (sy * lv.width + sx) as isize;
            let mut s = 0.0f32;
            for &(d, row) in &known {
                s += tex.dist[row + tex.assign[(c + d) as usize] as usize];
                if s >= best {
                    break;
                }
            }
            best = best.min(s);
        }
    }
    best as f64 / known.len() as f64
}

/// Largest fraction of output pixels whose sample pixel recurs at one translation `t` with
/// `min_shift <= |t|_inf <= max(sample side)`.
fn repetition(map: &CoordMap, min_shift: usize) -> f64 {
    let (h, w) = (map.height, map.width);
    let big = map.sample_height.max(map.sample_width);
    let span = 2 * big + 1;
    // Output pixels grouped by sample pixel, each group in raster order (a counting sort).
    let ns = map.sample_height * map.sample_width;
    let mut start = vec![0usize; ns + 1];
    for &s in &map.src {
        start[s as usize + 1] += 1;
    }
    for i in 0..ns {
        start[i + 1] += start[i];
    }
    let mut fill = start.clone();
    let mut order = vec![0u32; h * w];
    for (p, &s) in map.src.iter().enumerate() {
        order[fill[s as usize]] = p as u32;
        fill[s as usize] += 1;
    }
    let votes = (0..ns)
        .into_par_iter()
        .fold(
            || vec![0u32; (big + 1) * span],
            |mut v, s| {
                let g = &order[start[s]..start[s + 1]];
                for (i, &a) in g.iter().enumerate() {
                    let (ax, ay) = ((a as usize % w) as isize, (a as usize / w) as isize);
                    for &b in &g[i + 1..] {
                        let (bx, by) = ((b as usize % w) as isize, (b as usize / w) as isize);
                        let (tx, ty) = (bx - ax, by - ay);
                        if ty > big as isize {
                            break;
                        }
                        let m = tx.unsigned_abs().max(ty as usize);
                        if tx.unsigned_abs() <= big && m >= min_shift {
                            v[ty as usize * span + (tx + big as isize) as usize] += 1;
                        }
                    }
                }
                v
            },
        )
        .reduce(
            || vec![0u32; (big + 1) * span],
            |mut a, b| {
                a.iter_mut().zip(&b).for_each(|(x, y)| *x += y);
                a
            },
        );
    votes.into_iter().max().unwrap_or(0) as f64 / (h * w) as f64
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::AnalysisOptions;
    use crate::pyramid::Features;

    fn analysis() -> Analysis {
        // A smooth non-periodic ramp plus noise: tiling it leaves visible seams.
        let data = (0..20 * 20)
            .flat_map(|i| {
                let (x, y) = ((i % 20) as f32, (i / 20) as f32);
                [x / 20.0, y / 20.0, 0.1 * btfrs_core::rng::hash01(1, i as i64, 0) as f32]
            })
            .collect();
        let f = Features::new(20, 20, 3, data).unwrap();
        let opts = AnalysisOptions { textons: 400, levels: 1, m: 4, iterations: 5, seed: 0 };
        Analysis::of_features(f, opts, &[1], &Monitor::new()).unwrap()
    }

    fn opts() -> QualityOptions {
        QualityOptions { radius: 1, samples: 10_000, ..Default::default() }
    }

    #[test]
    fn closed_form_cases() {
        let an = analysis();
        // The identity map reproduces the sample: every window is in it, every pair coherent.
        let id = CoordMap::tiled(20, 20, 20, 20);
        let q = quality(&an, &id, &opts(), &Monitor::new()).unwrap();
        assert_eq!(q.nn_distance, 0.0);
        assert_eq!((q.coherence, q.seam, q.seam_mean, q.repetition), (1.0, 0.0, 0.0, 0.0));
        // No discontinuity: every window is a sample window, no window straddles a seam.
        assert_eq!((q.structure, q.seam_error, q.seam_error_p90, q.straddling), (0.0, 0.0, 0.0, 0.0));
        assert_eq!(q.structure_levels, vec![0.0, 0.0]);
        // Tiling 2 x 1: one seam column, repetition at t = (20, 0) for half the pixels.
        let t = CoordMap::tiled(20, 40, 20, 20);
        let q = quality(&an, &t, &opts(), &Monitor::new()).unwrap();
        assert!((q.repetition - 0.5).abs() < 1e-12);
        assert!((q.coherence - (20.0 * 38.0 + 19.0 * 40.0) / (20.0 * 39.0 + 19.0 * 40.0)).abs() < 1e-12);
        // At the seam column both continuations, (20, y) and (-1, y), leave the sample, so a
        // pair costs the distance to the closest adjacent pair of the sample (float64 search).
        let tex = &an.levels[0].textons;
        let px = |x: usize, y: usize| tex.assign[y * 20 + x];
        let mut costs: Vec<f64> = (0..20)
            .map(|y| {
                let mut best = f64::INFINITY;
                for uy in 0..20 {
                    for ux in 0..19 {
                        best = best.min(tex.d(px(ux, uy), px(19, y)) as f64 + tex.d(px(ux + 1, uy), px(0, y)) as f64);
                    }
                }
                0.5 * best
            })
            .collect();
        costs.sort_by(f64::total_cmp);
        let direct = costs[10];
        assert!(direct > 0.0);
        assert!(
            (q.seam - direct / tex.mean_pair_distance()).abs() < 1e-6,
            "{} vs {}",
            q.seam,
            direct / tex.mean_pair_distance()
        );
        // Random placement is far from the sample.
        let r = CoordMap::random(20, 40, 20, 20, 1);
        let qr = quality(&an, &r, &opts(), &Monitor::new()).unwrap();
        assert!(qr.nn_distance > 0.2 && qr.coherence < 0.05 && qr.seam_mean > 0.5, "{qr:?}");
    }

    /// The bricks texture as an analysed sample: `size^2`, period (4, 2) bricks = 68 x 76 pixels.
    fn bricks(size: usize) -> (Analysis, Vec<f32>) {
        let t = crate::textures::texture("bricks", size, size, 5, (4, 2)).unwrap();
        let f = Features::new(size, size, 3, t.clone()).unwrap();
        let opts = AnalysisOptions { textons: 1024, levels: 1, m: 4, iterations: 5, seed: 0 };
        (Analysis::of_features(f, opts, &[1], &Monitor::new()).unwrap(), t)
    }

    #[test]
    fn seams_and_structure_rank_tilings_as_the_eye_does() {
        let (an, _) = bricks(128);
        let out = 256;
        let o = QualityOptions { samples: 1024, ..Default::default() };
        let q = |m: &CoordMap| quality(&an, m, &o, &Monitor::new()).unwrap();
        // Tiling at the period: seamless (its jumps from column 75 to 0 continue the pattern).
        let (ph, pw) = crate::textures::period_pixels((4, 2));
        let good = CoordMap {
            width: out,
            height: out,
            sample_width: 128,
            sample_height: 128,
            src: (0..out * out).map(|p| ((p / out % ph) * 128 + p % out % pw) as u32).collect(),
        };
        let qg = q(&good);
        assert!(qg.straddling > 0.05, "{qg:?}");
        assert!(qg.seam_error < 1e-6 && qg.structure < 1e-6, "{qg:?}");
        // Plain tiling of the off-period crop: broken mortar at every tile boundary.
        let qt = q(&CoordMap::tiled(out, out, 128, 128));
        assert!(qt.seam_error > 0.05 && qt.seam_error_p90 > qt.seam_error, "{qt:?}");
        assert!(qt.structure > 0.01, "{qt:?}");
        // The old pair measure calls it seamless along its worst line: what the user reported.
        // Random placement is far worse still.
        let qr = q(&CoordMap::random(out, out, 128, 128, 3));
        assert!(qr.seam_error > 2.0 * qt.seam_error && qr.structure > 10.0 * qt.structure, "{qr:?} {qt:?}");
        assert!((qr.straddling - 1.0).abs() < 1e-12);
    }
}
