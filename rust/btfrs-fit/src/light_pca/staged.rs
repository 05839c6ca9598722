//! The light-PCA fit of the RBF and bilinear models ([`super`]) cut into the stages a blockwise
//! driver runs over texel blocks fitted apart (`btfrs.dask`, [`crate::blockwise`]). The local
//! fit holds one view slot's resampled functions of *every* texel to find its principal
//! directions; here each block contributes sufficient statistics instead, so no machine holds
//! more than one block:
//!
//! 1. [`Basis::plan`]: the slots' pairs and resampling operators, a function of the directions,
//!    mask and options only (every task computes the same one).
//! 2. [`moments`] per block: per slot and group (see [`super::groups`]), the count, the mean and
//!    the centred second moment `M2 = sum (x - mean)(x - mean)^T` of the resampled functions,
//!    accumulated in `f64`.
//! 3. [`Moments::merge`]: two blocks' moments as one by the pairwise update of Chan, Golub and
//!    LeVeque ("Updating formulae and a pairwise algorithm for computing sample variances",
//!    1979): `M2 = M2a + M2b + delta delta^T na nb / n`, `delta = mean_b - mean_a`. Centred
//!    per block and merged in pairs (a tree), so no sum of squares of large values cancels.
//! 4. [`table`] on the client: per slot and group, the `f64` eigenvectors of `M2`, the same
//!    exact PCA as the local fit's covariance path (the top `components` directions with
//!    eigenvalue above `1e-12` of the largest, zero functions beyond), written as the model's table.
//! 5. [`project`] per block: each texel's coefficients against the table's mean and directions
//!    (as the local fit computes them).
//! 6. [`assemble`] on the client: the 8-bit quantization over all texels' coefficients and the
//!    model.
//!
//! The result equals the local fit to rounding: the same principal subspace of every slot (the
//! eigenproblem of the same covariance, summed in another order), each direction possibly of the
//! opposite sign (an eigenvector's sign is arbitrary; the coefficient flips with it, so every
//! evaluation agrees). The covariance is `d x d` per slot and group, so a block's moments are
//! `8 V d^2` bytes (RBF defaults, `d = 3 * 12^2 = 432`, 81 views: 121 MB): the blockwise fit
//! takes groups of at most [`super::EXACT_PCA_DIM`] values (rgb up to resolution 16, ycc up to
//! 19), where the local fit itself is exact; above, it would need the randomized subspace
//! iteration as passes over the blocks, which is not built.

use super::{
    group_planes, groups, put_coeffs, read_slot, write_slot, Colour, LightPca, PcaOptions, Plan, EXACT_PCA_DIM,
};
use crate::bilinear::{self, BilinearOptions};
use crate::model::Model;
use crate::options;
use crate::planes::Planes;
use crate::rbf::{self, RbfOptions};
use btfrs_core::{ensure_arg, BtfRef, Error, Result};
use btfrs_numerics::dense::{gemm, sym_eigen_desc, view, view_t};
use nalgebra::DMatrix;
use rayon::prelude::*;

/// Which light-PCA model, with its options.
#[derive(Debug, Clone, Copy)]
pub enum Basis {
    /// [`crate::rbf::Rbf`].
    Rbf(RbfOptions),
    /// [`crate::bilinear::Bilinear`].
    Bilinear(BilinearOptions),
}

impl Basis {
    /// Model `kind` (`"rbf"` or `"bilinear"`) with its options (a JSON object, as the fit takes
    /// them), checked, including the blockwise limit on the vector length (module doc).
    pub fn parse(kind: &str, options_json: &str) -> Result<Basis> {
        let b = match kind {
            "rbf" => Basis::Rbf(options::parse(<rbf::Rbf as Model>::OPTIONS, options_json)?),
            "bilinear" => Basis::Bilinear(options::parse(<bilinear::Bilinear as Model>::OPTIONS, options_json)?),
            other => {
                return Err(Error::arg(
                    "kind",
                    format!("expected \"rbf\" or \"bilinear\" (a light-PCA model), got {other:?}"),
                ))
            }
        };
        let o = b.options()?;
        let g = o.resolution * o.resolution;
        let d = if o.colour == Colour::Rgb { 3 * g } else { 2 * g };
        ensure_arg!(
            d <= EXACT_PCA_DIM,
            "resolution",
            "the blockwise {kind} fit sums a {d} x {d} covariance per view slot (resolution {}, colour {}), more than \
             the {EXACT_PCA_DIM} values it supports: use resolution <= {} or fit it out of core on one machine \
             (btfrs.fit.{kind}(btf, memory_limit=...))",
            o.resolution,
            if o.colour == Colour::Rgb { "rgb" } else { "ycc" },
            if o.colour == Colour::Rgb { 16 } else { 19 }
        );
        Ok(b)
    }

    /// The model's name.
    pub fn kind(&self) -> &'static str {
        match self {
            Basis::Rbf(_) => "rbf",
            Basis::Bilinear(_) => "bilinear",
        }
    }

    /// The light-PCA options (checked as the fit checks them).
    pub fn options(&self) -> Result<PcaOptions> {
        Ok(match self {
            Basis::Rbf(o) => rbf::prepare(o)?.0,
            Basis::Bilinear(o) => bilinear::prepare(o, &[])?.0,
        })
    }

    /// Stage 1: the plan of every slot for these directions and mask (the local fit's).
    pub fn plan(&self, views: &[[f64; 3]], lights: &[[f64; 3]], mask: Option<&[bool]>) -> Result<Plan> {
        match self {
            Basis::Rbf(o) => {
                let (p, op) = rbf::prepare(o)?;
                Plan::new(views, lights, mask, p.resolution, &*op, "rbf")
            }
            Basis::Bilinear(o) => {
                let (p, op) = bilinear::prepare(o, lights)?;
                Plan::new(views, lights, mask, p.resolution, &*op, "bilinear")
            }
        }
    }

    /// Wrap the fitted light basis as the model.
    pub fn model(&self, m: LightPca) -> Box<dyn crate::DynModel> {
        match self {
            Basis::Rbf(_) => Box::new(rbf::Rbf(m)),
            Basis::Bilinear(_) => Box::new(bilinear::Bilinear(m)),
        }
    }
}

/// One group's moments over some texels for every slot.
#[derive(Debug, Clone, PartialEq)]
pub struct GroupMoments {
    /// Values per vector.
    pub d: usize,
    /// `[V][d]` means.
    pub mean: Vec<f64>,
    /// `[V][d][d]` centred second moments (symmetric).
    pub m2: Vec<f64>,
}

/// The moments of a set of texels (stage 2): the count and each group's (module doc).
#[derive(Debug, Clone, PartialEq)]
pub struct Moments {
    /// Texels counted.
    pub n: u64,
    /// One per group ([`super::groups`]: rgb one, ycc luminance then chroma).
    pub groups: Vec<GroupMoments>,
}

impl Moments {
    /// Both sets' moments as one (Chan et al.'s pairwise update, module doc).
    pub fn merge(&self, other: &Moments) -> Result<Moments> {
        let same = self.groups.len() == other.groups.len()
            && self.groups.iter().zip(&other.groups).all(|(a, b)| {
                a.d == b.d
                    && a.mean.len() == b.mean.len()
                    && a.m2.len() == b.m2.len()
                    && a.m2.len() == a.mean.len() * a.d
            });
        ensure_arg!(same, "moments", "the two sets of moments have different layouts (another model or options?)");
        if self.n == 0 {
            return Ok(other.clone());
        }
        if other.n == 0 {
            return Ok(self.clone());
        }
        let (na, nb) = (self.n as f64, other.n as f64);
        let n = na + nb;
        let groups = self
            .groups
            .iter()
            .zip(&other.groups)
            .map(|(a, b)| {
                let d = a.d;
                let delta: Vec<f64> = a.mean.iter().zip(&b.mean).map(|(x, y)| y - x).collect();
                let mean = a.mean.iter().zip(&delta).map(|(x, dl)| x + dl * nb / n).collect();
                let f = na * nb / n;
                let mut m2: Vec<f64> = a.m2.iter().zip(&b.m2).map(|(x, y)| x + y).collect();
                m2.par_chunks_mut(d * d).zip(delta.par_chunks(d)).for_each(|(m, dl)| {
                    for i in 0..d {
                        for j in 0..d {
                            m[i * d + j] += dl[i] * dl[j] * f;
                        }
                    }
                });
                GroupMoments { d, mean, m2 }
            })
            .collect();
        Ok(Moments { n: self.n + other.n, groups })
    }
}

/// Stage 2: the moments of one block's texels (its directions and mask those of the plan).
pub fn moments(block: &BtfRef<'_>, plan: &Plan, opts: &PcaOptions) -> Result<Moments> {
    check_block(block, plan)?;
    let (nv, t, g) = (block.views.len(), block.texels(), opts.resolution * opts.resolution);
    // Per slot in parallel: the slots are independent, and one slot's block is small.
    let per: Vec<Vec<(Vec<f64>, Vec<f64>)>> = (0..nv)
        .into_par_iter()
        .map(|v| {
            let r = plan.resample(block, v);
            groups(r.as_slice(), g, t, opts.colour)
                .into_iter()
                .map(|(x, d)| {
                    let mut mean = vec![0.0f64; d];
                    for col in x.chunks_exact(d) {
                        mean.iter_mut().zip(col).for_each(|(m, &v)| *m += v as f64);
                    }
                    mean.iter_mut().for_each(|m| *m /= t.max(1) as f64);
                    let xc = DMatrix::<f64>::from_fn(d, t, |i, j| x[j * d + i] as f64 - mean[i]);
                    let m2 = &xc * xc.transpose();
                    (mean, m2.as_slice().to_vec())
                })
                .collect()
        })
        .collect();
    let ng = per.first().map_or(0, |p| p.len());
    let groups = (0..ng)
        .map(|gi| {
            let d = per[0][gi].0.len();
            let mut mean = Vec::with_capacity(nv * d);
            let mut m2 = Vec::with_capacity(nv * d * d);
            for slot in &per {
                mean.extend_from_slice(&slot[gi].0);
                m2.extend_from_slice(&slot[gi].1);
            }
            GroupMoments { d, mean, m2 }
        })
        .collect();
    Ok(Moments { n: t as u64, groups })
}

/// Stage 4: the model's table (`[V][G][R]`, module doc of [`super`]) from the moments of all
/// texels.
pub fn table(m: &Moments, opts: &PcaOptions, nv: usize) -> Result<Vec<f32>> {
    let kc = opts.check()?;
    let (g, km) = (opts.resolution * opts.resolution, opts.components);
    let planes = group_planes(opts.colour, km, kc);
    let dims: Vec<usize> = match opts.colour {
        Colour::Rgb => vec![3 * g],
        Colour::Ycc => vec![g, 2 * g],
    };
    let ok = m.n > 0
        && m.groups.len() == dims.len()
        && m.groups.iter().zip(&dims).all(|(gm, &d)| gm.d == d && gm.mean.len() == nv * d && gm.m2.len() == nv * d * d);
    ensure_arg!(
        ok,
        "moments",
        "expected the moments of {nv} view slots of groups {dims:?} values long over some texels"
    );
    let stride = 3 + km * if opts.colour == Colour::Rgb { 3 } else { 1 } + 2 * kc;
    let mut table = vec![0.0f32; nv * g * stride];
    table.par_chunks_mut(g * stride).enumerate().for_each(|(v, slot)| {
        let parts: Vec<(Vec<f32>, DMatrix<f32>)> = m
            .groups
            .iter()
            .zip(&planes)
            .map(|(gm, &(k, _))| {
                let d = gm.d;
                let m2 = &gm.m2[v * d * d..(v + 1) * d * d];
                let c = DMatrix::<f64>::from_fn(d, d, |i, j| 0.5 * (m2[i * d + j] + m2[j * d + i]));
                let (vals, vecs) = sym_eigen_desc(c);
                let top = vals.first().copied().unwrap_or(0.0);
                let keep = (0..k.min(d)).take_while(|&j| top > 0.0 && vals[j] > 1e-12 * top).count();
                let basis = DMatrix::<f32>::from_fn(d, k, |i, j| if j < keep { vecs[(i, j)] as f32 } else { 0.0 });
                let mean = gm.mean[v * d..(v + 1) * d].iter().map(|&x| x as f32).collect();
                (mean, basis)
            })
            .collect();
        let refs: Vec<(&[f32], &DMatrix<f32>)> = parts.iter().map(|(a, b)| (a.as_slice(), b)).collect();
        write_slot(slot, opts.colour, km, g, &refs);
    });
    btfrs_core::arrays::check_finite("table", &table)?;
    Ok(table)
}

/// Stage 5: one block's coefficients `[texel][V][K]` (f32, before quantization) against the
/// table's means and directions.
pub fn project(block: &BtfRef<'_>, plan: &Plan, table: &[f32], opts: &PcaOptions) -> Result<Vec<f32>> {
    check_block(block, plan)?;
    let kc = opts.check()?;
    let (nv, t, g, km) = (block.views.len(), block.texels(), opts.resolution * opts.resolution, opts.components);
    let k = km + kc;
    let stride = 3 + km * if opts.colour == Colour::Rgb { 3 } else { 1 } + 2 * kc;
    ensure_arg!(table.len() == nv * g * stride, "table", "expected {nv} x {g} x {stride} values, got {}", table.len());
    let per: Vec<Vec<(usize, DMatrix<f32>)>> = (0..nv)
        .into_par_iter()
        .map(|v| {
            let r = plan.resample(block, v);
            let stored = read_slot(&table[v * g * stride..(v + 1) * g * stride], opts.colour, km, kc, g);
            groups(r.as_slice(), g, t, opts.colour)
                .into_iter()
                .zip(stored)
                .zip(group_planes(opts.colour, km, kc))
                .map(|(((x, d), (mean, basis)), (_, off))| {
                    let mut xc = DMatrix::<f32>::from_column_slice(d, t, &x);
                    xc.column_iter_mut().for_each(|mut c| c.iter_mut().zip(&mean).for_each(|(a, m)| *a -= m));
                    (off, gemm(&view_t(&basis), &view(&xc)))
                })
                .collect()
        })
        .collect();
    let mut coeffs = vec![0.0f32; t * nv * k];
    for (v, parts) in per.iter().enumerate() {
        for (off, c) in parts {
            put_coeffs(&mut coeffs, c, v, nv, k, *off);
        }
    }
    if coeffs.iter().any(|x| !x.is_finite()) {
        return Err(Error::Degenerate("the projection of the resampled light functions is not finite".into()));
    }
    Ok(coeffs)
}

/// Stage 6: the model from the table and every texel's coefficients (`[T][V][K]`, texel order),
/// quantized over all texels as the local fit does.
pub fn assemble(
    height: usize,
    width: usize,
    views: &[[f64; 3]],
    plan: Plan,
    table: Vec<f32>,
    coeffs: &[f32],
    opts: &PcaOptions,
) -> Result<LightPca> {
    let k = opts.components + opts.check()?;
    let nv = views.len();
    ensure_arg!(
        coeffs.len() == height * width * nv * k,
        "coeffs",
        "expected {height} x {width} texels x {nv} slots x {k} planes, got {} values",
        coeffs.len()
    );
    let Plan { pooled, fallback_slots, .. } = plan;
    super::assemble(height, width, views, opts, Planes::quantize(coeffs, nv * k)?, table, pooled, fallback_slots)
}

fn check_block(block: &BtfRef<'_>, plan: &Plan) -> Result<()> {
    ensure_arg!(
        plan.slots.len() == block.views.len(),
        "views",
        "the plan has {} view slots, the block {}",
        plan.slots.len(),
        block.views.len()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Model;
    use btfrs_core::materials::{generate, MaterialSpec, Preset};
    use btfrs_core::Monitor;

    /// The rows `r0..r1` of `b` as a block.
    fn rows<'a>(b: &BtfRef<'a>, r0: usize, r1: usize) -> BtfRef<'a> {
        let per = b.abrdf_len() * b.width;
        BtfRef { height: r1 - r0, data: &b.data[r0 * per..r1 * per], ..*b }
    }

    #[test]
    fn table_round_trips_through_write_and_read() {
        // read_slot inverts write_slot for both colour groupings.
        let mut rng = btfrs_core::rng::Rng::new(3);
        for (colour, km, kc) in [(Colour::Rgb, 3, 0), (Colour::Ycc, 4, 2)] {
            let g = 9;
            let dims: Vec<usize> = if colour == Colour::Rgb { vec![3 * g] } else { vec![g, 2 * g] };
            let parts: Vec<(Vec<f32>, DMatrix<f32>)> = dims
                .iter()
                .zip(group_planes(colour, km, kc))
                .map(|(&d, (k, _))| {
                    let m: Vec<f32> = (0..d).map(|_| rng.next_f64() as f32).collect();
                    (m, DMatrix::from_fn(d, k, |_, _| rng.next_f64() as f32))
                })
                .collect();
            let stride = 3 + km * if colour == Colour::Rgb { 3 } else { 1 } + 2 * kc;
            let mut t = vec![f32::NAN; g * stride];
            let refs: Vec<(&[f32], &DMatrix<f32>)> = parts.iter().map(|(a, b)| (a.as_slice(), b)).collect();
            write_slot(&mut t, colour, km, g, &refs);
            assert!(t.iter().all(|x| x.is_finite()), "{colour:?}: some table entries were not written");
            assert_eq!(read_slot(&t, colour, km, kc, g), parts, "{colour:?}");
        }
    }

    #[test]
    fn merged_moments_equal_a_float64_reference() {
        // Two blocks' moments merged against numpy-style moments of all texels at once.
        let btf = generate(&MaterialSpec::new(Preset::Bumps, 8, 3), &Monitor::new()).unwrap();
        let b = btf.as_ref();
        let basis = Basis::parse("bilinear", r#"{"resolution": 4, "colour": "ycc"}"#).unwrap();
        let o = basis.options().unwrap();
        let plan = basis.plan(b.views, b.lights, None).unwrap();
        let whole = moments(&b, &plan, &o).unwrap();
        let parts = [moments(&rows(&b, 0, 3), &plan, &o).unwrap(), moments(&rows(&b, 3, 8), &plan, &o).unwrap()];
        let merged = parts[0].merge(&parts[1]).unwrap();
        assert_eq!(merged.n, 64);
        // The reference: sums over all texels in f64 from the resampled data directly.
        let g = 16;
        for v in [0, b.views.len() - 1] {
            let r = plan.resample(&b, v);
            for (gi, (x, d)) in groups(r.as_slice(), g, 64, Colour::Ycc).into_iter().enumerate() {
                let cols: Vec<&[f32]> = x.chunks_exact(d).collect();
                let mean: Vec<f64> = (0..d).map(|i| cols.iter().map(|c| c[i] as f64).sum::<f64>() / 64.0).collect();
                let gm = &merged.groups[gi];
                let scale = gm.m2[v * d * d..(v + 1) * d * d].iter().fold(0.0f64, |a, x| a.max(x.abs()));
                for i in 0..d {
                    assert!((gm.mean[v * d + i] - mean[i]).abs() < 1e-9);
                    for j in 0..d {
                        let m2: f64 = cols.iter().map(|c| (c[i] as f64 - mean[i]) * (c[j] as f64 - mean[j])).sum();
                        assert!((gm.m2[v * d * d + i * d + j] - m2).abs() <= 1e-9 * scale, "slot {v} group {gi}");
                        let w = whole.groups[gi].m2[v * d * d + i * d + j];
                        assert!((w - m2).abs() <= 1e-9 * scale);
                    }
                }
            }
        }
        // Merging with an empty set is the identity; different layouts are refused.
        let empty = Moments { n: 0, groups: merged.groups.clone() };
        assert_eq!(empty.merge(&merged).unwrap(), merged);
        let rgb = Basis::parse("bilinear", r#"{"resolution": 4}"#).unwrap();
        let other = moments(&b, &rgb.plan(b.views, b.lights, None).unwrap(), &rgb.options().unwrap()).unwrap();
        assert!(merged.merge(&other).unwrap_err().to_string().starts_with("moments: the two sets"));
        assert!(table(&other, &o, b.views.len()).unwrap_err().to_string().starts_with("moments: expected"));
    }

    #[test]
    fn staged_fits_evaluate_as_the_local_fits() {
        // Both models and both colour groupings, with a mask: three blocks through the stages
        // against the local fit. The principal subspaces are the same, the directions' signs may
        // differ: every evaluation agrees to rounding.
        let btf = generate(&MaterialSpec::new(Preset::Bumps, 12, 3), &Monitor::new()).unwrap();
        let b = btf.as_ref();
        let (nv, nl) = (b.views.len(), b.lights.len());
        let mask: Vec<bool> = (0..nv * nl).map(|i| i % 7 != 3).collect();
        let b = BtfRef { mask: Some(&mask), ..b };
        for (kind, json) in [
            ("rbf", r#"{"components": 5}"#),
            ("rbf", r#"{"components": 4, "colour": "ycc", "resolution": 8}"#),
            ("bilinear", r#"{"components": 6}"#),
            ("bilinear", r#"{"components": 5, "colour": "ycc", "chroma_components": 2}"#),
        ] {
            let basis = Basis::parse(kind, json).unwrap();
            let o = basis.options().unwrap();
            let plan = basis.plan(b.views, b.lights, b.mask).unwrap();
            let blocks = [rows(&b, 0, 5), rows(&b, 5, 6), rows(&b, 6, 12)];
            let m = blocks.iter().map(|x| moments(x, &plan, &o).unwrap()).reduce(|a, x| a.merge(&x).unwrap()).unwrap();
            let tab = table(&m, &o, nv).unwrap();
            let coeffs: Vec<f32> = blocks.iter().flat_map(|x| project(x, &plan, &tab, &o).unwrap()).collect();
            let staged = assemble(b.height, b.width, b.views, plan, tab, &coeffs, &o).unwrap();
            let local = match basis {
                Basis::Rbf(ro) => rbf::Rbf::fit(&b, &ro, &Monitor::new()).unwrap().0,
                Basis::Bilinear(bo) => bilinear::Bilinear::fit(&b, &bo, &Monitor::new()).unwrap().0,
            };
            assert_eq!(
                (staged.pooled.clone(), staged.fallback_slots.clone()),
                (local.pooled.clone(), local.fallback_slots.clone())
            );
            let mut worst = 0.0f32;
            let mut peak = 0.0f32;
            for (vi, li) in [(0, 0), (3, 17), (nv - 1, nl - 1), (nv / 2, nl / 3)] {
                let (qs, ql) = (staged.query(b.views[vi], b.lights[li]), local.query(b.views[vi], b.lights[li]));
                for t in 0..b.texels() {
                    let (x, y) = (staged.eval(t, &qs), local.eval(t, &ql));
                    for c in 0..3 {
                        worst = worst.max((x[c] - y[c]).abs());
                        peak = peak.max(y[c].abs());
                    }
                }
            }
            // Measured: 2.4e-7 of the peak (float rounding); one 8-bit step of a coefficient that
            // rounds the other way would be about 1e-3.
            assert!(worst <= 2e-3 * peak, "{kind} {json}: staged and local differ by {worst} (peak {peak})");
        }
    }

    #[test]
    fn bad_input_is_refused() {
        let e = |k: &str, j: &str| Basis::parse(k, j).unwrap_err().to_string();
        assert!(e("ptm", "{}").starts_with("kind: expected \"rbf\" or \"bilinear\""));
        assert!(e("rbf", r#"{"resolution": 17}"#).starts_with("resolution: the blockwise rbf fit sums a 867 x 867"));
        assert!(Basis::parse("rbf", r#"{"resolution": 19, "colour": "ycc"}"#).is_ok());
        assert!(e("bilinear", r#"{"regularization": -1}"#).starts_with("regularization:"));
        assert!(e("rbf", r#"{"bogus": 1}"#).contains("bogus"));
    }
}
