//! GAP-TV: generalized alternating projection with total-variation denoising (X. Yuan, "Generalized
//! alternating projection based total variation minimization for compressive sensing", ICIP 2016), with the
//! accelerated variant (X. Liao, H. Li, L. Carin, "Generalized alternating projection for weighted-ℓ2,1
//! minimization with applications to model-based compressive sensing", SIAM J. Imaging Sci. 2014), as the
//! MST/DeSCI codes run it, preconditioned by D = diag(ΦΦᵀ𝟙) ([`super::solve::data_term`]). From θ₀ (0 or `init`),
//! ỹ₀ = 0, for k = 1…K:
//!
//! - plain:        x_k = θ_{k−1} + λ Φᵀ D⁻¹ (y − Φθ_{k−1})
//! - accelerated:  ỹ_k = ỹ_{k−1} + (y − Φθ_{k−1});  x_k = θ_{k−1} + λ Φᵀ D⁻¹ (ỹ_k − Φθ_{k−1})
//! - θ_k = TV-denoise(x_k) (Chambolle, [`super::tv`]; skipped when the TV weight is 0) — or any
//!   [`Denoiser`] D(x_k, σ_k): PnP-GAP (`pnp-gap`) plugs in the learned network with the decreasing σ
//!   schedule of [`super::solve::prior_step::sigma_schedule`], the cube scaled to peak 1 around D.
//! - optional stops: the discrepancy principle ‖y − Φθ_{k−1}‖₂ ≤ τ·δ (δ the expected norm of the
//!   measurement's noise, [`super::solve::stopping::Discrepancy`]: fixed, or re-estimated from the data every
//!   few iterations by the request's [`MonteCarloSpread`](super::solve::noise::MonteCarloSpread); θ_{k−1} is
//!   returned), or
//!   ‖θ_k − θ_{k−1}‖₂ / ‖θ_k‖₂ < `tolerance` (the record says which rule ended the run).
//!
//! Cost per iteration: one Φ, one Φᵀ, one TV denoising. Memory: 6 cube-sized f32 buffers (θ, x, and the
//! TV's p₁, p₂ and their next iterate) plus 3 image-sized ones (ỹ, Φθ, D⁻¹); at 512×512×28 that is 6 × 29.4 MB = 176 MB,
//! the operator's own buffers apart (+1 with a tolerance: θ_{k−1}; PnP: θ, x, the scaled copy and the
//! network's activations instead of the TV's four).
//!
//! ```
//! use diffcassi::recon::{gap::gap, solve::run::Problem, solver::SolverConfig, shift::ShiftOperator, CubeShape, ImageShape, TvDenoiser};
//! use diffcassi::render::Mask;
//! let shape = CubeShape { height: 8, width: 8, bands: 2 };
//! let op = ShiftOperator::new(shape, ImageShape { height: 8, width: 10 }, &Mask::open(8, 8), 0, vec![0, 2], 1, 1)?;
//! let y = vec![1.0f32; 80];
//! let config = SolverConfig { iterations: 3, ..SolverConfig::gap_tv() };
//! let mut tv = TvDenoiser::new(config.tv_weight, config.tv_iterations, config.tv_coupling);
//! let problem = Problem { op: &op, y: &y, init: None, config: &config, progress: &|_, _| {}, observe: &mut |_, _| {}, spread: None, cancel: None };
//! let rec = gap(problem, &mut tv)?;
//! assert_eq!(rec.cube.len(), 128);
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::prior::Denoiser;
use super::solve::data_term::residual_norm;
use super::solve::record::Reconstruction;
use super::solve::run::{Problem, Run};
use crate::error::Result;
use rayon::prelude::*;

/// GAP with any denoiser as the prior step θ_k = D(x_k, σ_k), plain or accelerated per `config.accelerated`
/// (see the [module docs](self); PnP kinds scale x to peak 1 around D and take σ_k from the schedule,
/// [`super::solve::prior_step::sigma_schedule`]). The dispatcher [`super::solver::reconstruct`] calls it for
/// `gap-tv` and `pnp-gap`.
pub fn gap(problem: Problem<'_>, denoiser: &mut dyn Denoiser) -> Result<Reconstruction> {
    let mut run = Run::start(problem, denoiser)?;
    let (op, y, config) = (run.op, run.y, run.config);
    let mut x = vec![0.0f32; run.shape.len()];
    let mut phi_theta = vec![0.0f32; y.len()];
    let mut y_acc = vec![0.0f32; y.len()];
    let mut e = vec![0.0f32; y.len()];
    let lambda = config.step;
    for k in 1..=config.iterations {
        if run.prior.done(k) {
            break;
        }
        op.apply_into(&run.theta, &mut phi_theta);
        // r = y − Φθ; e = D⁻¹ r (plain) or D⁻¹ (ỹ − Φθ) with ỹ += r (accelerated).
        e.par_iter_mut().zip(y.par_iter()).zip(phi_theta.par_iter()).for_each(|((e, a), b)| *e = *a - *b);
        let r = residual_norm(y, &phi_theta) / run.ny;
        // PnP's TV phase ends where GAP-TV would stop: the network starts from GAP-TV's stopped iterate.
        // δ re-estimated from the data at θ_{k−1} when due (MonteCarloSpread: one Φ'θ).
        run.noise.update(k, &run.theta, &phi_theta, &mut run.discrepancy);
        if run.prior.in_tv_phase() && run.discrepancy.tv_phase_reached(r * run.ny, k) {
            run.prior.switch(k - 1, "discrepancy");
        }
        // Discrepancy principle on θ_{k−1} (from the network's first output on): the data are explained to
        // the noise level.
        if run.discrepancy.reached(r * run.ny, k, run.prior.first_network_iteration()) {
            run.stopped_by = "discrepancy";
            break;
        }
        run.record(r, &e);
        if config.accelerated {
            e.par_iter_mut().zip(y_acc.par_iter_mut()).zip(phi_theta.par_iter()).zip(run.pre.inverse.par_iter()).for_each(|(((e, ya), p), w)| {
                *ya += *e;
                *e = (*ya - *p) * *w;
            });
        } else {
            e.par_iter_mut().zip(run.pre.inverse.par_iter()).for_each(|(e, w)| *e *= *w);
        }
        op.adjoint_into(&e, &mut x);
        x.par_iter_mut().zip(run.theta.par_iter()).for_each(|(x, t)| *x = *t + lambda * *x);
        let network = run.prior_step(k, &x)?;
        if run.end_iteration(k, r, network) {
            break;
        }
    }
    Ok(run.finish(&mut phi_theta, 2))
}
