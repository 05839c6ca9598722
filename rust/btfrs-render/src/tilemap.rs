//! Tile maps: the texel lookup of a Wang-tiled surface (paper 002, section 4).
//!
//! A tile set is an *atlas* of texel ids (the canonical arrangement of `btfrs-wang`, or any
//! grid of equal tiles) and a *layout*: per cell the atlas tile drawn there. A fragment's
//! `uv * uv_scale` (fractional part) spans the whole layout; the cell and the position inside it
//! pick one atlas texel, whose entry is the model texel to shade. Tiles are never rotated (a BTF
//! keeps its orientation) and the tangent frame stays the mesh's in every tile. The lookup is
//! written once here and once in `common.wgsl`, in the same f32 operations:
//!
//! ```text
//! gx = f.x * cols;  gy = (1 - f.y) * rows          (row 0 at the top, as the sample's)
//! cx = min(u32(gx), cols - 1);  cy = min(u32(gy), rows - 1)
//! px = min(u32((gx - cx) * tile), tile - 1);  py likewise
//! e = layout[cy * cols + cx];  ax = (e & 0xffff) * tile + px;  ay = (e >> 16) * tile + py
//! texel = atlas[ay * atlas_cols * tile + ax]
//! ```

use btfrs_core::{Error, Result};

/// Largest layout or atlas side, in cells / tiles (entries are packed as 16-bit halves).
pub const MAX_CELLS: usize = 1 << 16;
/// Largest number of entries (layout plus atlas): storage indices stay exact in u32, and f32
/// cell coordinates stay exact below 2^24.
pub const MAX_ENTRIES: usize = 1 << 28;

/// A tile map: see the module docs.
#[derive(Clone, Copy, Debug)]
pub struct TileMap<'a> {
    /// Tile side in texels.
    pub tile: usize,
    /// Atlas size in tiles: columns.
    pub atlas_cols: usize,
    /// Atlas size in tiles: rows.
    pub atlas_rows: usize,
    /// Per atlas texel (row-major, row 0 at the top), the model texel (row-major index) to shade.
    pub atlas: &'a [u32],
    /// Layout size in cells: columns.
    pub layout_cols: usize,
    /// Layout size in cells: rows.
    pub layout_rows: usize,
    /// Per cell (row-major, row 0 at the top), the atlas tile: `(atlas_row << 16) | atlas_col`.
    pub layout: &'a [u32],
}

impl TileMap<'_> {
    /// Check sizes and every entry against a model of `texels` texels (argument "tiles").
    pub fn validate(&self, texels: usize) -> Result<()> {
        let bad = |m: String| Err(Error::arg("tiles", m));
        if self.tile == 0
            || self.atlas_cols == 0
            || self.atlas_rows == 0
            || self.layout_cols == 0
            || self.layout_rows == 0
        {
            return bad(format!(
                "expected non-empty sizes, got tile {}, atlas {} x {} tiles, layout {} x {} cells",
                self.tile, self.atlas_rows, self.atlas_cols, self.layout_rows, self.layout_cols
            ));
        }
        for (what, v) in [
            ("atlas columns", self.atlas_cols),
            ("atlas rows", self.atlas_rows),
            ("layout columns", self.layout_cols),
            ("layout rows", self.layout_rows),
        ] {
            if v > MAX_CELLS {
                return bad(format!("{what}: {v} is above {MAX_CELLS}"));
            }
        }
        let side = self.tile.checked_mul(self.atlas_cols.max(self.atlas_rows));
        let want = self.tile.checked_mul(self.tile).and_then(|t| t.checked_mul(self.atlas_cols * self.atlas_rows));
        if side.is_none_or(|s| s > MAX_CELLS * 16) || want.is_none_or(|w| w + self.layout.len() > MAX_ENTRIES) {
            return bad(format!("the atlas is too large (at most {MAX_ENTRIES} entries with the layout)"));
        }
        let want = want.unwrap_or(0);
        if self.atlas.len() != want {
            return bad(format!(
                "the atlas of {} x {} tiles of {}^2 needs {want} entries, got {}",
                self.atlas_rows,
                self.atlas_cols,
                self.tile,
                self.atlas.len()
            ));
        }
        if self.layout.len() != self.layout_cols * self.layout_rows {
            return bad(format!(
                "a {} x {} layout needs {} entries, got {}",
                self.layout_rows,
                self.layout_cols,
                self.layout_cols * self.layout_rows,
                self.layout.len()
            ));
        }
        if let Some(i) = self
            .layout
            .iter()
            .position(|&e| (e & 0xffff) as usize >= self.atlas_cols || (e >> 16) as usize >= self.atlas_rows)
        {
            return bad(format!(
                "layout cell (row {}, column {}) names atlas tile (row {}, column {}), outside the {} x {} atlas",
                i / self.layout_cols,
                i % self.layout_cols,
                self.layout[i] >> 16,
                self.layout[i] & 0xffff,
                self.atlas_rows,
                self.atlas_cols
            ));
        }
        if let Some(i) = self.atlas.iter().position(|&t| t as usize >= texels) {
            let w = self.atlas_cols * self.tile;
            return bad(format!(
                "atlas entry (row {}, column {}) is texel {}, but the model has {texels} texels",
                i / w,
                i % w,
                self.atlas[i]
            ));
        }
        Ok(())
    }

    /// The model texel at the fractional texture coordinate `f` (both in [0, 1)), in the f32
    /// operations of `common.wgsl`.
    #[inline]
    pub fn texel(&self, f: [f32; 2]) -> usize {
        let (lc, lr, tile) = (self.layout_cols as u32, self.layout_rows as u32, self.tile as u32);
        let gx = f[0] * lc as f32;
        let gy = (1.0 - f[1]) * lr as f32;
        let cx = (gx as u32).min(lc - 1);
        let cy = (gy as u32).min(lr - 1);
        let px = (((gx - cx as f32) * tile as f32) as u32).min(tile - 1);
        let py = (((gy - cy as f32) * tile as f32) as u32).min(tile - 1);
        let e = self.layout[(cy * lc + cx) as usize];
        let ax = (e & 0xffff) * tile + px;
        let ay = (e >> 16) * tile + py;
        self.atlas[(ay * self.atlas_cols as u32 * tile + ax) as usize] as usize
    }

    /// The GPU form: the layout followed by the atlas, one u32 buffer; the atlas offset.
    pub fn packed(&self) -> (Vec<u32>, u32) {
        let mut v = Vec::with_capacity(self.layout.len() + self.atlas.len());
        v.extend_from_slice(self.layout);
        v.extend_from_slice(self.atlas);
        (v, self.layout.len() as u32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lookup_walks_cells_and_tiles() {
        // 2 x 1 atlas of 2^2 tiles with ids 0..8 (tile 0: 0 1 / 4 5 in atlas texels), layout
        // 1 x 2 drawing tile 1 then tile 0.
        let atlas: Vec<u32> = (0..8).collect();
        let layout = [1u32, 0];
        let m = TileMap {
            tile: 2,
            atlas_cols: 2,
            atlas_rows: 1,
            atlas: &atlas,
            layout_cols: 2,
            layout_rows: 1,
            layout: &layout,
        };
        m.validate(8).unwrap();
        // Top-left quarter of the first cell: tile 1's top-left = atlas (0, 2) = 2.
        assert_eq!(m.texel([0.1, 0.9]), 2);
        assert_eq!(m.texel([0.4, 0.1]), 7); // bottom-right of tile 1: atlas (1, 3)
        assert_eq!(m.texel([0.6, 0.9]), 0);
        assert_eq!(m.texel([0.999_999_9, 0.0]), 5);
        assert!(m.validate(7).unwrap_err().to_string().contains("texel 7"));
        let bad = [2u32, 0];
        let m2 = TileMap { layout: &bad, ..m };
        assert!(m2.validate(8).unwrap_err().to_string().contains("outside the 1 x 2 atlas"));
    }
}
