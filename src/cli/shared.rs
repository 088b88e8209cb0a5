//! Helpers shared by the command modules: loading the system and tracer the options name, parsing the
//! text forms of wavelengths, fields and pupil patterns, and CPU-time measurement for the benchmarks.
//! Every command module imports from here and from [`super::args`] (the shared option groups); no command
//! module imports another's helpers, so the CLI's modules form no import cycle.
//!
//! ```
//! let ws = diffcassi::cli::parse_wavelengths("450:650:3")?;
//! assert_eq!(ws, vec![450.0, 550.0, 650.0]);
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::args::{BackendArgs, SystemArgs};
use crate::error::{Error, Result};
use crate::rays::PupilPattern;
use crate::spec::SystemSpec;
use crate::system::SequentialSystem;
use crate::tracer::Tracer;

/// The spec named by `--preset` or `--system`.
pub fn load_spec(args: &SystemArgs) -> Result<SystemSpec> {
    match (&args.preset, &args.system) {
        (Some(p), None) => crate::presets::spec(p),
        (None, Some(path)) => crate::spec::load_spec_file(path),
        (None, None) => Err(Error::invalid("give a system: --preset sp|ap|msp|map or --system FILE")),
        (Some(_), Some(_)) => Err(Error::invalid("give either --preset or --system, not both")),
    }
}

/// Build the system named by the arguments, with any extra glass catalogues.
/// The input files of `--system` / `--glass-catalog`, as (option, path) for the output policy
/// ([`crate::io::policy`]: an output never overwrites an input).
pub fn system_inputs(args: &SystemArgs) -> Vec<(&'static str, &std::path::Path)> {
    let mut v: Vec<(&'static str, &std::path::Path)> = args.system.iter().map(|p| ("--system", p.as_path())).collect();
    v.extend(args.glass_catalogs.iter().map(|p| ("--glass-catalog", p.as_path())));
    v
}

pub fn load_system(args: &SystemArgs) -> Result<SequentialSystem> {
    // A `.zmx` file's errors, at the build and after it (a `--wavelength-nm` outside a glass's range), name the
    // file's own fixes (its `DCWP` record, not a spec's field): the system's origin (crate::system::SystemOrigin).
    let origin = args.system.as_deref().map(crate::system::SystemOrigin::of_path).unwrap_or_default();
    let built = SequentialSystem::build_from(&load_spec_with_catalogs(args)?, origin);
    if let Ok(system) = &built {
        for w in system.warnings() {
            eprintln!("warning: {w}");
        }
    }
    built
}

/// The note of a `.zmx` system's skipped `COAT` records ([`crate::spec::zmx::ZmxImport::coating_note`]) for
/// `command`, a Fresnel ghost path command whose numbers coatings change; `None` for any other system. The file
/// is read again (milliseconds): the loaded system keeps no record of what its reader skipped.
pub(super) fn zmx_coating_note(args: &SystemArgs, command: &str) -> Option<String> {
    let path = args.system.as_deref().filter(|p| args.preset.is_none() && crate::system::SystemOrigin::of_path(p) == crate::system::SystemOrigin::Zmx)?;
    let extra: Vec<String> = args.glass_catalogs.iter().map(|p| crate::spec::catalog_entry(p)).collect();
    let options = crate::spec::zmx::ZmxOptions { glass_catalogs: extra, ..Default::default() };
    crate::spec::zmx::import_zmx_file(path, &options).ok()?.coating_note(command)
}

/// The spec named by the arguments with each `--glass-catalog` appended to its `glass_catalogs` (after the
/// spec's own: a later catalogue wins, as in [`SequentialSystem::build`]), as an absolute path, so that the
/// system's spec — what `render.json`, `study.json` and the spec's SHA-256 record — names every catalogue
/// its glasses came from and a later `reconstruct --from` reads the same ones.
/// A `.zmx` file's glasses are looked up in them too, after the file's `GCAT` catalogues
/// ([`crate::spec::load_spec_file_with_catalogs`]).
pub fn load_spec_with_catalogs(args: &SystemArgs) -> Result<SystemSpec> {
    let extra: Vec<String> = args.glass_catalogs.iter().map(|p| crate::spec::catalog_entry(p)).collect();
    if let (None, Some(path)) = (&args.preset, &args.system) {
        return crate::spec::load_spec_file_with_catalogs(path, &extra);
    }
    let mut spec = load_spec(args)?;
    spec.glass_catalogs.extend(extra);
    Ok(spec)
}

/// The tracer named by `--backend`, `--refine`, `--mesh-max-sag-um`, `--mesh-segments`.
pub fn make_tracer(a: &BackendArgs) -> Result<Box<dyn Tracer>> {
    let mut cfg: crate::tracer::BackendConfig = a.backend.as_deref().unwrap_or("analytic").parse()?;
    if let Some(r) = &a.refine {
        cfg.refine = r.parse()?;
    }
    if let Some(um) = a.mesh_max_sag_um {
        cfg.mesh = crate::surfaces::MeshResolution::MaxSagErrorUm(um);
    }
    if let Some(n) = a.mesh_segments {
        cfg.mesh = crate::surfaces::MeshResolution::Segments(n);
    }
    if cfg.backend == crate::tracer::Backend::AnalyticF32 {
        return Err(Error::invalid("--backend analytic-f32: this command runs in f64 (its results are compared to Zemax); f32 is for render, render-dataset and mapping, with --precision f32"));
    }
    if cfg.backend == crate::tracer::Backend::Analytic && (a.mesh_max_sag_um.is_some() || a.mesh_segments.is_some() || a.refine.as_deref().is_some_and(|r| r != "f64")) {
        return Err(Error::invalid("--refine, --mesh-max-sag-um and --mesh-segments apply to the Embree backends only (--backend embree-user|embree-mesh)"));
    }
    cfg.build()
}

/// `520`, `450,520,650` or `450:650:28` (first:last:count) → wavelengths in nm.
pub fn parse_wavelengths(text: &str) -> Result<Vec<f64>> {
    parse_wavelengths_for("--wavelength-nm", text)
}

/// [`parse_wavelengths`] for the option named `option` (errors name it): the library's
/// [`crate::render::settings::parse_wavelengths`].
pub fn parse_wavelengths_for(option: &str, text: &str) -> Result<Vec<f64>> {
    crate::render::settings::parse_wavelengths(option, text)
}

/// `X,Y` → field angles (degrees) of `--field-deg`: each finite and within (−90, 90).
pub fn parse_field_deg(text: &str) -> Result<[f64; 2]> {
    parse_pair("--field-deg", text, "X,Y in degrees, e.g. 0,10", |v| {
        (!(v.is_finite() && v.abs() < 90.0)).then(|| format!("{} is not an angle within (-90, 90) degrees", crate::limits::fmt_num(v)))
    })
}

/// `X,Y` of `flag`: two numbers, each accepted by `check` (`Some(why)` refuses it); errors name the flag,
/// the text and how to write it (`usage`).
fn parse_pair(flag: &str, text: &str, usage: &str, check: impl Fn(f64) -> Option<String>) -> Result<[f64; 2]> {
    let bad = |why: String| Error::invalid(format!("{flag} `{text}`: {why} (use {usage})"));
    let parts: Vec<&str> = text.split(',').collect();
    if parts.len() != 2 {
        return Err(bad("expected two numbers".into()));
    }
    let mut v = [0.0f64; 2];
    for (k, p) in parts.iter().enumerate() {
        v[k] = p.trim().parse().map_err(|_| bad(format!("`{p}` is not a number")))?;
        if let Some(why) = check(v[k]) {
            return Err(bad(why));
        }
    }
    Ok(v)
}

/// The field points of `--field-mm` / `--field-deg` for `system`: mm for a finite object, degrees for an
/// object at infinity (the wrong one is an error naming the right one); none given → `None`.
pub fn parse_fields_for(system: &crate::system::SequentialSystem, mm: &[String], deg: &[String]) -> Result<Option<Vec<[f64; 2]>>> {
    use crate::system::FieldUnit;
    let mut out = Vec::new();
    for t in mm {
        out.push(system.field_point(parse_field(t)?, FieldUnit::Mm, "--field-mm")?);
    }
    for t in deg {
        out.push(system.field_point(parse_field_deg(t)?, FieldUnit::Deg, "--field-deg")?);
    }
    Ok(if out.is_empty() { None } else { Some(out) })
}

/// `X,Y` → field point (mm).
pub fn parse_field(text: &str) -> Result<[f64; 2]> {
    parse_pair("--field-mm", text, "X,Y in mm, e.g. 2.5,0", |v| {
        (!(v.is_finite() && v.abs() <= crate::limits::MAX_LENGTH_MM)).then(|| format!("{} is outside ±{:e} mm", crate::limits::fmt_num(v), crate::limits::MAX_LENGTH_MM))
    })
}

/// `chief`, `marginal`, `hexapolar:R`, `grid:N`, `grid-step:S`, `random:N:SEED` ([`PupilPattern::parse_for`],
/// naming `--pupil`).
pub fn parse_pupil(text: &str) -> Result<PupilPattern> {
    PupilPattern::parse_for("--pupil", text)
}

// ---------------------------------------------------------------- timing

/// CPU time (s) used so far by all threads of this process: the sum of /proc/self/task/*/schedstat's run
/// times (ns resolution; Linux only, `None` elsewhere). Rays per CPU-second is rays/s per thread even on
/// a machine shared with other jobs, where wall time hides how much of the cores a run was given. Threads
/// that have exited are not counted, so take differences around work done by live threads (rayon's pool).
pub fn cpu_seconds() -> Option<f64> {
    let mut ns = 0u64;
    for t in std::fs::read_dir("/proc/self/task").ok()?.flatten() {
        // A thread may exit between the listing and the read: skip it.
        let Ok(s) = std::fs::read_to_string(t.path().join("schedstat")) else { continue };
        ns += s.split_whitespace().next().and_then(|v| v.parse::<u64>().ok()).unwrap_or(0);
    }
    Some(ns as f64 * 1e-9)
}

/// The shortest CPU interval (s) the benchmarks report: the kernel adds a running thread's time to its
/// schedstat at scheduler ticks (1–10 ms) and context switches, so a shorter difference of [`cpu_seconds`]
/// is mostly that accounting's error (a held-out battery, round 19: `bench nonsequential --rays 200` read
/// 0.00 CPU-s per M rays for a kernel taking 3.2 wall-s per M rays); below it a table says `n/a`.
pub const MIN_CPU_INTERVAL_S: f64 = 0.1;

/// The CPU time (s) between two [`cpu_seconds`] readings, when both exist and it is at least
/// [`MIN_CPU_INTERVAL_S`] (else `None`: too short to measure).
pub fn cpu_interval(before: Option<f64>, after: Option<f64>) -> Option<f64> {
    let d = after? - before?;
    (d >= MIN_CPU_INTERVAL_S).then_some(d)
}

/// CPU seconds (user + system) used by this process so far, from /proc/self/stat (Linux, USER_HZ = 100);
/// `None` elsewhere. On a shared machine wall time alone hides how much of the cores the run was given.
pub fn process_cpu_seconds() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/stat").ok()?;
    let after = &s[s.rfind(')')? + 2..];
    let f: Vec<&str> = after.split_whitespace().collect();
    let (u, k): (f64, f64) = (f.get(11)?.parse().ok()?, f.get(12)?.parse().ok()?);
    Some((u + k) / 100.0)
}
