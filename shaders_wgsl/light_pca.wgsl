// light_pca.wgsl: the RBF and bilinear light bases (rust/btfrs-fit/src/rbf.rs, bilinear.rs), both
// stored by rust/btfrs-fit/src/light_pca.rs: per view slot a table of principal light functions
// on an n x n grid of the concentric square, and per texel 8-bit coefficients with a scale and a
// bias per plane. WGSL has no includes, so the two models share this one file (two pipelines).
//
// Parameters: `mp`, the `LightPcaParams` struct of light_pca.rs (the WGSL `struct Params` is
// generated from it). The three nearest view slots are blended (interp3); per slot the table
// rows of the light's four grid nodes are interpolated bilinearly and each channel is the mean
// plus one dot product with the texel's decoded coefficients.

struct ViewQuery {
    w: Weights3,
};

fn view_query(v: vec3<f32>) -> ViewQuery {
    return ViewQuery(interp3(0u, mp.n_views, mp.view_table, v));
}

// Plane `p` (of all V K) of texel `texel`, decoded.
fn lp_coeff(texel: u32, p: u32) -> f32 {
    let kt = mp.n_views * (mp.k_main + mp.k_chroma);
    let i = texel * kt + p;
    let q = (load_u32(mp.q + i / 4u) >> ((i & 3u) * 8u)) & 0xffu;
    return load(mp.scale + kt + p) + load(mp.scale + p) * f32(q);
}

// The bilinear blend of the light's four grid nodes, `w` = (w00, w10, w01, w11), of table
// column `o` (rows `row0` and `row1` of the node grid, node stride `r`).
fn lp_tap(row0: u32, row1: u32, r: u32, o: u32, w: vec4<f32>) -> f32 {
    return w.x * load(row0 + o) + w.y * load(row0 + r + o) + w.z * load(row1 + o) + w.w * load(row1 + r + o);
}

// The value of slot `v` at texel `texel` for the light at square point `st`. Channels are
// written as whole vectors, never `acc[ch]` in a loop: lavapipe keeps a dynamically indexed
// vector variable in memory and scalarises every access to it.
fn lp_slot(texel: u32, v: u32, st: vec2<f32>) -> vec3<f32> {
    let n = mp.resolution;
    let d = f32(n - 1u);
    let x = clamp(st * d, vec2<f32>(0.0), vec2<f32>(d));
    let i = min(vec2<u32>(floor(x)), vec2<u32>(n - 2u));
    let f = x - vec2<f32>(i);
    let r = mp.stride;
    let row0 = mp.table + (v * n * n + i.y * n + i.x) * r;
    let row1 = row0 + n * r;
    let w = vec4<f32>((1.0 - f.x) * (1.0 - f.y), f.x * (1.0 - f.y), (1.0 - f.x) * f.y, f.x * f.y);
    var acc = vec3<f32>(lp_tap(row0, row1, r, 0u, w), lp_tap(row0, row1, r, 1u, w), lp_tap(row0, row1, r, 2u, w));
    let k = mp.k_main + mp.k_chroma;
    let p0 = v * k;
    if (mp.colour == 0u) {
        for (var p = 0u; p < k; p++) {
            let c = lp_coeff(texel, p0 + p);
            let o = 3u + 3u * p;
            acc += c * vec3<f32>(lp_tap(row0, row1, r, o, w), lp_tap(row0, row1, r, o + 1u, w), lp_tap(row0, row1, r, o + 2u, w));
        }
        return acc;
    }
    var luma = acc.x;
    for (var p = 0u; p < mp.k_main; p++) {
        luma += lp_coeff(texel, p0 + p) * lp_tap(row0, row1, r, 3u + p, w);
    }
    var chroma = acc.yz;
    for (var p = 0u; p < mp.k_chroma; p++) {
        let c = lp_coeff(texel, p0 + mp.k_main + p);
        let o = 3u + mp.k_main + 2u * p;
        chroma += c * vec2<f32>(lp_tap(row0, row1, r, o, w), lp_tap(row0, row1, r, o + 1u, w));
    }
    return vec3<f32>(luma + chroma.y, luma - chroma.x - chroma.y, luma + chroma.x);
}

fn eval_model(texel: u32, vq: ViewQuery, l: vec3<f32>) -> vec3<f32> {
    let st = hemisphere_to_square(l);
    var out = vq.w.w0 * lp_slot(texel, vq.w.i0, st);
    if (vq.w.w1 > 0.0) {
        out += vq.w.w1 * lp_slot(texel, vq.w.i1, st);
    }
    if (vq.w.w2 > 0.0) {
        out += vq.w.w2 * lp_slot(texel, vq.w.i2, st);
    }
    return out;
}
