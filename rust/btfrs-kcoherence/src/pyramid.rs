//! The sample pyramid (paper 000 section 4.2, "Hierarchical synthesis").
//!
//! "For each image of the sample BTF an image pyramid is built, where each layer has half the
//! resolution of the previous layer." Halving by averaging 2 x 2 blocks is bilinear interpolation
//! at the block centres, which is what the paper relies on ("because the lower resolution sample
//! was created by bilinear interpolation, we will find a similar pixel at these coordinates").
//!
//! The pyramid is built over the per-pixel *feature vectors* rather than the raw images: every
//! feature mode of [`crate::textons`] is linear in the images (all of them, a subset, or one shared
//! PCA projection), and averaging commutes with a linear map, so this is the same as projecting
//! each level of an image pyramid, at a fraction of the cost.

use btfrs_core::{Error, Result};
use rayon::prelude::*;

/// A feature image: `[height, width, dim]` `f32`, row-major, one vector per sample pixel.
#[derive(Debug, Clone, PartialEq)]
pub struct Features {
    /// Rows.
    pub height: usize,
    /// Columns.
    pub width: usize,
    /// Length of each pixel's vector.
    pub dim: usize,
    /// `height * width * dim` values.
    pub data: Vec<f32>,
}

impl Features {
    /// Wrap a `[height, width, dim]` array, checking its size and that it is finite.
    pub fn new(height: usize, width: usize, dim: usize, data: Vec<f32>) -> Result<Self> {
        if height == 0 || width == 0 || dim == 0 {
            return Err(Error::arg(
                "sample",
                format!("expected a non-empty [H, W, D] array, got {height} x {width} x {dim}"),
            ));
        }
        if data.len() != height * width * dim {
            return Err(Error::arg(
                "sample",
                format!("expected {height} x {width} x {dim} = {} values, got {}", height * width * dim, data.len()),
            ));
        }
        if let Some(i) = btfrs_core::btf::first_non_finite(&data) {
            let t = i / dim;
            return Err(Error::arg(
                "sample",
                format!("value {} at texel (row {}, column {}) is not finite", data[i], t / width, t % width),
            ));
        }
        Ok(Self { height, width, dim, data })
    }

    /// Number of pixels.
    pub fn pixels(&self) -> usize {
        self.height * self.width
    }

    /// The vector of pixel `i` (row-major index).
    pub fn pixel(&self, i: usize) -> &[f32] {
        &self.data[i * self.dim..(i + 1) * self.dim]
    }
}

/// Halve a feature image by averaging 2 x 2 blocks (an odd last row or column is dropped, so
/// pixel `(x, y)` of the result covers exactly `(2x..2x+2, 2y..2y+2)` of the input).
pub fn downsample(f: &Features) -> Features {
    let (h, w, d) = (f.height / 2, f.width / 2, f.dim);
    let mut out = vec![0.0f32; h * w * d];
    out.par_chunks_mut(w * d).enumerate().for_each(|(y, row)| {
        for x in 0..w {
            let o = &mut row[x * d..(x + 1) * d];
            for (dy, dx) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                let src = f.pixel((2 * y + dy) * f.width + 2 * x + dx);
                for (o, &s) in o.iter_mut().zip(src) {
                    *o += 0.25 * s;
                }
            }
        }
    });
    Features { height: h, width: w, dim: d, data: out }
}

/// The pyramid `[finest, ..., coarsest]` with `levels` levels (1 = the sample alone).
pub fn pyramid(f: Features, levels: usize) -> Vec<Features> {
    let mut out = vec![f];
    while out.len() < levels {
        let next = downsample(out.last().expect("non-empty"));
        out.push(next);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn downsample_averages_blocks_and_drops_odd_edges() {
        // 3 x 5 x 2: value = 10 y + x in channel 0, -(10 y + x) in channel 1.
        let data: Vec<f32> = (0..3)
            .flat_map(|y| (0..5).flat_map(move |x| [10.0 * y as f32 + x as f32, -(10.0 * y as f32 + x as f32)]))
            .collect();
        let f = Features::new(3, 5, 2, data).unwrap();
        let g = downsample(&f);
        assert_eq!((g.height, g.width, g.dim), (1, 2, 2));
        // Block (0..2, 0..2): mean of 0, 1, 10, 11 = 5.5; block (2..4): 7.5.
        assert_eq!(g.data, vec![5.5, -5.5, 7.5, -7.5]);
        let p = pyramid(f, 3);
        assert_eq!(p.len(), 3);
        assert_eq!((p[2].height, p[2].width), (0, 1));
    }

    #[test]
    fn features_reject_bad_sizes_and_nan() {
        assert!(Features::new(2, 2, 1, vec![0.0; 3]).is_err());
        assert!(Features::new(0, 2, 1, vec![]).is_err());
        assert!(Features::new(1, 1, 1, vec![f32::NAN]).is_err());
    }
}
