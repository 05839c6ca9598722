//! Light calibration of RTI captures from a reflective sphere.
//!
//! Photographs of a surface under many lights, a glossy black sphere in the frame and no light
//! file: each photograph's light is the mirror image of its highlight on the sphere. This crate
//! finds the sphere ([`detect`]: a dark disc, then its outline to a fraction of a pixel, fitted
//! by [`fit`]), each photograph's highlight ([`highlight`]: sub-pixel, robust to clipping,
//! doubled highlights flagged), turns it into a direction ([`geometry`]: orthographic or
//! perspective camera), optionally measures each light's intensity on a white target, and
//! writes the `.lp` file relight, RTIBuilder and btfrs read ([`lp`]).
//!
//! [`calibrate`] reads every photograph once (twice for the few, at most 12, that the coarse
//! sphere search looks at when no circle is given), in parallel, decoding each and keeping only
//! the luminance around the sphere; it reports progress and stops on cancel through its
//! [`Monitor`]. The method is the one RTIBuilder and relight use (highlight centroid, mirror
//! reflection); what is new here is the automatic search, the robust outline and spot rules,
//! and the perspective model (relight corrects for perspective only through the sphere's
//! ellipse; here the exact cone of view rays is fitted).

pub mod detect;
pub mod fit;
pub mod geometry;
pub mod highlight;
pub mod lp;
pub mod photo;

use btfrs_core::{Error, Monitor, Result};
use btfrs_io::decode::Transfer;
use geometry::{Camera, SphereView};
use highlight::{Finding, Search, Status};
use photo::Rect;
use rayon::prelude::*;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// The photographs of a capture.
#[derive(Debug, Clone, PartialEq)]
pub enum Input {
    /// Every photograph in a folder (by extension: JPEG, PNG, TIFF, EXR), sorted by name.
    Folder(PathBuf),
    /// These files, in this order.
    Files(Vec<PathBuf>),
}

impl Input {
    /// The files, and how the capture is named in messages.
    pub fn files(&self) -> Result<(Vec<PathBuf>, String)> {
        match self {
            Input::Folder(d) => {
                let shown = d.display().to_string();
                if !d.is_dir() {
                    return Err(Error::io(&shown, std::io::Error::from(std::io::ErrorKind::NotFound)));
                }
                let names = btfrs_io::stack::Store::Folder(d.clone()).list_images()?;
                if names.is_empty() {
                    return Err(Error::arg(
                        "images",
                        format!("{shown} holds no photographs (expected .jpg, .jpeg, .png, .tif, .tiff or .exr files)"),
                    ));
                }
                Ok((names.iter().map(|n| d.join(n)).collect(), shown))
            }
            Input::Files(f) => {
                if f.is_empty() {
                    return Err(Error::arg("images", "no photographs given; expected a folder or a list of files"));
                }
                for p in f {
                    if !p.is_file() {
                        let shown = p.display().to_string();
                        return Err(Error::io(&shown, std::io::Error::from(std::io::ErrorKind::NotFound)));
                    }
                }
                Ok((f.clone(), format!("the {} photographs", f.len())))
            }
        }
    }
}

/// How the photographs were projected.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum Projection {
    /// Parallel view rays (a long lens far away; RTIBuilder's and relight's default).
    #[default]
    Orthographic,
    /// A pinhole with this horizontal field of view in degrees (across the image's width).
    FieldOfView(f64),
    /// A pinhole with this 35 mm-equivalent focal length in millimetres (what EXIF's
    /// `FocalLengthIn35mmFilm` holds: the image's diagonal spans 43.27 mm).
    Focal35mm(f64),
}

impl Projection {
    /// The camera for a `width x height` image.
    pub fn camera(self, width: usize, height: usize) -> Result<Camera> {
        let (w, h) = (width as f64, height as f64);
        let focal_px = match self {
            Projection::Orthographic => return Ok(Camera::Orthographic),
            Projection::FieldOfView(f) => {
                if !(f.is_finite() && f > 0.0 && f < 170.0) {
                    return Err(Error::arg("fov", format!("expected a field of view in (0, 170) degrees, got {f}")));
                }
                0.5 * w / (0.5 * f.to_radians()).tan()
            }
            Projection::Focal35mm(f) => {
                if !(f.is_finite() && f > 0.0) {
                    return Err(Error::arg("focal", format!("expected a focal length in mm above 0, got {f}")));
                }
                f * w.hypot(h) / 36f64.hypot(24.0)
            }
        };
        Ok(Camera::Perspective { focal_px, width: w, height: h })
    }
}

/// What [`calibrate`] is told.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Options {
    /// The sphere's outline as a circle (cx, cy, r) in pixels (x right, y down, the image's
    /// top-left corner at (0, 0)), used as given; None: found.
    pub sphere: Option<[f64; 3]>,
    /// The camera.
    pub projection: Projection,
    /// A white (Lambertian) target facing the camera: (row, col, rows, cols) in pixels, as
    /// btfrs's crops are given. Its mean colour per photograph, divided by the light's cosine,
    /// is the light's relative intensity.
    pub white: Option<[usize; 4]>,
    /// How 8- and 16-bit values map to linear light.
    pub transfer: Transfer,
}

/// The sphere as found (or given).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SphereReport {
    /// Its outline's circle (cx, cy, r) in pixels.
    pub circle: [f64; 3],
    /// Whether it was found (false: given).
    pub detected: bool,
    /// The outline points traced, those the fit kept, and their RMS distance from the outline
    /// (pixels); zeros when given.
    pub edge_points: usize,
    pub edge_kept: usize,
    pub edge_rms_px: f64,
    /// Perspective: the unit direction of the sphere's centre from the camera and the angular
    /// radius (degrees) of the sphere seen from it.
    pub axis: Option<[f64; 3]>,
    pub angular_radius_deg: Option<f64>,
    /// When found: the coarse circle the outline was traced from.
    pub coarse: Option<[f64; 3]>,
}

/// One photograph's calibration.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ImageReport {
    /// The file (the path as listed or given).
    pub file: String,
    /// What the highlight search found.
    #[serde(flatten)]
    pub finding: Finding,
    /// The highlight's centre in pixels, when calibrated.
    pub highlight: Option<[f64; 2]>,
    /// The light direction (unit, btfrs's frame), when calibrated.
    pub light: Option<[f64; 3]>,
    /// Something to know about a calibrated light (moved onto the horizon).
    pub note: Option<String>,
    /// With a white target: its mean linear RGB and its clipped pixels.
    pub white_rgb: Option<[f64; 3]>,
    pub white_clipped: usize,
    /// With a white target, when calibrated: the light's relative intensity per channel (the
    /// target's colour over the light's cosine, the median over the capture's luminance = 1).
    pub intensity: Option<[f64; 3]>,
}

/// The result of [`calibrate`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Calibration {
    /// Size of every photograph.
    pub width: usize,
    pub height: usize,
    /// The camera model used.
    pub camera: Camera,
    /// The sphere.
    pub sphere: SphereReport,
    /// Every photograph, in order.
    pub images: Vec<ImageReport>,
    /// The white target's rectangle (row, col, rows, cols), if any.
    pub white: Option<[usize; 4]>,
    /// What the caller should show (a clipped white target, grazing lights' intensities).
    pub warnings: Vec<String>,
}

impl Calibration {
    /// The calibrated photographs.
    pub fn calibrated(&self) -> impl Iterator<Item = &ImageReport> {
        self.images.iter().filter(|i| i.light.is_some())
    }
}

/// Photographs the coarse sphere search reads (evenly spread over the capture).
const COARSE_IMAGES: usize = 12;
/// The coarse search works on photographs reduced to at most this many pixels across.
const COARSE_SIDE: f64 = 768.0;
/// Lights lower than this (degrees of elevation) get a warning about their intensity.
const LOW_INTENSITY_ELEVATION: f64 = 10.0;

fn check_size(shown: &Path, got: (usize, usize), want: (usize, usize), first: &Path) -> Result<()> {
    if got != want {
        return Err(Error::format(
            shown.display(),
            format!(
                "the photograph is {} x {} pixels (width x height); expected {} x {} like {} (the capture's photographs \
                 must all have one size)",
                got.0,
                got.1,
                want.0,
                want.1,
                first.display()
            ),
        ));
    }
    Ok(())
}

/// Decode a photograph into `buf` (each rayon task keeps one, from one photograph to the next)
/// after checking for a cancel, and check its size against the capture's.
fn open_checked<'a>(
    f: &Path,
    transfer: Transfer,
    buf: &'a mut Vec<u8>,
    size: (usize, usize),
    first: &Path,
    monitor: &Monitor,
) -> Result<photo::Photo<'a>> {
    monitor.check()?;
    let p = photo::open(f, transfer, buf)?;
    check_size(f, (p.width, p.height), size, first)?;
    Ok(p)
}

/// Calibrate the lights of `input` (see the crate's documentation). Photographs that cannot be
/// calibrated are reported in [`ImageReport::finding`]; none calibrated at all is an error
/// naming each with its reason.
pub fn calibrate(input: &Input, opts: &Options, monitor: &Monitor) -> Result<Calibration> {
    let (files, shown) = input.files()?;
    let n = files.len();
    // Sizes from the headers first: a photograph of another size is refused before any decode.
    let mut size: Option<((usize, usize), &Path)> = None;
    for f in &files {
        if let Some(s) = photo::header_size(f)? {
            match size {
                None => size = Some((s, f)),
                Some((s0, f0)) => check_size(f, s, s0, f0)?,
            }
        }
    }
    let (size, first) = match size {
        Some(s) => s,
        None => {
            let mut buf = Vec::new();
            let first = photo::open(&files[0], opts.transfer, &mut buf)?;
            ((first.width, first.height), files[0].as_path())
        }
    };
    let (w, h) = size;
    let camera = opts.projection.camera(w, h)?;
    if let Some([cx, cy, r]) = opts.sphere {
        if ![cx, cy, r].iter().all(|v| v.is_finite()) || r < 3.0 {
            return Err(Error::arg(
                "sphere",
                format!("expected (cx, cy, r) with r >= 3 pixels, got ({cx}, {cy}, {r})"),
            ));
        }
        if cx - r < -0.5 * r || cy - r < -0.5 * r || cx + r > w as f64 + 0.5 * r || cy + r > h as f64 + 0.5 * r {
            return Err(Error::arg(
                "sphere",
                format!("the circle ({cx}, {cy}, {r}) lies mostly outside the {w} x {h} photographs"),
            ));
        }
    }
    let white = match opts.white {
        None => None,
        Some([row, col, rows, cols]) => {
            if rows == 0 || cols == 0 || row + rows > h || col + cols > w {
                return Err(Error::arg(
                    "white",
                    format!(
                        "expected (row, col, rows, cols) inside the {h} x {w} (height x width) photographs, got \
                         ({row}, {col}, {rows}, {cols})"
                    ),
                ));
            }
            Some(Rect { x0: col, y0: row, w: cols, h: rows })
        }
    };
    // The coarse circle, or the given one.
    let coarse_count = if opts.sphere.is_some() { 0 } else { n.min(COARSE_IMAGES) };
    monitor.start((coarse_count + n) as u64);
    let (circle, slack) = match opts.sphere {
        Some(c) => (c, 0.0),
        None => {
            let k = coarse_count;
            let picks: Vec<usize> = (0..k).map(|i| if k == 1 { 0 } else { i * (n - 1) / (k - 1) }).collect();
            let s = ((w.max(h) as f64 / COARSE_SIDE).ceil() as usize).max(1);
            let frames = picks
                .par_iter()
                .map_init(Vec::new, |buf, &i| {
                    let p = open_checked(&files[i], opts.transfer, buf, size, first, monitor)?;
                    let (d, _, _) = photo::downsample(&p, s);
                    monitor.advance(1);
                    Ok(d)
                })
                .collect::<Result<Vec<_>>>()?;
            let c = detect::coarse(&frames, w.div_ceil(s), h.div_ceil(s), s, &shown)?;
            // How far the coarse circle may be off: its outline is found within a reduced pixel
            // or two, plus a share of the radius where the sphere's shadow clung to it.
            (c, 2.0 * s as f64 + 0.03 * c[2] + 2.0)
        }
    };
    // The highlights are looked for on the circle known before reading them all: the given
    // one, or the coarse one (a few reduced pixels off at most, which moves the edge of the
    // search, at 47.5 degrees of normal, by a fraction of a degree; the directions come from
    // the outline fitted afterwards). So each photograph is searched as soon as it is decoded
    // and its pixels dropped: memory stays that of the photographs being decoded, whatever the
    // capture's length.
    let inner = Rect::around([circle[0], circle[1], 0.8 * circle[2]], 2.0, w, h);
    let search = Search::new(&SphereView::from_circle(camera, circle), inner);
    // Only the searched pixels' luminance is needed: the rows' runs of the search's disc.
    let disc = photo::ring_runs(inner, circle[0], circle[1], 0.0, 0.8 * circle[2] + 2.0);
    // The mean photograph is summed over a ring around the coarse outline only: the outline is
    // traced within `slack` of it, then within `slack` of a first fit that moved by `slack` at
    // most (a quarter of the pixels of the whole disc's box, for a large sphere).
    let reach = 2.0 * slack + 4.0;
    let outer = Rect::around(circle, reach, w, h);
    let runs = if opts.sphere.is_some() {
        Vec::new()
    } else {
        photo::ring_runs(outer, circle[0], circle[1], (circle[2] - reach).max(0.0), circle[2] + reach)
    };
    let acc = Mutex::new(vec![0f64; if opts.sphere.is_some() { 0 } else { outer.len() }]);
    let per = files
        .par_iter()
        .map_init(Vec::new, |buf, f| {
            let p = open_checked(f, opts.transfer, buf, size, first, monitor)?;
            if !runs.is_empty() {
                let ring = photo::luminance_runs(&p, &runs);
                let mut a = acc.lock().unwrap_or_else(|e| e.into_inner());
                let mut k = 0;
                for &(y, x0, x1) in &runs {
                    let at = (y - outer.y0) * outer.w + (x0 - outer.x0);
                    for (s, v) in a[at..at + x1 - x0].iter_mut().zip(&ring[k..k + x1 - x0]) {
                        *s += *v as f64;
                    }
                    k += x1 - x0;
                }
            }
            let finding = highlight::find(&photo::luminance_in(&p, inner, &disc), &search);
            let wt = white.map(|r| photo::rect_mean(&p, r));
            monitor.advance(1);
            Ok((finding, wt))
        })
        .collect::<Result<Vec<_>>>()?;

    // The outline.
    let (view, sphere) = match opts.sphere {
        Some(c) => (
            SphereView::from_circle(camera, c),
            SphereReport {
                circle: c,
                detected: false,
                edge_points: 0,
                edge_kept: 0,
                edge_rms_px: 0.0,
                axis: None,
                angular_radius_deg: None,
                coarse: None,
            },
        ),
        None => {
            let acc = acc.into_inner().unwrap_or_else(|e| e.into_inner());
            let mean: Vec<f32> = acc.iter().map(|s| (s / n as f64) as f32).collect();
            // Traced twice: from the coarse circle, then from the first fit with a narrow window
            // (a coarse circle several pixels off leaves part of the outline outside the first
            // window; its rays catch shadow edges, which the robust fit drops).
            let moved = |c: [f64; 3]| (c[0] - circle[0]).hypot(c[1] - circle[1]) + (c[2] - circle[2]).abs();
            let pts = detect::edge_points(&mean, outer, circle, slack);
            let first = detect::outline(&pts, camera, &shown)?;
            let second = (moved(first.circle) <= slack).then(|| {
                let pts = detect::edge_points(&mean, outer, first.circle, (4.0 * first.rms_px).clamp(2.0, slack));
                detect::outline(&pts, camera, &shown)
            });
            let o = match second {
                Some(o) => o?,
                None => first,
            };
            if moved(o.circle) > 2.0 * slack || 2 * o.kept < o.points {
                return Err(Error::Degenerate(format!(
                    "no sphere found in {shown}: the dark disc near ({:.0}, {:.0}) has no clear round outline (only {} \
                     of {} edge points agree); give its circle instead: sphere=(cx, cy, r) in pixels, or --sphere CX CY R",
                    circle[0], circle[1], o.kept, o.points
                )));
            }
            let view = SphereView { camera, circle: o.circle, cone: o.cone };
            (
                view,
                SphereReport {
                    circle: o.circle,
                    detected: true,
                    edge_points: o.points,
                    edge_kept: o.kept,
                    edge_rms_px: o.rms_px,
                    axis: o.cone.map(|c| c.0),
                    angular_radius_deg: o.cone.map(|c| c.1.acos().to_degrees()),
                    coarse: Some(circle),
                },
            )
        }
    };
    let (axis, angular) = match (sphere.axis, view.cone) {
        (None, Some((a, c))) => (Some(a), Some(c.acos().to_degrees())),
        _ => (sphere.axis, sphere.angular_radius_deg),
    };
    let sphere = SphereReport { axis, angular_radius_deg: angular, ..sphere };

    // The lights, from the final outline.
    let below = -highlight::HORIZON_TOLERANCE_DEG.to_radians().sin();
    let mut images: Vec<ImageReport> = files
        .iter()
        .zip(per)
        .map(|(f, (mut finding, wt))| {
            let mut report = ImageReport {
                file: f.display().to_string(),
                finding: finding.clone(),
                highlight: None,
                light: None,
                note: None,
                white_rgb: wt.map(|t| t.0),
                white_clipped: wt.map_or(0, |t| t.1),
                intensity: None,
            };
            if finding.status == Status::Ok {
                let s = finding.spots[0];
                let (hx, hy) = (s.x, s.y);
                match view.light_at(hx, hy).map(geometry::unit) {
                    Some(mut l) if l[2] >= below => {
                        if l[2] < 0.0 {
                            report.note = Some(format!(
                                "the light was {:.2} degrees below the horizon; moved onto it",
                                -l[2].asin().to_degrees()
                            ));
                            l = geometry::unit([l[0], l[1], 0.0]);
                        }
                        report.highlight = Some([hx, hy]);
                        report.light = Some(l);
                    }
                    found => {
                        finding.status = Status::Missing;
                        finding.reason = Some(match found {
                            None => "the highlight's centre is off the sphere".into(),
                            Some(l) => format!(
                                "the highlight mirrors a light {:.1} degrees below the horizon",
                                -l[2].asin().to_degrees()
                            ),
                        });
                        report.finding = finding;
                    }
                }
            }
            report
        })
        .collect();

    if images.iter().all(|i| i.light.is_none()) {
        let list: Vec<String> = images
            .iter()
            .take(8)
            .map(|i| format!("{}: {}", i.file, i.finding.reason.as_deref().unwrap_or("not calibrated")))
            .collect();
        return Err(Error::Degenerate(format!(
            "no photograph of {shown} could be calibrated (sphere at ({:.1}, {:.1}), radius {:.1} pixels): {}{}",
            sphere.circle[0],
            sphere.circle[1],
            sphere.circle[2],
            list.join("; "),
            if n > 8 { format!("; and {} more", n - 8) } else { String::new() }
        )));
    }

    let mut warnings = Vec::new();
    if let Some(rect) = opts.white {
        intensities(&mut images, rect, &mut warnings)?;
    }
    Ok(Calibration { width: w, height: h, camera, sphere, images, white: opts.white, warnings })
}

/// Each calibrated light's relative intensity from the white target (see [`Options::white`]).
fn intensities(images: &mut [ImageReport], rect: [usize; 4], warnings: &mut Vec<String>) -> Result<()> {
    let low = LOW_INTENSITY_ELEVATION.to_radians().sin();
    let mut lum = Vec::new();
    for im in images.iter_mut() {
        if let (Some(l), Some(c)) = (im.light, im.white_rgb) {
            // A Lambertian target facing the camera reads albedo x E x cos(theta_l); never
            // divide by a cosine under that of 2 degrees.
            let cos = l[2].max(2f64.to_radians().sin());
            let e = c.map(|v| v / cos);
            lum.push(photo::luminance(e[0] as f32, e[1] as f32, e[2] as f32) as f64);
            im.intensity = Some(e);
        }
    }
    let mut sorted = lum.clone();
    sorted.sort_by(f64::total_cmp);
    let med = sorted[sorted.len() / 2];
    if med.is_nan() || med <= 0.0 {
        return Err(Error::arg(
            "white",
            format!("the white target {rect:?} (row, col, rows, cols) is black in the photographs; expected a lit white area"),
        ));
    }
    for im in images.iter_mut() {
        if let Some(e) = im.intensity.as_mut() {
            *e = e.map(|v| v / med);
        }
    }
    // A hot pixel or a glint of dust is not a clipped target: one pixel in a hundred is.
    let area = rect[2] * rect[3];
    let clipped: Vec<&str> = images
        .iter()
        .filter(|i| i.intensity.is_some() && 100 * i.white_clipped > area)
        .map(|i| Path::new(&i.file).file_name().and_then(|n| n.to_str()).unwrap_or(&i.file))
        .collect();
    if !clipped.is_empty() {
        warnings.push(format!(
            "the white target is clipped (over 1% of its pixels at the top of the range) in {} photographs ({}{}): \
             their intensities are too low",
            clipped.len(),
            clipped[..clipped.len().min(3)].join(", "),
            if clipped.len() > 3 { ", ..." } else { "" }
        ));
    }
    let dark: Vec<&str> = images
        .iter()
        .filter(|i| i.intensity.is_some_and(|e| photo::luminance(e[0] as f32, e[1] as f32, e[2] as f32) < 0.05))
        .map(|i| Path::new(&i.file).file_name().and_then(|n| n.to_str()).unwrap_or(&i.file))
        .collect();
    if !dark.is_empty() {
        warnings.push(format!(
            "the white target is dark (in a shadow?) in {} photographs ({}{}): their intensities are meaningless",
            dark.len(),
            dark[..dark.len().min(3)].join(", "),
            if dark.len() > 3 { ", ..." } else { "" }
        ));
    }
    let grazing = images.iter().filter(|i| i.intensity.is_some() && i.light.is_some_and(|l| l[2] < low)).count();
    if grazing > 0 {
        warnings.push(format!(
            "{grazing} lights are under {LOW_INTENSITY_ELEVATION} degrees of elevation: their intensities divide by a \
             small cosine and are uncertain"
        ));
    }
    Ok(())
}
