//! Scratch space a fit may move out of its memory limit: a zeroed `f32` buffer held in memory, or
//! in an unlinked temporary file mapped into memory. The mapped pages are file-backed, like a
//! memory-mapped BTF's: the kernel writes them to the file and drops them when memory runs short,
//! so they are not the process's anonymous memory that `memory_limit` bounds.
//!
//! Used for values a streaming fit must keep for every texel before a last step over all of them
//! (RBF's and bilinear's float coefficients, before the 8-bit quantization needs each plane's
//! range over all texels): on a BTF of 640² texels and 81 views they are 2.4 GB. The file lives in
//! the system's temporary directory (`TMPDIR`) and disappears with the buffer, also on a crash
//! (it is unlinked as soon as it is created).

use crate::{Error, Result};
use std::ops::{Deref, DerefMut};

/// A zeroed `f32` buffer (module doc).
#[derive(Debug)]
pub enum Floats {
    /// Held in memory.
    Memory(Vec<f32>),
    /// Held in an unlinked temporary file, mapped.
    File(memmap2::MmapMut),
}

impl Floats {
    /// `n` zeros, in a temporary file when `spill` (else in memory).
    pub fn zeros(n: usize, spill: bool) -> Result<Floats> {
        if !spill || n == 0 {
            return Ok(Floats::Memory(vec![0.0; n]));
        }
        let dir = std::env::temp_dir();
        let io = |e: std::io::Error| Error::io(format!("{} (temporary file)", dir.display()), e);
        let file = tempfile::tempfile_in(&dir).map_err(io)?;
        // A sparse file: the zeros take no space until written. The space it needs is reserved
        // up front where the file system can (posix_fallocate), so a full disk is an error here,
        // not a SIGBUS when a page is written later.
        let bytes = (n * 4) as u64;
        file.set_len(bytes).map_err(io)?;
        reserve(&file, bytes).map_err(io)?;
        // SAFETY: the file is ours alone (unlinked, never shared) and keeps its length while mapped.
        let map = unsafe { memmap2::MmapMut::map_mut(&file) }.map_err(io)?;
        Ok(Floats::File(map))
    }

    /// Whether the values live in a temporary file.
    pub fn spilled(&self) -> bool {
        matches!(self, Floats::File(_))
    }
}

#[cfg(target_os = "linux")]
fn reserve(file: &std::fs::File, bytes: u64) -> std::io::Result<()> {
    use std::os::fd::AsRawFd;
    extern "C" {
        fn posix_fallocate(fd: i32, offset: i64, len: i64) -> i32;
    }
    // SAFETY: a plain system call on an open descriptor we own.
    match unsafe { posix_fallocate(file.as_raw_fd(), 0, bytes as i64) } {
        0 => Ok(()),
        // A file system without it (EOPNOTSUPP, EINVAL): the sparse file stays as it is.
        95 | 22 => Ok(()),
        e => Err(std::io::Error::from_raw_os_error(e)),
    }
}

#[cfg(not(target_os = "linux"))]
fn reserve(_file: &std::fs::File, _bytes: u64) -> std::io::Result<()> {
    Ok(())
}

impl Deref for Floats {
    type Target = [f32];
    fn deref(&self) -> &[f32] {
        match self {
            Floats::Memory(v) => v,
            Floats::File(m) => bytemuck::cast_slice(&m[..]),
        }
    }
}

impl DerefMut for Floats {
    fn deref_mut(&mut self) -> &mut [f32] {
        match self {
            Floats::Memory(v) => v,
            Floats::File(m) => bytemuck::cast_slice_mut(&mut m[..]),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn both_kinds_hold_zeros_and_what_is_written() {
        for spill in [false, true] {
            let mut f = Floats::zeros(3000, spill).unwrap();
            assert_eq!(f.spilled(), spill);
            assert!(f.iter().all(|&x| x == 0.0));
            f.iter_mut().enumerate().for_each(|(i, x)| *x = i as f32 * 0.5);
            assert_eq!(f[2999], 1499.5);
            assert_eq!(f.iter().map(|&x| x as f64).sum::<f64>(), 0.5 * 2999.0 * 3000.0 / 2.0);
        }
        assert!(Floats::zeros(0, true).unwrap().is_empty());
    }
}
