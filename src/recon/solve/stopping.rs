//! The stopping rules: the discrepancy principle ([`Discrepancy`]) and the relative change ([`Stopping`]).
use super::config::{SolverConfig, PNP_TV_DISCREPANCY};
use crate::recon::layout::dot;
use rayon::prelude::*;

/// The discrepancy principle (Morozov 1966; for iterative regularisation, Engl, Hanke & Neubauer,
/// "Regularization of Inverse Problems", 1996, §4.3 and §7): an iterative method applied to y = Φx + n
/// fits the noise once ‖y − Φθ‖ falls below ‖n‖, so it stops at the first θ_{k−1} with
/// ‖y − Φθ_{k−1}‖₂ ≤ τ·δ, δ = [`SolverConfig::noise_norm`] (the expected ‖n‖, here the sensor noise and the
/// exact operator's Monte-Carlo mismatch), τ = [`SolverConfig::discrepancy`]. Needs no ground truth. The
/// first iterate tested is θ₁ (at least one update runs) and, for PnP, the first network output (the TV
/// warm-up always completes, as for the relative-change rule).
pub struct Discrepancy {
    tau: f64,
    /// δ in use: the configuration's, or the latest data-driven estimate ([`MonteCarloSpread`](super::noise::MonteCarloSpread)).
    delta: f64,
    /// Whether δ is re-estimated during the run (the rule is then on whenever τ > 0).
    tracked: bool,
}

impl Discrepancy {
    pub fn new(config: &SolverConfig) -> Self {
        Discrepancy { tau: config.discrepancy, delta: config.noise_norm, tracked: false }
    }

    /// The rule with δ re-estimated during the run (see [`MonteCarloSpread`](super::noise::MonteCarloSpread)); `config.noise_norm` is the
    /// starting value (the sensor term alone, say) until the first estimate.
    pub fn tracked(config: &SolverConfig) -> Self {
        Discrepancy { tracked: true, ..Self::new(config) }
    }

    /// Whether the rule is on (τ > 0 and δ > 0, or δ re-estimated).
    pub fn is_on(&self) -> bool {
        self.tau > 0.0 && (self.delta > 0.0 || self.tracked)
    }

    /// The δ in use.
    pub fn delta(&self) -> f64 {
        self.delta
    }

    /// Replace δ by a new estimate.
    pub fn set_delta(&mut self, delta: f64) {
        self.delta = delta;
    }

    /// Whether iteration k (1-based) tests θ_{k−1}: θ_{k−1} is the output of the network phase's first
    /// iteration or a later one (`first_network`: [`PriorStep`](super::prior_step::PriorStep)'s; 1 for TV solvers, so k ≥ 2).
    pub fn applies(&self, k: usize, first_network: Option<usize>) -> bool {
        first_network.is_some_and(|f| k > f)
    }

    /// At iteration k, with `residual` = ‖y − Φθ_{k−1}‖₂ (absolute): stop?
    pub fn reached(&self, residual: f64, k: usize, first_network: Option<usize>) -> bool {
        let t = self.tau * self.delta;
        self.is_on() && self.applies(k, first_network) && t > 0.0 && residual <= t
    }

    /// PnP's TV phase: does θ_{k−1} meet GAP-TV's own rule ‖y − Φθ‖ ≤ [`PNP_TV_DISCREPANCY`]·δ (k ≥ 2)?
    pub fn tv_phase_reached(&self, residual: f64, k: usize) -> bool {
        let t = PNP_TV_DISCREPANCY * self.delta;
        k >= 2 && t > 0.0 && residual <= t
    }
}

/// The stopping rule's bookkeeping: θ_{k−1} (kept only when the tolerance is on) and the relative changes.
pub(crate) struct Stopping {
    tolerance: f64,
    previous: Vec<f32>,
    pub(crate) changes: Vec<f64>,
}

impl Stopping {
    pub(crate) fn new(tolerance: f64) -> Self {
        Stopping { tolerance, previous: Vec::new(), changes: Vec::new() }
    }

    /// Before the prior step of an iteration: remember θ_{k−1}.
    pub(crate) fn remember(&mut self, theta: &[f32]) {
        if self.tolerance > 0.0 {
            self.previous.clear();
            self.previous.extend_from_slice(theta);
        }
    }

    /// After it: record ‖θ_k − θ_{k−1}‖ / ‖θ_k‖ and say whether to stop.
    pub(crate) fn stop(&mut self, theta: &[f32]) -> bool {
        if self.tolerance <= 0.0 {
            return false;
        }
        let d = theta.par_iter().zip(self.previous.par_iter()).map(|(a, b)| ((*a - *b) as f64).powi(2)).sum::<f64>().sqrt();
        let n = dot(theta, theta).sqrt();
        let c = if n > 0.0 { d / n } else if d > 0.0 { f64::INFINITY } else { 0.0 };
        self.changes.push(c);
        c < self.tolerance
    }

    pub(crate) fn cube_buffers(&self) -> usize {
        usize::from(self.tolerance > 0.0)
    }
}
