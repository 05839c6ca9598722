//! Surfaces from their slopes: Frankot and Chellappa's projection onto integrable surfaces
//! (1988), the least-squares height whose differences best match a slope field, solved in
//! frequency. The same method as `btfrs.height` (python/btfrs/photometric.py), which the tests
//! check this against: the central difference `j sin w` as the derivative (normal maps made from
//! heights by central differences are read back to a few percent of the height's spread), a small
//! curvature penalty near Nyquist, and for surfaces that do not tile, the slopes mirrored at the
//! borders first (an even extension: the Neumann boundary of a Poisson solve).

use rustfft::num_complex::Complex;
use rustfft::FftPlanner;

/// The weight of the curvature penalty: a small price on the second difference, which vanishes
/// at low frequencies and holds near Nyquist, where the central difference cannot see the height.
pub const CURVATURE: f64 = 0.05;

/// How the surface continues beyond its borders.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Boundary {
    /// It tiles (a periodic sample).
    Periodic,
    /// It is mirrored at each border (a capture of a larger surface).
    Mirror,
}

/// A 2D FFT in place over `rows x cols` (row-major), forward or inverse (unnormalised).
fn fft2(data: &mut [Complex<f64>], rows: usize, cols: usize, inverse: bool) {
    use rayon::prelude::*;
    let mut planner = FftPlanner::<f64>::new();
    let (fr, fc) = if inverse {
        (planner.plan_fft_inverse(cols), planner.plan_fft_inverse(rows))
    } else {
        (planner.plan_fft_forward(cols), planner.plan_fft_forward(rows))
    };
    data.par_chunks_mut(cols).for_each(|row| fr.process(row));
    // Columns: through a transposed copy, so each column is contiguous for the FFT.
    let mut t = vec![Complex::new(0.0, 0.0); rows * cols];
    for r in 0..rows {
        for c in 0..cols {
            t[c * rows + r] = data[r * cols + c];
        }
    }
    t.par_chunks_mut(rows).for_each(|col| fc.process(col));
    for c in 0..cols {
        for r in 0..rows {
            data[r * cols + c] = t[c * rows + r];
        }
    }
}

/// The height (mean 0, in the slopes' units of texel widths) whose central differences best
/// match slopes `p` (along x, the columns) and `q` (along y, UP the image: row `r` lies at
/// `y = -r`), both `rows x cols` row-major.
pub fn integrate_slopes(p: &[f64], q: &[f64], rows: usize, cols: usize, boundary: Boundary) -> Vec<f64> {
    assert!(p.len() == rows * cols && q.len() == rows * cols);
    if rows == 0 || cols == 0 {
        return Vec::new();
    }
    // The grid the transform runs on: the slopes themselves, or their even extension (dz/dx
    // flips sign across a vertical mirror, dz/dy does not, and the other way for a horizontal
    // one).
    let (gr, gc) = match boundary {
        Boundary::Periodic => (rows, cols),
        Boundary::Mirror => (2 * rows, 2 * cols),
    };
    let mut pf = vec![Complex::new(0.0, 0.0); gr * gc];
    let mut qf = vec![Complex::new(0.0, 0.0); gr * gc];
    for r in 0..gr {
        for c in 0..gc {
            let (sr, fr) = if r < rows { (r, 1.0) } else { (2 * rows - 1 - r, -1.0) };
            let (sc, fcol) = if c < cols { (c, 1.0) } else { (2 * cols - 1 - c, -1.0) };
            let i = sr * cols + sc;
            pf[r * gc + c] = Complex::new(p[i] * fcol, 0.0);
            qf[r * gc + c] = Complex::new(q[i] * fr, 0.0);
        }
    }
    fft2(&mut pf, gr, gc, false);
    fft2(&mut qf, gr, gc, false);
    let freq = |i: usize, n: usize| {
        let k = if i <= (n - 1) / 2 { i as f64 } else { i as f64 - n as f64 };
        2.0 * std::f64::consts::PI * k / n as f64
    };
    for r in 0..gr {
        let wy = freq(r, gr);
        // y up the image: d/dy = -d/drow, so the y derivative is -j sin(wy).
        let dy = Complex::new(0.0, -wy.sin());
        for c in 0..gc {
            let wx = freq(c, gc);
            let dx = Complex::new(0.0, wx.sin());
            let i = r * gc + c;
            let den = dx.norm_sqr() + dy.norm_sqr() + CURVATURE * ((1.0 - wx.cos()).powi(2) + (1.0 - wy.cos()).powi(2));
            pf[i] = if i == 0 { Complex::new(0.0, 0.0) } else { (dx.conj() * pf[i] + dy.conj() * qf[i]) / den };
        }
    }
    fft2(&mut pf, gr, gc, true);
    let n = (gr * gc) as f64;
    let mut z: Vec<f64> = (0..rows * cols).map(|i| pf[(i / cols) * gc + i % cols].re / n).collect();
    let mean = z.iter().sum::<f64>() / z.len() as f64;
    z.iter_mut().for_each(|x| *x -= mean);
    z
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Slopes of `z` by central differences (x right, y up), wrapping or mirroring at borders.
    fn slopes(z: &[f64], rows: usize, cols: usize, periodic: bool) -> (Vec<f64>, Vec<f64>) {
        let at = |r: isize, c: isize| {
            let (r, c) = if periodic {
                (r.rem_euclid(rows as isize) as usize, c.rem_euclid(cols as isize) as usize)
            } else {
                (r.clamp(0, rows as isize - 1) as usize, c.clamp(0, cols as isize - 1) as usize)
            };
            z[r * cols + c]
        };
        let mut p = vec![0.0; rows * cols];
        let mut q = vec![0.0; rows * cols];
        for r in 0..rows as isize {
            for c in 0..cols as isize {
                let i = r as usize * cols + c as usize;
                p[i] = (at(r, c + 1) - at(r, c - 1)) / 2.0;
                q[i] = -(at(r + 1, c) - at(r - 1, c)) / 2.0;
            }
        }
        (p, q)
    }

    fn spread_error(a: &[f64], b: &[f64]) -> f64 {
        let ma = a.iter().sum::<f64>() / a.len() as f64;
        let mb = b.iter().sum::<f64>() / b.len() as f64;
        let err = a.iter().zip(b).map(|(x, y)| ((x - ma) - (y - mb)).abs()).fold(0.0, f64::max);
        let spread = b.iter().cloned().fold(f64::MIN, f64::max) - b.iter().cloned().fold(f64::MAX, f64::min);
        err / spread
    }

    #[test]
    fn periodic_surface_is_recovered_from_its_central_differences() {
        let (rows, cols) = (24, 40);
        let z: Vec<f64> = (0..rows * cols)
            .map(|i| {
                let (r, c) = ((i / cols) as f64, (i % cols) as f64);
                3.0 * (2.0 * std::f64::consts::PI * c / cols as f64).sin()
                    + 2.0 * (2.0 * std::f64::consts::PI * 2.0 * r / rows as f64).cos()
            })
            .collect();
        let (p, q) = slopes(&z, rows, cols, true);
        let back = integrate_slopes(&p, &q, rows, cols, Boundary::Periodic);
        // Low frequencies: the curvature penalty costs a fraction of a percent there.
        assert!(spread_error(&back, &z) < 0.01, "{}", spread_error(&back, &z));
    }

    #[test]
    fn mirrored_integration_recovers_a_slope_that_does_not_tile() {
        // A tilted plane plus a bump: periodic integration cannot hold the tilt, the mirrored
        // one can.
        let (rows, cols) = (32, 48);
        let z: Vec<f64> = (0..rows * cols)
            .map(|i| {
                let (r, c) = ((i / cols) as f64, (i % cols) as f64);
                0.3 * c - 0.2 * r + 4.0 * (-((c - 20.0).powi(2) + (r - 14.0).powi(2)) / 30.0).exp()
            })
            .collect();
        let (p, q) = slopes(&z, rows, cols, false);
        let mirrored = integrate_slopes(&p, &q, rows, cols, Boundary::Mirror);
        let periodic = integrate_slopes(&p, &q, rows, cols, Boundary::Periodic);
        let (em, ep) = (spread_error(&mirrored, &z), spread_error(&periodic, &z));
        assert!(em < 0.05 && ep > 4.0 * em, "mirror {em}, periodic {ep}");
    }
}
