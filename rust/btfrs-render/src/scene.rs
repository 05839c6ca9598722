//! What is rendered: triangle meshes with per-vertex tangent frames, a perspective camera and lights.
//!
//! # Tangent frames follow the parameterisation
//!
//! A BTF is measured in the local frame of a flat sample: its x axis runs along the image columns,
//! its y axis up the image rows, its z axis along the sample normal. To put it on a curved surface
//! the renderer needs, at every shaded point, the frame (T, B, N) that the texture parameterisation
//! induces there. As paper 002 (Leung et al., "Tileable BTF", section 4.2 "Rendering") stresses,
//! the tangent and binormal are *not* the curvature-defined ones of a generic TBN transform: they
//! are aligned with the surface parameterisation grid, so that light and view vectors transformed
//! into (T, B, N) agree with the coordinate system in which the raw BTF samples were taken.
//! Hence every mesh here carries, per vertex, tangent = dP/du, bitangent = dP/dv (both made unit
//! and orthogonal to the normal) and the normal.
//!
//! # UV convention
//!
//! A texture coordinate (u, v) has u along the texture columns and v pointing *up* the texture
//! image. So the BTF's local x is T (columns, increasing u), its local y is B (up the image rows,
//! increasing v) and its local z is N. A texel lookup at (u, v) in an image of `height` rows reads
//! row `(1 - v) * height` (row 0 is the top row of the image) and column `u * width`.
//!
//! For a parameterisation that keeps orientation, (T, B, N) is right-handed (N = T x B). Mirrored
//! UVs give a left-handed frame; we keep it that way (B stays dP/dv rather than being replaced by
//! N x T), because the BTF's y axis must follow v, not the handedness of the mesh.

use btfrs_core::{Error, Result};
use glam::{DVec2, DVec3, Mat4, Vec3};
use std::f64::consts::PI;

/// Largest vertex count the generated meshes may have: keeps indices in `u32` and allocations sane.
const MAX_GENERATED_VERTICES: u64 = 1 << 26;

/// A triangle mesh with per-vertex attributes. Frames follow the UV parameterisation
/// (paper 002, section 4.2): tangent = dP/du, bitangent = dP/dv, normal, all unit, per vertex.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    /// Vertex positions in world space.
    pub positions: Vec<[f32; 3]>,
    /// Unit normals.
    pub normals: Vec<[f32; 3]>,
    /// Unit tangents, the direction of dP/du, orthogonal to the normal.
    pub tangents: Vec<[f32; 3]>,
    /// Unit bitangents, the direction of dP/dv, orthogonal to normal and tangent.
    pub bitangents: Vec<[f32; 3]>,
    /// Texture coordinates, v pointing up the texture (see the module docs).
    pub uvs: Vec<[f32; 2]>,
    /// 3 per triangle, counter-clockwise seen from the normal side.
    pub indices: Vec<u32>,
}

impl Mesh {
    /// A square of side `size` in the z = 0 plane, centred at the origin, normal +z; u runs along
    /// +x and v along +y over [0, 1]^2. Two triangles, split along the diagonal from (-, -) to (+, +).
    ///
    /// No argument check (the signature is infallible): a non-finite or zero `size` gives a mesh
    /// that [`Mesh::validate`] or the rasteriser rejects or that covers nothing.
    pub fn plane(size: f32) -> Mesh {
        let h = 0.5 * size;
        Mesh {
            positions: vec![[-h, -h, 0.0], [h, -h, 0.0], [h, h, 0.0], [-h, h, 0.0]],
            normals: vec![[0.0, 0.0, 1.0]; 4],
            tangents: vec![[1.0, 0.0, 0.0]; 4],
            bitangents: vec![[0.0, 1.0, 0.0]; 4],
            uvs: vec![[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]],
            indices: vec![0, 1, 2, 0, 2, 3],
        }
    }

    /// A UV sphere centred at the origin with its poles on the z axis.
    ///
    /// u = azimuth / (2 pi), measured from +x towards +y; v = 0 at the south pole (z = -r) to 1 at
    /// the north pole. Frames are analytic: T = east (-sin phi, cos phi, 0), B = north, N = outward.
    /// The seam at u = 0 / 1 has duplicated vertices (bit-identical positions, so the seam is
    /// watertight for the rasteriser) so that no triangle wraps around. Each pole is a row of
    /// `segments + 1` coincident vertices; pole vertex `i` sits at u = (i + 1/2) / segments (the
    /// middle of the fan triangle that uses it; the last one is unused) and carries the analytic
    /// T / B of that azimuth, which are well defined (no NaN) even though the position is singular.
    pub fn sphere(radius: f32, segments: u32, rings: u32) -> Result<Mesh> {
        check_positive("radius", radius)?;
        if segments < 3 {
            return Err(Error::arg("segments", format!("need at least 3, got {segments}")));
        }
        if rings < 2 {
            return Err(Error::arg("rings", format!("need at least 2, got {rings}")));
        }
        let cols = segments as u64 + 1;
        let rows = rings as u64 + 1;
        let n_vert = cols.saturating_mul(rows);
        if n_vert > MAX_GENERATED_VERTICES {
            return Err(Error::arg(
                "segments",
                format!("{segments} x {rings} needs {n_vert} vertices, above the limit {MAX_GENERATED_VERTICES}"),
            ));
        }
        let r = radius as f64;
        let n_vert = n_vert as usize;
        let mut mesh = Mesh::with_capacity(n_vert, 6 * segments as usize * rings as usize);
        for j in 0..=rings {
            // Latitude from -pi/2 (south) to pi/2 (north); the poles are set exactly so that all
            // pole vertices coincide bit for bit.
            let v = j as f64 / rings as f64;
            let (sin_lat, cos_lat) = if j == 0 {
                (-1.0, 0.0)
            } else if j == rings {
                (1.0, 0.0)
            } else {
                (PI * (v - 0.5)).sin_cos()
            };
            let pole = j == 0 || j == rings;
            for i in 0..=segments {
                // Pole vertices sit mid-way between meridians, in the middle of their fan triangle.
                let u =
                    if pole && i < segments { (i as f64 + 0.5) / segments as f64 } else { i as f64 / segments as f64 };
                // The azimuth of the position and frame is computed from `i % segments` so that the
                // seam copies (u = 0 and u = 1) are bit-identical.
                let phi = if pole && i < segments {
                    2.0 * PI * u
                } else {
                    2.0 * PI * (i % segments) as f64 / segments as f64
                };
                let (sin_phi, cos_phi) = phi.sin_cos();
                let n = [cos_lat * cos_phi, cos_lat * sin_phi, sin_lat];
                mesh.positions.push(to_f32([r * n[0], r * n[1], r * n[2]]));
                mesh.normals.push(to_f32(n));
                mesh.tangents.push(to_f32([-sin_phi, cos_phi, 0.0]));
                mesh.bitangents.push(to_f32([-sin_lat * cos_phi, -sin_lat * sin_phi, cos_lat]));
                mesh.uvs.push([u as f32, v as f32]);
            }
        }
        let idx = |j: u32, i: u32| j * (segments + 1) + i;
        for j in 0..rings {
            for i in 0..segments {
                let (a, b, c, d) = (idx(j, i), idx(j, i + 1), idx(j + 1, i + 1), idx(j + 1, i));
                // Counter-clockwise in (u, v) is counter-clockwise seen from outside, since
                // T x B = N. At the poles one triangle of the quad has zero area: skip it.
                if j == 0 {
                    mesh.indices.extend_from_slice(&[a, c, d]);
                } else if j == rings - 1 {
                    mesh.indices.extend_from_slice(&[a, b, c]);
                } else {
                    mesh.indices.extend_from_slice(&[a, b, c, a, c, d]);
                }
            }
        }
        Ok(mesh)
    }

    /// The open side of a cylinder of axis z centred at the origin (no caps).
    ///
    /// u = azimuth / (2 pi) from +x towards +y, v = (z + height/2) / height. T = east
    /// (-sin phi, cos phi, 0), B = +z, N = outward; the seam at u = 0 / 1 has duplicated vertices.
    pub fn cylinder(radius: f32, height: f32, segments: u32) -> Result<Mesh> {
        check_positive("radius", radius)?;
        check_positive("height", height)?;
        if segments < 3 {
            return Err(Error::arg("segments", format!("need at least 3, got {segments}")));
        }
        if 2 * (segments as u64 + 1) > MAX_GENERATED_VERTICES {
            return Err(Error::arg(
                "segments",
                format!("{segments} is above the limit {}", MAX_GENERATED_VERTICES / 2 - 1),
            ));
        }
        let r = radius as f64;
        let h = height as f64;
        let mut mesh = Mesh::with_capacity(2 * (segments as usize + 1), 6 * segments as usize);
        for j in 0..2u32 {
            let v = j as f64;
            let z = -0.5 * h + h * v;
            for i in 0..=segments {
                let u = i as f64 / segments as f64;
                let (sin_phi, cos_phi) = (2.0 * PI * (i % segments) as f64 / segments as f64).sin_cos();
                mesh.positions.push(to_f32([r * cos_phi, r * sin_phi, z]));
                mesh.normals.push(to_f32([cos_phi, sin_phi, 0.0]));
                mesh.tangents.push(to_f32([-sin_phi, cos_phi, 0.0]));
                mesh.bitangents.push([0.0, 0.0, 1.0]);
                mesh.uvs.push([u as f32, v as f32]);
            }
        }
        let row = segments + 1;
        for i in 0..segments {
            let (a, b, c, d) = (i, i + 1, row + i + 1, row + i);
            mesh.indices.extend_from_slice(&[a, b, c, a, c, d]);
        }
        Ok(mesh)
    }

    /// An indexed mesh from user arrays, with tangent frames derived from the UV mapping.
    ///
    /// Checks (errors name the argument and the offending index): non-empty `positions` and
    /// `faces`; `uvs` (and `normals`) as long as `positions`; everything finite; normals non-zero;
    /// indices in range; no triangle of (near) zero area (below 1e-12 times the squared bounding-box
    /// diagonal) and no triangle whose UV image has (near) zero area (it has no dP/du, dP/dv).
    ///
    /// Normals default to area-weighted face normals (faces counter-clockwise seen from the normal
    /// side); given normals are normalised. Tangent frames follow Lengyel's method: per triangle,
    /// dP/du and dP/dv from the position and UV differences, summed per vertex, then Gram-Schmidt
    /// against the normal: T = normalize(T - N (N.T)), B = normalize(B - N (N.B) - T (T.B)). B keeps
    /// its own direction (it is not replaced by N x T), so mirrored UVs still give B = dP/dv.
    /// Vertices no face uses get a normal of +z and an arbitrary orthonormal frame.
    pub fn from_arrays(
        positions: &[[f32; 3]],
        uvs: &[[f32; 2]],
        faces: &[[u32; 3]],
        normals: Option<&[[f32; 3]]>,
    ) -> Result<Mesh> {
        let n = positions.len();
        if n == 0 {
            return Err(Error::arg("positions", "empty"));
        }
        if faces.is_empty() {
            return Err(Error::arg("faces", "empty"));
        }
        if uvs.len() != n {
            return Err(Error::arg("uvs", format!("has {} entries, positions has {n}", uvs.len())));
        }
        if let Some(i) = positions.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
            return Err(Error::arg("positions", format!("vertex {i} is not finite: {:?}", positions[i])));
        }
        if let Some(i) = uvs.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
            return Err(Error::arg("uvs", format!("vertex {i} is not finite: {:?}", uvs[i])));
        }
        if let Some(normals) = normals {
            if normals.len() != n {
                return Err(Error::arg("normals", format!("has {} entries, positions has {n}", normals.len())));
            }
            for (i, nv) in normals.iter().enumerate() {
                let v = Vec3::from(*nv).as_dvec3();
                if !v.is_finite() || v.length_squared() == 0.0 {
                    return Err(Error::arg("normals", format!("normal {i} is zero or not finite: {nv:?}")));
                }
            }
        }
        for (f, face) in faces.iter().enumerate() {
            if let Some(&bad) = face.iter().find(|&&k| k as usize >= n) {
                return Err(Error::arg("faces", format!("face {f} has index {bad}, out of range for {n} vertices")));
            }
        }

        // Scale-relative degeneracy thresholds: squared bounding-box diagonals.
        let p64: Vec<DVec3> = positions.iter().map(|p| Vec3::from(*p).as_dvec3()).collect();
        let t64: Vec<DVec2> = uvs.iter().map(|t| DVec2::new(t[0] as f64, t[1] as f64)).collect();
        let diag2 = bbox_diag2(p64.iter().copied());
        let uv_diag2 = {
            let (lo, hi) =
                t64.iter().fold((DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY)), |(lo, hi), t| {
                    (lo.min(*t), hi.max(*t))
                });
            (hi - lo).length_squared()
        };
        const REL_AREA: f64 = 1e-12;

        let mut acc_n = vec![DVec3::ZERO; n];
        let mut acc_t = vec![DVec3::ZERO; n];
        let mut acc_b = vec![DVec3::ZERO; n];
        let mut first_face_normal: Vec<Option<DVec3>> = vec![None; n];
        for (f, face) in faces.iter().enumerate() {
            let [i0, i1, i2] = face.map(|k| k as usize);
            let (e1, e2) = (p64[i1] - p64[i0], p64[i2] - p64[i0]);
            let cross = e1.cross(e2); // |cross| = 2 * area, along the normal of a CCW face
            if 0.5 * cross.length() <= REL_AREA * diag2 {
                return Err(Error::arg("faces", format!("face {f} has zero area (vertices {face:?})")));
            }
            let (d1, d2) = (t64[i1] - t64[i0], t64[i2] - t64[i0]);
            let det = d1.x * d2.y - d2.x * d1.y; // 2 * signed UV area
            if 0.5 * det.abs() <= REL_AREA * uv_diag2 {
                return Err(Error::arg("uvs", format!("face {f} has a degenerate UV mapping (zero UV area)")));
            }
            // Lengyel: [e1 e2] = [dP/du dP/dv] [d1 d2]  =>  solve for dP/du, dP/dv.
            let r = 1.0 / det;
            let dpdu = (e1 * d2.y - e2 * d1.y) * r;
            let dpdv = (e2 * d1.x - e1 * d2.x) * r;
            let face_n = cross.normalize();
            for k in [i0, i1, i2] {
                acc_n[k] += cross;
                acc_t[k] += dpdu;
                acc_b[k] += dpdv;
                first_face_normal[k].get_or_insert(face_n);
            }
        }

        let mut mesh = Mesh::with_capacity(n, 3 * faces.len());
        mesh.positions.extend_from_slice(positions);
        mesh.uvs.extend_from_slice(uvs);
        mesh.indices.extend(faces.iter().flatten());
        for k in 0..n {
            let nrm = match normals {
                Some(given) => Vec3::from(given[k]).as_dvec3().normalize(),
                // Faces whose normals cancel (a vertex shared by two opposite faces) fall back to
                // the first face's normal; unused vertices to +z.
                None => acc_n[k].try_normalize().or(first_face_normal[k]).unwrap_or(DVec3::Z),
            };
            let (t, b) = orthonormalise(nrm, acc_t[k], acc_b[k]);
            mesh.normals.push(to_f32(nrm.to_array()));
            mesh.tangents.push(to_f32(t.to_array()));
            mesh.bitangents.push(to_f32(b.to_array()));
        }
        Ok(mesh)
    }

    /// Number of triangles (`indices.len() / 3`).
    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }

    /// Checks that all attribute arrays are as long as `positions`, that everything is finite, and
    /// that `indices` holds whole triangles of in-range indices. An empty mesh is valid (it covers
    /// nothing). Errors name the argument "mesh".
    pub fn validate(&self) -> Result<()> {
        let n = self.positions.len();
        let lens = [
            ("normals", self.normals.len()),
            ("tangents", self.tangents.len()),
            ("bitangents", self.bitangents.len()),
            ("uvs", self.uvs.len()),
        ];
        for (name, len) in lens {
            if len != n {
                return Err(Error::arg("mesh", format!("{name} has {len} entries, positions has {n}")));
            }
        }
        if !self.indices.len().is_multiple_of(3) {
            return Err(Error::arg("mesh", format!("indices has {} entries, not a multiple of 3", self.indices.len())));
        }
        let vec3s = [
            ("positions", &self.positions),
            ("normals", &self.normals),
            ("tangents", &self.tangents),
            ("bitangents", &self.bitangents),
        ];
        for (name, arr) in vec3s {
            if let Some(i) = arr.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
                return Err(Error::arg("mesh", format!("{name}[{i}] is not finite: {:?}", arr[i])));
            }
        }
        if let Some(i) = self.uvs.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
            return Err(Error::arg("mesh", format!("uvs[{i}] is not finite: {:?}", self.uvs[i])));
        }
        if let Some(i) = self.indices.iter().position(|&k| k as usize >= n) {
            return Err(Error::arg(
                "mesh",
                format!("indices[{i}] = {} is out of range for {n} vertices", self.indices[i]),
            ));
        }
        Ok(())
    }

    fn with_capacity(vertices: usize, indices: usize) -> Mesh {
        Mesh {
            positions: Vec::with_capacity(vertices),
            normals: Vec::with_capacity(vertices),
            tangents: Vec::with_capacity(vertices),
            bitangents: Vec::with_capacity(vertices),
            uvs: Vec::with_capacity(vertices),
            indices: Vec::with_capacity(indices),
        }
    }
}

/// Gram-Schmidt of the accumulated dP/du, dP/dv against the unit normal `n`, keeping B's own
/// direction (and so the handedness of the UV mapping). Degenerate accumulations (a vertex whose
/// triangles' tangents cancel, or an unused vertex) fall back to a right-handed frame.
fn orthonormalise(n: DVec3, t_acc: DVec3, b_acc: DVec3) -> (DVec3, DVec3) {
    let b_perp = (b_acc - n * n.dot(b_acc)).try_normalize();
    let t = (t_acc - n * n.dot(t_acc))
        .try_normalize()
        // B x N = T for a right-handed frame.
        .or_else(|| b_perp.map(|b| b.cross(n)))
        .unwrap_or_else(|| n.any_orthonormal_vector());
    let b = (b_acc - n * n.dot(b_acc) - t * t.dot(b_acc)).try_normalize().unwrap_or_else(|| n.cross(t));
    (t, b)
}

fn bbox_diag2(points: impl Iterator<Item = DVec3>) -> f64 {
    let (lo, hi) = points
        .fold((DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)), |(lo, hi), p| (lo.min(p), hi.max(p)));
    (hi - lo).length_squared()
}

fn to_f32(v: [f64; 3]) -> [f32; 3] {
    v.map(|c| c as f32)
}

fn check_positive(name: &str, value: f32) -> Result<()> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(Error::arg(name, format!("expected a finite positive value, got {value}")))
    }
}

fn check_finite3(name: &str, v: [f32; 3]) -> Result<()> {
    if v.iter().all(|c| c.is_finite()) {
        Ok(())
    } else {
        Err(Error::arg(name, format!("not finite: {v:?}")))
    }
}

/// `sin` of the angle under which the view direction and `up` count as parallel; `look_at_rh`
/// would build a NaN or badly conditioned basis from them.
const PARALLEL_SIN: f32 = 1e-4;

/// Perspective camera (right-handed, z up by default).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Eye position in world space.
    pub eye: [f32; 3],
    /// The point looked at; it projects to the image centre.
    pub target: [f32; 3],
    /// Up direction; it need not be orthogonal to the view direction, only not parallel to it.
    pub up: [f32; 3],
    /// Vertical field of view in degrees, in (0, 180).
    pub fov_y_deg: f32,
    /// Near clipping distance (depth 0), > 0.
    pub near: f32,
    /// Far clipping distance (depth 1), > near.
    pub far: f32,
}

impl Camera {
    /// A camera at `eye` looking at `target`, up = +z, near 0.01, far 100.
    ///
    /// When the view direction is parallel to +z (looking straight up or down), up falls back to
    /// +y instead of failing. Errors: non-finite input, `eye == target`, `fov_y_deg` outside (0, 180).
    pub fn look_at(eye: [f32; 3], target: [f32; 3], fov_y_deg: f32) -> Result<Camera> {
        check_finite3("eye", eye)?;
        check_finite3("target", target)?;
        let dir = Vec3::from(target) - Vec3::from(eye);
        if !dir.is_finite() || dir.length_squared() == 0.0 {
            return Err(Error::arg(
                "target",
                format!("must differ from eye {eye:?} by a finite amount, got {target:?}"),
            ));
        }
        let up = if is_parallel(dir, Vec3::Z) { [0.0, 1.0, 0.0] } else { [0.0, 0.0, 1.0] };
        let camera = Camera { eye, target, up, fov_y_deg, near: 0.01, far: 100.0 };
        camera.validate()?;
        Ok(camera)
    }

    /// Checks the fields: finite, eye != target, `up` non-zero, fov in (0, 180), 0 < near < far.
    /// An `up` parallel to the view direction is not an error (see [`Camera::view_proj`]).
    pub fn validate(&self) -> Result<()> {
        check_finite3("eye", self.eye)?;
        check_finite3("target", self.target)?;
        check_finite3("up", self.up)?;
        let dir = Vec3::from(self.target) - Vec3::from(self.eye);
        if !dir.is_finite() || dir.length_squared() == 0.0 {
            return Err(Error::arg("target", format!("must differ from eye {:?}, got {:?}", self.eye, self.target)));
        }
        if Vec3::from(self.up).length_squared() == 0.0 {
            return Err(Error::arg("up", "must be non-zero"));
        }
        if !(self.fov_y_deg > 0.0 && self.fov_y_deg < 180.0) {
            return Err(Error::arg("fov_y_deg", format!("expected a value in (0, 180), got {}", self.fov_y_deg)));
        }
        if !(self.near.is_finite() && self.near > 0.0) {
            return Err(Error::arg("near", format!("expected a finite positive value, got {}", self.near)));
        }
        if !(self.far.is_finite() && self.far > self.near) {
            return Err(Error::arg(
                "far",
                format!("expected a finite value above near = {}, got {}", self.near, self.far),
            ));
        }
        Ok(())
    }

    /// The view-projection matrix for `aspect` = width / height: `Mat4::perspective_rh` (depth 0 at
    /// the near plane to 1 at the far plane, the wgpu convention) times `Mat4::look_at_rh`. The GPU
    /// uses this very matrix, so both renderers see the same clip-space positions.
    ///
    /// If `up` is parallel to the view direction, +y is used instead (+z if the view is along y),
    /// the same fallback as [`Camera::look_at`]. The result is meaningless (but no panic) for an
    /// invalid camera or a non-positive `aspect`.
    pub fn view_proj(&self, aspect: f32) -> Mat4 {
        let eye = Vec3::from(self.eye);
        let target = Vec3::from(self.target);
        let dir = target - eye;
        let mut up = Vec3::from(self.up);
        if is_parallel(dir, up) {
            up = if is_parallel(dir, Vec3::Y) { Vec3::Z } else { Vec3::Y };
        }
        Mat4::perspective_rh(self.fov_y_deg.to_radians(), aspect, self.near, self.far)
            * Mat4::look_at_rh(eye, target, up)
    }
}

fn is_parallel(a: Vec3, b: Vec3) -> bool {
    let (a, b) = (a.normalize_or_zero(), b.normalize_or_zero());
    a.cross(b).length() <= PARALLEL_SIN
}

/// A light. Intensities are RGB.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Light {
    /// Irradiance intensity / distance^2 from `position`.
    Point { position: [f32; 3], intensity: [f32; 3] },
    /// Constant irradiance `intensity` from `direction` (unit, pointing *towards* the light; a
    /// non-unit direction is normalised by [`Light::at`]).
    Directional { direction: [f32; 3], intensity: [f32; 3] },
}

impl Light {
    /// Checks that everything is finite, intensities are non-negative and a direction is non-zero.
    pub fn validate(&self) -> Result<()> {
        let intensity = match self {
            Light::Point { position, intensity } => {
                check_finite3("position", *position)?;
                intensity
            }
            Light::Directional { direction, intensity } => {
                check_finite3("direction", *direction)?;
                if Vec3::from(*direction).length_squared() == 0.0 {
                    return Err(Error::arg("direction", "must be non-zero"));
                }
                intensity
            }
        };
        check_finite3("intensity", *intensity)?;
        if intensity.iter().any(|&c| c < 0.0) {
            return Err(Error::arg("intensity", format!("must be non-negative, got {intensity:?}")));
        }
        Ok(())
    }

    /// The unit direction from world point `p` towards the light, and the irradiance (RGB) the light
    /// delivers at `p` on a surface facing it. At the position of a point light itself, where both
    /// are undefined, it returns zeros (no contribution) rather than NaN.
    pub fn at(&self, p: Vec3) -> (Vec3, Vec3) {
        match *self {
            Light::Point { position, intensity } => {
                let d = Vec3::from(position) - p;
                let r2 = d.length_squared();
                if r2 > 0.0 && r2.is_finite() {
                    (d / r2.sqrt(), Vec3::from(intensity) / r2)
                } else {
                    (Vec3::ZERO, Vec3::ZERO)
                }
            }
            Light::Directional { direction, intensity } => {
                (Vec3::from(direction).normalize_or_zero(), Vec3::from(intensity))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{Vec4, Vec4Swizzles};

    fn v3(a: [f32; 3]) -> DVec3 {
        Vec3::from(a).as_dvec3()
    }

    fn angle_deg(a: DVec3, b: DVec3) -> f64 {
        a.normalize().dot(b.normalize()).clamp(-1.0, 1.0).acos().to_degrees()
    }

    fn arg_name(err: &Error) -> &str {
        match err {
            Error::InvalidArgument { name, .. } => name,
            other => panic!("expected InvalidArgument, got {other:?}"),
        }
    }

    /// Unit, orthogonal and right-handed (N = T x B) frames everywhere.
    fn check_orthonormal_right_handed(mesh: &Mesh) {
        for k in 0..mesh.positions.len() {
            let (t, b, n) = (v3(mesh.tangents[k]), v3(mesh.bitangents[k]), v3(mesh.normals[k]));
            for (name, v) in [("T", t), ("B", b), ("N", n)] {
                assert!((v.length() - 1.0).abs() < 1e-5, "vertex {k}: |{name}| = {}", v.length());
            }
            assert!(t.dot(b).abs() < 1e-5 && t.dot(n).abs() < 1e-5 && b.dot(n).abs() < 1e-5, "vertex {k}");
            assert!((t.cross(b) - n).length() < 1e-5, "vertex {k}: T x B != N");
        }
    }

    fn sphere_point(r: f64, u: f64, v: f64) -> DVec3 {
        let (phi, lat) = (2.0 * PI * u, PI * (v - 0.5));
        r * DVec3::new(lat.cos() * phi.cos(), lat.cos() * phi.sin(), lat.sin())
    }

    #[test]
    fn sphere_frames_are_orthonormal_and_follow_the_parameterisation() {
        let r = 1.5;
        let mesh = Mesh::sphere(r as f32, 24, 12).unwrap();
        mesh.validate().unwrap();
        assert_eq!(mesh.positions.len(), 25 * 13);
        assert_eq!(mesh.triangle_count(), 2 * 24 * 12 - 2 * 24);
        check_orthonormal_right_handed(&mesh);
        let h = 1e-6;
        for k in 0..mesh.positions.len() {
            let [u, v] = mesh.uvs[k].map(|c| c as f64);
            let p = v3(mesh.positions[k]);
            assert!((p - sphere_point(r, u, v)).length() < 1e-5, "vertex {k}: position off the surface");
            assert!((v3(mesh.normals[k]) - p / r).length() < 1e-5 || v == 0.0 || v == 1.0);
            if v == 0.0 || v == 1.0 {
                continue; // dP/du vanishes at the poles; the frame there is checked above
            }
            let dpdu = sphere_point(r, u + h, v) - sphere_point(r, u - h, v);
            let dpdv = sphere_point(r, u, v + h) - sphere_point(r, u, v - h);
            assert!(angle_deg(v3(mesh.tangents[k]), dpdu) < 0.01, "vertex {k}: T is not dP/du");
            assert!(angle_deg(v3(mesh.bitangents[k]), dpdv) < 0.01, "vertex {k}: B is not dP/dv");
        }
        // Poles: all vertices at the pole, with the south normal -z and north +z.
        assert_eq!(mesh.positions[0], [0.0, 0.0, -1.5]);
        assert_eq!(mesh.normals[0], [0.0, 0.0, -1.0]);
        assert_eq!(*mesh.positions.last().unwrap(), [0.0, 0.0, 1.5]);
        // Seam copies are bit-identical (watertight seam).
        for j in 0..13 {
            assert_eq!(mesh.positions[j * 25], mesh.positions[j * 25 + 24]);
            assert_eq!(
                (mesh.uvs[j * 25][0], mesh.uvs[j * 25 + 24][0]),
                if j == 0 || j == 12 { (0.5 / 24.0, 1.0) } else { (0.0, 1.0) }
            );
        }
        // Every triangle is counter-clockwise seen from outside.
        for tri in mesh.indices.chunks(3) {
            let [a, b, c] = [0, 1, 2].map(|i| v3(mesh.positions[tri[i] as usize]));
            let centroid = (a + b + c) / 3.0;
            assert!((b - a).cross(c - a).dot(centroid) > 0.0, "triangle {tri:?} faces inwards");
        }
    }

    #[test]
    fn cylinder_frames_are_orthonormal_and_follow_the_parameterisation() {
        let (r, h) = (0.7, 2.0);
        let mesh = Mesh::cylinder(r as f32, h as f32, 16).unwrap();
        mesh.validate().unwrap();
        assert_eq!(mesh.triangle_count(), 32);
        check_orthonormal_right_handed(&mesh);
        let surface = |u: f64, v: f64| {
            let phi = 2.0 * PI * u;
            DVec3::new(r * phi.cos(), r * phi.sin(), h * (v - 0.5))
        };
        let e = 1e-6;
        for k in 0..mesh.positions.len() {
            let [u, v] = mesh.uvs[k].map(|c| c as f64);
            assert!((v3(mesh.positions[k]) - surface(u, v)).length() < 1e-5);
            let dpdu = surface(u + e, v) - surface(u - e, v);
            let dpdv = surface(u, v + e) - surface(u, v - e);
            assert!(angle_deg(v3(mesh.tangents[k]), dpdu) < 0.01, "vertex {k}");
            assert!(angle_deg(v3(mesh.bitangents[k]), dpdv) < 0.01, "vertex {k}");
        }
        for tri in mesh.indices.chunks(3) {
            let [a, b, c] = [0, 1, 2].map(|i| v3(mesh.positions[tri[i] as usize]));
            let centroid = (a + b + c) / 3.0;
            let radial = DVec3::new(centroid.x, centroid.y, 0.0);
            assert!((b - a).cross(c - a).dot(radial) > 0.0, "triangle {tri:?} faces inwards");
        }
    }

    #[test]
    fn from_arrays_recovers_the_analytic_sphere_frames() {
        let analytic = Mesh::sphere(2.0, 128, 64).unwrap();
        let faces: Vec<[u32; 3]> = analytic.indices.chunks(3).map(|c| [c[0], c[1], c[2]]).collect();
        let mesh = Mesh::from_arrays(&analytic.positions, &analytic.uvs, &faces, None).unwrap();
        mesh.validate().unwrap();
        let mut checked = 0;
        let (mut worst_t, mut worst_b, mut worst_n) = (0.0f64, 0.0f64, 0.0f64);
        for k in 0..mesh.positions.len() {
            if mesh.positions[k][2].abs() > 0.9 * 2.0 {
                continue; // away from the poles
            }
            worst_n = worst_n.max(angle_deg(v3(mesh.normals[k]), v3(analytic.normals[k])));
            worst_t = worst_t.max(angle_deg(v3(mesh.tangents[k]), v3(analytic.tangents[k])));
            worst_b = worst_b.max(angle_deg(v3(mesh.bitangents[k]), v3(analytic.bitangents[k])));
            checked += 1;
        }
        assert!(checked > 5000);
        assert!(worst_n < 3.0 && worst_t < 3.0 && worst_b < 3.0, "worst angles N {worst_n} T {worst_t} B {worst_b}");
        // The frames are orthonormal everywhere, poles included (and right-handed: the UV map of
        // a sphere seen from outside keeps orientation).
        check_orthonormal_right_handed(&mesh);
    }

    #[test]
    fn mirrored_uvs_keep_the_handedness() {
        let plane = Mesh::plane(2.0);
        let faces = [[0, 1, 2], [0, 2, 3]];
        let mirrored: Vec<[f32; 2]> = plane.uvs.iter().map(|t| [1.0 - t[0], t[1]]).collect();
        let mesh = Mesh::from_arrays(&plane.positions, &mirrored, &faces, None).unwrap();
        for k in 0..4 {
            assert!((v3(mesh.normals[k]) - DVec3::Z).length() < 1e-6);
            assert!((v3(mesh.tangents[k]) + DVec3::X).length() < 1e-6, "T = {:?}", mesh.tangents[k]);
            assert!((v3(mesh.bitangents[k]) - DVec3::Y).length() < 1e-6, "B = {:?}", mesh.bitangents[k]);
        }
        // Unmirrored, from_arrays reproduces the analytic plane.
        let same = Mesh::from_arrays(&plane.positions, &plane.uvs, &faces, None).unwrap();
        for k in 0..4 {
            assert!((v3(same.tangents[k]) - DVec3::X).length() < 1e-6);
            assert!((v3(same.bitangents[k]) - DVec3::Y).length() < 1e-6);
        }
    }

    #[test]
    fn from_arrays_uses_and_normalises_given_normals() {
        let p = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let uv = [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]];
        let tilted = [[0.0, 0.0, 2.0], [0.0, 1.0, 1.0], [0.0, 0.0, 3.0]];
        let mesh = Mesh::from_arrays(&p, &uv, &[[0, 1, 2]], Some(&tilted)).unwrap();
        let n1 = v3(mesh.normals[1]);
        assert!((n1 - DVec3::new(0.0, 1.0, 1.0).normalize()).length() < 1e-6);
        // T stays dP/du = +x (already orthogonal to n1); B = dP/dv projected: orthogonal to n1.
        assert!((v3(mesh.tangents[1]) - DVec3::X).length() < 1e-6);
        assert!(v3(mesh.bitangents[1]).dot(n1).abs() < 1e-6 && v3(mesh.bitangents[1]).y > 0.0);
        // Reversed winding flips the default normal.
        let flipped = Mesh::from_arrays(&p, &uv, &[[0, 2, 1]], None).unwrap();
        assert!((v3(flipped.normals[0]) + DVec3::Z).length() < 1e-6);
    }

    #[test]
    fn from_arrays_errors_name_the_argument() {
        let p = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0]];
        let uv = [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]];
        let ok = [[0u32, 1, 2], [1, 3, 2]];
        assert!(Mesh::from_arrays(&p, &uv, &ok, None).is_ok());
        let cases: Vec<(&str, Result<Mesh>, &str)> = vec![
            ("faces", Mesh::from_arrays(&p, &uv, &[[0, 1, 2], [1, 3, 4]], None), "4"),
            ("faces", Mesh::from_arrays(&p, &uv, &[[0, 1, 2], [1, 1, 2]], None), "face 1"),
            (
                "faces",
                Mesh::from_arrays(&[[0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]], &uv[..3], &[[0, 1, 2]], None),
                "face 0",
            ),
            ("uvs", Mesh::from_arrays(&p, &[[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [1.0, 1.0]], &ok, None), "face 0"),
            (
                "positions",
                Mesh::from_arrays(&[[0.0; 3], [1.0, f32::NAN, 0.0], [0.0, 1.0, 0.0]], &uv[..3], &ok[..1], None),
                "1",
            ),
            ("uvs", Mesh::from_arrays(&p, &[[0.0, 0.0], [1.0, 0.0], [0.0, f32::INFINITY], [1.0, 1.0]], &ok, None), "2"),
            ("positions", Mesh::from_arrays(&[], &[], &ok, None), "empty"),
            ("faces", Mesh::from_arrays(&p, &uv, &[], None), "empty"),
            ("uvs", Mesh::from_arrays(&p, &uv[..3], &ok, None), "3"),
            ("normals", Mesh::from_arrays(&p, &uv, &ok, Some(&[[0.0, 0.0, 1.0]; 3])), "3"),
            (
                "normals",
                Mesh::from_arrays(&p, &uv, &ok, Some(&[[0.0, 0.0, 1.0], [0.0; 3], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])),
                "1",
            ),
        ];
        for (i, (name, result, index)) in cases.into_iter().enumerate() {
            let err = result.expect_err(&format!("case {i} should fail"));
            assert_eq!(arg_name(&err), name, "case {i}: {err}");
            assert!(err.to_string().contains(index), "case {i}: {err} should mention {index}");
        }
    }

    #[test]
    fn validate_catches_broken_meshes() {
        let good = Mesh::plane(1.0);
        good.validate().unwrap();
        let mut m = good.clone();
        m.normals.pop();
        assert!(m.validate().unwrap_err().to_string().contains("normals"));
        let mut m = good.clone();
        m.indices[4] = 4;
        assert!(m.validate().unwrap_err().to_string().contains("indices[4]"));
        let mut m = good.clone();
        m.indices.pop();
        assert!(m.validate().is_err());
        let mut m = good.clone();
        m.tangents[2][1] = f32::NAN;
        assert!(m.validate().unwrap_err().to_string().contains("tangents[2]"));
        assert!(Mesh::plane(f32::NAN).validate().is_err());
        Mesh::default().validate().unwrap();
    }

    #[test]
    fn generator_argument_errors() {
        assert_eq!(arg_name(&Mesh::sphere(0.0, 8, 4).unwrap_err()), "radius");
        assert_eq!(arg_name(&Mesh::sphere(f32::NAN, 8, 4).unwrap_err()), "radius");
        assert_eq!(arg_name(&Mesh::sphere(1.0, 2, 4).unwrap_err()), "segments");
        assert_eq!(arg_name(&Mesh::sphere(1.0, 8, 1).unwrap_err()), "rings");
        assert_eq!(arg_name(&Mesh::sphere(1.0, u32::MAX, u32::MAX).unwrap_err()), "segments");
        assert_eq!(arg_name(&Mesh::cylinder(1.0, -1.0, 8).unwrap_err()), "height");
        assert_eq!(arg_name(&Mesh::cylinder(1.0, 1.0, 2).unwrap_err()), "segments");
        assert_eq!(arg_name(&Mesh::cylinder(1.0, 1.0, u32::MAX).unwrap_err()), "segments");
        Mesh::sphere(1.0, 3, 2).unwrap().validate().unwrap();
    }

    fn project(vp: Mat4, p: Vec3) -> Vec3 {
        let c = vp * Vec4::new(p.x, p.y, p.z, 1.0);
        c.xyz() / c.w
    }

    #[test]
    fn camera_maps_target_to_centre_and_near_far_to_depth_0_1() {
        let cam = Camera::look_at([3.0, -4.0, 2.0], [0.5, 0.25, -0.5], 50.0).unwrap();
        assert_eq!((cam.near, cam.far, cam.up), (0.01, 100.0, [0.0, 0.0, 1.0]));
        let vp = cam.view_proj(16.0 / 9.0);
        let t = project(vp, Vec3::from(cam.target));
        assert!(t.x.abs() < 1e-5 && t.y.abs() < 1e-5, "{t}");
        assert!(t.z > 0.0 && t.z < 1.0);
        // Near and far planes, projected in f64 through the f32 matrix. Depth near the near plane
        // is ~1/near times more sensitive than distance, so the f32 rounding of the matrix's
        // translation (eye . axis ~ 5, ulp 5e-7) shows up as ~5e-5 in depth; at the origin there
        // is no translation and the match is tight.
        for (eye, target, tol) in [(cam.eye, cam.target, 2e-4), ([0.0; 3], [0.3, 1.0, -0.2], 1e-6)] {
            let cam = Camera::look_at(eye, target, 50.0).unwrap();
            let vp64 = cam.view_proj(16.0 / 9.0).as_dmat4();
            let (eye, dir) = (v3(eye), (v3(target) - v3(eye)).normalize());
            let depth = |p: DVec3| {
                let c = vp64 * p.extend(1.0);
                c.z / c.w
            };
            let side = DVec3::Z.cross(dir).normalize();
            let near = depth(eye + dir * cam.near as f64);
            let near_side = depth(eye + dir * cam.near as f64 + side * 0.001);
            let far = depth(eye + dir * cam.far as f64);
            assert!(near.abs() < tol && near_side.abs() < tol, "near {near} {near_side}");
            assert!((far - 1.0).abs() < tol, "far {far}");
        }
        // Up is +z in the image: a point above the target has ndc y > 0; right-handed: a point
        // along dir x up is on the right (ndc x > 0).
        let eye = Vec3::from(cam.eye);
        let dir = (Vec3::from(cam.target) - eye).normalize();
        assert!(project(vp, Vec3::from(cam.target) + Vec3::Z * 0.1).y > 0.0);
        assert!(project(vp, Vec3::from(cam.target) + dir.cross(Vec3::Z) * 0.1).x > 0.0);
        // The field of view: a point at angle fov/2 above the axis maps to the top edge.
        let up_axis = dir.cross(Vec3::Z).normalize().cross(dir);
        let edge = eye + (dir + up_axis * 25f32.to_radians().tan()) * 2.0;
        assert!((project(vp, edge).y - 1.0).abs() < 1e-4);
    }

    #[test]
    fn camera_looking_along_z_falls_back_to_up_y() {
        let cam = Camera::look_at([0.0, 0.0, 5.0], [0.0, 0.0, 0.0], 90.0).unwrap();
        assert_eq!(cam.up, [0.0, 1.0, 0.0]);
        let vp = cam.view_proj(1.0);
        assert!(vp.is_finite());
        assert!(project(vp, Vec3::new(0.0, 1.0, 0.0)).y > 0.0);
        // A hand-built camera with a parallel up gets the same fallback in view_proj.
        let manual = Camera { up: [0.0, 0.0, 3.0], ..cam };
        assert_eq!(manual.view_proj(1.0), vp);
        let along_y = Camera { eye: [0.0, -5.0, 0.0], up: [0.0, 1.0, 0.0], ..cam };
        assert!(along_y.view_proj(1.0).is_finite());
    }

    #[test]
    fn camera_errors() {
        assert_eq!(arg_name(&Camera::look_at([1.0; 3], [1.0; 3], 60.0).unwrap_err()), "target");
        assert_eq!(arg_name(&Camera::look_at([0.0; 3], [1.0; 3], 0.0).unwrap_err()), "fov_y_deg");
        assert_eq!(arg_name(&Camera::look_at([0.0; 3], [1.0; 3], 180.0).unwrap_err()), "fov_y_deg");
        assert_eq!(arg_name(&Camera::look_at([0.0; 3], [1.0; 3], f32::NAN).unwrap_err()), "fov_y_deg");
        assert_eq!(arg_name(&Camera::look_at([f32::NAN, 0.0, 0.0], [1.0; 3], 60.0).unwrap_err()), "eye");
        assert_eq!(arg_name(&Camera::look_at([0.0; 3], [f32::INFINITY, 0.0, 0.0], 60.0).unwrap_err()), "target");
        assert_eq!(arg_name(&Camera::look_at([-3e38, 0.0, 0.0], [3e38, 0.0, 0.0], 60.0).unwrap_err()), "target");
        let cam = Camera::look_at([0.0; 3], [1.0; 3], 60.0).unwrap();
        assert_eq!(arg_name(&Camera { near: 0.0, ..cam }.validate().unwrap_err()), "near");
        assert_eq!(arg_name(&Camera { far: 0.005, ..cam }.validate().unwrap_err()), "far");
        assert_eq!(arg_name(&Camera { up: [0.0; 3], ..cam }.validate().unwrap_err()), "up");
    }

    #[test]
    fn lights() {
        let point = Light::Point { position: [0.0, 0.0, 2.0], intensity: [4.0, 8.0, 0.0] };
        point.validate().unwrap();
        let (dir, e) = point.at(Vec3::ZERO);
        assert!((dir - Vec3::Z).length() < 1e-6 && (e - Vec3::new(1.0, 2.0, 0.0)).length() < 1e-6);
        assert_eq!(point.at(Vec3::new(0.0, 0.0, 2.0)), (Vec3::ZERO, Vec3::ZERO));
        let sun = Light::Directional { direction: [0.0, 3.0, 4.0], intensity: [1.0; 3] };
        sun.validate().unwrap();
        let (dir, e) = sun.at(Vec3::new(5.0, 6.0, 7.0));
        assert!((dir - Vec3::new(0.0, 0.6, 0.8)).length() < 1e-6 && e == Vec3::ONE);
        let bad = [
            (Light::Directional { direction: [0.0; 3], intensity: [1.0; 3] }, "direction"),
            (Light::Directional { direction: [0.0, 0.0, 1.0], intensity: [1.0, -1.0, 1.0] }, "intensity"),
            (Light::Point { position: [f32::NAN, 0.0, 0.0], intensity: [1.0; 3] }, "position"),
            (Light::Point { position: [0.0; 3], intensity: [f32::INFINITY, 0.0, 0.0] }, "intensity"),
        ];
        for (light, name) in bad {
            assert_eq!(arg_name(&light.validate().unwrap_err()), name);
        }
    }
}
