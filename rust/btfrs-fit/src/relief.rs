//! A sample's relief, for models that must draw its cast shadows: the surface height from
//! photometric stereo (Woodham 1980, [`crate::photometric`]) integrated by Frankot and Chellappa
//! (1988, `btfrs_numerics::poisson`), and from it the **horizon map**: per texel and azimuth, the
//! elevation angle above which a light is not hidden by the relief around it (the horizon maps
//! of Max 1988, "Horizon mapping: shadows for bump-mapped surfaces").
//!
//! Why: a light between two measured ones casts a shadow between theirs, and a texel's own
//! values cannot say where (it is lit under one, shadowed under the other). Its neighbours can:
//! the relief places the edge. Measured on the SynthRTI relief scenes, a decoder told
//! `elevation(l) - horizon(azimuth(l))` predicts unseen lights 2-3 dB better than one that is
//! not (BENCHMARKS.md, "RTI relighting").
//!
//! A model stores the map compactly ([`HorizonMap`]): the horizons at [`BINS`] azimuths are
//! highly correlated (neighbouring azimuths see the same relief), so each texel keeps the
//! coordinates of its horizon row in the map's leading principal components, as 8-bit planes;
//! a lookup rebuilds the two bins around an azimuth from them.
//!
//! Photometric-stereo heights are too flat where the relief is deep (shadowed lights pull the
//! normals towards the view); [`choose_scale`] picks the height scale whose horizons best
//! explain the shadows the capture shows.

use crate::photometric::{photometric_stereo, Method};
use crate::planes::Planes;
use btfrs_core::{BtfRef, Error, Monitor, NamedArrays, Result};
use btfrs_numerics::poisson::{integrate_slopes, Boundary};
use rayon::prelude::*;
use std::f64::consts::PI;

/// The steepest slope a normal is read as (87 degrees), as `btfrs.height` clamps it.
const MAX_SLOPE: f64 = 20.0;
/// The height scales [`choose_scale`] tries.
pub const SCALES: [f32; 8] = [0.5, 0.75, 1.0, 1.5, 2.0, 2.5, 3.0, 4.0];

/// A height map: `rows x cols` row-major, row 0 the top of the image, in texel widths.
#[derive(Debug, Clone, PartialEq)]
pub struct Height {
    /// Rows.
    pub rows: usize,
    /// Columns.
    pub cols: usize,
    /// The heights.
    pub z: Vec<f32>,
}

impl Height {
    /// The height at fractional (row, column), bilinear; `None` outside the map.
    #[inline]
    fn at(&self, r: f32, c: f32) -> Option<f32> {
        if !(r >= 0.0 && c >= 0.0 && r <= (self.rows - 1) as f32 && c <= (self.cols - 1) as f32) {
            return None;
        }
        // Both are at least 0 here, so truncation is the floor (without a libm call per sample:
        // this lookup is the inner loop of the horizon march).
        let (r0, c0) = (r as usize, c as usize);
        let (r1, c1) = ((r0 + 1).min(self.rows - 1), (c0 + 1).min(self.cols - 1));
        let (fr, fc) = (r - r0 as f32, c - c0 as f32);
        let z = &self.z;
        let top = z[r0 * self.cols + c0] * (1.0 - fc) + z[r0 * self.cols + c1] * fc;
        let bottom = z[r1 * self.cols + c0] * (1.0 - fc) + z[r1 * self.cols + c1] * fc;
        Some(top * (1.0 - fr) + bottom * fr)
    }
}

impl Height {
    /// The map averaged over blocks of `f x f` texels (the last row and column of blocks
    /// partial), in units of the coarse texel's width: heights divided by `f`, so that angles
    /// are those of the fine map.
    pub fn coarse(&self, f: usize) -> Height {
        let (rows, cols) = (self.rows.div_ceil(f), self.cols.div_ceil(f));
        let mut sum = vec![0.0f64; rows * cols];
        let mut count = vec![0u32; rows * cols];
        for (i, &z) in self.z.iter().enumerate() {
            let b = (i / self.cols / f) * cols + (i % self.cols) / f;
            sum[b] += z as f64;
            count[b] += 1;
        }
        let z = sum.iter().zip(&count).map(|(s, &n)| (s / n.max(1) as f64 / f as f64) as f32).collect();
        Height { rows, cols, z }
    }
}

/// The most texels a horizon map is marched at (2048^2): a larger map is marched on its height
/// averaged over blocks of [`coarse_factor`] texels a side, each texel taking its block's
/// horizons. A march costs up to [`REACH`] lookups per azimuth and texel: at 24 megapixels,
/// 32 bins and a relief integrated over the whole frame, the full-resolution march ran past 6
/// minutes; at a factor of 3 it is 27 times less work, and the shadows it places are those of
/// relief at least 3 texels across.
pub const HORIZON_TEXELS: usize = 1 << 22;

/// The side of the blocks a `rows x cols` map's horizons are marched over (1: every texel).
pub fn coarse_factor(rows: usize, cols: usize) -> usize {
    let t = rows * cols;
    let mut f = 1;
    while t.div_ceil(f * f) > HORIZON_TEXELS {
        f += 1;
    }
    f
}

/// A capture's view slot averaged over blocks of texels: the input of the relief of a
/// camera-sized capture ([`HORIZON_TEXELS`]).
#[derive(Debug, Clone)]
pub struct Blocks {
    /// Block rows.
    pub rows: usize,
    /// Block columns.
    pub cols: usize,
    /// The one view.
    pub views: Vec<[f64; 3]>,
    /// Per block and light, the block's mean grey value `(R + G + B) / 3` three times (the
    /// layout of a one-view BTF; photometric stereo and [`choose_scale`] read grey only).
    pub data: Vec<f32>,
    /// The view slot's present lights (`None`: all).
    pub mask: Option<Vec<bool>>,
}

/// View slot `view` of `btf` averaged over blocks of `f x f` texels (the last row and column of
/// blocks partial): one pass over the slot's values, block row by block row (`monitor` counts
/// them).
pub fn blocks_of(btf: &BtfRef<'_>, view: usize, f: usize, monitor: &Monitor) -> Result<Blocks> {
    let (rows, cols) = (btf.height.div_ceil(f), btf.width.div_ceil(f));
    let nl = btf.lights.len();
    let base = view * nl * 3;
    let mut data = vec![0.0f32; rows * cols * nl * 3];
    monitor.start(rows as u64);
    data.par_chunks_mut(cols * nl * 3).enumerate().try_for_each(|(br, out)| -> Result<()> {
        monitor.check()?;
        let mut sum = vec![0.0f64; cols * nl];
        let mut count = vec![0u32; cols];
        for r in br * f..((br + 1) * f).min(btf.height) {
            for c in 0..btf.width {
                let v = &btf.texel(r * btf.width + c)[base..base + nl * 3];
                let s = &mut sum[(c / f) * nl..(c / f + 1) * nl];
                for (l, x) in s.iter_mut().enumerate() {
                    *x += (v[3 * l] as f64 + v[3 * l + 1] as f64 + v[3 * l + 2] as f64) / 3.0;
                }
                count[c / f] += 1;
            }
        }
        for (bc, o) in out.chunks_exact_mut(nl * 3).enumerate() {
            for l in 0..nl {
                let g = (sum[bc * nl + l] / count[bc].max(1) as f64) as f32;
                o[3 * l..3 * l + 3].fill(g);
            }
        }
        monitor.advance(1);
        Ok(())
    })?;
    let mask = btf.mask.map(|m| m[view * nl..(view + 1) * nl].to_vec());
    Ok(Blocks { rows, cols, views: vec![btf.views[view]], data, mask })
}

/// Per-texel vectors (unit normals or RGB albedo), row-major.
pub type TexelVectors = Vec<[f32; 3]>;

/// The height of view slot `view` of `btf` from its robust photometric-stereo normals, mirrored
/// at the borders (a capture need not tile), with the normals and albedo it came from.
pub fn height_map(btf: &BtfRef<'_>, view: usize, monitor: &Monitor) -> Result<(Height, TexelVectors, TexelVectors)> {
    let maps = photometric_stereo(btf, view, Method::Robust, monitor)?;
    let (rows, cols) = (btf.height, btf.width);
    let (p, q): (Vec<f64>, Vec<f64>) = maps
        .normals
        .iter()
        .map(|n| {
            let nz = (n[2] as f64).max(0.05);
            ((-n[0] as f64 / nz).clamp(-MAX_SLOPE, MAX_SLOPE), (-n[1] as f64 / nz).clamp(-MAX_SLOPE, MAX_SLOPE))
        })
        .unzip();
    let z = integrate_slopes(&p, &q, rows, cols, Boundary::Mirror);
    Ok((Height { rows, cols, z: z.into_iter().map(|v| v as f32).collect() }, maps.normals, maps.albedo))
}

/// The azimuth of bin `k` of `bins`: `2 pi k / bins`, from x towards y (up the image).
pub fn bin_azimuth(k: usize, bins: usize) -> f64 {
    2.0 * PI * k as f64 / bins as f64
}

/// Where direction `d` falls among `bins` azimuth bins: `(k0, k1, w, elevation)`, its horizon
/// `(1 - w) h[k0] + w h[k1]`, its elevation in radians.
#[inline]
pub fn lookup(d: [f64; 3], bins: usize) -> (usize, usize, f32, f32) {
    let phi = d[1].atan2(d[0]).rem_euclid(2.0 * PI);
    let f = phi / (2.0 * PI) * bins as f64;
    let k0 = (f.floor() as usize) % bins;
    let w = (f - f.floor()) as f32;
    (k0, (k0 + 1) % bins, w, d[2].clamp(-1.0, 1.0).asin() as f32)
}

/// The farthest a horizon looks, in texels: relief farther away is taken as open. A shadow cast
/// from farther needs an occluder taller than `REACH tan(elevation)` (55 texels for a light at
/// 12 degrees, a dome's lowest ring), and the march of a texel on a peak would otherwise cross
/// the whole map in every direction: at 6000 x 4000 texels, hours.
pub const REACH: usize = 256;
/// Side of the blocks whose highest points bound the march ([`Ceiling`]).
const BLOCK: usize = 32;

/// Per block of `BLOCK x BLOCK` texels, the highest height within the reach of any of its texels
/// (and the texel beside: a bilinear lookup reads it): the local bound of the march's early
/// stop. The map's single highest point would keep every texel of a flat part of a capture
/// marching to the reach because a tall relief lies elsewhere in the frame.
struct Ceiling {
    cols: usize,
    max: Vec<f32>,
}

impl Ceiling {
    fn new(height: &Height, reach: usize) -> Ceiling {
        let (br, bc) = (height.rows.div_ceil(BLOCK), height.cols.div_ceil(BLOCK));
        let mut blocks = vec![f32::MIN; br * bc];
        for (i, &z) in height.z.iter().enumerate() {
            let b = (i / height.cols / BLOCK) * bc + (i % height.cols) / BLOCK;
            blocks[b] = blocks[b].max(z);
        }
        // A separable maximum over the blocks within the reach (and one more for the texel
        // beside the farthest sample), first along rows, then along columns.
        let radius = reach.div_ceil(BLOCK) + 1;
        let mut across = vec![f32::MIN; br * bc];
        for r in 0..br {
            for c in 0..bc {
                let (c0, c1) = (c.saturating_sub(radius), (c + radius).min(bc - 1));
                across[r * bc + c] = blocks[r * bc + c0..=r * bc + c1].iter().cloned().fold(f32::MIN, f32::max);
            }
        }
        let mut max = vec![f32::MIN; br * bc];
        for r in 0..br {
            let (r0, r1) = (r.saturating_sub(radius), (r + radius).min(br - 1));
            for c in 0..bc {
                max[r * bc + c] = (r0..=r1).map(|q| across[q * bc + c]).fold(f32::MIN, f32::max);
            }
        }
        Ceiling { cols: bc, max }
    }

    /// The bound at texel (`r`, `c`).
    #[inline]
    fn at(&self, r: usize, c: usize) -> f32 {
        self.max[(r / BLOCK) * self.cols + c / BLOCK]
    }
}

/// The tangent of the horizon from texel (`r`, `c`) along image step (`dc`, `dr`) per texel,
/// heights times `scale`, at least 0, over the relief within `reach` texels. `rise` is `scale` times
/// the tallest relief within the reach minus the texel's height: once even that would be seen
/// below the best angle found, no farther sample can raise the horizon, and the march stops.
#[inline]
fn horizon_tan(height: &Height, r: usize, c: usize, (dc, dr): (f32, f32), scale: f32, rise: f32, reach: f32) -> f32 {
    let z0 = height.z[r * height.cols + c];
    let mut best = 0.0f32;
    let mut t = 1.0f32;
    while rise > best * t && t <= reach {
        match height.at(r as f32 + dr * t, c as f32 + dc * t) {
            Some(z) => best = best.max((z - z0) * scale / t),
            None => break,
        }
        t += 1.0;
    }
    best
}

/// The image step (columns, rows) per texel along azimuth bin `k` of `bins` (y up the image).
fn steps(bins: usize) -> Vec<(f32, f32)> {
    (0..bins).map(|k| (bin_azimuth(k, bins).cos() as f32, -(bin_azimuth(k, bins).sin() as f32))).collect()
}

/// The horizons of `texels` (row-major indices) over `height` times `scale`: `bins` elevation
/// angles each (radians, at least 0), bin `k` looking along azimuth [`bin_azimuth`]: the largest
/// angle under which the relief within the map and within `reach` texels ([`REACH`] at the
/// texels' own resolution) is seen from the texel. Beyond the map's border the relief is taken
/// as open (no occluder).
pub fn horizons_of(height: &Height, scale: f32, bins: usize, texels: &[usize], reach: usize) -> Vec<f32> {
    let ceiling = Ceiling::new(height, reach);
    let dirs = steps(bins);
    let mut out = vec![0.0f32; texels.len() * bins];
    out.par_chunks_mut(bins).zip(texels.par_iter()).for_each(|(o, &t)| {
        let (r, c) = (t / height.cols, t % height.cols);
        let rise = (ceiling.at(r, c) - height.z[t]) * scale;
        for (x, &d) in o.iter_mut().zip(&dirs) {
            *x = horizon_tan(height, r, c, d, scale, rise, reach as f32).atan();
        }
    });
    out
}

/// The horizon map of every texel ([`horizons_of`]), `[texel][bin]`.
pub fn horizons(height: &Height, scale: f32, bins: usize, reach: usize) -> Vec<f32> {
    let all: Vec<usize> = (0..height.rows * height.cols).collect();
    horizons_of(height, scale, bins, &all, reach)
}

/// The horizon of texel row `h` (its `bins` angles) towards direction `d`: `elevation(d) -
/// horizon(azimuth(d))`, positive where `d` clears the relief.
#[inline]
pub fn clearance(h: &[f32], d: [f64; 3]) -> f32 {
    let (k0, k1, w, el) = lookup(d, h.len());
    el - (h[k0] * (1.0 - w) + h[k1] * w)
}

/// Texels [`choose_scale`] scores at most.
const SCALE_TEXELS: usize = 1 << 18;

/// The scale of [`SCALES`] whose horizons best explain the cast shadows of view slot `view`:
/// a texel under a light it faces (`n . l >= 0.3`) is counted shadowed where its luminance is
/// below 0.35 of the Lambertian prediction `albedo (n . l)`, lit above 0.7; the score is the
/// balanced accuracy of `clearance > 0` as a predictor of lit, on every third texel of every
/// third row (sparser beyond [`SCALE_TEXELS`] texels), with 16 azimuth bins. `height` is the
/// map the horizons are marched on: the texels' own, or one of blocks of `factor` texels a
/// side ([`Height::coarse`]). Returns the scale and its score.
pub fn choose_scale(
    btf: &BtfRef<'_>,
    view: usize,
    height: &Height,
    factor: usize,
    normals: &[[f32; 3]],
    albedo: &[[f32; 3]],
) -> (f32, f64) {
    let (rows, cols) = (btf.height, btf.width);
    let mut step = 3;
    while (rows.div_ceil(step)) * (cols.div_ceil(step)) > SCALE_TEXELS {
        step += 1;
    }
    let bins = 16;
    let sub: Vec<usize> =
        (0..rows).step_by(step).flat_map(|r| (0..cols).step_by(step).map(move |c| r * cols + c)).collect();
    let marched: Vec<usize> = sub.iter().map(|&t| (t / cols / factor) * height.cols + (t % cols) / factor).collect();
    let nl = btf.lights.len();
    let lights: Vec<usize> = (0..nl).filter(|&l| btf.has(view, l)).collect();
    // Observed shadows: (texel index in `sub`, light, lit?).
    let mut seen: Vec<(usize, usize, bool)> = Vec::new();
    for (si, &t) in sub.iter().enumerate() {
        let n = normals[t];
        let a = (albedo[t][0] + albedo[t][1] + albedo[t][2]) as f64 / 3.0;
        if a <= 0.0 {
            continue;
        }
        let vals = &btf.texel(t)[view * nl * 3..(view + 1) * nl * 3];
        for &l in &lights {
            let d = btf.lights[l];
            let ndl = n[0] as f64 * d[0] + n[1] as f64 * d[1] + n[2] as f64 * d[2];
            if ndl < 0.3 {
                continue;
            }
            let lum = (vals[l * 3] + vals[l * 3 + 1] + vals[l * 3 + 2]) as f64 / 3.0;
            let ratio = lum / (a * ndl);
            if ratio < 0.35 {
                seen.push((si, l, false));
            } else if ratio > 0.7 {
                seen.push((si, l, true));
            }
        }
    }
    let lit_count = seen.iter().filter(|s| s.2).count();
    let dark_count = seen.len() - lit_count;
    if lit_count == 0 || dark_count == 0 {
        return (1.0, 0.0);
    }
    let mut best = (1.0f32, f64::MIN);
    for &scale in &SCALES {
        let hz = horizons_of(height, scale, bins, &marched, REACH.div_ceil(factor));
        let (mut tp, mut tn) = (0usize, 0usize);
        for &(si, l, lit) in &seen {
            let predicted = clearance(&hz[si * bins..(si + 1) * bins], btf.lights[l]) > 0.0;
            if predicted && lit {
                tp += 1;
            } else if !predicted && !lit {
                tn += 1;
            }
        }
        let score = 0.5 * (tp as f64 / lit_count as f64 + tn as f64 / dark_count as f64);
        if score > best.1 + 1e-9 {
            best = (scale, score);
        }
    }
    (best.0, best.1)
}

/// Azimuth bins of a [`HorizonMap`].
pub const BINS: usize = 32;
/// Texels the principal components of a horizon map are computed from, at most.
const PCA_TEXELS: usize = 65_536;
/// The largest full horizon map (bytes) built in one piece; 64 MiB is 512^2 texels at 32 bins.
const WHOLE_MAP_BYTES: usize = 64 << 20;

/// A compact horizon map: per texel the coordinates of its row of [`BINS`] horizon angles in
/// the map's leading principal components (8-bit planes), `horizon(t, k) = mean[k] + sum_i
/// coeffs[t, i] basis[i, k]`.
#[derive(Debug, Clone, PartialEq)]
pub struct HorizonMap {
    /// Azimuth bins.
    pub bins: usize,
    /// The mean row (`bins`).
    pub mean: Vec<f32>,
    /// The components, `[component][bin]`.
    pub basis: Vec<f32>,
    /// Per texel its coordinates (`texels x components`).
    pub coeffs: Planes,
}

impl HorizonMap {
    /// The map of `height` times `scale` in `components` principal components: the components
    /// from the horizons of up to [`PCA_TEXELS`] texels spread over the map, then every texel's
    /// horizons, a block of rows at a time, projected on them (`monitor` counts rows).
    pub fn build(height: &Height, scale: f32, components: usize, monitor: &Monitor) -> Result<HorizonMap> {
        Self::build_within(height, scale, components, monitor, WHOLE_MAP_BYTES, REACH)
    }

    /// [`HorizonMap::build`] over a map of blocks of `f x f` texels ([`Height::coarse`]): the
    /// same reach in the texels' widths.
    pub fn build_coarse(
        height: &Height,
        f: usize,
        scale: f32,
        components: usize,
        monitor: &Monitor,
    ) -> Result<HorizonMap> {
        Self::build_within(height, scale, components, monitor, WHOLE_MAP_BYTES, REACH.div_ceil(f))
    }

    /// [`HorizonMap::build`], marching the whole map at once when it fits in `whole_bytes`.
    fn build_within(
        height: &Height,
        scale: f32,
        components: usize,
        monitor: &Monitor,
        whole_bytes: usize,
        reach: usize,
    ) -> Result<HorizonMap> {
        let (bins, m) = (BINS, components.min(BINS));
        let texels = height.rows * height.cols;
        let stride = texels.div_ceil(PCA_TEXELS).max(1);
        let sample: Vec<usize> = (0..texels).step_by(stride).collect();
        // A map that fits in `whole_bytes` is marched once and the sample read from it (a third
        // of the fit's setup at 320^2 was the sample marched twice); a larger one marches the
        // sample, then every texel a block at a time.
        let whole = (texels * bins * 4 <= whole_bytes).then(|| horizons(height, scale, bins, reach));
        let hs = match &whole {
            Some(all) => sample.iter().flat_map(|&t| all[t * bins..(t + 1) * bins].iter().copied()).collect(),
            None => horizons_of(height, scale, bins, &sample, reach),
        };
        let n = sample.len() as f64;
        let mut mean = vec![0.0f64; bins];
        for row in hs.chunks_exact(bins) {
            mean.iter_mut().zip(row).for_each(|(m, &x)| *m += x as f64 / n);
        }
        let mut cov = nalgebra::DMatrix::<f64>::zeros(bins, bins);
        for row in hs.chunks_exact(bins) {
            for i in 0..bins {
                let a = row[i] as f64 - mean[i];
                for j in i..bins {
                    cov[(i, j)] += a * (row[j] as f64 - mean[j]);
                }
            }
        }
        for i in 0..bins {
            for j in 0..i {
                cov[(i, j)] = cov[(j, i)];
            }
        }
        let (_, vecs) = btfrs_numerics::dense::sym_eigen_desc(cov);
        let basis: Vec<f32> =
            (0..m).flat_map(|c| (0..bins).map(move |k| (c, k))).map(|(c, k)| vecs[(k, c)] as f32).collect();
        let mean: Vec<f32> = mean.iter().map(|&x| x as f32).collect();
        // Every texel's coordinates, a block of rows at a time (the full map at 32 bins is
        // 128 bytes per texel).
        let mut coeffs = vec![0.0f32; texels * m];
        let rows_per = (65_536 / height.cols.max(1)).max(1);
        monitor.start(height.rows as u64);
        for r0 in (0..height.rows).step_by(rows_per) {
            monitor.check()?;
            let r1 = (r0 + rows_per).min(height.rows);
            let marched;
            let hb: &[f32] = match &whole {
                Some(all) => &all[r0 * height.cols * bins..r1 * height.cols * bins],
                None => {
                    let block: Vec<usize> = (r0 * height.cols..r1 * height.cols).collect();
                    marched = horizons_of(height, scale, bins, &block, reach);
                    &marched
                }
            };
            coeffs[r0 * height.cols * m..r1 * height.cols * m]
                .par_chunks_mut(m.max(1))
                .zip(hb.par_chunks(bins))
                .for_each(|(c, row)| {
                    for (i, ci) in c.iter_mut().enumerate() {
                        let b = &basis[i * bins..(i + 1) * bins];
                        *ci = row.iter().zip(&mean).zip(b).map(|((x, mu), w)| (x - mu) * w).sum();
                    }
                });
            monitor.advance((r1 - r0) as u64);
        }
        Ok(HorizonMap { bins, mean, basis, coeffs: Planes::quantize(&coeffs, m.max(1))? })
    }

    /// The map of a `rows x cols` grid whose texels take the coordinates of their block of
    /// `f x f` in `self` (a map of `rows.div_ceil(f) x cols.div_ceil(f)` blocks).
    pub fn expand(&self, f: usize, rows: usize, cols: usize) -> HorizonMap {
        let bc = cols.div_ceil(f);
        let block: Vec<usize> = (0..rows * cols).map(|t| (t / cols / f) * bc + (t % cols) / f).collect();
        self.select(&block)
    }

    /// The map of `texels` (in that order): the same components.
    pub fn select(&self, texels: &[usize]) -> HorizonMap {
        HorizonMap {
            bins: self.bins,
            mean: self.mean.clone(),
            basis: self.basis.clone(),
            coeffs: self.coeffs.select(texels),
        }
    }

    /// Components per texel.
    pub fn components(&self) -> usize {
        self.coeffs.k
    }

    /// Texel `t`'s row of horizons, rebuilt from its stored coordinates, into `out` (`bins`).
    pub fn row(&self, t: usize, out: &mut [f32]) {
        out.copy_from_slice(&self.mean);
        for i in 0..self.components() {
            let c = self.coeffs.get(t, i);
            out.iter_mut().zip(&self.basis[i * self.bins..(i + 1) * self.bins]).for_each(|(o, b)| *o += c * b);
        }
    }

    /// The rows of `texels`, `[texel][bin]`.
    pub fn rows(&self, texels: &[usize]) -> Vec<f32> {
        let mut out = vec![0.0f32; texels.len() * self.bins];
        out.par_chunks_mut(self.bins).zip(texels.par_iter()).for_each(|(o, &t)| self.row(t, o));
        out
    }

    /// Texel `t`'s horizon at bin `k`.
    #[inline]
    pub fn at(&self, t: usize, k: usize) -> f32 {
        let mut h = self.mean[k];
        for i in 0..self.components() {
            h += self.coeffs.get(t, i) * self.basis[i * self.bins + k];
        }
        h
    }

    /// Texel `t`'s clearance towards a direction looked up as `(k0, k1, w, elevation)`
    /// ([`lookup`]).
    #[inline]
    pub fn clearance(&self, t: usize, (k0, k1, w, el): (usize, usize, f32, f32)) -> f32 {
        el - (self.at(t, k0) * (1.0 - w) + self.at(t, k1) * w)
    }

    /// Bytes a renderer holds: the coordinates' planes, the mean and the components.
    pub fn nbytes(&self) -> usize {
        self.coeffs.nbytes() + 4 * (self.mean.len() + self.basis.len())
    }

    /// Store as `{prefix}q`/`scale`/`bias` (the coordinates, `shape` = texel dims + components),
    /// `{prefix}mean` (`[bins]`) and `{prefix}basis` (`[components, bins]`).
    pub fn insert_into(&self, a: &mut NamedArrays, prefix: &str, shape: Vec<usize>) {
        self.coeffs.insert_into(a, prefix, shape);
        a.put(&format!("{prefix}mean"), &[self.bins], self.mean.clone());
        a.put(&format!("{prefix}basis"), &[self.components(), self.bins], self.basis.clone());
    }

    /// Read back what [`HorizonMap::insert_into`] stored for `texels` texels and `components`,
    /// every value checked finite.
    pub fn from_arrays(a: &NamedArrays, prefix: &str, texels: usize, components: usize) -> Result<HorizonMap> {
        let coeffs = Planes::from_arrays(a, prefix, texels, components)?;
        let mean_name = format!("{prefix}mean");
        let (mean, ms) = a.get::<f32>(&mean_name, &[None])?;
        let bins = ms[0];
        if !(2..=256).contains(&bins) {
            return Err(Error::format(&mean_name, format!("expected 2 to 256 azimuth bins, got {bins}")));
        }
        let basis_name = format!("{prefix}basis");
        let (basis, _) = a.get::<f32>(&basis_name, &[Some(components), Some(bins)])?;
        for (name, v) in [(&mean_name, mean), (&basis_name, basis)] {
            if let Some(i) = v.iter().position(|x| !x.is_finite()) {
                return Err(Error::format(name, format!("value {i} ({}) is not finite", v[i])));
            }
        }
        Ok(HorizonMap { bins, mean: mean.to_vec(), basis: basis.to_vec(), coeffs })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plateau(rows: usize, cols: usize) -> Height {
        // A 4-texel-high block in the middle of a flat floor.
        let z = (0..rows * cols)
            .map(|i| {
                let (r, c) = (i / cols, i % cols);
                if (10..14).contains(&r) && (10..14).contains(&c) {
                    4.0
                } else {
                    0.0
                }
            })
            .collect();
        Height { rows, cols, z }
    }

    #[test]
    fn horizon_of_a_block_is_its_angle_seen_from_the_floor() {
        let h = plateau(24, 24);
        let bins = 8;
        let hz = horizons(&h, 1.0, bins, REACH);
        // Texel (12, 6): the block's face at column 10 is 4 texels away along +x (bin 0), 4 high.
        let t = 12 * 24 + 6;
        assert!((hz[t * bins] - (4.0f32 / 4.0).atan()).abs() < 1e-5, "{}", hz[t * bins]);
        // Looking away from it (-x, bin 4) the floor is open.
        assert_eq!(hz[t * bins + 4], 0.0);
        // Twice the scale: twice the tangent.
        let hz2 = horizons(&h, 2.0, bins, REACH);
        assert!((hz2[t * bins] - 2.0f32.atan()).abs() < 1e-5);
        // Up the image is -row: bin 2 (+y) of texel (18, 12) sees the block's face at row 13.
        let t = 18 * 24 + 12;
        assert!((hz[t * bins + 2] - (4.0f32 / 5.0).atan()).abs() < 1e-5, "{}", hz[t * bins + 2]);
        // The block's top sees nothing above it.
        assert!(hz[(11 * 24 + 11) * bins..(11 * 24 + 12) * bins].iter().all(|&a| a == 0.0));
    }

    #[test]
    fn clearance_interpolates_between_bins() {
        let h = [0.1f32, 0.3, 0.0, 0.0];
        // Azimuth 45 degrees, half way between bins 0 and 1, elevation 30 degrees.
        let (e, a) = (30f64.to_radians(), 45f64.to_radians());
        let d = [e.cos() * a.cos(), e.cos() * a.sin(), e.sin()];
        assert!((clearance(&h, d) - (30f32.to_radians() - 0.2)).abs() < 1e-6);
        assert_eq!(lookup([1.0, -1e-12, 0.0], 4).0, 3);
    }

    #[test]
    fn early_stop_matches_a_full_march() {
        // Random relief: the pruned march must equal the exhaustive one.
        let (rows, cols) = (20, 17);
        let mut rng = btfrs_core::rng::Rng::new(5);
        let z: Vec<f32> = (0..rows * cols).map(|_| (rng.next_f64() * 6.0) as f32).collect();
        let h = Height { rows, cols, z };
        let bins = 6;
        let hz = horizons(&h, 1.5, bins, REACH);
        for t in [0, 37, 150, rows * cols - 1] {
            let (r, c) = (t / cols, t % cols);
            for k in 0..bins {
                let (dc, dr) = steps(bins)[k];
                let mut best = 0.0f32;
                let mut s = 1.0f32;
                while let Some(zz) = h.at(r as f32 + dr * s, c as f32 + dc * s) {
                    best = best.max((zz - h.z[t]) * 1.5 / s);
                    s += 1.0;
                }
                assert!((hz[t * bins + k] - best.atan()).abs() < 1e-6);
            }
        }
    }
}

#[cfg(test)]
mod reach_tests {
    use super::*;

    /// Beyond the reach the relief is open, and the local bound prunes nothing the exhaustive
    /// march within the reach would find: a map wider than the reach, a low random relief with
    /// two tall peaks (one beyond the reach of the texels on the left, one within it).
    #[test]
    fn the_march_sees_the_relief_within_the_reach_and_no_farther() {
        let (rows, cols) = (12, 2 * REACH + 90);
        let mut rng = btfrs_core::rng::Rng::new(9);
        let mut z: Vec<f32> = (0..rows * cols).map(|_| (rng.next_f64() * 0.5) as f32).collect();
        for r in 4..8 {
            z[r * cols + REACH + 40] = 30.0;
            z[r * cols + cols - 3] = 60.0;
        }
        let h = Height { rows, cols, z };
        let bins = 8;
        let texels: Vec<usize> = (0..rows * cols).step_by(7).collect();
        let hz = horizons_of(&h, 1.0, bins, &texels, REACH);
        for (i, &t) in texels.iter().enumerate() {
            let (r, c) = (t / cols, t % cols);
            for k in 0..bins {
                let (dc, dr) = steps(bins)[k];
                let mut best = 0.0f32;
                let mut s = 1.0f32;
                while s <= REACH as f32 {
                    let Some(zz) = h.at(r as f32 + dr * s, c as f32 + dc * s) else { break };
                    best = best.max((zz - h.z[t]) / s);
                    s += 1.0;
                }
                assert!((hz[i * bins + k] - best.atan()).abs() < 1e-6, "texel {t} bin {k}");
            }
        }
        // On a flat floor, a peak 30 high is seen from 196 texels and not from 286.
        let mut flat = Height { rows, cols, z: vec![0.0; rows * cols] };
        flat.z[5 * cols + REACH + 40] = 30.0;
        let seen = horizons_of(&flat, 1.0, bins, &[5 * cols + 100, 5 * cols + 10], REACH);
        // A map of blocks of 2 texels reaches half as many of its (wider) texels.
        let c = flat.coarse(2);
        let near = horizons_of(&c, 1.0, bins, &[2 * c.cols + 50, 2 * c.cols + 5], REACH.div_ceil(2));
        assert!(near[0] > 0.0 && near[bins] == 0.0, "{near:?}");
        assert!((seen[0] - (30.0f32 / 196.0).atan()).abs() < 1e-6, "{}", seen[0]);
        assert_eq!(seen[bins], 0.0);
    }
}

#[cfg(test)]
mod map_tests {
    use super::*;

    /// A smooth relief, features 15 to 40 texels across.
    fn smooth(rows: usize, cols: usize) -> Height {
        let z = (0..rows * cols)
            .map(|i| {
                let (r, c) = ((i / cols) as f32, (i % cols) as f32);
                3.0 * (r / 5.0).sin() * (c / 7.0).cos() + 2.0 * ((r + c) / 9.0).sin()
            })
            .collect();
        Height { rows, cols, z }
    }

    #[test]
    fn compact_map_rebuilds_the_marched_horizons() {
        // Smooth random relief: with every component kept the rows come back to the 8-bit
        // step; with few, to a fraction of the horizons' spread; the arrays round-trip.
        let (rows, cols) = (40, 36);
        let h = smooth(rows, cols);
        let full = horizons(&h, 1.0, BINS, REACH);
        for (m, tol) in [(BINS, 0.01f32), (8, 0.15)] {
            let map = HorizonMap::build(&h, 1.0, m, &Monitor::new()).unwrap();
            let back = map.rows(&(0..rows * cols).collect::<Vec<_>>());
            let rms = (full.iter().zip(&back).map(|(a, b)| (a - b).powi(2)).sum::<f32>() / full.len() as f32).sqrt();
            let spread = (full.iter().map(|a| a * a).sum::<f32>() / full.len() as f32).sqrt();
            assert!(rms < tol * spread, "{m} components: rms {rms} of {spread}");
            assert!((map.at(77, 5) - back[77 * BINS + 5]).abs() < 1e-5);
            let mut a = NamedArrays::new();
            map.insert_into(&mut a, "horizon_", vec![rows, cols, m]);
            assert_eq!(HorizonMap::from_arrays(&a, "horizon_", rows * cols, m).unwrap(), map);
            // Marched in blocks (a map too large to hold whole): the same map.
            assert_eq!(HorizonMap::build_within(&h, 1.0, m, &Monitor::new(), 0, REACH).unwrap(), map);
        }
    }

    #[test]
    fn a_camera_sized_map_is_marched_on_blocks_of_texels() {
        assert_eq!(coarse_factor(2048, 2048), 1);
        assert_eq!(coarse_factor(2049, 2048), 2);
        assert_eq!(coarse_factor(4000, 6000), 3);
        // A smooth relief (features 15 to 40 texels across): the horizons marched on blocks of
        // 2 x 2 texels are those of the texels to a fraction of their spread.
        let (rows, cols) = (41, 36);
        let h = smooth(rows, cols);
        let c = h.coarse(2);
        assert_eq!((c.rows, c.cols), (21, 18));
        let block = (h.z[0] + h.z[1] + h.z[cols] + h.z[cols + 1]) / 4.0;
        assert!((c.z[0] - block / 2.0).abs() < 1e-6);
        assert!((c.z[20 * 18 + 3] - (h.z[40 * cols + 6] + h.z[40 * cols + 7]) / 2.0 / 2.0).abs() < 1e-6);
        let coarse = HorizonMap::build_coarse(&c, 2, 1.0, BINS, &Monitor::new()).unwrap();
        let map = coarse.expand(2, rows, cols);
        assert_eq!(map.coeffs.texels, rows * cols);
        let all: Vec<usize> = (0..rows * cols).collect();
        let back = map.rows(&all);
        assert_eq!(&back[(7 * cols + 5) * BINS..][..BINS], &coarse.rows(&[3 * 18 + 2])[..]);
        let fine = horizons(&h, 1.0, BINS, REACH);
        let rms = (fine.iter().zip(&back).map(|(a, b)| (a - b).powi(2)).sum::<f32>() / fine.len() as f32).sqrt();
        let spread = (fine.iter().map(|a| a * a).sum::<f32>() / fine.len() as f32).sqrt();
        assert!(rms < 0.25 * spread, "rms {rms} of {spread}");
    }
}
