//! Train/test splits over (view, light) pairs.
//!
//! The split is two masks over the same data: nothing is copied, and the test half is exactly the
//! pairs the training half does not contain (BENCHMARKS.md, "How accuracy is measured").

use crate::{rng::Rng, Error, Result};

/// Split the present pairs of a `[V, L]` grid (all of them when `mask` is `None`) into
/// `(train, test)` masks; `test` holds `round(holdout * present)` pairs drawn without replacement
/// with `seed`. `holdout` must lie in (0, 1) and leave at least one pair on each side.
pub fn split_pairs(
    n_views: usize,
    n_lights: usize,
    mask: Option<&[bool]>,
    holdout: f64,
    seed: u64,
) -> Result<(Vec<bool>, Vec<bool>)> {
    if !(holdout > 0.0 && holdout < 1.0) {
        return Err(Error::arg("holdout", format!("expected a fraction in (0, 1), got {holdout}")));
    }
    let n = n_views * n_lights;
    if let Some(m) = mask {
        if m.len() != n {
            return Err(Error::arg("mask", format!("expected {n} entries, got {}", m.len())));
        }
    }
    let mut present: Vec<usize> = (0..n).filter(|&i| mask.is_none_or(|m| m[i])).collect();
    let k = (holdout * present.len() as f64).round() as usize;
    if k == 0 || k >= present.len() {
        return Err(Error::arg(
            "holdout",
            format!("{holdout} of {} pairs leaves an empty train or test set", present.len()),
        ));
    }
    // Partial Fisher-Yates: the first k entries become a uniform random k-subset.
    let mut rng = Rng::new(seed);
    for i in 0..k {
        let j = i + rng.below(present.len() - i);
        present.swap(i, j);
    }
    let mut test = vec![false; n];
    for &i in &present[..k] {
        test[i] = true;
    }
    let train = (0..n).map(|i| mask.is_none_or(|m| m[i]) && !test[i]).collect();
    Ok((train, test))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn split_partitions_the_pairs() {
        let (tr, te) = split_pairs(81, 81, None, 0.1, 3).unwrap();
        let nt = te.iter().filter(|&&b| b).count();
        assert_eq!(nt, 656);
        assert!(tr.iter().zip(&te).all(|(a, b)| a ^ b));
        let (_, te2) = split_pairs(81, 81, None, 0.1, 3).unwrap();
        assert_eq!(te, te2);
        let (_, te3) = split_pairs(81, 81, None, 0.1, 4).unwrap();
        assert_ne!(te, te3);
        // Splitting the train half again never touches the held-out pairs.
        let (tr2, te4) = split_pairs(81, 81, Some(&tr), 0.5, 1).unwrap();
        assert!((0..81 * 81).all(|i| !(te[i] && (tr2[i] || te4[i]))));
    }

    #[test]
    fn bad_holdout_is_rejected() {
        assert!(split_pairs(2, 2, None, 0.0, 0).is_err());
        assert!(split_pairs(2, 2, None, 1.0, 0).is_err());
        assert!(split_pairs(2, 2, None, f64::NAN, 0).is_err());
        assert!(split_pairs(2, 2, None, 0.01, 0).unwrap_err().to_string().contains("empty"));
    }
}
