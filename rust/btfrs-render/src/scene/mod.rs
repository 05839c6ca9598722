//! What is rendered: triangle meshes with per-vertex tangent frames ([`mesh`]), a perspective
//! camera ([`camera`]) and lights ([`lights`]). The types are re-exported here, so
//! `btfrs_render::scene::{Mesh, Camera, Light}` is the path to use.
//!
//! The frames follow the texture parameterisation, as paper 002 (section 4.2 "Rendering")
//! requires for BTFs: see [`mesh`] for that and for the UV convention.

pub mod camera;
pub mod lights;
pub mod mesh;

pub use camera::Camera;
pub use lights::Light;
pub use mesh::Mesh;

use btfrs_core::{Error, Result};

fn check_positive(name: &str, value: f32) -> Result<()> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(Error::arg(name, format!("expected a finite positive value, got {value}")))
    }
}

fn check_finite3(name: &str, v: [f32; 3]) -> Result<()> {
    if v.iter().all(|c| c.is_finite()) {
        Ok(())
    } else {
        Err(Error::arg(name, format!("not finite: {v:?}")))
    }
}

#[cfg(test)]
mod tests;
