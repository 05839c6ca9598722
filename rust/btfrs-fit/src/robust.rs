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
//! are cleared by one comparison). A value above `FACTOR = 8` times the larger of the two medians
//! (plus 5% of the data's mean, so that noise in the dark is not flagged) is inconsistent with
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
//! **Bad images.** For every (view, light) pair the median over 64 texels (an 8 x 8 grid) of
//! `|ln((x + a) / (m + a))|`, the log ratio of the image's luminance to its light neighbours'
//! (`m`: their mean without the smallest and the largest, so one bad neighbour moves it little),
//! is its *spread*; the same against the same light seen from the 4 nearest views is its view
//! spread. An image whose spreads both exceed `ln 2` and 6 robust standard deviations (1.4826
//! median absolute deviations) above the typical spread of all images is reported with its pair
//! (an image near the horizon is far from its light neighbours, all on one side of it, but not
//! from its view neighbours). A misfired flash changes every
//! texel's ratio; a moved sample scrambles a textured image against its neighbours. With
//! `exclude_bad_images` those pairs are left out of the fit (masked), as if not measured.

use crate::options::Spec;
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
/// Texels sampled (an 8 x 8 grid) for the images' spreads and the data's mean: the spreads are medians over them, and 64 keep that cost under a third of a one-pass fit.
const SAMPLE_TEXELS: usize = 64;

/// The robust options every fit takes besides its own (one source: the Python signatures, the
/// CLI and the docs are generated from them).
pub const OPTIONS: &[Spec] = &[
    Spec::bool(
        "robust",
        false,
        "screen the values for outliers (hot pixels, dust, glints) before fitting, replacing those \
         far above both their light and their spatial neighbours; false: fit every value as it is",
    ),
    Spec::bool(
        "exclude_bad_images",
        false,
        "leave out of the fit the whole images found far from their light neighbours (a misfired \
         flash, a moved sample); they are reported either way",
    ),
];

/// [`OPTIONS`] as a struct.
#[derive(Debug, Clone, Copy, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RobustOptions {
    /// Screen and repair outliers.
    pub robust: bool,
    /// Mask the bad images out of the fit.
    pub exclude_bad_images: bool,
}

impl Default for RobustOptions {
    fn default() -> Self {
        crate::options::build(OPTIONS, serde_json::Map::new()).expect("the schema's defaults build")
    }
}

/// Flat indices into the data, with replacement values.
type Flags = Vec<(usize, f32)>;

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
    by.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
    by.into_iter().take(k).map(|(_, o)| o).collect()
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
    let (lo, mid, _) = v.select_nth_unstable_by(n / 2, f32::total_cmp);
    let hi = *mid;
    if n % 2 == 1 {
        hi
    } else {
        let lo_max = lo.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        0.5 * (lo_max + hi)
    }
}

/// Screen `btf`'s present values (module docs).
pub fn screen(btf: &BtfRef<'_>, monitor: &Monitor) -> Result<Screen> {
    let (h, w, nv, nl) = (btf.height, btf.width, btf.views.len(), btf.lights.len());
    let abrdf = nv * nl * 3;
    let present = |v: usize, l: usize| btf.mask.is_none_or(|m| m[v * nl + l]);
    // Per view: its present lights and each one's nearest present lights (in parallel; views
    // with the same present lights, all of them without a mask, share one table).
    type Table = std::sync::Arc<Vec<(usize, Vec<usize>)>>;
    let table = |ls: &[usize]| -> Vec<(usize, Vec<usize>)> {
        let k = NEIGHBOURS.min(ls.len().saturating_sub(1));
        ls.par_iter().map(|&l| (l, nearest(btf.lights, l, ls, k))).collect()
    };
    let mut seen: std::collections::HashMap<Vec<usize>, Table> = std::collections::HashMap::new();
    let mut nbrs: Vec<Table> = Vec::with_capacity(nv);
    for v in 0..nv {
        let ls: Vec<usize> = (0..nl).filter(|&l| present(v, l)).collect();
        let t = match seen.get(&ls) {
            Some(t) => t.clone(),
            None => {
                let t: Table = std::sync::Arc::new(table(&ls));
                seen.insert(ls, t.clone());
                t
            }
        };
        nbrs.push(t);
    }
    // The sampled texels: a grid of at most SAMPLE_TEXELS spread over the sample (every texel of
    // a small one).
    let (gr, gc) = {
        let side = (SAMPLE_TEXELS as f64).sqrt() as usize;
        (side.min(h), side.min(w))
    };
    let sampled: Vec<usize> = (0..gr)
        .flat_map(|i| (0..gc).map(move |j| ((2 * i + 1) * h / (2 * gr)) * w + (2 * j + 1) * w / (2 * gc)))
        .collect();
    // The data's mean over the sampled texels' present values: the scale of the floor.
    let (sum, count) = sampled
        .par_iter()
        .map(|&t| {
            let mut s = 0.0f64;
            let mut n = 0u64;
            for (v, per) in nbrs.iter().enumerate() {
                for (l, _) in per.iter() {
                    let o = t * abrdf + (v * nl + l) * 3;
                    s += btf.data[o..o + 3].iter().map(|&x| x as f64).sum::<f64>();
                    n += 3;
                }
            }
            (s, n)
        })
        .reduce(|| (0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    let floor = (FLOOR as f64 * sum / (count.max(1) as f64)).max(1e-30) as f32;
    monitor.check()?;
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
        (x > FACTOR * md + floor).then_some(md)
    };
    let rows: Vec<Flags> = (0..h)
        .into_par_iter()
        .map(|r| {
            let mut found = Vec::new();
            let (mut b1, mut b2, mut b3) =
                (Vec::with_capacity(NEIGHBOURS), Vec::with_capacity(8), Vec::with_capacity(NEIGHBOURS));
            for c0 in 0..w {
                let t = r * w + c0;
                for (v, per) in nbrs.iter().enumerate() {
                    if per.len() <= 2 {
                        continue;
                    }
                    let row = &btf.data[t * abrdf + v * nl * 3..t * abrdf + (v + 1) * nl * 3];
                    // First the gate: 8 times the mean of the texel's row of lights per channel
                    // without its two largest values (so that two hot values in a row do not
                    // raise it). A value below the gate cannot wreck a fit; the few above it
                    // (highlights, mostly) are the only ones compared with their neighbours.
                    // (All three channels in one pass over the row: this loop is the screen's
                    // cost on clean data.)
                    let (mut sum, mut top, mut second) = ([0.0f64; 3], [f32::NEG_INFINITY; 3], [f32::NEG_INFINITY; 3]);
                    let mut add = |px: &[f32]| {
                        for c in 0..3 {
                            // (Branch-free: the two largest by max/min.)
                            let x = px[c];
                            sum[c] += x as f64;
                            second[c] = second[c].max(top[c].min(x));
                            top[c] = top[c].max(x);
                        }
                    };
                    if per.len() == nl {
                        row.chunks_exact(3).for_each(&mut add);
                    } else {
                        per.iter().for_each(|(l, _)| add(&row[l * 3..l * 3 + 3]));
                    }
                    let gate: [f32; 3] = std::array::from_fn(|c| {
                        let trimmed = (sum[c] - top[c] as f64 - second[c] as f64) / (per.len() - 2) as f64;
                        FACTOR * trimmed.max(0.0) as f32 + floor
                    });
                    // Nothing in the row above its gate: the common case, one comparison per
                    // channel.
                    if (0..3).all(|c| top[c].partial_cmp(&gate[c]) != Some(std::cmp::Ordering::Greater)) {
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
                            let Some(md) = above_lights(t, v, nb, c, x, &mut b1) else {
                                continue;
                            };
                            // The spatial neighbours, but for those that are themselves far
                            // above their light neighbours: at 1% of the values hot, some
                            // texel has half its neighbours hot at the same pair somewhere.
                            b2.clear();
                            for dr in [-1i64, 0, 1] {
                                for dc in [-1i64, 0, 1] {
                                    let (rr, cc) = (r as i64 + dr, c0 as i64 + dc);
                                    if (dr, dc) == (0, 0) || rr < 0 || cc < 0 || rr as usize >= h || cc as usize >= w {
                                        continue;
                                    }
                                    let tn = rr as usize * w + cc as usize;
                                    let y = at(tn, v, *l, c);
                                    if above_lights(tn, v, nb, c, y, &mut b3).is_none() {
                                        b2.push(y);
                                    }
                                }
                            }
                            let ms = if b2.is_empty() { 0.0 } else { median(&mut b2) };
                            if x > FACTOR * ms + floor {
                                found.push((t * abrdf + (v * nl + l) * 3 + c, md));
                            }
                        }
                    }
                }
            }
            found
        })
        .collect();
    monitor.check()?;
    let values: Flags = rows.into_iter().flatten().collect();
    // Each image's spreads against its light neighbours (same view) and its view neighbours
    // (same light), over the sampled texels (luminance). A bad image is far from both; an image
    // near the horizon is far from its light neighbours (all on one side of it) but not from
    // the same light seen from the views beside it.
    // Texel-major: one sampled texel's luminances for every pair (its ABRDF, read once), then
    // each pair's ratios to its neighbours from that small table.
    let all_views: Vec<usize> = (0..nv).collect();
    let view_nbrs: Vec<Vec<usize>> = (0..nv).map(|v| nearest(btf.views, v, &all_views, VIEW_NEIGHBOURS)).collect();
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
    let ns = sampled.len();
    let npairs = nv * nl;
    let by_texel: Vec<f32> = sampled
        .par_iter()
        .flat_map_iter(|&t| btf.data[t * abrdf..(t + 1) * abrdf].chunks_exact(3).map(|p| (p[0] + p[1] + p[2]) / 3.0))
        .collect();
    let mut lum = vec![0.0f32; npairs * ns];
    lum.par_chunks_mut(64 * ns).enumerate().for_each(|(blk, out)| {
        for (i, row) in out.chunks_exact_mut(ns).enumerate() {
            let p = blk * 64 + i;
            for (k, y) in row.iter_mut().enumerate() {
                *y = by_texel[k * npairs + p];
            }
        }
    });
    drop(by_texel);
    let per_pair: Vec<(usize, f32, f32)> = flat
        .par_iter()
        .map(|(p, nlt, nvw, nb)| {
            let (p, nlt, nvw) = (*p as usize, *nlt as usize, *nvw as usize);
            let x = &lum[p * ns..(p + 1) * ns];
            let (mut sum, mut lo, mut hi, mut d) =
                (vec![0.0f32; ns], vec![0.0f32; ns], vec![0.0f32; ns], vec![0.0f32; ns]);
            let mut spread = |from: usize, n: usize| -> f32 {
                if n < 2 {
                    return f32::NAN;
                }
                // Per texel the neighbours' mean without their smallest and largest (one bad
                // neighbour moves it little, and it runs across the texels in lockstep, where
                // a median per texel would not), the ratio's magnitude, and its log once per
                // pair, after the median over texels.
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
                for ((((d, s), l), h), &y) in d.iter_mut().zip(&sum).zip(&lo).zip(&hi).zip(x) {
                    let m = (s - drop2 * (l + h)) / keep + floor;
                    let y = y + floor;
                    *d = if y > m { y / m } else { m / y };
                }
                median(&mut d).ln()
            };
            (p, spread(0, nlt), spread(nlt, nvw))
        })
        .collect();
    let mut spread = vec![f32::NAN; nv * nl];
    let mut spread_view = vec![f32::NAN; nv * nl];
    for (i, a, b) in per_pair {
        spread[i] = a;
        spread_view[i] = b;
    }
    // Far: above `least` and 6 robust standard deviations above the typical spread.
    let far = |sp: &[f32], least: f32| -> Vec<bool> {
        let mut all: Vec<f32> = sp.iter().copied().filter(|s| s.is_finite()).collect();
        let typical = median(&mut all);
        let mut dev: Vec<f32> = all.iter().map(|s| (s - typical).abs()).collect();
        let mad = 1.4826 * median(&mut dev);
        sp.iter().map(|&s| s.is_finite() && s > least && s > typical + 6.0 * mad).collect()
    };
    let several_views = spread_view.iter().any(|s| s.is_finite());
    let by_light = far(&spread, if several_views { std::f32::consts::LN_2 } else { ONE_VIEW_LEAST });
    let by_view = far(&spread_view, std::f32::consts::LN_2);
    let bad_images = (0..nv * nl)
        .filter(|&i| by_light[i] && (by_view[i] || !spread_view[i].is_finite() && !several_views))
        .map(|i| (i / nl, i % nl))
        .collect();
    Ok(Screen { values, spread, bad_images, floor })
}

impl Screen {
    /// The report of a robust fit: how many values were replaced, the texels and pairs with the
    /// most (so a bad image or a bad patch of the sensor can be found), and the bad images.
    pub fn report(&self, btf: &BtfRef<'_>, replaced: bool, excluded: bool) -> Value {
        let (w, nv, nl) = (btf.width, btf.views.len(), btf.lights.len());
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
        let present = btf.mask.map_or(nv * nl, |m| m.iter().filter(|&&x| x).count()) * btf.height * w * 3;
        json!({
            "values_flagged": self.values.len(),
            "fraction_flagged": self.values.len() as f64 / present.max(1) as f64,
            "values_replaced": if replaced { self.values.len() } else { 0 },
            "top_texels": top(by_texel).iter().map(|&(t, n)| json!({"row": t / w, "col": t % w, "values": n})).collect::<Vec<_>>(),
            "top_pairs": top(by_pair).iter().map(|&(p, n)| json!({"view": p / nl, "light": p % nl, "values": n})).collect::<Vec<_>>(),
            "bad_images": self.bad_images.iter().map(|&(v, l)| json!({"view": v, "light": l, "spread": self.spread[v * nl + l]})).collect::<Vec<_>>(),
            "bad_images_excluded": excluded && !self.bad_images.is_empty(),
        })
    }
}

/// Fit model `kind` with its options (a JSON object) robustly: screen, repair the flagged
/// values in a copy, optionally mask the bad images, fit. Returns the model and the robust
/// report (`Null` with `robust = false`).
pub fn fit(
    entry: &crate::registry::Entry,
    btf: &BtfRef<'_>,
    options: &str,
    robust: RobustOptions,
    monitor: &Monitor,
) -> Result<(Box<dyn crate::model::DynModel>, Value)> {
    if !robust.robust && !robust.exclude_bad_images {
        return Ok(((entry.fit)(btf, options, monitor)?, Value::Null));
    }
    let sc = screen(btf, monitor)?;
    let mut mask_owned: Option<Vec<bool>> = None;
    if robust.exclude_bad_images && !sc.bad_images.is_empty() {
        let nl = btf.lights.len();
        let mut m = btf.mask.map_or_else(|| vec![true; btf.views.len() * nl], <[bool]>::to_vec);
        for &(v, l) in &sc.bad_images {
            m[v * nl + l] = false;
        }
        if !m.iter().any(|&x| x) {
            return Err(Error::arg("exclude_bad_images", "every image was found bad; nothing is left to fit"));
        }
        mask_owned = Some(m);
    }
    // Out of core: a repaired copy that does not fit the memory limit is not made; the values
    // found are reported (`repaired: false`, with the reason) and the fit sees them as measured.
    let too_big =
        robust.robust && monitor.memory_limit().is_some_and(|limit| std::mem::size_of_val(btf.data) as u64 > limit);
    let repaired = |sc: &Screen| -> Option<Vec<f32>> {
        if !robust.robust || too_big || sc.values.is_empty() {
            return None;
        }
        let mut d = btf.data.to_vec();
        for &(i, x) in &sc.values {
            d[i] = x;
        }
        Some(d)
    };
    let mask = mask_owned.as_deref().or(btf.mask);
    let fit_on = |data: Option<&[f32]>| -> Result<Box<dyn crate::model::DynModel>> {
        let b = BtfRef::new(btf.height, btf.width, btf.views, btf.lights, data.unwrap_or(btf.data), mask)?;
        (entry.fit)(&b, options, monitor)
    };
    let data = repaired(&sc);
    let model = fit_on(data.as_deref())?;
    let replace = data.is_some();
    let mut report = sc.report(btf, replace, robust.exclude_bad_images);
    report["robust"] = json!(robust.robust);
    if too_big && !sc.values.is_empty() {
        report["not_repaired"] = json!(format!(
            "a repaired copy of the values ({:.1} MB) would exceed memory_limit; pass robust=False to skip the screen \
             or raise the limit",
            std::mem::size_of_val(btf.data) as f64 / 1e6
        ));
    }
    Ok((model, report))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lambert(h: usize, w: usize, nv: usize, nl: usize) -> (Vec<[f64; 3]>, Vec<[f64; 3]>, Vec<f32>) {
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
            let albedo = 0.3 + 0.5 * ((t * 37 % 11) as f32 / 11.0);
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
        let sc = screen(&b, &Monitor::new()).unwrap();
        let mut got: Vec<usize> = sc.values.iter().map(|v| v.0).collect();
        got.sort();
        assert_eq!(got, hot);
        // The replacement is the light neighbours' median: near the clean value on a smooth BRDF.
        for &(i, x) in &sc.values {
            assert!((x - clean[i]).abs() <= 0.25 * clean[i] + 1e-6, "{i}: {x} vs {}", clean[i]);
        }
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
