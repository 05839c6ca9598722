// neural.wgsl: the neural model (rust/btfrs-fit/src/neural.rs): per texel 8-bit latent codes with
// a scale and a bias per plane, and one decoder MLP, (latents, direction encoding) -> hidden ->
// hidden -> RGB, evaluated per fragment and light.
//
// Parameters: `mp`, the `NeuralParams` struct of neural.rs, followed in the same uniform block by
// the decoder's dense layers (`mp.constants`, decoder.rs `gpu_dense`): half-precision values two
// to a word, rows padded to vectors of eight halves (one `vec4<u32>`): w1 [hidden][n8], b1 [h8],
// w2 [hidden][h8], b2 [h8], w3 [3][h8], b3 [1], matrices row-major [out][in], the output layer
// divided by `mp.out_scale`. Every fragment reads the same weights: GPUs serve uniform reads from
// their constant caches, and software rasterisers read a uniform block without the per-lane
// bounds checks of a storage buffer; two halves per word halve the reads again. The learned
// direction tables are in the store (decoder.rs `gpu_tables`; per direction, view, light, half
// vector, as many as the encoding has: `grid x grid` nodes of `features` halves, padded to an
// even count, over the concentric square, looked up bilinearly: decoder.rs, `taps`). The
// second and output layers
// are fused: each second-layer unit is added into the output as soon as it is computed, so only
// the first layer's activations are kept in a private array.

// The clearance inputs (decoder.rs, `Shape::clearances`): a direction's elevation above the
// texel's horizon at its azimuth, the horizon map rebuilt from the texel's 8-bit coordinates in
// the map's components (relief.rs, `HorizonMap`): `mean[k] + sum_i c_i basis[i][k]` for the two
// bins around the azimuth, linearly interpolated.
fn nn_clearance(texel: u32, d: vec3<f32>) -> f32 {
    let bins = mp.hbins;
    let m = mp.hcomp;
    let tau = 6.283185307179586;
    var phi = atan2(d.y, d.x);
    if (phi < 0.0) {
        phi += tau;
    }
    let f = phi / tau * f32(bins);
    let k0 = u32(floor(f)) % bins;
    let k1 = (k0 + 1u) % bins;
    let w = f - floor(f);
    var h0 = load(mp.hbasis + k0);
    var h1 = load(mp.hbasis + k1);
    for (var i = 0u; i < m; i++) {
        let j = texel * m + i;
        let q = (load_u32(mp.hq + j / 4u) >> ((j & 3u) * 8u)) & 0xffu;
        let c = load(mp.hscale + m + i) + load(mp.hscale + i) * f32(q);
        let row = mp.hbasis + (1u + i) * bins;
        h0 += c * load(row + k0);
        h1 += c * load(row + k1);
    }
    return asin(clamp(d.z, -1.0, 1.0)) - (h0 * (1.0 - w) + h1 * w);
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

// The first and last four halves of a vector of eight.
fn lo4(u: vec4<u32>) -> vec4<f32> {
    return vec4<f32>(unpack2x16float(u.x), unpack2x16float(u.y));
}
fn hi4(u: vec4<u32>) -> vec4<f32> {
    return vec4<f32>(unpack2x16float(u.z), unpack2x16float(u.w));
}

// Halves 4j to 4j + 3 of the row of vectors starting at constant vector `b`.
fn nc4(b: u32, j: u32) -> vec4<f32> {
    let u = mp.constants[b + j / 2u];
    return select(lo4(u), hi4(u), (j & 1u) == 1u);
}

// Four rows' products with eight inputs `x0`, `x1`: constant vectors `r`, `r + stride`,
// `r + 2 stride`, `r + 3 stride` (eight halves each).
fn rows4x8(r: u32, stride: u32, x0: vec4<f32>, x1: vec4<f32>) -> vec4<f32> {
    let u0 = mp.constants[r];
    let u1 = mp.constants[r + stride];
    let u2 = mp.constants[r + 2u * stride];
    let u3 = mp.constants[r + 3u * stride];
    return vec4<f32>(
        dot(lo4(u0), x0) + dot(hi4(u0), x1),
        dot(lo4(u1), x0) + dot(hi4(u1), x1),
        dot(lo4(u2), x0) + dot(hi4(u2), x1),
        dot(lo4(u3), x0) + dot(hi4(u3), x1),
    );
}

// Table `t`'s features at direction `d`, written into the inputs from `first` (decoder.rs,
// `taps`: node (i, j) at square point (i, j) / (grid - 1), index j * grid + i). Two features
// per store word.
fn nn_table(inp: ptr<function, array<vec4<f32>, 22>>, first: u32, t: u32, d: vec3<f32>) {
    let g = mp.grid;
    let c = mp.features;
    let cw = (c + 1u) / 2u;
    let m = f32(g - 1u);
    let x = clamp(hemisphere_to_square(d) * m, vec2<f32>(0.0), vec2<f32>(m));
    let i = min(vec2<u32>(floor(x)), vec2<u32>(g - 2u));
    let f = x - vec2<f32>(i);
    let n0 = mp.tables + (t * g * g + i.y * g + i.x) * cw;
    let n2 = n0 + g * cw;
    let w = vec4<f32>((1.0 - f.x) * (1.0 - f.y), f.x * (1.0 - f.y), (1.0 - f.x) * f.y, f.x * f.y);
    for (var p = 0u; p < cw; p++) {
        let v = w.x * unpack2x16float(load_u32(n0 + p)) + w.y * unpack2x16float(load_u32(n0 + cw + p))
            + w.z * unpack2x16float(load_u32(n2 + p)) + w.w * unpack2x16float(load_u32(n2 + cw + p));
        let k = first + 2u * p;
        (*inp)[k / 4u][k % 4u] = v.x;
        // An odd count's padding feature is not an input (the next inputs stay zero).
        if (2u * p + 1u < c) {
            (*inp)[(k + 1u) / 4u][(k + 1u) % 4u] = v.y;
        }
    }
}

// The inputs are kept as vectors of four (zero beyond the last) and every layer computes four
// units at a time: one read of the private arrays per four products instead of one per product
// (lavapipe keeps dynamically indexed arrays in memory), one constant vector per eight weights.
// Rows are padded with zero weights to vectors of eight, and the inputs and activations beyond
// the last are zero. The hidden width is a multiple of 4 (neural.rs checks).
fn eval_model(texel: u32, vq: ViewQuery, l: vec3<f32>) -> vec3<f32> {
    let k = mp.latents;
    let h = mp.hidden;
    // The inputs: decoded latents, then the direction encoding (decoder.rs, Directions::encode),
    // then the clearances and the table features: at most 32 latents, 6 coordinates, 2
    // clearances and 3 x 16 features.
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
    // The clearances above the texel's horizon, after the coordinates: the light's, and for the
    // BTF encodings the view's first.
    if (mp.hbins > 0u) {
        if (mp.directions == 0u) {
            inp[n / 4u][n % 4u] = nn_clearance(texel, l);
            n = n + 1u;
        } else {
            inp[n / 4u][n % 4u] = nn_clearance(texel, vq.v);
            inp[(n + 1u) / 4u][(n + 1u) % 4u] = nn_clearance(texel, l);
            n = n + 2u;
        }
    }
    // The direction tables' features, after the coordinates and clearances.
    let c = mp.features;
    var nt = 0u;
    if (c > 0u) {
        nt = select(select(3u, 2u, mp.directions == 1u), 1u, mp.directions == 0u);
    }
    if (nt == 1u) {
        nn_table(&inp, n, 0u, l);
    } else if (nt >= 2u) {
        let v = vq.v;
        nn_table(&inp, n, 0u, v);
        nn_table(&inp, n + c, 1u, l);
        if (nt == 3u) {
            let hv = v + l;
            var hd = vec3<f32>(0.0, 0.0, 1.0);
            if (length(hv) > 1e-9) {
                hd = normalize(hv);
            }
            nn_table(&inp, n + 2u * c, 2u, hd);
        }
    }
    n = n + nt * c;
    // Where each layer starts, in vectors of eight halves.
    let n8 = (n + 7u) / 8u;
    let h8 = (h + 7u) / 8u;
    let b1 = h * n8;
    let w2 = b1 + h8;
    let b2 = w2 + h * h8;
    let w3 = b2 + h8;
    let b3 = w3 + 3u * h8;
    let h4 = h / 4u;
    var h1: array<vec4<f32>, 16>;
    for (var j = 0u; j < h4; j++) {
        let r = 4u * j * n8;
        var acc = nc4(b1, j);
        for (var i = 0u; i < n8; i++) {
            acc += rows4x8(r + i, n8, inp[2u * i], inp[2u * i + 1u]);
        }
        h1[j] = nn_act4(acc);
    }
    var out = nc4(b3, 0u).xyz;
    for (var j = 0u; j < h4; j++) {
        let r = w2 + 4u * j * h8;
        var acc = nc4(b2, j);
        for (var i = 0u; i < h8; i++) {
            acc += rows4x8(r + i, h8, h1[2u * i], h1[2u * i + 1u]);
        }
        let a = nn_act4(acc);
        out += vec3<f32>(dot(a, nc4(w3, j)), dot(a, nc4(w3 + h8, j)), dot(a, nc4(w3 + 2u * h8, j)));
    }
    out *= mp.out_scale;
    // The BTF encodings' output is a reflectance times the light's cosine (Directions::gain).
    if (mp.directions != 0u) {
        out *= max(l.z, 0.0);
    }
    return out;
}
