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
//! `|c(lambda)|^2 = sum_k b~_k^2 / (d_k + lambda)^2`, which decreases monotonically in lambda:
//! a safeguarded Newton iteration on the secular equation finds lambda in `O(k)` per step.
//! [`Solver`] does that per (texel, channel), on rotated right-hand sides the caller computes in
//! batches.

/// Relative width of the bracket at which the search for lambda stops (1e-6 is asked).
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
    /// contributes nothing even where `d_k + lambda = 0`), and `sum b~_k^2 / (d_k + lambda)^3`
    /// (minus half its derivative). Four independent partial sums, so that the divisions run as
    /// SIMD lanes instead of one long dependency chain.
    #[inline]
    fn norm2_slope(&self, lambda: f64) -> (f64, f64) {
        let (mut acc, mut acc3) = ([0.0f64; 4], [0.0f64; 4]);
        let (bb, dd) = (self.b2.chunks_exact(4), self.d.chunks_exact(4));
        let (mut tail, mut tail3) = (0.0, 0.0);
        for (&b2, &d) in bb.remainder().iter().zip(dd.remainder()) {
            let r = 1.0 / (d + lambda);
            tail += b2 * r * r;
            tail3 += b2 * r * r * r;
        }
        for (b, d) in bb.zip(dd) {
            for k in 0..4 {
                let r = 1.0 / (d[k] + lambda);
                let q = b[k] * r * r;
                acc[k] += q;
                acc3[k] += q * r;
            }
        }
        (acc[0] + acc[1] + acc[2] + acc[3] + tail, acc3[0] + acc3[1] + acc3[2] + acc3[3] + tail3)
    }

    fn norm2(&self, lambda: f64) -> f64 {
        self.norm2_slope(lambda).0
    }

    /// Replace `coef` (the rotated `b~`) by `c~ = b~ / (d + lambda)` and return lambda: 0 for
    /// plain least squares or when the least-squares solution meets `||c||^2 <= energy`,
    /// otherwise the smallest lambda that meets it (to 1e-6 relative, on the feasible side).
    /// `hint` (0 for none) is where the search starts: a neighbouring fit's lambda saves
    /// steps; it does not change the result beyond the tolerance.
    pub fn solve(&mut self, coef: &mut [f64], d: &[f64], energy: f64, cls: bool, hint: f64) -> f64 {
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
            self.multiplier(energy, hint)
        };
        for (c, &dk) in coef.iter_mut().zip(d) {
            let den = dk + lambda;
            *c = if *c == 0.0 || den <= 0.0 { 0.0 } else { *c / den };
        }
        lambda
    }

    /// The smallest lambda > 0 with `norm2(lambda) <= energy`, given `norm2(0) > energy > 0`,
    /// to `LAMBDA_RTOL` relative, on the feasible side.
    ///
    /// The root is bracketed first. With `B = sum b~^2` and the eigenvalues in `[d_min, d_max]`,
    /// `B / (d_max + lambda)^2 <= norm2(lambda) <= B / (d_min + lambda)^2`, and every term alone
    /// gives `norm2(lambda) >= b~_k^2 / (d_k + lambda)^2`; so the root lies in
    /// `[max(sqrt(B / E) - d_max, max_k sqrt(b~_k^2 / E) - d_k, 0), sqrt(B / E) - d_min]`.
    ///
    /// Then Newton's method on `phi(lambda) = 1 / sqrt(norm2(lambda)) - 1 / sqrt(E)` from the
    /// infeasible end (the secular equation of the trust-region subproblem, solved as Moré and
    /// Sorensen, 1983, do): `phi` is concave and nearly linear for `lambda > -d_min`, so each
    /// step from below lands below the root and the iterates rise to it quadratically, in a
    /// handful of steps where bisection took 25 to 40 (from a hint, Newton's first step lands
    /// below the root too, concavity again). A step that leaves the bracket (rounding)
    /// is replaced by a bisection step, and once a step is shorter than the tolerance the
    /// iterate is pushed just past the root to close the bracket.
    fn multiplier(&self, energy: f64, hint: f64) -> f64 {
        let (mut dmin, mut dmax, mut bsum, mut lo) = (f64::INFINITY, 0.0f64, 0.0f64, 0.0f64);
        for (&b2, &d) in self.b2.iter().zip(&self.d) {
            dmin = dmin.min(d);
            dmax = dmax.max(d);
            bsum += b2;
            lo = lo.max((b2 / energy).sqrt() - d);
        }
        let root = (bsum / energy).sqrt();
        lo = lo.max(root - dmax);
        let mut hi = (root - dmin).max(root * 1e-3);
        for _ in 0..64 {
            // The bound holds exactly; this only absorbs rounding.
            if self.norm2(hi) <= energy {
                break;
            }
            hi *= 2.0;
        }
        // Start at the hint when it lies inside the bracket (a neighbouring texel's lambda is
        // usually within tens of percent of this one's), else at the infeasible end.
        let mut x = if hint > lo && hint < hi { hint } else { lo };
        let (mut n, mut s3) = self.norm2_slope(x);
        if x == lo && n.partial_cmp(&energy) != Some(std::cmp::Ordering::Greater) {
            // `lo` is infeasible in exact arithmetic, so this is rounding only (and `lo > 0`:
            // `norm2(0) > energy` is the precondition).
            return lo;
        }
        for _ in 0..200 {
            if n > energy {
                lo = x;
            } else {
                hi = x;
            }
            if hi <= lo * (1.0 + LAMBDA_RTOL) {
                break;
            }
            // Newton's step on phi (positive from the infeasible side, negative from the
            // feasible one, landing below the root either way), kept inside the bracket; a step
            // within the tolerance is pushed just across the root to close the bracket.
            let step = n * ((n / energy).sqrt() - 1.0) / s3;
            let mut next = x + step;
            if next > lo && next < hi && step.abs() <= 0.5 * LAMBDA_RTOL * next {
                next = x * if n > energy { 1.0 + 0.5 * LAMBDA_RTOL } else { 1.0 - 0.5 * LAMBDA_RTOL };
            }
            if !(next > lo && next < hi) {
                next = if lo > 0.0 { (lo * hi).sqrt() } else { hi * 1e-3 };
            }
            x = next;
            (n, s3) = self.norm2_slope(x);
        }
        hi
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `||c(lambda)||^2` in plain f64, independent of the solver's lanes.
    fn norm2(b: &[f64], d: &[f64], lambda: f64) -> f64 {
        b.iter().zip(d).filter(|(&b, _)| b != 0.0).map(|(&b, &d)| b * b / ((d + lambda) * (d + lambda))).sum()
    }

    /// A reference lambda by plain bisection to 1e-12 relative (a few hundred steps).
    fn reference(b: &[f64], d: &[f64], energy: f64) -> f64 {
        let (mut lo, mut hi) = (0.0f64, 1.0f64);
        while norm2(b, d, hi) > energy {
            hi *= 2.0;
        }
        for _ in 0..2000 {
            let mid = 0.5 * (lo + hi);
            if norm2(b, d, mid) > energy {
                lo = mid;
            } else {
                hi = mid;
            }
            if hi - lo <= 1e-12 * hi {
                break;
            }
        }
        hi
    }

    /// Seeded problems like the double-SH fit's: eigenvalues spanning 1e-16 to 1e3 relative
    /// (exact zeros included), right-hand sides of mixed sizes, energy bounds from far below
    /// the least-squares norm to just below it. The multiplier is the bisection reference's
    /// to 1e-6 relative, on the feasible side, and the coefficients are `b / (d + lambda)`.
    #[test]
    fn multiplier_matches_a_bisection_reference() {
        let mut rng = btfrs_core::rng::Rng::new(7);
        let mut uniform = move || rng.next_f64();
        let mut solver = Solver::new(64);
        let mut active = 0;
        for case in 0..400 {
            let n = 1 + (uniform() * 63.0) as usize;
            let d: Vec<f64> = (0..n)
                .map(|k| if case % 5 == 0 && k % 7 == 3 { 0.0 } else { 10f64.powf(3.0 - 19.0 * uniform()) })
                .collect();
            let b: Vec<f64> = (0..n)
                .map(|k| if k % 11 == 5 { 0.0 } else { (uniform() - 0.5) * 10f64.powf(2.0 * uniform() - 1.0) })
                .collect();
            let ls = norm2(&b, &d, 0.0);
            let target = if ls.is_finite() { ls } else { b.iter().map(|x| x * x).sum::<f64>() * 1e6 };
            let energy = target * 10f64.powf(-8.0 * uniform()) * 0.999;
            let mut c = b.clone();
            let hint = if case % 3 == 0 { 0.0 } else { reference(&b, &d, energy) * 10f64.powf(2.0 * uniform() - 1.0) };
            let lambda = solver.solve(&mut c, &d, energy, true, hint);
            if ls.is_finite() && ls <= energy {
                assert_eq!(lambda, 0.0, "case {case}");
                continue;
            }
            active += 1;
            let want = reference(&b, &d, energy);
            assert!((lambda / want - 1.0).abs() < 1e-6, "case {case}: lambda {lambda} vs reference {want}");
            assert!(
                norm2(&b, &d, lambda) <= energy * (1.0 + 1e-12),
                "case {case}: infeasible {} vs {energy}, lambda {lambda} ref {want}",
                norm2(&b, &d, lambda)
            );
            for k in 0..n {
                let w = if b[k] == 0.0 { 0.0 } else { b[k] / (d[k] + lambda) };
                assert!((c[k] - w).abs() <= 1e-12 * w.abs(), "case {case} coefficient {k}");
            }
        }
        assert!(active > 300, "only {active} constrained cases");
    }
}
