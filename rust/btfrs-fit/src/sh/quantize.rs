//! The 8-bit storage of the SH coefficients (paper 002, section 5.2: one byte per coefficient
//! with a scale and a bias per colour channel), and its inverse.
//!
//! The renderer never dequantizes a whole model: with `value = bias + scale q`, the double sum
//! splits into `bias * sum(yv) sum(yl) + scale * sum(q yv yl)` (see the `ReflectanceModel` impl
//! of [`super::Sh`] and the WGSL shader), so only [`dequantize`] needs the per-value formula.

use rayon::prelude::*;

/// Uniform 8-bit quantization per colour channel of coefficients in the `[.., 3, kv, kl]`
/// layout, `per_channel = kv * kl` values per channel block: value `x` becomes
/// `q = round((x - bias) / scale)` with `bias` the channel's minimum and
/// `scale = (max - min) / 255`, so `|bias + scale * q - x| <= scale / 2`. A channel whose
/// values are all equal gets `scale = 0` and `q = 0` (no division). `per_channel = 0` is
/// treated as 1.
pub fn quantize(coeffs: &[f32], per_channel: usize) -> (Vec<u8>, [f32; 3], [f32; 3]) {
    let pc = per_channel.max(1);
    // Channel blocks of `pc` values, channel `i % 3` for block `i`: whole blocks per task, so
    // that no value pays for an index division.
    let fold = |(mut lo, mut hi): ([f32; 3], [f32; 3]), (i, block): (usize, &[f32])| {
        let c = i % 3;
        for &x in block.iter().filter(|x| x.is_finite()) {
            lo[c] = lo[c].min(x);
            hi[c] = hi[c].max(x);
        }
        (lo, hi)
    };
    let none = || ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    let (lo, hi) = coeffs.par_chunks(pc).enumerate().fold(none, fold).reduce(none, |(a, b), (c, d)| {
        (std::array::from_fn(|k| a[k].min(c[k])), std::array::from_fn(|k| b[k].max(d[k])))
    });
    let mut scale = [0.0f32; 3];
    let mut bias = [0.0f32; 3];
    for c in 0..3 {
        if lo[c] <= hi[c] {
            bias[c] = lo[c];
            scale[c] = ((hi[c] as f64 - lo[c] as f64) / 255.0) as f32;
        }
    }
    let mut q = vec![0u8; coeffs.len()];
    q.par_chunks_mut(pc).zip(coeffs.par_chunks(pc)).enumerate().for_each(|(i, (q, block))| {
        let c = i % 3;
        if scale[c] > 0.0 {
            let (b, s) = (bias[c] as f64, scale[c] as f64);
            for (q, &x) in q.iter_mut().zip(block) {
                if x.is_finite() {
                    *q = ((x as f64 - b) / s).round().clamp(0.0, 255.0) as u8;
                }
            }
        }
    });
    (q, scale, bias)
}

/// The inverse of [`quantize`]: `bias[ch] + scale[ch] * q` for every byte, with the channel of
/// index `k` being `(k / per_channel) % 3` (`per_channel = 0` is treated as 1).
pub(crate) fn dequantize(q: &[u8], scale: &[f32; 3], bias: &[f32; 3], per_channel: usize) -> Vec<f32> {
    let pc = per_channel.max(1);
    q.iter()
        .enumerate()
        .map(|(k, &x)| {
            let c = (k / pc) % 3;
            bias[c] + scale[c] * x as f32
        })
        .collect()
}
