//! [`EmbreeNextHit`]: the Embree implementation of the non-sequential [`NextHit`] kernel. Embree's f32
//! hit only *identifies* the object; the decisions are re-made in f64 exactly as the Embree tracer's
//! f64 refinement makes them (`tracer.rs`): a blade hit whose exact point on the group's figure lies
//! inside its apertures is the interface (or, for a virtual group, a pass); a wall hit within a few f32
//! ulps of a surface just left is the shared rim (queried again past it); a face the wall joins met no
//! later than the wall wins; a mesh hit outside the surface's exact clear aperture (the mesh covers it
//! with a margin, `scene::covering_mesh`) is passed. The walk ([`crate::tracer::nonseq::tree`]) re-solves
//! optical hits in f64.
//!
//! ```no_run
//! use diffcassi::prelude::*;
//! use diffcassi::tracer::embree::{EmbreeNextHit, SceneOptions};
//! use diffcassi::tracer::nonseq::{trace_trees, TreeOptions};
//! let sys = SequentialSystem::build(&presets::spec("sp")?)?;
//! let kernel = EmbreeNextHit::new(&sys, &SceneOptions::default())?;
//! let rays = RayBatch::chief_rays(&sys, &[[0.0, 0.0]], 520.0)?;
//! let trees = trace_trees(&kernel, &sys, &rays, &TreeOptions::default())?;
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::scene::{OpticalScene, SceneOptions};
use super::wrapper::Ray;
use crate::error::Result;
use crate::surfaces::SurfaceShape;
use crate::system::SequentialSystem;
use crate::tracer::nonseq::next_hit::f32_ulps;
use crate::tracer::nonseq::{Event, ExtraGeometry, ExtraHit, NextHit, Query, Role, Solids};
use glam::DVec3;
use std::sync::Arc;

/// The Embree kernel: the committed scene and the solids it was built from (same object order), and
/// optional extra geometry (the mechanics as Embree triangle meshes: `crate::mechanics::MechanicsScene`, a
/// second Embree scene queried up to the distance of the solids' answer).
pub struct EmbreeNextHit {
    scene: OpticalScene,
    solids: Solids,
    extra: Option<Arc<dyn ExtraGeometry>>,
}

impl EmbreeNextHit {
    pub fn new(system: &SequentialSystem, options: &SceneOptions) -> Result<Self> {
        // One build of the solids: the scene is made of them, object for object, and the walk reads them.
        OpticalScene::check_options(options)?;
        let solids = Solids::build(system, &options.solids())?;
        Ok(EmbreeNextHit { scene: OpticalScene::from_solids(system, options, solids.clone())?, solids, extra: None })
    }

    /// With extra geometry (mechanics) tested at every bounce, after the solids.
    pub fn with_extra(mut self, extra: Arc<dyn ExtraGeometry>) -> Self {
        // An object at infinity: the rays start in front of the extra geometry too (the walk starts them
        // from these solids' plane).
        self.solids.start_plane = self.solids.start_plane.map(|p| p.in_front_of_z(extra.lowest_z_mm()));
        self.extra = Some(extra);
        self
    }

    /// The solids' answer and its approximate distance (∞ for a miss).
    fn solids_hit(&self, q: &Query) -> (Event, f64) {
        let objects = &self.scene.objects;
        let exclude_mask = q.exclude.map(|k| objects[k].mask).unwrap_or(0);
        let mut tnear = q.tnear as f32;
        let mut retried = q.tnear > 0.0;
        loop {
            let mut ray = Ray::new(q.p.as_vec3().to_array(), q.d.as_vec3().to_array());
            ray.mask = !exclude_mask;
            ray.tnear = tnear;
            let hit = self.scene.scene.intersect1(&ray);
            if !hit.is_hit() {
                return (Event::Miss, f64::INFINITY);
            }
            let id = hit.geom_id as usize;
            let th = hit.t as f64;
            let obj = &objects[id];
            match &obj.role {
                Role::Interface { .. } | Role::Mirror { .. } | Role::Detector { .. } => {
                    // A mesh covers its clear aperture with a margin (`scene::covering_mesh`): a hit
                    // whose exact point lies outside the aperture is not a hit of the patch (brute force
                    // tests the same point); query again just past it.
                    if let (Some(_), Some(patch)) = (&obj.mesh, obj.patch.as_ref()) {
                        let (p0, d) = (obj.frame.point_to_local(q.p), obj.frame.dir_to_local(q.d));
                        if let Some(t) = patch.nearest_root(p0, d, th) {
                            let x = p0 + d * t;
                            if !patch.aperture.contains(x.x, x.y) {
                                // Strictly increasing: the walk ends (finitely many triangles).
                                tnear = hit.t.next_up();
                                continue;
                            }
                        }
                    }
                    return (Event::Optical { object: id, t: th }, th);
                }
                Role::Wall { ends, .. } => {
                    let eps = f32_ulps(q.p, 16.0) as f32;
                    if q.after_interaction && hit.t < eps && !retried {
                        tnear = eps;
                        retried = true;
                        continue;
                    }
                    let tie = f32_ulps(q.p, 64.0);
                    for &k in ends {
                        let face = &objects[k];
                        if Some(k) == q.exclude {
                            continue;
                        }
                        let Some(patch) = face.patch.as_ref() else { continue };
                        let (p, d) = (face.frame.point_to_local(q.p), face.frame.dir_to_local(q.d));
                        let Some(t) = patch.nearest_root(p, d, hit.t as f64).filter(|t| *t >= -tie && *t <= hit.t as f64 + tie) else { continue };
                        let x = p + d * t;
                        // Outside an explicit aperture the walk's aperture test vignettes it; inside the
                        // clear aperture the face is hit.
                        if face.apertures.iter().any(|(_, ap)| !ap.contains(x.x, x.y)) || patch.aperture.contains(x.x, x.y) {
                            return (Event::Optical { object: k, t }, t);
                        }
                    }
                    return (Event::Absorber { object: id }, th);
                }
                Role::Blade { interface, .. } => {
                    if let Some(patch) = obj.patch.as_ref() {
                        let (p0, d) = (obj.frame.point_to_local(q.p), obj.frame.dir_to_local(q.d));
                        if let Some(t) = patch.nearest_root(p0, d, hit.t as f64) {
                            let mut x = p0 + d * t;
                            if matches!(patch.shape, SurfaceShape::Plane | SurfaceShape::Paraxial { .. }) {
                                x.z = 0.0;
                            }
                            if x.is_finite() && obj.apertures.iter().all(|(_, ap)| ap.contains(x.x, x.y)) {
                                match interface {
                                    Some(k) if Some(*k) != q.exclude => return (Event::Optical { object: *k, t: th }, th),
                                    _ if t > q.tnear => return (Event::Pass { point: obj.frame.point_to_global(x) }, th),
                                    // Passed already (the point is behind the start): query past the blade.
                                    _ => {
                                        tnear = hit.t + f32_ulps(q.p, 16.0) as f32;
                                        continue;
                                    }
                                }
                            }
                        }
                    }
                    return (Event::Absorber { object: id }, th);
                }
            }
        }
    }
}

impl NextHit for EmbreeNextHit {
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
        let (event, t) = self.solids_hit(q);
        if let Some(extra) = &self.extra {
            if let Some(h) = extra.intersect(q.p, q.d, q.tnear, t).filter(|h| h.t < t) {
                return Event::Extra(h);
            }
        }
        event
    }
}
