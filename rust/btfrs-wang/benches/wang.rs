//! Tile-set synthesis speed (paper 002 Table III took 15 to 51 minutes per set): 16 tiles of
//! 64^2 over a 128^2 sample in the SH-like feature dimension, and the tiling of a 1024^2 layout.

use btfrs_core::rng::Rng;
use btfrs_core::Monitor;
use btfrs_wang::{synthesize, Features, WangOptions};
use criterion::{criterion_group, criterion_main, Criterion};

fn sample(n: usize, dim: usize) -> Features {
    // Smooth random field: sums of a few random sinusoids per channel.
    let mut rng = Rng::new(1);
    let waves: Vec<(f64, f64, f64)> =
        (0..dim * 3).map(|_| (rng.next_f64() * 0.5, rng.next_f64() * 0.5, rng.next_f64() * 6.3)).collect();
    let mut data = Vec::with_capacity(n * n * dim);
    for y in 0..n {
        for x in 0..n {
            for d in 0..dim {
                let v: f64 =
                    waves[d * 3..d * 3 + 3].iter().map(|(a, b, p)| (a * y as f64 + b * x as f64 + p).sin()).sum();
                data.push(v as f32);
            }
        }
    }
    Features::new(n, n, dim, data).unwrap()
}

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("wang");
    g.sample_size(10);
    for (tile, n, dim) in [(64usize, 128usize, 48usize), (128, 256, 48)] {
        let f = sample(n, dim);
        let o = WangOptions { tile, edge_height: tile / 4, colors: 2, seed: 5, ..Default::default() };
        g.bench_function(format!("synthesize 16 tiles {tile}^2 from {n}^2 x {dim}"), |b| {
            b.iter(|| synthesize(&f, &o, &Monitor::new()).unwrap())
        });
    }
    g.bench_function("tiling 1024 x 1024", |b| {
        b.iter(|| btfrs_wang::tiling::tiling(2, 1024, 1024, 1, (false, false), None).unwrap())
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
