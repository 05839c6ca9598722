//! A sample of a capture's texels as short runs spread over the frame: what the neural decoder
//! trains on ([`crate::neural`]) and what the light bases' principal functions are computed
//! from on large captures ([`crate::light_pca`]).
//!
//! The sample is runs of [`RUN`] consecutive texels, one at a random place in each of as many
//! equal stretches of the texels: spread over the whole frame (no region is missed, and the
//! random offsets keep the runs from lining up with a pattern of the image), and read from a
//! memory-mapped file as short sequential stretches, not as scattered pages.

use btfrs_core::rng::{mix, Rng};

/// Consecutive texels per run of the sample.
pub const RUN: usize = 64;

/// The texels of a sample of `n` of `t`: runs of [`RUN`] consecutive texels, one at a random
/// place in each of `n / RUN` equal stretches, in increasing order (every texel when `n >= t`).
pub fn sample_texels(t: usize, n: usize, seed: u64) -> Vec<usize> {
    if n >= t {
        return (0..t).collect();
    }
    let run = RUN.min(n).max(1);
    let runs = (n / run).max(1);
    let stretch = t / runs;
    let mut rng = Rng::new(mix(seed ^ 0x5a3b1e));
    let mut out = Vec::with_capacity(runs * run);
    for i in 0..runs {
        let start = i * stretch + rng.below(stretch - run + 1);
        out.extend(start..start + run);
    }
    out
}
