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
use rayon::prelude::*;
use std::io::{BufRead, Cursor, Read, Seek, SeekFrom};

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
/// batch of images never holds float copies. (A single image is decoded in place instead,
/// [`decode_place`].)
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

    /// Linear RGB of the `n` consecutive pixels from pixel `p` (row-major) into `dst`, pixel `k`
    /// at `dst[k * stride..k * stride + 3]` (`stride >= 3`; `dst` holds at least
    /// `(n - 1) * stride + 3` values): [`Raw::rgb`] for a run, the sample type and lookup table
    /// chosen once per run instead of once per pixel. The scatter into a capture converts every
    /// pixel of every image this way, straight into the texel-major output (stride: the values
    /// per texel).
    pub fn rgb_run(&self, p: usize, n: usize, dst: &mut [f32], stride: usize) {
        fn run<T: Copy>(v: &[T], ch: usize, p: usize, n: usize, dst: &mut [f32], stride: usize, f: impl Fn(T) -> f32) {
            let src = v[p * ch..(p + n) * ch].chunks_exact(ch);
            let dst = dst.chunks_mut(stride).take(n);
            if ch >= 3 {
                for (d, s) in dst.zip(src) {
                    d[..3].copy_from_slice(&[f(s[0]), f(s[1]), f(s[2])]);
                }
            } else {
                for (d, s) in dst.zip(src) {
                    d[..3].fill(f(s[0]));
                }
            }
        }
        assert!(
            stride >= 3 && (n == 0 || dst.len() >= (n - 1) * stride + 3),
            "rgb_run: {n} pixels at stride {stride} into {}",
            dst.len()
        );
        match &self.samples {
            Samples::U8(v, ch) => {
                let l = lut8(self.transfer);
                run(v, *ch, p, n, dst, stride, |x| l[x as usize]);
            }
            Samples::U16(v, ch) => {
                let l = lut16(self.transfer);
                run(v, *ch, p, n, dst, stride, |x| l[x as usize]);
            }
            Samples::F32(v, ch) => run(v, *ch, p, n, dst, stride, |x| x),
        }
    }

    /// Bytes per pixel of the samples (channels x bytes per sample).
    pub fn pixel_bytes(&self) -> usize {
        match &self.samples {
            Samples::U8(_, ch) => *ch,
            Samples::U16(_, ch) => 2 * ch,
            Samples::F32(_, ch) => 4 * ch,
        }
    }

    /// Write the samples of the `rows x cols` pixels from (`row`, `col`) to `file` at `offset`,
    /// row by row (one write when the rows are whole); [`Raw::read_rows`] reads rows of them
    /// back. Returns the bytes written.
    pub fn write_rect(&self, file: &std::fs::File, offset: u64, rect: crate::capture::Crop) -> std::io::Result<u64> {
        use std::os::unix::fs::FileExt;
        let bytes: &[u8] = match &self.samples {
            Samples::U8(v, _) => v,
            Samples::U16(v, _) => bytemuck::cast_slice(v),
            Samples::F32(v, _) => bytemuck::cast_slice(v),
        };
        let px = self.pixel_bytes();
        let row_bytes = rect.cols * px;
        if rect.cols == self.width {
            let start = rect.row * self.width * px;
            file.write_all_at(&bytes[start..start + rect.rows * row_bytes], offset)?;
        } else {
            for r in 0..rect.rows {
                let start = ((rect.row + r) * self.width + rect.col) * px;
                file.write_all_at(&bytes[start..start + row_bytes], offset + (r * row_bytes) as u64)?;
            }
        }
        Ok((rect.rows * row_bytes) as u64)
    }

    /// An image of no pixels with this one's sample type, channels and transfer.
    pub fn like(&self) -> Raw {
        let samples = match &self.samples {
            Samples::U8(_, ch) => Samples::U8(Vec::new(), *ch),
            Samples::U16(_, ch) => Samples::U16(Vec::new(), *ch),
            Samples::F32(_, ch) => Samples::F32(Vec::new(), *ch),
        };
        Raw { width: 0, height: 0, samples, transfer: self.transfer }
    }

    /// `rows` rows of `cols` pixels written by [`Raw::write_rect`] of an image like this one
    /// (its sample type and channels), read from `file` at `offset`: a `rows x cols` image.
    pub fn read_rows(&self, file: &std::fs::File, offset: u64, rows: usize, cols: usize) -> std::io::Result<Raw> {
        use std::os::unix::fs::FileExt;
        let n = rows * cols;
        let samples = match &self.samples {
            Samples::U8(_, ch) => {
                let mut v = vec![0u8; n * ch];
                file.read_exact_at(&mut v, offset)?;
                Samples::U8(v, *ch)
            }
            Samples::U16(_, ch) => {
                let mut v = vec![0u16; n * ch];
                file.read_exact_at(bytemuck::cast_slice_mut(&mut v), offset)?;
                Samples::U16(v, *ch)
            }
            Samples::F32(_, ch) => {
                let mut v = vec![0f32; n * ch];
                file.read_exact_at(bytemuck::cast_slice_mut(&mut v), offset)?;
                Samples::F32(v, *ch)
            }
        };
        Ok(Raw { width: cols, height: rows, samples, transfer: self.transfer })
    }

    /// Bytes the samples hold.
    pub fn sample_bytes(&self) -> usize {
        match &self.samples {
            Samples::U8(v, _) => v.len(),
            Samples::U16(v, _) => 2 * v.len(),
            Samples::F32(v, _) => 4 * v.len(),
        }
    }

    /// The 8-bit samples as RGB bytes (grey replicated, alpha dropped), as stored (no
    /// transfer applied); `None` for 16-bit or float samples.
    pub fn rgb8(self) -> Option<Vec<u8>> {
        let Samples::U8(v, ch) = self.samples else { return None };
        Some(match ch {
            3 => v,
            1 | 2 => v.chunks_exact(ch).flat_map(|p| [p[0]; 3]).collect(),
            _ => v.chunks_exact(ch).flat_map(|p| [p[0], p[1], p[2]]).collect(),
        })
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
    let mut rgb = Vec::new();
    let (width, height) =
        decode_place(Cursor::new(bytes), shown, transfer, bytes.len() as u64, budget, Place::New(&mut rgb))?;
    Ok(Decoded { width, height, rgb })
}

/// Where [`decode_place`] writes an image's linear float RGB.
#[derive(Debug)]
pub enum Place<'a> {
    /// A new buffer, sized from the file's header.
    New(&'a mut Vec<f32>),
    /// An existing `[rows, cols, 3]` buffer; the image must be `rows x cols` pixels.
    Fixed(&'a mut [f32], usize, usize),
}

fn io_err(shown: &str) -> impl Fn(std::io::Error) -> Error + '_ {
    move |e| Error::io(shown, e)
}

/// Whether `pat` (not empty) occurs in `hay`: a scan for its first byte, the rest compared only
/// there. (Comparing every window as a slice called `memcmp` once per byte: a tenth of the time
/// of loading 200 JPEGs went to finding their end markers.)
fn contains(hay: &[u8], pat: &[u8]) -> bool {
    let (first, rest) = (pat[0], &pat[1..]);
    let mut from = 0;
    while let Some(k) = hay[from..].iter().position(|&b| b == first) {
        let at = from + k;
        if hay[at + 1..].starts_with(rest) {
            return true;
        }
        from = at + 1;
    }
    false
}

/// Whether `pat` occurs in what `r` reads from where it stands, read in 64 KiB pieces.
fn occurs<R: Read>(r: &mut R, pat: &[u8]) -> std::io::Result<bool> {
    let mut buf = vec![0u8; 64 << 10];
    let mut keep = 0;
    loop {
        let n = r.read(&mut buf[keep..])?;
        if n == 0 {
            return Ok(false);
        }
        let end = keep + n;
        if contains(&buf[..end], pat) {
            return Ok(true);
        }
        keep = (pat.len() - 1).min(end);
        buf.copy_within(end - keep..end, 0);
    }
}

/// That a JPEG's entropy-coded data is complete: the segments before the first scan are walked
/// by their lengths, and an end-of-image marker (FF D9) must follow the scan data (byte
/// stuffing keeps FF D9 out of entropy-coded data; bytes after it are allowed). The file is
/// read as a stream, never held.
pub fn check_jpeg_complete<R: Read + Seek>(r: &mut R, shown: &str) -> Result<()> {
    let bad = |m: &str| Err(Error::format(shown, format!("{m}; the JPEG is truncated or corrupted")));
    let mut at = |pos: u64, n: usize| -> Result<Option<[u8; 4]>> {
        let mut b = [0u8; 4];
        r.seek(SeekFrom::Start(pos)).map_err(io_err(shown))?;
        match r.read_exact(&mut b[..n]) {
            Ok(()) => Ok(Some(b)),
            Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => Ok(None),
            Err(e) => Err(Error::io(shown, e)),
        }
    };
    if at(0, 2)?.is_none_or(|b| b[..2] != [0xFF, 0xD8]) {
        return bad("no start-of-image marker (FF D8)");
    }
    let mut pos = 2u64;
    loop {
        let Some(m) = at(pos, 2)? else {
            return bad(&format!("expected a marker at byte {pos} before the image data"));
        };
        match m {
            [0xFF, 0xFF, ..] => pos += 1,
            [0xFF, 0xDA, ..] => break,
            [0xFF, m, ..] if m == 0x01 || (0xD0..=0xD7).contains(&m) => pos += 2,
            [0xFF, ..] => {
                let Some(l) = at(pos + 2, 2)? else {
                    return bad(&format!("segment at byte {pos} is cut"));
                };
                pos += 2 + u64::from(u16::from_be_bytes([l[0], l[1]]));
            }
            _ => return bad(&format!("expected a marker at byte {pos} before the image data")),
        }
    }
    r.seek(SeekFrom::Start(pos)).map_err(io_err(shown))?;
    if !occurs(r, &[0xFF, 0xD9]).map_err(io_err(shown))? {
        return bad("no end-of-image marker (FF D9) after the image data");
    }
    Ok(())
}

/// The IEND chunk with its CRC, which closes every complete PNG.
const PNG_IEND: [u8; 12] = [0, 0, 0, 0, b'I', b'E', b'N', b'D', 0xAE, 0x42, 0x60, 0x82];

/// That a PNG ends with its IEND chunk (bytes after it are allowed), read as a stream. Chunk
/// CRCs and the zlib checksum are checked by the decoder.
pub fn check_png_complete<R: Read + Seek>(r: &mut R, shown: &str) -> Result<()> {
    r.seek(SeekFrom::Start(0)).map_err(io_err(shown))?;
    if !occurs(r, &PNG_IEND).map_err(io_err(shown))? {
        return Err(Error::format(shown, "no IEND chunk at the end; the PNG is truncated or corrupted"));
    }
    Ok(())
}

/// An integer or float image's decoder, after the checks every file passes: a known format,
/// complete (JPEG: end marker; PNG: IEND chunk), and a declared size within `max_bytes` and
/// [`crate::capture::MAX_DECODE_RATIO`] times `disk`, its bytes on disk (an archive member's
/// compressed size). Nothing is decoded yet.
fn open_decoder<'a, R: 'a + BufRead + Seek>(
    mut r: R,
    shown: &str,
    disk: u64,
    max_bytes: u64,
) -> Result<impl image::ImageDecoder + 'a> {
    let len = r.seek(SeekFrom::End(0)).map_err(io_err(shown))?;
    let mut head = [0u8; 64];
    r.seek(SeekFrom::Start(0)).map_err(io_err(shown))?;
    let got = r.by_ref().take(64).read(&mut head).map_err(io_err(shown))?;
    let format = match image::guess_format(&head[..got]) {
        Ok(f @ (image::ImageFormat::Jpeg | image::ImageFormat::Png | image::ImageFormat::Tiff)) => f,
        _ => return Err(Error::format(shown, "not a JPEG, PNG, TIFF or OpenEXR image")),
    };
    match format {
        image::ImageFormat::Jpeg => check_jpeg_complete(&mut r, shown)?,
        image::ImageFormat::Png => check_png_complete(&mut r, shown)?,
        _ => {}
    }
    r.seek(SeekFrom::Start(0)).map_err(io_err(shown))?;
    let mut reader = image::ImageReader::with_format(r, format);
    // The decoder's own buffers: within what the file can justify (deflate at most ~1032:1)
    // and the budget. The float size is checked from the header before any pixel is decoded.
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(len.saturating_mul(1032 * 4).clamp(1 << 20, 16 << 30).min(max_bytes.max(1 << 20)));
    reader.limits(limits);
    let dec = reader.into_decoder().map_err(|e| Error::format(shown, e))?;
    let (w, h) = image::ImageDecoder::dimensions(&dec);
    crate::capture::check_image_budget(shown, u64::from(w), u64::from(h), disk, max_bytes)?;
    Ok(dec)
}

/// An OpenEXR file's float RGB, refused if any value is not finite.
fn decode_exr<R: Read + Seek>(mut r: R, shown: &str, disk: u64, max_bytes: u64) -> Result<(Vec<f32>, usize, usize)> {
    r.seek(SeekFrom::Start(0)).map_err(io_err(shown))?;
    let mut bytes = Vec::new();
    r.read_to_end(&mut bytes).map_err(io_err(shown))?;
    let meta =
        exr::meta::MetaData::read_from_buffered(Cursor::new(&bytes), false).map_err(|e| Error::format(shown, e))?;
    for h in &meta.headers {
        crate::capture::check_image_budget(shown, h.layer_size.0 as u64, h.layer_size.1 as u64, disk, max_bytes)?;
    }
    let (rgb, width, height) = crate::image::read_exr_bytes(&bytes, shown)?;
    check_finite(&rgb, width, shown)?;
    Ok((rgb, width, height))
}

fn check_finite(rgb: &[f32], width: usize, shown: &str) -> Result<()> {
    if let Some(i) = rgb.iter().position(|x| !x.is_finite()) {
        let (p, c) = (i / 3, i % 3);
        return Err(Error::format(
            shown,
            format!(
                "pixel (row {}, column {}) channel {c} is {}; expected finite values",
                p / width.max(1),
                p % width.max(1),
                rgb[i]
            ),
        ));
    }
    Ok(())
}

/// Decode an image (`shown` names it in errors) straight into linear float RGB at `place`,
/// after [`decode_raw_from`]'s checks. The decoder writes the file's samples into the last
/// bytes of the float buffer, and they are widened to floats in place from the first pixel on
/// (pixel `p`'s floats end at byte `12(p+1)`, never past pixel `p+1`'s samples), so a single
/// image needs no memory beyond its floats and the decoder's own. Returns (width, height).
pub fn decode_place<R: BufRead + Seek>(
    mut r: R,
    shown: &str,
    transfer: Transfer,
    disk: u64,
    max_bytes: u64,
    place: Place<'_>,
) -> Result<(usize, usize)> {
    fn fit<'p>(w: usize, h: usize, place: Place<'p>, shown: &str) -> Result<&'p mut [f32]> {
        match place {
            Place::New(v) => {
                v.clear();
                v.resize(w * h * 3, 0.0);
                Ok(&mut v[..])
            }
            Place::Fixed(s, rows, cols) => {
                if (h, w) != (rows, cols) {
                    return Err(Error::format(
                        shown,
                        format!("the image is {h} x {w} pixels; expected {rows} x {cols} like the first image"),
                    ));
                }
                debug_assert_eq!(s.len(), w * h * 3);
                Ok(s)
            }
        }
    }
    if is_exr(shown) {
        let (rgb, w, h) = decode_exr(&mut r, shown, disk, max_bytes)?;
        fit(w, h, place, shown)?.copy_from_slice(&rgb);
        return Ok((w, h));
    }
    let dec = open_decoder(r, shown, disk, max_bytes)?;
    let (w, h) = image::ImageDecoder::dimensions(&dec);
    let (w, h) = (w as usize, h as usize);
    let color = image::ImageDecoder::color_type(&dec);
    let Some((ch, depth)) = layout(color) else {
        return Err(Error::format(shown, format!("unsupported pixel layout {color:?}")));
    };
    let out = fit(w, h, place, shown)?;
    let (n, b) = (w * h, ch * depth);
    if b > 12 {
        // Four float channels do not fit in three: decode beside, then convert.
        let raw = raw_from(dec, shown, transfer)?;
        out.par_chunks_mut(3).enumerate().for_each(|(p, px)| px.copy_from_slice(&raw.rgb(p)));
    } else {
        let bytes: &mut [u8] = bytemuck::cast_slice_mut(out);
        let start = 12 * n - b * n;
        image::ImageDecoder::read_image(dec, &mut bytes[start..]).map_err(|e| Error::format(shown, e))?;
        let (l8, l16) = (lut8(transfer), lut16(transfer));
        for p in 0..n {
            let s = start + b * p;
            let mut v = [0f32; 4];
            for (c, v) in v.iter_mut().enumerate().take(ch) {
                let at = s + c * depth;
                *v = match depth {
                    1 => l8[bytes[at] as usize],
                    2 => l16[u16::from_ne_bytes([bytes[at], bytes[at + 1]]) as usize],
                    _ => f32::from_ne_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]]),
                };
            }
            let rgb = if ch < 3 { [v[0]; 3] } else { [v[0], v[1], v[2]] };
            for (c, x) in rgb.iter().enumerate() {
                bytes[12 * p + 4 * c..12 * p + 4 * c + 4].copy_from_slice(&x.to_ne_bytes());
            }
        }
        if depth == 4 {
            check_finite(out, w, shown)?;
        }
    }
    Ok((w, h))
}

/// Channels and bytes per channel of a pixel layout the readers accept.
fn layout(c: image::ColorType) -> Option<(usize, usize)> {
    use image::ColorType as C;
    Some(match c {
        C::L8 => (1, 1),
        C::La8 => (2, 1),
        C::Rgb8 => (3, 1),
        C::Rgba8 => (4, 1),
        C::L16 => (1, 2),
        C::La16 => (2, 2),
        C::Rgb16 => (3, 2),
        C::Rgba16 => (4, 2),
        C::Rgb32F => (3, 4),
        C::Rgba32F => (4, 4),
        _ => return None,
    })
}

fn raw_from(dec: impl image::ImageDecoder, shown: &str, transfer: Transfer) -> Result<Raw> {
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

/// Decode an image file's bytes (`shown` names it in errors) without converting its samples,
/// after checking that it is complete (JPEG: end marker; PNG: IEND chunk and CRCs) and that its
/// decoded float size fits `max_bytes` and [`crate::capture::MAX_DECODE_RATIO`] times `disk`,
/// its bytes on disk (an archive member's compressed size).
pub fn decode_raw(bytes: &[u8], shown: &str, transfer: Transfer, disk: u64, max_bytes: u64) -> Result<Raw> {
    decode_raw_from(Cursor::new(bytes), shown, transfer, disk, max_bytes)
}

/// [`decode_raw`] of a stream (a file is read as the decoder goes, not held).
pub fn decode_raw_from<R: BufRead + Seek>(
    mut r: R,
    shown: &str,
    transfer: Transfer,
    disk: u64,
    max_bytes: u64,
) -> Result<Raw> {
    if is_exr(shown) {
        let (rgb, width, height) = decode_exr(&mut r, shown, disk, max_bytes)?;
        return Ok(Raw { width, height, samples: Samples::F32(rgb, 3), transfer });
    }
    raw_from(open_decoder(r, shown, disk, max_bytes)?, shown, transfer)
}

/// An image file opened as every reader opens a file ([`crate::untrusted::open`]: a regular
/// file, never blocking on a FIFO), with its bytes on disk.
fn open_file(path: &std::path::Path) -> Result<(std::io::BufReader<std::fs::File>, String, u64)> {
    let shown = path.display().to_string();
    let (f, disk) = crate::untrusted::open(path)?;
    Ok((std::io::BufReader::with_capacity(256 << 10, f), shown, disk))
}

/// Read and decode an image file.
pub fn read(path: &std::path::Path, transfer: Transfer) -> Result<Decoded> {
    read_within(path, transfer, crate::capture::default_max_bytes())
}

/// [`read`] within `max_bytes`.
pub fn read_within(path: &std::path::Path, transfer: Transfer, max_bytes: u64) -> Result<Decoded> {
    let (f, shown, disk) = open_file(path)?;
    let mut rgb = Vec::new();
    let (width, height) = decode_place(f, &shown, transfer, disk, max_bytes, Place::New(&mut rgb))?;
    Ok(Decoded { width, height, rgb })
}

/// An image's (width, height, bytes per pixel of the samples [`decode_raw`] would hold) from
/// its header, after the checks every file passes (complete, a plausible size within
/// `max_bytes`); no pixel is decoded.
pub fn probe_from<R: BufRead + Seek>(
    mut r: R,
    shown: &str,
    disk: u64,
    max_bytes: u64,
) -> Result<(usize, usize, usize)> {
    if is_exr(shown) {
        r.seek(SeekFrom::Start(0)).map_err(io_err(shown))?;
        let meta = exr::meta::MetaData::read_from_buffered(r, false).map_err(|e| Error::format(shown, e))?;
        let h = meta.headers.first().ok_or_else(|| Error::format(shown, "an OpenEXR file without a layer"))?;
        let (w, ht) = (h.layer_size.0, h.layer_size.1);
        crate::capture::check_image_budget(shown, w as u64, ht as u64, disk, max_bytes)?;
        return Ok((w, ht, 12));
    }
    let dec = open_decoder(r, shown, disk, max_bytes)?;
    let (w, h) = image::ImageDecoder::dimensions(&dec);
    let color = image::ImageDecoder::color_type(&dec);
    let Some((ch, depth)) = layout(color) else {
        return Err(Error::format(shown, format!("unsupported pixel layout {color:?}")));
    };
    Ok((w as usize, h as usize, ch * depth))
}

/// [`probe_from`] of a file.
pub fn probe(path: &std::path::Path, max_bytes: u64) -> Result<(usize, usize, usize)> {
    let (f, shown, disk) = open_file(path)?;
    probe_from(f, &shown, disk, max_bytes)
}

/// Read an image file and decode it without converting ([`decode_raw`]).
pub fn read_raw(path: &std::path::Path, transfer: Transfer, max_bytes: u64) -> Result<Raw> {
    let (f, shown, disk) = open_file(path)?;
    decode_raw_from(f, &shown, transfer, disk, max_bytes)
}

/// [`decode_place`] of a file.
pub fn read_place(
    path: &std::path::Path,
    transfer: Transfer,
    max_bytes: u64,
    place: Place<'_>,
) -> Result<(usize, usize)> {
    let (f, shown, disk) = open_file(path)?;
    decode_place(f, &shown, transfer, disk, max_bytes, place)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn contains_finds_a_pattern_where_a_window_scan_does() {
        let hay: Vec<u8> = (0..5000u32).map(|i| (i.wrapping_mul(2654435761) >> 24) as u8).collect();
        for pat in [&[0xFFu8, 0xD9][..], &[7], &hay[4998..], &hay[100..104], &[0xFF, 0xFF, 0xFF], &[0, 0xD9]] {
            for end in [0, 1, 2, 3, 100, 4999, 5000] {
                let want = hay[..end].windows(pat.len()).any(|w| w == pat);
                assert_eq!(contains(&hay[..end], pat), want, "{pat:?} in the first {end}");
            }
        }
    }

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
    fn in_place_widening_matches_the_samples_for_every_layout() {
        // Each layout's decode in place against the same file's samples converted one pixel at
        // a time into a separate buffer (`Raw::rgb`), over odd sizes; 16-bit TIFF and 32-bit
        // float TIFF included (four float channels take the decode-beside path).
        use image::DynamicImage as D;
        let (w, h) = (37u32, 23u32);
        let v = |x: u32, y: u32, c: u32| ((x * 7 + y * 13 + c * 101) % 256) as u8;
        let rgba8 =
            image::RgbaImage::from_fn(w, h, |x, y| image::Rgba([v(x, y, 0), v(x, y, 1), v(x, y, 2), v(x, y, 3)]));
        let base = D::ImageRgba8(rgba8);
        let cases = [
            (D::ImageLuma8(base.to_luma8()), image::ImageFormat::Png),
            (D::ImageLumaA8(base.to_luma_alpha8()), image::ImageFormat::Png),
            (D::ImageRgb8(base.to_rgb8()), image::ImageFormat::Png),
            (base.clone(), image::ImageFormat::Png),
            (D::ImageRgb8(base.to_rgb8()), image::ImageFormat::Jpeg),
            (D::ImageLuma16(base.to_luma16()), image::ImageFormat::Png),
            (D::ImageLumaA16(base.to_luma_alpha16()), image::ImageFormat::Png),
            (D::ImageRgb16(base.to_rgb16()), image::ImageFormat::Tiff),
            (D::ImageRgba16(base.to_rgba16()), image::ImageFormat::Png),
            (D::ImageRgb32F(base.to_rgb32f()), image::ImageFormat::Tiff),
            (D::ImageRgba32F(base.to_rgba32f()), image::ImageFormat::Tiff),
        ];
        for (img, fmt) in cases {
            let bytes = encode(img.clone(), fmt);
            for transfer in [Transfer::Srgb, Transfer::Linear] {
                let raw = decode_raw(&bytes, "a", transfer, bytes.len() as u64, 1 << 30).unwrap();
                let want: Vec<f32> = (0..(w * h) as usize).flat_map(|p| raw.rgb(p)).collect();
                let got = decode(&bytes, "a", transfer).unwrap();
                assert_eq!((got.width, got.height), (w as usize, h as usize));
                assert_eq!(got.rgb, want, "{:?} {fmt:?} {transfer:?}", img.color());
                let mut fixed = vec![f32::NAN; want.len()];
                decode_place(Cursor::new(&bytes), "a", transfer, 1 << 20, 1 << 30, Place::Fixed(&mut fixed, 23, 37))
                    .unwrap();
                assert_eq!(fixed, want);
                let e = decode_place(
                    Cursor::new(&bytes),
                    "a",
                    transfer,
                    1 << 20,
                    1 << 30,
                    Place::Fixed(&mut fixed, 37, 23),
                )
                .unwrap_err()
                .to_string();
                assert!(e.contains("23 x 37 pixels; expected 37 x 23"), "{e}");
            }
        }
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
