// common.wgsl: what every BTF model shader shares (prepended to the model's own file).
//
// The mesh is rasterised with its per-vertex tangent frame (T = dP/du, B = dP/dv, N), which
// follows the UV parameterisation as paper 002, section 4.2 requires; each fragment expresses
// the view and light directions in that frame and asks the model for the BTF value there. The
// texel comes from the UV coordinate, optionally through a coordinate map (paper 000, section
// 5: a synthesised BTF is the sample plus a map of u16 (x, y) texel coordinates), or through a
// Wang tile map (paper 002, section 4: a layout of atlas tiles, two lookups in `coord_map`).
//
// A model file provides:
//   struct ViewQuery { ... }                                  per-fragment view preparation
//   fn view_query(v: vec3<f32>) -> ViewQuery
//   fn eval_model(texel: u32, vq: ViewQuery, l: vec3<f32>) -> vec3<f32>
// and reads its data through `load(i)` (the model store) and `mp` (its parameters).
// The CPU reference (rust/btfrs-render/src/cpu.rs) mirrors every formula here.

struct Globals {
    view_proj: mat4x4<f32>,
    eye: vec4<f32>,
    uv_scale: vec2<f32>,
    sample_size: vec2<u32>,   // model texels (width, height)
    map_size: vec2<u32>,      // coordinate map (width, height); (0, 0) = no map
    n_lights: u32,
    chunk_len: u32,           // f32 elements per store chunk
    tiles: vec4<u32>,         // tile map: (tile side, layout columns, layout rows, atlas width); x = 0: none
    tile_atlas: vec4<u32>,    // tile map: (offset of the atlas in coord_map, unused x 3)
    lookup: vec4<u32>,        // filtered lookups: (mode 0 nearest / 1 bilinear / 2 trilinear, mip levels, mip table offset in coord_map, unused)
};

struct Light {
    pos: vec4<f32>,           // w = 1: point light at xyz; w = 0: directional, xyz towards the light
    intensity: vec4<f32>,
};

@group(0) @binding(0) var<uniform> g: Globals;
@group(0) @binding(1) var<storage, read> lights: array<Light>;
@group(0) @binding(2) var<storage, read> coord_map: array<u32>;
// Per-frame data of a lighting method other than the light list (the SH environment method of
// sh.wgsl, `fs_env`); one placeholder vector otherwise.
@group(0) @binding(3) var<storage, read> env: array<vec4<f32>>;

// The model's parameters `mp` (group 1, binding 0) are a `struct Params` of 16 words generated
// from the model's Rust parameter struct (btfrs_fit::gpu_params!) and placed after this file, so
// each word's meaning is written once, in Rust. The data store: the model's arrays concatenated
// and split into chunks no larger than the adapter's storage binding limit (128 MiB on
// lavapipe), so that a large BTF still fits.
@group(1) @binding(1) var<storage, read> s0: array<u32>;
@group(1) @binding(2) var<storage, read> s1: array<u32>;
@group(1) @binding(3) var<storage, read> s2: array<u32>;
@group(1) @binding(4) var<storage, read> s3: array<u32>;
@group(1) @binding(5) var<storage, read> s4: array<u32>;
@group(1) @binding(6) var<storage, read> s5: array<u32>;
@group(1) @binding(7) var<storage, read> s6: array<u32>;
@group(1) @binding(8) var<storage, read> s7: array<u32>;
// The model's measured direction sets (xyz, w unused), searched once or more per fragment: kept
// apart from the store so the search reads them as whole vectors without the chunk switch.
@group(1) @binding(9) var<storage, read> mdirs: array<vec4<f32>>;
// Per direction set, a candidate table over the concentric-map square (see nearest4).
@group(1) @binding(10) var<storage, read> tables: array<u32>;
// An optional RGBA8 3D texture with its trilinear sampler (the resampled LPCA Eigen-BRDFs of
// paper 004, section 6.2); a 1 x 1 x 1 placeholder for the other models.
@group(1) @binding(11) var vol: texture_3d<f32>;
@group(1) @binding(12) var vol_sampler: sampler;

// <load>
fn load_u32(i: u32) -> u32 {
    let c = i / g.chunk_len;
    let o = i - c * g.chunk_len;
    switch c {
        case 0u: { return s0[o]; }
        case 1u: { return s1[o]; }
        case 2u: { return s2[o]; }
        case 3u: { return s3[o]; }
        case 4u: { return s4[o]; }
        case 5u: { return s5[o]; }
        case 6u: { return s6[o]; }
        default: { return s7[o]; }
    }
}
// </load>

// The store holds 32-bit words: f32 values bit for bit, or packed integers (8-bit quantized
// models read `load_u32` and unpack).
fn load(i: u32) -> f32 {
    return bitcast<f32>(load_u32(i));
}

// Entry `j` of a u16 array packed two to a word from store offset `base` (low half first).
fn load_u16(base: u32, j: u32) -> u32 {
    return (load_u32(base + j / 2u) >> ((j & 1u) * 16u)) & 0xffffu;
}

fn load_dir(i: u32) -> vec3<f32> {
    return vec3<f32>(load(i), load(i + 1u), load(i + 2u));
}

// --- Interpolation over measured directions (mirrors btfrs_core::directions::interp_weights) --

fn angle_between(a: vec3<f32>, b: vec3<f32>) -> f32 {
    return atan2(length(cross(a, b)), dot(a, b));
}

// The four nearest directions so far, by cosine (largest first). Plain fields and straight-line
// insertion instead of arrays: dynamically indexed local arrays are slow on software rasterisers.
struct Near4 {
    i0: u32, i1: u32, i2: u32, i3: u32,
    c0: f32, c1: f32, c2: f32, c3: f32,
};

// --- The elevated concentric map (paper 004, section 6.1; mirrors rust/btfrs-hemimap) ----------

// Direction (any length, z >= 0) to the square [0, 1]^2: inverse of the elevation map (rho from
// z without cancellation), then of Shirley and Chiu's concentric map, one atan2 per call.
fn hemisphere_to_square(d0: vec3<f32>) -> vec2<f32> {
    let m = max(max(abs(d0.x), abs(d0.y)), abs(d0.z));
    var d = d0;
    if (m > 0.0) {
        d = d0 / m;
    }
    var rho = 1.0;
    if (d.z > 0.0) {
        let h2 = d.x * d.x + d.y * d.y;
        let n2 = h2 + d.z * d.z;
        rho = clamp(sqrt(h2 / (n2 + sqrt(n2) * d.z)), 0.0, 1.0);
    }
    let swap = abs(d.y) > abs(d.x);
    var u = d.x;
    var v = d.y;
    if (swap) {
        u = d.y;
        v = d.x;
    }
    var r = rho;
    if (u < 0.0) {
        r = -rho;
        u = -u;
        v = -v;
    }
    let side = r * (atan2(v, u) * 1.2732395447351628);
    var a = r;
    var b = side;
    if (swap) {
        a = side;
        b = r;
    }
    return clamp(vec2<f32>((a + 1.0) * 0.5, (b + 1.0) * 0.5), vec2<f32>(0.0), vec2<f32>(1.0));
}

// The four directions of mdirs[first .. first + count] nearest to q. Only the candidates that
// the table lists for q's cell of the concentric-map square are tested: a conservative superset
// of every point of the cell's four nearest (rust/btfrs-render/src/model.rs, candidate_table),
// so the result is the brute-force one at a fraction of the cost. Nearest by cosine, which
// orders exactly as the angle does; angles are computed afterwards for the four only.
fn nearest4(first: u32, table: u32, q: vec3<f32>) -> Near4 {
    var n = Near4(0u, 0u, 0u, 0u, -2.0, -2.0, -2.0, -2.0);
    let gsz = tables[table];
    let st = hemisphere_to_square(q);
    let cx = min(u32(st.x * f32(gsz)), gsz - 1u);
    let cy = min(u32(st.y * f32(gsz)), gsz - 1u);
    let cell = table + 1u + cy * gsz + cx;
    let list = table + 2u + gsz * gsz;
    for (var k = tables[cell]; k < tables[cell + 1u]; k++) {
        let i = tables[list + k];
        let c = dot(mdirs[first + i].xyz, q);
        if (c <= n.c3) {
            continue;
        }
        if (c > n.c0) {
            n.i3 = n.i2; n.c3 = n.c2; n.i2 = n.i1; n.c2 = n.c1; n.i1 = n.i0; n.c1 = n.c0; n.i0 = i; n.c0 = c;
        } else if (c > n.c1) {
            n.i3 = n.i2; n.c3 = n.c2; n.i2 = n.i1; n.c2 = n.c1; n.i1 = i; n.c1 = c;
        } else if (c > n.c2) {
            n.i3 = n.i2; n.c3 = n.c2; n.i2 = i; n.c2 = c;
        } else {
            n.i3 = i; n.c3 = c;
        }
    }
    return n;
}

// Up to three directions and their weights (unused entries have weight 0).
struct Weights3 {
    i0: u32, i1: u32, i2: u32,
    w0: f32, w1: f32, w2: f32,
};

// Mirrors btfrs_core::directions::interp_weights with k = 3: w_k = 1/d_k - 1/d_4 over the
// three nearest (d = angle), normalised, so a direction's weight reaches zero as it leaves the
// neighbour set and images change continuously with the query.
fn interp3(first: u32, count: u32, table: u32, q: vec3<f32>) -> Weights3 {
    let n = nearest4(first, table, q);
    var out = Weights3(n.i0, n.i1, n.i2, 0.0, 0.0, 0.0);
    let d0 = angle_between(mdirs[first + n.i0].xyz, q);
    if (d0 < 1e-9 || count == 1u) {
        out.w0 = 1.0;
        return out;
    }
    let d1 = angle_between(mdirs[first + n.i1].xyz, q);
    var cut = 0.0;
    var d2 = 0.0;
    if (count >= 3u) {
        d2 = angle_between(mdirs[first + n.i2].xyz, q);
    }
    if (count >= 4u) {
        cut = 1.0 / angle_between(mdirs[first + n.i3].xyz, q);
    }
    out.w0 = max(1.0 / d0 - cut, 0.0);
    out.w1 = max(1.0 / d1 - cut, 0.0);
    if (count >= 3u) {
        out.w2 = max(1.0 / d2 - cut, 0.0);
    }
    let total = out.w0 + out.w1 + out.w2;
    if (total > 0.0) {
        out.w0 /= total;
        out.w1 /= total;
        out.w2 /= total;
    } else {
        let k = f32(min(count, 3u));
        out.w0 = 1.0 / k;
        out.w1 = 1.0 / k;
        if (count >= 3u) {
            out.w2 = 1.0 / k;
        }
    }
    return out;
}

// Light weights with the measured cosine divided out and the query's multiplied in (mirrors
// btfrs_core::directions::cos_corrected: blending values that include cos(theta_l) would darken
// every light between measured directions, cos being concave).
fn cos_correct(w: Weights3, first: u32, l: vec3<f32>) -> Weights3 {
    var o = w;
    let q = max(l.z, 0.0);
    o.w0 *= q / max(mdirs[first + w.i0].z, 0.02);
    o.w1 *= q / max(mdirs[first + w.i1].z, 0.02);
    o.w2 *= q / max(mdirs[first + w.i2].z, 0.02);
    return o;
}

// --- Texel addressing ------------------------------------------------------------------------

// The model texel for a surface UV: repeat `uv_scale` times, v up the texture (row 0 = top).
fn texel_index(uv: vec2<f32>) -> u32 {
    let s = uv * g.uv_scale;
    let f = s - floor(s);
    if (g.tiles.x > 0u) {
        // Wang tile map (paper 002 section 4; rust/btfrs-render/src/tilemap.rs): the layout
        // cell, the texel inside it, its atlas tile, the atlas entry.
        let tile = g.tiles.x;
        let gx = f.x * f32(g.tiles.y);
        let gy = (1.0 - f.y) * f32(g.tiles.z);
        let cx = min(u32(gx), g.tiles.y - 1u);
        let cy = min(u32(gy), g.tiles.z - 1u);
        let px = min(u32((gx - f32(cx)) * f32(tile)), tile - 1u);
        let py = min(u32((gy - f32(cy)) * f32(tile)), tile - 1u);
        let e = coord_map[cy * g.tiles.y + cx];
        let ax = (e & 0xffffu) * tile + px;
        let ay = (e >> 16u) * tile + py;
        return coord_map[g.tile_atlas.x + ay * g.tiles.w + ax];
    }
    if (g.map_size.x > 0u) {
        let mc = min(u32(f.x * f32(g.map_size.x)), g.map_size.x - 1u);
        let mr = min(u32((1.0 - f.y) * f32(g.map_size.y)), g.map_size.y - 1u);
        let e = coord_map[mr * g.map_size.x + mc];
        return (e >> 16u) * g.sample_size.x + (e & 0xffffu);
    }
    let c = min(u32(f.x * f32(g.sample_size.x)), g.sample_size.x - 1u);
    let r = min(u32((1.0 - f.y) * f32(g.sample_size.y)), g.sample_size.y - 1u);
    return r * g.sample_size.x + c;
}

// --- Filtered lookups (rust/btfrs-render/src/filter.rs, which this mirrors) -------------------
//
// In the virtual texture the surface shows (the sample, the coordinate map, the tile layout),
// each tap resolved through the map on its own (no seams at map discontinuities); mip levels
// hold appearance medoids. The level table at g.lookup.z: per level (width, height, offset of
// its ids in coord_map, row stride).

struct Taps {
    t: array<u32, 8>,
    w: array<f32, 8>,
    n: u32,
};

fn mip_texel(level: u32, x: u32, y: u32) -> u32 {
    let lt = g.lookup.z + level * 4u;
    let off = coord_map[lt + 2u];
    let stride = coord_map[lt + 3u];
    if (g.tiles.x > 0u) {
        let tl = g.tiles.x >> level;
        let e = coord_map[(y / tl) * g.tiles.y + x / tl];
        let ax = (e & 0xffffu) * tl + x % tl;
        let ay = (e >> 16u) * tl + y % tl;
        return coord_map[off + ay * stride + ax];
    }
    return coord_map[off + y * stride + x];
}

fn wrap_index(v: i32, n: u32) -> u32 {
    let m = i32(n);
    return u32(((v % m) + m) % m);
}

fn bilinear_taps(level: u32, f: vec2<f32>, scale: f32, taps: ptr<function, Taps>) {
    let lt = g.lookup.z + level * 4u;
    let w = coord_map[lt];
    let h = coord_map[lt + 1u];
    let px = f.x * f32(w) - 0.5;
    let py = (1.0 - f.y) * f32(h) - 0.5;
    let x0f = floor(px);
    let y0f = floor(py);
    let fx = px - x0f;
    let fy = py - y0f;
    let x0 = wrap_index(i32(x0f), w);
    let y0 = wrap_index(i32(y0f), h);
    let x1 = (x0 + 1u) % w;
    let y1 = (y0 + 1u) % h;
    let n = (*taps).n;
    (*taps).t[n] = mip_texel(level, x0, y0);
    (*taps).w[n] = (1.0 - fx) * (1.0 - fy) * scale;
    (*taps).t[n + 1u] = mip_texel(level, x1, y0);
    (*taps).w[n + 1u] = fx * (1.0 - fy) * scale;
    (*taps).t[n + 2u] = mip_texel(level, x0, y1);
    (*taps).w[n + 2u] = (1.0 - fx) * fy * scale;
    (*taps).t[n + 3u] = mip_texel(level, x1, y1);
    (*taps).w[n + 3u] = fx * fy * scale;
    (*taps).n = n + 4u;
}

fn texel_taps(uv: vec2<f32>, duv_dx: vec2<f32>, duv_dy: vec2<f32>) -> Taps {
    let s = uv * g.uv_scale;
    let f = s - floor(s);
    var taps: Taps;
    taps.n = 0u;
    if (g.lookup.x == 1u) {
        bilinear_taps(0u, f, 1.0, &taps);
        return taps;
    }
    let sz = g.uv_scale * vec2<f32>(f32(coord_map[g.lookup.z]), f32(coord_map[g.lookup.z + 1u]));
    let lx = sqrt((duv_dx.x * sz.x) * (duv_dx.x * sz.x) + (duv_dx.y * sz.y) * (duv_dx.y * sz.y));
    let ly = sqrt((duv_dy.x * sz.x) * (duv_dy.x * sz.x) + (duv_dy.y * sz.y) * (duv_dy.y * sz.y));
    let lambda = clamp(log2(max(max(lx, ly), 1e-30)), 0.0, f32(g.lookup.y - 1u));
    let l0 = floor(lambda);
    let fr = lambda - l0;
    bilinear_taps(u32(l0), f, 1.0 - fr, &taps);
    if (fr > 0.0) {
        bilinear_taps(u32(l0) + 1u, f, fr, &taps);
    }
    return taps;
}

// --- Vertex and fragment stages --------------------------------------------------------------

struct VsIn {
    @location(0) pos: vec3<f32>,
    @location(1) nrm: vec3<f32>,
    @location(2) tan: vec3<f32>,
    @location(3) bit: vec3<f32>,
    @location(4) uv: vec2<f32>,
};

struct VsOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) pos: vec3<f32>,
    @location(1) nrm: vec3<f32>,
    @location(2) tan: vec3<f32>,
    @location(3) bit: vec3<f32>,
    @location(4) uv: vec2<f32>,
};

@vertex
fn vs_main(v: VsIn) -> VsOut {
    var o: VsOut;
    o.clip = g.view_proj * vec4<f32>(v.pos, 1.0);
    o.pos = v.pos;
    o.nrm = v.nrm;
    o.tan = v.tan;
    o.bit = v.bit;
    o.uv = v.uv;
    return o;
}

fn to_local(w: vec3<f32>, t: vec3<f32>, b: vec3<f32>, n: vec3<f32>) -> vec3<f32> {
    return normalize(vec3<f32>(dot(w, t), dot(w, b), dot(w, n)));
}

// The lights at one texel.
fn shade_lights(texel: u32, vq: ViewQuery, pos: vec3<f32>, t: vec3<f32>, b: vec3<f32>, n: vec3<f32>) -> vec3<f32> {
    var sum = vec3<f32>(0.0);
    for (var i = 0u; i < g.n_lights; i++) {
        let light = lights[i];
        var lw = light.pos.xyz;
        var irr = light.intensity.xyz;
        if (light.pos.w > 0.5) {
            let d = light.pos.xyz - pos;
            let d2 = dot(d, d);
            lw = d / sqrt(d2);
            irr = light.intensity.xyz / d2;
        }
        let l = to_local(lw, t, b, n);
        if (l.z <= 0.0) {
            continue;
        }
        sum += eval_model(texel, vq, l) * irr;
    }
    return sum;
}

// Nearest lookups (the unfiltered renderer). Filtered lookups have their own entry point,
// `fs_filtered` (the pipeline is chosen per frame): keeping the taps out of this one keeps its
// code as small as before (on lavapipe the unused filtered branch cost a PTM frame 40%).
@fragment
fn fs_main(f: VsOut) -> @location(0) vec4<f32> {
    let n = normalize(f.nrm);
    let t = normalize(f.tan);
    let b = normalize(f.bit);
    let v = to_local(normalize(g.eye.xyz - f.pos), t, b, n);
    if (v.z <= 0.0) {
        // The back of the surface: a BTF is defined over the upper hemisphere only.
        return vec4<f32>(0.0, 0.0, 0.0, 1.0);
    }
    return vec4<f32>(shade_lights(texel_index(f.uv), view_query(v), f.pos, t, b, n), 1.0);
}

@fragment
fn fs_filtered(f: VsOut) -> @location(0) vec4<f32> {
    // Derivatives first, in uniform control flow (every invocation of the quad reaches them).
    let duv_dx = dpdxFine(f.uv);
    let duv_dy = dpdyFine(f.uv);
    let n = normalize(f.nrm);
    let t = normalize(f.tan);
    let b = normalize(f.bit);
    let v = to_local(normalize(g.eye.xyz - f.pos), t, b, n);
    if (v.z <= 0.0) {
        return vec4<f32>(0.0, 0.0, 0.0, 1.0);
    }
    let vq = view_query(v);
    let taps = texel_taps(f.uv, duv_dx, duv_dy);
    var sum = vec3<f32>(0.0);
    for (var k = 0u; k < taps.n; k++) {
        sum += taps.w[k] * shade_lights(taps.t[k], vq, f.pos, t, b, n);
    }
    return vec4<f32>(sum, 1.0);
}
