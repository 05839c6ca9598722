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
use crate::relief::HorizonMap;
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
pub(crate) const CHUNK: usize = 32;
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
    /// The step from which the rate fell to zero because validation stopped improving (null:
    /// the schedule ran its course).
    pub cooldown_from: Option<usize>,
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
    /// Per clearance input (`Shape::clearance_directions`): the horizon bins around the
    /// direction's azimuth, the second's weight, and its elevation (`crate::relief::lookup`).
    pub(crate) look: [(u16, u16, f32, f32); 2],
}

impl Pair {
    /// Pair (`v`, `l`) at ABRDF offset `off`.
    pub(crate) fn new(shape: &Shape, v: [f64; 3], l: [f64; 3], off: usize) -> Pair {
        let mut raw = [0.0f32; 6];
        shape.directions.encode(v, l, &mut raw);
        let mut look = [(0u16, 0u16, 0.0f32, 0.0f32); 2];
        if shape.horizon > 0 {
            for (o, d) in look.iter_mut().zip(shape.clearance_directions(v, l)) {
                let (k0, k1, w, el) = crate::relief::lookup(d, shape.horizon);
                *o = (k0 as u16, k1 as u16, w, el);
            }
        }
        Pair { off, raw, gain: shape.directions.gain(l), taps: table_taps(shape, v, l), look }
    }

    /// The pair's part of the encoding under `params`, into `out`: the coordinates, zeros where
    /// the (per texel) clearances go, the table features.
    #[inline]
    fn encode(&self, shape: &Shape, params: &[f32], out: &mut [f32]) {
        let d = shape.directions.dims();
        out[..d].copy_from_slice(&self.raw[..d]);
        let e = d + shape.clearances();
        out[d..e].fill(0.0);
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

    /// Its clearance `i` above a texel's horizon row `hz`.
    #[inline]
    fn clearance(&self, i: usize, hz: &[f32]) -> f32 {
        let (k0, k1, w, el) = self.look[i];
        el - (hz[k0 as usize] * (1.0 - w) + hz[k1 as usize] * w)
    }

    /// Add the gradient `de` of the encoding to the tables' gradients in `g`.
    #[inline]
    fn scatter(&self, shape: &Shape, de: &[f32], g: &mut [f32]) {
        let e = shape.directions.dims() + shape.clearances();
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
pub(crate) struct Pairs {
    pub(crate) train: Vec<Pair>,
    pub(crate) val: Vec<Pair>,
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
pub(crate) struct Adam {
    m: Vec<f32>,
    v: Vec<f32>,
}

impl Adam {
    pub(crate) fn new(n: usize) -> Adam {
        Adam { m: vec![0.0; n], v: vec![0.0; n] }
    }
    /// One update of `x` by gradient `g` at step `t` (1-based) with rate `lr`, on the range `r`.
    #[inline]
    pub(crate) fn update(&mut self, x: &mut [f32], g: &[f32], r: std::ops::Range<usize>, t: usize, lr: f32) {
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

/// `sum a b` over slices of one length, in eight lanes (so it vectorizes).
#[inline]
fn dot(a: &[f32], b: &[f32]) -> f32 {
    let mut acc = [0.0f32; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for i in 0..8 {
            acc[i] += x[i] * y[i];
        }
    }
    let tail: f32 = ra.iter().zip(rb).map(|(x, y)| x * y).sum();
    acc.iter().sum::<f32>() + tail
}

/// `count` distinct indices below `n` (all of them, in order, when `count >= n`): Floyd's
/// sampling.
fn distinct(rng: &mut Rng, n: usize, count: usize) -> Vec<usize> {
    if count >= n {
        return (0..n).collect();
    }
    let mut out: Vec<usize> = Vec::with_capacity(count);
    for j in n - count..n {
        let t = rng.below(j + 1);
        out.push(if out.contains(&t) { j } else { t });
    }
    out
}

/// Forward and backward over `texels` (their latents `z`, `k` each, and horizon rows `hz`,
/// `shape.horizon` each or none) at `PAIRS` random training pairs shared by the chunk (so the
/// first layer's direction part is computed once per pair, its latent part once per texel);
/// `targets` scaled by `inv_scale`; the loss is the sum of squared errors divided by `norm`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn chunk_grad(
    btf: &BtfRef<'_>,
    pairs: &[Pair],
    dec: &Decoder,
    texels: &[usize],
    z: &[f32],
    hz: &[f32],
    inv_scale: f32,
    norm: f32,
    seed: u64,
    want_dz: bool,
) -> ChunkGrad {
    SCRATCH.with_borrow_mut(|sc| chunk_grad_in(sc, btf, pairs, dec, texels, z, hz, inv_scale, norm, seed, want_dz))
}

/// Buffers of a chunk's step, kept per thread across steps: fresh ones cost a tenth of a step
/// in allocation and zeroing. Each is overwritten before it is read, but for the sums, which are
/// cleared.
#[derive(Default)]
struct Scratch {
    enc: Vec<f32>,
    tgt: Vec<f32>,
    a: Vec<f32>,
    q: Vec<f32>,
    clear: Vec<f32>,
    h1: Vec<f32>,
    h2: Vec<f32>,
    dh2: Vec<f32>,
    dy: Vec<f32>,
    dh1: Vec<f32>,
    da: Vec<f32>,
    dq: Vec<f32>,
    dws: Vec<f32>,
    de: Vec<f32>,
}

thread_local! {
    static SCRATCH: std::cell::RefCell<Scratch> = std::cell::RefCell::new(Scratch::default());
}

/// `v` as `len` values (its old contents where it had them: every caller overwrites or clears).
fn sized(v: &mut Vec<f32>, len: usize) -> &mut [f32] {
    if v.len() < len {
        v.resize(len, 0.0);
    }
    &mut v[..len]
}

crate::simd::by_cpu! {
    /// [`chunk_grad_body`] compiled for the widest vectors the CPU has: the wheel is built for
    /// the x86-64 baseline (SSE2), and the step's element-wise passes (activations, the output
    /// layer, the sums over pairs and texels) are most of its work outside the matrix products.
    #[allow(clippy::too_many_arguments)]
    fn chunk_grad_in(
        sc: &mut Scratch,
        btf: &BtfRef<'_>,
        pairs: &[Pair],
        dec: &Decoder,
        texels: &[usize],
        z: &[f32],
        hz: &[f32],
        inv_scale: f32,
        norm: f32,
        seed: u64,
        want_dz: bool,
    ) -> ChunkGrad ["avx512f", "avx2"] {
        chunk_grad_body(sc, btf, pairs, dec, texels, z, hz, inv_scale, norm, seed, want_dz)
    }
}

#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn chunk_grad_body(
    sc: &mut Scratch,
    btf: &BtfRef<'_>,
    pairs: &[Pair],
    dec: &Decoder,
    texels: &[usize],
    z: &[f32],
    hz: &[f32],
    inv_scale: f32,
    norm: f32,
    seed: u64,
    want_dz: bool,
) -> ChunkGrad {
    let sh = dec.shape;
    let (k, e, h, ni) = (sh.latents, sh.encoding(), sh.hidden, sh.inputs());
    let (nd, ns, bins) = (sh.directions.dims(), sh.clearances(), sh.horizon);
    let o = sh.offsets();
    let p = &dec.params;
    let act = sh.activation;
    let c = texels.len();
    let mut rng = Rng::new(seed);
    let picked: Vec<&Pair> = distinct(&mut rng, pairs.len(), PAIRS).into_iter().map(|i| &pairs[i]).collect();
    let np = picked.len();
    let n = c * np;
    // The pairs' encodings and the targets, sample r = texel (r / np), pair (r % np).
    let enc = sized(&mut sc.enc, np * e);
    for (pi, pair) in picked.iter().enumerate() {
        pair.encode(&sh, p, &mut enc[pi * e..(pi + 1) * e]);
    }
    let tgt = sized(&mut sc.tgt, n * 3);
    for (ci, &t) in texels.iter().enumerate() {
        let texel = btf.texel(t);
        for (pi, pair) in picked.iter().enumerate() {
            let r = ci * np + pi;
            for ch in 0..3 {
                tgt[r * 3 + ch] = texel[pair.off + ch] * inv_scale;
            }
        }
    }
    // Layer 1: the latent part per texel (with the bias), the direction part per pair, the
    // clearances per sample.
    let w1 = &p[o.w1..o.b1];
    let a = sized(&mut sc.a, c * h);
    strided(z, View::rows(c, k), w1, View::block_t(k, h, ni), 0.0, a, View::rows(c, h));
    for row in a.chunks_exact_mut(h) {
        row.iter_mut().zip(&p[o.b1..o.w2]).for_each(|(x, b)| *x += b);
    }
    let q = sized(&mut sc.q, np * h);
    strided(enc, View::rows(np, e), &w1[k..], View::block_t(e, h, ni), 0.0, q, View::rows(np, h));
    let ws: Vec<f32> = (0..ns).flat_map(|i| (0..h).map(move |j| w1[j * ni + k + nd + i])).collect();
    let clear = sized(&mut sc.clear, n * ns);
    let h1 = sized(&mut sc.h1, n * h);
    for ci in 0..c {
        let hzr = &hz[ci * bins..(ci + 1) * bins];
        for (pi, pair) in picked.iter().enumerate() {
            let r = ci * np + pi;
            let row = &mut h1[r * h..(r + 1) * h];
            row.iter_mut()
                .zip(&a[ci * h..(ci + 1) * h])
                .zip(&q[pi * h..(pi + 1) * h])
                .for_each(|((x, a), q)| *x = a + q);
            for i in 0..ns {
                let s = pair.clearance(i, hzr);
                clear[r * ns + i] = s;
                row.iter_mut().zip(&ws[i * h..(i + 1) * h]).for_each(|(x, w)| *x += s * w);
            }
        }
    }
    act.apply_fast(h1);
    // Layer 2.
    let h2 = sized(&mut sc.h2, n * h);
    GEMM.abt(n, h, h, h1, &p[o.w2..o.b2], h2, false);
    for row in h2.chunks_exact_mut(h) {
        row.iter_mut().zip(&p[o.b2..o.w3]).for_each(|(x, b)| *x += b);
    }
    act.apply_fast(h2);
    // Output and its gradient; dy [n][3] for the output layer's weights.
    let w3 = &p[o.w3..o.b3];
    let mut g = vec![0.0f32; o.len];
    let dh2 = sized(&mut sc.dh2, n * h);
    let dy = sized(&mut sc.dy, n * 3);
    let mut sse = 0.0f64;
    for r in 0..n {
        let hr = &h2[r * h..(r + 1) * h];
        let gain = picked[r % np].gain;
        let mut d3 = [0.0f32; 3];
        for ch in 0..3 {
            let y = p[o.b3 + ch] + dot(&w3[ch * h..(ch + 1) * h], hr);
            let d = y * gain - tgt[r * 3 + ch];
            sse += (d as f64) * (d as f64);
            d3[ch] = 2.0 * d * gain / norm;
        }
        dy[r * 3..r * 3 + 3].copy_from_slice(&d3);
        let row = &mut dh2[r * h..(r + 1) * h];
        for (j, x) in row.iter_mut().enumerate() {
            *x = d3[0] * w3[j] + d3[1] * w3[h + j] + d3[2] * w3[2 * h + j];
        }
    }
    // The output layer's gradients: w3 += dy^T h2, b3 += the sums of dy.
    GEMM.atb(3, n, h, dy, h2, &mut g[o.w3..o.b3], true);
    for r in 0..n {
        for ch in 0..3 {
            g[o.b3 + ch] += dy[r * 3 + ch];
        }
    }
    act.backward(h2, dh2);
    // Layer 2's gradients.
    GEMM.atb(h, n, h, dh2, h1, &mut g[o.w2..o.b2], true);
    for row in dh2.chunks_exact(h) {
        g[o.b2..o.w3].iter_mut().zip(row).for_each(|(gb, d)| *gb += d);
    }
    let dh1 = sized(&mut sc.dh1, n * h);
    GEMM.ab(n, h, h, dh2, &p[o.w2..o.b2], dh1, false);
    act.backward(h1, dh1);
    // Layer 1's gradients: summed over pairs for each texel (the latent columns, the bias),
    // over texels for each pair (the direction columns); the clearances' columns per sample.
    let da = sized(&mut sc.da, c * h);
    let dq = sized(&mut sc.dq, np * h);
    let dws = sized(&mut sc.dws, ns * h);
    da.fill(0.0);
    dq.fill(0.0);
    dws.fill(0.0);
    for ci in 0..c {
        for pi in 0..np {
            let r = ci * np + pi;
            let d = &dh1[r * h..(r + 1) * h];
            da[ci * h..(ci + 1) * h].iter_mut().zip(d).for_each(|(x, d)| *x += d);
            dq[pi * h..(pi + 1) * h].iter_mut().zip(d).for_each(|(x, d)| *x += d);
            for i in 0..ns {
                let s = clear[r * ns + i];
                dws[i * h..(i + 1) * h].iter_mut().zip(d).for_each(|(x, d)| *x += s * d);
            }
        }
    }
    for row in da.chunks_exact(h) {
        g[o.b1..o.w2].iter_mut().zip(row).for_each(|(x, d)| *x += d);
    }
    strided(da, View::transposed(h, c), z, View::rows(c, k), 1.0, &mut g[o.w1..], View::block(h, k, ni));
    strided(dq, View::transposed(h, np), enc, View::rows(np, e), 1.0, &mut g[o.w1 + k..], View::block(h, e, ni));
    for i in 0..ns {
        for j in 0..h {
            g[o.w1 + j * ni + k + nd + i] += dws[i * h + j];
        }
    }
    if sh.tables() > 0 {
        let de = sized(&mut sc.de, np * e);
        strided(dq, View::rows(np, h), &w1[k..], View::block(h, e, ni), 0.0, de, View::rows(np, e));
        for (pi, pair) in picked.iter().enumerate() {
            pair.scatter(&sh, &de[pi * e..(pi + 1) * e], &mut g);
        }
    }
    let mut dz = vec![0.0f32; if want_dz { c * k } else { 0 }];
    if want_dz {
        strided(da, View::rows(c, h), w1, View::block(h, k, ni), 0.0, &mut dz, View::rows(c, k));
    }
    ChunkGrad { dec: g, dz, sse }
}

/// Relative L2 error over `texels` x `pairs` (values scaled by `inv_scale`; codes `z` of every
/// texel, horizon rows `hz` of `texels` in their order).
#[allow(clippy::too_many_arguments)]
pub(crate) fn val_error(
    btf: &BtfRef<'_>,
    pairs: &[Pair],
    dec: &Decoder,
    z: &[f32],
    hz: &[f32],
    texels: &[usize],
    inv_scale: f32,
) -> f64 {
    let sh = dec.shape;
    let (k, e, h, ni) = (sh.latents, sh.encoding(), sh.hidden, sh.inputs());
    let (ns, bins) = (sh.clearances(), sh.horizon);
    let o = sh.offsets();
    let w2t = dec.w2t();
    let ws = dec.clearance_columns();
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
        .enumerate()
        .map(|(ti, &t)| {
            let texel = btf.texel(t);
            let hzr = &hz[ti * bins..(ti + 1) * bins];
            let mut a = vec![0.0f32; h];
            dec.latent_part(&z[t * k..(t + 1) * k], &mut a);
            let (mut pre, mut scratch) = (vec![0.0f32; h], vec![0.0f32; h]);
            let (mut sse, mut sgt) = (0.0f64, 0.0f64);
            for (pi, pair) in pairs.iter().enumerate() {
                let off = pair.off;
                pre.iter_mut().zip(&a).zip(&qb[pi * h..(pi + 1) * h]).for_each(|((x, a), b)| *x = a + b);
                for i in 0..ns {
                    let s = pair.clearance(i, hzr);
                    pre.iter_mut().zip(&ws[i * h..(i + 1) * h]).for_each(|(x, w)| *x += s * w);
                }
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
pub(crate) fn schedule(lr: f64, i: usize, n: usize) -> f32 {
    let warm = (n / 50).max(1);
    if i < warm {
        return (lr * (i + 1) as f64 / warm as f64) as f32;
    }
    let x = (i - warm) as f64 / (n - warm).max(1) as f64;
    (lr * (0.05 + 0.95 * 0.5 * (1.0 + (std::f64::consts::PI * x).cos()))) as f32
}

/// The texels of each step: the next `batch` of a shuffled order, reshuffled when spent.
pub(crate) struct Batches {
    order: Vec<usize>,
    cursor: usize,
    batch: usize,
}

impl Batches {
    /// Batches of `batch` of the texels below `t` (the first drawn after a shuffle).
    pub(crate) fn new(t: usize, batch: usize) -> Batches {
        Batches { order: (0..t).collect(), cursor: t, batch }
    }

    pub(crate) fn next(&mut self, rng: &mut Rng) -> Vec<usize> {
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

/// The texels' horizon rows as training reads them: rebuilt from the stored map for the texels
/// of each step (the whole map at 32 bins would be 128 bytes per texel).
pub(crate) struct Horizons<'a> {
    pub(crate) map: Option<&'a HorizonMap>,
    pub(crate) bins: usize,
}

impl Horizons<'_> {
    /// The rows of `texels`, `[texel][bin]` (empty without a map).
    pub(crate) fn rows(&self, texels: &[usize]) -> Vec<f32> {
        self.map.map_or_else(Vec::new, |m| m.rows(texels))
    }
}

/// The gradients of one step over `texels` (codes from `z`, `k` each; horizon rows from `hz`),
/// chunk by chunk in parallel and returned in chunk order; chunk `ci` gets seed
/// `mix(seed + ci)` for its pairs.
#[allow(clippy::type_complexity)]
fn batch_grads(
    texels: &[usize],
    (z, k): (&[f32], usize),
    hz: &Horizons<'_>,
    seed: u64,
    grad: impl Fn(&[usize], &[f32], &[f32], u64) -> ChunkGrad + Sync,
) -> Vec<ChunkGrad> {
    let zb: Vec<f32> = texels.iter().flat_map(|&ti| z[ti * k..(ti + 1) * k].iter().copied()).collect();
    let bins = hz.bins;
    let hb = hz.rows(texels);
    texels
        .par_chunks(CHUNK)
        .enumerate()
        .map(|(ci, tx)| {
            let zc = &zb[ci * CHUNK * k..ci * CHUNK * k + tx.len() * k];
            let hc = &hb[ci * CHUNK * bins..ci * CHUNK * bins + tx.len() * bins];
            grad(tx, zc, hc, mix(seed.wrapping_add(ci as u64)))
        })
        .collect()
}

/// What the float stage of training leaves for what follows: the quantization-aware end
/// ([`finish`]) and, for a fit on a sample of texels, the encoder of the others
/// ([`super::encoder`]).
pub(crate) struct Stage {
    /// The present pairs, training and validation.
    pub(crate) pairs: Pairs,
    /// The decoder, on the values divided by the report's `scale`.
    pub(crate) dec: Decoder,
    /// The float codes, `texels x latents`.
    pub(crate) z: Vec<f32>,
    /// What happened so far.
    pub(crate) report: TrainReport,
    /// The learning rate after any halvings.
    pub(crate) lr: f64,
    batches: Batches,
    rng: Rng,
    /// The texels the validation error is measured on, and their horizon rows.
    pub(crate) val_texels: Vec<usize>,
    pub(crate) val_hz: Vec<f32>,
    /// One over the values' root mean square.
    pub(crate) inv_scale: f32,
    /// The loss's divisor: the values of a step.
    pub(crate) norm: f32,
}

/// Train a neural model on the present pairs of `btf`, with the texels' horizon map when the
/// decoder reads clearances (the stored one: the rows it rebuilds); `monitor` counts steps.
pub fn train(btf: &BtfRef<'_>, s: &Setup, horizon: Option<&HorizonMap>, monitor: &Monitor) -> Result<Trained> {
    let st = train_float(btf, s, horizon, monitor, 0)?;
    let planes = Planes::quantize(&st.z, s.shape.latents)?;
    let zq = planes.dequantize();
    let (decoder, report) = finish(btf, s, st, horizon, &zq, monitor, Some(0))?;
    Ok(Trained { latents: planes, decoder, report })
}

/// Steps 1 to 3 of the module docs: the codes and the decoder in float, the best parameters by
/// validation kept. The monitor's total counts `extra` more steps (a sampled fit's encoder).
pub(crate) fn train_float(
    btf: &BtfRef<'_>,
    s: &Setup,
    horizon: Option<&HorizonMap>,
    monitor: &Monitor,
    extra: u64,
) -> Result<Stage> {
    let pairs = split_pairs(btf, s)?;
    let sh = s.shape;
    let (k, bins) = (sh.latents, sh.horizon);
    let t = btf.texels();
    let hz = Horizons { map: horizon, bins };
    monitor.start((s.steps + (s.steps / 10).max(1)) as u64 + 1 + extra);
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
    let mut batches = Batches::new(t, batch);
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
    let val_hz = hz.rows(&val_texels);
    let eval_every = (s.steps / 40).clamp(50, 500);
    let mut report = TrainReport { validation_pairs: pairs.val.len(), pca_components, scale, ..Default::default() };
    let mut best: Option<(f64, Vec<f32>, Vec<f32>)> = None;
    let mut since_best = 0;
    let mut lr = s.learning_rate;
    let norm = (batch * PAIRS * 3) as f32;
    let mut step = 0;
    // When validation stops improving, the rate falls linearly from where it is to zero over
    // a further fifth of the steps run (the "decay" of a warm-up, stable, decay schedule): a fit
    // stopped at its plateau with the cosine still near its peak leaves the parameters as noisy
    // as the steps were large, and measured 0.2-0.3 dB short of the same fit annealed.
    let mut cool: Option<(usize, usize, f32)> = None;
    while step < s.steps && cool.is_none_or(|(c0, len, _)| step < c0 + len) {
        monitor.check()?;
        let texels = batches.next(&mut rng);
        let seed = mix(s.seed ^ mix((step * 4096) as u64));
        let grads = batch_grads(&texels, (&z, k), &hz, seed, |tx, zc, hc, sd| {
            chunk_grad(btf, &pairs.train, &dec, tx, zc, hc, inv_scale, norm, sd, true)
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
        let rate = match cool {
            Some((c0, len, r0)) => r0 * (1.0 - (step - c0) as f32 / len as f32),
            None => schedule(lr, step, s.steps),
        };
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
            let err = val_error(btf, &pairs.val, &dec, &z, &val_hz, &val_texels, inv_scale);
            if best.as_ref().is_none_or(|(b, _, _)| err < *b) {
                best = Some((err, dec.params.clone(), z.clone()));
                report.best_step = step;
                since_best = 0;
            } else {
                since_best += 1;
                if since_best >= PATIENCE {
                    report.stopped_early = true;
                    if cool.is_some() {
                        break;
                    }
                    let len = (step / 5).max(2 * eval_every).min(s.steps - step.min(s.steps)).max(1);
                    cool = Some((step, len, schedule(lr, step, s.steps)));
                    report.cooldown_from = Some(step);
                    since_best = 0;
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
    Ok(Stage { pairs, dec, z, report, lr, batches, rng, val_texels, val_hz, inv_scale, norm })
}

/// Step 4 of the module docs: the decoder trained on the 8-bit codes `zq` (decoded, `texels x
/// latents` of `btf`) for a tenth of the float steps, and brought back to the data's scale.
/// `extra`: the monitor's total is set to the steps run plus these and `extra` (`None`: left
/// as the caller set it).
#[allow(clippy::too_many_arguments)]
pub(crate) fn finish(
    btf: &BtfRef<'_>,
    s: &Setup,
    st: Stage,
    horizon: Option<&HorizonMap>,
    zq: &[f32],
    monitor: &Monitor,
    extra: Option<u64>,
) -> Result<(Decoder, TrainReport)> {
    let Stage { pairs, mut dec, mut report, lr, mut batches, mut rng, val_texels, val_hz, inv_scale, norm, .. } = st;
    let sh = s.shape;
    let k = sh.latents;
    let hz = Horizons { map: horizon, bins: sh.horizon };
    let scale = report.scale;
    let step = report.steps;
    // Quantization-aware end: the decoder learns the decoded 8-bit latents, for a tenth of the
    // steps run (early stopping included; the progress total shrinks to match).
    let qat = (step / 10).max(1);
    if let Some(extra) = extra {
        monitor.set_total((step + qat) as u64 + 1 + extra);
    }
    let mut adam = Adam::new(dec.params.len());
    let qat_lr = (0.2 * lr).min(s.learning_rate);
    for i in 0..qat {
        monitor.check()?;
        let texels = batches.next(&mut rng);
        let seed = mix(s.seed ^ mix(((s.steps + i) * 4096) as u64));
        let grads = batch_grads(&texels, (zq, k), &hz, seed, |tx, zc, hc, sd| {
            chunk_grad(btf, &pairs.train, &dec, tx, zc, hc, inv_scale, norm, sd, false)
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
        report.validation_error_8bit = Some(val_error(btf, &pairs.val, &dec, zq, &val_hz, &val_texels, inv_scale));
    }
    // Back to the data's scale: the last layer times the scale.
    let o = sh.offsets();
    dec.params[o.w3..o.tables].iter_mut().for_each(|x| *x *= scale as f32);
    let decoder = Decoder::new(sh, dec.params, "decoder")?;
    Ok((decoder, report))
}
