//! Synthesis speed (paper 000 Table 1: 3 levels, 256^2 and 512^2 outputs, k in {1, 3, 6},
//! neighbourhood 2 and 3; the analysis excluded, as in the paper), the jump map, the texton
//! analysis of a 64^2 x 81 x 81 sample, and Embark's `texture-synthesis` on the same RGB texture
//! and output size as our k-coherence (`rgb_*` rows: analysis + synthesis for ours, since
//! Embark's run includes its own set-up).
//!
//! `cargo bench -p btfrs-kcoherence`; the quality scores of the RGB comparison are printed by
//! `cargo run --release -p btfrs-kcoherence --example compare_texture_synthesis`.
use btfrs_core::Monitor;
use btfrs_kcoherence::{jump_map, kcoherence, JumpOptions, SynthOptions};
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};

mod common;

fn table1(c: &mut Criterion) {
    let btf = common::knit(64);
    let an = common::analyse_btf(&btf, &[2, 3]);
    let mut g = c.benchmark_group("kcoherence_3_levels");
    g.sample_size(10);
    for (size, k, r) in
        [(256usize, 1usize, 2usize), (256, 3, 2), (256, 6, 2), (256, 6, 3), (512, 1, 2), (512, 3, 2), (512, 6, 2)]
    {
        let o = SynthOptions {
            height: size,
            width: size,
            k,
            radius: r,
            coarse_radius: r,
            levels: 3,
            toroidal: false,
            seed: 7,
        };
        g.bench_with_input(BenchmarkId::new(format!("k{k}_n{r}"), size), &o, |b, o| {
            b.iter(|| kcoherence(&an, o, &Monitor::new()).unwrap())
        });
    }
    g.finish();
    let mut g = c.benchmark_group("jump_map");
    g.sample_size(10);
    for size in [256usize, 512] {
        let o = JumpOptions { height: size, width: size, radius: 2, jump: 0.05, seed: 7 };
        g.bench_with_input(BenchmarkId::new("n2", size), &o, |b, o| {
            b.iter(|| jump_map(&an, o, &Monitor::new()).unwrap())
        });
    }
    g.finish();
}

fn analysis(c: &mut Criterion) {
    let btf = common::knit(64);
    let mut g = c.benchmark_group("analysis_64x64x81x81");
    g.sample_size(10);
    g.bench_function("pca48_t1024_3_levels_n2", |b| b.iter(|| common::analyse_btf(&btf, &[2])));
    g.finish();
}

fn versus_embark(c: &mut Criterion) {
    let btf = common::knit(64);
    let rgb = common::rgb_texture(&btf);
    let mut g = c.benchmark_group("rgb_64_to_256");
    g.sample_size(10);
    g.bench_function("btfrs_analysis_and_kcoherence_k3_n2", |b| {
        b.iter(|| {
            let an = common::analyse_rgb(&rgb, 64, 64, &[2]);
            let o = SynthOptions {
                height: 256,
                width: 256,
                k: 3,
                radius: 2,
                coarse_radius: 2,
                levels: 3,
                toroidal: false,
                seed: 7,
            };
            kcoherence(&an, &o, &Monitor::new()).unwrap()
        })
    });
    g.bench_function("embark_texture_synthesis_default", |b| b.iter(|| common::embark(&rgb, 64, 64, 256, 7)));
    g.finish();
}

criterion_group!(benches, table1, analysis, versus_embark);
criterion_main!(benches);
