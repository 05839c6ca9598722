//! Radial-basis-function light bases (the RTI "RBF" of relight, Ponchio et al.), fitted per view
//! slot: for a fixed view, each texel's values under the slot's measured lights are interpolated
//! by Gaussian radial basis functions
//!
//! ```text
//! f(l) = mu + sum_j a_j exp(-|l - l_j|^2 / (2 sigma^2)),   (K + lambda I) a = y - mu 1
//! ```
//!
//! (`mu` the mean of the samples, so that far from every light the interpolant returns to it;
//! `K` the kernel matrix of the lights; `lambda` the `regularization`, relative to the kernel's
//! unit diagonal). The kernel width `sigma` is `width` times the light spacing [`light_spacing`]
//! (the side of the patch of the lights' cap each light owns). The interpolant is
//! resampled on the grid of [`crate::light_pca`] (option `resolution`), whose PCA over all
//! texels gives `components` 8-bit coefficient planes and a float table of principal functions.
//! The operator `y -> f(grid)` depends on the lights only, so it is computed once per slot.
//!
//! Degenerate slots: a view slot of a multi-view BTF with fewer than
//! [`crate::light_pca::MIN_LIGHTS`] present lights borrows the lights of the nearest views
//! (`report["pooled_slots"]`, [`crate::light_pca::PooledSlot`]); one light (or all lights at
//! one direction) gives the constant `mu`; a BTF without any light is an error; `regularization = 0`
//! with duplicate lights (a singular kernel matrix) is an error asking for a positive one.

use crate::light_pca::{self, Colour, LightPca, PcaOptions};
use crate::model::{average_texels, Bench, Mip, Model, Sampling};
use crate::options::Spec;
use btfrs_core::{ensure_arg, BtfRef, Error, Monitor, NamedArrays, Result};
use nalgebra::DMatrix;

/// Fit options.
#[derive(Debug, Clone, Copy, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RbfOptions {
    /// Coefficient planes per slot (rgb), or luminance planes (ycc).
    pub components: usize,
    /// `"rgb"` (joint PCA of the three channels) or `"ycc"` (luminance and chroma apart).
    pub colour: Colour,
    /// Chroma planes for `colour = "ycc"` (default `max(1, components / 4)`).
    pub chroma_components: Option<usize>,
    /// Light grid nodes per side (2 to 32).
    pub resolution: usize,
    /// Kernel width in units of the light spacing (> 0). The default (2.5, with regularization
    /// 0.1) is the best held-out error of RBF-18 on the single-view captures of BENCHMARKS.md
    /// ("Single-view RTI captures"): narrower kernels dip towards the mean between lights.
    pub width: f64,
    /// Ridge added to the kernel matrix's unit diagonal (>= 0).
    pub regularization: f64,
    /// Seed of the randomized PCA (used for long vectors only).
    pub seed: u64,
}

impl Default for RbfOptions {
    /// The defaults of [`Rbf`]'s option schema.
    fn default() -> Self {
        crate::options::defaults(<Rbf as Model>::OPTIONS)
    }
}

/// A fitted RBF light basis.
#[derive(Debug, Clone, PartialEq)]
pub struct Rbf(pub LightPca);

fn dist2(a: [f64; 3], b: [f64; 3]) -> f64 {
    (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)
}

/// The light spacing: `sqrt(omega / m)` for `m` distinct lights, `omega` the solid angle of the
/// cap around the normal that holds them all (`2 pi (1 - min z)`): the side of the square each
/// light would own on an even sampling of that cap (0 for fewer than two distinct lights).
pub fn light_spacing(lights: &[[f64; 3]]) -> f64 {
    let distinct =
        lights.iter().enumerate().filter(|&(i, a)| lights[..i].iter().all(|b| dist2(*a, *b) > 1e-18)).count();
    if distinct < 2 {
        return 0.0;
    }
    let zmin = lights.iter().map(|l| l[2] / (l[0] * l[0] + l[1] * l[1] + l[2] * l[2]).sqrt()).fold(1.0, f64::min);
    let omega = std::f64::consts::TAU * (1.0 - zmin.clamp(-1.0, 1.0)).max(1e-6);
    (omega / distinct as f64).sqrt()
}

/// The `targets x lights` matrix mapping one channel's samples at `lights` to the RBF
/// interpolant (see the module doc) at `targets`.
pub fn rbf_operator(
    lights: &[[f64; 3]],
    targets: &[[f64; 3]],
    width: f64,
    regularization: f64,
) -> Result<DMatrix<f64>> {
    let m = lights.len();
    ensure_arg!(m > 0, "lights", "expected at least one light");
    let mean = DMatrix::<f64>::from_element(targets.len(), m, 1.0 / m as f64);
    let spacing = light_spacing(lights);
    if m == 1 || spacing == 0.0 {
        return Ok(mean);
    }
    let singular = || {
        Error::Degenerate(format!(
            "rbf: the kernel matrix of {m} lights is singular (duplicate lights?) with regularization {regularization}; \
             use a positive regularization"
        ))
    };
    if regularization == 0.0
        && lights.iter().enumerate().any(|(i, a)| lights[..i].iter().any(|b| dist2(*a, *b) < 1e-18))
    {
        return Err(singular());
    }
    let s2 = 2.0 * (width * spacing).powi(2);
    let k = |a: [f64; 3], b: [f64; 3]| (-dist2(a, b) / s2).exp();
    let a = DMatrix::<f64>::from_fn(m, m, |i, j| k(lights[i], lights[j]) + if i == j { regularization } else { 0.0 });
    let chol = a.cholesky().ok_or_else(singular)?;
    // (I - J / m): subtract the mean before interpolating.
    let centre = DMatrix::<f64>::from_fn(m, m, |i, j| if i == j { 1.0 } else { 0.0 } - 1.0 / m as f64);
    let sol = chol.solve(&centre);
    let kx = DMatrix::<f64>::from_fn(targets.len(), m, |i, j| k(targets[i], lights[j]));
    let w = kx * sol + mean;
    if w.iter().any(|x| !x.is_finite()) {
        return Err(singular());
    }
    Ok(w)
}

/// The light-PCA options of `o`.
fn pca_options(o: &RbfOptions) -> PcaOptions {
    light_pca::pca_options_of!(o)
}

/// The options checked, as the light-PCA options and the resampling operator of one slot.
pub(crate) fn prepare(o: &RbfOptions) -> Result<(PcaOptions, Box<light_pca::Operator<'static>>)> {
    ensure_arg!(o.width.is_finite() && o.width > 0.0, "width", "expected a positive kernel width, got {}", o.width);
    ensure_arg!(
        o.regularization.is_finite() && o.regularization >= 0.0,
        "regularization",
        "expected a finite value >= 0, got {}",
        o.regularization
    );
    let pca = pca_options(o);
    pca.check()?;
    let grid = light_pca::grid_directions(o.resolution);
    let (width, regularization) = (o.width, o.regularization);
    let op = move |lights: &[[f64; 3]], _n: usize| Ok((rbf_operator(lights, &grid, width, regularization)?, None));
    Ok((pca, Box::new(op)))
}

/// Fit an RBF light basis to the present pairs of `btf`; `monitor` counts view slots.
pub fn fit_rbf(btf: &BtfRef<'_>, o: &RbfOptions, monitor: &Monitor) -> Result<Rbf> {
    let (pca, op) = prepare(o)?;
    Ok(Rbf(light_pca::fit(btf, &pca, &*op, "rbf", monitor)?))
}

light_pca::light_pca_model!(Rbf);

impl Model for Rbf {
    const KIND: &'static str = "rbf";
    const EXPORTS: &'static [&'static str] = &["relight"];
    const DOC: &'static str =
        "Gaussian RBF light interpolation per view slot, resampled on a light grid, PCA into 8-bit planes (relight's RBF)";
    const ABOUT: &'static str = "\
relight's RBF light basis (the RTI default of relight) per view slot. Per slot and texel, the
values under the slot's lights are interpolated by Gaussian radial basis functions (`f(l) = mu +
sum_j a_j exp(-|l - l_j|^2 / 2 sigma^2)` with `(K + regularization I) a = y - mu`), `sigma =
width` times the light spacing. The interpolant is resampled on a `resolution x resolution` grid
of the concentric square, and the grid functions of all texels are compressed by PCA into
`components` planes stored 8-bit with a scale and bias per plane, next to a float32 table of the
principal functions (counted in `nbytes`). A light is evaluated by a bilinear lookup of the table
and one dot product per channel; the three nearest view slots are blended, as for the PTM. A slot
of a multi-view BTF with fewer than 6 present lights borrows the nearest views' lights
(`model.report[\"pooled_slots\"]`).";
    const OPTIONS: &'static [Spec] = &[
        Spec::int(
            "components",
            18,
            1,
            Some(light_pca::MAX_COMPONENTS as i64),
            "coefficient planes per slot (\"rgb\"), or luminance planes (\"ycc\")",
        ),
        Spec::choice(
            "colour",
            "rgb",
            &["rgb", "ycc"],
            "\"rgb\": one PCA of the three channels; \"ycc\": luminance and chroma compressed apart",
        ),
        Spec::opt_int(
            "chroma_components",
            0,
            Some(light_pca::MAX_COMPONENTS as i64),
            "chroma planes for \"ycc\" (null: max(1, components // 4))",
        ),
        Spec::int("resolution", 12, 2, Some(light_pca::MAX_RESOLUTION as i64), "light grid nodes per side"),
        Spec::positive("width", 2.5, "kernel width in units of the light spacing"),
        Spec::float(
            "regularization",
            0.1,
            0.0,
            "ridge on the kernel matrix's unit diagonal (0 with duplicate lights is an error)",
        ),
        Spec::seed("seed of the randomized PCA (vectors longer than 768 values) and of the texel sample whose moments give the principal functions (captures above 262144 texels)"),
    ];
    const EXAMPLES: &'static [(&'static str, &'static str)] =
        &[("RBF-9", r#"{"components": 9}"#), ("RBF-18", r#"{"components": 18}"#), ("RBF-27", r#"{"components": 27}"#)];
    const SAMPLING: Sampling = Sampling::PerView { min_lights: 3, why: "18 planes" };
    const TEXEL_ARRAYS: &'static [&'static str] = &["coeffs_q"];
    // The single-view RTI captures: relight's sizes, the other table resolution, the YCC split.
    const BENCH: &'static [Bench] = &[
        Bench::new("RBF-{components}", r#"{"components": [3, 6, 9, 12, 18, 27]}"#, &["single_view"]),
        Bench::new("RBF-{components} r8", r#"{"components": [3, 9, 18], "resolution": 8}"#, &["single_view"]),
        Bench::new("RBF-YCC 9+3", r#"{"components": 9, "colour": "ycc", "chroma_components": 3}"#, &["single_view"]),
        Bench::new("RBF-YCC 12+3", r#"{"components": 12, "colour": "ycc", "chroma_components": 3}"#, &["single_view"]),
        Bench::new("RBF-YCC 18+4", r#"{"components": 18, "colour": "ycc", "chroma_components": 4}"#, &["single_view"]),
        Bench::new("RBF-18", r#"{"components": 18}"#, &["summary", "single_view_reference"])
            .note("relight RBF, 18 planes 24.6% in 85 KB"),
        Bench::new("RBF-9", r#"{"components": 9}"#, &["dask"]),
    ];
    const MIP: Mip = Mip::Average;
    type Options = RbfOptions;
    // Each value checked as the fit reads it (per block of texels; per view slot for the light bases).
    const SCANS_VALUES: bool = true;
    const BLOCKWISE: crate::blockwise::Blockwise = crate::blockwise::Blockwise::Staged("light_pca");

    fn mip_texels(&self, groups: &[Vec<(u32, f32)>]) -> Result<Self> {
        average_texels(self, groups)
    }

    fn fit(btf: &BtfRef<'_>, options: &RbfOptions, monitor: &Monitor) -> Result<Self> {
        fit_rbf(btf, options, monitor)
    }

    /// Not streamed below one view slot's resampled data and the float coefficients
    /// ([`light_pca::least_memory`]).
    fn least_memory(btf: &BtfRef<'_>, options: &RbfOptions) -> u64 {
        light_pca::least_memory(btf, &pca_options(options))
    }

    /// See [`LightPca::to_arrays`].
    fn to_arrays(&self) -> NamedArrays {
        self.0.to_arrays()
    }

    fn from_arrays(a: &NamedArrays) -> Result<Self> {
        Ok(Rbf(LightPca::from_arrays(a)?))
    }

    /// `{"planes", "chroma_planes", "table_bytes", "resolution", "colour", "pooled_slots"}`.
    fn report(&self) -> serde_json::Value {
        report(&self.0)
    }
}

/// The report of both light-basis models.
pub(crate) fn report(m: &LightPca) -> serde_json::Value {
    serde_json::json!({
        "planes": m.k(),
        "chroma_planes": m.k_chroma,
        "table_bytes": m.table_bytes(),
        "resolution": m.resolution,
        "colour": if m.colour == Colour::Rgb { "rgb" } else { "ycc" },
        "pooled_slots": m.pooled,
        "fallback_slots": m.fallback_slots,
    })
}

#[cfg(test)]
pub(crate) mod tests;
