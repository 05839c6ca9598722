// raw.wgsl: the measured BTF itself, interpolated between measured directions (the quality
// reference every model is judged against).
//
// Parameters: word 0 = number of views V (directions mdirs[0 .. V]), 1 = number of lights L
// (directions mdirs[V .. V + L]), 2 and 3 = the candidate tables of the views and the lights in
// `tables`, 4 = store offset of the data ([texel][V][L][3], the Btf's own
// texel-major layout). The value is the weighted sum over the three nearest views times the
// three nearest lights (nine samples).

struct ViewQuery {
    w: Weights3,
};

fn view_query(v: vec3<f32>) -> ViewQuery {
    return ViewQuery(interp3(0u, param(0u), param(2u), v));
}

fn raw_view(texel: u32, view: u32, lw: Weights3) -> vec3<f32> {
    let nl = param(1u);
    let row = param(4u) + (texel * param(0u) + view) * nl * 3u;
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
    let lw = interp3(param(0u), param(1u), param(3u), l);
    var out = vq.w.w0 * raw_view(texel, vq.w.i0, lw);
    if (vq.w.w1 > 0.0) {
        out += vq.w.w1 * raw_view(texel, vq.w.i1, lw);
    }
    if (vq.w.w2 > 0.0) {
        out += vq.w.w2 * raw_view(texel, vq.w.i2, lw);
    }
    return out;
}
