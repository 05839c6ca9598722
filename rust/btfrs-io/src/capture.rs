//! Measured captures in: what every loader of real data (UBO2003 / ATRIUM archives, UBO2014
//! `.btf` files, RTI `.lp` sets, image stacks) shares.
//!
//! A loader opens its files and describes what it will produce (a [`Capture`]: texel size,
//! view and light directions in btfrs's frame, which pairs are present) *before* decoding any
//! pixel, applying the user's [`Selection`] (crop, view and light subsets) so that only what is
//! asked for is ever decoded. It then decodes straight into a caller-provided texel-major
//! `[H, W, V, L, 3]` f32 buffer ([`Source::decode_into`]): a `Vec` ([`load`]) or a
//! memory-mapped `.btfrs` file ([`load_to_file`]), so the data is never held twice.
//!
//! Directions are unit vectors in the tangent frame of the sample (z the normal, x along the
//! image columns to the right, y up the image, theta from z, phi from x towards y); each loader
//! documents how its file's angles map to it.

use btfrs_core::{Error, Monitor, Result};

/// A rectangle of texels: `rows x cols` starting at (`row`, `col`), row 0 being the top row of
/// the images.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Crop {
    /// First row.
    pub row: usize,
    /// First column.
    pub col: usize,
    /// Rows kept.
    pub rows: usize,
    /// Columns kept.
    pub cols: usize,
}

impl Crop {
    /// Check the crop against a `height x width` image.
    pub fn check(&self, height: usize, width: usize) -> Result<()> {
        if self.rows == 0 || self.cols == 0 {
            return Err(Error::arg(
                "crop",
                format!("expected a non-empty rectangle, got {} x {}", self.rows, self.cols),
            ));
        }
        if self.row.checked_add(self.rows).is_none_or(|e| e > height)
            || self.col.checked_add(self.cols).is_none_or(|e| e > width)
        {
            return Err(Error::arg(
                "crop",
                format!(
                    "rows {}..{} x columns {}..{} lie outside the {height} x {width} images",
                    self.row,
                    self.row.saturating_add(self.rows),
                    self.col,
                    self.col.saturating_add(self.cols)
                ),
            ));
        }
        Ok(())
    }
}

/// What of a capture to load: a crop and subsets of its views and lights (indices into the
/// file's own view and light lists, in the order [`Capture`] reports them before selection).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Selection {
    /// Texel rectangle (`None`: every texel).
    pub crop: Option<Crop>,
    /// View indices, kept in the order given (`None`: every view).
    pub views: Option<Vec<usize>>,
    /// Light indices, kept in the order given (`None`: every light).
    pub lights: Option<Vec<usize>>,
}

impl Selection {
    /// The kept indices of an axis of `n` entries, checked (in range, no duplicates).
    pub fn pick(name: &str, sel: &Option<Vec<usize>>, n: usize) -> Result<Vec<usize>> {
        let Some(s) = sel else { return Ok((0..n).collect()) };
        if s.is_empty() {
            return Err(Error::arg(name, "expected at least one index"));
        }
        let mut seen = vec![false; n];
        for &i in s {
            if i >= n {
                return Err(Error::arg(name, format!("index {i} is out of range for {n} {name}")));
            }
            if std::mem::replace(&mut seen[i], true) {
                return Err(Error::arg(name, format!("index {i} is given twice")));
            }
        }
        Ok(s.clone())
    }

    /// The crop as (row, col, rows, cols) of a `height x width` image, checked.
    pub fn rect(&self, height: usize, width: usize) -> Result<Crop> {
        match self.crop {
            Some(c) => {
                c.check(height, width)?;
                Ok(c)
            }
            None => Ok(Crop { row: 0, col: 0, rows: height, cols: width }),
        }
    }
}

/// What the readers accept of files from strangers: how much memory a capture may take, and
/// whether it may name files outside its folder.
///
/// * `max_bytes`: the most bytes the readers allocate for one capture: the in-memory BTF
///   (texels x pairs x 3 x 4 bytes) and every decoded image (a zip entry's declared size too).
///   Default [`default_max_bytes`]: half the machine's physical memory.
/// * Independently of it, an image whose decoded float pixels (width x height x 3 x 4 bytes)
///   exceed [`MAX_DECODE_RATIO`] times its bytes on disk (its compressed size in an archive) is
///   refused as implausible (a decompression bomb), above a floor of [`RATIO_FLOOR`] bytes.
/// * `allow_outside`: image paths of `.lp` files and direction tables must resolve inside the
///   capture's folder (symlinks followed) unless this is true.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Limits {
    /// Most bytes one capture may allocate.
    pub max_bytes: u64,
    /// Whether image paths may lead out of the capture's folder.
    pub allow_outside: bool,
}

impl Default for Limits {
    fn default() -> Self {
        Limits { max_bytes: default_max_bytes(), allow_outside: false }
    }
}

/// Largest ratio of an image's decoded float RGB bytes (12 per pixel) to its bytes on disk.
/// 1024 is 256 to 1 on 8-bit RGB samples: photographs compress far less (JPEG at low quality
/// about 50 to 1, PNG about 3 to 1), but deflate can reach 1032 to 1 on a constant image, so a
/// few hundred bytes could otherwise declare gigabytes.
pub const MAX_DECODE_RATIO: u64 = 1024;

/// Decoded sizes up to this (64 MiB, a 2300 x 2300 image) are never refused by the ratio: a
/// small synthetic image (a constant rendering) may compress better than any photograph, and
/// allocating it is harmless.
pub const RATIO_FLOOR: u64 = 64 << 20;

/// Half the machine's physical memory (read once; 8 GiB when it cannot be read).
pub fn default_max_bytes() -> u64 {
    static M: std::sync::OnceLock<u64> = std::sync::OnceLock::new();
    *M.get_or_init(|| physical_memory().unwrap_or(16 << 30) / 2)
}

/// The machine's physical memory in bytes (Linux: `/proc/meminfo`; elsewhere `None`).
pub fn physical_memory() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemTotal:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    kb.checked_mul(1024)
}

/// Check an image of `width x height` about to be decoded to float RGB: within `max_bytes` and
/// within [`MAX_DECODE_RATIO`] of its `disk` bytes. `shown` names it.
pub fn check_image_budget(shown: &str, width: u64, height: u64, disk: u64, max_bytes: u64) -> Result<()> {
    let need = width.checked_mul(height).and_then(|p| p.checked_mul(12));
    let need_s = need.map_or_else(|| "more than 2^64".to_string(), |n| n.to_string());
    if need.is_none_or(|n| n > max_bytes) {
        return Err(Error::format(
            shown,
            format!("a {width} x {height} image needs {need_s} bytes decoded, more than max_bytes = {max_bytes}"),
        ));
    }
    let most = disk.saturating_mul(MAX_DECODE_RATIO).max(RATIO_FLOOR);
    if need.is_none_or(|n| n > most) {
        return Err(Error::format(
            shown,
            format!(
                "a {width} x {height} image would decode to {need_s} bytes from {disk} bytes on disk, more than \
                 {MAX_DECODE_RATIO} times its size (at most {most}); refused as implausible (corrupted, or a \
                 decompression bomb)"
            ),
        ));
    }
    Ok(())
}

/// What a loader will produce, after selection.
#[derive(Debug, Clone, PartialEq)]
pub struct Capture {
    /// Rows of texels.
    pub height: usize,
    /// Columns of texels.
    pub width: usize,
    /// View directions (unit, tangent frame).
    pub views: Vec<[f64; 3]>,
    /// Light directions (unit, tangent frame).
    pub lights: Vec<[f64; 3]>,
    /// `[V * L]` presence of each (view, light) pair (`None`: all present).
    pub mask: Option<Vec<bool>>,
    /// What the file says about itself (format, names, units), kept in the container's meta.
    pub meta: serde_json::Value,
}

/// The record every reader puts under `"values"` in [`Capture::meta`]: how the file's numbers
/// were brought to btfrs's convention (linear RGB, the light's cosine included, the file's
/// colour scale applied). `cosine` says where the cosine comes from, `scale` is the per-channel
/// factor applied, `transfer` how stored numbers became linear values.
pub fn values_record(cosine: &str, scale: [f32; 3], transfer: &str) -> serde_json::Value {
    serde_json::json!({
        "convention": "linear RGB, cosine of the light's polar angle included, colour scale applied",
        "cosine": cosine,
        "scale_applied": scale,
        "transfer": transfer,
    })
}

impl Capture {
    /// Values of the texel-major `[H, W, V, L, 3]` buffer.
    pub fn len(&self) -> usize {
        self.height * self.width * self.views.len() * self.lights.len() * 3
    }
    /// True when the buffer would be empty.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// That `out` is the buffer [`Source::decode_into`] fills: `len()` values.
    pub fn check_buffer(&self, out: &[f32]) -> Result<()> {
        if out.len() != self.len() {
            return Err(Error::arg("out", format!("expected {} values, got {}", self.len(), out.len())));
        }
        Ok(())
    }
    /// Values per texel (`V * L * 3`).
    pub fn abrdf_len(&self) -> usize {
        self.views.len() * self.lights.len() * 3
    }
}

/// A loader, opened and planned: decoding writes the capture into a buffer.
pub trait Source: Sync {
    /// What [`Source::decode_into`] produces.
    fn capture(&self) -> &Capture;
    /// Decode every selected image into `out` (texel-major `[H, W, V, L, 3]`, `capture().len()`
    /// values, pre-filled with zeros: absent pairs stay 0). Reports progress in images (or the
    /// loader's natural unit) on `monitor` and stops with [`Error::Interrupted`] when it is
    /// cancelled. Every decoded value is finite (a non-finite one is an error naming its file).
    fn decode_into(&self, out: &mut [f32], monitor: &Monitor) -> Result<()>;
}

/// Decode a whole source into memory.
pub fn load(source: &dyn Source, monitor: &Monitor) -> Result<Vec<f32>> {
    load_within(source, "capture", default_max_bytes(), monitor)
}

/// [`load`], refusing (an [`Error::Format`] naming `shown`, the capture's file) a BTF of more
/// than `max_bytes` bytes before allocating it.
pub fn load_within(source: &dyn Source, shown: &str, max_bytes: u64, monitor: &Monitor) -> Result<Vec<f32>> {
    let cap = source.capture();
    let n = cap.len();
    let need = (n as u64).saturating_mul(4);
    if need > max_bytes {
        return Err(Error::format(
            shown,
            format!(
                "the capture ({} x {} texels, {} views x {} lights) needs {need} bytes in memory, more than \
                 max_bytes = {max_bytes}; load a crop or a subset, raise max_bytes, or decode to a file with mmap_to=",
                cap.height,
                cap.width,
                cap.views.len(),
                cap.lights.len()
            ),
        ));
    }
    let mut out = zeroed(n).ok_or_else(|| {
        Error::arg("capture", format!("{n} float32 values do not fit in memory; load with mmap_to= a file"))
    })?;
    source.decode_into(&mut out, monitor)?;
    Ok(out)
}

/// `n` zeros, or `None` when they cannot be allocated. Zeroed by the allocator (a large block
/// comes from the system as fresh zero pages), not written: every value is written again by the
/// decode, and writing zeros first cost a tenth of a 629 MB load.
fn zeroed(n: usize) -> Option<Vec<f32>> {
    if n == 0 {
        return Some(Vec::new());
    }
    let layout = std::alloc::Layout::array::<f32>(n).ok()?;
    // SAFETY: the layout's size is non-zero; a null pointer (allocation failure) is returned
    // as None; all-zero bytes are the f32 0.0; the Vec owns the block with the layout it was
    // allocated with (f32's alignment, capacity n), so it frees it correctly.
    unsafe {
        let p = std::alloc::alloc_zeroed(layout).cast::<f32>();
        (!p.is_null()).then(|| Vec::from_raw_parts(p, n, n))
    }
}

/// Decode a source straight into a new `.btfrs` BTF file at `path` (the values memory-mapped,
/// never held in memory as a whole), written atomically: on any error or cancel nothing is
/// left at `path`. The file is what `Btf.save` writes (kind `btf`, arrays `data`, `views`,
/// `lights` and `mask` when pairs are absent), with the capture's meta under `"source"`.
pub fn load_to_file(source: &dyn Source, path: &std::path::Path, monitor: &Monitor) -> Result<()> {
    let cap = source.capture();
    let meta = serde_json::json!({"layout": "HWVL3", "source": cap.meta});
    write_btf_streamed(path, cap.height, cap.width, &cap.views, &cap.lights, cap.mask.as_deref(), meta, |out| {
        source.decode_into(out, monitor)
    })
}

/// Write a `.btfrs` BTF file (what `Btf.save` writes: kind `btf`, arrays `data`, `views`,
/// `lights`, and `mask` when given) whose values `fill` writes in place into the memory-mapped
/// file, so a BTF larger than memory can be made; atomic like every writer here (on an error or
/// a cancel in `fill`, nothing is left at `path`). `fill` must write finite values only (the
/// header flags the values finite, which lets `Btf.load(mmap=True)` skip its scan).
#[allow(clippy::too_many_arguments)] // the file's parts, each once
pub fn write_btf_streamed(
    path: &std::path::Path,
    height: usize,
    width: usize,
    views: &[[f64; 3]],
    lights: &[[f64; 3]],
    mask: Option<&[bool]>,
    meta: serde_json::Value,
    fill: impl FnOnce(&mut [f32]) -> Result<()>,
) -> Result<()> {
    use crate::container::{as_bytes, ArrayRef, Dtype};
    let shape = [height, width, views.len(), lights.len(), 3];
    let vflat: Vec<f64> = views.iter().flatten().copied().collect();
    let lflat: Vec<f64> = lights.iter().flatten().copied().collect();
    let vshape = [views.len(), 3];
    let lshape = [lights.len(), 3];
    let mshape = [views.len(), lights.len()];
    let mask: Option<Vec<u8>> = mask.map(|m| m.iter().map(|&b| b as u8).collect());
    let mut arrays = vec![
        ArrayRef { name: "views", dtype: Dtype::F64, shape: &vshape, bytes: as_bytes(&vflat) },
        ArrayRef { name: "lights", dtype: Dtype::F64, shape: &lshape, bytes: as_bytes(&lflat) },
    ];
    if let Some(m) = &mask {
        arrays.push(ArrayRef { name: "mask", dtype: Dtype::Bool, shape: &mshape, bytes: m });
    }
    crate::container::write_streamed(path, "btf", meta, "data", &shape, &arrays, fill)
}
