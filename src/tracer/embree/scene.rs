//! A sequential system turned into an Embree scene of solids for non-sequential tracing. The
//! description of the solids (interfaces, walls, blades, detector; merged and virtual interfaces) is
//! kernel-independent and lives in [`crate::tracer::nonseq::solids`]; this file turns it into Embree
//! geometries, one per solid, in the same order (geometry ID = solid index).
//!
//! Every optical surface of the sequential path becomes one Embree geometry over its clear aperture —
//! a sag-exact triangle mesh ([`SurfaceRepresentation::Mesh`]) or an analytic user geometry whose callback
//! solves the exact figure ([`SurfaceRepresentation::User`]) — and knows the media on both sides:
//! the *front* (−normal side, where the sequential ray comes from) and the *back*. Around them:
//! * **walls** (absorbers): wherever the medium after a surface is glass, the rims of that surface and of
//!   the next are joined by a ruled side wall, closing the solid (prisms get their side/top/bottom faces,
//!   lenses their rims). A ray reaching a wall leaves through a side face: [`RayStatus::Absorbed`].
//! * **blades** (absorbers): an explicit aperture (Zemax's "(aper)") gets an annular (or rectangular-frame)
//!   blade outside it in the surface's rim plane, like a stop blade or lens mount. A ray reaching one is
//!   [`RayStatus::Vignetted`], as in the sequential tracer.
//! * the **detector**: the image surface; a ray reaching it is done.
//!
//! Zero-thickness and dummy surfaces are resolved explicitly, never left to floating-point ties between
//! coincident geometry: consecutive path surfaces with an identity transform between them and the same
//! plane figure (the stop plane inside the SP prism, the split plane inside the double Amici) are
//! **merged** into one interface with the front medium of the first and the back medium of the last; an
//! interface whose two media are the same (and that is not an ideal lens) is **virtual** — no geometry,
//! only its rim (for walls) and blades (for its explicit apertures). Coordinate breaks are frames only.
//!
//! Surfaces without an explicit aperture (Zemax semi-diameters do not clip) get a *mechanical* clear
//! aperture: the larger of Zemax's semi-diameter and the automatic semi-diameter of the system's fields
//! mirrored to all four quadrants at its wavelengths, plus [`SceneOptions::mechanical_margin_mm`]; the
//! detector gets [`SceneOptions::detector_margin_mm`] on top — or less, where the detector disc would stand
//! in the design beam of a folded system: the scene is built from [`Solids::build`]'s objects, which shrink
//! it ([`crate::tracer::nonseq::design_beam`]), so the Embree and brute-force detectors are the same disc.
//!
//! The analytic user geometry answers the lanes of a callback's packet together, with the SIMD kernel's
//! lane code (`AnalyticSurface::intersect_exact_lanes`): each lane gets bit for bit what the scalar solve
//! gives its ray (docs/nonsequential.md, "Packet-wide user geometry").
//!
//! [`RayStatus::Absorbed`]: crate::tracer::RayStatus::Absorbed
//! [`RayStatus::Vignetted`]: crate::tracer::RayStatus::Vignetted
use super::wrapper::{CommittedScene, Device, ExactAnswer, ExactRay, Geometry, Scene, UserGeometry, UserLanes, USER_LANES};
use crate::error::{Error, Result};
use crate::geometry::Frame;
use crate::surfaces::{tessellate_covering, Aperture, MeshResolution, SurfacePatch, TriangleMesh};
use crate::system::SequentialSystem;
use crate::tracer::nonseq::{Solid, Solids, SolidsOptions, StartPlane};
use crate::tracer::simd::block::{conic_roots_both, rotate};
use crate::tracer::simd::lanes::{Lanes, V3};
use crate::tracer::simd::{at_level, LaneKernel, SimdLevel};
use crate::surfaces::SurfaceShape;
use glam::{DMat3, DVec3};
use std::sync::Arc;

/// How optical surfaces are represented in Embree.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SurfaceRepresentation {
    /// Analytic user geometry: the callback solves the exact figure in f64 (result rounded to f32).
    User,
    /// Sag-exact triangle mesh at this resolution.
    Mesh(MeshResolution),
}

/// Scene construction options.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SceneOptions {
    pub representation: SurfaceRepresentation,
    /// Added to the larger of Zemax's and the automatic semi-diameter of surfaces without explicit
    /// aperture (mm).
    pub mechanical_margin_mm: f64,
    /// Extra margin on the detector (mm).
    pub detector_margin_mm: f64,
    /// Radial width of the absorbing blade around an explicit aperture (mm).
    pub blade_width_mm: f64,
}

impl SceneOptions {
    /// The kernel-independent part: the margins of the solids.
    pub fn solids(&self) -> SolidsOptions {
        SolidsOptions { mechanical_margin_mm: self.mechanical_margin_mm, detector_margin_mm: self.detector_margin_mm, blade_width_mm: self.blade_width_mm }
    }
}

impl Default for SceneOptions {
    fn default() -> Self {
        SceneOptions { representation: SurfaceRepresentation::User, mechanical_margin_mm: 1.0, detector_margin_mm: 25.0, blade_width_mm: 10.0 }
    }
}

pub(crate) use crate::tracer::nonseq::Role;

/// One geometry of the scene (indexed by Embree geometry ID).
pub(crate) struct SceneObject {
    pub role: Role,
    /// Local frame of the surface (global = frame · local).
    pub frame: Frame,
    /// The exact figure over its clear aperture (absorbers: the plane patch they lie in, unused).
    pub patch: Option<SurfacePatch>,
    /// For mesh interfaces: vertices (global, f64) and exact unit normals (global, oriented like the
    /// surface's +z normal) at them, and the triangles — for barycentric normal interpolation.
    pub mesh: Option<MeshNormals>,
    /// Geometry mask bit.
    pub mask: u32,
    /// The explicit apertures (with their sequential surface) of the object's group, in its local frame:
    /// with f64 refinement the aperture test is repeated on the exact hit point (see the tracer).
    pub apertures: Vec<(usize, Aperture)>,
}

pub(crate) struct MeshNormals {
    pub normals: Vec<DVec3>,
    pub triangles: Vec<[u32; 3]>,
}

/// A committed Embree scene built from a sequential system.
pub struct OpticalScene {
    pub(crate) scene: CommittedScene,
    pub(crate) objects: Vec<SceneObject>,
    /// Sequential index of the image surface.
    pub image_surface: usize,
    /// An object at infinity: the plane its rays start on ([`crate::tracer::nonseq::launch`]).
    pub start_plane: Option<StartPlane>,
    /// Largest measured chord-sag error of the meshed surfaces (µm), 0 for user geometry.
    pub max_sag_error_um: f64,
    /// Triangles in the scene (surfaces + absorbers).
    pub triangle_count: usize,
    /// Number of Embree geometries by role: (interfaces, absorbers).
    pub geometry_count: (usize, usize),
    _device: Device,
}

impl std::fmt::Debug for OpticalScene {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OpticalScene")
            .field("image_surface", &self.image_surface)
            .field("geometries", &self.objects.len())
            .field("triangles", &self.triangle_count)
            .field("max_sag_error_um", &self.max_sag_error_um)
            .finish()
    }
}

/// The mask bit shared by absorbers (rays stop there, so they never need excluding).
pub(crate) const ABSORBER_MASK: u32 = 1 << 31;
/// Most interfaces (including the detector) a scene can hold: one private mask bit each.
pub const MAX_INTERFACES: usize = 31;
fn embree_err(e: super::wrapper::EmbreeError) -> Error {
    Error::invalid(format!("Embree: {e}"))
}

impl OpticalScene {
    /// The committed Embree scene (geometry ID = solid index), for direct queries — e.g. comparing
    /// Embree's query modes on the tracer's own scene (tests/embree_speed.rs).
    pub fn committed(&self) -> &CommittedScene {
        &self.scene
    }

    /// Build the scene of `system`.
    pub fn build(system: &SequentialSystem, options: &SceneOptions) -> Result<Self> {
        Self::check_options(options)?;
        Self::build_with(system, options, Solids::build(system, &options.solids())?, false)
    }

    /// The options' margins finite and ≥ 0, the blade width > 0 (checked before the solids are built).
    pub fn check_options(options: &SceneOptions) -> Result<()> {
        if !(options.mechanical_margin_mm.is_finite() && options.mechanical_margin_mm >= 0.0)
            || !(options.detector_margin_mm.is_finite() && options.detector_margin_mm >= 0.0)
            || !(options.blade_width_mm.is_finite() && options.blade_width_mm > 0.0)
        {
            return Err(Error::invalid(format!("Embree scene options {options:?}: margins must be finite and ≥ 0, blade width > 0")));
        }
        Ok(())
    }

    /// Build the scene of `system` from its solids, already built with `options.solids()` (a caller that
    /// keeps the solids too, as [`super::EmbreeNextHit`] does, builds them once).
    pub fn from_solids(system: &SequentialSystem, options: &SceneOptions, solids: Solids) -> Result<Self> {
        Self::build_with(system, options, solids, false)
    }

    /// The same scene (same geometries, bounds, masks and order) with the analytic user geometries'
    /// callbacks replaced by the oracle ([`Geometry::user_oracle`]), for the floor benchmark
    /// (`super::floor`): it may only be queried with [`CommittedScene::intersect16_oracle`].
    pub(crate) fn build_oracle(system: &SequentialSystem, options: &SceneOptions) -> Result<Self> {
        if options.representation != SurfaceRepresentation::User {
            return Err(Error::invalid("the oracle scene replaces analytic user geometry: it needs SurfaceRepresentation::User"));
        }
        Self::check_options(options)?;
        Self::build_with(system, options, Solids::build(system, &options.solids())?, true)
    }

    fn build_with(system: &SequentialSystem, options: &SceneOptions, solids: Solids, oracle: bool) -> Result<Self> {
        Self::check_options(options)?;
        let device = Device::new("").map_err(embree_err)?;
        if !device.supports_ray_masks() {
            return Err(Error::invalid("this Embree build does not support ray masks (RTC_DEVICE_PROPERTY_RAY_MASK_SUPPORTED), which the tracer needs"));
        }
        // The kernel-independent description (shared with the brute-force tracer, object for object).
        let interfaces = solids.interfaces();
        if interfaces > MAX_INTERFACES {
            return Err(Error::invalid(format!(
                "system `{}` has {interfaces} optical interfaces; the Embree backend supports at most {MAX_INTERFACES} (one ray-mask bit each)",
                system.name()
            )));
        }
        let mut scene = Scene::new(&device).map_err(embree_err)?;
        scene.set_robust().map_err(embree_err)?;
        let mut objects: Vec<SceneObject> = Vec::new();
        let (mut max_sag_error_um, mut triangle_count) = (0.0f64, 0usize);
        let mut next_bit = 0u32;
        let mut absorbers = 0usize;
        for solid in solids.objects {
            let Solid { role, frame, patch, vertices, triangles, apertures } = solid;
            let (geom, mesh, mask) = if matches!(role, Role::Interface { .. } | Role::Mirror { .. } | Role::Detector { .. }) {
                let patch = patch.as_ref().expect("an optical solid has its patch");
                let mask = 1u32 << next_bit;
                next_bit += 1;
                let surface = match &role {
                    Role::Interface { surfaces, .. } => surfaces[0],
                    Role::Mirror { surface, .. } | Role::Detector { surface, .. } => *surface,
                    _ => unreachable!(),
                };
                match options.representation {
                    SurfaceRepresentation::User => {
                        let user = Arc::new(AnalyticSurface::new(frame, patch.clone()));
                        let geom = if oracle { Geometry::user_oracle(&device, user, mask) } else { Geometry::user(&device, user, mask) };
                        (geom.map_err(embree_err)?, None, mask)
                    }
                    SurfaceRepresentation::Mesh(res) => {
                        let m = covering_mesh(patch, res).map_err(|e| Error::invalid(format!("surface {surface}: {e}")))?;
                        max_sag_error_um = max_sag_error_um.max(m.max_sag_error_um);
                        triangle_count += m.triangles.len();
                        let vertices: Vec<DVec3> = m.vertices.iter().map(|v| frame.point_to_global(DVec3::from_array(*v))).collect();
                        let normals = m.vertices.iter().map(|v| frame.dir_to_global(patch.shape.normal(DVec3::from_array(*v)))).collect();
                        let v32: Vec<[f32; 3]> = vertices.iter().map(|v| v.as_vec3().to_array()).collect();
                        let geom = Geometry::triangle_mesh(&device, &v32, &m.triangles).and_then(|g| g.with_mask(mask)).map_err(embree_err)?;
                        (geom, Some(MeshNormals { normals, triangles: m.triangles }), mask)
                    }
                }
            } else {
                triangle_count += triangles.len();
                absorbers += 1;
                let v32: Vec<[f32; 3]> = vertices.iter().map(|v| v.as_vec3().to_array()).collect();
                let geom = Geometry::triangle_mesh(&device, &v32, &triangles).and_then(|g| g.with_mask(ABSORBER_MASK)).map_err(embree_err)?;
                (geom, None, ABSORBER_MASK)
            };
            let id = scene.attach(&geom).map_err(embree_err)? as usize;
            if id != objects.len() {
                return Err(Error::invalid(format!("Embree assigned geometry ID {id}, expected {}", objects.len())));
            }
            objects.push(SceneObject { role, frame, patch, mesh, mask, apertures });
        }
        let scene = scene.commit().map_err(embree_err)?;
        let (image_surface, start_plane) = (solids.image_surface, solids.start_plane);
        Ok(OpticalScene { scene, objects, image_surface, start_plane, max_sag_error_um, triangle_count, geometry_count: (interfaces, absorbers), _device: device })
    }
}

/// The mesh of an optical surface, made to **cover** its clear aperture
/// ([`tessellate_covering`]). A mesh inscribed in a circular aperture (the hexagon of a plane, whose
/// chord-sag error is 0 at one ring) lost rays through the band between polygon and circle — up to
/// r(1 − cos 30°) = 13 % of the radius on SP's detector — where the exact patch (brute force, user
/// geometry) is hit: the ghost paths `18R 17R` and `17R 16R` of SP on 13 % of the trees. So the boundary
/// is the circumscribed polygon, with (at a chord-sag tolerance) enough segments that it overshoots the
/// circle by at most that tolerance, and the interior as coarse as the chord-sag tolerance allows (a
/// plane: a graded band of rings from a hexagon out to the boundary, ≈ 3 triangles per boundary segment
/// instead of the 6n² of uniform rings). Hits in the overshoot margin are refused on the exact figure
/// (`EmbreeNextHit`, and the tracer's f64 refinement), as the exact patch refuses them. Where the figure
/// is undefined just outside the aperture (a conic at its domain's edge) the inscribed ring is kept.
/// Rectangles are exact already.
pub(crate) fn covering_mesh(patch: &SurfacePatch, res: MeshResolution) -> std::result::Result<TriangleMesh, String> {
    tessellate_covering(&patch.shape, &patch.aperture, res)
}

/// Analytic user geometry: the exact patch in its frame, solved in f64 from Embree's f32 ray.
struct AnalyticSurface {
    frame: Frame,
    /// `frame.rotation` transposed: what [`Frame::point_to_local`] and [`Frame::dir_to_local`] apply.
    to_local: DMat3,
    patch: SurfacePatch,
    /// The instruction set of the packet solve: the SIMD kernel's choice ([`SimdLevel::detect`]), once.
    level: SimdLevel,
}

/// Below this many lanes a callback's lanes are solved one by one (the same bits): a 16-lane pass costs
/// more than one or two scalar solves.
const LANE_SOLVE_MIN: usize = 3;

impl AnalyticSurface {
    fn new(frame: Frame, patch: SurfacePatch) -> Self {
        let to_local = frame.rotation.transpose();
        AnalyticSurface { frame, to_local, patch, level: SimdLevel::detect() }
    }

    /// The hit of the exact ray (local `p`, `d`; `roots` of the figure along it) reported to Embree: the
    /// first root in (tnear, tfar] inside the aperture, as a distance along Embree's f32 ray.
    #[allow(clippy::too_many_arguments)]
    #[inline]
    fn answer(&self, p: DVec3, d: DVec3, roots: [Option<f64>; 2], org: [f32; 3], dir: [f32; 3], tnear: f32, tfar: f32, exact: &ExactRay) -> ExactAnswer {
        let o32 = DVec3::new(org[0] as f64, org[1] as f64, org[2] as f64);
        let d32 = DVec3::new(dir[0] as f64, dir[1] as f64, dir[2] as f64);
        let dd = d32.dot(d32);
        if !(dd > 0.0) {
            return ExactAnswer::Miss;
        }
        for t in roots.into_iter().flatten() {
            let q = p + d * t;
            // Distance along Embree's f32 ray to the exact point (t of the exact ray up to f32 rounding).
            let t32 = (exact.org + exact.dir * t - o32).dot(d32) / dd;
            if t32 > tnear as f64 && t32 <= tfar as f64 && self.patch.aperture.contains(q.x, q.y) {
                return ExactAnswer::Hit { t: t32 as f32, roots };
            }
        }
        ExactAnswer::Miss
    }

    /// The exact rays of `lanes` in the local frame and the figure's roots along them, all lanes at once
    /// with the SIMD kernel's lane code (`rotate`, `conic_roots_both`: glam's and `conic_roots`'
    /// operations in their order, so every lane equals [`SurfacePatch::closed_form_roots`] on
    /// [`Frame::point_to_local`]'s ray bit for bit). Planes and conics only.
    #[inline(always)]
    fn solve_lanes(&self, lanes: &UserLanes, local: &mut [(DVec3, DVec3); USER_LANES], roots: &mut [[Option<f64>; 2]; USER_LANES]) {
        type L = Lanes<f64, USER_LANES>;
        let n = lanes.count;
        let (mut o, mut d) = (V3 { x: L::of(0.0), y: L::of(0.0), z: L::of(0.0) }, V3 { x: L::of(0.0), y: L::of(0.0), z: L::of(0.0) });
        for k in 0..USER_LANES {
            // Lanes past `count` repeat the last ray (computed, not used).
            let e = &lanes.exact[k.min(n - 1)];
            let v = e.org - self.frame.origin;
            (o.x.0[k], o.y.0[k], o.z.0[k]) = (v.x, v.y, v.z);
            (d.x.0[k], d.y.0[k], d.z.0[k]) = (e.dir.x, e.dir.y, e.dir.z);
        }
        let p = rotate(&self.to_local, o);
        let d = rotate(&self.to_local, d);
        let (ok1, t1, ok2, t2) = match self.patch.shape {
            SurfaceShape::Conic { curvature, conic } if curvature != 0.0 => conic_roots_both(curvature, conic, p, d),
            // `plane_root`: −p_z / d_z where d_z ≠ 0 and finite.
            _ => {
                let t = -p.z / d.z;
                (d.z.ne(L::of(0.0)) & t.is_finite(), t, crate::tracer::simd::lanes::Mask::splat(false), t)
            }
        };
        for k in 0..n {
            local[k] = (DVec3::new(p.x.0[k], p.y.0[k], p.z.0[k]), DVec3::new(d.x.0[k], d.y.0[k], d.z.0[k]));
            roots[k] = [ok1.0[k].then_some(t1.0[k]), ok2.0[k].then_some(t2.0[k])];
        }
    }
}

/// [`AnalyticSurface::solve_lanes`] as lane code for the SIMD kernel's one level dispatch
/// ([`at_level`]: compiled for AVX-512, AVX2 or portable, as the sequential kernel).
struct SolveLanes<'a> {
    surface: &'a AnalyticSurface,
    lanes: &'a UserLanes,
    local: &'a mut [(DVec3, DVec3); USER_LANES],
    roots: &'a mut [[Option<f64>; 2]; USER_LANES],
}

impl LaneKernel for SolveLanes<'_> {
    type Output = ();
    #[inline(always)]
    fn run(self) {
        self.surface.solve_lanes(self.lanes, self.local, self.roots)
    }
}

impl UserGeometry for AnalyticSurface {
    fn bounds(&self) -> ([f32; 3], [f32; 3]) {
        let (lo, hi) = self.patch.local_bounds();
        let mut glo = DVec3::splat(f64::INFINITY);
        let mut ghi = DVec3::splat(f64::NEG_INFINITY);
        for i in 0..8 {
            let c = DVec3::new(if i & 1 == 0 { lo.x } else { hi.x }, if i & 2 == 0 { lo.y } else { hi.y }, if i & 4 == 0 { lo.z } else { hi.z });
            let g = self.frame.point_to_global(c);
            glo = glo.min(g);
            ghi = ghi.max(g);
        }
        // Outward rounding to f32 (one ulp-scale pad is plenty: 1e-6 relative + 1e-6 mm).
        let pad = (ghi - glo).abs().max_element() * 1e-6 + 1e-6 + glo.abs().max(ghi.abs()).max_element() * 1e-6;
        ((glo - pad).as_vec3().to_array(), (ghi + pad).as_vec3().to_array())
    }

    fn intersect(&self, org: [f32; 3], dir: [f32; 3], tnear: f32, tfar: f32) -> Option<(f32, [f32; 3])> {
        let d = DVec3::new(dir[0] as f64, dir[1] as f64, dir[2] as f64);
        let len = d.length();
        if !(len > 0.0) {
            return None;
        }
        let p = self.frame.point_to_local(DVec3::new(org[0] as f64, org[1] as f64, org[2] as f64));
        let dl = self.frame.dir_to_local(d / len);
        let t = self.patch.first_hit(p, dl, tnear as f64 * len, tfar as f64 * len)?;
        let n = self.frame.dir_to_global(self.patch.shape.normal(p + dl * t));
        Some(((t / len) as f32, n.as_vec3().to_array()))
    }

    /// Solved once on the exact ray, in the same local frame and by the same code as the tracer's f64
    /// refinement (`SurfacePatch::closed_form_roots`), which then reuses the roots. The reported distance
    /// is that of the exact hit point projected on the f32 ray (what Embree compares with other hits);
    /// the first root in (tnear, tfar] inside the aperture wins, as in [`SurfacePatch::first_hit`].
    fn intersect_exact(&self, org: [f32; 3], dir: [f32; 3], tnear: f32, tfar: f32, exact: &ExactRay) -> ExactAnswer {
        let p = self.frame.point_to_local(exact.org);
        let d = self.frame.dir_to_local(exact.dir);
        let Some(roots) = self.patch.closed_form_roots(p, d) else { return ExactAnswer::Unsupported };
        self.answer(p, d, roots, org, dir, tnear, tfar, exact)
    }

    /// Three or more lanes of a plane or conic are solved together ([`Self::solve_lanes`], the same bits
    /// as [`Self::intersect_exact`] lane by lane); fewer, or an even asphere, lane by lane.
    #[allow(clippy::needless_range_loop)] // lanes of several parallel arrays
    fn intersect_exact_lanes(&self, lanes: &UserLanes, out: &mut [ExactAnswer; USER_LANES]) {
        let closed = matches!(self.patch.shape, SurfaceShape::Plane | SurfaceShape::Paraxial { .. } | SurfaceShape::Conic { .. });
        if lanes.count < LANE_SOLVE_MIN || !closed {
            for k in 0..lanes.count {
                out[k] = self.intersect_exact(lanes.org[k], lanes.dir[k], lanes.tnear[k], lanes.tfar[k], &lanes.exact[k]);
            }
            return;
        }
        let mut local = [(DVec3::ZERO, DVec3::ZERO); USER_LANES];
        let mut roots = [[None; 2]; USER_LANES];
        at_level(self.level, SolveLanes { surface: self, lanes, local: &mut local, roots: &mut roots });
        for k in 0..lanes.count {
            let (p, d) = local[k];
            out[k] = self.answer(p, d, roots[k], lanes.org[k], lanes.dir[k], lanes.tnear[k], lanes.tfar[k], &lanes.exact[k]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::rotation_xyz;
    use rand::{Rng, SeedableRng};

    /// The packet solve of a callback's lanes (`intersect_exact_lanes`, 3–16 lanes through the SIMD lane
    /// code at every instruction set this CPU runs) gives each lane exactly what the scalar solve
    /// (`intersect_exact`) gives it — hit or miss, reported distance and both roots, bit for bit — on
    /// planes, paraxial planes and conics of every kind (sphere, paraboloid along its axis: the linear
    /// case; hyperboloid, oblate ellipsoid; curvature 0), tilted frames, seeded rays from both sides,
    /// parallel to the plane and grazing.
    #[test]
    fn lane_solve_equals_scalar_solve_bit_for_bit() {
        let shapes = [
            SurfaceShape::Plane,
            SurfaceShape::Paraxial { focal_length: 50.0 },
            SurfaceShape::Conic { curvature: 1.0 / 30.0, conic: 0.0 },
            SurfaceShape::Conic { curvature: -1.0 / 50.0, conic: -1.0 },
            SurfaceShape::Conic { curvature: 1.0 / 40.0, conic: -2.5 },
            SurfaceShape::Conic { curvature: 1.0 / 25.0, conic: 0.6 },
            SurfaceShape::Conic { curvature: 0.0, conic: 0.0 },
        ];
        let frame = Frame::new(DVec3::new(1.5, -2.0, 40.0), rotation_xyz(0.3, -0.5, 0.1));
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(23);
        let (mut lanes_solved, mut hits) = (0usize, 0usize);
        for shape in shapes {
            let patch = SurfacePatch::new(shape.clone(), Aperture::circular(10.0)).unwrap();
            let mut surface = AnalyticSurface::new(frame, patch);
            for level in SimdLevel::available() {
                surface.level = level;
                for batch in 0..60 {
                    let mut q = UserLanes::EMPTY;
                    q.count = 1 + batch % USER_LANES;
                    for k in 0..q.count {
                        let local_o = DVec3::new(rng.gen_range(-12.0..12.0), rng.gen_range(-12.0..12.0), rng.gen_range(-20.0..20.0));
                        let mut local_d = match (batch + k) % 5 {
                            0 => DVec3::Z,                                                   // along the axis
                            1 => DVec3::new(rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0), 0.0), // parallel
                            _ => DVec3::new(rng.gen_range(-0.5..0.5), rng.gen_range(-0.5..0.5), if rng.gen_bool(0.8) { 1.0 } else { -1.0 }),
                        };
                        local_d = local_d.normalize();
                        let e = ExactRay { org: frame.point_to_global(local_o), dir: frame.dir_to_global(local_d).normalize() };
                        q.exact[k] = e;
                        q.org[k] = e.org.as_vec3().to_array();
                        q.dir[k] = e.dir.as_vec3().to_array();
                        q.tnear[k] = if k % 7 == 3 { 5.0 } else { 0.0 };
                        q.tfar[k] = if k % 5 == 4 { 15.0 } else { f32::INFINITY };
                    }
                    let mut out = [ExactAnswer::Unsupported; USER_LANES];
                    surface.intersect_exact_lanes(&q, &mut out);
                    for k in 0..q.count {
                        let scalar = surface.intersect_exact(q.org[k], q.dir[k], q.tnear[k], q.tfar[k], &q.exact[k]);
                        assert_eq!(format!("{:?}", out[k]), format!("{scalar:?}"), "{shape:?} {level:?} batch {batch} lane {k}");
                        if let (ExactAnswer::Hit { t: a, roots: ra }, ExactAnswer::Hit { t: b, roots: rb }) = (out[k], scalar) {
                            assert_eq!(a.to_bits(), b.to_bits());
                            assert_eq!(ra.map(|r| r.map(f64::to_bits)), rb.map(|r| r.map(f64::to_bits)));
                            hits += 1;
                        }
                        lanes_solved += (q.count >= LANE_SOLVE_MIN) as usize;
                    }
                }
            }
        }
        assert!(lanes_solved > 1000 && hits > 200, "{lanes_solved} lanes through the packet solve, {hits} hits");
    }
}
