//! `render-dataset` and `dataset-status`: render a folder of scenes (whole, or one shard of a Slurm job
//! array) and audit the result. The rules both follow (shards, the canonical configuration, what counts as
//! done, all-or-nothing scene folders) live in the library, [`crate::render::dataset`]; see docs/slurm.md.
//!
//! ```text
//! diffcassi render-dataset --scenes scenes/ --preset sp --out out/sp-dataset              # everything
//! diffcassi render-dataset --scenes scenes/ --preset sp --out out/sp-dataset --shard 1/4  # scenes 1, 5, 9, …
//! diffcassi render-dataset --scenes scenes/ --preset sp --out out/sp-dataset --shard slurm  # in a job array
//! diffcassi dataset-status out/sp-dataset --scenes scenes/ [--json]
//! ```
//!
//! stdout of `render-dataset` is JSON Lines, one object per scene of the shard:
//! `{"scene":"s03","status":"rendered","seconds":1.25,"output":"out/sp-dataset/s03"}` (`status` is
//! `rendered`, `skipped` or `failed`; `failed` adds `"error"`). Progress and messages go to stderr.
use super::shared::load_system;
use super::render::{apply_noise, config_from, load_fitted, name_hash, parse_fit, progress_bar, render_tracer, scene_wavelengths, NoiseArgs, RenderCommon};
use crate::error::{Error, Result};
use crate::io::write_atomic;
use crate::render::dataset::{self, DatasetOptions, DatasetStatus, SceneState, Shard};
use crate::render::{output, NoiseConfig, PlaneTransport, Renderer};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Environment variable (milliseconds) that makes `render-dataset` wait after writing each scene's
/// temporary folder and before moving it into place. A test hook: it keeps a scene "in flight" long enough
/// for the Slurm test to kill the task there (tests/slurm/run.sh).
pub const DEBUG_SCENE_DELAY_ENV: &str = "DIFFCASSI_DEBUG_SCENE_DELAY_MS";

#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum OnMismatch {
    /// Stop with an error before writing anything, naming the scenes and the differing settings.
    Refuse,
    /// Render those scenes again and replace their folders (and the shared outputs) whole.
    Rerender,
}

#[derive(Args, Debug)]
pub struct RenderDatasetArgs {
    #[command(flatten)]
    pub common: RenderCommon,
    /// Folder of scenes (.exr, .npy, PNG sub-folders).
    #[arg(long)]
    pub scenes: PathBuf,
    /// Output folder: one sub-folder per scene, plus dataset.json, mask.png and the mapping cube. New, empty,
    /// or a previous render-dataset output (it holds dataset.json; resumed); never --scenes, inside it or
    /// containing it.
    #[arg(long)]
    pub out: PathBuf,
    /// Accept an --out folder that holds other files (not a previous render-dataset output): the dataset is
    /// written beside them, nothing else there is touched (docs/robustness.md, "Output policy").
    #[arg(long)]
    pub force: bool,
    /// Keep the traced light transport in memory up to this size (GB); beyond it, trace per scene.
    #[arg(long = "transport-memory-gb", default_value_t = 4.0, value_parser = super::render::positive_gb)]
    pub transport_memory_gb: f64,
    /// Sensor noise; each scene's noise seed is `--noise-seed` + a hash of the scene's name (FNV-1a), so a
    /// scene's noise does not depend on which other scenes are in the folder or shard.
    #[command(flatten)]
    pub noise: NoiseArgs,
    /// Render only shard K of N: the scenes whose index in the full sorted list is ≡ K (mod N). `slurm`
    /// takes K and N from SLURM_ARRAY_TASK_ID / SLURM_ARRAY_TASK_COUNT; `slurm/N` takes K from Slurm and N
    /// as given (for a resubmitted subset of an array).
    #[arg(long, value_name = "K/N|slurm|slurm/N", value_parser = parse_shard_arg)]
    pub shard: Option<Shard>,
    /// A scene (or dataset.json) already rendered with another configuration: refuse (the default; nothing
    /// is written) or rerender it.
    #[arg(long = "on-mismatch", value_enum, default_value = "refuse")]
    pub on_mismatch: OnMismatch,
}

fn parse_shard_arg(text: &str) -> std::result::Result<Shard, String> {
    Shard::parse(text, |k| std::env::var(k).ok())
}

#[derive(Args, Debug)]
pub struct DatasetStatusArgs {
    /// Output folder of render-dataset.
    pub dir: PathBuf,
    /// Scenes folder: check its scenes (default: the scene list recorded in DIR/dataset.json).
    #[arg(long)]
    pub scenes: Option<PathBuf>,
    /// Print the report as one JSON object.
    #[arg(long)]
    pub json: bool,
}

/// One JSON line of `render-dataset`'s stdout.
#[derive(serde::Serialize)]
struct SceneLine<'a> {
    scene: &'a str,
    status: &'a str,
    seconds: f64,
    output: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    error: Option<String>,
}

fn emit(line: &SceneLine) {
    // One write per line: a killed task's log holds whole lines only.
    let text = serde_json::to_string(line).unwrap_or_else(|e| format!("{{\"scene\":\"?\",\"status\":\"failed\",\"error\":\"JSON encoding: {e}\"}}"));
    let mut out = std::io::stdout().lock();
    let _ = out.write_all(format!("{text}\n").as_bytes());
    let _ = out.flush();
}

fn debug_delay() -> Result<Option<std::time::Duration>> {
    match std::env::var(DEBUG_SCENE_DELAY_ENV) {
        Err(_) => Ok(None),
        Ok(v) => v.trim().parse::<u64>().map(|ms| Some(std::time::Duration::from_millis(ms))).map_err(|_| Error::invalid(format!("{DEBUG_SCENE_DELAY_ENV}=`{v}`: expected milliseconds (a whole number)"))),
    }
}

/// Write the outputs shared by all scenes and shards: mask.png, the mapping cube, then dataset.json
/// (last; it records the others' sizes and CRC-32). Each file is replaced atomically; every shard of one
/// request writes the same bytes, so concurrent shards may race harmlessly.
fn write_shared(out: &Path, renderer: &Renderer, configuration: &serde_json::Value, scene_names: &[String]) -> Result<()> {
    renderer.mask.save_png(&out.join("mask.png"))?;
    if configuration["mapping"].as_bool().unwrap_or(false) {
        output::write_mapping(out, renderer)?;
    }
    let records = dataset::file_records(out, &dataset::shared_output_names(configuration))?;
    let manifest = dataset::manifest(configuration, scene_names, records);
    let text = serde_json::to_string_pretty(&manifest).map_err(|e| Error::invalid(format!("JSON encoding failed: {e}")))?;
    write_atomic(out.join(dataset::MANIFEST), text.as_bytes())?;
    Ok(())
}

/// Write one scene's files into `dir` (its temporary folder): images, mask, then render.json with the
/// configuration and every other file's size and CRC-32.
fn write_scene(dir: &Path, renderer: &Renderer, acq: &crate::render::Acquisition, scene: &serde_json::Value, configuration: &serde_json::Value, extra: serde_json::Value, seconds: f64) -> Result<()> {
    let scale = output::write_images(dir, renderer, acq)?;
    renderer.mask.save_png(&dir.join("mask.png"))?;
    let mut names = vec!["acquisition.exr", "acquisition.png", "mask.png"];
    if acq.bands.is_some() {
        names.push("cube.exr");
    }
    let records = dataset::file_records(dir, &names)?;
    let mut json = output::sidecar(renderer, acq, scene, scale, seconds, rayon::current_num_threads());
    if let (Some(o), serde_json::Value::Object(e)) = (json.as_object_mut(), extra) {
        o.extend(e);
        o.insert("configuration".into(), configuration.clone());
        o.insert("outputs".into(), records);
    }
    output::write_sidecar(dir, &json)
}

pub fn render_dataset(a: RenderDatasetArgs) -> Result<()> {
    let t0 = Instant::now();
    let shard = a.shard.unwrap_or(Shard::WHOLE);
    if !(a.transport_memory_gb.is_finite() && a.transport_memory_gb >= 0.0) {
        return Err(Error::invalid(format!("--transport-memory-gb {}: must be finite and ≥ 0", a.transport_memory_gb)));
    }
    let delay = debug_delay()?;
    // The output policy before any work: --out new, empty, a previous dataset (or --force), never an input.
    let mut inputs = super::shared::system_inputs(&a.common.system);
    inputs.push(("--scenes", a.scenes.as_path()));
    inputs.extend(a.common.mask.as_deref().map(|p| ("--mask", p)));
    // A shard started beside others (or killed) before dataset.json exists leaves only the dataset's own
    // files: the shared outputs, scene folders of this scene list, temporaries.
    let listed: Vec<String> = dataset::find_scenes(&a.scenes).map(|v| v.into_iter().map(|s| s.name).collect()).unwrap_or_default();
    let owned = |n: &str| n == dataset::MANIFEST || n == "mask.png" || (n.starts_with("mapping") && n.ends_with(".npy")) || listed.iter().any(|s| s == n) || (n.starts_with('.') && (n.contains(".partial-") || n.contains(".old-")));
    let rule = crate::io::policy::FolderRule { option: "--out", command: "render-dataset", marker: dataset::MANIFEST, force: a.force };
    crate::io::policy::check_out_folder_owned(&a.out, &rule, &inputs, &owned)?;
    let noise = a.noise.config()?;
    let system = load_system(&a.common.system)?;
    let (mut cfg, mask) = config_from(&a.common)?;
    let scenes = dataset::find_scenes(&a.scenes)?;
    if scenes.is_empty() {
        return Err(Error::File { path: a.scenes.display().to_string(), message: "no scenes (.exr, .npy, or folders of .png)".into() });
    }
    let scene_names: Vec<String> = scenes.iter().map(|s| s.name.clone()).collect();
    let options = DatasetOptions { fit: parse_fit(&a.common.fit)?, scene_wavelengths_nm: scene_wavelengths(&a.common)?, cube: a.common.cube, mapping: !a.common.no_mapping };
    let (tracer, rays) = render_tracer(&a.common, &system, &mut cfg, &mask)?;
    cfg.rays_per_pixel = rays;
    let renderer = Renderer::new(&system, tracer.as_ref(), cfg, mask)?;
    let mut configuration = dataset::configuration(&renderer, &options);
    if let Some(o) = configuration.as_object_mut() {
        // Sensor noise is part of what a scene's files hold: a request with other noise is another configuration.
        // How its random numbers are drawn too: a dataset rendered with the earlier single row-major stream
        // holds other noise for the same settings, so it is another configuration (`noise.rng`).
        let mut noise_json = serde_json::to_value(&noise).map_err(|e| Error::invalid(format!("noise settings: {e}")))?;
        if let Some(n) = noise_json.as_object_mut() {
            n.insert("rng".into(), crate::render::noise::RNG.into());
        }
        o.insert("noise".into(), noise_json);
        // The GPU kernels accumulate in fixed point, the CPU renderer in f32 (docs/gpu.md): other bytes, so
        // another configuration — a dataset is never a mix of the two (a held-out battery resumed a CPU
        // dataset on the twin, scene by scene). `cuda` and `cpu-twin` give the same bits: one configuration,
        // so a dataset started on a GPU node resumes on the twin and back. CPU datasets keep their records.
        if a.common.device.parse::<crate::render::Device>()? != crate::render::Device::Cpu {
            o.insert("accumulation".into(), serde_json::json!("gpu-kernels"));
        }
    }

    // Decide everything before writing anything.
    let mine = shard.select(&scenes);
    let shared_state = dataset::check_shared(&a.out, Some(&configuration));
    let mut todo = Vec::new();
    let mut skipped = Vec::new();
    let mut mismatched: Vec<String> = Vec::new();
    if let SceneState::Mismatch(d) = &shared_state {
        mismatched.push(format!("{} ({})", dataset::MANIFEST, d.join("; ")));
    }
    for s in &mine {
        // Done and rendered from the same scene content (a scene file replaced since is rendered again).
        match dataset::with_scene_input(dataset::check_scene(&a.out, &s.name, Some(&configuration)), &a.out, s) {
            SceneState::Done => skipped.push(*s),
            SceneState::Missing => todo.push(*s),
            SceneState::Damaged(p) => {
                eprintln!("{}: damaged, rendering again ({})", s.name, p.join("; "));
                todo.push(*s)
            }
            SceneState::Mismatch(d) => {
                mismatched.push(format!("{} ({})", s.name, d.join("; ")));
                todo.push(*s)
            }
        }
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
        eprintln!("rendering again (--on-mismatch rerender): {}", mismatched.join(", "));
    }
    eprintln!(
        "{} scenes in {}; shard {shard} holds {}: {} to render, {} complete (skipped)",
        scenes.len(),
        a.scenes.display(),
        mine.len(),
        todo.len(),
        skipped.len()
    );
    for s in &skipped {
        emit(&SceneLine { scene: &s.name, status: "skipped", seconds: 0.0, output: a.out.join(&s.name).display().to_string(), error: None });
    }
    if shared_state != SceneState::Done || !todo.is_empty() {
        write_shared(&a.out, &renderer, &configuration, &scene_names)?;
    }
    if todo.is_empty() {
        return Ok(());
    }

    // On the CPU: trace the transport once (if it fits the budget), then apply it to every scene. On a GPU
    // every scene is traced on the device (its kernels trace and accumulate in one pass; docs/gpu.md).
    let device: crate::render::Device = a.common.device.parse()?;
    let on_cpu = device == crate::render::Device::Cpu;
    let planes = renderer.config.spectral.planes();
    let t_trace = Instant::now();
    let probe = if on_cpu { renderer.trace_plane(planes / 2)? } else { PlaneTransport::default() };
    let estimate = probe.bytes() as f64 * planes as f64 * 1.25;
    let budget = a.transport_memory_gb * 1e9;
    let cached: Option<Vec<PlaneTransport>> = if on_cpu && todo.len() > 1 && estimate <= budget {
        let pb = progress_bar(renderer.rays_per_render(), "tracing the light transport");
        let t = renderer.trace_all(&|k| pb.inc(k))?;
        pb.finish_and_clear();
        let bytes: usize = t.iter().map(|p| p.bytes()).sum();
        eprintln!("light transport traced in {:.2} s ({:.2} GB), reused for {} scenes", t_trace.elapsed().as_secs_f64(), bytes as f64 / 1e9, todo.len());
        Some(t)
    } else {
        if on_cpu && todo.len() > 1 {
            eprintln!("light transport would need ~{:.2} GB > {:.2} GB: tracing each scene", estimate / 1e9, a.transport_memory_gb);
        }
        None
    };
    let transport_seconds = t_trace.elapsed().as_secs_f64();
    drop(probe);

    let pb_scenes = ProgressBar::new(todo.len() as u64);
    pb_scenes.set_style(ProgressStyle::with_template("scenes [{elapsed_precise}] {wide_bar} {pos}/{len}, {per_sec}, ETA {eta} {msg}").unwrap_or_else(|_| ProgressStyle::default_bar()));
    let mut failed: Vec<String> = Vec::new();
    for s in &todo {
        let ts = Instant::now();
        pb_scenes.set_message(s.name.clone());
        let dest = a.out.join(&s.name);
        let result = (|| -> Result<()> {
            // This shard owns the scene: what a killed task left for it is garbage.
            dataset::remove_leftovers(&a.out, &s.name)?;
            // The scene's files as they are before it is read (a change during the render shows next time).
            let scene_input = dataset::scene_input_record(s, a.common.scene_wavelengths.is_none())?;
            let (scene, desc) = load_fitted(&s.path, &a.common)?;
            let (mut acq, device_record) = match &cached {
                Some(t) => (renderer.render_cached(&scene, t, a.common.cube, &|_| {})?, None),
                None => {
                    let pb = progress_bar(renderer.rays_per_render(), &s.name);
                    let out = crate::render::device::render_for(device, &renderer, &scene, a.common.cube, &|k| pb.inc(k))?;
                    pb.finish_and_clear();
                    out
                }
            };
            let scene_noise = noise.as_ref().map(|n| NoiseConfig { seed: n.seed.wrapping_add(name_hash(&s.name)), ..n.clone() });
            let noise_json = apply_noise(scene_noise.as_ref(), &mut acq, "", true)?;
            let partial = dataset::partial_dir(&a.out, &s.name)?;
            let mut extra = serde_json::json!({"dataset_mode": true, "transport_cached": cached.is_some(), "transport_seconds": transport_seconds, "seconds_scene": ts.elapsed().as_secs_f64(), "noise": noise_json, "device": crate::render::device::record_json(&renderer, device_record.as_ref()), "scene_input": scene_input});
            if let Some(x) = renderer.spectral_extrapolation(&scene) {
                eprintln!("warning: {}: {}", s.name, x.message());
                extra["spectral_extrapolation"] = x.to_json();
            }
            let written = write_scene(&partial, &renderer, &acq, &desc, &configuration, extra, ts.elapsed().as_secs_f64()).and_then(|()| {
                if let Some(d) = delay {
                    std::thread::sleep(d);
                }
                dataset::commit_scene(&partial, &a.out, &s.name)
            });
            if written.is_err() {
                let _ = std::fs::remove_dir_all(&partial);
            }
            written
        })();
        let seconds = ts.elapsed().as_secs_f64();
        match result {
            Ok(()) => {
                emit(&SceneLine { scene: &s.name, status: "rendered", seconds, output: dest.display().to_string(), error: None });
                pb_scenes.println(format!("{}: {seconds:.2} s", s.name));
            }
            Err(e) => {
                emit(&SceneLine { scene: &s.name, status: "failed", seconds, output: dest.display().to_string(), error: Some(format!("{e:#}")) });
                pb_scenes.println(format!("{}: failed: {e:#}", s.name));
                failed.push(s.name.clone());
            }
        }
        pb_scenes.inc(1);
    }
    pb_scenes.finish_and_clear();
    eprintln!("rendered {} of {} scenes of shard {shard} into {} in {:.2} s", todo.len() - failed.len(), todo.len(), a.out.display(), t0.elapsed().as_secs_f64());
    if !failed.is_empty() {
        return Err(Error::invalid(format!("{} of {} scenes failed (their JSON lines say why): {}", failed.len(), todo.len(), failed.join(", "))));
    }
    Ok(())
}

pub fn dataset_status(a: DatasetStatusArgs) -> Result<()> {
    if !a.dir.is_dir() {
        return Err(Error::File { path: a.dir.display().to_string(), message: "not a folder (the --out of render-dataset)".into() });
    }
    let found = a.scenes.as_ref().map(|src| dataset::find_scenes(src)).transpose()?;
    let names = found.as_ref().map(|v| v.iter().map(|s| s.name.clone()).collect::<Vec<_>>());
    let mut st = DatasetStatus::check(&a.dir, names, None)?;
    // With --scenes: a scene done from files that have changed since is to be rendered again.
    for s in st.scenes.iter_mut() {
        if let Some(f) = found.iter().flatten().find(|f| f.name == s.scene) {
            s.state = dataset::with_scene_input(s.state.clone(), &a.dir, f);
        }
    }
    if st.scenes.is_empty() {
        let source = match &a.scenes {
            Some(src) => format!("--scenes {} holds no scenes (.exr, .npy, or folders of .png)", src.display()),
            None => format!("its {} lists no scenes", dataset::MANIFEST),
        };
        return Err(Error::File { path: a.dir.display().to_string(), message: format!("no scenes: {source}; nothing can be done or missing") });
    }
    let (done, missing, corrupt) = st.counts();
    if a.json {
        let text = serde_json::to_string_pretty(&st.to_json()).map_err(|e| Error::invalid(format!("JSON encoding failed: {e}")))?;
        println!("{text}");
    } else {
        let shared_problems = st.shared.problems();
        println!("{:<8} {}{}", st.shared.word(), dataset::MANIFEST, if shared_problems.is_empty() { String::new() } else { format!(": {}", shared_problems.join("; ")) });
        for s in &st.scenes {
            let p = s.state.problems();
            println!("{:<8} {}{}", s.state.word(), s.scene, if p.is_empty() { String::new() } else { format!(": {}", p.join("; ")) });
        }
        for l in &st.leftovers {
            println!("{:<8} {} (a running task's, or a killed task's: removed when that scene's shard runs again)", "temp", l.display());
        }
        println!("{}: {} scenes: {done} done, {missing} missing, {corrupt} corrupt; shared outputs {}", a.dir.display(), st.scenes.len(), st.shared.word());
    }
    if st.is_clean() {
        Ok(())
    } else {
        Err(Error::invalid(format!("{}: {missing} missing, {corrupt} corrupt of {} scenes; shared outputs {}", a.dir.display(), st.scenes.len(), st.shared.word())))
    }
}
