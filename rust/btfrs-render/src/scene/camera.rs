//! The perspective camera of the renderers: a look-at frame and the view-projection matrix both
//! the CPU rasteriser and the GPU pipeline use, so that both see the same clip-space positions.

use super::check_finite3;
use btfrs_core::{ensure_arg, Error, Result};
use glam::{Mat4, Vec3};

/// `sin` of the angle under which the view direction and `up` count as parallel; `look_at_rh`
/// would build a NaN or badly conditioned basis from them.
const PARALLEL_SIN: f32 = 1e-4;

/// Perspective camera (right-handed, z up by default).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Eye position in world space.
    pub eye: [f32; 3],
    /// The point looked at; it projects to the image centre.
    pub target: [f32; 3],
    /// Up direction; it need not be orthogonal to the view direction, only not parallel to it.
    pub up: [f32; 3],
    /// Vertical field of view in degrees, in (0, 180).
    pub fov_y_deg: f32,
    /// Near clipping distance (depth 0), > 0.
    pub near: f32,
    /// Far clipping distance (depth 1), > near.
    pub far: f32,
}

impl Camera {
    /// A camera at `eye` looking at `target`, up = +z, near 0.01, far 100.
    ///
    /// When the view direction is parallel to +z (looking straight up or down), up falls back to
    /// +y instead of failing. Errors: non-finite input, `eye == target`, `fov_y_deg` outside (0, 180).
    pub fn look_at(eye: [f32; 3], target: [f32; 3], fov_y_deg: f32) -> Result<Camera> {
        check_finite3("eye", eye)?;
        check_finite3("target", target)?;
        let dir = Vec3::from(target) - Vec3::from(eye);
        if !dir.is_finite() || dir.length_squared() == 0.0 {
            return Err(Error::arg(
                "target",
                format!("must differ from eye {eye:?} by a finite amount, got {target:?}"),
            ));
        }
        let up = if is_parallel(dir, Vec3::Z) { [0.0, 1.0, 0.0] } else { [0.0, 0.0, 1.0] };
        let camera = Camera { eye, target, up, fov_y_deg, near: 0.01, far: 100.0 };
        camera.validate()?;
        Ok(camera)
    }

    /// A camera at `eye` looking at `target` with the given `up` (any vector not parallel to the
    /// view direction; it need not be orthogonal to it), near 0.01, far 100. Errors: as
    /// [`Camera::look_at`], and an `up` that is zero or parallel to the view direction ("up").
    pub fn look_at_up(eye: [f32; 3], target: [f32; 3], fov_y_deg: f32, up: [f32; 3]) -> Result<Camera> {
        let mut camera = Camera::look_at(eye, target, fov_y_deg)?;
        check_finite3("up", up)?;
        let dir = Vec3::from(target) - Vec3::from(eye);
        if Vec3::from(up).length_squared() == 0.0 || is_parallel(dir, Vec3::from(up)) {
            return Err(Error::arg(
                "up",
                format!("must not be zero nor parallel to the view direction {dir:?}, got {up:?}"),
            ));
        }
        camera.up = up;
        Ok(camera)
    }

    /// Checks the fields: finite, eye != target, `up` non-zero, fov in (0, 180), 0 < near < far.
    /// An `up` parallel to the view direction is not an error (see [`Camera::view_proj`]).
    pub fn validate(&self) -> Result<()> {
        check_finite3("eye", self.eye)?;
        check_finite3("target", self.target)?;
        check_finite3("up", self.up)?;
        let dir = Vec3::from(self.target) - Vec3::from(self.eye);
        if !dir.is_finite() || dir.length_squared() == 0.0 {
            return Err(Error::arg("target", format!("must differ from eye {:?}, got {:?}", self.eye, self.target)));
        }
        ensure_arg!(Vec3::from(self.up).length_squared() > 0.0, "up", "must be non-zero");
        if !(self.fov_y_deg > 0.0 && self.fov_y_deg < 180.0) {
            return Err(Error::arg("fov_y_deg", format!("expected a value in (0, 180), got {}", self.fov_y_deg)));
        }
        if !(self.near.is_finite() && self.near > 0.0) {
            return Err(Error::arg("near", format!("expected a finite positive value, got {}", self.near)));
        }
        if !(self.far.is_finite() && self.far > self.near) {
            return Err(Error::arg(
                "far",
                format!("expected a finite value above near = {}, got {}", self.near, self.far),
            ));
        }
        Ok(())
    }

    /// The view-projection matrix for `aspect` = width / height: `Mat4::perspective_rh` (depth 0 at
    /// the near plane to 1 at the far plane, the wgpu convention) times `Mat4::look_at_rh`. The GPU
    /// uses this very matrix, so both renderers see the same clip-space positions.
    ///
    /// If `up` is parallel to the view direction, +y is used instead (+z if the view is along y),
    /// the same fallback as [`Camera::look_at`]. The result is meaningless (but no panic) for an
    /// invalid camera or a non-positive `aspect`.
    pub fn view_proj(&self, aspect: f32) -> Mat4 {
        let eye = Vec3::from(self.eye);
        let target = Vec3::from(self.target);
        let dir = target - eye;
        let mut up = Vec3::from(self.up);
        if is_parallel(dir, up) {
            up = if is_parallel(dir, Vec3::Y) { Vec3::Z } else { Vec3::Y };
        }
        Mat4::perspective_rh(self.fov_y_deg.to_radians(), aspect, self.near, self.far)
            * Mat4::look_at_rh(eye, target, up)
    }
}

fn is_parallel(a: Vec3, b: Vec3) -> bool {
    let (a, b) = (a.normalize_or_zero(), b.normalize_or_zero());
    a.cross(b).length() <= PARALLEL_SIN
}
