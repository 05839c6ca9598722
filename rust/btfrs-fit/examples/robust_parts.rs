//! Where a robust fit's fixed cost goes at small sizes: the images' checks (the spread table of
//! the sampled texels, the registration patch) against the plain and robust PTM-RGB fits.
//! `cargo run --release -p btfrs-fit --example robust_parts [SIZE]`
use btfrs_core::materials::{generate, MaterialSpec, Preset};
use btfrs_core::Monitor;
use btfrs_fit::robust::{moved_images, patch_window, sample_texels, screen_images};
use std::time::Instant;

fn best<T>(n: usize, mut f: impl FnMut() -> T) -> f64 {
    (0..n)
        .map(|_| {
            let t = Instant::now();
            std::hint::black_box(f());
            t.elapsed().as_secs_f64() * 1e3
        })
        .fold(f64::INFINITY, f64::min)
}

fn main() {
    let size: usize = std::env::args().nth(1).map_or(32, |s| s.parse().unwrap());
    let btf = generate(&MaterialSpec::new(Preset::Knit, size, 1), &Monitor::new()).unwrap();
    let b = btf.as_ref();
    let entry = btfrs_fit::registry::lookup("ptm").unwrap();
    let plain = btfrs_fit::driver::RobustOptions { robust: false, exclude_bad_images: false };
    let robust = btfrs_fit::driver::RobustOptions { robust: true, exclude_bad_images: false };
    let options = btfrs_fit::options::parse_json(r#"{"kind": "rgb"}"#).unwrap();
    let fit = |o| btfrs_fit::driver::fit(entry, &b, &options, o, &Monitor::new()).unwrap();
    let sampled = sample_texels(b.height, b.width);
    let window = patch_window(b.height, b.width);
    if std::env::var("IMAGES_ONLY").is_ok() {
        for _ in 0..200 {
            std::hint::black_box(screen_images(b.views, b.lights, b.mask, b.data, &sampled).unwrap());
            std::hint::black_box(moved_images(b.views, b.lights, b.mask, b.data, b.width, window).unwrap());
        }
        return;
    }
    for _ in 0..3 {
        println!(
            "{size}²: plain {:.1} ms, robust {:.1} ms; images' spread table {:.2} ms, registration {:.2} ms",
            best(10, || fit(plain)),
            best(10, || fit(robust)),
            best(20, || screen_images(b.views, b.lights, b.mask, b.data, &sampled).unwrap()),
            best(20, || moved_images(b.views, b.lights, b.mask, b.data, b.width, window).unwrap()),
        );
    }
}
