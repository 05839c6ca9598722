//! Filtered lookups (bilinear, trilinear with appearance-medoid mips): a slanted plane's
//! trilinear render is closer to an 8 x 8 supersampled nearest render than the nearest render
//! is; lookups through a coordinate map or a tile map whose virtual texture is the sample
//! shifted equal the plain sample's with shifted texture coordinates (no seams at the maps'
//! discontinuities); GPU = CPU throughout.

use btfrs_core::materials::{generate, MaterialSpec, Preset};
use btfrs_core::{Btf, Monitor};
use btfrs_fit::{fit_ptm, Shade};
use btfrs_render::cpu::render_cpu;
use btfrs_render::filter::{signatures, Filter, MipChain, Source, SIGNATURE_LEN};
use btfrs_render::scene::{Camera, Light, Mesh};
use btfrs_render::{gpu, Gpu, TileMap, View};

fn psnr(a: &[f32], b: &[f32]) -> f64 {
    let peak = a.iter().chain(b).fold(0.0f32, |m, &x| m.max(x)) as f64;
    let mse = a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum::<f64>() / a.len() as f64;
    if mse == 0.0 {
        return f64::INFINITY;
    }
    10.0 * (peak * peak / mse).log10()
}

fn material() -> Btf {
    let mut spec = MaterialSpec::new(Preset::Bumps, 16, 5);
    spec.views = btfrs_core::directions::ubo81().into_iter().step_by(3).collect();
    generate(&spec, &Monitor::new()).unwrap()
}

fn lights() -> Vec<Light> {
    vec![Light::Directional { direction: [0.4, -0.3, 0.8], intensity: [1.0; 3] }]
}

/// A large plane seen at 45 degrees, the texture repeated so finely that one pixel covers about
/// two to six texels (more along the slope): nearest lookups alias there.
fn slanted() -> (Mesh, Camera) {
    (Mesh::plane(8.0), Camera::look_at([0.0, -3.0, 3.0], [0.0, 0.5, 0.0], 50.0).unwrap())
}

fn view<'a>(mesh: &'a Mesh, cam: &'a Camera, lights: &'a [Light], size: (usize, usize)) -> View<'a> {
    View {
        mesh,
        camera: cam,
        lights,
        width: size.0,
        height: size.1,
        uv_scale: [40.0, 40.0],
        coords: None,
        tiles: None,
        filter: None,
    }
}

/// Mean of each `k x k` block.
fn box_down(img: &[f32], w: usize, h: usize, k: usize) -> Vec<f32> {
    let (ow, oh) = (w / k, h / k);
    let mut out = vec![0.0f32; ow * oh * 3];
    for y in 0..h {
        for x in 0..w {
            for c in 0..3 {
                out[((y / k) * ow + x / k) * 3 + c] += img[(y * w + x) * 3 + c] / (k * k) as f32;
            }
        }
    }
    out
}

fn rms(a: &[f32], b: &[f32]) -> f64 {
    (a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum::<f64>() / a.len() as f64).sqrt()
}

#[test]
fn trilinear_is_closer_to_supersampling_than_nearest() {
    let gpu = Gpu::shared().expect("a wgpu adapter (lavapipe)");
    let btf = material();
    let ptm = fit_ptm(&btf.as_ref(), &Default::default(), &Monitor::new()).unwrap();
    let up = gpu::upload(&gpu, &ptm).unwrap();
    let sig = signatures(&ptm);
    assert_eq!(sig.len(), 16 * 16 * SIGNATURE_LEN);
    let chain = MipChain::build(Source::Sample(16, 16), &sig, SIGNATURE_LEN, 256).unwrap();
    let (mesh, cam) = slanted();
    let lights = lights();
    // The averaged pyramid (exact box filter of the model's linear arrays).
    let (avg_chain, groups) = MipChain::build_average(Source::Sample(16, 16), 256).unwrap();
    let pyramid = btfrs_fit::registry::mip_texels(&ptm, &groups).unwrap();
    let up_avg = gpu::upload(&gpu, pyramid.as_ref()).unwrap();
    let (w, h) = (64usize, 48usize);
    let (big, _) = gpu::render(&gpu, &up, &view(&mesh, &cam, &lights, (8 * w, 8 * h))).unwrap();
    let reference = box_down(&big, 8 * w, 8 * h, 8);
    let mut errors = Vec::new();
    for filter in [Filter::Nearest, Filter::Bilinear, Filter::Trilinear] {
        let v = View { filter: Some((filter, &chain)), ..view(&mesh, &cam, &lights, (w, h)) };
        let (g, _) = gpu::render(&gpu, &up, &v).unwrap();
        let c = render_cpu(&ptm, &v).unwrap();
        let p = psnr(&g, &c);
        assert!(p >= 40.0, "{filter:?}: GPU vs CPU {p:.1} dB");
        errors.push(rms(&g, &reference));
    }
    // Trilinear over the averaged pyramid.
    let v = View { filter: Some((Filter::Trilinear, &avg_chain)), ..view(&mesh, &cam, &lights, (w, h)) };
    let (g, _) = gpu::render(&gpu, &up_avg, &v).unwrap();
    let c = render_cpu(pyramid.as_ref(), &v).unwrap();
    assert!(psnr(&g, &c) >= 40.0, "averaged trilinear: GPU vs CPU {:.1} dB", psnr(&g, &c));
    errors.push(rms(&g, &reference));
    eprintln!(
        "RMS error vs 8x8 supersampled nearest: nearest {:.4}, bilinear {:.4}, trilinear (medoid levels) {:.4}, trilinear (averaged levels) {:.4}",
        errors[0], errors[1], errors[2], errors[3]
    );
    assert!(errors[3] < 0.8 * errors[0], "averaged trilinear {} vs nearest {}", errors[3], errors[0]);
}

/// The plane's texture coordinates shifted by `d` (texture units).
fn shifted_plane(d: [f32; 2]) -> Mesh {
    let mut m = Mesh::plane(2.0);
    for uv in &mut m.uvs {
        uv[0] += d[0];
        uv[1] += d[1];
    }
    m
}

#[test]
fn maps_filter_without_seams() {
    let gpu = Gpu::shared().expect("a wgpu adapter (lavapipe)");
    let btf = material();
    let ptm = fit_ptm(&btf.as_ref(), &Default::default(), &Monitor::new()).unwrap();
    let up = gpu::upload(&gpu, &ptm).unwrap();
    let sig = signatures(&ptm);
    let (n, s) = (16usize, 8usize);
    assert_eq!(ptm.shade_dims(), (n, n));
    let cam = Camera::look_at([0.2, -1.2, 1.4], [0.0, 0.0, 0.0], 60.0).unwrap();
    let lights = lights();
    let plain_chain = MipChain::build(Source::Sample(n, n), &sig, SIGNATURE_LEN, n * n).unwrap();
    // The sample shifted by s texels in x and y: map entry (x, y) -> ((x + s) % n, (y + s) % n),
    // a map with a jump in the middle of each axis; the same shift as a tile layout of the
    // sample's quadrants, swapped.
    let map: Vec<u32> = (0..n * n).map(|i| (((i % n + s) % n) | (((i / n + s) % n) << 16)) as u32).collect();
    let map_chain = MipChain::build(Source::Coords(n, n, &map, n), &sig, SIGNATURE_LEN, n * n).unwrap();
    let atlas: Vec<u32> = (0..(n * n) as u32).collect();
    let layout = [1u32 << 16 | 1, 1 << 16, 1, 0];
    let tiles = TileMap {
        tile: s,
        atlas_cols: 2,
        atlas_rows: 2,
        atlas: &atlas,
        layout_cols: 2,
        layout_rows: 2,
        layout: &layout,
    };
    let tile_chain = MipChain::build(Source::Tiles(&tiles), &sig, SIGNATURE_LEN, n * n).unwrap();
    let plane = Mesh::plane(2.0);
    let shifted = shifted_plane([s as f32 / n as f32, -(s as f32) / n as f32]);
    let size = (48usize, 40usize);
    let base = |mesh| View { uv_scale: [1.0, 1.0], ..view(mesh, &cam, &lights, size) };
    for filter in [Filter::Bilinear, Filter::Trilinear] {
        let want = render_cpu(&ptm, &View { filter: Some((filter, &plain_chain)), ..base(&shifted) }).unwrap();
        let through_map = View { coords: Some((n, n, &map[..])), filter: Some((filter, &map_chain)), ..base(&plane) };
        let c = render_cpu(&ptm, &through_map).unwrap();
        let (g, _) = gpu::render(&gpu, &up, &through_map).unwrap();
        let (pc, pg) = (psnr(&c, &want), psnr(&g, &c));
        eprintln!("{filter:?} through the coordinate map vs the shifted sample: {pc:.1} dB (GPU vs CPU {pg:.1} dB)");
        assert!(pc >= 50.0 && pg >= 40.0, "{filter:?}: {pc:.1} / {pg:.1} dB");
        // Tiles have fewer levels (the tile side), so compare bilinear only.
        if filter == Filter::Bilinear {
            let through_tiles = View { tiles: Some(tiles), filter: Some((filter, &tile_chain)), ..base(&plane) };
            let c = render_cpu(&ptm, &through_tiles).unwrap();
            let (g, _) = gpu::render(&gpu, &up, &through_tiles).unwrap();
            let (pc, pg) = (psnr(&c, &want), psnr(&g, &c));
            eprintln!("{filter:?} through the tile map vs the shifted sample: {pc:.1} dB (GPU vs CPU {pg:.1} dB)");
            assert!(pc >= 50.0 && pg >= 40.0, "tiles: {pc:.1} / {pg:.1} dB");
        }
    }
    // Nearest through the map also equals the shifted sample, but bilinear without the
    // per-tap resolution (the sample's own neighbours of the mapped texel) would not: the
    // plain-sample bilinear render with unshifted uv differs clearly.
    let unshifted = render_cpu(&ptm, &View { filter: Some((Filter::Bilinear, &plain_chain)), ..base(&plane) }).unwrap();
    let want = render_cpu(&ptm, &View { filter: Some((Filter::Bilinear, &plain_chain)), ..base(&shifted) }).unwrap();
    assert!(psnr(&unshifted, &want) < 35.0);
    // A chain built for another texture is refused.
    let wrong = View { coords: Some((n, n, &map[..])), filter: Some((Filter::Bilinear, &tile_chain)), ..base(&plane) };
    assert!(render_cpu(&ptm, &wrong).is_err());
}
