//! Time to generate a built-in material with the UBO 81 x 81 directions (target: 64^2 < 5 s).
use btfrs_core::materials::{generate, MaterialSpec, Preset};
use btfrs_core::Monitor;
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("material_ubo81");
    g.sample_size(10);
    for size in [32usize, 64] {
        g.throughput(Throughput::Elements((size * size * 81 * 81) as u64));
        g.bench_with_input(BenchmarkId::new("knit", size), &size, |b, &size| {
            b.iter(|| generate(&MaterialSpec::new(Preset::Knit, size, 1), &Monitor::new()).unwrap())
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
