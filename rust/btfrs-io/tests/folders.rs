//! The folder formats from strangers (relight and NeuralRTI web folders, Mitsuba scenes): what
//! an index file declares is refused before anything of that size is allocated, and the XML
//! and JSON index files are parsed within their caps. A counting global allocator records the
//! largest single allocation made during each read; the tests of this file take turns.

use btfrs_core::Error;
use btfrs_io::capture::Limits;
use btfrs_io::formats;
use serde_json::json;
use std::alloc::{GlobalAlloc, Layout, System};
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};

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

/// The message of a format error (its path must end in `file`), and the largest allocation
/// made by `read`.
fn refused<T>(file: &str, read: impl FnOnce() -> btfrs_core::Result<T>) -> (String, usize) {
    LARGEST.store(0, Ordering::SeqCst);
    let r = read();
    let largest = LARGEST.load(Ordering::SeqCst);
    match r {
        Err(Error::Format { path, msg }) => {
            assert!(path.ends_with(file), "{path}: {msg}");
            (msg, largest)
        }
        Err(e) => panic!("expected a format error, got {e:?}"),
        Ok(_) => panic!("expected a format error, got a model"),
    }
}

fn rgb_png(path: &Path, w: u32, h: u32) {
    image::RgbImage::from_fn(w, h, |x, y| image::Rgb([x as u8 * 20, y as u8 * 30, 7])).save(path).unwrap();
}

fn limits(max_bytes: u64) -> Limits {
    Limits { max_bytes, allow_outside: false }
}

#[test]
fn a_relight_folder_declaring_32768_squared_is_refused_before_allocating() {
    let _turn = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tempfile::tempdir().unwrap();
    let info = json!({"width": 32768, "height": 32768, "type": "hsh", "colorspace": "rgb", "nplanes": 3,
                      "materials": [{"scale": [1.0, 1.0, 1.0], "bias": [0.0, 0.0, 0.0]}]});
    std::fs::write(dir.path().join("info.json"), info.to_string()).unwrap();
    rgb_png(&dir.path().join("plane_0.png"), 8, 8);
    let index = dir.path().join("info.json");
    // Within max_bytes: the plane's header tells.
    let (msg, largest) = refused("plane_0.png", || formats::import(&index, &limits(64 << 30)));
    assert_eq!(msg, "8 x 8 pixels; info.json declares 32768 x 32768");
    assert!(largest < 1 << 20, "largest allocation {largest} bytes");
    // Beyond it: the declared size alone.
    let (msg, largest) = refused("info.json", || formats::import(&index, &limits(1 << 30)));
    assert!(msg.contains("needs 19327352832 bytes, more than max_bytes = 1073741824"), "{msg}");
    assert!(largest < 1 << 20, "largest allocation {largest} bytes");
    // The true size reads.
    let info = json!({"width": 8, "height": 8, "type": "hsh", "colorspace": "rgb", "nplanes": 3,
                      "materials": [{"scale": [1.0, 1.0, 1.0], "bias": [0.0, 0.0, 0.0]}]});
    std::fs::write(&index, info.to_string()).unwrap();
    let m = formats::import(&index, &limits(1 << 30)).unwrap();
    assert_eq!(m.model.kind(), "hsh");
}

#[test]
fn a_neuralrti_folder_declaring_32768_squared_is_refused_before_allocating() {
    let _turn = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tempfile::tempdir().unwrap();
    let hp = 4;
    let info = |side: u32| {
        json!({"type": "neural", "width": side, "height": side, "planes": 9, "samples": hp, "colorspace": "bgr",
               "min": vec![0.0; 9], "max": vec![1.0; 9],
               "weights": [vec![0.1; hp * 12], vec![0.1; hp * hp], vec![0.1; 3 * hp]],
               "biases": [vec![0.0; hp], vec![0.0; hp], vec![0.0; 3]]})
    };
    let index = dir.path().join("info.json");
    std::fs::write(&index, info(32768).to_string()).unwrap();
    for i in 1..=3 {
        rgb_png(&dir.path().join(format!("plane_{i}.png")), 8, 8);
    }
    let (msg, largest) = refused("plane_1.png", || formats::import(&index, &limits(64 << 30)));
    assert_eq!(msg, "8 x 8 pixels; info.json declares 32768 x 32768");
    assert!(largest < 1 << 20, "largest allocation {largest} bytes");
    std::fs::write(&index, info(65536).to_string()).unwrap();
    let (msg, _) = refused("info.json", || formats::import(&index, &limits(64 << 30)));
    assert!(msg.contains("expected a size in 1..=32768, got 65536"), "{msg}");
    std::fs::write(&index, info(8).to_string()).unwrap();
    assert_eq!(formats::import(&index, &limits(1 << 30)).unwrap().model.kind(), "neural");
}

#[test]
fn an_index_file_padded_with_an_unused_array_is_bounded_by_its_cap_and_max_bytes() {
    let _turn = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tempfile::tempdir().unwrap();
    let index = dir.path().join("info.json");
    // 8 MiB of zeros in an unused array: under the 16 MiB cap, parsed within 32 bytes per byte.
    let pad = "0,".repeat(4 << 20);
    std::fs::write(&index, format!("{{\"type\": \"bogus\", \"pad\": [{pad}0]}}")).unwrap();
    let len = std::fs::metadata(&index).unwrap().len();
    let (msg, largest) = refused("info.json", || formats::import(&index, &limits(64 << 30)));
    assert!(msg.starts_with("width:"), "{msg}");
    let bound = (len * btfrs_io::untrusted::PARSE_FACTOR) as usize;
    assert!(largest < bound, "largest allocation {largest} bytes for a {len}-byte file");
    // Refused before parsing when the parse could exceed max_bytes.
    let (msg, largest) = refused("info.json", || formats::import(&index, &limits(len * 16)));
    assert!(msg.contains("more than max_bytes"), "{msg}");
    assert!(largest < 1 << 20, "largest allocation {largest} bytes");
}

#[test]
fn a_scene_with_many_attributes_or_deep_nesting_is_refused_by_count() {
    let _turn = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tempfile::tempdir().unwrap();
    let index = dir.path().join("scene.xml");
    let many: String = (0..300_000).map(|i| format!(" a{i}=\"1\"")).collect();
    std::fs::write(
        &index,
        format!("<?xml version=\"1.0\"?>\n<scene version=\"3.0.0\">\n<integrator{many}/>\n</scene>\n"),
    )
    .unwrap();
    let (msg, _) = refused("scene.xml", || formats::import(&index, &limits(1 << 30)));
    assert_eq!(msg, "line 3: an element with more than 64 attributes; at most 64 are read");
    let deep = format!("<scene>{}{}</scene>", "<a>".repeat(100_000), "</a>".repeat(100_000));
    std::fs::write(&index, deep).unwrap();
    let (msg, _) = refused("scene.xml", || formats::import(&index, &limits(1 << 30)));
    assert_eq!(msg, "line 1: elements nested more than 64 levels deep; at most 64 are read");
    let nodes = format!("<scene>{}</scene>", "<a/>".repeat(300_000));
    std::fs::write(&index, nodes).unwrap();
    let (msg, _) = refused("scene.xml", || formats::import(&index, &limits(1 << 30)));
    assert!(msg.contains("more than 262144 XML nodes"), "{msg}");
}
