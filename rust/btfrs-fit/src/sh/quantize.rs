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
    let chan = |k: usize| (k / pc) % 3;
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for (k, &x) in coeffs.iter().enumerate() {
        let c = chan(k);
        if x.is_finite() {
            lo[c] = lo[c].min(x);
            hi[c] = hi[c].max(x);
        }
    }
    let mut scale = [0.0f32; 3];
    let mut bias = [0.0f32; 3];
    for c in 0..3 {
        if lo[c] <= hi[c] {
            bias[c] = lo[c];
            scale[c] = ((hi[c] as f64 - lo[c] as f64) / 255.0) as f32;
        }
    }
    let q = coeffs
        .par_iter()
        .enumerate()
        .map(|(k, &x)| {
            let c = chan(k);
            if scale[c] > 0.0 && x.is_finite() {
                ((x as f64 - bias[c] as f64) / scale[c] as f64).round().clamp(0.0, 255.0) as u8
            } else {
                0
            }
        })
        .collect();
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
