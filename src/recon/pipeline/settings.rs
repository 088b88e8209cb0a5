//! The settings of one reconstruction ([`SolveSettings`]: solver, iterations, TV weight, PnP schedule,
//! stopping rule, noise estimate) and the [`SolverConfig`] they resolve to ([`solver_config`], checked
//! before any work by [`check_solver`]).
use super::noise::{NoiseEstimate, NoiseModel};
use crate::error::{Error, Result};
use crate::recon::solver::SettingScope;
use crate::recon::{SolverConfig, SolverKind};
use std::path::PathBuf;

/// Settings of one reconstruction (everything but the operator).
#[derive(Clone, Debug)]
pub struct SolveSettings {
    pub solver: String,
    pub iterations: Option<usize>,
    pub tv_weight: Option<f64>,
    /// GAP-TV's accelerated variant (asked for explicitly; it is gap-tv's default anyway).
    pub accelerated: bool,
    /// GAP-TV: plain GAP instead of the accelerated default.
    pub plain: bool,
    /// PnP: the denoiser's weights file (`None`: embedded).
    pub denoiser: Option<PathBuf>,
    /// PnP: the σ schedule's ends (relative to the peak).
    pub sigma_max: Option<f64>,
    pub sigma_min: Option<f64>,
    /// PnP: σ_1 from the TV iterate's estimated error instead of σ max.
    pub sigma_auto: bool,
    /// PnP: equivariant PnP on / off (`None`: the default, [`crate::recon::solver::PNP_EQUIVARIANT`]).
    pub equivariant: Option<bool>,
    /// PnP: the seed of equivariant PnP's transforms (`None`: 0).
    pub equivariant_seed: Option<u64>,
    /// The stopping rule's relative-change tolerance.
    pub tolerance: Option<f64>,
    /// PnP: TV warm-up iterations.
    pub tv_warmup: Option<usize>,
    /// The discrepancy principle's τ (`None`: the solver's default).
    pub discrepancy: Option<f64>,
    /// The measurement's expected noise norm δ ([`noise_estimate`]; `None`: unknown, the rule is off).
    pub noise: Option<NoiseEstimate>,
    /// How the exact operator's Monte-Carlo term of δ is estimated (`--noise-estimate`; `None`: not given, the
    /// default [`NoiseModel::Spread`]). Given, it is refused where δ is not used (the unrolled network, a TV
    /// solver with the rule off, a model operator: [`super::Request::validate`]).
    pub noise_model: Option<NoiseModel>,
    /// `unrolled`: the network's weights file (`None`: the committed weights of the render's system).
    pub weights: Option<PathBuf>,
    /// `unrolled`: the network loaded and checked against the render record ([`super::unrolled::prepare`]);
    /// the solve needs it.
    pub unrolled: Option<std::sync::Arc<super::unrolled::PreparedUnrolled>>,
}

impl SolveSettings {
    /// `solver` with every other setting at its default (the solver's own; δ unknown; `--noise-estimate spread`).
    pub fn new(solver: &str) -> Self {
        SolveSettings {
            solver: solver.to_string(),
            iterations: None,
            tv_weight: None,
            accelerated: false,
            plain: false,
            denoiser: None,
            sigma_max: None,
            sigma_min: None,
            sigma_auto: false,
            equivariant: None,
            equivariant_seed: None,
            tolerance: None,
            tv_warmup: None,
            discrepancy: None,
            noise: None,
            noise_model: None,
            weights: None,
            unrolled: None,
        }
    }

    /// The iterative solvers' settings given (not left at their default), as (field name — the key of
    /// [`SettingScope`] and of the Python keywords —, the command line's flag): what `unrolled` refuses whole,
    /// what another solver refuses by [`SettingScope`], what `study` checks some solver of its list takes.
    pub fn given(&self) -> Vec<(&'static str, &'static str)> {
        [
            ("iterations", "--iterations", self.iterations.is_some()),
            ("tv_weight", "--tv-weight", self.tv_weight.is_some()),
            ("accelerated", "--accelerated", self.accelerated),
            ("plain", "--plain", self.plain),
            ("denoiser", "--denoiser", self.denoiser.is_some()),
            ("sigma_max", "--sigma-max", self.sigma_max.is_some()),
            ("sigma_min", "--sigma-min", self.sigma_min.is_some()),
            ("sigma_auto", "--sigma-auto", self.sigma_auto),
            ("equivariant", "--equivariant / --no-equivariant", self.equivariant.is_some()),
            ("equivariant_seed", "--equivariant-seed", self.equivariant_seed.is_some()),
            ("tolerance", "--tolerance", self.tolerance.is_some()),
            ("tv_warmup", "--tv-warmup", self.tv_warmup.is_some()),
            ("discrepancy", "--discrepancy", self.discrepancy.is_some()),
            ("noise_estimate", "--noise-estimate", self.noise_model.is_some()),
        ]
        .into_iter()
        .filter(|g| g.2)
        .map(|(key, flag, _)| (key, flag))
        .collect()
    }
}

/// The solver configuration the settings describe (the solver's defaults, overridden by iterations / TV weight).
pub fn solver_config(s: &SolveSettings) -> Result<SolverConfig> {
    if super::unrolled::is_unrolled(&s.solver) {
        return Err(Error::invalid("internal: --solver unrolled has no iterative solver configuration (recon::pipeline::unrolled)"));
    }
    let kind: SolverKind = s.solver.parse().map_err(|_| Error::invalid(format!("--solver `{}`: use {}, or unrolled", s.solver, crate::recon::solver::SOLVER_NAMES)))?;
    let mut cfg = SolverConfig::for_solver(kind);
    if let Some(n) = s.iterations {
        cfg.iterations = n;
    }
    if let Some(w) = s.tv_weight {
        // The solvers hold the weight in f32: checked as given (1e200 was "TV weight inf", 1e-50 ran as 0).
        cfg.tv_weight = crate::recon::solve::config::f32_setting("--tv-weight", w)?;
    }
    // Settings of other solvers are refused, never ignored (one rule for the CLI and the bindings).
    SettingScope::check(kind, &s.given())?;
    if s.accelerated {
        cfg.accelerated = true;
    }
    if s.plain {
        if s.accelerated {
            return Err(Error::invalid("--plain and --accelerated: choose one"));
        }
        cfg.accelerated = false;
    }
    for (flag, v) in [("--sigma-max", s.sigma_max), ("--sigma-min", s.sigma_min), ("--tolerance", s.tolerance)] {
        if let Some(v) = v {
            if !v.is_finite() || v < 0.0 {
                return Err(Error::invalid(format!("{flag} {v}: must be finite and ≥ 0")));
            }
        }
    }
    if let Some(on) = s.equivariant {
        cfg.equivariant = on;
    }
    if let Some(seed) = s.equivariant_seed {
        if !cfg.equivariant {
            return Err(Error::invalid(format!("--equivariant-seed {seed}: seeds equivariant PnP's transforms, which are off (give --equivariant too)")));
        }
        cfg.equivariant_seed = seed;
    }
    if s.sigma_auto {
        cfg.sigma_auto = true;
    }
    if let Some(n) = s.tv_warmup {
        cfg.tv_warmup = n;
    }
    if let Some(v) = s.sigma_max {
        cfg.sigma_max = crate::recon::solve::config::f32_setting("--sigma-max", v)?;
    }
    if let Some(v) = s.sigma_min {
        cfg.sigma_min = crate::recon::solve::config::f32_setting("--sigma-min", v)?;
    }
    if let Some(v) = s.tolerance {
        cfg.tolerance = v;
    }
    if let Some(v) = s.discrepancy {
        if !v.is_finite() || v < 0.0 || v > crate::recon::solver::MAX_DISCREPANCY {
            return Err(Error::invalid(format!("--discrepancy {}: must be finite and in [0, {}] (τ ≈ 1 in theory; a larger τ stops before the first update)", crate::limits::fmt_num(v), crate::recon::solver::MAX_DISCREPANCY)));
        }
        cfg.discrepancy = v;
    }
    if let Some(n) = &s.noise {
        cfg.noise_norm = n.norm;
    }
    if let Some(p) = &s.denoiser {
        cfg.denoiser = Some(p.display().to_string());
    }
    cfg.validate()?;
    Ok(cfg)
}

/// Reject an unknown solver or bad solver settings before any work (PnP: the weights are loaded and checked;
/// unrolled: its options and `--weights` file).
pub fn check_solver(s: &SolveSettings) -> Result<()> {
    if super::unrolled::is_unrolled(&s.solver) {
        return check_unrolled_settings(s);
    }
    if s.weights.is_some() {
        return Err(Error::invalid(format!("--weights applies to --solver unrolled only (the unrolled network's weights), not `{}`; the PnP solvers' network is --denoiser", s.solver)));
    }
    let cfg = solver_config(s)?;
    if cfg.solver.is_pnp() {
        crate::recon::solver::config_denoiser(&cfg)?;
    }
    if let (Some(m), false) = (s.noise_model, uses_noise_estimate(&cfg)) {
        // It was accepted and changed nothing (a held-out battery, round 10).
        return Err(Error::invalid(format!(
            "--noise-estimate {}: {} stops by no discrepancy rule (τ = 0), so δ is not used; give --discrepancy too, or drop it",
            m.name(),
            cfg.solver.name()
        )));
    }
    Ok(())
}

/// Whether a solve with `cfg` uses the noise estimate δ: the discrepancy rule (τ > 0), or PnP's TV phase, which
/// stops by GAP-TV's rule whatever the network phase's τ.
pub fn uses_noise_estimate(cfg: &SolverConfig) -> bool {
    cfg.discrepancy > 0.0 || cfg.solver.is_pnp()
}

/// The settings `unrolled` takes, checked before any work: the iterative solvers' options are refused (the
/// network has a fixed number of stages, its weights' `stages`), and a `--weights` file is read and checked
/// (format, architecture, tensors).
fn check_unrolled_settings(s: &SolveSettings) -> Result<()> {
    let given: Vec<&str> = s.given().into_iter().map(|(_, flag)| flag).collect();
    if !given.is_empty() {
        return Err(Error::invalid(format!("{}: not options of --solver unrolled (a fixed number of stages, the weights' `stages`; no iterations, prior or stopping rule to set)", given.join(", "))));
    }
    super::unrolled::check_weights_file(s.weights.as_deref())
}
