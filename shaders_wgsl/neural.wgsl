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

// A decoder parameter. The decoder is the store's first part (neural.rs), so it lies in the first
// storage binding: read directly, without `load`'s chunk lookup (a division and a switch per
// weight, which dominated the frame).
fn nw(i: u32) -> f32 {
    return bitcast<f32>(s0[i]);
}

struct ViewQuery {
    v: vec3<f32>,
};

fn view_query(v: vec3<f32>) -> ViewQuery {
    return ViewQuery(v);
}

fn nn_act4(x: vec4<f32>) -> vec4<f32> {
    if (mp.activation == 0u) {
        return select(exp(x) - vec4<f32>(1.0), x, x > vec4<f32>(0.0));
    }
    return max(x, vec4<f32>(0.0));
}

// Four consecutive decoder parameters from `i`.
fn nw4(i: u32) -> vec4<f32> {
    return vec4<f32>(nw(i), nw(i + 1u), nw(i + 2u), nw(i + 3u));
}

// Table `t`'s features at direction `d`, written into the inputs from `first` (decoder.rs,
// `taps`: node (i, j) at square point (i, j) / (grid - 1), index j * grid + i).
fn nn_table(inp: ptr<function, array<vec4<f32>, 22>>, first: u32, tables: u32, t: u32, d: vec3<f32>) {
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
        let k = first + ch;
        (*inp)[k / 4u][k % 4u] = w.x * nw(n0 + ch) + w.y * nw(n0 + c + ch) + w.z * nw(n2 + ch) + w.w * nw(n2 + c + ch);
    }
}

// The inputs are kept as vectors of four (zero beyond the last) and every layer computes four
// units at a time: one read of the private arrays per four products instead of one per product
// (lavapipe keeps dynamically indexed arrays in memory). The weight matrices' rows are read
// four values at a time from their start; a row's last vector may run into the next row, whose
// values meet zero inputs. The hidden width is a multiple of 4 (neural.rs checks).
fn eval_model(texel: u32, vq: ViewQuery, l: vec3<f32>) -> vec3<f32> {
    let k = mp.latents;
    let h = mp.hidden;
    // The inputs: decoded latents, then the direction encoding (decoder.rs, Directions::encode),
    // then the table features: at most 32 latents, 6 coordinates and 3 x 16 features.
    var inp: array<vec4<f32>, 22>;
    for (var i = 0u; i < k; i++) {
        let j = texel * k + i;
        let q = (load_u32(mp.q + j / 4u) >> ((j & 3u) * 8u)) & 0xffu;
        inp[i / 4u][i % 4u] = load(mp.scale + k + i) + load(mp.scale + i) * f32(q);
    }
    var coords = array<f32, 6>(l.x, l.y, 0.0, 0.0, 0.0, 0.0);
    var n = k + 2u;
    if (mp.directions != 0u) {
        let v = vq.v;
        coords = array<f32, 6>(v.x, v.y, l.x, l.y, 0.0, 0.0);
        n = k + 4u;
        if (mp.directions == 2u) {
            let hv = v + l;
            let len = length(hv);
            var hn = vec2<f32>(0.0);
            if (len > 1e-9) {
                hn = hv.xy / len;
            }
            coords[4] = hn.x;
            coords[5] = hn.y;
            n = k + 6u;
        }
    }
    for (var i = k; i < n; i++) {
        inp[i / 4u][i % 4u] = coords[i - k];
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
    let n4 = (n + 3u) / 4u;
    let h4 = h / 4u;
    var h1: array<vec4<f32>, 16>;
    for (var j = 0u; j < h4; j++) {
        let r = w1 + 4u * j * n;
        var acc = nw4(b1 + 4u * j);
        for (var i = 0u; i < n4; i++) {
            let x = inp[i];
            let o = 4u * i;
            acc += vec4<f32>(dot(nw4(r + o), x), dot(nw4(r + n + o), x), dot(nw4(r + 2u * n + o), x), dot(nw4(r + 3u * n + o), x));
        }
        h1[j] = nn_act4(acc);
    }
    var out = vec3<f32>(nw(b3), nw(b3 + 1u), nw(b3 + 2u));
    for (var j = 0u; j < h4; j++) {
        let r = w2 + 4u * j * h;
        var acc = nw4(b2 + 4u * j);
        for (var i = 0u; i < h4; i++) {
            let x = h1[i];
            let o = 4u * i;
            acc += vec4<f32>(dot(nw4(r + o), x), dot(nw4(r + h + o), x), dot(nw4(r + 2u * h + o), x), dot(nw4(r + 3u * h + o), x));
        }
        let a = nn_act4(acc);
        out += vec3<f32>(dot(a, nw4(w3 + 4u * j)), dot(a, nw4(w3 + h + 4u * j)), dot(a, nw4(w3 + 2u * h + 4u * j)));
    }
    // The BTF encodings' output is a reflectance times the light's cosine (Directions::gain).
    if (mp.directions != 0u) {
        out *= max(l.z, 0.0);
    }
    return out;
}
