use rayon::prelude::*;
use std::time::Instant;
fn fold_check(data: &[f32]) -> bool {
    const CHUNK: usize = 1 << 16;
    data.par_chunks(CHUNK).all(|c| c.chunks(256).all(|b| b.iter().fold(true, |a, x| a & x.is_finite())))
}
fn main() {
    let n = 4096 * 6561 * 3;
    let data: Vec<f32> = (0..n).map(|i| (i % 1000) as f32 * 0.001).collect();
    for _ in 0..3 {
        let t = Instant::now();
        let r = btfrs_core::btf::check_finite("data", &data).is_ok();
        let a = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let r2 = fold_check(&data);
        let b = t.elapsed().as_secs_f64();
        println!("check_finite {:.1} ms ({r}), fold {:.1} ms ({r2})", a * 1e3, b * 1e3);
    }
}
