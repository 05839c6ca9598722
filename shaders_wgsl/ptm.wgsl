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
// Per invocation, the texel's view-blended coefficients of the six basis terms (RGB, or for
// LRGB the luminance coefficients times each slot's base colour: sum_s w_s L_sk rgb_s), computed
// at the first light and kept for the others (shade_lights loops every light at one texel with
// one view query): N lights read and dequantize the 3 slots' coefficients once, not N times.
var<private> c_texel: u32 = 0xffffffffu;
var<private> c0: vec3<f32>;
var<private> c1: vec3<f32>;
var<private> c2: vec3<f32>;
var<private> c3: vec3<f32>;
var<private> c4: vec3<f32>;
var<private> c5: vec3<f32>;

fn add_slot(texel: u32, view: u32, wt: f32) {
    let slot = texel * mp.n_views + view;
    if (mp.kind == 0u) {
        let c = mp.coeffs + slot * 18u;
        let pc = view * 18u;
        for (var ch = 0u; ch < 3u; ch++) {
            let a = c + ch * 6u;
            let p = pc + ch * 6u;
            c0[ch] += wt * coef(a, p);
            c1[ch] += wt * coef(a + 1u, p + 1u);
            c2[ch] += wt * coef(a + 2u, p + 2u);
            c3[ch] += wt * coef(a + 3u, p + 3u);
            c4[ch] += wt * coef(a + 4u, p + 4u);
            c5[ch] += wt * coef(a + 5u, p + 5u);
        }
        return;
    }
    let a = mp.coeffs + slot * 6u;
    let p = view * 6u;
    let rgb = wt * base_rgb(slot, view);
    c0 += coef(a, p) * rgb;
    c1 += coef(a + 1u, p + 1u) * rgb;
    c2 += coef(a + 2u, p + 2u) * rgb;
    c3 += coef(a + 3u, p + 3u) * rgb;
    c4 += coef(a + 4u, p + 4u) * rgb;
    c5 += coef(a + 5u, p + 5u) * rgb;
}

fn eval_model(texel: u32, vq: ViewQuery, l: vec3<f32>) -> vec3<f32> {
    if (texel != c_texel) {
        c0 = vec3<f32>(0.0);
        c1 = vec3<f32>(0.0);
        c2 = vec3<f32>(0.0);
        c3 = vec3<f32>(0.0);
        c4 = vec3<f32>(0.0);
        c5 = vec3<f32>(0.0);
        add_slot(texel, vq.w.i0, vq.w.w0);
        if (vq.w.w1 > 0.0) {
            add_slot(texel, vq.w.i1, vq.w.w1);
        }
        if (vq.w.w2 > 0.0) {
            add_slot(texel, vq.w.i2, vq.w.w2);
        }
        c_texel = texel;
    }
    return c0 * (l.x * l.x) + c1 * (l.y * l.y) + c2 * (l.x * l.y) + c3 * l.x + c4 * l.y + c5;
}
