//! `btfrs._native`: the PyO3 translation layer.
//!
//! Nothing here computes: each function converts Python arguments (numpy arrays are borrowed
//! without copying where their layout allows), releases the GIL around the Rust call, and maps
//! errors onto the exception classes of `btfrs.exceptions`. Algorithms live in the plain crates.

mod arrays;
mod blockwise;
mod calibrate;
mod core;
mod errors;
mod graphcut;
mod hemimap;
mod io;
mod models;
mod photometric;
mod render;
mod run;
mod synth;
mod tiles;
mod values;

use pyo3::prelude::*;

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    // Rayon's global pool is this process's; a child forked from it will run its parallel work
    // on a pool of its own (see btfrs_core::process).
    btfrs_core::process::claim_global_pool();
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_function(wrap_pyfunction!(run::_panic_for_test, m)?)?;
    m.add_function(wrap_pyfunction!(core::ubo81, m)?)?;
    m.add_function(wrap_pyfunction!(core::validate_btf, m)?)?;
    m.add_function(wrap_pyfunction!(core::split_pairs, m)?)?;
    m.add_function(wrap_pyfunction!(core::material_names, m)?)?;
    m.add_function(wrap_pyfunction!(core::make_material, m)?)?;
    m.add_function(wrap_pyfunction!(photometric::material_heightfield, m)?)?;
    m.add_function(wrap_pyfunction!(photometric::photometric_normals, m)?)?;
    m.add_function(wrap_pyfunction!(hemimap::square_to_disk, m)?)?;
    m.add_function(wrap_pyfunction!(hemimap::disk_to_square, m)?)?;
    m.add_function(wrap_pyfunction!(hemimap::square_to_hemisphere, m)?)?;
    m.add_function(wrap_pyfunction!(hemimap::hemisphere_to_square, m)?)?;
    m.add_class::<models::PyModel>()?;
    m.add_function(wrap_pyfunction!(models::fit_model, m)?)?;
    m.add_function(wrap_pyfunction!(models::load_model, m)?)?;
    m.add_function(wrap_pyfunction!(models::check_options, m)?)?;
    m.add_function(wrap_pyfunction!(models::model_facts, m)?)?;
    m.add_function(wrap_pyfunction!(models::fit_options, m)?)?;
    m.add_function(wrap_pyfunction!(models::texel_arrays, m)?)?;
    m.add_function(wrap_pyfunction!(blockwise::blockwise_plan, m)?)?;
    m.add_function(wrap_pyfunction!(blockwise::finish_blocks, m)?)?;
    m.add_function(wrap_pyfunction!(blockwise::robust_sample_texels, m)?)?;
    m.add_function(wrap_pyfunction!(blockwise::robust_images, m)?)?;
    m.add_function(wrap_pyfunction!(blockwise::robust_screen_block, m)?)?;
    m.add_function(wrap_pyfunction!(blockwise::robust_report, m)?)?;
    m.add_function(wrap_pyfunction!(blockwise::robust_moved, m)?)?;
    m.add_function(wrap_pyfunction!(blockwise::robust_patch_window, m)?)?;
    m.add_function(wrap_pyfunction!(blockwise::srf_sums, m)?)?;
    m.add_function(wrap_pyfunction!(blockwise::srf_phong, m)?)?;
    m.add_function(wrap_pyfunction!(blockwise::srf_residual, m)?)?;
    m.add_function(wrap_pyfunction!(blockwise::lpca_sample, m)?)?;
    m.add_function(wrap_pyfunction!(blockwise::lpca_subspace, m)?)?;
    m.add_function(wrap_pyfunction!(blockwise::lpca_project, m)?)?;
    m.add_function(wrap_pyfunction!(blockwise::lpca_cluster, m)?)?;
    m.add_function(wrap_pyfunction!(blockwise::lpca_fit_cluster, m)?)?;
    m.add_function(wrap_pyfunction!(blockwise::lpca_assemble, m)?)?;
    m.add_function(wrap_pyfunction!(blockwise::light_pca_check, m)?)?;
    m.add_function(wrap_pyfunction!(blockwise::light_pca_moments, m)?)?;
    m.add_function(wrap_pyfunction!(blockwise::light_pca_merge, m)?)?;
    m.add_function(wrap_pyfunction!(blockwise::light_pca_table, m)?)?;
    m.add_function(wrap_pyfunction!(blockwise::light_pca_project, m)?)?;
    m.add_function(wrap_pyfunction!(blockwise::light_pca_assemble, m)?)?;
    m.add_function(wrap_pyfunction!(io::save_container, m)?)?;
    m.add_function(wrap_pyfunction!(io::read_container_header, m)?)?;
    m.add_class::<io::ModelFormat>()?;
    m.add_function(wrap_pyfunction!(io::model_formats, m)?)?;
    m.add_function(wrap_pyfunction!(io::export_model, m)?)?;
    m.add_function(wrap_pyfunction!(io::import_model, m)?)?;
    m.add_function(wrap_pyfunction!(io::export_tiled, m)?)?;
    m.add_function(wrap_pyfunction!(io::plane_images, m)?)?;
    m.add_function(wrap_pyfunction!(io::model_with_planes, m)?)?;
    m.add_function(wrap_pyfunction!(io::write_png, m)?)?;
    m.add_function(wrap_pyfunction!(io::read_png, m)?)?;
    m.add_function(wrap_pyfunction!(io::write_exr, m)?)?;
    m.add_function(wrap_pyfunction!(io::read_exr, m)?)?;
    m.add_function(wrap_pyfunction!(io::load_capture, m)?)?;
    m.add_function(wrap_pyfunction!(io::write_exr_channels, m)?)?;
    m.add_function(wrap_pyfunction!(io::write_png16, m)?)?;
    m.add_function(wrap_pyfunction!(calibrate::calibrate_sphere, m)?)?;
    m.add_function(wrap_pyfunction!(calibrate::write_lp, m)?)?;
    m.add_class::<render::PyScene>()?;
    m.add_class::<render::PyCamera>()?;
    m.add_class::<render::PyGpuModel>()?;
    m.add_function(wrap_pyfunction!(render::gpu_info, m)?)?;
    m.add_function(wrap_pyfunction!(render::gpu_upload_raw, m)?)?;
    m.add_function(wrap_pyfunction!(render::gpu_render, m)?)?;
    m.add_function(wrap_pyfunction!(render::cpu_render_raw, m)?)?;
    m.add_function(wrap_pyfunction!(render::gpu_upload_model, m)?)?;
    m.add_function(wrap_pyfunction!(render::web_model, m)?)?;
    m.add_function(wrap_pyfunction!(render::web_layout, m)?)?;
    m.add_function(wrap_pyfunction!(render::web_window, m)?)?;
    m.add_function(wrap_pyfunction!(render::web_map, m)?)?;
    m.add_function(wrap_pyfunction!(render::cpu_render_model, m)?)?;
    m.add_function(wrap_pyfunction!(render::env_check, m)?)?;
    m.add_function(wrap_pyfunction!(render::env_sky, m)?)?;
    m.add_function(wrap_pyfunction!(render::env_sample, m)?)?;
    m.add_function(wrap_pyfunction!(render::env_quadrature, m)?)?;
    m.add_function(wrap_pyfunction!(render::env_sh, m)?)?;
    m.add_function(wrap_pyfunction!(render::render_env_sh, m)?)?;
    m.add_class::<render::PyMipChain>()?;
    m.add_function(wrap_pyfunction!(render::filter_signature, m)?)?;
    m.add_function(wrap_pyfunction!(render::filter_build, m)?)?;
    m.add_function(wrap_pyfunction!(render::mip_model, m)?)?;
    m.add_function(wrap_pyfunction!(render::scene_directions, m)?)?;
    m.add_function(wrap_pyfunction!(graphcut::min_cut_native, m)?)?;
    m.add_function(wrap_pyfunction!(graphcut::grid_min_cut_native, m)?)?;
    m.add_function(wrap_pyfunction!(tiles::wang_model_features, m)?)?;
    m.add_function(wrap_pyfunction!(tiles::wang_synthesize, m)?)?;
    m.add_function(wrap_pyfunction!(tiles::wang_tiling, m)?)?;
    m.add_function(wrap_pyfunction!(tiles::wang_check, m)?)?;
    m.add_function(wrap_pyfunction!(tiles::wang_atlas_positions, m)?)?;
    m.add_function(wrap_pyfunction!(tiles::wang_seam_errors, m)?)?;
    m.add_function(wrap_pyfunction!(tiles::wang_random_crops, m)?)?;
    m.add_class::<synth::PyAnalysis>()?;
    m.add_function(wrap_pyfunction!(synth::analyse_btf_native, m)?)?;
    m.add_function(wrap_pyfunction!(synth::analyse_features_native, m)?)?;
    m.add_function(wrap_pyfunction!(synth::texture_names, m)?)?;
    m.add_function(wrap_pyfunction!(synth::make_texture, m)?)?;
    Ok(())
}
