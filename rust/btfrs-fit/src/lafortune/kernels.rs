//! The math kernels of the Lafortune fit (paper 000, section 3.2): fast `exp`/`ln`, the lobe
//! model evaluated over all samples (the cost), its Jacobian accumulated into the normal
//! equations `J^T J`, `J^T r`, and a small Cholesky solve. The Levenberg-Marquardt loop that
//! drives them is in `lm.rs`, the linear initialisation in `init.rs`.
//!
//! Everything here works on *normalised* data (the driver divides a fit's target values by their
//! RMS), so the bounds and tolerances do not depend on the units of the BTF.
//!
//! Parameter vector `theta` of one fit: `[kd, (Cx, Cy, Cz, ln n) per lobe]` when the diffuse term
//! is fitted, `[(Cx, Cy, Cz, ln n) per lobe]` when it is not (kd is then fixed at 0). The exponent
//! is solved for as `ln n`: a lobe's shape changes with the *ratio* of exponents (n = 2 to 4 is as
//! big a change as 50 to 100), and in `n` itself the Gauss-Newton steps of sharp lobes jump by
//! tens and overflow `s^n`, which cost most of the iterations of fits with several lobes.
//!
//! Samples are stored structure-of-arrays and padded with zeros to a multiple of [`CH`]: a padded
//! sample has `lz = 0` and `s = 0`, hence model 0, target 0, residual 0 and a zero Jacobian row,
//! so the chunk loops need no remainder case and LLVM vectorises them over the samples. Each pass
//! is compiled twice, portable and with AVX2 + FMA, and picks one at run time ([`have_fma`]).

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

/// Whether this CPU runs the AVX-512 versions of the sample passes (twice the vector width of
/// AVX2); `BTFRS_NO_AVX512` set in the environment turns them off (for comparisons).
#[cfg(target_arch = "x86_64")]
#[inline]
pub(crate) fn have_avx512() -> bool {
    static OK: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *OK.get_or_init(|| {
        std::arch::is_x86_feature_detected!("avx512f")
            && std::arch::is_x86_feature_detected!("avx512dq")
            && std::arch::is_x86_feature_detected!("avx512vl")
            && have_fma()
            && std::env::var_os("BTFRS_NO_AVX512").is_none()
    })
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

/// Lanes of the partial sums that [`dot_lanes`] and [`gram_block`] keep across the chunks of a
/// pass: each lane sums every eighth product, and the lanes are added only once at the end
/// ([`lane_sum`]), instead of reducing a vector to one number for every chunk and product (74
/// reductions per chunk of a two-lobe Newton step).
pub(crate) const LANES: usize = 8;
/// The side of the square blocks in which [`gram_chunk`] accumulates `J^T J`.
const TILE: usize = 4;
/// One block of the Gram matrix: `TILE x TILE` entries of [`LANES`] partial sums each.
pub(crate) type Tile = [[f64; LANES]; TILE * TILE];
/// Rows of one chunk's Jacobian and residual (the residual as the row after the parameters),
/// padded with zero rows to whole tiles.
const ROWS: usize = (MAXM + 1).next_multiple_of(TILE);

/// The blocks of the upper triangle of the Gram matrix of `rows` Jacobian and residual rows
/// ([`blocks`]).
pub(crate) fn gram_tiles(rows: usize) -> usize {
    let nb = rows.div_ceil(TILE);
    nb * (nb + 1) / 2
}

/// The lanes of `v` added up, in a fixed order (the same at every call, so the result does not
/// depend on which kernel produced the lanes' layout).
#[inline(always)]
fn lane_sum(v: &[f64; LANES]) -> f64 {
    ((v[0] + v[1]) + (v[2] + v[3])) + ((v[4] + v[5]) + (v[6] + v[7]))
}

/// Adds the products `x[i] y[i]` of one chunk into the [`LANES`] partial sums `acc` (lane `i %
/// 8` for the portable and AVX-512 kernels; the AVX2 kernel uses lanes 0-3). Written as lanes
/// rather than one running sum because LLVM may not reassociate floating-point additions by
/// itself, and a single chain would not vectorise.
#[inline(always)]
fn dot_lanes<const F: bool, const Z: bool>(x: &[f64; CH], y: &[f64; CH], acc: &mut [f64; LANES]) {
    #[cfg(target_arch = "x86_64")]
    if Z {
        // SAFETY: `Z` is true only in the kernels compiled with AVX-512, which run only after
        // `have_avx512()` confirmed the CPU has it.
        return unsafe { dot_lanes_avx512(x, y, acc) };
    }
    #[cfg(target_arch = "x86_64")]
    if F {
        // SAFETY: `F` is true only in the kernels compiled with AVX2 and FMA enabled, which run
        // only after `have_fma()` confirmed the CPU has both.
        return unsafe { dot_lanes_avx2(x, y, acc) };
    }
    for (xs, ys) in x.as_chunks::<LANES>().0.iter().zip(y.as_chunks::<LANES>().0) {
        for k in 0..LANES {
            acc[k] = mad::<F>(xs[k], ys[k], acc[k]);
        }
    }
}

/// [`dot_lanes`] with AVX2 intrinsics: four 4-lane FMA chains, added into lanes 0-3. LLVM's own
/// vectorisation of the portable version shuffles lanes across the fully unrolled chunk and
/// runs 3x slower.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline]
fn dot_lanes_avx2(x: &[f64; CH], y: &[f64; CH], acc: &mut [f64; LANES]) {
    use std::arch::x86_64::*;
    const { assert!(CH.is_multiple_of(16)) };
    let (px, py) = (x.as_ptr(), y.as_ptr());
    let mut t = [_mm256_setzero_pd(); 4];
    for j in (0..CH).step_by(16) {
        for (k, a) in t.iter_mut().enumerate() {
            // SAFETY: j + 4 k + 3 < CH, so the 4 loaded values lie inside both arrays.
            let (xv, yv) = unsafe { (_mm256_loadu_pd(px.add(j + 4 * k)), _mm256_loadu_pd(py.add(j + 4 * k))) };
            *a = _mm256_fmadd_pd(xv, yv, *a);
        }
    }
    let s = _mm256_add_pd(_mm256_add_pd(t[0], t[1]), _mm256_add_pd(t[2], t[3]));
    // SAFETY: `acc` holds 8 >= 4 values.
    unsafe { _mm256_storeu_pd(acc.as_mut_ptr(), _mm256_add_pd(_mm256_loadu_pd(acc.as_ptr()), s)) };
}

/// [`dot_lanes`] with AVX-512 intrinsics: two 8-lane FMA chains.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[inline]
fn dot_lanes_avx512(x: &[f64; CH], y: &[f64; CH], acc: &mut [f64; LANES]) {
    use std::arch::x86_64::*;
    const { assert!(CH.is_multiple_of(16)) };
    let (px, py) = (x.as_ptr(), y.as_ptr());
    let mut t = [_mm512_setzero_pd(); 2];
    for j in (0..CH).step_by(16) {
        for (k, a) in t.iter_mut().enumerate() {
            // SAFETY: j + 8 k + 7 < CH, so the 8 loaded values lie inside both arrays.
            let (xv, yv) = unsafe { (_mm512_loadu_pd(px.add(j + 8 * k)), _mm512_loadu_pd(py.add(j + 8 * k))) };
            *a = _mm512_fmadd_pd(xv, yv, *a);
        }
    }
    // SAFETY: `acc` holds the 8 values one vector loads and stores.
    unsafe {
        let s = _mm512_add_pd(_mm512_loadu_pd(acc.as_ptr()), _mm512_add_pd(t[0], t[1]));
        _mm512_storeu_pd(acc.as_mut_ptr(), s);
    }
}

/// The row blocks of the Gram matrix of `rows` Jacobian and residual rows: `TILE` rows each, the
/// last one 2 (a fit has `4 lobes + 1` or `+ 2` of them; an odd count is padded with a zero row).
fn blocks(rows: usize) -> impl Iterator<Item = (usize, usize)> {
    let n = rows.next_multiple_of(2);
    (0..n).step_by(TILE).map(move |q0| (q0, TILE.min(n - q0)))
}

/// Adds the products of rows `q0..q0 + TQ` with rows `u0..u0 + TU` of one chunk into `tile`
/// (entry `4 a + b` for rows `q0 + a`, `u0 + b`), as [`dot_lanes`] would for each pair; `DIAG`:
/// the block on the diagonal (`q0 = u0`), of which only the upper triangle is computed. The
/// point of a block: each loaded vector of samples serves up to four products instead of one,
/// so the `J^T J` accumulation (45 products for two lobes and kd) is no longer bound by the
/// loads, which two dot products per pair were (two loads for each multiply-add).
#[inline(always)]
fn gram_block<const F: bool, const Z: bool, const TQ: usize, const TU: usize, const DIAG: bool>(
    rows: &[[f64; CH]; ROWS],
    q0: usize,
    u0: usize,
    tile: &mut Tile,
) {
    let (Some(qr), Some(ur)) = (rows[q0..].first_chunk::<TQ>(), rows[u0..].first_chunk::<TU>()) else {
        return; // blocks() stays inside ROWS, a multiple of TILE: unreachable
    };
    #[cfg(target_arch = "x86_64")]
    if Z {
        // SAFETY: as in `dot_lanes`.
        return unsafe { gram_block_avx512::<TQ, TU, DIAG>(qr, ur, tile) };
    }
    for a in 0..TQ {
        for b in 0..TU {
            if !DIAG || b >= a {
                dot_lanes::<F, Z>(&qr[a], &ur[b], &mut tile[TILE * a + b]);
            }
        }
    }
}

/// [`gram_block`] with AVX-512 intrinsics: up to 16 accumulators of 8 lanes, `TQ + TU` loads
/// for up to `TQ TU` multiply-adds.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[inline]
fn gram_block_avx512<const TQ: usize, const TU: usize, const DIAG: bool>(
    qr: &[[f64; CH]; TQ],
    ur: &[[f64; CH]; TU],
    tile: &mut Tile,
) {
    use std::arch::x86_64::*;
    let mut t = [_mm512_setzero_pd(); TILE * TILE];
    for j in (0..CH).step_by(8) {
        // SAFETY: j + 7 < CH, so every load lies inside its row.
        let qv: [__m512d; TQ] = std::array::from_fn(|a| unsafe { _mm512_loadu_pd(qr[a].as_ptr().add(j)) });
        let uv: [__m512d; TU] = std::array::from_fn(|b| unsafe { _mm512_loadu_pd(ur[b].as_ptr().add(j)) });
        for a in 0..TQ {
            for b in 0..TU {
                if !DIAG || b >= a {
                    t[TILE * a + b] = _mm512_fmadd_pd(qv[a], uv[b], t[TILE * a + b]);
                }
            }
        }
    }
    for a in 0..TQ {
        for b in 0..TU {
            if !DIAG || b >= a {
                let acc = &mut tile[TILE * a + b];
                // SAFETY: each entry holds the 8 values one vector loads and stores.
                unsafe {
                    _mm512_storeu_pd(acc.as_mut_ptr(), _mm512_add_pd(_mm512_loadu_pd(acc.as_ptr()), t[TILE * a + b]))
                };
            }
        }
    }
}

/// One chunk's products of every pair of rows of `rows` (the `m1` Jacobian and residual rows)
/// added into `gram`, block by block ([`blocks`]) in the upper triangle.
#[inline(always)]
fn gram_chunk<const F: bool, const Z: bool>(rows: &[[f64; CH]; ROWS], m1: usize, gram: &mut [Tile]) {
    let mut t = 0;
    for (q0, tq) in blocks(m1) {
        for (u0, tu) in blocks(m1).filter(|&(u0, _)| u0 >= q0) {
            let tile = &mut gram[t];
            match (tq, tu, q0 == u0) {
                (4, 4, true) => gram_block::<F, Z, 4, 4, true>(rows, q0, u0, tile),
                (4, 4, false) => gram_block::<F, Z, 4, 4, false>(rows, q0, u0, tile),
                (4, _, false) => gram_block::<F, Z, 4, 2, false>(rows, q0, u0, tile),
                _ => gram_block::<F, Z, 2, 2, true>(rows, q0, u0, tile),
            }
            t += 1;
        }
    }
}

/// Per-fit scratch: the target values and, per sample and lobe, `s^n` and `ln s` of the last
/// cost pass, which the Jacobian pass reuses (an accepted step then costs no second exp/ln).
#[derive(Debug, Clone, Default)]
pub(crate) struct Work {
    /// Targets, padded with zeros.
    pub y: Vec<f64>,
    /// The scratch of the coarse start on a subset of the samples (made on first use).
    pub sub: Option<Box<Work>>,
    /// `s^n` per (chunk, lobe, sample in chunk).
    e: Vec<f64>,
    /// `ln s` likewise (0 where s <= 0).
    l: Vec<f64>,
    /// The lane sums of `J^T J` and `J^T r`, by blocks ([`gram_chunk`]).
    gram: Vec<Tile>,
    /// The lane sums of the second-order term, 10 per lobe.
    second: Vec<[f64; LANES]>,
}

impl Work {
    pub fn new(npad: usize, lobes: usize) -> Self {
        Work {
            y: vec![0.0; npad],
            sub: None,
            e: vec![0.0; npad * lobes],
            l: vec![0.0; npad * lobes],
            // kd, 4 per lobe and the residual.
            gram: vec![[[0.0; LANES]; TILE * TILE]; gram_tiles(4 * lobes + 2)],
            second: vec![[0.0; LANES]; 10 * lobes],
        }
    }
}

/// Sum of squared residuals at `th`; fills `w.e`, `w.l` for [`normal_equations`]. Non-finite when
/// `th` makes the model overflow (then the step is rejected).
pub(crate) fn cost(g: &Geometry, lay: Layout, th: &[f64], w: &mut Work) -> f64 {
    #[cfg(target_arch = "x86_64")]
    if have_avx512() {
        // SAFETY: the CPU supports AVX-512 F/DQ/VL, AVX2 and FMA (checked just above).
        return unsafe { cost_avx512(g, lay, th, w) };
    }
    #[cfg(target_arch = "x86_64")]
    if have_fma() {
        // SAFETY: the CPU supports AVX2 and FMA (checked just above), all that `cost_fma` needs.
        return unsafe { cost_fma(g, lay, th, w) };
    }
    cost_impl::<false>(g, lay, th, w)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512dq,avx512vl,avx2,fma")]
fn cost_avx512(g: &Geometry, lay: Layout, th: &[f64], w: &mut Work) -> f64 {
    cost_impl::<true>(g, lay, th, w)
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
// The Gauss-Newton part alone: the tests, and fits built on these kernels that do not take
// Newton steps, call it.
#[cfg_attr(not(test), allow(dead_code))]
pub(crate) fn normal_equations(g: &Geometry, lay: Layout, th: &[f64], w: &mut Work, jtj: &mut [f64], jtr: &mut [f64]) {
    normal_equations_with(g, lay, th, w, jtj, jtr, None)
}

/// [`normal_equations`] and, when `second` is given, the second-order part of the Hessian of the
/// cost, `S = sum_i r_i d^2 v_i / d theta^2` (full `m x m`, row-major; the cost's Hessian is
/// `2 (J^T J + S)`). Only the 4 x 4 block of each lobe is non-zero (the model is a sum of lobes
/// and linear in kd): with `g = lz n s^(n-1)` and the sample products `(a, b, c)`,
///
/// ```text
/// d^2 v / dC_p dC_q   = lz n (n - 1) s^(n-2) p q
/// d^2 v / dC_p d ln n = g p (1 + n ln s)
/// d^2 v / d(ln n)^2   = lz n s^n ln s (1 + n ln s)
/// ```
///
/// Gauss-Newton drops `S`, which converges only linearly on these fits: their residuals are large
/// (shadows and masking leave 30-50% of the signal unexplained by any lobe), so `S` is not small.
pub(crate) fn normal_equations_with(
    g: &Geometry,
    lay: Layout,
    th: &[f64],
    w: &mut Work,
    jtj: &mut [f64],
    jtr: &mut [f64],
    second: Option<&mut [f64]>,
) {
    #[cfg(target_arch = "x86_64")]
    if have_avx512() {
        // SAFETY: the CPU supports AVX-512 F/DQ/VL, AVX2 and FMA (checked just above).
        return unsafe { normal_equations_avx512(g, lay, th, w, jtj, jtr, second) };
    }
    #[cfg(target_arch = "x86_64")]
    if have_fma() {
        // SAFETY: the CPU supports AVX2 and FMA (checked just above).
        return unsafe { normal_equations_fma(g, lay, th, w, jtj, jtr, second) };
    }
    normal_equations_impl::<false, false>(g, lay, th, w, jtj, jtr, second)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512dq,avx512vl,avx2,fma")]
fn normal_equations_avx512(
    g: &Geometry,
    lay: Layout,
    th: &[f64],
    w: &mut Work,
    jtj: &mut [f64],
    jtr: &mut [f64],
    second: Option<&mut [f64]>,
) {
    normal_equations_impl::<true, true>(g, lay, th, w, jtj, jtr, second)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn normal_equations_fma(
    g: &Geometry,
    lay: Layout,
    th: &[f64],
    w: &mut Work,
    jtj: &mut [f64],
    jtr: &mut [f64],
    second: Option<&mut [f64]>,
) {
    normal_equations_impl::<true, false>(g, lay, th, w, jtj, jtr, second)
}

/// [`normal_equations_with`] for kernels compiled with (`F`) or without FMA, and with AVX-512
/// (`Z`, which implies `F`).
#[inline(always)]
pub(crate) fn normal_equations_impl<const F: bool, const Z: bool>(
    g: &Geometry,
    lay: Layout,
    th: &[f64],
    w: &mut Work,
    jtj: &mut [f64],
    jtr: &mut [f64],
    second: Option<&mut [f64]>,
) {
    let m = lay.m();
    let (off, nl) = (lay.off(), lay.lobes);
    let kd = lay.kd(th);
    // The Gram matrix of the m Jacobian rows and the residual (row m), by tiles of lane sums.
    let m1 = m + 1;
    let tiles = gram_tiles(m1);
    if w.gram.len() < tiles || w.second.len() < 10 * nl {
        w.gram.resize(tiles, [[0.0; LANES]; TILE * TILE]);
        w.second.resize(10 * nl, [0.0; LANES]);
    }
    let Work { y, e, l, gram, second: sacc, .. } = w;
    let gram = &mut gram[..tiles];
    let sacc = &mut sacc[..10 * nl];
    gram.iter_mut().for_each(|t| *t = [[0.0; LANES]; TILE * TILE]);
    sacc.iter_mut().for_each(|v| *v = [0.0; LANES]);
    // Rows past the residual stay zero: they pad the last tiles.
    let mut rows = [[0.0f64; CH]; ROWS];
    // Per lobe, `lz n s^(n-2)` (0 where s <= S_MIN): the second derivatives' common factor.
    let mut g2 = [[0.0f64; CH]; MAX_LOBES];
    let (mut r1, mut px, mut py, mut pz) = ([0.0f64; CH], [0.0f64; CH], [0.0f64; CH], [0.0f64; CH]);
    let (a, b, c) = (g.a.as_chunks::<CH>().0, g.b.as_chunks::<CH>().0, g.c.as_chunks::<CH>().0);
    let (lz, y) = (g.lz.as_chunks::<CH>().0, y.as_chunks::<CH>().0);
    let mut es = e.as_chunks::<CH>().0.iter();
    let mut ls = l.as_chunks::<CH>().0.iter();
    for ((((aj, bj), cj), lzj), yj) in a.iter().zip(b).zip(c).zip(lz).zip(y) {
        let mut sum = [kd; CH];
        let mut lobe_l = [&[0.0f64; CH]; MAX_LOBES];
        for k in 0..nl {
            let p = &th[off + 4 * k..off + 4 * k + 4];
            let (cx, cy, cz, n) = (p[0], p[1], p[2], p[3].exp());
            let (Some(e), Some(l)) = (es.next(), ls.next()) else {
                return; // Work holds npad * lobes entries: unreachable
            };
            lobe_l[k] = l;
            let Some([rx, ry, rz, rn]) = rows[off + 4 * k..].first_chunk_mut::<4>() else {
                return; // m = off + 4 lobes rows exist by construction
            };
            let g2k = &mut g2[k];
            for i in 0..CH {
                let s = mad::<F>(cx, aj[i], mad::<F>(cy, bj[i], cz * cj[i]));
                // e = 0 wherever s <= S_MIN, so the safe divisor only avoids 0/0 there. One
                // division: 1 / s serves the first and the second derivatives.
                let inv = 1.0 / s.max(S_MIN);
                let gi = lzj[i] * n * e[i] * inv;
                g2k[i] = gi * inv;
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
        let r = &mut rows[m];
        for i in 0..CH {
            r[i] = mad::<F>(lzj[i], sum[i], -yj[i]);
        }
        if second.is_some() {
            let r = &rows[m];
            for k in 0..nl {
                let n = th[off + 4 * k + 3].exp();
                let l = lobe_l[k];
                let [rx, ry, rz, rn] =
                    [&rows[off + 4 * k], &rows[off + 4 * k + 1], &rows[off + 4 * k + 2], &rows[off + 4 * k + 3]];
                for i in 0..CH {
                    // lz n (n-1) s^(n-2), times the residual; 0 wherever s <= S_MIN.
                    let q = r[i] * (n - 1.0) * g2[k][i];
                    px[i] = q * aj[i];
                    py[i] = q * bj[i];
                    pz[i] = q * cj[i];
                    r1[i] = r[i] * mad::<F>(n, l[i], 1.0);
                }
                let Some(s) = sacc[10 * k..].first_chunk_mut::<10>() else {
                    return; // 10 per lobe by construction: unreachable
                };
                dot_lanes::<F, Z>(&px, aj, &mut s[0]);
                dot_lanes::<F, Z>(&px, bj, &mut s[1]);
                dot_lanes::<F, Z>(&px, cj, &mut s[2]);
                dot_lanes::<F, Z>(&py, bj, &mut s[3]);
                dot_lanes::<F, Z>(&py, cj, &mut s[4]);
                dot_lanes::<F, Z>(&pz, cj, &mut s[5]);
                dot_lanes::<F, Z>(&r1, rx, &mut s[6]);
                dot_lanes::<F, Z>(&r1, ry, &mut s[7]);
                dot_lanes::<F, Z>(&r1, rz, &mut s[8]);
                dot_lanes::<F, Z>(&r1, rn, &mut s[9]);
            }
        }
        gram_chunk::<F, Z>(&rows, m1, gram);
    }
    let mut t = 0;
    for (q0, _) in blocks(m1) {
        for (u0, _) in blocks(m1).filter(|&(u0, _)| u0 >= q0) {
            for i in 0..TILE {
                for j in 0..TILE {
                    let (q, u) = (q0 + i, u0 + j);
                    if q <= u && q < m && u < m1 {
                        let v = lane_sum(&gram[t][TILE * i + j]);
                        if u < m {
                            jtj[q * m + u] = v;
                            jtj[u * m + q] = v;
                        } else {
                            jtr[q] = v;
                        }
                    }
                }
            }
            t += 1;
        }
    }
    if let Some(sm) = second {
        sm[..m * m].iter_mut().for_each(|x| *x = 0.0);
        const BLOCK: [(usize, usize); 10] =
            [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2), (0, 3), (1, 3), (2, 3), (3, 3)];
        for k in 0..nl {
            let o = off + 4 * k;
            for (&(u, v), x) in BLOCK.iter().zip(&sacc[10 * k..10 * k + 10]) {
                let x = lane_sum(x);
                sm[(o + u) * m + o + v] = x;
                sm[(o + v) * m + o + u] = x;
            }
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
