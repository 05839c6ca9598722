//! Constrained least squares (paper 002, appendix): the solver that keeps the double-SH fit of
//! double SH (`btfrs_fit::sh`) well posed on hemispherical data.
//!
//! A least-squares fit `min |Y c - beta|^2` whose samples leave some combinations of the basis
//! unconstrained (SH over the full sphere fitted to upper-hemisphere data) puts large coefficients
//! of opposite sign into combinations that nearly cancel at the samples; they reproduce the data
//! but amplify any perturbation, such as quantization. The appendix bounds the coefficient energy
//! by the energy `E` of the sampled function:
//!
//! ```text
//! min |Y c - beta|^2  subject to  c^T c <= E
//!   =>  c = (A + lambda I)^-1 b,   A = Y^T Y,   b = Y^T beta,
//!       lambda = 0 if the unconstrained solution meets the bound,
//!       else the lambda > 0 with c^T c = E
//! ```
//!
//! (the Lagrange condition of the constrained problem). With the eigendecomposition
//! `A = Q D Q^T`, shared by every texel because `A` depends only on the directions, and the
//! rotated right-hand side `b~ = Q^T b`, the solution is `c~ = b~ / (d + lambda)` and
//! `|c(lambda)|^2 = sum_k b~_k^2 / (d_k + lambda)^2`, which decreases monotonically in lambda: a
//! bisection in log space finds lambda in `O(k)` per step. [`Solver`] does that per (texel,
//! channel), on rotated right-hand sides the caller computes in batches.

/// Relative width at which the bisection for lambda stops (the brief asks for 1e-6).
const LAMBDA_RTOL: f64 = 1e-7;

/// One constrained least-squares solve at a time in the eigenbasis of `A`, with reusable scratch
/// (one per thread: a fit calls [`Solver::solve`] once per texel and colour channel).
#[derive(Debug)]
pub struct Solver {
    /// Squared rotated right-hand sides and eigenvalues of the nonzero entries.
    b2: Vec<f64>,
    d: Vec<f64>,
}

impl Solver {
    pub fn new(n: usize) -> Self {
        Solver { b2: Vec::with_capacity(n), d: Vec::with_capacity(n) }
    }

    /// `||c(lambda)||^2 = sum b~_k^2 / (d_k + lambda)^2` over the nonzero `b~_k` (a zero one
    /// contributes nothing even where `d_k + lambda = 0`). Four independent partial sums, so
    /// that the divisions run as SIMD lanes instead of one long dependency chain.
    #[inline]
    fn norm2(&self, lambda: f64) -> f64 {
        let mut acc = [0.0f64; 4];
        let (bb, dd) = (self.b2.chunks_exact(4), self.d.chunks_exact(4));
        let tail: f64 =
            bb.remainder().iter().zip(dd.remainder()).map(|(&b2, &d)| b2 / ((d + lambda) * (d + lambda))).sum();
        for (b, d) in bb.zip(dd) {
            for k in 0..4 {
                let den = d[k] + lambda;
                acc[k] += b[k] / (den * den);
            }
        }
        acc[0] + acc[1] + acc[2] + acc[3] + tail
    }

    /// Replace `coef` (the rotated `b~`) by `c~ = b~ / (d + lambda)` and return lambda: 0 for
    /// plain least squares or when the least-squares solution meets `||c||^2 <= energy`,
    /// otherwise the smallest lambda that meets it (to 1e-6 relative, on the feasible side).
    pub fn solve(&mut self, coef: &mut [f64], d: &[f64], energy: f64, cls: bool) -> f64 {
        self.b2.clear();
        self.d.clear();
        for (&b, &dk) in coef.iter().zip(d) {
            if b != 0.0 {
                self.b2.push(b * b);
                self.d.push(dk);
            }
        }
        let lambda = if !cls || self.b2.is_empty() || self.norm2(0.0) <= energy {
            0.0
        } else if energy.is_nan() || energy <= 0.0 {
            // Nonzero data with no quadrature weight (pathological direction sets only): the
            // only coefficients within a zero energy bound are zeros.
            coef.iter_mut().for_each(|c| *c = 0.0);
            return f64::INFINITY;
        } else {
            self.bisect(energy)
        };
        for (c, &dk) in coef.iter_mut().zip(d) {
            let den = dk + lambda;
            *c = if *c == 0.0 || den <= 0.0 { 0.0 } else { *c / den };
        }
        lambda
    }

    /// The smallest lambda > 0 with `norm2(lambda) <= energy`, given `norm2(0) > energy > 0`.
    ///
    /// With `B = sum b~^2` and the eigenvalues in `[d_min, d_max]`,
    /// `B / (d_max + lambda)^2 <= norm2(lambda) <= B / (d_min + lambda)^2`, so the root lies in
    /// `[sqrt(B / E) - d_max, sqrt(B / E) - d_min]`: that bracket (or, when its lower end is not
    /// positive, one found by stepping down from its upper end by factors of 1e3) is bisected in
    /// log space until its ends agree to 1e-7 relative; the feasible end is returned.
    fn bisect(&self, energy: f64) -> f64 {
        let (dmin, dmax) = self.d.iter().fold((f64::INFINITY, 0.0f64), |(a, b), &d| (a.min(d), b.max(d)));
        let root = (self.b2.iter().sum::<f64>() / energy).sqrt();
        let mut hi = (root - dmin).max(root * 1e-3);
        for _ in 0..64 {
            // The bound holds exactly; this only absorbs rounding.
            if self.norm2(hi) <= energy {
                break;
            }
            hi *= 2.0;
        }
        let mut lo = root - dmax;
        if !(lo > 0.0 && lo < hi && self.norm2(lo) > energy) {
            let mut found = false;
            for _ in 0..110 {
                lo = hi * 1e-3;
                if self.norm2(lo) > energy {
                    found = true;
                    break;
                }
                hi = lo;
            }
            if !found {
                // norm2(0) exceeds the bound by a rounding error only: the tiny hi is the answer.
                return hi;
            }
        }
        for _ in 0..64 {
            if hi <= lo * (1.0 + LAMBDA_RTOL) {
                break;
            }
            let mid = (lo * hi).sqrt();
            if self.norm2(mid) > energy {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        hi
    }
}
