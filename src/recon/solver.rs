//! The solver dispatcher: [`reconstruct`] (and [`reconstruct_with`], [`reconstruct_estimated`]) runs GAP
//! ([`super::gap::gap`]: `gap-tv`, `pnp-gap`) or ADMM ([`super::admm::admm`]: `admm-tv`, `pnp-admm`) with the
//! prior [`config_denoiser`] names. It sits above the solvers in the import graph: the settings, record,
//! stopping rules and shared run bookkeeping they import live in [`super::solve`] and are re-exported here,
//! so `recon::solver::SolverConfig` and the rest keep their paths. Solvers see only a `&dyn` [`Operator`].
//!
//! ```
//! use diffcassi::recon::{solver::{reconstruct, SolverConfig}, shift::ShiftOperator, CubeShape, ImageShape, Operator};
//! use diffcassi::render::Mask;
//! let shape = CubeShape { height: 16, width: 16, bands: 4 };
//! let op = ShiftOperator::new(shape, ImageShape { height: 16, width: 22 }, &Mask::random(16, 16, 0.5, 1)?,
//!                             0, vec![0, 2, 4, 6], 1, 1)?;
//! let truth = vec![0.5f32; shape.len()];
//! let y = (&op as &dyn Operator).apply(&truth)?;
//! let mut cfg = SolverConfig::gap_tv();
//! cfg.iterations = 20;
//! let rec = reconstruct(&op, &y, None, &cfg, &|_, _| {})?;
//! assert_eq!(rec.residuals.len(), 20);
//! assert!(rec.final_residual < rec.residuals[0]);
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::operator::Operator;
use super::prior::{network::SpectralUNet, tv::TvDenoiser, Denoiser};
use super::solve::run::Problem;
use crate::error::Result;

pub use super::solve::config::{
    SettingScope, SolverConfig, SolverKind, ADMM_TV_DISCREPANCY, MAX_DISCREPANCY, ADMM_TV_ITERATIONS, GAP_TV_DISCREPANCY, GAP_TV_ITERATIONS, PNP_ACCELERATED, PNP_DISCREPANCY, PNP_EQUIVARIANT, PNP_ITERATIONS, PNP_NETWORK_ITERATIONS, PNP_SIGMA_GAIN,
    PNP_SIGMA_MAX, PNP_SIGMA_MIN, PNP_TOLERANCE, PNP_TV_DISCREPANCY, PNP_TV_WARMUP, SOLVER_NAMES,
};
pub use super::solve::data_term::{Preconditioner, D_GUARD};
pub use super::solve::noise::{monte_carlo_noise_norm, MonteCarloSpread, MC_MISMATCH_PER_RAY, SPREAD_EVERY};
pub use super::solve::prior_step::{denoise_at_network_scale, denoise_at_network_scale_transformed, sigma_schedule, NetworkScale, PNP_SCALE_GAIN, PNP_SCALE_QUANTILE};
pub use super::solve::record::Reconstruction;
pub use super::solve::stopping::Discrepancy;

/// The denoiser `config` names: TV with its weight/iterations/coupling for the TV solvers, the learned
/// network for PnP (the embedded Gaussian weights, or `config.denoiser`'s file of either stage:
/// [`SpectralUNet::load_pnp`]).
pub fn config_denoiser(config: &SolverConfig) -> Result<Box<dyn Denoiser>> {
    if config.solver.is_pnp() {
        Ok(Box::new(SpectralUNet::load_pnp(config.denoiser.as_deref().map(std::path::Path::new))?))
    } else {
        Ok(Box::new(TvDenoiser::new(config.tv_weight, config.tv_iterations, config.tv_coupling)))
    }
}

/// Reconstruct the cube from measurement `y` with the configured solver. `init` is the starting cube
/// (default 0, so the first GAP step is λΦᵀD⁻¹y); `progress(k, residual)` is called after each iteration k
/// (1-based) with its relative residual. The prior is [`config_denoiser`]'s.
pub fn reconstruct(op: &dyn Operator, y: &[f32], init: Option<&[f32]>, config: &SolverConfig, progress: &(dyn Fn(usize, f64) + Sync)) -> Result<Reconstruction> {
    config.validate()?;
    let mut denoiser = config_denoiser(config)?;
    reconstruct_with(op, y, init, config, denoiser.as_mut(), progress)
}

/// [`reconstruct`] with any [`Denoiser`] as the prior (GAP's or ADMM's data step per `config.solver`; PnP
/// kinds scale the cube to peak 1 around the denoiser and follow the σ schedule).
pub fn reconstruct_with(op: &dyn Operator, y: &[f32], init: Option<&[f32]>, config: &SolverConfig, denoiser: &mut dyn Denoiser, progress: &(dyn Fn(usize, f64) + Sync)) -> Result<Reconstruction> {
    reconstruct_estimated(op, y, init, config, denoiser, progress, &mut |_, _| {}, None)
}

/// [`reconstruct_with`] with an observer `observe(k, θ_k)` called after each prior step (evaluation against a known
/// truth, e.g. `reconstruct --truth`; nothing it computes reaches the solver) and δ estimated from the data during
/// the run ([`MonteCarloSpread`]: the exact operator's Monte-Carlo spread at the iterate) instead of the fixed
/// `config.noise_norm` (its start value).
#[allow(clippy::too_many_arguments)]
pub fn reconstruct_estimated(
    op: &dyn Operator,
    y: &[f32],
    init: Option<&[f32]>,
    config: &SolverConfig,
    denoiser: &mut dyn Denoiser,
    progress: &(dyn Fn(usize, f64) + Sync),
    observe: &mut dyn FnMut(usize, &[f32]),
    spread: Option<&MonteCarloSpread<'_>>,
) -> Result<Reconstruction> {
    solve_problem(Problem { op, y, init, config, progress, observe, spread, cancel: None }, denoiser)
}

/// The solve of a [`Problem`] (GAP's or ADMM's data step per `config.solver`, `denoiser` the prior): what
/// [`reconstruct_estimated`] runs, and with the problem's `cancel` a solve that stops at the next iteration
/// once cancelled ([`crate::Error::Interrupted`]; [`crate::recon::pipeline::run_solver`]'s `cancel`).
pub fn solve_problem(problem: Problem<'_>, denoiser: &mut dyn Denoiser) -> Result<Reconstruction> {
    let (op, config) = (problem.op, problem.config);
    if let Some(s) = problem.spread {
        s.check(op)?;
    }
    if config.solver.is_gap() {
        super::gap::gap(problem, denoiser)
    } else {
        super::admm::admm(problem, denoiser)
    }
}
