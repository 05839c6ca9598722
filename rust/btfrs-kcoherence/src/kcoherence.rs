//! Hierarchical k-coherence synthesis into a coordinate map (paper 000 section 4.2, after Tong et
//! al. 2002 and Ashikhmin 2001).
//!
//! Output pixels are synthesized in scanline order. For pixel `p0`, every already known pixel
//! `p = p0 + o` of its window carries a sample coordinate `s(p)`; the *coherent* candidate it
//! proposes is `s(p) - o`, the sample pixel that would continue the patch `p` came from. With
//! `k = 1` these are the only candidates (Ashikhmin's algorithm); with `k >= 2` each brings its
//! `k - 1` most similar sample neighbourhoods from the analysis (Figure 3). The candidate whose
//! sample window is closest to the known part of the output window wins; distances are sums of
//! texton distances ([`crate::textons`]), so a candidate costs one table lookup per known pixel.
//!
//! **Hierarchical synthesis** (Figure 4): the coarsest level is synthesized on its own, its border
//! initialised with random sample pixels ("the border of the output is initialized with random
//! pixels from the sample"). Every finer level starts from the coarser result: a quarter of its
//! pixels, `(2x, 2y)`, get the coarser coordinates doubled and are omitted from the scanline pass;
//! the others are synthesized around them (their windows see the preset pixels ahead of them too);
//! "after the synthesis of the missing pixels, the synthesis is again performed on the previously
//! omitted pixels". The random border of the coarsest level is re-synthesized the same way, with
//! the windows complete, so no random pixel survives.
//!
//! **Toroidal output**: windows wrap around the output edges, so the map tiles seamlessly; only
//! the top rows start random (the rows that wrap onto them are not synthesized yet).
//!
//! The scanline order makes each pixel depend on every earlier one, so the coarsest level runs on
//! one thread. A finer level already has a quarter of its pixels from the coarser level, which
//! carry the structure across any row, so it is cut into bands of [`BAND`] rows synthesized in
//! parallel, each in scanline order, each seeing the others' preset pixels (see
//! `LevelSynth::pass`). Random choices are hashes of (seed, level, pixel): the result is a
//! function of the seed alone, whatever the number of threads.

use crate::analysis::{Analysis, Level, Neighbours};
use crate::coordmap::CoordMap;
use btfrs_core::{rng, Error, Monitor, Result};
use rayon::prelude::*;

/// Parameters of a k-coherence synthesis.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SynthOptions {
    /// Output rows.
    pub height: usize,
    /// Output columns.
    pub width: usize,
    /// Candidates per known neighbour: its coherent shift plus `k - 1` similar pixels.
    pub k: usize,
    /// Window radius (the paper's "neighborhood size") at the finest level.
    pub radius: usize,
    /// Window radius at the coarser levels (at least `radius`): larger windows there see the
    /// structure of a regular texture (brick courses) that the finest level's window is too
    /// small for (paper 000, Figure 6: larger neighbourhoods and more levels help).
    pub coarse_radius: usize,
    /// Pyramid levels used (at most those of the analysis).
    pub levels: usize,
    /// Wrap windows around the output edges (a tileable result).
    pub toroidal: bool,
    /// Seed of the random border and of the fallbacks.
    pub seed: u64,
}

/// Largest output side accepted (the coordinate map stays addressable by `u32`).
pub const MAX_SIDE: usize = 32768;

/// Output sizes per level, finest first: `ceil(size / 2^l)`.
pub(crate) fn level_sizes(h: usize, w: usize, levels: usize) -> Vec<(usize, usize)> {
    (0..levels).map(|l| (h.div_ceil(1 << l), w.div_ceil(1 << l))).collect()
}

pub(crate) fn check_size(h: usize, w: usize, radius: usize, levels: usize) -> Result<()> {
    let side = 2 * radius + 1;
    if h > MAX_SIDE || w > MAX_SIDE {
        return Err(Error::arg(
            "size",
            format!("expected at most {MAX_SIDE} x {MAX_SIDE} output pixels, got {h} x {w}"),
        ));
    }
    let (ch, cw) = level_sizes(h, w, levels)[levels - 1];
    if ch < side || cw < side {
        return Err(Error::arg(
            "size",
            format!(
                "a {h} x {w} output is {ch} x {cw} at its coarsest level ({levels} levels), smaller than the \
                 {side} x {side} neighbourhood: ask for at least {} x {} pixels or fewer levels",
                side << (levels - 1),
                side << (levels - 1)
            ),
        ));
    }
    Ok(())
}

/// The similar neighbourhoods of the first `levels` levels, or an error naming `neighbourhood`.
pub(crate) fn neighbours_of(an: &Analysis, radius: usize, levels: usize) -> Result<Vec<&Neighbours>> {
    neighbours_of_from(an, radius, 0, levels)
}

/// The similar neighbourhoods of levels `first..levels`.
pub(crate) fn neighbours_of_from(
    an: &Analysis,
    radius: usize,
    first: usize,
    levels: usize,
) -> Result<Vec<&Neighbours>> {
    an.levels
        .iter()
        .take(levels)
        .skip(first)
        .map(|lv| {
            lv.neighbours(radius).ok_or_else(|| {
                Error::arg(
                    "neighbourhood",
                    format!("the analysis has no similar neighbourhoods of radius {radius}; compute them first"),
                )
            })
        })
        .collect()
}

/// A random interior pixel of a level for radius `r` (a hash of seed and position).
#[inline]
pub(crate) fn random_interior(lv: &Level, r: usize, seed: u64, x: usize, y: usize) -> u32 {
    let (iw, ih) = (lv.width - 2 * r, lv.height - 2 * r);
    let sx = r + (rng::hash01(seed, x as i64, y as i64) * iw as f64) as usize;
    let sy = r + (rng::hash01(seed ^ 0x5151, y as i64, x as i64) * ih as f64) as usize;
    (sy * lv.width + sx) as u32
}

impl SynthOptions {
    /// The window radius at level `l`.
    pub fn radius_at(&self, l: usize) -> usize {
        if l == 0 {
            self.radius
        } else {
            self.coarse_radius
        }
    }
}

/// Run a hierarchical k-coherence synthesis. The analysis must hold the similar neighbourhoods
/// of `radius` on the finest level and of `coarse_radius` on the coarser levels used
/// ([`Analysis::ensure_neighbours_at`]). `monitor` is started with the number of output rows
/// over all levels and passes.
pub fn kcoherence(an: &Analysis, o: &SynthOptions, monitor: &Monitor) -> Result<CoordMap> {
    an.check_levels(o.radius, o.levels)?;
    if o.levels > 1 {
        if o.coarse_radius < o.radius {
            return Err(Error::arg(
                "coarse_neighbourhood",
                format!("expected at least the neighbourhood {}, got {}", o.radius, o.coarse_radius),
            ));
        }
        an.check_levels_from(o.coarse_radius, 1, o.levels)?;
    }
    if o.k == 0 || o.k > an.m {
        return Err(Error::arg(
            "k",
            format!("expected 1 to {} (the m similar neighbourhoods of the analysis), got {}", an.m, o.k),
        ));
    }
    check_size(o.height, o.width, o.radius_at(o.levels - 1), o.levels)?;
    let mut nbs = neighbours_of(an, o.radius, 1)?;
    if o.levels > 1 {
        let coarse = neighbours_of_from(an, o.coarse_radius, 1, o.levels)?;
        nbs.extend(coarse);
    }
    let sizes = level_sizes(o.height, o.width, o.levels);
    monitor.start(sizes.iter().map(|s| 2 * s.0 as u64).sum());
    let mut prev: Option<(Vec<u32>, usize)> = None;
    for l in (0..o.levels).rev() {
        let (oh, ow) = sizes[l];
        let lv = &an.levels[l];
        let mut s = LevelSynth::new(lv, nbs[l], o, l, oh, ow);
        match &prev {
            None => s.random_border(),
            Some((src, pw)) => s.preset(src, *pw),
        }
        let banded = prev.is_some();
        s.pass(1, banded, monitor)?;
        s.pass(2, banded, monitor)?;
        prev = Some((s.src, ow));
    }
    let (src, _) = prev.expect("at least one level");
    let (h0, w0) = an.size();
    Ok(CoordMap { width: o.width, height: o.height, sample_width: w0, sample_height: h0, src })
}

/// Rows per band of the parallel passes of the finer levels.
pub const BAND: usize = 32;

/// The synthesis of one level.
#[derive(Clone)]
struct LevelSynth<'a> {
    lv: &'a Level,
    nb: &'a Neighbours,
    k: usize,
    r: usize,
    toroidal: bool,
    seed: u64,
    oh: usize,
    ow: usize,
    /// Sample pixel of each output pixel, `u32::MAX` while unknown.
    src: Vec<u32>,
    /// Texton of each known output pixel's sample pixel.
    ot: Vec<u16>,
    /// Which pass synthesizes each pixel (1 or 2).
    pass_of: Vec<u8>,
    /// Window offsets `(dx, dy)` without the centre.
    offsets: Vec<(isize, isize)>,
    scratch: Scratch,
}

#[derive(Default, Clone)]
struct Scratch {
    /// Known pixels of the current window: (offset in the sample, row of the distance table).
    known: Vec<(isize, usize)>,
    cands: Vec<u32>,
    /// `stamp[c] == tick` when candidate `c` is already in `cands`.
    stamp: Vec<u32>,
    /// `expanded[c] == tick` when the similar pixels of candidate `c` are already in `cands`.
    expanded: Vec<u32>,
    tick: u32,
}

impl<'a> LevelSynth<'a> {
    fn new(lv: &'a Level, nb: &'a Neighbours, o: &SynthOptions, level: usize, oh: usize, ow: usize) -> Self {
        let r = o.radius_at(level);
        let ri = r as isize;
        let offsets = (-ri..=ri).flat_map(|dy| (-ri..=ri).map(move |dx| (dx, dy))).filter(|&d| d != (0, 0)).collect();
        Self {
            lv,
            nb,
            k: o.k,
            r,
            toroidal: o.toroidal,
            seed: rng::mix(o.seed ^ rng::mix(level as u64 + 1)),
            oh,
            ow,
            src: vec![u32::MAX; oh * ow],
            ot: vec![0; oh * ow],
            pass_of: vec![1; oh * ow],
            offsets,
            scratch: Scratch {
                stamp: vec![0; lv.height * lv.width],
                expanded: vec![0; lv.height * lv.width],
                ..Default::default()
            },
        }
    }

    fn set(&mut self, p: usize, s: u32) {
        self.src[p] = s;
        self.ot[p] = self.lv.textons.assign[s as usize];
    }

    /// Coarsest level: random sample pixels on the border (the top rows only when toroidal),
    /// re-synthesized in pass 2.
    fn random_border(&mut self) {
        let r = self.r;
        for y in 0..self.oh {
            for x in 0..self.ow {
                let border = y < r || (!self.toroidal && (x < r || x + r >= self.ow));
                if border {
                    let s = random_interior(self.lv, r, self.seed, x, y);
                    self.set(y * self.ow + x, s);
                    self.pass_of[y * self.ow + x] = 2;
                }
            }
        }
    }

    /// Finer level: pixels (2x, 2y) take the coarser level's coordinates doubled, and are
    /// re-synthesized in pass 2.
    fn preset(&mut self, coarse: &[u32], cw: usize) {
        let (lw, r) = (self.lv.width, self.r);
        let cws = lw / 2; // width of the coarser sample level
        for y in (0..self.oh).step_by(2) {
            for x in (0..self.ow).step_by(2) {
                let c = coarse[(y / 2) * cw + x / 2] as usize;
                let (cx, cy) = (c % cws, c / cws);
                // Interior at the coarser level doubles to interior here; clamp only as a guard.
                let sx = (2 * cx).clamp(r, lw - r - 1);
                let sy = (2 * cy).clamp(r, self.lv.height - r - 1);
                self.set(y * self.ow + x, (sy * lw + sx) as u32);
                self.pass_of[y * self.ow + x] = 2;
            }
        }
    }

    /// Synthesize the pixels of pass `which` in rows `y0..y1`, in scanline order.
    fn rows(&mut self, which: u8, y0: usize, y1: usize, monitor: &Monitor) -> Result<()> {
        for y in y0..y1 {
            monitor.check()?;
            for x in 0..self.ow {
                let p = y * self.ow + x;
                if self.pass_of[p] == which {
                    let s = self.best(x, y);
                    self.set(p, s);
                }
            }
            monitor.advance(1);
        }
        Ok(())
    }

    /// One pass. The coarsest level runs in one scanline sweep. A finer level runs in bands of
    /// [`BAND`] rows in parallel: each band sweeps its own rows in scanline order and sees the
    /// other bands as they were when the pass began (in pass 1, only their preset pixels from
    /// the coarser level), so the result depends on the band size, fixed, and not on the
    /// number of threads.
    fn pass(&mut self, which: u8, banded: bool, monitor: &Monitor) -> Result<()> {
        if !banded || self.oh <= BAND {
            return self.rows(which, 0, self.oh, monitor);
        }
        let bands: Vec<usize> = (0..self.oh).step_by(BAND).collect();
        let this = &*self;
        let done: Vec<(usize, Vec<u32>, Vec<u16>)> = bands
            .par_iter()
            .map(|&y0| -> Result<_> {
                let y1 = (y0 + BAND).min(this.oh);
                let mut band = this.clone();
                band.rows(which, y0, y1, monitor)?;
                let r = y0 * this.ow..y1 * this.ow;
                Ok((y0, band.src[r.clone()].to_vec(), band.ot[r].to_vec()))
            })
            .collect::<Result<_>>()?;
        for (y0, src, ot) in done {
            let a = y0 * self.ow;
            self.src[a..a + src.len()].copy_from_slice(&src);
            self.ot[a..a + ot.len()].copy_from_slice(&ot);
        }
        Ok(())
    }

    /// The best candidate for output pixel `(x, y)` given the pixels known now.
    fn best(&mut self, x: usize, y: usize) -> u32 {
        let lv = self.lv;
        let (sw, t, m) = (lv.width, lv.textons.count(), self.nb.m);
        let sc = &mut self.scratch;
        sc.known.clear();
        sc.cands.clear();
        sc.tick = sc.tick.wrapping_add(1);
        if sc.tick == 0 {
            sc.stamp.fill(0);
            sc.expanded.fill(0);
            sc.tick = 1;
        }
        let (ow, oh) = (self.ow as isize, self.oh as isize);
        for &(dx, dy) in &self.offsets {
            let (mut qx, mut qy) = (x as isize + dx, y as isize + dy);
            if self.toroidal {
                qx = qx.rem_euclid(ow);
                qy = qy.rem_euclid(oh);
            } else if qx < 0 || qy < 0 || qx >= ow || qy >= oh {
                continue;
            }
            let q = (qy * ow + qx) as usize;
            let s = self.src[q];
            if s == u32::MAX {
                continue;
            }
            sc.known.push((dy * sw as isize + dx, self.ot[q] as usize * t));
            let (cx, cy) = ((s as usize % sw) as isize - dx, (s as usize / sw) as isize - dy);
            if !lv.interior(cx, cy, self.r) {
                continue;
            }
            let c = (cy * sw as isize + cx) as u32;
            // In a coherent patch most known pixels propose the same `c`: its similar pixels
            // are in the list already after the first time.
            if sc.expanded[c as usize] == sc.tick {
                continue;
            }
            sc.expanded[c as usize] = sc.tick;
            let mut add = |c: u32| {
                if c != u32::MAX && sc.stamp[c as usize] != sc.tick {
                    sc.stamp[c as usize] = sc.tick;
                    sc.cands.push(c);
                }
            };
            add(c);
            for &n in &self.nb.index[c as usize * m..c as usize * m + self.k - 1] {
                add(n);
            }
        }
        if sc.cands.is_empty() {
            return random_interior(lv, self.r, self.seed ^ 0xC0FFEE, x, y);
        }
        let (dist, assign) = (&lv.textons.dist, &lv.textons.assign);
        let mut best = (f32::INFINITY, sc.cands[0]);
        for &c in &sc.cands {
            let mut s = 0.0f32;
            let term = |&(d, row): &(isize, usize)| dist[row + assign[(c as isize + d) as usize] as usize];
            // The sum in order, tested every four terms: a partial sum only grows, so testing
            // less often never keeps a loser, and the four loads overlap.
            for ks in sc.known.chunks(4) {
                for k in ks {
                    s += term(k);
                }
                if s >= best.0 {
                    break;
                }
            }
            if s < best.0 {
                best = (s, c);
            }
        }
        best.1
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::AnalysisOptions;
    use crate::pyramid::Features;

    /// A sample with structure: stripes of period 6 plus a little noise, one texton per pixel.
    fn stripes(h: usize, w: usize) -> Features {
        let data = (0..h * w)
            .flat_map(|i| {
                let (x, y) = (i % w, i / w);
                let v = if (x + 2 * y) % 6 < 3 { 1.0 } else { 0.0 };
                [v, 0.05 * btfrs_core::rng::hash01(5, x as i64, y as i64) as f32]
            })
            .collect();
        Features::new(h, w, 2, data).unwrap()
    }

    fn analysis(levels: usize) -> Analysis {
        let opts = AnalysisOptions { textons: 256, levels, m: 6, iterations: 10, seed: 1 };
        Analysis::of_features(stripes(32, 32), opts, &[2], &Monitor::new()).unwrap()
    }

    #[test]
    fn output_is_coherent_interior_and_deterministic() {
        let an = analysis(2);
        let o = SynthOptions {
            height: 40,
            width: 50,
            k: 3,
            radius: 2,
            levels: 2,
            coarse_radius: 2,
            toroidal: false,
            seed: 7,
        };
        let a = kcoherence(&an, &o, &Monitor::new()).unwrap();
        assert_eq!((a.height, a.width, a.src.len()), (40, 50, 2000));
        // Every output pixel comes from the interior of the sample.
        for y in 0..40 {
            for x in 0..50 {
                let (sx, sy) = a.source(x, y);
                assert!((2..30).contains(&sx) && (2..30).contains(&sy), "({x}, {y}) -> ({sx}, {sy})");
            }
        }
        assert_eq!(a, kcoherence(&an, &o, &Monitor::new()).unwrap());
        let b = kcoherence(&an, &SynthOptions { seed: 8, ..o }, &Monitor::new()).unwrap();
        assert_ne!(a, b);
        // The stripes continue: the output's stripe phase (x + 2y mod 6 class) is preserved for
        // almost every horizontally adjacent pair.
        let val = |sx: usize, sy: usize| (sx + 2 * sy) % 6 < 3;
        let mut agree = 0;
        for y in 0..40 {
            for x in 0..49 {
                let (p, q) = (a.source(x, y), a.source(x + 1, y));
                // Moving right by one in a stripe pattern of period 6 changes the class at a known
                // rate in the sample; compare with the sample's own rate via the coherent pixel.
                agree += (val(q.0, q.1) == val((p.0 + 1).min(31), p.1)) as usize;
            }
        }
        assert!(agree as f64 > 0.9 * (40.0 * 49.0), "{agree}");
    }

    #[test]
    fn banded_levels_do_not_depend_on_the_thread_count() {
        let an = analysis(2);
        // 100 rows at the finest level: several bands of BAND rows.
        let o = SynthOptions {
            height: 100,
            width: 70,
            k: 3,
            radius: 2,
            coarse_radius: 2,
            levels: 2,
            toroidal: false,
            seed: 11,
        };
        let a = kcoherence(&an, &o, &Monitor::new()).unwrap();
        let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        let one = pool.install(|| kcoherence(&an, &o, &Monitor::new()).unwrap());
        assert_eq!(a, one);
    }

    #[test]
    fn bad_parameters_name_themselves() {
        let an = analysis(2);
        let o = SynthOptions {
            height: 40,
            width: 40,
            k: 3,
            radius: 2,
            levels: 2,
            coarse_radius: 2,
            toroidal: false,
            seed: 7,
        };
        let err = |o: SynthOptions| kcoherence(&an, &o, &Monitor::new()).unwrap_err().to_string();
        assert!(err(SynthOptions { k: 7, ..o }).starts_with("k:"));
        assert!(err(SynthOptions { k: 0, ..o }).starts_with("k:"));
        assert!(err(SynthOptions { height: 8, ..o }).starts_with("size:"));
        assert!(err(SynthOptions { levels: 3, ..o }).starts_with("levels:"));
        assert!(err(SynthOptions { radius: 1, ..o }).starts_with("neighbourhood:"));
        assert!(err(SynthOptions { coarse_radius: 1, ..o }).starts_with("coarse_neighbourhood:"));
        // A coarse radius whose neighbourhoods were not computed.
        assert!(err(SynthOptions { coarse_radius: 3, ..o }).starts_with("neighbourhood:"));
    }

    #[test]
    fn larger_coarse_neighbourhoods_use_their_own_sets() {
        let mut an = analysis(2);
        an.ensure_neighbours_at(3, 1, 2, &Monitor::new()).unwrap();
        // Only the coarse level got radius-3 neighbourhoods.
        assert!(an.levels[0].neighbours(3).is_none() && an.levels[1].neighbours(3).is_some());
        let o = SynthOptions {
            height: 64,
            width: 64,
            k: 3,
            radius: 2,
            coarse_radius: 3,
            levels: 2,
            toroidal: false,
            seed: 7,
        };
        let a = kcoherence(&an, &o, &Monitor::new()).unwrap();
        assert_eq!(a, kcoherence(&an, &o, &Monitor::new()).unwrap());
        assert_ne!(a, kcoherence(&an, &SynthOptions { coarse_radius: 2, ..o }, &Monitor::new()).unwrap());
        for y in 0..64 {
            for x in 0..64 {
                let (sx, sy) = a.source(x, y);
                assert!((2..30).contains(&sx) && (2..30).contains(&sy));
            }
        }
    }

    #[test]
    fn toroidal_output_wraps_coherently() {
        let an = analysis(1);
        let o = SynthOptions {
            height: 24,
            width: 24,
            k: 2,
            radius: 2,
            coarse_radius: 2,
            levels: 1,
            toroidal: true,
            seed: 3,
        };
        let a = kcoherence(&an, &o, &Monitor::new()).unwrap();
        // The stripe class along the wrap seam (last column -> first column) agrees as well as
        // inside: the map tiles.
        let val = |p: (usize, usize)| (p.0 + 2 * p.1) % 6 < 3;
        let next = |p: (usize, usize)| ((p.0 + 1).min(31), p.1);
        let seam = (0..24).filter(|&y| val(a.source(0, y)) == val(next(a.source(23, y)))).count();
        assert!(seam >= 21, "{seam} of 24 rows agree across the wrap");
    }
}
