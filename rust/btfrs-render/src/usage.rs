//! What a scene asks of a BTF: per covered pixel, the local view and light directions the
//! renderers will evaluate the model at, the light's irradiance, and the texel footprint.
//!
//! `btfrs.choose` derives from this which measured view and light slots a scene uses (weighted
//! by how many pixels ask) and at which mip level it sees the texture, so that it can fit only
//! what the scene needs and score candidates on the scene's own direction distribution. The
//! directions come from the CPU reference pipeline itself ([`crate::raster::rasterize`] and the
//! frame arithmetic of [`crate::cpu::render_cpu`]), so they are exactly the ones the renderers
//! shade, not an approximation of them.

use crate::cpu::validate_common;
use crate::gpu::View;
use crate::raster;
use btfrs_core::{Error, Result};
use glam::Vec3;
use rayon::prelude::*;

/// The directions a scene asks for, per covered pixel where the view is above the surface.
///
/// Pixel `i` of the lists is image pixel `pixels[i]` (row-major, row 0 at the top). Lights are
/// stored `n_lights` per pixel: `lights[i * n_lights + j]` is light `j`'s local direction at
/// pixel `i`, with `irradiance[i * n_lights + j]` its irradiance (mean of the RGB intensity /
/// distance^2); a light below the local horizon has irradiance 0 (the renderers skip it) and
/// its direction is still given.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SceneDirections {
    /// Image width in pixels.
    pub width: usize,
    /// Image height in pixels.
    pub height: usize,
    /// Number of lights per pixel.
    pub n_lights: usize,
    /// Row-major pixel index of each entry.
    pub pixels: Vec<u32>,
    /// Unit view direction in the surface's tangent frame (z >= 0).
    pub views: Vec<[f32; 3]>,
    /// Unit light direction in the tangent frame, `n_lights` per pixel.
    pub lights: Vec<[f32; 3]>,
    /// Irradiance of each light at the pixel (0 below the horizon), `n_lights` per pixel.
    pub irradiance: Vec<f32>,
    /// The interpolated texture coordinate, times `uv_scale` (so its fractional part is the
    /// position in the sample).
    pub uv: Vec<[f32; 2]>,
    /// Texels of the sample per pixel: the larger of the lengths of the screen-space
    /// derivatives of the texel position along x and y (the GPU's mip-level measure), by finite
    /// differences with a covered neighbour. NaN where neither axis has a usable neighbour.
    pub footprint: Vec<f32>,
}

fn to_local(w: Vec3, t: Vec3, b: Vec3, n: Vec3) -> Vec3 {
    Vec3::new(w.dot(t), w.dot(b), w.dot(n)).normalize()
}

/// The directions, irradiance and texel footprint `view` asks of a sample of `dims` = (height,
/// width) texels (see [`SceneDirections`]).
///
/// Errors: those of the renderers (no light, a bad mesh, camera, size or uv scale).
pub fn scene_directions(view: &View<'_>, dims: (usize, usize)) -> Result<SceneDirections> {
    if dims.0 == 0 || dims.1 == 0 {
        return Err(Error::arg("dims", format!("expected a non-empty sample, got {} x {}", dims.0, dims.1)));
    }
    validate_common(view, dims)?;
    let gb = raster::rasterize(view.mesh, view.camera, view.width, view.height)?;
    let (w, h) = (gb.width, gb.height);
    let eye = Vec3::from(view.camera.eye);
    let scale = view.uv_scale;
    let texel_pos = |uv: [f32; 2]| [uv[0] * scale[0] * dims.1 as f32, uv[1] * scale[1] * dims.0 as f32];
    // One derivative from a covered neighbour (forward, else backward, as a GPU quad would take
    // one of them). A jump of more than half the texture in u or v is the seam of a wrapped
    // parameterisation (a sphere's u = 0 / 1), not a footprint: that neighbour is ignored.
    let deriv = |x: usize, y: usize, dx: isize, dy: isize, p: [f32; 2]| -> Option<f32> {
        let q = |s: isize| -> Option<[f32; 2]> {
            let (nx, ny) = (x as isize + s * dx, y as isize + s * dy);
            if nx < 0 || ny < 0 {
                return None;
            }
            gb.get(nx as usize, ny as usize).map(|f| texel_pos(f.uv))
        };
        let half = [0.5 * scale[0] * dims.1 as f32, 0.5 * scale[1] * dims.0 as f32];
        [q(1), q(-1)].into_iter().flatten().find_map(|n| {
            let d = [n[0] - p[0], n[1] - p[1]];
            (d[0].abs() <= half[0] && d[1].abs() <= half[1]).then(|| (d[0] * d[0] + d[1] * d[1]).sqrt())
        })
    };
    let nl = view.lights.len();
    type Entry = (u32, [f32; 3], Vec<([f32; 3], f32)>, [f32; 2], f32);
    let entries: Vec<Entry> = (0..w * h)
        .into_par_iter()
        .filter_map(|i| {
            let f = gb.pixels[i].as_ref()?;
            let n = Vec3::from(f.normal).normalize();
            let t = Vec3::from(f.tangent).normalize();
            let b = Vec3::from(f.bitangent).normalize();
            let p = Vec3::from(f.position);
            let v = to_local((eye - p).normalize(), t, b, n);
            // The renderers shade nothing where the view is below the local horizon.
            if v.z.is_nan() || v.z <= 0.0 {
                return None;
            }
            let lights = view
                .lights
                .iter()
                .map(|light| {
                    let (lw, irr) = light.at(p);
                    let l = to_local(lw, t, b, n);
                    let e = if l.z > 0.0 { (irr.x + irr.y + irr.z) / 3.0 } else { 0.0 };
                    (if l.is_finite() { l.to_array() } else { [0.0; 3] }, e)
                })
                .collect();
            let (x, y) = (i % w, i / w);
            let tp = texel_pos(f.uv);
            let fp = match (deriv(x, y, 1, 0, tp), deriv(x, y, 0, 1, tp)) {
                (Some(a), Some(b)) => a.max(b),
                (Some(a), None) | (None, Some(a)) => a,
                (None, None) => f32::NAN,
            };
            Some((i as u32, v.to_array(), lights, [f.uv[0] * scale[0], f.uv[1] * scale[1]], fp))
        })
        .collect();
    let mut out = SceneDirections { width: w, height: h, n_lights: nl, ..Default::default() };
    for (i, v, ls, uv, fp) in entries {
        out.pixels.push(i);
        out.views.push(v);
        for (l, e) in ls {
            out.lights.push(l);
            out.irradiance.push(e);
        }
        out.uv.push(uv);
        out.footprint.push(fp);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{Camera, Light, Mesh};

    fn view<'a>(mesh: &'a Mesh, cam: &'a Camera, lights: &'a [Light], size: usize, uv_scale: f32) -> View<'a> {
        View {
            mesh,
            camera: cam,
            lights,
            width: size,
            height: size,
            uv_scale: [uv_scale; 2],
            coords: None,
            tiles: None,
            filter: None,
        }
    }

    #[test]
    fn plane_from_above_in_closed_form() {
        // A square of side 1 seen from height d with a 90 degree field of view: the image spans
        // [-d, d] at z = 0, so the square covers (size / (2 d))^2 of the pixels; every view
        // direction is the normalised (eye - p) in the plane's frame (x, y, z), and a
        // directional light's local direction is its own (the frame is the world's).
        let (d, size) = (2.0f32, 64usize);
        let mesh = Mesh::plane(1.0);
        let cam = Camera::look_at([0.0, 0.0, d], [0.0; 3], 90.0).unwrap();
        let dir = Vec3::new(0.3, -0.2, 0.9).normalize();
        let lights = [
            Light::Directional { direction: dir.to_array(), intensity: [2.0, 2.0, 2.0] },
            Light::Directional { direction: [0.0, 1.0, -0.5], intensity: [1.0; 3] },
        ];
        let s = scene_directions(&view(&mesh, &cam, &lights, size, 2.0), (16, 16)).unwrap();
        let side = size as f32 / (2.0 * d); // 16 pixels
        assert_eq!(s.pixels.len(), (side * side) as usize);
        assert_eq!((s.n_lights, s.lights.len(), s.irradiance.len()), (2, 2 * s.pixels.len(), 2 * s.pixels.len()));
        // Pixel centres and exact view directions.
        let mut centre_seen = false;
        for (k, &p) in s.pixels.iter().enumerate() {
            let (x, y) = ((p as usize % size) as f32 + 0.5, (p as usize / size) as f32 + 0.5);
            let world = Vec3::new((x / size as f32 * 2.0 - 1.0) * d, (1.0 - y / size as f32 * 2.0) * d, 0.0);
            let expect = (Vec3::new(0.0, 0.0, d) - world).normalize();
            assert!((Vec3::from(s.views[k]) - expect).length() < 1e-4, "pixel {p}");
            if (x - 32.5).abs() < 1.0 && (y - 32.5).abs() < 1.0 {
                centre_seen = true;
                assert!(s.views[k][2] > 0.999);
            }
            assert!((Vec3::from(s.lights[2 * k]) - dir).length() < 1e-6);
            assert_eq!(s.irradiance[2 * k], 2.0);
            // The second light is below the horizon: no irradiance.
            assert_eq!(s.irradiance[2 * k + 1], 0.0);
            // uv spans the square once per repetition: 16 pixels for 2 x 16 texels.
            assert!((s.footprint[k] - 2.0).abs() < 1e-3, "footprint {}", s.footprint[k]);
            assert!((s.uv[k][0] - 2.0 * (world.x + 0.5)).abs() < 1e-4);
        }
        assert!(centre_seen);
    }

    #[test]
    fn distant_plane_has_a_larger_footprint_and_seam_is_ignored() {
        let mesh = Mesh::plane(1.0);
        let lights = [Light::Point { position: [0.0, 0.0, 3.0], intensity: [9.0; 3] }];
        let fp = |d: f32| {
            let cam = Camera::look_at([0.0, 0.0, d], [0.0; 3], 30.0).unwrap();
            let s = scene_directions(&view(&mesh, &cam, &lights, 64, 1.0), (64, 64)).unwrap();
            let mut f: Vec<f32> = s.footprint.clone();
            f.sort_by(f32::total_cmp);
            f[f.len() / 2]
        };
        let (near, far) = (fp(2.5), fp(10.0));
        assert!((far / near - 4.0).abs() < 0.1, "near {near}, far {far}");
        // A sphere's u seam would give a footprint of the whole texture: never more than a few
        // texels per pixel here.
        let sphere = Mesh::sphere(1.0, 64, 32).unwrap();
        let cam = Camera::look_at([3.0, 0.0, 0.0], [0.0; 3], 40.0).unwrap();
        let s = scene_directions(&view(&sphere, &cam, &lights, 64, 1.0), (64, 64)).unwrap();
        assert!(s.footprint.iter().filter(|f| f.is_finite()).all(|&f| f < 20.0));
        assert!(s.views.iter().all(|v| v[2] > 0.0));
    }

    #[test]
    fn argument_errors() {
        let mesh = Mesh::plane(1.0);
        let cam = Camera::look_at([0.0, 0.0, 2.0], [0.0; 3], 40.0).unwrap();
        let l = [Light::Directional { direction: [0.0, 0.0, 1.0], intensity: [1.0; 3] }];
        let e = scene_directions(&view(&mesh, &cam, &[], 8, 1.0), (4, 4)).unwrap_err();
        assert!(matches!(e, Error::InvalidArgument { ref name, .. } if name == "lights"), "{e:?}");
        let e = scene_directions(&view(&mesh, &cam, &l, 0, 1.0), (4, 4)).unwrap_err();
        assert!(matches!(e, Error::InvalidArgument { ref name, .. } if name == "size"), "{e:?}");
        let e = scene_directions(&view(&mesh, &cam, &l, 8, -1.0), (4, 4)).unwrap_err();
        assert!(matches!(e, Error::InvalidArgument { ref name, .. } if name == "uv_scale"), "{e:?}");
    }
}
