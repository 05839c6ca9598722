//! A texton analysis as named arrays: the layout an `analysis` container stores, defined here
//! beside the analysis (not in the bindings), so a Rust user can save and load one with
//! `btfrs_io::model_file::{save_arrays, load_arrays}`.
//!
//! Per pyramid level `l`: `level{l}.centers` `[T, D]` f32 (texton centres), `level{l}.textons`
//! `[H, W]` u16 (each pixel's texton) and, per window radius `r` that was analysed,
//! `level{l}.similar{r}.index` `[H, W, m]` i32 (flat pixel index, -1 = none) with
//! `level{l}.similar{r}.dist` `[H, W, m]` f32. The options travel beside the arrays.

use crate::analysis::{Analysis, AnalysisOptions, Level, Neighbours, MAX_RADIUS};
use crate::textons::Textons;
use btfrs_core::{NamedArrays, Result};

impl Analysis {
    /// The analysis's arrays (copies), by name.
    pub fn to_arrays(&self) -> NamedArrays {
        let mut a = NamedArrays::new();
        for (l, lv) in self.levels.iter().enumerate() {
            let t = &lv.textons;
            a.put(&format!("level{l}.centers"), &[t.count(), t.dim], t.centers.clone());
            a.put(&format!("level{l}.textons"), &[lv.height, lv.width], t.assign.clone());
            for n in &lv.neighbours {
                let idx: Vec<i32> = n.index.iter().map(|&i| if i == u32::MAX { -1 } else { i as i32 }).collect();
                let shape = [lv.height, lv.width, n.m];
                a.put(&format!("level{l}.similar{}.index", n.radius), &shape, idx);
                a.put(&format!("level{l}.similar{}.dist", n.radius), &shape, n.dist.clone());
            }
        }
        a
    }

    /// Rebuild from [`Analysis::to_arrays`] and the options it was made with, validating every
    /// array and the pyramid ([`Analysis::from_levels`]).
    pub fn from_arrays(a: &NamedArrays, options: AnalysisOptions) -> Result<Self> {
        let mut levels = Vec::new();
        for l in 0.. {
            let key = format!("level{l}.centers");
            if !a.contains(&key) {
                break;
            }
            let (centers, cs) = a.get::<f32>(&key, &[None, None])?;
            let (assign, ts) = a.get::<u16>(&format!("level{l}.textons"), &[None, None])?;
            let textons = Textons::from_parts(cs[1], centers.to_vec(), assign.to_vec())?;
            let mut neighbours = Vec::new();
            for r in 1..=MAX_RADIUS {
                let key = format!("level{l}.similar{r}.index");
                if !a.contains(&key) {
                    continue;
                }
                let (idx, s) = a.get::<i32>(&key, &[Some(ts[0]), Some(ts[1]), Some(options.m)])?;
                let (dist, _) =
                    a.get::<f32>(&format!("level{l}.similar{r}.dist"), &[Some(s[0]), Some(s[1]), Some(s[2])])?;
                let index = idx.iter().map(|&i| if i < 0 { u32::MAX } else { i as u32 }).collect();
                neighbours.push(Neighbours { radius: r, m: options.m, index, dist: dist.to_vec() });
            }
            levels.push(Level { height: ts[0], width: ts[1], textons, neighbours });
        }
        Analysis::from_levels(levels, options)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pyramid::Features;
    use btfrs_core::Monitor;

    #[test]
    fn arrays_round_trip_and_a_wrong_level_is_named() {
        let data = (0..16 * 16 * 2).map(|i| btfrs_core::rng::hash01(7, i as i64, 0) as f32).collect();
        let f = Features::new(16, 16, 2, data).unwrap();
        let opts = AnalysisOptions { textons: 12, levels: 2, m: 3, iterations: 4, seed: 1 };
        let an = Analysis::of_features(f, opts, &[1, 2], &Monitor::new()).unwrap();
        let a = an.to_arrays();
        assert!(a.contains("level0.similar1.index") && a.contains("level1.centers"));
        let back = Analysis::from_arrays(&a, opts).unwrap();
        assert_eq!(back.to_arrays(), a);
        // A level that is not half the previous one: the pyramid check names the array.
        let mut bad = a.clone();
        bad.put("level1.textons", &[5, 8], vec![0u16; 40]);
        let e = Analysis::from_arrays(&bad, opts).unwrap_err().to_string();
        assert!(e.starts_with("level1.") || e.contains("level 1"), "{e}");
        // A wrong dtype is an error naming the array, never a panic.
        let mut bad = a;
        bad.put("level0.centers", &[1], vec![0u8]);
        assert!(Analysis::from_arrays(&bad, opts).unwrap_err().to_string().starts_with("level0.centers"));
    }
}
