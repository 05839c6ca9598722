//! The light-PCA models by name: which of RBF ([`crate::rbf`]) and bilinear ([`crate::bilinear`])
//! a blockwise fit of the `light_pca` protocol drives ([`crate::light_pca::staged`]), with its
//! options, its plan and the model its stages assemble. Apart from [`crate::light_pca`], which
//! both models build on and which therefore names neither.

use crate::bilinear::{self, BilinearOptions};
use crate::light_pca::{exact_dim, LightPca, PcaOptions, Plan, EXACT_PCA_DIM};
use crate::model::Model;
use crate::options::{self, Values};
use crate::rbf::{self, RbfOptions};
use btfrs_core::{ensure_arg, Error, Result};

/// Which light-PCA model, with its options.
#[derive(Debug, Clone, Copy)]
pub enum Basis {
    /// [`crate::rbf::Rbf`].
    Rbf(RbfOptions),
    /// [`crate::bilinear::Bilinear`].
    Bilinear(BilinearOptions),
}

impl Basis {
    /// Model `kind` (`"rbf"` or `"bilinear"`) with its options (as the fit takes them), checked.
    pub fn parse(kind: &str, values: &Values) -> Result<Basis> {
        let b = match kind {
            "rbf" => Basis::Rbf(options::build(<rbf::Rbf as Model>::OPTIONS, values.clone())?),
            "bilinear" => Basis::Bilinear(options::build(<bilinear::Bilinear as Model>::OPTIONS, values.clone())?),
            other => {
                return Err(Error::arg(
                    "kind",
                    format!("expected \"rbf\" or \"bilinear\" (a light-PCA model), got {other:?}"),
                ))
            }
        };
        b.options()?;
        Ok(b)
    }

    /// The model's name.
    pub fn kind(&self) -> &'static str {
        match self {
            Basis::Rbf(_) => "rbf",
            Basis::Bilinear(_) => "bilinear",
        }
    }

    /// The light-PCA options (checked as the fit checks them).
    pub fn options(&self) -> Result<PcaOptions> {
        Ok(match self {
            Basis::Rbf(o) => rbf::prepare(o)?.0,
            Basis::Bilinear(o) => bilinear::prepare(o, &[])?.0,
        })
    }

    /// Stage 1: the plan of every slot for these directions and mask (the local fit's), checked
    /// against the blockwise limit on the eigenproblems (module doc).
    pub fn plan(&self, views: &[[f64; 3]], lights: &[[f64; 3]], mask: Option<&[bool]>) -> Result<Plan> {
        let plan = match self {
            Basis::Rbf(o) => {
                let (p, op) = rbf::prepare(o)?;
                Plan::new(views, lights, mask, p.resolution, &*op, "rbf")?
            }
            Basis::Bilinear(o) => {
                let (p, op) = bilinear::prepare(o, lights)?;
                Plan::new(views, lights, mask, p.resolution, &*op, "bilinear")?
            }
        };
        let o = self.options()?;
        let (m, e) = (plan.max_pairs(), exact_dim(&o, plan.max_pairs()));
        ensure_arg!(
            e <= EXACT_PCA_DIM,
            "resolution",
            "the blockwise {} fit solves an exact {e} x {e} eigenproblem per view slot (the smaller of the values per \
             vector at resolution {} and 3 x {m} samples), more than the {EXACT_PCA_DIM} it supports: use a lower \
             resolution or fewer lights per view, or fit it on one machine (btfrs.fit.{}(btf, memory_limit=...))",
            self.kind(),
            o.resolution,
            self.kind()
        );
        Ok(plan)
    }

    /// Wrap the fitted light basis as the model.
    pub fn model(&self, m: LightPca) -> Box<dyn crate::model::DynModel> {
        match self {
            Basis::Rbf(_) => Box::new(rbf::Rbf(m)),
            Basis::Bilinear(_) => Box::new(bilinear::Bilinear(m)),
        }
    }
}
