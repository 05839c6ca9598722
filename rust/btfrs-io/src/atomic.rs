//! Writing files so that a failure never leaves a half-written target.
//!
//! The bytes go to a uniquely named temporary file in the target's directory (so the rename
//! cannot cross file systems), are synced, and the file is then renamed over the target; on any
//! error the temporary file is removed and the target is untouched.

use btfrs_core::{Error, Result};
use std::fs::{self, OpenOptions};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Write `path` through `fill`, atomically (temporary file + rename).
pub fn write_atomic(path: &Path, fill: impl FnOnce(&mut dyn Write) -> std::io::Result<()>) -> Result<()> {
    let (shown, tmp, file) = temp_beside(path)?;
    let mut w = BufWriter::with_capacity(1 << 20, file);
    let result = fill(&mut w)
        .and_then(|()| w.into_inner().map_err(|e| e.into_error()))
        .and_then(|f| f.sync_all())
        .and_then(|()| fs::rename(&tmp, path));
    if let Err(e) = result {
        // Best effort: the original error is what the caller needs to see.
        let _ = fs::remove_file(&tmp);
        return Err(Error::io(shown, e));
    }
    Ok(())
}

/// Write `path` atomically through `fill`, which gets the temporary file itself (to size it,
/// write at offsets or memory-map it). An error from `fill` (its own, typed: a format error of
/// an input, a cancel) removes the temporary file and is returned unchanged.
pub fn write_atomic_file(path: &Path, fill: impl FnOnce(&fs::File) -> Result<()>) -> Result<()> {
    let (shown, tmp, file) = temp_beside(path)?;
    let result = fill(&file)
        .and_then(|()| file.sync_all().and_then(|()| fs::rename(&tmp, path)).map_err(|e| Error::io(&shown, e)));
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    result
}

/// The target as shown in errors, and a new temporary file in its directory.
fn temp_beside(path: &Path) -> Result<(String, PathBuf, fs::File)> {
    let shown = path.display().to_string();
    let file_name = path.file_name().ok_or_else(|| Error::arg("path", format!("{shown} does not name a file")))?;
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let (tmp, file) = create_temp(&dir, &file_name.to_string_lossy()).map_err(|e| Error::io(&shown, e))?;
    Ok((shown, tmp, file))
}

/// Create a new, uniquely named temporary file next to the target. `create_new` makes sure we
/// never truncate somebody else's file; a name clash just moves on to the next name.
fn create_temp(dir: &Path, name: &str) -> std::io::Result<(PathBuf, fs::File)> {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let pid = std::process::id();
    let mut last_err = None;
    for _ in 0..100 {
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let tmp = dir.join(format!(".{name}.{pid}.{n}.tmp"));
        // Readable too: a streamed container memory-maps it (mmap needs a readable descriptor).
        match OpenOptions::new().read(true).write(true).create_new(true).open(&tmp) {
            Ok(f) => return Ok((tmp, f)),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => last_err = Some(e),
            Err(e) => return Err(e),
        }
    }
    Err(last_err.unwrap_or_else(|| std::io::Error::other("could not create a temporary file")))
}
