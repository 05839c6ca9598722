//! How the per-texel Lafortune and double-SH models are laid out for their shaders
//! (`lafortune.wgsl`, `sh.wgsl`); LPCA is in [`crate::lpca`], PTM, SRF and the raw BTF in
//! [`crate::model`].

use crate::model::{words, GpuModel, Shader};
use btfrs_fit::{Lafortune, LafortuneKind, ReflectanceModel, Sh, ShCoeffs};
use std::borrow::Cow;

impl GpuModel for Lafortune {
    fn shader(&self) -> Shader {
        Shader::Lafortune
    }

    fn dims(&self) -> (usize, usize) {
        ReflectanceModel::dims(self)
    }

    fn gpu_parts(&self) -> Vec<Cow<'_, [u32]>> {
        let mut p = vec![words(&self.params)];
        if let Some(rgb) = &self.rgb {
            p.push(words(rgb));
        }
        p
    }

    fn gpu_dir_sets(&self) -> Vec<&[[f64; 3]]> {
        Vec::new()
    }

    fn gpu_params(&self, offsets: &[u32], _tables: &[u32]) -> [u32; 16] {
        let mut w = [0u32; 16];
        w[0] = match self.kind {
            LafortuneKind::Rgb => 0,
            LafortuneKind::Lum => 1,
        };
        w[1] = self.lobes as u32;
        w[2] = offsets[0];
        w[3] = offsets.get(1).copied().unwrap_or(0);
        w
    }
}

/// Repack `[texel][3][kv][kl]` bytes into rows of `ceil(kl / 4)` little-endian words (zero
/// padded), so the shader reads each row with whole-word loads.
pub fn sh_words(q: &[u8], kv: usize, kl: usize) -> Vec<u32> {
    let rw = kl.div_ceil(4);
    let rows = q.len() / kl;
    let mut out = vec![0u32; rows * rw];
    for (r, row) in q.chunks_exact(kl).enumerate() {
        for (j, &b) in row.iter().enumerate() {
            out[r * rw + j / 4] |= (b as u32) << (8 * (j % 4));
        }
    }
    let _ = kv;
    out
}

impl GpuModel for Sh {
    fn shader(&self) -> Shader {
        Shader::Sh
    }

    fn dims(&self) -> (usize, usize) {
        ReflectanceModel::dims(self)
    }

    fn gpu_parts(&self) -> Vec<Cow<'_, [u32]>> {
        // The shader reads 8-bit coefficients; an unquantized model is quantized for the GPU.
        let (q, scale, bias) = match &self.coeffs {
            ShCoeffs::Quantized { q, scale, bias } => (Cow::Borrowed(&q[..]), *scale, *bias),
            ShCoeffs::Float(c) => {
                let (q, s, b) = btfrs_fit::sh::quantize(c, self.view_coeffs * self.light_coeffs);
                (Cow::Owned(q), s, b)
            }
        };
        let sb: Vec<u32> = scale.iter().chain(&bias).map(|x| x.to_bits()).collect();
        vec![Cow::Owned(sb), Cow::Owned(sh_words(&q, self.view_coeffs, self.light_coeffs))]
    }

    fn gpu_dir_sets(&self) -> Vec<&[[f64; 3]]> {
        Vec::new()
    }

    fn gpu_params(&self, offsets: &[u32], _tables: &[u32]) -> [u32; 16] {
        let mut w = [0u32; 16];
        w[0] = self.view_coeffs as u32;
        w[1] = self.light_coeffs as u32;
        w[2] = offsets[0];
        w[3] = offsets[1];
        w
    }
}
