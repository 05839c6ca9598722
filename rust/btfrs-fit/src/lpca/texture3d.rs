//! The revised LPCA renderer of paper 004, section 6: the Eigen-BRDFs resampled into one 3D
//! texture.
//!
//! [`Lpca3d`] resamples every Eigen-BRDF on an `N^4` grid of the elevated concentric map
//! (section 6.1) and packs the grids into one RGBA8 3D texture with the t_l slices stacked along
//! z (section 6.2); the GPU filters three dimensions, the shader lerps the fourth
//! (`lpca_3d.wgsl`). Its CPU reference ([`ReflectanceModel`] below) samples the same texels with
//! the same trilinear weights, so the shader is tested against it like any other model.
//!
//! The grid values are the 9-tap interpolation of the measured Eigen-BRDFs at the grid's
//! directions, rounded to 8 bits with each Eigen-BRDF's own scale and bias, so the texel weights
//! (which fold those in, section 6.3) are shared by both renderers.
//!
//! **The light cosine.** The 9-tap renderer blends the measured lights with the cosine divided
//! out ([`btfrs_core::directions::cos_corrected`]: weights `w_k cos(l) / cos(l_k)`, which no
//! longer sum to 1, so the texel's constant term scales with their sum `S(l)` too). The grid
//! keeps the same blend as the normalised weights `(w_k / cos(l_k)) / sum` (values stay in the
//! 8-bit range) and stores `S` at each light node in the alpha channel (`S = 0.5 + a / 255`,
//! 0.5 to 1.5; `S` is 1 at a measured light and about 1.07 midway at 70 degrees); the renderer
//! multiplies the whole texel value by the interpolated `S`. Without it the 3D renderer drifted
//! to 34 dB from the 9-tap one (paper 004's target: 35).

use super::Lpca;
use crate::gpu::{words, GpuLayout, Shader, Volume};
use crate::model::ReflectanceModel;
use btfrs_core::directions::{interp_weights, COS_FLOOR};
use btfrs_core::{Error, Result};
use btfrs_hemimap::{hemisphere_to_square, square_to_hemisphere};
use rayon::prelude::*;
use std::borrow::Cow;

/// Default grid resolution per axis of the resampled Eigen-BRDFs: 16 x 16 directions per
/// hemisphere, about 11 degrees apart, finer than the UBO's 15-degree rings.
pub const DEFAULT_GRID: usize = 16;

/// An LPCA model with its Eigen-BRDFs resampled into a 3D texture (paper 004, section 6).
#[derive(Debug, Clone)]
pub struct Lpca3d<'a> {
    lpca: &'a Lpca,
    n: usize,
    gx: usize,
    gy: usize,
    /// RGBA8 texels, x fastest: `[N * N][N * gy][N * gx][4]`.
    vol: Vec<u8>,
}

impl<'a> Lpca3d<'a> {
    /// Resample `lpca`'s Eigen-BRDFs on an `n^4` grid. `max_dim` is the device's 3D texture
    /// limit per side (2048 in WebGPU's defaults).
    pub fn new(lpca: &'a Lpca, n: usize, max_dim: usize) -> Result<Self> {
        if !(2..=64).contains(&n) || n * n > max_dim {
            return Err(Error::arg(
                "grid",
                format!(
                    "expected 2 to {} samples per axis (N^2 <= {max_dim}), got {n}",
                    (max_dim as f64).sqrt() as usize
                ),
            ));
        }
        let e = lpca.clusters * (lpca.components + 1);
        let gx = (e as f64).sqrt().ceil() as usize;
        let gy = e.div_ceil(gx);
        if n * gx > max_dim || n * gy > max_dim {
            return Err(Error::arg(
                "grid",
                format!(
                    "{e} Eigen-BRDFs of {n} x {n} need a {} x {} texture plane, more than {max_dim}",
                    n * gx,
                    n * gy
                ),
            ));
        }
        let (nv, nl) = (lpca.views.len(), lpca.lights.len());
        let at = |i: usize| {
            square_to_hemisphere((i % n) as f64 / n as f64 + 0.5 / n as f64, (i / n) as f64 / n as f64 + 0.5 / n as f64)
        };
        // Interpolation weights of every grid direction over the measured ones (the 9-tap rule).
        let wv: Vec<Vec<(usize, f64)>> = (0..n * n).map(|i| interp_weights(&lpca.views, at(i), 3)).collect();
        // Lights with the cosine divided out (module doc): normalised weights and their sum S.
        let wl: Vec<(Vec<(usize, f64)>, f64)> = (0..n * n)
            .map(|i| {
                let d = at(i);
                let mut w = interp_weights(&lpca.lights, d, 3);
                w.iter_mut().for_each(|(l, x)| *x /= lpca.lights[*l][2].max(COS_FLOOR));
                let sum: f64 = w.iter().map(|x| x.1).sum();
                w.iter_mut().for_each(|x| x.1 /= sum);
                (w, d[2].max(0.0) * sum)
            })
            .collect();
        let (w, h, d) = (n * gx, n * gy, n * n);
        let mut vol = vec![0u8; w * h * d * 4];
        // One z slice (a light grid direction) at a time: z = t_l * N + s_l = the light grid index.
        vol.par_chunks_mut(w * h * 4).enumerate().for_each(|(z, slice)| {
            for ei in 0..e {
                let (tx, ty) = (ei % gx, ei / gx);
                for (vi, wvi) in wv.iter().enumerate() {
                    let (x, y) = (tx * n + vi % n, ty * n + vi / n);
                    let mut rgb = [0.0f64; 3];
                    for &(v, a) in wvi {
                        for &(l, b) in &wl[z].0 {
                            let o = ((ei * nv + v) * nl + l) * 4;
                            for (x, &q) in rgb.iter_mut().zip(&lpca.basis[o..o + 3]) {
                                *x += a * b * q as f64;
                            }
                        }
                    }
                    let px = &mut slice[(y * w + x) * 4..(y * w + x) * 4 + 4];
                    for c in 0..3 {
                        px[c] = rgb[c].round().clamp(0.0, 255.0) as u8;
                    }
                    px[3] = ((wl[z].1 - 0.5) * 255.0).round().clamp(0.0, 255.0) as u8;
                }
            }
        });
        Ok(Lpca3d { lpca, n, gx, gy, vol })
    }

    /// Samples per axis.
    pub fn grid(&self) -> usize {
        self.n
    }

    /// Bytes of the 3D texture.
    pub fn texture_bytes(&self) -> usize {
        self.vol.len()
    }

    /// Clamp-to-edge trilinear sample of the texture at texel coordinates (x, y, z) (sample
    /// centres at i + 0.5), as the GPU's linear sampler computes it: RGBA in 0..1.
    fn sample(&self, p: [f32; 3]) -> [f32; 4] {
        let size = [self.n * self.gx, self.n * self.gy, self.n * self.n];
        let mut idx = [[0usize; 2]; 3];
        let mut f = [0.0f32; 3];
        for a in 0..3 {
            let u = p[a] - 0.5;
            let i = u.floor();
            f[a] = u - i;
            let clampi = |v: f32| (v.max(0.0) as usize).min(size[a] - 1);
            idx[a] = [clampi(i), clampi(i + 1.0)];
        }
        let mut out = [0.0f32; 4];
        for (dz, wz) in [(0, 1.0 - f[2]), (1, f[2])] {
            for (dy, wy) in [(0, 1.0 - f[1]), (1, f[1])] {
                for (dx, wx) in [(0, 1.0 - f[0]), (1, f[0])] {
                    let o = ((idx[2][dz] * size[1] + idx[1][dy]) * size[0] + idx[0][dx]) * 4;
                    for (x, &q) in out.iter_mut().zip(&self.vol[o..o + 4]) {
                        *x += wx * wy * wz * q as f32 / 255.0;
                    }
                }
            }
        }
        out
    }
}

fn grid_coord(x: f32, n: f32) -> f32 {
    (x * n).clamp(0.5, n - 0.5)
}

/// A prepared 3D-texture query: the view's (s_v, t_v) and the light's slices and weight.
#[derive(Debug, Clone, Copy)]
pub struct Lpca3dQuery {
    xy: [f32; 2],
    zs: f32,
    i0: usize,
    i1: usize,
    w: f32,
}

impl ReflectanceModel for Lpca3d<'_> {
    type Query = Lpca3dQuery;

    fn dims(&self) -> (usize, usize) {
        ReflectanceModel::dims(self.lpca)
    }

    fn query(&self, view: [f64; 3], light: [f64; 3]) -> Lpca3dQuery {
        let nf = self.n as f32;
        let sv = hemisphere_to_square(view);
        let sl = hemisphere_to_square(light);
        let ft = (sl[1] as f32 * nf - 0.5).clamp(0.0, nf - 1.0);
        let i0 = (ft as usize).min(self.n - 1);
        Lpca3dQuery {
            xy: [grid_coord(sv[0] as f32, nf), grid_coord(sv[1] as f32, nf)],
            zs: grid_coord(sl[0] as f32, nf),
            i0,
            i1: (i0 + 1).min(self.n - 1),
            w: ft - i0 as f32,
        }
    }

    fn eval(&self, t: usize, q: &Lpca3dQuery) -> [f32; 3] {
        let m = self.lpca;
        let c = m.components;
        let k = m.ids[t] as usize;
        let wt = &m.weights[t * (c + 2)..(t + 1) * (c + 2)];
        let mut out = [wt[0]; 3];
        let nf = self.n as f32;
        let mut s = 0.0f32;
        for j in 0..=c {
            let e = k * (c + 1) + j;
            let tile = [(e % self.gx) as f32 * nf, (e / self.gx) as f32 * nf];
            let p = [tile[0] + q.xy[0], tile[1] + q.xy[1]];
            let a = self.sample([p[0], p[1], q.i0 as f32 * nf + q.zs]);
            let b = self.sample([p[0], p[1], q.i1 as f32 * nf + q.zs]);
            for ch in 0..3 {
                out[ch] += wt[1 + j] * (a[ch] + (b[ch] - a[ch]) * q.w);
            }
            if j == 0 {
                s = 0.5 + a[3] + (b[3] - a[3]) * q.w;
            }
        }
        out.map(|x| x * s)
    }
}

crate::gpu_params! {
    /// Parameters of `lpca_3d.wgsl`.
    pub struct Lpca3dParams {
        /// Grid samples per axis N.
        pub grid: u32,
        /// Eigen-BRDF tiles per row of the texture's xy plane.
        pub gx: u32,
        /// Tile rows.
        pub gy: u32,
        /// Store offset of the cluster ids: u16, two per word.
        pub ids: u32,
        /// Store offset of the weights `[texel][c + 2]` f32 (as `lpca_9tap.wgsl`).
        pub weights: u32,
        /// Components c.
        pub components: u32,
    }
}

impl GpuLayout for Lpca3d<'_> {
    type Params = Lpca3dParams;
    const SHADER: Shader =
        Shader::new::<Lpca3dParams>("lpca_3d", include_str!("../../../../shaders_wgsl/lpca_3d.wgsl"));

    fn parts(&self) -> Vec<Cow<'_, [u32]>> {
        vec![Cow::Owned(self.lpca.id_words()), words(&self.lpca.weights)]
    }

    fn params(&self, offsets: &[u32], _tables: &[u32]) -> Lpca3dParams {
        Lpca3dParams {
            grid: self.n as u32,
            gx: self.gx as u32,
            gy: self.gy as u32,
            ids: offsets[0],
            weights: offsets[1],
            components: self.lpca.components as u32,
        }
    }

    fn volume(&self) -> Option<Volume<'_>> {
        Some(Volume {
            size: [(self.n * self.gx) as u32, (self.n * self.gy) as u32, (self.n * self.n) as u32],
            texels: Cow::Borrowed(&self.vol),
        })
    }
}
