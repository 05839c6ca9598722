//! btfrs-numerics: the general numerics the fits and the synthesis share, in one place with no
//! knowledge of BTF models.
//!
//! * [`dense`]: column- and row-major views, GEMM over rayon (nalgebra's `matrixmultiply`),
//!   small symmetric eigenproblems in `f64`, orthonormalization.
//! * [`cls`]: constrained least squares (paper 002, appendix): energy-bounded solutions by
//!   a safeguarded Newton iteration on the Lagrange multiplier.
//! * [`mod@kmeans`]: k-means++ seeding and Lloyd iterations on column-major points.
//! * [`pca`]: centred PCA of a set of vectors, exact (eigenvectors of the covariance or of the
//!   Gram matrix) up to a given size, randomized above.
//! * [`rpca`]: randomized PCA (Halko et al.'s range finder), streamed through chunks when
//!   memory is limited; principal coordinates of texels.
//! * [`poisson`]: surfaces from their slopes (Frankot and Chellappa 1988), periodic or mirrored.

pub mod cls;
pub mod dense;
pub mod kmeans;
pub mod pca;
pub mod poisson;
pub mod rpca;

pub use kmeans::{kmeans, KMeans};
pub use rpca::principal_coordinates;
