//! Reconstruction: from a coded acquisition back to the hyperspectral cube.
//!
//! Data flow: **operator** ([`operator`]: the linear map Φ from an H×W×B cube to a detector image, and its
//! adjoint Φᵀ) → **solver** (iterative, sees only an [`operator::Operator`]) → **metrics** (the field's
//! RMSE / PSNR / SSIM / SAM). The operator/solver split follows solver libraries: an operator knows apply
//! and adjoint; a solver knows only operators.
//!
//! Operators: [`exact::ExactOperator`] (the renderer's own light transport), [`mapping::MappingOperator`]
//! (the paper's chief-ray mapping, nearest or bilinear, and its initialisation I = A ∘ f),
//! [`shift::ShiftOperator`] (the field's simplified SD-CASSI model). Solvers: [`gap::gap`] (GAP-TV,
//! plain or accelerated) and [`admm::admm`] (ADMM-TV), both through the dispatcher [`solver::reconstruct`]
//! with a [`solver::SolverConfig`]; TV denoising by Chambolle's projection in [`tv`]. Priors are denoisers
//! ([`prior::Denoiser`]: TV, or the learned [`prior::network::SpectralUNet`]); the plug-and-play solvers
//! `pnp-gap` / `pnp-admm` (the same [`gap::gap`], [`admm::admm`] with the network and a σ schedule) plug the
//! learned one into the same data steps. The unrolled network ([`unrolled::unrolled`], arch `unrolled-gap-v1`:
//! K GAP stages with learned steps and per-stage denoisers, [`prior::unrolled::UnrolledNetwork`], trained in
//! PyTorch by `scripts/train_unrolled.py`) is a fixed-cost forward pass through the same operator. What the solvers share (settings, record, stopping rules, prior
//! step, preconditioner) is in [`solve`], below them: imports in src/recon form no circle
//! (`scripts/check_import_cycles.py`). The command-line pipeline (render record → operator → noise estimate
//! → solver settings → solve → record) is [`pipeline`]. See docs/reconstruction.md.
//!
//! Public API (stable):
//! - `ExactOperator::new(renderer: Renderer<'a>, bands_nm: &[f64], memory_budget_bytes: u64) -> Result<Self>`
//!   (and `with_progress(.., progress: &(dyn Fn(u64) + Sync))`), `.renderer()`, `.bands_nm()`,
//!   `.is_streaming()`, `.transport_bytes()`;
//! - `MappingOperator::new(&MappingCube, &Detector, &Mask, MappingInterpolation) -> Result<Self>`,
//!   `MappingOperator::from_renderer(&Renderer, bands_nm, MappingInterpolation)`,
//!   `.initialisation(acquisition: &[f32]) -> Result<Vec<f32>>`; `mapping::nearest_pixel`;
//! - `ShiftOperator::new(CubeShape, ImageShape, &Mask, row0, columns, sigma_x, sigma_y) -> Result<Self>`,
//!   `ShiftOperator::from_renderer(&Renderer, bands_nm)`, `.shifts_px()`, `.placement()`;
//! - `reconstruct(op: &dyn Operator, y: &[f32], init: Option<&[f32]>, &SolverConfig,
//!   progress: &(dyn Fn(usize, f64) + Sync)) -> Result<Reconstruction>`; `SolverConfig::{gap_tv, admm_tv,
//!   for_solver, validate}`, `SolverKind: FromStr` (`gap-tv`, `admm-tv`, `pnp-gap`, `pnp-admm`);
//!   `Reconstruction` (serde); `reconstruct_with(.., denoiser: &mut dyn Denoiser, ..)`;
//!   `SpectralUNet::{embedded, from_file, load}`, `Denoiser::denoise(x, out, shape, sigma)`.
//!
//! ```
//! use diffcassi::prelude::*;
//! use diffcassi::recon::{reconstruct, ExactOperator, Operator, SolverConfig};
//! use diffcassi::render::{Mask, RenderConfig, Renderer, SpectralSampling};
//! use diffcassi::scene::synthetic_scene;
//! let system = SequentialSystem::build(&presets::spec("ap")?)?;
//! let tracer = AnalyticTracer::default();
//! let bands = vec![480.0, 520.0, 560.0];
//! let mut cfg = RenderConfig::paper(12);
//! cfg.spectral = SpectralSampling::new(bands.clone(), 2)?;
//! cfg.rays_per_pixel = 4;
//! let renderer = Renderer::new(&system, &tracer, cfg, Mask::random(12, 12, 0.5, 1)?)?;
//! let truth = synthetic_scene(12, 12, &bands, 2);
//! let y = renderer.render(&truth, false, &|_| {})?.image_f32();
//! let phi = ExactOperator::new(renderer, &bands, 1 << 30)?; // same seed: the oracle
//! let rec = reconstruct(&phi, &y, None, &SolverConfig { iterations: 20, ..SolverConfig::gap_tv() }, &|_, _| {})?;
//! assert_eq!(rec.cube.len(), 12 * 12 * 3);
//! assert!(rec.final_residual < rec.residuals[0]);
//! # Ok::<(), diffcassi::Error>(())
//! ```
pub mod admm;
pub mod compact;
pub mod exact;
pub mod gap;
pub mod layout;
pub mod mapping;
pub mod metrics;
pub mod operator;
pub mod pipeline;
pub mod prior;
pub mod shift;
pub mod solve;
pub mod solver;
pub mod sparse;
pub mod tv;
pub mod unrolled;

pub use exact::ExactOperator;
pub use mapping::{MappingInterpolation, MappingOperator};
pub use metrics::{evaluate, Evaluation, Metrics};
pub use prior::{network::SpectralUNet, tv::TvDenoiser, Denoiser};
pub use solve::run::Problem;
pub use solver::{reconstruct, reconstruct_estimated, reconstruct_with, solve_problem, MonteCarloSpread, Reconstruction, SolverConfig, SolverKind};
pub use tv::TvCoupling;
pub use operator::{CubeShape, ImageShape, Operator};
pub use shift::ShiftOperator;
pub use sparse::{CsrMatrix, SparseExport};
