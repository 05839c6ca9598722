//! What a model must provide to be drawn: its shader and its data, laid out for that shader.
//!
//! Adding a model = a WGSL file in `shaders_wgsl/` (defining `ViewQuery`, `view_query`,
//! `eval_model`), a [`Shader`] variant naming it, and a [`GpuModel`] impl that lists the arrays
//! and the parameter words the shader reads. The CPU reference needs nothing more: it uses the
//! model's own [`ReflectanceModel`] evaluation.

use btfrs_fit::{Ptm, PtmKind, RawModel, ReflectanceModel, Srf};
use std::borrow::Cow;

/// The model shaders.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Shader {
    /// `raw.wgsl`
    Raw,
    /// `ptm.wgsl`
    Ptm,
    /// `srf.wgsl`
    Srf,
    /// `lafortune.wgsl`
    Lafortune,
    /// `sh.wgsl`
    Sh,
    /// `lpca_9tap.wgsl`
    Lpca9,
    /// `lpca_3d.wgsl`
    Lpca3d,
    /// A model shader given as source (tests and experiments; the pipeline is cached per source).
    Custom(&'static str),
}

impl Shader {
    /// The file name without extension.
    pub fn name(self) -> &'static str {
        match self {
            Shader::Raw => "raw",
            Shader::Ptm => "ptm",
            Shader::Srf => "srf",
            Shader::Lafortune => "lafortune",
            Shader::Sh => "sh",
            Shader::Lpca9 => "lpca_9tap",
            Shader::Lpca3d => "lpca_3d",
            Shader::Custom(_) => "custom",
        }
    }

    /// The model's WGSL (without `common.wgsl`).
    pub fn source(self) -> &'static str {
        match self {
            Shader::Raw => crate::shaders::RAW,
            Shader::Ptm => crate::shaders::PTM,
            Shader::Srf => crate::shaders::SRF,
            Shader::Lafortune => crate::shaders::LAFORTUNE,
            Shader::Sh => crate::shaders::SH,
            Shader::Lpca9 => crate::shaders::LPCA_9TAP,
            Shader::Lpca3d => crate::shaders::LPCA_3D,
            Shader::Custom(src) => src,
        }
    }
}

/// A model the GPU renderer can draw.
pub trait GpuModel: Sync {
    /// Which shader evaluates it.
    fn shader(&self) -> Shader;
    /// (height, width) of the sample in texels.
    fn dims(&self) -> (usize, usize);
    /// The arrays the shader reads, as 32-bit words (f32 values bit for bit, or packed
    /// integers), in order; they are concatenated into the model store.
    fn gpu_parts(&self) -> Vec<Cow<'_, [u32]>>;
    /// The measured direction sets the shader searches, in order; they are concatenated into
    /// `mdirs` and each gets a candidate table ([`candidate_table`]) in `tables`.
    fn gpu_dir_sets(&self) -> Vec<&[[f64; 3]]>;
    /// The 16 parameter words, given the store offset of each part and the `tables` offset of
    /// each direction set's candidate table.
    fn gpu_params(&self, offsets: &[u32], tables: &[u32]) -> [u32; 16];
    /// An RGBA8 3D texture the shader samples with trilinear filtering (`vol` in common.wgsl).
    fn gpu_volume(&self) -> Option<Volume<'_>> {
        None
    }
}

/// An RGBA8 3D texture: `size` = (width, height, depth), texels x fastest, then y, then z.
#[derive(Debug, Clone, PartialEq)]
pub struct Volume<'a> {
    /// Width, height, depth in texels.
    pub size: [u32; 3],
    /// `4 * width * height * depth` bytes.
    pub texels: Cow<'a, [u8]>,
}

impl Volume<'_> {
    /// Check the size against the data and the device's 3D texture limit.
    pub fn validate(&self, max_dim: u32) -> btfrs_core::Result<()> {
        let n = self.size.iter().map(|&x| x as usize).product::<usize>();
        if self.size.iter().any(|&x| x == 0 || x > max_dim) || self.texels.len() != 4 * n {
            return Err(btfrs_core::Error::Device(format!(
                "a 3D texture of {:?} texels ({} bytes) does not fit the device's limit of {max_dim} per side",
                self.size,
                self.texels.len()
            )));
        }
        Ok(())
    }
}

/// f32 arrays as store words (no copy).
pub fn words(x: &[f32]) -> Cow<'_, [u32]> {
    Cow::Borrowed(bytemuck::cast_slice(x))
}

impl<M: GpuModel + ?Sized> GpuModel for &M {
    fn shader(&self) -> Shader {
        (**self).shader()
    }
    fn dims(&self) -> (usize, usize) {
        (**self).dims()
    }
    fn gpu_parts(&self) -> Vec<Cow<'_, [u32]>> {
        (**self).gpu_parts()
    }
    fn gpu_dir_sets(&self) -> Vec<&[[f64; 3]]> {
        (**self).gpu_dir_sets()
    }
    fn gpu_params(&self, offsets: &[u32], tables: &[u32]) -> [u32; 16] {
        (**self).gpu_params(offsets, tables)
    }
    fn gpu_volume(&self) -> Option<Volume<'_>> {
        (**self).gpu_volume()
    }
}

/// Any model drawn with another shader source: for testing shaders against the CPU reference
/// (a deliberately wrong one must fail) and for measuring parts of a shader.
#[derive(Debug, Clone, Copy)]
pub struct WithShader<'a, M>(pub &'a M, pub &'static str);

impl<M: GpuModel> GpuModel for WithShader<'_, M> {
    fn shader(&self) -> Shader {
        Shader::Custom(self.1)
    }
    fn dims(&self) -> (usize, usize) {
        self.0.dims()
    }
    fn gpu_parts(&self) -> Vec<Cow<'_, [u32]>> {
        self.0.gpu_parts()
    }
    fn gpu_dir_sets(&self) -> Vec<&[[f64; 3]]> {
        self.0.gpu_dir_sets()
    }
    fn gpu_params(&self, offsets: &[u32], tables: &[u32]) -> [u32; 16] {
        self.0.gpu_params(offsets, tables)
    }
    fn gpu_volume(&self) -> Option<Volume<'_>> {
        self.0.gpu_volume()
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

impl GpuModel for Ptm {
    fn shader(&self) -> Shader {
        Shader::Ptm
    }

    fn dims(&self) -> (usize, usize) {
        ReflectanceModel::dims(self)
    }

    fn gpu_parts(&self) -> Vec<Cow<'_, [u32]>> {
        let mut p = vec![words(&self.coeffs)];
        if let Some(rgb) = &self.rgb {
            p.push(words(rgb));
        }
        p
    }

    fn gpu_dir_sets(&self) -> Vec<&[[f64; 3]]> {
        vec![&self.views]
    }

    fn gpu_params(&self, offsets: &[u32], tables: &[u32]) -> [u32; 16] {
        let mut w = [0u32; 16];
        w[2] = tables[0];
        w[0] = match self.kind {
            PtmKind::Rgb => 0,
            PtmKind::Lrgb => 1,
        };
        w[1] = self.views.len() as u32;
        w[3] = offsets[0];
        w[4] = offsets.get(1).copied().unwrap_or(0);
        w
    }
}

impl GpuModel for RawModel<'_> {
    fn shader(&self) -> Shader {
        Shader::Raw
    }

    fn dims(&self) -> (usize, usize) {
        ReflectanceModel::dims(self)
    }

    fn gpu_parts(&self) -> Vec<Cow<'_, [u32]>> {
        vec![words(self.btf().data)]
    }

    fn gpu_dir_sets(&self) -> Vec<&[[f64; 3]]> {
        vec![self.btf().views, self.btf().lights]
    }

    fn gpu_params(&self, offsets: &[u32], tables: &[u32]) -> [u32; 16] {
        let b = self.btf();
        let mut w = [0u32; 16];
        w[0] = b.views.len() as u32;
        w[1] = b.lights.len() as u32;
        w[2] = tables[0];
        w[3] = tables[1];
        w[4] = offsets[0];
        w
    }
}

impl GpuModel for Srf {
    fn shader(&self) -> Shader {
        Shader::Srf
    }

    fn dims(&self) -> (usize, usize) {
        ReflectanceModel::dims(self)
    }

    fn gpu_parts(&self) -> Vec<Cow<'_, [u32]>> {
        let p = &self.phong;
        let material: Vec<u32> = p.kd.iter().chain(&p.ks).chain([&p.n]).map(|&x| (x as f32).to_bits()).collect();
        vec![Cow::Owned(material), words(&self.s)]
    }

    fn gpu_dir_sets(&self) -> Vec<&[[f64; 3]]> {
        Vec::new()
    }

    fn gpu_params(&self, offsets: &[u32], _tables: &[u32]) -> [u32; 16] {
        let mut w = [0u32; 16];
        w[0] = offsets[0];
        w[1] = offsets[1];
        w
    }
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
