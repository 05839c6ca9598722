//! Triangle meshes with per-vertex tangent frames: generators (plane, sphere, cylinder) and
//! indexed meshes from arrays, each vertex carrying the frame the BTF is looked up in.
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

use super::check_positive;
use btfrs_core::{Error, Result};
use glam::{DVec2, DVec3, Vec3};
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
