//! One view slot of a PTM as a model of its own: the single-view polynomial texture map of
//! Malzbender et al., which is what a `.ptm` file holds (the format has no view axis; paper 000,
//! section 3.1 fits one such map per view slot). `btfrs-io` reads and writes the files; the
//! layout of the slots inside [`Ptm`] is known only here.

use super::{Ptm, PtmKind, PtmPlanes};
use crate::planes::Planes;
use btfrs_core::{ensure_arg, Error, Result};

/// A single-view PTM: the coefficients of one view slot.
#[derive(Debug, Clone, PartialEq)]
pub struct PtmSlot {
    /// The variant.
    pub kind: PtmKind,
    /// Rows.
    pub height: usize,
    /// Columns.
    pub width: usize,
    /// Rgb: `[H, W, 3, 6]`; Lrgb: `[H, W, 6]`.
    pub coeffs: Vec<f32>,
    /// Lrgb only: `[H, W, 3]` base colour.
    pub rgb: Option<Vec<f32>>,
    /// The slot's 8-bit planes (`k` = 18 or 6, and 3 for the colours) when quantized; `coeffs`
    /// and `rgb` are then their decoded values.
    pub planes: Option<PtmPlanes>,
}

impl Ptm {
    /// The coefficients of view slot `view` (e.g. to write it as a `.ptm` file).
    ///
    /// Errors: `view` is not a slot index; the arrays disagree with the dimensions (a model that
    /// fails [`Ptm::validate`]).
    pub fn slot(&self, view: usize) -> Result<PtmSlot> {
        let nv = self.views.len();
        ensure_arg!(view < nv, "view", "expected a view slot index in [0, {nv}), got {view}");
        self.validate()?;
        let pc = self.per_coef();
        let texels = self.height * self.width;
        let pick = |src: &[f32], n: usize| -> Vec<f32> {
            (0..texels).flat_map(|t| src[(t * nv + view) * n..(t * nv + view + 1) * n].iter().copied()).collect()
        };
        let rgb = match (self.kind, &self.rgb) {
            (PtmKind::Lrgb, Some(r)) => Some(pick(r, 3)),
            (PtmKind::Rgb, _) => None,
            (PtmKind::Lrgb, None) => return Err(Error::arg("rgb", "an LRGB PTM needs its base colours")),
        };
        let sub = |p: &Planes, n: usize| -> Planes {
            let r = view * n..(view + 1) * n;
            Planes {
                texels,
                k: n,
                q: (0..texels).flat_map(|t| p.q[t * p.k + r.start..t * p.k + r.end].iter().copied()).collect(),
                scale: p.scale[r.clone()].to_vec(),
                bias: p.bias[r].to_vec(),
            }
        };
        let planes = self
            .quantized
            .as_ref()
            .map(|q| PtmPlanes { coeffs: sub(&q.coeffs, pc), rgb: q.rgb.as_ref().map(|r| sub(r, 3)) });
        Ok(PtmSlot {
            kind: self.kind,
            height: self.height,
            width: self.width,
            coeffs: pick(&self.coeffs, pc),
            rgb,
            planes,
        })
    }

    /// A one-slot model from a single-view PTM (e.g. one read from a `.ptm` file), its view
    /// the normal `(0, 0, 1)`; checked like a loaded model ([`Ptm::validate`]).
    pub fn from_slot(slot: PtmSlot) -> Result<Ptm> {
        let p = Ptm {
            kind: slot.kind,
            height: slot.height,
            width: slot.width,
            views: vec![[0.0, 0.0, 1.0]],
            coeffs: slot.coeffs,
            rgb: slot.rgb,
            degenerate_slots: Vec::new(),
            quantized: slot.planes,
        };
        p.validate()?;
        Ok(p)
    }
}
