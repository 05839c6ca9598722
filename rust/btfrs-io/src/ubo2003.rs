//! Bonn UBO2003 and ATRIUM BTF archives: a zip archive (or a folder) of rectified images, one per
//! (view, light) pair, whose names carry the angles, e.g.
//! `WoolPKNT256_00084_tl015_pl000_tv015_pv120.jpg`: light theta 15, phi 0, view theta 15,
//! phi 120, in degrees. JPEG or PNG (sRGB, decoded to linear), EXR for the HDR variants.
//!
//! **Frame.** The images are rectified to the sample: columns run along the sample's u axis and
//! rows down its v axis. A (theta, phi) pair becomes `(sin t cos p, sin t sin p, cos t)` with phi
//! measured from the image's +x (columns, to the right) towards +y (*up* the image), which is
//! btfrs's tangent frame, so no angle is changed. This is the convention of the UBO documentation
//! as we read it; it could not be checked against a Bonn file here (no downloads), so the test
//! archive of this module encodes each image's own light direction in a Lambertian relief and
//! checks that a light at phi = 0 lights the slopes facing +x, at phi = 90 those facing up the
//! image. If a real archive shows the opposite, `phi_offset`/`flip` in one place
//! ([`direction`]) changes it.
//!
//! Views and lights are sorted by (theta, phi), which for a complete archive is the UBO 81
//! order of `btfrs.directions.ubo81()`.

use crate::capture::{Limits, Selection};
use crate::decode::Transfer;
use crate::stack::{from_angles, ImageStack, Member, Store};
use btfrs_core::{Error, Result};
use std::path::Path;

/// The angles (light theta, light phi, view theta, view phi, degrees) in a UBO file name, or
/// `None` when one is missing. Tokens are separated by `_` (or `.`, `-`): `tl015`, `pl000`,
/// `tv015`, `pv120`; decimals are allowed (`tl7.5`).
pub fn parse_name(name: &str) -> Option<[f64; 4]> {
    let base = name.rsplit(['/', '\\']).next().unwrap_or(name);
    let stem = base.rsplit_once('.').map_or(base, |(s, _)| s);
    let mut found = [None; 4];
    for tok in stem.split(['_', '-']) {
        let lower = tok.to_ascii_lowercase();
        for (k, pre) in ["tl", "pl", "tv", "pv"].iter().enumerate() {
            if let Some(num) = lower.strip_prefix(pre) {
                if let Ok(v) = num.parse::<f64>() {
                    if v.is_finite() && !num.is_empty() && num.chars().next().is_some_and(|c| c.is_ascii_digit()) {
                        found[k] = Some(v);
                    }
                }
            }
        }
    }
    Some([found[0]?, found[1]?, found[2]?, found[3]?])
}

/// The direction of a UBO (theta, phi) in btfrs's frame (see the module doc).
pub fn direction(theta_deg: f64, phi_deg: f64) -> [f64; 3] {
    let d = from_angles(theta_deg, phi_deg);
    // Snap the tiny x/y of theta = 0 to exactly the normal, so that all phi of the pole group.
    if theta_deg == 0.0 {
        [0.0, 0.0, 1.0]
    } else {
        d
    }
}

fn by_theta_phi(a: &[f64; 3], b: &[f64; 3]) -> std::cmp::Ordering {
    let tp = |d: &[f64; 3]| {
        let t = d[2].clamp(-1.0, 1.0).acos().to_degrees();
        let p = d[1].atan2(d[0]).to_degrees().rem_euclid(360.0);
        // Angles come from names with at most a few decimals: compare at 1e-6 degrees.
        ((t * 1e6).round() as i64, if t < 1e-9 { 0 } else { (p * 1e6).round() as i64 })
    };
    tp(a).cmp(&tp(b))
}

/// Open a UBO2003 / ATRIUM archive (`.zip`) or folder. Every image must have the four angles in
/// its name (an error names the first that does not); other files are ignored. The selection's
/// indices refer to the views and lights sorted by (theta, phi). `transfer` applies to JPEG and
/// PNG images (EXR is linear).
pub fn open(path: &Path, sel: &Selection, transfer: Transfer) -> Result<ImageStack> {
    open_limited(path, sel, transfer, &Limits::default())
}

/// [`open`] within `limits` (every image's decode, and a zip entry's declared size, bounded).
pub fn open_limited(path: &Path, sel: &Selection, transfer: Transfer, limits: &Limits) -> Result<ImageStack> {
    let shown = path.display().to_string();
    let store = if path.is_dir() {
        Store::Folder(path.to_path_buf())
    } else if path.is_file() {
        Store::Zip(path.to_path_buf())
    } else {
        return Err(Error::io(&shown, std::io::Error::from(std::io::ErrorKind::NotFound)));
    };
    let names = store.list_images()?;
    if names.is_empty() {
        return Err(Error::format(
            &shown,
            "holds no images (expected .jpg, .png or .exr files named like name_tl015_pl000_tv015_pv120.jpg)",
        ));
    }
    let mut members = Vec::with_capacity(names.len());
    for n in names {
        if let Store::Folder(d) = &store {
            if !limits.allow_outside && !crate::stack::inside(d, &d.join(&n)) {
                return Err(Error::format(
                    store.shown(&n),
                    "is a link to a file outside the capture's folder; expected the images inside it \
                     (pass allow_outside=True to read it anyway)",
                ));
            }
        }
        let [tl, pl, tv, pv] = parse_name(&n).ok_or_else(|| {
            Error::format(
                store.shown(&n),
                "the name lacks light and view angles; expected tl<theta>_pl<phi>_tv<theta>_pv<phi> in degrees, e.g. \
                 _tl015_pl000_tv015_pv120 (a plain image stack needs a direction table: directions=)",
            )
        })?;
        for (what, t) in [("tl", tl), ("tv", tv)] {
            if !(0.0..=90.0).contains(&t) {
                return Err(Error::format(store.shown(&n), format!("{what}{t}: expected a theta of 0 to 90 degrees")));
            }
        }
        members.push(Member { name: n, view: direction(tv, pv), light: direction(tl, pl), at: String::new() });
    }
    let meta = serde_json::json!({"format": "ubo2003", "source": shown});
    ImageStack::new_limited(store, members, sel, transfer, Some(by_theta_phi), meta, limits)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_parse_with_and_without_decimals() {
        assert_eq!(parse_name("WoolPKNT256_00084_tl015_pl000_tv015_pv120.jpg"), Some([15.0, 0.0, 15.0, 120.0]));
        assert_eq!(parse_name("dir/x_tv60_pv7.5_tl75_pl345.exr"), Some([75.0, 345.0, 60.0, 7.5]));
        assert_eq!(parse_name("x_tl015_pl000_tv015.jpg"), None);
        assert_eq!(parse_name("plain.jpg"), None);
    }

    #[test]
    fn directions_follow_the_frame() {
        let d = direction(90.0, 0.0);
        assert!((d[0] - 1.0).abs() < 1e-12 && d[1].abs() < 1e-12);
        let d = direction(90.0, 90.0);
        assert!((d[1] - 1.0).abs() < 1e-12 && d[0].abs() < 1e-12);
        assert_eq!(direction(0.0, 120.0), [0.0, 0.0, 1.0]);
    }
}
