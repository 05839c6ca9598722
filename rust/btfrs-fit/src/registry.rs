//! The model registry: the one list of models. Everything that iterates over models (the
//! bindings, `btfrs.load`, `btfrs.fit.<kind>`, the CLI, `btfrs.evaluate`, the renderers, the
//! demo, the bench, the docs) asks it, so a new model is registered by one line in [`MODELS`]
//! (see CONTRIBUTING.md), and every fact about a model is read from its entry ([`describe`]).

use crate::model::{Bench, DynModel, Mip, Model, Sampling, Setting};
use crate::options::{self, Spec, Values};
use btfrs_core::{BtfRef, Error, Monitor, NamedArrays, Result};
use serde_json::{json, Value};

/// What the registry knows of one model, independent of its type.
#[derive(Debug, Clone, Copy)]
pub struct Entry {
    /// [`Model::KIND`].
    pub kind: &'static str,
    /// The model's Rust type (`btfrs_fit::ptm::Ptm`): where its files are.
    pub type_name: fn() -> &'static str,
    /// [`Model::DOC`].
    pub doc: &'static str,
    /// [`Model::ABOUT`].
    pub about: &'static str,
    /// [`Model::OPTIONS`].
    pub options: &'static [Spec],
    /// [`Model::RENDERERS`].
    pub renderers: &'static [&'static str],
    /// [`Model::EXAMPLES`].
    pub examples: &'static [(&'static str, &'static str)],
    /// [`Model::SWEEP`].
    pub sweep: &'static [Setting],
    /// [`Model::SAMPLING`].
    pub sampling: Sampling,
    /// [`Model::EXPORTS`].
    pub exports: &'static [&'static str],
    /// [`Model::MIP`].
    pub mip: Mip,
    /// Fit with options by name (checked against [`Entry::options`]).
    pub fit: fn(&BtfRef<'_>, &Values, &Monitor) -> Result<Box<dyn DynModel>>,
    /// [`Model::from_arrays`].
    pub from_arrays: fn(&NamedArrays) -> Result<Box<dyn DynModel>>,
    /// [`Model::shaders`].
    pub shaders: fn() -> Vec<crate::gpu::Shader>,
    /// [`Model::TEXEL_ARRAYS`].
    pub texel_arrays: &'static [&'static str],
    /// [`Model::SCANS_VALUES`]: the fit checks the values itself, in its own pass.
    pub scans_values: bool,
    /// [`Model::fit_screened`] with options by name, for the models that
    /// [`Model::SCREENS_TEXELS`].
    pub fit_screened: Option<FitScreened>,
    /// [`Model::BLOCKWISE`].
    pub blockwise: crate::blockwise::Blockwise,
    /// Rebuild from the stitched arrays of a blockwise fit and [`Model::finish_blocks`] with
    /// options by name (those of the whole fit, not the blocks').
    pub finish_blocks: fn(&NamedArrays, &Values) -> Result<Box<dyn DynModel>>,
    /// [`Model::STOCHASTIC`].
    pub stochastic: bool,
    /// [`Model::EXPORT_OPTIONS`].
    pub export_options: &'static str,
    /// [`Model::SMALLEST`] (`""`: the first example).
    pub smallest: &'static str,
    /// [`Model::BENCH`].
    pub bench: &'static [Bench],
}

impl Entry {
    /// The settings `btfrs.evaluate` sweeps: [`Model::SWEEP`], or the examples (the first quick).
    pub fn sweep(&self) -> Vec<Setting> {
        if !self.sweep.is_empty() {
            return self.sweep.to_vec();
        }
        self.examples
            .iter()
            .enumerate()
            .map(|(i, &(label, options))| Setting { label, options, quick: i == 0, note: "" })
            .collect()
    }

    /// The bench's settings ([`Model::BENCH`]) with their grids expanded: `(label, options,
    /// setting)` per combination, in the order written (a grid's options in name order, the
    /// first varying slowest).
    pub fn bench_settings(&self) -> Result<Vec<(String, Values, &'static Bench)>> {
        let mut out = Vec::new();
        for b in self.bench {
            let base = options::parse_json(b.options)?;
            let mut combos: Vec<(String, Values)> = vec![(b.label.to_string(), Values::new())];
            for (name, v) in &base {
                let choices = match v {
                    Value::Array(a) => a.clone(),
                    other => vec![other.clone()],
                };
                combos = combos
                    .into_iter()
                    .flat_map(|(label, o)| {
                        choices.iter().map(move |c| {
                            let mut o = o.clone();
                            o.insert(name.clone(), c.clone());
                            (label.replace(&format!("{{{name}}}"), &c.to_string()), o)
                        })
                    })
                    .collect();
            }
            out.extend(combos.into_iter().map(|(label, o)| (label, o, b)));
        }
        Ok(out)
    }

    /// [`Entry::fit`] with the options written as a JSON object: the registry's own facts (an
    /// example, a sweep setting) and the tests.
    pub fn fit_json(&self, btf: &BtfRef<'_>, options: &str, monitor: &Monitor) -> Result<Box<dyn DynModel>> {
        (self.fit)(btf, &options::parse_json(options)?, monitor)
    }
}

fn fit_erased<M: Model + std::fmt::Debug>(
    btf: &BtfRef<'_>,
    options: &Values,
    mon: &Monitor,
) -> Result<Box<dyn DynModel>> {
    let o = checked_options::<M>(btf, options, mon)?;
    Ok(Box::new(M::fit(btf, &o, mon)?))
}

/// The model's options, with the memory limit checked against the least the fit of `btf`
/// needs and set on `mon`.
fn checked_options<M: Model>(btf: &BtfRef<'_>, options: &Values, mon: &Monitor) -> Result<M::Options> {
    let (map, limit) = take_memory_limit(options)?;
    let o: M::Options = options::build(M::OPTIONS, map)?;
    if let Some(limit) = limit {
        let least = M::least_memory(btf, &o);
        if limit < least {
            return Err(Error::arg(
                "memory_limit",
                format!(
                    "expected at least {:.1} MB for a {} fit of {} x {} texels, got {:.1} MB",
                    least as f64 / 1e6,
                    M::KIND,
                    btf.height,
                    btf.width,
                    limit as f64 / 1e6
                ),
            ));
        }
    }
    mon.set_memory_limit(limit);
    Ok(o)
}

/// The option every fit takes besides its own: `memory_limit`, the anonymous memory in bytes
/// the fit may allocate besides the model it returns (out-of-core fitting of memory-mapped
/// BTFs); taken out of the options before the model's own are checked.
pub(crate) fn take_memory_limit(options: &Values) -> Result<(Values, Option<u64>)> {
    let mut map = options.clone();
    let limit = match map.remove("memory_limit") {
        None | Some(Value::Null) => None,
        Some(v) => match v.as_u64() {
            Some(b) if b > 0 => Some(b),
            _ => {
                let wrong_type = !v.is_number();
                return Err(Error::value("memory_limit", v, "a positive number of bytes", wrong_type));
            }
        },
    };
    Ok((map, limit))
}

/// A fit with the value screen inside its pass ([`Entry::fit_screened`]).
pub type FitScreened = fn(&BtfRef<'_>, &Values, &crate::robust::TexelScreen<'_>, &Monitor) -> Result<Box<dyn DynModel>>;

fn fit_screened_erased<M: Model + std::fmt::Debug>(
    btf: &BtfRef<'_>,
    options: &Values,
    screen: &crate::robust::TexelScreen<'_>,
    mon: &Monitor,
) -> Result<Box<dyn DynModel>> {
    let o = checked_options::<M>(btf, options, mon)?;
    Ok(Box::new(M::fit_screened(btf, &o, screen, mon)?))
}

fn from_arrays_erased<M: Model + std::fmt::Debug>(a: &NamedArrays) -> Result<Box<dyn DynModel>> {
    Ok(Box::new(M::from_arrays(a)?))
}

fn finish_blocks_erased<M: Model + std::fmt::Debug>(a: &NamedArrays, options: &Values) -> Result<Box<dyn DynModel>> {
    let (map, _) = take_memory_limit(options)?;
    let o: M::Options = options::build(M::OPTIONS, map)?;
    Ok(Box::new(M::from_arrays(a)?.finish_blocks(&o)?))
}

/// The registry entry of `M`.
pub const fn entry<M: Model + std::fmt::Debug>() -> Entry {
    Entry {
        kind: M::KIND,
        type_name: std::any::type_name::<M>,
        doc: M::DOC,
        about: M::ABOUT,
        options: M::OPTIONS,
        renderers: M::RENDERERS,
        examples: M::EXAMPLES,
        sweep: M::SWEEP,
        sampling: M::SAMPLING,
        exports: M::EXPORTS,
        mip: M::MIP,
        fit: fit_erased::<M>,
        from_arrays: from_arrays_erased::<M>,
        shaders: M::shaders,
        texel_arrays: M::TEXEL_ARRAYS,
        scans_values: M::SCANS_VALUES,
        fit_screened: if M::SCREENS_TEXELS { Some(fit_screened_erased::<M>) } else { None },
        blockwise: M::BLOCKWISE,
        finish_blocks: finish_blocks_erased::<M>,
        stochastic: M::STOCHASTIC,
        export_options: M::EXPORT_OPTIONS,
        smallest: if M::SMALLEST.is_empty() { M::EXAMPLES[0].1 } else { M::SMALLEST },
        bench: M::BENCH,
    }
}

/// Every model, in the order the demo and the bench show them.
pub const MODELS: &[Entry] = &[
    entry::<crate::ptm::Ptm>(),
    entry::<crate::hsh::Hsh>(),
    entry::<crate::lafortune::Lafortune>(),
    entry::<crate::lafortune::per_view::LafortuneView>(),
    entry::<crate::srf::Srf>(),
    entry::<crate::sh::Sh>(),
    entry::<crate::lpca::Lpca>(),
    entry::<crate::rbf::Rbf>(),
    entry::<crate::bilinear::Bilinear>(),
    entry::<crate::neural::Neural>(),
    entry::<crate::svbrdf::Svbrdf>(),
];

/// The entry of `kind`, or an error listing the registered models.
pub fn lookup(kind: &str) -> Result<&'static Entry> {
    MODELS.iter().find(|e| e.kind == kind).ok_or_else(|| {
        let names: Vec<String> = MODELS.iter().map(|e| format!("{:?}", e.kind)).collect();
        Error::arg("kind", format!("unknown model {kind:?}; expected one of {}", names.join(", ")))
    })
}

/// Fit model `kind` with options by name (empty for the defaults).
pub fn fit(kind: &str, btf: &BtfRef<'_>, options: &Values, monitor: &Monitor) -> Result<Box<dyn DynModel>> {
    (lookup(kind)?.fit)(btf, options, monitor)
}

/// Check options for model `kind` as its fit would, without fitting: the CLI checks `--set`
/// before reading any data.
pub fn check_options(kind: &str, options: &Values) -> Result<()> {
    let e = lookup(kind)?;
    let (map, _) = take_memory_limit(options)?;
    options::check(e.options, &map)
}

/// Rebuild model `kind` from its arrays.
pub fn from_arrays(kind: &str, arrays: &NamedArrays) -> Result<Box<dyn DynModel>> {
    (lookup(kind)?.from_arrays)(arrays)
}

/// A JSON object of the registry's own facts as a value (checked by `every_schema_builds_its_options`).
fn fact(json: &str) -> Value {
    Value::Object(options::parse_json(json).unwrap_or_default())
}

/// Every fact of every model as JSON: what the Python API, the CLI and the docs are built from.
pub fn describe() -> Value {
    Value::Array(
        MODELS
            .iter()
            .map(|e| {
                let (blockwise, why, _) = e.blockwise.describe();
                let sampling = match e.sampling {
                    Sampling::PerView { min_lights, why } => json!({"per_view": true, "min_lights": min_lights, "why": why}),
                    Sampling::Any { note, one_view } => json!({"per_view": false, "note": note, "one_view": one_view}),
                };
                json!({
                    "kind": e.kind,
                    "type": (e.type_name)(),
                    "doc": e.doc,
                    "about": e.about,
                    "options": options::schema_json(e.options),
                    "renderers": e.renderers,
                    "examples": e.examples.iter().map(|(l, o)| json!([l, fact(o)])).collect::<Vec<_>>(),
                    "sweep": e.sweep().iter().map(|s| json!({"label": s.label, "options": fact(s.options), "quick": s.quick, "note": s.note})).collect::<Vec<_>>(),
                    "sampling": sampling,
                    "exports": e.exports,
                    "mip": e.mip.name(),
                    "texel_arrays": e.texel_arrays,
                    "scans_values": e.scans_values,
                    "blockwise": blockwise,
                    "blockwise_note": why,
                    "stochastic": e.stochastic,
                    "export_options": fact(e.export_options),
                    "smallest": fact(e.smallest),
                    "bench": e.bench_settings().unwrap_or_default().into_iter().map(|(label, o, b)| json!({
                        "label": label, "options": o, "roles": b.roles, "peer": b.peer, "note": b.note,
                    })).collect::<Vec<_>>(),
                })
            })
            .collect(),
    )
}

/// The model extended by averaged texels (the coarse levels of a box-filtered mip pyramid):
/// texel `n + g` (n = the model's texel count) is a weighted sum of the texels `groups[g]`
/// names, which may name earlier new texels; the width is kept and `ceil(groups / width)` rows
/// are added, so every original texel keeps its index. What "averaged" means is the model's own
/// ([`Model::mip`]): the exact average of its parameters ([`Mip::Average`]), or a projection of
/// the averaged appearance ([`Mip::Projected`]); medoid models are an error naming `filter`.
pub fn mip_texels(model: &dyn DynModel, groups: &[Vec<(u32, f32)>]) -> Result<Box<dyn DynModel>> {
    if model.mip() == Mip::Medoid {
        return Err(Error::arg(
            "filter",
            format!("the {} model's parameters cannot be averaged (use medoid levels)", model.kind()),
        ));
    }
    model.mip_texels(groups)
}

/// The model of a subset of texels: texel `k` of the result is texel `texels[k]` (row-major
/// index) of `model`, every other parameter shared. The result has dims `(1, texels.len())`.
/// A tile set stores its BTFel table this way (paper 002, section 5.3).
pub fn select_texels(model: &dyn DynModel, texels: &[u32]) -> Result<Box<dyn DynModel>> {
    let entry = lookup(model.kind())?;
    let (h, w) = model.dims();
    let n = h * w;
    if texels.is_empty() {
        return Err(Error::arg("texels", "expected at least one texel"));
    }
    if let Some(&bad) = texels.iter().find(|&&t| t as usize >= n) {
        return Err(Error::arg("texels", format!("texel {bad} is outside the {h} x {w} model")));
    }
    let arrays = model.to_arrays();
    let mut out = NamedArrays::new();
    for (name, a) in arrays.iter() {
        if !entry.texel_arrays.contains(&name) {
            out.insert(name, a.clone());
            continue;
        }
        if a.shape.len() < 2 || a.shape[0] != h || a.shape[1] != w {
            return Err(Error::arg(
                "model",
                format!("{} array {name} has shape {:?}, not [{h}, {w}, ...]", entry.kind, a.shape),
            ));
        }
        let per: usize = a.shape[2..].iter().product();
        let mut shape = vec![1, texels.len()];
        shape.extend_from_slice(&a.shape[2..]);
        fn gather<T: Copy>(v: &[T], per: usize, texels: &[u32]) -> Vec<T> {
            texels.iter().flat_map(|&t| v[t as usize * per..(t as usize + 1) * per].iter().copied()).collect()
        }
        use btfrs_core::arrays::ArrayData as D;
        let data = match &a.data {
            D::U8(v) => D::U8(gather(v, per, texels)),
            D::U16(v) => D::U16(gather(v, per, texels)),
            D::I32(v) => D::I32(gather(v, per, texels)),
            D::F32(v) => D::F32(gather(v, per, texels)),
            D::F64(v) => D::F64(gather(v, per, texels)),
        };
        out.insert_checked(name, shape, data)?;
    }
    (entry.from_arrays)(&out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use btfrs_core::materials::{generate, MaterialSpec, Preset};

    fn sample() -> btfrs_core::Btf {
        generate(&MaterialSpec::new(Preset::Bumps, 8, 3), &Monitor::new()).unwrap()
    }

    #[test]
    fn every_model_round_trips_through_its_arrays() {
        // Fitted with its first example, saved as arrays and rebuilt: the rebuilt model must
        // evaluate to the same values at a direction pair between the measured ones, report the
        // same bytes, and produce the same arrays again.
        let btf = sample();
        let b = btf.as_ref();
        let (v, l) = ([0.2, -0.1, 0.97468], [-0.3, 0.4, 0.86603]);
        let norm = |d: [f64; 3]| {
            let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            d.map(|x| x / n)
        };
        for e in MODELS {
            let m = e.fit_json(&b, e.examples[0].1, &Monitor::new()).unwrap();
            assert_eq!(m.kind(), e.kind);
            let a = m.to_arrays();
            let r = from_arrays(e.kind, &a).unwrap();
            assert_eq!(r.to_arrays(), a, "{}", e.kind);
            assert_eq!(r.nbytes(), m.nbytes(), "{}", e.kind);
            let x = m.evaluate_image(norm(v), norm(l)).unwrap();
            let y = r.evaluate_image(norm(v), norm(l)).unwrap();
            assert_eq!(x, y, "{}", e.kind);
            assert!(x.iter().all(|p| p.is_finite()) && x.iter().any(|&p| p > 0.0), "{}", e.kind);
        }
    }

    #[test]
    fn models_that_scan_their_values_fail_as_the_scan_would() {
        // Their caller skips check_finite (rust/btfrs-py/src/models.rs fit_model), so a
        // non-finite value anywhere, in a pair the mask leaves out too, must fail the fit with
        // check_finite's own error, wherever it lies (first and last texel, middle of the data).
        let btf = sample();
        let mut mask = vec![true; btf.views.len() * btf.lights.len()];
        mask[5] = false;
        let scanning: Vec<_> = MODELS.iter().filter(|e| e.scans_values).collect();
        assert!(scanning.iter().any(|e| e.kind == "ptm") && scanning.iter().any(|e| e.kind == "hsh"));
        for e in scanning {
            for (at, x) in [
                (0, f32::NAN),
                (btf.data.len() / 2 + 7, f32::INFINITY),
                (btf.data.len() - 1, f32::NAN),
                (5 * 3, f32::NAN),
            ] {
                let mut data = btf.data.clone();
                data[at] = x;
                let mut b = btf.as_ref();
                b.data = &data;
                b.mask = Some(&mask);
                let want = btfrs_core::btf::check_finite("data", &data).unwrap_err().to_string();
                for (label, options) in e.examples {
                    let got = e.fit_json(&b, options, &Monitor::new()).unwrap_err().to_string();
                    assert_eq!(got, want, "{label}, non-finite at {at}");
                }
            }
        }
    }

    #[test]
    fn nbytes_is_what_the_default_renderer_uploads() {
        // Counted independently from the renderer's own parts: the words it uploads (the store
        // and the constants after the parameter block), plus the 3D texture of renderers that
        // have one.
        let btf = sample();
        for e in MODELS {
            let m = e.fit_json(&btf.as_ref(), e.examples[0].1, &Monitor::new()).unwrap();
            let r = m.renderer(e.renderers[0], 2048).unwrap();
            let words: usize = r.gpu_parts().iter().map(|p| p.len()).sum::<usize>() + r.gpu_constants().len();
            assert_eq!(m.nbytes(), 4 * words + r.gpu_volume().map_or(0, |v| v.texels.len()), "{}", e.kind);
        }
    }

    #[test]
    fn options_errors_name_the_option_the_value_and_what_is_allowed() {
        let btf = sample();
        let b = btf.as_ref();
        let err = |kind: &str, o: &str| {
            options::parse_json(o).and_then(|o| fit(kind, &b, &o, &Monitor::new())).unwrap_err().to_string()
        };
        let check = |kind: &str, o: &str| check_options(kind, &options::parse_json(o).unwrap());
        assert_eq!(err("lafortune", r#"{"lobes": 2.9}"#), "lobes: expected an integer from 1 to 7, got 2.9");
        assert_eq!(err("lpca", r#"{"clusters": -1}"#), "clusters: expected an integer >= 1, got -1");
        assert!(err("ptm", r#"{"knd": "rgb"}"#).starts_with("knd: unknown option; expected one of kind, rcond,"));
        assert_eq!(err("ptm", r#"{"kind": "xyz"}"#), "kind: expected \"rgb\" or \"lrgb\", got \"xyz\"");
        assert_eq!(err("ptm", r#"{"bits": 16}"#), "bits: expected 8 or 32, got 16");
        assert_eq!(
            err("sh", r#"{"light_coeffs": 20}"#),
            "light_coeffs: expected 1, 4, 9, 16, 25, 36, 49 or 64, got 20"
        );
        assert_eq!(err("srf", r#"{"x": 1}"#), "x: unknown option; this model takes no options");
        assert!(err("nope", "{}").contains("unknown model \"nope\""));
        assert_eq!(err("ptm", "[1]"), "options: expected a JSON object of option names");
        assert!(check("rbf", r#"{"width": 0}"#).unwrap_err().to_string().starts_with("width: expected a number > 0"));
        assert!(check("rbf", r#"{"width": 1, "memory_limit": 1000000}"#).is_ok());
        assert_eq!(
            check("rbf", r#"{"memory_limit": -3}"#).unwrap_err().to_string(),
            "memory_limit: expected a positive number of bytes, got -3"
        );
    }

    #[test]
    fn every_schema_builds_its_options() {
        // The schema is the one place a default is written: its defaults must build the options
        // struct (a field missing from either side fails here), every option must be settable
        // alone to its default, and each example and sweep setting must pass the checks.
        let btf = sample();
        for e in MODELS {
            assert!(!e.about.is_empty() && !e.doc.is_empty(), "{}", e.kind);
            let mut names = std::collections::HashSet::new();
            for s in e.options {
                assert!(names.insert(s.name), "{}: option {} twice", e.kind, s.name);
                assert!(!s.doc.is_empty(), "{}.{}", e.kind, s.name);
                s.check(&s.default_value()).unwrap_or_else(|x| panic!("{}: default of {}: {x}", e.kind, s.name));
                check_options(e.kind, &Values::from_iter([(s.name.to_string(), s.default_value())])).unwrap();
            }
            for st in e.sweep() {
                options::parse_json(st.options)
                    .and_then(|o| check_options(e.kind, &o))
                    .unwrap_or_else(|x| panic!("{} {}: {x}", e.kind, st.label));
            }
            assert!(e.sweep().iter().any(|s| s.quick), "{}: no quick setting", e.kind);
            // The bench's settings: every combination passes the checks, its label filled in,
            // every role known.
            for (label, o, b) in e.bench_settings().unwrap_or_else(|x| panic!("{}: bench: {x}", e.kind)) {
                assert!(!label.contains('{'), "{}: {label}: a placeholder without its option", e.kind);
                check_options(e.kind, &o).unwrap_or_else(|x| panic!("{} {label}: {x}", e.kind));
                for r in b.roles {
                    assert!(
                        crate::model::BENCH_ROLES.iter().any(|k| k.0 == *r),
                        "{} {label}: unknown bench role {r}",
                        e.kind
                    );
                }
            }
            for (label, o) in e.examples.iter().chain([&("smallest", e.smallest)]) {
                options::parse_json(o)
                    .and_then(|o| check_options(e.kind, &o))
                    .unwrap_or_else(|x| panic!("{} {label}: {x}", e.kind));
            }
            // The defaults fit (an error naming the options struct would mean a schema mismatch).
            if let Err(x) = fit(e.kind, &btf.as_ref(), &Values::new(), &Monitor::new()) {
                assert!(!x.to_string().contains("internal"), "{}: {x}", e.kind);
            }
        }
    }

    #[test]
    fn describe_carries_every_fact_the_python_surface_needs() {
        let d = describe();
        let a = d.as_array().unwrap();
        assert_eq!(a.len(), MODELS.len());
        for (m, e) in a.iter().zip(MODELS) {
            assert_eq!(m["kind"], e.kind);
            assert_eq!(m["options"].as_array().unwrap().len(), e.options.len());
            for key in [
                "doc",
                "about",
                "renderers",
                "examples",
                "sweep",
                "sampling",
                "exports",
                "blockwise",
                "stochastic",
                "export_options",
                "smallest",
            ] {
                assert!(!m[key].is_null(), "{} lacks {key}", e.kind);
            }
        }
        let ptm = &a[0];
        assert_eq!(ptm["options"][0]["choices"], json!(["rgb", "lrgb"]));
        assert_eq!(ptm["exports"], json!(["ptm", "relight"]));
        assert_eq!(ptm["examples"][0][1], json!({"kind": "lrgb"}));
    }

    #[test]
    fn corrupted_arrays_are_errors_not_panics() {
        // Every array of every model, replaced by an empty one, a wrong-dtype one, and dropped:
        // each rebuild is an error naming some array, never a panic.
        let btf = sample();
        for e in MODELS {
            let m = e.fit_json(&btf.as_ref(), e.examples[0].1, &Monitor::new()).unwrap();
            let a = m.to_arrays();
            for (name, arr) in a.iter() {
                let mut shapes = vec![vec![0; arr.shape.len()]];
                if !arr.shape.is_empty() {
                    let mut s = arr.shape.clone();
                    s[0] = 0;
                    shapes.push(s);
                    let mut s = arr.shape.clone();
                    *s.last_mut().unwrap() = 0;
                    shapes.push(s);
                }
                for shape in shapes {
                    let mut b = a.clone();
                    let data = match arr.data {
                        btfrs_core::arrays::ArrayData::U8(_) => btfrs_core::arrays::ArrayData::U8(vec![]),
                        btfrs_core::arrays::ArrayData::U16(_) => btfrs_core::arrays::ArrayData::U16(vec![]),
                        btfrs_core::arrays::ArrayData::I32(_) => btfrs_core::arrays::ArrayData::I32(vec![]),
                        btfrs_core::arrays::ArrayData::F32(_) => btfrs_core::arrays::ArrayData::F32(vec![]),
                        btfrs_core::arrays::ArrayData::F64(_) => btfrs_core::arrays::ArrayData::F64(vec![]),
                    };
                    b.insert_checked(name, shape.clone(), data).unwrap();
                    assert!(from_arrays(e.kind, &b).is_err(), "{} {name} {shape:?}", e.kind);
                }
                let mut b = a.clone();
                b.put(name, &[1], vec![0u16]);
                assert!(from_arrays(e.kind, &b).is_err(), "{} {name} as u16", e.kind);
            }
        }
    }
}
