//! The reusable analysis of a sample (paper 000 sections 4.1 and 4.2).
//!
//! For every level of the sample pyramid: the textons (see [`crate::textons`]) and, for each
//! neighbourhood radius asked for, the `m` most similar neighbourhoods of every sample pixel
//! ("for each pixel in the sample, a number of (for example 10) pixels with the most similar
//! neighborhoods"), found by brute force over the whole level as the paper does for samples up
//! to 128 x 128, in parallel. The synthesis only reads this: its cost does not depend on the
//! sample resolution or on the length of the appearance vectors (the paper's Table 1 remark).
//!
//! A neighbourhood of radius `r` is the `(2r+1) x (2r+1)` window around a pixel. Only *interior*
//! pixels, whose window lies inside the sample, take part: the sample is not assumed to tile.
//! A pixel's own window (pixels closer than `r + 1` in both axes) is excluded from its similar
//! set, since overlapping windows are similar for a trivial reason and the k-coherence candidates
//! already include the coherent shifts.

use crate::pyramid::{pyramid, Features};
use crate::textons::{btf_features, FeatureMode, Textons};
use btfrs_core::{BtfRef, Error, Monitor, Result};
use rayon::prelude::*;

/// Largest neighbourhood radius accepted (a 17 x 17 window).
pub const MAX_RADIUS: usize = 8;

/// Parameters of the analysis.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AnalysisOptions {
    /// Textons of the finest level (coarser levels use at most one per pixel).
    pub textons: usize,
    /// Pyramid levels (1 = no hierarchy).
    pub levels: usize,
    /// Similar neighbourhoods kept per sample pixel (the largest usable `k` is `m + 1`... see
    /// [`crate::kcoherence`]: `k - 1 <= m`).
    pub m: usize,
    /// Lloyd iterations of every k-means.
    pub iterations: usize,
    /// Seed of every random choice (k-means++ seeding, PCA sketch).
    pub seed: u64,
}

impl Default for AnalysisOptions {
    fn default() -> Self {
        Self { textons: 1024, levels: 3, m: 10, iterations: 20, seed: 0 }
    }
}

/// The `m` most similar neighbourhoods of every pixel of one level, for one radius.
#[derive(Debug, Clone, PartialEq)]
pub struct Neighbours {
    /// Window radius.
    pub radius: usize,
    /// Entries per pixel.
    pub m: usize,
    /// `[pixels, m]` row-major pixel indices, most similar first; `u32::MAX` for the pixels that
    /// are not interior (they are never candidates).
    pub index: Vec<u32>,
    /// `[pixels, m]` neighbourhood distances (sum of texton distances over the window).
    pub dist: Vec<f32>,
}

/// One pyramid level of the analysis.
#[derive(Debug, Clone)]
pub struct Level {
    /// Rows.
    pub height: usize,
    /// Columns.
    pub width: usize,
    /// Textons of the level.
    pub textons: Textons,
    /// Similar neighbourhoods, one entry per radius computed so far (sorted by radius).
    pub neighbours: Vec<Neighbours>,
}

impl Level {
    /// The similar neighbourhoods for `radius`, if computed.
    pub fn neighbours(&self, radius: usize) -> Option<&Neighbours> {
        self.neighbours.iter().find(|n| n.radius == radius)
    }

    /// Whether pixel `(x, y)` is interior for `radius`.
    #[inline]
    pub fn interior(&self, x: isize, y: isize, radius: usize) -> bool {
        let r = radius as isize;
        x >= r && y >= r && x < self.width as isize - r && y < self.height as isize - r
    }
}

/// The analysis of a sample: one [`Level`] per pyramid level, finest first.
#[derive(Debug, Clone)]
pub struct Analysis {
    /// Finest first.
    pub levels: Vec<Level>,
    /// Similar neighbourhoods per pixel.
    pub m: usize,
    /// The options it was made with.
    pub options: AnalysisOptions,
}

/// Smallest level side accepted by the analysis.
const MIN_SIDE: usize = 4;

impl Analysis {
    /// Analyse a BTF sample: appearance vectors by `mode`, then [`Analysis::of_features`].
    /// Announces its total work on `monitor` and advances it.
    pub fn of_btf(
        btf: &BtfRef<'_>,
        mode: FeatureMode,
        opts: AnalysisOptions,
        radii: &[usize],
        monitor: &Monitor,
    ) -> Result<Self> {
        check_options(btf.height, btf.width, &opts)?;
        let feat_units = match mode {
            FeatureMode::All => 1,
            FeatureMode::Pca { .. } => 4,
            FeatureMode::Images { .. } => opts.iterations as u64,
        };
        monitor.start(feat_units + units(btf.height, &opts, radii));
        let f = btf_features(btf, mode, opts.iterations, opts.seed, monitor)?;
        Self::build(f, opts, radii, monitor)
    }

    /// Analyse a sample given as per-pixel feature vectors (an RGB texture is `dim = 3`).
    pub fn of_features(f: Features, opts: AnalysisOptions, radii: &[usize], monitor: &Monitor) -> Result<Self> {
        check_options(f.height, f.width, &opts)?;
        monitor.start(units(f.height, &opts, radii));
        Self::build(f, opts, radii, monitor)
    }

    fn build(f: Features, opts: AnalysisOptions, radii: &[usize], monitor: &Monitor) -> Result<Self> {
        let mut levels = Vec::with_capacity(opts.levels);
        for (l, f) in pyramid(f, opts.levels).into_iter().enumerate() {
            monitor.check()?;
            let t = opts.textons.min(f.pixels());
            let seed = opts.seed.wrapping_add(l as u64);
            let textons = Textons::fit(&f, t, opts.iterations, seed, monitor)?;
            levels.push(Level { height: f.height, width: f.width, textons, neighbours: Vec::new() });
        }
        let mut an = Self { levels, m: opts.m, options: opts };
        for &r in radii {
            // As many levels as are big enough for this radius (a synthesis asking for more
            // levels gets the error then); none at all is an error now.
            match (1..=an.levels.len()).rev().find(|&l| an.check_levels(r, l).is_ok()) {
                Some(l) => an.ensure_neighbours(r, l, monitor)?,
                None => an.check_levels(r, 1)?,
            }
        }
        Ok(an)
    }

    /// Rebuild from saved parts (a loaded file), checking everything the synthesis relies on, so
    /// that a corrupted or hand-made analysis is an error here and not a panic or a wrong result
    /// later. Errors name the saved array (`level{l}.textons`, `level{l}.centers`,
    /// `level{l}.similar{r}.index`, `level{l}.similar{r}.dist`):
    ///
    /// * the options are valid for the finest level's size (as [`Analysis::of_features`] checks)
    ///   and there are as many levels as they say;
    /// * each level is half the previous one, rounded down ([`crate::pyramid::downsample`] drops
    ///   an odd last row or column): k-coherence maps a coarse pixel `(x, y)` to `(2x, 2y)` and
    ///   reads the coarser level as `width / 2` columns;
    /// * every level has one texton per pixel, the same vector length, and no more textons than
    ///   pixels or than the options ask for;
    /// * the similar neighbourhoods have `m` entries per pixel, each empty (`u32::MAX`) or an
    ///   interior pixel for their radius (the synthesis reads that pixel's whole window), with a
    ///   distance that is not NaN or negative.
    pub fn from_levels(levels: Vec<Level>, options: AnalysisOptions) -> Result<Self> {
        let Some(first) = levels.first() else {
            return Err(Error::arg("levels", "expected at least one level"));
        };
        let (h0, w0, dim) = (first.height, first.width, first.textons.dim);
        check_options(h0, w0, &options)?;
        if levels.len() != options.levels {
            return Err(Error::arg(
                "levels",
                format!("the options say {} pyramid levels, the arrays hold {}", options.levels, levels.len()),
            ));
        }
        for (l, lv) in levels.iter().enumerate() {
            let textons = format!("level{l}.textons");
            let (eh, ew) = (h0 >> l, w0 >> l);
            if (lv.height, lv.width) != (eh, ew) {
                return Err(Error::arg(
                    textons,
                    format!(
                        "level {l} is {} x {}, expected {eh} x {ew} (each level is half the previous one, \
                         rounded down, from the {h0} x {w0} sample)",
                        lv.height, lv.width
                    ),
                ));
            }
            let pixels = lv.height * lv.width;
            if lv.textons.assign.len() != pixels {
                return Err(Error::arg(
                    textons,
                    format!("level {l}: expected {} x {} texton indices", lv.height, lv.width),
                ));
            }
            let t = lv.textons.count();
            if lv.textons.dim != dim || t > pixels.min(options.textons) {
                return Err(Error::arg(
                    format!("level{l}.centers"),
                    format!(
                        "level {l} has {t} textons of length {}; expected at most {} of length {dim} (as level 0)",
                        lv.textons.dim,
                        pixels.min(options.textons)
                    ),
                ));
            }
            for n in &lv.neighbours {
                let (r, m) = (n.radius, n.m);
                let index = format!("level{l}.similar{r}.index");
                let len = pixels * m;
                if r == 0 || r > MAX_RADIUS || m != options.m || n.index.len() != len || n.dist.len() != len {
                    return Err(Error::arg(
                        index,
                        format!("level {l}, radius {r}: expected {} x {} x {} entries", lv.height, lv.width, options.m),
                    ));
                }
                let ok = |i: u32| {
                    let i = i as usize;
                    i == u32::MAX as usize
                        || (i < pixels && lv.interior((i % lv.width) as isize, (i / lv.width) as isize, r))
                };
                if let Some(p) = n.index.iter().position(|&i| !ok(i)) {
                    return Err(Error::arg(
                        index,
                        format!(
                            "level {l}, radius {r}: entry {p} is {}, not an interior pixel of the {} x {} level",
                            n.index[p] as i64, lv.height, lv.width
                        ),
                    ));
                }
                if let Some(p) = n.dist.iter().position(|d| d.is_nan() || *d < 0.0) {
                    return Err(Error::arg(
                        format!("level{l}.similar{r}.dist"),
                        format!("level {l}, radius {r}: distance {p} is {}, expected >= 0", n.dist[p]),
                    ));
                }
            }
        }
        Ok(Self { levels, m: options.m, options })
    }

    /// Rows and columns of the finest level (the sample).
    pub fn size(&self) -> (usize, usize) {
        (self.levels[0].height, self.levels[0].width)
    }

    /// Check that `levels` levels of the pyramid are big enough for windows of `radius` (each
    /// needs more than `m` interior pixels outside any one window).
    pub fn check_levels(&self, radius: usize, levels: usize) -> Result<()> {
        self.check_levels_from(radius, 0, levels)
    }

    /// [`Analysis::check_levels`] for levels `first..levels` only (a coarse-level radius).
    pub fn check_levels_from(&self, radius: usize, first: usize, levels: usize) -> Result<()> {
        if radius == 0 || radius > MAX_RADIUS {
            return Err(Error::arg(
                "neighbourhood",
                format!("expected a window radius of 1 to {MAX_RADIUS}, got {radius}"),
            ));
        }
        if levels == 0 || levels > self.levels.len() {
            return Err(Error::arg(
                "levels",
                format!("expected 1 to {} levels (the levels of the analysis), got {levels}", self.levels.len()),
            ));
        }
        for (l, lv) in self.levels.iter().enumerate().take(levels).skip(first) {
            let (ih, iw) = (lv.height.saturating_sub(2 * radius), lv.width.saturating_sub(2 * radius));
            let w = (2 * radius + 1).pow(2);
            if ih * iw < w + self.m {
                let (h0, w0) = self.size();
                let name = if l == 0 { "neighbourhood" } else { "levels" };
                return Err(Error::arg(
                    name,
                    format!(
                        "the {h0} x {w0} sample is {} x {} at level {l}, too small for neighbourhood {radius} \
                         ({} x {} windows) with m = {}: use fewer levels, a smaller neighbourhood or a larger sample",
                        lv.height,
                        lv.width,
                        2 * radius + 1,
                        2 * radius + 1,
                        self.m
                    ),
                ));
            }
        }
        Ok(())
    }

    /// Compute (once) the similar neighbourhoods for `radius` on the first `levels` levels.
    pub fn ensure_neighbours(&mut self, radius: usize, levels: usize, monitor: &Monitor) -> Result<()> {
        self.ensure_neighbours_at(radius, 0, levels, monitor)
    }

    /// Compute (once) the similar neighbourhoods for `radius` on levels `first..levels` (the
    /// coarse levels of a synthesis with a larger coarse neighbourhood).
    pub fn ensure_neighbours_at(
        &mut self,
        radius: usize,
        first: usize,
        levels: usize,
        monitor: &Monitor,
    ) -> Result<()> {
        self.check_levels_from(radius, first, levels)?;
        let m = self.m;
        for lv in self.levels.iter_mut().take(levels).skip(first) {
            if lv.neighbours(radius).is_none() {
                let n = similar_neighbourhoods(lv, radius, m, monitor)?;
                lv.neighbours.push(n);
                lv.neighbours.sort_by_key(|n| n.radius);
            }
        }
        Ok(())
    }

    /// Work units of [`Analysis::ensure_neighbours`] (for progress reporting).
    pub fn neighbour_units(&self, radius: usize, levels: usize) -> u64 {
        self.neighbour_units_at(radius, 0, levels)
    }

    /// Work units of [`Analysis::ensure_neighbours_at`].
    pub fn neighbour_units_at(&self, radius: usize, first: usize, levels: usize) -> u64 {
        self.levels
            .iter()
            .take(levels)
            .skip(first)
            .filter(|lv| lv.neighbours(radius).is_none())
            .map(|lv| lv.height.saturating_sub(2 * radius) as u64)
            .sum()
    }
}

fn check_options(h: usize, w: usize, opts: &AnalysisOptions) -> Result<()> {
    if opts.textons == 0 || opts.textons > h * w {
        return Err(Error::arg(
            "textons",
            format!("expected 1 to {} textons (the {h} x {w} pixels of the sample), got {}", h * w, opts.textons),
        ));
    }
    if opts.textons > crate::textons::MAX_TEXTONS {
        return Err(Error::arg(
            "textons",
            format!("expected at most {} textons, got {}", crate::textons::MAX_TEXTONS, opts.textons),
        ));
    }
    if opts.m == 0 || opts.m > 64 {
        return Err(Error::arg("m", format!("expected 1 to 64 similar neighbourhoods per pixel, got {}", opts.m)));
    }
    if opts.iterations == 0 {
        return Err(Error::arg("iterations", "expected at least 1 k-means iteration, got 0"));
    }
    let max_levels = (0..).take_while(|&l| (h >> l) >= MIN_SIDE && (w >> l) >= MIN_SIDE).count();
    if opts.levels == 0 || opts.levels > max_levels {
        return Err(Error::arg(
            "levels",
            format!(
                "a {h} x {w} sample allows 1 to {max_levels} pyramid levels of at least {MIN_SIDE} x {MIN_SIDE} pixels, got {}",
                opts.levels
            ),
        ));
    }
    Ok(())
}

/// Progress units of an analysis: the k-means iterations of every level plus one per interior
/// row of every level whose similar neighbourhoods are computed.
fn units(h: usize, opts: &AnalysisOptions, radii: &[usize]) -> u64 {
    let rows: u64 =
        radii.iter().flat_map(|&r| (0..opts.levels).map(move |l| (h >> l).saturating_sub(2 * r) as u64)).sum();
    (opts.levels * opts.iterations) as u64 + rows
}

/// Brute-force `m` most similar interior neighbourhoods of every interior pixel of a level.
///
/// Every pair of interior windows is scored, displacement by displacement: for a displacement
/// `v`, the distances `e(u) = d(u, u + v)` of every pixel to the pixel `v` away are computed
/// once, and a window pair's distance is the box sum of `e` over the window (its rows summed
/// left to right, then the row sums top to bottom). Each pixel thus costs one texton distance
/// per displacement instead of one per window pixel, and the sum of a pair is the same whichever
/// of its two pixels it is scored for, so only half the displacements are visited and each pair
/// is offered to both pixels. Each pixel keeps the `m` smallest `(distance, index)` pairs, ties
/// going to the lower index; the pairs are compared as a whole, so the result does not depend
/// on the visiting order or on how the displacements are split among the threads.
///
/// A texton distance is an entry of the texton distance table, except for appearance vectors of
/// at most four values (an RGB texture's): a table of a thousand textons is 4 MB, and reading it
/// at random waits on the cache for every entry, so those entries are recomputed from the pixels'
/// vectors instead, by the table's own formula (the same bits).
fn similar_neighbourhoods(lv: &Level, r: usize, m: usize, monitor: &Monitor) -> Result<Neighbours> {
    match lv.textons.dim {
        1 => search(lv, r, m, &Vectors::<1>::new(lv), monitor),
        2 => search(lv, r, m, &Vectors::<2>::new(lv), monitor),
        3 => search(lv, r, m, &Vectors::<3>::new(lv), monitor),
        4 => search(lv, r, m, &Vectors::<4>::new(lv), monitor),
        _ => search(lv, r, m, &Table(&lv.textons), monitor),
    }
}

/// The texton distance of pixel pairs, as [`search`] reads it.
trait PairCost: Sync {
    /// `out[i]` = the distance between pixel `u + i` and pixel `u + i + v`.
    fn run(&self, u: usize, v: usize, out: &mut [f32]);
}

/// Entries of the texton distance table.
struct Table<'a>(&'a Textons);

impl PairCost for Table<'_> {
    fn run(&self, u: usize, v: usize, out: &mut [f32]) {
        let (t, assign, dist) = (self.0.count(), &self.0.assign, &self.0.dist);
        for ((o, &a), &b) in out.iter_mut().zip(&assign[u..]).zip(&assign[u + v..]) {
            *o = dist[a as usize * t + b as usize];
        }
    }
}

/// The table's entries recomputed from the pixels' appearance vectors of `D` values.
struct Vectors<const D: usize> {
    /// Every pixel's texton's vector, widened.
    pixels: Vec<[f64; D]>,
}

impl<const D: usize> Vectors<D> {
    fn new(lv: &Level) -> Self {
        let tex = &lv.textons;
        let at = |a: u16, k: usize| tex.centers[a as usize * D + k] as f64;
        Self { pixels: tex.assign.iter().map(|&a| std::array::from_fn(|k| at(a, k))).collect() }
    }
}

impl<const D: usize> PairCost for Vectors<D> {
    fn run(&self, u: usize, v: usize, out: &mut [f32]) {
        for ((o, a), b) in out.iter_mut().zip(&self.pixels[u..]).zip(&self.pixels[u + v..]) {
            // `Textons::from_parts`'s entry: the squared differences in f64, summed in order.
            let mut e = (a[0] - b[0]) * (a[0] - b[0]);
            for k in 1..D {
                e += (a[k] - b[k]) * (a[k] - b[k]);
            }
            *o = e as f32;
        }
    }
}

/// Every pixel's `m` best `(distance, index)` pairs so far, in order (empty: `(inf, MAX)`).
struct Lists {
    m: usize,
    best: Vec<(f32, u32)>,
    /// Every pixel's `m`-th distance, apart: almost every offer loses to it, and this check
    /// then reads 4 bytes per pixel instead of a pixel's whole list.
    worst: Vec<f32>,
}

impl Lists {
    fn new(pixels: usize, m: usize) -> Self {
        Self { m, best: vec![(f32::INFINITY, u32::MAX); pixels * m], worst: vec![f32::INFINITY; pixels] }
    }

    /// Offer `(s, q)` to pixel `p`.
    #[inline(always)]
    fn offer(&mut self, p: usize, s: f32, q: u32) {
        if s > self.worst[p] {
            return;
        }
        let l = &mut self.best[p * self.m..(p + 1) * self.m];
        let before = |e: &(f32, u32)| s < e.0 || (s == e.0 && q < e.1);
        if !before(&l[l.len() - 1]) {
            return;
        }
        let mut j = l.len() - 1;
        while j > 0 && before(&l[j - 1]) {
            l[j] = l[j - 1];
            j -= 1;
        }
        l[j] = (s, q);
        self.worst[p] = l[l.len() - 1].0;
    }

    /// The `m` best of both, per pixel.
    fn merge(mut self, other: Self) -> Self {
        for (p, l) in other.best.chunks(self.m).enumerate() {
            for &(s, q) in l.iter().take_while(|e| e.1 != u32::MAX) {
                self.offer(p, s, q);
            }
        }
        self
    }
}

/// [`similar_neighbourhoods`] with texton distances from `cost`.
fn search<C: PairCost>(lv: &Level, r: usize, m: usize, cost: &C, monitor: &Monitor) -> Result<Neighbours> {
    let (h, w) = (lv.height, lv.width);
    let (ih, iw) = (h - 2 * r, w - 2 * r);
    let side = 2 * r + 1;
    let n = h * w;
    // One task per vertical displacement `dy >= 0` (with `dx > 0` when `dy = 0`): the other
    // half are the same pairs seen from the other pixel.
    let lists = (0..ih)
        .into_par_iter()
        .try_fold(
            || (Lists::new(n, m), Vec::new(), Vec::new()),
            |(mut lists, mut e, mut hs), dy| -> Result<_> {
                monitor.check()?;
                let dxs = if dy == 0 { 1 } else { 1 - iw as isize }..iw as isize;
                for dx in dxs {
                    if dy <= r && dx.unsigned_abs() <= r {
                        continue; // the windows overlap
                    }
                    // Pixels p = (x, y) with p and p + (dx, dy) interior: x in x0..x1, y in r..y1.
                    let x0 = (r as isize).max(r as isize - dx) as usize;
                    let x1 = ((w - r) as isize).min((w - r) as isize - dx) as usize;
                    let y1 = h - r - dy;
                    let (nx, ny) = (x1 - x0, y1 - r);
                    let (ew, eh) = (nx + 2 * r, ny + 2 * r);
                    let v = (dy as isize * w as isize + dx) as usize;
                    // e over the windows' pixels, then its row sums over `side` columns.
                    e.resize(ew * eh, 0.0f32);
                    hs.resize(nx * eh, 0.0f32);
                    for (j, (er, hr)) in e.chunks_exact_mut(ew).zip(hs.chunks_exact_mut(nx)).enumerate() {
                        cost.run(j * w + x0 - r, v, er);
                        hr.copy_from_slice(&er[..nx]);
                        for k in 1..side {
                            for (a, &b) in hr.iter_mut().zip(&er[k..k + nx]) {
                                *a += b;
                            }
                        }
                    }
                    let mut col = vec![0.0f32; nx];
                    for j in 0..ny {
                        col.copy_from_slice(&hs[j * nx..(j + 1) * nx]);
                        for k in 1..side {
                            for (a, &b) in col.iter_mut().zip(&hs[(j + k) * nx..(j + k + 1) * nx]) {
                                *a += b;
                            }
                        }
                        let p0 = (j + r) * w + x0;
                        for (i, &s) in col.iter().enumerate() {
                            let p = p0 + i;
                            lists.offer(p, s, (p + v) as u32);
                            lists.offer(p + v, s, p as u32);
                        }
                    }
                }
                monitor.advance(1);
                Ok((lists, e, hs))
            },
        )
        .map(|l| l.map(|(lists, _, _)| lists))
        .try_reduce(|| Lists::new(n, m), |a, b| Ok(a.merge(b)))?;
    let (index, dist) = lists.best.into_iter().map(|(s, q)| (q, s)).unzip();
    Ok(Neighbours { radius: r, m, index, dist })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn noise(h: usize, w: usize, seed: u64) -> Features {
        let data = (0..h * w).map(|i| btfrs_core::rng::hash01(seed, i as i64, 0) as f32).collect();
        Features::new(h, w, 1, data).unwrap()
    }

    #[test]
    fn similar_neighbourhoods_match_a_direct_search() {
        let f = noise(14, 13, 3);
        let opts = AnalysisOptions { textons: 14 * 13, levels: 1, m: 4, iterations: 5, seed: 0 };
        let an = Analysis::of_features(f.clone(), opts, &[1], &Monitor::new()).unwrap();
        let nb = an.levels[0].neighbours(1).unwrap();
        // Direct float64 search over the raw values (one texton per pixel: exact distances).
        let v = |x: usize, y: usize| f.data[y * 13 + x] as f64;
        for (y, x) in [(1usize, 1usize), (5, 7), (12, 11)] {
            let mut all: Vec<(f64, usize)> = Vec::new();
            for qy in 1usize..13 {
                for qx in 1usize..12 {
                    if qy.abs_diff(y) <= 1 && qx.abs_diff(x) <= 1 {
                        continue;
                    }
                    let mut s = 0.0;
                    for dy in 0..3 {
                        for dx in 0..3 {
                            s += (v(x + dx - 1, y + dy - 1) - v(qx + dx - 1, qy + dy - 1)).powi(2);
                        }
                    }
                    all.push((s, qy * 13 + qx));
                }
            }
            all.sort_by(|a, b| a.partial_cmp(b).unwrap());
            for (j, &(d, i)) in all.iter().take(4).enumerate() {
                assert_eq!(nb.index[(y * 13 + x) * 4 + j] as usize, i, "pixel ({x}, {y}) rank {j}");
                assert!((nb.dist[(y * 13 + x) * 4 + j] as f64 - d).abs() < 1e-5);
            }
        }
        // Border pixels have no entries.
        assert_eq!(nb.index[0], u32::MAX);
    }

    #[test]
    fn every_pixel_gets_the_best_pairs_of_an_exhaustive_scan() {
        // Few textons (so many windows tie exactly and the index must break the ties), vectors
        // of 3 values (distances recomputed from the vectors) and of 6 (the table), radii 1
        // and 2, on a level too big for one thread's share of the displacements.
        for (dim, r) in [(3usize, 1usize), (3, 2), (6, 1), (6, 2)] {
            let (h, w) = (17usize, 15usize);
            let data = (0..h * w * dim).map(|i| btfrs_core::rng::hash01(dim as u64, i as i64, 1) as f32).collect();
            let f = Features::new(h, w, dim, data).unwrap();
            let opts = AnalysisOptions { textons: 6, levels: 1, m: 5, iterations: 4, seed: 2 };
            let an = Analysis::of_features(f, opts, &[r], &Monitor::new()).unwrap();
            let lv = &an.levels[0];
            let nb = lv.neighbours(r).unwrap();
            let d = |a: usize, b: usize| lv.textons.d(lv.textons.assign[a], lv.textons.assign[b]);
            let side = 2 * r + 1;
            for y in r..h - r {
                for x in r..w - r {
                    let p = y * w + x;
                    let mut all: Vec<(f32, u32, f64)> = Vec::new();
                    for qy in r..h - r {
                        for qx in r..w - r {
                            if qy.abs_diff(y) <= r && qx.abs_diff(x) <= r {
                                continue;
                            }
                            let q = qy * w + qx;
                            // Row sums left to right, then the rows top to bottom; and in f64.
                            let (mut s, mut s64) = (0.0f32, 0.0f64);
                            for oy in 0..side {
                                let mut row = 0.0f32;
                                for ox in 0..side {
                                    let o = oy * w + ox;
                                    row += d(p - r * w - r + o, q - r * w - r + o);
                                    s64 += d(p - r * w - r + o, q - r * w - r + o) as f64;
                                }
                                s += row;
                            }
                            all.push((s, q as u32, s64));
                        }
                    }
                    all.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
                    for (j, &(s, q, s64)) in all.iter().take(5).enumerate() {
                        assert_eq!(nb.index[p * 5 + j], q, "dim {dim}, r {r}, pixel ({x}, {y}), rank {j}");
                        assert_eq!(nb.dist[p * 5 + j], s);
                        assert!((s as f64 - s64).abs() <= 1e-5 * (1.0 + s64));
                    }
                }
            }
        }
    }

    #[test]
    fn loaded_levels_must_form_the_pyramid_the_synthesis_assumes() {
        let f = noise(17, 16, 2);
        let opts = AnalysisOptions { textons: 12, levels: 2, m: 3, iterations: 3, seed: 0 };
        let an = Analysis::of_features(f, opts, &[1], &Monitor::new()).unwrap();
        // Levels are 17 x 16 and 8 x 8 (the odd row dropped): a faithful copy loads.
        assert_eq!((an.levels[1].height, an.levels[1].width), (8, 8));
        let back = Analysis::from_levels(an.levels.clone(), opts).unwrap();
        let o = crate::SynthOptions {
            height: 24,
            width: 24,
            k: 2,
            radius: 1,
            coarse_radius: 1,
            levels: 2,
            toroidal: false,
            seed: 3,
        };
        let want = crate::kcoherence(&an, &o, &Monitor::new()).unwrap();
        assert_eq!(crate::kcoherence(&back, &o, &Monitor::new()).unwrap().src, want.src);
        let err = |levels: Vec<Level>, o: AnalysisOptions| Analysis::from_levels(levels, o).unwrap_err().to_string();

        // A coarse level that is not half the finest one (here: the finest one again, which the
        // synthesis would read with the wrong width), and one rounded up instead of down.
        let mut same = an.levels.clone();
        same[1] = same[0].clone();
        let msg = err(same, opts);
        assert!(msg.starts_with("level1.textons:") && msg.contains("expected 8 x 8"), "{msg}");
        let mut up = an.levels.clone();
        let textons = Textons::from_parts(1, vec![0.0], vec![0; 9 * 8]).unwrap();
        up[1] = Level { height: 9, width: 8, textons, neighbours: Vec::new() };
        assert!(err(up, opts).starts_with("level1.textons:"));
        // A level missing, or the options asking for more levels than the sample allows.
        assert!(err(an.levels[..1].to_vec(), opts).starts_with("levels:"));
        assert!(err(an.levels.clone(), AnalysisOptions { levels: 3, ..opts }).starts_with("levels:"));
        // Vectors of another length than level 0's.
        let mut dim = an.levels.clone();
        let n1 = dim[1].textons.assign.len();
        dim[1].textons = Textons::from_parts(2, vec![0.0; 4], vec![0; n1]).unwrap();
        assert!(err(dim, opts).starts_with("level1.centers:"));
        // A similar-neighbourhood entry on the border (the synthesis would read outside the
        // level), a NaN distance.
        let mut border = an.levels.clone();
        border[0].neighbours[0].index[16 * 5 + 5] = 0;
        let msg = err(border, opts);
        assert!(msg.starts_with("level0.similar1.index:") && msg.contains("not an interior pixel"), "{msg}");
        let mut nan = an.levels.clone();
        nan[1].neighbours[0].dist[3] = f32::NAN;
        assert!(err(nan, opts).starts_with("level1.similar1.dist:"));
    }

    #[test]
    fn bad_options_name_their_parameter() {
        let f = noise(16, 16, 1);
        let bad =
            |o: AnalysisOptions| Analysis::of_features(f.clone(), o, &[], &Monitor::new()).unwrap_err().to_string();
        let o = AnalysisOptions { textons: 16, levels: 2, m: 4, iterations: 3, seed: 0 };
        assert!(bad(AnalysisOptions { textons: 257, ..o }).starts_with("textons:"));
        assert!(bad(AnalysisOptions { levels: 4, ..o }).starts_with("levels:"));
        let an = Analysis::of_features(f.clone(), o, &[], &Monitor::new()).unwrap();
        // 8 x 8 at level 1 leaves 2 x 2 interior pixels for radius 3: too few.
        assert!(an.check_levels(3, 2).unwrap_err().to_string().starts_with("levels:"));
        assert!(an.check_levels(1, 2).is_ok());
        assert!(an.check_levels(0, 1).unwrap_err().to_string().starts_with("neighbourhood:"));
    }
}
