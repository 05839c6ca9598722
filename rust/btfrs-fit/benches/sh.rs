//! Double-SH fit throughput on a built-in material with UBO 81 x 81 directions (paper 002,
//! Table II: 25 x 25 coefficients on 128^2 texels in 10 min 13 s; our target is <= 10 s, see
//! the `sh_timing_128` test). 32^2 texels here, CLS vs plain least squares, and the masked
//! (general eigenbasis) path with 10 % of the pairs held out.
use btfrs_core::materials::{generate, MaterialSpec, Preset};
use btfrs_core::{BtfRef, Monitor};
use btfrs_fit::{fit_sh, ShOptions};
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("sh_fit_ubo81");
    g.sample_size(10);
    let size = 32;
    let btf = generate(&MaterialSpec::new(Preset::Knit, size, 1), &Monitor::new()).unwrap();
    let r = btf.as_ref();
    g.throughput(Throughput::Bytes((btf.data.len() * 4) as u64));
    let (train, _) = btfrs_core::split::split_pairs(81, 81, None, 0.1, 0).unwrap();
    let masked = BtfRef { mask: Some(&train), ..r };
    for (name, k, cls, input) in [
        ("cls_25x25", 25, true, &r),
        ("ls_25x25", 25, false, &r),
        ("cls_16x16", 16, true, &r),
        ("cls_16x16_masked", 16, true, &masked),
    ] {
        let opts = ShOptions { view_coeffs: k, light_coeffs: k, cls, ..Default::default() };
        g.bench_with_input(BenchmarkId::new(name, size), &size, |b, _| {
            b.iter(|| fit_sh(input, &opts, &Monitor::new()).unwrap())
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
