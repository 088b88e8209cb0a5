//! `reconstruct`: a render folder's acquisition back to the hyperspectral cube.
//!
//! ```text
//! diffcassi render --preset sp --scene data/scenes/coffee.png --fit resize --scene-size 128 --out out/sp-coffee
//! diffcassi reconstruct --from out/sp-coffee --operator exact --solver gap-tv --iterations 100 --out out/sp-coffee-rec
//! diffcassi reconstruct --from out/sp-coffee --operator shift --out out/sp-coffee-shift     # the field's simplified model
//! diffcassi reconstruct --from out/sp-coffee --operator exact --operator-seed same --out out/oracle
//! ```
//!
//! Everything comes from the render folder: the system (`render.json`'s `system_spec`), the render
//! configuration (scene size and pitch, bands, planes, rays, sampling, Airy blur, detector pitch), the mask
//! (`mask.png`, the file the render wrote) and the acquisition (`acquisition.exr`). The operator is rebuilt
//! from them; for `exact` with a *different* ray seed by default (acquisition seed + 1: a model never knows the
//! Monte-Carlo noise of the measurement); `--operator-seed same` gives the oracle. Outputs, all written into
//! a temporary sibling folder that is renamed into place only when complete: `cube.npy` (H, W, B) float32 +
//! `cube_wavelengths_nm.npy`, `cube.exr` (one channel per band), `rgb.png` (sRGB preview: CIE 1931 under
//! D65, [`crate::scene::colorimetry`]) and `reconstruct.json` (settings, per-iteration residual, seconds,
//! `stopping`: the rule, the noise estimate δ of [`noise_estimate`], the cap, the iteration and the reason
//! it stopped). `--truth CUBE` adds the PSNR of every iterate (evaluation only; docs/reconstruction.md,
//! "Defaults and stopping").
use super::args::BackendArgs;
use crate::error::{Error, Result};
use crate::recon::{ExactOperator, MappingInterpolation, MappingOperator, Operator, ShiftOperator, SolverConfig, SolverKind};
use crate::render::{AiryConfig, Mask, RenderConfig, Renderer, Sampling, SpectralSampling};
use crate::scene::{colorimetry, save_exr, save_npy, SpectralCube};
use crate::system::SequentialSystem;
use crate::tracer::Tracer;
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Args, Debug, Clone)]
pub struct ReconstructArgs {
    /// Render folder (with render.json, acquisition.exr, mask.png).
    #[arg(long = "from")]
    pub from: PathBuf,
    /// Forward model: exact (the renderer's transport), mapping (chief-ray mapping, bilinear),
    /// mapping-nearest, shift (the field's simplified SD-CASSI model).
    #[arg(long, default_value = "exact")]
    pub operator: String,
    /// Solver: gap-tv, admm-tv, pnp-gap or pnp-admm (plug-and-play with the learned denoiser).
    #[arg(long, default_value = "gap-tv")]
    pub solver: String,
    #[command(flatten)]
    pub tuning: SolverTuning,
    /// Ray seed of the exact operator: a number, or `same` (the acquisition's: the oracle)
    /// [default: acquisition seed + 1].
    #[arg(long = "operator-seed")]
    pub operator_seed: Option<String>,
    /// Rays per scene pixel per plane of the exact operator [default: the acquisition's]. More rays than the
    /// acquisition approach the expected transport (less Monte-Carlo mismatch, more memory and tracing).
    #[arg(long = "operator-rays")]
    pub operator_rays: Option<usize>,
    /// Keep the exact operator's light transport in memory up to this size (GB); beyond it, re-trace on the fly.
    #[arg(long = "transport-memory-gb", default_value_t = 4.0)]
    pub transport_memory_gb: f64,
    /// Evaluation only: the true cube (.npy with its wavelengths file, as `evaluate --truth`); records the
    /// PSNR of every iterate and ‖y − Φx_true‖/‖y‖ in reconstruct.json `stopping` (the solver never sees it).
    #[arg(long)]
    pub truth: Option<PathBuf>,
    #[command(flatten)]
    pub backend: BackendArgs,
    /// Output folder: new, empty, or a previous reconstruction (replaced whole); never --from, inside it or
    /// containing it.
    #[arg(long)]
    pub out: PathBuf,
    /// Accept an --out folder that holds other files (not a previous reconstruction): the outputs are moved
    /// in beside them, nothing else there is touched (docs/robustness.md, "Output policy").
    #[arg(long)]
    pub force: bool,
}

/// The forward models `--operator` names.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OperatorKind {
    Exact,
    Mapping(MappingInterpolation),
    Shift,
}

impl OperatorKind {
    pub fn parse(s: &str) -> Result<Self> {
        match s.trim() {
            "exact" => Ok(OperatorKind::Exact),
            "mapping" | "mapping-bilinear" => Ok(OperatorKind::Mapping(MappingInterpolation::Bilinear)),
            "mapping-nearest" => Ok(OperatorKind::Mapping(MappingInterpolation::Nearest)),
            "shift" => Ok(OperatorKind::Shift),
            other => Err(Error::invalid(format!("--operator `{other}`: use exact, mapping, mapping-nearest or shift"))),
        }
    }
    pub fn name(&self) -> &'static str {
        match self {
            OperatorKind::Exact => "exact",
            OperatorKind::Mapping(MappingInterpolation::Bilinear) => "mapping",
            OperatorKind::Mapping(MappingInterpolation::Nearest) => "mapping-nearest",
            OperatorKind::Shift => "shift",
        }
    }
}

/// A render folder read back: what `render` wrote, checked for consistency.
pub struct RenderRecord {
    pub dir: PathBuf,
    pub json: Value,
    pub system: SequentialSystem,
    pub config: RenderConfig,
    pub mask: Mask,
    /// The acquisition (detector image, row-major f32).
    pub acquisition: Vec<f32>,
    pub detector_height: usize,
    pub detector_width: usize,
    /// The tracer `render` used (render.json `tracer`).
    pub tracer_name: String,
}

fn ferr(path: &Path, m: impl Into<String>) -> Error {
    Error::File { path: path.display().to_string(), message: m.into() }
}

/// Field `name` of `json` (`name` may be a dotted path for messages, `airy.rings`: its last part is the key).
fn field<'a>(json: &'a Value, path: &Path, name: &str) -> Result<&'a Value> {
    let key = name.rsplit('.').next().unwrap_or(name);
    json.get(key).filter(|v| !v.is_null()).ok_or_else(|| ferr(path, format!("field `{name}` is missing")))
}

fn field_f64(json: &Value, path: &Path, name: &str) -> Result<f64> {
    let v = field(json, path, name)?;
    v.as_f64().filter(|v| v.is_finite()).ok_or_else(|| ferr(path, format!("field `{name}` = {v} is not a finite number")))
}

fn field_usize(json: &Value, path: &Path, name: &str) -> Result<usize> {
    let v = field(json, path, name)?;
    v.as_u64().and_then(|x| usize::try_from(x).ok()).ok_or_else(|| ferr(path, format!("field `{name}` = {v} is not a non-negative integer")))
}

impl RenderRecord {
    /// Read `dir/render.json`, `dir/mask.png` and `dir/acquisition.exr` and rebuild the system and configuration.
    pub fn load(dir: &Path) -> Result<Self> {
        if !dir.is_dir() {
            return Err(ferr(dir, "not a render folder (no such folder)"));
        }
        let jp = dir.join("render.json");
        if !jp.is_file() {
            return Err(ferr(&jp, "missing: not a (complete) render folder — run `diffcassi render --out` first"));
        }
        let text = std::fs::read_to_string(&jp).map_err(|e| ferr(&jp, format!("cannot read: {e}")))?;
        let json: Value = serde_json::from_str(&text).map_err(|e| ferr(&jp, format!("not valid JSON: {e}")))?;
        let spec: crate::spec::SystemSpec = serde_json::from_value(field(&json, &jp, "system_spec")?.clone()).map_err(|e| ferr(&jp, format!("field `system_spec`: {e}")))?;
        let mut catalog = crate::materials::GlassCatalog::builtin();
        for p in &spec.glass_catalogs {
            catalog.merge(crate::materials::GlassCatalog::from_agf_file(Path::new(p))?);
        }
        let system = SequentialSystem::build_with_catalog(&spec, &catalog)?;
        // Every field is checked against the limits `render` applies, naming the field and its value, and the
        // memory is estimated, before anything is allocated (a tampered render.json cannot abort the process).
        let h = field_usize(&json, &jp, "scene_height")?;
        let w = field_usize(&json, &jp, "scene_width")?;
        if h == 0 || w == 0 {
            return Err(ferr(&jp, format!("scene size {h}×{w} is empty")));
        }
        let bands: Vec<f64> = serde_json::from_value(field(&json, &jp, "bands_nm")?.clone()).map_err(|e| ferr(&jp, format!("field `bands_nm`: {e}")))?;
        let (lo, hi) = crate::limits::WAVELENGTH_RANGE_NM;
        if bands.is_empty() || bands.len() > crate::limits::MAX_WAVELENGTHS {
            return Err(ferr(&jp, format!("field `bands_nm` has {} bands: must be in 1..={}", bands.len(), crate::limits::MAX_WAVELENGTHS)));
        }
        if let Some((k, b)) = bands.iter().enumerate().find(|(_, b)| !(lo..=hi).contains(*b)) {
            return Err(ferr(&jp, format!("field `bands_nm`: band {k} = {} nm is outside {lo}–{hi} nm", crate::limits::fmt_num(*b))));
        }
        let planes = field_usize(&json, &jp, "planes")?;
        if planes == 0 || planes > crate::limits::MAX_PLANES {
            return Err(ferr(&jp, format!("field `planes` = {planes}: must be in 1..={} (the limit of render --planes)", crate::limits::MAX_PLANES)));
        }
        let rays_per_pixel = field_usize(&json, &jp, "rays_per_pixel")?;
        if rays_per_pixel == 0 {
            return Err(ferr(&jp, "field `rays_per_pixel` = 0: must be ≥ 1"));
        }
        let airy = match json.get("airy") {
            None | Some(Value::Null) => None,
            Some(a) => {
                let airy = AiryConfig { diameter_px: field_f64(a, &jp, "airy.diameter_px")?, reference_nm: field_f64(a, &jp, "airy.reference_nm")?, rings: field_usize(a, &jp, "airy.rings")? };
                airy.validate().map_err(|e| ferr(&jp, format!("field {e}")))?;
                Some(airy)
            }
        };
        let scene_pitch_mm = field_f64(&json, &jp, "scene_pitch_mm")?;
        let detector_pitch_mm = match json.get("detector_pitch_mm") {
            None | Some(Value::Null) => scene_pitch_mm,
            Some(_) => field_f64(&json, &jp, "detector_pitch_mm")?,
        };
        for (name, v) in [("scene_pitch_mm", scene_pitch_mm), ("detector_pitch_mm", detector_pitch_mm)] {
            if !(v > 0.0 && v <= crate::limits::MAX_LENGTH_MM) {
                return Err(ferr(&jp, format!("field `{name}` = {} mm: must be > 0 and ≤ {:e} mm", crate::limits::fmt_num(v), crate::limits::MAX_LENGTH_MM)));
            }
        }
        let detector_extra_px = match json.get("detector_extra_px") {
            None | Some(Value::Null) => 0,
            Some(_) => field_usize(&json, &jp, "detector_extra_px")?,
        };
        if detector_extra_px > u16::MAX as usize {
            return Err(ferr(&jp, format!("field `detector_extra_px` = {detector_extra_px}: must be ≤ {} (a detector side is at most 65535 pixels)", u16::MAX)));
        }
        let det = field(&json, &jp, "detector")?;
        let (dh, dw) = (field_usize(det, &jp, "detector.height")?, field_usize(det, &jp, "detector.width")?);
        if dh == 0 || dw == 0 || dh > u16::MAX as usize || dw > u16::MAX as usize {
            return Err(ferr(&jp, format!("field `detector` is {dh}×{dw} pixels: each side must be in 1..=65535")));
        }
        let n = ((h as f64) * (w as f64)).sqrt().ceil() as usize;
        let what = format!("scene_height × scene_width × planes ({h} × {w} × {planes}, {} bands)", bands.len());
        crate::limits::check_memory(&what, crate::limits::bytes_render(n, bands.len(), bands.len(), planes, false, airy.map(|a| a.diameter_px)) + dh as f64 * dw as f64 * 8.0).map_err(|e| ferr(&jp, e.to_string()))?;
        let spectral = SpectralSampling::with_planes(bands, planes).map_err(|e| ferr(&jp, format!("fields `bands_nm`/`planes`: {e}")))?;
        if let Some(recorded) = json.get("planes_nm").and_then(|v| serde_json::from_value::<Vec<f64>>(v.clone()).ok()) {
            if recorded.len() != spectral.planes() || recorded.iter().zip(&spectral.planes_nm).any(|(a, b)| (a - b).abs() > 1e-9) {
                return Err(ferr(&jp, "field `planes_nm` does not match the planes rebuilt from `bands_nm` and `planes`"));
            }
        }
        let mut cfg = RenderConfig::paper(h);
        cfg.scene_height = h;
        cfg.scene_width = w;
        cfg.scene_pitch_mm = scene_pitch_mm;
        cfg.detector_pitch_mm = detector_pitch_mm;
        cfg.detector_extra_px = detector_extra_px;
        cfg.force_batched = json.get("force_batched").and_then(Value::as_bool).unwrap_or(false);
        cfg.spectral = spectral;
        cfg.rays_per_pixel = rays_per_pixel;
        cfg.seed = field(&json, &jp, "seed")?.as_u64().ok_or_else(|| ferr(&jp, "field `seed` is not a non-negative integer"))?;
        cfg.sampling = serde_json::from_value::<Sampling>(field(&json, &jp, "sampling")?.clone()).map_err(|e| ferr(&jp, format!("field `sampling`: {e}")))?;
        cfg.airy = airy;
        let mask_name = json.get("mask_file").and_then(Value::as_str).unwrap_or("mask.png");
        let mask_path = dir.join(mask_name);
        if !mask_path.is_file() {
            return Err(ferr(&mask_path, "missing: the render folder's mask is needed to rebuild the operator"));
        }
        let mut mask = Mask::load(&mask_path)?;
        if (mask.height, mask.width) != (h, w) {
            return Err(ferr(&mask_path, format!("the mask is {}×{} but the scene (render.json) is {h}×{w}", mask.height, mask.width)));
        }
        if let Some(d) = json.get("mask").and_then(Value::as_str) {
            mask.description = d.to_string();
        }
        let ap = dir.join("acquisition.exr");
        if !ap.is_file() {
            return Err(ferr(&ap, "missing: the render folder has no acquisition"));
        }
        let img = crate::io::exr::read_exr(&ap)?;
        let ch = img.channels.iter().find(|c| c.name == "Y").or(img.channels.first()).ok_or_else(|| ferr(&ap, "no channel"))?;
        if let Some(i) = ch.data.iter().position(|v| !v.is_finite()) {
            return Err(ferr(&ap, format!("pixel {} (row {}, col {}) is {} (not finite)", i, i / img.width, i % img.width, ch.data[i])));
        }
        // The solvers work in f32: an acquisition beyond the scene radiance limit would overflow their sums
        // (and end as "a non-finite value"); refuse it up front, naming the pixel, the value and the limit.
        if let Some(i) = ch.data.iter().position(|v| v.abs() as f64 > crate::limits::MAX_SCENE_VALUE) {
            return Err(ferr(
                &ap,
                format!(
                    "pixel (row {}, col {}) = {}: acquisition values must be within ±{:.3e} (f32 range / 10⁹, the scene radiance limit) so that the reconstruction's f32 sums cannot overflow; rescale the acquisition",
                    i / img.width,
                    i % img.width,
                    crate::limits::fmt_num(ch.data[i] as f64),
                    crate::limits::MAX_SCENE_VALUE
                ),
            ));
        }
        if (img.height, img.width) != (dh, dw) {
            return Err(ferr(&ap, format!("the acquisition is {}×{} but render.json's detector is {dh}×{dw}", img.height, img.width)));
        }
        let tracer_name = json.get("tracer").and_then(Value::as_str).unwrap_or("analytic-f64").to_string();
        Ok(RenderRecord { dir: dir.to_path_buf(), acquisition: ch.data.clone(), json, system, config: cfg, mask, detector_height: dh, detector_width: dw, tracer_name })
    }

    /// The bands the cube is reconstructed at (the render's bands).
    pub fn bands_nm(&self) -> &[f64] {
        &self.config.spectral.bands_nm
    }

    /// A renderer with the recorded configuration and `seed`, checked to have the recorded detector.
    pub fn renderer<'a>(&'a self, tracer: &'a dyn Tracer, seed: u64) -> Result<Renderer<'a>> {
        let mut cfg = self.config.clone();
        cfg.seed = seed;
        let r = Renderer::new(&self.system, tracer, cfg, self.mask.clone())?;
        if (r.detector.height, r.detector.width) != (self.detector_height, self.detector_width) {
            return Err(ferr(&self.dir.join("render.json"), format!("the rebuilt detector is {}×{} but the render's is {}×{}: the folder does not match this diffcassi version or tracer", r.detector.height, r.detector.width, self.detector_height, self.detector_width)));
        }
        Ok(r)
    }
}

/// The exact operator's ray seed: `None` → acquisition seed + 1, `same` → the acquisition's, or a number.
pub fn operator_seed(acquisition_seed: u64, given: Option<&str>) -> Result<u64> {
    match given.map(str::trim) {
        None => Ok(acquisition_seed.wrapping_add(1)),
        Some("same") => Ok(acquisition_seed),
        Some(s) => s.parse::<u64>().map_err(|_| Error::invalid(format!("--operator-seed `{s}`: a non-negative integer or `same`"))),
    }
}

/// The tracer: `--backend` if given, else the one the render recorded (analytic when it cannot be parsed).
pub fn record_tracer(record: &RenderRecord, backend: &BackendArgs) -> Result<Box<dyn Tracer>> {
    if backend.backend.is_some() || backend.refine.is_some() || backend.mesh_max_sag_um.is_some() || backend.mesh_segments.is_some() {
        return super::shared::make_tracer(backend);
    }
    let cfg: crate::tracer::BackendConfig = record.tracer_name.parse().unwrap_or_else(|_| "analytic".parse().expect("analytic parses"));
    cfg.build()
}

/// Build the operator `kind` for the record (exact: traced with `seed`, transport kept up to `budget_bytes`).
pub fn build_operator<'a>(kind: OperatorKind, record: &'a RenderRecord, tracer: &'a dyn Tracer, seed: u64, budget_bytes: u64, progress: &(dyn Fn(u64) + Sync)) -> Result<Box<dyn Operator + 'a>> {
    if kind == OperatorKind::Exact {
        // The exact operator traces what the render traced: the same ray budget (`--max-rays`).
        let c = &record.config;
        let what = format!("scene_height × scene_width × planes × rays_per_pixel ({} × {} × {} × {})", c.scene_height, c.scene_width, c.spectral.planes(), c.rays_per_pixel);
        crate::limits::check_rays(&what, c.scene_height as f64 * c.scene_width as f64 * c.spectral.planes() as f64 * c.rays_per_pixel as f64).map_err(|e| ferr(&record.dir.join("render.json"), e.to_string()))?;
    }
    let renderer = record.renderer(tracer, seed)?;
    let bands = record.bands_nm().to_vec();
    Ok(match kind {
        OperatorKind::Exact => Box::new(ExactOperator::with_progress(renderer, &bands, budget_bytes, progress)?),
        OperatorKind::Mapping(interp) => Box::new(MappingOperator::from_renderer(&renderer, &bands, interp)?),
        OperatorKind::Shift => Box::new(ShiftOperator::from_renderer(&renderer, &bands)?),
    })
}

/// The output policy of a reconstruction folder: new, empty, a previous reconstruction (it holds
/// `reconstruct.json`) or, with `force`, a folder of other files ([`crate::io::policy`]).
pub fn reconstruction_rule(force: bool) -> crate::io::policy::FolderRule<'static> {
    crate::io::policy::FolderRule { option: "--out", command: "reconstruct", marker: "reconstruct.json", force }
}

/// Write a reconstruction folder all or nothing through `set` (an [`OutputSet::folder`](crate::io::OutputSet)
/// made with [`reconstruction_rule`] before the work): everything goes into its staging folder, which replaces
/// `out` when complete. `exr`: also write `cube.exr`.
pub fn write_reconstruction(set: crate::io::OutputSet, cube: &SpectralCube, json: &Value, exr: bool) -> Result<()> {
    let tmp = set.stage_dir().ok_or_else(|| Error::invalid("write_reconstruction needs a folder output set"))?.to_path_buf();
    save_npy(cube, &tmp.join("cube.npy"))?;
    if exr {
        save_exr(cube, &tmp.join("cube.exr"))?;
    }
    colorimetry::save_srgb_png(cube, 1.0, &tmp.join("rgb.png"))?;
    let text = serde_json::to_string_pretty(json).map_err(|e| Error::invalid(format!("JSON encoding failed: {e}")))?;
    crate::io::write_atomic(tmp.join("reconstruct.json"), text.as_bytes())?;
    set.commit()?;
    Ok(())
}

fn iteration_bar(n: u64, what: &str) -> ProgressBar {
    let pb = ProgressBar::new(n);
    pb.set_style(ProgressStyle::with_template("{msg} [{elapsed_precise}] {wide_bar} {pos}/{len} iterations, ETA {eta}").unwrap_or_else(|_| ProgressStyle::default_bar()));
    pb.set_message(what.to_string());
    pb
}

/// The solver options `reconstruct` and `study` share (one definition, so their flags and help agree).
#[derive(Args, Debug, Clone)]
pub struct SolverTuning {
    /// Iterations [default: the solver's].
    #[arg(long)]
    pub iterations: Option<usize>,
    /// TV weight [default: the solver's].
    #[arg(long = "tv-weight")]
    pub tv_weight: Option<f64>,
    /// GAP-TV / PnP-GAP: the accelerated variant (Liao/Yuan) — their default since the measured defaults
    /// (docs/reconstruction.md, "Defaults and stopping"); kept so older commands keep working.
    #[arg(long)]
    pub accelerated: bool,
    /// GAP-TV / PnP-GAP: plain GAP instead of the accelerated default (the former default).
    #[arg(long, conflicts_with = "accelerated")]
    pub plain: bool,
    /// pnp-gap / pnp-admm: the denoiser's weights (safetensors, arch spectral-unet-v2) [default: the
    /// embedded checkpoint].
    #[arg(long)]
    pub denoiser: Option<PathBuf>,
    /// pnp-gap / pnp-admm: σ of the first network denoising (relative to the cube's peak, in (0, 1]); with
    /// --sigma-auto the ceiling of σ_1 [default 0.2].
    #[arg(long = "sigma-max")]
    pub sigma_max: Option<f64>,
    /// pnp-gap / pnp-admm: the floor σ of the last denoising (geometric schedule), in (0, σ max]
    /// [default 0.05].
    #[arg(long = "sigma-min")]
    pub sigma_min: Option<f64>,
    /// pnp-gap / pnp-admm: start the σ schedule at the TV iterate's estimated error (what TV removed in its
    /// last step, clamped to [σ min, σ max]) instead of σ max (measured: it underestimates the error ≈ 10×).
    #[arg(long = "sigma-auto")]
    pub sigma_auto: bool,
    /// pnp-gap / pnp-admm: the TV phase's cap (GAP-TV / ADMM-TV iterations before the network; the phase
    /// ends earlier at GAP-TV's own discrepancy stop) [default 300]; must leave at least one of
    /// --iterations to the network.
    #[arg(long = "tv-warmup")]
    pub tv_warmup: Option<usize>,
    /// Stopping rule: stop when the relative change ‖θ_k − θ_{k−1}‖/‖θ_k‖ falls below this (0: run every
    /// iteration) [default: the solver's: 0 (TV and PnP)].
    #[arg(long)]
    pub tolerance: Option<f64>,
    /// Stopping rule (discrepancy principle): stop once ‖y − Φθ‖₂ ≤ τ·δ, δ the noise norm estimated from
    /// render.json (sensor noise, the exact operator's Monte-Carlo mismatch); 0 turns it off
    /// [default: the solver's, docs/reconstruction.md].
    #[arg(long)]
    pub discrepancy: Option<f64>,
    /// How δ's Monte-Carlo term (exact operator, another seed) is estimated: `spread` — from the data, the
    /// operator's spread against a twin traced with another seed, at the current iterate (twice the
    /// operator's memory and tracing, one more Φ every 5 iterations); `model` — the constant relative
    /// mismatch measured on 128² crops (cheaper; miscalibrated on smoother, larger scenes)
    /// [docs/reconstruction.md, "Defaults and stopping"].
    #[arg(long = "noise-estimate", default_value = "spread", value_parser = ["spread", "model"])]
    pub noise_estimate: String,
}

impl SolverTuning {
    /// The settings of one solve with `solver`; `accelerated` as given (the caller decides whether it applies).
    pub fn settings(&self, solver: &str, accelerated: bool) -> SolveSettings {
        SolveSettings {
            solver: solver.to_string(),
            iterations: self.iterations,
            tv_weight: self.tv_weight,
            accelerated,
            plain: self.plain,
            denoiser: self.denoiser.clone(),
            sigma_max: self.sigma_max,
            sigma_min: self.sigma_min,
            sigma_auto: self.sigma_auto,
            tolerance: self.tolerance,
            tv_warmup: self.tv_warmup,
            discrepancy: self.discrepancy,
            noise: None,
            noise_model: if self.noise_estimate == "model" { NoiseModel::Model } else { NoiseModel::Spread },
        }
    }
}

/// Settings of one reconstruction (everything but the operator).
#[derive(Clone, Debug)]
pub struct SolveSettings {
    pub solver: String,
    pub iterations: Option<usize>,
    pub tv_weight: Option<f64>,
    /// GAP-TV's accelerated variant (asked for explicitly; it is gap-tv's default anyway).
    pub accelerated: bool,
    /// GAP-TV: plain GAP instead of the accelerated default.
    pub plain: bool,
    /// PnP: the denoiser's weights file (`None`: embedded).
    pub denoiser: Option<PathBuf>,
    /// PnP: the σ schedule's ends (relative to the peak).
    pub sigma_max: Option<f64>,
    pub sigma_min: Option<f64>,
    /// PnP: σ_1 from the TV iterate's estimated error instead of σ max.
    pub sigma_auto: bool,
    /// The stopping rule's relative-change tolerance.
    pub tolerance: Option<f64>,
    /// PnP: TV warm-up iterations.
    pub tv_warmup: Option<usize>,
    /// The discrepancy principle's τ (`None`: the solver's default).
    pub discrepancy: Option<f64>,
    /// The measurement's expected noise norm δ ([`noise_estimate`]; `None`: unknown, the rule is off).
    pub noise: Option<NoiseEstimate>,
    /// How the exact operator's Monte-Carlo term of δ is estimated (`--noise-estimate`).
    pub noise_model: NoiseModel,
}

/// `--noise-estimate`: the exact operator's Monte-Carlo term of δ from the data (a twin operator's spread at
/// the iterate, [`crate::recon::MonteCarloSpread`]) or from the constant model [`MC_MISMATCH_PER_RAY`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NoiseModel {
    Spread,
    Model,
}

/// The twin operator's ray seed for the data-driven δ: the operator's + 1, skipping the acquisition's (the
/// twin must be independent of both).
pub fn twin_seed(acquisition_seed: u64, operator_seed: u64) -> u64 {
    let s = operator_seed.wrapping_add(1);
    if s == acquisition_seed {
        s.wrapping_add(1)
    } else {
        s
    }
}

/// The data-driven δ's plan (`--noise-estimate spread`): build the twin with `twin_seed`, scale its spread by
/// `factor`, add `sensor_norm` in quadrature.
#[derive(Clone, Debug)]
pub struct SpreadPlan {
    pub twin_seed: u64,
    pub factor: f64,
    pub sensor_norm: f64,
}

pub use crate::recon::solver::MC_MISMATCH_PER_RAY;

/// The expected norm δ of y − Φx_true and how it was estimated (recorded as `noise_estimate`).
#[derive(Clone, Debug)]
pub struct NoiseEstimate {
    /// δ in acquisition units (with a [`SpreadPlan`]: the start value, the sensor term, until the first estimate).
    pub norm: f64,
    pub record: Value,
    /// `Some`: the Monte-Carlo term is estimated from the data during the solve.
    pub spread: Option<SpreadPlan>,
}

/// Estimate δ = E‖y − Φx_true‖₂ from render.json, without the truth: (a) the sensor noise its `noise`
/// object describes — shot noise of variance y_i/K per pixel (K electrons per unit), read noise (σ_e/K)²,
/// ADC quantisation (g/K)²/12 — and (b) for the `exact` operator traced with another seed, the Monte-Carlo
/// mismatch [`MC_MISMATCH_PER_RAY`]·((1/R_a + 1/R_o)/F)^½·‖y‖ (0 for the oracle: same seed and rays). δ² is the
/// sum. The `mapping` and `shift` operators' model error is systematic and not estimated: only (a) counts,
/// so with a noiseless acquisition the rule is off for them.
///
/// With [`NoiseModel::Spread`] (the default) the Monte-Carlo term is not taken from the constant model but
/// estimated during the solve ([`crate::recon::MonteCarloSpread`]; the returned plan says how): δ starts at the
/// sensor term and the record's `norm`/`monte_carlo_norm` become the last estimate's after the solve.
pub fn noise_estimate(record: &RenderRecord, kind: OperatorKind, operator_seed: u64, operator_rays: usize, acquisition_rays: usize, model: NoiseModel) -> NoiseEstimate {
    let y = &record.acquisition;
    let y_norm = y.iter().map(|v| (*v as f64).powi(2)).sum::<f64>().sqrt();
    let noise = record.json.get("noise").filter(|v| v.is_object());
    let num = |k: &str| noise.and_then(|n| n.get(k)).and_then(Value::as_f64).filter(|v| v.is_finite());
    let sources: Vec<String> = noise.and_then(|n| n.get("sources")).and_then(Value::as_array).map(|a| a.iter().filter_map(|s| s.as_str().map(str::to_string)).collect()).unwrap_or_default();
    let k = num("electrons_per_unit").filter(|k| *k > 0.0);
    let mut sensor_sq = 0.0;
    if let Some(k) = k {
        if sources.iter().any(|s| s == "shot") {
            sensor_sq += y.iter().map(|v| (*v as f64).max(0.0)).sum::<f64>() / k;
        }
        if let Some(r) = num("read_noise_e").filter(|_| sources.iter().any(|s| s == "read")) {
            sensor_sq += y.len() as f64 * (r / k).powi(2);
        }
        if let Some(g) = num("adc_gain_e_per_dn").filter(|_| sources.iter().any(|s| s == "adc")) {
            sensor_sq += y.len() as f64 * (g / k).powi(2) / 12.0;
        }
    }
    let oracle = operator_seed == record.config.seed && operator_rays == acquisition_rays;
    let planes_per_band = record.config.spectral.planes() as f64 / record.bands_nm().len().max(1) as f64;
    let mc_model = if kind == OperatorKind::Exact && !oracle {
        crate::recon::solver::monte_carlo_noise_norm(y_norm, acquisition_rays, operator_rays, planes_per_band)
    } else {
        0.0
    };
    let spread = (model == NoiseModel::Spread && mc_model > 0.0).then(|| SpreadPlan {
        twin_seed: twin_seed(record.config.seed, operator_seed),
        factor: crate::recon::MonteCarloSpread::factor_for(acquisition_rays, operator_rays),
        sensor_norm: sensor_sq.sqrt(),
    });
    let mc = if spread.is_some() { 0.0 } else { mc_model };
    let norm = (sensor_sq + mc * mc).sqrt();
    let mut rec = serde_json::json!({
        "norm": norm,
        "relative": if y_norm > 0.0 { norm / y_norm } else { 0.0 },
        "sensor_norm": sensor_sq.sqrt(),
        "sensor_sources": sources,
        "monte_carlo_norm": mc,
        "estimator": if spread.is_some() { "monte-carlo-spread" } else { "model" },
        "monte_carlo_model": format!("{MC_MISMATCH_PER_RAY}·((1/R_acquisition + 1/R_operator)/F)^½·‖y‖ (F planes per band) for the exact operator with another seed or ray count, else 0"),
        "monte_carlo_model_norm": mc_model,
        "planes_per_band": planes_per_band,
        "acquisition_rays": acquisition_rays,
        "operator_rays": operator_rays,
        "definition": "δ ≈ E‖y − Φx_true‖₂ in acquisition units: sensor noise from render.json `noise` (shot y/K, read (σ/K)², ADC (g/K)²/12 per pixel) plus the exact operator's Monte-Carlo mismatch",
    });
    if let (Some(p), Some(o)) = (&spread, rec.as_object_mut()) {
        o.insert(
            "spread".into(),
            serde_json::json!({
                "twin_seed": p.twin_seed, "factor": p.factor, "every": crate::recon::solver::SPREAD_EVERY,
                "definition": "δ_MC = factor·‖(Φ_o − Φ')θ‖₂ at the iterate θ, Φ' the operator's twin (same rays, seed twin_seed), factor = ((1 + R_operator/R_acquisition)/2)^½; re-estimated every `every` iterations from iteration 2; norm and monte_carlo_norm are the last estimate's",
            }),
        );
    }
    NoiseEstimate { norm, record: rec, spread }
}

/// The result of a solve: the cube (C order), the per-iteration relative data residual, the solver's
/// resolved settings and record (JSON) and seconds.
pub struct Solved {
    pub cube: Vec<f32>,
    /// Per iteration k: ‖y − Φv_k‖₂ / ‖y‖₂ ([`crate::recon::Reconstruction::residuals`]).
    pub residuals: Vec<f64>,
    pub final_residual: f64,
    pub settings: Value,
    /// The stopping rule and what ended the run (`{"rule", "tolerance", "stopped_by", "relative_changes"}`).
    pub stopping: Value,
    pub seconds: f64,
}

/// The solver configuration the settings describe (the solver's defaults, overridden by iterations / TV weight).
pub fn solver_config(s: &SolveSettings) -> Result<SolverConfig> {
    let kind: SolverKind = s.solver.parse().map_err(|_| Error::invalid(format!("--solver `{}`: use {}", s.solver, crate::recon::solver::SOLVER_NAMES)))?;
    let mut cfg = SolverConfig::for_solver(kind);
    if let Some(n) = s.iterations {
        cfg.iterations = n;
    }
    if let Some(w) = s.tv_weight {
        cfg.tv_weight = w as f32;
    }
    if s.accelerated {
        if !kind.is_gap() {
            return Err(Error::invalid(format!("--accelerated applies to gap-tv and pnp-gap only, not `{}`", s.solver)));
        }
        cfg.accelerated = true;
    }
    if s.plain {
        if !kind.is_gap() {
            return Err(Error::invalid(format!("--plain applies to gap-tv and pnp-gap only, not `{}`", s.solver)));
        }
        if s.accelerated {
            return Err(Error::invalid("--plain and --accelerated: choose one"));
        }
        cfg.accelerated = false;
    }
    for (flag, v) in [("--sigma-max", s.sigma_max), ("--sigma-min", s.sigma_min), ("--tolerance", s.tolerance)] {
        if let Some(v) = v {
            if !v.is_finite() || v < 0.0 {
                return Err(Error::invalid(format!("{flag} {v}: must be finite and ≥ 0")));
            }
        }
    }
    if !kind.is_pnp() && (s.denoiser.is_some() || s.sigma_max.is_some() || s.sigma_min.is_some() || s.tv_warmup.is_some() || s.sigma_auto) {
        return Err(Error::invalid(format!("--denoiser / --sigma-max / --sigma-min / --sigma-auto / --tv-warmup apply to pnp-gap and pnp-admm only, not `{}`", s.solver)));
    }
    if s.sigma_auto {
        cfg.sigma_auto = true;
    }
    if let Some(n) = s.tv_warmup {
        cfg.tv_warmup = n;
    }
    if let Some(v) = s.sigma_max {
        cfg.sigma_max = v as f32;
    }
    if let Some(v) = s.sigma_min {
        cfg.sigma_min = v as f32;
    }
    if let Some(v) = s.tolerance {
        cfg.tolerance = v;
    }
    if let Some(v) = s.discrepancy {
        if !v.is_finite() || v < 0.0 {
            return Err(Error::invalid(format!("--discrepancy {v}: must be finite and ≥ 0")));
        }
        cfg.discrepancy = v;
    }
    if let Some(n) = &s.noise {
        cfg.noise_norm = n.norm;
    }
    if let Some(p) = &s.denoiser {
        cfg.denoiser = Some(p.display().to_string());
    }
    cfg.validate()?;
    Ok(cfg)
}

/// Run the solver on `op` and the acquisition `y` (starting from 0), with an iteration progress bar when
/// `show_progress`.
/// `twin`: the operator's twin for the data-driven δ (when `s.noise` has a [`SpreadPlan`]).
pub fn solve(op: &dyn Operator, y: &[f32], s: &SolveSettings, show_progress: bool, twin: Option<&dyn Operator>) -> Result<Solved> {
    solve_observed(op, y, s, show_progress, None, twin)
}

/// [`solve`], and with a `truth` cube (same shape) the PSNR (paper convention) of every iterate θ_k,
/// recorded as `psnr_per_iteration` beside ‖y − Φx_true‖₂/‖y‖₂ (`truth_residual`): evaluation only, for
/// measuring defaults and stopping rules (the solver never sees it).
/// With a [`SpreadPlan`] in `s.noise` and its `twin`, δ's Monte-Carlo term is re-estimated during the solve
/// (and, with `truth`, the estimator at the truth is recorded as `truth_spread_estimate`).
pub fn solve_observed(op: &dyn Operator, y: &[f32], s: &SolveSettings, show_progress: bool, truth: Option<&[f32]>, twin: Option<&dyn Operator>) -> Result<Solved> {
    let cfg = solver_config(s)?;
    let pb = if show_progress { iteration_bar(cfg.iterations as u64, &format!("{} / {}", op.name(), cfg.solver.name())) } else { ProgressBar::hidden() };
    let mut denoiser = crate::recon::solver::config_denoiser(&cfg)?;
    let shape = op.cube_shape();
    let mut psnrs: Vec<f64> = Vec::new();
    let plan = s.noise.as_ref().and_then(|n| n.spread.clone());
    let spread = match (&plan, twin) {
        (Some(p), Some(t)) => Some(crate::recon::MonteCarloSpread { twin: t, factor: p.factor, sensor_norm: p.sensor_norm, every: crate::recon::solver::SPREAD_EVERY }),
        (Some(_), None) => return Err(Error::invalid("internal: the data-driven noise estimate needs the operator's twin")),
        _ => None,
    };
    let rec = crate::recon::reconstruct_estimated(
        op,
        y,
        None,
        &cfg,
        denoiser.as_mut(),
        &|_, r| {
            pb.set_message(format!("{} / {}: residual {r:.3e}", op.name(), cfg.solver.name()));
            pb.inc(1);
        },
        &mut |_, theta| {
            if let Some(t) = truth {
                psnrs.push(crate::recon::metrics::psnr_db(t, theta, shape).unwrap_or(f64::NAN));
            }
        },
        spread.as_ref(),
    )?;
    pb.finish_and_clear();
    if let Some(i) = rec.cube.iter().position(|v| !v.is_finite()) {
        let peak = y.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        return Err(Error::invalid(format!(
            "the solver produced a non-finite value at index {i} (the acquisition's largest |value| is {}; values beyond ±{:.3e} can overflow the f32 sums): not written",
            crate::limits::fmt_num(peak as f64),
            crate::limits::MAX_SCENE_VALUE
        )));
    }
    let settings = serde_json::to_value(&rec.config).unwrap_or(Value::Null);
    let mut record = serde_json::to_value(&rec).unwrap_or(Value::Null);
    if let Some(o) = record.as_object_mut() {
        o.remove("residuals");
    }
    let ny = y.iter().map(|v| (*v as f64).powi(2)).sum::<f64>().sqrt();
    let mut noise_record = s.noise.as_ref().map(|n| n.record.clone());
    if let (Some(p), Some(o)) = (&plan, noise_record.as_mut().and_then(Value::as_object_mut)) {
        // The data-driven δ: the record's norm and Monte-Carlo term are the last estimate's.
        let mc = (rec.noise_norm.powi(2) - p.sensor_norm.powi(2)).max(0.0).sqrt();
        o.insert("norm".into(), serde_json::json!(rec.noise_norm));
        o.insert("relative".into(), serde_json::json!(if ny > 0.0 { rec.noise_norm / ny } else { 0.0 }));
        o.insert("monte_carlo_norm".into(), serde_json::json!(mc));
    }
    let mut stopping = rec.stopping_record(y, noise_record);
    if let (Some(t), Some(o)) = (truth, stopping.as_object_mut()) {
        let mut phi_t = vec![0.0f32; y.len()];
        op.apply_into(t, &mut phi_t);
        let r = y.iter().zip(&phi_t).map(|(a, b)| ((*a - *b) as f64).powi(2)).sum::<f64>().sqrt();
        o.insert("truth_residual".into(), serde_json::json!(if ny > 0.0 { r / ny } else { 0.0 }));
        if let Some(sp) = &spread {
            // The estimator evaluated at the truth (what δ̂ at the iterate approximates), relative to ‖y‖.
            let mut scratch = Vec::new();
            let d = sp.estimate(t, &phi_t, &mut scratch);
            o.insert("truth_spread_estimate".into(), serde_json::json!(if ny > 0.0 { d / ny } else { 0.0 }));
        }
        o.insert("psnr_per_iteration".into(), serde_json::json!(psnrs));
    }
    Ok(Solved { residuals: rec.residuals.clone(), final_residual: rec.final_residual, settings: serde_json::json!({"config": settings, "record": record}), stopping, seconds: rec.seconds, cube: rec.cube })
}

pub fn reconstruct(a: ReconstructArgs) -> Result<()> {
    let t0 = Instant::now();
    let kind = OperatorKind::parse(&a.operator)?;
    if a.tuning.iterations == Some(0) {
        return Err(Error::invalid("--iterations must be ≥ 1"));
    }
    if let Some(w) = a.tuning.tv_weight {
        if !(w.is_finite() && w >= 0.0) {
            return Err(Error::invalid(format!("--tv-weight {w}: must be finite and ≥ 0")));
        }
    }
    if !(a.transport_memory_gb.is_finite() && a.transport_memory_gb >= 0.0) {
        return Err(Error::invalid(format!("--transport-memory-gb {}: must be finite and ≥ 0", a.transport_memory_gb)));
    }
    if let Some(t) = a.backend.tolerance_um {
        // Accepted by the shared backend options but never used here: refuse rather than ignore it.
        return Err(Error::invalid(format!(
            "--tolerance-um {t}: reconstruct does not choose a tracer by tolerance — the operator is rebuilt with the render's tracer (render.json `tracer`) or the one --backend names; the rays per pixel are the render's"
        )));
    }
    if a.operator_seed.is_some() && kind != OperatorKind::Exact {
        return Err(Error::invalid(format!("--operator-seed applies to the exact operator only (its traced rays), not `{}`", kind.name())));
    }
    if a.backend.calibration_cache.is_some() {
        return Err(Error::invalid("--calibration-cache: only used with --tolerance-um, which reconstruct does not take"));
    }
    let settings = a.tuning.settings(&a.solver, a.tuning.accelerated);
    check_solver(&settings)?;
    // The output policy before any work: --out never --from, inside it or containing it.
    let inputs = [("--from", a.from.as_path())];
    crate::io::policy::check_out_folder(&a.out, &reconstruction_rule(a.force), &inputs)?;
    if let Some(n) = a.operator_rays {
        if n == 0 {
            return Err(Error::invalid("--operator-rays 0: must be ≥ 1"));
        }
        if kind != OperatorKind::Exact {
            return Err(Error::invalid(format!("--operator-rays applies to the exact operator only, not `{}`", kind.name())));
        }
    }
    let mut record = RenderRecord::load(&a.from)?;
    let truth = match &a.truth {
        Some(p) => {
            let t = crate::scene::load_scene(p, None).map_err(|e| Error::invalid(format!("--truth {}: {e}", p.display())))?;
            if t.height != record.config.scene_height || t.width != record.config.scene_width || t.bands() != record.bands_nm().len() {
                return Err(Error::invalid(format!(
                    "--truth {}: {}×{}×{} cube, the render's scene is {}×{}×{}",
                    p.display(),
                    t.height,
                    t.width,
                    t.bands(),
                    record.config.scene_height,
                    record.config.scene_width,
                    record.bands_nm().len()
                )));
            }
            Some(t)
        }
        None => None,
    };
    let acquisition_rays = record.config.rays_per_pixel;
    if let Some(n) = a.operator_rays {
        // The operator is rebuilt from the record's configuration: only its ray count changes (the ray budget
        // of `build_operator` applies to it).
        record.config.rays_per_pixel = n;
    }
    // The staging folder, filled and swapped in at the end (a killed run's is removed by the next).
    let set = crate::io::OutputSet::folder(&a.out, &reconstruction_rule(a.force), &inputs)?;
    let seed = operator_seed(record.config.seed, a.operator_seed.as_deref())?;
    let tracer = record_tracer(&record, &a.backend)?;
    let t_op = Instant::now();
    let op = {
        let c = &record.config;
        let rays = (c.scene_height as f64 * c.scene_width as f64 * c.rays_per_pixel as f64 * c.spectral.planes() as f64) as u64;
        let pb = ProgressBar::new(if kind == OperatorKind::Exact { rays } else { 0 });
        pb.set_style(ProgressStyle::with_template("{msg} [{elapsed_precise}] {wide_bar} {human_pos}/{human_len} rays, ETA {eta}").unwrap_or_else(|_| ProgressStyle::default_bar()));
        pb.set_message(format!("operator {}", kind.name()));
        let op = build_operator(kind, &record, tracer.as_ref(), seed, (a.transport_memory_gb * 1e9) as u64, &|k| pb.inc(k))?;
        pb.finish_and_clear();
        op
    };
    let mut settings = settings;
    let noise = noise_estimate(&record, kind, seed, record.config.rays_per_pixel, acquisition_rays, settings.noise_model);
    // The data-driven δ: the operator's twin (same rays, another seed).
    let twin = match &noise.spread {
        Some(p) => Some(build_operator(kind, &record, tracer.as_ref(), p.twin_seed, (a.transport_memory_gb * 1e9) as u64, &|_| {})?),
        None => None,
    };
    let seconds_operator = t_op.elapsed().as_secs_f64();
    settings.noise = Some(noise);
    let solved = solve_observed(op.as_ref(), &record.acquisition, &settings, true, truth.as_ref().map(|t| t.data.as_slice()), twin.as_deref())?;
    let c = op.cube_shape();
    let cube = SpectralCube::new(c.height, c.width, record.bands_nm().to_vec(), solved.cube, "reconstructed cube")?;
    let json = serde_json::json!({
        "version": env!("CARGO_PKG_VERSION"),
        "from": a.from.display().to_string(),
        "system": record.system.name(),
        "operator": kind.name(),
        "operator_seed": seed,
        "acquisition_seed": record.config.seed,
        "oracle": seed == record.config.seed && record.config.rays_per_pixel == acquisition_rays,
        "operator_rays": record.config.rays_per_pixel,
        "acquisition_rays": acquisition_rays,
        "tracer": tracer.name(),
        "solver": settings.solver,
        "solver_settings": solved.settings,
        "shape": {"height": c.height, "width": c.width, "bands": c.bands},
        "bands_nm": record.bands_nm(),
        "residual": solved.residuals,
        "residual_definition": "per iteration k: ‖y − Φv_k‖₂ / ‖y‖₂, v_k the point iteration k projects (GAP: θ_{k−1})",
        "final_residual": solved.final_residual,
        "iterations_run": solved.residuals.len(),
        "stopping": solved.stopping,
        "threads": rayon::current_num_threads(),
        "seconds_operator": seconds_operator,
        "seconds_solve": solved.seconds,
        "seconds": t0.elapsed().as_secs_f64(),
    });
    write_reconstruction(set, &cube, &json, true)?;
    println!(
        "{} / {} / {}: {}×{}×{} cube, {} iterations, final residual {:.4e}; operator {:.2} s, solve {:.2} s, total {:.2} s → {}",
        record.system.name(),
        kind.name(),
        settings.solver,
        c.height,
        c.width,
        c.bands,
        solved.residuals.len(),
        solved.final_residual,
        seconds_operator,
        solved.seconds,
        t0.elapsed().as_secs_f64(),
        a.out.display()
    );
    Ok(())
}

/// Reject an unknown solver or bad solver settings before any work (PnP: the weights are loaded and checked).
pub fn check_solver(s: &SolveSettings) -> Result<()> {
    let cfg = solver_config(s)?;
    if cfg.solver.is_pnp() {
        crate::recon::solver::config_denoiser(&cfg)?;
    }
    Ok(())
}
