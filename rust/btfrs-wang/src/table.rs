//! Compact storage and the canonical arrangement of a tile set (paper 002, section 5.3 and
//! Table III; Wei 2004 for the arrangement).
//!
//! * **BTFel table**: not every sample texel is used by a tile set and many are used many times,
//!   so the set stores the referenced texels once (the table, ascending sample index) and per
//!   tile a `tile x tile` array of indices into it.
//! * **Canonical arrangement**: the complete set of `C^4` tiles packed into one `C^2 x C^2`
//!   atlas of tiles such that every two tiles adjacent in the atlas (cyclically) match along
//!   their shared edge. Column `j` holds the tiles whose (west, east) colours are the pair
//!   `(d_j, d_{j+1})` of a de Bruijn sequence `d` of order 2 over the `C` colours (every ordered
//!   pair occurs once, cyclically), row `i` those whose (north, south) colours are
//!   `(d_i, d_{i+1})`. Any layout of tile ids then addresses any material's tile set with the
//!   same colours: the atlas position of a tile is a function of its colours alone, so tile sets
//!   of different materials swap on one layout without re-tiling, and filtering across atlas
//!   borders reads matching neighbours.

use crate::tiles::{tile_code, tile_id, WangTiles};

/// A de Bruijn sequence of order 2 over `k` symbols (length `k^2`), by the standard recursive
/// construction over Lyndon words.
pub fn de_bruijn(k: usize) -> Vec<u8> {
    fn db(t: usize, p: usize, k: usize, a: &mut Vec<usize>, out: &mut Vec<u8>) {
        const N: usize = 2;
        if t > N {
            if N.is_multiple_of(p) {
                out.extend(a[1..=p].iter().map(|&v| v as u8));
            }
        } else {
            a[t] = a[t - p];
            db(t + 1, p, k, a, out);
            for j in a[t - p] + 1..k {
                a[t] = j;
                db(t + 1, t, k, a, out);
            }
        }
    }
    let mut a = vec![0usize; 3];
    let mut out = Vec::new();
    db(1, 1, k, &mut a, &mut out);
    out
}

/// The atlas position (row, column), in tiles, of tile `id` in the canonical arrangement.
pub fn atlas_position(id: usize, colors: usize) -> (usize, usize) {
    let d = de_bruijn(colors);
    let m = d.len();
    let [n, e, s, w] = tile_code(id, colors);
    let pair = |a: u8, b: u8| (0..m).find(|&j| d[j] == a && d[(j + 1) % m] == b).expect("every pair occurs");
    (pair(n, s), pair(w, e))
}

/// The tile at atlas position (row, column): the inverse of [`atlas_position`].
pub fn atlas_tile(row: usize, col: usize, colors: usize) -> usize {
    let d = de_bruijn(colors);
    let m = d.len();
    tile_id([d[row], d[(col + 1) % m], d[(row + 1) % m], d[col]], colors)
}

/// The compact form of a tile set.
#[derive(Debug, Clone)]
pub struct Table {
    /// Referenced sample texels, ascending, each once.
    pub btfels: Vec<u32>,
    /// Per tile, `tile * tile` indices into `btfels`.
    pub tiles: Vec<Vec<u32>>,
    /// The canonical atlas: `(C^2 tile) x (C^2 tile)` indices into `btfels`, row-major.
    pub atlas: Vec<u32>,
    /// Atlas side in tiles (`C^2`).
    pub atlas_tiles: usize,
}

impl Table {
    /// Build the table of `set`.
    pub fn new(set: &WangTiles) -> Table {
        let mut btfels: Vec<u32> = set.texels.iter().flatten().copied().collect();
        btfels.sort_unstable();
        btfels.dedup();
        let index = |t: u32| btfels.binary_search(&t).expect("every texel is in the table") as u32;
        let tiles: Vec<Vec<u32>> = set.texels.iter().map(|tile| tile.iter().map(|&t| index(t)).collect()).collect();
        let a = set.colors * set.colors;
        let w = set.tile;
        let side = a * w;
        let mut atlas = vec![0u32; side * side];
        for r in 0..a {
            for c in 0..a {
                let id = atlas_tile(r, c, set.colors);
                for y in 0..w {
                    let dst = (r * w + y) * side + c * w;
                    atlas[dst..dst + w].copy_from_slice(&tiles[id][y * w..(y + 1) * w]);
                }
            }
        }
        Table { btfels, tiles, atlas, atlas_tiles: a }
    }

    /// Fraction of the sample's texels the set references (Table III's percentage).
    pub fn referenced_fraction(&self, sample_texels: usize) -> f64 {
        self.btfels.len() as f64 / sample_texels as f64
    }

    /// Bytes of the index arrays as stored for rendering: the atlas, u16 indices when the table
    /// has at most 65536 entries, else u32.
    pub fn index_bytes(&self) -> usize {
        self.atlas.len() * if self.btfels.len() <= 1 << 16 { 2 } else { 4 }
    }
}

/// Check that `id` is a tile of a `colors` set (for callers handing ids around).
pub fn valid_id(id: usize, colors: usize) -> bool {
    id < colors.pow(4) && tile_id(tile_code(id, colors), colors) == id
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn de_bruijn_sequences_hold_every_pair_once() {
        for k in 2..=8 {
            let d = de_bruijn(k);
            assert_eq!(d.len(), k * k);
            let mut seen = vec![false; k * k];
            for j in 0..d.len() {
                let p = d[j] as usize * k + d[(j + 1) % d.len()] as usize;
                assert!(!seen[p], "pair {p} twice for k = {k}");
                seen[p] = true;
            }
        }
    }

    #[test]
    fn the_atlas_is_itself_a_valid_periodic_tiling() {
        for colors in 2usize..=4 {
            let a = colors * colors;
            let mut used = vec![false; colors.pow(4)];
            for r in 0..a {
                for c in 0..a {
                    let id = atlas_tile(r, c, colors);
                    assert_eq!(atlas_position(id, colors), (r, c));
                    used[id] = true;
                    let [_, e, s, _] = tile_code(id, colors);
                    let right = tile_code(atlas_tile(r, (c + 1) % a, colors), colors);
                    let below = tile_code(atlas_tile((r + 1) % a, c, colors), colors);
                    assert_eq!(e, right[3]);
                    assert_eq!(s, below[0]);
                }
            }
            assert!(used.iter().all(|&u| u), "every tile appears once");
        }
    }
}
