//! The camera, the sphere as the camera sees it, and the mirror reflection that turns a highlight
//! into a light direction.
//!
//! Pixel coordinates are continuous: `u` to the right, `v` down, the image's top-left corner at
//! (0, 0), so the centre of pixel (row i, column j) is (j + 0.5, i + 0.5). Directions are in
//! btfrs's frame: x along the columns (right), y *up* the image, z out of the surface towards the
//! camera, which looks straight down at the surface.
//!
//! * **Orthographic** (the default; a long lens far from a small sphere): every view ray is
//!   (0, 0, -1) and the sphere's outline is a circle (cx, cy, r). The normal under pixel (u, v) is
//!   ((u - cx) / r, -(v - cy) / r, nz).
//! * **Perspective** (a pinhole at focal length `f` pixels, the principal point at the image's
//!   centre): the view ray through (u, v) is d ~ ((u - W/2) / f, -(v - H/2) / f, -1), and the
//!   sphere's outline is a cone of rays around the direction `a` of its centre with half-angle
//!   `alpha` (its image an ellipse, stretched away from the image's centre). With the centre at
//!   distance 1 along `a` (the scale does not change a direction), the sphere's radius is
//!   sin(alpha), the ray meets it at `t = d.a - sqrt((d.a)^2 - cos^2 alpha)` and the normal is
//!   `(t d - a) / sin(alpha)`.
//!
//! In both, the light seen in a highlight at a point with normal `n` and direction to the camera
//! `e` is its mirror image: `l = 2 (n.e) n - e`.

use serde::Serialize;

/// How the photographs were projected.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "projection", rename_all = "snake_case")]
pub enum Camera {
    /// Parallel view rays along -z.
    Orthographic,
    /// A pinhole at `focal_px` pixels from the image, the principal point at the image's centre.
    Perspective {
        /// Focal length in pixels.
        focal_px: f64,
        /// Image width and height in pixels (the principal point is their half).
        width: f64,
        height: f64,
    },
}

impl Camera {
    /// The unit view ray through pixel position (u, v), from the camera into the scene.
    #[inline]
    pub fn ray(&self, u: f64, v: f64) -> [f64; 3] {
        match *self {
            Camera::Orthographic => [0.0, 0.0, -1.0],
            Camera::Perspective { focal_px, width, height } => {
                unit([(u - 0.5 * width) / focal_px, -(v - 0.5 * height) / focal_px, -1.0])
            }
        }
    }

    /// Horizontal field of view in degrees (None for orthographic).
    pub fn fov_deg(&self) -> Option<f64> {
        match *self {
            Camera::Orthographic => None,
            Camera::Perspective { focal_px, width, .. } => Some(2.0 * (0.5 * width / focal_px).atan().to_degrees()),
        }
    }
}

/// The sphere as seen by a camera: enough to find the normal under any pixel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SphereView {
    /// The camera.
    pub camera: Camera,
    /// The outline's circle in pixels (cx, cy, r): exact for an orthographic camera, the best
    /// circle through the outline's points for a perspective one (drawn in pictures, reported).
    pub circle: [f64; 3],
    /// Perspective only: the unit direction of the sphere's centre from the camera and the
    /// cosine of the outline cone's half-angle.
    pub cone: Option<([f64; 3], f64)>,
}

impl SphereView {
    /// An orthographic view of the circle (cx, cy, r).
    pub fn orthographic(circle: [f64; 3]) -> Self {
        SphereView { camera: Camera::Orthographic, circle, cone: None }
    }

    /// A perspective view whose outline passes through (approximately) the circle (cx, cy, r):
    /// the cone's axis through the circle's centre, its half-angle the mean angle to 16 points
    /// of the circle. Used for a circle given by hand; a detected outline is fitted as a cone
    /// ([`crate::fit::fit_cone`]).
    pub fn from_circle(camera: Camera, circle: [f64; 3]) -> Self {
        if camera == Camera::Orthographic {
            return Self::orthographic(circle);
        }
        let [cx, cy, r] = circle;
        let a = camera.ray(cx, cy);
        let n = 16;
        let mean = (0..n)
            .map(|k| {
                let t = std::f64::consts::TAU * k as f64 / n as f64;
                dot(camera.ray(cx + r * t.cos(), cy + r * t.sin()), a).clamp(-1.0, 1.0).acos()
            })
            .sum::<f64>()
            / n as f64;
        SphereView { camera, circle, cone: Some((a, mean.cos())) }
    }

    /// The sphere's unit normal at pixel position (u, v) and the unit direction from there to
    /// the camera; None off the sphere.
    #[inline]
    pub fn normal_at(&self, u: f64, v: f64) -> Option<([f64; 3], [f64; 3])> {
        match self.cone {
            None => {
                let [cx, cy, r] = self.circle;
                let (x, y) = ((u - cx) / r, -(v - cy) / r);
                let q = x * x + y * y;
                (q <= 1.0).then(|| ([x, y, (1.0 - q).sqrt()], [0.0, 0.0, 1.0]))
            }
            Some((a, cos_a)) => {
                let d = self.camera.ray(u, v);
                let b = dot(d, a);
                let disc = b * b - cos_a * cos_a;
                if disc < 0.0 || b <= 0.0 {
                    return None;
                }
                let t = b - disc.sqrt();
                let sin_a = (1.0 - cos_a * cos_a).sqrt();
                let n = unit([(t * d[0] - a[0]) / sin_a, (t * d[1] - a[1]) / sin_a, (t * d[2] - a[2]) / sin_a]);
                Some((n, [-d[0], -d[1], -d[2]]))
            }
        }
    }

    /// The direction of a light whose mirror image is seen at pixel position (u, v); None off
    /// the sphere.
    #[inline]
    pub fn light_at(&self, u: f64, v: f64) -> Option<[f64; 3]> {
        let (n, e) = self.normal_at(u, v)?;
        Some(reflect(n, e))
    }
}

/// The mirror image of `e` about the unit normal `n`: `2 (n.e) n - e`.
#[inline]
pub fn reflect(n: [f64; 3], e: [f64; 3]) -> [f64; 3] {
    let k = 2.0 * dot(n, e);
    [k * n[0] - e[0], k * n[1] - e[1], k * n[2] - e[2]]
}

#[inline]
pub(crate) fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline]
pub(crate) fn unit(a: [f64; 3]) -> [f64; 3] {
    let n = dot(a, a).sqrt();
    [a[0] / n, a[1] / n, a[2] / n]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn angle(a: [f64; 3], b: [f64; 3]) -> f64 {
        dot(unit(a), unit(b)).clamp(-1.0, 1.0).acos().to_degrees()
    }

    #[test]
    fn orthographic_centre_reflects_the_camera_and_the_axes_follow_the_frame() {
        let s = SphereView::orthographic([100.0, 80.0, 50.0]);
        // The centre of the sphere mirrors a light straight above.
        assert!(angle(s.light_at(100.0, 80.0).unwrap(), [0.0, 0.0, 1.0]) < 1e-9);
        // Right of the centre: a light towards +x; above it (smaller v): towards +y.
        let l = s.light_at(100.0 + 50.0 * (22.5f64).to_radians().sin(), 80.0).unwrap();
        assert!(angle(l, [45f64.to_radians().sin(), 0.0, 45f64.to_radians().cos()]) < 1e-9, "{l:?}");
        let l = s.light_at(100.0, 80.0 - 25.0).unwrap();
        assert!(l[1] > 0.0 && l[0].abs() < 1e-12);
        // At 45 degrees of normal the light grazes the horizon; off the disc there is none.
        let l = s.light_at(100.0 + 50.0 * 45f64.to_radians().sin(), 80.0).unwrap();
        assert!(l[2].abs() < 1e-12);
        assert!(s.light_at(151.0, 80.0).is_none());
    }

    #[test]
    fn perspective_normals_match_a_ray_traced_sphere() {
        // A sphere of radius 0.3 at C seen by a pinhole at the origin: trace the ray through a
        // pixel by hand and compare the normal.
        let cam = Camera::Perspective { focal_px: 400.0, width: 640.0, height: 480.0 };
        let c = [0.8, -0.4, -3.0];
        let rad = 0.3f64;
        let dist = dot(c, c).sqrt();
        let a = unit(c);
        let cos_a = (1.0 - (rad / dist).powi(2)).sqrt();
        let s = SphereView { camera: cam, circle: [0.0; 3], cone: Some((a, cos_a)) };
        // The pixel of the centre's direction, then one a little off it.
        let (u0, v0) = (320.0 + 400.0 * c[0] / -c[2], 240.0 - 400.0 * c[1] / -c[2]);
        for (du, dv) in [(0.0, 0.0), (20.0, -13.0), (-31.0, 5.0)] {
            let d = cam.ray(u0 + du, v0 + dv);
            // |t d - c| = rad, the nearer root.
            let b = dot(d, c);
            let t = b - (b * b - dot(c, c) + rad * rad).sqrt();
            let p = [t * d[0], t * d[1], t * d[2]];
            let want = unit([p[0] - c[0], p[1] - c[1], p[2] - c[2]]);
            let (n, e) = s.normal_at(u0 + du, v0 + dv).unwrap();
            assert!(angle(n, want) < 1e-7, "{n:?} {want:?}");
            assert!(angle(e, [-d[0], -d[1], -d[2]]) < 1e-9);
        }
        assert_eq!(
            cam.fov_deg().map(|f| (f * 1e6).round() / 1e6),
            Some((2.0 * (0.8f64).atan().to_degrees() * 1e6).round() / 1e6)
        );
    }

    #[test]
    fn a_circle_given_by_hand_makes_a_cone_through_it() {
        let cam = Camera::Perspective { focal_px: 500.0, width: 600.0, height: 400.0 };
        let s = SphereView::from_circle(cam, [150.0, 120.0, 40.0]);
        // The circle's centre is on the sphere and points of the circle are (nearly) its edge.
        assert!(s.normal_at(150.0, 120.0).is_some());
        assert!(s.normal_at(150.0, 120.0 - 42.0).is_none());
        assert!(s.normal_at(150.0, 120.0 - 38.0).is_some());
    }
}
