//! Shared by the criterion bench and the comparison example: the built-in knit as a BTF sample
//! and as an 8-bit RGB texture, our analysis of either, and Embark's `texture-synthesis` run on
//! the same RGB texture with its coordinate map recovered for the quality measures.
#![allow(dead_code)]

use btfrs_core::materials::{generate, MaterialSpec, Preset};
use btfrs_core::{Btf, Monitor};
use btfrs_kcoherence::{Analysis, AnalysisOptions, CoordMap, FeatureMode, Features};
use texture_synthesis as ts;

/// The knit sample, `size^2` x UBO 81 x 81.
pub fn knit(size: usize) -> Btf {
    generate(&MaterialSpec::new(Preset::Knit, size, 1), &Monitor::new()).unwrap()
}

/// One image of the sample (view 0, a light 45 degrees up) as 8-bit sRGB-ish RGB, row-major.
pub fn rgb_texture(btf: &Btf) -> Vec<u8> {
    let (v, l) = (0, 7);
    let nl = btf.lights.len();
    let np = btf.views.len() * nl;
    let img: Vec<f32> =
        (0..btf.height * btf.width).flat_map(|t| btf.data[(t * np + v * nl + l) * 3..][..3].to_vec()).collect();
    let peak = img.iter().cloned().fold(0.0f32, f32::max).max(1e-6);
    img.iter().map(|&x| ((x / peak).clamp(0.0, 1.0).powf(1.0 / 2.2) * 255.0).round() as u8).collect()
}

/// The default analysis of a BTF sample (PCA of all images, 1024 textons, 3 levels, radii 2 and 3).
pub fn analyse_btf(btf: &Btf, radii: &[usize]) -> Analysis {
    let opts = AnalysisOptions { textons: 1024.min(btf.height * btf.width), ..Default::default() };
    Analysis::of_btf(&btf.as_ref(), FeatureMode::Pca { dims: 48 }, opts, radii, &Monitor::new()).unwrap()
}

/// Our analysis of an RGB texture (values / 255 as features).
pub fn analyse_rgb(rgb: &[u8], h: usize, w: usize, radii: &[usize]) -> Analysis {
    analyse_rgb_levels(rgb, h, w, radii, 3)
}

/// [`analyse_rgb`] with `levels` pyramid levels.
pub fn analyse_rgb_levels(rgb: &[u8], h: usize, w: usize, radii: &[usize], levels: usize) -> Analysis {
    let f = Features::new(h, w, 3, rgb.iter().map(|&v| v as f32 / 255.0).collect()).unwrap();
    let opts = AnalysisOptions { textons: 1024.min(h * w), levels, ..Default::default() };
    Analysis::of_features(f, opts, radii, &Monitor::new()).unwrap()
}

/// Embark's synthesizer with its default parameters (2 threads here), `out x out` pixels.
pub fn embark(rgb: &[u8], h: usize, w: usize, out: u32, seed: u64) -> ts::GeneratedImage {
    let rgba: Vec<u8> = rgb.chunks(3).flat_map(|c| [c[0], c[1], c[2], 255]).collect();
    let img = ts::image::DynamicImage::ImageRgba8(ts::image::RgbaImage::from_raw(w as u32, h as u32, rgba).unwrap());
    let s = ts::Session::builder().add_example(img).output_size(ts::Dims::square(out)).seed(seed).build().unwrap();
    s.run(None)
}

/// The coordinate map of an Embark result: its transform applied to an image whose pixels
/// encode their own coordinates (red = x, green = y; samples up to 256 x 256).
pub fn embark_map(g: &ts::GeneratedImage, h: usize, w: usize) -> CoordMap {
    assert!(h <= 256 && w <= 256);
    let code: Vec<u8> = (0..h * w).flat_map(|i| [(i % w) as u8, (i / w) as u8, 0, 255]).collect();
    let img = ts::image::DynamicImage::ImageRgba8(ts::image::RgbaImage::from_raw(w as u32, h as u32, code).unwrap());
    let out = g.get_coordinate_transform().apply([ts::ImageSource::Image(img)]).unwrap();
    let (ow, oh) = (out.width() as usize, out.height() as usize);
    let xy: Vec<u16> = out.pixels().flat_map(|p| [p.0[0] as u16, p.0[1] as u16]).collect();
    CoordMap::from_xy(oh, ow, &xy, h, w).unwrap()
}

/// Write 8-bit RGB as a PNG.
pub fn write_png(path: &str, rgb: &[u8], h: usize, w: usize) {
    let f = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut e = png::Encoder::new(f, w as u32, h as u32);
    e.set_color(png::ColorType::Rgb);
    e.set_depth(png::BitDepth::Eight);
    e.write_header().unwrap().write_image_data(rgb).unwrap();
}

/// A deliberately scrambled map: `out^2` made of `block^2` blocks of the `n^2` sample, each from
/// a random place (seeded).
pub fn scrambled(out: usize, n: usize, block: usize, seed: u64) -> CoordMap {
    let mut src = vec![0u32; out * out];
    for by in (0..out).step_by(block) {
        for bx in (0..out).step_by(block) {
            let h = |c: i64| btfrs_core::rng::hash01(seed, (by * out + bx) as i64, c);
            let (sx, sy) = ((h(0) * (n - block) as f64) as usize, (h(1) * (n - block) as f64) as usize);
            for y in by..(by + block).min(out) {
                for x in bx..(bx + block).min(out) {
                    src[y * out + x] = ((sy + y - by) * n + sx + x - bx) as u32;
                }
            }
        }
    }
    CoordMap { width: out, height: out, sample_width: n, sample_height: n, src }
}

/// Best wall time of three runs of `f`, and the last map it made.
pub fn best_of(f: &mut dyn FnMut() -> CoordMap) -> (f64, CoordMap) {
    let mut best = f64::INFINITY;
    let mut map = None;
    for _ in 0..3 {
        let t = std::time::Instant::now();
        map = Some(f());
        best = best.min(t.elapsed().as_secs_f64());
    }
    (best, map.expect("three runs"))
}
