//! Bilinear light grids (the RTI "bilinear" basis of relight, Ponchio et al.), fitted per view
//! slot: for a fixed view, each texel's value under light `l` is the bilinear interpolation of
//! values `g` on the `n x n` grid of [`crate::light_pca`] (the concentric square, option
//! `resolution`), at the light's square point. The grid values are the regularised least-squares
//! fit of the slot's samples,
//!
//! ```text
//! min_g |B g - y|^2 + lambda |D g|^2 + eps |g - mean(y)|^2
//! ```
//!
//! with `B` the bilinear weights of the lights, `D` the second differences of the grid along
//! both axes (which vanish exactly on functions `a + b s + c t + d s t`, so such a function is
//! recovered at any `lambda`), `lambda = regularization * tr(B^T B) / tr(D^T D)`, and a tiny
//! ridge `eps = 1e-9 tr(B^T B) / G` towards the samples' mean that only decides the nodes the
//! data and the smoothness leave free (a slot with fewer than 4 lights: one light gives the
//! constant). The operator `y -> g` depends on the lights only (one Cholesky per slot).
//!
//! Second differences extrapolate linearly: where a slot's lights leave part of the hemisphere
//! empty (lights on one side, or a few lights of a decimated multi-view sampling) the grid runs
//! away from the data. When the fit's *amplification* at the BTF's light directions (the largest
//! sum of the absolute weights it gives the samples in one prediction) exceeds [`K_AMP`], the
//! slot is fitted instead with first differences (the membrane, with `lambda` from
//! `max(regularization, 1)`), whose solution between and beyond the samples is harmonic and so
//! bounded by them; `report["fallback_slots"]` lists each such slot with the rejected
//! amplification. A well-spread RTI sampling stays with the second differences (81 UBO lights:
//! amplification 2.2; 160 dome lights: 2.3; the UBO lights of one azimuth half: 26). The grid
//! functions of all texels are then compressed by PCA into `components` 8-bit planes and a float
//! table of principal functions, as for [`crate::rbf`].

use crate::light_pca::{self, Colour, LightPca, PcaOptions};
use crate::model::{average_texels, Bench, Mip, Model, Sampling};
use crate::options::Spec;
use btfrs_core::{ensure_arg, BtfRef, Error, Monitor, NamedArrays, Result};
use nalgebra::DMatrix;

/// Fit options.
#[derive(Debug, Clone, Copy, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BilinearOptions {
    /// Coefficient planes per slot (rgb), or luminance planes (ycc).
    pub components: usize,
    /// `"rgb"` (joint PCA of the three channels) or `"ycc"` (luminance and chroma apart).
    pub colour: Colour,
    /// Chroma planes for `colour = "ycc"` (default `max(1, components / 4)`).
    pub chroma_components: Option<usize>,
    /// Light grid nodes per side (2 to 32).
    pub resolution: usize,
    /// Weight of the second-difference smoothness (>= 0, relative; see the module doc). The
    /// default 0.3 keeps 1000x outliers on 0.01% of the samples from being amplified (the
    /// stability suite); 0.1 was 2.3 points better on the grooves single-view capture and equal
    /// on bumps and knit (BENCHMARKS.md).
    pub regularization: f64,
    /// Seed of the randomized PCA (used for long vectors only).
    pub seed: u64,
}

impl Default for BilinearOptions {
    /// The defaults of [`Bilinear`]'s option schema.
    fn default() -> Self {
        crate::options::defaults(<Bilinear as Model>::OPTIONS)
    }
}

/// A fitted bilinear light grid.
#[derive(Debug, Clone, PartialEq)]
pub struct Bilinear(pub LightPca);

/// Above this amplification at the BTF's light directions (`max_l sum_j |w_j(l)|`, the weights
/// the fit gives each sample in the prediction at light `l`; cf. the PTM's `K_AMP`) the
/// second-difference fit of a slot is replaced by the membrane.
pub const K_AMP: f64 = 6.0;

/// Which smoothness penalty.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Penalty {
    /// Second differences (zero on `a + b s + c t + d s t`): extrapolates linearly.
    Thin,
    /// First differences (the membrane): harmonic between the samples, bounded by them.
    Membrane,
}

/// The `G x m` matrix mapping one channel's samples at `lights` to the fitted grid values (see
/// the module doc), `G = n^2`, with the given smoothness penalty.
pub fn bilinear_operator(lights: &[[f64; 3]], n: usize, regularization: f64, penalty: Penalty) -> Result<DMatrix<f64>> {
    let m = lights.len();
    ensure_arg!(m > 0, "lights", "expected at least one light");
    ensure_arg!(n >= 2, "resolution", "expected at least 2 grid nodes per side, got {n}");
    let g = n * n;
    let mut b = DMatrix::<f64>::zeros(m, g);
    for (j, &l) in lights.iter().enumerate() {
        for (node, w) in light_pca::grid_weights(n, l) {
            b[(j, node)] += w;
        }
    }
    let mut p = DMatrix::<f64>::zeros(g, g);
    let mut add = |idx: &[usize], coef: &[f64]| {
        for x in 0..idx.len() {
            for y in 0..idx.len() {
                p[(idx[x], idx[y])] += coef[x] * coef[y];
            }
        }
    };
    for j in 0..n {
        match penalty {
            Penalty::Thin => {
                for i in 1..n - 1 {
                    add(&[j * n + i - 1, j * n + i, j * n + i + 1], &[1.0, -2.0, 1.0]);
                    add(&[(i - 1) * n + j, i * n + j, (i + 1) * n + j], &[1.0, -2.0, 1.0]);
                }
            }
            Penalty::Membrane => {
                for i in 0..n - 1 {
                    add(&[j * n + i, j * n + i + 1], &[-1.0, 1.0]);
                    add(&[i * n + j, (i + 1) * n + j], &[-1.0, 1.0]);
                }
            }
        }
    }
    let btb = b.transpose() * &b;
    let tr = btb.trace();
    let lambda = if p.trace() > 0.0 { regularization * tr / p.trace() } else { 0.0 };
    let eps = 1e-9 * tr / g as f64;
    let a = &btb + p * lambda + DMatrix::<f64>::identity(g, g) * eps;
    let chol = a.cholesky().ok_or_else(|| {
        Error::Degenerate(format!("bilinear: the normal equations of {m} lights on a {n} x {n} grid are singular"))
    })?;
    let rhs = b.transpose() + DMatrix::<f64>::from_element(g, m, eps / m as f64);
    Ok(chol.solve(&rhs))
}

/// `max_l sum_j |w_j(l)|` over the query directions `queries` for the grid operator `w`.
pub fn amplification(w: &DMatrix<f64>, n: usize, queries: &[[f64; 3]]) -> f64 {
    queries
        .iter()
        .map(|&l| {
            let nodes = light_pca::grid_weights(n, l);
            (0..w.ncols()).map(|j| nodes.iter().map(|&(k, x)| x * w[(k, j)]).sum::<f64>().abs()).sum::<f64>()
        })
        .fold(0.0, f64::max)
}

/// The operator of one slot: the second-difference fit, or, when it amplifies its samples by
/// more than [`K_AMP`] at any light direction of the BTF (sparse or one-sided lights), the
/// membrane with `max(regularization, 1)`; `Some(amplification)` of the rejected fit then.
pub fn slot_operator(
    lights: &[[f64; 3]],
    n: usize,
    regularization: f64,
    queries: &[[f64; 3]],
) -> Result<(DMatrix<f64>, Option<f64>)> {
    let w = bilinear_operator(lights, n, regularization, Penalty::Thin)?;
    let a = amplification(&w, n, queries);
    if a <= K_AMP {
        return Ok((w, None));
    }
    Ok((bilinear_operator(lights, n, regularization.max(1.0), Penalty::Membrane)?, Some(a)))
}

/// The light-PCA options of `o`.
fn pca_options(o: &BilinearOptions) -> PcaOptions {
    light_pca::pca_options_of!(o)
}

/// The options checked, as the light-PCA options and the resampling operator of one slot
/// (its amplification measured at `queries`, the BTF's lights).
pub(crate) fn prepare<'a>(
    o: &BilinearOptions,
    queries: &'a [[f64; 3]],
) -> Result<(PcaOptions, Box<light_pca::Operator<'a>>)> {
    ensure_arg!(
        o.regularization.is_finite() && o.regularization >= 0.0,
        "regularization",
        "expected a finite value >= 0, got {}",
        o.regularization
    );
    let pca = pca_options(o);
    pca.check()?;
    let regularization = o.regularization;
    let op = move |lights: &[[f64; 3]], n: usize| slot_operator(lights, n, regularization, queries);
    Ok((pca, Box::new(op)))
}

/// Fit a bilinear light grid to the present pairs of `btf`; `monitor` counts view slots.
pub fn fit_bilinear(btf: &BtfRef<'_>, o: &BilinearOptions, monitor: &Monitor) -> Result<Bilinear> {
    let (pca, op) = prepare(o, btf.lights)?;
    Ok(Bilinear(light_pca::fit(btf, &pca, &*op, "bilinear", monitor)?))
}

light_pca::light_pca_model!(Bilinear);

impl Model for Bilinear {
    const KIND: &'static str = "bilinear";
    const EXPORTS: &'static [&'static str] = &["relight"];
    const DOC: &'static str =
        "bilinear light grid per view slot by regularised least squares, PCA into 8-bit planes (relight's bilinear)";
    const ABOUT: &'static str = "\
relight's bilinear light basis per view slot. Per slot and texel, values on a `resolution x
resolution` grid of the concentric square are fitted by regularised least squares so that their
bilinear interpolation at each light's square point matches its sample (`min |B g - y|^2 + lambda
|D g|^2`, `D` the second differences of the grid; a tiny ridge towards the samples' mean decides
the nodes nothing else does). A slot whose fit would amplify its samples more than 6 times at
some light direction is fitted with first differences instead (`model.report[\"fallback_slots\"]`);
a slot of a multi-view BTF with fewer than 6 lights borrows the nearest views'
(`report[\"pooled_slots\"]`). The grid functions are then compressed by PCA into 8-bit planes
exactly as for the RBF basis.";
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
        Spec::int("resolution", 8, 2, Some(light_pca::MAX_RESOLUTION as i64), "light grid nodes per side"),
        Spec::float("regularization", 0.3, 0.0, "weight of the second-difference smoothness (relative)"),
        Spec::seed("seed of the randomized PCA (vectors longer than 768 values) and of the texel sample whose moments give the principal functions (captures above 262144 texels)"),
    ];
    const SAMPLING: Sampling = Sampling::PerView { min_lights: 4, why: "8 x 8 grid" };
    const EXAMPLES: &'static [(&'static str, &'static str)] = &[
        ("Bilinear-9", r#"{"components": 9}"#),
        ("Bilinear-18", r#"{"components": 18}"#),
        ("Bilinear-27", r#"{"components": 27}"#),
    ];
    const TEXEL_ARRAYS: &'static [&'static str] = &["coeffs_q"];
    // The single-view RTI captures: relight's sizes, the other table resolution, the YCC split.
    const BENCH: &'static [Bench] = &[
        Bench::new("Bilinear-{components}", r#"{"components": [3, 6, 9, 12, 18, 27]}"#, &["single_view"]),
        Bench::new("Bilinear-{components} r12", r#"{"components": [3, 9, 18], "resolution": 12}"#, &["single_view"]),
        Bench::new(
            "Bilinear-YCC 9+3",
            r#"{"components": 9, "colour": "ycc", "chroma_components": 3}"#,
            &["single_view"],
        ),
        Bench::new(
            "Bilinear-YCC 12+3",
            r#"{"components": 12, "colour": "ycc", "chroma_components": 3}"#,
            &["single_view"],
        ),
        Bench::new(
            "Bilinear-YCC 18+4",
            r#"{"components": 18, "colour": "ycc", "chroma_components": 4}"#,
            &["single_view"],
        ),
        Bench::new("Bilinear-18", r#"{"components": 18}"#, &["summary"]).note("relight bilinear 25.3% in 50 KB"),
        Bench::new("Bilinear-9", r#"{"components": 9}"#, &["dask"]),
    ];
    const MIP: Mip = Mip::Average;
    type Options = BilinearOptions;
    // Each value checked as the fit reads it (per block of texels; per view slot for the light bases).
    const SCANS_VALUES: bool = true;
    const BLOCKWISE: crate::blockwise::Blockwise = crate::blockwise::Blockwise::Staged("light_pca");

    fn mip_texels(&self, groups: &[Vec<(u32, f32)>]) -> Result<Self> {
        average_texels(self, groups)
    }

    fn fit(btf: &BtfRef<'_>, options: &BilinearOptions, monitor: &Monitor) -> Result<Self> {
        fit_bilinear(btf, options, monitor)
    }

    /// Not streamed below one view slot's resampled data and the float coefficients
    /// ([`light_pca::least_memory`]).
    fn least_memory(btf: &BtfRef<'_>, options: &BilinearOptions) -> u64 {
        light_pca::least_memory(btf, &pca_options(options))
    }

    /// See [`LightPca::to_arrays`].
    fn to_arrays(&self) -> NamedArrays {
        self.0.to_arrays()
    }

    fn from_arrays(a: &NamedArrays) -> Result<Self> {
        Ok(Bilinear(LightPca::from_arrays(a)?))
    }

    /// `{"planes", "chroma_planes", "table_bytes", "resolution", "colour", "pooled_slots",
    /// "fallback_slots"}` (see [`crate::light_pca::PooledSlot`], [`crate::light_pca::FallbackSlot`]).
    fn report(&self) -> serde_json::Value {
        crate::rbf::report(&self.0)
    }
}

#[cfg(test)]
mod tests;
