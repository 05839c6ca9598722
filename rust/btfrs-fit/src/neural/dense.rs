//! The three matrix products of a training step's hidden layer (forward, and the two halves of
//! backward), row-major and contiguous, in two implementations: the `matrixmultiply` crate's
//! packed, register-blocked SGEMM (AVX/FMA chosen at run time) and hand-written row updates
//! (`c[i, ..] += a * b[p, ..]`, which the compiler vectorizes for the build's baseline target).
//! `benches/neural.rs` measures both on the step's shapes; training uses [`GEMM`], the faster.

/// An implementation of the products.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Gemm {
    /// The `matrixmultiply` crate.
    Crate,
    /// Hand-written row updates.
    Hand,
}

/// What training uses: the crate, 3.5x faster than the hand-written updates on the step's
/// shapes (BENCHMARKS.md, "Neural decoder products").
pub const GEMM: Gemm = Gemm::Crate;

#[allow(clippy::too_many_arguments)]
fn sgemm(
    m: usize,
    k: usize,
    n: usize,
    a: &[f32],
    rsa: isize,
    csa: isize,
    b: &[f32],
    rsb: isize,
    csb: isize,
    beta: f32,
    c: &mut [f32],
) {
    assert!(c.len() >= m * n && a.len() >= m * k && b.len() >= k * n);
    // SAFETY: the asserts above bound every index the strides reach: a is m x k, b is k x n
    // and c is m x n, each read through strides that stay inside its slice.
    unsafe {
        matrixmultiply::sgemm(
            m,
            k,
            n,
            1.0,
            a.as_ptr(),
            rsa,
            csa,
            b.as_ptr(),
            rsb,
            csb,
            beta,
            c.as_mut_ptr(),
            n as isize,
            1,
        );
    }
}

/// A matrix in a slice: its rows and columns and their strides (elements).
#[derive(Debug, Clone, Copy)]
pub struct View {
    /// Rows.
    pub rows: usize,
    /// Columns.
    pub cols: usize,
    /// Row stride.
    pub rs: usize,
    /// Column stride.
    pub cs: usize,
}

impl View {
    /// A contiguous row-major `rows x cols` matrix.
    pub fn rows(rows: usize, cols: usize) -> View {
        View { rows, cols, rs: cols, cs: 1 }
    }
    /// The transpose of a contiguous row-major `cols x rows` matrix seen as `rows x cols`.
    pub fn transposed(rows: usize, cols: usize) -> View {
        View { rows, cols, rs: 1, cs: rows }
    }
    /// A `rows x cols` block of a row-major matrix of row stride `rs`.
    pub fn block(rows: usize, cols: usize, rs: usize) -> View {
        View { rows, cols, rs, cs: 1 }
    }
    /// A `rows x cols` view whose element (i, j) is element (j, i) of a row-major matrix of
    /// row stride `rs`.
    pub fn block_t(rows: usize, cols: usize, rs: usize) -> View {
        View { rows, cols, rs: 1, cs: rs }
    }
    fn end(&self) -> usize {
        if self.rows == 0 || self.cols == 0 {
            0
        } else {
            (self.rows - 1) * self.rs + (self.cols - 1) * self.cs + 1
        }
    }
}

/// `c = a . b + beta c` for matrices given as strided views (the `matrixmultiply` crate): the
/// first layer's products, whose direction columns are a block of the weight matrix.
pub fn strided(a: &[f32], va: View, b: &[f32], vb: View, beta: f32, c: &mut [f32], vc: View) {
    assert!(va.cols == vb.rows && vc.rows == va.rows && vc.cols == vb.cols);
    assert!(va.end() <= a.len() && vb.end() <= b.len() && vc.end() <= c.len());
    if va.rows == 0 || vb.cols == 0 {
        return;
    }
    // SAFETY: the asserts bound the last element each view reaches within its slice; the views
    // of `c` never alias `a` or `b` (distinct borrows).
    unsafe {
        matrixmultiply::sgemm(
            va.rows,
            va.cols,
            vb.cols,
            1.0,
            a.as_ptr(),
            va.rs as isize,
            va.cs as isize,
            b.as_ptr(),
            vb.rs as isize,
            vb.cs as isize,
            beta,
            c.as_mut_ptr(),
            vc.rs as isize,
            vc.cs as isize,
        );
    }
}

#[allow(clippy::too_many_arguments)]
impl Gemm {
    /// `c [m][n] = a [m][k] . b [n][k]^T` (`accumulate`: `c +=`).
    pub fn abt(self, m: usize, k: usize, n: usize, a: &[f32], b: &[f32], c: &mut [f32], accumulate: bool) {
        match self {
            Gemm::Crate => sgemm(m, k, n, a, k as isize, 1, b, 1, k as isize, accumulate as u8 as f32, c),
            Gemm::Hand => {
                let mut bt = vec![0.0f32; k * n];
                for j in 0..n {
                    for p in 0..k {
                        bt[p * n + j] = b[j * k + p];
                    }
                }
                Gemm::Hand.ab(m, k, n, a, &bt, c, accumulate);
            }
        }
    }

    /// `c [m][n] = a [k][m]^T . b [k][n]` (`accumulate`: `c +=`).
    pub fn atb(self, m: usize, k: usize, n: usize, a: &[f32], b: &[f32], c: &mut [f32], accumulate: bool) {
        match self {
            Gemm::Crate => sgemm(m, k, n, a, 1, m as isize, b, n as isize, 1, accumulate as u8 as f32, c),
            Gemm::Hand => {
                if !accumulate {
                    c[..m * n].fill(0.0);
                }
                for p in 0..k {
                    let brow = &b[p * n..(p + 1) * n];
                    for i in 0..m {
                        let x = a[p * m + i];
                        for (o, &y) in c[i * n..(i + 1) * n].iter_mut().zip(brow) {
                            *o += x * y;
                        }
                    }
                }
            }
        }
    }

    /// `c [m][n] = a [m][k] . b [k][n]` (`accumulate`: `c +=`).
    pub fn ab(self, m: usize, k: usize, n: usize, a: &[f32], b: &[f32], c: &mut [f32], accumulate: bool) {
        match self {
            Gemm::Crate => sgemm(m, k, n, a, k as isize, 1, b, n as isize, 1, accumulate as u8 as f32, c),
            Gemm::Hand => {
                for i in 0..m {
                    let row = &mut c[i * n..(i + 1) * n];
                    if !accumulate {
                        row.fill(0.0);
                    }
                    for p in 0..k {
                        let x = a[i * k + p];
                        for (o, &y) in row.iter_mut().zip(&b[p * n..(p + 1) * n]) {
                            *o += x * y;
                        }
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn naive(
        m: usize,
        k: usize,
        n: usize,
        a: impl Fn(usize, usize) -> f32,
        b: impl Fn(usize, usize) -> f32,
    ) -> Vec<f64> {
        let mut c = vec![0.0f64; m * n];
        for i in 0..m {
            for j in 0..n {
                c[i * n + j] = (0..k).map(|p| a(i, p) as f64 * b(p, j) as f64).sum();
            }
        }
        c
    }

    #[test]
    fn both_implementations_match_a_float64_product() {
        let (m, k, n) = (37, 19, 11);
        let x: Vec<f32> = (0..m * k).map(|i| ((i * 7919 % 97) as f32 - 48.0) / 31.0).collect();
        let y: Vec<f32> = (0..k * n).map(|i| ((i * 104729 % 89) as f32 - 44.0) / 29.0).collect();
        // a [m][k], b [k][n]; their transposed storages for abt / atb.
        let xt: Vec<f32> = (0..k * m).map(|i| x[(i % m) * k + i / m]).collect(); // [k][m]
        let yt: Vec<f32> = (0..n * k).map(|i| y[(i % k) * n + i / k]).collect(); // [n][k]
        let want = naive(m, k, n, |i, p| x[i * k + p], |p, j| y[p * n + j]);
        for g in [Gemm::Crate, Gemm::Hand] {
            for acc in [false, true] {
                let check = |c: &[f32], what: &str| {
                    for (i, (&c, &w)) in c.iter().zip(&want).enumerate() {
                        let w = if acc { w + 1.0 } else { w };
                        assert!((c as f64 - w).abs() < 1e-4 * (1.0 + w.abs()), "{g:?} {what} {i}: {c} vs {w}");
                    }
                };
                let mut c = vec![if acc { 1.0 } else { f32::NAN }; m * n];
                if !acc {
                    c.fill(7.0);
                }
                g.ab(m, k, n, &x, &y, &mut c, acc);
                check(&c, "ab");
                let mut c = vec![if acc { 1.0 } else { 7.0 }; m * n];
                g.abt(m, k, n, &x, &yt, &mut c, acc);
                check(&c, "abt");
                let mut c = vec![if acc { 1.0 } else { 7.0 }; m * n];
                g.atb(m, k, n, &xt, &y, &mut c, acc);
                check(&c, "atb");
            }
        }
    }
}
