//! `diffcassi bench tradeoff`: the speed/accuracy frontier. Every backend/option traces the same fixed,
//! seeded workloads; each row reports its error against the analytic f64 reference and its throughput.
//!
//! Workloads (sizes: full / `--quick`):
//!
//! * `rays`: [`RaySetSpec::tradeoff`] — 13×13 grid-distortion chief rays over the field plus full-pupil
//!   spots (5000 / 250 seeded random pupil points) of the system's fields, at 28 wavelengths 450–650 nm.
//!   Error: image-plane distance to the analytic f64 position, max and RMS over the rays; rays that arrive
//!   in one trace only are `mismatches`.
//! * `mapping`: the chief-ray mapping cube, 128×128 / 32×32 pixels of 10 µm at the 28 wavelengths, for
//!   every backend (exact) and for the interpolated model (analytic, strides 2–16). Error: distance of each
//!   entry to the exact analytic cube.
//! * `render`: a coded acquisition of the synthetic scene, 32×32 / 16×16, 28 planes, Airy blur on, random
//!   mask. Backends at N = 16 / 8 rays per pixel against the analytic render with the same rays; and the
//!   analytic render at N = 1…32 against an N = 512 / 128 analytic render. Error (µm): displacement of each
//!   scene pixel's deposited-energy centroid on the detector (bilinear splat weights, before the Airy
//!   blur), max and RMS over pixels and planes; plus `image_max_rel`/`image_rms_rel`, the largest and RMS
//!   pixel difference of the acquisitions relative to the reference's peak. (For the N ladder the
//!   reference's own Monte-Carlo error, σ/√N_ref, is part of what is measured.)
//!
//! `rays_per_s` counts rays actually traced; `items_per_s` counts the workload's outputs (rays; cube
//! entries; scene pixel-planes), which is what a cheaper model (interpolation, fewer rays) buys.
use super::measure::{candidate_configs, describe, time_best, ErrorAccumulator, ErrorStats};
use super::workload::RaySetSpec;
use crate::analysis::{linspace, mapping_cube, mapping_cube_interpolated, MappingCube};
use crate::error::{Error, Result};
use crate::io::{CsvValue, CsvWriter};
use crate::render::{Mask, PlaneTransport, RenderConfig, Renderer, SpectralSampling};
use crate::scene::{synthetic_scene, synthetic_wavelengths};
use crate::system::SequentialSystem;
use crate::tracer::{Backend, BackendConfig};
use std::path::Path;
use std::time::Instant;

/// Sizes of a trade-off run.
#[derive(Clone, Debug)]
pub struct TradeoffOptions {
    pub quick: bool,
    /// Timing repeats (best kept).
    pub repeat: usize,
    pub wavelengths: usize,
}

impl TradeoffOptions {
    pub fn new(quick: bool) -> Self {
        TradeoffOptions { quick, repeat: if quick { 2 } else { 3 }, wavelengths: 28 }
    }
    fn mesh_sag_um(&self) -> Vec<f64> {
        if self.quick {
            vec![10.0, 1.0, 0.1]
        } else {
            vec![10.0, 1.0, 0.1, 0.01]
        }
    }
    fn pupil_rays(&self) -> usize {
        if self.quick { 250 } else { 5000 }
    }
    fn mapping_size(&self) -> usize {
        if self.quick { 32 } else { 128 }
    }
    fn render_size(&self) -> usize {
        if self.quick { 16 } else { 32 }
    }
    fn render_rays(&self) -> usize {
        if self.quick { 8 } else { 16 }
    }
    fn render_reference_rays(&self) -> usize {
        if self.quick { 128 } else { 512 }
    }
    fn ladder(&self) -> Vec<usize> {
        if self.quick { vec![1, 4, 16] } else { vec![1, 2, 4, 8, 16, 32] }
    }
    fn strides(&self) -> Vec<usize> {
        if self.quick { vec![2, 4, 8] } else { vec![2, 4, 8, 16] }
    }

    /// (peak bytes, rays traced) of [`run_tradeoff`] with these options, estimated before anything runs:
    /// per backend configuration, (repeat + 1) × (the ray set, the mapping cube, a render), the references,
    /// the high-ray reference render and the rays-per-pixel ladder; memory for the ray set and its traces, two
    /// mapping cubes and the renders (scene, detector images and the traced transports of every plane).
    ///
    /// The Embree mesh candidates add their scene ([`mesh_scene_bytes`] of the finest `max-sag`, which does not
    /// depend on `--wavelengths`): round 19 measured 0.52 GB under an estimate of 0.04 GB at `--wavelengths 1`,
    /// the 0.01 µm mesh of SP holding ~0.45 GB.
    pub fn estimate(&self, system: &SequentialSystem) -> Result<(f64, f64)> {
        let (bytes, traced) = self.estimate_workloads();
        let mesh = if BackendConfig::available(Backend::EmbreeMesh) {
            let finest = self.mesh_sag_um().into_iter().fold(f64::INFINITY, f64::min);
            mesh_scene_bytes(system, finest)?
        } else {
            0.0
        };
        Ok((bytes + mesh, traced))
    }

    /// The workloads' part of [`Self::estimate`] (no mesh scene).
    fn estimate_workloads(&self) -> (f64, f64) {
        let wl = self.wavelengths as f64;
        let r = self.repeat as f64 + 1.0;
        let configs = super::measure::candidate_configs(&self.mesh_sag_um()).len() as f64;
        let rays = 13.0 * self.pupil_rays() as f64 * wl;
        let (ms, rs) = (self.mapping_size(), self.render_size());
        let mapping = (ms * ms) as f64 * wl;
        let pixel_planes = (rs * rs) as f64 * wl;
        let ladder: usize = self.ladder().iter().sum();
        let traced = configs * r * (rays + mapping + 2.0 * pixel_planes * self.render_rays() as f64)
            + 2.0 * r * mapping * self.strides().len() as f64
            + pixel_planes * (3.0 * self.render_reference_rays() as f64 + 2.0 * r * ladder as f64)
            + rays + mapping;
        let bytes = 3.0 * rays * crate::limits::BYTES_PER_RAY
            + 2.0 * (crate::limits::bytes_mapping(ms, ms, self.wavelengths) + crate::limits::bytes_mapping_batch(ms, ms))
            + 3.0 * crate::limits::bytes_render_hw(rs, rs, 31, self.wavelengths, self.wavelengths, false, Some(2.5))
            + 3.0 * pixel_planes * 256.0;
        (bytes, traced)
    }
}

/// Bytes one Embree mesh scene holds per triangle: the tessellation (f64 vertices, ~½ per triangle, and the
/// index triple), Embree's f32 copy with its BVH, and the per-vertex normals the tracer keeps for refinement;
/// fitted to round 19's measurement (SP at `max-sag=0.01um`: ~0.45 GB over the estimated triangle count).
pub const BYTES_PER_MESH_TRIANGLE: f64 = 200.0;

/// Triangles of the covering mesh of `patch` at a chord-sag tolerance `tol_um`, without building it (the finest
/// mesh takes ~30 s to tessellate): the mesh at 1 µm (or `tol_um` if coarser) is built, and its ring count scaled
/// as the chord sag falls, 1/n² (so n ∝ 1/√tol): a circular aperture has 6n² triangles in its uniform rings plus
/// a graded band of ≈ 3 per boundary segment, m = the fewest segments whose overshoot r(1/cos(π/m) − 1) is
/// ≤ tol; a rectangle's n × n grid has 2n².
pub fn mesh_triangles(patch: &crate::surfaces::SurfacePatch, tol_um: f64) -> Result<f64> {
    use crate::surfaces::{tessellate_covering, Aperture, MeshResolution};
    let tol0 = tol_um.max(1.0);
    let mesh = tessellate_covering(&patch.shape, &patch.aperture, MeshResolution::MaxSagErrorUm(tol0)).map_err(Error::invalid)?;
    let k = (tol0 / tol_um).sqrt();
    let n = (mesh.segments as f64 * k).ceil();
    Ok(match patch.aperture {
        Aperture::Circular { semi_diameter_mm: r, .. } => {
            let half_step = (1.0 / (1.0 + tol_um * 1e-3 / r)).acos();
            let m = 6.0 * (std::f64::consts::PI / half_step / 6.0).ceil();
            (6.0 * n * n + 3.0 * (m - 6.0 * n).max(0.0)).max(mesh.triangles.len() as f64)
        }
        _ => (mesh.triangles.len() as f64 * k * k).max(2.0 * n * n),
    })
}

/// Memory of one Embree mesh scene of `system` at a chord-sag tolerance `tol_um` (µm): [`BYTES_PER_MESH_TRIANGLE`]
/// per triangle of every optical surface's covering mesh ([`mesh_triangles`]).
pub fn mesh_scene_bytes(system: &SequentialSystem, tol_um: f64) -> Result<f64> {
    let solids = crate::tracer::nonseq::solids::Solids::build(system, &Default::default())?;
    let mut triangles = 0.0;
    for patch in solids.objects.iter().filter(|o| o.is_optical()).filter_map(|o| o.patch.as_ref()) {
        triangles += mesh_triangles(patch, tol_um)?;
    }
    Ok(triangles * BYTES_PER_MESH_TRIANGLE)
}

/// One row of the trade-off table.
#[derive(Clone, Debug, serde::Serialize)]
pub struct TradeoffRow {
    pub workload: String,
    pub backend: String,
    pub options: String,
    pub threads: usize,
    /// Rays traced (per repeat).
    pub rays: u64,
    /// Workload outputs (rays, cube entries, scene pixel-planes).
    pub items: u64,
    pub seconds: f64,
    pub rays_per_s: f64,
    pub items_per_s: f64,
    /// Items/s relative to the analytic exact row of the same workload.
    pub speed_vs_analytic: f64,
    pub error: ErrorStats,
    pub setup_seconds: f64,
    pub image_max_rel: Option<f64>,
    pub image_rms_rel: Option<f64>,
}

struct RenderSetup {
    config: RenderConfig,
    mask: Mask,
    scene: crate::scene::SpectralCube,
}

fn render_setup(size: usize, rays: usize, wavelengths: &[f64]) -> Result<RenderSetup> {
    let mut config = RenderConfig::paper(size);
    config.spectral = SpectralSampling::with_planes(wavelengths.to_vec(), wavelengths.len())?;
    config.rays_per_pixel = rays;
    Ok(RenderSetup { config, mask: Mask::random(size, size, 0.5, 0)?, scene: synthetic_scene(size, size, &synthetic_wavelengths(), 0) })
}

/// Footprint centroids (detector px, column/row) per (plane, scene pixel).
fn centroids(transport: &[PlaneTransport]) -> Vec<std::collections::HashMap<u32, (f64, f64)>> {
    transport.iter().map(|t| t.footprints.iter().filter_map(|f| t.centroid_px(f).map(|c| (f.pixel, c))).collect()).collect()
}

/// Centroid displacement (µm) between two transports, pixel by pixel (fixed order: planes, then pixels
/// sorted); a pixel deposited in one only is a mismatch.
fn centroid_error(reference: &[PlaneTransport], candidate: &[PlaneTransport], pitch_mm: f64) -> ErrorStats {
    let (a, b) = (centroids(reference), centroids(candidate));
    let mut acc = ErrorAccumulator::default();
    for (ra, rb) in a.iter().zip(&b) {
        let mut keys: Vec<u32> = ra.keys().chain(rb.keys()).copied().collect();
        keys.sort_unstable();
        keys.dedup();
        for k in keys {
            match (ra.get(&k), rb.get(&k)) {
                (Some(p), Some(q)) => acc.add_mm((q.0 - p.0) * pitch_mm, (q.1 - p.1) * pitch_mm),
                _ => acc.mismatches += 1,
            }
        }
    }
    acc.finish()
}

fn image_diff(reference: &[f64], candidate: &[f64]) -> (f64, f64) {
    let peak = reference.iter().cloned().fold(0.0, f64::max).max(f64::MIN_POSITIVE);
    let (mut max, mut s2) = (0.0f64, 0.0);
    for (a, b) in reference.iter().zip(candidate) {
        let d = (a - b).abs();
        max = max.max(d);
        s2 += d * d;
    }
    (max / peak, (s2 / reference.len().max(1) as f64).sqrt() / peak)
}

/// Image-plane distance (µm) of every entry of `candidate` from `reference` (same shape); an entry valid in
/// one cube only is a mismatch.
pub fn mapping_error(reference: &MappingCube, candidate: &MappingCube) -> ErrorStats {
    let mut acc = ErrorAccumulator::default();
    for k in 0..reference.valid.len() {
        match (reference.valid[k] == 1, candidate.valid[k] == 1) {
            (true, true) => acc.add_mm(candidate.positions_mm[2 * k] - reference.positions_mm[2 * k], candidate.positions_mm[2 * k + 1] - reference.positions_mm[2 * k + 1]),
            (false, false) => {}
            _ => acc.mismatches += 1,
        }
    }
    acc.finish()
}

fn best_of<T>(repeat: usize, mut f: impl FnMut() -> Result<T>) -> Result<(T, f64)> {
    let mut best = f64::INFINITY;
    let mut last = None;
    for _ in 0..repeat.max(1) {
        let t = Instant::now();
        let v = f()?;
        best = best.min(t.elapsed().as_secs_f64());
        last = Some(v);
    }
    Ok((last.expect("one repeat"), best.max(1e-9)))
}

/// Run every workload with every configuration; `progress` sees each row as it is measured.
pub fn run_tradeoff(system: &SequentialSystem, opts: &TradeoffOptions, progress: &mut dyn FnMut(&TradeoffRow)) -> Result<Vec<TradeoffRow>> {
    let ws = linspace(450.0, 650.0, opts.wavelengths.max(1));
    let threads = rayon::current_num_threads();
    let rays = RaySetSpec::tradeoff(13, opts.pupil_rays(), 7).build(system, &ws)?;
    let ms = opts.mapping_size();
    let rs = render_setup(opts.render_size(), opts.render_rays(), &ws)?;
    let configs = candidate_configs(&opts.mesh_sag_um());
    let analytic_cfg = BackendConfig::default();
    let analytic = analytic_cfg.build()?;
    // References.
    let ray_ref = analytic.trace(system, &rays)?;
    let map_ref = mapping_cube(system, analytic.as_ref(), ms, ms, 0.01, &ws)?;
    let ref_renderer = Renderer::new(system, analytic.as_ref(), rs.config.clone(), rs.mask.clone())?;
    let render_ref_transport = ref_renderer.trace_all(&|_| {})?;
    let render_ref = ref_renderer.render(&rs.scene, false, &|_| {})?;
    let pixel_planes = (rs.mask.values.iter().filter(|v| **v > 0.0).count() * rs.config.spectral.planes()) as u64;

    let mut rows: Vec<TradeoffRow> = Vec::new();
    let mut emit = |mut row: TradeoffRow, rows: &mut Vec<TradeoffRow>| {
        // The first row of each workload is the analytic f64 reference (configs[0]).
        let base = rows.iter().find(|r| r.workload == row.workload).map(|r| r.items_per_s);
        row.speed_vs_analytic = base.map(|b| row.items_per_s / b).unwrap_or(1.0);
        progress(&row);
        rows.push(row);
    };
    let row = |workload: &str, cfg: (String, String), rays: u64, items: u64, seconds: f64, error: ErrorStats, setup: f64, img: Option<(f64, f64)>| TradeoffRow {
        workload: workload.into(),
        backend: cfg.0,
        options: cfg.1,
        threads,
        rays,
        items,
        seconds,
        rays_per_s: rays as f64 / seconds,
        items_per_s: items as f64 / seconds,
        speed_vs_analytic: 1.0,
        error,
        setup_seconds: setup,
        image_max_rel: img.map(|i| i.0),
        image_rms_rel: img.map(|i| i.1),
    };

    let mut render_rows = Vec::new();
    let mut mapping_rows = Vec::new();
    for cfg in &configs {
        let tracer = cfg.build()?;
        let t = Instant::now();
        tracer.trace(system, &super::measure::first_ray(&rays))?; // builds an Embree scene
        let setup = if matches!(cfg.backend, Backend::Analytic | Backend::AnalyticF32) { 0.0 } else { t.elapsed().as_secs_f64() };
        // rays
        let (out, secs) = time_best(tracer.as_ref(), system, &rays, opts.repeat)?;
        emit(row("rays", describe(cfg), rays.len() as u64, rays.len() as u64, secs, ErrorStats::compare(&ray_ref, &out), setup, None), &mut rows);
        // mapping (exact cube through this backend)
        let n_map = (ms * ms * ws.len()) as u64;
        let (cube, secs) = best_of(opts.repeat, || mapping_cube(system, tracer.as_ref(), ms, ms, 0.01, &ws))?;
        mapping_rows.push(row("mapping", describe(cfg), n_map, n_map, secs, mapping_error(&map_ref, &cube), setup, None));
        // render (same rays as the analytic reference render)
        // (f32 renders through the analytic tracer's direct path in f32, as `render --precision f32` does.)
        let (render_tracer, render_cfg) = match cfg.backend {
            Backend::AnalyticF32 => (analytic.as_ref(), RenderConfig { precision: crate::tracer::Precision::F32, ..rs.config.clone() }),
            _ => (tracer.as_ref(), rs.config.clone()),
        };
        let mut r = Renderer::new(system, render_tracer, render_cfg, rs.mask.clone())?;
        r.detector = ref_renderer.detector;
        let (acq, secs) = best_of(opts.repeat, || r.render(&rs.scene, false, &|_| {}))?;
        let transport = r.trace_all(&|_| {})?;
        let err = centroid_error(&render_ref_transport, &transport, r.detector.pitch_mm);
        let mut d = describe(cfg);
        d.1 = format!("{},rays_per_pixel={}", d.1, rs.config.rays_per_pixel);
        render_rows.push(row("render", d, acq.stats.traced, pixel_planes, secs, err, setup, Some(image_diff(&render_ref.image, &acq.image))));
    }
    // Cheaper models on the analytic tracer: interpolated mapping cubes.
    for s in opts.strides() {
        let n_map = (ms * ms * ws.len()) as u64;
        let (cube, secs) = best_of(opts.repeat, || mapping_cube_interpolated(system, analytic.as_ref(), ms, ms, 0.01, &ws, s))?;
        let traced = (crate::analysis::NodeGrid::count(ms, ms, s) * ws.len()) as u64;
        mapping_rows.push(row("mapping", ("analytic".into(), format!("f64,stride={s}")), traced, n_map, secs, mapping_error(&map_ref, &cube), 0.0, None));
    }
    for r in mapping_rows {
        emit(r, &mut rows);
    }
    // Rays per pixel: the analytic render at N against a high-N analytic render.
    let mut hi = rs.config.clone();
    hi.rays_per_pixel = opts.render_reference_rays();
    let hi_renderer = Renderer::new(system, analytic.as_ref(), hi, rs.mask.clone())?;
    let hi_transport = hi_renderer.trace_all(&|_| {})?;
    let hi_acq = hi_renderer.render(&rs.scene, false, &|_| {})?;
    for r in render_rows {
        emit(r, &mut rows);
    }
    for n in opts.ladder() {
        let mut c = rs.config.clone();
        c.rays_per_pixel = n;
        c.seed = 1; // independent of the reference's random numbers
        let mut r = Renderer::new(system, analytic.as_ref(), c, rs.mask.clone())?;
        r.detector = hi_renderer.detector;
        let (acq, secs) = best_of(opts.repeat, || r.render(&rs.scene, false, &|_| {}))?;
        let transport = r.trace_all(&|_| {})?;
        let err = centroid_error(&hi_transport, &transport, r.detector.pitch_mm);
        emit(
            row("render", ("analytic".into(), format!("f64,rays_per_pixel={n},vs_rays_per_pixel={}", opts.render_reference_rays())), acq.stats.traced, pixel_planes, secs, err, 0.0, Some(image_diff(&hi_acq.image, &acq.image))),
            &mut rows,
        );
    }
    Ok(rows)
}

/// The CSV columns, in order.
pub const CSV_COLUMNS: [&str; 17] = [
    "workload", "backend", "options", "error_max_um", "error_rms_um", "rays_per_s", "items_per_s", "speed_vs_analytic", "threads", "rays", "items", "seconds", "setup_seconds", "compared", "mismatches", "image_max_rel", "image_rms_rel",
];

/// Write the rows as CSV (atomically).
pub fn write_csv(path: &Path, system: &SequentialSystem, opts: &TradeoffOptions, rows: &[TradeoffRow]) -> Result<()> {
    let mut w = CsvWriter::new(path, &CSV_COLUMNS)?;
    w.comment(&format!(
        "diffcassi {} bench tradeoff: system {}, {} wavelengths 450-650 nm, {} mode; errors are image-plane distances (um) to the analytic f64 reference; render errors are splat-centroid displacements (see docs/tradeoff.md)",
        env!("CARGO_PKG_VERSION"),
        system.name(),
        opts.wavelengths,
        if opts.quick { "quick" } else { "full" }
    ));
    for r in rows {
        let opt = |v: Option<f64>| v.map(CsvValue::F64).unwrap_or(CsvValue::Str(""));
        w.row(&[
            CsvValue::Str(&r.workload),
            CsvValue::Str(&r.backend),
            CsvValue::Str(&r.options.replace(',', ";")),
            CsvValue::F64(r.error.max_um),
            CsvValue::F64(r.error.rms_um),
            CsvValue::F64(r.rays_per_s),
            CsvValue::F64(r.items_per_s),
            CsvValue::F64(r.speed_vs_analytic),
            CsvValue::Int(r.threads as i64),
            CsvValue::Int(r.rays as i64),
            CsvValue::Int(r.items as i64),
            CsvValue::F64(r.seconds),
            CsvValue::F64(r.setup_seconds),
            CsvValue::Int(r.error.compared as i64),
            CsvValue::Int(r.error.mismatches as i64),
            opt(r.image_max_rel),
            opt(r.image_rms_rel),
        ])?;
    }
    w.finish()?;
    Ok(())
}

/// A Markdown table of the rows (for the terminal and docs/tradeoff.md).
pub fn markdown(rows: &[TradeoffRow]) -> String {
    let mut s = String::from("| workload | backend | options | max error µm | RMS error µm | mismatches | M rays/s | M items/s | vs analytic | set-up s |\n|---|---|---|---|---|---|---|---|---|---|\n");
    for r in rows {
        s += &format!(
            "| {} | {} | {} | {:.2e} | {:.2e} | {} | {:.3} | {:.3} | {:.2}× | {:.2} |\n",
            r.workload, r.backend, r.options, r.error.max_um, r.error.rms_um, r.error.mismatches, r.rays_per_s / 1e6, r.items_per_s / 1e6, r.speed_vs_analytic, r.setup_seconds
        );
    }
    s
}

/// Reject a row set that cannot be plotted or reported (no rows).
pub fn check_rows(rows: &[TradeoffRow]) -> Result<()> {
    if rows.is_empty() {
        return Err(Error::invalid("the trade-off produced no rows"));
    }
    Ok(())
}

/// Short point label of a row for the plot.
fn label(r: &TradeoffRow) -> String {
    let b = match r.backend.as_str() {
        "analytic" => "analytic",
        "embree-user" => "user",
        "embree-mesh" => "mesh",
        other => other,
    };
    let o = r.options.replace("refine=", "").replace("max-sag=", "").replace("rays_per_pixel=", "N=").replace(",vs_N=", " vs N=").replace(",stride=", " stride ").replace(',', " ");
    format!("{b} {o}")
}

/// The frontier PNG: one panel per workload, max error vs items/s.
pub fn plot(path: &Path, system: &SequentialSystem, rows: &[TradeoffRow]) -> Result<()> {
    check_rows(rows)?;
    let mut panels = Vec::new();
    for (w, unit) in [("rays", "rays"), ("mapping", "cube entries"), ("render", "scene pixel-planes")] {
        let pts: Vec<crate::plot::FrontierPoint> = rows
            .iter()
            .filter(|r| r.workload == w && r.items_per_s > 0.0)
            .map(|r| crate::plot::FrontierPoint { label: label(r), throughput: r.items_per_s / 1e6, error_um: r.error.max_um })
            .collect();
        if !pts.is_empty() {
            panels.push((format!("{w} (throughput in M {unit}/s)"), pts));
        }
    }
    crate::plot::frontier_plot(path, &format!("{}: speed vs accuracy ({} threads)", system.name(), rows[0].threads), "throughput (M workload items/s, log)", &panels)?;
    Ok(())
}
