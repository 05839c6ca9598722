//! btfrs-io: everything that touches files.
//!
//! * [`container`]: the `.btfrs` file for BTFs and fitted models (JSON header + aligned raw arrays).
//! * [`model_file`]: any registered model saved to and loaded from a container.
//! * [`ptm_file`]: `PTM_1.2` files (Malzbender et al. 2001) as RTIViewer and relight read them.
//! * [`rti_file`]: `.rti` hemispherical-harmonics files (`#HSH1.2`, RTI type 3), relight's reading.
//! * [`image`]: PNG output of rendered or measured images.
//! * [`capture`]: what the loaders of measured data share (selection, the capture plan, decoding into a texel-major buffer).
//! * [`atomic`]: every writer goes through a temporary file and a rename.

pub mod atomic;
pub mod capture;
pub mod container;
pub mod image;
pub mod model_file;
pub mod ptm_file;
pub mod rti_file;
