//! The CPU reference rasteriser: which surface point every pixel sees, as the GPU sees it.
//!
//! The GPU renderer (wgpu, Vulkan rules; Mesa's lavapipe in CI) rasterises the mesh and runs a
//! fragment shader at each covered pixel; the CPU renderer must shade *the same points* so that the
//! two images agree to >= 40 dB PSNR, silhouettes included. [`rasterize`] therefore reproduces the
//! fixed-function pipeline step by step and returns a G-buffer holding, per pixel, exactly the
//! interpolated vertex attributes the fragment shader receives:
//!
//! 1. **Vertex stage**: clip = `camera.view_proj(width / height) * (position, 1)`, in f32.
//! 2. **Clipping** in homogeneous clip space against the six frustum planes
//!    `-w <= x <= w`, `-w <= y <= w`, `0 <= z <= w`, in that order, Sutherland-Hodgman as in Mesa's
//!    draw module (which lavapipe uses): only planes some vertex violates are applied; a new vertex is
//!    always interpolated from the outside vertex towards the inside one,
//!    `v = out + t (in - out)`, `t = d_out / (d_out - d_in)`, in f32, attributes included (they are
//!    linear in clip space), so an edge shared by two triangles is cut at the same point; the clipped
//!    polygon is drawn as a fan from its first vertex.
//! 3. **Viewport**: `x = ndc_x * W/2 + W/2`, `y = ndc_y * (-H/2) + H/2` (framebuffer y grows
//!    downwards, wgpu's flipped viewport), `depth = ndc_z` in [0, 1], computed as
//!    `clip * (1 / w) * scale + offset` in f32 like Mesa.
//! 4. **Coverage**: positions snapped to the sub-pixel grid of 1/256 pixel (8 bits, lavapipe's
//!    `FIXED_ORDER`) as `round((x - 0.5) * 256)` (round half away from zero), so pixel (px, py) samples
//!    the integer point (256 px, 256 py), its centre. Triangles whose snapped area is zero are dropped.
//!    A pixel is covered if its centre is strictly inside all three edges, or on an edge that is a
//!    *top* edge (horizontal, interior below) or a *left* edge (interior to its right) of the
//!    triangle, in framebuffer coordinates (y down). Edge functions are exact 64-bit integers, so two
//!    triangles sharing an edge never both cover, nor both miss, a pixel centre on it. Both windings
//!    are drawn (no back-face culling).
//! 5. **Depth**: screen-linear interpolation of the vertices' depth at the pixel centre, clamped to
//!    [0, 1], test LESS against a buffer cleared to [`CLEAR_DEPTH`] = 1, triangles in index order
//!    (ties keep the earlier triangle, as on the GPU).
//! 6. **Attributes**: perspective-correct barycentrics at the pixel centre,
//!    `a = sum(l_i a_i / w_i) / sum(l_i / w_i)` with `l_i` the screen-space barycentrics computed
//!    from the *unsnapped* float window positions (as llvmpipe sets up its interpolation planes; a
//!    pixel covered only thanks to snapping extrapolates slightly, exactly like the GPU).
//!
//! Interpolation runs in f64 and the result is rounded to f32. The GPU interpolates in f32 with an
//! operation order (plane equations, fused multiply-adds) we cannot reproduce bit for bit anyway;
//! f64 makes our side the correctly rounded value of the ideal interpolant, so the CPU/GPU difference
//! is the GPU's own rounding (~1e-6 relative), far below what the 40 dB target can see. Coverage,
//! which decides silhouettes, does not depend on this: it is integer arithmetic on positions
//! computed in f32 exactly as the GPU computes them.
//!
//! The interpolated normal, tangent and bitangent are **not renormalised**: the fragment shader
//! receives the raw interpolants too and renormalises them itself, and the CPU shader must do the
//! same (a G-buffer normal is slightly shorter than unit inside a triangle).
//!
//! Work is parallel with rayon: triangles are set up (transformed, clipped, snapped) in parallel,
//! binned into bands of [`BAND_ROWS`] rows, and the bands rasterised in parallel, each visiting
//! its triangles in index order so the depth test resolves ties as the GPU does.

use crate::scene::{Camera, Mesh};
use btfrs_core::{Error, Result};
use glam::Vec4;
use rayon::prelude::*;

/// Largest accepted width or height.
pub const MAX_IMAGE_SIZE: usize = 16384;
/// Sub-pixel precision of the snapped vertex positions (lavapipe: 8 bits, 1/256 pixel).
pub const SUBPIXEL_BITS: u32 = 8;
/// Value the depth buffer starts from; the depth test is LESS, so depth 1 itself is never drawn.
pub const CLEAR_DEPTH: f32 = 1.0;
/// Rows per band of the parallel rasteriser.
pub const BAND_ROWS: usize = 16;

const SUB: i64 = 1 << SUBPIXEL_BITS;
/// Bound on snapped coordinates. After clipping they lie within the viewport (at most
/// 16384 * 256 = 2^22); anything beyond 2^28 is numerical garbage, and the bound keeps the edge
/// functions (products of two differences) far from i64 overflow.
const MAX_FIXED: f32 = (1u32 << 28) as f32;
/// Interpolated attributes: position (3), normal (3), tangent (3), bitangent (3), uv (2).
const N_ATTR: usize = 14;
/// Clip planes: x >= -w, x <= w, y >= -w, y <= w, z >= 0, z <= w.
const N_PLANES: usize = 6;
/// A convex polygon clipped by 6 planes has at most 9 vertices; room for rounding surprises.
const MAX_POLY: usize = 16;

/// What the fragment shader sees at one covered pixel.
///
/// `normal`, `tangent` and `bitangent` are the raw perspective-correct interpolants of the unit
/// vertex vectors, *not* renormalised (the shader renormalises).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Fragment {
    /// World-space position of the surface point.
    pub position: [f32; 3],
    /// Interpolated vertex normal (not unit).
    pub normal: [f32; 3],
    /// Interpolated vertex tangent (not unit).
    pub tangent: [f32; 3],
    /// Interpolated vertex bitangent (not unit).
    pub bitangent: [f32; 3],
    /// Interpolated texture coordinate.
    pub uv: [f32; 2],
    /// Window depth in [0, 1] (0 at the near plane).
    pub depth: f32,
    /// Fine screen-space derivatives of `uv`, as `dpdxFine` / `dpdyFine` give them in a 2 x 2
    /// pixel quad: the difference of the same triangle's interpolated uv at the odd and the even
    /// column (row) of the quad, at this pixel's row (column); the partner pixel's value is
    /// extrapolated from the triangle when it is not covered, like a GPU helper invocation.
    pub duv_dx: [f32; 2],
    /// See `duv_dx`: rows (y down).
    pub duv_dy: [f32; 2],
}

/// A G-buffer: `width * height` entries, row 0 at the top; None where no triangle covers the pixel
/// centre.
#[derive(Clone, Debug, PartialEq)]
pub struct GBuffer {
    /// Image width in pixels.
    pub width: usize,
    /// Image height in pixels.
    pub height: usize,
    /// Row-major, `pixels[y * width + x]`, row 0 at the top.
    pub pixels: Vec<Option<Fragment>>,
}

impl GBuffer {
    /// The fragment at column `x`, row `y` (row 0 at the top); None if uncovered or out of range.
    pub fn get(&self, x: usize, y: usize) -> Option<&Fragment> {
        if x < self.width && y < self.height {
            self.pixels.get(y * self.width + x)?.as_ref()
        } else {
            None
        }
    }

    /// Number of covered pixels.
    pub fn covered_count(&self) -> usize {
        self.pixels.iter().filter(|p| p.is_some()).count()
    }
}

/// Rasterise `mesh` as seen by `camera` into a `width` x `height` G-buffer, with the Vulkan rules
/// described in the module docs.
///
/// Errors: `width` or `height` 0 or above [`MAX_IMAGE_SIZE`] (argument "size"), an invalid mesh
/// ("mesh", see [`Mesh::validate`]) or camera (see [`Camera::validate`]). Triangles whose clip
/// coordinates overflow f32 are skipped.
pub fn rasterize(mesh: &Mesh, camera: &Camera, width: usize, height: usize) -> Result<GBuffer> {
    for (what, v) in [("width", width), ("height", height)] {
        if v == 0 || v > MAX_IMAGE_SIZE {
            return Err(Error::arg("size", format!("{what} must be in 1..={MAX_IMAGE_SIZE}, got {v}")));
        }
    }
    mesh.validate()?;
    camera.validate()?;

    let view_proj = camera.view_proj(width as f32 / height as f32);
    let clip: Vec<[f32; 4]> =
        mesh.positions.par_iter().map(|p| (view_proj * Vec4::new(p[0], p[1], p[2], 1.0)).to_array()).collect();
    let viewport = Viewport { width, height, half_w: width as f32 * 0.5, half_h: height as f32 * 0.5 };

    // Set-up in parallel; rayon's collect keeps the triangle order, which the depth test needs.
    let tris: Vec<TriSetup> = mesh
        .indices
        .par_chunks_exact(3)
        .flat_map_iter(|tri| {
            let verts = [0, 1, 2].map(|k| clip_vertex(mesh, &clip, tri[k] as usize));
            setup_triangle(verts, &viewport)
        })
        .collect();

    let n_bands = height.div_ceil(BAND_ROWS);
    let mut bins: Vec<Vec<usize>> = vec![Vec::new(); n_bands];
    for (i, t) in tris.iter().enumerate() {
        for bin in &mut bins[t.y0 / BAND_ROWS..=t.y1 / BAND_ROWS] {
            bin.push(i);
        }
    }

    let mut pixels = vec![None; width * height];
    pixels.par_chunks_mut(width * BAND_ROWS).zip(bins.par_iter()).enumerate().for_each(|(band, (out, bin))| {
        raster_band(&tris, bin, band * BAND_ROWS, width, out);
    });
    Ok(GBuffer { width, height, pixels })
}

struct Viewport {
    width: usize,
    height: usize,
    half_w: f32,
    half_h: f32,
}

/// A vertex in clip space with the attributes the fragment shader interpolates.
#[derive(Clone, Copy, Debug)]
struct ClipVertex {
    clip: [f32; 4],
    attr: [f32; N_ATTR],
}

fn clip_vertex(mesh: &Mesh, clip: &[[f32; 4]], k: usize) -> ClipVertex {
    let mut attr = [0.0; N_ATTR];
    attr[0..3].copy_from_slice(&mesh.positions[k]);
    attr[3..6].copy_from_slice(&mesh.normals[k]);
    attr[6..9].copy_from_slice(&mesh.tangents[k]);
    attr[9..12].copy_from_slice(&mesh.bitangents[k]);
    attr[12..14].copy_from_slice(&mesh.uvs[k]);
    ClipVertex { clip: clip[k], attr }
}

impl ClipVertex {
    /// `out + t (in - out)`, component-wise in f32, as Mesa's clipper interpolates.
    fn towards(&self, inside: &ClipVertex, t: f32) -> ClipVertex {
        let mut v = *self;
        for (o, i) in v.clip.iter_mut().zip(inside.clip) {
            *o += t * (i - *o);
        }
        for (o, i) in v.attr.iter_mut().zip(inside.attr) {
            *o += t * (i - *o);
        }
        v
    }
}

/// Signed distance-like value of a clip position to frustum plane `plane` (inside: >= 0), the
/// same single f32 operation as Mesa's `dot4` with the plane's 0 / +-1 coefficients.
fn plane_distance(c: &[f32; 4], plane: usize) -> f32 {
    match plane {
        0 => c[0] + c[3],
        1 => c[3] - c[0],
        2 => c[1] + c[3],
        3 => c[3] - c[1],
        4 => c[2],
        _ => c[3] - c[2],
    }
}

/// Clips a triangle against the frustum; returns the polygon and its vertex count (< 3: nothing left).
fn clip_triangle(tri: [ClipVertex; 3]) -> ([ClipVertex; MAX_POLY], usize) {
    let mut poly = [tri[0]; MAX_POLY];
    poly[..3].copy_from_slice(&tri);
    let mut n = 3;
    let mut planes = 0u32;
    for v in &tri {
        for p in 0..N_PLANES {
            if plane_distance(&v.clip, p) < 0.0 {
                planes |= 1 << p;
            }
        }
    }
    if planes == 0 {
        return (poly, n);
    }
    let mut next = [tri[0]; MAX_POLY];
    for p in (0..N_PLANES).filter(|p| planes & (1 << p) != 0) {
        let mut dist = [0.0f32; MAX_POLY];
        for (d, v) in dist.iter_mut().zip(&poly[..n]) {
            *d = plane_distance(&v.clip, p);
        }
        let mut m = 0;
        for i in 0..n {
            let j = (i + 1) % n;
            let (prev, cur) = (&poly[i], &poly[j]);
            let (d_prev, d_cur) = (dist[i], dist[j]);
            if m + 2 > MAX_POLY {
                return (poly, 0); // cannot happen for a convex polygon; drop rather than overflow
            }
            if d_prev >= 0.0 {
                next[m] = *prev;
                m += 1;
            }
            if (d_prev < 0.0) != (d_cur < 0.0) {
                // Always from the outside vertex towards the inside one (Mesa's `interp`), so the
                // new vertex on a shared edge is bit-identical in both triangles.
                next[m] = if d_cur < 0.0 {
                    cur.towards(prev, d_cur / (d_cur - d_prev))
                } else {
                    prev.towards(cur, d_prev / (d_prev - d_cur))
                };
                m += 1;
            }
        }
        std::mem::swap(&mut poly, &mut next);
        n = m;
        if n < 3 {
            return (poly, 0);
        }
    }
    (poly, n)
}

/// A vertex after the perspective divide and viewport transform.
#[derive(Clone, Copy, Debug)]
struct WindowVertex {
    x: f32,
    y: f32,
    z: f32,
    oow: f32,
}

fn to_window(c: &[f32; 4], vp: &Viewport) -> WindowVertex {
    // Mesa's order of operations: 1/w first, then scale and offset.
    let oow = 1.0 / c[3];
    WindowVertex { x: c[0] * oow * vp.half_w + vp.half_w, y: c[1] * oow * -vp.half_h + vp.half_h, z: c[2] * oow, oow }
}

/// Snaps a window coordinate to the sub-pixel grid, relative to the pixel-centre lattice.
fn snap(v: f32) -> Option<i64> {
    let s = ((v - 0.5) * SUB as f32).round();
    (s.abs() <= MAX_FIXED).then_some(s as i64)
}

/// Everything the band rasteriser needs for one (clipped) triangle.
#[derive(Clone, Debug)]
struct TriSetup {
    /// Snapped vertex positions (1/256 pixel, pixel centres at multiples of 256), positive area.
    fx: [i64; 3],
    fy: [i64; 3],
    /// Edge i runs from vertex i to vertex i + 1: its (dx, dy) and 1 unless it is top-left.
    edx: [i64; 3],
    edy: [i64; 3],
    bias: [i64; 3],
    /// Inclusive pixel bounding box, clamped to the image.
    x0: usize,
    x1: usize,
    y0: usize,
    y1: usize,
    /// Screen-space barycentrics at a pixel centre (cx, cy), relative to vertex 0 at (ox, oy):
    /// l1 = (dx * k[0] - dy * k[1]) * inv_den, l2 = (dy * k[2] - dx * k[3]) * inv_den.
    ox: f64,
    oy: f64,
    k: [f64; 4],
    inv_den: f64,
    z: [f64; 3],
    oow: [f64; 3],
    attr: [[f32; N_ATTR]; 3],
}

/// Clips a triangle and sets up the fan of triangles that remains.
fn setup_triangle(tri: [ClipVertex; 3], vp: &Viewport) -> impl Iterator<Item = TriSetup> + '_ {
    let finite = tri.iter().all(|v| v.clip.iter().all(|c| c.is_finite()));
    let (poly, n) = if finite { clip_triangle(tri) } else { ([tri[0]; MAX_POLY], 0) };
    let mut win = [WindowVertex { x: 0.0, y: 0.0, z: 0.0, oow: 0.0 }; MAX_POLY];
    for (w, v) in win.iter_mut().zip(&poly[..n]) {
        *w = to_window(&v.clip, vp);
    }
    (1..n.saturating_sub(1)).filter_map(move |i| {
        let idx = [0, i, i + 1];
        setup_window_triangle(idx.map(|k| win[k]), idx.map(|k| poly[k].attr), vp)
    })
}

fn setup_window_triangle(mut w: [WindowVertex; 3], mut attr: [[f32; N_ATTR]; 3], vp: &Viewport) -> Option<TriSetup> {
    if !w.iter().all(|v| v.x.is_finite() && v.y.is_finite() && v.z.is_finite() && v.oow.is_finite()) {
        return None;
    }
    let mut fx = [0i64; 3];
    let mut fy = [0i64; 3];
    for k in 0..3 {
        fx[k] = snap(w[k].x)?;
        fy[k] = snap(w[k].y)?;
    }
    let area = (fx[1] - fx[0]) * (fy[2] - fy[0]) - (fy[1] - fy[0]) * (fx[2] - fx[0]);
    if area == 0 {
        return None;
    }
    if area < 0 {
        // Both windings are drawn: reorder so that the interior is on the positive side of
        // every edge function.
        fx.swap(1, 2);
        fy.swap(1, 2);
        w.swap(1, 2);
        attr.swap(1, 2);
    }
    let mut edx = [0i64; 3];
    let mut edy = [0i64; 3];
    let mut bias = [0i64; 3];
    for i in 0..3 {
        let j = (i + 1) % 3;
        edx[i] = fx[j] - fx[i];
        edy[i] = fy[j] - fy[i];
        // Top edge: horizontal with the interior below (y down); left edge: interior to its right.
        let top_left = edy[i] < 0 || (edy[i] == 0 && edx[i] > 0);
        bias[i] = if top_left { 0 } else { 1 };
    }
    let ceil_px = |v: i64| (v + SUB - 1).div_euclid(SUB);
    let floor_px = |v: i64| v.div_euclid(SUB);
    let clamp_to = |v: i64, size: usize| v.clamp(0, size as i64 - 1) as usize;
    let (xmin, xmax) = (ceil_px(*fx.iter().min()?), floor_px(*fx.iter().max()?));
    let (ymin, ymax) = (ceil_px(*fy.iter().min()?), floor_px(*fy.iter().max()?));
    if xmin > xmax || ymin > ymax || xmax < 0 || ymax < 0 || xmin >= vp.width as i64 || ymin >= vp.height as i64 {
        return None;
    }

    // Interpolation planes from the unsnapped window positions; if snapping made a triangle out of
    // a numerically flat one, fall back to the snapped positions (same pixel-centre frame).
    let (mut sx, mut sy) = (w.map(|v| v.x as f64), w.map(|v| v.y as f64));
    let mut den = (sx[1] - sx[0]) * (sy[2] - sy[0]) - (sy[1] - sy[0]) * (sx[2] - sx[0]);
    if !(den.abs() > 0.0 && den.is_finite()) {
        sx = fx.map(|v| v as f64 / SUB as f64 + 0.5);
        sy = fy.map(|v| v as f64 / SUB as f64 + 0.5);
        den = (sx[1] - sx[0]) * (sy[2] - sy[0]) - (sy[1] - sy[0]) * (sx[2] - sx[0]);
    }
    Some(TriSetup {
        fx,
        fy,
        edx,
        edy,
        bias,
        x0: clamp_to(xmin, vp.width),
        x1: clamp_to(xmax, vp.width),
        y0: clamp_to(ymin, vp.height),
        y1: clamp_to(ymax, vp.height),
        ox: sx[0],
        oy: sy[0],
        k: [sy[2] - sy[0], sx[2] - sx[0], sx[1] - sx[0], sy[1] - sy[0]],
        inv_den: 1.0 / den,
        z: w.map(|v| v.z as f64),
        oow: w.map(|v| v.oow as f64),
        attr,
    })
}

/// Rasterises the triangles of one band (rows `row0..row0 + out.len() / width`), in index order.
fn raster_band(tris: &[TriSetup], bin: &[usize], row0: usize, width: usize, out: &mut [Option<Fragment>]) {
    let rows = out.len() / width;
    let mut depth = vec![CLEAR_DEPTH; out.len()];
    for &ti in bin {
        let t = &tris[ti];
        let (ya, yb) = (t.y0.max(row0), t.y1.min(row0 + rows - 1));
        for py in ya..=yb {
            let (x_fixed, y_fixed) = (t.x0 as i64 * SUB, py as i64 * SUB);
            let mut e = [0i64; 3];
            let mut step = [0i64; 3];
            for i in 0..3 {
                e[i] = t.edx[i] * (y_fixed - t.fy[i]) - t.edy[i] * (x_fixed - t.fx[i]) - t.bias[i];
                step[i] = -t.edy[i] * SUB;
            }
            let row = (py - row0) * width;
            for px in t.x0..=t.x1 {
                if (e[0] | e[1] | e[2]) >= 0 {
                    shade(t, px, py, &mut depth[row + px], &mut out[row + px]);
                }
                for i in 0..3 {
                    e[i] += step[i];
                }
            }
        }
    }
}

/// Perspective-correct barycentric weights (normalised) at the centre of pixel (px, py).
fn weights_at(t: &TriSetup, px: usize, py: usize) -> [f64; 3] {
    let dx = px as f64 + 0.5 - t.ox;
    let dy = py as f64 + 0.5 - t.oy;
    let l1 = (dx * t.k[0] - dy * t.k[1]) * t.inv_den;
    let l2 = (dy * t.k[2] - dx * t.k[3]) * t.inv_den;
    let l0 = 1.0 - l1 - l2;
    let mut b = [l0 * t.oow[0], l1 * t.oow[1], l2 * t.oow[2]];
    let mut s = b[0] + b[1] + b[2];
    if !(s > 0.0 && s.is_finite()) {
        b = [l0, l1, l2].map(|l| l.max(0.0));
        s = (b[0] + b[1] + b[2]).max(f64::MIN_POSITIVE);
    }
    b.map(|x| x / s)
}

/// The interpolated uv at pixel (px, py) of the triangle (extrapolated outside it).
fn uv_at(t: &TriSetup, px: usize, py: usize) -> [f32; 2] {
    let b = weights_at(t, px, py);
    [12, 13].map(|k| (b[0] * t.attr[0][k] as f64 + b[1] * t.attr[1][k] as f64 + b[2] * t.attr[2][k] as f64) as f32)
}

/// Depth test and attribute interpolation at the centre of a covered pixel.
fn shade(t: &TriSetup, px: usize, py: usize, depth: &mut f32, out: &mut Option<Fragment>) {
    let dx = px as f64 + 0.5 - t.ox;
    let dy = py as f64 + 0.5 - t.oy;
    let l1 = (dx * t.k[0] - dy * t.k[1]) * t.inv_den;
    let l2 = (dy * t.k[2] - dx * t.k[3]) * t.inv_den;
    let l0 = 1.0 - l1 - l2;
    // Window depth is affine in screen space: no perspective correction.
    let z = (t.z[0] + l1 * (t.z[1] - t.z[0]) + l2 * (t.z[2] - t.z[0])).clamp(0.0, 1.0) as f32;
    if z.is_nan() || z >= *depth {
        return;
    }
    let mut b = [l0 * t.oow[0], l1 * t.oow[1], l2 * t.oow[2]];
    let mut s = b[0] + b[1] + b[2];
    if !(s > 0.0 && s.is_finite()) {
        // Only reachable through extreme extrapolation; keep the fragment finite.
        b = [l0, l1, l2].map(|l| l.max(0.0));
        s = (b[0] + b[1] + b[2]).max(f64::MIN_POSITIVE);
    }
    let inv_s = 1.0 / s;
    let mut a = [0.0f32; N_ATTR];
    for (k, ak) in a.iter_mut().enumerate() {
        *ak = ((b[0] * t.attr[0][k] as f64 + b[1] * t.attr[1][k] as f64 + b[2] * t.attr[2][k] as f64) * inv_s) as f32;
    }
    *depth = z;
    *out = Some(Fragment {
        position: [a[0], a[1], a[2]],
        normal: [a[3], a[4], a[5]],
        tangent: [a[6], a[7], a[8]],
        bitangent: [a[9], a[10], a[11]],
        uv: [a[12], a[13]],
        depth: z,
        duv_dx: {
            let (e, o) = (uv_at(t, px & !1, py), uv_at(t, px | 1, py));
            [o[0] - e[0], o[1] - e[1]]
        },
        duv_dy: {
            let (e, o) = (uv_at(t, px, py & !1), uv_at(t, px, py | 1));
            [o[0] - e[0], o[1] - e[1]]
        },
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{DMat4, DVec3, DVec4};
    use std::f64::consts::PI;

    /// The camera straight above the origin at height `h`, 90 degree field of view: world (x, y, 0)
    /// maps to window (W/2 + x W/(2h), H/2 - y H/(2h)).
    fn top_camera(h: f32) -> Camera {
        Camera::look_at([0.0, 0.0, h], [0.0, 0.0, 0.0], 90.0).unwrap()
    }

    /// A mesh of triangles given in window coordinates of `top_camera(1.0)` on a `w` x `h` image.
    fn window_mesh(points: &[[f64; 2]], faces: &[[u32; 3]], w: usize, h: usize) -> Mesh {
        let positions: Vec<[f32; 3]> = points
            .iter()
            .map(|p| {
                [
                    ((p[0] - w as f64 / 2.0) / (w as f64 / 2.0)) as f32,
                    ((h as f64 / 2.0 - p[1]) / (h as f64 / 2.0)) as f32,
                    0.0,
                ]
            })
            .collect();
        let uvs: Vec<[f32; 2]> = positions.iter().map(|p| [p[0], p[1]]).collect();
        Mesh::from_arrays(&positions, &uvs, faces, None).unwrap()
    }

    fn covered_set(g: &GBuffer) -> Vec<bool> {
        g.pixels.iter().map(|p| p.is_some()).collect()
    }

    /// Expected covered pixel range along one axis for an interval (lo, hi) in window coordinates,
    /// with centres px + 0.5: inclusive at `lo` (left / top edge), exclusive at `hi`.
    fn covered_range(lo: f64, hi: f64) -> std::ops::Range<usize> {
        ((lo - 0.5).ceil() as usize)..((hi - 0.5).ceil() as usize)
    }

    #[test]
    fn plane_from_above_covers_the_expected_rectangle() {
        // Half-extent in pixels = (size / 2) / h * (W / 2). Case 1 puts the edges between pixel
        // centres, case 2 exactly on pixel centres (then the top-left rule decides), case 3 is
        // off-centre and non-square.
        for (size, h, w, ht) in [(0.625f32, 1.0f32, 64usize, 64usize), (0.65625, 1.0, 64, 64), (0.8, 1.3, 90, 50)] {
            let g = rasterize(&Mesh::plane(size), &top_camera(h), w, ht).unwrap();
            let half_x = (size as f64 / 2.0) / h as f64 * (ht as f64 / 2.0); // aspect: x scale uses H
            let half_y = half_x;
            let xs = covered_range(w as f64 / 2.0 - half_x, w as f64 / 2.0 + half_x);
            let ys = covered_range(ht as f64 / 2.0 - half_y, ht as f64 / 2.0 + half_y);
            let expected = xs.len() * ys.len();
            assert_eq!(g.covered_count(), expected, "size {size}: x {xs:?} y {ys:?}");
            for y in 0..ht {
                for x in 0..w {
                    assert_eq!(g.get(x, y).is_some(), xs.contains(&x) && ys.contains(&y), "pixel ({x}, {y})");
                }
            }
        }
        // Case 2 in closed form: the square spans window [21.5, 42.5]^2, centres 21.5 .. 41.5.
        let g = rasterize(&Mesh::plane(0.65625), &top_camera(1.0), 64, 64).unwrap();
        assert_eq!(g.covered_count(), 21 * 21);
        assert!(g.get(21, 21).is_some() && g.get(41, 41).is_some());
        assert!(g.get(42, 30).is_none() && g.get(30, 42).is_none() && g.get(20, 30).is_none());
    }

    #[test]
    fn back_faces_are_drawn_and_rows_grow_downwards() {
        let below = Camera::look_at([0.0, 0.0, -1.0], [0.0, 0.0, 0.0], 90.0).unwrap();
        let g = rasterize(&Mesh::plane(0.625), &below, 64, 64).unwrap();
        assert_eq!(g.covered_count(), 20 * 20);
        // A small square at world +y (the image's up) lands in the top rows.
        let mut m = Mesh::plane(0.25);
        for p in &mut m.positions {
            p[1] += 0.6;
        }
        let g = rasterize(&m, &top_camera(1.0), 64, 64).unwrap();
        let rows: Vec<usize> = (0..64).filter(|&y| (0..64).any(|x| g.get(x, y).is_some())).collect();
        assert_eq!(rows, (9..17).collect::<Vec<_>>());
    }

    /// Per-pixel coverage counts of each triangle of `mesh` rasterised on its own.
    fn coverage_counts(mesh: &Mesh, camera: &Camera, w: usize, h: usize) -> Vec<u32> {
        let mut counts = vec![0u32; w * h];
        for tri in mesh.indices.chunks(3) {
            let single = Mesh { indices: tri.to_vec(), ..mesh.clone() };
            let g = rasterize(&single, camera, w, h).unwrap();
            for (c, p) in counts.iter_mut().zip(&g.pixels) {
                *c += p.is_some() as u32;
            }
        }
        counts
    }

    #[test]
    fn shared_edges_cover_each_pixel_exactly_once() {
        // The plane's diagonal runs exactly through pixel centres (21.5 + k, 42.5 - k).
        let cam = top_camera(1.0);
        let counts = coverage_counts(&Mesh::plane(0.65625), &cam, 64, 64);
        for y in 0..64 {
            for x in 0..64 {
                let inside = (21..42).contains(&x) && (21..42).contains(&y);
                assert_eq!(counts[y * 64 + x], inside as u32, "pixel ({x}, {y})");
            }
        }
        // A fan around a pixel centre, with horizontal, vertical, diagonal and generic shared
        // edges through many pixel centres: no pixel twice, the centre pixel once, and every
        // pixel strictly inside the polygon once.
        let (w, h) = (64usize, 64usize);
        let c = [32.5, 32.5];
        let rim = [
            [52.5, 32.5],
            [46.5, 46.5],
            [32.5, 52.5],
            [20.5, 50.5],
            [12.5, 32.5],
            [17.5, 15.5],
            [32.5, 12.5],
            [47.5, 21.0],
        ];
        let mut points = vec![c];
        points.extend_from_slice(&rim);
        let faces: Vec<[u32; 3]> = (0..rim.len() as u32).map(|k| [0, 1 + k, 1 + (k + 1) % rim.len() as u32]).collect();
        let mesh = window_mesh(&points, &faces, w, h);
        let counts = coverage_counts(&mesh, &cam, w, h);
        assert!(counts.iter().all(|&n| n <= 1), "double coverage");
        assert_eq!(counts[32 * w + 32], 1, "the shared vertex's pixel");
        // Inside test against the rim polygon (counter-clockwise on screen with y down = clockwise
        // in y-up), with a margin so that pixels on the rim are left out.
        let inside = |x: f64, y: f64| {
            (0..rim.len()).all(|k| {
                let (a, b) = (rim[k], rim[(k + 1) % rim.len()]);
                let cross = (b[0] - a[0]) * (y - a[1]) - (b[1] - a[1]) * (x - a[0]);
                let len = ((b[0] - a[0]).powi(2) + (b[1] - a[1]).powi(2)).sqrt();
                cross / len > 1e-3
            })
        };
        let mut strictly_inside = 0;
        for y in 0..h {
            for x in 0..w {
                if inside(x as f64 + 0.5, y as f64 + 0.5) {
                    strictly_inside += 1;
                    assert_eq!(counts[y * w + x], 1, "gap at ({x}, {y})");
                }
            }
        }
        assert!(strictly_inside > 900);
        // The whole fan at once gives the union.
        let g = rasterize(&mesh, &cam, w, h).unwrap();
        assert_eq!(covered_set(&g), counts.iter().map(|&n| n == 1).collect::<Vec<_>>());
    }

    /// Intersects the ray through the centre of pixel (x, y) with the plane z = 0.
    fn ray_hit_z0(view_proj: DMat4, w: usize, h: usize, x: usize, y: usize) -> DVec3 {
        let inv = view_proj.inverse();
        let ndc_x = (x as f64 + 0.5) / w as f64 * 2.0 - 1.0;
        let ndc_y = 1.0 - (y as f64 + 0.5) / h as f64 * 2.0;
        let unproject = |z: f64| {
            let p = inv * DVec4::new(ndc_x, ndc_y, z, 1.0);
            p.truncate() / p.w
        };
        let (a, b) = (unproject(0.0), unproject(1.0));
        a + (b - a) * (-a.z / (b.z - a.z))
    }

    #[test]
    fn interpolated_uv_matches_the_ray_hit() {
        let size = 2.0f64;
        let cam = Camera::look_at([0.6, -1.7, 1.1], [0.1, 0.2, 0.0], 60.0).unwrap();
        let (w, h) = (96usize, 64usize);
        let g = rasterize(&Mesh::plane(size as f32), &cam, w, h).unwrap();
        let vp = cam.view_proj(w as f32 / h as f32).as_dmat4();
        assert!(g.covered_count() > 1000);
        let mut worst = 0.0f64;
        for y in 0..h {
            for x in 0..w {
                let Some(f) = g.get(x, y) else { continue };
                let hit = ray_hit_z0(vp, w, h, x, y);
                let uv = [hit.x / size + 0.5, hit.y / size + 0.5];
                worst = worst.max((f.uv[0] as f64 - uv[0]).abs()).max((f.uv[1] as f64 - uv[1]).abs());
                assert!((DVec3::from(f.position.map(|c| c as f64)) - hit).length() < 1e-4, "({x}, {y})");
                let clip = vp * hit.extend(1.0);
                assert!((f.depth as f64 - clip.z / clip.w).abs() < 1e-5, "depth at ({x}, {y})");
                assert_eq!((f.normal, f.tangent, f.bitangent), ([0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]));
            }
        }
        assert!(worst < 1e-4, "worst uv error {worst}");
    }

    #[test]
    fn far_sphere_covers_a_disc_of_the_projected_radius() {
        let (r, d, size) = (1.0f64, 50.0f64, 256usize);
        let sphere = Mesh::sphere(r as f32, 64, 32).unwrap();
        // Looking at the side and at the pole (up falls back to +y there).
        for eye in [[0.0, -d as f32, 0.0], [0.0, 0.0, d as f32], [30.0, -30.0, 28.7]] {
            let dist = DVec3::from(eye.map(|c| c as f64)).length();
            let fov = 2.0 * (0.0256f64).atan();
            let cam = Camera::look_at(eye, [0.0; 3], fov.to_degrees() as f32).unwrap();
            let g = rasterize(&sphere, &cam, size, size).unwrap();
            let r_px = (r / dist).asin().tan() / (fov / 2.0).tan() * size as f64 / 2.0;
            let expected = PI * r_px * r_px;
            let got = g.covered_count() as f64;
            assert!((got / expected - 1.0).abs() < 0.01, "eye {eye:?}: {got} pixels, expected {expected:.1}");
            // Interpolated normals are not renormalised: inside triangles they are a bit short.
            let lens: Vec<f64> =
                g.pixels.iter().flatten().map(|f| DVec3::from(f.normal.map(|c| c as f64)).length()).collect();
            assert!(lens.iter().all(|&l| l > 0.99 && l < 1.0 + 1e-5));
            assert!(lens.iter().any(|&l| l < 0.9999));
        }
    }

    #[test]
    fn near_triangle_hides_far_one_whatever_the_order() {
        let far = Mesh::plane(2.0);
        let mut near = Mesh::plane(1.0);
        for p in &mut near.positions {
            p[2] = 0.5;
        }
        let cam = top_camera(3.0);
        for near_first in [true, false] {
            let (a, b) = if near_first { (&near, &far) } else { (&far, &near) };
            let positions: Vec<[f32; 3]> = a.positions.iter().chain(&b.positions).copied().collect();
            let uvs: Vec<[f32; 2]> = a.uvs.iter().chain(&b.uvs).copied().collect();
            let faces = [[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]];
            let mesh = Mesh::from_arrays(&positions, &uvs, &faces, None).unwrap();
            let g = rasterize(&mesh, &cam, 60, 60).unwrap();
            // Near square: window half-extent 0.5 / 2.5 * 30 = 6 px; far: 1 / 3 * 30 = 10 px.
            let (mut n_near, mut n_far) = (0, 0);
            for f in g.pixels.iter().flatten() {
                if f.position[2] == 0.5 {
                    n_near += 1;
                } else {
                    assert_eq!(f.position[2], 0.0);
                    n_far += 1;
                }
            }
            assert_eq!((n_near, n_far), (12 * 12, 20 * 20 - 12 * 12), "near first: {near_first}");
            assert!(g.get(30, 30).unwrap().depth < rasterize(&far, &cam, 60, 60).unwrap().get(30, 30).unwrap().depth);
        }
    }

    /// A floor square z = `floor_z`, |x|, |y| <= `half`, seen from the origin looking along +y.
    fn floor_view(floor_z: f32, half: f32, near: f32) -> (GBuffer, Camera) {
        let p = [[-half, -half, floor_z], [half, -half, floor_z], [half, half, floor_z], [-half, half, floor_z]];
        let uv = p.map(|q| [q[0] / (2.0 * half) + 0.5, q[1] / (2.0 * half) + 0.5]);
        let mesh = Mesh::from_arrays(&p, &uv, &[[0, 1, 2], [0, 2, 3]], None).unwrap();
        let cam = Camera { near, ..Camera::look_at([0.0; 3], [0.0, 1.0, 0.0], 90.0).unwrap() };
        (rasterize(&mesh, &cam, 100, 100).unwrap(), cam)
    }

    fn assert_rows(g: &GBuffer, rows: std::ops::Range<usize>) {
        for y in 0..g.height {
            for x in 0..g.width {
                assert_eq!(g.get(x, y).is_some(), rows.contains(&y), "pixel ({x}, {y})");
            }
        }
        for f in g.pixels.iter().flatten() {
            let all = f.position.iter().chain(&f.normal).chain(&f.tangent).chain(&f.bitangent).chain(&f.uv);
            assert!(all.copied().chain([f.depth]).all(f32::is_finite), "{f:?}");
            assert!((0.0..=1.0).contains(&f.depth));
        }
    }

    #[test]
    fn triangles_crossing_the_near_plane_are_clipped() {
        // Half the floor lies behind the eye (w < 0). The far edge y = 50 projects to window row
        // 51.0, so rows 51..99 are covered (full width: at those depths |x| <= depth < 50).
        let (g, cam) = floor_view(-1.0, 50.0, 0.01);
        assert_rows(&g, 51..100);
        let vp = cam.view_proj(1.0).as_dmat4();
        for (x, y) in [(3, 60), (50, 75), (97, 99)] {
            let f = g.get(x, y).unwrap();
            // The ray hit on z = -1: shift the plane-z0 helper by translating the matrix.
            let shifted = vp * DMat4::from_translation(DVec3::new(0.0, 0.0, -1.0));
            let hit = ray_hit_z0(shifted, 100, 100, x, y);
            let uv = [hit.x / 100.0 + 0.5, hit.y / 100.0 + 0.5];
            assert!((f.uv[0] as f64 - uv[0]).abs() < 1e-4 && (f.uv[1] as f64 - uv[1]).abs() < 1e-4, "({x}, {y})");
        }
        // With the near plane at distance 1 and the floor at z = -0.5, the points closer than 1
        // (window rows below y = 75.0) are cut away; the far edge y = 40 is at row 50.625.
        let (g, _) = floor_view(-0.5, 40.0, 1.0);
        assert_rows(&g, 51..75);
    }

    #[test]
    fn triangles_outside_the_frustum_and_degenerate_input() {
        let cam = top_camera(1.0);
        // Entirely behind the camera, beyond the far plane, or off to the side: nothing.
        for dz in [5.0, -200.0] {
            let mut m = Mesh::plane(1.0);
            m.positions.iter_mut().for_each(|p| p[2] = dz);
            assert_eq!(rasterize(&m, &cam, 32, 32).unwrap().covered_count(), 0);
        }
        let mut m = Mesh::plane(1.0);
        m.positions.iter_mut().for_each(|p| p[0] += 5.0);
        assert_eq!(rasterize(&m, &cam, 32, 32).unwrap().covered_count(), 0);
        // A plane much larger than the view covers everything (clipped on all four sides).
        assert_eq!(rasterize(&Mesh::plane(100.0), &cam, 33, 17).unwrap().covered_count(), 33 * 17);
        // Zero-area (collinear) triangle in a hand-built mesh: no coverage, no panic.
        let mut m = Mesh::plane(1.0);
        m.positions[2] = [0.0, 0.0, 0.0];
        m.positions[0] = [-0.5, -0.5, 0.0];
        m.positions[1] = [0.5, 0.5, 0.0];
        m.indices.truncate(3);
        assert_eq!(rasterize(&m, &cam, 32, 32).unwrap().covered_count(), 0);
        // Huge coordinates: clip space overflows to infinity; the triangle is skipped.
        let mut m = Mesh::plane(1.0);
        m.positions[0] = [3e38, 3e38, 0.0];
        assert!(rasterize(&m, &cam, 32, 32).is_ok());
        // Empty mesh.
        assert_eq!(rasterize(&Mesh::default(), &cam, 8, 8).unwrap().covered_count(), 0);
    }

    #[test]
    fn argument_errors() {
        let cam = top_camera(1.0);
        let mesh = Mesh::plane(1.0);
        for (w, h) in [(0, 10), (10, 0), (MAX_IMAGE_SIZE + 1, 10), (10, MAX_IMAGE_SIZE + 1)] {
            match rasterize(&mesh, &cam, w, h) {
                Err(Error::InvalidArgument { name, .. }) => assert_eq!(name, "size"),
                other => panic!("{w} x {h}: {other:?}"),
            }
        }
        let mut bad = mesh.clone();
        bad.indices[0] = 99;
        assert!(matches!(rasterize(&bad, &cam, 8, 8), Err(Error::InvalidArgument { name, .. }) if name == "mesh"));
        let bad_cam = Camera { fov_y_deg: 0.0, ..cam };
        assert!(
            matches!(rasterize(&mesh, &bad_cam, 8, 8), Err(Error::InvalidArgument { name, .. }) if name == "fov_y_deg")
        );
    }

    #[test]
    fn bands_do_not_change_the_result() {
        // Image heights that are and are not multiples of the band height give the same
        // coverage for the same geometry rows.
        let cam = Camera::look_at([2.0, -3.0, 1.5], [0.0; 3], 40.0).unwrap();
        let sphere = Mesh::sphere(1.0, 32, 16).unwrap();
        let g = rasterize(&sphere, &cam, 80, 80).unwrap();
        let serial = {
            // All triangles in one bin, one band covering the whole image.
            let vp = cam.view_proj(1.0);
            let clip: Vec<[f32; 4]> =
                sphere.positions.iter().map(|p| (vp * Vec4::new(p[0], p[1], p[2], 1.0)).to_array()).collect();
            let viewport = Viewport { width: 80, height: 80, half_w: 40.0, half_h: 40.0 };
            let tris: Vec<TriSetup> = sphere
                .indices
                .chunks(3)
                .flat_map(|tri| {
                    setup_triangle([0, 1, 2].map(|k| clip_vertex(&sphere, &clip, tri[k] as usize)), &viewport)
                        .collect::<Vec<_>>()
                })
                .collect();
            let mut out = vec![None; 80 * 80];
            raster_band(&tris, &(0..tris.len()).collect::<Vec<_>>(), 0, 80, &mut out);
            out
        };
        assert_eq!(g.pixels, serial);
        assert!(g.covered_count() > 500);
    }
}
