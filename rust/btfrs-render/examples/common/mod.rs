//! The scene the render examples and the frame benches time, as the Python bench's frames: a unit sphere (64 x 32
//! segments) seen from (0, -3, 2) with a 40 degree field of view, the texture repeated 4 x 4,
//! and one point light at (2, -2, 3).
use btfrs_render::scene::{Camera, Light, Mesh};
use btfrs_render::View;

/// The sphere, the camera and the point light.
pub struct Sphere {
    pub mesh: Mesh,
    pub camera: Camera,
    pub point: [Light; 1],
}

impl Sphere {
    pub fn new() -> Sphere {
        Sphere {
            mesh: Mesh::sphere(1.0, 64, 32).expect("a valid sphere"),
            camera: Camera::look_at([0.0, -3.0, 2.0], [0.0, 0.0, 0.0], 40.0).expect("a valid camera"),
            point: [Light::Point { position: [2.0, -2.0, 3.0], intensity: [8.0; 3] }],
        }
    }

    /// A `height x width` frame of the sphere under `lights`.
    pub fn view<'a>(&'a self, lights: &'a [Light], (height, width): (usize, usize)) -> View<'a> {
        View {
            mesh: &self.mesh,
            camera: &self.camera,
            lights,
            width,
            height,
            uv_scale: [4.0, 4.0],
            coords: None,
            tiles: None,
            filter: None,
        }
    }
}
