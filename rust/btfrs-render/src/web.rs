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

/// A part of a tiled page's store: per texel, `bytes` bytes, byte `j` being plane `from[j]`
/// of the image (plane `p` = channel `p % 3` of image `p / 3`), texel-major from word `offset`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TexelPart {
    /// Word offset of the part in the store.
    pub offset: u32,
    /// Bytes per texel.
    pub bytes: u32,
    /// The plane of each byte.
    pub from: Vec<u32>,
}

/// What a page drawing a model from image tiles needs: the model of a window of at most
/// `capacity` texels (any width and height with `width * height <= capacity`) has this store
/// layout and these parameters, whatever the window shows; its texel parts are filled from the
/// tiles' bytes by [`TexelPart`]s, its other parts are the same for every window.
#[derive(Debug, Clone)]
pub struct WebWindow {
    /// The assembled WGSL (single-chunk store).
    pub shader: String,
    /// The uniform block for a store laid out for `capacity` texels.
    pub params: Vec<u32>,
    /// The parts every window shares: (word offset, words).
    pub constants: Vec<(u32, Vec<u32>)>,
    /// The parts filled per window.
    pub texels: Vec<TexelPart>,
    /// Store words in all.
    pub store_words: u32,
    /// Texels a window may hold.
    pub capacity: u32,
    /// The measured direction sets (as [`WebModel::dirs`]).
    pub dirs: Vec<[f32; 4]>,
    /// Their candidate tables.
    pub tables: Vec<u32>,
}

/// Probe models for [`web_window`]: each the model a folder's index file makes from plane bytes
/// of `texels` texels (`planes`, texel-major, `nplanes` per texel).
#[allow(missing_debug_implementations)]
pub struct Probe<'a> {
    /// The model.
    pub model: &'a dyn GpuModel,
    /// Its plane bytes.
    pub planes: &'a [u8],
    /// Its texel count.
    pub texels: usize,
}

/// The window layout of a model family from probes: models made from random plane bytes (two of
/// one texel count, one of another, each a multiple of 4). Found from the probes alone, with no
/// knowledge of the model: a store part whose length and words are the same in every probe is
/// shared; one whose length grows with the texels must hold, for each texel, the same plane
/// bytes in the same order in every probe (found by matching the bytes, which random planes make
/// unambiguous), else the model cannot be drawn from tiles and the error says so.
pub fn web_window(probes: &[Probe<'_>], nplanes: usize, capacity: usize) -> Result<WebWindow> {
    let not = |why: String| Error::arg("tiles", format!("this model cannot be drawn from image tiles: {why}"));
    if probes.len() < 3 || probes.iter().any(|p| p.texels == 0 || p.texels % 4 != 0) {
        return Err(Error::arg("probes", "expected three probes or more, each of a multiple of 4 texels"));
    }
    if probes.iter().all(|p| p.texels == probes[0].texels) {
        return Err(Error::arg("probes", "expected probes of two texel counts"));
    }
    for p in probes {
        if p.planes.len() != p.texels * nplanes {
            return Err(Error::arg(
                "probes",
                format!("expected {} plane bytes, got {}", p.texels * nplanes, p.planes.len()),
            ));
        }
    }
    let prepared = probes.iter().map(|p| crate::gpu::prepare(p.model)).collect::<Result<Vec<_>>>()?;
    let first = &prepared[0];
    if prepared.iter().any(|q| q.parts.len() != first.parts.len() || q.dirs != first.dirs || q.tables != first.tables) {
        return Err(not("its store's parts or direction sets change with the plane bytes".into()));
    }
    if first.volume.is_some() {
        return Err(not("it samples a 3D texture".into()));
    }
    let bytes_of = |words: &[u32]| -> Vec<u8> { words.iter().flat_map(|w| w.to_le_bytes()).collect() };
    let mut lengths = Vec::new();
    let mut constants = Vec::new();
    let mut texels = Vec::new();
    for i in 0..first.parts.len() {
        let same = prepared.iter().all(|q| q.parts[i] == first.parts[i]);
        if same {
            lengths.push(first.parts[i].len());
            constants.push((i, first.parts[i].to_vec()));
            continue;
        }
        // A texel part: R bytes per texel, texel-major.
        let r = 4 * first.parts[i].len() / probes[0].texels;
        let ok = r > 0 && probes.iter().zip(&prepared).all(|(p, q)| q.parts[i].len() * 4 == p.texels * r);
        if !ok {
            return Err(not(format!(
                "store part {i} changes with the planes but is not a fixed number of bytes per texel"
            )));
        }
        let bytes: Vec<Vec<u8>> = prepared.iter().map(|q| bytes_of(&q.parts[i])).collect();
        let mut from = Vec::with_capacity(r);
        for j in 0..r {
            let plane = (0..nplanes).find(|&pl| {
                probes
                    .iter()
                    .zip(&bytes)
                    .all(|(p, b)| (0..p.texels).all(|t| b[t * r + j] == p.planes[t * nplanes + pl]))
            });
            match plane {
                Some(pl) => from.push(pl as u32),
                None => {
                    return Err(not(format!(
                        "byte {j} of each texel's {r} in store part {i} is not one of the image's planes"
                    )))
                }
            }
        }
        lengths.push((capacity * r).div_ceil(4));
        texels.push((i, r, from));
    }
    let mut offsets = Vec::with_capacity(lengths.len());
    let mut total = 0usize;
    for l in &lengths {
        offsets.push(u32::try_from(total).map_err(|_| not("its window store passes 2^32 words".into()))?);
        total += l;
    }
    if total as u64 * 4 > 1 << 31 {
        return Err(Error::arg(
            "capacity",
            format!(
                "a window of {capacity} texels needs {} MiB in one storage buffer; the viewer binds at most 2 GiB",
                total / 262144
            ),
        ));
    }
    let (params, _, dirs, tables) = crate::gpu::params_at(probes[0].model, &offsets)?;
    // Parameters that depend on the texel count other than through the offsets: not tileable.
    for p in &probes[1..] {
        if crate::gpu::params_at(p.model, &offsets)?.0 != params {
            return Err(not("its parameters change with the size of the image".into()));
        }
    }
    Ok(WebWindow {
        shader: shader_source(probes[0].model.shader(), true),
        params,
        constants: constants.into_iter().map(|(i, w)| (offsets[i], w)).collect(),
        texels: texels
            .into_iter()
            .map(|(i, r, from)| TexelPart { offset: offsets[i], bytes: r as u32, from })
            .collect(),
        store_words: total.max(1) as u32,
        capacity: capacity as u32,
        dirs: if dirs.is_empty() { vec![[0.0; 4]] } else { dirs },
        tables: if tables.is_empty() { vec![0] } else { tables },
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
    use btfrs_fit::gpu::{pack_u8, GpuParams, Shader};
    use std::borrow::Cow;

    btfrs_fit::gpu_params! {
        /// A mock model's parameters: the offsets of its parts.
        pub struct MockParams {
            /// Store offset of the shared words.
            pub head: u32,
            /// Store offset of the texel bytes.
            pub texels: u32,
            /// Store offset of the tail.
            pub tail: u32,
        }
    }

    /// A model whose store is shared words, each texel's plane bytes in a fixed order (or, with
    /// `floats`, its first plane as an f32 word: not a plane byte), and shared words again.
    struct Mock {
        texels: usize,
        q: Vec<u8>,
        order: Vec<usize>,
        floats: bool,
    }

    impl GpuModel for Mock {
        fn shader(&self) -> Shader {
            Shader::new::<MockParams>("mock", "")
        }
        fn gpu_dims(&self) -> (usize, usize) {
            (1, self.texels)
        }
        fn gpu_parts(&self) -> Vec<Cow<'_, [u32]>> {
            let k = self.q.len() / self.texels;
            let texel: Vec<u32> = if self.floats {
                (0..self.texels).map(|t| (self.q[t * k] as f32 / 255.0).to_bits()).collect()
            } else {
                let bytes: Vec<u8> =
                    (0..self.texels).flat_map(|t| self.order.iter().map(move |&p| self.q[t * k + p])).collect();
                pack_u8(&bytes)
            };
            vec![Cow::Owned(vec![7, 8, 9]), Cow::Owned(texel), Cow::Owned(vec![1])]
        }
        fn gpu_params(&self, offsets: &[u32], _tables: &[u32]) -> [u32; 16] {
            MockParams { head: offsets[0], texels: offsets[1], tail: offsets[2] }.words()
        }
    }

    fn probes(k: usize, order: &[usize], floats: bool) -> Vec<(Mock, Vec<u8>)> {
        let mut seed = 1u32;
        [(8usize, 1), (8, 2), (12, 3)]
            .into_iter()
            .map(|(texels, _)| {
                let q: Vec<u8> = (0..texels * k)
                    .map(|_| {
                        seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                        (seed >> 24) as u8
                    })
                    .collect();
                (Mock { texels, q: q.clone(), order: order.to_vec(), floats }, q)
            })
            .collect()
    }

    #[test]
    fn the_window_layout_is_found_from_probes_alone() {
        let order = [4, 0, 3, 1, 2];
        let ms = probes(5, &order, false);
        let list: Vec<Probe<'_>> = ms.iter().map(|(m, q)| Probe { model: m, planes: q, texels: m.texels }).collect();
        let w = web_window(&list, 5, 1000).unwrap();
        // The texel part's bytes, each the plane the model put there; the shared parts moved
        // to the offsets of a 1000-texel store, and the parameters pointing at them.
        assert_eq!(w.texels, vec![TexelPart { offset: 3, bytes: 5, from: order.iter().map(|&p| p as u32).collect() }]);
        let texel_words = (1000 * 5usize).div_ceil(4) as u32;
        assert_eq!(w.constants, vec![(0, vec![7, 8, 9]), (3 + texel_words, vec![1])]);
        assert_eq!(w.store_words, 3 + texel_words + 1);
        assert_eq!(&w.params[..3], &[0, 3, 3 + texel_words]);
        // A model whose per-texel words are not the planes' bytes cannot be drawn from tiles.
        let fs = probes(5, &order, true);
        let list: Vec<Probe<'_>> = fs.iter().map(|(m, q)| Probe { model: m, planes: q, texels: m.texels }).collect();
        let e = web_window(&list, 5, 1000).unwrap_err();
        assert!(e.to_string().contains("not one of the image's planes"), "{e}");
    }

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
