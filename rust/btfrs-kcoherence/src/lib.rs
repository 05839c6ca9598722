//! BTF synthesis into a coordinate map: texton analysis, hierarchical k-coherence and the jump map
//! (paper 000, section 4).
//!
//! The synthesis never creates new appearance: every output pixel is a pixel of the sample, so
//! the result is a **coordinate map** into the sample (section 4, "Using large BTFs for
//! rendering") that the renderer follows with one extra lookup. The algorithm only needs a
//! distance between two sample pixels, so it is data independent (section 4.2): a BTF, an RGB
//! texture or any `[H, W, D]` feature image goes through the same code.
//!
//! * [`pyramid`]: the sample pyramid (each level half the resolution of the previous one).
//! * [`textons`]: per-pixel appearance vectors (all images, a representative subset, or a PCA
//!   projection), k-means textons and the texton distance table (section 4.1).
//! * [`analysis`]: the reusable analysis of a sample: textons per pyramid level and the `m` most
//!   similar neighbourhoods of every sample pixel (section 4.2, brute force, parallel).
//! * [`kcoherence`]: hierarchical k-coherence synthesis (section 4.2, Figures 3 and 4).
//! * [`jump_map`]: the jump map (Zelinka and Garland 2002, the paper's reference 19) over the same
//!   analysis: no neighbourhood search at synthesis time.
//! * [`coordmap`]: the coordinate map and the two baselines (plain tiling, random placement).
//! * [`quality`]: measures of a coordinate map against its sample: multi-scale window distances
//!   to the best sample match (`structure`), the same for the windows straddling the map's
//!   discontinuities (`seam_error`), and the older texton-window distance, coherence, pair seams,
//!   repetition.
//! * [`textures`]: photograph-like structured RGB test textures (bricks), seeded, cropped off
//!   their period.

pub mod analysis;
mod analysis_arrays;
pub mod coordmap;
pub mod jump_map;
pub mod kcoherence;
pub mod pyramid;
pub mod quality;
pub mod textons;
pub mod textures;
mod windows;

pub use analysis::{Analysis, AnalysisOptions, Level, Neighbours};
pub use coordmap::CoordMap;
pub use jump_map::{jump_map, JumpOptions};
pub use kcoherence::{kcoherence, SynthOptions};
pub use pyramid::Features;
pub use quality::{quality, Quality, QualityOptions};
pub use textons::{btf_features, FeatureMode, Textons};
