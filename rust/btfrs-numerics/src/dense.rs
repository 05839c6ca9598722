//! Small dense linear algebra shared by the fits (k-means, local PCA, randomized PCA, double SH).
//!
//! The clustering fits work on **column-major** `f32` matrices whose columns are points (a
//! texel's ABRDF, or its coordinates in a reduced space), which is exactly the texel-major layout
//! of a BTF: the `[T, D]` data seen column-major is a `D x T` matrix with one texel per column,
//! so it is multiplied in place, without a copy. The SH fit works on row-major `f64` blocks
//! ([`rows`], [`rows_mut`]). Products go through nalgebra, whose `f32`/`f64` products on dynamic
//! matrices call the `matrixmultiply` GEMM (any strides, so a transposed view costs nothing):
//! [`gemm_into`] is one such call on the calling thread, for callers that are parallel
//! themselves; [`gemm`] splits the output into blocks over rayon. Small symmetric eigenproblems
//! are solved in `f64`.

use btfrs_core::rng::Rng;
use nalgebra::{DMatrix, Dyn, MatrixView, MatrixViewMut};
use rayon::prelude::*;

/// The scalars of the products: `f32` and `f64`, the two types for which nalgebra hands a
/// dynamic product to `matrixmultiply` (it dispatches on the type at run time).
pub trait Real: nalgebra::RealField + Copy {}
impl Real for f32 {}
impl Real for f64 {}

/// A borrowed matrix with arbitrary strides.
pub type View<'a, T = f32> = MatrixView<'a, T, Dyn, Dyn, Dyn, Dyn>;
/// A mutably borrowed matrix with arbitrary strides.
pub type ViewMut<'a, T = f32> = MatrixViewMut<'a, T, Dyn, Dyn, Dyn, Dyn>;

/// The strides of an `nrows x ncols` view: `strides`, except for an empty view, which reads
/// nothing but which nalgebra's length check rejects unless the stride along its non-empty
/// dimension is 0.
fn empty_strides(nrows: usize, ncols: usize, strides: (usize, usize)) -> (usize, usize) {
    match (nrows, ncols) {
        (0, 0) => (1, 1),
        (0, _) => (1, 0),
        (_, 0) => (0, 1),
        _ => strides,
    }
}

/// `rows x cols` column-major matrix over `data` (column `j` is `data[j * rows..(j + 1) * rows]`).
pub fn cols<T: Real>(data: &[T], rows: usize, cols: usize) -> View<'_, T> {
    let (rs, cs) = empty_strides(rows, cols, (1, rows));
    View::from_slice_with_strides(data, rows, cols, rs, cs)
}

/// The transpose of the column-major `rows x cols` matrix over `data`, i.e. a `cols x rows` view.
pub fn cols_t<T: Real>(data: &[T], rows: usize, cols: usize) -> View<'_, T> {
    let (rs, cs) = empty_strides(cols, rows, (rows, 1));
    View::from_slice_with_strides(data, cols, rows, rs, cs)
}

/// `nrows x ncols` row-major matrix over `data` (row `i` is `data[i * ncols..(i + 1) * ncols]`).
pub fn rows<T: Real>(data: &[T], nrows: usize, ncols: usize) -> View<'_, T> {
    cols_t(data, ncols, nrows)
}

/// The transpose of the row-major `nrows x ncols` matrix over `data`, i.e. an `ncols x nrows` view.
pub fn rows_t<T: Real>(data: &[T], nrows: usize, ncols: usize) -> View<'_, T> {
    cols(data, ncols, nrows)
}

/// [`rows`], writable (the output of [`gemm_into`]).
pub fn rows_mut<T: Real>(data: &mut [T], nrows: usize, ncols: usize) -> ViewMut<'_, T> {
    let (rs, cs) = empty_strides(nrows, ncols, (ncols, 1));
    ViewMut::from_slice_with_strides_mut(data, nrows, ncols, rs, cs)
}

/// A view of an owned matrix.
pub fn view<T: Real>(m: &DMatrix<T>) -> View<'_, T> {
    cols(m.as_slice(), m.nrows(), m.ncols())
}

/// A transposed view of an owned matrix.
pub fn view_t<T: Real>(m: &DMatrix<T>) -> View<'_, T> {
    cols_t(m.as_slice(), m.nrows(), m.ncols())
}

/// Products below this many multiply-adds run on one thread (splitting costs more than it saves).
const PAR_MIN_WORK: usize = 1 << 20;
/// nalgebra sends products with a dimension below this to a generic fallback (slow, and unsound
/// with some strided views) instead of `matrixmultiply`.
const MIN_GEMM_DIM: usize = 6;

/// `x` copied into the top-left corner of a zero `rows x cols` matrix; `None` when `x` already
/// has that shape.
fn padded<T: Real>(x: &View<'_, T>, rows: usize, cols: usize) -> Option<DMatrix<T>> {
    (x.shape() != (rows, cols)).then(|| {
        let mut p = DMatrix::<T>::zeros(rows, cols);
        p.view_mut((0, 0), x.shape()).copy_from(x);
        p
    })
}

/// `c = a * b` on the calling thread (one `matrixmultiply` call), for operands and an output with
/// any strides.
///
/// A dimension below [`MIN_GEMM_DIM`] is zero-padded up to it, which copies only the operands
/// (and the output) that have the thin dimension: the copies are as small as that dimension.
///
/// # Panics
/// If the shapes do not agree (like nalgebra's products).
pub fn gemm_into<T: Real>(a: &View<'_, T>, b: &View<'_, T>, c: &mut ViewMut<'_, T>) {
    let (m, k) = a.shape();
    let n = b.ncols();
    assert!(k == b.nrows() && c.shape() == (m, n), "gemm_into: {m}x{k} times {:?} into {:?}", b.shape(), c.shape());
    if m == 0 || n == 0 {
        return;
    }
    if k == 0 {
        c.fill(nalgebra::zero());
        return;
    }
    if m >= MIN_GEMM_DIM && n >= MIN_GEMM_DIM && k >= MIN_GEMM_DIM {
        c.gemm(nalgebra::one(), a, b, nalgebra::zero());
        return;
    }
    let (mp, kp, np) = (m.max(MIN_GEMM_DIM), k.max(MIN_GEMM_DIM), n.max(MIN_GEMM_DIM));
    let (ap, bp) = (padded(a, mp, kp), padded(b, kp, np));
    let (av, bv) = (ap.as_ref().map_or(*a, view), bp.as_ref().map_or(*b, view));
    if (mp, np) == (m, n) {
        c.gemm(nalgebra::one(), &av, &bv, nalgebra::zero());
    } else {
        let mut t = DMatrix::<T>::zeros(mp, np);
        t.gemm(nalgebra::one(), &av, &bv, nalgebra::zero());
        c.copy_from(&t.view((0, 0), (m, n)));
    }
}

/// `a * b` with the output split into row or column blocks over rayon.
///
/// Each block is one `matrixmultiply` call whose result does not depend on the number of
/// threads, so the product is deterministic. Operands with a dimension below [`MIN_GEMM_DIM`]
/// are first copied into zero-padded matrices (see [`gemm_into`]).
pub fn gemm<T: Real>(a: &View<'_, T>, b: &View<'_, T>) -> DMatrix<T> {
    let (m, k) = a.shape();
    let n = b.ncols();
    assert_eq!(k, b.nrows(), "gemm: inner dimensions differ");
    if m == 0 || n == 0 || k == 0 {
        return DMatrix::zeros(m, n);
    }
    if m < MIN_GEMM_DIM || n < MIN_GEMM_DIM || k < MIN_GEMM_DIM {
        let (mp, kp, np) = (m.max(MIN_GEMM_DIM), k.max(MIN_GEMM_DIM), n.max(MIN_GEMM_DIM));
        let (ap, bp) = (padded(a, mp, kp), padded(b, kp, np));
        let c = gemm(&ap.as_ref().map_or(*a, view), &bp.as_ref().map_or(*b, view));
        return if (mp, np) == (m, n) { c } else { c.view((0, 0), (m, n)).into_owned() };
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
    let mut out = DMatrix::<T>::zeros(m, n);
    if m >= n {
        // Row bands of the output (strided in column-major), assembled afterwards.
        let parts: Vec<(usize, DMatrix<T>)> =
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
pub fn column_mean(data: &[f32], rows: usize, columns: Option<&[u32]>) -> Vec<f32> {
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
pub fn gaussian(rows: usize, cols: usize, seed: u64) -> DMatrix<f32> {
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
pub fn sym_eigen_desc(m: DMatrix<f64>) -> (Vec<f64>, DMatrix<f64>) {
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
pub fn gram_t(a: &DMatrix<f32>) -> DMatrix<f64> {
    gram_bands(&view(a), &view_t(a))
}

/// `x x^T` in `f64` of the column-major `rows x cols` matrix `x` in `data` (as [`gram_t`]: the
/// blocks on and above the diagonal multiplied, the rest mirrored).
pub fn gram(data: &[f32], rows: usize, cols: usize) -> DMatrix<f64> {
    gram_bands(&cols_t(data, rows, cols), &self::cols(data, rows, cols))
}

/// `a^T a` given `a` and its transpose `at` (views of the same values).
fn gram_bands(a: &View<'_, f32>, at: &View<'_, f32>) -> DMatrix<f64> {
    let n = a.ncols();
    let bands = if n >= 128 { 8 } else { 1 };
    let edges: Vec<(usize, usize)> = (0..bands).map(|b| (b * n / bands, (b + 1) * n / bands)).collect();
    let parts: Vec<DMatrix<f32>> =
        edges.par_iter().map(|&(j0, j1)| gemm(&at.rows(0, j1), &a.columns(j0, j1 - j0))).collect();
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
pub fn orthonormalize(y: &DMatrix<f32>) -> DMatrix<f32> {
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
    fn gemm_into_writes_strided_outputs_in_both_precisions() {
        // Row-major operands and outputs (the SH fit's layout), transposed views and thin
        // dimensions (padded), in f64 and f32, against an f64 triple loop on the same values.
        for (m, k, n) in [(40, 30, 20), (1, 9, 7), (9, 1, 7), (9, 7, 4), (5, 5, 5), (64, 81, 25), (3, 0, 2)] {
            let a32 = gaussian(m, k, 5);
            let b32 = gaussian(k, n, 6);
            let want = naive(&a32, &b32);
            let a: Vec<f64> = (0..m * k).map(|i| a32[(i / k, i % k)] as f64).collect(); // row-major
            let bt: Vec<f64> = (0..n * k).map(|i| b32[(i % k, i / k)] as f64).collect(); // row-major b^T
            let mut c = vec![f64::NAN; m * n];
            gemm_into(&rows(&a, m, k), &rows_t(&bt, n, k), &mut rows_mut(&mut c, m, n));
            for i in 0..m {
                for j in 0..n {
                    assert!((c[i * n + j] - want[(i, j)]).abs() < 1e-12, "{m}x{k}x{n} at ({i}, {j})");
                }
            }
            // f32, column-major output.
            let mut c32 = DMatrix::<f32>::from_element(m, n, f32::NAN);
            let (cr, cc) = c32.shape();
            let mut out = ViewMut::from_slice_with_strides_mut(c32.as_mut_slice(), cr, cc, 1, cr.max(1));
            gemm_into(&view(&a32), &view(&b32), &mut out);
            let worst = c32.iter().zip(want.iter()).map(|(x, y)| (*x as f64 - y).abs()).fold(0.0, f64::max);
            assert!(worst < 1e-4 * (k.max(1) as f64).sqrt(), "{m}x{k}x{n}: {worst}");
            // The parallel product agrees with the single call.
            assert_eq!(gemm(&view(&a32), &view(&b32)), c32);
        }
    }

    #[test]
    fn gram_is_x_x_transposed_in_both_band_counts() {
        // 200 rows (8 bands) and 20 rows (one), against an f64 triple loop.
        for (rows, ncols) in [(200, 57), (20, 300)] {
            let x = gaussian(rows, ncols, 4);
            let g = gram(x.as_slice(), rows, ncols);
            let mut worst = 0.0f64;
            for i in 0..rows {
                for j in 0..rows {
                    let r: f64 = (0..ncols).map(|k| x[(i, k)] as f64 * x[(j, k)] as f64).sum();
                    worst = worst.max((g[(i, j)] - r).abs());
                }
            }
            // f32 products of standard normals summed in f32: about 1e-5 of sums near sqrt(300).
            assert!(worst < 1e-3, "{rows} x {ncols}: {worst}");
            assert_eq!(g, g.transpose());
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
