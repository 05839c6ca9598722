//! Reading and writing Polynomial Texture Maps (`.ptm`, version `PTM_1.2`), the format that
//! RTIViewer (ISTI-CNR and Cultural Heritage Imaging) and relight (ISTI-CNR) open.
//!
//! # The model
//!
//! A PTM stores, per texel, the six coefficients of a biquadratic in the light direction
//! (Malzbender, Gelb and Wolters, "Polynomial Texture Maps", SIGGRAPH 2001, pp. 519-528):
//!
//! ```text
//! L(lu, lv) = a0 lu^2 + a1 lv^2 + a2 lu lv + a3 lu + a4 lv + a5
//! ```
//!
//! where `(lu, lv)` are the x and y components of the unit vector towards the light, in the
//! texture's tangent frame. In the PTM convention the texture's origin is its bottom-left corner
//! (see the row order below), so `u` points right and `v` towards the *top* of the image; this
//! module stores the coefficients as given and does not change frames. The format is described in T. Malzbender, D. Gelb, H. Wolters,
//! "Polynomial Texture Map (.ptm) File Format", HP Labs technical report HPL-2001-104, version 1.2
//! (November 2001), distributed as `PtmFormat12.pdf`.
//!
//! # The file
//!
//! ```text
//! PTM_1.2\n
//! PTM_FORMAT_LRGB\n          (or PTM_FORMAT_RGB)
//! <width>\n
//! <height>\n
//! <scale0> ... <scale5>\n    six floats
//! <bias0> ... <bias5>\n      six integers
//! <binary data, uncompressed>
//! ```
//!
//! A stored byte `c` of coefficient index `k` decodes to `(c - bias_k) * scale_k`; the same
//! `scale_k`/`bias_k` serve all texels and, for RGB, all three channels.
//!
//! * `PTM_FORMAT_LRGB`: a block of `W*H*6` bytes (`a0..a5` of the luminance polynomial, texel
//!   after texel), then a block of `W*H*3` bytes (`r, g, b` per texel).
//! * `PTM_FORMAT_RGB`: three blocks of `W*H*6` bytes, red, then green, then blue.
//!
//! Within every block the texels are in "reversed scanline order": the first row in the file is
//! the *bottom* row of the image, rows run left to right. [`PtmImage`] holds rows top to bottom
//! (row 0 = top), so the reader and the writer flip the rows.
//!
//! # Units (what the readers compute)
//!
//! The project's units are linear values where 1.0 is the viewer's white (byte 255). The
//! decoded coefficients of a PTM file are in *byte* units (0..255 = black..white), as the real
//! readers show:
//!
//! * RTIViewer (`rtiviewer/src/ptm.cpp`, `util.h`, `defaultrendering.h`; read in the
//!   `olvidalo/RTIViewer` copy on GitHub) decodes `static_cast<int>((c - bias[i]) * scale[i])`,
//!   evaluates the polynomial and, for `PTM_FORMAT_RGB`, writes the result straight to an 8-bit
//!   channel (`tobyte`: clamp to 0..255, truncate). For `PTM_FORMAT_LRGB` it computes
//!   `lum = poly / 255` and shows `tobyte(rgb_byte * lum)` per channel.
//! * relight (`cnr-isti-vclab/relight`, `src/legacy_rti.cpp`, `src/cli/convert_rti.cpp`) reads
//!   the same fields and turns the bias into `bias / 255` so that its texture values in 0..1
//!   decode to coefficients in 0..1 (i.e. the file's byte units divided by 255); the LRGB colour
//!   planes get scale 1, bias 0.
//! * The LRGB shaders of other viewers (e.g. `ksjogo/oxrti`) likewise compute
//!   `rgb01 * poly_bytes / 255`, and Perathoner's `ptmlib` fits the polynomial to 8-bit samples.
//!
//! So, writing `A_k` for the file's decoded coefficient and `a_k` for ours:
//!
//! * `A_k = 255 * a_k` for both formats; the header's scale is `255 *` [`PtmQuantization::scale`]
//!   (the quantization step in our units) and the bias is the same integer.
//! * RGB: the viewer shows `L_file = 255 * L_ours` per channel, i.e. our value 1.0 is white.
//! * LRGB: the colour byte is `round(255 * rgb)`, and the viewer shows
//!   `rgb_byte * L_file / 255 = 255 * rgb * L_ours`, i.e. the image is `rgb * L(lu, lv)` in our
//!   units. [`read_ptm`] returns exactly these quantities, so write and read are inverse up to
//!   the 8-bit quantization.
//!
//! The viewers apply no transfer function: the byte goes to the screen as is. Whether our
//! "linear" values should be sRGB-encoded before writing is the caller's choice.
//! RTIViewer also truncates each decoded coefficient to an integer number of byte units, so a
//! scale below 1 (a coefficient range narrower than 1.0 in our units) buys no extra precision
//! in RTIViewer, though it does in relight and in [`read_ptm`].
//!
//! # Choosing scale and bias
//!
//! Per coefficient index `k`, over all texels (and channels), with `lo`, `hi` the minimum and
//! maximum in byte units: `scale = (hi - lo) / 255` and `bias = round(-lo / scale)`. Because the
//! bias must be an integer, rounding it shifts the 256 codes by at most half a step; every value
//! in `[lo, hi]` then maps into `[-0.5, 255.5]` before rounding, so the error is at most
//! `scale / 2` even at the two ends (where a code of -1 or 256 clips to 0 or 255 with an error of
//! exactly half a step). The bias may be negative or above 255 (a coefficient that is all
//! positive, e.g. `a5`, gets a negative bias). All readers examined parse the bias as a signed
//! number (RTIViewer `QString::toInt` into an `int`, relight `strtod` into a `float`, `ptmlib`
//! `fscanf("%d")`, ptmconvert `operator>>(int&)`), and `ptmlib` itself writes unclamped, possibly
//! negative biases (`-256 * min / (max - min)`). To keep the bias within a 16-bit range, the
//! step is never made smaller than `max(|lo|, |hi|) / 32767`, which bounds `|bias| <= 32767`;
//! this only matters for coefficients whose spread is tiny compared with their magnitude
//! (including constant ones, `hi == lo`, which need no division by `hi - lo`). An all-zero
//! coefficient gets scale 1 (byte units), bias 0.
//!
//! # What the reader accepts
//!
//! The spec separates the five header sections by newlines "with an optional space before the
//! newline" and allows width and height on one line or two. RTIViewer reads line by line (width
//! and height on separate lines, scale and bias each on one line, split on spaces, with no `\r`
//! stripping), relight likewise line by line; ptmconvert and `ptmlib` read whitespace-separated
//! tokens. This reader is token based: any ASCII whitespace (spaces, tabs, `\r\n`, one number
//! per line, width and height on one line) separates the header fields, and the binary data start
//! right after the first `\n` that follows the last bias value (spaces, tabs and `\r` before it
//! are skipped). The writer emits the strictest form (the RTIViewer layout: one field per line,
//! `\n` only, no trailing spaces).
//!
//! * Version: `PTM_1.2`, and `PTM_1.1`, which RTIViewer and relight both still read: identical
//!   except that an LRGB file interleaves the colour with the coefficients (9 bytes per texel,
//!   `a0..a5 r g b`) instead of using a separate colour block. Other versions are rejected.
//! * Further header lines: none of the readers examined (RTIViewer, relight, ptmconvert,
//!   `ptmlib`) expects or skips any line between the bias line and the data of an uncompressed
//!   RGB/LRGB file, and no writer examined (relight, `ptmlib`, libvips' `writeptm`) emits one,
//!   so this reader does not skip any either. Extra lines exist only for other formats: the JPEG
//!   formats add the compression parameter, transforms, motion
//!   vectors, order, reference planes, compressed sizes and side-information sizes after the bias
//!   line, and `ptmlib` writes a 16-float colour matrix for `PTM_FORMAT_LUM`. Those formats
//!   (`PTM_FORMAT_LUM`, `_PTM_LUT`, `_PTM_C_LUT`, `_JPEG_RGB`, `_JPEG_LRGB`, `_JPEGLS_RGB`,
//!   `_JPEGLS_LRGB`) are rejected with an error naming the format.
//! * Bias values are read as any finite number (`128.0` too, as relight's `strtod` reads them;
//!   RTIViewer would reject a non-integer); scale values must be finite numbers too.
//! * Bytes after the expected data are ignored, as the viewers ignore them; missing bytes are an
//!   error, found before anything is allocated (the data must hold `width * height` texels).
//! * A scale and bias whose decoded coefficients overflow `f32` are an error.

use std::path::Path;

use btfrs_core::{Error, Result};
use btfrs_fit::planes::Planes;
use btfrs_fit::{PtmKind, PtmPlanes, PtmSlot};

/// Coefficients per polynomial.
const NCOEF: usize = 6;

/// Header tokens longer than this are not PTM header fields (probably binary data).
const MAX_TOKEN: usize = 64;

/// Which PTM variant.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PtmFormat {
    /// `PTM_FORMAT_RGB`: one polynomial per colour channel.
    Rgb,
    /// `PTM_FORMAT_LRGB`: one luminance polynomial and a base colour per texel.
    Lrgb,
}

impl PtmFormat {
    /// The format string of the header, e.g. `PTM_FORMAT_LRGB`.
    pub fn header_name(self) -> &'static str {
        match self {
            PtmFormat::Rgb => "PTM_FORMAT_RGB",
            PtmFormat::Lrgb => "PTM_FORMAT_LRGB",
        }
    }

    /// Polynomial coefficients per texel in [`PtmImage::coeffs`].
    fn coeffs_per_texel(self) -> usize {
        match self {
            PtmFormat::Rgb => 3 * NCOEF,
            PtmFormat::Lrgb => NCOEF,
        }
    }
}

/// One PTM image in memory, in the project's units: the polynomial evaluates to linear values where
/// 1.0 corresponds to byte 255 (the viewer's white). Rows top to bottom (row 0 = top of the image).
#[derive(Debug, Clone, PartialEq)]
pub struct PtmImage {
    /// Texels per row.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Which variant; decides the layout of `coeffs` and whether `rgb` is present.
    pub format: PtmFormat,
    /// Rgb: `[height][width][3 channels][6 coefficients]`; Lrgb: `[height][width][6]` (luminance)
    pub coeffs: Vec<f32>,
    /// Lrgb only: `[height][width][3]` base colour in [0, 1]; None for Rgb.
    pub rgb: Option<Vec<f32>>,
}

impl PtmImage {
    /// The colour a viewer shows at texel `(x, y)` (row `y` from the top) for the light direction
    /// `(lu, lv)`, in the project's units and before the viewer's clamping to [0, 1]:
    /// Rgb: the three channel polynomials; Lrgb: `rgb * L(lu, lv)`.
    ///
    /// Panics if `(x, y)` is outside the image or the buffers do not have the documented lengths.
    pub fn eval(&self, x: usize, y: usize, lu: f32, lv: f32) -> [f32; 3] {
        assert!(x < self.width && y < self.height, "texel ({x}, {y}) outside the image");
        let texel = y * self.width + x;
        let m = [lu * lu, lv * lv, lu * lv, lu, lv, 1.0];
        let poly = |a: &[f32]| a.iter().zip(m).map(|(a, m)| a * m).sum::<f32>();
        match self.format {
            PtmFormat::Rgb => {
                let base = texel * 3 * NCOEF;
                let c = &self.coeffs[base..base + 3 * NCOEF];
                [poly(&c[0..6]), poly(&c[6..12]), poly(&c[12..18])]
            }
            PtmFormat::Lrgb => {
                let l = poly(&self.coeffs[texel * NCOEF..(texel + 1) * NCOEF]);
                let rgb = self.rgb.as_ref().expect("an Lrgb PtmImage has rgb");
                [rgb[texel * 3] * l, rgb[texel * 3 + 1] * l, rgb[texel * 3 + 2] * l]
            }
        }
    }
}

/// The scale and bias chosen per coefficient index, so that a caller (and a test) knows the bound
/// of the 8-bit error: |a - decoded(a)| <= scale_k / 2 for every coefficient that was not clipped.
///
/// `scale` is in the project's units (the quantization step of `a_k`); the file header stores
/// `255 * scale[k]` because the file's coefficients are in byte units (see the module doc).
/// `bias` is the header's integer bias. With the writer's choice nothing is clipped by more
/// than half a step, so the bound holds for every coefficient.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PtmQuantization {
    /// Quantization step per coefficient index, in the project's units.
    pub scale: [f32; 6],
    /// Bias per coefficient index, as written in the header.
    pub bias: [i32; 6],
}

/// A PTM image as the file stores it: the header's scale (byte units) and bias per coefficient
/// index and the bytes, rows top to bottom (the reader and writer flip them). A PTM model
/// quantized by the fit ([`btfrs_fit::Ptm::quantize`]) is written this way byte for byte.
#[derive(Debug, Clone, PartialEq)]
pub struct PtmBytes {
    /// Texels per row.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Which variant.
    pub format: PtmFormat,
    /// The header's scale per coefficient index (byte units).
    pub scale: [f32; 6],
    /// The header's bias per coefficient index (an integer as written; any finite number read).
    pub bias: [f64; 6],
    /// Rgb: `[height][width][3][6]`; Lrgb: `[height][width][6]` bytes.
    pub coeffs: Vec<u8>,
    /// Lrgb only: `[height][width][3]` colour bytes.
    pub rgb: Option<Vec<u8>>,
}

impl PtmBytes {
    /// The decoded image: coefficient `(c - bias_k) * scale_k / 255`, colour `c / 255`.
    pub fn decode(&self, path_for_errors: &str) -> Result<PtmImage> {
        // Byte -> coefficient in our units, per coefficient index: (c - bias) * scale is in byte
        // units, / 255 makes 255 = 1.0.
        let lut: Vec<[f32; 256]> = (0..NCOEF)
            .map(|k| std::array::from_fn(|c| ((c as f64 - self.bias[k]) * f64::from(self.scale[k]) / 255.0) as f32))
            .collect();
        // A finite scale and bias can still decode beyond the f32 range (e.g. bias 1e300): that is
        // no PTM a writer produced, and the coefficients must not silently become infinite.
        if let Some(k) = lut.iter().position(|t| !(t[0].is_finite() && t[255].is_finite())) {
            return Err(Error::format(
                path_for_errors,
                format!(
                    "scale value {} ({}) and bias value {} ({}) decode to coefficients beyond the float range",
                    k + 1,
                    self.scale[k],
                    k + 1,
                    self.bias[k]
                ),
            ));
        }
        let coeffs = self.coeffs.iter().enumerate().map(|(i, &c)| lut[i % NCOEF][usize::from(c)]).collect();
        let rgb = self.rgb.as_ref().map(|r| r.iter().map(|&c| f32::from(c) / 255.0).collect());
        Ok(PtmImage { width: self.width, height: self.height, format: self.format, coeffs, rgb })
    }
}

impl PtmBytes {
    /// The file of a quantized single-view PTM ([`btfrs_fit::Ptm::slot`] of a model fitted with
    /// `bits` 8), byte for byte: `None` when the slot is not quantized or its planes are not of
    /// the file's form (channels sharing scale and an integer bias per coefficient, colours
    /// `c / 255`), e.g. planes made by another tool.
    pub fn from_slot(slot: &PtmSlot) -> Option<PtmBytes> {
        let p = slot.planes.as_ref()?;
        let format = match slot.kind {
            PtmKind::Rgb => PtmFormat::Rgb,
            PtmKind::Lrgb => PtmFormat::Lrgb,
        };
        let pc = format.coeffs_per_texel();
        if p.coeffs.k != pc || p.coeffs.texels != slot.width * slot.height {
            return None;
        }
        let mut scale = [0f32; NCOEF];
        let mut bias = [0f64; NCOEF];
        for k in 0..NCOEF {
            let (s, b) = (p.coeffs.scale[k], p.coeffs.bias[k]);
            if s <= 0.0
                || !s.is_finite()
                || (k..pc).step_by(NCOEF).any(|i| p.coeffs.scale[i] != s || p.coeffs.bias[i] != b)
            {
                return None;
            }
            scale[k] = (f64::from(s) * 255.0) as f32;
            let bb = -f64::from(b) / f64::from(s);
            if (bb - bb.round()).abs() > 1e-3 || bb.abs() > i32::MAX as f64 {
                return None;
            }
            bias[k] = bb.round();
        }
        let rgb = match (&p.rgb, format) {
            (None, PtmFormat::Rgb) => None,
            (Some(r), PtmFormat::Lrgb) => {
                let unit = (1.0f64 / 255.0) as f32;
                if r.k != 3 || r.scale.iter().any(|&s| s != unit) || r.bias.iter().any(|&b| b != 0.0) {
                    return None;
                }
                Some(r.q.clone())
            }
            _ => return None,
        };
        Some(PtmBytes { width: slot.width, height: slot.height, format, scale, bias, coeffs: p.coeffs.q.clone(), rgb })
    }

    /// The single-view PTM of this file as 8-bit planes: plane scale `scale_k / 255`, bias
    /// `-bias_k scale_k / 255`, colours `c / 255` ([`btfrs_fit::Ptm::from_slot`] makes it a model).
    pub fn to_slot(&self) -> PtmSlot {
        let texels = self.width * self.height;
        let pc = self.format.coeffs_per_texel();
        let coeffs = Planes {
            texels,
            k: pc,
            q: self.coeffs.clone(),
            scale: (0..pc).map(|p| (f64::from(self.scale[p % NCOEF]) / 255.0) as f32).collect(),
            bias: (0..pc).map(|p| (-self.bias[p % NCOEF] * f64::from(self.scale[p % NCOEF]) / 255.0) as f32).collect(),
        };
        let rgb = self.rgb.as_ref().map(|r| Planes {
            texels,
            k: 3,
            q: r.clone(),
            scale: vec![(1.0f64 / 255.0) as f32; 3],
            bias: vec![0.0; 3],
        });
        let kind = match self.format {
            PtmFormat::Rgb => PtmKind::Rgb,
            PtmFormat::Lrgb => PtmKind::Lrgb,
        };
        PtmSlot {
            kind,
            height: self.height,
            width: self.width,
            coeffs: coeffs.dequantize(),
            rgb: rgb.as_ref().map(|r| r.dequantize()),
            planes: Some(PtmPlanes { coeffs, rgb }),
        }
    }
}

/// Encode already quantized bytes as an uncompressed `PTM_1.2` file (the bias must be integers).
pub fn encode_ptm_bytes(b: &PtmBytes) -> Result<Vec<u8>> {
    if b.width == 0 || b.height == 0 {
        return Err(Error::arg("width", format!("the image is {} x {} texels", b.width, b.height)));
    }
    let texels = b.width.checked_mul(b.height).ok_or_else(|| Error::arg("width", "too many texels"))?;
    if b.coeffs.len() != texels * b.format.coeffs_per_texel() {
        return Err(Error::arg(
            "coeffs",
            format!("expected {} bytes, got {}", texels * b.format.coeffs_per_texel(), b.coeffs.len()),
        ));
    }
    match (b.format, &b.rgb) {
        (PtmFormat::Rgb, None) => {}
        (PtmFormat::Lrgb, Some(r)) if r.len() == texels * 3 => {}
        _ => return Err(Error::arg("rgb", "expected 3 colour bytes per texel for LRGB and none for RGB")),
    }
    if let Some(k) = (0..NCOEF).find(|&k| !(b.scale[k].is_finite() && b.scale[k] > 0.0)) {
        return Err(Error::arg("scale", format!("value {k} is {}, not a positive finite number", b.scale[k])));
    }
    if let Some(k) = (0..NCOEF).find(|&k| b.bias[k].fract() != 0.0 || b.bias[k].abs() > i32::MAX as f64) {
        return Err(Error::arg("bias", format!("value {k} is {}, not an integer", b.bias[k])));
    }
    let (w, h) = (b.width, b.height);
    let mut header = String::new();
    header.push_str("PTM_1.2\n");
    header.push_str(b.format.header_name());
    header.push('\n');
    header.push_str(&format!("{w}\n{h}\n"));
    let scales: Vec<String> = b.scale.iter().map(|&s| format_scale(s)).collect();
    header.push_str(&scales.join(" "));
    header.push('\n');
    let biases: Vec<String> = b.bias.iter().map(|&x| (x as i64).to_string()).collect();
    header.push_str(&biases.join(" "));
    header.push('\n');
    let data_len = texels * if b.format == PtmFormat::Rgb { 3 * NCOEF } else { NCOEF + 3 };
    let mut out = Vec::with_capacity(header.len() + data_len);
    out.extend_from_slice(header.as_bytes());
    match b.format {
        PtmFormat::Rgb => {
            for ch in 0..3 {
                for file_row in 0..h {
                    let y = h - 1 - file_row; // the file starts with the bottom row
                    for x in 0..w {
                        let base = ((y * w + x) * 3 + ch) * NCOEF;
                        out.extend_from_slice(&b.coeffs[base..base + NCOEF]);
                    }
                }
            }
        }
        PtmFormat::Lrgb => {
            let rgb = b.rgb.as_ref().expect("checked");
            for file_row in 0..h {
                let y = h - 1 - file_row;
                out.extend_from_slice(&b.coeffs[y * w * NCOEF..(y + 1) * w * NCOEF]);
            }
            for file_row in 0..h {
                let y = h - 1 - file_row;
                out.extend_from_slice(&rgb[y * w * 3..(y + 1) * w * 3]);
            }
        }
    }
    debug_assert_eq!(out.len(), header.len() + data_len);
    Ok(out)
}

/// Write already quantized bytes to `path` as a `PTM_1.2` file, atomically.
pub fn write_ptm_bytes(path: &Path, b: &PtmBytes) -> Result<()> {
    let bytes = encode_ptm_bytes(b)?;
    crate::atomic::write_atomic(path, |w| w.write_all(&bytes))
}

/// Read a `.ptm` file as the file stores it (see [`read_ptm`] for what is accepted).
pub fn read_ptm_bytes(path: &Path) -> Result<PtmBytes> {
    let shown = path.display().to_string();
    let bytes = crate::untrusted::read_bytes(path, crate::capture::default_max_bytes(), "a PTM file within max_bytes")?;
    decode_ptm_bytes(&bytes, &shown)
}

/// Write `img` to `path` as an uncompressed `PTM_1.2` file.
///
/// The bytes go to a temporary file in the same directory, which is then renamed over `path`, so
/// a failure never leaves a half-written target; the temporary file is removed on error.
pub fn write_ptm(path: &Path, img: &PtmImage) -> Result<PtmQuantization> {
    let (bytes, quant) = encode_ptm(img)?;
    crate::atomic::write_atomic(path, |w| w.write_all(&bytes))?;
    Ok(quant)
}

/// Read a `.ptm` file (uncompressed `PTM_FORMAT_RGB` or `PTM_FORMAT_LRGB`, version 1.2 or 1.1).
///
/// A missing or unreadable file gives [`Error::Io`] (whose `source.kind()` tells `NotFound`
/// apart); a file that is not a supported PTM gives [`Error::Format`].
pub fn read_ptm(path: &Path) -> Result<PtmImage> {
    let shown = path.display().to_string();
    let bytes = crate::untrusted::read_bytes(path, crate::capture::default_max_bytes(), "a PTM file within max_bytes")?;
    decode_ptm(&bytes, &shown)
}

/// Encode `img` as the bytes of an uncompressed `PTM_1.2` file, and report the scale and bias
/// chosen per coefficient index.
pub fn encode_ptm(img: &PtmImage) -> Result<(Vec<u8>, PtmQuantization)> {
    let texels = validate(img)?;
    let (w, h) = (img.width, img.height);

    // Per coefficient index k: min and max over all texels and channels, in byte units.
    let mut lo = [f64::INFINITY; NCOEF];
    let mut hi = [f64::NEG_INFINITY; NCOEF];
    for poly in img.coeffs.chunks_exact(NCOEF) {
        for k in 0..NCOEF {
            let v = 255.0 * f64::from(poly[k]);
            lo[k] = lo[k].min(v);
            hi[k] = hi[k].max(v);
        }
    }
    let mut file_scale = [0f32; NCOEF];
    let mut bias = [0i32; NCOEF];
    for k in 0..NCOEF {
        let (s, b) = choose_scale_bias(lo[k], hi[k]).ok_or_else(|| {
            Error::arg(
                "coeffs",
                format!("coefficient a{k} spans [{}, {}], too wide to store", lo[k] / 255.0, hi[k] / 255.0),
            )
        })?;
        file_scale[k] = s;
        bias[k] = b;
    }
    let quant = PtmQuantization { scale: file_scale.map(|s| (f64::from(s) / 255.0) as f32), bias };

    let mut header = String::new();
    header.push_str("PTM_1.2\n");
    header.push_str(img.format.header_name());
    header.push('\n');
    header.push_str(&format!("{w}\n{h}\n"));
    let scales: Vec<String> = file_scale.iter().map(|&s| format_scale(s)).collect();
    header.push_str(&scales.join(" "));
    header.push('\n');
    let biases: Vec<String> = bias.iter().map(i32::to_string).collect();
    header.push_str(&biases.join(" "));
    header.push('\n');

    // Step 255 / scale per byte unit of our coefficient (our a is 1/255 of the file's A).
    let mul: [f64; NCOEF] = std::array::from_fn(|k| 255.0 / f64::from(file_scale[k]));
    let quantize = |k: usize, a: f32| -> u8 {
        let code = (f64::from(a) * mul[k] + f64::from(bias[k])).round();
        code.clamp(0.0, 255.0) as u8
    };

    let data_len = texels * if img.format == PtmFormat::Rgb { 3 * NCOEF } else { NCOEF + 3 };
    let mut out = Vec::with_capacity(header.len() + data_len);
    out.extend_from_slice(header.as_bytes());
    match img.format {
        PtmFormat::Rgb => {
            for ch in 0..3 {
                for file_row in 0..h {
                    let y = h - 1 - file_row; // the file starts with the bottom row
                    for x in 0..w {
                        let base = ((y * w + x) * 3 + ch) * NCOEF;
                        for k in 0..NCOEF {
                            out.push(quantize(k, img.coeffs[base + k]));
                        }
                    }
                }
            }
        }
        PtmFormat::Lrgb => {
            let rgb = img.rgb.as_ref().expect("validated");
            for file_row in 0..h {
                let y = h - 1 - file_row;
                for x in 0..w {
                    let base = (y * w + x) * NCOEF;
                    for k in 0..NCOEF {
                        out.push(quantize(k, img.coeffs[base + k]));
                    }
                }
            }
            for file_row in 0..h {
                let y = h - 1 - file_row;
                for x in 0..w {
                    let base = (y * w + x) * 3;
                    for c in 0..3 {
                        // Validated to lie in [0, 1].
                        out.push((f64::from(rgb[base + c]) * 255.0).round() as u8);
                    }
                }
            }
        }
    }
    debug_assert_eq!(out.len(), header.len() + data_len);
    Ok((out, quant))
}

/// Check the shape and values of `img`; return the number of texels.
fn validate(img: &PtmImage) -> Result<usize> {
    if img.width == 0 {
        return Err(Error::arg("width", "must be positive, got 0"));
    }
    if img.height == 0 {
        return Err(Error::arg("height", "must be positive, got 0"));
    }
    let too_big = || Error::arg("width", format!("{} x {} texels is too large", img.width, img.height));
    let texels = img.width.checked_mul(img.height).ok_or_else(too_big)?;
    // The largest buffer we will build: 18 bytes per texel plus the header.
    texels.checked_mul(3 * NCOEF + 1).ok_or_else(too_big)?;
    let per = img.format.coeffs_per_texel();
    let want = texels * per;
    if img.coeffs.len() != want {
        return Err(Error::arg(
            "coeffs",
            format!(
                "expected {want} values ({} x {} texels x {per} for {:?}), got {}",
                img.height,
                img.width,
                img.format,
                img.coeffs.len()
            ),
        ));
    }
    if let Some(i) = img.coeffs.iter().position(|v| !v.is_finite()) {
        return Err(Error::arg("coeffs", format!("value {i} is {}, not finite", img.coeffs[i])));
    }
    match (img.format, &img.rgb) {
        (PtmFormat::Rgb, Some(_)) => {
            return Err(Error::arg("rgb", "must be None for PtmFormat::Rgb (the colour is in the coefficients)"));
        }
        (PtmFormat::Rgb, None) => {}
        (PtmFormat::Lrgb, None) => {
            return Err(Error::arg("rgb", "is required for PtmFormat::Lrgb"));
        }
        (PtmFormat::Lrgb, Some(rgb)) => {
            if rgb.len() != texels * 3 {
                return Err(Error::arg(
                    "rgb",
                    format!(
                        "expected {} values ({} x {} texels x 3), got {}",
                        texels * 3,
                        img.height,
                        img.width,
                        rgb.len()
                    ),
                ));
            }
            if let Some(i) = rgb.iter().position(|v| !(0.0..=1.0).contains(v)) {
                return Err(Error::arg("rgb", format!("value {i} is {}, outside [0, 1]", rgb[i])));
            }
        }
    }
    Ok(texels)
}

/// Scale (in byte units, as written in the header) and bias for a coefficient whose values (in
/// byte units) lie in `[lo, hi]`: [`btfrs_fit::ptm::file_scale_bias`], shared with the PTM's own
/// 8-bit planes so that a fitted model is written byte for byte.
fn choose_scale_bias(lo: f64, hi: f64) -> Option<(f32, i32)> {
    btfrs_fit::ptm::file_scale_bias(lo, hi)
}

/// The shortest decimal that reads back as exactly `s` (Rust's `Display` for f32, never an
/// exponent), unless that is long (very small or large values): then the exponent form, which
/// `strtod` and `QString::toDouble` read too. Keeps the scale line well under relight's 256-byte
/// line buffer.
fn format_scale(s: f32) -> String {
    let plain = s.to_string();
    if plain.len() <= 24 {
        plain
    } else {
        format!("{s:e}")
    }
}

/// Decode the bytes of a `.ptm` file. `path_for_errors` names the file in [`Error::Format`].
pub fn decode_ptm(bytes: &[u8], path_for_errors: &str) -> Result<PtmImage> {
    decode_ptm_bytes(bytes, path_for_errors)?.decode(path_for_errors)
}

/// Decode the header and the bytes of a `.ptm` file without dequantizing.
pub fn decode_ptm_bytes(bytes: &[u8], path_for_errors: &str) -> Result<PtmBytes> {
    let mut hdr = Header { bytes, pos: 0, path: path_for_errors };

    let version = hdr.token("version string")?;
    let interleaved_lrgb = match version {
        b"PTM_1.2" => false,
        b"PTM_1.1" => true,
        v if v.starts_with(b"PTM_") => {
            return Err(hdr.err(format!("unsupported PTM version {} (this reader knows PTM_1.1 and PTM_1.2)", show(v))));
        }
        v => {
            return Err(hdr.err(format!("not a PTM file: it starts with {}, not PTM_1.2", show(v))));
        }
    };

    let (format, jpeg) = match hdr.token("format string")? {
        b"PTM_FORMAT_RGB" => (PtmFormat::Rgb, false),
        b"PTM_FORMAT_LRGB" => (PtmFormat::Lrgb, false),
        b"PTM_FORMAT_JPEG_RGB" => (PtmFormat::Rgb, true),
        b"PTM_FORMAT_JPEG_LRGB" => (PtmFormat::Lrgb, true),
        f @ (b"PTM_FORMAT_LUM"
        | b"PTM_FORMAT_PTM_LUT"
        | b"PTM_FORMAT_PTM_C_LUT"
        | b"PTM_FORMAT_JPEGLS_RGB"
        | b"PTM_FORMAT_JPEGLS_LRGB") => {
            return Err(hdr.err(format!(
                "PTM format {} is not supported (RGB and LRGB, uncompressed or JPEG, are read)",
                show(f)
            )));
        }
        f => return Err(hdr.err(format!("unknown PTM format {}", show(f)))),
    };

    let width = hdr.size("width")?;
    let height = hdr.size("height")?;
    let mut scale = [0f32; NCOEF];
    for (k, s) in scale.iter_mut().enumerate() {
        let what = format!("scale value {} of 6", k + 1);
        let t = hdr.token(&what)?;
        *s = std::str::from_utf8(t)
            .ok()
            .and_then(|t| t.parse::<f32>().ok())
            .filter(|v| v.is_finite())
            .ok_or_else(|| hdr.err(format!("{what} is not a finite number: {}", show(t))))?;
    }
    let mut bias = [0f64; NCOEF];
    for (k, b) in bias.iter_mut().enumerate() {
        let what = format!("bias value {} of 6", k + 1);
        let t = hdr.token(&what)?;
        *b = std::str::from_utf8(t)
            .ok()
            .and_then(|t| t.parse::<f64>().ok())
            .filter(|v| v.is_finite())
            .ok_or_else(|| hdr.err(format!("{what} is not a number: {}", show(t))))?;
    }
    if jpeg {
        width
            .checked_mul(height)
            .and_then(|t| t.checked_mul(3 * NCOEF))
            .ok_or_else(|| hdr.err(format!("{width} x {height} texels is too large")))?;
        let planes = jpeg_planes(&mut hdr, format, width, height)?;
        let probe =
            PtmBytes { width: 1, height: 1, format: PtmFormat::Rgb, scale, bias, coeffs: vec![0; 18], rgb: None };
        probe.decode(path_for_errors)?;
        return Ok(from_planes(format, width, height, scale, bias, &planes));
    }
    hdr.end_of_header()?;

    let too_big = || hdr.err(format!("{width} x {height} texels is too large"));
    let texels = width.checked_mul(height).ok_or_else(too_big)?;
    let per_texel = match format {
        PtmFormat::Rgb => 3 * NCOEF,
        PtmFormat::Lrgb => NCOEF + 3,
    };
    let need = texels.checked_mul(per_texel).ok_or_else(too_big)?;
    let data = &bytes[hdr.pos..];
    if data.len() < need {
        return Err(hdr.err(format!(
            "truncated: a {width} x {height} {} needs {need} bytes of data after the header, the file has {}",
            format.header_name(),
            data.len()
        )));
    }

    // Fail early on a scale and bias that decode beyond the f32 range.
    let probe = PtmBytes { width: 1, height: 1, format: PtmFormat::Rgb, scale, bias, coeffs: vec![0; 18], rgb: None };
    probe.decode(path_for_errors)?;

    let (w, h) = (width, height);
    let mut coeffs = vec![0u8; texels * format.coeffs_per_texel()];
    let rgb = match format {
        PtmFormat::Rgb => {
            let block_len = texels * NCOEF;
            for ch in 0..3 {
                let block = &data[ch * block_len..(ch + 1) * block_len];
                for file_row in 0..h {
                    let y = h - 1 - file_row; // the file starts with the bottom row
                    for x in 0..w {
                        let src = (file_row * w + x) * NCOEF;
                        let dst = ((y * w + x) * 3 + ch) * NCOEF;
                        coeffs[dst..dst + NCOEF].copy_from_slice(&block[src..src + NCOEF]);
                    }
                }
            }
            None
        }
        PtmFormat::Lrgb => {
            let mut rgb = vec![0u8; texels * 3];
            // PTM_1.2: coefficient block then colour block; PTM_1.1: 9 bytes per texel.
            for file_row in 0..h {
                let y = h - 1 - file_row;
                for x in 0..w {
                    let t = file_row * w + x; // texel index in file order
                    let (src, c_src) = if interleaved_lrgb {
                        (t * (NCOEF + 3), t * (NCOEF + 3) + NCOEF)
                    } else {
                        (t * NCOEF, texels * NCOEF + t * 3)
                    };
                    let dst = (y * w + x) * NCOEF;
                    coeffs[dst..dst + NCOEF].copy_from_slice(&data[src..src + NCOEF]);
                    let c_dst = (y * w + x) * 3;
                    rgb[c_dst..c_dst + 3].copy_from_slice(&data[c_src..c_src + 3]);
                }
            }
            Some(rgb)
        }
    };
    Ok(PtmBytes { width, height, format, scale, bias, coeffs, rgb })
}

/// The planes of a JPEG-compressed PTM (the PTM 1.2 format's `PTM_FORMAT_JPEG_RGB` and
/// `_LRGB`, as relight writes and reads them): after the biases, the quality and seven lists of
/// one integer per plane (transform, motion x, motion y, decoding order, reference plane,
/// compressed size, side-information size), then per plane a greyscale JPEG and its side
/// information (5-byte corrections: a big-endian texel index and the byte it holds). A plane
/// with a reference plane `r` stores `value - reference + 128`. Transforms and motion vectors
/// other than 0 are refused, as relight refuses them. Planes are in file order (rows bottom
/// first); for RGB, plane `3 j + c` is coefficient `j` of channel `c`; for LRGB, planes 0-5
/// are the coefficients and 6-8 the colour.
fn jpeg_planes(hdr: &mut Header<'_>, format: PtmFormat, width: usize, height: usize) -> Result<Vec<Vec<u8>>> {
    let n = match format {
        PtmFormat::Rgb => 3 * NCOEF,
        PtmFormat::Lrgb => NCOEF + 3,
    };
    let int = |hdr: &mut Header<'_>, what: &str| -> Result<i64> {
        let t = hdr.token(what)?;
        std::str::from_utf8(t)
            .ok()
            .and_then(|t| t.parse::<i64>().ok())
            .ok_or_else(|| hdr.err(format!("the {what} is not an integer: {}", show(t))))
    };
    int(hdr, "JPEG quality")?;
    let mut lists: Vec<Vec<i64>> = Vec::new();
    for what in [
        "transform",
        "motion vector x",
        "motion vector y",
        "order",
        "reference plane",
        "compressed size",
        "side information size",
    ] {
        let list = (0..n).map(|k| int(hdr, &format!("{what} of plane {k}"))).collect::<Result<Vec<_>>>()?;
        lists.push(list);
    }
    hdr.end_of_header()?;
    let (order, reference, sizes, side) = (&lists[3], &lists[4], &lists[5], &lists[6]);
    for k in 0..n {
        if lists[0][k] != 0 || lists[1][k] != 0 || lists[2][k] != 0 {
            return Err(
                hdr.err(format!("plane {k}: JPEG PTM transforms and motion vectors are not supported (only 0)"))
            );
        }
        if sizes[k] <= 0 || side[k] < 0 || side[k] % 5 != 0 {
            return Err(hdr.err(format!(
                "plane {k}: compressed size {} and side information size {} (expected a positive size and a multiple of 5)",
                sizes[k], side[k]
            )));
        }
    }
    // order[k] is the step at which plane k is decoded: a permutation of 0..n.
    let mut sequence = vec![usize::MAX; n];
    for (k, &o) in order.iter().enumerate() {
        if o < 0 || o as usize >= n || sequence[o as usize] != usize::MAX {
            return Err(hdr.err(format!("the decoding order {order:?} is not a permutation of 0..{n}")));
        }
        sequence[o as usize] = k;
    }
    let mut start = vec![hdr.pos; n + 1];
    for k in 0..n {
        start[k + 1] = start[k] + sizes[k] as usize + side[k] as usize;
    }
    if start[n] > hdr.bytes.len() {
        return Err(hdr.err(format!(
            "truncated: the planes need {} bytes after the header, the file has {}",
            start[n] - hdr.pos,
            hdr.bytes.len() - hdr.pos
        )));
    }
    let texels = width * height;
    let mut planes: Vec<Option<Vec<u8>>> = vec![None; n];
    for &k in &sequence {
        let jpeg = &hdr.bytes[start[k]..start[k] + sizes[k] as usize];
        let mut reader = ::image::ImageReader::with_format(std::io::Cursor::new(jpeg), ::image::ImageFormat::Jpeg);
        let mut limits = ::image::Limits::default();
        limits.max_image_width = Some(width as u32);
        limits.max_image_height = Some(height as u32);
        reader.limits(limits);
        let img = reader.decode().map_err(|e| hdr.err(format!("plane {k}: {e}")))?.to_luma8();
        if (img.width() as usize, img.height() as usize) != (width, height) {
            return Err(hdr.err(format!(
                "plane {k}: the JPEG is {} x {}, the header says {width} x {height}",
                img.width(),
                img.height()
            )));
        }
        let mut plane = img.into_raw();
        let r = reference[k];
        if r != -1 {
            let base =
                usize::try_from(r).ok().and_then(|r| planes.get(r)).and_then(|p| p.as_ref()).ok_or_else(|| {
                    hdr.err(format!("plane {k}: reference plane {r} is not a plane decoded before it"))
                })?;
            for (v, &b) in plane.iter_mut().zip(base) {
                *v = (i32::from(*v) - 128 + i32::from(b)).clamp(0, 255) as u8;
            }
        }
        let corrections = &hdr.bytes[start[k] + sizes[k] as usize..start[k + 1]];
        for c in corrections.chunks_exact(5) {
            let at = u32::from_be_bytes([c[0], c[1], c[2], c[3]]) as usize;
            if at >= texels {
                return Err(hdr.err(format!("plane {k}: a correction at texel {at} of {texels}")));
            }
            plane[at] = c[4];
        }
        planes[k] = Some(plane);
    }
    Ok(planes.into_iter().map(|p| p.expect("every plane decoded")).collect())
}

/// The bytes of a PTM from its planes in file order (see [`jpeg_planes`]).
fn from_planes(format: PtmFormat, w: usize, h: usize, scale: [f32; 6], bias: [f64; 6], planes: &[Vec<u8>]) -> PtmBytes {
    let texels = w * h;
    let mut coeffs = vec![0u8; texels * format.coeffs_per_texel()];
    let mut rgb = (format == PtmFormat::Lrgb).then(|| vec![0u8; texels * 3]);
    for file_row in 0..h {
        let y = h - 1 - file_row; // the planes start with the bottom row
        for x in 0..w {
            let (src, t) = (file_row * w + x, y * w + x);
            match format {
                PtmFormat::Rgb => {
                    for (p, plane) in planes.iter().enumerate() {
                        let (j, c) = (p / 3, p % 3);
                        coeffs[(t * 3 + c) * NCOEF + j] = plane[src];
                    }
                }
                PtmFormat::Lrgb => {
                    for j in 0..NCOEF {
                        coeffs[t * NCOEF + j] = planes[j][src];
                    }
                    if let Some(rgb) = rgb.as_mut() {
                        for c in 0..3 {
                            rgb[t * 3 + c] = planes[NCOEF + c][src];
                        }
                    }
                }
            }
        }
    }
    PtmBytes { width: w, height: h, format, scale, bias, coeffs, rgb }
}

/// A cursor over the text header.
struct Header<'a> {
    bytes: &'a [u8],
    pos: usize,
    path: &'a str,
}

impl<'a> Header<'a> {
    fn err(&self, msg: impl std::fmt::Display) -> Error {
        Error::format(self.path, msg)
    }

    /// The next whitespace-separated token.
    fn token(&mut self, what: &str) -> Result<&'a [u8]> {
        while self.pos < self.bytes.len() && self.bytes[self.pos].is_ascii_whitespace() {
            self.pos += 1;
        }
        if self.pos == self.bytes.len() {
            return Err(self.err(format!("truncated: the file ends in the header, before the {what}")));
        }
        let start = self.pos;
        while self.pos < self.bytes.len() && !self.bytes[self.pos].is_ascii_whitespace() {
            self.pos += 1;
            if self.pos - start > MAX_TOKEN {
                return Err(self.err(format!(
                    "the {what} is not a header field (starts with {}...)",
                    show(&self.bytes[start..start + 16])
                )));
            }
        }
        Ok(&self.bytes[start..self.pos])
    }

    /// A positive integer (width or height).
    fn size(&mut self, what: &str) -> Result<usize> {
        let t = self.token(what)?;
        let v = std::str::from_utf8(t)
            .ok()
            .and_then(|t| t.parse::<usize>().ok())
            .ok_or_else(|| self.err(format!("the {what} is not a non-negative integer: {}", show(t))))?;
        if v == 0 {
            return Err(self.err(format!("the {what} is 0")));
        }
        Ok(v)
    }

    /// After the last bias value: optional spaces, tabs or `\r`, then exactly one `\n`. Binary
    /// data follow, so nothing beyond that newline may be skipped.
    fn end_of_header(&mut self) -> Result<()> {
        while self.pos < self.bytes.len() && matches!(self.bytes[self.pos], b' ' | b'\t' | b'\r') {
            self.pos += 1;
        }
        match self.bytes.get(self.pos) {
            Some(b'\n') => {
                self.pos += 1;
                Ok(())
            }
            None => Err(self.err("truncated: the file ends after the header, with no data")),
            Some(_) => {
                Err(self
                    .err("expected the end of the line after the six bias values (a newline before the binary data)"))
            }
        }
    }
}

/// A header token for an error message: quoted, lossy UTF-8, shortened.
fn show(t: &[u8]) -> String {
    let s = String::from_utf8_lossy(&t[..t.len().min(40)]);
    format!("{:?}{}", s, if t.len() > 40 { "..." } else { "" })
}

/// The `.ptm` format (HP Labs' PTM 1.2, read by RTIViewer, relight and OpenLIME's converters).
pub const FORMAT: crate::formats::Format = crate::formats::Format {
    name: "ptm",
    extension: "ptm",
    doc: "Polynomial Texture Map 1.2 (RGB or LRGB, 8-bit), one view slot",
    folder: false,
    index: "",
    export: export_model,
    import: import_model,
    tiles: None,
};

/// Write one view slot of a PTM as a `.ptm` file: `{"scale": [..], "bias": [..]}` per
/// coefficient index (scale in our units, the quantization step). A model quantized by the fit
/// (`bits` 8) is written byte for byte from its planes; a float model is quantized for the file.
fn export_model(model: &dyn btfrs_fit::DynModel, view: usize, path: &Path) -> Result<serde_json::Value> {
    let p: &btfrs_fit::Ptm = crate::formats::concrete(model, "a PTM")?;
    let slot = p.slot(view)?;
    if let Some(b) = PtmBytes::from_slot(&slot) {
        write_ptm_bytes(path, &b)?;
        let scale: Vec<f32> = b.scale.iter().map(|&s| (f64::from(s) / 255.0) as f32).collect();
        let bias: Vec<i32> = b.bias.iter().map(|&x| x as i32).collect();
        return Ok(serde_json::json!({"scale": scale, "bias": bias}));
    }
    let format = match slot.kind {
        PtmKind::Rgb => PtmFormat::Rgb,
        PtmKind::Lrgb => PtmFormat::Lrgb,
    };
    let img = PtmImage { width: slot.width, height: slot.height, format, coeffs: slot.coeffs, rgb: slot.rgb };
    let q = write_ptm(path, &img)?;
    Ok(serde_json::json!({"scale": q.scale.to_vec(), "bias": q.bias.to_vec()}))
}

/// Read a `.ptm` file as a one-slot PTM (view = the normal), its 8-bit planes the file's bytes.
fn import_model(path: &Path, limits: &crate::capture::Limits) -> Result<crate::formats::Imported> {
    let shown = path.display().to_string();
    let bytes = crate::untrusted::read_model_file(path, limits.max_bytes, "a PTM file")?;
    let b = decode_ptm_bytes(&bytes, &shown)?;
    drop(bytes);
    let m = btfrs_fit::Ptm::from_slot(b.to_slot()).map_err(crate::untrusted::as_format(&shown, "coefficients"))?;
    Ok(crate::formats::Imported::model(Box::new(m)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::fs;

    /// A small deterministic generator (xorshift64*), so the tests need no extra crate.
    struct Rng(u64);
    impl Rng {
        fn next_f32(&mut self) -> f32 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            let v = self.0.wrapping_mul(0x2545_F491_4F6C_DD1D);
            (v >> 40) as f32 / (1u64 << 24) as f32
        }
        fn uniform(&mut self, lo: f32, hi: f32) -> f32 {
            lo + (hi - lo) * self.next_f32()
        }
    }

    /// Typical ranges per coefficient index: quadratic terms negative-ish, a5 positive.
    const RANGES: [(f32, f32); 6] = [(-0.8, 0.1), (-0.6, 0.3), (-0.2, 0.25), (-0.5, 0.9), (-0.9, 0.4), (0.05, 1.3)];

    fn random_image(format: PtmFormat, w: usize, h: usize, seed: u64) -> PtmImage {
        let mut rng = Rng(seed);
        let n = w * h * format.coeffs_per_texel();
        let coeffs = (0..n)
            .map(|i| {
                let (lo, hi) = RANGES[i % 6];
                rng.uniform(lo, hi)
            })
            .collect();
        let rgb = (format == PtmFormat::Lrgb).then(|| (0..w * h * 3).map(|_| rng.next_f32()).collect());
        PtmImage { width: w, height: h, format, coeffs, rgb }
    }

    /// The header's six lines and the offset of the binary data.
    fn split_header(bytes: &[u8]) -> (Vec<String>, usize) {
        let mut lines = Vec::new();
        let mut start = 0;
        for (i, &b) in bytes.iter().enumerate() {
            if b == b'\n' {
                lines.push(String::from_utf8(bytes[start..i].to_vec()).unwrap());
                start = i + 1;
                if lines.len() == 6 {
                    return (lines, start);
                }
            }
        }
        panic!("fewer than six header lines");
    }

    fn assert_roundtrip(img: &PtmImage) {
        let (bytes, q) = encode_ptm(img).unwrap();
        let back = decode_ptm(&bytes, "mem.ptm").unwrap();
        assert_eq!((back.width, back.height, back.format), (img.width, img.height, img.format));
        assert_eq!(back.coeffs.len(), img.coeffs.len());
        for (i, (&a, &d)) in img.coeffs.iter().zip(&back.coeffs).enumerate() {
            let k = i % 6;
            let bound = q.scale[k] / 2.0 + 1e-6 * a.abs().max(1.0);
            assert!((a - d).abs() <= bound, "coefficient {i} (a{k}): {a} -> {d}, bound {bound}");
        }
        match (&img.rgb, &back.rgb) {
            (None, None) => {}
            (Some(a), Some(b)) => {
                for (i, (&x, &y)) in a.iter().zip(b).enumerate() {
                    assert!((x - y).abs() <= 0.5 / 255.0 + 1e-6, "rgb {i}: {x} -> {y}");
                }
            }
            _ => panic!("rgb presence changed"),
        }
    }

    #[test]
    fn roundtrip_rgb_random() {
        assert_roundtrip(&random_image(PtmFormat::Rgb, 7, 5, 1));
    }

    #[test]
    fn roundtrip_lrgb_random() {
        assert_roundtrip(&random_image(PtmFormat::Lrgb, 9, 4, 2));
    }

    #[test]
    fn quantization_uses_the_full_byte_range() {
        // scale = (max - min) / 255 and every index reaches (within one code) both 0 and 255.
        for format in [PtmFormat::Rgb, PtmFormat::Lrgb] {
            let img = random_image(format, 16, 16, 3);
            let (bytes, q) = encode_ptm(&img).unwrap();
            let (_, data_at) = split_header(&bytes);
            let nblocks = if format == PtmFormat::Rgb { 3 } else { 1 };
            let coef_bytes = &bytes[data_at..data_at + 16 * 16 * 6 * nblocks];
            for k in 0..6 {
                let vals = img.coeffs.iter().skip(k).step_by(6);
                let lo = vals.clone().fold(f32::INFINITY, |m, &v| m.min(v));
                let hi = vals.fold(f32::NEG_INFINITY, |m, &v| m.max(v));
                let ideal = (hi - lo) / 255.0;
                assert!((q.scale[k] - ideal).abs() <= 1e-6 * ideal, "a{k}: scale {} vs {ideal}", q.scale[k]);
                let codes = coef_bytes.iter().skip(k).step_by(6);
                let cmin = *codes.clone().min().unwrap();
                let cmax = *codes.max().unwrap();
                assert!(cmin <= 1 && cmax >= 254, "a{k}: codes {cmin}..{cmax}");
            }
        }
    }

    #[test]
    fn constant_and_narrow_coefficients() {
        // a0 all zero, a1 constant positive, a2 constant negative, a3 a narrow range far from 0,
        // a4 tiny values, a5 ordinary.
        let (w, h) = (4, 3);
        let mut coeffs = Vec::new();
        for i in 0..w * h {
            let t = i as f32 / (w * h) as f32;
            coeffs.extend_from_slice(&[0.0, 0.7, -0.3, 1000.0 + 0.001 * t, 1e-30 * t, t]);
        }
        let img = PtmImage { width: w, height: h, format: PtmFormat::Lrgb, coeffs, rgb: Some(vec![0.5; w * h * 3]) };
        let (bytes, q) = encode_ptm(&img).unwrap();
        for k in 0..6 {
            assert!(q.scale[k] > 0.0 && q.scale[k].is_finite(), "a{k}: scale {}", q.scale[k]);
            assert!(q.bias[k].abs() <= 32767, "a{k}: bias {}", q.bias[k]);
        }
        // The header stays short and parseable by line-based readers.
        let (lines, _) = split_header(&bytes);
        assert!(lines[4].len() < 200, "scale line {:?}", lines[4]);
        assert_roundtrip(&img);
        let back = decode_ptm(&bytes, "mem").unwrap();
        assert!(back.coeffs.iter().step_by(6).all(|&v| v == 0.0), "all-zero a0 decodes exactly");
    }

    #[test]
    fn row_order_bottom_row_first() {
        // 3 x 2 image whose a5 (and colour) grows with the row index (row 0 = top).
        let (w, h) = (3, 2);
        for format in [PtmFormat::Lrgb, PtmFormat::Rgb] {
            let per = format.coeffs_per_texel();
            let mut coeffs = vec![0f32; w * h * per];
            for y in 0..h {
                for x in 0..w {
                    for p in 0..per / 6 {
                        coeffs[(y * w + x) * per + p * 6 + 5] = 0.2 + 0.6 * y as f32 + 0.01 * x as f32;
                    }
                }
            }
            let rgb = (format == PtmFormat::Lrgb)
                .then(|| (0..w * h * 3).map(|i| if i / (w * 3) == 0 { 0.2 } else { 0.8 }).collect::<Vec<f32>>());
            let img = PtmImage { width: w, height: h, format, coeffs, rgb };
            let (bytes, _) = encode_ptm(&img).unwrap();
            let (_, at) = split_header(&bytes);
            let data = &bytes[at..];
            // a5 byte of the file's first texel belongs to the bottom row (y = 1, larger a5),
            // that of the file's second row to the top row (y = 0).
            let first_row_a5 = data[5];
            let second_row_a5 = data[w * 6 + 5];
            assert!(
                first_row_a5 > second_row_a5,
                "{format:?}: first row a5 byte {first_row_a5}, second {second_row_a5}"
            );
            // Within a row, left to right.
            assert!(data[6 + 5] > data[5], "{format:?}: x order");
            if format == PtmFormat::Lrgb {
                let colour = &data[w * h * 6..];
                assert_eq!(colour.len(), w * h * 3);
                assert_eq!(colour[0], 204); // bottom row 0.8
                assert_eq!(colour[w * 3], 51); // top row 0.2
            } else {
                assert_eq!(data.len(), 3 * w * h * 6);
                // Each of the three channel blocks starts with the bottom row again.
                for ch in 0..3 {
                    let block = &data[ch * w * h * 6..];
                    assert_eq!(block[5], first_row_a5, "channel {ch}");
                }
            }
            let back = decode_ptm(&bytes, "mem").unwrap();
            assert!(back.coeffs[5] < back.coeffs[w * per + 5], "{format:?}: decoded rows flipped back");
        }
    }

    #[test]
    fn header_is_exactly_the_format() {
        let img = random_image(PtmFormat::Lrgb, 3, 2, 4);
        let (bytes, q) = encode_ptm(&img).unwrap();
        let (lines, at) = split_header(&bytes);
        assert_eq!(lines[0], "PTM_1.2");
        assert_eq!(lines[1], "PTM_FORMAT_LRGB");
        assert_eq!(lines[2], "3");
        assert_eq!(lines[3], "2");
        let scales: Vec<f32> = lines[4].split(' ').map(|t| t.parse().unwrap()).collect();
        assert_eq!(scales.len(), 6);
        for (k, &s) in scales.iter().enumerate() {
            // The header's scale is in byte units: 255 x the step in our units.
            let ours = (f64::from(s) / 255.0) as f32;
            assert_eq!(ours, q.scale[k], "a{k}");
        }
        let biases: Vec<i32> = lines[5].split(' ').map(|t| t.parse().unwrap()).collect();
        assert_eq!(biases, q.bias.to_vec());
        assert_eq!(bytes.len() - at, 3 * 2 * 9);

        let (rgb_bytes, _) = encode_ptm(&random_image(PtmFormat::Rgb, 3, 2, 5)).unwrap();
        let (lines, at) = split_header(&rgb_bytes);
        assert_eq!(lines[1], "PTM_FORMAT_RGB");
        assert_eq!(rgb_bytes.len() - at, 3 * 2 * 18);
    }

    #[test]
    fn viewer_brightness_matches_our_units() {
        // Emulate RTIViewer on the encoded bytes: LRGB shows rgb_byte * poly_bytes / 255, RGB shows
        // poly_bytes. Both must be 255 x our eval().
        for format in [PtmFormat::Lrgb, PtmFormat::Rgb] {
            let img = random_image(format, 4, 3, 6);
            let (bytes, q) = encode_ptm(&img).unwrap();
            let (lines, at) = split_header(&bytes);
            let scale: Vec<f64> = lines[4].split(' ').map(|t| t.parse().unwrap()).collect();
            let bias: Vec<f64> = lines[5].split(' ').map(|t| t.parse().unwrap()).collect();
            let data = &bytes[at..];
            let (w, h) = (4, 3);
            let (lu, lv) = (0.3f64, -0.5f64);
            let m = [lu * lu, lv * lv, lu * lv, lu, lv, 1.0];
            let poly = |s: &[u8]| (0..6).map(|k| (f64::from(s[k]) - bias[k]) * scale[k] * m[k]).sum::<f64>();
            // Worst-case quantization error of the polynomial, in our units.
            let tol: f64 = (0..6).map(|k| f64::from(q.scale[k]) / 2.0 * m[k].abs()).sum::<f64>() + 0.5 / 255.0 * 2.0;
            for y in 0..h {
                for x in 0..w {
                    let want = img.eval(x, y, lu as f32, lv as f32);
                    let t = (h - 1 - y) * w + x;
                    let shown: [f64; 3] = match format {
                        PtmFormat::Lrgb => {
                            let l = poly(&data[t * 6..]) / 255.0;
                            let c = &data[w * h * 6 + t * 3..];
                            [f64::from(c[0]) * l, f64::from(c[1]) * l, f64::from(c[2]) * l]
                        }
                        PtmFormat::Rgb => std::array::from_fn(|ch| poly(&data[ch * w * h * 6 + t * 6..])),
                    };
                    for c in 0..3 {
                        let got = shown[c] / 255.0;
                        assert!(
                            (got - f64::from(want[c])).abs() <= tol * 1.5,
                            "{format:?} ({x},{y}) ch {c}: viewer {got}, ours {}",
                            want[c]
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn hand_written_files_decode() {
        // As another tool might write it: CRLF, trailing spaces, width and height on one line,
        // one number per line, a float bias.
        let mut lrgb = b"PTM_1.2 \r\nPTM_FORMAT_LRGB\r\n2 1\r\n2.0\n1 \n 1\n1\n1\n0.5\n0 0\n0 0 0 128.0 \r\n".to_vec();
        // texel 0 (x=0), texel 1 (x=1): a0..a5
        lrgb.extend_from_slice(&[10, 20, 30, 40, 50, 60, 255, 0, 1, 2, 3, 100]);
        lrgb.extend_from_slice(&[255, 0, 51, 1, 2, 3]);
        let img = decode_ptm(&lrgb, "hand.ptm").unwrap();
        assert_eq!((img.width, img.height, img.format), (2, 1, PtmFormat::Lrgb));
        let scale = [2.0, 1.0, 1.0, 1.0, 1.0, 0.5];
        let bias = [0.0, 0.0, 0.0, 0.0, 0.0, 128.0];
        let raw: [u8; 12] = [10, 20, 30, 40, 50, 60, 255, 0, 1, 2, 3, 100];
        for (i, &r) in raw.iter().enumerate() {
            let k = i % 6;
            let want = ((f64::from(r) - bias[k]) * scale[k] / 255.0) as f32;
            assert_eq!(img.coeffs[i], want, "coefficient {i}");
        }
        assert_eq!(img.rgb.as_deref().unwrap(), &[1.0, 0.0, 0.2, 1.0 / 255.0, 2.0 / 255.0, 3.0 / 255.0]);

        // PTM_FORMAT_RGB, 1 x 2: the file's first row is the image's bottom row (row 1).
        let mut rgb = b"PTM_1.2\nPTM_FORMAT_RGB\n1\n2\n1 1 1 1 1 1\n0 0 0 0 0 0\n".to_vec();
        for ch in 0..3u8 {
            rgb.extend_from_slice(&[0, 0, 0, 0, 0, 200 + ch]); // bottom
            rgb.extend_from_slice(&[0, 0, 0, 0, 0, 10 + ch]); // top
        }
        let img = decode_ptm(&rgb, "rgb.ptm").unwrap();
        assert!(img.rgb.is_none());
        for ch in 0..3 {
            assert_eq!(img.coeffs[ch * 6 + 5], (10 + ch) as f32 / 255.0, "top row, channel {ch}");
            assert_eq!(img.coeffs[18 + ch * 6 + 5], (200 + ch) as f32 / 255.0, "bottom row, channel {ch}");
        }

        // PTM_1.1 LRGB interleaves the colour with the coefficients.
        let mut old = b"PTM_1.1\nPTM_FORMAT_LRGB\n1\n1\n1 1 1 1 1 1\n0 0 0 0 0 0\n".to_vec();
        old.extend_from_slice(&[1, 2, 3, 4, 5, 6, 7, 8, 9]);
        let img = decode_ptm(&old, "old.ptm").unwrap();
        assert_eq!(img.coeffs, [1.0, 2.0, 3.0, 4.0, 5.0, 6.0].map(|v: f32| v / 255.0));
        assert_eq!(img.rgb.unwrap(), [7.0, 8.0, 9.0].map(|v: f32| v / 255.0));
    }

    #[test]
    fn data_starting_with_whitespace_bytes_is_not_skipped() {
        // The first data bytes are '\n', ' ' and '\r': only the header's own newline is consumed.
        let mut f = b"PTM_1.2\nPTM_FORMAT_LRGB\n1\n1\n1 1 1 1 1 1\n0 0 0 0 0 0\n".to_vec();
        f.extend_from_slice(&[b'\n', b' ', b'\r', 4, 5, 6, 7, 8, 9]);
        let img = decode_ptm(&f, "ws.ptm").unwrap();
        assert_eq!(img.coeffs[0], 10.0 / 255.0);
        assert_eq!(img.coeffs[2], 13.0 / 255.0);
        assert_eq!(img.rgb.unwrap()[2], 9.0 / 255.0);
    }

    fn format_error(bytes: &[u8]) -> String {
        match decode_ptm(bytes, "bad.ptm") {
            Err(Error::Format { path, msg }) => {
                assert_eq!(path, "bad.ptm");
                msg
            }
            other => panic!("expected a format error, got {other:?}"),
        }
    }

    #[test]
    fn jpeg_lrgb_planes_with_a_reference_and_a_correction() {
        // Nine constant greyscale planes (a constant 8x8 block is exact in JPEG), plane 1 stored
        // relative to plane 0, one side-information correction in plane 7 (red).
        let (w, h) = (16usize, 8usize);
        let values: [u8; 9] = [10, 100, 30, 40, 50, 60, 70, 80, 90];
        let encode = |v: u8| {
            let mut out = Vec::new();
            ::image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 90)
                .encode(&vec![v; w * h], w as u32, h as u32, ::image::ExtendedColorType::L8)
                .unwrap();
            out
        };
        let stored: Vec<u8> =
            values.iter().enumerate().map(|(k, &v)| if k == 1 { 100 - 10 + 128 } else { v }).collect();
        let jpegs: Vec<Vec<u8>> = stored.iter().map(|&v| encode(v)).collect();
        let side: Vec<usize> = (0..9).map(|k| if k == 6 { 5 } else { 0 }).collect();
        let list = |f: &dyn Fn(usize) -> String| (0..9).map(f).collect::<Vec<_>>().join(" ");
        let mut f = format!(
            "PTM_1.2\nPTM_FORMAT_JPEG_LRGB\n{w}\n{h}\n1 1 1 1 1 1\n0 0 0 0 0 0\n90\n{z}\n{z}\n{z}\n{order}\n{refs}\n{sizes}\n{side}\n",
            z = list(&|_| "0".into()),
            order = list(&|k| k.to_string()),
            refs = list(&|k| if k == 1 { "0".into() } else { "-1".into() }),
            sizes = list(&|k| jpegs[k].len().to_string()),
            side = list(&|k| side[k].to_string()),
        )
        .into_bytes();
        for (k, j) in jpegs.iter().enumerate() {
            f.extend_from_slice(j);
            if k == 6 {
                // texel 3 of the file (bottom row, column 3) gets red 255
                f.extend_from_slice(&[0, 0, 0, 3, 255]);
            }
        }
        let b = decode_ptm_bytes(&f, "j.ptm").unwrap();
        assert_eq!((b.width, b.height, b.format), (w, h, PtmFormat::Lrgb));
        for t in 0..w * h {
            assert_eq!(b.coeffs[t * 6..t * 6 + 6], values[..6]);
        }
        let rgb = b.rgb.unwrap();
        // file texel 3 is row h - 1 (the bottom), column 3
        let t = (h - 1) * w + 3;
        assert_eq!(rgb[t * 3..t * 3 + 3], [255, 80, 90]);
        assert_eq!(rgb[0..3], [70, 80, 90]);
        // A cut plane: truncated, named.
        assert!(format_error(&f[..f.len() - 10]).contains("truncated"));
    }

    #[test]
    fn decode_errors() {
        let (good, _) = encode_ptm(&random_image(PtmFormat::Lrgb, 3, 2, 7)).unwrap();
        assert!(format_error(&good[..good.len() - 1]).contains("truncated"));
        let (lines, at) = split_header(&good);
        assert!(format_error(&good[..at - 1]).contains("truncated"), "cut inside the header");

        let unknown = b"PTM_1.2\nPTM_FORMAT_FOO\n1\n1\n1 1 1 1 1 1\n0 0 0 0 0 0\n";
        assert!(format_error(unknown).contains("PTM_FORMAT_FOO"));
        let jpeg = b"PTM_1.2\nPTM_FORMAT_JPEG_LRGB\n1\n1\n1 1 1 1 1 1\n0 0 0 0 0 0\n";
        let msg = format_error(jpeg);
        assert!(msg.contains("truncated") && msg.contains("JPEG quality"), "{msg}");
        let msg = format_error(b"PTM_1.2\nPTM_FORMAT_JPEGLS_RGB\n");
        assert!(msg.contains("PTM_FORMAT_JPEGLS_RGB") && msg.contains("not supported"), "{msg}");
        assert!(format_error(b"PTM_1.2\nPTM_FORMAT_LUM\n").contains("PTM_FORMAT_LUM"));
        assert!(format_error(b"PTM_1.0\nPTM_FORMAT_LRGB\n").contains("PTM_1.0"));
        assert!(format_error(b"\x89PNG\r\n\x1a\n").contains("not a PTM file"));

        let bad_scale = format!("PTM_1.2\nPTM_FORMAT_LRGB\n1\n1\n1 1 x 1 1 1\n{}\n", lines[5]);
        assert!(format_error(bad_scale.as_bytes()).contains("scale value 3"));
        let nan_scale = b"PTM_1.2\nPTM_FORMAT_LRGB\n1\n1\n1 1 NaN 1 1 1\n0 0 0 0 0 0\n";
        assert!(format_error(nan_scale).contains("scale value 3"));
        let zero_w = b"PTM_1.2\nPTM_FORMAT_LRGB\n0\n1\n1 1 1 1 1 1\n0 0 0 0 0 0\n";
        assert!(format_error(zero_w).contains("width"));
        let neg_h = b"PTM_1.2\nPTM_FORMAT_LRGB\n1\n-1\n1 1 1 1 1 1\n0 0 0 0 0 0\n";
        assert!(format_error(neg_h).contains("height"));
        let huge = b"PTM_1.2\nPTM_FORMAT_RGB\n99999999999\n99999999999\n1 1 1 1 1 1\n0 0 0 0 0 0\n\0";
        let msg = format_error(huge);
        assert!(msg.contains("too large") || msg.contains("truncated"), "{msg}");
        // Finite scale and bias, but the decoded coefficients overflow f32.
        let mut overflow = b"PTM_1.2\nPTM_FORMAT_LRGB\n1\n1\n1 1 1e38 1 1 1\n0 0 -1e300 0 0 0\n".to_vec();
        overflow.extend_from_slice(&[0; 9]);
        let msg = format_error(&overflow);
        assert!(msg.contains("scale value 3") && msg.contains("float range"), "{msg}");
        let no_newline = b"PTM_1.2\nPTM_FORMAT_LRGB\n1\n1\n1 1 1 1 1 1\n0 0 0 0 0 0 7";
        assert!(format_error(no_newline).contains("bias"));
    }

    fn arg_error(img: &PtmImage) -> (String, String) {
        match encode_ptm(img) {
            Err(Error::InvalidArgument { name, msg, .. }) => (name, msg),
            other => panic!("expected an invalid-argument error, got {other:?}"),
        }
    }

    #[test]
    fn encode_validation_errors() {
        let good = random_image(PtmFormat::Lrgb, 2, 2, 8);
        assert_eq!(arg_error(&PtmImage { width: 0, ..good.clone() }).0, "width");
        assert_eq!(arg_error(&PtmImage { height: 0, ..good.clone() }).0, "height");
        let mut nan = good.clone();
        nan.coeffs[5] = f32::NAN;
        let (name, msg) = arg_error(&nan);
        assert_eq!(name, "coeffs");
        assert!(msg.contains("NaN"), "{msg}");
        let mut inf = good.clone();
        inf.coeffs[0] = f32::INFINITY;
        assert_eq!(arg_error(&inf).0, "coeffs");
        let mut short = good.clone();
        short.coeffs.pop();
        assert_eq!(arg_error(&short).0, "coeffs");
        assert_eq!(arg_error(&PtmImage { rgb: None, ..good.clone() }).0, "rgb");
        assert_eq!(arg_error(&PtmImage { rgb: Some(vec![0.5; 11]), ..good.clone() }).0, "rgb");
        let mut bright = good.clone();
        bright.rgb.as_mut().unwrap()[3] = 1.5;
        assert_eq!(arg_error(&bright).0, "rgb");
        let mut nan_rgb = good.clone();
        nan_rgb.rgb.as_mut().unwrap()[0] = f32::NAN;
        assert_eq!(arg_error(&nan_rgb).0, "rgb");
        let rgb_with_colour = PtmImage { rgb: Some(vec![0.5; 12]), ..random_image(PtmFormat::Rgb, 2, 2, 9) };
        assert_eq!(arg_error(&rgb_with_colour).0, "rgb");
        // The Rgb layout needs 18 values per texel, not 6.
        let wrong_layout = PtmImage { format: PtmFormat::Rgb, rgb: None, ..good };
        assert_eq!(arg_error(&wrong_layout).0, "coeffs");
    }

    #[test]
    fn read_missing_file_keeps_not_found() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("absent.ptm");
        match read_ptm(&path) {
            Err(Error::Io { path: p, source }) => {
                assert_eq!(source.kind(), std::io::ErrorKind::NotFound);
                assert!(p.ends_with("absent.ptm"));
            }
            other => panic!("expected an I/O error, got {other:?}"),
        }
    }

    fn dir_entries(dir: &Path) -> Vec<String> {
        let mut names: Vec<String> =
            fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
        names.sort();
        names
    }

    #[test]
    fn write_and_read_file_leave_no_temp() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.ptm");
        let img = random_image(PtmFormat::Rgb, 5, 3, 10);
        let q = write_ptm(&path, &img).unwrap();
        assert_eq!(dir_entries(dir.path()), ["out.ptm"]);
        let back = read_ptm(&path).unwrap();
        for (i, (&a, &d)) in img.coeffs.iter().zip(&back.coeffs).enumerate() {
            assert!((a - d).abs() <= q.scale[i % 6] / 2.0 + 1e-6, "coefficient {i}");
        }
        // Overwriting an existing target replaces it.
        let img2 = random_image(PtmFormat::Lrgb, 2, 2, 11);
        write_ptm(&path, &img2).unwrap();
        assert_eq!(dir_entries(dir.path()), ["out.ptm"]);
        assert_eq!(read_ptm(&path).unwrap().format, PtmFormat::Lrgb);
    }

    #[test]
    fn failed_writes_leave_no_temp() {
        let dir = tempfile::tempdir().unwrap();
        let img = random_image(PtmFormat::Lrgb, 2, 2, 12);

        // The target's directory does not exist: the temporary file cannot even be created.
        let missing = dir.path().join("no_such_dir").join("out.ptm");
        match write_ptm(&missing, &img) {
            Err(Error::Io { source, .. }) => {
                assert_eq!(source.kind(), std::io::ErrorKind::NotFound)
            }
            other => panic!("expected an I/O error, got {other:?}"),
        }
        assert!(dir_entries(dir.path()).is_empty());

        // The target is a directory: the temporary file is written, the rename fails, and the
        // temporary file must be removed.
        let target = dir.path().join("taken.ptm");
        fs::create_dir(&target).unwrap();
        fs::write(target.join("keep"), b"x").unwrap();
        assert!(matches!(write_ptm(&target, &img), Err(Error::Io { .. })));
        assert_eq!(dir_entries(dir.path()), ["taken.ptm"]);

        // An invalid image fails before touching the disk.
        let bad = PtmImage { width: 0, ..img };
        assert!(matches!(write_ptm(&dir.path().join("x.ptm"), &bad), Err(Error::InvalidArgument { .. })));
        assert_eq!(dir_entries(dir.path()), ["taken.ptm"]);
    }

    #[test]
    fn a_fitted_8_bit_slot_is_written_byte_for_byte() {
        use btfrs_core::{directions::ubo81, BtfRef, Monitor};
        use btfrs_fit::{fit_ptm, Ptm, PtmOptions};
        let d = ubo81();
        let (h, w) = (3, 2);
        let data: Vec<f32> = (0..h * w * d.len() * d.len() * 3).map(|i| ((i * 7919) % 1000) as f32 / 900.0).collect();
        let btf = BtfRef::new(h, w, &d, &d, &data, None).unwrap();
        for kind in [PtmKind::Rgb, PtmKind::Lrgb] {
            let m = fit_ptm(&btf, &PtmOptions { kind, ..Default::default() }, &Monitor::new()).unwrap();
            let slot = m.slot(5).unwrap();
            let b = PtmBytes::from_slot(&slot).expect("a fitted 8-bit slot has the file's form");
            assert_eq!(b.coeffs, slot.planes.as_ref().unwrap().coeffs.q, "the model's own bytes");
            let file = encode_ptm_bytes(&b).unwrap();
            let back = decode_ptm_bytes(&file, "s.ptm").unwrap();
            assert_eq!(back, b);
            // the reader's decoding equals the model's values up to float rounding
            let img = back.decode("s.ptm").unwrap();
            for (x, y) in img.coeffs.iter().zip(&slot.coeffs) {
                assert!((x - y).abs() <= 2e-6 * (1.0 + y.abs()), "{kind:?}: {x} vs {y}");
            }
            // and the one-slot model read back holds the same bytes
            let one = Ptm::from_slot(back.to_slot()).unwrap();
            assert_eq!(one.quantized.as_ref().unwrap().coeffs.q, b.coeffs);
            assert_eq!(PtmBytes::from_slot(&one.slot(0).unwrap()).unwrap(), b);
            // a float model has no file bytes of its own
            let f = fit_ptm(&btf, &PtmOptions { kind, bits: 32, ..Default::default() }, &Monitor::new()).unwrap();
            assert!(PtmBytes::from_slot(&f.slot(0).unwrap()).is_none());
        }
    }
}
