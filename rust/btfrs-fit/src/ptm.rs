//! Polynomial Texture Maps (Malzbender et al. 2001), fitted per view slot as in paper 000,
//! section 3.1.
//!
//! For a fixed view, each texel's value under light `l` is modelled by the biquadratic
//!
//! ```text
//! L(lu, lv) = a0 lu^2 + a1 lv^2 + a2 lu lv + a3 lu + a4 lv + a5
//! ```
//!
//! where (lu, lv) are the light direction's x and y in the tangent frame. The least-squares fit
//! of all texels shares one design matrix per view slot, so its pseudo-inverse is computed once
//! (by SVD, small singular values clamped) and applied to every texel: the fit costs one pass over
//! the data. Two variants:
//!
//! * **RGB**: one polynomial per channel, 18 coefficients per texel and view slot;
//! * **LRGB**: one polynomial for the luminance (the channel mean) and a per-texel base colour,
//!   `rgb(l) = L(l) * base`, 6 + 3 values. The base colour is the least-squares modulation of the
//!   fitted luminance, then scaled so its largest channel is 1 (the factor moves into the
//!   polynomial), which is the convention of the `.ptm` LRGB format.
//!
//! A view slot needs at least 6 lights whose (lu, lv) are not degenerate (e.g. all on one line).
//! Paper 000 (section 6) fits a complete UBO sampling, where every slot has 81 lights; with
//! sparse or uneven sampling (a random 10% of the 6561 pairs leaves some slots 4 or 5 lights)
//! one such slot used to fail the whole fit. What happens to it is [`Degenerate`]:
//!
//! * **reduce** (the default): such a slot is fitted from fewer terms, the plane
//!   `a3 lu + a4 lv + a5` of its own lights when they determine it (3 or more not on one line)
//!   without extrapolating, else from its lights pooled with those of the nearest view slots (by
//!   angle) until the biquadratic is determined. The same happens to a slot that has 6 or more
//!   lights but whose fit would extrapolate: few lights clustered in one part of the
//!   hemisphere give a biquadratic that is exact at them and wild elsewhere (the *amplification*
//!   [`K_AMP`]; a random 10% of the pairs gave a held-out relative error of 5.9 on the built-in
//!   grooves from such slots, 0.80 with this policy). Well-sampled slots keep their own full fit,
//!   and [`Ptm::degenerate_slots`] (the model's `report`) lists each other slot, why and what
//!   was done, so no fallback is silent. It is the default because a sparse slot is a property
//!   of the sampling, not an error of the user, and a reported, local fallback costs the user
//!   less than a failed fit;
//! * **raise**: fail with [`Error::Degenerate`] naming the slot;
//! * **clamp**: the minimum-norm least-squares solution (small singular values zeroed).

mod slot;

use crate::gpu::{words, GpuLayout, Shader};
use crate::model::{Model, ReflectanceModel};
use btfrs_core::arrays::check_finite;
use btfrs_core::{directions, BtfRef, Error, Monitor, NamedArrays, Result};
use nalgebra::DMatrix;
use rayon::prelude::*;
use std::borrow::Cow;

pub use slot::PtmSlot;

/// Coefficients per polynomial.
pub const NCOEF: usize = 6;

/// Which PTM variant.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PtmKind {
    /// One polynomial per channel (18 coefficients).
    Rgb,
    /// A luminance polynomial times a base colour (6 + 3).
    Lrgb,
}

/// What to do with a view slot whose lights do not determine the 6 coefficients.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Degenerate {
    /// Fail with [`Error::Degenerate`] naming the slot.
    Raise,
    /// Zero the small singular values: the minimum-norm least-squares solution.
    Clamp,
    /// Fewer terms, else the lights of the nearest view slots; also for slots whose fit would
    /// extrapolate (amplification above [`K_AMP`]). Each such slot is listed in
    /// [`Ptm::degenerate_slots`].
    Reduce,
}

/// Under [`Degenerate::Reduce`], a slot's fit is accepted only when no prediction at any light
/// direction of the BTF exceeds `K_AMP` times the largest |sample| of the slot: the fit's
/// *amplification*, `max_l sum_i |w_i(l)|` where `w(l) = P^T b(l)` are the weights the fit gives
/// each sample in the prediction at light `l`. It depends on the light directions only (one
/// number per slot, no data). A complete UBO slot has 2.2 (biquadratic) and 1.7 (the plane); 6
/// to 10 random lights give 7 to 30 (median), and a random 10% of the pairs made the PTM's
/// held-out relative error 5.9 on the built-in grooves (16^2) from such slots alone. 4 is met by
/// every slot of a complete or half sampling and rejects the runaway ones.
pub const K_AMP: f64 = 4.0;

/// A view slot that did not get the plain biquadratic fit of its own lights, and what was done.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct DegenerateSlot {
    /// The view slot index.
    pub slot: usize,
    /// Its present lights.
    pub lights: usize,
    /// Why: `"few lights"` (< 6), `"degenerate lights"` (rank-deficient, e.g. collinear) or
    /// `"extrapolates"` (amplification above [`K_AMP`]).
    pub reason: &'static str,
    /// `"linear"` (the plane `a3 lu + a4 lv + a5` of its own lights), `"pooled"` (the
    /// biquadratic of its lights and those of the slots `from`, the nearest views first),
    /// `"kept"` (its own biquadratic: no alternative extrapolated less), `"clamped"` (the
    /// minimum-norm fit) or `"zero"` (no light at all).
    pub action: &'static str,
    /// The slots whose lights were pooled in.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub from: Vec<usize>,
    /// The amplification of the fit used (see [`K_AMP`]).
    pub amplification: f64,
}

/// Fit options.
#[derive(Debug, Clone, Copy, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PtmOptions {
    /// The variant.
    pub kind: PtmKind,
    /// Singular values below `rcond * s_max` count as zero.
    pub rcond: f64,
    /// Policy for rank-deficient view slots.
    pub on_degenerate: Degenerate,
}

impl Default for PtmOptions {
    fn default() -> Self {
        PtmOptions { kind: PtmKind::Rgb, rcond: 1e-6, on_degenerate: Degenerate::Reduce }
    }
}

/// A fitted PTM: one polynomial set per texel and view slot.
#[derive(Debug, Clone)]
pub struct Ptm {
    /// The variant.
    pub kind: PtmKind,
    /// Rows.
    pub height: usize,
    /// Columns.
    pub width: usize,
    /// The view direction of each slot.
    pub views: Vec<[f64; 3]>,
    /// Rgb: `[H, W, V, 3, 6]`; Lrgb: `[H, W, V, 6]`.
    pub coeffs: Vec<f32>,
    /// Lrgb only: `[H, W, V, 3]` base colour, largest channel 1 (or all 0 for a black texel).
    pub rgb: Option<Vec<f32>>,
    /// The slots fitted by a fallback (empty for a loaded model: files do not record it).
    pub degenerate_slots: Vec<DegenerateSlot>,
}

/// The six basis functions at light direction `l`.
#[inline]
pub fn basis(l: [f64; 3]) -> [f64; NCOEF] {
    let (u, v) = (l[0], l[1]);
    [u * u, v * v, u * v, u, v, 1.0]
}

/// The pseudo-inverse `[k, n]` (row-major) of the design matrix of `lights` over the basis
/// columns `cols` (indices into [`basis`]), with singular values below `rcond * s_max` zeroed;
/// its rank and smallest/largest singular value ratio. `None` when the SVD fails.
fn pinv_cols(lights: &[[f64; 3]], cols: &[usize], rcond: f64) -> Option<(Vec<f64>, usize, f64)> {
    let (n, k) = (lights.len(), cols.len());
    if n == 0 {
        return Some((Vec::new(), 0, 0.0));
    }
    let a = DMatrix::from_fn(n, k, |i, j| basis(lights[i])[cols[j]]);
    let svd = a.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    let s = &svd.singular_values;
    let smax = s.iter().copied().fold(0.0f64, f64::max);
    let cut = rcond * smax;
    let rank = s.iter().filter(|&&x| x > cut).count();
    let smin = if s.len() < k { 0.0 } else { s.iter().copied().fold(f64::INFINITY, f64::min) };
    // pinv = V diag(1/s) U^T with the clamped singular values' reciprocals set to zero.
    let mut p = vec![0.0f64; k * n];
    for (j, &sj) in s.iter().enumerate() {
        if sj <= cut {
            continue;
        }
        for c in 0..k {
            let vk = vt[(j, c)] / sj;
            for i in 0..n {
                p[c * n + i] += vk * u[(i, j)];
            }
        }
    }
    Some((p, rank, smin / smax.max(f64::MIN_POSITIVE)))
}

/// A slot's fit: the samples it reads (flat `v * L + l` pair indices and their lights) and its
/// pseudo-inverse in the full basis, stored transposed (`[n][6]`, unused terms 0) so that the
/// per-texel loop walks the samples and the matrix in the same order.
struct Slot {
    pairs: Vec<usize>,
    lights: Vec<usize>,
    pt: Vec<[f64; NCOEF]>,
}

impl Slot {
    /// From a `[k, n]` pseudo-inverse over basis columns `cols`.
    fn new(pairs: Vec<usize>, lights: Vec<usize>, p: &[f64], cols: &[usize]) -> Slot {
        let n = pairs.len();
        let pt = (0..n)
            .map(|i| {
                let mut row = [0.0f64; NCOEF];
                for (j, &c) in cols.iter().enumerate() {
                    row[c] = p[j * n + i];
                }
                row
            })
            .collect();
        Slot { pairs, lights, pt }
    }

    /// `max_l sum_i |w_i(l)|` over the light directions `all` (see [`K_AMP`]).
    fn amplification(&self, all: &[[f64; 3]]) -> f64 {
        all.iter()
            .map(|&l| {
                let b = basis(l);
                self.pt.iter().map(|r| (0..NCOEF).map(|k| r[k] * b[k]).sum::<f64>().abs()).sum::<f64>()
            })
            .fold(0.0, f64::max)
    }
}

const FULL: [usize; NCOEF] = [0, 1, 2, 3, 4, 5];
const PLANE: [usize; 3] = [3, 4, 5];

/// The fit of view slot `v` under `opts`, and its entry in the report when it is not the plain
/// biquadratic of its own lights.
fn slot_fit(btf: &BtfRef<'_>, v: usize, opts: &PtmOptions) -> Result<(Slot, Option<DegenerateSlot>)> {
    let nl = btf.lights.len();
    let own = btf.lights_of_view(v);
    let n = own.len();
    let dirs = |ls: &[usize]| -> Vec<[f64; 3]> { ls.iter().map(|&l| btf.lights[l]).collect() };
    let name = || {
        let (theta, phi) = directions::to_theta_phi(btf.views[v]);
        format!("view slot {v} (theta {:.1}, phi {:.1} deg)", theta.to_degrees(), phi.to_degrees())
    };
    let fit = |ls: &[usize], pairs: Vec<usize>, cols: &[usize]| -> Result<(Slot, usize, f64)> {
        let (p, rank, ratio) = pinv_cols(&dirs(ls), cols, opts.rcond)
            .ok_or_else(|| Error::Degenerate(format!("{}: the SVD of the light design matrix failed", name())))?;
        Ok((Slot::new(pairs, ls.to_vec(), &p, cols), rank, ratio))
    };
    let own_pairs: Vec<usize> = own.iter().map(|&l| v * nl + l).collect();
    let (full, rank, ratio) = fit(&own, own_pairs.clone(), &FULL)?;
    let reason = if n < NCOEF {
        "few lights"
    } else if rank < NCOEF {
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
        amplification: slot.amplification(btf.lights),
    };
    match opts.on_degenerate {
        Degenerate::Raise | Degenerate::Clamp => {
            if n < NCOEF && opts.on_degenerate == Degenerate::Raise {
                return Err(Error::Degenerate(format!(
                    "{} has {n} lights; a biquadratic PTM needs at least {NCOEF} (on_degenerate=\"reduce\" fits such \
                     a slot from fewer terms or its neighbours' lights, \"clamp\" gives the minimum-norm fit)",
                    name()
                )));
            }
            if rank == NCOEF {
                return Ok((full, None));
            }
            if opts.on_degenerate == Degenerate::Raise {
                return Err(Error::Degenerate(format!(
                    "{}: its {n} lights determine only {rank} of the {NCOEF} PTM coefficients (smallest/largest \
                     singular value {ratio:.2e} < rcond {:.0e}); the lights' (x, y) are degenerate, e.g. collinear \
                     (on_degenerate=\"reduce\" fits such a slot from fewer terms or its neighbours' lights)",
                    name(),
                    opts.rcond
                )));
            }
            let e = entry(if n == 0 { "zero" } else { "clamped" }, Vec::new(), &full);
            Ok((full, Some(e)))
        }
        Degenerate::Reduce => {
            // Candidates in order of preference; the first within K_AMP is taken, else the one
            // with the least amplification.
            if rank == NCOEF && full.amplification(btf.lights) <= K_AMP {
                return Ok((full, None));
            }
            // A full-rank but extrapolating fit of its own lights is kept only if nothing else does better.
            let mut best: Option<(f64, Slot, &'static str, Vec<usize>)> = None;
            if rank == NCOEF {
                best = Some((full.amplification(btf.lights), full, "kept", Vec::new()));
            }
            if n >= 3 {
                let (plane, r3, _) = fit(&own, own_pairs.clone(), &PLANE)?;
                if r3 == 3 {
                    let a = plane.amplification(btf.lights);
                    if a <= K_AMP {
                        let e = entry("linear", Vec::new(), &plane);
                        return Ok((plane, Some(e)));
                    }
                    if best.as_ref().is_none_or(|b| a < b.0) {
                        best = Some((a, plane, "linear", Vec::new()));
                    }
                }
            }
            // Pool the lights of the nearest views (by angle): a neighbouring view sees nearly the
            // same reflectance field, and the union of their lights covers the light hemisphere.
            let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
            let mut order: Vec<usize> = (0..btf.views.len()).filter(|&u| u != v).collect();
            order.sort_by(|&a, &b| dot(btf.views[v], btf.views[b]).total_cmp(&dot(btf.views[v], btf.views[a])));
            let (mut ls, mut pairs, mut from) = (own.clone(), own_pairs.clone(), Vec::new());
            for u in order {
                let more = btf.lights_of_view(u);
                if more.is_empty() {
                    continue;
                }
                from.push(u);
                pairs.extend(more.iter().map(|&l| u * nl + l));
                ls.extend(more);
                if ls.len() < NCOEF {
                    continue;
                }
                let (pooled, r, _) = fit(&ls, pairs.clone(), &FULL)?;
                if r < NCOEF {
                    continue;
                }
                let a = pooled.amplification(btf.lights);
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
                // Nothing determines even a plane: the minimum-norm fit of its own lights.
                None => {
                    let (s, _, _) = fit(&own, own_pairs, &FULL)?;
                    let e = entry(if n == 0 { "zero" } else { "clamped" }, Vec::new(), &s);
                    Ok((s, Some(e)))
                }
            }
        }
    }
}

/// Fit a PTM to the present (view, light) pairs of `btf`; `monitor` counts texel rows.
pub fn fit_ptm(btf: &BtfRef<'_>, opts: &PtmOptions, monitor: &Monitor) -> Result<Ptm> {
    if !(opts.rcond.is_finite() && opts.rcond > 0.0 && opts.rcond < 1.0) {
        return Err(Error::arg("rcond", format!("expected a value in (0, 1), got {}", opts.rcond)));
    }
    let nv = btf.views.len();
    let fitted: Vec<(Slot, Option<DegenerateSlot>)> = (0..nv).map(|v| slot_fit(btf, v, opts)).collect::<Result<_>>()?;
    let mut slots = Vec::with_capacity(nv);
    let mut degenerate_slots = Vec::new();
    for (s, e) in fitted {
        slots.push(s);
        degenerate_slots.extend(e);
    }

    let (h, w) = (btf.height, btf.width);
    let per_coef = match opts.kind {
        PtmKind::Rgb => 3 * NCOEF,
        PtmKind::Lrgb => NCOEF,
    };
    let mut coeffs = vec![0.0f32; h * w * nv * per_coef];
    let mut rgb = match opts.kind {
        PtmKind::Rgb => Vec::new(),
        PtmKind::Lrgb => vec![0.0f32; h * w * nv * 3],
    };
    monitor.start(h as u64);
    let row_c = w * nv * per_coef;
    let row_rgb = if opts.kind == PtmKind::Lrgb { w * nv * 3 } else { 0 };
    let mut rgb_rows: Vec<&mut [f32]> =
        if row_rgb > 0 { rgb.chunks_mut(row_rgb).collect() } else { (0..h).map(|_| &mut [][..]).collect() };
    coeffs.par_chunks_mut(row_c).zip(rgb_rows.par_iter_mut()).enumerate().for_each(|(row, (crow, rrow))| {
        if monitor.is_cancelled() {
            return;
        }
        for col in 0..w {
            let abrdf = btf.texel(row * w + col);
            for (v, slot) in slots.iter().enumerate() {
                let out = &mut crow[(col * nv + v) * per_coef..(col * nv + v + 1) * per_coef];
                match opts.kind {
                    PtmKind::Rgb => fit_rgb(slot, abrdf, out),
                    PtmKind::Lrgb => {
                        let base = &mut rrow[(col * nv + v) * 3..(col * nv + v + 1) * 3];
                        fit_lrgb(slot, abrdf, btf.lights, out, base)
                    }
                }
            }
        }
        monitor.advance(1);
    });
    monitor.check()?;
    Ok(Ptm {
        kind: opts.kind,
        height: h,
        width: w,
        views: btf.views.to_vec(),
        coeffs,
        rgb: (opts.kind == PtmKind::Lrgb).then_some(rgb),
        degenerate_slots,
    })
}

/// 18 coefficients `[3][6]` of one texel and slot from the texel's ABRDF; f64 accumulation.
#[inline]
fn fit_rgb(slot: &Slot, abrdf: &[f32], out: &mut [f32]) {
    let mut acc = [[0.0f64; NCOEF]; 3];
    for (&i, p) in slot.pairs.iter().zip(&slot.pt) {
        let x = &abrdf[i * 3..i * 3 + 3];
        for c in 0..3 {
            let xc = x[c] as f64;
            for k in 0..NCOEF {
                acc[c][k] += p[k] * xc;
            }
        }
    }
    for c in 0..3 {
        for k in 0..NCOEF {
            out[c * NCOEF + k] = acc[c][k] as f32;
        }
    }
}

/// Luminance coefficients and base colour of one texel and slot.
#[inline]
fn fit_lrgb(slot: &Slot, abrdf: &[f32], lights: &[[f64; 3]], out: &mut [f32], base: &mut [f32]) {
    let mut a = [0.0f64; NCOEF];
    for (&i, p) in slot.pairs.iter().zip(&slot.pt) {
        let x = &abrdf[i * 3..i * 3 + 3];
        let lum = (x[0] as f64 + x[1] as f64 + x[2] as f64) / 3.0;
        for k in 0..NCOEF {
            a[k] += p[k] * lum;
        }
    }
    // Least-squares modulation: base_c = sum L(l) rgb_c(l) / sum L(l)^2 over the slot's samples.
    let (mut num, mut den) = ([0.0f64; 3], 0.0f64);
    for (&i, &l) in slot.pairs.iter().zip(&slot.lights) {
        let b = basis(lights[l]);
        let lf: f64 = (0..NCOEF).map(|k| a[k] * b[k]).sum();
        let x = &abrdf[i * 3..i * 3 + 3];
        for c in 0..3 {
            num[c] += lf * x[c] as f64;
        }
        den += lf * lf;
    }
    let mut col = if den > 0.0 { num.map(|n| n / den) } else { [0.0; 3] };
    let m = col.iter().copied().fold(0.0f64, f64::max);
    if m > 0.0 {
        col = col.map(|c| (c / m).max(0.0));
        a = a.map(|x| x * m);
    } else {
        // A black (or negative) texel: nothing to modulate.
        col = [0.0; 3];
        a = [0.0; NCOEF];
    }
    for k in 0..NCOEF {
        out[k] = a[k] as f32;
    }
    for c in 0..3 {
        base[c] = col[c] as f32;
    }
}

/// A prepared PTM query: view-slot weights and the light's basis.
#[derive(Debug, Clone)]
pub struct PtmQuery {
    slots: Vec<(usize, f32)>,
    basis: [f32; NCOEF],
}

impl Ptm {
    /// Values per texel and slot in `coeffs`.
    fn per_coef(&self) -> usize {
        match self.kind {
            PtmKind::Rgb => 3 * NCOEF,
            PtmKind::Lrgb => NCOEF,
        }
    }

    /// Check that the arrays agree with the dimensions (for models built from loaded files).
    pub fn validate(&self) -> Result<()> {
        let t = self.height * self.width * self.views.len();
        if self.height == 0 || self.width == 0 {
            return Err(Error::arg("coeffs", "the PTM has no texels"));
        }
        directions::validate("views", &self.views)?;
        if self.coeffs.len() != t * self.per_coef() {
            return Err(Error::arg(
                "coeffs",
                format!("expected {} values, got {}", t * self.per_coef(), self.coeffs.len()),
            ));
        }
        match (&self.rgb, self.kind) {
            (Some(r), PtmKind::Lrgb) if r.len() == t * 3 => {}
            (None, PtmKind::Rgb) => {}
            _ => return Err(Error::arg("rgb", "expected a [H, W, V, 3] base colour for LRGB and none for RGB")),
        }
        Ok(())
    }
}

impl ReflectanceModel for Ptm {
    type Query = PtmQuery;

    fn dims(&self) -> (usize, usize) {
        (self.height, self.width)
    }

    fn query(&self, view: [f64; 3], light: [f64; 3]) -> PtmQuery {
        // The PTM is only defined at its view slots; in between, blend the three nearest.
        let slots = directions::interp_weights(&self.views, view, 3).into_iter().map(|(i, w)| (i, w as f32)).collect();
        PtmQuery { slots, basis: basis(light).map(|b| b as f32) }
    }

    #[inline]
    fn eval(&self, t: usize, q: &PtmQuery) -> [f32; 3] {
        let nv = self.views.len();
        let pc = self.per_coef();
        let mut out = [0.0f32; 3];
        for &(v, wgt) in &q.slots {
            let c = &self.coeffs[(t * nv + v) * pc..(t * nv + v + 1) * pc];
            match self.kind {
                PtmKind::Rgb => {
                    for ch in 0..3 {
                        let s: f32 = (0..NCOEF).map(|k| c[ch * NCOEF + k] * q.basis[k]).sum();
                        out[ch] += wgt * s;
                    }
                }
                PtmKind::Lrgb => {
                    let l: f32 = (0..NCOEF).map(|k| c[k] * q.basis[k]).sum();
                    let base = &self.rgb.as_ref().expect("validated: LRGB has base colours")[(t * nv + v) * 3..];
                    for ch in 0..3 {
                        out[ch] += wgt * l * base[ch];
                    }
                }
            }
        }
        out
    }
}

crate::gpu_params! {
    /// Parameters of `ptm.wgsl`.
    pub struct PtmParams {
        /// 0 = RGB, 1 = LRGB.
        pub kind: u32,
        /// Number of view slots V (their directions are `mdirs[0 .. V]`).
        pub n_views: u32,
        /// Offset of the slots' candidate table in `tables`.
        pub view_table: u32,
        /// Store offset of the coefficients: RGB `[texel][V][3][6]`, LRGB `[texel][V][6]` f32.
        pub coeffs: u32,
        /// Store offset of the LRGB base colours `[texel][V][3]` f32.
        pub rgb: u32,
    }
}

impl GpuLayout for Ptm {
    type Params = PtmParams;
    const SHADER: Shader = Shader::new::<PtmParams>("ptm", include_str!("../../../shaders_wgsl/ptm.wgsl"));

    fn parts(&self) -> Vec<Cow<'_, [u32]>> {
        let mut p = vec![words(&self.coeffs)];
        if let Some(rgb) = &self.rgb {
            p.push(words(rgb));
        }
        p
    }

    fn dir_sets(&self) -> Vec<&[[f64; 3]]> {
        vec![&self.views]
    }

    fn params(&self, offsets: &[u32], tables: &[u32]) -> PtmParams {
        PtmParams {
            kind: match self.kind {
                PtmKind::Rgb => 0,
                PtmKind::Lrgb => 1,
            },
            n_views: self.views.len() as u32,
            view_table: tables[0],
            coeffs: offsets[0],
            rgb: offsets.get(1).copied().unwrap_or(0),
        }
    }
}

impl Model for Ptm {
    const KIND: &'static str = "ptm";
    const TEXEL_ARRAYS: &'static [&'static str] = &["coeffs", "rgb"];
    const DOC: &'static str = "Polynomial Texture Maps per view slot (paper 000, section 3.1)";
    const EXAMPLES: &'static [(&'static str, &'static str)] =
        &[("PTM-LRGB", r#"{"kind": "lrgb"}"#), ("PTM-RGB", r#"{"kind": "rgb"}"#)];
    type Options = PtmOptions;

    fn fit(btf: &BtfRef<'_>, options: &PtmOptions, monitor: &Monitor) -> Result<Self> {
        fit_ptm(btf, options, monitor)
    }

    /// `coeffs` (RGB `[H, W, V, 3, 6]`, LRGB `[H, W, V, 6]`), `views` `[V, 3]` and, for LRGB,
    /// `rgb` `[H, W, V, 3]`. The kind follows from the shape of `coeffs`.
    fn to_arrays(&self) -> NamedArrays {
        let mut a = NamedArrays::new();
        let (h, w, nv) = (self.height, self.width, self.views.len());
        match self.kind {
            PtmKind::Rgb => a.put("coeffs", &[h, w, nv, 3, NCOEF], self.coeffs.clone()),
            PtmKind::Lrgb => a.put("coeffs", &[h, w, nv, NCOEF], self.coeffs.clone()),
        }
        a.put_directions("views", &self.views);
        if let Some(rgb) = &self.rgb {
            a.put("rgb", &[h, w, nv, 3], rgb.clone());
        }
        a
    }

    /// `{"degenerate_slots": [{"slot", "lights", "action", "from"?}, ...]}`: the slots fitted
    /// by a fallback (empty when all had the full fit, or for a loaded model).
    fn report(&self) -> serde_json::Value {
        serde_json::json!({ "degenerate_slots": self.degenerate_slots })
    }

    fn from_arrays(a: &NamedArrays) -> Result<Self> {
        let views = a.directions("views", None)?;
        let nv = Some(views.len());
        let (coeffs, sh) = match a.get::<f32>("coeffs", &[None, None, nv, Some(3), Some(NCOEF)]) {
            Ok(c) => c,
            Err(_) => a.get::<f32>("coeffs", &[None, None, nv, Some(NCOEF)]).map_err(|_| {
                Error::arg(
                    "coeffs",
                    format!("expected shape [H, W, {}, 3, 6] (RGB) or [H, W, {}, 6] (LRGB)", views.len(), views.len()),
                )
            })?,
        };
        check_finite("coeffs", coeffs)?;
        let kind = if sh.len() == 5 { PtmKind::Rgb } else { PtmKind::Lrgb };
        let rgb = match kind {
            PtmKind::Rgb => None,
            PtmKind::Lrgb => {
                let (r, _) = a.get::<f32>("rgb", &[Some(sh[0]), Some(sh[1]), nv, Some(3)])?;
                check_finite("rgb", r)?;
                Some(r.to_vec())
            }
        };
        let m = Ptm {
            kind,
            height: sh[0],
            width: sh[1],
            views,
            coeffs: coeffs.to_vec(),
            rgb,
            degenerate_slots: Vec::new(),
        };
        m.validate()?;
        Ok(m)
    }
}

#[cfg(test)]
mod tests;
