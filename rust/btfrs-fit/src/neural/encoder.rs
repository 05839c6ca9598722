//! Training at camera scale: the decoder learns from a sample of texels, and an **encoder** gives
//! every other texel its code in one pass over the capture.
//!
//! The auto-decoder of [`super::train`] updates a texel's code only when the texel is drawn, so
//! its steps grow with the texel count (500 visits per texel), and every step reads random
//! texels: at 24 megapixels that is 100,000 steps of random reads from a 17 GB memory-mapped
//! file, past an hour. A decoder shared by all texels does not need them all: trained on a
//! sample of a few hundred thousand texels spread over the frame it has seen every kind of
//! appearance the capture holds. The codes of the rest then come from an encoder, as in
//! NeuralRTI (Dulecha et al. 2020, section 3: an MLP from a pixel's measured values to its
//! code), here trained after the decoder, with the decoder fixed:
//!
//! 1. **Regression.** The encoder, `inputs -> hidden -> hidden -> latents` with ELU, reading a
//!    texel's values at (up to [`INPUT_PAIRS`]) training pairs, first learns the sample's
//!    trained codes (mean squared error in code space: cheap, no decoder pass).
//! 2. **Reconstruction.** Then it learns to reproduce the texels' values through the fixed
//!    decoder (the loss of training, whose gradient with respect to the codes
//!    [`super::train::chunk_grad`] gives), the best step kept by the error at the held-out
//!    pairs.
//! 3. **Encoding.** Every texel of the capture is read once, in storage order, screened for
//!    outliers when the fit is robust, and encoded.
//!
//! The sample is [`crate::runs`]: short runs of consecutive texels spread over the frame.

use super::decoder::Activation;
use super::dense::GEMM;
use super::train::{chunk_grad, schedule, val_error, Adam, Batches, Horizons, Stage, CHUNK};
use crate::robust::TexelScreen;
pub use crate::runs::{sample_texels, RUN};
use btfrs_core::rng::{mix, Rng};
use btfrs_core::{BtfRef, Monitor, Result};
use rayon::prelude::*;

/// Training pairs an encoder reads per texel, at most (a random subset beyond: a BTF's
/// thousands of pairs would make its first layer the cost of the encoding pass).
pub const INPUT_PAIRS: usize = 128;
/// Texels per encoder training step.
const BATCH: usize = 256;
/// Texels encoded per parallel task of the encoding pass.
const ENCODE_CHUNK: usize = 256;
/// Texels per progress step and cancellation check of the encoding pass.
const ENCODE_BAND: usize = 1 << 16;

/// An encoder's parameters: `w1 [hidden][inputs]`, `b1`, `w2 [hidden][hidden]`, `b2`,
/// `w3 [latents][hidden]`, `b3`.
#[derive(Debug, Clone)]
pub struct Encoder {
    /// Offsets in a texel's values of the pairs it reads (three values each).
    offs: Vec<usize>,
    hidden: usize,
    latents: usize,
    /// The values are multiplied by this before the first layer.
    inv_scale: f32,
    params: Vec<f32>,
}

/// Buffers of a forward pass, kept for the backward one.
#[derive(Default)]
struct Pass {
    x: Vec<f32>,
    h1: Vec<f32>,
    h2: Vec<f32>,
    z: Vec<f32>,
}

const ACT: Activation = Activation::Elu;

impl Encoder {
    fn inputs(&self) -> usize {
        3 * self.offs.len()
    }

    /// Offsets of `w1, b1, w2, b2, w3, b3` and the length.
    fn layout(&self) -> [usize; 7] {
        let (d, h, k) = (self.inputs(), self.hidden, self.latents);
        let w1 = 0;
        let b1 = w1 + h * d;
        let w2 = b1 + h;
        let b2 = w2 + h * h;
        let w3 = b2 + h;
        let b3 = w3 + k * h;
        [w1, b1, w2, b2, w3, b3, b3 + k]
    }

    /// Glorot-uniform weights, zero biases.
    fn new(offs: Vec<usize>, hidden: usize, latents: usize, inv_scale: f32, seed: u64) -> Encoder {
        let mut e = Encoder { offs, hidden, latents, inv_scale, params: Vec::new() };
        let [w1, b1, w2, b2, w3, b3, len] = e.layout();
        let d = e.inputs();
        let mut p = vec![0.0f32; len];
        let mut rng = Rng::new(mix(seed ^ 0xe4c0de));
        let mut fill = |p: &mut [f32], fan_in: usize, fan_out: usize| {
            let a = (6.0 / (fan_in + fan_out) as f64).sqrt();
            p.iter_mut().for_each(|x| *x = ((2.0 * rng.next_f64() - 1.0) * a) as f32);
        };
        fill(&mut p[w1..b1], d, hidden);
        fill(&mut p[w2..b2], hidden, hidden);
        fill(&mut p[w3..b3], hidden, latents);
        e.params = p;
        e
    }

    /// The inputs of one texel (its values as `values`) into `out`.
    #[inline]
    fn gather(&self, values: &[f32], out: &mut [f32]) {
        for (o, &off) in out.chunks_exact_mut(3).zip(&self.offs) {
            for c in 0..3 {
                o[c] = values[off + c] * self.inv_scale;
            }
        }
    }

    /// The codes of the `n` texels whose inputs are in `pass.x`, into `pass.z`.
    fn forward(&self, n: usize, pass: &mut Pass) {
        let [w1, b1, w2, b2, w3, b3, _] = self.layout();
        let (d, h, k) = (self.inputs(), self.hidden, self.latents);
        let p = &self.params;
        pass.h1.resize(n * h, 0.0);
        pass.h2.resize(n * h, 0.0);
        pass.z.resize(n * k, 0.0);
        GEMM.abt(n, d, h, &pass.x, &p[w1..b1], &mut pass.h1, false);
        for row in pass.h1.chunks_exact_mut(h) {
            row.iter_mut().zip(&p[b1..w2]).for_each(|(x, b)| *x += b);
        }
        ACT.apply_fast(&mut pass.h1);
        GEMM.abt(n, h, h, &pass.h1, &p[w2..b2], &mut pass.h2, false);
        for row in pass.h2.chunks_exact_mut(h) {
            row.iter_mut().zip(&p[b2..w3]).for_each(|(x, b)| *x += b);
        }
        ACT.apply_fast(&mut pass.h2);
        GEMM.abt(n, h, k, &pass.h2, &p[w3..b3], &mut pass.z, false);
        for row in pass.z.chunks_exact_mut(k) {
            row.iter_mut().zip(&p[b3..]).for_each(|(x, b)| *x += b);
        }
    }

    /// The gradient of a loss with gradient `dz` (`n x latents`) at the codes of `pass`.
    fn backward(&self, n: usize, pass: &Pass, dz: &[f32]) -> Vec<f32> {
        let [w1, b1, w2, b2, w3, b3, len] = self.layout();
        let (d, h, k) = (self.inputs(), self.hidden, self.latents);
        let p = &self.params;
        let mut g = vec![0.0f32; len];
        GEMM.atb(k, n, h, dz, &pass.h2, &mut g[w3..b3], false);
        for row in dz.chunks_exact(k) {
            g[b3..].iter_mut().zip(row).for_each(|(a, b)| *a += b);
        }
        let mut dh2 = vec![0.0f32; n * h];
        GEMM.ab(n, k, h, dz, &p[w3..b3], &mut dh2, false);
        ACT.backward(&pass.h2, &mut dh2);
        GEMM.atb(h, n, h, &dh2, &pass.h1, &mut g[w2..b2], false);
        for row in dh2.chunks_exact(h) {
            g[b2..w3].iter_mut().zip(row).for_each(|(a, b)| *a += b);
        }
        let mut dh1 = vec![0.0f32; n * h];
        GEMM.ab(n, h, h, &dh2, &p[w2..b2], &mut dh1, false);
        ACT.backward(&pass.h1, &mut dh1);
        GEMM.atb(h, n, d, &dh1, &pass.x, &mut g[w1..b1], false);
        for row in dh1.chunks_exact(h) {
            g[b1..w2].iter_mut().zip(row).for_each(|(a, b)| *a += b);
        }
        g
    }

    /// The inputs of `texels` of `btf` into `pass.x`.
    fn load(&self, btf: &BtfRef<'_>, texels: &[usize], pass: &mut Pass) {
        let d = self.inputs();
        pass.x.resize(texels.len() * d, 0.0);
        for (row, &t) in pass.x.chunks_exact_mut(d).zip(texels) {
            self.gather(btf.texel(t), row);
        }
    }

    /// The codes of every texel of `btf` (`texels x latents`), each texel read once in storage
    /// order and, with a `screen`, its flagged values repaired first; `monitor` counts bands of
    /// texels from `done` on.
    pub fn encode(&self, btf: &BtfRef<'_>, screen: Option<&TexelScreen<'_>>, monitor: &Monitor) -> Result<Vec<f32>> {
        let (k, d) = (self.latents, self.inputs());
        let t = btf.texels();
        let mut z = vec![0.0f32; t * k];
        for (bi, band) in z.chunks_mut(ENCODE_BAND * k).enumerate() {
            monitor.check()?;
            let t0 = bi * ENCODE_BAND;
            band.par_chunks_mut(ENCODE_CHUNK * k).enumerate().for_each(|(ci, out)| {
                let first = t0 + ci * ENCODE_CHUNK;
                let n = out.len() / k;
                let mut pass = Pass { x: vec![0.0; n * d], ..Default::default() };
                for (i, row) in pass.x.chunks_exact_mut(d).enumerate() {
                    let values = btf.texel(first + i);
                    match screen.and_then(|s| s.repaired(first + i, values)) {
                        Some(fixed) => self.gather(&fixed, row),
                        None => self.gather(values, row),
                    }
                }
                self.forward(n, &mut pass);
                out.copy_from_slice(&pass.z);
            });
            monitor.advance(1);
        }
        Ok(z)
    }
}

/// What the encoder's training reports.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct EncoderReport {
    /// Training pairs it reads per texel.
    pub input_pairs: usize,
    /// Steps of regression onto the trained codes, then of reconstruction.
    pub regression_steps: usize,
    /// Steps of reconstruction through the fixed decoder.
    pub reconstruction_steps: usize,
    /// The relative error at the held-out pairs of the validation texels with its codes (the
    /// decoder's own codes give the report's `validation_error`), after regression and at the
    /// kept reconstruction step.
    pub error_after_regression: Option<f64>,
    /// The same at the kept reconstruction step.
    pub error: Option<f64>,
}

/// Train an encoder for the decoder of `st` on the texels of `btf` (the sample) with their
/// horizon rows from `horizon`: `steps` steps, half of regression onto `st.z`, half of
/// reconstruction (module docs); `monitor` advances one per step.
pub(crate) fn train_encoder(
    btf: &BtfRef<'_>,
    st: &Stage,
    hz: &Horizons<'_>,
    steps: usize,
    seed: u64,
    monitor: &Monitor,
) -> Result<(Encoder, EncoderReport)> {
    let k = st.dec.shape.latents;
    let t = btf.texels();
    let mut rng = Rng::new(mix(seed ^ 0xe4c));
    // The inputs: the training pairs, or a random subset of them in pair order.
    let mut pick: Vec<usize> = (0..st.pairs.train.len()).collect();
    if pick.len() > INPUT_PAIRS {
        for i in 0..INPUT_PAIRS {
            let j = i + rng.below(pick.len() - i);
            pick.swap(i, j);
        }
        pick.truncate(INPUT_PAIRS);
        pick.sort_unstable();
    }
    let offs: Vec<usize> = pick.iter().map(|&i| st.pairs.train[i].off).collect();
    let mut enc = Encoder::new(offs, st.dec.shape.hidden.max(16), k, st.inv_scale, seed);
    let mut report = EncoderReport { input_pairs: enc.offs.len(), ..Default::default() };
    let regression = steps / 2;
    let reconstruction = steps - regression;
    let lr = st.lr.min(0.002);
    let batch = BATCH.min(t);
    let mut batches = Batches::new(t, batch);
    let mut adam = Adam::new(enc.params.len());
    let len = enc.params.len();
    let mut pass = Pass::default();
    // The validation texels' codes go into a full-length array (val_error indexes codes by texel).
    let mut zval = vec![0.0f32; t * k];
    let mut validate = |enc: &Encoder| -> Option<f64> {
        if st.pairs.val.is_empty() {
            return None;
        }
        let mut p = Pass::default();
        enc.load(btf, &st.val_texels, &mut p);
        enc.forward(st.val_texels.len(), &mut p);
        for (i, &ti) in st.val_texels.iter().enumerate() {
            zval[ti * k..(ti + 1) * k].copy_from_slice(&p.z[i * k..(i + 1) * k]);
        }
        Some(val_error(btf, &st.pairs.val, &st.dec, &zval, &st.val_hz, &st.val_texels, st.inv_scale))
    };
    for i in 0..regression {
        monitor.check()?;
        let texels = batches.next(&mut rng);
        let n = texels.len();
        enc.load(btf, &texels, &mut pass);
        enc.forward(n, &mut pass);
        let norm = (n * k) as f32;
        let mut dz = vec![0.0f32; n * k];
        for (j, &ti) in texels.iter().enumerate() {
            for c in 0..k {
                dz[j * k + c] = 2.0 * (pass.z[j * k + c] - st.z[ti * k + c]) / norm;
            }
        }
        let g = enc.backward(n, &pass, &dz);
        if g.iter().all(|x| x.is_finite()) {
            adam.update(&mut enc.params, &g, 0..len, i + 1, schedule(lr, i, regression));
        }
        report.regression_steps = i + 1;
        monitor.advance(1);
    }
    report.error_after_regression = validate(&enc);
    let mut best = (report.error_after_regression.unwrap_or(f64::INFINITY), enc.params.clone());
    let eval_every = (reconstruction / 20).clamp(50, 500);
    let mut adam = Adam::new(len);
    let bins = hz.bins;
    for i in 0..reconstruction {
        monitor.check()?;
        let texels = batches.next(&mut rng);
        let n = texels.len();
        enc.load(btf, &texels, &mut pass);
        enc.forward(n, &mut pass);
        let hb = hz.rows(&texels);
        let step_seed = mix(seed ^ mix((i as u64 + 1) << 20));
        let norm = st.norm * n as f32 / BATCH as f32;
        let zs = &pass.z;
        let parts: Vec<Vec<f32>> = texels
            .par_chunks(CHUNK)
            .enumerate()
            .map(|(ci, tx)| {
                let zc = &zs[ci * CHUNK * k..ci * CHUNK * k + tx.len() * k];
                let hc = &hb[ci * CHUNK * bins..ci * CHUNK * bins + tx.len() * bins];
                let inv = st.inv_scale;
                chunk_grad(btf, &st.pairs.train, &st.dec, tx, zc, hc, inv, norm, mix(step_seed + ci as u64), true).dz
            })
            .collect();
        let dz: Vec<f32> = parts.concat();
        let g = enc.backward(n, &pass, &dz);
        if g.iter().all(|x| x.is_finite()) {
            adam.update(&mut enc.params, &g, 0..len, i + 1, schedule(lr, i, reconstruction));
        }
        report.reconstruction_steps = i + 1;
        monitor.advance(1);
        if (i + 1) % eval_every == 0 || i + 1 == reconstruction {
            if let Some(err) = validate(&enc) {
                if err < best.0 {
                    best = (err, enc.params.clone());
                }
            }
        }
    }
    enc.params = best.1;
    report.error = best.0.is_finite().then_some(best.0);
    Ok((enc, report))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The backward pass against central differences of the loss `sum(z * w)` for random `w`,
    /// in float64 from a float32 forward: a step of 1e-2 and a loose tolerance.
    #[test]
    fn encoder_gradients_match_central_differences() {
        let offs = vec![0, 3, 9];
        let mut enc = Encoder::new(offs, 8, 3, 0.7, 4);
        let values: Vec<Vec<f32>> =
            (0..5).map(|i| (0..12).map(|j| ((i * 12 + j) as f32 * 0.61).sin() + 1.0).collect()).collect();
        let w: Vec<f32> = (0..5 * 3).map(|i| (i as f32 * 1.3).cos()).collect();
        let inputs = |e: &Encoder| -> Pass {
            let x = values
                .iter()
                .flat_map(|v| {
                    let mut r = vec![0.0; 9];
                    e.gather(v, &mut r);
                    r
                })
                .collect();
            Pass { x, ..Default::default() }
        };
        let loss = |e: &Encoder| -> f64 {
            let mut p = inputs(e);
            e.forward(5, &mut p);
            p.z.iter().zip(&w).map(|(a, b)| (a * b) as f64).sum()
        };
        let mut p = inputs(&enc);
        enc.forward(5, &mut p);
        let g = enc.backward(5, &p, &w);
        let h = 1e-2f32;
        let mut worst = 0.0f64;
        for (i, gi) in g.iter().enumerate() {
            let x = enc.params[i];
            enc.params[i] = x + h;
            let up = loss(&enc);
            enc.params[i] = x - h;
            let down = loss(&enc);
            enc.params[i] = x;
            let num = (up - down) / (2.0 * h as f64);
            worst = worst.max((num - *gi as f64).abs() / (1.0 + num.abs()));
        }
        assert!(worst < 2e-3, "worst relative difference {worst}");
    }

    #[test]
    fn a_sample_is_runs_spread_over_the_texels() {
        let s = sample_texels(10_000, 640, 3);
        assert_eq!(s.len(), 640);
        assert!(s.windows(2).all(|w| w[0] < w[1]));
        // Ten runs, one in each tenth of the texels.
        for (i, run) in s.chunks(RUN).enumerate() {
            assert!(run.windows(2).all(|w| w[1] == w[0] + 1));
            assert!(run[0] >= i * 1000 && run[RUN - 1] < (i + 1) * 1000, "run {i} at {}", run[0]);
        }
        assert_eq!(sample_texels(100, 500, 3), (0..100).collect::<Vec<_>>());
        assert_ne!(sample_texels(10_000, 640, 3), sample_texels(10_000, 640, 4));
    }
}
