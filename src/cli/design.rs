//! `diffcassi calibrate` and `diffcassi design amici`: the derivative-based commands.
use crate::calibration::{add_noise, calibrate, observe_named, CalibrationSetup};
use crate::diff::{preset_alias, Param, ParamSet};
use crate::error::{Error, Result};
use crate::spec::SystemSpec;
use clap::{Args, Subcommand};
use serde_json::json;
use std::path::{Path, PathBuf};

#[derive(Args, Debug)]
pub struct CalibrateArgs {
    /// The nominal system: a preset (sp, ap, msp, map) or a spec file.
    #[arg(long)]
    pub from: String,
    /// The system whose spot centroids are observed: a preset or a spec file.
    #[arg(long)]
    pub observed: String,
    /// Parameters to fit (repeat or comma-separate): prism_tilt_x|y|z, or s<N>.<column> (e.g. s4.tilt_x_deg).
    /// prism_tilt_* names a surface of --from: 4 in sp, msp and map, 3 in ap — not the same rotation in ap and
    /// map (AP's stop break holds α_c in y and nothing undoes its x tilt; mAP's 5° x tilt at 4 is undone by a
    /// fixed −5° break at 19).
    /// The fit searches start ± 45° on angles and ± 10 mm on lengths (printed; a parameter on an edge is warned
    /// about). A truth is shown only when --observed numbers its surfaces as --from does.
    #[arg(long, required = true, value_delimiter = ',')]
    pub free: Vec<String>,
    /// Gaussian noise added to each observed centroid coordinate (µm).
    #[arg(long = "noise-um", default_value_t = 0.0)]
    pub noise_um: f64,
    /// Seed of the noise (ChaCha8).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Observation set: standard (5×5 fields over ±2.5 mm × 450/520/650 nm × 37 pupil rays) or small.
    #[arg(long, default_value = "standard")]
    pub setup: String,
    /// JSON report.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Write the calibrated system spec (TOML or JSON).
    #[arg(long = "system-out")]
    pub system_out: Option<PathBuf>,
}

#[derive(Args, Debug)]
pub struct DesignArgs {
    #[command(subcommand)]
    pub command: DesignCommand,
}

#[derive(Subcommand, Debug)]
pub enum DesignCommand {
    /// Optimise the double-Amici prism (α_c, A1, A2, two glasses) to match a 60° N-BK7 prism's dispersion
    /// (the reference paper's design), snap the glasses to the catalogue and re-optimise the angles.
    Amici(AmiciArgs),
}

#[derive(Args, Debug)]
pub struct AmiciArgs {
    /// Seed of the start-point perturbation (results are deterministic for a seed).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Adam iterations of the continuous-glass stage.
    #[arg(long, default_value_t = 400)]
    pub iterations: usize,
    /// w_t of the final angle re-optimisation (the paper's 5e3 applies in the continuous stage).
    #[arg(long = "final-thickness-weight", default_value_t = 500.0)]
    pub final_thickness_weight: f64,
    /// AGF catalogue for the glass distance and the snapping: its glasses only, the built-ins are not added
    /// (default: ../shared/reference/glass/SCHOTT.AGF when present, else the built-in glasses). The target's
    /// N-BK7 and the start's N-SK2/N-SF10 are the file's when it has them, else the built-ins.
    #[arg(long = "glass-catalog")]
    pub glass_catalog: Option<PathBuf>,
    /// JSON report.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// The designed system spec (TOML or JSON).
    #[arg(long = "system-out")]
    pub system_out: Option<PathBuf>,
}

fn spec_of(text: &str) -> Result<SystemSpec> {
    if crate::presets::ALL_NAMES.contains(&text.to_ascii_lowercase().as_str()) {
        crate::presets::spec(text)
    } else {
        crate::spec::load_spec_file(Path::new(text))
    }
}

fn resolve_param(system: &str, name: &str) -> Result<Param> {
    match preset_alias(system, name) {
        Some(p) => Ok(p),
        None if name.starts_with("prism_tilt") => {
            Err(Error::invalid(format!("--free {name}: the alias is defined for the presets (sp, ap, msp, map), not `{system}`; give s<N>.<column>")))
        }
        None => Param::parse(name),
    }
}

/// Writes `--report` and `--system-out` as one set ([`crate::io::OutputSet`]): each is staged beside its
/// destination (the extension kept: the spec format follows it) and both are moved into place only when both
/// are written, so a failure leaves the previous pair as it was.
fn write_outputs(report: Option<(&Path, &serde_json::Value)>, system_out: Option<(&Path, &SystemSpec)>) -> Result<()> {
    let mut set = crate::io::OutputSet::files();
    if let Some((path, value)) = report {
        crate::limits::check_json_finite(&path.display().to_string(), value)?;
        let text = serde_json::to_string_pretty(value).map_err(|e| Error::invalid(format!("JSON: {e}")))?;
        crate::io::write_atomic(set.stage(path), text.as_bytes())?;
    }
    if let Some((path, spec)) = system_out {
        // The format follows the extension (.toml/.json); any other is an error (never TOML in a .yaml).
        crate::spec::save_spec_file(spec, &set.stage(path))?;
    }
    set.commit()?;
    for p in report.map(|r| r.0).into_iter().chain(system_out.map(|s| s.0)) {
        println!("wrote {}", p.display());
    }
    Ok(())
}

/// `--system-out` and `--report` name files of their format and follow the output policy (files, never a
/// folder, never one of the command's `inputs`, not both the same file), checked before the optimisation runs.
fn check_outputs(system_out: &Option<PathBuf>, report: &Option<PathBuf>, inputs: &[(&str, &Path)]) -> Result<()> {
    if let Some(p) = system_out {
        crate::io::policy::check_out_file("--system-out", p, inputs)?;
    }
    if let Some(p) = report {
        crate::io::policy::check_out_file("--report", p, inputs)?;
        if let Some(q) = system_out {
            if crate::io::policy::resolved(p) == crate::io::policy::resolved(q) {
                return Err(Error::invalid(format!("--report and --system-out are the same file {}", p.display())));
            }
        }
    }
    if let Some(p) = system_out {
        let ext = p.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
        if !matches!(ext.as_deref(), Some("toml") | Some("json")) {
            return Err(Error::invalid(format!("--system-out {}: the spec format follows the extension, use .toml or .json", p.display())));
        }
    }
    if let Some(p) = report {
        if !p.extension().and_then(|e| e.to_str()).is_some_and(|e| e.eq_ignore_ascii_case("json")) {
            return Err(Error::invalid(format!("--report {}: the report is JSON, name it .json", p.display())));
        }
    }
    Ok(())
}

pub(super) fn calibrate_cmd(a: CalibrateArgs) -> Result<()> {
    // The spec files the two systems are read from (a preset name is no file).
    let inputs: Vec<(&str, &Path)> = [("--from", a.from.as_str()), ("--observed", a.observed.as_str())]
        .into_iter()
        .filter(|(_, t)| Path::new(t).exists())
        .map(|(o, t)| (o, Path::new(t)))
        .collect();
    check_outputs(&a.system_out, &a.report, &inputs)?;
    // Noise on the centroids is bounded by the detector's scale (1 cm = 1e4 µm): beyond it the fit is of noise
    // alone, and 1e300 µm made an infinite residual written as `null` (a held-out battery).
    if !(a.noise_um.is_finite() && a.noise_um >= 0.0 && a.noise_um <= MAX_NOISE_UM) {
        return Err(Error::invalid(format!("--noise-um {}: must be in [0, {MAX_NOISE_UM:e}] µm", crate::limits::fmt_num(a.noise_um))));
    }
    let setup = match a.setup.as_str() {
        "standard" => CalibrationSetup::standard(),
        "small" => CalibrationSetup::small(),
        s => return Err(Error::invalid(format!("--setup `{s}`: use standard or small"))),
    };
    let from = spec_of(&a.from)?;
    let observed_spec = spec_of(&a.observed)?;
    let params: Vec<Param> = a.free.iter().map(|n| resolve_param(&a.from, n.trim())).collect::<Result<_>>()?;
    // A fitted glass (n_d, V_d of a Cauchy model) has no place in a spec, which names catalogue glasses: a
    // --system-out written without it was the nominal system, silently (a held-out battery, round 6).
    if let (Some(out), Some(p)) = (&a.system_out, params.iter().find(|p| matches!(p, Param::GlassNd(_) | Param::GlassVd(_)))) {
        return Err(Error::invalid(format!(
            "--system-out {}: the fitted {} cannot be written into a spec (a spec names catalogue glasses; a fitted index has no entry there); drop it from --free or drop --system-out (the --report records it)",
            out.display(),
            p.name()
        )));
    }
    // The setup's fields are object heights (mm): a system whose object is at infinity takes field angles.
    for (option, s) in [("--from", &from), ("--observed", &observed_spec)] {
        if crate::system::SequentialSystem::build(s).is_ok_and(|sys| sys.object_at_infinity()) {
            return Err(Error::invalid(format!("{option} {}: its object is at infinity, but the calibration setup's fields are object heights in mm (it read them as angles); calibrate needs a finite object", if option == "--from" { &a.from } else { &a.observed })));
        }
    }
    let catalog = crate::system::SequentialSystem::catalog_of(&from)?;
    let set = ParamSet::new(from, catalog, params.clone())?;
    let observed_sys = crate::system::SequentialSystem::build(&observed_spec)?;
    let clean = observe_named(&observed_sys, &setup, &format!("--observed {}", a.observed))?;
    // The fit moves --from's free parameters only: an observed system of another structure (other surfaces,
    // in number or type) is not a misaligned copy of it, and its cells are no truth for --from's (SP observed
    // as AP printed a truth of 0 beside a 115 µm residual, exit 0: a held-out battery, round 8).
    let structure = crate::calibration::structure_difference(&set.spec.surfaces, &observed_spec.surfaces);
    if let Some(d) = &structure {
        eprintln!("warning: --observed {} is not --from {} with other values ({d}): the fit can only approximate it with --from's free parameters, and no truth is shown", a.observed, a.from);
    }
    // Truth: --from's parameter read from the observed spec, only where the two number their surfaces alike
    // (`truth_of`; a cell the observed spec leaves out — a break's tilt, a conic — is its default, 0). The alias
    // is resolved on --from only: `prism_tilt_*` is another surface in AP (3) than in mAP (4), and not the same
    // rotation either (a held-out battery, round 16: AP vs mAP printed truths from other surfaces).
    let truth_or_why: Vec<std::result::Result<f64, String>> = params
        .iter()
        .map(|p| match &structure {
            Some(d) => Err(format!("--observed is not --from with other values ({d})")),
            None => crate::calibration::truth_of(p, &set.spec.surfaces, &observed_spec.surfaces),
        })
        .collect();
    let truth: Vec<Option<f64>> = truth_or_why.iter().map(|t| t.as_ref().ok().copied()).collect();
    let mut truth_warnings = Vec::new();
    if structure.is_none() {
        for ((name, p), t) in a.free.iter().zip(&params).zip(&truth_or_why) {
            // A surface cell the observed spec could have held but that is another quantity there: a warning (a
            // glass or ray parameter is never read from a spec, which its `null` says in `truth_unknown`).
            if let (Err(why), Param::Cell { .. }) = (t, p) {
                truth_warnings.push(format!("{}: no truth or error shown: {why}", name.trim()));
            }
        }
    }
    let fit_with = |noise: f64, seed: u64| -> Result<(crate::calibration::CalibrationFit, serde_json::Value)> {
        let mut obs = clean.clone();
        if noise > 0.0 {
            add_noise(&mut obs, noise, seed);
        }
        let fit = calibrate(&set, &obs, &setup)?;
        if !(fit.residual_um.is_finite() && fit.max_residual_um.is_finite() && fit.x.iter().all(|v| v.is_finite())) {
            return Err(Error::invalid(format!("calibrate: the fit (noise {} µm) did not converge to finite values (residual {} µm); nothing was written", crate::limits::fmt_num(noise), fit.residual_um)));
        }
        let mut rec = serde_json::Map::new();
        let mut err = serde_json::Map::new();
        for (k, name) in a.free.iter().enumerate() {
            rec.insert(name.trim().to_string(), json!(fit.x[k]));
            if let Some(t) = truth[k] {
                err.insert(name.trim().to_string(), json!(fit.x[k] - t));
            }
        }
        let v = json!({
            "noise_um": noise, "seed": seed, "recovered": rec, "error": err,
            "residual_um": fit.residual_um, "max_residual_um": fit.max_residual_um,
            "iterations": fit.report.iterations, "stop_reason": fit.report.stop_reason, "warnings": fit.report.warnings,
        });
        Ok((fit, v))
    };
    let (fit, main) = fit_with(a.noise_um, a.seed)?;
    let (_, study) = fit_with(1.0, a.seed)?;
    println!("calibrate {} → {}: {} centroids ({} fields × {} wavelengths × {} pupil rays)", a.from, a.observed, clean.len(), setup.fields_mm.len(), setup.wavelengths_nm.len(), setup.pupil.len());
    println!("{:16} {:>14} {:>14} {:>14} {:>16}", "parameter", "start", "recovered", "truth", "error (1 µm noise)");
    let start = set.values()?;
    for (k, name) in a.free.iter().enumerate() {
        let t = truth[k].map(|v| format!("{v:.6}")).unwrap_or_else(|| "?".into());
        let e1 = study["error"].get(name.trim()).and_then(|v| v.as_f64()).map(|v| format!("{v:+.2e}")).unwrap_or_else(|| "?".into());
        println!("{:16} {:>14.6} {:>14.8} {:>14} {:>16}", name.trim(), start[k], fit.x[k], t, e1);
    }
    println!("residual {:.4} µm RMS, {:.4} µm max ({} iterations, {})", fit.residual_um, fit.max_residual_um, fit.report.iterations, fit.report.stop_reason);
    // The box the fit searched (a parameter on its edge is warned about below: a held-out battery, round 16).
    let fmt_bound = |v: f64| if v.is_finite() { format!("{v:.6}") } else { "unbounded".into() };
    println!("bounds (start ± {}° on angles, ± {} mm on lengths): {}", crate::calibration::ANGLE_BOUND_DEG, crate::calibration::LENGTH_BOUND_MM,
        a.free.iter().zip(&fit.bounds).map(|(n, b)| format!("{} [{}, {}]", n.trim(), fmt_bound(b[0]), fmt_bound(b[1]))).collect::<Vec<_>>().join(", "));
    // The fit's warnings (parameters the data do not determine, or stopped by a bound) on stderr too, with
    // the truths that could not be read; the report keeps them.
    let warnings: Vec<String> = fit.report.warnings.iter().cloned().chain(truth_warnings.iter().cloned()).collect();
    for w in &warnings {
        eprintln!("warning: {w}");
    }
    let mut rec = serde_json::Map::new();
    let mut tr = serde_json::Map::new();
    let mut unknown = serde_json::Map::new();
    let mut bounds = serde_json::Map::new();
    for (k, name) in a.free.iter().enumerate() {
        rec.insert(name.trim().to_string(), json!(fit.x[k]));
        tr.insert(name.trim().to_string(), json!(truth[k]));
        if let Err(why) = &truth_or_why[k] {
            unknown.insert(name.trim().to_string(), json!(why));
        }
        // `null`: unbounded (JSON has no infinity).
        let b = fit.bounds[k].map(|v| v.is_finite().then_some(v));
        bounds.insert(name.trim().to_string(), json!(b));
    }
    let report = json!({
        "from": a.from, "observed": a.observed,
        "free": a.free, "parameters": params.iter().map(|p| p.name()).collect::<Vec<_>>(),
        "start": start, "recovered": rec, "truth": tr, "truth_unknown": unknown, "error": main["error"], "bounds": bounds,
        "residual_um": fit.residual_um, "max_residual_um": fit.max_residual_um,
        "noise_um": a.noise_um, "seed": a.seed,
        "iterations": fit.report.iterations, "stop_reason": fit.report.stop_reason, "warnings": warnings,
        "structure_difference": structure,
        "noise_study": study,
        "setup": {"fields_mm": setup.fields_mm, "wavelengths_nm": setup.wavelengths_nm, "pupil_rays": setup.pupil.len()},
    });
    let fitted = match &a.system_out {
        Some(_) => Some(set.with_values(&fit.x)?.spec),
        None => None,
    };
    write_outputs(a.report.as_deref().map(|p| (p, &report)), a.system_out.as_deref().zip(fitted.as_ref()))
}

/// The largest `--final-thickness-weight`: 2000× the default, far beyond any useful balance of the loss terms.
const MAX_LOSS_WEIGHT: f64 = 1e6;

/// The largest `--noise-um` (µm): a centimetre, the detector's scale.
const MAX_NOISE_UM: f64 = 1e4;

pub(super) fn design_cmd(a: DesignArgs) -> Result<()> {
    match a.command {
        DesignCommand::Amici(a) => amici_cmd(a),
    }
}

fn amici_cmd(a: AmiciArgs) -> Result<()> {
    let inputs: Vec<(&str, &Path)> = a.glass_catalog.iter().map(|p| ("--glass-catalog", p.as_path())).collect();
    check_outputs(&a.system_out, &a.report, &inputs)?;
    let catalog = crate::design::design_catalog(a.glass_catalog.as_deref())?;
    // Bounded: the loss (weight × a squared thickness error) must stay finite (1.7e308 gave an infinite loss,
    // written as `null`, and a degenerate design, exit 0: a held-out battery, round 6).
    if !(a.final_thickness_weight.is_finite() && (0.0..=MAX_LOSS_WEIGHT).contains(&a.final_thickness_weight)) {
        return Err(Error::invalid(format!("--final-thickness-weight {}: must be in [0, {MAX_LOSS_WEIGHT:e}] (default 500)", crate::limits::fmt_num(a.final_thickness_weight))));
    }
    if a.iterations == 0 {
        return Err(Error::invalid("--iterations 0: the continuous stage needs at least one Adam iteration"));
    }
    if a.iterations > crate::limits::MAX_ITERATIONS {
        return Err(Error::invalid(format!("--iterations {}: at most {} Adam iterations", a.iterations, crate::limits::MAX_ITERATIONS)));
    }
    let opts = crate::design::AmiciOptions { seed: a.seed, iterations: a.iterations, final_thickness_weight: a.final_thickness_weight, ..Default::default() };
    let out = crate::design::design_amici(&catalog, &opts)?;
    out.print();
    // The optimisers' warnings (a parameter on its bound, one the loss ignores) on stderr too; the report keeps
    // them (α_c ended on its −20° bound with warnings [] and no word: a held-out battery, round 16).
    for (stage, v) in [("continuous stage", &out.report.continuous_stage), ("final stage", &out.report.final_stage)] {
        for w in v["warnings"].as_array().into_iter().flatten().filter_map(|w| w.as_str()) {
            eprintln!("warning: {stage}: {w}");
        }
    }
    // Before the conversion to a JSON value (which turns inf into `null`): every number finite.
    crate::limits::check_json_finite("design amici: the report", &out.report)?;
    let report = serde_json::to_value(&out.report).map_err(|e| Error::invalid(format!("JSON: {e}")))?;
    write_outputs(a.report.as_deref().map(|p| (p, &report)), a.system_out.as_deref().map(|p| (p, &out.spec)))
}
