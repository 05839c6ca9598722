//! The shared WGSL, embedded at build time from `shaders_wgsl/` at the repository root. Each
//! model's own file is embedded by the model (its `GpuLayout::SHADER`), next to its parameter
//! struct.

/// Shared structures, bindings, interpolation, texel addressing, vertex and fragment stages.
pub const COMMON: &str = include_str!("../../../shaders_wgsl/common.wgsl");
