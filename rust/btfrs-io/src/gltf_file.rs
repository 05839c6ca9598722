//! glTF 2.0 (Khronos) assets of `svbrdf` models: a textured square, the material as
//! metallic-roughness maps with `KHR_materials_specular` (and `KHR_materials_ior` at 0, the
//! extension's documented conversion of specular-glossiness materials, so the specular colour
//! *is* F0), for the engines, Blender and viewers that read glTF.
//!
//! # The folder
//!
//! * `material.gltf`: the JSON (the index file), written last.
//! * `material.bin`: the square's vertices (`POSITION`, `NORMAL`, `TANGENT`, `TEXCOORD_0`) and
//!   its six indices.
//! * `base_color.png` (sRGB, 16-bit): the diffuse colour, the `baseColorTexture`.
//! * `metallic_roughness.png` (linear, 16-bit): glTF's roughness `sqrt(alpha)` in green,
//!   metallic 0 in blue (`metallicFactor` 0, `roughnessFactor` 1).
//! * `normal.png` (linear, 16-bit): the tangent-space normal as `(n + 1) / 2`, +X along the
//!   texture's columns and +Y up its rows (glTF's convention, which is btfrs's).
//! * `specular_color.png` (sRGB, 16-bit): the specular colour, `KHR_materials_specular`'s
//!   `specularColorTexture`.
//!
//! The square has side 1, lies in the XZ plane facing +Y (glTF is Y-up), texture row 0 at -Z;
//! texture coordinates run 0..1 with `REPEAT` samplers, so a user tiles the sample by scaling
//! them.
//!
//! # How close glTF's material is to the model's lobe
//!
//! glTF's BRDF (the core specification's appendix B) shares the model's Lambertian diffuse and
//! GGX distribution (glTF's roughness squared is the model's alpha), with F0 = the specular
//! colour. It differs in three ways the format fixes: Schlick's Fresnel rises to 1 at grazing
//! angles, the masking is Smith's height-correlated form, and the diffuse lobe is weakened by
//! the specular's Fresnel. Colours above 1 cannot be stored (a base colour is at most 1, a
//! dielectric F0 too): they are clipped, and the export's report counts them. The Mitsuba
//! export ([`crate::mitsuba_file`]) is the exact one.
//!
//! # Reading
//!
//! [`import`] reads such an asset back as an `svbrdf` model: the first material's four
//! textures (and factors), of any glTF whose material is a non-metal of this form. Image URIs
//! must be plain file names in the asset's folder (no `..`, no absolute paths, no `data:`);
//! images are decoded within the memory budget of every btfrs reader.

use std::path::{Path, PathBuf};

use btfrs_core::{Error, NamedArrays, Result};
use btfrs_fit::svbrdf::lobe::{ALPHA_MAX, ALPHA_MIN};
use btfrs_fit::svbrdf::Svbrdf;
use btfrs_fit::{DynModel, Model};
use serde_json::{json, Value};

use crate::atomic::write_atomic;
use crate::capture::Limits;
use crate::decode::{self, Transfer};
use crate::formats::{concrete, decode_normals, plain_name, read_index, Format, Imported};
use crate::image::{linear_to_srgb, write_png16};
use crate::untrusted::{self, Repairs};

/// The format's entry in [`crate::formats::FORMATS`].
pub const FORMAT: Format = Format {
    name: "gltf",
    extension: "gltf",
    doc: "a glTF 2.0 asset (textured square, metallic-roughness + KHR_materials_specular) for engines and Blender",
    folder: true,
    index: INDEX,
    export: export_model,
    import: import_model,
};

/// The index file.
pub const INDEX: &str = "material.gltf";
/// glTF's sampler constants.
const LINEAR: u32 = 9729;
const LINEAR_MIPMAP_LINEAR: u32 = 9987;
const REPEAT: u32 = 10497;
const FLOAT: u32 = 5126;
const UNSIGNED_SHORT: u32 = 5123;
const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;

fn export_model(model: &dyn DynModel, _view: usize, path: &Path) -> Result<Value> {
    export(concrete::<Svbrdf>(model, "an svbrdf model")?, path)
}

fn import_model(path: &Path, limits: &Limits) -> Result<Imported> {
    let (m, warnings) = import_within(path, limits)?;
    Ok(Imported { model: Box::new(m), warnings })
}

/// The square's buffer: 4 vertices of position, normal, tangent and texture coordinates (f32,
/// in that order, one block each) and 6 u16 indices; with the accessors' JSON.
fn square() -> (Vec<u8>, Vec<Value>, Vec<Value>) {
    let h = 0.5f32;
    // Corners: bottom-left, bottom-right, top-right, top-left of the texture; +y of the sample
    // (up its rows) is -Z.
    let pos = [[-h, 0.0, h], [h, 0.0, h], [h, 0.0, -h], [-h, 0.0, -h]];
    let uv = [[0.0f32, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]];
    let mut bytes = Vec::new();
    let mut views = Vec::new();
    let mut accessors = Vec::new();
    let mut block = |data: Vec<f32>, ty: &str, bounds: Option<(Vec<f32>, Vec<f32>)>| {
        let offset = bytes.len();
        bytes.extend(data.iter().flat_map(|x| x.to_le_bytes()));
        views.push(json!({"buffer": 0, "byteOffset": offset, "byteLength": data.len() * 4, "target": ARRAY_BUFFER}));
        let mut a = json!({"bufferView": views.len() - 1, "componentType": FLOAT, "count": 4, "type": ty});
        if let Some((lo, hi)) = bounds {
            a["min"] = json!(lo);
            a["max"] = json!(hi);
        }
        accessors.push(a);
    };
    block(pos.iter().flatten().copied().collect(), "VEC3", Some((vec![-h, 0.0, -h], vec![h, 0.0, h])));
    block([[0.0f32, 1.0, 0.0]; 4].iter().flatten().copied().collect(), "VEC3", None);
    // Tangent +X (along the columns, increasing u); w = 1: bitangent = normal x tangent = -Z,
    // up the texture's rows, where its normals' +Y points.
    block([[1.0f32, 0.0, 0.0, 1.0]; 4].iter().flatten().copied().collect(), "VEC4", None);
    block(uv.iter().flatten().copied().collect(), "VEC2", None);
    let offset = bytes.len();
    let idx: [u16; 6] = [0, 1, 2, 0, 2, 3];
    bytes.extend(idx.iter().flat_map(|i| i.to_le_bytes()));
    views.push(json!({"buffer": 0, "byteOffset": offset, "byteLength": 12, "target": ELEMENT_ARRAY_BUFFER}));
    accessors
        .push(json!({"bufferView": views.len() - 1, "componentType": UNSIGNED_SHORT, "count": 6, "type": "SCALAR"}));
    (bytes, views, accessors)
}

/// Write `m` as a glTF folder at `path` (the folder, or its `material.gltf`). Returns the
/// files written and how many colour values were clipped to 1.
pub fn export(m: &Svbrdf, path: &Path) -> Result<Value> {
    m.validate()?;
    let dir = FORMAT.folder_of(path);
    std::fs::create_dir_all(&dir).map_err(|e| Error::io(dir.display().to_string(), e))?;
    let (w, h, t) = (m.width, m.height, m.width * m.height);
    let clip = |v: &[f32]| v.iter().filter(|&&x| x > 1.0).count();
    let (clipped_diffuse, clipped_specular) = (clip(&m.diffuse), clip(&m.specular));
    let srgb = |v: &[f32]| v.iter().map(|&x| linear_to_srgb(x)).collect::<Vec<f32>>();
    let mut mr = vec![0.0f32; 3 * t];
    for (i, a) in m.roughness.iter().enumerate() {
        mr[3 * i + 1] = a.sqrt();
    }
    let normal: Vec<f32> = m.normal.iter().map(|&x| ((x + 1.0) * 0.5).clamp(0.0, 1.0)).collect();
    let maps: [(&str, Vec<f32>); 4] = [
        ("base_color.png", srgb(&m.diffuse)),
        ("metallic_roughness.png", mr),
        ("normal.png", normal),
        ("specular_color.png", srgb(&m.specular)),
    ];
    for (name, values) in &maps {
        write_png16(&dir.join(name), values, w, h, 3)?;
    }
    let (bin, views, accessors) = square();
    write_atomic(&dir.join("material.bin"), |f| f.write_all(&bin))?;
    let tex = |i: usize| json!({"index": i, "texCoord": 0});
    let doc = json!({
        "asset": {"version": "2.0", "generator": format!("btfrs {}", env!("CARGO_PKG_VERSION"))},
        "extensionsUsed": ["KHR_materials_specular", "KHR_materials_ior"],
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": "sample"}],
        "meshes": [{"name": "sample", "primitives": [{
            "attributes": {"POSITION": 0, "NORMAL": 1, "TANGENT": 2, "TEXCOORD_0": 3},
            "indices": 4, "material": 0, "mode": 4}]}],
        "materials": [{
            "name": "btfrs svbrdf",
            "pbrMetallicRoughness": {
                "baseColorTexture": tex(0),
                "baseColorFactor": [1.0, 1.0, 1.0, 1.0],
                "metallicRoughnessTexture": tex(1),
                "metallicFactor": 0.0,
                "roughnessFactor": 1.0
            },
            "normalTexture": {"index": 2, "texCoord": 0, "scale": 1.0},
            "extensions": {
                "KHR_materials_specular": {
                    "specularFactor": 1.0,
                    "specularColorFactor": [1.0, 1.0, 1.0],
                    "specularColorTexture": tex(3)
                },
                "KHR_materials_ior": {"ior": 0.0}
            }
        }],
        "textures": (0..4).map(|i| json!({"sampler": 0, "source": i})).collect::<Vec<_>>(),
        "images": maps.iter().map(|(n, _)| json!({"uri": n, "mimeType": "image/png"})).collect::<Vec<_>>(),
        "samplers": [{"magFilter": LINEAR, "minFilter": LINEAR_MIPMAP_LINEAR, "wrapS": REPEAT, "wrapT": REPEAT}],
        "buffers": [{"uri": "material.bin", "byteLength": bin.len()}],
        "bufferViews": views,
        "accessors": accessors,
    });
    let text = serde_json::to_string_pretty(&doc).map_err(|e| Error::Numerical(format!("{INDEX}: {e}")))?;
    // The index last: a reader that finds it finds every file it names.
    write_atomic(&dir.join(INDEX), |f| f.write_all(text.as_bytes()))?;
    let mut files: Vec<&str> = maps.iter().map(|(n, _)| *n).collect();
    files.extend(["material.bin", INDEX]);
    Ok(json!({
        "folder": dir.display().to_string(),
        "files": files,
        "clipped": {"diffuse": clipped_diffuse, "specular": clipped_specular},
    }))
}

fn bad(shown: &str, what: &str, msg: impl std::fmt::Display) -> Error {
    Error::format(shown, format!("{what}: {msg}"))
}

/// A number at `v`, or `default` when absent.
fn number(v: &Value, default: f64, shown: &str, what: &str) -> Result<f64> {
    match v {
        Value::Null => Ok(default),
        Value::Number(n) => n.as_f64().filter(|x| x.is_finite()).ok_or_else(|| bad(shown, what, "not a finite number")),
        _ => Err(bad(shown, what, format!("expected a number, got {v}"))),
    }
}

/// A factor array of `n` numbers at `v`, or `default` when absent.
fn factors(v: &Value, default: &[f64], shown: &str, what: &str) -> Result<Vec<f64>> {
    match v {
        Value::Null => Ok(default.to_vec()),
        Value::Array(a) if a.len() == default.len() => a
            .iter()
            .enumerate()
            .map(|(i, x)| number(x, f64::NAN, shown, &format!("{what}[{i}]")))
            .collect::<Result<Vec<f64>>>()
            .and_then(|f| {
                if f.iter().all(|x| (0.0..=1e6).contains(x)) {
                    Ok(f)
                } else {
                    Err(bad(shown, what, format!("expected values >= 0, got {f:?}")))
                }
            }),
        _ => Err(bad(shown, what, format!("expected {} numbers, got {v}", default.len()))),
    }
}

/// The image file of texture reference `info` (a `textureInfo` object): its path in `dir`.
fn texture_path(doc: &Value, info: &Value, dir: &Path, shown: &str, what: &str) -> Result<PathBuf> {
    let index = |v: &Value, w: &str| -> Result<usize> {
        v.as_u64().map(|i| i as usize).ok_or_else(|| bad(shown, w, format!("expected an index, got {v}")))
    };
    let t = index(&info["index"], &format!("{what}.index"))?;
    if !matches!(info["texCoord"], Value::Null) && info["texCoord"].as_u64() != Some(0) {
        return Err(bad(shown, what, "only TEXCOORD_0 is read"));
    }
    let texture = doc["textures"].get(t).ok_or_else(|| bad(shown, what, format!("texture {t} does not exist")))?;
    let s = index(&texture["source"], &format!("textures[{t}].source"))?;
    let image = doc["images"].get(s).ok_or_else(|| bad(shown, what, format!("image {s} does not exist")))?;
    let uri = image["uri"]
        .as_str()
        .ok_or_else(|| bad(shown, &format!("images[{s}]"), "expected a uri (buffer views are not read)"))?;
    if !plain_name(uri) {
        return Err(bad(
            shown,
            &format!("images[{s}].uri"),
            format!("{uri:?}: expected a file name in the asset's folder (no folders, no data: or other URIs)"),
        ));
    }
    let file = dir.join(uri);
    if !untrusted::present(&file) {
        return Err(bad(shown, &format!("images[{s}].uri"), format!("{uri:?} does not exist beside the asset")));
    }
    Ok(file)
}

/// Read an image of `w x h` pixels (or set them from the first image) as linear RGB.
fn read_map(path: &Path, transfer: Transfer, size: &mut Option<(usize, usize)>, max_bytes: u64) -> Result<Vec<f32>> {
    let d = decode::read_within(path, transfer, max_bytes)?;
    match *size {
        Some((w, h)) if (d.width, d.height) != (w, h) => Err(Error::format(
            path.display().to_string(),
            format!("expected {w} x {h} pixels as the other maps, got {} x {}", d.width, d.height),
        )),
        _ => {
            *size = Some((d.width, d.height));
            Ok(d.rgb)
        }
    }
}

/// Read a glTF asset (its folder or `.gltf` file) as an `svbrdf` model: the first material's
/// base colour, metallic-roughness, normal and specular colour textures with their factors.
/// A roughness below the model's range (glTF's 0, a mirror) is raised to it with a warning
/// ([`import_within`] returns it).
pub fn import(path: &Path) -> Result<Svbrdf> {
    Ok(import_within(path, &Limits::default())?.0)
}

/// [`import`] within `limits` (see [`crate::untrusted`]), with the warnings about values it
/// changed.
pub fn import_within(path: &Path, limits: &Limits) -> Result<(Svbrdf, Vec<String>)> {
    let (dir, shown, text) = read_index(path, INDEX, untrusted::JSON_INDEX, limits.max_bytes)?;
    let shown = shown.as_str();
    let doc: Value = untrusted::parse_json(&text, shown)?;
    drop(text);
    let max_bytes = limits.max_bytes;
    if doc["asset"]["version"].as_str() != Some("2.0") {
        return Err(bad(shown, "asset.version", format!("expected \"2.0\", got {}", doc["asset"]["version"])));
    }
    let mat = doc["materials"].get(0).ok_or_else(|| bad(shown, "materials", "the asset has no material"))?;
    let pbr = &mat["pbrMetallicRoughness"];
    let metallic = number(&pbr["metallicFactor"], 1.0, shown, "metallicFactor")?;
    if metallic != 0.0 {
        return Err(bad(shown, "metallicFactor", format!("{metallic}: only non-metals (0) are read as an svbrdf")));
    }
    let spec = &mat["extensions"]["KHR_materials_specular"];
    let ior = number(&mat["extensions"]["KHR_materials_ior"]["ior"], 1.5, shown, "KHR_materials_ior.ior")?;
    let f0 = if ior == 0.0 { 1.0 } else { ((ior - 1.0) / (ior + 1.0)).powi(2) };
    let need = |v: &Value, what: &str| -> Result<PathBuf> {
        if v.is_null() {
            return Err(bad(shown, what, "missing; an svbrdf needs every map"));
        }
        texture_path(&doc, v, &dir, shown, what)
    };
    let mut size = None;
    let files = [
        need(&pbr["baseColorTexture"], "baseColorTexture")?,
        need(&pbr["metallicRoughnessTexture"], "metallicRoughnessTexture")?,
        need(&mat["normalTexture"], "normalTexture")?,
        need(&spec["specularColorTexture"], "specularColorTexture")?,
    ];
    // The maps' sizes from their headers, and the model's floats within max_bytes, before
    // any map is decoded.
    let (w0, h0) = untrusted::image_size(&files[0])?;
    for f in &files[1..] {
        let (w, h) = untrusted::image_size(f)?;
        if (w, h) != (w0, h0) {
            return Err(Error::format(
                f.display(),
                format!("{w} x {h} pixels; the base colour map has {w0} x {h0}, and every map the same"),
            ));
        }
    }
    untrusted::check_declared(
        shown,
        &format!("a {w0} x {h0} svbrdf model (4 maps of 3 floats per texel and their model, 96 bytes per texel)"),
        u64::from(w0).checked_mul(u64::from(h0)).and_then(|t| t.checked_mul(96)),
        max_bytes,
    )?;
    let base = read_map(&files[0], Transfer::Srgb, &mut size, max_bytes)?;
    let mr = read_map(&files[1], Transfer::Linear, &mut size, max_bytes)?;
    let nrm = read_map(&files[2], Transfer::Linear, &mut size, max_bytes)?;
    let sc = read_map(&files[3], Transfer::Srgb, &mut size, max_bytes)?;
    let base_f = factors(&pbr["baseColorFactor"], &[1.0; 4], shown, "baseColorFactor")?;
    let rough_f = number(&pbr["roughnessFactor"], 1.0, shown, "roughnessFactor")?;
    if !(0.0..=1.0).contains(&rough_f) {
        return Err(bad(shown, "roughnessFactor", format!("{rough_f}: expected a number in [0, 1] (glTF 2.0)")));
    }
    let scale = number(&mat["normalTexture"]["scale"], 1.0, shown, "normalTexture.scale")?;
    let sc_f = factors(&spec["specularColorFactor"], &[1.0; 3], shown, "specularColorFactor")?;
    let s_f = number(&spec["specularFactor"], 1.0, shown, "specularFactor")?;
    let (w, h) = size.unwrap_or((0, 0));
    let t = w * h;
    let mut a = NamedArrays::new();
    let diffuse: Vec<f32> = (0..3 * t).map(|i| (base[i] as f64 * base_f[i % 3]) as f32).collect();
    // glTF clamps the dielectric F0 to 1 before the specular factor.
    let specular: Vec<f32> = (0..3 * t).map(|i| ((f0 * sc_f[i % 3] * sc[i] as f64).min(1.0) * s_f) as f32).collect();
    // glTF's roughness r in [0, 1] is the model's alpha = r^2; below the model's smallest
    // alpha (a mirror) it is raised to it, and said so when it lies below by more than a
    // 16-bit map's step (2 r / 65535 in alpha: the export's own ALPHA_MIN rounds to just under).
    let mut raised = Repairs::new(
        shown,
        format!("roughness value(s) of metallicRoughnessTexture below the svbrdf's smallest (alpha {ALPHA_MIN}) raised to it"),
        "alpha(s)",
        "pixel(s)",
    );
    let roughness: Vec<f32> = (0..t)
        .map(|i| {
            let a = (rough_f * mr[3 * i + 1] as f64).powi(2);
            if a < ALPHA_MIN - 1e-4 {
                raised.add(i, a);
            }
            a.clamp(ALPHA_MIN, ALPHA_MAX) as f32
        })
        .collect();
    let normal = decode_normals(&nrm, scale, shown, "normalTexture")?;
    a.put("diffuse", &[h, w, 3], diffuse);
    a.put("specular", &[h, w, 3], specular);
    a.put("roughness", &[h, w], roughness);
    a.put("normal", &[h, w, 3], normal);
    let m = <Svbrdf as Model>::from_arrays(&a).map_err(|e| bad(shown, "maps", e))?;
    Ok((m, raised.warning().into_iter().collect()))
}
