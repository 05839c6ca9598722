//! Multi-scale window distances of an output image against its sample: the search behind the
//! `structure` and `seam_error` measures of [`crate::quality`].
//!
//! **Scales.** Scale `l` is the image blurred by a binomial filter (`[1, 4, 6, 4, 1] / 16`,
//! separable, edges clamped) `l` times, the taps of the `i`-th blur `2^(i-1)` pixels apart (the
//! "à trous" form of a Gaussian pyramid: level `l` of the pyramid, at every sub-sampling phase at
//! once). A window of radius `r` at scale `l` is the `(2r + 1)^2` pixels `c + 2^l (dx, dy)`, so
//! it spans `2^(l+1) r + 1` pixels of the image: larger windows at coarser scales. A sample
//! window at scale `l` is taken around *every* sample pixel whose window and blur footprint lie
//! inside the sample, so a coarse output window is compared with the sample at any phase (a patch
//! copied at an odd offset is still found).
//!
//! **Distances.** The squared distance of two windows is the sum over their pixels of the squared
//! distance of the pixel vectors; a window's score is the distance to its best sample window per
//! pixel, divided by the scale's normaliser: the mean squared distance between two random pixels
//! of the blurred sample (twice its total variance), so 1 is "as different as random pixels" and
//! scores compare across textures and scales.
//!
//! **Exact search, fast.** Every candidate carries a lower bound descriptor: the window cut into
//! 3 x 3 blocks, each block's mean of the first `min(dim, 4)` feature components scaled by the
//! root of its pixel count. The squared distance of two descriptors is at most the squared window
//! distance (a projection onto coordinates and Jensen's inequality per block), so the candidates
//! are visited by increasing bound and the search stops when the bound reaches the best exact
//! distance found: the result is the exact nearest window. (The first feature components are the
//! leading principal coordinates for PCA features, so the bound is tight there too.)

use btfrs_core::{rng, Monitor, Result};
use rayon::prelude::*;

/// An image `[h, w, d]`, row-major.
#[derive(Debug, Clone)]
pub(crate) struct Img {
    pub h: usize,
    pub w: usize,
    pub d: usize,
    pub data: Vec<f32>,
}

impl Img {
    fn px(&self, x: usize, y: usize) -> &[f32] {
        let i = (y * self.w + x) * self.d;
        &self.data[i..i + self.d]
    }
}

/// One binomial blur with taps `step` apart, edges clamped.
fn blur(img: &Img, step: usize) -> Img {
    const K: [f32; 5] = [1.0 / 16.0, 4.0 / 16.0, 6.0 / 16.0, 4.0 / 16.0, 1.0 / 16.0];
    let (h, w, d) = (img.h, img.w, img.d);
    let s = step as isize;
    let pass = |src: &[f32], horizontal: bool| -> Vec<f32> {
        let mut out = vec![0.0f32; h * w * d];
        out.par_chunks_mut(w * d).enumerate().for_each(|(y, row)| {
            for x in 0..w {
                let o = &mut row[x * d..(x + 1) * d];
                for (t, &k) in K.iter().enumerate() {
                    let off = (t as isize - 2) * s;
                    let (qx, qy) = if horizontal {
                        ((x as isize + off).clamp(0, w as isize - 1) as usize, y)
                    } else {
                        (x, (y as isize + off).clamp(0, h as isize - 1) as usize)
                    };
                    let q = &src[(qy * w + qx) * d..(qy * w + qx + 1) * d];
                    for (o, &v) in o.iter_mut().zip(q) {
                        *o += k * v;
                    }
                }
            }
        });
        out
    };
    let a = pass(&img.data, true);
    Img { h, w, d, data: pass(&a, false) }
}

/// Scales `0..levels` of an image (scale 0 is the image itself).
pub(crate) fn scales(img: Img, levels: usize) -> Vec<Img> {
    let mut out = vec![img];
    while out.len() < levels {
        let step = 1 << (out.len() - 1);
        let next = blur(out.last().expect("non-empty"), step);
        out.push(next);
    }
    out
}

/// Pixels a window of radius `r` at scale `l` depends on, either side of its centre: its extent
/// `2^l r` plus the blur footprint `2 (2^l - 1)`.
pub(crate) fn margin(r: usize, l: usize) -> usize {
    (r << l) + 2 * ((1 << l) - 1)
}

/// The window offsets split into 3 x 3 blocks: for each block the pixel offsets `(dx, dy)`.
fn blocks(r: usize) -> Vec<Vec<(isize, isize)>> {
    let n = 2 * r + 1;
    let g = [n / 3, n - 2 * (n / 3), n / 3];
    let mut cuts = vec![-(r as isize)];
    for s in g {
        let last = *cuts.last().expect("non-empty");
        cuts.push(last + s as isize);
    }
    let mut out = Vec::new();
    for by in 0..3 {
        for bx in 0..3 {
            let mut b = Vec::new();
            for dy in cuts[by]..cuts[by + 1] {
                for dx in cuts[bx]..cuts[bx + 1] {
                    b.push((dx, dy));
                }
            }
            if !b.is_empty() {
                out.push(b);
            }
        }
    }
    // The centre block first: it rules most candidates out soonest.
    out.swap(0, 4);
    out
}

/// The sample windows of one scale, ready for exact nearest-window queries.
pub(crate) struct Search<'a> {
    img: &'a Img,
    r: usize,
    step: isize,
    blocks: Vec<Vec<(isize, isize)>>,
    p: usize,
    /// Candidate centres `(x, y)`.
    cands: Vec<(u32, u32)>,
    /// `[cands, blocks * p]` lower-bound descriptors.
    desc: Vec<f32>,
    /// Normaliser of the scale (mean squared distance of two random pixels).
    pub norm: f64,
    /// Margin of the candidate centres.
    m: usize,
}

impl<'a> Search<'a> {
    /// The windows of radius `r` at scale `l` of `img` (the sample at that scale); `None` when
    /// the sample holds fewer than 4 x 4 such windows.
    pub fn new(img: &'a Img, r: usize, l: usize) -> Option<Self> {
        let m = margin(r, l);
        if img.w < 2 * m + 4 || img.h < 2 * m + 4 {
            return None;
        }
        let blocks = blocks(r);
        let p = img.d.min(4);
        let step = 1isize << l;
        let cands: Vec<(u32, u32)> =
            (m..img.h - m).flat_map(|y| (m..img.w - m).map(move |x| (x as u32, y as u32))).collect();
        let mut s = Self { img, r, step, blocks, p, cands, desc: Vec::new(), norm: 1.0, m };
        let dl = s.blocks.len() * p;
        let mut desc = vec![0.0f32; s.cands.len() * dl];
        desc.par_chunks_mut(dl).zip(&s.cands).for_each(|(o, &(x, y))| s.describe(img, x as usize, y as usize, o));
        s.desc = desc;
        // Twice the total variance over the pixels the candidates cover.
        let (mut sum, mut sq, mut n) = (vec![0.0f64; img.d], 0.0f64, 0usize);
        let e = (r << l) as isize;
        let (x0, x1) = ((m as isize - e) as usize, (img.w as isize - m as isize + e) as usize);
        let (y0, y1) = ((m as isize - e) as usize, (img.h as isize - m as isize + e) as usize);
        for y in y0..y1 {
            for x in x0..x1 {
                for (c, &v) in img.px(x, y).iter().enumerate() {
                    sum[c] += v as f64;
                    sq += (v as f64) * (v as f64);
                }
                n += 1;
            }
        }
        let var = sq / n as f64 - sum.iter().map(|s| (s / n as f64).powi(2)).sum::<f64>();
        s.norm = if var > 1e-12 { 2.0 * var } else { 1.0 };
        Some(s)
    }

    /// Window pixels per window.
    pub fn pixels(&self) -> usize {
        (2 * self.r + 1).pow(2)
    }

    fn describe(&self, img: &Img, x: usize, y: usize, out: &mut [f32]) {
        let p = self.p;
        for (b, offs) in self.blocks.iter().enumerate() {
            let o = &mut out[b * p..(b + 1) * p];
            o.fill(0.0);
            for &(dx, dy) in offs {
                let q = img.px((x as isize + dx * self.step) as usize, (y as isize + dy * self.step) as usize);
                for (o, &v) in o.iter_mut().zip(&q[..p]) {
                    *o += v;
                }
            }
            let k = 1.0 / (offs.len() as f32).sqrt();
            o.iter_mut().for_each(|v| *v *= k);
        }
    }

    /// Exact squared distance of the output window at `(x, y)` of `out` to candidate `c`,
    /// abandoned (returning at least `bound`) once it reaches `bound`.
    fn exact(&self, out: &Img, x: usize, y: usize, c: usize, bound: f32) -> f32 {
        let (cx, cy) = (self.cands[c].0 as isize, self.cands[c].1 as isize);
        let (ri, st) = (self.r as isize, self.step);
        let mut s = 0.0f32;
        for dy in -ri..=ri {
            for dx in -ri..=ri {
                let a = out.px((x as isize + dx * st) as usize, (y as isize + dy * st) as usize);
                let b = self.img.px((cx + dx * st) as usize, (cy + dy * st) as usize);
                s += a.iter().zip(b).map(|(a, b)| (a - b) * (a - b)).sum::<f32>();
            }
            if s >= bound {
                return s;
            }
        }
        s
    }

    /// The candidate centred on sample pixel `(x, y)`, if there is one.
    fn candidate_at(&self, x: usize, y: usize) -> Option<usize> {
        let (cw, ch) = (self.img.w - 2 * self.m, self.img.h - 2 * self.m);
        let (cx, cy) = (x.checked_sub(self.m)?, y.checked_sub(self.m)?);
        (cx < cw && cy < ch).then_some(cy * cw + cx)
    }

    /// Per-pixel distance (normalised) from the window at `(x, y)` of `out` (the output at this
    /// scale; the window must lie inside it) to its nearest sample window. `hint` is a sample
    /// pixel whose window is likely close (the one the output pixel was copied from): it is tried
    /// first, so that most candidates are ruled out by the first blocks of their bound.
    pub fn nearest(
        &self,
        out: &Img,
        x: usize,
        y: usize,
        hint: Option<(usize, usize)>,
        work: &mut Vec<(f32, u32)>,
    ) -> f64 {
        let dl = self.blocks.len() * self.p;
        let mut q = vec![0.0f32; dl];
        self.describe(out, x, y, &mut q);
        let mut best = f32::INFINITY;
        if let Some(c) = hint.and_then(|(hx, hy)| self.candidate_at(hx, hy)) {
            best = self.exact(out, x, y, c, best);
            if best <= 0.0 {
                return 0.0;
            }
        }
        // Bounds block by block, abandoned once they reach the best distance so far.
        work.clear();
        let p = self.p;
        for (i, d) in self.desc.chunks_exact(dl).enumerate() {
            let mut s = 0.0f32;
            let mut alive = true;
            for (db, qb) in d.chunks_exact(p).zip(q.chunks_exact(p)) {
                s += db.iter().zip(qb).map(|(a, b)| (a - b) * (a - b)).sum::<f32>();
                if s >= best {
                    alive = false;
                    break;
                }
            }
            if alive {
                work.push((s, i as u32));
            }
        }
        // The smallest bound's exact distance first, then only the bounds below it, in order.
        if let Some(&(_, i)) = work.iter().min_by(|a, b| a.0.total_cmp(&b.0)) {
            best = best.min(self.exact(out, x, y, i as usize, best));
        }
        work.retain(|e| e.0 < best);
        work.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        for &(lb, i) in work.iter() {
            // A bound only a rounding error below the best cannot improve it.
            if lb * (1.0 + 1e-5) >= best {
                break;
            }
            best = best.min(self.exact(out, x, y, i as usize, best));
        }
        best.max(0.0) as f64 / self.pixels() as f64 / self.norm
    }
}

/// Scores of the windows at the given centres (normalised per-pixel nearest distances), in
/// parallel; `monitor` advances by one per 64 windows.
/// `hint(x, y)` is the sample pixel output pixel `(x, y)` shows.
pub(crate) fn score(
    search: &Search<'_>,
    out: &Img,
    centres: &[(usize, usize)],
    hint: &(dyn Fn(usize, usize) -> (usize, usize) + Sync),
    monitor: &Monitor,
) -> Result<Vec<f64>> {
    let v = centres
        .par_chunks(64)
        .map(|chunk| -> Result<Vec<f64>> {
            monitor.check()?;
            let mut work = Vec::new();
            let v = chunk.iter().map(|&(x, y)| search.nearest(out, x, y, Some(hint(x, y)), &mut work)).collect();
            monitor.advance(1);
            Ok(v)
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(v.into_iter().flatten().collect())
}

/// `n` centres drawn (with replacement, by `seed`) from `pool`, or all of `pool` when it has at
/// most `n`.
pub(crate) fn draw<T: Copy>(pool: &[T], n: usize, seed: u64, salt: i64) -> Vec<T> {
    if pool.len() <= n {
        return pool.to_vec();
    }
    (0..n).map(|i| pool[(rng::hash01(seed, i as i64, salt) * pool.len() as f64) as usize % pool.len()]).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn noise(h: usize, w: usize, d: usize, seed: u64) -> Img {
        let data = (0..h * w * d).map(|i| rng::hash01(seed, i as i64, 0) as f32).collect();
        Img { h, w, d, data }
    }

    #[test]
    fn the_search_is_exact() {
        let s = noise(30, 34, 3, 1);
        let o = noise(24, 20, 3, 2);
        for l in 0..2 {
            let (ss, os) = (scales(s.clone(), l + 1), scales(o.clone(), l + 1));
            let r = 2;
            let search = Search::new(&ss[l], r, l).unwrap();
            let m = margin(r, l) as isize;
            let st = 1isize << l;
            for (x, y) in [(m as usize, m as usize), (12, 11), (20 - 1 - m as usize, 24 - 1 - m as usize)] {
                let got = search.nearest(&os[l], x, y, None, &mut Vec::new());
                // Brute force over every candidate, in f64.
                let mut best = f64::INFINITY;
                for cy in m..30 - m {
                    for cx in m..34 - m {
                        let mut d = 0.0f64;
                        for dy in -2..=2isize {
                            for dx in -2..=2isize {
                                let a = os[l].px((x as isize + dx * st) as usize, (y as isize + dy * st) as usize);
                                let b = ss[l].px((cx + dx * st) as usize, (cy + dy * st) as usize);
                                d += a.iter().zip(b).map(|(a, b)| ((a - b) as f64).powi(2)).sum::<f64>();
                            }
                        }
                        best = best.min(d);
                    }
                }
                let want = best / 25.0 / search.norm;
                assert!((got - want).abs() <= 1e-5 * want.max(1e-3), "level {l} ({x}, {y}): {got} vs {want}");
            }
            // A window copied from the sample scores 0.
            if l == 0 {
                let got = search.nearest(&ss[0], 10, 12, Some((10, 12)), &mut Vec::new());
                assert_eq!(got, 0.0);
            }
        }
    }
}
