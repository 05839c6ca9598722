//! Writing an `.lp` file: the light directions of a capture as relight, RTIBuilder and btfrs
//! read them.
//!
//! The first line is the number of photographs and nothing else (relight reads the whole line
//! as one integer); each further line is `filename lx ly lz`, the light direction in btfrs's
//! frame, which is the `.lp` convention (x right, y up the image, z towards the camera).
//! relight splits a line at white space and wants exactly four fields, so a file name with a
//! space is written (btfrs reads it) but will not load there; the caller warns. The file is
//! written atomically (temporary file and rename): an error leaves no partial `.lp`.

use btfrs_core::{Error, Result};
use std::path::Path;

/// Write `entries` (file name as it goes into the file, unit light direction) to `path`.
pub fn write_lp(path: &Path, entries: &[(String, [f64; 3])]) -> Result<()> {
    let shown = path.display().to_string();
    if entries.is_empty() {
        return Err(Error::arg("lights", format!("{shown}: no light to write; expected at least one")));
    }
    for (name, l) in entries {
        if name.is_empty() || name.contains(['\n', '\r']) {
            return Err(Error::arg("names", format!("{name:?} cannot be written on one line of {shown}")));
        }
        let n = (l[0] * l[0] + l[1] * l[1] + l[2] * l[2]).sqrt();
        if !l.iter().all(|v| v.is_finite()) || (n - 1.0).abs() > 1e-6 {
            return Err(Error::arg("lights", format!("{name}: {l:?} is not a unit direction")));
        }
    }
    btfrs_io::atomic::write_atomic(path, |w| {
        writeln!(w, "{}", entries.len())?;
        for (name, l) in entries {
            writeln!(w, "{name} {:.6} {:.6} {:.6}", l[0], l[1], l[2])?;
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn written_lp_reads_back_with_btfrs_io_and_the_format_is_relights() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("dirs.lp");
        let l = [0.6f64, -0.0, 0.8];
        let entries = vec![("a.jpg".to_string(), l), ("b.jpg".to_string(), [0.0, 0.0, 1.0])];
        write_lp(&p, &entries).unwrap();
        let text = std::fs::read_to_string(&p).unwrap();
        assert_eq!(text.lines().next(), Some("2"));
        // Four fields a line, as relight splits them.
        assert!(text.lines().skip(1).all(|line| line.split_whitespace().count() == 4), "{text}");
        let back = btfrs_io::rti::parse_lp(&text, "dirs.lp").unwrap();
        assert_eq!(back.len(), 2);
        assert_eq!(back[0].name, "a.jpg");
        assert!((0..3).all(|k| (back[0].light[k] - l[k]).abs() < 1e-6));
        // Refused before anything is written: no lights, a name across lines, not a unit vector.
        let q = dir.path().join("bad.lp");
        assert!(write_lp(&q, &[]).is_err());
        assert!(write_lp(&q, &[("a\nb.jpg".into(), l)]).is_err());
        assert!(write_lp(&q, &[("a.jpg".into(), [1.0, 1.0, 1.0])]).is_err());
        assert!(!q.exists());
    }
}
