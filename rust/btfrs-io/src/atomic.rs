//! Writing files so that a failure never leaves a half-written target.
//!
//! The bytes go to a uniquely named temporary file in the target's directory (so the rename
//! cannot cross file systems), are synced, and the file is then renamed over the target; on any
//! error the temporary file is removed and the target is untouched.
//!
//! A writer killed outright (SIGKILL, a power cut) cannot remove its temporary file, so the name
//! says whose it is: `.{target}.{pid}.{n}.btfrs-tmp`. Every write first removes the temporary
//! files in its directory whose process no longer runs ([`sweep_stale`]); Python's
//! `btfrs.io.atomic_write` names and sweeps them the same way.

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
    sweep_stale(&dir);
    let (tmp, file) = create_temp(&dir, &file_name.to_string_lossy()).map_err(|e| Error::io(&shown, e))?;
    Ok((shown, tmp, file))
}

/// Write the folder `path` through `fill`, atomically: `fill` writes into a new temporary
/// folder beside it (named as the temporary files are), which is then renamed to `path`. An
/// existing `path` (a folder, a file or a link) is replaced only with `replace` (else an
/// [`Error::InvalidArgument`] naming it, before anything is written); on any error the
/// temporary folder is removed and `path` is untouched.
pub fn write_folder<T>(path: &Path, replace: bool, fill: impl FnOnce(&Path) -> Result<T>) -> Result<T> {
    let shown = path.display().to_string();
    let exists = fs::symlink_metadata(path).is_ok();
    if exists && !replace {
        return Err(Error::arg("path", format!("{shown} exists; pass force=True (--force) to replace it")));
    }
    let name = path.file_name().ok_or_else(|| Error::arg("path", format!("{shown} does not name a folder")))?;
    let parent = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    fs::create_dir_all(&parent).map_err(|e| Error::io(parent.display(), e))?;
    sweep_stale(&parent);
    let tmp = create_temp_dir(&parent, &name.to_string_lossy()).map_err(|e| Error::io(&shown, e))?;
    let result = fill(&tmp).and_then(|v| {
        let old = fs::symlink_metadata(path);
        if let Ok(meta) = old {
            let r = if meta.is_dir() { fs::remove_dir_all(path) } else { fs::remove_file(path) };
            r.map_err(|e| Error::io(&shown, e))?;
        }
        fs::rename(&tmp, path).map_err(|e| Error::io(&shown, e))?;
        Ok(v)
    });
    if result.is_err() {
        let _ = fs::remove_dir_all(&tmp);
    }
    result
}

fn create_temp_dir(dir: &Path, name: &str) -> std::io::Result<PathBuf> {
    let pid = std::process::id();
    let mut last_err = None;
    for _ in 0..100 {
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let tmp = dir.join(format!(".{name}.{pid}.{n}{TEMP_SUFFIX}"));
        match fs::create_dir(&tmp) {
            Ok(()) => return Ok(tmp),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => last_err = Some(e),
            Err(e) => return Err(e),
        }
    }
    Err(last_err.unwrap_or_else(|| std::io::Error::other("could not create a temporary folder")))
}

static COUNTER: AtomicU64 = AtomicU64::new(0);

/// The suffix of btfrs's temporary files.
pub const TEMP_SUFFIX: &str = ".btfrs-tmp";

/// The process id a temporary file name of btfrs carries: `.{name}.{pid}.{n}.btfrs-tmp`, or the
/// `.{name}.{pid}.{n}.tmp` of earlier versions. `None` for any other name.
pub fn temp_owner(file_name: &str) -> Option<u32> {
    let stem = file_name
        .strip_suffix(TEMP_SUFFIX)
        .or_else(|| file_name.strip_suffix(".tmp"))
        .filter(|_| file_name.starts_with('.'))?;
    let mut parts = stem.rsplitn(3, '.');
    let n = parts.next()?;
    let pid = parts.next()?;
    let name = parts.next()?;
    if name.len() < 2 || n.is_empty() || !n.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    pid.parse().ok()
}

/// Remove the temporary files of btfrs writers in `dir` whose process is gone (killed before it
/// could clean up). Only where the system says which processes run (Linux's `/proc`); a file of
/// a running process, this one included, is never touched. Best effort: errors are ignored (the
/// write itself does not depend on it).
pub fn sweep_stale(dir: &Path) {
    let proc = Path::new("/proc/self");
    if !proc.exists() {
        return;
    }
    let Ok(entries) = fs::read_dir(dir) else { return };
    for e in entries.flatten() {
        let name = e.file_name();
        let Some(pid) = name.to_str().and_then(temp_owner) else { continue };
        if pid != std::process::id() && !Path::new("/proc").join(pid.to_string()).exists() {
            // A folder writer's temporary folder ([`write_folder`]) or a file.
            if e.file_type().is_ok_and(|t| t.is_dir()) {
                let _ = fs::remove_dir_all(e.path());
            } else {
                let _ = fs::remove_file(e.path());
            }
        }
    }
}

/// Create a new, uniquely named temporary file next to the target. `create_new` makes sure we
/// never truncate somebody else's file; a name clash just moves on to the next name.
fn create_temp(dir: &Path, name: &str) -> std::io::Result<(PathBuf, fs::File)> {
    let pid = std::process::id();
    let mut last_err = None;
    for _ in 0..100 {
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let tmp = dir.join(format!(".{name}.{pid}.{n}{TEMP_SUFFIX}"));
        // Readable too: a streamed container memory-maps it (mmap needs a readable descriptor).
        match OpenOptions::new().read(true).write(true).create_new(true).open(&tmp) {
            Ok(f) => return Ok((tmp, f)),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => last_err = Some(e),
            Err(e) => return Err(e),
        }
    }
    Err(last_err.unwrap_or_else(|| std::io::Error::other("could not create a temporary file")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn temporary_names_say_whose_they_are_and_stale_ones_are_swept() {
        assert_eq!(temp_owner(".fit_ptm.btfrs.4242.0.btfrs-tmp"), Some(4242));
        assert_eq!(temp_owner(".a.7.12.tmp"), Some(7));
        for other in ["fit.btfrs", ".a.b.tmp", "a.7.1.tmp", ".7.1.tmp", ".a.7.x.btfrs-tmp", ".a.7.1.btfrs-tmpx"] {
            assert_eq!(temp_owner(other), None, "{other}");
        }
        let dir = tempfile::tempdir().unwrap();
        // A dead writer's file (pid 2^22 + 1 is above Linux's largest pid_max), a live one's
        // (ours), an unrelated hidden file: the next write removes only the first.
        let dead = dir.path().join(".x.btfrs.4194305.0.btfrs-tmp");
        let ours = dir.path().join(format!(".y.btfrs.{}.99.btfrs-tmp", std::process::id()));
        let other = dir.path().join(".z.tmp");
        for p in [&dead, &ours, &other] {
            fs::write(p, b"x").unwrap();
        }
        write_atomic(&dir.path().join("t.bin"), |w| w.write_all(b"ok")).unwrap();
        assert!(!dead.exists() || !Path::new("/proc/self").exists());
        assert!(ours.exists() && other.exists());
        assert_eq!(fs::read(dir.path().join("t.bin")).unwrap(), b"ok");
    }
}
