//! Robust fitting: hot and stuck sensor pixels, dust, a glint from a loose fibre or a blooming
//! highlight must not wreck a model, and a whole bad image (a misfired flash, a moved sample)
//! is found and named.
//!
//! **Why the values are screened before the fit, not by the fit's residuals.** Classic robust
//! regression starts from a first fit and scales its residuals by a robust spread. Here the first
//! fit is the problem: a least-squares fit spreads one value 1000 times too large over every value
//! it shares coefficients with (a PTM's 81 lights of a view slot, an LPCA cluster's basis), so
//! on the `grooves` material with 0.01% of the values hot, the clean values beside a hot one
//! reach 905 robust standard deviations (MAD per texel and per slot) while the hot values start
//! at 10: no threshold on the first fit's residuals separates them. The screen instead compares
//! each value with two robust local models that an outlier cannot move:
//!
//! * the median of the same texel, view and channel under the `K = 8` nearest measured lights
//!   (the light directions' neighbours: a BRDF is smooth between them at the sampling of a
//!   capture), and
//! * the median of the same pair and channel at the texel's 8 spatial neighbours (inside the
//!   sample).
//!
//! Only values above a gate are compared with their neighbours: 8 times the mean of the texel's
//! row of lights (same view and channel) without its two largest values. A value below it cannot
//! wreck a fit, and the gate keeps the screen to one streaming pass over the data (most values
//! are cleared by one comparison). The criteria are ratios, which mean something for radiance
//! only: a row with a value below minus the floor (below) is not screened (signed data, made
//! from a model's random coefficients or a difference of images). A value above `FACTOR = 8`
//! times the larger of the two medians (plus 5% of the data's mean, so that noise in the dark is
//! not flagged) is inconsistent with
//! both its light neighbours and its spatial neighbours: it is replaced by its light neighbours'
//! median and the model is fitted to the repaired values (trimming with imputation: every model's
//! own fit, with its fast paths, the shared pseudo-inverse of PTM and HSH, the randomized range
//! finder of LPCA, the constrained solve of SH, runs unchanged, since the sampling stays
//! complete). Spatial neighbours that are themselves far above their light neighbours are left
//! out of the spatial median: with 1% of the values hot, somewhere a texel has half its
//! neighbours hot at the same pair. A real highlight is bright under neighbouring lights too, or
//! at neighbouring texels, and is kept: on the clean built-in materials a few values in ten
//! thousand are flagged and no model's error moves by 1%.
//!
//! **Where the value screen runs.** Most fits get a repaired copy of the values, screened in a
//! pass of its own before the fit. PTM and HSH fit every texel from its own values alone, so
//! they judge each texel inside their own pass instead ([`TexelScreen`]), while its values are
//! in cache, and fit a texel with flagged values from a repaired copy of its ABRDF: the same
//! model, without the second read of the data nor a copy of it (a memory-mapped BTF larger than
//! the memory limit is repaired too).
//!
//! **Bad images.** For every (view, light) pair the log of the median over 64 texels (an 8 x 8
//! grid) of `(x + a) / (m + a)`, the ratio of the image's luminance to its light neighbours'
//! (`m`: their mean without the smallest and the largest, so one bad neighbour moves it little),
//! is its *spread* (signed: below 0, darker than its neighbours); the same against the same
//! light seen from the 4 nearest views is its view spread. An image whose spreads both lie
//! beyond `ln 2` on the same side and 6 robust standard deviations (1.4826 median absolute
//! deviations) from the typical spread of all images is reported with its pair. A grazing light
//! is far from its light neighbours (all on one side of it) but not from the same light seen
//! from the views beside it; a grazing view's shadows scatter its ratios both ways, leaving
//! their median near 1. A misfired or doubled flash changes every texel's ratio alike; a
//! brighter image counts only alone, since pairs around it nearly as bright trace a sharp
//! feature of the BRDF (a specular ridge). A moved sample leaves the ratios' median near 1 and
//! is found by its registration instead ([`moved_images`]: a central 16 x 16 patch correlated
//! with its neighbours', shifted by up to 6 texels). With `exclude_bad_images` those pairs are
//! left out of the fit (masked), as if not measured.

use btfrs_core::{BtfRef, Error, Monitor, Result};
use rayon::prelude::*;
use serde_json::{json, Value};

/// How far above both local models a value must lie to be an outlier.
pub const FACTOR: f32 = 8.0;
/// Light neighbours per value.
pub const NEIGHBOURS: usize = 8;
/// The additive floor, as a fraction of the data's mean.
pub const FLOOR: f32 = 0.05;
/// View neighbours an image is compared with (same light).
const VIEW_NEIGHBOURS: usize = 4;
/// With one view only the light neighbours judge an image, and images near the horizon differ
/// from theirs by up to a factor of 3.4 on the built-in materials: a bad image must be 4 times
/// off.
const ONE_VIEW_LEAST: f32 = 1.386_294_4;
/// Texels sampled (an 8 x 8 grid) for the images' spreads and the data's mean: the spreads are
/// medians over them, and 64 keep that cost under a third of a one-pass fit.
const SAMPLE_TEXELS: usize = 64;

/// Flat indices into the data, with replacement values.
pub type Flags = Vec<(usize, f32)>;

/// What the screen found.
#[derive(Debug, Clone, Default)]
pub struct Screen {
    /// Flat indices into the data of the values flagged, with their replacements.
    pub values: Vec<(usize, f32)>,
    /// Per pair `v * L + l`: the image's spread against its light neighbours (NaN where the
    /// pair is absent).
    pub spread: Vec<f32>,
    /// Pairs `(view, light)` whose images are far from their neighbours.
    pub bad_images: Vec<(usize, usize)>,
    /// The additive floor used.
    pub floor: f32,
    /// Images moved against their neighbours, `(view, light, rows, columns)`: how far the
    /// image's content lies from its neighbours' (these pairs are among `bad_images` too).
    pub moved: Vec<(usize, usize, i32, i32)>,
}

/// The `k` directions of `among` (indices into `dirs`) nearest to `dirs[of]`, itself left out;
/// ties broken by index, so the choice is deterministic.
fn nearest(dirs: &[[f64; 3]], of: usize, among: &[usize], k: usize) -> Vec<usize> {
    let a = dirs[of];
    let mut by: Vec<(f64, usize)> = among
        .iter()
        .filter(|&&o| o != of)
        .map(|&o| {
            let b = dirs[o];
            (-(a[0] * b[0] + a[1] * b[1] + a[2] * b[2]), o)
        })
        .collect();
    // The k smallest first (linear), then only those sorted: the same k in the same order as a
    // full sort, since the order is total (ties broken by index).
    let cmp = |x: &(f64, usize), y: &(f64, usize)| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1));
    if k < by.len() {
        by.select_nth_unstable_by(k, cmp);
        by.truncate(k);
    }
    by.sort_by(cmp);
    by.into_iter().map(|(_, o)| o).collect()
}

fn median(v: &mut [f32]) -> f32 {
    let n = v.len();
    if n == 0 {
        return f32::NAN;
    }
    if n <= 16 {
        // A neighbourhood: an insertion sort is several times faster than a selection here,
        // and the screen takes a million of these medians per sampled image set.
        for i in 1..n {
            let x = v[i];
            let mut j = i;
            while j > 0 && v[j - 1].total_cmp(&x) == std::cmp::Ordering::Greater {
                v[j] = v[j - 1];
                j -= 1;
            }
            v[j] = x;
        }
        return if n % 2 == 1 { v[n / 2] } else { 0.5 * (v[n / 2 - 1] + v[n / 2]) };
    }
    // Select on integer keys in the order of `f32::total_cmp` (its own definition: the bits
    // with the magnitude flipped below zero), in place, then back: an integer comparison is a
    // fraction of `total_cmp`'s, and the screen takes two of these medians per image.
    let key = |b: u32| (b ^ (((b as i32 >> 31) as u32) >> 1)) as i32;
    // SAFETY: `f32` and `i32` have the same size and alignment, and every bit pattern is valid
    // for both; the slice is only reborrowed for this function.
    let keys: &mut [i32] = unsafe { std::slice::from_raw_parts_mut(v.as_mut_ptr().cast::<i32>(), n) };
    keys.iter_mut().for_each(|k| *k = key(*k as u32));
    let (lo, mid, _) = keys.select_nth_unstable(n / 2);
    let hi = *mid;
    let lo_max = if n.is_multiple_of(2) { lo.iter().copied().max() } else { None };
    // The map is its own inverse (it flips the magnitude bits of negative values only, and
    // keeps the sign bit).
    keys.iter_mut().for_each(|k| *k = key(*k as u32));
    let back = |k: i32| f32::from_bits(key(k as u32) as u32);
    match lo_max {
        None => back(hi),
        Some(l) => 0.5 * (back(l) + back(hi)),
    }
}

/// Per view: its present lights and each one's `NEIGHBOURS` nearest present lights (views with
/// the same present lights, all of them without a mask, share one table). The distinct light
/// sets are found first and their tables made in parallel, one set per task: with pairs held
/// out every view has its own set, and a parallel loop over the few dozen lights of each set
/// spent more on waking the pool's threads than on the work.
type Table = std::sync::Arc<Vec<(usize, Vec<usize>)>>;

fn light_tables(lights: &[[f64; 3]], mask: Option<&[bool]>, nv: usize) -> Vec<Table> {
    let nl = lights.len();
    let present = |v: usize, l: usize| mask.is_none_or(|m| m[v * nl + l]);
    let table = |ls: &[usize]| -> Vec<(usize, Vec<usize>)> {
        let k = NEIGHBOURS.min(ls.len().saturating_sub(1));
        ls.iter().map(|&l| (l, nearest(lights, l, ls, k))).collect()
    };
    let sets: Vec<Vec<usize>> = (0..nv).map(|v| (0..nl).filter(|&l| present(v, l)).collect()).collect();
    let mut first: std::collections::HashMap<&[usize], usize> = std::collections::HashMap::new();
    let mut distinct: Vec<&[usize]> = Vec::new();
    let which: Vec<usize> = sets
        .iter()
        .map(|ls| {
            *first.entry(ls.as_slice()).or_insert_with(|| {
                distinct.push(ls);
                distinct.len() - 1
            })
        })
        .collect();
    let tables: Vec<Table> = distinct.par_iter().map(|ls| std::sync::Arc::new(table(ls))).collect();
    which.iter().map(|&i| tables[i].clone()).collect()
}

/// The texels (flat indices) that judge the images and set the floor: a grid of at most
/// `SAMPLE_TEXELS` spread over an `h x w` sample (every texel of a small one). A blockwise fit
/// gathers the same texels, so it screens as the fit in memory does.
pub fn sample_texels(h: usize, w: usize) -> Vec<usize> {
    let side = (SAMPLE_TEXELS as f64).sqrt() as usize;
    let (gr, gc) = (side.min(h), side.min(w));
    (0..gr).flat_map(|i| (0..gc).map(move |j| ((2 * i + 1) * h / (2 * gr)) * w + (2 * j + 1) * w / (2 * gc))).collect()
}

/// Luminance of every pair at the `texels` of `data` (whole ABRDFs of `npairs` RGB pairs,
/// one after the other), pair-major: `out[p * n + k]` for pair p, texel k. Blocks of 64 pairs
/// in parallel, each reading 64 pairs of 8 texels at once (contiguous runs) into a small tile
/// that is written out as runs of 8 texels, so that neither the reads nor the writes stride
/// across the whole table one value at a time.
fn luminance_by_pair(data: &[f32], texels: &[usize], npairs: usize) -> Vec<f32> {
    const PAIRS: usize = 64;
    const TEX: usize = 8;
    let n = texels.len();
    let mut lum = vec![0.0f32; npairs * n];
    lum.par_chunks_mut(PAIRS * n).enumerate().for_each(|(blk, out)| {
        let p0 = blk * PAIRS;
        let m = out.len() / n;
        let mut tile = [[0.0f32; TEX]; PAIRS];
        for (g, ts) in texels.chunks(TEX).enumerate() {
            for (k, &t) in ts.iter().enumerate() {
                let src = &data[(t * npairs + p0) * 3..(t * npairs + p0 + m) * 3];
                for (row, px) in tile.iter_mut().zip(src.chunks_exact(3)) {
                    row[k] = (px[0] + px[1] + px[2]) / 3.0;
                }
            }
            for (i, row) in tile.iter().take(m).enumerate() {
                out[i * n + g * TEX..i * n + g * TEX + ts.len()].copy_from_slice(&row[..ts.len()]);
            }
        }
    });
    lum
}

/// What the sampled texels say about the whole: the floor and each image's spreads.
#[derive(Debug, Clone, Default)]
pub struct Images {
    /// Per pair `v * L + l`: the image's spread against its light neighbours (NaN where the
    /// pair is absent).
    pub spread: Vec<f32>,
    /// Pairs `(view, light)` whose images are far from their neighbours.
    pub bad_images: Vec<(usize, usize)>,
    /// The additive floor of the value screen.
    pub floor: f32,
}

/// Judge the images and set the floor from the ABRDFs of the [`sample_texels`]: `texels` of
/// `data` (whole ABRDFs, `views x lights x 3` values each, one after the other).
pub fn screen_images(
    views: &[[f64; 3]],
    lights: &[[f64; 3]],
    mask: Option<&[bool]>,
    data: &[f32],
    texels: &[usize],
) -> Result<Images> {
    let (nv, nl) = (views.len(), lights.len());
    let abrdf = nv * nl * 3;
    if abrdf == 0 || texels.is_empty() || texels.iter().any(|&t| (t + 1) * abrdf > data.len()) {
        return Err(Error::arg("data", format!("expected ABRDFs of {abrdf} values at texels {texels:?}")));
    }
    let ns = texels.len();
    let present = |v: usize, l: usize| mask.is_none_or(|m| m[v * nl + l]);
    let nbrs = light_tables(lights, mask, nv);
    // The data's mean over the sampled texels' present values: the scale of the floor.
    let (sum, count) = texels
        .par_iter()
        .map(|&t| {
            let a = &data[t * abrdf..(t + 1) * abrdf];
            let mut s = 0.0f64;
            let mut n = 0u64;
            for (v, per) in nbrs.iter().enumerate() {
                for (l, _) in per.iter() {
                    let o = (v * nl + l) * 3;
                    s += a[o..o + 3].iter().map(|&x| x as f64).sum::<f64>();
                    n += 3;
                }
            }
            (s, n)
        })
        .reduce(|| (0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    let floor = (FLOOR as f64 * sum / (count.max(1) as f64)).max(1e-30) as f32;
    // Each image's spreads against its light neighbours (same view) and its view neighbours
    // (same light), over the sampled texels (luminance). A bad image is far from both; an image
    // near the horizon is far from its light neighbours (all on one side of it) but not from
    // the same light seen from the views beside it.
    // Texel-major: one sampled texel's luminances for every pair (its ABRDF, read once), then
    // each pair's ratios to its neighbours from that small table.
    let all_views: Vec<usize> = (0..nv).collect();
    let view_nbrs: Vec<Vec<usize>> = (0..nv).map(|v| nearest(views, v, &all_views, VIEW_NEIGHBOURS)).collect();
    // Per present pair: its index, how many light and view neighbours it has, and their pair
    // indices (flat: the inner loop below runs a million times; no pointer chasing in it).
    const NB: usize = NEIGHBOURS + VIEW_NEIGHBOURS;
    let mut flat: Vec<(u32, u8, u8, [u32; NB])> = Vec::with_capacity(nv * nl);
    for (v, per) in nbrs.iter().enumerate() {
        for (l, nb) in per.iter() {
            let mut f = (0u32, 0u8, 0u8, [0u32; NB]);
            f.0 = (v * nl + l) as u32;
            let mut k = 0;
            for &o in nb.iter().take(NEIGHBOURS) {
                f.3[k] = (v * nl + o) as u32;
                k += 1;
            }
            f.1 = k as u8;
            for &o in view_nbrs[v].iter().filter(|&&o| present(o, *l)).take(VIEW_NEIGHBOURS) {
                f.3[k] = (o * nl + l) as u32;
                k += 1;
            }
            f.2 = (k - f.1 as usize) as u8;
            flat.push(f);
        }
    }
    // The sampled texels' luminances, pair-major (`lum[p * ns + k]`: pair p, sampled texel k):
    // each texel's ABRDF is read once, contiguously, then transposed in blocks, so that a pair's
    // neighbours are a few contiguous rows of `ns` values.
    let npairs = nv * nl;
    let lum = luminance_by_pair(data, texels, npairs);
    let per_pair: Vec<(usize, f32, f32)> = flat
        .par_iter()
        .map_init(
            || [vec![0.0f32; ns], vec![0.0f32; ns], vec![0.0f32; ns], vec![0.0f32; ns]],
            |[sum, lo, hi, d], (p, nlt, nvw, nb)| {
                let (p, nlt, nvw) = (*p as usize, *nlt as usize, *nvw as usize);
                let x = &lum[p * ns..(p + 1) * ns];
                let mut spread = |from: usize, n: usize| -> f32 {
                    if n < 2 {
                        return f32::NAN;
                    }
                    // Per texel the neighbours' mean without their smallest and largest (one bad
                    // neighbour moves it little, and it runs across the texels in lockstep, where
                    // a median per texel would not), the ratio to it, and the log of the ratios'
                    // median over the texels: signed, so that a brightness change common to the
                    // texels (a misfired flash) is told from ratios scattered both ways (shadows
                    // at grazing angles, which differ from texel to texel).
                    sum.fill(0.0);
                    lo.fill(f32::INFINITY);
                    hi.fill(f32::NEG_INFINITY);
                    for &o in &nb[from..from + n] {
                        let row = &lum[o as usize * ns..(o as usize + 1) * ns];
                        // (Comparisons rather than f32::min/max, whose NaN rules keep the loop
                        // from vectorising; NaNs here only make this pair's spread NaN.)
                        for (((s, l), h), &y) in sum.iter_mut().zip(lo.iter_mut()).zip(hi.iter_mut()).zip(row) {
                            *s += y;
                            *l = if y < *l { y } else { *l };
                            *h = if y > *h { y } else { *h };
                        }
                    }
                    let (drop2, keep) = if n > 2 { (1.0, (n - 2) as f32) } else { (0.0, n as f32) };
                    for ((((d, s), l), h), &y) in d.iter_mut().zip(sum.iter()).zip(lo.iter()).zip(hi.iter()).zip(x) {
                        let m = (s - drop2 * (l + h)) / keep + floor;
                        *d = (y + floor) / m;
                    }
                    median(d).ln()
                };
                (p, spread(0, nlt), spread(nlt, nvw))
            },
        )
        .collect();
    let mut spread = vec![f32::NAN; nv * nl];
    let mut spread_view = vec![f32::NAN; nv * nl];
    for (i, a, b) in per_pair {
        spread[i] = a;
        spread_view[i] = b;
    }
    // Far: more than `least` from 0 and 6 robust standard deviations from the typical spread.
    let far = |sp: &[f32], least: f32| -> Vec<bool> {
        let mut all: Vec<f32> = sp.iter().copied().filter(|s| s.is_finite()).collect();
        let typical = median(&mut all);
        let mut dev: Vec<f32> = all.iter().map(|s| (s - typical).abs()).collect();
        let mad = 1.4826 * median(&mut dev);
        sp.iter().map(|&s| s.is_finite() && s.abs() > least && (s - typical).abs() > 6.0 * mad).collect()
    };
    let several_views = spread_view.iter().any(|s| s.is_finite());
    let by_light = far(&spread, if several_views { std::f32::consts::LN_2 } else { ONE_VIEW_LEAST });
    let by_view = far(&spread_view, std::f32::consts::LN_2);
    let far_both = |i: usize| {
        by_light[i]
            && (by_view[i] && spread[i].signum() == spread_view[i].signum()
                || !spread_view[i].is_finite() && !several_views)
    };
    // A brighter image is a bad one only alone: where a neighbouring pair is above its own
    // light neighbours by half as much (in log), the pairs trace a sharp feature of the BRDF (grooves' facets seen at
    // grazing angles light up a ridge of pairs 2.5 times above their neighbours, one light
    // per view, moving with the view), while a second flash fires for one image. A darker
    // image is bad either way.
    // The neighbourhood is the pairs' own: the view and its nearest views, each with the light
    // and its nearest lights (a feature that moves with the view, a specular ridge, is
    // diagonal in it).
    let bright = |i: usize, of: usize| spread[i] > 0.5 * spread[of];
    let light_nbrs = |l: usize| -> &[usize] {
        nbrs.iter().find_map(|per| per.iter().find(|(x, _)| *x == l)).map_or(&[], |(_, nb)| nb.as_slice())
    };
    let clustered = |i: usize| {
        let (v, l) = (i / nl, i % nl);
        std::iter::once(v).chain(view_nbrs[v].iter().copied()).any(|vv| {
            std::iter::once(l)
                .chain(light_nbrs(l).iter().copied())
                .any(|ll| (vv, ll) != (v, l) && present(vv, ll) && bright(vv * nl + ll, i))
        })
    };
    let bad_images = flat
        .iter()
        .map(|f| f.0 as usize)
        .filter(|&i| far_both(i) && (spread[i] < 0.0 || !clustered(i)))
        .map(|i| (i / nl, i % nl))
        .collect();
    Ok(Images { spread, bad_images, floor })
}

/// Side of the central patch of texels that judges the images' registration.
pub const PATCH: usize = 16;
/// The largest shift searched, in texels.
const MAX_SHIFT: i32 = 6;
/// A moved image matches its neighbours shifted at least this well (normalized cross
/// correlation)...
const MOVED_MATCH: f32 = 0.8;
/// ...and this much better than unshifted. On the built-in materials at 32², a clean image
/// gains at most 0.67 (grooves, at grazing light, whose shadows move with the light) and
/// never reaches the match; one rolled by 5 texels gains 0.8 to 1.5.
const MOVED_GAIN: f32 = 0.4;

/// The central patch, at most `PATCH x PATCH` texels: `(first row, first column, rows,
/// columns)`.
pub fn patch_window(h: usize, w: usize) -> (usize, usize, usize, usize) {
    let (ph, pw) = (PATCH.min(h), PATCH.min(w));
    ((h - ph) / 2, (w - pw) / 2, ph, pw)
}

/// [`ncc`] unshifted, of two images of the same size (every image once): one pass over both.
/// Eight `f32` lanes per statistic, so that the loop vectorises, each lane summing 8 values
/// before the totals are taken in `f64` (blocks of 64 values).
#[inline(always)]
fn ncc0(a: &[f32], b: &[f32]) -> f32 {
    let mut tot = [0.0f64; 5];
    for (ba, bb) in a.chunks(64).zip(b.chunks(64)) {
        let mut l = [[0.0f32; 8]; 5];
        let mut add = |k: usize, p: f32, q: f32| {
            l[0][k] += p;
            l[1][k] += q;
            l[2][k] += p * p;
            l[3][k] += q * q;
            l[4][k] += p * q;
        };
        let (ca, cb) = (ba.chunks_exact(8), bb.chunks_exact(8));
        let (ra, rb) = (ca.remainder(), cb.remainder());
        for (ca, cb) in ca.zip(cb) {
            for k in 0..8 {
                add(k, ca[k], cb[k]);
            }
        }
        for (k, (&p, &q)) in ra.iter().zip(rb).enumerate() {
            add(k, p, q);
        }
        for (t, lane) in tot.iter_mut().zip(&l) {
            *t += lane.iter().map(|&x| x as f64).sum::<f64>();
        }
    }
    let [sa, sb, saa, sbb, sab] = tot;
    let n = a.len() as f64;
    let (va, vb) = (saa - sa * sa / n, sbb - sb * sb / n);
    if va <= 1e-12 * saa.max(1e-30) || vb <= 1e-12 * sbb.max(1e-30) {
        return f32::NAN;
    }
    ((sab - sa * sb / n) / (va * vb).sqrt()) as f32
}

/// Normalized cross correlation of `a` and `b` (`ph x pw` images) over their overlap when `a`'s
/// texel `(y + dy, x + dx)` is laid on `b`'s `(y, x)`; NaN without contrast.
fn ncc(a: &[f32], b: &[f32], ph: usize, pw: usize, dy: i32, dx: i32) -> f32 {
    if (dy, dx) == (0, 0) {
        return ncc0(&a[..ph * pw], &b[..ph * pw]);
    }
    let (ph_, pw_) = (ph as i32, pw as i32);
    let (y0, y1) = (0.max(-dy), ph_.min(ph_ - dy));
    let (x0, x1) = (0.max(-dx), pw_.min(pw_ - dx));
    if y1 - y0 < 4 || x1 - x0 < 4 {
        return f32::NAN;
    }
    let n = ((y1 - y0) * (x1 - x0)) as f64;
    let (mut sa, mut sb, mut saa, mut sbb, mut sab) = (0.0f64, 0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for y in y0..y1 {
        let ra = &a[((y + dy) * pw_) as usize..];
        let rb = &b[(y * pw_) as usize..];
        for x in x0..x1 {
            let (p, q) = (ra[(x + dx) as usize] as f64, rb[x as usize] as f64);
            sa += p;
            sb += q;
            saa += p * p;
            sbb += q * q;
            sab += p * q;
        }
    }
    let (va, vb) = (saa - sa * sa / n, sbb - sb * sb / n);
    if va <= 1e-12 * saa.max(1e-30) || vb <= 1e-12 * sbb.max(1e-30) {
        return f32::NAN;
    }
    ((sab - sa * sb / n) / (va * vb).sqrt()) as f32
}

/// The reference image of the pairs `pairs` of `lum` (images of `np` texels, one after the
/// other): per texel their mean without the smallest and largest (the plain mean of one or two),
/// into `r[0]` (`r[1]`, `r[2]` scratch). False, and `r[0]` untouched, when there are none.
/// Neighbour by neighbour across the texels, so the loops vectorise.
#[inline(always)]
fn reference_into(lum: &[f32], np: usize, pairs: impl Iterator<Item = usize>, r: &mut [Vec<f32>; 3]) -> bool {
    let [s, lo, hi] = r;
    s.fill(0.0);
    lo.fill(f32::INFINITY);
    hi.fill(f32::NEG_INFINITY);
    let mut n = 0usize;
    for q in pairs {
        n += 1;
        for (((s, l), h), &y) in s.iter_mut().zip(lo.iter_mut()).zip(hi.iter_mut()).zip(&lum[q * np..(q + 1) * np]) {
            *s += y;
            *l = if y < *l { y } else { *l };
            *h = if y > *h { y } else { *h };
        }
    }
    if n == 0 {
        return false;
    }
    if n > 2 {
        let k = (n - 2) as f32;
        s.iter_mut().zip(lo.iter()).zip(hi.iter()).for_each(|((s, l), h)| *s = (*s - l - h) / k);
    } else {
        s.iter_mut().for_each(|s| *s /= n as f32);
    }
    true
}

crate::simd::by_cpu! {
    /// `ncc` of `img` with the reference of `pairs` ([`reference_into`]) unshifted; NaN without
    /// neighbours. Compiled apart for AVX2 and chosen at run time (the wheel targets the x86-64
    /// baseline), as the value screen's gate is.
    fn unshifted_ncc(
        lum: &[f32],
        np: usize,
        pairs: impl Iterator<Item = usize>,
        img: &[f32],
        ph: usize,
        pw: usize,
        scratch: &mut [Vec<f32>; 3],
    ) -> f32 ["avx2"] {
        if reference_into(lum, np, pairs, scratch) {
            ncc0(&img[..ph * pw], &scratch[0][..ph * pw])
        } else {
            f32::NAN
        }
    }
}

/// Images moved against their neighbours (a sample knocked between two shots, a misregistered
/// image): `(view, light, rows, columns)` of the shift. `data` holds rows of `width` texels'
/// ABRDFs, and the images are judged on its `window` (`(row, column, rows, columns)`, the
/// [`patch_window`]). Each image's luminance is correlated with its light
/// neighbours' (their mean per texel without the smallest and largest); the images far less
/// correlated than is typical (6 robust standard deviations) are searched over shifts of up to
/// 6 texels, and one is moved when a shift matches far better than none, against its light
/// neighbours and, with several views, against the same light seen from the nearest views.
/// A texture that repeats within the shift, or has none, cannot show a move.
pub fn moved_images(
    views: &[[f64; 3]],
    lights: &[[f64; 3]],
    mask: Option<&[bool]>,
    data: &[f32],
    width: usize,
    window: (usize, usize, usize, usize),
) -> Result<Vec<(usize, usize, i32, i32)>> {
    let (nv, nl) = (views.len(), lights.len());
    let abrdf = nv * nl * 3;
    let (r0, c0, ph, pw) = window;
    let np = ph * pw;
    if c0 + pw > width || ((r0 + ph) * width) * abrdf > data.len() {
        return Err(Error::arg("window", format!("{window:?} does not lie inside rows of {width} texels")));
    }
    let texels: Vec<usize> = (r0..r0 + ph).flat_map(|r| (c0..c0 + pw).map(move |c| r * width + c)).collect();
    if ph < 8 || pw < 8 {
        return Ok(Vec::new());
    }
    let present = |v: usize, l: usize| mask.is_none_or(|m| m[v * nl + l]);
    let nbrs = light_tables(lights, mask, nv);
    let all_views: Vec<usize> = (0..nv).collect();
    let view_nbrs: Vec<Vec<usize>> = (0..nv).map(|v| nearest(views, v, &all_views, VIEW_NEIGHBOURS)).collect();
    // Luminance per pair, each a ph x pw image.
    let npairs = nv * nl;
    let lum = luminance_by_pair(data, &texels, npairs);
    // The reference image: the neighbours' mean per texel without their smallest and largest
    // (neighbour by neighbour across the texels, so the loop vectorises).
    let reference = |pairs: &[usize]| -> Option<Vec<f32>> {
        let mut r = [vec![0.0f32; np], vec![0.0f32; np], vec![0.0f32; np]];
        reference_into(&lum, np, pairs.iter().copied(), &mut r).then(|| r[0].clone())
    };
    let light_pairs = |v: usize, nb: &[usize]| -> Vec<usize> { nb.iter().map(|&o| v * nl + o).collect() };
    let cases: Vec<(usize, usize, &[usize])> =
        nbrs.iter().enumerate().flat_map(|(v, per)| per.iter().map(move |(l, nb)| (v, *l, nb.as_slice()))).collect();
    // Every image's correlation with its light neighbours' reference: the part of this check
    // that runs for every pair (per-thread scratch; compiled for AVX2 where the CPU has it).
    let unshifted: Vec<f32> = cases
        .par_iter()
        .map_init(
            || [vec![0.0f32; np], vec![0.0f32; np], vec![0.0f32; np]],
            |scratch, &(v, l, nb)| {
                let img = &lum[(v * nl + l) * np..(v * nl + l + 1) * np];
                unshifted_ncc(&lum, np, nb.iter().map(|&o| v * nl + o), img, ph, pw, scratch)
            },
        )
        .collect();
    let mut finite: Vec<f32> = unshifted.iter().copied().filter(|x| x.is_finite()).collect();
    if finite.is_empty() {
        return Ok(Vec::new());
    }
    let typical = median(&mut finite);
    let mut dev: Vec<f32> = finite.iter().map(|x| (x - typical).abs()).collect();
    let mad = 1.4826 * median(&mut dev);
    let mut shifts: Vec<(i32, i32)> =
        (-MAX_SHIFT..=MAX_SHIFT).flat_map(|dy| (-MAX_SHIFT..=MAX_SHIFT).map(move |dx| (dy, dx))).collect();
    shifts.sort_by_key(|&(dy, dx)| (dy * dy + dx * dx, dy, dx));
    // The best shift of an image against a reference, and its gain over none.
    let best_shift = |img: &[f32], r: &[f32]| -> (f32, f32, i32, i32) {
        let at0 = ncc(img, r, ph, pw, 0, 0);
        // Nearest shifts first, a farther one taken only when clearly better: a texture that
        // repeats matches several shifts, and the smallest is the move.
        let mut best = (f32::NEG_INFINITY, 0, 0);
        for &(dy, dx) in &shifts {
            let c = ncc(img, r, ph, pw, dy, dx);
            if c > best.0 + 1e-4 {
                best = (c, dy, dx);
            }
        }
        (best.0, best.0 - at0.max(-1.0), best.1, best.2)
    };
    let several_views = nv > 1;
    let moved: Vec<(usize, usize, i32, i32)> = cases
        .par_iter()
        .zip(&unshifted)
        .filter(|(_, &u)| u.is_finite() && u < typical - 6.0 * mad)
        .filter_map(|(&(v, l, nb), _)| {
            let img = &lum[(v * nl + l) * np..(v * nl + l + 1) * np];
            let (m, gain, dy, dx) = best_shift(img, &reference(&light_pairs(v, nb))?);
            if m < MOVED_MATCH || gain < MOVED_GAIN || (dy, dx) == (0, 0) {
                return None;
            }
            if several_views {
                let vp: Vec<usize> = view_nbrs[v].iter().filter(|&&o| present(o, l)).map(|&o| o * nl + l).collect();
                let (m2, gain2, dy2, dx2) = best_shift(img, &reference(&vp)?);
                if m2 < MOVED_MATCH || gain2 < MOVED_GAIN || (dy2, dx2) != (dy, dx) {
                    return None;
                }
            }
            Some((v, l, dy, dx))
        })
        .collect();
    Ok(moved)
}

/// Per colour channel of a row of interleaved RGB values: the sum, the two largest values and
/// the smallest (the screen's gate). A NaN never becomes the top or the lowest and makes the sum
/// NaN: such a row's gate is the floor, and the fit names the value.
struct RowStats {
    sum: [f64; 3],
    top: [f32; 3],
    second: [f32; 3],
    lowest: [f32; 3],
}

impl RowStats {
    fn new() -> Self {
        RowStats {
            sum: [0.0; 3],
            top: [f32::NEG_INFINITY; 3],
            second: [f32::NEG_INFINITY; 3],
            lowest: [f32::INFINITY; 3],
        }
    }
}

crate::simd::by_cpu! {
    /// [`RowStats`] of a row, in the widest vector registers the CPU has: the wheel is built for
    /// the x86-64 baseline, so the AVX2 and AVX-512 forms are compiled apart and chosen at run
    /// time (the same code, [`row_lanes`]).
    fn row_stats(row: &[f32]) -> RowStats {
        ["avx512f"] => row_lanes::<48, true>(row),
        ["avx2"] => row_lanes::<24, true>(row),
        _ => row_lanes::<12, true>(row),
    }
}

crate::simd::by_cpu! {
    /// [`row_stats`] without the second largest values (left at minus infinity): the sums, the
    /// largest and the smallest, the same bits, in three fifths of the work. This loop is the
    /// screen's cost on clean data: a gate that takes the largest value for the second too is
    /// lower than the true gate, so a row under it is under the true one.
    fn row_bounds(row: &[f32]) -> RowStats {
        ["avx512f"] => row_lanes::<48, false>(row),
        ["avx2"] => row_lanes::<24, false>(row),
        _ => row_lanes::<12, false>(row),
    }
}

/// [`RowStats`] in `N` independent lanes, `N` a multiple of 12 (so that lane `k` always holds
/// channel `k % 3`, and the lanes fold to 12), sized to four vector registers per statistic:
/// one pixel at a time is a chain of dependent scalar selects. The lanes' sums are `f32` over
/// at most `nl / 4` values each, then added in `f64`; the two largest of a channel are the
/// two largest of its lanes' two largest.
#[inline(always)]
fn row_lanes<const N: usize, const SECOND: bool>(row: &[f32]) -> RowStats {
    let (mut sum, mut top, mut second, mut lowest) =
        ([0.0f32; N], [f32::NEG_INFINITY; N], [f32::NEG_INFINITY; N], [f32::INFINITY; N]);
    let chunks = row.chunks_exact(N);
    let rest = chunks.remainder();
    for chunk in chunks {
        for k in 0..N {
            let x = chunk[k];
            sum[k] += x;
            if SECOND {
                let m = if x < top[k] { x } else { top[k] };
                second[k] = if m > second[k] { m } else { second[k] };
            }
            top[k] = if x > top[k] { x } else { top[k] };
            lowest[k] = if x < lowest[k] { x } else { lowest[k] };
        }
    }
    for (k, &x) in rest.iter().enumerate() {
        sum[k] += x;
        if SECOND {
            let m = if x < top[k] { x } else { top[k] };
            second[k] = if m > second[k] { m } else { second[k] };
        }
        top[k] = if x > top[k] { x } else { top[k] };
        lowest[k] = if x < lowest[k] { x } else { lowest[k] };
    }
    // Fold the lanes in halves, element by element (in vector registers), down to the three
    // channels: lanes `k` and `k + n / 2` hold the same channel while `n / 2` is a multiple of 3.
    let mut n = N;
    while n > 3 {
        let half = if (n / 2).is_multiple_of(3) { n / 2 } else { 3 };
        for k in 0..n - half {
            let (t, s) = (top[half + k], second[half + k]);
            sum[k] += sum[half + k];
            if SECOND {
                let lo = if t < top[k] { t } else { top[k] };
                let hs = if s > second[k] { s } else { second[k] };
                second[k] = if lo > hs { lo } else { hs };
            }
            top[k] = if t > top[k] { t } else { top[k] };
            lowest[k] = if lowest[half + k] < lowest[k] { lowest[half + k] } else { lowest[k] };
        }
        n -= half;
    }
    let mut st = RowStats::new();
    for c in 0..3 {
        st.sum[c] = sum[c] as f64;
        st.top[c] = top[c];
        st.second[c] = second[c];
        st.lowest[c] = lowest[c];
    }
    st
}

/// The values of `btf` far above both their light and their spatial neighbours (module docs),
/// among the texels of rows `rows` and columns `cols` (the others are only neighbours: a block
/// with its one-texel halo), with `floor` from [`screen_images`]. Flat indices into `btf.data`
/// with their replacements.
pub fn screen_values(
    btf: &BtfRef<'_>,
    floor: f32,
    rows: std::ops::Range<usize>,
    cols: std::ops::Range<usize>,
    monitor: &Monitor,
) -> Result<Flags> {
    let (h, w) = (btf.height, btf.width);
    if rows.end > h || cols.end > w {
        return Err(Error::arg("rows", format!("rows {rows:?} and columns {cols:?} must lie inside {h} x {w}")));
    }
    let judge = ValueScreen::new(btf, floor);
    let found: Vec<Result<Flags>> = rows
        .into_par_iter()
        .map(|r| {
            monitor.check()?;
            let (mut found, mut scratch) = (Vec::new(), Scratch::default());
            for c in cols.clone() {
                judge.flag_texel(r * w + c, &mut scratch, &mut found);
            }
            Ok(found)
        })
        .collect();
    monitor.check()?;
    let mut values = Flags::new();
    for f in found {
        values.extend(f?);
    }
    Ok(values)
}

/// The value screen's judge of one texel at a time (module docs): what [`screen_values`] runs
/// over a block, and what a per-texel fit runs inside its own pass ([`TexelScreen`]).
#[derive(Debug)]
struct ValueScreen<'a> {
    btf: BtfRef<'a>,
    floor: f32,
    /// Per view slot, the present lights with their light neighbours.
    nbrs: Vec<Table>,
}

/// The buffers of [`ValueScreen::flag_texel`], kept across the texels a thread judges (empty
/// until a row needs them).
#[derive(Default)]
struct Scratch {
    /// A value's light neighbours (its texel's, then a spatial neighbour's).
    lights: Vec<f32>,
    neighbour_lights: Vec<f32>,
    /// The spatial neighbours that are not themselves far above their light neighbours.
    spatial: Vec<f32>,
    /// The present values of a row with lights held out.
    present: Vec<f32>,
}

impl<'a> ValueScreen<'a> {
    fn new(btf: &BtfRef<'a>, floor: f32) -> Self {
        ValueScreen { btf: *btf, floor, nbrs: light_tables(btf.lights, btf.mask, btf.views.len()) }
    }

    /// Append the flagged values of texel `t` (flat indices into the data, in increasing order,
    /// with their replacements) to `found`.
    fn flag_texel(&self, t: usize, s: &mut Scratch, found: &mut Flags) {
        let (btf, floor) = (&self.btf, self.floor);
        let (h, w, nv, nl) = (btf.height, btf.width, btf.views.len(), btf.lights.len());
        let abrdf = nv * nl * 3;
        let (r, c0) = (t / w, t % w);
        let at = |t: usize, v: usize, l: usize, c: usize| btf.data[t * abrdf + (v * nl + l) * 3 + c];
        // Whether value (t, v, l, c) = x is more than FACTOR times above its light neighbours'
        // median, and that median. The minimum bounds the median from below, so most values are
        // cleared by the minimum alone, without a selection.
        let above_lights = |t: usize, v: usize, nb: &[usize], c: usize, x: f32, buf: &mut Vec<f32>| -> Option<f32> {
            let base = t * abrdf + v * nl * 3 + c;
            let lowest = nb.iter().map(|&o| btf.data[base + o * 3]).fold(f32::INFINITY, f32::min);
            // (A NaN is never above: it is left for the fit to name.)
            if x.partial_cmp(&(FACTOR * lowest + floor)) != Some(std::cmp::Ordering::Greater) {
                return None;
            }
            buf.clear();
            buf.extend(nb.iter().map(|&o| btf.data[base + o * 3]));
            let md = median(buf);
            // (Signed data, a PTM's or noise's negative values: a negative median is no scale.)
            (x > FACTOR * md.max(0.0) + floor).then_some(md)
        };
        for (v, per) in self.nbrs.iter().enumerate() {
            if per.len() <= 2 {
                continue;
            }
            let row = &btf.data[t * abrdf + v * nl * 3..t * abrdf + (v + 1) * nl * 3];
            // First the gate: 8 times the mean of the texel's row of lights per channel without
            // its two largest values (so that two hot values in a row do not raise it). A value
            // below the gate cannot wreck a fit; the few above it (highlights, mostly) are the
            // only ones compared with their neighbours. (All three channels in one pass over the
            // row: this loop is the screen's cost on clean data. A row with lights held out, as
            // every row of a split BTF, has its present values gathered first, so that they too
            // are read in vector lanes.)
            let values: &[f32] = if per.len() == nl {
                row
            } else {
                s.present.clear();
                s.present.extend(per.iter().flat_map(|(l, _)| &row[l * 3..l * 3 + 3]));
                &s.present
            };
            // A row with values below -floor is not radiance (data made from a model's random
            // coefficients, a difference of images): "8 times its neighbours" means nothing
            // there, and the row is not screened.
            let gate_of = |st: &RowStats, second: [f32; 3]| -> [f32; 3] {
                std::array::from_fn(|c| {
                    let trimmed = (st.sum[c] - st.top[c] as f64 - second[c] as f64) / (per.len() - 2) as f64;
                    if st.lowest[c] < -floor {
                        f32::INFINITY
                    } else {
                        FACTOR * trimmed.max(0.0) as f32 + floor
                    }
                })
            };
            let under = |top: &[f32; 3], gate: &[f32; 3]| {
                (0..3).all(|c| top[c].partial_cmp(&gate[c]) != Some(std::cmp::Ordering::Greater))
            };
            // Nothing in the row above its gate: the common case, one comparison per channel,
            // first against the lower gate of the largest value taken twice (no second largest
            // to track: the same sums in fewer operations; every step of the gate is monotonic,
            // so a row under it is under the true gate).
            let bounds = row_bounds(values);
            if under(&bounds.top, &gate_of(&bounds, bounds.top)) {
                continue;
            }
            let st = row_stats(values);
            let gate = gate_of(&st, st.second);
            if under(&st.top, &gate) {
                continue;
            }
            for (l, nb) in per.iter() {
                if nb.is_empty() {
                    continue;
                }
                for (c, g) in gate.iter().enumerate() {
                    let x = row[l * 3 + c];
                    if x.partial_cmp(g) != Some(std::cmp::Ordering::Greater) {
                        continue;
                    }
                    let Some(md) = above_lights(t, v, nb, c, x, &mut s.lights) else {
                        continue;
                    };
                    // The spatial neighbours, but for those that are themselves far above their
                    // light neighbours: at 1% of the values hot, some texel has half its
                    // neighbours hot at the same pair somewhere.
                    s.spatial.clear();
                    for dr in [-1i64, 0, 1] {
                        for dc in [-1i64, 0, 1] {
                            let (rr, cc) = (r as i64 + dr, c0 as i64 + dc);
                            if (dr, dc) == (0, 0) || rr < 0 || cc < 0 || rr as usize >= h || cc as usize >= w {
                                continue;
                            }
                            let tn = rr as usize * w + cc as usize;
                            let y = at(tn, v, *l, c);
                            if above_lights(tn, v, nb, c, y, &mut s.neighbour_lights).is_none() {
                                s.spatial.push(y);
                            }
                        }
                    }
                    let ms = if s.spatial.is_empty() { 0.0 } else { median(&mut s.spatial) };
                    if x > FACTOR * ms.max(0.0) + floor {
                        found.push((t * abrdf + (v * nl + l) * 3 + c, md));
                    }
                }
            }
        }
    }
}

/// The value screen inside a fit's own pass over the texels, for the models whose texels are
/// fitted apart (PTM, HSH) or read once into the fit's own copy (neural:
/// [`crate::Model::SCREENS_TEXELS`]). A separate screen reads every
/// value once more before the fit (a third of a small PTM fit's time and more); here each
/// texel is judged while the fit has its values in cache, and a texel with flagged values is
/// fitted from a repaired copy of its ABRDF, which is what the fit of a repaired copy of the
/// whole data does to that texel. The values flagged are collected for the report.
#[derive(Debug)]
pub struct TexelScreen<'a> {
    judge: ValueScreen<'a>,
    found: std::sync::Mutex<Flags>,
}

impl<'a> TexelScreen<'a> {
    /// The screen of the values of `btf` (its values and mask: those judged, which a fit that
    /// leaves out bad images does not share) with the `floor` of [`screen_images`].
    pub fn new(btf: &BtfRef<'a>, floor: f32) -> Self {
        TexelScreen { judge: ValueScreen::new(btf, floor), found: std::sync::Mutex::new(Flags::new()) }
    }

    /// Texel `t`'s ABRDF (`values`, as the fit reads it) with its flagged values replaced, or
    /// `None` when none is flagged (the common case: no copy).
    pub fn repaired(&self, t: usize, values: &[f32]) -> Option<Vec<f32>> {
        let mut flags = Flags::new();
        self.judge.flag_texel(t, &mut Scratch::default(), &mut flags);
        if flags.is_empty() {
            return None;
        }
        let base = t * values.len();
        let mut fixed = values.to_vec();
        for &(i, x) in &flags {
            fixed[i - base] = x;
        }
        self.found.lock().unwrap_or_else(|e| e.into_inner()).extend(flags);
        Some(fixed)
    }

    /// Every value flagged, in increasing index (as [`screen_values`] lists them), each once
    /// (a fit may read a texel twice: the neural fit's sample, then its encoding pass).
    pub fn into_flags(self) -> Flags {
        let mut f = self.found.into_inner().unwrap_or_else(|e| e.into_inner());
        f.sort_unstable_by_key(|x| x.0);
        f.dedup_by_key(|x| x.0);
        f
    }
}

/// Screen `btf`'s present values (module docs).
pub fn screen(btf: &BtfRef<'_>, monitor: &Monitor) -> Result<Screen> {
    let sampled = sample_texels(btf.height, btf.width);
    let im = screen_images(btf.views, btf.lights, btf.mask, btf.data, &sampled)?;
    let window = patch_window(btf.height, btf.width);
    let moved = moved_images(btf.views, btf.lights, btf.mask, btf.data, btf.width, window)?;
    monitor.check()?;
    let values = screen_values(btf, im.floor, 0..btf.height, 0..btf.width, monitor)?;
    Ok(Screen::new(values, im, moved))
}

impl Screen {
    /// The screen's parts as one: the moved images join the bad images.
    pub fn new(values: Flags, images: Images, moved: Vec<(usize, usize, i32, i32)>) -> Screen {
        let mut bad = images.bad_images;
        bad.extend(moved.iter().map(|m| (m.0, m.1)));
        bad.sort_unstable();
        bad.dedup();
        Screen { values, spread: images.spread, bad_images: bad, floor: images.floor, moved }
    }

    /// The report of a robust fit: how many values were replaced, the texels and pairs with the
    /// most (so a bad image or a bad patch of the sensor can be found), and the bad images.
    pub fn report(&self, btf: &BtfRef<'_>, replaced: bool, excluded: bool) -> Value {
        self.report_for([btf.height, btf.width, btf.views.len(), btf.lights.len()], btf.mask, replaced, excluded)
    }

    /// [`Screen::report`] for a BTF of `[height, width, views, lights]` with `mask` (a
    /// blockwise fit, which holds no whole BTF).
    pub fn report_for(&self, dims: [usize; 4], mask: Option<&[bool]>, replaced: bool, excluded: bool) -> Value {
        let [height, w, nv, nl] = dims;
        let abrdf = nv * nl * 3;
        let mut by_texel = std::collections::BTreeMap::<usize, u64>::new();
        let mut by_pair = std::collections::BTreeMap::<usize, u64>::new();
        for &(i, _) in &self.values {
            *by_texel.entry(i / abrdf).or_default() += 1;
            *by_pair.entry((i % abrdf) / 3).or_default() += 1;
        }
        let top = |m: std::collections::BTreeMap<usize, u64>| {
            let mut v: Vec<(usize, u64)> = m.into_iter().collect();
            v.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
            v.truncate(10);
            v
        };
        let present = mask.map_or(nv * nl, |m| m.iter().filter(|&&x| x).count()) * height * w * 3;
        json!({
            "values_flagged": self.values.len(),
            "fraction_flagged": self.values.len() as f64 / present.max(1) as f64,
            "values_replaced": if replaced { self.values.len() } else { 0 },
            "top_texels": top(by_texel).iter().map(|&(t, n)| json!({"row": t / w, "col": t % w, "values": n})).collect::<Vec<_>>(),
            "top_pairs": top(by_pair).iter().map(|&(p, n)| json!({"view": p / nl, "light": p % nl, "values": n})).collect::<Vec<_>>(),
            "bad_images": self.bad_images.iter().map(|&(v, l)| {
                let mut e = json!({"view": v, "light": l, "spread": self.spread[v * nl + l]});
                if let Some(m) = self.moved.iter().find(|m| (m.0, m.1) == (v, l)) {
                    e["moved"] = json!([m.2, m.3]);
                }
                e
            }).collect::<Vec<_>>(),
            "bad_images_excluded": excluded && !self.bad_images.is_empty(),
        })
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// The nearest directions against a full sort of every candidate, with ties (repeated
    /// directions) broken by index, for k from 0 to all of them.
    #[test]
    fn nearest_equals_the_first_of_a_full_sort() {
        let mut rng = btfrs_core::rng::Rng::new(3);
        let mut dirs: Vec<[f64; 3]> = (0..40)
            .map(|_| {
                let (x, y) = (rng.next_f64() - 0.5, rng.next_f64() - 0.5);
                [x, y, (1.0 - x * x - y * y).sqrt()]
            })
            .collect();
        dirs.extend_from_within(..10);
        let among: Vec<usize> = (0..dirs.len()).filter(|i| i % 7 != 3).collect();
        for of in [0, 5, 12, 44] {
            let a = dirs[of];
            let mut all: Vec<(f64, usize)> = among
                .iter()
                .filter(|&&o| o != of)
                .map(|&o| (-(a[0] * dirs[o][0] + a[1] * dirs[o][1] + a[2] * dirs[o][2]), o))
                .collect();
            all.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
            for k in [0, 1, 4, 8, all.len() - 1, all.len(), all.len() + 3] {
                let want: Vec<usize> = all.iter().take(k).map(|x| x.1).collect();
                assert_eq!(nearest(&dirs, of, &among, k), want, "of {of}, k {k}");
            }
        }
    }

    /// The median against a full sort, for lengths on both sides of the insertion sort's limit,
    /// with negative values, signed zeros and ties; the values come back (in some order).
    #[test]
    fn median_equals_the_middle_of_a_sort() {
        let mut rng = btfrs_core::rng::Rng::new(3);
        for n in 1..=80usize {
            let v: Vec<f32> = (0..n)
                .map(|i| {
                    let u = rng.next_f64() as f32 - 0.5;
                    match i % 9 {
                        0 => -0.0,
                        1 => 0.0,
                        2 => 0.125,
                        _ => u * 1e3,
                    }
                })
                .collect();
            let mut sorted = v.clone();
            sorted.sort_by(f32::total_cmp);
            let want = if n % 2 == 1 { sorted[n / 2] } else { 0.5 * (sorted[n / 2 - 1] + sorted[n / 2]) };
            let mut w = v.clone();
            assert_eq!(median(&mut w).to_bits(), want.to_bits(), "n {n}");
            w.sort_by(f32::total_cmp);
            assert!(w.iter().zip(&sorted).all(|(a, b)| a.to_bits() == b.to_bits()), "n {n}: values changed");
        }
    }

    /// The lanes' statistics, in every lane count and in the form this CPU runs, equal a plain
    /// pass in f64 over every pixel (the sums to f32 rounding): rows of every length up to 100
    /// pixels, with ties, negative values and values far above the rest.
    #[test]
    fn row_statistics_in_lanes_equal_a_plain_pass() {
        let mut rng = btfrs_core::rng::Rng::new(5);
        for n in 1..=100 {
            let row: Vec<f32> = (0..3 * n)
                .map(|i| {
                    let u = rng.next_f64() as f32;
                    if i % 17 == 4 {
                        1000.0 * u
                    } else if i % 5 == 0 {
                        0.25
                    } else {
                        u - 0.1
                    }
                })
                .collect();
            let full = [
                row_stats(&row),
                row_lanes::<12, true>(&row),
                row_lanes::<24, true>(&row),
                row_lanes::<48, true>(&row),
            ];
            let bounds = [
                row_bounds(&row),
                row_lanes::<12, false>(&row),
                row_lanes::<24, false>(&row),
                row_lanes::<48, false>(&row),
            ];
            // Without the second largest: the same bits for the rest (the gate's order relies on it).
            for (b, f) in bounds.iter().zip(&full) {
                assert!(b.sum == f.sum && b.top == f.top && b.lowest == f.lowest, "n {n}");
                assert_eq!(b.second, [f32::NEG_INFINITY; 3]);
            }
            for st in full {
                for c in 0..3 {
                    let mut v: Vec<f32> = row.iter().skip(c).step_by(3).copied().collect();
                    let sum: f64 = v.iter().map(|&y| y as f64).sum();
                    v.sort_by(|a, b| b.total_cmp(a));
                    assert!((st.sum[c] - sum).abs() <= 1e-6 * v.iter().map(|y| y.abs() as f64).sum::<f64>(), "n {n}");
                    assert_eq!(st.top[c], v[0], "n {n} channel {c}");
                    assert_eq!(st.second[c], if n > 1 { v[1] } else { f32::NEG_INFINITY }, "n {n} channel {c}");
                    assert_eq!(st.lowest[c], v[v.len() - 1], "n {n} channel {c}");
                }
            }
        }
    }

    /// A Lambertian sample of `h x w` texels of random albedo under `nv` views and `nl` lights
    /// (also the driver's tests' sample).
    pub(crate) fn lambert(h: usize, w: usize, nv: usize, nl: usize) -> (Vec<[f64; 3]>, Vec<[f64; 3]>, Vec<f32>) {
        let dirs = |n: usize, s: f64| -> Vec<[f64; 3]> {
            (0..n)
                .map(|i| {
                    let th = 0.2 + 1.0 * ((i as f64 * 0.618 + s) % 1.0);
                    let ph = i as f64 * 2.399;
                    [th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()]
                })
                .collect()
        };
        let (views, lights) = (dirs(nv, 0.1), dirs(nl, 0.3));
        let mut data = Vec::with_capacity(h * w * nv * nl * 3);
        for t in 0..h * w {
            // (A texture that does not repeat: a moved image has one shift that fits.)
            let mut x = t as u64 + 1;
            x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            let albedo = 0.3 + 0.5 * ((x ^ (x >> 31)) % 1000) as f32 / 1000.0;
            for _ in 0..nv {
                for l in &lights {
                    let x = albedo * l[2] as f32;
                    data.extend([x, 0.8 * x, 0.6 * x]);
                }
            }
        }
        (views, lights, data)
    }

    #[test]
    fn hot_values_are_found_and_clean_values_kept() {
        let (h, w, nv, nl) = (8, 9, 2, 40);
        let (views, lights, mut data) = lambert(h, w, nv, nl);
        let clean = data.clone();
        let b = BtfRef::new(h, w, &views, &lights, &data, None).unwrap();
        let sc = screen(&b, &Monitor::new()).unwrap();
        assert!(sc.values.is_empty() && sc.bad_images.is_empty(), "{:?}", sc.bad_images);
        let hot = [5usize, 1000, 4321, data.len() - 1];
        for &i in &hot {
            data[i] *= 1000.0;
        }
        let b = BtfRef::new(h, w, &views, &lights, &data, None).unwrap();
        assert_flags_exactly(&b, &hot, &clean);
    }

    /// The screen of `b` flags exactly the values at `hot`, each replaced by its light
    /// neighbours' median: near the `clean` value on a smooth BRDF.
    fn assert_flags_exactly(b: &BtfRef<'_>, hot: &[usize], clean: &[f32]) {
        let sc = screen(b, &Monitor::new()).unwrap();
        let mut got: Vec<usize> = sc.values.iter().map(|v| v.0).collect();
        got.sort();
        assert_eq!(got, hot);
        for &(i, x) in &sc.values {
            assert!((x - clean[i]).abs() <= 0.25 * clean[i] + 1e-6, "{i}: {x} vs {}", clean[i]);
        }
    }

    /// With pairs held out (every row of lights incomplete, as in a split BTF, so the gate's
    /// statistics come from the gathered present values): the hot values at present pairs are
    /// found, and one at an absent pair is not (it was not measured).
    #[test]
    fn hot_values_are_found_with_lights_held_out() {
        let (h, w, nv, nl) = (8, 9, 2, 40);
        let (views, lights, mut data) = lambert(h, w, nv, nl);
        let clean = data.clone();
        let abrdf = nv * nl * 3;
        let mut mask: Vec<bool> = (0..nv * nl).map(|i| i % 7 != 3).collect();
        let at = |t: usize, v: usize, l: usize, c: usize| t * abrdf + (v * nl + l) * 3 + c;
        let hot = [at(0, 0, 1, 2), at(13, 1, 20, 0), at(40, 0, 39, 1), at(71, 1, 0, 2)];
        let absent = at(20, 0, 10, 0);
        mask[10] = false;
        assert!(hot.iter().all(|&i| mask[(i % abrdf) / 3]));
        for &i in hot.iter().chain([&absent]) {
            data[i] *= 1000.0;
        }
        let b = BtfRef::new(h, w, &views, &lights, &data, Some(&mask)).unwrap();
        assert_flags_exactly(&b, &hot, &clean);
    }

    #[test]
    fn a_block_with_its_halo_flags_what_the_whole_flags() {
        let (h, w, nv, nl) = (9, 10, 2, 30);
        let (views, lights, mut data) = lambert(h, w, nv, nl);
        let abrdf = nv * nl * 3;
        // Hot values on a block's edge and beside it, where the halo decides.
        for &(t, k) in &[(3 * w + 4, 7), (3 * w + 5, 7), (4 * w + 4, 100), (0, 3), (8 * w + 9, 50)] {
            data[t * abrdf + k] *= 1000.0;
        }
        let b = BtfRef::new(h, w, &views, &lights, &data, None).unwrap();
        let whole = screen(&b, &Monitor::new()).unwrap();
        assert_eq!(whole.values.len(), 5);
        let mut got = Vec::new();
        for (r0, r1) in [(0, 4), (4, 9)] {
            for (c0, c1) in [(0, 5), (5, 10)] {
                // The block and its one-texel halo, as btfrs.dask's overlap hands it over.
                let (hr0, hr1, hc0, hc1) = (r0.max(1) - 1, (r1 + 1).min(h), c0.max(1) - 1, (c1 + 1).min(w));
                let (bh, bw) = (hr1 - hr0, hc1 - hc0);
                let mut blk = Vec::with_capacity(bh * bw * abrdf);
                for r in hr0..hr1 {
                    blk.extend_from_slice(&data[(r * w + hc0) * abrdf..(r * w + hc1) * abrdf]);
                }
                let bb = BtfRef::new(bh, bw, &views, &lights, &blk, None).unwrap();
                let f =
                    screen_values(&bb, whole.floor, r0 - hr0..r1 - hr0, c0 - hc0..c1 - hc0, &Monitor::new()).unwrap();
                for (i, x) in f {
                    let (t, k) = (i / abrdf, i % abrdf);
                    got.push((((hr0 + t / bw) * w + hc0 + t % bw) * abrdf + k, x));
                }
            }
        }
        got.sort_by_key(|v| v.0);
        let mut want = whole.values.clone();
        want.sort_by_key(|v| v.0);
        assert_eq!(got, want);
    }

    #[test]
    fn a_moved_image_is_found_with_its_shift() {
        let (h, w, nv, nl) = (20, 20, 2, 30);
        let (views, lights, mut data) = lambert(h, w, nv, nl);
        let abrdf = nv * nl * 3;
        let b = BtfRef::new(h, w, &views, &lights, &data, None).unwrap();
        assert!(screen(&b, &Monitor::new()).unwrap().moved.is_empty());
        // Image (1, 7) rolled 3 texels to the right and 2 up.
        let pair = (nl + 7) * 3;
        let before = data.clone();
        for r in 0..h {
            for c in 0..w {
                let from = ((r + 2) % h) * w + (c + w - 3) % w;
                for k in 0..3 {
                    data[(r * w + c) * abrdf + pair + k] = before[from * abrdf + pair + k];
                }
            }
        }
        let b = BtfRef::new(h, w, &views, &lights, &data, None).unwrap();
        let sc = screen(&b, &Monitor::new()).unwrap();
        assert_eq!(sc.moved, vec![(1, 7, -2, 3)]);
        assert_eq!(sc.bad_images, vec![(1, 7)]);
        assert_eq!(sc.report(&b, true, false)["bad_images"][0]["moved"], json!([-2, 3]));
    }

    #[test]
    fn a_misfired_flash_is_a_bad_image() {
        let (h, w, nv, nl) = (6, 6, 1, 30);
        let (views, lights, mut data) = lambert(h, w, nv, nl);
        let abrdf = nv * nl * 3;
        for t in 0..h * w {
            for c in 0..3 {
                data[t * abrdf + 7 * 3 + c] *= 0.2;
            }
        }
        let b = BtfRef::new(h, w, &views, &lights, &data, None).unwrap();
        let sc = screen(&b, &Monitor::new()).unwrap();
        assert_eq!(sc.bad_images, vec![(0, 7)]);
        assert!(sc.values.is_empty());
    }
}
