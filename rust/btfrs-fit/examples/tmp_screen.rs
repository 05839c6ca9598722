use btfrs_core::materials::{generate, MaterialSpec, Preset};
use btfrs_core::Monitor;
use btfrs_fit::robust::{moved_images, patch_window, sample_texels, screen_images, screen_values, TexelScreen};
use btfrs_fit::{fit_ptm, PtmOptions};
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
    for size in [32usize, 64] {
        let btf = generate(&MaterialSpec::new(Preset::Knit, size, 0), &Monitor::new()).unwrap();
        let b = btf.as_ref();
        let s = sample_texels(size, size);
        let w = patch_window(size, size);
        let im = screen_images(b.views, b.lights, b.mask, b.data, &s).unwrap();
        let a = best(10, || screen_images(b.views, b.lights, b.mask, b.data, &s).unwrap());
        let m = best(10, || moved_images(b.views, b.lights, b.mask, b.data, size, w).unwrap());
        let v = best(10, || screen_values(&b, im.floor, 0..size, 0..size, &Monitor::new()).unwrap());
        let p = best(10, || fit_ptm(&b, &PtmOptions::default(), &Monitor::new()).unwrap());
        let q = best(10, || {
            let ts = TexelScreen::new(&b, im.floor);
            btfrs_fit::ptm::fit_ptm_screened(&b, &PtmOptions::default(), Some(&ts), &Monitor::new()).unwrap()
        });
        let r = best(10, || TexelScreen::new(&b, im.floor));
        println!("{size}^2: screen_images {a:.1} ms, moved_images {m:.1} ms, screen_values {v:.1} ms, PTM fit {p:.1} ms, screened {q:.1} ms (new screen {r:.2} ms)");
    }
}
