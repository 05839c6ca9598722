// raw.wgsl: the measured BTF itself, interpolated between measured directions (the quality
// reference every model is judged against).
//
// Parameters: `mp`, the `RawParams` struct of rust/btfrs-fit/src/model.rs (its fields and their meaning are
// written there once; the WGSL `struct Params` is generated from it). The value is the
// weighted sum over the three nearest views times the three nearest lights (nine samples).

struct ViewQuery {
    w: Weights3,
};

fn view_query(v: vec3<f32>) -> ViewQuery {
    return ViewQuery(interp3(0u, mp.n_views, mp.view_table, v));
}

fn raw_view(texel: u32, view: u32, lw: Weights3) -> vec3<f32> {
    let nl = mp.n_lights;
    let row = mp.data + (texel * mp.n_views + view) * nl * 3u;
    var out = lw.w0 * load_dir(row + lw.i0 * 3u);
    if (lw.w1 > 0.0) {
        out += lw.w1 * load_dir(row + lw.i1 * 3u);
    }
    if (lw.w2 > 0.0) {
        out += lw.w2 * load_dir(row + lw.i2 * 3u);
    }
    return out;
}

fn eval_model(texel: u32, vq: ViewQuery, l: vec3<f32>) -> vec3<f32> {
    let lw = cos_correct(interp3(mp.n_views, mp.n_lights, mp.light_table, l), mp.n_views, l);
    var out = vq.w.w0 * raw_view(texel, vq.w.i0, lw);
    if (vq.w.w1 > 0.0) {
        out += vq.w.w1 * raw_view(texel, vq.w.i1, lw);
    }
    if (vq.w.w2 > 0.0) {
        out += vq.w.w2 * raw_view(texel, vq.w.i2, lw);
    }
    return out;
}
