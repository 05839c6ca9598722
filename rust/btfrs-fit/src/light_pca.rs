//! What the RBF ([`crate::rbf`]) and bilinear ([`crate::bilinear`]) light bases share: per view
//! slot, each texel's values under the slot's measured lights are *resampled* onto a regular grid
//! of light directions by a linear operator (the one thing the two models differ in), the
//! resampled functions of all texels are compressed by PCA into a few coefficient planes, and
//! the planes are stored 8-bit with a scale and a bias per plane ([`crate::planes`]) next to a
//! float table of the principal functions on the grid. This is how relight (the RTI fitter of
//! Ponchio et al.) stores its RBF and bilinear bases, so `nbytes` is what a viewer holds.
//!
//! **The grid.** `resolution` `n`: `n x n` nodes on the concentric square of
//! [`btfrs_hemimap`] (node `(i, j)` at square point `(i / (n - 1), j / (n - 1))`, direction
//! `square_to_hemisphere` of it; index `j n + i`). A light is looked up by bilinear
//! interpolation between the four nodes around its square point (`hemisphere_to_square`, which
//! the shaders have in `common.wgsl`). The map is equal-area, so the nodes are spread evenly over
//! the hemisphere; the square's boundary is the horizon.
//!
//! **The PCA.** Per slot the resampled functions are grouped by [`Colour`]:
//!
//! * `rgb` (*joint RGB*): one vector of `3 G` values per texel (`G = n^2`, channel-major),
//!   `components` principal directions; each component is an RGB function on the grid;
//! * `ycc` (*luminance/chroma split*, as relight's YCC): `Y = (r + g + b) / 3`, `Cb = b - Y`,
//!   `Cr = r - Y`; the `G` luminance values get `components` principal directions, the `2 G`
//!   chroma values (Cb, Cr jointly) `chroma_components`. Back to RGB: `r = Y + Cr`,
//!   `g = Y - Cb - Cr`, `b = Y + Cb`.
//!
//! The PCA is centred (the mean function is a row of the table). It is exact (the `f64`
//! eigenvectors of the covariance, or of the Gram matrix when there are fewer texels than values)
//! when the vectors have at most [`EXACT_PCA_DIM`] values, the randomized subspace iteration of
//! [`btfrs_numerics::rpca`] above. When the data have fewer directions
//! than asked for (fewer texels than components, or a constant slot), the missing components
//! are zero functions with zero coefficients: every slot has the same number of planes.
//!
//! **Two passes.** The exact PCA needs only each slot's mean and covariance, and those follow
//! from the mean and covariance of the texels' samples, which texel blocks sum apart
//! ([`staged`]). So the fit reads the data in two passes over blocks of texels in storage order
//! (the moments, then the coefficients) instead of slot by slot: a memory-mapped BTF larger than
//! memory is read twice, not once per view slot. Slot by slot remain the fits whose eigenproblem
//! (`min(d, 3 m)` rows for `m` lights, [`exact_dim`]) exceeds [`EXACT_PCA_DIM`] (the randomized
//! PCA) and those of fewer texels than its rows (one slot's Gram matrix is then smaller).
//!
//! **Storage.** Coefficients `[texel][slot][K]` (`K = components + chroma_components`) as one
//! [`Planes`] (`coeffs_q`, `coeffs_scale`, `coeffs_bias`: a scale and bias per slot and
//! component); the table `[slot][node][R]` f32, row `R = 3 + w components (+ 2 chroma)` with `w`
//! 3 (rgb) or 1 (ycc): the three mean values (r, g, b or Y, Cb, Cr), then each component's
//! values at the node. The table is counted in `nbytes` (it is what the shader reads).
//!
//! **Evaluation** at (view, light): the three nearest view slots are blended as the PTM does;
//! per slot, the table rows of the light's four grid nodes are interpolated bilinearly
//! (per query, not per texel), then each channel is the interpolated mean plus one dot product of
//! the texel's decoded coefficients with the interpolated component values.

use crate::gpu::{words, Shader};
use crate::planes::Planes;
use btfrs_core::arrays::{check_finite, ArrayData};
use btfrs_core::btf::TexelScan;
use btfrs_core::{directions, ensure_arg, BtfRef, Error, Monitor, NamedArrays, Result};
use btfrs_numerics::dense::{gemm, view};
use nalgebra::DMatrix;
use rayon::prelude::*;
use std::borrow::Cow;

pub mod staged;

/// Largest grid resolution (nodes per side).
pub const MAX_RESOLUTION: usize = 32;
/// Largest number of planes per slot (luminance/RGB plus chroma).
pub const MAX_COMPONENTS: usize = 64;
/// A view slot with fewer present lights borrows those of the nearest views (see [`PooledSlot`]).
pub const MIN_LIGHTS: usize = 6;
/// Vectors of at most this many values get the exact PCA; longer ones the randomized one.
pub const EXACT_PCA_DIM: usize = 768;

/// How the colour channels are compressed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Colour {
    /// One PCA of the three channels together.
    Rgb,
    /// A PCA of the luminance and one of the two chroma differences.
    Ycc,
}

/// The options both models share (checked by [`PcaOptions::check`]).
#[derive(Debug, Clone, Copy)]
pub struct PcaOptions {
    /// Grid nodes per side.
    pub resolution: usize,
    /// Principal components (rgb) or luminance components (ycc).
    pub components: usize,
    /// Chroma components (ycc only; `None`: `max(1, components / 4)`).
    pub chroma_components: Option<usize>,
    /// The colour grouping.
    pub colour: Colour,
    /// Seed of the randomized PCA (long vectors only).
    pub seed: u64,
}

impl PcaOptions {
    /// Check the options; the number of chroma components in use.
    pub fn check(&self) -> Result<usize> {
        ensure_arg!(
            (2..=MAX_RESOLUTION).contains(&self.resolution),
            "resolution",
            "expected 2 to {MAX_RESOLUTION} grid nodes per side, got {}",
            self.resolution
        );
        ensure_arg!(
            (1..=MAX_COMPONENTS).contains(&self.components),
            "components",
            "expected 1 to {MAX_COMPONENTS} components, got {}",
            self.components
        );
        let kc = match (self.colour, self.chroma_components) {
            (Colour::Rgb, None | Some(0)) => 0,
            (Colour::Rgb, Some(k)) => {
                return Err(Error::arg(
                    "chroma_components",
                    format!("only colour=\"ycc\" has chroma components (got {k} with colour=\"rgb\")"),
                ))
            }
            (Colour::Ycc, None) => (self.components / 4).max(1),
            (Colour::Ycc, Some(k)) => k,
        };
        ensure_arg!(
            self.components + kc <= MAX_COMPONENTS,
            "chroma_components",
            "expected at most {MAX_COMPONENTS} planes in all, got {} + {kc}",
            self.components
        );
        Ok(kc)
    }
}

/// The grid's node directions (`n^2`, index `j n + i`).
pub fn grid_directions(n: usize) -> Vec<[f64; 3]> {
    let d = (n - 1) as f64;
    (0..n * n).map(|k| btfrs_hemimap::square_to_hemisphere((k % n) as f64 / d, (k / n) as f64 / d)).collect()
}

/// The four grid nodes around light `l` and their bilinear weights (summing to 1).
pub fn grid_weights(n: usize, l: [f64; 3]) -> [(usize, f64); 4] {
    let [s, t] = btfrs_hemimap::hemisphere_to_square(l);
    let d = (n - 1) as f64;
    let cell = |x: f64| {
        let x = (x * d).clamp(0.0, d);
        let i = (x.floor() as usize).min(n - 2);
        (i, x - i as f64)
    };
    let ((i, fx), (j, fy)) = (cell(s), cell(t));
    [
        (j * n + i, (1.0 - fx) * (1.0 - fy)),
        (j * n + i + 1, fx * (1.0 - fy)),
        ((j + 1) * n + i, (1.0 - fx) * fy),
        ((j + 1) * n + i + 1, fx * fy),
    ]
}

/// A view slot fitted from its lights pooled with those of the nearest views: a slot with fewer
/// than [`MIN_LIGHTS`] present lights (sparse or decimated sampling of a multi-view BTF) borrows
/// the samples of the nearest views (by angle), which see nearly the same reflectance field,
/// until it has that many. A single-view capture keeps its own lights however few (one light
/// gives the constant).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct PooledSlot {
    /// The view slot index.
    pub slot: usize,
    /// Its own present lights.
    pub lights: usize,
    /// The slots whose lights were pooled in, nearest first.
    pub from: Vec<usize>,
}

/// A fitted light basis: the model behind [`crate::rbf::Rbf`] and [`crate::bilinear::Bilinear`].
#[derive(Debug, Clone, PartialEq)]
pub struct LightPca {
    /// Rows.
    pub height: usize,
    /// Columns.
    pub width: usize,
    /// The view direction of each slot.
    pub views: Vec<[f64; 3]>,
    /// Grid nodes per side.
    pub resolution: usize,
    /// The colour grouping.
    pub colour: Colour,
    /// RGB or luminance components per slot.
    pub k_main: usize,
    /// Chroma components per slot (0 for rgb).
    pub k_chroma: usize,
    /// `[texel][slot][K]` coefficients, 8-bit with per-plane scale and bias.
    pub planes: Planes,
    /// `[slot][node][R]` f32 (see the module doc).
    pub table: Vec<f32>,
    /// The slots fitted from pooled lights (empty for a loaded model: files do not record it).
    pub pooled: Vec<PooledSlot>,
    /// The slots whose resampling fell back to a more stable operator (empty when loaded).
    pub fallback_slots: Vec<FallbackSlot>,
}

/// A prepared query: per blended slot, its weight and the table row interpolated at the light.
#[derive(Debug, Clone)]
pub struct LightPcaQuery {
    slots: Vec<(usize, f32, Vec<f32>)>,
}

impl LightPca {
    /// Planes per slot.
    pub fn k(&self) -> usize {
        self.k_main + self.k_chroma
    }

    /// Values per table row.
    pub fn stride(&self) -> usize {
        3 + self.k_main * if self.colour == Colour::Rgb { 3 } else { 1 } + 2 * self.k_chroma
    }

    /// Check that the parts agree (for models built from loaded files).
    pub fn validate(&self) -> Result<()> {
        let (t, nv, g) = (self.height * self.width, self.views.len(), self.resolution * self.resolution);
        ensure_arg!(t > 0, "coeffs_q", "the model has no texels");
        directions::validate("views", &self.views)?;
        ensure_arg!(
            (2..=MAX_RESOLUTION).contains(&self.resolution),
            "table",
            "expected 2 to {MAX_RESOLUTION} grid nodes per side, got {}",
            self.resolution
        );
        ensure_arg!(
            self.k_main >= 1 && self.k() <= MAX_COMPONENTS && (self.colour == Colour::Ycc || self.k_chroma == 0),
            "layout",
            "expected 1 to {MAX_COMPONENTS} planes per slot (chroma only for ycc), got {} + {}",
            self.k_main,
            self.k_chroma
        );
        ensure_arg!(
            self.planes.texels == t && self.planes.k == nv * self.k() && self.planes.q.len() == t * nv * self.k(),
            "coeffs_q",
            "expected {t} texels x {} planes",
            nv * self.k()
        );
        ensure_arg!(
            self.table.len() == nv * g * self.stride(),
            "table",
            "expected {nv} x {g} x {} values, got {}",
            self.stride(),
            self.table.len()
        );
        check_finite("table", &self.table)?;
        Ok(())
    }

    /// The table row of slot `v` interpolated at light `l`.
    pub fn row_at(&self, v: usize, l: [f64; 3]) -> Vec<f32> {
        let (g, r) = (self.resolution * self.resolution, self.stride());
        let mut row = vec![0.0f32; r];
        for (node, w) in grid_weights(self.resolution, l) {
            let src = &self.table[(v * g + node) * r..(v * g + node + 1) * r];
            for (o, &x) in row.iter_mut().zip(src) {
                *o += w as f32 * x;
            }
        }
        row
    }

    /// The model's value at texel `t` and slot `v` given the slot's interpolated table row.
    #[inline]
    pub fn eval_slot(&self, t: usize, v: usize, row: &[f32]) -> [f32; 3] {
        let k = self.k();
        let base = v * k;
        let mut acc = [row[0], row[1], row[2]];
        match self.colour {
            Colour::Rgb => {
                for p in 0..k {
                    let c = self.planes.get(t, base + p);
                    for ch in 0..3 {
                        acc[ch] += c * row[3 + 3 * p + ch];
                    }
                }
                acc
            }
            Colour::Ycc => {
                let km = self.k_main;
                for p in 0..km {
                    acc[0] += self.planes.get(t, base + p) * row[3 + p];
                }
                for p in 0..self.k_chroma {
                    let c = self.planes.get(t, base + km + p);
                    acc[1] += c * row[3 + km + 2 * p];
                    acc[2] += c * row[3 + km + 2 * p + 1];
                }
                let [y, cb, cr] = acc;
                [y + cr, y - cb - cr, y + cb]
            }
        }
    }

    /// Prepare a query (see the module doc).
    pub fn query(&self, view: [f64; 3], light: [f64; 3]) -> LightPcaQuery {
        let slots = directions::interp_weights(&self.views, view, 3)
            .into_iter()
            .map(|(v, w)| (v, w as f32, self.row_at(v, light)))
            .collect();
        LightPcaQuery { slots }
    }

    /// Evaluate a prepared query at texel `t`.
    #[inline]
    pub fn eval(&self, t: usize, q: &LightPcaQuery) -> [f32; 3] {
        let mut out = [0.0f32; 3];
        for (v, w, row) in &q.slots {
            let x = self.eval_slot(t, *v, row);
            for c in 0..3 {
                out[c] += w * x[c];
            }
        }
        out
    }

    /// The GPU store: the coefficient bytes, scale then bias, the table.
    pub fn parts(&self) -> Vec<Cow<'_, [u32]>> {
        vec![Cow::Owned(self.planes.words()), Cow::Owned(self.planes.scale_bias_words()), words(&self.table)]
    }

    /// The shader's parameters.
    pub fn params(&self, offsets: &[u32], tables: &[u32]) -> LightPcaParams {
        LightPcaParams {
            n_views: self.views.len() as u32,
            view_table: tables[0],
            resolution: self.resolution as u32,
            colour: match self.colour {
                Colour::Rgb => 0,
                Colour::Ycc => 1,
            },
            k_main: self.k_main as u32,
            k_chroma: self.k_chroma as u32,
            stride: self.stride() as u32,
            q: offsets[0],
            scale: offsets[1],
            table: offsets[2],
        }
    }

    /// `coeffs_q` (u8 `[H, W, V, K]`), `coeffs_scale`, `coeffs_bias` (f32 `[V K]`), `table`
    /// (f32 `[V, n, n, R]`), `views` `[V, 3]` and `layout` (i32 `[3]`: colour 0 = rgb, 1 = ycc;
    /// main components; chroma components).
    pub fn to_arrays(&self) -> NamedArrays {
        let mut a = NamedArrays::new();
        let (h, w, nv, n) = (self.height, self.width, self.views.len(), self.resolution);
        self.planes.insert_into(&mut a, "coeffs_", vec![h, w, nv, self.k()]);
        a.put("table", &[nv, n, n, self.stride()], self.table.clone());
        a.put_directions("views", &self.views);
        let colour = match self.colour {
            Colour::Rgb => 0,
            Colour::Ycc => 1,
        };
        a.put("layout", &[3], vec![colour, self.k_main as i32, self.k_chroma as i32]);
        a
    }

    /// Rebuild from [`LightPca::to_arrays`], validating every array.
    pub fn from_arrays(a: &NamedArrays) -> Result<LightPca> {
        let views = a.directions("views", None)?;
        let nv = views.len();
        let (layout, _) = a.get::<i32>("layout", &[Some(3)])?;
        let colour = match layout[0] {
            0 => Colour::Rgb,
            1 => Colour::Ycc,
            c => return Err(Error::format("layout", format!("colour {c} is neither 0 (rgb) nor 1 (ycc)"))),
        };
        let ok = |x: i32| usize::try_from(x).ok().filter(|&k| k <= MAX_COMPONENTS);
        let (Some(k_main), Some(k_chroma)) = (ok(layout[1]), ok(layout[2])) else {
            return Err(Error::format("layout", format!("components {:?} out of range", &layout[1..])));
        };
        let q = a.array("coeffs_q").ok_or_else(|| Error::arg("coeffs_q", "missing array"))?;
        let k = k_main + k_chroma;
        if q.shape.len() != 4 || q.shape[2] != nv || q.shape[3] != k || !matches!(q.data, ArrayData::U8(_)) {
            return Err(Error::format(
                "coeffs_q",
                format!("expected uint8 [H, W, {nv}, {k}], got {} {:?}", q.data.dtype(), q.shape),
            ));
        }
        let (h, w) = (q.shape[0], q.shape[1]);
        let (table, tsh) = a.get::<f32>("table", &[Some(nv), None, None, None])?;
        ensure_arg!(tsh[1] == tsh[2], "table", "expected a square grid, got {:?}", tsh);
        let planes = Planes::from_arrays(a, "coeffs_", h * w, nv * k)?;
        let m = LightPca {
            height: h,
            width: w,
            views,
            resolution: tsh[1],
            colour,
            k_main,
            k_chroma,
            planes,
            table: table.to_vec(),
            pooled: Vec::new(),
            fallback_slots: Vec::new(),
        };
        m.validate()?;
        ensure_arg!(tsh[3] == m.stride(), "table", "expected rows of {} values, got {}", m.stride(), tsh[3]);
        Ok(m)
    }

    /// Bytes of the table alone (part of `nbytes`).
    pub fn table_bytes(&self) -> usize {
        4 * self.table.len()
    }
}

crate::gpu_params! {
    /// Parameters of `light_pca.wgsl` (the RBF and bilinear models).
    pub struct LightPcaParams {
        /// Number of view slots V (directions `mdirs[0 .. V]`).
        pub n_views: u32,
        /// Offset of the slots' candidate table in `tables`.
        pub view_table: u32,
        /// Grid nodes per side n.
        pub resolution: u32,
        /// 0 = joint RGB, 1 = luminance / chroma.
        pub colour: u32,
        /// RGB or luminance components per slot.
        pub k_main: u32,
        /// Chroma components per slot.
        pub k_chroma: u32,
        /// f32 values per table row R.
        pub stride: u32,
        /// Store offset of the coefficient bytes `[texel][V][K]`, four per word.
        pub q: u32,
        /// Store offset of the per-plane scales (V K f32), followed by the biases (V K f32).
        pub scale: u32,
        /// Store offset of the table `[V][n * n][R]` f32.
        pub table: u32,
    }
}

/// The shared shader of both models (WGSL has no includes: one file, two pipeline names).
pub const fn shader(name: &'static str) -> Shader {
    Shader::new::<LightPcaParams>(name, include_str!("../../../shaders_wgsl/light_pca.wgsl"))
}

/// The resampling operator of one slot: given the slot's light directions (`m`, at least one)
/// and the grid resolution `n`, the `n^2 x m` matrix that maps the samples of one channel to its
/// values at the nodes, and `Some(amplification)` when the model's own fit extrapolated and a
/// fallback was used (listed in [`LightPca::fallback_slots`]).
pub type Operator<'a> = dyn Fn(&[[f64; 3]], usize) -> Result<(DMatrix<f64>, Option<f64>)> + Sync + 'a;

/// A view slot whose resampling operator fell back to a more stable one (the bilinear grid's
/// membrane smoothing, see [`crate::bilinear`]).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct FallbackSlot {
    /// The view slot index.
    pub slot: usize,
    /// The amplification of the fit it replaced.
    pub amplification: f64,
}

/// The least memory limit of [`fit`] on `btf` (bytes, besides the model): it does not stream
/// below it. In two passes ([`two_passes`]): 16 MB, the moments of every slot and per thread a
/// product ([`block_memory`]), a block of [`MIN_BLOCK`] texels, and above
/// [`staged::MOMENT_TEXELS`] texels 16 MB of sampled values; every texel's float
/// coefficients too when the limit holds them (4 bytes per stored byte), else they wait for the
/// quantization in a temporary file ([`btfrs_core::scratch`]). Slot by slot: 16 MB, the float
/// coefficients, one view slot's samples and its resampled data with their centred copy
/// (`3 L + 6 G` floats per texel).
pub fn least_memory(btf: &BtfRef<'_>, opts: &PcaOptions) -> u64 {
    let (t, nl) = (btf.texels() as u64, btf.lights.len() as u64);
    let g = (opts.resolution * opts.resolution) as u64;
    if two_passes(opts, btf.texels(), max_slot_pairs(btf)) {
        let (fixed, per) = block_memory(btf, opts);
        // Above MOMENT_TEXELS, the copy of the sampled values whose moments are summed.
        let sample = if btf.texels() > staged::MOMENT_TEXELS { staged::SAMPLE_COPY_BYTES as u64 } else { 0 };
        16_000_000 + fixed + MIN_BLOCK as u64 * per + sample
    } else {
        16_000_000 + coefficient_bytes(btf, opts) + 4 * t * (3 * nl + 6 * g)
    }
}

/// The float coefficients of every texel and slot, bytes.
fn coefficient_bytes(btf: &BtfRef<'_>, opts: &PcaOptions) -> u64 {
    let kc = opts.check().unwrap_or(0) as u64; // a bad option is reported by the fit itself
    4 * btf.texels() as u64 * btf.views.len() as u64 * (opts.components as u64 + kc)
}

/// Whether the two-pass fit under `limit` keeps the float coefficients in a temporary file: when
/// the limit does not hold them besides its least.
fn spills(btf: &BtfRef<'_>, opts: &PcaOptions, limit: Option<u64>) -> bool {
    limit.is_some_and(|l| l < least_memory(btf, opts) + coefficient_bytes(btf, opts))
}

/// The fewest texels per block of the two-pass fit.
pub const MIN_BLOCK: usize = 64;

/// The values per vector of each PCA group of `opts` ([`groups`]).
fn group_dims(opts: &PcaOptions) -> Vec<usize> {
    let g = opts.resolution * opts.resolution;
    match opts.colour {
        Colour::Rgb => vec![3 * g],
        Colour::Ycc => vec![g, 2 * g],
    }
}

/// The size of the exact eigenproblems of a slot fitted from `m` pairs: a group's covariance
/// has the rank of its map ([`Plan::group_maps`]), at most `min(d, 3 m)`.
pub fn exact_dim(opts: &PcaOptions, m: usize) -> usize {
    group_dims(opts).into_iter().max().unwrap_or(0).min(3 * m)
}

/// Whether [`fit`] runs in two passes over blocks of texels ([`staged::fit_two_passes`]), its
/// slots fitted from at most `m` pairs: when the exact eigenproblems ([`exact_dim`]) have at most
/// [`EXACT_PCA_DIM`] rows and there are at least as many texels (below, one slot's Gram matrix
/// is the smaller exact eigenproblem).
pub(crate) fn two_passes(opts: &PcaOptions, t: usize, m: usize) -> bool {
    let d = exact_dim(opts, m);
    d <= EXACT_PCA_DIM && t >= d
}

/// The most pairs a slot of `btf` is fitted from ([`slot_pairs`]).
fn max_slot_pairs(btf: &BtfRef<'_>) -> usize {
    (0..btf.views.len()).map(|v| slot_pairs(btf, v).0.len()).max().unwrap_or(0)
}

/// The two-pass fit's memory besides the coefficients: `(fixed, per texel of a block)`. Fixed:
/// the samples' moments (`8 V (s^2 + s)`, `s = 3 m`) and per thread a block's second moment
/// (`4 s^2`) and a slot's group maps and eigenproblem (`8 (d s + 2 d^2)`); per texel and thread:
/// one slot's samples and their centred copy; the block's coefficients.
fn block_memory(btf: &BtfRef<'_>, opts: &PcaOptions) -> (u64, u64) {
    let threads = rayon::current_num_threads() as u64;
    let nv = btf.views.len() as u64;
    let s = 3 * max_slot_pairs(btf) as u64;
    let d = exact_dim(opts, max_slot_pairs(btf)) as u64;
    let dg: u64 = group_dims(opts).iter().map(|&d| d as u64).sum();
    (8 * nv * (s * s + s) + threads * (4 * s * s + 8 * (dg * s + 2 * d * d)), 8 * threads * s + 8 * nv * 64)
}

/// Texels per block of the two-pass fit: about 256 MB of values (an eighth of `limit` when
/// smaller, at least 8 MB), and no more than what `limit` leaves for the work on a block.
pub(crate) fn block_texels(btf: &BtfRef<'_>, opts: &PcaOptions, limit: Option<u64>) -> usize {
    let full = btf.abrdf_len().max(1) as u64;
    let bytes = limit.map_or(256 << 20, |l| (l / 8).clamp(8 << 20, 256 << 20));
    let mut n = (bytes / (4 * full)).max(MIN_BLOCK as u64);
    if let Some(l) = limit {
        // What the least memory holds besides its block (and the coefficients, unless they
        // spill), then as many texels as the rest holds.
        let per = block_memory(btf, opts).1.max(1);
        let mut rest = least_memory(btf, opts) - MIN_BLOCK as u64 * per;
        if !spills(btf, opts, limit) {
            rest += coefficient_bytes(btf, opts);
        }
        n = n.min(l.saturating_sub(rest) / per).max(MIN_BLOCK as u64);
    }
    (n as usize).min(btf.texels()).max(1)
}

/// One view slot's resampling: the (view, light) pairs it is fitted from and the operator from
/// their samples to the grid (`G x m`).
#[derive(Debug, Clone)]
pub(crate) struct SlotPlan {
    pairs: Vec<(usize, usize)>,
    w: DMatrix<f32>,
}

/// The resampling of every view slot, with what the report says about it: a function of the
/// directions, the mask and the options only, so every texel block of a blockwise fit
/// ([`staged`]) computes the same one.
#[derive(Debug, Clone)]
pub struct Plan {
    slots: Vec<SlotPlan>,
    /// The slots fitted from pooled lights.
    pub pooled: Vec<PooledSlot>,
    /// The slots whose operator fell back to a more stable one.
    pub fallback_slots: Vec<FallbackSlot>,
}

/// One slot's plan and what the report says about it.
type PlannedSlot = (SlotPlan, Option<PooledSlot>, Option<FallbackSlot>);

impl Plan {
    /// The plan of every slot of a BTF with these directions and mask: the pairs of
    /// [`slot_pairs`] and the operator `op` of their lights. `what` names the model in errors.
    pub fn new(
        views: &[[f64; 3]],
        lights: &[[f64; 3]],
        mask: Option<&[bool]>,
        n: usize,
        op: &Operator<'_>,
        what: &str,
    ) -> Result<Plan> {
        let geo = BtfRef { height: 0, width: 0, views, lights, data: &[], mask };
        // The operators are independent per slot (an RBF or least-squares solve each): in
        // parallel, the first failing slot's error reported.
        let per: Vec<Result<PlannedSlot>> = (0..views.len())
            .into_par_iter()
            .map(|v| {
                let (pairs, from) = slot_pairs(&geo, v);
                if pairs.is_empty() {
                    let (theta, phi) = directions::to_theta_phi(views[v]);
                    return Err(Error::Degenerate(format!(
                        "{what}: view slot {v} (theta {:.1}, phi {:.1} deg) has no lights, and no other view has any",
                        theta.to_degrees(),
                        phi.to_degrees()
                    )));
                }
                let pooled =
                    (!from.is_empty()).then(|| PooledSlot { slot: v, lights: geo.lights_of_view(v).len(), from });
                let dirs: Vec<[f64; 3]> = pairs.iter().map(|&(_, l)| lights[l]).collect();
                let (w, fell_back) = op(&dirs, n)?;
                let w = DMatrix::<f32>::from_fn(w.nrows(), w.ncols(), |i, j| w[(i, j)] as f32);
                let fallback = fell_back.map(|amplification| FallbackSlot { slot: v, amplification });
                Ok((SlotPlan { pairs, w }, pooled, fallback))
            })
            .collect();
        let mut plan = Plan { slots: Vec::new(), pooled: Vec::new(), fallback_slots: Vec::new() };
        for r in per {
            let (s, p, f) = r?;
            plan.slots.push(s);
            plan.pooled.extend(p);
            plan.fallback_slots.extend(f);
        }
        Ok(plan)
    }

    /// Slot `v`'s functions of every texel of `btf` on the grid: column `3 t + c` (`G` values) is
    /// texel `t`'s channel `c`, so the `3 G x T` matrix over the same storage is the joint RGB
    /// data (channel-major per texel). Every value of view `v` (all its lights, present or not)
    /// is checked on the way when `scan` is given: over all views, each value of the BTF once, as
    /// the fit reads it (`SCANS_VALUES`).
    pub(crate) fn resample_checked(&self, btf: &BtfRef<'_>, v: usize, scan: Option<&TexelScan>) -> DMatrix<f32> {
        let m = self.slots[v].pairs.len();
        let s = self.samples(btf, v, scan);
        gemm(&view(&self.slots[v].w), &btfrs_numerics::dense::cols(&s, m, 3 * btf.texels()))
    }

    /// Slot `v`'s samples of every texel of `btf`, `[T][3][m]` (texel `t`'s channel `c` at the
    /// slot's `m` pairs), checking every value of view `v` when `scan` is given.
    pub(crate) fn samples(&self, btf: &BtfRef<'_>, v: usize, scan: Option<&TexelScan>) -> Vec<f32> {
        let pairs = &self.slots[v].pairs;
        let (m, nl, t) = (pairs.len(), btf.lights.len(), btf.texels());
        // Runs of consecutive pairs (one run for a slot without a mask): `(first value, first
        // sample, length)`, copied without an index check per value.
        let mut runs: Vec<(usize, usize, usize)> = Vec::new();
        for (j, &(u, l)) in pairs.iter().enumerate() {
            let at = (u * nl + l) * 3;
            match runs.last_mut() {
                Some((a0, j0, len)) if *a0 + 3 * *len == at && *j0 + *len == j => *len += 1,
                _ => runs.push((at, j, 1)),
            }
        }
        let mut s = vec![0.0f32; m * 3 * t];
        s.par_chunks_mut(3 * m).enumerate().for_each(|(tx, out)| {
            let a = btf.texel(tx);
            if let Some(scan) = scan {
                scan.check(&a[v * nl * 3..(v + 1) * nl * 3]);
            }
            let (r, gb) = out.split_at_mut(m);
            let (g, b) = gb.split_at_mut(m);
            for &(a0, j0, len) in &runs {
                let src = a[a0..a0 + 3 * len].chunks_exact(3);
                let dst = r[j0..j0 + len].iter_mut().zip(&mut g[j0..j0 + len]).zip(&mut b[j0..j0 + len]);
                for (((r, g), b), px) in dst.zip(src) {
                    (*r, *g, *b) = (px[0], px[1], px[2]);
                }
            }
        });
        s
    }

    /// The most pairs any slot is fitted from.
    pub fn max_pairs(&self) -> usize {
        self.slots.iter().map(|s| s.pairs.len()).max().unwrap_or(0)
    }

    /// Slot `v`'s pairs.
    pub(crate) fn pairs(&self, v: usize) -> usize {
        self.slots[v].pairs.len()
    }

    /// Slot `v`'s map from a texel's samples (`3 m`, as [`Plan::samples`]) to each group's
    /// vector ([`groups`]): `d x 3 m` per group. rgb: the operator `W` on each channel; ycc: the
    /// luminance `W (r + g + b) / 3`, then the chroma `W b - Y` and `W r - Y`.
    pub(crate) fn group_maps(&self, v: usize, colour: Colour) -> Vec<DMatrix<f64>> {
        let w = &self.slots[v].w;
        let (g, m) = (w.nrows(), w.ncols());
        // Rows [r0, r0 + g) of a group map get `coef[c] W` in channel c's columns.
        let put = |t: &mut DMatrix<f64>, r0: usize, coef: [f64; 3]| {
            for c in 0..3 {
                for i in 0..g {
                    for j in 0..m {
                        t[(r0 + i, c * m + j)] = coef[c] * w[(i, j)] as f64;
                    }
                }
            }
        };
        let third = 1.0 / 3.0;
        match colour {
            Colour::Rgb => {
                let mut t = DMatrix::<f64>::zeros(3 * g, 3 * m);
                put(&mut t, 0, [1.0, 0.0, 0.0]);
                put(&mut t, g, [0.0, 1.0, 0.0]);
                put(&mut t, 2 * g, [0.0, 0.0, 1.0]);
                vec![t]
            }
            Colour::Ycc => {
                let mut y = DMatrix::<f64>::zeros(g, 3 * m);
                put(&mut y, 0, [third; 3]);
                let mut ch = DMatrix::<f64>::zeros(2 * g, 3 * m);
                put(&mut ch, 0, [-third, -third, 1.0 - third]);
                put(&mut ch, g, [1.0 - third, -third, -third]);
                vec![y, ch]
            }
        }
    }
}

/// The vectors one PCA compresses, from a slot's resampled functions `r` (`3 G x T`, see
/// [`Plan::resample`]): `rgb` one group of `3 G` values per texel; `ycc` the luminance (`G`)
/// and the two chroma differences (`2 G`, Cb then Cr). Each group is `(values, d)`, column-major
/// `d x T`.
pub(crate) fn groups(r: &[f32], g: usize, t: usize, colour: Colour) -> Vec<(Cow<'_, [f32]>, usize)> {
    match colour {
        Colour::Rgb => vec![(Cow::Borrowed(r), 3 * g)],
        Colour::Ycc => {
            let mut y = vec![0.0f32; g * t];
            let mut ch = vec![0.0f32; 2 * g * t];
            y.par_chunks_mut(g).zip(ch.par_chunks_mut(2 * g)).enumerate().for_each(|(tx, (yo, co))| {
                let x = &r[tx * 3 * g..(tx + 1) * 3 * g];
                for node in 0..g {
                    let (rr, gg, bb) = (x[node], x[g + node], x[2 * g + node]);
                    let lum = (rr + gg + bb) / 3.0;
                    yo[node] = lum;
                    co[node] = bb - lum;
                    co[g + node] = rr - lum;
                }
            });
            vec![(Cow::Owned(y), g), (Cow::Owned(ch), 2 * g)]
        }
    }
}

/// The groups' `(components, first plane)` within a slot's `K` planes (as [`groups`]).
pub(crate) fn group_planes(colour: Colour, km: usize, kc: usize) -> Vec<(usize, usize)> {
    match colour {
        Colour::Rgb => vec![(km, 0)],
        Colour::Ycc => vec![(km, 0), (kc, km)],
    }
}

/// Where value `i` of group `group` lives in a slot's table: `(node, mean column, first basis
/// column, basis column step)`, component `p` at `first + step p` (see the module doc).
fn place(colour: Colour, km: usize, g: usize, group: usize, i: usize) -> (usize, usize, usize, usize) {
    let (c, node) = (i / g, i % g);
    match (colour, group) {
        (Colour::Rgb, _) => (node, c, 3 + c, 3),
        (Colour::Ycc, 0) => (node, 0, 3, 1),
        (Colour::Ycc, _) => (node, 1 + c, 3 + km + c, 2),
    }
}

/// Write a slot's table (`G` rows of `stride`) from each group's mean and principal directions.
pub(crate) fn write_slot(table: &mut [f32], colour: Colour, km: usize, g: usize, parts: &[(&[f32], &DMatrix<f32>)]) {
    let stride = table.len() / g;
    for (gi, (mean, basis)) in parts.iter().enumerate() {
        for (i, &m) in mean.iter().enumerate() {
            let (node, mc, first, step) = place(colour, km, g, gi, i);
            let row = &mut table[node * stride..(node + 1) * stride];
            row[mc] = m;
            for p in 0..basis.ncols() {
                row[first + step * p] = basis[(i, p)];
            }
        }
    }
}

/// Read back what [`write_slot`] wrote: each group's mean and principal directions.
pub(crate) fn read_slot(
    table: &[f32],
    colour: Colour,
    km: usize,
    kc: usize,
    g: usize,
) -> Vec<(Vec<f32>, DMatrix<f32>)> {
    let stride = table.len() / g;
    let dims = match colour {
        Colour::Rgb => vec![3 * g],
        Colour::Ycc => vec![g, 2 * g],
    };
    dims.iter()
        .zip(group_planes(colour, km, kc))
        .enumerate()
        .map(|(gi, (&d, (k, _)))| {
            let mut mean = vec![0.0f32; d];
            let mut basis = DMatrix::<f32>::zeros(d, k);
            for (i, m) in mean.iter_mut().enumerate() {
                let (node, mc, first, step) = place(colour, km, g, gi, i);
                let row = &table[node * stride..(node + 1) * stride];
                *m = row[mc];
                for p in 0..k {
                    basis[(i, p)] = row[first + step * p];
                }
            }
            (mean, basis)
        })
        .collect()
}

/// Fit: resample every slot with `op`, then PCA and quantize (see the module doc). Where the
/// PCA is the exact one of a covariance ([`two_passes`]), in two passes over blocks of texels in
/// storage order ([`staged::fit_two_passes`]; `monitor` counts the blocks of both), else slot by
/// slot (`monitor` counts slots). `what` names the model in errors.
pub fn fit(btf: &BtfRef<'_>, opts: &PcaOptions, op: &Operator<'_>, what: &str, monitor: &Monitor) -> Result<LightPca> {
    opts.check()?;
    let t = btf.texels();
    let plan = Plan::new(btf.views, btf.lights, btf.mask, opts.resolution, op, what)?;
    if two_passes(opts, t, plan.max_pairs()) {
        let block = block_texels(btf, opts, monitor.memory_limit());
        let spill = spills(btf, opts, monitor.memory_limit());
        staged::fit_two_passes(btf, opts, plan, block, spill, staged::MOMENT_TEXELS, monitor)
    } else {
        fit_per_slot(btf, opts, plan, monitor)
    }
}

/// The fit slot by slot: each slot's resampled functions of every texel at once, then their
/// PCA ([`pca`]: the Gram matrix's or the randomized one).
pub(crate) fn fit_per_slot(btf: &BtfRef<'_>, opts: &PcaOptions, plan: Plan, monitor: &Monitor) -> Result<LightPca> {
    let kc = opts.check()?;
    let (nv, t) = (btf.views.len(), btf.texels());
    let n = opts.resolution;
    let g = n * n;
    let km = opts.components;
    let k = km + kc;
    let lw = if opts.colour == Colour::Rgb { 3 } else { 1 };
    let stride = 3 + lw * km + 2 * kc;
    monitor.start(nv as u64);
    let mut coeffs = vec![0.0f32; t * nv * k];
    let mut table = vec![0.0f32; nv * g * stride];
    let scan = TexelScan::new();
    for v in 0..nv {
        let r = plan.resample_checked(btf, v, Some(&scan));
        scan.finish("data", btf.data)?;
        monitor.check()?;
        let slot_table = &mut table[v * g * stride..(v + 1) * g * stride];
        let seed = opts.seed.wrapping_add(v as u64);
        let mut parts = Vec::new();
        for (gi, ((x, d), (kk, off))) in
            groups(r.as_slice(), g, t, opts.colour).into_iter().zip(group_planes(opts.colour, km, kc)).enumerate()
        {
            // The chroma PCA's seed differs from the luminance's (randomized path only).
            let (mean, basis, c) = pca(&x, d, t, kk, if gi == 0 { seed } else { seed ^ 0x9e37 })?;
            put_coeffs(&mut coeffs, &c, v, nv, k, off);
            parts.push((mean, basis));
        }
        let refs: Vec<(&[f32], &DMatrix<f32>)> = parts.iter().map(|(m, b)| (m.as_slice(), b)).collect();
        write_slot(slot_table, opts.colour, km, g, &refs);
        monitor.advance(1);
    }
    let Plan { pooled, fallback_slots, .. } = plan;
    assemble(btf.height, btf.width, btf.views, opts, Planes::quantize(&coeffs, nv * k)?, table, pooled, fallback_slots)
}

/// The model from its parts (validated).
#[allow(clippy::too_many_arguments)]
pub(crate) fn assemble(
    height: usize,
    width: usize,
    views: &[[f64; 3]],
    opts: &PcaOptions,
    planes: Planes,
    table: Vec<f32>,
    pooled: Vec<PooledSlot>,
    fallback_slots: Vec<FallbackSlot>,
) -> Result<LightPca> {
    let m = LightPca {
        height,
        width,
        views: views.to_vec(),
        resolution: opts.resolution,
        colour: opts.colour,
        k_main: opts.components,
        k_chroma: opts.check()?,
        planes,
        table,
        pooled,
        fallback_slots,
    };
    m.validate()?;
    Ok(m)
}

/// The (view, light) pairs slot `v` is fitted from, and the other slots it borrowed from: its
/// own present lights when it has at least [`MIN_LIGHTS`] (or when no other view has lights);
/// else its lights pooled with those of the nearest views (by angle) until it has that many.
fn slot_pairs(btf: &BtfRef<'_>, v: usize) -> (Vec<(usize, usize)>, Vec<usize>) {
    let mut pairs: Vec<(usize, usize)> = btf.lights_of_view(v).into_iter().map(|l| (v, l)).collect();
    let mut from = Vec::new();
    if pairs.len() >= MIN_LIGHTS {
        return (pairs, from);
    }
    let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let mut order: Vec<usize> = (0..btf.views.len()).filter(|&u| u != v).collect();
    order.sort_by(|&a, &b| dot(btf.views[v], btf.views[b]).total_cmp(&dot(btf.views[v], btf.views[a])));
    for u in order {
        let more = btf.lights_of_view(u);
        if more.is_empty() {
            continue;
        }
        from.push(u);
        pairs.extend(more.into_iter().map(|l| (u, l)));
        if pairs.len() >= MIN_LIGHTS {
            break;
        }
    }
    (pairs, from)
}

/// Write the `kk x T` coefficients `c` of slot `v` at plane offset `off`.
pub(crate) fn put_coeffs(out: &mut [f32], c: &DMatrix<f32>, v: usize, nv: usize, k: usize, off: usize) {
    let kk = c.nrows();
    out.par_chunks_mut(nv * k).enumerate().for_each(|(t, o)| {
        for p in 0..kk {
            o[v * k + off + p] = c[(p, t)];
        }
    });
}

/// Centred PCA of the `t` columns (each `d` values) of the column-major `data`: exact up to
/// [`EXACT_PCA_DIM`] values per vector, randomized above ([`btfrs_numerics::pca::centred`]).
pub(crate) fn pca(
    data: &[f32],
    d: usize,
    t: usize,
    k: usize,
    seed: u64,
) -> Result<(Vec<f32>, DMatrix<f32>, DMatrix<f32>)> {
    let (mean, basis, coeffs) = btfrs_numerics::pca::centred(data, d, t, k, seed, EXACT_PCA_DIM);
    if coeffs.iter().any(|x| !x.is_finite()) {
        return Err(Error::Degenerate("the PCA of the resampled light functions is not finite".into()));
    }
    Ok((mean, basis, coeffs))
}

/// Implement the model contract for a newtype `$ty(pub LightPca)` whose fit is `$fit`.
macro_rules! light_pca_model {
    ($ty:ident) => {
        impl $crate::eval::ReflectanceModel for $ty {
            type Query = $crate::light_pca::LightPcaQuery;
            fn dims(&self) -> (usize, usize) {
                (self.0.height, self.0.width)
            }
            fn query(&self, view: [f64; 3], light: [f64; 3]) -> Self::Query {
                self.0.query(view, light)
            }
            #[inline]
            fn eval(&self, t: usize, q: &Self::Query) -> [f32; 3] {
                self.0.eval(t, q)
            }
        }

        impl $crate::gpu::GpuLayout for $ty {
            type Params = $crate::light_pca::LightPcaParams;
            const SHADER: $crate::gpu::Shader = $crate::light_pca::shader(<$ty as $crate::model::Model>::KIND);
            fn parts(&self) -> Vec<std::borrow::Cow<'_, [u32]>> {
                self.0.parts()
            }
            fn dir_sets(&self) -> Vec<&[[f64; 3]]> {
                vec![&self.0.views]
            }
            fn params(&self, offsets: &[u32], tables: &[u32]) -> Self::Params {
                self.0.params(offsets, tables)
            }
        }
    };
}
pub(crate) use light_pca_model;

/// The [`PcaOptions`] of a light-PCA model's options (RBF's and bilinear's share these fields).
macro_rules! pca_options_of {
    ($o:expr) => {
        $crate::light_pca::PcaOptions {
            resolution: $o.resolution,
            components: $o.components,
            chroma_components: $o.chroma_components,
            colour: $o.colour,
            seed: $o.seed,
        }
    };
}
pub(crate) use pca_options_of;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grid_weights_interpolate_node_positions() {
        // At a node the weight is all on it; in between, the weights reproduce the square point.
        let n = 5;
        for (k, d) in grid_directions(n).iter().enumerate() {
            if d[2] < 1e-9 {
                continue; // on the horizon the square point of a direction is not unique at corners
            }
            let w = grid_weights(n, *d);
            let top = w.iter().copied().fold((0, 0.0), |a, b| if b.1 > a.1 { b } else { a });
            assert_eq!(top.0, k);
            assert!((top.1 - 1.0).abs() < 1e-9, "{k}: {w:?}");
        }
        let l = btfrs_hemimap::square_to_hemisphere(0.3f64, 0.62);
        let w = grid_weights(n, l);
        let (mut s, mut t) = (0.0, 0.0);
        for (node, x) in w {
            s += x * (node % n) as f64 / 4.0;
            t += x * (node / n) as f64 / 4.0;
        }
        assert!((s - 0.3).abs() < 1e-9 && (t - 0.62).abs() < 1e-9, "{s} {t}");
        assert!((w.iter().map(|x| x.1).sum::<f64>() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn options_are_checked() {
        let o = PcaOptions { resolution: 8, components: 4, chroma_components: None, colour: Colour::Rgb, seed: 0 };
        assert_eq!(o.check().unwrap(), 0);
        assert_eq!(PcaOptions { colour: Colour::Ycc, ..o }.check().unwrap(), 1);
        let e = |o: PcaOptions| o.check().unwrap_err().to_string();
        assert!(e(PcaOptions { resolution: 1, ..o }).starts_with("resolution: expected 2 to 32"));
        assert!(e(PcaOptions { components: 0, ..o }).starts_with("components: expected 1 to 64"));
        assert!(e(PcaOptions { chroma_components: Some(2), ..o }).starts_with("chroma_components: only"));
        assert!(e(PcaOptions { colour: Colour::Ycc, components: 60, chroma_components: Some(10), ..o })
            .starts_with("chroma_components: expected at most 64"));
    }
}
