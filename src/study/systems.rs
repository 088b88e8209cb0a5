//! The systems of a study (the rows of its tables): presets (`--presets`, named as in the paper) and files
//! (`--systems`, named by their stem), each built and labelled, with what each adds to the study's
//! configuration.
use super::settings::{split_list, StudySettings, DEFAULT_PRESETS};
use crate::error::{Error, Result};
use crate::render::RenderConfig;
use crate::system::SequentialSystem;
use serde_json::{json, Value};
use std::path::PathBuf;

/// Display names of the paper's systems.
pub fn system_label(preset: &str) -> String {
    match preset {
        "ap" => "AP".into(),
        "sp" => "SP".into(),
        "map" => "mAP".into(),
        "msp" => "mSP".into(),
        "gsp" => "gSP".into(),
        other => other.to_string(),
    }
}

/// A system of the study (a row of its tables): a preset or a file of `--systems`.
pub(super) struct StudySystem {
    /// The folder name under `renders/`, `recon/` and `cells/`: the preset's name or the file's stem.
    pub(super) key: String,
    /// The tables' name: the paper's display name of a preset ([`system_label`]), a file's stem.
    pub(super) label: String,
    /// The preset it is (`None` for a file).
    pub(super) preset: Option<String>,
    /// The file it was read from (`None` for a preset).
    pub(super) file: Option<PathBuf>,
    pub(super) system: SequentialSystem,
}

impl StudySystem {
    /// Where an error about this system points: its file, or `--presets NAME`.
    pub(super) fn error(&self, message: impl std::fmt::Display) -> Error {
        match &self.file {
            Some(p) => Error::File { path: p.display().to_string(), message: format!("system `{}`: {message}", self.label) },
            None => Error::invalid(format!("--presets {}: {message}", self.key)),
        }
    }

    /// What this system adds to the study's configuration (every setting that changes its numbers): for a
    /// file, its resolved spec and the glass catalogue files it reads, by content (editing either recomputes its
    /// renders and cells); for an object at infinity, the scenes' angular extent. Presets add nothing (their
    /// content is the code's; earlier study folders stay resumable).
    pub(super) fn configuration(&self, scene_fov_deg: Option<f64>) -> Vec<(&'static str, Value)> {
        let mut v = Vec::new();
        if self.file.is_some() {
            v.push(("system_spec", serde_json::to_value(&self.system.spec).unwrap_or(Value::Null)));
            // (a built-in catalogue, `builtin:NAME`, is the code's; a file was read by the build just before)
            let agf: serde_json::Map<String, Value> = (self.system.spec.glass_catalogs.iter())
                .filter(|e| crate::materials::builtin_catalogs::entry_name(e).is_none())
                .map(|e| (e.clone(), std::fs::read(e).map_or(Value::Null, |b| json!(crate::render::dataset::crc32_hex(&b)))))
                .collect();
            if !agf.is_empty() {
                v.push(("glass_catalogs_crc32", Value::Object(agf)));
            }
        }
        if let (true, Some(f)) = (self.system.object_at_infinity(), scene_fov_deg) {
            v.push(("scene_fov_deg", json!(f)));
        }
        v
    }
}

/// The study's systems, presets then files, each built (a file with its own glass catalogues then those of
/// `--glass-catalog`, as `--system` reads it) and labelled; two systems of one label (or folder name,
/// compared without case) are refused.
pub(super) fn load_systems(a: &StudySettings) -> Result<Vec<StudySystem>> {
    if a.systems.is_empty() && !a.glass_catalogs.is_empty() {
        return Err(Error::invalid("--glass-catalog applies to the files of --systems (a preset's glasses are built in), and none is given"));
    }
    let presets = match (&a.presets, a.systems.is_empty()) {
        (Some(p), _) => split_list(p, "presets")?,
        (None, true) => split_list(DEFAULT_PRESETS, "presets")?,
        (None, false) => Vec::new(),
    };
    let mut out = Vec::new();
    for p in presets {
        let system = SequentialSystem::build(&crate::presets::spec(&p)?)?;
        out.push(StudySystem { key: p.clone(), label: system_label(&p), preset: Some(p), file: None, system });
    }
    for path in &a.systems {
        let ferr = |m: String| Error::File { path: path.display().to_string(), message: m };
        // The input check every reader uses (a FIFO, a folder or a device is named as such, not "no such file").
        match crate::io::input::open_input(path, crate::limits::MAX_TEXT_FILE_BYTES) {
            Ok(_) => {}
            Err(crate::io::IoError::Io { source, .. }) if source.kind() == std::io::ErrorKind::NotFound => return Err(ferr("--systems: no such file".into())),
            Err(crate::io::IoError::Input { reason, .. }) => return Err(ferr(format!("--systems: {reason}"))),
            Err(e) => return Err(ferr(format!("--systems: {e}"))),
        }
        let stem = path.file_stem().and_then(|s| s.to_str()).filter(|s| !s.is_empty()).ok_or_else(|| ferr("--systems: the file name has no UTF-8 stem to label its rows with".into()))?.to_string();
        let extra: Vec<String> = a.glass_catalogs.iter().map(crate::spec::catalog_entry).collect();
        let spec = crate::spec::load_spec_file_with_catalogs(path, &extra)?;
        let system = SequentialSystem::build_from(&spec, crate::system::SystemOrigin::of_path(path)).map_err(|e| ferr(e.to_string()))?;
        out.push(StudySystem { key: stem.clone(), label: stem, preset: None, file: Some(path.clone()), system });
    }
    for (i, s) in out.iter().enumerate() {
        if let Some(t) = out[..i].iter().find(|t| t.key.eq_ignore_ascii_case(&s.key) || t.label.eq_ignore_ascii_case(&s.label)) {
            let what = |x: &StudySystem| match (&x.file, &x.preset) {
                (Some(f), _) => format!("--systems {}", f.display()),
                (None, p) => format!("--presets {}", p.as_deref().unwrap_or("")),
            };
            let name = if t.key.eq_ignore_ascii_case(&s.key) { &s.key } else { &s.label };
            return Err(Error::invalid(format!(
                "{} and {} would both be named `{name}` (a file's rows and folders are named by its stem, a preset's by its name, compared without case): rename one of the files",
                what(t), what(s)
            )));
        }
    }
    Ok(out)
}

/// The render configuration of system `s`: the study's, with the scenes' angular extent for an object at
/// infinity; the system checked against it as the renderer will (an object at infinity without
/// `--scene-fov-deg` is refused, naming the system).
pub(super) fn system_render_config(cfg: &RenderConfig, s: &StudySystem, scene_fov_deg: Option<f64>) -> Result<RenderConfig> {
    let mut c = cfg.clone();
    c.scene_fov_deg = if s.system.object_at_infinity() { scene_fov_deg } else { None };
    crate::render::scene_pitch_for(&s.system, &c).map_err(|e| s.error(e))?;
    Ok(c)
}

/// `--scene-fov-deg` against the systems: a valid angle, and at least one system at infinity to apply to.
pub(super) fn check_scene_fov(a: &StudySettings, systems: &[StudySystem]) -> Result<()> {
    let Some(f) = a.scene_fov_deg else { return Ok(()) };
    crate::render::check_scene_fov_deg(f)?;
    if !systems.iter().any(|s| s.system.object_at_infinity()) {
        let names: Vec<&str> = systems.iter().map(|s| s.label.as_str()).collect();
        return Err(Error::invalid(format!(
            "--scene-fov-deg {}: no system of the study has its object at infinity ({} {} a finite object, where a scene pixel is {} mm on the object plane); --scene-fov-deg is for objects at infinity",
            crate::limits::fmt_num(f),
            names.join(", "),
            if names.len() == 1 { "has" } else { "have" },
            RenderConfig::paper(1).scene_pitch_mm
        )));
    }
    Ok(())
}

