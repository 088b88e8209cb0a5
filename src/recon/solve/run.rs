//! One solver run's bookkeeping, shared by GAP ([`crate::recon::gap`]) and ADMM ([`crate::recon::admm`]):
//! the request ([`Problem`]), the iterate θ and the preconditioner, the prior step with its σ record, the
//! stopping rules and δ, the per-iteration residuals, and the final [`Reconstruction`]. Each solver keeps
//! only its own data step.
use super::config::SolverConfig;
use super::data_term::{check_inputs, residual_norm, scale, Preconditioner};
use super::noise::{MonteCarloSpread, NoiseTrack};
use super::prior_step::PriorStep;
use super::record::Reconstruction;
use super::stopping::{Discrepancy, Stopping};
use crate::error::Result;
use crate::recon::operator::{CubeShape, Operator};
use crate::recon::prior::Denoiser;
use std::time::Instant;

/// A reconstruction request: the operator Φ, the measurement y, the start cube (`None`: 0), the settings,
/// `progress(k, residual)` after each iteration k (1-based, relative residual), `observe(k, θ_k)` after each
/// prior step (evaluation against a known truth; the solver never reads what it computes), and δ
/// re-estimated from the data every few iterations (`spread`, [`MonteCarloSpread`]; `None`: the fixed
/// `config.noise_norm`), and the caller's stop request (`cancel`, polled before each iteration's prior step:
/// [`crate::Error::Interrupted`] once cancelled; `None`: never stopped).
pub struct Problem<'a> {
    pub op: &'a dyn Operator,
    pub y: &'a [f32],
    pub init: Option<&'a [f32]>,
    pub config: &'a SolverConfig,
    pub progress: &'a (dyn Fn(usize, f64) + Sync),
    pub observe: &'a mut dyn FnMut(usize, &[f32]),
    pub spread: Option<&'a MonteCarloSpread<'a>>,
    pub cancel: Option<&'a crate::cancel::Cancel>,
}

/// The state of one run (see the [module docs](self)); the solver owns its own buffers beside it.
pub(crate) struct Run<'a, 'd> {
    pub(crate) op: &'a dyn Operator,
    pub(crate) y: &'a [f32],
    pub(crate) config: &'a SolverConfig,
    progress: &'a (dyn Fn(usize, f64) + Sync),
    observe: &'a mut dyn FnMut(usize, &[f32]),
    cancel: Option<&'a crate::cancel::Cancel>,
    t0: Instant,
    pub(crate) shape: CubeShape,
    pub(crate) pre: Preconditioner,
    /// ‖y‖₂ (1 for y = 0) and ‖y‖_{D⁻¹}.
    pub(crate) ny: f64,
    nyw: f64,
    /// θ, the iterate (the returned cube).
    pub(crate) theta: Vec<f32>,
    pub(crate) prior: PriorStep<'d>,
    stopping: Stopping,
    sigmas: Vec<f32>,
    pub(crate) stopped_by: &'static str,
    pub(crate) noise: NoiseTrack<'a>,
    pub(crate) discrepancy: Discrepancy,
    residuals: Vec<f64>,
    weighted: Vec<f64>,
    dark_bands: Vec<usize>,
    /// The run's cube- and image-sized arrays, registered with the memory budget while it lasts
    /// ([`crate::limits::hold`]): the denoiser's own check counts them (round 19).
    _held: crate::limits::Held,
}

impl<'a, 'd> Run<'a, 'd> {
    /// Check the request and set up the run: D, the norms of y, θ₀, the prior step, the rules.
    pub(crate) fn start(p: Problem<'a>, denoiser: &'d mut dyn Denoiser) -> Result<Self> {
        let Problem { op, y, init, config, progress, observe, spread, cancel } = p;
        check_inputs(op, y, init, config)?;
        // The network polls the request per layer (a call can take seconds); `None` clears an earlier one.
        denoiser.set_cancel(cancel.cloned());
        let t0 = Instant::now();
        let shape = op.cube_shape();
        let pre = Preconditioner::new(op);
        // A zero operator (ΦΦᵀ𝟙 = 0 everywhere, so Φ = 0: the operators are non-negative) makes every solver
        // return the zero cube with residual 1 — a silently wrong result; refuse it.
        if !(pre.max() > 0.0) {
            return Err(crate::error::Error::invalid(format!(
                "the operator `{}` maps no voxel of the {}×{}×{} cube onto any of the {}×{} detector pixels (ΦΦᵀ𝟙 = 0 everywhere): every solver would return 0 — it does not model this acquisition (the mask is closed wherever the light lands: closed everywhere, or, in a dual-disperser system whose mask has the scene's pixel count, a small scene or a fine mask pitch lets the dispersion carry the image past the mask; the chief-ray operators see only the bands' centres)",
                op.name(),
                shape.height,
                shape.width,
                shape.bands,
                op.image_shape().height,
                op.image_shape().width
            )));
        }
        // Bands no detector pixel sees: their voxels are 0 whatever the data, and the record says so (a ddsp
        // 3×3 operator was zero in every band but one, an unevenly spaced band list left one band without a
        // plane; both silent: a held-out battery, round 17).
        let dark_bands = op.dark_bands();
        let (ny, nyw) = (scale(y), pre.weighted_norm(y).max(f64::MIN_POSITIVE));
        let theta = match init {
            Some(x) => x.to_vec(),
            None => vec![0.0f32; shape.len()],
        };
        let noise = NoiseTrack::new(spread);
        let discrepancy = if noise.is_tracked() { Discrepancy::tracked(config) } else { Discrepancy::new(config) };
        let prior = PriorStep::new(denoiser, config);
        let stopping = Stopping::new(config.tolerance);
        // Resident through the run: θ, the solver's own cube-sized buffers (GAP: 2, ADMM: 4), the prior's
        // and the stopping rule's, f32 each; the preconditioner and 2 image-sized buffers (Φθ, the residual).
        let own = if config.solver.is_gap() { 2 } else { 4 };
        let cubes = 1 + own + prior.cube_buffers() + stopping.cube_buffers();
        let image = op.image_shape().len() as f64;
        let held_bytes = 4.0 * (cubes as f64 * shape.len() as f64 + 3.0 * image);
        let _held = crate::limits::hold(format!("the {} solver's arrays ({cubes} cubes of {}×{}×{})", config.solver.name(), shape.height, shape.width, shape.bands), held_bytes);
        Ok(Run {
            op,
            y,
            config,
            progress,
            observe,
            cancel,
            t0,
            shape,
            pre,
            ny,
            nyw,
            theta,
            prior,
            stopping,
            sigmas: Vec::new(),
            stopped_by: "iterations",
            noise,
            discrepancy,
            residuals: Vec::with_capacity(config.iterations),
            weighted: Vec::with_capacity(config.iterations),
            dark_bands,
            _held,
        })
    }

    /// Record iteration k's relative residual `r` and its preconditioned counterpart from `e` = y − Φv.
    pub(crate) fn record(&mut self, r: f64, e: &[f32]) {
        self.residuals.push(r);
        self.weighted.push(self.pre.weighted_norm(e) / self.nyw);
    }

    /// The prior step of iteration k: θ_k = D(x, σ_k) (θ_{k−1} remembered for the relative change, σ_k
    /// recorded for PnP), then the observer. Returns whether the network ran (the relative-change rule
    /// applies from then on: PnP's TV phase always completes).
    pub(crate) fn prior_step(&mut self, k: usize, x: &[f32]) -> Result<bool> {
        // The solve's stop poll: once per iteration, before its most expensive step (the TV iterations or the
        // network); an interrupted solve returns nothing.
        crate::cancel::check(self.cancel)?;
        self.stopping.remember(&self.theta);
        let network = !self.prior.in_tv_phase();
        if self.config.solver.is_pnp() {
            self.sigmas.push(self.prior.sigma(k));
        }
        self.prior.apply(k, x, &mut self.theta, self.shape)?;
        (self.observe)(k, &self.theta);
        Ok(network)
    }

    /// The end of iteration k (relative residual `r`): report progress, then the relative-change rule.
    /// Returns whether to stop.
    pub(crate) fn end_iteration(&mut self, k: usize, r: f64, network: bool) -> bool {
        (self.progress)(k, r);
        if self.stopping.stop(&self.theta) && network {
            self.stopped_by = "tolerance";
            return true;
        }
        false
    }

    /// The record of the run: the final residual ‖y − Φθ‖₂/‖y‖₂ (`scratch`: an image-sized buffer for Φθ)
    /// and `own_buffers`, the solver's cube-sized buffers besides the prior's and the rule's.
    pub(crate) fn finish(self, scratch: &mut [f32], own_buffers: usize) -> Reconstruction {
        self.op.apply_into(&self.theta, scratch);
        let final_residual = residual_norm(self.y, scratch) / self.ny;
        let (cube_buffers, denoiser_record) = (own_buffers + self.prior.cube_buffers() + self.stopping.cube_buffers(), self.prior.describe());
        Reconstruction {
            cube: self.theta,
            shape: self.shape,
            operator: self.op.name().to_string(),
            config: self.config.clone(),
            iterations_run: self.residuals.len(),
            residuals: self.residuals,
            weighted_residuals: self.weighted,
            final_residual,
            cube_buffers,
            seconds: self.t0.elapsed().as_secs_f64(),
            stopped_by: self.stopped_by.to_string(),
            relative_changes: self.stopping.changes,
            noise_norm: self.discrepancy.delta(),
            noise_estimates: self.noise.history,
            sigmas: self.sigmas,
            denoiser: denoiser_record,
            dark_bands: self.dark_bands,
        }
    }
}
