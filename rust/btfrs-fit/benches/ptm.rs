//! PTM fit throughput on built-in materials with UBO 81 x 81 directions (paper 000, Table 2 fits
//! a 256^2 PTM-RGB in 22 s). Sizes sweep 32^2..128^2; the fit should be bounded by one pass over
//! the data, so the `read_once` row (a plain sum over the same bytes) is the floor to compare to.
use btfrs_core::materials::{generate, MaterialSpec, Preset};
use btfrs_core::Monitor;
use btfrs_fit::{fit_ptm, PtmKind, PtmOptions};
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use rayon::prelude::*;

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("ptm_fit_ubo81");
    g.sample_size(10);
    for size in [32usize, 64, 128] {
        let btf = generate(&MaterialSpec::new(Preset::Knit, size, 1), &Monitor::new()).unwrap();
        let r = btf.as_ref();
        g.throughput(Throughput::Bytes((btf.data.len() * 4) as u64));
        for (name, kind) in [("rgb", PtmKind::Rgb), ("lrgb", PtmKind::Lrgb)] {
            let opts = PtmOptions { kind, ..Default::default() };
            g.bench_with_input(BenchmarkId::new(name, size), &size, |b, _| {
                b.iter(|| fit_ptm(&r, &opts, &Monitor::new()).unwrap())
            });
        }
        g.bench_with_input(BenchmarkId::new("read_once", size), &size, |b, _| {
            b.iter(|| btf.data.par_chunks(1 << 16).map(|c| c.iter().map(|&x| x as f64).sum::<f64>()).sum::<f64>())
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
