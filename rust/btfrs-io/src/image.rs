//! Image files: 8-bit sRGB PNG (for looking at) and float OpenEXR (HDR, exact) from linear RGB.

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

/// Read an 8-bit RGB or RGBA PNG into linear float RGB `[height, width, 3]` (sRGB decoded).
pub fn read_png(path: &Path) -> Result<(Vec<f32>, usize, usize)> {
    let shown = &path.display().to_string();
    let f = std::fs::File::open(path).map_err(|e| Error::io(shown, e))?;
    let dec = png::Decoder::new(std::io::BufReader::new(f));
    let mut r = dec.read_info().map_err(|e| Error::format(shown, e))?;
    let size = r.output_buffer_size().ok_or_else(|| Error::format(shown, "image too large"))?;
    let mut buf = vec![0u8; size];
    let info = r.next_frame(&mut buf).map_err(|e| Error::format(shown, e))?;
    let ch = match (info.color_type, info.bit_depth) {
        (png::ColorType::Rgb, png::BitDepth::Eight) => 3,
        (png::ColorType::Rgba, png::BitDepth::Eight) => 4,
        (c, d) => return Err(Error::format(shown, format!("unsupported PNG {c:?} {d:?}; expected 8-bit RGB or RGBA"))),
    };
    let (w, h) = (info.width as usize, info.height as usize);
    let srgb_to_linear = |b: u8| {
        let x = b as f32 / 255.0;
        if x <= 0.04045 {
            x / 12.92
        } else {
            ((x + 0.055) / 1.055).powf(2.4)
        }
    };
    let out = buf[..w * h * ch].chunks(ch).flat_map(|p| [p[0], p[1], p[2]].map(srgb_to_linear)).collect();
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
pub fn read_exr(path: &Path) -> Result<(Vec<f32>, usize, usize)> {
    use exr::prelude::{read_first_rgba_layer_from_file, Vec2};
    let shown = &path.display().to_string();
    if !path.exists() {
        return Err(Error::io(shown, std::io::Error::from(std::io::ErrorKind::NotFound)));
    }
    let img = read_first_rgba_layer_from_file(
        path,
        |res: Vec2<usize>, _| (vec![0.0f32; res.0 * res.1 * 3], res.0, res.1),
        |px: &mut (Vec<f32>, usize, usize), Vec2(x, y): Vec2<usize>, (r, g, b, _a): (f32, f32, f32, f32)| {
            let i = (y * px.1 + x) * 3;
            px.0[i..i + 3].copy_from_slice(&[r, g, b]);
        },
    )
    .map_err(|e| Error::format(shown, e))?;
    let (data, w, h) = img.layer_data.channel_data.pixels;
    Ok((data, w, h))
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
}
