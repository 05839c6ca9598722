//! RTI capture sets: photographs of one view under many lights, listed by a `.lp` file.
//!
//! An `.lp` file's first line is the number of images; each further line is
//! `filename lx ly lz`, the light direction of that photograph with x to the right of the image,
//! y *up* the image and z towards the camera (the RTIBuilder / relight convention). That is
//! btfrs's tangent frame, so the vectors are used as they are, normalised. A light a hair below
//! the horizon (its unit z at least minus [`crate::untrusted::HORIZON_TOLERANCE`], as a dome's
//! calibration gives for its lowest ring) is moved onto it (z = 0, renormalised); one further
//! below is refused, naming its line. Each kind of repair is reported in one summary warning
//! for the whole file in `meta.warnings` (how many, the range of the lengths or of z, the first
//! lines; `btfrs.io.load` shows them as warnings). The view is the normal. The file is read as
//! [`crate::untrusted`] reads a light list (at most [`crate::untrusted::MAX_LP`] bytes, UTF-8). File names may be absolute, relative to the `.lp` file, or (as written on
//! another machine) a path whose last component is found beside the `.lp` file; names may
//! contain spaces (the three numbers are read from the end of the line).
//!
//! relight's `.dome` files are not read: they hold the light geometry of a dome (positions,
//! diameter, offsets) but no image names, so they do not describe a capture on their own.

use crate::capture::{Limits, Selection};
use crate::decode::Transfer;
use crate::stack::{ImageStack, Member, Store};
use btfrs_core::{Error, Result};
use std::path::{Path, PathBuf};

/// One line of an `.lp` file.
#[derive(Debug, Clone, PartialEq)]
pub struct LpEntry {
    /// The file name as written.
    pub name: String,
    /// The light vector as written.
    pub light: [f64; 3],
    /// Its line in the file (from 1).
    pub line: usize,
}

/// Parse the text of an `.lp` file (`shown` names it in errors).
pub fn parse_lp(text: &str, shown: &str) -> Result<Vec<LpEntry>> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut lines = text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty() && !l.trim_start().starts_with('#'));
    let (_, first) =
        lines.next().ok_or_else(|| Error::format(shown, "is empty; expected the image count on the first line"))?;
    let count: usize = first
        .split_whitespace()
        .next()
        .and_then(|t| t.parse().ok())
        .ok_or_else(|| Error::format(shown, format!("first line {first:?}: expected the number of images")))?;
    let mut out = Vec::with_capacity(count.min(1 << 16));
    for (i, line) in lines {
        let toks: Vec<&str> = line.split_whitespace().collect();
        let bad = || Error::format(shown, format!("line {}: expected `filename lx ly lz`, got {line:?}", i + 1));
        if toks.len() < 4 {
            return Err(bad());
        }
        let n = toks.len();
        let num = |t: &str| t.parse::<f64>().ok().filter(|x| x.is_finite());
        let (x, y, z) = match (num(toks[n - 3]), num(toks[n - 2]), num(toks[n - 1])) {
            (Some(x), Some(y), Some(z)) => (x, y, z),
            _ => return Err(bad()),
        };
        if !(x * x + y * y + z * z).is_finite() {
            return Err(Error::format(
                shown,
                format!(
                    "line {}: light ({x}, {y}, {z}) is too large (its length overflows); expected a direction",
                    i + 1
                ),
            ));
        }
        // The name is everything before the numbers, spaces kept as written.
        let name = line.trim_start();
        let mut rest = name;
        for t in toks[n - 3..].iter().rev() {
            rest = rest.trim_end().strip_suffix(t).unwrap_or(rest);
        }
        out.push(LpEntry { name: rest.trim().to_string(), light: [x, y, z], line: i + 1 });
    }
    if out.len() != count {
        return Err(Error::format(shown, format!("declares {count} images on its first line but lists {}", out.len())));
    }
    Ok(out)
}

/// Where an `.lp` line's file is.
enum Found {
    /// The file.
    At(PathBuf),
    /// An existing file outside the folder (refused unless allowed).
    Outside(PathBuf),
    /// Nothing.
    Missing,
}

/// Find the file an `.lp` line names (see the module doc): as written (absolute, or relative
/// to the `.lp` file's folder) when it lies inside that folder (symlinks resolved) or
/// `allow_outside`; else (a path written on another machine) its last component beside the
/// `.lp` file.
fn resolve(dir: &Path, name: &str, allow_outside: bool) -> Found {
    let as_written = dir.join(name); // an absolute `name` replaces `dir`
    let mut outside = None;
    // Present, whatever it is: a FIFO or device is refused by name when read, never skipped.
    let exists = |p: &Path| crate::untrusted::present(p) && !p.is_dir();
    if exists(&as_written) {
        if allow_outside || crate::stack::inside(dir, &as_written) {
            return Found::At(as_written);
        }
        outside = Some(as_written);
    }
    let base = name.rsplit(['/', '\\']).next().unwrap_or(name);
    let beside = dir.join(base);
    if outside.is_none() && !base.is_empty() && exists(&beside) {
        if allow_outside || crate::stack::inside(dir, &beside) {
            return Found::At(beside);
        }
        outside = Some(beside);
    }
    outside.map_or(Found::Missing, Found::Outside)
}

/// Open an RTI capture set from its `.lp` file. The selection's `lights` index the `.lp` lines
/// in order; there is one view (the normal).
pub fn open_lp(path: &Path, sel: &Selection, transfer: Transfer) -> Result<ImageStack> {
    open_lp_limited(path, sel, transfer, &Limits::default())
}

/// [`open_lp`] within `limits`: image paths must stay in the `.lp` file's folder unless
/// `limits.allow_outside`, and every decode is bounded (see [`Limits`]).
pub fn open_lp_limited(path: &Path, sel: &Selection, transfer: Transfer, limits: &Limits) -> Result<ImageStack> {
    let shown = path.display().to_string();
    let text = crate::untrusted::read_text(path, crate::untrusted::LIGHT_LIST, limits.max_bytes)?;
    let entries = parse_lp(&text, &shown)?;
    let dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
    let dir = if dir.as_os_str().is_empty() { PathBuf::from(".") } else { dir };
    let mut warnings = Vec::new();
    let mut lights = crate::untrusted::Directions::new(&shown, "light", "line(s)");
    let mut members = Vec::with_capacity(entries.len());
    for e in &entries {
        let line = e.line;
        let file = match resolve(&dir, &e.name, limits.allow_outside) {
            Found::At(f) => f,
            Found::Missing => {
                return Err(Error::format(
                    &shown,
                    format!("line {line} names {:?}, which is not found (looked beside the .lp file too)", e.name),
                ))
            }
            Found::Outside(f) => {
                return Err(Error::format(
                    &shown,
                    format!(
                        "line {line} names {:?} ({}), which lies outside the capture's folder {}; expected a path \
                         inside it (pass allow_outside=True to read it anyway)",
                        e.name,
                        f.display(),
                        dir.display()
                    ),
                ))
            }
        };
        let [x, y, z] = e.light;
        let light = lights.unit(line, e.light).ok_or_else(|| {
            Error::format(
                &shown,
                format!(
                    "line {line}: light ({x}, {y}, {z}) is not a direction above the surface (a light at most {} \
                     below the horizon, as unit z, is read as on it)",
                    crate::untrusted::HORIZON_TOLERANCE
                ),
            )
        })?;
        members.push(Member {
            name: file.display().to_string(),
            view: [0.0, 0.0, 1.0],
            light,
            at: format!("line {line}"),
        });
    }
    lights.report(&mut warnings);
    let meta = serde_json::json!({"format": "rti-lp", "source": shown, "warnings": warnings});
    ImageStack::new_limited(Store::Folder(PathBuf::new()), members, sel, transfer, None, meta, limits)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lp_lines_parse_names_with_spaces_and_count_is_checked() {
        let t = "3\nimg 1.jpg 0.1 0.2 0.97\nC:\\caps\\img2.jpg -0.5 0 0.866\n/abs/p.png 0 0 1\n";
        let e = parse_lp(t, "a.lp").unwrap();
        assert_eq!(e[0].name, "img 1.jpg");
        assert_eq!(e[1].name, "C:\\caps\\img2.jpg");
        assert_eq!(e[1].light, [-0.5, 0.0, 0.866]);
        let err = parse_lp("4\na.jpg 0 0 1\n", "a.lp").unwrap_err().to_string();
        assert!(err.contains("declares 4") && err.contains("lists 1"), "{err}");
        assert!(parse_lp("2\na.jpg 0 x 1\n", "a.lp").unwrap_err().to_string().contains("line 2"));
        assert!(parse_lp("", "a.lp").unwrap_err().to_string().contains("empty"));
    }
}
