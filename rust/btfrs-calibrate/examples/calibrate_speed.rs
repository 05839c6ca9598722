//! Where calibration's time goes on a folder of photographs: decoding alone (every photograph
//! in parallel, as calibration reads them, each task reusing its buffer; and as btfrs-io's
//! readers do, a new buffer each) against the whole calibration, wall and CPU time.
//!
//!     cargo run --profile bench -p btfrs-calibrate --example calibrate_speed -- /tmp/big60 [runs]

use btfrs_calibrate::{calibrate, photo, Input, Options};
use btfrs_core::Monitor;
use rayon::prelude::*;
use std::path::PathBuf;
use std::time::Instant;

/// User + system CPU seconds of this process so far (Linux: /proc/self/stat).
fn cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let fields: Vec<&str> = stat.rsplit(')').next().unwrap_or("").split_whitespace().collect();
    let ticks = |i: usize| fields.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    // utime and stime are fields 14 and 15 of the line, 12 and 13 after the command's ')'.
    (ticks(11) + ticks(12)) / 100.0
}

fn main() -> btfrs_core::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let dir = PathBuf::from(args.get(1).expect("usage: calibrate_speed DIR [runs]"));
    let runs: usize = args.get(2).and_then(|r| r.parse().ok()).unwrap_or(2);
    let input = Input::Folder(dir.clone());
    let (files, _) = input.files()?;
    println!("{} photographs, {} threads", files.len(), rayon::current_num_threads());
    for _ in 0..runs {
        let (t, c) = (Instant::now(), cpu_seconds());
        let pixels: usize = files
            .par_iter()
            .map_init(Vec::new, |buf, f| photo::open(f, Default::default(), buf).map(|p| p.width * p.height))
            .collect::<btfrs_core::Result<Vec<_>>>()?
            .iter()
            .sum();
        let (dt, dc) = (t.elapsed().as_secs_f64(), cpu_seconds() - c);
        println!(
            "decode, buffers reused: {dt:.2} s wall, {dc:.2} s CPU ({:.0} MP per CPU second, {:.0} MP/s)",
            pixels as f64 / 1e6 / dc,
            pixels as f64 / 1e6 / dt
        );
        let (t, c) = (Instant::now(), cpu_seconds());
        files
            .par_iter()
            .map(|f| btfrs_io::decode::read_raw(f, Default::default(), u64::MAX).map(|r| r.width))
            .collect::<btfrs_core::Result<Vec<_>>>()?;
        let (dt, dc) = (t.elapsed().as_secs_f64(), cpu_seconds() - c);
        println!(
            "decode, a new buffer each: {dt:.2} s wall, {dc:.2} s CPU ({:.0} MP per CPU second)",
            pixels as f64 / 1e6 / dc
        );
        let (t, c) = (Instant::now(), cpu_seconds());
        let cal = calibrate(&input, &Options::default(), &Monitor::new())?;
        let (dt, dc) = (t.elapsed().as_secs_f64(), cpu_seconds() - c);
        println!(
            "calibrate:   {dt:.2} s wall, {dc:.2} s CPU ({:.0} MP per CPU second); {} of {} calibrated",
            pixels as f64 / 1e6 / dc,
            cal.calibrated().count(),
            cal.images.len()
        );
    }
    Ok(())
}
