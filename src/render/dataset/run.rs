//! The `render-dataset` pipeline: a folder of scenes (whole, or one shard of a Slurm job array) rendered into
//! one sub-folder each, resumably, with the rules of [`super`] (shards, the canonical configuration, what
//! counts as done, all-or-nothing scene folders). The command line and the Python `render_dataset` are
//! clients: they choose the system and the tracer, fill a [`DatasetRequest`] and show what
//! [`DatasetProgress`] reports.
//!
//! ```no_run
//! use diffcassi::render::dataset::{self, DatasetOptions, DatasetRequest, Shard};
//! use diffcassi::render::settings::RenderSettings;
//! use diffcassi::prelude::*;
//! let system = SequentialSystem::build(&presets::spec("sp")?)?;
//! let tracer = AnalyticTracer::default();
//! let settings = RenderSettings { scene_size: 64, ..RenderSettings::default() };
//! let (cfg, mask) = settings.config()?;
//! let request = DatasetRequest::new("scenes/", "out/sp-dataset", DatasetOptions { fit: settings.fit, scene_wavelengths_nm: None, cube: false, mapping: true });
//! let done = dataset::run(&request, &[], &system, &tracer, cfg, mask, &dataset::SilentDataset)?;
//! println!("{} rendered, {} skipped", done.rendered, done.skipped);
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::{check_scene, check_shared, commit_scene, configuration, configuration_differences, file_records, find_scenes, manifest, partial_dir, read_manifest, remove_leftovers, scene_input_record, shared_output_names, with_scene_input, DatasetOptions, DatasetScene, SceneOrder, SceneState, Shard, MANIFEST};
use crate::error::{Error, Result};
use crate::render::Device;
use crate::render::{output, Acquisition, Mask, NoiseConfig, PlaneTransport, RenderConfig, Renderer};
use crate::scene::{load_scene, Fit, SpectralCube};
use crate::system::SequentialSystem;
use crate::tracer::Tracer;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// What to do with a scene (or `dataset.json`) already rendered with another configuration.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OnMismatch {
    /// Stop with an error before writing anything, naming the scenes and the differing settings.
    Refuse,
    /// Render those scenes again and replace their folders (and the shared outputs) whole.
    Rerender,
}

/// A dataset render: where the scenes are, where they go, and what besides the render configuration shapes
/// them. [`DatasetRequest::new`] holds the defaults (whole dataset, no noise, refuse mismatches, 4 GB of
/// cached transport, the CPU).
#[derive(Clone, Debug)]
pub struct DatasetRequest {
    /// Folder of scenes (.exr, .npy, RGB .png photographs, folders of per-band .png).
    pub scenes: PathBuf,
    /// Output folder: one sub-folder per scene, dataset.json, mask.png and the mapping cube.
    pub out: PathBuf,
    /// Accept an `out` folder that holds other files (not a previous dataset).
    pub force: bool,
    pub options: DatasetOptions,
    /// Sensor noise; each scene's seed is the noise seed + [`name_hash`] of its name.
    pub noise: Option<NoiseConfig>,
    pub shard: Shard,
    pub on_mismatch: OnMismatch,
    /// Keep the traced light transport in memory up to this size (GB); beyond it, trace per scene.
    pub transport_memory_gb: f64,
    /// Where the scenes are rendered (a GPU traces every scene on the device).
    pub device: Device,
    /// The error tolerance (µm) that chose the rays per pixel and the precision, recorded in each scene's
    /// render.json as `tolerance_um` (`null`: both as given).
    pub tolerance_um: Option<f64>,
    /// The error (µm) the tolerance's choice predicts ([`crate::fidelity::RenderChoice::error_um`]), recorded
    /// as `tolerance_predicted_error_um` (`null` without a tolerance).
    pub tolerance_predicted_error_um: Option<f64>,
    /// The `--backend` text of the tolerance's choice (`analytic-f32`: the f32 lanes), recorded with the
    /// tolerance in dataset.json so that the dataset's other shards take the same choice
    /// ([`super::tolerance::run_with_source`]; `None` without a tolerance).
    pub tolerance_backend: Option<String>,
    /// A test hook: wait this long after writing each scene's temporary folder, before moving it into place.
    pub scene_delay: Option<Duration>,
}

impl DatasetRequest {
    pub fn new(scenes: impl Into<PathBuf>, out: impl Into<PathBuf>, options: DatasetOptions) -> Self {
        DatasetRequest {
            scenes: scenes.into(),
            out: out.into(),
            force: false,
            options,
            noise: None,
            shard: Shard::WHOLE,
            on_mismatch: OnMismatch::Refuse,
            transport_memory_gb: crate::recon::pipeline::TRANSPORT_MEMORY_GB,
            device: Device::Cpu,
            tolerance_um: None,
            tolerance_predicted_error_um: None,
            tolerance_backend: None,
            scene_delay: None,
        }
    }
}

/// What happened to one scene of the shard.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SceneStatus {
    Rendered,
    Skipped,
    Failed,
}

impl SceneStatus {
    pub fn word(self) -> &'static str {
        match self {
            SceneStatus::Rendered => "rendered",
            SceneStatus::Skipped => "skipped",
            SceneStatus::Failed => "failed",
        }
    }
}

/// One scene's outcome (the command line prints it as a JSON line).
#[derive(Clone, Debug)]
pub struct SceneOutcome {
    pub scene: String,
    pub status: SceneStatus,
    pub seconds: f64,
    pub output: PathBuf,
    /// Why it failed.
    pub error: Option<String>,
}

/// What a client shows while a dataset renders; every method does nothing by default ([`SilentDataset`]).
pub trait DatasetProgress: Sync {
    /// A line for the user (the plan, the transport's size, warnings, the summary).
    fn message(&self, _text: &str) {}
    /// A scene of the shard is skipped (done), rendered or failed.
    fn scene(&self, _outcome: &SceneOutcome) {}
    /// Rays are being traced: the transport shared by all scenes, or one scene's render (`what` names it).
    fn tracing_started(&self, _what: &str, _rays: u64) {}
    fn rays(&self, _n: u64) {}
    fn tracing_done(&self) {}
    /// `n` scenes to render; then each starts ([`DatasetProgress::scene_started`]) and ends ([`DatasetProgress::scene`]).
    fn scenes_started(&self, _n: u64) {}
    fn scene_started(&self, _name: &str) {}
    fn scenes_done(&self) {}
}

/// No progress reports.
pub struct SilentDataset;

impl DatasetProgress for SilentDataset {}

/// What a run did.
#[derive(Clone, Debug)]
pub struct DatasetSummary {
    pub rendered: usize,
    pub skipped: usize,
    pub seconds: f64,
}

/// A scene's render warnings as the dataset's messages, named by the scene.
struct SceneWarnings<'a> {
    progress: &'a dyn DatasetProgress,
    scene: &'a str,
}

impl crate::render::folder::RenderProgress for SceneWarnings<'_> {
    fn warning(&self, text: &str) {
        self.progress.message(&format!("warning: {}: {text}", self.scene));
    }
}

/// 64-bit FNV-1a hash of a scene name: the offset of its noise seed, so a scene's noise does not depend on
/// which other scenes are in the folder or shard.
pub fn name_hash(name: &str) -> u64 {
    name.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| (h ^ b as u64).wrapping_mul(0x0100_0000_01b3))
}

/// Load a scene file and fit it to `size × size`: the cube and its description for render.json (`source`,
/// the native size and wavelengths, the fit). `wavelengths_nm` overrides the file's bands.
pub fn load_fitted(path: &Path, size: usize, wavelengths_nm: Option<&[f64]>, fit: Fit) -> Result<(SpectralCube, Value)> {
    let raw = load_scene(path, wavelengths_nm)?;
    let cube = raw.fit(size, fit).map_err(|e| Error::File { path: path.display().to_string(), message: e.to_string() })?;
    crate::render::settings::check_scene_values(&cube).map_err(|m| Error::File { path: path.display().to_string(), message: m })?;
    // Where the bands' wavelengths came from: the file (names, companion list) or the caller
    // (`--scene-wavelengths`), which replaces what the file says (recorded; it was silent).
    let source = if wavelengths_nm.is_some() { "given" } else { "file" };
    let desc = serde_json::json!({"source": path.display().to_string(), "native_height": raw.height, "native_width": raw.width, "native_wavelengths_nm": raw.wavelengths_nm, "wavelengths_source": source, "fit": fit});
    Ok((cube, desc))
}

/// The output policy of a dataset folder, checked before any work: `out` new, empty, a previous dataset (or
/// `force`), never `scenes` or one of `inputs` (the system and mask files), inside one or containing one. A
/// shard started beside others (or killed) before dataset.json exists leaves only the dataset's own files:
/// the shared outputs, scene folders of this scene list, temporaries.
pub fn check_out(request: &DatasetRequest, inputs: &[(&str, &Path)]) -> Result<()> {
    let mut inputs = inputs.to_vec();
    inputs.push(("--scenes", request.scenes.as_path()));
    let listed: Vec<String> = find_scenes(&request.scenes).map(|v| v.into_iter().map(|s| s.name).collect()).unwrap_or_default();
    let owned = |n: &str| n == MANIFEST || n == "mask.png" || (n.starts_with("mapping") && n.ends_with(".npy")) || listed.iter().any(|s| s == n) || (n.starts_with('.') && (n.contains(".partial-") || n.contains(".old-")));
    let rule = crate::io::policy::FolderRule { option: "--out", command: "render-dataset", marker: MANIFEST, force: request.force };
    crate::io::policy::check_out_folder_owned(&request.out, &rule, &inputs, &owned)?;
    Ok(())
}

/// Write the outputs shared by all scenes and shards: mask.png, the mapping cube, then dataset.json
/// (last; it records the others' sizes and CRC-32). Each file is replaced atomically; every shard of one
/// request writes the same bytes, so concurrent shards may race harmlessly.
fn write_shared(out: &Path, renderer: &Renderer, configuration: &Value, scene_names: &[String], tolerance: Option<Value>) -> Result<()> {
    renderer.mask.save_png(&out.join("mask.png"))?;
    if configuration["mapping"].as_bool().unwrap_or(false) {
        output::write_mapping(out, renderer)?;
    }
    let records = file_records(out, &shared_output_names(configuration))?;
    let mut manifest = manifest(configuration, scene_names, records);
    // The tolerance's choice, which the other shards take (`super::tolerance`); a run without a tolerance
    // keeps the one recorded for this same configuration.
    let kept = || {
        let v = crate::io::input::read_sidecar_json(&out.join(MANIFEST)).ok()?;
        let same = configuration_differences(v.get("configuration")?, configuration).is_empty();
        same.then(|| v.get(super::tolerance::TOLERANCE_KEY).cloned()).flatten()
    };
    if let Some(t) = tolerance.or_else(kept) {
        manifest[super::tolerance::TOLERANCE_KEY] = t;
    }
    let text = serde_json::to_string_pretty(&manifest).map_err(|e| Error::invalid(format!("JSON encoding failed: {e}")))?;
    crate::io::write_atomic(out.join(MANIFEST), text.as_bytes())?;
    Ok(())
}

/// Lock the output folder `out` (created if new) against other `render-dataset` runs: waits while another
/// holds it (checking or claiming the folder, or committing a scene: moments). `progress` hears of the
/// wait, and of a file system that cannot lock the folder (the run then goes on unguarded, as before).
fn lock_out(out: &Path, progress: Option<&dyn DatasetProgress>) -> Result<Option<crate::io::lock::FolderLock>> {
    use crate::io::lock::{lock_folder, LockAttempt};
    std::fs::create_dir_all(out).map_err(|e| Error::File { path: out.display().to_string(), message: format!("cannot create: {e}") })?;
    let failed = |e: std::io::Error| Error::File { path: out.display().to_string(), message: format!("cannot open the folder to lock it: {e}") };
    let mut attempt = lock_folder(out, false).map_err(failed)?;
    if matches!(attempt, LockAttempt::Busy) {
        if let Some(p) = progress {
            p.message(&format!("waiting for another render-dataset run on {} (it is checking or claiming the folder)", out.display()));
        }
        attempt = lock_folder(out, true).map_err(failed)?;
    }
    match attempt {
        LockAttempt::Held(l) => Ok(Some(l)),
        LockAttempt::Busy => Ok(None),
        LockAttempt::Unsupported(e) => {
            if let Some(p) = progress {
                p.message(&format!("warning: {}: the file system cannot lock this folder ({e}): runs with other settings started at the same moment are not told apart", out.display()));
            }
            Ok(None)
        }
    }
}

/// Move a scene's finished temporary folder into place, under the folder's lock, only while `dataset.json`
/// still records this run's configuration: a run with other settings and `--on-mismatch rerender` that
/// claimed the folder meanwhile would otherwise get this run's scenes under its dataset.json (a held-out
/// battery, round 16).
fn commit_claimed(partial: &Path, out: &Path, name: &str, configuration: &Value) -> Result<()> {
    let _lock = lock_out(out, None)?;
    if let Ok((recorded, _)) = read_manifest(out) {
        let d = configuration_differences(&recorded, configuration);
        if !d.is_empty() {
            return Err(Error::File {
                path: out.join(MANIFEST).display().to_string(),
                message: format!("another render-dataset run claimed this folder for another configuration while this one ran ({}); this scene was not written", d.join("; ")),
            });
        }
    }
    commit_scene(partial, out, name)
}

/// Write one scene's files into `dir` (its temporary folder): images, mask, then render.json with the
/// configuration and every other file's size and CRC-32.
fn write_scene(dir: &Path, renderer: &Renderer, acq: &Acquisition, device: Option<&crate::render::device::DeviceRecord>, scene: &Value, configuration: &Value, extra: Value, seconds: f64) -> Result<()> {
    let scale = output::write_images(dir, renderer, acq)?;
    renderer.mask.save_png(&dir.join("mask.png"))?;
    let mut names = vec!["acquisition.exr", "acquisition.png", "mask.png"];
    if acq.bands.is_some() {
        names.push("cube.exr");
    }
    let records = file_records(dir, &names)?;
    let mut json = output::sidecar(renderer, acq, device, scene, scale, seconds, rayon::current_num_threads());
    if let (Some(o), Value::Object(e)) = (json.as_object_mut(), extra) {
        o.extend(e);
        o.insert("configuration".into(), configuration.clone());
        o.insert("outputs".into(), records);
    }
    output::write_sidecar(dir, &json)
}

/// What a run will do with its shard's scenes, decided before anything is written.
struct Plan {
    /// The list the shard indexes.
    order: SceneOrder,
    /// Scenes to render (missing, damaged, or mismatching).
    todo: Vec<DatasetScene>,
    /// Scenes complete with this configuration (from unchanged files), by name.
    skipped: Vec<String>,
    /// Mismatching scenes with their differences.
    mismatched: Vec<String>,
    /// Messages for the user (damaged scenes rendered again, recorded scenes gone but done).
    notes: Vec<String>,
    /// Recorded scenes of this shard no longer in the folder and not done: (name, why), reported failed.
    gone_failed: Vec<(String, String)>,
}

impl Plan {
    fn new(a: &DatasetRequest, order: SceneOrder, found: Vec<DatasetScene>, configuration: &Value) -> Plan {
        let mut p = Plan { order, todo: vec![], skipped: vec![], mismatched: vec![], notes: vec![], gone_failed: vec![] };
        let mine: Vec<String> = p.order.select(a.shard).into_iter().map(String::from).collect();
        for name in mine {
            let Some(s) = found.iter().find(|f| f.name == name) else {
                // A recorded scene no longer in the folder keeps its place (no other scene moves); what it left
                // stands when done, otherwise nothing can render it.
                match check_scene(&a.out, &name, Some(configuration)) {
                    SceneState::Done => {
                        p.notes.push(format!("{name}: no longer in {}, kept as rendered (its input cannot be compared)", a.scenes.display()));
                        p.skipped.push(name);
                    }
                    state => {
                        let why = match state.problems() {
                            v if v.is_empty() => String::new(),
                            v => format!(" (its folder: {})", v.join("; ")),
                        };
                        p.gone_failed.push((name.clone(), format!("{MANIFEST} lists the scene but {} no longer holds it, and it is not rendered{why}: restore its file, or render into another --out (the list keeps its place so that no other scene moves to another shard)", a.scenes.display())));
                    }
                }
                continue;
            };
            // Done and rendered from the same scene content (a scene file replaced since is rendered again).
            match with_scene_input(check_scene(&a.out, &s.name, Some(configuration)), &a.out, s) {
                SceneState::Done => p.skipped.push(s.name.clone()),
                SceneState::Missing => p.todo.push(s.clone()),
                SceneState::Damaged(d) => {
                    p.notes.push(format!("{}: damaged, rendering again ({})", s.name, d.join("; ")));
                    p.todo.push(s.clone())
                }
                SceneState::Mismatch(d) => {
                    p.mismatched.push(format!("{} ({})", s.name, d.join("; ")));
                    p.todo.push(s.clone())
                }
            }
        }
        p
    }
}

/// The configuration `request` asks for with `renderer` (what dataset.json and each render.json record and
/// a resume compares): [`configuration`], the sensor noise and, on a GPU, its accumulation.
pub fn requested_configuration(a: &DatasetRequest, renderer: &Renderer) -> Result<Value> {
    let mut configuration = configuration(renderer, &a.options);
    if let Some(o) = configuration.as_object_mut() {
        // Sensor noise is part of what a scene's files hold: a request with other noise is another configuration.
        // How its random numbers are drawn too: a dataset rendered with the earlier single row-major stream
        // holds other noise for the same settings, so it is another configuration (`noise.rng`).
        let mut noise_json = serde_json::to_value(&a.noise).map_err(|e| Error::invalid(format!("noise settings: {e}")))?;
        if let Some(n) = noise_json.as_object_mut() {
            n.insert("rng".into(), crate::render::noise::RNG.into());
        }
        o.insert("noise".into(), noise_json);
        // The GPU kernels accumulate in fixed point, the CPU renderer in f32 (docs/gpu.md): other bytes, so
        // another configuration — a dataset is never a mix of the two (a held-out battery resumed a CPU
        // dataset on the twin, scene by scene). `cuda` and `cpu-twin` give the same bits: one configuration,
        // so a dataset started on a GPU node resumes on the twin and back. CPU datasets keep their records.
        if a.device != Device::Cpu {
            o.insert("accumulation".into(), serde_json::json!("gpu-kernels"));
        }
    }
    Ok(configuration)
}

/// Render the dataset `request` describes through `system` with `tracer`, `cfg` (its rays per pixel as
/// chosen) and `mask`; `inputs` are the files the output must not touch besides the scenes. Decides
/// everything before writing anything; a scene that fails is reported and the others go on (the run then
/// ends with an error naming the failed ones).
#[allow(clippy::too_many_arguments)]
pub fn run(request: &DatasetRequest, inputs: &[(&str, &Path)], system: &SequentialSystem, tracer: &dyn Tracer, cfg: RenderConfig, mask: Mask, progress: &dyn DatasetProgress) -> Result<DatasetSummary> {
    let t0 = Instant::now();
    let a = request;
    if !(a.transport_memory_gb.is_finite() && a.transport_memory_gb >= 0.0) {
        return Err(Error::invalid(format!("--transport-memory-gb {}: must be finite and ≥ 0", a.transport_memory_gb)));
    }
    check_out(a, inputs)?;
    let scenes = find_scenes(&a.scenes)?;
    if scenes.is_empty() {
        return Err(Error::File { path: a.scenes.display().to_string(), message: "no scenes (.exr, .npy, or folders of .png)".into() });
    }
    let shard = a.shard;
    let renderer = Renderer::new(system, tracer, cfg, mask)?;
    let configuration = requested_configuration(a, &renderer)?;

    // Decide everything before writing anything. The shard indexes the dataset's list (SceneOrder: the one
    // dataset.json recorded, then scenes new in the folder), not the folder's sorted listing alone.
    let mut plan = Plan::new(a, SceneOrder::of(&a.out, &scenes), scenes, &configuration);
    // The folder's configuration is checked and claimed (dataset.json written) under the folder's lock: two
    // runs with different settings both found no dataset.json, both wrote it and both exited 0 over a mixed
    // folder (a held-out battery, round 16). Now the second sees the first's dataset.json and is refused as a
    // mismatch, nothing written; shards of one configuration take the lock in turn and go on.
    let claim = lock_out(&a.out, Some(progress))?;
    // A task that claimed the folder meanwhile may have recorded another list (a scene added between the two
    // tasks' starts): plan again from it, so every task of the array partitions the same list.
    // (dataset.json is read once here, under the lock: the list, the warning below and the comparison before
    // writing all use this reading.)
    let found = find_scenes(&a.scenes)?;
    let recorded = read_manifest(&a.out);
    let order = SceneOrder::new(recorded.as_ref().ok().map(|(_, n)| n.as_slice()), &found);
    if order != plan.order {
        plan = Plan::new(a, order, found, &configuration);
    }
    let Plan { order, todo, skipped, mut mismatched, notes, gone_failed } = plan;
    let shared_state = check_shared(&a.out, Some(&configuration));
    if let SceneState::Mismatch(d) = &shared_state {
        mismatched.insert(0, format!("{} ({})", MANIFEST, d.join("; ")));
    }
    if !mismatched.is_empty() {
        if a.on_mismatch == OnMismatch::Refuse {
            return Err(Error::File {
                path: a.out.display().to_string(),
                message: format!(
                    "{} output(s) were rendered with another configuration than requested, or from scene files that have changed since: {}. Nothing was written: rerun with --on-mismatch rerender to replace them, or choose another --out",
                    mismatched.len(),
                    mismatched.join(", ")
                ),
            });
        }
        progress.message(&format!("rendering again (--on-mismatch rerender): {}", mismatched.join(", ")));
    }
    if let Some(m) = order.changes_message(&a.scenes) {
        progress.message(&m);
    }
    if let (true, Err(e)) = (a.out.join(MANIFEST).exists(), &recorded) {
        progress.message(&format!("warning: {e}: its scene list is unreadable, so shards index the folder's sorted list (scenes added since the list was recorded may now fall to other shards)"));
    }
    for n in &notes {
        progress.message(n);
    }
    let held = order.select(shard).len();
    progress.message(&format!(
        "{} scenes in the list of {}; shard {shard} holds {held}: {} to render, {} complete (skipped){}",
        order.names.len(),
        a.scenes.display(),
        todo.len(),
        skipped.len(),
        if gone_failed.is_empty() { String::new() } else { format!(", {} no longer in the folder and not rendered (failed)", gone_failed.len()) }
    ));
    for s in &skipped {
        progress.scene(&SceneOutcome { scene: s.clone(), status: SceneStatus::Skipped, seconds: 0.0, output: a.out.join(s), error: None });
    }
    let mut failed: Vec<String> = Vec::new();
    for (name, why) in &gone_failed {
        progress.scene(&SceneOutcome { scene: name.clone(), status: SceneStatus::Failed, seconds: 0.0, output: a.out.join(name), error: Some(why.clone()) });
        failed.push(name.clone());
    }
    // The list is recorded as soon as it grows, so a later addition is appended after this one whichever
    // task sees it first (two additions appended at once are sorted; one after the other, in turn).
    let recorded_names = recorded.as_ref().ok().map(|(_, n)| n);
    if shared_state != SceneState::Done || !todo.is_empty() || recorded_names != Some(&order.names) {
        write_shared(&a.out, &renderer, &configuration, &order.names, super::tolerance::choice_record(a, renderer.config.rays_per_pixel))?;
    }
    drop(claim);
    let n_failed_gone = failed.len();
    let failed_error = |failed: &[String], of: usize| Error::invalid(format!("{} of {} scenes failed (their JSON lines say why): {}", failed.len(), of, failed.join(", ")));
    if todo.is_empty() {
        if !failed.is_empty() {
            return Err(failed_error(&failed, n_failed_gone));
        }
        return Ok(DatasetSummary { rendered: 0, skipped: skipped.len(), seconds: t0.elapsed().as_secs_f64() });
    }

    // On the CPU: trace the transport once (if it fits the budget), then apply it to every scene. On a GPU
    // every scene is traced on the device (its kernels trace and accumulate in one pass; docs/gpu.md).
    let on_cpu = a.device == Device::Cpu;
    let planes = renderer.config.spectral.planes();
    let t_trace = Instant::now();
    let probe = if on_cpu { Some(crate::recon::exact::TransportMemory::probe(&renderer)?) } else { None };
    // The cache holds every plane's footprints (the exact operator's estimate from the middle plane, ×planes
    // ×1.25); it lives beside each scene's render (its cube, images and kernels), so both count against the
    // memory budget (`--max-memory-gb`): a cache over it is not kept, each scene traced instead (round 19: the
    // cache was added on top of the budget unchecked).
    let estimate = probe.as_ref().map_or(0.0, |(m, _)| m.footprints);
    let c = &renderer.config;
    let scene_bytes = crate::limits::bytes_render_hw(c.scene_height, c.scene_width, c.spectral.bands_nm.len().max(31), c.spectral.bands_nm.len(), planes, a.options.cube, c.airy.as_ref().map(|a| a.diameter_px));
    let memory = crate::limits::budget();
    let (held, _) = crate::limits::held_now();
    let over_memory = !(estimate + scene_bytes + held <= memory.memory_bytes);
    let budget = a.transport_memory_gb * 1e9;
    let cached: Option<Vec<PlaneTransport>> = if on_cpu && todo.len() > 1 && estimate <= budget && !over_memory {
        progress.tracing_started("tracing the light transport", renderer.rays_per_render());
        let t = renderer.trace_all(&|k| progress.rays(k));
        progress.tracing_done();
        let t = t?;
        let bytes: usize = t.iter().map(|p| p.bytes()).sum();
        progress.message(&format!("light transport traced in {:.2} s ({:.2} GB), reused for {} scenes", t_trace.elapsed().as_secs_f64(), bytes as f64 / 1e9, todo.len()));
        Some(t)
    } else {
        if on_cpu && todo.len() > 1 && estimate > budget {
            progress.message(&format!("light transport would need ~{:.2} GB > {:.2} GB (--transport-memory-gb): tracing each scene", estimate / 1e9, a.transport_memory_gb));
        } else if on_cpu && todo.len() > 1 {
            progress.message(&format!(
                "light transport would need ~{} beside ~{} for each scene's render{}, over the memory budget of {} ({}): tracing each scene",
                crate::limits::fmt_gb(estimate),
                crate::limits::fmt_gb(scene_bytes),
                if held > 0.0 { format!(" and {} held already", crate::limits::fmt_gb(held)) } else { String::new() },
                crate::limits::fmt_gb(memory.memory_bytes),
                memory.memory_source
            ));
        }
        None
    };
    let _cache_held = cached.as_ref().map(|t| crate::limits::hold("render-dataset's cached light transport", t.iter().map(|p| p.bytes()).sum::<usize>() as f64));
    let transport_seconds = t_trace.elapsed().as_secs_f64();
    drop(probe);

    // f32's rounding on this system (one measurement for every scene; `render`'s warning, once).
    let f32_error = renderer.f32_chief_ray_error()?;
    if let Some(m) = f32_error.and_then(|f| f.message()) {
        progress.message(&format!("warning: {m}"));
    }
    // Planes a coded-mask surface passes nothing at (the same for every scene of the dataset).
    let mask_dark = renderer.mask_dark_planes()?;
    if let Some(d) = &mask_dark {
        progress.message(&format!("warning: {}", d.message()));
    }
    progress.scenes_started(todo.len() as u64);
    for s in &todo {
        let ts = Instant::now();
        progress.scene_started(&s.name);
        let dest = a.out.join(&s.name);
        let result = (|| -> Result<()> {
            // This shard owns the scene: what a killed task left for it is garbage.
            remove_leftovers(&a.out, &s.name)?;
            // The scene's files as they are before it is read (a change during the render shows next time).
            let scene_input = scene_input_record(s, a.options.scene_wavelengths_nm.is_none())?;
            let (scene, desc) = load_fitted(&s.path, renderer.config.scene_height, a.options.scene_wavelengths_nm.as_deref(), a.options.fit)?;
            let (mut acq, device_record) = match &cached {
                Some(t) => (renderer.render_cached(&scene, t, a.options.cube, &|_| {})?, None),
                None => {
                    progress.tracing_started(&s.name, renderer.rays_per_render());
                    let out = crate::render::device::render_for(a.device, &renderer, &scene, a.options.cube, &|k| progress.rays(k));
                    progress.tracing_done();
                    out?
                }
            };
            let noise = a.noise.as_ref().map(|n| NoiseConfig { seed: n.seed.wrapping_add(name_hash(&s.name)), ..n.clone() });
            let noise_json = crate::render::folder::apply_noise(noise.as_ref(), &mut acq, &SceneWarnings { progress, scene: &s.name })?;
            let partial = partial_dir(&a.out, &s.name)?;
            let mut extra = serde_json::json!({"dataset_mode": true, "transport_cached": cached.is_some(), "transport_seconds": transport_seconds, "seconds_scene": ts.elapsed().as_secs_f64(), "noise": noise_json, "scene_input": scene_input, "tolerance_um": a.tolerance_um, "tolerance_predicted_error_um": a.tolerance_predicted_error_um});
            if let Some(x) = renderer.spectral_extrapolation(&scene) {
                progress.message(&format!("warning: {}: {}", s.name, x.message()));
                extra["spectral_extrapolation"] = x.to_json();
            }
            if let Some(w) = device_record.as_ref().and_then(|d| d.fixed_point_warning.as_ref()) {
                progress.message(&format!("warning: {}: {w}", s.name));
            }
            if let Some(d) = &mask_dark {
                extra["mask_dark_planes"] = d.to_json();
            }
            if let Some(f) = f32_error {
                extra["f32_chief_ray_error"] = f.to_json();
            }
            let written = write_scene(&partial, &renderer, &acq, device_record.as_ref(), &desc, &configuration, extra, ts.elapsed().as_secs_f64()).and_then(|()| {
                if let Some(d) = a.scene_delay {
                    std::thread::sleep(d);
                }
                commit_claimed(&partial, &a.out, &s.name, &configuration)
            });
            if written.is_err() {
                let _ = std::fs::remove_dir_all(&partial);
            } else if let Some(w) = crate::render::folder::zero_warning(&acq, &noise_json) {
                // The warning `render` gives a zero acquisition, per scene (noted in session 36).
                progress.message(&format!("warning: {}: {w}", s.name));
            }
            written
        })();
        let seconds = ts.elapsed().as_secs_f64();
        match result {
            Ok(()) => progress.scene(&SceneOutcome { scene: s.name.clone(), status: SceneStatus::Rendered, seconds, output: dest, error: None }),
            Err(e) => {
                progress.scene(&SceneOutcome { scene: s.name.clone(), status: SceneStatus::Failed, seconds, output: dest, error: Some(format!("{e:#}")) });
                failed.push(s.name.clone());
            }
        }
    }
    progress.scenes_done();
    progress.message(&format!("rendered {} of {} scenes of shard {shard} into {} in {:.2} s", todo.len() + n_failed_gone - failed.len(), todo.len(), a.out.display(), t0.elapsed().as_secs_f64()));
    if !failed.is_empty() {
        return Err(failed_error(&failed, todo.len() + n_failed_gone));
    }
    Ok(DatasetSummary { rendered: todo.len(), skipped: skipped.len(), seconds: t0.elapsed().as_secs_f64() })
}
