//! Accuracy metrics with f64 accumulation.
//!
//! The two accuracy figures (reconstruction and held-out; BENCHMARKS.md, "How accuracy is
//! measured") are both computed with [`ErrorSums`]: sums of squared error and squared ground
//! truth, merged across threads, then turned into RMSE, relative L2 error `||pred - gt|| / ||gt||`
//! and PSNR.

/// Running sums for one comparison.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ErrorSums {
    /// Sum of (pred - gt)^2.
    pub sse: f64,
    /// Sum of gt^2.
    pub sgt: f64,
    /// Number of values compared.
    pub n: u64,
    /// Largest ground-truth value seen (the PSNR peak).
    pub peak: f64,
}

impl ErrorSums {
    /// Add one pair of values.
    #[inline]
    pub fn add(&mut self, pred: f64, gt: f64) {
        let d = pred - gt;
        self.sse += d * d;
        self.sgt += gt * gt;
        self.n += 1;
        if gt > self.peak {
            self.peak = gt;
        }
    }

    /// Combine two partial sums.
    pub fn merge(self, o: ErrorSums) -> ErrorSums {
        ErrorSums { sse: self.sse + o.sse, sgt: self.sgt + o.sgt, n: self.n + o.n, peak: self.peak.max(o.peak) }
    }

    /// Root mean squared error.
    pub fn rmse(&self) -> f64 {
        if self.n == 0 {
            f64::NAN
        } else {
            (self.sse / self.n as f64).sqrt()
        }
    }

    /// Relative L2 error; 0 for a perfect match of all-zero data.
    pub fn relative(&self) -> f64 {
        if self.sgt == 0.0 {
            if self.sse == 0.0 {
                0.0
            } else {
                f64::INFINITY
            }
        } else {
            (self.sse / self.sgt).sqrt()
        }
    }

    /// Peak signal-to-noise ratio in dB against the largest ground-truth value.
    pub fn psnr(&self) -> f64 {
        let mse = self.sse / self.n.max(1) as f64;
        if mse == 0.0 {
            f64::INFINITY
        } else {
            10.0 * (self.peak * self.peak / mse).log10()
        }
    }
}

/// Sums over two equally long slices.
pub fn compare(pred: &[f32], gt: &[f32]) -> ErrorSums {
    let mut s = ErrorSums::default();
    for (&p, &g) in pred.iter().zip(gt) {
        s.add(p as f64, g as f64);
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn closed_form_values() {
        let s = compare(&[1.0, 2.0, 3.0, 5.0], &[1.0, 2.0, 3.0, 4.0]);
        assert!((s.rmse() - 0.5).abs() < 1e-12);
        assert!((s.relative() - 1.0 / 30f64.sqrt()).abs() < 1e-12);
        assert!((s.psnr() - 10.0 * (16.0f64 / 0.25).log10()).abs() < 1e-12);
        let half = compare(&[1.0, 2.0], &[1.0, 2.0]).merge(compare(&[3.0, 5.0], &[3.0, 4.0]));
        assert_eq!(half, s);
    }
}
