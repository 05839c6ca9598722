// sh.wgsl: double spherical harmonics (paper 002, sections 3.1 and 4.2), 8-bit coefficients.
//
// f_c(v, l) = sum_ij C[c][i][j] y_i(v) y_j(l), C = bias[c] + scale[c] * q with q in 0..255.
// The real orthonormal SH are evaluated here independently of the Rust code (which the CPU
// reference uses): degree L, order M, index L(L+1)+M; cos(M phi) sin^M(theta) and
// sin(M phi) sin^M(theta) from the powers of (x + i y), and Q_L^M = P_L^M / sin^M(theta), a
// polynomial in z, by Q_M^M = (-1)^M (2M-1)!!, Q_{M+1}^M = (2M+1) z Q_M^M,
// Q_L^M = ((2L-1) z Q_{L-1}^M - (L+M-1) Q_{L-2}^M) / (L-M).
//
// Storage: per texel and channel, kv rows of ceil(kl / 4) words, four 8-bit coefficients per word
// (the row padded with zeros), so a row is read with whole-word loads and unpack4x8unorm.
// Parameters: `mp`, the `ShParams` struct of rust/btfrs-fit/src/sh.rs (its fields and their meaning are
// written there once; the WGSL `struct Params` is generated from it).

// Regions marked <view>, <direct> and <cached> are the generic form: rust/btfrs-fit/src/sh/wgsl.rs
// replaces them by code generated for the model's kv x kl: straight-line up to 16 x 16, and
// above it a middle form (the one-light evaluation a loop over a row's words whose body is
// written out over the rows, and up to 36 x 36 the several-light coefficients the same way).
// lavapipe keeps dynamically indexed private arrays in memory and gathers them per lane; with
// constant indices they stay in registers (a 25x25 one-light frame 1.54 s -> 0.18 s,
// BENCHMARKS.md), and the middle form compiles in about a second where full straight-line code
// takes seconds to minutes from 25 x 36.
// <view>
struct ViewQuery {
    y: array<f32, 64>,
    sum: f32,
};

// </view>

fn sh_basis(n: u32, d: vec3<f32>) -> array<f32, 64> {
    var y: array<f32, 64>;
    let deg = u32(round(sqrt(f32(n)))) - 1u;
    var cm = 1.0;   // Re (x + i y)^m
    var sm = 0.0;   // Im (x + i y)^m
    var qmm = 1.0;  // Q_m^m
    var inv_fact2m = 1.0;  // 1 / (2m)!
    for (var m = 0u; m <= deg; m++) {
        if (m > 0u) {
            let c = cm * d.x - sm * d.y;
            sm = cm * d.y + sm * d.x;
            cm = c;
            qmm = -qmm * f32(2u * m - 1u);
        }
        var q_prev = 0.0;
        var q = qmm;
        // K_l^m^2 = (2l+1) / (4 pi) * (l-m)! / (l+m)!, stepped in l (no loop over factorials):
        // at l = m it is (2m+1) / (4 pi (2m)!), and l -> l+1 multiplies it by
        // (2l+3) / (2l+1) * (l+1-m) / (l+1+m).
        if (m > 0u) {
            inv_fact2m /= f32((2u * m - 1u) * (2u * m));
        }
        var k2 = f32(2u * m + 1u) / 12.566370614359172 * inv_fact2m;
        for (var l = m; l <= deg; l++) {
            if (l > m) {
                k2 *= f32(2u * l + 1u) / f32(2u * l - 1u) * f32(l - m) / f32(l + m);
            }
            if (l == m + 1u) {
                q_prev = q;
                q = f32(2u * m + 1u) * d.z * qmm;
            } else if (l > m + 1u) {
                let qn = (f32(2u * l - 1u) * d.z * q - f32(l + m - 1u) * q_prev) / f32(l - m);
                q_prev = q;
                q = qn;
            }
            let k = sqrt(k2);
            if (m == 0u) {
                y[l * (l + 1u)] = k * q;
            } else {
                y[l * (l + 1u) + m] = 1.4142135623730951 * k * q * cm;
                y[l * (l + 1u) - m] = 1.4142135623730951 * k * q * sm;
            }
        }
    }
    return y;
}

// <view>
fn view_query(v: vec3<f32>) -> ViewQuery {
    let kv = mp.kv;
    let y = sh_basis(kv, v);
    var s = 0.0;
    for (var i = 0u; i < kv; i++) {
        s += y[i];
    }
    return ViewQuery(y, s);
}
// </view>

// <cached>
// Per invocation, the texel's light coefficients at this fragment's view, h[c][j] =
// sum_i y_i(v) q[c][i][j] (in groups of four, as the rows), computed at the first light and
// kept for the others: shade_lights loops every light at one texel with one view query, so a
// frame with N lights (64 sampled environment lights) reads the 3 kv kl coefficients once, not N
// times. A fragment has one view query, and the texel is the key (a filtered fragment visits
// several).
var<private> h_texel: u32 = 0xffffffffu;
var<private> h4: array<vec4<f32>, 48>;

fn light_coefficients(texel: u32, vq: ViewQuery) {
    let kv = mp.kv;
    let rw = (mp.kl + 3u) / 4u;
    for (var ch = 0u; ch < 3u; ch++) {
        let base = mp.coeffs + (texel * 3u + ch) * kv * rw;
        for (var w = 0u; w < rw; w++) {
            var acc = vec4<f32>(0.0);
            for (var i = 0u; i < kv; i++) {
                acc += vq.y[i] * unpack4x8unorm(load_u32(base + i * rw + w));
            }
            h4[ch * 16u + w] = acc;
        }
    }
    h_texel = texel;
}

// </cached>

// <direct>
// One light: the coefficients are read once anyway, and contracting with the light basis
// first keeps the accumulator in registers (the cached path below stores h in a private array,
// which made a one-light frame slower on lavapipe).
fn eval_direct(texel: u32, vq: ViewQuery, l: vec3<f32>) -> vec3<f32> {
    let kv = mp.kv;
    let kl = mp.kl;
    let rw = (kl + 3u) / 4u;
    let yl = sh_basis(kl, l);
    var yl4: array<vec4<f32>, 16>;
    var sl = 0.0;
    for (var w = 0u; w < rw; w++) {
        var g = vec4<f32>(0.0);
        for (var s = 0u; s < 4u; s++) {
            let j = 4u * w + s;
            if (j < kl) {
                g[s] = yl[j];
            }
        }
        yl4[w] = g;
        sl += g.x + g.y + g.z + g.w;
    }
    let sb = mp.scale_bias;
    var out = vec3<f32>(0.0);
    for (var ch = 0u; ch < 3u; ch++) {
        let base = mp.coeffs + (texel * 3u + ch) * kv * rw;
        var acc = 0.0;
        for (var i = 0u; i < kv; i++) {
            var r = 0.0;
            for (var w = 0u; w < rw; w++) {
                r += dot(unpack4x8unorm(load_u32(base + i * rw + w)), yl4[w]);
            }
            acc += vq.y[i] * r;
        }
        out[ch] = load(sb + 3u + ch) * vq.sum * sl + 255.0 * load(sb + ch) * acc;
    }
    return out;
}
// </direct>

// <cached>

fn eval_model(texel: u32, vq: ViewQuery, l: vec3<f32>) -> vec3<f32> {
    if (g.n_lights == 1u) {
        return eval_direct(texel, vq, l);
    }
    if (texel != h_texel) {
        light_coefficients(texel, vq);
    }
    let kl = mp.kl;
    let rw = (kl + 3u) / 4u;
    let yl = sh_basis(kl, l);
    let sb = mp.scale_bias;
    var acc = vec3<f32>(0.0);
    var sl = 0.0;
    for (var w = 0u; w < rw; w++) {
        // The light basis in groups of four (zero beyond kl), matching the padded rows.
        var g = vec4<f32>(0.0);
        for (var s = 0u; s < 4u; s++) {
            let j = 4u * w + s;
            if (j < kl) {
                g[s] = yl[j];
            }
        }
        sl += g.x + g.y + g.z + g.w;
        acc += vec3<f32>(dot(h4[w], g), dot(h4[16u + w], g), dot(h4[32u + w], g));
    }
    var out = vec3<f32>(0.0);
    for (var ch = 0u; ch < 3u; ch++) {
        out[ch] = load(sb + 3u + ch) * vq.sum * sl + 255.0 * load(sb + ch) * acc[ch];
    }
    return out;
}

// </cached>

// --- Environment light in the SH domain (paper 002, section 4; rust/btfrs-render/src/sh_env.rs) ---
//
// `env` holds [d_k] x kl, the environment's coefficients [e_j] x kl, then G = A blockdiag(M_l^-T)
// by rows of ceil(kl / 4) vec4. Per pixel: f_k = E_band(k)(R^T d_k) (the environment rotated
// into the tangent frame, sampled per band), h = G f (rotation finished and the hemispherical
// autocorrelation applied), out_c = sum_i y_i(v) sum_j C_cij h_cj.
@fragment
fn fs_env(f: VsOut) -> @location(0) vec4<f32> {
    let duv_dx = dpdxFine(f.uv);
    let duv_dy = dpdyFine(f.uv);
    let n = normalize(f.nrm);
    let t = normalize(f.tan);
    let b = normalize(f.bit);
    let v = to_local(normalize(g.eye.xyz - f.pos), t, b, n);
    if (v.z <= 0.0) {
        return vec4<f32>(0.0, 0.0, 0.0, 1.0);
    }
    var taps: Taps;
    if (g.lookup.x == 0u) {
        taps.n = 1u;
        taps.t[0] = texel_index(f.uv);
        taps.w[0] = 1.0;
    } else {
        taps = texel_taps(f.uv, duv_dx, duv_dy);
    }
    let kv = mp.kv;
    let kl = mp.kl;
    let rw = (kl + 3u) / 4u;
    var fk: array<vec3<f32>, 64>;
    var deg = 0u;
    for (var k = 0u; k < kl; k++) {
        if (k >= (deg + 1u) * (deg + 1u)) {
            deg += 1u;
        }
        let d = env[k].xyz;
        let w = normalize(d.x * t + d.y * b + d.z * n);
        let y = sh_basis((deg + 1u) * (deg + 1u), w);
        var s = vec3<f32>(0.0);
        for (var j = deg * deg; j < (deg + 1u) * (deg + 1u); j++) {
            s += env[kl + j].xyz * y[j];
        }
        fk[k] = s;
    }
    // h = G f, grouped by four coefficients per channel to match the padded coefficient rows.
    var h4: array<mat3x4<f32>, 16>;
    var hsum = vec3<f32>(0.0);
    for (var w = 0u; w < rw; w++) {
        var m = mat3x4<f32>(vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0));
        for (var s = 0u; s < 4u; s++) {
            let i = 4u * w + s;
            if (i < kl) {
                var acc = vec3<f32>(0.0);
                for (var q = 0u; q < rw; q++) {
                    let row = env[2u * kl + i * rw + q];
                    for (var c = 0u; c < 4u; c++) {
                        let k = 4u * q + c;
                        if (k < kl) {
                            acc += row[c] * fk[k];
                        }
                    }
                }
                m[0][s] = acc.x;
                m[1][s] = acc.y;
                m[2][s] = acc.z;
                hsum += acc;
            }
        }
        h4[w] = m;
    }
    let yv = sh_basis(kv, v);
    var ysum = 0.0;
    for (var i = 0u; i < kv; i++) {
        ysum += yv[i];
    }
    let sb = mp.scale_bias;
    var out = vec3<f32>(0.0);
    for (var tap = 0u; tap < taps.n; tap++) {
        let texel = taps.t[tap];
        for (var ch = 0u; ch < 3u; ch++) {
            let base = mp.coeffs + (texel * 3u + ch) * kv * rw;
            var acc = 0.0;
            for (var i = 0u; i < kv; i++) {
                var r = 0.0;
                for (var w = 0u; w < rw; w++) {
                    r += dot(unpack4x8unorm(load_u32(base + i * rw + w)), h4[w][ch]);
                }
                acc += yv[i] * r;
            }
            out[ch] += taps.w[tap] * (load(sb + 3u + ch) * ysum * hsum[ch] + 255.0 * load(sb + ch) * acc);
        }
    }
    return vec4<f32>(out, 1.0);
}
