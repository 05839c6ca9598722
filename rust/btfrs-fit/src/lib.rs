//! btfrs-fit: compact per-texel reflectance models fitted to a BTF.
//!
//! * [`ptm`]: Polynomial Texture Maps, RGB and LRGB, one per view slot (paper 000, section 3.1).
//! * [`lpca`]: local PCA, clustered Eigen-BRDFs quantized to 8 bits (paper 004, sections 3 and 6).
//! * [`mod@kmeans`]: k-means++ and Lloyd on column-major points (the clustering of [`lpca`]).
//! * [`model`]: what every model shares: evaluation at any (view, light) and the error against a
//!   BTF, computed in parallel with f64 accumulation.

mod dense;
pub mod kmeans;
pub mod lpca;
pub mod model;
pub mod ptm;

pub use kmeans::{kmeans, KMeans};
pub use lpca::{fit_lpca, Lpca, LpcaOptions, LpcaQuery};
pub use model::{evaluate_image, model_error, RawModel, ReflectanceModel};
pub use ptm::{fit_ptm, Degenerate, Ptm, PtmKind, PtmOptions};
