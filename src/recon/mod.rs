//! Reconstruction: from a coded acquisition back to the hyperspectral cube.
//!
//! Data flow: **operator** ([`operator`]: the linear map Φ from an H×W×B cube to a detector image, and its
//! adjoint Φᵀ) → **solver** (iterative, sees only an [`operator::Operator`]) → **metrics** (the field's
//! RMSE / PSNR / SSIM / SAM). The operator/solver split follows solver libraries: an operator knows apply
//! and adjoint; a solver knows only operators.
//!
//! Operators: [`exact::ExactOperator`] (the renderer's own light transport), [`mapping::MappingOperator`]
//! (the paper's chief-ray mapping, nearest or bilinear, and its initialisation I = A ∘ f),
//! [`shift::ShiftOperator`] (the field's simplified SD-CASSI model). Solvers: [`gap::gap_tv`] (GAP-TV,
//! plain or accelerated) and [`admm::admm_tv`] (ADMM-TV), both through [`solver::reconstruct`] with a
//! [`solver::SolverConfig`]; TV denoising by Chambolle's projection in [`tv`]. See docs/reconstruction.md.
pub mod admm;
pub mod exact;
pub mod gap;
pub mod layout;
pub mod mapping;
pub mod metrics;
pub mod operator;
pub mod shift;
pub mod solver;
pub mod tv;

pub use exact::ExactOperator;
pub use mapping::{MappingInterpolation, MappingOperator};
pub use metrics::{evaluate, Evaluation, Metrics};
pub use shift::ShiftOperator;
pub use solver::{reconstruct, Reconstruction, SolverConfig, SolverKind};
pub use tv::TvCoupling;
pub use operator::{CubeShape, ImageShape, Operator};
