//! GAP-TV: generalized alternating projection with total-variation denoising (X. Yuan, "Generalized
//! alternating projection based total variation minimization for compressive sensing", ICIP 2016), with the
//! accelerated variant (X. Liao, H. Li, L. Carin, "Generalized alternating projection for weighted-ℓ2,1
//! minimization with applications to model-based compressive sensing", SIAM J. Imaging Sci. 2014), as the
//! MST/DeSCI codes run it, preconditioned by D = diag(ΦΦᵀ𝟙) ([`super::solver`]). From θ₀ (0 or `init`),
//! ỹ₀ = 0, for k = 1…K:
//!
//! - plain:        x_k = θ_{k−1} + λ Φᵀ D⁻¹ (y − Φθ_{k−1})
//! - accelerated:  ỹ_k = ỹ_{k−1} + (y − Φθ_{k−1});  x_k = θ_{k−1} + λ Φᵀ D⁻¹ (ỹ_k − Φθ_{k−1})
//! - θ_k = TV-denoise(x_k) (Chambolle, [`super::tv`]; skipped when the TV weight is 0) — or, in [`gap`],
//!   any [`Denoiser`] D(x_k, σ_k): PnP-GAP (`pnp-gap`) plugs in the learned network with the decreasing σ
//!   schedule of [`super::solver::sigma_schedule`], the cube scaled to peak 1 around D.
//! - optional stops: the discrepancy principle ‖y − Φθ_{k−1}‖₂ ≤ τ·δ (δ the expected norm of the
//!   measurement's noise, [`super::solver::Discrepancy`]: fixed, or re-estimated from the data every few
//!   iterations by [`gap_estimated`]'s [`MonteCarloSpread`]; θ_{k−1} is returned), or
//!   ‖θ_k − θ_{k−1}‖₂ / ‖θ_k‖₂ < `tolerance` (the record says which rule ended the run).
//!
//! Cost per iteration: one Φ, one Φᵀ, one TV denoising. Memory: 6 cube-sized f32 buffers (θ, x, and the
//! TV's p₁, p₂ and their next iterate) plus 3 image-sized ones (ỹ, Φθ, D⁻¹); at 512×512×28 that is 6 × 29.4 MB = 176 MB,
//! the operator's own buffers apart (+1 with a tolerance: θ_{k−1}; PnP: θ, x, the scaled copy and the
//! network's activations instead of the TV's four).
//!
//! ```
//! use diffcassi::recon::{gap::gap_tv, solver::SolverConfig, shift::ShiftOperator, CubeShape, ImageShape};
//! use diffcassi::render::Mask;
//! let shape = CubeShape { height: 8, width: 8, bands: 2 };
//! let op = ShiftOperator::new(shape, ImageShape { height: 8, width: 10 }, &Mask::open(8, 8), 0, vec![0, 2], 1, 1)?;
//! let y = vec![1.0f32; 80];
//! let rec = gap_tv(&op, &y, None, &SolverConfig { iterations: 3, ..SolverConfig::gap_tv() }, &|_, _| {})?;
//! assert_eq!(rec.cube.len(), 128);
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::operator::Operator;
use super::prior::{tv::TvDenoiser, Denoiser};
use super::solver::{check_inputs, residual_norm, scale, Discrepancy, MonteCarloSpread, NoiseTrack, Preconditioner, PriorStep, Reconstruction, SolverConfig, Stopping};
use crate::error::Result;
use rayon::prelude::*;
use std::time::Instant;

/// Run GAP-TV (plain or accelerated per `config.accelerated`; see the [module docs](self)): [`gap`] with the
/// TV denoiser of `config`.
pub fn gap_tv(op: &dyn Operator, y: &[f32], init: Option<&[f32]>, config: &SolverConfig, progress: &(dyn Fn(usize, f64) + Sync)) -> Result<Reconstruction> {
    let mut tv = TvDenoiser::new(config.tv_weight, config.tv_iterations, config.tv_coupling);
    gap(op, y, init, config, &mut tv, progress)
}

/// GAP with any denoiser as the prior step θ_k = D(x_k, σ_k) (plain or accelerated; PnP kinds scale x to
/// peak 1 around D and take σ_k from the schedule, [`super::solver::sigma_schedule`]). Stops early when the
/// relative change falls under `config.tolerance`.
pub fn gap(op: &dyn Operator, y: &[f32], init: Option<&[f32]>, config: &SolverConfig, denoiser: &mut dyn Denoiser, progress: &(dyn Fn(usize, f64) + Sync)) -> Result<Reconstruction> {
    gap_estimated(op, y, init, config, denoiser, progress, &mut |_, _| {}, None)
}

/// [`gap`] with an observer `observe(k, θ_k)` called after each prior step (evaluation against a known truth,
/// `reconstruct --truth`; the solver never reads what it computes) and δ re-estimated from the data every few
/// iterations (`spread`, [`MonteCarloSpread`]); `None`: the fixed `config.noise_norm`.
#[allow(clippy::too_many_arguments)]
pub fn gap_estimated(
    op: &dyn Operator,
    y: &[f32],
    init: Option<&[f32]>,
    config: &SolverConfig,
    denoiser: &mut dyn Denoiser,
    progress: &(dyn Fn(usize, f64) + Sync),
    observe: &mut dyn FnMut(usize, &[f32]),
    spread: Option<&MonteCarloSpread<'_>>,
) -> Result<Reconstruction> {
    check_inputs(op, y, init, config)?;
    let t0 = Instant::now();
    let shape = op.cube_shape();
    let pre = Preconditioner::new(op);
    let (ny, nyw) = (scale(y), pre.weighted_norm(y).max(f64::MIN_POSITIVE));
    let mut theta = match init {
        Some(x) => x.to_vec(),
        None => vec![0.0f32; shape.len()],
    };
    let mut x = vec![0.0f32; shape.len()];
    let mut phi_theta = vec![0.0f32; y.len()];
    let mut y_acc = vec![0.0f32; y.len()];
    let mut e = vec![0.0f32; y.len()];
    let mut prior = PriorStep::new(denoiser, config);
    let mut stopping = Stopping::new(config.tolerance);
    let mut sigmas = Vec::new();
    let mut stopped_by = "iterations";
    let mut noise = NoiseTrack::new(spread);
    let mut discrepancy = if noise.is_tracked() { Discrepancy::tracked(config) } else { Discrepancy::new(config) };
    let lambda = config.step;
    let (mut residuals, mut weighted) = (Vec::with_capacity(config.iterations), Vec::with_capacity(config.iterations));
    for k in 1..=config.iterations {
        if prior.done(k) {
            break;
        }
        op.apply_into(&theta, &mut phi_theta);
        // r = y − Φθ; e = D⁻¹ r (plain) or D⁻¹ (ỹ − Φθ) with ỹ += r (accelerated).
        e.par_iter_mut().zip(y.par_iter()).zip(phi_theta.par_iter()).for_each(|((e, a), b)| *e = *a - *b);
        let r = residual_norm(y, &phi_theta) / ny;
        // PnP's TV phase ends where GAP-TV would stop: the network starts from GAP-TV's stopped iterate.
        // δ re-estimated from the data at θ_{k−1} when due (MonteCarloSpread: one Φ'θ).
        noise.update(k, &theta, &phi_theta, &mut discrepancy);
        if prior.in_tv_phase() && discrepancy.tv_phase_reached(r * ny, k) {
            prior.switch(k - 1);
        }
        // Discrepancy principle on θ_{k−1} (from the network's first output on): the data are explained to
        // the noise level.
        if discrepancy.reached(r * ny, k, prior.first_network_iteration()) {
            stopped_by = "discrepancy";
            break;
        }
        residuals.push(r);
        weighted.push(pre.weighted_norm(&e) / nyw);
        if config.accelerated {
            e.par_iter_mut().zip(y_acc.par_iter_mut()).zip(phi_theta.par_iter()).zip(pre.inverse.par_iter()).for_each(|(((e, ya), p), w)| {
                *ya += *e;
                *e = (*ya - *p) * *w;
            });
        } else {
            e.par_iter_mut().zip(pre.inverse.par_iter()).for_each(|(e, w)| *e *= *w);
        }
        op.adjoint_into(&e, &mut x);
        x.par_iter_mut().zip(theta.par_iter()).for_each(|(x, t)| *x = *t + lambda * *x);
        stopping.remember(&theta);
        let network = !prior.in_tv_phase();
        if config.solver.is_pnp() {
            sigmas.push(prior.sigma(k));
        }
        prior.apply(k, &x, &mut theta, shape)?;
        observe(k, &theta);
        progress(k, r);
        // The rule applies once the network runs (PnP's TV phase always completes).
        if stopping.stop(&theta) && network {
            stopped_by = "tolerance";
            break;
        }
    }
    op.apply_into(&theta, &mut phi_theta);
    let final_residual = residual_norm(y, &phi_theta) / ny;
    let (cube_buffers, denoiser_record) = (2 + prior.cube_buffers() + stopping.cube_buffers(), prior.describe());
    Ok(Reconstruction {
        cube: theta,
        shape,
        operator: op.name().to_string(),
        config: config.clone(),
        iterations_run: residuals.len(),
        residuals,
        weighted_residuals: weighted,
        final_residual,
        cube_buffers,
        seconds: t0.elapsed().as_secs_f64(),
        stopped_by: stopped_by.to_string(),
        relative_changes: stopping.changes,
        noise_norm: discrepancy.delta(),
        noise_estimates: noise.history,
        sigmas,
        denoiser: denoiser_record,
    })
}
