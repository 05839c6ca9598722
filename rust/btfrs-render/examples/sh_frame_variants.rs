//! Double-SH frames against PTM-RGB's, with other WGSL forms of the SH shader: a 512² sphere
//! under one point light, knit 16², fitted at `N x N` coefficients (env `N`, default 64: the
//! largest size the fit makes). Prints the first frame (pipeline build and draw: run with
//! `MESA_SHADER_CACHE_DISABLE=true` so that every first frame compiles) and the best of 3 draws,
//! for PTM-RGB, the SH model's own shader, and each WGSL file given (drawn with `WithShader`,
//! their images compared with the own shader's). `--dump DIR` writes the generated middle form
//! and the generic shader there, to edit into variants.
//! `MESA_SHADER_CACHE_DISABLE=true cargo run --release -p btfrs-render --example sh_frame_variants -- [FILE.wgsl ...]`
use btfrs_core::materials::{generate, MaterialSpec, Preset};
use btfrs_core::Monitor;
use btfrs_fit::{fit_ptm, fit_sh, PtmOptions, ShOptions};
use btfrs_render::{gpu, Gpu, View, WithShader};
use std::time::Instant;

mod common;

fn time(gpu: &Gpu, m: &dyn btfrs_fit::Renderable, view: &View<'_>, repeat: usize) -> (f64, f64) {
    let up = gpu::upload(gpu, m).unwrap();
    let t = Instant::now();
    let _ = gpu::render(gpu, &up, view).unwrap();
    let first = t.elapsed().as_secs_f64();
    let best = (0..repeat).map(|_| gpu::render(gpu, &up, view).unwrap().1.draw_ms).fold(f64::INFINITY, f64::min);
    (first, best)
}

fn main() {
    let gpu = Gpu::shared().expect("adapter");
    let mon = Monitor::new();
    let size: usize = std::env::var("N").map(|s| s.parse().unwrap()).unwrap_or(64);
    let btf = generate(&MaterialSpec::new(Preset::Knit, 16, 1), &mon).unwrap();
    let b = btf.as_ref();
    let ptm = fit_ptm(&b, &PtmOptions::default(), &mon).unwrap();
    let sh = fit_sh(&b, &ShOptions { light_coeffs: size, view_coeffs: size, ..ShOptions::default() }, &mon).unwrap();
    let args: Vec<String> = std::env::args().skip(1).collect();
    if let [flag, dir] = &args[..] {
        if flag == "--dump" {
            let dir = std::path::Path::new(dir);
            std::fs::write(dir.join("middle.wgsl"), btfrs_fit::sh::wgsl::middle_source(size, size)).unwrap();
            std::fs::write(dir.join("generic.wgsl"), btfrs_fit::sh::wgsl::GENERIC).unwrap();
            return;
        }
    }
    let scene = common::Sphere::new();
    let view = scene.view(&scene.point, (512, 512));
    let (f, p) = time(&gpu, &ptm, &view, 5);
    println!("PTM-RGB: first {f:.2} s, draw {p:.0} ms");
    let (f0, d0) = time(&gpu, &sh, &view, 3);
    let up = gpu::upload(&gpu, &sh).unwrap();
    let reference = gpu::render(&gpu, &up, &view).unwrap().0;
    println!("SH {size}x{size} built-in: first {f0:.2} s, draw {d0:.0} ms ({:.2}x)", d0 / p);
    for path in args {
        let src: &'static str = Box::leak(std::fs::read_to_string(&path).unwrap().into_boxed_str());
        let w = WithShader(&sh, src);
        let (f, d) = time(&gpu, &w, &view, 3);
        let up = gpu::upload(&gpu, &w).unwrap();
        let img = gpu::render(&gpu, &up, &view).unwrap().0;
        let diff = img.iter().zip(&reference).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
        println!("{path}: first {f:.2} s, draw {d:.0} ms ({:.2}x), max diff {diff:.2e}", d / p);
    }
}
