//! Per-view Lafortune lobes, registry kind `"lafortune_view"`: paper 000, section 3.2, which fits
//! the Lafortune model "like the PTM" (section 3.1): one lobe set per texel **and measured view
//! slot**, the view fixed per slot and the lobes a function of the light, blended between the
//! slots at render time as the PTM is (the three nearest slots, weights of
//! [`directions::interp_weights`]). The global form, one lobe set per texel over all views at
//! once (McAllister's SBRDF), is the parent module [`crate::lafortune`].
//!
//! Within a slot of view `v` each texel's values are modelled by the Lafortune formula with that
//! view:
//!
//! ```text
//! value(l) = l_z * ( kd + sum_i max(Cx_i lx vx + Cy_i ly vy + Cz_i lz vz, 0)^n_i )
//! ```
//!
//! so the fit is the global model's fit fed with one slot's samples: the same kernels,
//! Levenberg-Marquardt, linear initialisation, bounds and fallback chain (damped restart, fewer
//! lobes, closed-form diffuse), the same per-fit status (0 converged, 1 fell back, 2 failed) and
//! the same counts in the report. One check is added, because a slot has one view's lights only:
//! a fit whose lobes rise above twice the slot's largest measured value anywhere on the
//! hemisphere (a sharp lobe placed in a gap between the lights, the "artifacts" of sparse
//! sampling paper 000 reports) is refitted with fewer lobes, then replaced by the closed-form
//! diffuse fit ([`fit_plausible`]). `kind="lum"` fits the luminance with 1 to 7 lobes times a base
//! colour per texel and slot (the least-squares modulation of the slot's measured luminance, as
//! the PTM's LRGB has one per slot); `kind="rgb"` fits each channel with 1 to 3 lobes.
//!
//! **Stored form.** With the view fixed, only the products `D = (Cx vx, Cy vy, Cz vz)` enter the
//! slot's function (`s = D . l`): at the normal view `Cx` and `Cy` multiply zero and the data say
//! nothing of them. The model stores `D`, the lobe's axis in light space, so each slot is a
//! function of the light alone, exactly like a PTM slot: evaluation and the shader need no view,
//! and no undetermined `C` component is ever stored or rendered.
//!
//! **Masked slots.** A slot whose present lights are fewer than a fit's unknowns (`1 + 4 lobes`,
//! or `4 lobes` without kd; no lights at all, e.g. a view held out entirely) cannot be fitted. It
//! borrows the lobes (and base colours and statuses) of the angularly nearest fitted slot, so
//! rendering near it shows the neighbouring view's reflectance field rather than black;
//! `source[v]` names the slot each slot's lobes come from and the report lists the borrowed
//! slots. A BTF with no fittable slot at all is a [`Error::Degenerate`].

use super::kernels::{Geometry, Layout, Work};
use super::{
    base_colour, Context, FitOut, FitReport, Interp, LafortuneKind, MAX_LOBES_LUM, MAX_LOBES_RGB, N_MAX, N_MIN,
};
use crate::gpu::{words, GpuLayout, Shader};
use crate::model::{Model, ReflectanceModel, Sampling, Setting};
use crate::options::Spec;
use btfrs_core::arrays::check_finite;
use btfrs_core::btf::TexelScan;
use btfrs_core::{directions, BtfRef, Error, Monitor, NamedArrays, Result};
use rayon::prelude::*;
use std::borrow::Cow;

/// Fit options of the per-view model (those of the global one without `densify`: a slot's
/// samples are its lights, and the paper's densification is over views and lights together).
#[derive(Debug, Clone, Copy, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LafortuneViewOptions {
    /// The variant.
    pub kind: LafortuneKind,
    /// Lobes per fit: 1 to 7 for `Lum`, 1 to 3 (per channel) for `Rgb`.
    pub lobes: usize,
    /// Fit the diffuse term kd; without it kd is fixed at 0.
    pub diffuse: bool,
    /// Most LM steps per run (>= 1).
    pub max_iter: usize,
}

impl Default for LafortuneViewOptions {
    /// The defaults of [`LafortuneView`]'s option schema.
    fn default() -> Self {
        crate::options::defaults(<LafortuneView as Model>::OPTIONS)
    }
}

/// How the per-view fits went: the counts of [`FitReport`] over all fits (one per texel and
/// fitted slot for `Lum`, three for `Rgb`; borrowed slots are not fits), and the slots.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct LafortuneViewReport {
    /// Counts over the fits (`rms_residual` over the fitted slots' samples).
    #[serde(flatten)]
    pub fits: FitReport,
    /// View slots.
    pub slots: usize,
    /// Slots fitted from their own samples.
    pub fitted_slots: usize,
    /// Slots with too few present lights, which use the lobes of `source[v]`.
    pub borrowed_slots: Vec<usize>,
}

/// A fitted per-view Lafortune model: per texel and view slot, a lobe set over the light.
#[derive(Debug, Clone)]
pub struct LafortuneView {
    /// The variant.
    pub kind: LafortuneKind,
    /// Rows.
    pub height: usize,
    /// Columns.
    pub width: usize,
    /// Lobes per fit.
    pub lobes: usize,
    /// The view direction of each slot.
    pub views: Vec<[f64; 3]>,
    /// Lum: `[H, W, V, P]`; Rgb: `[H, W, V, 3, P]`; `P = 1 + 4 * lobes`, ordered
    /// `[kd, (Dx, Dy, Dz, n) per lobe]` with `D = (Cx vx, Cy vy, Cz vz)` for the slot's view `v`.
    pub params: Vec<f32>,
    /// Lum only: `[H, W, V, 3]` base colour per texel and slot.
    pub rgb: Option<Vec<f32>>,
    /// `[H, W, V]` (Rgb: `[H, W, V, 3]`) status of the fit a slot's lobes come from: 0 converged,
    /// 1 fell back, 2 failed (as for [`crate::Lafortune::status`]). May be empty for a model
    /// loaded without it.
    pub status: Vec<u8>,
    /// `[V]`: the slot whose fit each slot uses (itself unless it was borrowed).
    pub source: Vec<usize>,
    /// The fit's summary (`LafortuneViewReport::default()` for a loaded model).
    pub report: LafortuneViewReport,
}

/// The max lobes of a kind.
fn max_lobes(kind: LafortuneKind) -> usize {
    match kind {
        LafortuneKind::Lum => MAX_LOBES_LUM,
        LafortuneKind::Rgb => MAX_LOBES_RGB,
    }
}

/// Fits per (texel, slot): 1 for Lum, 3 for Rgb.
fn fits_of(kind: LafortuneKind) -> usize {
    match kind {
        LafortuneKind::Lum => 1,
        LafortuneKind::Rgb => 3,
    }
}

/// Fit a per-view Lafortune model to the present pairs of `btf`; `monitor` counts texels.
pub fn fit_lafortune_view(btf: &BtfRef<'_>, opts: &LafortuneViewOptions, monitor: &Monitor) -> Result<LafortuneView> {
    let ml = max_lobes(opts.kind);
    if !(1..=ml).contains(&opts.lobes) {
        return Err(Error::arg(
            "lobes",
            format!("expected 1 to {ml} lobes for the {:?} model, got {}", opts.kind, opts.lobes),
        ));
    }
    if opts.max_iter == 0 {
        return Err(Error::arg("max_iter", "expected at least 1 iteration, got 0"));
    }
    let lay = Layout { diffuse: opts.diffuse, lobes: opts.lobes };
    let (nv, nl) = (btf.views.len(), btf.lights.len());

    // One fit context per fittable slot: the slot's present lights with its view, i.e. the
    // global model's context restricted to one view and without densification.
    let ctxs: Vec<Option<Vec<Context>>> = (0..nv)
        .into_par_iter()
        .map(|v| {
            let ls = btf.lights_of_view(v);
            if ls.len() < lay.m() {
                return None;
            }
            let dirs: Vec<([f64; 3], [f64; 3])> = ls.iter().map(|&l| (btf.views[v], btf.lights[l])).collect();
            let geo = Geometry::new(dirs.iter().copied());
            // The global fit's coarse start on every SUB-th sample (it is used only when a slot
            // has at least SUB_MIN of them).
            let sub_idx: Vec<usize> = (0..dirs.len()).step_by(super::SUB).collect();
            let geo_sub = Geometry::new(sub_idx.iter().map(|&i| dirs[i]));
            let basis = super::init::Basis::new(&geo);
            let meas: Vec<usize> = ls.iter().map(|&l| v * nl + l).collect();
            // `lobes`, `lobes - 1`, ..., 1: the fits tried in turn until one is plausible.
            let chain = (1..=opts.lobes)
                .rev()
                .map(|lobes| Context {
                    meas: meas.clone(),
                    extra: Interp::default(),
                    geo: geo.clone(),
                    basis: basis.clone(),
                    // The global guard's check pairs are not needed: every slot fit goes through
                    // `fit_plausible`, which probes the whole hemisphere of lights for this
                    // slot's view (with an empty guard the global driver never rejects).
                    guard: super::guard::Guard::default(),
                    lay: Layout { lobes, ..lay },
                    max_iter: opts.max_iter,
                    geo_sub: geo_sub.clone(),
                    sub_idx: sub_idx.clone(),
                })
                .collect();
            Some(chain)
        })
        .collect();
    let probe = probe_lights(btf.lights);
    let fitted: Vec<usize> = (0..nv).filter(|&v| ctxs[v].is_some()).collect();
    if fitted.is_empty() {
        let most = (0..nv).map(|v| btf.lights_of_view(v).len()).max().unwrap_or(0);
        return Err(Error::Degenerate(format!(
            "no view slot has enough present lights for a {}-lobe per-view Lafortune fit: it has {} parameters \
             per texel{} and slot, the best slot has {most} lights; use fewer lobes or more lights",
            opts.lobes,
            lay.m(),
            if opts.kind == LafortuneKind::Rgb { " and channel" } else { "" },
        )));
    }
    let source: Vec<usize> = (0..nv).map(|v| nearest_fitted(btf.views, &fitted, v)).collect();
    monitor.check()?;

    let (h, w) = (btf.height, btf.width);
    let nt = h * w;
    let nf = fits_of(opts.kind);
    let pp = 1 + 4 * opts.lobes;
    let mut params = vec![0.0f32; nt * nv * nf * pp];
    let mut base = vec![0.0f32; nt * nv * 3];
    let mut status = vec![0u8; nt * nv * nf];
    let mut sse = vec![0.0f64; nt * nv * nf];
    let mut iters = vec![0u32; nt * nv * nf];
    let mut extrap = vec![false; nt * nv * nf];
    monitor.start(nt as u64);
    let scan = TexelScan::new();
    params
        .par_chunks_mut(nv * nf * pp)
        .zip(base.par_chunks_mut(nv * 3))
        .zip(status.par_chunks_mut(nv * nf))
        .zip(sse.par_chunks_mut(nv * nf))
        .zip(iters.par_chunks_mut(nv * nf))
        .zip(extrap.par_chunks_mut(nv * nf))
        .enumerate()
        .for_each_init(
            || Work::new(0, opts.lobes),
            |work, (t, (((((p, rgb), st), e), it), ex))| {
                if monitor.is_cancelled() || scan.failed() {
                    return;
                }
                let texel = btf.texel(t);
                if !scan.check(texel) {
                    return;
                }
                for (v, chain) in ctxs.iter().enumerate() {
                    let Some(chain) = chain else { continue };
                    let geo = &chain[0].geo;
                    // The kernels run over the slot's padded length; a scratch sized for
                    // another length is replaced (slots of a masked BTF differ), and the padding
                    // is zeroed because a shorter slot before may have left targets there.
                    if work.y.len() != geo.npad() {
                        *work = Work::new(geo.npad(), opts.lobes);
                    }
                    work.y[geo.n..].fill(0.0);
                    let (pv, sv) = (&mut p[v * nf * pp..(v + 1) * nf * pp], v * nf);
                    match opts.kind {
                        LafortuneKind::Lum => {
                            base_colour(texel, &chain[0].meas, &mut rgb[3 * v..3 * v + 3]);
                            let r = fit_plausible(chain, texel, None, work, &probe, btf.views[v]);
                            ex[sv] = r.extrapolated;
                            r.write(pv, &mut st[sv], &mut e[sv], &mut it[sv]);
                        }
                        LafortuneKind::Rgb => {
                            for c in 0..3 {
                                let r = fit_plausible(chain, texel, Some(c), work, &probe, btf.views[v]);
                                let (s, x) = (sv + c, &mut pv[c * pp..(c + 1) * pp]);
                                ex[s] = r.extrapolated;
                                r.write(x, &mut st[s], &mut e[s], &mut it[s]);
                            }
                        }
                    }
                    to_light_axes(pv, btf.views[v], opts.lobes);
                }
                // Borrowed slots copy their source's fit within this texel.
                for v in (0..nv).filter(|&v| source[v] != v) {
                    let s = source[v];
                    p.copy_within(s * nf * pp..(s + 1) * nf * pp, v * nf * pp);
                    rgb.copy_within(3 * s..3 * s + 3, 3 * v);
                    st.copy_within(s * nf..(s + 1) * nf, v * nf);
                }
                monitor.advance(1);
            },
        );
    monitor.check()?;
    scan.finish("data", btf.data)?;

    // Counts over the real fits only (a borrowed slot repeats its source's).
    let (mut counts, mut total_iters, mut total_sse, mut fits) = ([0usize; 3], 0u64, 0.0f64, 0usize);
    let mut extrapolated = 0usize;
    let mut samples = 0usize;
    for t in 0..nt {
        for &v in &fitted {
            for c in 0..nf {
                let i = (t * nv + v) * nf + c;
                counts[status[i].min(2) as usize] += 1;
                extrapolated += usize::from(extrap[i]);
                total_iters += iters[i] as u64;
                total_sse += sse[i];
                fits += 1;
                samples += ctxs[v].as_ref().map_or(0, |x| x[0].geo.n);
            }
        }
    }
    let report = LafortuneViewReport {
        fits: FitReport {
            fits,
            converged: counts[0],
            fell_back: counts[1],
            failed: counts[2],
            extrapolated,
            mean_iterations: total_iters as f64 / fits as f64,
            rms_residual: (total_sse / samples.max(1) as f64).sqrt(),
        },
        slots: nv,
        fitted_slots: fitted.len(),
        borrowed_slots: (0..nv).filter(|&v| source[v] != v).collect(),
    };
    Ok(LafortuneView {
        kind: opts.kind,
        height: h,
        width: w,
        lobes: opts.lobes,
        views: btf.views.to_vec(),
        params,
        rgb: (opts.kind == LafortuneKind::Lum).then_some(base),
        status,
        source,
        report,
    })
}

/// How far above the slot's largest measured value a fit may rise anywhere on the hemisphere
/// before it counts as implausible (see [`fit_plausible`]).
const PLAUSIBLE_PEAK: f64 = 2.0;
/// Side of the equal-area grid of probe lights (plus the measured light directions).
const PROBE_GRID: usize = 12;

/// The light directions at which every slot fit is probed: all measured light directions
/// (present or masked: only their directions are used), a `PROBE_GRID^2` equal-area grid, and
/// the global guard's rings of grazing directions up to the horizon (the grid's outer cells sit
/// near 85 degrees; measured on weave 64^2 before the rings: 2-lobe slot fits rendered `inf` at a
/// sphere's silhouette).
fn probe_lights(lights: &[[f64; 3]]) -> Vec<[f64; 3]> {
    let n = PROBE_GRID;
    let grid = (0..n * n).map(|k| {
        btfrs_hemimap::square_to_hemisphere(((k / n) as f64 + 0.5) / n as f64, ((k % n) as f64 + 0.5) / n as f64)
    });
    lights.iter().copied().chain(grid).chain(super::guard::grazing_rings()).collect()
}

/// One slot fit with a plausibility check that the global model does not need. A slot has one
/// view's lights only (81, fewer where masked), and LM readily places a sharp lobe in a gap
/// between them: it fits the samples and peaks far above them in between, which is the "visual
/// artifacts under sparse sampling" paper 000 warns of (measured on weave 32^2 without this
/// check: 111% held-out error at one lobe, overflow to infinity at two). So each fit (the
/// parent's whole chain) is evaluated at the probe lights; one that rises above
/// [`PLAUSIBLE_PEAK`] times the slot's largest measured value is refitted with one lobe fewer,
/// and after one lobe replaced by the closed-form `kd` fit (status 2; without `diffuse`, by
/// zeros). A refit plausible one has status at least 1 (fell back).
fn fit_plausible(
    chain: &[Context],
    texel: &[f32],
    channel: Option<usize>,
    work: &mut Work,
    probe: &[[f64; 3]],
    view: [f64; 3],
) -> FitOut {
    let mut iters = 0;
    let ctx0 = &chain[0];
    // Whether a fit with more lobes was rejected as implausible (counted as "extrapolated").
    let mut rejected = false;
    for (i, ctx) in chain.iter().enumerate() {
        ctx.gather(texel, channel, &mut work.y);
        let ymax = work.y[..ctx.geo.n].iter().fold(0.0f64, |a, &b| a.max(b));
        let mut r = ctx.fit(work);
        iters += r.iters;
        r.iters = iters;
        if i > 0 {
            r.status = r.status.max(1);
        }
        if peak(&r.p, view, probe) <= PLAUSIBLE_PEAK * ymax {
            r.extrapolated = rejected;
            return r;
        }
        rejected = true;
    }
    // Closed form: value = kd l_z by least squares over the slot's samples.
    ctx0.gather(texel, channel, &mut work.y);
    let mut r = FitOut::zero(2);
    r.iters = iters;
    r.extrapolated = rejected;
    let (mut yl, mut ll, mut yy) = (0.0f64, 0.0f64, 0.0f64);
    for i in 0..ctx0.geo.n {
        yl += work.y[i] * ctx0.geo.lz[i];
        ll += ctx0.geo.lz[i] * ctx0.geo.lz[i];
        yy += work.y[i] * work.y[i];
    }
    let kd = if ctx0.lay.diffuse && ll > 0.0 { (yl / ll).max(0.0) } else { 0.0 };
    r.p[0] = kd;
    r.sse = (yy - 2.0 * kd * yl + kd * kd * ll).max(0.0);
    r
}

/// The largest value of a fit `p = [kd, (Cx, Cy, Cz, n) x MAX_LOBES]` (data units) at the probe
/// lights for view `v`; infinite when it overflows.
fn peak(p: &[f64], v: [f64; 3], probe: &[[f64; 3]]) -> f64 {
    let mut most = 0.0f64;
    for l in probe {
        let mut rho = p[0];
        for k in 0..super::kernels::MAX_LOBES {
            let q = &p[1 + 4 * k..5 + 4 * k];
            let s = q[0] * l[0] * v[0] + q[1] * l[1] * v[1] + q[2] * l[2] * v[2];
            if s > 0.0 {
                rho += s.powf(q[3]);
            }
        }
        let x = l[2].max(0.0) * rho;
        most = if x.is_nan() { f64::INFINITY } else { most.max(x) };
    }
    most
}

/// The fitted slot angularly nearest to slot `v` (`v` itself when it is fitted; ties go to the
/// lower index, so the choice is deterministic).
fn nearest_fitted(views: &[[f64; 3]], fitted: &[usize], v: usize) -> usize {
    let mut best = (f64::INFINITY, fitted[0]);
    for &f in fitted {
        let d = directions::angle_between(views[v], views[f]);
        if d < best.0 {
            best = (d, f);
        }
    }
    best.1
}

/// Turn one slot's fitted `[kd, (Cx, Cy, Cz, n) x lobes]` (per channel) into the stored
/// `[kd, (Dx, Dy, Dz, n) x lobes]`, `D = C * v` componentwise. In f64 from the f32 result: the
/// product of two values each within f32 rounding, stored once more in f32.
fn to_light_axes(p: &mut [f32], v: [f64; 3], lobes: usize) {
    let pp = 1 + 4 * lobes;
    for fit in p.chunks_mut(pp) {
        for k in 0..lobes {
            for (i, x) in fit[1 + 4 * k..4 + 4 * k].iter_mut().enumerate() {
                *x = (*x as f64 * v[i]) as f32;
            }
        }
    }
}

/// A prepared per-view query: the blend weights of the nearest slots and the light.
#[derive(Debug, Clone)]
pub struct LafortuneViewQuery {
    slots: Vec<(usize, f32)>,
    l: [f32; 3],
    lz: f32,
}

impl LafortuneView {
    /// Values per fit: `1 + 4 * lobes`.
    pub fn params_per_fit(&self) -> usize {
        1 + 4 * self.lobes
    }

    /// Check array lengths, finiteness, exponent bounds and the slot sources (for models built
    /// from loaded files).
    pub fn validate(&self) -> Result<()> {
        if self.height == 0 || self.width == 0 {
            return Err(Error::arg("params", "the per-view Lafortune model has no texels"));
        }
        directions::validate("views", &self.views)?;
        let ml = max_lobes(self.kind);
        if !(1..=ml).contains(&self.lobes) {
            return Err(Error::arg("lobes", format!("expected 1 to {ml} lobes, got {}", self.lobes)));
        }
        let nv = self.views.len();
        let fits = self.height * self.width * nv * fits_of(self.kind);
        let pp = self.params_per_fit();
        if self.params.len() != fits * pp {
            return Err(Error::arg("params", format!("expected {} values, got {}", fits * pp, self.params.len())));
        }
        check_finite("params", &self.params)?;
        for (f, p) in self.params.chunks(pp).enumerate() {
            for k in 0..self.lobes {
                let n = p[4 + 4 * k] as f64;
                if !(N_MIN..=N_MAX).contains(&n) {
                    return Err(Error::arg(
                        "params",
                        format!("fit {f}, lobe {k}: exponent {n} is outside [{N_MIN}, {N_MAX}]"),
                    ));
                }
            }
        }
        match (&self.rgb, self.kind) {
            (Some(r), LafortuneKind::Lum) if r.len() == self.height * self.width * nv * 3 => check_finite("rgb", r)?,
            (None, LafortuneKind::Rgb) => {}
            _ => return Err(Error::arg("rgb", "expected a [H, W, V, 3] base colour for Lum and none for Rgb")),
        }
        if !(self.status.is_empty() || self.status.len() == fits) {
            return Err(Error::arg("status", format!("expected {fits} entries (or none), got {}", self.status.len())));
        }
        if let Some(s) = self.status.iter().find(|&&s| s > 2) {
            return Err(Error::arg("status", format!("expected 0, 1 or 2, got {s}")));
        }
        if self.source.len() != nv {
            return Err(Error::arg("source", format!("expected {nv} slot indices, got {}", self.source.len())));
        }
        for (v, &s) in self.source.iter().enumerate() {
            // A source is a slot that was fitted itself: one hop, never a chain or a cycle.
            if s >= nv || self.source[s] != s {
                return Err(Error::arg(
                    "source",
                    format!("slot {v}: expected a fitted slot in 0..{nv} (one whose source is itself), got {s}"),
                ));
            }
        }
        Ok(())
    }

    /// `kd + sum max(D . l, 0)^n` of one fit's parameters `p`.
    #[inline]
    fn rho(&self, p: &[f32], l: [f32; 3]) -> f32 {
        let mut v = p[0];
        for k in 0..self.lobes {
            let c = &p[1 + 4 * k..5 + 4 * k];
            let s = c[0] * l[0] + c[1] * l[1] + c[2] * l[2];
            if s > 0.0 {
                v += s.powf(c[3]);
            }
        }
        v
    }

    /// The value of texel `t` in slot `v` alone (no blending, no foreshortening).
    #[inline]
    fn slot_rho(&self, t: usize, v: usize, l: [f32; 3]) -> [f32; 3] {
        let nv = self.views.len();
        let pp = self.params_per_fit();
        let ts = t * nv + v;
        match self.kind {
            LafortuneKind::Lum => {
                let lum = self.rho(&self.params[ts * pp..(ts + 1) * pp], l);
                let b = &self.rgb.as_ref().expect("validated: Lum has base colours")[3 * ts..3 * ts + 3];
                [b[0] * lum, b[1] * lum, b[2] * lum]
            }
            LafortuneKind::Rgb => {
                std::array::from_fn(|c| self.rho(&self.params[(3 * ts + c) * pp..(3 * ts + c + 1) * pp], l))
            }
        }
    }
}

impl ReflectanceModel for LafortuneView {
    type Query = LafortuneViewQuery;

    fn dims(&self) -> (usize, usize) {
        (self.height, self.width)
    }

    fn query(&self, view: [f64; 3], light: [f64; 3]) -> LafortuneViewQuery {
        // Defined at the slots only; in between, blend the three nearest, as the PTM does.
        let slots = directions::interp_weights(&self.views, view, 3).into_iter().map(|(i, w)| (i, w as f32)).collect();
        LafortuneViewQuery {
            slots,
            l: light.map(|x| x as f32),
            // As in the fit: no light arrives from at or below the horizon.
            lz: light[2].max(0.0) as f32,
        }
    }

    #[inline]
    fn eval(&self, t: usize, q: &LafortuneViewQuery) -> [f32; 3] {
        let mut out = [0.0f32; 3];
        for &(v, wgt) in &q.slots {
            let x = self.slot_rho(t, v, q.l);
            for c in 0..3 {
                out[c] += wgt * x[c];
            }
        }
        out.map(|x| q.lz * x)
    }
}

crate::gpu_params! {
    /// Parameters of `lafortune_view.wgsl`.
    pub struct LafortuneViewParams {
        /// 0 = RGB (one parameter set per channel), 1 = luminance times a base colour.
        pub kind: u32,
        /// Lobes per fit.
        pub lobes: u32,
        /// Number of view slots V (their directions are `mdirs[0 .. V]`).
        pub n_views: u32,
        /// Offset of the slots' candidate table in `tables`.
        pub view_table: u32,
        /// Store offset of the parameters: `[texel][V][P]` (lum) or `[texel][V][3][P]` (rgb) f32,
        /// `P = 1 + 4 * lobes`, ordered kd, (Dx, Dy, Dz, n) per lobe (D: the lobe axis in light
        /// space, `C * v` of the slot's view).
        pub params: u32,
        /// Store offset of the base colours `[texel][V][3]` f32 (luminance kind only).
        pub rgb: u32,
    }
}

impl GpuLayout for LafortuneView {
    type Params = LafortuneViewParams;
    const SHADER: Shader = Shader::new::<LafortuneViewParams>(
        "lafortune_view",
        include_str!("../../../../shaders_wgsl/lafortune_view.wgsl"),
    );

    fn parts(&self) -> Vec<Cow<'_, [u32]>> {
        let mut p = vec![words(&self.params)];
        if let Some(rgb) = &self.rgb {
            p.push(words(rgb));
        }
        p
    }

    fn dir_sets(&self) -> Vec<&[[f64; 3]]> {
        vec![&self.views]
    }

    fn params(&self, offsets: &[u32], tables: &[u32]) -> LafortuneViewParams {
        LafortuneViewParams {
            kind: match self.kind {
                LafortuneKind::Rgb => 0,
                LafortuneKind::Lum => 1,
            },
            lobes: self.lobes as u32,
            n_views: self.views.len() as u32,
            view_table: tables[0],
            params: offsets[0],
            rgb: offsets.get(1).copied().unwrap_or(0),
        }
    }
}

impl Model for LafortuneView {
    const KIND: &'static str = "lafortune_view";
    const TEXEL_ARRAYS: &'static [&'static str] = &["params", "rgb", "status"];
    const DOC: &'static str =
        "Lafortune lobes per texel and view slot, blended between slots like the PTM (paper 000, section 3.2)";
    // Cheap ones: they are fitted and rendered in the GPU-vs-CPU tests and the demo.
    const ABOUT: &'static str = "\
Lafortune lobes per texel and view slot, as paper 000 (section 3.2) does: \"like the PTM\", one
lobe set per measured view, a function of the light, blended between the nearest view slots when
rendered. The same Levenberg-Marquardt fit as the global model (kernels, initialisation, bounds,
fallbacks, `status` and `report` counts) fed with one slot's samples at a time. About `V` times
the parameters of the global model (81 for the UBO sampling), and it follows how the reflectance
changes with the view (parallax, masking) that one lobe set per texel cannot. A view slot with
fewer present lights than a fit's unknowns borrows the lobes of the nearest fitted slot
(`model.report[\"borrowed_slots\"]`; `model.arrays[\"source\"]` maps each slot to the slot it uses).";
    const OPTIONS: &'static [Spec] = &[
        Spec::choice(
            "kind",
            "lum",
            &["lum", "rgb"],
            "\"lum\": lobes on the luminance times a base colour; \"rgb\": lobes per channel",
        ),
        Spec::int(
            "lobes",
            2,
            1,
            Some(crate::lafortune::MAX_LOBES_LUM as i64),
            "lobes per fit: 1 to 7 for \"lum\", 1 to 3 for \"rgb\"",
        ),
        Spec::bool("diffuse", true, "fit the diffuse term kd (false: kd = 0)"),
        Spec::int("max_iter", 60, 1, None, "most Levenberg-Marquardt steps per run"),
    ];
    const EXAMPLES: &'static [(&'static str, &'static str)] = &[
        ("Lafortune-view-Lum 1", r#"{"kind": "lum", "lobes": 1}"#),
        ("Lafortune-view-RGB 1", r#"{"kind": "rgb", "lobes": 1}"#),
    ];
    // Ten Levenberg-Marquardt steps run every stage of the fit (the start, the steps, the
    // fallbacks) at a sixth of the default's cost.
    const SMALLEST: &'static str = r#"{"kind": "lum", "lobes": 1, "max_iter": 10}"#;
    const SWEEP: &'static [Setting] = &[
        Setting::quick("Lafortune/view-Lum 1", r#"{"kind": "lum", "lobes": 1}"#),
        Setting::full("Lafortune/view-Lum 2", r#"{"kind": "lum", "lobes": 2}"#),
        Setting::full("Lafortune/view-RGB 1", r#"{"kind": "rgb", "lobes": 1}"#),
    ];
    const SAMPLING: Sampling = Sampling::PerView { min_lights: 4, why: "1 lobe" };
    type Options = LafortuneViewOptions;
    // Each texel's values are checked as the per-texel pass reads them (TexelScan).
    const SCANS_VALUES: bool = true;

    // One Levenberg-Marquardt fit per texel (per texel and view slot), nothing shared.
    const BLOCKWISE: crate::blockwise::Blockwise = crate::blockwise::Blockwise::Texels {
        overrides: "{}",
        counts: &["converged", "extrapolated", "failed", "fell_back", "fits"],
    };

    fn fit(btf: &BtfRef<'_>, options: &LafortuneViewOptions, monitor: &Monitor) -> Result<Self> {
        fit_lafortune_view(btf, options, monitor)
    }

    /// `params` (lum `[H, W, V, P]`, rgb `[H, W, V, 3, P]` f32), `views` `[V, 3]`, `source`
    /// `[V]` i32, for lum `rgb` `[H, W, V, 3]`, and `status` u8 (`[H, W, V]` or
    /// `[H, W, V, 3]`) when the fit recorded it. The kind follows from the shape of `params`.
    fn to_arrays(&self) -> NamedArrays {
        let mut a = NamedArrays::new();
        let (h, w, nv, p) = (self.height, self.width, self.views.len(), self.params_per_fit());
        match self.kind {
            LafortuneKind::Lum => a.put("params", &[h, w, nv, p], self.params.clone()),
            LafortuneKind::Rgb => a.put("params", &[h, w, nv, 3, p], self.params.clone()),
        }
        a.put_directions("views", &self.views);
        a.put("source", &[nv], self.source.iter().map(|&s| s as i32).collect::<Vec<i32>>());
        if let Some(rgb) = &self.rgb {
            a.put("rgb", &[h, w, nv, 3], rgb.clone());
        }
        if !self.status.is_empty() {
            match self.kind {
                LafortuneKind::Lum => a.put("status", &[h, w, nv], self.status.clone()),
                LafortuneKind::Rgb => a.put("status", &[h, w, nv, 3], self.status.clone()),
            }
        }
        a
    }

    fn from_arrays(a: &NamedArrays) -> Result<Self> {
        let views = a.directions("views", None)?;
        let nv = views.len();
        let (params, sh) = match a.get::<f32>("params", &[None, None, Some(nv), None]) {
            Ok(x) => x,
            Err(_) => a.get::<f32>("params", &[None, None, Some(nv), Some(3), None]).map_err(|_| {
                Error::arg(
                    "params",
                    format!("expected shape [H, W, {nv}, P] (lum) or [H, W, {nv}, 3, P] (rgb) of float32"),
                )
            })?,
        };
        let kind = if sh.len() == 4 { LafortuneKind::Lum } else { LafortuneKind::Rgb };
        let p = sh[sh.len() - 1];
        if p < 5 || (p - 1) % 4 != 0 {
            return Err(Error::arg("params", format!("expected 1 + 4 * lobes values per fit, got {p}")));
        }
        let (h, w) = (Some(sh[0]), Some(sh[1]));
        let rgb = match kind {
            LafortuneKind::Lum => Some(a.get::<f32>("rgb", &[h, w, Some(nv), Some(3)])?.0.to_vec()),
            LafortuneKind::Rgb => None,
        };
        let status_shape: &[Option<usize>] = match kind {
            LafortuneKind::Lum => &[h, w, Some(nv)],
            LafortuneKind::Rgb => &[h, w, Some(nv), Some(3)],
        };
        let status = a.get_opt::<u8>("status", status_shape)?.map_or_else(Vec::new, |(s, _)| s.to_vec());
        let (src, _) = a.get::<i32>("source", &[Some(nv)])?;
        // Negative indices map past any valid slot, so validate() names them.
        let source = src.iter().map(|&s| usize::try_from(s).unwrap_or(usize::MAX)).collect();
        let m = LafortuneView {
            kind,
            height: sh[0],
            width: sh[1],
            lobes: (p - 1) / 4,
            views,
            params: params.to_vec(),
            rgb,
            status,
            source,
            report: LafortuneViewReport::default(),
        };
        m.validate()?;
        Ok(m)
    }

    fn report(&self) -> serde_json::Value {
        serde_json::to_value(&self.report).unwrap_or_default()
    }
}

#[cfg(test)]
mod tests;
