//! [`RenderRecord`]: a render folder read back — the system (`render.json`'s `system_spec`), the render
//! configuration (scene size and pitch, bands, planes, rays, sampling, Airy blur, detector pitch), the mask
//! (`mask.png`, the file the render wrote) and the acquisition (`acquisition.exr`) — every field checked
//! against the limits `render` applies before anything is allocated.
use crate::error::{Error, Result};
use crate::render::{AiryConfig, Mask, RenderConfig, Renderer, Sampling, SpectralSampling};
use crate::system::SequentialSystem;
use crate::tracer::Tracer;
use serde_json::Value;
use std::path::{Path, PathBuf};

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

pub(crate) fn ferr(path: &Path, m: impl Into<String>) -> Error {
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

/// `name` is one path component naming a file (no folder, no `..`, not absolute).
fn is_plain_file_name(name: &str) -> bool {
    let mut c = Path::new(name).components();
    matches!((c.next(), c.next()), (Some(std::path::Component::Normal(_)), None))
}

/// render.json's `noise` object (what `render --noise` wrote, [`crate::render::noise::NoiseConfig::to_json`]):
/// absent or null for a clean acquisition; otherwise `sources` a list of distinct `shot`, `read`, `adc`, and each
/// number the sources need finite and > 0 — the stopping rule's sensor term is computed from them, so a tampered
/// or damaged block is an error naming the field, never a term silently 0.
fn check_noise(json: &Value, jp: &Path) -> Result<()> {
    let noise = match json.get("noise") {
        None | Some(Value::Null) => return Ok(()),
        Some(Value::Object(o)) => o,
        Some(v) => return Err(ferr(jp, format!("field `noise` = {v} is not an object (render --noise writes one) or null"))),
    };
    let sources = noise.get("sources").and_then(Value::as_array).ok_or_else(|| ferr(jp, "field `noise.sources` is missing or not a list"))?;
    let mut seen: Vec<&str> = Vec::new();
    for s in sources {
        let name = s.as_str().filter(|n| ["shot", "read", "adc"].contains(n)).ok_or_else(|| ferr(jp, format!("field `noise.sources`: {s} is not one of \"shot\", \"read\", \"adc\"")))?;
        if seen.contains(&name) {
            return Err(ferr(jp, format!("field `noise.sources` lists \"{name}\" twice")));
        }
        seen.push(name);
    }
    let positive = |key: &str| -> Result<()> {
        let v = noise.get(key).ok_or_else(|| ferr(jp, format!("field `noise.{key}` is missing")))?;
        v.as_f64().filter(|x| x.is_finite() && *x > 0.0).map(|_| ()).ok_or_else(|| ferr(jp, format!("field `noise.{key}` = {v} is not a finite number > 0")))
    };
    if !seen.is_empty() {
        positive("electrons_per_unit")?;
    }
    if seen.contains(&"read") {
        positive("read_noise_e")?;
    }
    if seen.contains(&"adc") {
        positive("adc_gain_e_per_dn")?;
    }
    // One ADC step and the read noise's σ in acquisition units within what an acquisition holds, as `render`
    // checks them (NoiseConfig::check_steps): beyond it the noise's norm δ is not a number (round 16).
    let k = noise.get("electrons_per_unit").and_then(Value::as_f64).unwrap_or(1.0);
    for (key, source) in [("adc_gain_e_per_dn", "adc"), ("read_noise_e", "read")] {
        let e = noise.get(key).and_then(Value::as_f64).unwrap_or(0.0);
        if seen.contains(&source) && !(e / k <= crate::limits::MAX_SCENE_VALUE) {
            return Err(ferr(
                jp,
                format!("field `noise.{key}` = {} at `noise.electrons_per_unit` = {} is {:.3e} acquisition units, beyond the ±{:.3e} an acquisition holds (render refuses it)", crate::limits::fmt_num(e), crate::limits::fmt_num(k), e / k, crate::limits::MAX_SCENE_VALUE),
            ));
        }
    }
    Ok(())
}

/// A render record read back and what rebuilding its renderer and solving with it hold beside the operator:
/// [`crate::limits::bytes_render`] of the scene (cube, mapping, mask, Airy kernels, images) and the
/// acquisition in f64 (8 B per detector pixel).
fn record_bytes(h: usize, w: usize, bands: usize, planes: usize, airy_diameter_px: Option<f64>, dh: usize, dw: usize) -> f64 {
    let n = ((h as f64) * (w as f64)).sqrt().ceil() as usize;
    crate::limits::bytes_render(n, bands, bands, planes, false, airy_diameter_px) + dh as f64 * dw as f64 * 8.0
}

impl RenderRecord {
    /// The memory estimate checked when the record was read ([`RenderRecord::load`]): what the record, its
    /// renderer and a solve's cube-sized arrays hold beside an operator (bytes).
    pub fn memory_bytes(&self) -> f64 {
        let c = &self.config;
        record_bytes(c.scene_height, c.scene_width, c.spectral.bands_nm.len(), c.spectral.planes(), c.airy.as_ref().map(|a| a.diameter_px), self.detector_height, self.detector_width)
    }

    /// Register [`RenderRecord::memory_bytes`] with the memory budget until dropped ([`crate::limits::hold`]):
    /// the operators and the denoiser built beside it are checked with it counted.
    pub fn hold(&self) -> crate::limits::Held {
        crate::limits::hold(format!("the render record of {}", self.dir.display()), self.memory_bytes())
    }

    /// Read `dir/render.json`, `dir/mask.png` and `dir/acquisition.exr` and rebuild the system and configuration.
    pub fn load(dir: &Path) -> Result<Self> {
        if !dir.is_dir() {
            return Err(ferr(dir, "not a render folder (no such folder)"));
        }
        let jp = dir.join("render.json");
        if !jp.is_file() {
            // A render-dataset or study output holds render folders one or two levels down: say where.
            if dir.join(crate::render::dataset::MANIFEST).is_file() {
                return Err(ferr(dir, format!("a render-dataset output, not a render folder: give one scene's folder (`{}/SCENE`)", dir.display())));
            }
            if dir.join("study.json").is_file() {
                return Err(ferr(dir, format!("a study output, not a render folder: its renders are `{}/renders/SYSTEM/SCENE`", dir.display())));
            }
            return Err(ferr(&jp, "missing: not a (complete) render folder — run `diffcassi render --out` first"));
        }
        let text = std::fs::read_to_string(&jp).map_err(|e| ferr(&jp, format!("cannot read: {e}")))?;
        let json: Value = serde_json::from_str(&text).map_err(|e| ferr(&jp, format!("not valid JSON: {e}")))?;
        check_noise(&json, &jp)?;
        if let Some(c) = crate::render::output::record_contradictions(&json).first() {
            return Err(ferr(&jp, format!("contradicts itself: {c}; render the scene again (`render-dataset` rerenders it)")));
        }
        let spec: crate::spec::SystemSpec = serde_json::from_value(field(&json, &jp, "system_spec")?.clone()).map_err(|e| ferr(&jp, format!("field `system_spec`: {e}")))?;
        let system = SequentialSystem::build(&spec)?;
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
        // An object at infinity records its angular extent (`scene_fov_deg`) instead of a pitch in mm; the
        // renderer turns it back into the pixel angle (the placeholder pitch below is replaced).
        let scene_fov_deg = match json.get("scene_fov_deg") {
            None | Some(Value::Null) => None,
            Some(_) => {
                let f = field_f64(&json, &jp, "scene_fov_deg")?;
                crate::render::check_scene_fov_deg(f).map_err(|e| ferr(&jp, format!("field `scene_fov_deg`: {e}")))?;
                Some(f)
            }
        };
        let scene_pitch_mm = match scene_fov_deg {
            Some(_) => 0.01,
            None => field_f64(&json, &jp, "scene_pitch_mm")?,
        };
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
        let what = format!("scene_height × scene_width × planes ({h} × {w} × {planes}, {} bands)", bands.len());
        crate::limits::check_memory(&what, record_bytes(h, w, bands.len(), planes, airy.map(|a| a.diameter_px), dh, dw)).map_err(|e| ferr(&jp, e.to_string()))?;
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
        cfg.scene_fov_deg = scene_fov_deg;
        cfg.detector_pitch_mm = detector_pitch_mm;
        cfg.detector_extra_px = detector_extra_px;
        cfg.force_batched = json.get("force_batched").and_then(Value::as_bool).unwrap_or(false);
        cfg.spectral = spectral;
        cfg.rays_per_pixel = rays_per_pixel;
        cfg.seed = field(&json, &jp, "seed")?.as_u64().ok_or_else(|| ferr(&jp, "field `seed` is not a non-negative integer"))?;
        cfg.sampling = serde_json::from_value::<Sampling>(field(&json, &jp, "sampling")?.clone()).map_err(|e| ferr(&jp, format!("field `sampling`: {e}")))?;
        cfg.airy = airy;
        // The render's kernel precision (f32 renders trace another set of landing points than f64: an f64
        // operator with `--operator-seed same` was no oracle for them, its mismatch ~10⁴× the f64 oracle's).
        cfg.precision = match json.get("precision") {
            None | Some(Value::Null) => crate::tracer::Precision::F64,
            Some(v) => serde_json::from_value(v.clone()).map_err(|_| ferr(&jp, format!("field `precision` = {v}: expected \"f64\" or \"f32\"")))?,
        };
        let mask_name = match json.get("mask_file") {
            None | Some(Value::Null) => "mask.png",
            Some(v) => v.as_str().filter(|n| is_plain_file_name(n)).ok_or_else(|| ferr(&jp, format!("field `mask_file` = {v} must name a file in the render folder (a plain file name)")))?,
        };
        let mask_path = dir.join(mask_name);
        if !mask_path.is_file() {
            return Err(ferr(&mask_path, "missing: the render folder's mask is needed to rebuild the operator"));
        }
        let mut mask = Mask::load(&mask_path)?;
        if (mask.height, mask.width) != (h, w) {
            return Err(ferr(&mask_path, format!("the mask is {}×{} but the scene (render.json) is {h}×{w}", mask.height, mask.width)));
        }
        if mask.values.iter().all(|&v| v == 0.0) {
            return Err(ferr(&mask_path, "the mask is closed at every pixel: no light of the scene reached the detector, there is nothing to reconstruct"));
        }
        // The mask the render used (its 16-bit codes' SHA-256; render.json since 30 Nov 2026, older records have
        // none): a replaced mask file would give a silently wrong reconstruction.
        if let Some(recorded) = json.get("mask_png_sha256") {
            let recorded = recorded.as_str().ok_or_else(|| ferr(&jp, format!("field `mask_png_sha256` = {recorded} is not a string")))?;
            let found = mask.png_sha256();
            if recorded != found {
                return Err(ferr(
                    &mask_path,
                    format!("not the mask this render used: its SHA-256 (16-bit codes) is {found}, render.json's `mask_png_sha256` is {recorded}; restore the render's mask file or render again"),
                ));
            }
        }
        if let Some(d) = json.get("mask").and_then(Value::as_str) {
            mask.description = d.to_string();
        }
        let ap = dir.join("acquisition.exr");
        if !ap.is_file() {
            return Err(ferr(&ap, "missing: the render folder has no acquisition"));
        }
        let img = crate::io::exr::read_exr(&ap)?;
        // The render writes one channel `Y`; a file of several channels without it (a cube's EXR copied in) is
        // not an acquisition (its first band was read as one; a held-out battery, round 7).
        let ch = match img.channels.iter().find(|c| c.name == "Y") {
            Some(c) => c,
            None if img.channels.len() == 1 => &img.channels[0],
            None => {
                let names: Vec<&str> = img.channels.iter().map(|c| c.name.as_str()).collect();
                return Err(ferr(&ap, format!("{} channels ({}) and no `Y`: not an acquisition (a render writes one channel `Y`)", names.len(), names.join(", "))));
            }
        };
        // The acquisition the render wrote (render.json since 30 Nov 2026; older records have none): another
        // run's acquisition.exr copied in would be reconstructed with this record's operator, exit 0.
        if let Some(recorded) = json.get("acquisition_f32le_sha256") {
            let recorded = recorded.as_str().ok_or_else(|| ferr(&jp, format!("field `acquisition_f32le_sha256` = {recorded} is not a string")))?;
            let found = crate::render::engine::acquisition_sha256(&ch.data);
            if recorded != found {
                return Err(ferr(
                    &ap,
                    format!("not the acquisition this render wrote: its SHA-256 (f32 values) is {found}, render.json's `acquisition_f32le_sha256` is {recorded}; restore the render's acquisition.exr or render again"),
                ));
            }
        }
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

    /// The tracer the render recorded (render.json `tracer`; analytic when it cannot be parsed).
    pub fn tracer(&self) -> Result<Box<dyn Tracer>> {
        // An f32 render records `analytic-f32` (the analytic backend's f32 twin, chosen by `precision`, which
        // the renderer takes from the record): the backend to build is the analytic one.
        let name = if self.tracer_name == "analytic-f32" { "analytic" } else { self.tracer_name.as_str() };
        let cfg = crate::tracer::BackendConfig::from_tracer_name(name).map_err(|e| ferr(&self.dir.join("render.json"), format!("field `tracer`: {e}; give the operator's tracer with --backend")))?;
        cfg.build()
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
