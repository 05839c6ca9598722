//! Photographs and HDR images in: JPEG, PNG and TIFF (8 or 16 bit, grey or colour, through the
//! `image` crate) and OpenEXR (through the `exr` crate), decoded to linear float RGB.
//!
//! Integer images are sRGB-encoded unless the caller says they are linear (RTI captures shot
//! in RAW and converted to 16-bit linear TIFF are); the sRGB decode is IEC 61966-2-1's curve,
//! through a lookup table per bit depth. Float images (EXR, 32-bit float TIFF) are linear and
//! kept as they are, but must be finite: a NaN or infinity is an error naming the file, as it
//! would otherwise poison every fit.
//!
//! Untrusted files: the declared size is checked against what the file can hold before the
//! pixel buffer is allocated (the `image` crate's allocation limit, set from the file length
//! and the format's largest compression ratio, and [`crate::image`]'s EXR bound).

use btfrs_core::{Error, Result};
use std::io::Cursor;

/// How integer pixel values map to linear light.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Transfer {
    /// sRGB-encoded (cameras' JPEGs, most PNGs): decoded with the sRGB curve.
    #[default]
    Srgb,
    /// Already linear: value / max.
    Linear,
}

/// A decoded image: `[height, width, 3]` linear RGB.
#[derive(Debug, Clone, PartialEq)]
pub struct Decoded {
    /// Columns.
    pub width: usize,
    /// Rows (row 0 is the top of the picture).
    pub height: usize,
    /// `height * width * 3` values.
    pub rgb: Vec<f32>,
}

/// The sRGB decode of `x` in [0, 1].
#[inline]
pub fn srgb_to_linear(x: f32) -> f32 {
    if x <= 0.040_45 {
        x / 12.92
    } else {
        ((x + 0.055) / 1.055).powf(2.4)
    }
}

fn lut(bits: u32, transfer: Transfer) -> Vec<f32> {
    let max = ((1u32 << bits) - 1) as f32;
    (0..1u32 << bits)
        .map(|v| {
            let x = v as f32 / max;
            match transfer {
                Transfer::Srgb => srgb_to_linear(x),
                Transfer::Linear => x,
            }
        })
        .collect()
}

fn lut8(transfer: Transfer) -> &'static [f32] {
    static S: std::sync::OnceLock<Vec<f32>> = std::sync::OnceLock::new();
    static L: std::sync::OnceLock<Vec<f32>> = std::sync::OnceLock::new();
    match transfer {
        Transfer::Srgb => S.get_or_init(|| lut(8, Transfer::Srgb)),
        Transfer::Linear => L.get_or_init(|| lut(8, Transfer::Linear)),
    }
}

fn lut16(transfer: Transfer) -> &'static [f32] {
    static S: std::sync::OnceLock<Vec<f32>> = std::sync::OnceLock::new();
    static L: std::sync::OnceLock<Vec<f32>> = std::sync::OnceLock::new();
    match transfer {
        Transfer::Srgb => S.get_or_init(|| lut(16, Transfer::Srgb)),
        Transfer::Linear => L.get_or_init(|| lut(16, Transfer::Linear)),
    }
}

/// Whether `name` is an OpenEXR file by its extension.
pub fn is_exr(name: &str) -> bool {
    name.rsplit('.').next().is_some_and(|e| e.eq_ignore_ascii_case("exr"))
}

/// Image file extensions the loaders pick up in a folder or archive.
pub const EXTENSIONS: &[&str] = &["jpg", "jpeg", "png", "tif", "tiff", "exr"];

/// Whether `name` has one of [`EXTENSIONS`].
pub fn is_image(name: &str) -> bool {
    name.rsplit_once('.').is_some_and(|(_, e)| EXTENSIONS.iter().any(|x| e.eq_ignore_ascii_case(x)))
}

/// Decode an image file's bytes; `shown` names it in errors.
pub fn decode(bytes: &[u8], shown: &str, transfer: Transfer) -> Result<Decoded> {
    if is_exr(shown) {
        let (rgb, width, height) = crate::image::read_exr_bytes(bytes, shown)?;
        if let Some(i) = rgb.iter().position(|x| !x.is_finite()) {
            let (p, c) = (i / 3, i % 3);
            return Err(Error::format(
                shown,
                format!(
                    "pixel (row {}, column {}) channel {c} is {}; expected finite values",
                    p / width,
                    p % width,
                    rgb[i]
                ),
            ));
        }
        return Ok(Decoded { width, height, rgb });
    }
    let mut reader =
        image::ImageReader::new(Cursor::new(bytes)).with_guessed_format().map_err(|e| Error::format(shown, e))?;
    if reader.format().is_none() {
        return Err(Error::format(shown, "not a JPEG, PNG, TIFF or OpenEXR image"));
    }
    // Compressed formats expand; deflate at most ~1032:1 (PNG, TIFF), and a float RGBA pixel
    // is 16 bytes. The bound only has to stop absurd headers, not be tight.
    let mut limits = image::Limits::default();
    limits.max_alloc = Some((bytes.len() as u64).saturating_mul(1032 * 4).clamp(1 << 20, 16 << 30));
    reader.limits(limits);
    let img = reader.decode().map_err(|e| Error::format(shown, e))?;
    let (width, height) = (img.width() as usize, img.height() as usize);
    use image::DynamicImage as D;
    let rgb: Vec<f32> = match &img {
        D::ImageLuma8(b) => b.as_raw().iter().flat_map(|&v| [lut8(transfer)[v as usize]; 3]).collect(),
        D::ImageLumaA8(b) => b.as_raw().chunks(2).flat_map(|p| [lut8(transfer)[p[0] as usize]; 3]).collect(),
        D::ImageRgb8(b) => b.as_raw().iter().map(|&v| lut8(transfer)[v as usize]).collect(),
        D::ImageRgba8(b) => {
            b.as_raw().chunks(4).flat_map(|p| [p[0], p[1], p[2]].map(|v| lut8(transfer)[v as usize])).collect()
        }
        D::ImageLuma16(b) => b.as_raw().iter().flat_map(|&v| [lut16(transfer)[v as usize]; 3]).collect(),
        D::ImageLumaA16(b) => b.as_raw().chunks(2).flat_map(|p| [lut16(transfer)[p[0] as usize]; 3]).collect(),
        D::ImageRgb16(b) => b.as_raw().iter().map(|&v| lut16(transfer)[v as usize]).collect(),
        D::ImageRgba16(b) => {
            b.as_raw().chunks(4).flat_map(|p| [p[0], p[1], p[2]].map(|v| lut16(transfer)[v as usize])).collect()
        }
        D::ImageRgb32F(b) => b.as_raw().clone(),
        D::ImageRgba32F(b) => b.as_raw().chunks(4).flat_map(|p| [p[0], p[1], p[2]]).collect(),
        other => return Err(Error::format(shown, format!("unsupported pixel layout {:?}", other.color()))),
    };
    if let Some(i) = rgb.iter().position(|x| !x.is_finite()) {
        return Err(Error::format(shown, format!("value at flat index {i} is {}; expected finite values", rgb[i])));
    }
    Ok(Decoded { width, height, rgb })
}

/// Read and decode an image file.
pub fn read(path: &std::path::Path, transfer: Transfer) -> Result<Decoded> {
    let shown = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|e| Error::io(&shown, e))?;
    decode(&bytes, &shown, transfer)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn encode(img: image::DynamicImage, fmt: image::ImageFormat) -> Vec<u8> {
        let mut c = Cursor::new(Vec::new());
        img.write_to(&mut c, fmt).unwrap();
        c.into_inner()
    }

    #[test]
    fn eight_and_sixteen_bit_grey_and_colour_decode_to_the_srgb_curve() {
        let rgb8 = image::RgbImage::from_fn(3, 2, |x, y| image::Rgb([(x * 100) as u8, (y * 200) as u8, 255]));
        let png = encode(image::DynamicImage::ImageRgb8(rgb8), image::ImageFormat::Png);
        let d = decode(&png, "a.png", Transfer::Srgb).unwrap();
        assert_eq!((d.width, d.height), (3, 2));
        // pixel (row 1, col 2): 200/255 -> sRGB decode, closed form
        let px = &d.rgb[(3 + 2) * 3..(3 + 2) * 3 + 3];
        let expect = ((200.0f64 / 255.0 + 0.055) / 1.055).powf(2.4) as f32;
        assert!((px[1] - expect).abs() < 1e-6 && (px[2] - 1.0).abs() < 1e-6);
        assert!((px[0] - (((200.0f64 / 255.0 + 0.055) / 1.055).powf(2.4)) as f32).abs() < 1e-6);
        let lin = decode(&png, "a.png", Transfer::Linear).unwrap();
        assert!((lin.rgb[(3 + 2) * 3 + 1] - 200.0 / 255.0).abs() < 1e-6);

        let g16 =
            image::ImageBuffer::<image::Luma<u16>, _>::from_fn(2, 2, |x, y| image::Luma([(x + 2 * y) as u16 * 20000]));
        for fmt in [image::ImageFormat::Png, image::ImageFormat::Tiff] {
            let bytes = encode(image::DynamicImage::ImageLuma16(g16.clone()), fmt);
            let d = decode(&bytes, "g", Transfer::Linear).unwrap();
            assert_eq!(d.rgb.len(), 12);
            assert!((d.rgb[9] - 60000.0 / 65535.0).abs() < 1e-6 && d.rgb[9] == d.rgb[11], "{fmt:?}");
        }
        let jpg = encode(
            image::DynamicImage::ImageRgb8(image::RgbImage::from_pixel(8, 8, image::Rgb([128, 128, 128]))),
            image::ImageFormat::Jpeg,
        );
        let d = decode(&jpg, "a.jpg", Transfer::Srgb).unwrap();
        assert!(d.rgb.iter().all(|&v| (v - srgb_to_linear(128.0 / 255.0)).abs() < 0.01));
    }

    #[test]
    fn garbage_and_non_finite_exr_are_named_errors() {
        let e = decode(b"hello, not an image at all", "x.png", Transfer::Srgb).unwrap_err().to_string();
        assert!(e.starts_with("x.png:"), "{e}");
        use exr::prelude::{Encoding, Image, Layer, LayerAttributes, SpecificChannels, Vec2, WritableImage};
        let enc = |bad: bool| {
            let px = SpecificChannels::rgb(move |Vec2(x, y): Vec2<usize>| {
                let g = if bad && (x, y) == (1, 0) { f32::NAN } else { 0.5 };
                (0.5f32, g, 0.5f32)
            });
            let layer = Layer::new((2, 2), LayerAttributes::default(), Encoding::UNCOMPRESSED, px);
            let mut c = Cursor::new(Vec::new());
            Image::from_layer(layer).write().to_buffered(&mut c).unwrap();
            c.into_inner()
        };
        assert_eq!(decode(&enc(false), "a.exr", Transfer::Srgb).unwrap().rgb, vec![0.5; 12]);
        let e = decode(&enc(true), "a.exr", Transfer::Srgb).unwrap_err().to_string();
        assert!(e.contains("a.exr") && e.contains("row 0, column 1") && e.contains("finite"), "{e}");
    }
}
