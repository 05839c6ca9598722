//! Where a frame's time goes on this adapter: the same scene with the PTM shader, with a shader
//! whose model does nothing, and with a model that only searches the view slots.
//! `cargo run --release -p btfrs-render --example frame_cost`
use btfrs_core::materials::{generate, MaterialSpec, Preset};
use btfrs_core::Monitor;
use btfrs_fit::{fit_ptm, PtmOptions};
use btfrs_render::{gpu, Gpu, WithShader};

mod common;

fn main() {
    let gpu = Gpu::shared().expect("adapter");
    println!("{}", gpu.describe());
    let btf = generate(&MaterialSpec::new(Preset::Weave, 64, 2), &Monitor::new()).unwrap();
    let ptm = fit_ptm(&btf.as_ref(), &PtmOptions::default(), &Monitor::new()).unwrap();
    let scene = common::Sphere::new();
    let view = scene.view(&scene.point, (512, 512));
    let nothing = "struct ViewQuery { x: f32 };\nfn view_query(v: vec3<f32>) -> ViewQuery { return ViewQuery(v.z); }\nfn eval_model(texel: u32, vq: ViewQuery, l: vec3<f32>) -> vec3<f32> { return vec3<f32>(vq.x * l.z); }\n";
    let search = "struct ViewQuery { w: Weights3 };\nfn view_query(v: vec3<f32>) -> ViewQuery { return ViewQuery(interp3(0u, mp.n_views, mp.view_table, v)); }\nfn eval_model(texel: u32, vq: ViewQuery, l: vec3<f32>) -> vec3<f32> { return vec3<f32>(vq.w.w0, vq.w.w1, f32(vq.w.i0)); }\n";
    for (name, src) in [
        ("nothing", nothing),
        ("view search only", search),
        ("ptm", <btfrs_fit::Ptm as btfrs_fit::GpuLayout>::SHADER.source),
    ] {
        let m = WithShader(&ptm, src);
        let up = gpu::upload(&gpu, &m).unwrap();
        let mut best = f64::INFINITY;
        for _ in 0..4 {
            let (_, t) = gpu::render(&gpu, &up, &view).unwrap();
            best = best.min(t.draw_ms);
        }
        println!("{name:<18} {best:8.1} ms draw (best of 4, 512^2 sphere)");
    }
}
