// hsh.wgsl: hemispherical harmonics per view slot (Gautron et al. 2004, the basis of .rti HSH
// files; the functions and their signs are written out in rust/btfrs-fit/src/hsh.rs).
//
// Parameters: `mp`, the `HshParams` struct of rust/btfrs-fit/src/hsh.rs. Between view slots the
// three nearest are blended (interp3). Coefficients `[texel][V][3][n^2]` are f32 words
// (`mp.bits` 32) or 8-bit planes (`mp.bits` 8: bytes four to a word, value `bias[p] + scale[p] * q`
// of plane `p` = flat index mod `mp.k`; see rust/btfrs-fit/src/planes.rs).

struct ViewQuery {
    w: Weights3,
};

fn view_query(v: vec3<f32>) -> ViewQuery {
    return ViewQuery(interp3(0u, mp.n_views, mp.view_table, v));
}

// Value `i` (flat) of plane `p` (= i mod mp.k, passed in: the caller knows it per slot, and an
// integer modulo per coefficient is scalarised on SIMD rasterisers such as lavapipe).
fn coef(i: u32, p: u32) -> f32 {
    if (mp.bits == 32u) {
        return load(mp.coeffs + i);
    }
    let q = f32((load_u32(mp.coeffs + i / 4u) >> (8u * (i % 4u))) & 255u);
    return load(mp.scale + mp.k + p) + load(mp.scale + p) * q;
}

const HSH_PI: f32 = 3.14159265358979;

fn hsh_basis(l: vec3<f32>) -> array<f32, 16> {
    var b: array<f32, 16>;
    let x = clamp(l.z, 0.0, 1.0);
    let phi = atan2(l.y, l.x);
    let s = sqrt(max(x - x * x, 0.0));
    let y = 2.0 * x - 1.0;
    let c1 = cos(phi);
    let s1 = sin(phi);
    b[0] = 1.0 / sqrt(2.0 * HSH_PI);
    let a = sqrt(6.0 / HSH_PI) * s;
    b[1] = a * c1;
    b[2] = sqrt(3.0 / (2.0 * HSH_PI)) * y;
    b[3] = a * s1;
    let c2 = cos(2.0 * phi);
    let s2 = sin(2.0 * phi);
    let k30 = sqrt(30.0 / HSH_PI);
    b[4] = k30 * c2 * (x * x - x);
    b[5] = k30 * c1 * y * s;
    b[6] = sqrt(5.0 / (2.0 * HSH_PI)) * (6.0 * x * x - 6.0 * x + 1.0);
    b[7] = k30 * s1 * y * s;
    b[8] = k30 * s2 * (x * x - x);
    let c3 = cos(3.0 * phi);
    let s3 = sin(3.0 * phi);
    let k35 = 2.0 * sqrt(35.0 / HSH_PI) * s * s * s;
    let k210 = sqrt(210.0 / HSH_PI) * y * (x * x - x);
    let k21 = 2.0 * sqrt(21.0 / HSH_PI) * s * (5.0 * x * x - 5.0 * x + 1.0);
    b[9] = k35 * c3;
    b[10] = k210 * c2;
    b[11] = k21 * c1;
    b[12] = sqrt(7.0 / (2.0 * HSH_PI)) * (20.0 * x * x * x - 30.0 * x * x + 12.0 * x - 1.0);
    b[13] = k21 * s1;
    b[14] = k210 * s2;
    b[15] = k35 * s3;
    return b;
}

// Per invocation, the texel's view-blended coefficients (sum over the three slots of w_s times
// the dequantized coefficients), computed at the first light and kept for the others
// (shade_lights loops every light at one texel with one view query): N lights read the slots'
// coefficients once, not N times.
var<private> c_texel: u32 = 0xffffffffu;
var<private> blended: array<vec3<f32>, 16>;

fn add_slot(texel: u32, view: u32, wt: f32) {
    let n2 = mp.order * mp.order;
    let slot = texel * mp.n_views + view;
    let base = slot * 3u * n2;
    // Planes are per (view, channel, coefficient): flat index mod k = view * 3 n^2 + ...
    let pb = view * 3u * n2;
    for (var j = 0u; j < n2; j++) {
        var c = blended[j];
        for (var ch = 0u; ch < 3u; ch++) {
            c[ch] += wt * coef(base + ch * n2 + j, pb + ch * n2 + j);
        }
        blended[j] = c;
    }
}

fn eval_model(texel: u32, vq: ViewQuery, l: vec3<f32>) -> vec3<f32> {
    let n2 = mp.order * mp.order;
    if (texel != c_texel) {
        for (var j = 0u; j < n2; j++) {
            blended[j] = vec3<f32>(0.0);
        }
        add_slot(texel, vq.w.i0, vq.w.w0);
        if (vq.w.w1 > 0.0) {
            add_slot(texel, vq.w.i1, vq.w.w1);
        }
        if (vq.w.w2 > 0.0) {
            add_slot(texel, vq.w.i2, vq.w.w2);
        }
        c_texel = texel;
    }
    let b = hsh_basis(l);
    var out = vec3<f32>(0.0);
    for (var j = 0u; j < n2; j++) {
        out += blended[j] * b[j];
    }
    return out;
}
