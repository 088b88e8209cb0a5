//! [`Reconstruction`]: what a solver returns — the cube and the record the CLI and the bindings serialise
//! (settings, per-iteration residuals, the stopping rule and what ended the run).
use super::config::{SolverConfig, SolverKind};

/// The range of TV weight / cube peak outside which [`Reconstruction::warnings`] says the TV weight does not
/// suit the cube's scale: the default 0.1 is tuned for peaks ≈ 1; the TV solution of k·y at weight w is not
/// k times that of y (ROF is homogeneous only if w scales too): a scene ×100 reconstructed at 0.1 moved by
/// 0.55 of its peak (a held-out battery, round 17).
pub const TV_WEIGHT_TO_PEAK: (f64, f64) = (0.005, 2.0);
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
    /// Bands (indices) no detector pixel sees (Φᵀ𝟙 = 0 over the band): their voxels are 0, not an estimate.
    pub dark_bands: Vec<usize>,
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
        if !self.dark_bands.is_empty() {
            let mut list = self.dark_bands.iter().take(8).map(|b| b.to_string()).collect::<Vec<_>>().join(", ");
            if self.dark_bands.len() > 8 {
                list += &format!(", … {} more", self.dark_bands.len() - 8);
            }
            w.push(format!(
                "{} of {} bands (index {list}) are seen by no detector pixel of the operator `{}` (Φᵀ𝟙 = 0 over the band): their reconstruction is 0, not an estimate (fewer render planes than bands left it unsampled, or the mask is closed or passed by where its light lands)",
                self.dark_bands.len(),
                self.shape.bands,
                self.operator
            ));
        }
        let peak = self.cube.iter().fold(0.0f32, |m, v| m.max(v.abs())) as f64;
        let tv = self.config.tv_weight as f64;
        let uses_tv = tv > 0.0 && (matches!(self.config.solver, SolverKind::GapTv | SolverKind::AdmmTv) || self.config.tv_warmup > 0);
        if uses_tv && peak > 0.0 && !(TV_WEIGHT_TO_PEAK.0..=TV_WEIGHT_TO_PEAK.1).contains(&(tv / peak)) {
            w.push(format!(
                "the TV weight {} is {:.3e} of the returned cube's peak {:.4e}: the weight is absolute, in the cube's units (the default 0.1 is tuned for cubes of peak ≈ 1, as the paper's scenes), so this cube is {}; scale the weight with the data (about 0.1 × the peak) or the acquisition to peak ≈ 1",
                self.config.tv_weight,
                tv / peak,
                peak,
                if tv / peak < TV_WEIGHT_TO_PEAK.0 { "barely regularised" } else { "smoothed towards a constant" }
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
