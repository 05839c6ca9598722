//! The Levenberg-Marquardt iteration that fits one texel's Lafortune lobes (paper 000, section
//! 3.2), with the parameter bounds it keeps.
//!
//! One run starts from a theta of `init.rs` and calls the kernels of `kernels.rs` for the cost and
//! the normal equations; the restarts and the fallbacks of a fit are decided by the driver in
//! `lafortune.rs`.

use super::kernels::{cholesky_solve, cost, normal_equations_with, Geometry, Layout, Work, MAXM};
use super::{C_MAX, N_MAX, N_MIN};

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

/// Stop when an accepted step lowers the cost by less than this fraction.
pub(crate) const REL_DECREASE: f64 = 1e-7;
/// Stop when the step is shorter than this times |theta| (plus the same absolute amount).
const SMALL_STEP: f64 = 1e-9;
/// Give up (not converged) once the damping exceeds this: no descent direction was found.
const LAMBDA_MAX: f64 = 1e16;

/// The decrease of the cost that the quadratic model with Hessian `H` (`J^T J`, or `J^T J + S`)
/// predicts for step `d`: `-(2 d . J^T r + d . H d)`.
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
/// a lobe that has gone dark (all its `s <= 0`, a zero column) stays solvable; the step's model
/// Hessian is the full one, `J^T J + S` (`S` the residual-weighted second derivatives of the
/// model, [`normal_equations_with`]), falling back to Gauss-Newton's `J^T J` for a step where the
/// damped full Hessian is not positive definite; Nielsen's damping
/// update (tenfold more after a wild overshoot); parameters held on a bound they are pushed
/// against (active set); every trial projected onto the bounds. A trial whose cost is not finite
/// or not lower is rejected and costs only a [`cost`] pass.
///
/// Converged: an accepted step lowers the cost by less than `tol` (relative), or a
/// rejected one was predicted to gain less than that (MINPACK's ftol test), or the step is
/// negligible, or the cost is 0. Not converged: `max_iter` trial steps, the damping passes
/// `LAMBDA_MAX` (no descent found), a non-finite start or normal equations.
///
/// `tol`: the relative-decrease tolerance (the fits use [`REL_DECREASE`] or a looser one).
/// `newton`: full Newton steps as above, or Gauss-Newton ones (`J^T J` alone, the more
/// conservative model of the restarts).
#[allow(clippy::too_many_arguments)]
pub(crate) fn levenberg_marquardt_tol(
    g: &Geometry,
    lay: Layout,
    th: &mut [f64],
    lambda0: f64,
    max_iter: usize,
    w: &mut Work,
    tol: f64,
    newton_steps: bool,
) -> LmRun {
    let m = lay.m();
    project(lay, th);
    let mut c = cost(g, lay, th, w);
    if !c.is_finite() {
        return LmRun { cost: c, iters: 0, converged: false };
    }
    let (mut jtj, mut jtr) = ([0.0f64; MAXM * MAXM], [0.0f64; MAXM]);
    // The Hessian model of the step: J^T J + S (Newton) when S is available and finite.
    let mut hes = [0.0f64; MAXM * MAXM];
    // Newton: J^T J + S when S came out finite (`false`: hes is J^T J alone).
    let newton = |th: &[f64],
                  w: &mut Work,
                  jtj: &mut [f64; MAXM * MAXM],
                  jtr: &mut [f64; MAXM],
                  hes: &mut [f64; MAXM * MAXM]|
     -> bool {
        if !newton_steps {
            normal_equations_with(g, lay, th, w, jtj, jtr, None);
            hes[..m * m].copy_from_slice(&jtj[..m * m]);
            return false;
        }
        normal_equations_with(g, lay, th, w, jtj, jtr, Some(&mut hes[..]));
        let ok = hes[..m * m].iter().all(|x| x.is_finite());
        for q in 0..m * m {
            hes[q] = if ok { jtj[q] + hes[q] } else { jtj[q] };
        }
        ok
    };
    let mut have_s = newton(th, w, &mut jtj, &mut jtr, &mut hes);
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
        let mut solved = false;
        let mut used_s = false;
        for try_s in [true, false] {
            if try_s && !have_s {
                continue;
            }
            let src = if try_s { &hes } else { &jtj };
            a[..m * m].copy_from_slice(&src[..m * m]);
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
            if cholesky_solve(&mut a[..m * m], m, &mut delta[..m]) {
                solved = true;
                used_s = try_s;
                break;
            }
        }
        let model = if used_s { &hes } else { &jtj };
        if !solved {
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
            // Gain ratio: actual over the quadratic model's predicted decrease.
            let pred = predicted_decrease(model, &jtr, &delta, m);
            let rho = if pred > 0.0 { (c - c_new) / pred } else { 1.0 };
            let rel = (c - c_new) / c;
            th[..m].copy_from_slice(&trial[..m]);
            c = c_new;
            have_s = newton(th, w, &mut jtj, &mut jtr, &mut hes);
            lambda *= (1.0 - (2.0 * rho - 1.0).powi(3)).max(1.0 / 3.0);
            lambda = lambda.max(1e-12);
            nu = 2.0;
            if rel < tol {
                return LmRun { cost: c, iters: it, converged: true };
            }
        } else {
            // MINPACK's ftol test: when the quadratic model itself predicts less than the
            // tolerance and the step does not do better, the cost is at its minimum to that
            // precision (near it, rounding makes the tiny predicted gains fail to materialise).
            if predicted_decrease(model, &jtr, &delta, m) < tol * c && c_new.is_finite() && c_new - c <= tol * c {
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
