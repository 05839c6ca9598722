//! btfrs-fit: compact per-texel reflectance models fitted to a BTF.
//!
//! * [`ptm`]: Polynomial Texture Maps, RGB and LRGB, one per view slot (paper 000, section 3.1).
//! * [`hsh`]: hemispherical harmonics (Gautron et al. 2004) of order 1 to 4 per view slot, the
//!   basis of RTIViewer's and relight's `.rti` HSH files, stored as 8-bit planes.
//! * [`lightfit`]: what PTM and HSH share: the per-slot light fit, its fallbacks, the storage.
//! * [`lafortune`]: per-texel Lafortune lobes over all views, RGB and luminance, fitted by
//!   Levenberg-Marquardt (paper 000, section 3.2).
//! * [`lafortune::per_view`]: per-view Lafortune (`"lafortune_view"`), one lobe set per texel and
//!   view slot, blended between slots like the PTM (paper 000, section 3.2).
//! * [`srf`]: Phong + spatially-varying residual function (paper 003, sections 4 and 5).
//! * [`sh`]: double spherical harmonics fitted by constrained least squares, 8-bit quantized
//!   (paper 002, section 3.1 and appendix).
//! * [`lpca`]: local PCA, clustered Eigen-BRDFs quantized to 8 bits (paper 004, sections 3 and 6).
//! * [`rbf`] and [`bilinear`]: relight's RTI light bases (Gaussian RBF interpolation, a
//!   bilinear light grid) per view slot, resampled on a light grid and compressed by PCA into
//!   8-bit planes ([`light_pca`]).
//! * [`light_bases`]: RBF and bilinear by name, for the blockwise fit of their stages.
//! * [`neural`]: per-texel latent codes and one decoder MLP, trained on the CPU as an
//!   auto-decoder (Rainer et al. 2019, NeuMIP 2021; NeuralRTI 2020 for single-view captures).
//! * [`svbrdf`]: a spatially varying GGX BRDF per texel (diffuse, specular, roughness, normal)
//!   fitted by Levenberg-Marquardt from photometric-stereo normals; exported to glTF and Mitsuba.
//! * [`photometric`]: photometric stereo (Woodham 1980), L2 and robust (IRLS): per-texel normals
//!   and Lambertian albedo of one view slot.
//! * [`relief`]: a sample's relief for models that draw its cast shadows: the height from
//!   photometric stereo and the horizon map (Max 1988) the neural decoder reads.
//! * [`runs`]: a sample of texels as short runs spread over the frame, what large captures
//!   train the neural decoder on and take the light bases' principal functions from.
//! * [`planes`]: 8-bit coefficient planes with per-plane scale and bias (what RTI viewers hold).
//! * [`eval`]: evaluation ([`ReflectanceModel`], [`Shade`]), what the model contract and its GPU
//!   half share.
//! * [`model`]: the model contract ([`Model`]): fit, evaluation at any (view, light), error
//!   against a BTF (parallel, f64 accumulation), named arrays, bytes, abilities.
//! * [`gpu`]: the GPU half of the contract: shader, parameter struct ([`gpu_params!`]), store.
//! * [`options`]: the option schema each model declares, and the checks made from it.
//! * [`registry`]: the list of models every consumer iterates over.
//! * [`robust`]: the screen for outlying values and bad images, which the models that judge
//!   each texel in their own pass (PTM, HSH) run too.
//! * [`driver`]: the fit every caller runs through the registry: the robust screen, then the
//!   model's fit on the repaired values.
//! * the general numerics (dense products, CLS, k-means, exact and randomized PCA, Poisson
//!   integration) are in `btfrs-numerics`.
//! * [`blockwise`]: how each fit splits over texel blocks fitted apart (`btfrs.dask`).

pub mod bilinear;
pub mod blockwise;
pub mod driver;
pub mod eval;
pub mod gpu;
pub mod hsh;
pub mod lafortune;
pub mod light_bases;
pub mod light_pca;
pub mod lightfit;
pub mod lpca;
pub mod model;
pub mod neural;
pub mod options;
pub mod photometric;
pub mod planes;
pub mod ptm;
pub mod rbf;
pub mod registry;
pub mod relief;
pub mod robust;
pub mod runs;
pub mod sh;
mod simd;
pub mod srf;
pub mod svbrdf;

pub use bilinear::{fit_bilinear, Bilinear, BilinearOptions};
pub use eval::{ReflectanceModel, Shade};
pub use gpu::{GpuLayout, GpuModel, Renderable};
pub use hsh::{fit_hsh, hsh_basis, Hsh, HshOptions, HshSlot};
pub use lafortune::per_view::{fit_lafortune_view, LafortuneView, LafortuneViewOptions, LafortuneViewReport};
pub use lafortune::{fit_lafortune, FitReport, Lafortune, LafortuneKind, LafortuneOptions};
pub use light_pca::{Colour, LightPca};
pub use lpca::{fit_lpca, Lpca, Lpca3d, LpcaOptions, LpcaQuery};
pub use model::{evaluate_image, model_error, DynModel, Model, RawModel};
pub use ptm::{fit_ptm, Degenerate, Ptm, PtmKind, PtmOptions, PtmPlanes, PtmSlot};
pub use rbf::{fit_rbf, Rbf, RbfOptions};
pub use sh::{fit_sh, quantize, sh_basis, Sh, ShCoeffs, ShOptions};
pub use srf::{fit_srf, Phong, Srf, SrfReport};
