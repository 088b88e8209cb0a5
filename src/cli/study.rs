//! `study`: the reference paper's four-system experiment, end to end. Every scene is rendered through every
//! system with one mask, reconstructed with every operator and solver, and evaluated against the scene:
//!
//! ```text
//! diffcassi study --presets ap,sp,map,msp --operators exact,mapping,shift --scenes data/scenes --scene-size 128 --out out/study
//! diffcassi study --synthetic 2 --scene-size 24 --presets ap,sp --planes 28 --rays 4 --iterations 5 --out out/tiny
//! diffcassi study --synthetic 2 --presets sp --systems my_cassi.toml,lens.zmx --scene-fov-deg 6 --out out/mine
//! ```
//!
//! Systems are presets (`--presets`, rows named as in the paper: SP, mAP…) and files (`--systems`, read as
//! `--system` elsewhere; rows named by the file stem). For a system whose object is at infinity the scenes span
//! `--scene-fov-deg` degrees across their width (as `render --scene-fov-deg`); finite systems keep 10 µm pixels.
//!
//! Layout of `--out`: `study.json` (the marker of a study folder: command, version, configuration, systems), `mask.png` (the mask every render uses), `renders/<system>/<scene>/` (complete render
//! folders, readable by `reconstruct --from`; `<system>` is the preset's name or the file's stem), `recon/<system>/<scene>/<operator>-<solver>/` (`cube.npy`,
//! `rgb.png`, `reconstruct.json`), `cells/<system>/<scene>/<operator>-<solver>.json` (one finished cell:
//! its configuration, metrics and seconds), and, rebuilt from every cell at the end, `study.csv` (one row per
//! scene × system × operator × solver), `study.md` (the paper-shaped table, mean ± std over scenes, and the
//! ablation "reconstruct with the simplified model") and `study_psnr.png` (grouped bars).
//!
//! Resumable: a render whose `render.json` carries the same study configuration, and a cell whose result file
//! carries the same configuration, are not recomputed; anything else is (the configuration is every setting
//! that changes a number: bands, planes, rays, seeds, mask, Airy, scene size and fit, solver settings; for a
//! system file its resolved spec, so that editing the file recomputes its rows; at infinity the angular extent).
//! The exact operator of a system is traced once (seed = acquisition seed + 1, as `reconstruct`'s default) and
//! reused for all its scenes; so are the other operators.
use super::reconstruct::{reconstruction_rule, write_reconstruction, SolverTuning};
use crate::recon::pipeline::{build_operator, check_solver, is_unrolled, noise_estimate, operator_seed, solve, OperatorKind, RenderRecord, SolveSettings, MC_MISMATCH_PER_RAY, RESIDUAL_DEFINITION};
use crate::error::{Error, Result};
use crate::recon::metrics::evaluate;
use crate::recon::Operator;
use crate::render::{output, AiryConfig, Mask, PlaneTransport, RenderConfig, Renderer, SpectralSampling};
use crate::scene::{load_scene, synthetic_scene, synthetic_wavelengths, Fit, SpectralCube};
use crate::system::SequentialSystem;
use crate::tracer::{AnalyticTracer, Tracer};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use serde_json::{json, Value};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Args, Debug, Clone)]
pub struct StudyArgs {
    /// Systems (presets), comma-separated [default: ap,sp,map,msp, unless --systems is given].
    #[arg(long)]
    pub presets: Option<String>,
    /// System files, comma-separated (or repeated): .toml/.json (our spec), .yml/.yaml, .csv or .zmx, read as
    /// `--system` elsewhere; each row is labelled by its file stem (`lens.zmx` → `lens`), unique among the systems.
    #[arg(long, value_delimiter = ',')]
    pub systems: Vec<PathBuf>,
    /// Extra AGF glass catalogue(s) for the `--systems` files, comma-separated (or repeated), loaded after each
    /// file's own catalogues as `--glass-catalog` elsewhere (recorded in each file's resolved spec).
    #[arg(long = "glass-catalog", value_delimiter = ',')]
    pub glass_catalogs: Vec<PathBuf>,
    /// For the systems whose object is at infinity: the scenes' full angular extent across their width (degrees,
    /// in (0, 180)), as `render --scene-fov-deg`; refused when no system of the study has its object at infinity.
    #[arg(long = "scene-fov-deg", allow_hyphen_values = true)]
    pub scene_fov_deg: Option<f64>,
    /// Operators, comma-separated: exact, mapping (bilinear), mapping-nearest, shift.
    #[arg(long, default_value = "exact,mapping,shift")]
    pub operators: String,
    /// Solvers, comma-separated: gap-tv, admm-tv, pnp-gap, pnp-admm, unrolled (the unrolled network: the
    /// committed weights of each system, sp and msp, or --weights for one system).
    #[arg(long, default_value = "gap-tv")]
    pub solvers: String,
    /// Folder of scenes: RGB .png photographs (uplifted to spectra), .npy/.exr cubes, CAVE-style PNG folders.
    #[arg(long, conflicts_with = "synthetic")]
    pub scenes: Option<PathBuf>,
    /// Use N synthetic scenes (seeds 0..N) instead of --scenes.
    #[arg(long)]
    pub synthetic: Option<usize>,
    /// Wavelengths (nm) of the scene files' bands (list or first:last:count), overriding what the files say
    /// (e.g. KAIST EXRs whose channel names carry no wavelength); for RGB photographs, the wavelengths they are
    /// uplifted at, as `render --scene-wavelengths` [default for them: the render bands].
    #[arg(long = "scene-wavelengths")]
    pub scene_wavelengths: Option<String>,
    /// Scene side (pixels of 10 µm on a finite object plane; at infinity --scene-fov-deg / S each); scenes are
    /// brought to S×S by --fit.
    #[arg(long = "scene-size", default_value_t = 128)]
    pub scene_size: usize,
    /// crop (centre) or resize (area average, then centre crop).
    #[arg(long, default_value = "resize", conflicts_with = "synthetic")]
    pub fit: String,
    /// Bands: list or first:last:count (nm).
    #[arg(long, default_value = "450:650:28")]
    pub bands: String,
    /// Spectral planes of the render (112 = 28 × 4, the paper's).
    #[arg(long, default_value_t = 112)]
    pub planes: usize,
    /// Rays per scene pixel per plane.
    #[arg(long, default_value_t = 20)]
    pub rays: usize,
    /// Acquisition ray seed (the exact operator uses seed + 1).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Mask file ((H, W) NPY or PNG, e.g. ../shared/reference/paper_mask_512.npy), centre-cropped to the scene size;
    /// default a random binary mask of --opening.
    #[arg(long, conflicts_with_all = ["opening", "mask_seed"])]
    pub mask: Option<PathBuf>,
    #[arg(long, default_value_t = 0.5)]
    pub opening: f64,
    #[arg(long = "mask-seed", default_value_t = 0)]
    pub mask_seed: u64,
    /// Airy disk diameter (pixels) at 520 nm.
    #[arg(long = "airy-diameter-px", default_value_t = 2.5)]
    pub airy_diameter_px: f64,
    #[command(flatten)]
    pub tuning: SolverTuning,
    /// Light-transport memory budget (GB) for the renders and the exact operator.
    #[arg(long = "transport-memory-gb", default_value_t = 4.0)]
    pub transport_memory_gb: f64,
    /// Output folder: new, empty, or a previous study (it holds study.json; resumed); never an input (--scenes, --mask,
    /// --denoiser), inside one or containing one.
    #[arg(long)]
    pub out: PathBuf,
    /// Accept an --out folder that holds other files (not a previous study): the study's files are written
    /// beside them, nothing else there is touched (docs/robustness.md, "Output policy").
    #[arg(long)]
    pub force: bool,
}

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

fn split_list(s: &str, what: &str) -> Result<Vec<String>> {
    let v: Vec<String> = s.split(',').map(|x| x.trim().to_string()).collect();
    if v.iter().all(String::is_empty) {
        return Err(Error::invalid(format!("--{what} is empty")));
    }
    // An empty entry (`gap-tv,`, `a,,b`) is a typo: refused rather than skipped.
    if v.iter().any(String::is_empty) {
        return Err(Error::invalid(format!("--{what} `{s}` has an empty entry (a stray comma)")));
    }
    let mut seen = v.clone();
    seen.sort();
    seen.dedup();
    if seen.len() != v.len() {
        return Err(Error::invalid(format!("--{what} `{s}` lists an entry twice")));
    }
    Ok(v)
}

/// A system of the study (a row of its tables): a preset or a file of `--systems`.
struct StudySystem {
    /// The folder name under `renders/`, `recon/` and `cells/`: the preset's name or the file's stem.
    key: String,
    /// The tables' name: the paper's display name of a preset ([`system_label`]), a file's stem.
    label: String,
    /// The preset it is (`None` for a file).
    preset: Option<String>,
    /// The file it was read from (`None` for a preset).
    file: Option<PathBuf>,
    system: SequentialSystem,
}

impl StudySystem {
    /// Where an error about this system points: its file, or `--presets NAME`.
    fn error(&self, message: impl std::fmt::Display) -> Error {
        match &self.file {
            Some(p) => Error::File { path: p.display().to_string(), message: format!("system `{}`: {message}", self.label) },
            None => Error::invalid(format!("--presets {}: {message}", self.key)),
        }
    }

    /// What this system adds to the study's configuration (every setting that changes its numbers): for a
    /// file, its resolved spec and the glass catalogue files it reads, by content (editing either recomputes its
    /// renders and cells); for an object at infinity, the scenes' angular extent. Presets add nothing (their
    /// content is the code's; earlier study folders stay resumable).
    fn configuration(&self, scene_fov_deg: Option<f64>) -> Vec<(&'static str, Value)> {
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
fn load_systems(a: &StudyArgs) -> Result<Vec<StudySystem>> {
    if a.systems.is_empty() && !a.glass_catalogs.is_empty() {
        return Err(Error::invalid("--glass-catalog applies to the files of --systems (a preset's glasses are built in), and none is given"));
    }
    let presets = match (&a.presets, a.systems.is_empty()) {
        (Some(p), _) => split_list(p, "presets")?,
        (None, true) => split_list("ap,sp,map,msp", "presets")?,
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
        let is_zmx = path.extension().is_some_and(|e| e.eq_ignore_ascii_case("zmx"));
        let system = SequentialSystem::build(&spec).map_err(|e| ferr(if is_zmx { crate::spec::zmx::with_zmx_hints(e) } else { e }.to_string()))?;
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
fn system_render_config(cfg: &RenderConfig, s: &StudySystem, scene_fov_deg: Option<f64>) -> Result<RenderConfig> {
    let mut c = cfg.clone();
    c.scene_fov_deg = if s.system.object_at_infinity() { scene_fov_deg } else { None };
    crate::render::scene_pitch_for(&s.system, &c).map_err(|e| s.error(e))?;
    Ok(c)
}

/// `--scene-fov-deg` against the systems: a valid angle, and at least one system at infinity to apply to.
fn check_scene_fov(a: &StudyArgs, systems: &[StudySystem]) -> Result<()> {
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

/// A scene of the study: its name and the fitted cube (the truth).
struct StudyScene {
    name: String,
    cube: SpectralCube,
    source: Value,
    /// SHA-256 of the fitted cube's values and wavelengths (`scene_sha256` in its render.json and cells): a
    /// resumed study renders and solves again a scene whose file changed (it kept the old results).
    digest: String,
}

impl StudyScene {
    fn new(name: String, cube: SpectralCube, source: Value) -> Self {
        let mut bytes: Vec<u8> = cube.wavelengths_nm.iter().flat_map(|w| w.to_le_bytes()).collect();
        bytes.extend(cube.data.iter().flat_map(|v| v.to_le_bytes()));
        let digest = crate::io::sha256::sha256_hex(&bytes);
        StudyScene { name, cube, source, digest }
    }
}

fn load_scenes(a: &StudyArgs, bands: &[f64]) -> Result<Vec<StudyScene>> {
    let n = a.scene_size;
    match (&a.scenes, a.synthetic) {
        (Some(dir), None) => {
            let fit = match a.fit.as_str() {
                "crop" => Fit::Crop,
                "resize" => Fit::Resize,
                other => return Err(Error::invalid(format!("--fit `{other}`: use crop or resize"))),
            };
            let given = a.scene_wavelengths.as_deref().map(super::shared::parse_wavelengths).transpose()?;
            let found = crate::render::dataset::find_scenes(dir)?;
            if found.is_empty() {
                return Err(Error::File { path: dir.display().to_string(), message: "no scenes (.png photographs, .exr, .npy, or folders of per-band .png)".into() });
            }
            let nb = bands.len().max(given.as_ref().map_or(31, Vec::len));
            crate::limits::check_memory(&format!("--scene-size {n} × {} scenes of {}", found.len(), dir.display()), found.len() as f64 * crate::limits::bytes_cube(n, n, nb))?;
            found
                .into_iter()
                .map(|s| {
                    // RGB photographs are uplifted at --scene-wavelengths as `render` does (it was ignored for them),
                    // else directly at the render bands; cubes keep their own bands unless --scene-wavelengths.
                    let ws = if crate::scene::natural::is_rgb_image(&s.path) { given.as_deref().or(Some(bands)) } else { given.as_deref() };
                    let raw = load_scene(&s.path, ws)?;
                    let cube = raw.fit(n, fit).map_err(|e| Error::File { path: s.path.display().to_string(), message: e.to_string() })?;
                    // The metrics take the scene's maximum as PSNR's peak: a black scene is refused before any
                    // render, naming it (it failed after its renders and solves with "the truth's maximum is 0").
                    crate::recon::metrics::truth_peak(&cube.data).map_err(|e| Error::File { path: s.path.display().to_string(), message: format!("as a truth at --scene-size {n}: {e}; remove it from the study") })?;
                    let source = json!({"source": s.path.display().to_string(), "native_height": raw.height, "native_width": raw.width, "fit": fit});
                    Ok(StudyScene::new(s.name, cube, source))
                })
                .collect()
        }
        (None, Some(k)) => {
            if k == 0 {
                return Err(Error::invalid("--synthetic must be ≥ 1"));
            }
            Ok((0..k).map(|s| StudyScene::new(format!("synthetic{s:02}"), synthetic_scene(n, n, &synthetic_wavelengths(), s as u64), json!({"source": "synthetic", "synthetic_seed": s}))).collect())
        }
        _ => Err(Error::invalid("give --scenes DIR or --synthetic N")),
    }
}

fn study_mask(a: &StudyArgs) -> Result<Mask> {
    let n = a.scene_size;
    match &a.mask {
        None => Mask::random(n, n, a.opening, a.mask_seed),
        Some(p) => {
            let m = Mask::load(p)?;
            if m.height < n || m.width < n {
                return Err(Error::File { path: p.display().to_string(), message: format!("the mask is {}×{}, smaller than the {n}×{n} scenes", m.height, m.width) });
            }
            let (r0, c0) = ((m.height - n) / 2, (m.width - n) / 2);
            let values = (0..n).flat_map(|r| m.values[(r0 + r) * m.width + c0..(r0 + r) * m.width + c0 + n].to_vec()).collect();
            Ok(Mask { height: n, width: n, values, description: format!("{} (centre {n}×{n} of {}×{})", m.description, m.height, m.width) })
        }
    }
}

/// The limits `render` applies (same messages), checked before any scene is loaded or generated: planes,
/// Airy diameter, opening, the memory of the renders and of the study's scenes held together, and the ray
/// budget of each render; `--fit`, `--transport-memory-gb` and `--accelerated` validated so none is ignored.
fn check_limits(a: &StudyArgs, bands: &[f64], solvers: &[String]) -> Result<()> {
    let n = a.scene_size;
    super::render::parse_fit(&a.fit)?;
    if a.planes == 0 || a.planes > crate::limits::MAX_PLANES {
        return Err(Error::invalid(format!("--planes {}: must be in 1..={}", a.planes, crate::limits::MAX_PLANES)));
    }
    if !(a.airy_diameter_px.is_finite() && a.airy_diameter_px > 0.0 && a.airy_diameter_px <= crate::limits::MAX_AIRY_DIAMETER_PX) {
        return Err(Error::invalid(format!("--airy-diameter-px {}: must be in (0, {}] pixels", a.airy_diameter_px, crate::limits::MAX_AIRY_DIAMETER_PX)));
    }
    if !(a.opening.is_finite() && (0.0..=1.0).contains(&a.opening)) {
        return Err(Error::invalid(format!("--opening {}: the mask's opening ratio must be in [0, 1]", a.opening)));
    }
    if a.opening == 0.0 && a.mask.is_none() {
        // A closed mask lets no light through: every acquisition is black, every reconstruction fails (it did so
        // after the renders).
        return Err(Error::invalid("--opening 0: a closed mask lets no light through, so there is nothing to reconstruct; give an opening in (0, 1]"));
    }
    if !(a.transport_memory_gb.is_finite() && a.transport_memory_gb >= 0.0) {
        return Err(Error::invalid(format!("--transport-memory-gb {}: must be finite and ≥ 0 (0: never keep the transport)", a.transport_memory_gb)));
    }
    if a.tuning.plain && !solvers.iter().any(|s| s == "gap-tv") {
        return Err(Error::invalid(format!("--plain applies to gap-tv only, and --solvers `{}` has no gap-tv", a.solvers)));
    }
    if a.tuning.accelerated && !solvers.iter().any(|s| s == "gap-tv") {
        return Err(Error::invalid(format!("--accelerated applies to gap-tv only, and --solvers `{}` has no gap-tv", a.solvers)));
    }
    if a.rays == 0 {
        return Err(Error::invalid("--rays must be ≥ 1"));
    }
    if a.synthetic.is_some() && a.scene_wavelengths.is_some() {
        return Err(Error::invalid("--scene-wavelengths applies to the files of --scenes, not to --synthetic scenes"));
    }
    if let Some(k) = a.synthetic {
        if k > crate::limits::MAX_SCENES {
            return Err(Error::invalid(format!("--synthetic {k}: must be in 1..={}", crate::limits::MAX_SCENES)));
        }
    }
    // Every scene's fitted cube is held for the whole study (its truth), beside one render.
    let scene_bands = synthetic_wavelengths().len().max(bands.len());
    let scenes = a.synthetic.unwrap_or(1);
    let what = format!("--scene-size {n} × --planes {} (× {} bands, {scenes} scenes)", a.planes, bands.len());
    crate::limits::check_memory(&what, crate::limits::bytes_render(n, scene_bands, bands.len(), a.planes, false, Some(a.airy_diameter_px)) + scenes as f64 * crate::limits::bytes_cube(n, n, scene_bands))?;
    super::render::check_render_rays(n, a.planes, a.rays)
}

/// The render configuration of the study.
fn render_config(a: &StudyArgs, bands: &[f64]) -> Result<RenderConfig> {
    let mut cfg = RenderConfig::paper(a.scene_size);
    cfg.spectral = SpectralSampling::with_planes(bands.to_vec(), a.planes)?;
    cfg.rays_per_pixel = a.rays;
    cfg.seed = a.seed;
    cfg.airy = Some(AiryConfig { diameter_px: a.airy_diameter_px, ..AiryConfig::default() });
    Ok(cfg)
}

/// Whether a stored configuration equals this one: every number compared by value, bit-exactly (the records
/// are written and read back exactly, serde_json's `float_roundtrip`).
fn same_config(stored: Option<&Value>, config: &Value) -> bool {
    stored.is_some_and(|s| crate::render::dataset::configuration_differences(s, config).is_empty())
}

/// A cell's or render's JSON record; `None` when missing, unreadable or not JSON (the cell is computed again).
/// Through `io::input`: a FIFO planted as a record is not waited on (it blocked `study`: a held-out battery).
fn read_json(path: &Path) -> Option<Value> {
    crate::io::input::read_sidecar_json(path).ok()
}

fn write_json(path: &Path, v: &Value) -> Result<()> {
    let text = serde_json::to_string_pretty(v).map_err(|e| Error::invalid(format!("JSON encoding failed: {e}")))?;
    crate::io::write_atomic(path, text.as_bytes())?;
    Ok(())
}

fn bar(n: u64, template: &str, what: &str) -> ProgressBar {
    let pb = ProgressBar::new(n);
    pb.set_style(ProgressStyle::with_template(template).unwrap_or_else(|_| ProgressStyle::default_bar()));
    pb.set_message(what.to_string());
    pb
}

/// Render the scenes whose render folder is missing or stale, tracing the transport once when it fits.
fn render_scenes(system: &SequentialSystem, tracer: &dyn Tracer, cfg: &RenderConfig, mask: &Mask, scenes: &[StudyScene], dirs: &[PathBuf], todo: &[usize], config: &Value, budget_bytes: f64) -> Result<()> {
    if todo.is_empty() {
        return Ok(());
    }
    let renderer = Renderer::new(system, tracer, cfg.clone(), mask.clone())?;
    let probe_bytes = renderer.trace_plane(renderer.config.spectral.planes() / 2)?.bytes() as f64 * renderer.config.spectral.planes() as f64 * 1.25;
    let t = Instant::now();
    let cached: Option<Vec<PlaneTransport>> = if todo.len() > 1 && probe_bytes <= budget_bytes {
        let pb = bar(renderer.rays_per_render(), "{msg} [{elapsed_precise}] {wide_bar} {human_pos}/{human_len} rays, ETA {eta}", &format!("{}: tracing the light transport", system.name()));
        let tr = renderer.trace_all(&|k| pb.inc(k))?;
        pb.finish_and_clear();
        Some(tr)
    } else {
        None
    };
    let transport_seconds = t.elapsed().as_secs_f64();
    for &i in todo {
        let ts = Instant::now();
        let acq = match &cached {
            Some(tr) => renderer.render_cached(&scenes[i].cube, tr, false, &|_| {})?,
            None => renderer.render(&scenes[i].cube, false, &|_| {})?,
        };
        let dir = &dirs[i];
        std::fs::create_dir_all(dir).map_err(|e| Error::File { path: dir.display().to_string(), message: format!("cannot create: {e}") })?;
        let scale = output::write_images(dir, &renderer, &acq)?;
        renderer.mask.save_png(&dir.join("mask.png"))?;
        let mut j = output::sidecar(&renderer, &acq, &scenes[i].source, scale, ts.elapsed().as_secs_f64(), rayon::current_num_threads());
        if let Some(o) = j.as_object_mut() {
            o.insert("study_config".into(), config.clone());
            o.insert("scene_sha256".into(), json!(scenes[i].digest));
            o.insert("transport_cached".into(), json!(cached.is_some()));
            o.insert("transport_seconds".into(), json!(transport_seconds));
            o.insert("noise".into(), Value::Null);
        }
        output::write_sidecar(dir, &j)?;
    }
    Ok(())
}

/// One finished cell, read back from its result file.
#[derive(Clone, Debug)]
struct Cell {
    /// The system's label (a preset's display name, a file's stem) and the preset it is (`None` for a file).
    system: String,
    preset: Option<String>,
    scene: String,
    operator: String,
    solver: String,
    metrics: BTreeMap<String, f64>,
    seconds_solve: f64,
    seconds_operator: f64,
    iterations: usize,
    residual: f64,
}

const METRIC_KEYS: [&str; 6] = ["psnr_db", "psnr_band_db", "ssim", "sam_deg", "sam_rad", "rmse"];

fn cell_from_json(v: &Value) -> Option<Cell> {
    let s = |k: &str| v.get(k).and_then(Value::as_str).map(str::to_string);
    let m = v.get("metrics")?;
    let metrics = METRIC_KEYS.iter().map(|k| Some((k.to_string(), m.get(*k)?.as_f64()?))).collect::<Option<BTreeMap<_, _>>>()?;
    Some(Cell {
        system: s("system")?,
        preset: s("preset"),
        scene: s("scene")?,
        operator: s("operator")?,
        solver: s("solver")?,
        metrics,
        seconds_solve: v.get("seconds_solve")?.as_f64()?,
        seconds_operator: v.get("seconds_operator")?.as_f64()?,
        iterations: v.get("iterations")?.as_u64()? as usize,
        residual: v.get("final_residual").and_then(Value::as_f64).unwrap_or(f64::NAN),
    })
}

/// The settings of one solver of the study: `--accelerated` applies to gap-tv only, the PnP options
/// (`--denoiser`, `--sigma-max`, `--sigma-min`) to the PnP solvers only.
fn cell_settings(a: &StudyArgs, solver: &str) -> SolveSettings {
    let mut s = a.tuning.settings(solver, a.tuning.accelerated && solver == "gap-tv");
    s.plain = a.tuning.plain && solver == "gap-tv";
    if !solver.parse::<crate::recon::SolverKind>().is_ok_and(|k| k.is_pnp()) {
        (s.denoiser, s.sigma_max, s.sigma_min, s.tv_warmup, s.sigma_auto, s.equivariant, s.equivariant_seed) = (None, None, None, None, false, None, None);
    }
    if is_unrolled(solver) {
        // The iterative solvers' options apply to them only.
        (s.iterations, s.tv_weight, s.tolerance, s.discrepancy, s.accelerated, s.plain) = (None, None, None, None, false, false);
    } else {
        s.weights = None;
    }
    s
}

/// An option that no solver of `--solvers` takes is refused: each cell drops the options of other solvers
/// ([`cell_settings`]), so with none of its solvers listed it would be ignored by every cell (e.g.
/// `--iterations` with `--solvers unrolled`, whose stages are fixed).
fn check_options_apply(a: &StudyArgs, solvers: &[String]) -> Result<()> {
    use crate::recon::solver::SettingScope;
    // --accelerated and --plain are checked against gap-tv in `check_limits` (the study applies them to it only).
    let mut given = a.tuning.settings("", false);
    given.plain = false;
    for (key, flag) in given.given() {
        let scope = SettingScope::of(key);
        if !solvers.iter().any(|s| s.parse::<crate::recon::SolverKind>().is_ok_and(|k| scope.contains(k))) {
            let takes = if scope == SettingScope::Every { "the iterative solvers (gap-tv, admm-tv, pnp-gap, pnp-admm; unrolled has a fixed number of stages)" } else { scope.solvers() };
            return Err(Error::invalid(format!("{flag}: applies to {takes}, and --solvers `{}` has none of them", a.solvers)));
        }
    }
    Ok(())
}

fn mean_std(v: &[f64]) -> (f64, f64) {
    let n = v.len().max(1) as f64;
    let m = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / n;
    (m, var.sqrt())
}

/// The file every study output folder holds (written first): the output policy recognises a previous study
/// by it ([`crate::io::policy`]).
pub const STUDY_MARKER: &str = "study.json";

pub fn study(a: StudyArgs) -> Result<()> {
    let t0 = Instant::now();
    // ---- validate everything before any work ----
    let systems = load_systems(&a)?;
    check_scene_fov(&a, &systems)?;
    let operators = split_list(&a.operators, "operators")?.iter().map(|o| OperatorKind::parse(o)).collect::<Result<Vec<_>>>()?;
    let solvers = split_list(&a.solvers, "solvers")?;
    for s in &solvers {
        // (the library names the setting `--solver`; here the entry is one of --solvers)
        check_solver(&cell_settings(&a, s)).map_err(|e| Error::invalid(format!("--solvers `{}`: {}", a.solvers, e.to_string().replace("--solver `", "entry `"))))?;
    }
    check_options_apply(&a, &solvers)?;
    if let (Some(e), false) = (&a.tuning.noise_estimate, operators.contains(&OperatorKind::Exact)) {
        return Err(Error::invalid(format!("--noise-estimate {e}: applies to the exact operator only, and --operators `{}` has none", a.operators)));
    }
    if a.tuning.weights.is_some() && !solvers.iter().any(|s| is_unrolled(s)) {
        return Err(Error::invalid(format!("--weights applies to the unrolled solver only, and --solvers `{}` has none", a.solvers)));
    }
    // The unrolled network: weights for every system (its own committed file, or the --weights file's system).
    if solvers.iter().any(|s| is_unrolled(s)) {
        for s in &systems {
            crate::recon::pipeline::unrolled::check_system(a.tuning.weights.as_deref(), &s.system.spec).map_err(|e| s.error(format!("--solvers unrolled: {e}")))?;
        }
    }
    if a.tuning.iterations == Some(0) {
        return Err(Error::invalid("--iterations must be ≥ 1"));
    }
    if a.scene_size == 0 {
        return Err(Error::invalid("--scene-size must be ≥ 1"));
    }
    // The output policy before any work: --out new, empty, a previous study (or --force), never an input.
    let mut inputs: Vec<(&str, &Path)> = a.scenes.iter().map(|p| ("--scenes", p.as_path())).collect();
    inputs.extend(a.mask.as_deref().map(|p| ("--mask", p)));
    inputs.extend(a.tuning.denoiser.as_deref().map(|p| ("--denoiser", p)));
    inputs.extend(a.tuning.weights.as_deref().map(|p| ("--weights", p)));
    inputs.extend(a.systems.iter().map(|p| ("--systems", p.as_path())));
    inputs.extend(a.glass_catalogs.iter().map(|p| ("--glass-catalog", p.as_path())));
    crate::io::policy::check_out_folder(&a.out, &crate::io::policy::FolderRule { option: "--out", command: "study", marker: STUDY_MARKER, force: a.force }, &inputs)?;
    let bands = super::shared::parse_wavelengths(&a.bands)?;
    check_limits(&a, &bands, &solvers)?;
    // The unrolled network's band count before any render, as the PnP denoiser's below (a mismatch failed after
    // the renders: a held-out battery, round 6).
    if solvers.iter().any(|s| is_unrolled(s)) {
        for s in &systems {
            let net = crate::recon::prior::unrolled::UnrolledNetwork::load(a.tuning.weights.as_deref(), &s.system.spec.name)?;
            if net.meta.bands != bands.len() {
                return Err(s.error(format!("--solvers unrolled: the network {} was trained for {} bands, but --bands `{}` gives {}", net.source, net.meta.bands, a.bands, bands.len())));
            }
        }
    }
    // The PnP denoiser's band count before any render (a mismatch failed after the renders and the other
    // solvers' cells: hours in at paper scale; a held-out battery, round 6).
    if solvers.iter().any(|s| s.parse::<crate::recon::SolverKind>().is_ok_and(|k| k.is_pnp())) {
        let d = crate::recon::prior::network::SpectralUNet::load_pnp(a.tuning.denoiser.as_deref())?;
        if d.bands != bands.len() {
            return Err(Error::invalid(format!(
                "--solvers `{}`: the PnP denoiser{} was trained for {} bands, but --bands `{}` gives {}",
                a.solvers,
                a.tuning.denoiser.as_deref().map(|p| format!(" {}", p.display())).unwrap_or_default(),
                d.bands,
                a.bands,
                bands.len()
            )));
        }
    }
    let cfg = render_config(&a, &bands)?;
    // Each system's render configuration (the angular extent for an object at infinity), checked now.
    let cfgs = systems.iter().map(|s| system_render_config(&cfg, s, a.scene_fov_deg)).collect::<Result<Vec<_>>>()?;
    let mask = study_mask(&a)?;
    let scenes = load_scenes(&a, &bands)?;
    let tracer = AnalyticTracer::default();
    let op_seed = operator_seed(a.seed, None)?;
    let budget = a.transport_memory_gb * 1e9;
    // Every setting that changes a number.
    let mut config = json!({
        // Synthetic scenes are generated at the study's size: no fit (null, not the default `resize`).
        "scene_size": a.scene_size, "fit": if a.synthetic.is_some() { None } else { Some(&a.fit) }, "bands_nm": bands, "planes": a.planes, "rays": a.rays, "seed": a.seed,
        "operator_seed": op_seed, "mask": mask.description, "mask_open_pixels": mask.values.iter().filter(|&&v| v > 0.0).count(),
        "airy_diameter_px": a.airy_diameter_px, "iterations": a.tuning.iterations, "tv_weight": a.tuning.tv_weight, "accelerated": a.tuning.accelerated, "plain": a.tuning.plain, "tracer": tracer.name(),
    });
    // PnP settings join the configuration only when a PnP solver runs (so TV-only studies stay resumable
    // from folders written before PnP existed); the weights enter by content (CRC-32), not only by path.
    if solvers.iter().any(|s| s.parse::<crate::recon::SolverKind>().is_ok_and(|k| k.is_pnp())) {
        let crc = crate::recon::prior::network::weights_crc32(a.tuning.denoiser.as_deref())?;
        if let Some(o) = config.as_object_mut() {
            o.insert("pnp".into(), json!({"denoiser": a.tuning.denoiser.as_ref().map(|p| p.display().to_string()), "weights_crc32": crc, "sigma_max": a.tuning.sigma_max, "sigma_min": a.tuning.sigma_min, "sigma_auto": a.tuning.sigma_auto, "tv_warmup": a.tuning.tv_warmup,
                "equivariant": if a.tuning.equivariant { Some(true) } else if a.tuning.no_equivariant { Some(false) } else { None }, "equivariant_seed": a.tuning.equivariant_seed,
                // The library's PnP defaults too: a cell computed under other defaults is recomputed.
                "defaults": crate::recon::SolverConfig::pnp_gap()}));
        }
    }
    // The unrolled network's weights by content (CRC-32 per system), only when it runs.
    if solvers.iter().any(|s| is_unrolled(s)) {
        let mut crcs = serde_json::Map::new();
        for s in &systems {
            let net = crate::recon::prior::unrolled::UnrolledNetwork::load(a.tuning.weights.as_deref(), s.system.name())?;
            crcs.insert(s.system.name().to_string(), json!(net.crc32));
        }
        if let Some(o) = config.as_object_mut() {
            o.insert("unrolled".into(), json!({"weights": a.tuning.weights.as_ref().map(|p| p.display().to_string()), "weights_crc32": crcs}));
        }
    }
    if let (Some(t), Some(o)) = (a.tuning.tolerance, config.as_object_mut()) {
        o.insert("tolerance".into(), json!(t));
    }
    if let Some(o) = config.as_object_mut() {
        // The stopping rule: τ as given and the library's TV defaults (a cell computed under other defaults
        // is recomputed). The defaults are labelled as such: the study's own iterations and weights are the
        // top-level keys (a block named `gap_tv` read as what ran; a held-out battery, round 7).
        o.insert("stopping".into(), json!({"discrepancy": a.tuning.discrepancy, "library_defaults": {"gap_tv": crate::recon::SolverConfig::gap_tv(), "admm_tv": crate::recon::SolverConfig::admm_tv()}, "mc_mismatch_per_ray": MC_MISMATCH_PER_RAY, "noise_estimate": a.tuning.noise_estimate.as_deref().unwrap_or("spread"), "spread_every": crate::recon::solver::SPREAD_EVERY}));
    }
    if let (Some(w), Some(o)) = (&a.scene_wavelengths, config.as_object_mut()) {
        o.insert("scene_wavelengths".into(), json!(w));
    }
    // A mask file enters by content (its 16-bit codes' SHA-256, as render.json records it): the same path with
    // other contents reused the earlier renders and cells (a held-out battery, round 7). A random mask is its
    // seed and opening.
    if let (Some(_), Some(o)) = (&a.mask, config.as_object_mut()) {
        o.insert("mask_png_sha256".into(), json!(mask.png_sha256()));
    }
    // Renders depend on everything but the operator seed and the solver settings.
    let render_key = {
        let mut r = config.clone();
        if let Some(o) = r.as_object_mut() {
            for k in ["operator_seed", "iterations", "tv_weight", "accelerated", "plain", "pnp", "unrolled", "tolerance", "stopping"] {
                o.remove(k);
            }
        }
        r
    };
    std::fs::create_dir_all(&a.out).map_err(|e| Error::File { path: a.out.display().to_string(), message: format!("cannot create: {e}") })?;
    // The marker that makes --out recognisable as a study (resumed by the next run), written first.
    // Each system: where it came from and what it adds to the configuration of its renders and cells.
    let listed: Vec<Value> = systems.iter().map(|s| {
        let mut v = json!({"label": s.label, "folder": s.key, "preset": s.preset, "file": s.file.as_ref().map(|p| p.display().to_string()), "name": s.system.name(), "object_at_infinity": s.system.object_at_infinity()});
        for (k, x) in s.configuration(a.scene_fov_deg) {
            v[k] = x;
        }
        v
    }).collect();
    let mut marker = json!({"command": "study", "version": env!("CARGO_PKG_VERSION"), "configuration": config, "systems": listed});
    if let Some(f) = a.scene_fov_deg {
        marker["scene_fov_deg"] = json!(f);
    }
    write_json(&a.out.join(STUDY_MARKER), &marker)?;
    mask.save_png(&a.out.join("mask.png"))?;
    println!(
        "study: {} scenes {}×{} × {} systems × {} operators × {} solvers = {} cells → {}",
        scenes.len(), a.scene_size, a.scene_size, systems.len(), operators.len(), solvers.len(),
        scenes.len() * systems.len() * operators.len() * solvers.len(), a.out.display()
    );
    let mut computed = 0usize;
    let mut skipped = 0usize;
    for (si, sys) in systems.iter().enumerate() {
        let (system, folder, label) = (&sys.system, &sys.key, &sys.label);
        // This system's configuration: the study's plus its own (a file's spec, an angular extent).
        let (mut config, mut render_key) = (config.clone(), render_key.clone());
        for (k, v) in sys.configuration(a.scene_fov_deg) {
            config[k] = v.clone();
            render_key[k] = v;
        }
        // ---- renders ----
        let dirs: Vec<PathBuf> = scenes.iter().map(|s| a.out.join("renders").join(folder).join(&s.name)).collect();
        let todo: Vec<usize> = (0..scenes.len())
            .filter(|&i| {
                let j = read_json(&dirs[i].join("render.json"));
                let same_scene = j.as_ref().and_then(|j| j.get("scene_sha256")).and_then(Value::as_str) == Some(scenes[i].digest.as_str());
                !(output::outputs_complete(&dirs[i])
                    && same_scene
                    && same_config(j.as_ref().and_then(|j| j.get("study_config")), &render_key)
                    && j.as_ref().is_some_and(|j| output::acquisition_intact(&dirs[i], j)))
            })
            .collect();
        let tr = Instant::now();
        render_scenes(system, &tracer, &cfgs[si], &mask, &scenes, &dirs, &todo, &render_key, budget)?;
        if !todo.is_empty() {
            println!("{}: rendered {} scenes in {:.1} s", label, todo.len(), tr.elapsed().as_secs_f64());
        }
        // ---- cells ----
        let cell_path = |s: &str, op: OperatorKind, solver: &str| a.out.join("cells").join(folder).join(s).join(format!("{}-{solver}.json", op.name()));
        // A cell is done for this configuration and this scene's content.
        let done = |p: &Path, digest: &str| read_json(p).is_some_and(|j| same_config(j.get("config"), &config) && j.get("scene_sha256").and_then(Value::as_str) == Some(digest) && cell_from_json(&j).is_some());
        let record = RenderRecord::load(&dirs[0])?; // all scenes of a system share system, configuration and mask
        for &op_kind in &operators {
            let pending: Vec<(usize, &String)> = scenes.iter().enumerate().flat_map(|(i, s)| solvers.iter().map(move |v| (i, v)).filter(move |(_, v)| !done(&cell_path(&s.name, op_kind, v), &s.digest))).collect();
            skipped += scenes.len() * solvers.len() - pending.len();
            if pending.is_empty() {
                continue;
            }
            // The unrolled network, checked against this system's renders (they share system, bands and mask).
            let unrolled = if pending.iter().any(|(_, v)| is_unrolled(v)) {
                let p = std::sync::Arc::new(crate::recon::pipeline::unrolled::prepare(a.tuning.weights.as_deref(), &record, op_seed)?);
                for w in &p.check.warnings {
                    eprintln!("warning: {}: {w}", label);
                }
                Some(p)
            } else {
                None
            };
            let t_op = Instant::now();
            // (an operator that cannot model this system is refused naming the system file and the operator)
            let op: Box<dyn Operator + '_> = build_operator(op_kind, &record, &tracer, op_seed, budget as u64, &|_| {}).map_err(|e| sys.error(format!("--operators {}: {e}", op_kind.name())))?;
            // The data-driven δ (exact operator, `--noise-estimate spread`): the operator's twin (not for the
            // unrolled network, which has no δ).
            let twin_plan = noise_estimate(&record, op_kind, op_seed, record.config.rays_per_pixel, record.config.rays_per_pixel, cell_settings(&a, &solvers[0]).noise_model).spread;
            let twin: Option<Box<dyn Operator + '_>> = match &twin_plan {
                Some(p) if pending.iter().any(|(_, v)| !is_unrolled(v)) => Some(build_operator(op_kind, &record, &tracer, p.twin_seed, budget as u64, &|_| {})?),
                _ => None,
            };
            let seconds_operator = t_op.elapsed().as_secs_f64();
            let pb = bar(pending.len() as u64, "{msg} [{elapsed_precise}] {wide_bar} {pos}/{len} cells, ETA {eta}", &format!("{} / {}", label, op_kind.name()));
            for (i, solver) in pending {
                let scene = &scenes[i];
                let rec = RenderRecord::load(&dirs[i])?;
                let mut settings = cell_settings(&a, solver);
                if is_unrolled(solver) {
                    settings.unrolled = unrolled.clone();
                }
                let rays = rec.config.rays_per_pixel;
                settings.noise = Some(noise_estimate(&rec, op_kind, op_seed, rays, rays, settings.noise_model));
                let solved = solve(op.as_ref(), &rec.acquisition, &settings, &|_, _| {}, twin.as_deref())?;
                let c = op.cube_shape();
                let estimate = SpectralCube::new(c.height, c.width, bands.clone(), solved.cube, "reconstructed cube")?;
                let ev = evaluate(&scene.cube, &estimate).map_err(|e| Error::invalid(format!("study: scene `{}` ({label}, {}, {solver}): {e}", scene.name, op_kind.name())))?;
                let final_residual = solved.final_residual;
                let rjson = json!({
                    "from": dirs[i].display().to_string(), "system": system.name(), "operator": op_kind.name(), "operator_seed": op_seed,
                    "acquisition_seed": a.seed, "oracle": op_seed == a.seed, "tracer": tracer.name(), "solver": solver, "solver_settings": solved.settings,
                    "shape": {"height": c.height, "width": c.width, "bands": c.bands}, "bands_nm": bands, "residual": solved.residuals,
                    "residual_definition": RESIDUAL_DEFINITION, "final_residual": final_residual, "stopping": solved.stopping, "threads": rayon::current_num_threads(),
                    "seconds_operator": seconds_operator, "seconds_solve": solved.seconds, "seconds": solved.seconds,
                });
                let rdir = a.out.join("recon").join(folder).join(&scene.name).join(format!("{}-{solver}", op_kind.name()));
                let set = crate::io::OutputSet::folder(&rdir, &reconstruction_rule(false), &[])?;
                write_reconstruction(set, &estimate, &rjson, false)?;
                let cell = json!({
                    "config": config, "preset": sys.preset, "system": label, "system_file": sys.file.as_ref().map(|p| p.display().to_string()), "scene": scene.name, "scene_sha256": scene.digest, "operator": op_kind.name(), "solver": solver,
                    "metrics": ev.metrics, "warnings": ev.warnings, "truth_resampled": ev.truth_resampled, "iterations": solved.residuals.len(), "stopped_by": solved.stopping.get("stopped_by"), "final_residual": final_residual,
                    "seconds_solve": solved.seconds, "seconds_operator": seconds_operator, "reconstruction": rdir.strip_prefix(&a.out).unwrap_or(&rdir).display().to_string(),
                });
                write_json(&cell_path(&scene.name, op_kind, solver), &cell)?;
                computed += 1;
                pb.println(format!("{} {} {} {}: PSNR {:.2} dB, SSIM {:.3}, SAM {:.2}°, {:.1} s", label, scene.name, op_kind.name(), solver, ev.metrics.psnr_db, ev.metrics.ssim, ev.metrics.sam_deg, solved.seconds));
                pb.inc(1);
            }
            pb.finish_and_clear();
        }
    }
    // ---- collect every cell of this configuration ----
    let mut cells = Vec::new();
    for sys in &systems {
        for s in &scenes {
            for &op in &operators {
                for v in &solvers {
                    let p = a.out.join("cells").join(&sys.key).join(&s.name).join(format!("{}-{v}.json", op.name()));
                    let c = read_json(&p).and_then(|j| cell_from_json(&j)).ok_or_else(|| Error::File { path: p.display().to_string(), message: "missing or unreadable cell result".into() })?;
                    cells.push(c);
                }
            }
        }
    }
    let labels: Vec<String> = systems.iter().map(|s| s.label.clone()).collect();
    write_tables(&a, &labels, &operators, &solvers, &scenes, &cells, t0.elapsed().as_secs_f64())?;
    println!("study: {computed} cells computed, {skipped} already done; {:.1} s → {}", t0.elapsed().as_secs_f64(), a.out.join("study.md").display());
    Ok(())
}

fn write_tables(a: &StudyArgs, labels: &[String], operators: &[OperatorKind], solvers: &[String], scenes: &[StudyScene], cells: &[Cell], seconds: f64) -> Result<()> {
    // study.csv, through the project's CSV writer (a scene name holding a comma is quoted), its numbers in the
    // writer's shortest round-trip form like every other table: they read back as the cells' own values (they
    // were rounded to 6 decimals, 3 for seconds, before — a held-out battery; the cells' JSON keeps them too).
    let mut csv = crate::io::CsvWriter::new(
        a.out.join("study.csv"),
        &["scene", "system", "preset", "operator", "solver", "psnr_db", "psnr_band_db", "ssim", "sam_rad", "sam_deg", "rmse", "iterations", "final_residual", "seconds_solve", "seconds_operator"],
    )?;
    for c in cells {
        use crate::io::CsvValue::{Int, Str, F64};
        let m = &c.metrics;
        let preset = c.preset.clone().unwrap_or_default();
        csv.row(&[
            Str(&c.scene),
            Str(&c.system),
            Str(&preset),
            Str(&c.operator),
            Str(&c.solver),
            F64(m["psnr_db"]),
            F64(m["psnr_band_db"]),
            F64(m["ssim"]),
            F64(m["sam_rad"]),
            F64(m["sam_deg"]),
            F64(m["rmse"]),
            Int(c.iterations as i64),
            F64(c.residual),
            F64(c.seconds_solve),
            F64(c.seconds_operator),
        ])?;
    }
    csv.finish()?;
    let pick = |system: &str, op: &str, solver: &str, key: &str| -> Vec<f64> { cells.iter().filter(|c| c.system == system && c.operator == op && c.solver == solver).map(|c| c.metrics[key]).collect() };
    let mut md = String::new();
    md.push_str(&format!(
        "# Study: {} scenes ({}×{}), {} systems, operators {}, solvers {}\n\nGenerated by `diffcassi study` ({} s for this invocation; cells computed earlier are reused). Mean ± standard deviation over the scenes. PSNR: paper convention (one MSE over the cube, peak = max of the truth) and MST convention (mean of per-band PSNR, peak 1); SSIM 11×11 Gaussian σ = 1.5, mean over bands; SAM mean spectral angle. Scenes: {}.\n\n",
        scenes.len(), a.scene_size, a.scene_size, labels.len(),
        operators.iter().map(|o| o.name()).collect::<Vec<_>>().join(", "), solvers.join(", "), seconds.round(),
        scenes.iter().map(|s| s.name.as_str()).collect::<Vec<_>>().join(", ")
    ));
    let metric_rows = [("PSNR (dB)", "psnr_db", 2), ("PSNR MST (dB)", "psnr_band_db", 2), ("SSIM", "ssim", 3), ("SAM (°)", "sam_deg", 2), ("RMSE", "rmse", 4)];
    for solver in solvers {
        md.push_str(&format!("## {solver}\n\n| metric | operator | {} |\n|---|---|{}\n", labels.join(" | "), "---|".repeat(labels.len())));
        for (label, key, digits) in metric_rows {
            for op in operators {
                let cols: Vec<String> = labels.iter().map(|p| {
                    let (m, s) = mean_std(&pick(p, op.name(), solver, key));
                    format!("{m:.digits$} ± {s:.digits$}")
                }).collect();
                md.push_str(&format!("| {label} | {} | {} |\n", op.name(), cols.join(" | ")));
            }
        }
        let secs: Vec<String> = labels.iter().map(|p| {
            let v: Vec<f64> = cells.iter().filter(|c| &c.system == p && &c.solver == solver).map(|c| c.seconds_solve).collect();
            format!("{:.1}", mean_std(&v).0)
        }).collect();
        md.push_str(&format!("| solve seconds (mean over operators and scenes) | | {} |\n\n", secs.join(" | ")));
        // Ablation: the simplified model against exact modelling, per scene.
        let base = if operators.contains(&OperatorKind::Exact) { Some("exact") } else { None };
        if let Some(base) = base {
            let others: Vec<&OperatorKind> = operators.iter().filter(|o| o.name() != base).collect();
            if !others.is_empty() {
                md.push_str(&format!("### Ablation ({solver}): PSNR of each model minus PSNR with the exact operator (dB, per scene, mean ± std)\n\n| operator | {} |\n|---|{}\n", labels.join(" | "), "---|".repeat(labels.len())));
                for op in others {
                    let cols: Vec<String> = labels.iter().map(|p| {
                        let d: Vec<f64> = scenes.iter().filter_map(|s| {
                            let get = |o: &str| cells.iter().find(|c| &c.system == p && c.scene == s.name && c.operator == o && &c.solver == solver).map(|c| c.metrics["psnr_db"]);
                            Some(get(op.name())? - get(base)?)
                        }).collect();
                        let (m, sd) = mean_std(&d);
                        format!("{m:+.2} ± {sd:.2}")
                    }).collect();
                    md.push_str(&format!("| {} | {} |\n", op.name(), cols.join(" | ")));
                }
                md.push('\n');
            }
        }
    }
    let plot = a.out.join("study_psnr.png");
    let series: Vec<crate::plot::BarSeries> = operators.iter().map(|op| {
        let (mean, std): (Vec<f64>, Vec<f64>) = labels.iter().map(|p| mean_std(&pick(p, op.name(), &solvers[0], "psnr_db"))).unzip();
        crate::plot::BarSeries { label: op.name().to_string(), mean, std }
    }).collect();
    crate::plot::grouped_bars(&plot, &format!("PSNR by system and forward model ({}, {} scenes {}×{})", solvers[0], scenes.len(), a.scene_size, a.scene_size), "PSNR (dB)", labels, &series)
        .map_err(|e| Error::File { path: plot.display().to_string(), message: e.to_string() })?;
    md.push_str(&format!("![PSNR by system and operator](study_psnr.png)\n\nRows of every cell: `study.csv`. Per-cell results: `cells/`, reconstructions: `recon/`, acquisitions: `renders/`.\n"));
    crate::io::write_atomic(a.out.join("study.md"), md.as_bytes())?;
    Ok(())
}
