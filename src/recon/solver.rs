//! Solver settings, result and the shared pieces of GAP-TV ([`super::gap`]) and ADMM-TV ([`super::admm`]):
//! the diagonal preconditioner, residual norms and input checks. Solvers see only a
//! `&dyn` [`Operator`].
//!
//! **Preconditioner.** The field's GAP divides the residual by ΦΦᵀ, which is diagonal only when each voxel
//! lands on one pixel (the `shift` model). For `exact` (a voxel spreads over a footprint and an Airy disk)
//! and bilinear `mapping` it is not, so both solvers use D = diag(d), d = ΦΦᵀ𝟙 (one Φᵀ and one Φ). For
//! non-negative Φ this majorises ΦΦᵀ: A = ΦΦᵀ is symmetric with non-negative entries and row sums d, and by
//! the Schur test (Gershgorin's row-sum bound applied to D^{-½} A D^{-½}, whose rows weighted by d^{½}
//! sum to d^{½}) the spectral radius of D^{-½} A D^{-½} is ≤ 1, i.e. A ⪯ D. Hence the projection step
//! x ← x + λ Φᵀ D⁻¹ (y − Φx), 0 < λ ≤ 2, never increases the data term ‖y − Φx‖_{D⁻¹} =
//! (Σ_i (y − Φx)_i² / d_i)^½ (the residual evolves as r ← (I − λ A D⁻¹) r). Entries with
//! d_i ≤ [`D_GUARD`]·max d (pixels no voxel reaches, or only the far tail of a footprint) get D⁻¹ = 0: they
//! are left out of the data term (the bound still holds on the rest, whose row sums only shrink).
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
use super::layout::dot;
use super::operator::{CubeShape, Operator};
use super::prior::{network::SpectralUNet, tv::TvDenoiser, Denoiser};
use super::tv::TvCoupling;
use crate::error::{Error, Result};
use rayon::prelude::*;
use std::str::FromStr;

/// d_i at or below this fraction of max d is treated as unreachable (D⁻¹ = 0).
pub const D_GUARD: f32 = 1e-6;

/// The iterative method.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SolverKind {
    /// Generalized alternating projection with TV (Yuan 2016), plain or accelerated (Liao, Li & Carin 2014).
    GapTv,
    /// ADMM with TV (plug-and-play form of Yuan's DeSCI/PnP code).
    AdmmTv,
    /// Plug-and-play GAP with the learned denoiser ([`super::prior::network`]) and a decreasing σ schedule.
    PnpGap,
    /// Plug-and-play ADMM with the learned denoiser.
    PnpAdmm,
}

impl SolverKind {
    pub fn name(&self) -> &'static str {
        match self {
            SolverKind::GapTv => "gap-tv",
            SolverKind::AdmmTv => "admm-tv",
            SolverKind::PnpGap => "pnp-gap",
            SolverKind::PnpAdmm => "pnp-admm",
        }
    }

    /// Whether the prior is the learned denoiser (plug-and-play) rather than TV.
    pub fn is_pnp(&self) -> bool {
        matches!(self, SolverKind::PnpGap | SolverKind::PnpAdmm)
    }

    /// Whether the data step is GAP's (else ADMM's).
    pub fn is_gap(&self) -> bool {
        matches!(self, SolverKind::GapTv | SolverKind::PnpGap)
    }
}

/// The names [`SolverKind`] parses, for messages.
pub const SOLVER_NAMES: &str = "gap-tv, admm-tv, pnp-gap or pnp-admm";

impl FromStr for SolverKind {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "gap-tv" => Ok(SolverKind::GapTv),
            "admm-tv" => Ok(SolverKind::AdmmTv),
            "pnp-gap" => Ok(SolverKind::PnpGap),
            "pnp-admm" => Ok(SolverKind::PnpAdmm),
            _ => Err(Error::invalid(format!("unknown solver `{s}` (expected {SOLVER_NAMES})"))),
        }
    }
}

/// Settings of a reconstruction. Defaults ([`SolverConfig::gap_tv`], [`SolverConfig::admm_tv`]) follow
/// the reference defaults of PAPER.md ("How the paper's code reconstructs": 50–100 iterations, TV weight
/// 0.07–0.1, 5 inner Chambolle iterations; GAP step λ = 1 as in the MST/DeSCI codes).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SolverConfig {
    pub solver: SolverKind,
    /// Outer iterations (default 100).
    pub iterations: usize,
    /// Step λ of the projection, in (0, 2] (default 1).
    pub step: f32,
    /// Chambolle weight w of the TV denoiser (default 0.1; 0 turns the denoiser off).
    pub tv_weight: f32,
    /// Chambolle iterations per denoising (default 5).
    pub tv_iterations: usize,
    /// Band coupling of the TV (default vectorial, as the MST/DeSCI TV denoiser).
    pub tv_coupling: TvCoupling,
    /// GAP only: the accelerated update ỹ_k = ỹ_{k−1} + (y − Φθ_{k−1}) (default true for `gap-tv`: on the
    /// natural scenes, 128×128×28, SP/mSP, 20 rays, exact operator with another seed, it gains 1.5 / 0.4 dB
    /// over plain GAP at 100 iterations and 1.9 / 0.4 dB at 300; it fits the data harder and, run long, the
    /// operator's Monte-Carlo mismatch, which the discrepancy rule stops; see docs/reconstruction.md,
    /// "Defaults and stopping"). PnP keeps plain GAP (its measured setting).
    pub accelerated: bool,
    /// ADMM only: η added to d in the projection (y − Φv)/(d + η), relative to max d (default 0.01).
    pub admm_eta: f32,
    /// PnP only: the noise level σ of the first denoising, relative to the cube's peak (the denoiser sees the
    /// cube scaled to peak 1; see [`sigma_schedule`]).
    #[serde(default)]
    pub sigma_max: f32,
    /// PnP only: the noise level σ of the last denoising, relative to the peak (σ decreases geometrically).
    #[serde(default)]
    pub sigma_min: f32,
    /// Stopping rule: stop after iteration k when ‖θ_k − θ_{k−1}‖₂ / ‖θ_k‖₂ < tolerance (0: run all the
    /// iterations). The record says which rule ended the run.
    #[serde(default)]
    pub tolerance: f64,
    /// Discrepancy principle (Morozov): stop before iteration k's update when ‖y − Φθ_{k−1}‖₂ ≤
    /// `discrepancy`·`noise_norm`, returning θ_{k−1} (τ ≥ 1 in theory; 0 turns the rule off). See [`Discrepancy`].
    #[serde(default)]
    pub discrepancy: f64,
    /// The expected norm δ = E‖y − Φx_true‖₂ of the measurement's noise and operator mismatch, in acquisition
    /// units (the CLI: sensor noise from render.json, and the exact operator's Monte-Carlo mismatch estimated
    /// during the run by [`MonteCarloSpread`], this field then being the sensor part; `noise_estimate` in
    /// reconstruct.json). 0: unknown, the discrepancy rule is off (unless a [`MonteCarloSpread`] is given).
    #[serde(default)]
    pub noise_norm: f64,
    /// PnP only: the denoiser's weights file (safetensors); `None`: the embedded checkpoint.
    #[serde(default)]
    pub denoiser: Option<String>,
    /// PnP only: the first `tv_warmup` iterations denoise with TV (`tv_weight`, `tv_iterations`,
    /// `tv_coupling`) before the network takes over, as PnP-SCI starts from GAP-TV (Yuan et al. 2020): the
    /// network, trained on Gaussian noise, does not fill the pixels the mask closes; TV does.
    #[serde(default)]
    pub tv_warmup: usize,
    /// PnP only: the σ of the first network denoising is the TV iterate's estimated error,
    /// clamp([`PNP_SIGMA_GAIN`]·ê, σ_min, σ_max), ê = rms(x − TV(x))/max x of the last TV step (what TV
    /// removed: the artefact level the network must remove); false: σ_max.
    #[serde(default)]
    pub sigma_auto: bool,
}

impl Default for SolverConfig {
    fn default() -> Self {
        Self::gap_tv()
    }
}

impl SolverConfig {
    /// GAP-TV, accelerated: at most [`GAP_TV_ITERATIONS`] iterations, the discrepancy rule with τ =
    /// [`GAP_TV_DISCREPANCY`] (on when the caller gives δ, [`SolverConfig::noise_norm`]), λ = 1, TV weight
    /// 0.1, 5 Chambolle iterations, vectorial coupling (measured: docs/reconstruction.md, "Defaults and
    /// stopping").
    pub fn gap_tv() -> Self {
        SolverConfig {
            solver: SolverKind::GapTv,
            iterations: GAP_TV_ITERATIONS,
            step: 1.0,
            tv_weight: 0.1,
            tv_iterations: 5,
            tv_coupling: TvCoupling::Vectorial,
            accelerated: true,
            admm_eta: 0.01,
            sigma_max: 0.0,
            sigma_min: 0.0,
            tolerance: 0.0,
            discrepancy: GAP_TV_DISCREPANCY,
            noise_norm: 0.0,
            denoiser: None,
            tv_warmup: 0,
            sigma_auto: false,
        }
    }

    /// PnP-GAP: accelerated GAP-TV to its discrepancy stop (at most [`PNP_TV_WARMUP`] iterations), then
    /// [`PNP_NETWORK_ITERATIONS`] accelerated GAP steps with the embedded learned denoiser, σ decaying
    /// geometrically from [`PNP_SIGMA_MAX`] to [`PNP_SIGMA_MIN`], no early stop in the network phase;
    /// docs/reconstruction.md, "Plug-and-play", and MODEL.md rounds 6–7 for the measurements behind these defaults.
    pub fn pnp_gap() -> Self {
        SolverConfig {
            solver: SolverKind::PnpGap,
            iterations: PNP_ITERATIONS,
            tv_warmup: PNP_TV_WARMUP,
            sigma_max: PNP_SIGMA_MAX,
            sigma_min: PNP_SIGMA_MIN,
            tolerance: PNP_TOLERANCE,
            discrepancy: PNP_DISCREPANCY,
            accelerated: PNP_ACCELERATED,
            sigma_auto: false,
            ..Self::gap_tv()
        }
    }

    /// PnP-ADMM: as [`SolverConfig::pnp_gap`] with ADMM's data step (η = 0.01·max d).
    pub fn pnp_admm() -> Self {
        SolverConfig { solver: SolverKind::PnpAdmm, accelerated: false, ..Self::pnp_gap() }
    }

    /// ADMM-TV: [`ADMM_TV_ITERATIONS`] iterations at most, the discrepancy rule with τ = [`ADMM_TV_DISCREPANCY`],
    /// η = 0.01·max d, TV as GAP-TV's.
    pub fn admm_tv() -> Self {
        SolverConfig { solver: SolverKind::AdmmTv, iterations: ADMM_TV_ITERATIONS, discrepancy: ADMM_TV_DISCREPANCY, accelerated: false, ..Self::gap_tv() }
    }

    /// The defaults of `solver`.
    pub fn for_solver(solver: SolverKind) -> Self {
        match solver {
            SolverKind::GapTv => Self::gap_tv(),
            SolverKind::AdmmTv => Self::admm_tv(),
            SolverKind::PnpGap => Self::pnp_gap(),
            SolverKind::PnpAdmm => Self::pnp_admm(),
        }
    }

    /// Check the settings, naming the bad field.
    pub fn validate(&self) -> Result<()> {
        if self.iterations == 0 {
            return Err(Error::invalid("solver iterations must be ≥ 1 (got 0)"));
        }
        let max = crate::limits::MAX_ITERATIONS;
        if self.iterations > max || self.tv_iterations > max {
            return Err(Error::invalid(format!(
                "solver iterations {} / TV iterations {}: at most {max} each (src/limits.rs)",
                self.iterations, self.tv_iterations
            )));
        }
        if !(self.step.is_finite() && self.step > 0.0 && self.step <= 2.0) {
            return Err(Error::invalid(format!("solver step λ = {} must be in (0, 2]", self.step)));
        }
        if !(self.tv_weight.is_finite() && self.tv_weight >= 0.0) {
            return Err(Error::invalid(format!("TV weight {} must be finite and ≥ 0", self.tv_weight)));
        }
        if self.tv_weight > 0.0 && self.tv_iterations == 0 {
            return Err(Error::invalid("TV iterations must be ≥ 1 when the TV weight is > 0"));
        }
        if !(self.admm_eta.is_finite() && self.admm_eta >= 0.0) {
            return Err(Error::invalid(format!("ADMM η = {} must be finite and ≥ 0", self.admm_eta)));
        }
        if !(self.tolerance.is_finite() && self.tolerance >= 0.0) {
            return Err(Error::invalid(format!("stopping tolerance {} must be finite and ≥ 0", self.tolerance)));
        }
        for (name, v) in [("discrepancy τ", self.discrepancy), ("noise norm δ", self.noise_norm)] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(Error::invalid(format!("stopping rule: {name} = {v} must be finite and ≥ 0")));
            }
        }
        if self.solver.is_pnp() {
            for (name, v) in [("σ max (--sigma-max)", self.sigma_max), ("σ min (--sigma-min)", self.sigma_min)] {
                if !(v.is_finite() && v > 0.0 && v <= 1.0) {
                    return Err(Error::invalid(format!("noise schedule: {name} = {v} must be finite, > 0 and ≤ 1 (relative to the cube's peak)")));
                }
            }
            if self.sigma_min > self.sigma_max {
                return Err(Error::invalid(format!("noise schedule: σ min {} is above σ max {} (the schedule decreases)", self.sigma_min, self.sigma_max)));
            }
            if self.tv_warmup >= self.iterations {
                return Err(Error::invalid(format!("TV warm-up of {} iterations leaves none of the {} iterations to the network", self.tv_warmup, self.iterations)));
            }
        }
        Ok(())
    }
}

/// The result of [`reconstruct`]: the cube and a record the CLI serialises (the cube is written apart).
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
    /// Data-driven δ ([`MonteCarloSpread`]): (iteration k, δ̂ at θ_{k−1}) of every re-estimate; empty when δ
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
            "stopped_by": self.stopped_by,
            "iterations_run": self.iterations_run,
            "relative_changes": self.relative_changes,
        })
    }
}

/// d = ΦΦᵀ𝟙 and its guarded inverse (see the [module docs](self)).
pub struct Preconditioner {
    pub d: Vec<f32>,
    pub inverse: Vec<f32>,
}

impl Preconditioner {
    pub fn new(op: &dyn Operator) -> Self {
        let ones = vec![1.0f32; op.image_shape().len()];
        let mut x = vec![0.0f32; op.cube_shape().len()];
        op.adjoint_into(&ones, &mut x);
        let mut d = vec![0.0f32; ones.len()];
        op.apply_into(&x, &mut d);
        let max = d.iter().cloned().fold(0.0f32, f32::max);
        let inverse = d.iter().map(|&v| if v > D_GUARD * max { 1.0 / v } else { 0.0 }).collect();
        Preconditioner { d, inverse }
    }

    /// ‖r‖_{D⁻¹} = (Σ r_i² / d_i)^½ over the kept pixels.
    pub fn weighted_norm(&self, r: &[f32]) -> f64 {
        let parts: Vec<f64> = r.par_chunks(REDUCE_CHUNK).zip(self.inverse.par_chunks(REDUCE_CHUNK)).map(|(r, w)| r.iter().zip(w).map(|(v, w)| (*v as f64) * (*v as f64) * *w as f64).sum::<f64>()).collect();
        parts.iter().sum::<f64>().sqrt()
    }

    /// Largest d.
    pub fn max(&self) -> f32 {
        self.d.iter().cloned().fold(0.0, f32::max)
    }
}

/// Check a measurement and an optional initial cube against the operator.
pub(crate) fn check_inputs(op: &dyn Operator, y: &[f32], init: Option<&[f32]>, config: &SolverConfig) -> Result<()> {
    config.validate()?;
    let (c, i) = (op.cube_shape(), op.image_shape());
    if y.len() != i.len() {
        return Err(Error::invalid(format!("the measurement has {} values, the operator `{}` expects {}×{} = {}", y.len(), op.name(), i.height, i.width, i.len())));
    }
    if let Some(k) = y.iter().position(|v| !v.is_finite()) {
        return Err(Error::invalid(format!("the measurement's value at row {}, column {} is {} (not finite)", k / i.width, k % i.width, y[k])));
    }
    if let Some(x) = init {
        if x.len() != c.len() {
            return Err(Error::invalid(format!("the initial cube has {} values, expected {}×{}×{} = {}", x.len(), c.height, c.width, c.bands, c.len())));
        }
        if let Some(k) = x.iter().position(|v| !v.is_finite()) {
            return Err(Error::invalid(format!("the initial cube's value {k} is {} (not finite)", x[k])));
        }
    }
    Ok(())
}

/// Fixed chunk length of the f64 reductions below: partial sums per chunk, added in chunk order, so the
/// stopping rule's norms (and the δ̂ they are compared with) are bit-identical for any thread count.
const REDUCE_CHUNK: usize = 1 << 16;

/// ‖a − b‖₂ (f64; deterministic for any thread count).
pub(crate) fn residual_norm(y: &[f32], phix: &[f32]) -> f64 {
    let parts: Vec<f64> = y.par_chunks(REDUCE_CHUNK).zip(phix.par_chunks(REDUCE_CHUNK)).map(|(a, b)| a.iter().zip(b).map(|(a, b)| ((*a - *b) as f64).powi(2)).sum::<f64>()).collect();
    parts.iter().sum::<f64>().sqrt()
}

/// ‖y‖₂, or 1 for a zero measurement (so relative residuals stay finite).
pub(crate) fn scale(y: &[f32]) -> f64 {
    let n = dot(y, y).sqrt();
    if n > 0.0 {
        n
    } else {
        1.0
    }
}

/// GAP-TV default: the iteration cap (accelerated GAP peaks at 157–300 iterations on the natural scenes).
pub const GAP_TV_ITERATIONS: usize = 300;
/// GAP-TV default: τ of the discrepancy rule. Measured: accelerated GAP-TV's best iterate has
/// ‖y − Φθ‖ = 0.62–0.81 δ̂ (median 0.67) on the 12 natural-scene cells; τ = 0.65 keeps the mean within
/// 0.06 dB of the best iterate (τ = 1 stops after ≈ 25 iterations, 2.5 dB short): TV, not early stopping,
/// regularises, and the rule guards against the long runs' over-fitting.
pub const GAP_TV_DISCREPANCY: f64 = 0.65;
/// ADMM-TV default: the iteration cap.
pub const ADMM_TV_ITERATIONS: usize = 100;
/// ADMM-TV default: τ of the discrepancy rule (GAP-TV's value; not measured for ADMM).
pub const ADMM_TV_DISCREPANCY: f64 = 0.65;
/// PnP default: τ of the network phase's discrepancy rule: 0, off — the network phase is a fixed schedule of
/// [`PNP_NETWORK_ITERATIONS`] calls (its cap is the stopping rule; the TV phase keeps GAP-TV's discrepancy stop).
/// With τ = 1 (the former default) the phase ended after its first call: the TV phase hands over at
/// ‖y − Φθ‖ ≤ 0.65 δ and the network keeps the fit, while every later call gains (MODEL.md, round 6).
pub const PNP_DISCREPANCY: f64 = 0.0;
/// PnP default: iterations at most, the TV phase's cap included: the cap plus [`PNP_NETWORK_ITERATIONS`].
pub const PNP_ITERATIONS: usize = PNP_TV_WARMUP + PNP_NETWORK_ITERATIONS;
/// PnP default: network iterations after the TV phase (accelerated GAP steps between them), σ 0.2 → 0.05.
/// Chosen on validation renders (dead leaves, never the natural scenes; MODEL.md rounds 6–7) by the rule:
/// the most PSNR whose SAM is no worse than one call's (SP and mSP). With the round-4 weights one call gains
/// +0.49 / +0.46 dB over GAP-TV (SP / mSP, SAM 9.01° / 9.08°), 5 calls +0.85 / +0.80 (SAM 9.00° / 9.04°),
/// 20 calls +1.51 / +1.41 dB but SAM 11.39° / 11.58° (the later calls' data steps bend the spectra of dark
/// and mid-bright pixels, round 7). (Rounds 1–3's weights lost with every call after the first.) Round 9's wider
/// weights (width 64, MODEL.md) keep the schedule: 5 calls gain +0.24 dB more than round 4's on the validation
/// renders, 12 calls less. Cost: one network call each (round 9: 1.4 CPU-s at 256², 6.9 at 512², `cargo bench
/// --bench recon`; the width-32 network 0.7 at 256²).
pub const PNP_NETWORK_ITERATIONS: usize = 5;
/// PnP default: the TV phase's cap (GAP-TV's own cap; the phase usually ends earlier, at GAP-TV's
/// discrepancy stop [`PNP_TV_DISCREPANCY`]).
pub const PNP_TV_WARMUP: usize = GAP_TV_ITERATIONS;
/// PnP: τ of the TV phase's discrepancy stop (GAP-TV's default τ: the network starts from GAP-TV's result).
pub const PNP_TV_DISCREPANCY: f64 = GAP_TV_DISCREPANCY;
/// PnP-GAP default: the accelerated GAP update in both phases (GAP-TV's default).
pub const PNP_ACCELERATED: bool = true;
/// PnP default: σ_1, relative to the cube's peak (the ceiling of σ_1 with `sigma_auto`): the top of the
/// network's Gaussian training range (σ ~ U[0, 0.2]; round 4 also saw PnP's artefact pairs at σ 0.3/0.4;
/// 0.2 beats 0.3 as the start of a multi-call schedule on validation renders, MODEL.md round 6); GAP-TV's stopped iterate is ≈ 0.1–0.2 of the peak off the truth
/// (RMSE), far above what TV removed in its last step (ê ≈ 0.01–0.017), so `sigma_auto` is off by default.
pub const PNP_SIGMA_MAX: f32 = 0.2;
/// PnP default: the floor σ_min the schedule decays to, relative to the peak (0.05 beats 0.02 and 0.08 at
/// 20 calls on validation renders, MODEL.md round 6; at 5 calls 0.05 and 0.1 tie in PSNR and 0.05 keeps SAM
/// lower, round 7).
pub const PNP_SIGMA_MIN: f32 = 0.05;
/// PnP: σ_1 = gain·ê (ê the TV iterate's estimated error, [`SolverConfig::sigma_auto`]).
pub const PNP_SIGMA_GAIN: f32 = 1.0;
/// PnP default: the relative-change tolerance of the stopping rule: 0, off (the network phase runs its
/// [`PNP_NETWORK_ITERATIONS`] calls, the schedule chosen on validation; [`PNP_DISCREPANCY`]).
pub const PNP_TOLERANCE: f64 = 0.0;

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

/// The noise-level schedule of the plug-and-play solvers: geometric from σ_max (iteration 1) to σ_min
/// (iteration K), σ_k = σ_max·(σ_min/σ_max)^((k−1)/(K−1)) — the continuous form of PnP-SCI's decreasing
/// σ stages (Yuan et al., CVPR 2020) and of DRUNet's log-spaced schedule (Zhang et al., TPAMI 2021): large σ
/// first, while the iterate is far from the measurement's solution set, small σ last, so the prior neither
/// freezes early errors nor keeps smoothing the converged cube. σ is relative to the cube's peak.
pub fn sigma_schedule(sigma_max: f32, sigma_min: f32, iterations: usize, k: usize) -> f32 {
    if iterations <= 1 {
        return sigma_max;
    }
    let t = (k.clamp(1, iterations) - 1) as f64 / (iterations - 1) as f64;
    (sigma_max as f64 * (sigma_min as f64 / sigma_max as f64).powf(t)) as f32
}

/// PnP's input scale: the network sees x/p with p the largest inlier of x, p = max{x_i : x_i ≤
/// [`PNP_SCALE_GAIN`]·Q(x)}, Q the [`PNP_SCALE_QUANTILE`] quantile of x (1 when p ≤ 0 or not finite). The
/// natural-scene cubes themselves have their peak at 1.00–1.11 × Q (the six scenes at 128², `data/scenes`);
/// the GAP iterate the network is handed has sparser spikes (max x = 1.5–3.9 × Q on the exact and shift cells
/// of SP/mSP at 128²), which the bound now leaves out: measured there, PnP changes by +0.00 to +0.08 dB
/// (docs/reconstruction.md, "Plug-and-play"). Outlier voxels (fewer than 1 − Q of them) cannot set the scale:
/// with p = max x, one voxel at 100× the peak divided the rest of the cube by 100 and the network, trained at
/// peak ≈ 1 with σ relative to it, smoothed the whole cube away.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct NetworkScale {
    /// p, the divisor.
    pub scale: f32,
    /// max x.
    pub max: f32,
    /// Q(x).
    pub quantile: f32,
}

/// PnP input scale: the quantile of x the scale is bounded by (see [`NetworkScale`]).
pub const PNP_SCALE_QUANTILE: f64 = 0.999;
/// PnP input scale: values above this gain × the [`PNP_SCALE_QUANTILE`] quantile are outliers (see [`NetworkScale`]).
pub const PNP_SCALE_GAIN: f32 = 1.5;

impl NetworkScale {
    /// The scale of `x` (`scratch` takes a copy of x for the quantile's selection; deterministic).
    pub fn of(x: &[f32], scratch: &mut Vec<f32>) -> NetworkScale {
        let max = x.par_iter().cloned().reduce(|| f32::MIN, f32::max);
        if x.is_empty() {
            return NetworkScale { scale: 1.0, max, quantile: f32::NAN };
        }
        scratch.clear();
        scratch.extend_from_slice(x);
        let k = ((x.len() - 1) as f64 * PNP_SCALE_QUANTILE).round() as usize;
        let (_, q, above) = scratch.select_nth_unstable_by(k, f32::total_cmp);
        let quantile = *q;
        // The largest inlier: max x when no voxel exceeds the bound (then bit for bit the former scale).
        let bound = PNP_SCALE_GAIN * quantile;
        let p = if max <= bound { max } else { above.iter().cloned().filter(|&v| v <= bound).fold(quantile, f32::max) };
        NetworkScale { scale: if p.is_finite() && p > 0.0 { p } else { 1.0 }, max, quantile }
    }
}

/// out ← p·D(x/p, σ) with p the [`NetworkScale`] of x: the plug-and-play solvers' call of a denoiser trained at
/// peak ≈ 1 (σ relative to p). `scratch` holds the scaled copy. Returns the scale.
pub fn denoise_at_network_scale(denoiser: &mut dyn Denoiser, x: &[f32], out: &mut [f32], shape: CubeShape, sigma: f32, scratch: &mut Vec<f32>) -> Result<NetworkScale> {
    let s = NetworkScale::of(x, scratch);
    let p = s.scale;
    scratch.resize(x.len(), 0.0);
    scratch.par_iter_mut().zip(x.par_iter()).for_each(|(s, x)| *s = *x / p);
    denoiser.denoise(scratch, out, shape, sigma)?;
    out.par_iter_mut().for_each(|v| *v *= p);
    Ok(s)
}

/// The prior step the solvers share: θ ← D(x, σ), and PnP's two phases. For PnP (`normalise`) the cube is
/// divided by its scale p ([`NetworkScale`]: its peak, leaving out outliers above [`PNP_SCALE_GAIN`] times its
/// [`PNP_SCALE_QUANTILE`] quantile) before the denoiser and multiplied by p after, so the network sees the
/// scale it was trained on (peak ≈ 1) and σ is relative to p ([`denoise_at_network_scale`]); TV gets x as it
/// is (bit for bit the direct call).
///
/// **Phases (PnP).** The TV phase (GAP-TV / ADMM-TV's own step, at most `tv_warmup` iterations) ends at its
/// cap or, earlier, when the caller finds ‖y − Φθ‖ ≤ [`PNP_TV_DISCREPANCY`]·δ (GAP-TV's own stop: the
/// network starts from GAP-TV's stopped iterate). The network phase then runs at most
/// `iterations − tv_warmup` iterations with σ_j = [`sigma_schedule`](σ_1, σ_min, N, j), σ_1 the
/// [`NoiseStart`] of the configuration (the TV iterate's estimated error, or σ_max).
pub(crate) struct PriorStep<'d> {
    denoiser: &'d mut dyn Denoiser,
    normalise: bool,
    scaled: Vec<f32>,
    /// PnP's TV phase: (its iteration cap, the TV denoiser).
    warmup: Option<(usize, TvDenoiser)>,
    /// The last TV iteration (the network runs from the next one); `None` while the TV phase runs.
    switched_after: Option<usize>,
    /// Network iterations at most (N).
    network_iterations: usize,
    /// ê: rms(x_k − TV(x_k)) / max x_k of the last TV step (what TV removed: the iterate's artefact level).
    tv_error: f32,
    sigma_first: f32,
    sigma_min: f32,
    sigma_max: f32,
    sigma_auto: bool,
    /// The network's input scale at the last network call (for the record).
    last_scale: Option<NetworkScale>,
}

impl<'d> PriorStep<'d> {
    /// The prior step of `config`'s solver around `denoiser` (PnP: normalised, with the TV phase).
    pub(crate) fn new(denoiser: &'d mut dyn Denoiser, config: &SolverConfig) -> Self {
        let pnp = config.solver.is_pnp();
        let warmup = (pnp && config.tv_warmup > 0).then(|| (config.tv_warmup, TvDenoiser::new(config.tv_weight, config.tv_iterations, config.tv_coupling)));
        let mut s = PriorStep {
            denoiser,
            normalise: pnp,
            scaled: Vec::new(),
            switched_after: None,
            network_iterations: if pnp { config.iterations - config.tv_warmup } else { config.iterations },
            tv_error: f32::NAN,
            sigma_first: config.sigma_max,
            sigma_min: config.sigma_min,
            sigma_max: config.sigma_max,
            sigma_auto: config.sigma_auto,
            warmup,
            last_scale: None,
        };
        if s.warmup.is_none() {
            s.switch(0);
        }
        s
    }

    /// Whether iteration k still belongs to the TV phase.
    pub(crate) fn in_tv_phase(&self) -> bool {
        self.switched_after.is_none()
    }

    /// The first iteration of the network phase (1 for TV solvers), once known.
    pub(crate) fn first_network_iteration(&self) -> Option<usize> {
        self.switched_after.map(|k| k + 1)
    }

    /// Whether iteration k is past the run's cap (TV phase + N network iterations).
    pub(crate) fn done(&self, k: usize) -> bool {
        self.switched_after.is_some_and(|s| k > s + self.network_iterations)
    }

    /// End the TV phase after iteration `last_tv`: σ_1 from the TV iterate's error (auto) or σ_max.
    pub(crate) fn switch(&mut self, last_tv: usize) {
        if self.switched_after.is_some() {
            return;
        }
        self.switched_after = Some(last_tv);
        self.sigma_first = if self.sigma_auto && self.tv_error.is_finite() && self.tv_error > 0.0 {
            (PNP_SIGMA_GAIN * self.tv_error).clamp(self.sigma_min, self.sigma_max)
        } else {
            self.sigma_max
        };
    }

    /// σ of iteration k (0 in the TV phase and for TV solvers).
    pub(crate) fn sigma(&self, k: usize) -> f32 {
        match self.switched_after {
            Some(s) if self.normalise && k > s => sigma_schedule(self.sigma_first, self.sigma_min, self.network_iterations, k - s),
            _ => 0.0,
        }
    }

    /// θ ← D(x) at iteration k (1-based). In the TV phase, also ê; at its cap, the switch.
    pub(crate) fn apply(&mut self, k: usize, x: &[f32], out: &mut [f32], shape: CubeShape) -> Result<()> {
        if let (None, Some((cap, tv))) = (self.switched_after, self.warmup.as_mut()) {
            let cap = *cap;
            tv.denoise(x, out, shape, 0.0)?;
            let peak = x.par_iter().cloned().reduce(|| f32::MIN, f32::max);
            let ss = x.par_iter().zip(out.par_iter()).map(|(a, b)| ((*a - *b) as f64).powi(2)).sum::<f64>();
            self.tv_error = if peak.is_finite() && peak > 0.0 { ((ss / x.len().max(1) as f64).sqrt() / peak as f64) as f32 } else { f32::NAN };
            if k >= cap {
                self.switch(k);
            }
            return Ok(());
        }
        let sigma = self.sigma(k);
        if !self.normalise {
            return self.denoiser.denoise(x, out, shape, sigma);
        }
        let scale = denoise_at_network_scale(self.denoiser, x, out, shape, sigma, &mut self.scaled)?;
        self.last_scale = Some(scale);
        Ok(())
    }

    /// Cube-sized buffers held (the scaled copy and the denoiser's).
    pub(crate) fn cube_buffers(&self) -> usize {
        usize::from(self.normalise) + self.denoiser.cube_buffers() + self.warmup.as_ref().map_or(0, |(_, tv)| tv.cube_buffers())
    }

    pub(crate) fn describe(&self) -> serde_json::Value {
        let mut d = self.denoiser.describe();
        if let (Some(scale), Some(o)) = (self.last_scale, d.as_object_mut()) {
            o.insert("network_input_scale".into(), serde_json::json!({"scale": scale.scale, "max": scale.max, "quantile": scale.quantile, "quantile_level": PNP_SCALE_QUANTILE, "gain": PNP_SCALE_GAIN}));
        }
        if let (true, Some(o)) = (self.normalise, d.as_object_mut()) {
            // The noise schedule as planned (the σ of the calls that ran: `sigmas` of the record), and the embedded
            // checkpoint's CRC-32 beside the one that ran (`weights_crc32`).
            let calls = self.network_iterations;
            let sigmas: Vec<f32> = (1..=calls).map(|j| sigma_schedule(self.sigma_first, self.sigma_min, calls, j)).collect();
            o.insert("schedule".into(), serde_json::json!({"network_calls_max": calls, "sigma_first": self.sigma_first, "sigma_min": self.sigma_min, "sigmas": sigmas, "rule": "σ_j = σ_1·(σ_min/σ_1)^((j−1)/(N−1)), j = 1…N"}));
            o.insert("embedded_weights_crc32".into(), serde_json::json!(super::prior::network::weights_crc32(None).ok()));
        }
        if let (Some((n, tv)), Some(o)) = (&self.warmup, d.as_object_mut()) {
            o.insert(
                "tv_warmup".into(),
                serde_json::json!({"iterations": n, "iterations_run": self.switched_after, "tv": tv.describe(),
                    "tv_error_estimate": if self.tv_error.is_finite() { Some(self.tv_error) } else { None },
                    "sigma_first": self.sigma_first, "sigma_auto": self.sigma_auto}),
            );
        }
        d
    }
}

/// The discrepancy principle (Morozov 1966; for iterative regularisation, Engl, Hanke & Neubauer,
/// "Regularization of Inverse Problems", 1996, §4.3 and §7): an iterative method applied to y = Φx + n
/// fits the noise once ‖y − Φθ‖ falls below ‖n‖, so it stops at the first θ_{k−1} with
/// ‖y − Φθ_{k−1}‖₂ ≤ τ·δ, δ = [`SolverConfig::noise_norm`] (the expected ‖n‖, here the sensor noise and the
/// exact operator's Monte-Carlo mismatch), τ = [`SolverConfig::discrepancy`]. Needs no ground truth. The
/// first iterate tested is θ₁ (at least one update runs) and, for PnP, the first network output (the TV
/// warm-up always completes, as for the relative-change rule).
pub struct Discrepancy {
    tau: f64,
    /// δ in use: the configuration's, or the latest data-driven estimate ([`MonteCarloSpread`]).
    delta: f64,
    /// Whether δ is re-estimated during the run (the rule is then on whenever τ > 0).
    tracked: bool,
}

impl Discrepancy {
    pub fn new(config: &SolverConfig) -> Self {
        Discrepancy { tau: config.discrepancy, delta: config.noise_norm, tracked: false }
    }

    /// The rule with δ re-estimated during the run (see [`MonteCarloSpread`]); `config.noise_norm` is the
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
    /// iteration or a later one (`first_network`: [`PriorStep`]'s; 1 for TV solvers, so k ≥ 2).
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

impl MonteCarloSpread<'_> {
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
    if let Some(s) = spread {
        s.check(op)?;
    }
    if config.solver.is_gap() {
        super::gap::gap_estimated(op, y, init, config, denoiser, progress, observe, spread)
    } else {
        super::admm::admm_estimated(op, y, init, config, denoiser, progress, observe, spread)
    }
}
