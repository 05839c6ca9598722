//! Lafortune fit throughput on the built-in knit, 32 x 32 texels x UBO 81 x 81 directions (paper
//! 000, Table 2: Lafortune-Lum with 2 lobes, 256^2 texels, 112 s on a 1.3 GHz AMD). Throughput is
//! in texels, so criterion's "elem/s" is texels per second; one LM fit per texel (Lum) or three
//! (Rgb, one per channel). Each iteration fits 1024 texels, several seconds: run it with
//! `cargo bench -p btfrs-fit --bench lafortune` when you mean it; `RAYON_NUM_THREADS=1` gives the
//! per-core time per texel.
use btfrs_core::materials::{generate, MaterialSpec, Preset};
use btfrs_core::Monitor;
use btfrs_fit::{fit_lafortune, LafortuneKind, LafortuneOptions};
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use std::time::Duration;

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("lafortune_fit_ubo81");
    g.sample_size(10);
    g.warm_up_time(Duration::from_secs(1));
    g.measurement_time(Duration::from_secs(30));
    let size = 32usize;
    let btf = generate(&MaterialSpec::new(Preset::Knit, size, 1), &Monitor::new()).expect("built-in material");
    let r = btf.as_ref();
    g.throughput(Throughput::Elements((size * size) as u64));
    for (name, kind) in [("lum2", LafortuneKind::Lum), ("rgb2", LafortuneKind::Rgb)] {
        let opts = LafortuneOptions { kind, lobes: 2, ..Default::default() };
        g.bench_with_input(BenchmarkId::new(name, size), &size, |b, _| {
            b.iter(|| fit_lafortune(&r, &opts, &Monitor::new()).expect("fit"))
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
