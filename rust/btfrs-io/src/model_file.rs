//! Fitted models in `.btfrs` containers: the container's `kind` is the model's registered name,
//! its arrays are the model's own [`NamedArrays`] (defined by the model, btfrs-fit), and `meta`
//! holds the fit report and whatever the caller adds (fit seconds). Any registered model saves
//! and loads through these two functions; nothing here names a model.

use crate::container::{self, as_bytes, from_bytes, ArrayRef, Dtype};
use btfrs_core::arrays::{ArrayData, NamedArrays};
use btfrs_core::{Error, Result};
use btfrs_fit::registry;
use btfrs_fit::DynModel;
use std::path::Path;

/// Write `model` atomically; `meta` (a JSON object, or null) is stored with its report under
/// `"report"`.
pub fn save_model(path: &Path, model: &dyn DynModel, meta: serde_json::Value) -> Result<()> {
    let mut meta = match meta {
        serde_json::Value::Null => serde_json::Map::new(),
        serde_json::Value::Object(m) => m,
        o => return Err(Error::arg("meta", format!("expected a JSON object, got {o}"))),
    };
    // The model's own report; what the caller's report adds beside it (a robust fit's screen,
    // which no model holds) is kept.
    let mut report = match model.report() {
        serde_json::Value::Object(m) => m,
        serde_json::Value::Null => serde_json::Map::new(),
        o => return Err(Error::arg("model", format!("a report must be a JSON object, got {o}"))),
    };
    if let Some(serde_json::Value::Object(extra)) = meta.get("report") {
        for (k, v) in extra {
            report.entry(k.clone()).or_insert_with(|| v.clone());
        }
    }
    let report = if report.is_empty() { serde_json::Value::Null } else { serde_json::Value::Object(report) };
    meta.insert("report".into(), report);
    save_arrays(path, model.kind(), serde_json::Value::Object(meta), &model.to_arrays())
}

/// Write named arrays as a container of `kind` (atomically).
pub fn save_arrays(path: &Path, kind: &str, meta: serde_json::Value, arrays: &NamedArrays) -> Result<()> {
    let refs: Vec<ArrayRef<'_>> = arrays
        .iter()
        .map(|(name, a)| {
            let (dtype, bytes) = match &a.data {
                ArrayData::U8(v) => (Dtype::U8, as_bytes(v)),
                ArrayData::U16(v) => (Dtype::U16, as_bytes(v)),
                ArrayData::I32(v) => (Dtype::I32, as_bytes(v)),
                ArrayData::F32(v) => (Dtype::F32, as_bytes(v)),
                ArrayData::F64(v) => (Dtype::F64, as_bytes(v)),
            };
            ArrayRef { name, dtype, shape: &a.shape, bytes }
        })
        .collect();
    container::write(path, kind, meta, &refs)
}

/// Read every array of a container: `(kind, meta, arrays)`.
pub fn load_arrays(path: &Path) -> Result<(String, serde_json::Value, NamedArrays)> {
    let c = container::read_contents(path)?;
    let shown = path.display().to_string();
    let mut out = NamedArrays::new();
    for info in &c.arrays {
        let bytes = container::read_array(path, info)?;
        let bad =
            || Error::format(&shown, format!("array {:?} has {} bytes, not whole elements", info.name, bytes.len()));
        let data = match info.dtype {
            Dtype::U8 | Dtype::Bool => ArrayData::U8(bytes),
            Dtype::U16 => ArrayData::U16(from_bytes(&bytes).ok_or_else(bad)?),
            Dtype::I32 => ArrayData::I32(from_bytes(&bytes).ok_or_else(bad)?),
            Dtype::F32 => ArrayData::F32(from_bytes(&bytes).ok_or_else(bad)?),
            Dtype::F64 => ArrayData::F64(from_bytes(&bytes).ok_or_else(bad)?),
        };
        out.insert_checked(&info.name, info.shape.clone(), data).map_err(|e| Error::format(&shown, e))?;
    }
    Ok((c.kind, c.meta, out))
}

/// Read a model written by [`save_model`]: the model and the file's `meta`. A file that holds
/// no registered model, or whose arrays do not make one, is a format error naming the file.
pub fn load_model(path: &Path) -> Result<(Box<dyn DynModel>, serde_json::Value)> {
    let shown = path.display().to_string();
    let (kind, meta, arrays) = load_arrays(path)?;
    registry::lookup(&kind).map_err(|_| Error::format(&shown, format!("holds a {kind:?}, not a fitted model")))?;
    let m = registry::from_arrays(&kind, &arrays).map_err(|e| Error::format(&shown, e))?;
    Ok((m, meta))
}

#[cfg(test)]
mod tests {
    use super::*;
    use btfrs_core::materials::{generate, MaterialSpec, Preset};
    use btfrs_core::Monitor;

    #[test]
    fn every_registered_model_round_trips_through_a_file() {
        let btf = generate(&MaterialSpec::new(Preset::Weave, 8, 1), &Monitor::new()).unwrap();
        let dir = tempfile::tempdir().unwrap();
        for e in registry::MODELS {
            let m = e.fit_json(&btf.as_ref(), e.examples[0].1, &Monitor::new()).unwrap();
            let p = dir.path().join(format!("{}.btfrs", e.kind));
            save_model(&p, m.as_ref(), serde_json::json!({"fit_seconds": 1.5})).unwrap();
            let (r, meta) = load_model(&p).unwrap();
            assert_eq!(r.kind(), e.kind);
            assert_eq!(r.to_arrays(), m.to_arrays());
            assert_eq!(meta["fit_seconds"], 1.5);
            assert_eq!(meta["report"], m.report());
            let v = [0.0, 0.0, 1.0];
            assert_eq!(r.evaluate_image(v, v).unwrap(), m.evaluate_image(v, v).unwrap());
        }
        // A BTF container is not a model.
        let p = dir.path().join("x.btfrs");
        save_arrays(&p, "btf", serde_json::json!({}), &NamedArrays::new()).unwrap();
        let e = load_model(&p).unwrap_err().to_string();
        assert!(e.contains("not a fitted model"), "{e}");
    }
}
