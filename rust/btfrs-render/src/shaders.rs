//! The WGSL sources, embedded at build time from `shaders_wgsl/` at the repository root.

/// Shared structures, bindings, interpolation, texel addressing, vertex and fragment stages.
pub const COMMON: &str = include_str!("../../../shaders_wgsl/common.wgsl");
/// Polynomial Texture Maps.
pub const PTM: &str = include_str!("../../../shaders_wgsl/ptm.wgsl");
/// The raw BTF, interpolated between measured directions.
pub const RAW: &str = include_str!("../../../shaders_wgsl/raw.wgsl");
/// Phong + spatially-varying residual function.
pub const SRF: &str = include_str!("../../../shaders_wgsl/srf.wgsl");
