//! Finding a photograph's highlight on the sphere, to a fraction of a pixel.
//!
//! The search covers the part of the sphere whose mirror image lies above the horizon (down to
//! [`HORIZON_TOLERANCE_DEG`] below it: calibration noise at grazing lights), so reflections of
//! the table near the sphere's rim are never taken for a highlight. In it:
//!
//! 1. the *background* is the median luminance (a black sphere: near 0) and the *peak* the
//!    largest; a peak less than [`MIN_CONTRAST`] above the background is no highlight
//!    (**missing**: a misfired flash, the sphere in shadow);
//! 2. the *spots* are the 8-connected groups of pixels above half-way between background and
//!    peak, each weighed by its excess over that level. The highlight's position is the
//!    centroid of its spot grown down to [`CENTROID_LEVEL`] of the way from background to peak
//!    (the pixels connected to it and near it), each pixel weighed by its excess over that
//!    level: for a clipped (flat-topped) highlight that is the centre of the plateau and its
//!    shoulders, symmetric about the true centre, unlike the brightest pixel (any pixel of the
//!    plateau) or a fit of a peaked profile. The low level matters: at half-way, a clipped
//!    highlight's shoulder is a fraction of a pixel wide and its centroid steps with the
//!    pixel grid (0.1 pixel on a highlight 6 pixels across, measured on Gaussian spots); at a
//!    tenth, the shoulders' partly covered pixels carry where the edge lies (0.02 pixel).
//!    The centroid is taken in the image, as relight and RTIBuilder take it: exact for a
//!    glossy sphere under a small lamp, whose highlight is its microfacet lobe brightened by
//!    1 / cos(view) where the image squeezes it by cos(view). On a mirror sphere reflecting a
//!    lamp of finite size (a highlight of even brightness on the sphere) the image squeezes
//!    the rim side, and the centroid falls short of the centre by about tan(theta) s^2 of
//!    normal angle (theta the highlight's angle from the sphere's centre, s its half-width):
//!    under 0.01 degree of light for a highlight 1 degree across, 0.3 degree for one
//!    8 degrees across at 32 (measured on drawn spheres). Averaging the pixels as normals
//!    instead would be exact there and off by as much on the glossy sphere (measured: the
//!    rendered captures' errors doubled);
//! 3. a second spot with at least [`DOUBLE_RATIO`] of the first's weight makes the photograph
//!    **ambiguous** (two lights fired, or a lamp reflected twice): no rule can tell which is the
//!    light of the `.lp`, so it is left out and both spots are reported. Smaller spots (a hot
//!    pixel, a glint of dust) are ignored;
//! 4. a sphere that is not dark (background above [`OVEREXPOSED_BACKGROUND`]) or a spot covering
//!    more than [`OVEREXPOSED_AREA`] of the search is **overexposed**: its centre says nothing.

use crate::geometry::SphereView;
use crate::photo::Rect;
use serde::Serialize;

/// Lights found up to this many degrees below the horizon are kept, moved onto it.
pub const HORIZON_TOLERANCE_DEG: f64 = 5.0;
/// The least excess of the peak over the sphere's median (linear luminance, 1 = white).
pub const MIN_CONTRAST: f32 = 0.1;
/// The centroid's level, as a share of the way from the background to the peak.
pub const CENTROID_LEVEL: f32 = 0.1;
/// A second spot this heavy relative to the first makes the photograph ambiguous.
pub const DOUBLE_RATIO: f64 = 0.2;
/// A sphere whose median luminance is above this is not dark: overexposed.
pub const OVEREXPOSED_BACKGROUND: f32 = 0.5;
/// A highlight covering more than this share of the searched sphere is overexposed.
pub const OVEREXPOSED_AREA: f64 = 0.25;

/// A bright spot on the sphere.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Spot {
    /// Its excess-weighted centroid in pixels (x right, y down, the image's top-left corner at
    /// (0, 0)).
    pub x: f64,
    pub y: f64,
    /// Its largest luminance.
    pub peak: f32,
    /// Its summed excess over the spot level.
    pub weight: f64,
    /// Its pixels.
    pub area: usize,
}

/// What a photograph's search found.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Status {
    /// One highlight: its light is known.
    Ok,
    /// No highlight.
    Missing,
    /// Two (or more) highlights of similar weight.
    Ambiguous,
    /// The sphere is not dark, or the highlight covers much of it.
    Overexposed,
}

/// The search's result for one photograph.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Finding {
    pub status: Status,
    /// Why it was not calibrated, in words (None when it was).
    pub reason: Option<String>,
    /// The spots, heaviest first (at most 4).
    pub spots: Vec<Spot>,
    /// The sphere's median and largest luminance over the search.
    pub background: f32,
    pub peak: f32,
    /// Pixels of the highlight's spot at the top of the range (>= 0.999).
    pub clipped_pixels: usize,
}

/// The pixels of a region where a highlight is looked for.
#[derive(Debug, Clone)]
pub struct Search {
    /// The region (a rectangle of the photograph).
    pub rect: Rect,
    /// Per pixel of `rect`: whether it is searched.
    pub mask: Vec<bool>,
    /// How many are.
    pub count: usize,
}

impl Search {
    /// The pixels of `rect` on the sphere whose mirror image is at most
    /// [`HORIZON_TOLERANCE_DEG`] below the horizon.
    pub fn new(view: &SphereView, rect: Rect) -> Search {
        let zmin = -HORIZON_TOLERANCE_DEG.to_radians().sin();
        let mask: Vec<bool> = (0..rect.len())
            .map(|i| {
                let (u, v) = ((rect.x0 + i % rect.w) as f64 + 0.5, (rect.y0 + i / rect.w) as f64 + 0.5);
                view.light_at(u, v).is_some_and(|l| l[2] >= zmin)
            })
            .collect();
        let count = mask.iter().filter(|&&m| m).count();
        Search { rect, mask, count }
    }
}

/// Look for the highlight in `lum`, the photograph's luminance over `search.rect`.
pub fn find(lum: &[f32], search: &Search) -> Finding {
    let Rect { x0, y0, w, h } = search.rect;
    // The background from every third searched pixel at most (a median needs no more; a sphere
    // of 1000 pixels' radius has 2 million).
    let stride = (search.count / 20_000).clamp(1, 3);
    let mut vals: Vec<f32> =
        lum.iter().zip(&search.mask).filter(|(_, m)| **m).step_by(stride).map(|(v, _)| *v).collect();
    let mut finding = Finding {
        status: Status::Missing,
        reason: None,
        spots: Vec::new(),
        background: 0.0,
        peak: 0.0,
        clipped_pixels: 0,
    };
    if vals.is_empty() {
        finding.reason = Some("the sphere has no pixel to search".into());
        return finding;
    }
    let mid = vals.len() / 2;
    let bg = *vals.select_nth_unstable_by(mid, |a, b| a.total_cmp(b)).1;
    let peak = lum.iter().zip(&search.mask).filter(|(_, m)| **m).fold(f32::NEG_INFINITY, |p, (v, _)| p.max(*v));
    finding.background = bg;
    finding.peak = peak;
    if bg > OVEREXPOSED_BACKGROUND {
        finding.status = Status::Overexposed;
        finding.reason = Some(format!("overexposed: the sphere is not dark (median luminance {bg:.2})"));
        return finding;
    }
    if peak - bg < MIN_CONTRAST {
        finding.reason = Some(format!(
            "no highlight on the sphere (its brightest pixel is {:.3} above its median; at least {MIN_CONTRAST} expected)",
            peak - bg
        ));
        return finding;
    }
    let level = bg + 0.5 * (peak - bg);
    let above = |i: usize| search.mask[i] && lum[i] >= level;
    let mut seen = vec![false; lum.len()];
    let mut spots = Vec::new();
    let mut clipped_of = Vec::new();
    let mut members: Vec<Vec<usize>> = Vec::new();
    let mut stack = Vec::new();
    for start in 0..lum.len() {
        if seen[start] || !above(start) {
            continue;
        }
        seen[start] = true;
        stack.push(start);
        let (mut sw, mut sx, mut sy, mut area, mut top, mut clipped) = (0f64, 0f64, 0f64, 0usize, f32::MIN, 0usize);
        let mut pixels = Vec::new();
        while let Some(i) = stack.pop() {
            pixels.push(i);
            let (x, y) = (i % w, i / w);
            let wt = (lum[i] - level) as f64;
            // The excess is zero on the level itself; a small floor keeps such pixels counted.
            let wt = wt.max(1e-6);
            sw += wt;
            sx += wt * (x0 + x) as f64;
            sy += wt * (y0 + y) as f64;
            area += 1;
            top = top.max(lum[i]);
            clipped += usize::from(lum[i] >= 0.999);
            for dy in -1i64..=1 {
                for dx in -1i64..=1 {
                    let (nx, ny) = (x as i64 + dx, y as i64 + dy);
                    if (dx, dy) == (0, 0) || nx < 0 || ny < 0 || nx >= w as i64 || ny >= h as i64 {
                        continue;
                    }
                    let j = ny as usize * w + nx as usize;
                    if !seen[j] && above(j) {
                        seen[j] = true;
                        stack.push(j);
                    }
                }
            }
        }
        // Pixel centres are at +0.5.
        spots.push(Spot { x: sx / sw + 0.5, y: sy / sw + 0.5, peak: top, weight: sw, area });
        clipped_of.push(clipped);
        members.push(pixels);
    }
    let mut order: Vec<usize> = (0..spots.len()).collect();
    order.sort_by(|&a, &b| spots[b].weight.total_cmp(&spots[a].weight));
    finding.clipped_pixels = clipped_of[order[0]];
    finding.spots = order.iter().take(4).map(|&i| spots[i]).collect();
    let first = finding.spots[0];
    if first.area as f64 > OVEREXPOSED_AREA * search.count as f64 {
        finding.status = Status::Overexposed;
        finding.reason = Some(format!(
            "overexposed: the highlight covers {:.0}% of the sphere's searched area",
            100.0 * first.area as f64 / search.count as f64
        ));
        return finding;
    }
    if let Some(second) = finding.spots.get(1).filter(|s| s.weight >= DOUBLE_RATIO * first.weight) {
        finding.status = Status::Ambiguous;
        finding.reason = Some(format!(
            "two highlights on the sphere, at ({:.1}, {:.1}) and ({:.1}, {:.1}) (the second {:.0}% as strong)",
            first.x,
            first.y,
            second.x,
            second.y,
            100.0 * second.weight / first.weight
        ));
        return finding;
    }
    let (x, y) = grown_centroid(lum, search, &members[order[0]], bg + CENTROID_LEVEL * (peak - bg), first);
    finding.spots[0].x = x;
    finding.spots[0].y = y;
    finding.status = Status::Ok;
    finding
}

/// The centroid of the spot `seed` grown through connected pixels at or above `level` within
/// twice its radius (plus 2 pixels) of its centre, each weighed by its excess over `level`.
fn grown_centroid(lum: &[f32], search: &Search, seed: &[usize], level: f32, spot: Spot) -> (f64, f64) {
    let Rect { x0, y0, w, h } = search.rect;
    let reach = 2.0 * (spot.area as f64 / std::f64::consts::PI).sqrt() + 2.0;
    let near = |i: usize| {
        let (x, y) = ((x0 + i % w) as f64 + 0.5, (y0 + i / w) as f64 + 0.5);
        (x - spot.x).hypot(y - spot.y) <= reach
    };
    // Pixels taken, in the box of `reach` around the spot (indices of `lum` outside it are
    // never visited).
    let (bx0, by0) =
        (((spot.x - reach).floor() as i64 - x0 as i64).max(0), ((spot.y - reach).floor() as i64 - y0 as i64).max(0));
    let (bw, bh) = ((2.0 * reach).ceil() as i64 + 3, (2.0 * reach).ceil() as i64 + 3);
    let mut seen = vec![false; (bw * bh) as usize];
    let mut mark = |j: usize| {
        let (x, y) = ((j % w) as i64 - bx0, (j / w) as i64 - by0);
        let k = (y * bw + x) as usize;
        let fresh = x >= 0 && y >= 0 && x < bw && y < bh && !seen[k];
        if fresh {
            seen[k] = true;
        }
        fresh
    };
    let mut stack: Vec<usize> = seed.iter().copied().filter(|&j| mark(j)).collect();
    let (mut sw, mut sx, mut sy) = (0f64, 0f64, 0f64);
    while let Some(i) = stack.pop() {
        let (x, y) = (i % w, i / w);
        let wt = ((lum[i] - level) as f64).max(0.0);
        sw += wt;
        sx += wt * ((x0 + x) as f64 + 0.5);
        sy += wt * ((y0 + y) as f64 + 0.5);
        for dy in -1i64..=1 {
            for dx in -1i64..=1 {
                let (nx, ny) = (x as i64 + dx, y as i64 + dy);
                if (dx, dy) == (0, 0) || nx < 0 || ny < 0 || nx >= w as i64 || ny >= h as i64 {
                    continue;
                }
                let j = ny as usize * w + nx as usize;
                if search.mask[j] && lum[j] >= level && near(j) && mark(j) {
                    stack.push(j);
                }
            }
        }
    }
    if sw > 0.0 {
        (sx / sw, sy / sw)
    } else {
        (spot.x, spot.y)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A dark sphere (cx, cy, r) in a `w x h` frame with Gaussian highlights (x, y, sigma, peak)
    /// clipped at 1, integrated over each pixel by 8 x 8 supersampling.
    fn frame(w: usize, h: usize, spots: &[(f64, f64, f64, f64)]) -> Vec<f32> {
        (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f64, (i / w) as f64);
                let mut acc = 0.0;
                for sy in 0..8 {
                    for sx in 0..8 {
                        let (px, py) = (x + (sx as f64 + 0.5) / 8.0, y + (sy as f64 + 0.5) / 8.0);
                        let v: f64 = spots
                            .iter()
                            .map(|&(cx, cy, s, p)| p * (-((px - cx).powi(2) + (py - cy).powi(2)) / (2.0 * s * s)).exp())
                            .sum();
                        acc += v;
                    }
                }
                (0.01 + acc / 64.0).min(1.0) as f32
            })
            .collect()
    }

    fn search(w: usize, h: usize) -> Search {
        Search::new(&SphereView::orthographic([60.0, 50.0, 45.0]), Rect { x0: 0, y0: 0, w, h })
    }

    #[test]
    fn a_clipped_highlight_is_found_at_its_centre() {
        let (w, h) = (120, 100);
        // Peak 20 x white: a plateau of about 5 pixels across.
        let (cx, cy) = (71.37, 38.82);
        let f = find(&frame(w, h, &[(cx, cy, 1.2, 20.0)]), &search(w, h));
        assert_eq!(f.status, Status::Ok, "{f:?}");
        assert!(f.clipped_pixels >= 9, "{f:?}");
        let s = f.spots[0];
        assert!((s.x - cx).abs() < 0.03 && (s.y - cy).abs() < 0.03, "{s:?}");
    }

    #[test]
    fn two_highlights_are_ambiguous_and_a_hot_pixel_is_not() {
        let (w, h) = (120, 100);
        let f = find(&frame(w, h, &[(50.0, 45.0, 1.2, 20.0), (72.0, 60.0, 1.0, 12.0)]), &search(w, h));
        assert_eq!(f.status, Status::Ambiguous, "{f:?}");
        assert!(f.reason.unwrap().contains("two highlights"));
        let mut one = frame(w, h, &[(50.0, 45.0, 1.2, 20.0)]);
        one[60 * w + 72] = 1.0; // a hot pixel
        let f = find(&one, &search(w, h));
        assert_eq!(f.status, Status::Ok, "{f:?}");
        assert!((f.spots[0].x - 50.0).abs() < 0.03);
    }

    #[test]
    fn no_highlight_and_an_overexposed_sphere_are_told_apart() {
        let (w, h) = (120, 100);
        let f = find(&frame(w, h, &[]), &search(w, h));
        assert_eq!(f.status, Status::Missing);
        assert!(f.reason.unwrap().contains("no highlight"));
        let f = find(&vec![0.9f32; w * h], &search(w, h));
        assert_eq!(f.status, Status::Overexposed);
        let f = find(&frame(w, h, &[(60.0, 50.0, 7.0, 50.0)]), &search(w, h));
        assert_eq!(f.status, Status::Overexposed, "{f:?}");
        assert!(f.reason.unwrap().contains("covers"));
    }

    #[test]
    fn reflections_near_the_rim_are_not_searched() {
        // A bright ring at 0.9 r (the table mirrored at grazing angles) and no highlight.
        let (w, h) = (120, 100);
        let mut img = frame(w, h, &[]);
        for (i, v) in img.iter_mut().enumerate() {
            let (x, y) = ((i % w) as f64 + 0.5, (i / w) as f64 + 0.5);
            if ((x - 60.0).hypot(y - 50.0) - 0.9 * 45.0).abs() < 1.5 {
                *v = 0.8;
            }
        }
        let s = search(w, h);
        assert_eq!(find(&img, &s).status, Status::Missing);
        // The search ends where the mirrored light is 5 degrees below the horizon: 47.5 degrees of
        // normal, sin(47.5) r from the centre.
        let edge = 45.0 * 47.5f64.to_radians().sin();
        assert!(s.mask[50 * w + (60.0 + edge - 1.0) as usize] && !s.mask[50 * w + (60.0 + edge + 1.0) as usize]);
    }
}
