//! What calibration reads of a photograph: its size (from the header, before anything is
//! decoded), and once decoded, linear luminance over runs of pixels (a disc, a ring), reduced
//! luminance of the whole frame, and the mean colour of a rectangle.
//!
//! 8-bit photographs (JPEG, 8-bit PNG and TIFF: nearly every capture) are decoded by the
//! `image` crate into a byte buffer that the caller keeps from one photograph to the next,
//! after the checks every btfrs reader makes (`btfrs_io::decode`: a complete file, a declared
//! size within the memory budget and plausible for its bytes on disk). btfrs-io's own readers
//! return a new buffer per image, and on 24-megapixel photographs the kernel's zeroing of each
//! fresh 72 MB buffer cost a sixth of the time; luminance then comes from the bytes through
//! lookup tables, with no float copy. Other layouts (16-bit, float, OpenEXR) go through
//! `btfrs_io::decode::read_raw`.

use btfrs_core::{Error, Result};
use btfrs_io::decode::{self, Raw, Transfer};
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::Path;
use std::sync::OnceLock;

/// Luminance of linear RGB (ITU-R BT.709 weights, those of sRGB's primaries).
#[inline]
pub fn luminance(r: f32, g: f32, b: f32) -> f32 {
    0.2126 * r + 0.7152 * g + 0.0722 * b
}

/// A rectangle of pixels: columns `x0..x0 + w`, rows `y0..y0 + h`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Rect {
    pub x0: usize,
    pub y0: usize,
    pub w: usize,
    pub h: usize,
}

impl Rect {
    /// The pixels within `pad` of the circle (cx, cy, r), clipped to a `width x height` image.
    pub fn around(circle: [f64; 3], pad: f64, width: usize, height: usize) -> Rect {
        let [cx, cy, r] = circle;
        let e = r + pad;
        let x0 = (cx - e).floor().clamp(0.0, width as f64) as usize;
        let x1 = (cx + e).ceil().clamp(0.0, width as f64) as usize;
        let y0 = (cy - e).floor().clamp(0.0, height as f64) as usize;
        let y1 = (cy + e).ceil().clamp(0.0, height as f64) as usize;
        Rect { x0, y0, w: x1.saturating_sub(x0), h: y1.saturating_sub(y0) }
    }

    /// Pixel count.
    pub fn len(&self) -> usize {
        self.w * self.h
    }

    /// Whether it holds no pixel.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// The (width, height) a photograph's header declares; None for a format whose header this
/// does not read (OpenEXR: checked when decoded).
pub fn header_size(path: &Path) -> Result<Option<(usize, usize)>> {
    let shown = path.display().to_string();
    if decode::is_exr(&shown) {
        return Ok(None);
    }
    let reader = image::ImageReader::open(path)
        .map_err(|e| Error::io(&shown, e))?
        .with_guessed_format()
        .map_err(|e| Error::io(&shown, e))?;
    let (w, h) = reader
        .into_dimensions()
        .map_err(|e| Error::format(&shown, format!("not a readable photograph (JPEG, PNG or TIFF): {e}")))?;
    Ok(Some((w as usize, h as usize)))
}

/// Lookup tables of an 8-bit transfer: linear value, and its share of the luminance per
/// channel.
#[derive(Debug)]
pub struct Lut {
    lin: [f32; 256],
    lum: [[f32; 256]; 3],
}

fn lut(transfer: Transfer) -> &'static Lut {
    fn make(transfer: Transfer) -> Lut {
        let lin: [f32; 256] = std::array::from_fn(|v| {
            let x = v as f32 / 255.0;
            match transfer {
                Transfer::Srgb => decode::srgb_to_linear(x),
                Transfer::Linear => x,
            }
        });
        let w = [0.2126f32, 0.7152, 0.0722];
        Lut { lin, lum: std::array::from_fn(|c| std::array::from_fn(|v| w[c] * lin[v])) }
    }
    static S: OnceLock<Lut> = OnceLock::new();
    static L: OnceLock<Lut> = OnceLock::new();
    match transfer {
        Transfer::Srgb => S.get_or_init(|| make(Transfer::Srgb)),
        Transfer::Linear => L.get_or_init(|| make(Transfer::Linear)),
    }
}

/// A decoded photograph.
#[derive(Debug)]
pub struct Photo<'a> {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    pixels: Pixels<'a>,
}

#[derive(Debug)]
enum Pixels<'a> {
    /// 8-bit samples, `channels` per pixel (grey, grey + alpha, RGB, RGBA).
    Bytes { data: &'a [u8], channels: usize, lut: &'static Lut },
    /// Anything else, as btfrs-io decodes it.
    Raw(Raw),
}

impl Photo<'_> {
    /// Linear luminance of the `n` pixels from pixel `p` (row-major) into `out[..n]`.
    pub fn luminance_run(&self, p: usize, n: usize, out: &mut [f32]) {
        match &self.pixels {
            Pixels::Bytes { data, channels, lut } => {
                let src = data[p * channels..(p + n) * channels].chunks_exact(*channels);
                if *channels >= 3 {
                    for (o, c) in out[..n].iter_mut().zip(src) {
                        *o = lut.lum[0][c[0] as usize] + lut.lum[1][c[1] as usize] + lut.lum[2][c[2] as usize];
                    }
                } else {
                    for (o, c) in out[..n].iter_mut().zip(src) {
                        *o = lut.lin[c[0] as usize];
                    }
                }
            }
            Pixels::Raw(raw) => {
                let mut rgb = vec![0f32; 3 * n];
                raw.rgb_run(p, n, &mut rgb, 3);
                for (o, c) in out[..n].iter_mut().zip(rgb.chunks_exact(3)) {
                    *o = luminance(c[0], c[1], c[2]);
                }
            }
        }
    }

    /// Linear RGB of the `n` pixels from pixel `p` into `out[..3 n]`.
    pub fn rgb_run(&self, p: usize, n: usize, out: &mut [f32]) {
        match &self.pixels {
            Pixels::Bytes { data, channels, lut } => {
                let src = data[p * channels..(p + n) * channels].chunks_exact(*channels);
                for (o, c) in out[..3 * n].chunks_exact_mut(3).zip(src) {
                    if *channels >= 3 {
                        o.copy_from_slice(&[lut.lin[c[0] as usize], lut.lin[c[1] as usize], lut.lin[c[2] as usize]]);
                    } else {
                        o.fill(lut.lin[c[0] as usize]);
                    }
                }
            }
            Pixels::Raw(raw) => raw.rgb_run(p, n, out, 3),
        }
    }
}

/// Decode the photograph at `path`, its 8-bit samples into `buf` (grown when too small, never
/// shrunk: the caller hands the same buffer to the next photograph).
pub fn open<'a>(path: &Path, transfer: Transfer, buf: &'a mut Vec<u8>) -> Result<Photo<'a>> {
    let shown = path.display().to_string();
    let max_bytes = btfrs_io::capture::default_max_bytes();
    if decode::is_exr(&shown) {
        return open_raw(path, transfer, max_bytes);
    }
    let io = |e: std::io::Error| Error::io(&shown, e);
    let file = std::fs::File::open(path).map_err(io)?;
    let disk = file.metadata().map_err(io)?.len();
    let mut r = BufReader::with_capacity(256 << 10, file);
    // The checks of btfrs_io::decode's readers, in the same order.
    let mut head = [0u8; 64];
    let got = r.by_ref().take(64).read(&mut head).map_err(io)?;
    let format = match image::guess_format(&head[..got]) {
        Ok(f @ (image::ImageFormat::Jpeg | image::ImageFormat::Png | image::ImageFormat::Tiff)) => f,
        _ => return Err(Error::format(&shown, "not a JPEG, PNG, TIFF or OpenEXR image")),
    };
    match format {
        image::ImageFormat::Jpeg => decode::check_jpeg_complete(&mut r, &shown)?,
        image::ImageFormat::Png => decode::check_png_complete(&mut r, &shown)?,
        _ => {}
    }
    r.seek(SeekFrom::Start(0)).map_err(io)?;
    let mut reader = image::ImageReader::with_format(r, format);
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(disk.saturating_mul(1032 * 4).clamp(1 << 20, 16 << 30).min(max_bytes.max(1 << 20)));
    reader.limits(limits);
    let dec = reader.into_decoder().map_err(|e| Error::format(&shown, e))?;
    let (w, h) = image::ImageDecoder::dimensions(&dec);
    btfrs_io::capture::check_image_budget(&shown, u64::from(w), u64::from(h), disk, max_bytes)?;
    let channels = match image::ImageDecoder::color_type(&dec) {
        image::ColorType::L8 => 1,
        image::ColorType::La8 => 2,
        image::ColorType::Rgb8 => 3,
        image::ColorType::Rgba8 => 4,
        _ => return open_raw(path, transfer, max_bytes),
    };
    let need = image::ImageDecoder::total_bytes(&dec) as usize;
    if buf.len() < need {
        buf.resize(need, 0);
    }
    image::ImageDecoder::read_image(dec, &mut buf[..need]).map_err(|e| Error::format(&shown, e))?;
    Ok(Photo {
        width: w as usize,
        height: h as usize,
        pixels: Pixels::Bytes { data: &buf[..need], channels, lut: lut(transfer) },
    })
}

fn open_raw<'a>(path: &Path, transfer: Transfer, max_bytes: u64) -> Result<Photo<'a>> {
    let raw = decode::read_raw(path, transfer, max_bytes)?;
    Ok(Photo { width: raw.width, height: raw.height, pixels: Pixels::Raw(raw) })
}

/// Linear luminance of the pixels of `runs` (row, first column, past the last; see
/// [`ring_runs`]) of `raw`, written into `rect`'s row-major array (other pixels 0).
pub fn luminance_in(photo: &Photo<'_>, rect: Rect, runs: &[(usize, usize, usize)]) -> Vec<f32> {
    let mut out = vec![0f32; rect.len()];
    for &(y, x0, x1) in runs {
        let at = (y - rect.y0) * rect.w + (x0 - rect.x0);
        photo.luminance_run(y * photo.width + x0, x1 - x0, &mut out[at..]);
    }
    out
}

/// Luminance box-averaged over `s x s` blocks (the last row and column of blocks over what is
/// left): `(values, columns, rows)`. Blocks of 8 rows or more are averaged over every
/// `s / 4`-th of their rows (a reduced picture to find a disc in needs no more, and the
/// conversion is most of the cost).
pub fn downsample(photo: &Photo<'_>, s: usize) -> (Vec<f32>, usize, usize) {
    let (w, h) = (photo.width, photo.height);
    let (dw, dh) = (w.div_ceil(s), h.div_ceil(s));
    let every = (s / 4).max(1);
    let mut sum = vec![0f64; dw * dh];
    let mut rows = vec![0usize; dh];
    let mut lum = vec![0f32; w];
    for y in (0..h).filter(|y| (y % s).is_multiple_of(every)) {
        rows[y / s] += 1;
        photo.luminance_run(y * w, w, &mut lum);
        let row = &mut sum[(y / s) * dw..(y / s + 1) * dw];
        // A block's pixels of this row summed in f32 (at most s of them), then added in f64.
        for (acc, block) in row.iter_mut().zip(lum.chunks(s)) {
            *acc += block.iter().sum::<f32>() as f64;
        }
    }
    let out = sum
        .iter()
        .enumerate()
        .map(|(i, v)| {
            let (bx, by) = (i % dw, i / dw);
            let n = ((bx + 1) * s).min(w) - bx * s;
            (v / (n * rows[by]) as f64) as f32
        })
        .collect();
    (out, dw, dh)
}

/// The runs of pixels `(row, first column, past the last)` of `rect` whose centres lie in the
/// ring between radii `r_in` and `r_out` around (cx, cy), row by row.
pub fn ring_runs(rect: Rect, cx: f64, cy: f64, r_in: f64, r_out: f64) -> Vec<(usize, usize, usize)> {
    let mut out = Vec::new();
    let clip = |a: f64, b: f64| {
        // Columns whose centres x + 0.5 lie in [a, b].
        let x0 = ((a - 0.5).ceil().max(rect.x0 as f64)) as usize;
        let x1 = (((b - 0.5).floor() + 1.0).min((rect.x0 + rect.w) as f64)).max(x0 as f64) as usize;
        (x0, x1)
    };
    for y in rect.y0..rect.y0 + rect.h {
        let dy = y as f64 + 0.5 - cy;
        if dy.abs() > r_out {
            continue;
        }
        let half = (r_out * r_out - dy * dy).sqrt();
        let segs = if dy.abs() < r_in {
            let hole = (r_in * r_in - dy * dy).sqrt();
            vec![clip(cx - half, cx - hole), clip(cx + hole, cx + half)]
        } else {
            vec![clip(cx - half, cx + half)]
        };
        out.extend(segs.into_iter().filter(|(a, b)| b > a).map(|(a, b)| (y, a, b)));
    }
    out
}

/// Linear luminance of the pixels of `runs` (see [`ring_runs`]), one after the other.
pub fn luminance_runs(photo: &Photo<'_>, runs: &[(usize, usize, usize)]) -> Vec<f32> {
    let mut out = vec![0f32; runs.iter().map(|r| r.2 - r.1).sum()];
    let mut k = 0;
    for &(y, x0, x1) in runs {
        photo.luminance_run(y * photo.width + x0, x1 - x0, &mut out[k..]);
        k += x1 - x0;
    }
    out
}

/// Mean linear RGB over `rect`, and how many of its pixels have a channel at the top of the
/// file's range (clipped: at or above 0.999).
pub fn rect_mean(photo: &Photo<'_>, rect: Rect) -> ([f64; 3], usize) {
    let mut sum = [0f64; 3];
    let mut clipped = 0;
    let mut rgb = vec![0f32; 3 * rect.w];
    for y in rect.y0..rect.y0 + rect.h {
        photo.rgb_run(y * photo.width + rect.x0, rect.w, &mut rgb);
        for c in rgb.chunks_exact(3) {
            for k in 0..3 {
                sum[k] += c[k] as f64;
            }
            clipped += usize::from(c.iter().any(|&v| v >= 0.999));
        }
    }
    let n = rect.len().max(1) as f64;
    (sum.map(|s| s / n), clipped)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ring_runs_hold_exactly_the_pixels_whose_centres_are_in_the_ring() {
        let rect = Rect { x0: 3, y0: 2, w: 60, h: 50 };
        let (cx, cy, a, b) = (30.3, 27.8, 10.5, 17.2);
        let runs = ring_runs(rect, cx, cy, a, b);
        let mut got = std::collections::HashSet::new();
        for (y, x0, x1) in runs {
            for x in x0..x1 {
                assert!(got.insert((x, y)));
            }
        }
        for y in rect.y0..rect.y0 + rect.h {
            for x in rect.x0..rect.x0 + rect.w {
                let d = (x as f64 + 0.5 - cx).hypot(y as f64 + 0.5 - cy);
                // Pixels exactly on a radius may go either way; none is that close here.
                assert_eq!(got.contains(&(x, y)), (a..=b).contains(&d), "({x}, {y}) at {d}");
            }
        }
    }

    #[test]
    fn rect_around_a_circle_is_clipped_to_the_image() {
        let r = Rect::around([10.0, 50.0, 20.0], 2.0, 100, 60);
        assert_eq!(r, Rect { x0: 0, y0: 28, w: 32, h: 32 });
        assert!(Rect::around([-100.0, -100.0, 5.0], 0.0, 10, 10).is_empty());
    }
}
