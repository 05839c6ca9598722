//! The numerical core of the Lafortune fit: fast `exp`/`ln`, the per-sample passes that give the
//! cost and the normal equations `J^T J`, `J^T r`, the damped Gauss-Newton (Levenberg-Marquardt)
//! iteration, and the linear initialisation over fixed candidate lobes.
//!
//! Everything here works on *normalised* data (the driver divides a fit's target values by their
//! RMS), so the bounds and tolerances below do not depend on the units of the BTF.
//!
//! Parameter vector `theta` of one fit: `[kd, (Cx, Cy, Cz, ln n) per lobe]` when the diffuse term
//! is fitted, `[(Cx, Cy, Cz, ln n) per lobe]` when it is not (kd is then fixed at 0). The exponent
//! is solved for as `ln n`: a lobe's shape changes with the *ratio* of exponents (n = 2 to 4 is as
//! big a change as 50 to 100), and in `n` itself the Gauss-Newton steps of sharp lobes jump by
//! tens and overflow `s^n`, which cost most of the iterations of fits with several lobes.
//!
//! Samples are stored structure-of-arrays and padded with zeros to a multiple of [`CH`]: a padded
//! sample has `lz = 0` and `s = 0`, hence model 0, target 0, residual 0 and a zero Jacobian row,
//! so the chunk loops need no remainder case and LLVM vectorises them over the samples.

use super::{C_MAX, N_MAX, N_MIN};

/// Samples per chunk of the inner loops.
pub(crate) const CH: usize = 64;
/// The most lobes of one fit (the luminance model's limit).
pub(crate) const MAX_LOBES: usize = 7;
/// The most unknowns of one fit: kd and 4 per lobe.
pub(crate) const MAXM: usize = 1 + 4 * MAX_LOBES;
/// Below this a lobe's cosine `s` counts as zero: the lobe contributes 0 and a zero derivative
/// there (it keeps `ln s` away from subnormals; `s^n <= 1e-300` is nothing anyway).
const S_MIN: f64 = 1e-300;

// ---------------------------------------------------------------------------------------------
// exp and ln
// ---------------------------------------------------------------------------------------------

/// ln 2 rounded to 32 significant bits (fdlibm's `ln2_hi`): `k * LN2_HI` is exact for |k| < 2^21.
const LN2_HI: f64 = f64::from_bits(0x3FE6_2E42_FEE0_0000);
/// ln 2 - LN2_HI (fdlibm's `ln2_lo`).
const LN2_LO: f64 = f64::from_bits(0x3DEA_39EF_3579_3C76);
/// 1.5 * 2^52: adding it rounds a double of magnitude < 2^51 to an integer (round to nearest),
/// and the integer then sits in the low bits of the sum's representation.
const MAGIC: f64 = 6_755_399_441_055_744.0;

/// `a * b + c`, as one fused instruction in the kernels compiled for FMA (`F`), plain otherwise
/// (`mul_add` without hardware FMA would be a slow library call).
#[inline(always)]
fn mad<const F: bool>(a: f64, b: f64, c: f64) -> f64 {
    if F {
        a.mul_add(b, c)
    } else {
        a * b + c
    }
}

/// `exp(x)` for `x` clamped to [-700, 700], relative error below 1e-15, branch-free so that the
/// sample loops vectorise (the libm call is neither inlinable nor vectorisable; the fit evaluates
/// one exp and one ln per sample, lobe and trial step, which dominates its cost).
///
/// Range reduction `x = k ln 2 + r`, `|r| <= ln 2 / 2` (Cody-Waite with a two-part ln 2), then the
/// Taylor polynomial of degree 12 of `exp(r)` (truncation < 1.7e-16 relative), evaluated by
/// Estrin's scheme (dependency depth 5 instead of Horner's 12: the loop is latency-bound), and
/// `2^k` built from its exponent bits.
#[inline(always)]
pub(crate) fn exp_fast<const F: bool>(x: f64) -> f64 {
    let x = x.clamp(-700.0, 700.0);
    let t = mad::<F>(x, std::f64::consts::LOG2_E, MAGIC);
    let k = t - MAGIC;
    let r = mad::<F>(-k, LN2_LO, mad::<F>(-k, LN2_HI, x));
    let r2 = r * r;
    let r4 = r2 * r2;
    let r8 = r4 * r4;
    let p01 = 1.0 + r;
    let p23 = mad::<F>(r, 1.0 / 6.0, 0.5);
    let p45 = mad::<F>(r, 1.0 / 120.0, 1.0 / 24.0);
    let p67 = mad::<F>(r, 1.0 / 5_040.0, 1.0 / 720.0);
    let p89 = mad::<F>(r, 1.0 / 362_880.0, 1.0 / 40_320.0);
    let p1011 = mad::<F>(r, 1.0 / 39_916_800.0, 1.0 / 3_628_800.0);
    let q0 = mad::<F>(r2, p23, p01);
    let q1 = mad::<F>(r2, p67, p45);
    let q2 = mad::<F>(r2, p1011, p89);
    let s0 = mad::<F>(r4, q1, q0);
    let s1 = mad::<F>(r4, 1.0 / 479_001_600.0, q2);
    let p = mad::<F>(r8, s1, s0);
    // |k| <= 1010, so k + 1023 is a valid biased exponent of a normal double.
    let ki = (t.to_bits() as i64).wrapping_sub(MAGIC.to_bits() as i64);
    let scale = f64::from_bits(((ki + 1023) as u64) << 52);
    p * scale
}

/// `ln(x)` for positive normal `x`, relative error below 1e-15 (absolute near x = 1), branch-free.
///
/// `x = 2^e m` with `m` in [sqrt(1/2), sqrt(2)); `ln m = 2 atanh(z)`, `z = (m - 1) / (m + 1)`,
/// `|z| <= 0.1716`, summed as `2 z (1 + z^2/3 + ... + z^18/19)` (truncation < 3e-17) by Estrin's
/// scheme. The exponent is turned into a double with the magic-number trick of [`exp_fast`],
/// because a packed i64 -> f64 conversion does not exist before AVX-512.
#[inline(always)]
pub(crate) fn ln_fast<const F: bool>(x: f64) -> f64 {
    const ONE_BITS: u64 = 0x3FF0_0000_0000_0000;
    const FRAC: u64 = 0x000F_FFFF_FFFF_FFFF;
    let bits = x.to_bits();
    // 2^52 + biased exponent, exactly, then minus (2^52 + 1023).
    let ef = f64::from_bits(0x4330_0000_0000_0000 | (bits >> 52)) - (4_503_599_627_370_496.0 + 1023.0);
    let m = f64::from_bits((bits & FRAC) | ONE_BITS);
    let big = m > std::f64::consts::SQRT_2;
    let m = if big { 0.5 * m } else { m };
    let ef = if big { ef + 1.0 } else { ef };
    let z = (m - 1.0) / (m + 1.0);
    let z2 = z * z;
    let w2 = z2 * z2;
    let w4 = w2 * w2;
    let w8 = w4 * w4;
    let p01 = mad::<F>(z2, 1.0 / 3.0, 1.0);
    let p23 = mad::<F>(z2, 1.0 / 7.0, 1.0 / 5.0);
    let p45 = mad::<F>(z2, 1.0 / 11.0, 1.0 / 9.0);
    let p67 = mad::<F>(z2, 1.0 / 15.0, 1.0 / 13.0);
    let p89 = mad::<F>(z2, 1.0 / 19.0, 1.0 / 17.0);
    let q0 = mad::<F>(w2, p23, p01);
    let q1 = mad::<F>(w2, p67, p45);
    let p = mad::<F>(w8, p89, mad::<F>(w4, q1, q0));
    mad::<F>(ef, LN2_HI, mad::<F>(ef, LN2_LO, 2.0 * z * p))
}

/// Whether this CPU runs the AVX2 + FMA versions of the sample passes (checked once by the
/// standard library and cached). Other architectures always run the portable versions.
#[cfg(target_arch = "x86_64")]
#[inline]
pub(crate) fn have_fma() -> bool {
    std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
}

// ---------------------------------------------------------------------------------------------
// Samples and the passes over them
// ---------------------------------------------------------------------------------------------

/// The per-sample products shared by every texel: `a = lx vx`, `b = ly vy`, `c = lz vz` and the
/// foreshortening `lz`, padded with zeros to a multiple of [`CH`].
#[derive(Debug, Clone)]
pub(crate) struct Geometry {
    /// Real samples (the rest is padding).
    pub n: usize,
    pub a: Vec<f64>,
    pub b: Vec<f64>,
    pub c: Vec<f64>,
    pub lz: Vec<f64>,
}

impl Geometry {
    /// From (view, light) pairs; `lz` is clamped at 0 (a light at or below the horizon sends no
    /// light in, whatever rounding left in its z).
    pub fn new(pairs: impl Iterator<Item = ([f64; 3], [f64; 3])>) -> Self {
        let (mut a, mut b, mut c, mut lz) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for (v, l) in pairs {
            a.push(l[0] * v[0]);
            b.push(l[1] * v[1]);
            c.push(l[2] * v[2]);
            lz.push(l[2].max(0.0));
        }
        let n = a.len();
        let npad = n.div_ceil(CH) * CH;
        for x in [&mut a, &mut b, &mut c, &mut lz] {
            x.resize(npad, 0.0);
        }
        Geometry { n, a, b, c, lz }
    }

    /// Padded length.
    #[inline]
    pub fn npad(&self) -> usize {
        self.a.len()
    }
}

/// The shape of one fit's parameter vector.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Layout {
    /// Whether theta starts with kd.
    pub diffuse: bool,
    /// Lobes.
    pub lobes: usize,
}

impl Layout {
    /// Offset of the first lobe.
    #[inline]
    pub fn off(&self) -> usize {
        usize::from(self.diffuse)
    }
    /// Unknowns.
    #[inline]
    pub fn m(&self) -> usize {
        self.off() + 4 * self.lobes
    }
    /// kd of `theta` (0 when not fitted).
    #[inline]
    pub fn kd(&self, th: &[f64]) -> f64 {
        if self.diffuse {
            th[0]
        } else {
            0.0
        }
    }
}

/// Keep `theta` physical: kd >= 0, |C| <= C_MAX, n in [N_MIN, N_MAX] (ln n in [ln N_MIN, ln N_MAX]). NaN never gets here (the
/// caller rejects non-finite steps), but would be mapped to a bound rather than kept.
pub(crate) fn project(lay: Layout, th: &mut [f64]) {
    if lay.diffuse {
        th[0] = th[0].max(0.0);
    }
    for k in 0..lay.lobes {
        let p = &mut th[lay.off() + 4 * k..lay.off() + 4 * k + 4];
        for x in &mut p[..3] {
            *x = x.clamp(-C_MAX, C_MAX);
        }
        p[3] = p[3].clamp(N_MIN.ln(), N_MAX.ln());
    }
}

/// The bounds of parameter `q` of `lay` (those that [`project`] enforces).
#[inline]
fn bounds(lay: Layout, q: usize) -> (f64, f64) {
    if q < lay.off() {
        (0.0, f64::INFINITY)
    } else if (q - lay.off()) % 4 == 3 {
        (N_MIN.ln(), N_MAX.ln())
    } else {
        (-C_MAX, C_MAX)
    }
}

/// Dot product of two chunks. Portable version: 8 independent partial sums (a sequential sum
/// would not vectorise: LLVM may not reassociate floating-point additions by itself).
#[inline(always)]
fn dot<const F: bool>(x: &[f64; CH], y: &[f64; CH]) -> f64 {
    #[cfg(target_arch = "x86_64")]
    if F {
        // SAFETY: `F` is true only in the kernels compiled with AVX2 and FMA enabled, which run
        // only after `have_fma()` confirmed the CPU has both.
        return unsafe { dot_avx2(x, y) };
    }
    let mut acc = [0.0f64; 8];
    for (xs, ys) in x.as_chunks::<8>().0.iter().zip(y.as_chunks::<8>().0) {
        for k in 0..8 {
            acc[k] = mad::<F>(xs[k], ys[k], acc[k]);
        }
    }
    ((acc[0] + acc[1]) + (acc[2] + acc[3])) + ((acc[4] + acc[5]) + (acc[6] + acc[7]))
}

/// [`dot`] with AVX2 intrinsics: four 4-lane FMA chains. LLVM's own vectorisation of the
/// portable version shuffles lanes across the fully unrolled chunk and runs 3x slower; the
/// `J^T J` accumulation is most of the cost of an accepted LM step.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline]
fn dot_avx2(x: &[f64; CH], y: &[f64; CH]) -> f64 {
    use std::arch::x86_64::*;
    const { assert!(CH.is_multiple_of(16)) };
    let (px, py) = (x.as_ptr(), y.as_ptr());
    let mut acc = [_mm256_setzero_pd(); 4];
    for j in (0..CH).step_by(16) {
        for (k, a) in acc.iter_mut().enumerate() {
            // SAFETY: j + 4 k + 3 < CH, so the 4 loaded values lie inside both arrays.
            let (xv, yv) = unsafe { (_mm256_loadu_pd(px.add(j + 4 * k)), _mm256_loadu_pd(py.add(j + 4 * k))) };
            *a = _mm256_fmadd_pd(xv, yv, *a);
        }
    }
    let s = _mm256_add_pd(_mm256_add_pd(acc[0], acc[1]), _mm256_add_pd(acc[2], acc[3]));
    let t = _mm_add_pd(_mm256_castpd256_pd128(s), _mm256_extractf128_pd::<1>(s));
    _mm_cvtsd_f64(_mm_add_sd(t, _mm_unpackhi_pd(t, t)))
}

/// Per-fit scratch: the target values and, per sample and lobe, `s^n` and `ln s` of the last
/// cost pass, which the Jacobian pass reuses (an accepted step then costs no second exp/ln).
#[derive(Debug, Clone, Default)]
pub(crate) struct Work {
    /// Targets, padded with zeros.
    pub y: Vec<f64>,
    /// `s^n` per (chunk, lobe, sample in chunk).
    e: Vec<f64>,
    /// `ln s` likewise (0 where s <= 0).
    l: Vec<f64>,
}

impl Work {
    pub fn new(npad: usize, lobes: usize) -> Self {
        Work { y: vec![0.0; npad], e: vec![0.0; npad * lobes], l: vec![0.0; npad * lobes] }
    }
}

/// Sum of squared residuals at `th`; fills `w.e`, `w.l` for [`normal_equations`]. Non-finite when
/// `th` makes the model overflow (then the step is rejected).
pub(crate) fn cost(g: &Geometry, lay: Layout, th: &[f64], w: &mut Work) -> f64 {
    #[cfg(target_arch = "x86_64")]
    if have_fma() {
        // SAFETY: the CPU supports AVX2 and FMA (checked just above), all that `cost_fma` needs.
        return unsafe { cost_fma(g, lay, th, w) };
    }
    cost_impl::<false>(g, lay, th, w)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn cost_fma(g: &Geometry, lay: Layout, th: &[f64], w: &mut Work) -> f64 {
    cost_impl::<true>(g, lay, th, w)
}

/// [`cost`] for kernels compiled with (`F`) or without FMA.
#[inline(always)]
pub(crate) fn cost_impl<const F: bool>(g: &Geometry, lay: Layout, th: &[f64], w: &mut Work) -> f64 {
    let kd = lay.kd(th);
    let nl = lay.lobes;
    let mut acc = [0.0f64; CH];
    let mut s = [0.0f64; CH];
    let (a, b, c) = (g.a.as_chunks::<CH>().0, g.b.as_chunks::<CH>().0, g.c.as_chunks::<CH>().0);
    let (lz, y) = (g.lz.as_chunks::<CH>().0, w.y.as_chunks::<CH>().0);
    let mut es = w.e.as_chunks_mut::<CH>().0.iter_mut();
    let mut ls = w.l.as_chunks_mut::<CH>().0.iter_mut();
    for ((((aj, bj), cj), lzj), yj) in a.iter().zip(b).zip(c).zip(lz).zip(y) {
        let mut sum = [kd; CH];
        for k in 0..nl {
            let p = &th[lay.off() + 4 * k..lay.off() + 4 * k + 4];
            let (cx, cy, cz, n) = (p[0], p[1], p[2], p[3].exp());
            let (Some(e), Some(l)) = (es.next(), ls.next()) else {
                return f64::NAN; // Work holds npad * lobes entries: unreachable
            };
            // Four short loops rather than one long one: each iteration of a fused loop is a
            // dependency chain of ~100 instructions (ln, then exp), too long for the out-of-order
            // window to overlap many of them; split, the iterations of each stage are independent
            // and short (15% faster in a micro-benchmark of this loop).
            for i in 0..CH {
                s[i] = mad::<F>(cx, aj[i], mad::<F>(cy, bj[i], cz * cj[i]));
            }
            // Branch-free: evaluate at max(s, S_MIN) and mask the result to 0 where s <= S_MIN
            // (a branch or a select around exp would keep the loops from vectorising).
            for i in 0..CH {
                l[i] = ln_fast::<F>(s[i].max(S_MIN));
            }
            for i in 0..CH {
                e[i] = exp_fast::<F>(n * l[i]);
            }
            for i in 0..CH {
                let mask = if s[i] > S_MIN { u64::MAX } else { 0 };
                e[i] = f64::from_bits(e[i].to_bits() & mask);
                l[i] = f64::from_bits(l[i].to_bits() & mask);
                sum[i] += e[i];
            }
        }
        for i in 0..CH {
            let r = mad::<F>(lzj[i], sum[i], -yj[i]);
            acc[i] = mad::<F>(r, r, acc[i]);
        }
    }
    acc.iter().sum()
}

/// `J^T J` (full `m x m`, row-major) and `J^T r` at the `th` of the last [`cost`] call, from the
/// `s^n` and `ln s` it stored. With `v = lz (kd + sum_k s_k^n_k)` and `r = v - y`:
///
/// ```text
/// dv/dkd = lz
/// dv/dCx_k = lz n_k s_k^(n_k - 1) lx vx   (likewise Cy with ly vy, Cz with lz vz)
/// dv/d(ln n_k) = lz n_k s_k^n_k ln s_k
/// ```
///
/// and 0 for a lobe whose `s_k <= 0`. J itself is only ever held one chunk at a time.
pub(crate) fn normal_equations(g: &Geometry, lay: Layout, th: &[f64], w: &Work, jtj: &mut [f64], jtr: &mut [f64]) {
    #[cfg(target_arch = "x86_64")]
    if have_fma() {
        // SAFETY: the CPU supports AVX2 and FMA (checked just above).
        return unsafe { normal_equations_fma(g, lay, th, w, jtj, jtr) };
    }
    normal_equations_impl::<false>(g, lay, th, w, jtj, jtr)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn normal_equations_fma(g: &Geometry, lay: Layout, th: &[f64], w: &Work, jtj: &mut [f64], jtr: &mut [f64]) {
    normal_equations_impl::<true>(g, lay, th, w, jtj, jtr)
}

/// [`normal_equations`] for kernels compiled with (`F`) or without FMA.
#[inline(always)]
pub(crate) fn normal_equations_impl<const F: bool>(
    g: &Geometry,
    lay: Layout,
    th: &[f64],
    w: &Work,
    jtj: &mut [f64],
    jtr: &mut [f64],
) {
    let m = lay.m();
    let (off, nl) = (lay.off(), lay.lobes);
    let kd = lay.kd(th);
    jtj[..m * m].iter_mut().for_each(|x| *x = 0.0);
    jtr[..m].iter_mut().for_each(|x| *x = 0.0);
    let mut rows = [[0.0f64; CH]; MAXM];
    let mut r = [0.0f64; CH];
    let (a, b, c) = (g.a.as_chunks::<CH>().0, g.b.as_chunks::<CH>().0, g.c.as_chunks::<CH>().0);
    let (lz, y) = (g.lz.as_chunks::<CH>().0, w.y.as_chunks::<CH>().0);
    let mut es = w.e.as_chunks::<CH>().0.iter();
    let mut ls = w.l.as_chunks::<CH>().0.iter();
    for ((((aj, bj), cj), lzj), yj) in a.iter().zip(b).zip(c).zip(lz).zip(y) {
        let mut sum = [kd; CH];
        for k in 0..nl {
            let p = &th[off + 4 * k..off + 4 * k + 4];
            let (cx, cy, cz, n) = (p[0], p[1], p[2], p[3].exp());
            let (Some(e), Some(l)) = (es.next(), ls.next()) else {
                return; // Work holds npad * lobes entries: unreachable
            };
            let Some([rx, ry, rz, rn]) = rows[off + 4 * k..].first_chunk_mut::<4>() else {
                return; // m = off + 4 lobes rows exist by construction
            };
            for i in 0..CH {
                let s = mad::<F>(cx, aj[i], mad::<F>(cy, bj[i], cz * cj[i]));
                // e = 0 wherever s <= S_MIN, so the safe divisor only avoids 0/0 there.
                let gi = lzj[i] * n * e[i] / s.max(S_MIN);
                rx[i] = gi * aj[i];
                ry[i] = gi * bj[i];
                rz[i] = gi * cj[i];
                rn[i] = lzj[i] * n * e[i] * l[i];
                sum[i] += e[i];
            }
        }
        if lay.diffuse {
            rows[0] = *lzj;
        }
        for i in 0..CH {
            r[i] = mad::<F>(lzj[i], sum[i], -yj[i]);
        }
        for q in 0..m {
            jtr[q] += dot::<F>(&rows[q], &r);
            for u in q..m {
                jtj[q * m + u] += dot::<F>(&rows[q], &rows[u]);
            }
        }
    }
    for q in 0..m {
        for u in 0..q {
            jtj[q * m + u] = jtj[u * m + q];
        }
    }
}

/// In-place Cholesky solve of the symmetric positive definite `a` (m x m, row-major, overwritten)
/// with right-hand side `x` (overwritten by the solution). `false` if `a` is not positive definite.
pub(crate) fn cholesky_solve(a: &mut [f64], m: usize, x: &mut [f64]) -> bool {
    for j in 0..m {
        let mut d = a[j * m + j];
        for k in 0..j {
            d -= a[j * m + k] * a[j * m + k];
        }
        if !(d > 0.0 && d.is_finite()) {
            return false;
        }
        let d = d.sqrt();
        a[j * m + j] = d;
        for i in j + 1..m {
            let mut s = a[i * m + j];
            for k in 0..j {
                s -= a[i * m + k] * a[j * m + k];
            }
            a[i * m + j] = s / d;
        }
    }
    for i in 0..m {
        let mut s = x[i];
        for k in 0..i {
            s -= a[i * m + k] * x[k];
        }
        x[i] = s / a[i * m + i];
    }
    for i in (0..m).rev() {
        let mut s = x[i];
        for k in i + 1..m {
            s -= a[k * m + i] * x[k];
        }
        x[i] = s / a[i * m + i];
    }
    x[..m].iter().all(|v| v.is_finite())
}

// ---------------------------------------------------------------------------------------------
// Levenberg-Marquardt
// ---------------------------------------------------------------------------------------------

/// Stop when an accepted step lowers the cost by less than this fraction.
pub(crate) const REL_DECREASE: f64 = 1e-7;
/// Stop when the step is shorter than this times |theta| (plus the same absolute amount).
const SMALL_STEP: f64 = 1e-9;
/// Give up (not converged) once the damping exceeds this: no descent direction was found.
const LAMBDA_MAX: f64 = 1e16;

/// The decrease of the cost that the Gauss-Newton model predicts for step `d`:
/// `-(2 d . J^T r + d . J^T J d)`.
fn predicted_decrease(jtj: &[f64], jtr: &[f64], d: &[f64], m: usize) -> f64 {
    let mut pred = 0.0;
    for q in 0..m {
        let mut jd = 0.0;
        for u in 0..m {
            jd += jtj[q * m + u] * d[u];
        }
        pred -= d[q] * (2.0 * jtr[q] + jd);
    }
    pred
}

/// How one LM run ended.
#[derive(Debug, Clone, Copy)]
pub(crate) struct LmRun {
    /// Final cost (finite unless the start already was not).
    pub cost: f64,
    /// Trial steps taken, accepted or not.
    pub iters: usize,
    /// Stopped by the relative-decrease or small-step criterion (or an exact fit).
    pub converged: bool,
}

/// Levenberg-Marquardt from `th` (projected first): Marquardt's diagonal scaling, floored so that
/// a lobe that has gone dark (all its `s <= 0`, a zero column) stays solvable; Nielsen's damping
/// update (tenfold more after a wild overshoot); parameters held on a bound they are pushed
/// against (active set); every trial projected onto the bounds. A trial whose cost is not finite
/// or not lower is rejected and costs only a [`cost`] pass.
///
/// Converged: an accepted step lowers the cost by less than [`REL_DECREASE`] (relative), or a
/// rejected one was predicted to gain less than that (MINPACK's ftol test), or the step is
/// negligible, or the cost is 0. Not converged: `max_iter` trial steps, the damping passes
/// `LAMBDA_MAX` (no descent found), a non-finite start or normal equations.
pub(crate) fn levenberg_marquardt(
    g: &Geometry,
    lay: Layout,
    th: &mut [f64],
    lambda0: f64,
    max_iter: usize,
    w: &mut Work,
) -> LmRun {
    let m = lay.m();
    project(lay, th);
    let mut c = cost(g, lay, th, w);
    if !c.is_finite() {
        return LmRun { cost: c, iters: 0, converged: false };
    }
    let (mut jtj, mut jtr) = ([0.0f64; MAXM * MAXM], [0.0f64; MAXM]);
    normal_equations(g, lay, th, w, &mut jtj, &mut jtr);
    let (mut lambda, mut nu) = (lambda0, 2.0f64);
    let mut a = [0.0f64; MAXM * MAXM];
    let mut delta = [0.0f64; MAXM];
    let mut trial = [0.0f64; MAXM];
    for it in 1..=max_iter {
        if c == 0.0 {
            return LmRun { cost: c, iters: it - 1, converged: true };
        }
        let dmax = (0..m).map(|q| jtj[q * m + q]).fold(0.0f64, f64::max);
        if !jtj[..m * m].iter().chain(&jtr[..m]).all(|x| x.is_finite()) {
            return LmRun { cost: c, iters: it - 1, converged: false };
        }
        if dmax <= 0.0 {
            // No parameter moves the model at any sample: nothing left to fit.
            return LmRun { cost: c, iters: it - 1, converged: true };
        }
        a[..m * m].copy_from_slice(&jtj[..m * m]);
        for q in 0..m {
            a[q * m + q] += lambda * jtj[q * m + q].max(1e-12 * dmax);
            delta[q] = -jtr[q];
        }
        // Active set: a parameter on a bound that the descent direction pushes further out is
        // held fixed for this step. Solving for it and clipping afterwards would leave the other
        // components computed for a move that does not happen, and LM would crawl along the bound
        // with most steps rejected.
        for q in 0..m {
            let (lo, hi) = bounds(lay, q);
            if (th[q] <= lo && jtr[q] > 0.0) || (th[q] >= hi && jtr[q] < 0.0) {
                for u in 0..m {
                    a[q * m + u] = 0.0;
                    a[u * m + q] = 0.0;
                }
                a[q * m + q] = 1.0;
                delta[q] = 0.0;
            }
        }
        if !cholesky_solve(&mut a[..m * m], m, &mut delta[..m]) {
            lambda *= nu;
            nu *= 2.0;
            if lambda > LAMBDA_MAX {
                return LmRun { cost: c, iters: it, converged: false };
            }
            continue;
        }
        for q in 0..m {
            trial[q] = th[q] + delta[q];
        }
        project(lay, &mut trial[..m]);
        // The step actually taken (after projection) and its size.
        let mut step2 = 0.0;
        let mut th2 = 0.0;
        for q in 0..m {
            delta[q] = trial[q] - th[q];
            step2 += delta[q] * delta[q];
            th2 += th[q] * th[q];
        }
        if step2.sqrt() <= SMALL_STEP * (th2.sqrt() + SMALL_STEP) {
            return LmRun { cost: c, iters: it, converged: true };
        }
        let c_new = cost(g, lay, &trial[..m], w);
        if c_new.is_finite() && c_new < c {
            // Gain ratio: actual over the Gauss-Newton model's predicted decrease.
            let pred = predicted_decrease(&jtj, &jtr, &delta, m);
            let rho = if pred > 0.0 { (c - c_new) / pred } else { 1.0 };
            let rel = (c - c_new) / c;
            th[..m].copy_from_slice(&trial[..m]);
            c = c_new;
            normal_equations(g, lay, th, w, &mut jtj, &mut jtr);
            lambda *= (1.0 - (2.0 * rho - 1.0).powi(3)).max(1.0 / 3.0);
            lambda = lambda.max(1e-12);
            nu = 2.0;
            if rel < REL_DECREASE {
                return LmRun { cost: c, iters: it, converged: true };
            }
        } else {
            // MINPACK's ftol test: when the Gauss-Newton model itself predicts less than the
            // tolerance and the step does not do better, the cost is at its minimum to that
            // precision (near it, rounding makes the tiny predicted gains fail to materialise).
            if predicted_decrease(&jtj, &jtr, &delta, m) < REL_DECREASE * c
                && c_new.is_finite()
                && c_new - c <= REL_DECREASE * c
            {
                return LmRun { cost: c, iters: it, converged: true };
            }
            // A wild overshoot (overflow, or several times the cost) says the damping is far too
            // low, not a little: raise it tenfold on top of Nielsen's factor, which saves a
            // rejected trial or two each time a sharp lobe's step overflows s^n.
            if c_new.is_nan() || c_new >= 4.0 * c {
                lambda *= 10.0;
            }
            lambda *= nu;
            nu *= 2.0;
            if lambda > LAMBDA_MAX {
                return LmRun { cost: c, iters: it, converged: false };
            }
        }
    }
    LmRun { cost: c, iters: max_iter, converged: false }
}

// ---------------------------------------------------------------------------------------------
// Initialisation over fixed candidate lobes
// ---------------------------------------------------------------------------------------------

/// Candidate lobe shapes `(Cx, Cy, Cz, n)` with unit amplitude: specular (`C = (-1, -1, 1)`,
/// `s = l . reflect(v)`), retro-reflective (`C = (1, 1, 1)`, `s = l . v`) and a lobe around the
/// normal (`C = (0, 0, 1)`, `s = lz vz`), at a few exponents.
pub(crate) const CANDIDATES: [[f64; 4]; 10] = [
    [-1.0, -1.0, 1.0, 2.0],
    [-1.0, -1.0, 1.0, 8.0],
    [-1.0, -1.0, 1.0, 32.0],
    [-1.0, -1.0, 1.0, 128.0],
    [1.0, 1.0, 1.0, 2.0],
    [1.0, 1.0, 1.0, 8.0],
    [1.0, 1.0, 1.0, 32.0],
    [0.0, 0.0, 1.0, 1.0],
    [0.0, 0.0, 1.0, 4.0],
    [0.0, 0.0, 1.0, 16.0],
];
/// Basis functions of the linear initialisation: the diffuse `lz` and the candidates.
pub(crate) const NB: usize = 1 + CANDIDATES.len();

/// The candidate basis evaluated once at every sample, `[NB][npad]`, and its Gram matrix.
#[derive(Debug, Clone)]
pub(crate) struct Basis {
    pub f: Vec<f64>,
    pub gram: [[f64; NB]; NB],
}

impl Basis {
    pub fn new(g: &Geometry) -> Self {
        let np = g.npad();
        let mut f = vec![0.0f64; NB * np];
        f[..np].copy_from_slice(&g.lz);
        for (k, cand) in CANDIDATES.iter().enumerate() {
            let row = &mut f[(k + 1) * np..(k + 2) * np];
            for (i, x) in row[..g.n].iter_mut().enumerate() {
                let s = cand[0] * g.a[i] + cand[1] * g.b[i] + cand[2] * g.c[i];
                *x = if s > 0.0 { g.lz[i] * s.powf(cand[3]) } else { 0.0 };
            }
        }
        let mut gram = [[0.0f64; NB]; NB];
        for p in 0..NB {
            for q in p..NB {
                let d: f64 = f[p * np..(p + 1) * np].iter().zip(&f[q * np..(q + 1) * np]).map(|(x, y)| x * y).sum();
                gram[p][q] = d;
                gram[q][p] = d;
            }
        }
        Basis { f, gram }
    }

    /// `F^T y` for the padded targets `y`.
    pub fn fty(&self, y: &[f64]) -> [f64; NB] {
        let np = y.len();
        let mut out = [0.0f64; NB];
        for (p, o) in out.iter_mut().enumerate() {
            let row = &self.f[p * np..(p + 1) * np];
            let mut acc = [0.0f64; 8];
            for (xs, ys) in row.as_chunks::<8>().0.iter().zip(y.as_chunks::<8>().0) {
                for k in 0..8 {
                    acc[k] += xs[k] * ys[k];
                }
            }
            *o = acc.iter().sum();
        }
        out
    }
}

/// Greedy forward selection of candidate lobes by linear least squares (kd included when
/// `diffuse`), each amplitude and kd required non-negative. Returns, for `l = 1..=lobes`, the
/// starting theta with `l` lobes. A slot for which no candidate gives a valid fit gets the next
/// unused candidate at a small amplitude (1e-3 of the normalised data), so that LM can still
/// grow it (a lobe at exactly zero has a zero gradient and would never move).
pub(crate) fn initial_guesses(basis: &Basis, fty: &[f64; NB], diffuse: bool, lobes: usize) -> Vec<[f64; MAXM]> {
    let mut chosen: Vec<usize> = if diffuse { vec![0] } else { Vec::new() };
    let mut out = Vec::with_capacity(lobes);
    let mut sol: Vec<f64> = Vec::new();
    if diffuse {
        let g0 = basis.gram[0][0];
        sol.push(if g0 > 0.0 { (fty[0] / g0).max(0.0) } else { 0.0 });
    }
    let mut seeds: Vec<usize> = Vec::new();
    for _ in 0..lobes {
        let mut best: Option<(f64, usize, Vec<f64>)> = None;
        for k in 1..NB {
            if chosen.contains(&k) {
                continue;
            }
            let idx: Vec<usize> = chosen.iter().copied().chain([k]).collect();
            let q = idx.len();
            let mut a = vec![0.0f64; q * q];
            let mut x: Vec<f64> = idx.iter().map(|&i| fty[i]).collect();
            for (r, &i) in idx.iter().enumerate() {
                for (s, &j) in idx.iter().enumerate() {
                    a[r * q + s] = basis.gram[i][j];
                }
            }
            if !cholesky_solve(&mut a, q, &mut x) {
                continue;
            }
            let ok = idx.iter().zip(&x).all(|(&i, &v)| if i == 0 { v >= 0.0 } else { v > 0.0 });
            if !ok {
                continue;
            }
            // Residual sum of squares minus the constant y^T y: -x . F^T y at the LS solution.
            let score = -idx.iter().zip(&x).map(|(&i, v)| v * fty[i]).sum::<f64>();
            if best.as_ref().is_none_or(|b| score < b.0) {
                best = Some((score, k, x));
            }
        }
        match best {
            Some((_, k, x)) => {
                chosen.push(k);
                sol = x;
            }
            None => {
                let k = (1..NB).find(|k| !chosen.contains(k) && !seeds.contains(k)).unwrap_or(1);
                seeds.push(k);
            }
        }
        out.push(theta_from(&chosen, &sol, &seeds, diffuse));
    }
    out
}

/// theta from the chosen basis indices (0 = kd), their amplitudes and the seeded candidates.
fn theta_from(chosen: &[usize], sol: &[f64], seeds: &[usize], diffuse: bool) -> [f64; MAXM] {
    let mut th = [0.0f64; MAXM];
    let mut at = usize::from(diffuse);
    for (&i, &amp) in chosen.iter().zip(sol) {
        if i == 0 {
            th[0] = amp;
            continue;
        }
        put_lobe(&mut th[at..at + 4], CANDIDATES[i - 1], amp);
        at += 4;
    }
    for &k in seeds {
        put_lobe(&mut th[at..at + 4], CANDIDATES[k - 1], 1e-3);
        at += 4;
    }
    th
}

/// A lobe of shape `cand` scaled by `amp`: `amp (u . p)^n = (amp^(1/n) u . p)^n`.
fn put_lobe(p: &mut [f64], cand: [f64; 4], amp: f64) {
    let s = amp.powf(1.0 / cand[3]);
    p[0] = cand[0] * s;
    p[1] = cand[1] * s;
    p[2] = cand[2] * s;
    p[3] = cand[3].ln();
}
