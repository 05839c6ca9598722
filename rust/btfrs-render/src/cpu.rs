//! The CPU reference renderer: the same scene, the same sample points, the same shading.
//!
//! [`crate::raster`] rasterises the mesh with the GPU's rules (pixel centres, top-left fill
//! rule, sub-pixel snapping, perspective-correct interpolation), so each pixel here shades the
//! point the fragment shader shades; the shading below is `fs_main` of `common.wgsl` line by line
//! in f32, and the model is evaluated by its own Rust code ([`Shade`]), which is the
//! independent implementation each WGSL model file is tested against.

use crate::filter::{Filter, Taps};
use crate::gpu::View;
use crate::raster;
use btfrs_core::{Error, Result};
use btfrs_fit::Shade;
use glam::Vec3;
use rayon::prelude::*;

/// Checks shared by both renderers: lights, mesh, uv scale, coordinate map, tile map.
pub fn validate_common(view: &View<'_>, dims: (usize, usize)) -> Result<()> {
    if view.lights.is_empty() {
        return Err(Error::arg("lights", "expected at least one light"));
    }
    for l in view.lights {
        l.validate()?;
    }
    view.mesh.validate()?;
    if !view.uv_scale.iter().all(|s| s.is_finite() && *s > 0.0) {
        return Err(Error::arg("uv_scale", format!("expected positive finite repetitions, got {:?}", view.uv_scale)));
    }
    validate_map(view.coords, view.tiles, dims)?;
    if let Some((_, chain)) = view.filter {
        let want = match (view.tiles, view.coords) {
            (Some(t), _) => ((t.layout_cols * t.tile) as u32, (t.layout_rows * t.tile) as u32, t.tile as u32),
            (None, Some((mw, mh, _))) => (mw as u32, mh as u32, 0),
            (None, None) => (dims.1 as u32, dims.0 as u32, 0),
        };
        // (A plain sample's averaged pyramid extends the model by rows: the sample is its top.)
        let got = chain.levels.first().map(|l| (l.width, l.height, chain.tile));
        let fits = match (got, view.tiles.is_none() && view.coords.is_none()) {
            (Some((w, h, t)), true) => w == want.0 && h <= want.1 && t == 0,
            (g, _) => g == Some(want),
        };
        if !fits || chain.ids.iter().any(|&i| i as usize >= dims.0 * dims.1) {
            return Err(Error::arg(
                "filter",
                format!(
                    "the mip chain was built for another texture ({got:?}, expected {want:?} = width, height, tile)"
                ),
            ));
        }
    }
    Ok(())
}

/// Check a coordinate map or a tile map (at most one) against a sample of `dims` (height,
/// width) texels: sizes, and every entry inside the sample.
pub fn validate_map(
    coords: Option<(usize, usize, &[u32])>,
    tiles: Option<crate::tilemap::TileMap<'_>>,
    dims: (usize, usize),
) -> Result<()> {
    if let Some(t) = tiles {
        if coords.is_some() {
            return Err(Error::arg("tiles", "give a coordinate map or a tile map, not both"));
        }
        t.validate(dims.0 * dims.1)?;
    }
    if let Some((mw, mh, map)) = coords {
        if mw == 0 || mh == 0 || map.len() != mw * mh {
            return Err(Error::arg(
                "coords",
                format!("expected a non-empty {mh} x {mw} map, got {} entries", map.len()),
            ));
        }
        let (h, w) = dims;
        if let Some(i) = map.iter().position(|&e| (e & 0xffff) as usize >= w || (e >> 16) as usize >= h) {
            return Err(Error::arg(
                "coords",
                format!(
                    "entry ({}, {}) at map row {}, column {} points outside the {h} x {w} sample",
                    map[i] & 0xffff,
                    map[i] >> 16,
                    i / mw,
                    i % mw
                ),
            ));
        }
    }
    Ok(())
}

/// `texel_index` of common.wgsl, in the same f32 arithmetic.
#[inline]
pub fn texel_index(
    uv: [f32; 2],
    uv_scale: [f32; 2],
    dims: (usize, usize),
    coords: Option<(usize, usize, &[u32])>,
    tiles: Option<&crate::tilemap::TileMap<'_>>,
) -> usize {
    let s = [uv[0] * uv_scale[0], uv[1] * uv_scale[1]];
    let f = [s[0] - s[0].floor(), s[1] - s[1].floor()];
    if let Some(t) = tiles {
        return t.texel(f);
    }
    let (h, w) = (dims.0 as u32, dims.1 as u32);
    // `as u32` saturates like WGSL's f32 -> u32 conversion of values in range; inputs are >= 0.
    if let Some((mw, mh, map)) = coords {
        let (mw, mh) = (mw as u32, mh as u32);
        let mc = ((f[0] * mw as f32) as u32).min(mw - 1);
        let mr = (((1.0 - f[1]) * mh as f32) as u32).min(mh - 1);
        let e = map[(mr * mw + mc) as usize];
        return ((e >> 16) * w + (e & 0xffff)) as usize;
    }
    let c = ((f[0] * w as f32) as u32).min(w - 1);
    let r = (((1.0 - f[1]) * h as f32) as u32).min(h - 1);
    (r * w + c) as usize
}

/// The texels (and weights) a fragment shades: one by [`texel_index`] unfiltered, else the taps
/// of [`crate::filter::taps`] (`fs_main` of common.wgsl makes the same choice).
pub fn fragment_taps(view: &View<'_>, f: &raster::Fragment, dims: (usize, usize)) -> Taps {
    match view.filter {
        Some((flt, chain)) if flt != Filter::Nearest => {
            crate::filter::taps(chain, flt, f.uv, f.duv_dx, f.duv_dy, view.uv_scale)
        }
        _ => {
            let mut t = Taps { n: 1, ..Default::default() };
            t.texel[0] = texel_index(f.uv, view.uv_scale, dims, view.coords, view.tiles.as_ref()) as u32;
            t.weight[0] = 1.0;
            t
        }
    }
}

fn to_local(w: Vec3, t: Vec3, b: Vec3, n: Vec3) -> Vec3 {
    Vec3::new(w.dot(t), w.dot(b), w.dot(n)).normalize()
}

/// Render `model` on the CPU into a `[height][width][3]` image.
pub fn render_cpu<M: Shade + ?Sized>(model: &M, view: &View<'_>) -> Result<Vec<f32>> {
    let dims = model.shade_dims();
    validate_common(view, dims)?;
    let gb = raster::rasterize(view.mesh, view.camera, view.width, view.height)?;
    let eye = Vec3::from(view.camera.eye);
    let mut img = vec![0.0f32; view.width * view.height * 3];
    img.par_chunks_mut(3).zip(gb.pixels.par_iter()).for_each(|(px, frag)| {
        let Some(f) = frag else { return };
        let n = Vec3::from(f.normal).normalize();
        let t = Vec3::from(f.tangent).normalize();
        let b = Vec3::from(f.bitangent).normalize();
        let p = Vec3::from(f.position);
        let v = to_local((eye - p).normalize(), t, b, n);
        if v.z <= 0.0 {
            return;
        }
        let taps = fragment_taps(view, f, dims);
        let vd = v.as_dvec3().to_array();
        let mut total = Vec3::ZERO;
        for k in 0..taps.n {
            let texel = taps.texel[k] as usize;
            let mut sum = Vec3::ZERO;
            for light in view.lights {
                let (lw, irr) = light.at(p);
                let l = to_local(lw, t, b, n);
                if l.z <= 0.0 {
                    continue;
                }
                sum += Vec3::from(model.shade(texel, vd, l.as_dvec3().to_array())) * irr;
            }
            total += taps.weight[k] * sum;
        }
        px.copy_from_slice(&total.to_array());
    });
    Ok(img)
}

/// The model's double-SH expansion, or an error naming the lighting method to use.
pub fn sh_expansion_of(model: &dyn btfrs_fit::DynModel) -> Result<btfrs_fit::model::ShExpansion<'_>> {
    model.sh_expansion().ok_or_else(|| {
        Error::arg(
            "lighting",
            format!(
                "lighting=\"sh\" needs a double-SH model (btfrs.fit.sh), not a {} model; use lighting=\"sampled\"",
                model.kind()
            ),
        )
    })
}

/// Render a double-SH model under an environment by the SH method on the CPU: the reference of
/// `fs_env` in sh.wgsl (same frame arithmetic, same steps; the model's coefficients
/// dequantized, the sums in f64). `view.lights` is not used.
pub fn render_cpu_env_sh(
    model: &dyn btfrs_fit::DynModel,
    view: &View<'_>,
    env: &crate::sh_env::ShEnvironment,
) -> Result<Vec<f32>> {
    let dims = model.dims();
    let model = sh_expansion_of(model)?;
    if env.n != model.light_coeffs {
        return Err(Error::arg(
            "environment",
            format!("prepared for {} light coefficients, the model has {}", env.n, model.light_coeffs),
        ));
    }
    let placeholder = [crate::scene::Light::Directional { direction: [0.0, 0.0, 1.0], intensity: [0.0; 3] }];
    validate_common(&View { lights: &placeholder, ..*view }, dims)?;
    let gb = raster::rasterize(view.mesh, view.camera, view.width, view.height)?;
    let eye = Vec3::from(view.camera.eye);
    let coeffs = &model.coeffs;
    let (kv, kl) = (model.view_coeffs, model.light_coeffs);
    let mut img = vec![0.0f32; view.width * view.height * 3];
    img.par_chunks_mut(3).zip(gb.pixels.par_iter()).for_each(|(px, frag)| {
        let Some(f) = frag else { return };
        let n = Vec3::from(f.normal).normalize();
        let t = Vec3::from(f.tangent).normalize();
        let b = Vec3::from(f.bitangent).normalize();
        let p = Vec3::from(f.position);
        let v = to_local((eye - p).normalize(), t, b, n);
        if v.z <= 0.0 {
            return;
        }
        let taps = fragment_taps(view, f, dims);
        let d = |x: Vec3| x.as_dvec3().to_array();
        let h = env.converted(&env.band_values(d(t), d(b), d(n)));
        let mut yv = vec![0.0f64; kv];
        btfrs_fit::sh_basis(kv, d(v), &mut yv);
        for (ch, o) in px.iter_mut().enumerate() {
            let mut total = 0.0f64;
            for k in 0..taps.n {
                let base = (taps.texel[k] as usize * 3 + ch) * kv * kl;
                let mut acc = 0.0f64;
                for (i, yi) in yv.iter().enumerate() {
                    let row = &coeffs[base + i * kl..base + (i + 1) * kl];
                    acc += yi * row.iter().zip(&h).map(|(&c, hj)| c as f64 * hj[ch]).sum::<f64>();
                }
                total += taps.weight[k] as f64 * acc;
            }
            *o = total as f32;
        }
    });
    Ok(img)
}
