//! [`Reconstruction`]: what a solver returns — the cube and the record the CLI and the bindings serialise
//! (settings, per-iteration residuals, the stopping rule and what ended the run).
use super::config::SolverConfig;
use crate::recon::layout::dot;
use crate::recon::operator::CubeShape;

/// The result of [`reconstruct`](crate::recon::solver::reconstruct): the cube and a record the CLI serialises (the cube is written apart).
#[derive(Clone, Debug, serde::Serialize)]
pub struct Reconstruction {
    /// H×W×B, `[row][col][band]`.
    #[serde(skip)]
    pub cube: Vec<f32>,
    pub shape: CubeShape,
    pub operator: String,
    pub config: SolverConfig,
    /// Per iteration k: ‖y − Φv_k‖₂ / ‖y‖₂, v_k the point iteration k projects (GAP: θ_{k−1}; ADMM:
    /// θ_{k−1} + b_{k−1}).
    pub residuals: Vec<f64>,
    /// The same in the preconditioned norm ‖·‖_{D⁻¹} (relative to ‖y‖_{D⁻¹}).
    pub weighted_residuals: Vec<f64>,
    /// ‖y − Φθ‖₂ / ‖y‖₂ of the returned cube.
    pub final_residual: f64,
    /// Cube-sized f32 buffers the solver held (its own and the TV's; not the operator's).
    pub cube_buffers: usize,
    pub seconds: f64,
    /// Iterations run (≤ `config.iterations`: the stopping rule may end the run early).
    pub iterations_run: usize,
    /// Which rule ended the run: `iterations` (all ran), `tolerance` (relative change below it) or
    /// `discrepancy` (‖y − Φθ‖₂ ≤ τ·δ: θ of the last completed iteration is returned).
    pub stopped_by: String,
    /// Per iteration k: ‖θ_k − θ_{k−1}‖₂ / ‖θ_k‖₂ (the stopping rule's quantity).
    pub relative_changes: Vec<f64>,
    /// PnP: σ of each iteration (relative to the peak); empty for TV.
    pub sigmas: Vec<f32>,
    /// The δ the discrepancy rule used last (`config.noise_norm`, or the last data-driven estimate).
    pub noise_norm: f64,
    /// Data-driven δ ([`MonteCarloSpread`](super::noise::MonteCarloSpread)): (iteration k, δ̂ at θ_{k−1}) of every re-estimate; empty when δ
    /// is fixed.
    pub noise_estimates: Vec<(usize, f64)>,
    /// The prior: the denoiser's record (name, weights / TV settings).
    pub denoiser: serde_json::Value,
}

impl Reconstruction {
    /// The stopping record `reconstruct.json` (`stopping`) and the Python record share: the rules, τ, δ
    /// (`noise_norm`, absolute) and τδ/‖y‖, how δ was estimated (`noise_estimate`: the caller's record,
    /// e.g. the CLI's from render.json), the cap, the iterations run, which rule ended the run, the
    /// relative changes and, for PnP, where the TV phase ended (`tv_phase_iterations`).
    pub fn stopping_record(&self, y: &[f32], noise_estimate: Option<serde_json::Value>) -> serde_json::Value {
        let ny = dot(y, y).sqrt();
        serde_json::json!({
            "rule": "discrepancy principle ‖y − Φθ_{k−1}‖₂ ≤ τ·δ (θ_{k−1} returned; τ = 0 or δ = 0: off), or relative change ‖θ_k − θ_{k−1}‖₂/‖θ_k‖₂ < tolerance (0: off), else the iteration cap",
            "tolerance": self.config.tolerance,
            "discrepancy_tau": self.config.discrepancy,
            "noise_norm": self.noise_norm,
            "discrepancy_threshold_relative": if ny > 0.0 { self.config.discrepancy * self.noise_norm / ny } else { 0.0 },
            "noise_estimator": if self.noise_estimates.is_empty() { "fixed" } else { "monte-carlo-spread" },
            "noise_norm_per_estimate": self.noise_estimates,
            "noise_estimate": noise_estimate,
            "iteration_cap": self.config.iterations,
            "tv_phase_iterations": self.denoiser.get("tv_warmup").and_then(|w| w.get("iterations_run")).cloned(),
            // What ended PnP's TV phase (`discrepancy`: its τ rule; `iterations`: --tv-warmup); `stopped_by`
            // is what ended the run, the network phase.
            "tv_phase_stopped_by": self.denoiser.get("tv_warmup").and_then(|w| w.get("ended_by")).cloned(),
            "stopped_by": self.stopped_by,
            "iterations_run": self.iterations_run,
            "relative_changes": self.relative_changes,
            "warnings": self.warnings(y),
        })
    }

    /// What the caller should know of this run beyond its numbers (each front end says them: the CLI on
    /// stderr and in `stopping.warnings`, Python as `UserWarning`s): a returned cube that fits `y` worse than
    /// the zero cube (the iteration diverged), and a discrepancy threshold τδ at or above ‖y‖ (the zero cube
    /// meets it, so the rule's stop says nothing; a data-driven δ measured at a diverging iterate grew past
    /// ‖y‖ and stopped the run there as "discrepancy"; a held-out battery, round 16).
    pub fn warnings(&self, y: &[f32]) -> Vec<String> {
        let ny = dot(y, y).sqrt();
        let mut w = Vec::new();
        if !(ny > 0.0) {
            return w;
        }
        if self.final_residual > 1.0 {
            w.push(format!(
                "the returned cube fits the acquisition worse than a zero cube (‖y − Φx‖/‖y‖ = {:.3} > 1): the iteration diverged on this acquisition, which the operator may not be able to produce (another system's, or an edited one); try the plain (not accelerated) iteration or fewer iterations",
                self.final_residual
            ));
        }
        let threshold = self.config.discrepancy * self.noise_norm;
        if threshold >= ny {
            w.push(format!(
                "the discrepancy threshold τ·δ = {:.4e} is at least ‖y‖ = {:.4e} (δ = {:.4e}{}): the zero cube meets it, so `stopped_by` says nothing of the fit; the noise estimate is larger than the measurement",
                threshold,
                ny,
                self.noise_norm,
                if self.noise_estimates.is_empty() { "" } else { ", estimated from the data at the iterate" }
            ));
        }
        w
    }
}
