//! Hemispherical harmonics (HSH) per view slot: the light basis of the `.rti` HSH files that
//! RTIViewer (ISTI-CNR and Cultural Heritage Imaging) and relight (ISTI-CNR) open, fitted like
//! the PTM of paper 000, section 3.1 (one fit per view slot, blended between slots).
//!
//! # The basis
//!
//! Gautron, Krivanek, Pattanaik and Bouatouch, "A Novel Hemispherical Basis for Accurate and
//! Efficient Rendering", EGSR 2004: the spherical harmonics with the associated Legendre
//! polynomials shifted from `[-1, 1]` to the hemisphere, `P_l^m(2 cos(theta) - 1)`, so that they
//! are orthonormal over the upper hemisphere (`dω = sin(theta) dtheta dphi`):
//!
//! ```text
//! H_l^m(theta, phi) = s_m sqrt(2) K_l^|m| P_l^|m|(2 cos(theta) - 1) cos(|m| phi)   m < 0
//!                   =            K_l^0   P_l^0  (2 cos(theta) - 1)                m = 0
//!                   = s_m sqrt(2) K_l^m   P_l^m  (2 cos(theta) - 1) sin(m phi)     m > 0
//! K_l^m = sqrt((2l + 1) (l - m)! / (2 pi (l + m)!))
//! ```
//!
//! with `P_l^m` without the Condon-Shortley phase, `theta` the angle from the normal
//! (`cos(theta) = l_z`) and `phi = atan2(l_y, l_x)` in the tangent frame. Term `j = l (l + 1) + m`
//! for `l = 0 .. order - 1`, `m = -l ..= l`, so order `n` has `n^2` terms (1, 4, 9, 16).
//!
//! The RTI viewers use one particular sign and ordering, and a file only shows correctly with
//! exactly theirs: negative `m` take `cos`, positive `m` take `sin`, and the sign `s_m` is
//! `(-1)^(|m| + 1)` (positive for `|m|` 1 and 3, negative for `|m| = 2`), i.e. in `x = cos(theta)`
//! and `s = sqrt(x - x^2)`:
//!
//! ```text
//! H0  = 1 / sqrt(2 pi)
//! H1  = sqrt(6 / pi) cos(phi) s            H3  = sqrt(6 / pi) sin(phi) s
//! H2  = sqrt(3 / (2 pi)) (2x - 1)
//! H4  = sqrt(30 / pi) cos(2 phi) (x^2 - x) H8  = sqrt(30 / pi) sin(2 phi) (x^2 - x)
//! H5  = sqrt(30 / pi) cos(phi) (2x - 1) s  H7  = sqrt(30 / pi) sin(phi) (2x - 1) s
//! H6  = sqrt(5 / (2 pi)) (6x^2 - 6x + 1)
//! H9  = 2 sqrt(35 / pi) cos(3 phi) s^3     H15 = 2 sqrt(35 / pi) sin(3 phi) s^3
//! H10 = sqrt(210 / pi) cos(2 phi) (2x - 1) (x^2 - x)
//! H14 = sqrt(210 / pi) sin(2 phi) (2x - 1) (x^2 - x)
//! H11 = 2 sqrt(21 / pi) cos(phi) s (5x^2 - 5x + 1)
//! H13 = 2 sqrt(21 / pi) sin(phi) s (5x^2 - 5x + 1)
//! H12 = sqrt(7 / (2 pi)) (20x^3 - 30x^2 + 12x - 1)
//! ```
//!
//! Terms 0 to 8 are those of the lighting function of ISTI-CNR's WebGL RTI viewer (the
//! `HSH` case of its `computeLightingFunction`, found as a public minified script); terms 9 to 15
//! follow the same sign pattern and Gautron's normalisation (the tests check orthonormality on
//! the hemisphere by quadrature and every term against an independent associated-Legendre
//! implementation). The viewers also clamp `theta` a little below 90 degrees (0.04 rad for
//! RTIViewer, 0.15 rad for the WebGL viewer) before evaluating; the model evaluates the basis
//! as written, without that clamp.
//!
//! # Fit and storage
//!
//! Per view slot, the least-squares fit of `order^2` coefficients per channel, with a small
//! ridge (`lambda`) and the PTM's handling of view slots whose lights do not determine the
//! basis ([`crate::ptm`], [`crate::lightfit::Degenerate`]: the reduced bases are the lower
//! orders). The fitted floats are quantized at the end to 8-bit planes ([`Planes`], one per slot,
//! channel and term) whose scale and bias are shared by the three channels of a (slot, term), as
//! a `.rti` file stores them, so one slot is written to a file byte for byte.

use crate::gpu::{GpuLayout, Shader};
use crate::lightfit::{check_bits, fit_slots, Coeffs, Degenerate, DegenerateSlot, LightBasis, SlotOptions};
use crate::model::{average_texels, Mip, Model, ReflectanceModel, Sampling};
use crate::options::Spec;
use crate::planes::Planes;
use btfrs_core::btf::TexelScan;
use btfrs_core::{directions, ensure_arg, BtfRef, Error, Monitor, NamedArrays, Result};
use rayon::prelude::*;
use std::borrow::Cow;
use std::f64::consts::PI;

/// The largest order (16 terms), as in the RTI files.
pub const MAX_ORDER: usize = 4;

/// The `order^2` HSH basis values at unit light direction `l` (tangent frame) into `out`
/// (see the module doc for the exact functions). Directions below the horizon are evaluated at
/// `l_z = 0`.
pub fn hsh_basis(order: usize, l: [f64; 3], out: &mut [f64]) {
    debug_assert!((1..=MAX_ORDER).contains(&order) && out.len() >= order * order);
    let x = l[2].clamp(0.0, 1.0);
    let phi = l[1].atan2(l[0]);
    let s = (x - x * x).max(0.0).sqrt();
    let y = 2.0 * x - 1.0;
    let (c1, s1) = (phi.cos(), phi.sin());
    out[0] = 1.0 / (2.0 * PI).sqrt();
    if order < 2 {
        return;
    }
    let a = (6.0 / PI).sqrt() * s;
    out[1] = a * c1;
    out[2] = (3.0 / (2.0 * PI)).sqrt() * y;
    out[3] = a * s1;
    if order < 3 {
        return;
    }
    let (c2, s2) = ((2.0 * phi).cos(), (2.0 * phi).sin());
    let k30 = (30.0 / PI).sqrt();
    out[4] = k30 * c2 * (x * x - x);
    out[5] = k30 * c1 * y * s;
    out[6] = (5.0 / (2.0 * PI)).sqrt() * (6.0 * x * x - 6.0 * x + 1.0);
    out[7] = k30 * s1 * y * s;
    out[8] = k30 * s2 * (x * x - x);
    if order < 4 {
        return;
    }
    let (c3, s3) = ((3.0 * phi).cos(), (3.0 * phi).sin());
    let k35 = 2.0 * (35.0 / PI).sqrt() * s * s * s;
    let k210 = (210.0 / PI).sqrt() * y * (x * x - x);
    let k21 = 2.0 * (21.0 / PI).sqrt() * s * (5.0 * x * x - 5.0 * x + 1.0);
    out[9] = k35 * c3;
    out[10] = k210 * c2;
    out[11] = k21 * c1;
    out[12] = (7.0 / (2.0 * PI)).sqrt() * (20.0 * x * x * x - 30.0 * x * x + 12.0 * x - 1.0);
    out[13] = k21 * s1;
    out[14] = k210 * s2;
    out[15] = k35 * s3;
}

/// Fit options.
#[derive(Debug, Clone, Copy, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HshOptions {
    /// The order `n` (1 to 4): `n^2` coefficients per channel.
    pub order: usize,
    /// Ridge weight relative to the largest squared singular value of a slot's design matrix
    /// (`|A c - y|^2 + lambda s_max^2 |c|^2`); 0 is plain least squares.
    pub lambda: f64,
    /// Singular values below `rcond * s_max` count as zero.
    pub rcond: f64,
    /// Policy for view slots whose lights do not determine the basis (as the PTM's; the reduced
    /// bases are the lower orders).
    pub on_degenerate: Degenerate,
    /// 8 (the default): 8-bit planes with per-plane scale and bias, as `.rti` files and viewers
    /// hold them; 32 keeps the floats.
    pub bits: u32,
}

impl Default for HshOptions {
    /// The defaults of [`Hsh`]'s option schema.
    fn default() -> Self {
        crate::options::defaults(<Hsh as Model>::OPTIONS)
    }
}

/// A fitted HSH: `order^2` coefficients per texel, view slot and channel.
#[derive(Debug, Clone)]
pub struct Hsh {
    /// The order (1 to 4).
    pub order: usize,
    /// Rows.
    pub height: usize,
    /// Columns.
    pub width: usize,
    /// The view direction of each slot.
    pub views: Vec<[f64; 3]>,
    /// `[H, W, V, 3, order^2]`: decoded values when quantized.
    pub coeffs: Coeffs,
    /// The slots fitted by a fallback (empty for a loaded model).
    pub degenerate_slots: Vec<DegenerateSlot>,
}

/// One view slot of an HSH (what a `.rti` file holds): `coeffs` `[H, W, 3, order^2]`, rows top to
/// bottom, and the slot's 8-bit planes (`k = 3 order^2`, the three channels of a term sharing
/// scale and bias) when quantized.
#[derive(Debug, Clone, PartialEq)]
pub struct HshSlot {
    /// The order.
    pub order: usize,
    /// Rows.
    pub height: usize,
    /// Columns.
    pub width: usize,
    /// Values (decoded when quantized).
    pub coeffs: Coeffs,
}

fn light_basis(order: usize) -> LightBasis<'static> {
    let eval: &'static (dyn Fn([f64; 3], &mut [f64]) + Sync) = match order {
        1 => &|l, o| hsh_basis(1, l, o),
        2 => &|l, o| hsh_basis(2, l, o),
        3 => &|l, o| hsh_basis(3, l, o),
        _ => &|l, o| hsh_basis(4, l, o),
    };
    const NAMES: [&str; 4] = ["order 1", "order 2", "order 3", "order 4"];
    LightBasis {
        k: order * order,
        eval,
        what: ["an order-1 HSH", "an order-2 HSH", "an order-3 HSH", "an order-4 HSH"][order - 1],
        coefficients: "HSH coefficients",
        reduced: (1..order).rev().map(|m| (NAMES[m - 1], (0..m * m).collect())).collect(),
    }
}

/// Quantize `values` (`texels * k`, `k = groups * 3 * n2`, layout `[.., group][channel][term]`) to
/// planes whose three channels of a (group, term) share one scale and bias, with the scale
/// rounded up to 16 significant bits so that `255 * scale` (a `.rti` file's scale) is an exact
/// f32 and reading a written file gives back the same planes bit for bit.
pub fn quantize_shared(values: &[f32], k: usize, n2: usize) -> Result<Planes> {
    if k == 0 || !k.is_multiple_of(3 * n2) || !values.len().is_multiple_of(k) {
        return Err(Error::arg("coeffs", format!("{} values are not whole texels of {k} planes", values.len())));
    }
    if let Some(i) = btfrs_core::btf::first_non_finite(values) {
        return Err(Error::arg("coeffs", format!("coefficient at flat index {i} is not finite")));
    }
    let groups = k / (3 * n2);
    Planes::quantize_grouped(values, k, groups * n2, |p| (p / (3 * n2)) * n2 + p % n2, round_up_16_bits)
}

/// The smallest f32 with at most 16 significant bits that is `>= x` (x >= 0, finite).
pub(crate) fn round_up_16_bits(x: f64) -> f32 {
    if x <= 0.0 {
        return 0.0;
    }
    let e = x.log2().floor() as i32 - 15;
    let unit = 2f64.powi(e);
    let r = (x / unit).ceil() * unit;
    let r32 = r as f32;
    // r has 16 or 17 significant bits (17 only when it rounded up to a power of two: still exact).
    if (r32 as f64) < x {
        f32::from_bits(r32.to_bits() + 1)
    } else {
        r32
    }
}

/// Fit an HSH to the present (view, light) pairs of `btf`; `monitor` counts texel rows.
pub fn fit_hsh(btf: &BtfRef<'_>, opts: &HshOptions, monitor: &Monitor) -> Result<Hsh> {
    fit_hsh_screened(btf, opts, None, monitor)
}

/// [`fit_hsh`] with the robust value screen run on each texel inside the fit's pass
/// ([`crate::robust::TexelScreen`]; `None`: the values as measured).
pub fn fit_hsh_screened(
    btf: &BtfRef<'_>,
    opts: &HshOptions,
    screen: Option<&crate::robust::TexelScreen<'_>>,
    monitor: &Monitor,
) -> Result<Hsh> {
    ensure_arg!((1..=MAX_ORDER).contains(&opts.order), "order", "expected 1, 2, 3 or 4, got {}", opts.order);
    check_bits(opts.bits)?;
    let n2 = opts.order * opts.order;
    let basis = light_basis(opts.order);
    let so = SlotOptions { rcond: opts.rcond, lambda: opts.lambda, on_degenerate: opts.on_degenerate };
    let (slots, degenerate_slots) = fit_slots(btf, &basis, &so)?;
    let (h, w, nv) = (btf.height, btf.width, btf.views.len());
    let per = 3 * n2;
    let mut coeffs = vec![0.0f32; h * w * nv * per];
    monitor.start(h as u64);
    let scan = TexelScan::new();
    coeffs.par_chunks_mut(w * nv * per).enumerate().for_each(|(row, crow)| {
        if monitor.is_cancelled() || scan.failed() {
            return;
        }
        let a = btf.abrdf_len();
        let values = &btf.data[row * w * a..(row + 1) * w * a];
        let r = crate::lightfit::Row { values, abrdf: a, first: row * w, screen };
        if !crate::lightfit::fit_row_rgb(&slots, &r, crow, &scan) {
            return;
        }
        monitor.advance(1);
    });
    monitor.check()?;
    scan.finish("data", btf.data)?;
    let coeffs =
        if opts.bits == 8 { quantized(coeffs, nv * per, n2)? } else { Coeffs { values: coeffs, planes: None } };
    Ok(Hsh { order: opts.order, height: h, width: w, views: btf.views.to_vec(), coeffs, degenerate_slots })
}

/// The float coefficients (`k` per texel) as 8-bit planes ([`quantize_shared`]), the values
/// replaced by the decoded planes.
fn quantized(values: Vec<f32>, k: usize, n2: usize) -> Result<Coeffs> {
    let planes = quantize_shared(&values, k, n2)?;
    let mut values = values;
    planes.dequantize_into(&mut values); // the floats' own buffer: no second copy at the peak
    Ok(Coeffs { values, planes: Some(planes) })
}

impl Hsh {
    fn n2(&self) -> usize {
        self.order * self.order
    }

    /// Check the dimensions (for models built from loaded files).
    pub fn validate(&self) -> Result<()> {
        ensure_arg!((1..=MAX_ORDER).contains(&self.order), "order", "expected 1, 2, 3 or 4, got {}", self.order);
        if self.height == 0 || self.width == 0 {
            return Err(Error::arg("coeffs", "the HSH has no texels"));
        }
        directions::validate("views", &self.views)?;
        let k = self.views.len() * 3 * self.n2();
        let t = self.height * self.width;
        if self.coeffs.values.len() != t * k {
            return Err(Error::arg("coeffs", format!("expected {} values, got {}", t * k, self.coeffs.values.len())));
        }
        if let Some(p) = &self.coeffs.planes {
            if p.texels != t || p.k != k {
                return Err(Error::arg("coeffs", format!("expected {t} x {k} planes, got {} x {}", p.texels, p.k)));
            }
        }
        Ok(())
    }

    /// View slot `view` as a single-view HSH (e.g. to write it as a `.rti` file). Its planes are
    /// those of the model when they share scale and bias over the channels (a fitted 8-bit
    /// model), else the floats are quantized that way for the file ([`quantize_shared`]).
    pub fn slot(&self, view: usize) -> Result<HshSlot> {
        let nv = self.views.len();
        ensure_arg!(view < nv, "view", "expected a view slot index in [0, {nv}), got {view}");
        self.validate()?;
        let (n2, texels) = (self.n2(), self.height * self.width);
        let per = 3 * n2;
        let pick = |src: &[f32]| -> Vec<f32> {
            (0..texels).flat_map(|t| src[(t * nv + view) * per..(t * nv + view + 1) * per].iter().copied()).collect()
        };
        let values = pick(&self.coeffs.values);
        let planes = match &self.coeffs.planes {
            Some(p) => {
                let r = view * per..(view + 1) * per;
                let (scale, bias) = (p.scale[r.clone()].to_vec(), p.bias[r.clone()].to_vec());
                let shared =
                    (0..n2).all(|j| (1..3).all(|c| scale[c * n2 + j] == scale[j] && bias[c * n2 + j] == bias[j]));
                if shared {
                    let q = (0..texels).flat_map(|t| p.q[t * p.k + r.start..t * p.k + r.end].iter().copied()).collect();
                    Planes { texels, k: per, q, scale, bias }
                } else {
                    quantize_shared(&values, per, n2)?
                }
            }
            None => quantize_shared(&values, per, n2)?,
        };
        Ok(HshSlot { order: self.order, height: self.height, width: self.width, coeffs: Coeffs::from_planes(planes) })
    }

    /// A one-slot model from a single-view HSH (e.g. read from a `.rti` file), its view the
    /// normal `(0, 0, 1)`.
    pub fn from_slot(slot: HshSlot) -> Result<Hsh> {
        let h = Hsh {
            order: slot.order,
            height: slot.height,
            width: slot.width,
            views: vec![[0.0, 0.0, 1.0]],
            coeffs: slot.coeffs,
            degenerate_slots: Vec::new(),
        };
        h.validate()?;
        Ok(h)
    }
}

/// A prepared HSH query: view-slot weights and the light's basis.
#[derive(Debug, Clone)]
pub struct HshQuery {
    slots: Vec<(usize, f32)>,
    basis: [f32; 16],
}

impl ReflectanceModel for Hsh {
    type Query = HshQuery;

    fn dims(&self) -> (usize, usize) {
        (self.height, self.width)
    }

    fn query(&self, view: [f64; 3], light: [f64; 3]) -> HshQuery {
        let slots = directions::interp_weights(&self.views, view, 3).into_iter().map(|(i, w)| (i, w as f32)).collect();
        let mut b = [0.0f64; 16];
        hsh_basis(self.order, light, &mut b);
        HshQuery { slots, basis: b.map(|x| x as f32) }
    }

    #[inline]
    fn eval(&self, t: usize, q: &HshQuery) -> [f32; 3] {
        let nv = self.views.len();
        let n2 = self.n2();
        let per = 3 * n2;
        let mut out = [0.0f32; 3];
        for &(v, wgt) in &q.slots {
            let c = &self.coeffs.values[(t * nv + v) * per..(t * nv + v + 1) * per];
            for ch in 0..3 {
                let s: f32 = c[ch * n2..(ch + 1) * n2].iter().zip(&q.basis).map(|(a, b)| a * b).sum();
                out[ch] += wgt * s;
            }
        }
        out
    }
}

crate::gpu_params! {
    /// Parameters of `hsh.wgsl`.
    pub struct HshParams {
        /// The order n (n^2 terms per channel).
        pub order: u32,
        /// Number of view slots V (their directions are `mdirs[0 .. V]`).
        pub n_views: u32,
        /// Offset of the slots' candidate table in `tables`.
        pub view_table: u32,
        /// Store offset of the coefficients `[texel][V][3][n^2]`: f32 (`bits` 32) or bytes packed
        /// four to a word (`bits` 8).
        pub coeffs: u32,
        /// 32 or 8.
        pub bits: u32,
        /// Planes per texel (`3 V n^2`).
        pub k: u32,
        /// `bits` 8: store offset of the `k` scales, then the `k` biases.
        pub scale: u32,
    }
}

impl GpuLayout for Hsh {
    type Params = HshParams;
    const SHADER: Shader = Shader::new::<HshParams>("hsh", include_str!("../../../shaders_wgsl/hsh.wgsl"));

    fn parts(&self) -> Vec<Cow<'_, [u32]>> {
        self.coeffs.parts()
    }

    fn dir_sets(&self) -> Vec<&[[f64; 3]]> {
        vec![&self.views]
    }

    fn params(&self, offsets: &[u32], tables: &[u32]) -> HshParams {
        let q = self.coeffs.planes.is_some();
        HshParams {
            order: self.order as u32,
            n_views: self.views.len() as u32,
            view_table: tables[0],
            coeffs: offsets[0],
            bits: self.coeffs.bits(),
            k: (self.views.len() * 3 * self.n2()) as u32,
            scale: if q { offsets[1] } else { 0 },
        }
    }
}

impl Model for Hsh {
    const KIND: &'static str = "hsh";
    const TEXEL_ARRAYS: &'static [&'static str] = &["coeffs", "coeffs_q"];
    const DOC: &'static str =
        "Hemispherical harmonics (Gautron et al. 2004, the basis of .rti HSH files) per view slot, 8-bit planes";
    const ABOUT: &'static str = "\
Hemispherical harmonics (Gautron et al. 2004) per view slot, the basis of the `.rti` HSH files
that RTIViewer and relight open, fitted like the PTM (paper 000, section 3.1): one regularised
pseudo-inverse of the `order^2`-column light design matrix per view slot, applied to every texel.
The basis is orthonormal on the hemisphere, with the RTI viewers' signs (term `j = l (l + 1) + m`,
`x = cos(theta)`: `1/sqrt(2 pi)`; `sqrt(6/pi) s cos(phi)`, `sqrt(3/(2 pi)) (2x - 1)`, ... up to
order 4). A slot with too few or degenerate lights gets a lower order of its own lights, else the
nearest views' lights pooled, and is listed in `model.report[\"degenerate_slots\"]`. With `bits=8`
the three channels of a slot and term share a scale and bias, as in a `.rti` file.";
    const OPTIONS: &'static [Spec] = &[
        Spec::int("order", 3, 1, Some(4), "the order n: n^2 coefficients per channel"),
        Spec::float("lambda", 1e-6, 0.0, "ridge weight relative to the largest squared singular value of a slot's design matrix (0: plain least squares)"),
        Spec::float("rcond", 1e-6, 0.0, "singular values below rcond x the largest count as zero"),
        Spec::choice("on_degenerate", "reduce", &["reduce", "raise", "clamp"], "a slot with too few or degenerate lights: a lower order or pooled lights (listed in the report), an error, or the minimum-norm solution"),
        Spec::int_choice("bits", 8, &[8, 32], "8: 8-bit planes with a scale and bias per slot and term (as .rti files); 32: float32 coefficients"),
    ];
    const EXAMPLES: &'static [(&'static str, &'static str)] =
        &[("HSH-2", r#"{"order": 2}"#), ("HSH-3", r#"{"order": 3}"#), ("HSH-4", r#"{"order": 4}"#)];
    const SAMPLING: Sampling = Sampling::PerView { min_lights: 9, why: "order 3; order 2 needs 4" };
    const EXPORTS: &'static [&'static str] = &["rti", "relight"];
    const MIP: Mip = Mip::Average;
    type Options = HshOptions;
    // Each texel's values are checked as the per-texel pass reads them (TexelScan).
    const SCANS_VALUES: bool = true;
    // As the PTM: the slots' pseudo-inverses depend on the lights and the mask only.
    const BLOCKWISE: crate::blockwise::Blockwise =
        crate::blockwise::Blockwise::Texels { overrides: r#"{"bits": 32}"#, counts: &[] };

    fn fit(btf: &BtfRef<'_>, options: &HshOptions, monitor: &Monitor) -> Result<Self> {
        fit_hsh(btf, options, monitor)
    }

    // Every texel is fitted from its own values alone.
    const SCREENS_TEXELS: bool = true;

    fn fit_screened(
        btf: &BtfRef<'_>,
        options: &HshOptions,
        screen: &crate::robust::TexelScreen<'_>,
        monitor: &Monitor,
    ) -> Result<Self> {
        fit_hsh_screened(btf, options, Some(screen), monitor)
    }

    fn mip_texels(&self, groups: &[Vec<(u32, f32)>]) -> Result<Self> {
        average_texels(self, groups)
    }

    /// The planes' scales span every texel: quantized over the stitched floats, as `fit_hsh`.
    fn finish_blocks(mut self, options: &HshOptions) -> Result<Self> {
        check_bits(options.bits)?;
        if options.bits == 8 && self.coeffs.planes.is_none() {
            let k = self.views.len() * 3 * self.n2();
            self.coeffs = quantized(std::mem::take(&mut self.coeffs.values), k, self.n2())?;
        }
        Ok(self)
    }

    /// `coeffs` `[H, W, V, 3, n^2]` (f32), or quantized `coeffs_q` (uint8, that shape) with
    /// `coeffs_scale` and `coeffs_bias` (`[3 V n^2]`); `views` `[V, 3]`. The order follows from
    /// the last axis.
    fn to_arrays(&self) -> NamedArrays {
        let mut a = NamedArrays::new();
        let shape = [self.height, self.width, self.views.len(), 3, self.n2()];
        self.coeffs.insert_into(&mut a, "coeffs", &shape);
        a.put_directions("views", &self.views);
        a
    }

    /// `{"degenerate_slots": [...]}` as for the PTM.
    fn report(&self) -> serde_json::Value {
        serde_json::json!({ "degenerate_slots": self.degenerate_slots })
    }

    fn from_arrays(a: &NamedArrays) -> Result<Self> {
        let views = a.directions("views", None)?;
        let (coeffs, sh) = Coeffs::from_arrays(a, "coeffs", &[None, None, Some(views.len()), Some(3), None], 2)?;
        let order = (1..=MAX_ORDER).find(|n| n * n == sh[4]).ok_or_else(|| {
            Error::arg("coeffs", format!("the last axis holds {} terms; expected 1, 4, 9 or 16 (order 1 to 4)", sh[4]))
        })?;
        let m = Hsh { order, height: sh[0], width: sh[1], views, coeffs, degenerate_slots: Vec::new() };
        m.validate()?;
        Ok(m)
    }
}

#[cfg(test)]
mod tests;
