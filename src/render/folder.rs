//! The `render` pipeline: one scene rendered into one folder, all or nothing — the acquisition (EXR and a
//! 16-bit preview), the mask, the mapping cube, optional per-band images, and `render.json` ([`super::output`]),
//! with sensor noise and an optional extra pass on the acquisition (ghosts and stray light) on the way. The
//! command line is a client: it chooses the system, the tracer and its rays (`--tolerance-um`), fills a
//! [`RenderRequest`] and shows what [`RenderProgress`] reports; `render-dataset` ([`super::dataset::run`]) is
//! the same render over a folder of scenes.
//!
//! ```no_run
//! use diffcassi::prelude::*;
//! use diffcassi::render::folder::{self, RenderRequest, SceneSource};
//! use diffcassi::render::{settings::RenderSettings, Renderer};
//! let system = SequentialSystem::build(&presets::spec("sp")?)?;
//! let settings = RenderSettings { scene_size: 64, ..RenderSettings::default() };
//! let (mut cfg, mask) = settings.config()?;
//! cfg.rays_per_pixel = 8;
//! let request = RenderRequest::new(SceneSource::Synthetic(0), "out/sp", &settings);
//! folder::check(&request, &[])?; // the output policy, before any work
//! let (scene, record) = folder::load_scene(&request, settings.scene_size)?;
//! let tracer = AnalyticTracer::default();
//! let renderer = Renderer::new(&system, &tracer, cfg, mask)?;
//! let done = folder::run(&request, &[], &renderer, &scene, &record, None, &folder::SilentRender)?;
//! println!("{} rays", done.rays_traced);
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::settings::{Device, RenderSettings};
use super::{output, Acquisition, NoiseConfig, NoiseReport, Renderer};
use crate::error::{Error, Result};
use crate::io::policy::FolderRule;
use crate::scene::{synthetic_scene, synthetic_wavelengths, Fit, SpectralCube};
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The scene a render takes.
#[derive(Clone, Debug, PartialEq)]
pub enum SceneSource {
    /// A scene file: `.exr` (KAIST-style), `.npy` (H, W, B), an RGB `.png` photograph or a folder of per-band PNGs.
    File(PathBuf),
    /// The synthetic demo scene of this seed ([`synthetic_scene`]).
    Synthetic(u64),
}

/// One render into a folder: the scene, where it goes, and what besides the render configuration shapes it.
/// [`RenderRequest::new`] takes the scene options of a [`RenderSettings`] (fit, scene wavelengths, per-band
/// images, device, whether the mapping cube is written) and holds the other defaults (no noise, no `force`).
#[derive(Clone, Debug)]
pub struct RenderRequest {
    pub scene: SceneSource,
    /// Output folder: new, empty, or a previous render's (replaced whole); another folder only with `force`.
    pub out: PathBuf,
    /// Accept an `out` folder that holds other files: the outputs are moved in beside them.
    pub force: bool,
    /// How a scene file is brought to N×N (the synthetic scene is made at N×N).
    pub fit: Fit,
    /// The wavelengths of the scene file's bands (nm), overriding what the file says.
    pub scene_wavelengths_nm: Option<Vec<f64>>,
    /// Also write `cube.exr`: the detector image of each band.
    pub cube: bool,
    /// Write the chief-ray mapping cube (`mapping.npy` and companions).
    pub mapping: bool,
    /// Sensor noise on the acquisition (the per-band images stay clean).
    pub noise: Option<NoiseConfig>,
    pub device: Device,
    /// The error tolerance (µm) that chose the rays per pixel and the precision (`--tolerance-um`), recorded
    /// as render.json's `tolerance_um` (`null`: both as given).
    pub tolerance_um: Option<f64>,
    /// The error (µm) the tolerance's choice predicts ([`crate::fidelity::RenderChoice::error_um`]), recorded
    /// as `tolerance_predicted_error_um` (`null` without a tolerance).
    pub tolerance_predicted_error_um: Option<f64>,
    /// When the request began: `render.json`'s `seconds_total` counts from here (set by [`RenderRequest::new`]).
    pub started: Instant,
}

impl RenderRequest {
    pub fn new(scene: SceneSource, out: impl Into<PathBuf>, settings: &RenderSettings) -> Self {
        RenderRequest {
            scene,
            out: out.into(),
            force: false,
            fit: settings.fit,
            scene_wavelengths_nm: settings.scene_wavelengths_nm.clone(),
            cube: settings.cube,
            mapping: settings.mapping,
            noise: None,
            device: settings.device,
            tolerance_um: None,
            tolerance_predicted_error_um: None,
            started: Instant::now(),
        }
    }

    /// The output folder's rule: `--out` of the `render` command, marked by `render.json`.
    pub fn folder_rule(&self) -> FolderRule<'static> {
        FolderRule { option: "--out", command: "render", marker: "render.json", force: self.force }
    }

    /// The request's own inputs (the scene file), which the output must not touch.
    fn inputs<'a>(&'a self, inputs: &[(&'a str, &'a Path)]) -> Vec<(&'a str, &'a Path)> {
        let mut all = inputs.to_vec();
        if let SceneSource::File(p) = &self.scene {
            all.push(("--scene", p.as_path()));
        }
        all
    }
}

/// Check the request before any work: options that do not apply to the synthetic scene, and the output
/// policy (`out` new, empty or a previous render, or `force`; never one of `inputs` — the system and mask
/// files — nor the scene). [`run`] checks both again; a client calls this first, before a long calibration.
pub fn check(request: &RenderRequest, inputs: &[(&str, &Path)]) -> Result<()> {
    check_scene_options(request)?;
    crate::io::policy::check_out_folder(&request.out, &request.folder_rule(), &request.inputs(inputs))?;
    Ok(())
}

/// The options that apply to a scene file only, refused for the synthetic scene.
fn check_scene_options(request: &RenderRequest) -> Result<()> {
    if matches!(request.scene, SceneSource::Synthetic(_)) {
        if request.scene_wavelengths_nm.is_some() {
            // Accepted and ignored before: the synthetic scene has its own 31 bands.
            return Err(Error::invalid("--scene-wavelengths applies to a --scene file, not to the synthetic scene"));
        }
        if request.fit != Fit::Crop {
            // Accepted and ignored before (the synthetic scene is made at N×N); `study` refuses it alike.
            return Err(Error::invalid(format!("--fit {}: brings a --scene file to N×N; the synthetic scene is made at N×N", request.fit.name())));
        }
    }
    Ok(())
}

/// The scene at `size`×`size` and its record for `render.json`'s `scene` (a file: read, fitted and checked;
/// the synthetic scene: made). Clients load it before a long tracer calibration, so a bad scene fails first.
pub fn load_scene(request: &RenderRequest, size: usize) -> Result<(SpectralCube, Value)> {
    match &request.scene {
        SceneSource::File(p) => super::dataset::load_fitted(p, size, request.scene_wavelengths_nm.as_deref(), request.fit),
        &SceneSource::Synthetic(seed) => {
            Ok((synthetic_scene(size, size, &synthetic_wavelengths(), seed), serde_json::json!({"source": "synthetic", "synthetic_seed": seed, "native_wavelengths_nm": synthetic_wavelengths()})))
        }
    }
}

/// A pass over the finished acquisition before the sensor noise (ghosts and stray light: the command line's
/// `--ghosts`); it adds its light to `acq` and returns its record for `render.json` (`ghosts`).
pub trait AcquisitionPass {
    fn run(&self, renderer: &Renderer, scene: &SpectralCube, acq: &mut Acquisition) -> Result<Value>;
}

/// What a client shows while a scene renders; every method does nothing by default ([`SilentRender`]).
pub trait RenderProgress: Sync {
    /// A warning for the user (spectral extrapolation, a zero acquisition).
    fn warning(&self, _text: &str) {}
    /// `rays` rays are being traced; [`RenderProgress::rays`] counts them, [`RenderProgress::tracing_done`] ends.
    fn tracing_started(&self, _rays: u64) {}
    fn rays(&self, _n: u64) {}
    fn tracing_done(&self) {}
    /// The sensor `noise` was applied; `report` says what it did.
    fn noise(&self, _noise: &NoiseConfig, _report: &NoiseReport) {}
}

/// No progress reports.
pub struct SilentRender;

impl RenderProgress for SilentRender {}

/// What a render did.
#[derive(Clone, Debug)]
pub struct RenderSummary {
    /// The folder written (the request's `out`).
    pub out: PathBuf,
    /// `render.json` as written.
    pub record: Value,
    pub rays_traced: u64,
    /// Seconds of the render itself, and of the whole request.
    pub render_seconds: f64,
    pub total_seconds: f64,
    /// Detector size (pixels).
    pub detector_width: usize,
    pub detector_height: usize,
    /// Fraction of the traced rays that reached the detector.
    pub transmission: f64,
}

/// Apply `noise` (if any) to `acq` and its record for `render.json` (`null` without noise): one place for
/// `render` and `render-dataset`.
pub fn apply_noise(noise: Option<&NoiseConfig>, acq: &mut Acquisition, progress: &dyn RenderProgress) -> Result<Value> {
    let Some(nc) = noise else { return Ok(Value::Null) };
    let report = nc.apply(&mut acq.image)?;
    progress.noise(nc, &report);
    // An exposure of less than one electron in the brightest pixel draws (almost) nothing: say so, rather than
    // blame the scene for the zeros (`--electrons-per-unit 1e-300` wrote all-zero acquisitions, exit 0; a
    // held-out battery, round 9).
    if report.clean_peak > 0.0 && report.peak_electrons < 1.0 {
        let zeros = if acq.is_zero() { ": the noisy acquisition is zero everywhere" } else { "" };
        progress.warning(&format!(
            "the exposure puts {:.3e} e⁻ in the brightest pixel (< 1 electron; {:.3e} electrons per unit){zeros}: raise --electrons-per-unit",
            report.peak_electrons,
            report.electrons_per_unit
        ));
    }
    Ok(nc.to_json(&report))
}

/// What a render says beside its acquisition, in the order the front ends say it — planes beyond the scene's
/// bands, the GPU's fixed-point resolution, a dual disperser's dark planes, the f32 kernel's measured
/// rounding — as warnings, and the render.json fields that record them (`spectral_extrapolation`,
/// `mask_dark_planes`, `f32_chief_ray_error`). The CLI's folder, Python's `render` and C++'s
/// `RenderInfo::warnings` say the same ([`zero_warning`], after the noise, besides).
pub fn render_notes(renderer: &Renderer, scene: &SpectralCube, device: Option<&super::device::DeviceRecord>) -> Result<(Vec<String>, serde_json::Map<String, Value>)> {
    let (mut warnings, mut fields) = (Vec::new(), serde_json::Map::new());
    if let Some(x) = renderer.spectral_extrapolation(scene) {
        warnings.push(x.message());
        fields.insert("spectral_extrapolation".into(), x.to_json());
    }
    warnings.extend(device.and_then(|d| d.fixed_point_warning.clone()));
    if let Some(d) = renderer.mask_dark_planes()? {
        warnings.push(d.message());
        fields.insert("mask_dark_planes".into(), d.to_json());
    }
    if let Some(f) = renderer.f32_chief_ray_error()? {
        warnings.extend(f.message());
        fields.insert("f32_chief_ray_error".into(), f.to_json());
    }
    Ok((warnings, fields))
}

/// The warning a zero acquisition gets (it is written — it is what the system delivers — but nothing
/// reconstructs from it), naming why; `noise` is its noise record ([`apply_noise`]). `None` for an acquisition
/// with light, or one the sensor noise zeroed at an exposure below an electron ([`apply_noise`] said so).
pub fn zero_warning(acq: &Acquisition, noise: &Value) -> Option<String> {
    let positive = |key: &str| noise[key].as_f64().is_some_and(|v| v > 0.0);
    let said = positive("clean_peak") && noise["peak_electrons"].as_f64().is_some_and(|p| p < 1.0);
    if !acq.is_zero() || said {
        return None;
    }
    let why = if positive("clean_total") {
        "the sensor noise drew no electron in any pixel"
    } else if acq.stats.traced == 0 {
        "no ray was traced: the mask is closed everywhere"
    } else if acq.stats.transmission() > 0.0 {
        "rays arrived, but the scene is dark where they came from"
    } else {
        "no ray delivered light to the detector: render.json's ray_stats say where they went"
    };
    Some(format!("the acquisition is zero everywhere ({why})"))
}

/// Render `scene` (with its `scene_record`, from [`load_scene`]) through `renderer` into the request's folder:
/// the render on the request's device, the `pass` (ghosts), the sensor noise, then every file written in a
/// staging folder that replaces `out` whole at the end (nothing is left half-written). `inputs` are the files
/// the output must not touch besides the scene (the system's and the mask's).
pub fn run(request: &RenderRequest, inputs: &[(&str, &Path)], renderer: &Renderer, scene: &SpectralCube, scene_record: &Value, pass: Option<&dyn AcquisitionPass>, progress: &dyn RenderProgress) -> Result<RenderSummary> {
    // The output policy is checked by the set itself (OutputSet::folder), as `check` checks it.
    check_scene_options(request)?;
    let set = crate::io::OutputSet::folder(&request.out, &request.folder_rule(), &request.inputs(inputs))?;
    progress.tracing_started(renderer.rays_per_render());
    let rendered = super::device::render_for(request.device, renderer, scene, request.cube, &|k| progress.rays(k));
    progress.tracing_done();
    let (mut acq, device_record) = rendered?;
    // Ghost and stray light (off by default): added to the acquisition before the sensor noise.
    let ghosts = match pass {
        Some(p) => p.run(renderer, scene, &mut acq)?,
        None => Value::Null,
    };
    let noise = apply_noise(request.noise.as_ref(), &mut acq, progress)?;
    let mut extra = serde_json::json!({"noise": noise, "tolerance_um": request.tolerance_um, "tolerance_predicted_error_um": request.tolerance_predicted_error_um});
    let (warnings, fields) = render_notes(renderer, scene, device_record.as_ref())?;
    for w in &warnings {
        progress.warning(w);
    }
    for (k, v) in fields {
        extra[k] = v;
    }
    if !ghosts.is_null() {
        extra["ghosts"] = ghosts;
    }
    let record = write_folder(set.stage_dir().unwrap_or(&request.out), renderer, &acq, device_record.as_ref(), scene_record, request.started, extra, request.mapping)?;
    set.commit()?;
    if let Some(w) = zero_warning(&acq, &noise) {
        progress.warning(&w);
    }
    Ok(RenderSummary {
        out: request.out.clone(),
        record,
        rays_traced: acq.stats.traced,
        render_seconds: acq.timings.wall_seconds,
        total_seconds: request.started.elapsed().as_secs_f64(),
        detector_width: acq.detector.width,
        detector_height: acq.detector.height,
        transmission: acq.stats.transmission(),
    })
}

/// Write a render's files into `dir`: images, mask, mapping cube (if asked), then `render.json` (last) with
/// `extra` merged in. Every value is checked finite before the first file.
fn write_folder(dir: &Path, renderer: &Renderer, acq: &Acquisition, device: Option<&super::device::DeviceRecord>, scene: &Value, started: Instant, extra: Value, mapping: bool) -> Result<Value> {
    std::fs::create_dir_all(dir).map_err(|e| Error::File { path: dir.display().to_string(), message: format!("cannot create: {e}") })?;
    crate::limits::check_finite_array("acquisition image", acq.image.iter().copied())?;
    crate::limits::check_finite_array("acquisition image (float32)", acq.image.iter().map(|&v| v as f32 as f64))?;
    let scale = output::write_images(dir, renderer, acq)?;
    renderer.mask.save_png(&dir.join("mask.png"))?;
    if mapping {
        output::write_mapping(dir, renderer)?;
    }
    let mut json = output::sidecar(renderer, acq, device, scene, scale, started.elapsed().as_secs_f64(), rayon::current_num_threads());
    if let (Some(o), Value::Object(e)) = (json.as_object_mut(), extra) {
        o.extend(e);
    }
    crate::limits::check_json_finite("render.json", &json)?;
    output::write_sidecar(dir, &json)?;
    Ok(json)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::prelude::*;

    fn tiny(out: &Path) -> (RenderRequest, RenderSettings) {
        let settings = RenderSettings { scene_size: 12, bands_nm: vec![500.0, 550.0, 600.0], planes: 3, rays: Some(2), airy_diameter_px: None, ..RenderSettings::default() };
        (RenderRequest::new(SceneSource::Synthetic(3), out, &settings), settings)
    }

    #[test]
    fn a_render_writes_a_whole_folder_that_reads_back() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("r");
        let (request, settings) = tiny(&out);
        let system = SequentialSystem::build(&crate::presets::spec("sp").unwrap()).unwrap();
        let (mut cfg, mask) = settings.config().unwrap();
        cfg.rays_per_pixel = 2;
        let tracer = AnalyticTracer::default();
        let renderer = Renderer::new(&system, &tracer, cfg, mask).unwrap();
        let (scene, record) = load_scene(&request, 12).unwrap();
        let done = run(&request, &[], &renderer, &scene, &record, None, &SilentRender).unwrap();
        assert!(output::outputs_complete(&out));
        assert!(out.join("mapping.npy").is_file() && out.join("mask.png").is_file());
        assert_eq!(done.record["scene"]["synthetic_seed"], 3);
        assert!(done.record["noise"].is_null());
        assert!(output::acquisition_intact(&out, &done.record));
        assert_eq!(done.rays_traced, done.record["ray_stats"]["traced"].as_u64().unwrap());
        // The same request again replaces the folder whole (a previous render), with the same acquisition.
        let again = run(&request, &[], &renderer, &scene, &record, None, &SilentRender).unwrap();
        assert_eq!(again.record["acquisition_f32le_sha256"], done.record["acquisition_f32le_sha256"]);
    }

    #[test]
    fn synthetic_scene_options_and_other_folders_are_refused_before_any_work() {
        let dir = tempfile::tempdir().unwrap();
        let (mut request, _) = tiny(&dir.path().join("r"));
        request.fit = Fit::Resize;
        assert!(check(&request, &[]).unwrap_err().to_string().contains("--fit resize"));
        request.fit = Fit::Crop;
        request.scene_wavelengths_nm = Some(vec![500.0]);
        assert!(check(&request, &[]).unwrap_err().to_string().contains("--scene-wavelengths"));
        request.scene_wavelengths_nm = None;
        std::fs::create_dir_all(dir.path().join("r")).unwrap();
        std::fs::write(dir.path().join("r/notes.txt"), "mine").unwrap();
        let e = check(&request, &[]).unwrap_err().to_string();
        assert!(e.contains("--out"), "{e}");
        assert_eq!(std::fs::read_to_string(dir.path().join("r/notes.txt")).unwrap(), "mine");
    }
}
