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
use crate::lightfit::{check_bits, fit_slots, Coeffs, LightBasis, Slot, SlotOptions};
use crate::model::{average_texels, Bench, CoefficientFeatures, Mip, Model, ReflectanceModel, Sampling, Setting};
use crate::options::Spec;
use crate::planes::Planes;
use btfrs_core::btf::TexelScan;
use btfrs_core::{directions, BtfRef, Error, Monitor, NamedArrays, Result};
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

pub use crate::lightfit::{Degenerate, DegenerateSlot, K_AMP};

/// Fit options.
#[derive(Debug, Clone, Copy, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PtmOptions {
    /// The variant.
    pub kind: PtmKind,
    /// Singular values below `rcond * s_max` count as zero.
    pub rcond: f64,
    /// Policy for rank-deficient view slots.
    pub on_degenerate: Degenerate,
    /// Storage of the fitted coefficients: 8 (the default) quantizes them to 8-bit planes with a
    /// scale and a bias per plane, as `.ptm` files and RTI viewers hold them, so that `nbytes` is
    /// what a viewer holds; 32 keeps the floats.
    pub bits: u32,
}

impl Default for PtmOptions {
    /// The defaults of [`Ptm`]'s option schema.
    fn default() -> Self {
        crate::options::defaults(<Ptm as Model>::OPTIONS)
    }
}

/// The 8-bit planes of a quantized PTM: `coeffs` over the `[H, W, V, 3, 6]` (RGB) or
/// `[H, W, V, 6]` (LRGB) coefficients, one plane per slot, channel and coefficient (`k` =
/// `V * 18` or `V * 6`), and for LRGB `rgb` over the `[H, W, V, 3]` base colours.
#[derive(Debug, Clone, PartialEq)]
pub struct PtmPlanes {
    /// The polynomial coefficients.
    pub coeffs: Planes,
    /// LRGB only: the base colours.
    pub rgb: Option<Planes>,
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
    /// The 8-bit planes when quantized (`bits` 8): then `coeffs` and `rgb` are their decoded
    /// values, and the planes are what the renderer uploads and `nbytes` counts.
    pub quantized: Option<PtmPlanes>,
}

/// The six basis functions at light direction `l`.
#[inline]
pub fn basis(l: [f64; 3]) -> [f64; NCOEF] {
    let (u, v) = (l[0], l[1]);
    [u * u, v * v, u * v, u, v, 1.0]
}

/// The basis as the per-slot fit sees it: the plane `a3 lu + a4 lv + a5` is the reduced basis.
fn light_basis() -> LightBasis<'static> {
    LightBasis {
        k: NCOEF,
        eval: &|l, out| out.copy_from_slice(&basis(l)),
        what: "a biquadratic PTM",
        coefficients: "PTM coefficients",
        reduced: vec![("linear", vec![3, 4, 5])],
    }
}

/// Fit a PTM to the present (view, light) pairs of `btf`; `monitor` counts texel rows.
pub fn fit_ptm(btf: &BtfRef<'_>, opts: &PtmOptions, monitor: &Monitor) -> Result<Ptm> {
    fit_ptm_screened(btf, opts, None, monitor)
}

/// [`fit_ptm`] with the robust value screen run on each texel inside the fit's pass
/// ([`crate::robust::TexelScreen`]; `None`: the values as measured).
pub fn fit_ptm_screened(
    btf: &BtfRef<'_>,
    opts: &PtmOptions,
    screen: Option<&crate::robust::TexelScreen<'_>>,
    monitor: &Monitor,
) -> Result<Ptm> {
    check_bits(opts.bits)?;
    let nv = btf.views.len();
    let so = SlotOptions { rcond: opts.rcond, lambda: 0.0, on_degenerate: opts.on_degenerate };
    let (slots, degenerate_slots) = fit_slots(btf, &light_basis(), &so)?;

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
    let scan = TexelScan::new();
    coeffs.par_chunks_mut(row_c).zip(rgb_rows.par_iter_mut()).enumerate().for_each(|(row, (crow, rrow))| {
        if monitor.is_cancelled() || scan.failed() {
            return;
        }
        if opts.kind == PtmKind::Rgb {
            let a = btf.abrdf_len();
            let values = &btf.data[row * w * a..(row + 1) * w * a];
            let r = crate::lightfit::Row { values, abrdf: a, first: row * w, screen };
            if !crate::lightfit::fit_row_rgb(&slots, &r, crow, &scan) {
                return;
            }
            monitor.advance(1);
            return;
        }
        for col in 0..w {
            let measured = btf.texel(row * w + col);
            if !scan.check(measured) {
                return;
            }
            let fixed = screen.and_then(|s| s.repaired(row * w + col, measured));
            let abrdf = fixed.as_deref().unwrap_or(measured);
            for (v, slot) in slots.iter().enumerate() {
                let out = &mut crow[(col * nv + v) * per_coef..(col * nv + v + 1) * per_coef];
                let base = &mut rrow[(col * nv + v) * 3..(col * nv + v + 1) * 3];
                fit_lrgb(slot, abrdf, btf.lights, out, base)
            }
        }
        monitor.advance(1);
    });
    monitor.check()?;
    scan.finish("data", btf.data)?;
    let mut ptm = Ptm {
        kind: opts.kind,
        height: h,
        width: w,
        views: btf.views.to_vec(),
        coeffs,
        rgb: (opts.kind == PtmKind::Lrgb).then_some(rgb),
        degenerate_slots,
        quantized: None,
    };
    if opts.bits == 8 {
        ptm.quantize()?;
    }
    Ok(ptm)
}

/// Luminance coefficients and base colour of one texel and slot.
#[inline]
fn fit_lrgb(slot: &Slot, abrdf: &[f32], lights: &[[f64; 3]], out: &mut [f32], base: &mut [f32]) {
    let mut a = [0.0f64; NCOEF];
    for (&i, p) in slot.pairs.iter().zip(slot.pt.chunks_exact(NCOEF)) {
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

/// The largest `|bias|` of a `.ptm` file's header that [`file_scale_bias`] produces.
pub const PTM_BIAS_LIMIT: f64 = 32767.0;

/// Scale (in byte units, as written in the header) and bias for a coefficient whose values (in
/// byte units) lie in `[lo, hi]`, as a `.ptm` file stores them (`btfrs-io`'s `ptm_file`, "Choosing
/// scale and bias": decoding is `(c - bias) * scale`, the step never below `max |value| / 32767` so
/// that `|bias| <= 32767`, an all-zero coefficient gets scale 1, bias 0). `None` if the scale does
/// not fit in an f32.
pub fn file_scale_bias(lo: f64, hi: f64) -> Option<(f32, i32)> {
    let max_abs = lo.abs().max(hi.abs());
    if max_abs == 0.0 {
        // All zero: any scale decodes byte `bias` to exactly 0.
        return Some((1.0, 0));
    }
    // 256 codes, 255 steps across the range; but never so fine a step that |bias| would exceed
    // PTM_BIAS_LIMIT (this is also what handles hi == lo without dividing by zero).
    let s = ((hi - lo) / 255.0).max(max_abs / PTM_BIAS_LIMIT);
    let mut s32 = s as f32;
    if !s32.is_finite() {
        return None;
    }
    if f64::from(s32) < s {
        // Round the f32 up rather than down, so the range still fits in 0..=255.
        s32 = f32::from_bits(s32.to_bits() + 1);
        if !s32.is_finite() {
            return None;
        }
    }
    if s32 == 0.0 {
        s32 = f32::MIN_POSITIVE;
    }
    // Decoding is (c - bias) * s, so the code of lo is lo / s + bias: put it within half a step
    // of code 0. Then hi lands within half a step of code 255 (hi - lo <= 255 s).
    let b = (-lo / f64::from(s32)).round();
    Some((s32, b.clamp(-PTM_BIAS_LIMIT, PTM_BIAS_LIMIT) as i32))
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

    /// Quantize the coefficients (and the LRGB base colours) to 8-bit planes as a `.ptm` file
    /// stores them, so that a slot is written byte for byte: per slot and coefficient index one
    /// scale and one integer bias ([`file_scale_bias`]) shared by the three channels (RGB), and
    /// the base colours as `round(255 rgb)`. One plane per slot, channel and coefficient, its
    /// scale `S / 255` and bias `-B S / 255` for the file's `S` and `B`; `coeffs` and `rgb` become
    /// the decoded values. The error of each value is at most half its plane's step.
    pub fn quantize(&mut self) -> Result<()> {
        let nv = self.views.len();
        let pc = self.per_coef();
        let k = nv * pc;
        // group of plane p: (slot, coefficient index)
        let group = |p: usize| (p / pc) * NCOEF + p % NCOEF;
        // Each plane's range, then the planes' ranges joined per group. 255 x is exact in f64
        // and monotone, so the range of 255 x is 255 times the range of x.
        let kk = k.max(1);
        let (plo, phi) = crate::planes::plane_ranges(&self.coeffs, k);
        let mut lo = vec![f64::INFINITY; nv * NCOEF];
        let mut hi = vec![f64::NEG_INFINITY; nv * NCOEF];
        for p in 0..k {
            let g = group(p);
            lo[g] = lo[g].min(255.0 * plo[p] as f64);
            hi[g] = hi[g].max(255.0 * phi[p] as f64);
        }
        let mut gs = vec![(1.0f32, 0i32); nv * NCOEF];
        for g in 0..nv * NCOEF {
            if lo[g] <= hi[g] {
                let (s, _) = file_scale_bias(lo[g], hi[g]).ok_or_else(|| {
                    Error::arg(
                        "coeffs",
                        format!("coefficient {} of slot {} is too wide to store", g % NCOEF, g / NCOEF),
                    )
                })?;
                // The plane's step s / 255 rounded up to 16 significant bits, so that the header's
                // scale 255 * step is an exact f32 and a file read back gives the same planes.
                let s = (255.0 * crate::hsh::round_up_16_bits(s as f64 / 255.0) as f64) as f32;
                let b = (-lo[g] / s as f64).round().clamp(-PTM_BIAS_LIMIT, PTM_BIAS_LIMIT) as i32;
                gs[g] = (s, b);
            }
        }
        let scale: Vec<f32> = (0..k).map(|p| (gs[group(p)].0 as f64 / 255.0) as f32).collect();
        let bias: Vec<f32> =
            (0..k).map(|p| (-(gs[group(p)].1 as f64) * gs[group(p)].0 as f64 / 255.0) as f32).collect();
        // Per plane its file scale and bias as f64 (the same arithmetic as value by value with
        // the group looked up, without a division of the index per value).
        let sb: Vec<(f64, f64)> = (0..k).map(|p| (gs[group(p)].0 as f64, gs[group(p)].1 as f64)).collect();
        let mut q = vec![0u8; self.coeffs.len()];
        q.par_chunks_mut(kk * 64).zip(self.coeffs.par_chunks(kk * 64)).for_each(|(q, a)| {
            for (q, a) in q.chunks_exact_mut(kk).zip(a.chunks_exact(kk)) {
                for ((q, &a), &(s, b)) in q.iter_mut().zip(a).zip(&sb) {
                    // Half up by truncation of the clamped value (`round` is a library call
                    // per value on the x86-64 baseline); below zero both give 0.
                    *q = (a as f64 * 255.0 / s + b + 0.5).clamp(0.0, 255.0) as u8;
                }
            }
        });
        let c = Planes { texels: self.height * self.width, k, q, scale, bias };
        let r = self.rgb.as_ref().map(|r| Planes {
            texels: self.height * self.width,
            k: nv * 3,
            q: r.iter().map(|&x| (x as f64 * 255.0).round().clamp(0.0, 255.0) as u8).collect(),
            scale: vec![(1.0f64 / 255.0) as f32; nv * 3],
            bias: vec![0.0; nv * 3],
        });
        // Into the floats' own buffers: no second copy of the coefficients at the peak.
        c.dequantize_into(&mut self.coeffs);
        if let (Some(p), Some(rgb)) = (&r, self.rgb.as_mut()) {
            p.dequantize_into(rgb);
        }
        self.quantized = Some(PtmPlanes { coeffs: c, rgb: r });
        Ok(())
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
        if let Some(q) = &self.quantized {
            let texels = self.height * self.width;
            let nv = self.views.len();
            if q.coeffs.texels != texels || q.coeffs.k != nv * self.per_coef() || q.coeffs.dequantize() != self.coeffs {
                return Err(Error::arg("coeffs", "the 8-bit planes do not match the coefficients"));
            }
            match (&q.rgb, &self.rgb) {
                (None, None) => {}
                (Some(p), Some(r)) if p.texels == texels && p.k == nv * 3 && &p.dequantize() == r => {}
                _ => return Err(Error::arg("rgb", "the 8-bit planes do not match the base colours")),
            }
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
        /// Store offset of the coefficients: RGB `[texel][V][3][6]`, LRGB `[texel][V][6]`, f32
        /// (`bits` 32) or bytes packed four to a word (`bits` 8, see `planes.rs`).
        pub coeffs: u32,
        /// Store offset of the LRGB base colours `[texel][V][3]`, like `coeffs`.
        pub rgb: u32,
        /// 32 (floats) or 8 (planes).
        pub bits: u32,
        /// Planes per texel of `coeffs` (`V * 18` or `V * 6`).
        pub k: u32,
        /// `bits` 8: store offset of the `k` scales then `k` biases of `coeffs`.
        pub scale: u32,
        /// `bits` 8, LRGB: store offset of the `3 V` scales then `3 V` biases of `rgb`.
        pub rgb_scale: u32,
    }
}

impl GpuLayout for Ptm {
    type Params = PtmParams;
    const SHADER: Shader = Shader::new::<PtmParams>("ptm", include_str!("../../../shaders_wgsl/ptm.wgsl"));

    fn parts(&self) -> Vec<Cow<'_, [u32]>> {
        if let Some(q) = &self.quantized {
            let mut p = vec![Cow::Owned(q.coeffs.words()), Cow::Owned(q.coeffs.scale_bias_words())];
            if let Some(r) = &q.rgb {
                p.push(Cow::Owned(r.words()));
                p.push(Cow::Owned(r.scale_bias_words()));
            }
            return p;
        }
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
        let q = self.quantized.is_some();
        PtmParams {
            kind: match self.kind {
                PtmKind::Rgb => 0,
                PtmKind::Lrgb => 1,
            },
            n_views: self.views.len() as u32,
            view_table: tables[0],
            coeffs: offsets[0],
            rgb: offsets.get(if q { 2 } else { 1 }).copied().unwrap_or(0),
            bits: if q { 8 } else { 32 },
            k: (self.views.len() * self.per_coef()) as u32,
            scale: if q { offsets[1] } else { 0 },
            rgb_scale: if q { offsets.get(3).copied().unwrap_or(0) } else { 0 },
        }
    }
}

/// The Gram matrix of the PTM basis averaged over the light hemisphere (uniform in solid
/// angle: the concentric map is area-preserving, so a uniform grid on its square is uniform on
/// the hemisphere), and its Cholesky factor.
pub fn gram_factor() -> [[f64; 6]; 6] {
    let n = 96;
    let mut g = nalgebra::DMatrix::<f64>::zeros(6, 6);
    for i in 0..n {
        for j in 0..n {
            let l = btfrs_hemimap::square_to_hemisphere((i as f64 + 0.5) / n as f64, (j as f64 + 0.5) / n as f64);
            let b = basis(l);
            for a in 0..6 {
                for c in 0..6 {
                    g[(a, c)] += b[a] * b[c];
                }
            }
        }
    }
    g /= (n * n) as f64;
    let l = nalgebra::Cholesky::new(g).expect("the PTM basis is linearly independent on the hemisphere").l();
    let mut out = [[0.0; 6]; 6];
    for (a, row) in out.iter_mut().enumerate() {
        for (c, v) in row.iter_mut().enumerate() {
            *v = l[(a, c)];
        }
    }
    out
}

impl Model for Ptm {
    const KIND: &'static str = "ptm";
    const TEXEL_ARRAYS: &'static [&'static str] = &["coeffs", "rgb", "coeffs_q", "rgb_q"];
    const DOC: &'static str = "Polynomial Texture Maps per view slot (paper 000, section 3.1)";
    const ABOUT: &'static str = "\
One SVD pseudo-inverse of the 6-column light design matrix per view slot, applied to every texel
(float64 accumulation), so the fit costs one pass over the data. `kind=\"rgb\"` fits one
biquadratic `a0 lu^2 + a1 lv^2 + a2 lu lv + a3 lu + a4 lv + a5` per channel, `\"lrgb\"` one for the
luminance times a base colour. A view slot with fewer than 6 lights, or degenerate (collinear)
lights, or whose biquadratic would extrapolate (a prediction above 4 times its samples' range),
gets the plane of its own lights or the lights of the nearest views pooled
(`on_degenerate=\"reduce\"`); `model.report[\"degenerate_slots\"]` lists each such slot. With
`bits=8` the coefficients are 8-bit planes as a `.ptm` file holds them (per slot and coefficient
a scale and a bias), so `nbytes` is what a viewer holds and `save_ptm` writes these bytes.";
    const OPTIONS: &'static [Spec] = &[
        Spec::choice("kind", "rgb", &["rgb", "lrgb"], "\"rgb\": 6 coefficients per channel; \"lrgb\": 6 for the luminance and a base colour"),
        Spec::float("rcond", 1e-6, 0.0, "singular values below rcond x the largest count as zero"),
        Spec::choice("on_degenerate", "reduce", &["reduce", "raise", "clamp"], "a slot with too few or degenerate lights: a reduced fit (listed in the report), an error, or the minimum-norm solution"),
        Spec::int_choice("bits", 8, &[8, 32], "8: 8-bit planes with a scale and bias per plane (as .ptm files); 32: float32 coefficients"),
    ];
    const EXAMPLES: &'static [(&'static str, &'static str)] =
        &[("PTM-LRGB", r#"{"kind": "lrgb"}"#), ("PTM-RGB", r#"{"kind": "rgb"}"#)];
    const SWEEP: &'static [Setting] =
        &[Setting::quick("PTM-RGB", r#"{"kind": "rgb"}"#), Setting::full("PTM-LRGB", r#"{"kind": "lrgb"}"#)];
    const BENCH: &'static [Bench] = &[
        Bench::new("PTM-RGB", r#"{"kind": "rgb"}"#, &["foundation"])
            .peer("ptm_rgb_numpy")
            .note(">= 3x numpy, 1e-4 rel."),
        Bench::new("PTM-LRGB", r#"{"kind": "lrgb"}"#, &["foundation"]),
        Bench::new("PTM-RGB", r#"{"kind": "rgb"}"#, &["reference", "per_material", "single_view", "dask"]),
        Bench::new("PTM-LRGB", r#"{"kind": "lrgb"}"#, &["per_material", "single_view"]),
        Bench::new("PTM-RGB", r#"{"kind": "rgb"}"#, &["summary"]).note("relight PTM 34.9% in 26 KB"),
        Bench::new("PTM", "{}", &["out_of_core"]),
    ];
    const SAMPLING: Sampling = Sampling::PerView { min_lights: 6, why: "biquadratic" };
    const EXPORTS: &'static [&'static str] = &["ptm", "relight"];
    type Options = PtmOptions;
    // Each texel's values are checked as the per-texel pass reads them (TexelScan).
    const SCANS_VALUES: bool = true;
    // The slots' pseudo-inverses depend on the lights and the mask only: texels fit apart.
    const BLOCKWISE: crate::blockwise::Blockwise =
        crate::blockwise::Blockwise::Texels { overrides: r#"{"bits": 32}"#, counts: &[] };

    fn fit(btf: &BtfRef<'_>, options: &PtmOptions, monitor: &Monitor) -> Result<Self> {
        fit_ptm(btf, options, monitor)
    }

    // Every texel is fitted from its own values alone.
    const SCREENS_TEXELS: bool = true;

    fn fit_screened(
        btf: &BtfRef<'_>,
        options: &PtmOptions,
        screen: &crate::robust::TexelScreen<'_>,
        monitor: &Monitor,
    ) -> Result<Self> {
        fit_ptm_screened(btf, options, Some(screen), monitor)
    }

    const MIP: Mip = Mip::Average;

    /// RGB is linear in its coefficients; LRGB multiplies two texel arrays, so its average is
    /// not the average appearance.
    fn mip(&self) -> Mip {
        match self.kind {
            PtmKind::Rgb => Mip::Average,
            PtmKind::Lrgb => Mip::Medoid,
        }
    }

    fn mip_texels(&self, groups: &[Vec<(u32, f32)>]) -> Result<Self> {
        match self.kind {
            PtmKind::Rgb => average_texels(self, groups),
            PtmKind::Lrgb => {
                Err(Error::arg("filter", "the LRGB PTM's parameters cannot be averaged (use medoid levels)"))
            }
        }
    }

    /// RGB: the coefficients whitened by the hemisphere Gram matrix ([`gram_factor`]), so that
    /// distances between texels are L2 distances of their light functions.
    fn coefficient_features(&self) -> Option<Result<CoefficientFeatures>> {
        if self.kind != PtmKind::Rgb {
            return None;
        }
        let l = gram_factor();
        // f = L^T c, so that |f|^2 = c^T G c = mean over the hemisphere of the squared value.
        let data: Vec<f32> = self
            .coeffs
            .par_chunks(6)
            .flat_map_iter(|c| (0..6).map(move |k| (0..6).map(|a| l[a][k] * c[a] as f64).sum::<f64>() as f32))
            .collect();
        let dim = data.len() / (self.height * self.width).max(1);
        Some(Ok(CoefficientFeatures { dim, data, label: "ptm coefficients (hemisphere Gram-whitened)" }))
    }

    /// The planes' scales span every texel: quantized over the stitched floats, as `fit_ptm`.
    fn finish_blocks(mut self, options: &PtmOptions) -> Result<Self> {
        check_bits(options.bits)?;
        if options.bits == 8 && self.quantized.is_none() {
            self.quantize()?;
        }
        Ok(self)
    }

    /// `coeffs` (RGB `[H, W, V, 3, 6]`, LRGB `[H, W, V, 6]`), `views` `[V, 3]` and, for LRGB,
    /// `rgb` `[H, W, V, 3]`. The kind follows from the shape of `coeffs`. A quantized model stores
    /// the planes instead: `coeffs_q` (uint8, the same shape) with `coeffs_scale` and
    /// `coeffs_bias` (`[k]`), and `rgb_q`, `rgb_scale`, `rgb_bias` for LRGB.
    fn to_arrays(&self) -> NamedArrays {
        let mut a = NamedArrays::new();
        let (h, w, nv) = (self.height, self.width, self.views.len());
        let cshape: Vec<usize> = match self.kind {
            PtmKind::Rgb => vec![h, w, nv, 3, NCOEF],
            PtmKind::Lrgb => vec![h, w, nv, NCOEF],
        };
        match &self.quantized {
            Some(q) => q.coeffs.insert_into(&mut a, "coeffs_", cshape),
            None => a.put("coeffs", &cshape, self.coeffs.clone()),
        }
        a.put_directions("views", &self.views);
        match (&self.quantized, &self.rgb) {
            (Some(PtmPlanes { rgb: Some(r), .. }), _) => r.insert_into(&mut a, "rgb_", vec![h, w, nv, 3]),
            (_, Some(rgb)) => a.put("rgb", &[h, w, nv, 3], rgb.clone()),
            _ => {}
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
        let cname = if a.contains("coeffs_q") { "coeffs_q" } else { "coeffs" };
        let ndim = a.array(cname).map(|x| x.shape.len());
        let pattern: &[Option<usize>] = match ndim {
            Some(5) => &[None, None, nv, Some(3), Some(NCOEF)],
            Some(4) => &[None, None, nv, Some(NCOEF)],
            _ => &[],
        };
        if pattern.is_empty()
            || a.array(cname)
                .is_some_and(|x| x.shape[2..] != pattern[2..].iter().map(|d| d.unwrap()).collect::<Vec<_>>())
        {
            return Err(Error::arg(
                cname,
                format!("expected shape [H, W, {}, 3, 6] (RGB) or [H, W, {}, 6] (LRGB)", views.len(), views.len()),
            ));
        }
        let (coeffs, sh) = Coeffs::from_arrays(a, "coeffs", pattern, 2)?;
        let kind = if sh.len() == 5 { PtmKind::Rgb } else { PtmKind::Lrgb };
        let rgb = match kind {
            PtmKind::Rgb => None,
            PtmKind::Lrgb => Some(Coeffs::from_arrays(a, "rgb", &[Some(sh[0]), Some(sh[1]), nv, Some(3)], 2)?.0),
        };
        let quantized = match (&coeffs.planes, rgb.as_ref().map(|r| &r.planes)) {
            (Some(c), None) => Some(PtmPlanes { coeffs: c.clone(), rgb: None }),
            (Some(c), Some(Some(r))) => Some(PtmPlanes { coeffs: c.clone(), rgb: Some(r.clone()) }),
            (None, None | Some(None)) => None,
            _ => {
                return Err(Error::arg(
                    "rgb",
                    "expected the coefficients and the base colours both as 8-bit planes or both as floats",
                ))
            }
        };
        let m = Ptm {
            kind,
            height: sh[0],
            width: sh[1],
            views,
            coeffs: coeffs.values,
            rgb: rgb.map(|r| r.values),
            degenerate_slots: Vec::new(),
            quantized,
        };
        m.validate()?;
        Ok(m)
    }
}

#[cfg(test)]
mod tests;
