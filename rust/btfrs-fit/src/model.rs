//! The contract every fitted model meets, written once per model.
//!
//! * [`ReflectanceModel`] (in [`crate::eval`], which the GPU half shares): evaluation. A model
//!   answers *queries*: one (view, light) pair, prepared once (`query`), then evaluated at every
//!   texel (`eval`). The CPU reference renderer shades through it ([`Shade`]).
//! * [`Model`]: everything else a model is: its name, its fit options and fit, its named arrays
//!   for saving ([`btfrs_core::NamedArrays`]), its fit report, the bytes it occupies as stored
//!   for rendering, and its renderers. Together with [`crate::gpu::GpuLayout`] (the shader and
//!   its parameter struct) that is the whole contract; [`crate::registry`] lists the models, and
//!   everything that iterates over models (bindings, `btfrs.load`, renderer, demo, bench) goes
//!   through [`DynModel`], the object-safe form.

pub use crate::eval::{ReflectanceModel, Shade};
use crate::gpu::{GpuLayout, GpuModel, Renderable};
use btfrs_core::{metrics::ErrorSums, BtfRef, Error, Monitor, NamedArrays, Result};
use rayon::prelude::*;
use serde::de::DeserializeOwned;
use std::any::Any;

/// A fitted model: the contract a new model implements once (see CONTRIBUTING.md).
pub trait Model: ReflectanceModel + GpuLayout + Send + Sized + 'static {
    /// The model's name (`"ptm"`, `"lpca"`, ...): the container's `kind`, the Python name.
    const KIND: &'static str;
    /// One line saying what it is and which paper section it follows.
    const DOC: &'static str;
    /// Renderer names; the first is the default. A model with several renderers (LPCA: the 9-tap
    /// lookup and the 3D texture) overrides [`Model::renderer`].
    const RENDERERS: &'static [&'static str] = &["default"];
    /// What the model is and how it is fitted, in a few paragraphs (Markdown): the docstring of
    /// `btfrs.fit.<kind>` and the top of its docs page.
    const ABOUT: &'static str;
    /// The fit's options ([`crate::options`]): names, types, defaults, allowed values, docs.
    /// `Options` is built from them; nothing else states a default.
    const OPTIONS: &'static [crate::options::Spec];
    /// Example option sets `(label, JSON)` from small to large: what the demo and the bench fit.
    const EXAMPLES: &'static [(&'static str, &'static str)];
    /// The cheapest option set (a JSON object) that still runs every stage of the fit: what the
    /// tests fit where the data are large (the out-of-core checks); `""`: the first of
    /// [`Model::EXAMPLES`]. A model whose fit time grows with an option the examples leave at
    /// its default (a trained model's steps) names a smaller one here.
    const SMALLEST: &'static str = "";
    /// The settings `btfrs.evaluate` sweeps (its quick sweep takes those marked `quick`); empty:
    /// the [`Model::EXAMPLES`], the first of them quick.
    const SWEEP: &'static [Setting] = &[];
    /// What the bench measures beyond the examples, by role ([`Bench`]): a new model needs no
    /// bench code, only the settings it wants measured in each role.
    const BENCH: &'static [Bench] = &[];
    /// What sampling the fit needs, for `btfrs info`'s advice on a capture.
    const SAMPLING: Sampling;
    /// File formats of other tools the model can be written as (`"ptm"`, `"rti"`); the writers
    /// are in `btfrs-io`, one file per format.
    const EXPORTS: &'static [&'static str] = &[];
    /// The arrays of [`Model::to_arrays`] that hold one entry per texel (shape `[H, W, ...]`):
    /// what [`crate::registry::select_texels`] gathers to make the model of a subset of texels
    /// (a tile set's BTFel table).
    const TEXEL_ARRAYS: &'static [&'static str];
    /// Fit options, read from JSON (`{"lobes": 2}`): unknown names and wrong types are errors
    /// naming the option.
    type Options: DeserializeOwned + std::fmt::Debug;

    /// Fit to the present pairs of `btf` (its values are finite: the caller checked, unless
    /// [`Model::SCANS_VALUES`]).
    ///
    /// Under a memory limit ([`Monitor::memory_limit`]) the fit allocates at most that much
    /// anonymous memory besides the model it returns, reading the values in place (a
    /// memory-mapped BTF stays on disk but for the pages being read).
    fn fit(btf: &BtfRef<'_>, options: &Self::Options, monitor: &Monitor) -> Result<Self>;
    /// The least memory limit (bytes, besides the model) the fit can keep to on `btf`; the
    /// registry rejects a lower `memory_limit` before fitting. The default is for the fits that
    /// stream the values texel by texel, solving each texel (or each view slot over all texels)
    /// with small scratch: a fixed 16 MB. A fit whose need grows with the data overrides it
    /// (double SH, RBF, bilinear: their float coefficients before quantizing), or sizes its
    /// chunks by the limit and reports the least itself (LPCA).
    fn least_memory(_btf: &BtfRef<'_>, _options: &Self::Options) -> u64 {
        16_000_000
    }
    /// Whether [`Model::fit`] checks every value of `btf` as it reads it
    /// ([`btfrs_core::btf::TexelScan`]) and fails as [`btfrs_core::btf::check_finite`] would,
    /// so its caller need not scan first: a memory-mapped BTF is then read once, not twice.
    const SCANS_VALUES: bool = false;
    /// Whether [`Model::fit_screened`] runs the robust value screen inside the fit's own pass
    /// (each texel judged and, if need be, repaired as it is read), which needs every texel to
    /// be fitted from its own values alone (PTM, HSH) or read once into the fit's own copy
    /// (the neural fit's training texels, and its encoding pass). The others are screened
    /// before the fit, from a repaired copy of the data ([`crate::driver::fit`]).
    const SCREENS_TEXELS: bool = false;
    /// [`Model::fit`] with `screen` run on each texel inside the pass; called only when
    /// [`Model::SCREENS_TEXELS`].
    fn fit_screened(
        _btf: &BtfRef<'_>,
        _options: &Self::Options,
        _screen: &crate::robust::TexelScreen<'_>,
        _monitor: &Monitor,
    ) -> Result<Self> {
        Err(btfrs_core::Error::arg(
            "robust",
            format!("a {} fit does not screen its texels in its own pass", Self::KIND),
        ))
    }
    /// Whether the fit is stochastic: trained by stochastic gradient descent on minibatches, so
    /// another `seed` gives another model and another error (not only another rounding). What
    /// holds of a deterministic fit ("the clean case is the best", equal results under a memory
    /// limit) holds of such a model within its spread over seeds.
    const STOCHASTIC: bool = false;
    /// Options (a JSON object) a fit needs for its model to be written in every format of
    /// [`Model::EXPORTS`], where the defaults make a model some of them cannot hold (`"{}"`: the
    /// defaults export). What a tool that fits in order to export (the CLI's tiled web page)
    /// passes, so that it names no model.
    const EXPORT_OPTIONS: &'static str = "{}";
    /// How the fit splits over blocks of texels fitted apart (a Dask cluster's chunks,
    /// `btfrs.dask`): see [`crate::blockwise`]. The default is the safe answer for a new model.
    const BLOCKWISE: crate::blockwise::Blockwise =
        crate::blockwise::Blockwise::Unsupported("it has not been split into texel blocks yet");
    /// Make the model stitched from the blocks of a [`crate::blockwise::Blockwise::Texels`] fit
    /// (each fitted with its `overrides`) what [`Model::fit`] with `options` returns on the
    /// whole BTF: the 8-bit models quantize here, over every texel at once, as their fit does.
    /// The default: unchanged.
    fn finish_blocks(self, options: &Self::Options) -> Result<Self> {
        let _ = options;
        Ok(self)
    }
    /// The arrays that describe the model completely (what a file stores).
    fn to_arrays(&self) -> NamedArrays;
    /// Rebuild from [`Model::to_arrays`] output, validating every array (it may come from a
    /// corrupted file or a user).
    fn from_arrays(arrays: &NamedArrays) -> Result<Self>;
    /// The fit's own statistics (iterations, fallbacks, ...) as a JSON object; `Null` when none.
    fn report(&self) -> serde_json::Value {
        serde_json::Value::Null
    }
    /// The parameters as a reader uses them, where that differs from what a file stores
    /// (decoded, unpadded, split by role: a decoder's layers, say); empty for most models. The
    /// model's own file decodes its arrays, so no other code repeats that decoding.
    fn unpacked(&self) -> NamedArrays {
        NamedArrays::new()
    }
    /// Every shader its renderers use (checked by the shader validation tests).
    fn shaders() -> Vec<crate::gpu::Shader> {
        vec![<Self as GpuLayout>::SHADER]
    }
    /// Bytes as stored for rendering: exactly what the default renderer uploads.
    fn nbytes(&self) -> usize {
        GpuModel::gpu_bytes(self)
    }
    /// How the coarse levels of a mip pyramid are made for filtered lookups (what the docs
    /// say; a model whose form depends on its fit overrides [`Model::mip`] as well).
    const MIP: Mip = Mip::Medoid;
    /// How this model's mip levels are made: [`Model::MIP`] unless the fit decides.
    fn mip(&self) -> Mip {
        Self::MIP
    }
    /// The model extended by averaged texels, for [`Mip::Average`] and [`Mip::Projected`] models
    /// (see [`crate::registry::mip_texels`]); [`average_texels`] is the exact average of a model
    /// linear in its [`Model::TEXEL_ARRAYS`].
    fn mip_texels(&self, groups: &[Vec<(u32, f32)>]) -> Result<Self> {
        let _ = groups;
        Err(Error::arg(
            "filter",
            format!("the {} model's parameters cannot be averaged (use medoid levels)", Self::KIND),
        ))
    }
    /// Per-texel features in a linear coefficient domain, for tile synthesis (paper 002, section
    /// 3.2: distances between texels there are distances between their appearances); `None`:
    /// the model has none, and the features are decoded at probe directions.
    fn coefficient_features(&self) -> Option<Result<CoefficientFeatures>> {
        None
    }
    /// The model as a double-SH expansion per texel and channel, for the SH environment method
    /// (paper 002, section 4); `None` for models that are not one.
    fn sh_expansion(&self) -> Option<ShExpansion<'_>> {
        None
    }
    /// The model as renderer `method` draws it (GPU layout and CPU reference). `max_3d` is the
    /// device's 3D texture limit per side.
    fn renderer(&self, method: &str, max_3d: usize) -> Result<Box<dyn Renderable + '_>> {
        let _ = max_3d;
        if method == Self::RENDERERS[0] || method == "default" {
            return Ok(Box::new(self));
        }
        Err(unknown_renderer(Self::KIND, Self::RENDERERS, method))
    }
}

/// The options of a model that has none: `{}` (anything else is an error naming it).
#[derive(Debug, Clone, Copy, Default, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NoOptions {}

/// One setting of `btfrs.evaluate`'s sweep of a model.
#[derive(Debug, Clone, Copy)]
pub struct Setting {
    /// The row's label (`"PTM-RGB"`).
    pub label: &'static str,
    /// The options, a JSON object.
    pub options: &'static str,
    /// Part of the quick sweep (the demo's and the tests').
    pub quick: bool,
    /// A note for the row (`""`: none).
    pub note: &'static str,
}

impl Setting {
    /// A setting of the full sweep.
    pub const fn full(label: &'static str, options: &'static str) -> Setting {
        Setting { label, options, quick: false, note: "" }
    }
    /// A setting of the quick sweep too.
    pub const fn quick(label: &'static str, options: &'static str) -> Setting {
        Setting { label, options, quick: true, note: "" }
    }
    /// With a note.
    pub const fn note(self, note: &'static str) -> Setting {
        Setting { note, ..self }
    }
}

/// What each role of a [`Bench`] setting means to the bench (`python -m btfrs.tools.bench`, whose
/// module doc says the same): the bench loops over the registry's settings by role and names no
/// model, so a new model is benched by declaring its settings here, with no bench code.
pub const BENCH_ROLES: &[(&str, &str)] = &[
    ("foundation", "timed at each --size in the first table (beside the setting's peer) and in its accuracy table"),
    ("reference", "the frame every other frame time is compared with (the 3x target), and the single-view summary's"),
    ("env", "the setting rendered by --env-only (else the reference, else the first example)"),
    ("models", "a row of the models table beyond the examples (with its peer's rows, if any)"),
    ("per_material", "a row of the per-material accuracy table (--accuracy)"),
    ("renderers", "rendered by each of the model's renderers, frame times and the PSNR between them"),
    ("reach", "searched for the cheapest setting reaching 2% reconstruction error on every material"),
    ("single_view", "fitted to the single-view RTI captures (--rti-only); a model with none fits its examples"),
    ("no_single_view", "left out of the single-view captures (the note says why)"),
    ("summary", "picked out in the single-view summary; the note is a peer tool's published figure"),
    ("single_view_reference", "the classic setting an against_all model is compared with on single-view captures"),
    ("against_all", "measured against every other model on accuracy per byte (--KIND-only)"),
    ("tiles", "the domain of the Wang tile sets (--tiles-only)"),
    ("big", "timed on a 128^2 x 81 x 81 sample (--KIND-big); the note is the target"),
    ("out_of_core", "fitted by --out-of-core when --out-of-core-fits is not given"),
    ("dask", "fitted locally and on a Dask cluster by --dask"),
];

/// A setting the bench measures and what for ([`BENCH_ROLES`]). `options` is a JSON object; an
/// option given as a list is a grid, one setting per combination, its `{name}` in `label` filled
/// in (`"LPCA {clusters}x{components}"`).
#[derive(Debug, Clone, Copy)]
pub struct Bench {
    /// The row's label (a template where `options` holds lists).
    pub label: &'static str,
    /// The options, a JSON object.
    pub options: &'static str,
    /// What the bench measures it for: names of [`BENCH_ROLES`].
    pub roles: &'static [&'static str],
    /// A peer of `btfrs.tools.baselines.PEERS` doing the same work another way (numpy, scipy,
    /// scikit-learn), timed and compared beside it; `""`: none.
    pub peer: &'static str,
    /// A note for its rows: the target it is held to, or a peer tool's published figure.
    pub note: &'static str,
}

impl Bench {
    /// A setting for `roles`.
    pub const fn new(label: &'static str, options: &'static str, roles: &'static [&'static str]) -> Bench {
        Bench { label, options, roles, peer: "", note: "" }
    }
    /// With a peer in `btfrs.tools.baselines`.
    pub const fn peer(self, peer: &'static str) -> Bench {
        Bench { peer, ..self }
    }
    /// With a note.
    pub const fn note(self, note: &'static str) -> Bench {
        Bench { note, ..self }
    }
}

/// What sampling of (view, light) pairs a fit needs.
#[derive(Debug, Clone, Copy)]
pub enum Sampling {
    /// A fit per view slot: at least `min_lights` lights in a slot, for the reason `why`.
    PerView {
        /// Lights per view slot.
        min_lights: usize,
        /// What needs them (`"biquadratic"`).
        why: &'static str,
    },
    /// Any sampling: `note`, and `one_view` for a capture with one view.
    Any {
        /// For several views.
        note: &'static str,
        /// For one view.
        one_view: &'static str,
    },
}

/// How a model's mip levels are made (filtered lookups, `btfrs.render(filter="trilinear")`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mip {
    /// The coarse texels are averages of the fine ones' parameters: exact, the model being
    /// linear in its texel arrays.
    Average,
    /// The coarse texels are projections of the averaged appearance ([`Model::mip_texels`]).
    Projected,
    /// Appearance medoids: the texel of each block nearest its mean appearance.
    Medoid,
}

impl Mip {
    /// Its name in Python (`model.mip`).
    pub fn name(self) -> &'static str {
        match self {
            Mip::Average => "average",
            Mip::Projected => "projected",
            Mip::Medoid => "medoid",
        }
    }
}

/// Per-texel features in a model's linear coefficient domain ([`Model::coefficient_features`]).
#[derive(Debug, Clone)]
pub struct CoefficientFeatures {
    /// Values per texel.
    pub dim: usize,
    /// `[texels][dim]`.
    pub data: Vec<f32>,
    /// What they are, for reports (`"sh coefficients"`).
    pub label: &'static str,
}

/// A model as a double-SH expansion ([`Model::sh_expansion`]): per texel and channel a
/// `view_coeffs x light_coeffs` matrix of real SH coefficients (paper 002, section 3.1).
#[derive(Debug, Clone)]
pub struct ShExpansion<'a> {
    /// View coefficients (a perfect square).
    pub view_coeffs: usize,
    /// Light coefficients (a perfect square).
    pub light_coeffs: usize,
    /// `[texel][channel][view_coeffs][light_coeffs]`, dequantized.
    pub coeffs: std::borrow::Cow<'a, [f32]>,
}

/// The exact mip texels of a model linear in its [`Model::TEXEL_ARRAYS`]: texel `n + g`
/// (n = the model's texel count) is `sum w x texel t` over `groups[g]`, which may name earlier
/// new texels. The result keeps the model's width and gains `ceil(groups / width)` rows (the last
/// padded with copies of texel 0), so every original texel keeps its index.
pub fn average_texels<M: Model>(model: &M, groups: &[Vec<(u32, f32)>]) -> Result<M> {
    use btfrs_core::arrays::ArrayData as D;
    let (h, w) = ReflectanceModel::dims(model);
    let n = h * w;
    for (g, grp) in groups.iter().enumerate() {
        if let Some(&(bad, _)) = grp.iter().find(|(t, _)| *t as usize >= n + g) {
            return Err(Error::arg("groups", format!("group {g} names texel {bad}, not defined before it")));
        }
    }
    let rows = h + groups.len().div_ceil(w.max(1));
    let arrays = model.to_arrays();
    let mut out = NamedArrays::new();
    for (name, a) in arrays.iter() {
        if !M::TEXEL_ARRAYS.contains(&name) {
            out.insert(name, a.clone());
            continue;
        }
        if a.shape.len() < 2 || a.shape[0] != h || a.shape[1] != w {
            return Err(Error::arg(
                "model",
                format!("{} array {name} has shape {:?}, not [{h}, {w}, ...]", M::KIND, a.shape),
            ));
        }
        let per: usize = a.shape[2..].iter().product();
        let mut shape = vec![rows, w];
        shape.extend_from_slice(&a.shape[2..]);
        // Averages in f64 over f64 copies, then back to the array's type (integers rounded).
        let mut v: Vec<f64> = match &a.data {
            D::U8(x) => x.iter().map(|&y| y as f64).collect(),
            D::U16(x) => x.iter().map(|&y| y as f64).collect(),
            D::I32(x) => x.iter().map(|&y| y as f64).collect(),
            D::F32(x) => x.iter().map(|&y| y as f64).collect(),
            D::F64(x) => x.clone(),
        };
        v.reserve((rows * w - n) * per);
        for grp in groups {
            let mut acc = vec![0.0f64; per];
            for &(t, wt) in grp {
                for (o, x) in acc.iter_mut().zip(&v[t as usize * per..(t as usize + 1) * per]) {
                    *o += wt as f64 * x;
                }
            }
            v.extend(acc);
        }
        let pad: Vec<f64> = v[..per].to_vec();
        while v.len() < rows * w * per {
            v.extend_from_slice(&pad);
        }
        let data = match &a.data {
            D::U8(_) => D::U8(v.iter().map(|x| x.round().clamp(0.0, 255.0) as u8).collect()),
            D::U16(_) => D::U16(v.iter().map(|x| x.round().clamp(0.0, 65535.0) as u16).collect()),
            D::I32(_) => D::I32(v.iter().map(|x| x.round() as i32).collect()),
            D::F32(_) => D::F32(v.iter().map(|&x| x as f32).collect()),
            D::F64(_) => D::F64(v),
        };
        out.insert_checked(name, shape, data)?;
    }
    M::from_arrays(&out)
}

/// The error for a renderer name a model does not have.
pub fn unknown_renderer(kind: &str, renderers: &[&str], method: &str) -> Error {
    let list: Vec<String> = renderers.iter().map(|r| format!("{r:?}")).collect();
    Error::arg("method", format!("the {kind} model has no renderer {method:?}; expected one of {}", list.join(", ")))
}

/// The object-safe face of every [`Model`]: what the registry, the bindings and the renderer
/// hold (`Box<dyn DynModel>`).
pub trait DynModel: Renderable + Send + std::fmt::Debug {
    /// [`Model::KIND`].
    fn kind(&self) -> &'static str;
    /// (height, width).
    fn dims(&self) -> (usize, usize);
    /// [`Model::nbytes`].
    fn nbytes(&self) -> usize;
    /// [`Model::to_arrays`].
    fn to_arrays(&self) -> NamedArrays;
    /// [`Model::report`].
    fn report(&self) -> serde_json::Value;
    /// [`Model::unpacked`].
    fn unpacked(&self) -> NamedArrays;
    /// [`Model::RENDERERS`].
    fn renderers(&self) -> &'static [&'static str];
    /// [`Model::renderer`].
    fn renderer(&self, method: &str, max_3d: usize) -> Result<Box<dyn Renderable + '_>>;
    /// [`evaluate_image`].
    fn evaluate_image(&self, view: [f64; 3], light: [f64; 3]) -> Result<Vec<f32>>;
    /// [`model_error`].
    fn error(&self, btf: &BtfRef<'_>) -> Result<ErrorSums>;
    /// [`Model::mip`].
    fn mip(&self) -> Mip;
    /// [`Model::mip_texels`].
    fn mip_texels(&self, groups: &[Vec<(u32, f32)>]) -> Result<Box<dyn DynModel>>;
    /// [`Model::coefficient_features`].
    fn coefficient_features(&self) -> Option<Result<CoefficientFeatures>>;
    /// [`Model::sh_expansion`].
    fn sh_expansion(&self) -> Option<ShExpansion<'_>>;
    /// The concrete model, for its own files only (a format writer of that model in
    /// `btfrs-io`): everything else asks the registry and the methods above.
    fn as_any(&self) -> &dyn Any;
}

impl<M: Model + std::fmt::Debug> DynModel for M {
    fn kind(&self) -> &'static str {
        M::KIND
    }
    fn dims(&self) -> (usize, usize) {
        ReflectanceModel::dims(self)
    }
    fn nbytes(&self) -> usize {
        Model::nbytes(self)
    }
    fn to_arrays(&self) -> NamedArrays {
        Model::to_arrays(self)
    }
    fn report(&self) -> serde_json::Value {
        Model::report(self)
    }
    fn unpacked(&self) -> NamedArrays {
        Model::unpacked(self)
    }
    fn renderers(&self) -> &'static [&'static str] {
        M::RENDERERS
    }
    fn renderer(&self, method: &str, max_3d: usize) -> Result<Box<dyn Renderable + '_>> {
        Model::renderer(self, method, max_3d)
    }
    fn evaluate_image(&self, view: [f64; 3], light: [f64; 3]) -> Result<Vec<f32>> {
        let img = evaluate_image(self, view, light)?;
        check_output(self, &img, "evaluate")?;
        Ok(img)
    }
    fn error(&self, btf: &BtfRef<'_>) -> Result<ErrorSums> {
        let sums = model_error(self, btf)?;
        if !(sums.sse.is_finite() && sums.sgt.is_finite()) {
            return Err(overflow(self, "error"));
        }
        Ok(sums)
    }
    fn mip(&self) -> Mip {
        Model::mip(self)
    }
    fn mip_texels(&self, groups: &[Vec<(u32, f32)>]) -> Result<Box<dyn DynModel>> {
        Ok(Box::new(Model::mip_texels(self, groups)?))
    }
    fn coefficient_features(&self) -> Option<Result<CoefficientFeatures>> {
        Model::coefficient_features(self)
    }
    fn sh_expansion(&self) -> Option<ShExpansion<'_>> {
        Model::sh_expansion(self)
    }
    fn as_any(&self) -> &dyn Any {
        self
    }
}

/// The array of `model` holding the largest magnitude, and that magnitude: where an overflow
/// comes from (only computed for an error).
pub fn largest_stored(model: &dyn DynModel) -> Option<(String, f64)> {
    use btfrs_core::arrays::ArrayData as D;
    let arrays = model.to_arrays();
    let mut best: Option<(String, f64)> = None;
    for (name, a) in arrays.iter() {
        let m = match &a.data {
            D::F32(x) => x.iter().fold(0.0f64, |m, &v| m.max((v as f64).abs())),
            D::F64(x) => x.iter().fold(0.0f64, |m, &v| m.max(v.abs())),
            _ => continue,
        };
        if best.as_ref().is_none_or(|(_, b)| m > *b) {
            best = Some((name.to_string(), m));
        }
    }
    best
}

/// The error for non-finite output of `model` in `what` (evaluate, error, render): its values
/// are finite as stored (every file is checked) but too large to be evaluated.
pub fn overflow(model: &dyn DynModel, what: &str) -> Error {
    let culprit = largest_stored(model)
        .map(|(name, m)| format!("; its largest stored value is {m:.3e}, in array {name:?}"))
        .unwrap_or_default();
    Error::Numerical(format!(
        "{what}: the {} model gives non-finite values (its stored values overflow when evaluated){culprit}",
        model.kind()
    ))
}

/// [`overflow`] when `values` hold a non-finite value.
pub fn check_output(model: &dyn DynModel, values: &[f32], what: &str) -> Result<()> {
    if values.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(overflow(model, what))
    }
}

/// A `[height, width, 3]` image of the model for one view and light.
pub fn evaluate_image<M: ReflectanceModel>(m: &M, view: [f64; 3], light: [f64; 3]) -> Result<Vec<f32>> {
    btfrs_core::directions::validate("view", &[view])?;
    btfrs_core::directions::validate("light", &[light])?;
    let (h, w) = m.dims();
    let q = m.query(view, light);
    let mut out = vec![0.0f32; h * w * 3];
    out.par_chunks_mut(3).enumerate().for_each(|(t, px)| px.copy_from_slice(&m.eval(t, &q)));
    Ok(out)
}

/// Error sums of the model against every present (view, light) pair of `btf`.
pub fn model_error<M: ReflectanceModel>(m: &M, btf: &BtfRef<'_>) -> Result<ErrorSums> {
    if m.dims() != (btf.height, btf.width) {
        return Err(Error::arg(
            "btf",
            format!("the model covers {:?} texels but the BTF has {} x {}", m.dims(), btf.height, btf.width),
        ));
    }
    let nl = btf.lights.len();
    let pairs: Vec<(usize, M::Query)> = (0..btf.views.len())
        .flat_map(|v| (0..nl).map(move |l| (v, l)))
        .filter(|&(v, l)| btf.has(v, l))
        .map(|(v, l)| ((v * nl + l) * 3, m.query(btf.views[v], btf.lights[l])))
        .collect();
    let sums = (0..btf.texels())
        .into_par_iter()
        .fold(ErrorSums::default, |mut acc, t| {
            let gt = btf.texel(t);
            for (off, q) in &pairs {
                let p = m.eval(t, q);
                for c in 0..3 {
                    acc.add(p[c] as f64, gt[off + c] as f64);
                }
            }
            acc
        })
        .reduce(ErrorSums::default, ErrorSums::merge);
    Ok(sums)
}

/// The measured BTF itself as a model: the value at any (view, light) is interpolated between
/// the three nearest measured views times the three nearest measured lights (weights of
/// [`btfrs_core::directions::interp_weights`]). The quality reference of every renderer and
/// model; it stores the whole BTF.
#[derive(Debug, Clone, Copy)]
pub struct RawModel<'a> {
    btf: BtfRef<'a>,
}

impl<'a> RawModel<'a> {
    /// Wrap a BTF; every (view, light) pair must be present (interpolating over a masked grid
    /// would silently use pairs the user held out).
    pub fn new(btf: BtfRef<'a>) -> Result<Self> {
        if btf.mask.is_some_and(|m| !m.iter().all(|&b| b)) {
            return Err(Error::arg("btf", "raw interpolation needs every (view, light) pair; this sample has a mask"));
        }
        Ok(RawModel { btf })
    }

    /// The wrapped BTF.
    pub fn btf(&self) -> &BtfRef<'a> {
        &self.btf
    }
}

/// View and light weights of a raw query.
#[derive(Debug, Clone)]
pub struct RawQuery {
    views: Vec<(usize, f32)>,
    lights: Vec<(usize, f32)>,
}

impl ReflectanceModel for RawModel<'_> {
    type Query = RawQuery;

    fn dims(&self) -> (usize, usize) {
        (self.btf.height, self.btf.width)
    }

    fn query(&self, view: [f64; 3], light: [f64; 3]) -> RawQuery {
        use btfrs_core::directions::{cos_corrected, interp_weights};
        let f32s = |w: Vec<(usize, f64)>| w.into_iter().map(|(i, w)| (i, w as f32)).collect();
        // Lights blend with the measured cosine divided out (see cos_corrected).
        let mut lw = interp_weights(self.btf.lights, light, 3);
        cos_corrected(&mut lw, self.btf.lights, light);
        RawQuery { views: f32s(interp_weights(self.btf.views, view, 3)), lights: f32s(lw) }
    }

    #[inline]
    fn eval(&self, t: usize, q: &RawQuery) -> [f32; 3] {
        let nl = self.btf.lights.len();
        let texel = self.btf.texel(t);
        let mut out = [0.0f32; 3];
        for &(v, wv) in &q.views {
            for &(l, wl) in &q.lights {
                let s = &texel[(v * nl + l) * 3..(v * nl + l) * 3 + 3];
                for c in 0..3 {
                    out[c] += wv * wl * s[c];
                }
            }
        }
        out
    }
}

crate::gpu_params! {
    /// Parameters of `raw.wgsl`.
    pub struct RawParams {
        /// Number of views V (directions `mdirs[0 .. V]`).
        pub n_views: u32,
        /// Number of lights L (directions `mdirs[V .. V + L]`).
        pub n_lights: u32,
        /// Offset of the views' candidate table in `tables`.
        pub view_table: u32,
        /// Offset of the lights' candidate table in `tables`.
        pub light_table: u32,
        /// Store offset of the data, `[texel][V][L][3]` f32 (the Btf's own texel-major layout).
        pub data: u32,
    }
}

impl GpuLayout for RawModel<'_> {
    type Params = RawParams;
    const SHADER: crate::gpu::Shader =
        crate::gpu::Shader::new::<RawParams>("raw", include_str!("../../../shaders_wgsl/raw.wgsl"));

    fn parts(&self) -> Vec<std::borrow::Cow<'_, [u32]>> {
        vec![crate::gpu::words(self.btf.data)]
    }

    fn dir_sets(&self) -> Vec<&[[f64; 3]]> {
        vec![self.btf.views, self.btf.lights]
    }

    fn params(&self, offsets: &[u32], tables: &[u32]) -> RawParams {
        RawParams {
            n_views: self.btf.views.len() as u32,
            n_lights: self.btf.lights.len() as u32,
            view_table: tables[0],
            light_table: tables[1],
            data: offsets[0],
        }
    }
}
