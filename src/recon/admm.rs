//! ADMM-TV: the alternating direction method of multipliers with a TV denoiser, in the plug-and-play form
//! of Yuan's DeSCI / PnP-SCI codes (X. Yuan, Y. Liu, J. Suo, Q. Dai, "Plug-and-play algorithms for
//! large-scale snapshot compressive imaging", CVPR 2020), preconditioned by D = diag(ΦΦᵀ𝟙)
//! ([`super::solver`]). From θ₀ (0 or `init`), b₀ = 0, for k = 1…K:
//!
//! - v = θ_{k−1} + b_{k−1}
//! - x_k = v + λ Φᵀ ((y − Φv) / (d + η)),  η = `admm_eta`·max d (entries with D⁻¹ = 0 stay 0)
//! - θ_k = TV-denoise(x_k − b_{k−1}) — or, in [`admm`], any [`Denoiser`] D(x_k − b_{k−1}, σ_k) (PnP-ADMM,
//!   `pnp-admm`: the learned network, σ schedule and peak normalisation as PnP-GAP's)
//! - b_k = b_{k−1} − (x_k − θ_k)
//! - optional stops as GAP's: the discrepancy principle on ‖y − Φθ_{k−1}‖₂ (one more Φ per iteration when
//!   it is on) or the relative change.
//!
//! Cost per iteration: one Φ, one Φᵀ, one TV denoising. Memory: 8 cube-sized f32 buffers (θ, b, x, a
//! temporary, and the TV's four) plus 3 image-sized ones; 235 MB at 512×512×28, the operator's apart.
//!
//! ```
//! use diffcassi::recon::{admm::admm_tv, solver::SolverConfig, shift::ShiftOperator, CubeShape, ImageShape};
//! use diffcassi::render::Mask;
//! let shape = CubeShape { height: 8, width: 8, bands: 2 };
//! let op = ShiftOperator::new(shape, ImageShape { height: 8, width: 10 }, &Mask::open(8, 8), 0, vec![0, 2], 1, 1)?;
//! let rec = admm_tv(&op, &vec![1.0f32; 80], None, &SolverConfig { iterations: 3, ..SolverConfig::admm_tv() }, &|_, _| {})?;
//! assert_eq!(rec.residuals.len(), 3);
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::operator::Operator;
use super::prior::{tv::TvDenoiser, Denoiser};
use super::solver::{check_inputs, residual_norm, scale, Discrepancy, MonteCarloSpread, NoiseTrack, Preconditioner, PriorStep, Reconstruction, SolverConfig, Stopping};
use crate::error::Result;
use rayon::prelude::*;
use std::time::Instant;

/// Run ADMM-TV (see the [module docs](self)): [`admm`] with the TV denoiser of `config`.
pub fn admm_tv(op: &dyn Operator, y: &[f32], init: Option<&[f32]>, config: &SolverConfig, progress: &(dyn Fn(usize, f64) + Sync)) -> Result<Reconstruction> {
    let mut tv = TvDenoiser::new(config.tv_weight, config.tv_iterations, config.tv_coupling);
    admm(op, y, init, config, &mut tv, progress)
}

/// ADMM with any denoiser as the prior step θ_k = D(x_k − b_{k−1}, σ_k) (PnP kinds scale to peak 1 around D
/// and take σ_k from the schedule). Stops early when the relative change falls under `config.tolerance`.
pub fn admm(op: &dyn Operator, y: &[f32], init: Option<&[f32]>, config: &SolverConfig, denoiser: &mut dyn Denoiser, progress: &(dyn Fn(usize, f64) + Sync)) -> Result<Reconstruction> {
    admm_estimated(op, y, init, config, denoiser, progress, &mut |_, _| {}, None)
}

/// [`admm`] with an observer `observe(k, θ_k)` called after each prior step (evaluation only) and δ re-estimated from
/// the data every few iterations (`spread`, [`MonteCarloSpread`]); `None`: the fixed `config.noise_norm`.
#[allow(clippy::too_many_arguments)]
pub fn admm_estimated(
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
    let eta = config.admm_eta * pre.max();
    let inv: Vec<f32> = pre.d.iter().zip(&pre.inverse).map(|(d, w)| if *w > 0.0 { 1.0 / (*d + eta) } else { 0.0 }).collect();
    let (ny, nyw) = (scale(y), pre.weighted_norm(y).max(f64::MIN_POSITIVE));
    let mut theta = match init {
        Some(x) => x.to_vec(),
        None => vec![0.0f32; shape.len()],
    };
    let mut b = vec![0.0f32; shape.len()];
    let mut x = vec![0.0f32; shape.len()];
    let mut tmp = vec![0.0f32; shape.len()];
    let mut phi_v = vec![0.0f32; y.len()];
    let mut e = vec![0.0f32; y.len()];
    let mut prior = PriorStep::new(denoiser, config);
    let mut stopping = Stopping::new(config.tolerance);
    let mut sigmas = Vec::new();
    let mut stopped_by = "iterations";
    let mut noise = NoiseTrack::new(spread);
    let mut discrepancy = if noise.is_tracked() { Discrepancy::tracked(config) } else { Discrepancy::new(config) };
    // ADMM projects v = θ + b, not θ: the discrepancy principle needs Φθ_{k−1} (one more Φ per iteration,
    // only when the rule is on).
    let pnp_tv = config.solver.is_pnp() && config.tv_warmup > 0 && (config.noise_norm > 0.0 || noise.is_tracked());
    let mut phi_t = if discrepancy.is_on() || pnp_tv || noise.is_tracked() { vec![0.0f32; y.len()] } else { Vec::new() };
    let lambda = config.step;
    let (mut residuals, mut weighted) = (Vec::with_capacity(config.iterations), Vec::with_capacity(config.iterations));
    for k in 1..=config.iterations {
        if prior.done(k) {
            break;
        }
        if (discrepancy.is_on() || (prior.in_tv_phase() && pnp_tv) || noise.due(k)) && k >= 2 {
            op.apply_into(&theta, &mut phi_t);
            let rt = residual_norm(y, &phi_t);
            noise.update(k, &theta, &phi_t, &mut discrepancy);
            // PnP's TV phase ends where the TV solver's own rule would stop it.
            if prior.in_tv_phase() && discrepancy.tv_phase_reached(rt, k) {
                prior.switch(k - 1);
            }
            if discrepancy.reached(rt, k, prior.first_network_iteration()) {
                stopped_by = "discrepancy";
                break;
            }
        }
        x.par_iter_mut().zip(theta.par_iter()).zip(b.par_iter()).for_each(|((v, t), b)| *v = *t + *b);
        op.apply_into(&x, &mut phi_v);
        e.par_iter_mut().zip(y.par_iter()).zip(phi_v.par_iter()).for_each(|((e, a), p)| *e = *a - *p);
        let r = residual_norm(y, &phi_v) / ny;
        residuals.push(r);
        weighted.push(pre.weighted_norm(&e) / nyw);
        e.par_iter_mut().zip(inv.par_iter()).for_each(|(e, w)| *e *= *w);
        op.adjoint_into(&e, &mut tmp);
        x.par_iter_mut().zip(tmp.par_iter()).for_each(|(x, g)| *x += lambda * *g);
        tmp.par_iter_mut().zip(x.par_iter()).zip(b.par_iter()).for_each(|((t, x), b)| *t = *x - *b);
        stopping.remember(&theta);
        let network = !prior.in_tv_phase();
        if config.solver.is_pnp() {
            sigmas.push(prior.sigma(k));
        }
        prior.apply(k, &tmp, &mut theta, shape)?;
        observe(k, &theta);
        b.par_iter_mut().zip(x.par_iter()).zip(theta.par_iter()).for_each(|((b, x), t)| *b -= *x - *t);
        progress(k, r);
        // The rule applies once the network runs (PnP's TV phase always completes).
        if stopping.stop(&theta) && network {
            stopped_by = "tolerance";
            break;
        }
    }
    op.apply_into(&theta, &mut phi_v);
    let final_residual = residual_norm(y, &phi_v) / ny;
    let (cube_buffers, denoiser_record) = (4 + prior.cube_buffers() + stopping.cube_buffers(), prior.describe());
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
