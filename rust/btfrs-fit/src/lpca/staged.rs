//! The LPCA fit (module doc of [`super`], steps 1 to 5) cut into the stages a blockwise driver
//! runs over texel blocks fitted apart (`btfrs.dask`, [`crate::blockwise`]), each the same code
//! as [`super::fit_lpca`]'s in-memory path, so the blockwise fit gives the same model:
//!
//! 1. [`sample`]: the texels the range finder works on (seeded); the driver gathers their
//!    ABRDFs; [`subspace`] finds the centre and subspace on them (one machine, 2048 ABRDFs).
//! 2. [`project`] per block (a map over the blocks); the driver stacks the rows in texel order.
//! 3. [`cluster`] on the client: principal axes, k-means, refinement, over `T x reduced_dims`
//!    coordinates (what the local fit holds too).
//! 4. [`fit_cluster`]: one task per cluster over its members' ABRDFs, in texel order (the
//!    driver gathers them from the blocks).
//! 5. [`assemble`]: the model (the same function as the local fit's).
//!
//! The texels' ABRDFs are their present pairs only (`V L` pairs, or the mask's present ones),
//! three values each, as the fit compacts them. The principal coordinates must be on
//! (`reduced_dims > 0`): clustering the full ABRDFs needs every value on one machine.

use super::{check_options, sampled, sub_seed, ClusterFit, LpcaOptions};
use btfrs_core::{ensure_arg, Monitor, Result};
use btfrs_numerics::rpca;
use nalgebra::DMatrix;
use rayon::prelude::*;

/// The options of a staged fit, by name (checked against the LPCA schema).
pub fn parse_options(values: &crate::options::Values) -> Result<LpcaOptions> {
    crate::options::build(<super::Lpca as crate::model::Model>::OPTIONS, values.clone())
}

/// Stage 1a: the texels whose ABRDFs [`subspace`] needs (`None`: every texel) for a
/// `height x width` BTF.
pub fn sample(height: usize, width: usize, opts: &LpcaOptions) -> Result<Option<Vec<u32>>> {
    check(opts, height, width)?;
    let t = height * width;
    Ok(match sampled::pick(t, opts) {
        // The range finder draws from the texel sample, as the local fit on it does.
        Some(pick) => Some(match rpca::sample_texels(pick.len(), sub_seed(opts.seed, 1)) {
            Some(sub) => sub.iter().map(|&i| pick[i as usize]).collect(),
            None => pick,
        }),
        None => rpca::sample_texels(t, sub_seed(opts.seed, 1)),
    })
}

/// The texels the clusters and their Eigen-BRDFs are found on (`None`: every texel): the
/// `sample` option's seeded draw, as the local fit makes it.
pub fn basis_texels(height: usize, width: usize, opts: &LpcaOptions) -> Result<Option<Vec<u32>>> {
    check(opts, height, width)?;
    Ok(sampled::pick(height * width, opts))
}

/// Stage 1b: the centre (`[d]`) and subspace (`d x l`) from the sample's ABRDFs (`s x d`,
/// texel-major, in the order of [`sample`]).
pub fn subspace(
    sample: &[f32],
    d: usize,
    height: usize,
    width: usize,
    opts: &LpcaOptions,
    monitor: &Monitor,
) -> Result<(Vec<f32>, DMatrix<f32>)> {
    check(opts, height, width)?;
    let t = height * width;
    let n = sampled::pick(t, opts).map_or(t, |p| p.len());
    rpca::sample_subspace(sample, d, n, opts.reduced_dims, sub_seed(opts.seed, 1), monitor)
}

/// Stage 2: one block's texels (`n x d`) projected on the subspace: `n x l`.
pub fn project(block: &[f32], d: usize, mu: &[f32], q: &DMatrix<f32>) -> Result<DMatrix<f32>> {
    rpca::project_texels(block, d, mu, q)
}

/// Stage 3: every texel's cluster and each cluster's members (texel order) from the projected
/// texels of all blocks (`T x l`, texel order).
pub fn cluster(
    z: &DMatrix<f32>,
    height: usize,
    width: usize,
    opts: &LpcaOptions,
    monitor: &Monitor,
) -> Result<(Vec<u32>, Vec<Vec<u32>>)> {
    check(opts, height, width)?;
    let t = height * width;
    ensure_arg!(z.nrows() == t, "z", "expected {t} projected texels, got {}", z.nrows());
    let Some(pick) = sampled::pick(t, opts) else {
        let (space, dim) = rpca::principal_axes(z, opts.reduced_dims);
        return super::cluster_space(&space, dim, t, opts, monitor);
    };
    // On a texel sample: its rows clustered, every other texel assigned to its best subspace.
    let zs = DMatrix::<f32>::from_fn(pick.len(), z.ncols(), |i, j| z[(pick[i] as usize, j)]);
    let (space, dim, vr) = rpca::principal_axes_map(&zs, opts.reduced_dims);
    let (ids_s, members_s) = super::cluster_space(&space, dim, pick.len(), opts, monitor)?;
    let pcas = sampled::reduced_pcas(&space, dim, &members_s, opts.components, opts.seed);
    let mut ids = vec![u32::MAX; t];
    for (&i, &k) in pick.iter().zip(&ids_s) {
        ids[i as usize] = k;
    }
    let others: Vec<usize> = (0..t).filter(|&i| ids[i] == u32::MAX).collect();
    let zo = DMatrix::<f32>::from_fn(others.len(), z.ncols(), |i, j| z[(others[i], j)]);
    let map = rpca::CoordinateMap { mu: Vec::new(), q: DMatrix::zeros(0, 0), vr };
    let best = sampled::assign(&map.rotate(&zo), dim, &pcas, opts.components);
    for (&i, &k) in others.iter().zip(&best) {
        ids[i] = k;
    }
    let mut members = vec![Vec::new(); members_s.len()];
    for (i, &k) in ids.iter().enumerate() {
        members[k as usize].push(i as u32);
    }
    Ok((ids, members))
}

/// Stage 4: cluster `index`'s Eigen-BRDFs, quantization and weights from its members' ABRDFs
/// (`n x d`, texel order).
pub fn fit_cluster(members: &[f32], d: usize, index: usize, opts: &LpcaOptions) -> Result<ClusterFit> {
    ensure_arg!(
        d > 0 && !members.is_empty() && members.len().is_multiple_of(d),
        "members",
        "expected the ABRDFs of at least one texel, {d} values each, got {} values",
        members.len()
    );
    ensure_arg!(opts.components <= super::MAX_COMPONENTS, "components", "expected 0 to {}", super::MAX_COMPONENTS);
    let m: Vec<u32> = (0..(members.len() / d) as u32).collect();
    Ok(super::fit_cluster(members, d, &m, opts.components, sub_seed(opts.seed, 1000 + index as u64), None))
}

/// Stage 4 of a fit on a texel sample ([`basis_texels`] is `Some`): cluster `index`'s
/// Eigen-BRDFs from those of its members in the sample, every member's weights solved against
/// them, as the local fit's streaming pass does. `texels`: the members' texel indices, ascending,
/// one per row of `members`.
pub fn fit_cluster_sampled(
    members: &[f32],
    texels: &[u32],
    d: usize,
    height: usize,
    width: usize,
    index: usize,
    opts: &LpcaOptions,
) -> Result<ClusterFit> {
    ensure_arg!(
        d > 0 && members.len() == texels.len() * d && !texels.is_empty(),
        "members",
        "expected one ABRDF of {d} values per texel of `texels` ({}), got {} values",
        texels.len(),
        members.len()
    );
    ensure_arg!(texels.windows(2).all(|w| w[0] < w[1]), "texels", "expected ascending texel indices");
    let Some(pick) = basis_texels(height, width, opts)? else {
        return fit_cluster(members, d, index, opts);
    };
    let rows: Vec<u32> =
        (0..texels.len() as u32).filter(|&i| pick.binary_search(&texels[i as usize]).is_ok()).collect();
    ensure_arg!(!rows.is_empty(), "texels", "cluster {index} has no member in the texel sample");
    let c = opts.components;
    let (basis, _) = super::cluster_basis(members, d, &rows, c, sub_seed(opts.seed, 1000 + index as u64), None);
    let mut xc = vec![0.0f32; members.len()];
    let norms: Vec<(f64, f64)> =
        xc.par_chunks_mut(d).zip(members.par_chunks(d)).map(|(o, x)| sampled::centre(x, &basis.mean, o)).collect();
    let (weights, _, _) = sampled::solve(&basis, &xc, d, &norms);
    Ok(ClusterFit { q: basis.q, scale: basis.scale, bias: basis.bias, weights })
}

/// Stage 5: the model from the clusters of [`cluster`] and their fits (in cluster order): the
/// local fit's own assembly.
pub use super::assemble;

fn check(opts: &LpcaOptions, height: usize, width: usize) -> Result<()> {
    check_options(opts, height, width)?;
    ensure_arg!(
        opts.reduced_dims > 0,
        "reduced_dims",
        "expected at least 1 for a blockwise fit (0 clusters the full ABRDFs, which needs every value on one machine)"
    );
    Ok(())
}
