//! Local-PCA fit time on the built-in knit, 32^2 texels x UBO 81 x 81 (77 MiB), 32 clusters and
//! 4 or 8 components (paper 004 section 3 keeps c < 8 for real-time rendering). The
//! `kmeans_pca` row is the fit without the local-PCA refinement, so the refinement's cost can
//! be read off.
use btfrs_core::materials::{generate, MaterialSpec, Preset};
use btfrs_core::Monitor;
use btfrs_fit::{fit_lpca, LpcaOptions};
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("lpca_fit_ubo81");
    g.sample_size(10);
    let size = 32;
    let btf = generate(&MaterialSpec::new(Preset::Knit, size, 1), &Monitor::new()).unwrap();
    let r = btf.as_ref();
    g.throughput(Throughput::Bytes((btf.data.len() * 4) as u64));
    for comps in [4usize, 8] {
        let opts = LpcaOptions { clusters: 32, components: comps, ..Default::default() };
        g.bench_with_input(BenchmarkId::new(format!("k32_c{comps}"), size), &size, |b, _| {
            b.iter(|| fit_lpca(&r, &opts, &Monitor::new()).unwrap())
        });
    }
    let plain = LpcaOptions { clusters: 32, components: 4, refine_iterations: 0, ..Default::default() };
    g.bench_with_input(BenchmarkId::new("kmeans_pca_k32_c4", size), &size, |b, _| {
        b.iter(|| fit_lpca(&r, &plain, &Monitor::new()).unwrap())
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
