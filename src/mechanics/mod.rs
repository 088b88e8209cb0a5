//! Mechanics: the opto-mechanical parts around a system — mounts generated from it ([`parts`]: lens tubes,
//! prism holder, detector housing, baffle) and user meshes imported from STL/OBJ ([`mesh_io`]) placed by a
//! transform — as triangle meshes in f64, each absorbing or Lambertian-scattering ([`SurfaceModel`]).
//! This is where non-sequential scenes get their triangle counts and where a BVH pays.
//!
//! Queries: [`Mechanics::intersect_brute`] tests every triangle in f64 (the reference), and
//! `MechanicsScene` (feature `embree`) finds the first hit with Embree in f32 then re-solves that one
//! triangle in f64. [`scatter::lambertian`] samples a cosine-weighted direction seeded per
//! (seed, ray, bounce), so a walk is the same for any thread count.
//!
//! ```
//! use diffcassi::prelude::*;
//! use diffcassi::mechanics::Mechanics;
//! use diffcassi::spec::MechanicsSpec;
//! use glam::DVec3;
//! let mut spec = presets::spec("sp")?;
//! spec.mechanics = Some(MechanicsSpec::default());
//! let system = SequentialSystem::build(&spec)?;
//! let mech = Mechanics::from_system(&system, std::path::Path::new("."))?;
//! assert!(mech.triangle_count() > 500);
//! // A ray along the first lens tube's wall, from the side, meets it.
//! let (lo, hi) = mech.parts[0].mesh.bounds();
//! let c = 0.5 * (lo + hi);
//! let hit = mech.intersect_brute(c + DVec3::new(0.0, 0.0, 0.0), DVec3::X, 0.0, f64::INFINITY);
//! assert!(hit.is_some());
//! # Ok::<(), diffcassi::Error>(())
//! ```
#[cfg(feature = "embree")]
mod embree;
mod intersect;
mod mesh;
pub mod mesh_io;
pub mod parts;
pub mod scatter;

#[cfg(feature = "embree")]
pub use embree::*;
pub use intersect::*;
pub use mesh::*;
pub use parts::GenerateOptions;

use crate::error::{Error, Result};
use crate::limits::fmt_num;
pub use crate::spec::SurfaceModel;
use crate::spec::{MechanicsSpec, MeshPartSpec};
use crate::system::SequentialSystem;
use glam::DVec3;
use std::path::Path;

/// What a part is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PartKind {
    LensTube,
    PrismHolder,
    DetectorHousing,
    Baffle,
    /// A user mesh from the spec.
    UserMesh,
}

/// One mechanical part: a closed (generated) or validated (imported) triangle mesh in global mm.
#[derive(Clone, Debug, PartialEq)]
pub struct Part {
    pub name: String,
    pub kind: PartKind,
    pub surface: SurfaceModel,
    pub mesh: TriMesh,
}

/// The first mechanical surface a ray meets.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MechHit {
    /// Distance along the (not necessarily unit) direction: `point = origin + t · dir`.
    pub t: f64,
    pub point: DVec3,
    /// Unit geometric normal of the triangle (outward for a consistently wound solid).
    pub normal: DVec3,
    pub part: usize,
    pub triangle: usize,
}

/// All mechanical parts of a scene.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mechanics {
    pub parts: Vec<Part>,
}

impl Mechanics {
    /// The parts the spec's `[mechanics]` section describes (none without one); mesh paths are relative
    /// to `base_dir` (the spec file's folder).
    pub fn from_system(system: &SequentialSystem, base_dir: &Path) -> Result<Self> {
        match &system.spec.mechanics {
            None => Ok(Mechanics::default()),
            Some(spec) => Self::build(system, spec, base_dir),
        }
    }

    /// The parts of `spec` around `system`.
    pub fn build(system: &SequentialSystem, spec: &MechanicsSpec, base_dir: &Path) -> Result<Self> {
        spec.validate().map_err(Error::invalid)?;
        let mut parts = Vec::new();
        if spec.generate {
            let o = GenerateOptions { segments: spec.resolution.segments(), surface: spec.surface, ..Default::default() };
            parts = parts::generate(system, &o)?;
        }
        for m in &spec.meshes {
            parts.push(Self::user_part(m, base_dir)?);
        }
        Ok(Mechanics { parts })
    }

    /// A user mesh loaded, validated and placed.
    pub fn user_part(m: &MeshPartSpec, base_dir: &Path) -> Result<Part> {
        let path = base_dir.join(&m.path);
        let file = mesh_io::load_mesh(&path, m.closed)?;
        // The placed part within ±MAX_LENGTH_MM, naming the vertex as the file has it and the scale.
        let mesh = file.placed(m.translate_mm, m.rotate_deg, m.scale);
        let lim = crate::limits::MAX_LENGTH_MM;
        if let Some((i, v)) = mesh.vertices.iter().enumerate().find(|(_, v)| !(v.is_finite() && v.abs().max_element() <= lim)) {
            let f = file.vertices[i];
            return Err(Error::File {
                path: path.display().to_string(),
                message: format!(
                    "vertex {i} = ({}, {}, {}) × scale {} (+ translate_mm) lands at ({}, {}, {}) mm, outside the plausible range ±{lim:e} mm; check `scale` (file units → mm)",
                    fmt_num(f.x), fmt_num(f.y), fmt_num(f.z), fmt_num(m.scale), fmt_num(v.x), fmt_num(v.y), fmt_num(v.z)
                ),
            });
        }
        // Placement cannot make a valid mesh invalid except by overflow: check again.
        mesh.validate(&path.display().to_string(), m.closed)?;
        Ok(Part { name: m.path.clone(), kind: PartKind::UserMesh, surface: m.surface, mesh })
    }

    pub fn triangle_count(&self) -> usize {
        self.parts.iter().map(|p| p.mesh.triangles.len()).sum()
    }

    /// The closest hit with `tmin < t ≤ tmax` over every triangle of every part, in f64 (see
    /// [`intersect`](self::ray_triangle) for the edge policy). `dir` need not be unit.
    pub fn intersect_brute(&self, origin: DVec3, dir: DVec3, tmin: f64, tmax: f64) -> Option<MechHit> {
        self.intersect_brute_masked(origin, dir, tmin, tmax, u64::MAX)
    }

    /// [`Self::intersect_brute`] over the parts whose bit (`1 << part`, parts ≥ 63 share bit 63) is in
    /// `parts_mask`.
    pub fn intersect_brute_masked(&self, origin: DVec3, dir: DVec3, tmin: f64, tmax: f64, parts_mask: u64) -> Option<MechHit> {
        let mut best: Option<(f64, usize, usize)> = None;
        let mut tmax = tmax;
        for (pi, p) in self.parts.iter().enumerate() {
            if parts_mask & (1u64 << pi.min(63)) == 0 {
                continue;
            }
            for k in 0..p.mesh.triangles.len() {
                let [a, b, c] = p.mesh.corners(k);
                // `t ≤ tmax` keeps a later equal-t triangle out only if it is strictly farther: ties go
                // to the first (lowest index), as documented.
                if let Some((t, _, _)) = ray_triangle(origin, dir, a, b, c, tmin, tmax) {
                    if best.is_none_or_farther(t) {
                        best = Some((t, pi, k));
                        tmax = t;
                    }
                }
            }
        }
        best.map(|(t, part, triangle)| self.hit(origin, dir, t, part, triangle))
    }

    /// The [`MechHit`] at distance `t` on (part, triangle).
    pub fn hit(&self, origin: DVec3, dir: DVec3, t: f64, part: usize, triangle: usize) -> MechHit {
        let [a, b, c] = self.parts[part].mesh.corners(triangle);
        MechHit { t, point: origin + dir * t, normal: (b - a).cross(c - a).normalize(), part, triangle }
    }
}

/// The non-sequential walk's extra geometry, every triangle tested in f64 (the reference kernel).
impl crate::tracer::nonseq::ExtraGeometry for Mechanics {
    fn intersect(&self, origin: DVec3, dir: DVec3, tmin: f64, tmax: f64) -> Option<crate::tracer::nonseq::ExtraHit> {
        self.intersect_brute(origin, dir, tmin, tmax).map(|h| self.extra_hit(&h))
    }
    fn name(&self) -> &'static str {
        "mechanics-brute"
    }
    fn lowest_z_mm(&self) -> f64 {
        self.parts.iter().flat_map(|p| p.mesh.vertices.iter().map(|v| v.z)).fold(f64::INFINITY, f64::min)
    }
    fn scatter(&self, hit: &crate::tracer::nonseq::ExtraHit, incoming: DVec3, seed: u64, ray: u64, bounce: u64) -> Option<(DVec3, f64)> {
        scatter::lambertian(hit.normal, incoming, hit.reflectance, seed, ray, bounce)
    }
}

impl Mechanics {
    /// A [`MechHit`] as the walk's [`crate::tracer::nonseq::ExtraHit`] (with its part's reflectance).
    pub fn extra_hit(&self, h: &MechHit) -> crate::tracer::nonseq::ExtraHit {
        crate::tracer::nonseq::ExtraHit { t: h.t, normal: h.normal, reflectance: self.parts[h.part].surface.reflectance(), part: h.part }
    }
}

/// `best` is empty or farther than `t` (equal distances keep the earlier triangle).
trait Farther {
    fn is_none_or_farther(&self, t: f64) -> bool;
}
impl Farther for Option<(f64, usize, usize)> {
    fn is_none_or_farther(&self, t: f64) -> bool {
        match self {
            None => true,
            Some((b, _, _)) => t < *b,
        }
    }
}
