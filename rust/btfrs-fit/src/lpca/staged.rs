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

use super::{check_options, sub_seed, ClusterFit, LpcaOptions};
use btfrs_core::{ensure_arg, Monitor, Result};
use btfrs_numerics::rpca;
use nalgebra::DMatrix;

/// The options of a staged fit, given as JSON (checked against the LPCA schema).
pub fn parse_options(json: &str) -> Result<LpcaOptions> {
    crate::options::parse(<super::Lpca as crate::model::Model>::OPTIONS, json)
}

/// Stage 1a: the texels whose ABRDFs [`subspace`] needs (`None`: every texel) for a
/// `height x width` BTF.
pub fn sample(height: usize, width: usize, opts: &LpcaOptions) -> Result<Option<Vec<u32>>> {
    check(opts, height, width)?;
    Ok(rpca::sample_texels(height * width, sub_seed(opts.seed, 1)))
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
    rpca::sample_subspace(sample, d, height * width, opts.reduced_dims, sub_seed(opts.seed, 1), monitor)
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
    let (space, dim) = rpca::principal_axes(z, opts.reduced_dims);
    super::cluster_space(&space, dim, t, opts, monitor)
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
