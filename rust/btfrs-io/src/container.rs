//! The `.btfrs` container: one file holding a BTF or a fitted model.
//!
//! Layout: 8 bytes of magic `BTFRS01\n`, the header length as a little-endian u64, a UTF-8 JSON
//! header, zero padding up to a multiple of 64 bytes, then the arrays, each starting on a 64-byte
//! boundary. The header names the content (`kind`), carries free-form `meta` (directions, model
//! parameters) and lists every array with its dtype, shape and offset from the start of the data.
//! Arrays are stored raw and little-endian, so a reader can memory-map them (numpy.memmap) instead
//! of reading a 1 GB BTF into memory. Files are written atomically ([`crate::atomic`]).
//!
//! The writer scans every float array once and records `"finite": true` in its header entry
//! when no value is NaN or infinite (`false` otherwise), so a reader that maps a large array can
//! trust the flag instead of reading every page to check. The flag is only as true as the file:
//! an array edited or corrupted after writing still reads cleanly, with whatever values it now
//! holds, and files written before the flag existed have none (readers scan those). Integer
//! arrays carry no flag.
//!
//! The reader checks everything the header claims against the file before it allocates: the
//! header length, every array's size (checked arithmetic) and extent, and that the arrays lie
//! after the header, so a corrupted or crafted file is a [`Error::Format`], never a huge
//! allocation or a read past the end.

use crate::atomic::write_atomic;
use btfrs_core::{Error, Result};
use serde::{Deserialize, Serialize};
use std::io::{Read, Seek, SeekFrom};
use std::os::unix::fs::FileExt;
use std::path::Path;

/// The first eight bytes of every `.btfrs` file.
pub const MAGIC: &[u8; 8] = b"BTFRS01\n";
const ALIGN: u64 = 64;

/// Element types the container stores.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Dtype {
    /// float32
    F32,
    /// float64
    F64,
    /// uint8
    U8,
    /// uint16
    U16,
    /// int32
    I32,
    /// bool, one byte each
    Bool,
}

impl Dtype {
    /// Bytes per element.
    pub fn size(self) -> usize {
        match self {
            Dtype::F32 | Dtype::I32 => 4,
            Dtype::F64 => 8,
            Dtype::U8 | Dtype::Bool => 1,
            Dtype::U16 => 2,
        }
    }
}

/// One array to write: raw little-endian bytes plus what they mean.
#[derive(Debug, Clone, Copy)]
pub struct ArrayRef<'a> {
    /// Name, unique in the file.
    pub name: &'a str,
    /// Element type.
    pub dtype: Dtype,
    /// Shape; the product times the dtype size must equal `bytes.len()`.
    pub shape: &'a [usize],
    /// The data.
    pub bytes: &'a [u8],
}

/// Where an array lies in a file.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ArrayInfo {
    /// Name.
    pub name: String,
    /// Element type.
    pub dtype: Dtype,
    /// Shape.
    pub shape: Vec<usize>,
    /// Absolute byte offset in the file.
    pub offset: u64,
    /// Length in bytes.
    pub nbytes: u64,
    /// Float arrays: whether the writer found every value finite (see the module doc). `None`
    /// for integer arrays and for files written before the flag existed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub finite: Option<bool>,
}

#[derive(Serialize, Deserialize)]
struct Header {
    kind: String,
    meta: serde_json::Value,
    arrays: Vec<ArrayInfo>,
}

/// A container's header: what it holds and where.
#[derive(Debug, Clone)]
pub struct Contents {
    /// What the file holds ("btf", "ptm", ...).
    pub kind: String,
    /// Free-form metadata.
    pub meta: serde_json::Value,
    /// The arrays, with absolute offsets.
    pub arrays: Vec<ArrayInfo>,
}

impl Contents {
    /// The array called `name`, or a format error naming the file.
    pub fn array(&self, path: &Path, name: &str) -> Result<&ArrayInfo> {
        self.arrays
            .iter()
            .find(|a| a.name == name)
            .ok_or_else(|| Error::format(path.display(), format!("no array named {name:?} in this {} file", self.kind)))
    }
}

fn align(x: u64) -> u64 {
    x.div_ceil(ALIGN) * ALIGN
}

/// Whether every value of a float array is finite (`None` for integer dtypes). Looks at the
/// exponent bits only (all ones means NaN or infinity), which needs no float decoding.
fn all_finite(dtype: Dtype, bytes: &[u8]) -> Option<bool> {
    match dtype {
        Dtype::F32 => Some(bytes.chunks_exact(4).all(|c| {
            let b = u32::from_le_bytes(c.try_into().expect("4 bytes"));
            b & 0x7f80_0000 != 0x7f80_0000
        })),
        Dtype::F64 => Some(bytes.chunks_exact(8).all(|c| {
            let b = u64::from_le_bytes(c.try_into().expect("8 bytes"));
            b & 0x7ff0_0000_0000_0000 != 0x7ff0_0000_0000_0000
        })),
        Dtype::U8 | Dtype::U16 | Dtype::I32 | Dtype::Bool => None,
    }
}

/// Check each array's byte length against its shape and the names' uniqueness, and lay the
/// arrays out: `(infos with offsets relative to the data start, header bytes, data start)`.
/// (name, dtype, shape, bytes, finite flag) of an array to lay out.
type Spec<'a> = (&'a str, Dtype, &'a [usize], usize, Option<bool>);

fn plan(kind: &str, meta: &serde_json::Value, specs: &[Spec<'_>]) -> Result<(Vec<ArrayInfo>, Vec<u8>, u64)> {
    if !meta.is_object() {
        return Err(Error::arg("meta", format!("expected a JSON object, got {meta}")));
    }
    let mut infos = Vec::with_capacity(specs.len());
    let mut rel = 0u64;
    for &(name, dtype, shape, nbytes, finite) in specs {
        let n = shape.iter().try_fold(dtype.size(), |acc, &s| acc.checked_mul(s));
        if n != Some(nbytes) {
            return Err(Error::arg(
                name,
                format!(
                    "shape {shape:?} of {dtype:?} needs {} bytes, got {nbytes}",
                    n.map_or_else(|| "more than 2^64".into(), |n| n.to_string()),
                ),
            ));
        }
        if infos.iter().any(|i: &ArrayInfo| i.name == name) {
            return Err(Error::arg(name, "array name used twice"));
        }
        infos.push(ArrayInfo {
            name: name.into(),
            dtype,
            shape: shape.to_vec(),
            offset: rel,
            nbytes: nbytes as u64,
            finite,
        });
        rel = align(rel + nbytes as u64);
    }
    // Offsets are stored absolute; they depend on the header length, which depends on the
    // offsets' digits. Iterate until the data start no longer moves (at most a few rounds).
    let mut data_start = 0u64;
    loop {
        let abs: Vec<ArrayInfo> =
            infos.iter().map(|i| ArrayInfo { offset: i.offset + data_start, ..i.clone() }).collect();
        let h = Header { kind: kind.into(), meta: meta.clone(), arrays: abs };
        let text = serde_json::to_vec(&h).map_err(|e| Error::arg("meta", e))?;
        let start = align(16 + text.len() as u64);
        if start == data_start {
            return Ok((infos, text, data_start));
        }
        data_start = start;
    }
}

/// Write a container atomically. `meta` must be a JSON object. Float arrays are scanned once
/// for their `finite` flag before anything is written.
pub fn write(path: &Path, kind: &str, meta: serde_json::Value, arrays: &[ArrayRef<'_>]) -> Result<()> {
    let specs: Vec<_> =
        arrays.iter().map(|a| (a.name, a.dtype, a.shape, a.bytes.len(), all_finite(a.dtype, a.bytes))).collect();
    let (infos, header, data_start) = plan(kind, &meta, &specs)?;
    write_atomic(path, |w| {
        w.write_all(MAGIC)?;
        w.write_all(&(header.len() as u64).to_le_bytes())?;
        w.write_all(&header)?;
        let mut pos = 16 + header.len() as u64;
        let zeros = [0u8; ALIGN as usize];
        for (a, info) in arrays.iter().zip(&infos) {
            let at = data_start + info.offset;
            w.write_all(&zeros[..(at - pos) as usize])?;
            w.write_all(a.bytes)?;
            pos = at + a.bytes.len() as u64;
        }
        Ok(())
    })
}

/// Write a container whose first array, `name` (float32, `shape`), is too large to hold in
/// memory twice: the file is created at its final size, the array's region is memory-mapped
/// and `fill` writes the values in place (zero-initialised), then the small `arrays` follow.
/// Atomic like [`write`]: on any error from `fill` (or a cancel) the temporary file is removed
/// and that error returned. `fill` must produce finite values only (the header records the
/// array as finite without a second pass: the loaders check every value as they decode it).
pub fn write_streamed(
    path: &Path,
    kind: &str,
    meta: serde_json::Value,
    name: &str,
    shape: &[usize],
    arrays: &[ArrayRef<'_>],
    fill: impl FnOnce(&mut [f32]) -> Result<()>,
) -> Result<()> {
    let count = shape.iter().try_fold(1usize, |a, &s| a.checked_mul(s));
    let nbytes = count
        .and_then(|c| c.checked_mul(4))
        .ok_or_else(|| Error::arg(name, format!("shape {shape:?} is too large")))?;
    let mut specs = vec![(name, Dtype::F32, shape, nbytes, Some(true))];
    specs.extend(arrays.iter().map(|a| (a.name, a.dtype, a.shape, a.bytes.len(), all_finite(a.dtype, a.bytes))));
    let (infos, header, data_start) = plan(kind, &meta, &specs)?;
    let last = infos.last().expect("at least the streamed array");
    let total = data_start + last.offset + last.nbytes;
    crate::atomic::write_atomic_file(path, |file| {
        let shown = path.display().to_string();
        let io = |e| Error::io(&shown, e);
        file.set_len(total).map_err(io)?;
        let mut head = Vec::with_capacity(data_start as usize);
        head.extend_from_slice(MAGIC);
        head.extend_from_slice(&(header.len() as u64).to_le_bytes());
        head.extend_from_slice(&header);
        file.write_all_at(&head, 0).map_err(io)?;
        for (a, info) in arrays.iter().zip(&infos[1..]) {
            file.write_all_at(a.bytes, data_start + info.offset).map_err(io)?;
        }
        if nbytes > 0 {
            // SAFETY: the file is our own freshly created temporary (create_new, not yet
            // renamed into place), so no other process maps or truncates it while we write.
            let mut map =
                unsafe { memmap2::MmapOptions::new().offset(data_start).len(nbytes).map_mut(file).map_err(io)? };
            let values: &mut [f32] = bytemuck_f32(&mut map);
            fill(values)?;
            map.flush().map_err(io)?;
        } else {
            fill(&mut [])?;
        }
        Ok(())
    })
}

/// The mapped bytes as f32 (the offset is a multiple of 64 and pages are aligned, so the
/// cast is aligned; checked anyway).
fn bytemuck_f32(bytes: &mut [u8]) -> &mut [f32] {
    assert!(bytes.as_ptr().align_offset(4) == 0 && bytes.len().is_multiple_of(4), "mapped region is f32-aligned");
    // SAFETY: alignment and length checked above; every bit pattern is a valid f32.
    unsafe { std::slice::from_raw_parts_mut(bytes.as_mut_ptr().cast::<f32>(), bytes.len() / 4) }
}

/// Read a container's header (the arrays stay on disk).
pub fn read_contents(path: &Path) -> Result<Contents> {
    let shown = &path.display().to_string();
    let (mut f, len) = crate::untrusted::open(path)?;
    let mut head = [0u8; 16];
    f.read_exact(&mut head).map_err(|_| Error::format(shown, "too short to be a .btfrs file"))?;
    if &head[..8] != MAGIC {
        return Err(Error::format(shown, "not a .btfrs file (bad magic bytes)"));
    }
    let hlen = u64::from_le_bytes(head[8..16].try_into().expect("8 bytes"));
    if hlen > len.saturating_sub(16) || hlen > 1 << 30 {
        return Err(Error::format(shown, format!("header length {hlen} exceeds the file ({len} bytes)")));
    }
    let mut text = vec![0u8; hlen as usize];
    f.read_exact(&mut text).map_err(|e| Error::io(shown, e))?;
    let h: Header = serde_json::from_slice(&text).map_err(|e| Error::format(shown, format!("bad header: {e}")))?;
    if !h.meta.is_object() {
        return Err(Error::format(shown, "bad header: meta is not a JSON object"));
    }
    let data_start = 16 + hlen;
    let mut names = std::collections::HashSet::with_capacity(h.arrays.len());
    for a in &h.arrays {
        // Checked arithmetic: a crafted header must not wrap around into a "consistent" size.
        let n = a.shape.iter().try_fold(a.dtype.size() as u64, |acc, &s| acc.checked_mul(s as u64));
        if n != Some(a.nbytes) || a.offset < data_start || a.offset.checked_add(a.nbytes).is_none_or(|end| end > len) {
            return Err(Error::format(shown, format!("array {:?} is truncated or inconsistent", a.name)));
        }
        if !names.insert(a.name.as_str()) {
            return Err(Error::format(shown, format!("array {:?} is listed twice", a.name)));
        }
    }
    Ok(Contents { kind: h.kind, meta: h.meta, arrays: h.arrays })
}

/// Read one array's bytes.
pub fn read_array(path: &Path, info: &ArrayInfo) -> Result<Vec<u8>> {
    let shown = &path.display().to_string();
    let (mut f, _) = crate::untrusted::open(path)?;
    f.seek(SeekFrom::Start(info.offset)).map_err(|e| Error::io(shown, e))?;
    let mut buf = vec![0u8; info.nbytes as usize];
    f.read_exact(&mut buf).map_err(|e| Error::io(shown, e))?;
    Ok(buf)
}

/// View a slice of plain numbers as little-endian bytes (all supported targets are little-endian).
pub fn as_bytes<T: Plain>(x: &[T]) -> &[u8] {
    // SAFETY: `Plain` types have no padding and every bit pattern is a valid u8.
    unsafe { std::slice::from_raw_parts(x.as_ptr() as *const u8, std::mem::size_of_val(x)) }
}

/// Decode little-endian bytes into numbers; `None` if the length is not a whole number of them.
pub fn from_bytes<T: Plain>(b: &[u8]) -> Option<Vec<T>> {
    if !b.len().is_multiple_of(std::mem::size_of::<T>()) {
        return None;
    }
    let n = b.len() / std::mem::size_of::<T>();
    let mut out = vec![T::default(); n];
    // SAFETY: `out` has room for exactly `n * size_of::<T>()` bytes and any bit pattern is a
    // valid `T` for the `Plain` types.
    unsafe { std::ptr::copy_nonoverlapping(b.as_ptr(), out.as_mut_ptr() as *mut u8, n * std::mem::size_of::<T>()) };
    Some(out)
}

/// Numbers whose every bit pattern is valid and which have no padding.
///
/// # Safety
/// Implement only for types without padding bytes for which every bit pattern is a valid value
/// (`as_bytes` reads every byte, `from_bytes` writes arbitrary ones).
pub unsafe trait Plain: Copy + Default + 'static {}
// SAFETY: primitive numbers: no padding, every bit pattern valid.
unsafe impl Plain for f32 {}
// SAFETY: as above.
unsafe impl Plain for f64 {}
// SAFETY: as above.
unsafe impl Plain for u8 {}
// SAFETY: as above.
unsafe impl Plain for u16 {}
// SAFETY: as above.
unsafe impl Plain for i32 {}

#[cfg(not(target_endian = "little"))]
compile_error!("the .btfrs container assumes a little-endian target");

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_with_alignment() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("x.btfrs");
        let a: Vec<f32> = (0..7).map(|x| x as f32 * 0.5).collect();
        let b: Vec<u16> = vec![1, 2, 65535];
        let meta = serde_json::json!({"views": [[0.0, 0.0, 1.0]], "note": "hi"});
        write(
            &p,
            "test",
            meta.clone(),
            &[
                ArrayRef { name: "a", dtype: Dtype::F32, shape: &[7], bytes: as_bytes(&a) },
                ArrayRef { name: "b", dtype: Dtype::U16, shape: &[3, 1], bytes: as_bytes(&b) },
            ],
        )
        .unwrap();
        let c = read_contents(&p).unwrap();
        assert_eq!(c.kind, "test");
        assert_eq!(c.meta, meta);
        for info in &c.arrays {
            assert_eq!(info.offset % 64, 0);
        }
        assert_eq!(from_bytes::<f32>(&read_array(&p, c.array(&p, "a").unwrap()).unwrap()), Some(a));
        assert_eq!(from_bytes::<u16>(&read_array(&p, c.array(&p, "b").unwrap()).unwrap()), Some(b));
        assert_eq!(from_bytes::<u16>(&[1, 2, 3]), None);
        assert!(c.array(&p, "zz").is_err());
        let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(names.len(), 1, "temporary files left: {names:?}");
    }

    #[test]
    fn float_arrays_record_whether_they_are_finite() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("f.btfrs");
        let good = [0.5f32, -1.0, f32::MAX, f32::MIN_POSITIVE / 2.0];
        let nan = [0.0f64, f64::NAN];
        let inf = [f32::NEG_INFINITY];
        let ids = [1u16, 2];
        write(
            &p,
            "t",
            serde_json::json!({}),
            &[
                ArrayRef { name: "good", dtype: Dtype::F32, shape: &[4], bytes: as_bytes(&good) },
                ArrayRef { name: "nan", dtype: Dtype::F64, shape: &[2], bytes: as_bytes(&nan) },
                ArrayRef { name: "inf", dtype: Dtype::F32, shape: &[1], bytes: as_bytes(&inf) },
                ArrayRef { name: "ids", dtype: Dtype::U16, shape: &[2], bytes: as_bytes(&ids) },
            ],
        )
        .unwrap();
        let c = read_contents(&p).unwrap();
        let flag = |n: &str| c.array(&p, n).unwrap().finite;
        assert_eq!((flag("good"), flag("nan"), flag("inf"), flag("ids")), (Some(true), Some(false), Some(false), None));
        // A file from before the flag (no "finite" key) reads with None.
        let hdr =
            br#"{"kind":"t","meta":{},"arrays":[{"name":"a","dtype":"f32","shape":[1],"offset":128,"nbytes":4}]}"#;
        let mut f = MAGIC.to_vec();
        f.extend_from_slice(&(hdr.len() as u64).to_le_bytes());
        f.extend_from_slice(hdr);
        f.resize(132, 0);
        std::fs::write(&p, &f).unwrap();
        assert_eq!(read_contents(&p).unwrap().arrays[0].finite, None);
    }

    #[test]
    fn bad_files_are_format_errors() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("bad.btfrs");
        std::fs::write(&p, b"hello world, this is not it").unwrap();
        assert!(matches!(read_contents(&p), Err(Error::Format { .. })));
        let a = [1.0f32; 16];
        write(
            &p,
            "t",
            serde_json::json!({}),
            &[ArrayRef { name: "a", dtype: Dtype::F32, shape: &[16], bytes: as_bytes(&a) }],
        )
        .unwrap();
        let full = std::fs::read(&p).unwrap();
        std::fs::write(&p, &full[..full.len() - 4]).unwrap();
        assert!(read_contents(&p).unwrap_err().to_string().contains("truncated"));
        // A header whose shape product overflows u64 is rejected, not wrapped to a small size.
        let hdr = br#"{"kind":"t","meta":{},"arrays":[{"name":"a","dtype":"f32","shape":[4294967296,4294967296,4],"offset":64,"nbytes":0}]}"#;
        let mut f = MAGIC.to_vec();
        f.extend_from_slice(&(hdr.len() as u64).to_le_bytes());
        f.extend_from_slice(hdr);
        f.resize(256, 0);
        std::fs::write(&p, &f).unwrap();
        assert!(read_contents(&p).unwrap_err().to_string().contains("inconsistent"));
        // Two arrays of one name, and an array placed inside the header, are rejected.
        let raw = |hdr: &[u8]| {
            let mut f = MAGIC.to_vec();
            f.extend_from_slice(&(hdr.len() as u64).to_le_bytes());
            f.extend_from_slice(hdr);
            f.resize(512, 0);
            std::fs::write(&p, &f).unwrap();
            read_contents(&p).map(|_| ()).unwrap_err().to_string()
        };
        let twice = br#"{"kind":"t","meta":{},"arrays":[{"name":"a","dtype":"u8","shape":[1],"offset":256,"nbytes":1},{"name":"a","dtype":"u8","shape":[1],"offset":320,"nbytes":1}]}"#;
        assert!(raw(twice).contains("listed twice"));
        let inside =
            br#"{"kind":"t","meta":{},"arrays":[{"name":"a","dtype":"u8","shape":[1],"offset":20,"nbytes":1}]}"#;
        assert!(raw(inside).contains("inconsistent"));
        let not_object = br#"{"kind":"t","meta":[1],"arrays":[]}"#;
        assert!(raw(not_object).contains("meta"));
        assert!(write(&p, "t", serde_json::json!(3), &[]).unwrap_err().to_string().starts_with("meta:"));
        let e = read_contents(&dir.path().join("missing.btfrs")).unwrap_err();
        assert!(matches!(e, Error::Io { ref source, .. } if source.kind() == std::io::ErrorKind::NotFound));
        let bad = write(
            &p,
            "t",
            serde_json::json!({}),
            &[ArrayRef { name: "a", dtype: Dtype::F32, shape: &[3], bytes: as_bytes(&a) }],
        );
        assert!(bad.unwrap_err().to_string().starts_with("a:"));
    }
}
