//! The neural decoder's frame against PTM-RGB's (the 3x target), measured in one process: a 512²
//! sphere under one point light, knit 32², the default decoder and a smaller one.
//! `ALT_NEURAL=path.wgsl` adds rows drawn with another `neural.wgsl`.
//! `cargo run --release -p btfrs-render --example neural_frame_variants`
use btfrs_core::Monitor;
use btfrs_fit::neural::{fit_neural, NeuralOptions};
use btfrs_render::WithShader;

mod common;

fn main() {
    let (gpu, btf, ptm) = common::frame_bench(32);
    let mon = Monitor::new();
    let b = btf.as_ref();
    let neural = fit_neural(&b, &NeuralOptions { steps: Some(300), ..NeuralOptions::default() }, &mon).unwrap();
    let small =
        NeuralOptions { steps: Some(300), latents: 4, hidden: 32, features: Some(8), ..NeuralOptions::default() };
    let small = fit_neural(&b, &small, &mon).unwrap();
    let scene = common::Sphere::new();
    let one = scene.view(&scene.point, (512, 512));
    let alt: Option<&'static str> =
        std::env::var("ALT_NEURAL").ok().map(|p| &*Box::leak(std::fs::read_to_string(p).unwrap().into_boxed_str()));
    let mut rows: Vec<(&str, Box<dyn btfrs_fit::Renderable + '_>)> = vec![
        ("PTM-RGB", Box::new(&ptm)),
        ("neural, default", Box::new(&neural)),
        ("neural, 4 latents 32 units", Box::new(&small)),
    ];
    if let Some(a) = alt {
        rows.push(("neural, default, ALT_NEURAL", Box::new(WithShader(&neural, a))));
        rows.push(("neural, small, ALT_NEURAL", Box::new(WithShader(&small, a))));
    }
    println!("{:<32} {:>12} {:>8}", "model", "512² 1 light", "x PTM");
    let mut ptm_ms = 0.0;
    for (name, m) in &rows {
        let a = common::best(&gpu, m.as_ref(), &one, 3);
        if ptm_ms == 0.0 {
            ptm_ms = a;
        }
        println!("{name:<32} {a:>10.1}ms {:>8.2}", a / ptm_ms);
    }
}
