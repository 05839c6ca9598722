//! The BTF container.
//!
//! Canonical layout: **texel-major** `[H, W, V, L, 3]`, float32 linear RGB. Each texel's apparent
//! BRDF (ABRDF, `V x L x 3` values) is contiguous, which is what every per-texel fit, LPCA and the
//! synthesis read; an image for one (view, light) pair is a strided view. Values include the
//! cos(theta_l) foreshortening, as measured BTFs do (paper 004, section 3).
//!
//! Row `i` of the sample is counted from the top of the image seen from above; column `j` from the
//! left. In the tangent frame, x points along the columns (right) and y along the rows *upwards*.
//!
//! [`BtfRef`] borrows the arrays (a numpy buffer from Python, without copying); [`Btf`] owns them.

use crate::{directions, Error, Result};
use rayon::prelude::*;

/// A borrowed BTF: the arrays may come straight from numpy.
#[derive(Debug, Clone, Copy)]
pub struct BtfRef<'a> {
    /// Rows (texels along y).
    pub height: usize,
    /// Columns (texels along x).
    pub width: usize,
    /// View directions, `V`.
    pub views: &'a [[f64; 3]],
    /// Light directions, `L`.
    pub lights: &'a [[f64; 3]],
    /// `[H, W, V, L, 3]` values.
    pub data: &'a [f32],
    /// Optional `[V, L]` mask: `true` where the pair is measured and may be used.
    pub mask: Option<&'a [bool]>,
}

impl<'a> BtfRef<'a> {
    /// Wrap borrowed arrays, checking that the sizes agree and the directions are valid. The
    /// values are not scanned here (see [`check_finite`]), so wrapping costs nothing.
    pub fn new(
        height: usize,
        width: usize,
        views: &'a [[f64; 3]],
        lights: &'a [[f64; 3]],
        data: &'a [f32],
        mask: Option<&'a [bool]>,
    ) -> Result<Self> {
        if height == 0 || width == 0 {
            return Err(Error::arg("data", format!("expected a non-empty sample, got {height} x {width} texels")));
        }
        directions::validate("views", views)?;
        directions::validate("lights", lights)?;
        let expect = height * width * views.len() * lights.len() * 3;
        if data.len() != expect {
            return Err(Error::arg(
                "data",
                format!(
                    "expected {height} x {width} x {} x {} x 3 = {expect} values, got {}",
                    views.len(),
                    lights.len(),
                    data.len()
                ),
            ));
        }
        if let Some(m) = mask {
            if m.len() != views.len() * lights.len() {
                return Err(Error::arg(
                    "mask",
                    format!("expected {} x {} entries, got {}", views.len(), lights.len(), m.len()),
                ));
            }
            if !m.iter().any(|&b| b) {
                return Err(Error::arg("mask", "no (view, light) pair is left: the mask is all false"));
            }
        }
        Ok(BtfRef { height, width, views, lights, data, mask })
    }

    /// Number of texels, H * W.
    #[inline]
    pub fn texels(&self) -> usize {
        self.height * self.width
    }

    /// Values per texel, V * L * 3.
    #[inline]
    pub fn abrdf_len(&self) -> usize {
        self.views.len() * self.lights.len() * 3
    }

    /// The ABRDF of texel `t` (row-major texel index), `[V, L, 3]`.
    #[inline]
    pub fn texel(&self, t: usize) -> &'a [f32] {
        let n = self.abrdf_len();
        &self.data[t * n..(t + 1) * n]
    }

    /// Whether the pair (view `v`, light `l`) is present.
    #[inline]
    pub fn has(&self, v: usize, l: usize) -> bool {
        self.mask.is_none_or(|m| m[v * self.lights.len() + l])
    }

    /// The indices of the lights present for view slot `v`.
    pub fn lights_of_view(&self, v: usize) -> Vec<usize> {
        (0..self.lights.len()).filter(|&l| self.has(v, l)).collect()
    }

    /// Number of present (view, light) pairs.
    pub fn pairs(&self) -> usize {
        self.mask.map_or(self.views.len() * self.lights.len(), |m| m.iter().filter(|&&b| b).count())
    }
}

/// Fail with the position of the first NaN or infinity in `data` (parallel scan).
pub fn check_finite(name: &str, data: &[f32]) -> Result<()> {
    match first_non_finite(data) {
        None => Ok(()),
        Some(i) => Err(Error::arg(name, format!("value {} at flat index {i} is not finite", data[i]))),
    }
}

/// The flat index of the first NaN or infinity in `data`, if any (parallel scan).
pub fn first_non_finite(data: &[f32]) -> Option<usize> {
    // Scan in large chunks: per-element rayon tasks cost far more than the test itself (rayon's
    // `position_first` element by element took 0.5 s of CPU for the 26 million coefficients of
    // an HSH of a 1200 x 800 capture).
    const CHUNK: usize = 1 << 16;
    // Each chunk by the fold of [`TexelScan::check`] (no early exit, so it vectorises: a 322 MB
    // BTF in 23 ms against 30 ms element by element on 2 cores); the bad value found after.
    let scan = TexelScan::new();
    let chunk = data.par_chunks(CHUNK).position_first(|c| !scan.check(c));
    chunk.and_then(|k| data[k * CHUNK..].iter().position(|x| !x.is_finite()).map(|i| k * CHUNK + i))
}

/// The finite-value check done inside a fit's own pass over the texels instead of as a scan
/// before it (a fit whose [`crate`] user skips [`check_finite`]): each texel's values are tested
/// as the fit reads them, while they are in cache, so a memory-mapped BTF is read from storage
/// once, not twice. On a non-finite value the pass stops early and [`TexelScan::finish`] gives
/// the same error as [`check_finite`] (the first bad value of the whole array).
#[derive(Debug, Default)]
pub struct TexelScan {
    bad: std::sync::atomic::AtomicBool,
}

impl TexelScan {
    /// A scan that has seen nothing bad yet.
    pub fn new() -> TexelScan {
        TexelScan::default()
    }

    /// Whether every value of `values` is finite (else it remembers that one was not).
    #[inline]
    pub fn check(&self, values: &[f32]) -> bool {
        // A fold without early exit vectorises; NaN and infinities have every exponent bit set.
        let bad = values.iter().fold(false, |b, x| b | (x.to_bits() & 0x7f80_0000 == 0x7f80_0000));
        if bad {
            self.bad.store(true, std::sync::atomic::Ordering::Relaxed);
        }
        !bad
    }

    /// Whether a non-finite value was seen (so the rest of the pass can stop).
    #[inline]
    pub fn failed(&self) -> bool {
        self.bad.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// After the pass: [`check_finite`]'s error for `data` if a non-finite value was seen.
    pub fn finish(&self, name: &str, data: &[f32]) -> Result<()> {
        if self.failed() {
            check_finite(name, data)
        } else {
            Ok(())
        }
    }
}

/// How a fit will read a (memory-mapped) array next: advice to the operating system
/// (`madvise` on Linux; nothing elsewhere). Advice only: nothing changes if it is ignored.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Access {
    /// The default read-ahead.
    Normal,
    /// Scattered reads (a sample of texels): no read-around, so a page fault reads that page
    /// and not the megabyte around it.
    Random,
    /// These values soon: the storage reads them in the background (a streaming fit advises its
    /// next block while it computes on the current one).
    WillNeed,
    /// Read and not needed again soon: the first pages to give back when memory runs short (a
    /// streaming pass over a file larger than memory), kept while it does not.
    Done,
}

/// Advise the operating system how `values` will be read ([`Access`]).
pub fn advise(values: &[f32], access: Access) {
    #[cfg(target_os = "linux")]
    {
        extern "C" {
            fn madvise(addr: *mut std::ffi::c_void, len: usize, advice: i32) -> i32;
        }
        const PAGE: usize = 4096;
        if values.is_empty() {
            return;
        }
        let advice = match access {
            Access::Normal => 0,
            Access::Random => 1,
            Access::WillNeed => 3,
            Access::Done => 20, // MADV_COLD (Linux 5.4); older kernels ignore it
        };
        let start = values.as_ptr() as usize;
        let aligned = start & !(PAGE - 1);
        let len = start + std::mem::size_of_val(values) - aligned;
        // SAFETY: advice on pages that hold (part of) a live slice; none of these advices
        // changes their contents, and an error (e.g. for some anonymous memory) is ignored.
        unsafe {
            madvise(aligned as *mut std::ffi::c_void, len, advice);
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = (values, access);
}

/// Run `work(j, b0, n)` over the blocks of `block` texels of `data` (`full` values per texel) in
/// storage order (block `j` starts at texel `b0` and holds `n`), while a reader thread keeps up to
/// `ahead` blocks in memory ahead of it: it asks for each block at once ([`Access::WillNeed`],
/// large requests) and touches one value per page, so it is the thread that waits for the
/// storage (a memory-mapped file larger than memory) while the computing threads find the pages
/// there. A streaming pass reads a file at the storage's speed this way and no page is read
/// twice. The reader stops when `work` fails or the last block is done.
pub fn stream_blocks<E>(
    data: &[f32],
    full: usize,
    block: usize,
    ahead: usize,
    mut work: impl FnMut(usize, usize, usize) -> std::result::Result<(), E>,
) -> std::result::Result<(), E> {
    use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
    let t = data.len() / full.max(1);
    let block = block.max(1);
    let computing = AtomicUsize::new(0);
    let done = AtomicBool::new(false);
    std::thread::scope(|scope| {
        scope.spawn(|| {
            for (j, b0) in (0..t).step_by(block).enumerate().skip(1) {
                while j > computing.load(Ordering::Acquire) + ahead {
                    if done.load(Ordering::Acquire) {
                        return;
                    }
                    std::thread::sleep(std::time::Duration::from_micros(200));
                }
                if done.load(Ordering::Acquire) {
                    return;
                }
                let x = &data[b0 * full..(b0 + block).min(t) * full];
                advise(x, Access::WillNeed);
                let mut sum = 0.0f32;
                for i in (0..x.len()).step_by(1024) {
                    sum += x[i];
                }
                std::hint::black_box(sum);
            }
        });
        let mut run = || {
            for (j, b0) in (0..t).step_by(block).enumerate() {
                computing.store(j, Ordering::Release);
                work(j, b0, block.min(t - b0))?;
            }
            Ok(())
        };
        let r = run();
        done.store(true, Ordering::Release);
        r
    })
}

/// An owned BTF (what the material generator and the file loader produce).
#[derive(Debug, Clone)]
pub struct Btf {
    /// Rows.
    pub height: usize,
    /// Columns.
    pub width: usize,
    /// View directions.
    pub views: Vec<[f64; 3]>,
    /// Light directions.
    pub lights: Vec<[f64; 3]>,
    /// `[H, W, V, L, 3]` values.
    pub data: Vec<f32>,
}

impl Btf {
    /// Borrow as a [`BtfRef`] with no mask.
    pub fn as_ref(&self) -> BtfRef<'_> {
        BtfRef {
            height: self.height,
            width: self.width,
            views: &self.views,
            lights: &self.lights,
            data: &self.data,
            mask: None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn check_finite_names_the_first_bad_value() {
        // Several chunks of the parallel scan, bad values in more than one of them.
        let mut data = vec![0.5f32; 5 << 16];
        assert!(check_finite("data", &data).is_ok());
        data[(3 << 16) + 9] = f32::NAN;
        data[(1 << 16) + 77] = f32::NEG_INFINITY;
        data[(4 << 16) + 1] = f32::INFINITY;
        let e = check_finite("data", &data).unwrap_err().to_string();
        assert_eq!(e, format!("data: value -inf at flat index {} is not finite", (1 << 16) + 77));
        data[(1 << 16) + 77] = f32::MAX; // finite, every exponent bit but one set
        let e = check_finite("data", &data).unwrap_err().to_string();
        assert_eq!(e, format!("data: value NaN at flat index {} is not finite", (3 << 16) + 9));
    }

    #[test]
    fn shape_errors_name_the_argument() {
        let d = directions::ubo81();
        let data = vec![0.0f32; 2 * 2 * 81 * 81 * 3];
        assert!(BtfRef::new(2, 2, &d, &d, &data, None).is_ok());
        let e = BtfRef::new(2, 3, &d, &d, &data, None).unwrap_err().to_string();
        assert!(e.starts_with("data:") && e.contains("2 x 3 x 81 x 81 x 3"), "{e}");
        let mask = vec![false; 81 * 81];
        let e = BtfRef::new(2, 2, &d, &d, &data, Some(&mask)).unwrap_err().to_string();
        assert!(e.starts_with("mask:"), "{e}");
        let mut bad = data.clone();
        bad[1234] = f32::INFINITY;
        let e = check_finite("data", &bad).unwrap_err().to_string();
        assert!(e.contains("1234"), "{e}");
    }

    #[test]
    fn stream_blocks_visits_every_texel_once_in_order_and_stops_at_an_error() {
        // 1000 texels of 3 values, blocks of 64: the last block is short.
        let data: Vec<f32> = (0..3000).map(|i| i as f32).collect();
        let mut seen = Vec::new();
        stream_blocks::<()>(&data, 3, 64, 2, |j, b0, n| {
            assert_eq!(b0, 64 * j);
            seen.extend(b0..b0 + n);
            Ok(())
        })
        .unwrap();
        assert_eq!(seen, (0..1000).collect::<Vec<_>>());
        let mut calls = 0;
        let r = stream_blocks(&data, 3, 64, 2, |j, _, _| {
            calls += 1;
            if j == 3 {
                Err(j)
            } else {
                Ok(())
            }
        });
        assert_eq!((r, calls), (Err(3), 4));
    }

    #[test]
    fn texel_scan_sees_what_check_finite_sees() {
        // Every kind of non-finite value (NaN of either sign, both infinities) and the largest
        // finite values, against Rust's is_finite; then the error after a pass is check_finite's.
        let specials = [f32::NAN, -f32::NAN, f32::INFINITY, f32::NEG_INFINITY, f32::MAX, f32::MIN, 0.0, -0.0, 1e-45];
        for x in specials {
            let mut v = vec![1.0f32; 37];
            v[29] = x;
            assert_eq!(TexelScan::new().check(&v), x.is_finite(), "{x}");
        }
        let mut data = vec![0.5f32; 4 * 100];
        data[250] = f32::NAN;
        data[320] = f32::INFINITY;
        let scan = TexelScan::new();
        let ok: Vec<bool> = data.chunks(100).map(|t| scan.check(t)).collect();
        assert_eq!(ok, [true, true, false, false]);
        assert!(scan.failed());
        assert_eq!(
            scan.finish("data", &data).unwrap_err().to_string(),
            check_finite("data", &data).unwrap_err().to_string()
        );
        assert!(TexelScan::new().finish("data", &data).is_ok(), "only what it saw counts");
    }

    #[test]
    fn texel_slices_are_contiguous_abrdfs() {
        let d = [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]];
        let data: Vec<f32> = (0..3 * 2 * 2 * 2 * 3).map(|x| x as f32).collect();
        let b = BtfRef::new(3, 2, &d, &d, &data, None).unwrap();
        assert_eq!(b.texel(5)[0], (5 * 12) as f32);
        assert_eq!(b.abrdf_len(), 12);
    }
}
