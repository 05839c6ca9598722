//! Photograph-like structured RGB textures for testing synthesis: the kind of sample on which a
//! synthesizer's broken structure is plain to see (mortar lines that end in mid-brick).
//!
//! * `bricks`: running-bond brickwork, bricks of 38 x 17 pixels with 3-pixel mortar joints, a
//!   colour per brick, darker top-left brick edges, smooth low-frequency shading and per-pixel
//!   noise.
//!
//! The pattern, per-brick colours and noise included, repeats exactly every `period` bricks
//! (`(rows, bricks per row)`, rows even for the running bond): `period.0 * 17` rows and
//! `period.1 * 38` columns. The image is a crop of it at an offset drawn from the seed, so an
//! image whose sides are not multiples of the period does not tile (plain tiling breaks the
//! mortar lines at every tile boundary), exactly like a crop of a photograph; tiling at the
//! period (`(x mod pw, y mod ph)`) is seamless whenever the image holds a whole period.

use btfrs_core::{rng, Error, Result};

/// Brick module (brick plus one mortar joint), pixels: width, height.
pub const BRICK: (usize, usize) = (38, 17);
/// Mortar joint width, pixels.
pub const MORTAR: usize = 3;

/// The names of the textures.
pub const NAMES: [&str; 1] = ["bricks"];

/// The period of a texture in pixels, `(rows, columns)`, for a period in bricks.
pub fn period_pixels(period: (usize, usize)) -> (usize, usize) {
    (period.0 * BRICK.1, period.1 * BRICK.0)
}

/// Generate texture `name` as `[height, width, 3]` `f32` RGB in `[0, 1]`, row-major, with the
/// pattern repeating every `period = (brick rows, bricks per row)`.
pub fn texture(name: &str, height: usize, width: usize, seed: u64, period: (usize, usize)) -> Result<Vec<f32>> {
    if name != "bricks" {
        return Err(Error::arg("name", format!("unknown texture {name:?}; expected one of {}", NAMES.join(", "))));
    }
    if height == 0 || width == 0 || height > 8192 || width > 8192 {
        return Err(Error::arg("size", format!("expected 1 to 8192 pixels per side, got {height} x {width}")));
    }
    let (rows, cols) = period;
    if rows < 2 || rows % 2 != 0 || rows > 256 || cols == 0 || cols > 256 {
        return Err(Error::arg(
            "period",
            format!("expected an even number of brick rows (2 to 256) and 1 to 256 bricks per row, got {period:?}"),
        ));
    }
    let (ph, pw) = period_pixels(period);
    let (bw, bh) = BRICK;
    let ox = (rng::hash01(seed, 11, 0) * pw as f64) as usize;
    let oy = (rng::hash01(seed, 12, 0) * ph as f64) as usize;
    // Smooth shading: a few periodic plane waves with random integer frequencies and phases.
    let waves: Vec<(f64, f64, f64, f64)> = (0..6)
        .map(|k| {
            let h = |j: i64| rng::hash01(seed ^ 0xB51C, k, j);
            let fu = 1.0 + (h(0) * 3.0).floor() * cols as f64 / 2.0;
            let fv = (h(1) * 3.0).floor() * rows as f64 / 2.0;
            (fu.round(), fv.round(), h(2) * std::f64::consts::TAU, 0.03 + 0.02 * h(3))
        })
        .collect();
    let mut out = Vec::with_capacity(height * width * 3);
    for y in 0..height {
        for x in 0..width {
            let (u, v) = ((x + ox) % pw, (y + oy) % ph);
            let j = v / bh;
            let shift = if j % 2 == 1 { bw / 2 } else { 0 };
            let uu = (u + shift) % pw;
            let i = uu / bw;
            let (a, b) = (uu % bw, v % bh);
            let cell = (u as i64) * 7919 + v as i64;
            let noise = |c: i64| rng::hash01(seed ^ 0x401E, cell, c) - 0.5;
            let smooth: f64 = waves
                .iter()
                .map(|&(fu, fv, ph0, amp)| {
                    amp * (std::f64::consts::TAU * (fu * u as f64 / pw as f64 + fv * v as f64 / ph as f64) + ph0).sin()
                })
                .sum();
            let rgb = if a < MORTAR || b < MORTAR {
                let g = 0.66 + 0.12 * noise(0) + smooth;
                [g + 0.03, g, g - 0.04]
            } else {
                let id = (j * cols + i) as i64;
                let hb = |c: i64| rng::hash01(seed ^ 0xB41C, id, c);
                let light = 0.8 + 0.4 * hb(0);
                let edge = if a == MORTAR || b == MORTAR { 0.8 } else { 1.0 };
                let f = light * edge;
                let n = 0.08 * noise(1);
                [
                    f * (0.58 + 0.10 * (hb(1) - 0.5)) + n + smooth,
                    f * (0.28 + 0.06 * (hb(2) - 0.5)) + n + 0.02 * noise(2) + smooth,
                    f * 0.20 + n + 0.02 * noise(3) + smooth,
                ]
            };
            out.extend(rgb.iter().map(|&c| c.clamp(0.0, 1.0) as f32));
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bricks_repeat_at_their_period_and_not_before() {
        let (ph, pw) = period_pixels((4, 2));
        assert_eq!((ph, pw), (68, 76));
        let (h, w) = (150, 160);
        let t = texture("bricks", h, w, 3, (4, 2)).unwrap();
        let px = |x: usize, y: usize| &t[(y * w + x) * 3..(y * w + x) * 3 + 3];
        for y in 0..h - ph {
            for x in 0..w - pw {
                assert_eq!(px(x, y), px(x + pw, y));
                assert_eq!(px(x, y), px(x, y + ph));
            }
        }
        // A 128 crop is off the period: shifting by 128 does not repeat (the plain tiling seam).
        let differ = (0..h).filter(|&y| (0..w - 128).any(|x| px(x, y) != px(x + 128, y))).count();
        assert_eq!(differ, h);
        // Mortar is light grey, bricks are red: the two kinds are both present.
        let red = t.chunks(3).filter(|c| c[0] > c[2] + 0.2).count();
        assert!(red > t.len() / 3 / 2 && red < t.len() / 3, "{red}");
        assert_eq!(t, texture("bricks", h, w, 3, (4, 2)).unwrap());
        assert_ne!(t, texture("bricks", h, w, 4, (4, 2)).unwrap());
        assert!(texture("gravel", 8, 8, 0, (4, 2)).unwrap_err().to_string().starts_with("name:"));
        assert!(texture("bricks", 8, 8, 0, (3, 2)).unwrap_err().to_string().starts_with("period:"));
    }
}
