//! Dataset mode: find the scenes of a folder, render each into its own sub-folder, skip those already
//! complete, and trace the system's light transport once for all of them (the acquisition is linear in the
//! scene). The transport lives in memory only while it fits a budget; otherwise every scene is traced
//! afresh. Either way each scene's result is bit-identical to rendering it alone with the same seed
//! (same footprints, applied in the same order).
//!
//! This module holds what `render-dataset` and `dataset-status` share, so that both commands agree on
//! what "done" means; [`run`] is the `render-dataset` pipeline itself (the command line and the Python
//! `render_dataset` are its clients):
//!
//! - [`Shard`]: a deterministic partition of the dataset's *full* scene list (scene index mod N = K), computed
//!   before finished scenes are skipped, so a re-run never moves a scene to another shard (Slurm job arrays).
//!   The list is [`SceneOrder`]'s: the one `dataset.json` recorded, then scenes new in the folder, appended.
//! - [`configuration`]: the canonical description of a render request (system, tracer, sizes, bands,
//!   planes, rays, seeds, mask content, options), free of timings. Every scene's `render.json` records it
//!   under `"configuration"`, and `dataset.json` at the root of the output folder records the request of
//!   the last run, beside the scene list and the shared outputs (mask, mapping cube).
//! - [`check_scene`] / [`check_shared`]: done, missing, damaged (unreadable, truncated or altered outputs:
//!   every output's size and CRC-32 is recorded when it is written) or rendered with another configuration.
//! - [`commit_scene`]: a scene's outputs are written into a hidden sibling folder
//!   (`.NAME.partial-HOST-PID-START`) and swapped into place at the end, so a killed task leaves either the old
//!   or the complete new set under the scene's name ([`crate::io::swap_into_place`]).
//!
//! ```
//! use diffcassi::render::dataset::{Shard, DatasetScene};
//! let scenes: Vec<DatasetScene> = (0..10).map(|i| DatasetScene { name: format!("s{i:02}"), path: format!("s{i:02}.npy").into() }).collect();
//! // `--shard 1/4`: scenes 1, 5, 9 of the full sorted list.
//! let shard = Shard::parse("1/4", |_| None).unwrap();
//! let mine: Vec<&str> = shard.select(&scenes).iter().map(|s| s.name.as_str()).collect();
//! assert_eq!(mine, ["s01", "s05", "s09"]);
//! // `--shard slurm` reads the array task's index and count from the environment.
//! let env = |k: &str| match k { "SLURM_ARRAY_TASK_ID" => Some("2".to_string()), "SLURM_ARRAY_TASK_COUNT" => Some("4".to_string()), _ => None };
//! assert_eq!(Shard::parse("slurm", env).unwrap(), Shard::new(2, 4).unwrap());
//! ```
pub mod run;
pub mod tolerance;

pub use tolerance::run_with_source;
pub use run::{check_out, load_fitted, name_hash, requested_configuration, run, DatasetProgress, DatasetRequest, DatasetSummary, OnMismatch, SceneOutcome, SceneStatus, SilentDataset};

use super::engine::Renderer;
use crate::error::{Error, Result};
use crate::io::input::file_crc32;
use crate::scene::Fit;
use serde_json::{json, Map, Value};
use std::fmt;
use std::path::{Path, PathBuf};

/// A scene found in a dataset folder.
#[derive(Clone, Debug, PartialEq)]
pub struct DatasetScene {
    /// Output sub-folder name (file stem or folder name).
    pub name: String,
    pub path: PathBuf,
}

/// Scenes of `dir`, sorted by name: `.exr` files, `.npy` cubes (not their `*_wavelengths_nm.npy` lists), RGB
/// `.png` photographs (uplifted to spectra) and sub-folders holding `.png` files (one per band, CAVE-style).
pub fn find_scenes(dir: &Path) -> Result<Vec<DatasetScene>> {
    let entries = std::fs::read_dir(dir).map_err(|e| Error::File { path: dir.display().to_string(), message: format!("cannot list the scenes folder: {e}") })?;
    let mut out = Vec::new();
    for e in entries.flatten() {
        let p = e.path();
        let stem = p.file_stem().unwrap_or_default().to_string_lossy().into_owned();
        let ext = p.extension().and_then(|x| x.to_str()).map(|x| x.to_ascii_lowercase());
        let is_scene = if p.is_dir() {
            std::fs::read_dir(&p).map(|r| r.flatten().any(|f| f.path().extension().and_then(|x| x.to_str()).map(|x| x.eq_ignore_ascii_case("png")).unwrap_or(false))).unwrap_or(false)
        } else {
            match ext.as_deref() {
                Some("exr") => true,
                Some("npy") => !stem.ends_with("_wavelengths_nm") && !stem.ends_with("_wavelengths"),
                // An RGB photograph, uplifted to spectra (crate::scene::natural) — but not the sRGB preview
                // `<stem>_rgb.png` that `make-scene` writes beside a `<stem>.npy`/`.exr` cube.
                Some("png") => !stem.strip_suffix("_rgb").is_some_and(|c| ["npy", "exr"].iter().any(|x| p.with_file_name(format!("{c}.{x}")).is_file())),
                _ => false,
            }
        };
        if is_scene {
            let name = if p.is_dir() { p.file_name().unwrap_or_default().to_string_lossy().into_owned() } else { stem };
            out.push(DatasetScene { name, path: p });
        }
    }
    out.sort_by(|a, b| a.name.cmp(&b.name).then(a.path.cmp(&b.path)));
    // A scene's folder beside the shared outputs must not take one of their names (a scene `mapping.npy.npy`
    // would replace the shared mapping cube by its folder, `dataset.json.npy` the manifest), nor a temporary's.
    if let Some(s) = out.iter().find(|s| ROOT_OUTPUTS.contains(&s.name.as_str()) || is_leftover_of(&s.name, None)) {
        return Err(Error::File {
            path: s.path.display().to_string(),
            message: format!("the scene's output folder would be named `{}`, a name the dataset's own outputs use ({}): rename the scene", s.name, ROOT_OUTPUTS.join(", ")),
        });
    }
    // A folder name the file system takes: not `.`/`..` (`..npy` made the scene's folder the dataset's
    // parent, saved only by the kernel's EBUSY), and short enough for its temporary `.NAME.partial-TAG.old`
    // (a 251-byte name failed after its render; a held-out battery, round 9). Refused before any work.
    if let Some(s) = out.iter().find(|s| s.name.is_empty() || s.name == "." || s.name == "..") {
        return Err(Error::File { path: s.path.display().to_string(), message: format!("the scene's output folder would be named `{}`, which is not a folder name: rename the scene", s.name) });
    }
    if let Some(s) = out.iter().find(|s| s.name.len() > MAX_SCENE_NAME_BYTES) {
        return Err(Error::File {
            path: s.path.display().to_string(),
            message: format!("the scene's name is {} bytes long: at most {MAX_SCENE_NAME_BYTES} (its temporary folder adds {} bytes to it, and file names end at 255): rename the scene", s.name.len(), 255 - MAX_SCENE_NAME_BYTES),
        });
    }
    for w in out.windows(2) {
        if w[0].name == w[1].name {
            return Err(Error::File { path: dir.display().to_string(), message: format!("two scenes would share the output folder `{}`: {} and {}", w[0].name, w[0].path.display(), w[1].path.display()) });
        }
    }
    Ok(out)
}

/// The longest scene name (bytes): 255 (a file name's limit) less its temporary folder's additions
/// (`.NAME.partial-` + the writer's tag + `.old`, and the stage temporaries of [`crate::io::stale`]).
pub const MAX_SCENE_NAME_BYTES: usize = 128;

// ---------------------------------------------------------------- scene inputs

/// The files scene `scene` is read from: the `.exr`/`.npy`/`.png` file, or a folder's per-band `.png` files
/// (sorted); with `with_lists` (no `--scene-wavelengths`) also the wavelength list the loader reads, a `.npy`'s
/// `<stem>_wavelengths_nm.npy` or a folder's `wavelengths.txt`/`wavelengths_nm.txt`, when present. Nothing
/// else: a stray file beside the bands is not the scene.
pub fn scene_input_files(scene: &DatasetScene, with_lists: bool) -> Vec<PathBuf> {
    let p = &scene.path;
    let ext_is = |f: &Path, ext: &str| f.extension().and_then(|x| x.to_str()).is_some_and(|x| x.eq_ignore_ascii_case(ext));
    if p.is_dir() {
        let list = |f: &Path| with_lists && f.file_name().is_some_and(|n| n == "wavelengths.txt" || n == "wavelengths_nm.txt");
        let mut v: Vec<PathBuf> = std::fs::read_dir(p).map(|r| r.flatten().map(|e| e.path()).filter(|f| f.is_file() && (ext_is(f, "png") || list(f))).collect()).unwrap_or_default();
        v.sort();
        return v;
    }
    let mut v = vec![p.clone()];
    if with_lists && ext_is(p, "npy") {
        let stem = p.file_stem().unwrap_or_default().to_string_lossy().into_owned();
        v.extend(Some(p.with_file_name(format!("{stem}_wavelengths_nm.npy"))).filter(|f| f.is_file()));
    }
    v
}

fn modified_ns(m: &std::fs::Metadata) -> Option<u128> {
    m.modified().ok()?.duration_since(std::time::UNIX_EPOCH).ok().map(|d| d.as_nanos())
}

fn file_sha256(path: &Path) -> std::result::Result<String, String> {
    // Through `io::input`: a FIFO planted as a scene is refused, not waited on.
    crate::io::input::read_input(path, u64::MAX).map(|b| crate::io::sha256::sha256_hex(&b)).map_err(|e| e.to_string())
}

/// `render.json`'s `scene_input`: each input file's name, size, modification time (ns since the epoch) and
/// SHA-256, so that a resume knows when the scene it rendered has changed ([`scene_input_changes`]).
pub fn scene_input_record(scene: &DatasetScene, with_lists: bool) -> Result<Value> {
    let mut files = Vec::new();
    for f in scene_input_files(scene, with_lists) {
        let m = std::fs::metadata(&f).map_err(|e| Error::File { path: f.display().to_string(), message: format!("cannot read: {e}") })?;
        // The reader's message already names the file (it was printed twice).
        let sha = file_sha256(&f).map_err(|e| Error::File { path: f.display().to_string(), message: e.strip_prefix(&format!("{}: ", f.display())).map(str::to_string).unwrap_or(e) })?;
        files.push(json!({"name": f.file_name().unwrap_or_default().to_string_lossy(), "bytes": m.len(), "modified_ns": modified_ns(&m).map(|t| t.to_string()), "sha256": sha}));
    }
    Ok(json!({ "files": files }))
}

/// How scene `scene`'s input differs from what `recorded` ([`scene_input_record`]) says it was: empty when the
/// same files are there with the same content. A file with the recorded size and modification time is taken as
/// unchanged without reading it; otherwise its SHA-256 decides (a file copied or touched with the same bytes is
/// unchanged). A render without the record (older diffcassi) is taken as it is. Each difference starts with
/// `scene input: `.
pub fn scene_input_changes(recorded: Option<&Value>, scene: &DatasetScene, with_lists: bool) -> Vec<String> {
    scene_input_differences(recorded, scene, with_lists).into_iter().map(|d| format!("scene input: {d}")).collect()
}

fn scene_input_differences(recorded: Option<&Value>, scene: &DatasetScene, with_lists: bool) -> Vec<String> {
    let Some(files) = recorded.and_then(|r| r.get("files")).and_then(Value::as_array) else {
        return vec![];
    };
    let now = scene_input_files(scene, with_lists);
    let names = |v: &[PathBuf]| v.iter().map(|f| f.file_name().unwrap_or_default().to_string_lossy().into_owned()).collect::<Vec<_>>();
    let recorded_names: Vec<String> = files.iter().map(|f| f.get("name").and_then(Value::as_str).unwrap_or("").to_string()).collect();
    if names(&now) != recorded_names {
        return vec![format!("the scene's files were {:?} when it was rendered, now {:?}", recorded_names, names(&now))];
    }
    let mut out = Vec::new();
    for (f, r) in now.iter().zip(files) {
        let name = f.file_name().unwrap_or_default().to_string_lossy().into_owned();
        let Ok(m) = std::fs::metadata(f) else {
            out.push(format!("{name}: unreadable"));
            continue;
        };
        let same_stat = r.get("bytes").and_then(Value::as_u64) == Some(m.len()) && r.get("modified_ns").and_then(Value::as_str).map(str::to_string) == modified_ns(&m).map(|t| t.to_string());
        if same_stat {
            continue;
        }
        match file_sha256(f) {
            Ok(sha) if Some(sha.as_str()) == r.get("sha256").and_then(Value::as_str) => {}
            Ok(sha) => out.push(format!("{name} changed since it was rendered (SHA-256 {sha}, rendered from {})", r.get("sha256").and_then(Value::as_str).unwrap_or("?"))),
            Err(e) => out.push(format!("{name}: {e}")),
        }
    }
    out
}

/// `state` ([`check_scene`]'s) of scene `scene` under `out`, a `Done` turned into a `Mismatch` when the scene's
/// files changed since it was rendered ([`check_scene_input`]): what `render-dataset` and `dataset-status
/// --scenes` skip or report.
pub fn with_scene_input(state: SceneState, out: &Path, scene: &DatasetScene) -> SceneState {
    match state {
        SceneState::Done => match check_scene_input(out, scene) {
            changes if changes.is_empty() => SceneState::Done,
            changes => SceneState::Mismatch(changes),
        },
        other => other,
    }
}

/// [`scene_input_changes`] of the scene rendered under `out` (its `render.json`'s `scene_input`; the wavelength
/// lists count when its configuration has no `scene_wavelengths_nm`, as the loader then reads them).
pub fn check_scene_input(out: &Path, scene: &DatasetScene) -> Vec<String> {
    match crate::io::input::read_sidecar_json(&out.join(&scene.name).join("render.json")) {
        Ok(v) => {
            let with_lists = v.get("configuration").and_then(|c| c.get("scene_wavelengths_nm")).is_none_or(Value::is_null);
            scene_input_changes(v.get("scene_input"), scene, with_lists)
        }
        Err(e) => vec![format!("scene input: {e}")],
    }
}

// ---------------------------------------------------------------- shards

/// Shard `index` of `count`: the scenes whose index in the full scene list ([`SceneOrder`]: the recorded list,
/// then new scenes; a fresh folder's sorted list) is ≡ `index` (mod `count`).
/// Round-robin rather than contiguous blocks, so shards get similar mixes when scene sizes drift with
/// their names.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shard {
    pub index: usize,
    pub count: usize,
}

/// Environment variables `--shard slurm` reads (set by Slurm in every task of a job array).
pub const SLURM_TASK_ID: &str = "SLURM_ARRAY_TASK_ID";
pub const SLURM_TASK_COUNT: &str = "SLURM_ARRAY_TASK_COUNT";
/// The array's first task ID (`--array=1-3`: 1); `slurm` without N needs it to be 0.
pub const SLURM_TASK_MIN: &str = "SLURM_ARRAY_TASK_MIN";
/// The array's last task ID and its step (`--array=0-4:2`: 4 and 2); `slurm` without N needs IDs 0…N−1.
pub const SLURM_TASK_MAX: &str = "SLURM_ARRAY_TASK_MAX";
pub const SLURM_TASK_STEP: &str = "SLURM_ARRAY_TASK_STEP";

impl Shard {
    /// Everything in one shard (no `--shard`).
    pub const WHOLE: Shard = Shard { index: 0, count: 1 };

    pub fn new(index: usize, count: usize) -> std::result::Result<Shard, String> {
        if count == 0 {
            return Err("the shard count N must be ≥ 1".into());
        }
        if index >= count {
            return Err(format!("shard index {index} is out of range for {count} shards (K must be in 0..{count}, i.e. 0 ≤ K < N)"));
        }
        Ok(Shard { index, count })
    }

    /// `K/N`, `slurm` (K and N from `SLURM_ARRAY_TASK_ID` / `SLURM_ARRAY_TASK_COUNT`) or `slurm/N` (K from
    /// Slurm, N explicit: a resubmitted subset of an array, e.g. `--array=2`, reports a count of 1).
    /// `env` looks up environment variables (`|k| std::env::var(k).ok()` in the command line).
    pub fn parse(text: &str, env: impl Fn(&str) -> Option<String>) -> std::result::Result<Shard, String> {
        let usage = "use K/N (0 ≤ K < N), slurm, or slurm/N";
        let whole = |s: &str, what: &str, min: usize| -> std::result::Result<usize, String> { s.trim().parse::<usize>().map_err(|_| format!("{what} `{s}` is not a whole number ≥ {min}; {usage}")) };
        let t = text.trim();
        let (k_text, n_text) = t.split_once('/').map(|(k, n)| (k, Some(n))).unwrap_or((t, None));
        if k_text.eq_ignore_ascii_case("slurm") {
            // A variable set but empty is named as such, not as unset, and each message names the variable whose
            // value is bad (`SLURM_ARRAY_TASK_COUNT=0` was reported as `SLURM_ARRAY_TASK_ID=1: the shard count N
            // must be ≥ 1`; an empty SLURM_ARRAY_TASK_MAX was accepted silently: a held-out battery, round 16).
            let var = |name: &str| -> std::result::Result<usize, String> {
                match env(name) {
                    None => Err(format!("`{text}` needs the Slurm variable {name}, which is not set (not inside a Slurm job array?); outside Slurm {usage}")),
                    Some(v) if v.trim().is_empty() => Err(format!("{name} is set but empty: `{text}` needs it to hold a whole number (Slurm sets it in every task of a job array; is the job script overriding it?)")),
                    Some(v) => v.trim().parse().map_err(|_| format!("{name}=`{v}` is not a whole number")),
                }
            };
            // The array's shape (first ID, step, last ID): unset is fine (older Slurm), set must be a number.
            let shape = |name: &str| -> std::result::Result<Option<usize>, String> { if env(name).is_none() { Ok(None) } else { var(name).map(Some) } };
            let k = var(SLURM_TASK_ID)?;
            // An array numbered from 1 (`--array=1-3`) gives IDs 1…N: task N failed, the others rendered shards
            // 1…N−1 and shard 0 never (a held-out battery). With N from Slurm the array must start at 0.
            let mut max = None;
            if n_text.is_none() {
                if let Some(min) = shape(SLURM_TASK_MIN)?.filter(|&m| m != 0) {
                    return Err(format!("{SLURM_TASK_MIN}={min}: `{text}` takes the shard count from Slurm, so the array must be numbered from 0 (--array=0-(N-1)); a subset of an array must give N: --shard slurm/N"));
                }
                // An array with a step (`--array=0-4:2`: IDs 0, 2, 4, count 3) rendered shards 0/3 and 2/3 and
                // failed task 4, shard 1 never rendered (a held-out battery, round 9): refused in every task.
                if let Some(step) = shape(SLURM_TASK_STEP)?.filter(|&s| s != 1) {
                    return Err(format!("{SLURM_TASK_STEP}={step}: `{text}` takes the shard count from Slurm, so the array's IDs must be 0, 1, …, N−1 (--array=0-(N-1), no step)"));
                }
                max = shape(SLURM_TASK_MAX)?;
            }
            let hint = if n_text.is_none() { " (submit the array as --array=0-(N-1); a resubmitted subset of an array must give N: --shard slurm/N)" } else { " (submit the array as --array=0-(N-1))" };
            // Where N came from, as messages name it.
            let (n, n_source) = match n_text {
                Some(n) => (whole(n, "shard count N", 1)?, format!("`{text}`")),
                None => {
                    let n = var(SLURM_TASK_COUNT)?;
                    (n, format!("{SLURM_TASK_COUNT}={n}"))
                }
            };
            if n == 0 {
                return Err(format!("{n_source}: the shard count N must be ≥ 1{hint}"));
            }
            if let Some(max) = max.filter(|&m| m != n - 1) {
                return Err(format!("{SLURM_TASK_MAX}={max} with {SLURM_TASK_COUNT}={n}: `{text}` takes the shard count from Slurm, so the array's IDs must be 0, 1, …, N−1 (--array=0-(N-1)); a subset of an array must give N: --shard slurm/N"));
            }
            return Shard::new(k, n).map_err(|e| format!("{SLURM_TASK_ID}={k} with {n_source}: {e}{hint}"));
        }
        let Some(n_text) = n_text else { return Err(format!("`{text}`: {usage}")) };
        Shard::new(whole(k_text, "shard index K", 0)?, whole(n_text, "shard count N", 1)?)
    }

    /// Whether the scene at `scene_index` of the full list ([`SceneOrder::names`]) belongs to this shard.
    pub fn contains(&self, scene_index: usize) -> bool {
        scene_index % self.count == self.index
    }

    /// This shard's scenes, in list order. Depends on the list only, never on which scenes are done.
    pub fn select<'a>(&self, scenes: &'a [DatasetScene]) -> Vec<&'a DatasetScene> {
        scenes.iter().enumerate().filter(|(i, _)| self.contains(*i)).map(|(_, s)| s).collect()
    }
}

impl fmt::Display for Shard {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

/// The dataset's scene list in partition order: the list `dataset.json` recorded (in its order), then the
/// scenes of the folder it does not hold, sorted by name. Shards index this list ([`Shard::contains`]), and
/// round-robin keeps an index's shard when the list only grows at its end, so a scene added to `--scenes` in
/// the middle of an array never moves a recorded scene to another shard (round 20: `a04.npy`, sorting first,
/// shifted every index; shard 1/2 then held shard 0's scenes, skipped them as done, exited 0, and its own
/// were never rendered). Without a recorded list it is the folder's sorted list.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SceneOrder {
    /// Every scene, recorded ones first: what shards index, and what the next `dataset.json` records.
    pub names: Vec<String>,
    /// Scenes of the folder that the recorded list does not hold, appended in this order.
    pub added: Vec<String>,
    /// Recorded scenes no longer in the folder: they keep their places (so no other scene moves), but no
    /// task can render them.
    pub gone: Vec<String>,
}

impl SceneOrder {
    /// The order for the recorded list `recorded` (`None`: no `dataset.json` yet) and the folder's scenes
    /// `found` ([`find_scenes`], sorted).
    pub fn new(recorded: Option<&[String]>, found: &[DatasetScene]) -> SceneOrder {
        let present: std::collections::HashSet<&str> = found.iter().map(|s| s.name.as_str()).collect();
        let mut seen = std::collections::HashSet::new();
        let mut names: Vec<String> = recorded.unwrap_or(&[]).iter().filter(|n| seen.insert(n.as_str())).cloned().collect();
        let gone = names.iter().filter(|n| !present.contains(n.as_str())).cloned().collect();
        let added: Vec<String> = found.iter().filter(|s| !seen.contains(s.name.as_str())).map(|s| s.name.clone()).collect();
        names.extend(added.iter().cloned());
        SceneOrder { names, added: if recorded.is_some() { added } else { vec![] }, gone }
    }

    /// The order for `out`'s recorded list (an unreadable `dataset.json` counts as none) and `found`.
    pub fn of(out: &Path, found: &[DatasetScene]) -> SceneOrder {
        let recorded = read_manifest(out).ok().map(|(_, n)| n);
        SceneOrder::new(recorded.as_deref(), found)
    }

    /// Whether `name` is a recorded scene no longer in the folder.
    pub fn is_gone(&self, name: &str) -> bool {
        self.gone.iter().any(|g| g == name)
    }

    /// Shard `shard`'s scene names, in list order. Depends on the list only, never on which scenes are done.
    pub fn select(&self, shard: Shard) -> Vec<&str> {
        self.names.iter().enumerate().filter(|(i, _)| shard.contains(*i)).map(|(_, n)| n.as_str()).collect()
    }

    /// What changed against the recorded list, for the user (`None` when nothing did): new scenes are
    /// appended, recorded ones gone from `dir` keep their places.
    pub fn changes_message(&self, dir: &Path) -> Option<String> {
        let list = |v: &[String]| if v.len() > 8 { format!("{}, … ({} in all)", v[..8].join(", "), v.len()) } else { v.join(", ") };
        let mut parts = Vec::new();
        if !self.added.is_empty() {
            let first = self.names.len() - self.added.len();
            parts.push(format!(
                "{} scene(s) in {} are new since {MANIFEST} recorded its list ({}): appended as {} of the list, so no recorded scene moves to another shard",
                self.added.len(),
                dir.display(),
                list(&self.added),
                if self.added.len() == 1 { format!("scene {first}") } else { format!("scenes {first}–{}", self.names.len() - 1) }
            ));
        }
        if !self.gone.is_empty() {
            parts.push(format!(
                "{} scene(s) of {MANIFEST}'s list are no longer in {} ({}): they keep their places in the list (so no other scene moves); one already rendered stays done, one not rendered cannot be (restore its file)",
                self.gone.len(),
                dir.display(),
                list(&self.gone)
            ));
        }
        (!parts.is_empty()).then(|| parts.join("; "))
    }
}

// ---------------------------------------------------------------- configuration

/// Options of a dataset render that are not part of the [`Renderer`] but change its outputs.
#[derive(Clone, Debug)]
pub struct DatasetOptions {
    /// How scenes are brought to the render field.
    pub fit: Fit,
    /// Wavelengths (nm) given for the scene files' bands, overriding the files (`--scene-wavelengths`).
    pub scene_wavelengths_nm: Option<Vec<f64>>,
    /// Whether each scene folder holds `cube.exr`.
    pub cube: bool,
    /// Whether the root holds the mapping cube (`mapping.npy`, `mapping_valid.npy`, `mapping_wavelengths_nm.npy`).
    pub mapping: bool,
}

/// Version of the layout of [`configuration`]; a change makes older outputs mismatch (and be re-rendered).
pub const CONFIGURATION_FORMAT: u32 = 1;

/// A spec's JSON as a dataset's identity: without its `[mechanics]` section (a render traces no mechanics, only
/// `render --ghosts K --mechanics` does, so their files are no part of what a dataset rendered; round 11), and
/// with each glass catalogue file named by its content — `NAME (N bytes, crc32 XXXXXXXX)` — not by the absolute
/// path a spec's relative entry becomes on load (round 12: a project folder moved elsewhere saw "another
/// configuration"). `builtin:` entries and files that cannot be read stay as written (then their paths
/// compare). Applied to the recorded configuration too, so a dataset recorded with paths resumes while its
/// catalogues are still where they were.
fn spec_identity(mut spec: Value) -> Value {
    if let Some(o) = spec.as_object_mut() {
        o.remove("mechanics");
        if let Some(Value::Array(catalogs)) = o.get_mut("glass_catalogs") {
            for entry in catalogs.iter_mut() {
                let Some(path) = entry.as_str() else { continue };
                if let Some(Ok(identity)) = crate::materials::GlassCatalog::entry_identity(path) {
                    *entry = json!(identity);
                }
            }
        }
    }
    spec
}

/// The canonical configuration of a dataset render: everything that determines the outputs' bytes and
/// nothing else (no timings, thread counts, paths of the output folder or diffcassi version; not the spec's
/// mechanics, which a render does not trace). Two renders with equal configurations and scenes give
/// identical files. The mask is identified by its content (CRC-32 of its f32 transmissions), not by the file
/// it came from.
pub fn configuration(renderer: &Renderer, options: &DatasetOptions) -> Value {
    let c = &renderer.config;
    let mask_bytes: Vec<u8> = renderer.mask.values.iter().flat_map(|v| v.to_le_bytes()).collect();
    let mut v = json!({
        "format": CONFIGURATION_FORMAT,
        "system": renderer.system.name(),
        "system_spec": spec_identity(serde_json::to_value(&renderer.system.spec).unwrap_or(Value::Null)),
        "tracer": renderer.tracer.name(),
        "scene_height": c.scene_height,
        "scene_width": c.scene_width,
        "scene_pitch_mm": if c.scene_fov_deg.is_some() { Value::Null } else { json!(c.scene_pitch_mm) },
        "detector_pitch_mm": c.detector_pitch_mm,
        "detector_extra_px": c.detector_extra_px,
        "fit": options.fit,
        "scene_wavelengths_nm": options.scene_wavelengths_nm,
        "bands_nm": c.spectral.bands_nm,
        "planes_nm": c.spectral.planes_nm,
        "plane_weight": c.spectral.plane_weight,
        "rays_per_pixel": c.rays_per_pixel,
        "sampling": c.sampling,
        "seed": c.seed,
        "airy": c.airy,
        "mask": {"height": renderer.mask.height, "width": renderer.mask.width, "description": renderer.mask.description, "values_f32le_crc32": crc32_hex(&mask_bytes)},
        "cube": options.cube,
        "mapping": options.mapping,
    });
    // f32 transport is another configuration; f64 datasets keep their recorded configuration unchanged.
    if c.precision != crate::tracer::Precision::F64 {
        v["precision"] = json!(c.precision);
    }
    // An object at infinity: the scene's angular extent replaces the pitch in mm.
    if let Some(f) = c.scene_fov_deg {
        v["scene_fov_deg"] = json!(f);
    }
    v
}

/// Human-readable differences between a recorded and a requested configuration (empty when equal): one
/// line per leaf that really differs, named by its path (`bands_nm[3]`, `system_spec.surfaces[2].radius`,
/// `airy`), with both values. Numbers compare by value (`1` equals `1.0`; the records are written and read
/// back bit-exactly, serde_json's `float_roundtrip`), so a mismatch is never an artefact of the JSON text.
pub fn configuration_differences(recorded: &Value, requested: &Value) -> Vec<String> {
    // A dataset recorded before the mechanics were left out, or with catalogue paths, compares as today's; the
    // requested side too, for callers that record the spec as loaded (the study's cells).
    let identity = |v: &Value| {
        let mut v = v.clone();
        if let Some(spec) = v.get_mut("system_spec") {
            *spec = spec_identity(spec.take());
        }
        // An f64 configuration records no precision (those of datasets from before f32 stay as they were):
        // compared as "f64", so an f32 dataset resumed in f64 reads `recorded "f32" ≠ requested "f64"`, not
        // `≠ requested absent`.
        if let Some(o) = v.as_object_mut() {
            o.entry("precision").or_insert_with(|| json!(crate::tracer::Precision::F64));
        }
        v
    };
    let (recorded, requested) = (&identity(recorded), &identity(requested));
    if !(recorded.is_object() && requested.is_object()) {
        return if same_json(recorded, requested) { vec![] } else { vec!["the configuration is not a JSON object".into()] };
    }
    let mut out = Vec::new();
    diff_json("", Some(recorded), Some(requested), &mut out);
    const MAX_LINES: usize = 12;
    if out.len() > MAX_LINES {
        let more = out.len() - MAX_LINES;
        out.truncate(MAX_LINES);
        out.push(format!("… and {more} more"));
    }
    out
}

/// JSON equality with numbers compared by value (an integer and the float of the same value are equal).
fn same_json(a: &Value, b: &Value) -> bool {
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => match (x.as_i128(), y.as_i128()) {
            (Some(i), Some(j)) => i == j,
            _ => x.as_f64() == y.as_f64(),
        },
        (Value::Array(x), Value::Array(y)) => x.len() == y.len() && x.iter().zip(y).all(|(a, b)| same_json(a, b)),
        (Value::Object(x), Value::Object(y)) => x.len() == y.len() && x.iter().all(|(k, v)| y.get(k).is_some_and(|w| same_json(v, w))),
        _ => a == b,
    }
}

fn diff_json(path: &str, r: Option<&Value>, q: Option<&Value>, out: &mut Vec<String>) {
    let short = |v: Option<&Value>| -> String {
        match v {
            None => "absent".into(),
            Some(v) => {
                let s = v.to_string();
                if s.chars().count() > 60 {
                    format!("{}…", s.chars().take(57).collect::<String>())
                } else {
                    s
                }
            }
        }
    };
    match (r, q) {
        (Some(Value::Object(a)), Some(Value::Object(b))) => {
            let mut keys: Vec<&String> = a.keys().chain(b.keys()).collect();
            keys.sort();
            keys.dedup();
            for k in keys {
                let p = if path.is_empty() { k.clone() } else { format!("{path}.{k}") };
                diff_json(&p, a.get(k), b.get(k), out);
            }
        }
        (Some(Value::Array(a)), Some(Value::Array(b))) if a.len() == b.len() => {
            for (i, (x, y)) in a.iter().zip(b).enumerate() {
                diff_json(&format!("{path}[{i}]"), Some(x), Some(y), out);
            }
        }
        (Some(Value::Array(a)), Some(Value::Array(b))) => out.push(format!("{path}: recorded {} elements ≠ requested {} ({} ≠ {})", a.len(), b.len(), short(r), short(q))),
        (Some(a), Some(b)) if same_json(a, b) => {}
        _ => out.push(format!("{path}: recorded {} ≠ requested {}", short(r), short(q))),
    }
}

// ---------------------------------------------------------------- output records

/// CRC-32 (IEEE) of `bytes` as 8 hex digits.
pub fn crc32_hex(bytes: &[u8]) -> String {
    format!("{:08x}", crc32fast::hash(bytes))
}


/// `{"NAME": {"bytes": N, "crc32": "…"}}` for the files `names` of `dir` (recorded when they are written,
/// checked by [`verify_records`]).
pub fn file_records(dir: &Path, names: &[&str]) -> Result<Value> {
    let mut m = Map::new();
    for name in names {
        let p = dir.join(name);
        let (bytes, crc) = file_crc32(&p).map_err(|e| Error::File { path: p.display().to_string(), message: format!("cannot read back: {e}") })?;
        m.insert(name.to_string(), json!({"bytes": bytes, "crc32": crc}));
    }
    Ok(Value::Object(m))
}

/// Problems with the files `records` describes: missing, unreadable, truncated (size) or altered (CRC-32).
pub fn verify_records(dir: &Path, records: &Value) -> Vec<String> {
    let Some(m) = records.as_object() else { return vec!["the output records are not a JSON object".into()] };
    let mut problems = Vec::new();
    for (name, rec) in m {
        let (want_bytes, want_crc) = (rec["bytes"].as_u64(), rec["crc32"].as_str());
        let (Some(want_bytes), Some(want_crc)) = (want_bytes, want_crc) else {
            problems.push(format!("{name}: malformed record {rec}"));
            continue;
        };
        match file_crc32(&dir.join(name)) {
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => problems.push(format!("{name}: missing")),
            Err(e) => problems.push(format!("{name}: unreadable ({e})")),
            Ok((n, _)) if n != want_bytes => problems.push(format!("{name}: {n} bytes, {want_bytes} written (truncated or replaced)")),
            Ok((_, crc)) if crc != want_crc => problems.push(format!("{name}: CRC-32 {crc}, {want_crc} written (altered)")),
            Ok(_) => {}
        }
    }
    problems
}

// ---------------------------------------------------------------- states

/// What a scene folder (or the shared outputs) holds, compared with a requested configuration.
#[derive(Clone, Debug, PartialEq)]
pub enum SceneState {
    /// Complete, intact, rendered with the requested configuration.
    Done,
    /// Not rendered (no folder).
    Missing,
    /// Present but unreadable, truncated, altered, or incomplete.
    Damaged(Vec<String>),
    /// Complete and intact but rendered with another configuration (the differences).
    Mismatch(Vec<String>),
}

impl SceneState {
    /// `done`, `missing` or `corrupt` (damaged or mismatching: `dataset-status`'s words).
    pub fn word(&self) -> &'static str {
        match self {
            SceneState::Done => "done",
            SceneState::Missing => "missing",
            SceneState::Damaged(_) | SceneState::Mismatch(_) => "corrupt",
        }
    }
    pub fn problems(&self) -> Vec<String> {
        match self {
            SceneState::Done | SceneState::Missing => vec![],
            SceneState::Damaged(p) => p.clone(),
            SceneState::Mismatch(d) => d.iter().map(|x| if x.starts_with("scene input: ") { x.clone() } else { format!("configuration differs: {x}") }).collect(),
        }
    }
}


/// Compare a sidecar (`render.json` or `dataset.json`) holding `"configuration"` and an output-records key
/// with the requested configuration (`None`: only check that the outputs are intact).
fn check_sidecar(dir: &Path, sidecar: &str, records_key: &str, requested: Option<&Value>) -> SceneState {
    let path = dir.join(sidecar);
    if !path.exists() {
        return SceneState::Damaged(vec![format!("{sidecar}: missing (incomplete output)")]);
    }
    let v = match crate::io::input::read_sidecar_json(&path) {
        Ok(v) => v,
        Err(p) => return SceneState::Damaged(vec![p]),
    };
    let (Some(recorded), Some(records)) = (v.get("configuration"), v.get(records_key)) else {
        return SceneState::Mismatch(vec![format!("{sidecar} records no configuration or output checksums (written by an older diffcassi or by `render`)")]);
    };
    let mut damaged = verify_records(dir, records);
    // A record whose top-level fields contradict its own configuration was edited: not done (round 16; the
    // manifest holds none of the fields compared at its top level).
    damaged.extend(crate::render::output::record_contradictions(&v).into_iter().map(|c| format!("{sidecar}: {c}")));
    if !damaged.is_empty() {
        return SceneState::Damaged(damaged);
    }
    match requested {
        Some(q) => {
            let d = configuration_differences(recorded, q);
            if d.is_empty() {
                SceneState::Done
            } else {
                SceneState::Mismatch(d)
            }
        }
        None => SceneState::Done,
    }
}

/// The state of scene `name` under the output folder `out`.
pub fn check_scene(out: &Path, name: &str, requested: Option<&Value>) -> SceneState {
    let dir = out.join(name);
    match std::fs::symlink_metadata(&dir) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => SceneState::Missing,
        Err(e) => SceneState::Damaged(vec![format!("{}: unreadable ({e})", dir.display())]),
        Ok(m) if !m.is_dir() => SceneState::Damaged(vec![format!("{}: not a folder", dir.display())]),
        Ok(_) => check_sidecar(&dir, "render.json", "outputs", requested),
    }
}

/// Name of the root manifest: the request, the scene list and the shared outputs.
pub const MANIFEST: &str = "dataset.json";

/// The state of the shared outputs (`dataset.json`, `mask.png`, mapping cube) under `out`.
pub fn check_shared(out: &Path, requested: Option<&Value>) -> SceneState {
    if !out.join(MANIFEST).exists() {
        return SceneState::Missing;
    }
    check_sidecar(out, MANIFEST, "shared_outputs", requested)
}

/// Every name the dataset writes at its root: the manifest, the mask, the mapping cube's three files.
pub const ROOT_OUTPUTS: [&str; 5] = [MANIFEST, "mask.png", "mapping.npy", "mapping_valid.npy", "mapping_wavelengths_nm.npy"];

/// The shared outputs' file names for a configuration (`"mapping": true` adds the mapping cube).
pub fn shared_output_names(configuration: &Value) -> Vec<&'static str> {
    let mut v = vec![ROOT_OUTPUTS[1]];
    if configuration["mapping"].as_bool().unwrap_or(false) {
        v.extend(&ROOT_OUTPUTS[2..]);
    }
    v
}

/// The root manifest written after the shared outputs: identical bytes from every shard of one request.
pub fn manifest(configuration: &Value, scene_names: &[String], shared_records: Value) -> Value {
    json!({
        "format": "diffcassi dataset",
        "configuration": configuration,
        "scenes": scene_names,
        "shared_outputs": shared_records,
    })
}

/// The configuration and scene list recorded in `out/dataset.json`.
pub fn read_manifest(out: &Path) -> Result<(Value, Vec<String>)> {
    let path = out.join(MANIFEST);
    let v = crate::io::input::read_sidecar_json(&path).map_err(|m| Error::File { path: path.display().to_string(), message: m })?;
    let names = v["scenes"].as_array().map(|a| a.iter().filter_map(|s| s.as_str().map(String::from)).collect::<Vec<_>>());
    match (v.get("configuration"), names) {
        (Some(c), Some(n)) => Ok((c.clone(), n)),
        _ => Err(Error::File { path: path.display().to_string(), message: "no `configuration` or `scenes`: not written by render-dataset".into() }),
    }
}

// ---------------------------------------------------------------- all-or-nothing scene folders

/// A fresh, empty temporary folder for scene `name` beside its final folder:
/// `out/.NAME.partial-HOST-PID-START` (the writer's tag, [`crate::io::stale`]).
pub fn partial_dir(out: &Path, name: &str) -> Result<PathBuf> {
    let p = out.join(format!(".{name}.partial-{}", crate::io::stale::writer_tag()));
    if p.exists() {
        std::fs::remove_dir_all(&p).map_err(|e| Error::File { path: p.display().to_string(), message: format!("cannot remove an old temporary folder: {e}") })?;
    }
    std::fs::create_dir_all(&p).map_err(|e| Error::File { path: p.display().to_string(), message: format!("cannot create: {e}") })?;
    Ok(p)
}

/// The writer's tag of a scene's temporary (`.NAME.partial-TAG[.old]`, `.NAME.old-TAG`, or a
/// [`crate::io::stale`] temporary `.NAME.stage-…`): `Some(None)` when it is one but the tag cannot be read.
fn leftover_writer(file_name: &str, scene: &str) -> Option<Option<crate::io::stale::Writer>> {
    if let Some(w) = crate::io::stale::temporary_of(file_name, scene) {
        return Some(Some(w));
    }
    let rest = file_name.strip_prefix('.')?.strip_prefix(scene)?;
    let tag = rest.strip_prefix(".partial-").or_else(|| rest.strip_prefix(".old-"))?;
    Some(crate::io::stale::parse_tag(tag.strip_suffix(".old").unwrap_or(tag)))
}

fn is_leftover_of(file_name: &str, scene: Option<&str>) -> bool {
    let Some(rest) = file_name.strip_prefix('.') else { return false };
    match scene {
        Some(s) => leftover_writer(file_name, s).is_some(),
        None => rest.contains(".partial-") || rest.contains(".old-") || rest.contains(".stage-") || rest.ends_with(".tmp"),
    }
}

/// Temporary folders and files under `out` (and one level below): what a killed or running task leaves
/// (`.NAME.partial-*`, `.NAME.old-*`, `.FILE.stage-*`, an earlier version's `.FILE.PID.N.tmp`).
pub fn leftovers(out: &Path) -> Vec<PathBuf> {
    let mut v = Vec::new();
    let list = |dir: &Path, v: &mut Vec<PathBuf>, deeper: bool| {
        if let Ok(rd) = std::fs::read_dir(dir) {
            for e in rd.flatten() {
                let name = e.file_name().to_string_lossy().into_owned();
                if is_leftover_of(&name, None) {
                    v.push(e.path());
                } else if deeper && e.path().is_dir() {
                    if let Ok(rd2) = std::fs::read_dir(e.path()) {
                        v.extend(rd2.flatten().filter(|f| is_leftover_of(&f.file_name().to_string_lossy(), None)).map(|f| f.path()));
                    }
                }
            }
        }
    };
    list(out, &mut v, true);
    v.sort();
    v
}

/// Remove what earlier (killed) tasks left for scene `name`. Only the shard owning the scene may call it: it
/// removes the scene's temporaries of any host (a task of another node is a killed or resubmitted one of
/// this shard) except those of a process still running on this host (a concurrent run, left alone).
pub fn remove_leftovers(out: &Path, name: &str) -> Result<usize> {
    let mut n = 0;
    let Ok(rd) = std::fs::read_dir(out) else { return Ok(0) };
    for e in rd.flatten() {
        let Some(writer) = leftover_writer(&e.file_name().to_string_lossy(), name) else { continue };
        let live_here = writer.is_some_and(|w| w.host.as_deref().map_or(true, |h| h == crate::io::stale::host_name()) && !w.is_gone());
        if live_here {
            continue;
        }
        let p = e.path();
        let r = if p.is_dir() { std::fs::remove_dir_all(&p) } else { std::fs::remove_file(&p) };
        r.map_err(|e| Error::File { path: p.display().to_string(), message: format!("cannot remove a leftover temporary: {e}") })?;
        n += 1;
    }
    Ok(n)
}

/// Move the complete temporary folder `partial` to `out/name`, replacing an existing folder (another
/// configuration, or damaged) whole with [`crate::io::swap_into_place`]: `out/name` holds the old set or the
/// new one at every instant (renameat2 exchange; see there for the fallback's window).
pub fn commit_scene(partial: &Path, out: &Path, name: &str) -> Result<()> {
    Ok(crate::io::swap_into_place(partial, &out.join(name))?)
}

// ---------------------------------------------------------------- dataset status

/// One scene's state in [`DatasetStatus`].
#[derive(Clone, Debug, PartialEq)]
pub struct SceneReport {
    pub scene: String,
    pub state: SceneState,
    /// Said beside the state: a recorded scene no longer in the `--scenes` folder.
    pub note: Option<String>,
}

/// What `dataset-status` reports about an output folder.
#[derive(Clone, Debug)]
pub struct DatasetStatus {
    /// The shared outputs and `dataset.json` (missing: nothing was rendered there yet, or not by render-dataset).
    pub shared: SceneState,
    pub scenes: Vec<SceneReport>,
    /// Temporary folders/files of running or killed tasks (not counted as problems: a running task has them).
    pub leftovers: Vec<PathBuf>,
}

impl DatasetStatus {
    /// Check `out` against the configuration in `out/dataset.json` (or `requested` when given), for the
    /// scenes `scene_names` (default: the list in `dataset.json`).
    pub fn check(out: &Path, scene_names: Option<Vec<String>>, requested: Option<Value>) -> Result<DatasetStatus> {
        let manifest = read_manifest(out);
        let (requested, names) = match (manifest, scene_names) {
            (Ok((c, n)), given) => (Some(requested.unwrap_or(c)), given.unwrap_or(n)),
            (Err(_), Some(given)) => (requested, given),
            (Err(e), None) => return Err(Error::File { path: out.display().to_string(), message: format!("no scene list: {e} (give --scenes SRC)") }),
        };
        let shared = check_shared(out, requested.as_ref());
        let scenes = names.into_iter().map(|s| SceneReport { state: check_scene(out, &s, requested.as_ref()), scene: s, note: None }).collect();
        Ok(DatasetStatus { shared, scenes, leftovers: leftovers(out) })
    }

    /// `dataset-status`: check `out` for the scenes `render-dataset` would render from `found` (a `--scenes`
    /// folder's, [`find_scenes`]), in its partition order ([`SceneOrder`]: the recorded list, then the folder's
    /// new scenes), or for the recorded list alone (`None`). A scene done from files that have changed since is
    /// a mismatch; a recorded scene no longer in the folder is reported by its output folder, with a note.
    pub fn check_scenes(out: &Path, found: Option<&[DatasetScene]>) -> Result<DatasetStatus> {
        let Some(found) = found else { return DatasetStatus::check(out, None, None) };
        let order = SceneOrder::of(out, found);
        let mut st = DatasetStatus::check(out, Some(order.names.clone()), None)?;
        for s in st.scenes.iter_mut() {
            match found.iter().find(|f| f.name == s.scene) {
                Some(f) => s.state = with_scene_input(s.state.clone(), out, f),
                None => s.note = Some(format!("listed in {MANIFEST} but no longer in the --scenes folder (it keeps its place in the list; it cannot be rendered again)")),
            }
        }
        Ok(st)
    }

    /// (done, missing, corrupt) scene counts.
    pub fn counts(&self) -> (usize, usize, usize) {
        let c = |w: &str| self.scenes.iter().filter(|s| s.state.word() == w).count();
        (c("done"), c("missing"), c("corrupt"))
    }

    /// Everything done and the shared outputs intact.
    pub fn is_clean(&self) -> bool {
        self.shared == SceneState::Done && self.scenes.iter().all(|s| s.state == SceneState::Done)
    }

    pub fn to_json(&self) -> Value {
        let (done, missing, corrupt) = self.counts();
        json!({
            "clean": self.is_clean(),
            "counts": {"scenes": self.scenes.len(), "done": done, "missing": missing, "corrupt": corrupt},
            "shared": {"status": self.shared.word(), "problems": self.shared.problems()},
            "scenes": self.scenes.iter().map(|s| {
                let mut v = json!({"scene": s.scene, "status": s.state.word(), "problems": s.state.problems()});
                if let Some(n) = &s.note {
                    v["note"] = json!(n);
                }
                v
            }).collect::<Vec<_>>(),
            "leftovers": self.leftovers.iter().map(|p| p.display().to_string()).collect::<Vec<_>>(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeSet;

    fn scenes(n: usize) -> Vec<DatasetScene> {
        (0..n).map(|i| DatasetScene { name: format!("scene{i:03}"), path: PathBuf::from(format!("/x/scene{i:03}.npy")) }).collect()
    }

    #[test]
    fn shards_are_disjoint_and_complete() {
        for n_scenes in [0, 1, 5, 12, 37] {
            let all = scenes(n_scenes);
            for count in 1..=7 {
                let mut seen = BTreeSet::new();
                let mut total = 0;
                for k in 0..count {
                    let mine = Shard::new(k, count).unwrap().select(&all);
                    total += mine.len();
                    for s in mine {
                        assert!(seen.insert(s.name.clone()), "{} in two shards ({count} shards)", s.name);
                    }
                    // Balanced: shard sizes differ by at most one.
                    let len = Shard::new(k, count).unwrap().select(&all).len();
                    assert!(len == n_scenes / count || len == n_scenes / count + 1, "{len}");
                }
                assert_eq!(total, n_scenes);
                assert_eq!(seen.len(), n_scenes);
            }
        }
    }

    /// The partition depends on the full list only: skipping finished scenes (done before selection or
    /// after) never moves a scene to another shard, and a shard's members are fixed by their list index.
    #[test]
    fn shards_are_stable_under_skipping() {
        let all = scenes(12);
        let done: BTreeSet<&str> = ["scene000", "scene003", "scene004", "scene009", "scene011"].into_iter().collect();
        for k in 0..4 {
            let shard = Shard::new(k, 4).unwrap();
            let before: Vec<&str> = shard.select(&all).iter().map(|s| s.name.as_str()).collect();
            let expected: Vec<String> = (0..12).filter(|i| i % 4 == k).map(|i| format!("scene{i:03}")).collect();
            assert_eq!(before, expected);
            // A re-run selects from the same full list, then skips the done ones.
            let todo: Vec<&str> = shard.select(&all).iter().map(|s| s.name.as_str()).filter(|n| !done.contains(n)).collect();
            assert!(todo.iter().all(|n| before.contains(n)));
            for n in &todo {
                let other = (0..4).filter(|&j| j != k).any(|j| Shard::new(j, 4).unwrap().select(&all).iter().any(|s| s.name == *n));
                assert!(!other, "{n} in another shard");
            }
        }
        // Adding a done flag to every scene changes nothing in the union of the to-do lists but the done ones.
        let union: BTreeSet<String> = (0..4).flat_map(|k| Shard::new(k, 4).unwrap().select(&all).into_iter().map(|s| s.name.clone())).filter(|n| !done.contains(n.as_str())).collect();
        assert_eq!(union.len(), 12 - done.len());
    }

    #[test]
    fn shard_parsing() {
        let none = |_: &str| None;
        assert_eq!(Shard::parse("0/1", none), Ok(Shard::WHOLE));
        assert_eq!(Shard::parse(" 3/4 ", none), Ok(Shard { index: 3, count: 4 }));
        for bad in ["4/4", "0/0", "a/b", "1", "-1/4", "1/-4", "", "/", "1/2/3", "slurm"] {
            let e = Shard::parse(bad, none).unwrap_err();
            assert!(!e.is_empty(), "{bad}");
        }
        assert!(Shard::parse("4/4", none).unwrap_err().contains("out of range"));
        assert!(Shard::parse("0/0", none).unwrap_err().contains("≥ 1"));
        assert!(Shard::parse("slurm", none).unwrap_err().contains(SLURM_TASK_ID));
        let env = |id: &'static str, count: &'static str| move |k: &str| match k {
            SLURM_TASK_ID => Some(id.to_string()),
            SLURM_TASK_COUNT => Some(count.to_string()),
            _ => None,
        };
        assert_eq!(Shard::parse("slurm", env("2", "4")), Ok(Shard { index: 2, count: 4 }));
        assert_eq!(Shard::parse("SLURM", env("0", "1")), Ok(Shard::WHOLE));
        // A resubmitted single index reports a count of 1: N must be given.
        let e = Shard::parse("slurm", env("2", "1")).unwrap_err();
        assert!(e.contains("slurm/N"), "{e}");
        assert_eq!(Shard::parse("slurm/4", env("2", "1")), Ok(Shard { index: 2, count: 4 }));
        assert!(Shard::parse("slurm/4", env("4", "1")).is_err());
        assert!(Shard::parse("slurm", env("x", "4")).unwrap_err().contains("x"));
        assert!(Shard::parse("slurm", env("1", "")).unwrap_err().contains(SLURM_TASK_COUNT));
        assert!(Shard::parse("slurm/0", env("0", "1")).is_err());
        // An array numbered from 1: refused in every task when N comes from Slurm; with N given, K is the ID.
        let from1 = |id: &'static str| move |k: &str| match k {
            SLURM_TASK_ID => Some(id.to_string()),
            SLURM_TASK_COUNT => Some("3".to_string()),
            SLURM_TASK_MIN => Some("1".to_string()),
            _ => None,
        };
        // An array with a step, or whose last ID is not N−1: refused in every task.
        let stepped = |id: &'static str| move |k: &str| match k {
            SLURM_TASK_ID => Some(id.to_string()),
            SLURM_TASK_COUNT => Some("3".to_string()),
            SLURM_TASK_MIN => Some("0".to_string()),
            SLURM_TASK_MAX => Some("4".to_string()),
            SLURM_TASK_STEP => Some("2".to_string()),
            _ => None,
        };
        for id in ["0", "2", "4"] {
            let e = Shard::parse("slurm", stepped(id)).unwrap_err();
            assert!(e.contains("SLURM_ARRAY_TASK_STEP=2") && e.contains("no step"), "{e}");
        }
        let gap = |k: &str| match k {
            SLURM_TASK_ID => Some("0".to_string()),
            SLURM_TASK_COUNT => Some("3".to_string()),
            SLURM_TASK_MAX => Some("5".to_string()),
            _ => None,
        };
        assert!(Shard::parse("slurm", gap).unwrap_err().contains("SLURM_ARRAY_TASK_MAX=5"));
        let whole_array = |k: &str| match k {
            SLURM_TASK_ID => Some("2".to_string()),
            SLURM_TASK_COUNT => Some("3".to_string()),
            SLURM_TASK_MIN => Some("0".to_string()),
            SLURM_TASK_MAX => Some("2".to_string()),
            SLURM_TASK_STEP => Some("1".to_string()),
            _ => None,
        };
        assert_eq!(Shard::parse("slurm", whole_array), Ok(Shard { index: 2, count: 3 }));
        for id in ["1", "2", "3"] {
            let e = Shard::parse("slurm", from1(id)).unwrap_err();
            assert!(e.contains("SLURM_ARRAY_TASK_MIN=1") && e.contains("--array=0-(N-1)"), "{e}");
        }
        assert_eq!(Shard::parse("slurm/4", from1("2")), Ok(Shard { index: 2, count: 4 }));
        // Each message names the variable whose value is bad; set-but-empty is not "not set" (a held-out
        // battery, round 16).
        let e = Shard::parse("slurm", env("1", "0")).unwrap_err();
        assert!(e.starts_with("SLURM_ARRAY_TASK_COUNT=0: the shard count N must be ≥ 1"), "{e}");
        let e = Shard::parse("slurm", env("1", " ")).unwrap_err();
        assert!(e.contains("SLURM_ARRAY_TASK_COUNT is set but empty") && !e.contains("not set"), "{e}");
        let e = Shard::parse("slurm", env("", "4")).unwrap_err();
        assert!(e.contains("SLURM_ARRAY_TASK_ID is set but empty"), "{e}");
        let e = Shard::parse("slurm", env("5", "4")).unwrap_err();
        assert!(e.starts_with("SLURM_ARRAY_TASK_ID=5 with SLURM_ARRAY_TASK_COUNT=4: shard index 5 is out of range"), "{e}");
        let e = Shard::parse("slurm/0", env("0", "1")).unwrap_err();
        assert!(e.starts_with("`slurm/0`: the shard count N must be ≥ 1"), "{e}");
        for (var, value) in [(SLURM_TASK_MAX, ""), (SLURM_TASK_MAX, "x"), (SLURM_TASK_MIN, ""), (SLURM_TASK_STEP, " ")] {
            let shaped = |k: &str| match k {
                SLURM_TASK_ID => Some("1".to_string()),
                SLURM_TASK_COUNT => Some("3".to_string()),
                k if k == var => Some(value.to_string()),
                _ => None,
            };
            let e = Shard::parse("slurm", shaped).unwrap_err();
            assert!(e.starts_with(var) && !e.contains("not set"), "{var}={value}: {e}");
            // With N given the array's shape is not consulted.
            assert_eq!(Shard::parse("slurm/3", shaped), Ok(Shard { index: 1, count: 3 }));
        }
        // N is a count ≥ 1, and says so.
        assert!(Shard::parse("1/1/1", none).unwrap_err().contains("whole number ≥ 1"));
    }

    fn write(p: &Path, bytes: &[u8]) {
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, bytes).unwrap();
    }

    /// A scene folder as render-dataset writes it (files + render.json with configuration and records).
    fn fake_scene(out: &Path, name: &str, cfg: &Value) {
        let dir = out.join(name);
        write(&dir.join("acquisition.exr"), &[7u8; 300]);
        write(&dir.join("acquisition.npy"), b"\x93NUMPY\x01\x00v\x00{'descr': '<f4', 'fortran_order': False, 'shape': (2,), }      \n\x00\x00\x80?\x00\x00\x00@");
        let rec = file_records(&dir, &["acquisition.exr", "acquisition.npy"]).unwrap();
        let sidecar = json!({"configuration": cfg, "outputs": rec, "seconds_total": 1.5});
        write(&dir.join("render.json"), serde_json::to_string_pretty(&sidecar).unwrap().as_bytes());
    }

    #[test]
    fn scene_states_detect_damage_and_mismatch() {
        let t = tempfile::tempdir().unwrap();
        let out = t.path();
        let cfg = json!({"seed": 1, "rays_per_pixel": 4, "system": "sp"});
        for s in ["ok", "trunc_exr", "trunc_npy", "flip", "json_cut", "no_json", "other_cfg", "old", "gone_file"] {
            fake_scene(out, s, &cfg);
        }
        let p = |s: &str, f: &str| out.join(s).join(f);
        // Truncated EXR and NPY, one flipped byte, a truncated render.json, no render.json, a deleted output.
        let exr = std::fs::read(p("trunc_exr", "acquisition.exr")).unwrap();
        std::fs::write(p("trunc_exr", "acquisition.exr"), &exr[..100]).unwrap();
        let npy = std::fs::read(p("trunc_npy", "acquisition.npy")).unwrap();
        std::fs::write(p("trunc_npy", "acquisition.npy"), &npy[..npy.len() - 3]).unwrap();
        let mut f = std::fs::read(p("flip", "acquisition.exr")).unwrap();
        f[10] ^= 1;
        std::fs::write(p("flip", "acquisition.exr"), f).unwrap();
        let j = std::fs::read(p("json_cut", "render.json")).unwrap();
        std::fs::write(p("json_cut", "render.json"), &j[..j.len() / 2]).unwrap();
        std::fs::remove_file(p("no_json", "render.json")).unwrap();
        std::fs::remove_file(p("gone_file", "acquisition.npy")).unwrap();
        // Another seed; and an old-style render.json without configuration.
        fake_scene(out, "other_cfg", &json!({"seed": 2, "rays_per_pixel": 4, "system": "sp"}));
        write(&p("old", "render.json"), br#"{"seed": 1}"#);
        // A file where a folder should be.
        write(&out.join("a_file"), b"x");

        let st = |s: &str| check_scene(out, s, Some(&cfg));
        assert_eq!(st("ok"), SceneState::Done);
        assert_eq!(st("never"), SceneState::Missing);
        let damaged = |s: &str, needle: &str| match st(s) {
            SceneState::Damaged(p) => assert!(p.iter().any(|x| x.contains(needle)), "{s}: {p:?}"),
            other => panic!("{s}: {other:?}"),
        };
        damaged("trunc_exr", "acquisition.exr: 100 bytes, 300 written");
        damaged("trunc_npy", "acquisition.npy");
        damaged("flip", "altered");
        damaged("json_cut", "not valid JSON");
        damaged("no_json", "render.json: missing");
        damaged("gone_file", "acquisition.npy: missing");
        damaged("a_file", "not a folder");
        match st("other_cfg") {
            SceneState::Mismatch(d) => assert_eq!(d, vec!["seed: recorded 2 ≠ requested 1".to_string()]),
            other => panic!("{other:?}"),
        }
        assert!(matches!(st("old"), SceneState::Mismatch(_)));
        // Without a requested configuration, only integrity counts.
        assert_eq!(check_scene(out, "other_cfg", None), SceneState::Done);
        for s in ["trunc_exr", "flip", "json_cut", "other_cfg"] {
            assert_eq!(st(s).word(), "corrupt");
        }
    }

    #[test]
    fn dataset_status_counts_and_manifest() {
        let t = tempfile::tempdir().unwrap();
        let out = t.path();
        let cfg = json!({"seed": 1, "mapping": false});
        let names: Vec<String> = ["a", "b", "c", "d"].iter().map(|s| s.to_string()).collect();
        // No dataset.json and no scene list: an error naming the way out.
        let e = DatasetStatus::check(out, None, None).unwrap_err().to_string();
        assert!(e.contains("--scenes"), "{e}");
        write(&out.join("mask.png"), b"mask bytes");
        let shared = file_records(out, &shared_output_names(&cfg)).unwrap();
        write(&out.join(MANIFEST), serde_json::to_string_pretty(&manifest(&cfg, &names, shared)).unwrap().as_bytes());
        fake_scene(out, "a", &cfg);
        fake_scene(out, "b", &cfg);
        fake_scene(out, "c", &json!({"seed": 9, "mapping": false}));
        std::fs::create_dir_all(out.join(".d.partial-host-1")).unwrap();
        let s = DatasetStatus::check(out, None, None).unwrap();
        assert_eq!(s.shared, SceneState::Done);
        assert_eq!(s.counts(), (2, 1, 1));
        assert!(!s.is_clean());
        assert_eq!(s.leftovers, vec![out.join(".d.partial-host-1")]);
        assert_eq!(s.to_json()["scenes"][2]["status"], "corrupt");
        // Only the scenes asked for.
        let s = DatasetStatus::check(out, Some(vec!["a".into(), "b".into()]), None).unwrap();
        assert!(s.is_clean());
        // A damaged shared output makes the dataset unclean.
        write(&out.join("mask.png"), b"mask byte");
        let s = DatasetStatus::check(out, Some(vec!["a".into()]), None).unwrap();
        assert!(matches!(s.shared, SceneState::Damaged(_)), "{:?}", s.shared);
        assert!(!s.is_clean());
        // Leftovers of scene d only are removed for d.
        std::fs::create_dir_all(out.join(".dd.partial-host-1")).unwrap();
        assert_eq!(remove_leftovers(out, "d").unwrap(), 1);
        assert_eq!(leftovers(out), vec![out.join(".dd.partial-host-1")]);
        // A live writer's temporary on this host (this process) stays; a killed one's (PID 0) goes.
        let live = partial_dir(out, "dd").unwrap();
        let dead = out.join(format!(".dd.partial-{}-0-1", crate::io::stale::host_name()));
        std::fs::create_dir_all(&dead).unwrap();
        assert_eq!(remove_leftovers(out, "dd").unwrap(), 2);
        assert!(live.exists() && !dead.exists());
    }

    #[test]
    fn commit_replaces_a_folder_whole() {
        let t = tempfile::tempdir().unwrap();
        let out = t.path();
        write(&out.join("s/old_only.txt"), b"old");
        write(&out.join("s/common.txt"), b"old");
        let p = partial_dir(out, "s").unwrap();
        write(&p.join("common.txt"), b"new");
        commit_scene(&p, out, "s").unwrap();
        assert_eq!(std::fs::read(out.join("s/common.txt")).unwrap(), b"new");
        assert!(!out.join("s/old_only.txt").exists());
        assert!(leftovers(out).is_empty(), "{:?}", leftovers(out));
        let p = partial_dir(out, "fresh").unwrap();
        write(&p.join("x"), b"1");
        commit_scene(&p, out, "fresh").unwrap();
        assert_eq!(std::fs::read(out.join("fresh/x")).unwrap(), b"1");
        assert!(leftovers(out).is_empty());
    }

    #[test]
    fn configuration_differences_name_the_keys() {
        let a = json!({"seed": 1, "rays_per_pixel": 20, "system_spec": {"x": "a".repeat(100)}});
        let b = json!({"seed": 1, "rays_per_pixel": 10, "system_spec": {"x": "b".repeat(100)}, "cube": true});
        let d = configuration_differences(&a, &b);
        assert_eq!(d.len(), 3, "{d:?}");
        assert!(d[0].starts_with("cube: recorded absent"));
        assert!(d[1].contains("rays_per_pixel: recorded 20 ≠ requested 10"));
        assert!(d[2].starts_with("system_spec.x: recorded") && d[2].contains('…'));
        assert!(configuration_differences(&a, &a).is_empty());
        // An f64 configuration records no precision; against an f32 one it reads as f64.
        let f32_cfg = json!({"seed": 1, "precision": crate::tracer::Precision::F32});
        assert_eq!(configuration_differences(&f32_cfg, &json!({"seed": 1})), vec!["precision: recorded \"f32\" ≠ requested \"f64\"".to_string()]);
    }

    /// Only the leaves that really differ are listed, by path; equal numbers written differently (1, 1.0)
    /// and equal arrays are not.
    #[test]
    fn configuration_differences_list_only_real_differences() {
        let bands = [450.0, 464.81481481481484, 479.6296296296296];
        let a = json!({"bands_nm": bands, "airy": {"diameter_px": 2.5, "rings": 3}, "seed": 1, "scale": 1.0, "spec": {"s": [{"r": 1.0}, {"r": 2.0}]}});
        let b = json!({"bands_nm": bands, "airy": {"diameter_px": 2.5, "rings": 3}, "seed": 1, "scale": 1, "spec": {"s": [{"r": 1.0}, {"r": 2.5}]}});
        assert_eq!(configuration_differences(&a, &b), vec!["spec.s[1].r: recorded 2.0 ≠ requested 2.5".to_string()]);
        let mut c = b.clone();
        c["bands_nm"][1] = json!(464.8148148148149); // one ulp off
        let d = configuration_differences(&a, &c);
        assert!(d.iter().any(|l| l.starts_with("bands_nm[1]: recorded 464.81481481481484 ≠ requested 464.8148148148149")), "{d:?}");
        c["bands_nm"] = json!([450.0]);
        assert!(configuration_differences(&a, &c).iter().any(|l| l.starts_with("bands_nm: recorded 3 elements ≠ requested 1")));
        // A recorded configuration read back from its own text is identical.
        let text = serde_json::to_string_pretty(&a).unwrap();
        assert!(configuration_differences(&serde_json::from_str(&text).unwrap(), &a).is_empty());
    }
}
