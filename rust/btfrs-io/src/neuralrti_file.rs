//! NeuralRTI's web format (Dulecha et al. 2020; written by univr-GRAIL/NeuralRTI, read by
//! OpenLIME's neural layer): a folder holding `info.json` and the latent planes as images.
//!
//! * `info.json`: `type` `"neural"`, `width`, `height`, `planes` (latents: 9, as OpenLIME reads),
//!   `samples` (OpenLIME takes it, rounded up to a multiple of 4, as the hidden width), `format`,
//!   `quality`, `colorspace` (a GLSL swizzle applied to the plane texels and to the network's
//!   output: `"bgr"`, NeuralRTI's OpenCV order), `min` and `max` per latent, and `weights` /
//!   `biases`: three layers, each matrix row-major `[out][in]` with both sides zero-padded to a
//!   multiple of 4 (the output layer's 3 rows excepted).
//! * The network: `(latents, light x, light y, 0) -> hidden -> hidden -> 3`, ELU, linear output.
//! * Planes: image `i` holds latents `3i, 3i+1, 3i+2` in its blue, green and red channels; a byte
//!   `b` decodes as `min + b / 255 (max - min)`. OpenLIME loads `plane_1.jpg` to `plane_3.jpg`;
//!   the same images are written losslessly as `plane_1.png` to `plane_3.png` (NeuralRTI also
//!   writes both; its own files are numbered from 0, which [`import`] also reads).
//!
//! btfrs's neural model in NeuralRTI's form (`directions = "light"`, no direction tables, ELU,
//! at most 9 latents) is written exactly: its 8-bit planes are the file's bytes (`min` its bias,
//! `max` its bias plus 255 steps), fewer latents are padded with constant planes and zero weights.
//! The values stay btfrs's (linear RGB, cosine included); OpenLIME shows the network's output
//! as display values, so a linear model looks darker there than btfrs's sRGB renderings.

use crate::atomic::write_atomic;
use crate::capture::Limits;
use crate::formats::{concrete, read_index, Format, Imported};
use crate::untrusted;
use btfrs_core::{Error, Result};
use btfrs_fit::neural::decoder::{Activation, Decoder, Directions, Shape};
use btfrs_fit::neural::Neural;
use btfrs_fit::planes::Planes;
use btfrs_fit::DynModel;
use serde_json::{json, Value};
use std::path::{Path, PathBuf};

/// The format's entry in [`crate::formats::FORMATS`].
pub const FORMAT: Format = Format {
    name: "neuralrti",
    extension: "json",
    doc: "NeuralRTI's web format (info.json + latent plane images), read by OpenLIME's neural layer",
    folder: true,
    index: "info.json",
    export: export_model,
    import: import_model,
};

/// Latents OpenLIME reads (three images of three channels).
pub const LATENTS: usize = 9;
/// JPEG quality of the planes OpenLIME loads.
pub const QUALITY: u8 = 95;
/// Largest image side accepted from `info.json` (before any plane is read).
const MAX_SIDE: u64 = 1 << 15;

fn pad4(n: usize) -> usize {
    n.div_ceil(4) * 4
}

/// The folder of `path`: itself, or its parent when it names the `info.json`.
fn folder(path: &Path) -> PathBuf {
    if path.file_name().is_some_and(|n| n == "info.json") {
        path.parent().map(Path::to_path_buf).unwrap_or_default()
    } else {
        path.to_path_buf()
    }
}

fn export_model(model: &dyn DynModel, view: usize, path: &Path) -> Result<Value> {
    let m: &Neural = concrete(model, "a neural model")?;
    if view != 0 {
        return Err(Error::arg(
            "view",
            format!("a neural model has one decoder for every view; expected view 0, got {view}"),
        ));
    }
    export(m, path)
}

/// Write `m` to folder `path` (created if missing); returns `{"min", "max", "files"}`.
pub fn export(m: &Neural, path: &Path) -> Result<Value> {
    let dec = m.decoder();
    let sh = dec.shape;
    let why = if sh.directions != Directions::Light {
        Some(format!(
            "its decoder reads the {:?} encoding, not the light's (x, y) alone (fit with directions=\"light\")",
            sh.directions.name()
        ))
    } else if sh.features > 0 {
        Some("its decoder reads learned direction tables (fit with features=0)".to_string())
    } else if sh.horizon > 0 {
        Some(
            "its decoder reads each texel's clearance above its horizon map, which OpenLIME does not hold \
             (fit with horizon=0)"
                .to_string(),
        )
    } else if sh.activation != Activation::Elu {
        Some("its activation is ReLU; OpenLIME's decoder applies ELU (fit with activation=\"elu\")".to_string())
    } else if sh.latents > LATENTS {
        Some(format!("it has {} latents; OpenLIME reads {LATENTS}", sh.latents))
    } else {
        None
    };
    if let Some(why) = why {
        return Err(Error::arg(
            "format",
            format!("NeuralRTI's form is (9 latents + light x, y) -> ELU MLP -> RGB; {why}"),
        ));
    }
    let dir = folder(path);
    std::fs::create_dir_all(&dir).map_err(|e| Error::io(dir.display().to_string(), e))?;
    let (height, width) = m.size();
    let k = sh.latents;
    let h = sh.hidden;
    let hp = pad4(h);
    let np = pad4(LATENTS + 2);
    let o = sh.offsets();
    let p = &dec.params;
    let n = sh.inputs();
    // Layer 1: [hp][np] = latents (padded to 9), x, y, 0.
    let mut w1 = vec![0.0f64; hp * np];
    let mut b1 = vec![0.0f64; hp];
    for j in 0..h {
        for i in 0..k {
            w1[j * np + i] = p[o.w1 + j * n + i] as f64;
        }
        w1[j * np + LATENTS] = p[o.w1 + j * n + k] as f64;
        w1[j * np + LATENTS + 1] = p[o.w1 + j * n + k + 1] as f64;
        b1[j] = p[o.b1 + j] as f64;
    }
    let mut w2 = vec![0.0f64; hp * hp];
    let mut b2 = vec![0.0f64; hp];
    for j in 0..h {
        for i in 0..h {
            w2[j * hp + i] = p[o.w2 + j * h + i] as f64;
        }
        b2[j] = p[o.b2 + j] as f64;
    }
    // Output rows in the colour space's order: "bgr" swizzles them back to RGB.
    let mut w3 = vec![0.0f64; 3 * hp];
    let mut b3 = vec![0.0f64; 3];
    for (row, c) in [2usize, 1, 0].into_iter().enumerate() {
        for i in 0..h {
            w3[row * hp + i] = p[o.w3 + c * h + i] as f64;
        }
        b3[row] = p[o.b3 + c] as f64;
    }
    let planes = m.latents();
    let mut min = vec![0.0f64; LATENTS];
    let mut max = vec![0.0f64; LATENTS];
    for i in 0..k {
        min[i] = planes.bias[i] as f64;
        max[i] = planes.bias[i] as f64 + 255.0 * planes.scale[i] as f64;
    }
    let texels = height * width;
    let mut files = Vec::new();
    for img in 0..LATENTS / 3 {
        // Latents 3 img + 0, 1, 2 in the image's blue, green and red channels.
        let mut rgb = vec![0u8; texels * 3];
        for t in 0..texels {
            for (ch, lat) in [(2usize, 3 * img), (1, 3 * img + 1), (0, 3 * img + 2)] {
                if lat < k {
                    rgb[t * 3 + ch] = planes.q[t * k + lat];
                }
            }
        }
        for ext in ["png", "jpg"] {
            let name = format!("plane_{}.{ext}", img + 1);
            let target = dir.join(&name);
            write_atomic(&target, |w| crate::image::encode_rgb8(w, &rgb, width, height, ext, QUALITY))?;
            files.push(name);
        }
    }
    let info = json!({
        "type": "neural",
        "width": width,
        "height": height,
        "planes": LATENTS,
        "samples": hp,
        "format": "jpg",
        "quality": QUALITY,
        "colorspace": "bgr",
        "min": min,
        "max": max,
        "weights": [w1, w2, w3],
        "biases": [b1, b2, b3],
        "btfrs": {
            "values": "linear RGB with the light's cosine (btfrs's convention), not display-encoded",
            "latents": k,
            "hidden": h,
        },
    });
    let text = serde_json::to_string(&info).map_err(|e| Error::Numerical(format!("info.json: {e}")))?;
    // info.json last: a reader that finds it finds every plane.
    write_atomic(&dir.join("info.json"), |w| w.write_all(text.as_bytes()))?;
    files.push("info.json".into());
    Ok(json!({"min": min, "max": max, "files": files}))
}

fn import_model(path: &Path, limits: &Limits) -> Result<Imported> {
    Ok(Imported::model(Box::new(import_within(path, limits)?)))
}

/// Read a NeuralRTI folder (or its `info.json`) as a neural model with one view (the normal).
/// Planes are read from `plane_1.png` (lossless) where present, else `plane_1.jpg`, or the
/// same numbered from 0 as NeuralRTI names them.
pub fn import(path: &Path) -> Result<Neural> {
    import_within(path, &Limits::default())
}

/// [`import`] within `limits` (see [`crate::untrusted`]).
pub fn import_within(path: &Path, limits: &Limits) -> Result<Neural> {
    let (dir, shown, text) = read_index(path, "info.json", untrusted::JSON_INDEX, limits.max_bytes)?;
    let info = untrusted::parse_json(&text, &shown)?;
    drop(text);
    from_info(&dir, &shown, &info, limits)
}

/// The model of a NeuralRTI folder `dir` whose `info.json` (`shown`) holds `info`.
pub(crate) fn from_info(dir: &Path, shown: &str, info: &Value, limits: &Limits) -> Result<Neural> {
    let bad = |what: &str, msg: String| Error::format(shown, format!("{what}: {msg}"));
    if info["type"].as_str() != Some("neural") {
        return Err(bad("type", format!("expected \"neural\", got {}", info["type"])));
    }
    let dim = |key: &str| -> Result<usize> {
        info[key]
            .as_u64()
            .filter(|&v| v > 0 && v <= MAX_SIDE)
            .map(|v| v as usize)
            .ok_or_else(|| bad(key, format!("expected a size in 1..={MAX_SIDE}, got {}", info[key])))
    };
    let (width, height) = (dim("width")?, dim("height")?);
    let k = dim("planes")?;
    if k != LATENTS {
        return Err(bad("planes", format!("expected {LATENTS} latents (three images), got {k}")));
    }
    let floats = |v: &Value, what: &str| -> Result<Vec<f64>> {
        let a = v.as_array().ok_or_else(|| bad(what, "expected a list of numbers".into()))?;
        let mut out = Vec::with_capacity(a.len());
        for x in a {
            // OpenLIME flattens nested lists (min/max as one triple per image).
            if let Some(inner) = x.as_array() {
                for y in inner {
                    out.push(
                        y.as_f64()
                            .filter(|f| f.is_finite())
                            .ok_or_else(|| bad(what, format!("{y} is not a finite number")))?,
                    );
                }
            } else {
                out.push(
                    x.as_f64()
                        .filter(|f| f.is_finite())
                        .ok_or_else(|| bad(what, format!("{x} is not a finite number")))?,
                );
            }
        }
        Ok(out)
    };
    let min = floats(&info["min"], "min")?;
    let max = floats(&info["max"], "max")?;
    if min.len() != k || max.len() != k {
        return Err(bad("min", format!("expected {k} values in min and max, got {} and {}", min.len(), max.len())));
    }
    let layers = |key: &str| -> Result<Vec<Vec<f64>>> {
        let a =
            info[key].as_array().filter(|a| a.len() == 3).ok_or_else(|| bad(key, "expected three layers".into()))?;
        a.iter().enumerate().map(|(i, l)| floats(l, &format!("{key}[{i}]"))).collect()
    };
    let w = layers("weights")?;
    let b = layers("biases")?;
    let hp = b[0].len();
    let np = pad4(k + 2);
    if hp == 0 || hp > btfrs_fit::neural::MAX_HIDDEN || b[1].len() != hp || b[2].len() != 3 {
        return Err(bad(
            "biases",
            format!(
                "expected hidden biases of one width (at most {}) and 3 output biases, got {}, {}, {}",
                btfrs_fit::neural::MAX_HIDDEN,
                b[0].len(),
                b[1].len(),
                b[2].len()
            ),
        ));
    }
    if w[0].len() != hp * np || w[1].len() != hp * hp || w[2].len() != 3 * hp {
        return Err(bad(
            "weights",
            format!(
                "expected {hp} x {np}, {hp} x {hp} and 3 x {hp} values, got {}, {} and {}",
                w[0].len(),
                w[1].len(),
                w[2].len()
            ),
        ));
    }
    let swizzle: [usize; 3] = match info["colorspace"].as_str().unwrap_or("rgb") {
        "bgr" => [2, 1, 0],
        "rgb" => [0, 1, 2],
        other => return Err(bad("colorspace", format!("expected \"bgr\" or \"rgb\", got {other:?}"))),
    };
    let shape = Shape {
        latents: k,
        directions: Directions::Light,
        features: 0,
        grid: 2,
        hidden: hp,
        activation: Activation::Elu,
        horizon: 0,
    };
    let o = shape.offsets();
    let n = shape.inputs();
    let mut p = vec![0.0f32; o.len];
    for j in 0..hp {
        for i in 0..k + 2 {
            p[o.w1 + j * n + i] = w[0][j * np + i] as f32;
        }
        p[o.b1 + j] = b[0][j] as f32;
        for i in 0..hp {
            p[o.w2 + j * hp + i] = w[1][j * hp + i] as f32;
        }
        p[o.b2 + j] = b[1][j] as f32;
    }
    // Output row r is displayed as channel swizzle[r].
    for r in 0..3 {
        let c = swizzle[r];
        for i in 0..hp {
            p[o.w3 + c * hp + i] = w[2][r * hp + i] as f32;
        }
        p[o.b3 + c] = b[2][r] as f32;
    }
    let decoder = Decoder::new(shape, p, shown)?;
    // Planes: image i's channels (after the swizzle) are latents 3i, 3i+1, 3i+2. Their sizes
    // (headers) and the model's memory are checked before the planes are allocated.
    let files = (0..k / 3)
        .map(|img| {
            untrusted::first_present(
                [1 + img, img].iter().flat_map(|i| ["png", "jpg"].map(|e| dir.join(format!("plane_{i}.{e}")))),
            )
            .ok_or_else(|| bad("planes", format!("no plane_{}.png or .jpg beside it", img + 1)))
        })
        .collect::<Result<Vec<_>>>()?;
    let texels = width * height;
    let need =
        (texels as u64).checked_mul(k as u64).and_then(|n| n.checked_mul(crate::relight_file::BYTES_PER_PLANE_TEXEL));
    untrusted::check_declared(
        shown,
        &format!(
            "a {width} x {height} model of {k} latents ({} bytes per latent and texel)",
            crate::relight_file::BYTES_PER_PLANE_TEXEL
        ),
        need,
        limits.max_bytes,
    )?;
    untrusted::check_image_sizes(&files, width, height, "info.json")?;
    let mut q = vec![0u8; texels * k];
    for (img, file) in files.iter().enumerate() {
        let rgb = untrusted::read_rgb8(file, width, height, limits.max_bytes)?;
        for (t, px) in rgb.chunks_exact(3).enumerate() {
            for (j, &c) in swizzle.iter().enumerate() {
                q[t * k + 3 * img + j] = px[c];
            }
        }
    }
    let scale: Vec<f32> = (0..k).map(|i| ((max[i] - min[i]) / 255.0) as f32).collect();
    if let Some(i) = scale.iter().position(|&s| s < 0.0) {
        return Err(bad("max", format!("latent {i}: max {} is below min {}", max[i], min[i])));
    }
    let bias: Vec<f32> = min.iter().map(|&x| x as f32).collect();
    let planes = Planes { texels, k, q, scale, bias };
    Neural::new(height, width, planes, None, decoder, json!({"imported": "neuralrti"}))
        .map_err(untrusted::as_format(shown, "planes"))
}
