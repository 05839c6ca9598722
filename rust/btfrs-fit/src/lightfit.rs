//! What the light-basis models fitted per view slot share (PTM, HSH): a linear basis in the light
//! direction, one least-squares fit per view slot whose (pseudo-)inverse is computed once and
//! applied to every texel, the policy for view slots whose lights do not determine the basis
//! ([`Degenerate`], explained in [`crate::ptm`]), and the storage of the fitted coefficients as
//! floats or as 8-bit planes ([`Coeffs`]).

use crate::gpu::words;
use crate::planes::Planes;
use btfrs_core::arrays::check_finite;
use btfrs_core::{directions, BtfRef, Error, NamedArrays, Result};
use nalgebra::DMatrix;
use std::borrow::Cow;

/// What to do with a view slot whose lights do not determine the basis coefficients.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Degenerate {
    /// Fail with [`Error::Degenerate`] naming the slot.
    Raise,
    /// Zero the small singular values: the minimum-norm least-squares solution.
    Clamp,
    /// Fewer terms, else the lights of the nearest view slots; also for slots whose fit would
    /// extrapolate (amplification above [`K_AMP`]). Each such slot is listed in the model's
    /// `degenerate_slots`.
    Reduce,
}

/// Under [`Degenerate::Reduce`], a slot's fit is accepted only when no prediction at any light
/// direction of the BTF exceeds `K_AMP` times the largest |sample| of the slot: the fit's
/// *amplification*, `max_l sum_i |w_i(l)|` where `w(l) = P^T b(l)` are the weights the fit gives
/// each sample in the prediction at light `l`. It depends on the light directions only (one
/// number per slot, no data). A complete UBO slot has 2.2 (PTM biquadratic) and 1.7 (the plane); 6
/// to 10 random lights give 7 to 30 (median), and a random 10% of the pairs made the PTM's
/// held-out relative error 5.9 on the built-in grooves (16^2) from such slots alone. 4 is met by
/// every slot of a complete or half sampling and rejects the runaway ones.
pub const K_AMP: f64 = 4.0;

/// A view slot that did not get the plain fit of its own lights, and what was done.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct DegenerateSlot {
    /// The view slot index.
    pub slot: usize,
    /// Its present lights.
    pub lights: usize,
    /// Why: `"few lights"` (fewer than the basis has terms), `"degenerate lights"`
    /// (rank-deficient, e.g. collinear) or `"extrapolates"` (amplification above [`K_AMP`]).
    pub reason: &'static str,
    /// `"pooled"` (the full basis fitted to its lights and those of the slots `from`, the
    /// nearest views first), `"kept"` (its own full fit: no alternative extrapolated less),
    /// `"clamped"` (the minimum-norm fit), `"zero"` (no light at all), or the name of a reduced
    /// basis of its own lights (PTM: `"linear"`, the plane `a3 lu + a4 lv + a5`; HSH: `"order 2"`,
    /// ...: the lower orders).
    pub action: &'static str,
    /// The slots whose lights were pooled in.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub from: Vec<usize>,
    /// The amplification of the fit used (see [`K_AMP`]).
    pub amplification: f64,
}

/// A linear basis in the light direction, as the per-slot fit sees it.
pub struct LightBasis<'a> {
    /// Terms.
    pub k: usize,
    /// Write the `k` basis values at a unit light direction.
    pub eval: &'a (dyn Fn([f64; 3], &mut [f64]) + Sync),
    /// The model in messages, e.g. `"a biquadratic PTM"`.
    pub what: &'a str,
    /// Its coefficients in messages, e.g. `"PTM coefficients"`.
    pub coefficients: &'a str,
    /// Reduced bases (action name, basis columns) in order of preference, for
    /// [`Degenerate::Reduce`].
    pub reduced: Vec<(&'static str, Vec<usize>)>,
}

impl std::fmt::Debug for LightBasis<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LightBasis")
            .field("k", &self.k)
            .field("what", &self.what)
            .field("reduced", &self.reduced)
            .finish()
    }
}

impl LightBasis<'_> {
    fn values(&self, l: [f64; 3]) -> Vec<f64> {
        let mut b = vec![0.0; self.k];
        (self.eval)(l, &mut b);
        b
    }
}

/// The options of the per-slot fit.
#[derive(Debug, Clone, Copy)]
pub struct SlotOptions {
    /// Singular values below `rcond * s_max` count as zero.
    pub rcond: f64,
    /// Ridge (Tikhonov) weight relative to the largest squared singular value: the fit minimises
    /// `|A c - y|^2 + lambda s_max^2 |c|^2`; 0 is plain least squares.
    pub lambda: f64,
    /// The policy for slots whose lights do not determine the basis.
    pub on_degenerate: Degenerate,
}

/// The (regularised) pseudo-inverse `[kc, n]` (row-major) of the design matrix of `lights` over
/// the basis columns `cols`, with singular values below `rcond * s_max` zeroed; its rank and
/// smallest/largest singular value ratio. `None` when the SVD fails.
fn pinv_cols(
    basis: &LightBasis<'_>,
    lights: &[[f64; 3]],
    cols: &[usize],
    rcond: f64,
    lambda: f64,
) -> Option<(Vec<f64>, usize, f64)> {
    let (n, k) = (lights.len(), cols.len());
    if n == 0 {
        return Some((Vec::new(), 0, 0.0));
    }
    let rows: Vec<Vec<f64>> = lights.iter().map(|&l| basis.values(l)).collect();
    let a = DMatrix::from_fn(n, k, |i, j| rows[i][cols[j]]);
    let svd = a.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    let s = &svd.singular_values;
    let smax = s.iter().copied().fold(0.0f64, f64::max);
    let cut = rcond * smax;
    let rank = s.iter().filter(|&&x| x > cut).count();
    let smin = if s.len() < k { 0.0 } else { s.iter().copied().fold(f64::INFINITY, f64::min) };
    let ridge = lambda * smax * smax;
    // pinv = V diag(s / (s^2 + ridge)) U^T with the clamped singular values' factors set to zero.
    let mut p = vec![0.0f64; k * n];
    for (j, &sj) in s.iter().enumerate() {
        if sj <= cut {
            continue;
        }
        let f = sj / (sj * sj + ridge);
        for c in 0..k {
            let vk = vt[(j, c)] * f;
            for i in 0..n {
                p[c * n + i] += vk * u[(i, j)];
            }
        }
    }
    Some((p, rank, smin / smax.max(f64::MIN_POSITIVE)))
}

/// A slot's fit: the samples it reads (flat `v * L + l` pair indices and their lights) and its
/// pseudo-inverse in the full basis, stored transposed (`[n][k]`, unused terms 0) so that the
/// per-texel loop walks the samples and the matrix in the same order.
#[derive(Debug, Clone)]
pub struct Slot {
    /// Flat pair indices `v * L + l` of the samples.
    pub pairs: Vec<usize>,
    /// The light index of each sample.
    pub lights: Vec<usize>,
    /// `[n][k]` weights: coefficient `c` is `sum_i pt[i * k + c] * sample_i`.
    pub pt: Vec<f64>,
    /// Terms of the full basis.
    pub k: usize,
}

impl Slot {
    /// From a `[kc, n]` pseudo-inverse over basis columns `cols`.
    fn new(pairs: Vec<usize>, lights: Vec<usize>, p: &[f64], cols: &[usize], k: usize) -> Slot {
        let n = pairs.len();
        let mut pt = vec![0.0f64; n * k];
        for i in 0..n {
            for (j, &c) in cols.iter().enumerate() {
                pt[i * k + c] = p[j * n + i];
            }
        }
        Slot { pairs, lights, pt, k }
    }

    /// `max_l sum_i |w_i(l)|` over the light directions `all` (see [`K_AMP`]).
    fn amplification(&self, basis: &LightBasis<'_>, all: &[[f64; 3]]) -> f64 {
        all.iter()
            .map(|&l| {
                let b = basis.values(l);
                self.pt
                    .chunks_exact(self.k)
                    .map(|r| r.iter().zip(&b).map(|(x, y)| x * y).sum::<f64>().abs())
                    .sum::<f64>()
            })
            .fold(0.0, f64::max)
    }

    /// The `3 k` coefficients `[channel][term]` of one texel from its ABRDF (RGB interleaved
    /// pairs); f64 accumulation. This runs once per texel and view slot, so the common term
    /// counts (PTM's 6, HSH's 4, 9 and 16) have their own instances, whose accumulators the
    /// compiler keeps in registers: with a run-time count they were a heap vector per call
    /// (41% of the PTM-RGB fit's time). Measured and left: two sets of accumulators (even and
    /// odd samples) spill at 6 terms and are 45% slower; the AVX2 + FMA form, chosen at run
    /// time, 30% slower (one longer dependency chain per accumulator).
    #[inline]
    pub fn fit_rgb(&self, abrdf: &[f32], out: &mut [f32]) {
        match self.k {
            4 => self.fit_rgb_k::<4>(abrdf, out),
            6 => self.fit_rgb_k::<6>(abrdf, out),
            9 => self.fit_rgb_k::<9>(abrdf, out),
            16 => self.fit_rgb_k::<16>(abrdf, out),
            k => {
                let mut acc = vec![0.0f64; 3 * k];
                for (&i, p) in self.pairs.iter().zip(self.pt.chunks_exact(k)) {
                    let x = &abrdf[i * 3..i * 3 + 3];
                    for c in 0..3 {
                        let xc = x[c] as f64;
                        for (a, &w) in acc[c * k..(c + 1) * k].iter_mut().zip(p) {
                            *a += w * xc;
                        }
                    }
                }
                for (o, a) in out.iter_mut().zip(&acc) {
                    *o = *a as f32;
                }
            }
        }
    }

    #[inline(always)]
    fn fit_rgb_k<const K: usize>(&self, abrdf: &[f32], out: &mut [f32]) {
        let mut acc = [[0.0f64; K]; 3];
        for (&i, p) in self.pairs.iter().zip(self.pt.chunks_exact(K)) {
            let x = &abrdf[i * 3..i * 3 + 3];
            for c in 0..3 {
                let xc = x[c] as f64;
                for j in 0..K {
                    acc[c][j] += p[j] * xc;
                }
            }
        }
        for c in 0..3 {
            for j in 0..K {
                out[c * K + j] = acc[c][j] as f32;
            }
        }
    }
}

/// One row of texels as [`fit_row_rgb`] reads it.
#[derive(Debug, Clone, Copy)]
pub struct Row<'a> {
    /// Their ABRDFs, `abrdf` values each.
    pub values: &'a [f32],
    /// Values per texel.
    pub abrdf: usize,
    /// The flat index of the row's first texel (where the screen finds its neighbours).
    pub first: usize,
    /// The robust value screen, run on each texel inside the pass (`None`: the values as
    /// measured).
    pub screen: Option<&'a crate::robust::TexelScreen<'a>>,
}

impl Row<'_> {
    /// Texel `col`'s values as the fit sees them: `values`, or their repaired copy when the
    /// screen flags any.
    #[inline]
    fn repaired(&self, col: usize, values: &[f32]) -> Option<Vec<f32>> {
        self.screen.and_then(|s| s.repaired(self.first + col, values))
    }
}

crate::simd::by_cpu! {
    /// Fit one row of texels in every view slot into `out` (`[texel][slot][3 k]`), each texel's
    /// values checked by `scan` first (false as soon as one is not finite), then judged by the
    /// row's screen if it has one. PTM-RGB and HSH share it.
    ///
    /// On a CPU with AVX-512 the texels go 8 at a time: the accumulators of one coefficient are a
    /// vector across the 8 texels (3 k vectors of 8 doubles stay in the 32 registers), so that
    /// every multiply-add fills its lanes, where one texel at a time leaves most of them idle. With
    /// AVX2 they go 4 at a time, one channel after the other: the 16 registers hold the k
    /// accumulators of one channel (3 k of them would spill), for HSH's 9 and 16 terms; PTM's 6 stay
    /// one texel at a time, which measured faster there. On a 2-core EPYC (AVX2), the float HSH of
    /// order 3 of a 1200 x 800 x 60 capture took 0.62 s of CPU instead of 1.16 s. Each
    /// texel's sums are the same products added in the same order, so the result is the same to
    /// the bit in every form.
    pub fn fit_row_rgb(slots: &[Slot], row: &Row<'_>, out: &mut [f32], scan: &btfrs_core::btf::TexelScan) -> bool {
        ["avx512f"] => fit_row_groups::<8, false>(slots, row, out, scan),
        ["avx2"] => if slots.iter().all(|s| matches!(s.k, 9 | 16)) {
            fit_row_groups::<4, true>(slots, row, out, scan)
        } else {
            fit_row_groups::<1, false>(slots, row, out, scan)
        },
        _ => fit_row_groups::<1, false>(slots, row, out, scan),
    }
}

/// [`fit_row_rgb`] with the texels `T` at a time (the last few one at a time), each group's
/// channels together or, with `BY_CHANNEL`, one after the other.
#[inline(always)]
fn fit_row_groups<const T: usize, const BY_CHANNEL: bool>(
    slots: &[Slot],
    row: &Row<'_>,
    out: &mut [f32],
    scan: &btfrs_core::btf::TexelScan,
) -> bool {
    let abrdf = row.abrdf;
    let w = row.values.len() / abrdf;
    let nv = slots.len();
    let per = slots.first().map_or(0, |s| 3 * s.k);
    let texel = |col: usize| &row.values[col * abrdf..(col + 1) * abrdf];
    let mut col = 0;
    // The group's values side by side (only for BY_CHANNEL).
    let mut lanes = vec![[0.0f64; T]; if BY_CHANNEL { abrdf } else { 0 }];
    if T > 1 {
        while col + T <= w {
            let measured: [&[f32]; T] = std::array::from_fn(|t| texel(col + t));
            if !measured.iter().all(|a| scan.check(a)) {
                return false;
            }
            let fixed: [Option<Vec<f32>>; T] = std::array::from_fn(|t| row.repaired(col + t, measured[t]));
            let texels: [&[f32]; T] = std::array::from_fn(|t| fixed[t].as_deref().unwrap_or(measured[t]));
            if BY_CHANNEL {
                for (value, lane) in lanes.iter_mut().enumerate() {
                    *lane = std::array::from_fn(|t| texels[t][value] as f64);
                }
            }
            for (v, slot) in slots.iter().enumerate() {
                let out = &mut out[(col * nv + v) * per..];
                match (BY_CHANNEL, slot.k) {
                    (true, 9) => slot.group_channels::<9, T>(&lanes, out, nv * per),
                    (true, 16) => slot.group_channels::<16, T>(&lanes, out, nv * per),
                    _ => slot.fit_rgb_group::<T>(&texels, out, nv * per),
                }
            }
            col += T;
        }
    }
    for col in col..w {
        let measured = texel(col);
        if !scan.check(measured) {
            return false;
        }
        let fixed = row.repaired(col, measured);
        let a = fixed.as_deref().unwrap_or(measured);
        for (v, slot) in slots.iter().enumerate() {
            slot.fit_rgb(a, &mut out[(col * nv + v) * per..(col * nv + v + 1) * per]);
        }
    }
    true
}

impl Slot {
    /// [`Slot::fit_rgb`] of `T` texels at once: texel `t`'s coefficients go to
    /// `out[t * stride..][..3 k]`. For the term counts that have their own instance.
    #[inline(always)]
    fn fit_rgb_group<const T: usize>(&self, texels: &[&[f32]; T], out: &mut [f32], stride: usize) {
        match self.k {
            4 => self.group_k::<4, T>(texels, out, stride),
            6 => self.group_k::<6, T>(texels, out, stride),
            9 => self.group_k::<9, T>(texels, out, stride),
            16 => self.group_k::<16, T>(texels, out, stride),
            k => {
                for (t, a) in texels.iter().enumerate() {
                    self.fit_rgb(a, &mut out[t * stride..t * stride + 3 * k]);
                }
            }
        }
    }

    #[inline(always)]
    fn group_k<const K: usize, const T: usize>(&self, texels: &[&[f32]; T], out: &mut [f32], stride: usize) {
        let mut acc = [[[0.0f64; T]; K]; 3];
        for (&i, p) in self.pairs.iter().zip(self.pt.chunks_exact(K)) {
            for c in 0..3 {
                let x: [f64; T] = std::array::from_fn(|t| texels[t][i * 3 + c] as f64);
                for j in 0..K {
                    for t in 0..T {
                        acc[c][j][t] += p[j] * x[t];
                    }
                }
            }
        }
        for t in 0..T {
            for c in 0..3 {
                for j in 0..K {
                    out[t * stride + c * K + j] = acc[c][j][t] as f32;
                }
            }
        }
    }

    /// [`Slot::group_k`] one channel at a time from the group's values transposed (`lanes[value]`
    /// holds the `T` texels' value side by side, one vector load): `K` accumulator vectors live
    /// at once, not `3 K`.
    #[inline(always)]
    fn group_channels<const K: usize, const T: usize>(&self, lanes: &[[f64; T]], out: &mut [f32], stride: usize) {
        for c in 0..3 {
            let mut acc = [[0.0f64; T]; K];
            for (&i, p) in self.pairs.iter().zip(self.pt.chunks_exact(K)) {
                let x = lanes[i * 3 + c];
                for j in 0..K {
                    for t in 0..T {
                        acc[j][t] += p[j] * x[t];
                    }
                }
            }
            for t in 0..T {
                for j in 0..K {
                    out[t * stride + c * K + j] = acc[j][t] as f32;
                }
            }
        }
    }
}

/// The plain fit of one set of lights to the full basis: its pseudo-inverse (`[k, n]`), rank,
/// smallest/largest singular value ratio and amplification. It depends on the lights only, so
/// the view slots that share their lights (every slot of a complete sampling) share it: found
/// once per set, not 81 times (an SVD and an amplification each, which made a small fit's fixed
/// cost).
#[derive(Clone)]
struct OwnFit {
    p: Vec<f64>,
    rank: usize,
    ratio: f64,
    amp: f64,
}

/// [`OwnFit`]s by light set.
type OwnFits = std::collections::HashMap<Vec<usize>, OwnFit>;

/// The fit of view slot `v`, and its entry in the report when it is not the plain fit of the
/// full basis to its own lights. `memo` keeps the plain fits of the light sets seen so far.
fn slot_fit(
    btf: &BtfRef<'_>,
    v: usize,
    basis: &LightBasis<'_>,
    opts: &SlotOptions,
    memo: &mut OwnFits,
) -> Result<(Slot, Option<DegenerateSlot>)> {
    let k = basis.k;
    let full: Vec<usize> = (0..k).collect();
    let nl = btf.lights.len();
    let own = btf.lights_of_view(v);
    let n = own.len();
    let dirs = |ls: &[usize]| -> Vec<[f64; 3]> { ls.iter().map(|&l| btf.lights[l]).collect() };
    let name = || {
        let (theta, phi) = directions::to_theta_phi(btf.views[v]);
        format!("view slot {v} (theta {:.1}, phi {:.1} deg)", theta.to_degrees(), phi.to_degrees())
    };
    let fit = |ls: &[usize], pairs: Vec<usize>, cols: &[usize]| -> Result<(Slot, usize, f64)> {
        let (p, rank, ratio) = pinv_cols(basis, &dirs(ls), cols, opts.rcond, opts.lambda)
            .ok_or_else(|| Error::Degenerate(format!("{}: the SVD of the light design matrix failed", name())))?;
        Ok((Slot::new(pairs, ls.to_vec(), &p, cols, k), rank, ratio))
    };
    let amp = |s: &Slot| s.amplification(basis, btf.lights);
    let own_pairs: Vec<usize> = own.iter().map(|&l| v * nl + l).collect();
    // The plain fit of its own lights, shared with the slots that have the same lights.
    let (own_fit, rank, ratio, own_amp) = match memo.get(&own) {
        Some(of) => (Slot::new(own_pairs.clone(), own.clone(), &of.p, &full, k), of.rank, of.ratio, of.amp),
        None => {
            let (p, rank, ratio) = pinv_cols(basis, &dirs(&own), &full, opts.rcond, opts.lambda)
                .ok_or_else(|| Error::Degenerate(format!("{}: the SVD of the light design matrix failed", name())))?;
            let slot = Slot::new(own_pairs.clone(), own.clone(), &p, &full, k);
            let amp = amp(&slot);
            memo.insert(own.clone(), OwnFit { p, rank, ratio, amp });
            (slot, rank, ratio, amp)
        }
    };
    let reason = if n < k {
        "few lights"
    } else if rank < k {
        "degenerate lights"
    } else {
        "extrapolates"
    };
    let entry = |action: &'static str, from: Vec<usize>, slot: &Slot| DegenerateSlot {
        slot: v,
        lights: n,
        reason,
        action,
        from,
        amplification: amp(slot),
    };
    match opts.on_degenerate {
        Degenerate::Raise | Degenerate::Clamp => {
            if n < k && opts.on_degenerate == Degenerate::Raise {
                return Err(Error::Degenerate(format!(
                    "{} has {n} lights; {} needs at least {k} (on_degenerate=\"reduce\" fits such a slot from fewer \
                     terms or its neighbours' lights, \"clamp\" gives the minimum-norm fit)",
                    name(),
                    basis.what
                )));
            }
            if rank == k {
                return Ok((own_fit, None));
            }
            if opts.on_degenerate == Degenerate::Raise {
                return Err(Error::Degenerate(format!(
                    "{}: its {n} lights determine only {rank} of the {k} {} (smallest/largest singular value \
                     {ratio:.2e} < rcond {:.0e}); the lights are degenerate, e.g. collinear in (x, y) \
                     (on_degenerate=\"reduce\" fits such a slot from fewer terms or its neighbours' lights)",
                    name(),
                    basis.coefficients,
                    opts.rcond
                )));
            }
            let e = entry(if n == 0 { "zero" } else { "clamped" }, Vec::new(), &own_fit);
            Ok((own_fit, Some(e)))
        }
        Degenerate::Reduce => {
            // Candidates in order of preference; the first within K_AMP is taken, else the one
            // with the least amplification.
            if rank == k && own_amp <= K_AMP {
                return Ok((own_fit, None));
            }
            // A full-rank but extrapolating fit of its own lights is kept only if nothing else does better.
            let mut best: Option<(f64, Slot, &'static str, Vec<usize>)> = None;
            if rank == k {
                best = Some((own_amp, own_fit, "kept", Vec::new()));
            }
            for (action, cols) in &basis.reduced {
                if n < cols.len() {
                    continue;
                }
                let (reduced, r, _) = fit(&own, own_pairs.clone(), cols)?;
                if r < cols.len() {
                    continue;
                }
                let a = amp(&reduced);
                if a <= K_AMP {
                    let e = entry(action, Vec::new(), &reduced);
                    return Ok((reduced, Some(e)));
                }
                if best.as_ref().is_none_or(|b| a < b.0) {
                    best = Some((a, reduced, action, Vec::new()));
                }
            }
            // Pool the lights of the nearest views (by angle): a neighbouring view sees nearly the
            // same reflectance field, and the union of their lights covers the light hemisphere.
            let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
            let mut order: Vec<usize> = (0..btf.views.len()).filter(|&u| u != v).collect();
            order.sort_by(|&a, &b| dot(btf.views[v], btf.views[b]).total_cmp(&dot(btf.views[v], btf.views[a])));
            let (mut ls, mut pairs, mut from) = (own.clone(), own_pairs.clone(), Vec::new());
            let mut seen = vec![false; nl];
            own.iter().for_each(|&l| seen[l] = true);
            for u in order {
                let more = btf.lights_of_view(u);
                if more.is_empty() {
                    continue;
                }
                // A view that adds no light direction the pool lacks adds data but no coverage:
                // its pairs join the pool, and the pool is fitted again only when a direction is
                // new. (Every view re-fitted made the pooling quadratic in the views: 4.6 s for a
                // PTM of 8^2 texels whose 81 views all have lights in one azimuth half only.)
                let grew = more.iter().any(|&l| !seen[l]);
                more.iter().for_each(|&l| seen[l] = true);
                from.push(u);
                pairs.extend(more.iter().map(|&l| u * nl + l));
                ls.extend(more);
                if ls.len() < k || !grew {
                    continue;
                }
                let (pooled, r, _) = fit(&ls, pairs.clone(), &full)?;
                if r < k {
                    continue;
                }
                let a = amp(&pooled);
                if a <= K_AMP {
                    let e = entry("pooled", from, &pooled);
                    return Ok((pooled, Some(e)));
                }
                if best.as_ref().is_none_or(|b| a < b.0) {
                    best = Some((a, pooled, "pooled", from.clone()));
                }
            }
            match best {
                Some((_, s, action, from)) => {
                    let e = entry(action, from, &s);
                    Ok((s, Some(e)))
                }
                // Nothing determines even a reduced basis: the minimum-norm fit of its own lights.
                None => {
                    let (s, _, _) = fit(&own, own_pairs, &full)?;
                    let e = entry(if n == 0 { "zero" } else { "clamped" }, Vec::new(), &s);
                    Ok((s, Some(e)))
                }
            }
        }
    }
}

/// Fit every view slot of `btf`: the slots and the report entries of those that needed a fallback.
pub fn fit_slots(
    btf: &BtfRef<'_>,
    basis: &LightBasis<'_>,
    opts: &SlotOptions,
) -> Result<(Vec<Slot>, Vec<DegenerateSlot>)> {
    if !(opts.rcond.is_finite() && opts.rcond > 0.0 && opts.rcond < 1.0) {
        return Err(Error::arg("rcond", format!("expected a value in (0, 1), got {}", opts.rcond)));
    }
    if !(opts.lambda.is_finite() && opts.lambda >= 0.0) {
        return Err(Error::arg("lambda", format!("expected a finite value >= 0, got {}", opts.lambda)));
    }
    let mut slots = Vec::with_capacity(btf.views.len());
    let mut degenerate = Vec::new();
    let mut memo = OwnFits::new();
    for v in 0..btf.views.len() {
        let (s, e) = slot_fit(btf, v, basis, opts, &mut memo)?;
        slots.push(s);
        degenerate.extend(e);
    }
    Ok((slots, degenerate))
}

/// Fitted coefficients as the renderer holds them: 32-bit floats, or 8-bit planes with a scale
/// and a bias per plane ([`Planes`]; `k` planes = the values per texel). `values` are always the
/// decoded floats (what [`crate::ReflectanceModel::eval`] reads), so the CPU reference computes
/// exactly what the shader decodes.
#[derive(Debug, Clone, PartialEq)]
pub struct Coeffs {
    /// Decoded values, texel-major (`texels * k`).
    pub values: Vec<f32>,
    /// The 8-bit planes, or None for floats.
    pub planes: Option<Planes>,
}

/// Check a `bits` option: 8 (planes) or 32 (floats).
pub fn check_bits(bits: u32) -> Result<()> {
    if bits == 8 || bits == 32 {
        Ok(())
    } else {
        Err(Error::arg(
            "bits",
            format!("expected 8 (8-bit planes with per-plane scale and bias) or 32 (floats), got {bits}"),
        ))
    }
}

impl Coeffs {
    /// Floats kept as they are (`bits` 32) or quantized to planes of `k` values per texel (8).
    pub fn new(values: Vec<f32>, k: usize, bits: u32) -> Result<Coeffs> {
        check_bits(bits)?;
        if bits == 32 {
            return Ok(Coeffs { values, planes: None });
        }
        let planes = Planes::quantize(&values, k)?;
        // Dequantized into the floats' own buffer: a second copy would double the fit's peak
        // memory (a fit under a memory limit holds the model and little else).
        let mut values = values;
        planes.dequantize_into(&mut values);
        Ok(Coeffs { values, planes: Some(planes) })
    }

    /// From planes (decoded once).
    pub fn from_planes(planes: Planes) -> Coeffs {
        Coeffs { values: planes.dequantize(), planes: Some(planes) }
    }

    /// 8 or 32.
    pub fn bits(&self) -> u32 {
        if self.planes.is_some() {
            8
        } else {
            32
        }
    }

    /// The store parts: floats (one part), or the packed bytes then scale and bias (two parts).
    pub fn parts(&self) -> Vec<Cow<'_, [u32]>> {
        match &self.planes {
            None => vec![words(&self.values)],
            Some(p) => vec![Cow::Owned(p.words()), Cow::Owned(p.scale_bias_words())],
        }
    }

    /// Store as `name` (f32, `shape`) or, quantized, as `{name}_q`, `{name}_scale`, `{name}_bias`
    /// (see [`Planes::insert_into`]).
    pub fn insert_into(&self, a: &mut NamedArrays, name: &str, shape: &[usize]) {
        match &self.planes {
            None => a.put(name, shape, self.values.clone()),
            Some(p) => p.insert_into(a, &format!("{name}_"), shape.to_vec()),
        }
    }

    /// Read back what [`Coeffs::insert_into`] stored: `{name}_q` (with scale and bias) when
    /// present, else the floats `name`, of shape `shape` (`None` = any; its product over the
    /// leading `lead` axes is the texel count, the rest the planes).
    pub fn from_arrays(
        a: &NamedArrays,
        name: &str,
        shape: &[Option<usize>],
        lead: usize,
    ) -> Result<(Coeffs, Vec<usize>)> {
        let qn = format!("{name}_q");
        if let Some(arr) = a.array(&qn) {
            let sh = arr.shape.clone();
            btfrs_core::arrays::check_shape(&qn, &sh, shape)?;
            let texels: usize = sh[..lead].iter().product();
            let k: usize = sh[lead..].iter().product();
            let p = Planes::from_arrays(a, &format!("{name}_"), texels, k)?;
            return Ok((Coeffs::from_planes(p), sh));
        }
        let (v, sh) = a.get::<f32>(name, shape)?;
        check_finite(name, v)?;
        Ok((Coeffs { values: v.to_vec(), planes: None }, sh.to_vec()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A row fitted texel by texel, 8 texels at a time (portable), and as the CPU chooses, gives
    /// the same coefficients to the bit, for term counts with and without their own instance,
    /// a row that is not a multiple of 8 and slots over a subset of the pairs (a mask).
    #[test]
    fn groups_of_texels_equal_one_at_a_time() {
        let mut rng = btfrs_core::rng::Rng::new(1);
        let mut u = move || rng.next_f64();
        let (nv, nl, w) = (3usize, 20usize, 19usize);
        let abrdf = nv * nl * 3;
        let row: Vec<f32> = (0..w * abrdf).map(|_| u() as f32).collect();
        for k in [4usize, 6, 9, 16, 5] {
            let slots: Vec<Slot> = (0..nv)
                .map(|v| {
                    // Every other light of slot 1 is absent.
                    let lights: Vec<usize> = (0..nl).filter(|l| v != 1 || l % 2 == 0).collect();
                    let pairs: Vec<usize> = lights.iter().map(|l| v * nl + l).collect();
                    let p: Vec<f64> = (0..k * lights.len()).map(|_| u() - 0.5).collect();
                    Slot::new(pairs, lights, &p, &(0..k).collect::<Vec<_>>(), k)
                })
                .collect();
            let n = w * nv * 3 * k;
            let (mut one, mut eight, mut four, mut chosen) =
                (vec![0.0f32; n], vec![0.0f32; n], vec![0.0f32; n], vec![0.0f32; n]);
            let scan = btfrs_core::btf::TexelScan::new();
            let r = Row { values: &row, abrdf, first: 0, screen: None };
            assert!(fit_row_groups::<1, false>(&slots, &r, &mut one, &scan));
            assert!(fit_row_groups::<8, false>(&slots, &r, &mut eight, &scan));
            assert!(fit_row_groups::<4, true>(&slots, &r, &mut four, &scan));
            assert!(fit_row_rgb(&slots, &r, &mut chosen, &scan));
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&one), bits(&eight), "k {k}");
            assert_eq!(bits(&one), bits(&four), "k {k}");
            assert_eq!(bits(&one), bits(&chosen), "k {k}");
            // And one texel by itself against an f64 sum of the slot's products.
            let (t, v) = (17, 1);
            let s = &slots[v];
            for c in 0..3 {
                for j in 0..k {
                    let want: f64 = s
                        .pairs
                        .iter()
                        .enumerate()
                        .map(|(i, &q)| s.pt[i * k + j] * row[t * abrdf + q * 3 + c] as f64)
                        .sum();
                    let got = one[(t * nv + v) * 3 * k + c * k + j];
                    assert!((got as f64 - want).abs() <= 1e-6 * (1.0 + want.abs()), "k {k}: {got} vs {want}");
                }
            }
        }
        // A value that is not finite stops the row.
        let mut bad = row.clone();
        bad[9 * abrdf + 4] = f32::NAN;
        let slots = vec![Slot::new(vec![0], vec![0], &[1.0; 6], &[0, 1, 2, 3, 4, 5], 6)];
        let mut out = vec![0.0f32; w * 18];
        let r = Row { values: &bad, abrdf, first: 0, screen: None };
        assert!(!fit_row_rgb(&slots, &r, &mut out, &btfrs_core::btf::TexelScan::new()));
    }
}
