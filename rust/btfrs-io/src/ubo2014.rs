//! Reading (and writing) the University of Bonn's binary `.btf` files of the UBO2014 BTF
//! database, in their DFMF form ("decorrelated full matrix factorization", signature
//! `!DFMF08FCR`).
//!
//! # The file (all numbers little-endian)
//!
//! ```text
//! signature         "!DFMF08FCR" (10 bytes; "!DFMF08FC" without the rotation block)
//! metadata block    u32 size       bytes of this block, the size field included
//!                   u32 version    1..=4
//!                   char[80]       measurement setup  (NUL-padded)
//!                   char[80]       image sensor
//!                   char[80]       light source
//!                   f32            pixels per mm
//!                   f32 x 3        RGB scale factors
//!   version >= 2:   u32            cosine flag (the data already hold cos(theta_light))
//!   version >= 3:   u32 n, n bytes the measurement's XML description
//!   version >= 4:   u32 c, then c x (u32 n, n bytes) channel names; before version 4 the
//!                   channels are R, G, B
//! sampling          u32 views, then per view: f32 theta, f32 phi,
//!                                             u32 lights, lights x (f32 theta, f32 phi)
//! image size        u32 width, u32 height
//! rotations         (only when the signature ends in 'R') u32 n, n x 9 f32 (3x3 matrices)
//! DFMF payload      u32 components (the largest per-channel count)
//!                   i32 colour model
//!                   f32 x 3 colour mean
//!                   f32 x 9 colour transform (3x3, row-major)
//!                   per channel:  u8 scalar size (2 = half, 4 = float, 8 = double)
//!                                 u32 components k, u32 rows, u32 columns
//!                                 k scalars S (singular values)
//!                                 rows x k scalars U (row-major)
//!                                 columns x k scalars S.V (row-major)
//! end of file       (nothing may follow the last channel)
//! ```
//!
//! Sources (read, never copied): the MIT-licensed `btf.hh` of Zdravko Velinov's
//! `zeroeffects/btf` (`LoadBTF`: the `BTFCommonHeader` struct, the `read_common` lambda and the
//! `DFMF` case; `BTFFetchSpectrum` and `BTFEvaluateMatrix` for the indices), and the readers and
//! writers of the Bonn `btflib` (`read_meta_data.m`, `write_meta_data.m`,
//! `read_bidir_sampling.m`, `read_common_header.m`, `read_ubo_dfmf.m`, `write_ubo_dfmf.m`,
//! `decode_dfmf_texture.m`, `sph2cart2.m`) for what `btf.hh` leaves open. The colour model
//! numbers are the ones `btflib`'s `undecorrelate.m` names; the formulas below are written
//! from their mathematical definitions.
//!
//! # The decisions this reader makes
//!
//! * **Rows of U** are (view, light) pairs, view-major: the row of light `j` of view `v` is
//!   `v * lights + j` (`btf.hh`: `lv_idx = view * LightCount + light`; `btflib`:
//!   `sub2ind([nL, nV], l, v)`). Both readers insist on one light list for every view. This
//!   reader also accepts views with different light lists: rows then count the lights of each
//!   view in turn (row of light `j` of view `v` = the lights of views `0..v` plus `j`), which is
//!   the same order whenever the lists agree. The capture's light list is the union of the
//!   views' lights (in order of first appearance, a light being its exact pair of angles) and
//!   [`Capture::mask`] marks the pairs the file holds.
//! * **Columns of S.V** are pixels, `row * width + column`, with row 0 the **top** row of the
//!   image: `btflib` reshapes a column into `[w, h]` and transposes it into a MATLAB image (row 1
//!   at the top); `btf.hh` swaps rows `y` and `height - 1 - y` after loading to get an
//!   OpenGL-style bottom-up texture, i.e. the file is top-down.
//! * **Values**: channel `c` of pair `r` at pixel `p` is `sum_k U_c[r, k] * SV_c[p, k]`; S is
//!   read past (the S.V block already holds the singular values). The three channels are then
//!   turned into RGB by the colour model (`eps` = 1e-5, the dynamic-range epsilon both readers
//!   hard-code; `YUV->RGB` is R = Y + 1.13983 V, G = Y - 0.39465 U - 0.58060 V,
//!   B = Y + 2.03211 U):
//!   - 0 RGB: as is;
//!   - 1 YUV: `YUV->RGB`;
//!   - 3 PCA: `rgb = c M + mean` (`c` a row vector, `M` the file's transform, row-major: `btf.hh`
//!     reads it as `Matrix3 {tangent, binormal, normal}`, `btflib` writes the transpose of M
//!     column-major, i.e. M row-major, and decodes `values * M + mean`). This is the only model
//!     that uses the mean and the transform;
//!   - 4 YCoCg: R = Y + Co - Cg, G = Y + Cg, B = Y - Co - Cg;
//!   - 9 Ylog UV: Y = exp(c0) - eps, then `YUV->RGB`;
//!   - 10 Ylog Ulog Vlog: Y = exp(c0) - eps, U = sign(c1) eps exp(|c1|), V likewise, then
//!     `YUV->RGB`;
//!   - 11 Ylog U/Y V/Y: Y = exp(c0) - eps, U = c1 (Y + eps), V = c2 (Y + eps), then `YUV->RGB`
//!     (the `btflib` form; `btf.hh` computes U = c1 Y + eps and clamps the result to [0, 1]);
//!   - 12 log RGB: exp(c) - eps.
//!
//!   LAB (2) and the spectral models (5, 6) are refused with an error naming the model, as is
//!   any other number. Sums are accumulated in f32 (eight lanes), the colour models evaluated in
//!   f64; double scalars are read as f32. No clamping is done.
//! * **btfrs's convention** (values include the light's cosine, colour scale applied): every
//!   value of channel `c` is multiplied by the file's RGB scale factor `c`, and, unless the
//!   cosine flag is set, by cos(theta_light). `btflib` reads the flag the same way ("is the
//!   cosine of the light source's polar angle already multiplied", `read_meta_data.m`) and
//!   divides flagged values by the cosine, because its convention is the other one; it never
//!   applies the scale factors. So a btfrs value is `btflib's value * cos(theta_light) * scale`
//!   whatever the flag, which the fixtures made by `btflib` check. Scale factors that are not
//!   finite and positive are refused. What was done is recorded under `"values"` in
//!   [`Capture::meta`] (`Btf.meta` in Python).
//! * **Directions**: the file's angles are radians (`btf.hh` feeds them to `tanf`, `btflib`'s
//!   `sph2cart2` documents radians), theta from the normal and phi the azimuth, with
//!   `(sin theta cos phi, sin theta sin phi, cos theta)` (`btf.hh` `SphereToCartesianCoordinates`,
//!   `btflib` `sph2cart2`). Neither source states how x and y lie on the image; this reader takes
//!   x along the image columns to the right and y towards the top row, which is btfrs's frame, so
//!   the vector is used as is. (`btf.hh` flips the image bottom-up and keeps the vector, which
//!   agrees: its texture y then grows in the direction of the vector's y.)
//! * **Rotations** are 9 floats (36 bytes) each (`btf.hh` reads `Matrix3`s, `btflib`
//!   `read_matrix(fid, '*float', n, 3, 3)`); they are read and reported in the header, not
//!   applied.
//! * **Signatures**: `!DFMF08FCR` and `!DFMF08FC` are read. `!FMF12FCER`, `!FMF06FCR`,
//!   `!FMF06FC`, `!PVF06FCR`, `!PVF06FC` and `!BDIF06R2!` are recognised and refused with an
//!   error naming the signature and the format; anything else is "not a UBO2014 `.btf` file".
//!   `!DFMF08FC` followed by a metadata size whose low byte is `'R'` looks like `!DFMF08FCR`
//!   (`btf.hh` would misread it); the version field tells them apart: read after the `'R'` it
//!   must be 1 to 4, which it never is when the `'R'` was the size's low byte (the version's
//!   high bytes are 0 and the next byte is the first of the setup string, so the misread
//!   version is 0 or at least 2^24).
//! * Only 3-channel files are decoded (the capture is RGB); [`read_header`] reports any channel
//!   count. Every channel needs at least one component; channels may differ in scalar size and
//!   component count (`btflib` allows this, `btf.hh` does not).
//! * Every size in the file is checked against the bytes that remain before anything is
//!   allocated or skipped; bytes after the last channel are an error (as in `btf.hh`).
//!
//! [`write_dfmf`] writes the same layout (metadata versions 1 to 4, half, float or double
//! scalars), so that tests and users can make files.

use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom, Write};
use std::path::Path;

use btfrs_core::{Error, Monitor, Result};
use rayon::prelude::*;

use crate::atomic::write_atomic;
use crate::capture::{Capture, Crop, Selection, Source};

/// The signature of a DFMF file with a rotation block.
pub const DFMF_SIGNATURE: &str = "!DFMF08FCR";
/// The signature of a DFMF file without rotations.
pub const DFMF_SIGNATURE_NO_ROTATIONS: &str = "!DFMF08FC";

/// Every signature this module recognises, longest first where one is a prefix of another,
/// with what it is.
pub const SIGNATURES: [(&str, &str); 8] = [
    ("!DFMF08FCR", "DFMF (decorrelated full matrix factorization) with rotations"),
    ("!DFMF08FC", "DFMF (decorrelated full matrix factorization)"),
    ("!FMF12FCER", "FMF (full matrix factorization, extended header) with rotations"),
    ("!FMF06FCR", "FMF (full matrix factorization) with rotations"),
    ("!FMF06FC", "FMF (full matrix factorization)"),
    ("!PVF06FCR", "PVF (per-view factorization) with rotations"),
    ("!PVF06FC", "PVF (per-view factorization)"),
    ("!BDIF06R2!", "BDI (bidirectional image chunks)"),
];

/// The dynamic-range epsilon of the log colour models (hard-coded by the format's readers).
pub const DRR_EPS: f64 = 1e-5;

/// Bytes of the three fixed-length strings of the metadata block.
const TEXT_LEN: usize = 80;
/// Bytes of a version-1 metadata block: size, version, 3 x char[80], f32, 3 x f32.
const META_V1_LEN: u64 = 4 + 4 + 3 * TEXT_LEN as u64 + 4 + 12;
/// The smallest channel header: u8 scalar size and three u32.
const CHANNEL_HEADER_LEN: u64 = 1 + 12;
/// Pixels decoded together against each (view, light) pair.
const PIXEL_BLOCK: usize = 16;

/// How the scalars of a channel are stored.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Scalar {
    /// IEEE 754 binary16 (scalar size 2), as UBO2014 files store them.
    Half,
    /// IEEE 754 binary32 (scalar size 4).
    F32,
    /// IEEE 754 binary64 (scalar size 8).
    F64,
}

impl Scalar {
    /// The scalar-size byte of the file.
    pub fn size(self) -> usize {
        match self {
            Scalar::Half => 2,
            Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    /// The scalar type for a scalar-size byte, if it is one.
    pub fn from_size(size: u8) -> Option<Scalar> {
        match size {
            2 => Some(Scalar::Half),
            4 => Some(Scalar::F32),
            8 => Some(Scalar::F64),
            _ => None,
        }
    }

    /// `x` as this scalar type stores it (what a reader gets back), as f64.
    pub fn quantize(self, x: f64) -> f64 {
        match self {
            Scalar::Half => half_to_f32(f32_to_half(x as f32)) as f64,
            Scalar::F32 => x as f32 as f64,
            Scalar::F64 => x,
        }
    }

    fn decode(self, bytes: &[u8], out: &mut Vec<f32>) {
        out.clear();
        match self {
            Scalar::Half => out.extend(bytes.chunks_exact(2).map(|b| half_to_f32(u16::from_le_bytes([b[0], b[1]])))),
            Scalar::F32 => out.extend(bytes.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))),
            Scalar::F64 => out.extend(
                bytes
                    .chunks_exact(8)
                    .map(|b| f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]) as f32),
            ),
        }
    }
}

/// A binary16 value (bits) as f32 (exact).
pub fn half_to_f32(h: u16) -> f32 {
    let sign = ((h >> 15) as u32) << 31;
    let exp = ((h >> 10) & 0x1f) as u32;
    let man = (h & 0x3ff) as u32;
    let bits = match exp {
        0 => {
            // Zero or subnormal: man * 2^-24, exact in f32.
            let v = man as f32 * (1.0 / 16_777_216.0);
            return if sign != 0 { -v } else { v };
        }
        31 => sign | 0x7f80_0000 | (man << 13),
        _ => sign | ((exp + 112) << 23) | (man << 13),
    };
    f32::from_bits(bits)
}

/// The binary16 value (bits) nearest to `x` (ties to even; overflow to infinity, NaN stays NaN).
pub fn f32_to_half(x: f32) -> u16 {
    let b = x.to_bits();
    let sign = ((b >> 16) & 0x8000) as u16;
    let exp = ((b >> 23) & 0xff) as i32;
    let man = b & 0x7f_ffff;
    if exp == 255 {
        return sign | 0x7c00 | if man != 0 { 0x200 } else { 0 };
    }
    let e = exp - 112; // the binary16 biased exponent
    if e >= 31 {
        return sign | 0x7c00;
    }
    let round = |m: u32, shift: u32| -> u32 {
        let h = m >> shift;
        let rem = m & ((1 << shift) - 1);
        let half = 1 << (shift - 1);
        if rem > half || (rem == half && h & 1 == 1) {
            h + 1
        } else {
            h
        }
    };
    if e <= 0 {
        if e < -10 {
            return sign;
        }
        // Subnormal: the 24-bit significand shifted to units of 2^-24 (a carry into 0x400 is
        // the smallest normal, as it should be).
        return sign | round(man | 0x80_0000, (14 - e) as u32) as u16;
    }
    // Normal: a carry out of the mantissa moves into the exponent (up to infinity), correctly.
    sign | round(((e as u32) << 23) | man, 13) as u16
}

/// The directions of one view in the file: its angles and its lights' angles (radians).
#[derive(Debug, Clone, PartialEq)]
pub struct ViewSampling {
    /// Polar angle of the view, from the normal (radians).
    pub theta: f32,
    /// Azimuth of the view (radians).
    pub phi: f32,
    /// `[theta, phi]` of each light of this view (radians).
    pub lights: Vec<[f32; 2]>,
}

/// One channel of the DFMF payload as the file describes it.
#[derive(Debug, Clone, PartialEq)]
pub struct DfmfChannel {
    /// How its scalars are stored.
    pub scalar: Scalar,
    /// Components `k` of its factorization.
    pub components: u32,
    /// Rows of U: the (view, light) pairs.
    pub rows: u32,
    /// Rows of S.V: the pixels, `width * height`.
    pub columns: u32,
    /// Byte offset of S (`k` scalars) in the file.
    pub s_offset: u64,
    /// Byte offset of U (`rows x k` scalars, row-major).
    pub u_offset: u64,
    /// Byte offset of S.V (`columns x k` scalars, row-major).
    pub sxv_offset: u64,
}

/// Everything a UBO2014 DFMF file says before (and about) its payload.
#[derive(Debug, Clone, PartialEq)]
pub struct Ubo2014Header {
    /// The signature, e.g. `!DFMF08FCR`.
    pub signature: String,
    /// The metadata block's size field (bytes, the field included).
    pub meta_size: u32,
    /// The metadata block's version (1 to 4).
    pub version: u32,
    /// Measurement setup (the `char[80]` up to its first NUL, lossy UTF-8).
    pub measurement_setup: String,
    /// Image sensor (`char[80]`).
    pub image_sensor: String,
    /// Light source (`char[80]`).
    pub light_source: String,
    /// Pixels per millimetre on the sample.
    pub pixels_per_mm: f32,
    /// RGB scale factors (not applied by the reader).
    pub rgb_scale: [f32; 3],
    /// Whether the data already hold the cosine of the light's polar angle (version >= 2).
    pub cosine_flag: Option<u32>,
    /// The measurement's XML description (version >= 3, lossy UTF-8).
    pub xml: Option<String>,
    /// Channel names: from the file for version >= 4, else `R`, `G`, `B`.
    pub channel_names: Vec<String>,
    /// Views in file order, each with its lights.
    pub views: Vec<ViewSampling>,
    /// Texels per image row.
    pub width: u32,
    /// Image rows.
    pub height: u32,
    /// Rotations (3x3, row-major as stored) when the signature ends in `R`, else empty.
    pub rotations: Vec<[f32; 9]>,
    /// The payload's component count (the largest per-channel count).
    pub components: u32,
    /// Colour model number (see the module doc).
    pub color_model: i32,
    /// Colour mean (used by the PCA model).
    pub color_mean: [f32; 3],
    /// Colour transform, row-major (used by the PCA model).
    pub color_transform: [f32; 9],
    /// The channels' factorizations.
    pub channels: Vec<DfmfChannel>,
}

/// A bounded reader: every read is checked against the bytes left in the file first.
struct Reader<'a> {
    r: BufReader<File>,
    pos: u64,
    len: u64,
    path: &'a str,
}

impl Reader<'_> {
    fn left(&self) -> u64 {
        self.len - self.pos
    }

    fn need(&self, n: u64, what: &str) -> Result<()> {
        if n > self.left() {
            return Err(Error::format(
                self.path,
                format!(
                    "the file ends inside {what}: {n} bytes needed at offset {}, {} left (truncated, or not a UBO2014 file)",
                    self.pos,
                    self.left()
                ),
            ));
        }
        Ok(())
    }

    fn bytes(&mut self, n: u64, what: &str) -> Result<Vec<u8>> {
        self.need(n, what)?;
        let mut v = vec![0u8; n as usize];
        self.r.read_exact(&mut v).map_err(|e| Error::io(self.path, e))?;
        self.pos += n;
        Ok(v)
    }

    fn array<const N: usize>(&mut self, what: &str) -> Result<[u8; N]> {
        self.need(N as u64, what)?;
        let mut v = [0u8; N];
        self.r.read_exact(&mut v).map_err(|e| Error::io(self.path, e))?;
        self.pos += N as u64;
        Ok(v)
    }

    fn u8(&mut self, what: &str) -> Result<u8> {
        Ok(self.array::<1>(what)?[0])
    }

    fn u32(&mut self, what: &str) -> Result<u32> {
        Ok(u32::from_le_bytes(self.array(what)?))
    }

    fn i32(&mut self, what: &str) -> Result<i32> {
        Ok(i32::from_le_bytes(self.array(what)?))
    }

    fn f32(&mut self, what: &str) -> Result<f32> {
        Ok(f32::from_le_bytes(self.array(what)?))
    }

    fn f32s<const N: usize>(&mut self, what: &str) -> Result<[f32; N]> {
        let mut v = [0f32; N];
        for x in &mut v {
            *x = self.f32(what)?;
        }
        Ok(v)
    }

    fn skip(&mut self, n: u64, what: &str) -> Result<()> {
        self.need(n, what)?;
        let step = i64::try_from(n).map_err(|_| Error::format(self.path, format!("{what} is too large")))?;
        self.r.seek_relative(step).map_err(|e| Error::io(self.path, e))?;
        self.pos += n;
        Ok(())
    }
}

/// A NUL-terminated (or NUL-padded) string as text.
fn text(bytes: &[u8]) -> String {
    let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
    String::from_utf8_lossy(&bytes[..end]).into_owned()
}

/// Bytes shown in an error: printable ASCII as is, the rest escaped.
fn shown_bytes(bytes: &[u8]) -> String {
    bytes.iter().flat_map(|&b| std::ascii::escape_default(b)).map(char::from).collect()
}

/// Read the signature; `Ok` only for DFMF.
fn read_signature(r: &mut Reader) -> Result<&'static str> {
    // The signature and the metadata block's size and version (to tell `!DFMF08FC` + a size
    // whose low byte is 'R' from `!DFMF08FCR`).
    let n = r.left().min(18);
    let head = r.bytes(n, "the signature")?;
    let expected = || SIGNATURES.iter().map(|s| s.0).collect::<Vec<_>>().join(", ");
    let Some(&(mut sig, what)) = SIGNATURES.iter().find(|(s, _)| head.starts_with(s.as_bytes())) else {
        if SIGNATURES.iter().any(|(s, _)| !head.is_empty() && s.as_bytes().starts_with(&head)) {
            return Err(Error::format(
                r.path,
                format!("the file ends inside the signature ({} bytes: \"{}\")", head.len(), shown_bytes(&head)),
            ));
        }
        return Err(Error::format(
            r.path,
            format!(
                "not a UBO2014 .btf file: expected a signature (one of {}), found \"{}\"",
                expected(),
                shown_bytes(&head[..head.len().min(10)])
            ),
        ));
    };
    if sig != DFMF_SIGNATURE && sig != DFMF_SIGNATURE_NO_ROTATIONS {
        return Err(Error::format(
            r.path,
            format!(
                "signature {sig}: {what} files are not supported; only DFMF files ({DFMF_SIGNATURE} or {DFMF_SIGNATURE_NO_ROTATIONS}) are read"
            ),
        ));
    }
    let version_at = |o: usize| head.get(o..o + 4).map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]));
    let valid = |v: Option<u32>| v.is_some_and(|v| (1..=4).contains(&v));
    if sig == DFMF_SIGNATURE && !valid(version_at(14)) && valid(version_at(13)) {
        sig = DFMF_SIGNATURE_NO_ROTATIONS;
    }
    // Step back over what followed the signature.
    let back = head.len() - sig.len();
    r.r.seek_relative(-(back as i64)).map_err(|e| Error::io(r.path, e))?;
    r.pos -= back as u64;
    Ok(sig)
}

/// Read the header of a UBO2014 DFMF `.btf` file (everything but the payload's scalars), with
/// every size checked against the file.
pub fn read_header(path: &Path) -> Result<Ubo2014Header> {
    let shown = path.display().to_string();
    let (file, _) = crate::untrusted::open(path)?;
    let len = file.metadata().map_err(|e| Error::io(&shown, e))?.len();
    let mut r = Reader { r: BufReader::with_capacity(1 << 16, file), pos: 0, len, path: &shown };
    let signature = read_signature(&mut r)?;
    let fmt = |msg: String| Error::format(&shown, msg);

    // Metadata block.
    let start = r.pos;
    let meta_size = r.u32("the metadata block")?;
    let version = r.u32("the metadata block")?;
    if !(1..=4).contains(&version) {
        return Err(fmt(format!("metadata version {version} is not supported (expected 1 to 4)")));
    }
    if (meta_size as u64) < META_V1_LEN {
        return Err(fmt(format!(
            "the metadata block's size {meta_size} is below the {META_V1_LEN} bytes of version 1"
        )));
    }
    r.need(meta_size as u64 - 8, "the metadata block")?;
    let meta_end = start + meta_size as u64;
    let measurement_setup = text(&r.bytes(TEXT_LEN as u64, "the measurement setup")?);
    let image_sensor = text(&r.bytes(TEXT_LEN as u64, "the image sensor")?);
    let light_source = text(&r.bytes(TEXT_LEN as u64, "the light source")?);
    let pixels_per_mm = r.f32("the pixels per mm")?;
    let rgb_scale = r.f32s::<3>("the RGB scale")?;
    let in_meta = |r: &Reader, n: u64, what: &str| -> Result<()> {
        if r.pos.checked_add(n).is_none_or(|e| e > meta_end) {
            return Err(Error::format(
                r.path,
                format!("{what} ({n} bytes at offset {}) runs past the metadata block's {meta_size} bytes", r.pos),
            ));
        }
        Ok(())
    };
    let cosine_flag = if version >= 2 {
        in_meta(&r, 4, "the cosine flag")?;
        Some(r.u32("the cosine flag")?)
    } else {
        None
    };
    let xml = if version >= 3 {
        in_meta(&r, 4, "the XML length")?;
        let n = r.u32("the XML length")? as u64;
        in_meta(&r, n, "the XML string")?;
        Some(String::from_utf8_lossy(&r.bytes(n, "the XML string")?).into_owned())
    } else {
        None
    };
    let channel_names = if version >= 4 {
        in_meta(&r, 4, "the channel count")?;
        let count = r.u32("the channel count")? as u64;
        in_meta(&r, count.saturating_mul(4), "the channel names")?;
        let mut names = Vec::with_capacity(count as usize);
        for c in 0..count {
            in_meta(&r, 4, "a channel name's length")?;
            let n = r.u32("a channel name's length")? as u64;
            in_meta(&r, n, &format!("channel name {c}"))?;
            names.push(String::from_utf8_lossy(&r.bytes(n, "a channel name")?).into_owned());
        }
        names
    } else {
        ["R", "G", "B"].map(String::from).to_vec()
    };
    if r.pos != meta_end {
        return Err(fmt(format!(
            "the metadata block (version {version}) holds {} bytes, its size field says {meta_size}",
            r.pos - start
        )));
    }

    // Bidirectional sampling.
    let nviews = r.u32("the view count")? as u64;
    r.need(nviews.saturating_mul(12), "the view directions")?;
    let mut views = Vec::with_capacity(nviews as usize);
    for v in 0..nviews {
        let theta = r.f32("a view direction")?;
        let phi = r.f32("a view direction")?;
        let nl = r.u32("a light count")? as u64;
        r.need(nl.saturating_mul(8), &format!("the light directions of view {v}"))?;
        let mut lights = Vec::with_capacity(nl as usize);
        for _ in 0..nl {
            lights.push(r.f32s::<2>("a light direction")?);
        }
        views.push(ViewSampling { theta, phi, lights });
    }
    let width = r.u32("the image width")?;
    let height = r.u32("the image height")?;
    let mut rotations = Vec::new();
    if signature.ends_with('R') {
        let n = r.u32("the rotation count")? as u64;
        r.need(n.saturating_mul(36), "the rotations")?;
        rotations.reserve_exact(n as usize);
        for _ in 0..n {
            rotations.push(r.f32s::<9>("a rotation")?);
        }
    }

    // DFMF payload.
    let components = r.u32("the component count")?;
    let color_model = r.i32("the colour model")?;
    let color_mean = r.f32s::<3>("the colour mean")?;
    let color_transform = r.f32s::<9>("the colour transform")?;
    let nchannels = channel_names.len() as u64;
    r.need(nchannels.saturating_mul(CHANNEL_HEADER_LEN), "the channels")?;
    let expected_rows: u64 = views.iter().map(|v| v.lights.len() as u64).sum();
    let expected_cols = width as u64 * height as u64;
    let mut channels = Vec::with_capacity(nchannels as usize);
    for c in 0..nchannels {
        let size = r.u8("a channel's scalar size")?;
        let scalar = Scalar::from_size(size).ok_or_else(|| {
            fmt(format!(
                "channel {c}: scalar size {size} is not supported (expected 2 = half, 4 = float or 8 = double)"
            ))
        })?;
        let k = r.u32("a channel's component count")?;
        let rows = r.u32("a channel's row count")?;
        let columns = r.u32("a channel's column count")?;
        if rows as u64 != expected_rows {
            return Err(fmt(format!(
                "channel {c} has {rows} rows, expected one per (view, light) pair: {expected_rows}"
            )));
        }
        if columns as u64 != expected_cols {
            return Err(fmt(format!(
                "channel {c} has {columns} columns, expected width x height = {width} x {height} = {expected_cols}"
            )));
        }
        if k == 0 {
            return Err(fmt(format!("channel {c} has no components")));
        }
        let ss = scalar.size() as u64;
        let k = k as u64;
        let s_bytes = k * ss;
        let u_bytes = (rows as u64).checked_mul(k * ss);
        let sxv_bytes = (columns as u64).checked_mul(k * ss);
        let (u_bytes, total) = u_bytes
            .zip(sxv_bytes)
            .and_then(|(u, x)| u.checked_add(x).and_then(|t| t.checked_add(s_bytes)).map(|t| (u, t)))
            .ok_or_else(|| fmt(format!("channel {c}: its matrices do not fit in a file")))?;
        r.need(total, &format!("channel {c}'s matrices ({k} components, {rows} rows, {columns} columns)"))?;
        let s_offset = r.pos;
        let u_offset = s_offset + s_bytes;
        let sxv_offset = u_offset + u_bytes;
        r.skip(total, "a channel's matrices")?;
        channels.push(DfmfChannel { scalar, components: k as u32, rows, columns, s_offset, u_offset, sxv_offset });
    }
    if r.pos != len {
        return Err(fmt(format!("{} unexpected bytes after the last channel (offset {})", len - r.pos, r.pos)));
    }
    Ok(Ubo2014Header {
        signature: signature.to_string(),
        meta_size,
        version,
        measurement_setup,
        image_sensor,
        light_source,
        pixels_per_mm,
        rgb_scale,
        cosine_flag,
        xml,
        channel_names,
        views,
        width,
        height,
        rotations,
        components,
        color_model,
        color_mean,
        color_transform,
        channels,
    })
}

/// The colour models the reader decodes (numbers as in the file).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum ColorModel {
    Rgb,
    Yuv,
    Pca,
    YCoCg,
    YlogUv,
    YlogUlogVlog,
    YlogUdivYVdivY,
    LogRgb,
}

impl ColorModel {
    fn from_file(model: i32) -> std::result::Result<ColorModel, String> {
        Ok(match model {
            0 => ColorModel::Rgb,
            1 => ColorModel::Yuv,
            3 => ColorModel::Pca,
            4 => ColorModel::YCoCg,
            9 => ColorModel::YlogUv,
            10 => ColorModel::YlogUlogVlog,
            11 => ColorModel::YlogUdivYVdivY,
            12 => ColorModel::LogRgb,
            2 => return Err("colour model 2 (LAB) is not supported".into()),
            5 | 6 => return Err(format!("colour model {model} (spectral) is not supported")),
            _ => {
                return Err(format!(
                    "colour model {model} is not supported (expected 0 RGB, 1 YUV, 3 PCA, 4 YCoCg, 9 Ylog-UV, 10 Ylog-Ulog-Vlog, 11 Ylog-U/Y-V/Y or 12 log-RGB)"
                ))
            }
        })
    }
}

fn yuv_to_rgb([y, u, v]: [f64; 3]) -> [f64; 3] {
    [y + 1.13983 * v, y - 0.39465 * u - 0.58060 * v, y + 2.03211 * u]
}

/// The colour transform of one decoded triple (see the module doc).
fn to_rgb(model: ColorModel, c: [f32; 3], mean: &[f64; 3], m: &[f64; 9]) -> [f64; 3] {
    let c = c.map(f64::from);
    let eps = DRR_EPS;
    match model {
        ColorModel::Rgb => c,
        ColorModel::Yuv => yuv_to_rgb(c),
        ColorModel::Pca => std::array::from_fn(|j| c[0] * m[j] + c[1] * m[3 + j] + c[2] * m[6 + j] + mean[j]),
        ColorModel::YCoCg => [c[0] + c[1] - c[2], c[0] + c[2], c[0] - c[1] - c[2]],
        ColorModel::YlogUv => yuv_to_rgb([c[0].exp() - eps, c[1], c[2]]),
        ColorModel::YlogUlogVlog => {
            let un = |x: f64| x.signum() * eps * x.abs().exp();
            let un = |x: f64| if x == 0.0 { 0.0 } else { un(x) };
            yuv_to_rgb([c[0].exp() - eps, un(c[1]), un(c[2])])
        }
        ColorModel::YlogUdivYVdivY => {
            let y = c[0].exp() - eps;
            yuv_to_rgb([y, c[1] * (y + eps), c[2] * (y + eps)])
        }
        ColorModel::LogRgb => c.map(|x| x.exp() - eps),
    }
}

/// A sum of products in eight f32 lanes (vectorizes; the error grows with `len / 8`, not `len`).
#[inline]
fn dot(a: &[f32], b: &[f32]) -> f32 {
    let mut acc = [0f32; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let tail: f32 = ca.remainder().iter().zip(cb.remainder()).map(|(x, y)| x * y).sum();
    for (x, y) in ca.zip(cb) {
        for i in 0..8 {
            acc[i] += x[i] * y[i];
        }
    }
    ((acc[0] + acc[4]) + (acc[1] + acc[5])) + ((acc[2] + acc[6]) + (acc[3] + acc[7])) + tail
}

fn direction(theta: f32, phi: f32) -> [f64; 3] {
    let (t, p) = (theta as f64, phi as f64);
    [t.sin() * p.cos(), t.sin() * p.sin(), t.cos()]
}

/// An opened UBO2014 DFMF file with a selection applied: a [`Source`] for [`crate::capture::load`].
#[derive(Debug)]
pub struct Ubo2014 {
    path: std::path::PathBuf,
    shown: String,
    header: Ubo2014Header,
    model: ColorModel,
    capture: Capture,
    crop: Crop,
    /// Kept file views.
    views: Vec<usize>,
    /// Kept union lights.
    lights: Vec<usize>,
    /// Per kept (view, light) pair (view-major): the row of U, or `None` when absent.
    rows: Vec<Option<u32>>,
    /// The union light list (file angles).
    union_lights: Vec<[f32; 2]>,
}

impl Ubo2014 {
    /// Open `path`, read its header and plan the decode of the selection (`sel.views` index the
    /// file's views, `sel.lights` the union of the views' lights).
    pub fn open(path: &Path, sel: &Selection) -> Result<Ubo2014> {
        let shown = path.display().to_string();
        let header = read_header(path)?;
        let fmt = |msg: String| Error::format(&shown, msg);
        if header.channels.len() != 3 {
            return Err(fmt(format!(
                "the file has {} channels ({}); only 3-channel colour DFMF files are decoded",
                header.channels.len(),
                header.channel_names.join(", ")
            )));
        }
        let model = ColorModel::from_file(header.color_model).map_err(fmt)?;
        if header.width == 0 || header.height == 0 {
            return Err(fmt(format!("the images are {} x {} texels", header.width, header.height)));
        }
        if header.views.is_empty() {
            return Err(fmt("the file has no views".into()));
        }
        if !header.rgb_scale.iter().all(|s| s.is_finite() && *s > 0.0) {
            return Err(fmt(format!(
                "the RGB scale factors are {:?}; expected three finite positive numbers (the values are multiplied by \
                 them, so with these the file's colours cannot be known)",
                header.rgb_scale
            )));
        }

        // The union of the views' lights, and each view's row per union light.
        let key = |l: &[f32; 2]| (l[0].to_bits(), l[1].to_bits());
        let mut index = std::collections::HashMap::new();
        let mut union_lights = Vec::new();
        for v in &header.views {
            for l in &v.lights {
                index.entry(key(l)).or_insert_with(|| {
                    union_lights.push(*l);
                    union_lights.len() - 1
                });
            }
        }
        if union_lights.is_empty() {
            return Err(fmt("the file has no lights".into()));
        }
        let nl = union_lights.len();
        let mut view_rows = Vec::with_capacity(header.views.len());
        let mut row = 0u32;
        for (vi, v) in header.views.iter().enumerate() {
            let mut rows = vec![None; nl];
            for l in &v.lights {
                let slot = &mut rows[index[&key(l)]];
                if slot.is_some() {
                    return Err(fmt(format!("view {vi} lists the light (theta {}, phi {}) twice", l[0], l[1])));
                }
                *slot = Some(row);
                row += 1;
            }
            view_rows.push(rows);
        }

        let (h, w) = (header.height as usize, header.width as usize);
        let crop = sel.rect(h, w)?;
        let views = Selection::pick("views", &sel.views, header.views.len())?;
        let lights = Selection::pick("lights", &sel.lights, nl)?;
        let rows: Vec<Option<u32>> =
            views.iter().flat_map(|&v| lights.iter().map(|&l| view_rows[v][l]).collect::<Vec<_>>()).collect();
        let mask =
            if rows.iter().all(Option::is_some) { None } else { Some(rows.iter().map(Option::is_some).collect()) };
        crop.rows
            .checked_mul(crop.cols)
            .and_then(|n| n.checked_mul(rows.len()))
            .and_then(|n| n.checked_mul(3))
            .ok_or_else(|| fmt("the selection's values do not fit in memory".into()))?;

        let meta = serde_json::json!({
            "format": "UBO2014 DFMF",
            "signature": header.signature,
            "version": header.version,
            "measurement_setup": header.measurement_setup,
            "image_sensor": header.image_sensor,
            "light_source": header.light_source,
            "pixels_per_mm": header.pixels_per_mm,
            "rgb_scale": header.rgb_scale,
            "cosine_flag": header.cosine_flag,
            "xml": header.xml,
            "channel_names": header.channel_names,
            "color_model": header.color_model,
            "components": header.channels.iter().map(|c| c.components).collect::<Vec<_>>(),
            "scalar_size": header.channels.iter().map(|c| c.scalar.size()).collect::<Vec<_>>(),
            "rotations": header.rotations.len(),
            "angles": "radians, theta from the normal, phi from x (image columns, right) towards y (up the image)",
            "values": crate::capture::values_record(
                if header.cosine_flag.is_some_and(|f| f != 0) {
                    "in the file (cosine flag set): kept"
                } else {
                    "multiplied in by the reader (the file's values exclude it: cosine flag 0 or absent)"
                },
                header.rgb_scale,
                "linear, as stored",
            ),
        });
        let capture = Capture {
            height: crop.rows,
            width: crop.cols,
            views: views.iter().map(|&v| direction(header.views[v].theta, header.views[v].phi)).collect(),
            lights: lights.iter().map(|&l| direction(union_lights[l][0], union_lights[l][1])).collect(),
            mask,
            meta,
        };
        Ok(Ubo2014 { path: path.to_path_buf(), shown, header, model, capture, crop, views, lights, rows, union_lights })
    }

    /// The file's header.
    pub fn header(&self) -> &Ubo2014Header {
        &self.header
    }

    /// The union of the views' lights, `[theta, phi]` in radians as the file gives them (what
    /// `Selection::lights` indexes).
    pub fn union_lights(&self) -> &[[f32; 2]] {
        &self.union_lights
    }

    /// The kept file view indices and union light indices.
    pub fn selected(&self) -> (&[usize], &[usize]) {
        (&self.views, &self.lights)
    }

    /// Per kept pair, the factor each channel is multiplied by to reach btfrs's convention
    /// (see the module doc): the file's RGB scale, times cos(theta_light) unless the cosine flag
    /// says the values already hold it.
    fn gains(&self) -> Vec<[f64; 3]> {
        let s = self.header.rgb_scale.map(f64::from);
        let with_cosine = self.header.cosine_flag.is_some_and(|f| f != 0);
        let nl = self.lights.len();
        (0..self.rows.len())
            .map(|p| {
                let c = if with_cosine { 1.0 } else { self.capture.lights[p % nl][2] };
                s.map(|x| x * c)
            })
            .collect()
    }

    /// U of channel `c` for the kept pairs: `[pairs][k]` (absent pairs 0).
    fn selected_u(&self, c: usize) -> Result<Vec<f32>> {
        let ch = &self.header.channels[c];
        let k = ch.components as usize;
        let row_bytes = k * ch.scalar.size();
        let io = |e| Error::io(&self.shown, e);
        let mut file = BufReader::with_capacity(1 << 16, File::open(&self.path).map_err(io)?);
        let mut out = vec![0f32; self.rows.len() * k];
        let mut buf = Vec::with_capacity(k);
        let present = self.rows.iter().filter(|r| r.is_some()).count();
        if present as u64 * 4 >= ch.rows as u64 {
            // Most rows are wanted: one read of the whole of U.
            let mut bytes = vec![0u8; ch.rows as usize * row_bytes];
            file.seek(SeekFrom::Start(ch.u_offset)).map_err(io)?;
            file.read_exact(&mut bytes).map_err(io)?;
            for (p, row) in self.rows.iter().enumerate() {
                if let Some(r) = *row {
                    let r = r as usize;
                    ch.scalar.decode(&bytes[r * row_bytes..(r + 1) * row_bytes], &mut buf);
                    out[p * k..(p + 1) * k].copy_from_slice(&buf);
                }
            }
        } else {
            // A small subset: the wanted rows only.
            let mut bytes = vec![0u8; row_bytes];
            for (p, row) in self.rows.iter().enumerate() {
                if let Some(r) = *row {
                    file.seek(SeekFrom::Start(ch.u_offset + r as u64 * row_bytes as u64)).map_err(io)?;
                    file.read_exact(&mut bytes).map_err(io)?;
                    ch.scalar.decode(&bytes, &mut buf);
                    out[p * k..(p + 1) * k].copy_from_slice(&buf);
                }
            }
        }
        Ok(out)
    }
}

impl Source for Ubo2014 {
    fn capture(&self) -> &Capture {
        &self.capture
    }

    fn decode_into(&self, out: &mut [f32], monitor: &Monitor) -> Result<()> {
        let cap = &self.capture;
        cap.check_buffer(out)?;
        let u: Vec<Vec<f32>> = (0..3).map(|c| self.selected_u(c)).collect::<Result<_>>()?;
        let mean = self.header.color_mean.map(f64::from);
        let m = self.header.color_transform.map(f64::from);
        let npairs = self.rows.len();
        let nl = self.lights.len();
        let gain = self.gains();
        let row_len = self.crop.cols * npairs * 3;
        let crop = self.crop;
        let width = self.header.width as u64;
        monitor.start(crop.rows as u64);
        out.par_chunks_mut(row_len).enumerate().try_for_each_init(
            || (File::open(&self.path), Vec::new(), [Vec::new(), Vec::new(), Vec::new()]),
            |(file, bytes, sxv), (i, chunk)| -> Result<()> {
                monitor.check()?;
                let file = match file {
                    Ok(f) => f,
                    Err(e) => return Err(Error::io(&self.shown, std::io::Error::new(e.kind(), e.to_string()))),
                };
                let texel_row = (crop.row + i) as u64;
                for (c, ch) in self.header.channels.iter().enumerate() {
                    let per_px = ch.components as u64 * ch.scalar.size() as u64;
                    let off = ch.sxv_offset + (texel_row * width + crop.col as u64) * per_px;
                    bytes.resize(crop.cols * per_px as usize, 0);
                    file.seek(SeekFrom::Start(off)).map_err(|e| Error::io(&self.shown, e))?;
                    file.read_exact(bytes).map_err(|e| Error::io(&self.shown, e))?;
                    ch.scalar.decode(bytes, &mut sxv[c]);
                }
                let ks = self.header.channels.iter().map(|c| c.components as usize).collect::<Vec<_>>();
                // Blocks of pixels, each against every pair: the pixels' S.V stay in L1 while
                // U streams through once per block (not once per pixel).
                for (b, block) in chunk.chunks_mut(PIXEL_BLOCK * npairs * 3).enumerate() {
                    let px0 = b * PIXEL_BLOCK;
                    for (p, row) in self.rows.iter().enumerate() {
                        if row.is_none() {
                            continue;
                        }
                        let up: [&[f32]; 3] = std::array::from_fn(|c| &u[c][p * ks[c]..(p + 1) * ks[c]]);
                        for (j, texel) in block.chunks_exact_mut(npairs * 3).enumerate() {
                            let px = px0 + j;
                            let ch: [f32; 3] =
                                std::array::from_fn(|c| dot(up[c], &sxv[c][px * ks[c]..(px + 1) * ks[c]]));
                            let g = &gain[p];
                            let rgb = to_rgb(self.model, ch, &mean, &m);
                            let v: [f32; 3] = std::array::from_fn(|c| (rgb[c] * g[c]) as f32);
                            if !v.iter().all(|x| x.is_finite()) {
                                return Err(Error::format(
                                    &self.shown,
                                    format!(
                                        "texel (row {}, column {}), view {}, light {} decodes to the non-finite value {:?}",
                                        texel_row,
                                        crop.col + px,
                                        self.views[p / nl],
                                        self.lights[p % nl],
                                        v
                                    ),
                                ));
                            }
                            texel[p * 3..p * 3 + 3].copy_from_slice(&v);
                        }
                    }
                }
                monitor.advance(1);
                Ok(())
            },
        )
    }
}

/// One view of a file to write: its angles and its lights' (radians).
pub type DfmfView = ViewSampling;

/// One channel to write: the factorization `U` (`rows x k`, row-major, rows = the (view, light)
/// pairs view-major) and `S.V` (`width*height x k`, row-major, pixels top row first), with the
/// singular values `S` (`k`; not used by the reader). Values are stored as `scalar` (rounded to
/// nearest; [`Scalar::quantize`] gives what a reader gets back), non-finite ones too.
#[derive(Debug, Clone, PartialEq)]
pub struct DfmfChannelData {
    /// How the scalars are stored.
    pub scalar: Scalar,
    /// Singular values (`k`).
    pub s: Vec<f64>,
    /// Left factor, `rows x k`.
    pub u: Vec<f64>,
    /// Right factor times the singular values, `width*height x k`.
    pub sxv: Vec<f64>,
}

/// Everything [`write_dfmf`] writes.
#[derive(Debug, Clone, PartialEq)]
pub struct DfmfFile {
    /// Metadata version, 1 to 4 (what the block holds: see the module doc).
    pub version: u32,
    /// Measurement setup (at most 80 bytes).
    pub measurement_setup: String,
    /// Image sensor (at most 80 bytes).
    pub image_sensor: String,
    /// Light source (at most 80 bytes).
    pub light_source: String,
    /// Pixels per mm.
    pub pixels_per_mm: f32,
    /// RGB scale factors.
    pub rgb_scale: [f32; 3],
    /// Cosine flag (written from version 2).
    pub cosine_flag: u32,
    /// XML description (written from version 3).
    pub xml: String,
    /// Channel names (written from version 4, one per channel; ignored before).
    pub channel_names: Vec<String>,
    /// Views with their lights.
    pub views: Vec<DfmfView>,
    /// Texels per row.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// `Some`: signature `!DFMF08FCR` and these rotations; `None`: `!DFMF08FC`.
    pub rotations: Option<Vec<[f32; 9]>>,
    /// Colour model number.
    pub color_model: i32,
    /// Colour mean.
    pub color_mean: [f32; 3],
    /// Colour transform, row-major.
    pub color_transform: [f32; 9],
    /// The channels (3 before version 4).
    pub channels: Vec<DfmfChannelData>,
}

impl DfmfFile {
    /// The metadata block's size field for this file.
    pub fn meta_size(&self) -> u64 {
        let mut n = META_V1_LEN;
        if self.version >= 2 {
            n += 4;
        }
        if self.version >= 3 {
            n += 4 + self.xml.len() as u64;
        }
        if self.version >= 4 {
            n += 4 + self.channel_names.iter().map(|s| 4 + s.len() as u64).sum::<u64>();
        }
        n
    }

    fn check(&self) -> Result<()> {
        let arg = |msg: String| Err(Error::arg("file", msg));
        if !(1..=4).contains(&self.version) {
            return arg(format!("version {} is not one of 1 to 4", self.version));
        }
        for (name, s) in [
            ("measurement_setup", &self.measurement_setup),
            ("image_sensor", &self.image_sensor),
            ("light_source", &self.light_source),
        ] {
            if s.len() > TEXT_LEN {
                return arg(format!("{name} has {} bytes, at most {TEXT_LEN} fit", s.len()));
            }
        }
        if self.version >= 4 && self.channel_names.len() != self.channels.len() {
            return arg(format!("{} channel names for {} channels", self.channel_names.len(), self.channels.len()));
        }
        if self.version < 4 && self.channels.len() != 3 {
            return arg(format!("a version {} file has 3 channels, got {}", self.version, self.channels.len()));
        }
        if self.meta_size() > u32::MAX as u64 {
            return arg("the metadata block is larger than 4 GiB".into());
        }
        let rows: u64 = self.views.iter().map(|v| v.lights.len() as u64).sum();
        let cols = self.width as u64 * self.height as u64;
        if rows > u32::MAX as u64 || cols > u32::MAX as u64 || self.views.len() > u32::MAX as usize {
            return arg("more than 2^32 - 1 rows, columns or views".into());
        }
        for (c, ch) in self.channels.iter().enumerate() {
            let k = ch.s.len() as u64;
            if k == 0 || k > u32::MAX as u64 {
                return arg(format!("channel {c} has {k} components"));
            }
            if ch.u.len() as u64 != rows * k || ch.sxv.len() as u64 != cols * k {
                return arg(format!(
                    "channel {c}: U has {} values, S.V {}; expected {rows} x {k} and {cols} x {k}",
                    ch.u.len(),
                    ch.sxv.len()
                ));
            }
        }
        Ok(())
    }
}

fn put_scalars(w: &mut dyn Write, scalar: Scalar, xs: &[f64]) -> std::io::Result<()> {
    let mut buf = Vec::with_capacity(xs.len().min(1 << 16) * scalar.size());
    for chunk in xs.chunks(1 << 16) {
        buf.clear();
        for &x in chunk {
            match scalar {
                Scalar::Half => buf.extend_from_slice(&f32_to_half(x as f32).to_le_bytes()),
                Scalar::F32 => buf.extend_from_slice(&(x as f32).to_le_bytes()),
                Scalar::F64 => buf.extend_from_slice(&x.to_le_bytes()),
            }
        }
        w.write_all(&buf)?;
    }
    Ok(())
}

/// Write a UBO2014 DFMF `.btf` file (atomically: a temporary file renamed over `path`).
pub fn write_dfmf(path: &Path, file: &DfmfFile) -> Result<()> {
    file.check()?;
    write_atomic(path, |w| {
        let u32le = |w: &mut dyn Write, x: u32| w.write_all(&x.to_le_bytes());
        let f32s = |w: &mut dyn Write, xs: &[f32]| xs.iter().try_for_each(|x| w.write_all(&x.to_le_bytes()));
        let sig = if file.rotations.is_some() { DFMF_SIGNATURE } else { DFMF_SIGNATURE_NO_ROTATIONS };
        w.write_all(sig.as_bytes())?;
        u32le(w, file.meta_size() as u32)?;
        u32le(w, file.version)?;
        for s in [&file.measurement_setup, &file.image_sensor, &file.light_source] {
            let mut field = [0u8; TEXT_LEN];
            field[..s.len()].copy_from_slice(s.as_bytes());
            w.write_all(&field)?;
        }
        f32s(w, &[file.pixels_per_mm])?;
        f32s(w, &file.rgb_scale)?;
        if file.version >= 2 {
            u32le(w, file.cosine_flag)?;
        }
        if file.version >= 3 {
            u32le(w, file.xml.len() as u32)?;
            w.write_all(file.xml.as_bytes())?;
        }
        if file.version >= 4 {
            u32le(w, file.channel_names.len() as u32)?;
            for name in &file.channel_names {
                u32le(w, name.len() as u32)?;
                w.write_all(name.as_bytes())?;
            }
        }
        u32le(w, file.views.len() as u32)?;
        for v in &file.views {
            f32s(w, &[v.theta, v.phi])?;
            u32le(w, v.lights.len() as u32)?;
            for l in &v.lights {
                f32s(w, l)?;
            }
        }
        u32le(w, file.width)?;
        u32le(w, file.height)?;
        if let Some(rot) = &file.rotations {
            u32le(w, rot.len() as u32)?;
            for r in rot {
                f32s(w, r)?;
            }
        }
        let k_max = file.channels.iter().map(|c| c.s.len()).max().unwrap_or(0);
        u32le(w, k_max as u32)?;
        w.write_all(&file.color_model.to_le_bytes())?;
        f32s(w, &file.color_mean)?;
        f32s(w, &file.color_transform)?;
        let rows: usize = file.views.iter().map(|v| v.lights.len()).sum();
        for ch in &file.channels {
            w.write_all(&[ch.scalar.size() as u8])?;
            u32le(w, ch.s.len() as u32)?;
            u32le(w, rows as u32)?;
            u32le(w, file.width * file.height)?;
            put_scalars(w, ch.scalar, &ch.s)?;
            put_scalars(w, ch.scalar, &ch.u)?;
            put_scalars(w, ch.scalar, &ch.sxv)?;
        }
        Ok(())
    })
}
