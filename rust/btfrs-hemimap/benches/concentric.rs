//! Throughput of the elevated concentric map (paper 004, section 6.1) on batches of 2^20 points:
//! forward (square -> hemisphere) and inverse (hemisphere -> square), f32 and f64.

use std::hint::black_box;

use btfrs_hemimap::{hemisphere_to_square_batch, square_to_hemisphere, square_to_hemisphere_batch, Real};
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};

const N: usize = 1 << 20;

/// Deterministic, well spread square points (a 2-D additive recurrence, R2 sequence).
fn square_points<T: Real>() -> Vec<[T; 2]> {
    const A1: f64 = 0.754_877_666_246_692_7;
    const A2: f64 = 0.569_840_290_998_053_3;
    (0..N)
        .map(|i| {
            let i = i as f64;
            [T::from_f64((0.5 + A1 * i).fract()), T::from_f64((0.5 + A2 * i).fract())]
        })
        .collect()
}

fn bench_type<T: Real>(c: &mut Criterion, name: &str) {
    let st = square_points::<T>();
    let dirs: Vec<[T; 3]> = st.iter().map(|&[s, t]| square_to_hemisphere(s, t)).collect();
    let mut out3 = vec![[T::ZERO; 3]; N];
    let mut out2 = vec![[T::ZERO; 2]; N];

    let mut group = c.benchmark_group("elevated_concentric");
    group.throughput(Throughput::Elements(N as u64));
    group.bench_function(BenchmarkId::new("square_to_hemisphere", name), |b| {
        b.iter(|| square_to_hemisphere_batch(black_box(&st), black_box(&mut out3)))
    });
    group.bench_function(BenchmarkId::new("hemisphere_to_square", name), |b| {
        b.iter(|| hemisphere_to_square_batch(black_box(&dirs), black_box(&mut out2)))
    });
    group.finish();
}

fn benches(c: &mut Criterion) {
    bench_type::<f32>(c, "f32");
    bench_type::<f64>(c, "f64");
}

criterion_group!(concentric, benches);
criterion_main!(concentric);
