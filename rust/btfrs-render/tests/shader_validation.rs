//! Every model shader, prefixed with common.wgsl and its generated parameter struct, parses and
//! validates with naga: no GPU needed, so a broken shader fails `cargo test` on any machine. The
//! parameter structs are checked against their Rust mirrors (layout and use).

use btfrs_fit::gpu::{GpuLayout, Shader, PARAM_WORDS};
use btfrs_fit::registry::MODELS;
use btfrs_fit::RawModel;
use btfrs_render::gpu::shader_source;

fn all_shaders() -> Vec<Shader> {
    let mut v = vec![<RawModel<'static> as GpuLayout>::SHADER];
    for e in MODELS {
        v.extend((e.shaders)());
    }
    v
}

fn parse(src: &str) -> Result<naga::Module, String> {
    let module = naga::front::wgsl::parse_str(src).map_err(|e| e.emit_to_string(src))?;
    // `unpack2x16float` (core WGSL) is behind this capability in naga: wgpu grants it on every
    // adapter that meets WebGPU's downlevel defaults (`SHADER_F16_IN_F32`), lavapipe included.
    let caps = naga::valid::Capabilities::SHADER_FLOAT16_IN_FLOAT32;
    naga::valid::Validator::new(naga::valid::ValidationFlags::all(), caps)
        .validate(&module)
        .map_err(|e| format!("{e:?}"))?;
    Ok(module)
}

#[test]
fn every_model_shader_validates() {
    let shaders = all_shaders();
    assert!(shaders.len() >= 7, "raw, five models, LPCA's second renderer");
    for s in shaders {
        for single in [false, true] {
            let src = shader_source(s, single);
            assert_eq!(src.contains("switch c"), !single, "the single-chunk variant replaces the chunk switch");
            if let Err(e) = parse(&src) {
                panic!("{}.wgsl (single chunk: {single}) does not validate:\n{e}", s.name);
            }
        }
    }
}

#[test]
fn parameter_structs_match_their_rust_mirrors() {
    // naga lays out the generated `struct Params` by WGSL's uniform rules: each field must sit at
    // the offset the Rust struct gives it (4 x its index, checked at compile time there), the
    // block must be 64 bytes (then the model's constants, if any), and the shader must read every
    // field it declares (a field the shader ignores means the two sides disagree about what the
    // words are).
    for s in all_shaders() {
        let module = parse(&shader_source(s, true)).unwrap();
        let (_, ty) = module
            .types
            .iter()
            .find(|(_, t)| t.name.as_deref() == Some("Params"))
            .unwrap_or_else(|| panic!("{}: no Params struct", s.name));
        let naga::TypeInner::Struct { members, span } = &ty.inner else { panic!("{}: Params is not a struct", s.name) };
        // A model with constants declares them after the 16 words: `constants`, an array of
        // vectors of four words at byte 64, which its shader reads.
        let constants = match members.get(PARAM_WORDS) {
            None => 0,
            Some(m) => {
                assert_eq!((m.name.as_deref(), m.offset as usize), (Some("constants"), 4 * PARAM_WORDS), "{}", s.name);
                let naga::TypeInner::Array { base, size: naga::ArraySize::Constant(n), stride: 16 } =
                    module.types[m.ty].inner
                else {
                    panic!("{}: constants is not a fixed array of 16-byte vectors", s.name)
                };
                assert!(
                    matches!(module.types[base].inner, naga::TypeInner::Vector { size: naga::VectorSize::Quad, scalar } if scalar == naga::Scalar::U32),
                    "{}: constants are vec4<u32>",
                    s.name
                );
                assert!(s.source.contains("mp.constants["), "{}.wgsl never reads mp.constants", s.name);
                n.get() as usize
            }
        };
        assert_eq!(*span as usize, 4 * PARAM_WORDS + 16 * constants, "{}", s.name);
        assert!(4 * constants <= btfrs_fit::gpu::MAX_CONSTANT_WORDS, "{}: within 64 KiB", s.name);
        assert_eq!(members.len(), PARAM_WORDS + (constants > 0) as usize, "{}", s.name);
        let params = (s.params)();
        for (i, m) in members.iter().take(PARAM_WORDS).enumerate() {
            assert_eq!(m.offset as usize, 4 * i, "{}: field {:?}", s.name, m.name);
            let name = m.name.as_deref().unwrap();
            if !name.starts_with("_pad") {
                assert!(params.contains(&format!("{name}: ")));
                assert!(s.source.contains(&format!("mp.{name}")), "{}.wgsl never reads mp.{name}", s.name);
            }
        }
    }
}

#[test]
fn a_broken_shader_is_caught() {
    // The check is real: a model file that calls an undefined function, or reads a parameter
    // its struct does not declare, fails it.
    let ptm = <btfrs_fit::Ptm as GpuLayout>::SHADER;
    let src = shader_source(ptm, true);
    assert!(parse(&src).is_ok());
    assert!(parse(&src.replace("load_dir(mp.rgb", "load_dirr(mp.rgb")).is_err());
    assert!(parse(&src.replace("mp.coeffs", "mp.coefs")).is_err());
}

#[test]
fn globals_match_their_rust_mirror() {
    // naga's layout of `struct Globals` (WGSL uniform rules) must be the Rust struct's, field by
    // field and in size: the tile-map fields grew it, and a mismatch would read garbage.
    let module = parse(&shader_source(<RawModel<'static> as GpuLayout>::SHADER, true)).unwrap();
    let (_, ty) = module.types.iter().find(|(_, t)| t.name.as_deref() == Some("Globals")).expect("struct Globals");
    let naga::TypeInner::Struct { members, span } = &ty.inner else { panic!("Globals is not a struct") };
    let (fields, size) = btfrs_render::gpu::GLOBALS_LAYOUT;
    let wgsl: Vec<(&str, usize)> = members.iter().map(|m| (m.name.as_deref().unwrap(), m.offset as usize)).collect();
    assert_eq!(wgsl, fields.to_vec());
    assert_eq!(*span as usize, size);
    assert_eq!(size % 16, 0, "a uniform block's size is a multiple of 16");
}

#[test]
fn every_double_sh_size_validates() {
    // The SH renderer draws with code generated per (kv, kl), straight-line or the middle form:
    // every size the fit accepts (degree 0 to 7 on each side, kl not a multiple of 4 included),
    // in both forms, must validate.
    let sizes = [1, 4, 9, 16, 25, 36, 49, 64];
    for kv in sizes {
        for kl in sizes {
            for s in [btfrs_fit::sh::wgsl::shader_for(kv, kl), btfrs_fit::sh::wgsl::middle_for(kv, kl)] {
                for single_chunk in [true, false] {
                    if let Err(e) = parse(&shader_source(s, single_chunk)) {
                        panic!("sh.wgsl for {kv} x {kl} (single chunk: {single_chunk}) does not validate:\n{e}");
                    }
                }
            }
        }
    }
}
