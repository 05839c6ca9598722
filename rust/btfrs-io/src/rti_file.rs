//! Reading and writing `.rti` files of the hemispherical-harmonics type (`#HSH1.2`, RTI type 3),
//! the format RTIBuilder writes and RTIViewer and relight (ISTI-CNR, Cultural Heritage Imaging)
//! open. The basis is [`btfrs_fit::hsh`]'s (Gautron et al. 2004 with the viewers' signs).
//!
//! # The file
//!
//! ```text
//! #HSH1.2\n                      comment lines start with '#'; the first names the version
//! 3\n                            the RTI type: 3 = HSH
//! <width> <height> 3\n           texels per row, rows, colour bands
//! <terms> <basis type> 1\n       order^2 coefficients per band, the basis type, bytes per value
//! <terms f32> <terms f32>        binary, little-endian: the two per-term float arrays
//! <data>                         width * height * 3 * terms bytes
//! ```
//!
//! The data hold, texel after texel, the `terms` bytes of red, then of green, then of blue; the
//! rows run from the *top* of the image to the bottom, left to right (unlike `.ptm`, whose rows
//! start at the bottom). That is how relight-cli reads and writes `.rti` files: its own `.rti`
//! fits relight to its own images only this way (`tests/fixtures/relight`, within 1 to 5 8-bit
//! steps; the other way round, 40 to 67 steps on average). RTIViewer could not be built here to
//! check its reading. The same two floats per term serve every texel and all three bands. The writer writes basis type 2
//! (the value RTIBuilder's HSH files carry, as far as we know); the reader accepts any value and
//! keeps it.
//!
//! # The two float arrays: relight's reading
//!
//! Readers disagree on what the two arrays mean. RTIViewer's `.rti` loader reads them as the
//! minimum and maximum of each term (`value = min + (max - min) * c / 255`; seen in an excerpt of
//! a copy of its `hsh.cpp`, GPL, not read further), while its loader of the compressed variant
//! and relight read them as a scale and a bias. This module implements relight's reading,
//! checked against relight-cli's own files and relit images (`tests/test_reference_tools.py`):
//!
//! ```text
//! value_j = bias_j + scale_j * c / 255      (first array scale, second bias)
//! ```
//!
//! in the project's units (1.0 = the viewer's white, byte 255, as for `.ptm`). A file written by
//! RTIBuilder for RTIViewer under the min/max reading decodes differently here; that is the
//! documented disagreement, not a bug of either reader.
//!
//! # What the reader accepts
//!
//! Any number of `#` comment lines before the type line (the first must be `#HSH1.2` or another
//! `#HSH` version), `\r\n` line ends, spaces or tabs between numbers. RTI types other than 3 are
//! rejected with an error naming the type; 3 bands and 1 byte per value only; `terms` must be
//! 1, 4, 9 or 16 (orders 1 to 4). Missing bytes are an error found before anything is allocated;
//! bytes after the data are ignored, as the viewers ignore them. Non-finite floats, or a negative
//! scale, are errors.

use std::path::Path;

use btfrs_core::{Error, Result};
use btfrs_fit::hsh::{HshSlot, MAX_ORDER};
use btfrs_fit::lightfit::Coeffs;
use btfrs_fit::planes::Planes;

/// The RTI type of hemispherical harmonics.
pub const RTI_HSH: u32 = 3;

/// The basis type the writer records.
pub const BASIS_TYPE: u32 = 2;

/// Header lines longer than this are not RTI header lines (probably binary data).
const MAX_LINE: usize = 256;

/// One `.rti` HSH image as the file holds it. Rows top to bottom (row 0 = top of the image);
/// the reader and the writer flip them.
#[derive(Debug, Clone, PartialEq)]
pub struct RtiHsh {
    /// Texels per row.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Coefficients per band (`order^2`: 1, 4, 9 or 16).
    pub terms: usize,
    /// The header's basis type (written as [`BASIS_TYPE`]).
    pub basis_type: u32,
    /// The first float array (`terms`): relight's scale.
    pub scale: Vec<f32>,
    /// The second float array (`terms`): relight's bias.
    pub bias: Vec<f32>,
    /// `[height][width][3 bands][terms]` bytes, row 0 = top.
    pub data: Vec<u8>,
}

impl RtiHsh {
    /// The order (`terms = order^2`).
    pub fn order(&self) -> usize {
        (1..=MAX_ORDER).find(|n| n * n == self.terms).unwrap_or(0)
    }

    /// Coefficient `j` of band `c` at texel `(x, y)` (row `y` from the top), relight's reading:
    /// `bias_j + scale_j * byte / 255`.
    ///
    /// Panics if an index is out of range.
    pub fn coefficient(&self, x: usize, y: usize, c: usize, j: usize) -> f32 {
        assert!(x < self.width && y < self.height && c < 3 && j < self.terms, "index out of range");
        let b = self.data[((y * self.width + x) * 3 + c) * self.terms + j];
        (self.bias[j] as f64 + self.scale[j] as f64 * b as f64 / 255.0) as f32
    }

    /// The single-view HSH this file holds: 8-bit planes (`k = 3 terms`) whose scale is
    /// `scale_j / 255` and whose bias is `bias_j` for every band.
    pub fn to_slot(&self) -> Result<HshSlot> {
        validate(self)?;
        let k = 3 * self.terms;
        let scale = (0..k).map(|p| (self.scale[p % self.terms] as f64 / 255.0) as f32).collect();
        let bias = (0..k).map(|p| self.bias[p % self.terms]).collect();
        let planes = Planes { texels: self.width * self.height, k, q: self.data.clone(), scale, bias };
        Ok(HshSlot { order: self.order(), height: self.height, width: self.width, coeffs: Coeffs::from_planes(planes) })
    }

    /// The file of a single-view HSH ([`btfrs_fit::Hsh::slot`]): its planes must share scale and
    /// bias over the three bands (the slots of a fitted model do). Scale is written as
    /// `255 * scale`, exact for the planes the fit makes (see `btfrs_fit::hsh::quantize_shared`),
    /// so reading the file back gives the same planes.
    pub fn from_slot(slot: &HshSlot) -> Result<RtiHsh> {
        let terms = slot.order * slot.order;
        let p = slot.coeffs.planes.as_ref().ok_or_else(|| {
            Error::arg("model", "expected 8-bit planes (Hsh.slot quantizes a float model for the file)")
        })?;
        if p.k != 3 * terms || p.texels != slot.width * slot.height {
            return Err(Error::arg(
                "model",
                format!("expected {} texels x {} planes", slot.width * slot.height, 3 * terms),
            ));
        }
        for j in 0..terms {
            if (1..3).any(|c| p.scale[c * terms + j] != p.scale[j] || p.bias[c * terms + j] != p.bias[j]) {
                return Err(Error::arg(
                    "model",
                    format!("term {j}: the three bands have different scales or biases; a .rti file shares them"),
                ));
            }
        }
        let img = RtiHsh {
            width: slot.width,
            height: slot.height,
            terms,
            basis_type: BASIS_TYPE,
            scale: (0..terms).map(|j| (p.scale[j] as f64 * 255.0) as f32).collect(),
            bias: p.bias[..terms].to_vec(),
            data: p.q.clone(),
        };
        validate(&img)?;
        Ok(img)
    }
}

/// Check the shape and values of `img`; return the number of data bytes.
fn validate(img: &RtiHsh) -> Result<usize> {
    if img.width == 0 {
        return Err(Error::arg("width", "must be positive, got 0"));
    }
    if img.height == 0 {
        return Err(Error::arg("height", "must be positive, got 0"));
    }
    if img.order() == 0 {
        return Err(Error::arg("terms", format!("expected 1, 4, 9 or 16 (order 1 to 4), got {}", img.terms)));
    }
    let n = img
        .width
        .checked_mul(img.height)
        .and_then(|t| t.checked_mul(3 * img.terms))
        .ok_or_else(|| Error::arg("width", format!("{} x {} texels is too large", img.width, img.height)))?;
    if img.data.len() != n {
        return Err(Error::arg(
            "data",
            format!("expected {n} bytes ({} x {} x 3 x {}), got {}", img.height, img.width, img.terms, img.data.len()),
        ));
    }
    for (name, v) in [("scale", &img.scale), ("bias", &img.bias)] {
        if v.len() != img.terms {
            return Err(Error::arg(name, format!("expected {} values, got {}", img.terms, v.len())));
        }
        if let Some(i) = v.iter().position(|x| !x.is_finite() || (name == "scale" && *x < 0.0)) {
            return Err(Error::arg(
                name,
                format!(
                    "value {i} is {}, not a finite{} number",
                    v[i],
                    if name == "scale" { " non-negative" } else { "" }
                ),
            ));
        }
    }
    Ok(n)
}

/// Encode `img` as the bytes of a `.rti` HSH file.
pub fn encode_rti(img: &RtiHsh) -> Result<Vec<u8>> {
    let n = validate(img)?;
    let (w, h, t) = (img.width, img.height, img.terms);
    let header = format!("#HSH1.2\n{RTI_HSH}\n{w} {h} 3\n{t} {} 1\n", img.basis_type);
    let mut out = Vec::with_capacity(header.len() + 8 * t + n);
    out.extend_from_slice(header.as_bytes());
    for x in img.scale.iter().chain(&img.bias) {
        out.extend_from_slice(&x.to_le_bytes());
    }
    // Rows top first, as relight reads and writes them (unlike `.ptm`).
    out.extend_from_slice(&img.data);
    debug_assert_eq!(out.len(), header.len() + 8 * t + n);
    Ok(out)
}

/// Write `img` to `path` as a `.rti` HSH file, atomically (temporary file + rename).
pub fn write_rti(path: &Path, img: &RtiHsh) -> Result<()> {
    let bytes = encode_rti(img)?;
    crate::atomic::write_atomic(path, |w| w.write_all(&bytes))
}

/// Read a `.rti` HSH file. A missing or unreadable file gives [`Error::Io`]; a file that is not
/// a supported HSH `.rti` gives [`Error::Format`] naming it.
pub fn read_rti(path: &Path) -> Result<RtiHsh> {
    let shown = path.display().to_string();
    let bytes =
        crate::untrusted::read_bytes(path, crate::capture::default_max_bytes(), "an RTI file within max_bytes")?;
    decode_rti(&bytes, &shown)
}

struct Lines<'a> {
    bytes: &'a [u8],
    pos: usize,
    path: &'a str,
}

impl<'a> Lines<'a> {
    fn err(&self, msg: impl std::fmt::Display) -> Error {
        Error::format(self.path, format!("{msg} (at byte {})", self.pos))
    }

    /// The next line without its `\n` (and `\r`).
    fn line(&mut self, what: &str) -> Result<&'a str> {
        let rest = &self.bytes[self.pos..];
        let end = rest.iter().take(MAX_LINE + 1).position(|&b| b == b'\n').ok_or_else(|| {
            if rest.len() <= MAX_LINE {
                self.err(format!("the file ends before the {what}"))
            } else {
                self.err(format!("no {what} line (no line end within {MAX_LINE} bytes)"))
            }
        })?;
        let raw = &rest[..end];
        let raw = raw.strip_suffix(b"\r").unwrap_or(raw);
        let s = std::str::from_utf8(raw).map_err(|_| self.err(format!("the {what} is not text")))?;
        self.pos += end + 1;
        Ok(s)
    }

    /// A line of `n` unsigned integers.
    fn numbers(&mut self, what: &str, n: usize) -> Result<Vec<usize>> {
        let at = self.pos;
        let l = self.line(what)?;
        let v: Vec<&str> = l.split_ascii_whitespace().collect();
        let bad = || {
            Error::format(self.path, format!("{what}: expected {n} non-negative integers, got {l:?} (at byte {at})"))
        };
        if v.len() != n {
            return Err(bad());
        }
        v.iter().map(|s| s.parse::<usize>().map_err(|_| bad())).collect()
    }
}

/// Decode the bytes of a `.rti` HSH file. `path_for_errors` names the file in [`Error::Format`].
pub fn decode_rti(bytes: &[u8], path_for_errors: &str) -> Result<RtiHsh> {
    let mut r = Lines { bytes, pos: 0, path: path_for_errors };
    let first = r.line("version line")?;
    if !first.starts_with("#HSH") {
        let shown: String = first.chars().take(40).collect();
        return Err(Error::format(
            path_for_errors,
            format!("not an HSH .rti file: it starts with {shown:?}, not #HSH1.2"),
        ));
    }
    // Further comment lines, then the type.
    let kind = loop {
        let at = r.pos;
        let l = r.line("RTI type")?;
        if l.starts_with('#') {
            continue;
        }
        let t = l.trim();
        break t.parse::<u32>().map_err(|_| {
            Error::format(path_for_errors, format!("RTI type: expected an integer, got {t:?} (at byte {at})"))
        })?;
    };
    if kind != RTI_HSH {
        let name = match kind {
            1 => " (PTM)",
            2 => " (spherical harmonics)",
            4 => " (adaptive basis)",
            9 => " (image set)",
            _ => "",
        };
        return Err(r.err(format!("RTI type {kind}{name} is not supported; this reader reads HSH files (type 3) only")));
    }
    let dims = r.numbers("width height bands", 3)?;
    let (width, height, bands) = (dims[0], dims[1], dims[2]);
    if width == 0 || height == 0 {
        return Err(r.err(format!("the image is {width} x {height} texels")));
    }
    if bands != 3 {
        return Err(r.err(format!("{bands} colour bands; only 3 (RGB) are supported")));
    }
    let basis = r.numbers("terms basis-type element-size", 3)?;
    let (terms, basis_type, elem) = (basis[0], basis[1], basis[2]);
    if !(1..=MAX_ORDER).any(|n| n * n == terms) {
        return Err(r.err(format!("{terms} basis terms; expected 1, 4, 9 or 16 (HSH order 1 to 4)")));
    }
    if elem != 1 {
        return Err(r.err(format!("element size {elem}; only 1 (8-bit coefficients) is supported")));
    }
    let basis_type = u32::try_from(basis_type).map_err(|_| r.err(format!("basis type {basis_type} is too large")))?;
    let data_len = width
        .checked_mul(height)
        .and_then(|t| t.checked_mul(3 * terms))
        .ok_or_else(|| r.err(format!("{width} x {height} texels is too large")))?;
    let need = 8 * terms + data_len;
    let have = bytes.len() - r.pos;
    if have < need {
        return Err(r.err(format!(
            "the data are truncated: {width} x {height} texels x 3 bands x {terms} terms need {need} bytes after the \
             header (the two float arrays included), the file has {have}"
        )));
    }
    let mut floats =
        bytes[r.pos..r.pos + 8 * terms].chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]));
    let scale: Vec<f32> = floats.by_ref().take(terms).collect();
    let bias: Vec<f32> = floats.collect();
    for (name, v) in [("scale", &scale), ("bias", &bias)] {
        if let Some(i) = v.iter().position(|x| !x.is_finite() || (name == "scale" && *x < 0.0)) {
            return Err(r.err(format!(
                "{name} value {i} is {}, not a finite{} number",
                v[i],
                if name == "scale" { " non-negative" } else { "" }
            )));
        }
    }
    let start = r.pos + 8 * terms;
    // Rows top first (see the module doc).
    let data = bytes[start..start + data_len].to_vec();
    Ok(RtiHsh { width, height, terms, basis_type, scale, bias, data })
}

/// The `.rti` HSH format (RTIViewer's, relight's and OpenLIME's converters' hemispherical
/// harmonics files).
pub const FORMAT: crate::formats::Format = crate::formats::Format {
    name: "rti",
    extension: "rti",
    doc: "RTI hemispherical harmonics (HSH, order 1 to 4, 8-bit), one view slot",
    folder: false,
    index: "",
    export: export_model,
    import: import_model,
};

/// Write one view slot of an HSH model as a `.rti` HSH file (relight's scale/bias reading):
/// `{"scale": [..], "bias": [..]}`, the file's arrays.
fn export_model(model: &dyn btfrs_fit::DynModel, view: usize, path: &Path) -> Result<serde_json::Value> {
    let h: &btfrs_fit::Hsh = crate::formats::concrete(model, "an HSH model")?;
    let img = RtiHsh::from_slot(&h.slot(view)?)?;
    write_rti(path, &img)?;
    Ok(serde_json::json!({"scale": img.scale, "bias": img.bias}))
}

/// Read a `.rti` HSH file as a one-slot HSH model (view = the normal).
fn import_model(path: &Path, limits: &crate::capture::Limits) -> Result<crate::formats::Imported> {
    let shown = path.display().to_string();
    let bytes = crate::untrusted::read_model_file(path, limits.max_bytes, "an RTI file")?;
    let img = decode_rti(&bytes, &shown)?;
    drop(bytes);
    let slot = img.to_slot().map_err(crate::untrusted::as_format(&shown, "coefficients"))?;
    let m = btfrs_fit::Hsh::from_slot(slot).map_err(crate::untrusted::as_format(&shown, "coefficients"))?;
    Ok(crate::formats::Imported::model(Box::new(m)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::fs;

    fn image(w: usize, h: usize, terms: usize, seed: u32) -> RtiHsh {
        let data = (0..w * h * 3 * terms)
            .map(|i| ((i as u32).wrapping_mul(2654435761u32).wrapping_add(seed) >> 24) as u8)
            .collect();
        RtiHsh {
            width: w,
            height: h,
            terms,
            basis_type: BASIS_TYPE,
            scale: (0..terms).map(|j| 0.5 + j as f32 * 0.25).collect(),
            bias: (0..terms).map(|j| -0.1 * j as f32).collect(),
            data,
        }
    }

    #[test]
    fn a_hand_made_file_is_parsed_field_by_field() {
        // 2 x 2 texels, order 2 (4 terms); rows top to bottom; R then G then B per texel.
        let mut f = b"#HSH1.2\r\n# made by hand\n3\n2 2 3\n4 2 1\n".to_vec();
        for x in [1.0f32, 2.0, 0.5, 0.25, 0.0, -1.0, 0.125, 3.0] {
            f.extend_from_slice(&x.to_le_bytes());
        }
        // texel index in file order (top row first) * 12 + band * 4 + term
        for i in 0..4 * 12u8 {
            f.push(i);
        }
        f.extend_from_slice(b"trailing bytes are ignored");
        let img = decode_rti(&f, "hand.rti").unwrap();
        assert_eq!((img.width, img.height, img.terms, img.basis_type, img.order()), (2, 2, 4, 2, 2));
        assert_eq!(img.scale, [1.0, 2.0, 0.5, 0.25]);
        assert_eq!(img.bias, [0.0, -1.0, 0.125, 3.0]);
        // The file's first texel is the top-left one.
        assert_eq!(img.data[..12], (0..12).collect::<Vec<u8>>()[..]);
        // bottom-right texel = file texel 3
        assert_eq!(img.data[(3 * 3) * 4], 36);
        // green, term 1 of the top-right texel (file texel 1): byte 12 + 4 + 1 = 17
        assert_eq!(img.data[(3 + 1) * 4 + 1], 17);
        let want = -1.0 + 2.0 * 17.0 / 255.0;
        assert!((img.coefficient(1, 0, 1, 1) - want).abs() < 1e-6);
        let slot = img.to_slot().unwrap();
        assert_eq!(slot.order, 2);
        let p = slot.coeffs.planes.as_ref().unwrap();
        assert!((p.get(1, 4 + 1) - want).abs() < 1e-6);
        // and written again it is the same file (without the comment and the trailing bytes)
        let again = encode_rti(&img).unwrap();
        let mut want_bytes = b"#HSH1.2\n3\n2 2 3\n4 2 1\n".to_vec();
        want_bytes.extend_from_slice(&f[f.len() - 26 - 48 - 32..f.len() - 26]);
        assert_eq!(again, want_bytes);
    }

    #[test]
    fn round_trip_is_identical_bytes_and_values() {
        for (w, h, t) in [(1, 1, 1), (3, 2, 4), (5, 4, 9), (2, 7, 16)] {
            let img = image(w, h, t, 7);
            let bytes = encode_rti(&img).unwrap();
            let back = decode_rti(&bytes, "x.rti").unwrap();
            assert_eq!(back, img);
            assert_eq!(encode_rti(&back).unwrap(), bytes);
        }
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.rti");
        let img = image(4, 3, 9, 1);
        write_rti(&path, &img).unwrap();
        assert_eq!(read_rti(&path).unwrap(), img);
        let names: Vec<_> = fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(names.len(), 1, "no temporary file left");
    }

    #[test]
    fn slots_round_trip_through_files() {
        use btfrs_core::{directions::ubo81, BtfRef, Monitor};
        use btfrs_fit::hsh::{fit_hsh, HshOptions};
        let d = ubo81();
        let (h, w) = (3, 2);
        let data: Vec<f32> = (0..h * w * d.len() * d.len() * 3).map(|i| ((i * 7919) % 1000) as f32 / 1000.0).collect();
        let btf = BtfRef::new(h, w, &d, &d, &data, None).unwrap();
        let m = fit_hsh(&btf, &HshOptions::default(), &Monitor::new()).unwrap();
        let slot = m.slot(10).unwrap();
        let img = RtiHsh::from_slot(&slot).unwrap();
        let back = decode_rti(&encode_rti(&img).unwrap(), "s.rti").unwrap().to_slot().unwrap();
        assert_eq!(back, slot, "the planes come back bit for bit");
        // relight's reading of the file equals the model's decoded values
        for y in 0..h {
            for x in 0..w {
                for c in 0..3 {
                    for j in 0..9 {
                        let model = slot.coeffs.values[((y * w + x) * 3 + c) * 9 + j];
                        assert!((img.coefficient(x, y, c, j) - model).abs() <= 1e-6 * (1.0 + model.abs()));
                    }
                }
            }
        }
    }

    fn format_error(bytes: &[u8]) -> String {
        match decode_rti(bytes, "bad.rti") {
            Err(e @ Error::Format { .. }) => e.to_string(),
            other => panic!("expected a format error, got {other:?}"),
        }
    }

    #[test]
    fn bad_files_are_named_errors() {
        let good = encode_rti(&image(2, 2, 4, 3)).unwrap();
        let e = format_error(b"#PTM\n1\n");
        assert!(e.contains("bad.rti") && e.contains("not an HSH"), "{e}");
        let e = format_error(b"#HSH1.2\n1\n2 2 3\n");
        assert!(e.contains("bad.rti") && e.contains("RTI type 1") && e.contains("HSH files (type 3)"), "{e}");
        let e = format_error(b"#HSH1.2\n3\n2 2 1\n4 2 1\n");
        assert!(e.contains("1 colour bands"), "{e}");
        let e = format_error(b"#HSH1.2\n3\n2 2 3\n5 2 1\n");
        assert!(e.contains("5 basis terms"), "{e}");
        let e = format_error(b"#HSH1.2\n3\n2 2 3\n4 2 2\n");
        assert!(e.contains("element size 2"), "{e}");
        let e = format_error(b"#HSH1.2\n3\n2 x 3\n");
        assert!(e.contains("width height bands"), "{e}");
        let e = format_error(&good[..good.len() - 1]);
        assert!(e.contains("truncated") && e.contains("need"), "{e}");
        // huge dimensions: refused before allocating
        let e = format_error(b"#HSH1.2\n3\n100000 100000 3\n16 2 1\n");
        assert!(e.contains("truncated"), "{e}");
        let e = format_error(b"#HSH1.2\n3\n18446744073709551615 2 3\n16 2 1\n");
        assert!(e.contains("too large"), "{e}");
        let mut nan = good.clone();
        let at = good.len() - 2 * 2 * 3 * 4 - 32;
        nan[at..at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
        let e = format_error(&nan);
        assert!(e.contains("scale value 0"), "{e}");
        match read_rti(Path::new("/nonexistent/x.rti")) {
            Err(Error::Io { source, .. }) => assert_eq!(source.kind(), std::io::ErrorKind::NotFound),
            other => panic!("{other:?}"),
        }
        let bad = RtiHsh { terms: 3, ..image(1, 1, 4, 0) };
        assert!(encode_rti(&bad).unwrap_err().to_string().contains("terms"));
    }
}
