//! The fit of one texel's lobe ([`super::lobe`]) to its measured values: variable projection
//! (Golub and Pereyra 1973) over the three nonlinear parameters, the normal's slopes and the
//! log roughness, with Levenberg-Marquardt; for each trial the diffuse and specular colours are
//! the non-negative least-squares solution of their linear problem, channel by channel.
//!
//! The start is the photometric-stereo normal ([`crate::photometric`]) and the best of a few
//! roughnesses; LM's Jacobian is by central differences of the projected residual (three extra
//! residual passes per side), cheap beside the pairs it covers.

use super::lobe::{basis_of, geometry, normal_of, ALPHA_MAX, ALPHA_MIN};

/// One measured value of the texel: view and light (unit, tangent frame) and its RGB value.
#[derive(Debug, Clone, Copy)]
pub struct Obs {
    /// Towards the camera.
    pub view: [f64; 3],
    /// Towards the light.
    pub light: [f64; 3],
    /// The measured RGB value.
    pub value: [f32; 3],
}

/// A fitted texel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TexelLobe {
    /// Diffuse colour.
    pub rho_d: [f64; 3],
    /// Specular colour.
    pub rho_s: [f64; 3],
    /// GGX roughness (alpha), in [`ALPHA_MIN`, `ALPHA_MAX`].
    pub alpha: f64,
    /// The normal's slopes `(p, q)`: normal `(-p, -q, 1) / |.|`.
    pub slopes: [f64; 2],
    /// Sum of squared residuals over the observations and channels.
    pub cost: f64,
    /// Iterations: golden-section steps for a kept normal, LM steps for a fitted one.
    pub iters: usize,
}

/// Largest slope of a fitted normal (about 84 degrees from the geometric normal).
pub const SLOPE_MAX: f64 = 10.0;
/// Log-spaced roughnesses of the global search, from [`ALPHA_MIN`] to [`ALPHA_MAX`].
const ALPHA_GRID: usize = 12;
/// Golden-section steps around the grid's best point (each shrinks the bracket by 0.618).
const GOLDEN_STEPS: usize = 10;
/// LM iterations at most.
const MAX_ITERS: usize = 30;

/// Scratch reused across the texels a thread fits.
#[derive(Debug, Default)]
pub struct Work {
    /// [`geometry`] of every observation for the normal of slopes `normal`.
    geom: Vec<[f64; 3]>,
    normal: Option<[f64; 2]>,
    bd: Vec<f64>,
    bs: Vec<f64>,
    r0: Vec<f64>,
    rp: Vec<f64>,
    rm: Vec<f64>,
    jac: Vec<f64>,
}

fn clamp_theta(t: [f64; 3]) -> [f64; 3] {
    [t[0].clamp(-SLOPE_MAX, SLOPE_MAX), t[1].clamp(-SLOPE_MAX, SLOPE_MAX), t[2].clamp(ALPHA_MIN.ln(), ALPHA_MAX.ln())]
}

/// The colours that best explain `obs` with bases `bd`, `bs` (non-negative least squares per
/// channel of the 2 x 2 problem) and the residuals `y - a bd - b bs` into `r` (channel-major).
fn project(obs: &[Obs], bd: &[f64], bs: &[f64], r: &mut Vec<f64>) -> ([f64; 3], [f64; 3], f64) {
    let (mut dd, mut ds, mut ss) = (0.0, 0.0, 0.0);
    for (d, s) in bd.iter().zip(bs) {
        dd += d * d;
        ds += d * s;
        ss += s * s;
    }
    let mut rho_d = [0.0; 3];
    let mut rho_s = [0.0; 3];
    r.clear();
    let mut cost = 0.0;
    for c in 0..3 {
        let (mut yd, mut ys) = (0.0, 0.0);
        for ((o, d), s) in obs.iter().zip(bd).zip(bs) {
            let y = o.value[c] as f64;
            yd += y * d;
            ys += y * s;
        }
        let det = dd * ss - ds * ds;
        let (mut a, mut b) = if det > 1e-12 * dd * ss && det > 0.0 {
            ((yd * ss - ys * ds) / det, (ys * dd - yd * ds) / det)
        } else {
            (-1.0, -1.0)
        };
        if !(a >= 0.0 && b >= 0.0) {
            // On the boundary: the better of diffuse alone and specular alone (each clamped).
            let a1 = if dd > 0.0 { (yd / dd).max(0.0) } else { 0.0 };
            let b1 = if ss > 0.0 { (ys / ss).max(0.0) } else { 0.0 };
            let e_a = -2.0 * a1 * yd + a1 * a1 * dd;
            let e_b = -2.0 * b1 * ys + b1 * b1 * ss;
            (a, b) = if e_a <= e_b { (a1, 0.0) } else { (0.0, b1) };
        }
        rho_d[c] = a;
        rho_s[c] = b;
        for ((o, d), s) in obs.iter().zip(bd).zip(bs) {
            let e = o.value[c] as f64 - a * d - b * s;
            cost += e * e;
            r.push(e);
        }
    }
    (rho_d, rho_s, cost)
}

fn residual(obs: &[Obs], theta: [f64; 3], w: &mut Work, out: Which) -> ([f64; 3], [f64; 3], f64) {
    if w.normal != Some([theta[0], theta[1]]) {
        let n = normal_of(theta[0], theta[1]);
        w.geom.clear();
        w.geom.extend(obs.iter().map(|o| geometry(n, o.view, o.light)));
        w.normal = Some([theta[0], theta[1]]);
    }
    let alpha = theta[2].exp();
    w.bd.clear();
    w.bs.clear();
    for g in &w.geom {
        let (d, s) = basis_of(*g, alpha);
        w.bd.push(d);
        w.bs.push(s);
    }
    let r = match out {
        Which::R0 => &mut w.r0,
        Which::Plus => &mut w.rp,
        Which::Minus => &mut w.rm,
    };
    project(obs, &w.bd, &w.bs, r)
}

#[derive(Clone, Copy)]
enum Which {
    R0,
    Plus,
    Minus,
}

/// Fit one texel from the normal `start` (unit, z > 0; the photometric-stereo normal); with
/// `free_normal` false the normal stays `start` and only the roughness and colours are fitted.
pub fn fit_texel(obs: &[Obs], start: [f64; 3], free_normal: bool, w: &mut Work) -> TexelLobe {
    let nz = start[2].max(0.05);
    let slopes = [-start[0] / nz, -start[1] / nz];
    w.normal = None; // another texel's geometry
                     // The roughness for the start normal: a global search of the one-dimensional cost (a
                     // log-spaced grid, then golden sections around its best point), which a local method
                     // started at a guess does not give: the cost of alpha has several minima where highlights
                     // and shadows pull apart.
    let slopes = clamp_theta([slopes[0], slopes[1], 0.0]);
    let cost_at = |la: f64, w: &mut Work| residual(obs, [slopes[0], slopes[1], la], w, Which::R0).2;
    let (lo, hi) = (ALPHA_MIN.ln(), ALPHA_MAX.ln());
    let step = (hi - lo) / (ALPHA_GRID - 1) as f64;
    let grid: Vec<f64> = (0..ALPHA_GRID).map(|i| cost_at(lo + step * i as f64, w)).collect();
    let best_i = (0..ALPHA_GRID).min_by(|&a, &b| grid[a].total_cmp(&grid[b])).unwrap_or(0);
    let (mut a, mut b) =
        (lo + step * best_i.saturating_sub(1) as f64, lo + step * (best_i + 1).min(ALPHA_GRID - 1) as f64);
    let g = 0.5 * (5f64.sqrt() - 1.0);
    let (mut x1, mut x2) = (b - g * (b - a), a + g * (b - a));
    let (mut f1, mut f2) = (cost_at(x1, w), cost_at(x2, w));
    for _ in 0..GOLDEN_STEPS {
        if f1 <= f2 {
            b = x2;
            (x2, f2) = (x1, f1);
            x1 = b - g * (b - a);
            f1 = cost_at(x1, w);
        } else {
            a = x1;
            (x1, f1) = (x2, f2);
            x2 = a + g * (b - a);
            f2 = cost_at(x2, w);
        }
    }
    let la = if f1.min(f2) <= grid[best_i] {
        if f1 <= f2 {
            x1
        } else {
            x2
        }
    } else {
        lo + step * best_i as f64
    };
    let mut theta = [slopes[0], slopes[1], la];
    let (mut rho_d, mut rho_s, mut cost) = residual(obs, theta, w, Which::R0);
    if !free_normal {
        return lobe(rho_d, rho_s, theta, cost, GOLDEN_STEPS);
    }
    let mut lambda = 1e-3;
    let mut iters = 0;
    let m = w.r0.len();
    while iters < MAX_ITERS && cost > 0.0 {
        iters += 1;
        // The projected residual's Jacobian by central differences.
        w.jac.resize(3 * m, 0.0);
        let base = w.r0.clone();
        for q in 0..3 {
            let h = 1e-5 * (1.0 + theta[q].abs());
            let mut tp = theta;
            let mut tm = theta;
            tp[q] += h;
            tm[q] -= h;
            residual(obs, tp, w, Which::Plus);
            residual(obs, tm, w, Which::Minus);
            for k in 0..m {
                w.jac[q * m + k] = (w.rp[k] - w.rm[k]) / (2.0 * h);
            }
        }
        let mut jtj = [[0.0f64; 3]; 3];
        let mut jtr = [0.0f64; 3];
        for (q, row) in jtj.iter_mut().enumerate() {
            for (u, x) in row.iter_mut().enumerate() {
                *x = (0..m).map(|k| w.jac[q * m + k] * w.jac[u * m + k]).sum();
            }
            jtr[q] = (0..m).map(|k| w.jac[q * m + k] * base[k]).sum();
        }
        let mut accepted = false;
        while lambda < 1e12 {
            let mut a = jtj;
            for (q, row) in a.iter_mut().enumerate() {
                row[q] += lambda * (jtj[q][q].max(1e-12));
            }
            let Some(step) = solve3(a, [-jtr[0], -jtr[1], -jtr[2]]) else {
                lambda *= 10.0;
                continue;
            };
            let trial = clamp_theta([theta[0] + step[0], theta[1] + step[1], theta[2] + step[2]]);
            let (d, s, c) = residual(obs, trial, w, Which::R0);
            if c.is_finite() && c < cost {
                let gain = (cost - c) / cost.max(f64::MIN_POSITIVE);
                theta = trial;
                (rho_d, rho_s, cost) = (d, s, c);
                lambda = (lambda / 3.0).max(1e-9);
                accepted = true;
                if gain < 1e-9 {
                    return lobe(rho_d, rho_s, theta, cost, iters);
                }
                break;
            }
            lambda *= 10.0;
        }
        if !accepted {
            // Restore the residual of the current theta (the failed trials overwrote it).
            residual(obs, theta, w, Which::R0);
            break;
        }
    }
    lobe(rho_d, rho_s, theta, cost, iters)
}

/// How far above a texel's brightest measured value the lobe may reach anywhere on the probes:
/// a lobe brighter than that is extrapolating from sparse pairs (paper 000, section 3.2 warns
/// of this for Lafortune's lobes; its fit has the same kind of guard).
pub const GUARD: f64 = 2.0;

/// Where [`guard`] looks for a lobe's peak: fixed (view, light) pairs spread over the
/// hemispheres, and views whose mirror direction about each texel's own normal is probed too
/// (the peak of a narrow lobe lies there, between any fixed pairs: a glossy texel seen from
/// above peaks at a light near the zenith that a dome need not have).
#[derive(Debug, Clone)]
pub struct Probes {
    /// Fixed pairs.
    pub pairs: Vec<([f64; 3], [f64; 3])>,
    /// Views probed at their mirror light.
    pub views: Vec<[f64; 3]>,
}

/// How near the normal, in units of the roughness, a measured pair's half vector must lie for
/// the lobe's peak to count as seen: one roughness width off the normal, GGX's distribution is
/// at a quarter of its peak, so a lobe that agrees with that pair peaks at most about four times
/// its value; two widths off (a sixteenth), a lobe fitted to it may peak at many times every
/// measured value, and did on a real single-view capture (six times).
const SEEN: f64 = 1.0;

/// The largest grey value (mean of the channels) of `lobe` over `probes`, and at the views'
/// mirror lights (where a narrow lobe peaks) unless a pair of `obs` saw its peak (a half vector
/// within [`SEEN`] roughness widths of the normal): a peak no pair came near is the lobe's
/// guess, not the data's.
fn peak(lobe: &TexelLobe, obs: &[Obs], probes: &Probes) -> f64 {
    let n = normal_of(lobe.slopes[0], lobe.slopes[1]);
    let (d, s) = (lobe.rho_d.iter().sum::<f64>() / 3.0, lobe.rho_s.iter().sum::<f64>() / 3.0);
    let value = |v: [f64; 3], l: [f64; 3]| {
        let (bd, bs) = basis_of(geometry(n, v, l), lobe.alpha);
        d * bd + s * bs
    };
    let fixed = probes.pairs.iter().fold(0.0f64, |m, &(v, l)| m.max(value(v, l)));
    let seen = (SEEN * lobe.alpha).min(std::f64::consts::FRAC_PI_2).cos();
    let near = obs.iter().any(|o| {
        let h = [o.view[0] + o.light[0], o.view[1] + o.light[1], o.view[2] + o.light[2]];
        let len = (h[0] * h[0] + h[1] * h[1] + h[2] * h[2]).sqrt();
        len > 0.0 && (n[0] * h[0] + n[1] * h[1] + n[2] * h[2]) / len >= seen
    });
    if near {
        return fixed;
    }
    probes.views.iter().fold(fixed, |m, &v| {
        let c = 2.0 * (n[0] * v[0] + n[1] * v[1] + n[2] * v[2]);
        let l = [c * n[0] - v[0], c * n[1] - v[1], c * n[2] - v[2]];
        if l[2] > 0.0 {
            m.max(value(v, l))
        } else {
            m
        }
    })
}

/// The guarded lobe: when the fitted lobe's [`peak`] exceeds [`GUARD`] times the texel's
/// brightest grey value of `obs`, the smallest roughness (by bisection between the fitted one
/// and [`ALPHA_MAX`], the colours re-solved for each) whose lobe stays within it; diffuse alone
/// if none does. Returns the lobe and whether it was guarded.
pub fn guard(obs: &[Obs], lobe: TexelLobe, probes: &Probes, w: &mut Work) -> (TexelLobe, bool) {
    let bright = obs.iter().fold(0.0f64, |m, o| m.max((o.value[0] + o.value[1] + o.value[2]) as f64 / 3.0));
    let limit = GUARD * bright;
    if peak(&lobe, obs, probes) <= limit {
        return (lobe, false);
    }
    let at = |alpha: f64, w: &mut Work| {
        let theta = [lobe.slopes[0], lobe.slopes[1], alpha.ln()];
        let (rho_d, rho_s, cost) = residual(obs, theta, w, Which::R0);
        TexelLobe { rho_d, rho_s, alpha, slopes: lobe.slopes, cost, iters: lobe.iters }
    };
    let top = at(ALPHA_MAX, w);
    if peak(&top, obs, probes) > limit {
        // Diffuse alone: each channel's least-squares factor of n.l.
        let n = normal_of(lobe.slopes[0], lobe.slopes[1]);
        let mut flat = top;
        let (mut dd, mut yd) = (0.0f64, [0.0f64; 3]);
        for o in obs {
            let d = basis_of(geometry(n, o.view, o.light), ALPHA_MAX).0;
            dd += d * d;
            for (c, y) in yd.iter_mut().enumerate() {
                *y += d * o.value[c] as f64;
            }
        }
        flat.rho_d = yd.map(|y| if dd > 0.0 { (y / dd).max(0.0) } else { 0.0 });
        flat.rho_s = [0.0; 3];
        return (flat, true);
    }
    let (mut lo, mut hi, mut best) = (lobe.alpha.ln(), ALPHA_MAX.ln(), top);
    for _ in 0..12 {
        let mid = 0.5 * (lo + hi);
        let cand = at(mid.exp(), w);
        if peak(&cand, obs, probes) <= limit {
            hi = mid;
            best = cand;
        } else {
            lo = mid;
        }
    }
    (best, true)
}

fn lobe(rho_d: [f64; 3], rho_s: [f64; 3], theta: [f64; 3], cost: f64, iters: usize) -> TexelLobe {
    TexelLobe { rho_d, rho_s, alpha: theta[2].exp(), slopes: [theta[0], theta[1]], cost, iters }
}

/// Solve the 3 x 3 system `a x = b` (Cramer's rule on a symmetric positive definite matrix);
/// None when singular.
fn solve3(a: [[f64; 3]; 3], b: [f64; 3]) -> Option<[f64; 3]> {
    let det = |m: &[[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d = det(&a);
    if !(d.is_finite() && d.abs() > 1e-300) {
        return None;
    }
    let mut x = [0.0; 3];
    for (i, xi) in x.iter_mut().enumerate() {
        let mut m = a;
        for r in 0..3 {
            m[r][i] = b[r];
        }
        *xi = det(&m) / d;
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::svbrdf::lobe::basis;
    use crate::svbrdf::tests::spiral as dirs;

    fn observations(truth: &TexelLobe) -> Vec<Obs> {
        let n = normal_of(truth.slopes[0], truth.slopes[1]);
        let mut out = Vec::new();
        for v in dirs(9, 20.0, 88.0, 0.3) {
            for l in dirs(40, 15.0, 88.0, 1.1) {
                let (d, s) = basis(n, truth.alpha, v, l);
                let value = [0, 1, 2].map(|c| (truth.rho_d[c] * d + truth.rho_s[c] * s) as f32);
                out.push(Obs { view: v, light: l, value });
            }
        }
        out
    }

    #[test]
    fn data_made_by_the_lobe_give_the_lobe_back() {
        let mut w = Work::default();
        for (slopes, alpha, rho_s) in [
            ([0.2, -0.1], 0.15, [0.3, 0.3, 0.3]),
            ([-0.4, 0.25], 0.4, [0.1, 0.2, 0.15]),
            ([0.0, 0.0], 0.07, [0.5, 0.4, 0.3]),
        ] {
            let truth = TexelLobe { rho_d: [0.4, 0.25, 0.1], rho_s, alpha, slopes, cost: 0.0, iters: 0 };
            let obs = observations(&truth);
            // Start 8 degrees off, as photometric stereo with a highlight would be.
            let n = normal_of(slopes[0] + 0.1, slopes[1] - 0.08);
            let got = fit_texel(&obs, n, true, &mut w);
            assert!((got.alpha - alpha).abs() < 1e-3 * alpha, "{got:?}");
            for (c, &s) in rho_s.iter().enumerate() {
                assert!((got.rho_d[c] - truth.rho_d[c]).abs() < 1e-4, "{got:?}");
                assert!((got.rho_s[c] - s).abs() < 1e-3 * s.max(0.1), "{got:?}");
            }
            assert!((got.slopes[0] - slopes[0]).abs() < 1e-4 && (got.slopes[1] - slopes[1]).abs() < 1e-4, "{got:?}");
        }
    }

    #[test]
    fn a_lambertian_texel_gets_no_specular_colour() {
        let truth =
            TexelLobe { rho_d: [0.3, 0.5, 0.2], rho_s: [0.0; 3], alpha: 0.3, slopes: [0.1, 0.2], cost: 0.0, iters: 0 };
        let obs = observations(&truth);
        let got = fit_texel(&obs, normal_of(0.1, 0.2), true, &mut Work::default());
        assert!(got.rho_s.iter().all(|&s| s < 1e-6), "{got:?}");
        assert!(got.cost < 1e-10, "{got:?}");
    }
}
