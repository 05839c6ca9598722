//! Seeded mutation tests of every reader in btfrs-io (issue 10, "robustness holes").
//!
//! Per format, a valid file is written and then [`CASES`] corrupted variants of it: random byte
//! flips, truncations at random lengths, and header fields inflated to huge sizes, counts or
//! dimensions (rewritten so that the rest of the file stays valid: the container's JSON is
//! re-padded, the PNG chunk CRC recomputed). Every read must be a clean read or an
//! [`Error::Format`]; never a panic, never slower than [`SLOW`], and never an allocation larger
//! than the file can justify (a counting global allocator records the largest single allocation
//! made during each read). A failure prints the format, the case's seed and the mutation, so
//! `case(format, seed)` reproduces it.

use btfrs_core::Error;
use btfrs_io::container::{self, as_bytes, ArrayRef, Dtype};
use btfrs_io::image;
use btfrs_io::ptm_file::{self, PtmFormat, PtmImage};
use btfrs_io::ubo2014::{self, DfmfChannelData, DfmfFile, DfmfView, Scalar};
use std::alloc::{GlobalAlloc, Layout, System};
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

/// Corrupted files per format.
const CASES: u64 = 400;
/// The fixed seed every case's seed derives from.
const SEED: u64 = 0xB7F5_0010;
/// A read slower than this counts as a hang (the valid files read in well under a millisecond).
const SLOW: Duration = Duration::from_secs(2);

/// Records the largest single allocation since the last reset.
struct Counting;
static LARGEST: AtomicUsize = AtomicUsize::new(0);

// SAFETY: forwards to the system allocator; only records sizes.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        LARGEST.fetch_max(l.size(), Ordering::Relaxed);
        // SAFETY: same layout, forwarded.
        unsafe { System.alloc(l) }
    }
    unsafe fn alloc_zeroed(&self, l: Layout) -> *mut u8 {
        LARGEST.fetch_max(l.size(), Ordering::Relaxed);
        // SAFETY: same layout, forwarded.
        unsafe { System.alloc_zeroed(l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, new: usize) -> *mut u8 {
        LARGEST.fetch_max(new, Ordering::Relaxed);
        // SAFETY: same pointer and layout, forwarded.
        unsafe { System.realloc(p, l, new) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        // SAFETY: same pointer and layout, forwarded.
        unsafe { System.dealloc(p, l) }
    }
}

#[global_allocator]
static ALLOC: Counting = Counting;

/// The counter is global: the tests of this file take turns.
static SERIAL: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// splitmix64: a small, well-mixed deterministic generator.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
    fn pick<'a, T>(&mut self, xs: &'a [T]) -> &'a T {
        &xs[self.below(xs.len())]
    }
}

/// Huge or degenerate replacements for numeric header fields.
const HUGE_DECIMAL: &[&str] = &[
    "0",
    "1",
    "65536",
    "4294967295",
    "4294967296",
    "9223372036854775807",
    "18446744073709551615",
    "18446744073709551616",
    "99999999999999999999999",
    "-1",
    "1e300",
];
const HUGE_U32: &[u32] = &[0, 1, 65535, 65536, 1 << 20, 1 << 24, 0x7fff_ffff, 0x8000_0000, u32::MAX];

/// The readers under test.
#[derive(Debug, Clone, Copy)]
enum Format {
    Container,
    PtmLrgb,
    PtmRgb,
    Png,
    Exr,
    Dfmf,
}

impl Format {
    /// Bytes the reader may allocate at once per byte of file (its output's expansion), plus
    /// [`SLACK`] for buffers of fixed size.
    fn alloc_ratio(self) -> u64 {
        match self {
            Format::Container => 1,
            // 18 bytes of an RGB texel become 18 f32.
            Format::PtmLrgb | Format::PtmRgb => 4,
            // 1032:1 deflate, then 4-byte floats of 3 of every 3 or 4 bytes.
            Format::Png => 4 * 1032,
            // 2048:1 (see image.rs), 12-byte output pixels from 6-byte ones at least.
            Format::Exr => 2 * 2048,
            // A low-rank file expands: 12 texels x 6 pairs x 3 f32 (864 bytes) from ~830 bytes.
            Format::Dfmf => 16,
        }
    }
}

/// Fixed-size buffers any reader may allocate whatever the file (a BufReader, the exr crate's
/// read chunks, the PNG decoder's minimum limit).
const SLACK: u64 = 1 << 20;

/// A small DFMF file: 2 views x 3 lights, 4 x 3 texels, half and float channels.
fn dfmf_file() -> DfmfFile {
    let lights: Vec<[f32; 2]> = (0..3).map(|l| [0.2 + 0.3 * l as f32, 0.9 * l as f32]).collect();
    let views = (0..2).map(|v| DfmfView { theta: 0.4 * v as f32, phi: v as f32, lights: lights.clone() }).collect();
    let scalars = [Scalar::Half, Scalar::F32, Scalar::Half];
    let channels = (0..3)
        .map(|c| {
            let k = c + 1;
            let val = |i: usize| scalars[c].quantize(((i * 37 + c * 11) % 23) as f64 / 23.0 - 0.4);
            DfmfChannelData {
                scalar: scalars[c],
                s: (0..k).map(val).collect(),
                u: (0..6 * k).map(val).collect(),
                sxv: (0..12 * k).map(|i| val(i + 5)).collect(),
            }
        })
        .collect();
    DfmfFile {
        version: 4,
        measurement_setup: "setup".into(),
        image_sensor: "sensor".into(),
        light_source: "light".into(),
        pixels_per_mm: 10.0,
        rgb_scale: [1.0; 3],
        cosine_flag: 0,
        xml: "<m/>".into(),
        channel_names: vec!["Y".into(), "U".into(), "V".into()],
        views,
        width: 4,
        height: 3,
        rotations: Some(vec![[0.0; 9]]),
        color_model: 11,
        color_mean: [0.0; 3],
        color_transform: [0.0; 9],
        channels,
    }
}

fn valid_file(format: Format, dir: &Path) -> Vec<u8> {
    let p = dir.join("valid");
    match format {
        Format::Dfmf => {
            ubo2014::write_dfmf(&p, &dfmf_file()).unwrap();
            std::fs::read(&p).unwrap()
        }
        Format::Container => {
            let a: Vec<f32> = (0..2 * 3 * 4).map(|i| i as f32 * 0.25 - 1.0).collect();
            let b: Vec<u16> = (0..10).map(|i| i * 1000).collect();
            let c: Vec<f64> = vec![0.5, -0.25, 1e-3];
            let d: Vec<i32> = vec![-1, 0, 7, 1 << 20];
            let e = [1u8, 0, 1, 1, 0, 0];
            let meta = serde_json::json!({"layout": "HWVL3", "options": {"levels": 2, "m": 4}});
            container::write(
                &p,
                "btf",
                meta,
                &[
                    ArrayRef { name: "data", dtype: Dtype::F32, shape: &[2, 3, 4], bytes: as_bytes(&a) },
                    ArrayRef { name: "ids", dtype: Dtype::U16, shape: &[10], bytes: as_bytes(&b) },
                    ArrayRef { name: "views", dtype: Dtype::F64, shape: &[1, 3], bytes: as_bytes(&c) },
                    ArrayRef { name: "index", dtype: Dtype::I32, shape: &[2, 2], bytes: as_bytes(&d) },
                    ArrayRef { name: "mask", dtype: Dtype::Bool, shape: &[2, 3], bytes: &e },
                    ArrayRef { name: "bytes", dtype: Dtype::U8, shape: &[3, 2], bytes: &e },
                ],
            )
            .unwrap();
            std::fs::read(&p).unwrap()
        }
        Format::PtmLrgb | Format::PtmRgb => {
            let (w, h) = (5, 3);
            let lrgb = matches!(format, Format::PtmLrgb);
            let per = if lrgb { 6 } else { 18 };
            let coeffs = (0..w * h * per).map(|i| ((i * 37) % 101) as f32 / 101.0 - 0.3).collect();
            let rgb = lrgb.then(|| (0..w * h * 3).map(|i| ((i * 13) % 17) as f32 / 16.0).collect());
            let format = if lrgb { PtmFormat::Lrgb } else { PtmFormat::Rgb };
            ptm_file::encode_ptm(&PtmImage { width: w, height: h, format, coeffs, rgb }).unwrap().0
        }
        Format::Png | Format::Exr => {
            let (w, h) = (7, 5);
            let img: Vec<f32> = (0..w * h * 3).map(|i| ((i * 29) % 97) as f32 / 96.0).collect();
            if matches!(format, Format::Png) {
                image::write_png(&p, &img, w, h, 1.0).unwrap();
            } else {
                image::write_exr(&p, &img, w, h).unwrap();
            }
            std::fs::read(&p).unwrap()
        }
    }
}

/// CRC-32 (ISO 3309, as PNG uses), bitwise.
fn crc32(bytes: &[u8]) -> u32 {
    let mut c = !0u32;
    for &b in bytes {
        c ^= u32::from(b);
        for _ in 0..8 {
            c = if c & 1 != 0 { 0xEDB8_8320 ^ (c >> 1) } else { c >> 1 };
        }
    }
    !c
}

/// Byte ranges of the decimal numbers in `text` that follow `[`, `,`, `:` or whitespace (JSON
/// numbers and PTM header fields, not digits inside names).
fn numbers(text: &[u8]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < text.len() {
        let starts = (text[i].is_ascii_digit() || text[i] == b'-')
            && (i == 0 || matches!(text[i - 1], b'[' | b',' | b':' | b' ' | b'\n' | b'\r' | b'\t'));
        if starts {
            let j = i + 1 + text[i + 1..].iter().take_while(|c| c.is_ascii_digit() || b".eE+-".contains(c)).count();
            out.push((i, j));
            i = j;
        } else {
            i += 1;
        }
    }
    out
}

/// Inflate one header field of `valid` (format-aware); returns the file and what was done.
fn inflate(format: Format, valid: &[u8], rng: &mut Rng) -> (Vec<u8>, String) {
    match format {
        Format::Dfmf => {
            // The u32 size and count fields, at the offsets the layout gives.
            let f = dfmf_file();
            let xml_len = 10 + 264 + 4;
            let names = xml_len + 4 + f.xml.len();
            let views = names + 4 + 3 * 5;
            let light_counts: Vec<usize> = (0..2).map(|v| views + 4 + v * (12 + 3 * 8) + 8).collect();
            let size = views + 4 + 2 * (12 + 3 * 8);
            let rot = size + 8;
            let dfmf = rot + 4 + 36;
            let mut fields = vec![("meta size", 10), ("version", 14), ("XML length", xml_len)];
            fields.extend([("channel count", names), ("view count", views), ("width", size), ("height", size + 4)]);
            fields.extend([("rotation count", rot), ("components", dfmf), ("colour model", dfmf + 4)]);
            fields.extend(light_counts.iter().map(|&a| ("light count", a)));
            let mut ch = dfmf + 4 + 4 + 12 + 36;
            for c in &f.channels {
                fields.extend([("channel components", ch + 1), ("channel rows", ch + 5), ("channel columns", ch + 9)]);
                ch += 13 + (c.s.len() + c.u.len() + c.sxv.len()) * c.scalar.size();
            }
            assert_eq!(ch, valid.len());
            let (name, at) = *rng.pick(&fields);
            let v = *rng.pick(HUGE_U32);
            let mut b = valid.to_vec();
            b[at..at + 4].copy_from_slice(&v.to_le_bytes());
            (b, format!("{name} at {at} := {v}"))
        }
        Format::Container => {
            let hlen = u64::from_le_bytes(valid[8..16].try_into().unwrap()) as usize;
            // The writer starts the data at the first 64-byte boundary after the header.
            let data_start = (16 + hlen).div_ceil(64) * 64;
            if rng.below(8) == 0 {
                // The header length itself.
                let v = u64::from(*rng.pick(HUGE_U32)) << rng.below(33);
                let mut f = valid.to_vec();
                f[8..16].copy_from_slice(&v.to_le_bytes());
                return (f, format!("header length := {v}"));
            }
            let text = &valid[16..16 + hlen];
            let (mut json, what) = if rng.below(4) == 0 {
                // A dtype changed: the shape no longer matches the bytes.
                let from = *rng.pick(&["\"f32\"", "\"u16\"", "\"f64\"", "\"i32\"", "\"bool\"", "\"u8\""]);
                let to = *rng.pick(&["\"f64\"", "\"u8\"", "\"f32\"", "\"bool\"", "\"f16\""]);
                let s = String::from_utf8(text.to_vec()).unwrap().replacen(from, to, 1);
                (s.into_bytes(), format!("dtype {from} := {to}"))
            } else {
                let nums = numbers(text);
                let (a, b) = *rng.pick(&nums);
                let v = *rng.pick(HUGE_DECIMAL);
                let mut s = text[..a].to_vec();
                s.extend_from_slice(v.as_bytes());
                s.extend_from_slice(&text[b..]);
                (s, format!("header number {:?} at {a} := {v}", String::from_utf8_lossy(&text[a..b])))
            };
            // Keep the arrays where they are: pad the new header with JSON whitespace up to the
            // old data start when it fits.
            let room = data_start - 16;
            if json.len() <= room {
                json.resize(room, b' ');
            }
            let mut f = valid[..8].to_vec();
            f.extend_from_slice(&(json.len() as u64).to_le_bytes());
            f.extend_from_slice(&json);
            f.extend_from_slice(&valid[data_start.min(f.len())..]);
            (f, what)
        }
        Format::PtmLrgb | Format::PtmRgb => {
            // The header is six lines; fields 3 and 4 (width, height) and the scales and biases.
            let mut lines = 0;
            let end = valid
                .iter()
                .position(|&b| {
                    lines += usize::from(b == b'\n');
                    lines == 6
                })
                .unwrap()
                + 1;
            let head = &valid[..end];
            let nums = numbers(head);
            let k = rng.below(nums.len());
            let (a, b) = nums[k];
            let v = if k < 2 {
                *rng.pick(HUGE_DECIMAL)
            } else {
                *rng.pick(&["1e38", "3.4e38", "1e300", "-1e300", "nan", "inf", "1e-45", "0", "-0"])
            };
            let mut f = head[..a].to_vec();
            f.extend_from_slice(v.as_bytes());
            f.extend_from_slice(&valid[b..]);
            (f, format!("header field {k} {:?} := {v}", String::from_utf8_lossy(&head[a..b])))
        }
        Format::Png => {
            let mut f = valid.to_vec();
            // IHDR: length at 8, type at 12, width 16, height 20, depth 24, colour 25, ..., CRC 29.
            let what = match rng.below(4) {
                0 | 1 => {
                    let (w, h) = (*rng.pick(HUGE_U32), *rng.pick(HUGE_U32));
                    f[16..20].copy_from_slice(&w.to_be_bytes());
                    f[20..24].copy_from_slice(&h.to_be_bytes());
                    format!("IHDR size := {w} x {h}")
                }
                2 => {
                    let (d, c) = (*rng.pick(&[1u8, 2, 4, 8, 16, 32, 255]), *rng.pick(&[0u8, 2, 3, 4, 6, 7, 255]));
                    f[24] = d;
                    f[25] = c;
                    format!("IHDR depth, colour := {d}, {c}")
                }
                _ => {
                    // A chunk length after IHDR (its CRC stays, so this tests the length bound).
                    let at = 33;
                    let v = *rng.pick(HUGE_U32);
                    f[at..at + 4].copy_from_slice(&v.to_be_bytes());
                    return (f, format!("second chunk length := {v}"));
                }
            };
            let crc = crc32(&f[12..29]);
            f[29..33].copy_from_slice(&crc.to_be_bytes());
            (f, what)
        }
        Format::Exr => {
            let mut f = valid.to_vec();
            let (attrs, offsets) = exr_layout(valid);
            if rng.below(3) == 0 && !offsets.is_empty() {
                let at = *rng.pick(&offsets);
                let v = u64::from(*rng.pick(HUGE_U32)) << rng.below(33);
                f[at..at + 8].copy_from_slice(&v.to_le_bytes());
                return (f, format!("chunk offset at {at} := {v}"));
            }
            let windows: Vec<_> = attrs.iter().filter(|(n, t, _)| t == "box2i" && n.ends_with("Window")).collect();
            let (name, _, at) = rng.pick(&windows);
            let field = rng.below(4);
            let v = *rng.pick(&[i32::MAX, i32::MIN, -1, 0, 1 << 16, 1 << 20, 1 << 30, 100_000]);
            let p = at + 4 * field;
            f[p..p + 4].copy_from_slice(&v.to_le_bytes());
            (f, format!("{name} field {field} := {v}"))
        }
    }
}

/// An OpenEXR file's header attributes `(name, type, value offset)` and the byte offsets of its
/// chunk offset table entries (single-part files, as `write_exr` writes).
fn exr_layout(f: &[u8]) -> (Vec<(String, String, usize)>, Vec<usize>) {
    let cstr = |at: usize| {
        let n = f[at..].iter().position(|&b| b == 0).unwrap();
        (String::from_utf8_lossy(&f[at..at + n]).into_owned(), at + n + 1)
    };
    let mut at = 8;
    let mut attrs = Vec::new();
    let mut rows = 0;
    let mut lines_per_chunk = 1;
    while f[at] != 0 {
        let (name, a) = cstr(at);
        let (ty, a) = cstr(a);
        let size = u32::from_le_bytes(f[a..a + 4].try_into().unwrap()) as usize;
        if name == "dataWindow" {
            let y0 = i32::from_le_bytes(f[a + 8..a + 12].try_into().unwrap());
            let y1 = i32::from_le_bytes(f[a + 16..a + 20].try_into().unwrap());
            rows = (y1 - y0 + 1) as usize;
        }
        if name == "compression" {
            lines_per_chunk = match f[a + 4] {
                0..=2 => 1,
                3 | 5 => 16,
                _ => 32,
            };
        }
        attrs.push((name, ty, a + 4));
        at = a + 4 + size;
    }
    let chunks = rows.div_ceil(lines_per_chunk);
    let offsets = (0..chunks).map(|i| at + 1 + 8 * i).collect();
    (attrs, offsets)
}

/// One corrupted variant of `valid`, from the case's own seed.
fn mutate(format: Format, valid: &[u8], seed: u64) -> (Vec<u8>, String) {
    let mut rng = Rng(seed);
    match rng.below(3) {
        0 => {
            let mut f = valid.to_vec();
            let n = 1 + rng.below(8);
            let mut what = Vec::new();
            for _ in 0..n {
                let i = rng.below(f.len());
                let x = 1 + rng.below(255) as u8;
                f[i] ^= x;
                what.push(format!("{i}^{x:#04x}"));
            }
            (f, format!("flip bytes {}", what.join(" ")))
        }
        1 => {
            let n = rng.below(valid.len());
            (valid[..n].to_vec(), format!("truncate to {n} of {} bytes", valid.len()))
        }
        _ => inflate(format, valid, &mut rng),
    }
}

/// Read `path` as `format` reads it; Ok or the error.
fn read(format: Format, path: &Path) -> btfrs_core::Result<()> {
    match format {
        Format::Container => {
            let c = container::read_contents(path)?;
            for a in &c.arrays {
                let b = container::read_array(path, a)?;
                assert_eq!(b.len() as u64, a.nbytes);
            }
            Ok(())
        }
        Format::PtmLrgb | Format::PtmRgb => ptm_file::read_ptm(path).map(|img| {
            assert!(img.coeffs.iter().chain(img.rgb.iter().flatten()).all(|v| v.is_finite()));
        }),
        Format::Png => image::read_png(path).map(|(v, w, h)| assert_eq!(v.len(), w * h * 3)),
        Format::Exr => image::read_exr(path).map(|(v, w, h)| assert_eq!(v.len(), w * h * 3)),
        Format::Dfmf => {
            use btfrs_io::capture::Source;
            let src = ubo2014::Ubo2014::open(path, &Default::default())?;
            let v = btfrs_io::capture::load(&src, &btfrs_core::Monitor::new())?;
            assert_eq!(v.len(), src.capture().len());
            assert!(v.iter().all(|x| x.is_finite()));
            Ok(())
        }
    }
}

/// Run every case of one format; returns (clean reads, format errors) or panics listing every
/// failing case.
fn run(format: Format) -> (usize, usize) {
    let dir = tempfile::tempdir().unwrap();
    let valid = valid_file(format, dir.path());
    let path = dir.path().join("mutated");
    std::fs::write(&path, &valid).unwrap();
    read(format, &path).unwrap_or_else(|e| panic!("{format:?}: the valid file does not read: {e}"));
    let (mut clean, mut errors, mut failures) = (0, 0, Vec::new());
    let fmt_seed = SEED ^ (format as u64).wrapping_mul(0x1000_0001);
    for i in 0..CASES {
        let seed = fmt_seed.wrapping_add(i);
        let (bytes, what) = mutate(format, &valid, seed);
        std::fs::write(&path, &bytes).unwrap();
        LARGEST.store(0, Ordering::Relaxed);
        let t0 = Instant::now();
        let got = std::panic::catch_unwind(|| read(format, &path));
        let took = t0.elapsed();
        let largest = LARGEST.load(Ordering::Relaxed) as u64;
        let allowed = format.alloc_ratio() * bytes.len() as u64 + SLACK;
        let case = format!("{format:?} case {i} (seed {seed:#x}, {} bytes): {what}", bytes.len());
        match got {
            Ok(Ok(())) => clean += 1,
            Ok(Err(Error::Format { .. })) => errors += 1,
            Ok(Err(e)) => failures.push(format!("{case}: not a format error: {e:?}")),
            Err(_) => failures.push(format!("{case}: panicked")),
        }
        if took > SLOW {
            failures.push(format!("{case}: took {took:?}"));
        }
        if largest > allowed {
            failures.push(format!("{case}: allocated {largest} bytes at once (allowed {allowed})"));
        }
    }
    assert!(failures.is_empty(), "{} of {CASES} cases failed:\n{}", failures.len(), failures.join("\n"));
    (clean, errors)
}

#[test]
fn every_reader_survives_corrupted_files() {
    let _turn = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    for format in [Format::Container, Format::PtmLrgb, Format::PtmRgb, Format::Png, Format::Exr, Format::Dfmf] {
        let t0 = Instant::now();
        let (clean, errors) = run(format);
        println!("{format:?}: {CASES} mutated files, {clean} clean reads, {errors} format errors, {:?}", t0.elapsed());
        // Enough of the cases must reach the checks behind the first bytes.
        assert!(errors > CASES as usize / 4, "{format:?}: only {errors} format errors");
    }
}

#[test]
fn inflated_image_headers_are_rejected_before_allocating() {
    // The image readers used to size their buffers from the header: a 100000 x 100000 PNG
    // header (with a valid CRC) in a file of a few hundred bytes must fail cleanly and quickly.
    let _turn = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tempfile::tempdir().unwrap();
    let mut png = valid_file(Format::Png, dir.path());
    png[16..20].copy_from_slice(&100_000u32.to_be_bytes());
    png[20..24].copy_from_slice(&100_000u32.to_be_bytes());
    let crc = crc32(&png[12..29]);
    png[29..33].copy_from_slice(&crc.to_be_bytes());
    let p = dir.path().join("big.png");
    std::fs::write(&p, &png).unwrap();
    LARGEST.store(0, Ordering::Relaxed);
    let msg = image::read_png(&p).unwrap_err().to_string();
    assert!(msg.contains("100000 x 100000") && msg.contains("more than a file of"), "{msg}");
    assert!((LARGEST.load(Ordering::Relaxed) as u64) < SLACK, "allocated {}", LARGEST.load(Ordering::Relaxed));

    let mut exr = valid_file(Format::Exr, dir.path());
    let (attrs, _) = exr_layout(&exr);
    let (_, _, at) = attrs.iter().find(|(n, _, _)| n == "dataWindow").unwrap().clone();
    exr[at + 8..at + 12].copy_from_slice(&1_000_000i32.to_le_bytes()); // xMax
    exr[at + 12..at + 16].copy_from_slice(&1_000_000i32.to_le_bytes()); // yMax
    let p = dir.path().join("big.exr");
    std::fs::write(&p, &exr).unwrap();
    LARGEST.store(0, Ordering::Relaxed);
    let e = image::read_exr(&p).unwrap_err();
    assert!(matches!(e, Error::Format { .. }), "{e:?}");
    assert!((LARGEST.load(Ordering::Relaxed) as u64) < SLACK, "allocated {}", LARGEST.load(Ordering::Relaxed));
}
