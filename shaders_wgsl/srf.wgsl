// srf.wgsl: Phong + spatially-varying residual function (paper 003, sections 4 and 5).
//
// value = kd * l.z + ks * max(h.z, 0)^n + (s_r . h, s_g . h, s_b . h), h the halfway vector.
// Parameters: `mp`, the `SrfParams` struct of rust/btfrs-fit/src/srf.rs (its fields and their meaning are
// written there once; the WGSL `struct Params` is generated from it). The cos(theta_l) of
// N . L is the one measured BTF values include, so the sum is the BTF value itself.

struct ViewQuery {
    v: vec3<f32>,
};

fn view_query(v: vec3<f32>) -> ViewQuery {
    return ViewQuery(v);
}

fn eval_model(texel: u32, vq: ViewQuery, l: vec3<f32>) -> vec3<f32> {
    let hs = vq.v + l;
    let hn = length(hs);
    var h = vec3<f32>(0.0, 0.0, 1.0);
    if (hn > 1e-12) {
        h = hs / hn;
    }
    let m = mp.material;
    var spec = 0.0;
    if (h.z > 0.0) {
        spec = pow(h.z, load(m + 6u));
    }
    let phong = load_dir(m) * l.z + load_dir(m + 3u) * spec;
    let s = mp.s + texel * 9u;
    return phong + vec3<f32>(dot(load_dir(s), h), dot(load_dir(s + 3u), h), dot(load_dir(s + 6u), h));
}
