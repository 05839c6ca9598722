//! The file formats of other tools that models are written as and read from (`.ptm`, `.rti`):
//! one [`Format`] per format, declared in that format's own file, listed in [`FORMATS`]. A model
//! names the formats it exports ([`btfrs_fit::Model::EXPORTS`]); the bindings, `btfrs.load`,
//! `model.export(...)` and the CLI go through this table and never name a model.

use btfrs_core::{Error, Result};
use btfrs_fit::DynModel;
use std::path::Path;

use crate::capture::Limits;
use crate::untrusted::{self, TextKind};

/// What reading another tool's file gives: the model, and one warning per kind of value the
/// reader changed ([`crate::untrusted::Repairs`]).
#[derive(Debug)]
pub struct Imported {
    /// The model read.
    pub model: Box<dyn DynModel>,
    /// Summary warnings, each naming the file.
    pub warnings: Vec<String>,
}

impl Imported {
    /// A model read without repairs.
    pub fn model(model: Box<dyn DynModel>) -> Imported {
        Imported { model, warnings: Vec::new() }
    }
}

/// One file format of another tool.
#[derive(Debug, Clone, Copy)]
pub struct Format {
    /// Its name, as models list it in `EXPORTS` (`"ptm"`).
    pub name: &'static str,
    /// The file extension, without the dot.
    pub extension: &'static str,
    /// One line: what the format is and which tools read it.
    pub doc: &'static str,
    /// Whether a model is written as a folder (holding the [`Format::index`] file, which is
    /// what [`Format::import`] and `btfrs.load` are given), not as one file.
    pub folder: bool,
    /// The index file of a folder format (`info.json`, `scene.xml`); empty for one-file formats.
    pub index: &'static str,
    /// Write view slot `view` of a model as this format; returns what the writer chose (the
    /// quantization's scales and biases) as a JSON object.
    pub export: fn(&dyn DynModel, usize, &Path) -> Result<serde_json::Value>,
    /// Read a file of this format as a one-slot model (view = the normal), within `limits`
    /// (`max_bytes`: the most bytes the reader allocates, its index file's parse included).
    pub import: fn(&Path, &Limits) -> Result<Imported>,
}

/// Every format, in the order `btfrs.load` tries extensions.
/// relight's folder comes before NeuralRTI's: both are an `info.json`, and relight's reader
/// hands a `"neural"` one to NeuralRTI's.
pub const FORMATS: &[Format] = &[
    crate::ptm_file::FORMAT,
    crate::rti_file::FORMAT,
    crate::relight_file::FORMAT,
    crate::neuralrti_file::FORMAT,
    crate::gltf_file::FORMAT,
    crate::mitsuba_file::FORMAT,
];

/// The format named `name`.
pub fn lookup(name: &str) -> Result<&'static Format> {
    FORMATS.iter().find(|f| f.name == name).ok_or_else(|| {
        let names: Vec<String> = FORMATS.iter().map(|f| format!("{:?}", f.name)).collect();
        Error::arg("format", format!("unknown format {name:?}; expected one of {}", names.join(", ")))
    })
}

/// The format of a file, by its extension (case-insensitive), if it is one of [`FORMATS`].
pub fn of_path(path: &Path) -> Option<&'static Format> {
    let ext = path.extension()?.to_str()?.to_ascii_lowercase();
    FORMATS.iter().find(|f| f.extension == ext)
}

/// Read `path` as the format its extension names ([`of_path`]) within `limits`. Whatever a
/// file's values make a model refuse is an [`Error::Format`] naming the file.
pub fn import(path: &Path, limits: &Limits) -> Result<Imported> {
    let f = of_path(path).ok_or_else(|| {
        let list: Vec<String> = FORMATS.iter().map(|f| format!(".{}", f.extension)).collect();
        Error::arg("path", format!("{}: expected a file ending in {}", path.display(), list.join(" or ")))
    })?;
    let shown = path.display().to_string();
    (f.import)(path, limits).map_err(untrusted::as_format(&shown, "values"))
}

/// Write view slot `view` of `model` as `format`: an error naming `format` when the model does
/// not export it, and for a folder format, an error naming `path` when its folder exists and
/// holds anything, unless `force` (then the folder's files are replaced, each atomically).
pub fn export(model: &dyn DynModel, format: &str, view: usize, path: &Path, force: bool) -> Result<serde_json::Value> {
    let f = lookup(format)?;
    let exports = btfrs_fit::registry::lookup(model.kind())?.exports;
    if !exports.contains(&f.name) {
        let list: Vec<String> = exports.iter().map(|e| format!("{e:?}")).collect();
        let can = if list.is_empty() { "none".to_string() } else { list.join(", ") };
        return Err(Error::arg(
            "format",
            format!("the {} model cannot be written as {format:?} (its formats: {can})", model.kind()),
        ));
    }
    if f.folder && !force {
        let dir = f.folder_of(path);
        if dir.is_file() {
            return Err(Error::arg("path", format!("{} is a file; expected a folder", dir.display())));
        }
        if std::fs::read_dir(&dir).is_ok_and(|mut d| d.next().is_some()) {
            return Err(Error::arg(
                "path",
                format!(
                    "{} exists and is not empty; pass force=True (--force on the command line) to write into it",
                    dir.display()
                ),
            ));
        }
    }
    (f.export)(model, view, path)
}

impl Format {
    /// The folder of a folder format's `path`: itself, or its parent when it names the index file.
    pub fn folder_of(&self, path: &Path) -> std::path::PathBuf {
        if !self.index.is_empty() && path.file_name().is_some_and(|n| n == self.index) {
            path.parent().map(Path::to_path_buf).unwrap_or_default()
        } else {
            path.to_path_buf()
        }
    }
}

/// The concrete model inside `model`, for a format's own writer; an error naming `model` when
/// it is another kind (the registry's exports keep that from happening).
pub(crate) fn concrete<'a, M: 'static>(model: &'a dyn DynModel, what: &str) -> Result<&'a M> {
    model
        .as_any()
        .downcast_ref::<M>()
        .ok_or_else(|| Error::arg("model", format!("expected {what}, got a {} model", model.kind())))
}

/// The index file of a folder format's `path` (the folder, or the index file itself) and its
/// folder, read as [`untrusted::read_text`] reads a text of `kind` (a regular file within the
/// kind's cap and `max_bytes`, UTF-8): `(folder, shown name, text)`.
pub(crate) fn read_index(
    path: &Path,
    index: &str,
    kind: TextKind,
    max_bytes: u64,
) -> Result<(std::path::PathBuf, String, String)> {
    let (dir, file) = if path.is_dir() {
        (path.to_path_buf(), path.join(index))
    } else {
        (path.parent().map(Path::to_path_buf).unwrap_or_default(), path.to_path_buf())
    };
    let dir = if dir.as_os_str().is_empty() { std::path::PathBuf::from(".") } else { dir };
    let shown = file.display().to_string();
    let text = untrusted::read_text(&file, kind, max_bytes)?;
    Ok((dir, shown, text))
}

/// Whether `name` (a map's file name from an index file) is a plain name in its folder: one
/// normal path component, no URI scheme or escapes, so a reader never leaves the folder.
pub(crate) fn plain_name(name: &str) -> bool {
    let p = Path::new(name);
    p.components().count() == 1
        && matches!(p.components().next(), Some(std::path::Component::Normal(_)))
        && !name.contains(':')
        && !name.contains('%')
}

/// Unit normals from a normal map's `(n + 1) / 2` encoding (`[t][3]`, x and y times `scale`),
/// an [`Error::Format`] naming `shown` and `what` for a texel whose normal does not face out.
pub(crate) fn decode_normals(encoded: &[f32], scale: f64, shown: &str, what: &str) -> Result<Vec<f32>> {
    let mut out = vec![0.0f32; encoded.len()];
    for (i, (e, o)) in encoded.chunks_exact(3).zip(out.chunks_exact_mut(3)).enumerate() {
        let v = [scale * (2.0 * e[0] as f64 - 1.0), scale * (2.0 * e[1] as f64 - 1.0), 2.0 * e[2] as f64 - 1.0];
        let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        if !(l > 1e-6 && v[2] > 0.0) {
            return Err(Error::format(shown, format!("{what}: the normal at pixel {i} is {v:?}, not facing out")));
        }
        for c in 0..3 {
            o[c] = (v[c] / l) as f32;
        }
    }
    Ok(out)
}
