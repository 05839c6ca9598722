// lpca_9tap.wgsl: Local-PCA BTF, the original renderer (paper 004, section 5).
//
// A texel stores its cluster k and folded weights [offset, w_0 .. w_c] (section 6.3: the 8-bit
// scales of the Eigen-BRDFs are folded into the weights, their biases into the offset); its value
// at a measured pair (v, l) is offset + sum_j w_j * E_kj(v, l), E read as 8-bit RGB (one u32 word
// per pair: R, G, B, pad; unpack4x8unorm gives q / 255). Between measured directions, the three
// nearest views times the three nearest lights are blended (nine weighted lookups per
// Eigen-BRDF), as the raw shader does.
//
// Parameters: `mp`, the `Lpca9Params` struct of rust/btfrs-fit/src/lpca.rs (its fields and their meaning are
// written there once; the WGSL `struct Params` is generated from it).

struct ViewQuery {
    w: Weights3,
};

fn view_query(v: vec3<f32>) -> ViewQuery {
    return ViewQuery(interp3(0u, mp.n_views, mp.view_table, v));
}

// The light-interpolated value of Eigen-BRDF `e` (= k * (c + 1) + j) at measured view `view`.
fn eigen_view(e: u32, view: u32, lw: Weights3) -> vec3<f32> {
    let row = mp.basis + (e * mp.n_views + view) * mp.n_lights;
    var out = lw.w0 * unpack4x8unorm(load_u32(row + lw.i0)).xyz;
    if (lw.w1 > 0.0) {
        out += lw.w1 * unpack4x8unorm(load_u32(row + lw.i1)).xyz;
    }
    if (lw.w2 > 0.0) {
        out += lw.w2 * unpack4x8unorm(load_u32(row + lw.i2)).xyz;
    }
    return out;
}

fn eval_model(texel: u32, vq: ViewQuery, l: vec3<f32>) -> vec3<f32> {
    let lw = cos_correct(interp3(mp.n_views, mp.n_lights, mp.light_table, l), mp.n_views, l);
    let c = mp.components;
    let k = load_u16(mp.ids, texel);
    let wt = mp.weights + texel * (c + 2u);
    // The constant term blends with the (cos-corrected, no longer unit-sum) light weights too.
    var out = vec3<f32>(load(wt) * (lw.w0 + lw.w1 + lw.w2));
    for (var j = 0u; j <= c; j++) {
        let e = k * (c + 1u) + j;
        var s = vq.w.w0 * eigen_view(e, vq.w.i0, lw);
        if (vq.w.w1 > 0.0) {
            s += vq.w.w1 * eigen_view(e, vq.w.i1, lw);
        }
        if (vq.w.w2 > 0.0) {
            s += vq.w.w2 * eigen_view(e, vq.w.i2, lw);
        }
        out += load(wt + 1u + j) * s;
    }
    return out;
}
