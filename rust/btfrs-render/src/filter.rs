//! Filtered texel lookups: bilinear and trilinear (mip-mapped) over the sample, a coordinate map
//! or a Wang tile map, the same in `common.wgsl` and the CPU reference.
//!
//! **The virtual texture.** What a fragment looks up is the texture the surface shows: the
//! sample itself (W x H), a synthesised coordinate map (Mw x Mh entries, paper 000 section 5) or
//! a tile layout (cols x tile by rows x tile texels, paper 002 section 4). Filtering happens in
//! that virtual texture: a bilinear lookup takes its four nearest virtual texels (wrapping, as
//! the texture repeats) and resolves *each* through the map on its own. So across a map
//! discontinuity (a jump in the coordinate map, an edge between two tiles) the taps are the
//! texels the synthesised texture really has side by side, not the sample's neighbours of one
//! of them: no seams. Hardware mip-mapping of the sample would blend the sample's neighbours and
//! show the map's discontinuities instead.
//!
//! **Mip levels.** Level `L` halves the virtual texture `L` times (sizes `max(1, s >> L)`, as GPUs
//! do; a tile map halves each tile, as long as the tile side stays an integer). A BTF texel is a
//! *model* (lobes, clusters, coefficients): most models' parameters cannot be averaged, so a
//! coarse texel is not a blend but the **appearance medoid** of its block: the finest texel of the
//! block whose appearance signature (the model evaluated at a few fixed view and light pairs,
//! computed by the caller) is closest to the block's mean signature. Chosen hierarchically (among
//! the four children's medoids, against the mean over all texels of the block), so building the
//! chain is O(texels). A trilinear lookup blends two bilinear lookups at the levels around
//! `lambda = log2(texels per pixel)`, from the fine (per 2 x 2 pixel quad row / column)
//! screen-space derivatives of the texture coordinate, `dpdxFine` / `dpdyFine` on the GPU, the
//! same differences of the interpolated coordinate on the CPU ([`crate::raster::Fragment`]).
//! A bilinear lookup evaluates the model four times per light, a trilinear one eight.

use btfrs_core::{Error, Result};

/// The lookup a render uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum Filter {
    /// One texel (the default; unchanged from the unfiltered renderer).
    #[default]
    Nearest,
    /// Four virtual texels of level 0.
    Bilinear,
    /// Two bilinear lookups at the levels around the pixel's footprint.
    Trilinear,
}

impl Filter {
    /// Parse "nearest" | "bilinear" | "trilinear" (argument "filter").
    pub fn parse(s: &str) -> Result<Filter> {
        match s {
            "nearest" => Ok(Filter::Nearest),
            "bilinear" => Ok(Filter::Bilinear),
            "trilinear" => Ok(Filter::Trilinear),
            o => Err(Error::arg("filter", format!("expected \"nearest\", \"bilinear\" or \"trilinear\", got {o:?}"))),
        }
    }

    /// The shader's mode number (`g.lookup.x`).
    pub fn mode(self) -> u32 {
        match self {
            Filter::Nearest => 0,
            Filter::Bilinear => 1,
            Filter::Trilinear => 2,
        }
    }
}

/// The (view, light) pairs of the appearance signature: the view at the normal and at 45 and
/// 60 degrees, lights around and opposite (specular-like), so that both diffuse colour and the
/// shape of the reflectance count. (theta_v, phi_v, theta_l, phi_l) in degrees.
pub const SIGNATURE_PAIRS: [[f64; 4]; 6] = [
    [0.0, 0.0, 30.0, 0.0],
    [0.0, 0.0, 30.0, 120.0],
    [0.0, 0.0, 30.0, 240.0],
    [45.0, 0.0, 45.0, 180.0],
    [45.0, 90.0, 60.0, 270.0],
    [60.0, 200.0, 20.0, 20.0],
];

/// Floats per texel of [`signatures`].
pub const SIGNATURE_LEN: usize = 3 * SIGNATURE_PAIRS.len();

/// Every texel's appearance signature: the model's RGB at [`SIGNATURE_PAIRS`], texel-major.
pub fn signatures<M: btfrs_fit::Shade + ?Sized>(model: &M) -> Vec<f32> {
    use rayon::prelude::*;
    let (h, w) = model.shade_dims();
    let dir = |t: f64, p: f64| {
        let (t, p) = (t.to_radians(), p.to_radians());
        [t.sin() * p.cos(), t.sin() * p.sin(), t.cos()]
    };
    let pairs: Vec<([f64; 3], [f64; 3])> = SIGNATURE_PAIRS.iter().map(|q| (dir(q[0], q[1]), dir(q[2], q[3]))).collect();
    let mut out = vec![0.0f32; h * w * SIGNATURE_LEN];
    out.par_chunks_mut(SIGNATURE_LEN).enumerate().for_each(|(t, o)| {
        for (k, (v, l)) in pairs.iter().enumerate() {
            o[3 * k..3 * k + 3].copy_from_slice(&model.shade(t, *v, *l));
        }
    });
    out
}

/// Averaged texels of [`MipChain::build_average`]: per new texel, the (texel, weight) pairs.
pub type Groups = Vec<Vec<(u32, f32)>>;

/// One level of a [`MipChain`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Level {
    /// Virtual texture width at this level.
    pub width: u32,
    /// Virtual texture height.
    pub height: u32,
    /// Offset of this level's ids in [`MipChain::ids`].
    pub offset: u32,
    /// Row length of the ids: the virtual width, or for a tile map the atlas width at this level.
    pub stride: u32,
}

/// The levels of a virtual texture, each holding per virtual texel (for a tile map: per atlas
/// texel) the model texel to shade (see the module docs).
#[derive(Clone, Debug, PartialEq, Eq, Default)]
pub struct MipChain {
    /// Level 0 first.
    pub levels: Vec<Level>,
    /// Model texel ids of every level.
    pub ids: Vec<u32>,
    /// Tile side of a tile map at level 0 (0: none).
    pub tile: u32,
    /// Layout columns and rows of a tile map.
    pub layout: (u32, u32),
    /// The tile map's layout entries (`row << 16 | col` per cell; empty without tiles). The GPU
    /// reads them from the map buffer, where the tile map already put them.
    pub layout_cells: Vec<u32>,
}

/// Where the level-0 ids come from.
#[derive(Debug)]
pub enum Source<'a> {
    /// The sample itself, `(height, width)`.
    Sample(usize, usize),
    /// A coordinate map `(width, height, entries x | y << 16)` into a sample of `width_s` columns.
    Coords(usize, usize, &'a [u32], usize),
    /// A tile map.
    Tiles(&'a crate::tilemap::TileMap<'a>),
}

impl MipChain {
    /// Build the chain of `source` from per-model-texel signatures `sig` (`k` floats per texel).
    /// Errors: a signature array of the wrong length ("filter").
    pub fn build(source: Source<'_>, sig: &[f32], k: usize, texels: usize) -> Result<MipChain> {
        if k == 0 || sig.len() != texels * k {
            return Err(Error::arg(
                "filter",
                format!("expected {k} signature values per texel for {texels} texels, got {}", sig.len()),
            ));
        }
        // Level 0: ids, and the row stride; the level sizes as functions of the level.
        let mut layout_cells = Vec::new();
        let (ids0, w0, h0, tile, layout) = match source {
            Source::Sample(h, w) => ((0..(w * h) as u32).collect::<Vec<u32>>(), w, h, 0usize, (0u32, 0u32)),
            Source::Coords(mw, mh, map, ws) => {
                (map.iter().map(|&e| (e >> 16) * ws as u32 + (e & 0xffff)).collect(), mw, mh, 0, (0, 0))
            }
            Source::Tiles(t) => {
                layout_cells = t.layout.to_vec();
                (
                    t.atlas.to_vec(),
                    t.atlas_cols * t.tile,
                    t.atlas_rows * t.tile,
                    t.tile,
                    (t.layout_cols as u32, t.layout_rows as u32),
                )
            }
        };
        if let Some(&bad) = ids0.iter().find(|&&i| i as usize >= texels) {
            return Err(Error::arg("filter", format!("texel {bad} is outside the model's {texels} texels")));
        }
        // For a tile map, level sizes follow the tile side (the ids are the atlas's).
        let n_levels = if tile > 0 {
            (0..).take_while(|&l| tile >> l >= 1 && tile % (1 << l) == 0).count()
        } else {
            usize::BITS as usize - w0.max(h0).leading_zeros() as usize
        };
        let mut chain = MipChain { levels: Vec::new(), ids: Vec::new(), tile: tile as u32, layout, layout_cells };
        let virtual_size = |l: usize, w: usize, h: usize| -> (u32, u32) {
            if tile > 0 {
                (layout.0 * (tile >> l) as u32, layout.1 * (tile >> l) as u32)
            } else {
                (w as u32, h as u32)
            }
        };
        let (vw, vh) = virtual_size(0, w0, h0);
        chain.levels.push(Level { width: vw, height: vh, offset: 0, stride: w0 as u32 });
        // Per node of the current level: mean signature and texel count.
        let mut mean: Vec<f32> =
            ids0.iter().flat_map(|&i| sig[i as usize * k..(i as usize + 1) * k].iter().copied()).collect();
        let mut count = vec![1u32; ids0.len()];
        chain.ids.extend_from_slice(&ids0);
        let (mut w, mut h) = (w0, h0);
        let mut ids = ids0;
        for l in 1..n_levels {
            let (nw, nh) = if tile > 0 { (w / 2, h / 2) } else { ((w / 2).max(1), (h / 2).max(1)) };
            let mut nids = vec![0u32; nw * nh];
            let mut nmean = vec![0.0f32; nw * nh * k];
            let mut ncount = vec![0u32; nw * nh];
            for y in 0..nh {
                for x in 0..nw {
                    let children: Vec<usize> = [(0, 0), (1, 0), (0, 1), (1, 1)]
                        .iter()
                        .map(|(dx, dy)| (2 * x + dx, 2 * y + dy))
                        .filter(|&(cx, cy)| cx < w && cy < h)
                        .map(|(cx, cy)| cy * w + cx)
                        .collect();
                    let o = (y * nw + x) * k;
                    let total: u32 = children.iter().map(|&c| count[c]).sum();
                    for &c in &children {
                        let wgt = count[c] as f32 / total as f32;
                        for j in 0..k {
                            nmean[o + j] += wgt * mean[c * k + j];
                        }
                    }
                    // The child medoid whose own texel's signature is nearest the block mean
                    // (ties: the first, so the chain is deterministic).
                    let dist = |c: usize| -> f32 {
                        let t = ids[c] as usize;
                        (0..k).map(|j| (sig[t * k + j] - nmean[o + j]).powi(2)).sum()
                    };
                    let best = children.iter().copied().fold((f32::INFINITY, children[0]), |acc, c| {
                        let d = dist(c);
                        if d < acc.0 {
                            (d, c)
                        } else {
                            acc
                        }
                    });
                    nids[y * nw + x] = ids[best.1];
                    ncount[y * nw + x] = total;
                }
            }
            let (vw, vh) = virtual_size(l, nw, nh);
            chain.levels.push(Level { width: vw, height: vh, offset: chain.ids.len() as u32, stride: nw as u32 });
            chain.ids.extend_from_slice(&nids);
            (w, h, ids, mean, count) = (nw, nh, nids, nmean, ncount);
        }
        Ok(chain)
    }

    /// The chain of `source` over a model of `texels` texels whose coarse levels are *averages*:
    /// every level-L virtual texel gets a new texel id `texels + g`, and `groups[g]` lists the
    /// (texel, weight) pairs it averages (its children one level finer, which may be averages
    /// themselves, weighted by how many level-0 texels they stand for). The caller makes the
    /// model holding them (`btfrs_fit::registry::mip_texels` for models linear in their texel
    /// arrays, a row-extended BTF for the raw data): the exact box-filtered pyramid.
    pub fn build_average(source: Source<'_>, texels: usize) -> Result<(MipChain, Groups)> {
        // The medoid build with a constant signature gives the level structure; the ids of the
        // coarse levels are then replaced by new texels averaging their children.
        let flat = vec![0.0f32; texels];
        let mut chain = MipChain::build(source, &flat, 1, texels)?;
        let mut groups: Vec<Vec<(u32, f32)>> = Vec::new();
        // Rows of level l's id grid (its ids run to the next level's offset).
        let rows = |c: &MipChain, l: usize| -> usize {
            let end = c.levels.get(l + 1).map_or(c.ids.len() as u32, |n| n.offset);
            (end - c.levels[l].offset) as usize / c.levels[l].stride as usize
        };
        let mut counts: Vec<u32> = vec![1; chain.levels[0].stride as usize * rows(&chain, 0)];
        for l in 1..chain.levels.len() {
            let (prev, cur) = (chain.levels[l - 1], chain.levels[l]);
            let (pw, ph) = (prev.stride as usize, rows(&chain, l - 1));
            let (cw, ch) = (cur.stride as usize, rows(&chain, l));
            let mut next_counts = vec![0u32; cw * ch];
            for y in 0..ch {
                for x in 0..cw {
                    let kids: Vec<usize> = [(0, 0), (1, 0), (0, 1), (1, 1)]
                        .iter()
                        .map(|(dx, dy)| (2 * x + dx, 2 * y + dy))
                        .filter(|&(cx, cy)| cx < pw && cy < ph)
                        .map(|(cx, cy)| cy * pw + cx)
                        .collect();
                    let total: u32 = kids.iter().map(|&k| counts[k]).sum();
                    let group = kids
                        .iter()
                        .map(|&k| (chain.ids[prev.offset as usize + k], counts[k] as f32 / total as f32))
                        .collect();
                    chain.ids[cur.offset as usize + y * cw + x] = (texels + groups.len()) as u32;
                    groups.push(group);
                    next_counts[y * cw + x] = total;
                }
            }
            counts = next_counts;
        }
        Ok((chain, groups))
    }

    /// The model texel of virtual texel (x, y) of `level` (in range).
    pub fn texel(&self, level: usize, x: u32, y: u32) -> u32 {
        let lv = self.levels[level];
        if self.tile > 0 {
            let tl = self.tile >> level;
            let e = self.layout_entry((y / tl) * self.layout.0 + x / tl);
            let ax = (e & 0xffff) * tl + x % tl;
            let ay = (e >> 16) * tl + y % tl;
            return self.ids[(lv.offset + ay * lv.stride + ax) as usize];
        }
        self.ids[(lv.offset + y * lv.stride + x) as usize]
    }

    fn layout_entry(&self, cell: u32) -> u32 {
        self.layout_cells[cell as usize]
    }

    /// The GPU form, appended to the map buffer at word `base`: per level `(width, height,
    /// base + offset, stride)`, then the ids. `g.lookup.z` holds `base`.
    pub fn gpu_words(&self, base: u32) -> Vec<u32> {
        let table = 4 * self.levels.len() as u32;
        let mut out = Vec::with_capacity(table as usize + self.ids.len());
        for l in &self.levels {
            out.extend([l.width, l.height, base + table + l.offset, l.stride]);
        }
        out.extend_from_slice(&self.ids);
        out
    }
}

/// Up to eight (texel, weight) taps of one filtered lookup.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Taps {
    /// Taps in use.
    pub n: usize,
    /// Model texels.
    pub texel: [u32; 8],
    /// Weights (sum 1).
    pub weight: [f32; 8],
}

/// `bilinear` of common.wgsl: the four taps of `level` at the texture position `f` (the
/// fractional part of uv x uv_scale), weights scaled by `scale`, appended to `taps`.
fn bilinear(chain: &MipChain, level: usize, f: [f32; 2], scale: f32, taps: &mut Taps) {
    let lv = chain.levels[level];
    let (w, h) = (lv.width, lv.height);
    let px = f[0] * w as f32 - 0.5;
    let py = (1.0 - f[1]) * h as f32 - 0.5;
    let (x0f, y0f) = (px.floor(), py.floor());
    let (fx, fy) = (px - x0f, py - y0f);
    let wrap = |v: i32, n: u32| -> u32 { v.rem_euclid(n as i32) as u32 };
    let (x0, y0) = (wrap(x0f as i32, w), wrap(y0f as i32, h));
    let (x1, y1) = ((x0 + 1) % w, (y0 + 1) % h);
    for (x, y, wt) in
        [(x0, y0, (1.0 - fx) * (1.0 - fy)), (x1, y0, fx * (1.0 - fy)), (x0, y1, (1.0 - fx) * fy), (x1, y1, fx * fy)]
    {
        taps.texel[taps.n] = chain.texel(level, x, y);
        taps.weight[taps.n] = wt * scale;
        taps.n += 1;
    }
}

/// The mip level `lambda` for the fine derivatives `duv_dx`, `duv_dy` of the texture coordinate
/// (`lod` of common.wgsl): log2 of the longer screen axis's footprint in level-0 texels.
pub fn lod(chain: &MipChain, duv_dx: [f32; 2], duv_dy: [f32; 2], uv_scale: [f32; 2]) -> f32 {
    let lv = chain.levels[0];
    let s = [uv_scale[0] * lv.width as f32, uv_scale[1] * lv.height as f32];
    let len = |d: [f32; 2]| ((d[0] * s[0]).powi(2) + (d[1] * s[1]).powi(2)).sqrt();
    len(duv_dx).max(len(duv_dy)).max(1e-30).log2()
}

/// The taps of a filtered lookup (`texel_taps` of common.wgsl).
pub fn taps(
    chain: &MipChain,
    filter: Filter,
    uv: [f32; 2],
    duv_dx: [f32; 2],
    duv_dy: [f32; 2],
    uv_scale: [f32; 2],
) -> Taps {
    let s = [uv[0] * uv_scale[0], uv[1] * uv_scale[1]];
    let f = [s[0] - s[0].floor(), s[1] - s[1].floor()];
    let mut t = Taps::default();
    if filter == Filter::Bilinear {
        bilinear(chain, 0, f, 1.0, &mut t);
        return t;
    }
    let top = (chain.levels.len() - 1) as f32;
    let lambda = lod(chain, duv_dx, duv_dy, uv_scale).clamp(0.0, top);
    let l0 = lambda.floor();
    let frac = lambda - l0;
    bilinear(chain, l0 as usize, f, 1.0 - frac, &mut t);
    if frac > 0.0 {
        bilinear(chain, l0 as usize + 1, f, frac, &mut t);
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn medoids_are_the_texels_nearest_the_block_mean() {
        // A 4 x 4 sample, signature = one value per texel: level 1 picks per 2 x 2 block the
        // texel closest to the block's mean, level 2 the one of those closest to the total mean.
        let sig: Vec<f32> = vec![0., 1., 5., 9., 3., 10., 6., 6., 2., 2., 0., 4., 2., 7., 1., 1.];
        let c = MipChain::build(Source::Sample(4, 4), &sig, 1, 16).unwrap();
        assert_eq!(c.levels.len(), 3);
        assert_eq!(c.levels.iter().map(|l| (l.width, l.height)).collect::<Vec<_>>(), [(4, 4), (2, 2), (1, 1)]);
        // Block (0,0): texels 0, 1, 4, 5 = 0, 1, 3, 10, mean 3.5 -> texel 4 (3).
        assert_eq!(c.texel(1, 0, 0), 4);
        // Block (1,0): 5, 9, 6, 6, mean 6.5 -> texel 6 (6, the first of the two sixes).
        assert_eq!(c.texel(1, 1, 0), 6);
        // Total mean 59 / 16 = 3.6875; medoids 3 (texel 4), 6, and those of the lower blocks:
        // (2, 2, 2, 7) mean 3.25 -> texel 8 (2); (0, 4, 1, 1) mean 1.5 -> texel 14 (1).
        assert_eq!(c.texel(1, 0, 1), 8);
        assert_eq!(c.texel(1, 1, 1), 14);
        assert_eq!(c.texel(2, 0, 0), 4);
    }

    #[test]
    fn bilinear_weights_and_wrapping() {
        let sig: Vec<f32> = (0..12).map(|i| i as f32).collect();
        let c = MipChain::build(Source::Sample(3, 4), &sig, 1, 12).unwrap();
        // At a texel centre: that texel alone (weight 1 on tap 0).
        let uv = [(1.5 / 4.0) as f32, 1.0 - (2.5 / 3.0) as f32];
        let t = taps(&c, Filter::Bilinear, uv, [0.0; 2], [0.0; 2], [1.0, 1.0]);
        assert_eq!(t.n, 4);
        assert_eq!(t.texel[0], 2 * 4 + 1);
        assert!((t.weight[0] - 1.0).abs() < 1e-5, "{t:?}");
        // At the left edge, halfway between columns 3 (wrapped) and 0.
        let t = taps(&c, Filter::Bilinear, [0.0, 1.0 - (0.5 / 3.0) as f32], [0.0; 2], [0.0; 2], [1.0, 1.0]);
        assert_eq!((t.texel[0], t.texel[1]), (3, 0));
        assert!((t.weight[0] - 0.5).abs() < 1e-5 && (t.weight[1] - 0.5).abs() < 1e-5);
        assert!((t.weight.iter().sum::<f32>() - 1.0).abs() < 1e-6);
    }

    #[test]
    fn trilinear_picks_levels_by_footprint() {
        let sig: Vec<f32> = (0..64).map(|i| (i * 7 % 11) as f32).collect();
        let c = MipChain::build(Source::Sample(8, 8), &sig, 1, 64).unwrap();
        // One texel per pixel: level 0 only; four: level 2 exactly; six: between 2 and 3.
        for (texels, expect) in [(1.0f32, 0.0f32), (4.0, 2.0), (6.0, 6f32.log2())] {
            let d = texels / 8.0;
            assert!((lod(&c, [d, 0.0], [0.0, d * 0.5], [1.0, 1.0]) - expect).abs() < 1e-5);
        }
        let t = taps(&c, Filter::Trilinear, [0.3, 0.6], [6.0 / 8.0, 0.0], [0.0; 2], [1.0, 1.0]);
        assert_eq!(t.n, 8);
        assert!((t.weight.iter().sum::<f32>() - 1.0).abs() < 1e-5);
        // Beyond the coarsest level: that level alone.
        let t = taps(&c, Filter::Trilinear, [0.3, 0.6], [100.0, 0.0], [0.0; 2], [1.0, 1.0]);
        assert_eq!(t.n, 4);
    }

    #[test]
    fn tile_maps_filter_within_their_layout() {
        // Two 2 x 2 atlas tiles (texels 0-3 and 4-7), layout [tile 1, tile 0]: level 0 reads the
        // atlas through the layout; level 1 (1 x 1 tiles) holds one medoid per tile.
        let atlas = [0u32, 1, 4, 5, 2, 3, 6, 7];
        let layout = [1u32, 0];
        let t = crate::tilemap::TileMap {
            tile: 2,
            atlas_cols: 2,
            atlas_rows: 1,
            atlas: &atlas,
            layout_cols: 2,
            layout_rows: 1,
            layout: &layout,
        };
        let sig: Vec<f32> = vec![0., 0., 1., 1., 5., 6., 6., 9.];
        let c = MipChain::build(Source::Tiles(&t), &sig, 1, 8).unwrap();
        assert_eq!(c.levels.len(), 2);
        assert_eq!((c.levels[0].width, c.levels[0].height), (4, 2));
        // Virtual texel (0, 0) is in cell 0, which shows atlas tile 1: atlas (2, 0) = texel 4.
        assert_eq!(c.texel(0, 0, 0), 4);
        assert_eq!(c.texel(0, 3, 1), 3);
        // Level 1: cell 0 = tile 1's medoid: texels 4, 5, 6, 7 = 5, 6, 6, 9, mean 6.5 -> 5 (6).
        assert_eq!(c.texel(1, 0, 0), 5);
        // Tile 0: 0, 0, 1, 1, mean 0.5: all equally near, the first child wins (texel 0).
        assert_eq!(c.texel(1, 1, 0), 0);
    }

    #[test]
    fn bad_input() {
        assert!(Filter::parse("cubic").is_err());
        assert!(MipChain::build(Source::Sample(2, 2), &[0.0; 3], 1, 4).is_err());
        assert!(MipChain::build(Source::Coords(1, 1, &[5], 2), &[0.0; 4], 1, 4).is_err());
    }
}
