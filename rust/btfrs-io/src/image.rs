//! Image files: 8-bit sRGB PNG (for looking at) and float OpenEXR (HDR, exact) from linear RGB.
//!
//! The readers take untrusted files: the size a header declares is checked against what the
//! file can hold before any pixel buffer is allocated. Both formats compress, so "can hold" is
//! the file length times the largest expansion of the format's compression: deflate (PNG,
//! EXR's ZIP and PXR24) inflates at most 1032 to 1, so a 100-byte PNG cannot decode to more than
//! about 100 KB, whatever its header says.

use crate::atomic::write_atomic;
use btfrs_core::{Error, Result};
use std::path::Path;

/// Linear [0, 1] -> sRGB-encoded [0, 1] (IEC 61966-2-1).
#[inline]
pub fn linear_to_srgb(x: f32) -> f32 {
    let x = x.clamp(0.0, 1.0);
    if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    }
}

/// Write a `[height, width, 3]` linear RGB image as an 8-bit sRGB PNG, multiplying by `exposure`
/// first and clipping to [0, 1]. NaN or infinite pixels are an error (they would silently become
/// black or white).
pub fn write_png(path: &Path, rgb: &[f32], width: usize, height: usize, exposure: f32) -> Result<()> {
    if width == 0 || height == 0 || rgb.len() != width * height * 3 {
        return Err(Error::arg("image", format!("expected {height} x {width} x 3 values, got {}", rgb.len())));
    }
    if let Some(i) = rgb.iter().position(|x| !x.is_finite()) {
        return Err(Error::arg("image", format!("pixel value at flat index {i} is not finite")));
    }
    if !(exposure.is_finite() && exposure > 0.0) {
        return Err(Error::arg("exposure", format!("expected a positive number, got {exposure}")));
    }
    let bytes: Vec<u8> = rgb.iter().map(|&x| (linear_to_srgb(x * exposure) * 255.0 + 0.5) as u8).collect();
    write_atomic(path, |w| {
        let mut enc = png::Encoder::new(w, width as u32, height as u32);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        enc.set_source_srgb(png::SrgbRenderingIntent::Perceptual);
        let mut wr = enc.write_header().map_err(std::io::Error::other)?;
        wr.write_image_data(&bytes).map_err(std::io::Error::other)?;
        wr.finish().map_err(std::io::Error::other)
    })
}

/// Write `[height][width][channels]` values in [0, 1] as a 16-bit PNG (grey for 1 channel, RGB
/// for 3), stored as they are: data maps (normals, heights, roughness), not colours, so no sRGB
/// curve and no sRGB chunk. Values outside [0, 1] or not finite are refused, naming the first.
pub fn write_png16(path: &Path, values: &[f32], width: usize, height: usize, channels: usize) -> Result<()> {
    if !matches!(channels, 1 | 3) || width == 0 || height == 0 || values.len() != width * height * channels {
        return Err(Error::arg(
            "image",
            format!("expected {height} x {width} x 1 or 3 values, got {} with {channels} channels", values.len()),
        ));
    }
    if let Some(i) = values.iter().position(|x| !(x.is_finite() && (0.0..=1.0).contains(x))) {
        return Err(Error::arg(
            "image",
            format!("value {} at flat index {i} is outside [0, 1] (a 16-bit PNG stores [0, 1])", values[i]),
        ));
    }
    // PNG stores 16-bit samples big-endian.
    let bytes: Vec<u8> = values.iter().flat_map(|&x| ((x * 65535.0 + 0.5) as u16).to_be_bytes()).collect();
    write_atomic(path, |w| {
        let mut enc = png::Encoder::new(w, width as u32, height as u32);
        enc.set_color(if channels == 1 { png::ColorType::Grayscale } else { png::ColorType::Rgb });
        enc.set_depth(png::BitDepth::Sixteen);
        let mut wr = enc.write_header().map_err(std::io::Error::other)?;
        wr.write_image_data(&bytes).map_err(std::io::Error::other)?;
        wr.finish().map_err(std::io::Error::other)
    })
}

/// Largest ratio of decompressed to compressed bytes of deflate (RFC 1951): a 258-byte match
/// costs at least 2 bits, so 1032 output bytes per input byte at most.
const DEFLATE_MAX_RATIO: u64 = 1032;

/// Largest ratio of decoded pixel bytes to file bytes this reader accepts for an OpenEXR layer:
/// deflate's 1032 times PXR24's 4/3 (it deflates 24 of every 32 bits) is below it, and RLE
/// (at most 128 bytes from 2), PIZ and B44 expand less.
const EXR_MAX_RATIO: u64 = 2048;

/// The error for a header that declares more pixel bytes than the file can hold.
/// Encode 8-bit RGB bytes (`width x height`, rows top first) as PNG (`ext` "png") or JPEG at
/// `quality`: the plane images of the web formats (relight's, NeuralRTI's), which hold data,
/// not pictures.
pub fn encode_rgb8(
    w: &mut dyn std::io::Write,
    rgb: &[u8],
    width: usize,
    height: usize,
    ext: &str,
    quality: u8,
) -> std::io::Result<()> {
    use image::ImageEncoder;
    let (wd, ht) = (width as u32, height as u32);
    let r = if ext == "png" {
        image::codecs::png::PngEncoder::new(w).write_image(rgb, wd, ht, image::ExtendedColorType::Rgb8)
    } else {
        image::codecs::jpeg::JpegEncoder::new_with_quality(w, quality).write_image(
            rgb,
            wd,
            ht,
            image::ExtendedColorType::Rgb8,
        )
    };
    r.map_err(std::io::Error::other)
}

fn too_large(shown: &str, what: String, need: Option<u64>, len: u64, ratio: u64) -> Error {
    let need = need.map_or_else(|| "more than 2^64".into(), |n| n.to_string());
    Error::format(
        shown,
        format!(
            "the header declares {what} ({need} bytes of pixels), more than a file of {len} bytes can hold \
             (at most {ratio} times its size); the file is corrupted or truncated"
        ),
    )
}

/// Read an 8-bit RGB or RGBA PNG into linear float RGB `[height, width, 3]` (sRGB decoded).
///
/// Anything else (palette, grey, 16-bit) is an [`Error::Format`], as is a corrupted file; the
/// pixel buffer is allocated only once the declared size is known to fit the file.
pub fn read_png(path: &Path) -> Result<(Vec<f32>, usize, usize)> {
    let shown = &path.display().to_string();
    let (f, len) = crate::untrusted::open(path)?;
    let most = len.saturating_mul(DEFLATE_MAX_RATIO);
    let mut dec = png::Decoder::new(std::io::BufReader::new(f));
    // Text and ICC chunks are not used; skipping them avoids their (compressed) allocations.
    dec.set_ignore_text_chunk(true);
    dec.set_ignore_iccp_chunk(true);
    // The decoder's own buffers (rows, chunks) within what the file can justify too.
    dec.set_limits(png::Limits { bytes: usize::try_from(most).unwrap_or(usize::MAX).clamp(1 << 16, 64 << 20) });
    // The IHDR chunk first: colour type and size are checked before the decoder sets up its
    // buffers. No transformations are set, so the output has the file's colour type and depth.
    let info = dec.read_header_info().map_err(|e| Error::format(shown, e))?;
    let ch: u64 = match (info.color_type, info.bit_depth) {
        (png::ColorType::Rgb, png::BitDepth::Eight) => 3,
        (png::ColorType::Rgba, png::BitDepth::Eight) => 4,
        (c, d) => return Err(Error::format(shown, format!("unsupported PNG {c:?} {d:?}; expected 8-bit RGB or RGBA"))),
    };
    let (hw, hh) = info.size();
    let need = u64::from(hw).checked_mul(u64::from(hh)).and_then(|p| p.checked_mul(ch));
    if need.is_none_or(|n| n > most) {
        return Err(too_large(shown, format!("{hw} x {hh} pixels"), need, len, DEFLATE_MAX_RATIO));
    }
    // The float image it becomes: within the memory budget and a plausible ratio to the file.
    crate::capture::check_image_budget(shown, u64::from(hw), u64::from(hh), len, crate::capture::default_max_bytes())?;
    // Decoded in place into its floats ([`crate::decode::decode_place`]): no 8-bit copy is held.
    let mut out = Vec::new();
    let (w, h) = crate::decode::read_place(
        path,
        crate::decode::Transfer::Srgb,
        crate::capture::default_max_bytes(),
        crate::decode::Place::New(&mut out),
    )?;
    Ok((out, w, h))
}

/// Write a `[height, width, 3]` linear RGB image as a 32-bit float OpenEXR file (the `exr`
/// crate; encoded in memory, then written atomically). Non-finite pixels are an error.
pub fn write_exr(path: &Path, rgb: &[f32], width: usize, height: usize) -> Result<()> {
    use exr::prelude::{Image, SpecificChannels, Vec2, WritableImage};
    if width == 0 || height == 0 || rgb.len() != width * height * 3 {
        return Err(Error::arg("image", format!("expected {height} x {width} x 3 values, got {}", rgb.len())));
    }
    if let Some(i) = rgb.iter().position(|x| !x.is_finite()) {
        return Err(Error::arg("image", format!("pixel value at flat index {i} is not finite")));
    }
    let channels = SpecificChannels::rgb(|Vec2(x, y): Vec2<usize>| {
        let i = (y * width + x) * 3;
        (rgb[i], rgb[i + 1], rgb[i + 2])
    });
    let mut buf = std::io::Cursor::new(Vec::new());
    Image::from_channels((width, height), channels)
        .write()
        .to_buffered(&mut buf)
        .map_err(|e| Error::arg("image", format!("could not encode OpenEXR: {e}")))?;
    write_atomic(path, |w| w.write_all(buf.get_ref()))
}

/// Read the first RGB(A) layer of an OpenEXR file as `[height, width, 3]` f32 (alpha dropped).
///
/// The headers are read first and every layer's declared size is checked against the file
/// length (see [`EXR_MAX_RATIO`]) before the pixels are decoded; a corrupted file is an
/// [`Error::Format`].
pub fn read_exr(path: &Path) -> Result<(Vec<f32>, usize, usize)> {
    read_exr_within(path, crate::capture::default_max_bytes())
}

/// [`read_exr`] within `max_bytes`: the file itself, and every layer's float RGB pixels.
pub fn read_exr_within(path: &Path, max_bytes: u64) -> Result<(Vec<f32>, usize, usize)> {
    let shown = &path.display().to_string();
    let bytes = crate::untrusted::read_bytes(path, max_bytes, "an OpenEXR image within max_bytes")?;
    let meta = exr::meta::MetaData::read_from_buffered(std::io::Cursor::new(&bytes), false)
        .map_err(|e| Error::format(shown, e))?;
    for h in &meta.headers {
        let (w, ht) = (h.layer_size.0 as u64, h.layer_size.1 as u64);
        crate::untrusted::check_declared(
            shown,
            &format!("a {w} x {ht} layer as float RGB"),
            w.checked_mul(ht).and_then(|p| p.checked_mul(12)),
            max_bytes,
        )?;
    }
    read_exr_bytes(&bytes, shown)
}

/// [`read_exr`] of a file's bytes (an archive member, say); `shown` names it in errors. A file
/// with only a luminance channel `Y` is read as grey.
pub fn read_exr_bytes(bytes: &[u8], shown: &str) -> Result<(Vec<f32>, usize, usize)> {
    use exr::prelude::{read, ReadChannels, ReadLayers};
    let len = bytes.len() as u64;
    let meta = exr::meta::MetaData::read_from_buffered(std::io::Cursor::new(bytes), false)
        .map_err(|e| Error::format(shown, e))?;
    let most = len.saturating_mul(EXR_MAX_RATIO);
    for h in &meta.headers {
        let (w, ht) = (h.layer_size.0, h.layer_size.1);
        let need = (w as u64).checked_mul(ht as u64).and_then(|p| p.checked_mul(h.channels.bytes_per_pixel as u64));
        // The layer we decode has R, G and B (6 bytes per pixel or more), so our 12-byte pixels
        // stay within twice this bound.
        if need.is_none_or(|n| n > most) {
            return Err(too_large(shown, format!("a {w} x {ht} layer"), need, len, EXR_MAX_RATIO));
        }
    }
    let img = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_buffered(std::io::Cursor::new(bytes))
        .map_err(|e| Error::format(shown, e))?;
    let layer = img.layer_data;
    let (w, h) = (layer.size.0, layer.size.1);
    let find = |n: &str| {
        layer.channel_data.list.iter().find(|c| {
            let name = c.name.to_string();
            name == n || name.ends_with(&format!(".{n}"))
        })
    };
    let chans: Vec<_> = match (find("R"), find("G"), find("B"), find("Y")) {
        (Some(r), Some(g), Some(b), _) => vec![r, g, b],
        (_, _, _, Some(y)) => vec![y, y, y],
        _ => {
            let names: Vec<String> = layer.channel_data.list.iter().map(|c| c.name.to_string()).collect();
            return Err(Error::format(shown, format!("expected R, G and B (or Y) channels, found {names:?}")));
        }
    };
    let mut out = vec![0.0f32; w * h * 3];
    for (c, ch) in chans.iter().enumerate() {
        for (i, v) in ch.sample_data.values_as_f32().enumerate().take(w * h) {
            out[i * 3 + c] = v;
        }
    }
    Ok((out, w, h))
}

/// Write named float channels of one `width x height` layer as an OpenEXR file (32-bit float,
/// ZIP-compressed): the coefficient maps of a model, `ptm.a0.R` and so on. Channel names must
/// be unique and non-empty; every channel holds `width * height` finite values (row 0 at the
/// top). Written atomically.
pub fn write_exr_channels(path: &Path, width: usize, height: usize, channels: &[(String, Vec<f32>)]) -> Result<()> {
    use exr::prelude::{
        AnyChannel, AnyChannels, Encoding, FlatSamples, Image, Layer, LayerAttributes, SmallVec, WritableImage,
    };
    if width == 0 || height == 0 {
        return Err(Error::arg("image", format!("expected a non-empty image, got {height} x {width}")));
    }
    if channels.is_empty() {
        return Err(Error::arg("channels", "expected at least one channel"));
    }
    let mut seen = std::collections::HashSet::new();
    for (name, v) in channels {
        if name.is_empty() || !seen.insert(name.as_str()) {
            return Err(Error::arg("channels", format!("channel name {name:?} is empty or used twice")));
        }
        if v.len() != width * height {
            return Err(Error::arg(
                name,
                format!("expected {} values ({height} x {width}), got {}", width * height, v.len()),
            ));
        }
        if let Some(i) = v.iter().position(|x| !x.is_finite()) {
            return Err(Error::arg(name, format!("value {i} is not finite")));
        }
    }
    let list: SmallVec<[AnyChannel<FlatSamples>; 4]> =
        channels.iter().map(|(n, v)| AnyChannel::new(n.as_str(), FlatSamples::F32(v.clone()))).collect();
    let layer =
        Layer::new((width, height), LayerAttributes::default(), Encoding::SMALL_LOSSLESS, AnyChannels::sort(list));
    let mut buf = std::io::Cursor::new(Vec::new());
    Image::from_layer(layer)
        .write()
        .to_buffered(&mut buf)
        .map_err(|e| Error::arg("channels", format!("could not encode OpenEXR: {e}")))?;
    write_atomic(path, |w| w.write_all(buf.get_ref()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn png_round_trip_within_quantization() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.png");
        let img: Vec<f32> = (0..4 * 3 * 3).map(|i| i as f32 / 36.0).collect();
        write_png(&p, &img, 4, 3, 1.0).unwrap();
        let (back, w, h) = read_png(&p).unwrap();
        assert_eq!((w, h), (4, 3));
        for (a, b) in img.iter().zip(&back) {
            // One 8-bit sRGB step is at most ~0.013 in linear units near white.
            assert!((a - b).abs() < 0.014, "{a} vs {b}");
        }
        let mut bad = img.clone();
        bad[5] = f32::NAN;
        assert!(write_png(&p, &bad, 4, 3, 1.0).unwrap_err().to_string().contains("index 5"));
    }
}

#[cfg(test)]
mod exr_tests {
    use super::*;

    #[test]
    fn exr_round_trip_is_exact_and_keeps_hdr_values() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.exr");
        // Values above 1 and tiny ones survive: no clipping, no quantisation (32-bit float).
        let img: Vec<f32> = (0..5 * 3 * 3).map(|i| (i as f32 - 7.0) * 0.37 + 1e-6 * i as f32).collect();
        write_exr(&p, &img, 5, 3).unwrap();
        let (back, w, h) = read_exr(&p).unwrap();
        assert_eq!((w, h), (5, 3));
        assert_eq!(back, img);
        assert!(write_exr(&p, &img[..10], 5, 3).unwrap_err().to_string().starts_with("image:"));
        assert!(matches!(read_exr(&dir.path().join("none.exr")), Err(Error::Io { .. })));
        std::fs::write(&p, b"not an exr").unwrap();
        assert!(matches!(read_exr(&p), Err(Error::Format { .. })));
    }

    #[test]
    fn named_channels_round_trip_through_the_exr_crate() {
        use exr::prelude::{read, ReadChannels, ReadLayers};
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("maps.exr");
        let (w, h) = (5, 3);
        let chans: Vec<(String, Vec<f32>)> = ["ptm.coeffs.0.R.0", "ptm.coeffs.0.G.0", "lpca.cluster"]
            .iter()
            .enumerate()
            .map(|(k, n)| (n.to_string(), (0..w * h).map(|i| (i * 10 + k) as f32 * 0.25 - 3.0).collect()))
            .collect();
        write_exr_channels(&p, w, h, &chans).unwrap();
        let img = read()
            .no_deep_data()
            .largest_resolution_level()
            .all_channels()
            .first_valid_layer()
            .all_attributes()
            .from_file(&p)
            .unwrap();
        assert_eq!((img.layer_data.size.0, img.layer_data.size.1), (w, h));
        for (name, vals) in &chans {
            let c =
                img.layer_data.channel_data.list.iter().find(|c| c.name.to_string() == *name).expect("channel present");
            let got: Vec<f32> = c.sample_data.values_as_f32().collect();
            assert_eq!(&got, vals, "{name}");
        }
        assert!(write_exr_channels(&p, w, h, &[("a".into(), vec![0.0; 3])]).unwrap_err().to_string().starts_with("a:"));
        let dup = vec![("a".to_string(), vec![0.0; 15]), ("a".to_string(), vec![0.0; 15])];
        assert!(write_exr_channels(&p, w, h, &dup).unwrap_err().to_string().contains("used twice"));
        let nan = vec![("a".to_string(), vec![f32::NAN; 15])];
        assert!(write_exr_channels(&p, w, h, &nan).unwrap_err().to_string().contains("not finite"));
    }
}
