//! Every model shader, prefixed with common.wgsl, parses and validates with naga: no GPU needed,
//! so a broken shader fails `cargo test` on any machine.

use btfrs_render::gpu::shader_source;
use btfrs_render::Shader;

fn validate(src: &str) -> Result<(), String> {
    let module = naga::front::wgsl::parse_str(src).map_err(|e| e.emit_to_string(src))?;
    naga::valid::Validator::new(naga::valid::ValidationFlags::all(), naga::valid::Capabilities::empty())
        .validate(&module)
        .map_err(|e| format!("{e:?}"))?;
    Ok(())
}

#[test]
fn every_model_shader_validates() {
    for s in [Shader::Raw, Shader::Ptm, Shader::Srf, Shader::Lafortune, Shader::Sh, Shader::Lpca9, Shader::Lpca3d] {
        for single in [false, true] {
            let src = shader_source(s, single);
            assert_eq!(src.contains("switch c"), !single, "the single-chunk variant replaces the chunk switch");
            if let Err(e) = validate(&src) {
                panic!("{}.wgsl (single chunk: {single}) does not validate:\n{e}", s.name());
            }
        }
    }
}

#[test]
fn a_broken_shader_is_caught() {
    // The check is real: a model file that calls an undefined function fails it.
    let bad = shader_source(Shader::Ptm, true).replace("load_dir(param(4u)", "load_dirr(param(4u)");
    assert!(validate(&bad).is_err());
}
