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
//! **Extra geometry** (mechanics: mounts, baffles, imported meshes): [`ExtraGeometry`] is any set of
//! surfaces answering `intersect(origin, dir, tmin, tmax)` with an [`ExtraHit`] (distance, normal,
//! Lambertian reflectance); a kernel built `with_extra` tests it at every bounce after the solids, and the
//! walk ([`super::tree`]) absorbs the ray there or scatters the fraction `reflectance` of it
//! ([`crate::mechanics::scatter::lambertian`]). [`crate::mechanics::Mechanics`] answers in f64 over
//! every triangle; `crate::mechanics::MechanicsScene` answers with Embree.
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
    /// Extra (mechanical) geometry: absorbs the ray, or scatters part of it.
    Extra(ExtraHit),
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
    /// The kernel holds extra geometry (mechanics) that may stop a ray's order-0 path.
    fn has_extra(&self) -> bool {
        false
    }
    /// The ray scattered at an [`Event::Extra`] hit (see [`ExtraGeometry::scatter`]); `None`: absorbed.
    fn scatter(&self, _hit: &ExtraHit, _incoming: DVec3, _seed: u64, _ray: u64, _bounce: u64) -> Option<(DVec3, f64)> {
        None
    }
}

/// Where a ray meets extra geometry.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ExtraHit {
    /// Distance along the (unit) query direction (mm).
    pub t: f64,
    /// Unit geometric normal (either orientation).
    pub normal: DVec3,
    /// Lambertian reflectance of the surface hit (0: an absorber).
    pub reflectance: f64,
    /// Which part (for reports).
    pub part: usize,
}

/// Extra geometry tested at every bounce (the mechanics).
pub trait ExtraGeometry: Sync + Send {
    /// The nearest hit with t in (tmin, tmax] of origin + t·dir (global, mm; `dir` unit).
    fn intersect(&self, origin: DVec3, dir: DVec3, tmin: f64, tmax: f64) -> Option<ExtraHit>;
    /// A short name for reports (`"mechanics-brute"`, `"mechanics-embree"`).
    fn name(&self) -> &'static str;
    /// The unit direction and energy weight of the ray scattered at `hit` for a ray arriving along
    /// `incoming`, its random numbers keyed by (seed, ray, bounce) only; `None`: absorbed.
    fn scatter(&self, hit: &ExtraHit, incoming: DVec3, seed: u64, ray: u64, bounce: u64) -> Option<(DVec3, f64)>;
    /// The lowest global z the geometry reaches (mm): the rays of an object at infinity start in front of
    /// it ([`super::launch`]). `f64::INFINITY` (the default): nothing to start in front of.
    fn lowest_z_mm(&self) -> f64 {
        f64::INFINITY
    }
}

/// A distance a few f32 ulps of the ray's coordinates long (the Embree tracer's tie and retry scale).
pub(crate) fn f32_ulps(p: DVec3, ulps: f64) -> f64 {
    ulps * f64::from(f32::EPSILON) * p.abs().max_element().max(1.0)
}
