//! The neural model's training products (`btfrs_fit::neural::dense`): the `matrixmultiply`
//! crate's SGEMM against hand-written row updates, on the shapes of one training chunk (8 texels
//! x 64 pairs = 512 samples, hidden widths 32 and 64): the forward product `H1 W2^T`, the weight
//! gradient `dH2^T H1` and the input gradient `dH2 W2`. Then one short fit of a 32^2 knit.
use btfrs_core::materials::{generate, MaterialSpec, Preset};
use btfrs_core::Monitor;
use btfrs_fit::neural::dense::Gemm;
use btfrs_fit::neural::{fit_neural, NeuralOptions};
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};

fn products(c: &mut Criterion) {
    let mut g = c.benchmark_group("neural_products");
    let n = 512;
    for h in [32usize, 64] {
        let x: Vec<f32> = (0..n * h).map(|i| ((i * 7919 % 97) as f32 - 48.0) / 31.0).collect();
        let w: Vec<f32> = (0..h * h).map(|i| ((i * 104729 % 89) as f32 - 44.0) / 29.0).collect();
        let mut out = vec![0.0f32; n * h];
        let mut gw = vec![0.0f32; h * h];
        for gemm in [Gemm::Crate, Gemm::Hand] {
            let name = format!("{gemm:?}").to_lowercase();
            g.bench_with_input(BenchmarkId::new(format!("{name}_step"), h), &h, |b, &h| {
                b.iter(|| {
                    gemm.abt(n, h, h, &x, &w, &mut out, false);
                    gemm.atb(h, n, h, &x, &out, &mut gw, true);
                    gemm.ab(n, h, h, &out, &w, &mut out.clone(), false);
                })
            });
        }
    }
    g.finish();
}

fn fit(c: &mut Criterion) {
    let mut g = c.benchmark_group("neural_fit");
    g.sample_size(10);
    let btf = generate(&MaterialSpec::new(Preset::Knit, 32, 1), &Monitor::new()).unwrap();
    let o = NeuralOptions { steps: Some(200), ..Default::default() };
    g.bench_function("knit32_200_steps", |b| b.iter(|| fit_neural(&btf.as_ref(), &o, &Monitor::new()).unwrap()));
    g.finish();
}

criterion_group!(benches, products, fit);
criterion_main!(benches);
