//! relight's web format: the folder (`info.json` beside `plane_0.jpg`, `plane_1.jpg`, ...) that
//! relight-cli (ISTI-CNR, Ponchio et al.) writes and OpenLIME's RTI layer and relight-cli itself
//! read, for the light bases btfrs shares with relight: PTM (RGB and LRGB), HSH up to order 3,
//! and the PCA light bases (`rbf`, `bilinear`; NeuralRTI's `"neural"` type is
//! [`crate::neuralrti_file`]'s).
//!
//! # The folder
//!
//! `info.json` holds `width`, `height`, `type` (`ptm`, `hsh`, `rbf`, `bilinear`), `colorspace`
//! (`rgb`, `lrgb`, `mrgb`, `mycc`), `nplanes` (or `yccplanes` for `mycc`), `quality`, and
//! `materials[0]` with a `scale` and `bias` per plane (and a `range` for `mrgb`/`mycc`). Plane
//! `p` is channel `p % 3` of `plane_{p / 3}.jpg`, rows top first. A plane byte `b` means, in
//! relight's units (0..255 = black..white of the 8-bit display value),
//!
//! ```text
//! value = 255 ((b / 255) - bias) scale                       (relight material.h, dequantize)
//! ```
//!
//! and btfrs's units are relight's / 255 (1.0 = byte 255, as for `.ptm`). Relighting at light
//! `(lx, ly)` takes per-basis weights `w` (relight `rti.cpp`, `lightWeights*`):
//!
//! * `ptm`: `w = (1, lx, ly, lx^2, lx ly, ly^2)`; `rgb` (18 planes): channel `c` is
//!   `sum_j w_j value_{3j + c}`; `lrgb` (9 planes): planes 0-2 are the base colour's bytes,
//!   planes 3-8 the luminance polynomial `L = sum_j w_j value_{3 + j}`, and channel `c` is
//!   `L * byte_c / 255`.
//! * `hsh`: the first `nplanes / 3` hemispherical harmonics (relight's basis is btfrs's
//!   [`btfrs_fit::hsh`] basis term for term, relight clamping theta to pi/2 - 0.01); channel `c`
//!   as for `ptm` `rgb`.
//! * `rbf`, `bilinear` with `mrgb`: a PCA basis `basis[p][d][k]` (`p` = 0 the mean, then one
//!   function per plane; `d` a light (`rbf`) or a grid node (`bilinear`); `k` the channel),
//!   stored in `info.json` as integers 0..255: the mean as the value in relight's units, a plane
//!   function as `127 + range_p f`. At a light, `rbf` blends the basis at the capture's lights
//!   with normalised Gaussian weights `exp(-|l - l_i|^2 / sigma^2)` (those above 0.001,
//!   renormalised); `bilinear` interpolates a `resolution^2` grid over the octahedral square,
//!   rotated 45 degrees: `s = |lx| + |ly| + |lz|`, `x = ((lx + ly) / s + 1) / 2`,
//!   `y = ((ly - lx) / s + 1) / 2`, node `(x, y) (resolution - 1)`. Channel `k` is the
//!   blended mean plus `sum_p value_p f_p`. `mycc` does the same in relight's YCoCg
//!   (`Color3::toRgb`: `tmp = Y - Cg/2; G = Cg + tmp; B = tmp - Co/2; R = B + Co`), its first
//!   `3 yccplanes[1]` planes cycling through Y, Co, Cg and the rest luminance.
//!
//! relight truncates the result to an integer and clamps it to 0..255.
//!
//! # What btfrs writes and reads
//!
//! **Export** (one view slot): `ptm` and `hsh` (orders 1-3) planes are the model's own 8-bit
//! planes with their scale and bias restated in relight's form (exact); a float model is
//! quantized first. `rbf` and `bilinear` are written as relight's `bilinear` type with `mrgb`:
//! btfrs's table of principal functions lives on the concentric square, relight's on the
//! octahedral one, so the table is resampled at the nodes of a grid of four times the model's
//! resolution, and both the mean and the functions are rounded to relight's integers (btfrs's
//! `ycc` layout is restated in RGB, which is exact). Planes are written as JPEG (what relight and
//! OpenLIME read; quality 100) and as lossless `plane_N.png` copies that btfrs reads back.
//!
//! **Import**: every type above, from the PNG copies when present, else the JPEGs. PTM and HSH
//! become one-slot `ptm` / `hsh` models holding the planes' bytes with relight's scale and bias
//! (exact). `rbf` and `bilinear` become a one-slot `rbf` / `bilinear` model with the plane bytes
//! as they are and relight's basis, blended by relight's own rule, sampled on btfrs's
//! `32 x 32` concentric grid (the one approximation; the agreement with relight's own relit
//! images is measured by the tests). `sh`, `h`, `dmd` and the `ycc` colour space are refused
//! with an error naming them.

use std::path::{Path, PathBuf};

use btfrs_core::{Error, Result};
use btfrs_fit::hsh::HshSlot;
use btfrs_fit::light_pca::{Colour, LightPca, MAX_COMPONENTS, MAX_RESOLUTION};
use btfrs_fit::lightfit::Coeffs;
use btfrs_fit::planes::Planes;
use btfrs_fit::{Bilinear, DynModel, Hsh, Ptm, PtmKind, PtmPlanes, PtmSlot, Rbf};
use serde_json::{json, Value};

use crate::atomic::write_atomic;
use crate::capture::Limits;
use crate::formats::{concrete, read_index, Imported};
use crate::untrusted;

/// The format entry.
pub const FORMAT: crate::formats::Format = crate::formats::Format {
    name: "relight",
    extension: "json",
    doc: "relight's web format (info.json + plane images) read by relight-cli and OpenLIME: PTM, HSH, PCA bases",
    folder: true,
    index: "info.json",
    export: export_model,
    import: import_model,
};

/// JPEG quality of the planes (relight's default is 95; the planes are data, not pictures).
pub const QUALITY: u8 = 100;
/// The PTM basis order of relight (`1, lx, ly, lx^2, lx ly, ly^2`) as indices into btfrs's
/// (`lu^2, lv^2, lu lv, lu, lv, 1`).
const PTM_ORDER: [usize; 6] = [5, 3, 4, 0, 2, 1];
/// The grid btfrs resamples an imported PCA basis on.
const IMPORT_RESOLUTION: usize = MAX_RESOLUTION;
/// Largest image side accepted from `info.json` (before any plane is decoded).
const MAX_SIDE: u64 = 1 << 15;
/// Bytes a folder's model needs per plane and texel: the plane bytes, their reordered copy and
/// their float values.
pub(crate) const BYTES_PER_PLANE_TEXEL: u64 = 6;

/// The folder of `path`: itself, or its parent when it names the `info.json`.
fn folder(path: &Path) -> PathBuf {
    if path.file_name().is_some_and(|n| n == "info.json") {
        path.parent().map(Path::to_path_buf).unwrap_or_default()
    } else {
        path.to_path_buf()
    }
}

// --- export ----------------------------------------------------------------------------------

/// What a folder holds before it is written: relight's plane bytes (texel-major, `nplanes`
/// per texel), per-plane scale and bias in relight's form, and the other `info.json` fields.
struct Web {
    width: usize,
    height: usize,
    nplanes: usize,
    q: Vec<u8>,
    scale: Vec<f64>,
    bias: Vec<f64>,
    fields: serde_json::Map<String, Value>,
}

/// Restate btfrs planes (`value = bias + scale b`, btfrs units) in relight's form
/// (`value = ((b / 255) - bias_w) scale_w`, btfrs units): `scale_w = 255 scale`,
/// `bias_w = -bias / (255 scale)`. A constant plane (scale 0) gets every byte 255 and
/// `scale_w` = its value.
fn relight_plane(scale: f32, bias: f32, bytes: &mut [u8]) -> (f64, f64) {
    let (s, b) = (f64::from(scale), f64::from(bias));
    if s == 0.0 {
        bytes.iter_mut().for_each(|x| *x = 255);
        (b, 0.0)
    } else {
        (255.0 * s, -b / (255.0 * s))
    }
}

/// Gather plane `src` of `planes` (texel-major) for every texel.
fn column(planes: &Planes, src: usize) -> Vec<u8> {
    (0..planes.texels).map(|t| planes.q[t * planes.k + src]).collect()
}

impl Web {
    fn new(width: usize, height: usize, nplanes: usize) -> Web {
        Web {
            width,
            height,
            nplanes,
            q: vec![0; width * height * nplanes],
            scale: vec![1.0; nplanes],
            bias: vec![0.0; nplanes],
            fields: serde_json::Map::new(),
        }
    }

    /// Set relight plane `p` from btfrs plane `src` of `planes`.
    fn put(&mut self, p: usize, planes: &Planes, src: usize) {
        let mut bytes = column(planes, src);
        let (s, b) = relight_plane(planes.scale[src], planes.bias[src], &mut bytes);
        self.put_bytes(p, &bytes, s, b);
    }

    fn put_bytes(&mut self, p: usize, bytes: &[u8], scale: f64, bias: f64) {
        for (t, &b) in bytes.iter().enumerate() {
            self.q[t * self.nplanes + p] = b;
        }
        self.scale[p] = scale;
        self.bias[p] = bias;
    }

    /// Write the folder: planes as JPEG and PNG, then `info.json` last (atomically each).
    fn write(mut self, path: &Path, kind: &str) -> Result<Value> {
        let dir = folder(path);
        std::fs::create_dir_all(&dir).map_err(|e| Error::io(dir.display().to_string(), e))?;
        let texels = self.width * self.height;
        let njpegs = self.nplanes.div_ceil(3);
        let mut files = Vec::new();
        for i in 0..njpegs {
            let mut rgb = vec![0u8; texels * 3];
            for t in 0..texels {
                for c in 0..3 {
                    if 3 * i + c < self.nplanes {
                        rgb[t * 3 + c] = self.q[t * self.nplanes + 3 * i + c];
                    }
                }
            }
            for ext in ["jpg", "png"] {
                let name = format!("plane_{i}.{ext}");
                write_atomic(&dir.join(&name), |w| {
                    crate::image::encode_rgb8(w, &rgb, self.width, self.height, ext, QUALITY)
                })?;
                files.push(name);
            }
        }
        let mut info = serde_json::Map::new();
        info.insert("width".into(), json!(self.width));
        info.insert("height".into(), json!(self.height));
        info.insert("format".into(), json!("jpg"));
        info.append(&mut self.fields);
        info.insert("nplanes".into(), json!(self.nplanes));
        info.insert("quality".into(), json!(QUALITY));
        let mut material = serde_json::Map::new();
        if let Some(range) = info.remove("range") {
            material.insert("range".into(), range);
        }
        material.insert("scale".into(), json!(self.scale));
        material.insert("bias".into(), json!(self.bias));
        info.insert("materials".into(), json!([material]));
        info.insert(
            "btfrs".into(),
            json!({"model": kind, "values": "btfrs units x 255 = relight's (the 8-bit display value)"}),
        );
        // Compact: the basis alone can hold tens of thousands of numbers.
        let text = serde_json::to_string(&Value::Object(info)).map_err(|e| Error::arg("model", e))?;
        write_atomic(&dir.join("info.json"), |w| w.write_all(text.as_bytes()))?;
        files.push("info.json".into());
        Ok(json!({"files": files}))
    }
}

fn export_model(model: &dyn DynModel, view: usize, path: &Path) -> Result<Value> {
    match model.kind() {
        "ptm" => export_ptm(concrete::<Ptm>(model, "a PTM")?, view, path),
        "hsh" => export_hsh(concrete::<Hsh>(model, "an HSH model")?, view, path),
        "rbf" => export_pca(&concrete::<Rbf>(model, "an RBF model")?.0, view, path, "rbf"),
        "bilinear" => export_pca(&concrete::<Bilinear>(model, "a bilinear model")?.0, view, path, "bilinear"),
        other => Err(Error::arg("format", format!("relight's web format holds no {other} model"))),
    }
}

fn export_ptm(m: &Ptm, view: usize, path: &Path) -> Result<Value> {
    let slot = m.slot(view)?;
    let texels = slot.width * slot.height;
    let planes = match &slot.planes {
        Some(p) => p.clone(),
        None => PtmPlanes {
            coeffs: Planes::quantize(&slot.coeffs, slot.coeffs.len() / texels)?,
            rgb: slot.rgb.as_ref().map(|r| Planes::quantize(r, 3)).transpose()?,
        },
    };
    let mut web = match slot.kind {
        PtmKind::Rgb => {
            let mut web = Web::new(slot.width, slot.height, 18);
            for (j, &ours) in PTM_ORDER.iter().enumerate() {
                for c in 0..3 {
                    web.put(3 * j + c, &planes.coeffs, c * 6 + ours);
                }
            }
            web.fields.insert("colorspace".into(), json!("rgb"));
            web
        }
        PtmKind::Lrgb => {
            let mut web = Web::new(slot.width, slot.height, 9);
            // The base colour is used by relight as raw bytes (value / 255), so it is written
            // as the decoded colour rounded to bytes.
            let rgb = slot.rgb.as_ref().ok_or_else(|| Error::arg("model", "an LRGB PTM without base colours"))?;
            for c in 0..3 {
                let bytes: Vec<u8> =
                    (0..texels).map(|t| (f64::from(rgb[t * 3 + c]) * 255.0).round().clamp(0.0, 255.0) as u8).collect();
                web.put_bytes(c, &bytes, 1.0, 0.0);
            }
            for (j, &ours) in PTM_ORDER.iter().enumerate() {
                web.put(3 + j, &planes.coeffs, ours);
            }
            web.fields.insert("colorspace".into(), json!("lrgb"));
            web
        }
    };
    web.fields.insert("type".into(), json!("ptm"));
    web.write(path, "ptm")
}

fn export_hsh(m: &Hsh, view: usize, path: &Path) -> Result<Value> {
    let slot = m.slot(view)?;
    if slot.order > 3 {
        return Err(Error::arg(
            "model",
            format!("relight's web format holds HSH up to order 3 (9 terms); this model is order {}", slot.order),
        ));
    }
    let n2 = slot.order * slot.order;
    let planes = match &slot.coeffs.planes {
        Some(p) => p.clone(),
        None => Planes::quantize(&slot.coeffs.values, 3 * n2)?,
    };
    let mut web = Web::new(slot.width, slot.height, 3 * n2);
    for j in 0..n2 {
        for c in 0..3 {
            web.put(3 * j + c, &planes, c * n2 + j);
        }
    }
    web.fields.insert("type".into(), json!("hsh"));
    web.fields.insert("colorspace".into(), json!("rgb"));
    web.write(path, "hsh")
}

/// The hemisphere direction of point `(x, y)` of relight's rotated octahedral square
/// (`[0, 1]^2`): the inverse of `lightWeightsBilinear`'s map.
fn octa_direction(x: f64, y: f64) -> [f64; 3] {
    let (u, v) = (2.0 * x - 1.0, 2.0 * y - 1.0);
    // u = (lx + ly) / s, v = (ly - lx) / s with s = |lx| + |ly| + lz.
    let (a, b) = ((u - v) / 2.0, (u + v) / 2.0);
    let z = (1.0 - a.abs() - b.abs()).max(0.0);
    let n = (a * a + b * b + z * z).sqrt();
    [a / n, b / n, z / n]
}

/// One table row of `m`'s slot `v` at light `l`, restated in RGB: `[mean r g b, then per plane
/// its r g b function]` (btfrs's `ycc` rows mapped through `r = Y + Cr, g = Y - Cb - Cr,
/// b = Y + Cb`, which is linear).
fn rgb_row(m: &LightPca, v: usize, l: [f64; 3]) -> Vec<f64> {
    let row = m.row_at(v, l);
    let k = m.k();
    let mut out = vec![0.0f64; 3 + 3 * k];
    match m.colour {
        Colour::Rgb => out.iter_mut().zip(&row).for_each(|(o, &x)| *o = f64::from(x)),
        Colour::Ycc => {
            let to_rgb = |y: f64, cb: f64, cr: f64| [y + cr, y - cb - cr, y + cb];
            let mean = to_rgb(row[0] as f64, row[1] as f64, row[2] as f64);
            out[..3].copy_from_slice(&mean);
            for p in 0..m.k_main {
                let y = f64::from(row[3 + p]);
                out[3 + 3 * p..6 + 3 * p].copy_from_slice(&to_rgb(y, 0.0, 0.0));
            }
            for p in 0..m.k_chroma {
                let (cb, cr) = (f64::from(row[3 + m.k_main + 2 * p]), f64::from(row[4 + m.k_main + 2 * p]));
                let q = m.k_main + p;
                out[3 + 3 * q..6 + 3 * q].copy_from_slice(&to_rgb(0.0, cb, cr));
            }
        }
    }
    out
}

fn export_pca(m: &LightPca, view: usize, path: &Path, kind: &str) -> Result<Value> {
    let nv = m.views.len();
    if view >= nv {
        return Err(Error::arg("view", format!("expected a view slot index in [0, {nv}), got {view}")));
    }
    m.validate()?;
    let k = m.k();
    let res = (4 * m.resolution).clamp(16, 64);
    let g = res * res;
    // The functions at relight's nodes, in btfrs units.
    let rows: Vec<Vec<f64>> = (0..g)
        .map(|node| {
            let (x, y) = ((node % res) as f64 / (res - 1) as f64, (node / res) as f64 / (res - 1) as f64);
            rgb_row(m, view, octa_direction(x, y))
        })
        .collect();
    // relight's integers: the mean in relight's units, a plane's function as 127 + range f.
    let mut basis = vec![0i64; (k + 1) * g * 3];
    let mut range = vec![1.0f64; k];
    for p in 0..=k {
        if p > 0 {
            let peak = rows.iter().flat_map(|r| r[3 * p..3 * p + 3].iter()).fold(0.0f64, |a, &x| a.max(x.abs()));
            range[p - 1] = if peak > 0.0 { 127.0 / peak } else { 1.0 };
        }
        for (d, r) in rows.iter().enumerate() {
            for c in 0..3 {
                let f = r[3 * p + c];
                basis[(p * g + d) * 3 + c] = if p == 0 {
                    (f * 255.0).round().clamp(0.0, 255.0) as i64
                } else {
                    (127.0 + range[p - 1] * f).round().clamp(0.0, 255.0) as i64
                };
            }
        }
    }
    let mut web = Web::new(m.width, m.height, k);
    for p in 0..k {
        web.put(p, &m.planes, view * k + p);
    }
    web.fields.insert("type".into(), json!("bilinear"));
    web.fields.insert("resolution".into(), json!(res));
    web.fields.insert("colorspace".into(), json!("mrgb"));
    web.fields.insert("basis".into(), json!(basis));
    web.fields.insert("range".into(), json!(range));
    let mut out = web.write(path, kind)?;
    out["resolution"] = json!(res);
    Ok(out)
}

// --- import ----------------------------------------------------------------------------------

fn import_model(path: &Path, limits: &Limits) -> Result<Imported> {
    let (dir, shown, text) = read_index(path, "info.json", untrusted::JSON_INDEX, limits.max_bytes)?;
    let info = untrusted::parse_json(&text, &shown)?;
    drop(text);
    if info["type"].as_str() == Some("neural") {
        return Ok(Imported::model(Box::new(crate::neuralrti_file::from_info(&dir, &shown, &info, limits)?)));
    }
    Ok(Imported::model(import(&dir, &info, &shown, limits)?))
}

/// An `info.json` field error.
fn bad(shown: &str, what: &str, msg: String) -> Error {
    Error::format(shown, format!("{what}: {msg}"))
}

fn numbers(info: &Value, key: &str, shown: &str) -> Result<Vec<f64>> {
    let a = info[key]
        .as_array()
        .ok_or_else(|| bad(shown, key, format!("expected a list of numbers, got {}", info[key])))?;
    a.iter()
        .map(|x| {
            x.as_f64().filter(|f| f.is_finite()).ok_or_else(|| bad(shown, key, format!("{x} is not a finite number")))
        })
        .collect()
}

/// The folder's planes, texel-major (`nplanes` bytes per texel): `plane_N.png` where present
/// (btfrs's lossless copies), else `plane_N.jpg`. Every image's size is read from its header
/// and checked against `info.json`'s, and the model's memory against `max_bytes`, before the
/// planes are allocated; each image is decoded within the budget of every image btfrs reads.
fn read_planes(
    dir: &Path,
    width: usize,
    height: usize,
    nplanes: usize,
    shown: &str,
    max_bytes: u64,
) -> Result<Vec<u8>> {
    let files = (0..nplanes.div_ceil(3))
        .map(|i| {
            untrusted::first_present(["png", "jpg"].map(|e| dir.join(format!("plane_{i}.{e}"))))
                .ok_or_else(|| bad(shown, "planes", format!("no plane_{i}.jpg (or .png) beside it")))
        })
        .collect::<Result<Vec<_>>>()?;
    let texels = width * height;
    let need = (texels as u64).checked_mul(nplanes as u64).and_then(|n| n.checked_mul(BYTES_PER_PLANE_TEXEL));
    untrusted::check_declared(
        shown,
        &format!("a {width} x {height} model of {nplanes} planes ({BYTES_PER_PLANE_TEXEL} bytes per plane and texel)"),
        need,
        max_bytes,
    )?;
    untrusted::check_image_sizes(&files, width, height, "info.json")?;
    let mut q = vec![0u8; texels * nplanes];
    for (i, file) in files.iter().enumerate() {
        let rgb = untrusted::read_rgb8(file, width, height, max_bytes)?;
        for (t, px) in rgb.chunks_exact(3).enumerate() {
            for c in 0..3 {
                if 3 * i + c < nplanes {
                    q[t * nplanes + 3 * i + c] = px[c];
                }
            }
        }
    }
    Ok(q)
}

/// btfrs planes from relight's: `value = ((b / 255) - bias) scale` (btfrs units) is
/// `b (scale / 255) - bias scale`.
fn btfrs_planes(q: Vec<u8>, texels: usize, k: usize, scale: &[f64], bias: &[f64]) -> Planes {
    Planes {
        texels,
        k,
        q,
        scale: scale.iter().map(|&s| (s / 255.0) as f32).collect(),
        bias: bias.iter().zip(scale).map(|(&b, &s)| (-b * s) as f32).collect(),
    }
}

/// Reorder texel-major planes: output plane `o` is input plane `from[o]`.
fn reorder(src: &[u8], texels: usize, k_in: usize, from: &[usize]) -> Vec<u8> {
    let k = from.len();
    let mut out = vec![0u8; texels * k];
    for t in 0..texels {
        for (o, &i) in from.iter().enumerate() {
            out[t * k + o] = src[t * k_in + i];
        }
    }
    out
}

fn import(dir: &Path, info: &Value, shown: &str, limits: &Limits) -> Result<Box<dyn DynModel>> {
    let dim = |key: &str| -> Result<usize> {
        info[key]
            .as_u64()
            .filter(|&v| v > 0 && v <= MAX_SIDE)
            .map(|v| v as usize)
            .ok_or_else(|| bad(shown, key, format!("expected a size in 1..={MAX_SIDE}, got {}", info[key])))
    };
    let (width, height) = (dim("width")?, dim("height")?);
    let texels = width * height;
    let kind = info["type"].as_str().unwrap_or("");
    let space = info["colorspace"].as_str().unwrap_or("");
    let nplanes = if space == "mycc" {
        let y = numbers(info, "yccplanes", shown)?;
        if y.len() != 3 || y.iter().any(|&v| v < 0.0 || v.fract() != 0.0) || y[1] != y[2] || y[0] < y[1] {
            return Err(bad(
                shown,
                "yccplanes",
                format!("expected three counts [Y, Co, Cg] with Co = Cg <= Y, got {y:?}"),
            ));
        }
        (y[0] + y[1] + y[2]) as usize
    } else {
        dim("nplanes")?
    };
    let material = info["materials"].get(0).ok_or_else(|| bad(shown, "materials", "expected one material".into()))?;
    let scale = numbers(material, "scale", shown)?;
    let bias = numbers(material, "bias", shown)?;
    if scale.len() != nplanes || bias.len() != nplanes {
        return Err(bad(
            shown,
            "materials",
            format!("expected {nplanes} scales and biases, got {} and {}", scale.len(), bias.len()),
        ));
    }
    let combo = (kind, space);
    match combo {
        ("ptm", "rgb") if nplanes == 18 => {}
        ("ptm", "lrgb") if nplanes == 9 => {}
        ("hsh", "rgb") if [3, 12, 27].contains(&nplanes) => {}
        ("rbf" | "bilinear", "mrgb" | "mycc") if (1..=MAX_COMPONENTS).contains(&nplanes) => {}
        ("ptm" | "hsh" | "rbf" | "bilinear", "rgb" | "lrgb" | "mrgb" | "mycc") => {
            return Err(bad(shown, "nplanes", format!("{nplanes} planes do not make a {kind} basis in {space}")))
        }
        _ => {
            return Err(bad(
                shown,
                "type",
                format!(
                    "btfrs reads relight's ptm (rgb, lrgb), hsh (rgb), rbf and bilinear (mrgb, mycc) and neural \
                     folders; got type {:?} with colorspace {:?}",
                    info["type"], info["colorspace"]
                ),
            ))
        }
    }
    let q = read_planes(dir, width, height, nplanes, shown, limits.max_bytes)?;
    match combo {
        ("ptm", "rgb") => {
            // btfrs plane c * 6 + ours <- relight plane 3 j + c.
            let mut from = vec![0; 18];
            for (j, &ours) in PTM_ORDER.iter().enumerate() {
                for c in 0..3 {
                    from[c * 6 + ours] = 3 * j + c;
                }
            }
            let pick = |v: &[f64]| from.iter().map(|&i| v[i]).collect::<Vec<_>>();
            let planes = btfrs_planes(reorder(&q, texels, 18, &from), texels, 18, &pick(&scale), &pick(&bias));
            let coeffs = planes.dequantize();
            let slot = PtmSlot {
                kind: PtmKind::Rgb,
                height,
                width,
                coeffs,
                rgb: None,
                planes: Some(PtmPlanes { coeffs: planes, rgb: None }),
            };
            Ok(Box::new(Ptm::from_slot(slot).map_err(untrusted::as_format(shown, "planes"))?))
        }
        ("ptm", "lrgb") => {
            let mut from = vec![0; 6];
            for (j, &ours) in PTM_ORDER.iter().enumerate() {
                from[ours] = 3 + j;
            }
            let pick = |v: &[f64]| from.iter().map(|&i| v[i]).collect::<Vec<_>>();
            let planes = btfrs_planes(reorder(&q, texels, 9, &from), texels, 6, &pick(&scale), &pick(&bias));
            // relight multiplies the luminance by the base colour's raw bytes / 255.
            let rgb_planes = Planes {
                texels,
                k: 3,
                q: reorder(&q, texels, 9, &[0, 1, 2]),
                scale: vec![1.0 / 255.0; 3],
                bias: vec![0.0; 3],
            };
            let slot = PtmSlot {
                kind: PtmKind::Lrgb,
                height,
                width,
                coeffs: planes.dequantize(),
                rgb: Some(rgb_planes.dequantize()),
                planes: Some(PtmPlanes { coeffs: planes, rgb: Some(rgb_planes) }),
            };
            Ok(Box::new(Ptm::from_slot(slot).map_err(untrusted::as_format(shown, "planes"))?))
        }
        ("hsh", "rgb") => {
            let n2 = nplanes / 3;
            let mut from = vec![0; nplanes];
            for j in 0..n2 {
                for c in 0..3 {
                    from[c * n2 + j] = 3 * j + c;
                }
            }
            let pick = |v: &[f64]| from.iter().map(|&i| v[i]).collect::<Vec<_>>();
            let planes =
                btfrs_planes(reorder(&q, texels, nplanes, &from), texels, nplanes, &pick(&scale), &pick(&bias));
            let order = [1, 2, 3].into_iter().find(|o| o * o == n2).expect("checked above");
            let slot = HshSlot { order, height, width, coeffs: Coeffs::from_planes(planes) };
            Ok(Box::new(Hsh::from_slot(slot).map_err(untrusted::as_format(shown, "planes"))?))
        }
        _ => {
            let planes = btfrs_planes(q, texels, nplanes, &scale, &bias);
            let m = import_pca(info, shown, kind, space, nplanes, planes, height, width)?;
            Ok(if kind == "rbf" { Box::new(Rbf(m)) } else { Box::new(Bilinear(m)) })
        }
    }
}

/// relight's light weights of a PCA basis at light `l`: per basis entry `d`, its weight.
fn basis_weights(kind: &str, l: [f64; 3], lights: &[[f64; 3]], sigma: f64, res: usize) -> Vec<(usize, f64)> {
    if kind == "rbf" {
        // rti.cpp lightWeightsRbf: normalised Gaussians, those above 0.001 kept and renormalised.
        let radius = 1.0 / (sigma * sigma);
        let w: Vec<f64> = lights
            .iter()
            .map(|li| (-radius * ((l[0] - li[0]).powi(2) + (l[1] - li[1]).powi(2) + (l[2] - li[2]).powi(2))).exp())
            .collect();
        let tot: f64 = w.iter().sum();
        let kept: Vec<(usize, f64)> =
            w.iter().enumerate().map(|(i, &x)| (i, x / tot)).filter(|&(_, x)| x > 0.001).collect();
        let re: f64 = kept.iter().map(|&(_, x)| x).sum();
        kept.into_iter().map(|(i, x)| (i, x / re)).collect()
    } else {
        // rti.cpp lightWeightsBilinear.
        let s = l[0].abs() + l[1].abs() + l[2].abs();
        let n = (res - 1) as f64;
        let x = ((l[0] + l[1]) / s + 1.0) / 2.0 * n;
        let y = ((l[1] - l[0]) / s + 1.0) / 2.0 * n;
        let sx = (x.floor().max(0.0) as usize).min(res - 2);
        let sy = (y.floor().max(0.0) as usize).min(res - 2);
        let (dx, dy) = (x - sx as f64, y - sy as f64);
        vec![
            (sx + sy * res, (1.0 - dx) * (1.0 - dy)),
            (sx + 1 + sy * res, dx * (1.0 - dy)),
            (sx + (sy + 1) * res, (1.0 - dx) * dy),
            (sx + 1 + (sy + 1) * res, dx * dy),
        ]
    }
}

#[allow(clippy::too_many_arguments)]
fn import_pca(
    info: &Value,
    shown: &str,
    kind: &str,
    space: &str,
    k: usize,
    planes: Planes,
    height: usize,
    width: usize,
) -> Result<LightPca> {
    let material = &info["materials"][0];
    let range = numbers(material, "range", shown)?;
    if range.len() != k || range.contains(&0.0) {
        return Err(bad(shown, "materials", format!("expected {k} non-zero ranges, got {range:?}")));
    }
    let (dims, lights, sigma, res) = if kind == "rbf" {
        let l = numbers(info, "lights", shown)?;
        if l.is_empty() || l.len() % 3 != 0 {
            return Err(bad(shown, "lights", format!("expected x, y, z triples, got {} numbers", l.len())));
        }
        let sigma = info["sigma"]
            .as_f64()
            .filter(|s| s.is_finite() && *s > 0.0)
            .ok_or_else(|| bad(shown, "sigma", format!("expected a positive number, got {}", info["sigma"])))?;
        let lights: Vec<[f64; 3]> = l.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        (lights.len(), lights, sigma, 0)
    } else {
        let res = info["resolution"]
            .as_u64()
            .filter(|&r| (2..=256).contains(&r))
            .ok_or_else(|| bad(shown, "resolution", format!("expected 2 to 256, got {}", info["resolution"])))?
            as usize;
        (res * res, Vec::new(), 0.0, res)
    };
    let raw = numbers(info, "basis", shown)?;
    if raw.len() != (k + 1) * dims * 3 {
        return Err(bad(shown, "basis", format!("expected {} values, got {}", (k + 1) * dims * 3, raw.len())));
    }
    // relight's basis is bytes: integers 0 to 255.
    if let Some(i) = raw.iter().position(|&b| !(0.0..=255.0).contains(&b)) {
        return Err(bad(shown, "basis", format!("value {} at index {i} is outside 0..255", raw[i])));
    }
    // In btfrs units: the mean / 255, a plane's function (b - 127) / range.
    let basis = |p: usize, d: usize, c: usize| -> f64 {
        let b = raw[(p * dims + d) * 3 + c];
        if p == 0 {
            b / 255.0
        } else {
            (b - 127.0) / range[p - 1]
        }
    };
    // relight's YCoCg (Y, Co, Cg) -> RGB (Color3::toRgb), linear.
    let to_rgb = |y: f64, co: f64, cg: f64| {
        let tmp = y - cg / 2.0;
        let b = tmp - co / 2.0;
        [b + co, cg + tmp, b]
    };
    let n_chroma = if space == "mycc" { numbers(info, "yccplanes", shown)?[1] as usize } else { 0 };
    let n = IMPORT_RESOLUTION;
    let stride = 3 + 3 * k;
    let mut table = vec![0.0f32; n * n * stride];
    for (node, dir) in btfrs_fit::light_pca::grid_directions(n).into_iter().enumerate() {
        let w = basis_weights(kind, dir, &lights, sigma, res);
        let blend = |p: usize, c: usize| w.iter().map(|&(d, x)| x * basis(p, d, c)).sum::<f64>();
        let row = &mut table[node * stride..(node + 1) * stride];
        if space == "mrgb" {
            for p in 0..=k {
                for c in 0..3 {
                    row[3 * p + c] = blend(p, c) as f32;
                }
            }
        } else {
            let m = to_rgb(blend(0, 0), blend(0, 1), blend(0, 2));
            row[..3].iter_mut().zip(m).for_each(|(o, x)| *o = x as f32);
            for p in 0..k {
                // Planes 3q + c (q < chroma count) feed channel c (Y, Co, Cg); the rest Y.
                let ch = if p < 3 * n_chroma { p % 3 } else { 0 };
                let mut ycc = [0.0; 3];
                ycc[ch] = blend(p + 1, ch);
                let rgb = to_rgb(ycc[0], ycc[1], ycc[2]);
                row[3 + 3 * p..6 + 3 * p].iter_mut().zip(rgb).for_each(|(o, x)| *o = x as f32);
            }
        }
    }
    let m = LightPca {
        height,
        width,
        views: vec![[0.0, 0.0, 1.0]],
        resolution: n,
        colour: Colour::Rgb,
        k_main: k,
        k_chroma: 0,
        planes,
        table,
        pooled: Vec::new(),
        fallback_slots: Vec::new(),
    };
    m.validate().map_err(untrusted::as_format(shown, "basis"))?;
    Ok(m)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn octahedral_square_inverts_relights_map() {
        // relight's forward map of the direction gives back the square point.
        for &(x, y) in &[(0.5, 0.5), (0.1, 0.7), (0.9, 0.2), (0.0, 0.5), (0.33, 0.99)] {
            let l = octa_direction(x, y);
            assert!(((l[0] * l[0] + l[1] * l[1] + l[2] * l[2]) - 1.0).abs() < 1e-12 && l[2] >= 0.0);
            let s = l[0].abs() + l[1].abs() + l[2].abs();
            let (fx, fy) = (((l[0] + l[1]) / s + 1.0) / 2.0, ((l[1] - l[0]) / s + 1.0) / 2.0);
            assert!((fx - x).abs() < 1e-12 && (fy - y).abs() < 1e-12, "({x}, {y}) -> {l:?} -> ({fx}, {fy})");
        }
    }

    #[test]
    fn relight_planes_restate_btfrs_planes_exactly() {
        let mut bytes = vec![0u8, 17, 128, 255];
        let (scale, bias) = (0.0123f32, -0.7f32);
        let (s, b) = relight_plane(scale, bias, &mut bytes);
        for &q in &bytes {
            let ours = f64::from(bias) + f64::from(scale) * f64::from(q);
            let theirs = (f64::from(q) / 255.0 - b) * s;
            assert!((ours - theirs).abs() < 1e-7, "{ours} vs {theirs}");
        }
        let back = btfrs_planes(bytes.clone(), 4, 1, &[s], &[b]);
        for (i, &q) in bytes.iter().enumerate() {
            assert!((back.get(i, 0) - (bias + scale * f32::from(q))).abs() < 1e-6);
        }
        // A constant plane: every byte 255 and the value in the scale.
        let mut c = vec![3u8, 9];
        let (s, b) = relight_plane(0.0, 0.25, &mut c);
        assert_eq!(c, [255, 255]);
        assert!(((255.0 / 255.0 - b) * s - 0.25).abs() < 1e-12);
    }
}
