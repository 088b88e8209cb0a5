//! δ, the expected norm of y − Φx_true the discrepancy rule compares the residual with: the exact
//! operator's Monte-Carlo mismatch as a model ([`monte_carlo_noise_norm`]) or estimated from the data during
//! the run ([`MonteCarloSpread`], tracked by [`NoiseTrack`]).
use super::data_term::residual_norm;
use super::stopping::Discrepancy;
use crate::error::{Error, Result};
use crate::recon::operator::Operator;

/// Monte-Carlo mismatch of the exact operator: ‖Φ_a x − Φ_o x‖₂ / ‖Φ_a x‖₂ ≈ `MC_MISMATCH_PER_RAY` ·
/// ((1/R_a + 1/R_o)/F)^½ for an acquisition traced with R_a rays per pixel per plane, an operator traced
/// with R_o rays and another seed (independent estimates of the same expected transport, each of variance
/// ∝ 1/R) and F render planes per band (each band's image averages F independent planes). Measured on the
/// six natural scenes at 128×128×28 (SP and mSP, F = 4, R_a = R_o = 20, Airy 2.5 px, the paper's mask) as
/// ‖y − Φ_o x_true‖/‖y‖ = 0.0089–0.0107, mean 0.0097 (`reconstruct --truth` records it as
/// `truth_residual`; docs/reconstruction.md, "Defaults and stopping"). A constant relative mismatch: it
/// overestimates δ on smoother scenes (the same photographs at 256² and 512²), so the CLI's default estimates the
/// term from the data ([`MonteCarloSpread`]) and keeps this model for `--noise-estimate model`.
pub const MC_MISMATCH_PER_RAY: f64 = 0.062;

/// δ_MC = [`MC_MISMATCH_PER_RAY`]·((1/R_a + 1/R_o)/F)^½·‖y‖: the expected ‖y − Φ_o x_true‖₂ of an exact
/// operator traced with another seed (R_o rays per pixel per plane) against an acquisition traced with R_a
/// rays, F render planes per band, `y_norm` = ‖y‖₂ (the CLI's Monte-Carlo term of δ; 0 rays count as 1).
pub fn monte_carlo_noise_norm(y_norm: f64, acquisition_rays: usize, operator_rays: usize, planes_per_band: f64) -> f64 {
    MC_MISMATCH_PER_RAY * ((1.0 / acquisition_rays.max(1) as f64 + 1.0 / operator_rays.max(1) as f64) / planes_per_band.max(1e-9)).sqrt() * y_norm
}

/// **δ estimated from the data** (issue 22): the exact operator's Monte-Carlo spread at the current iterate.
/// Φ_o (the operator, R_o rays per pixel per plane, seed s_o) and its *twin* Φ' (the same optics, planes and
/// rays, another seed) are independent estimates of the expected transport Φ̄, as is the acquisition's own
/// Φ_a (R_a rays). With V_R(x) = E‖(Φ_R − Φ̄)x‖² the Monte-Carlo variance of an R-ray operator,
///
/// - the truth residual of a noiseless acquisition: E‖y − Φ_o x‖² = E‖(Φ_a − Φ_o)x‖² = V_{R_a}(x) + V_{R_o}(x);
/// - the twins' difference: E‖(Φ_o − Φ')x‖² = 2 V_{R_o}(x);
///
/// and, with V_R = V_1/R (independent rays; exact for any sampling when R_a = R_o),
/// δ_MC² = ‖(Φ_o − Φ')θ‖² · (1 + R_o/R_a)/2, evaluated at the iterate θ ≈ x (no ground truth). Sensor noise
/// adds in quadrature: δ̂² = δ_s² + δ_MC². The difference is a sum over every detector pixel and plane, so a
/// single draw is close to its mean. Cost: the twin's memory and build (as much as the operator's), and one
/// Φ'θ every [`MonteCarloSpread::every`] iterations (Φ_oθ is the solver's own).
pub struct MonteCarloSpread<'o> {
    /// Φ': the operator's twin (independent rays).
    pub twin: &'o dyn Operator,
    /// ((1 + R_o/R_a)/2)^½ (1 for equal ray counts).
    pub factor: f64,
    /// The sensor-noise term δ_s (0 for a noiseless acquisition).
    pub sensor_norm: f64,
    /// Re-estimate δ at iterations 2, 2 + every, 2 + 2·every, … (≥ 1).
    pub every: usize,
}

/// Default period of [`MonteCarloSpread`]'s re-estimation (one extra Φ per this many iterations).
pub const SPREAD_EVERY: usize = 5;

/// The largest spread factor taken ([`MonteCarloSpread::check_factor`]): [`MonteCarloSpread::factor_for`] of
/// ray counts within the ray budget is ≤ ~10⁵; a factor of 10³⁰⁰ made δ infinite and stopped a run at its
/// first iteration with a record of `null`s (a held-out battery, round 15).
pub const MAX_SPREAD_FACTOR: f64 = 1e6;

impl MonteCarloSpread<'_> {
    /// A caller's factor (Python's `noise_factor`): finite, > 0 and ≤ [`MAX_SPREAD_FACTOR`].
    pub fn check_factor(factor: f64) -> Result<f64> {
        if !(factor.is_finite() && factor > 0.0 && factor <= MAX_SPREAD_FACTOR) {
            return Err(Error::invalid(format!(
                "--noise-factor {}: must be finite, > 0 and at most {} (the factor ((1 + R_operator/R_acquisition)/2)^½ of ray counts within the ray budget is ≤ ~1e5)",
                crate::limits::fmt_num(factor),
                crate::limits::fmt_num(MAX_SPREAD_FACTOR)
            )));
        }
        Ok(factor)
    }

    /// ((1 + R_o/R_a)/2)^½: the factor from the twins' spread to the expected truth residual.
    pub fn factor_for(acquisition_rays: usize, operator_rays: usize) -> f64 {
        ((1.0 + operator_rays.max(1) as f64 / acquisition_rays.max(1) as f64) / 2.0).sqrt()
    }

    /// Whether iteration k (1-based) re-estimates δ.
    pub fn due(&self, k: usize) -> bool {
        k >= 2 && (k - 2) % self.every.max(1) == 0
    }

    /// The Monte-Carlo term alone at `theta`: factor·‖Φ_oθ − Φ'θ‖₂ (`phi_theta` = Φ_oθ; `scratch` takes Φ'θ).
    pub fn monte_carlo(&self, theta: &[f32], phi_theta: &[f32], scratch: &mut Vec<f32>) -> f64 {
        scratch.resize(phi_theta.len(), 0.0);
        self.twin.apply_into(theta, scratch);
        self.factor * residual_norm(phi_theta, scratch)
    }

    /// δ̂ = (δ_s² + δ_MC²)^½ at `theta`.
    pub fn estimate(&self, theta: &[f32], phi_theta: &[f32], scratch: &mut Vec<f32>) -> f64 {
        let mc = self.monte_carlo(theta, phi_theta, scratch);
        (self.sensor_norm * self.sensor_norm + mc * mc).sqrt()
    }

    /// Check the twin against the operator (same shapes) and the settings.
    pub fn check(&self, op: &dyn Operator) -> Result<()> {
        if self.twin.cube_shape() != op.cube_shape() || self.twin.image_shape() != op.image_shape() {
            return Err(Error::invalid(format!("noise estimate: the twin operator `{}` has other shapes than the operator `{}`", self.twin.name(), op.name())));
        }
        if !(self.factor.is_finite() && self.factor > 0.0) || !(self.sensor_norm.is_finite() && self.sensor_norm >= 0.0) || self.every == 0 {
            return Err(Error::invalid(format!(
                "noise estimate: factor {} must be finite and > 0, sensor norm {} finite and ≥ 0, period {} ≥ 1",
                self.factor, self.sensor_norm, self.every
            )));
        }
        Ok(())
    }
}

/// The run's δ: fixed, or re-estimated by a [`MonteCarloSpread`] (with its history for the record).
pub(crate) struct NoiseTrack<'o> {
    spread: Option<&'o MonteCarloSpread<'o>>,
    scratch: Vec<f32>,
    pub(crate) history: Vec<(usize, f64)>,
}

impl<'o> NoiseTrack<'o> {
    pub(crate) fn new(spread: Option<&'o MonteCarloSpread<'o>>) -> Self {
        NoiseTrack { spread, scratch: Vec::new(), history: Vec::new() }
    }

    pub(crate) fn is_tracked(&self) -> bool {
        self.spread.is_some()
    }

    /// Whether iteration k needs Φθ_{k−1} for a new estimate.
    pub(crate) fn due(&self, k: usize) -> bool {
        self.spread.is_some_and(|s| s.due(k))
    }

    /// At iteration k with θ_{k−1} and Φθ_{k−1}: re-estimate δ when due and hand it to the rule.
    pub(crate) fn update(&mut self, k: usize, theta: &[f32], phi_theta: &[f32], rule: &mut Discrepancy) {
        if let Some(s) = self.spread.filter(|s| s.due(k)) {
            let d = s.estimate(theta, phi_theta, &mut self.scratch);
            self.history.push((k, d));
            rule.set_delta(d);
        }
    }
}
