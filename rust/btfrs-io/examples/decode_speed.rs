//! How long decoding takes, by stage: `cargo run --release -p btfrs-io --example decode_speed -- DIR`
//! (every .jpg/.png in DIR, one thread): the image crate's decode, our conversion to linear f32;
//! with a `c.lp` in DIR, the capture's load on every thread against its decode alone.
use std::time::Instant;

fn main() {
    let dir = std::env::args().nth(1).expect("a folder of images");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| btfrs_io::decode::is_image(&p.to_string_lossy()))
        .collect();
    files.sort();
    let bytes: Vec<Vec<u8>> = files.iter().map(|p| std::fs::read(p).unwrap()).collect();
    let t = Instant::now();
    for b in &bytes {
        let img = image::load_from_memory(b).unwrap();
        std::hint::black_box(img);
    }
    let raw = t.elapsed().as_secs_f64();
    let t = Instant::now();
    for (b, p) in bytes.iter().zip(&files) {
        let d = btfrs_io::decode::decode(b, &p.to_string_lossy(), btfrs_io::decode::Transfer::Srgb).unwrap();
        std::hint::black_box(d);
    }
    let ours = t.elapsed().as_secs_f64();
    println!("{} images: image crate decode {:.3} s, btfrs decode (with linear f32) {:.3} s", files.len(), raw, ours);
    if let Some(lp) = files.first().and_then(|f| f.parent()).map(|d| d.join("c.lp")).filter(|p| p.exists()) {
        let sel = btfrs_io::capture::Selection::default();
        let t = Instant::now();
        let s = btfrs_io::rti::open_lp(&lp, &sel, btfrs_io::decode::Transfer::Srgb).unwrap();
        let plan = t.elapsed().as_secs_f64();
        // The decode alone on every thread (compressed bytes to samples, as the load's first
        // phase; the conversion to linear f32 happens in its scatter), then the whole load: the
        // difference is the scatter (conversion and transposition into the texel-major layout).
        use rayon::prelude::*;
        let t = Instant::now();
        let raws: Vec<_> = bytes
            .par_iter()
            .zip(&files)
            .map(|(b, p)| {
                let shown = p.to_string_lossy();
                btfrs_io::decode::decode_raw(b, &shown, btfrs_io::decode::Transfer::Srgb, b.len() as u64, u64::MAX)
                    .unwrap()
            })
            .collect();
        let decode = t.elapsed().as_secs_f64();
        drop(raws);
        let t = Instant::now();
        let v = btfrs_io::capture::load(&s, &btfrs_core::Monitor::new()).unwrap();
        let load = t.elapsed().as_secs_f64();
        println!(
            "lp: plan {plan:.3} s, load (parallel decode + scatter) {load:.3} s ({:.0} MB/s decoded), {} values; \
             parallel decode alone {decode:.3} s, so the scatter {:.3} s = {:.2} of the decode",
            v.len() as f64 * 4.0 / 1e6 / load,
            v.len(),
            load - decode,
            (load - decode) / decode
        );
    }
}
