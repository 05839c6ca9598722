//! The light-PCA fit of the RBF and bilinear models ([`super`]) cut into stages over texel
//! blocks: what a blockwise driver runs on blocks fitted apart (`btfrs.dask`,
//! [`crate::blockwise`]), and what the local fit runs in two passes over a BTF's blocks in
//! storage order ([`fit_two_passes`]). Each block contributes sufficient statistics, so no
//! machine holds more than one block and a file is read twice, not once per view slot:
//!
//! 1. [`Plan::new`] (for a model by name: [`crate::light_bases::Basis::plan`]): the slots' pairs
//!    and resampling operators, a function of the directions, mask and options only (every task
//!    computes the same one).
//! 2. [`moments`] per block: per slot, the count, the mean and the centred second moment
//!    `M2 = sum (s - mean)(s - mean)^T` of the texels' *samples* `s` (the `3 m` values under the
//!    slot's `m` pairs), accumulated in `f64`. Every group's vector is a linear map `T s` of them
//!    ([`Plan::group_maps`]: the resampling, then the colour grouping), so these moments hold
//!    the groups' too, in `(3 m)^2` values instead of `d^2` (RBF defaults: 243^2 against 432^2).
//! 3. [`Moments::merge`]: two blocks' moments as one by the pairwise update of Chan, Golub and
//!    LeVeque ("Updating formulae and a pairwise algorithm for computing sample variances",
//!    1979): `M2 = M2a + M2b + delta delta^T na nb / n`, `delta = mean_b - mean_a`. Centred
//!    per block and merged in pairs (a tree), so no sum of squares of large values cancels.
//! 4. [`table`] on the client: per slot and group, the `f64` eigenvectors of `T M2 T^T` (or of
//!    the smaller `R M2 R^T`, `T = Q R`), the same exact PCA as the local fit's (the top
//!    `components` directions with eigenvalue above `1e-12` of the largest, zero functions
//!    beyond), written as the model's table.
//! 5. [`project`] per block: each texel's coefficients against the table's mean and directions,
//!    one product of its samples with `B^T T`.
//! 6. [`assemble`] on the client: the 8-bit quantization over all texels' coefficients and the
//!    model.
//!
//! The result equals the slot-by-slot fit to rounding: the same principal subspace of every
//! slot (the eigenproblem of the same covariance, summed in another order), each direction
//! possibly of the opposite sign (an eigenvector's sign is arbitrary; the coefficient flips with
//! it, so every evaluation agrees). A block's moments are `8 V (3 m)^2` bytes (81 views of 81
//! lights: 38 MB); the eigenproblems are at most `min(d, 3 m)` square, and the blockwise fit
//! takes those up to [`super::EXACT_PCA_DIM`] (above, it would need the randomized subspace
//! iteration as passes over the blocks, which is not built).

use super::{group_planes, put_coeffs, read_slot, write_slot, Colour, LightPca, PcaOptions, Plan};
use crate::planes::Planes;
use btfrs_core::btf::{advise, stream_blocks, Access, TexelScan};
use btfrs_core::scratch::Floats;
use btfrs_core::{ensure_arg, BtfRef, Error, Monitor, Result};
use btfrs_numerics::dense::{gemm, gram, sym_eigen_desc, view};
use nalgebra::DMatrix;
use rayon::prelude::*;

/// The moments of a set of texels (stage 2, module doc): per view slot, those of the texels'
/// samples, `d = 3 m` values for the most pairs `m` a slot has (a slot with fewer leaves the rest
/// zero).
#[derive(Debug, Clone, PartialEq)]
pub struct Moments {
    /// Texels counted.
    pub n: u64,
    /// Values per slot (`3 m`).
    pub d: usize,
    /// `[V][d]` means.
    pub mean: Vec<f64>,
    /// `[V][d][d]` centred second moments (symmetric).
    pub m2: Vec<f64>,
}

impl Moments {
    /// Both sets' moments as one (Chan et al.'s pairwise update, module doc).
    pub fn merge(&self, other: &Moments) -> Result<Moments> {
        let same = self.d == other.d
            && self.mean.len() == other.mean.len()
            && self.m2.len() == other.m2.len()
            && self.m2.len() == self.mean.len() * self.d;
        ensure_arg!(same, "moments", "the two sets of moments have different layouts (another model or options?)");
        if self.n == 0 {
            return Ok(other.clone());
        }
        if other.n == 0 {
            return Ok(self.clone());
        }
        let (na, nb) = (self.n as f64, other.n as f64);
        let n = na + nb;
        let d = self.d;
        let delta: Vec<f64> = self.mean.iter().zip(&other.mean).map(|(x, y)| y - x).collect();
        let mean = self.mean.iter().zip(&delta).map(|(x, dl)| x + dl * nb / n).collect();
        let f = na * nb / n;
        let mut m2: Vec<f64> = self.m2.iter().zip(&other.m2).map(|(x, y)| x + y).collect();
        m2.par_chunks_mut(d * d).zip(delta.par_chunks(d)).for_each(|(m, dl)| {
            for i in 0..d {
                for j in 0..d {
                    m[i * d + j] += dl[i] * dl[j] * f;
                }
            }
        });
        Ok(Moments { n: self.n + other.n, d, mean, m2 })
    }
}

/// Stage 2: the moments of one block's texels (its directions and mask those of the plan).
pub fn moments(block: &BtfRef<'_>, plan: &Plan) -> Result<Moments> {
    check_block(block, plan)?;
    let mut m = Moments::empty(plan);
    m.add(block, plan, None);
    Ok(m)
}

impl Moments {
    /// The moments of no texel for the slots of `plan`.
    pub fn empty(plan: &Plan) -> Moments {
        let (nv, d) = (plan.slots.len(), 3 * plan.max_pairs());
        Moments { n: 0, d, mean: vec![0.0; nv * d], m2: vec![0.0; nv * d * d] }
    }

    /// Add the texels of `block` (the plan's directions and mask; checked by the caller): per
    /// slot in parallel, the block's samples are centred on their own mean, their second moment
    /// is one symmetric `f32` product ([`gram`]), and it is merged into the running `f64` sums by the pairwise update
    /// (module doc). In place: no second copy of the moments.
    /// With `scan`, every value of the block is checked on the way ([`Plan::samples`]).
    pub(crate) fn add(&mut self, block: &BtfRef<'_>, plan: &Plan, scan: Option<&TexelScan>) {
        let t = block.texels();
        if t == 0 {
            return;
        }
        let (na, nb) = (self.n as f64, t as f64);
        let n = na + nb;
        let d = self.d;
        self.mean.par_chunks_mut(d).zip(self.m2.par_chunks_mut(d * d)).enumerate().for_each(|(v, (mean, m2))| {
            let sd = 3 * plan.pairs(v);
            let x = plan.samples(block, v, scan);
            let mut mb = vec![0.0f64; sd];
            for col in x.chunks_exact(sd) {
                mb.iter_mut().zip(col).for_each(|(m, &v)| *m += v as f64);
            }
            mb.iter_mut().for_each(|m| *m /= nb);
            let mb32: Vec<f32> = mb.iter().map(|&m| m as f32).collect();
            let mut xc = x;
            xc.chunks_exact_mut(sd).for_each(|c| c.iter_mut().zip(&mb32).for_each(|(a, m)| *a -= m));
            // Symmetric: the blocks on and above the diagonal only (about 0.56 of the product).
            let m2b = gram(&xc, sd, t);
            // Chan et al.: M2 = M2a + M2b + delta delta^T na nb / n, mean += delta nb / n.
            let delta: Vec<f64> = mean.iter().zip(&mb).map(|(a, b)| b - a).collect();
            let f = na * nb / n;
            for i in 0..sd {
                let row = &mut m2[i * d..i * d + sd];
                for (j, m) in row.iter_mut().enumerate() {
                    *m += m2b[(i, j)] + delta[i] * delta[j] * f;
                }
            }
            mean.iter_mut().zip(&delta).for_each(|(m, dl)| *m += dl * nb / n);
        });
        self.n += t as u64;
    }
}

/// Stage 4: the model's table (`[V][G][R]`, module doc of [`super`]) from the moments of all
/// texels: per slot and group, the mean and covariance of the group's vectors are those of the
/// samples through the group's map `T` ([`Plan::group_maps`]): `T mu` and `T C T^T`. Its
/// eigenvectors are found in the smaller of two exact forms: the `d x d` matrix itself, or, when
/// `T` has fewer columns than rows, `R C R^T` of `T = Q R` (thin QR; `T C T^T = Q (R C R^T)
/// Q^T`, so its eigenvectors `y` give `Q y`).
pub fn table(m: &Moments, plan: &Plan, opts: &PcaOptions) -> Result<Vec<f32>> {
    let kc = opts.check()?;
    let (g, km) = (opts.resolution * opts.resolution, opts.components);
    let nv = plan.slots.len();
    let d = 3 * plan.max_pairs();
    let planes = group_planes(opts.colour, km, kc);
    let ok = m.n > 0 && m.d == d && m.mean.len() == nv * d && m.m2.len() == nv * d * d;
    ensure_arg!(ok, "moments", "expected the moments of {nv} view slots of {d} samples over some texels");
    let stride = 3 + km * if opts.colour == Colour::Rgb { 3 } else { 1 } + 2 * kc;
    let mut table = vec![0.0f32; nv * g * stride];
    table.par_chunks_mut(g * stride).enumerate().for_each(|(v, slot)| {
        let sd = 3 * plan.pairs(v);
        let m2 = &m.m2[v * d * d..(v + 1) * d * d];
        let c = DMatrix::<f64>::from_fn(sd, sd, |i, j| 0.5 * (m2[i * d + j] + m2[j * d + i]));
        let mu = nalgebra::DVector::from_column_slice(&m.mean[v * d..v * d + sd]);
        let parts: Vec<(Vec<f32>, DMatrix<f32>)> = plan
            .group_maps(v, opts.colour)
            .into_iter()
            .zip(&planes)
            .map(|(tm, &(k, _))| {
                let dg = tm.nrows();
                let (vals, vecs) = if dg <= sd {
                    let cx = &tm * &c * tm.transpose();
                    sym_eigen_desc(DMatrix::from_fn(dg, dg, |i, j| 0.5 * (cx[(i, j)] + cx[(j, i)])))
                } else {
                    let qr = tm.clone().qr();
                    let (q, r) = (qr.q(), qr.r());
                    let kr = &r * &c * r.transpose();
                    let (vals, y) = sym_eigen_desc(DMatrix::from_fn(sd, sd, |i, j| 0.5 * (kr[(i, j)] + kr[(j, i)])));
                    (vals, q * y)
                };
                let top = vals.first().copied().unwrap_or(0.0);
                let keep = (0..k.min(vals.len())).take_while(|&j| top > 0.0 && vals[j] > 1e-12 * top).count();
                let basis = DMatrix::<f32>::from_fn(dg, k, |i, j| if j < keep { vecs[(i, j)] as f32 } else { 0.0 });
                let mean = (&tm * &mu).iter().map(|&x| x as f32).collect();
                (mean, basis)
            })
            .collect();
        let refs: Vec<(&[f32], &DMatrix<f32>)> = parts.iter().map(|(a, b)| (a.as_slice(), b)).collect();
        write_slot(slot, opts.colour, km, g, &refs);
    });
    btfrs_core::arrays::check_finite("table", &table)?;
    Ok(table)
}

/// Stage 5: one block's coefficients `[texel][V][K]` (f32, before quantization) against the
/// table's means and directions: per slot and group, `B^T (T s - mean)` as one product of the
/// samples `s` with `B^T T` (`K x 3 m`, [`Plan::group_maps`]), so no texel's vector is formed.
pub fn project(block: &BtfRef<'_>, plan: &Plan, table: &[f32], opts: &PcaOptions) -> Result<Vec<f32>> {
    project_checked(block, plan, table, opts, None)
}

/// [`project`], checking every value of the block on the way when `scan` is given.
fn project_checked(
    block: &BtfRef<'_>,
    plan: &Plan,
    table: &[f32],
    opts: &PcaOptions,
    scan: Option<&TexelScan>,
) -> Result<Vec<f32>> {
    check_block(block, plan)?;
    let kc = opts.check()?;
    let (nv, t, g, km) = (block.views.len(), block.texels(), opts.resolution * opts.resolution, opts.components);
    let k = km + kc;
    let stride = 3 + km * if opts.colour == Colour::Rgb { 3 } else { 1 } + 2 * kc;
    ensure_arg!(table.len() == nv * g * stride, "table", "expected {nv} x {g} x {stride} values, got {}", table.len());
    let per: Vec<Vec<(usize, DMatrix<f32>)>> = (0..nv)
        .into_par_iter()
        .map(|v| {
            let sd = 3 * plan.pairs(v);
            let x = plan.samples(block, v, scan);
            let stored = read_slot(&table[v * g * stride..(v + 1) * g * stride], opts.colour, km, kc, g);
            plan.group_maps(v, opts.colour)
                .into_iter()
                .zip(stored)
                .zip(group_planes(opts.colour, km, kc))
                .map(|((tm, (mean, basis)), (_, off))| {
                    let b64 = DMatrix::<f64>::from_fn(basis.nrows(), basis.ncols(), |i, j| basis[(i, j)] as f64);
                    let a64 = b64.transpose() * &tm;
                    let a = DMatrix::<f32>::from_fn(a64.nrows(), sd, |i, j| a64[(i, j)] as f32);
                    let bias: Vec<f32> = (0..basis.ncols())
                        .map(|p| (0..mean.len()).map(|i| b64[(i, p)] * mean[i] as f64).sum::<f64>() as f32)
                        .collect();
                    let mut c = gemm(&view(&a), &btfrs_numerics::dense::cols(&x, sd, t));
                    c.column_iter_mut().for_each(|mut col| col.iter_mut().zip(&bias).for_each(|(y, b)| *y -= b));
                    (off, c)
                })
                .collect()
        })
        .collect();
    let mut coeffs = vec![0.0f32; t * nv * k];
    for (v, parts) in per.iter().enumerate() {
        for (off, c) in parts {
            put_coeffs(&mut coeffs, c, v, nv, k, *off);
        }
    }
    if coeffs.iter().any(|x| !x.is_finite()) {
        return Err(Error::Degenerate("the projection of the resampled light functions is not finite".into()));
    }
    Ok(coeffs)
}

/// Stage 6: the model from the table and every texel's coefficients (`[T][V][K]`, texel order),
/// quantized over all texels as the local fit does.
pub fn assemble(
    height: usize,
    width: usize,
    views: &[[f64; 3]],
    plan: Plan,
    table: Vec<f32>,
    coeffs: &[f32],
    opts: &PcaOptions,
) -> Result<LightPca> {
    let k = opts.components + opts.check()?;
    let nv = views.len();
    ensure_arg!(
        coeffs.len() == height * width * nv * k,
        "coeffs",
        "expected {height} x {width} texels x {nv} slots x {k} planes, got {} values",
        coeffs.len()
    );
    let Plan { pooled, fallback_slots, .. } = plan;
    super::assemble(height, width, views, opts, Planes::quantize(coeffs, nv * k)?, table, pooled, fallback_slots)
}

/// Blocks the two-pass fit keeps in memory ahead of the one it computes on.
const AHEAD: usize = 2;

/// Texels whose moments give the principal functions at most ([`fit_two_passes`]): a capture with
/// more takes them from a sample of this many spread over the frame.
pub const MOMENT_TEXELS: usize = 1 << 18;

/// Bytes of sampled values copied at a time for their moments.
pub(crate) const SAMPLE_COPY_BYTES: usize = 16 << 20;

/// The local fit ([`super::fit`]) in two passes over texel blocks in storage order, where its
/// vectors get the exact PCA ([`super::two_passes`]): the stages above run by one machine. The
/// first pass checks every value and sums the moments, the second projects; so a BTF larger
/// than memory (a memory-mapped file) is read twice, whatever its number of view slots, where a
/// slot-by-slot fit would read each texel's values once per slot. `block`: texels per block;
/// `spill`: the float coefficients wait for the quantization in a temporary file
/// ([`btfrs_core::scratch`]) instead of memory.
///
/// Above `sample` texels ([`MOMENT_TEXELS`] in [`super::fit`]) the first pass reads only a
/// sample of that many ([`crate::runs`], seeded by the options' `seed`) and the second checks the
/// values: the moments of the 60-light samples cost 16,000 multiply-adds a texel, the projection
/// a tenth of that, and a quarter of a million texels spread over the frame give the principal
/// functions of every kind of appearance a capture holds (relight computes its PCA from a sample
/// of pixels likewise). The capture is then read once and a sample, not twice.
pub(crate) fn fit_two_passes(
    btf: &BtfRef<'_>,
    opts: &PcaOptions,
    plan: Plan,
    block: usize,
    spill: bool,
    sample: usize,
    monitor: &Monitor,
) -> Result<LightPca> {
    let kc = opts.check()?;
    let (nv, t, full) = (btf.views.len(), btf.texels(), btf.abrdf_len());
    let k = opts.components + kc;
    monitor.start(if t > sample { 1 } else { 2 } * t.div_ceil(block.max(1)) as u64);
    // Only out of core: on a BTF held in memory the advice would mark the caller's own array as
    // the first to swap out.
    let out_of_core = monitor.memory_limit().is_some();
    let sub = |b0: usize, n: usize| BtfRef { height: 1, width: n, data: &btf.data[b0 * full..(b0 + n) * full], ..*btf };
    let scan = TexelScan::new();
    let mut moments = Moments::empty(&plan);
    let sampled = t > sample;
    if sampled {
        // 1. The moments of a sample of runs spread over the frame (`crate::runs`), copied a
        //    few megabytes at a time; the sample's values checked as they are copied (a bad one
        //    is named as the caller's scan would, not as a non-finite table), every value in the
        //    second pass.
        let picked = crate::runs::sample_texels(t, sample, opts.seed);
        let per_copy = (SAMPLE_COPY_BYTES / (4 * full.max(1))).clamp(1, block.max(1));
        let mut buf: Vec<f32> = Vec::with_capacity(per_copy.min(picked.len()) * full);
        for chunk in picked.chunks(per_copy) {
            monitor.check()?;
            buf.clear();
            for &x in chunk {
                buf.extend_from_slice(&btf.data[x * full..(x + 1) * full]);
            }
            scan.check(&buf);
            scan.finish("data", btf.data)?;
            moments.add(&BtfRef { height: 1, width: chunk.len(), data: &buf, ..*btf }, &plan, None);
        }
    } else {
        // 1. Every value checked (present or not, as the caller's scan would), the moments summed.
        stream_blocks(btf.data, full, block, AHEAD, |_, b0, n| {
            monitor.check()?;
            let b = sub(b0, n);
            moments.add(&b, &plan, Some(&scan));
            scan.finish("data", btf.data)?;
            if out_of_core {
                advise(b.data, Access::Done);
            }
            monitor.advance(1);
            Ok(())
        })?;
    }
    let table = table(&moments, &plan, opts)?;
    drop(moments);
    // 2. Every texel's coefficients against the table (every value checked here when the
    //    moments came from a sample).
    let mut coeffs = Floats::zeros(t * nv * k, spill)?;
    stream_blocks(btf.data, full, block, AHEAD, |_, b0, n| {
        monitor.check()?;
        let b = sub(b0, n);
        // A non-finite value is named before the projection's own error about it.
        let c = project_checked(&b, &plan, &table, opts, sampled.then_some(&scan));
        scan.finish("data", btf.data)?;
        let c = c?;
        coeffs[b0 * nv * k..(b0 + n) * nv * k].copy_from_slice(&c);
        if out_of_core {
            advise(b.data, Access::Done);
        }
        monitor.advance(1);
        Ok(())
    })?;
    assemble(btf.height, btf.width, btf.views, plan, table, &coeffs, opts)
}

fn check_block(block: &BtfRef<'_>, plan: &Plan) -> Result<()> {
    ensure_arg!(
        plan.slots.len() == block.views.len(),
        "views",
        "the plan has {} view slots, the block {}",
        plan.slots.len(),
        block.views.len()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bilinear::{self, BilinearOptions};
    use crate::light_bases::Basis;
    use crate::model::Model;
    use crate::options::{self, parse_json};
    use crate::rbf;
    use btfrs_core::materials::{generate, MaterialSpec, Preset};
    use btfrs_core::Monitor;

    /// The rows `r0..r1` of `b` as a block.
    fn rows<'a>(b: &BtfRef<'a>, r0: usize, r1: usize) -> BtfRef<'a> {
        let per = b.abrdf_len() * b.width;
        BtfRef { height: r1 - r0, data: &b.data[r0 * per..r1 * per], ..*b }
    }

    /// The largest difference of two light bases' evaluations over every texel at four (view,
    /// light) pairs of `b`, and the largest value of `y`'s.
    fn difference(x: &LightPca, y: &LightPca, b: &BtfRef<'_>) -> (f32, f32) {
        let (nv, nl) = (b.views.len(), b.lights.len());
        let (mut worst, mut peak) = (0.0f32, 0.0f32);
        for (vi, li) in [(0, 0), (3, 17), (nv - 1, nl - 1), (nv / 2, nl / 3)] {
            let (qx, qy) = (x.query(b.views[vi], b.lights[li]), y.query(b.views[vi], b.lights[li]));
            for t in 0..b.texels() {
                let (a, c) = (x.eval(t, &qx), y.eval(t, &qy));
                for ch in 0..3 {
                    worst = worst.max((a[ch] - c[ch]).abs());
                    peak = peak.max(c[ch].abs());
                }
            }
        }
        (worst, peak)
    }

    #[test]
    fn table_round_trips_through_write_and_read() {
        // read_slot inverts write_slot for both colour groupings.
        let mut rng = btfrs_core::rng::Rng::new(3);
        for (colour, km, kc) in [(Colour::Rgb, 3, 0), (Colour::Ycc, 4, 2)] {
            let g = 9;
            let dims: Vec<usize> = if colour == Colour::Rgb { vec![3 * g] } else { vec![g, 2 * g] };
            let parts: Vec<(Vec<f32>, DMatrix<f32>)> = dims
                .iter()
                .zip(group_planes(colour, km, kc))
                .map(|(&d, (k, _))| {
                    let m: Vec<f32> = (0..d).map(|_| rng.next_f64() as f32).collect();
                    (m, DMatrix::from_fn(d, k, |_, _| rng.next_f64() as f32))
                })
                .collect();
            let stride = 3 + km * if colour == Colour::Rgb { 3 } else { 1 } + 2 * kc;
            let mut t = vec![f32::NAN; g * stride];
            let refs: Vec<(&[f32], &DMatrix<f32>)> = parts.iter().map(|(a, b)| (a.as_slice(), b)).collect();
            write_slot(&mut t, colour, km, g, &refs);
            assert!(t.iter().all(|x| x.is_finite()), "{colour:?}: some table entries were not written");
            assert_eq!(read_slot(&t, colour, km, kc, g), parts, "{colour:?}");
        }
    }

    #[test]
    fn merged_moments_equal_a_float64_reference() {
        // Two blocks' moments merged against moments of all texels' samples at once in f64, with
        // a mask (slots of different sizes in one padded layout).
        let btf = generate(&MaterialSpec::new(Preset::Bumps, 8, 3), &Monitor::new()).unwrap();
        let (nv, nl) = (btf.views.len(), btf.lights.len());
        let mask: Vec<bool> = (0..nv * nl).map(|i| (i / nl) % 2 == 0 || i % 3 != 1).collect();
        let b = BtfRef { mask: Some(&mask), ..btf.as_ref() };
        let basis = Basis::parse("bilinear", &parse_json(r#"{"resolution": 4, "colour": "ycc"}"#).unwrap()).unwrap();
        let plan = basis.plan(b.views, b.lights, b.mask).unwrap();
        let whole = moments(&b, &plan).unwrap();
        let parts = [moments(&rows(&b, 0, 3), &plan).unwrap(), moments(&rows(&b, 3, 8), &plan).unwrap()];
        let merged = parts[0].merge(&parts[1]).unwrap();
        assert_eq!(merged.n, 64);
        let (gm, d) = (&merged, merged.d);
        assert_eq!(d, 3 * nl);
        let mut worst = 0.0f64;
        for v in [0, 1, nv - 1] {
            let sd = 3 * plan.pairs(v);
            let x = plan.samples(&b, v, None);
            let cols: Vec<&[f32]> = x.chunks_exact(sd).collect();
            let mean: Vec<f64> = (0..sd).map(|i| cols.iter().map(|c| c[i] as f64).sum::<f64>() / 64.0).collect();
            let scale = gm.m2[v * d * d..(v + 1) * d * d].iter().fold(0.0f64, |a, x| a.max(x.abs()));
            for i in 0..d {
                for j in 0..d {
                    let m2: f64 = if i < sd && j < sd {
                        cols.iter().map(|c| (c[i] as f64 - mean[i]) * (c[j] as f64 - mean[j])).sum()
                    } else {
                        0.0 // the padding of a slot with fewer pairs
                    };
                    for m in [&gm.m2, &whole.m2] {
                        worst = worst.max((m[v * d * d + i * d + j] - m2).abs() / scale);
                    }
                }
                let mu = if i < sd { mean[i] } else { 0.0 };
                assert!((gm.mean[v * d + i] - mu).abs() < 1e-9, "slot {v}: mean {i}");
            }
        }
        // Each block's second moment is one f32 product of values centred on the block's mean
        // (merged in f64): measured 4.5e-7 of the largest entry, f32 rounding of 64-term sums.
        assert!(worst <= 2e-6, "the merged second moments differ by {worst:e} of the largest from the f64 sums");
        // Merging with an empty set is the identity; different layouts are refused.
        let empty = Moments { n: 0, ..merged.clone() };
        assert_eq!(empty.merge(&merged).unwrap(), merged);
        let few: Vec<bool> = (0..nv * nl).map(|i| i % nl < 40).collect();
        let other_plan = basis.plan(b.views, b.lights, Some(&few)).unwrap();
        let other = moments(&BtfRef { mask: Some(&few), ..b }, &other_plan).unwrap();
        assert!(merged.merge(&other).unwrap_err().to_string().starts_with("moments: the two sets"));
        let o = basis.options().unwrap();
        assert!(table(&other, &plan, &o).unwrap_err().to_string().starts_with("moments: expected"));
    }

    #[test]
    fn staged_fits_evaluate_as_the_local_fits() {
        // Both models and both colour groupings, with a mask: three blocks through the stages
        // against the local fit. The principal subspaces are the same, the directions' signs may
        // differ: every evaluation agrees to rounding.
        let btf = generate(&MaterialSpec::new(Preset::Bumps, 12, 3), &Monitor::new()).unwrap();
        let b = btf.as_ref();
        let (nv, nl) = (b.views.len(), b.lights.len());
        let mask: Vec<bool> = (0..nv * nl).map(|i| i % 7 != 3).collect();
        let b = BtfRef { mask: Some(&mask), ..b };
        for (kind, json) in [
            ("rbf", r#"{"components": 5}"#),
            ("rbf", r#"{"components": 4, "colour": "ycc", "resolution": 8}"#),
            ("bilinear", r#"{"components": 6}"#),
            ("bilinear", r#"{"components": 5, "colour": "ycc", "chroma_components": 2}"#),
        ] {
            let basis = Basis::parse(kind, &parse_json(json).unwrap()).unwrap();
            let o = basis.options().unwrap();
            let plan = basis.plan(b.views, b.lights, b.mask).unwrap();
            let blocks = [rows(&b, 0, 5), rows(&b, 5, 6), rows(&b, 6, 12)];
            let m = blocks.iter().map(|x| moments(x, &plan).unwrap()).reduce(|a, x| a.merge(&x).unwrap()).unwrap();
            let tab = table(&m, &plan, &o).unwrap();
            let coeffs: Vec<f32> = blocks.iter().flat_map(|x| project(x, &plan, &tab, &o).unwrap()).collect();
            let staged = assemble(b.height, b.width, b.views, plan, tab, &coeffs, &o).unwrap();
            let local = match basis {
                Basis::Rbf(ro) => rbf::Rbf::fit(&b, &ro, &Monitor::new()).unwrap().0,
                Basis::Bilinear(bo) => bilinear::Bilinear::fit(&b, &bo, &Monitor::new()).unwrap().0,
            };
            assert_eq!(
                (staged.pooled.clone(), staged.fallback_slots.clone()),
                (local.pooled.clone(), local.fallback_slots.clone())
            );
            let (worst, peak) = difference(&staged, &local, &b);
            // Measured: 2.4e-7 of the peak (float rounding); one 8-bit step of a coefficient that
            // rounds the other way would be about 1e-3.
            assert!(worst <= 2e-3 * peak, "{kind} {json}: staged and local differ by {worst} (peak {peak})");
        }
    }

    #[test]
    fn two_pass_fits_evaluate_as_slot_by_slot_fits() {
        // The two-pass fit (one block; blocks of 100, 100 and 56 texels with the coefficients in
        // a temporary file) against the slot-by-slot fit of the same options, with a mask; then
        // under a memory limit of exactly the least the fit needs, which streams blocks of
        // MIN_BLOCK texels and spills.
        // RBF at resolution 12 has 432 values per vector from 3 x 65 samples: the eigenproblem
        // of R C R^T; the other two the covariance's own.
        let btf = generate(&MaterialSpec::new(Preset::Bumps, 16, 3), &Monitor::new()).unwrap();
        let b = btf.as_ref();
        let (nv, nl) = (b.views.len(), b.lights.len());
        let mask: Vec<bool> = (0..nv * nl).map(|i| i % 5 != 2).collect();
        let b = BtfRef { mask: Some(&mask), ..b };
        for (kind, json) in [
            ("bilinear", r#"{"components": 6, "resolution": 4}"#),
            ("rbf", r#"{"components": 4, "colour": "ycc", "resolution": 6}"#),
            ("rbf", r#"{"components": 5, "resolution": 12}"#),
        ] {
            let basis = Basis::parse(kind, &parse_json(json).unwrap()).unwrap();
            let o = basis.options().unwrap();
            let plan = || basis.plan(b.views, b.lights, b.mask).unwrap();
            assert!(super::super::two_passes(&o, b.texels(), plan().max_pairs()));
            let slots = super::super::fit_per_slot(&b, &o, plan(), &Monitor::new()).unwrap();
            let limited = Monitor::new();
            let least = match basis {
                Basis::Rbf(ro) => rbf::Rbf::least_memory(&b, &ro),
                Basis::Bilinear(bo) => bilinear::Bilinear::least_memory(&b, &bo),
            };
            limited.set_memory_limit(Some(least));
            assert_eq!(super::super::block_texels(&b, &o, Some(least)), super::super::MIN_BLOCK);
            let fits = [
                fit_two_passes(&b, &o, plan(), 256, false, usize::MAX, &Monitor::new()).unwrap(),
                fit_two_passes(&b, &o, plan(), 100, true, usize::MAX, &Monitor::new()).unwrap(),
                match basis {
                    Basis::Rbf(ro) => rbf::Rbf::fit(&b, &ro, &limited).unwrap().0,
                    Basis::Bilinear(bo) => bilinear::Bilinear::fit(&b, &bo, &limited).unwrap().0,
                },
            ];
            for (fi, fit) in fits.iter().enumerate() {
                assert_eq!((&fit.pooled, &fit.fallback_slots), (&slots.pooled, &slots.fallback_slots));
                let (worst, peak) = difference(fit, &slots, &b);
                // Float rounding only; one 8-bit step of a coefficient that rounds the other way
                // would be about 1e-3 of the peak.
                assert!(worst <= 2e-3 * peak, "{kind} fit {fi}: differs from slot by slot by {worst} (peak {peak})");
            }
        }
    }

    #[test]
    fn two_pass_fits_check_every_value() {
        // A non-finite value at a masked-out pair fails as the caller's scan would, naming it.
        let btf = generate(&MaterialSpec::new(Preset::Bumps, 12, 3), &Monitor::new()).unwrap();
        let (nv, nl) = (btf.views.len(), btf.lights.len());
        let mask: Vec<bool> = (0..nv * nl).map(|i| i != 7).collect();
        let mut data = btf.data.clone();
        let at = 100 * nv * nl * 3 + 7 * 3 + 1;
        data[at] = f32::NAN;
        let b = BtfRef { mask: Some(&mask), data: &data, ..btf.as_ref() };
        let o: BilinearOptions =
            options::build(<bilinear::Bilinear as Model>::OPTIONS, parse_json(r#"{"resolution": 4}"#).unwrap())
                .unwrap();
        let e = bilinear::Bilinear::fit(&b, &o, &Monitor::new()).unwrap_err().to_string();
        let want = btfrs_core::btf::check_finite("data", &data).unwrap_err().to_string();
        assert_eq!(e, want);
    }

    /// The relative RMS error of `fit` against the values of `b` at every present pair.
    fn rms_error(fit: &LightPca, b: &BtfRef<'_>) -> f64 {
        let (mut e, mut n) = (0.0f64, 0.0f64);
        for (v, &view) in b.views.iter().enumerate() {
            for (l, &light) in b.lights.iter().enumerate() {
                if !b.has(v, l) {
                    continue;
                }
                let q = fit.query(view, light);
                for t in 0..b.texels() {
                    let got = fit.eval(t, &q);
                    for (c, &g) in got.iter().enumerate() {
                        let want = b.texel(t)[(v * b.lights.len() + l) * 3 + c] as f64;
                        e += (g as f64 - want).powi(2);
                        n += want * want;
                    }
                }
            }
        }
        (e / n).sqrt()
    }

    #[test]
    fn principal_functions_from_a_sample_fit_nearly_as_well_as_from_every_texel() {
        // Moments of 256 of 1024 texels (4 runs of 64): the fit's error at the measured pairs
        // within 10% of the exact PCA's, every texel still projected, and the same report.
        let btf = generate(&MaterialSpec::new(Preset::Bumps, 32, 3), &Monitor::new()).unwrap();
        let b = btf.as_ref();
        for (kind, json) in [
            ("bilinear", r#"{"components": 6, "resolution": 4}"#),
            ("rbf", r#"{"components": 4, "colour": "ycc", "resolution": 6}"#),
        ] {
            let basis = Basis::parse(kind, &parse_json(json).unwrap()).unwrap();
            let o = basis.options().unwrap();
            let plan = || basis.plan(b.views, b.lights, b.mask).unwrap();
            let all = fit_two_passes(&b, &o, plan(), 256, false, usize::MAX, &Monitor::new()).unwrap();
            let sampled = fit_two_passes(&b, &o, plan(), 256, false, 256, &Monitor::new()).unwrap();
            let (ea, es) = (rms_error(&all, &b), rms_error(&sampled, &b));
            assert!(es <= 1.10 * ea && es > 0.0, "{kind}: sampled {es} against every texel {ea}");
            // Not the same fit: the sample's principal functions differ from the exact ones.
            assert!(difference(&sampled, &all, &b).0 > 0.0, "{kind}");
            assert_eq!((&sampled.pooled, &sampled.fallback_slots), (&all.pooled, &all.fallback_slots));
        }
    }

    #[test]
    fn a_sampled_fit_still_checks_every_value() {
        // A non-finite value outside the sample (the projection pass finds it) and one inside
        // it (found as it is copied, before the moments): each with the caller's scan's error.
        let btf = generate(&MaterialSpec::new(Preset::Bumps, 32, 3), &Monitor::new()).unwrap();
        let picked = crate::runs::sample_texels(btf.as_ref().texels(), 256, 0);
        let outside = (0..1024).rev().find(|t| !picked.contains(t)).unwrap();
        for (texel, bad) in [(outside, f32::INFINITY), (picked[100], f32::NAN)] {
            let mut data = btf.data.clone();
            data[texel * btf.as_ref().abrdf_len() + 5] = bad;
            let b = BtfRef { data: &data, ..btf.as_ref() };
            let basis = Basis::parse("bilinear", &parse_json(r#"{"resolution": 4, "seed": 0}"#).unwrap()).unwrap();
            let o = basis.options().unwrap();
            let plan = basis.plan(b.views, b.lights, b.mask).unwrap();
            let e = fit_two_passes(&b, &o, plan, 256, false, 256, &Monitor::new()).unwrap_err().to_string();
            assert_eq!(e, btfrs_core::btf::check_finite("data", &data).unwrap_err().to_string(), "texel {texel}");
        }
    }

    #[test]
    fn bad_input_is_refused() {
        let parse = |k: &str, j: &str| Basis::parse(k, &parse_json(j).unwrap());
        let e = |k: &str, j: &str| parse(k, j).unwrap_err().to_string();
        assert!(e("ptm", "{}").starts_with("kind: expected \"rbf\" or \"bilinear\""));
        // The blockwise limit is the eigenproblem's size, min(values per vector, 3 x lights).
        let d = btfrs_core::directions::ubo81();
        let many: Vec<[f64; 3]> = (0..300)
            .map(|i| {
                let (th, ph) = (1.2 * (i as f64 + 0.5) / 300.0, 2.4 * i as f64);
                [th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()]
            })
            .collect();
        let rbf17 = parse("rbf", r#"{"resolution": 17}"#).unwrap();
        assert!(rbf17.plan(&d, &d, None).is_ok(), "867 values per vector, but 243 samples");
        let err = rbf17.plan(&d[..1], &many, None).unwrap_err().to_string();
        assert!(err.starts_with("resolution: the blockwise rbf fit solves an exact 867 x 867"), "{err}");
        assert!(parse("rbf", r#"{"resolution": 12}"#).unwrap().plan(&d[..1], &many, None).is_ok());
        assert!(e("bilinear", r#"{"regularization": -1}"#).starts_with("regularization:"));
        assert!(e("rbf", r#"{"bogus": 1}"#).contains("bogus"));
    }
}
