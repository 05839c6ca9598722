//! Files from strangers: memory bounds, truncation, folder confinement and named errors of the
//! capture readers.

use btfrs_core::{Error, Monitor};
use btfrs_io::capture::{self, Limits, Selection, Source};
use btfrs_io::decode::{self, Transfer};
use btfrs_io::{rti, stack, ubo2003};
use std::alloc::{GlobalAlloc, Layout, System};
use std::io::{Cursor, Write};
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

/// Counts live bytes and their peak while `TRACK` is set.
struct Peak;
static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);
static TRACK: AtomicBool = AtomicBool::new(false);

unsafe impl GlobalAlloc for Peak {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        let p = unsafe { System.alloc(l) };
        if TRACK.load(Ordering::Relaxed) {
            let now = LIVE.fetch_add(l.size(), Ordering::Relaxed) + l.size();
            PEAK.fetch_max(now, Ordering::Relaxed);
        }
        p
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        if TRACK.load(Ordering::Relaxed) {
            LIVE.fetch_sub(l.size(), Ordering::Relaxed);
        }
        unsafe { System.dealloc(p, l) }
    }
}

#[global_allocator]
static A: Peak = Peak;

fn format_msg(r: btfrs_core::Result<impl Sized>) -> (String, String) {
    match r {
        Err(Error::Format { path, msg }) => (path, msg),
        Err(e) => panic!("expected a format error, got {e:?}"),
        Ok(_) => panic!("expected a format error, got Ok"),
    }
}

/// A PNG of `w x h` zeros (8-bit grey or RGB), streamed row by row.
fn zero_png(w: u32, h: u32, rgb: bool) -> Vec<u8> {
    let f = tempfile::NamedTempFile::new().unwrap();
    let mut enc = png::Encoder::new(std::io::BufWriter::new(f.reopen().unwrap()), w, h);
    enc.set_color(if rgb { png::ColorType::Rgb } else { png::ColorType::Grayscale });
    enc.set_depth(png::BitDepth::Eight);
    enc.set_compression(png::Compression::High);
    let mut wr = enc.write_header().unwrap().into_stream_writer().unwrap();
    let row = vec![0u8; w as usize * if rgb { 3 } else { 1 }];
    for _ in 0..h {
        wr.write_all(&row).unwrap();
    }
    wr.finish().unwrap();
    std::fs::read(f.path()).unwrap()
}

fn zip_of(name: &str, bytes: &[u8]) -> Vec<u8> {
    let mut z = zip::ZipWriter::new(Cursor::new(Vec::new()));
    let opts = zip::write::SimpleFileOptions::default()
        .compression_method(zip::CompressionMethod::Deflated)
        .compression_level(Some(9));
    z.start_file(name, opts).unwrap();
    z.write_all(bytes).unwrap();
    z.finish().unwrap().into_inner()
}

#[test]
fn tiny_zips_declaring_huge_pngs_are_refused_before_decoding() {
    let dir = tempfile::tempdir().unwrap();
    for side in [8000u32, 12000] {
        let p = dir.path().join(format!("bomb{side}.zip"));
        let z = zip_of("a_tl000_pl000_tv000_pv000.png", &zero_png(side, side, false));
        std::fs::write(&p, &z).unwrap();
        assert!(z.len() < 4000, "{}", z.len());
        let (path, msg) = format_msg(ubo2003::open(&p, &Selection::default(), Transfer::Srgb));
        assert!(path.contains(&format!("bomb{side}.zip")), "{path}");
        let need = side as u64 * side as u64 * 12;
        assert!(msg.contains(&format!("{side} x {side}")) && msg.contains(&need.to_string()), "{msg}");
    }
}

#[test]
fn a_420_kb_png_that_decodes_to_2_gb_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("big.png");
    let bytes = zero_png(13000, 13000, true);
    assert!(bytes.len() < 600_000, "{}", bytes.len());
    std::fs::write(&p, &bytes).unwrap();
    let (path, msg) = format_msg(btfrs_io::image::read_png(&p));
    assert!(path.ends_with("big.png") && msg.contains("2028000000"), "{msg}");
    let (_, msg) = format_msg(decode::read(&p, Transfer::Srgb));
    assert!(msg.contains("2028000000"), "{msg}");
}

fn gradient_png(path: &Path, w: u32, h: u32) {
    image::RgbImage::from_fn(w, h, |x, y| image::Rgb([(x / 8) as u8, (y / 8) as u8, 7])).save(path).unwrap();
}

#[test]
fn max_bytes_bounds_images_and_the_btf_and_names_both_numbers() {
    let dir = tempfile::tempdir().unwrap();
    gradient_png(&dir.path().join("a.png"), 40, 30);
    std::fs::write(dir.path().join("d.csv"), "file,lx,ly,lz\na.png,0,0,1\n").unwrap();
    let t = dir.path().join("d.csv");
    let lim = |max_bytes| Limits { max_bytes, allow_outside: false };
    // the image: 40 x 30 x 12 = 14400 bytes
    let (path, msg) =
        format_msg(stack::open_table_limited(&t, None, &Selection::default(), Transfer::Srgb, &lim(14399)));
    assert!(path.ends_with("a.png") && msg.contains("14400") && msg.contains("14399"), "{msg}");
    let s = stack::open_table_limited(&t, None, &Selection::default(), Transfer::Srgb, &lim(14400)).unwrap();
    let (path, msg) = format_msg(capture::load_within(&s, "cap", 14399, &Monitor::new()));
    assert!(path == "cap" && msg.contains("14400") && msg.contains("14399"), "{msg}");
    assert_eq!(capture::load_within(&s, "cap", 14400, &Monitor::new()).unwrap().len(), 3600);
}

#[test]
fn a_one_image_stack_does_not_hold_its_data_twice() {
    let dir = tempfile::tempdir().unwrap();
    gradient_png(&dir.path().join("a.png"), 2000, 1500);
    std::fs::write(dir.path().join("d.csv"), "file,lx,ly,lz\na.png,0,0,1\n").unwrap();
    let s = stack::open_table(&dir.path().join("d.csv"), None, &Selection::default(), Transfer::Srgb).unwrap();
    let result = 2000 * 1500 * 12;
    LIVE.store(0, Ordering::SeqCst);
    PEAK.store(0, Ordering::SeqCst);
    TRACK.store(true, Ordering::SeqCst);
    let v = capture::load(&s, &Monitor::new()).unwrap();
    TRACK.store(false, Ordering::SeqCst);
    assert_eq!(v.len() * 4, result);
    let peak = PEAK.load(Ordering::SeqCst);
    assert!((peak as f64) < 1.3 * result as f64, "peak {peak} for a result of {result}");
}

fn encode(fmt: image::ImageFormat) -> Vec<u8> {
    let img =
        image::RgbImage::from_fn(16, 16, |x, y| image::Rgb([(x * 13 + y * 7) as u8, (x * y) as u8, (y * 31) as u8]));
    let mut c = Cursor::new(Vec::new());
    image::DynamicImage::ImageRgb8(img).write_to(&mut c, fmt).unwrap();
    c.into_inner()
}

#[test]
fn every_cut_of_a_jpeg_after_its_scan_starts_is_an_error() {
    let jpg = encode(image::ImageFormat::Jpeg);
    let sos = jpg.windows(2).position(|w| w == [0xFF, 0xDA]).unwrap();
    assert!(decode::decode(&jpg, "a.jpg", Transfer::Srgb).is_ok());
    for cut in sos..jpg.len() {
        let (path, _) = format_msg(decode::decode(&jpg[..cut], "a.jpg", Transfer::Srgb));
        assert_eq!(path, "a.jpg", "cut {cut}");
    }
}

#[test]
fn every_cut_of_a_png_after_its_data_starts_is_an_error() {
    let png = encode(image::ImageFormat::Png);
    let idat = png.windows(4).position(|w| w == b"IDAT").unwrap() - 4;
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("a.png");
    assert!(decode::decode(&png, "a.png", Transfer::Srgb).is_ok());
    for cut in idat..png.len() {
        let (path, _) = format_msg(decode::decode(&png[..cut], "a.png", Transfer::Srgb));
        assert_eq!(path, "a.png", "cut {cut}");
        std::fs::write(&p, &png[..cut]).unwrap();
        let (path, _) = format_msg(btfrs_io::image::read_png(&p));
        assert!(path.ends_with("a.png"), "cut {cut}");
    }
    // a flipped bit in the image data: the CRC (or the zlib checksum) catches it
    let mut bad = png.clone();
    bad[idat + 10] ^= 1;
    format_msg(decode::decode(&bad, "a.png", Transfer::Srgb));
}

fn lp_capture(dir: &Path, lines: &str) -> std::path::PathBuf {
    gradient_png(&dir.join("a.png"), 4, 3);
    gradient_png(&dir.join("b.png"), 4, 3);
    let p = dir.join("c.lp");
    std::fs::write(&p, lines).unwrap();
    p
}

#[test]
fn lp_image_paths_stay_in_the_folder() {
    let root = tempfile::tempdir().unwrap();
    let cap = root.path().join("cap");
    std::fs::create_dir(&cap).unwrap();
    gradient_png(&root.path().join("out.png"), 4, 3);
    let sel = Selection::default();
    let open = |p: &Path, allow_outside| {
        let lim = Limits { allow_outside, ..Limits::default() };
        rti::open_lp_limited(p, &sel, Transfer::Srgb, &lim)
    };
    let outside = root.path().join("out.png").display().to_string();
    for bad in ["../out.png".to_string(), outside.clone()] {
        let p = lp_capture(&cap, &format!("2\na.png 0 0 1\n{bad} 0.6 0 0.8\n"));
        let (path, msg) = format_msg(open(&p, false));
        assert!(path.ends_with("c.lp") && msg.contains("line 3") && msg.contains("outside"), "{msg}");
        assert!(open(&p, true).is_ok());
    }
    #[cfg(unix)]
    {
        std::os::unix::fs::symlink(root.path().join("out.png"), cap.join("link.png")).unwrap();
        let p = lp_capture(&cap, "2\na.png 0 0 1\nlink.png 0.6 0 0.8\n");
        let (_, msg) = format_msg(open(&p, false));
        assert!(msg.contains("line 3") && msg.contains("outside"), "{msg}");
        assert!(open(&p, true).is_ok());
    }
    // a path written on another machine is found by its name in the folder; subfolders are in
    std::fs::create_dir(cap.join("sub")).unwrap();
    gradient_png(&cap.join("sub/c.png"), 4, 3);
    let p = lp_capture(&cap, "2\n/elsewhere/x/a.png 0 0 1\nsub/c.png 0.6 0 0.8\n");
    assert!(open(&p, false).is_ok());
}

#[test]
fn table_image_paths_stay_in_the_folder() {
    let root = tempfile::tempdir().unwrap();
    let cap = root.path().join("cap");
    std::fs::create_dir(&cap).unwrap();
    gradient_png(&root.path().join("out.png"), 4, 3);
    gradient_png(&cap.join("a.png"), 4, 3);
    let t = cap.join("directions.csv");
    std::fs::write(&t, "file,lx,ly,lz\na.png,0,0,1\n../out.png,0.6,0,0.8\n").unwrap();
    let open = |allow_outside| {
        let lim = Limits { allow_outside, ..Limits::default() };
        stack::open_table_limited(&t, None, &Selection::default(), Transfer::Srgb, &lim)
    };
    let (path, msg) = format_msg(open(false));
    assert!(path.ends_with("directions.csv") && msg.contains("line 3") && msg.contains("outside"), "{msg}");
    assert!(open(true).is_ok());
}

#[test]
fn text_errors_name_the_file_and_line() {
    let dir = tempfile::tempdir().unwrap();
    let sel = Selection::default();
    // invalid UTF-8
    let p = lp_capture(dir.path(), "");
    std::fs::write(&p, b"2\na.png 0 0 1\nb\xff.png 0.6 0 0.8\n").unwrap();
    let (path, msg) = format_msg(rti::open_lp(&p, &sel, Transfer::Srgb));
    assert!(path.ends_with("c.lp") && msg.contains("line 3") && msg.contains("UTF-8"), "{msg}");
    let t = dir.path().join("directions.csv");
    std::fs::write(&t, b"file,lx,ly,lz\na.png,0,0,1\nb\xff.png,0.6,0,0.8\n").unwrap();
    let (path, msg) = format_msg(stack::open_table(&t, None, &sel, Transfer::Srgb));
    assert!(path.ends_with("directions.csv") && msg.contains("line 3"), "{msg}");
    // overflowing and tiny numbers
    let p = lp_capture(dir.path(), "2\na.png 0 0 1\nb.png 1e200 0 1\n");
    let (path, msg) = format_msg(rti::open_lp(&p, &sel, Transfer::Srgb));
    assert!(path.ends_with("c.lp") && msg.contains("line 3"), "{msg}");
    let p = lp_capture(dir.path(), "2\na.png 0 0 1\nb.png 1e-200 0 1e-200\n");
    let (_, msg) = format_msg(rti::open_lp(&p, &sel, Transfer::Srgb));
    assert!(msg.contains("line 3"), "{msg}");
    // a byte-order mark is accepted in both
    let p = lp_capture(dir.path(), "\u{feff}2\na.png 0 0 1\nb.png 0.6 0 0.8\n");
    assert_eq!(rti::open_lp(&p, &sel, Transfer::Srgb).unwrap().capture().lights.len(), 2);
    std::fs::write(&t, "\u{feff}file,lx,ly,lz\na.png,0,0,1\nb.png,0.6,0,0.8\n").unwrap();
    assert_eq!(stack::open_table(&t, None, &sel, Transfer::Srgb).unwrap().capture().lights.len(), 2);
    // warnings name the file
    std::fs::write(&t, "file,lx,ly,lz\na.png,0,0,1\nb.png,0.6,0,0.9\n").unwrap();
    let s = stack::open_table(&t, None, &sel, Transfer::Srgb).unwrap();
    let w = s.capture().meta["warnings"][0].as_str().unwrap().to_string();
    assert!(w.contains("directions.csv") && w.contains("line 3"), "{w}");
    // duplicate pairs name both lines
    let p = lp_capture(dir.path(), "2\na.png 0 0 1\nb.png 0 0 1\n");
    let (path, msg) = format_msg(rti::open_lp(&p, &sel, Transfer::Srgb));
    assert!(path.ends_with("c.lp") && msg.contains("line 2") && msg.contains("line 3"), "{msg}");
    std::fs::write(&t, "file,lx,ly,lz\na.png,0,0,1\n\nb.png,0,0,1\n").unwrap();
    let (_, msg) = format_msg(stack::open_table(&t, None, &sel, Transfer::Srgb));
    assert!(msg.contains("line 2") && msg.contains("line 4"), "{msg}");
    // both vectors and angles
    std::fs::write(&t, "file,lx,ly,lz,light_theta,light_phi\na.png,0,0,1,0,0\n").unwrap();
    let (_, msg) = format_msg(stack::open_table(&t, None, &sel, Transfer::Srgb));
    assert!(msg.contains("light_theta") && msg.contains("lx, ly, lz") && msg.contains("line 2"), "{msg}");
}

#[cfg(unix)]
#[test]
fn ubo_folder_links_leading_out_are_refused() {
    let root = tempfile::tempdir().unwrap();
    let cap = root.path().join("cap");
    std::fs::create_dir(&cap).unwrap();
    gradient_png(&cap.join("m_tl000_pl000_tv000_pv000.png"), 4, 3);
    gradient_png(&root.path().join("out.png"), 4, 3);
    std::os::unix::fs::symlink(root.path().join("out.png"), cap.join("m_tl030_pl000_tv000_pv000.png")).unwrap();
    let open = |allow_outside| {
        ubo2003::open_limited(
            &cap,
            &Selection::default(),
            Transfer::Srgb,
            &Limits { allow_outside, ..Limits::default() },
        )
    };
    let (path, msg) = format_msg(open(false));
    assert!(path.ends_with("m_tl030_pl000_tv000_pv000.png") && msg.contains("outside"), "{msg}");
    assert_eq!(open(true).unwrap().capture().lights.len(), 2);
}
