//! The extrapolation guard of the Lafortune fit (paper 000, section 6: LM fits of sparse or
//! uneven samples "produce visual artifacts").
//!
//! Least squares only constrains the lobes *at* the samples. With few samples a lobe can grow a
//! large coefficient `C` and a high exponent `n` whose cosine stays below 1 at every sample but
//! exceeds it between them, where `s^n` then explodes: measured on the built-in grooves (16^2,
//! 5% of the pairs kept) such fits predict up to 10^4 times the texel's largest measured value on
//! the held-out pairs, and the held-out relative error reaches 10^2 to 10^4 while the error on
//! the fitted samples stays 0.6 and the LM reports convergence. Nothing in the LM can see it.
//!
//! The guard evaluates a converged fit on a fixed set of (view, light) pairs, the BTF's own
//! direction grid (every view with every light, present or not: the directions a held-out test
//! asks for, inside the cone the sampling covers) widened by rings of grazing directions up to
//! the horizon ([`GRAZING_DEG`]: a renderer asks for those at every silhouette, and a lobe with
//! `|C| > 1` that stays bounded inside the measured 75 degrees overflows f32 there; measured on
//! weave 32^2, Lafortune-Lum 3 rendered `inf` on a sphere before the rings were added), and compares the largest value of
//! the lobe sum `kd + sum max(s, 0)^n` (the BRDF without the `l_z` foreshortening, so a fit to
//! grazing samples is not flagged for the foreshortening alone) with the largest measured
//! `value / l_z` of that texel. A fit above [`K_EXTRAP`] times that is *extrapolating*; the driver
//! in `lafortune.rs` then drops to fewer lobes and finally to the diffuse closed form, and counts
//! the fit in `FitReport::extrapolated`.

use super::kernels::Layout;

/// A fit whose lobe sum somewhere on the check pairs exceeds this times the texel's largest
/// measured `value / l_z` is extrapolating. On the built-in materials (16^2, 90% to 5% of the
/// pairs kept) well-posed fits stay below 1.2 times (their peaks are sampled), while the runaway
/// fits of sparse sampling sit at 20 to 10^20 times; 3 separates the two with room on both sides
/// (a sharp highlight between sparse samples may legitimately peak above every sample).
pub const K_EXTRAP: f64 = 3.0;

/// At most this many check pairs (every `k`-th pair of the grid beyond it): each converged fit
/// costs one evaluation per check pair and lobe, a fraction of one LM iteration's cost at full
/// sampling.
pub const MAX_CHECK_PAIRS: usize = 8192;

/// Elevations (degrees) of the rings of grazing check directions added to the measured ones,
/// each with [`GRAZING_AZIMUTHS`] azimuths: beyond the UBO sampling's 75 degrees up to the
/// horizon.
pub const GRAZING_DEG: [f64; 3] = [80.0, 85.0, 89.0];
/// Azimuths per grazing ring (every 30 degrees).
pub const GRAZING_AZIMUTHS: usize = 12;

/// The grazing check directions: [`GRAZING_AZIMUTHS`] azimuths on each ring of [`GRAZING_DEG`].
pub(crate) fn grazing_rings() -> Vec<[f64; 3]> {
    GRAZING_DEG
        .iter()
        .flat_map(|&t| {
            (0..GRAZING_AZIMUTHS).map(move |k| {
                let (t, p) = (t.to_radians(), std::f64::consts::TAU * k as f64 / GRAZING_AZIMUTHS as f64);
                [t.sin() * p.cos(), t.sin() * p.sin(), t.cos()]
            })
        })
        .collect()
}

/// The check pairs as the products the lobes need: `a = lx vx`, `b = ly vy`, `c = lz vz`.
#[derive(Debug, Clone, Default)]
pub(crate) struct Guard {
    a: Vec<f64>,
    b: Vec<f64>,
    c: Vec<f64>,
}

impl Guard {
    /// The check pairs: every view with every light, both widened by the grazing rings, strided
    /// down to at most [`MAX_CHECK_PAIRS`].
    pub fn new(views: &[[f64; 3]], lights: &[[f64; 3]]) -> Self {
        let rings = grazing_rings();
        let views: Vec<[f64; 3]> = views.iter().chain(&rings).copied().collect();
        let lights: Vec<[f64; 3]> = lights.iter().chain(&rings).copied().collect();
        let total = views.len() * lights.len();
        let stride = total.div_ceil(MAX_CHECK_PAIRS).max(1);
        let mut g = Guard::default();
        for i in (0..total).step_by(stride) {
            let (v, l) = (views[i / lights.len()], lights[i % lights.len()]);
            if l[2] <= 0.0 {
                continue; // no light arrives from the horizon: the model is 0 there whatever the lobes
            }
            g.a.push(l[0] * v[0]);
            g.b.push(l[1] * v[1]);
            g.c.push(l[2] * v[2]);
        }
        g
    }

    /// The largest lobe sum `kd + sum max(Cx a + Cy b + Cz c, 0)^n` of the (normalised) theta
    /// `th` of layout `lay` over the check pairs; exponents are stored as `ln n`.
    pub fn peak(&self, lay: Layout, th: &[f64]) -> f64 {
        let kd = lay.kd(th);
        let lobes: Vec<[f64; 4]> = (0..lay.lobes)
            .map(|k| {
                let q = &th[lay.off() + 4 * k..lay.off() + 4 * k + 4];
                [q[0], q[1], q[2], q[3].exp()]
            })
            .collect();
        let mut peak = kd;
        for i in 0..self.a.len() {
            let mut f = kd;
            for q in &lobes {
                let s = q[0] * self.a[i] + q[1] * self.b[i] + q[2] * self.c[i];
                if s > 0.0 {
                    f += s.powf(q[3]);
                }
            }
            // A NaN lobe sum is treated as infinite (always extrapolating).
            if f.is_nan() {
                peak = f64::INFINITY;
            } else if f > peak {
                peak = f;
            }
        }
        peak
    }

    /// Whether `th` extrapolates: its peak exceeds [`K_EXTRAP`] times `fmax`, the largest
    /// measured `value / l_z` (normalised as `th` is).
    pub fn extrapolates(&self, lay: Layout, th: &[f64], fmax: f64) -> bool {
        self.peak(lay, th) > K_EXTRAP * fmax.max(0.0)
    }
}

#[cfg(test)]
mod tests {
    use super::super::{fit_lafortune, LafortuneOptions};
    use super::K_EXTRAP;
    use crate::model::model_error;
    use btfrs_core::materials::{generate, MaterialSpec, Preset};
    use btfrs_core::split::split_pairs;
    use btfrs_core::{BtfRef, Monitor};

    /// The largest lobe sum (the model without `l_z`) of a Lum fit `p = [kd, (C, n) x lobes]` over
    /// every pair of `views x lights`, in plain f64 with `powf`: independent of the guard's code.
    fn peak(p: &[f32], lobes: usize, views: &[[f64; 3]], lights: &[[f64; 3]]) -> f64 {
        let mut best = 0.0f64;
        for v in views {
            for l in lights.iter().filter(|l| l[2] > 0.0) {
                let mut f = p[0] as f64;
                for k in 0..lobes {
                    let q = &p[1 + 4 * k..5 + 4 * k];
                    let s = q[0] as f64 * l[0] * v[0] + q[1] as f64 * l[1] * v[1] + q[2] as f64 * l[2] * v[2];
                    if s > 0.0 {
                        f += s.powf(q[3] as f64);
                    }
                }
                best = best.max(f);
            }
        }
        best
    }

    /// Per texel, the largest measured luminance / l_z over the present pairs.
    fn measured_max(btf: &BtfRef<'_>, t: usize) -> f64 {
        let (nv, nl) = (btf.views.len(), btf.lights.len());
        let x = btf.texel(t);
        (0..nv * nl)
            .filter(|&i| btf.has(i / nl, i % nl) && btf.lights[i % nl][2] > 1e-3)
            .map(|i| (x[3 * i] as f64 + x[3 * i + 1] as f64 + x[3 * i + 2] as f64) / 3.0 / btf.lights[i % nl][2])
            .fold(0.0, f64::max)
    }

    /// Every texel's fitted lobes stay within `K_EXTRAP` times its data on the whole grid.
    fn assert_bounded(btf: &BtfRef<'_>, m: &super::super::Lafortune) {
        let pp = m.params_per_fit();
        for t in 0..btf.texels() {
            let got = peak(&m.params[t * pp..(t + 1) * pp], m.lobes, btf.views, btf.lights);
            let lim = K_EXTRAP * measured_max(btf, t);
            assert!(got <= lim * 1.001 + 1e-9, "texel {t}: peak {got} > {lim} ({:?})", m.report);
        }
    }

    #[test]
    fn sparse_pairs_no_longer_extrapolate() {
        // Grooves 16^2 with 5% of the pairs: before the guard, 2-lobe LM fits converged on the
        // samples to lobes peaking at up to 10^4 times the data on the other pairs (held-out
        // relative error 170 with this split); now they are flagged and replaced.
        let mat = generate(&MaterialSpec::new(Preset::Grooves, 16, 0), &Monitor::new()).unwrap();
        let full = mat.as_ref();
        let (train, test) = split_pairs(81, 81, None, 0.95, 0).unwrap();
        let tr = BtfRef::new(16, 16, full.views, full.lights, full.data, Some(&train)).unwrap();
        let te = BtfRef::new(16, 16, full.views, full.lights, full.data, Some(&test)).unwrap();
        let m = fit_lafortune(&tr, &LafortuneOptions::default(), &Monitor::new()).unwrap();
        assert!(m.report.extrapolated > 0, "{:?}", m.report);
        assert!(m.report.extrapolated <= m.report.fell_back + m.report.failed, "{:?}", m.report);
        assert_bounded(&tr, &m);
        let held_out = model_error(&m, &te).unwrap().relative();
        assert!(held_out < 1.0, "held-out relative error {held_out} ({:?})", m.report);
    }

    #[test]
    fn a_narrow_cone_of_samples_does_not_grow_lobes_outside_it() {
        // Views and lights only within 30 degrees of the normal (19 x 19 of the 81 x 81 pairs):
        // nothing is known about grazing directions, and the lobes must not explode there.
        let mat = generate(&MaterialSpec::new(Preset::Knit, 8, 3), &Monitor::new()).unwrap();
        let full = mat.as_ref();
        let cone = |d: [f64; 3]| d[2] >= 30f64.to_radians().cos() - 1e-9;
        let mask: Vec<bool> = (0..81 * 81).map(|i| cone(full.views[i / 81]) && cone(full.lights[i % 81])).collect();
        assert_eq!(mask.iter().filter(|&&m| m).count(), 19 * 19);
        let tr = BtfRef::new(8, 8, full.views, full.lights, full.data, Some(&mask)).unwrap();
        let m = fit_lafortune(&tr, &LafortuneOptions { lobes: 3, ..Default::default() }, &Monitor::new()).unwrap();
        assert_bounded(&tr, &m);
        assert!(m.params.iter().all(|x| x.is_finite()));
    }

    #[test]
    fn full_sampling_does_not_overflow_at_grazing_directions() {
        // Weave with every pair: 3-lobe fits are well posed inside the measured 75 degrees, but
        // before the grazing rings some grew |C| > 1 lobes that overflowed to inf at
        // (view 80, light 89 degrees) on a rendered sphere. Checked here on rings *between* the
        // guard's own (82 and 87 degrees, 7 azimuths), so the bound is not the guard grading itself;
        // between its rings a lobe may rise a little above K_EXTRAP, hence the slack of 2.
        let mat = generate(&MaterialSpec::new(Preset::Weave, 12, 2), &Monitor::new()).unwrap();
        let btf = mat.as_ref();
        let m = fit_lafortune(&btf, &LafortuneOptions { lobes: 3, ..Default::default() }, &Monitor::new()).unwrap();
        let ring: Vec<[f64; 3]> = [82.0f64, 87.0]
            .iter()
            .flat_map(|&t| {
                (0..7).map(move |k| {
                    let (t, p) = (t.to_radians(), 0.4 + std::f64::consts::TAU * k as f64 / 7.0);
                    [t.sin() * p.cos(), t.sin() * p.sin(), t.cos()]
                })
            })
            .collect();
        let views: Vec<[f64; 3]> = btf.views.iter().chain(&ring).copied().collect();
        let lights: Vec<[f64; 3]> = btf.lights.iter().chain(&ring).copied().collect();
        let pp = m.params_per_fit();
        for t in 0..btf.texels() {
            let got = peak(&m.params[t * pp..(t + 1) * pp], m.lobes, &views, &lights);
            let lim = 2.0 * K_EXTRAP * measured_max(&btf, t);
            assert!(got.is_finite() && got <= lim, "texel {t}: peak {got} > {lim} ({:?})", m.report);
        }
    }
}
