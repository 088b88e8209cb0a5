//! Files of a rendered acquisition, all written atomically (temporary file + rename):
//! `acquisition.exr` (one f32 channel `Y`, detector-sized), `acquisition.png` (16-bit preview, linear,
//! scaled so the maximum is 65535; the scale is in the sidecar), optional `cube.exr` (the per-band detector
//! images — their sum is the acquisition — one channel per band named `band_NN_<λ>nm`, zero-padded so they
//! sort), `mask.png`, optional `mapping.npy` (+ `mapping_valid.npy`, `mapping_wavelengths_nm.npy`: the
//! chief-ray mapping cube at the band wavelengths, detector mm) and `render.json`, written last, whose
//! presence marks the outputs complete.
use super::engine::{Acquisition, Renderer};
use crate::error::{Error, Result};
use crate::io::exr::{write_exr, ExrChannel};
use crate::io::png16::write_png_gray16;
use crate::io::write_atomic;
use crate::scene::band_channel_name;
use std::path::Path;

/// Names of the files that must exist for a render folder to count as complete.
pub const REQUIRED_OUTPUTS: [&str; 3] = ["acquisition.exr", "acquisition.png", "render.json"];

/// Whether `dir` holds a complete render (every required file; `render.json` is written last).
pub fn outputs_complete(dir: &Path) -> bool {
    REQUIRED_OUTPUTS.iter().all(|f| dir.join(f).is_file())
}

/// Whether `dir/acquisition.exr` is the acquisition its render.json (`json`) records (its `Y` channel's
/// `acquisition_f32le_sha256`; a record without one, from before 30 Nov 2026, is taken as it is). A resumed
/// study re-renders a scene whose acquisition was replaced instead of scoring another scene's data.
pub fn acquisition_intact(dir: &Path, json: &serde_json::Value) -> bool {
    let Some(recorded) = json.get("acquisition_f32le_sha256") else { return true };
    let Ok(img) = crate::io::exr::read_exr(dir.join("acquisition.exr")) else { return false };
    img.channels.iter().find(|c| c.name == "Y").is_some_and(|c| recorded.as_str() == Some(super::engine::acquisition_sha256(&c.data).as_str()))
}

/// [`record_contradictions`]' fields: a dataset scene's render.json holds each at its top level and in its
/// `configuration`, in the same form.
pub const RECORD_FIELDS_IN_CONFIGURATION: [&str; 13] =
    ["seed", "rays_per_pixel", "planes_nm", "bands_nm", "scene_height", "scene_width", "scene_pitch_mm", "detector_pitch_mm", "detector_extra_px", "plane_weight", "sampling", "airy", "system"];

/// Where a dataset scene's render.json contradicts itself: a top-level field that its `configuration` (the
/// dataset's request, which resume and `dataset-status` compare) also holds, with another value — an edited
/// record (`seed` 0 → 5 counted as done, and `reconstruct` traced the operator with the edited seed; a held-out
/// battery, round 16). The fields compared are the ones `reconstruct` rebuilds the operator from and both
/// levels record in one form ([`RECORD_FIELDS_IN_CONFIGURATION`]; `mask`, `noise` and `system_spec` are
/// recorded in two forms: the request's settings, the render's report, catalogues by content). Empty for a
/// record without `configuration` (`render`'s own folders).
pub fn record_contradictions(json: &serde_json::Value) -> Vec<String> {
    let (Some(top), Some(conf)) = (json.as_object(), json.get("configuration").and_then(serde_json::Value::as_object)) else { return Vec::new() };
    let short = |v: &serde_json::Value| {
        let t = v.to_string();
        if t.chars().count() > 60 {
            format!("{}…", t.chars().take(60).collect::<String>())
        } else {
            t
        }
    };
    conf.iter()
        .filter(|(k, _)| RECORD_FIELDS_IN_CONFIGURATION.contains(&k.as_str()))
        .filter_map(|(k, c)| top.get(k).filter(|t| *t != c).map(|t| format!("`{k}` = {} but `configuration.{k}` = {} (an edited record)", short(t), short(c))))
        .collect()
}

/// The 16-bit preview's scale: 65535 / the acquisition's maximum (0 for a black acquisition); `render.json`
/// records it as `preview_scale`.
pub fn preview_scale(acq: &Acquisition) -> f64 {
    let max = acq.image.iter().cloned().fold(0.0, f64::max);
    if max > 0.0 {
        65535.0 / max
    } else {
        0.0
    }
}

/// Write `acquisition.exr`, `acquisition.png` and (if the bands were kept) `cube.exr`. Returns the preview
/// scale (PNG value = min(65535, round(value × scale))).
pub fn write_images(dir: &Path, renderer: &Renderer, acq: &Acquisition) -> Result<f64> {
    let det = &acq.detector;
    // The acquisition sums the planes and concentrates light: a scene within the radiance limit can give
    // values `reconstruct` refuses (its f32 sums; a held-out battery, round 7). Refused before anything is written.
    if let Some((i, &v)) = acq.image.iter().enumerate().find(|(_, v)| v.abs() > crate::limits::MAX_SCENE_VALUE) {
        return Err(crate::error::Error::invalid(format!(
            "the acquisition reaches {} at detector pixel (row {}, col {}), beyond ±{:.3e}, what `reconstruct` accepts (its f32 sums could overflow): scale the scene's radiance down",
            crate::limits::fmt_num(v),
            i / det.width,
            i % det.width,
            crate::limits::MAX_SCENE_VALUE
        )));
    }
    let img = acq.image_f32();
    write_exr(dir.join("acquisition.exr"), det.width, det.height, &[ExrChannel { name: "Y".into(), data: img.clone() }])?;
    let scale = preview_scale(acq);
    let png: Vec<u16> = acq.image.iter().map(|&v| (v.max(0.0) * scale).round().min(65535.0) as u16).collect();
    write_png_gray16(dir.join("acquisition.png"), det.width, det.height, &png)?;
    if let Some(bands) = &acq.bands {
        let b = &renderer.config.spectral.bands_nm;
        let channels: Vec<ExrChannel> = bands.iter().enumerate().map(|(k, d)| ExrChannel { name: band_channel_name(k, b.len(), b[k]), data: d.clone() }).collect();
        write_exr(dir.join("cube.exr"), det.width, det.height, &channels)?;
    }
    Ok(scale)
}

/// Write the chief-ray mapping cube of the scene grid at the band wavelengths.
pub fn write_mapping(dir: &Path, renderer: &Renderer) -> Result<()> {
    let c = &renderer.config;
    let ws = &c.spectral.bands_nm;
    // The mapping is traced in the render's precision (f32 renders an f32 mapping).
    let f32_tracer = match c.precision {
        crate::tracer::Precision::F32 => Some(c.precision.tracer(c.kernel)?),
        crate::tracer::Precision::F64 => None,
    };
    let tracer = f32_tracer.as_deref().unwrap_or(renderer.tracer);
    let cube = crate::analysis::mapping_cube(renderer.system, tracer, c.scene_height, c.scene_width, c.scene_pitch_mm, ws)?;
    let shape = [c.scene_height, c.scene_width, ws.len(), 2];
    let v: Vec<f32> = cube.positions_mm.iter().map(|&x| x as f32).collect();
    crate::io::write_npy_f32(dir.join("mapping.npy"), &shape, &v)?;
    crate::io::write_npy_u8(dir.join("mapping_valid.npy"), &shape[..3], &cube.valid)?;
    crate::io::write_npy_f64(dir.join("mapping_wavelengths_nm.npy"), &[ws.len()], ws)?;
    Ok(())
}

/// The sidecar's common part: everything needed to reproduce the render. `device`: the record of a render on
/// a device's kernels (`None`: the CPU renderer), written as `device`; `kernel` names the code that traced —
/// the CPU's SIMD or scalar kernel, or the GPU kernels (`cuda-kernels`, or `cuda-kernels-host-twin` for
/// `cpu-twin`: render.json named the CPU's SIMD kernel, which the twin does not use).
pub fn sidecar(renderer: &Renderer, acq: &Acquisition, device: Option<&super::device::DeviceRecord>, scene: &serde_json::Value, preview_scale: f64, seconds_total: f64, threads: usize) -> serde_json::Value {
    let c = &renderer.config;
    let traced = acq.stats.traced;
    let kernel = match device {
        None => c.kernel.name(),
        Some(d) if d.device == "cpu-twin" => "cuda-kernels-host-twin".to_string(),
        Some(_) => "cuda-kernels".to_string(),
    };
    let mut v = serde_json::json!({
        "version": env!("CARGO_PKG_VERSION"),
        "system": renderer.system.name(),
        "system_spec": serde_json::to_value(&renderer.system.spec).unwrap_or(serde_json::Value::Null),
        "tracer": renderer.tracer_name(),
        "kernel": kernel,
        "precision": c.precision,
        "scene": scene,
        "scene_size": c.scene_height,
        "scene_height": c.scene_height,
        "scene_width": c.scene_width,
        "scene_pitch_mm": if c.scene_fov_deg.is_some() { serde_json::Value::Null } else { serde_json::json!(c.scene_pitch_mm) },
        "detector_pitch_mm": c.detector_pitch_mm,
        "detector_extra_px": c.detector_extra_px,
        "force_batched": c.force_batched,
        "mask_file": "mask.png",
        "mask_png_sha256": renderer.mask.png_sha256(),
        "seed": c.seed,
        "sampling": c.sampling,
        "rays_per_pixel": c.rays_per_pixel,
        "bands_nm": c.spectral.bands_nm,
        "bands": c.spectral.bands_nm.len(),
        "planes": c.spectral.planes(),
        "planes_nm": c.spectral.planes_nm,
        "plane_weight": c.spectral.plane_weight,
        "spectral_interpolation": "linear in wavelength between the scene's bands, constant beyond its range",
        "airy": c.airy,
        "mask": renderer.mask.description,
        "mask_opening": renderer.mask.opening(),
        "detector": acq.detector,
        "detector_convention": "pixel (row i, col j) centre at x = x_left_mm + (j + 0.5) pitch, y = y_top_mm - (i + 0.5) pitch, image-surface frame",
        "rays_traced": traced,
        "rays_nominal": (c.scene_height * c.scene_width * c.rays_per_pixel * c.spectral.planes()) as u64,
        "ray_stats": acq.stats,
        "transmission": acq.stats.transmission(),
        "acquisition_total": acq.total(),
        "preview_scale": preview_scale,
        "threads": threads,
        "seconds_total": seconds_total,
        "seconds_render": acq.timings.wall_seconds,
        "timings": acq.timings,
        "rays_per_second": if acq.timings.wall_seconds > 0.0 { traced as f64 / acq.timings.wall_seconds } else { 0.0 },
    });
    // The acquisition.exr the render writes, by content (`reconstruct` and a resumed study check it).
    v["device"] = super::device::record_json(renderer, device);
    v["acquisition_f32le_sha256"] = serde_json::json!(acq.image_sha256());
    // An object at infinity: the scene's angular extent (what `reconstruct` rebuilds the renderer from) and
    // the pixel's angle; there is no scene pitch in mm.
    if let Some(f) = c.scene_fov_deg {
        v["scene_fov_deg"] = serde_json::json!(f);
        v["scene_pitch_rad"] = serde_json::json!(c.scene_pitch_mm);
    }
    v
}

/// Write `render.json` (last: its presence marks the folder complete).
pub fn write_sidecar(dir: &Path, value: &serde_json::Value) -> Result<()> {
    let text = serde_json::to_string_pretty(value).map_err(|e| Error::invalid(format!("JSON encoding failed: {e}")))?;
    write_atomic(dir.join("render.json"), text.as_bytes())?;
    Ok(())
}
