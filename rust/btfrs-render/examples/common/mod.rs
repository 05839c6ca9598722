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

/// The best draw time of `repeat` frames of `m` after one that builds the pipeline.
#[allow(dead_code)] // not every example times frames
pub fn best(gpu: &btfrs_render::Gpu, m: &dyn btfrs_fit::Renderable, view: &View<'_>, repeat: usize) -> f64 {
    use btfrs_render::gpu;
    let up = gpu::upload(gpu, m).unwrap();
    let _ = gpu::render(gpu, &up, view).unwrap(); // builds the pipeline
    (0..repeat).map(|_| gpu::render(gpu, &up, view).unwrap().1.draw_ms).fold(f64::INFINITY, f64::min)
}

/// The frame benches' start: the adapter (printed), knit at `size`² (seed 1) and its PTM-RGB
/// fit (the 3x target's reference).
#[allow(dead_code)] // not every example times frames
pub fn frame_bench(size: usize) -> (std::sync::Arc<btfrs_render::Gpu>, btfrs_core::Btf, btfrs_fit::Ptm) {
    use btfrs_core::materials::{generate, MaterialSpec, Preset};
    let gpu = btfrs_render::Gpu::shared().expect("adapter");
    println!("{}", gpu.describe());
    let mon = btfrs_core::Monitor::new();
    let btf = generate(&MaterialSpec::new(Preset::Knit, size, 1), &mon).unwrap();
    let ptm = btfrs_fit::fit_ptm(&btf.as_ref(), &btfrs_fit::PtmOptions::default(), &mon).unwrap();
    (gpu, btf, ptm)
}
