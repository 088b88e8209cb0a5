//! The reconstruction pipeline of `diffcassi reconstruct` and `study`: a render folder read back
//! ([`RenderRecord`]) → the operator rebuilt from it ([`build_operator`], with the exact operator's seed,
//! [`operator_seed`]) → the noise estimate δ ([`noise_estimate`]) → the solver settings ([`SolveSettings`] →
//! [`SolverConfig`](crate::recon::SolverConfig), [`solver_config`]) → the solve with its stopping rule
//! ([`solve_observed`], [`run_solver`]) → the record (`reconstruct.json`, [`Reconstructed::record`]).
//! [`reconstruct`] runs it end to end for one render folder; `study` uses the pieces (one operator per system
//! and operator kind, reused for every scene); the Python `reconstruct` calls [`run_solver`]. The command line
//! keeps only argument parsing, the output policy and writing, and printing (src/cli/reconstruct.rs).
//!
//! ```no_run
//! use diffcassi::recon::pipeline::{self, OperatorKind, Request, RenderRecord, SolveSettings};
//! let record = RenderRecord::load(std::path::Path::new("out/sp-coffee"))?;
//! let tracer = record.tracer()?;
//! let request = Request::new(OperatorKind::Exact, SolveSettings::new("gap-tv"));
//! request.validate()?;
//! let done = pipeline::reconstruct(record, &request, tracer.as_ref(), None, &pipeline::Silent)?;
//! println!("{} iterations, residual {:.3e}", done.iterations_run, done.final_residual);
//! # Ok::<(), diffcassi::Error>(())
//! ```
pub mod noise;
pub mod operators;
pub mod output;
pub mod record;
pub mod settings;
pub mod solve;
pub mod solved;
pub mod unrolled;

pub use noise::{noise_estimate, twin_seed, NoiseEstimate, NoiseModel, SpreadPlan, MC_MISMATCH_PER_RAY};
pub use operators::{build_operator, operator_seed, OperatorKind};
pub use record::RenderRecord;
pub use settings::{check_solver, solver_config, SolveSettings};
pub use solve::{run_solver, solve, solve_observed};
pub use solved::Solved;
pub use unrolled::{is_unrolled, PreparedUnrolled};

use crate::error::{Error, Result};
use crate::scene::SpectralCube;
use crate::tracer::Tracer;
use serde_json::Value;
use std::path::Path;
use std::time::Instant;

/// The exact operator's default transport budget (GB): its light transport is kept in memory up to this size.
pub const TRANSPORT_MEMORY_GB: f64 = 4.0;

/// What [`reconstruct`] does with a render record: the operator, its seed and rays, the transport memory
/// budget and the solver settings (`reconstruct`'s options).
#[derive(Clone, Debug)]
pub struct Request {
    pub operator: OperatorKind,
    /// The exact operator's ray seed: a number or `same` (`None`: acquisition seed + 1, [`operator_seed`]).
    pub operator_seed: Option<String>,
    /// The exact operator's rays per scene pixel per plane (`None`: the acquisition's).
    pub operator_rays: Option<usize>,
    /// Keep the exact operator's transport in memory up to this size (GB); beyond it, re-trace on the fly
    /// (`None`: [`TRANSPORT_MEMORY_GB`]; exact operator only).
    pub transport_memory_gb: Option<f64>,
    pub settings: SolveSettings,
}

impl Request {
    /// `operator` with `settings`, the default seed and rays, and the default transport budget ([`TRANSPORT_MEMORY_GB`]).
    pub fn new(operator: OperatorKind, settings: SolveSettings) -> Self {
        Request { operator, operator_seed: None, operator_rays: None, transport_memory_gb: None, settings }
    }

    /// Check everything that needs no render record, naming the option and its value: iterations, TV weight,
    /// transport budget, the seed and rays (exact operator only), the solver settings (PnP: the weights are
    /// loaded and checked).
    pub fn validate(&self) -> Result<()> {
        let s = &self.settings;
        if s.iterations == Some(0) {
            return Err(Error::invalid("--iterations must be ≥ 1"));
        }
        if let Some(w) = s.tv_weight {
            if !(w.is_finite() && w >= 0.0) {
                return Err(Error::invalid(format!("--tv-weight {w}: must be finite and ≥ 0")));
            }
        }
        if let Some(gb) = self.transport_memory_gb {
            if !(gb.is_finite() && gb >= 0.0) {
                return Err(Error::invalid(format!("--transport-memory-gb {gb}: must be finite and ≥ 0")));
            }
            if self.operator != OperatorKind::Exact {
                return Err(Error::invalid(format!("--transport-memory-gb {gb}: applies to the exact operator only (its traced transport), not `{}`", self.operator.name())));
            }
        }
        if let (Some(m), false) = (s.noise_model, self.operator == OperatorKind::Exact) {
            // A model operator has no Monte-Carlo term to estimate (the record said `model` whatever was asked).
            return Err(Error::invalid(format!("--noise-estimate {}: applies to the exact operator only (how its Monte-Carlo mismatch is estimated), not `{}`", m.name(), self.operator.name())));
        }
        if self.operator_seed.is_some() && self.operator != OperatorKind::Exact {
            return Err(Error::invalid(format!("--operator-seed applies to the exact operator only (its traced rays), not `{}`", self.operator.name())));
        }
        check_solver(s)?;
        if let Some(n) = self.operator_rays {
            if n == 0 {
                return Err(Error::invalid("--operator-rays 0: must be ≥ 1"));
            }
            if self.operator != OperatorKind::Exact {
                return Err(Error::invalid(format!("--operator-rays applies to the exact operator only, not `{}`", self.operator.name())));
            }
        }
        Ok(())
    }

    fn budget_bytes(&self) -> u64 {
        (self.transport_memory_gb.unwrap_or(TRANSPORT_MEMORY_GB) * 1e9) as u64
    }
}

/// What the pipeline reports while it works (the command line draws progress bars; [`Silent`] nothing).
pub trait Progress: Sync {
    /// The operator `name` is being built; `rays` to trace (0 when it traces none).
    fn operator_started(&self, _name: &str, _rays: u64) {}
    /// `n` more rays traced.
    fn rays(&self, _n: u64) {}
    fn operator_done(&self) {}
    /// The solve starts: `label` (operator / solver), at most `iterations`.
    fn solve_started(&self, _label: &str, _iterations: usize) {}
    /// Iteration k done with relative residual `residual`.
    fn iteration(&self, _label: &str, _k: usize, _residual: f64) {}
    fn solve_done(&self) {}
    /// A warning for the user (e.g. unrolled weights trained with another mask); also in the record.
    fn warning(&self, _message: &str) {}
}

/// No progress reports.
pub struct Silent;

impl Progress for Silent {}

/// A finished reconstruction: the cube and its record.
pub struct Reconstructed {
    pub cube: SpectralCube,
    /// `reconstruct.json`: settings, per-iteration residual, the stopping record, seconds of the operator and
    /// the solve (the caller adds `seconds`, its own wall time).
    pub record: Value,
    pub system: String,
    pub iterations_run: usize,
    pub final_residual: f64,
    pub seconds_operator: f64,
    pub seconds_solve: f64,
}

/// `--truth`: the true cube (.npy with its wavelengths file, as `evaluate --truth`), checked against the
/// record's scene size and brought to the render's bands as `evaluate` does: used as it is at the same
/// wavelengths, resampled (linear in λ) when its bands differ but cover the render's, refused when a render band
/// lies outside them. (Its wavelengths were ignored before: a truth at other wavelengths with the right band
/// count gave wrong PSNRs, a held-out battery.)
pub fn load_truth(record: &RenderRecord, path: &Path) -> Result<SpectralCube> {
    use crate::scene::AtWavelengths;
    let t = crate::scene::load_scene(path, None).map_err(|e| Error::invalid(format!("--truth {}: {e}", path.display())))?;
    let bands = record.bands_nm();
    if t.height != record.config.scene_height || t.width != record.config.scene_width {
        return Err(Error::invalid(format!(
            "--truth {}: {}×{}×{} cube, the render's scene is {}×{}×{}",
            path.display(),
            t.height,
            t.width,
            t.bands(),
            record.config.scene_height,
            record.config.scene_width,
            bands.len()
        )));
    }
    // PSNR takes the truth's maximum as its peak (`evaluate` refuses a truth of maximum ≤ 0): refused here before
    // the solve, not recorded as a column of `null` PSNRs (a held-out battery's all-zero truth, exit 0).
    crate::recon::metrics::truth_peak(&t.data).map_err(|e| Error::invalid(format!("--truth {}: {e}; give the true cube", path.display())))?;
    // Values within the radiance limit a render applies (a truth of 3.3e38 wrote `null` residuals, exit 0; a
    // held-out battery, round 10); small negatives (dark-subtracted data) are a truth's, as `evaluate` takes them.
    if let Some(i) = t.data.iter().position(|v| !((*v as f64).abs() <= crate::limits::MAX_SCENE_VALUE)) {
        return Err(Error::invalid(format!(
            "--truth {}: value {:e} at index {i} is beyond ±{:.3e}, the radiance limit of a render (f32's range / 10⁹)",
            path.display(),
            t.data[i],
            crate::limits::MAX_SCENE_VALUE
        )));
    }
    match t.at_wavelengths(bands)? {
        AtWavelengths::Same => Ok(t),
        AtWavelengths::Resampled(r) => Ok(r),
        AtWavelengths::Outside(w) => Err(Error::invalid(format!(
            "--truth {}: its bands ({} – {} nm, {}) do not cover the render's band at {} nm; give the truth at the render's bands",
            path.display(),
            crate::limits::fmt_num(t.wavelengths_nm[0]),
            crate::limits::fmt_num(t.wavelengths_nm[t.bands() - 1]),
            t.bands(),
            crate::limits::fmt_num(w)
        ))),
    }
}

/// The whole pipeline for one render record (checked by [`Request::validate`] first): the operator with its
/// seed ([`operator_seed`]) and rays, δ ([`noise_estimate`]) with the operator's twin when it is estimated from
/// the data, the solve ([`solve_observed`]; `truth`: evaluation only) and the record. `tracer`: the render's
/// ([`RenderRecord::tracer`]) or another.
pub fn reconstruct(mut record: RenderRecord, request: &Request, tracer: &dyn Tracer, truth: Option<&SpectralCube>, progress: &dyn Progress) -> Result<Reconstructed> {
    let kind = request.operator;
    let acquisition_rays = record.config.rays_per_pixel;
    if let Some(n) = request.operator_rays {
        // The operator is rebuilt from the record's configuration: only its ray count changes (the ray budget
        // of `build_operator` applies to it).
        record.config.rays_per_pixel = n;
    }
    let record = record;
    let seed = operator_seed(record.config.seed, request.operator_seed.as_deref())?;
    let oracle = seed == record.config.seed && record.config.rays_per_pixel == acquisition_rays;
    if let (Some(NoiseModel::Spread), true) = (request.settings.noise_model, oracle) {
        // The record said `model` for an explicit `spread` (a held-out battery, round 10); refused before the
        // operator is traced.
        return Err(Error::invalid("--noise-estimate spread: the operator traces the acquisition's own rays (its seed and ray count), so there is no Monte-Carlo mismatch to estimate; drop --noise-estimate, or give the operator another --operator-seed"));
    }
    let mut settings = request.settings.clone();
    // The unrolled network: chosen and checked against the record before the operator is built.
    let unrolled_net = if is_unrolled(&settings.solver) {
        let p = std::sync::Arc::new(unrolled::prepare(settings.weights.as_deref(), &record, seed)?);
        for w in &p.check.warnings {
            progress.warning(w);
        }
        settings.unrolled = Some(p.clone());
        Some(p)
    } else {
        None
    };
    let t_op = Instant::now();
    let op = {
        let c = &record.config;
        let rays = (c.scene_height as f64 * c.scene_width as f64 * c.rays_per_pixel as f64 * c.spectral.planes() as f64) as u64;
        progress.operator_started(kind.name(), if kind == OperatorKind::Exact { rays } else { 0 });
        let op = build_operator(kind, &record, tracer, seed, request.budget_bytes(), &|k| progress.rays(k))?;
        progress.operator_done();
        op
    };
    let mut noise = noise_estimate(&record, kind, seed, record.config.rays_per_pixel, acquisition_rays, settings.noise_model.unwrap_or(NoiseModel::Spread));
    // δ unused (a TV solver with the rule off) and no truth to evaluate the estimator at
    // (`truth_spread_estimate`): no twin is traced for it (it was, doubling the tracing).
    if unrolled_net.is_none() && truth.is_none() && !settings::uses_noise_estimate(&solver_config(&settings)?) {
        noise.spread = None;
        if let Some(o) = noise.record.as_object_mut() {
            o.remove("spread");
            o.insert("estimator".into(), serde_json::json!("unused: the discrepancy rule is off (τ = 0), no twin traced"));
            // Not estimated: null, not a δ of 0 (its Monte-Carlo part was left to the twin).
            for k in ["norm", "monte_carlo_norm", "relative"] {
                o.insert(k.into(), Value::Null);
            }
        }
    }
    // The data-driven δ: the operator's twin (same rays, another seed); the unrolled network has no δ.
    let twin = match (&noise.spread, &unrolled_net) {
        (Some(p), None) => Some(build_operator(kind, &record, tracer, p.twin_seed, request.budget_bytes(), &|_| {})?),
        _ => None,
    };
    // The record is resident through the solve: the denoiser's check counts it ([`crate::limits::hold`]; the
    // operators' checks count it in `build_operator`).
    let _record_held = record.hold();
    let seconds_operator = t_op.elapsed().as_secs_f64();
    let (solver_name, cap) = match &unrolled_net {
        Some(p) => (unrolled::SOLVER, p.net.stages()),
        None => {
            settings.noise = Some(noise);
            let cfg = solver_config(&settings)?;
            (cfg.solver.name(), cfg.iterations)
        }
    };
    let label = format!("{} / {}", op.name(), solver_name);
    progress.solve_started(&label, cap);
    let solved = solve_observed(op.as_ref(), &record.acquisition, &settings, &|k, r| progress.iteration(&label, k, r), truth.map(|t| t.data.as_slice()), twin.as_deref())?;
    progress.solve_done();
    for w in solved.warnings() {
        progress.warning(w);
    }
    let c = op.cube_shape();
    let cube = SpectralCube::new(c.height, c.width, record.bands_nm().to_vec(), solved.cube, "reconstructed cube")?;
    let mut json = serde_json::json!({
        "version": env!("CARGO_PKG_VERSION"),
        // Absolute: the record is read from wherever the folder is (a relative `from` named the invoking
        // directory's view; a held-out battery, round 7).
        "from": std::path::absolute(&record.dir).unwrap_or_else(|_| record.dir.clone()).display().to_string(),
        "system": record.system.name(),
        "operator": kind.name(),
        // The seed and rays are the exact operator's (its traced rays); the model operators trace none: null.
        "operator_seed": if kind == OperatorKind::Exact { serde_json::json!(seed) } else { serde_json::Value::Null },
        "acquisition_seed": record.config.seed,
        "oracle": kind == OperatorKind::Exact && seed == record.config.seed && record.config.rays_per_pixel == acquisition_rays,
        "operator_rays": if kind == OperatorKind::Exact { serde_json::json!(record.config.rays_per_pixel) } else { serde_json::Value::Null },
        "acquisition_rays": acquisition_rays,
        // The exact operator traces in the render's precision (an f32 render: the f32 twin); the model
        // operators trace chief rays with the f64 tracer.
        "tracer": if kind == OperatorKind::Exact { crate::render::engine::tracer_of_record(tracer.name(), record.config.precision) } else { tracer.name() },
        "solver": settings.solver,
        "solver_settings": solved.settings,
        "shape": {"height": c.height, "width": c.width, "bands": c.bands},
        "bands_nm": record.bands_nm(),
        "residual": solved.residuals,
        "residual_definition": RESIDUAL_DEFINITION,
        "final_residual": solved.final_residual,
        "iterations_run": solved.residuals.len(),
        "stopping": solved.stopping,
        "threads": rayon::current_num_threads(),
        "seconds_operator": seconds_operator,
        "seconds_solve": solved.seconds,
    });
    if let (Some(p), Some(o)) = (&unrolled_net, json.as_object_mut()) {
        // The interface other checks read: the weights and their CRC-32 at the top level.
        o.insert("weights".into(), serde_json::json!(p.net.source));
        o.insert("weights_crc32".into(), serde_json::json!(p.net.crc32));
        o.insert("warnings".into(), serde_json::json!(p.check.warnings));
    }
    Ok(Reconstructed {
        cube,
        record: json,
        system: record.system.name().to_string(),
        iterations_run: solved.residuals.len(),
        final_residual: solved.final_residual,
        seconds_operator,
        seconds_solve: solved.seconds,
    })
}

/// What `residual` in a reconstruction record means.
pub const RESIDUAL_DEFINITION: &str = "per iteration k: ‖y − Φv_k‖₂ / ‖y‖₂, v_k the point iteration k projects (GAP: θ_{k−1})";
