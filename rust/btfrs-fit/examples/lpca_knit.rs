//! Fit time and reconstruction error of local PCA on the built-in knit (UBO 81 x 81).
//!
//! `cargo run --release -p btfrs-fit --example lpca_knit -- [size] [clusters] [components]
//! [refine_iterations] [reduced_dims]` (defaults 64 32 4 2 64). Prints the best of 3 fits on all
//! pairs and of 3 on 90% of them (split seed 0), and both accuracy figures: reconstruction (all
//! pairs, fitted on all) and held-out (fitted on the 90%, error on the other 10%).
use btfrs_core::materials::{generate, MaterialSpec, Preset};
use btfrs_core::{split::split_pairs, BtfRef, Monitor};
use btfrs_fit::Model;
use btfrs_fit::{fit_lpca, model_error, LpcaOptions};
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let defaults = [64usize, 32, 4, 2, 64];
    let args: Vec<usize> = std::env::args().skip(1).map(|a| a.parse()).collect::<Result<_, _>>()?;
    let arg = |i: usize| args.get(i).copied().unwrap_or(defaults[i]);
    let (size, clusters, components) = (arg(0), arg(1), arg(2));
    let btf = generate(&MaterialSpec::new(Preset::Knit, size, 1), &Monitor::new())?;
    let r = btf.as_ref();
    let opts =
        LpcaOptions { clusters, components, refine_iterations: arg(3), reduced_dims: arg(4), ..Default::default() };
    let mut best = f64::INFINITY;
    let mut model = None;
    for _ in 0..3 {
        let t0 = Instant::now();
        let m = fit_lpca(&r, &opts, &Monitor::new())?;
        best = best.min(t0.elapsed().as_secs_f64());
        model = Some(m);
    }
    let m = model.ok_or("no fit")?;
    let e = model_error(&m, &r)?;
    let n = btf.views.len();
    let (train, test) = split_pairs(n, n, None, 0.1, 0)?;
    let part = |mask| BtfRef::new(size, size, &btf.views, &btf.lights, &btf.data, Some(mask));
    let (mut best_held, mut held) = (f64::INFINITY, None);
    for _ in 0..3 {
        let t0 = Instant::now();
        let m = fit_lpca(&part(&train)?, &opts, &Monitor::new())?;
        best_held = best_held.min(t0.elapsed().as_secs_f64());
        held = Some(m);
    }
    let h = model_error(&held.ok_or("no fit")?, &part(&test)?)?;
    println!(
        "knit {size}^2 x 81 x 81, {opts:?}: fit {best:.3} s, on 90% of the pairs {best_held:.3} s (best of 3 \
         each), {} clusters used, reconstruction relative error {:.3}%, held-out {:.3}%, {} bytes (1:{:.1})",
        m.clusters,
        e.relative() * 100.0,
        h.relative() * 100.0,
        m.nbytes(),
        (btf.data.len() * 4) as f64 / m.nbytes() as f64
    );
    Ok(())
}
