//! Where the non-sequential walks start the rays of an **object at infinity**.
//!
//! The sequential tracer starts the parallel beam of a field angle on the plane of surface 1's vertex
//! (z = 0 of the object frame, [`crate::rays::PupilAim::parallel_ray`]) and meets surface 1 as a full
//! line, at a negative distance wherever its figure bulges in front of that plane (a convex first lens
//! surface, the rim of a concave mirror). A non-sequential walk follows rays forward only: started on that
//! plane, such a ray would begin inside the glass or behind the mirror and never meet the surface's front.
//!
//! So each launched ray is moved back along its own line to the **start plane** z = `z_mm` (object frame,
//! which is the solids' global frame), in front of every solid of the system: the object-space medium is
//! homogeneous up to the first surface, so a ray's line and direction are unchanged and only its origin
//! moves (by rounding of p + t·d, t < 0). A ray met by nothing between the start plane and surface 1 then
//! meets exactly what the sequential ray meets; a solid that lies in the incoming beam in front of
//! surface 1 — a Cassegrain's secondary mirror, whose back faces the sky — shadows the rays it lies in
//! front of, as it does physically (the sequential file models that shadow, if at all, with an `OBSC`
//! on a surface, which the solids model too: [`super::solids`]).
//!
//! Extra geometry (the mechanics: a baffle in front of the first lens) moves the plane in front of it too
//! (`with_extra` of the kernels).
//!
//! Rays already in front of the plane (z ≤ `z_mm`), rays not heading toward +z and non-finite rays are left
//! as they are (the walk classifies the last).
//!
//! ```
//! use diffcassi::tracer::nonseq::StartPlane;
//! use glam::DVec3;
//! let plane = StartPlane { z_mm: -2.0 };
//! let d = DVec3::new(0.0, 0.6, 0.8);
//! let o = plane.start(DVec3::new(1.0, 3.0, 0.0), d);
//! assert!((o.z + 2.0).abs() < 1e-15 && (o.y - 1.5).abs() < 1e-15 && o.x == 1.0);
//! ```
use super::solids::Solid;
use glam::DVec3;

/// Where a walk starts a launched ray: moved back to `plane` ([`StartPlane::start`]) for an object at
/// infinity, unchanged without one (a finite object).
#[inline]
pub fn launch_origin(plane: Option<&StartPlane>, origin: DVec3, d: DVec3) -> DVec3 {
    match plane {
        Some(plane) => plane.start(origin, d),
        None => origin,
    }
}

/// Distance of the start plane in front of the nearest solid (mm): far above the f32 resolution of the
/// Embree scene's coordinates (6e-5 mm at 1 m), far below any lens spacing.
pub const START_MARGIN_MM: f64 = 0.01;

/// The plane z = `z_mm` (global frame) on which the rays of an object at infinity start.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StartPlane {
    pub z_mm: f64,
}

impl StartPlane {
    /// The plane [`START_MARGIN_MM`] in front of the lowest global z any of `objects` reaches: the
    /// corners of each optical patch's (and blade's) local bounding box, and every absorber vertex.
    pub fn in_front_of(objects: &[Solid]) -> Self {
        let mut z_min = f64::INFINITY;
        for o in objects {
            if let Some(patch) = &o.patch {
                let (lo, hi) = patch.local_bounds();
                for i in 0..8 {
                    let c = DVec3::new(if i & 1 == 0 { lo.x } else { hi.x }, if i & 2 == 0 { lo.y } else { hi.y }, if i & 4 == 0 { lo.z } else { hi.z });
                    z_min = z_min.min(o.frame.point_to_global(c).z);
                }
            }
            for v in &o.vertices {
                z_min = z_min.min(v.z);
            }
        }
        StartPlane { z_mm: if z_min.is_finite() { z_min - START_MARGIN_MM } else { -START_MARGIN_MM } }
    }

    /// The plane moved, if need be, [`START_MARGIN_MM`] in front of `z_mm` too (extra geometry: the
    /// mechanics' lowest point, [`super::ExtraGeometry::lowest_z_mm`]).
    pub fn in_front_of_z(self, z_mm: f64) -> Self {
        StartPlane { z_mm: if z_mm.is_finite() { self.z_mm.min(z_mm - START_MARGIN_MM) } else { self.z_mm } }
    }

    /// The origin of the ray `origin` + t·`d` moved back to the start plane (see the [module docs](self)).
    #[inline]
    pub fn start(&self, origin: DVec3, d: DVec3) -> DVec3 {
        if !(origin.is_finite() && d.is_finite() && d.z > 0.0 && origin.z > self.z_mm) {
            return origin;
        }
        let t = (self.z_mm - origin.z) / d.z;
        let p = origin + d * t;
        // On the plane exactly (the rounding of origin.z + t·d.z aside).
        DVec3::new(p.x, p.y, self.z_mm)
    }
}
