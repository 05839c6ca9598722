//! What calibration reads of a photograph: its size (from the header, before anything is
//! decoded), and once decoded, linear luminance over a region, box-averaged luminance of the
//! whole frame, and the mean colour of a rectangle.
//!
//! Photographs are decoded by `btfrs_io::decode` (the `image` crate for JPEG, PNG and TIFF, the
//! `exr` crate for OpenEXR; the same checks of truncation and size as every btfrs reader),
//! without converting the whole frame to floats: only the rows a region needs are converted,
//! through the sRGB lookup table (or as linear values).

use btfrs_core::{Error, Result};
use btfrs_io::decode::{self, Raw, Transfer};
use std::path::Path;

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

/// Decode a photograph (its samples as stored).
pub fn open(path: &Path, transfer: Transfer) -> Result<Raw> {
    decode::read_raw(path, transfer, btfrs_io::capture::default_max_bytes())
}

/// Linear luminance of `rect` of `raw`, row-major.
pub fn luminance_of(raw: &Raw, rect: Rect) -> Vec<f32> {
    let mut out = vec![0f32; rect.len()];
    let mut rgb = vec![0f32; 3 * rect.w];
    for (y, row) in out.chunks_exact_mut(rect.w.max(1)).enumerate().take(rect.h) {
        raw.rgb_run((rect.y0 + y) * raw.width + rect.x0, rect.w, &mut rgb, 3);
        for (o, c) in row.iter_mut().zip(rgb.chunks_exact(3)) {
            *o = luminance(c[0], c[1], c[2]);
        }
    }
    out
}

/// Luminance box-averaged over `s x s` blocks (the last row and column of blocks over what is
/// left): `(values, columns, rows)`.
pub fn downsample(raw: &Raw, s: usize) -> (Vec<f32>, usize, usize) {
    let (w, h) = (raw.width, raw.height);
    let (dw, dh) = (w.div_ceil(s), h.div_ceil(s));
    let mut sum = vec![0f64; dw * dh];
    let mut rgb = vec![0f32; 3 * w];
    for y in 0..h {
        raw.rgb_run(y * w, w, &mut rgb, 3);
        let row = &mut sum[(y / s) * dw..(y / s + 1) * dw];
        for (x, c) in rgb.chunks_exact(3).enumerate() {
            row[x / s] += luminance(c[0], c[1], c[2]) as f64;
        }
    }
    let out = sum
        .iter()
        .enumerate()
        .map(|(i, v)| {
            let (bx, by) = (i % dw, i / dw);
            let n = ((bx + 1) * s).min(w) - bx * s;
            let m = ((by + 1) * s).min(h) - by * s;
            (v / (n * m) as f64) as f32
        })
        .collect();
    (out, dw, dh)
}

/// Mean linear RGB over `rect`, and how many of its pixels have a channel at the top of the
/// file's range (clipped: at or above 0.999).
pub fn rect_mean(raw: &Raw, rect: Rect) -> ([f64; 3], usize) {
    let mut sum = [0f64; 3];
    let mut clipped = 0;
    let mut rgb = vec![0f32; 3 * rect.w];
    for y in rect.y0..rect.y0 + rect.h {
        raw.rgb_run(y * raw.width + rect.x0, rect.w, &mut rgb, 3);
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
    fn rect_around_a_circle_is_clipped_to_the_image() {
        let r = Rect::around([10.0, 50.0, 20.0], 2.0, 100, 60);
        assert_eq!(r, Rect { x0: 0, y0: 28, w: 32, h: 32 });
        assert!(Rect::around([-100.0, -100.0, 5.0], 0.0, 10, 10).is_empty());
    }
}
