//! Graph-cut patch filling (Kwatra et al. 2003, "Graphcut Textures", as paper 002 section 3.2
//! uses it for its edge and interior synthesis).
//!
//! A [`Canvas`] is a grid of *labels*: each pixel holds the sample texel it copies (or nothing
//! yet). A patch is the sample translated by an offset; placing it over the canvas, a minimum
//! cut decides which pixels take the patch and which keep their texel. The cost of a seam
//! between neighbours `p`, `q` labelled `A` and `B` is Kwatra's
//! `M = |A(p) - B(p)|^2 + |A(q) - B(q)|^2`, where `A(q)` is the texel label `A` would put at `q`
//! (its sample position shifted by `q - p`) and `|.|^2` the squared feature distance of
//! [`crate::features`]. Neighbours copying adjacent sample texels are no seam (cost 0).
//!
//! * **Old seams** are kept: a seam already in the canvas enters the cut through a seam node
//!   (Kwatra, section 3.2), so a new patch can remove or replace it; their costs need no table
//!   because a seam's cost is a function of the two labels, recomputed from the canvas.
//! * **Per-pixel error**: half the cost of each seam through a pixel's four edges; all errors
//!   start at infinity (empty pixels), as the paper says.
//! * **Acceptance**: a patch that covers empty pixels is always taken; a refinement patch
//!   (placed over the pixel of largest error) only if the seam cost of the region it touches
//!   goes down.
//! * **Stopping**: when the canvas is full and both the mean and the largest per-pixel error
//!   are below their thresholds, after a number of rejected refinements in a row, or at the
//!   patch budget.
//! * **Placement**: the patch position follows the first empty pixel in scan order (then the
//!   worst pixel); its sample offset is chosen by the matching cost (sum of squared differences
//!   over the overlap, PCA-reduced features) over a grid of candidate offsets refined locally,
//!   one of the `best_of` cheapest taken at random (seeded), so the fill neither copies the
//!   sample verbatim nor picks blindly.

use crate::features::{dist2, FeatureOps, Features};
use btfrs_core::rng::Rng;
use btfrs_core::{Monitor, Result};
use btfrs_graphcut::Graph;

/// No texel yet.
pub const EMPTY: u32 = u32::MAX;

/// The sample a fill copies from: full features for cut costs, reduced ones for matching.
#[derive(Debug, Clone, Copy)]
pub struct Sample<'a> {
    /// Features the seam costs are computed with.
    pub full: &'a Features,
    /// Features the candidate offsets are matched with (same size, fewer dimensions).
    pub matching: &'a Features,
}

impl Sample<'_> {
    fn h(&self) -> i64 {
        self.full.height as i64
    }
    fn w(&self) -> i64 {
        self.full.width as i64
    }
    /// The texel `label` puts at a pixel displaced by (dy, dx) from where it sits, if in the sample.
    #[inline]
    fn shifted(&self, label: u32, dy: i64, dx: i64) -> Option<u32> {
        let (y, x) = ((label as i64) / self.w() + dy, (label as i64) % self.w() + dx);
        (y >= 0 && x >= 0 && y < self.h() && x < self.w()).then(|| (y * self.w() + x) as u32)
    }
    /// Kwatra's seam cost between `a` at p and `b` at q = p + (dy, dx).
    #[inline]
    pub fn seam(&self, a: u32, b: u32, dy: i64, dx: i64) -> f64 {
        let a_at_q = self.shifted(a, dy, dx);
        if a_at_q == Some(b) {
            return 0.0;
        }
        let b_at_p = self.shifted(b, -dy, -dx);
        let f = |t: u32| self.full.at(t as usize);
        match (b_at_p, a_at_q) {
            (Some(bp), Some(aq)) => dist2(f(a), f(bp)) + dist2(f(aq), f(b)),
            (Some(bp), None) => 2.0 * dist2(f(a), f(bp)),
            (None, Some(aq)) => 2.0 * dist2(f(aq), f(b)),
            (None, None) => 2.0 * dist2(f(a), f(b)),
        }
    }
}

/// A grid of labels under construction.
#[derive(Debug, Clone)]
pub struct Canvas {
    /// Rows.
    pub height: usize,
    /// Columns.
    pub width: usize,
    /// Per pixel, the sample texel it copies, or [`EMPTY`].
    pub src: Vec<u32>,
    /// Pixels no patch may change (corner samples, the tile frame).
    pub fixed: Vec<bool>,
}

impl Canvas {
    /// An empty canvas.
    pub fn new(height: usize, width: usize) -> Self {
        Canvas { height, width, src: vec![EMPTY; height * width], fixed: vec![false; height * width] }
    }

    /// The sum of all seam costs (each edge once).
    pub fn seam_total(&self, s: &Sample<'_>) -> f64 {
        let mut e = 0.0;
        for y in 0..self.height {
            for x in 0..self.width {
                e += self.edge_cost(s, y, x, 0, 1) + self.edge_cost(s, y, x, 1, 0);
            }
        }
        e
    }

    /// Per-pixel error: half of each seam through the pixel; infinite for empty pixels.
    pub fn pixel_errors(&self, s: &Sample<'_>) -> Vec<f64> {
        let mut err = vec![0.0f64; self.height * self.width];
        for y in 0..self.height {
            for x in 0..self.width {
                let i = y * self.width + x;
                if self.src[i] == EMPTY {
                    err[i] = f64::INFINITY;
                    continue;
                }
                for (dy, dx) in [(0, 1), (1, 0)] {
                    let c = self.edge_cost(s, y, x, dy, dx);
                    if c > 0.0 {
                        err[i] += 0.5 * c;
                        err[(y + dy) * self.width + x + dx] += 0.5 * c;
                    }
                }
            }
        }
        err
    }

    /// Seam cost of the edge from (y, x) to (y + dy, x + dx) (0 if either is empty or outside).
    fn edge_cost(&self, s: &Sample<'_>, y: usize, x: usize, dy: usize, dx: usize) -> f64 {
        let (qy, qx) = (y + dy, x + dx);
        if qy >= self.height || qx >= self.width {
            return 0.0;
        }
        let (a, b) = (self.src[y * self.width + x], self.src[qy * self.width + qx]);
        if a == EMPTY || b == EMPTY {
            return 0.0;
        }
        s.seam(a, b, dy as i64, dx as i64)
    }
}

/// The seam cost of every edge of a canvas (to the right and downwards neighbour), kept up to
/// date patch by patch, so a refinement step reads the per-pixel errors without recomputing
/// every seam (each costs four feature distances: hundreds of coefficients for an SH model).
#[derive(Debug, Clone)]
struct EdgeCosts {
    right: Vec<f64>,
    down: Vec<f64>,
}

impl EdgeCosts {
    fn new(c: &Canvas, s: &Sample<'_>) -> Self {
        let mut e = EdgeCosts { right: vec![0.0; c.src.len()], down: vec![0.0; c.src.len()] };
        e.update(c, s, &Rect { y0: 0, x0: 0, h: c.height, w: c.width });
        e
    }

    /// Recompute the edges with an end in `r`.
    fn update(&mut self, c: &Canvas, s: &Sample<'_>, r: &Rect) {
        let (y0, x0) = (r.y0.saturating_sub(1), r.x0.saturating_sub(1));
        for y in y0..(r.y0 + r.h).min(c.height) {
            for x in x0..(r.x0 + r.w).min(c.width) {
                let i = y * c.width + x;
                self.right[i] = c.edge_cost(s, y, x, 0, 1);
                self.down[i] = c.edge_cost(s, y, x, 1, 0);
            }
        }
    }

    fn pixel_errors(&self, c: &Canvas) -> Vec<f64> {
        let mut err = vec![0.0f64; c.src.len()];
        for y in 0..c.height {
            for x in 0..c.width {
                let i = y * c.width + x;
                if c.src[i] == EMPTY {
                    err[i] = f64::INFINITY;
                    continue;
                }
                let (r, d) = (self.right[i], self.down[i]);
                if r > 0.0 {
                    err[i] += 0.5 * r;
                    err[i + 1] += 0.5 * r;
                }
                if d > 0.0 {
                    err[i] += 0.5 * d;
                    err[i + c.width] += 0.5 * d;
                }
            }
        }
        err
    }

    fn edge(&self, c: &Canvas, (py, px): (usize, usize), (qy, _): (usize, usize)) -> f64 {
        let i = py * c.width + px;
        if qy > py {
            self.down[i]
        } else {
            self.right[i]
        }
    }
}

/// How a fill proceeds. Thresholds are in units of the sample's mean squared distance between
/// random texel pairs ([`Features::pair_scale`]), i.e. 1.0 is the seam cost of unrelated texels.
#[derive(Debug, Clone)]
pub struct FillOptions {
    /// Patch side in pixels.
    pub patch: usize,
    /// Candidate sample offsets evaluated per placement (on a grid, then refined locally).
    pub candidates: usize,
    /// One of the cheapest this many candidates is taken (at random).
    pub best_of: usize,
    /// Stop when no pixel's error exceeds this (relative units) ...
    pub pixel_threshold: f64,
    /// ... and the mean per-pixel error is below this (relative units).
    pub total_threshold: f64,
    /// Refinement patches tried after the canvas is full (at most).
    pub refine: usize,
    /// Stop refining after this many rejections in a row.
    pub max_rejects: usize,
}

impl Default for FillOptions {
    fn default() -> Self {
        FillOptions {
            patch: 32,
            candidates: 1024,
            best_of: 3,
            pixel_threshold: 0.3,
            total_threshold: 0.02,
            refine: 24,
            max_rejects: 6,
        }
    }
}

/// What a fill did.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct FillStats {
    /// Patches placed over empty pixels.
    pub fill_patches: usize,
    /// Refinement patches accepted / rejected.
    pub refined: usize,
    /// Refinement patches rejected (they did not lower the seam cost).
    pub rejected: usize,
    /// Sum of the seam costs left, relative units.
    pub seam_total: f64,
    /// Mean per-pixel error over the filled region, relative units.
    pub seam_mean: f64,
    /// Largest per-pixel error, relative units.
    pub seam_max: f64,
    /// Whether both thresholds were met.
    pub converged: bool,
}

/// Fill every empty pixel of `canvas` from `sample`, then refine (see the module docs).
pub fn fill(
    canvas: &mut Canvas,
    sample: &Sample<'_>,
    opts: &FillOptions,
    scale: f64,
    rng: &mut Rng,
    monitor: &Monitor,
) -> Result<FillStats> {
    let mut stats = FillStats::default();
    let p = opts.patch.min(sample.full.height).min(sample.full.width).max(2);
    let region: Vec<usize> = (0..canvas.src.len()).filter(|&i| !canvas.fixed[i]).collect();
    // First pass: patches over the first empty pixel, overlapping what is above and left of it.
    let overlap = (p / 3).max(1) as i64;
    while let Some(i) = (0..canvas.src.len()).find(|&i| canvas.src[i] == EMPTY && !canvas.fixed[i]) {
        monitor.check()?;
        let (y, x) = ((i / canvas.width) as i64, (i % canvas.width) as i64);
        let r = Rect::clipped(y - overlap, x - overlap, p, canvas);
        let offset = choose_offset(canvas, sample, &r, opts, rng, None);
        place(canvas, sample, &r, offset, true, None);
        stats.fill_patches += 1;
    }
    // Refinement: a patch over the worst pixel, kept only if it lowers the seam cost.
    let mut rejects = 0;
    let mut costs = EdgeCosts::new(canvas, sample);
    for _ in 0..opts.refine {
        monitor.check()?;
        let err = costs.pixel_errors(canvas);
        let (worst, mean) = region_error(&err, &region);
        if worst / scale <= opts.pixel_threshold && mean / scale <= opts.total_threshold {
            break;
        }
        if rejects >= opts.max_rejects {
            break;
        }
        let i = region.iter().copied().max_by(|&a, &b| err[a].total_cmp(&err[b])).unwrap_or(0);
        let (y, x) = ((i / canvas.width) as i64, (i % canvas.width) as i64);
        let half = (p / 2) as i64;
        let r = Rect::clipped(y - half, x - half, p, canvas);
        let current = canvas.src[i];
        let offset = choose_offset(canvas, sample, &r, opts, rng, Some((i, current)));
        if place(canvas, sample, &r, offset, false, Some(&costs)) {
            costs.update(canvas, sample, &r);
            stats.refined += 1;
            rejects = 0;
        } else {
            stats.rejected += 1;
            rejects += 1;
        }
    }
    let err = costs.pixel_errors(canvas);
    let (worst, mean) = region_error(&err, &region);
    stats.seam_total = (costs.right.iter().sum::<f64>() + costs.down.iter().sum::<f64>()) / scale;
    stats.seam_mean = mean / scale;
    stats.seam_max = worst / scale;
    stats.converged = stats.seam_max <= opts.pixel_threshold && stats.seam_mean <= opts.total_threshold;
    Ok(stats)
}

fn region_error(err: &[f64], region: &[usize]) -> (f64, f64) {
    if region.is_empty() {
        return (0.0, 0.0);
    }
    let worst = region.iter().map(|&i| err[i]).fold(0.0, f64::max);
    let mean = region.iter().map(|&i| err[i]).sum::<f64>() / region.len() as f64;
    (worst, mean)
}

/// A patch rectangle on the canvas (clipped to it).
#[derive(Debug, Clone, Copy)]
struct Rect {
    y0: usize,
    x0: usize,
    h: usize,
    w: usize,
}

impl Rect {
    fn clipped(y: i64, x: i64, p: usize, c: &Canvas) -> Rect {
        let y0 = y.clamp(0, (c.height as i64 - p as i64).max(0)) as usize;
        let x0 = x.clamp(0, (c.width as i64 - p as i64).max(0)) as usize;
        Rect { y0, x0, h: p.min(c.height - y0), w: p.min(c.width - x0) }
    }
}

/// The sample texel an offset (oy, ox) puts at canvas pixel (y, x): offsets are sample
/// positions of the patch's top-left pixel.
#[inline]
fn patch_texel(s: &Sample<'_>, r: &Rect, off: (usize, usize), y: usize, x: usize) -> u32 {
    ((off.0 + y - r.y0) * s.full.width + off.1 + x - r.x0) as u32
}

/// Matching cost of offset `off`: squared differences over the overlap (filled pixels of the
/// rectangle), on the reduced features, every `step`-th pixel.
fn match_cost(c: &Canvas, s: &Sample<'_>, r: &Rect, off: (usize, usize), step: usize) -> f64 {
    let m = s.matching;
    let mut e = 0.0;
    let mut y = r.y0;
    while y < r.y0 + r.h {
        let mut x = r.x0;
        while x < r.x0 + r.w {
            let t = c.src[y * c.width + x];
            if t != EMPTY {
                e += dist2(m.at(t as usize), m.at(patch_texel(s, r, off, y, x) as usize));
            }
            x += step;
        }
        y += step;
    }
    e
}

fn choose_offset(
    c: &Canvas,
    s: &Sample<'_>,
    r: &Rect,
    opts: &FillOptions,
    rng: &mut Rng,
    avoid: Option<(usize, u32)>,
) -> (usize, usize) {
    let (ny, nx) = (s.full.height - r.h + 1, s.full.width - r.w + 1);
    let filled = (0..r.h)
        .flat_map(|y| (0..r.w).map(move |x| (y, x)))
        .filter(|&(y, x)| c.src[(r.y0 + y) * c.width + r.x0 + x] != EMPTY)
        .count();
    if filled == 0 {
        return (rng.below(ny), rng.below(nx));
    }
    let step = if filled > 256 { 2 } else { 1 };
    // The offset that would reproduce the current texel at the worst pixel changes nothing.
    let same = |off: (usize, usize)| {
        avoid.is_some_and(|(i, t)| {
            let (y, x) = (i / c.width, i % c.width);
            patch_texel(s, r, off, y, x) == t
        })
    };
    let stride = (((ny * nx) as f64 / opts.candidates.max(1) as f64).sqrt().floor() as usize).max(1);
    let (jy, jx) = (rng.below(stride), rng.below(stride));
    let mut scored: Vec<(f64, (usize, usize))> = Vec::new();
    for oy in (jy.min(ny - 1)..ny).step_by(stride) {
        for ox in (jx.min(nx - 1)..nx).step_by(stride) {
            if !same((oy, ox)) {
                scored.push((match_cost(c, s, r, (oy, ox), step), (oy, ox)));
            }
        }
    }
    scored.sort_by(|a, b| a.0.total_cmp(&b.0));
    // Local refinement of the best few around their grid points.
    let keep = (opts.best_of * 2).max(4).min(scored.len());
    let mut refined: Vec<(f64, (usize, usize))> = Vec::new();
    if stride > 1 {
        let rad = stride as i64 / 2;
        for &(_, (oy, ox)) in &scored[..keep] {
            let mut best = (f64::INFINITY, (oy, ox));
            for dy in -rad..=rad {
                for dx in -rad..=rad {
                    let (y, x) = (oy as i64 + dy, ox as i64 + dx);
                    if y < 0 || x < 0 || y >= ny as i64 || x >= nx as i64 || same((y as usize, x as usize)) {
                        continue;
                    }
                    let e = match_cost(c, s, r, (y as usize, x as usize), step);
                    if e < best.0 {
                        best = (e, (y as usize, x as usize));
                    }
                }
            }
            refined.push(best);
        }
        refined.sort_by(|a, b| a.0.total_cmp(&b.0));
        refined.dedup_by(|a, b| a.1 == b.1);
    } else {
        refined = scored;
    }
    if refined.is_empty() {
        return (rng.below(ny), rng.below(nx));
    }
    let k = opts.best_of.clamp(1, refined.len());
    refined[rng.below(k)].1
}

/// Where a pixel of the rectangle stands for the cut.
#[derive(Clone, Copy, PartialEq)]
enum Role {
    /// Keeps its texel (fixed, or outside the rectangle and filled).
    Old,
    /// Takes the patch (empty, inside the rectangle).
    New,
    /// Decided by the cut (graph node id).
    Node(usize),
    /// No texel and not covered: no seam with it.
    Nothing,
}

/// Place the patch at `off` over `r` with a minimum cut; returns whether it was applied.
/// `force`: apply even if the seam cost of the region goes up (first pass: empty pixels).
/// `costs`: the canvas's current edge costs (refinement), for the seam cost before the patch.
fn place(
    c: &mut Canvas,
    s: &Sample<'_>,
    r: &Rect,
    off: (usize, usize),
    force: bool,
    costs: Option<&EdgeCosts>,
) -> bool {
    let idx = |y: usize, x: usize| y * c.width + x;
    let inside = |y: usize, x: usize| y >= r.y0 && y < r.y0 + r.h && x >= r.x0 && x < r.x0 + r.w;
    let mut node_of = vec![usize::MAX; r.h * r.w];
    let mut pixels = Vec::new();
    for y in r.y0..r.y0 + r.h {
        for x in r.x0..r.x0 + r.w {
            let i = idx(y, x);
            if c.src[i] != EMPTY && !c.fixed[i] {
                node_of[(y - r.y0) * r.w + x - r.x0] = pixels.len();
                pixels.push((y, x));
            }
        }
    }
    let role = |y: i64, x: i64| -> Role {
        if y < 0 || x < 0 || y >= c.height as i64 || x >= c.width as i64 {
            return Role::Nothing;
        }
        let (y, x) = (y as usize, x as usize);
        let i = idx(y, x);
        if inside(y, x) {
            if c.fixed[i] {
                Role::Old
            } else if c.src[i] == EMPTY {
                Role::New
            } else {
                Role::Node(node_of[(y - r.y0) * r.w + x - r.x0])
            }
        } else if c.src[i] == EMPTY {
            Role::Nothing
        } else {
            Role::Old
        }
    };
    let new_at = |y: usize, x: usize| patch_texel(s, r, off, y, x);
    // Label value at a pixel for a role decision: old texel or patch texel. The patch texel
    // exists for pixels in the rectangle; outside it, the patch's extension (if in the sample).
    let patch_ext = |y: usize, x: usize| -> Option<u32> {
        let (sy, sx) = (off.0 as i64 + y as i64 - r.y0 as i64, off.1 as i64 + x as i64 - r.x0 as i64);
        (sy >= 0 && sx >= 0 && sy < s.h() && sx < s.w()).then(|| (sy * s.w() + sx) as u32)
    };

    let mut g: Graph<f64> = Graph::with_capacity(pixels.len(), pixels.len() * 3);
    let mut constant = 0.0f64;
    // Every edge with at least one end in the rectangle, once: right and down neighbours of
    // rectangle pixels, plus the left / up edges that enter it from outside.
    let mut edges: Vec<((usize, usize), (usize, usize))> = Vec::new();
    for y in r.y0..r.y0 + r.h {
        for x in r.x0..r.x0 + r.w {
            if x + 1 < c.width {
                edges.push(((y, x), (y, x + 1)));
            }
            if y + 1 < c.height {
                edges.push(((y, x), (y + 1, x)));
            }
            if x == r.x0 && x > 0 {
                edges.push(((y, x - 1), (y, x)));
            }
            if y == r.y0 && y > 0 {
                edges.push(((y - 1, x), (y, x)));
            }
        }
    }
    let mut old_energy = 0.0f64;
    for &((py, px), (qy, qx)) in &edges {
        let (dy, dx) = ((qy - py) as i64, (qx - px) as i64);
        let (rp, rq) = (role(py as i64, px as i64), role(qy as i64, qx as i64));
        if rp == Role::Nothing || rq == Role::Nothing {
            continue;
        }
        let (op, oq) = (c.src[idx(py, px)], c.src[idx(qy, qx)]);
        if let Some(k) = costs {
            old_energy += k.edge(c, (py, px), (qy, qx));
        }
        // The patch's texel at a pixel: inside the rectangle always; outside, its extension.
        let np = if inside(py, px) { Some(new_at(py, px)) } else { patch_ext(py, px) };
        let nq = if inside(qy, qx) { Some(new_at(qy, qx)) } else { patch_ext(qy, qx) };
        // Seam costs for (p label, q label), labels as texels; a pixel outside the rectangle
        // can only keep its texel, so its New case never arises.
        let cost = |a: Option<u32>, b: Option<u32>| match (a, b) {
            (Some(a), Some(b)) => s.seam(a, b, dy, dx),
            _ => 0.0,
        };
        let (p_old, p_new) = (Some(op).filter(|&t| t != EMPTY), np);
        let (q_old, q_new) = (Some(oq).filter(|&t| t != EMPTY), nq);
        match (rp, rq) {
            (Role::Node(a), Role::Node(b)) => {
                let e_ab = cost(p_old, q_new); // p keeps, q takes the patch
                let e_ba = cost(p_new, q_old);
                let e_aa = cost(p_old, q_old);
                if e_aa > 0.0 {
                    // Kwatra's seam node: an old seam between p and q can be removed by the
                    // patch (both new: cost 0) or kept (both old: its cost), or replaced.
                    let sigma = g.add_node();
                    let _ = g.add_edge(a, sigma, e_ab, e_ab);
                    let _ = g.add_edge(sigma, b, e_ba, e_ba);
                    let _ = g.add_terminal(sigma, 0.0, e_aa);
                } else {
                    let _ = g.add_edge(a, b, e_ab, e_ba);
                }
            }
            (Role::Node(a), Role::Old) => {
                let _ = g.add_terminal(a, cost(p_new, q_old), cost(p_old, q_old));
            }
            (Role::Old, Role::Node(b)) => {
                let _ = g.add_terminal(b, cost(p_old, q_new), cost(p_old, q_old));
            }
            (Role::Node(a), Role::New) => {
                let _ = g.add_terminal(a, 0.0, cost(p_old, q_new));
            }
            (Role::New, Role::Node(b)) => {
                let _ = g.add_terminal(b, 0.0, cost(p_new, q_old));
            }
            (Role::Old, Role::New) => constant += cost(p_old, q_new),
            (Role::New, Role::Old) => constant += cost(p_new, q_old),
            (Role::Old, Role::Old) => constant += cost(p_old, q_old),
            (Role::New, Role::New) => {}
            _ => {}
        }
    }
    let has_empty =
        (r.y0..r.y0 + r.h).any(|y| (r.x0..r.x0 + r.w).any(|x| c.src[idx(y, x)] == EMPTY && !c.fixed[idx(y, x)]));
    let flow = if pixels.is_empty() { 0.0 } else { g.maxflow() };
    let new_energy = flow + constant;
    if !(force || has_empty || costs.is_none()) && new_energy >= old_energy * (1.0 - 1e-9) {
        return false;
    }
    // Source side keeps the old texel; sink side and empty pixels take the patch.
    for (k, &(y, x)) in pixels.iter().enumerate() {
        if !g.is_source_side(k) {
            c.src[idx(y, x)] = new_at(y, x);
        }
    }
    for y in r.y0..r.y0 + r.h {
        for x in r.x0..r.x0 + r.w {
            let i = idx(y, x);
            if c.src[i] == EMPTY && !c.fixed[i] {
                c.src[i] = new_at(y, x);
            }
        }
    }
    true
}

#[cfg(test)]
#[allow(clippy::needless_range_loop)] // index loops mirror the set-ups being checked
mod tests {
    use super::*;

    fn noise(h: usize, w: usize, seed: u64) -> Features {
        let mut rng = Rng::new(seed);
        let data = (0..h * w * 3).map(|_| rng.next_f64() as f32).collect();
        Features::new(h, w, 3, data).unwrap()
    }

    #[test]
    fn seam_cost_is_kwatras_and_zero_for_adjacent_texels() {
        let f = noise(8, 8, 1);
        let s = Sample { full: &f, matching: &f };
        // Adjacent sample texels: no seam.
        assert_eq!(s.seam(9, 10, 0, 1), 0.0);
        assert_eq!(s.seam(9, 17, 1, 0), 0.0);
        // Otherwise |A(p) - B(p)|^2 + |A(q) - B(q)|^2 with A(q) = a + 1, B(p) = b - 1.
        let (a, b) = (9u32, 30u32);
        let want = dist2(f.at(9), f.at(29)) + dist2(f.at(10), f.at(30));
        assert!((s.seam(a, b, 0, 1) - want).abs() < 1e-12);
    }

    #[test]
    fn filling_a_periodic_sample_finds_seamless_cuts() {
        // A sample that repeats with period 6 in both directions: every seam can be hidden
        // exactly, so after the fill the seam cost must be (near) zero, while a canvas built
        // from random texels costs about 1 per edge.
        let (h, w, per) = (48, 48, 6);
        let mut rng = Rng::new(3);
        let cell: Vec<f32> = (0..per * per * 3).map(|_| rng.next_f64() as f32).collect();
        let mut data = vec![0.0f32; h * w * 3];
        for y in 0..h {
            for x in 0..w {
                let k = ((y % per) * per + x % per) * 3;
                data[(y * w + x) * 3..(y * w + x) * 3 + 3].copy_from_slice(&cell[k..k + 3]);
            }
        }
        let f = Features::new(h, w, 3, data).unwrap();
        let s = Sample { full: &f, matching: &f };
        let mut c = Canvas::new(40, 40);
        let opts = FillOptions { patch: 16, candidates: 4096, best_of: 1, ..Default::default() };
        let scale = f.pair_scale(0);
        let st = fill(&mut c, &s, &opts, scale, &mut Rng::new(7), &Monitor::new()).unwrap();
        assert!(c.src.iter().all(|&t| t != EMPTY));
        assert!(st.seam_total < 1e-9, "{st:?}");
        // Control: random labels.
        let mut r = Canvas::new(40, 40);
        r.src.iter_mut().for_each(|t| *t = rng.below(h * w) as u32);
        assert!(r.seam_total(&s) / scale > 1000.0);
    }

    #[test]
    fn fixed_pixels_are_kept_and_the_cut_beats_no_cut() {
        // Canvas with fixed left and right ends from unrelated places of a noise sample; the
        // middle is filled; fixed pixels must be untouched, and the graph cut's seams must cost
        // less than pasting the patches without a cut would (a straight seam at each end).
        let f = noise(64, 64, 5);
        let s = Sample { full: &f, matching: &f };
        let mut c = Canvas::new(16, 64);
        for y in 0..16 {
            for x in 0..8 {
                c.src[y * 64 + x] = (y * 64 + x + 3) as u32;
                c.fixed[y * 64 + x] = true;
                c.src[y * 64 + 56 + x] = ((y + 40) * 64 + x + 20) as u32;
                c.fixed[y * 64 + 56 + x] = true;
            }
        }
        let before: Vec<u32> = c.src.clone();
        let scale = f.pair_scale(0);
        let st = fill(
            &mut c,
            &s,
            &FillOptions { patch: 16, ..Default::default() },
            scale,
            &mut Rng::new(1),
            &Monitor::new(),
        )
        .unwrap();
        for i in 0..c.src.len() {
            if c.fixed[i] {
                assert_eq!(c.src[i], before[i]);
            }
        }
        assert!(st.fill_patches >= 4);
        // On white noise every seam edge costs ~2 relative units; the fill must not be worse
        // than straight seams along the 16 rows at each fixed end plus between 16-wide patches.
        let straight = 16.0 * 2.0 * 5.0;
        assert!(st.seam_total < straight, "{st:?}");
    }
}
