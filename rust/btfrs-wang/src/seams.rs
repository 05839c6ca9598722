//! Seams you can measure: the neighbourhood error of a tiled texture across tile edges against
//! inside tiles.
//!
//! Each window (`window x window` texels) of an output is compared with its best match among all
//! windows of the sample; a window that copies the sample scores 0, one that straddles a visible
//! seam scores the distance to the nearest thing the sample really contains. Windows centred on a
//! tile edge (the window straddles it) and windows that straddle none are drawn at random
//! (seeded), and the mean of each group is reported relative to the sample's pair scale
//! ([`crate::features::Features::pair_scale`]) per window texel. A tile set without visible
//! seams has an edge error close to its interior error; plain tiling of random crops of a sample
//! has interior error 0 and a large edge error.

use crate::features::{dist2, FeatureOps, Features};
use btfrs_core::rng::{mix, Rng};
use btfrs_core::{Error, Result};
use rayon::prelude::*;

/// The texels of a tiled output: `layout` (rows x cols tile ids) drawn with `tiles` (per tile id,
/// `tile * tile` sample texels). Row-major `(rows * tile) x (cols * tile)`.
pub fn layout_texels(tiles: &[Vec<u32>], tile: usize, layout: &[u32], rows: usize, cols: usize) -> Result<Vec<u32>> {
    if layout.len() != rows * cols {
        return Err(Error::arg("layout", format!("expected {rows} x {cols} ids, got {}", layout.len())));
    }
    if let Some(&bad) = layout.iter().find(|&&t| t as usize >= tiles.len()) {
        return Err(Error::arg("layout", format!("tile {bad} does not exist (the set has {})", tiles.len())));
    }
    let side = cols * tile;
    let mut out = vec![0u32; rows * tile * side];
    for r in 0..rows {
        for c in 0..cols {
            let t = &tiles[layout[r * cols + c] as usize];
            for y in 0..tile {
                let dst = (r * tile + y) * side + c * tile;
                out[dst..dst + tile].copy_from_slice(&t[y * tile..(y + 1) * tile]);
            }
        }
    }
    Ok(out)
}

/// Plain tiling of random crops: `rows x cols` cells, each an independent random `tile x tile`
/// crop of the sample (the baseline a seam measure must catch).
pub fn random_crops(sample: (usize, usize), tile: usize, rows: usize, cols: usize, seed: u64) -> Vec<u32> {
    let (sh, sw) = sample;
    let mut rng = Rng::new(mix(seed ^ 0xc40b));
    let tiles: Vec<Vec<u32>> = (0..rows * cols)
        .map(|_| {
            let (oy, ox) = (rng.below(sh - tile + 1), rng.below(sw - tile + 1));
            (0..tile * tile).map(|i| ((oy + i / tile) * sw + ox + i % tile) as u32).collect()
        })
        .collect();
    let layout: Vec<u32> = (0..(rows * cols) as u32).collect();
    layout_texels(&tiles, tile, &layout, rows, cols).expect("layout of its own tiles")
}

/// Edge and interior window errors of an `height x width` output of sample texels tiled by
/// `tile`; `windows` windows of each kind.
#[allow(clippy::too_many_arguments)]
pub fn edge_interior_error(
    f: &Features,
    output: &[u32],
    height: usize,
    width: usize,
    tile: usize,
    window: usize,
    windows: usize,
    seed: u64,
) -> Result<(f64, f64)> {
    if output.len() != height * width {
        return Err(Error::arg("output", format!("expected {height} x {width} texels, got {}", output.len())));
    }
    if window < 2 || window >= tile || window > f.height || window > f.width {
        return Err(Error::arg("window", format!("expected 2..{tile} and within the sample, got {window}")));
    }
    if let Some(&bad) = output.iter().find(|&&t| t as usize >= f.texels()) {
        return Err(Error::arg("output", format!("texel {bad} is outside the sample")));
    }
    let (red, _) = f.reduced(4.min(f.dim));
    let d = red.dim;
    let wn = window;
    let patch = |get: &dyn Fn(usize, usize) -> u32, y: usize, x: usize| -> Vec<f32> {
        let mut v = Vec::with_capacity(wn * wn * d);
        for dy in 0..wn {
            for dx in 0..wn {
                v.extend_from_slice(red.at(get(y + dy, x + dx) as usize));
            }
        }
        v
    };
    let sw = f.width;
    let from_sample = |y: usize, x: usize| (y * sw + x) as u32;
    let sample_windows: Vec<Vec<f32>> = (0..=f.height - wn)
        .flat_map(|y| (0..=f.width - wn).map(move |x| (y, x)))
        .collect::<Vec<_>>()
        .par_iter()
        .map(|&(y, x)| patch(&from_sample, y, x))
        .collect();
    let from_out = |y: usize, x: usize| output[y * width + x];
    let mut rng = Rng::new(mix(seed ^ 0x5ea3));
    // Windows straddling a tile edge: top-left corners such that the window crosses a boundary
    // line; interior windows: crossing none.
    let crosses = |a: usize| (a / tile) != ((a + wn - 1) / tile);
    let mut edge = Vec::new();
    let mut inner = Vec::new();
    let mut tries = 0;
    while (edge.len() < windows || inner.len() < windows) && tries < windows * 200 {
        tries += 1;
        let (y, x) = (rng.below(height - wn + 1), rng.below(width - wn + 1));
        let on_edge = crosses(y) || crosses(x);
        if on_edge && edge.len() < windows {
            edge.push((y, x));
        } else if !on_edge && inner.len() < windows {
            inner.push((y, x));
        }
    }
    let score = |set: &[(usize, usize)]| -> f64 {
        let s: f64 = set
            .par_iter()
            .map(|&(y, x)| {
                let p = patch(&from_out, y, x);
                sample_windows.iter().map(|q| dist2(&p, q)).fold(f64::INFINITY, f64::min)
            })
            .sum();
        s / set.len().max(1) as f64
    };
    let norm = f.pair_scale(seed) * (wn * wn) as f64;
    Ok((score(&edge) / norm, score(&inner) / norm))
}
