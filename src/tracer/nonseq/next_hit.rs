//! The one question a non-sequential walk asks of its geometry kernel: *what does this ray meet next?*
//!
//! [`NextHit`] is implemented by the brute-force f64 kernel ([`super::BruteForce`]: every object tested)
//! and by Embree (`crate::tracer::embree::EmbreeNextHit`: an f32 hit that only identifies the object,
//! re-decided in f64). Both answer over the same [`Solids`], object for object, so the ray tree
//! ([`super::tree`]) is written once. An [`Event::Optical`] carries only the approximate distance: the
//! walk re-solves the hit exactly with [`crate::surfaces::SurfacePatch::nearest_root`], as the Embree
//! tracer's f64 refinement does, so the two kernels give the same bits wherever they identify the same
//! object.
//!
//! **Hook for extra geometry** (mechanics: mounts, baffles, imported meshes): [`ExtraGeometry`] is an
//! absorbing set of triangles or any other shape answering `intersect_brute(origin, dir, tmin, tmax)`;
//! a kernel built `with_extra` tests it at every bounce like the walls, and a hit there ends the ray as
//! absorbed (a scattering surface would return its own event; not wired yet).
//!
//! ```
//! use diffcassi::prelude::*;
//! use diffcassi::tracer::nonseq::{BruteForce, Event, NextHit, Query, SolidsOptions};
//! let sys = SequentialSystem::build(&presets::spec("sp")?)?;
//! let brute = BruteForce::new(&sys, &SolidsOptions::default())?;
//! let rays = RayBatch::chief_rays(&sys, &[[0.0, 0.0]], 520.0)?;
//! let e = brute.next_hit(&Query { p: rays.origin(0), d: rays.direction(0).normalize(), exclude: None, tnear: 0.0, after_interaction: false });
//! assert!(matches!(e, Event::Optical { object: 0, .. }));
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::solids::Solids;
use glam::DVec3;

/// One query: the ray p + t·d (global, `d` unit), t > `tnear`, never meeting the optical object
/// `exclude` (the one it just left). `after_interaction`: the ray starts on a surface it has just
/// interacted with (a wall hit within a few f32 ulps is then the shared rim, not an exit).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Query {
    pub p: DVec3,
    pub d: DVec3,
    pub exclude: Option<usize>,
    pub tnear: f64,
    pub after_interaction: bool,
}

/// What the ray meets next.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Event {
    /// An interface or the detector (solid index), at approximately `t` along the ray.
    Optical { object: usize, t: f64 },
    /// A wall or blade that stops the ray (solid index).
    Absorber { object: usize },
    /// Extra (mechanical) geometry that absorbs the ray.
    Extra,
    /// The ray crosses a virtual (same-media) group's aperture plane inside its apertures at `point`
    /// (global): continue from there, past it.
    Pass { point: DVec3 },
    /// Nothing: the ray leaves the system.
    Miss,
}

/// The geometry kernel of a non-sequential walk.
pub trait NextHit: Sync {
    /// The solids the object indices refer to.
    fn solids(&self) -> &Solids;
    /// What the ray of `q` meets next.
    fn next_hit(&self, q: &Query) -> Event;
}

/// Extra absorbing geometry tested at every bounce (the mechanics hook).
pub trait ExtraGeometry: Sync + Send {
    /// Smallest t in (tmin, tmax] where origin + t·dir (global, mm) meets the geometry.
    fn intersect_brute(&self, origin: DVec3, dir: DVec3, tmin: f64, tmax: f64) -> Option<f64>;
}

/// A distance a few f32 ulps of the ray's coordinates long (the Embree tracer's tie and retry scale).
pub(crate) fn f32_ulps(p: DVec3, ulps: f64) -> f64 {
    ulps * f64::from(f32::EPSILON) * p.abs().max_element().max(1.0)
}
