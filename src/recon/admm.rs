//! ADMM-TV: the alternating direction method of multipliers with a TV denoiser, in the plug-and-play form
//! of Yuan's DeSCI / PnP-SCI codes (X. Yuan, Y. Liu, J. Suo, Q. Dai, "Plug-and-play algorithms for
//! large-scale snapshot compressive imaging", CVPR 2020), preconditioned by D = diag(ΦΦᵀ𝟙)
//! ([`super::solve::data_term`]). From θ₀ (0 or `init`), b₀ = 0, for k = 1…K:
//!
//! - v = θ_{k−1} + b_{k−1}
//! - x_k = v + λ Φᵀ ((y − Φv) / (d + η)),  η = `admm_eta`·max d (entries with D⁻¹ = 0 stay 0)
//! - θ_k = TV-denoise(x_k − b_{k−1}) — or any [`Denoiser`] D(x_k − b_{k−1}, σ_k) (PnP-ADMM,
//!   `pnp-admm`: the learned network, σ schedule and peak normalisation as PnP-GAP's)
//! - b_k = b_{k−1} − (x_k − θ_k)
//! - optional stops as GAP's: the discrepancy principle on ‖y − Φθ_{k−1}‖₂ (one more Φ per iteration when
//!   it is on) or the relative change.
//!
//! Cost per iteration: one Φ, one Φᵀ, one TV denoising. Memory: 8 cube-sized f32 buffers (θ, b, x, a
//! temporary, and the TV's four) plus 3 image-sized ones; 235 MB at 512×512×28, the operator's apart.
//!
//! ```
//! use diffcassi::recon::{reconstruct, solver::SolverConfig, shift::ShiftOperator, CubeShape, ImageShape};
//! use diffcassi::render::Mask;
//! let shape = CubeShape { height: 8, width: 8, bands: 2 };
//! let op = ShiftOperator::new(shape, ImageShape { height: 8, width: 10 }, &Mask::open(8, 8), 0, vec![0, 2], 1, 1)?;
//! // The dispatcher runs ADMM for `admm-tv` and `pnp-admm` (admm::admm with the configured denoiser).
//! let rec = reconstruct(&op, &vec![1.0f32; 80], None, &SolverConfig { iterations: 3, ..SolverConfig::admm_tv() }, &|_, _| {})?;
//! assert_eq!(rec.residuals.len(), 3);
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::prior::Denoiser;
use super::solve::data_term::residual_norm;
use super::solve::record::Reconstruction;
use super::solve::run::{Problem, Run};
use crate::error::Result;
use rayon::prelude::*;

/// ADMM with any denoiser as the prior step θ_k = D(x_k − b_{k−1}, σ_k) (see the [module docs](self); PnP
/// kinds scale to peak 1 around D and take σ_k from the schedule). The dispatcher
/// [`super::solver::reconstruct`] calls it for `admm-tv` and `pnp-admm`.
pub fn admm(problem: Problem<'_>, denoiser: &mut dyn Denoiser) -> Result<Reconstruction> {
    let mut run = Run::start(problem, denoiser)?;
    let (op, y, config) = (run.op, run.y, run.config);
    let eta = config.admm_eta * run.pre.max();
    let inv: Vec<f32> = run.pre.d.iter().zip(&run.pre.inverse).map(|(d, w)| if *w > 0.0 { 1.0 / (*d + eta) } else { 0.0 }).collect();
    let n = run.shape.len();
    let mut b = vec![0.0f32; n];
    let mut x = vec![0.0f32; n];
    let mut tmp = vec![0.0f32; n];
    let mut phi_v = vec![0.0f32; y.len()];
    let mut e = vec![0.0f32; y.len()];
    // ADMM projects v = θ + b, not θ: the discrepancy principle needs Φθ_{k−1} (one more Φ per iteration,
    // only when the rule is on).
    let pnp_tv = config.solver.is_pnp() && config.tv_warmup > 0 && (config.noise_norm > 0.0 || run.noise.is_tracked());
    let mut phi_t = if run.discrepancy.is_on() || pnp_tv || run.noise.is_tracked() { vec![0.0f32; y.len()] } else { Vec::new() };
    let lambda = config.step;
    for k in 1..=config.iterations {
        if run.prior.done(k) {
            break;
        }
        if (run.discrepancy.is_on() || (run.prior.in_tv_phase() && pnp_tv) || run.noise.due(k)) && k >= 2 {
            op.apply_into(&run.theta, &mut phi_t);
            let rt = residual_norm(y, &phi_t);
            run.noise.update(k, &run.theta, &phi_t, &mut run.discrepancy);
            // PnP's TV phase ends where the TV solver's own rule would stop it.
            if run.prior.in_tv_phase() && run.discrepancy.tv_phase_reached(rt, k) {
                run.prior.switch(k - 1, "discrepancy");
            }
            if run.discrepancy.reached(rt, k, run.prior.first_network_iteration()) {
                run.stopped_by = "discrepancy";
                break;
            }
        }
        x.par_iter_mut().zip(run.theta.par_iter()).zip(b.par_iter()).for_each(|((v, t), b)| *v = *t + *b);
        op.apply_into(&x, &mut phi_v);
        e.par_iter_mut().zip(y.par_iter()).zip(phi_v.par_iter()).for_each(|((e, a), p)| *e = *a - *p);
        let r = residual_norm(y, &phi_v) / run.ny;
        run.record(r, &e);
        e.par_iter_mut().zip(inv.par_iter()).for_each(|(e, w)| *e *= *w);
        op.adjoint_into(&e, &mut tmp);
        x.par_iter_mut().zip(tmp.par_iter()).for_each(|(x, g)| *x += lambda * *g);
        tmp.par_iter_mut().zip(x.par_iter()).zip(b.par_iter()).for_each(|((t, x), b)| *t = *x - *b);
        let network = run.prior_step(k, &tmp)?;
        b.par_iter_mut().zip(x.par_iter()).zip(run.theta.par_iter()).for_each(|((b, x), t)| *b -= *x - *t);
        if run.end_iteration(k, r, network) {
            break;
        }
    }
    Ok(run.finish(&mut phi_v, 4))
}
