//! Structured texture, side by side: the bricks test texture (128^2 crop, off its 68 x 76 pixel
//! period) synthesized to 384^2 by our k-coherence, our jump map and Embark's
//! `texture-synthesis` (default parameters), beside plain tiling (broken mortar at every tile
//! boundary), tiling at the period (seamless), 16^2 blocks scrambled and random placement.
//! Prints wall times and the quality measures of every map (one analysis scores them all) and
//! writes every output as a PNG.
//!
//! `cargo run --profile bench -p btfrs-kcoherence --example compare_structured -- [out_dir]`
use btfrs_core::Monitor;
use btfrs_kcoherence::{jump_map, kcoherence, quality, textures, CoordMap, JumpOptions, QualityOptions, SynthOptions};
use std::time::Instant;

#[path = "../benches/common/mod.rs"]
mod common;

fn main() {
    let dir = std::env::args().nth(1).unwrap_or_else(|| "target/compare_structured".into());
    std::fs::create_dir_all(&dir).unwrap();
    let (n, out) = (128usize, 384usize);
    let period = (4, 2);
    let (ph, pw) = textures::period_pixels(period);
    let rgb: Vec<u8> =
        textures::texture("bricks", n, n, 5, period).unwrap().iter().map(|&v| (v * 255.0).round() as u8).collect();
    common::write_png(&format!("{dir}/sample.png"), &rgb, n, n);
    let best_of = common::best_of;
    let t = Instant::now();
    let mut an = common::analyse_rgb_levels(&rgb, n, n, &[2], 4);
    let t_an = t.elapsed().as_secs_f64();
    let mut rows: Vec<(String, f64, CoordMap)> = Vec::new();
    // `k,n,coarse n,levels` per variant, `;`-separated (default: the ones in BENCHMARKS.md).
    let variants: Vec<Vec<usize>> = std::env::var("VARIANTS")
        .unwrap_or_else(|_| "3,2,2,3;3,2,4,3;3,2,3,4;1,2,4,3".into())
        .split(';')
        .map(|v| v.split(',').map(|x| x.trim().parse().unwrap()).collect())
        .collect();
    for v in variants {
        let (k, r, cr, levels) = (v[0], v[1], v[2], v[3]);
        let t = Instant::now();
        an.ensure_neighbours(r, 1, &Monitor::new()).unwrap();
        an.ensure_neighbours_at(cr, 1, levels, &Monitor::new()).unwrap();
        let t_nb = t.elapsed().as_secs_f64();
        let o =
            SynthOptions { height: out, width: out, k, radius: r, coarse_radius: cr, levels, toroidal: false, seed: 7 };
        let (t_k, m) = best_of(&mut || kcoherence(&an, &o, &Monitor::new()).unwrap());
        rows.push((
            format!("btfrs k-coherence k={k} n={r} coarse n={cr}, {levels} levels (+{t_nb:.2} s neighbourhoods)"),
            t_an + t_k,
            m,
        ));
    }
    let jo = JumpOptions { height: out, width: out, radius: 2, jump: 0.05, seed: 7 };
    let (t_j, m_j) = best_of(&mut || jump_map(&an, &jo, &Monitor::new()).unwrap());
    rows.push(("btfrs jump map (n=2)".into(), t_an + t_j, m_j));
    if std::env::var("SKIP_EMBARK").is_err() {
        let t = Instant::now();
        let g = common::embark(&rgb, n, n, out as u32, 7);
        let t_e = t.elapsed().as_secs_f64();
        rows.push(("Embark texture-synthesis 0.8.2 (defaults)".into(), t_e, common::embark_map(&g, n, n)));
    }
    let tiled_at = |ph: usize, pw: usize| CoordMap {
        width: out,
        height: out,
        sample_width: n,
        sample_height: n,
        src: (0..out * out).map(|p| ((p / out % ph) * n + p % out % pw) as u32).collect(),
    };
    rows.push(("plain tiling (128^2 tiles)".into(), 0.0, CoordMap::tiled(out, out, n, n)));
    rows.push((format!("tiling at the period ({ph} x {pw})"), 0.0, tiled_at(ph, pw)));
    rows.push(("16^2 blocks scrambled".into(), 0.0, common::scrambled(out, n, 16, 3)));
    rows.push(("random placement".into(), 0.0, CoordMap::random(out, out, n, n, 7)));
    println!("bricks {n}x{n} (period {ph} x {pw}) -> {out}x{out}; our times include the analysis ({t_an:.3} s, 4 levels, radius 2); best of 3 (Embark: one run)");
    println!("| method | seconds | structure | levels | seam_error | seam_p90 | straddling | nn_distance | seam (old) | seam_mean (old) | repetition | quality s |");
    println!("|---|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|");
    for (i, (name, secs, map)) in rows.iter().enumerate() {
        let t = Instant::now();
        let q = quality(&an, map, &QualityOptions::default(), &Monitor::new()).unwrap();
        let tq = t.elapsed().as_secs_f64();
        let lv: Vec<String> = q.structure_levels.iter().map(|v| format!("{v:.3}")).collect();
        println!(
            "| {name} | {secs:.3} | {:.4} | {} | {:.4} | {:.4} | {:.3} | {:.4} | {:.4} | {:.4} | {:.3} | {tq:.2} |",
            q.structure,
            lv.join(" / "),
            q.seam_error,
            q.seam_error_p90,
            q.straddling,
            q.nn_distance,
            q.seam,
            q.seam_mean,
            q.repetition
        );
        let img: Vec<u8> = map.src.iter().flat_map(|&s| rgb[s as usize * 3..s as usize * 3 + 3].to_vec()).collect();
        common::write_png(&format!("{dir}/{i:02}.png"), &img, out, out);
    }
}
