//! What a model must provide to be drawn: its shader and its data, laid out for that shader.
//!
//! Adding a model = a WGSL file in `shaders_wgsl/` (defining `ViewQuery`, `view_query`,
//! `eval_model`), a [`Shader`] variant naming it, and a [`GpuModel`] impl that lists the arrays
//! and the parameter words the shader reads. The CPU reference needs nothing more: it uses the
//! model's own [`ReflectanceModel`] evaluation.

use btfrs_fit::{Ptm, PtmKind, RawModel, ReflectanceModel};
use std::borrow::Cow;

/// The model shaders.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Shader {
    /// `raw.wgsl`
    Raw,
    /// `ptm.wgsl`
    Ptm,
    /// A model shader given as source (tests and experiments; the pipeline is cached per source).
    Custom(&'static str),
}

impl Shader {
    /// The file name without extension.
    pub fn name(self) -> &'static str {
        match self {
            Shader::Raw => "raw",
            Shader::Ptm => "ptm",
            Shader::Custom(_) => "custom",
        }
    }

    /// The model's WGSL (without `common.wgsl`).
    pub fn source(self) -> &'static str {
        match self {
            Shader::Raw => crate::shaders::RAW,
            Shader::Ptm => crate::shaders::PTM,
            Shader::Custom(src) => src,
        }
    }
}

/// A model the GPU renderer can draw.
pub trait GpuModel: Sync {
    /// Which shader evaluates it.
    fn shader(&self) -> Shader;
    /// (height, width) of the sample in texels.
    fn dims(&self) -> (usize, usize);
    /// The arrays the shader reads, in order; they are concatenated into the model store.
    fn gpu_parts(&self) -> Vec<Cow<'_, [f32]>>;
    /// The measured direction sets the shader searches (`mdirs`), concatenated.
    fn gpu_dirs(&self) -> Vec<[f32; 4]>;
    /// The 16 parameter words, given the store offset of each part.
    fn gpu_params(&self, offsets: &[u32]) -> [u32; 16];
}

fn dirs4(d: &[[f64; 3]]) -> impl Iterator<Item = [f32; 4]> + '_ {
    d.iter().map(|v| [v[0] as f32, v[1] as f32, v[2] as f32, 0.0])
}

impl GpuModel for Ptm {
    fn shader(&self) -> Shader {
        Shader::Ptm
    }

    fn dims(&self) -> (usize, usize) {
        ReflectanceModel::dims(self)
    }

    fn gpu_parts(&self) -> Vec<Cow<'_, [f32]>> {
        let mut p = vec![Cow::Borrowed(&self.coeffs[..])];
        if let Some(rgb) = &self.rgb {
            p.push(Cow::Borrowed(&rgb[..]));
        }
        p
    }

    fn gpu_dirs(&self) -> Vec<[f32; 4]> {
        dirs4(&self.views).collect()
    }

    fn gpu_params(&self, offsets: &[u32]) -> [u32; 16] {
        let mut w = [0u32; 16];
        w[0] = match self.kind {
            PtmKind::Rgb => 0,
            PtmKind::Lrgb => 1,
        };
        w[1] = self.views.len() as u32;
        w[3] = offsets[0];
        w[4] = offsets.get(1).copied().unwrap_or(0);
        w
    }
}

impl GpuModel for RawModel<'_> {
    fn shader(&self) -> Shader {
        Shader::Raw
    }

    fn dims(&self) -> (usize, usize) {
        ReflectanceModel::dims(self)
    }

    fn gpu_parts(&self) -> Vec<Cow<'_, [f32]>> {
        vec![Cow::Borrowed(self.btf().data)]
    }

    fn gpu_dirs(&self) -> Vec<[f32; 4]> {
        dirs4(self.btf().views).chain(dirs4(self.btf().lights)).collect()
    }

    fn gpu_params(&self, offsets: &[u32]) -> [u32; 16] {
        let b = self.btf();
        let mut w = [0u32; 16];
        w[0] = b.views.len() as u32;
        w[1] = b.lights.len() as u32;
        w[4] = offsets[0];
        w
    }
}
