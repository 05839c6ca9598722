//! The wgpu renderer: one render pipeline per model shader, an offscreen float target, read-back.
//!
//! A model is uploaded once ([`upload`]) as its parameter words plus a *store*: its arrays
//! concatenated and split into at most [`MAX_CHUNKS`] storage buffers no larger than the
//! adapter's storage-binding limit (128 MiB on lavapipe), so a 300 MiB raw BTF still binds.
//! [`render`] then draws a mesh with a camera and lights into an `Rgba32Float` target with a
//! `Depth32Float` buffer and reads the image back as `[height][width][3]` f32.

use crate::device::Gpu;
use crate::scene::{Camera, Light, Mesh};
use btfrs_core::process::ProcessId;
use btfrs_core::{Error, Result};
use btfrs_fit::gpu::{GpuModel, Shader, Volume};
use bytemuck::{Pod, Zeroable};
use std::collections::HashMap;
use std::mem::ManuallyDrop;
use std::sync::{Mutex, MutexGuard};
use wgpu::util::DeviceExt;

/// Storage buffers in a model's store (bindings 1..=8 of group 1 in `common.wgsl`).
pub const MAX_CHUNKS: usize = 8;
/// Binding of the optional 3D texture (its sampler is the next binding).
pub(crate) const VOLUME_BINDING: u32 = 11;

const COLOR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Float;
const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

/// `Globals` of common.wgsl (std140-compatible layout, 144 bytes).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable, Debug)]
struct Globals {
    view_proj: [[f32; 4]; 4],
    eye: [f32; 4],
    uv_scale: [f32; 2],
    sample_size: [u32; 2],
    map_size: [u32; 2],
    n_lights: u32,
    chunk_len: u32,
    /// Tile map: (tile side, layout columns, layout rows, atlas width in texels); tile 0 = none.
    tiles: [u32; 4],
    /// Tile map: (atlas offset in the map buffer, 0, 0, 0).
    tile_atlas: [u32; 4],
    /// Filtered lookups: (mode, mip levels, mip table offset in the map buffer, 0).
    lookup: [u32; 4],
}

/// Field names and byte offsets of the Rust `Globals`, and its size: the shader validation test
/// checks them against naga's layout of the WGSL struct (a field added on one side only, or
/// padding that differs, fails there).
pub const GLOBALS_LAYOUT: (&[(&str, usize)], usize) = (
    &[
        ("view_proj", std::mem::offset_of!(Globals, view_proj)),
        ("eye", std::mem::offset_of!(Globals, eye)),
        ("uv_scale", std::mem::offset_of!(Globals, uv_scale)),
        ("sample_size", std::mem::offset_of!(Globals, sample_size)),
        ("map_size", std::mem::offset_of!(Globals, map_size)),
        ("n_lights", std::mem::offset_of!(Globals, n_lights)),
        ("chunk_len", std::mem::offset_of!(Globals, chunk_len)),
        ("tiles", std::mem::offset_of!(Globals, tiles)),
        ("tile_atlas", std::mem::offset_of!(Globals, tile_atlas)),
        ("lookup", std::mem::offset_of!(Globals, lookup)),
    ],
    std::mem::size_of::<Globals>(),
);

/// `Light` of common.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable, Debug)]
pub(crate) struct GpuLight {
    pub(crate) pos: [f32; 4],
    pub(crate) intensity: [f32; 4],
}

/// Interleaved vertex: position, normal, tangent, bitangent, uv.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable, Debug)]
pub(crate) struct Vertex {
    pub(crate) pos: [f32; 3],
    pub(crate) nrm: [f32; 3],
    pub(crate) tan: [f32; 3],
    pub(crate) bit: [f32; 3],
    pub(crate) uv: [f32; 2],
}

/// The interleaved vertices of `mesh`.
pub(crate) fn vertices(mesh: &Mesh) -> Vec<Vertex> {
    (0..mesh.positions.len())
        .map(|i| Vertex {
            pos: mesh.positions[i],
            nrm: mesh.normals[i],
            tan: mesh.tangents[i],
            bit: mesh.bitangents[i],
            uv: mesh.uvs[i],
        })
        .collect()
}

/// The WGSL of a shader: `common.wgsl` followed by the model's file (WGSL has no includes).
/// With `single_chunk`, the store's `load_u32` reads the first buffer directly.
pub fn shader_source(shader: Shader, single_chunk: bool) -> String {
    let common = crate::shaders::COMMON;
    let common = match (single_chunk, common.find("// <load>"), common.find("// </load>")) {
        (true, Some(a), Some(b)) => {
            format!(
                "{}fn load_u32(i: u32) -> u32 {{\n    return s0[i];\n}}\n{}",
                &common[..a],
                &common[b + "// </load>".len()..]
            )
        }
        _ => common.to_string(),
    };
    format!("{common}\n{}\n{}", (shader.params)(), shader.source)
}

/// A model's data on the device.
#[derive(Debug)]
pub struct UploadedModel {
    shader: Shader,
    dims: (usize, usize),
    chunk_len: u32,
    chunks: usize,
    /// Holds the model's buffers and texture (wgpu keeps them alive through it).
    bind_group: ManuallyDrop<wgpu::BindGroup>,
    /// The process that uploaded the model.
    owner: ProcessId,
    /// Bytes of model data on the device: the store, the constants in the uniform block and the
    /// 3D texture.
    pub device_bytes: u64,
}

impl UploadedModel {
    /// The name of the shader that draws it (the model's, or "raw").
    pub fn shader_name(&self) -> &'static str {
        self.shader.name
    }
}

impl Drop for UploadedModel {
    fn drop(&mut self) {
        // In a forked child the device is the parent's, reached through file descriptors the two
        // processes share: freeing the model's buffers from here could free the parent's. Leak
        // them instead (the child's copy of the memory goes when the child exits).
        if self.owner.is_current() {
            // SAFETY: dropped once, here, and never used again.
            unsafe { ManuallyDrop::drop(&mut self.bind_group) }
        }
    }
}

/// The bind group layouts and render pipelines of one device, kept in its [`Gpu`] (so they are
/// dropped with the device and never found by another one).
#[derive(Debug)]
pub(crate) struct Pipelines {
    globals_layout: wgpu::BindGroupLayout,
    model_layout: wgpu::BindGroupLayout,
    by_shader: HashMap<(Shader, bool, &'static str), wgpu::RenderPipeline>,
}

fn storage_entry(binding: u32) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::FRAGMENT,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only: true },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

fn uniform_entry(binding: u32, vis: wgpu::ShaderStages) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: vis,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

/// The layouts and pipelines of `gpu`, created once per device.
fn state(gpu: &Gpu) -> MutexGuard<'_, Pipelines> {
    gpu.pipelines
        .get_or_init(|| {
            let d = &gpu.device;
            let globals_layout = d.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("btfrs globals"),
                entries: &[
                    uniform_entry(0, wgpu::ShaderStages::VERTEX_FRAGMENT),
                    storage_entry(1),
                    storage_entry(2),
                    storage_entry(3),
                ],
            });
            let mut entries = vec![uniform_entry(0, wgpu::ShaderStages::FRAGMENT)];
            entries.extend((1..=MAX_CHUNKS as u32 + 2).map(storage_entry));
            entries.push(wgpu::BindGroupLayoutEntry {
                binding: VOLUME_BINDING,
                visibility: wgpu::ShaderStages::FRAGMENT,
                ty: wgpu::BindingType::Texture {
                    sample_type: wgpu::TextureSampleType::Float { filterable: true },
                    view_dimension: wgpu::TextureViewDimension::D3,
                    multisampled: false,
                },
                count: None,
            });
            entries.push(wgpu::BindGroupLayoutEntry {
                binding: VOLUME_BINDING + 1,
                visibility: wgpu::ShaderStages::FRAGMENT,
                ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                count: None,
            });
            let model_layout = d.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("btfrs model"),
                entries: &entries,
            });
            Mutex::new(Pipelines { globals_layout, model_layout, by_shader: HashMap::new() })
        })
        .lock()
        .unwrap_or_else(|e| e.into_inner())
}

/// Render pipelines built so far on `gpu` (one per shader variant drawn).
pub fn cached_pipelines(gpu: &Gpu) -> usize {
    gpu.pipelines.get().map_or(0, |p| p.lock().unwrap_or_else(|e| e.into_inner()).by_shader.len())
}

fn pipeline(
    gpu: &Gpu,
    st: &mut Pipelines,
    shader: Shader,
    single_chunk: bool,
    entry: &'static str,
) -> Result<wgpu::RenderPipeline> {
    if let Some(p) = st.by_shader.get(&(shader, single_chunk, entry)) {
        return Ok(p.clone());
    }
    let d = &gpu.device;
    let p = gpu.checked(&format!("building the {} pipeline", shader.name), || {
        let module = d.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some(shader.name),
            source: wgpu::ShaderSource::Wgsl(shader_source(shader, single_chunk).into()),
        });
        let layout = d.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("btfrs"),
            bind_group_layouts: &[Some(&st.globals_layout), Some(&st.model_layout)],
            immediate_size: 0,
        });
        let attrs =
            wgpu::vertex_attr_array![0 => Float32x3, 1 => Float32x3, 2 => Float32x3, 3 => Float32x3, 4 => Float32x2];
        d.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some(shader.name),
            layout: Some(&layout),
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some("vs_main"),
                compilation_options: Default::default(),
                buffers: &[wgpu::VertexBufferLayout {
                    array_stride: std::mem::size_of::<Vertex>() as u64,
                    step_mode: wgpu::VertexStepMode::Vertex,
                    attributes: &attrs,
                }],
            },
            primitive: wgpu::PrimitiveState {
                topology: wgpu::PrimitiveTopology::TriangleList,
                cull_mode: None,
                ..Default::default()
            },
            depth_stencil: Some(wgpu::DepthStencilState {
                format: DEPTH_FORMAT,
                depth_write_enabled: Some(true),
                depth_compare: Some(wgpu::CompareFunction::Less),
                stencil: Default::default(),
                bias: Default::default(),
            }),
            multisample: Default::default(),
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                targets: &[Some(wgpu::ColorTargetState {
                    format: COLOR_FORMAT,
                    blend: None,
                    write_mask: wgpu::ColorWrites::ALL,
                })],
            }),
            multiview_mask: None,
            cache: None,
        })
    })?;
    st.by_shader.insert((shader, single_chunk, entry), p.clone());
    Ok(p)
}

/// What a model puts on the device, before any device is involved (shared with the web viewer's
/// [`crate::web`]): its store parts, the parameter words that address them, its measured
/// direction sets with their candidate tables, and its optional 3D texture. `params` is the
/// uniform block: the 16 parameter words, then the model's constants if it has any.
pub(crate) struct Prepared<'a> {
    pub(crate) parts: Vec<std::borrow::Cow<'a, [u32]>>,
    pub(crate) total: usize,
    pub(crate) params: Vec<u32>,
    /// The model's constant words in `params` (after the parameter words; the rest is padding).
    pub(crate) constant_words: usize,
    pub(crate) dirs: Vec<[f32; 4]>,
    pub(crate) tables: Vec<u32>,
    pub(crate) volume: Option<Volume<'a>>,
}

/// Gather [`Prepared`] for `model`.
pub(crate) fn prepare(model: &dyn GpuModel) -> Result<Prepared<'_>> {
    let parts = model.gpu_parts();
    let mut offsets = Vec::with_capacity(parts.len());
    let mut total = 0usize;
    for p in &parts {
        offsets.push(u32::try_from(total).map_err(|_| Error::Device("the model has more than 2^32 values".into()))?);
        total += p.len();
    }
    let (params, constant_words, dirs, tables) = params_at(model, &offsets)?;
    Ok(Prepared { parts, total, params, constant_words, dirs, tables, volume: model.gpu_volume() })
}

/// The uniform block of `model` with its store parts at `offsets` (the 16 parameter words,
/// then its constants padded to the length its shader declares), the count of its constant
/// words, and its direction sets with their candidate tables, as [`prepare`] gathers them.
#[allow(clippy::type_complexity)]
pub(crate) fn params_at(model: &dyn GpuModel, offsets: &[u32]) -> Result<(Vec<u32>, usize, Vec<[f32; 4]>, Vec<u32>)> {
    let sets = model.gpu_dir_sets();
    let mut dirs: Vec<[f32; 4]> = Vec::new();
    let mut tables: Vec<u32> = Vec::new();
    let mut table_at = Vec::with_capacity(sets.len());
    for set in &sets {
        dirs.extend(set.iter().map(|v| [v[0] as f32, v[1] as f32, v[2] as f32, 0.0]));
        table_at.push(tables.len() as u32);
        tables.extend(crate::model::candidate_table(set, crate::model::TABLE_GRID));
    }
    // The parameter block, then the model's constants in the same uniform buffer.
    let mut params = model.gpu_params(offsets, &table_at).to_vec();
    let (mut constants, declared) = (model.gpu_constants(), model.gpu_constants_len());
    if constants.len() > declared {
        return Err(Error::Device(format!(
            "the {} model has {} constant words, more than the {declared} its shader declares",
            model.shader().name,
            constants.len()
        )));
    }
    let constant_words = constants.len();
    constants.resize(declared, 0);
    params.extend(constants);
    Ok((params, constant_words, dirs, tables))
}

/// Upload a model's store and parameters.
pub fn upload(gpu: &Gpu, model: &dyn GpuModel) -> Result<UploadedModel> {
    gpu.check_process()?;
    let Prepared { parts, total, params, constant_words, dirs, tables, volume } = prepare(model)?;
    if let Some(v) = &volume {
        v.validate(gpu.limits.max_texture_dimension_3d)?;
    }
    // Chunks no larger than the binding limit, nor than the largest buffer, and 4-byte aligned.
    let max_binding = gpu.limits.max_storage_buffer_binding_size.min(gpu.limits.max_buffer_size) as usize;
    let chunk_len = (max_binding / 4).clamp(1, u32::MAX as usize);
    let n_chunks = total.div_ceil(chunk_len).max(1);
    if n_chunks > MAX_CHUNKS {
        return Err(Error::Device(format!(
            "the {} model needs {:.0} MiB on the device, more than {MAX_CHUNKS} storage buffers of {:.0} MiB that {} can bind",
            model.shader().name,
            (total * 4) as f64 / 1048576.0,
            max_binding as f64 / 1048576.0,
            gpu.info.name
        )));
    }
    let d = &gpu.device;
    let st = state(gpu);
    gpu.checked("uploading the model", || {
        let chunks: Vec<wgpu::Buffer> = (0..MAX_CHUNKS)
            .map(|c| {
                let len = if c < n_chunks { chunk_len.min(total - c * chunk_len).max(1) } else { 1 };
                d.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("btfrs model store"),
                    size: (len * 4) as u64,
                    usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                })
            })
            .collect();
        // Write each part into the chunks it spans.
        let mut at = 0usize;
        for p in &parts {
            let mut done = 0usize;
            while done < p.len() {
                let pos = at + done;
                let (c, o) = (pos / chunk_len, pos % chunk_len);
                let n = (chunk_len - o).min(p.len() - done);
                gpu.queue.write_buffer(&chunks[c], (o * 4) as u64, bytemuck::cast_slice(&p[done..done + n]));
                done += n;
            }
            at += p.len();
        }
        let pbuf = d.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("btfrs model params"),
            contents: bytemuck::cast_slice(&params),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let dbuf = d.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("btfrs model directions"),
            contents: bytemuck::cast_slice(if dirs.is_empty() { &[[0.0f32; 4]][..] } else { &dirs[..] }),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let tbuf = d.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("btfrs candidate tables"),
            contents: bytemuck::cast_slice(if tables.is_empty() { &[0u32][..] } else { &tables[..] }),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let placeholder = Volume { size: [1, 1, 1], texels: vec![0u8; 4].into() };
        let vol = volume.as_ref().unwrap_or(&placeholder);
        let extent = wgpu::Extent3d { width: vol.size[0], height: vol.size[1], depth_or_array_layers: vol.size[2] };
        let texture = d.create_texture(&wgpu::TextureDescriptor {
            label: Some("btfrs model volume"),
            size: extent,
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D3,
            format: wgpu::TextureFormat::Rgba8Unorm,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        gpu.queue.write_texture(
            wgpu::TexelCopyTextureInfo {
                texture: &texture,
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            &vol.texels,
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(4 * vol.size[0]),
                rows_per_image: Some(vol.size[1]),
            },
            extent,
        );
        let texture_view = texture.create_view(&Default::default());
        // Trilinear within the volume; clamping at the edges (the shader keeps its coordinates
        // inside each block, so neighbouring blocks never bleed in).
        let sampler = d.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("btfrs model volume"),
            address_mode_u: wgpu::AddressMode::ClampToEdge,
            address_mode_v: wgpu::AddressMode::ClampToEdge,
            address_mode_w: wgpu::AddressMode::ClampToEdge,
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            mipmap_filter: wgpu::MipmapFilterMode::Nearest,
            ..Default::default()
        });
        let mut entries = vec![
            wgpu::BindGroupEntry {
                binding: VOLUME_BINDING,
                resource: wgpu::BindingResource::TextureView(&texture_view),
            },
            wgpu::BindGroupEntry { binding: VOLUME_BINDING + 1, resource: wgpu::BindingResource::Sampler(&sampler) },
            wgpu::BindGroupEntry { binding: 0, resource: pbuf.as_entire_binding() },
            wgpu::BindGroupEntry { binding: MAX_CHUNKS as u32 + 1, resource: dbuf.as_entire_binding() },
            wgpu::BindGroupEntry { binding: MAX_CHUNKS as u32 + 2, resource: tbuf.as_entire_binding() },
        ];
        entries.extend(
            chunks
                .iter()
                .enumerate()
                .map(|(i, b)| wgpu::BindGroupEntry { binding: i as u32 + 1, resource: b.as_entire_binding() }),
        );
        let bind_group = d.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("btfrs model"),
            layout: &st.model_layout,
            entries: &entries,
        });
        UploadedModel {
            shader: model.shader(),
            dims: model.gpu_dims(),
            chunk_len: chunk_len as u32,
            chunks: n_chunks,
            bind_group: ManuallyDrop::new(bind_group),
            owner: ProcessId::current(),
            // Measured from what was allocated (the store chunks in use and the 3D texture) and
            // written (the constants in the uniform block, without its parameter words and
            // padding), not from the model's own count, so `nbytes` can be tested against it.
            device_bytes: chunks[..n_chunks].iter().map(|b| b.size()).sum::<u64>()
                + 4 * constant_words as u64
                + volume.as_ref().map_or(0, |_| {
                    texture.width() as u64 * texture.height() as u64 * texture.depth_or_array_layers() as u64 * 4
                }),
        }
    })
}

/// What to draw, besides the model.
#[derive(Debug, Clone, Copy)]
pub struct View<'a> {
    /// The surface.
    pub mesh: &'a Mesh,
    /// The camera.
    pub camera: &'a Camera,
    /// The lights (at least one).
    pub lights: &'a [Light],
    /// Image width in pixels.
    pub width: usize,
    /// Image height in pixels.
    pub height: usize,
    /// Texture repetitions over the UV square.
    pub uv_scale: [f32; 2],
    /// Optional coordinate map: (width, height, entries `x | y << 16`, row 0 at the top).
    pub coords: Option<(usize, usize, &'a [u32])>,
    /// Optional Wang tile map (exclusive with `coords`).
    pub tiles: Option<crate::tilemap::TileMap<'a>>,
    /// Optional filtered lookups with the mip chain of this view's virtual texture (built by
    /// [`crate::filter::MipChain::build`] for the same sample, map or tiles); None = nearest.
    pub filter: Option<(crate::filter::Filter, &'a crate::filter::MipChain)>,
}

/// Times of one frame, in milliseconds.
#[derive(Debug, Clone, Copy, Default)]
pub struct FrameTimes {
    /// Recording, submitting and waiting for the draw.
    pub draw_ms: f64,
    /// Copying the target into a buffer, mapping it and unpacking it.
    pub readback_ms: f64,
}

/// Check a view's sizes against the device and the model.
pub fn validate_view(gpu: &Gpu, view: &View<'_>, dims: (usize, usize)) -> Result<()> {
    let max = gpu.limits.max_texture_dimension_2d as usize;
    if view.width == 0 || view.height == 0 || view.width > max || view.height > max {
        return Err(Error::arg(
            "size",
            format!(
                "expected 1 to {max} pixels per side on {}, got {} x {} (height x width)",
                gpu.info.name, view.height, view.width
            ),
        ));
    }
    crate::cpu::validate_common(view, dims)?;
    // The coordinate map or tile map goes to the GPU as one storage buffer.
    let words = view.tiles.map_or(0, |t| t.layout.len() + t.atlas.len())
        + view.coords.map_or(0, |(_, _, m)| m.len())
        + view.filter.map_or(0, |(_, c)| c.ids.len() + 4 * c.levels.len());
    let limit = gpu.limits.max_storage_buffer_binding_size as usize;
    if words * 4 > limit {
        let what = if view.tiles.is_some() { "tiles" } else { "coords" };
        return Err(Error::arg(
            what,
            format!(
                "the map takes {} bytes; {} binds at most {limit} bytes (render with the CPU backend)",
                words * 4,
                gpu.info.name
            ),
        ));
    }
    Ok(())
}

/// The `Globals` fields that describe a coordinate map or a tile map (zeros for neither).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MapFields {
    /// `map_size`: the coordinate map's (width, height).
    pub map_size: [u32; 2],
    /// `tiles`: (tile side, layout columns, layout rows, atlas width in texels).
    pub tiles: [u32; 4],
    /// `tile_atlas`: (the atlas's offset in the map buffer, 0, 0, 0).
    pub tile_atlas: [u32; 4],
}

impl MapFields {
    /// The fields for a view's map.
    pub fn of(coords: Option<(usize, usize, &[u32])>, tiles: Option<crate::tilemap::TileMap<'_>>) -> Self {
        MapFields {
            map_size: coords.map_or([0, 0], |(mw, mh, _)| [mw as u32, mh as u32]),
            tiles: tiles.map_or([0; 4], |t| {
                [t.tile as u32, t.layout_cols as u32, t.layout_rows as u32, (t.atlas_cols * t.tile) as u32]
            }),
            tile_atlas: [tiles.map_or(0, |t| t.layout.len() as u32), 0, 0, 0],
        }
    }
}

/// The words of the map buffer (group 0, `coord_map`) for a view's map: the tile layout then its
/// atlas, or the coordinate map, or one placeholder word (a storage binding cannot be empty).
pub fn map_words<'a>(
    coords: Option<(usize, usize, &'a [u32])>,
    tiles: Option<crate::tilemap::TileMap<'a>>,
) -> std::borrow::Cow<'a, [u32]> {
    match (tiles, coords) {
        (Some(t), _) => std::borrow::Cow::Owned(t.packed().0),
        (None, Some((_, _, m))) => std::borrow::Cow::Borrowed(m),
        (None, None) => std::borrow::Cow::Owned(vec![0]),
    }
}

/// Render `model` (uploaded with [`upload`]) into a `[height][width][3]` image.
pub fn render(gpu: &Gpu, model: &UploadedModel, view: &View<'_>) -> Result<(Vec<f32>, FrameTimes)> {
    validate_view(gpu, view, model.dims)?;
    let filtered = view.filter.is_some_and(|(f, _)| f != crate::filter::Filter::Nearest);
    draw(gpu, model, view, &[[0.0; 4]], if filtered { "fs_filtered" } else { "fs_main" })
}

/// Render a double-SH model (uploaded with [`upload`]) under the environment `env` by the SH
/// method ([`crate::sh_env`]; `fs_env` of sh.wgsl). `view.lights` is not used (it may be empty).
pub fn render_env_sh(
    gpu: &Gpu,
    model: &UploadedModel,
    view: &View<'_>,
    env: &crate::sh_env::ShEnvironment,
) -> Result<(Vec<f32>, FrameTimes)> {
    // The SH method is the shader's own entry point (`fs_env`), which only shaders of models
    // with an SH expansion define.
    if !model.shader.source.contains("fn fs_env(") {
        return Err(Error::arg(
            "lighting",
            format!(
                "the SH environment method needs a double-SH model, not {} (use lighting=\"sampled\")",
                model.shader.name
            ),
        ));
    }
    let placeholder = [crate::scene::Light::Directional { direction: [0.0, 0.0, 1.0], intensity: [0.0; 3] }];
    let v = View { lights: &placeholder, ..*view };
    validate_view(gpu, &v, model.dims)?;
    draw(gpu, model, &View { lights: &[], ..*view }, &env.gpu_words(), "fs_env")
}

fn draw(
    gpu: &Gpu,
    model: &UploadedModel,
    view: &View<'_>,
    env_words: &[[f32; 4]],
    entry: &'static str,
) -> Result<(Vec<f32>, FrameTimes)> {
    gpu.check_process()?;
    let d = &gpu.device;
    let mut st = state(gpu);
    let pipe = pipeline(gpu, &mut st, model.shader, model.chunks == 1, entry)?;
    let (w, h) = (view.width as u32, view.height as u32);
    let t0 = std::time::Instant::now();
    let filter = view.filter.filter(|(f, _)| *f != crate::filter::Filter::Nearest);
    let base_map_len = view.tiles.map_or(0, |t| (t.layout.len() + t.atlas.len()) as u32)
        + view.coords.map_or(0, |(_, _, m)| m.len() as u32)
        + (view.tiles.is_none() && view.coords.is_none()) as u32;
    let out = gpu.checked("rendering", || {
        let vp = view.camera.view_proj(view.width as f32 / view.height as f32);
        let m = MapFields::of(view.coords, view.tiles);
        let globals = Globals {
            view_proj: vp.to_cols_array_2d(),
            eye: [view.camera.eye[0], view.camera.eye[1], view.camera.eye[2], 1.0],
            uv_scale: view.uv_scale,
            sample_size: [model.dims.1 as u32, model.dims.0 as u32],
            map_size: m.map_size,
            n_lights: view.lights.len() as u32,
            chunk_len: model.chunk_len,
            tiles: m.tiles,
            tile_atlas: m.tile_atlas,
            lookup: filter.map_or([0; 4], |(f, c)| [f.mode(), c.levels.len() as u32, base_map_len, 0]),
        };
        let mut lights: Vec<GpuLight> = view
            .lights
            .iter()
            .map(|l| match *l {
                Light::Point { position: p, intensity: i } => {
                    GpuLight { pos: [p[0], p[1], p[2], 1.0], intensity: [i[0], i[1], i[2], 0.0] }
                }
                Light::Directional { direction: p, intensity: i } => {
                    // Normalised here as Light::at does for the CPU (validate() rejects zero).
                    let p = glam::Vec3::from(p).normalize().to_array();
                    GpuLight { pos: [p[0], p[1], p[2], 0.0], intensity: [i[0], i[1], i[2], 0.0] }
                }
            })
            .collect();
        if lights.is_empty() {
            lights.push(GpuLight::zeroed()); // a storage binding cannot be empty
        }
        let base_map = map_words(view.coords, view.tiles);
        let base_map: &[u32] = &base_map;
        // The mip chain of a filtered view follows the map in the same buffer.
        let with_mips: Vec<u32>;
        let map: &[u32] = match filter {
            Some((_, chain)) => {
                with_mips = [base_map, &chain.gpu_words(base_map.len() as u32)].concat();
                &with_mips
            }
            None => base_map,
        };
        let gbuf = d.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("globals"),
            contents: bytemuck::bytes_of(&globals),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let lbuf = d.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("lights"),
            contents: bytemuck::cast_slice(&lights),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let mbuf = d.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("coordinate map"),
            contents: bytemuck::cast_slice(map),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let ebuf = d.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("environment"),
            contents: bytemuck::cast_slice(env_words),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let globals_bg = d.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("globals"),
            layout: &st.globals_layout,
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: gbuf.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 1, resource: lbuf.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 2, resource: mbuf.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 3, resource: ebuf.as_entire_binding() },
            ],
        });
        let verts = vertices(view.mesh);
        let vbuf = d.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("vertices"),
            contents: bytemuck::cast_slice(&verts),
            usage: wgpu::BufferUsages::VERTEX,
        });
        let ibuf = d.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("indices"),
            contents: bytemuck::cast_slice(&view.mesh.indices),
            usage: wgpu::BufferUsages::INDEX,
        });
        let size = wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 };
        let target = d.create_texture(&wgpu::TextureDescriptor {
            label: Some("target"),
            size,
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: COLOR_FORMAT,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
            view_formats: &[],
        });
        let depth = d.create_texture(&wgpu::TextureDescriptor {
            label: Some("depth"),
            size,
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: DEPTH_FORMAT,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
            view_formats: &[],
        });
        let tview = target.create_view(&Default::default());
        let dview = depth.create_view(&Default::default());
        let mut enc = d.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("btfrs frame") });
        {
            let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("btfrs frame"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &tview,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &dview,
                    depth_ops: Some(wgpu::Operations { load: wgpu::LoadOp::Clear(1.0), store: wgpu::StoreOp::Discard }),
                    stencil_ops: None,
                }),
                ..Default::default()
            });
            pass.set_pipeline(&pipe);
            pass.set_bind_group(0, &globals_bg, &[]);
            pass.set_bind_group(1, &*model.bind_group, &[]);
            pass.set_vertex_buffer(0, vbuf.slice(..));
            pass.set_index_buffer(ibuf.slice(..), wgpu::IndexFormat::Uint32);
            pass.draw_indexed(0..view.mesh.indices.len() as u32, 0, 0..1);
        }
        gpu.queue.submit([enc.finish()]);
        target
    })?;
    let _ = d.poll(wgpu::PollType::wait_indefinitely());
    let draw_ms = t0.elapsed().as_secs_f64() * 1e3;
    let t1 = std::time::Instant::now();
    let img = read_back(gpu, &out, w, h)?;
    let readback_ms = t1.elapsed().as_secs_f64() * 1e3;
    Ok((img, FrameTimes { draw_ms, readback_ms }))
}

/// Copy an `Rgba32Float` texture into host memory as `[h][w][3]` (alpha dropped).
fn read_back(gpu: &Gpu, tex: &wgpu::Texture, w: u32, h: u32) -> Result<Vec<f32>> {
    Ok(read_back_rgba(gpu, tex, w, h)?.into_iter().flat_map(|p| [p[0], p[1], p[2]]).collect())
}

/// Copy an `Rgba32Float` texture (with `COPY_SRC` usage) into host memory, row 0 first, waiting
/// for all submitted work that writes it.
pub fn read_back_rgba(gpu: &Gpu, tex: &wgpu::Texture, w: u32, h: u32) -> Result<Vec<[f32; 4]>> {
    let d = &gpu.device;
    // Rows of a texture-to-buffer copy must be padded to 256 bytes.
    let row = w * 16;
    let padded = row.div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT) * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
    let buf = gpu.checked("reading the image back", || {
        let buf = d.create_buffer(&wgpu::BufferDescriptor {
            label: Some("read-back"),
            size: padded as u64 * h as u64,
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        let mut enc = d.create_command_encoder(&Default::default());
        enc.copy_texture_to_buffer(
            wgpu::TexelCopyTextureInfo {
                texture: tex,
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            wgpu::TexelCopyBufferInfo {
                buffer: &buf,
                layout: wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(padded), rows_per_image: Some(h) },
            },
            wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 },
        );
        gpu.queue.submit([enc.finish()]);
        buf
    })?;
    let slice = buf.slice(..);
    let (tx, rx) = std::sync::mpsc::channel();
    slice.map_async(wgpu::MapMode::Read, move |r| {
        let _ = tx.send(r);
    });
    d.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| Error::Device(format!("waiting for the GPU: {e}")))?;
    rx.recv()
        .map_err(|_| Error::Device("the read-back was dropped".into()))?
        .map_err(|e| Error::Device(format!("mapping the read-back buffer: {e}")))?;
    let data = slice.get_mapped_range();
    let mut img = Vec::with_capacity((w * h) as usize);
    for y in 0..h as usize {
        let r: &[f32] = bytemuck::cast_slice(&data[y * padded as usize..y * padded as usize + row as usize]);
        img.extend(r.chunks_exact(4).map(|p| [p[0], p[1], p[2], p[3]]));
    }
    drop(data);
    buf.unmap();
    Ok(img)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::device::AdapterChoice;
    use btfrs_core::materials::{generate, MaterialSpec, Preset};
    use btfrs_core::Monitor;

    /// Devices opened and dropped one after the other at the same address (which the old
    /// address-keyed cache mistook for the same device, handing the second one the dropped
    /// device's pipelines): each starts with no pipelines, builds its own and draws the same
    /// image.
    #[test]
    fn each_device_has_its_own_pipelines() {
        let mut spec = MaterialSpec::new(Preset::Bumps, 8, 1);
        spec.views = btfrs_core::directions::ubo81().into_iter().step_by(9).collect();
        let btf = generate(&spec, &Monitor::new()).unwrap();
        let ptm = btfrs_fit::fit_ptm(&btf.as_ref(), &Default::default(), &Monitor::new()).unwrap();
        let (mesh, cam) = (Mesh::plane(2.0), Camera::look_at([0.0, -2.0, 2.0], [0.0; 3], 45.0).unwrap());
        let lights = [Light::Point { position: [1.0, -1.0, 2.0], intensity: [4.0; 3] }];
        let view = View {
            mesh: &mesh,
            camera: &cam,
            lights: &lights,
            width: 16,
            height: 16,
            uv_scale: [1.0; 2],
            coords: None,
            tiles: None,
            filter: None,
        };
        let mut images = Vec::new();
        for _ in 0..3 {
            // By value: each iteration's device sits in the same stack slot, at the same address.
            let gpu = Gpu::new(&AdapterChoice::Cpu).expect("lavapipe (apt-get install mesa-vulkan-drivers)");
            assert_eq!(cached_pipelines(&gpu), 0, "a new device must not find another device's pipelines");
            let up = upload(&gpu, &ptm).unwrap();
            images.push(render(&gpu, &up, &view).unwrap().0);
            assert_eq!(cached_pipelines(&gpu), 1);
            render(&gpu, &up, &view).unwrap();
            assert_eq!(cached_pipelines(&gpu), 1, "the second frame reuses the pipeline");
        }
        assert!(images[0].iter().any(|&x| x > 0.0), "nothing drawn");
        assert!(images.iter().all(|im| im == &images[0]));
    }
}
