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
use super::bars::{bar, BarSlot};
use super::shared::load_system;
use super::render::{progress_bar, NoiseArgs, RenderCommon};
use crate::error::{Error, Result};
use crate::render::dataset::{self, DatasetOptions, DatasetProgress, DatasetRequest, DatasetStatus, SceneOutcome, Shard};
use clap::Args;
use std::io::Write;
use std::path::PathBuf;

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

impl From<OnMismatch> for dataset::OnMismatch {
    fn from(o: OnMismatch) -> Self {
        match o {
            OnMismatch::Refuse => dataset::OnMismatch::Refuse,
            OnMismatch::Rerender => dataset::OnMismatch::Rerender,
        }
    }
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
    /// Render only shard K of N: the scenes whose index in the dataset's list is ≡ K (mod N) (the list
    /// dataset.json recorded, then scenes new in --scenes appended; at first the sorted folder). `slurm`
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

/// Audit lines `emit` could not write, and the first reason: the run goes on (its scenes are on disk), then
/// fails naming them (a full disk under a Slurm `.out` lost every line, exit 0; a held-out battery, round 16).
static AUDIT_LOST: std::sync::Mutex<(usize, Option<String>)> = std::sync::Mutex::new((0, None));

fn emit(line: &SceneLine) {
    // One write per line: a killed task's log holds whole lines only.
    let text = serde_json::to_string(line).unwrap_or_else(|e| format!("{{\"scene\":\"?\",\"status\":\"failed\",\"error\":\"JSON encoding: {e}\"}}"));
    let mut out = std::io::stdout().lock();
    if let Err(e) = out.write_all(format!("{text}\n").as_bytes()).and_then(|_| out.flush()) {
        let mut lost = AUDIT_LOST.lock().unwrap_or_else(|p| p.into_inner());
        lost.0 += 1;
        lost.1.get_or_insert_with(|| e.to_string());
    }
}

/// The error for audit lines that could not be written, if any.
fn audit_lost() -> Result<()> {
    let lost = AUDIT_LOST.lock().unwrap_or_else(|p| p.into_inner());
    match &lost.1 {
        None => Ok(()),
        Some(why) => Err(Error::invalid(format!(
            "standard output: {} of render-dataset's audit lines (JSON Lines, one per scene) could not be written ({why}); the scenes rendered are on disk: `diffcassi dataset-status` lists them",
            lost.0
        ))),
    }
}

fn debug_delay() -> Result<Option<std::time::Duration>> {
    match std::env::var(DEBUG_SCENE_DELAY_ENV) {
        Err(_) => Ok(None),
        Ok(v) => v.trim().parse::<u64>().map(|ms| Some(std::time::Duration::from_millis(ms))).map_err(|_| Error::invalid(format!("{DEBUG_SCENE_DELAY_ENV}=`{v}`: expected milliseconds (a whole number)"))),
    }
}

/// The dataset's progress on the terminal: JSON lines on stdout (one per scene of the shard), messages and
/// bars on stderr.
#[derive(Default)]
struct Terminal {
    rays: BarSlot,
    scenes: BarSlot,
}

impl Terminal {
    /// A scene's line above the scenes bar (shown on a terminal only, like the bar).
    fn println(&self, text: String) {
        if self.scenes.with(|pb| pb.println(&text)).is_none() {
            eprintln!("{text}");
        }
    }
}

impl DatasetProgress for Terminal {
    /// Messages and warnings go to stderr always (the bars step aside).
    fn message(&self, text: &str) {
        if self.scenes.with(|pb| pb.suspend(|| eprintln!("{text}"))).is_none() {
            eprintln!("{text}");
        }
    }
    fn scene(&self, o: &SceneOutcome) {
        emit(&SceneLine { scene: &o.scene, status: o.status.word(), seconds: o.seconds, output: o.output.display().to_string(), error: o.error.clone() });
        match (o.status, &o.error) {
            (dataset::SceneStatus::Skipped, _) => return,
            (_, Some(e)) => self.println(format!("{}: failed: {e}", o.scene)),
            (_, None) => self.println(format!("{}: {:.2} s", o.scene, o.seconds)),
        }
        self.scenes.with(|pb| pb.inc(1));
    }
    fn tracing_started(&self, what: &str, rays: u64) {
        self.rays.show(progress_bar(rays, what));
    }
    fn rays(&self, n: u64) {
        self.rays.with(|pb| pb.inc(n));
    }
    fn tracing_done(&self) {
        self.rays.clear();
    }
    fn scenes_started(&self, n: u64) {
        self.scenes.show(bar(n, "scenes [{elapsed_precise}] {wide_bar} {pos}/{len}, {per_sec}, ETA {eta} {msg}", ""));
    }
    fn scene_started(&self, name: &str) {
        self.scenes.with(|pb| pb.set_message(name.to_string()));
    }
    fn scenes_done(&self) {
        self.scenes.clear();
    }
}

/// `render-dataset`: the library's [`dataset::run`] with the system, tracer and settings the options give.
pub fn render_dataset(a: RenderDatasetArgs) -> Result<()> {
    // The options parsed once, into the library's render settings (their errors name each option).
    let settings = a.common.settings()?;
    let request = DatasetRequest {
        scenes: a.scenes.clone(),
        out: a.out.clone(),
        force: a.force,
        options: DatasetOptions { fit: settings.fit, scene_wavelengths_nm: settings.scene_wavelengths_nm.clone(), cube: settings.cube, mapping: !a.common.no_mapping },
        noise: a.noise.config()?,
        shard: a.shard.unwrap_or(Shard::WHOLE),
        on_mismatch: a.on_mismatch.into(),
        transport_memory_gb: a.transport_memory_gb,
        device: settings.device,
        tolerance_um: a.common.backend.tolerance_um,
        tolerance_predicted_error_um: None,
        tolerance_backend: None,
        scene_delay: debug_delay()?,
    };
    // The output policy before any work (the tracer's calibration may write its cache).
    let mut inputs = super::shared::system_inputs(&a.common.system);
    inputs.extend(a.common.mask.as_deref().map(|p| ("--mask", p)));
    dataset::check_out(&request, &inputs)?;
    let system = load_system(&a.common.system)?;
    let (cfg, mask) = settings.config()?;
    // The tracer as given, or chosen for --tolerance-um — or the choice dataset.json records for it, so that
    // every shard of one array renders with one choice (the library's step; its explanation on stderr).
    let source = super::fidelity::render_source(&a.common.backend)?;
    dataset::run_with_source(&request, &inputs, &system, source, &settings, cfg, mask, &Terminal::default())?;
    audit_lost()
}

pub fn dataset_status(a: DatasetStatusArgs) -> Result<()> {
    if !a.dir.is_dir() {
        return Err(Error::File { path: a.dir.display().to_string(), message: "not a folder (the --out of render-dataset)".into() });
    }
    let found = a.scenes.as_ref().map(|src| dataset::find_scenes(src)).transpose()?;
    // With --scenes: render-dataset's list (the recorded one, then new scenes), each done scene's files compared.
    let st = DatasetStatus::check_scenes(&a.dir, found.as_deref())?;
    // An empty --scenes folder is refused as render-dataset refuses it, whatever dataset.json lists.
    if st.scenes.is_empty() || found.as_ref().is_some_and(|f| f.is_empty()) {
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
            let p: Vec<String> = p.into_iter().chain(s.note.clone()).collect();
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
