//! Double spherical harmonics fitted by constrained least squares (paper 002, section 3.1 and
//! the appendix), quantized to 8 bits per coefficient (section 5.2).
//!
//! Each texel's ABRDF is projected on real spherical harmonics over *both* the view and the light
//! direction ("double SH projection", 002 section 3.1): per colour channel
//!
//! ```text
//! f(v, l) = sum_{i < kv} sum_{j < kl} C[i][j] y_i(v) y_j(l)
//! ```
//!
//! with `y` the real orthonormal SH of the full sphere ([`sh_basis`]). The BTF value itself,
//! cos(theta_l) included, is fitted. Measured BTFs cover only the upper hemisphere, so the
//! projection cannot be an integral: it is a least-squares fit over the present (view, light)
//! pairs, and the lower hemisphere is unconstrained. A plain least-squares fit then puts large
//! coefficients of opposite sign into combinations that nearly cancel on the upper hemisphere;
//! they reproduce the samples but fall apart once quantized. The constrained least squares (CLS)
//! of the appendix bounds the coefficient energy by the function's own:
//!
//! ```text
//! c = (A + lambda I)^-1 b,   A = Y^T Y,   b = Y^T beta,   smallest lambda >= 0 with c^T c <= E
//! ```
//!
//! where `E` is the energy of the sampled function, estimated by solid-angle quadrature over the
//! present pairs ([`solid_angle_weights`]). `||c(lambda)||^2` decreases monotonically in lambda,
//! so lambda is found by a safeguarded Newton iteration (to 1e-7 relative, `btfrs_numerics::cls`).
//!
//! **Fitting in the eigenbasis.** `A` depends only on the directions and the mask, which every
//! texel shares: it is eigen-decomposed once, `A = Q D Q^T`, and per texel and channel
//! `c~ = Q^T b`, `||c(lambda)||^2 = sum_k c~_k^2 / (d_k + lambda)^2`, so each step of that search
//! costs O(k). With the complete (view, light) grid `A` is a Kronecker product,
//! `A = (Yv^T Yv) kron (Yl^T Yl)`, and only the two small factors are decomposed; the texel's
//! `[V, L]` data matrix `F` is then rotated by `b~ = (Yv Qv)^T F (Yl Ql)`, two matrix products that
//! are batched over a block of texels into two large GEMMs (`dense::gemm_into`: `matrixmultiply`
//! through nalgebra's strided views), with `d_ij = dv_i dl_j`. A mask breaks the Kronecker
//! structure: the general `(kv kl)^2` matrix `A` over the present pairs is decomposed instead, `b`
//! is computed by the same separable products on data with the absent pairs zeroed, and rotated by
//! a GEMM per block.
//!
//! **Streaming.** Texels are processed in chunks of [`ShOptions::chunk_texels`], in order, with
//! rayon inside a chunk (paper 002 section 5.2 processes its BTFs scanline by scanline so they
//! need not fit in memory); a memory-mapped BTF is read once. Quantization (per colour channel,
//! uniform over all texels and coefficients) runs after the last chunk.
//!
//! **Rendering** (002 section 4.2): unquantize, then the double sum at the tangent-frame view and
//! light ([`ReflectanceModel`] for [`Sh`]; mirrored by the WGSL shader).
//!
//! **Where the parts live.** The basis ([`sh_basis`], `sh/basis.rs`), the quadrature weights of
//! the energy bound ([`solid_angle_weights`], `sh/quadrature.rs`), the constrained least-squares
//! solver (`cls.rs`, named for paper 002's appendix) and the 8-bit storage ([`quantize`],
//! `sh/quantize.rs`) are modules of their own; this file holds the model and the fit that ties
//! them together.

mod basis;
mod quadrature;
mod quantize;
pub mod wgsl;

use crate::gpu::{GpuLayout, Shader};
use crate::model::{
    average_texels, Bench, CoefficientFeatures, Mip, Model, ReflectanceModel, Sampling, Setting, ShExpansion,
};
use crate::options::Spec;
use btfrs_core::btf::TexelScan;

/// The coefficient counts the fit accepts: perfect squares up to [`MAX_COEFFS`].
const SQUARES: &[i64] = &[1, 4, 9, 16, 25, 36, 49, 64];
/// The evaluate sweep's note on a float model.
const FLOAT_NOTE: &str = "rendered (and bytes counted) after 8-bit quantization for the GPU";
use basis::basis_matrix;
use btfrs_core::arrays::check_finite;
use btfrs_core::{ensure_arg, BtfRef, Error, Monitor, NamedArrays, Result};
use btfrs_numerics::cls::Solver;
use btfrs_numerics::dense::{gemm, gemm_into, rows, rows_mut, rows_t, sym_eigen_desc, view, view_t};
use nalgebra::DMatrix;
use rayon::prelude::*;
use std::borrow::Cow;

pub use basis::{sh_basis, MAX_COEFFS, MAX_DEGREE};
pub use quadrature::solid_angle_weights;
pub use quantize::quantize;

/// Fit options.
#[derive(Debug, Clone, Copy, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShOptions {
    /// SH coefficients over the light direction, a perfect square in 1..=64 (degree <= 7).
    pub light_coeffs: usize,
    /// SH coefficients over the view direction, a perfect square in 1..=64.
    pub view_coeffs: usize,
    /// Constrained least squares (the paper's); `false` = plain least squares, for comparison.
    pub cls: bool,
    /// Store 8-bit coefficients (per channel scale and bias) instead of f32.
    pub quantize: bool,
    /// Texels processed per chunk: working memory besides the output is O(chunk).
    pub chunk_texels: usize,
}

impl Default for ShOptions {
    /// The defaults of [`Sh`]'s option schema.
    fn default() -> Self {
        crate::options::defaults(<Sh as Model>::OPTIONS)
    }
}

/// Stored coefficients.
#[derive(Debug, Clone, PartialEq)]
pub enum ShCoeffs {
    /// f32 coefficients.
    Float(Vec<f32>),
    /// 8-bit coefficients: value = `bias[ch] + scale[ch] * q`.
    Quantized {
        /// One byte per coefficient.
        q: Vec<u8>,
        /// Per colour channel step.
        scale: [f32; 3],
        /// Per colour channel offset (the smallest coefficient of the channel).
        bias: [f32; 3],
    },
}

/// A fitted double-SH BTF.
#[derive(Debug, Clone)]
pub struct Sh {
    /// Rows.
    pub height: usize,
    /// Columns.
    pub width: usize,
    /// Coefficients over the view direction, `kv`.
    pub view_coeffs: usize,
    /// Coefficients over the light direction, `kl`.
    pub light_coeffs: usize,
    /// layout [H, W, 3, view_coeffs, light_coeffs] (light index innermost); value = bias[ch] + scale[ch] * q
    pub coeffs: ShCoeffs,
    /// fit statistics: fraction of (texel, channel) fits where the constraint was active (lambda > 0), mean lambda
    pub constrained_fraction: f64,
    /// Mean lambda over all (texel, channel) fits, zeros included. (An infinite lambda, nonzero
    /// data under a zero energy bound, which only direction sets with weightless members allow,
    /// counts as constrained but not in the mean.)
    pub mean_lambda: f64,
}

/// Eigenvalues (clamped at 0: `A` is a Gram matrix, negative values are rounding) and
/// eigenvectors (the columns, in the same order) of the symmetric matrix `a`.
fn gram_eigen(a: DMatrix<f64>) -> (Vec<f64>, DMatrix<f64>) {
    let (vals, vecs) = sym_eigen_desc(a);
    (vals.into_iter().map(|x| x.max(0.0)).collect(), vecs)
}

// ---------------------------------------------------------------------------------------------
// The fit
// ---------------------------------------------------------------------------------------------

/// Eigenvalues of `A = Y^T Y` below this fraction of the largest count as zero for plain least
/// squares: a few f64 epsilons, the resolution of a symmetric eigensolver. (On UBO 81 the
/// smallest/largest ratio is 1.6e-14 for 25 x 25 coefficients, 1e-17 for 36 x 25.)
const LS_RCOND: f64 = 1e-15;
/// Texels per rayon task inside a chunk: enough rows for the GEMMs to run at full speed while
/// the block's f64 copy (`16 x 81 x 81 x 3 x 8` bytes = 2.5 MB at UBO 81) stays cache friendly.
const BLOCK_TEXELS: usize = 16;

/// How `A` is diagonalised.
enum Rotation {
    /// Complete grid: `A = Av kron Al`; `pv = Yv Qv`, `pl = Yl Ql` (V x kv, L x kl); `qv`, `ql`
    /// the eigenvectors of `Av`, `Al` (columns).
    Separable { qv: DMatrix<f64>, ql: DMatrix<f64> },
    /// Masked grid: `pv = Yv`, `pl = Yl` (unrotated), `q` the n x n eigenvectors of `A`.
    General { q: DMatrix<f64> },
}

/// Everything shared by all texels.
struct Plan {
    nv: usize,
    nl: usize,
    kv: usize,
    kl: usize,
    /// `[V, L]` present pairs (None = all present).
    mask: Option<Vec<bool>>,
    /// Quadrature weights of views and lights, and the factor that scales the energy over the
    /// present pairs up to the whole grid.
    wv: Vec<f64>,
    wl: Vec<f64>,
    energy_scale: f64,
    pv: DMatrix<f64>,
    pl: DMatrix<f64>,
    rot: Rotation,
    /// Eigenvalues of `A`, in the order of the rotated coefficients (separable: `dv_i dl_j` at
    /// `i * kl + j`).
    d: Vec<f64>,
    cls: bool,
}

/// Test hooks: not options a user needs.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Knobs {
    /// Use the general (masked) path even for a complete grid.
    pub force_general: bool,
    /// Multiplies the energy bound `E` (1 = the paper's).
    pub energy_factor: f64,
}

impl Default for Knobs {
    fn default() -> Self {
        Knobs { force_general: false, energy_factor: 1.0 }
    }
}

/// Per (texel, channel) lambda and energy bound, `[T, 3]` (read by the tests).
#[derive(Debug, Clone, Default)]
#[cfg_attr(not(test), allow(dead_code))]
pub(crate) struct Detail {
    pub lambda: Vec<f64>,
    pub energy: Vec<f64>,
}

fn check_coeffs(name: &str, k: usize) -> Result<()> {
    let r = (k as f64).sqrt().round() as usize;
    if !(1..=MAX_COEFFS).contains(&k) || r * r != k {
        return Err(Error::arg(
            name,
            format!("expected a perfect square in 1..=64 (1, 4, 9, 16, 25, 36, 49 or 64: degree 0 to 7), got {k}"),
        ));
    }
    Ok(())
}

impl Plan {
    fn new(btf: &BtfRef<'_>, opts: &ShOptions, knobs: &Knobs) -> Result<Plan> {
        let (nv, nl) = (btf.views.len(), btf.lights.len());
        let (kv, kl) = (opts.view_coeffs, opts.light_coeffs);
        let n = kv * kl;
        let present = btf.pairs();
        if !opts.cls && n > present {
            return Err(Error::Degenerate(format!(
                "plain least squares with {kv} x {kl} = {n} coefficients needs at least {n} present (view, light) \
                 pairs, got {present}; use cls=true (the constraint keeps the fit well posed) or fewer coefficients"
            )));
        }
        let mask: Option<Vec<bool>> = btf.mask.filter(|m| !m.iter().all(|&b| b)).map(|m| m.to_vec());
        let wv = solid_angle_weights(btf.views);
        let wl = solid_angle_weights(btf.lights);
        let all: f64 = wv.iter().sum::<f64>() * wl.iter().sum::<f64>();
        let part: f64 = wv
            .iter()
            .enumerate()
            .flat_map(|(v, &a)| wl.iter().enumerate().filter(move |&(l, _)| btf.has(v, l)).map(move |(_, &b)| a * b))
            .sum();
        // The present pairs carry no quadrature weight only in pathological direction sets (a
        // direction owning no grid cell); then E cannot be scaled and stays the unscaled sum.
        let energy_scale = knobs.energy_factor * if part > 0.0 { all / part } else { 1.0 };
        let yv = basis_matrix(btf.views, kv);
        let yl = basis_matrix(btf.lights, kl);
        let (yvm, ylm) = (rows(&yv, nv, kv), rows(&yl, nl, kl));
        let (pv, pl, rot, d) = if mask.is_none() && !knobs.force_general {
            let (dv, qv) = gram_eigen(gemm(&rows_t(&yv, nv, kv), &yvm));
            let (dl, ql) = gram_eigen(gemm(&rows_t(&yl, nl, kl), &ylm));
            let (pv, pl) = (gemm(&yvm, &view(&qv)), gemm(&ylm, &view(&ql)));
            let d = dv.iter().flat_map(|&a| dl.iter().map(move |&b| a * b)).collect();
            (pv, pl, Rotation::Separable { qv, ql }, d)
        } else {
            let a = general_gram(&yv, &yl, nv, nl, kv, kl, mask.as_deref());
            let (d, q) = gram_eigen(a);
            (yvm.into_owned(), ylm.into_owned(), Rotation::General { q }, d)
        };
        if !opts.cls {
            let dmax = d.iter().copied().fold(0.0f64, f64::max);
            let rank = d.iter().filter(|&&x| x > LS_RCOND * dmax).count();
            if rank < n {
                return Err(Error::Degenerate(format!(
                    "plain least squares: the {nv} views and {nl} lights ({present} present pairs) determine only \
                     {rank} of the {kv} x {kl} = {n} SH coefficients (the directions are too few or too clustered \
                     for this degree); use cls=true or fewer coefficients"
                )));
            }
        }
        Ok(Plan { nv, nl, kv, kl, mask, wv, wl, energy_scale, pv, pl, rot, d, cls: opts.cls })
    }

    fn n(&self) -> usize {
        self.kv * self.kl
    }

    /// Fit a block of `nb` texels: `data` their ABRDFs, `out` their `[nb, 3, kv, kl]`
    /// coefficients, `lambda` and `energy` their `[nb, 3]` statistics.
    fn block(&self, data: &[f32], nb: usize, out: &mut [f32], lambda: &mut [f64], energy: &mut [f64]) {
        let (nv, nl, kv, kl, n) = (self.nv, self.nl, self.kv, self.kl, self.n());
        // Columns of the batched products: (channel, texel) pairs, channel-major.
        let cols = 3 * nb;
        // 1. De-interleave into x[v][ch][t][l] (f64, absent pairs zeroed) and sum the energy.
        let mut x = vec![0.0f64; nv * cols * nl];
        energy.iter_mut().for_each(|e| *e = 0.0);
        for t in 0..nb {
            let abrdf = &data[t * nv * nl * 3..(t + 1) * nv * nl * 3];
            for v in 0..nv {
                let mut ev = [0.0f64; 3];
                for l in 0..nl {
                    // Absent pairs are skipped, not multiplied by 0: they may hold NaN.
                    if self.mask.as_ref().is_some_and(|m| !m[v * nl + l]) {
                        continue;
                    }
                    let s = &abrdf[(v * nl + l) * 3..(v * nl + l) * 3 + 3];
                    for ch in 0..3 {
                        let f = s[ch] as f64;
                        x[((v * 3 + ch) * nb + t) * nl + l] = f;
                        ev[ch] += self.wl[l] * f * f;
                    }
                }
                for ch in 0..3 {
                    energy[t * 3 + ch] += self.wv[v] * ev[ch];
                }
            }
        }
        energy.iter_mut().for_each(|e| *e *= self.energy_scale);
        // 2. g[v][(ch, t)][j] = sum_l x[v][(ch, t)][l] pl[l][j]: one GEMM over all rows.
        let mut g = vec![0.0f64; nv * cols * kl];
        gemm_into(&rows(&x, nv * cols, nl), &view(&self.pl), &mut rows_mut(&mut g, nv * cols, kl));
        drop(x);
        // 3. bt[i][(ch, t)][j] = sum_v pv[v][i] g[v][(ch, t)][j]: the second GEMM.
        let w = cols * kl;
        let mut bt = vec![0.0f64; kv * w];
        gemm_into(&view_t(&self.pv), &rows(&g, nv, w), &mut rows_mut(&mut bt, kv, w));
        drop(g);
        // 4. Solve in the eigenbasis, rotate back and scatter into [t][ch][i][j].
        let mut scratch = Solver::new(n);
        let mut coef = vec![0.0f64; n];
        match &self.rot {
            Rotation::Separable { qv, ql } => {
                for col in 0..cols {
                    for i in 0..kv {
                        coef[i * kl..(i + 1) * kl].copy_from_slice(&bt[i * w + col * kl..i * w + (col + 1) * kl]);
                    }
                    let (t, ch) = (col % nb, col / nb);
                    // The search starts at the texel's previous channel's lambda (columns go
                    // channel by channel), which is scale-invariant and so close when the
                    // channels differ mostly in brightness; a neighbouring texel's would tie
                    // the result, to the tolerance, to where the blocks start.
                    let hint = if ch > 0 { lambda[t * 3 + ch - 1] } else { 0.0 };
                    lambda[t * 3 + ch] = scratch.solve(&mut coef, &self.d, energy[t * 3 + ch], self.cls, hint);
                    for i in 0..kv {
                        bt[i * w + col * kl..i * w + (col + 1) * kl].copy_from_slice(&coef[i * kl..(i + 1) * kl]);
                    }
                }
                // c = Qv c~ Ql^T, batched: first every (i, ch, t) row times Ql^T, then Qv times all.
                let mut tmp = vec![0.0f64; kv * w];
                gemm_into(&rows(&bt, kv * cols, kl), &view_t(ql), &mut rows_mut(&mut tmp, kv * cols, kl));
                gemm_into(&view(qv), &rows(&tmp, kv, w), &mut rows_mut(&mut bt, kv, w));
                for col in 0..cols {
                    let (t, ch) = (col % nb, col / nb);
                    let dst = &mut out[(t * 3 + ch) * n..(t * 3 + ch + 1) * n];
                    for i in 0..kv {
                        for j in 0..kl {
                            dst[i * kl + j] = bt[i * w + col * kl + j] as f32;
                        }
                    }
                }
            }
            Rotation::General { q } => {
                // b as an n x cols matrix, then b~ = Q^T b.
                let mut b = vec![0.0f64; n * cols];
                for i in 0..kv {
                    for col in 0..cols {
                        for j in 0..kl {
                            b[(i * kl + j) * cols + col] = bt[i * w + col * kl + j];
                        }
                    }
                }
                drop(bt);
                let mut rb = vec![0.0f64; n * cols];
                gemm_into(&view_t(q), &rows(&b, n, cols), &mut rows_mut(&mut rb, n, cols));
                for col in 0..cols {
                    for k in 0..n {
                        coef[k] = rb[k * cols + col];
                    }
                    let (t, ch) = (col % nb, col / nb);
                    // The search starts at the texel's previous channel's lambda (columns go
                    // channel by channel), which is scale-invariant and so close when the
                    // channels differ mostly in brightness; a neighbouring texel's would tie
                    // the result, to the tolerance, to where the blocks start.
                    let hint = if ch > 0 { lambda[t * 3 + ch - 1] } else { 0.0 };
                    lambda[t * 3 + ch] = scratch.solve(&mut coef, &self.d, energy[t * 3 + ch], self.cls, hint);
                    for k in 0..n {
                        rb[k * cols + col] = coef[k];
                    }
                }
                gemm_into(&view(q), &rows(&rb, n, cols), &mut rows_mut(&mut b, n, cols));
                for col in 0..cols {
                    let (t, ch) = (col % nb, col / nb);
                    let dst = &mut out[(t * 3 + ch) * n..(t * 3 + ch + 1) * n];
                    for k in 0..n {
                        dst[k] = b[k * cols + col] as f32;
                    }
                }
            }
        }
    }
}

/// `A = sum over present (v, l) of (yv yv^T) kron (yl yl^T)`, built as
/// `A[(i, j), (i', j')] = sum_v yv_i yv_i' M_v[j, j']` with `M_v = Yl^T diag(mask_v) Yl`:
/// V kl^2 L + V (kv kl)^2 operations instead of V L (kv kl)^2.
fn general_gram(
    yv: &[f64],
    yl: &[f64],
    nv: usize,
    nl: usize,
    kv: usize,
    kl: usize,
    mask: Option<&[bool]>,
) -> DMatrix<f64> {
    let n = kv * kl;
    let mv: Vec<Vec<f64>> = (0..nv)
        .into_par_iter()
        .map(|v| {
            let mut m = vec![0.0f64; kl * kl];
            for l in 0..nl {
                if mask.is_some_and(|mk| !mk[v * nl + l]) {
                    continue;
                }
                let y = &yl[l * kl..(l + 1) * kl];
                for j in 0..kl {
                    for jj in 0..kl {
                        m[j * kl + jj] += y[j] * y[jj];
                    }
                }
            }
            m
        })
        .collect();
    // Row (i, j) of A, in parallel over rows; A is symmetric so row-major == column-major.
    let mut a = vec![0.0f64; n * n];
    a.par_chunks_mut(n).enumerate().for_each(|(r, row)| {
        let (i, j) = (r / kl, r % kl);
        for (v, m) in mv.iter().enumerate() {
            let yvi = yv[v * kv + i];
            if yvi == 0.0 {
                continue;
            }
            let yvr = &yv[v * kv..(v + 1) * kv];
            let mj = &m[j * kl..(j + 1) * kl];
            for ii in 0..kv {
                let s = yvi * yvr[ii];
                for jj in 0..kl {
                    row[ii * kl + jj] += s * mj[jj];
                }
            }
        }
    });
    DMatrix::from_vec(n, n, a)
}
fn check_options(opts: &ShOptions) -> Result<()> {
    check_coeffs("light_coeffs", opts.light_coeffs)?;
    check_coeffs("view_coeffs", opts.view_coeffs)?;
    ensure_arg!(opts.chunk_texels > 0, "chunk_texels", "expected at least 1 texel per chunk, got 0");
    Ok(())
}

/// Fit double SH to the present (view, light) pairs of `btf`; `monitor` counts texels and is
/// checked between chunks.
pub fn fit_sh(btf: &BtfRef<'_>, opts: &ShOptions, monitor: &Monitor) -> Result<Sh> {
    fit_sh_with(btf, opts, monitor, &Knobs::default(), false).map(|(sh, _)| sh)
}

/// [`fit_sh`] with test hooks; `detail` keeps the per-fit lambda and energy bound.
pub(crate) fn fit_sh_with(
    btf: &BtfRef<'_>,
    opts: &ShOptions,
    monitor: &Monitor,
    knobs: &Knobs,
    detail: bool,
) -> Result<(Sh, Option<Detail>)> {
    check_options(opts)?;
    let plan = Plan::new(btf, opts, knobs)?;
    let n = plan.n();
    let texels = btf.texels();
    let abrdf = btf.abrdf_len();
    let mut coeffs = vec![0.0f32; texels * 3 * n];
    let mut kept = Detail::default();
    let (mut constrained, mut lambda_sum) = (0usize, 0.0f64);
    monitor.start(texels as u64);
    let chunk = opts.chunk_texels;
    // Every value is checked as the pass reads it, absent pairs too (`SCANS_VALUES`).
    let scan = TexelScan::new();
    for start in (0..texels).step_by(chunk) {
        monitor.check()?;
        let end = (start + chunk).min(texels);
        let data = &btf.data[start * abrdf..end * abrdf];

        let mut lambda = vec![0.0f64; (end - start) * 3];
        let mut energy = vec![0.0f64; (end - start) * 3];
        coeffs[start * 3 * n..end * 3 * n]
            .par_chunks_mut(BLOCK_TEXELS * 3 * n)
            .zip(lambda.par_chunks_mut(BLOCK_TEXELS * 3))
            .zip(energy.par_chunks_mut(BLOCK_TEXELS * 3))
            .zip(data.par_chunks(BLOCK_TEXELS * abrdf))
            .for_each(|(((out, lam), en), d)| {
                // Checked while the block is in cache, just before its fit reads it.
                if scan.check(d) {
                    plan.block(d, d.len() / abrdf, out, lam, en);
                }
            });
        scan.finish("data", btf.data)?;
        // The energy sums every present value squared: it is not finite exactly when one of
        // the texel's present values is not (absent pairs are never read).
        if let Some(i) = energy.iter().position(|e| !e.is_finite()) {
            let t = start + i / 3;
            return Err(Error::arg(
                "data",
                format!(
                    "texel {t} (row {}, column {}) has a value that is not finite in channel {} at a present \
                     (view, light) pair",
                    t / btf.width,
                    t % btf.width,
                    i % 3
                ),
            ));
        }
        constrained += lambda.iter().filter(|&&l| l > 0.0).count();
        // One running sum in texel order, so that the chunk size cannot change the rounding.
        lambda_sum = lambda.iter().filter(|l| l.is_finite()).fold(lambda_sum, |a, &l| a + l);
        if detail {
            kept.lambda.extend_from_slice(&lambda);
            kept.energy.extend_from_slice(&energy);
        }
        monitor.advance((end - start) as u64);
    }
    monitor.check()?;
    let fits = (texels * 3) as f64;
    let (constrained_fraction, mean_lambda) = (constrained as f64 / fits, lambda_sum / fits);
    let coeffs = if opts.quantize {
        let (q, scale, bias) = quantize(&coeffs, n);
        ShCoeffs::Quantized { q, scale, bias }
    } else {
        ShCoeffs::Float(coeffs)
    };
    let sh = Sh {
        height: btf.height,
        width: btf.width,
        view_coeffs: opts.view_coeffs,
        light_coeffs: opts.light_coeffs,
        coeffs,
        constrained_fraction,
        mean_lambda,
    };
    Ok((sh, detail.then_some(kept)))
}

impl Sh {
    /// Coefficients per colour channel, `kv * kl`.
    fn per_channel(&self) -> usize {
        self.view_coeffs * self.light_coeffs
    }

    /// Check that the arrays agree with the dimensions (for models built from loaded files).
    pub fn validate(&self) -> Result<()> {
        if self.height == 0 || self.width == 0 {
            return Err(Error::arg("coeffs", "the SH model has no texels"));
        }
        check_coeffs("light_coeffs", self.light_coeffs)?;
        check_coeffs("view_coeffs", self.view_coeffs)?;
        let expect = self.height * self.width * 3 * self.per_channel();
        let len = match &self.coeffs {
            ShCoeffs::Float(c) => {
                if let Some(i) = c.iter().position(|x| !x.is_finite()) {
                    return Err(Error::arg("coeffs", format!("coefficient {i} is not finite: {}", c[i])));
                }
                c.len()
            }
            ShCoeffs::Quantized { q, scale, bias } => {
                if !scale.iter().all(|s| s.is_finite() && *s >= 0.0) {
                    return Err(Error::arg("scale", format!("expected finite values >= 0, got {scale:?}")));
                }
                if !bias.iter().all(|b| b.is_finite()) {
                    return Err(Error::arg("bias", format!("expected finite values, got {bias:?}")));
                }
                q.len()
            }
        };
        if len != expect {
            return Err(Error::arg(
                "coeffs",
                format!(
                    "expected {} x {} x 3 x {} x {} = {expect} coefficients, got {len}",
                    self.height, self.width, self.view_coeffs, self.light_coeffs
                ),
            ));
        }
        if !(0.0..=1.0).contains(&self.constrained_fraction) {
            return Err(Error::arg(
                "constrained_fraction",
                format!("expected a fraction in [0, 1], got {}", self.constrained_fraction),
            ));
        }
        if !(self.mean_lambda.is_finite() && self.mean_lambda >= 0.0) {
            return Err(Error::arg("mean_lambda", format!("expected a finite value >= 0, got {}", self.mean_lambda)));
        }
        Ok(())
    }

    /// All coefficients as f32, `[H, W, 3, kv, kl]` (a copy for float models).
    pub fn dequantized(&self) -> Vec<f32> {
        match &self.coeffs {
            ShCoeffs::Float(c) => c.clone(),
            ShCoeffs::Quantized { q, scale, bias } => quantize::dequantize(q, scale, bias, self.per_channel()),
        }
    }
}

/// A prepared query: the products `y_i(view) y_j(light)` in coefficient order, so that a
/// texel's value per channel is one dot product with its coefficients, and
/// `sum(yv) * sum(yl)` (what a per-channel bias contributes to the double sum).
#[derive(Debug, Clone)]
pub struct ShQuery {
    w: Vec<f32>,
    bias_gain: f32,
}

/// `sum_k to_f32(c_k) w_k` with eight independent accumulators (the sums do not wait on each
/// other, and the compiler can map the lanes onto SIMD registers).
#[inline]
fn dot<T: Copy>(c: &[T], w: &[f32], to_f32: impl Fn(T) -> f32) -> f32 {
    let mut acc = [0.0f32; 8];
    let (cc, ww) = (c.chunks_exact(8), w.chunks_exact(8));
    let tail: f32 = cc.remainder().iter().zip(ww.remainder()).map(|(&a, b)| to_f32(a) * b).sum();
    for (a, b) in cc.zip(ww) {
        for k in 0..8 {
            acc[k] += to_f32(a[k]) * b[k];
        }
    }
    acc.iter().sum::<f32>() + tail
}

impl ReflectanceModel for Sh {
    type Query = ShQuery;

    fn dims(&self) -> (usize, usize) {
        (self.height, self.width)
    }

    fn query(&self, view: [f64; 3], light: [f64; 3]) -> ShQuery {
        let mut yv = vec![0.0f64; self.view_coeffs];
        let mut yl = vec![0.0f64; self.light_coeffs];
        sh_basis(self.view_coeffs, view, &mut yv);
        sh_basis(self.light_coeffs, light, &mut yl);
        let bias_gain = (yv.iter().sum::<f64>() * yl.iter().sum::<f64>()) as f32;
        let w = yv.iter().flat_map(|&a| yl.iter().map(move |&b| (a * b) as f32)).collect();
        ShQuery { w, bias_gain }
    }

    #[inline]
    fn eval(&self, t: usize, q: &ShQuery) -> [f32; 3] {
        let pc = self.view_coeffs * self.light_coeffs;
        let mut out = [0.0f32; 3];
        for (ch, o) in out.iter_mut().enumerate() {
            let base = (t * 3 + ch) * pc;
            *o = match &self.coeffs {
                ShCoeffs::Float(c) => dot(&c[base..base + pc], &q.w, |x| x),
                // sum (bias + scale q) yv yl = bias sum(yv) sum(yl) + scale sum q yv yl.
                ShCoeffs::Quantized { q: qc, scale, bias } => {
                    bias[ch] * q.bias_gain + scale[ch] * dot(&qc[base..base + pc], &q.w, |x| x as f32)
                }
            };
        }
        out
    }
}

crate::gpu_params! {
    /// Parameters of `sh.wgsl`.
    pub struct ShParams {
        /// Coefficients over the view direction, kv.
        pub kv: u32,
        /// Coefficients over the light direction, kl.
        pub kl: u32,
        /// Store offset of scale[3] then bias[3] (f32).
        pub scale_bias: u32,
        /// Store offset of the coefficient words: per texel and channel, kv rows of
        /// `ceil(kl / 4)` words, four 8-bit coefficients per word (rows zero padded).
        pub coeffs: u32,
    }
}

/// Repack `[texel][3][kv][kl]` bytes into rows of `ceil(kl / 4)` little-endian words (zero
/// padded), so the shader reads each row with whole-word loads.
pub fn sh_words(q: &[u8], kl: usize) -> Vec<u32> {
    q.chunks_exact(kl).flat_map(crate::gpu::pack_u8).collect()
}

impl GpuLayout for Sh {
    type Params = ShParams;
    const SHADER: Shader = Shader::new::<ShParams>("sh", wgsl::GENERIC);

    fn parts(&self) -> Vec<Cow<'_, [u32]>> {
        // The shader reads 8-bit coefficients; an unquantized model is quantized for the GPU.
        let (q, scale, bias) = match &self.coeffs {
            ShCoeffs::Quantized { q, scale, bias } => (Cow::Borrowed(&q[..]), *scale, *bias),
            ShCoeffs::Float(c) => {
                let (q, s, b) = quantize(c, self.per_channel());
                (Cow::Owned(q), s, b)
            }
        };
        let sb: Vec<u32> = scale.iter().chain(&bias).map(|x| x.to_bits()).collect();
        vec![Cow::Owned(sb), Cow::Owned(sh_words(&q, self.light_coeffs))]
    }

    fn params(&self, offsets: &[u32], _tables: &[u32]) -> ShParams {
        ShParams {
            kv: self.view_coeffs as u32,
            kl: self.light_coeffs as u32,
            scale_bias: offsets[0],
            coeffs: offsets[1],
        }
    }

    /// Straight-line code for this model's `kv x kl` where that pays ([`wgsl`]).
    fn instance_shader(&self) -> Shader {
        wgsl::shader(self.view_coeffs, self.light_coeffs)
    }
}

impl Model for Sh {
    const KIND: &'static str = "sh";
    const TEXEL_ARRAYS: &'static [&'static str] = &["q", "coeffs"];
    const DOC: &'static str = "double spherical harmonics by constrained least squares (paper 002, section 3.1)";
    const ABOUT: &'static str = "\
Real spherical harmonics over the view and over the light direction, `view_coeffs x
light_coeffs` coefficients per texel and channel, fitted by constrained least squares (the
paper's appendix): each fit's coefficient energy is kept within the sampled function's (the
Lagrange multiplier found by Newton's method on the secular equation), which makes the
coefficients robust to the 8-bit quantization that follows (`quantize=false` keeps float32;
`cls=false` is plain least squares, for comparison). Texels are processed `chunk_texels` at a time, so a memory-mapped BTF streams
through. Double-SH models also render under an environment by the SH method (paper 002,
section 4: `btfrs.render(..., environment=env, lighting=\"sh\")`).";
    const OPTIONS: &'static [Spec] = &[
        Spec::int_choice(
            "light_coeffs",
            25,
            SQUARES,
            "SH coefficients over the light direction (a perfect square: degree + 1 squared)",
        ),
        Spec::int_choice(
            "view_coeffs",
            25,
            SQUARES,
            "SH coefficients over the view direction (a perfect square; 1 for a single view)",
        ),
        Spec::bool("cls", true, "constrained least squares (the paper's); false: plain least squares"),
        Spec::bool("quantize", true, "store 8-bit coefficients (a scale and bias per channel); false: float32"),
        Spec::int("chunk_texels", 1024, 1, None, "texels fitted per chunk: the working memory besides the model"),
    ];
    const EXAMPLES: &'static [(&'static str, &'static str)] = &[
        ("SH-CLS 16x16", r#"{"view_coeffs": 16, "light_coeffs": 16}"#),
        ("SH-CLS 25x25", r#"{"view_coeffs": 25, "light_coeffs": 25}"#),
    ];
    const SWEEP: &'static [Setting] = &[
        Setting::full("SH-CLS 9x9", r#"{"light_coeffs": 9, "view_coeffs": 9}"#),
        Setting::quick("SH-CLS 16x16", r#"{"light_coeffs": 16, "view_coeffs": 16}"#),
        Setting::full("SH-CLS 25x25", r#"{"light_coeffs": 25, "view_coeffs": 25}"#),
        Setting::full("SH-CLS 36x36", r#"{"light_coeffs": 36, "view_coeffs": 36}"#),
        Setting::full("SH-CLS 25x25 float", r#"{"light_coeffs": 25, "view_coeffs": 25, "quantize": false}"#)
            .note(FLOAT_NOTE),
        Setting::full("SH-LS 25x25", r#"{"light_coeffs": 25, "view_coeffs": 25, "cls": false}"#),
        Setting::full(
            "SH-LS 25x25 float",
            r#"{"light_coeffs": 25, "view_coeffs": 25, "cls": false, "quantize": false}"#,
        )
        .note(FLOAT_NOTE),
    ];
    const BENCH: &'static [Bench] = &[
        Bench::new("SH-CLS 25x25", r#"{"light_coeffs": 25, "view_coeffs": 25}"#, &["env", "per_material"]),
        Bench::new("SH-CLS 36x25", r#"{"light_coeffs": 36, "view_coeffs": 25}"#, &["models"]),
        Bench::new("SH-LS 25x25 (no CLS)", r#"{"light_coeffs": 25, "view_coeffs": 25, "cls": false}"#, &["models"])
            .peer("sh_numpy_lstsq"),
        Bench::new("SH-CLS 1x{light_coeffs}", r#"{"light_coeffs": [9, 16, 25], "view_coeffs": 1}"#, &["single_view"]),
        Bench::new("SH-CLS 16x16", r#"{"light_coeffs": 16, "view_coeffs": 16}"#, &["tiles"]),
        Bench::new("SH-CLS 25x25", r#"{"light_coeffs": 25, "view_coeffs": 25}"#, &["big"]).note("target <= 1.0 s"),
    ];
    const SAMPLING: Sampling = Sampling::Any { note: "over all pairs", one_view: "view_coeffs=1 for a single view" };
    const MIP: Mip = Mip::Average;
    type Options = ShOptions;
    /// The generic shader and the forms the example sizes draw with (and one with kv != kl);
    /// every size in both forms is validated in rust/btfrs-render/tests/shader_validation.rs.
    fn shaders() -> Vec<Shader> {
        let mut v = vec![<Self as GpuLayout>::SHADER];
        v.extend([(16, 16), (25, 25), (25, 9), (36, 36)].map(|(kv, kl)| wgsl::shader(kv, kl)));
        v
    }
    // The CLS solves each texel alone; only the quantization's scale and bias span all texels.
    // Each value checked as the fit reads it (per block of texels; per view slot for the light bases).
    const SCANS_VALUES: bool = true;
    const BLOCKWISE: crate::blockwise::Blockwise =
        crate::blockwise::Blockwise::Texels { overrides: r#"{"quantize": false}"#, counts: &[] };

    fn fit(btf: &BtfRef<'_>, options: &ShOptions, monitor: &Monitor) -> Result<Self> {
        fit_sh(btf, options, monitor)
    }

    fn mip_texels(&self, groups: &[Vec<(u32, f32)>]) -> Result<Self> {
        average_texels(self, groups)
    }

    /// The dequantized coefficients: the SH domain is linear, so distances there are distances
    /// between the texels' appearances.
    fn coefficient_features(&self) -> Option<Result<CoefficientFeatures>> {
        let data = self.dequantized();
        let dim = data.len() / (self.height * self.width).max(1);
        Some(Ok(CoefficientFeatures { dim, data, label: "sh coefficients" }))
    }

    fn sh_expansion(&self) -> Option<ShExpansion<'_>> {
        Some(ShExpansion {
            view_coeffs: self.view_coeffs,
            light_coeffs: self.light_coeffs,
            coeffs: std::borrow::Cow::Owned(self.dequantized()),
        })
    }

    /// Quantized over the stitched floats of every texel, as `fit_sh`.
    fn finish_blocks(mut self, options: &ShOptions) -> Result<Self> {
        check_options(options)?;
        ensure_arg!(
            (options.view_coeffs, options.light_coeffs) == (self.view_coeffs, self.light_coeffs),
            "options",
            "the blocks were fitted with {} x {} coefficients, the options ask for {} x {}",
            self.view_coeffs,
            self.light_coeffs,
            options.view_coeffs,
            options.light_coeffs
        );
        if let (true, ShCoeffs::Float(c)) = (options.quantize, &self.coeffs) {
            let (q, scale, bias) = quantize(c, self.per_channel());
            self.coeffs = ShCoeffs::Quantized { q, scale, bias };
        }
        Ok(self)
    }

    /// The float coefficients of every texel before they are quantized (4 bytes per stored
    /// byte; none when not quantized: then they are the model), and 16 MB for a chunk of texels'
    /// solver scratch.
    fn least_memory(btf: &BtfRef<'_>, options: &ShOptions) -> u64 {
        let n = (options.view_coeffs * options.light_coeffs) as u64;
        16_000_000 + if options.quantize { 4 * 3 * n * btf.texels() as u64 } else { 0 }
    }

    /// Quantized: `q` `[H, W, 3, kv, kl]` u8 with `scale` and `bias` `[3]` f32; else `coeffs`
    /// `[H, W, 3, kv, kl]` f32.
    fn to_arrays(&self) -> NamedArrays {
        let mut a = NamedArrays::new();
        let shape = [self.height, self.width, 3, self.view_coeffs, self.light_coeffs];
        match &self.coeffs {
            ShCoeffs::Quantized { q, scale, bias } => {
                a.put("q", &shape, q.clone());
                a.put("scale", &[3], scale.to_vec());
                a.put("bias", &[3], bias.to_vec());
            }
            ShCoeffs::Float(c) => a.put("coeffs", &shape, c.clone()),
        }
        a
    }

    fn from_arrays(a: &NamedArrays) -> Result<Self> {
        let shape = [None, None, Some(3), None, None];
        let (coeffs, sh) = if a.contains("q") {
            let (q, sh) = a.get::<u8>("q", &shape)?;
            let (scale, _) = a.get::<f32>("scale", &[Some(3)])?;
            let (bias, _) = a.get::<f32>("bias", &[Some(3)])?;
            check_finite("scale", scale)?;
            check_finite("bias", bias)?;
            let q = ShCoeffs::Quantized {
                q: q.to_vec(),
                scale: [scale[0], scale[1], scale[2]],
                bias: [bias[0], bias[1], bias[2]],
            };
            (q, sh)
        } else {
            let (c, sh) = a.get::<f32>("coeffs", &shape)?;
            check_finite("coeffs", c)?;
            (ShCoeffs::Float(c.to_vec()), sh)
        };
        let m = Sh {
            height: sh[0],
            width: sh[1],
            view_coeffs: sh[3],
            light_coeffs: sh[4],
            coeffs,
            constrained_fraction: 0.0,
            mean_lambda: 0.0,
        };
        m.validate()?;
        Ok(m)
    }

    fn report(&self) -> serde_json::Value {
        serde_json::json!({"constrained_fraction": self.constrained_fraction, "mean_lambda": self.mean_lambda})
    }
}

#[cfg(test)]
mod tests;
