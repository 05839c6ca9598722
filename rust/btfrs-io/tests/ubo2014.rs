//! UBO2014 DFMF `.btf` files: files written from known low-rank BTFs read back value by value,
//! the byte layout checked field by field, and bad files (truncated, inflated sizes, foreign or
//! unsupported signatures) refused with `Error::Format` and no large allocation.

use btfrs_core::rng::Rng;
use btfrs_core::{Error, Monitor};
use btfrs_io::capture::{load, Crop, Selection, Source};
use btfrs_io::ubo2014::{
    f32_to_half, half_to_f32, read_header, write_dfmf, DfmfChannelData, DfmfFile, DfmfView, Scalar, Ubo2014, SIGNATURES,
};
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::f32::consts::PI;
use std::path::Path;

/// Records the largest single allocation of the current thread since its last reset.
struct Counting;
thread_local! {
    static LARGEST: Cell<usize> = const { Cell::new(0) };
}

fn note(size: usize) {
    let _ = LARGEST.try_with(|l| l.set(l.get().max(size)));
}

// SAFETY: forwards to the system allocator; only records sizes.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        note(l.size());
        // SAFETY: same layout, forwarded.
        unsafe { System.alloc(l) }
    }
    unsafe fn alloc_zeroed(&self, l: Layout) -> *mut u8 {
        note(l.size());
        // SAFETY: same layout, forwarded.
        unsafe { System.alloc_zeroed(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        // SAFETY: forwarded.
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        note(n);
        // SAFETY: forwarded.
        unsafe { System.realloc(p, l, n) }
    }
}

#[global_allocator]
static ALLOC: Counting = Counting;

/// Views with the same `nl` lights each (angles in radians).
fn grid_views(nv: usize, nl: usize) -> Vec<DfmfView> {
    let lights: Vec<[f32; 2]> = (0..nl).map(|l| [0.1 + 0.3 * l as f32, 0.7 * l as f32]).collect();
    (0..nv).map(|v| DfmfView { theta: 0.2 * v as f32, phi: 0.5 + v as f32, lights: lights.clone() }).collect()
}

/// A DFMF file of a random low-rank BTF (values stored exactly: quantized before writing).
fn sample(
    seed: u64,
    views: Vec<DfmfView>,
    w: u32,
    h: u32,
    ks: [usize; 3],
    scalars: [Scalar; 3],
    model: i32,
) -> DfmfFile {
    let mut rng = Rng::new(seed);
    let rows: usize = views.iter().map(|v| v.lights.len()).sum();
    let px = (w * h) as usize;
    let channels = (0..3)
        .map(|c| {
            let q = scalars[c];
            let mut r = |n: usize, s: f64| (0..n).map(|_| q.quantize((rng.next_f64() - 0.5) * s)).collect::<Vec<_>>();
            DfmfChannelData { scalar: q, s: r(ks[c], 4.0), u: r(rows * ks[c], 1.0), sxv: r(px * ks[c], 1.0) }
        })
        .collect();
    DfmfFile {
        version: 4,
        measurement_setup: "UBO Dome 1".into(),
        image_sensor: "Canon".into(),
        light_source: "flash".into(),
        pixels_per_mm: 11.5,
        rgb_scale: [1.0, 1.5, 2.0],
        cosine_flag: 1,
        xml: "<measurement/>".into(),
        channel_names: vec!["Y".into(), "U".into(), "V".into()],
        views,
        width: w,
        height: h,
        rotations: Some(vec![[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]]),
        color_model: model,
        color_mean: [0.1, 0.2, 0.3],
        color_transform: [0.9, 0.1, 0.0, -0.2, 1.1, 0.05, 0.0, 0.3, 0.8],
        channels,
    }
}

fn yuv(y: f64, u: f64, v: f64) -> [f64; 3] {
    [y + 1.13983 * v, y - 0.39465 * u - 0.5806 * v, y + 2.03211 * u]
}

/// The colour models, written out again from their definitions.
fn reference_rgb(f: &DfmfFile, c: [f64; 3]) -> [f64; 3] {
    let eps = 1e-5;
    let m = f.color_transform.map(f64::from);
    let mean = f.color_mean.map(f64::from);
    match f.color_model {
        0 => c,
        1 => yuv(c[0], c[1], c[2]),
        3 => [0, 1, 2].map(|j| (0..3).map(|i| c[i] * m[3 * i + j]).sum::<f64>() + mean[j]),
        4 => [c[0] + c[1] - c[2], c[0] + c[2], c[0] - c[1] - c[2]],
        9 => yuv(c[0].exp() - eps, c[1], c[2]),
        10 => {
            let g = |x: f64| if x == 0.0 { 0.0 } else { x.signum() * (x.abs() + eps.ln()).exp() };
            yuv(c[0].exp() - eps, g(c[1]), g(c[2]))
        }
        11 => {
            let y = c[0].exp() - eps;
            yuv(y, c[1] * (y + eps), c[2] * (y + eps))
        }
        12 => c.map(|x| x.exp() - eps),
        m => panic!("no reference for model {m}"),
    }
}

/// The full decode in f64: (union lights, `[H, W, V, L, 3]` values, `[V * L]` presence, and a
/// per-value size scale `sum_k |u v|` for the tolerance).
#[allow(clippy::type_complexity)]
fn reference(f: &DfmfFile) -> (Vec<[f32; 2]>, Vec<f64>, Vec<bool>, Vec<f64>) {
    let mut union: Vec<[f32; 2]> = Vec::new();
    for v in &f.views {
        for l in &v.lights {
            if !union.contains(l) {
                union.push(*l);
            }
        }
    }
    let (nv, nl) = (f.views.len(), union.len());
    let mut row_of = vec![None; nv * nl];
    let mut row = 0;
    for (vi, v) in f.views.iter().enumerate() {
        for l in &v.lights {
            row_of[vi * nl + union.iter().position(|x| x == l).unwrap()] = Some(row);
            row += 1;
        }
    }
    let (w, h) = (f.width as usize, f.height as usize);
    let mut out = vec![0.0; h * w * nv * nl * 3];
    let mut scale = vec![0.0; h * w * nv * nl * 3];
    for p in 0..h * w {
        for (pair, r) in row_of.iter().enumerate() {
            let Some(r) = *r else { continue };
            let mut c = [0.0; 3];
            let mut s = 0.0f64;
            for (ci, ch) in f.channels.iter().enumerate() {
                let k = ch.s.len();
                for j in 0..k {
                    c[ci] += ch.u[r * k + j] * ch.sxv[p * k + j];
                    s += (ch.u[r * k + j] * ch.sxv[p * k + j]).abs();
                }
            }
            let rgb = reference_rgb(f, c);
            // btfrs's convention: the RGB scale applied, the light's cosine multiplied in
            // unless the cosine flag (metadata version >= 2) says the values hold it.
            let flagged = f.version >= 2 && f.cosine_flag != 0;
            let cos = if flagged { 1.0 } else { (union[pair % nl][0] as f64).cos() };
            for ci in 0..3 {
                let g = f.rgb_scale[ci] as f64 * cos;
                out[(p * nv * nl + pair) * 3 + ci] = rgb[ci] * g;
                scale[(p * nv * nl + pair) * 3 + ci] = s * g;
            }
        }
    }
    (union, out, row_of.iter().map(Option::is_some).collect(), scale)
}

fn decode(path: &Path, sel: &Selection) -> (Ubo2014, Vec<f32>) {
    let src = Ubo2014::open(path, sel).unwrap();
    let values = load(&src, &Monitor::new()).unwrap();
    (src, values)
}

fn assert_close(got: &[f32], want: &[f64], scale: &[f64], rel: f64, what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: length");
    for (i, ((&g, &w), &s)) in got.iter().zip(want).zip(scale).enumerate() {
        let tol = rel * (w.abs() + s + 1e-3);
        assert!((g as f64 - w).abs() <= tol, "{what}: value {i} is {g}, expected {w} (tolerance {tol})");
    }
}

fn check_roundtrip(f: &DfmfFile, rel: f64, what: &str) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("m.btf");
    write_dfmf(&path, f).unwrap();
    let (src, got) = decode(&path, &Selection::default());
    let (union, want, present, scale) = reference(f);
    let cap = src.capture();
    assert_eq!((cap.height, cap.width), (f.height as usize, f.width as usize));
    assert_eq!((cap.views.len(), cap.lights.len()), (f.views.len(), union.len()));
    assert_eq!(src.union_lights(), &union[..]);
    let mask = cap.mask.clone().unwrap_or_else(|| vec![true; present.len()]);
    assert_eq!(mask, present, "{what}: mask");
    assert_close(&got, &want, &scale, rel, what);
}

#[test]
fn every_value_matches_the_f64_product() {
    let cases =
        [([Scalar::Half; 3], "half"), ([Scalar::F32; 3], "float"), ([Scalar::Half, Scalar::F32, Scalar::F64], "mixed")];
    for (seed, (scalars, what)) in cases.into_iter().enumerate() {
        // Nine components in one channel exercise the eight-lane sum and its tail.
        let f = sample(seed as u64 + 1, grid_views(3, 4), 5, 4, [3, 1, 9], scalars, 0);
        check_roundtrip(&f, 1e-6, what);
    }
    // Rows wider than the decoder's pixel blocks (16), with a partial last block.
    let f = sample(4, grid_views(2, 3), 37, 2, [2, 8, 5], [Scalar::Half; 3], 0);
    check_roundtrip(&f, 1e-6, "wide rows");
}

#[test]
fn colour_models() {
    for model in [0, 1, 3, 4, 9, 10, 11, 12] {
        let f = sample(40 + model as u64, grid_views(2, 3), 3, 2, [2, 2, 2], [Scalar::F32; 3], model);
        check_roundtrip(&f, 1e-5, &format!("colour model {model}"));
    }
}

#[test]
fn unsupported_colour_models_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("m.btf");
    for (model, word) in [(2, "LAB"), (5, "spectral"), (6, "spectral"), (7, "7"), (-1, "-1")] {
        let f = sample(3, grid_views(1, 1), 1, 1, [1, 1, 1], [Scalar::F32; 3], model);
        write_dfmf(&path, &f).unwrap();
        assert!(read_header(&path).is_ok());
        match Ubo2014::open(&path, &Selection::default()) {
            Err(Error::Format { path: p, msg }) => {
                assert!(msg.contains("colour model") && msg.contains(word), "{msg}");
                assert!(p.contains("m.btf"));
            }
            other => panic!("model {model}: {other:?}"),
        }
    }
}

/// A little-endian cursor for reading the writer's bytes by hand.
struct Hand<'a> {
    b: &'a [u8],
    pos: usize,
}

impl Hand<'_> {
    fn take(&mut self, n: usize) -> &[u8] {
        let s = &self.b[self.pos..self.pos + n];
        self.pos += n;
        s
    }
    fn u8(&mut self) -> u8 {
        self.take(1)[0]
    }
    fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.take(4).try_into().unwrap())
    }
    fn i32(&mut self) -> i32 {
        i32::from_le_bytes(self.take(4).try_into().unwrap())
    }
    fn f32(&mut self) -> f32 {
        f32::from_le_bytes(self.take(4).try_into().unwrap())
    }
    fn f64(&mut self) -> f64 {
        f64::from_le_bytes(self.take(8).try_into().unwrap())
    }
    fn half(&mut self) -> f32 {
        half_to_f32(u16::from_le_bytes(self.take(2).try_into().unwrap()))
    }
    fn at(&self, offset: usize) {
        assert_eq!(self.pos, offset, "field offset");
    }
}

#[test]
fn byte_layout_field_by_field() {
    let views = vec![
        DfmfView { theta: 0.25, phi: 1.5, lights: vec![[0.5, 0.75], [1.0, 2.0]] },
        DfmfView { theta: 0.5, phi: 3.0, lights: vec![[0.5, 0.75], [1.25, 2.5]] },
    ];
    let mut f = sample(7, views, 2, 1, [1, 2, 1], [Scalar::Half, Scalar::F32, Scalar::F64], 3);
    f.channel_names = vec!["R".into(), "G".into(), "B".into()];
    f.measurement_setup = "Setup".into();
    f.image_sensor = "Sensor".into();
    f.light_source = "Lamp".into();
    f.pixels_per_mm = 12.5;
    f.rgb_scale = [1.0, 2.0, 3.0];
    f.cosine_flag = 1;
    f.xml = "<x/>".into();
    f.rotations = Some(vec![[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0]]);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("layout.btf");
    write_dfmf(&path, &f).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let mut h = Hand { b: &bytes, pos: 0 };

    assert_eq!(h.take(10), b"!DFMF08FCR");
    // Metadata: 264 bytes of version 1, the cosine flag, the XML string, three channel names.
    let meta_size = 264 + 4 + (4 + 4) + (4 + 3 * (4 + 1));
    assert_eq!(h.u32(), meta_size);
    assert_eq!(h.u32(), 4);
    h.at(18);
    let setup = h.take(80);
    assert_eq!(&setup[..6], b"Setup\0");
    assert!(setup[5..].iter().all(|&b| b == 0));
    h.at(98);
    assert_eq!(&h.take(80)[..7], b"Sensor\0");
    h.at(178);
    assert_eq!(&h.take(80)[..5], b"Lamp\0");
    h.at(258);
    assert_eq!(h.f32(), 12.5);
    assert_eq!([h.f32(), h.f32(), h.f32()], [1.0, 2.0, 3.0]);
    h.at(274);
    assert_eq!(h.u32(), 1, "cosine flag");
    assert_eq!(h.u32(), 4, "XML length");
    assert_eq!(h.take(4), b"<x/>");
    assert_eq!(h.u32(), 3, "channel count");
    for name in [b"R", b"G", b"B"] {
        assert_eq!(h.u32(), 1);
        assert_eq!(h.take(1), name);
    }
    h.at(10 + meta_size as usize);
    h.at(305);
    // Sampling: views with their lights.
    assert_eq!(h.u32(), 2);
    for v in &f.views {
        assert_eq!([h.f32(), h.f32()], [v.theta, v.phi]);
        assert_eq!(h.u32(), 2);
        for l in &v.lights {
            assert_eq!([h.f32(), h.f32()], *l);
        }
    }
    h.at(365);
    assert_eq!([h.u32(), h.u32()], [2, 1], "width, height");
    assert_eq!(h.u32(), 1, "rotations");
    let rot: Vec<f32> = (0..9).map(|_| h.f32()).collect();
    assert_eq!(rot, (1..=9).map(|x| x as f32).collect::<Vec<_>>());
    h.at(413);
    // DFMF: components, colour model, mean, transform.
    assert_eq!(h.u32(), 2, "largest component count");
    assert_eq!(h.i32(), 3, "colour model");
    assert_eq!([h.f32(), h.f32(), h.f32()], f.color_mean);
    let m: Vec<f32> = (0..9).map(|_| h.f32()).collect();
    assert_eq!(m, f.color_transform);
    h.at(469);
    let mut offsets = Vec::new();
    for (c, (size, k)) in [(2u8, 1usize), (4, 2), (8, 1)].into_iter().enumerate() {
        let ch = &f.channels[c];
        assert_eq!(h.u8(), size, "channel {c} scalar size");
        assert_eq!(h.u32(), k as u32, "channel {c} components");
        assert_eq!(h.u32(), 4, "channel {c} rows = lights x views");
        assert_eq!(h.u32(), 2, "channel {c} columns = width x height");
        let mut read = |n: usize| -> Vec<f64> {
            (0..n)
                .map(|_| match size {
                    2 => h.half() as f64,
                    4 => h.f32() as f64,
                    _ => h.f64(),
                })
                .collect()
        };
        let s_at = read(0);
        assert!(s_at.is_empty());
        let s = read(k);
        let u = read(4 * k);
        let sxv = read(2 * k);
        assert_eq!((s, u, sxv), (ch.s.clone(), ch.u.clone(), ch.sxv.clone()), "channel {c} S, U, S.V");
        offsets.push(h.pos);
    }
    assert_eq!(offsets, [496, 565, 634]);
    assert_eq!(h.pos, bytes.len(), "nothing after the last channel");

    // The header reports the same fields and offsets.
    let hd = read_header(&path).unwrap();
    assert_eq!(hd.signature, "!DFMF08FCR");
    assert_eq!((hd.meta_size, hd.version), (meta_size, 4));
    assert_eq!((&*hd.measurement_setup, &*hd.image_sensor, &*hd.light_source), ("Setup", "Sensor", "Lamp"));
    assert_eq!((hd.pixels_per_mm, hd.rgb_scale, hd.cosine_flag), (12.5, [1.0, 2.0, 3.0], Some(1)));
    assert_eq!(hd.xml.as_deref(), Some("<x/>"));
    assert_eq!(hd.channel_names, ["R", "G", "B"]);
    assert_eq!(hd.views, f.views);
    assert_eq!((hd.width, hd.height), (2, 1));
    assert_eq!(hd.rotations, f.rotations.clone().unwrap());
    assert_eq!(
        (hd.components, hd.color_model, hd.color_mean, hd.color_transform),
        (2, 3, f.color_mean, f.color_transform)
    );
    let offs: Vec<_> = hd.channels.iter().map(|c| (c.s_offset, c.u_offset, c.sxv_offset)).collect();
    assert_eq!(offs, [(482, 484, 492), (509, 517, 549), (578, 586, 618)]);

    // Everything but the format facts is in the capture's meta.
    let src = Ubo2014::open(&path, &Selection::default()).unwrap();
    let meta = &src.capture().meta;
    assert_eq!(meta["signature"], "!DFMF08FCR");
    assert_eq!(meta["version"], 4);
    assert_eq!(meta["measurement_setup"], "Setup");
    assert_eq!(meta["pixels_per_mm"], 12.5);
    assert_eq!(meta["rgb_scale"], serde_json::json!([1.0, 2.0, 3.0]));
    assert_eq!(meta["cosine_flag"], 1);
    assert_eq!(meta["channel_names"], serde_json::json!(["R", "G", "B"]));
}

#[test]
fn each_metadata_version() {
    let dir = tempfile::tempdir().unwrap();
    for version in 1..=4u32 {
        let mut f = sample(20 + version as u64, grid_views(2, 2), 3, 2, [2, 1, 2], [Scalar::Half; 3], 0);
        f.version = version;
        f.rotations = if version % 2 == 0 { None } else { Some(vec![[0.5; 9]; 2]) };
        let path = dir.path().join(format!("v{version}.btf"));
        write_dfmf(&path, &f).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let sig: &[u8] = if f.rotations.is_some() { b"!DFMF08FCR" } else { b"!DFMF08FC" };
        assert_eq!(&bytes[..sig.len()], sig);
        let size = u32::from_le_bytes(bytes[sig.len()..sig.len() + 4].try_into().unwrap());
        let expected = 264 + [0, 4, 4 + 4 + 14, 4 + 4 + 14 + 4 + 3 * 5][version as usize - 1];
        assert_eq!(size, expected, "version {version} metadata size");
        let hd = read_header(&path).unwrap();
        assert_eq!(hd.version, version);
        assert_eq!(hd.meta_size, expected);
        assert_eq!(hd.cosine_flag, (version >= 2).then_some(1));
        assert_eq!(hd.xml.as_deref(), (version >= 3).then_some("<measurement/>"));
        let names = if version >= 4 { ["Y", "U", "V"] } else { ["R", "G", "B"] };
        assert_eq!(hd.channel_names, names);
        assert_eq!(hd.rotations.len(), if version % 2 == 0 { 0 } else { 2 });
        check_roundtrip(&f, 1e-6, &format!("version {version}"));
    }
}

#[test]
fn crop_and_subsets_equal_slices_of_the_full_decode() {
    let f = sample(11, grid_views(4, 5), 7, 6, [3, 2, 4], [Scalar::Half; 3], 1);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("m.btf");
    write_dfmf(&path, &f).unwrap();
    let (full_src, full) = decode(&path, &Selection::default());
    let (nv, nl) = (full_src.capture().views.len(), full_src.capture().lights.len());
    // Most of the pairs (U read whole) and a few of them (U read row by row).
    let cases: [(Crop, Vec<usize>, Vec<usize>); 2] = [
        (Crop { row: 1, col: 2, rows: 4, cols: 3 }, vec![3, 0, 2], vec![4, 1, 3]),
        (Crop { row: 0, col: 6, rows: 6, cols: 1 }, vec![1, 3], vec![2]),
    ];
    for (crop, views, lights) in cases {
        let sel = Selection { crop: Some(crop), views: Some(views.clone()), lights: Some(lights.clone()) };
        let (src, part) = decode(&path, &sel);
        let cap = src.capture();
        assert_eq!((cap.height, cap.width), (crop.rows, crop.cols));
        assert_eq!((cap.views.len(), cap.lights.len()), (views.len(), lights.len()));
        assert_eq!(cap.views[0], full_src.capture().views[views[0]]);
        assert_eq!(cap.lights[0], full_src.capture().lights[lights[0]]);
        let mut i = 0;
        for r in crop.row..crop.row + crop.rows {
            for c in crop.col..crop.col + crop.cols {
                for &v in &views {
                    for &l in &lights {
                        for ch in 0..3 {
                            let j = ((((r * 7 + c) * nv + v) * nl + l) * 3) + ch;
                            assert_eq!(part[i], full[j], "texel ({r}, {c}), view {v}, light {l}, channel {ch}");
                            i += 1;
                        }
                    }
                }
            }
        }
        assert_eq!(i, part.len());
    }
    // Bad selections are argument errors.
    for bad in [
        Selection { views: Some(vec![4]), ..Default::default() },
        Selection { lights: Some(vec![1, 1]), ..Default::default() },
        Selection { crop: Some(Crop { row: 5, col: 0, rows: 2, cols: 1 }), ..Default::default() },
    ] {
        assert!(matches!(Ubo2014::open(&path, &bad), Err(Error::InvalidArgument { .. })), "{bad:?}");
    }
}

#[test]
fn views_with_different_lights_give_the_union_and_a_mask() {
    let (a, b, c) = ([0.1f32, 0.2f32], [0.3, 0.4], [0.5, 0.6]);
    let views = vec![
        DfmfView { theta: 0.0, phi: 0.0, lights: vec![a, b] },
        DfmfView { theta: 0.4, phi: 1.0, lights: vec![b, c, a] },
        DfmfView { theta: 0.8, phi: 2.0, lights: vec![c] },
    ];
    let f = sample(5, views, 3, 2, [2, 3, 1], [Scalar::F32; 3], 0);
    check_roundtrip(&f, 1e-6, "different light lists");
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("m.btf");
    write_dfmf(&path, &f).unwrap();
    let (src, values) = decode(&path, &Selection::default());
    assert_eq!(src.union_lights(), &[a, b, c]);
    let mask = src.capture().mask.clone().expect("a mask");
    assert_eq!(mask, [true, true, false, true, true, true, false, false, true]);
    // Absent pairs stay 0.
    for p in 0..6 {
        for (pair, &m) in mask.iter().enumerate() {
            if !m {
                assert_eq!(&values[(p * 9 + pair) * 3..(p * 9 + pair) * 3 + 3], &[0.0; 3]);
            }
        }
    }
    // A selection of present pairs only has no mask.
    let sel = Selection { views: Some(vec![1]), ..Default::default() };
    assert_eq!(Ubo2014::open(&path, &sel).unwrap().capture().mask, None);
    let sel = Selection { views: Some(vec![2, 0]), lights: Some(vec![2, 0]), ..Default::default() };
    assert_eq!(Ubo2014::open(&path, &sel).unwrap().capture().mask, Some(vec![true, false, false, true]));
}

#[test]
fn a_light_listed_twice_in_a_view_is_an_error() {
    let views = vec![DfmfView { theta: 0.0, phi: 0.0, lights: vec![[0.1, 0.2], [0.1, 0.2]] }];
    let f = sample(6, views, 1, 1, [1, 1, 1], [Scalar::F32; 3], 0);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("m.btf");
    write_dfmf(&path, &f).unwrap();
    match Ubo2014::open(&path, &Selection::default()) {
        Err(Error::Format { msg, .. }) => assert!(msg.contains("twice"), "{msg}"),
        other => panic!("{other:?}"),
    }
}

#[test]
fn directions_follow_the_documented_frame() {
    let views = vec![
        DfmfView { theta: 0.0, phi: 0.0, lights: vec![[PI / 2.0, 0.0]] },
        DfmfView { theta: PI / 2.0, phi: PI / 2.0, lights: vec![[PI / 2.0, 0.0]] },
        DfmfView { theta: PI / 3.0, phi: PI, lights: vec![[PI / 2.0, 0.0]] },
    ];
    let f = sample(8, views, 1, 1, [1, 1, 1], [Scalar::F32; 3], 0);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("m.btf");
    write_dfmf(&path, &f).unwrap();
    let src = Ubo2014::open(&path, &Selection::default()).unwrap();
    let cap = src.capture();
    let near = |a: [f64; 3], b: [f64; 3]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-6);
    assert!(near(cap.views[0], [0.0, 0.0, 1.0]), "{:?}", cap.views[0]);
    assert!(near(cap.views[1], [0.0, 1.0, 0.0]), "{:?}", cap.views[1]); // up the image
    let s = (PI as f64 / 3.0).sin();
    assert!(near(cap.views[2], [-s, 0.0, 0.5]), "{:?}", cap.views[2]);
    assert!(near(cap.lights[0], [1.0, 0.0, 0.0]), "{:?}", cap.lights[0]); // along the columns
}

#[test]
fn image_rows_are_top_first() {
    // One component, U = 1: every image is S.V itself, pixel p = row * width + column.
    let mut f = sample(9, grid_views(1, 1), 3, 2, [1, 1, 1], [Scalar::F32; 3], 0);
    f.rgb_scale = [1.0; 3];
    for ch in &mut f.channels {
        ch.u = vec![1.0];
        ch.sxv = (0..6).map(|p| p as f64).collect();
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("m.btf");
    write_dfmf(&path, &f).unwrap();
    let sel = Selection { crop: Some(Crop { row: 1, col: 1, rows: 1, cols: 2 }), ..Default::default() };
    let (_, v) = decode(&path, &sel);
    assert_eq!(v, [4.0, 4.0, 4.0, 5.0, 5.0, 5.0]);
}

/// `Error::Format` naming the file, with no allocation far beyond the file's size.
fn expect_format(path: &Path, what: &str) -> String {
    let len = std::fs::metadata(path).unwrap().len() as usize;
    LARGEST.with(|l| l.set(0));
    let r = Ubo2014::open(path, &Selection::default()).and_then(|s| load(&s, &Monitor::new()).map(|_| ()));
    let largest = LARGEST.with(Cell::get);
    assert!(largest <= (1 << 16) + 4 * len, "{what}: an allocation of {largest} bytes for a {len}-byte file");
    match r {
        Err(Error::Format { path: p, msg }) => {
            assert!(p.contains(path.file_name().unwrap().to_str().unwrap()), "{what}: {p}");
            msg
        }
        other => panic!("{what}: expected a format error, got {other:?}"),
    }
}

#[test]
fn truncated_files_at_every_cut_are_format_errors() {
    let f = sample(12, grid_views(2, 3), 3, 2, [2, 3, 1], [Scalar::Half, Scalar::F32, Scalar::Half], 0);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("full.btf");
    write_dfmf(&path, &f).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let cut = dir.path().join("cut.btf");
    for n in 0..bytes.len() {
        std::fs::write(&cut, &bytes[..n]).unwrap();
        let msg = expect_format(&cut, &format!("cut at {n}"));
        assert!(!msg.is_empty());
    }
    // Trailing bytes are refused too.
    let mut longer = bytes.clone();
    longer.extend_from_slice(&[0; 3]);
    std::fs::write(&cut, &longer).unwrap();
    assert!(expect_format(&cut, "trailing").contains("3 unexpected bytes"));
}

#[test]
fn huge_sizes_in_a_small_file_are_format_errors() {
    // A small file (2 views x 1 light, 2 x 1 texels, one component each).
    let mut f = sample(13, grid_views(2, 1), 2, 1, [1, 1, 1], [Scalar::F32; 3], 0);
    f.rotations = Some(vec![[0.0; 9]]);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("small.btf");
    write_dfmf(&path, &f).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    assert!(bytes.len() < 700, "{}", bytes.len());
    let hd = read_header(&path).unwrap();
    let meta_end = 10 + hd.meta_size as usize;
    let views_at = meta_end;
    let size_at = views_at + 4 + 2 * (12 + 8);
    let rot_at = size_at + 8;
    let dfmf_at = rot_at + 4 + 36;
    let ch0 = dfmf_at + 4 + 4 + 12 + 36;
    assert_eq!(hd.channels[0].s_offset as usize, ch0 + 13);
    let xml_len_at = 10 + 264 + 4;
    let names_at = xml_len_at + 4 + f.xml.len();
    let huge = 1u32 << 31;
    let cases: Vec<(&str, usize, u32)> = vec![
        ("metadata size", 10, huge),
        ("metadata version", 14, 7),
        ("XML length", xml_len_at, huge),
        ("channel count", names_at, huge),
        ("view count", views_at, huge),
        ("light count", views_at + 12, huge),
        ("width", size_at, huge),
        ("height", size_at + 4, huge),
        ("rotation count", rot_at, huge),
        ("channel components", ch0 + 1, huge),
        ("channel components 2^32-1", ch0 + 1, u32::MAX),
        ("channel rows", ch0 + 5, huge),
        ("channel columns", ch0 + 9, huge),
    ];
    let bad = dir.path().join("bad.btf");
    for (what, at, value) in cases {
        let mut b = bytes.clone();
        b[at..at + 4].copy_from_slice(&value.to_le_bytes());
        std::fs::write(&bad, &b).unwrap();
        let msg = expect_format(&bad, what);
        assert!(!msg.is_empty(), "{what}");
    }
    // Scalar sizes other than 2, 4, 8.
    for size in [0u8, 1, 3, 16] {
        let mut b = bytes.clone();
        b[ch0] = size;
        std::fs::write(&bad, &b).unwrap();
        assert!(expect_format(&bad, "scalar size").contains("scalar size"));
    }
    // Zero components.
    let mut b = bytes.clone();
    b[ch0 + 1..ch0 + 5].copy_from_slice(&0u32.to_le_bytes());
    std::fs::write(&bad, &b).unwrap();
    assert!(expect_format(&bad, "zero components").contains("no components"));
}

#[test]
fn unsupported_and_foreign_signatures_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("other.btf");
    for (sig, what) in SIGNATURES.iter().filter(|(s, _)| !s.starts_with("!DFMF")) {
        let mut b = sig.as_bytes().to_vec();
        b.extend_from_slice(&[0u8; 300]);
        std::fs::write(&path, &b).unwrap();
        let msg = expect_format(&path, sig);
        assert!(msg.contains(sig) && msg.contains(what) && msg.contains("!DFMF08FCR"), "{msg}");
        assert!(matches!(read_header(&path), Err(Error::Format { .. })));
    }
    for (bytes, shown) in [(&b"hello world, not a btf"[..], "hello worl"), (b"\x89PNG\r\n", "PNG"), (b"", "")] {
        std::fs::write(&path, bytes).unwrap();
        let msg = expect_format(&path, "foreign");
        assert!(msg.contains("not a UBO2014") && msg.contains(shown) && msg.contains("!DFMF08FCR"), "{msg}");
    }
    // A file ending inside a signature.
    std::fs::write(&path, b"!DFMF0").unwrap();
    assert!(expect_format(&path, "short").contains("inside the signature"));
}

#[test]
fn non_finite_values_name_the_file() {
    let mut f = sample(14, grid_views(1, 2), 2, 2, [1, 1, 1], [Scalar::F32; 3], 0);
    f.channels[1].u[1] = f64::NAN;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("nan.btf");
    write_dfmf(&path, &f).unwrap();
    let msg = expect_format(&path, "NaN");
    assert!(msg.contains("non-finite") && msg.contains("light 1"), "{msg}");
    // Overflow through the colour model counts too.
    let mut f = sample(15, grid_views(1, 1), 1, 1, [1, 1, 1], [Scalar::F32; 3], 12);
    f.channels[0].u = vec![1000.0];
    f.channels[0].sxv = vec![1.0];
    write_dfmf(&path, &f).unwrap();
    assert!(expect_format(&path, "exp overflow").contains("non-finite"));
}

#[test]
fn decoding_stops_on_cancel_and_reports_progress() {
    let f = sample(16, grid_views(2, 2), 4, 5, [2, 2, 2], [Scalar::Half; 3], 0);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("m.btf");
    write_dfmf(&path, &f).unwrap();
    let src = Ubo2014::open(&path, &Selection::default()).unwrap();
    let monitor = Monitor::new();
    let mut out = vec![0.0; src.capture().len()];
    src.decode_into(&mut out, &monitor).unwrap();
    assert_eq!(monitor.progress(), (5, 5));
    monitor.cancel();
    assert!(matches!(src.decode_into(&mut out, &monitor), Err(Error::Interrupted)));
    assert!(matches!(src.decode_into(&mut out[1..], &Monitor::new()), Err(Error::InvalidArgument { .. })));
}

#[test]
fn the_writer_checks_its_input_and_leaves_nothing_half_written() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("w.btf");
    let good = sample(17, grid_views(1, 2), 2, 1, [1, 1, 1], [Scalar::F32; 3], 0);
    let mut bad = Vec::new();
    let mut f = good.clone();
    f.channels[0].u.pop();
    bad.push(f);
    let mut f = good.clone();
    f.version = 5;
    bad.push(f);
    let mut f = good.clone();
    f.measurement_setup = "x".repeat(81);
    bad.push(f);
    let mut f = good.clone();
    f.channel_names.pop();
    bad.push(f);
    let mut f = good.clone();
    f.version = 3;
    f.channels.pop();
    bad.push(f);
    for f in &bad {
        assert!(matches!(write_dfmf(&path, f), Err(Error::InvalidArgument { .. })));
        assert!(!path.exists());
    }
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0, "no temporary file left");
    write_dfmf(&path, &good).unwrap();
}

#[test]
fn half_floats_convert_exactly() {
    for h in 0..=u16::MAX {
        let x = half_to_f32(h);
        if x.is_nan() {
            assert!(f32_to_half(x) & 0x7c00 == 0x7c00 && f32_to_half(x) & 0x3ff != 0);
        } else {
            assert_eq!(f32_to_half(x), h, "{h:#06x} -> {x}");
        }
    }
    let known: [(f32, u16); 10] = [
        (1.0, 0x3c00),
        (-2.0, 0xc000),
        (65504.0, 0x7bff),
        (65520.0, 0x7c00),
        (1e9, 0x7c00),
        (5.960_464_5e-8, 0x0001),
        (2.980_232_3e-8, 0x0000), // half the smallest subnormal: ties to even (0)
        (0.1, 0x2e66),
        (6.103_515_6e-5, 0x0400),
        (1.0 + 1.0 / 2048.0, 0x3c00), // a tie between 1 and 1 + 2^-10: to even
    ];
    for (x, h) in known {
        assert_eq!(f32_to_half(x), h, "{x}");
    }
    assert_eq!(half_to_f32(0x3555), 0.333_251_95);
    assert!(half_to_f32(0xfc00).is_infinite() && half_to_f32(0xfc00) < 0.0);
}

#[test]
fn no_rotation_signature_with_an_r_shaped_size_byte() {
    // Without rotations the signature is `!DFMF08FC`; a version-3 metadata block of
    // 264 + 4 + 4 + 66 = 338 = 0x152 bytes starts with the byte 'R' (0x52).
    let mut f = sample(18, grid_views(2, 2), 2, 2, [1, 2, 1], [Scalar::Half; 3], 0);
    f.version = 3;
    f.rotations = None;
    f.xml = "x".repeat(66);
    assert_eq!(f.meta_size(), 0x152);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("r.btf");
    write_dfmf(&path, &f).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    assert_eq!(&bytes[..10], b"!DFMF08FCR");
    let hd = read_header(&path).unwrap();
    assert_eq!((hd.signature.as_str(), hd.meta_size, hd.version), ("!DFMF08FC", 0x152, 3));
    assert!(hd.rotations.is_empty());
    check_roundtrip(&f, 1e-6, "R-shaped size byte");
}
