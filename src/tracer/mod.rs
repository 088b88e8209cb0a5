//! Tracer backends. [`Tracer`] is the one interface; [`AnalyticTracer`] (exact f64, sequential) is the
//! reference implementation, and the Embree backend implements the same trait.
//!
//! ```
//! use diffcassi::{presets, rays::RayBatch, system::SequentialSystem, tracer::{AnalyticTracer, Tracer, RayStatus}};
//! let sys = SequentialSystem::build(&presets::spec("ap").unwrap()).unwrap();
//! let rays = RayBatch::chief_rays(&sys, &[[0.0, 0.0]], 520.0).unwrap();
//! let out = AnalyticTracer::default().trace(&sys, &rays).unwrap();
//! assert_eq!(out.status[0], RayStatus::Ok);
//! assert!(out.x[0].abs() < 1e-6); // the primary chief ray lands on the image origin
//! ```
mod analytic;
mod backend;
pub mod hits;
pub mod kernel;
pub mod nonseq;
mod precision;
#[cfg(feature = "embree")]
pub mod embree;
pub mod simd;
mod slices;
mod traced;

pub use analytic::*;
pub use backend::*;
pub use precision::Precision;
pub use simd::{Kernel, SimdLevel};
pub use slices::*;
pub use traced::*;

use crate::error::Result;
use crate::rays::RayBatch;
use crate::system::SequentialSystem;

/// A backend that traces object-space rays to the image surface.
pub trait Tracer: Send + Sync {
    /// Short name for tables and logs ("analytic-f64", "embree-mesh", …).
    fn name(&self) -> String;
    /// Trace every ray of `rays` (object frame) to the image surface. Rays that miss, are vignetted or
    /// totally reflect are classified in `status`; their positions are NaN-free (set to 0).
    /// Errors are for the batch as a whole (e.g. a wavelength outside a glass's range).
    fn trace(&self, system: &SequentialSystem, rays: &RayBatch) -> Result<TracedBatch>;
    /// [`Tracer::trace`] over borrowed columns (zero copy in; the C++ API's path). The default copies
    /// them into a [`RayBatch`]; backends that can read the slices directly override it, with results
    /// identical to `trace` on the same rays.
    fn trace_slices(&self, system: &SequentialSystem, rays: RaySlices<'_>) -> Result<TracedBatch> {
        self.trace(system, &rays.to_batch())
    }
    /// This backend as the analytic tracer, when it is one: callers with many rays of their own making
    /// (the mapping cube, the renderer) then run its f64 kernel directly instead of building batches.
    fn as_analytic(&self) -> Option<&AnalyticTracer> {
        None
    }
    /// This backend as the f32 analytic tracer, when it is one (the mapping cube then runs its f32 lane
    /// kernel directly, as [`Tracer::as_analytic`] does for f64).
    fn as_analytic_f32(&self) -> Option<&AnalyticF32Tracer> {
        None
    }
}

/// Outcome of one ray.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[repr(u8)]
pub enum RayStatus {
    Ok = 0,
    /// No intersection with a surface (or off the conic's vertex branch).
    Missed = 1,
    /// Outside a surface aperture.
    Vignetted = 2,
    TotalInternalReflection = 3,
    /// Even-asphere intersection did not converge.
    NoConvergence = 4,
    /// Non-finite or zero-length input ray.
    InvalidInput = 5,
    /// Non-sequential tracers: absorbed by a side wall of a solid (a prism's side/top/bottom face, a lens
    /// rim) — the ray left the optical path through a face that is not an optical surface.
    Absorbed = 6,
    /// Non-sequential tracers: more surface interactions than the tracer's bounce limit.
    BounceLimit = 7,
    /// Arrived, but at a non-finite or implausible position (|x| or |y| beyond
    /// [`crate::limits::MAX_IMAGE_COORD_MM`]) or direction: an overflow, never reported as `ok`.
    OutOfRange = 8,
    /// A diffraction grating's order does not propagate after the surface (|n₁ d_t − mλT ŷ_t| > n₂, the
    /// grating equation's evanescent case) — the grating's "TIR" (`src/surfaces/grating.rs`).
    Evanescent = 9,
}

impl RayStatus {
    /// Every status, in code order (`ALL[k] as u8 == k`; Python's `diffcassi.STATUS` is built from it).
    ///
    /// ```
    /// use diffcassi::tracer::RayStatus;
    /// assert!(RayStatus::ALL.iter().enumerate().all(|(k, s)| *s as usize == k));
    /// assert_eq!(RayStatus::ALL[8].words(), "out of range");
    /// assert_eq!(RayStatus::TotalInternalReflection.words(), "total internal reflection");
    /// ```
    pub const ALL: [RayStatus; 10] = [
        RayStatus::Ok,
        RayStatus::Missed,
        RayStatus::Vignetted,
        RayStatus::TotalInternalReflection,
        RayStatus::NoConvergence,
        RayStatus::InvalidInput,
        RayStatus::Absorbed,
        RayStatus::BounceLimit,
        RayStatus::OutOfRange,
        RayStatus::Evanescent,
    ];

    /// The status in words (`total internal reflection`, `out of range`): the label with spaces, `tir` spelt out.
    pub fn words(self) -> String {
        match self {
            RayStatus::TotalInternalReflection => "total internal reflection".to_string(),
            s => s.label().replace('_', " "),
        }
    }

    /// For `#[serde(serialize_with = "RayStatus::serialize_label")]`: a status field written as its label
    /// (`ok`, `tir`, …), as the CSV tables and `trace` write it, so a JSON and a CSV of one analysis agree.
    pub fn serialize_label<S: serde::Serializer>(s: &RayStatus, out: S) -> std::result::Result<S::Ok, S::Error> {
        out.serialize_str(s.label())
    }

    pub fn label(self) -> &'static str {
        match self {
            RayStatus::Ok => "ok",
            RayStatus::Missed => "missed",
            RayStatus::Vignetted => "vignetted",
            RayStatus::TotalInternalReflection => "tir",
            RayStatus::NoConvergence => "no_convergence",
            RayStatus::InvalidInput => "invalid_input",
            RayStatus::Absorbed => "absorbed",
            RayStatus::BounceLimit => "bounce_limit",
            RayStatus::OutOfRange => "out_of_range",
            RayStatus::Evanescent => "evanescent",
        }
    }

    /// What the outcome means, in a few words, for messages that explain lost rays.
    pub fn meaning(self) -> &'static str {
        match self {
            RayStatus::Ok => "arrived",
            RayStatus::Missed => "no intersection with the surface",
            RayStatus::Vignetted => "outside the surface's aperture",
            RayStatus::TotalInternalReflection => "total internal reflection",
            RayStatus::NoConvergence => "the asphere intersection did not converge",
            RayStatus::InvalidInput => "a non-finite or zero-length input ray",
            RayStatus::Absorbed => "absorbed by a side wall of a solid",
            RayStatus::BounceLimit => "more interactions than the bounce limit",
            RayStatus::OutOfRange => "arrived at a non-finite or implausible position",
            RayStatus::Evanescent => "the grating order does not propagate",
        }
    }
}
