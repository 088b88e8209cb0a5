//! Brute-force non-sequential geometry kernel in f64, without Embree: every object of the [`Solids`] is
//! tested at every bounce — interfaces and the detector by their exact bounded-patch hit
//! ([`crate::surfaces::SurfacePatch::first_hit`]), walls and blades triangle by triangle (Möller–Trumbore
//! in f64; each absorber's triangles are grouped in runs of [`CHUNK`] with a bounding box, the only
//! culling — no hierarchy). It is the reference the Embree kernel is checked against and the baseline of
//! the backend benchmark.
//!
//! Decisions mirror the Embree tracer's f64 refinement (`src/tracer/embree/tracer.rs`): a blade hit whose
//! exact point on the group's figure lies inside all its apertures is not a vignetting (the interface
//! itself is hit, or for a virtual group the ray passes, [`Event::Pass`]); a wall hit within a few f32
//! ulps right after an interaction is the shared rim (skipped); a face the wall joins that is met no later
//! than the wall (up to the same tie) wins over it.
//!
//! ```
//! use diffcassi::prelude::*;
//! use diffcassi::tracer::nonseq::{BruteForce, SolidsOptions};
//! let sys = SequentialSystem::build(&presets::spec("ap")?)?;
//! let brute = BruteForce::new(&sys, &SolidsOptions::default())?;
//! assert!(brute.solids.absorber_triangles() > 0);
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::next_hit::{f32_ulps, Event, ExtraGeometry, ExtraHit, NextHit, Query};
use super::solids::{Role, Solids, SolidsOptions};
use crate::error::Result;
use crate::system::SequentialSystem;
use glam::DVec3;
use std::sync::Arc;

/// Triangles per bounding box.
pub const CHUNK: usize = 16;

/// The brute-force kernel.
pub struct BruteForce {
    pub solids: Solids,
    /// Per absorber object: (box lo, box hi, first triangle, end triangle).
    boxes: Vec<Vec<(DVec3, DVec3, usize, usize)>>,
    extra: Option<Arc<dyn ExtraGeometry>>,
}

impl std::fmt::Debug for BruteForce {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BruteForce").field("objects", &self.solids.objects.len()).field("extra", &self.extra.is_some()).finish()
    }
}

impl BruteForce {
    pub fn new(system: &SequentialSystem, options: &SolidsOptions) -> Result<Self> {
        Ok(Self::from_solids(Solids::build(system, options)?))
    }

    pub fn from_solids(solids: Solids) -> Self {
        let boxes = solids
            .objects
            .iter()
            .map(|o| {
                (0..o.triangles.len())
                    .step_by(CHUNK)
                    .map(|a| {
                        let b = (a + CHUNK).min(o.triangles.len());
                        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
                        for t in &o.triangles[a..b] {
                            for &v in t {
                                lo = lo.min(o.vertices[v as usize]);
                                hi = hi.max(o.vertices[v as usize]);
                            }
                        }
                        let pad = 1e-9 * (1.0 + lo.abs().max(hi.abs()).max_element());
                        (lo - pad, hi + pad, a, b)
                    })
                    .collect()
            })
            .collect();
        BruteForce { solids, boxes, extra: None }
    }

    /// With extra geometry (mechanics) tested at every bounce, after the solids.
    pub fn with_extra(mut self, extra: Arc<dyn ExtraGeometry>) -> Self {
        // An object at infinity: the rays start in front of the extra geometry too.
        self.solids.start_plane = self.solids.start_plane.map(|p| p.in_front_of_z(extra.lowest_z_mm()));
        self.extra = Some(extra);
        self
    }

    /// Nearest triangle hit of absorber `k` in (tmin, tmax).
    fn absorber_hit(&self, k: usize, p: DVec3, d: DVec3, tmin: f64, tmax: f64) -> Option<f64> {
        let o = &self.solids.objects[k];
        let inv = d.recip();
        let mut best: Option<f64> = None;
        for &(lo, hi, a, b) in &self.boxes[k] {
            let limit = best.unwrap_or(tmax);
            if !slab(p, inv, lo, hi, tmin, limit) {
                continue;
            }
            for tri in &o.triangles[a..b] {
                let [v0, v1, v2] = tri.map(|i| o.vertices[i as usize]);
                if let Some(t) = triangle_hit(p, d, v0, v1, v2) {
                    if t > tmin && t < best.unwrap_or(tmax) {
                        best = Some(t);
                    }
                }
            }
        }
        best
    }
}

/// Does the ray meet the box within (tmin, tmax)?
fn slab(p: DVec3, inv: DVec3, lo: DVec3, hi: DVec3, tmin: f64, tmax: f64) -> bool {
    let (t1, t2) = ((lo - p) * inv, (hi - p) * inv);
    let (a, b) = (t1.min(t2), t1.max(t2));
    // NaN (0 · ∞ on a box face) is ignored by max/min, leaving the other axes to decide.
    let enter = a.x.max(a.y).max(a.z).max(tmin);
    let exit = b.x.min(b.y).min(b.z).min(tmax);
    enter <= exit
}

/// Möller–Trumbore ray–triangle intersection (f64), the distance t or `None` (parallel or outside).
fn triangle_hit(p: DVec3, d: DVec3, v0: DVec3, v1: DVec3, v2: DVec3) -> Option<f64> {
    let (e1, e2) = (v1 - v0, v2 - v0);
    let h = d.cross(e2);
    let a = e1.dot(h);
    if a.abs() < 1e-300 {
        return None;
    }
    let f = 1.0 / a;
    let s = p - v0;
    let u = f * s.dot(h);
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(e1);
    let v = f * d.dot(q);
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    Some(f * e2.dot(q))
}

impl NextHit for BruteForce {
    fn solids(&self) -> &Solids {
        &self.solids
    }

    fn has_extra(&self) -> bool {
        self.extra.is_some()
    }

    fn scatter(&self, hit: &ExtraHit, incoming: DVec3, seed: u64, ray: u64, bounce: u64) -> Option<(DVec3, f64)> {
        self.extra.as_ref()?.scatter(hit, incoming, seed, ray, bounce)
    }

    fn next_hit(&self, q: &Query) -> Event {
        let objects = &self.solids.objects;
        let (p, d) = (q.p, q.d);
        let rim = f32_ulps(p, 16.0);
        let tie = f32_ulps(p, 64.0);
        // Optical objects: exact first hits.
        let optical: Vec<Option<f64>> = objects
            .iter()
            .enumerate()
            .map(|(k, o)| {
                if !o.is_optical() || q.exclude == Some(k) {
                    return None;
                }
                let patch = o.patch.as_ref()?;
                patch.first_hit(o.frame.point_to_local(p), o.frame.dir_to_local(d), q.tnear, f64::INFINITY)
            })
            .collect();
        let mut best: (f64, Event) = (f64::INFINITY, Event::Miss);
        for (k, t) in optical.iter().enumerate() {
            if let Some(t) = *t {
                if t < best.0 {
                    best = (t, Event::Optical { object: k, t });
                }
            }
        }
        for (k, o) in objects.iter().enumerate() {
            if o.is_optical() {
                continue;
            }
            let tmin = match o.role {
                Role::Wall { .. } if q.after_interaction => q.tnear.max(rim),
                _ => q.tnear,
            };
            let Some(t) = self.absorber_hit(k, p, d, tmin, best.0) else { continue };
            match &o.role {
                Role::Blade { interface, .. } => {
                    // Re-decide on the exact figure: inside every aperture → not a vignetting.
                    if let Some(patch) = o.patch.as_ref() {
                        let (pl, dl) = (o.frame.point_to_local(p), o.frame.dir_to_local(d));
                        if let Some(te) = patch.nearest_root(pl, dl, t) {
                            let mut x = pl + dl * te;
                            if matches!(patch.shape, crate::surfaces::SurfaceShape::Plane | crate::surfaces::SurfaceShape::Paraxial { .. }) {
                                x.z = 0.0;
                            }
                            if x.is_finite() && o.apertures.iter().all(|(_, ap)| ap.contains(x.x, x.y)) {
                                match interface {
                                    Some(i) if q.exclude != Some(*i) => {}
                                    // A pass moves the ray to the figure's point: only forward (a point
                                    // behind the start was passed already; the blade is then ignored).
                                    _ if te > q.tnear => best = (t, Event::Pass { point: o.frame.point_to_global(x) }),
                                    _ => {}
                                }
                                continue;
                            }
                        }
                    }
                    best = (t, Event::Absorber { object: k });
                }
                Role::Wall { ends, .. } => {
                    // A face the wall joins, met no later than the wall (up to f32 ties), wins.
                    if ends.iter().any(|&e| optical[e].is_some_and(|tf| tf <= t + tie)) {
                        continue;
                    }
                    best = (t, Event::Absorber { object: k });
                }
                _ => {}
            }
        }
        if let Some(extra) = &self.extra {
            if let Some(h) = extra.intersect(p, d, q.tnear, best.0).filter(|h| h.t < best.0) {
                return Event::Extra(h);
            }
        }
        best.1
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn triangle_hit_inside_and_outside() {
        let (v0, v1, v2) = (DVec3::ZERO, DVec3::X, DVec3::Y);
        let t = triangle_hit(DVec3::new(0.2, 0.2, -3.0), DVec3::Z, v0, v1, v2).unwrap();
        assert!((t - 3.0).abs() < 1e-15);
        assert!(triangle_hit(DVec3::new(0.8, 0.8, -3.0), DVec3::Z, v0, v1, v2).is_none());
        assert!(slab(DVec3::new(0.5, 0.5, -1.0), DVec3::Z.recip(), DVec3::ZERO, DVec3::ONE, 0.0, 10.0));
    }
}
