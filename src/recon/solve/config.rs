//! The solvers' settings: [`SolverKind`] (which method) and [`SolverConfig`] (its parameters, defaults and
//! validation), with the measured defaults of every solver (docs/reconstruction.md, "Defaults and
//! stopping"; PnP: "Plug-and-play").
use crate::error::{Error, Result};
use crate::recon::tv::TvCoupling;
use std::str::FromStr;

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

/// The solvers a setting applies to: given to another solver it is refused, never ignored
/// ([`SettingScope::check`]). The settings are named as [`SolverConfig`]'s fields (the Python keywords).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SettingScope {
    /// Every solver (iterations, step, the TV settings — PnP's TV phase uses them —, the stopping rules).
    Every,
    /// GAP's data step: `accelerated` (and the CLI's `--plain`).
    Gap,
    /// ADMM's data step: `admm_eta`.
    Admm,
    /// The learned denoiser and its schedule: `denoiser`, `sigma_max`, `sigma_min`, `sigma_auto`, `tv_warmup`,
    /// `equivariant`, `equivariant_seed`.
    Pnp,
}

impl SettingScope {
    /// The scope of the setting `key` (a [`SolverConfig`] field name; `plain` is GAP's).
    pub fn of(key: &str) -> SettingScope {
        match key {
            "accelerated" | "plain" => SettingScope::Gap,
            "admm_eta" => SettingScope::Admm,
            "denoiser" | "sigma_max" | "sigma_min" | "sigma_auto" | "tv_warmup" | "equivariant" | "equivariant_seed" => SettingScope::Pnp,
            _ => SettingScope::Every,
        }
    }

    pub fn contains(self, solver: SolverKind) -> bool {
        match self {
            SettingScope::Every => true,
            SettingScope::Gap => solver.is_gap(),
            SettingScope::Admm => !solver.is_gap(),
            SettingScope::Pnp => solver.is_pnp(),
        }
    }

    /// The solvers of the scope, for messages.
    pub fn solvers(self) -> &'static str {
        match self {
            SettingScope::Every => "every solver",
            SettingScope::Gap => "gap-tv and pnp-gap only",
            SettingScope::Admm => "admm-tv and pnp-admm only",
            SettingScope::Pnp => "pnp-gap and pnp-admm only",
        }
    }

    /// Refuse the given settings (`(key, shown)`: the field name and how the caller names it, e.g.
    /// `("sigma_max", "--sigma-max")`) that do not apply to `solver`, all named in one message.
    pub fn check(solver: SolverKind, given: &[(&str, &str)]) -> Result<()> {
        let bad: Vec<(&str, SettingScope)> = given.iter().map(|&(k, shown)| (shown, SettingScope::of(k))).filter(|(_, s)| !s.contains(solver)).collect();
        if bad.is_empty() {
            return Ok(());
        }
        // Every foreign setting, grouped by the solvers it belongs to (in the order given).
        let mut scopes: Vec<SettingScope> = Vec::new();
        for (_, s) in &bad {
            if !scopes.contains(s) {
                scopes.push(*s);
            }
        }
        let groups: Vec<String> = scopes
            .iter()
            .map(|&scope| {
                let names: Vec<&str> = bad.iter().filter(|(_, s)| *s == scope).map(|(n, _)| *n).collect();
                format!("{}: {} {}", names.join(" / "), if names.len() == 1 { "applies to" } else { "apply to" }, scope.solvers())
            })
            .collect();
        Err(Error::invalid(format!("{}, not `{}` (a setting another solver would ignore is refused)", groups.join("; "), solver.name())))
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
    /// cube scaled to peak 1; see [`sigma_schedule`](super::prior_step::sigma_schedule)).
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
    /// `discrepancy`·`noise_norm`, returning θ_{k−1} (τ ≥ 1 in theory; 0 turns the rule off). See [`Discrepancy`](super::stopping::Discrepancy).
    #[serde(default)]
    pub discrepancy: f64,
    /// The expected norm δ = E‖y − Φx_true‖₂ of the measurement's noise and operator mismatch, in acquisition
    /// units (the CLI: sensor noise from render.json, and the exact operator's Monte-Carlo mismatch estimated
    /// during the run by [`MonteCarloSpread`](super::noise::MonteCarloSpread), this field then being the sensor part; `noise_estimate` in
    /// reconstruct.json). 0: unknown, the discrepancy rule is off (unless a [`MonteCarloSpread`](super::noise::MonteCarloSpread) is given).
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
    /// PnP only: equivariant PnP — each network call denoises a randomly flipped or rotated iterate and
    /// transforms the result back, θ = g⁻¹ D(g x, σ), g drawn from the dihedral group (the 8 flips and quarter
    /// turns of the spatial axes for square cubes, the 4 flips otherwise) by
    /// [`Dihedral::draw`](crate::recon::prior::dihedral::Dihedral::draw)(`equivariant_seed`, j) at the j-th
    /// network call (default [`PNP_EQUIVARIANT`]).
    #[serde(default)]
    pub equivariant: bool,
    /// PnP only: the seed of the equivariant transforms' stream (default 0).
    #[serde(default)]
    pub equivariant_seed: u64,
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
            equivariant: false,
            equivariant_seed: 0,
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
            equivariant: PNP_EQUIVARIANT,
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
        if self.discrepancy > MAX_DISCREPANCY {
            return Err(Error::invalid(format!(
                "stopping rule: discrepancy τ = {}: at most {MAX_DISCREPANCY} (τ ≈ 1 in theory, {GAP_TV_DISCREPANCY} by default; a larger τ stops every run before its first update, and τ·δ overflowed the record)",
                crate::limits::fmt_num(self.discrepancy)
            )));
        }
        if self.solver.is_pnp() {
            // Named by their command-line options (Python's keywords in the binding's messages).
            for (name, v) in [("σ max (--sigma-max)", self.sigma_max), ("σ min (--sigma-min)", self.sigma_min)] {
                if !(v.is_finite() && v > 0.0 && v <= 1.0) {
                    return Err(Error::invalid(format!("noise schedule: {name} = {v} must be finite, > 0 and ≤ 1 (relative to the cube's peak)")));
                }
            }
            if self.sigma_min > self.sigma_max {
                return Err(Error::invalid(format!("noise schedule: σ min (--sigma-min) {} is above σ max (--sigma-max) {} (the schedule decreases)", self.sigma_min, self.sigma_max)));
            }
            if self.tv_warmup >= self.iterations {
                return Err(Error::invalid(format!("TV warm-up of {} iterations leaves none of the {} iterations to the network", self.tv_warmup, self.iterations)));
            }
        } else if self.equivariant {
            return Err(Error::invalid(format!("equivariant (random flips/rotations around the denoiser) applies to pnp-gap and pnp-admm only, not `{}`", self.solver.name())));
        }
        Ok(())
    }
}

/// The largest discrepancy factor τ accepted (τ ≈ 1 in theory; a larger one only stops before the first update).
pub const MAX_DISCREPANCY: f64 = 1e3;

/// A solver setting the solvers hold in f32 (`tv_weight`, `step`, `admm_eta`, `sigma_max`, `sigma_min`), taken
/// from the f64 a front end was given and checked as given: finite, and 0 or a normal f32 in magnitude. `1e200`
/// was reported as "inf", `1e-50` ran as 0 while the record said 1e-50, and Python cast silently (held-out
/// batteries, rounds 8 and 10). `name` is the front end's (`--tv-weight`, `tv_weight`).
pub fn f32_setting(name: &str, v: f64) -> Result<f32> {
    let f = v as f32;
    if v.is_finite() && f.is_finite() && (v == 0.0 || f.abs() >= f32::MIN_POSITIVE) {
        return Ok(f);
    }
    Err(Error::invalid(format!(
        "{name} {}: must be finite, and 0 or within f32's range in magnitude, the solvers' precision ({:.3e} to {:.3e})",
        crate::limits::fmt_num(v),
        f32::MIN_POSITIVE,
        f32::MAX
    )))
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
/// PnP default: equivariant PnP off/on (see [`SolverConfig::equivariant`]): off. Measured on the validation
/// renders (dead leaves, 128², SP/mSP, 5 calls; docs/reconstruction.md, "Equivariant PnP"): −0.01 dB with seed 0,
/// −0.11 / −0.16 dB with seeds whose first call draws a quarter turn (the network's artefact training flipped its
/// pairs but never turned them: the dispersion stays along x), ±0.02 dB with the flips alone.
pub const PNP_EQUIVARIANT: bool = false;
/// PnP default: the relative-change tolerance of the stopping rule: 0, off (the network phase runs its
/// [`PNP_NETWORK_ITERATIONS`] calls, the schedule chosen on validation; [`PNP_DISCREPANCY`]).
pub const PNP_TOLERANCE: f64 = 0.0;

#[cfg(test)]
mod tests {
    use super::*;

    /// Each setting belongs to its solvers; another solver refuses it, naming every foreign setting of one scope.
    #[test]
    fn settings_of_other_solvers_are_refused() {
        use SolverKind::*;
        for (key, ok, bad) in [("accelerated", PnpGap, AdmmTv), ("admm_eta", PnpAdmm, GapTv), ("sigma_max", PnpAdmm, GapTv), ("iterations", AdmmTv, AdmmTv)] {
            assert!(SettingScope::check(ok, &[(key, key)]).is_ok(), "{key} on {}", ok.name());
            if SettingScope::of(key) != SettingScope::Every {
                let e = SettingScope::check(bad, &[(key, key)]).unwrap_err().to_string();
                assert!(e.contains(&format!("{key}: applies to")) && e.contains(bad.name()), "{e}");
            }
        }
        let e = SettingScope::check(GapTv, &[("sigma_max", "--sigma-max"), ("tv_warmup", "--tv-warmup")]).unwrap_err().to_string();
        assert!(e.starts_with("--sigma-max / --tv-warmup: apply to pnp-gap and pnp-admm only, not `gap-tv`"), "{e}");
        let e = SettingScope::check(AdmmTv, &[("accelerated", "accelerated"), ("sigma_max", "sigma_max")]).unwrap_err().to_string();
        assert!(e.starts_with("accelerated: applies to gap-tv and pnp-gap only; sigma_max: applies to pnp-gap and pnp-admm only, not `admm-tv`"), "{e}");
    }

    #[test]
    fn the_discrepancy_factor_is_bounded() {
        assert!(SolverConfig { discrepancy: MAX_DISCREPANCY, ..SolverConfig::gap_tv() }.validate().is_ok());
        let e = SolverConfig { discrepancy: 1e308, ..SolverConfig::gap_tv() }.validate().unwrap_err().to_string();
        assert!(e.contains("discrepancy τ = 1e308: at most 1000"), "{e}");
    }
}
