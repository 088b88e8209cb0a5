//! `--tolerance-um` in a dataset: one choice per dataset. The task that first claims the folder chooses the
//! tracer, rays per pixel and precision (a calibration: a measurement of the machine) and records the choice
//! in `dataset.json` (`"tolerance": {"tolerance_um", "backend", "rays_per_pixel", "predicted_error_um"}`);
//! every other shard, and a resumed or resubmitted array, asking for the same tolerance with the same settings
//! takes that choice as recorded ([`TracerSource::Recorded`]) instead of choosing again on its own timings.
//! A held-out battery (round 20) started three shards of `--tolerance-um 5` on SP, where the f32 lanes'
//! measured speed-up sits near the 1.25× margin: some chose f32, some f64, and refused each other's
//! dataset.json ("precision: recorded "f64" ≠ requested "f32"", scenes missing).
//!
//! A task that chose before another claimed the folder (shards started together on separate calibration
//! caches) is refused by the configuration check before it writes anything; it then takes the recorded
//! choice and runs again, once. A request that differs in anything else (another tolerance, system, size,
//! noise…) chooses afresh and meets the usual refusal.
use super::run::{requested_configuration, run, DatasetProgress, DatasetRequest, DatasetSummary};
use super::{configuration_differences, MANIFEST};
use crate::error::Result;
use crate::fidelity::{RenderTracing, TracerSource};
use crate::render::{Mask, RenderConfig, RenderSettings, Renderer};
use crate::system::SequentialSystem;
use serde_json::{json, Value};
use std::path::Path;

/// Key of the tolerance's choice in `dataset.json` (beside `configuration`, which holds what it chose).
pub const TOLERANCE_KEY: &str = "tolerance";

/// The record of a request's tolerance choice for `dataset.json` (`None` without a tolerance).
pub fn choice_record(request: &DatasetRequest, rays_per_pixel: usize) -> Option<Value> {
    match (request.tolerance_um, &request.tolerance_backend, request.tolerance_predicted_error_um) {
        (Some(t), Some(b), Some(e)) => Some(json!({"tolerance_um": t, "backend": b, "rays_per_pixel": rays_per_pixel, "predicted_error_um": e})),
        _ => None,
    }
}

/// The tolerance choice `out/dataset.json` records for `tolerance_um` (the same value, bit for bit), as a
/// source that takes it; `None` when the folder has no dataset.json, no record, or one for another tolerance.
pub fn recorded_source(out: &Path, tolerance_um: f64) -> Option<TracerSource> {
    let path = out.join(MANIFEST);
    let v = crate::io::input::read_sidecar_json(&path).ok()?;
    let r = v.get(TOLERANCE_KEY)?;
    let t = r.get("tolerance_um")?.as_f64()?;
    if t.to_bits() != tolerance_um.to_bits() {
        return None;
    }
    Some(TracerSource::Recorded {
        tolerance_um,
        backend: r.get("backend")?.as_str()?.to_string(),
        rays_per_pixel: usize::try_from(r.get("rays_per_pixel")?.as_u64()?).ok()?,
        predicted_error_um: r.get("predicted_error_um")?.as_f64()?,
        origin: path.display().to_string(),
    })
}

/// The recorded choice resolved for this request, when it fits it: with it, the requested configuration is
/// exactly the one dataset.json records (the same system, planes, size, mask, noise… so the choice was made
/// for this very render). `cfg` is set to it.
fn adopt(request: &DatasetRequest, system: &SequentialSystem, settings: &RenderSettings, cfg: &mut RenderConfig, mask: &Mask, tolerance_um: f64) -> Option<RenderTracing> {
    let source = recorded_source(&request.out, tolerance_um)?;
    let (recorded, _) = super::read_manifest(&request.out).ok()?;
    let mut c = cfg.clone();
    let tracing = RenderTracing::resolve(source, system, settings, &mut c, mask).ok()?;
    let renderer = Renderer::new(system, tracing.tracer.as_ref(), c.clone(), mask.clone()).ok()?;
    let requested = requested_configuration(request, &renderer).ok()?;
    drop(renderer);
    configuration_differences(&recorded, &requested).is_empty().then(|| {
        *cfg = c;
        tracing
    })
}

/// [`run`] with the tracer from `source`: given, chosen for a tolerance, or — with a tolerance — the choice
/// `dataset.json` records for the same tolerance and settings (see the module docs). The choice's
/// explanation goes to `progress` (a message); the request records the tolerance, its choice and predicted
/// error (each scene's render.json, dataset.json). `cfg` and `mask` are the settings' ([`RenderSettings::config`]).
#[allow(clippy::too_many_arguments)]
pub fn run_with_source(request: &DatasetRequest, inputs: &[(&str, &Path)], system: &SequentialSystem, source: TracerSource, settings: &RenderSettings, cfg: RenderConfig, mask: Mask, progress: &dyn DatasetProgress) -> Result<DatasetSummary> {
    let tolerance = match &source {
        TracerSource::Tolerance { tolerance_um, .. } => Some(*tolerance_um),
        _ => None,
    };
    let settle = |tracing: &RenderTracing| {
        let mut r = request.clone();
        r.tolerance_um = tracing.tolerance_um;
        r.tolerance_predicted_error_um = tracing.predicted_error_um;
        r.tolerance_backend = tracing.backend.clone();
        if let Some(x) = &tracing.explanation {
            progress.message(x);
        }
        r
    };
    let mut c = cfg.clone();
    let (tracing, adopted) = match tolerance.and_then(|t| adopt(request, system, settings, &mut c, &mask, t)) {
        Some(t) => (t, true),
        None => {
            c = cfg.clone();
            (RenderTracing::resolve(source, system, settings, &mut c, &mask)?, false)
        }
    };
    let r = settle(&tracing);
    let first = run(&r, inputs, system, tracing.tracer.as_ref(), c, mask.clone(), progress);
    let (Err(_), false, Some(t)) = (&first, adopted, tolerance) else { return first };
    // Refused, having chosen on this run's own timings: if another task recorded its choice for this very
    // request meanwhile (it claimed the folder first), take that one and run again. Nothing was written.
    let mut c = cfg;
    let Some(theirs) = adopt(request, system, settings, &mut c, &mask, t) else { return first };
    if theirs.backend == tracing.backend && theirs.rays_per_pixel == tracing.rays_per_pixel {
        return first;
    }
    progress.message(&format!(
        "--tolerance-um {}: another task of this dataset claimed {} first with its own choice; this one chose --backend {} --rays {} on its own timings and takes the recorded choice instead, so that the dataset has one",
        crate::limits::fmt_num(t),
        request.out.display(),
        tracing.backend.as_deref().unwrap_or("?"),
        tracing.rays_per_pixel
    ));
    let r = settle(&theirs);
    run(&r, inputs, system, theirs.tracer.as_ref(), c, mask, progress)
}
