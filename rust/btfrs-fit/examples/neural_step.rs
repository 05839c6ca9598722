//! Where a neural training step's time goes: a single-view capture (a built-in material seen
//! from above under its 81 lights) trained for a fixed number of steps, timed; run it under
//! `valgrind --tool=callgrind` for the instruction count per function (repeatable on a shared
//! machine, where wall time is not).
//! `cargo run --release -p btfrs-fit --example neural_step [SIZE] [STEPS] [OPTIONS_JSON]`
use btfrs_core::materials::{generate, MaterialSpec, Preset};
use btfrs_core::Monitor;
use std::time::Instant;

fn main() {
    let mut args = std::env::args().skip(1);
    let size: usize = args.next().map_or(64, |s| s.parse().unwrap());
    let steps: usize = args.next().map_or(300, |s| s.parse().unwrap());
    let extra = args.next().unwrap_or_else(|| "{}".into());
    let mut spec = MaterialSpec::new(Preset::Bumps, size, 1);
    spec.views = vec![[0.0, 0.0, 1.0]];
    let btf = generate(&spec, &Monitor::new()).unwrap();
    let b = btf.as_ref();
    let mut o: serde_json::Value = serde_json::from_str(&extra).unwrap();
    o["steps"] = steps.into();
    o["validation"] = 0.0.into();
    let entry = btfrs_fit::registry::lookup("neural").unwrap();
    let plain = btfrs_fit::driver::RobustOptions { robust: false, exclude_bad_images: false };
    let t = Instant::now();
    let options = btfrs_fit::options::parse_json(&o.to_string()).unwrap();
    let m = btfrs_fit::driver::fit(entry, &b, &options, plain, &Monitor::new()).unwrap();
    let s = t.elapsed().as_secs_f64();
    let r = m.0.report();
    println!(
        "{size}² x {} lights, {} + {} steps: {s:.2} s, {:.2} ms per step",
        b.lights.len(),
        r["steps"],
        r["qat_steps"],
        1e3 * s / (r["steps"].as_u64().unwrap() + r["qat_steps"].as_u64().unwrap()) as f64
    );
}
