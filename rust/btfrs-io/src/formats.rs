//! The file formats of other tools that models are written as and read from (`.ptm`, `.rti`):
//! one [`Format`] per format, declared in that format's own file, listed in [`FORMATS`]. A model
//! names the formats it exports ([`btfrs_fit::Model::EXPORTS`]); the bindings, `btfrs.load`,
//! `model.export(...)` and the CLI go through this table and never name a model.

use btfrs_core::{Error, Result};
use btfrs_fit::DynModel;
use std::path::Path;

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
    /// Read a file of this format as a one-slot model (view = the normal).
    pub import: fn(&Path) -> Result<Box<dyn DynModel>>,
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
