//! The model side of the renderer: the GPU contract every model implements lives with the models
//! (`btfrs_fit::gpu`: [`GpuModel`], [`Shader`], [`Volume`], parameter structs); this module adds
//! what the renderer derives from it: the candidate tables of measured direction sets, and
//! [`WithShader`] to draw a model with another shader source.

pub use btfrs_fit::gpu::{GpuModel, Shader, Volume, PARAM_WORDS};
use btfrs_fit::Shade;
use std::borrow::Cow;

/// Any model drawn with another shader source: for testing shaders against the CPU reference
/// (a deliberately wrong one must fail) and for measuring parts of a shader. The pipeline is
/// cached per source.
#[derive(Debug, Clone, Copy)]
pub struct WithShader<'a, M: ?Sized>(pub &'a M, pub &'static str);

impl<M: GpuModel + ?Sized> GpuModel for WithShader<'_, M> {
    fn shader(&self) -> Shader {
        Shader { name: "custom", source: self.1, params: self.0.shader().params }
    }
    fn gpu_dims(&self) -> (usize, usize) {
        self.0.gpu_dims()
    }
    fn gpu_parts(&self) -> Vec<Cow<'_, [u32]>> {
        self.0.gpu_parts()
    }
    fn gpu_dir_sets(&self) -> Vec<&[[f64; 3]]> {
        self.0.gpu_dir_sets()
    }
    fn gpu_params(&self, offsets: &[u32], tables: &[u32]) -> [u32; PARAM_WORDS] {
        self.0.gpu_params(offsets, tables)
    }
    fn gpu_constants(&self) -> Vec<u32> {
        self.0.gpu_constants()
    }
    fn gpu_constants_len(&self) -> usize {
        self.0.gpu_constants_len()
    }
    fn gpu_volume(&self) -> Option<Volume<'_>> {
        self.0.gpu_volume()
    }
}

impl<M: Shade + ?Sized> Shade for WithShader<'_, M> {
    fn shade_dims(&self) -> (usize, usize) {
        self.0.shade_dims()
    }
    fn shade(&self, t: usize, view: [f64; 3], light: [f64; 3]) -> [f32; 3] {
        self.0.shade(t, view, light)
    }
}

/// Cells per side of the candidate tables.
pub const TABLE_GRID: usize = 32;

/// For a direction set, the candidates of each cell of a `grid x grid` partition of the
/// concentric-map square (paper 004, section 6.1): every direction that can be among the four
/// nearest of *some* point of the cell. Layout: `[grid, offsets[grid^2 + 1], indices...]`,
/// offsets relative to the index list, cells row-major with t (the square's second coordinate)
/// as the row, indices ascending so ties resolve to the lower index as the brute-force sort does.
///
/// Why it is exact: let c be the cell's centre direction and r bound the angle from c to any
/// point of the cell (the largest over a dense sampling of the cell's boundary, plus a margin:
/// on the sphere the distance from c has no interior maximum). For q in the cell, the four
/// directions nearest to c lie within d4(c) + r of q, so q's four nearest lie within that too,
/// hence within d4(c) + 2r of c: the list `{ j : angle(j, c) <= d4(c) + 2r }` contains them.
pub fn candidate_table(dirs: &[[f64; 3]], grid: usize) -> Vec<u32> {
    use btfrs_core::directions::angle_between;
    use btfrs_hemimap::square_to_hemisphere;
    let mut offsets = Vec::with_capacity(grid * grid + 1);
    let mut list = Vec::new();
    offsets.push(0u32);
    for cy in 0..grid {
        for cx in 0..grid {
            let at =
                |fx: f64, fy: f64| square_to_hemisphere((cx as f64 + fx) / grid as f64, (cy as f64 + fy) / grid as f64);
            let c = at(0.5, 0.5);
            let mut r = 0.0f64;
            for k in 0..=16 {
                let f = k as f64 / 16.0;
                for p in [at(f, 0.0), at(f, 1.0), at(0.0, f), at(1.0, f)] {
                    r = r.max(angle_between(c, p));
                }
            }
            // Margin: the boundary sampling's gaps, and f32 rounding on the GPU near cell edges.
            let r = r * 1.05 + 1e-3;
            let mut d: Vec<f64> = dirs.iter().map(|&j| angle_between(j, c)).collect();
            let mut sorted = d.clone();
            sorted.sort_by(f64::total_cmp);
            let d4 = sorted.get(3).or(sorted.last()).copied().unwrap_or(0.0);
            for (j, dj) in d.iter_mut().enumerate() {
                if *dj <= d4 + 2.0 * r {
                    list.push(j as u32);
                }
            }
            offsets.push(list.len() as u32);
        }
    }
    let mut out = Vec::with_capacity(1 + offsets.len() + list.len());
    out.push(grid as u32);
    out.extend(offsets);
    out.extend(list);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use btfrs_core::directions::{interp_weights, ubo81};
    use btfrs_core::rng::Rng;

    #[test]
    fn candidate_tables_hold_the_four_nearest_of_every_query() {
        // Random queries, each looked up in its cell: the brute-force four nearest must all be
        // listed there, for the UBO set and for an irregular one.
        let mut rng = Rng::new(9);
        let irregular: Vec<[f64; 3]> =
            (0..40).map(|_| btfrs_hemimap::square_to_hemisphere(rng.next_f64(), rng.next_f64())).collect();
        for dirs in [ubo81(), irregular] {
            let t = candidate_table(&dirs, TABLE_GRID);
            let g = t[0] as usize;
            let mut total = 0usize;
            for _ in 0..20000 {
                let (s, u) = (rng.next_f64(), rng.next_f64());
                let q = btfrs_hemimap::square_to_hemisphere(s, u);
                let cell = ((u * g as f64) as usize).min(g - 1) * g + ((s * g as f64) as usize).min(g - 1);
                let (a, b) = (t[1 + cell] as usize, t[2 + cell] as usize);
                let list = &t[2 + g * g + a..2 + g * g + b];
                total += list.len();
                let mut near: Vec<(usize, f64)> =
                    dirs.iter().enumerate().map(|(i, &d)| (i, btfrs_core::directions::angle_between(d, q))).collect();
                near.sort_by(|x, y| x.1.total_cmp(&y.1));
                for &(i, _) in &near[..4] {
                    assert!(list.contains(&(i as u32)), "direction {i} missing from cell {cell}");
                }
                // The weights only ever use the three nearest.
                assert!(interp_weights(&dirs, q, 3).iter().all(|(i, _)| list.contains(&(*i as u32))));
            }
            // And the table is worth having: far fewer candidates than directions.
            let mean = total as f64 / 20000.0;
            assert!(mean < dirs.len() as f64 / 3.0, "{mean} candidates on average of {}", dirs.len());
        }
    }
}
