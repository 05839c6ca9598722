// svbrdf.wgsl: per-texel microfacet SVBRDF (rust/btfrs-fit/src/svbrdf/lobe.rs has the math).
//
// value = rho_d (n.l) + rho_s pi D(n.h) G1(n.l) G1(n.v) / (4 n.v), GGX D and Smith G1, zero
// where light or view is below the shading normal's horizon (or the surface's).
// Parameters: `mp`, the `SvbrdfParams` struct of rust/btfrs-fit/src/svbrdf.rs. Per texel ten
// f32 words: diffuse rgb, specular rgb, roughness, normal xyz.

struct ViewQuery {
    v: vec3<f32>,
};

fn view_query(v: vec3<f32>) -> ViewQuery {
    return ViewQuery(v);
}

fn ggx_g1(c: f32, a2: f32) -> f32 {
    return 2.0 * c / (c + sqrt(a2 + (1.0 - a2) * c * c));
}

fn eval_model(texel: u32, vq: ViewQuery, l: vec3<f32>) -> vec3<f32> {
    let base = mp.texels + texel * 10u;
    let n = load_dir(base + 7u);
    let nl = dot(n, l);
    let nv = dot(n, vq.v);
    if (nl <= 0.0 || nv <= 0.0 || l.z <= 0.0 || vq.v.z <= 0.0) {
        return vec3<f32>(0.0);
    }
    let hs = vq.v + l;
    let hn = length(hs);
    var nh = 0.0;
    if (hn > 0.0) {
        nh = dot(n, hs) / hn;
    }
    var spec = 0.0;
    if (nh > 0.0) {
        let alpha = load(base + 6u);
        let a2 = alpha * alpha;
        let t = nh * nh * (a2 - 1.0) + 1.0;
        // pi D = a2 / t^2
        spec = a2 / (t * t) * ggx_g1(nl, a2) * ggx_g1(nv, a2) / (4.0 * nv);
    }
    return load_dir(base) * nl + load_dir(base + 3u) * spec;
}
