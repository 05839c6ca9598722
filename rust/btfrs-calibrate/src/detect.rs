//! Finding the sphere: a coarse dark disc in reduced photographs, then its outline to a fraction
//! of a pixel in the full-resolution mean of all of them.
//!
//! **Coarse.** A glossy black sphere is the darkest round thing in the frame under every light
//! but for its small highlight, while the table and the object around it are lit by most
//! lights. So the coarse search looks at the upper quartile of each reduced pixel over a
//! subset of the photographs (a pixel that is dark in three quarters of them: shadows move with
//! the light and highlights are small, so neither survives the quartile) and splits it into
//! dark and bright by Otsu's threshold. A dark region stands for a sphere when its darkest core
//! is shaped like a disc (bounding box nearly square, the disc inscribed in it nearly filled):
//! the core is found by Otsu's threshold again within the region, and again, down to where
//! the sphere parts from its own shadow, which clings to it in the quartile. Among those, the
//! one where the most photographs show a small bright spot (a highlight) wins, then the
//! largest: a dark round object that is not the sphere (a coin under raking light) shows no
//! highlight. The core is centred on the sphere (its rim, brightened by reflections at grazing
//! angles, is the same all round) but smaller; the radius is where the mean photograph
//! brightens outwards along the most rays from the core's centre (the sphere's edge adds up at
//! one radius, other edges at many).
//!
//! **Outline.** Along rays from the coarse centre, the outline is where the mean photograph
//! brightens fastest going outwards (the largest difference across one pixel, located between
//! samples by a parabola through the three best). The points go to the robust fits of
//! [`crate::fit`]. Where the sphere is no darker than its surroundings (a black velvet
//! background), neither step works: the circle must be given.

use crate::fit::{fit_circle, fit_cone, Outline};
use crate::geometry::Camera;
use crate::photo::Rect;
use btfrs_core::{Error, Result};

/// Otsu's threshold of `v` (the level that best splits it into two classes, by between-class
/// variance), over a 256-bin histogram of its range.
fn otsu(v: &[f32]) -> f32 {
    let (lo, hi) = v.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
    if hi <= lo {
        return hi;
    }
    let bins = 256;
    let mut hist = vec![0u64; bins];
    let scale = (bins - 1) as f32 / (hi - lo);
    for &x in v {
        hist[((x - lo) * scale) as usize] += 1;
    }
    let n = v.len() as f64;
    let total: f64 = hist.iter().enumerate().map(|(i, &c)| i as f64 * c as f64).sum();
    let (mut w0, mut s0, mut best, mut at) = (0f64, 0f64, -1f64, 0usize);
    for (i, &c) in hist.iter().enumerate() {
        w0 += c as f64;
        s0 += i as f64 * c as f64;
        let w1 = n - w0;
        if w0 == 0.0 || w1 == 0.0 {
            continue;
        }
        let (m0, m1) = (s0 / w0, (total - s0) / w1);
        let between = w0 * w1 * (m0 - m1) * (m0 - m1);
        if between > best {
            best = between;
            at = i;
        }
    }
    lo + (at as f32 + 1.0) / scale
}

/// A dark region of the reduced frame.
#[derive(Debug, Clone, PartialEq)]
struct Region {
    area: usize,
    x0: usize,
    y0: usize,
    x1: usize,
    y1: usize,
}

/// The 4-connected regions of `mask` (`w` columns).
fn regions(mask: &[bool], w: usize) -> Vec<Region> {
    let h = mask.len() / w;
    let mut seen = vec![false; mask.len()];
    let mut out = Vec::new();
    let mut stack = Vec::new();
    for start in 0..mask.len() {
        if !mask[start] || seen[start] {
            continue;
        }
        seen[start] = true;
        stack.push(start);
        let mut r = Region { area: 0, x0: usize::MAX, y0: usize::MAX, x1: 0, y1: 0 };
        while let Some(i) = stack.pop() {
            let (x, y) = (i % w, i / w);
            r.area += 1;
            r.x0 = r.x0.min(x);
            r.x1 = r.x1.max(x);
            r.y0 = r.y0.min(y);
            r.y1 = r.y1.max(y);
            let mut visit = |j: usize| {
                if mask[j] && !seen[j] {
                    seen[j] = true;
                    stack.push(j);
                }
            };
            if x > 0 {
                visit(i - 1);
            }
            if x + 1 < w {
                visit(i + 1);
            }
            if y > 0 {
                visit(i - w);
            }
            if y + 1 < h {
                visit(i + w);
            }
        }
        out.push(r);
    }
    out
}

/// The coarse circle (cx, cy, r) in full-resolution pixels from reduced photographs (`frames`,
/// each `dw x dh`, reduced by `s`). `shown` names the photographs in the error.
pub fn coarse(frames: &[Vec<f32>], dw: usize, dh: usize, s: usize, shown: &str) -> Result<[f64; 3]> {
    let n = frames.len();
    let q = (3 * (n - 1)) / 4; // the upper quartile's rank
    let mut col = vec![0f32; n];
    let upper: Vec<f32> = (0..dw * dh)
        .map(|p| {
            for (c, f) in col.iter_mut().zip(frames) {
                *c = f[p];
            }
            *col.select_nth_unstable_by(q, |a, b| a.total_cmp(b)).1
        })
        .collect();
    let t = otsu(&upper);
    let dark: Vec<bool> = upper.iter().map(|&v| v < t).collect();
    let not_found = |why: &str| {
        Error::Degenerate(format!(
            "no sphere found in {shown}: {why}; expected a glossy black sphere darker than what surrounds it \
             (give its circle instead: sphere=(cx, cy, r) in pixels, or --sphere CX CY R)"
        ))
    };
    let mut best: Option<((usize, usize), Region)> = None;
    for r in regions(&dark, dw) {
        if r.area < 16 {
            continue;
        }
        // The sphere's shadow on the table, dark in many photographs, may join the disc at this
        // threshold: the region's darkest round core stands for it then.
        let Some(core) = core(&upper, dw, dh, &r, s) else { continue };
        let (cx, cy, rad) = as_disc(&core, s).unwrap_or_default();
        // Photographs with a highlight: a reduced pixel well above the disc's typical level
        // within 0.75 of its radius.
        let inner: Vec<usize> = (core.y0..=core.y1)
            .flat_map(|y| (core.x0..=core.x1).map(move |x| (x, y)))
            .filter(|&(x, y)| (x as f64 + 0.5 - cx).hypot(y as f64 + 0.5 - cy) <= 0.75 * rad)
            .map(|(x, y)| y * dw + x)
            .collect();
        if inner.is_empty() {
            continue;
        }
        let mut levels: Vec<f32> = inner.iter().map(|&p| upper[p]).collect();
        let mid = levels.len() / 2;
        let typical = *levels.select_nth_unstable_by(mid, |a, b| a.total_cmp(b)).1;
        let lit = frames.iter().filter(|f| inner.iter().any(|&p| f[p] > typical + 0.25)).count();
        if best.as_ref().is_none_or(|(k, _)| (lit, r.area) > *k) {
            best = Some(((lit, r.area), core));
        }
    }
    let (_, core) = best.ok_or_else(|| not_found("no dark round region in the photographs"))?;
    let (cx, cy, rad) = as_disc(&core, s).unwrap_or_default();
    // The core is centred on the sphere (its rim, brightened by reflections at grazing angles,
    // is the same all round) but smaller than it. The radius is the one where the mean
    // photograph brightens outwards along the most rays: summed over rays from the centre, the
    // sphere's edge adds up at one radius, other edges (the relief, a target, a shadow) at many.
    let mean: Vec<f32> =
        (0..dw * dh).map(|p| (frames.iter().map(|f| f[p] as f64).sum::<f64>() / n as f64) as f32).collect();
    let rect = Rect { x0: 0, y0: 0, w: dw, h: dh };
    let r0 = radial_vote(&mean, rect, cx, cy, 0.9 * rad, 1.6 * rad + 2.0).unwrap_or(rad);
    Ok([cx * s as f64, cy * s as f64, r0 * s as f64])
}

/// The region's disc (cx, cy, r) in reduced pixels when it is shaped like one: its bounding box
/// nearly square, the disc inscribed in it nearly filled, big enough.
fn as_disc(r: &Region, s: usize) -> Option<(f64, f64, f64)> {
    let (bw, bh) = ((r.x1 - r.x0 + 1) as f64, (r.y1 - r.y0 + 1) as f64);
    let rad = 0.25 * (bw + bh);
    let fill = r.area as f64 / (std::f64::consts::PI * rad * rad);
    let round = (0.8..=1.25).contains(&(bw / bh)) && (0.75..=1.2).contains(&fill);
    (round && rad >= 4.0 && rad * s as f64 >= 8.0)
        .then(|| (0.5 * (r.x0 + r.x1 + 1) as f64, 0.5 * (r.y0 + r.y1 + 1) as f64, rad))
}

/// The darkest round part of the region `r`: thresholds by Otsu's method over its bounding box
/// grown by a quarter on each side, then over what is darker than that, and so on (up to four
/// times); of the regions around the box's darkest spot (its darkest 3 x 3 mean) at each level,
/// the last that is round, as long as it keeps a tenth of the first's area.
fn core(upper: &[f32], dw: usize, dh: usize, r: &Region, s: usize) -> Option<Region> {
    let (mx, my) = ((r.x1 - r.x0 + 1) / 4 + 1, (r.y1 - r.y0 + 1) / 4 + 1);
    let (x0, y0) = (r.x0.saturating_sub(mx), r.y0.saturating_sub(my));
    let (x1, y1) = ((r.x1 + mx).min(dw - 1), (r.y1 + my).min(dh - 1));
    let (ww, wh) = (x1 - x0 + 1, y1 - y0 + 1);
    let window: Vec<f32> = (y0..=y1).flat_map(|y| upper[y * dw + x0..=y * dw + x1].iter().copied()).collect();
    let box3 = |x: usize, y: usize| -> f32 {
        (0..3).flat_map(|j| (0..3).map(move |i| (i, j))).map(|(i, j)| window[(y + j - 1) * ww + x + i - 1]).sum()
    };
    let seed = (1..wh.saturating_sub(1))
        .flat_map(|y| (1..ww.saturating_sub(1)).map(move |x| (x, y)))
        .min_by(|&(ax, ay), &(bx, by)| box3(ax, ay).total_cmp(&box3(bx, by)))?;
    let mut values = window.clone();
    let mut last: Option<Region> = None;
    for _ in 0..4 {
        let t = otsu(&values);
        let mask: Vec<bool> = window.iter().map(|&v| v < t).collect();
        if !mask[seed.1 * ww + seed.0] {
            break;
        }
        let Some(found) = regions(&mask, ww)
            .into_iter()
            .find(|q| q.x0 <= seed.0 && seed.0 <= q.x1 && q.y0 <= seed.1 && seed.1 <= q.y1)
        else {
            break;
        };
        let here =
            Region { area: found.area, x0: found.x0 + x0, y0: found.y0 + y0, x1: found.x1 + x0, y1: found.y1 + y0 };
        if last.as_ref().is_some_and(|l| 10 * here.area < l.area) {
            break;
        }
        match (as_disc(&here, s), &last) {
            (Some(_), _) => last = Some(here),
            (None, Some(_)) => break,
            (None, None) => {}
        }
        values.retain(|&v| v < t);
        if values.len() < 16 {
            break;
        }
    }
    last
}

/// The radius in `lo..hi` at which `img` (over `rect`) brightens outwards the most, summed over
/// rays from (cx, cy) (the steps of a quarter pixel, differences across one pixel, the peak
/// located between steps by a parabola); None when nothing brightens.
fn radial_vote(img: &[f32], rect: Rect, cx: f64, cy: f64, lo: f64, hi: f64) -> Option<f64> {
    let step = 0.25;
    let half = 2;
    let count = ((hi - lo) / step) as usize + 1;
    let mut votes = vec![0f64; count];
    let rays = ((std::f64::consts::TAU * hi) as usize).clamp(90, 1440);
    for k in 0..rays {
        let t = std::f64::consts::TAU * k as f64 / rays as f64;
        let (dx, dy) = (t.cos(), t.sin());
        let at = |i: usize| {
            let rho = lo + i as f64 * step;
            sample(img, rect.w, rect.h, cx + rho * dx - rect.x0 as f64, cy + rho * dy - rect.y0 as f64)
        };
        for (i, v) in votes.iter_mut().enumerate().take(count.saturating_sub(half)).skip(half) {
            if let (Some(a), Some(b)) = (at(i - half), at(i + half)) {
                *v += (b - a).max(0.0);
            }
        }
    }
    let (i, &best) = votes.iter().enumerate().max_by(|a, b| a.1.total_cmp(b.1))?;
    if best <= 0.0 {
        return None;
    }
    let off = match (i.checked_sub(1).map(|j| votes[j]), votes.get(i + 1)) {
        (Some(a), Some(&c)) if a - 2.0 * best + c < 0.0 => (0.5 * (a - c) / (a - 2.0 * best + c)).clamp(-0.5, 0.5),
        _ => 0.0,
    };
    Some(lo + (i as f64 + off) * step)
}

/// Bilinear sample of `img` (`w x h`, pixel centres at +0.5) at (x, y); None outside.
#[inline]
fn sample(img: &[f32], w: usize, h: usize, x: f64, y: f64) -> Option<f64> {
    let (fx, fy) = (x - 0.5, y - 0.5);
    if fx < 0.0 || fy < 0.0 || fx > (w - 1) as f64 || fy > (h - 1) as f64 {
        return None;
    }
    let (ix, iy) = ((fx as usize).min(w.saturating_sub(2)), (fy as usize).min(h.saturating_sub(2)));
    let (tx, ty) = (fx - ix as f64, fy - iy as f64);
    let at = |x: usize, y: usize| img[y * w + x] as f64;
    let top = at(ix, iy) * (1.0 - tx) + at(ix + 1, iy) * tx;
    let bottom = at(ix, iy + 1) * (1.0 - tx) + at(ix + 1, iy + 1) * tx;
    Some(top * (1.0 - ty) + bottom * ty)
}

/// The outline's points along rays from the coarse circle's centre, in full-resolution pixels:
/// `mean` is the mean photograph over `rect`, `slack` how far (pixels) the coarse radius may be
/// off.
pub fn edge_points(mean: &[f32], rect: Rect, coarse: [f64; 3], slack: f64) -> Vec<[f64; 2]> {
    let [cx, cy, r] = coarse;
    let (lo, hi) = ((r - slack).max(0.5 * r), r + slack);
    let rays = ((std::f64::consts::TAU * r) as usize).clamp(90, 1440);
    let step = 0.25;
    let half = 2; // differences across 2 x 2 steps: one pixel
    let mut out = Vec::with_capacity(rays);
    let mut prof = Vec::new();
    for k in 0..rays {
        let t = std::f64::consts::TAU * k as f64 / rays as f64;
        let (dx, dy) = (t.cos(), t.sin());
        prof.clear();
        let mut rho = lo - 1.0;
        while rho <= hi + 1.0 {
            let (x, y) = (cx + rho * dx - rect.x0 as f64, cy + rho * dy - rect.y0 as f64);
            prof.push(sample(mean, rect.w, rect.h, x, y));
            rho += step;
        }
        if prof.iter().any(Option::is_none) || prof.len() < 2 * half + 3 {
            continue;
        }
        let p: Vec<f64> = prof.iter().map(|v| v.unwrap_or(0.0)).collect();
        let g: Vec<f64> = (half..p.len() - half).map(|i| p[i + half] - p[i - half]).collect();
        let Some((i, &gm)) = g.iter().enumerate().max_by(|a, b| a.1.total_cmp(b.1)) else { continue };
        if gm <= 0.0 || i == 0 || i + 1 >= g.len() {
            continue;
        }
        let (a, b, c) = (g[i - 1], gm, g[i + 1]);
        let den = a - 2.0 * b + c;
        let off = if den < 0.0 { (0.5 * (a - c) / den).clamp(-0.5, 0.5) } else { 0.0 };
        let rho = lo - 1.0 + (i + half) as f64 * step + off * step;
        out.push([cx + rho * dx, cy + rho * dy]);
    }
    out
}

/// The outline fitted to [`edge_points`], for `camera`; `shown` names the photographs.
pub fn outline(points: &[[f64; 2]], camera: Camera, shown: &str) -> Result<Outline> {
    let fitted = match camera {
        Camera::Orthographic => fit_circle(points),
        Camera::Perspective { .. } => fit_cone(points, camera),
    };
    fitted.ok_or_else(|| {
        Error::Degenerate(format!(
            "no sphere found in {shown}: the dark disc's outline could not be traced ({} edge points); give its \
             circle instead: sphere=(cx, cy, r) in pixels, or --sphere CX CY R",
            points.len()
        ))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A grey frame with a dark disc (cx, cy, r), anti-aliased by 4 x 4 supersampling.
    fn disc(w: usize, h: usize, c: [f64; 3], inside: f32, outside: f32) -> Vec<f32> {
        (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f64, (i / w) as f64);
                let mut k = 0;
                for sy in 0..4 {
                    for sx in 0..4 {
                        let (px, py) = (x + (sx as f64 + 0.5) / 4.0, y + (sy as f64 + 0.5) / 4.0);
                        k += usize::from((px - c[0]).hypot(py - c[1]) < c[2]);
                    }
                }
                let f = k as f32 / 16.0;
                f * inside + (1.0 - f) * outside
            })
            .collect()
    }

    #[test]
    fn otsu_splits_two_levels() {
        let v: Vec<f32> = (0..1000).map(|i| if i % 3 == 0 { 0.02 } else { 0.4 }).collect();
        let t = otsu(&v);
        assert!(t > 0.02 && t < 0.4, "{t}");
    }

    #[test]
    fn coarse_finds_the_disc_with_highlights_not_the_square() {
        let (w, h) = (160, 120);
        let c = [50.3, 61.7, 30.2];
        let mut frames = Vec::new();
        for k in 0..6 {
            let mut f = disc(w, h, c, 0.01, 0.3);
            // A dark square (not round) elsewhere, and a highlight on the disc.
            for y in 10..50 {
                for x in 110..150 {
                    f[y * w + x] = 0.01;
                }
            }
            f[(55 + k) * w + 45 + 2 * k] = 1.0;
            frames.push(f);
        }
        let got = coarse(&frames, w, h, 1, "test").unwrap();
        assert!((got[0] - c[0]).abs() < 1.5 && (got[1] - c[1]).abs() < 1.5 && (got[2] - c[2]).abs() < 1.5, "{got:?}");
        // Reduced by 2, the circle comes back in full-resolution pixels.
        let small: Vec<Vec<f32>> = (0..3).map(|_| disc(w / 2, h / 2, c.map(|v| v / 2.0), 0.01, 0.3)).collect();
        let got = coarse(&small, w / 2, h / 2, 2, "test").unwrap();
        assert!((got[0] - c[0]).abs() < 3.0 && (got[2] - c[2]).abs() < 3.0, "{got:?}");
        // Nothing dark and round: a clear error.
        let flat = vec![vec![0.3f32; w * h]; 3];
        let e = coarse(&flat, w, h, 1, "photos/").unwrap_err().to_string();
        assert!(e.contains("no sphere found in photos/") && e.contains("sphere=(cx, cy, r)"), "{e}");
    }

    #[test]
    fn outline_to_a_small_fraction_of_a_pixel() {
        let (w, h) = (200, 160);
        let c = [97.37, 83.61, 52.45];
        let img = disc(w, h, c, 0.02, 0.35);
        let rect = Rect { x0: 0, y0: 0, w, h };
        let pts = edge_points(&img, rect, [c[0] + 1.7, c[1] - 1.2, c[2] + 2.5], 6.0);
        assert!(pts.len() > 300);
        let o = outline(&pts, Camera::Orthographic, "test").unwrap();
        for k in 0..3 {
            assert!((o.circle[k] - c[k]).abs() < 0.03, "{:?} vs {c:?}", o.circle);
        }
    }
}
