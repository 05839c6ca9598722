//! The starting point of every Lafortune fit: a linear least-squares fit over fixed candidate
//! lobes (specular, retro-reflective and around the normal, at a few exponents), chosen greedily.
//! Levenberg-Marquardt (`lm.rs`) is local; starting it from the best linear combination of
//! plausible lobes rather than from a fixed guess is what lets it converge on most texels.

use super::kernels::{cholesky_solve, Geometry, MAXM};

/// Candidate lobe shapes `(Cx, Cy, Cz, n)` with unit amplitude: specular (`C = (-1, -1, 1)`,
/// `s = l . reflect(v)`), retro-reflective (`C = (1, 1, 1)`, `s = l . v`) and a lobe around the
/// normal (`C = (0, 0, 1)`, `s = lz vz`), at a few exponents.
pub(crate) const CANDIDATES: [[f64; 4]; 10] = [
    [-1.0, -1.0, 1.0, 2.0],
    [-1.0, -1.0, 1.0, 8.0],
    [-1.0, -1.0, 1.0, 32.0],
    [-1.0, -1.0, 1.0, 128.0],
    [1.0, 1.0, 1.0, 2.0],
    [1.0, 1.0, 1.0, 8.0],
    [1.0, 1.0, 1.0, 32.0],
    [0.0, 0.0, 1.0, 1.0],
    [0.0, 0.0, 1.0, 4.0],
    [0.0, 0.0, 1.0, 16.0],
];
/// Basis functions of the linear initialisation: the diffuse `lz` and the candidates.
pub(crate) const NB: usize = 1 + CANDIDATES.len();

/// The candidate basis evaluated once at every sample, `[NB][npad]`, and its Gram matrix.
#[derive(Debug, Clone)]
pub(crate) struct Basis {
    pub f: Vec<f64>,
    pub gram: [[f64; NB]; NB],
}

impl Basis {
    pub fn new(g: &Geometry) -> Self {
        let np = g.npad();
        let mut f = vec![0.0f64; NB * np];
        f[..np].copy_from_slice(&g.lz);
        for (k, cand) in CANDIDATES.iter().enumerate() {
            let row = &mut f[(k + 1) * np..(k + 2) * np];
            for (i, x) in row[..g.n].iter_mut().enumerate() {
                let s = cand[0] * g.a[i] + cand[1] * g.b[i] + cand[2] * g.c[i];
                *x = if s > 0.0 { g.lz[i] * pow_exact(s, cand[3]) } else { 0.0 };
            }
        }
        let mut gram = [[0.0f64; NB]; NB];
        for p in 0..NB {
            for q in p..NB {
                let d = dot8(&f[p * np..(p + 1) * np], &f[q * np..(q + 1) * np]);
                gram[p][q] = d;
                gram[q][p] = d;
            }
        }
        Basis { f, gram }
    }

    /// `F^T y` for the padded targets `y`.
    pub fn fty(&self, y: &[f64]) -> [f64; NB] {
        let np = y.len();
        let mut out = [0.0f64; NB];
        for (p, o) in out.iter_mut().enumerate() {
            *o = dot8(&self.f[p * np..(p + 1) * np], y);
        }
        out
    }
}

/// `x . y` over whole chunks of 8 (the padded length is a multiple of it), with 8 partial sums so
/// that the loop vectorises (one running sum would be a chain of dependent additions).
fn dot8(x: &[f64], y: &[f64]) -> f64 {
    let mut acc = [0.0f64; 8];
    for (xs, ys) in x.as_chunks::<8>().0.iter().zip(y.as_chunks::<8>().0) {
        for k in 0..8 {
            acc[k] += xs[k] * ys[k];
        }
    }
    acc.iter().sum()
}

/// `s^n` for `s > 0`; by repeated squaring (`powi`) when `n` is a small integer, as every
/// candidate's exponent is: a few multiplications instead of a libm `pow` call per sample and
/// candidate, which made this setup (once per fit call) cost as much as a third of a texel's fit.
fn pow_exact(s: f64, n: f64) -> f64 {
    if n.fract() == 0.0 && (1.0..=1024.0).contains(&n) {
        s.powi(n as i32)
    } else {
        s.powf(n)
    }
}

/// Greedy forward selection of candidate lobes by linear least squares (kd included when
/// `diffuse`), each amplitude and kd required non-negative. Returns, for `l = 1..=lobes`, the
/// starting theta with `l` lobes. A slot for which no candidate gives a valid fit gets the next
/// unused candidate at a small amplitude (1e-3 of the normalised data), so that LM can still
/// grow it (a lobe at exactly zero has a zero gradient and would never move).
pub(crate) fn initial_guesses(basis: &Basis, fty: &[f64; NB], diffuse: bool, lobes: usize) -> Vec<[f64; MAXM]> {
    let mut chosen: Vec<usize> = if diffuse { vec![0] } else { Vec::new() };
    let mut out = Vec::with_capacity(lobes);
    let mut sol: Vec<f64> = Vec::new();
    if diffuse {
        let g0 = basis.gram[0][0];
        sol.push(if g0 > 0.0 { (fty[0] / g0).max(0.0) } else { 0.0 });
    }
    let mut seeds: Vec<usize> = Vec::new();
    for _ in 0..lobes {
        let mut best: Option<(f64, usize, Vec<f64>)> = None;
        for k in 1..NB {
            if chosen.contains(&k) {
                continue;
            }
            let idx: Vec<usize> = chosen.iter().copied().chain([k]).collect();
            let q = idx.len();
            let mut a = vec![0.0f64; q * q];
            let mut x: Vec<f64> = idx.iter().map(|&i| fty[i]).collect();
            for (r, &i) in idx.iter().enumerate() {
                for (s, &j) in idx.iter().enumerate() {
                    a[r * q + s] = basis.gram[i][j];
                }
            }
            if !cholesky_solve(&mut a, q, &mut x) {
                continue;
            }
            let ok = idx.iter().zip(&x).all(|(&i, &v)| if i == 0 { v >= 0.0 } else { v > 0.0 });
            if !ok {
                continue;
            }
            // Residual sum of squares minus the constant y^T y: -x . F^T y at the LS solution.
            let score = -idx.iter().zip(&x).map(|(&i, v)| v * fty[i]).sum::<f64>();
            if best.as_ref().is_none_or(|b| score < b.0) {
                best = Some((score, k, x));
            }
        }
        match best {
            Some((_, k, x)) => {
                chosen.push(k);
                sol = x;
            }
            None => {
                let k = (1..NB).find(|k| !chosen.contains(k) && !seeds.contains(k)).unwrap_or(1);
                seeds.push(k);
            }
        }
        out.push(theta_from(&chosen, &sol, &seeds, diffuse));
    }
    out
}

/// theta from the chosen basis indices (0 = kd), their amplitudes and the seeded candidates.
fn theta_from(chosen: &[usize], sol: &[f64], seeds: &[usize], diffuse: bool) -> [f64; MAXM] {
    let mut th = [0.0f64; MAXM];
    let mut at = usize::from(diffuse);
    for (&i, &amp) in chosen.iter().zip(sol) {
        if i == 0 {
            th[0] = amp;
            continue;
        }
        put_lobe(&mut th[at..at + 4], CANDIDATES[i - 1], amp);
        at += 4;
    }
    for &k in seeds {
        put_lobe(&mut th[at..at + 4], CANDIDATES[k - 1], 1e-3);
        at += 4;
    }
    th
}

/// A lobe of shape `cand` scaled by `amp`: `amp (u . p)^n = (amp^(1/n) u . p)^n`.
fn put_lobe(p: &mut [f64], cand: [f64; 4], amp: f64) {
    let s = amp.powf(1.0 / cand[3]);
    p[0] = cand[0] * s;
    p[1] = cand[1] * s;
    p[2] = cand[2] * s;
    p[3] = cand[3].ln();
}
