//! Centred principal component analysis of a set of vectors: the mean, the top principal
//! directions and every vector's coefficients, exact (`f64` eigenvectors of the covariance, or
//! of the Gram matrix when there are fewer vectors than values) up to a size the caller chooses,
//! the randomized subspace iteration of [`crate::rpca`] above.

use crate::dense::{column_mean, gemm, sym_eigen_desc, view, view_t};
use nalgebra::DMatrix;

/// Centred PCA of the `t` columns (each `d` values) of the column-major `data`: the mean (`d`),
/// `k` orthonormal principal directions (`d x k`, zero columns where the data have fewer
/// directions: eigenvalues at most `1e-12` of the largest are dropped) and the coefficients
/// (`k x t`). Exact for `d <= exact_max` (from the `t x t` Gram matrix when there are fewer
/// vectors than values, the same directions at a smaller eigenproblem), randomized subspace
/// iteration ([`crate::rpca::top_directions`], seeded by `seed`) above. The caller checks the
/// coefficients for non-finite values (data too large for `f32` products).
pub fn centred(
    data: &[f32],
    d: usize,
    t: usize,
    k: usize,
    seed: u64,
    exact_max: usize,
) -> (Vec<f32>, DMatrix<f32>, DMatrix<f32>) {
    let mut basis = DMatrix::<f32>::zeros(d, k);
    if k == 0 {
        return (column_mean(data, d, None), basis, DMatrix::zeros(0, t));
    }
    let mean = column_mean(data, d, None);
    let mut xc = DMatrix::<f32>::from_column_slice(d, t, data);
    xc.column_iter_mut().for_each(|mut c| c.iter_mut().zip(&mean).for_each(|(x, m)| *x -= m));
    let dirs: DMatrix<f32> = if t < d && t <= exact_max {
        // Fewer texels than values per vector (a small sample): the same directions from the
        // smaller `t x t` eigenproblem of the Gram matrix, `u_j = Xc v_j / sqrt(lambda_j)`.
        // Exact like the covariance path, and the eigensolver's cubic cost falls from d^3 to t^3
        // (RBF at resolution 12 on 16^2 texels: 432^3 -> 256^3 per view slot).
        let g32 = gemm(&view_t(&xc), &view(&xc));
        let g = DMatrix::<f64>::from_fn(t, t, |i, j| 0.5 * (g32[(i, j)] as f64 + g32[(j, i)] as f64));
        let (vals, vecs) = sym_eigen_desc(g);
        let top = vals.first().copied().unwrap_or(0.0);
        let keep = (0..k.min(t)).take_while(|&j| top > 0.0 && vals[j] > 1e-12 * top).count();
        let v = DMatrix::<f32>::from_fn(t, keep, |i, j| (vecs[(i, j)] / vals[j].sqrt()) as f32);
        let u = gemm(&view(&xc), &view(&v));
        // Re-normalise in f64: the f32 products leave the columns a little off unit length.
        // Each column's norm once (found per value, it was half of a small RBF fit's time).
        let norms: Vec<f64> = (0..keep)
            .map(|j| u.column(j).iter().map(|&x| (x as f64).powi(2)).sum::<f64>().sqrt().max(1e-300))
            .collect();
        DMatrix::from_fn(d, keep, |i, j| (u[(i, j)] as f64 / norms[j]) as f32)
    } else if d <= exact_max {
        let c32 = gemm(&view(&xc), &view_t(&xc));
        let c = DMatrix::<f64>::from_fn(d, d, |i, j| 0.5 * (c32[(i, j)] as f64 + c32[(j, i)] as f64));
        let (vals, vecs) = sym_eigen_desc(c);
        let top = vals.first().copied().unwrap_or(0.0);
        let keep = (0..k.min(d)).take_while(|&j| top > 0.0 && vals[j] > 1e-12 * top).count();
        DMatrix::from_fn(d, keep, |i, j| vecs[(i, j)] as f32)
    } else {
        crate::rpca::top_directions(&xc, k, seed, 1e-12)
    };
    let keep = dirs.ncols().min(k);
    basis.columns_mut(0, keep).copy_from(&dirs.columns(0, keep));
    let coeffs = gemm(&view_t(&basis), &view(&xc));
    (mean, basis, coeffs)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The exact limit of the tests (the light bases' own).
    const EXACT: usize = 768;

    #[test]
    fn pca_matches_a_float64_svd_reference() {
        // Data of rank 3 plus small noise; the exact path against nalgebra's f64 SVD of the centred
        // data: the same subspace (principal angles ~ 0) and the same reconstruction.
        let (d, t, k) = (40, 300, 3);
        let mut rng = btfrs_core::rng::Rng::new(5);
        let f = DMatrix::<f64>::from_fn(d, k, |_, _| rng.next_f64() - 0.5);
        let a = DMatrix::<f64>::from_fn(k, t, |i, _| (rng.next_f64() - 0.5) * (3.0 - i as f64));
        let x = &f * &a + DMatrix::<f64>::from_fn(d, t, |_, _| 1e-3 * (rng.next_f64() - 0.5));
        let data: Vec<f32> = x.iter().map(|&v| v as f32).collect();
        let (mean, basis, coeffs) = centred(&data, d, t, k, 0, EXACT);
        let mu = x.column_mean();
        let xc = DMatrix::from_fn(d, t, |i, j| x[(i, j)] - mu[i]);
        let svd = xc.clone().svd(true, false);
        let mut order: Vec<usize> = (0..svd.singular_values.len()).collect();
        order.sort_by(|&i, &j| svd.singular_values[j].total_cmp(&svd.singular_values[i]));
        let u = svd.u.unwrap();
        let uk = DMatrix::from_fn(d, k, |i, j| u[(i, order[j])]);
        let b64 = DMatrix::from_fn(d, k, |i, j| basis[(i, j)] as f64);
        // |U_k^T B| has singular values cos(principal angles): all ~ 1.
        let cos = (uk.transpose() * &b64).svd(false, false).singular_values;
        assert!(cos.iter().all(|&c| c > 1.0 - 1e-6), "{cos}");
        for i in 0..d {
            assert!((mean[i] as f64 - mu[i]).abs() < 1e-5);
        }
        let rec = &b64 * DMatrix::from_fn(k, t, |i, j| coeffs[(i, j)] as f64);
        let ref_rec = &uk * (uk.transpose() * &xc);
        assert!((rec - ref_rec).abs().max() < 1e-4);
        // The randomized path (long vectors) agrees on data above the exact limit.
        let d2 = EXACT + 40;
        let f2 = DMatrix::<f64>::from_fn(d2, k, |_, _| rng.next_f64() - 0.5);
        let x2 = &f2 * &a;
        let data2: Vec<f32> = x2.iter().map(|&v| v as f32).collect();
        let (_, b2, c2) = centred(&data2, d2, t, k, 0, EXACT);
        let mu2 = x2.column_mean();
        let rec2 = DMatrix::from_fn(d2, k, |i, j| b2[(i, j)] as f64) * DMatrix::from_fn(k, t, |i, j| c2[(i, j)] as f64);
        let err =
            (0..d2).flat_map(|i| (0..t).map(move |j| (i, j))).map(|(i, j)| (rec2[(i, j)] + mu2[i] - x2[(i, j)]).abs());
        assert!(err.fold(0.0, f64::max) < 1e-3);
    }

    #[test]
    fn pca_of_fewer_vectors_than_dimensions_matches_a_float64_svd_reference() {
        // t < d takes the Gram-matrix path: the same subspace and reconstruction as the f64 SVD.
        let (d, t, k) = (120, 30, 4);
        let mut rng = btfrs_core::rng::Rng::new(9);
        let f = DMatrix::<f64>::from_fn(d, k, |_, _| rng.next_f64() - 0.5);
        let a = DMatrix::<f64>::from_fn(k, t, |i, _| (rng.next_f64() - 0.5) * (4.0 - i as f64));
        let x = &f * &a + DMatrix::<f64>::from_fn(d, t, |_, _| 1e-3 * (rng.next_f64() - 0.5));
        let data: Vec<f32> = x.iter().map(|&v| v as f32).collect();
        let (_, basis, coeffs) = centred(&data, d, t, k, 0, EXACT);
        let mu = x.column_mean();
        let xc = DMatrix::from_fn(d, t, |i, j| x[(i, j)] - mu[i]);
        let svd = xc.clone().svd(true, false);
        let mut order: Vec<usize> = (0..svd.singular_values.len()).collect();
        order.sort_by(|&i, &j| svd.singular_values[j].total_cmp(&svd.singular_values[i]));
        let u = svd.u.unwrap();
        let uk = DMatrix::from_fn(d, k, |i, j| u[(i, order[j])]);
        let b64 = DMatrix::from_fn(d, k, |i, j| basis[(i, j)] as f64);
        let cos = (uk.transpose() * &b64).svd(false, false).singular_values;
        assert!(cos.iter().all(|&c| c > 1.0 - 1e-6), "{cos}");
        // Orthonormal columns, and the reconstruction of the exact rank-k projection.
        assert!((b64.transpose() * &b64 - DMatrix::<f64>::identity(k, k)).abs().max() < 1e-5);
        let rec = &b64 * DMatrix::from_fn(k, t, |i, j| coeffs[(i, j)] as f64);
        assert!((rec - &uk * (uk.transpose() * &xc)).abs().max() < 1e-4);
    }

    #[test]
    fn pca_pads_missing_directions_with_zeros() {
        // Two texels: at most one direction; the rest are zero columns with zero coefficients.
        let data = vec![1.0f32, 2.0, 3.0, 5.0, 2.0, 1.0];
        let (_, b, c) = centred(&data, 3, 2, 4, 0, EXACT);
        assert_eq!(b.ncols(), 4);
        assert!(b.columns(1, 3).iter().all(|&x| x == 0.0) && c.rows(1, 3).iter().all(|&x| x == 0.0));
        assert!((b.column(0).norm() - 1.0).abs() < 1e-5);
    }
}
