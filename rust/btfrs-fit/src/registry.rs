//! The model registry: the one list of models. Everything that iterates over models (the
//! bindings, `btfrs.load`, the renderers, the demo, the bench) asks it, so a new model is
//! registered by one line in [`MODELS`] (see CONTRIBUTING.md).

use crate::model::{parse_options, DynModel, Model};
use btfrs_core::{BtfRef, Error, Monitor, NamedArrays, Result};

/// What the registry knows of one model, independent of its type.
#[derive(Debug, Clone, Copy)]
pub struct Entry {
    /// [`Model::KIND`].
    pub kind: &'static str,
    /// [`Model::DOC`].
    pub doc: &'static str,
    /// [`Model::RENDERERS`].
    pub renderers: &'static [&'static str],
    /// [`Model::EXAMPLES`].
    pub examples: &'static [(&'static str, &'static str)],
    /// Fit with options given as a JSON object.
    pub fit: fn(&BtfRef<'_>, &str, &Monitor) -> Result<Box<dyn DynModel>>,
    /// [`Model::from_arrays`].
    pub from_arrays: fn(&NamedArrays) -> Result<Box<dyn DynModel>>,
    /// The defaults of its options, for display (`{:?}` of `Options::default()`).
    pub default_options: fn() -> String,
    /// [`Model::shaders`].
    pub shaders: fn() -> Vec<crate::gpu::Shader>,
    /// [`Model::TEXEL_ARRAYS`].
    pub texel_arrays: &'static [&'static str],
    /// [`Model::SCANS_VALUES`]: the fit checks the values itself, in its own pass.
    pub scans_values: bool,
    /// [`Model::BLOCKWISE`].
    pub blockwise: crate::blockwise::Blockwise,
    /// Rebuild from the stitched arrays of a blockwise fit and [`Model::finish_blocks`] with
    /// options given as a JSON object (those of the whole fit, not the blocks').
    pub finish_blocks: fn(&NamedArrays, &str) -> Result<Box<dyn DynModel>>,
}

fn fit_erased<M: Model + std::fmt::Debug>(btf: &BtfRef<'_>, options: &str, mon: &Monitor) -> Result<Box<dyn DynModel>> {
    let (options, limit) = take_memory_limit(options)?;
    let o: M::Options = parse_options(&options)?;
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
    Ok(Box::new(M::fit(btf, &o, mon)?))
}

/// The option every fit takes besides its own: `memory_limit`, the anonymous memory in bytes
/// the fit may allocate besides the model it returns (out-of-core fitting of memory-mapped
/// BTFs); taken out of the JSON object before the model's options are parsed.
fn take_memory_limit(options: &str) -> Result<(String, Option<u64>)> {
    let Ok(serde_json::Value::Object(mut map)) = serde_json::from_str::<serde_json::Value>(options) else {
        return Ok((options.to_string(), None)); // parse_options reports it
    };
    let limit = match map.remove("memory_limit") {
        None | Some(serde_json::Value::Null) => None,
        Some(v) => match v.as_u64() {
            Some(b) if b > 0 => Some(b),
            _ => return Err(Error::arg("memory_limit", format!("expected a positive number of bytes, got {v}"))),
        },
    };
    Ok((serde_json::Value::Object(map).to_string(), limit))
}

fn from_arrays_erased<M: Model + std::fmt::Debug>(a: &NamedArrays) -> Result<Box<dyn DynModel>> {
    Ok(Box::new(M::from_arrays(a)?))
}

fn finish_blocks_erased<M: Model + std::fmt::Debug>(a: &NamedArrays, options: &str) -> Result<Box<dyn DynModel>> {
    let (options, _) = take_memory_limit(options)?;
    let o: M::Options = parse_options(&options)?;
    Ok(Box::new(M::from_arrays(a)?.finish_blocks(&o)?))
}

fn default_options<M: Model>() -> String {
    format!("{:?}", M::Options::default())
}

/// The registry entry of `M`.
pub const fn entry<M: Model + std::fmt::Debug>() -> Entry {
    Entry {
        kind: M::KIND,
        doc: M::DOC,
        renderers: M::RENDERERS,
        examples: M::EXAMPLES,
        fit: fit_erased::<M>,
        from_arrays: from_arrays_erased::<M>,
        default_options: default_options::<M>,
        shaders: M::shaders,
        texel_arrays: M::TEXEL_ARRAYS,
        scans_values: M::SCANS_VALUES,
        blockwise: M::BLOCKWISE,
        finish_blocks: finish_blocks_erased::<M>,
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
];

/// The entry of `kind`, or an error listing the registered models.
pub fn lookup(kind: &str) -> Result<&'static Entry> {
    MODELS.iter().find(|e| e.kind == kind).ok_or_else(|| {
        let names: Vec<String> = MODELS.iter().map(|e| format!("{:?}", e.kind)).collect();
        Error::arg("kind", format!("unknown model {kind:?}; expected one of {}", names.join(", ")))
    })
}

/// Fit model `kind` with options as a JSON object (`"{}"` for the defaults).
pub fn fit(kind: &str, btf: &BtfRef<'_>, options: &str, monitor: &Monitor) -> Result<Box<dyn DynModel>> {
    (lookup(kind)?.fit)(btf, options, monitor)
}

/// Rebuild model `kind` from its arrays.
pub fn from_arrays(kind: &str, arrays: &NamedArrays) -> Result<Box<dyn DynModel>> {
    (lookup(kind)?.from_arrays)(arrays)
}

/// Models whose value is linear in their per-texel arrays, so that averaging the arrays of a
/// block of texels averages their appearance exactly: what [`mip_texels`] accepts. (PTM's LRGB
/// variant multiplies two texel arrays; its average is exact for the RGB variant only.)
pub const AVERAGEABLE: &[&str] = &["ptm", "hsh", "sh", "rbf", "bilinear"];

/// The model extended by averaged texels (the coarse levels of a box-filtered mip pyramid):
/// texel `n + g` (n = the model's texel count) is `sum w x texel t` over `groups[g]`, which
/// may name earlier new texels. The result keeps the model's width and gains
/// `ceil(groups / width)` rows (the last padded with copies of texel 0), so every original texel
/// keeps its index. LPCA (linear within a cluster only) gets projected texels instead
/// ([`crate::lpca::Lpca::mip_texels`]). Errors: any other model not linear in its texel arrays
/// ([`AVERAGEABLE`]), a group naming a texel not yet defined ("groups").
pub fn mip_texels(model: &dyn DynModel, groups: &[Vec<(u32, f32)>]) -> Result<Box<dyn DynModel>> {
    let entry = lookup(model.kind())?;
    if let Some(lpca) = model.as_any().downcast_ref::<crate::lpca::Lpca>() {
        // Not linear across clusters: the mean appearance projected (Lpca::mip_texels).
        return Ok(Box::new(lpca.mip_texels(groups)?));
    }
    if !AVERAGEABLE.contains(&entry.kind) {
        return Err(Error::arg(
            "filter",
            format!("the {} model's parameters cannot be averaged (use medoid levels)", entry.kind),
        ));
    }
    let (h, w) = model.dims();
    let n = h * w;
    for (g, grp) in groups.iter().enumerate() {
        if let Some(&(bad, _)) = grp.iter().find(|(t, _)| *t as usize >= n + g) {
            return Err(Error::arg("groups", format!("group {g} names texel {bad}, not defined before it")));
        }
    }
    let rows = h + groups.len().div_ceil(w.max(1));
    let arrays = model.to_arrays();
    let mut out = NamedArrays::new();
    use btfrs_core::arrays::ArrayData as D;
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
    (entry.from_arrays)(&out)
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
            let m = (e.fit)(&b, e.examples[0].1, &Monitor::new()).unwrap();
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
                    let got = (e.fit)(&b, options, &Monitor::new()).unwrap_err().to_string();
                    assert_eq!(got, want, "{label}, non-finite at {at}");
                }
            }
        }
    }

    #[test]
    fn nbytes_is_what_the_default_renderer_uploads() {
        // Counted independently from the renderer's own parts: the words it uploads, plus the
        // 3D texture of renderers that have one.
        let btf = sample();
        for e in MODELS {
            let m = (e.fit)(&btf.as_ref(), e.examples[0].1, &Monitor::new()).unwrap();
            let r = m.renderer(e.renderers[0], 2048).unwrap();
            let words: usize = r.gpu_parts().iter().map(|p| p.len()).sum();
            assert_eq!(m.nbytes(), 4 * words + r.gpu_volume().map_or(0, |v| v.texels.len()), "{}", e.kind);
        }
    }

    #[test]
    fn options_errors_name_the_option() {
        let btf = sample();
        let b = btf.as_ref();
        let err = |kind: &str, o: &str| fit(kind, &b, o, &Monitor::new()).unwrap_err().to_string();
        assert!(err("lafortune", r#"{"lobes": 2.9}"#).starts_with("lobes: invalid type: floating point `2.9`"));
        assert!(err("lpca", r#"{"clusters": -1}"#).starts_with("clusters: invalid value: integer `-1`"));
        assert!(err("ptm", r#"{"knd": "rgb"}"#).starts_with("knd: unknown field `knd`"));
        assert!(err("ptm", r#"{"kind": "xyz"}"#).starts_with("kind: unknown variant `xyz`"));
        assert!(err("srf", r#"{"x": 1}"#).starts_with("x: unknown field `x`"));
        assert!(err("nope", "{}").contains("unknown model \"nope\""));
        assert!(err("ptm", "[1]").starts_with("options: expected a JSON object"));
    }

    #[test]
    fn corrupted_arrays_are_errors_not_panics() {
        // Every array of every model, replaced by an empty one, a wrong-dtype one, and dropped:
        // each rebuild is an error naming some array, never a panic.
        let btf = sample();
        for e in MODELS {
            let m = (e.fit)(&btf.as_ref(), e.examples[0].1, &Monitor::new()).unwrap();
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
