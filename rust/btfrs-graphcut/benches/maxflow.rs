//! Boykov-Kolmogorov on 4-connected grids, 256^2 and 512^2, general [`Graph`] against the
//! implicit [`GridGraph`], building included (what a caller pays):
//!
//! * `kwatra`: a seam problem as in Kwatra et al.'s graph-cut textures: the cost of cutting
//!   between neighbours p, q is |A(p) - B(p)| + |A(q) - B(q)| for two noise images A and B, the
//!   two leftmost columns are tied to the source and the two rightmost to the sink;
//! * `segmentation`: random unary terms around a smooth field (source / sink capacity per
//!   pixel) and a constant smoothness weight.
//!
//! Integer capacities (`i64`, the exact path); the grid also in `f64` at 512^2.

use std::hint::black_box;

use btfrs_core::rng::Rng;
use btfrs_graphcut::{Capacity, Graph, GridGraph};
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};

/// A grid problem: `right[y * (w - 1) + x]`, `down[y * w + x]` (forward, backward) and
/// `terminals[y * w + x]` (source, sink).
struct Problem<C> {
    h: usize,
    w: usize,
    right: Vec<[C; 2]>,
    down: Vec<[C; 2]>,
    terminals: Vec<[C; 2]>,
}

fn kwatra<C: Capacity>(n: usize, seed: u64, conv: impl Fn(f64) -> C) -> Problem<C> {
    let mut rng = Rng::new(seed);
    let diff: Vec<f64> = (0..n * n).map(|_| (rng.next_f64() - rng.next_f64()).abs()).collect();
    let cost = |i: usize, j: usize| conv(1000.0 * (diff[i] + diff[j]));
    let mut right = Vec::with_capacity(n * (n - 1));
    let mut down = Vec::with_capacity(n * (n - 1));
    for y in 0..n {
        for x in 0..n - 1 {
            let c = cost(y * n + x, y * n + x + 1);
            right.push([c, c]);
        }
    }
    for y in 0..n - 1 {
        for x in 0..n {
            let c = cost(y * n + x, (y + 1) * n + x);
            down.push([c, c]);
        }
    }
    // "infinite" ties: more than any cut through the grid can cost
    let tie = conv(1e9);
    let terminals = (0..n * n)
        .map(|i| match i % n {
            x if x < 2 => [tie, C::ZERO],
            x if x >= n - 2 => [C::ZERO, tie],
            _ => [C::ZERO; 2],
        })
        .collect();
    Problem { h: n, w: n, right, down, terminals }
}

fn segmentation<C: Capacity>(n: usize, seed: u64, conv: impl Fn(f64) -> C) -> Problem<C> {
    let mut rng = Rng::new(seed);
    let terminals = (0..n * n)
        .map(|i| {
            let (y, x) = ((i / n) as f64, (i % n) as f64);
            let field = (x / 23.0).sin() * (y / 17.0).cos() + 0.8 * (rng.next_f64() - 0.5);
            let fg = 100.0 * (1.0 + field).max(0.0);
            let bg = 100.0 * (1.0 - field).max(0.0);
            [conv(fg), conv(bg)]
        })
        .collect();
    let lambda = conv(40.0);
    Problem { h: n, w: n, right: vec![[lambda; 2]; n * (n - 1)], down: vec![[lambda; 2]; n * (n - 1)], terminals }
}

fn solve_graph<C: Capacity>(p: &Problem<C>) -> C {
    let (h, w) = (p.h, p.w);
    let mut g = Graph::<C>::with_capacity(h * w, p.right.len() + p.down.len());
    for y in 0..h {
        for x in 0..w - 1 {
            let [f, b] = p.right[y * (w - 1) + x];
            g.add_edge(y * w + x, y * w + x + 1, f, b).unwrap();
        }
    }
    for y in 0..h - 1 {
        for x in 0..w {
            let [f, b] = p.down[y * w + x];
            g.add_edge(y * w + x, (y + 1) * w + x, f, b).unwrap();
        }
    }
    for (i, &[s, t]) in p.terminals.iter().enumerate() {
        g.add_terminal(i, s, t).unwrap();
    }
    g.maxflow()
}

fn solve_grid<C: Capacity>(p: &Problem<C>) -> C {
    let (h, w) = (p.h, p.w);
    let mut g = GridGraph::<C>::new(h, w);
    for y in 0..h {
        for x in 0..w - 1 {
            let [f, b] = p.right[y * (w - 1) + x];
            g.set_right(y, x, f, b).unwrap();
        }
    }
    for y in 0..h - 1 {
        for x in 0..w {
            let [f, b] = p.down[y * w + x];
            g.set_down(y, x, f, b).unwrap();
        }
    }
    for (i, &[s, t]) in p.terminals.iter().enumerate() {
        g.add_terminal(i / w, i % w, s, t).unwrap();
    }
    g.maxflow()
}

fn benches(c: &mut Criterion) {
    let mut group = c.benchmark_group("maxflow");
    group.sample_size(10);
    for n in [256usize, 512] {
        for (case, p) in [("kwatra", kwatra(n, 1, |v| v as i64)), ("segmentation", segmentation(n, 2, |v| v as i64))] {
            assert_eq!(solve_graph(&p), solve_grid(&p), "{case} {n}");
            let id = format!("{case}/{n}x{n}/i64");
            group.bench_function(BenchmarkId::new("Graph", &id), |b| b.iter(|| solve_graph(black_box(&p))));
            group.bench_function(BenchmarkId::new("GridGraph", &id), |b| b.iter(|| solve_grid(black_box(&p))));
        }
    }
    for (case, p) in [("kwatra", kwatra(512, 1, |v| v)), ("segmentation", segmentation(512, 2, |v| v))] {
        let id = format!("{case}/512x512/f64");
        group.bench_function(BenchmarkId::new("GridGraph", &id), |b| b.iter(|| solve_grid(black_box(&p))));
    }
    group.finish();
}

criterion_group!(maxflow, benches);
criterion_main!(maxflow);
