use btfrs_core::materials::{generate, MaterialSpec, Preset};
use btfrs_core::{split::split_pairs, BtfRef, Monitor};
use btfrs_fit::{fit_lpca, LpcaOptions};
use std::time::Instant;
fn main() {
    let size = 64;
    let btf = generate(&MaterialSpec::new(Preset::Knit, size, 1), &Monitor::new()).unwrap();
    let n = btf.views.len();
    let (train, _) = split_pairs(n, n, None, 0.1, 0).unwrap();
    let part = BtfRef::new(size, size, &btf.views, &btf.lights, &btf.data, Some(&train)).unwrap();
    let reps: usize = std::env::var("REPS").map(|s| s.parse().unwrap()).unwrap_or(5);
    for _ in 0..reps {
        let t0 = Instant::now();
        let m = fit_lpca(&part, &LpcaOptions::default(), &Monitor::new()).unwrap();
        println!("{:.3} s ({} clusters)", t0.elapsed().as_secs_f64(), m.clusters);
    }
}
