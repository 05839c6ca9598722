//! Environment light (paper 002, section 4): the sampled method against the brute-force
//! quadrature over every lat-long pixel (CPU reference), its error falling with the sample
//! count; the SH method of double-SH models against its CPU reference and against that
//! quadrature; GPU = CPU for both.

use btfrs_core::materials::{generate, MaterialSpec, Preset};
use btfrs_core::{Btf, Monitor};
use btfrs_fit::{fit_ptm, fit_sh, ShOptions};
use btfrs_render::cpu::{render_cpu, render_cpu_env_sh};
use btfrs_render::environment::Environment;
use btfrs_render::scene::{Camera, Light, Mesh};
use btfrs_render::sh_env::ShEnvironment;
use btfrs_render::{gpu, Gpu, View};

fn psnr(a: &[f32], b: &[f32]) -> f64 {
    let peak = a.iter().chain(b).fold(0.0f32, |m, &x| m.max(x)) as f64;
    let mse = a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum::<f64>() / a.len() as f64;
    10.0 * (peak * peak / mse).log10()
}

/// Relative RMS difference over the covered pixels.
fn rel_rms(a: &[f32], reference: &[f32]) -> f64 {
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (x, y) in a.iter().zip(reference) {
        if *y > 0.0 {
            num += ((x - y) as f64).powi(2);
            den += (*y as f64).powi(2);
        }
    }
    (num / den).sqrt()
}

fn material() -> Btf {
    let mut spec = MaterialSpec::new(Preset::Bumps, 12, 3);
    spec.views = btfrs_core::directions::ubo81().into_iter().step_by(2).collect();
    generate(&spec, &Monitor::new()).unwrap()
}

fn scenes() -> Vec<(&'static str, Mesh, Camera)> {
    vec![
        ("plane", Mesh::plane(2.0), Camera::look_at([0.3, -2.0, 1.6], [0.0, 0.0, 0.0], 50.0).unwrap()),
        ("sphere", Mesh::sphere(1.0, 48, 24).unwrap(), Camera::look_at([0.0, -3.0, 2.0], [0.0; 3], 40.0).unwrap()),
    ]
}

fn view<'a>(mesh: &'a Mesh, cam: &'a Camera, lights: &'a [Light]) -> View<'a> {
    View {
        mesh,
        camera: cam,
        lights,
        width: 40,
        height: 32,
        uv_scale: [2.0, 2.0],
        coords: None,
        tiles: None,
        filter: None,
    }
}

#[test]
fn sampled_renders_converge_to_the_quadrature_over_every_pixel() {
    let gpu = Gpu::shared().expect("a wgpu adapter (lavapipe)");
    let btf = material();
    let ptm = fit_ptm(&btf.as_ref(), &Default::default(), &Monitor::new()).unwrap();
    let up = gpu::upload(&gpu, &ptm).unwrap();
    let env = Environment::sky([0.4, -0.5, 0.75], 3.0, 16, 0.3).unwrap();
    let all = env.quadrature_lights();
    for (scene, mesh, cam) in scenes() {
        let reference = render_cpu(&ptm, &view(&mesh, &cam, &all)).unwrap();
        let mut errors = Vec::new();
        for n in [16usize, 64, 256, 1024] {
            let lights = env.sample_lights(n, 7).unwrap();
            let (g, _) = gpu::render(&gpu, &up, &view(&mesh, &cam, &lights)).unwrap();
            let c = render_cpu(&ptm, &view(&mesh, &cam, &lights)).unwrap();
            assert!(psnr(&g, &c) >= 40.0, "{scene}, {n} samples: GPU vs CPU {:.1} dB", psnr(&g, &c));
            errors.push(rel_rms(&g, &reference));
        }
        eprintln!("{scene}: relative RMS error vs the quadrature at 16/64/256/1024 samples: {errors:.4?}");
        assert!(errors.windows(2).all(|w| w[1] < w[0]), "{scene}: the error must fall with n: {errors:?}");
        assert!(errors[3] < 0.02, "{scene}: {errors:?}");
        assert!(errors[0] > 2.0 * errors[3], "{scene}: {errors:?}");
    }
}

#[test]
fn the_sh_method_matches_its_reference_and_the_integral() {
    let gpu = Gpu::shared().expect("a wgpu adapter (lavapipe)");
    let btf = material();
    let env = Environment::sky([0.4, -0.5, 0.75], 3.0, 16, 0.3).unwrap();
    let all = env.quadrature_lights();
    for k in [9usize, 16] {
        let opts = ShOptions { light_coeffs: k, view_coeffs: k, ..Default::default() };
        let sh = fit_sh(&btf.as_ref(), &opts, &Monitor::new()).unwrap();
        let up = gpu::upload(&gpu, &sh).unwrap();
        let she = ShEnvironment::new(&env, k).unwrap();
        for (scene, mesh, cam) in scenes() {
            let v = view(&mesh, &cam, &[]);
            let (g, _) = gpu::render_env_sh(&gpu, &up, &v, &she).unwrap();
            let c = render_cpu_env_sh(&sh, &v, &she).unwrap();
            let p = psnr(&g, &c);
            let reference = render_cpu(&sh, &view(&mesh, &cam, &all)).unwrap();
            let e = rel_rms(&c, &reference);
            eprintln!("SH {k}x{k} on {scene}: GPU vs CPU {p:.1} dB; SH method vs quadrature {e:.4} relative RMS");
            assert!(p >= 40.0, "SH {k} on {scene}: GPU vs CPU {p:.1} dB");
            assert!(e < 0.04, "SH {k} on {scene}: {e}");
        }
    }
}
