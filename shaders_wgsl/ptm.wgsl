// ptm.wgsl: Polynomial Texture Maps per view slot (paper 000, section 3.1).
//
// Parameters: word 0 = kind (0 RGB, 1 LRGB), 1 = number of view slots V (their directions are
// mdirs[0 .. V]), 2 = their candidate table in `tables`, 3 = store offset of the coefficients (RGB [texel][V][3][6], LRGB
// [texel][V][6]), 4 = store offset of the LRGB base colours ([texel][V][3]).
// Between view slots the three nearest are blended (interp3); the light enters through the
// biquadratic basis (lu^2, lv^2, lu lv, lu, lv, 1) of its tangent-frame x and y.

struct ViewQuery {
    w: Weights3,
};

fn view_query(v: vec3<f32>) -> ViewQuery {
    return ViewQuery(interp3(0u, param(1u), param(2u), v));
}

fn ptm_slot(slot: u32, l: vec3<f32>) -> vec3<f32> {
    let b0 = l.x * l.x;
    let b1 = l.y * l.y;
    let b2 = l.x * l.y;
    if (param(0u) == 0u) {
        let c = param(3u) + slot * 18u;
        var out = vec3<f32>(0.0);
        for (var ch = 0u; ch < 3u; ch++) {
            let a = c + ch * 6u;
            out[ch] = load(a) * b0 + load(a + 1u) * b1 + load(a + 2u) * b2 + load(a + 3u) * l.x + load(a + 4u) * l.y
                + load(a + 5u);
        }
        return out;
    }
    let a = param(3u) + slot * 6u;
    let lum = load(a) * b0 + load(a + 1u) * b1 + load(a + 2u) * b2 + load(a + 3u) * l.x + load(a + 4u) * l.y + load(a + 5u);
    return lum * load_dir(param(4u) + slot * 3u);
}

fn eval_model(texel: u32, vq: ViewQuery, l: vec3<f32>) -> vec3<f32> {
    let base = texel * param(1u);
    var out = vq.w.w0 * ptm_slot(base + vq.w.i0, l);
    if (vq.w.w1 > 0.0) {
        out += vq.w.w1 * ptm_slot(base + vq.w.i1, l);
    }
    if (vq.w.w2 > 0.0) {
        out += vq.w.w2 * ptm_slot(base + vq.w.i2, l);
    }
    return out;
}
