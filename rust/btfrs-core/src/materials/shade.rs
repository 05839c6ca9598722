//! Masking, cast shadows and shading of a [`Surface`] into a texel-major BTF.

use super::presets::Surface;
use crate::{Monitor, Result};
use rayon::prelude::*;

/// March step along a ray, in texels. Half a texel keeps thin ridges from being stepped over;
/// the hit is then refined by bisection.
const STEP: f64 = 0.4;
/// Penumbra sharpness of the soft shadow test (larger is harder).
const PENUMBRA: f64 = 8.0;
/// Unshadowed ambient fraction (stands in for inter-reflection).
const AMBIENT: f32 = 0.04;
/// Lowest elevation cosine used for marching: directions at the horizon are marched as if at
/// about 89 degrees so that the march stays bounded.
const MIN_COS: f64 = 0.02;

/// Bilinear interpolation on the periodic grid: the four texel indices and weights around (x, y).
#[inline]
fn corners(size: usize, x: f64, y: f64) -> ([usize; 4], [f64; 4]) {
    let n = size as i64;
    let (fx, fy) = (x - 0.5, y - 0.5);
    let (x0, y0) = (fx.floor(), fy.floor());
    let (tx, ty) = (fx - x0, fy - y0);
    let (x0, y0) = (x0 as i64, y0 as i64);
    let idx = |a: i64, b: i64| (b.rem_euclid(n) * n + a.rem_euclid(n)) as usize;
    (
        [idx(x0, y0), idx(x0 + 1, y0), idx(x0, y0 + 1), idx(x0 + 1, y0 + 1)],
        [(1.0 - tx) * (1.0 - ty), tx * (1.0 - ty), (1.0 - tx) * ty, tx * ty],
    )
}

#[inline]
fn height_at(s: &Surface, x: f64, y: f64) -> f64 {
    let (c, w) = corners(s.size, x, y);
    (0..4).map(|k| s.height[c[k]] as f64 * w[k]).sum()
}

fn range(s: &Surface) -> (f64, f64, f64) {
    let lo = s.height.iter().copied().fold(f32::INFINITY, f32::min) as f64;
    let hi = s.height.iter().copied().fold(f32::NEG_INFINITY, f32::max) as f64;
    let mean = s.height.iter().map(|&h| h as f64).sum::<f64>() / s.height.len() as f64;
    (lo, hi, mean)
}

/// For every view and grid texel, the (x, y) of the surface point that texel shows: the first
/// intersection of the ray through the mean-height plane above the texel, travelling along `-v`.
/// Layout `[V][texel]`. Counts one unit per view on `monitor`; once cancelled, the remaining
/// views are skipped (left empty) and the caller's `monitor.check()` reports the interruption.
pub(super) fn hit_points(s: &Surface, views: &[[f64; 3]], monitor: &Monitor) -> Vec<Vec<[f64; 2]>> {
    let (lo, hi, zref) = range(s);
    let n = s.size;
    views
        .par_iter()
        .map(|v| {
            if monitor.is_cancelled() {
                return Vec::new();
            }
            let vz = v[2].max(MIN_COS);
            let hits = (0..n * n)
                .map(|g| {
                    let (x, y) = ((g % n) as f64 + 0.5, (g / n) as f64 + 0.5);
                    if hi - lo < 1e-9 || v[2] >= 1.0 - 1e-12 {
                        return [x, y];
                    }
                    let at = |t: f64| [x + t * v[0], y + t * v[1], zref + t * vz];
                    let below = |t: f64| {
                        let q = at(t);
                        q[2] <= height_at(s, q[0], q[1])
                    };
                    let top = (hi - zref) / vz + 1e-6;
                    let bottom = (lo - zref) / vz;
                    let mut t_prev = top;
                    let mut t = top;
                    let mut hit = bottom;
                    while t > bottom {
                        t = (t - STEP).max(bottom);
                        if below(t) {
                            // Bisection between the last point above and the first below.
                            let (mut a, mut b) = (t_prev, t);
                            for _ in 0..10 {
                                let m = 0.5 * (a + b);
                                if below(m) {
                                    b = m
                                } else {
                                    a = m
                                }
                            }
                            hit = 0.5 * (a + b);
                            break;
                        }
                        t_prev = t;
                    }
                    let q = at(hit);
                    [q[0], q[1]]
                })
                .collect();
            monitor.advance(1);
            hits
        })
        .collect()
}

/// Soft visibility of every light from every grid texel's surface point, layout `[texel][L]`.
/// Counts one unit per grid row on `monitor` and stops early once it is cancelled.
pub(super) fn shadow_maps(s: &Surface, lights: &[[f64; 3]], monitor: &Monitor) -> Vec<f32> {
    let (_, hi, _) = range(s);
    let n = s.size;
    let nl = lights.len();
    let mut out = vec![1.0f32; n * n * nl];
    out.par_chunks_mut(nl * n).enumerate().for_each(|(gy, grid_row)| {
        if monitor.is_cancelled() {
            return;
        }
        for (gx, row) in grid_row.chunks_mut(nl).enumerate() {
            let g = gy * n + gx;
            let (x, y) = (gx as f64 + 0.5, gy as f64 + 0.5);
            let z = s.height[g] as f64;
            for (l, d) in lights.iter().enumerate() {
                let lz = d[2].max(MIN_COS);
                let mut vis: f64 = 1.0;
                let mut t = 0.5 * STEP;
                // Once the ray is above the highest point nothing can occlude it any more.
                while z + t * lz <= hi {
                    let q = [x + t * d[0], y + t * d[1], z + t * lz];
                    let gap = q[2] - height_at(s, q[0], q[1]);
                    vis = vis.min(PENUMBRA * gap / t);
                    if vis <= 0.0 {
                        vis = 0.0;
                        break;
                    }
                    t += STEP;
                }
                row[l] = vis.clamp(0.0, 1.0) as f32;
            }
        }
        monitor.advance(1);
    });
    out
}

/// Shade every (texel, view, light) into a `[H, W, V, L, 3]` buffer (row 0 = top of the image).
pub(super) fn render_btf(
    s: &Surface,
    views: &[[f64; 3]],
    lights: &[[f64; 3]],
    subsurface: f64,
    monitor: &Monitor,
) -> Result<Vec<f32>> {
    let maps = prepare(s, views, lights, monitor)?;
    let len = s.size * s.size * views.len() * lights.len() * 3;
    // Fallible allocation: running out of memory must be an error, not an abort of the process.
    let mut data = Vec::new();
    data.try_reserve_exact(len).map_err(|_| {
        crate::Error::arg(
            "size",
            format!("cannot allocate {:.1} GiB for the BTF", (len * 4) as f64 / (1u64 << 30) as f64),
        )
    })?;
    data.resize(len, 0.0f32);
    shade_into(s, views, lights, subsurface, &maps, &mut data, monitor)?;
    Ok(data)
}

/// [`render_btf`] into `data` (`[size, size, V, L, 3]`, e.g. a memory-mapped file: every value
/// is written, row by row, and the blur works in place, so nothing of the BTF's size is
/// allocated besides `data`).
pub(super) fn render_btf_into(
    s: &Surface,
    views: &[[f64; 3]],
    lights: &[[f64; 3]],
    subsurface: f64,
    data: &mut [f32],
    monitor: &Monitor,
) -> Result<()> {
    let maps = prepare(s, views, lights, monitor)?;
    shade_into(s, views, lights, subsurface, &maps, data, monitor)
}

/// What every texel's shading reads: the surface point each view sees through each texel, and
/// each light's visibility map.
struct Maps {
    hits: Vec<Vec<[f64; 2]>>,
    shadow: Vec<f32>,
}

/// Starts the progress count (one unit per view for the masking, one per grid row for the
/// shadows, one per output row) and computes the [`Maps`].
fn prepare(s: &Surface, views: &[[f64; 3]], lights: &[[f64; 3]], monitor: &Monitor) -> Result<Maps> {
    monitor.start((views.len() + 2 * s.size) as u64);
    let hits = hit_points(s, views, monitor);
    monitor.check()?;
    let shadow = shadow_maps(s, lights, monitor);
    monitor.check()?;
    Ok(Maps { hits, shadow })
}

/// The shading of every texel into `data`, row by row, then the blur in place.
fn shade_into(
    s: &Surface,
    views: &[[f64; 3]],
    lights: &[[f64; 3]],
    subsurface: f64,
    maps: &Maps,
    data: &mut [f32],
    monitor: &Monitor,
) -> Result<()> {
    let n = s.size;
    let (nv, nl) = (views.len(), lights.len());
    let (hits, shadow) = (&maps.hits, &maps.shadow);
    let per_texel = nv * nl * 3;
    let lf: Vec<[f32; 3]> = lights.iter().map(|d| d.map(|c| c as f32)).collect();
    assert_eq!(data.len(), n * n * per_texel, "render_btf_into: output of the wrong size");
    data.par_chunks_mut(n * per_texel).enumerate().for_each(|(row, out_row)| {
        if monitor.is_cancelled() {
            return;
        }
        // Output row 0 is the top of the image, i.e. the highest y.
        let gy = n - 1 - row;
        let mut vis = vec![0.0f32; nl];
        for col in 0..n {
            let g = gy * n + col;
            let texel = &mut out_row[col * per_texel..(col + 1) * per_texel];
            for (v, vd) in views.iter().enumerate() {
                let [hx, hy] = hits[v][g];
                let (c, w) = corners(n, hx, hy);
                let w = w.map(|x| x as f32);
                let mut nrm = [0.0f32; 3];
                let mut alb = [0.0f32; 3];
                let (mut ks, mut ex) = (0.0f32, 0.0f32);
                for k in 0..4 {
                    for a in 0..3 {
                        nrm[a] += w[k] * s.normal[c[k]][a];
                        alb[a] += w[k] * s.albedo[c[k]][a];
                    }
                    ks += w[k] * s.ks[c[k]];
                    ex += w[k] * s.exponent[c[k]];
                }
                let inv = 1.0 / (nrm[0] * nrm[0] + nrm[1] * nrm[1] + nrm[2] * nrm[2]).sqrt();
                let nrm = nrm.map(|x| x * inv);
                let sh = [&shadow[c[0] * nl..], &shadow[c[1] * nl..], &shadow[c[2] * nl..], &shadow[c[3] * nl..]];
                for (l, vl) in vis.iter_mut().enumerate() {
                    *vl = w[0] * sh[0][l] + w[1] * sh[1][l] + w[2] * sh[2][l] + w[3] * sh[3][l];
                }
                let vv = vd.map(|x| x as f32);
                let norm = (ex + 8.0) / 8.0;
                let out = &mut texel[v * nl * 3..(v + 1) * nl * 3];
                for (l, ld) in lf.iter().enumerate() {
                    let ndl = (nrm[0] * ld[0] + nrm[1] * ld[1] + nrm[2] * ld[2]).max(0.0);
                    let hv = [ld[0] + vv[0], ld[1] + vv[1], ld[2] + vv[2]];
                    let hl = (hv[0] * hv[0] + hv[1] * hv[1] + hv[2] * hv[2]).sqrt().max(1e-12);
                    let ndh = ((nrm[0] * hv[0] + nrm[1] * hv[1] + nrm[2] * hv[2]) / hl).max(0.0);
                    let spec = ks * norm * ndh.powf(ex);
                    let direct = vis[l] * ndl;
                    let amb = AMBIENT * ld[2].max(0.0);
                    for a in 0..3 {
                        out[l * 3 + a] = direct * (alb[a] + spec) + amb * alb[a];
                    }
                }
            }
        }
        monitor.advance(1);
    });
    monitor.check()?;
    if subsurface > 0.0 {
        blur_in_place(data, n, per_texel, subsurface as f32);
    }
    Ok(())
}

/// Mix each texel's ABRDF with the mean of its four neighbours (periodic), weight `a`, in place:
/// row by row, keeping the original values of the row above, the row itself and row 0 (the last
/// row's neighbour below), so three rows are copied instead of the whole BTF.
fn blur_in_place(data: &mut [f32], n: usize, per: usize, a: f32) {
    let row = n * per;
    let first: Vec<f32> = data[..row].to_vec();
    let mut above: Vec<f32> = data[(n - 1) * row..].to_vec();
    let mut me: Vec<f32> = vec![0.0f32; row];
    for r in 0..n {
        me.copy_from_slice(&data[r * row..(r + 1) * row]);
        let (head, tail) = data.split_at_mut((r + 1) * row);
        let below: &[f32] = if r + 1 < n { &tail[..row] } else { &first };
        head[r * row..].par_chunks_mut(per).enumerate().for_each(|(c, o)| {
            // The neighbours in the order up, down, left, right (the sum's order).
            let (l, rt) = ((c + n - 1) % n, (c + 1) % n);
            let nb = [&above[c * per..], &below[c * per..], &me[l * per..], &me[rt * per..]];
            let x = &me[c * per..(c + 1) * per];
            for k in 0..per {
                let m: f32 = nb.iter().map(|q| q[k]).sum::<f32>() * 0.25;
                o[k] = (1.0 - a) * x[k] + a * m;
            }
        });
        std::mem::swap(&mut above, &mut me);
    }
}
