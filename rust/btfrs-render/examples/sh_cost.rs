//! Frame cost of the double-SH shader against PTM-RGB on this adapter, and of the SH shader with
//! its coefficient counts as constants (what pipeline-overridable constants give the compiler).
//! `cargo run --release -p btfrs-render --example sh_cost`
use btfrs_core::materials::{generate, MaterialSpec, Preset};
use btfrs_core::Monitor;
use btfrs_fit::{fit_ptm, fit_sh, PtmOptions, ShOptions};
use btfrs_render::scene::{Camera, Light, Mesh};
use btfrs_render::{gpu, Gpu, View, WithShader};

fn best(gpu: &Gpu, m: &dyn btfrs_fit::Renderable, view: &View<'_>) -> f64 {
    let up = gpu::upload(gpu, m).unwrap();
    let mut best = f64::INFINITY;
    for _ in 0..3 {
        let (_, t) = gpu::render(gpu, &up, view).unwrap();
        best = best.min(t.draw_ms);
    }
    best
}

fn main() {
    let gpu = Gpu::shared().expect("adapter");
    println!("{}", gpu.describe());
    let btf = generate(&MaterialSpec::new(Preset::Knit, 32, 1), &Monitor::new()).unwrap();
    let ptm = fit_ptm(&btf.as_ref(), &PtmOptions::default(), &Monitor::new()).unwrap();
    let sh = fit_sh(&btf.as_ref(), &ShOptions::default(), &Monitor::new()).unwrap();
    let mesh = Mesh::sphere(1.0, 64, 32).unwrap();
    let cam = Camera::look_at([0.0, -3.0, 2.0], [0.0, 0.0, 0.0], 40.0).unwrap();
    let lights = [Light::Point { position: [2.0, -2.0, 3.0], intensity: [8.0; 3] }];
    let view = View {
        mesh: &mesh,
        camera: &cam,
        lights: &lights,
        width: 512,
        height: 512,
        uv_scale: [4.0, 4.0],
        coords: None,
        tiles: None,
        filter: None,
    };
    println!("ptm {:8.1} ms", best(&gpu, &ptm, &view));
    println!("sh  {:8.1} ms", best(&gpu, &sh, &view));
    let src = <btfrs_fit::Sh as btfrs_fit::GpuLayout>::SHADER.source;
    let fixed: &'static str = Box::leak(src.replace("mp.kv", "25u").replace("mp.kl", "25u").into_boxed_str());
    println!("sh constant sizes {:8.1} ms", best(&gpu, &WithShader(&sh, fixed), &view));
}
