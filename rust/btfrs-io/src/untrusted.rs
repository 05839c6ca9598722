//! Files from strangers: the one reading discipline every btfrs reader follows, whatever the
//! format (measured captures, `.btfrs` containers, other tools' model files, the folder formats
//! and their index files). A reader opens, reads and parses its files through this module, so
//! each rule holds for every format at once:
//!
//! * **Regular files only** ([`open`]): a folder, FIFO, socket or device (or a link to one) is
//!   an [`Error::Format`] naming the path. The type is read from the path's metadata *before*
//!   it is opened, the file is opened non-blocking (so a FIFO swapped in after the check does
//!   not block either) and the type is checked again on the open handle.
//! * **A size cap per text file** ([`TextKind`]): `info.json` and `material.gltf`
//!   [`MAX_JSON`], `scene.xml` [`MAX_XML`], `.lp` light lists [`MAX_LP`], direction tables
//!   [`MAX_TABLE`]; besides, a text whose parse may take more than `max_bytes` (at most
//!   [`PARSE_FACTOR`] times its size) is refused. The file is never read past its cap.
//! * **UTF-8 text**: invalid UTF-8, UTF-16 (by its byte-order mark) and NUL bytes (UTF-16
//!   without a mark, or binary data) are an [`Error::Format`] naming the file and line.
//! * **Linear parses with caps** ([`parse_json`], [`parse_xml`]): JSON nesting is serde_json's
//!   128 levels and a JSON file holds at most [`MAX_JSON_CONTAINERS`] arrays and objects; XML
//!   is scanned once before it is parsed for at most [`MAX_XML_ATTRIBUTES`]
//!   attributes on one element (the XML parser's duplicate check is quadratic in them) and
//!   [`MAX_XML_DEPTH`] levels of nesting, and parsed with at most [`MAX_XML_NODES`] nodes and no
//!   DTD.
//! * **Declared sizes before allocation** ([`check_declared`], [`image_size`]): what an index
//!   file declares (a width, a height, a number of planes) is checked against `max_bytes` and
//!   against the headers of the images actually present before any buffer of that size is
//!   made, and every image is decoded within the decompression budget of
//!   [`crate::capture::check_image_budget`] ([`read_rgb8`]).
//! * **Repairs are reported** ([`Repairs`]): a value a reader changes (a light vector
//!   normalised, a light a hair below the horizon moved onto it, a roughness clamped to the
//!   model's range) is counted per kind of repair and reported in one summary warning per file
//!   (how many, the range of the values, the first few places), never changed silently.

use std::fmt::Write as _;
use std::fs::File;
use std::io::Read;
use std::path::Path;

use btfrs_core::{Error, Result};

/// The largest JSON index file read (`info.json` of relight and NeuralRTI, `material.gltf`):
/// 16 MiB. btfrs writes a few KB to a few MB (a relight PCA basis of 64 planes on a 64 x 64
/// grid is 3 MB).
pub const MAX_JSON: u64 = 16 << 20;
/// The largest `scene.xml` read: 4 MiB (btfrs writes 4 KB).
pub const MAX_XML: u64 = 4 << 20;
/// The largest `.lp` light list read: 4 MiB (about 100,000 lines).
pub const MAX_LP: u64 = 4 << 20;
/// The largest direction table (`.csv`, `.json`) read: 16 MiB.
pub const MAX_TABLE: u64 = 16 << 20;
/// Most bytes a parsed text may take per byte of text: a JSON number of two bytes (`0,`)
/// becomes a 32-byte value, and a growing list may hold twice what it needs. A text of `n`
/// bytes is refused when `PARSE_FACTOR * n` exceeds `max_bytes`.
pub const PARSE_FACTOR: u64 = 32;
/// Most arrays and objects in a JSON file (btfrs's index files hold a few dozen): each costs
/// an allocation however small its text (`[],` is 3 bytes), which would otherwise let 16 MiB
/// of empty arrays take seconds and a gigabyte to parse.
pub const MAX_JSON_CONTAINERS: usize = 1 << 16;
/// Most attributes on one XML element (btfrs's scenes use 3).
pub const MAX_XML_ATTRIBUTES: usize = 64;
/// Deepest nesting of XML elements (btfrs's scenes: 7).
pub const MAX_XML_DEPTH: usize = 64;
/// Most nodes (elements, texts, comments) of an XML file (btfrs's scenes: about 200).
pub const MAX_XML_NODES: u32 = 1 << 18;
/// How far below the horizon a light may be and still be read (as a light on it): a
/// unit light vector's z of at least minus this (about 1.15 degrees), which a dome's calibration
/// gives for its lowest ring. A light further below is refused.
pub const HORIZON_TOLERANCE: f64 = 0.02;
/// How many places a summary warning lists.
pub const SHOWN_PLACES: usize = 5;

/// A kind of text file and its cap.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TextKind {
    /// What the file is, for messages (`"an index file"`).
    pub what: &'static str,
    /// Its size cap in bytes.
    pub max: u64,
}

/// A JSON index file (`info.json`, `material.gltf`).
pub const JSON_INDEX: TextKind = TextKind { what: "a JSON index file", max: MAX_JSON };
/// An XML index file (`scene.xml`).
pub const XML_INDEX: TextKind = TextKind { what: "an XML scene file", max: MAX_XML };
/// An `.lp` light list.
pub const LIGHT_LIST: TextKind = TextKind { what: "an .lp light list", max: MAX_LP };
/// A direction table.
pub const TABLE: TextKind = TextKind { what: "a direction table", max: MAX_TABLE };

/// What a file that is not a regular file is, in words.
fn what_it_is(ft: &std::fs::FileType) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if ft.is_fifo() {
            return "a FIFO (named pipe)";
        }
        if ft.is_socket() {
            return "a socket";
        }
        if ft.is_block_device() || ft.is_char_device() {
            return "a device";
        }
    }
    if ft.is_dir() {
        "a folder"
    } else {
        "not a regular file"
    }
}

fn not_regular(shown: &str, ft: &std::fs::FileType) -> Error {
    Error::format(shown, format!("is {}; expected a regular file", what_it_is(ft)))
}

/// That `path` (links followed) is a regular file; its length. A missing file is an
/// [`Error::Io`] (not found), anything but a regular file an [`Error::Format`] naming it.
pub fn check_regular(path: &Path) -> Result<u64> {
    let shown = path.display().to_string();
    let meta = std::fs::metadata(path).map_err(|e| Error::io(&shown, e))?;
    if !meta.file_type().is_file() {
        return Err(not_regular(&shown, &meta.file_type()));
    }
    Ok(meta.len())
}

/// Whether `path` (links followed) is a regular file, without an error: what a reader asks
/// before choosing among candidate files (`plane_0.png` or `plane_0.jpg`). A path that exists
/// but is not a regular file counts as present, so that [`open`] refuses it by name.
pub fn present(path: &Path) -> bool {
    std::fs::metadata(path).is_ok()
}

/// Open a regular file for reading: its handle and length (see the module doc). Never blocks
/// on a FIFO.
pub fn open(path: &Path) -> Result<(File, u64)> {
    let shown = path.display().to_string();
    check_regular(path)?;
    let mut opts = std::fs::OpenOptions::new();
    opts.read(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        // Non-blocking: a FIFO put in place after the check opens at once instead of waiting
        // for a writer, and is refused below. On a regular file the flag changes nothing.
        opts.custom_flags(libc::O_NONBLOCK);
    }
    let f = opts.open(path).map_err(|e| Error::io(&shown, e))?;
    let meta = f.metadata().map_err(|e| Error::io(&shown, e))?;
    if !meta.file_type().is_file() {
        return Err(not_regular(&shown, &meta.file_type()));
    }
    Ok((f, meta.len()))
}

/// A regular file's bytes, refused (an [`Error::Format`] naming it) when larger than `max`;
/// never reads more than `max + 1` bytes, whatever the file grows to meanwhile.
pub fn read_bytes(path: &Path, max: u64, what: &str) -> Result<Vec<u8>> {
    let shown = path.display().to_string();
    let (f, len) = open(path)?;
    if len > max {
        return Err(too_big(&shown, len, max, what));
    }
    let mut bytes = Vec::with_capacity(len as usize);
    f.take(max.saturating_add(1)).read_to_end(&mut bytes).map_err(|e| Error::io(&shown, e))?;
    if bytes.len() as u64 > max {
        return Err(too_big(&shown, bytes.len() as u64, max, what));
    }
    Ok(bytes)
}

/// Bytes a one-file model (`.ptm`, `.rti`) needs per byte of its file: the file, its
/// coefficients' bytes and their float values.
pub const MODEL_FILE_FACTOR: u64 = 6;

/// A one-file model's bytes (`what`: `"a PTM file"`), refused when the model it makes
/// ([`MODEL_FILE_FACTOR`] times the file) would exceed `max_bytes`.
pub fn read_model_file(path: &Path, max_bytes: u64, what: &str) -> Result<Vec<u8>> {
    let shown = path.display().to_string();
    let len = check_regular(path)?;
    check_declared(
        &shown,
        &format!("the model of a {len}-byte file ({MODEL_FILE_FACTOR} bytes per byte of the file)"),
        len.checked_mul(MODEL_FILE_FACTOR),
        max_bytes,
    )?;
    read_bytes(path, max_bytes / MODEL_FILE_FACTOR, what)
}

fn too_big(shown: &str, len: u64, max: u64, what: &str) -> Error {
    Error::format(shown, format!("{len} bytes; {what} of at most {max} bytes ({}) is read", human(max)))
}

/// `n` bytes in words (`16 MiB`).
pub fn human(n: u64) -> String {
    match n {
        n if n >= 1 << 30 && n.is_multiple_of(1 << 30) => format!("{} GiB", n >> 30),
        n if n >= 1 << 20 && n.is_multiple_of(1 << 20) => format!("{} MiB", n >> 20),
        n if n >= 1 << 10 && n.is_multiple_of(1 << 10) => format!("{} KiB", n >> 10),
        n => format!("{n} bytes"),
    }
}

/// The line (from 1) of byte offset `at` in `bytes`.
pub fn line_of(bytes: &[u8], at: usize) -> usize {
    bytes[..at.min(bytes.len())].iter().filter(|&&b| b == b'\n').count() + 1
}

/// `bytes` as UTF-8 text without a leading byte-order mark: invalid UTF-8, UTF-16 and NUL
/// bytes are an [`Error::Format`] naming `shown` and the line.
pub fn utf8(bytes: Vec<u8>, shown: &str) -> Result<String> {
    if bytes.starts_with(&[0xFF, 0xFE]) || bytes.starts_with(&[0xFE, 0xFF]) {
        return Err(Error::format(shown, "line 1: UTF-16 text (a UTF-16 byte-order mark); expected UTF-8"));
    }
    if let Some(at) = bytes.iter().position(|&b| b == 0) {
        return Err(Error::format(
            shown,
            format!(
                "line {}: a NUL byte (byte {at}): UTF-16 text or binary data; expected UTF-8 text",
                line_of(&bytes, at)
            ),
        ));
    }
    match String::from_utf8(bytes) {
        Ok(t) => Ok(match t.strip_prefix('\u{feff}') {
            Some(s) => s.to_string(),
            None => t,
        }),
        Err(e) => {
            let at = e.utf8_error().valid_up_to();
            Err(Error::format(
                shown,
                format!("line {}: invalid UTF-8 (byte {at}); expected a UTF-8 text file", line_of(e.as_bytes(), at)),
            ))
        }
    }
}

/// A text file of `kind`: a regular file within the kind's cap, whose parse fits `max_bytes`
/// ([`PARSE_FACTOR`]), as UTF-8 ([`utf8`]).
pub fn read_text(path: &Path, kind: TextKind, max_bytes: u64) -> Result<String> {
    let shown = path.display().to_string();
    let len = check_regular(path)?;
    check_parse(&shown, len, max_bytes)?;
    utf8(read_bytes(path, kind.max, kind.what)?, &shown)
}

/// That a text of `len` bytes may be parsed within `max_bytes`.
pub fn check_parse(shown: &str, len: u64, max_bytes: u64) -> Result<()> {
    let need = len.saturating_mul(PARSE_FACTOR);
    if need > max_bytes {
        return Err(Error::format(
            shown,
            format!(
                "{len} bytes of text may take up to {need} bytes parsed ({PARSE_FACTOR} per byte), more than \
                 max_bytes = {max_bytes}"
            ),
        ));
    }
    Ok(())
}

/// One linear pass over JSON text: at most `max_containers` arrays and objects (outside
/// strings). Whether the text is valid JSON is the parser's to say.
pub fn scan_json(text: &str, shown: &str, max_containers: usize) -> Result<()> {
    let b = text.as_bytes();
    let (mut containers, mut in_string, mut escaped) = (0usize, false, false);
    for (i, &c) in b.iter().enumerate() {
        if in_string {
            if escaped {
                escaped = false;
            } else if c == b'\\' {
                escaped = true;
            } else if c == b'"' {
                in_string = false;
            }
        } else if c == b'"' {
            in_string = true;
        } else if c == b'[' || c == b'{' {
            containers += 1;
            if containers > max_containers {
                return Err(Error::format(
                    shown,
                    format!(
                        "line {}: more than {max_containers} JSON arrays and objects; at most that many are read",
                        line_of(b, i)
                    ),
                ));
            }
        }
    }
    Ok(())
}

/// Parse JSON with at most [`MAX_JSON_CONTAINERS`] arrays and objects ([`scan_json`];
/// serde_json: linear, nesting at most 128 levels). An error names `shown`, the line and the
/// column.
pub fn parse_json(text: &str, shown: &str) -> Result<serde_json::Value> {
    parse_json_within(text, shown, MAX_JSON_CONTAINERS)
}

/// [`parse_json`] with at most `max_containers` arrays and objects (a direction table holds
/// one object per image).
pub fn parse_json_within(text: &str, shown: &str, max_containers: usize) -> Result<serde_json::Value> {
    scan_json(text, shown, max_containers)?;
    serde_json::from_str(text).map_err(|e| {
        let what = if e.to_string().contains("recursion limit") {
            "nested more than 128 levels deep".to_string()
        } else {
            e.to_string()
        };
        Error::format(shown, format!("not valid JSON: {what}"))
    })
}

/// The end of the first `pat` in `b` from `from` (or the end of `b`).
fn skip_past(b: &[u8], from: usize, pat: &[u8]) -> usize {
    match b.get(from..).and_then(|r| r.windows(pat.len()).position(|w| w == pat)) {
        Some(p) => from + p + pat.len(),
        None => b.len(),
    }
}

/// One linear pass over XML text: at most [`MAX_XML_ATTRIBUTES`] attributes on an element and
/// [`MAX_XML_DEPTH`] levels of nesting. It follows the markup (comments, CDATA, processing
/// instructions, declarations, quoted attribute values) only as far as counting needs;
/// whether the text is well-formed is the parser's to say.
pub fn scan_xml(text: &str, shown: &str) -> Result<()> {
    let b = text.as_bytes();
    let mut i = 0;
    let mut depth = 0usize;
    while i < b.len() {
        let Some(lt) = b[i..].iter().position(|&c| c == b'<') else { break };
        i += lt;
        let rest = &b[i..];
        if rest.starts_with(b"<!--") {
            i = skip_past(b, i + 4, b"-->");
        } else if rest.starts_with(b"<![CDATA[") {
            i = skip_past(b, i + 9, b"]]>");
        } else if rest.starts_with(b"<?") {
            i = skip_past(b, i + 2, b"?>");
        } else if rest.starts_with(b"<!") {
            i = skip_past(b, i + 2, b">");
        } else if rest.starts_with(b"</") {
            depth = depth.saturating_sub(1);
            i = skip_past(b, i + 2, b">");
        } else {
            let start = i;
            let (mut j, mut attrs, mut quote) = (i + 1, 0usize, 0u8);
            while j < b.len() {
                let c = b[j];
                if quote != 0 {
                    if c == quote {
                        quote = 0;
                    }
                } else if c == b'"' || c == b'\'' {
                    quote = c;
                } else if c == b'=' {
                    attrs += 1;
                    if attrs > MAX_XML_ATTRIBUTES {
                        return Err(Error::format(
                            shown,
                            format!(
                                "line {}: an element with more than {MAX_XML_ATTRIBUTES} attributes; at most \
                                 {MAX_XML_ATTRIBUTES} are read",
                                line_of(b, start)
                            ),
                        ));
                    }
                } else if c == b'>' {
                    break;
                }
                j += 1;
            }
            if !(j < b.len() && b[j - 1] == b'/') {
                depth += 1;
                if depth > MAX_XML_DEPTH {
                    return Err(Error::format(
                        shown,
                        format!(
                            "line {}: elements nested more than {MAX_XML_DEPTH} levels deep; at most \
                             {MAX_XML_DEPTH} are read",
                            line_of(b, start)
                        ),
                    ));
                }
            }
            i = j + 1;
        }
    }
    Ok(())
}

/// Parse XML within the caps of [`scan_xml`], at most [`MAX_XML_NODES`] nodes and no DTD.
pub fn parse_xml<'i>(text: &'i str, shown: &str) -> Result<roxmltree::Document<'i>> {
    scan_xml(text, shown)?;
    let opts = roxmltree::ParsingOptions { allow_dtd: false, nodes_limit: MAX_XML_NODES, ..Default::default() };
    roxmltree::Document::parse_with_options(text, opts).map_err(|e| {
        let what = match e {
            roxmltree::Error::NodesLimitReached => {
                format!("more than {MAX_XML_NODES} XML nodes; at most that many are read")
            }
            e => e.to_string(),
        };
        Error::format(shown, format!("not valid XML: {what}"))
    })
}

/// That `need` bytes (`None`: more than 2^64), declared by `shown` for `what`, fit `max_bytes`;
/// checked before anything of that size is allocated.
pub fn check_declared(shown: &str, what: &str, need: Option<u64>, max_bytes: u64) -> Result<()> {
    if need.is_none_or(|n| n > max_bytes) {
        let n = need.map_or_else(|| "more than 2^64".to_string(), |n| n.to_string());
        return Err(Error::format(shown, format!("{what} needs {n} bytes, more than max_bytes = {max_bytes}")));
    }
    Ok(())
}

/// An error of what a file's values made (a model's own check: `InvalidArgument`, a
/// degenerate or non-finite result) restated as the [`Error::Format`] of the file `shown` that
/// holds the values, `what` naming the part; I/O errors, format errors and interrupts pass
/// unchanged.
pub fn as_format<'a>(shown: &'a str, what: &'a str) -> impl FnOnce(Error) -> Error + 'a {
    move |e| match e {
        Error::InvalidArgument { .. } | Error::ArgumentType { .. } | Error::Degenerate(_) | Error::Numerical(_) => {
            Error::format(shown, format!("{what}: {e}"))
        }
        e => e,
    }
}

/// An image file's width and height from its header alone (JPEG, PNG or TIFF; nothing is
/// decoded), the file checked as [`open`] does.
pub fn image_size(path: &Path) -> Result<(u32, u32)> {
    let shown = path.display().to_string();
    let (f, _) = open(path)?;
    image::ImageReader::new(std::io::BufReader::new(f))
        .with_guessed_format()
        .map_err(|e| Error::io(&shown, e))?
        .into_dimensions()
        .map_err(|e| Error::format(&shown, format!("not a readable image: {e}")))
}

/// The first of `candidates` that exists (whatever it is: [`open`] refuses it later by name
/// when it is not a regular file).
pub fn first_present(candidates: impl IntoIterator<Item = std::path::PathBuf>) -> Option<std::path::PathBuf> {
    candidates.into_iter().find(|p| present(p))
}

/// That every image of `files` is `width x height` pixels, from their headers alone: what an
/// index file (`index`, for messages) declares is checked against the images actually there
/// before anything of the declared size is allocated.
pub fn check_image_sizes(files: &[std::path::PathBuf], width: usize, height: usize, index: &str) -> Result<()> {
    for f in files {
        let (w, h) = image_size(f)?;
        if (w as usize, h as usize) != (width, height) {
            return Err(Error::format(f.display(), format!("{w} x {h} pixels; {index} declares {width} x {height}")));
        }
    }
    Ok(())
}

/// An 8-bit image of `width x height` pixels as RGB bytes (row 0 the top; grey images
/// replicated, an alpha channel dropped), within `max_bytes` and the decompression budget of
/// every image btfrs reads ([`crate::decode`]); another size, or 16-bit samples, are an
/// [`Error::Format`] naming the file. Call [`image_size`] on every image of a set before
/// allocating for the set.
pub fn read_rgb8(path: &Path, width: usize, height: usize, max_bytes: u64) -> Result<Vec<u8>> {
    let shown = path.display().to_string();
    let raw = crate::decode::read_raw(path, crate::decode::Transfer::Linear, max_bytes)?;
    if (raw.width, raw.height) != (width, height) {
        return Err(Error::format(
            &shown,
            format!(
                "{} x {} pixels; expected {width} x {height} (the size its index file declares)",
                raw.width, raw.height
            ),
        ));
    }
    raw.rgb8().ok_or_else(|| Error::format(&shown, "expected 8-bit samples (grey, RGB or RGBA)"))
}

/// Values of one kind that a reader changed in one file, reported as one warning: how many,
/// the range of a measure of them, and the first [`SHOWN_PLACES`] places.
#[derive(Debug, Clone)]
pub struct Repairs {
    shown: String,
    what: String,
    measure: &'static str,
    unit: &'static str,
    count: usize,
    lo: f64,
    hi: f64,
    places: Vec<String>,
}

/// `x` rounded to 6 decimals, shortest form.
fn short(x: f64) -> String {
    format!("{}", (x * 1e6).round() / 1e6)
}

impl Repairs {
    /// Repairs of `what` (`"light vector(s) normalised"`) in `shown`, each with a value of
    /// `measure` (`"length(s)"`) at a place counted in `unit` (`"line(s)"`, or `""` when each
    /// place names itself); `(s)` becomes the plural's `s` when there is more than one.
    pub fn new(shown: &str, what: impl Into<String>, measure: &'static str, unit: &'static str) -> Repairs {
        Repairs {
            shown: shown.to_string(),
            what: what.into(),
            measure,
            unit,
            count: 0,
            lo: f64::INFINITY,
            hi: f64::NEG_INFINITY,
            places: Vec::new(),
        }
    }

    /// One repair at `place` (a line number) of a value `value` (of the measure).
    pub fn add(&mut self, place: impl std::fmt::Display, value: f64) {
        self.count += 1;
        self.lo = self.lo.min(value);
        self.hi = self.hi.max(value);
        if self.places.len() < SHOWN_PLACES {
            self.places.push(place.to_string());
        }
    }

    /// How many repairs.
    pub fn count(&self) -> usize {
        self.count
    }

    /// The summary warning (`None` when nothing was repaired).
    pub fn warning(&self) -> Option<String> {
        if self.count == 0 {
            return None;
        }
        let range =
            if self.lo == self.hi { short(self.lo) } else { format!("{} to {}", short(self.lo), short(self.hi)) };
        let n = |t: &str, k: usize| t.replace("(s)", if k == 1 { "" } else { "s" });
        let unit = n(self.unit, self.places.len());
        let mut s = format!(
            "{}: {} {} ({} {range}) at {unit}{}{}",
            self.shown,
            self.count,
            n(&self.what, self.count),
            n(self.measure, self.count),
            if unit.is_empty() { "" } else { " " },
            self.places.join(", ")
        );
        if self.count > self.places.len() {
            let _ = write!(s, " and {} more", self.count - self.places.len());
        }
        Some(s)
    }

    /// Push the summary warning, if any, onto `warnings`.
    pub fn report(&self, warnings: &mut Vec<String>) {
        warnings.extend(self.warning());
    }
}

/// Light or view vectors read from a file, brought to unit vectors above the surface: a length
/// off by more than 1e-3 is normalised, a vector at most [`HORIZON_TOLERANCE`] below the
/// horizon (its unit z) is moved onto it (z = 0, renormalised), each kind counted in one
/// [`Repairs`] summary; anything else that is not a direction above the surface is refused by
/// the caller, which names the line.
#[derive(Debug, Clone)]
pub struct Directions {
    normalised: Repairs,
    lifted: Repairs,
}

impl Directions {
    /// Vectors of `what` (`"light"`, `"view"`) in `shown`, at places counted in `unit`
    /// (`"line(s)"`, or `""`).
    pub fn new(shown: &str, what: &str, unit: &'static str) -> Directions {
        Directions {
            normalised: Repairs::new(shown, format!("{what} vector(s) normalised"), "length(s)", unit),
            lifted: Repairs::new(
                shown,
                format!("{what}(s) a hair below the horizon (unit z >= -{HORIZON_TOLERANCE}) moved onto it"),
                "z",
                unit,
            ),
        }
    }

    /// The unit direction of `v` at `place`, or `None` when it is not a direction above the
    /// surface (zero, not finite, or further below the horizon than the tolerance).
    pub fn unit(&mut self, place: impl std::fmt::Display + Clone, v: [f64; 3]) -> Option<[f64; 3]> {
        let [x, y, z] = v;
        let n = (x * x + y * y + z * z).sqrt();
        if !(n.is_finite() && n > 0.0) {
            return None;
        }
        let u = [x / n, y / n, z / n];
        if u[2] < -HORIZON_TOLERANCE {
            return None;
        }
        if (n - 1.0).abs() > 1e-3 {
            self.normalised.add(place.clone(), n);
        }
        if u[2] < 0.0 {
            let r = (u[0] * u[0] + u[1] * u[1]).sqrt();
            self.lifted.add(place, u[2]);
            return Some([u[0] / r, u[1] / r, 0.0]);
        }
        Some(u)
    }

    /// Push the summary warnings onto `warnings`.
    pub fn report(&self, warnings: &mut Vec<String>) {
        self.normalised.report(warnings);
        self.lifted.report(warnings);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn xml_caps_count_attributes_and_depth_and_skip_quoted_and_commented_markup() {
        let attrs = |n: usize| {
            let a: String = (0..n).map(|i| format!(" a{i}=\"x=y>\"")).collect();
            format!("<?xml version=\"1.0\"?>\n<!-- a=b c=d <e> -->\n<scene{a}/>")
        };
        assert!(scan_xml(&attrs(MAX_XML_ATTRIBUTES), "s.xml").is_ok());
        let e = scan_xml(&attrs(MAX_XML_ATTRIBUTES + 1), "s.xml").unwrap_err().to_string();
        assert!(e.starts_with("s.xml: line 3: an element with more than 64 attributes"), "{e}");
        let nest = |n: usize| format!("{}{}", "<a>".repeat(n), "</a>".repeat(n));
        assert!(scan_xml(&nest(MAX_XML_DEPTH), "s.xml").is_ok());
        // siblings do not add up
        assert!(scan_xml(&"<a><b/><c></c></a>".repeat(1000), "s.xml").is_ok());
        let e = scan_xml(&nest(MAX_XML_DEPTH + 1), "s.xml").unwrap_err().to_string();
        assert!(e.contains("nested more than 64 levels"), "{e}");
        // The parser agrees on what passes: both documents parse.
        assert!(parse_xml(&attrs(MAX_XML_ATTRIBUTES), "s.xml").is_ok());
        assert!(parse_xml(&nest(MAX_XML_DEPTH), "s.xml").is_ok());
        // A DTD is refused by the parser.
        let e = parse_xml("<!DOCTYPE x [<!ENTITY a \"b\">]><x>&a;</x>", "s.xml").unwrap_err().to_string();
        assert!(e.contains("not valid XML"), "{e}");
    }

    #[test]
    fn json_nesting_is_capped_and_errors_give_the_line() {
        let deep = format!("{}{}", "[".repeat(129), "]".repeat(129));
        let e = parse_json(&deep, "info.json").unwrap_err().to_string();
        assert!(e.contains("nested more than 128 levels"), "{e}");
        let ok = format!("{}{}", "[".repeat(100), "]".repeat(100));
        assert!(parse_json(&ok, "info.json").is_ok());
        // Containers are counted outside strings only.
        let many = |n: usize| format!("[{}0, \"[[{{\\\"[\"]", "[],".repeat(n - 1));
        assert!(parse_json(&many(MAX_JSON_CONTAINERS), "info.json").is_ok());
        let e = parse_json(&many(MAX_JSON_CONTAINERS + 1), "info.json").unwrap_err().to_string();
        assert!(e.contains("line 1: more than 65536 JSON arrays and objects"), "{e}");
        let e = parse_json("{\n\"a\": 1,\n\"b\": }", "info.json").unwrap_err().to_string();
        assert!(e.contains("line 3"), "{e}");
    }

    #[test]
    fn text_must_be_utf8_without_nul_bytes() {
        let e = utf8(b"ab\ncd\xff".to_vec(), "f").unwrap_err().to_string();
        assert_eq!(e, "f: line 2: invalid UTF-8 (byte 5); expected a UTF-8 text file");
        let e = utf8(b"\xff\xfe{\0}\0".to_vec(), "f").unwrap_err().to_string();
        assert!(e.contains("UTF-16"), "{e}");
        let e = utf8(b"{\0\"\0".to_vec(), "f").unwrap_err().to_string();
        assert!(e.contains("NUL byte") && e.contains("line 1"), "{e}");
        assert_eq!(utf8("\u{feff}ok".as_bytes().to_vec(), "f").unwrap(), "ok");
    }

    #[test]
    fn only_regular_files_are_read_and_caps_hold() {
        let dir = tempfile::tempdir().unwrap();
        let e = open(dir.path()).unwrap_err().to_string();
        assert!(e.ends_with("is a folder; expected a regular file"), "{e}");
        let p = dir.path().join("t.lp");
        std::fs::write(&p, "x".repeat(100)).unwrap();
        assert_eq!(read_bytes(&p, 100, "t").unwrap().len(), 100);
        let e = read_bytes(&p, 99, "a light list").unwrap_err().to_string();
        assert!(e.contains("100 bytes; a light list of at most 99 bytes"), "{e}");
        let e = read_text(&p, LIGHT_LIST, 100 * PARSE_FACTOR - 1).unwrap_err().to_string();
        assert!(e.contains("more than max_bytes"), "{e}");
        assert!(read_text(&p, LIGHT_LIST, 100 * PARSE_FACTOR).is_ok());
        #[cfg(unix)]
        {
            let e = open(Path::new("/dev/zero")).unwrap_err().to_string();
            assert!(e.ends_with("is a device; expected a regular file"), "{e}");
            let link = dir.path().join("zero");
            std::os::unix::fs::symlink("/dev/zero", &link).unwrap();
            assert!(open(&link).unwrap_err().to_string().contains("is a device"));
        }
    }

    #[test]
    fn repairs_are_summarised_in_one_warning() {
        let mut r = Repairs::new("d.lp", "light vector(s) normalised", "length(s)", "line(s)");
        assert_eq!(r.warning(), None);
        for (i, l) in [0.9991, 1.0012, 0.998, 1.0007, 1.002, 0.9995, 1.0001].iter().enumerate() {
            r.add(i + 2, *l);
        }
        assert_eq!(
            r.warning().unwrap(),
            "d.lp: 7 light vectors normalised (lengths 0.998 to 1.002) at lines 2, 3, 4, 5, 6 and 2 more"
        );
        let mut r = Repairs::new("s.xml", "value(s) raised", "value(s)", "pixel(s)");
        r.add(3, 0.0);
        assert_eq!(r.warning().unwrap(), "s.xml: 1 value raised (value 0) at pixel 3");
        let mut r = Repairs::new("t.csv", "thing(s) done", "value(s)", "");
        r.add("line 3", 1.0);
        r.add("entry 4", 2.0);
        assert_eq!(r.warning().unwrap(), "t.csv: 2 things done (values 1 to 2) at line 3, entry 4");
    }

    #[test]
    fn directions_are_normalised_and_lifted_onto_the_horizon_within_the_tolerance() {
        let mut d = Directions::new("d.lp", "light", "line(s)");
        assert_eq!(d.unit(2, [0.0, 0.0, 1.0]), Some([0.0, 0.0, 1.0]));
        let u = d.unit(3, [0.0, 0.0, 1.01]).unwrap();
        assert!((u[2] - 1.0).abs() < 1e-15);
        // a hair below: onto the horizon, unit length
        let u = d.unit(4, [0.6, 0.8, -0.0012]).unwrap();
        assert!(u[2] == 0.0 && ((u[0] * u[0] + u[1] * u[1]).sqrt() - 1.0).abs() < 1e-15, "{u:?}");
        assert!((u[0] - 0.6).abs() < 1e-5 && (u[1] - 0.8).abs() < 1e-5);
        assert!(d.unit(5, [1.0, 0.0, -0.019]).is_some());
        // clearly below, zero, not finite: refused
        assert_eq!(d.unit(6, [1.0, 0.0, -0.03]), None);
        assert_eq!(d.unit(7, [0.0, 0.0, 0.0]), None);
        assert_eq!(d.unit(8, [f64::INFINITY, 0.0, 1.0]), None);
        let mut w = Vec::new();
        d.report(&mut w);
        assert_eq!(w.len(), 2, "{w:?}");
        assert_eq!(w[0], "d.lp: 1 light vector normalised (length 1.01) at line 3");
        assert!(
            w[1].starts_with("d.lp: 2 lights a hair below the horizon (unit z >= -0.02) moved onto it (z ")
                && w[1].ends_with("at lines 4, 5")
        );
    }
}
