//! Frame times on this machine's adapter (lavapipe without a GPU): every registered model (its
//! first example option set; PTM-RGB, the reference of the "every model within 3x of PTM"
//! target, and SH 25x25, the slowest) and the raw BTF on knit 32², as a 256² sphere under one
//! point light and as a 320 x 240 sphere under the built-in sky's 64 importance-sampled lights
//! (paper 002, section 4: 3.2 to 4.5 minutes per 640 x 480 frame); double SH also by the SH
//! method. `python -m btfrs.bench --env-only` measures the same at 512² and 640 x 480 (the
//! figures in BENCHMARKS.md); these are smaller so the whole group runs in about a minute.
//! Each iteration is a whole frame: draw and read-back.
use btfrs_core::materials::{generate, MaterialSpec, Preset};
use btfrs_core::Monitor;
use btfrs_fit::registry::MODELS;
use btfrs_fit::{DynModel, RawModel, Renderable};
use btfrs_render::environment::Environment;
use btfrs_render::sh_env::ShEnvironment;
use btfrs_render::{gpu, Gpu};
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use std::time::Duration;

// The scene of the render examples.
#[path = "../examples/common/mod.rs"]
mod common;

fn bench(c: &mut Criterion) {
    let gpu = Gpu::shared().expect("a wgpu adapter (lavapipe: apt-get install mesa-vulkan-drivers)");
    let btf = generate(&MaterialSpec::new(Preset::Knit, 32, 1), &Monitor::new()).unwrap();
    let b = btf.as_ref();
    let scene = common::Sphere::new();
    let env = Environment::sky([0.3, 0.2, 0.9], 3.0, 128, 0.2).unwrap();
    let sky = env.sample_lights(64, 0).unwrap();
    let (one, many) = (scene.view(&scene.point, (256, 256)), scene.view(&sky, (240, 320)));

    let mut fitted: Vec<(&str, Box<dyn DynModel>, &str)> = Vec::new();
    for e in MODELS {
        let pick = match e.kind {
            "ptm" => "PTM-RGB",
            "sh" => "SH-CLS 25x25",
            _ => e.examples[0].0,
        };
        let (label, options) = e.examples.iter().find(|x| x.0 == pick).unwrap_or(&e.examples[0]);
        fitted.push((label, e.fit_json(&b, options, &Monitor::new()).unwrap(), e.renderers[0]));
    }
    let raw = RawModel::new(b).unwrap();
    // (label, renderer, the light coefficients of a double-SH model for the SH method)
    let mut models: Vec<(&str, Box<dyn Renderable + '_>, Option<usize>)> = vec![("raw", Box::new(&raw), None)];
    for (label, m, method) in &fitted {
        let sh = m.sh_expansion().map(|s| s.light_coeffs);
        models.push((label, m.renderer(method, gpu.limits.max_texture_dimension_3d as usize).unwrap(), sh));
    }

    let mut g = c.benchmark_group("frame");
    g.sample_size(10).warm_up_time(Duration::from_millis(500)).measurement_time(Duration::from_secs(2));
    for (label, m, sh) in &models {
        let up = gpu::upload(&gpu, m.as_ref()).unwrap();
        g.bench_function(BenchmarkId::new("sphere_256_point", label), |bch| {
            bch.iter(|| gpu::render(&gpu, &up, &one).unwrap())
        });
        g.bench_function(BenchmarkId::new("sphere_320x240_sky64", label), |bch| {
            bch.iter(|| gpu::render(&gpu, &up, &many).unwrap())
        });
        if let Some(kl) = *sh {
            let she = ShEnvironment::new(&env, kl).unwrap();
            g.bench_function(BenchmarkId::new("sphere_320x240_sh_method", label), |bch| {
                bch.iter(|| gpu::render_env_sh(&gpu, &up, &many, &she).unwrap())
            });
        }
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
