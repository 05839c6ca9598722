//! The WGSL sources, embedded at build time from `shaders_wgsl/` at the repository root.

/// Shared structures, bindings, interpolation, texel addressing, vertex and fragment stages.
pub const COMMON: &str = include_str!("../../../shaders_wgsl/common.wgsl");
/// Polynomial Texture Maps.
pub const PTM: &str = include_str!("../../../shaders_wgsl/ptm.wgsl");
/// The raw BTF, interpolated between measured directions.
pub const RAW: &str = include_str!("../../../shaders_wgsl/raw.wgsl");
/// Phong + spatially-varying residual function.
pub const SRF: &str = include_str!("../../../shaders_wgsl/srf.wgsl");
/// Per-texel Lafortune lobes.
pub const LAFORTUNE: &str = include_str!("../../../shaders_wgsl/lafortune.wgsl");
/// Double spherical harmonics, 8-bit coefficients.
pub const SH: &str = include_str!("../../../shaders_wgsl/sh.wgsl");
/// Local PCA, nine lookups per Eigen-BRDF (paper 004, section 5).
pub const LPCA_9TAP: &str = include_str!("../../../shaders_wgsl/lpca_9tap.wgsl");
/// Local PCA from one 3D texture (paper 004, section 6).
pub const LPCA_3D: &str = include_str!("../../../shaders_wgsl/lpca_3d.wgsl");
