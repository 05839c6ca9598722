//! A neural BTF: per texel a code of `latents` values (8-bit planes with a scale and bias per
//! plane), and one small decoder MLP per material mapping (code, view, light) to RGB: Rainer et
//! al. 2019 ("Neural BTF Compression and Interpolation", a per-material network continuous in the
//! directions), NeuMIP (Kuznetsov et al. 2021: latents per texel, no encoder) and NeuralRTI
//! (Dulecha et al. 2020: `(latents + 2) -> hidden -> hidden -> 3` with ELU for single-view
//! captures, whose web format `btfrs-io` writes).
//!
//! * [`decoder`]: the MLP, its direction encodings and activations.
//! * [`train`]: the auto-decoder training (PCA start, Adam, early stopping, quantization-aware end).
//! * [`encoder`]: training at camera scale, on a sample of texels, with an encoder for the rest.
//! * [`dense`]: the matrix products of a training step, crate and hand-written.
//!
//! Evaluation splits the first layer in two, as the training does: the latent columns times a
//! texel's code (cached per texel, `hidden` floats) plus the direction columns times the pair's
//! encoding (once per query); the rest is one `hidden x hidden` layer and the RGB output.
//!
//! The decoder's parameters are half-precision values ([`decoder::Decoder::new`] rounds them).
//! The renderer reads its dense layers as halves from the uniform block (`mp.constants`): every
//! fragment reads the same weights, which GPUs serve from their constant caches and software
//! rasterisers without per-lane bounds checks, and two halves to a word halve the reads.

pub mod decoder;
pub mod dense;
pub mod encoder;
pub mod train;

use crate::gpu::{GpuLayout, Shader};
use crate::model::{Mip, Model, ReflectanceModel, Sampling, Setting};
use crate::options::Spec;
use crate::planes::Planes;
use crate::relief::{self, HorizonMap};
use btfrs_core::{ensure_arg, BtfRef, Error, Monitor, NamedArrays, Result};
use decoder::{query_bias, Activation, Decoder, Directions, Shape};
use std::borrow::Cow;

/// The widest hidden layer (the shader's private arrays are this long).
pub const MAX_HIDDEN: usize = 64;
/// The most latents per texel.
pub const MAX_LATENTS: usize = 32;
/// The most channels per direction table.
pub const MAX_FEATURES: usize = 16;
/// The largest cache of the codes' first-layer parts a model keeps (bytes): 64 floats per texel
/// would be 6 GB at 24 megapixels, 24 times the codes themselves. Above it each evaluation
/// computes its texel's part (`latents x hidden` more multiplications, an eighth of the rest).
pub const CACHE_BYTES: usize = 256 << 20;

/// Vectors of four words the largest decoder's dense layers take as halves
/// ([`Decoder::gpu_dense`]): rows of `inputs` then `hidden` values padded to vectors of eight.
const GPU_CONSTANTS: usize = {
    let n8 = (MAX_LATENTS + decoder::MAX_ENCODING).div_ceil(8);
    let h8 = MAX_HIDDEN.div_ceil(8);
    MAX_HIDDEN * n8 + h8 + MAX_HIDDEN * h8 + h8 + 3 * h8 + 1
};

/// Fit options.
#[derive(Debug, Clone, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NeuralOptions {
    /// Latent channels per texel.
    pub latents: usize,
    /// Width of both hidden layers.
    pub hidden: usize,
    /// `"auto"`, `"light"`, `"xy"` or `"half"`.
    pub directions: String,
    /// `"auto"`, `"elu"` or `"relu"`.
    pub activation: String,
    /// Channels of each learned direction table (`None`: 0 for `"light"`, else 16).
    pub features: Option<usize>,
    /// Nodes per side of each direction table.
    pub grid: usize,
    /// Steps at most (`None`: from the texel count).
    pub steps: Option<usize>,
    /// Adam's peak learning rate.
    pub learning_rate: f64,
    /// Fraction of the present pairs kept out for early stopping.
    pub validation: f64,
    /// Components per texel of the horizon map (0: none; `None`: automatic).
    pub horizon: Option<usize>,
    /// Texels the decoder is trained on at most (`None`: [`TRAIN_TEXELS`]); a capture with more
    /// trains on a sample of that many and encodes the rest ([`encoder`]).
    pub train_texels: Option<usize>,
    /// Seed of every random choice.
    pub seed: u64,
}

impl Default for NeuralOptions {
    /// The defaults of [`Neural`]'s option schema.
    fn default() -> Self {
        crate::options::defaults(<Neural as Model>::OPTIONS)
    }
}

/// Visits per texel of the automatic step count.
const VISITS: usize = 500;
/// Texels the decoder is trained on at most by default: a capture with more (a camera's
/// megapixels) trains on a sample of this many texels ([`encoder`]). At 60 lights the sample
/// is 190 MB of values.
pub const TRAIN_TEXELS: usize = 262_144;
/// The most bytes of values a sample holds (a BTF's texels are thousands of values each).
const SAMPLE_BYTES: usize = 1 << 30;
/// Components per texel of the horizon map by default.
pub const HORIZON_COMPONENTS: usize = 8;

impl NeuralOptions {
    /// The checked training setup for `btf`.
    fn setup(&self, btf: &BtfRef<'_>) -> Result<train::Setup> {
        ensure_arg!(
            self.learning_rate.is_finite() && self.learning_rate > 0.0 && self.learning_rate <= 0.1,
            "learning_rate",
            "expected a learning rate in (0, 0.1], got {}",
            self.learning_rate
        );
        ensure_arg!(
            self.validation.is_finite() && (0.0..=0.5).contains(&self.validation),
            "validation",
            "expected a fraction in [0, 0.5], got {}",
            self.validation
        );
        let one_view = btf.views.len() == 1;
        let directions = match self.directions.as_str() {
            "auto" if one_view => Directions::Light,
            "auto" | "half" => Directions::Half,
            "light" => Directions::Light,
            "xy" => Directions::Xy,
            other => return Err(Error::arg("directions", format!("unknown encoding {other:?}"))),
        };
        if directions == Directions::Light && !one_view {
            let views = btf.views.len();
            let distinct = btf.views.iter().any(|v| btf.views.iter().any(|w| v != w));
            ensure_arg!(
                !distinct,
                "directions",
                "expected \"auto\", \"xy\" or \"half\" for a BTF of {views} views: \"light\" ignores the view"
            );
        }
        let activation = match self.activation.as_str() {
            "auto" if directions == Directions::Light => Activation::Elu,
            "auto" | "relu" => Activation::Relu,
            "elu" => Activation::Elu,
            other => return Err(Error::arg("activation", format!("unknown activation {other:?}"))),
        };
        ensure_arg!(
            self.hidden.is_multiple_of(4),
            "hidden",
            "expected a multiple of 4 (the shader computes four units at a time), got {}",
            self.hidden
        );
        let texels = btf.texels();
        let steps = self.steps.unwrap_or((VISITS * texels / train::BATCH_TEXELS).clamp(1000, 100_000));
        let features = self.features.unwrap_or(if directions == Directions::Light { 0 } else { 16 });
        let components = self.horizon.unwrap_or(HORIZON_COMPONENTS);
        Ok(train::Setup {
            shape: Shape {
                latents: self.latents,
                directions,
                features,
                grid: self.grid,
                hidden: self.hidden,
                activation,
                horizon: if components > 0 { relief::BINS } else { 0 },
            },
            steps,
            learning_rate: self.learning_rate,
            validation: self.validation,
            seed: self.seed,
        })
    }
}

/// A fitted neural model.
#[derive(Debug, Clone)]
pub struct Neural {
    height: usize,
    width: usize,
    latents: Planes,
    /// The texels' horizon map (a decoder with clearance inputs reads it).
    horizon: Option<HorizonMap>,
    decoder: Decoder,
    report: serde_json::Value,
    /// Per texel, the latent columns of layer 1 times its decoded code (`texels x hidden`), when
    /// that fits in [`CACHE_BYTES`]; else each evaluation computes its texel's part.
    cache: Option<Vec<f32>>,
    /// Layer 2's weights transposed.
    w2t: Vec<f32>,
    /// Layer 1's clearance columns, `[clearance][hidden]`.
    clear: Vec<f32>,
}

impl PartialEq for Neural {
    fn eq(&self, o: &Self) -> bool {
        (self.height, self.width) == (o.height, o.width)
            && self.latents == o.latents
            && self.horizon == o.horizon
            && self.decoder == o.decoder
    }
}

impl Neural {
    /// Assemble and check: the codes' and the horizon map's texel counts, and a horizon map
    /// exactly when the decoder reads one.
    pub fn new(
        height: usize,
        width: usize,
        latents: Planes,
        horizon: Option<HorizonMap>,
        decoder: Decoder,
        report: serde_json::Value,
    ) -> Result<Self> {
        let sh = decoder.shape;
        match &horizon {
            Some(m) => ensure_arg!(
                m.coeffs.texels == height * width && m.bins == sh.horizon,
                "horizon_q",
                "expected a horizon map of {height} x {width} texels and {} azimuth bins, got {} texels and {} bins",
                sh.horizon,
                m.coeffs.texels,
                m.bins
            ),
            None => ensure_arg!(sh.horizon == 0, "horizon_q", "the decoder reads a horizon map and none is given"),
        }
        ensure_arg!(
            latents.texels == height * width && latents.k == sh.latents,
            "latents_q",
            "expected {height} x {width} x {} latent bytes, got {} x {}",
            sh.latents,
            latents.texels,
            latents.k
        );
        let h = sh.hidden;
        let cache = (latents.texels * h * 4 <= CACHE_BYTES).then(|| {
            let mut cache = vec![0.0f32; latents.texels * h];
            let z = latents.dequantize();
            use rayon::prelude::*;
            cache.par_chunks_mut(h).zip(z.par_chunks(sh.latents)).for_each(|(c, z)| decoder.latent_part(z, c));
            cache
        });
        let w2t = decoder.w2t();
        let clear = decoder.clearance_columns();
        Ok(Neural { height, width, latents, horizon, decoder, report, cache, w2t, clear })
    }

    /// The model without its first-layer cache, as one above [`CACHE_BYTES`] is built.
    #[cfg(test)]
    pub(crate) fn without_cache(mut self) -> Self {
        self.cache = None;
        self
    }

    /// The decoder.
    pub fn decoder(&self) -> &Decoder {
        &self.decoder
    }

    /// The 8-bit latent planes (`texels x latents`, texel-major).
    pub fn latents(&self) -> &Planes {
        &self.latents
    }

    /// The texels' horizon map, if the decoder reads one.
    pub fn horizon(&self) -> Option<&HorizonMap> {
        self.horizon.as_ref()
    }

    /// (height, width) in texels.
    pub fn size(&self) -> (usize, usize) {
        (self.height, self.width)
    }
}

/// Present lights a view slot needs for its relief: photometric stereo's minimum is 3, and a
/// height from so few is mostly noise.
const RELIEF_MIN_LIGHTS: usize = 6;

/// The view slot a sample's relief is measured in: the one seen most nearly from above among
/// those with at least [`RELIEF_MIN_LIGHTS`] present lights (a sample trained on grazing pairs
/// only may have none in its frontal slots); `None` if no slot has that many.
fn relief_view(btf: &BtfRef<'_>) -> Option<usize> {
    let nl = btf.lights.len();
    let present = |v: usize| (0..nl).filter(|&l| btf.mask.is_none_or(|m| m[v * nl + l])).count();
    (0..btf.views.len())
        .filter(|&v| present(v) >= RELIEF_MIN_LIGHTS)
        .max_by(|&a, &b| btf.views[a][2].total_cmp(&btf.views[b][2]))
}

/// The horizon map of `btf` and the report's entries about it; `Ok(None)` with the reason when
/// the default (no `horizon` given) meets a sample whose relief cannot be measured, so that the
/// model fits without clearance inputs instead of failing. A `horizon` asked for explicitly
/// gets the error.
fn relief_of(
    btf: &BtfRef<'_>,
    o: &NeuralOptions,
    monitor: &Monitor,
    extra: &mut serde_json::Map<String, serde_json::Value>,
) -> Result<Option<HorizonMap>> {
    relief_in_blocks(btf, o, monitor, extra, relief::coarse_factor(btf.height, btf.width))
}

/// [`relief_of`] measured on blocks of `factor x factor` texels (1: the texels themselves).
fn relief_in_blocks(
    btf: &BtfRef<'_>,
    o: &NeuralOptions,
    monitor: &Monitor,
    extra: &mut serde_json::Map<String, serde_json::Value>,
    factor: usize,
) -> Result<Option<HorizonMap>> {
    // A camera-sized capture's relief is measured on blocks of texels (relief::HORIZON_TEXELS):
    // their values averaged (grey) in the relief's view slot, then photometric stereo, the
    // integration, the scale and the horizons on the block grid, each texel taking its block's.
    let blocks = match relief_view(btf) {
        Some(view) if factor > 1 => Some(relief::blocks_of(btf, view, factor, monitor)?),
        _ => None,
    };
    let measured_on = match &blocks {
        Some(b) => Some(BtfRef::new(b.rows, b.cols, &b.views, btf.lights, &b.data, b.mask.as_deref())?),
        None => None,
    };
    let on = measured_on.as_ref().unwrap_or(btf);
    let measured = (if blocks.is_some() { Some(0) } else { relief_view(btf) })
        .ok_or_else(|| {
            Error::Degenerate(format!(
                "no view slot has the {RELIEF_MIN_LIGHTS} present lights the horizon map's photometric stereo needs"
            ))
        })
        .and_then(|view| relief::height_map(on, view, monitor).map(|h| (view, h)));
    let (view, (height, normals, albedo)) = match measured {
        Ok(m) => m,
        Err(Error::Degenerate(why)) if o.horizon.is_none() => {
            extra.insert("horizon_skipped".into(), why.into());
            return Ok(None);
        }
        Err(e) => return Err(e),
    };
    let (scale, score) = relief::choose_scale(on, view, &height, 1, &normals, &albedo);
    // The block averages and the per-texel maps are not needed past here.
    drop((normals, albedo, blocks));
    let components = o.horizon.unwrap_or(HORIZON_COMPONENTS);
    let mut map = HorizonMap::build_coarse(&height, factor, scale, components, monitor)?;
    if factor > 1 {
        map = map.expand(factor, btf.height, btf.width);
        extra.insert("horizon_block".into(), factor.into());
    }
    extra.insert("horizon_scale".into(), scale.into());
    extra.insert("horizon_agreement".into(), score.into());
    Ok(Some(map))
}

/// The texels a fit of `btf` trains its decoder on: `None` for all of them, else a sample's
/// size. A capture of more than `train_texels` texels (default [`TRAIN_TEXELS`]) trains on a
/// sample: the auto-decoder's steps grow with the texels and each reads random ones, which from
/// a memory-mapped file larger than the memory is a disk seek each. The sample holds at most
/// [`SAMPLE_BYTES`] of values, and a quarter of the memory limit.
fn sample_size(btf: &BtfRef<'_>, o: &NeuralOptions, monitor: &Monitor) -> Option<usize> {
    let t = btf.texels();
    let cap = o.train_texels.unwrap_or(TRAIN_TEXELS);
    if t <= cap {
        return None;
    }
    let texel_bytes = (btf.abrdf_len() * 4).max(1);
    let budget = monitor.memory_limit().map_or(SAMPLE_BYTES, |limit| SAMPLE_BYTES.min(limit as usize / 4));
    Some(cap.min(budget / texel_bytes).max(encoder::RUN))
}

/// Fit a neural model to the present pairs of `btf`; `monitor` counts training steps.
pub fn fit_neural(btf: &BtfRef<'_>, o: &NeuralOptions, monitor: &Monitor) -> Result<Neural> {
    fit_neural_screened(btf, o, None, monitor)
}

/// [`fit_neural`] with the robust value `screen`: the texels trained on (all of them, or the
/// sample) are read through it, and so are those encoded.
pub fn fit_neural_screened(
    btf: &BtfRef<'_>,
    o: &NeuralOptions,
    screen: Option<&crate::robust::TexelScreen<'_>>,
    monitor: &Monitor,
) -> Result<Neural> {
    let mut s = o.setup(btf)?;
    let mut extra = serde_json::Map::new();
    let horizon = if s.shape.horizon > 0 { relief_of(btf, o, monitor, &mut extra)? } else { None };
    if horizon.is_none() {
        s.shape.horizon = 0;
    }
    let (latents, decoder, mut report) = match sample_size(btf, o, monitor) {
        None => {
            let repaired = screen.and_then(|ts| repaired_copy(btf, ts));
            let data = repaired.as_deref().unwrap_or(btf.data);
            let b = BtfRef::new(btf.height, btf.width, btf.views, btf.lights, data, btf.mask)?;
            let t = train::train(&b, &s, horizon.as_ref(), monitor)?;
            (t.latents, t.decoder, serde_json::to_value(&t.report).unwrap_or(serde_json::Value::Null))
        }
        Some(n) => fit_sampled(btf, &s, horizon.as_ref(), screen, n, monitor)?,
    };
    if let serde_json::Value::Object(m) = &mut report {
        m.insert("directions".into(), s.shape.directions.name().into());
        m.insert("activation".into(), s.shape.activation.name().into());
        m.insert("max_steps".into(), s.steps.into());
        m.insert("horizon".into(), horizon.as_ref().map_or(0, |h| h.components()).into());
        m.extend(extra);
    }
    Neural::new(btf.height, btf.width, latents, horizon, decoder, report)
}

/// The values of `btf` with the values `screen` flags replaced, `None` when none is flagged (the
/// fit then reads the values in place): what the robust fit of a model screened before its fit
/// trains on ([`crate::driver::fit`]).
fn repaired_copy(btf: &BtfRef<'_>, screen: &crate::robust::TexelScreen<'_>) -> Option<Vec<f32>> {
    use rayon::prelude::*;
    let fixes: Vec<(usize, Vec<f32>)> =
        (0..btf.texels()).into_par_iter().filter_map(|t| screen.repaired(t, btf.texel(t)).map(|f| (t, f))).collect();
    if fixes.is_empty() {
        return None;
    }
    let n = btf.abrdf_len();
    let mut d = btf.data.to_vec();
    for (t, fixed) in fixes {
        d[t * n..(t + 1) * n].copy_from_slice(&fixed);
    }
    Some(d)
}

/// Steps of an encoder's training (half regression, half reconstruction) for a fit of `steps`.
fn encoder_steps(steps: usize) -> usize {
    (steps / 4).clamp(200, 10_000)
}

/// A fit on a sample of `n` texels ([`encoder`]): the decoder trained on the sample, an encoder
/// trained on it with the decoder fixed, every texel encoded, the decoder's quantization-aware
/// end on the sample's 8-bit codes. Returns the codes, the decoder and the report.
fn fit_sampled(
    btf: &BtfRef<'_>,
    s: &train::Setup,
    horizon: Option<&HorizonMap>,
    screen: Option<&crate::robust::TexelScreen<'_>>,
    n: usize,
    monitor: &Monitor,
) -> Result<(Planes, Decoder, serde_json::Value)> {
    use rayon::prelude::*;
    let sample = encoder::sample_texels(btf.texels(), n, s.seed);
    let len = btf.abrdf_len();
    let mut data = vec![0.0f32; sample.len() * len];
    data.par_chunks_mut(len).zip(sample.par_iter()).for_each(|(row, &t)| {
        let values = btf.texel(t);
        match screen.and_then(|ts| ts.repaired(t, values)) {
            Some(fixed) => row.copy_from_slice(&fixed),
            None => row.copy_from_slice(values),
        }
    });
    monitor.check()?;
    let sub = horizon.map(|h| h.select(&sample));
    let sb = BtfRef::new(1, sample.len(), btf.views, btf.lights, &data, btf.mask)?;
    let esteps = encoder_steps(s.steps);
    let st = train::train_float(&sb, s, sub.as_ref(), monitor, esteps as u64)?;
    let hz = train::Horizons { map: sub.as_ref(), bins: s.shape.horizon };
    let (enc, ereport) = encoder::train_encoder(&sb, &st, &hz, esteps, s.seed, monitor)?;
    let bands = btf.texels().div_ceil(1 << 16);
    let qat = (st.report.steps / 10).max(1);
    monitor.start((bands + qat) as u64);
    let z = enc.encode(btf, screen, monitor)?;
    let planes = Planes::quantize(&z, s.shape.latents)?;
    drop(z);
    let zq = planes.select(&sample).dequantize();
    let (decoder, report) = train::finish(&sb, s, st, sub.as_ref(), &zq, monitor, None)?;
    let mut report = serde_json::to_value(&report).unwrap_or(serde_json::Value::Null);
    if let serde_json::Value::Object(m) = &mut report {
        m.insert("sample_texels".into(), sample.len().into());
        m.insert("encoder".into(), serde_json::to_value(&ereport).unwrap_or(serde_json::Value::Null));
    }
    Ok((planes, decoder, report))
}

/// A prepared (view, light) pair: the direction part of layer 1, the output gain, and where
/// the clearance directions fall among the horizon bins.
#[derive(Debug, Clone, Copy)]
pub struct NeuralQuery {
    bias: [f32; MAX_HIDDEN],
    gain: f32,
    look: [(usize, usize, f32, f32); 2],
}

impl ReflectanceModel for Neural {
    type Query = NeuralQuery;

    fn dims(&self) -> (usize, usize) {
        (self.height, self.width)
    }

    fn query(&self, view: [f64; 3], light: [f64; 3]) -> NeuralQuery {
        let mut bias = [0.0f32; MAX_HIDDEN];
        let sh = &self.decoder.shape;
        query_bias(sh, &self.decoder.params, view, light, &mut bias);
        let mut look = [(0, 0, 0.0, 0.0); 2];
        if sh.horizon > 0 {
            for (o, d) in look.iter_mut().zip(sh.clearance_directions(view, light)) {
                *o = relief::lookup(d, sh.horizon);
            }
        }
        NeuralQuery { bias, gain: sh.directions.gain(light), look }
    }

    #[inline]
    fn eval(&self, t: usize, q: &NeuralQuery) -> [f32; 3] {
        let h = self.decoder.shape.hidden;
        let mut pre = [0.0f32; MAX_HIDDEN];
        let mut scratch = [0.0f32; MAX_HIDDEN];
        match &self.cache {
            Some(cache) => {
                for ((p, a), b) in pre[..h].iter_mut().zip(&cache[t * h..(t + 1) * h]).zip(&q.bias[..h]) {
                    *p = a + b;
                }
            }
            None => {
                let k = self.latents.k;
                let mut z = [0.0f32; MAX_LATENTS];
                z[..k].iter_mut().enumerate().for_each(|(p, x)| *x = self.latents.get(t, p));
                self.decoder.latent_part(&z[..k], &mut pre[..h]);
                pre[..h].iter_mut().zip(&q.bias[..h]).for_each(|(p, b)| *p += b);
            }
        }
        if let Some(map) = &self.horizon {
            for (i, col) in self.clear.chunks_exact(h).enumerate() {
                let s = map.clearance(t, q.look[i]);
                pre[..h].iter_mut().zip(col).for_each(|(p, w)| *p += s * w);
            }
        }
        self.decoder.finish(&mut pre[..h], &self.w2t, &mut scratch).map(|x| x * q.gain)
    }
}

crate::gpu_params! {
    /// Parameters of `neural.wgsl`.
    pub struct NeuralParams {
        /// Latents per texel.
        pub latents: u32,
        /// Width of both hidden layers.
        pub hidden: u32,
        /// The direction encoding (0 light, 1 xy, 2 half).
        pub directions: u32,
        /// The activation (0 ELU, 1 ReLU).
        pub activation: u32,
        /// Store offset of the latent bytes, `[texel][latent]`, four to a word.
        pub q: u32,
        /// Store offset of the latents' scales then biases (`2 latents` f32).
        pub scale: u32,
        /// Store offset of the direction tables (`[table][grid * grid][features]` as halves,
        /// two to a word, each node's features padded to an even count).
        pub tables: u32,
        /// Channels of each direction table (0: none).
        pub features: u32,
        /// Nodes per side of each direction table.
        pub grid: u32,
        /// The power of two the output layer's halves are scaled by.
        pub out_scale: f32,
        /// Azimuth bins of the horizon map (0: none).
        pub hbins: u32,
        /// Its components per texel.
        pub hcomp: u32,
        /// Store offset of its mean row then components (`(1 + hcomp) hbins` f32).
        pub hbasis: u32,
        /// Store offset of its coordinates' scales then biases (`2 hcomp` f32).
        pub hscale: u32,
        /// Store offset of its coordinate bytes, `[texel][component]`, four to a word.
        pub hq: u32,
    }
    constants = GPU_CONSTANTS;
}

impl GpuLayout for Neural {
    type Params = NeuralParams;
    const SHADER: Shader = Shader::new::<NeuralParams>("neural", include_str!("../../../shaders_wgsl/neural.wgsl"));

    fn parts(&self) -> Vec<Cow<'_, [u32]>> {
        // The direction tables first: at the start of the store they lie in the first storage
        // binding, which the shader reads directly (no chunk lookup per feature).
        let mut parts = vec![
            Cow::Owned(self.decoder.gpu_tables()),
            Cow::Owned(self.latents.scale_bias_words()),
            Cow::Owned(self.latents.words()),
        ];
        if let Some(m) = &self.horizon {
            parts.push(Cow::Owned(m.mean.iter().chain(&m.basis).map(|x| x.to_bits()).collect()));
            parts.push(Cow::Owned(m.coeffs.scale_bias_words()));
            parts.push(Cow::Owned(m.coeffs.words()));
        }
        parts
    }

    fn constants(&self) -> Vec<u32> {
        self.decoder.gpu_dense()
    }

    fn params(&self, offsets: &[u32], _tables: &[u32]) -> NeuralParams {
        let sh = self.decoder.shape;
        NeuralParams {
            latents: sh.latents as u32,
            hidden: sh.hidden as u32,
            directions: sh.directions.code() as u32,
            activation: sh.activation.code() as u32,
            q: offsets[2],
            scale: offsets[1],
            tables: offsets[0],
            features: sh.features as u32,
            grid: sh.grid as u32,
            out_scale: self.decoder.output_scale(),
            hbins: self.horizon.as_ref().map_or(0, |m| m.bins as u32),
            hcomp: self.horizon.as_ref().map_or(0, |m| m.components() as u32),
            hbasis: offsets.get(3).copied().unwrap_or(0),
            hscale: offsets.get(4).copied().unwrap_or(0),
            hq: offsets.get(5).copied().unwrap_or(0),
        }
    }
}

impl Model for Neural {
    const KIND: &'static str = "neural";
    const DOC: &'static str =
        "per-texel 8-bit latent codes and one small decoder MLP per material (Rainer 2019, NeuMIP 2021, NeuralRTI 2020)";
    const ABOUT: &'static str = "\
A neural BTF. Every texel holds a code of `latents` values, stored as 8-bit planes with a scale and
a bias per plane; one decoder per material, a multilayer perceptron with two hidden layers of
`hidden` units, maps the code and the (view, light) pair to RGB. The pair enters as the (x, y) of
the view and light and of their half vector (`directions = \"half\"`), or, for a capture with one
view, as the light's (x, y) alone: NeuralRTI's exact form `(latents + 2) -> hidden -> hidden -> 3`
with ELU, which `model.export(\"neuralrti\", ...)` writes in the web format OpenLIME reads.

It is trained on the CPU as an auto-decoder (no encoder): the codes start as the texels'
principal coordinates (randomized PCA), then codes and weights are optimized together by Adam
on minibatches of random texels, each under random present pairs. A fraction `validation` of the
present pairs is kept out; training stops when the error on them stops falling, and keeps the
best step. The last tenth of the steps trains the decoder on the 8-bit codes, so the stored model
is the trained one. `model.report` gives the steps, the validation errors (float and 8-bit codes)
and whether training stopped early. A capture of more than `train_texels` texels (a camera's
megapixels) trains on a sample of them spread over the frame, then gives every texel its code with
an encoder trained on the sample (NeuralRTI's), in one pass over the capture. Filtered lookups
average the codes (`mip = \"latent\"`).";
    const OPTIONS: &'static [Spec] = &[
        Spec::int("latents", 8, 1, Some(MAX_LATENTS as i64), "latent channels per texel (8-bit planes)"),
        Spec::int("hidden", 64, 4, Some(MAX_HIDDEN as i64), "units of each of the decoder's two hidden layers, a multiple of 4"),
        Spec::choice(
            "directions",
            "auto",
            &["auto", "light", "xy", "half"],
            "direction encoding: \"half\" (view, light and half vector x, y), \"xy\", \"light\" (the light only: NeuralRTI, one view); \"auto\": \"light\" for one view, else \"half\"",
        ),
        Spec::choice(
            "activation",
            "auto",
            &["auto", "elu", "relu"],
            "activation of the hidden layers; \"auto\": ELU for \"light\" (NeuralRTI's), else ReLU (as accurate, twice as fast to train)",
        ),
        Spec::opt_int(
            "features",
            0,
            Some(MAX_FEATURES as i64),
            "channels of each learned direction table (view, light, half vector) fed to the decoder (null: 0 for \"light\", NeuralRTI's form; else 16)",
        ),
        Spec::int("grid", 8, 2, Some(32), "nodes per side of each direction table, over the concentric square"),
        Spec::opt_int(
            "steps",
            1,
            Some(1_000_000),
            "training steps at most, of 256 texels x 16 pairs each (null: 500 visits per texel, 1000 to 100000)",
        ),
        Spec::positive("learning_rate", 0.005, "Adam's peak learning rate, at most 0.1 (cosine schedule)"),
        Spec::float("validation", 0.05, 0.0, "fraction of the present pairs kept out for early stopping, at most 0.5"),
        Spec::opt_int(
            "horizon",
            0,
            Some(relief::BINS as i64),
            "components per texel of the horizon map, whose clearances the decoder reads to place cast shadows (0: none, NeuralRTI's form; null: 8)",
        ),
        Spec::opt_int(
            "train_texels",
            1,
            None,
            "texels the decoder is trained on at most; a capture with more trains on a sample of that many spread over the frame and gives the others their codes with an encoder (null: 262144)",
        ),
        Spec::seed("seed of the PCA start, the initial weights, the minibatches, the validation pairs and the sample"),
    ];
    const EXAMPLES: &'static [(&'static str, &'static str)] =
        &[("Neural-8", r#"{"latents": 8}"#), ("Neural-16", r#"{"latents": 16}"#)];
    const SWEEP: &'static [Setting] = &[
        Setting::full("Neural-4", r#"{"latents": 4, "hidden": 32, "features": 8}"#),
        Setting::quick("Neural-8", r#"{"latents": 8}"#),
        Setting::full("Neural-16", r#"{"latents": 16}"#),
    ];
    const SAMPLING: Sampling = Sampling::Any {
        note: "any sampling: trained on random present pairs, a few hundred per texel",
        one_view: "one view: NeuralRTI's form, the light's (x, y) only",
    };
    const EXPORTS: &'static [&'static str] = &["neuralrti"];
    const TEXEL_ARRAYS: &'static [&'static str] = &["latents_q", "horizon_q"];
    const STOCHASTIC: bool = true;
    // NeuralRTI's decoder (OpenLIME) has no input for the horizon map's clearances.
    const EXPORT_OPTIONS: &'static str = r#"{"horizon": 0}"#;
    const SMALLEST: &'static str = r#"{"latents": 4, "hidden": 16, "steps": 300}"#;
    const BENCH: &'static [crate::model::Bench] = &[crate::model::Bench::new("Neural-8", "{}", &["against_all"])];
    // Averaged latents were measured against supersampling (a plane at 40 repeats, bumps 16^2):
    // RMSE 0.086 against nearest lookups' 0.069, worse (the decoder is not linear in its codes);
    // appearance medoids keep every level a real texel's appearance.
    const MIP: Mip = Mip::Medoid;
    const BLOCKWISE: crate::blockwise::Blockwise = crate::blockwise::Blockwise::Unsupported(
        "its decoder is shared by every texel and trained on all of them at once",
    );
    type Options = NeuralOptions;

    fn fit(btf: &BtfRef<'_>, options: &NeuralOptions, monitor: &Monitor) -> Result<Self> {
        fit_neural(btf, options, monitor)
    }

    // The texels trained on are read through the screen, once (a repaired copy of all of them,
    // or of the sample), and so is every texel the encoder of a sampled fit reads.
    const SCREENS_TEXELS: bool = true;

    fn fit_screened(
        btf: &BtfRef<'_>,
        options: &NeuralOptions,
        screen: &crate::robust::TexelScreen<'_>,
        monitor: &Monitor,
    ) -> Result<Self> {
        fit_neural_screened(btf, options, Some(screen), monitor)
    }

    /// The latents with Adam's moments, the PCA start's smallest sample, the relief (height,
    /// normals, albedo and the horizon map's coordinates), and scratch.
    /// A fit on a sample holds the sample's values and its codes' Adam moments, and every
    /// texel's float code and byte code instead.
    fn least_memory(btf: &BtfRef<'_>, options: &NeuralOptions) -> u64 {
        let t = btf.texels() as u64;
        let k = options.latents as u64;
        // The relief's maps per texel, or per block with the blocks' values (relief::blocks_of).
        let f = relief::coarse_factor(btf.height, btf.width) as u64;
        let per_block = 72 + 12 * btf.lights.len() as u64;
        let relief = match options.horizon.unwrap_or(HORIZON_COMPONENTS) {
            0 => 0,
            _ if f > 1 => t.div_ceil(f * f) * per_block,
            _ => t * 72,
        };
        let cap = options.train_texels.unwrap_or(TRAIN_TEXELS) as u64;
        if t > cap {
            let n = cap.min((SAMPLE_BYTES / (btf.abrdf_len() * 4).max(1)) as u64);
            return n * (btf.abrdf_len() as u64 * 4 + k * 16 + 12 * k.div_ceil(3)) + t * k * 5 + relief + 16_000_000;
        }
        t * k * 16 + t * 12 * k.div_ceil(3) + relief + 16_000_000
    }

    fn to_arrays(&self) -> NamedArrays {
        let sh = self.decoder.shape;
        let mut a = NamedArrays::new();
        self.latents.insert_into(&mut a, "latents_", vec![self.height, self.width, sh.latents]);
        if let Some(m) = &self.horizon {
            m.insert_into(&mut a, "horizon_", vec![self.height, self.width, m.components()]);
        }
        a.put(
            "architecture",
            &[7],
            vec![
                sh.latents as i32,
                sh.hidden as i32,
                sh.directions.code(),
                sh.activation.code(),
                sh.features as i32,
                sh.grid as i32,
                self.horizon.as_ref().map_or(0, |m| m.components() as i32),
            ],
        );
        a.put("decoder", &[self.decoder.params.len()], self.decoder.params.clone());
        a
    }

    fn from_arrays(a: &NamedArrays) -> Result<Self> {
        // Files written before horizon maps hold six values (no map).
        let (arch, ashape) = a.get::<i32>("architecture", &[None])?;
        let bad = |msg: String| Error::format("architecture", msg);
        if !(ashape[0] == 6 || ashape[0] == 7) {
            return Err(bad(format!("expected 6 or 7 values, got {}", ashape[0])));
        }
        let components = if ashape[0] == 7 { arch[6] } else { 0 };
        if !(0..=relief::BINS as i32).contains(&components) {
            return Err(bad(format!("expected 0 to {} horizon components, got {components}", relief::BINS)));
        }
        let latents = arch[0];
        let hidden = arch[1];
        if !(1..=MAX_LATENTS as i32).contains(&latents) {
            return Err(bad(format!("expected 1 to {MAX_LATENTS} latents, got {latents}")));
        }
        if !(4..=MAX_HIDDEN as i32).contains(&hidden) || hidden % 4 != 0 {
            return Err(bad(format!("expected a multiple of 4 from 4 to {MAX_HIDDEN} hidden units, got {hidden}")));
        }
        let directions =
            Directions::from_code(arch[2]).ok_or_else(|| bad(format!("unknown direction encoding {}", arch[2])))?;
        let activation =
            Activation::from_code(arch[3]).ok_or_else(|| bad(format!("unknown activation {}", arch[3])))?;
        let (features, grid) = (arch[4], arch[5]);
        if !(0..=MAX_FEATURES as i32).contains(&features) {
            return Err(bad(format!("expected 0 to {MAX_FEATURES} table features, got {features}")));
        }
        if !(2..=32).contains(&grid) {
            return Err(bad(format!("expected 2 to 32 table nodes per side, got {grid}")));
        }
        let shape = Shape {
            latents: latents as usize,
            directions,
            features: features as usize,
            grid: grid as usize,
            hidden: hidden as usize,
            activation,
            horizon: 0,
        };
        let (_, qshape) = a.get::<u8>("latents_q", &[None, None, Some(shape.latents)])?;
        let (height, width) = (qshape[0], qshape[1]);
        if height == 0 || width == 0 {
            return Err(Error::format("latents_q", format!("expected at least one texel, got {height} x {width}")));
        }
        let planes = Planes::from_arrays(a, "latents_", height * width, shape.latents)?;
        let horizon = match components {
            0 => None,
            m => Some(HorizonMap::from_arrays(a, "horizon_", height * width, m as usize)?),
        };
        let shape = Shape { horizon: horizon.as_ref().map_or(0, |m| m.bins), ..shape };
        let (params, _) = a.get::<f32>("decoder", &[None])?;
        let decoder = Decoder::new(shape, params.to_vec(), "decoder")?;
        Neural::new(height, width, planes, horizon, decoder, serde_json::Value::Null)
    }

    fn report(&self) -> serde_json::Value {
        self.report.clone()
    }

    fn unpacked(&self) -> NamedArrays {
        self.decoder.unpacked()
    }
}

#[cfg(test)]
mod tests;
