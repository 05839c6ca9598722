//! Built-in procedural materials: BTFs computed from a periodic heightfield.
//!
//! Each preset ([`Preset`]) defines, over a sample of `size x size` texels that tiles seamlessly,
//! a height, an albedo and a glossy Blinn-Phong lobe. A BTF image for view `v` and light `l` is then
//! made the way a measured one is:
//!
//! 1. **Masking and parallax**: the camera sees texel `(i, j)` through the point of the mean-height
//!    reference plane above it; the ray from there along `-v` is marched through the heightfield and
//!    the first hit is the surface point that texel shows (see [`shade::hit_points`]).
//! 2. **Cast shadows**: for every light a visibility map over the surface is computed by marching
//!    from each surface point towards the light, with a soft penumbra (see [`shade::shadow_maps`]).
//! 3. **Shading**: `value = vis * max(n.l, 0) * (albedo + ks (e+8)/8 (n.h)^e) + ambient`, i.e. pi
//!    times a normalised Blinn-Phong BRDF times cos(theta_l), so values include the foreshortening
//!    as measured BTFs do (paper 004, section 3); a small unshadowed ambient term stands in for
//!    inter-reflection so that shadows are dark but not black.
//! 4. Optionally a sub-surface-like blur mixes each texel's ABRDF with its neighbours'.
//!
//! Everything is deterministic for a given seed and parallel over texels with rayon.

mod presets;
mod shade;

pub use presets::Preset;

use crate::{directions, Btf, Error, Monitor, Result};

/// What to generate.
#[derive(Debug, Clone)]
pub struct MaterialSpec {
    /// Which surface.
    pub preset: Preset,
    /// Texels per side (16 to 256 are the supported range; 8 to 1024 are accepted).
    pub size: usize,
    /// View directions (unit, z >= 0).
    pub views: Vec<[f64; 3]>,
    /// Light directions (unit, z >= 0).
    pub lights: Vec<[f64; 3]>,
    /// Seed of every random choice (cell variation, noise).
    pub seed: u64,
    /// Multiplier of the preset's relief height (1 = the preset's own; 0 = flat).
    pub relief: f64,
    /// Strength in [0, 1) of the sub-surface-like blur between neighbouring texels.
    pub subsurface: f64,
}

impl MaterialSpec {
    /// The preset at `size` texels with the UBO 81 x 81 directions, default relief, no blur.
    pub fn new(preset: Preset, size: usize, seed: u64) -> Self {
        let d = directions::ubo81();
        MaterialSpec { preset, size, views: d.clone(), lights: d, seed, relief: 1.0, subsurface: 0.0 }
    }

    fn validate(&self) -> Result<()> {
        if !(8..=1024).contains(&self.size) {
            return Err(Error::arg("size", format!("expected 8 to 1024 texels per side, got {}", self.size)));
        }
        directions::validate("views", &self.views)?;
        directions::validate("lights", &self.lights)?;
        if !(self.relief.is_finite() && (0.0..=4.0).contains(&self.relief)) {
            return Err(Error::arg("relief", format!("expected a multiplier in [0, 4], got {}", self.relief)));
        }
        if !(self.subsurface.is_finite() && (0.0..1.0).contains(&self.subsurface)) {
            return Err(Error::arg("subsurface", format!("expected a value in [0, 1), got {}", self.subsurface)));
        }
        Ok(())
    }

    /// The number of values, `size^2 V L 3`.
    pub fn values(&self) -> usize {
        self.size * self.size * self.views.len() * self.lights.len() * 3
    }
}

/// Generate the BTF described by `spec` in memory (at most 8 GiB of values; larger ones go to
/// a file with [`generate_into`]). `monitor` counts texel rows and can cancel.
pub fn generate(spec: &MaterialSpec, monitor: &Monitor) -> Result<Btf> {
    spec.validate()?;
    let bytes = spec.values() as u128 * 4;
    if bytes > 8u128 << 30 {
        return Err(Error::arg(
            "size",
            format!(
                "the BTF would take {:.1} GiB; the limit in memory is 8 GiB (write it to a file instead)",
                bytes as f64 / (1u64 << 30) as f64
            ),
        ));
    }
    let surface = presets::surface(spec.preset, spec.size, spec.seed, spec.relief);
    let data = shade::render_btf(&surface, &spec.views, &spec.lights, spec.subsurface, monitor)?;
    Ok(Btf { height: spec.size, width: spec.size, views: spec.views.clone(), lights: spec.lights.clone(), data })
}

/// The surface a material is generated from, in the BTF's texel order (row 0 at the top, x
/// right, y up the image): heights in texel units, unit normals (central differences of the
/// periodic heights, the normals the shading uses at texel centres) and albedo.
#[derive(Debug, Clone)]
pub struct Heightfield {
    /// Texels per side.
    pub size: usize,
    /// `[size * size]` heights, in texel widths.
    pub height: Vec<f32>,
    /// `[size * size]` unit normals (x right, y up the image, z out of the surface).
    pub normals: Vec<[f32; 3]>,
    /// `[size * size]` diffuse albedo (RGB).
    pub albedo: Vec<[f32; 3]>,
}

/// The heightfield, normals and albedo of a preset, as [`generate`] uses them for the same
/// `preset`, `size`, `seed` and `relief` (checked like [`MaterialSpec`]'s).
pub fn heightfield(preset: Preset, size: usize, seed: u64, relief: f64) -> Result<Heightfield> {
    let spec = MaterialSpec { relief, ..MaterialSpec::new(preset, size, seed) };
    spec.validate()?;
    let s = presets::surface(preset, size, seed, relief);
    // The surface's grid has row 0 at the bottom; the BTF's row 0 is the top.
    let flip = |g: usize| (size - 1 - g / size) * size + g % size;
    Ok(Heightfield {
        size,
        height: (0..size * size).map(|g| s.height[flip(g)]).collect(),
        normals: (0..size * size).map(|g| s.normal[flip(g)]).collect(),
        albedo: (0..size * size).map(|g| s.albedo[flip(g)]).collect(),
    })
}

/// Generate the values of the BTF described by `spec` into `out` (`[size, size, V, L, 3]`, all
/// [`MaterialSpec::values`] of them), e.g. a memory-mapped file, with no size limit: besides
/// `out` the generation holds the surface, the visibility maps (`V + L` values per texel) and
/// three texel rows. The same values as [`generate`].
pub fn generate_into(spec: &MaterialSpec, out: &mut [f32], monitor: &Monitor) -> Result<()> {
    spec.validate()?;
    if out.len() != spec.values() {
        return Err(Error::arg("out", format!("expected {} values, got {}", spec.values(), out.len())));
    }
    let surface = presets::surface(spec.preset, spec.size, spec.seed, spec.relief);
    shade::render_btf_into(&surface, &spec.views, &spec.lights, spec.subsurface, out, monitor)
}

#[cfg(test)]
mod tests;
