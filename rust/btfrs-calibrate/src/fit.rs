//! Fitting the sphere's outline to edge points: a circle (orthographic camera) or a cone of view
//! rays (perspective camera), robust to stray points.
//!
//! The circle starts from Kasa's algebraic fit (the linear least squares of
//! `x^2 + y^2 + D x + E y + F = 0`, on centred coordinates) and is refined by Gauss-Newton on the
//! geometric distances `|p - c| - r`. The cone is the same idea on unit rays: `d . w = 1` in the
//! least-squares sense gives `w = a / cos(alpha)`, the axis and the half-angle at once. Both
//! drop the points farther than three robust standard deviations (1.4826 x the median absolute
//! residual, and never under half a pixel) and refit, a few rounds: an edge point found on a
//! shadow or the relief instead of the sphere's outline does not pull the fit.

use crate::geometry::{dot, unit, Camera};

/// A fitted outline.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Outline {
    /// The circle (cx, cy, r) in pixels.
    pub circle: [f64; 3],
    /// Perspective: the cone's unit axis and the cosine of its half-angle.
    pub cone: Option<([f64; 3], f64)>,
    /// The points kept, and all of them.
    pub kept: usize,
    pub points: usize,
    /// Root-mean-square distance of the kept points from the outline, in pixels.
    pub rms_px: f64,
}

/// Solve the 3 x 3 system `m x = b` by Gaussian elimination with partial pivoting; None when
/// singular.
pub(crate) fn solve3(mut m: [[f64; 3]; 3], mut b: [f64; 3]) -> Option<[f64; 3]> {
    for c in 0..3 {
        let p = (c..3).max_by(|&i, &j| m[i][c].abs().total_cmp(&m[j][c].abs()))?;
        if m[p][c].abs() < 1e-300 {
            return None;
        }
        m.swap(c, p);
        b.swap(c, p);
        let (pivot, pb) = (m[c], b[c]);
        for (row, rb) in m.iter_mut().zip(b.iter_mut()).skip(c + 1) {
            let f = row[c] / pivot[c];
            for (x, p) in row.iter_mut().zip(pivot).skip(c) {
                *x -= f * p;
            }
            *rb -= f * pb;
        }
    }
    let mut x = [0.0; 3];
    for c in (0..3).rev() {
        let s: f64 = (c + 1..3).map(|k| m[c][k] * x[k]).sum();
        x[c] = (b[c] - s) / m[c][c];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

fn kasa(p: &[[f64; 2]]) -> Option<[f64; 3]> {
    let n = p.len() as f64;
    let (mx, my) = (p.iter().map(|q| q[0]).sum::<f64>() / n, p.iter().map(|q| q[1]).sum::<f64>() / n);
    let mut m = [[0.0; 3]; 3];
    let mut b = [0.0; 3];
    for q in p {
        let (x, y) = (q[0] - mx, q[1] - my);
        let row = [x, y, 1.0];
        let z = -(x * x + y * y);
        for i in 0..3 {
            for j in 0..3 {
                m[i][j] += row[i] * row[j];
            }
            b[i] += row[i] * z;
        }
    }
    let [d, e, f] = solve3(m, b)?;
    let (cx, cy) = (-0.5 * d, -0.5 * e);
    let r2 = cx * cx + cy * cy - f;
    (r2 > 0.0).then(|| [cx + mx, cy + my, r2.sqrt()])
}

fn geometric(p: &[[f64; 2]], mut c: [f64; 3]) -> [f64; 3] {
    for _ in 0..20 {
        let mut m = [[0.0; 3]; 3];
        let mut g = [0.0; 3];
        for q in p {
            let (dx, dy) = (q[0] - c[0], q[1] - c[1]);
            let d = (dx * dx + dy * dy).sqrt().max(1e-12);
            let res = d - c[2];
            let j = [-dx / d, -dy / d, -1.0];
            for i in 0..3 {
                for k in 0..3 {
                    m[i][k] += j[i] * j[k];
                }
                g[i] -= j[i] * res;
            }
        }
        let Some(step) = solve3(m, g) else { break };
        for i in 0..3 {
            c[i] += step[i];
        }
        if step.iter().map(|s| s * s).sum::<f64>() < 1e-18 {
            break;
        }
    }
    c
}

fn median(mut v: Vec<f64>) -> f64 {
    let n = v.len();
    let (_, m, _) = v.select_nth_unstable_by(n / 2, |a, b| a.total_cmp(b));
    *m
}

/// Keep the points within three robust standard deviations of the model (at least `floor`).
fn inliers(res: &[f64], floor: f64) -> Vec<bool> {
    let s = 1.4826 * median(res.iter().map(|r| r.abs()).collect());
    let lim = (3.0 * s).max(floor);
    res.iter().map(|r| r.abs() <= lim).collect()
}

/// The circle through `points` (pixels), robustly; None with fewer than 8 points or a
/// degenerate set.
pub fn fit_circle(points: &[[f64; 2]]) -> Option<Outline> {
    if points.len() < 8 {
        return None;
    }
    let mut keep = vec![true; points.len()];
    let mut c = [0.0; 3];
    for _ in 0..5 {
        let sel: Vec<[f64; 2]> = points.iter().zip(&keep).filter(|(_, k)| **k).map(|(p, _)| *p).collect();
        if sel.len() < 8 {
            return None;
        }
        c = geometric(&sel, kasa(&sel)?);
        let res: Vec<f64> = points.iter().map(|p| (p[0] - c[0]).hypot(p[1] - c[1]) - c[2]).collect();
        let next = inliers(&res, 0.5);
        if next == keep {
            break;
        }
        keep = next;
    }
    let res: Vec<f64> =
        points.iter().zip(&keep).filter(|(_, k)| **k).map(|(p, _)| (p[0] - c[0]).hypot(p[1] - c[1]) - c[2]).collect();
    let rms = (res.iter().map(|r| r * r).sum::<f64>() / res.len() as f64).sqrt();
    (c.iter().all(|v| v.is_finite()) && c[2] > 0.0).then_some(Outline {
        circle: c,
        cone: None,
        kept: res.len(),
        points: points.len(),
        rms_px: rms,
    })
}

/// The cone of view rays through `points` (pixels) for a perspective `camera`, robustly, with
/// the circle through the same points for pictures; None as [`fit_circle`].
pub fn fit_cone(points: &[[f64; 2]], camera: Camera) -> Option<Outline> {
    let Camera::Perspective { focal_px, .. } = camera else { return fit_circle(points) };
    let circle = fit_circle(points)?;
    let rays: Vec<[f64; 3]> = points.iter().map(|p| camera.ray(p[0], p[1])).collect();
    let mut keep = vec![true; rays.len()];
    let mut cone = ([0.0; 3], 1.0);
    for _ in 0..5 {
        let mut m = [[0.0; 3]; 3];
        let mut b = [0.0; 3];
        let mut n = 0;
        for (d, _) in rays.iter().zip(&keep).filter(|(_, k)| **k) {
            for i in 0..3 {
                for j in 0..3 {
                    m[i][j] += d[i] * d[j];
                }
                b[i] += d[i];
            }
            n += 1;
        }
        if n < 8 {
            return None;
        }
        let w = solve3(m, b)?;
        let len = dot(w, w).sqrt();
        cone = (unit(w), (1.0 / len).min(1.0));
        // Residuals as angles, turned into pixels near the axis (f pixels per radian).
        let alpha = cone.1.acos();
        let res: Vec<f64> = rays.iter().map(|d| (dot(*d, cone.0).clamp(-1.0, 1.0).acos() - alpha) * focal_px).collect();
        let next = inliers(&res, 0.5);
        if next == keep {
            break;
        }
        keep = next;
    }
    let alpha = cone.1.acos();
    let res: Vec<f64> = rays
        .iter()
        .zip(&keep)
        .filter(|(_, k)| **k)
        .map(|(d, _)| (dot(*d, cone.0).clamp(-1.0, 1.0).acos() - alpha) * focal_px)
        .collect();
    let rms = (res.iter().map(|r| r * r).sum::<f64>() / res.len() as f64).sqrt();
    (cone.0.iter().all(|v| v.is_finite()) && cone.1 > 0.0 && cone.1 < 1.0).then_some(Outline {
        circle: circle.circle,
        cone: Some(cone),
        kept: res.len(),
        points: points.len(),
        rms_px: rms,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A deterministic jitter in [-1, 1].
    fn jitter(k: usize) -> f64 {
        ((k as f64 * 12.9898).sin() * 43758.5453).rem_euclid(1.0) * 2.0 - 1.0
    }

    #[test]
    fn circle_from_noisy_points_with_outliers() {
        let (cx, cy, r) = (130.3, 77.8, 54.2);
        let mut p: Vec<[f64; 2]> = (0..360)
            .map(|k| {
                let t = (k as f64).to_radians();
                let rr = r + 0.2 * jitter(k);
                [cx + rr * t.cos(), cy + rr * t.sin()]
            })
            .collect();
        // A tenth of the points on something else (a shadow's edge 9 pixels out).
        for (k, q) in p.iter_mut().enumerate().filter(|(k, _)| k % 10 == 3) {
            let t = (k as f64).to_radians();
            *q = [cx + (r + 9.0) * t.cos(), cy + (r + 9.0) * t.sin()];
        }
        let o = fit_circle(&p).unwrap();
        assert!((o.circle[0] - cx).abs() < 0.03 && (o.circle[1] - cy).abs() < 0.03, "{:?}", o.circle);
        assert!((o.circle[2] - r).abs() < 0.03, "{:?}", o.circle);
        assert_eq!(o.kept, 324);
        assert!(o.rms_px < 0.15);
        assert!(fit_circle(&p[..5]).is_none());
    }

    #[test]
    fn cone_through_the_outline_of_a_sphere_seen_off_axis() {
        // The exact outline of a sphere seen by a pinhole: rays at angle alpha from the axis.
        let cam = Camera::Perspective { focal_px: 700.0, width: 800.0, height: 600.0 };
        let a = unit([0.35, 0.2, -1.0]);
        let alpha = 0.08f64;
        // Two unit vectors perpendicular to a.
        let e1 = unit([a[2], 0.0, -a[0]]);
        let e2 = [a[1] * e1[2] - a[2] * e1[1], a[2] * e1[0] - a[0] * e1[2], a[0] * e1[1] - a[1] * e1[0]];
        let pts: Vec<[f64; 2]> = (0..200)
            .map(|k| {
                let t = std::f64::consts::TAU * k as f64 / 200.0;
                let d: Vec<f64> =
                    (0..3).map(|i| alpha.cos() * a[i] + alpha.sin() * (t.cos() * e1[i] + t.sin() * e2[i])).collect();
                [400.0 + 700.0 * d[0] / -d[2], 300.0 - 700.0 * d[1] / -d[2]]
            })
            .collect();
        let o = fit_cone(&pts, cam).unwrap();
        let (axis, cos_a) = o.cone.unwrap();
        assert!(dot(axis, a) > (1e-7f64).cos(), "{axis:?}");
        assert!((cos_a.acos() - alpha).abs() < 1e-9);
        assert!(o.rms_px < 1e-6);
        // The outline is not a circle: the circle through it misses by more than the cone.
        let circle = fit_circle(&pts).unwrap();
        assert!(circle.rms_px > 100.0 * o.rms_px);
    }

    #[test]
    fn solve3_matches_a_known_solution_and_refuses_singular() {
        let m = [[4.0, -2.0, 1.0], [3.0, 6.0, -4.0], [2.0, 1.0, 8.0]];
        let x = [1.5, -2.0, 0.25];
        let b: [f64; 3] = std::array::from_fn(|i| (0..3).map(|j| m[i][j] * x[j]).sum::<f64>());
        let got = solve3(m, b).unwrap();
        assert!((0..3).all(|i| (got[i] - x[i]).abs() < 1e-12));
        assert!(solve3([[1.0, 2.0, 3.0], [2.0, 4.0, 6.0], [0.0, 0.0, 1.0]], [1.0, 2.0, 3.0]).is_none());
    }
}
