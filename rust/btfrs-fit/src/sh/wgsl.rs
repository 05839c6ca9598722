//! Straight-line WGSL for one double-SH size `kv x kl` (the renderer of paper 002, section 4.2,
//! specialised per model).
//!
//! `shaders_wgsl/sh.wgsl` evaluates any size with loops over runtime bounds and private arrays
//! indexed by loop counters. That is correct, but lavapipe keeps such arrays in memory and
//! gathers them lane by lane: a 25x25 model's one-light 512² sphere took 1.54 s against PTM's
//! 0.27 s (BENCHMARKS.md, "SH frames: where the time goes"). Measured by swapping parts of the
//! shader: hand-unrolling the inner loop gave 1.07 s, constant loop bounds alone nothing, and
//! straight-line code with every index a constant 0.51 s. This module generates that code for a
//! model's sizes: the SH basis with its normalisation and recurrence constants folded (the same
//! recurrence as the generic `sh_basis`, written out per (l, m)), the view query as an
//! `array<f32, kv>`, and both evaluation paths (one light: contract the coefficient rows with
//! the light basis; several lights: the texel's light coefficients kept in named private
//! vectors) with every load offset a constant.
//!
//! Only small models draw with it ([`MAX_STRAIGHT_LINE`]): lavapipe's compile time grows
//! much faster than the code (512² sphere, knit 16², `kv x kl`: first frame = pipeline build +
//! draw, then the draw; one light | two lights, generic loops against straight-line):
//!
//! | size | generic draw | straight-line draw | straight-line first frame |
//! |---|---|---|---|
//! | 16x16 | 590 / 1299 ms | 158 / 195 ms | 0.2 s |
//! | 25x25 | 834 / 2409 ms | 441 / 577 ms | 0.6 s |
//! | 25x36 | | 566 / 848 ms | 4.3 s |
//! | 36x25 | | 762 / 1156 ms | 9.7 s |
//! | 36x36 | 1332 / 4188 ms | 962 / 1592 ms | 9.4 s |
//! | 49x49 | 1518 / 6887 ms | 2504 / 3851 ms | 39.9 s |
//!
//! Above 25 on either side a first frame would wait seconds to minutes for the compiler (and
//! from 49 the one-light draw is slower: the unrolled rows spill). Above 16 the models draw with
//! a *middle form* ([`middle_for`]): the bases straight-line as above, the one-light evaluation a
//! loop over the `ceil(kl / 4)` words of a coefficient row whose body is written out over the
//! `kv` rows (every view-basis index a constant, so the basis stays in registers, and code that
//! grows with `kv`, not `kv x kl`); several lights the same way up to 36 x 36 (the texel's light
//! coefficients by that loop into a private array of `3 ceil(kl / 4)` vectors, then one loop of
//! dot products), the generic loops above ([`MAX_MIDDLE_CACHED`]). Measured (512² sphere, one light, knit 16², release build, Mesa's shader cache
//! disabled; PTM-RGB 152-159 ms in the same runs):
//!
//! | size | straight-line draw, first frame | middle form draw, first frame |
//! |---|---|---|
//! | 9x9 | 48 ms, 0.25 s | |
//! | 16x16 | 113 ms, 0.62 s | 123 ms, 1.23 s (an early middle form) |
//! | 25x25 | 342 ms, 2.31 s | 97-106 ms, 0.36-0.37 s |
//! | 36x36 | | 157-179 ms, 0.50-0.54 s |
//! | 49x49 | | 447-465 ms, 0.97-1.03 s |
//! | 64x64 | | 721-746 ms, 1.69-1.74 s |
//!
//! The generic regions of `sh.wgsl` (marked `// <view>`, `// <cached>`, `// <direct>`) are cut
//! and the generated code appended; the rest of the file (`sh_basis` for the environment
//! shader, `fs_env`) is kept. Sources are built once per size and kept for the process
//! (pipelines are cached by the source's address).

use crate::gpu::Shader;
use std::collections::HashMap;
use std::fmt::Write;
use std::sync::{Mutex, OnceLock};

use super::ShParams;

/// The generic shader's source (every size).
pub const GENERIC: &str = include_str!("../../../../shaders_wgsl/sh.wgsl");

/// The largest `kv` and `kl` drawn with straight-line code (the table above; from 25 the middle
/// form is faster to draw and to compile).
pub const MAX_STRAIGHT_LINE: usize = 16;

/// The shader a `kv x kl` model draws with: its straight-line variant up to
/// [`MAX_STRAIGHT_LINE`] coefficients on each side, else the generic loops.
pub fn shader(kv: usize, kl: usize) -> Shader {
    // A size the fit would not make (`Sh`'s fields are public) draws with the generic loops,
    // which read theirs from the parameters, and fails there as any malformed model would.
    if !(valid(kv) && valid(kl)) {
        <super::Sh as crate::gpu::GpuLayout>::SHADER
    } else if kv <= MAX_STRAIGHT_LINE && kl <= MAX_STRAIGHT_LINE {
        shader_for(kv, kl)
    } else {
        middle_for(kv, kl)
    }
}

/// The middle form for the sizes above [`MAX_STRAIGHT_LINE`]: the bases straight-line (their
/// constants folded) and the one-light evaluation as a loop over the `ceil(kl / 4)` words of a
/// coefficient row whose body is written out over the `kv` rows (`sum_i y_i(v) q[i][w]`, every
/// view-basis index a constant, then one dot product with the light basis's group `w`): code
/// that grows with `kv`, not `kv x kl`; several lights the same way ([`MAX_MIDDLE_CACHED`]).
pub fn middle_for(kv: usize, kl: usize) -> Shader {
    static CACHE: Sources = OnceLock::new();
    kept(&CACHE, kv, kl, middle_source)
}

/// Generated sources by size, built once and kept for the process.
type Sources = OnceLock<Mutex<HashMap<(usize, usize), &'static str>>>;

/// The shader of `make(kv, kl)`, the same source (and address) for every call with the same
/// sizes: the pipeline cache keys on it.
fn kept(cache: &'static Sources, kv: usize, kl: usize, make: fn(usize, usize) -> String) -> Shader {
    assert!(valid(kv) && valid(kl), "double SH sizes are perfect squares in 1..=64, got {kv} x {kl}");
    let mut cache = cache.get_or_init(Default::default).lock().unwrap_or_else(|e| e.into_inner());
    let source = *cache.entry((kv, kl)).or_insert_with(|| Box::leak(make(kv, kl).into_boxed_str()));
    Shader::new::<ShParams>("sh", source)
}

/// The full WGSL of the middle form (without common.wgsl and the parameter struct).
pub fn middle_source(kv: usize, kl: usize) -> String {
    let cached = kv <= MAX_MIDDLE_CACHED && kl <= MAX_MIDDLE_CACHED;
    let mut src = GENERIC.to_string();
    for tag in ["view", "direct"].into_iter().chain(cached.then_some("cached")) {
        src = cut_regions(&src, tag);
    }
    let _ = writeln!(
        src,
        "\n// ---- middle form generated by rust/btfrs-fit/src/sh/wgsl.rs for kv = {kv}, kl = {kl} ----\n"
    );
    let (view, lb) = view_part(kv, kl);
    src.push_str(&view);
    src.push_str(&direct_middle(kv, kl, lb));
    if cached {
        src.push_str(&cached_middle(kv, kl, lb));
    }
    src
}

/// The largest `kv` and `kl` whose several-light path takes the middle form too (every size the
/// fit makes): with the generic loops there, 49x49 draws one light faster (2.2x against 2.9x
/// PTM-RGB) but compiles in 1.7-1.8 s against 1.0 s, and 64x64 in 2.4-2.5 s against 1.7 s.
pub const MAX_MIDDLE_CACHED: usize = 64;

/// `sum_i y_i(v) q[i][w]` over the `kv` rows for the word offset `r` (the middle form's body).
fn row_sum(kv: usize, rw: usize, indent: &str) -> String {
    let terms: Vec<String> =
        (0..kv).map(|i| format!("vq.y[{i}] * unpack4x8unorm(load_u32(r + {}u))", i * rw)).collect();
    terms.join(&format!("\n{indent}+ "))
}

/// Several lights, the middle form: the texel's light coefficients `h[c][w]` (one loop over
/// the words per channel, the body over the rows) in a private array, contracted with the light
/// basis by one loop over the words.
fn cached_middle(kv: usize, kl: usize, lb: &str) -> String {
    let rw = kl.div_ceil(4);
    let mut s = String::new();
    let _ = writeln!(s, "var<private> h_texel: u32 = 0xffffffffu;\nvar<private> hm: array<vec4<f32>, {}>;\n", 3 * rw);
    let _ = writeln!(s, "fn light_coefficients(texel: u32, vq: ViewQuery) {{");
    let _ = writeln!(s, "    for (var ch = 0u; ch < 3u; ch++) {{");
    let _ = writeln!(s, "        let o = mp.coeffs + (texel * 3u + ch) * {}u;", kv * rw);
    let _ = writeln!(s, "        for (var w = 0u; w < {rw}u; w++) {{\n            let r = o + w;");
    let _ =
        writeln!(s, "            hm[ch * {rw}u + w] = {};\n        }}\n    }}", row_sum(kv, rw, "                "));
    s.push_str("    h_texel = texel;\n}\n\n");
    s.push_str(&eval_model_head(kl, lb));
    let groups: Vec<String> = (0..rw).map(|w| format!("g{w}")).collect();
    let _ = writeln!(s, "    let gl = array<vec4<f32>, {rw}>({});", groups.join(", "));
    let _ = writeln!(s, "    var acc = vec3<f32>(0.0);\n    for (var w = 0u; w < {rw}u; w++) {{");
    let _ = writeln!(s, "        let gw = gl[w];");
    let _ = writeln!(
        s,
        "        acc += vec3<f32>(dot(hm[w], gw), dot(hm[{rw}u + w], gw), dot(hm[{}u + w], gw));\n    }}",
        2 * rw
    );
    s.push_str(EVAL_MODEL_TAIL);
    s
}

/// The head both one-light forms share: the signature, the light basis and its groups of four.
fn direct_head(kl: usize, lb: &str) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "fn eval_direct(texel: u32, vq: ViewQuery, l: vec3<f32>) -> vec3<f32> {{");
    let _ = writeln!(s, "    let yl = {lb}(l);");
    s.push_str(&light_groups(kl, "    "));
    s
}

/// One light, the middle form: a loop over the row's words, its body written out over the rows.
fn direct_middle(kv: usize, kl: usize, lb: &str) -> String {
    let (rw, mut s) = (kl.div_ceil(4), direct_head(kl, lb));
    let groups: Vec<String> = (0..rw).map(|w| format!("g{w}")).collect();
    let _ = writeln!(s, "    let gl = array<vec4<f32>, {rw}>({});", groups.join(", "));
    let _ = writeln!(s, "    let sb = mp.scale_bias;\n    var out = vec3<f32>(0.0);");
    let _ = writeln!(s, "    for (var ch = 0u; ch < 3u; ch++) {{");
    let _ = writeln!(s, "        let o = mp.coeffs + (texel * 3u + ch) * {}u;\n        var acc = 0.0;", kv * rw);
    let _ = writeln!(s, "        for (var w = 0u; w < {rw}u; w++) {{");
    let _ = writeln!(s, "            let r = o + w;");
    let _ = writeln!(s, "            let a = {};", row_sum(kv, rw, "                "));
    let _ = writeln!(s, "            acc += dot(a, gl[w]);\n        }}");
    s.push_str("        out[ch] = load(sb + 3u + ch) * vq.sum * sl + 255.0 * load(sb + ch) * acc;\n    }\n    return out;\n}\n\n");
    s
}

/// The shader specialised to `kv x kl` coefficients (perfect squares in 1..=64, as the fit
/// checks), whatever the size; the same source (and address) for every call with the same sizes.
pub fn shader_for(kv: usize, kl: usize) -> Shader {
    static CACHE: Sources = OnceLock::new();
    kept(&CACHE, kv, kl, source_for)
}

/// A coefficient count the fit accepts: a perfect square in 1..=64.
fn valid(n: usize) -> bool {
    let d = (n as f64).sqrt().round() as usize;
    (1..=super::MAX_COEFFS).contains(&n) && d * d == n
}

/// The full WGSL of the `kv x kl` variant (without common.wgsl and the parameter struct).
pub fn source_for(kv: usize, kl: usize) -> String {
    let mut src = GENERIC.to_string();
    for tag in ["view", "cached", "direct"] {
        src = cut_regions(&src, tag);
    }
    let _ = writeln!(src, "\n// ---- generated by rust/btfrs-fit/src/sh/wgsl.rs for kv = {kv}, kl = {kl} ----\n");
    src.push_str(&generated(kv, kl));
    src
}

/// `src` without the lines from each `// <tag>` to its `// </tag>` (both included).
fn cut_regions(src: &str, tag: &str) -> String {
    let (open, close) = (format!("// <{tag}>"), format!("// </{tag}>"));
    let mut out = String::with_capacity(src.len());
    let mut inside = false;
    for line in src.lines() {
        let t = line.trim_start();
        if !inside && t.starts_with(&open) {
            inside = true;
        } else if inside && t.starts_with(&close) {
            inside = false;
        } else if !inside {
            out.push_str(line);
            out.push('\n');
        }
    }
    assert!(!inside, "sh.wgsl: region <{tag}> is not closed");
    out
}

/// A WGSL float literal of `x` (shortest round trip, always with a point or exponent).
fn lit(x: f64) -> String {
    let s = format!("{x:?}");
    if s.contains(['.', 'e', 'E']) {
        s
    } else {
        format!("{s}.0")
    }
}

/// `fn name(d) -> array<f32, n>`: the real orthonormal SH of `sh.wgsl`'s `sh_basis`, with the
/// recurrence of Q_l^m = P_l^m / sin^m(theta) and K_l^m written out per (l, m).
fn basis(name: &str, n: usize) -> String {
    let deg = (n as f64).sqrt().round() as usize - 1;
    let mut s = String::new();
    let _ = writeln!(s, "fn {name}(d: vec3<f32>) -> array<f32, {n}> {{\n    var y: array<f32, {n}>;");
    // c_m + i s_m = (x + i y)^m.
    for m in 1..=deg {
        if m == 1 {
            let _ = writeln!(s, "    let c1 = d.x;\n    let s1 = d.y;");
        } else {
            let p = m - 1;
            let _ = writeln!(s, "    let c{m} = c{p} * d.x - s{p} * d.y;\n    let s{m} = c{p} * d.y + s{p} * d.x;");
        }
    }
    let fact = |k: usize| (1..=k).map(|i| i as f64).product::<f64>();
    for m in 0..=deg {
        // Q_m^m = (-1)^m (2m - 1)!!
        let qmm = (1..m).fold(1.0f64, |a, i| a * (2 * i + 1) as f64) * if m % 2 == 1 { -1.0 } else { 1.0 };
        for l in m..=deg {
            let q = if l == m {
                lit(qmm)
            } else if l == m + 1 {
                format!("{} * d.z", lit((2 * m + 1) as f64 * qmm))
            } else {
                let a = (2 * l - 1) as f64 / (l - m) as f64;
                let b = (l + m - 1) as f64 / (l - m) as f64;
                format!("{} * d.z * q{}_{m} - {} * q{}_{m}", lit(a), l - 1, lit(b), l - 2)
            };
            let _ = writeln!(s, "    let q{l}_{m} = {q};");
            let k = ((2 * l + 1) as f64 / (4.0 * std::f64::consts::PI) * fact(l - m) / fact(l + m)).sqrt();
            if m == 0 {
                let _ = writeln!(s, "    y[{}] = {} * q{l}_0;", l * (l + 1), lit(k));
            } else {
                let k2 = lit(std::f64::consts::SQRT_2 * k);
                let _ = writeln!(s, "    y[{}] = {k2} * q{l}_{m} * c{m};", l * (l + 1) + m);
                let _ = writeln!(s, "    y[{}] = {k2} * q{l}_{m} * s{m};", l * (l + 1) - m);
            }
        }
    }
    s.push_str("    return y;\n}\n\n");
    s
}

/// The several-light `eval_model` up to its contraction: one light goes to `eval_direct`, a new
/// texel gets its light coefficients, then the light basis in groups (`g0..`, `sl`).
fn eval_model_head(kl: usize, lb: &str) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "fn eval_model(texel: u32, vq: ViewQuery, l: vec3<f32>) -> vec3<f32> {{");
    s.push_str("    if (g.n_lights == 1u) {\n        return eval_direct(texel, vq, l);\n    }\n");
    s.push_str("    if (texel != h_texel) {\n        light_coefficients(texel, vq);\n    }\n");
    let _ = writeln!(s, "    let yl = {lb}(l);");
    s.push_str(&light_groups(kl, "    "));
    s
}

/// `eval_model` after its contraction `acc`: the stored bias and scale applied.
const EVAL_MODEL_TAIL: &str = "    let sb = mp.scale_bias;
    let bias = vec3<f32>(load(sb + 3u), load(sb + 4u), load(sb + 5u));
    let scale = vec3<f32>(load(sb), load(sb + 1u), load(sb + 2u));
    return bias * (vq.sum * sl) + 255.0 * scale * acc;
}
";

/// `let g0 = vec4(yl[0], ..); ..` and `let sl = ..`: the light basis in the groups of four
/// of the padded coefficient rows (zero beyond kl), and its sum.
fn light_groups(kl: usize, indent: &str) -> String {
    let rw = kl.div_ceil(4);
    let mut s = String::new();
    for w in 0..rw {
        let c: Vec<String> =
            (0..4).map(|i| if 4 * w + i < kl { format!("yl[{}]", 4 * w + i) } else { "0.0".into() }).collect();
        let _ = writeln!(s, "{indent}let g{w} = vec4<f32>({});", c.join(", "));
    }
    let sum: Vec<String> = (0..rw).map(|w| format!("g{w}")).collect();
    let _ = writeln!(s, "{indent}let sl = dot({}, vec4<f32>(1.0));", sum.join(" + "));
    s
}

fn generated(kv: usize, kl: usize) -> String {
    let (mut s, lb) = view_part(kv, kl);
    s.push_str(&direct_straight(kv, kl, lb));
    s.push_str(&cached_straight(kv, kl, lb));
    s
}

/// The view query (`struct ViewQuery`, `view_query`) and the bases, straight-line; returns the
/// code and the light basis's function name.
fn view_part(kv: usize, kl: usize) -> (String, &'static str) {
    let mut s = String::new();
    let _ = writeln!(s, "struct ViewQuery {{\n    y: array<f32, {kv}>,\n    sum: f32,\n}};\n");
    s.push_str(&basis("sh_basis_v", kv));
    let lb = if kl == kv {
        "sh_basis_v"
    } else {
        s.push_str(&basis("sh_basis_l", kl));
        "sh_basis_l"
    };
    let ysum: Vec<String> = (0..kv).map(|i| format!("y[{i}]")).collect();
    let _ = writeln!(
        s,
        "fn view_query(v: vec3<f32>) -> ViewQuery {{\n    let y = sh_basis_v(v);\n    return ViewQuery(y, {});\n}}\n",
        ysum.join(" + ")
    );
    (s, lb)
}

/// One light, straight-line: each coefficient row dotted with the light basis as it is loaded.
fn direct_straight(kv: usize, kl: usize, lb: &str) -> String {
    let (rw, mut s) = (kl.div_ceil(4), direct_head(kl, lb));
    let _ = writeln!(s, "    let sb = mp.scale_bias;\n    var out = vec3<f32>(0.0);");
    let _ = writeln!(s, "    for (var ch = 0u; ch < 3u; ch++) {{");
    let _ = writeln!(s, "        let o = mp.coeffs + (texel * 3u + ch) * {}u;\n        var acc = 0.0;", kv * rw);
    for i in 0..kv {
        let t: Vec<String> =
            (0..rw).map(|w| format!("dot(unpack4x8unorm(load_u32(o + {}u)), g{w})", i * rw + w)).collect();
        let _ = writeln!(s, "        acc += vq.y[{i}] * ({});", t.join(" + "));
    }
    s.push_str("        out[ch] = load(sb + 3u + ch) * vq.sum * sl + 255.0 * load(sb + ch) * acc;\n    }\n    return out;\n}\n\n");
    s
}

/// Several lights, straight-line: h[c][j] = sum_i y_i(v) q[c][i][j] at the texel's first light,
/// kept in named private vectors (no array, so no indexing at all) for the others.
fn cached_straight(kv: usize, kl: usize, lb: &str) -> String {
    let rw = kl.div_ceil(4);
    let mut s = String::new();
    // Several lights: h[c][j] = sum_i y_i(v) q[c][i][j] at the texel's first light, kept in
    // named private vectors (no array, so no indexing at all) for the others.
    let _ = writeln!(s, "var<private> h_texel: u32 = 0xffffffffu;");
    for ch in 0..3 {
        for w in 0..rw {
            let _ = writeln!(s, "var<private> h{ch}_{w}: vec4<f32>;");
        }
    }
    let _ = writeln!(s, "\nfn light_coefficients(texel: u32, vq: ViewQuery) {{");
    for ch in 0..3 {
        let _ = writeln!(s, "    let o{ch} = mp.coeffs + (texel * 3u + {ch}u) * {}u;", kv * rw);
        for w in 0..rw {
            let t: Vec<String> =
                (0..kv).map(|i| format!("vq.y[{i}] * unpack4x8unorm(load_u32(o{ch} + {}u))", i * rw + w)).collect();
            let _ = writeln!(s, "    h{ch}_{w} = {};", t.join("\n        + "));
        }
    }
    s.push_str("    h_texel = texel;\n}\n\n");
    s.push_str(&eval_model_head(kl, lb));
    let dots = |ch: usize| (0..rw).map(|w| format!("dot(h{ch}_{w}, g{w})")).collect::<Vec<_>>().join(" + ");
    let _ = writeln!(s, "    let acc = vec3<f32>({}, {}, {});", dots(0), dots(1), dots(2));
    s.push_str(EVAL_MODEL_TAIL);
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sh::sh_basis;

    #[test]
    fn the_generic_regions_are_cut_and_replaced() {
        let src = source_for(25, 9);
        for name in ["fn view_query", "fn eval_direct", "fn eval_model", "fn light_coefficients", "struct ViewQuery"] {
            assert_eq!(src.matches(name).count(), 1, "{name} once in the variant");
            assert_eq!(GENERIC.matches(name).count(), 1, "{name} once in the generic shader");
        }
        assert!(src.contains("fn fs_env") && src.contains("fn sh_basis("), "the environment shader is kept");
        assert!(src.contains("array<f32, 25>") && src.contains("fn sh_basis_l(d: vec3<f32>) -> array<f32, 9>"));
        assert!(!src.contains("// <view>") && !src.contains("h4[ch * 16u + w]"));
    }

    #[test]
    fn large_models_take_the_middle_form_and_malformed_ones_the_generic_loops() {
        assert!(shader(16, 16) == shader_for(16, 16) && shader(16, 4) == shader_for(16, 4));
        for (kv, kl) in [(25, 25), (25, 9), (36, 25), (25, 36), (64, 64), (49, 9)] {
            assert!(shader(kv, kl) == middle_for(kv, kl), "{kv} x {kl}: the middle form");
            let src = shader(kv, kl).source;
            // One loop over the row's words, its body written out over the kv rows (once for
            // one light, once more for the light coefficients of several).
            assert!(!src.contains("// <direct>"), "{kv} x {kl}");
            // Several lights in the middle form too up to 36 (the body once more), the generic
            // loops above.
            let middle_cached = kv <= MAX_MIDDLE_CACHED && kl <= MAX_MIDDLE_CACHED;
            let bodies = if middle_cached { 2 } else { 1 };
            assert_eq!(src.matches("unpack4x8unorm(load_u32(r + ").count(), bodies * kv, "{kv} x {kl}");
            assert_eq!(src.contains("h4[ch * 16u + w]"), !middle_cached, "{kv} x {kl}");
            assert_eq!(src.matches("fn light_coefficients").count(), 1, "{kv} x {kl}");
        }
        for (kv, kl) in [(0, 9), (9, 0), (10, 9), (9, 24)] {
            assert!(shader(kv, kl).source == GENERIC, "{kv} x {kl}");
        }
    }

    #[test]
    fn the_same_sizes_give_the_same_source() {
        let (a, b, c) = (shader_for(16, 16), shader_for(16, 16), shader_for(16, 25));
        assert!(std::ptr::eq(a.source, b.source), "one source per size: the pipeline cache keys on it");
        assert_ne!(a, c);
    }

    /// The folded constants are the basis: interpret the generated `sh_basis_v` (a list of
    /// `let` and `y[i] =` lines over d.x, d.y, d.z) in f64 and compare with `sh_basis`.
    #[test]
    fn the_generated_basis_is_the_real_sh() {
        for n in [1, 4, 9, 16, 25, 36, 49, 64] {
            let src = basis("b", n);
            for d in [[0.3f64, -0.5, 0.81], [0.0, 0.0, 1.0], [-0.9, 0.1, 0.2], [0.6, 0.64, -0.48]] {
                let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                let d = [d[0] / len, d[1] / len, d[2] / len];
                let got = interpret(&src, d, n);
                let mut want = vec![0.0; n];
                sh_basis(n, d, &mut want);
                for (i, (g, w)) in got.iter().zip(&want).enumerate() {
                    assert!((g - w).abs() < 1e-12 * (1.0 + w.abs()), "n {n}, y[{i}]: {g} vs {w}");
                }
            }
        }
    }

    /// A tiny evaluator for the generated basis: products and sums of literals and names.
    fn interpret(src: &str, d: [f64; 3], n: usize) -> Vec<f64> {
        let mut vars: HashMap<String, f64> =
            [("d.x", d[0]), ("d.y", d[1]), ("d.z", d[2])].iter().map(|(k, v)| (k.to_string(), *v)).collect();
        let mut y = vec![f64::NAN; n];
        let term = |t: &str, vars: &HashMap<String, f64>| -> f64 {
            t.split(" * ").map(|f| f.trim().parse::<f64>().unwrap_or_else(|_| vars[f.trim()])).product()
        };
        let expr = |e: &str, vars: &HashMap<String, f64>| -> f64 {
            let mut total = 0.0;
            for sum in e.split(" + ") {
                for (k, part) in sum.split(" - ").enumerate() {
                    let v = term(part, vars);
                    total += if k == 0 { v } else { -v };
                }
            }
            total
        };
        for line in src.lines().map(str::trim) {
            if let Some(rest) = line.strip_prefix("let ") {
                let (name, e) = rest.trim_end_matches(';').split_once(" = ").unwrap();
                let v = expr(e, &vars);
                vars.insert(name.to_string(), v);
            } else if let Some(rest) = line.strip_prefix("y[") {
                let (i, e) = rest.trim_end_matches(';').split_once("] = ").unwrap();
                y[i.parse::<usize>().unwrap()] = expr(e, &vars);
            }
        }
        y
    }
}
