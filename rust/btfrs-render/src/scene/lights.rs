//! The lights of a scene: point lights (inverse-square falloff) and directional lights, with
//! the direction and irradiance each delivers at a shaded point. The renderers evaluate the BTF
//! for the light direction in the point's tangent frame and scale it by this irradiance.

use super::check_finite3;
use btfrs_core::{ensure_arg, Result};
use glam::Vec3;

/// A light. Intensities are RGB.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Light {
    /// Irradiance intensity / distance^2 from `position`.
    Point { position: [f32; 3], intensity: [f32; 3] },
    /// Constant irradiance `intensity` from `direction` (unit, pointing *towards* the light; a
    /// non-unit direction is normalised by [`Light::at`]).
    Directional { direction: [f32; 3], intensity: [f32; 3] },
}

impl Light {
    /// Checks that everything is finite, intensities are non-negative and a direction is non-zero.
    pub fn validate(&self) -> Result<()> {
        let intensity = match self {
            Light::Point { position, intensity } => {
                check_finite3("position", *position)?;
                intensity
            }
            Light::Directional { direction, intensity } => {
                check_finite3("direction", *direction)?;
                ensure_arg!(Vec3::from(*direction).length_squared() > 0.0, "direction", "must be non-zero");
                intensity
            }
        };
        check_finite3("intensity", *intensity)?;
        ensure_arg!(intensity.iter().all(|&c| c >= 0.0), "intensity", "must be non-negative, got {intensity:?}");
        Ok(())
    }

    /// The unit direction from world point `p` towards the light, and the irradiance (RGB) the light
    /// delivers at `p` on a surface facing it. At the position of a point light itself, where both
    /// are undefined, it returns zeros (no contribution) rather than NaN.
    pub fn at(&self, p: Vec3) -> (Vec3, Vec3) {
        match *self {
            Light::Point { position, intensity } => {
                let d = Vec3::from(position) - p;
                let r2 = d.length_squared();
                if r2 > 0.0 && r2.is_finite() {
                    (d / r2.sqrt(), Vec3::from(intensity) / r2)
                } else {
                    (Vec3::ZERO, Vec3::ZERO)
                }
            }
            Light::Directional { direction, intensity } => {
                (Vec3::from(direction).normalize_or_zero(), Vec3::from(intensity))
            }
        }
    }
}
