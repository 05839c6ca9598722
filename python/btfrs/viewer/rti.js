// The 2D view of a single-view model (an RTI capture) as RTI viewers show it: straight on,
// orthographic, filling the canvas, panned and zoomed down to the texel, each pixel bilinear
// between the four texels around it, in one of RTIViewer's rendering modes (Malzbender et al.
// 2001, section 5; the manifest's `rti` block, written by btfrs.web.rti_block, says what each
// does). The WGSL below is appended to the model's own shader: it calls only what every model
// file provides (`view_query`, `eval_model`), so it draws any model the registry has.

export const RTI_MODES = ["default", "diffuse_gain", "specular", "normals"];
// Fit lights the uniform block holds at most.
export const RTI_MAX_FIT = 32;
// Bytes of the RtiView uniform: 9 vectors, then the fit lights, then the 6 x 32 fit matrix.
export const RTI_UNIFORM_SIZE = 16 * (9 + RTI_MAX_FIT + (6 * RTI_MAX_FIT) / 4);

// The RtiView uniform block, shared by both passes.
const RTI_STRUCT = `
const RTI_MAX_FIT: u32 = ${RTI_MAX_FIT}u;

struct RtiView {
    to_level: vec4<f32>,   // level coordinates of a pixel centre: xy * to_level.xy + to_level.zw
    image: vec4<f32>,      // the image's extent in level coordinates (x, y); z: background
    level: vec4<u32>,      // the level's size (x, y) and the window's origin in it (z, w)
    mode: vec4<u32>,       // the mode (0 default, 1 diffuse gain, 2 specular, 3 normals), fit lights, taps (4)
    light: vec4<f32>,      // towards the light, unit
    intensity: vec4<f32>,  // the light's RGB
    params: vec4<f32>,     // gain, kd, ks, exponent
    lum: vec4<f32>,        // luminance weights
    texels: vec4<u32>,     // the texels the first pass of two relights: origin (x, y), size (z, w)
    fit_l: array<vec4<f32>, ${RTI_MAX_FIT}>,
    fit_m: array<vec4<f32>, ${(6 * RTI_MAX_FIT) / 4}>,
};
`;

export const RTI_WGSL = `
// --- The 2D view (python/btfrs/viewer/rti.js) -------------------------------------------------
${RTI_STRUCT}
@group(2) @binding(0) var<uniform> rti: RtiView;

@vertex
fn vs_rti(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    let p = vec2<f32>(f32((i << 1u) & 2u), f32(i & 2u));
    return vec4<f32>(p * 2.0 - 1.0, 0.5, 1.0);
}

fn rti_m(r: u32, k: u32) -> f32 {
    let i = r * RTI_MAX_FIT + k;
    return rti.fit_m[i / 4u][i % 4u];
}

// Per channel, the coefficients of (lx^2, ly^2, lx ly, lx, ly, 1) fitted to the texel's values at
// the fit lights by least squares (the manifest's matrix).
struct RtiPoly {
    a0: vec3<f32>, a1: vec3<f32>, a2: vec3<f32>, a3: vec3<f32>, a4: vec3<f32>, a5: vec3<f32>,
};

// RTIViewer's normal: the stationary point (u0, v0) of the luminance polynomial ((0, 0) where its
// quadratic part is singular), clamped to the unit disc, lifted onto the hemisphere.
fn rti_normal(p: RtiPoly) -> vec3<f32> {
    let w = rti.lum.xyz;
    let a0 = dot(w, p.a0);
    let a1 = dot(w, p.a1);
    let a2 = dot(w, p.a2);
    let a3 = dot(w, p.a3);
    let a4 = dot(w, p.a4);
    let det = 4.0 * a0 * a1 - a2 * a2;
    var uv = vec2<f32>(0.0);
    if (abs(det) > 1e-6 * (a0 * a0 + a1 * a1 + a2 * a2)) {
        uv = vec2<f32>((a2 * a4 - 2.0 * a1 * a3) / det, (a2 * a3 - 2.0 * a0 * a4) / det);
    }
    let r = length(uv);
    if (r > 1.0) {
        uv = uv / r;
    }
    return vec3<f32>(uv, sqrt(max(0.0, 1.0 - dot(uv, uv))));
}

// The mode's value at one texel. The model is evaluated at one call site, in one loop over the
// fit lights and then the light (only the light in the default mode): software rasterisers
// inline every call, and one call keeps the pipeline as small as the model's own.
fn rti_texel(texel: u32, vq: ViewQuery) -> vec3<f32> {
    let mode = rti.mode.x;
    let nk = rti.mode.y;
    var p = RtiPoly(vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0));
    var f = vec3<f32>(0.0);
    var k = select(0u, nk, mode == 0u);
    loop {
        if (k > nk) {
            break;
        }
        var l = rti.light.xyz;
        if (k < nk) {
            l = rti.fit_l[k].xyz;
        }
        let y = eval_model(texel, vq, l);
        if (k < nk) {
            p.a0 += rti_m(0u, k) * y;
            p.a1 += rti_m(1u, k) * y;
            p.a2 += rti_m(2u, k) * y;
            p.a3 += rti_m(3u, k) * y;
            p.a4 += rti_m(4u, k) * y;
            p.a5 += rti_m(5u, k) * y;
        } else {
            f = y;
        }
        k++;
    }
    if (mode == 0u) {
        return f * rti.intensity.xyz;
    }
    let n = rti_normal(p);
    if (mode == 3u) {
        return (n + vec3<f32>(1.0)) * 0.5;
    }
    let l = rti.light.xyz;
    if (mode == 1u) {
        // Diffuse gain: the quadratic terms times g, the value and slope at (u0, v0) kept.
        let g = rti.params.x;
        let u0 = n.x;
        let v0 = n.y;
        let d3 = (1.0 - g) * (2.0 * p.a0 * u0 + p.a2 * v0);
        let d4 = (1.0 - g) * (2.0 * p.a1 * v0 + p.a2 * u0);
        let d5 = (1.0 - g) * (p.a0 * u0 * u0 + p.a1 * v0 * v0 + p.a2 * u0 * v0) - d3 * u0 - d4 * v0;
        let dq = (g - 1.0) * (p.a0 * l.x * l.x + p.a1 * l.y * l.y + p.a2 * l.x * l.y) + d3 * l.x + d4 * l.y + d5;
        return (f + dq) * rti.intensity.xyz;
    }
    // Specular enhancement: kd f + ks (n . h)^exponent, h between the light and the view.
    let h = normalize(l + vec3<f32>(0.0, 0.0, 1.0));
    let nh = dot(n, h);
    var s = 0.0;
    if (nh > 0.0) {
        s = pow(nh, rti.params.w);
    }
    return (rti.params.y * f + vec3<f32>(rti.params.z * s)) * rti.intensity.xyz;
}

// The window's index of level texel (x, y) (the window is the store's texels: g.sample_size).
fn rti_index(x: i32, y: i32) -> u32 {
    let wx = clamp(x - i32(rti.level.z), 0, i32(g.sample_size.x) - 1);
    let wy = clamp(y - i32(rti.level.w), 0, i32(g.sample_size.y) - 1);
    return u32(wy) * g.sample_size.x + u32(wx);
}

@fragment
fn fs_rti(@builtin(position) pos: vec4<f32>) -> @location(0) vec4<f32> {
    let p = pos.xy * rti.to_level.xy + rti.to_level.zw;
    if (p.x < 0.0 || p.y < 0.0 || p.x >= rti.image.x || p.y >= rti.image.y) {
        return vec4<f32>(vec3<f32>(rti.image.z), 1.0);
    }
    let vq = view_query(vec3<f32>(0.0, 0.0, 1.0));
    // Bilinear between the texel centres (at k + 0.5), clamped at the image's edges.
    let q = p - vec2<f32>(0.5);
    let i0 = floor(q);
    let f = q - i0;
    let wl = i32(rti.level.x) - 1;
    let hl = i32(rti.level.y) - 1;
    let x0 = clamp(i32(i0.x), 0, wl);
    let x1 = clamp(i32(i0.x) + 1, 0, wl);
    let y0 = clamp(i32(i0.y), 0, hl);
    let y1 = clamp(i32(i0.y) + 1, 0, hl);
    // The four taps in one loop (rti.mode.z = 4): one call site of the model.
    var sum = vec3<f32>(0.0);
    for (var t = 0u; t < rti.mode.z; t++) {
        let right = (t & 1u) == 1u;
        let down = t >= 2u;
        let w = select(1.0 - f.x, f.x, right) * select(1.0 - f.y, f.y, down);
        sum += w * rti_texel(rti_index(select(x0, x1, right), select(y0, y1, down)), vq);
    }
    return vec4<f32>(sum, 1.0);
}

// The first of two passes (magnified views): the mode's value of each texel of rti.texels, one
// fragment a texel, into a float texture the second pass (RTI_SHOW_WGSL) interpolates.
@fragment
fn fs_rti_texels(@builtin(position) pos: vec4<f32>) -> @location(0) vec4<f32> {
    let x = i32(rti.texels.x) + i32(pos.x);
    let y = i32(rti.texels.y) + i32(pos.y);
    let vq = view_query(vec3<f32>(0.0, 0.0, 1.0));
    return vec4<f32>(rti_texel(rti_index(x, y), vq), 1.0);
}
`;

// The second pass of two: each pixel bilinear between the four relit texels around it (a
// module of its own, the model not involved).
export const RTI_SHOW_WGSL = `
${RTI_STRUCT}
@group(0) @binding(0) var<uniform> rti: RtiView;
@group(0) @binding(1) var values: texture_2d<f32>;

@vertex
fn vs_show(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    let p = vec2<f32>(f32((i << 1u) & 2u), f32(i & 2u));
    return vec4<f32>(p * 2.0 - 1.0, 0.5, 1.0);
}

fn value_at(x: i32, y: i32) -> vec3<f32> {
    let tx = clamp(x - i32(rti.texels.x), 0, i32(rti.texels.z) - 1);
    let ty = clamp(y - i32(rti.texels.y), 0, i32(rti.texels.w) - 1);
    return textureLoad(values, vec2<i32>(tx, ty), 0).xyz;
}

@fragment
fn fs_show(@builtin(position) pos: vec4<f32>) -> @location(0) vec4<f32> {
    let p = pos.xy * rti.to_level.xy + rti.to_level.zw;
    if (p.x < 0.0 || p.y < 0.0 || p.x >= rti.image.x || p.y >= rti.image.y) {
        return vec4<f32>(vec3<f32>(rti.image.z), 1.0);
    }
    let q = p - vec2<f32>(0.5);
    let i0 = floor(q);
    let f = q - i0;
    let wl = i32(rti.level.x) - 1;
    let hl = i32(rti.level.y) - 1;
    let x0 = clamp(i32(i0.x), 0, wl);
    let x1 = clamp(i32(i0.x) + 1, 0, wl);
    let y0 = clamp(i32(i0.y), 0, hl);
    let y1 = clamp(i32(i0.y) + 1, 0, hl);
    let c = mix(mix(value_at(x0, y0), value_at(x1, y0), f.x), mix(value_at(x0, y1), value_at(x1, y1), f.x), f.y);
    return vec4<f32>(c, 1.0);
}
`;

// The level drawn at `zoom` screen pixels per image texel, of a pyramid of `levels` levels (the
// last the image): texels of about one pixel, never smaller than 0.7 pixel.
export function rtiLevelFor(zoom, levels) {
  const halvings = Math.max(0, Math.round(Math.log2(1 / zoom)));
  return Math.max(0, levels - 1 - halvings);
}

// The size of level `level` of a pyramid of an image `width x height` in `levels` levels (each
// level half the next, rounded down, at least 1).
export function rtiLevelSize(width, height, levels, level) {
  const s = levels - 1 - level;
  return [Math.max(1, Math.floor(width / 2 ** s)), Math.max(1, Math.floor(height / 2 ** s))];
}

// The window of level `level` a view needs: the texels under the canvas and one more around
// (bilinear taps), clamped to the level, widened to whole tiles of `align` (0: none).
// `view`: {width, height (canvas pixels), zoom, center [x, y] (image texels)}.
export function rtiWindow(view, imageSize, levels, level, align) {
  const [lw, lh] = rtiLevelSize(imageSize[0], imageSize[1], levels, level);
  const s = 2 ** (levels - 1 - level);
  const half = [view.width / (2 * view.zoom), view.height / (2 * view.zoom)];
  let x0 = Math.floor((view.center[0] - half[0]) / s) - 1;
  let y0 = Math.floor((view.center[1] - half[1]) / s) - 1;
  let x1 = Math.ceil((view.center[0] + half[0]) / s) + 1;
  let y1 = Math.ceil((view.center[1] + half[1]) / s) + 1;
  if (align > 0) {
    x0 = Math.floor(x0 / align) * align;
    y0 = Math.floor(y0 / align) * align;
    x1 = Math.ceil(x1 / align) * align;
    y1 = Math.ceil(y1 / align) * align;
  }
  x0 = Math.min(Math.max(0, x0), lw - 1);
  y0 = Math.min(Math.max(0, y0), lh - 1);
  x1 = Math.max(x0 + 1, Math.min(lw, x1));
  y1 = Math.max(y0 + 1, Math.min(lh, y1));
  return { level, x0, y0, w: x1 - x0, h: y1 - y0, levelSize: [lw, lh], scale: s };
}

// The texels under the canvas, with the taps around them, within the window: what the first of
// two passes relights. {x0, y0, w, h} in level texels.
export function rtiVisible(view, win) {
  const s = win.scale;
  const lo = (c, half) => Math.floor((c - half) / s - 0.5);
  const hi = (c, half) => Math.floor((c + half) / s - 0.5) + 2;
  const hx = view.width / (2 * view.zoom);
  const hy = view.height / (2 * view.zoom);
  const x0 = Math.min(Math.max(win.x0, lo(view.center[0], hx)), win.x0 + win.w - 1);
  const y0 = Math.min(Math.max(win.y0, lo(view.center[1], hy)), win.y0 + win.h - 1);
  const x1 = Math.max(x0 + 1, Math.min(win.x0 + win.w, hi(view.center[0], hx)));
  const y1 = Math.max(y0 + 1, Math.min(win.y0 + win.h, hi(view.center[1], hy)));
  return { x0, y0, w: x1 - x0, h: y1 - y0 };
}

// The RtiView uniform block of a frame. `view`: {width, height, zoom, center}; `win`: the
// window (rtiWindow); `rti`: the manifest's block; `s`: {mode, light, intensity, gain, kd, ks,
// exponent}; `imageSize`: the image's [width, height]; `texels`: the texels the first of two
// passes relights (rtiVisible), or null for one pass.
export function rtiUniform(view, win, rti, s, imageSize, texels) {
  const data = new ArrayBuffer(RTI_UNIFORM_SIZE);
  const f = new Float32Array(data);
  const u = new Uint32Array(data);
  const k = 1 / (view.zoom * win.scale);
  // Level coordinate of a pixel centre (x + 0.5 in WebGPU's fragment position).
  f.set([k, k, (view.center[0] - view.width / (2 * view.zoom)) / win.scale,
    (view.center[1] - view.height / (2 * view.zoom)) / win.scale], 0);
  f.set([imageSize[0] / win.scale, imageSize[1] / win.scale, 0, 0], 4);
  u.set([win.levelSize[0], win.levelSize[1], win.x0, win.y0], 8);
  const mode = RTI_MODES.indexOf(s.mode);
  const lights = rti.fit_lights;
  if (lights.length > RTI_MAX_FIT) throw new Error(`the manifest has ${lights.length} fit lights; at most ${RTI_MAX_FIT}`);
  u.set([mode, lights.length, 4, 0], 12);
  f.set([s.light[0], s.light[1], s.light[2], 0], 16);
  f.set([s.intensity[0], s.intensity[1], s.intensity[2], 0], 20);
  f.set([s.gain, s.kd, s.ks, s.exponent], 24);
  f.set([rti.luminance[0], rti.luminance[1], rti.luminance[2], 0], 28);
  const t = texels || { x0: 0, y0: 0, w: 0, h: 0 };
  u.set([t.x0, t.y0, t.w, t.h], 32);
  lights.forEach((l, i) => f.set([l[0], l[1], l[2], 0], 36 + 4 * i));
  const m0 = 36 + 4 * RTI_MAX_FIT;
  rti.fit_matrix.forEach((row, r) => row.forEach((x, j) => { f[m0 + r * RTI_MAX_FIT + j] = x; }));
  return data;
}
