// lpca_3d.wgsl: Local-PCA BTF, the revised renderer (paper 004, section 6).
//
// Every Eigen-BRDF E_kj(s_v, t_v, s_l, t_l) is resampled on an N x N x N x N grid of the
// elevated concentric map (sample i of an axis at (i + 0.5) / N) and stored in one RGBA8 3D
// texture `vol`: Eigen-BRDF e = k * (c + 1) + j occupies the tile (e % gx, e / gx) of the xy
// plane (x = s_v, y = t_v), and z = t_l index * N + s_l (the t_l slices stacked, section 6.2).
// The sampler filters s_v, t_v and s_l trilinearly; t_l is interpolated here: two fetches and
// one lerp per Eigen-BRDF. Coordinates are clamped to the sample centres of their tile and
// slice, so neighbouring tiles and slices never bleed in. Alpha holds the sum S of the light
// weights with the cosine divided out (S = 0.5 + a, texture3d.rs): the value is scaled by it.
//
// Parameters: `mp`, the `Lpca3dParams` struct of rust/btfrs-fit/src/lpca/texture3d.rs (its fields and their meaning are
// written there once; the WGSL `struct Params` is generated from it).

struct ViewQuery {
    xy: vec2<f32>,    // (s_v, t_v) in texel units within a tile
};

fn grid_coord(x: f32, n: f32) -> f32 {
    return clamp(x * n, 0.5, n - 0.5);
}

fn view_query(v: vec3<f32>) -> ViewQuery {
    let n = f32(mp.grid);
    let st = hemisphere_to_square(v);
    return ViewQuery(vec2<f32>(grid_coord(st.x, n), grid_coord(st.y, n)));
}

fn eval_model(texel: u32, vq: ViewQuery, l: vec3<f32>) -> vec3<f32> {
    let n = mp.grid;
    let nf = f32(n);
    let gx = mp.gx;
    let size = vec3<f32>(f32(n * gx), f32(n * mp.gy), nf * nf);
    let st = hemisphere_to_square(l);
    let zs = grid_coord(st.x, nf);
    let ft = clamp(st.y * nf - 0.5, 0.0, nf - 1.0);
    let i0 = min(u32(ft), n - 1u);
    let i1 = min(i0 + 1u, n - 1u);
    let w = ft - f32(i0);
    let z0 = (f32(i0) * nf + zs) / size.z;
    let z1 = (f32(i1) * nf + zs) / size.z;
    let c = mp.components;
    let k = load_u16(mp.ids, texel);
    let wt = mp.weights + texel * (c + 2u);
    var out = vec3<f32>(load(wt));
    // The tile of Eigen-BRDF e = k (c + 1) + j, stepped along the row instead of e % gx and
    // e / gx per Eigen-BRDF: lavapipe scalarises an integer division by a non-constant.
    let e0 = k * (c + 1u);
    var tx = e0 % gx;
    var ty = e0 / gx;
    var s = 1.0;
    for (var j = 0u; j <= c; j++) {
        let tile = vec2<f32>(f32(tx), f32(ty)) * nf;
        tx += 1u;
        if (tx == gx) {
            tx = 0u;
            ty += 1u;
        }
        let uv = (tile + vq.xy) / size.xy;
        let a = textureSampleLevel(vol, vol_sampler, vec3<f32>(uv, z0), 0.0);
        let b = textureSampleLevel(vol, vol_sampler, vec3<f32>(uv, z1), 0.0);
        out += load(wt + 1u + j) * mix(a.xyz, b.xyz, w);
        if (j == 0u) {
            s = 0.5 + mix(a.w, b.w, w);
        }
    }
    return out * s;
}
