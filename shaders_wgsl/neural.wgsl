// neural.wgsl: the neural model (rust/btfrs-fit/src/neural.rs): per texel 8-bit latent codes with
// a scale and a bias per plane, and one decoder MLP, (latents, direction encoding) -> hidden ->
// hidden -> RGB, evaluated per fragment and light.
//
// Parameters: `mp`, the `NeuralParams` struct of neural.rs. The decoder's parameters are one
// f32 array in the store (w1 [hidden][inputs], b1, w2 [hidden][hidden], b2, w3 [3][hidden], b3,
// matrices row-major [out][in]: decoder.rs's layout), then the learned direction tables: per
// direction (view, light, half vector; as many as the encoding has) `grid x grid` nodes of
// `features` channels over the concentric square, looked up bilinearly (decoder.rs, `taps`). The
// second and output layers are fused: each second-layer unit is added into the output as soon as
// it is computed, so only the first layer's activations are kept in a private array.

struct ViewQuery {
    v: vec3<f32>,
};

fn view_query(v: vec3<f32>) -> ViewQuery {
    return ViewQuery(v);
}

fn nn_act(x: f32) -> f32 {
    if (mp.activation == 0u) {
        return select(exp(x) - 1.0, x, x > 0.0);
    }
    return max(x, 0.0);
}

// Add table `t`'s features at direction `d` to the inputs from `first` (decoder.rs, `taps`:
// node (i, j) at square point (i, j) / (grid - 1), index j * grid + i).
fn nn_table(inp: ptr<function, array<f32, 88>>, first: u32, tables: u32, t: u32, d: vec3<f32>) {
    let g = mp.grid;
    let c = mp.features;
    let m = f32(g - 1u);
    let x = clamp(hemisphere_to_square(d) * m, vec2<f32>(0.0), vec2<f32>(m));
    let i = min(vec2<u32>(floor(x)), vec2<u32>(g - 2u));
    let f = x - vec2<f32>(i);
    let n0 = tables + (t * g * g + i.y * g + i.x) * c;
    let n2 = n0 + g * c;
    let w = vec4<f32>((1.0 - f.x) * (1.0 - f.y), f.x * (1.0 - f.y), (1.0 - f.x) * f.y, f.x * f.y);
    for (var ch = 0u; ch < c; ch++) {
        (*inp)[first + ch] = w.x * load(n0 + ch) + w.y * load(n0 + c + ch) + w.z * load(n2 + ch) + w.w * load(n2 + c + ch);
    }
}

fn eval_model(texel: u32, vq: ViewQuery, l: vec3<f32>) -> vec3<f32> {
    let k = mp.latents;
    let h = mp.hidden;
    // The inputs: decoded latents, then the direction encoding (decoder.rs, Directions::encode),
    // then the table features: at most 32 latents, 6 coordinates and 3 x 16 features.
    var inp: array<f32, 88>;
    for (var i = 0u; i < k; i++) {
        let j = texel * k + i;
        let q = (load_u32(mp.q + j / 4u) >> ((j & 3u) * 8u)) & 0xffu;
        inp[i] = load(mp.scale + k + i) + load(mp.scale + i) * f32(q);
    }
    var n = k + 2u;
    if (mp.directions == 0u) {
        inp[k] = l.x;
        inp[k + 1u] = l.y;
    } else {
        let v = vq.v;
        inp[k] = v.x;
        inp[k + 1u] = v.y;
        inp[k + 2u] = l.x;
        inp[k + 3u] = l.y;
        n = k + 4u;
        if (mp.directions == 2u) {
            let hv = v + l;
            let len = length(hv);
            var hn = vec2<f32>(0.0);
            if (len > 1e-9) {
                hn = hv.xy / len;
            }
            inp[k + 4u] = hn.x;
            inp[k + 5u] = hn.y;
            n = k + 6u;
        }
    }
    // The direction tables' features, after the coordinates.
    let c = mp.features;
    var nt = 0u;
    if (c > 0u) {
        nt = select(select(3u, 2u, mp.directions == 1u), 1u, mp.directions == 0u);
    }
    let ni = n + nt * c;
    let tables = mp.weights + h * ni + h + h * h + h + 3u * h + 3u;
    if (nt == 1u) {
        nn_table(&inp, n, tables, 0u, l);
    } else if (nt >= 2u) {
        let v = vq.v;
        nn_table(&inp, n, tables, 0u, v);
        nn_table(&inp, n + c, tables, 1u, l);
        if (nt == 3u) {
            let hv = v + l;
            var hd = vec3<f32>(0.0, 0.0, 1.0);
            if (length(hv) > 1e-9) {
                hd = normalize(hv);
            }
            nn_table(&inp, n + 2u * c, tables, 2u, hd);
        }
    }
    n = ni;
    let w1 = mp.weights;
    let b1 = w1 + h * n;
    let w2 = b1 + h;
    let b2 = w2 + h * h;
    let w3 = b2 + h;
    let b3 = w3 + 3u * h;
    var h1: array<f32, 64>;
    for (var j = 0u; j < h; j++) {
        var s = load(b1 + j);
        let row = w1 + j * n;
        for (var i = 0u; i < n; i++) {
            s += load(row + i) * inp[i];
        }
        h1[j] = nn_act(s);
    }
    var out = vec3<f32>(load(b3), load(b3 + 1u), load(b3 + 2u));
    for (var j = 0u; j < h; j++) {
        var s = load(b2 + j);
        let row = w2 + j * h;
        for (var i = 0u; i < h; i++) {
            s += load(row + i) * h1[i];
        }
        out += nn_act(s) * vec3<f32>(load(w3 + j), load(w3 + h + j), load(w3 + 2u * h + j));
    }
    // The BTF encodings' output is a reflectance times the light's cosine (Directions::gain).
    if (mp.directions != 0u) {
        out *= max(l.z, 0.0);
    }
    return out;
}
