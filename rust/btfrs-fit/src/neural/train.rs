//! Training of the neural model: an auto-decoder (no encoder: every texel's latent code and the
//! decoder's weights are optimized together, as in NeuMIP, Kuznetsov et al. 2021, section 4),
//! by Adam on minibatches of random texels, each seen under random present (view, light) pairs.
//!
//! 1. **Start where linear models end.** The latents start as the leading principal coordinates
//!    of the texels' values at a random subset of pairs (the randomized PCA of
//!    `btfrs_numerics::rpca`), each scaled to unit variance; the decoder starts from Glorot-uniform
//!    weights. Values are divided by their root mean square, folded back into the last layer.
//! 2. **Minibatches.** Each step takes the next `BATCH_TEXELS` texels of a shuffled order (so a
//!    texel's latent gets one update per visit, Adam's moments kept per texel) and `PAIRS` random
//!    training pairs per texel, read in place from the BTF (a memory-mapped file stays on disk but
//!    for the pages read). The texels are split into chunks worked on in parallel; each returns
//!    its gradients, summed in chunk order so a seed gives one answer whatever the thread count.
//! 3. **Early stopping.** A fraction of the present pairs is kept out of training; every
//!    `eval_every` steps the relative error on those pairs (over a fixed sample of texels) is
//!    measured, the best parameters kept, and training stops after `PATIENCE` evaluations without
//!    improvement. A non-finite loss restores the best parameters and halves the learning rate.
//! 4. **Quantization-aware end.** The latents are then quantized to their 8-bit planes and the
//!    decoder alone is trained on the decoded codes for a tenth of the steps, so the model that is
//!    stored and scored is the one trained.

use super::decoder::{table_taps, Decoder, Shape, Taps, MAX_ENCODING};
use super::dense::{strided, View, GEMM};
use crate::planes::Planes;
use btfrs_core::rng::{mix, Rng};
use btfrs_core::{BtfRef, Error, Monitor, Result};
use rayon::prelude::*;

/// Texels per training step. Many texels with few pairs each: a latent is updated only when its
/// texel is drawn, so more texels per step means more updates per latent for the same work
/// (measured on knit 32^2, 2000 steps: held-out 0.272 with 64 x 64, 0.265 with 256 x 16).
pub const BATCH_TEXELS: usize = 256;
/// Pairs per texel per step.
pub const PAIRS: usize = 16;
/// Texels per parallel chunk (512 samples).
const CHUNK: usize = 32;
/// Evaluations without improvement before training stops.
const PATIENCE: usize = 6;
/// Texels the validation error is measured on.
const VALIDATION_TEXELS: usize = 512;
/// Pairs per texel in the PCA that starts the latents.
const PCA_PAIRS: usize = 96;
/// The latents' learning rate relative to the decoder's: each latent is updated only when its
/// texel is in the batch (measured on knit 32^2, 2000 steps: held-out 0.282 at 0.2x, 0.265 at
/// 1x, 0.259 at 5x).
const LATENT_RATE: f32 = 3.0;
/// Adam's moment decay rates and epsilon.
const BETA1: f32 = 0.9;
const BETA2: f32 = 0.999;
const EPS: f32 = 1e-8;

/// What training needs.
#[derive(Debug, Clone, Copy)]
pub struct Setup {
    /// The decoder's shape.
    pub shape: Shape,
    /// Optimization steps at most (early stopping may end sooner), before the quantization-aware
    /// steps.
    pub steps: usize,
    /// Adam's learning rate (the peak of a cosine schedule).
    pub learning_rate: f64,
    /// Fraction of the present pairs kept out for early stopping.
    pub validation: f64,
    /// Seed of every random choice.
    pub seed: u64,
}

/// What training reports.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct TrainReport {
    /// Steps run (before the quantization-aware steps).
    pub steps: usize,
    /// Quantization-aware steps run.
    pub qat_steps: usize,
    /// The step whose parameters were kept.
    pub best_step: usize,
    /// Whether early stopping ended training.
    pub stopped_early: bool,
    /// Pairs kept out for early stopping.
    pub validation_pairs: usize,
    /// Relative error on them with float latents at the kept step (null: none kept out).
    pub validation_error: Option<f64>,
    /// The same after quantization-aware training, with the 8-bit latents.
    pub validation_error_8bit: Option<f64>,
    /// Principal components the latents started from.
    pub pca_components: usize,
    /// Times a non-finite loss halved the learning rate.
    pub lr_halvings: usize,
    /// The values' root mean square (folded into the last layer).
    pub scale: f64,
}

/// A trained model's parts.
#[derive(Debug)]
pub struct Trained {
    /// 8-bit latents, `texels x latents`.
    pub latents: Planes,
    /// The decoder, on the data's own scale.
    pub decoder: Decoder,
    /// What happened.
    pub report: TrainReport,
}

/// One (view, light) pair as training reads it.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Pair {
    /// Offset of the pair's RGB in a texel's ABRDF.
    pub(crate) off: usize,
    /// The direction coordinates ([`super::decoder::Directions::encode`]).
    pub(crate) raw: [f32; 6],
    /// The output gain ([`super::decoder::Directions::gain`]).
    pub(crate) gain: f32,
    /// Its taps in each direction table.
    pub(crate) taps: [Taps; 3],
}

impl Pair {
    /// Pair (`v`, `l`) at ABRDF offset `off`.
    pub(crate) fn new(shape: &Shape, v: [f64; 3], l: [f64; 3], off: usize) -> Pair {
        let mut raw = [0.0f32; 6];
        shape.directions.encode(v, l, &mut raw);
        Pair { off, raw, gain: shape.directions.gain(l), taps: table_taps(shape, v, l) }
    }

    /// The encoding (coordinates, then table features) under `params`, into `out`.
    #[inline]
    fn encode(&self, shape: &Shape, params: &[f32], out: &mut [f32]) {
        let e = shape.directions.dims();
        out[..e].copy_from_slice(&self.raw[..e]);
        let c = shape.features;
        let base = shape.offsets().tables;
        let nodes = shape.grid * shape.grid;
        for (ti, taps) in self.taps.iter().enumerate().take(shape.tables()) {
            let o = &mut out[e + ti * c..e + (ti + 1) * c];
            o.fill(0.0);
            for &(node, w) in taps {
                let row = &params[base + (ti * nodes + node as usize) * c..][..c];
                o.iter_mut().zip(row).for_each(|(x, f)| *x += w * f);
            }
        }
    }

    /// Add the gradient `de` of the encoding to the tables' gradients in `g`.
    #[inline]
    fn scatter(&self, shape: &Shape, de: &[f32], g: &mut [f32]) {
        let e = shape.directions.dims();
        let c = shape.features;
        let base = shape.offsets().tables;
        let nodes = shape.grid * shape.grid;
        for (ti, taps) in self.taps.iter().enumerate().take(shape.tables()) {
            let d = &de[e + ti * c..e + (ti + 1) * c];
            for &(node, w) in taps {
                let row = &mut g[base + (ti * nodes + node as usize) * c..][..c];
                row.iter_mut().zip(d).for_each(|(x, f)| *x += w * f);
            }
        }
    }
}

/// The present pairs, split into training and validation pairs.
struct Pairs {
    train: Vec<Pair>,
    val: Vec<Pair>,
}

fn split_pairs(btf: &BtfRef<'_>, s: &Setup) -> Result<Pairs> {
    let nl = btf.lights.len();
    let mut all: Vec<Pair> = Vec::new();
    for v in 0..btf.views.len() {
        for l in 0..nl {
            if btf.has(v, l) {
                all.push(Pair::new(&s.shape, btf.views[v], btf.lights[l], (v * nl + l) * 3));
            }
        }
    }
    let mut rng = Rng::new(mix(s.seed ^ 0x5a17));
    for i in (1..all.len()).rev() {
        all.swap(i, rng.below(i + 1));
    }
    // Too few pairs to spare any: no early stopping (the report says so).
    let n_val =
        if all.len() >= 20 { ((all.len() as f64 * s.validation).round() as usize).min(all.len() / 2) } else { 0 };
    let val = all.split_off(all.len() - n_val);
    let k = s.shape.latents;
    if all.len() < k {
        return Err(Error::arg(
            "latents",
            format!(
                "expected at most as many latents as training pairs: {k} latents per texel cannot be \
                 determined from {} present pairs ({} kept for validation)",
                all.len(),
                n_val
            ),
        ));
    }
    Ok(Pairs { train: all, val })
}

/// Adam's state for one parameter vector.
#[derive(Debug, Clone)]
struct Adam {
    m: Vec<f32>,
    v: Vec<f32>,
}

impl Adam {
    fn new(n: usize) -> Adam {
        Adam { m: vec![0.0; n], v: vec![0.0; n] }
    }
    /// One update of `x` by gradient `g` at step `t` (1-based) with rate `lr`, on the range `r`.
    #[inline]
    fn update(&mut self, x: &mut [f32], g: &[f32], r: std::ops::Range<usize>, t: usize, lr: f32) {
        let c1 = 1.0 - BETA1.powi(t as i32);
        let c2 = 1.0 - BETA2.powi(t as i32);
        let step = lr * c2.sqrt() / c1;
        for ((x, &g), (m, v)) in x.iter_mut().zip(g).zip(self.m[r.clone()].iter_mut().zip(&mut self.v[r])) {
            *m = BETA1 * *m + (1.0 - BETA1) * g;
            *v = BETA2 * *v + (1.0 - BETA2) * g * g;
            *x -= step * *m / (v.sqrt() + EPS);
        }
    }
}

/// Glorot-uniform weights, zero biases.
fn init_decoder(shape: Shape, seed: u64) -> Vec<f32> {
    let o = shape.offsets();
    let mut p = vec![0.0f32; o.len];
    let mut rng = Rng::new(mix(seed ^ 0xdec0de));
    let mut fill = |p: &mut [f32], fan_in: usize, fan_out: usize| {
        let a = (6.0 / (fan_in + fan_out) as f64).sqrt();
        p.iter_mut().for_each(|x| *x = ((2.0 * rng.next_f64() - 1.0) * a) as f32);
    };
    let (n, h) = (shape.inputs(), shape.hidden);
    fill(&mut p[o.w1..o.b1], n, h);
    fill(&mut p[o.w2..o.b2], h, h);
    fill(&mut p[o.w3..o.b3], h, 3);
    // The tables start at zero (their gradient is not: the first layer's weights differ), so
    // a node no measured direction reaches (beyond the sampling's last ring) stays neutral
    // instead of random: random starts drew wild values at grazing unmeasured directions.
    let _ = o.tables;
    p
}

/// The values' root mean square over a sample of texels and training pairs.
fn value_scale(btf: &BtfRef<'_>, pairs: &Pairs, seed: u64) -> f64 {
    let mut rng = Rng::new(mix(seed ^ 0x5ca1e));
    let t = btf.texels();
    let (mut s2, mut n) = (0.0f64, 0usize);
    for _ in 0..4096.min(t * pairs.train.len()) {
        let texel = btf.texel(rng.below(t));
        let off = pairs.train[rng.below(pairs.train.len())].off;
        for c in 0..3 {
            s2 += (texel[off + c] as f64).powi(2);
        }
        n += 3;
    }
    let rms = (s2 / n.max(1) as f64).sqrt();
    if rms > 0.0 && rms.is_finite() {
        rms
    } else {
        1.0
    }
}

/// The starting latents, `texels x k`: principal coordinates of the texels' values at a random
/// subset of the training pairs, each scaled to unit variance. Returns them and the component
/// count found.
fn pca_latents(btf: &BtfRef<'_>, pairs: &Pairs, k: usize, seed: u64, monitor: &Monitor) -> Result<(Vec<f32>, usize)> {
    let t = btf.texels();
    let mut npairs = PCA_PAIRS.min(pairs.train.len());
    if let Some(limit) = monitor.memory_limit() {
        // The gathered sample is the fit's largest allocation: keep it within half the limit.
        npairs = npairs.min(((limit / 2) as usize / (t * 12).max(1)).max(k.div_ceil(3)).max(1));
    }
    let mut rng = Rng::new(mix(seed ^ 0x9ca));
    let mut idx: Vec<usize> = (0..pairs.train.len()).collect();
    let len = idx.len();
    for i in 0..npairs {
        idx.swap(i, i + rng.below(len - i));
    }
    let offs: Vec<usize> = idx[..npairs].iter().map(|&i| pairs.train[i].off).collect();
    let d = 3 * npairs;
    let mut g = vec![0.0f32; t * d];
    g.par_chunks_mut(d).enumerate().for_each(|(ti, row)| {
        let texel = btf.texel(ti);
        for (j, &o) in offs.iter().enumerate() {
            row[3 * j..3 * j + 3].copy_from_slice(&texel[o..o + 3]);
        }
    });
    let mut z = vec![0.0f32; t * k];
    let mut found = 0;
    if t > 1 {
        let (coords, r) = btfrs_numerics::rpca::principal_coordinates(
            &g,
            d,
            t,
            k.min(d).min(t - 1).max(1),
            seed,
            None,
            1,
            &Monitor::new(),
        )?;
        found = r;
        for c in 0..r {
            let col: Vec<f64> = (0..t).map(|i| coords[i * r + c] as f64).collect();
            let mean = col.iter().sum::<f64>() / t as f64;
            let sd = (col.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / t as f64).sqrt();
            if sd > 0.0 && sd.is_finite() {
                for i in 0..t {
                    z[i * k + c] = ((col[i] - mean) / sd) as f32;
                }
            } else {
                found = found.min(c);
            }
        }
    }
    // Channels the PCA could not fill start as small noise, so their gradients differ.
    for i in 0..t {
        for c in found..k {
            z[i * k + c] = (0.02 * (rng.next_f64() - 0.5)) as f32;
        }
    }
    Ok((z, found))
}

/// One chunk's gradients.
pub(crate) struct ChunkGrad {
    pub(crate) dec: Vec<f32>,
    pub(crate) dz: Vec<f32>,
    pub(crate) sse: f64,
}

/// Forward and backward over `texels` (their latents `z`, `k` each) at `PAIRS` random training
/// pairs each; `targets` scaled by `1 / scale`; the loss is the sum of squared errors divided by
/// `norm`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn chunk_grad(
    btf: &BtfRef<'_>,
    pairs: &[Pair],
    dec: &Decoder,
    texels: &[usize],
    z: &[f32],
    inv_scale: f32,
    norm: f32,
    seed: u64,
    want_dz: bool,
) -> ChunkGrad {
    let sh = dec.shape;
    let (k, e, h, ni) = (sh.latents, sh.encoding(), sh.hidden, sh.inputs());
    let o = sh.offsets();
    let p = &dec.params;
    let c = texels.len();
    let mut picked: Vec<&Pair> = Vec::with_capacity(c * PAIRS);
    let n = c * PAIRS;
    let mut rng = Rng::new(seed);
    // Inputs and targets.
    let mut enc = vec![0.0f32; n * e];
    let mut gain = vec![0.0f32; n];
    let mut tgt = vec![0.0f32; n * 3];
    for (ci, &t) in texels.iter().enumerate() {
        let texel = btf.texel(t);
        for s in 0..PAIRS {
            let r = ci * PAIRS + s;
            let pair = &pairs[rng.below(pairs.len())];
            pair.encode(&sh, p, &mut enc[r * e..(r + 1) * e]);
            gain[r] = pair.gain;
            for ch in 0..3 {
                tgt[r * 3 + ch] = texel[pair.off + ch] * inv_scale;
            }
            picked.push(pair);
        }
    }
    // Layer 1: the latent part per texel, the direction part per sample.
    let w1 = &p[o.w1..o.b1];
    let mut a = vec![0.0f32; c * h];
    for ci in 0..c {
        for j in 0..h {
            a[ci * h + j] = (0..k).map(|q| w1[j * ni + q] * z[ci * k + q]).sum::<f32>() + p[o.b1 + j];
        }
    }
    // The direction part of every sample at once: enc [n][e] times the direction columns of
    // W1 (a block of it, row stride ni) transposed; then each sample's texel part.
    let mut h1 = vec![0.0f32; n * h];
    strided(&enc, View::rows(n, e), &w1[k..], View::block_t(e, h, ni), 0.0, &mut h1, View::rows(n, h));
    for r in 0..n {
        let ar = &a[(r / PAIRS) * h..(r / PAIRS + 1) * h];
        h1[r * h..(r + 1) * h].iter_mut().zip(ar).for_each(|(x, a)| *x += a);
    }
    sh.activation.apply(&mut h1);
    // Layer 2.
    let mut h2 = vec![0.0f32; n * h];
    GEMM.abt(n, h, h, &h1, &p[o.w2..o.b2], &mut h2, false);
    for r in 0..n {
        h2[r * h..(r + 1) * h].iter_mut().zip(&p[o.b2..o.w3]).for_each(|(x, b)| *x += b);
    }
    sh.activation.apply(&mut h2);
    // Output and its gradient.
    let w3 = &p[o.w3..o.b3];
    let mut g = vec![0.0f32; o.len];
    let mut dh2 = vec![0.0f32; n * h];
    let mut sse = 0.0f64;
    for r in 0..n {
        let hr = &h2[r * h..(r + 1) * h];
        for ch in 0..3 {
            let y = p[o.b3 + ch] + w3[ch * h..(ch + 1) * h].iter().zip(hr).map(|(w, x)| w * x).sum::<f32>();
            let d = y * gain[r] - tgt[r * 3 + ch];
            sse += (d as f64) * (d as f64);
            let dy = 2.0 * d * gain[r] / norm;
            g[o.b3 + ch] += dy;
            g[o.w3 + ch * h..o.w3 + (ch + 1) * h].iter_mut().zip(hr).for_each(|(gw, x)| *gw += dy * x);
            dh2[r * h..(r + 1) * h].iter_mut().zip(&w3[ch * h..(ch + 1) * h]).for_each(|(d2, w)| *d2 += dy * w);
        }
    }
    sh.activation.backward(&h2, &mut dh2);
    // Layer 2's gradients.
    GEMM.atb(h, n, h, &dh2, &h1, &mut g[o.w2..o.b2], true);
    for r in 0..n {
        g[o.b2..o.w3].iter_mut().zip(&dh2[r * h..(r + 1) * h]).for_each(|(gb, d)| *gb += d);
    }
    let mut dh1 = vec![0.0f32; n * h];
    GEMM.ab(n, h, h, &dh2, &p[o.w2..o.b2], &mut dh1, false);
    sh.activation.backward(&h1, &mut dh1);
    // Layer 1's gradients: direction columns per sample, latent columns per texel.
    // Layer 1's gradients: the direction columns (a block of W1) and their inputs, for every
    // sample at once; the bias and the latent columns per texel.
    strided(&dh1, View::transposed(h, n), &enc, View::rows(n, e), 1.0, &mut g[o.w1 + k..], View::block(h, e, ni));
    let mut da = vec![0.0f32; c * h];
    for r in 0..n {
        da[(r / PAIRS) * h..(r / PAIRS + 1) * h].iter_mut().zip(&dh1[r * h..(r + 1) * h]).for_each(|(x, d)| *x += d);
    }
    for ci in 0..c {
        g[o.b1..o.b1 + h].iter_mut().zip(&da[ci * h..(ci + 1) * h]).for_each(|(x, d)| *x += d);
    }
    if sh.tables() > 0 {
        let mut de = vec![0.0f32; n * e];
        strided(&dh1, View::rows(n, h), &w1[k..], View::block(h, e, ni), 0.0, &mut de, View::rows(n, e));
        for (r, pair) in picked.iter().enumerate() {
            pair.scatter(&sh, &de[r * e..(r + 1) * e], &mut g);
        }
    }
    let mut dz = vec![0.0f32; if want_dz { c * k } else { 0 }];
    for ci in 0..c {
        for j in 0..h {
            let d = da[ci * h + j];
            for q in 0..k {
                g[o.w1 + j * ni + q] += d * z[ci * k + q];
                if want_dz {
                    dz[ci * k + q] += d * w1[j * ni + q];
                }
            }
        }
    }
    ChunkGrad { dec: g, dz, sse }
}

/// Relative L2 error over `texels` x `pairs` (values scaled by `inv_scale`).
fn val_error(btf: &BtfRef<'_>, pairs: &[Pair], dec: &Decoder, z: &[f32], texels: &[usize], inv_scale: f32) -> f64 {
    let sh = dec.shape;
    let (k, e, h, ni) = (sh.latents, sh.encoding(), sh.hidden, sh.inputs());
    let o = sh.offsets();
    let w2t = dec.w2t();
    // The direction part of layer 1 per pair.
    let mut qb = vec![0.0f32; pairs.len() * h];
    let mut en = [0.0f32; MAX_ENCODING];
    for (pi, pair) in pairs.iter().enumerate() {
        pair.encode(&sh, &dec.params, &mut en[..e]);
        for j in 0..h {
            let row = &dec.params[o.w1 + j * ni + k..o.w1 + (j + 1) * ni];
            qb[pi * h + j] = dec.params[o.b1 + j] + row.iter().zip(&en[..e]).map(|(w, x)| w * x).sum::<f32>();
        }
    }
    let gains: Vec<f32> = pairs.iter().map(|p| p.gain).collect();
    let (sse, sgt) = texels
        .par_iter()
        .map(|&t| {
            let texel = btf.texel(t);
            let mut a = vec![0.0f32; h];
            dec.latent_part(&z[t * k..(t + 1) * k], &mut a);
            let (mut pre, mut scratch) = (vec![0.0f32; h], vec![0.0f32; h]);
            let (mut sse, mut sgt) = (0.0f64, 0.0f64);
            for (pi, pair) in pairs.iter().enumerate() {
                let off = pair.off;
                pre.iter_mut().zip(&a).zip(&qb[pi * h..(pi + 1) * h]).for_each(|((x, a), b)| *x = a + b);
                let y = dec.finish(&mut pre, &w2t, &mut scratch);
                for ch in 0..3 {
                    let gt = (texel[off + ch] * inv_scale) as f64;
                    sse += ((y[ch] * gains[pi]) as f64 - gt).powi(2);
                    sgt += gt * gt;
                }
            }
            (sse, sgt)
        })
        .reduce(|| (0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
    if sgt > 0.0 {
        (sse / sgt).sqrt()
    } else {
        sse.sqrt()
    }
}

/// The learning rate at step `i` of `n`: a linear warm-up over the first 2%, then a cosine
/// from `lr` down to `lr / 20`.
fn schedule(lr: f64, i: usize, n: usize) -> f32 {
    let warm = (n / 50).max(1);
    if i < warm {
        return (lr * (i + 1) as f64 / warm as f64) as f32;
    }
    let x = (i - warm) as f64 / (n - warm).max(1) as f64;
    (lr * (0.05 + 0.95 * 0.5 * (1.0 + (std::f64::consts::PI * x).cos()))) as f32
}

/// The texels of each step: the next `batch` of a shuffled order, reshuffled when spent.
struct Batches {
    order: Vec<usize>,
    cursor: usize,
    batch: usize,
}

impl Batches {
    fn next(&mut self, rng: &mut Rng) -> Vec<usize> {
        let t = self.order.len();
        if self.cursor + self.batch > t {
            for i in (1..t).rev() {
                self.order.swap(i, rng.below(i + 1));
            }
            self.cursor = 0;
        }
        let out = self.order[self.cursor..self.cursor + self.batch].to_vec();
        self.cursor += self.batch;
        out
    }
}

/// The gradients of one step over `texels` (codes from `z`, `k` each), chunk by chunk in
/// parallel and returned in chunk order; chunk `ci` gets seed `mix(seed + ci)` for its pairs.
fn batch_grads(
    texels: &[usize],
    z: &[f32],
    k: usize,
    seed: u64,
    grad: impl Fn(&[usize], &[f32], u64) -> ChunkGrad + Sync,
) -> Vec<ChunkGrad> {
    let zb: Vec<f32> = texels.iter().flat_map(|&ti| z[ti * k..(ti + 1) * k].iter().copied()).collect();
    texels
        .par_chunks(CHUNK)
        .zip(zb.par_chunks(CHUNK * k))
        .enumerate()
        .map(|(ci, (tx, zc))| grad(tx, zc, mix(seed.wrapping_add(ci as u64))))
        .collect()
}

/// Train a neural model on the present pairs of `btf`; `monitor` counts steps.
pub fn train(btf: &BtfRef<'_>, s: &Setup, monitor: &Monitor) -> Result<Trained> {
    let pairs = split_pairs(btf, s)?;
    let sh = s.shape;
    let k = sh.latents;
    let t = btf.texels();
    let qat = (s.steps / 10).max(1);
    monitor.start((s.steps + qat) as u64 + 1);
    let scale = value_scale(btf, &pairs, s.seed);
    let inv_scale = (1.0 / scale) as f32;
    let (mut z, pca_components) = pca_latents(btf, &pairs, k, s.seed, monitor)?;
    monitor.advance(1);
    monitor.check()?;
    let mut dec = Decoder { shape: sh, params: init_decoder(sh, s.seed) };
    let mut adam = Adam::new(dec.params.len());
    let mut zadam = Adam::new(t * k);
    let mut ztime = vec![0u32; t];
    let batch = BATCH_TEXELS.min(t);
    let mut batches = Batches { order: (0..t).collect(), cursor: t, batch };
    let mut rng = Rng::new(mix(s.seed ^ 0x0de7));
    let val_texels: Vec<usize> = {
        let mut idx: Vec<usize> = (0..t).collect();
        let m = VALIDATION_TEXELS.min(t);
        for i in 0..m {
            idx.swap(i, i + rng.below(t - i));
        }
        idx.truncate(m);
        idx
    };
    let eval_every = (s.steps / 40).clamp(50, 500);
    let mut report = TrainReport { validation_pairs: pairs.val.len(), pca_components, scale, ..Default::default() };
    let mut best: Option<(f64, Vec<f32>, Vec<f32>)> = None;
    let mut since_best = 0;
    let mut lr = s.learning_rate;
    let norm = (batch * PAIRS * 3) as f32;
    let mut step = 0;
    while step < s.steps {
        monitor.check()?;
        let texels = batches.next(&mut rng);
        let seed = mix(s.seed ^ mix((step * 4096) as u64));
        let grads = batch_grads(&texels, &z, k, seed, |tx, zc, sd| {
            chunk_grad(btf, &pairs.train, &dec, tx, zc, inv_scale, norm, sd, true)
        });
        let mut g = vec![0.0f32; dec.params.len()];
        let mut sse = 0.0;
        for cg in &grads {
            g.iter_mut().zip(&cg.dec).for_each(|(a, b)| *a += b);
            sse += cg.sse;
        }
        if !sse.is_finite() || g.iter().any(|x| !x.is_finite()) {
            // Diverged: back to the best parameters at half the rate.
            report.lr_halvings += 1;
            if report.lr_halvings > 8 {
                return Err(Error::Numerical(format!(
                    "neural: training diverged at step {step} even at learning rate {lr:.2e}; lower learning_rate"
                )));
            }
            lr *= 0.5;
            if let Some((_, bp, bz)) = &best {
                dec.params.clone_from(bp);
                z.clone_from(bz);
            } else {
                dec.params = init_decoder(sh, s.seed ^ report.lr_halvings as u64);
            }
            adam = Adam::new(dec.params.len());
            zadam = Adam::new(t * k);
            ztime.fill(0);
            continue;
        }
        let rate = schedule(lr, step, s.steps);
        let n = dec.params.len();
        adam.update(&mut dec.params, &g, 0..n, step + 1, rate);
        for (cg, tx) in grads.iter().zip(texels.chunks(CHUNK)) {
            for (j, &ti) in tx.iter().enumerate() {
                ztime[ti] += 1;
                zadam.update(
                    &mut z[ti * k..(ti + 1) * k],
                    &cg.dz[j * k..(j + 1) * k],
                    ti * k..(ti + 1) * k,
                    ztime[ti] as usize,
                    rate * LATENT_RATE,
                );
            }
        }
        step += 1;
        monitor.advance(1);
        if !pairs.val.is_empty() && (step % eval_every == 0 || step == s.steps) {
            let err = val_error(btf, &pairs.val, &dec, &z, &val_texels, inv_scale);
            if best.as_ref().is_none_or(|(b, _, _)| err < *b) {
                best = Some((err, dec.params.clone(), z.clone()));
                report.best_step = step;
                since_best = 0;
            } else {
                since_best += 1;
                if since_best >= PATIENCE {
                    report.stopped_early = true;
                    break;
                }
            }
        }
    }
    report.steps = step;
    if let Some((err, bp, bz)) = best {
        dec.params = bp;
        z = bz;
        report.validation_error = Some(err);
    } else {
        report.best_step = step;
    }
    // Quantization-aware end: the decoder learns the decoded 8-bit latents.
    let planes = Planes::quantize(&z, k)?;
    let zq = planes.dequantize();
    let mut adam = Adam::new(dec.params.len());
    let qat_lr = (0.2 * lr).min(s.learning_rate);
    for i in 0..qat {
        monitor.check()?;
        let texels = batches.next(&mut rng);
        let seed = mix(s.seed ^ mix(((s.steps + i) * 4096) as u64));
        let grads = batch_grads(&texels, &zq, k, seed, |tx, zc, sd| {
            chunk_grad(btf, &pairs.train, &dec, tx, zc, inv_scale, norm, sd, false)
        });
        let mut g = vec![0.0f32; dec.params.len()];
        for cg in &grads {
            g.iter_mut().zip(&cg.dec).for_each(|(a, b)| *a += b);
        }
        if g.iter().any(|x| !x.is_finite()) {
            break; // keep the parameters of the last finite step
        }
        let n = dec.params.len();
        adam.update(&mut dec.params, &g, 0..n, i + 1, schedule(qat_lr, i, qat));
        report.qat_steps = i + 1;
        monitor.advance(1);
    }
    if !pairs.val.is_empty() {
        report.validation_error_8bit = Some(val_error(btf, &pairs.val, &dec, &zq, &val_texels, inv_scale));
    }
    // Back to the data's scale: the last layer times the scale.
    let o = sh.offsets();
    dec.params[o.w3..o.tables].iter_mut().for_each(|x| *x *= scale as f32);
    let decoder = Decoder::new(sh, dec.params, "decoder")?;
    Ok(Trained { latents: planes, decoder, report })
}
