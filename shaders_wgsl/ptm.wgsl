// ptm.wgsl: Polynomial Texture Maps per view slot (paper 000, section 3.1).
//
// Parameters: `mp`, the `PtmParams` struct of rust/btfrs-fit/src/ptm.rs (its fields and their meaning are
// written there once; the WGSL `struct Params` is generated from it).
// Between view slots the three nearest are blended (interp3); the light enters through the
// biquadratic basis (lu^2, lv^2, lu lv, lu, lv, 1) of its tangent-frame x and y.

struct ViewQuery {
    w: Weights3,
};

fn view_query(v: vec3<f32>) -> ViewQuery {
    return ViewQuery(interp3(0u, mp.n_views, mp.view_table, v));
}

fn ptm_slot(slot: u32, l: vec3<f32>) -> vec3<f32> {
    let b0 = l.x * l.x;
    let b1 = l.y * l.y;
    let b2 = l.x * l.y;
    if (mp.kind == 0u) {
        let c = mp.coeffs + slot * 18u;
        var out = vec3<f32>(0.0);
        for (var ch = 0u; ch < 3u; ch++) {
            let a = c + ch * 6u;
            out[ch] = load(a) * b0 + load(a + 1u) * b1 + load(a + 2u) * b2 + load(a + 3u) * l.x + load(a + 4u) * l.y
                + load(a + 5u);
        }
        return out;
    }
    let a = mp.coeffs + slot * 6u;
    let lum = load(a) * b0 + load(a + 1u) * b1 + load(a + 2u) * b2 + load(a + 3u) * l.x + load(a + 4u) * l.y + load(a + 5u);
    return lum * load_dir(mp.rgb + slot * 3u);
}

fn eval_model(texel: u32, vq: ViewQuery, l: vec3<f32>) -> vec3<f32> {
    let base = texel * mp.n_views;
    var out = vq.w.w0 * ptm_slot(base + vq.w.i0, l);
    if (vq.w.w1 > 0.0) {
        out += vq.w.w1 * ptm_slot(base + vq.w.i1, l);
    }
    if (vq.w.w2 > 0.0) {
        out += vq.w.w2 * ptm_slot(base + vq.w.i2, l);
    }
    return out;
}
