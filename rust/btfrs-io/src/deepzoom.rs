//! Deep Zoom image pyramids as relight-cli writes them and OpenLIME's `deepzoom` layout reads
//! them (`LayoutTiles.js`): an image `NAME` becomes `NAME.dzi` (an XML descriptor) beside
//! `NAME_files/{level}/{column}_{row}.{jpg|png}`.
//!
//! # The layout
//!
//! * `NAME.dzi`: `<Image xmlns="http://schemas.microsoft.com/deepzoom/2008" Format="jpg"
//!   Overlap="0" TileSize="256"><Size Width="W" Height="H"/></Image>`.
//! * **Levels** are numbered as OpenLIME's `deepzoom` layout numbers them (relight's variant of
//!   Deep Zoom, whose root is one tile, not one pixel): level 0 is the coarsest, the whole image
//!   in one tile; the last level, `levels - 1`, is the image itself. `levels` is the smallest
//!   `k + 1` with `max(W, H) <= TileSize * 2^k` (OpenLIME: `ceil(log2(max / TileSize)) + 1`).
//!   Level `l` is `W >> s` by `H >> s` pixels, `s = levels - 1 - l` (at least 1), each pixel the
//!   mean of the 2 x 2 pixels under it one level finer, rounded (an odd last row or column is
//!   dropped, as relight's writer drops it).
//! * **Tiles**: level `l` is cut into `ceil(Wl / TileSize)` columns and `ceil(Hl / TileSize)`
//!   rows; tile `(c, r)` holds the pixels `x` in `[max(0, c T - Overlap), min((c + 1) T +
//!   Overlap, Wl))` (the same in `y`): Deep Zoom's overlap convention (relight writes
//!   `Overlap="0"`).
//!
//! # Reading
//!
//! [`read_image`] reads the last level, assembled from its tiles, after checking every tile of
//! every level: the descriptor through [`crate::untrusted`] (a regular file within the XML cap,
//! parsed with its bounds), each tile present as a regular file of the size the layout gives
//! it (from its header), and decoded within the image budget, so that a missing, truncated or
//! resized tile anywhere in the pyramid is an [`Error::Format`] naming the tile.

use std::path::{Path, PathBuf};

use btfrs_core::{Error, Monitor, Result};
use rayon::prelude::*;

use crate::untrusted;

/// The tile side relight and OpenLIME use.
pub const TILE_SIZE: usize = 256;
/// Largest tile side accepted from a descriptor.
pub const MAX_TILE: usize = 8192;
/// Largest image side accepted from a descriptor (relight's and NeuralRTI's cap).
pub const MAX_SIDE: usize = 1 << 15;

/// How a pyramid is written: tile side, overlap, image format (`"jpg"` or `"png"`) and JPEG
/// quality.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Tiling {
    /// Tile side in pixels.
    pub tile_size: usize,
    /// Pixels each tile shares with its neighbours, per side.
    pub overlap: usize,
    /// `"jpg"` or `"png"`.
    pub format: String,
    /// JPEG quality (1 to 100).
    pub quality: u8,
}

impl Default for Tiling {
    fn default() -> Tiling {
        Tiling { tile_size: TILE_SIZE, overlap: 0, format: "jpg".into(), quality: 95 }
    }
}

impl Tiling {
    /// Check the settings (an error naming the setting).
    pub fn validate(&self) -> Result<()> {
        if !(16..=MAX_TILE).contains(&self.tile_size) {
            return Err(Error::arg("tile_size", format!("expected 16 to {MAX_TILE} pixels, got {}", self.tile_size)));
        }
        if self.overlap >= self.tile_size / 2 {
            return Err(Error::arg(
                "overlap",
                format!("expected fewer than half the tile side ({}) pixels, got {}", self.tile_size / 2, self.overlap),
            ));
        }
        if self.format != "jpg" && self.format != "png" {
            return Err(Error::arg("tile_format", format!("expected \"jpg\" or \"png\", got {:?}", self.format)));
        }
        if !(1..=100).contains(&self.quality) {
            return Err(Error::arg("quality", format!("expected 1 to 100, got {}", self.quality)));
        }
        Ok(())
    }
}

/// The pyramid of a `width x height` image cut in `tile_size` tiles with `overlap`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Pyramid {
    /// Image width (the last level's).
    pub width: usize,
    /// Image height.
    pub height: usize,
    /// Tile side.
    pub tile_size: usize,
    /// Overlap per side.
    pub overlap: usize,
    /// Number of levels.
    pub levels: usize,
}

/// OpenLIME's level count: the smallest `k + 1` with `max(width, height) <= tile * 2^k`.
pub fn level_count(width: usize, height: usize, tile: usize) -> usize {
    let m = width.max(height).max(1);
    let mut k = 0;
    while tile << k < m {
        k += 1;
    }
    k + 1
}

impl Pyramid {
    /// The pyramid of an image (sizes checked).
    pub fn new(width: usize, height: usize, tile_size: usize, overlap: usize) -> Result<Pyramid> {
        if width == 0 || height == 0 || width > MAX_SIDE || height > MAX_SIDE {
            return Err(Error::arg("image", format!("expected sides in 1..={MAX_SIDE}, got {width} x {height}")));
        }
        Ok(Pyramid { width, height, tile_size, overlap, levels: level_count(width, height, tile_size) })
    }

    /// `(width, height)` of level `level` (0 the coarsest).
    pub fn size(&self, level: usize) -> (usize, usize) {
        let s = self.levels - 1 - level;
        ((self.width >> s).max(1), (self.height >> s).max(1))
    }

    /// `(columns, rows)` of tiles at `level`.
    pub fn grid(&self, level: usize) -> (usize, usize) {
        let (w, h) = self.size(level);
        (w.div_ceil(self.tile_size), h.div_ceil(self.tile_size))
    }

    /// The pixels `[x0, x1) x [y0, y1)` of tile `(col, row)` at `level`.
    pub fn rect(&self, level: usize, col: usize, row: usize) -> [usize; 4] {
        let (w, h) = self.size(level);
        let (t, o) = (self.tile_size, self.overlap);
        [
            (col * t).saturating_sub(o),
            (row * t).saturating_sub(o),
            ((col + 1) * t + o).min(w),
            ((row + 1) * t + o).min(h),
        ]
    }

    /// Every tile: `(level, col, row)`, coarsest level first.
    pub fn tiles(&self) -> Vec<(usize, usize, usize)> {
        let mut out = Vec::new();
        for l in 0..self.levels {
            let (c, r) = self.grid(l);
            for row in 0..r {
                for col in 0..c {
                    out.push((l, col, row));
                }
            }
        }
        out
    }

    /// The descriptor (`NAME.dzi`) of this pyramid with tiles in `format`.
    pub fn dzi(&self, format: &str) -> String {
        format!(
            "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<Image xmlns=\"http://schemas.microsoft.com/deepzoom/2008\"\n  \
             Format=\"{format}\"\n  Overlap=\"{}\"\n  TileSize=\"{}\">\n  <Size Height=\"{}\" Width=\"{}\"/>\n</Image>\n",
            self.overlap, self.tile_size, self.height, self.width
        )
    }
}

/// The next coarser level of an RGB image: each pixel the rounded mean of the 2 x 2 under it
/// (an odd last row or column dropped; a side of 1 stays 1).
pub fn halve(rgb: &[u8], width: usize, height: usize) -> (Vec<u8>, usize, usize) {
    let (w, h) = ((width / 2).max(1), (height / 2).max(1));
    let mut out = vec![0u8; w * h * 3];
    out.par_chunks_mut(w * 3).enumerate().for_each(|(y, row)| {
        let y0 = (2 * y).min(height - 1);
        let y1 = (2 * y + 1).min(height - 1);
        for x in 0..w {
            let x0 = (2 * x).min(width - 1);
            let x1 = (2 * x + 1).min(width - 1);
            for c in 0..3 {
                let s = rgb[(y0 * width + x0) * 3 + c] as u32
                    + rgb[(y0 * width + x1) * 3 + c] as u32
                    + rgb[(y1 * width + x0) * 3 + c] as u32
                    + rgb[(y1 * width + x1) * 3 + c] as u32;
                row[x * 3 + c] = ((s + 2) / 4) as u8;
            }
        }
    });
    (out, w, h)
}

/// The folder of a pyramid's tiles: `NAME_files` beside `NAME.dzi`.
pub fn tiles_folder(dir: &Path, name: &str) -> PathBuf {
    dir.join(format!("{name}_files"))
}

/// The file of one tile.
pub fn tile_path(dir: &Path, name: &str, level: usize, col: usize, row: usize, format: &str) -> PathBuf {
    tiles_folder(dir, name).join(level.to_string()).join(format!("{col}_{row}.{format}"))
}

/// Write the pyramid of an RGB image (`width x height`, rows top first) as `NAME.dzi` and
/// `NAME_files/` in `dir` (plain writes: the caller writes into a temporary folder that it
/// renames). Tiles are encoded in parallel; `monitor` advances by one per tile and stops the
/// work when cancelled. Returns the number of tiles.
pub fn write_image(
    dir: &Path,
    name: &str,
    rgb: &[u8],
    width: usize,
    height: usize,
    tiling: &Tiling,
    monitor: &Monitor,
) -> Result<usize> {
    tiling.validate()?;
    let pyr = Pyramid::new(width, height, tiling.tile_size, tiling.overlap)?;
    // Levels, finest first, then written coarsest first.
    let mut levels = vec![(rgb.to_vec(), width, height)];
    for _ in 1..pyr.levels {
        let (img, w, h) = levels.last().expect("one level at least");
        let next = halve(img, *w, *h);
        levels.push(next);
    }
    levels.reverse();
    let mut count = 0;
    for (l, (img, w, _)) in levels.iter().enumerate() {
        debug_assert_eq!((*w, levels[l].2), pyr.size(l));
        let folder = tiles_folder(dir, name).join(l.to_string());
        std::fs::create_dir_all(&folder).map_err(|e| Error::io(folder.display(), e))?;
        let (cols, rows) = pyr.grid(l);
        let cells: Vec<(usize, usize)> = (0..rows).flat_map(|r| (0..cols).map(move |c| (c, r))).collect();
        cells.par_iter().try_for_each(|&(c, r)| -> Result<()> {
            monitor.check()?;
            let [x0, y0, x1, y1] = pyr.rect(l, c, r);
            let tw = x1 - x0;
            let mut tile = Vec::with_capacity(tw * (y1 - y0) * 3);
            for y in y0..y1 {
                tile.extend_from_slice(&img[(y * w + x0) * 3..(y * w + x1) * 3]);
            }
            let path = tile_path(dir, name, l, c, r, &tiling.format);
            let mut bytes = Vec::new();
            crate::image::encode_rgb8(&mut bytes, &tile, tw, y1 - y0, &tiling.format, tiling.quality)
                .map_err(|e| Error::io(path.display(), e))?;
            std::fs::write(&path, bytes).map_err(|e| Error::io(path.display(), e))?;
            monitor.advance(1);
            Ok(())
        })?;
        count += cells.len();
    }
    let dzi = dir.join(format!("{name}.dzi"));
    std::fs::write(&dzi, pyr.dzi(&tiling.format)).map_err(|e| Error::io(dzi.display(), e))?;
    Ok(count)
}

/// What a `.dzi` declares.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Dzi {
    /// The tiles' file extension (`Format`).
    pub format: String,
    /// The pyramid (`TileSize`, `Overlap`, `Size`).
    pub pyramid: Pyramid,
}

/// Read a `.dzi` descriptor (an [`Error::Format`] naming it for anything but a Deep Zoom
/// image of sane sizes).
pub fn read_dzi(path: &Path, max_bytes: u64) -> Result<Dzi> {
    let shown = path.display().to_string();
    let text = untrusted::read_text(path, untrusted::XML_INDEX, max_bytes)?;
    let doc = untrusted::parse_xml(&text, &shown)?;
    let root = doc.root_element();
    if root.tag_name().name() != "Image" {
        return Err(Error::format(
            &shown,
            format!("expected a Deep Zoom <Image> element, got <{}>", root.tag_name().name()),
        ));
    }
    let num = |node: roxmltree::Node<'_, '_>, key: &str, lo: usize, hi: usize| -> Result<usize> {
        let v = node
            .attribute(key)
            .ok_or_else(|| Error::format(&shown, format!("<{}> has no {key} attribute", node.tag_name().name())))?;
        v.trim()
            .parse::<usize>()
            .ok()
            .filter(|n| (lo..=hi).contains(n))
            .ok_or_else(|| Error::format(&shown, format!("{key}: expected an integer in {lo}..={hi}, got {v:?}")))
    };
    let format = root
        .attribute("Format")
        .ok_or_else(|| Error::format(&shown, "<Image> has no Format attribute"))?
        .to_ascii_lowercase();
    if !["jpg", "jpeg", "png"].contains(&format.as_str()) {
        return Err(Error::format(&shown, format!("Format: expected jpg or png tiles, got {format:?}")));
    }
    let tile = num(root, "TileSize", 1, MAX_TILE)?;
    let overlap = num(root, "Overlap", 0, tile / 2)?;
    let size = root
        .children()
        .find(|n| n.is_element() && n.tag_name().name() == "Size")
        .ok_or_else(|| Error::format(&shown, "<Image> has no <Size> element"))?;
    let width = num(size, "Width", 1, MAX_SIDE)?;
    let height = num(size, "Height", 1, MAX_SIDE)?;
    Ok(Dzi { format, pyramid: Pyramid::new(width, height, tile, overlap)? })
}

/// The descriptor `dir/NAME.dzi`, its `Size` checked against the `width x height` the index
/// file `index` declares (what a reader checks of every pyramid before allocating the image).
pub fn read_sized_dzi(dir: &Path, name: &str, width: usize, height: usize, index: &str, max_bytes: u64) -> Result<Dzi> {
    let dzi_path = dir.join(format!("{name}.dzi"));
    let dzi = read_dzi(&dzi_path, max_bytes)?;
    let pyr = dzi.pyramid;
    if (pyr.width, pyr.height) != (width, height) {
        return Err(Error::format(
            dzi_path.display(),
            format!("Size is {} x {}; {index} declares {width} x {height}", pyr.width, pyr.height),
        ));
    }
    Ok(dzi)
}

/// The last level of the pyramid `dir/NAME.dzi` as RGB bytes (`width x height`, the size the
/// index file `index` declares), every tile of every level checked first (see the module doc).
/// `levels`: the level count the index file declares, if it does. Decoding stays within
/// `max_bytes` per tile; the caller checks the image's own bytes against its budget.
pub fn read_image(
    dir: &Path,
    name: &str,
    width: usize,
    height: usize,
    levels: Option<usize>,
    index: &str,
    max_bytes: u64,
) -> Result<Vec<u8>> {
    let dzi = read_sized_dzi(dir, name, width, height, index, max_bytes)?;
    let pyr = dzi.pyramid;
    if let Some(n) = levels {
        if n != pyr.levels {
            return Err(Error::format(
                index,
                format!(
                    "declares {n} levels of tiles, but {name}.dzi ({} x {}, {}-pixel tiles) makes {} levels",
                    pyr.width, pyr.height, pyr.tile_size, pyr.levels
                ),
            ));
        }
    }
    // No level beyond the last (a pyramid numbered another way: from a 1-pixel root).
    let extra = tiles_folder(dir, name).join(pyr.levels.to_string());
    if untrusted::present(&extra) {
        return Err(Error::format(
            extra.display(),
            format!(
                "a level {} beside {name}.dzi, whose {} x {} pixels in {}-pixel tiles make levels 0 to {} \
                 (level 0 one tile, as relight and OpenLIME number them)",
                pyr.levels,
                pyr.width,
                pyr.height,
                pyr.tile_size,
                pyr.levels - 1
            ),
        ));
    }
    let tiles = pyr.tiles();
    // Every tile present and of its size (headers only) before anything is decoded.
    tiles.par_iter().try_for_each(|&(l, c, r)| -> Result<()> {
        let path = tile_path(dir, name, l, c, r, &dzi.format);
        if !untrusted::present(&path) {
            return Err(Error::format(
                path.display(),
                format!("missing: tile ({c}, {r}) of level {l} of {name}.dzi ({} levels)", pyr.levels),
            ));
        }
        let [x0, y0, x1, y1] = pyr.rect(l, c, r);
        let (w, h) = untrusted::image_size(&path)?;
        if (w as usize, h as usize) != (x1 - x0, y1 - y0) {
            return Err(Error::format(
                path.display(),
                format!(
                    "{w} x {h} pixels; tile ({c}, {r}) of level {l} of {name}.dzi is {} x {} pixels",
                    x1 - x0,
                    y1 - y0
                ),
            ));
        }
        Ok(())
    })?;
    let last = pyr.levels - 1;
    let mut out = vec![0u8; width * height * 3];
    // Decoded level by level: the coarser levels only to find a damaged tile.
    for l in 0..pyr.levels {
        let level: Vec<&(usize, usize, usize)> = tiles.iter().filter(|t| t.0 == l).collect();
        let decoded = level
            .par_iter()
            .map(|&&(_, c, r)| {
                let [x0, y0, x1, y1] = pyr.rect(l, c, r);
                let path = tile_path(dir, name, l, c, r, &dzi.format);
                let px = untrusted::read_rgb8(&path, x1 - x0, y1 - y0, max_bytes)?;
                Ok(if l == last { Some((c, r, px)) } else { None })
            })
            .collect::<Result<Vec<_>>>()?;
        for (c, r, px) in decoded.into_iter().flatten() {
            let [x0, y0, x1, _] = pyr.rect(l, c, r);
            // The tile's own pixels, without the overlap it shares with its neighbours.
            let (cx0, cy0) = (c * pyr.tile_size, r * pyr.tile_size);
            let (cx1, cy1) = (((c + 1) * pyr.tile_size).min(width), ((r + 1) * pyr.tile_size).min(height));
            let tw = x1 - x0;
            for y in cy0..cy1 {
                let src = ((y - y0) * tw + (cx0 - x0)) * 3;
                out[(y * width + cx0) * 3..(y * width + cx1) * 3].copy_from_slice(&px[src..src + (cx1 - cx0) * 3]);
            }
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn level_counts_and_sizes_are_openlimes() {
        // OpenLIME: nlevels = ceil(log2(max / tile)) + 1, each level half the next (floor).
        for (w, h, n) in [(256, 100, 1), (257, 10, 2), (512, 512, 2), (513, 3, 3), (2048, 2048, 4), (6000, 4000, 6)] {
            let want = (w.max(h) as f64 / 256.0).log2().ceil().max(0.0) as usize + 1;
            assert_eq!(level_count(w, h, 256), n, "{w} x {h}");
            assert_eq!(n, want);
        }
        let p = Pyramid::new(6000, 4000, 256, 0).unwrap();
        assert_eq!(p.size(5), (6000, 4000));
        assert_eq!(p.size(0), (187, 125));
        assert!(p.size(0).0 <= 256 && p.size(1).0 > 256);
        assert_eq!(p.grid(5), (24, 16));
    }

    #[test]
    fn tiles_cover_each_level_once_and_share_the_overlap() {
        let p = Pyramid::new(600, 300, 256, 1).unwrap();
        let l = p.levels - 1;
        let (w, h) = p.size(l);
        let mut cover = vec![0u32; w * h];
        let (cols, rows) = p.grid(l);
        for r in 0..rows {
            for c in 0..cols {
                let [x0, y0, x1, y1] = p.rect(l, c, r);
                assert_eq!(x0, (c * 256).saturating_sub(1));
                assert_eq!(x1, ((c + 1) * 256 + 1).min(w));
                assert_eq!(y0, (r * 256).saturating_sub(1));
                for y in y0..y1 {
                    for x in x0..x1 {
                        cover[y * w + x] += 1;
                    }
                }
            }
        }
        // Every pixel at least once; the seams' pixels (255, 256) twice.
        assert!(cover.iter().all(|&n| n >= 1));
        assert_eq!(cover[10 * w + 255], 2);
        assert_eq!(cover[10 * w + 300], 1);
    }

    #[test]
    fn halving_averages_two_by_two_and_drops_an_odd_edge() {
        let (w, h) = (5, 3);
        let rgb: Vec<u8> = (0..w * h * 3).map(|i| (i * 7 % 256) as u8).collect();
        let (out, ow, oh) = halve(&rgb, w, h);
        assert_eq!((ow, oh), (2, 1));
        for x in 0..2 {
            for c in 0..3 {
                let at = |xx: usize, yy: usize| rgb[(yy * w + xx) * 3 + c] as f64;
                let mean = (at(2 * x, 0) + at(2 * x + 1, 0) + at(2 * x, 1) + at(2 * x + 1, 1)) / 4.0;
                assert!((out[x * 3 + c] as f64 - mean).abs() <= 0.5, "{x} {c}");
            }
        }
    }

    #[test]
    fn a_written_pyramid_reads_back_and_its_damage_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let (w, h) = (300, 140);
        let rgb: Vec<u8> = (0..w * h * 3).map(|i| ((i * 31) ^ (i / 7)) as u8).collect();
        let t = Tiling { tile_size: 128, overlap: 1, format: "png".into(), quality: 90 };
        let n = write_image(dir.path(), "plane_0", &rgb, w, h, &t, &Monitor::new()).unwrap();
        // Levels 75 x 35 (1 tile), 150 x 70 (2), 300 x 140 (3 x 2).
        assert_eq!(n, 1 + 2 + 6);
        let back = read_image(dir.path(), "plane_0", w, h, Some(3), "info.json", 1 << 30).unwrap();
        assert_eq!(back, rgb);
        let e = read_image(dir.path(), "plane_0", w, h, Some(4), "info.json", 1 << 30).unwrap_err();
        assert!(e.to_string().contains("declares 4 levels"), "{e}");
        // A truncated coarse tile, then a missing one.
        let t0 = tile_path(dir.path(), "plane_0", 1, 1, 0, "png");
        let bytes = std::fs::read(&t0).unwrap();
        std::fs::write(&t0, &bytes[..bytes.len() / 2]).unwrap();
        let e = read_image(dir.path(), "plane_0", w, h, None, "info.json", 1 << 30).unwrap_err();
        assert!(matches!(&e, Error::Format { path, .. } if path.ends_with("1_0.png")), "{e}");
        std::fs::remove_file(&t0).unwrap();
        let e = read_image(dir.path(), "plane_0", w, h, None, "info.json", 1 << 30).unwrap_err();
        assert!(e.to_string().contains("missing") && e.to_string().contains("1_0.png"), "{e}");
    }
}
