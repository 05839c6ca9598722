//! btfrs-io: everything that touches files.
//!
//! * [`container`]: the `.btfrs` file for BTFs and fitted models (JSON header + aligned raw arrays).
//! * [`model_file`]: any registered model saved to and loaded from a container.
//! * [`ptm_file`]: `PTM_1.2` files (Malzbender et al. 2001) as RTIViewer and relight read them.
//! * [`neuralrti_file`]: NeuralRTI's web format (`info.json` + latent plane images), as OpenLIME reads it.
//! * [`gltf_file`]: glTF 2.0 assets (a textured plane, metallic-roughness + `KHR_materials_specular`) of `svbrdf` models.
//! * [`mitsuba_file`]: Mitsuba 3 scenes (XML + EXR maps) of `svbrdf` models, its BSDFs matching the model's lobe exactly.
//! * [`rti_file`]: `.rti` hemispherical-harmonics files (`#HSH1.2`, RTI type 3), relight's reading.
//! * [`image`]: PNG and OpenEXR images (rendered or measured), multi-channel EXR coefficient maps.
//! * [`decode`]: photographs (JPEG, PNG, TIFF; 8 or 16 bit) and EXR decoded to linear RGB.
//! * [`stack`]: image stacks (folder or zip) decoded in parallel into the texel-major layout; CSV/JSON direction tables.
//! * [`ubo2003`]: Bonn UBO2003 / ATRIUM archives (angles in the file names).
//! * [`rti`]: RTI capture sets (`.lp` light files).
//! * [`ubo2014`]: UBO2014 `.btf` files (Bonn's DFMF binary) read as a capture, and written.
//! * [`capture`]: what the loaders of measured data share (selection, the capture plan, decoding into a texel-major buffer).
//! * [`atomic`]: every writer goes through a temporary file and a rename.
//! * [`untrusted`]: the reading discipline of every reader (regular files only, size caps, UTF-8,
//!   bounded parses, declared sizes checked before allocation, repairs reported).

pub mod atomic;
pub mod capture;
pub mod container;
pub mod decode;
pub mod formats;
pub mod gltf_file;
pub mod image;
pub mod mitsuba_file;
pub mod model_file;
pub mod neuralrti_file;
pub mod ptm_file;
pub mod relight_file;
pub mod rti;
pub mod rti_file;
pub mod stack;
pub mod ubo2003;
pub mod ubo2014;
pub mod untrusted;
