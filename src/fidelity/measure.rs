//! Measuring a configuration: image-plane error against the analytic f64 reference, and throughput.
//!
//! The error of a ray is the distance on the image surface (µm) between where the candidate and the
//! reference put it, over the rays that arrive in both. A ray that arrives in one and not the other is a
//! *classification mismatch*: it has no finite error, so it is counted separately, and a configuration
//! with mismatches never qualifies for a tolerance.
//!
//! ```
//! use diffcassi::fidelity::ErrorStats;
//! use diffcassi::tracer::{RayStatus, TracedBatch};
//! let a = TracedBatch::zeroed(2);
//! let mut b = TracedBatch::zeroed(2);
//! b.x[0] = 1e-3; // 1 µm off
//! b.status[1] = RayStatus::Vignetted;
//! let e = ErrorStats::compare(&a, &b);
//! assert_eq!((e.compared, e.mismatches), (1, 1));
//! assert!((e.max_um - 1.0).abs() < 1e-12);
//! ```
use crate::error::{Error, Result};
use crate::rays::RayBatch;
use crate::system::SequentialSystem;
use crate::tracer::{Backend, BackendConfig, RayStatus, TracedBatch, Tracer};
use std::time::Instant;

/// Image-plane error of a trace against a reference trace of the same rays.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ErrorStats {
    /// Largest image-plane distance (µm) over the rays that arrived in both.
    pub max_um: f64,
    /// Root-mean-square distance (µm) over the same rays.
    pub rms_um: f64,
    /// Rays that arrived in both traces.
    pub compared: usize,
    /// Rays that arrived in exactly one of the two traces.
    pub mismatches: usize,
}

impl ErrorStats {
    /// Compare `candidate` with `reference` (same rays, same order). Positions are mm; errors µm.
    pub fn compare(reference: &TracedBatch, candidate: &TracedBatch) -> ErrorStats {
        let mut acc = ErrorAccumulator::default();
        for i in 0..reference.len().min(candidate.len()) {
            let (r, c) = (reference.status[i] == RayStatus::Ok, candidate.status[i] == RayStatus::Ok);
            match (r, c) {
                (true, true) => acc.add_mm(candidate.x[i] - reference.x[i], candidate.y[i] - reference.y[i]),
                (false, false) => {}
                _ => acc.mismatches += 1,
            }
        }
        acc.mismatches += reference.len().abs_diff(candidate.len());
        acc.finish()
    }

    /// Whether this error meets a tolerance (µm): no mismatches and max ≤ tolerance.
    pub fn within(&self, tolerance_um: f64) -> bool {
        self.mismatches == 0 && self.max_um <= tolerance_um
    }
}

/// Running max / sum of squares of 2-D displacements, in a fixed order (deterministic).
#[derive(Clone, Copy, Debug, Default)]
pub struct ErrorAccumulator {
    max_um: f64,
    sum2_um2: f64,
    n: usize,
    pub mismatches: usize,
}

impl ErrorAccumulator {
    /// Add one displacement given in mm.
    pub fn add_mm(&mut self, dx_mm: f64, dy_mm: f64) {
        let e = 1e3 * dx_mm.hypot(dy_mm);
        self.max_um = self.max_um.max(e);
        self.sum2_um2 += e * e;
        self.n += 1;
    }
    pub fn finish(&self) -> ErrorStats {
        ErrorStats { max_um: self.max_um, rms_um: if self.n > 0 { (self.sum2_um2 / self.n as f64).sqrt() } else { 0.0 }, compared: self.n, mismatches: self.mismatches }
    }
}

/// Backend name and options as two short strings for tables: ("embree-mesh", "max-sag=1um,refine=none").
pub fn describe(cfg: &BackendConfig) -> (String, String) {
    match cfg.backend {
        Backend::Analytic => ("analytic".into(), "f64".into()),
        Backend::AnalyticF32 => ("analytic".into(), "f32".into()),
        Backend::EmbreeUser => ("embree-user".into(), format!("refine={}", refine_text(cfg))),
        Backend::EmbreeMesh => {
            let mesh = match cfg.mesh {
                crate::surfaces::MeshResolution::MaxSagErrorUm(um) => format!("max-sag={um}um"),
                crate::surfaces::MeshResolution::Segments(n) => format!("segments={n}"),
            };
            ("embree-mesh".into(), format!("{mesh},refine={}", refine_text(cfg)))
        }
    }
}

/// The `--backend` text that names `cfg` (parses back to it).
pub fn backend_text(cfg: &BackendConfig) -> String {
    match cfg.backend {
        Backend::Analytic => "analytic".into(),
        Backend::AnalyticF32 => "analytic-f32".into(),
        Backend::EmbreeUser => format!("embree-user:{}", refine_text(cfg)),
        Backend::EmbreeMesh => match cfg.mesh {
            crate::surfaces::MeshResolution::MaxSagErrorUm(um) => format!("embree-mesh:{um}:{}", refine_text(cfg)),
            crate::surfaces::MeshResolution::Segments(n) => format!("embree-mesh(segments={n}):{}", refine_text(cfg)),
        },
    }
}

fn refine_text(cfg: &BackendConfig) -> &'static str {
    match cfg.refine {
        crate::tracer::Refine::F64 => "f64",
        crate::tracer::Refine::None => "none",
    }
}

/// The configurations compared by `bench tradeoff` and considered by `--tolerance-um`: the analytic f64
/// tracer; the analytic f32 lane kernel (chosen for renders only, see [`super::select`]); Embree user
/// geometry with and without f64 refinement; Embree meshes at the given chord-sag bounds (µm), with and
/// without refinement. Embree ones only when this build has them.
pub fn candidate_configs(mesh_sag_um: &[f64]) -> Vec<BackendConfig> {
    use crate::tracer::Refine;
    let mut v = vec![BackendConfig::default(), BackendConfig { backend: Backend::AnalyticF32, ..Default::default() }];
    if BackendConfig::available(Backend::EmbreeUser) {
        for refine in [Refine::F64, Refine::None] {
            v.push(BackendConfig { backend: Backend::EmbreeUser, refine, ..Default::default() });
        }
        for &um in mesh_sag_um {
            for refine in [Refine::F64, Refine::None] {
                v.push(BackendConfig { backend: Backend::EmbreeMesh, refine, mesh: crate::surfaces::MeshResolution::MaxSagErrorUm(um) });
            }
        }
    }
    v
}

/// One configuration measured on one ray set.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Measured {
    /// `--backend` text of the configuration.
    pub backend: String,
    pub error: ErrorStats,
    /// Rays traced per second, scene already built: in `bench tradeoff` the best of the repeats; in a
    /// `--tolerance-um` calibration the throughput the choice credits the candidate with (the analytic
    /// tracer's median over interleaved rounds, × for any other candidate its smallest speed-up over the
    /// analytic in one round: [`super::select`]).
    pub rays_per_s: f64,
    /// Seconds of one trace of the set: the best repeat (`bench tradeoff`), the median round (a calibration).
    pub seconds: f64,
    /// One-time set-up (Embree scene construction), s; 0 for the analytic tracer.
    pub setup_seconds: f64,
}

/// Build `cfg`'s tracer, time its set-up (first trace of one ray builds an Embree scene), trace `rays`
/// `repeat` times (best time kept) and compare with `reference` (the analytic trace of `rays`).
pub fn measure(system: &SequentialSystem, cfg: &BackendConfig, rays: &RayBatch, reference: &TracedBatch, repeat: usize) -> Result<(Measured, TracedBatch)> {
    if rays.is_empty() {
        return Err(Error::invalid("cannot measure a configuration on an empty ray set"));
    }
    let tracer = cfg.build()?;
    let t = Instant::now();
    tracer.trace(system, &first_ray(rays))?;
    let setup_seconds = if matches!(cfg.backend, Backend::Analytic | Backend::AnalyticF32) { 0.0 } else { t.elapsed().as_secs_f64() };
    let (out, seconds) = time_best(tracer.as_ref(), system, rays, repeat)?;
    let error = ErrorStats::compare(reference, &out);
    Ok((Measured { backend: backend_text(cfg), error, rays_per_s: rays.len() as f64 / seconds, seconds, setup_seconds }, out))
}

/// Trace `rays` `repeat` (≥ 1) times; the last result and the best wall time (s).
pub fn time_best(tracer: &dyn Tracer, system: &SequentialSystem, rays: &RayBatch, repeat: usize) -> Result<(TracedBatch, f64)> {
    let mut best = f64::INFINITY;
    let mut last = None;
    for _ in 0..repeat.max(1) {
        let t = Instant::now();
        let out = tracer.trace(system, rays)?;
        best = best.min(t.elapsed().as_secs_f64());
        last = Some(out);
    }
    Ok((last.expect("at least one repeat"), best.max(1e-9)))
}

/// The first ray of a non-empty batch, as a batch (traced once to build a backend's scene outside timing).
pub(crate) fn first_ray(b: &RayBatch) -> RayBatch {
    RayBatch { origin_x: vec![b.origin_x[0]], origin_y: vec![b.origin_y[0]], origin_z: vec![b.origin_z[0]], dir_x: vec![b.dir_x[0]], dir_y: vec![b.dir_y[0]], dir_z: vec![b.dir_z[0]], wavelength_nm: vec![b.wavelength_nm[0]] }
}
