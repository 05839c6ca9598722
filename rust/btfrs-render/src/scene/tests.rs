//! Tests of the meshes' frames, the camera's projection and the lights.

use super::*;
use btfrs_core::Error;
use glam::{DVec3, Mat4, Vec3, Vec4, Vec4Swizzles};
use std::f64::consts::PI;

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
