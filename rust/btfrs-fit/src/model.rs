//! The contract every fitted model meets: evaluation and error against a BTF.
//!
//! A model answers *queries*: one (view, light) pair, prepared once (`query`), then evaluated at
//! every texel (`eval`). Splitting the two keeps per-pair work (interpolation weights over view
//! slots, basis functions of the light) out of the per-texel loop.

use btfrs_core::{metrics::ErrorSums, BtfRef, Error, Result};
use rayon::prelude::*;

/// A per-texel reflectance model over a `height x width` sample.
pub trait ReflectanceModel: Sync {
    /// Everything about one (view, light) pair that does not depend on the texel.
    type Query: Send + Sync;
    /// (height, width) in texels.
    fn dims(&self) -> (usize, usize);
    /// Prepare a query for unit directions `view` and `light` in the tangent frame.
    fn query(&self, view: [f64; 3], light: [f64; 3]) -> Self::Query;
    /// The model's RGB value at texel `t` (row-major index).
    fn eval(&self, t: usize, q: &Self::Query) -> [f32; 3];
}

/// A `[height, width, 3]` image of the model for one view and light.
pub fn evaluate_image<M: ReflectanceModel>(m: &M, view: [f64; 3], light: [f64; 3]) -> Result<Vec<f32>> {
    btfrs_core::directions::validate("view", &[view])?;
    btfrs_core::directions::validate("light", &[light])?;
    let (h, w) = m.dims();
    let q = m.query(view, light);
    let mut out = vec![0.0f32; h * w * 3];
    out.par_chunks_mut(3).enumerate().for_each(|(t, px)| px.copy_from_slice(&m.eval(t, &q)));
    Ok(out)
}

/// Error sums of the model against every present (view, light) pair of `btf`.
pub fn model_error<M: ReflectanceModel>(m: &M, btf: &BtfRef<'_>) -> Result<ErrorSums> {
    if m.dims() != (btf.height, btf.width) {
        return Err(Error::arg(
            "btf",
            format!("the model covers {:?} texels but the BTF has {} x {}", m.dims(), btf.height, btf.width),
        ));
    }
    let nl = btf.lights.len();
    let pairs: Vec<(usize, M::Query)> = (0..btf.views.len())
        .flat_map(|v| (0..nl).map(move |l| (v, l)))
        .filter(|&(v, l)| btf.has(v, l))
        .map(|(v, l)| ((v * nl + l) * 3, m.query(btf.views[v], btf.lights[l])))
        .collect();
    let sums = (0..btf.texels())
        .into_par_iter()
        .fold(ErrorSums::default, |mut acc, t| {
            let gt = btf.texel(t);
            for (off, q) in &pairs {
                let p = m.eval(t, q);
                for c in 0..3 {
                    acc.add(p[c] as f64, gt[off + c] as f64);
                }
            }
            acc
        })
        .reduce(ErrorSums::default, ErrorSums::merge);
    Ok(sums)
}

/// The measured BTF itself as a model: the value at any (view, light) is interpolated between
/// the three nearest measured views times the three nearest measured lights (weights of
/// [`btfrs_core::directions::interp_weights`]). The quality reference of every renderer and
/// model; it stores the whole BTF.
#[derive(Debug, Clone, Copy)]
pub struct RawModel<'a> {
    btf: BtfRef<'a>,
}

impl<'a> RawModel<'a> {
    /// Wrap a BTF; every (view, light) pair must be present (interpolating over a masked grid
    /// would silently use pairs the user held out).
    pub fn new(btf: BtfRef<'a>) -> Result<Self> {
        if btf.mask.is_some_and(|m| !m.iter().all(|&b| b)) {
            return Err(Error::arg("btf", "raw interpolation needs every (view, light) pair; this sample has a mask"));
        }
        Ok(RawModel { btf })
    }

    /// The wrapped BTF.
    pub fn btf(&self) -> &BtfRef<'a> {
        &self.btf
    }
}

/// View and light weights of a raw query.
#[derive(Debug, Clone)]
pub struct RawQuery {
    views: Vec<(usize, f32)>,
    lights: Vec<(usize, f32)>,
}

impl ReflectanceModel for RawModel<'_> {
    type Query = RawQuery;

    fn dims(&self) -> (usize, usize) {
        (self.btf.height, self.btf.width)
    }

    fn query(&self, view: [f64; 3], light: [f64; 3]) -> RawQuery {
        let w = |d: &[[f64; 3]], q| {
            btfrs_core::directions::interp_weights(d, q, 3).into_iter().map(|(i, w)| (i, w as f32)).collect()
        };
        RawQuery { views: w(self.btf.views, view), lights: w(self.btf.lights, light) }
    }

    #[inline]
    fn eval(&self, t: usize, q: &RawQuery) -> [f32; 3] {
        let nl = self.btf.lights.len();
        let texel = self.btf.texel(t);
        let mut out = [0.0f32; 3];
        for &(v, wv) in &q.views {
            for &(l, wl) in &q.lights {
                let s = &texel[(v * nl + l) * 3..(v * nl + l) * 3 + 3];
                for c in 0..3 {
                    out[c] += wv * wl * s[c];
                }
            }
        }
        out
    }
}
