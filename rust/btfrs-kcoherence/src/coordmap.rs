//! The synthesis result: a coordinate map into the sample (paper 000 section 4, "Using large
//! BTFs for rendering"), and the two baselines it is measured against.
//!
//! "The key for saving memory is to store only the coordinates to the BTF sample in a coordinate
//! map as synthesis result instead of copying the large vectors." The renderer reads the map as
//! `[H, W, 2]` `u16` `(x, y)` pairs ([`CoordMap::to_xy`]); here it is one sample pixel index per
//! output pixel, which is what the synthesis and the quality measures index with.

use btfrs_core::{rng, Error, Result};

/// Sample pixel (row-major index into the finest sample level) of every output pixel.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CoordMap {
    /// Output columns.
    pub width: usize,
    /// Output rows.
    pub height: usize,
    /// Sample columns.
    pub sample_width: usize,
    /// Sample rows.
    pub sample_height: usize,
    /// `height * width` sample pixel indices, row-major.
    pub src: Vec<u32>,
}

impl CoordMap {
    /// `[height, width, 2]` `(x, y)` pairs, as the renderer takes them.
    pub fn to_xy(&self) -> Vec<u16> {
        self.src
            .iter()
            .flat_map(|&s| [(s as usize % self.sample_width) as u16, (s as usize / self.sample_width) as u16])
            .collect()
    }

    /// Build from `[height, width, 2]` `(x, y)` pairs, checking they fall inside the sample.
    pub fn from_xy(height: usize, width: usize, xy: &[u16], sample_height: usize, sample_width: usize) -> Result<Self> {
        if height == 0 || width == 0 || xy.len() != height * width * 2 {
            return Err(Error::arg(
                "coords",
                format!("expected a non-empty [H, W, 2] map, got {} values for {height} x {width}", xy.len()),
            ));
        }
        if let Some(p) =
            xy.chunks_exact(2).position(|c| c[0] as usize >= sample_width || c[1] as usize >= sample_height)
        {
            return Err(Error::arg(
                "coords",
                format!(
                    "pixel ({}, {}) maps to ({}, {}), outside the {sample_height} x {sample_width} sample",
                    p % width,
                    p / width,
                    xy[2 * p],
                    xy[2 * p + 1]
                ),
            ));
        }
        let src = xy.chunks_exact(2).map(|c| c[1] as u32 * sample_width as u32 + c[0] as u32).collect();
        Ok(Self { width, height, sample_width, sample_height, src })
    }

    /// Plain tiling: output pixel `(x, y)` is sample pixel `(x mod w, y mod h)`.
    pub fn tiled(height: usize, width: usize, sample_height: usize, sample_width: usize) -> Self {
        let src = (0..height)
            .flat_map(|y| (0..width).map(move |x| ((y % sample_height) * sample_width + x % sample_width) as u32))
            .collect();
        Self { width, height, sample_width, sample_height, src }
    }

    /// Random placement: every output pixel an independent uniformly drawn sample pixel.
    pub fn random(height: usize, width: usize, sample_height: usize, sample_width: usize, seed: u64) -> Self {
        let n = (sample_height * sample_width) as f64;
        let src = (0..height * width).map(|i| (rng::hash01(seed, i as i64, 17) * n) as u32).collect();
        Self { width, height, sample_width, sample_height, src }
    }

    /// Sample pixel `(x, y)` of output pixel `(x, y)`.
    #[inline]
    pub fn source(&self, x: usize, y: usize) -> (usize, usize) {
        let s = self.src[y * self.width + x] as usize;
        (s % self.sample_width, s / self.sample_width)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn xy_round_trip_and_range_check() {
        let m = CoordMap::random(5, 7, 3, 4, 9);
        let xy = m.to_xy();
        assert_eq!(CoordMap::from_xy(5, 7, &xy, 3, 4).unwrap(), m);
        assert!(m.src.iter().all(|&s| s < 12));
        let mut bad = xy.clone();
        bad[2 * 6] = 4;
        assert!(CoordMap::from_xy(5, 7, &bad, 3, 4).unwrap_err().to_string().starts_with("coords:"));
        let t = CoordMap::tiled(5, 7, 3, 4);
        assert_eq!(t.source(6, 4), (2, 1));
    }
}
