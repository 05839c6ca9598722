//! btfrs-render: rendering BTF models onto surfaces, on the GPU with wgpu and on the CPU.
//!
//! * [`device`]: the headless wgpu device (a real GPU, else Mesa's lavapipe; `BTFRS_ADAPTER`).
//! * [`scene`]: meshes (plane, sphere, cylinder, indexed triangle meshes) whose per-vertex
//!   tangent frames follow the UV parameterisation (paper 002, section 4.2), a perspective
//!   camera, point and directional lights.
//! * [`gpu`]: one render pipeline per model shader (`shaders_wgsl/`), model upload, read-back.
//! * [`model`]: what the renderer derives from a model's GPU layout (candidate tables of its
//!   direction sets); the layouts themselves live with the models (`btfrs_fit::gpu`), so the
//!   renderer never names a model.
//! * [`raster`] and [`cpu`]: the CPU reference renderer, which shades the same points with the
//!   same formulas, so every shader is tested against it.
//! * [`usage`]: what a scene asks of a BTF (per-pixel local view and light directions, texel
//!   footprint), for `btfrs.choose`.
//! * Coordinate maps (paper 000, section 5): an optional map of u16 (x, y) texel coordinates
//!   applied as one extra lookup, for synthesised BTFs of any size.
//! * [`environment`] and [`sh_env`]: distant environment light (paper 002, section 4), as
//!   importance-sampled directional lights for every model and in the SH domain for double-SH
//!   models.
//! * [`filter`]: bilinear and trilinear lookups through the sample, coordinate maps and tile
//!   maps (appearance-medoid mip levels), the same on both renderers.
//! * [`tilemap`]: Wang tile maps (paper 002, section 4): a layout of atlas tiles, two lookups.

pub mod cpu;
pub mod device;
pub mod environment;
pub mod filter;
pub mod gpu;
pub mod model;
pub mod raster;
pub mod scene;
pub mod sh_env;
pub mod shaders;
pub mod tilemap;
pub mod usage;
pub mod web;

pub use device::{AdapterChoice, Gpu};
pub use gpu::{render, upload, FrameTimes, UploadedModel, View};
pub use model::{GpuModel, Shader, WithShader};
pub use tilemap::TileMap;
