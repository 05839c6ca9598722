//! Wang tile synthesis in the four steps of paper 002, section 3.2 (Figures 4 to 6).
//!
//! Geometry (tile side `w`, edge height `h`, `half = h / 2`, `C` colours per edge direction, so
//! the complete set has `C^4` tiles, each named by its (north, east, south, west) colours):
//!
//! * every horizontal colour `c` owns an **edge strip** `H_c` of `h x w` texels; a tile whose
//!   north colour is `c` takes `H_c`'s bottom half as its top `half` rows and a tile whose south
//!   colour is `c` its top half as its bottom rows, so two tiles meeting along a `c` edge put
//!   `H_c` back together: the boundary is inside a synthesized strip, never a seam. Vertical
//!   colours own `w x h` strips `V_c` the same way (east: left half, west: right half).
//! * **1. Corner sampling.** The ends of each strip are *corner samples* copied from the
//!   sample: `h x half` for horizontal strips (left and right ends), `half x h` for vertical ones
//!   (top and bottom). At each tile corner a horizontal and a vertical corner sample overlap in a
//!   `half x half` quadrant; a minimum cut there joins them, the horizontal texels continuing
//!   across the tile's horizontal boundary and the vertical ones across its vertical boundary.
//!   Every (horizontal, vertical) colour pair meets in every quadrant kind in a complete set, so
//!   the corner samples are chosen (random candidates, then rounds of coordinate descent) to
//!   minimise the sum of all these short cuts, with distinct colours' samples kept apart.
//! * **2. Edge synthesis**: the `w - h` texels between the two corner samples of each strip are
//!   filled by graph-cut patch filling ([`crate::fill`]).
//! * **3. Frame construction**: each tile's border bands come from its four strips, its corner
//!   quadrants from the cuts of step 1.
//! * **4. Interior synthesis**: the `(w - h)^2` interior is filled by the same patch filling.
//!   Only the outer `h / 4` texels of the frame are held (what the neighbouring tile continues);
//!   the fill's patches overlap the inner `h / 4`, so the frame-interior seam is a minimum cut
//!   that can wander, not the straight line a fully fixed frame leaves (the same holds for the
//!   corner samples at the ends of the edge strips in step 2).
//!
//! Tiles are never rotated (section 6: a BTF has an orientation). Strips and tiles are
//! independent given the corner samples, so steps 2 and 4 run in parallel, each with its own
//! seeded generator (results do not depend on the thread count).

use crate::features::{FeatureOps, Features};
use crate::fill::{fill, Canvas, FillOptions, FillStats, Sample, EMPTY};
use btfrs_core::rng::{mix, Rng};
use btfrs_core::{Error, Monitor, Result};
use btfrs_graphcut::Graph;
use rayon::prelude::*;
use std::time::Instant;

/// Options of a tile-set synthesis.
#[derive(Debug, Clone, serde::Deserialize, serde::Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct WangOptions {
    /// Tile side in texels.
    pub tile: usize,
    /// Edge height `h` (the feature size): even, at most half the tile.
    pub edge_height: usize,
    /// Colours per edge direction (the set has `colors^4` tiles).
    pub colors: usize,
    /// Seed of every random choice.
    pub seed: u64,
    /// Patch side of the fills (0: `min(5 h / 2, 5 tile / 8)`, at least 8).
    pub patch: usize,
    /// Candidate offsets per patch placement.
    pub candidates: usize,
    /// Take one of this many cheapest candidates at random.
    pub best_of: usize,
    /// Fill thresholds, relative to the mean squared distance of random texel pairs.
    pub pixel_threshold: f64,
    /// Mean per-pixel seam error threshold (relative).
    pub total_threshold: f64,
    /// Refinement patches per fill (at most).
    pub refine: usize,
    /// Random candidates per corner sample and round of corner sampling.
    pub corner_candidates: usize,
    /// Dimensions of the PCA-reduced features used for matching (the cuts use all).
    pub matching_dims: usize,
}

impl Default for WangOptions {
    fn default() -> Self {
        let f = FillOptions::default();
        WangOptions {
            tile: 64,
            edge_height: 16,
            colors: 2,
            seed: 0,
            patch: 0,
            candidates: f.candidates,
            best_of: f.best_of,
            pixel_threshold: f.pixel_threshold,
            total_threshold: f.total_threshold,
            refine: f.refine,
            corner_candidates: 48,
            matching_dims: 8,
        }
    }
}

impl WangOptions {
    /// Check every option against the sample size, naming the one at fault.
    pub fn validate(&self, sample_h: usize, sample_w: usize) -> Result<()> {
        if self.tile < 4 {
            return Err(Error::arg("tile", format!("expected at least 4 texels, got {}", self.tile)));
        }
        if self.tile > sample_h || self.tile > sample_w {
            return Err(Error::arg(
                "tile",
                format!("a {} texel tile is larger than the {sample_h} x {sample_w} sample", self.tile),
            ));
        }
        if self.edge_height < 2 || !self.edge_height.is_multiple_of(2) {
            return Err(Error::arg("edge_height", format!("expected an even number >= 2, got {}", self.edge_height)));
        }
        if self.edge_height > self.tile / 2 {
            return Err(Error::arg(
                "edge_height",
                format!("{} is larger than half the tile ({})", self.edge_height, self.tile / 2),
            ));
        }
        if !(2..=8).contains(&self.colors) {
            return Err(Error::arg(
                "colors",
                format!("expected 2 to 8 colours per edge direction, got {}", self.colors),
            ));
        }
        for (name, v) in [("pixel_threshold", self.pixel_threshold), ("total_threshold", self.total_threshold)] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(Error::arg(name, format!("expected a finite value >= 0, got {v}")));
            }
        }
        for (name, v) in
            [("candidates", self.candidates), ("best_of", self.best_of), ("matching_dims", self.matching_dims)]
        {
            if v == 0 {
                return Err(Error::arg(name, "expected at least 1"));
            }
        }
        if self.corner_candidates == 0 {
            return Err(Error::arg("corner_candidates", "expected at least 1"));
        }
        Ok(())
    }

    fn fill_options(&self) -> FillOptions {
        let patch = if self.patch == 0 { (5 * self.edge_height / 2).min(5 * self.tile / 8).max(8) } else { self.patch };
        FillOptions {
            patch,
            candidates: self.candidates,
            best_of: self.best_of,
            pixel_threshold: self.pixel_threshold,
            total_threshold: self.total_threshold,
            refine: self.refine,
            max_rejects: 6,
        }
    }
}

/// One step of the synthesis, as reported.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct StepReport {
    /// "corner sampling", "edge synthesis", "frame construction", "interior synthesis".
    pub step: String,
    /// Wall time.
    pub seconds: f64,
    /// Patches placed (fills) or cuts evaluated (corner sampling).
    pub work: usize,
    /// Sum of the seam costs left by the step (relative units).
    pub seam_total: f64,
    /// Largest per-pixel seam error (relative units).
    pub seam_max: f64,
    /// Mean per-pixel seam error over the synthesized region (relative units).
    pub seam_mean: f64,
    /// Fills that met both thresholds, of all fills.
    pub converged: String,
}

/// A synthesized complete Wang tile set over a sample.
#[derive(Debug, Clone)]
pub struct WangTiles {
    /// Tile side.
    pub tile: usize,
    /// Edge height.
    pub edge_height: usize,
    /// Colours per edge direction.
    pub colors: usize,
    /// Sample (height, width).
    pub sample_dims: (usize, usize),
    /// Per tile (canonical id, see [`tile_id`]), `tile * tile` sample texel indices, row-major.
    pub texels: Vec<Vec<u32>>,
    /// Per tile, its (north, east, south, west) colours.
    pub codes: Vec<[u8; 4]>,
    /// The steps.
    pub steps: Vec<StepReport>,
    /// Mean squared distance between random texel pairs (the unit of the seam costs).
    pub pair_scale: f64,
    /// Variance fraction kept by the matching features.
    pub matching_variance: f64,
}

/// The canonical id of the tile with colours (north, east, south, west):
/// `((n * C + e) * C + s) * C + w`.
pub fn tile_id(code: [u8; 4], colors: usize) -> usize {
    code.iter().fold(0usize, |a, &c| a * colors + c as usize)
}

/// The colours of tile `id` (inverse of [`tile_id`]).
pub fn tile_code(id: usize, colors: usize) -> [u8; 4] {
    let mut out = [0u8; 4];
    let mut r = id;
    for k in (0..4).rev() {
        out[k] = (r % colors) as u8;
        r /= colors;
    }
    out
}

/// Sample positions (row, column) of each strip's two corner samples.
#[derive(Debug, Clone)]
struct Corners {
    /// Horizontal strips: left end, right end (each `h x half`).
    hl: Vec<(usize, usize)>,
    hr: Vec<(usize, usize)>,
    /// Vertical strips: top end, bottom end (each `half x h`).
    vt: Vec<(usize, usize)>,
    vb: Vec<(usize, usize)>,
}

/// The four kinds of corner quadrant of a tile.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Quadrant {
    TopLeft,
    TopRight,
    BottomLeft,
    BottomRight,
}
const QUADRANTS: [Quadrant; 4] = [Quadrant::TopLeft, Quadrant::TopRight, Quadrant::BottomLeft, Quadrant::BottomRight];

struct Geometry {
    half: usize,
    sw: usize,
}

impl Geometry {
    fn texel(&self, (y, x): (usize, usize), dy: usize, dx: usize) -> u32 {
        ((y + dy) * self.sw + x + dx) as u32
    }

    /// For quadrant `q` (pixel (y, x) in `0..half`), the texels of the horizontal and vertical
    /// corner samples that overlap there.
    fn quadrant_labels(&self, q: Quadrant, c: &Corners, hc: usize, vc: usize, y: usize, x: usize) -> (u32, u32) {
        let half = self.half;
        match q {
            // Tile rows 0..half come from the bottom half of H_n (strip rows half..h); tile
            // columns 0..half from the right half of V_w (strip columns half..h).
            Quadrant::TopLeft => (self.texel(c.hl[hc], y + half, x), self.texel(c.vt[vc], y, x + half)),
            Quadrant::TopRight => (self.texel(c.hr[hc], y + half, x), self.texel(c.vt[vc], y, x)),
            Quadrant::BottomLeft => (self.texel(c.hl[hc], y, x), self.texel(c.vb[vc], y, x + half)),
            Quadrant::BottomRight => (self.texel(c.hr[hc], y, x), self.texel(c.vb[vc], y, x)),
        }
    }
}

/// The minimum cut joining a horizontal and a vertical corner sample in one quadrant: returns
/// its cost and, per quadrant pixel (row-major), whether it takes the horizontal sample.
///
/// The quadrant's sides touch: the tile boundary that the horizontal strip crosses (its texels
/// must continue there), the tile boundary the vertical strip crosses, the horizontal band of
/// the tile and the vertical band. Each side is a fixed label whose texels are the sample
/// continuation of that corner sample, so the cut also pays for seams along the sides.
fn quadrant_cut(g: &Geometry, s: &Sample<'_>, q: Quadrant, c: &Corners, hc: usize, vc: usize) -> (f64, Vec<bool>) {
    let n = g.half;
    let mut graph: Graph<f64> = Graph::with_capacity(n * n, 2 * n * n);
    let labels: Vec<(u32, u32)> = (0..n * n).map(|i| g.quadrant_labels(q, c, hc, vc, i / n, i % n)).collect();
    // Side labels: which label the neighbour across each side of the quadrant has. Top/bottom
    // sides: for the top quadrants the tile's top boundary (horizontal continues) and the
    // vertical band below; left/right sides: the tile's vertical boundary (vertical continues)
    // and the horizontal band.
    let (top_h, left_h) = match q {
        // top side: across the tile's top edge -> H; bottom side: the V band -> V.
        // left side: across the tile's left edge -> V; right side: the H band -> H.
        Quadrant::TopLeft => (true, false),
        // top: tile edge -> H; bottom: V band. right: tile edge -> V; left: H band -> H.
        Quadrant::TopRight => (true, true),
        // bottom: tile edge -> H; top: V band -> V. left: tile edge -> V; right: H band.
        Quadrant::BottomLeft => (false, false),
        Quadrant::BottomRight => (false, true),
    };
    // Source = horizontal label, sink = vertical label.
    for y in 0..n {
        for x in 0..n {
            let i = y * n + x;
            let (hp, vp) = labels[i];
            // Internal edges to the right and down.
            for (dy, dx) in [(0usize, 1usize), (1, 0)] {
                let (qy, qx) = (y + dy, x + dx);
                if qy >= n || qx >= n {
                    continue;
                }
                let j = qy * n + qx;
                let (hq, vq) = labels[j];
                let e_hv = s.seam(hp, vq, dy as i64, dx as i64);
                let e_vh = s.seam(vp, hq, dy as i64, dx as i64);
                let _ = graph.add_edge(i, j, e_hv, e_vh);
            }
            // Sides: the neighbour outside carries one label, continued from this pixel's.
            let mut side = |dy: i64, dx: i64, outside_h: bool| {
                // The outside neighbour's texel is the continuation of its label's sample.
                let shift = |t: u32| -> Option<u32> {
                    let (ty, tx) = (t as i64 / s.full.width as i64 + dy, t as i64 % s.full.width as i64 + dx);
                    (ty >= 0 && tx >= 0 && ty < s.full.height as i64 && tx < s.full.width as i64)
                        .then(|| (ty * s.full.width as i64 + tx) as u32)
                };
                let Some(out) = shift(if outside_h { hp } else { vp }) else { return };
                let cost_h = s.seam(hp, out, dy, dx);
                let cost_v = s.seam(vp, out, dy, dx);
                // p horizontal (source side) pays cost_h via its sink link and vice versa.
                let _ = graph.add_terminal(i, cost_v, cost_h);
            };
            if y == 0 {
                side(-1, 0, top_h);
            }
            if y == n - 1 {
                side(1, 0, !top_h);
            }
            if x == 0 {
                side(0, -1, left_h);
            }
            if x == n - 1 {
                side(0, 1, !left_h);
            }
        }
    }
    let flow = graph.maxflow();
    (flow, (0..n * n).map(|i| graph.is_source_side(i)).collect())
}

/// Synthesize the complete tile set over `sample` (see the module docs).
pub fn synthesize(sample: &Features, opts: &WangOptions, monitor: &Monitor) -> Result<WangTiles> {
    opts.validate(sample.height, sample.width)?;
    let (w, h, colors) = (opts.tile, opts.edge_height, opts.colors);
    let half = h / 2;
    let (matching, matching_variance) = sample.reduced(opts.matching_dims);
    let s = Sample { full: sample, matching: &matching };
    let scale = sample.pair_scale(opts.seed);
    let g = Geometry { half, sw: sample.width };
    let fopts = opts.fill_options();
    // Texels held at strip ends and tile borders (see steps 2 and 3).
    let keep = (half / 2).max(1);
    let n_tiles = colors.pow(4);
    // Progress: corner sampling 1, strips 2C, tiles C^4.
    monitor.start((1 + 2 * colors + n_tiles) as u64);
    let mut steps = Vec::new();

    // --- 1. Corner sampling -------------------------------------------------------------
    let t0 = Instant::now();
    let mut rng = Rng::new(mix(opts.seed ^ 0xc0));
    let (sh, sw) = (sample.height, sample.width);
    let pos_h = |rng: &mut Rng| (rng.below(sh - h + 1), rng.below(sw - half + 1));
    let pos_v = |rng: &mut Rng| (rng.below(sh - half + 1), rng.below(sw - h + 1));
    let mut c = Corners {
        hl: (0..colors).map(|_| pos_h(&mut rng)).collect(),
        hr: (0..colors).map(|_| pos_h(&mut rng)).collect(),
        vt: (0..colors).map(|_| pos_v(&mut rng)).collect(),
        vb: (0..colors).map(|_| pos_v(&mut rng)).collect(),
    };
    // The search scores the cuts on the matching features (a PCA subspace: cheap for the
    // hundreds of coefficients of an SH model); the cuts the frames use are then computed on the
    // full features. Cut costs are cached per (quadrant, horizontal colour, vertical colour) and
    // a candidate for one corner sample re-cuts only the 2 C quadrants it takes part in.
    let sm = Sample { full: &matching, matching: &matching };
    let key = |qi: usize, hc: usize, vc: usize| (qi * colors + hc) * colors + vc;
    let cut_all = |c: &Corners| -> Vec<f64> {
        let mut v = vec![0.0; 4 * colors * colors];
        for (qi, q) in QUADRANTS.iter().enumerate() {
            for hc in 0..colors {
                for vc in 0..colors {
                    v[key(qi, hc, vc)] = quadrant_cut(&g, &sm, *q, c, hc, vc).0;
                }
            }
        }
        v
    };
    // Quadrants a corner sample takes part in: H left end: TL, BL; H right: TR, BR; V top: TL,
    // TR; V bottom: BL, BR.
    let involved = |which: usize| -> [usize; 2] {
        match which {
            0 => [0, 2],
            1 => [1, 3],
            2 => [0, 1],
            _ => [2, 3],
        }
    };
    // Distinct colours' corner samples (and the two ends of one strip) must not overlap, or the
    // set would repeat one patch at every corner.
    let apart = |a: (usize, usize), b: (usize, usize)| a.0.abs_diff(b.0) >= h || a.1.abs_diff(b.1) >= h;
    let ok = |c: &Corners| {
        let all: Vec<(usize, usize)> = c.hl.iter().chain(&c.hr).chain(&c.vt).chain(&c.vb).copied().collect();
        (0..all.len()).all(|i| (i + 1..all.len()).all(|j| apart(all[i], all[j])))
    };
    let mut cache = cut_all(&c);
    let mut cuts = cache.len();
    let mut cur_ok = ok(&c);
    for round in 0..3u64 {
        for which in 0..4 {
            for k in 0..colors {
                monitor.check()?;
                let base = mix(opts.seed ^ ((which * 16 + k) as u64) ^ (round << 40));
                let cands: Vec<(usize, usize)> = (0..opts.corner_candidates)
                    .map(|i| {
                        let mut r = Rng::new(mix(base ^ i as u64));
                        if which < 2 {
                            pos_h(&mut r)
                        } else {
                            pos_v(&mut r)
                        }
                    })
                    .collect();
                let keys: Vec<(usize, usize, usize)> = involved(which)
                    .iter()
                    .flat_map(|&qi| (0..colors).map(move |o| if which < 2 { (qi, k, o) } else { (qi, o, k) }))
                    .collect();
                let current: f64 = keys.iter().map(|&(qi, hc, vc)| cache[key(qi, hc, vc)]).sum();
                let scored: Vec<Scored> = cands
                    .par_iter()
                    .map(|&p| {
                        let mut t = c.clone();
                        set(&mut t, which, k, p);
                        let v: Vec<f64> = keys
                            .iter()
                            .map(|&(qi, hc, vc)| quadrant_cut(&g, &sm, QUADRANTS[qi], &t, hc, vc).0)
                            .collect();
                        (v.iter().sum(), ok(&t), p, v)
                    })
                    .collect();
                cuts += scored.len() * keys.len();
                let mut best = current;
                for (e, good, p, v) in scored {
                    // Prefer configurations whose samples are apart, then lower cost.
                    if (good && !cur_ok) || (good == cur_ok && e < best) {
                        best = e;
                        cur_ok = good;
                        set(&mut c, which, k, p);
                        for (&(qi, hc, vc), x) in keys.iter().zip(v) {
                            cache[key(qi, hc, vc)] = x;
                        }
                    }
                }
            }
        }
    }
    // The cuts the frames will use, on the full features.
    let mut quad_cut = vec![Vec::new(); 4 * colors * colors];
    let mut best = 0.0;
    for (qi, q) in QUADRANTS.iter().enumerate() {
        for hc in 0..colors {
            for vc in 0..colors {
                let (e, labels) = quadrant_cut(&g, &s, *q, &c, hc, vc);
                best += e;
                quad_cut[key(qi, hc, vc)] = labels;
            }
        }
    }
    monitor.advance(1);
    steps.push(StepReport {
        step: "corner sampling".into(),
        seconds: t0.elapsed().as_secs_f64(),
        work: cuts,
        seam_total: best / scale,
        seam_max: f64::NAN,
        seam_mean: best / scale / (4 * colors * colors * half * half) as f64,
        converged: if cur_ok { "samples apart".into() } else { "samples overlap (sample too small)".into() },
    });
    // --- 2. Edge synthesis ----------------------------------------------------------------
    let t1 = Instant::now();
    let strips: Vec<(Canvas, FillStats)> = (0..2 * colors)
        .into_par_iter()
        .map(|k| -> Result<(Canvas, FillStats)> {
            let horizontal = k < colors;
            let col = k % colors;
            let mut canvas = if horizontal { Canvas::new(h, w) } else { Canvas::new(w, h) };
            for y in 0..canvas.height {
                for x in 0..canvas.width {
                    let i = y * canvas.width + x;
                    let t = if horizontal {
                        if x < half {
                            Some(g.texel(c.hl[col], y, x))
                        } else if x >= w - half {
                            Some(g.texel(c.hr[col], y, x - (w - half)))
                        } else {
                            None
                        }
                    } else if y < half {
                        Some(g.texel(c.vt[col], y, x))
                    } else if y >= w - half {
                        Some(g.texel(c.vb[col], y - (w - half), x))
                    } else {
                        None
                    };
                    if let Some(t) = t {
                        canvas.src[i] = t;
                        // Only the outer `keep` texels at each end are held: the fill's patches
                        // overlap the rest, so its cuts weave through them instead of leaving a
                        // straight seam where the corner sample ends.
                        let from_end = if horizontal { x.min(w - 1 - x) } else { y.min(w - 1 - y) };
                        canvas.fixed[i] = from_end < keep;
                    }
                }
            }
            let mut r = Rng::new(mix(opts.seed ^ 0xed9e ^ ((k as u64) << 20)));
            let st = fill(&mut canvas, &s, &fopts, scale, &mut r, monitor)?;
            monitor.advance(1);
            Ok((canvas, st))
        })
        .collect::<Result<Vec<_>>>()?;
    steps.push(fill_step("edge synthesis", t1, strips.iter().map(|x| &x.1)));

    // --- 3. Frame construction ------------------------------------------------------------
    let t2 = Instant::now();
    let frames: Vec<Canvas> = (0..n_tiles)
        .map(|id| {
            let [n, e, so, we] = tile_code(id, colors).map(|v| v as usize);
            let (hn, hs) = (&strips[n].0, &strips[so].0);
            let (ve, vw) = (&strips[colors + e].0, &strips[colors + we].0);
            let mut canvas = Canvas::new(w, w);
            for y in 0..w {
                for x in 0..w {
                    let top = y < half;
                    let bottom = y >= w - half;
                    let left = x < half;
                    let right = x >= w - half;
                    let from_h = |strip: &Canvas, sy: usize| strip.src[sy * w + x];
                    let from_v = |strip: &Canvas, sx: usize| strip.src[y * h + sx];
                    let t = match (top, bottom, left, right) {
                        (true, _, true, _) | (true, _, _, true) | (_, true, true, _) | (_, true, _, true) => {
                            let (q, qy, qx, hc, vc) = match (top, left) {
                                (true, true) => (0usize, y, x, n, we),
                                (true, false) => (1, y, x - (w - half), n, e),
                                (false, true) => (2, y - (w - half), x, so, we),
                                (false, false) => (3, y - (w - half), x - (w - half), so, e),
                            };
                            let takes_h = quad_cut[(q * colors + hc) * colors + vc][qy * half + qx];
                            match (takes_h, top, left) {
                                (true, true, _) => from_h(hn, y + half),
                                (true, false, _) => from_h(hs, y - (w - half)),
                                (false, _, true) => from_v(vw, x + half),
                                (false, _, false) => from_v(ve, x - (w - half)),
                            }
                        }
                        _ if top => from_h(hn, y + half),
                        _ if bottom => from_h(hs, y - (w - half)),
                        _ if left => from_v(vw, x + half),
                        _ if right => from_v(ve, x - (w - half)),
                        _ => EMPTY,
                    };
                    if t != EMPTY {
                        canvas.src[y * w + x] = t;
                        // The texels next to the tile boundary are what the neighbour continues:
                        // held. The inner part of the band is the interior fill's overlap, so
                        // the frame-interior seam is a cut, not a straight line.
                        let from_border = y.min(x).min(w - 1 - y).min(w - 1 - x);
                        canvas.fixed[y * w + x] = from_border < keep;
                    }
                }
            }
            canvas
        })
        .collect();
    {
        let totals: Vec<f64> = frames.iter().map(|f| f.seam_total(&s) / scale).collect();
        let errs: Vec<f64> = frames
            .iter()
            .flat_map(|f| f.pixel_errors(&s).into_iter().filter(|e| e.is_finite()).collect::<Vec<_>>())
            .collect();
        steps.push(StepReport {
            step: "frame construction".into(),
            seconds: t2.elapsed().as_secs_f64(),
            work: n_tiles,
            seam_total: totals.iter().sum(),
            seam_max: errs.iter().copied().fold(0.0, f64::max) / scale,
            seam_mean: errs.iter().sum::<f64>() / errs.len().max(1) as f64 / scale,
            converged: format!("{n_tiles} frames"),
        });
    }

    // --- 4. Interior synthesis ------------------------------------------------------------
    let t3 = Instant::now();
    let tiles: Vec<(Canvas, FillStats)> = frames
        .into_par_iter()
        .enumerate()
        .map(|(id, mut canvas)| -> Result<(Canvas, FillStats)> {
            let mut r = Rng::new(mix(opts.seed ^ 0x1a7e ^ ((id as u64) << 24)));
            let st = fill(&mut canvas, &s, &fopts, scale, &mut r, monitor)?;
            monitor.advance(1);
            Ok((canvas, st))
        })
        .collect::<Result<Vec<_>>>()?;
    steps.push(fill_step("interior synthesis", t3, tiles.iter().map(|x| &x.1)));

    Ok(WangTiles {
        tile: w,
        edge_height: h,
        colors,
        sample_dims: (sample.height, sample.width),
        codes: (0..n_tiles).map(|i| tile_code(i, colors)).collect(),
        texels: tiles.into_iter().map(|(c, _)| c.src).collect(),
        steps,
        pair_scale: scale,
        matching_variance,
    })
}

/// A corner-sample candidate: summed cut cost, whether the samples stay apart, its position,
/// the cut costs it changes.
type Scored = (f64, bool, (usize, usize), Vec<f64>);

fn set(c: &mut Corners, which: usize, k: usize, p: (usize, usize)) {
    match which {
        0 => c.hl[k] = p,
        1 => c.hr[k] = p,
        2 => c.vt[k] = p,
        _ => c.vb[k] = p,
    }
}

fn fill_step<'a>(name: &str, t: Instant, stats: impl Iterator<Item = &'a FillStats>) -> StepReport {
    let stats: Vec<&FillStats> = stats.collect();
    StepReport {
        step: name.into(),
        seconds: t.elapsed().as_secs_f64(),
        work: stats.iter().map(|s| s.fill_patches + s.refined + s.rejected).sum(),
        seam_total: stats.iter().map(|s| s.seam_total).sum(),
        seam_max: stats.iter().map(|s| s.seam_max).fold(0.0, f64::max),
        seam_mean: stats.iter().map(|s| s.seam_mean).sum::<f64>() / stats.len().max(1) as f64,
        converged: format!("{}/{}", stats.iter().filter(|s| s.converged).count(), stats.len()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tile_ids_round_trip() {
        for colors in 2usize..5 {
            for id in 0..colors.pow(4) {
                assert_eq!(tile_id(tile_code(id, colors), colors), id);
            }
        }
        assert_eq!(tile_code(1, 2), [0, 0, 0, 1]);
    }
}
