//! Fidelity from a tolerance: choose the cheapest configuration whose *measured* error on this system and
//! these wavelengths is within the tolerance (µm, image plane, against the analytic f64 reference).
//!
//! Three jobs, three sets of candidates:
//!
//! * **rays** (trace, spot, distortion, dispersion): the backends of [`candidate_configs`]
//!   (analytic f64; Embree user geometry f64/none; Embree meshes at 10, 1, 0.1 µm chord-sag, f64/none),
//!   each measured on the [`RaySetSpec::calibration`] set at the job's wavelengths: error (max over rays,
//!   plus classification mismatches, which disqualify) and throughput in the same run. A mapping or a
//!   render measures them over its own field too ([`calibrate_backends_over`]: the cube's or the scene's
//!   half width, where it is wider than the system's fields).
//! * **mapping**: the backends (exact cube) and the interpolated cube of
//!   [`crate::analysis::mapping_cube_interpolated`] at strides 2–32 on the analytic tracer, whose error is
//!   measured at 281 check pixels (seeded random, corners, centre, and each stride's corner cells) at the
//!   shortest, middle and longest wavelength against exactly traced chief rays, and whose cost is timed at
//!   the middle wavelength.
//! * **render**: backends × rays per pixel N, including the f32 lane kernel (`analytic-f32`, rendered as
//!   `--precision f32`; the only job that may choose it, see [`render_only`]). The render's error (µm) is
//!   defined as the error of where a scene pixel's energy lands on the detector: the backend's position
//!   error plus the Monte-Carlo standard error of the mean landing position of N rays, σ/√N, with σ the
//!   RMS radius of a pixel's ray landings about their mean (pupil × pixel area; largest over a 3×3 grid of pixels at the shortest,
//!   middle and longest plane, 1024 stratified rays each). σ/√N is the standard error of independent
//!   sampling; the stratified sampler does at least about as well (Owen 1997: variance ≤ N/(N−1) × that
//!   of independent sampling).
//!
//! Cost = set-up (Embree scene) + job size / measured throughput. The analytic tracer is the exact
//! reference; another configuration replaces it only when its predicted cost is below the analytic's by
//! the margin [`SPEED_MARGIN`], so timing noise alone never trades exactness for nothing — and, for a
//! render, only at no more rays per pixel than the analytic tracer needs (a faster kernel paying for more
//! rays is decided by throughputs within a few % of each other, so the acquisition would depend on the
//! run's timing). Throughputs are timed in interleaved rounds and a candidate is credited with its smallest
//! speed-up over the analytic tracer in one round ([`TIMING_ROUNDS`]), so a disturbed round can only keep the
//! exact tracer. Calibrations are cached ([`super::cache`]), first writer wins: one cache, one choice.
use super::cache::{self, CacheKey, Lookup};
use super::measure::{backend_text, candidate_configs, time_best, Measured};
use super::workload::{scene_half_width, RaySetSpec};
use crate::analysis::{mapping_cube_interpolated, MappingCube, NodeGrid};
use crate::error::{Error, Result};
use crate::rays::{aimed_ray, object_ray, RayBatch};
use crate::render::{RaySampler, RenderConfig};
use crate::spec::RayAiming;
use crate::system::SequentialSystem;
use crate::tracer::{AnalyticTracer, Backend, BackendConfig, Precision, RayStatus, Tracer};
use rand::{Rng, SeedableRng};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// A non-reference configuration must be predicted this many times cheaper than the analytic tracer
/// to be chosen over it.
pub const SPEED_MARGIN: f64 = 1.25;
/// Chord-sag bounds (µm) of the mesh candidates of `--tolerance-um`. (0.01 µm is left out: its scene takes
/// ~26 s to build for SP, longer than the analytic trace of any job here, and its unrefined error, f32
/// limited, is no better than user geometry's; `bench tradeoff` measures it.)
pub const SELECTOR_MESH_SAG_UM: [f64; 3] = [10.0, 1.0, 0.1];
/// Interpolation strides the mapping selector considers.
pub const MAPPING_STRIDES: [usize; 6] = [1, 2, 4, 8, 16, 32];
/// Most rays per pixel a render tolerance may ask for.
pub const MAX_RAYS_PER_PIXEL: usize = 4096;

/// Where calibrations are cached (`None`: not at all).
#[derive(Clone, Debug, Default)]
pub struct CacheOptions {
    pub dir: Option<PathBuf>,
}

impl CacheOptions {
    /// The default directory (environment), or `explicit`.
    pub fn resolve(explicit: Option<&Path>) -> Self {
        CacheOptions { dir: cache::cache_dir(explicit) }
    }

    /// [`Self::resolve`] for a directory a caller named (`--calibration-cache DIR`): refused when it exists and
    /// is not a directory (a file named by mistake was reported as a "corrupt entry" at every lookup). One that
    /// does not exist yet is created when a calibration is stored.
    pub fn checked(explicit: Option<&Path>) -> Result<Self> {
        if let Some(p) = explicit {
            if p.exists() && !p.is_dir() {
                return Err(Error::invalid(format!("--calibration-cache {}: not a directory (the calibration cache is a folder of JSON files)", p.display())));
            }
        }
        Ok(Self::resolve(explicit))
    }
    pub fn none() -> Self {
        CacheOptions { dir: None }
    }
}

/// Where a calibration came from, for the printed explanation.
#[derive(Clone, Debug, PartialEq)]
pub enum Provenance {
    /// Calibrated now; `cache_note` says why the cache did not serve or keep it (a corrupt entry ignored, a
    /// directory that cannot be written), `None` when it did or there is none.
    Measured { rays: usize, seconds: f64, cache_note: Option<String> },
    Cached(PathBuf),
    /// Calibrated now (`seconds`), but another process stored this key's calibration first while this one
    /// ran: that entry is used and this measurement dropped, so every process on one cache makes one choice
    /// ([`cache::store_first`]).
    Adopted { path: PathBuf, seconds: f64 },
}

impl std::fmt::Display for Provenance {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Provenance::Measured { rays, seconds, cache_note: None } => write!(f, "calibrated now on {rays} rays in {seconds:.2} s"),
            Provenance::Measured { rays, seconds, cache_note: Some(n) } => write!(f, "calibrated now on {rays} rays in {seconds:.2} s; cache: {n}"),
            Provenance::Cached(p) => write!(f, "calibration from the cache {}", p.display()),
            Provenance::Adopted { path, seconds } => write!(f, "calibration from the cache {}, stored by another run while this one calibrated ({seconds:.2} s, its own measurement dropped: one cache, one choice)", path.display()),
        }
    }
}

fn check_tolerance(tolerance_um: f64) -> Result<()> {
    if tolerance_um.is_finite() && tolerance_um > 0.0 {
        Ok(())
    } else {
        Err(Error::invalid(format!("--tolerance-um {tolerance_um}: must be finite and > 0")))
    }
}

fn spec_text(system: &SequentialSystem) -> String {
    serde_json::to_string(&system.spec).unwrap_or_else(|_| format!("{:?}", system.spec))
}

fn floats_text(v: &[f64]) -> String {
    v.iter().map(|x| format!("{:016x}", x.to_bits())).collect::<Vec<_>>().join(",")
}

/// Equal up to JSON's last-digit rounding (the key already pins the exact values).
fn same_floats(a: &[f64], b: &[f64]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x - y).abs() <= 1e-12 * y.abs().max(1.0))
}

fn finite_nonneg(v: f64) -> bool {
    v.is_finite() && v >= 0.0
}

fn measured_ok(m: &Measured) -> bool {
    finite_nonneg(m.error.max_um) && finite_nonneg(m.error.rms_um) && m.rays_per_s.is_finite() && m.rays_per_s > 0.0 && finite_nonneg(m.setup_seconds) && m.backend.parse::<BackendConfig>().is_ok()
}

/// Load-or-compute through the cache; returns the payload and its provenance.
fn cached<T: serde::Serialize + serde::de::DeserializeOwned>(cache: &CacheOptions, key: &CacheKey, valid: impl Fn(&T) -> bool, compute: impl FnOnce() -> Result<(T, usize)>) -> Result<(T, Provenance)> {
    // What the cache could not do is said in the provenance (the explanation every front end shows), not on
    // the library's own stderr.
    let mut notes = Vec::new();
    if let Some(dir) = &cache.dir {
        match cache::load::<T>(dir, key, &valid) {
            Lookup::Hit(t) => return Ok((t, Provenance::Cached(dir.join(key.file_name())))),
            Lookup::Miss => {}
            Lookup::Corrupt(why) => notes.push(format!("ignored a corrupt entry ({why})")),
        }
    }
    let t0 = Instant::now();
    let (payload, rays) = compute()?;
    let seconds = t0.elapsed().as_secs_f64();
    if let Some(dir) = &cache.dir {
        // First writer wins: a process that stored this key meanwhile (shards started together on a fresh
        // cache) decides for all of them; this one takes its entry instead of choosing on its own timings.
        match cache::store_first(dir, key, &payload, &valid) {
            Ok(cache::Stored::Mine(_)) => {}
            Ok(cache::Stored::Theirs(theirs, path)) => return Ok((theirs, Provenance::Adopted { path, seconds: t0.elapsed().as_secs_f64() })),
            Err(e) => notes.push(format!("not stored ({e})")),
        }
    }
    let cache_note = (!notes.is_empty()).then(|| notes.join("; "));
    Ok((payload, Provenance::Measured { rays, seconds, cache_note }))
}

/// The backend candidates measured on the calibration set of `system` at `wavelengths_nm`.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct BackendCalibration {
    pub wavelengths_nm: Vec<f64>,
    pub rays: usize,
    pub candidates: Vec<Measured>,
    /// The candidates that do not model this system, each with why: said in every choice's explanation (the
    /// library printed them on its own stderr before).
    #[serde(default)]
    pub left_out: Vec<LeftOut>,
}

/// A backend candidate that does not model the system (a diffraction grating for the Embree backends).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LeftOut {
    pub backend: String,
    pub reason: String,
}

impl BackendCalibration {
    /// The explanation's line for [`Self::left_out`], the backends grouped by reason (empty when every
    /// candidate was measured).
    fn left_out_line(&self) -> String {
        let mut groups: Vec<(&str, Vec<&str>)> = Vec::new();
        for l in &self.left_out {
            match groups.iter_mut().find(|g| g.0 == l.reason) {
                Some(g) => g.1.push(&l.backend),
                None => groups.push((&l.reason, vec![&l.backend])),
            }
        }
        groups.iter().map(|(why, b)| format!("\n  left out: {} ({why})", b.join(", "))).collect()
    }
}

/// Measure every backend candidate on the system's fields (cached).
pub fn calibrate_backends(system: &SequentialSystem, wavelengths_nm: &[f64], cache: &CacheOptions) -> Result<(BackendCalibration, Provenance)> {
    calibrate_backends_over(system, wavelengths_nm, None, cache)
}

/// [`calibrate_backends`] over a job's own field as well (`half_width`: the system's field unit, mm or rad;
/// [`RaySetSpec::covering`]): a render's scene or a mapping's cube may reach beyond the system's fields,
/// where f32's error is larger (a lens file with an axial field only was calibrated on the axis).
pub fn calibrate_backends_over(system: &SequentialSystem, wavelengths_nm: &[f64], half_width: Option<f64>, cache: &CacheOptions) -> Result<(BackendCalibration, Provenance)> {
    let configs = candidate_configs(&SELECTOR_MESH_SAG_UM);
    let cfg_text: Vec<String> = configs.iter().map(backend_text).collect();
    let set = match half_width {
        Some(h) => RaySetSpec::calibration().covering(system, h),
        None => RaySetSpec::calibration(),
    };
    let mut parts = vec![spec_text(system), floats_text(wavelengths_nm), cfg_text.join(";")];
    // (The system's own set keeps its key: caches written before the covering set stay valid.)
    if let Some(h) = set.cover_half_width {
        parts.push(format!("cover {:016x}", h.to_bits()));
    }
    let key = CacheKey::new("backends", &parts.iter().map(String::as_str).collect::<Vec<_>>());
    let n = configs.len();
    cached(
        cache,
        &key,
        |c: &BackendCalibration| {
            c.candidates.len() <= n && c.candidates.iter().any(|m| m.backend == "analytic") && c.candidates.iter().all(measured_ok) && same_floats(&c.wavelengths_nm, wavelengths_nm)
        },
        || {
            let rays = set.build(system, wavelengths_nm)?;
            let reference = AnalyticTracer::default().trace(system, &rays)?;
            let (mut prepared, mut left_out) = (Vec::new(), Vec::new());
            for cfg in &configs {
                match prepare(system, cfg, &rays, &reference) {
                    Ok(p) => prepared.push(p),
                    // A backend that does not model this system (the Embree and f32 lane backends refuse
                    // some surfaces, naming them) is no candidate; the exact reference must always be one.
                    Err(e) if !is_reference(cfg) => left_out.push(LeftOut { backend: backend_text(cfg), reason: e.to_string() }),
                    Err(e) => return Err(e),
                }
            }
            let (candidates, traced) = time_interleaved(system, prepared, &rays)?;
            Ok((BackendCalibration { wavelengths_nm: wavelengths_nm.to_vec(), rays: rays.len(), candidates, left_out }, traced))
        },
    )
}

/// Timing rounds of a backend calibration: every candidate is timed once per round, in an order rotated
/// each round (interleaved, so a slow spell of a shared machine hits every candidate alike).
pub const TIMING_ROUNDS: usize = 7;
/// A timing sample repeats a fast candidate's trace until it lasts at least this long (s): one trace of
/// the calibration set takes ~0.3 ms on the analytic tracer, within a thread pool's wake-up noise.
pub const TIMING_SAMPLE_SECONDS: f64 = 2e-3;

/// A candidate built, its scene set up (timed), its error measured, ready for the timing rounds.
struct Prepared {
    cfg: BackendConfig,
    tracer: Box<dyn Tracer>,
    setup_seconds: f64,
    error: super::ErrorStats,
    /// Traces per timing sample (≥ 1).
    repeats: usize,
}

fn prepare(system: &SequentialSystem, cfg: &BackendConfig, rays: &RayBatch, reference: &crate::tracer::TracedBatch) -> Result<Prepared> {
    let tracer = cfg.build()?;
    // Set-up: the first trace of one ray builds an Embree scene.
    let t = Instant::now();
    tracer.trace(system, &super::measure::first_ray(rays))?;
    let setup_seconds = if matches!(cfg.backend, Backend::Analytic | Backend::AnalyticF32) { 0.0 } else { t.elapsed().as_secs_f64() };
    // The error, from an untimed trace of the whole set (also the timing's warm-up).
    let t = Instant::now();
    let out = tracer.trace(system, rays)?;
    let once = t.elapsed().as_secs_f64().max(1e-9);
    let error = super::ErrorStats::compare(reference, &out);
    let repeats = ((TIMING_SAMPLE_SECONDS / once).ceil() as usize).clamp(1, 64);
    Ok(Prepared { cfg: cfg.clone(), tracer, setup_seconds, error, repeats })
}

/// Time the candidates in [`TIMING_ROUNDS`] interleaved rounds and credit each with a throughput: the
/// analytic reference with its median; every other candidate with the reference's median × its *smallest*
/// speed-up over the reference in the same round (the two timed back to back). A candidate therefore
/// counts as faster by the choice's [`SPEED_MARGIN`] only if it was that much faster in every round: a
/// disturbed round can only keep the exact tracer, never trade it away (a held-out battery, round 20: the
/// f32 lanes' best-of-3 speed-up on SP was 1.23–1.27× run to run, 1.5–1.8× in a disturbed run, around the
/// 1.25× margin, so a fresh calibration chose f32 or f64 by chance). Returns the candidates and the rays
/// traced.
fn time_interleaved(system: &SequentialSystem, prepared: Vec<Prepared>, rays: &RayBatch) -> Result<(Vec<Measured>, usize)> {
    let n = prepared.len();
    let mut times = vec![Vec::with_capacity(TIMING_ROUNDS); n];
    let mut traced = rays.len() * (1 + 2 * n);
    for round in 0..TIMING_ROUNDS {
        for k in 0..n {
            let i = (k + round) % n;
            let p = &prepared[i];
            let t = Instant::now();
            for _ in 0..p.repeats {
                p.tracer.trace(system, rays)?;
            }
            times[i].push((t.elapsed().as_secs_f64() / p.repeats as f64).max(1e-9));
            traced += rays.len() * p.repeats;
        }
    }
    let median = |v: &[f64]| {
        let mut s = v.to_vec();
        s.sort_by(f64::total_cmp);
        s[s.len() / 2]
    };
    let r = prepared.iter().position(|p| is_reference(&p.cfg)).ok_or_else(|| Error::invalid("calibration lacks the analytic reference"))?;
    let ref_median = median(&times[r]);
    let candidates = prepared
        .iter()
        .zip(&times)
        .enumerate()
        .map(|(i, (p, t))| {
            let seconds = median(t);
            let rays_per_s = if i == r {
                rays.len() as f64 / ref_median
            } else {
                let speedup = t.iter().zip(&times[r]).map(|(c, a)| a / c).fold(f64::INFINITY, f64::min);
                rays.len() as f64 / ref_median * speedup
            };
            Measured { backend: backend_text(&p.cfg), error: p.error, rays_per_s, seconds, setup_seconds: p.setup_seconds }
        })
        .collect();
    Ok((candidates, traced))
}

/// A chosen configuration and why.
#[derive(Clone, Debug)]
pub struct Choice {
    pub config: BackendConfig,
    /// Predicted error (µm) of the choice.
    pub error_um: f64,
    /// Predicted cost of the job (s) with the choice, and with the analytic tracer.
    pub predicted_seconds: f64,
    pub analytic_seconds: f64,
    /// One or two lines: what was chosen, the candidates with their error and speed.
    pub explanation: String,
}

fn pick<T: Clone>(items: &[(T, f64, f64, bool)]) -> Option<(T, f64, f64)> {
    // items: (candidate, error, cost, is_reference); feasible ones only.
    let reference = items.iter().find(|i| i.3);
    let best = items.iter().filter(|i| !i.3).min_by(|a, b| a.2.total_cmp(&b.2));
    match (reference, best) {
        (Some(r), Some(b)) if b.2 * SPEED_MARGIN < r.2 => Some((b.0.clone(), b.1, b.2)),
        (Some(r), _) => Some((r.0.clone(), r.1, r.2)),
        (None, Some(b)) => Some((b.0.clone(), b.1, b.2)),
        (None, None) => None,
    }
}

fn fmt_err(e: f64) -> String {
    if e == 0.0 {
        "0".into()
    } else {
        format!("{e:.2e}")
    }
}

/// Choose the backend for a job of `job_rays` rays at tolerance `tolerance_um` from a calibration.
pub fn choose_backend(cal: &BackendCalibration, tolerance_um: f64, job_rays: u64) -> Result<Choice> {
    check_tolerance(tolerance_um)?;
    // The tolerance as typed, not 309 digits for 1e308 (round 12).
    let tol = crate::limits::fmt_num(tolerance_um);
    let cost = |m: &Measured| m.setup_seconds + job_rays as f64 / m.rays_per_s;
    let analytic = cal.candidates.iter().find(|m| m.backend == "analytic").ok_or_else(|| Error::invalid("calibration lacks the analytic reference"))?;
    let items: Vec<(&Measured, f64, f64, bool)> = cal.candidates.iter().filter(|m| !render_only(m) && m.error.within(tolerance_um)).map(|m| (m, m.error.max_um, cost(m), m.backend == "analytic")).collect();
    let (m, err, secs) = pick(&items).ok_or_else(|| Error::invalid(format!("no configuration meets --tolerance-um {tol}")))?;
    let list: Vec<String> = cal
        .candidates
        .iter()
        .map(|c| format!("{} {} µm{} {:.2} M rays/s", c.backend, fmt_err(c.error.max_um), if c.error.mismatches > 0 { format!(" ({} mismatches)", c.error.mismatches) } else { String::new() }, c.rays_per_s / 1e6))
        .collect();
    let explanation = format!(
        "fidelity: tolerance {tol} µm → --backend {} (max error {} µm ≤ {tol}, predicted {:.3} s for {job_rays} rays; analytic {:.3} s)\n  candidates (max error vs analytic f64, throughput): {}",
        m.backend,
        fmt_err(err),
        secs,
        cost(analytic),
        list.join("; ")
    ) + &cal.left_out_line();
    Ok(Choice { config: m.backend.parse()?, error_um: err, predicted_seconds: secs, analytic_seconds: cost(analytic), explanation })
}

// ---------------------------------------------------------------- mapping

/// One interpolation stride measured.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct StrideModel {
    pub stride: usize,
    /// Interpolation error at the check pixels (µm); `None` when a node did not arrive.
    pub error: Option<super::ErrorStats>,
    /// Seconds to build the cube at one wavelength (analytic tracer).
    pub seconds_per_wavelength: f64,
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct MappingCalibration {
    pub strides: Vec<StrideModel>,
}

/// The factor on an interpolated cube's measured error before it is compared with `--tolerance-um` (and
/// reported): the measurement is a maximum over [`check_pixels`] at three wavelengths, which a held-out battery
/// (round 12) found 0.5–3.6 % below the whole cube's maximum (map and ap, 64² and 256², 8 wavelengths: the
/// worst entries at a wavelength between the calibrated ones), so a tolerance between the two was exceeded.
pub const SAMPLED_ERROR_MARGIN: f64 = 1.1;

/// The check pixels: 256 seeded random pixels, the four corners and the centre, and for every stride the
/// four pixels halfway between nodes in the corner cells of its node lattice (the outermost field, where
/// random pixels rarely fall and the interpolation error is largest: without them the measured maximum
/// was 13–23 % below the whole cube's on SP and mSP at 512×512, with them within 2 %; `bench-render
/// --parts mapping` prints both).
fn check_pixels(height: usize, width: usize) -> Vec<(usize, usize)> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x6d61_7070);
    let mut v: Vec<(usize, usize)> = (0..256).map(|_| (rng.gen_range(0..height), rng.gen_range(0..width))).collect();
    v.extend([(0, 0), (0, width - 1), (height - 1, 0), (height - 1, width - 1), (height / 2, width / 2)]);
    // Midpoints of the first and of the last node interval of an axis of n pixels at stride s.
    let mids = |n: usize, s: usize| {
        let last = (n - 1).div_ceil(s).max(1) - 1;
        [(s / 2).min(n - 1), (last * s + s / 2).min(n - 1)]
    };
    for &s in MAPPING_STRIDES.iter().filter(|&&s| s > 1) {
        for r in mids(height, s) {
            for c in mids(width, s) {
                v.push((r, c));
            }
        }
    }
    v
}

fn three_wavelengths(ws: &[f64]) -> Vec<f64> {
    let mut s = ws.to_vec();
    s.sort_by(f64::total_cmp);
    let mut v = vec![s[0], s[s.len() / 2], s[s.len() - 1]];
    v.dedup();
    v
}

/// Measure the interpolated mapping at each stride (cached).
pub fn calibrate_mapping(system: &SequentialSystem, height: usize, width: usize, pitch_mm: f64, wavelengths_nm: &[f64], cache: &CacheOptions) -> Result<(MappingCalibration, Provenance)> {
    if height == 0 || width == 0 || wavelengths_nm.is_empty() {
        return Err(Error::invalid(format!("mapping cube {height}×{width}×{}: every dimension must be ≥ 1", wavelengths_nm.len())));
    }
    let key = CacheKey::new("mapping-2", &[&spec_text(system), &floats_text(wavelengths_nm), &format!("{height}x{width}@{:016x}", pitch_mm.to_bits())]);
    cached(
        cache,
        &key,
        |c: &MappingCalibration| {
            c.strides.len() == MAPPING_STRIDES.len()
                && c.strides.iter().all(|s| finite_nonneg(s.seconds_per_wavelength) && s.error.map_or(true, |e| finite_nonneg(e.max_um) && finite_nonneg(e.rms_um)))
        },
        || {
            let tracer = AnalyticTracer::default();
            let ws3 = three_wavelengths(wavelengths_nm);
            let mid = ws3[ws3.len() / 2];
            let px = check_pixels(height, width);
            let fields: Vec<[f64; 2]> = px.iter().map(|&(r, c)| MappingCube::scene_xy(height, width, pitch_mm, r, c)).collect();
            let mut exact = Vec::new();
            for &w in &ws3 {
                exact.push(tracer.trace(system, &RayBatch::chief_rays(system, &fields, w)?)?);
            }
            let mut rays = fields.len() * ws3.len();
            let mut strides = Vec::new();
            for &s in &MAPPING_STRIDES {
                let t = Instant::now();
                let built = mapping_cube_interpolated(system, &tracer, height, width, pitch_mm, &[mid], s);
                let seconds_per_wavelength = t.elapsed().as_secs_f64();
                let error = match (s, built) {
                    (1, Ok(_)) => Some(super::ErrorStats::default()),
                    (_, Err(_)) => None,
                    (_, Ok(_)) => match NodeGrid::trace(system, &tracer, height, width, pitch_mm, &ws3, s) {
                        Err(_) => None,
                        Ok(g) => {
                            rays += g.rows * g.cols * ws3.len();
                            let mut acc = super::ErrorAccumulator::default();
                            for (b, ex) in exact.iter().enumerate() {
                                for (k, &(r, c)) in px.iter().enumerate() {
                                    if ex.status[k] == RayStatus::Ok {
                                        let v = g.at(r, c, b);
                                        acc.add_mm(v[0] - ex.x[k], v[1] - ex.y[k]);
                                    } else {
                                        acc.mismatches += 1;
                                    }
                                }
                            }
                            Some(acc.finish())
                        }
                    },
                };
                rays += if s == 1 { height * width } else { NodeGrid::count(height, width, s) };
                strides.push(StrideModel { stride: s, error, seconds_per_wavelength });
            }
            Ok((MappingCalibration { strides }, rays))
        },
    )
}

/// The chosen mapping model: a backend and an interpolation stride.
#[derive(Clone, Debug)]
pub struct MappingChoice {
    pub config: BackendConfig,
    pub stride: usize,
    pub error_um: f64,
    pub explanation: String,
}

/// Choose backend and stride for an H×W×Nλ cube at `tolerance_um`.
pub fn choose_mapping(backends: &BackendCalibration, mapping: &MappingCalibration, tolerance_um: f64, wavelengths: usize) -> Result<MappingChoice> {
    check_tolerance(tolerance_um)?;
    // The tolerance as typed, not 309 digits for 1e308 (round 12).
    let tol = crate::limits::fmt_num(tolerance_um);
    let nl = wavelengths as f64;
    let analytic = backends.candidates.iter().find(|m| m.backend == "analytic").ok_or_else(|| Error::invalid("calibration lacks the analytic reference"))?;
    let exact = mapping.strides.iter().find(|s| s.stride == 1).ok_or_else(|| Error::invalid("mapping calibration lacks stride 1"))?;
    let exact_secs = exact.seconds_per_wavelength * nl;
    // (backend text, stride, error, cost, is_reference)
    let mut all: Vec<((String, usize), f64, f64, bool)> = Vec::new();
    for m in backends.candidates.iter().filter(|m| !render_only(m)) {
        let cost = m.setup_seconds + exact_secs * analytic.rays_per_s / m.rays_per_s;
        all.push(((m.backend.clone(), 1), if m.error.mismatches > 0 { f64::INFINITY } else { m.error.max_um }, cost, m.backend == "analytic"));
    }
    for s in mapping.strides.iter().filter(|s| s.stride > 1) {
        let e = s.error.map(|e| if e.mismatches > 0 { f64::INFINITY } else { e.max_um * SAMPLED_ERROR_MARGIN }).unwrap_or(f64::INFINITY);
        all.push((("analytic".into(), s.stride), e, s.seconds_per_wavelength * nl, false));
    }
    let feasible: Vec<_> = all.iter().filter(|i| i.1 <= tolerance_um).cloned().collect();
    let ((backend, stride), err, secs) = pick(&feasible).ok_or_else(|| Error::invalid(format!("no mapping model meets --tolerance-um {tol}")))?;
    let list: Vec<String> = all
        .iter()
        .map(|((b, s), e, c, _)| format!("{b}{} {} µm {:.3} s", if *s > 1 { format!(" stride {s}") } else { String::new() }, if e.is_finite() { fmt_err(*e) } else { "n/a".into() }, c))
        .collect();
    let explanation = format!(
        "fidelity: tolerance {tol} µm → mapping with --backend {backend}, {} (max error {} µm, predicted {secs:.3} s; exact analytic {exact_secs:.3} s)\n  candidates (max error vs exact analytic chief rays, predicted time): {}",
        if stride > 1 { format!("chief rays every {stride} pixels, cubic interpolation between") } else { "every chief ray traced".into() },
        fmt_err(err),
        list.join("; ")
    ) + &backends.left_out_line();
    Ok(MappingChoice { config: backend.parse()?, stride, error_um: err, explanation })
}

// ---------------------------------------------------------------- render

/// The render's Monte-Carlo spread.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct RenderCalibration {
    /// Largest RMS radius (µm) of one scene pixel's ray landings about their mean, over the check pixels
    /// and planes.
    pub sigma_um: f64,
}

/// Measure σ of the render `config` (cached).
pub fn calibrate_render(system: &SequentialSystem, config: &RenderConfig, cache: &CacheOptions) -> Result<(RenderCalibration, Provenance)> {
    let (h, w) = (config.scene_height, config.scene_width);
    if h == 0 || w == 0 || config.spectral.planes_nm.is_empty() {
        return Err(Error::invalid("render calibration: empty scene or no planes"));
    }
    // The scene pitch in the system's field unit: mm on a finite object plane, radians of field angle for an
    // object at infinity (`--scene-fov-deg` / width), as the renderer samples it.
    let pitch = crate::render::scene_pitch_for(system, config)?;
    let key = CacheKey::new("render", &[&spec_text(system), &floats_text(&config.spectral.planes_nm), &format!("{h}x{w}@{:016x} {:?}", pitch.to_bits(), config.sampling)]);
    cached(
        cache,
        &key,
        |c: &RenderCalibration| c.sigma_um.is_finite() && c.sigma_um > 0.0,
        || {
            const M: usize = 1024;
            let sampler = RaySampler::new(M, config.sampling);
            let mut samples = vec![[0.0; 4]; M];
            let tracer = AnalyticTracer::default();
            let mut sigma: f64 = 0.0;
            let mut rays = 0;
            for (p, &wl) in three_wavelengths(&config.spectral.planes_nm).iter().enumerate() {
                let n = system.indices(wl)?;
                for row in [0, h / 2, h - 1] {
                    for col in [0, w / 2, w - 1] {
                        sampler.fill(config.seed ^ 0xca11b, p as u64, (row * w + col) as u64, &mut samples);
                        let mut batch = RayBatch::with_capacity(M);
                        for s in &samples {
                            let field = MappingCube::sample_xy(h, w, pitch, row, col, s[2], s[3]);
                            let (o, d) = if system.spec.ray_aiming == RayAiming::Off { object_ray(system, field, s[0], s[1]) } else { aimed_ray(system, &n, field, s[0], s[1])? };
                            batch.push(o, d, wl);
                        }
                        rays += M;
                        let out = tracer.trace(system, &batch)?;
                        if let Some(st) = crate::analysis::spot_stats((0..out.len()).filter(|&i| out.status[i] == RayStatus::Ok).map(|i| (out.x[i], out.y[i]))) {
                            sigma = sigma.max(st.rms_radius_um);
                        }
                    }
                }
            }
            if !(sigma > 0.0) {
                return Err(Error::invalid("render calibration: no ray of the check pixels arrived"));
            }
            Ok((RenderCalibration { sigma_um: sigma }, rays))
        },
    )
}

/// The chosen render fidelity: backend and rays per pixel.
#[derive(Clone, Debug)]
pub struct RenderChoice {
    pub config: BackendConfig,
    pub rays_per_pixel: usize,
    pub error_um: f64,
    pub explanation: String,
}

/// Choose backend and rays per pixel for a render of `rays_per_n` rays per unit N at `tolerance_um`.
pub fn choose_render(backends: &BackendCalibration, render: &RenderCalibration, tolerance_um: f64, rays_per_n: u64) -> Result<RenderChoice> {
    check_tolerance(tolerance_um)?;
    // The tolerance as typed, not 309 digits for 1e308 (round 12).
    let tol = crate::limits::fmt_num(tolerance_um);
    let sigma = render.sigma_um;
    let mut items: Vec<((String, usize), f64, f64, bool)> = Vec::new();
    let mut notes = Vec::new();
    for m in backends.candidates.iter().filter(|m| m.error.mismatches == 0) {
        let room = tolerance_um - m.error.max_um;
        if room <= 0.0 {
            continue;
        }
        let n = ((sigma / room).powi(2)).ceil().max(1.0);
        if n > MAX_RAYS_PER_PIXEL as f64 {
            notes.push(format!("{} would need {n:.0} rays per pixel", m.backend));
            continue;
        }
        let n = n as usize;
        let err = m.error.max_um + sigma / (n as f64).sqrt();
        items.push(((m.backend.clone(), n), err, m.setup_seconds + (n as u64 * rays_per_n) as f64 / m.rays_per_s, m.backend == "analytic"));
    }
    // A candidate that needs more rays per pixel than the reference is not offered: whether its faster kernel
    // pays for the extra rays is decided by throughputs a few % apart (f32 at N = 6 against f64 at N = 5 needs
    // 1.5× at the margin; 1.52× was measured, and the same command rendered either acquisition from run to
    // run: a held-out battery, round 7). At the reference's N or fewer the margin keeps the choice stable.
    if let Some(n_ref) = items.iter().find(|i| i.3).map(|i| (i.0).1) {
        let dropped: Vec<String> = items.iter().filter(|i| !i.3 && (i.0).1 > n_ref).map(|i| format!("{} needs N={} > the analytic N={n_ref}", (i.0).0, (i.0).1)).collect();
        items.retain(|i| i.3 || (i.0).1 <= n_ref);
        notes.extend(dropped);
    }
    let ((backend, n), err, secs) = pick(&items).ok_or_else(|| {
        Error::invalid(format!(
            "--tolerance-um {tol}: a render's splat position has a Monte-Carlo standard error σ/√N with σ = {sigma:.2} µm here, so it needs N = {:.0} rays per pixel per plane, above the limit {MAX_RAYS_PER_PIXEL}; give a tolerance ≥ {:.3} µm",
            (sigma / tolerance_um).powi(2).ceil(),
            sigma / (MAX_RAYS_PER_PIXEL as f64).sqrt()
        ))
    })?;
    let explanation = format!(
        "fidelity: tolerance {tol} µm → --backend {backend} --rays {n} (error {} µm = trace error + σ/√N, σ = {sigma:.2} µm the RMS spread of one pixel's ray landings; predicted {secs:.2} s)\n  candidates: {}{}",
        fmt_err(err),
        items.iter().map(|((b, n), e, c, _)| format!("{b} N={n} {} µm {c:.2} s", fmt_err(*e))).collect::<Vec<_>>().join("; "),
        if notes.is_empty() { String::new() } else { format!("; {}", notes.join("; ")) }
    ) + &backends.left_out_line();
    Ok(RenderChoice { config: backend.parse()?, rays_per_pixel: n, error_um: err, explanation })
}

impl RenderChoice {
    /// The render's precision: f32 when the choice is the f32 lane kernel (`analytic-f32`), which the
    /// renderer runs as the analytic tracer's direct path in f32 ([`crate::render::Renderer`]).
    pub fn precision(&self) -> Precision {
        if self.config.backend == Backend::AnalyticF32 {
            Precision::F32
        } else {
            Precision::F64
        }
    }

    /// The tracer to give the renderer: the analytic tracer for `analytic-f32` (its direct path runs in f32
    /// with [`Self::precision`]), else the chosen backend.
    pub fn tracer(&self) -> Result<Box<dyn Tracer>> {
        if self.config.backend == Backend::AnalyticF32 {
            return Ok(Box::new(AnalyticTracer::default()));
        }
        self.config.build()
    }
}

/// The render fidelity `--tolerance-um` chooses for a render of `system` with `config` over `open_pixels`
/// open scene pixels on `device`: the backends calibrated at the render's planes, σ of the render, then
/// [`choose_render`] among the candidates this render can use — for a system with a coded-mask surface
/// (dual-disperser CASSI), and on a device other than the CPU (the GPU kernels and their twin are the
/// analytic tracer's; the candidates' throughputs and the f32 lanes' error are the CPU's, not the device's),
/// the analytic f64 tracer only (the others stay measured, in the calibration, but are not offered).
/// Returns the choice and where the calibrations came from (measured or cached), for the explanation a
/// front end prints. Front ends call it through [`super::RenderTracing::resolve`].
pub fn choose_render_for(system: &SequentialSystem, config: &RenderConfig, device: crate::render::Device, tolerance_um: f64, open_pixels: usize, cache: &CacheOptions) -> Result<(RenderChoice, String)> {
    check_tolerance(tolerance_um)?;
    // Over the scene's field, not only the system's fields.
    let half = scene_half_width(config.scene_height, config.scene_width, crate::render::scene_pitch_for(system, config)?);
    let (mut cal, prov) = calibrate_backends_over(system, &config.spectral.planes_nm, Some(half), cache)?;
    let only_f64 = if system.coded_mask.is_some() {
        Some("a coded-mask surface renders on the analytic f64 direct path only".to_string())
    } else if device != crate::render::Device::Cpu {
        Some(format!("--device {device}: the GPU kernels are the analytic tracer's, chosen in f64 (the other candidates' speeds and the f32 lanes' error are the CPU's)"))
    } else {
        None
    };
    if only_f64.is_some() {
        cal.candidates.retain(|m| m.backend == "analytic");
    }
    let (rc, prov2) = calibrate_render(system, config, cache)?;
    let per_n = (open_pixels * config.spectral.planes()) as u64;
    let mut choice = choose_render(&cal, &rc, tolerance_um, per_n)?;
    if let Some(why) = only_f64 {
        choice.explanation.push_str(&format!("; {why}"));
    }
    Ok((choice, format!("backends: {prov}; σ: {prov2}")))
}

/// Convenience for tests and callers: time one tracer on a ray set (best of `repeat`), rays/s.
pub fn rays_per_second(tracer: &dyn Tracer, system: &SequentialSystem, rays: &RayBatch, repeat: usize) -> Result<f64> {
    Ok(rays.len() as f64 / time_best(tracer, system, rays, repeat)?.1)
}

/// Whether a candidate may only be chosen for renders: the f32 lane kernel (`analytic-f32`). Ray jobs
/// (spot, distortion, dispersion: compared to Zemax) and the mapping stay f64 or the Embree backends; the
/// f32 kernel's measured error is shown in their candidate lists but never chosen there.
pub fn render_only(m: &Measured) -> bool {
    m.backend == "analytic-f32"
}

/// Whether `cfg` is the exact reference.
pub fn is_reference(cfg: &BackendConfig) -> bool {
    cfg.backend == Backend::Analytic
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fidelity::measure::ErrorStats;

    fn measured(backend: &str, max_um: f64, rays_per_s: f64) -> Measured {
        Measured { backend: backend.into(), error: ErrorStats { max_um, rms_um: max_um, compared: 100, mismatches: 0 }, rays_per_s, seconds: 1.0, setup_seconds: 0.0 }
    }

    /// A faster kernel that needs more rays per pixel than the analytic tracer is not chosen, however fast
    /// (the choice would hinge on throughputs a few % apart, and so would the acquisition); at the same N
    /// it is, beyond the margin.
    #[test]
    fn a_render_choice_never_trades_more_rays_for_a_faster_kernel() {
        let rc = RenderCalibration { sigma_um: 10.0 };
        // Tolerance 5.5 µm: f64 (exact) needs N = ⌈(10/5.5)²⌉ = 4; f32 with 0.6 µm of trace error ⌈(10/4.9)²⌉ = 5.
        let cal = BackendCalibration { wavelengths_nm: vec![520.0], rays: 100, candidates: vec![measured("analytic", 0.0, 1e7), measured("analytic-f32", 0.6, 1e9)], left_out: vec![] };
        let c = choose_render(&cal, &rc, 5.5, 1000).unwrap();
        assert_eq!((c.config.backend, c.rays_per_pixel), (Backend::Analytic, 4), "{}", c.explanation);
        assert!(c.explanation.contains("analytic-f32 needs N=5 > the analytic N=4"), "{}", c.explanation);
        // With an f32 error small enough for the same N, the faster kernel wins.
        let cal = BackendCalibration { candidates: vec![measured("analytic", 0.0, 1e7), measured("analytic-f32", 1e-6, 2e7)], ..cal };
        let c = choose_render(&cal, &rc, 5.5, 1000).unwrap();
        assert_eq!((c.config.backend, c.rays_per_pixel), (Backend::AnalyticF32, 4), "{}", c.explanation);
    }
}
