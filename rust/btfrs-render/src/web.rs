//! What a WebGPU page needs to draw a model exactly as [`crate::gpu`] does: the same WGSL
//! (`common.wgsl`, the model's generated `Params` struct and its own file, assembled by
//! [`crate::gpu::shader_source`]), the same words in the same buffers, and a description of every
//! layout the page must agree on (uniform structs, bindings, vertex attributes) generated from
//! the Rust types, so the JavaScript viewer holds no offset of its own.
//!
//! The browser binds the store as one buffer (WebGPU guarantees 128 MiB per binding and most
//! adapters allow far more), so the single-chunk variant of the shader is used: its `load_u32`
//! reads `s0` only, and the seven other chunk bindings, unused, are left out of the layout (which
//! keeps the page within WebGPU's default of 8 storage buffers per stage).

use crate::gpu::{shader_source, GpuLight, Vertex, GLOBALS_LAYOUT, MAX_CHUNKS};
use crate::scene::Mesh;
use btfrs_core::{Error, Result};
use btfrs_fit::gpu::GpuModel;
use serde_json::{json, Value};

/// A model ready for the page: every buffer as little-endian words, and the shader.
#[derive(Debug, Clone)]
pub struct WebModel {
    /// The assembled WGSL (single-chunk store).
    pub shader: String,
    /// The model's uniform block (`Params`, group 1 binding 0): its 16 parameter words, then
    /// its constants if it has any.
    pub params: Vec<u32>,
    /// The store: the model's arrays concatenated (group 1 binding 1, `s0`).
    pub store: Vec<u32>,
    /// The measured direction sets as `vec4<f32>` (group 1 binding 9).
    pub dirs: Vec<[f32; 4]>,
    /// The candidate tables of the direction sets (group 1 binding 10).
    pub tables: Vec<u32>,
    /// The optional RGBA8 3D texture: (width, height, depth) and its bytes (group 1 binding 11).
    pub volume: Option<([u32; 3], Vec<u8>)>,
    /// The store's length in words, the `chunk_len` the shader divides by.
    pub chunk_len: u32,
}

/// Gather a model's GPU data as [`crate::gpu::upload`] does, for the page.
pub fn web_model(model: &dyn GpuModel) -> Result<WebModel> {
    let prepared = crate::gpu::prepare(model)?;
    let store: Vec<u32> = prepared.parts.iter().flat_map(|p| p.iter().copied()).collect();
    if store.len() as u64 * 4 > 1 << 31 {
        return Err(Error::arg(
            "model",
            format!(
                "the model needs {} MiB in one storage buffer; the viewer binds at most 2 GiB",
                store.len() / 262144
            ),
        ));
    }
    let chunk_len = store.len().max(1) as u32;
    Ok(WebModel {
        shader: shader_source(model.shader(), true),
        params: prepared.params,
        dirs: if prepared.dirs.is_empty() { vec![[0.0; 4]] } else { prepared.dirs },
        tables: if prepared.tables.is_empty() { vec![0] } else { prepared.tables },
        volume: prepared.volume.map(|v| (v.size, v.texels.into_owned())),
        store: if store.is_empty() { vec![0] } else { store },
        chunk_len,
    })
}

/// A coordinate map or a Wang tile map for the page: the map buffer's words (group 0,
/// `coord_map`) and the `Globals` fields that describe it, as the native renderer fills them.
#[derive(Debug, Clone)]
pub struct WebMap {
    /// The map buffer (the tile layout then its atlas, or the coordinate map).
    pub words: Vec<u32>,
    /// The `Globals` fields `map_size`, `tiles` and `tile_atlas`.
    pub fields: crate::gpu::MapFields,
}

/// Check a map against a model of `dims` (height, width) texels and lay it out for the page.
pub fn web_map(
    coords: Option<(usize, usize, &[u32])>,
    tiles: Option<crate::tilemap::TileMap<'_>>,
    dims: (usize, usize),
) -> Result<WebMap> {
    if coords.is_none() && tiles.is_none() {
        return Err(Error::arg("coords", "expected a coordinate map or a tile map"));
    }
    crate::cpu::validate_map(coords, tiles, dims)?;
    let words = crate::gpu::map_words(coords, tiles).into_owned();
    if words.len() as u64 * 4 > 1 << 27 {
        // WebGPU's guaranteed storage binding size (128 MiB).
        let what = if tiles.is_some() { "tiles" } else { "coords" };
        return Err(Error::arg(
            what,
            format!("the map takes {} MiB; the viewer binds at most 128 MiB", words.len() / 262144),
        ));
    }
    Ok(WebMap { words, fields: crate::gpu::MapFields::of(coords, tiles) })
}

/// A mesh as the page's vertex buffer (the interleaved layout of [`layout`]) and its indices.
pub fn mesh_buffers(mesh: &Mesh) -> (Vec<u8>, Vec<u32>) {
    let v = crate::gpu::vertices(mesh);
    (bytemuck::cast_slice(&v).to_vec(), mesh.indices.clone())
}

/// Every layout the page must agree on with the shader, from the Rust structs: the `Globals`
/// uniform and `Light` fields (byte offsets, sizes), the vertex attributes, the bind groups
/// (binding, kind), the entry points and the formats of the offscreen targets.
pub fn layout() -> Value {
    let (fields, size) = GLOBALS_LAYOUT;
    let light = std::mem::size_of::<GpuLight>();
    let vertex = std::mem::size_of::<Vertex>();
    json!({
        "globals": {"size": size, "fields": fields.iter().map(|(n, o)| json!({"name": n, "offset": o})).collect::<Vec<_>>()},
        "light": {"size": light, "fields": [
            {"name": "pos", "offset": std::mem::offset_of!(GpuLight, pos), "note": "w = 1 point light at xyz, w = 0 directional towards xyz"},
            {"name": "intensity", "offset": std::mem::offset_of!(GpuLight, intensity)},
        ]},
        "vertex": {"stride": vertex, "attributes": [
            {"location": 0, "offset": std::mem::offset_of!(Vertex, pos), "format": "float32x3", "name": "position"},
            {"location": 1, "offset": std::mem::offset_of!(Vertex, nrm), "format": "float32x3", "name": "normal"},
            {"location": 2, "offset": std::mem::offset_of!(Vertex, tan), "format": "float32x3", "name": "tangent"},
            {"location": 3, "offset": std::mem::offset_of!(Vertex, bit), "format": "float32x3", "name": "bitangent"},
            {"location": 4, "offset": std::mem::offset_of!(Vertex, uv), "format": "float32x2", "name": "uv"},
        ]},
        "bindings": {
            "0": [
                {"binding": 0, "kind": "uniform", "name": "globals"},
                {"binding": 1, "kind": "read-only-storage", "name": "lights"},
                {"binding": 2, "kind": "read-only-storage", "name": "coord_map"},
                {"binding": 3, "kind": "read-only-storage", "name": "env"},
            ],
            "1": [
                {"binding": 0, "kind": "uniform", "name": "params"},
                {"binding": 1, "kind": "read-only-storage", "name": "store"},
                {"binding": MAX_CHUNKS + 1, "kind": "read-only-storage", "name": "dirs"},
                {"binding": MAX_CHUNKS + 2, "kind": "read-only-storage", "name": "tables"},
                {"binding": crate::gpu::VOLUME_BINDING, "kind": "texture-3d", "name": "volume",
                 "sample_type": "float", "view_dimension": "3d", "format": "rgba8unorm"},
                {"binding": crate::gpu::VOLUME_BINDING + 1, "kind": "sampler", "name": "volume_sampler",
                 "filter": "linear", "address": "clamp-to-edge"},
            ],
        },
        "entry": {"vertex": "vs_main", "fragment": "fs_main"},
        "targets": {"color": "rgba32float", "depth": "depth32float", "depth_compare": "less", "cull": "none",
                    "clear": [0.0, 0.0, 0.0, 1.0]},
        "camera": "view_proj = perspective_rh(fov_y, aspect, near, far) * look_at_rh(eye, target, up), glam's \
                   right-handed matrices with depth in [0, 1], column-major",
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_layout_names_every_globals_field_and_the_vertex_fits_its_stride() {
        let l = layout();
        let fields = l["globals"]["fields"].as_array().unwrap();
        assert_eq!(fields.len(), GLOBALS_LAYOUT.0.len());
        assert_eq!(l["vertex"]["stride"], 56);
        let last = l["vertex"]["attributes"].as_array().unwrap().last().unwrap()["offset"].as_u64().unwrap();
        assert_eq!(last + 8, 56);
        let (v, i) = mesh_buffers(&Mesh::plane(2.0));
        assert_eq!((v.len(), i.len()), (4 * 56, 6));
    }
}
