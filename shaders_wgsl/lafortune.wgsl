// lafortune.wgsl: per-texel Lafortune lobes (paper 000, section 3.2), fitted over all views.
//
// rho(v, l) = kd + sum_i max(Cx_i lx vx + Cy_i ly vy + Cz_i lz vz, 0)^n_i, and the BTF value is
// l.z * rho (measured values include the cos(theta_l) foreshortening).
// Parameters: `mp`, the `LafortuneParams` struct of rust/btfrs-fit/src/lafortune.rs (its fields and their meaning are
// written there once; the WGSL `struct Params` is generated from it).

struct ViewQuery {
    v: vec3<f32>,
};

fn view_query(v: vec3<f32>) -> ViewQuery {
    return ViewQuery(v);
}

fn lafortune_rho(a: u32, p: vec3<f32>) -> f32 {
    var rho = load(a);
    for (var i = 0u; i < mp.lobes; i++) {
        let b = a + 1u + 4u * i;
        let s = load(b) * p.x + load(b + 1u) * p.y + load(b + 2u) * p.z;
        if (s > 0.0) {
            rho += pow(s, load(b + 3u));
        }
    }
    return rho;
}

fn eval_model(texel: u32, vq: ViewQuery, l: vec3<f32>) -> vec3<f32> {
    let p = vq.v * l;
    let np = 1u + 4u * mp.lobes;
    if (mp.kind == 0u) {
        let a = mp.params + texel * 3u * np;
        return l.z * vec3<f32>(lafortune_rho(a, p), lafortune_rho(a + np, p), lafortune_rho(a + 2u * np, p));
    }
    return l.z * lafortune_rho(mp.params + texel * np, p) * load_dir(mp.rgb + texel * 3u);
}
