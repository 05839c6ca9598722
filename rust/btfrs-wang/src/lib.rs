//! btfrs-wang: tileable BTFs, the graph-cut Wang BTF tile sets of paper 002 (section 3.2
//! synthesis, 4.1 tiling, 5.3 storage, Table III), in any per-texel domain.
//!
//! * [`features`]: the synthesis domain: per-texel feature vectors whose squared distance
//!   stands for the BTF-space distance (SH coefficients, Gram-whitened PTM coefficients, a
//!   decoded probe set for every model, RGB).
//! * [`fill`]: graph-cut patch filling (Kwatra et al. 2003) with old seams, per-pixel error and
//!   thresholds, over the max-flow of `btfrs-graphcut`.
//! * [`tiles`]: the four steps: corner sampling, edge synthesis, frame construction, interior
//!   synthesis.
//! * [`table`]: the BTFel table, per-tile index arrays, the canonical atlas arrangement.
//! * [`tiling`]: stochastic Wang tilings, with wrap-around and tile subsets, and their check.
//! * [`seams`]: neighbourhood error across tile edges against inside tiles.

pub mod features;
pub mod fill;
pub mod seams;
pub mod table;
pub mod tiles;
pub mod tiling;

pub use features::{FeatureOps, Features};
pub use table::Table;
pub use tiles::{synthesize, WangOptions, WangTiles};
