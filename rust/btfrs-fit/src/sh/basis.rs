//! The real orthonormal spherical harmonics that the double-SH model projects every ABRDF on, over
//! the view and over the light direction (paper 002, section 3.1, the "double SH projection"),
//! evaluated by the recurrences of the associated Legendre functions without forming any angle.
//!
//! The WGSL shader of the SH renderer mirrors [`sh_basis`] line by line, so the GPU and the CPU
//! reference evaluate the same basis.

/// Highest supported SH degree per direction.
pub const MAX_DEGREE: usize = 7;
/// Most coefficients per direction, `(MAX_DEGREE + 1)^2`.
pub const MAX_COEFFS: usize = (MAX_DEGREE + 1) * (MAX_DEGREE + 1);

/// The first `n` real orthonormal spherical harmonics at the unit direction `d`, into `out`.
///
/// Index `i = L (L + 1) + M` for degree `L` and order `M` in `[-L, L]`:
///
/// ```text
/// M > 0:  sqrt(2) K_L^M cos(M phi) P_L^M(cos theta)
/// M < 0:  sqrt(2) K_L^|M| sin(|M| phi) P_L^|M|(cos theta)
/// M = 0:  K_L^0 P_L(cos theta)
/// K_L^M = sqrt((2L + 1) / (4 pi) (L - M)! / (L + M)!)
/// ```
///
/// with `P_L^M` the associated Legendre functions *with* the Condon-Shortley phase `(-1)^M`
/// (so `y_1 = -0.4886 y`, `y_2 = 0.4886 z`, `y_3 = -0.4886 x`). No angles are formed: with
/// `s = sin(theta)`, both `P_L^M(z) = s^M Q_L^M(z)` and the azimuthal factor `s^M e^{i M phi}`
/// carry `s^M`, so the product is computed from polynomials in `x`, `y`, `z`:
///
/// * `C_M + i S_M = (x + i y)^M = s^M (cos(M phi) + i sin(M phi))`, by
///   `C_{M+1} = x C_M - y S_M`, `S_{M+1} = x S_M + y C_M`, `C_0 = 1`, `S_0 = 0`;
/// * `Q_M^M = (-1)^M (2M - 1)!!`, `Q_{M+1}^M = (2M + 1) z Q_M^M`,
///   `Q_L^M = ((2L - 1) z Q_{L-1}^M - (L + M - 1) Q_{L-2}^M) / (L - M)`: the standard
///   recurrences of `P_L^M` divided by `s^M`;
/// * `y = sqrt(2) K_L^M Q_L^M C_M` (M > 0), `sqrt(2) K_L^M Q_L^M S_M` (M < 0), `K_L^0 Q_L^0`.
///
/// At most `min(n, 64, out.len())` entries are written (degree <= 7); `n` need not be a perfect
/// square. Plain loops over fixed arrays: the WGSL shader mirrors this function line by line.
pub fn sh_basis(n: usize, d: [f64; 3], out: &mut [f64]) {
    let n = n.min(MAX_COEFFS).min(out.len());
    if n == 0 {
        return;
    }
    let (x, y, z) = (d[0], d[1], d[2]);
    // Smallest degree lmax with (lmax + 1)^2 >= n.
    let mut lmax = 0;
    while (lmax + 1) * (lmax + 1) < n {
        lmax += 1;
    }
    // Azimuthal parts times sin^m(theta): C_m + i S_m = (x + i y)^m.
    let mut cm = [0.0f64; MAX_DEGREE + 1];
    let mut sm = [0.0f64; MAX_DEGREE + 1];
    cm[0] = 1.0;
    for m in 1..=lmax {
        cm[m] = x * cm[m - 1] - y * sm[m - 1];
        sm[m] = x * sm[m - 1] + y * cm[m - 1];
    }
    let mut qmm = 1.0; // Q_m^m = (-1)^m (2m - 1)!!
    for m in 0..=lmax {
        if m > 0 {
            qmm *= -((2 * m - 1) as f64);
        }
        let mut q2 = 0.0; // Q_{l-2}^m
        let mut q1 = 0.0; // Q_{l-1}^m
        for l in m..=lmax {
            let q = if l == m {
                qmm
            } else if l == m + 1 {
                (2 * m + 1) as f64 * z * qmm
            } else {
                ((2 * l - 1) as f64 * z * q1 - (l + m - 1) as f64 * q2) / (l - m) as f64
            };
            q2 = q1;
            q1 = q;
            // K_l^m^2 = (2l + 1) / (4 pi) * (l - m)! / (l + m)!.
            let mut k2 = (2 * l + 1) as f64 / (4.0 * std::f64::consts::PI);
            for f in (l - m + 1)..=(l + m) {
                k2 /= f as f64;
            }
            let center = l * (l + 1);
            if m == 0 {
                if center < n {
                    out[center] = k2.sqrt() * q;
                }
            } else {
                let kq = std::f64::consts::SQRT_2 * k2.sqrt() * q;
                if center + m < n {
                    out[center + m] = kq * cm[m];
                }
                if center - m < n {
                    out[center - m] = kq * sm[m];
                }
            }
        }
    }
}

/// The basis of every direction, `[dirs.len(), n]` row-major.
pub(crate) fn basis_matrix(dirs: &[[f64; 3]], n: usize) -> Vec<f64> {
    let mut y = vec![0.0f64; dirs.len() * n];
    for (row, d) in y.chunks_mut(n).zip(dirs) {
        sh_basis(n, *d, row);
    }
    y
}
