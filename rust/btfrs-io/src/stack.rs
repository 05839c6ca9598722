//! Image stacks: one photograph per (view, light) pair, in a folder or a zip archive, decoded
//! in parallel straight into the texel-major `[H, W, V, L, 3]` layout.
//!
//! This is the engine under the UBO2003 / ATRIUM archives ([`crate::ubo2003`]), RTI capture
//! sets ([`crate::rti`]) and generic stacks with a direction table (CSV or JSON, here). Each
//! loader turns its files into a list of [`Member`]s (a file and its view and light direction);
//! [`ImageStack::new`] groups the directions, applies the [`Selection`] (only selected images
//! are ever read) and checks the first image's size; [`Source::decode_into`] then decodes
//! batches of images in parallel and scatters each batch into the buffer in parallel over
//! texels, so only one batch of images (bounded to about 256 MB) is in memory beside the output.

use crate::capture::{Capture, Crop, Limits, Selection, Source};
use crate::decode::{self, Raw, Transfer};
use btfrs_core::{Error, Monitor, Result};
use rayon::prelude::*;
use std::io::Read;
use std::path::{Path, PathBuf};

/// Where the images are.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Store {
    /// Files; member names are paths relative to this folder (or absolute).
    Folder(PathBuf),
    /// A zip archive; member names are entry names.
    Zip(PathBuf),
}

impl Store {
    /// How a member is named in errors.
    pub fn shown(&self, name: &str) -> String {
        match self {
            Store::Folder(d) => d.join(name).display().to_string(),
            Store::Zip(z) => format!("{}!{name}", z.display()),
        }
    }

    /// The image files of the store (file names relative to it, sorted), skipping anything
    /// that is not an image by its extension ([`decode::EXTENSIONS`]). Folders are listed
    /// without recursion; archives by all their entries.
    pub fn list_images(&self) -> Result<Vec<String>> {
        let mut names = match self {
            Store::Folder(d) => {
                let shown = d.display().to_string();
                let mut v = Vec::new();
                for e in std::fs::read_dir(d).map_err(|e| Error::io(&shown, e))? {
                    let e = e.map_err(|e| Error::io(&shown, e))?;
                    let name = e.file_name().to_string_lossy().into_owned();
                    // Anything but a folder: a FIFO or device named as an image is refused by
                    // name when it is read, not skipped.
                    if decode::is_image(&name) && !e.path().is_dir() {
                        v.push(name);
                    }
                }
                v
            }
            Store::Zip(z) => {
                let shown = z.display().to_string();
                let (f, _) = crate::untrusted::open(z)?;
                let zip = zip::ZipArchive::new(f)
                    .map_err(|e| Error::format(&shown, format!("not a readable zip archive: {e}")))?;
                let mut v = Vec::new();
                for n in zip.file_names() {
                    let n = n.map_err(|e| Error::format(&shown, format!("unreadable entry name: {e}")))?;
                    if !n.ends_with('/') && decode::is_image(&n) {
                        v.push(n.into_owned());
                    }
                }
                v
            }
        };
        names.sort();
        Ok(names)
    }
}

/// One image of a stack and the (view, light) pair it shows (unit vectors in btfrs's frame).
#[derive(Debug, Clone, PartialEq)]
pub struct Member {
    /// File name in the store.
    pub name: String,
    /// View direction.
    pub view: [f64; 3],
    /// Light direction.
    pub light: [f64; 3],
    /// Where the list that names it says so (`"line 3"`), for errors; empty when the name itself
    /// is the listing (UBO archives).
    pub at: String,
}

/// Group directions that are equal within `1e-9` (as written by one tool they are equal bit
/// for bit; the tolerance absorbs a round trip through text), in first-appearance order.
fn group(dirs: impl Iterator<Item = [f64; 3]>) -> (Vec<[f64; 3]>, Vec<usize>) {
    let mut unique: Vec<[f64; 3]> = Vec::new();
    let mut index = Vec::new();
    for d in dirs {
        let i = unique.iter().position(|u| (0..3).all(|k| (u[k] - d[k]).abs() < 1e-9)).unwrap_or_else(|| {
            unique.push(d);
            unique.len() - 1
        });
        index.push(i);
    }
    (unique, index)
}

/// An order of directions (UBO archives sort by theta, then phi).
pub type DirOrder = fn(&[f64; 3], &[f64; 3]) -> std::cmp::Ordering;

/// A planned stack: which file goes to which (view, light) slot of the output.
#[derive(Debug)]
pub struct ImageStack {
    store: Store,
    /// (member name, view slot, light slot) of the selected images.
    slots: Vec<(String, usize, usize)>,
    capture: Capture,
    /// Full image size (height, width) and the crop.
    full: (usize, usize),
    crop: Crop,
    transfer: Transfer,
    max_bytes: u64,
    /// Bytes per pixel of the first image's samples (the others' are expected alike).
    pixel_bytes: usize,
}

impl ImageStack {
    /// Plan a stack. `order` sorts the unique views and lights (UBO archives sort by
    /// (theta, phi); `None` keeps first appearance, e.g. the order of an `.lp` file). The
    /// selection's indices refer to the sorted lists. Two images of the same pair are an error
    /// naming both; so is an empty stack.
    pub fn new(
        store: Store,
        members: Vec<Member>,
        sel: &Selection,
        transfer: Transfer,
        order: Option<DirOrder>,
        meta: serde_json::Value,
    ) -> Result<ImageStack> {
        ImageStack::new_limited(store, members, sel, transfer, order, meta, &Limits::default())
    }

    /// [`ImageStack::new`] within `limits` (every image's decode is checked against
    /// `limits.max_bytes` and the ratio bound of [`Limits`]). Two images of the same pair are
    /// an [`Error::Format`] naming the listing file (`meta.source`) and both lines.
    #[allow(clippy::too_many_arguments)] // the parts of a stack, each once
    pub fn new_limited(
        store: Store,
        members: Vec<Member>,
        sel: &Selection,
        transfer: Transfer,
        order: Option<DirOrder>,
        mut meta: serde_json::Value,
        limits: &Limits,
    ) -> Result<ImageStack> {
        let max_bytes = limits.max_bytes;
        if members.is_empty() {
            return Err(Error::arg("path", "found no images (expected .jpg, .jpeg, .png, .tif, .tiff or .exr files)"));
        }
        let sort = |(mut u, idx): (Vec<[f64; 3]>, Vec<usize>)| -> (Vec<[f64; 3]>, Vec<usize>) {
            let Some(cmp) = order else { return (u, idx) };
            let mut perm: Vec<usize> = (0..u.len()).collect();
            perm.sort_by(|&a, &b| cmp(&u[a], &u[b]));
            let mut rank = vec![0; u.len()];
            for (r, &p) in perm.iter().enumerate() {
                rank[p] = r;
            }
            let sorted = perm.iter().map(|&p| u[p]).collect();
            u = sorted;
            (u, idx.into_iter().map(|i| rank[i]).collect())
        };
        let (views, vi) = sort(group(members.iter().map(|m| m.view)));
        let (lights, li) = sort(group(members.iter().map(|m| m.light)));
        let source = meta.get("source").and_then(|v| v.as_str()).map(String::from).unwrap_or_else(|| store.shown(""));
        for (what, d) in [("views", &views), ("lights", &lights)] {
            btfrs_core::directions::validate(what, d).map_err(|e| Error::format(&source, e))?;
        }
        let (nv, nl) = (views.len(), lights.len());
        let mut owner: Vec<Option<usize>> = vec![None; nv * nl];
        for (k, m) in members.iter().enumerate() {
            if let Some(o) = owner[vi[k] * nl + li[k]].replace(k) {
                let label = |m: &Member| {
                    if m.at.is_empty() {
                        store.shown(&m.name)
                    } else {
                        format!("{} ({})", m.at, m.name)
                    }
                };
                return Err(Error::format(
                    &source,
                    format!(
                        "{} and {} show the same (view, light) pair; expected one image per pair",
                        label(&members[o]),
                        label(m)
                    ),
                ));
            }
        }
        let keep_v = Selection::pick("views", &sel.views, nv)?;
        let keep_l = Selection::pick("lights", &sel.lights, nl)?;
        let mut vmap = vec![usize::MAX; nv];
        for (new, &old) in keep_v.iter().enumerate() {
            vmap[old] = new;
        }
        let mut lmap = vec![usize::MAX; nl];
        for (new, &old) in keep_l.iter().enumerate() {
            lmap[old] = new;
        }
        let (snv, snl) = (keep_v.len(), keep_l.len());
        let mut mask = vec![false; snv * snl];
        let mut slots = Vec::new();
        for (k, m) in members.into_iter().enumerate() {
            let (v, l) = (vmap[vi[k]], lmap[li[k]]);
            if v != usize::MAX && l != usize::MAX {
                mask[v * snl + l] = true;
                slots.push((m.name, v, l));
            }
        }
        if slots.is_empty() {
            return Err(Error::arg("views", "the selection keeps no image"));
        }
        // The first selected image fixes the size (read from its header); every other one is
        // checked as it is decoded.
        let (fw, fh, pixel_bytes) = probe_member(&store, &slots[0].0, max_bytes)?;
        let full = (fh, fw);
        let crop = sel.rect(full.0, full.1)?;
        if let serde_json::Value::Object(o) = &mut meta {
            o.insert("image_size".into(), serde_json::json!([full.0, full.1]));
            o.insert("crop".into(), serde_json::json!([crop.row, crop.col, crop.rows, crop.cols]));
            o.insert("images".into(), serde_json::json!(slots.len()));
            // Photographs of a lit surface: the irradiance's cosine is in every pixel.
            let transfer = match transfer {
                Transfer::Srgb => "sRGB curve removed from 8- and 16-bit images (value / max); EXR as stored",
                Transfer::Linear => "8- and 16-bit images read as linear (value / max); EXR as stored",
            };
            o.entry("values").or_insert_with(|| {
                crate::capture::values_record("in the images (photographs of the lit surface)", [1.0; 3], transfer)
            });
        }
        let capture = Capture {
            height: crop.rows,
            width: crop.cols,
            views: keep_v.iter().map(|&i| views[i]).collect(),
            lights: keep_l.iter().map(|&i| lights[i]).collect(),
            mask: if mask.iter().all(|&m| m) { None } else { Some(mask) },
            meta,
        };
        Ok(ImageStack { store, slots, capture, full, crop, transfer, max_bytes, pixel_bytes })
    }

    /// The store the images come from.
    pub fn store(&self) -> &Store {
        &self.store
    }
}

/// A member's (width, height, bytes per pixel of its samples), from its header.
fn probe_member(store: &Store, name: &str, max_bytes: u64) -> Result<(usize, usize, usize)> {
    match store {
        Store::Folder(d) => decode::probe(&d.join(name), max_bytes),
        Store::Zip(_) => {
            let (bytes, disk) = ZipReader::open(store)?.read(name, max_bytes)?;
            decode::probe_from(std::io::Cursor::new(bytes), &store.shown(name), disk, max_bytes)
        }
    }
}

fn read_member(store: &Store, name: &str, transfer: Transfer, max_bytes: u64) -> Result<Raw> {
    match store {
        Store::Folder(d) => decode::read_raw(&d.join(name), transfer, max_bytes),
        Store::Zip(_) => {
            let (bytes, disk) = ZipReader::open(store)?.read(name, max_bytes)?;
            decode::decode_raw(&bytes, &store.shown(name), transfer, disk, max_bytes)
        }
    }
}

/// Sequential access to a zip archive's members (the zip crate reads through `&mut`).
struct ZipReader<'a> {
    store: &'a Store,
    zip: zip::ZipArchive<std::fs::File>,
}

impl<'a> ZipReader<'a> {
    fn open(store: &'a Store) -> Result<ZipReader<'a>> {
        let Store::Zip(z) = store else { unreachable!("zip reader of a folder") };
        let shown = z.display().to_string();
        let (f, _) = crate::untrusted::open(z)?;
        let zip =
            zip::ZipArchive::new(f).map_err(|e| Error::format(&shown, format!("not a readable zip archive: {e}")))?;
        Ok(ZipReader { store, zip })
    }

    /// A member's bytes and its compressed size (its bytes on disk). Its declared size must fit
    /// `max_bytes` and what deflate can expand its compressed bytes to (1032:1); it is read
    /// no further than declared (the zip crate checks the CRC at the end).
    fn read(&mut self, name: &str, max_bytes: u64) -> Result<(Vec<u8>, u64)> {
        let shown = self.store.shown(name);
        let f = self.zip.by_name(name).map_err(|e| Error::format(&shown, e))?;
        let (size, packed) = (f.size(), f.compressed_size());
        if size > max_bytes {
            return Err(Error::format(
                &shown,
                format!("the archive entry declares {size} bytes, more than max_bytes = {max_bytes}"),
            ));
        }
        if size > packed.saturating_mul(1032).max(1 << 16) {
            return Err(Error::format(
                &shown,
                format!(
                    "the archive entry declares {size} bytes from {packed} compressed bytes, more than deflate \
                     can expand (1032:1); the archive is corrupted"
                ),
            ));
        }
        let mut out = Vec::with_capacity(size as usize);
        f.take(size + 1).read_to_end(&mut out).map_err(|e| Error::format(&shown, e))?;
        if out.len() as u64 != size {
            return Err(Error::format(
                &shown,
                format!("the archive entry holds {} bytes or more; it declares {size}", out.len()),
            ));
        }
        Ok((out, packed))
    }
}

impl Source for ImageStack {
    fn capture(&self) -> &Capture {
        &self.capture
    }

    fn decode_into(&self, out: &mut [f32], monitor: &Monitor) -> Result<()> {
        let cap = &self.capture;
        cap.check_buffer(out)?;
        let (fh, fw) = self.full;
        let crop = self.crop;
        let n = self.slots.len();
        if let ([(name, _, _)], true) = (&self.slots[..], (crop.rows, crop.cols) == (fh, fw)) {
            // One whole image is laid out in `out` as it is in the file: decoded in place.
            monitor.start(1);
            let place = decode::Place::Fixed(out, fh, fw);
            match &self.store {
                Store::Folder(d) => decode::read_place(&d.join(name), self.transfer, self.max_bytes, place)?,
                Store::Zip(_) => {
                    let (b, disk) = ZipReader::open(&self.store)?.read(name, self.max_bytes)?;
                    let shown = self.store.shown(name);
                    decode::decode_place(std::io::Cursor::new(b), &shown, self.transfer, disk, self.max_bytes, place)?
                }
            };
            monitor.advance(1);
            return Ok(());
        }
        // Progress in images: each counts once when decoded and once when written into `out`.
        monitor.start(2 * n as u64);
        let plan = StagePlan::new(monitor.memory_limit(), fh * fw * self.pixel_bytes, (fh, fw))?;
        let (held, spill) = self.decode_all(&plan, monitor)?;
        self.write_bands(&held, spill.as_ref(), &plan, out, monitor)
    }
}

/// A decoded photograph waiting to be written into the capture: its samples in memory, or
/// cropped to the capture's rectangle in the spill file at `offset` (`like` a zero-size image
/// of its sample type).
#[derive(Debug)]
enum Held {
    Memory(Raw),
    File { offset: u64, like: Raw },
}

/// The spill file: unlinked at creation (nothing is left behind, even after a crash), in the
/// system's temporary directory (`TMPDIR`); `end` is where the next image goes.
#[derive(Debug)]
struct Spill {
    file: std::fs::File,
    end: u64,
}

/// An error of the spill file, naming the temporary directory.
fn spill_err(e: std::io::Error) -> Error {
    Error::io(format!("{} (temporary file)", std::env::temp_dir().display()), e)
}

/// How the decoded photographs are staged (see [`ImageStack::decode_into`]).
#[derive(Debug)]
struct StagePlan {
    /// Images decoded at a time.
    chunk: usize,
    /// Bytes of decoded samples kept in memory before the rest is spilled.
    keep: u64,
    /// Bytes for the rows read back from the spill file per band.
    band_bytes: u64,
}

/// The memory the decoded photographs may take when the caller sets no `memory_limit`: a quarter
/// of the physical memory (half of [`crate::capture::default_max_bytes`]).
pub fn default_stage_bytes() -> u64 {
    crate::capture::default_max_bytes() / 2
}

impl StagePlan {
    fn new(limit: Option<u64>, per: usize, full: (usize, usize)) -> Result<StagePlan> {
        let budget = limit.unwrap_or_else(default_stage_bytes);
        let per = per.max(1) as u64;
        // Rows read back per band: a quarter of the budget, at most 64 MB (and at least one row
        // of every spilled image, whatever the budget).
        let band_bytes = (budget / 4).min(64 << 20);
        // The least budget leaving one image's samples beside the band.
        let least = if per.div_ceil(3) * 4 <= 256 << 20 { per.div_ceil(3) * 4 } else { per + (64 << 20) };
        if budget < least {
            return Err(Error::arg(
                "memory_limit",
                format!(
                    "expected at least {least} bytes to decode {} x {} photographs ({per} bytes of samples each) one \
                     at a time, got {budget}",
                    full.1, full.0
                ),
            ));
        }
        let threads = rayon::current_num_threads().max(1) as u64;
        // Large photographs take long enough each that one per thread keeps every thread busy;
        // small ones go a few per thread, so that an uneven chunk's wait is short.
        let want = if per >= 16 << 20 { threads } else { 4 * threads };
        let chunk = ((budget - band_bytes) / per).clamp(1, want);
        let keep = budget - band_bytes - chunk * per;
        Ok(StagePlan { chunk: chunk as usize, keep, band_bytes })
    }
}

impl ImageStack {
    /// Decode every photograph (in parallel, [`StagePlan::chunk`] at a time), checking its
    /// size, and keep its samples: in memory while they fit [`StagePlan::keep`], else cropped
    /// into the spill file.
    fn decode_all(&self, plan: &StagePlan, monitor: &Monitor) -> Result<(Vec<Held>, Option<Spill>)> {
        let (fh, fw) = self.full;
        let mut zip = match &self.store {
            Store::Zip(_) => Some(ZipReader::open(&self.store)?),
            Store::Folder(_) => None,
        };
        let mut spill: Option<Spill> = None;
        let mut kept = 0u64;
        let mut held = Vec::with_capacity(self.slots.len());
        let max_bytes = self.max_bytes;
        for chunk in self.slots.chunks(plan.chunk) {
            monitor.check()?;
            // Archive members are read in order (one reader), then decoded in parallel.
            let bytes: Vec<Option<(Vec<u8>, u64)>> = match &mut zip {
                Some(z) => chunk.iter().map(|(n, _, _)| z.read(n, max_bytes).map(Some)).collect::<Result<_>>()?,
                None => vec![None; chunk.len()],
            };
            let images: Vec<Raw> = chunk
                .par_iter()
                .zip(bytes)
                .map(|((name, _, _), b)| {
                    if monitor.is_cancelled() {
                        return Err(Error::Interrupted);
                    }
                    let img = match b {
                        Some((b, disk)) => {
                            decode::decode_raw(&b, &self.store.shown(name), self.transfer, disk, max_bytes)?
                        }
                        None => read_member(&self.store, name, self.transfer, max_bytes)?,
                    };
                    if (img.height, img.width) != (fh, fw) {
                        return Err(Error::format(
                            self.store.shown(name),
                            format!(
                                "the image is {} x {} pixels; expected {fh} x {fw} like the first image",
                                img.height, img.width
                            ),
                        ));
                    }
                    monitor.advance(1);
                    Ok(img)
                })
                .collect::<Result<_>>()?;
            for img in images {
                let b = img.sample_bytes() as u64;
                if kept + b <= plan.keep {
                    kept += b;
                    held.push(Held::Memory(img));
                } else {
                    held.push(self.spill(&mut spill, img)?);
                }
            }
        }
        Ok((held, spill))
    }

    /// Write an image's crop into the spill file (made on first use).
    fn spill(&self, spill: &mut Option<Spill>, img: Raw) -> Result<Held> {
        let s = match spill {
            Some(s) => s,
            None => {
                let file = tempfile::tempfile_in(std::env::temp_dir()).map_err(spill_err)?;
                spill.insert(Spill { file, end: 0 })
            }
        };
        let offset = s.end;
        s.end += img.write_rect(&s.file, offset, self.crop).map_err(spill_err)?;
        Ok(Held::File { offset, like: img.like() })
    }

    /// Write the held photographs into `out`, band of texel rows by band: each band's texels are
    /// written once, with every photograph's value (the spilled ones' rows read back first).
    fn write_bands(
        &self,
        held: &[Held],
        spill: Option<&Spill>,
        plan: &StagePlan,
        out: &mut [f32],
        monitor: &Monitor,
    ) -> Result<()> {
        let (nl, abrdf) = (self.capture.lights.len(), self.capture.abrdf_len());
        let (_, fw) = self.full;
        let crop = self.crop;
        let spilled_row: usize = held
            .iter()
            .map(|h| match h {
                Held::File { like, .. } => crop.cols * like.pixel_bytes(),
                Held::Memory(_) => 0,
            })
            .sum();
        let out_row = crop.cols * abrdf;
        // Bands of at most 256 MB of output (the unit of progress and of cancelling) and of what
        // the plan allows to read back.
        let rows = (plan.band_bytes as usize / spilled_row.max(1))
            .min((256usize << 20) / (4 * out_row).max(1))
            .clamp(1, crop.rows);
        let n = held.len() as u64;
        let mut done = 0u64;
        for r0 in (0..crop.rows).step_by(rows) {
            monitor.check()?;
            let r1 = (r0 + rows).min(crop.rows);
            let back: Vec<Option<Raw>> = held
                .par_iter()
                .map(|h| match h {
                    Held::File { offset, like } => {
                        let at = offset + (r0 * crop.cols * like.pixel_bytes()) as u64;
                        let file = &spill.expect("an image was spilled").file;
                        like.read_rows(file, at, r1 - r0, crop.cols).map(Some).map_err(spill_err)
                    }
                    Held::Memory(_) => Ok(None),
                })
                .collect::<Result<_>>()?;
            let images: Vec<Rows<'_>> = held
                .iter()
                .zip(&back)
                .zip(&self.slots)
                .map(|((h, b), &(_, v, l))| match (h, b) {
                    (Held::Memory(img), _) => {
                        Rows { slot: v * nl + l, img, first: (crop.row + r0) * fw + crop.col, stride: fw }
                    }
                    (Held::File { .. }, Some(img)) => Rows { slot: v * nl + l, img, first: 0, stride: crop.cols },
                    (Held::File { .. }, None) => unreachable!("every spilled image is read back"),
                })
                .collect();
            scatter(&mut out[r0 * out_row..r1 * out_row], abrdf, crop.cols, &images);
            let now = n * r1 as u64 / crop.rows as u64;
            monitor.advance(now - done);
            done = now;
        }
        Ok(())
    }
}

/// Rows of one photograph for [`scatter`]: texel `t` of a band (`t / cols` rows down, `t % cols`
/// across) is pixel `first + (t / cols) * stride + t % cols` of `img`, written at `slot` (the
/// (view, light) pair's index) of the texel.
#[derive(Debug)]
struct Rows<'a> {
    slot: usize,
    img: &'a Raw,
    first: usize,
    stride: usize,
}

/// Texels per block of the scatter (measured best of 16 to 128): a block's slices of the output
/// (`SCATTER_BLOCK` texels of `abrdf` values) stay in cache while every image writes its run of
/// pixels into them, each image's run converted in one loop straight into them ([`Raw::rgb_run`]).
const SCATTER_BLOCK: usize = 128;

/// Write every photograph's pixels into the band `out` of texel-major values (`abrdf` per
/// texel, `cols` texels a row). Blocks of texels in parallel; within a block, image by image,
/// run by run (a run ends at a row's end).
fn scatter(out: &mut [f32], abrdf: usize, cols: usize, images: &[Rows<'_>]) {
    out.par_chunks_mut(abrdf * SCATTER_BLOCK).enumerate().for_each(|(b, block)| {
        let (t0, n) = (b * SCATTER_BLOCK, block.len() / abrdf);
        for im in images {
            let dst = im.slot * 3;
            let mut i = 0;
            while i < n {
                let t = t0 + i;
                let run = (n - i).min(cols - t % cols);
                let p = im.first + (t / cols) * im.stride + t % cols;
                im.img.rgb_run(p, run, &mut block[i * abrdf + dst..], abrdf);
                i += run;
            }
        }
    });
}

/// A direction from theta and phi in degrees: `(sin t cos p, sin t sin p, cos t)`.
pub fn from_angles(theta_deg: f64, phi_deg: f64) -> [f64; 3] {
    let (t, p) = (theta_deg.to_radians(), phi_deg.to_radians());
    [t.sin() * p.cos(), t.sin() * p.sin(), t.cos()]
}

/// A generic stack: images listed by a direction table, CSV or JSON, beside them.
///
/// * **CSV**: a header row naming the columns; `file` (or `filename`, `image`), then either
///   `light_theta, light_phi` (degrees) or `lx, ly, lz`, and optionally `view_theta, view_phi`
///   or `vx, vy, vz` (absent: the view is the normal). Blank lines and lines starting with `#`
///   are skipped.
/// * **JSON**: a list of objects with the same keys (or `{"images": [...]}`).
///
/// File names are relative to `folder` (default: the table's folder). Vectors are normalised
/// and a vector a hair below the horizon is moved onto it, as for `.lp` files
/// ([`crate::untrusted::Directions`]), each kind of repair reported in one summary warning in
/// `meta.warnings`. The table is read as [`crate::untrusted`] reads one (at most
/// [`crate::untrusted::MAX_TABLE`] bytes, UTF-8).
pub fn open_table(table: &Path, folder: Option<&Path>, sel: &Selection, transfer: Transfer) -> Result<ImageStack> {
    open_table_limited(table, folder, sel, transfer, &Limits::default())
}

/// Whether the existing `file` lies inside `dir` (or its subfolders), symlinks resolved.
pub fn inside(dir: &Path, file: &Path) -> bool {
    match (dir.canonicalize(), file.canonicalize()) {
        (Ok(d), Ok(f)) => f.starts_with(d),
        _ => false,
    }
}

/// [`open_table`] within `limits`: image names must stay in the folder unless
/// `limits.allow_outside`, and every decode is bounded (see [`Limits`]).
pub fn open_table_limited(
    table: &Path,
    folder: Option<&Path>,
    sel: &Selection,
    transfer: Transfer,
    limits: &Limits,
) -> Result<ImageStack> {
    let shown = table.display().to_string();
    let text = crate::untrusted::read_text(table, crate::untrusted::TABLE, limits.max_bytes)?;
    let is_json = shown.to_ascii_lowercase().ends_with(".json");
    let mut lines: Vec<String> = Vec::new();
    let rows: Vec<serde_json::Map<String, serde_json::Value>> = if is_json {
        // One object per image: up to a million images.
        let v = crate::untrusted::parse_json_within(&text, &shown, 1 << 20)?;
        let list = match v {
            serde_json::Value::Array(a) => a,
            serde_json::Value::Object(mut o) => match o.remove("images") {
                Some(serde_json::Value::Array(a)) => a,
                _ => return Err(Error::format(&shown, "expected a list of images or {\"images\": [...]}")),
            },
            _ => return Err(Error::format(&shown, "expected a list of images or {\"images\": [...]}")),
        };
        list.into_iter()
            .enumerate()
            .map(|(i, r)| match r {
                serde_json::Value::Object(o) => {
                    lines.push(format!("entry {i}"));
                    Ok(o)
                }
                _ => Err(Error::format(&shown, format!("entry {i} is not an object"))),
            })
            .collect::<Result<_>>()?
    } else {
        let mut rdr = csv::ReaderBuilder::new().comment(Some(b'#')).trim(csv::Trim::All).from_reader(text.as_bytes());
        let headers: Vec<String> =
            rdr.headers().map_err(|e| Error::format(&shown, e))?.iter().map(|h| h.to_ascii_lowercase()).collect();
        let mut rows = Vec::new();
        for rec in rdr.records() {
            let rec = rec.map_err(|e| Error::format(&shown, e))?;
            // The line from the record's byte offset (the reader's own count skips blank lines).
            // It may point at blank or comment lines the reader skipped before the record.
            let line = rec.position().filter(|p| (p.byte() as usize) <= text.len()).map_or_else(
                || format!("row {}", rows.len() + 1),
                |p| {
                    let start = p.byte() as usize;
                    let mut n = text.as_bytes()[..start].iter().filter(|&&c| c == b'\n').count() + 1;
                    for l in text[start..].split('\n') {
                        let t = l.trim();
                        if !(t.is_empty() || t.starts_with('#')) {
                            break;
                        }
                        n += 1;
                    }
                    format!("line {n}")
                },
            );
            lines.push(line);
            let mut o = serde_json::Map::new();
            for (h, v) in headers.iter().zip(rec.iter()) {
                let val = v.parse::<f64>().map(serde_json::Value::from).unwrap_or_else(|_| serde_json::Value::from(v));
                o.insert(h.clone(), val);
            }
            rows.push(o);
        }
        rows
    };
    let mut warnings = Vec::new();
    let mut light_dirs = crate::untrusted::Directions::new(&shown, "light", "");
    let mut view_dirs = crate::untrusted::Directions::new(&shown, "view", "");
    let mut members = Vec::with_capacity(rows.len());
    for (i, r) in rows.iter().enumerate() {
        let line = &lines[i];
        let at = |what: &str| format!("{line}: {what}");
        let file = ["file", "filename", "image"]
            .iter()
            .find_map(|k| r.get(*k).and_then(|v| v.as_str()))
            .ok_or_else(|| Error::format(&shown, at("has no file (expected a column file, filename or image)")))?;
        let num = |k: &str| r.get(k).and_then(|v| v.as_f64());
        let mut dir = |pre: &str, vec: [&str; 3]| -> Result<Option<[f64; 3]>> {
            let angles = [format!("{pre}_theta"), format!("{pre}_phi")];
            if angles.iter().any(|k| r.contains_key(k)) && vec.iter().any(|k| r.contains_key(*k)) {
                return Err(Error::format(
                    &shown,
                    at(&format!(
                        "both angle columns ({}, {}) and vector columns ({}) give the {pre} direction; expected one of them",
                        angles[0],
                        angles[1],
                        vec.join(", ")
                    )),
                ));
            }
            if let (Some(t), Some(p)) = (num(&format!("{pre}_theta")), num(&format!("{pre}_phi"))) {
                if !(0.0..=90.0).contains(&t) {
                    return Err(Error::format(&shown, at(&format!("{pre}_theta = {t}: expected 0 to 90 degrees"))));
                }
                return Ok(Some(from_angles(t, p)));
            }
            match (num(vec[0]), num(vec[1]), num(vec[2])) {
                (Some(x), Some(y), Some(z)) => {
                    let dirs = if pre == "light" { &mut light_dirs } else { &mut view_dirs };
                    let u = dirs.unit(line.as_str(), [x, y, z]).ok_or_else(|| {
                        Error::format(
                            &shown,
                            at(&format!(
                                "{pre} ({x}, {y}, {z}) is not a direction above the surface (one at most {} below \
                                 the horizon, as unit z, is read as on it)",
                                crate::untrusted::HORIZON_TOLERANCE
                            )),
                        )
                    })?;
                    Ok(Some(u))
                }
                _ => Ok(None),
            }
        };
        let light = dir("light", ["lx", "ly", "lz"])?.ok_or_else(|| {
            Error::format(&shown, at("has no light direction (light_theta, light_phi or lx, ly, lz)"))
        })?;
        let view = dir("view", ["vx", "vy", "vz"])?.unwrap_or([0.0, 0.0, 1.0]);
        members.push(Member { name: file.to_string(), view, light, at: line.clone() });
    }
    let dir =
        folder.map(Path::to_path_buf).unwrap_or_else(|| table.parent().map(Path::to_path_buf).unwrap_or_default());
    let dir = if dir.as_os_str().is_empty() { PathBuf::from(".") } else { dir };
    for m in &members {
        let p = dir.join(&m.name);
        // Present, whatever it is: a FIFO or device is refused by name when it is read.
        if !crate::untrusted::present(&p) || p.is_dir() {
            return Err(Error::format(&shown, format!("{}: names {}, which does not exist", m.at, p.display())));
        }
        if !limits.allow_outside && !inside(&dir, &p) {
            return Err(Error::format(
                &shown,
                format!(
                    "{}: names {:?}, which lies outside the capture's folder {}; expected a path inside it \
                     (pass allow_outside=True to read it anyway)",
                    m.at,
                    m.name,
                    dir.display()
                ),
            ));
        }
    }
    light_dirs.report(&mut warnings);
    view_dirs.report(&mut warnings);
    let meta = serde_json::json!({"format": "stack", "source": shown, "warnings": warnings});
    ImageStack::new_limited(Store::Folder(dir), members, sel, transfer, None, meta, limits)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::capture;

    fn stack(dir: &Path) -> ImageStack {
        let mut members = Vec::new();
        for (i, l) in [[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, -0.6, 0.8]].into_iter().enumerate() {
            let img =
                image::RgbImage::from_fn(4, 3, |x, y| image::Rgb([(x * 60) as u8, (y * 100) as u8, (i * 100) as u8]));
            let name = format!("i{i}.png");
            img.save(dir.join(&name)).unwrap();
            members.push(Member { name, view: [0.0, 0.0, 1.0], light: l, at: String::new() });
        }
        ImageStack::new(
            Store::Folder(dir.to_path_buf()),
            members,
            &Selection::default(),
            Transfer::Linear,
            None,
            serde_json::json!({}),
        )
        .unwrap()
    }

    #[test]
    fn streamed_file_equals_the_in_memory_load() {
        let dir = tempfile::tempdir().unwrap();
        let s = stack(dir.path());
        let mem = capture::load(&s, &Monitor::new()).unwrap();
        // texel (row 2, col 3) of light 2: (3*60, 2*100, 200) / 255
        let t = (2 * 4 + 3) * 9 + 2 * 3;
        assert_eq!(&mem[t..t + 3], &[180.0 / 255.0, 200.0 / 255.0, 200.0 / 255.0]);
        let out = dir.path().join("c.btfrs");
        capture::load_to_file(&s, &out, &Monitor::new()).unwrap();
        let c = crate::container::read_contents(&out).unwrap();
        assert_eq!(c.kind, "btf");
        let info = c.array(&out, "data").unwrap();
        assert_eq!(info.shape, vec![3, 4, 1, 3, 3]);
        assert_eq!(info.finite, Some(true));
        let bytes = crate::container::read_array(&out, info).unwrap();
        assert_eq!(crate::container::from_bytes::<f32>(&bytes).unwrap(), mem);
    }

    #[test]
    fn spilled_photographs_load_as_held_ones() {
        // Seven 9 x 7 photographs, one of them 16-bit and one grey, loaded whole and cropped:
        // with no limit (all held in memory), and with limits that spill some or all of them to
        // the temporary file and write the capture in bands of one row. Every load must equal
        // the values decoded image by image (`decode::read`), placed by hand.
        let dir = tempfile::tempdir().unwrap();
        let (w, h) = (9u32, 7u32);
        let mut members = Vec::new();
        for i in 0..7u32 {
            let name = format!("i{i}.png");
            let px = |x: u32, y: u32, c: u32| (x * 29 + y * 17 + c * 71 + i * 13) % 256;
            match i {
                3 => image::ImageBuffer::<image::Rgb<u16>, _>::from_fn(w, h, |x, y| {
                    image::Rgb([0, 1, 2].map(|c| (px(x, y, c) * 257 + c) as u16))
                })
                .save(dir.path().join(&name))
                .unwrap(),
                5 => image::GrayImage::from_fn(w, h, |x, y| image::Luma([px(x, y, 0) as u8]))
                    .save(dir.path().join(&name))
                    .unwrap(),
                _ => image::RgbImage::from_fn(w, h, |x, y| image::Rgb([0, 1, 2].map(|c| px(x, y, c) as u8)))
                    .save(dir.path().join(&name))
                    .unwrap(),
            }
            let a = i as f64 * 0.8;
            let light = [0.6 * a.cos(), 0.6 * a.sin(), 0.8];
            members.push(Member { name, view: [0.0, 0.0, 1.0], light, at: String::new() });
        }
        let decoded: Vec<decode::Decoded> =
            (0..7).map(|i| decode::read(&dir.path().join(format!("i{i}.png")), Transfer::Srgb).unwrap()).collect();
        for crop in [None, Some(Crop { row: 2, col: 3, rows: 4, cols: 5 })] {
            let sel = Selection { crop, ..Selection::default() };
            let s = ImageStack::new(
                Store::Folder(dir.path().to_path_buf()),
                members.clone(),
                &sel,
                Transfer::Srgb,
                None,
                serde_json::json!({}),
            )
            .unwrap();
            let c = crop.unwrap_or(Crop { row: 0, col: 0, rows: 7, cols: 9 });
            let mut want = vec![0.0f32; c.rows * c.cols * 7 * 3];
            for (l, d) in decoded.iter().enumerate() {
                for t in 0..c.rows * c.cols {
                    let p = (c.row + t / c.cols) * 9 + c.col + t % c.cols;
                    want[t * 21 + l * 3..t * 21 + l * 3 + 3].copy_from_slice(&d.rgb[p * 3..p * 3 + 3]);
                }
            }
            // The first image holds 9 x 7 x 3 bytes (189): the least budget is 252 bytes.
            for (limit, spilled) in [(None, 0..=0), (Some(3000), 1..=6), (Some(300), 7..=7), (Some(252), 7..=7)] {
                let m = Monitor::new();
                m.set_memory_limit(limit);
                let got = capture::load(&s, &m).unwrap();
                assert_eq!(got, want, "crop {crop:?}, memory_limit {limit:?}");
                assert_eq!(m.progress(), (14, 14));
                let plan = StagePlan::new(limit, 9 * 7 * 3, (7, 9)).unwrap();
                let (held, _) = s.decode_all(&plan, &Monitor::new()).unwrap();
                let n = held.iter().filter(|h| matches!(h, Held::File { .. })).count();
                assert!(spilled.contains(&n), "memory_limit {limit:?}: {n} spilled");
            }
            let m = Monitor::new();
            m.set_memory_limit(Some(251));
            let e = capture::load(&s, &m).unwrap_err().to_string();
            assert!(e.starts_with("memory_limit: expected at least 252 bytes") && e.contains("9 x 7"), "{e}");
        }
    }

    #[test]
    fn cancelled_stream_leaves_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let s = stack(dir.path());
        let m = Monitor::new();
        m.cancel();
        let out = dir.path().join("c.btfrs");
        assert!(matches!(capture::load_to_file(&s, &out, &m), Err(Error::Interrupted)));
        let mut left: Vec<String> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        left.sort();
        assert_eq!(left, ["i0.png", "i1.png", "i2.png"]);
        // a file of another size in the stack is an error naming it, and nothing is written
        image::RgbImage::new(5, 3).save(dir.path().join("i2.png")).unwrap();
        let e = capture::load_to_file(&s, &out, &Monitor::new()).unwrap_err().to_string();
        assert!(e.contains("i2.png") && e.contains("3 x 5") && e.contains("expected 3 x 4"), "{e}");
        assert!(!out.exists());
    }
}
