// ptm.wgsl: Polynomial Texture Maps per view slot (paper 000, section 3.1).
//
// Parameters: `mp`, the `PtmParams` struct of rust/btfrs-fit/src/ptm.rs (its fields and their meaning are
// written there once; the WGSL `struct Params` is generated from it).
// Between view slots the three nearest are blended (interp3); the light enters through the
// biquadratic basis (lu^2, lv^2, lu lv, lu, lv, 1) of its tangent-frame x and y. The coefficients
// are f32 words (`mp.bits` 32) or 8-bit planes (`mp.bits` 8: bytes four to a word, value
// `bias[p] + scale[p] * q` of plane `p` = flat index mod `mp.k`; see rust/btfrs-fit/src/planes.rs).

struct ViewQuery {
    w: Weights3,
};

fn view_query(v: vec3<f32>) -> ViewQuery {
    return ViewQuery(interp3(0u, mp.n_views, mp.view_table, v));
}

fn byte_at(base: u32, i: u32) -> f32 {
    return f32((load_u32(base + i / 4u) >> (8u * (i % 4u))) & 255u);
}

// Value `i` (flat, texel-major) of the coefficients, of plane `p` (= i mod mp.k, passed in: the
// caller knows it per slot, and an integer modulo per coefficient is scalarised on SIMD
// rasterisers such as lavapipe, where it cost a 512^2 frame several times its arithmetic).
fn coef(i: u32, p: u32) -> f32 {
    if (mp.bits == 32u) {
        return load(mp.coeffs + i);
    }
    return load(mp.scale + mp.k + p) + load(mp.scale + p) * byte_at(mp.coeffs, i);
}

// Base colour of flat slot index `slot` (LRGB), view slot `view` (its planes: view * 3 + c).
fn base_rgb(slot: u32, view: u32) -> vec3<f32> {
    if (mp.bits == 32u) {
        return load_dir(mp.rgb + slot * 3u);
    }
    let k = 3u * mp.n_views;
    var out = vec3<f32>(0.0);
    for (var c = 0u; c < 3u; c++) {
        let i = slot * 3u + c;
        let p = view * 3u + c;
        out[c] = load(mp.rgb_scale + k + p) + load(mp.rgb_scale + p) * byte_at(mp.rgb, i);
    }
    return out;
}

// Planes are per (view, coefficient) within a texel: plane of coefficient j of view v is
// v * (coefficients per slot) + j, the flat index mod mp.k.
fn ptm_slot(texel: u32, view: u32, l: vec3<f32>) -> vec3<f32> {
    let slot = texel * mp.n_views + view;
    let b0 = l.x * l.x;
    let b1 = l.y * l.y;
    let b2 = l.x * l.y;
    if (mp.kind == 0u) {
        let c = mp.coeffs + slot * 18u;
        let pc = view * 18u;
        var out = vec3<f32>(0.0);
        for (var ch = 0u; ch < 3u; ch++) {
            let a = c + ch * 6u;
            let p = pc + ch * 6u;
            out[ch] = coef(a, p) * b0 + coef(a + 1u, p + 1u) * b1 + coef(a + 2u, p + 2u) * b2
                + coef(a + 3u, p + 3u) * l.x + coef(a + 4u, p + 4u) * l.y + coef(a + 5u, p + 5u);
        }
        return out;
    }
    let a = mp.coeffs + slot * 6u;
    let p = view * 6u;
    let lum = coef(a, p) * b0 + coef(a + 1u, p + 1u) * b1 + coef(a + 2u, p + 2u) * b2 + coef(a + 3u, p + 3u) * l.x
        + coef(a + 4u, p + 4u) * l.y + coef(a + 5u, p + 5u);
    return lum * base_rgb(slot, view);
}

fn eval_model(texel: u32, vq: ViewQuery, l: vec3<f32>) -> vec3<f32> {
    var out = vq.w.w0 * ptm_slot(texel, vq.w.i0, l);
    if (vq.w.w1 > 0.0) {
        out += vq.w.w1 * ptm_slot(texel, vq.w.i1, l);
    }
    if (vq.w.w2 > 0.0) {
        out += vq.w.w2 * ptm_slot(texel, vq.w.i2, l);
    }
    return out;
}
