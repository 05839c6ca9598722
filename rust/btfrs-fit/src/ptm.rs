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
//! A view slot needs at least 6 lights whose (lu, lv) are not degenerate (e.g. all on one line):
//! such a slot is an error by default, or clamped to a minimum-norm solution on request.

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
        PtmOptions { kind: PtmKind::Rgb, rcond: 1e-6, on_degenerate: Degenerate::Raise }
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
}

/// The six basis functions at light direction `l`.
#[inline]
pub fn basis(l: [f64; 3]) -> [f64; NCOEF] {
    let (u, v) = (l[0], l[1]);
    [u * u, v * v, u * v, u, v, 1.0]
}

/// The pseudo-inverse `[6, n]` (row-major) of the design matrix of `lights`.
fn pinv(slot: usize, view: [f64; 3], lights: &[[f64; 3]], opts: &PtmOptions) -> Result<Vec<f64>> {
    let n = lights.len();
    let (theta, phi) = directions::to_theta_phi(view);
    let name = format!("view slot {slot} (theta {:.1}, phi {:.1} deg)", theta.to_degrees(), phi.to_degrees());
    if n < NCOEF && opts.on_degenerate == Degenerate::Raise {
        return Err(Error::Degenerate(format!(
            "{name} has {n} lights; a biquadratic PTM needs at least {NCOEF} (pass on_degenerate=\"clamp\" for a minimum-norm fit)"
        )));
    }
    if n == 0 {
        // Clamp policy and no light at all: the minimum-norm solution is all zeros.
        return Ok(Vec::new());
    }
    let a = DMatrix::from_fn(n, NCOEF, |i, k| basis(lights[i])[k]);
    let svd = a.svd(true, true);
    let (u, vt) = match (svd.u, svd.v_t) {
        (Some(u), Some(vt)) => (u, vt),
        _ => return Err(Error::Degenerate(format!("{name}: the SVD of the light design matrix failed"))),
    };
    let s = &svd.singular_values;
    let smax = s.iter().copied().fold(0.0f64, f64::max);
    let cut = opts.rcond * smax;
    let rank = s.iter().filter(|&&x| x > cut).count();
    if rank < NCOEF && opts.on_degenerate == Degenerate::Raise {
        let smin = s.iter().copied().fold(f64::INFINITY, f64::min);
        return Err(Error::Degenerate(format!(
            "{name}: its {n} lights determine only {rank} of the {NCOEF} PTM coefficients (smallest/largest \
             singular value {:.2e} < rcond {:.0e}); the lights' (x, y) are degenerate, e.g. collinear",
            smin / smax.max(f64::MIN_POSITIVE),
            opts.rcond
        )));
    }
    // pinv = V diag(1/s) U^T with the clamped singular values' reciprocals set to zero.
    let mut p = vec![0.0f64; NCOEF * n];
    for (j, &sj) in s.iter().enumerate() {
        if sj <= cut {
            continue;
        }
        for k in 0..NCOEF {
            let vk = vt[(j, k)] / sj;
            for i in 0..n {
                p[k * n + i] += vk * u[(i, j)];
            }
        }
    }
    Ok(p)
}

/// One view slot's light indices and pseudo-inverse, stored transposed (`[n][6]`) so that the
/// per-texel loop walks the texel's contiguous light samples and the matrix in the same order.
struct Slot {
    lights: Vec<usize>,
    pt: Vec<[f64; NCOEF]>,
}

/// Fit a PTM to the present (view, light) pairs of `btf`; `monitor` counts texel rows.
pub fn fit_ptm(btf: &BtfRef<'_>, opts: &PtmOptions, monitor: &Monitor) -> Result<Ptm> {
    if !(opts.rcond.is_finite() && opts.rcond > 0.0 && opts.rcond < 1.0) {
        return Err(Error::arg("rcond", format!("expected a value in (0, 1), got {}", opts.rcond)));
    }
    let (nv, nl) = (btf.views.len(), btf.lights.len());
    let slots: Vec<Slot> = (0..nv)
        .map(|v| {
            let ls = btf.lights_of_view(v);
            let dirs: Vec<[f64; 3]> = ls.iter().map(|&l| btf.lights[l]).collect();
            let p = pinv(v, btf.views[v], &dirs, opts)?;
            let n = ls.len();
            let pt = (0..n).map(|i| std::array::from_fn(|k| p[k * n + i])).collect();
            Ok(Slot { lights: ls, pt })
        })
        .collect::<Result<_>>()?;

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
                let samples = &abrdf[v * nl * 3..(v + 1) * nl * 3];
                let out = &mut crow[(col * nv + v) * per_coef..(col * nv + v + 1) * per_coef];
                match opts.kind {
                    PtmKind::Rgb => fit_rgb(slot, samples, out),
                    PtmKind::Lrgb => {
                        let base = &mut rrow[(col * nv + v) * 3..(col * nv + v + 1) * 3];
                        fit_lrgb(slot, samples, btf.lights, out, base)
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
    })
}

/// 18 coefficients `[3][6]` of one texel and slot; f64 accumulation.
#[inline]
fn fit_rgb(slot: &Slot, samples: &[f32], out: &mut [f32]) {
    let mut acc = [[0.0f64; NCOEF]; 3];
    for (&l, p) in slot.lights.iter().zip(&slot.pt) {
        let x = &samples[l * 3..l * 3 + 3];
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
fn fit_lrgb(slot: &Slot, samples: &[f32], lights: &[[f64; 3]], out: &mut [f32], base: &mut [f32]) {
    let mut a = [0.0f64; NCOEF];
    for (&l, p) in slot.lights.iter().zip(&slot.pt) {
        let x = &samples[l * 3..l * 3 + 3];
        let lum = (x[0] as f64 + x[1] as f64 + x[2] as f64) / 3.0;
        for k in 0..NCOEF {
            a[k] += p[k] * lum;
        }
    }
    // Least-squares modulation: base_c = sum L(l) rgb_c(l) / sum L(l)^2 over the slot's lights.
    let (mut num, mut den) = ([0.0f64; 3], 0.0f64);
    for &l in &slot.lights {
        let b = basis(lights[l]);
        let lf: f64 = (0..NCOEF).map(|k| a[k] * b[k]).sum();
        let x = &samples[l * 3..l * 3 + 3];
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
        let m = Ptm { kind, height: sh[0], width: sh[1], views, coeffs: coeffs.to_vec(), rgb };
        m.validate()?;
        Ok(m)
    }
}

#[cfg(test)]
mod tests;
