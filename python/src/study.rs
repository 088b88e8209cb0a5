//! `diffcassi.study`: the library's four-system study ([`diffcassi::study::run`]) from Python — the same
//! pipeline, folder layout and resumption as `diffcassi study`, silent. Keywords are the command line's
//! options in snake case; lists are a comma string or a sequence.
use crate::errors::{value_error, IntoPy};
use crate::settings::get;
use diffcassi::recon::pipeline::NoiseModel;
use diffcassi::study::{self, StudyProgress, StudySettings};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyString};
use std::path::PathBuf;
use std::sync::Mutex;

/// A list setting: a comma string as given, or a sequence of strings or numbers joined with commas (numbers in
/// their shortest round-trip form, so they parse back to the same values).
fn list(key: &str, v: &Bound<'_, PyAny>) -> PyResult<String> {
    if let Ok(s) = v.downcast::<PyString>() {
        return s.extract::<String>();
    }
    // Bytes are a sequence of integers to Python (`b"sp"` read as the preset `115,112`).
    if v.is_instance_of::<pyo3::types::PyBytes>() || v.is_instance_of::<pyo3::types::PyByteArray>() {
        return Err(value_error(format!("study: `{key}` must be a comma string or a sequence of strings or numbers, not bytes")));
    }
    if let Ok(items) = v.extract::<Vec<String>>() {
        return Ok(items.join(","));
    }
    if let Ok(items) = v.extract::<Vec<f64>>() {
        return Ok(items.iter().map(|x| format!("{x}")).collect::<Vec<_>>().join(","));
    }
    Err(value_error(format!("study: `{key}` must be a comma string or a sequence of strings or numbers")))
}

/// Paths: a comma string (split as the command line splits `--systems a.toml,b.zmx`), one path-like, or a
/// sequence of paths.
fn paths(key: &str, v: &Bound<'_, PyAny>) -> PyResult<Vec<PathBuf>> {
    if let Ok(s) = v.downcast::<PyString>() {
        return Ok(s.extract::<String>()?.split(',').map(PathBuf::from).collect());
    }
    if let Ok(p) = v.extract::<PathBuf>() {
        return Ok(vec![p]);
    }
    get(key, v, "a path, a comma string of paths or a sequence of paths")
}

/// The settings the keywords give (unknown keywords refused, naming them and the known ones).
fn settings(out: PathBuf, kw: Option<&Bound<'_, PyDict>>) -> PyResult<StudySettings> {
    let mut s = StudySettings::new(out);
    let Some(kw) = kw else { return Ok(s) };
    // `None` is the default, as in `render`.
    let given = |k: &str| kw.get_item(k).ok().flatten().is_some_and(|v| !v.is_none());
    let truthy = |k: &str| kw.get_item(k).ok().flatten().is_some_and(|v| v.is_truthy().unwrap_or(false));
    if given("mask") && (given("opening") || given("mask_seed")) {
        return Err(value_error("study: `mask` (a file) and `opening` / `mask_seed` (a random mask): give one"));
    }
    if given("scenes") && given("synthetic") {
        return Err(value_error("study: `scenes` (a folder) and `synthetic` (generated scenes): give one"));
    }
    if given("synthetic") && given("fit") {
        return Err(value_error("study: `fit` applies to the files of `scenes`; synthetic scenes are generated at the scene size"));
    }
    if truthy("accelerated") && truthy("plain") {
        return Err(value_error("study: `accelerated` and `plain`: give one"));
    }
    for (k, v) in kw.iter() {
        let key: String = k.extract()?;
        if v.is_none() {
            continue;
        }
        let t = &mut s.tuning;
        match key.as_str() {
            "presets" => s.presets = Some(list(&key, &v)?),
            "systems" => s.systems = paths(&key, &v)?,
            "glass_catalogs" => s.glass_catalogs = paths(&key, &v)?,
            "scene_fov_deg" => s.scene_fov_deg = Some(get(&key, &v, "a number (degrees)")?),
            "operators" => s.operators = list(&key, &v)?,
            "solvers" => s.solvers = list(&key, &v)?,
            "scenes" => s.scenes = Some(get(&key, &v, "a folder path")?),
            "synthetic" => s.synthetic = Some(get(&key, &v, crate::arrays::COUNT)?),
            "scene_wavelengths" => s.scene_wavelengths = Some(list(&key, &v)?),
            "scene_size" => s.scene_size = get(&key, &v, crate::arrays::COUNT)?,
            "fit" => s.fit = get(&key, &v, "\"crop\" or \"resize\"")?,
            "bands" => s.bands = list(&key, &v)?,
            "planes" => s.planes = get(&key, &v, crate::arrays::COUNT)?,
            "rays" => s.rays = get(&key, &v, crate::arrays::COUNT)?,
            "seed" => s.seed = get(&key, &v, crate::arrays::SEED)?,
            "mask" => s.mask = Some(get(&key, &v, "a file path")?),
            "opening" => s.opening = get(&key, &v, "a number in [0, 1]")?,
            "mask_seed" => s.mask_seed = get(&key, &v, crate::arrays::SEED)?,
            "airy_diameter_px" => s.airy_diameter_px = get(&key, &v, "a number (pixels)")?,
            "transport_memory_gb" => s.transport_memory_gb = get(&key, &v, "a number (GB)")?,
            "force" => s.force = get(&key, &v, "True or False")?,
            "noise_estimate" => s.noise_estimate = Some(NoiseModel::parse("noise_estimate", &get::<String>(&key, &v, "\"spread\" or \"model\"")?).py()?),
            "iterations" => t.iterations = Some(get(&key, &v, crate::arrays::COUNT)?),
            "tv_weight" => t.tv_weight = Some(get(&key, &v, "a number")?),
            "accelerated" => t.accelerated = get(&key, &v, "True or False")?,
            "plain" => t.plain = get(&key, &v, "True or False")?,
            "denoiser" => t.denoiser = Some(get(&key, &v, "a file path")?),
            "weights" => t.weights = Some(get(&key, &v, "a file path")?),
            "sigma_max" => t.sigma_max = Some(get(&key, &v, "a number")?),
            "sigma_min" => t.sigma_min = Some(get(&key, &v, "a number")?),
            "sigma_auto" => t.sigma_auto = get(&key, &v, "True or False")?,
            "equivariant" => t.equivariant = Some(get(&key, &v, "True or False")?),
            "equivariant_seed" => t.equivariant_seed = Some(get(&key, &v, crate::arrays::SEED)?),
            "tv_warmup" => t.tv_warmup = Some(get(&key, &v, "an integer ≥ 0")?),
            "tolerance" => t.tolerance = Some(get(&key, &v, "a number ≥ 0")?),
            "discrepancy" => t.discrepancy = Some(get(&key, &v, "a number ≥ 0")?),
            other => return Err(value_error(format!("study: unknown setting `{other}` (threads and budgets: diffcassi.set_num_threads, diffcassi.set_limits; the options of `diffcassi study` in snake case: presets, systems, glass_catalogs, scene_fov_deg, operators, solvers, scenes, synthetic, scene_wavelengths, scene_size, fit, bands, planes, rays, seed, mask, opening, mask_seed, airy_diameter_px, transport_memory_gb, force, noise_estimate, iterations, tv_weight, accelerated, plain, denoiser, weights, sigma_max, sigma_min, sigma_auto, equivariant, equivariant_seed, tv_warmup, tolerance, discrepancy)"))),
        }
    }
    Ok(s)
}

/// The study's progress seen from Python: silent, but stopped between cells by Ctrl-C
/// ([`crate::pool::run_interruptible`] sets `stop`), its warnings raised as `UserWarning`s.
struct PyProgress {
    stop: diffcassi::cancel::Cancel,
    warnings: Mutex<Vec<String>>,
}

impl StudyProgress for PyProgress {
    fn warning(&self, text: &str) {
        self.warnings.lock().unwrap_or_else(|e| e.into_inner()).push(text.to_string());
    }
    fn interrupted(&self) -> bool {
        self.stop.is_cancelled()
    }
}

/// Run (or resume) a study into `out`; returns JSON: cells computed and reused, seconds, the table's path.
#[pyfunction]
#[pyo3(signature = (out, **settings_kw))]
fn _study(py: Python<'_>, out: &Bound<'_, PyAny>, settings_kw: Option<&Bound<'_, PyDict>>) -> PyResult<String> {
    let out: PathBuf = out.extract().map_err(|_| value_error(format!("study: `out` must be a folder path (str or os.PathLike), got {}", out.repr().map(|r| r.to_string()).unwrap_or_default())))?;
    let s = settings(out, settings_kw)?;
    let progress = PyProgress { stop: diffcassi::cancel::Cancel::new(), warnings: Mutex::new(Vec::new()) };
    let (result, signal) = crate::pool::run_interruptible(py, &progress.stop, || study::run(&s, &progress));
    for w in progress.warnings.lock().unwrap_or_else(|e| e.into_inner()).iter() {
        PyErr::warn(py, py.get_type::<pyo3::exceptions::PyUserWarning>().as_any(), &std::ffi::CString::new(format!("study: {}", crate::errors::pythonic(w))).unwrap_or_default(), 1)?;
    }
    // Stopped by Ctrl-C: the KeyboardInterrupt itself (the cells finished so far are kept).
    if let Some(e) = signal {
        return Err(e);
    }
    let done = result.py()?;
    Ok(serde_json::json!({"computed": done.computed, "skipped": done.skipped, "seconds": done.seconds, "table": done.table.display().to_string()}).to_string())
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(_study, m)?)?;
    Ok(())
}
