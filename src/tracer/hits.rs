//! Per-interaction hit records of a trace — returned only when asked for (a plain trace records nothing
//! and pays nothing). They carry what implicit differentiation at hit points needs
//! ([`crate::diff::DiffSystem::jacobian_from_hits`]): which sequential surface was hit, the hit point (f64,
//! refined onto the exact surface when the backend refines), the incoming direction and the media.
//!
//! Two producers: [`sequential_hits`] (the analytic sequential trace, bit-identical values to
//! [`crate::tracer::AnalyticTracer`]) and, with the `embree` feature,
//! `EmbreeTracer::trace_with_hits` (the non-sequential walk, which may also record total internal
//! reflections it followed).
//!
//! ```
//! use diffcassi::prelude::*;
//! use diffcassi::tracer::hits::{sequential_hits, HitKind};
//! let sys = SequentialSystem::build(&presets::spec("ap")?)?;
//! let rays = RayBatch::chief_rays(&sys, &[[0.0, 0.0]], 520.0)?;
//! let (traced, log) = sequential_hits(&sys, &rays)?;
//! assert_eq!(traced, AnalyticTracer::default().trace(&sys, &rays)?);
//! let hits = log.ray(0);
//! assert_eq!(hits.len(), sys.surfaces_per_ray());         // one record per path step
//! assert_eq!(hits.last().unwrap().kind, HitKind::Detector);
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::analytic::index_table;
use super::kernel::trace_step;
use super::{RayStatus, TracedBatch};
use crate::error::{Error, Result};
use crate::rays::RayBatch;
use crate::surfaces::SurfaceShape;
use crate::system::{Interaction, SequentialSystem};
use glam::DVec3;
use rayon::prelude::*;

/// What happened at a hit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HitKind {
    /// Refraction by vector Snell's law (also a dummy surface between equal media).
    Refraction,
    /// Ideal-lens deflection (Zemax Paraxial surface).
    Deflection,
    /// Total internal reflection (non-sequential backends follow it; the sequential model stops there).
    Reflection,
    /// Specular reflection at a mirror (`GLAS MIRROR`): the sequential path's own step, recorded with the
    /// media the sequential model gives it (before: the surface before; after: the mirror's, the same medium).
    Mirror,
    /// The image surface: the ray is done.
    Detector,
}

/// One ray–surface interaction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HitRecord {
    /// Sequential surfaces of the interface, first and last (several when a backend merged coincident
    /// planes, e.g. the stop plane inside the SP prism; equal otherwise).
    pub first_surface: u32,
    pub last_surface: u32,
    /// Hit point in the local frame of `first_surface` (mm).
    pub point: DVec3,
    /// Incoming unit direction in that frame.
    pub direction: DVec3,
    /// Media before and after the interaction, as indices into [`SequentialSystem::indices`] (the medium
    /// after surface m). A ray crossing the interface backward has them swapped.
    pub medium_in: u32,
    pub medium_out: u32,
    pub kind: HitKind,
}

/// The hit records of a batch, ray after ray: `hits[offsets[i]..offsets[i + 1]]` belong to ray `i`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct HitLog {
    pub offsets: Vec<usize>,
    pub hits: Vec<HitRecord>,
}

impl HitLog {
    /// From per-ray record lists, in ray order.
    pub fn from_rays(per_ray: impl IntoIterator<Item = Vec<HitRecord>>) -> Self {
        let mut log = HitLog { offsets: vec![0], hits: Vec::new() };
        for r in per_ray {
            log.hits.extend(r);
            log.offsets.push(log.hits.len());
        }
        log
    }
    /// Number of rays.
    pub fn len(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// The records of ray `i`, in the order the ray met them.
    pub fn ray(&self, i: usize) -> &[HitRecord] {
        &self.hits[self.offsets[i]..self.offsets[i + 1]]
    }
}

/// Rays per rayon task.
const CHUNK: usize = 1024;

/// The analytic sequential trace, recording one [`HitRecord`] per path step (values bit-identical to
/// [`crate::tracer::AnalyticTracer`]: the same per-step kernel). A ray that stops records the steps it
/// completed.
pub fn sequential_hits(system: &SequentialSystem, rays: &RayBatch) -> Result<(TracedBatch, HitLog)> {
    if !rays.is_consistent() {
        return Err(Error::invalid("ray batch columns have different lengths"));
    }
    let table = index_table(system, &rays.wavelength_nm)?;
    let n = rays.len();
    let path = &system.path;
    let last = path.len().saturating_sub(1);
    type RayOut = (RayStatus, u32, DVec3, DVec3, Vec<HitRecord>);
    let per_ray: Vec<RayOut> = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .flat_map_iter(|c| {
            let table = &table;
            (c * CHUNK..((c + 1) * CHUNK).min(n)).map(move |i| {
                let idx = &table[&rays.wavelength_nm[i].to_bits()];
                let (mut p, mut d) = (rays.origin(i), rays.direction(i));
                let len = d.length();
                let mut records = Vec::new();
                if !(p.is_finite() && d.is_finite()) || !(len > 0.0) {
                    return (RayStatus::InvalidInput, 0, DVec3::ZERO, DVec3::ZERO, records);
                }
                d /= len;
                for (k, step) in path.iter().enumerate() {
                    // The incoming direction in the step's frame, recorded before the step refracts.
                    let din = step.rotation * d;
                    match trace_step(step, idx, p, d) {
                        Ok((q, e)) => {
                            let s = step.surface as u32;
                            let kind = match step.shape {
                                _ if k == last => HitKind::Detector,
                                SurfaceShape::Paraxial { .. } => HitKind::Deflection,
                                _ if step.interaction == Interaction::Reflect => HitKind::Mirror,
                                _ => HitKind::Refraction,
                            };
                            records.push(HitRecord { first_surface: s, last_surface: s, point: q, direction: din, medium_in: s - 1, medium_out: s, kind });
                            (p, d) = (q, e);
                        }
                        Err((status, surface)) => return (status, surface as u32, DVec3::ZERO, DVec3::ZERO, records),
                    }
                }
                (RayStatus::Ok, u32::MAX, p, d, records)
            })
        })
        .collect();
    let mut out = TracedBatch::zeroed(n);
    let mut records = Vec::with_capacity(n);
    for (i, (status, surface, p, d, r)) in per_ray.into_iter().enumerate() {
        out.status[i] = status;
        out.surface[i] = surface;
        if status == RayStatus::Ok {
            (out.x[i], out.y[i], out.z[i]) = (p.x, p.y, p.z);
            (out.dir_x[i], out.dir_y[i], out.dir_z[i]) = (d.x, d.y, d.z);
        }
        records.push(r);
    }
    Ok((out, HitLog::from_rays(records)))
}
