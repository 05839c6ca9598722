//! btfrs-core: the data model every other btfrs crate shares.
//!
//! * [`Btf`] / [`BtfRef`]: a measured (or generated) Bidirectional Texture Function stored
//!   texel-major, `[H, W, V, L, 3]` float32 linear RGB, with its view and light directions and an
//!   optional mask of which (view, light) pairs are present (a train/test split is two masks over
//!   the same data, see [`split::split_pairs`]).
//! * [`directions`]: the UBO 2003 81-direction set of the Bonn BTF database and (theta, phi) <->
//!   vector conversions in the local tangent frame (z = normal, x = the sample's u axis).
//! * [`metrics`]: RMSE, relative L2 error and PSNR with f64 accumulation.
//! * [`materials`]: procedural BTFs (periodic heightfields with cast shadows and masking) used as
//!   the built-in material of the demo and the tests.
//! * [`monitor`]: progress counting and cancellation for long work.
//! * [`arrays`]: named, typed arrays: how models and analyses describe themselves for saving.
//! * [`process`]: the thread pool (and other per-process state) made afresh in a forked child.
//! * [`Error`]: the error enum that the Python layer maps onto exception classes.

pub mod arrays;
pub mod btf;
pub mod directions;
mod error;
pub mod materials;
pub mod metrics;
pub mod monitor;
pub mod process;
pub mod rng;
pub mod scratch;
pub mod split;

pub use arrays::NamedArrays;
pub use btf::{Btf, BtfRef};
pub use error::{Detail, Error, Result};
pub use monitor::Monitor;
