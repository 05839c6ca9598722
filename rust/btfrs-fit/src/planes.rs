//! 8-bit coefficient planes with a scale and a bias per plane: the storage of the light bases
//! RTI viewers hold (`.ptm`, `.rti`, relight's planes), shared by the PTM, HSH, RBF and bilinear
//! models so that their `nbytes` is what a viewer keeps in memory.
//!
//! A model with `k` coefficients per texel (all view slots and channels included) stores them
//! texel-major as `q[t * k + p]`, one byte each, and decodes plane `p` as
//! `value = bias[p] + scale[p] * q`. Quantization is uniform over each plane's range
//! (`bias` its minimum, `scale = (max - min) / 255`), so the decoded value is within
//! `scale / 2` of the fitted one; a constant plane gets `scale = 0`.
//!
//! On the GPU the bytes are packed four to a 32-bit word in little-endian order (byte `i` of the
//! model is bits `8 (i % 4) ..` of word `i / 4`), read by `load_byte` in `common.wgsl`-style
//! helpers of each shader; scale and bias are two arrays of `k` f32 words.

use btfrs_core::arrays::ArrayData;
use btfrs_core::{Error, NamedArrays, Result};
use rayon::prelude::*;

/// `k` 8-bit planes over `texels` texels, with per-plane scale and bias.
#[derive(Debug, Clone, PartialEq)]
pub struct Planes {
    /// Texels.
    pub texels: usize,
    /// Planes (coefficients per texel).
    pub k: usize,
    /// `texels * k` bytes, texel-major.
    pub q: Vec<u8>,
    /// Per-plane scale (`k`).
    pub scale: Vec<f32>,
    /// Per-plane bias (`k`).
    pub bias: Vec<f32>,
}

/// The smallest and largest value of each of the `k` planes of `values` (`texels * k`,
/// texel-major; infinities for none): blocks of texels in parallel, plane by plane with no
/// lookup in the inner loop, so that it vectorises. The quantizers join these per group.
pub fn plane_ranges(values: &[f32], k: usize) -> (Vec<f32>, Vec<f32>) {
    let empty = || (vec![f32::INFINITY; k], vec![f32::NEG_INFINITY; k]);
    if k == 0 {
        return empty();
    }
    values
        .par_chunks(k * 256)
        .fold(empty, |(mut lo, mut hi), block| {
            for t in block.chunks_exact(k) {
                for ((l, h), &x) in lo.iter_mut().zip(hi.iter_mut()).zip(t) {
                    *l = l.min(x);
                    *h = h.max(x);
                }
            }
            (lo, hi)
        })
        .reduce(empty, |(mut a, mut b), (c, d)| {
            for p in 0..k {
                a[p] = a[p].min(c[p]);
                b[p] = b[p].max(d[p]);
            }
            (a, b)
        })
}

impl Planes {
    /// Quantize `values` (`texels * k`, texel-major, finite) plane by plane.
    pub fn quantize(values: &[f32], k: usize) -> Result<Planes> {
        Planes::quantize_grouped(values, k, k, |p| p, |step| step as f32)
    }

    /// [`Planes::quantize`] with planes sharing a scale and bias: plane `p` belongs to group
    /// `group_of(p)` (`< groups`), each group spans the range of all its planes, and its scale is
    /// `step((max - min) / 255)` (a format may need the scale rounded, e.g. `.rti`'s).
    pub fn quantize_grouped(
        values: &[f32],
        k: usize,
        groups: usize,
        group_of: impl Fn(usize) -> usize + Sync,
        step: impl Fn(f64) -> f32,
    ) -> Result<Planes> {
        if k == 0 || !values.len().is_multiple_of(k) {
            return Err(Error::arg(
                "planes",
                format!("{} values are not a whole number of {k}-plane texels", values.len()),
            ));
        }
        if let Some(i) = btfrs_core::btf::first_non_finite(values) {
            return Err(Error::arg("planes", format!("coefficient at flat index {i} is not finite")));
        }
        let texels = values.len() / k;
        let (plo, phi) = plane_ranges(values, k);
        let (mut lo, mut hi) = (vec![f32::INFINITY; groups], vec![f32::NEG_INFINITY; groups]);
        for p in 0..k {
            let g = group_of(p);
            lo[g] = lo[g].min(plo[p]);
            hi[g] = hi[g].max(phi[p]);
        }
        let mut gscale = vec![0.0f32; groups];
        let mut gbias = vec![0.0f32; groups];
        for g in 0..groups {
            if lo[g] <= hi[g] {
                gbias[g] = lo[g];
                gscale[g] = step((hi[g] as f64 - lo[g] as f64) / 255.0);
            }
        }
        let scale: Vec<f32> = (0..k).map(|p| gscale[group_of(p)]).collect();
        let bias: Vec<f32> = (0..k).map(|p| gbias[group_of(p)]).collect();
        // Texel by texel against the planes' reciprocal scales (0 for a constant plane), rounded
        // half up: every value is at least its plane's bias, so `(v + 0.5) as u8` (truncation,
        // saturating) is the nearest step. Branch-free and without a division or a call to
        // `round` per value, the loop vectorises: with the chunked finite check above, the 8-bit
        // planes of HSH order 3 of a 1200 x 800 x 60 capture took 0.10 s of CPU instead of 0.97 s.
        let (inv, bf): (Vec<f64>, Vec<f64>) =
            scale.iter().zip(&bias).map(|(&s, &b)| (if s > 0.0 { 1.0 / s as f64 } else { 0.0 }, b as f64)).unzip();
        let mut q = vec![0u8; values.len()];
        q.par_chunks_mut(k * 64).zip(values.par_chunks(k * 64)).for_each(|(q, x)| {
            for (q, x) in q.chunks_exact_mut(k).zip(x.chunks_exact(k)) {
                for (((q, &x), &r), &b) in q.iter_mut().zip(x).zip(&inv).zip(&bf) {
                    *q = ((x as f64 - b) * r + 0.5).min(255.0) as u8;
                }
            }
        });
        Ok(Planes { texels, k, q, scale, bias })
    }

    /// The planes of `texels` (in that order), with the same scales and biases.
    pub fn select(&self, texels: &[usize]) -> Planes {
        let k = self.k;
        let q = texels.iter().flat_map(|&t| self.q[t * k..(t + 1) * k].iter().copied()).collect();
        Planes { texels: texels.len(), k, q, scale: self.scale.clone(), bias: self.bias.clone() }
    }

    /// The decoded value of plane `p` at texel `t`.
    #[inline]
    pub fn get(&self, t: usize, p: usize) -> f32 {
        self.bias[p] + self.scale[p] * self.q[t * self.k + p] as f32
    }

    /// Every decoded value (`texels * k`, texel-major).
    pub fn dequantize(&self) -> Vec<f32> {
        let mut out = Vec::new();
        self.dequantize_into(&mut out);
        out
    }

    /// [`Planes::dequantize`] into `out` (resized to the values' count), reusing its buffer.
    pub fn dequantize_into(&self, out: &mut Vec<f32>) {
        out.resize(self.q.len(), 0.0);
        // Texel by texel against the planes (no division of the index per value).
        let k = self.k.max(1);
        out.par_chunks_mut(k * 64).zip(self.q.par_chunks(k * 64)).for_each(|(o, q)| {
            for (o, q) in o.chunks_exact_mut(k).zip(q.chunks_exact(k)) {
                for (((o, &b), &s), &c) in o.iter_mut().zip(q).zip(&self.scale).zip(&self.bias) {
                    *o = c + s * b as f32;
                }
            }
        });
    }

    /// The bytes packed four to a little-endian 32-bit word (the GPU store; zero padded).
    pub fn words(&self) -> Vec<u32> {
        self.q.chunks(4).map(|c| c.iter().enumerate().fold(0u32, |w, (i, &b)| w | (b as u32) << (8 * i))).collect()
    }

    /// Scale then bias as f32 bit patterns (`2 k` words).
    pub fn scale_bias_words(&self) -> Vec<u32> {
        self.scale.iter().chain(&self.bias).map(|x| x.to_bits()).collect()
    }

    /// Bytes a viewer holds: one per coefficient plus the two per-plane float arrays.
    pub fn nbytes(&self) -> usize {
        self.q.len() + 8 * self.k
    }

    /// Store as `{prefix}q` (u8, `shape` = texel dims + coefficient dims, their product
    /// `texels * k`), `{prefix}scale` and `{prefix}bias` (f32, `[k]`).
    pub fn insert_into(&self, arrays: &mut NamedArrays, prefix: &str, shape: Vec<usize>) {
        arrays.put(&format!("{prefix}q"), &shape, self.q.clone());
        arrays.put(&format!("{prefix}scale"), &[self.k], self.scale.clone());
        arrays.put(&format!("{prefix}bias"), &[self.k], self.bias.clone());
    }

    /// Read back what [`Planes::insert_into`] stored, checking that `{prefix}q` holds
    /// `texels * k` bytes and that scale and bias are `k` finite values, scale non-negative.
    pub fn from_arrays(arrays: &NamedArrays, prefix: &str, texels: usize, k: usize) -> Result<Planes> {
        let qn = format!("{prefix}q");
        let a = arrays.array(&qn).ok_or_else(|| Error::arg(&qn, "missing array"))?;
        let ArrayData::U8(q) = &a.data else {
            return Err(Error::format(&qn, format!("expected dtype uint8, got {}", a.data.dtype())));
        };
        let q = q.clone();
        if q.len() != texels * k {
            return Err(Error::format(&qn, format!("expected {texels} x {k} bytes, got {}", q.len())));
        }
        let get = |name: &str| -> Result<Vec<f32>> {
            let n = format!("{prefix}{name}");
            let v = arrays.get::<f32>(&n, &[Some(k)])?.0.to_vec();
            if v.len() != k {
                return Err(Error::format(&n, format!("expected {k} values, got {}", v.len())));
            }
            if let Some(i) = v.iter().position(|x| !x.is_finite() || (name == "scale" && *x < 0.0)) {
                return Err(Error::format(
                    &n,
                    format!(
                        "value {i} ({}) is not a finite{} number",
                        v[i],
                        if name == "scale" { " non-negative" } else { "" }
                    ),
                ));
            }
            Ok(v)
        };
        let scale = get("scale")?;
        let bias = get("bias")?;
        Ok(Planes { texels, k, q, scale, bias })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantization_error_is_at_most_half_a_step_per_plane() {
        let k = 5;
        let vals: Vec<f32> =
            (0..k * 300).map(|i| ((i * 7919) % 1000) as f32 * 0.01 * (1 + i % k) as f32 - 3.0).collect();
        let p = Planes::quantize(&vals, k).unwrap();
        let back = p.dequantize();
        for (i, (&a, &b)) in vals.iter().zip(&back).enumerate() {
            assert!((a - b).abs() <= p.scale[i % k] * 0.5 + 1e-5, "{i}: {a} vs {b}");
            assert_eq!(b, p.get(i / k, i % k));
        }
        // the extremes of every plane (300 texels: two blocks of the parallel range pass) are
        // the bias and the top of the plane's 255 steps
        for pl in 0..k {
            let col: Vec<f32> = vals.iter().skip(pl).step_by(k).copied().collect();
            let lo = col.iter().cloned().fold(f32::INFINITY, f32::min);
            let hi = col.iter().cloned().fold(f32::NEG_INFINITY, f32::max);
            assert_eq!(p.bias[pl], lo);
            assert!((p.bias[pl] + 255.0 * p.scale[pl] - hi).abs() <= 1e-5 * hi.abs().max(1.0), "plane {pl}");
            assert_eq!(plane_ranges(&vals, k).1[pl], hi);
        }
    }

    #[test]
    fn constant_plane_and_word_packing() {
        let vals = vec![2.0f32, 0.0, 2.0, 100.0, 2.0, 510.0];
        let p = Planes::quantize(&vals, 2).unwrap();
        assert_eq!(p.scale[0], 0.0);
        assert_eq!(p.get(1, 0), 2.0);
        assert_eq!(p.q, vec![0, 0, 0, 50, 0, 255]);
        assert_eq!(p.words(), vec![50 << 24, 255 << 8]);
        assert_eq!(p.nbytes(), 6 + 16);
    }

    #[test]
    fn bad_input_is_named() {
        assert!(Planes::quantize(&[1.0, f32::NAN], 2).unwrap_err().to_string().contains("not finite"));
        assert!(Planes::quantize(&[1.0, 2.0, 3.0], 2).is_err());
        let p = Planes::quantize(&[1.0, 2.0, 3.0, 4.0], 2).unwrap();
        let mut a = NamedArrays::new();
        p.insert_into(&mut a, "c_", vec![2, 2]);
        assert_eq!(Planes::from_arrays(&a, "c_", 2, 2).unwrap(), p);
        assert!(Planes::from_arrays(&a, "c_", 3, 2).unwrap_err().to_string().contains("c_q"));
    }
}
