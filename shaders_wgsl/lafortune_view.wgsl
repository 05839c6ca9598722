// lafortune_view.wgsl: Lafortune lobes per texel and view slot (paper 000, section 3.2, fitted
// "like the PTM"), blended between view slots as ptm.wgsl does.
//
// Within a slot, rho(l) = kd + sum_i max(Dx_i lx + Dy_i ly + Dz_i lz, 0)^n_i, where D = C * v is
// the lobe axis in light space for the slot's view v (stored so, a slot is a function of the light
// alone); the BTF value is l.z * rho (measured values include the cos(theta_l) foreshortening).
// Between view slots the three nearest are blended (interp3).
// Parameters: `mp`, the `LafortuneViewParams` struct of rust/btfrs-fit/src/lafortune/per_view.rs
// (its fields and their meaning are written there once; the WGSL `struct Params` is generated
// from it).

struct ViewQuery {
    w: Weights3,
};

fn view_query(v: vec3<f32>) -> ViewQuery {
    return ViewQuery(interp3(0u, mp.n_views, mp.view_table, v));
}

fn lafortune_view_rho(a: u32, l: vec3<f32>) -> f32 {
    var rho = load(a);
    for (var i = 0u; i < mp.lobes; i++) {
        let b = a + 1u + 4u * i;
        let s = load(b) * l.x + load(b + 1u) * l.y + load(b + 2u) * l.z;
        if (s > 0.0) {
            rho += pow(s, load(b + 3u));
        }
    }
    return rho;
}

// One slot's value without the foreshortening; `slot` is texel * V + view slot.
fn lafortune_view_slot(slot: u32, l: vec3<f32>) -> vec3<f32> {
    let np = 1u + 4u * mp.lobes;
    if (mp.kind == 0u) {
        let a = mp.params + slot * 3u * np;
        return vec3<f32>(lafortune_view_rho(a, l), lafortune_view_rho(a + np, l), lafortune_view_rho(a + 2u * np, l));
    }
    return lafortune_view_rho(mp.params + slot * np, l) * load_dir(mp.rgb + slot * 3u);
}

fn eval_model(texel: u32, vq: ViewQuery, l: vec3<f32>) -> vec3<f32> {
    let base = texel * mp.n_views;
    var out = vq.w.w0 * lafortune_view_slot(base + vq.w.i0, l);
    if (vq.w.w1 > 0.0) {
        out += vq.w.w1 * lafortune_view_slot(base + vq.w.i1, l);
    }
    if (vq.w.w2 > 0.0) {
        out += vq.w.w2 * lafortune_view_slot(base + vq.w.i2, l);
    }
    return l.z * out;
}
