//! Per-texel Lafortune lobes fitted by Levenberg-Marquardt (paper 000, section 3.2), over all
//! views at once as in McAllister et al.'s spatial BRDF (SBRDF). The per-view form that paper 000
//! itself fits (one lobe set per view slot, blended like the PTM) is [`per_view`]
//! (`"lafortune_view"`), on the same kernels.
//!
//! Each texel's measured values (which include the cos(theta_l) foreshortening) are modelled as
//!
//! ```text
//! value(v, l) = l_z * ( kd + sum_i max(Cx_i lx vx + Cy_i ly vy + Cz_i lz vz, 0)^n_i )
//! ```
//!
//! with directions in the tangent frame. Two variants, as for the PTM (paper 000, section 3.2):
//!
//! * **Lum**: one fit of the luminance (the mean of R, G, B) with 1 to 7 lobes, times a per-texel
//!   base colour, the least-squares modulation of the *measured* luminance,
//!   `base_c = sum lum x_c / sum lum^2` over the present samples (so the base's channel mean is 1
//!   and `rgb = base * lum_model`);
//! * **Rgb**: each channel fitted on its own with 1 to 3 lobes (the paper uses 2: 24 coefficients).
//!
//! The model is not linear in its parameters, so each fit is a small non-linear least-squares
//! problem solved by Levenberg-Marquardt with an analytic Jacobian in f64 (the numerics, and why
//! the exponent is solved for as `ln n`, are in `lafortune/kernels.rs`, the iteration in `lafortune/lm.rs`). The paper reports that this fit is slow and "produces visual artifacts" where the
//! sampling of the hemisphere is sparse or uneven, and interpolates extra images to cure it
//! (section 6). Here that is handled in three ways:
//!
//! * **bounds**: after every step the parameters are projected onto kd >= 0,
//!   `|Cx|, |Cy|, |Cz| <= C_MAX` and `n in [N_MIN, N_MAX]`, so no lobe can blow up between the
//!   samples; a lobe whose cosine is <= 0 contributes 0 and a zero derivative, never a NaN;
//! * **detection and fallback**: each fit records whether LM converged (relative cost decrease below
//!   1e-7, or a negligible step); if not (non-finite cost, no descent, or `max_iter` reached), it is
//!   restarted from the initialisation with strong damping, then with fewer lobes
//!   (`lobes - 1, ..., 1`), and finally replaced by the closed-form diffuse-only fit. The per-fit
//!   status (0 converged, 1 fell back, 2 failed) and a [`FitReport`] say how often each happened;
//! * **extrapolation guard** (`lafortune/guard.rs`): a converged fit is evaluated on the BTF's
//!   whole direction grid (present and missing pairs); one whose lobes there exceed
//!   `K_EXTRAP = 3` times the texel's largest measured value (both without the `l_z`
//!   foreshortening) is rejected as extrapolating, and the fit drops to fewer lobes, then to the
//!   diffuse closed form ([`FitReport::extrapolated`] counts them). Under sparse sampling (5% of
//!   the pairs) LM converges on the samples to lobes that explode between them; without the guard
//!   nothing flagged the held-out error of 10^2 to 10^4 that followed;
//! * **densification** ([`LafortuneOptions::densify`]): an `n x n` equal-area grid of extra view
//!   and light directions whose values are interpolated from the present pairs, added to the
//!   measured samples, which evens out the sampling as the paper suggests.
//!
//! Each fit is started from a linear least-squares fit over fixed candidate lobes (specular,
//! retro-reflective and normal-centred shapes at a few exponents, evaluated once for all texels),
//! chosen greedily; a candidate's amplitude `A` goes into its coefficients as `A^(1/n)`.
//!
//! The fit works on each target divided by its RMS, so that tolerances, damping and [`C_MAX`] do not
//! depend on the data's units; the stored coefficients are scaled back (`kd * rms`,
//! `C * rms^(1/n)`).
//!
//! An all-black texel (or channel) has nothing to fit: its parameters are all zero (exponents 1),
//! with status "converged". Unused lobes of a fit that fell back to fewer lobes are zero, exponent 1.

mod guard;
mod init;
mod kernels;
mod lm;
pub mod per_view;

use crate::gpu::{words, GpuLayout, Shader};
use crate::model::{Bench, Model, ReflectanceModel, Sampling, Setting};
use crate::options::Spec;
use btfrs_core::btf::TexelScan;
use btfrs_core::{directions, BtfRef, Error, Monitor, NamedArrays, Result};
use init::Basis;
use kernels::{Geometry, Layout, Work, MAXM};
use rayon::prelude::*;
use std::borrow::Cow;

/// Smallest lobe exponent: below 1 a lobe is no longer differentiable where its cosine reaches 0
/// and behaves like a step, which the sparse samples cannot pin down.
pub const N_MIN: f64 = 1.0;
/// Largest lobe exponent: 200 is a lobe of about 5 degrees half-width at half maximum, already
/// narrower than the 15-degree UBO sampling can resolve; higher values only let LM chase a single
/// sample.
pub const N_MAX: f64 = 200.0;
/// Bound on each lobe coefficient during the fit, in units of the fitted target's RMS (see the
/// module docs): a linear lobe (n = 1) with |C| = 1000 already peaks at a thousand times the
/// texel's RMS value, so the bound never binds on a lobe the data supports; it only keeps a
/// runaway lobe finite.
pub const C_MAX: f64 = 1e3;
/// Most lobes of the luminance model (7 fit a single rendering pass in paper 000).
pub const MAX_LOBES_LUM: usize = 7;
/// Most lobes per channel of the RGB model.
pub const MAX_LOBES_RGB: usize = 3;
/// Largest densification grid side (it adds `densify^4` samples per fit).
pub const MAX_DENSIFY: usize = 32;
/// Initial damping of a first LM run, relative to the diagonal of `J^T J`. The linear
/// initialisation is far from the optimum and undamped Gauss-Newton steps from it mostly overshoot;
/// on the built-in materials 1e-1 took a few steps less than 1e-3 (and 1e-2, 1) for 2 lobes.
const LAMBDA0: f64 = 1e-1;
/// Initial damping of the restart after a run that did not converge: short, gradient-like steps.
const LAMBDA_RESTART: f64 = 10.0;
/// A first run starts on every `SUB`-th sample only (coarse to fine). The approach from the linear
/// initialisation is most of a run's steps (its first trials overshoot and the damping then comes
/// down by at most 3x per step) and needs no more than the general shape of the data; on the
/// bench's 64 knit texels every 4th sample cut the all-sample steps from 22.5 to 10.8 per fit
/// for 17 quarter-cost ones, and the final cost came out 1e-4 lower (other local minima).
const SUB: usize = 4;
/// The coarse start is used only with at least this many samples in it (4 per parameter of the
/// largest fit and then some), so that it is well determined.
const SUB_MIN: usize = 256;
/// Relative-decrease tolerance of the coarse run: it only has to get near the minimum.
const SUB_TOL: f64 = 1e-5;
/// Initial damping of the all-sample run that follows a converged coarse one (close to the
/// minimum: near Newton steps).
const LAMBDA_FINE: f64 = 1e-1;

/// Which Lafortune variant.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LafortuneKind {
    /// One set of lobes per colour channel.
    Rgb,
    /// One set of lobes for the luminance times a per-texel base colour.
    Lum,
}

/// Fit options.
#[derive(Debug, Clone, Copy, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LafortuneOptions {
    /// The variant.
    pub kind: LafortuneKind,
    /// Lobes per fit: 1 to 7 for `Lum`, 1 to 3 (per channel) for `Rgb`.
    pub lobes: usize,
    /// Fit the diffuse term kd; without it kd is fixed at 0.
    pub diffuse: bool,
    /// Most LM steps per run (>= 1).
    pub max_iter: usize,
    /// 0 = off; else `n` in 1..=32: add an `n x n` equal-area grid of extra view and light
    /// directions (all `n^4` pairs), values interpolated from present pairs.
    pub densify: usize,
}

impl Default for LafortuneOptions {
    /// The defaults of [`Lafortune`]'s option schema.
    fn default() -> Self {
        crate::options::defaults(<Lafortune as Model>::OPTIONS)
    }
}

/// How the fits went, counted over all fits (one per texel for `Lum`, three for `Rgb`).
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct FitReport {
    /// Number of fits.
    pub fits: usize,
    /// Fits whose first LM run converged (black texels included).
    pub converged: usize,
    /// Fits that converged only after a damped restart or with fewer lobes.
    pub fell_back: usize,
    /// Fits replaced by a closed-form fit (see [`Lafortune::status`]).
    pub failed: usize,
    /// Fits whose converged lobes extrapolated (exceeded `K_EXTRAP` times the texel's largest
    /// measured value somewhere on the direction grid) and were replaced by fewer lobes or the
    /// diffuse fit; they are also counted in `fell_back` or `failed`.
    pub extrapolated: usize,
    /// Mean LM steps (trial steps, accepted or rejected) per fit, all runs of a fit summed.
    pub mean_iterations: f64,
    /// RMS of the final residuals of all fits over all their samples (measured and densified), in
    /// the data's units (`Lum`: of the luminance).
    pub rms_residual: f64,
}

/// A fitted per-texel Lafortune model.
#[derive(Debug, Clone)]
pub struct Lafortune {
    /// The variant.
    pub kind: LafortuneKind,
    /// Rows.
    pub height: usize,
    /// Columns.
    pub width: usize,
    /// Lobes per fit.
    pub lobes: usize,
    /// per texel: Lum: `[H, W, P]`; Rgb: `[H, W, 3, P]`; `P = 1 + 4 * lobes`, order
    /// `[kd, (Cx, Cy, Cz, n) per lobe]`.
    pub params: Vec<f32>,
    /// Lum only: `[H, W, 3]` base colour.
    pub rgb: Option<Vec<f32>>,
    /// per texel (Rgb: per texel and channel, `[H, W, 3]`) status: 0 converged (black texels
    /// included), 1 fell back (converged after the damped restart or with fewer lobes), 2 failed
    /// (the closed-form diffuse-only fit; without `diffuse`, the best single candidate lobe of the
    /// initialisation; all zeros where the data were not finite). May be empty for a model loaded
    /// without it.
    pub status: Vec<u8>,
    /// The fit's summary (`FitReport::default()` for a loaded model).
    pub report: FitReport,
}

/// Fit a Lafortune model to the present (view, light) pairs of `btf`; `monitor` counts texels.
pub fn fit_lafortune(btf: &BtfRef<'_>, opts: &LafortuneOptions, monitor: &Monitor) -> Result<Lafortune> {
    let max_lobes = match opts.kind {
        LafortuneKind::Lum => MAX_LOBES_LUM,
        LafortuneKind::Rgb => MAX_LOBES_RGB,
    };
    if !(1..=max_lobes).contains(&opts.lobes) {
        return Err(Error::arg(
            "lobes",
            format!("expected 1 to {max_lobes} lobes for the {:?} model, got {}", opts.kind, opts.lobes),
        ));
    }
    if opts.max_iter == 0 {
        return Err(Error::arg("max_iter", "expected at least 1 iteration, got 0"));
    }
    if opts.densify > MAX_DENSIFY {
        return Err(Error::arg(
            "densify",
            format!("expected 0 (off) to {MAX_DENSIFY} grid directions per side, got {}", opts.densify),
        ));
    }
    let lay = Layout { diffuse: opts.diffuse, lobes: opts.lobes };
    let pairs = btf.pairs();
    if pairs < lay.m() {
        return Err(Error::Degenerate(format!(
            "the BTF has {pairs} present (view, light) pairs but a {}-lobe Lafortune fit has {} parameters per \
             texel{}; use fewer lobes or more directions",
            opts.lobes,
            lay.m(),
            if opts.kind == LafortuneKind::Rgb { " and channel" } else { "" },
        )));
    }
    let ctx = Context::new(btf, opts, lay);
    monitor.check()?;

    let (h, w) = (btf.height, btf.width);
    let nt = h * w;
    let pp = 1 + 4 * opts.lobes;
    let nf = match opts.kind {
        LafortuneKind::Lum => 1,
        LafortuneKind::Rgb => 3,
    };
    let mut params = vec![0.0f32; nt * nf * pp];
    let mut base = vec![0.0f32; nt * 3];
    let mut status = vec![0u8; nt * nf];
    let mut sse = vec![0.0f64; nt * nf];
    let mut iters = vec![0u32; nt * nf];
    let mut extrap = vec![false; nt * nf];
    monitor.start(nt as u64);
    let scan = TexelScan::new();
    params
        .par_chunks_mut(nf * pp)
        .zip(base.par_chunks_mut(3))
        .zip(status.par_chunks_mut(nf))
        .zip(sse.par_chunks_mut(nf))
        .zip(iters.par_chunks_mut(nf))
        .zip(extrap.par_chunks_mut(nf))
        .enumerate()
        .for_each_init(
            || Work::new(ctx.geo.npad(), opts.lobes),
            |work, (t, (((((p, rgb), st), e), it), ex))| {
                if monitor.is_cancelled() || scan.failed() {
                    return;
                }
                let texel = btf.texel(t);
                if !scan.check(texel) {
                    return;
                }
                match opts.kind {
                    LafortuneKind::Lum => {
                        ctx.gather(texel, None, &mut work.y);
                        base_colour(texel, &ctx.meas, rgb);
                        let r = ctx.fit(work);
                        ex[0] = r.extrapolated;
                        r.write(p, &mut st[0], &mut e[0], &mut it[0]);
                    }
                    LafortuneKind::Rgb => {
                        for c in 0..3 {
                            ctx.gather(texel, Some(c), &mut work.y);
                            let r = ctx.fit(work);
                            ex[c] = r.extrapolated;
                            r.write(&mut p[c * pp..(c + 1) * pp], &mut st[c], &mut e[c], &mut it[c]);
                        }
                    }
                }
                monitor.advance(1);
            },
        );
    monitor.check()?;
    scan.finish("data", btf.data)?;

    let fits = nt * nf;
    let count = |s: u8| status.iter().filter(|&&x| x == s).count();
    let total_sse: f64 = sse.iter().sum();
    let report = FitReport {
        fits,
        converged: count(0),
        fell_back: count(1),
        failed: count(2),
        extrapolated: extrap.iter().filter(|&&x| x).count(),
        mean_iterations: iters.iter().map(|&x| x as f64).sum::<f64>() / fits as f64,
        rms_residual: (total_sse / (fits * ctx.geo.n) as f64).sqrt(),
    };
    Ok(Lafortune {
        kind: opts.kind,
        height: h,
        width: w,
        lobes: opts.lobes,
        params,
        rgb: (opts.kind == LafortuneKind::Lum).then_some(base),
        status,
        report,
    })
}

/// The least-squares modulation of the measured luminance, `base_c = sum lum x_c / sum lum^2`
/// over the present samples; 0 for a black texel.
fn base_colour(texel: &[f32], meas: &[usize], out: &mut [f32]) {
    let (mut num, mut den) = ([0.0f64; 3], 0.0f64);
    for &i in meas {
        let x = &texel[3 * i..3 * i + 3];
        let lum = (x[0] as f64 + x[1] as f64 + x[2] as f64) / 3.0;
        for c in 0..3 {
            num[c] += lum * x[c] as f64;
        }
        den += lum * lum;
    }
    for c in 0..3 {
        let b = if den > 0.0 { (num[c] / den) as f32 } else { 0.0 };
        out[c] = if b.is_finite() { b } else { 0.0 };
    }
}

/// Densified samples: for each, the present pairs (flat `v * L + l` indices) and weights that
/// interpolate its value, in compressed rows.
#[derive(Debug, Clone, Default)]
struct Interp {
    start: Vec<usize>,
    idx: Vec<usize>,
    w: Vec<f64>,
}

/// Everything shared by all texels' fits.
#[derive(Debug)]
struct Context {
    /// Flat pair indices (`v * L + l`) of the present pairs, in sample order.
    meas: Vec<usize>,
    /// Interpolation of the densified samples, which follow the measured ones.
    extra: Interp,
    geo: Geometry,
    /// The check pairs of the extrapolation guard.
    guard: guard::Guard,
    basis: Basis,
    lay: Layout,
    max_iter: usize,
    /// Every [`SUB`]-th sample (measured and densified), for the coarse start of a first run.
    geo_sub: Geometry,
    /// Their indices among the samples.
    sub_idx: Vec<usize>,
}

impl Context {
    fn new(btf: &BtfRef<'_>, opts: &LafortuneOptions, lay: Layout) -> Self {
        let (nv, nl) = (btf.views.len(), btf.lights.len());
        let meas: Vec<usize> = (0..nv * nl).filter(|&i| btf.has(i / nl, i % nl)).collect();
        let mut dirs: Vec<([f64; 3], [f64; 3])> =
            meas.iter().map(|&i| (btf.views[i / nl], btf.lights[i % nl])).collect();
        let mut extra = Interp::default();
        if opts.densify > 0 {
            let n = opts.densify;
            let grid: Vec<[f64; 3]> = (0..n * n)
                .map(|k| {
                    let (i, j) = (k / n, k % n);
                    btfrs_hemimap::square_to_hemisphere((i as f64 + 0.5) / n as f64, (j as f64 + 0.5) / n as f64)
                })
                .collect();
            let weights: Vec<Vec<(usize, usize, f64)>> = (0..grid.len() * grid.len())
                .into_par_iter()
                .map(|k| {
                    let (v, l) = (grid[k / grid.len()], grid[k % grid.len()]);
                    directions::present_pair_weights(btf.views, btf.lights, btf.mask, v, l)
                })
                .collect();
            extra.start.push(0);
            for (k, ws) in weights.iter().enumerate() {
                for &(v, l, x) in ws {
                    extra.idx.push(v * nl + l);
                    extra.w.push(x);
                }
                extra.start.push(extra.idx.len());
                dirs.push((grid[k / grid.len()], grid[k % grid.len()]));
            }
        }
        let sub_idx: Vec<usize> = (0..dirs.len()).step_by(SUB).collect();
        let geo_sub = Geometry::new(sub_idx.iter().map(|&i| dirs[i]));
        let geo = Geometry::new(dirs.into_iter());
        let basis = Basis::new(&geo);
        let guard = guard::Guard::new(btf.views, btf.lights);
        Context { meas, extra, geo, guard, basis, lay, max_iter: opts.max_iter, geo_sub, sub_idx }
    }

    /// The fit's targets into `y` (padded with zeros): the luminance (`channel = None`) or one
    /// channel, at the measured samples and interpolated at the densified ones.
    fn gather(&self, texel: &[f32], channel: Option<usize>, y: &mut [f64]) {
        let val = |i: usize| match channel {
            Some(c) => texel[3 * i + c] as f64,
            None => (texel[3 * i] as f64 + texel[3 * i + 1] as f64 + texel[3 * i + 2] as f64) / 3.0,
        };
        let nm = self.meas.len();
        for (o, &i) in y.iter_mut().zip(&self.meas) {
            *o = val(i);
        }
        for (k, o) in y[nm..self.geo.n].iter_mut().enumerate() {
            let (s, e) = (self.extra.start[k], self.extra.start[k + 1]);
            *o = self.extra.idx[s..e].iter().zip(&self.extra.w[s..e]).map(|(&i, &w)| w * val(i)).sum();
        }
    }

    /// One fit of the targets in `w.y`, with the fallback chain of the module docs.
    fn fit(&self, w: &mut Work) -> FitOut {
        let n = self.geo.n;
        let lay = self.lay;
        let yy: f64 = w.y[..n].iter().map(|v| v * v).sum();
        if yy == 0.0 {
            return FitOut::zero(0);
        }
        if !yy.is_finite() {
            return FitOut::zero(2);
        }
        let scale = (yy / n as f64).sqrt();
        w.y[..n].iter_mut().for_each(|v| *v /= scale);
        let fty = self.basis.fty(&w.y);
        let guesses = init::initial_guesses(&self.basis, &fty, lay.diffuse, lay.lobes);
        // The guard's reference: the largest measured value without the foreshortening (the
        // lobe sum is compared with it; samples with the light at the horizon carry no BRDF).
        let fmax = (0..n).filter(|&i| self.geo.lz[i] > 1e-3).map(|i| w.y[i] / self.geo.lz[i]).fold(0.0f64, f64::max);
        let mut iters = 0usize;
        let mut extrapolated = false;
        let mut attempts: Vec<(Layout, f64)> = vec![(lay, LAMBDA0), (lay, LAMBDA_RESTART)];
        attempts.extend((1..lay.lobes).rev().map(|l| (Layout { lobes: l, ..lay }, LAMBDA0)));
        // Once a fit with `l` lobes extrapolated, a restart with as many lobes converges to the
        // same runaway lobes: only fewer lobes are tried.
        let mut below = usize::MAX;
        for (a, &(la, lambda0)) in attempts.iter().enumerate() {
            if la.lobes >= below {
                continue;
            }
            let mut th = guesses[la.lobes - 1];
            let mut lambda0 = lambda0;
            if a == 0 && self.geo_sub.n >= SUB_MIN {
                // Coarse to fine: the approach from the initialisation on every SUB-th sample
                // (a quarter of the cost per step), then LM on all samples from there.
                let ws = w.sub.get_or_insert_with(|| Box::new(Work::new(self.geo_sub.npad(), self.lay.lobes)));
                for (o, &i) in ws.y.iter_mut().zip(&self.sub_idx) {
                    *o = w.y[i];
                }
                let mut ts = th;
                let r =
                    lm::levenberg_marquardt_tol(&self.geo_sub, la, &mut ts, lambda0, self.max_iter, ws, SUB_TOL, true);
                iters += r.iters;
                if r.converged && r.cost.is_finite() {
                    th = ts;
                    lambda0 = LAMBDA_FINE;
                }
            }
            // The first run takes Newton steps; the restarts are this fit's earlier algorithm
            // (Gauss-Newton on all samples from the initialisation), so a texel where the faster
            // path fails still gets every chance the fit ever gave it.
            let tol = lm::REL_DECREASE;
            let run = lm::levenberg_marquardt_tol(&self.geo, la, &mut th, lambda0, self.max_iter, w, tol, a == 0);
            iters += run.iters;
            if run.converged && run.cost.is_finite() {
                if fmax > 0.0 && self.guard.extrapolates(la, &th, fmax) {
                    extrapolated = true;
                    below = la.lobes;
                    continue;
                }
                let mut out = FitOut::new(la, &th, scale, run.cost, u8::from(a > 0 || extrapolated), iters);
                out.extrapolated = extrapolated;
                return out;
            }
        }
        // Failed: the closed-form fit with kd alone, or without kd the best single candidate lobe.
        if lay.diffuse {
            let g0 = self.basis.gram[0][0];
            let kd = if g0 > 0.0 { (fty[0] / g0).max(0.0) } else { 0.0 };
            let cost = (n as f64 - 2.0 * kd * fty[0] + kd * kd * g0).max(0.0);
            let mut th = [0.0f64; MAXM];
            th[0] = kd;
            let mut out = FitOut::new(Layout { lobes: 0, ..lay }, &th, scale, cost, 2, iters);
            out.extrapolated = extrapolated;
            out
        } else {
            let la = Layout { lobes: 1, ..lay };
            let mut th = guesses[0];
            lm::project(la, &mut th);
            let cost = kernels::cost(&self.geo, la, &th, w);
            let mut out = FitOut::new(la, &th, scale, cost, 2, iters);
            out.extrapolated = extrapolated;
            out
        }
    }
}

/// One fit's result in data units, laid out `[kd, (Cx, Cy, Cz, n) x lobes]`.
#[derive(Debug, Clone, Copy)]
struct FitOut {
    p: [f64; MAXM],
    status: u8,
    sse: f64,
    iters: usize,
    /// A fit with more lobes extrapolated and was rejected (see `lafortune/guard.rs`).
    extrapolated: bool,
}

impl FitOut {
    /// All zero (exponents 1).
    fn zero(status: u8) -> Self {
        let mut p = [0.0f64; MAXM];
        for k in 0..kernels::MAX_LOBES {
            p[4 + 4 * k] = 1.0;
        }
        FitOut { p, status, sse: 0.0, iters: 0, extrapolated: false }
    }

    /// From a normalised theta of layout `la` (possibly fewer lobes than the model; exponents as
    /// `ln n`).
    fn new(la: Layout, th: &[f64], scale: f64, cost: f64, status: u8, iters: usize) -> Self {
        let mut out = FitOut::zero(status);
        out.p[0] = la.kd(th) * scale;
        for k in 0..la.lobes {
            let q = &th[la.off() + 4 * k..la.off() + 4 * k + 4];
            let n = q[3].exp().clamp(N_MIN, N_MAX);
            let f = scale.powf(1.0 / n);
            out.p[1 + 4 * k..4 + 4 * k].copy_from_slice(&[q[0] * f, q[1] * f, q[2] * f]);
            out.p[4 + 4 * k] = n;
        }
        out.sse = cost * scale * scale;
        out.iters = iters;
        out
    }

    /// Store into the model's arrays; a result that does not fit in f32 (data near f32's range)
    /// is replaced by zeros and reported failed, so no NaN or infinity ever reaches `params`.
    fn write(&self, p: &mut [f32], st: &mut u8, sse: &mut f64, it: &mut u32) {
        let ok = p.iter_mut().zip(&self.p).fold(true, |ok, (o, &x)| {
            *o = x as f32;
            ok && o.is_finite()
        });
        *st = self.status;
        *sse = if self.sse.is_finite() { self.sse } else { 0.0 };
        *it = self.iters.min(u32::MAX as usize) as u32;
        if !ok {
            let z = FitOut::zero(2);
            p.iter_mut().zip(&z.p).for_each(|(o, &x)| *o = x as f32);
            *st = 2;
        }
    }
}

impl Lafortune {
    /// Values per fit: `1 + 4 * lobes`.
    pub fn params_per_fit(&self) -> usize {
        1 + 4 * self.lobes
    }

    /// Fits per texel (1 for Lum, 3 for Rgb).
    fn fits_per_texel(&self) -> usize {
        match self.kind {
            LafortuneKind::Lum => 1,
            LafortuneKind::Rgb => 3,
        }
    }

    /// Check array lengths, finiteness and the exponent bounds (for models built from loaded files).
    pub fn validate(&self) -> Result<()> {
        if self.height == 0 || self.width == 0 {
            return Err(Error::arg("params", "the Lafortune model has no texels"));
        }
        let max_lobes = match self.kind {
            LafortuneKind::Lum => MAX_LOBES_LUM,
            LafortuneKind::Rgb => MAX_LOBES_RGB,
        };
        if !(1..=max_lobes).contains(&self.lobes) {
            return Err(Error::arg("lobes", format!("expected 1 to {max_lobes} lobes, got {}", self.lobes)));
        }
        let fits = self.height * self.width * self.fits_per_texel();
        let pp = self.params_per_fit();
        if self.params.len() != fits * pp {
            return Err(Error::arg("params", format!("expected {} values, got {}", fits * pp, self.params.len())));
        }
        if let Some(i) = self.params.iter().position(|x| !x.is_finite()) {
            return Err(Error::arg("params", format!("value {} at flat index {i} is not finite", self.params[i])));
        }
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
            (Some(r), LafortuneKind::Lum) if r.len() == self.height * self.width * 3 => {
                if let Some(i) = r.iter().position(|x| !x.is_finite()) {
                    return Err(Error::arg("rgb", format!("value {} at flat index {i} is not finite", r[i])));
                }
            }
            (None, LafortuneKind::Rgb) => {}
            _ => return Err(Error::arg("rgb", "expected a [H, W, 3] base colour for Lum and none for Rgb")),
        }
        if !(self.status.is_empty() || self.status.len() == fits) {
            return Err(Error::arg("status", format!("expected {fits} entries (or none), got {}", self.status.len())));
        }
        if let Some(s) = self.status.iter().find(|&&s| s > 2) {
            return Err(Error::arg("status", format!("expected 0, 1 or 2, got {s}")));
        }
        Ok(())
    }

    /// The lobe sum of one fit's parameters `p` at a query, `lz (kd + sum max(s, 0)^n)`.
    #[inline]
    fn lobe_sum(&self, p: &[f32], q: &LafortuneQuery) -> f32 {
        let mut v = p[0];
        for k in 0..self.lobes {
            let c = &p[1 + 4 * k..5 + 4 * k];
            let s = c[0] * q.a + c[1] * q.b + c[2] * q.c;
            if s > 0.0 {
                v += s.powf(c[3]);
            }
        }
        q.lz * v
    }
}

/// A prepared Lafortune query: the light's foreshortening and the three direction products.
#[derive(Debug, Clone, Copy)]
pub struct LafortuneQuery {
    lz: f32,
    a: f32,
    b: f32,
    c: f32,
}

impl ReflectanceModel for Lafortune {
    type Query = LafortuneQuery;

    fn dims(&self) -> (usize, usize) {
        (self.height, self.width)
    }

    fn query(&self, view: [f64; 3], light: [f64; 3]) -> LafortuneQuery {
        LafortuneQuery {
            // As in the fit: no light arrives from at or below the horizon.
            lz: light[2].max(0.0) as f32,
            a: (light[0] * view[0]) as f32,
            b: (light[1] * view[1]) as f32,
            c: (light[2] * view[2]) as f32,
        }
    }

    #[inline]
    fn eval(&self, t: usize, q: &LafortuneQuery) -> [f32; 3] {
        let pp = self.params_per_fit();
        match self.kind {
            LafortuneKind::Lum => {
                let lum = self.lobe_sum(&self.params[t * pp..(t + 1) * pp], q);
                match &self.rgb {
                    Some(base) => [base[3 * t] * lum, base[3 * t + 1] * lum, base[3 * t + 2] * lum],
                    None => [lum; 3],
                }
            }
            LafortuneKind::Rgb => {
                std::array::from_fn(|c| self.lobe_sum(&self.params[(3 * t + c) * pp..(3 * t + c + 1) * pp], q))
            }
        }
    }
}

crate::gpu_params! {
    /// Parameters of `lafortune.wgsl`.
    pub struct LafortuneParams {
        /// 0 = RGB (one parameter set per channel), 1 = luminance times a base colour.
        pub kind: u32,
        /// Lobes per fit.
        pub lobes: u32,
        /// Store offset of the parameters: `[texel][P]` (lum) or `[texel][3][P]` (rgb) f32,
        /// `P = 1 + 4 * lobes`, ordered kd, (Cx, Cy, Cz, n) per lobe.
        pub params: u32,
        /// Store offset of the base colours `[texel][3]` f32 (luminance kind only).
        pub rgb: u32,
    }
}

impl GpuLayout for Lafortune {
    type Params = LafortuneParams;
    const SHADER: Shader =
        Shader::new::<LafortuneParams>("lafortune", include_str!("../../../shaders_wgsl/lafortune.wgsl"));

    fn parts(&self) -> Vec<Cow<'_, [u32]>> {
        let mut p = vec![words(&self.params)];
        if let Some(rgb) = &self.rgb {
            p.push(words(rgb));
        }
        p
    }

    fn params(&self, offsets: &[u32], _tables: &[u32]) -> LafortuneParams {
        LafortuneParams {
            kind: match self.kind {
                LafortuneKind::Rgb => 0,
                LafortuneKind::Lum => 1,
            },
            lobes: self.lobes as u32,
            params: offsets[0],
            rgb: offsets.get(1).copied().unwrap_or(0),
        }
    }
}

impl Model for Lafortune {
    const KIND: &'static str = "lafortune";
    const TEXEL_ARRAYS: &'static [&'static str] = &["params", "rgb", "status"];
    const DOC: &'static str = "per-texel Lafortune lobes by Levenberg-Marquardt (paper 000, section 3.2)";
    const ABOUT: &'static str = "\
One Levenberg-Marquardt fit per texel over all its present (view, light) samples, with analytic
Jacobians and bounds that keep the lobes physical: `kind=\"lum\"` fits 1 to 7 lobes to the
luminance times a base colour, `kind=\"rgb\"` 1 to 3 lobes per channel. Paper 000 reports LM
artifacts under sparse or uneven sampling: fits that diverge get a damped restart, then fewer
lobes, then the diffuse-only closed form; `model.report` counts converged, fell-back and failed
fits and `model.arrays[\"status\"]` flags each texel. `densify=n` adds an `n x n` equal-area grid
of view and light directions whose values are interpolated from the present pairs before
fitting (the paper's remedy).";
    const OPTIONS: &'static [Spec] = &[
        Spec::choice(
            "kind",
            "lum",
            &["lum", "rgb"],
            "\"lum\": lobes on the luminance times a base colour; \"rgb\": lobes per channel",
        ),
        Spec::int("lobes", 2, 1, Some(MAX_LOBES_LUM as i64), "lobes per fit: 1 to 7 for \"lum\", 1 to 3 for \"rgb\""),
        Spec::bool("diffuse", true, "fit the diffuse term kd (false: kd = 0)"),
        Spec::int("max_iter", 60, 1, None, "most Levenberg-Marquardt steps per run"),
        Spec::int(
            "densify",
            0,
            0,
            Some(MAX_DENSIFY as i64),
            "0: off; n: add an n x n equal-area grid of interpolated view and light directions",
        ),
    ];
    const EXAMPLES: &'static [(&'static str, &'static str)] = &[
        ("Lafortune-Lum 1", r#"{"kind": "lum", "lobes": 1}"#),
        ("Lafortune-Lum 2", r#"{"kind": "lum", "lobes": 2}"#),
        ("Lafortune-RGB 2", r#"{"kind": "rgb", "lobes": 2}"#),
    ];
    // Ten Levenberg-Marquardt steps run every stage of the fit (the start, the steps, the
    // fallbacks) at a sixth of the default's cost.
    const SMALLEST: &'static str = r#"{"kind": "lum", "lobes": 1, "max_iter": 10}"#;
    const BENCH: &'static [Bench] = &[
        Bench::new("Lafortune-Lum 2", r#"{"kind": "lum", "lobes": 2}"#, &["per_material", "models"])
            .peer("lafortune_scipy"),
        Bench::new("Lafortune-Lum 3", r#"{"kind": "lum", "lobes": 3}"#, &["models"]),
        Bench::new("", "{}", &["no_single_view"])
            .note("its lobes span the views; on one view it is the per-view model"),
    ];
    const SWEEP: &'static [Setting] = &[
        Setting::full("Lafortune-Lum 1", r#"{"kind": "lum", "lobes": 1}"#),
        Setting::quick("Lafortune-Lum 2", r#"{"kind": "lum", "lobes": 2}"#),
        Setting::full("Lafortune-Lum 3", r#"{"kind": "lum", "lobes": 3}"#),
        Setting::full("Lafortune-Lum 4", r#"{"kind": "lum", "lobes": 4}"#),
        Setting::full("Lafortune-RGB 1", r#"{"kind": "rgb", "lobes": 1}"#),
        Setting::full("Lafortune-RGB 2", r#"{"kind": "rgb", "lobes": 2}"#),
    ];
    const SAMPLING: Sampling =
        Sampling::Any { note: "over all pairs", one_view: "one view: the lobes see no view dependence" };
    type Options = LafortuneOptions;
    // Each texel's values are checked as the per-texel pass reads them (TexelScan).
    const SCANS_VALUES: bool = true;

    // One Levenberg-Marquardt fit per texel (per texel and view slot), nothing shared.
    const BLOCKWISE: crate::blockwise::Blockwise = crate::blockwise::Blockwise::Texels {
        overrides: "{}",
        counts: &["converged", "extrapolated", "failed", "fell_back", "fits"],
    };

    fn fit(btf: &BtfRef<'_>, options: &LafortuneOptions, monitor: &Monitor) -> Result<Self> {
        fit_lafortune(btf, options, monitor)
    }

    /// `params` (lum `[H, W, P]`, rgb `[H, W, 3, P]` f32, `P = 1 + 4 * lobes`), for lum `rgb`
    /// `[H, W, 3]`, and `status` u8 (`[H, W]` or `[H, W, 3]`) when the fit recorded it.
    fn to_arrays(&self) -> NamedArrays {
        let mut a = NamedArrays::new();
        let (h, w, p) = (self.height, self.width, self.params_per_fit());
        match self.kind {
            LafortuneKind::Lum => a.put("params", &[h, w, p], self.params.clone()),
            LafortuneKind::Rgb => a.put("params", &[h, w, 3, p], self.params.clone()),
        }
        if let Some(rgb) = &self.rgb {
            a.put("rgb", &[h, w, 3], rgb.clone());
        }
        if !self.status.is_empty() {
            match self.kind {
                LafortuneKind::Lum => a.put("status", &[h, w], self.status.clone()),
                LafortuneKind::Rgb => a.put("status", &[h, w, 3], self.status.clone()),
            }
        }
        a
    }

    fn from_arrays(a: &NamedArrays) -> Result<Self> {
        let (params, sh) = match a.get::<f32>("params", &[None, None, None]) {
            Ok(x) => x,
            Err(_) => a
                .get::<f32>("params", &[None, None, Some(3), None])
                .map_err(|_| Error::arg("params", "expected shape [H, W, P] (lum) or [H, W, 3, P] (rgb) of float32"))?,
        };
        let kind = if sh.len() == 3 { LafortuneKind::Lum } else { LafortuneKind::Rgb };
        let p = sh[sh.len() - 1];
        if p < 5 || (p - 1) % 4 != 0 {
            return Err(Error::arg("params", format!("expected 1 + 4 * lobes values per fit, got {p}")));
        }
        let (h, w) = (Some(sh[0]), Some(sh[1]));
        let rgb = match kind {
            LafortuneKind::Lum => Some(a.get::<f32>("rgb", &[h, w, Some(3)])?.0.to_vec()),
            LafortuneKind::Rgb => None,
        };
        let status_shape: &[Option<usize>] = match kind {
            LafortuneKind::Lum => &[h, w],
            LafortuneKind::Rgb => &[h, w, Some(3)],
        };
        let status = a.get_opt::<u8>("status", status_shape)?.map_or_else(Vec::new, |(s, _)| s.to_vec());
        let m = Lafortune {
            kind,
            height: sh[0],
            width: sh[1],
            lobes: (p - 1) / 4,
            params: params.to_vec(),
            rgb,
            status,
            report: FitReport::default(),
        };
        m.validate()?;
        Ok(m)
    }

    fn report(&self) -> serde_json::Value {
        serde_json::to_value(self.report).unwrap_or_default()
    }
}

#[cfg(test)]
mod tests;
