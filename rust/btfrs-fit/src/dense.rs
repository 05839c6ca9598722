//! Small dense linear algebra shared by the clustering fits (k-means, local PCA).
//!
//! Everything here works on **column-major** `f32` matrices whose columns are points (a texel's
//! ABRDF, or its coordinates in a reduced space), which is exactly the texel-major layout of a
//! BTF: the `[T, D]` data seen column-major is a `D x T` matrix with one texel per column, so it
//! is multiplied in place, without a copy. Big products go through nalgebra, whose `f32`/`f64`
//! products on dynamic matrices call the `matrixmultiply` GEMM (any strides, so a transposed view
//! costs nothing); `matrixmultiply` is single-threaded here, so [`gemm`] splits the output into
//! blocks over rayon. Small symmetric eigenproblems are solved in `f64`.

use btfrs_core::rng::Rng;
use nalgebra::{DMatrix, Dyn, MatrixView};
use rayon::prelude::*;

/// A borrowed `f32` matrix with arbitrary strides.
pub(crate) type View<'a> = MatrixView<'a, f32, Dyn, Dyn, Dyn, Dyn>;

/// `rows x cols` column-major matrix over `data` (column `j` is `data[j * rows..(j + 1) * rows]`).
pub(crate) fn cols(data: &[f32], rows: usize, cols: usize) -> View<'_> {
    View::from_slice_with_strides(data, rows, cols, 1, rows.max(1))
}

/// The transpose of the column-major `rows x cols` matrix over `data`, i.e. a `cols x rows` view.
pub(crate) fn cols_t(data: &[f32], rows: usize, cols: usize) -> View<'_> {
    View::from_slice_with_strides(data, cols, rows, rows.max(1), 1)
}

/// A view of an owned matrix.
pub(crate) fn view(m: &DMatrix<f32>) -> View<'_> {
    cols(m.as_slice(), m.nrows(), m.ncols())
}

/// A transposed view of an owned matrix.
pub(crate) fn view_t(m: &DMatrix<f32>) -> View<'_> {
    cols_t(m.as_slice(), m.nrows(), m.ncols())
}

/// Products below this many multiply-adds run on one thread (splitting costs more than it saves).
const PAR_MIN_WORK: usize = 1 << 20;

/// `a * b` with the output split into row or column blocks over rayon.
///
/// Each block is one `matrixmultiply` call whose result does not depend on the number of
/// threads, so the product is deterministic. nalgebra sends products with a dimension of 5 or
/// less to a generic fallback (slow, and unsound with some strided views), so such operands are
/// first copied into zero-padded 6-wide matrices: the copy is as small as the thin dimension.
pub(crate) fn gemm(a: &View<'_>, b: &View<'_>) -> DMatrix<f32> {
    let (m, k) = a.shape();
    let n = b.ncols();
    assert_eq!(k, b.nrows(), "gemm: inner dimensions differ");
    if m == 0 || n == 0 || k == 0 {
        return DMatrix::zeros(m, n);
    }
    const MIN: usize = 6;
    if m < MIN || n < MIN || k < MIN {
        let (mp, kp, np) = (m.max(MIN), k.max(MIN), n.max(MIN));
        let mut ap = DMatrix::<f32>::zeros(mp, kp);
        ap.view_mut((0, 0), (m, k)).copy_from(a);
        let mut bp = DMatrix::<f32>::zeros(kp, np);
        bp.view_mut((0, 0), (k, n)).copy_from(b);
        let c = gemm(&view(&ap), &view(&bp));
        return c.view((0, 0), (m, n)).into_owned();
    }
    let threads = rayon::current_num_threads().max(1);
    if m * n * k < PAR_MIN_WORK || threads == 1 {
        return a * b;
    }
    // Blocks of at least 32 rows or columns (so never below nalgebra's GEMM threshold).
    let split = |len: usize| -> Vec<(usize, usize)> {
        let nb = (2 * threads).min(len / 32).max(1);
        (0..nb).map(|b| (b * len / nb, (b + 1) * len / nb - b * len / nb)).collect()
    };
    let mut out = DMatrix::<f32>::zeros(m, n);
    if m >= n {
        // Row bands of the output (strided in column-major), assembled afterwards.
        let parts: Vec<(usize, DMatrix<f32>)> =
            split(m).into_par_iter().map(|(i0, len)| (i0, a.rows(i0, len) * b)).collect();
        for (i0, p) in parts {
            out.rows_mut(i0, p.nrows()).copy_from(&p);
        }
    } else {
        // Column ranges of the output: contiguous, written in place.
        let blocks = split(n);
        let mut rest = out.as_mut_slice();
        let mut chunks = Vec::with_capacity(blocks.len());
        for &(j0, len) in &blocks {
            let (head, tail) = rest.split_at_mut(len * m);
            chunks.push((j0, len, head));
            rest = tail;
        }
        chunks.into_par_iter().for_each(|(j0, len, chunk)| {
            let p = a * b.columns(j0, len);
            chunk.copy_from_slice(p.as_slice());
        });
    }
    out
}

/// Per-row means of a column-major `rows x n` matrix over the given columns (all when `None`),
/// accumulated in `f64` in column order (deterministic).
pub(crate) fn column_mean(data: &[f32], rows: usize, columns: Option<&[u32]>) -> Vec<f32> {
    let n = columns.map_or(data.len() / rows.max(1), |c| c.len());
    let mut out = vec![0.0f32; rows];
    const BAND: usize = 2048;
    out.par_chunks_mut(BAND).enumerate().for_each(|(b, o)| {
        let r0 = b * BAND;
        let mut acc = vec![0.0f64; o.len()];
        let mut add = |j: usize| {
            for (a, &x) in acc.iter_mut().zip(&data[j * rows + r0..j * rows + r0 + o.len()]) {
                *a += x as f64;
            }
        };
        match columns {
            Some(cs) => cs.iter().for_each(|&j| add(j as usize)),
            None => (0..n).for_each(&mut add),
        }
        let inv = 1.0 / n.max(1) as f64;
        for (x, a) in o.iter_mut().zip(acc) {
            *x = (a * inv) as f32;
        }
    });
    out
}

/// A `rows x cols` matrix of independent standard normal values (Box-Muller on the seeded RNG).
pub(crate) fn gaussian(rows: usize, cols: usize, seed: u64) -> DMatrix<f32> {
    let mut rng = Rng::new(seed);
    let mut m = DMatrix::<f32>::zeros(rows, cols);
    let s = m.as_mut_slice();
    let mut i = 0;
    while i < s.len() {
        // 1 - u lies in (0, 1], so the logarithm is finite.
        let r = (-2.0 * (1.0 - rng.next_f64()).ln()).sqrt();
        let (sn, cs) = (std::f64::consts::TAU * rng.next_f64()).sin_cos();
        s[i] = (r * cs) as f32;
        if i + 1 < s.len() {
            s[i + 1] = (r * sn) as f32;
        }
        i += 2;
    }
    m
}

/// Eigenpairs of a symmetric `f64` matrix sorted by decreasing eigenvalue: (values, vectors as
/// the columns of a matrix in the same order).
pub(crate) fn sym_eigen_desc(m: DMatrix<f64>) -> (Vec<f64>, DMatrix<f64>) {
    let n = m.nrows();
    if n == 0 {
        return (Vec::new(), DMatrix::zeros(0, 0));
    }
    let e = m.symmetric_eigen();
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&i, &j| e.eigenvalues[j].total_cmp(&e.eigenvalues[i]));
    let vals = order.iter().map(|&i| e.eigenvalues[i]).collect();
    let vecs = DMatrix::from_fn(n, n, |r, c| e.eigenvectors[(r, order[c])]);
    (vals, vecs)
}

/// `a^T a` in `f64` (from `f32` GEMMs).
///
/// Only the blocks on and above the diagonal are multiplied (column band `j` against the columns
/// up to its end), which saves about 40% of the work of a full product for a large Gram matrix;
/// the lower triangle is mirrored.
pub(crate) fn gram_t(a: &DMatrix<f32>) -> DMatrix<f64> {
    let n = a.ncols();
    let bands = if n >= 128 { 8 } else { 1 };
    let edges: Vec<(usize, usize)> = (0..bands).map(|b| (b * n / bands, (b + 1) * n / bands)).collect();
    let parts: Vec<DMatrix<f32>> =
        edges.par_iter().map(|&(j0, j1)| gemm(&view_t(a).rows(0, j1), &view(a).columns(j0, j1 - j0))).collect();
    let mut g = DMatrix::<f64>::zeros(n, n);
    for (&(j0, j1), p) in edges.iter().zip(&parts) {
        for j in j0..j1 {
            for i in 0..=j {
                let v = p[(i, j - j0)] as f64;
                g[(i, j)] = v;
                g[(j, i)] = v;
            }
        }
    }
    g
}

/// An orthonormal basis of the column space of `y` (`rows x l` -> `rows x l'`, `l' <= l`).
///
/// Gram-based ("Cholesky-QR" through an eigendecomposition), applied twice: the first pass
/// whitens the columns with `V diag(1/sqrt(lambda))` of `y^T y`, which costs two GEMMs instead of a
/// sequential Householder QR of a tall matrix, and loses orthogonality in proportion to the
/// condition number squared; the second pass, on a nearly orthonormal matrix, restores it to
/// `f32` precision. Directions whose eigenvalue is below `1e-10` of the largest (numerically
/// absent: `f32` data cannot resolve them) are dropped, so a rank-deficient `y` gives fewer
/// columns, and an all-zero `y` none.
pub(crate) fn orthonormalize(y: &DMatrix<f32>) -> DMatrix<f32> {
    let mut q = whiten(y, 1e-10);
    if q.ncols() > 0 {
        // The second pass sees eigenvalues near 1; anything far below is a lost direction.
        q = whiten(&q, 1e-4);
    }
    q
}

fn whiten(y: &DMatrix<f32>, rel_cut: f64) -> DMatrix<f32> {
    let (vals, vecs) = sym_eigen_desc(gram_t(y));
    let top = vals.first().copied().unwrap_or(0.0);
    let keep = vals.iter().take_while(|&&v| top > 0.0 && v > rel_cut * top).count();
    let m = DMatrix::<f32>::from_fn(y.ncols(), keep, |i, j| (vecs[(i, j)] / vals[j].sqrt()) as f32);
    gemm(&view(y), &view(&m))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn naive(a: &DMatrix<f32>, b: &DMatrix<f32>) -> DMatrix<f64> {
        DMatrix::from_fn(a.nrows(), b.ncols(), |i, j| (0..a.ncols()).map(|k| a[(i, k)] as f64 * b[(k, j)] as f64).sum())
    }

    #[test]
    fn gemm_blocks_match_a_naive_product() {
        // Both split directions and the single-thread path, against an f64 triple loop.
        for (m, k, n) in
            [(300, 40, 7), (7, 40, 300), (5, 3, 4), (1, 50, 9), (9, 2, 70), (129, 129, 129), (2000, 300, 64)]
        {
            let a = gaussian(m, k, 1);
            let b = gaussian(k, n, 2);
            let c = gemm(&view(&a), &view(&b));
            let r = naive(&a, &b);
            let worst = c.iter().zip(r.iter()).map(|(x, y)| (*x as f64 - y).abs()).fold(0.0, f64::max);
            assert!(worst < 1e-4 * (k as f64).sqrt(), "{m}x{k}x{n}: {worst}");
            // A transposed view multiplies like the transposed copy.
            let at = a.transpose();
            let c2 = gemm(&view_t(&at), &view(&b));
            assert_eq!(c, c2);
        }
    }

    #[test]
    fn orthonormalize_spans_the_columns_and_drops_the_null_space() {
        // 200 x 6 of rank 4 (two columns are combinations of the others).
        let mut y = gaussian(200, 6, 3);
        for i in 0..200 {
            y[(i, 4)] = y[(i, 0)] - 2.0 * y[(i, 1)];
            y[(i, 5)] = 0.5 * y[(i, 2)] + y[(i, 3)];
        }
        let q = orthonormalize(&y);
        assert_eq!(q.ncols(), 4);
        let g = gram_t(&q);
        for i in 0..4 {
            for j in 0..4 {
                let want = if i == j { 1.0 } else { 0.0 };
                assert!((g[(i, j)] - want).abs() < 1e-5, "{i} {j} {}", g[(i, j)]);
            }
        }
        // Every column of y is reproduced by its projection on q.
        let qty = gemm(&view_t(&q), &view(&y));
        let proj = gemm(&view(&q), &view(&qty));
        let worst = proj.iter().zip(y.iter()).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
        assert!(worst < 1e-4, "{worst}");
        assert_eq!(orthonormalize(&DMatrix::zeros(10, 3)).ncols(), 0);
    }

    #[test]
    fn gaussian_is_standard_normal_and_seeded() {
        let g = gaussian(1000, 20, 9);
        let n = g.len() as f64;
        let mean = g.iter().map(|&x| x as f64).sum::<f64>() / n;
        let var = g.iter().map(|&x| (x as f64 - mean).powi(2)).sum::<f64>() / n;
        assert!(mean.abs() < 0.02 && (var - 1.0).abs() < 0.03, "{mean} {var}");
        assert_eq!(g, gaussian(1000, 20, 9));
        assert_ne!(g, gaussian(1000, 20, 10));
    }
}
