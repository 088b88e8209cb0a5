//! The solve of a reconstruction: [`run_solver`] (the configured solver with its denoiser, an optional
//! data-driven δ and an optional truth observer; the Python `reconstruct` calls it too) and [`solve`] /
//! [`solve_observed`] (settings → configuration → solve → the record `reconstruct` and `study` write: the
//! resolved settings, the residuals, the stopping record with the noise estimate).
use super::settings::{solver_config, SolveSettings};
use super::solved::{truth_residual, Solved};
use crate::error::{Error, Result};
use crate::recon::{MonteCarloSpread, Operator, Reconstruction, SolverConfig};
use serde_json::Value;

/// Run the solver on `op` and the acquisition `y` (starting from 0); `progress(k, residual)` after each
/// iteration k ([`crate::recon::reconstruct`]'s).
/// `twin`: the operator's twin for the data-driven δ (when `s.noise` has a [`SpreadPlan`](super::SpreadPlan)).
pub fn solve(op: &dyn Operator, y: &[f32], s: &SolveSettings, progress: &(dyn Fn(usize, f64) + Sync), twin: Option<&dyn Operator>) -> Result<Solved> {
    solve_observed(op, y, s, progress, None, twin)
}

/// The solver `cfg` names on `op` and `y` from `init` (0 when `None`), with its denoiser
/// ([`crate::recon::solver::config_denoiser`]), δ re-estimated from the data when `spread` is given, and with a
/// `truth` cube (same shape) the PSNR (paper convention) of every iterate θ_k (the second value; empty
/// without a truth). `progress(k, residual)` after each iteration. `cancel`: the caller's stop request, polled
/// once per iteration ([`Error::Interrupted`] once cancelled; [`crate::cancel`]); `None`: never stopped.
#[allow(clippy::too_many_arguments)]
pub fn run_solver(
    op: &dyn Operator,
    y: &[f32],
    init: Option<&[f32]>,
    cfg: &SolverConfig,
    spread: Option<&MonteCarloSpread<'_>>,
    truth: Option<&[f32]>,
    progress: &(dyn Fn(usize, f64) + Sync),
    cancel: Option<&crate::cancel::Cancel>,
) -> Result<(Reconstruction, Vec<f64>)> {
    crate::cancel::check(cancel)?;
    let mut denoiser = crate::recon::solver::config_denoiser(cfg)?;
    let shape = op.cube_shape();
    let mut psnrs: Vec<f64> = Vec::new();
    let mut observe = |_: usize, theta: &[f32]| {
        if let Some(t) = truth {
            psnrs.push(crate::recon::metrics::psnr_db(t, theta, shape).unwrap_or(f64::NAN));
        }
    };
    let problem = crate::recon::Problem { op, y, init, config: cfg, progress, observe: &mut observe, spread, cancel };
    let rec = crate::recon::solve_problem(problem, denoiser.as_mut())?;
    Ok((rec, psnrs))
}

/// [`solve`], and with a `truth` cube (same shape) the PSNR (paper convention) of every iterate θ_k,
/// recorded as `psnr_per_iteration` beside ‖y − Φx_true‖₂/‖y‖₂ (`truth_residual`): evaluation only, for
/// measuring defaults and stopping rules (the solver never sees it).
/// With a [`SpreadPlan`](super::SpreadPlan) in `s.noise` and its `twin`, δ's Monte-Carlo term is re-estimated during the solve
/// (and, with `truth`, the estimator at the truth is recorded as `truth_spread_estimate`).
/// `unrolled` ([`super::unrolled::solve_unrolled`]): `s.unrolled` must hold the prepared network; no δ, no twin.
pub fn solve_observed(op: &dyn Operator, y: &[f32], s: &SolveSettings, progress: &(dyn Fn(usize, f64) + Sync), truth: Option<&[f32]>, twin: Option<&dyn Operator>) -> Result<Solved> {
    if super::unrolled::is_unrolled(&s.solver) {
        // The unrolled network (no iterations, no δ): prepared from the render record by the caller.
        let p = s.unrolled.as_deref().ok_or_else(|| Error::invalid("internal: --solver unrolled needs its network prepared against the render record (recon::pipeline::unrolled::prepare)"))?;
        return super::unrolled::solve_unrolled(op, y, p, truth, progress);
    }
    let cfg = solver_config(s)?;
    let plan = s.noise.as_ref().and_then(|n| n.spread.clone());
    let spread = match (&plan, twin) {
        (Some(p), Some(t)) => Some(MonteCarloSpread { twin: t, factor: p.factor, sensor_norm: p.sensor_norm, every: crate::recon::solver::SPREAD_EVERY }),
        (Some(_), None) => return Err(Error::invalid("internal: the data-driven noise estimate needs the operator's twin")),
        _ => None,
    };
    let (rec, psnrs) = run_solver(op, y, None, &cfg, spread.as_ref(), truth, progress, None)?;
    if let Some(i) = rec.cube.iter().position(|v| !v.is_finite()) {
        let peak = y.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        return Err(Error::invalid(format!(
            "the solver produced a non-finite value at index {i} (the acquisition's largest |value| is {}; values beyond ±{:.3e} can overflow the f32 sums): not written",
            crate::limits::fmt_num(peak as f64),
            crate::limits::MAX_SCENE_VALUE
        )));
    }
    let settings = serde_json::to_value(&rec.config).unwrap_or(Value::Null);
    let mut record = serde_json::to_value(&rec).unwrap_or(Value::Null);
    if let Some(o) = record.as_object_mut() {
        o.remove("residuals");
    }
    let ny = y.iter().map(|v| (*v as f64).powi(2)).sum::<f64>().sqrt();
    let mut noise_record = s.noise.as_ref().map(|n| n.record.clone());
    if let (Some(p), Some(o)) = (&plan, noise_record.as_mut().and_then(Value::as_object_mut)) {
        // The data-driven δ: the record's norm and Monte-Carlo term are the last estimate's.
        let mc = (rec.noise_norm.powi(2) - p.sensor_norm.powi(2)).max(0.0).sqrt();
        o.insert("norm".into(), serde_json::json!(rec.noise_norm));
        o.insert("relative".into(), serde_json::json!(if ny > 0.0 { rec.noise_norm / ny } else { 0.0 }));
        o.insert("monte_carlo_norm".into(), serde_json::json!(mc));
    }
    let mut stopping = rec.stopping_record(y, noise_record);
    if let (Some(t), Some(o)) = (truth, stopping.as_object_mut()) {
        let (phi_t, rel) = truth_residual(op, y, t);
        o.insert("truth_residual".into(), serde_json::json!(rel));
        if let Some(sp) = &spread {
            // The estimator evaluated at the truth (what δ̂ at the iterate approximates), relative to ‖y‖.
            let mut scratch = Vec::new();
            let d = sp.estimate(t, &phi_t, &mut scratch);
            o.insert("truth_spread_estimate".into(), serde_json::json!(if ny > 0.0 { d / ny } else { 0.0 }));
        }
        o.insert("psnr_per_iteration".into(), serde_json::json!(psnrs));
    }
    Ok(Solved { residuals: rec.residuals.clone(), final_residual: rec.final_residual, settings: serde_json::json!({"config": settings, "record": record}), stopping, seconds: rec.seconds, cube: rec.cube })
}
