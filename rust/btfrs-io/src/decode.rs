//! Photographs and HDR images in: JPEG, PNG and TIFF (8 or 16 bit, grey or colour, through the
//! `image` crate) and OpenEXR (through the `exr` crate), decoded to linear float RGB.
//!
//! Integer images are sRGB-encoded unless the caller says they are linear (RTI captures shot
//! in RAW and converted to 16-bit linear TIFF are); the sRGB decode is IEC 61966-2-1's curve,
//! through a lookup table per bit depth. Float images (EXR, 32-bit float TIFF) are linear and
//! kept as they are, but must be finite: a NaN or infinity is an error naming the file, as it
//! would otherwise poison every fit.
//!
//! Untrusted files: the declared size is checked before the pixel buffer is allocated, against
//! the memory budget and a plausible ratio to the bytes on disk
//! ([`crate::capture::check_image_budget`]), besides the `image` crate's allocation limit and
//! [`crate::image`]'s EXR bound. A JPEG without its end-of-image marker or a PNG without its
//! IEND chunk is refused as truncated (the decoders would pad a cut file silently).

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

/// An image decoded but not yet converted: the file's own samples (8 or 16-bit integers, or
/// float), converted to linear float RGB pixel by pixel as it is scattered into a capture, so a
/// batch of images never holds float copies (a one-image stack peaks at the output plus the
/// file's samples, 1.25 times the output for 8-bit RGB).
#[derive(Debug, Clone, PartialEq)]
pub struct Raw {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    samples: Samples,
    transfer: Transfer,
}

#[derive(Debug, Clone, PartialEq)]
enum Samples {
    U8(Vec<u8>, usize),
    U16(Vec<u16>, usize),
    F32(Vec<f32>, usize),
}

impl Raw {
    /// Linear RGB of pixel `p` (row-major).
    #[inline]
    pub fn rgb(&self, p: usize) -> [f32; 3] {
        match &self.samples {
            Samples::U8(v, ch) => {
                let (l, i) = (lut8(self.transfer), p * ch);
                if *ch < 3 {
                    [l[v[i] as usize]; 3]
                } else {
                    [l[v[i] as usize], l[v[i + 1] as usize], l[v[i + 2] as usize]]
                }
            }
            Samples::U16(v, ch) => {
                let (l, i) = (lut16(self.transfer), p * ch);
                if *ch < 3 {
                    [l[v[i] as usize]; 3]
                } else {
                    [l[v[i] as usize], l[v[i + 1] as usize], l[v[i + 2] as usize]]
                }
            }
            Samples::F32(v, ch) => {
                let i = p * ch;
                if *ch < 3 {
                    [v[i]; 3]
                } else {
                    [v[i], v[i + 1], v[i + 2]]
                }
            }
        }
    }

    /// Convert to float RGB.
    pub fn into_decoded(self) -> Decoded {
        let rgb = (0..self.width * self.height).flat_map(|p| self.rgb(p)).collect();
        Decoded { width: self.width, height: self.height, rgb }
    }
}

/// Decode an image file's bytes; `shown` names it in errors.
pub fn decode(bytes: &[u8], shown: &str, transfer: Transfer) -> Result<Decoded> {
    let budget = crate::capture::default_max_bytes();
    Ok(decode_raw(bytes, shown, transfer, bytes.len() as u64, budget)?.into_decoded())
}

/// That a JPEG's entropy-coded data is complete: the segments before the first scan are walked
/// by their lengths, and an end-of-image marker (FF D9) must follow the scan data (byte
/// stuffing keeps FF D9 out of entropy-coded data; bytes after it are allowed).
pub fn check_jpeg_complete(bytes: &[u8], shown: &str) -> Result<()> {
    let bad = |m: &str| Err(Error::format(shown, format!("{m}; the JPEG is truncated or corrupted")));
    if !bytes.starts_with(&[0xFF, 0xD8]) {
        return bad("no start-of-image marker (FF D8)");
    }
    let mut pos = 2;
    loop {
        while bytes.get(pos) == Some(&0xFF) && bytes.get(pos + 1) == Some(&0xFF) {
            pos += 1;
        }
        let (Some(&0xFF), Some(&m)) = (bytes.get(pos), bytes.get(pos + 1)) else {
            return bad(&format!("expected a marker at byte {pos} before the image data"));
        };
        if m == 0xDA {
            break;
        }
        if m == 0x01 || (0xD0..=0xD7).contains(&m) {
            pos += 2;
            continue;
        }
        let Some(len) = bytes.get(pos + 2..pos + 4).map(|b| u16::from_be_bytes([b[0], b[1]]) as usize) else {
            return bad(&format!("segment at byte {pos} is cut"));
        };
        pos += 2 + len;
    }
    if !bytes[pos..].windows(2).any(|w| w == [0xFF, 0xD9]) {
        return bad("no end-of-image marker (FF D9) after the image data");
    }
    Ok(())
}

/// The IEND chunk with its CRC, which closes every complete PNG.
const PNG_IEND: [u8; 12] = [0, 0, 0, 0, b'I', b'E', b'N', b'D', 0xAE, 0x42, 0x60, 0x82];

/// That a PNG ends with its IEND chunk (bytes after it are allowed). Chunk CRCs and the zlib
/// checksum are checked by the decoder.
pub fn check_png_complete(bytes: &[u8], shown: &str) -> Result<()> {
    if !bytes.windows(12).any(|w| w == PNG_IEND) {
        return Err(Error::format(shown, "no IEND chunk at the end; the PNG is truncated or corrupted"));
    }
    Ok(())
}

/// Decode an image file's bytes (`shown` names it in errors) without converting its samples,
/// checking first that its decoded float size fits `max_bytes` and [`crate::capture::MAX_DECODE_RATIO`]
/// times `disk`, its bytes on disk (an archive member's compressed size), and that the file is
/// complete (JPEG: end marker; PNG: IEND chunk and CRCs).
pub fn decode_raw(bytes: &[u8], shown: &str, transfer: Transfer, disk: u64, max_bytes: u64) -> Result<Raw> {
    use crate::capture::check_image_budget;
    if is_exr(shown) {
        let meta =
            exr::meta::MetaData::read_from_buffered(Cursor::new(bytes), false).map_err(|e| Error::format(shown, e))?;
        for h in &meta.headers {
            check_image_budget(shown, h.layer_size.0 as u64, h.layer_size.1 as u64, disk, max_bytes)?;
        }
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
        return Ok(Raw { width, height, samples: Samples::F32(rgb, 3), transfer });
    }
    let mut reader =
        image::ImageReader::new(Cursor::new(bytes)).with_guessed_format().map_err(|e| Error::format(shown, e))?;
    match reader.format() {
        None => return Err(Error::format(shown, "not a JPEG, PNG, TIFF or OpenEXR image")),
        Some(image::ImageFormat::Jpeg) => check_jpeg_complete(bytes, shown)?,
        Some(image::ImageFormat::Png) => check_png_complete(bytes, shown)?,
        Some(_) => {}
    }
    // The decoder's own buffers: within what the file can justify (deflate at most ~1032:1)
    // and the budget. The float size is checked from the header before any pixel is decoded.
    let mut limits = image::Limits::default();
    limits.max_alloc =
        Some((bytes.len() as u64).saturating_mul(1032 * 4).clamp(1 << 20, 16 << 30).min(max_bytes.max(1 << 20)));
    reader.limits(limits);
    let dec = reader.into_decoder().map_err(|e| Error::format(shown, e))?;
    let (w, h) = image::ImageDecoder::dimensions(&dec);
    check_image_budget(shown, u64::from(w), u64::from(h), disk, max_bytes)?;
    let img = image::DynamicImage::from_decoder(dec).map_err(|e| Error::format(shown, e))?;
    let (width, height) = (img.width() as usize, img.height() as usize);
    use image::DynamicImage as D;
    let samples = match img {
        D::ImageLuma8(b) => Samples::U8(b.into_raw(), 1),
        D::ImageLumaA8(b) => Samples::U8(b.into_raw(), 2),
        D::ImageRgb8(b) => Samples::U8(b.into_raw(), 3),
        D::ImageRgba8(b) => Samples::U8(b.into_raw(), 4),
        D::ImageLuma16(b) => Samples::U16(b.into_raw(), 1),
        D::ImageLumaA16(b) => Samples::U16(b.into_raw(), 2),
        D::ImageRgb16(b) => Samples::U16(b.into_raw(), 3),
        D::ImageRgba16(b) => Samples::U16(b.into_raw(), 4),
        D::ImageRgb32F(b) => Samples::F32(b.into_raw(), 3),
        D::ImageRgba32F(b) => Samples::F32(b.into_raw(), 4),
        other => return Err(Error::format(shown, format!("unsupported pixel layout {:?}", other.color()))),
    };
    if let Samples::F32(v, ch) = &samples {
        if let Some(i) = v.iter().enumerate().position(|(i, x)| i % ch < 3 && !x.is_finite()) {
            return Err(Error::format(shown, format!("value at flat index {i} is {}; expected finite values", v[i])));
        }
    }
    Ok(Raw { width, height, samples, transfer })
}

/// Read and decode an image file.
pub fn read(path: &std::path::Path, transfer: Transfer) -> Result<Decoded> {
    Ok(read_raw(path, transfer, crate::capture::default_max_bytes())?.into_decoded())
}

/// Read an image file and decode it without converting ([`decode_raw`]).
pub fn read_raw(path: &std::path::Path, transfer: Transfer, max_bytes: u64) -> Result<Raw> {
    let shown = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|e| Error::io(&shown, e))?;
    decode_raw(&bytes, &shown, transfer, bytes.len() as u64, max_bytes)
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
