//! Side by side on the same 64^2 RGB texture (the knit under one light) and 256^2 output: our
//! analysis + k-coherence, our jump map, Embark's `texture-synthesis` (default parameters), plain
//! tiling and random placement. Prints wall times and the quality measures of every coordinate
//! map, scored by one analysis of the texture (windows of radius 2).
//!
//! `cargo run --release -p btfrs-kcoherence --example compare_texture_synthesis`
use btfrs_core::Monitor;
use btfrs_kcoherence::{jump_map, kcoherence, quality, CoordMap, JumpOptions, QualityOptions, SynthOptions};
use std::time::Instant;

#[path = "../benches/common/mod.rs"]
mod common;

fn main() {
    let btf = common::knit(64);
    let rgb = common::rgb_texture(&btf);
    let (h, w, out) = (64usize, 64usize, 256usize);
    let best_of = common::best_of;
    let t = Instant::now();
    let an = common::analyse_rgb(&rgb, h, w, &[2]);
    let t_an = t.elapsed().as_secs_f64();
    let o = SynthOptions {
        height: out,
        width: out,
        k: 3,
        radius: 2,
        coarse_radius: 2,
        levels: 3,
        toroidal: false,
        seed: 7,
    };
    let (t_k, m_k) = best_of(&mut || kcoherence(&an, &o, &Monitor::new()).unwrap());
    let jo = JumpOptions { height: out, width: out, radius: 2, jump: 0.05, seed: 7 };
    let (t_j, m_j) = best_of(&mut || jump_map(&an, &jo, &Monitor::new()).unwrap());
    let (t_e, m_e) = best_of(&mut || common::embark_map(&common::embark(&rgb, h, w, out as u32, 7), h, w));
    let rows = [
        ("btfrs k-coherence (k=3, n=2, 3 levels)", t_an + t_k, m_k),
        ("btfrs jump map (n=2)", t_an + t_j, m_j),
        ("Embark texture-synthesis 0.8.2 (defaults)", t_e, m_e),
        ("plain tiling", 0.0, CoordMap::tiled(out, out, h, w)),
        ("random placement", 0.0, CoordMap::random(out, out, h, w, 7)),
    ];
    println!("64x64 RGB texture -> {out}x{out}; our times include the analysis ({t_an:.3} s); best of 3");
    println!("| method | seconds | nn_distance | coherence | seam | seam_mean | repetition |");
    println!("|---|---|---|---|---|---|---|");
    for (name, secs, map) in rows {
        let q = quality(&an, &map, &QualityOptions { samples: 8192, ..Default::default() }, &Monitor::new()).unwrap();
        println!(
            "| {name} | {secs:.3} | {:.4} | {:.3} | {:.4} | {:.4} | {:.3} |",
            q.nn_distance, q.coherence, q.seam, q.seam_mean, q.repetition
        );
    }
}
