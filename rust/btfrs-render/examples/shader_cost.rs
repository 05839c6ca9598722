//! Frame cost of shader variants, measured in one process so ratios do not depend on how busy
//! the machine was: a 512² sphere under one point light and a 640 x 480 sphere under the sky's
//! 64 importance-sampled lights (the `--env-only` bench's scenes), knit 32², for PTM-RGB (the
//! reference of the 3x target), double SH 25x25 with its generated straight-line variant and
//! with the generic loop shader, and RBF / bilinear. `ALT_LIGHT_PCA=path.wgsl` adds rows for
//! RBF and bilinear drawn with another `light_pca.wgsl` (e.g. the one before 7ed5146: `git show c597a3c:shaders_wgsl/light_pca.wgsl`).
//! `cargo run --release -p btfrs-render --example shader_cost`
use btfrs_core::Monitor;
use btfrs_fit::{fit_bilinear, fit_rbf, fit_sh, BilinearOptions, RbfOptions, ShOptions};
use btfrs_render::environment::Environment;
use btfrs_render::WithShader;

mod common;

fn main() {
    let (gpu, btf, ptm) = common::frame_bench(32);
    let mon = Monitor::new();
    let b = btf.as_ref();
    let sh = fit_sh(&b, &ShOptions::default(), &mon).unwrap();
    let rbf = fit_rbf(&b, &RbfOptions::default(), &mon).unwrap();
    let bil = fit_bilinear(&b, &BilinearOptions::default(), &mon).unwrap();
    let scene = common::Sphere::new();
    let sky = Environment::sky([0.3, 0.2, 0.9], 3.0, 128, 0.2).unwrap().sample_lights(64, 0).unwrap();
    let (one, env) = (scene.view(&scene.point, (512, 512)), scene.view(&sky, (480, 640)));
    let generic = btfrs_fit::sh::wgsl::GENERIC;
    let alt: Option<&'static str> =
        std::env::var("ALT_LIGHT_PCA").ok().map(|p| &*Box::leak(std::fs::read_to_string(p).unwrap().into_boxed_str()));
    let mut rows: Vec<(&str, Box<dyn btfrs_fit::Renderable + '_>, usize)> = vec![
        ("PTM-RGB", Box::new(&ptm), 5),
        ("SH 25x25, generated variant", Box::new(&sh), 3),
        ("SH 25x25, generic loops", Box::new(WithShader(&sh, generic)), 1),
        ("RBF-9", Box::new(&rbf), 3),
        ("Bilinear-9", Box::new(&bil), 3),
    ];
    if let Some(a) = alt {
        rows.push(("RBF-9, ALT_LIGHT_PCA", Box::new(WithShader(&rbf, a)), 3));
        rows.push(("Bilinear-9, ALT_LIGHT_PCA", Box::new(WithShader(&bil, a)), 3));
    }
    println!("{:<30} {:>12} {:>8} {:>16}", "model", "512² 1 light", "x PTM", "640x480 env 64");
    let mut ptm_ms = 0.0;
    for (name, m, repeat) in &rows {
        let (a, e) =
            (common::best(&gpu, m.as_ref(), &one, *repeat), common::best(&gpu, m.as_ref(), &env, (*repeat).min(2)));
        if ptm_ms == 0.0 {
            ptm_ms = a;
        }
        println!("{name:<30} {a:>10.1}ms {:>8.2} {:>14.2}s", a / ptm_ms, e / 1e3);
    }
}
