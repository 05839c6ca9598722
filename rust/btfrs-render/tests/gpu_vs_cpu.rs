//! Every model shader against the CPU reference renderer, on every kind of scene, plain, with a
//! coordinate map and with a Wang tile map: the images must agree to >= 40 dB PSNR. The models come from the
//! registry (every example option set of every model, every renderer), so a new model is tested
//! here without naming it. Runs on whatever adapter the machine has (lavapipe in CI); there is
//! no skipping: a missing adapter fails the test.

use btfrs_core::materials::{generate, MaterialSpec, Preset};
use btfrs_core::{Btf, Monitor};
use btfrs_fit::gpu::GpuLayout;
use btfrs_fit::registry::MODELS;
use btfrs_fit::{fit_ptm, fit_sh, PtmOptions, RawModel, Renderable, ShOptions};
use btfrs_render::cpu::render_cpu;
use btfrs_render::filter::{Filter, MipChain, Source};
use btfrs_render::scene::{Camera, Light, Mesh};
use btfrs_render::{gpu, Gpu, TileMap, View, WithShader};

fn psnr(a: &[f32], b: &[f32]) -> f64 {
    let peak = a.iter().chain(b).fold(0.0f32, |m, &x| m.max(x)) as f64;
    let mse = a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum::<f64>() / a.len() as f64;
    if mse == 0.0 {
        f64::INFINITY
    } else {
        10.0 * (peak * peak / mse).log10()
    }
}

fn material() -> Btf {
    let mut spec = MaterialSpec::new(Preset::Bumps, 16, 3);
    // A coarser direction set keeps the raw BTF small; the interpolation code is the same.
    spec.views = btfrs_core::directions::ubo81().into_iter().step_by(2).collect();
    generate(&spec, &Monitor::new()).unwrap()
}

/// A bumpy disc-like mesh built from arrays (frames computed from UV derivatives).
fn wavy_mesh() -> Mesh {
    let n = 24;
    let mut pos = Vec::new();
    let mut uv = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            let (u, v) = (i as f32 / n as f32, j as f32 / n as f32);
            let (x, y) = (2.0 * u - 1.0, 2.0 * v - 1.0);
            pos.push([x, y, 0.15 * (3.0 * x).sin() * (2.0 * y).cos()]);
            uv.push([u, v]);
        }
    }
    let mut faces = Vec::new();
    for j in 0..n {
        for i in 0..n {
            let a = (j * (n + 1) + i) as u32;
            faces.push([a, a + 1, a + n as u32 + 2]);
            faces.push([a, a + n as u32 + 2, a + n as u32 + 1]);
        }
    }
    Mesh::from_arrays(&pos, &uv, &faces, None).unwrap()
}

fn scenes() -> Vec<(&'static str, Mesh, Camera)> {
    vec![
        ("plane", Mesh::plane(2.0), Camera::look_at([0.3, -2.0, 1.6], [0.0, 0.0, 0.0], 50.0).unwrap()),
        (
            "sphere",
            Mesh::sphere(1.0, 48, 24).unwrap(),
            Camera::look_at([0.0, -3.0, 2.0], [0.0, 0.0, 0.0], 40.0).unwrap(),
        ),
        // Looking at the +x side, where the sphere's and cylinder's UV seams are.
        (
            "cylinder",
            Mesh::cylinder(0.8, 1.6, 48).unwrap(),
            Camera::look_at([3.0, 0.5, 1.0], [0.0, 0.0, 0.0], 45.0).unwrap(),
        ),
        ("mesh", wavy_mesh(), Camera::look_at([0.5, -2.2, 1.8], [0.0, 0.0, 0.0], 45.0).unwrap()),
    ]
}

fn lights() -> Vec<Light> {
    vec![
        Light::Point { position: [2.0, -2.0, 3.0], intensity: [8.0, 8.0, 8.0] },
        Light::Directional { direction: [-0.6, -0.3, 0.74], intensity: [0.5, 0.45, 0.4] },
    ]
}

fn coords(h: usize, w: usize) -> (usize, usize, Vec<u32>) {
    // A 40 x 24 map pointing into the sample with a shift and a flip (any map will do).
    let (mw, mh) = (40usize, 24usize);
    let m = (0..mw * mh).map(|i| ((i % mw * 7 + 3) % w) as u32 | ((((i / mw) * 5 + 1) % h) as u32) << 16).collect();
    (mw, mh, m)
}

/// A Wang-style tile map: a 3 x 2 atlas of 5^2 tiles with scattered texel ids, a 7 x 4 layout
/// of random atlas tiles (any map will do: the lookup is what is checked).
fn tile_map(h: usize, w: usize) -> (Vec<u32>, Vec<u32>) {
    let atlas = (0..3 * 2 * 25).map(|i: usize| ((i * 37 + 11) % (h * w)) as u32).collect();
    let layout = (0..7 * 4).map(|i: usize| ((i * 5 + 1) % 3) as u32 | (((i * 3) % 2) as u32) << 16).collect();
    (atlas, layout)
}

/// A view without coordinate or tile map.
fn plain_view<'a>(
    mesh: &'a Mesh,
    cam: &'a Camera,
    lights: &'a [Light],
    size: (usize, usize),
    uv_scale: [f32; 2],
) -> View<'a> {
    View { mesh, camera: cam, lights, width: size.0, height: size.1, uv_scale, coords: None, tiles: None, filter: None }
}

fn check(gpu: &Gpu, name: &str, model: &dyn Renderable) -> f64 {
    let up = gpu::upload(gpu, model).unwrap();
    let (h, w) = model.shade_dims();
    let (mw, mh, map) = coords(h, w);
    let (atlas, layout) = tile_map(h, w);
    let tiles = TileMap {
        tile: 5,
        atlas_cols: 3,
        atlas_rows: 2,
        atlas: &atlas,
        layout_cols: 7,
        layout_rows: 4,
        layout: &layout,
    };
    let lights = lights();
    let mut worst = f64::INFINITY;
    for (scene, mesh, cam) in scenes() {
        for with_map in [0, 1, 2] {
            let view = View {
                mesh: &mesh,
                camera: &cam,
                lights: &lights,
                width: 64,
                height: 56,
                uv_scale: [3.0, 2.0],
                coords: (with_map == 1).then_some((mw, mh, &map[..])),
                tiles: (with_map == 2).then_some(tiles),
                filter: None,
            };
            let (g, _) = gpu::render(gpu, &up, &view).unwrap();
            let c = render_cpu(model, &view).unwrap();
            let p = psnr(&g, &c);
            let lit = c.iter().filter(|&&x| x > 0.0).count();
            assert!(lit > 64 * 56 / 10, "{name} on {scene}: the image is almost empty");
            assert!(p >= 40.0, "{name} on {scene} (map mode {with_map}): GPU vs CPU PSNR {p:.1} dB < 40");
            worst = worst.min(p);
            // Filtered lookups (medoid levels, which every model supports) on the plane: the
            // CPU reference implements the same filter.
            if scene == "plane" {
                let sig = btfrs_render::filter::signatures(model);
                let source = match (with_map, &tiles) {
                    (1, _) => Source::Coords(mw, mh, &map, w),
                    (2, t) => Source::Tiles(t),
                    _ => Source::Sample(h, w),
                };
                let chain = MipChain::build(source, &sig, btfrs_render::filter::SIGNATURE_LEN, h * w).unwrap();
                for f in [Filter::Bilinear, Filter::Trilinear] {
                    let v = View { filter: Some((f, &chain)), ..view };
                    let (g, _) = gpu::render(gpu, &up, &v).unwrap();
                    let c = render_cpu(model, &v).unwrap();
                    let p = psnr(&g, &c);
                    assert!(
                        p >= 40.0,
                        "{name} on {scene} (map mode {with_map}, {f:?}): GPU vs CPU PSNR {p:.1} dB < 40"
                    );
                    worst = worst.min(p);
                }
            }
        }
    }
    worst
}

#[test]
fn every_model_matches_the_cpu_reference_on_every_scene() {
    let gpu = Gpu::shared().expect("a wgpu adapter (lavapipe: apt-get install mesa-vulkan-drivers)");
    let btf = material();
    let b = btf.as_ref();
    let raw = RawModel::new(b).unwrap();
    eprintln!("raw: worst PSNR {:.1} dB on {}", check(&gpu, "raw", &raw), gpu.describe());
    let max_3d = gpu.limits.max_texture_dimension_3d as usize;
    let mut checked = 0;
    for e in MODELS {
        for (label, options) in e.examples {
            let m = e.fit_json(&b, options, &Monitor::new()).unwrap();
            for method in e.renderers {
                let r = m.renderer(method, max_3d).unwrap();
                let p = check(&gpu, label, r.as_ref());
                eprintln!("{label} ({method}): worst PSNR {p:.1} dB");
                checked += 1;
            }
        }
    }
    assert!(checked >= 10, "every example of every model, every renderer");
}

#[test]
fn double_sh_variants_match_the_cpu_reference_and_the_generic_shader() {
    // The SH renderer draws with code generated for the model's kv x kl (btfrs_fit::sh::wgsl)
    // up to 25 x 25: sizes beyond the registry's examples (kv != kl, kl not a multiple of 4,
    // degree 0), with one light (the direct path) and with two (the cached light
    // coefficients), against the CPU reference and against the generic loop shader, in both
    // generated forms (straight-line, and the middle form that sizes above 25 draw with).
    let gpu = Gpu::shared().expect("a wgpu adapter");
    let btf = material();
    let (_, mesh, cam) = scenes().swap_remove(1);
    let two = lights();
    let one = vec![two[0]];
    for (kv, kl) in [(9, 16), (25, 9), (1, 4), (9, 36)] {
        let opts = ShOptions { view_coeffs: kv, light_coeffs: kl, ..Default::default() };
        let sh = fit_sh(&btf.as_ref(), &opts, &Monitor::new()).unwrap();
        let variant = btfrs_fit::sh::wgsl::shader_for(kv, kl);
        let middle = btfrs_fit::sh::wgsl::middle_for(kv, kl);
        let drawn = btfrs_fit::gpu::GpuModel::shader(&sh);
        let small = kv <= btfrs_fit::sh::wgsl::MAX_STRAIGHT_LINE && kl <= btfrs_fit::sh::wgsl::MAX_STRAIGHT_LINE;
        assert_eq!(
            drawn,
            if small { variant } else { middle },
            "{kv} x {kl}: straight-line up to 16, else the middle form"
        );
        assert!(variant.source.contains(&format!("y: array<f32, {kv}>")));
        let up_generic = gpu::upload(&gpu, &WithShader(&sh, btfrs_fit::sh::wgsl::GENERIC)).unwrap();
        for (form, shader) in [("straight-line", variant), ("middle", middle)] {
            let up = gpu::upload(&gpu, &WithShader(&sh, shader.source)).unwrap();
            for lights in [&one, &two] {
                let view = plain_view(&mesh, &cam, lights, (96, 80), [3.0, 2.0]);
                let (g, _) = gpu::render(&gpu, &up, &view).unwrap();
                let (gg, _) = gpu::render(&gpu, &up_generic, &view).unwrap();
                let c = render_cpu(&sh, &view).unwrap();
                assert!(c.iter().filter(|&&x| x > 0.0).count() > 96 * 80 / 10);
                let (p, pg) = (psnr(&g, &c), psnr(&g, &gg));
                let n = lights.len();
                eprintln!("SH {kv}x{kl} {form}, {n} light(s): {p:.1} dB vs CPU, {pg:.1} dB vs the generic shader");
                assert!(p >= 40.0, "SH {kv}x{kl} {form}, {n} light(s): GPU vs CPU PSNR {p:.1} dB < 40");
                assert!(pg >= 60.0, "SH {kv}x{kl} {form}, {n} light(s): against the generic {pg:.1} dB < 60");
            }
        }
    }
}

#[test]
fn light_bases_in_ycc_match_the_cpu_reference() {
    // The registry's RBF and bilinear examples are RGB; the shader's other branch (a PCA of the
    // luminance and one of the chroma pair, recombined per channel) is checked here on every
    // scene and lookup, and a shader that swaps the two chroma differences must fail.
    let gpu = Gpu::shared().expect("a wgpu adapter");
    let btf = material();
    let right = "luma + chroma.y, luma - chroma.x - chroma.y, luma + chroma.x";
    let source = <btfrs_fit::Rbf as GpuLayout>::SHADER.source;
    assert_eq!(source.matches(right).count(), 1, "light_pca.wgsl recombines YCC in one place");
    let swapped: &'static str = Box::leak(
        source.replace(right, "luma + chroma.x, luma - chroma.x - chroma.y, luma + chroma.y").into_boxed_str(),
    );
    for kind in ["rbf", "bilinear"] {
        let e = btfrs_fit::registry::lookup(kind).unwrap();
        let options = r#"{"components": 6, "chroma_components": 3, "colour": "ycc"}"#;
        let m = e.fit_json(&btf.as_ref(), options, &Monitor::new()).unwrap();
        let r = m.renderer(e.renderers[0], 2048).unwrap();
        let p = check(&gpu, kind, r.as_ref());
        eprintln!("{kind} ycc: worst PSNR {p:.1} dB");
        let (_, mesh, cam) = scenes().swap_remove(1);
        let lights = lights();
        let view = plain_view(&mesh, &cam, &lights, (96, 80), [3.0, 2.0]);
        let c = render_cpu(r.as_ref(), &view).unwrap();
        let (g, _) = gpu::render(&gpu, &gpu::upload(&gpu, &WithShader(r.as_ref(), swapped)).unwrap(), &view).unwrap();
        let bad = psnr(&g, &c);
        eprintln!("{kind} ycc, chroma swapped: {bad:.1} dB");
        assert!(bad < 40.0, "{kind}: a shader with Cb and Cr swapped passes the comparison ({bad:.1} dB)");
    }
}

#[test]
fn a_wrong_shader_fails_the_comparison() {
    let gpu = Gpu::shared().expect("a wgpu adapter");
    let btf = material();
    let ptm = fit_ptm(&btf.as_ref(), &PtmOptions::default(), &Monitor::new()).unwrap();
    // Mirror the light's y in the basis: a plausible bug that still renders a sensible image.
    let ptm_src = <btfrs_fit::Ptm as GpuLayout>::SHADER.source;
    let src = ptm_src.replace("c2 * (l.x * l.y)", "c2 * (-l.x * l.y)");
    assert_ne!(src, ptm_src);
    let bad = WithShader(&ptm, Box::leak(src.into_boxed_str()));
    let up = gpu::upload(&gpu, &bad).unwrap();
    let lights = lights();
    let (_, mesh, cam) = scenes().swap_remove(1);
    let view = plain_view(&mesh, &cam, &lights, (96, 80), [3.0, 2.0]);
    let (g, _) = gpu::render(&gpu, &up, &view).unwrap();
    let c = render_cpu(&ptm, &view).unwrap();
    let p = psnr(&g, &c);
    assert!(p < 40.0, "a wrong shader still reached {p:.1} dB: the comparison cannot catch bugs");
}

#[test]
fn bad_views_are_errors_not_crashes() {
    let gpu = Gpu::shared().expect("a wgpu adapter");
    let btf = material();
    let ptm = fit_ptm(&btf.as_ref(), &PtmOptions::default(), &Monitor::new()).unwrap();
    let up = gpu::upload(&gpu, &ptm).unwrap();
    let lights = lights();
    let (_, mesh, cam) = scenes().swap_remove(0);
    let base = plain_view(&mesh, &cam, &lights, (32, 32), [1.0, 1.0]);
    let too_big = gpu.limits.max_texture_dimension_2d as usize + 1;
    for (what, v) in [
        ("size", View { width: 0, ..base }),
        ("size", View { width: too_big, ..base }),
        ("lights", View { lights: &[], ..base }),
        ("uv_scale", View { uv_scale: [f32::NAN, 1.0], ..base }),
    ] {
        let e = gpu::render(&gpu, &up, &v).unwrap_err().to_string();
        assert!(e.starts_with(what), "{e}");
    }
    let outside = vec![16u32 | (3 << 16)];
    let e = gpu::render(&gpu, &up, &View { coords: Some((1, 1, &outside)), ..base }).unwrap_err().to_string();
    assert!(e.starts_with("coords:") && e.contains("outside the 16 x 16 sample"), "{e}");
}

#[test]
fn tile_maps_reproduce_plain_renders_and_are_validated() {
    // Independent of the lookup formula: a 1 x 1 layout of one tile holding the identity
    // arrangement of a sample of that size is the plain render; a 2 x 2 layout of that tile is
    // the plain render with uv_scale doubled. CPU reference (exact) and GPU (>= 40 dB).
    let gpu = Gpu::shared().expect("a wgpu adapter");
    let btf = material();
    let m = fit_ptm(&btf.as_ref(), &PtmOptions::default(), &Monitor::new()).unwrap();
    let up = gpu::upload(&gpu, &m).unwrap();
    let (h, w) = (btf.height, btf.width);
    assert_eq!(h, w);
    let ident: Vec<u32> = (0..(h * w) as u32).collect();
    let lights = lights();
    let (_, mesh, cam) = scenes().remove(0);
    let base = plain_view(&mesh, &cam, &lights, (64, 64), [1.0, 1.0]);
    let one = [0u32];
    let four = [0u32; 4];
    let t1 =
        TileMap { tile: w, atlas_cols: 1, atlas_rows: 1, atlas: &ident, layout_cols: 1, layout_rows: 1, layout: &one };
    let t2 = TileMap { layout_cols: 2, layout_rows: 2, layout: &four, ..t1 };
    let plain = render_cpu(&m, &base).unwrap();
    assert_eq!(render_cpu(&m, &View { tiles: Some(t1), ..base }).unwrap(), plain);
    let doubled = render_cpu(&m, &View { uv_scale: [2.0, 2.0], ..base }).unwrap();
    let tiled = render_cpu(&m, &View { tiles: Some(t2), ..base }).unwrap();
    let same = doubled.iter().zip(&tiled).filter(|(a, b)| a == b).count();
    // uv * 2 and (uv mod 1/2) * 2 can round differently at a handful of cell borders.
    assert!(same as f64 > 0.995 * doubled.len() as f64, "{same} of {}", doubled.len());
    let (g, _) = gpu::render(&gpu, &up, &View { tiles: Some(t2), ..base }).unwrap();
    assert!(psnr(&g, &tiled) >= 40.0);
    // Errors name the tile map.
    let bad = [5u32];
    let e = render_cpu(&m, &View { tiles: Some(TileMap { layout: &bad, ..t1 }), ..base }).unwrap_err().to_string();
    assert!(e.starts_with("tiles:") && e.contains("outside the 1 x 1 atlas"), "{e}");
    let short = &ident[..10];
    let e =
        gpu::render(&gpu, &up, &View { tiles: Some(TileMap { atlas: short, ..t1 }), ..base }).unwrap_err().to_string();
    assert!(e.starts_with("tiles:") && e.contains("needs"), "{e}");
    let map = [0u32];
    let e = render_cpu(&m, &View { tiles: Some(t1), coords: Some((1, 1, &map)), ..base }).unwrap_err().to_string();
    assert!(e.contains("not both"), "{e}");
}
