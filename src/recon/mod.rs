//! Reconstruction: from a coded acquisition back to the hyperspectral cube.
//!
//! Data flow: **operator** ([`operator`]: the linear map Φ from an H×W×B cube to a detector image, and its
//! adjoint Φᵀ) → **solver** (iterative, sees only an [`operator::Operator`]) → **metrics** (the field's
//! RMSE / PSNR / SSIM / SAM). The operator/solver split follows solver libraries: an operator knows apply
//! and adjoint; a solver knows only operators.
pub mod metrics;
pub mod operator;

pub use metrics::{evaluate, Evaluation, Metrics};
pub use operator::{CubeShape, ImageShape, Operator};
