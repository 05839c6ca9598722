//! Stochastic Wang tilings (paper 002, section 4.1; Cohen et al. 2003): a `rows x cols` grid of
//! tile ids whose shared edges have matching colours, chosen at random (seeded), optionally
//! wrapping around (a cylinder's seam, a torus) and optionally from a subset of the tiles.
//!
//! With the complete set every colour assignment of the grid's edges is realised by exactly one
//! tile per cell, so the tiling draws the edge colours independently and reads the tiles off:
//! non-periodic, each tile equally likely. With a subset, cells are filled in scan order from
//! the tiles matching their north and west neighbours (and the wrapped edges in the last row and
//! column), backtracking when none fits; a request no arrangement satisfies is an error.

use crate::tiles::{tile_code, tile_id};
use btfrs_core::rng::{mix, Rng};
use btfrs_core::{Error, Result};

/// The largest grid side accepted.
pub const MAX_SIDE: usize = 1 << 15;

/// A valid tiling of `rows x cols` cells (row-major tile ids, row 0 at the top).
///
/// `wrap = (columns, rows)`: whether the last column must match the first (and the last row the
/// first). `allowed`: the tile ids that may be used (None: all `colors^4`).
pub fn tiling(
    colors: usize,
    rows: usize,
    cols: usize,
    seed: u64,
    wrap: (bool, bool),
    allowed: Option<&[usize]>,
) -> Result<Vec<u32>> {
    if !(2..=8).contains(&colors) {
        return Err(Error::arg("colors", format!("expected 2 to 8, got {colors}")));
    }
    for (name, v) in [("rows", rows), ("cols", cols)] {
        if v == 0 || v > MAX_SIDE {
            return Err(Error::arg(name, format!("expected 1..={MAX_SIDE} cells, got {v}")));
        }
    }
    let n = colors.pow(4);
    let mut rng = Rng::new(mix(seed ^ 0x7111e));
    match allowed {
        None => {
            // North/south colours of the horizontal edges, west/east of the vertical ones.
            let hrows = if wrap.1 { rows } else { rows + 1 };
            let vcols = if wrap.0 { cols } else { cols + 1 };
            let hedge: Vec<u8> = (0..hrows * cols).map(|_| rng.below(colors) as u8).collect();
            let vedge: Vec<u8> = (0..rows * vcols).map(|_| rng.below(colors) as u8).collect();
            let mut out = Vec::with_capacity(rows * cols);
            for r in 0..rows {
                for c in 0..cols {
                    let north = hedge[r * cols + c];
                    let south = hedge[((r + 1) % hrows) * cols + c];
                    let west = vedge[r * vcols + c];
                    let east = vedge[r * vcols + (c + 1) % vcols];
                    out.push(tile_id([north, east, south, west], colors) as u32);
                }
            }
            Ok(out)
        }
        Some(ids) => {
            if ids.is_empty() {
                return Err(Error::arg("tiles", "expected at least one allowed tile"));
            }
            if let Some(&bad) = ids.iter().find(|&&i| i >= n) {
                return Err(Error::arg(
                    "tiles",
                    format!("tile {bad} does not exist in a {colors}-colour set of {n} tiles"),
                ));
            }
            let mut ids: Vec<usize> = ids.to_vec();
            ids.sort_unstable();
            ids.dedup();
            backtrack(colors, rows, cols, wrap, &ids, &mut rng)
        }
    }
}

fn backtrack(
    colors: usize,
    rows: usize,
    cols: usize,
    wrap: (bool, bool),
    ids: &[usize],
    rng: &mut Rng,
) -> Result<Vec<u32>> {
    let codes: Vec<[u8; 4]> = ids.iter().map(|&i| tile_code(i, colors)).collect();
    let cells = rows * cols;
    let mut choice: Vec<Vec<usize>> = vec![Vec::new(); cells]; // remaining candidates per cell
    let mut pick = vec![usize::MAX; cells];
    let mut i = 0usize;
    let mut steps = 0usize;
    let limit = 2_000_000usize.max(cells * 64);
    let fits = |pick: &[usize], i: usize, k: usize| {
        let (r, c) = (i / cols, i % cols);
        let t = codes[k];
        if r > 0 && codes[pick[i - cols]][2] != t[0] {
            return false;
        }
        if c > 0 && codes[pick[i - 1]][1] != t[3] {
            return false;
        }
        if wrap.0 && c == cols - 1 && codes[pick[i - c]][3] != t[1] && cols > 1 {
            return false;
        }
        if wrap.0 && cols == 1 && t[1] != t[3] {
            return false;
        }
        if wrap.1 && r == rows - 1 && rows > 1 && codes[pick[c]][0] != t[2] {
            return false;
        }
        if wrap.1 && rows == 1 && t[0] != t[2] {
            return false;
        }
        true
    };
    while i < cells {
        steps += 1;
        if steps > limit {
            return Err(Error::arg(
                "tiles",
                format!("no valid {rows} x {cols} tiling found with these {} tiles within {limit} steps", ids.len()),
            ));
        }
        if pick[i] == usize::MAX {
            let mut cand: Vec<usize> = (0..codes.len()).filter(|&k| fits(&pick, i, k)).collect();
            // Random order (Fisher-Yates), so the tiling is stochastic.
            for j in (1..cand.len()).rev() {
                cand.swap(j, rng.below(j + 1));
            }
            choice[i] = cand;
        }
        if let Some(k) = choice[i].pop() {
            pick[i] = k;
            i += 1;
        } else {
            pick[i] = usize::MAX;
            if i == 0 {
                return Err(Error::arg(
                    "tiles",
                    format!(
                        "no valid {rows} x {cols} tiling{} exists with these {} tiles",
                        if wrap.0 || wrap.1 { " (with wrap-around)" } else { "" },
                        ids.len()
                    ),
                ));
            }
            i -= 1;
        }
    }
    Ok(pick.iter().map(|&k| ids[k] as u32).collect())
}

/// Check a layout: every id a tile of the set, every shared edge matching (and the wrapped
/// edges if asked). The error names the first mismatching cell.
pub fn check(colors: usize, rows: usize, cols: usize, layout: &[u32], wrap: (bool, bool)) -> Result<()> {
    let n = colors.pow(4);
    if layout.len() != rows * cols {
        return Err(Error::arg("layout", format!("expected {rows} x {cols} ids, got {}", layout.len())));
    }
    if let Some(i) = layout.iter().position(|&t| t as usize >= n) {
        return Err(Error::arg(
            "layout",
            format!("cell (row {}, column {}) holds tile {}, but the set has {n} tiles", i / cols, i % cols, layout[i]),
        ));
    }
    let code = |r: usize, c: usize| tile_code(layout[r * cols + c] as usize, colors);
    for r in 0..rows {
        for c in 0..cols {
            let t = code(r, c);
            if c + 1 < cols || wrap.0 {
                let e = code(r, (c + 1) % cols);
                if t[1] != e[3] {
                    return Err(Error::arg(
                        "layout",
                        format!(
                            "cell (row {r}, column {c}): east colour {} meets west colour {} of its right neighbour",
                            t[1], e[3]
                        ),
                    ));
                }
            }
            if r + 1 < rows || wrap.1 {
                let s = code((r + 1) % rows, c);
                if t[2] != s[0] {
                    return Err(Error::arg(
                        "layout",
                        format!("cell (row {r}, column {c}): south colour {} meets north colour {} below", t[2], s[0]),
                    ));
                }
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn complete_set_tilings_are_valid_and_not_periodic() {
        for wrap in [(false, false), (true, false), (true, true)] {
            let t = tiling(2, 32, 32, 1, wrap, None).unwrap();
            check(2, 32, 32, &t, wrap).unwrap();
            // Every tile is used, and no row repeats the first with any period below 8.
            let mut used = [0usize; 16];
            t.iter().for_each(|&i| used[i as usize] += 1);
            assert!(used.iter().all(|&u| u > 20), "{used:?}");
            for p in 1..8 {
                assert!((0..32 - p).any(|c| t[c] != t[c + p]), "period {p}");
            }
        }
        // A different seed, a different tiling.
        assert_ne!(
            tiling(2, 8, 8, 1, (false, false), None).unwrap(),
            tiling(2, 8, 8, 2, (false, false), None).unwrap()
        );
    }

    #[test]
    fn subsets_tile_by_backtracking_or_fail_clearly() {
        // Tiles whose east colour equals their west colour and north equals south: a valid
        // wrapped tiling exists (any such tile repeated); the subset check must find one.
        let ids: Vec<usize> = (0..16)
            .filter(|&i| {
                let c = tile_code(i, 2);
                c[1] == c[3] && c[0] == c[2]
            })
            .collect();
        let t = tiling(2, 6, 5, 3, (true, true), Some(&ids)).unwrap();
        check(2, 6, 5, &t, (true, true)).unwrap();
        // One tile with east 1 and west 0 cannot tile a row of two.
        let bad = [tile_id([0, 1, 0, 0], 2)];
        let e = tiling(2, 1, 2, 0, (false, false), Some(&bad)).unwrap_err().to_string();
        assert!(e.contains("no valid 1 x 2 tiling"), "{e}");
        assert!(tiling(2, 0, 4, 0, (false, false), None).unwrap_err().to_string().contains("rows"));
        assert!(tiling(2, 2, 2, 0, (false, false), Some(&[16])).unwrap_err().to_string().contains("does not exist"));
    }

    #[test]
    fn check_names_the_mismatch() {
        let mut t = tiling(2, 4, 4, 5, (false, false), None).unwrap();
        t[5] ^= 1; // flip the west colour of cell (1, 1)
        let e = check(2, 4, 4, &t, (false, false)).unwrap_err().to_string();
        assert!(e.contains("row 1, column 0"), "{e}");
    }
}
