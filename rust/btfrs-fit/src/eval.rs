//! Evaluation, the half of the model contract every consumer shares: the fit's own models
//! ([`crate::model`]), their GPU layouts ([`crate::gpu`]) and the CPU reference renderer.
//!
//! A model answers *queries*: one (view, light) pair, prepared once ([`ReflectanceModel::query`]),
//! then evaluated at every texel ([`ReflectanceModel::eval`]). Splitting the two keeps per-pair
//! work (interpolation weights over view slots, basis functions of the light) out of the
//! per-texel loop. [`Shade`] is its object-safe form. It sits apart from [`crate::model`] so that
//! the model contract and the GPU layout can both build on it without importing each other.

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

impl<M: ReflectanceModel + ?Sized> ReflectanceModel for &M {
    type Query = M::Query;
    fn dims(&self) -> (usize, usize) {
        (**self).dims()
    }
    fn query(&self, view: [f64; 3], light: [f64; 3]) -> M::Query {
        (**self).query(view, light)
    }
    #[inline]
    fn eval(&self, t: usize, q: &M::Query) -> [f32; 3] {
        (**self).eval(t, q)
    }
}

/// Evaluation of one texel at one (view, light) pair without a prepared query: the object-safe
/// form of [`ReflectanceModel`] that the CPU reference renderer uses (it prepares a query per
/// fragment and light anyway).
pub trait Shade: Sync {
    /// (height, width) in texels.
    fn shade_dims(&self) -> (usize, usize);
    /// The RGB value at texel `t`.
    fn shade(&self, t: usize, view: [f64; 3], light: [f64; 3]) -> [f32; 3];
}

impl<M: ReflectanceModel> Shade for M {
    fn shade_dims(&self) -> (usize, usize) {
        self.dims()
    }
    fn shade(&self, t: usize, view: [f64; 3], light: [f64; 3]) -> [f32; 3] {
        self.eval(t, &self.query(view, light))
    }
}
