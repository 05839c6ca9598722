//! Times the figures of BENCHMARKS.md's synthesis targets without criterion: the analysis of the
//! knit 64^2 x 81 x 81 (PCA 48, 1024 textons, 3 levels, radius 2), split into its phases, and the
//! k-coherence syntheses k3_n2 at 256^2 and k6_n2 at 512^2 (3 levels, seed 7). Prints the best
//! of `runs` (first argument, default 5) and a hash of every result, so that a change can be
//! checked to leave the outputs bit-identical. A second argument, `analysis` or `synthesis`,
//! times only that part (for `perf stat`, whose counts do not depend on the machine's load).
//!
//! `cargo run --profile bench -p btfrs-kcoherence --example time_synthesis -- 5 [analysis|synthesis]`
use btfrs_core::Monitor;
use btfrs_kcoherence::pyramid::pyramid;
use btfrs_kcoherence::{btf_features, kcoherence, Analysis, AnalysisOptions, FeatureMode, SynthOptions, Textons};
use std::hash::{Hash, Hasher};
use std::time::Instant;

#[path = "../benches/common/mod.rs"]
mod common;

fn hash<T: Hash>(v: &T) -> u64 {
    let mut h = std::collections::hash_map::DefaultHasher::new();
    v.hash(&mut h);
    h.finish()
}

fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

/// Best wall time in ms of `runs` calls of `f`, and its last result.
fn best<T>(runs: usize, mut f: impl FnMut() -> T) -> (f64, T) {
    let mut t_best = f64::INFINITY;
    let mut out = None;
    for _ in 0..runs {
        let t = Instant::now();
        out = Some(f());
        t_best = t_best.min(t.elapsed().as_secs_f64() * 1e3);
    }
    (t_best, out.expect("at least one run"))
}

fn main() {
    let runs: usize = std::env::args().nth(1).map_or(5, |a| a.parse().expect("a run count"));
    let only = std::env::args().nth(2).unwrap_or_default();
    let btf = common::knit(64);
    let m = Monitor::new();
    if only != "analysis" {
        synthesis(&btf, runs, &m);
    }
    if only != "synthesis" {
        analysis(&btf, runs, &m);
    }
}

fn analysis(btf: &btfrs_core::Btf, runs: usize, m: &Monitor) {
    let opts = AnalysisOptions { textons: 1024, ..Default::default() };

    let (t_pca, f) = best(runs, || btf_features(&btf.as_ref(), FeatureMode::Pca { dims: 48 }, 20, 0, m).unwrap());
    println!("pca          {t_pca:8.1} ms  hash {:016x}", hash(&bits(&f.data)));
    for (l, lf) in pyramid(f.clone(), 3).into_iter().enumerate() {
        let t = opts.textons.min(lf.pixels());
        let (ms, tx) = best(runs, || Textons::fit(&lf, t, opts.iterations, l as u64, m).unwrap());
        println!("textons l{l}   {ms:8.1} ms  hash {:016x}", hash(&(bits(&tx.centers), &tx.assign)));
    }
    let (t_an, an) = best(runs, || common::analyse_btf(btf, &[2]));
    let nb: Vec<_> = an.levels.iter().map(|l| (&l.neighbours[0].index, bits(&l.neighbours[0].dist))).collect();
    println!("analysis     {t_an:8.1} ms  hash {:016x}", hash(&nb));
    let mut an = Analysis::from_levels(an.levels.clone(), an.options).unwrap();
    for lv in &mut an.levels {
        lv.neighbours.clear();
    }
    let (t_nb, _) = best(runs, || {
        let mut a = an.clone();
        a.ensure_neighbours(2, 3, m).unwrap();
        a
    });
    println!("neighbours   {t_nb:8.1} ms");
}

fn synthesis(btf: &btfrs_core::Btf, runs: usize, m: &Monitor) {
    let an = common::analyse_btf(btf, &[2, 3]);
    for (size, k) in [(256usize, 3usize), (512, 6)] {
        let o = SynthOptions {
            height: size,
            width: size,
            k,
            radius: 2,
            coarse_radius: 2,
            levels: 3,
            toroidal: false,
            seed: 7,
        };
        let (ms, map) = best(runs * 2, || kcoherence(&an, &o, m).unwrap());
        println!("k{k}_n2 {size:4}  {ms:8.1} ms  hash {:016x}", hash(&map.src));
    }
}
