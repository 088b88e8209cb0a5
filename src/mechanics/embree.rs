//! [`MechanicsScene`]: the mechanical parts as Embree triangle geometry, one geometry per part with its
//! own mask bit (`1 << part`, parts ≥ 31 share bit 31), so a walker can exclude the part a ray just
//! scattered from. A query finds the first hit in f32 (Embree's BVH), then re-solves *that one triangle*
//! in f64 from the f64 ray ([`ray_plane_t`]): the point is then exact on the triangle's plane, and agrees
//! with [`Mechanics::intersect_brute`] to rounding where both pick the same (or a coplanar/adjacent)
//! triangle.
//!
//! ```
//! use diffcassi::mechanics::{Mechanics, MechanicsScene, Part, PartKind, SurfaceModel, TriMesh};
//! use diffcassi::mechanics::parts::box_solid;
//! use diffcassi::geometry::Frame;
//! use glam::DVec3;
//! let mesh = box_solid(&Frame::IDENTITY, DVec3::splat(-1.0), DVec3::splat(1.0), 2);
//! let m = Mechanics { parts: vec![Part { name: "cube".into(), kind: PartKind::UserMesh, surface: SurfaceModel::Absorbing, mesh }] };
//! let scene = MechanicsScene::new(&m)?;
//! let hit = scene.intersect(DVec3::new(0.3, 0.2, 5.0), DVec3::new(0.0, 0.0, -1.0), 0.0, f64::INFINITY, u32::MAX).unwrap();
//! assert!((hit.t - 4.0).abs() < 1e-12 && hit.normal.z > 0.0);
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::{ray_plane_t, MechHit, Mechanics};
use crate::error::{Error, Result};
use crate::tracer::embree::{CommittedScene, Device, Geometry, Ray, Scene};
use glam::DVec3;

/// The mask bit of part `i`.
pub fn part_mask(i: usize) -> u32 {
    1u32 << i.min(31)
}

/// Mechanics in an Embree scene.
pub struct MechanicsScene {
    scene: CommittedScene,
    /// Part of each Embree geometry ID.
    mechanics: Mechanics,
    _device: Device,
}

impl MechanicsScene {
    pub fn new(mechanics: &Mechanics) -> Result<Self> {
        let err = |e: crate::tracer::embree::EmbreeError| Error::invalid(format!("mechanics scene: {e}"));
        let device = Device::new("").map_err(err)?;
        let mut scene = Scene::new(&device).map_err(err)?;
        for (i, p) in mechanics.parts.iter().enumerate() {
            let v: Vec<[f32; 3]> = p.mesh.vertices.iter().map(|v| v.as_vec3().to_array()).collect();
            let g = Geometry::triangle_mesh(&device, &v, &p.mesh.triangles).and_then(|g| g.with_mask(part_mask(i))).map_err(err)?;
            let id = scene.attach(&g).map_err(err)?;
            if id as usize != i {
                return Err(Error::invalid(format!("mechanics scene: Embree gave part {i} geometry ID {id}")));
            }
        }
        let scene = scene.commit().map_err(err)?;
        Ok(MechanicsScene { scene, mechanics: mechanics.clone(), _device: device })
    }

    pub fn mechanics(&self) -> &Mechanics {
        &self.mechanics
    }

    /// The first part (among those whose [`part_mask`] bit is in `mask`) met by `origin + t·dir` with
    /// `tmin ≤ t ≤ tmax`: Embree in f32, then the f64 re-solve of the triangle it found. Rays Embree cannot
    /// take (non-finite, zero direction, an interval beyond f32) are misses.
    pub fn intersect(&self, origin: DVec3, dir: DVec3, tmin: f64, tmax: f64, mask: u32) -> Option<MechHit> {
        let mut ray = Ray::new(origin.as_vec3().to_array(), dir.as_vec3().to_array());
        ray.tnear = tmin as f32;
        ray.tfar = tmax as f32;
        ray.mask = mask;
        let hit = self.scene.intersect1(&ray);
        self.resolve(origin, dir, &hit)
    }

    /// Sixteen queries at once (`rtcIntersect16`, incoherent): one [`Self::intersect`] per lane.
    pub fn intersect16(&self, rays: &[(DVec3, DVec3); 16], tmin: f64, tmax: f64, mask: u32) -> [Option<MechHit>; 16] {
        let packet = rays.map(|(o, d)| {
            let mut r = Ray::new(o.as_vec3().to_array(), d.as_vec3().to_array());
            r.tnear = tmin as f32;
            r.tfar = tmax as f32;
            r.mask = mask;
            r
        });
        let hits = self.scene.intersect16(&packet, &[true; 16]);
        std::array::from_fn(|i| self.resolve(rays[i].0, rays[i].1, &hits[i]))
    }

    fn resolve(&self, origin: DVec3, dir: DVec3, hit: &crate::tracer::embree::Hit) -> Option<MechHit> {
        if !hit.is_hit() {
            return None;
        }
        let (part, triangle) = (hit.geom_id as usize, hit.prim_id as usize);
        let [a, b, c] = self.mechanics.parts[part].mesh.corners(triangle);
        let t = ray_plane_t(origin, dir, a, b, c).unwrap_or(hit.t as f64);
        Some(self.mechanics.hit(origin, dir, t, part, triangle))
    }
}

/// The non-sequential walk's extra geometry through Embree (f32 BVH, f64 re-solve of the hit triangle).
/// The far end is widened by a few f32 ulps for Embree and the f64 distance is then held to (tmin, tmax];
/// a triangle Embree finds at or before `tmin` in f64 (the one a scattered ray leaves, seen in f32) is
/// stepped over and the query repeated past it.
impl crate::tracer::nonseq::ExtraGeometry for MechanicsScene {
    fn intersect(&self, origin: DVec3, dir: DVec3, tmin: f64, tmax: f64) -> Option<crate::tracer::nonseq::ExtraHit> {
        let ulp = f64::from(f32::EPSILON) * origin.abs().max_element().max(1.0);
        let far = tmax + 64.0 * ulp;
        let mut near = tmin;
        for _ in 0..4 {
            let h = self.intersect(origin, dir, near, far, u32::MAX)?;
            if h.t > tmin {
                return (h.t <= tmax).then(|| self.mechanics.extra_hit(&h));
            }
            near = near.max(h.t) + 4.0 * ulp;
        }
        None
    }
    fn name(&self) -> &'static str {
        "mechanics-embree"
    }
    fn lowest_z_mm(&self) -> f64 {
        crate::tracer::nonseq::ExtraGeometry::lowest_z_mm(&self.mechanics)
    }
    fn scatter(&self, hit: &crate::tracer::nonseq::ExtraHit, incoming: DVec3, seed: u64, ray: u64, bounce: u64) -> Option<(DVec3, f64)> {
        super::scatter::lambertian(hit.normal, incoming, hit.reflectance, seed, ray, bounce)
    }
}
