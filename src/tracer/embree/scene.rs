//! A sequential system turned into an Embree scene of solids for non-sequential tracing.
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
//! detector gets [`SceneOptions::detector_margin_mm`] on top.
//!
//! [`RayStatus::Absorbed`]: crate::tracer::RayStatus::Absorbed
//! [`RayStatus::Vignetted`]: crate::tracer::RayStatus::Vignetted
use super::wrapper::{CommittedScene, Device, Geometry, Scene, UserGeometry};
use crate::analysis::automatic_semi_diameters;
use crate::error::{Error, Result};
use crate::geometry::Frame;
use crate::surfaces::{tessellate, Aperture, MeshResolution, SurfacePatch, SurfaceShape};
use crate::system::SequentialSystem;
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

impl Default for SceneOptions {
    fn default() -> Self {
        SceneOptions { representation: SurfaceRepresentation::User, mechanical_margin_mm: 1.0, detector_margin_mm: 25.0, blade_width_mm: 10.0 }
    }
}

/// What a geometry does to a ray that reaches it.
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum Role {
    /// Refracting (or ideal-lens) interface. `surfaces`: the merged sequential surfaces; media are indices
    /// into [`SequentialSystem::indices`].
    Interface { surfaces: Vec<usize>, front_medium: usize, back_medium: usize, paraxial_focal_mm: Option<f64> },
    /// The image surface, with the media before and after it: the sequential tracer refracts at the image
    /// surface like at any other, so the detector reports the same (refracted) direction.
    Detector { surface: usize, front_medium: usize, back_medium: usize },
    /// Absorbing blade outside an explicit aperture of `surface` (→ vignetted). `interface`: the object
    /// index of the group's refracting geometry (`None` for a virtual group, e.g. a stop in air).
    Blade { surface: usize, interface: Option<usize> },
    /// Absorbing side wall of the solid that starts at `surface` (→ absorbed). `ends`: the object indices
    /// of the refracting geometries whose rims the wall joins (f64 refinement settles ties with them).
    Wall { surface: usize, ends: Vec<usize> },
}

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
/// Samples on a rim polygon (walls and blades).
const RIM_SAMPLES: usize = 192;

/// A group of merged sequential path steps.
struct Group {
    surfaces: Vec<usize>,
    frame: Frame,
    shape: SurfaceShape,
    explicit: Vec<(usize, Aperture)>,
    /// Clear aperture used for the geometry and the rim.
    clear: Aperture,
    front_medium: usize,
    back_medium: usize,
    virtual_: bool,
    is_image: bool,
}

fn embree_err(e: super::wrapper::EmbreeError) -> Error {
    Error::invalid(format!("Embree: {e}"))
}

impl OpticalScene {
    /// Build the scene of `system`.
    pub fn build(system: &SequentialSystem, options: &SceneOptions) -> Result<Self> {
        if !(options.mechanical_margin_mm.is_finite() && options.mechanical_margin_mm >= 0.0)
            || !(options.detector_margin_mm.is_finite() && options.detector_margin_mm >= 0.0)
            || !(options.blade_width_mm.is_finite() && options.blade_width_mm > 0.0)
        {
            return Err(Error::invalid(format!("Embree scene options {options:?}: margins must be finite and ≥ 0, blade width > 0")));
        }
        let device = Device::new("").map_err(embree_err)?;
        if !device.supports_ray_masks() {
            return Err(Error::invalid("this Embree build does not support ray masks (RTC_DEVICE_PROPERTY_RAY_MASK_SUPPORTED), which the tracer needs"));
        }
        // A negative object distance puts the object after surface 1 (a virtual object, reached by
        // propagating rays backwards as a sequential tracer may); a non-sequential tracer only follows rays
        // forward, so every ray would silently miss. Refuse it with the reason instead.
        let object_mm = system.surfaces[0].thickness_mm;
        if object_mm < 0.0 {
            return Err(Error::invalid(format!(
                "system `{}`: surface 0 thickness {object_mm} mm < 0 is a virtual object; the Embree backends trace rays forward only (use the analytic backend)",
                system.name()
            )));
        }
        let groups = group_surfaces(system, options)?;
        let interfaces = groups.iter().filter(|g| !g.virtual_).count();
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

        let attach = |scene: &mut Scene, objects: &mut Vec<SceneObject>, geom: Geometry, object: SceneObject| -> Result<()> {
            let id = scene.attach(&geom).map_err(embree_err)? as usize;
            if id != objects.len() {
                return Err(Error::invalid(format!("Embree assigned geometry ID {id}, expected {}", objects.len())));
            }
            objects.push(object);
            Ok(())
        };

        // Interface object of each group, and the walls (object index, group) whose ends are filled in
        // once every group's interface exists.
        let mut group_interface: Vec<Option<usize>> = Vec::with_capacity(groups.len());
        let mut walls: Vec<(usize, usize)> = Vec::new();
        for (gi, g) in groups.iter().enumerate() {
            let mut interface_object = None;
            // The optical interface (or detector).
            if !g.virtual_ {
                let patch = SurfacePatch::new(g.shape.clone(), g.clear.clone())
                    .map_err(|e| Error::invalid(format!("surface {}: {e}", g.surfaces[0])))?;
                let mask = 1u32 << next_bit;
                next_bit += 1;
                let role = if g.is_image {
                    Role::Detector { surface: g.surfaces[0], front_medium: g.front_medium, back_medium: g.back_medium }
                } else {
                    Role::Interface {
                        surfaces: g.surfaces.clone(),
                        front_medium: g.front_medium,
                        back_medium: g.back_medium,
                        paraxial_focal_mm: match g.shape {
                            SurfaceShape::Paraxial { focal_length } => Some(focal_length),
                            _ => None,
                        },
                    }
                };
                let (geom, mesh) = match options.representation {
                    SurfaceRepresentation::User => {
                        let user = Arc::new(AnalyticSurface { frame: g.frame, patch: patch.clone() });
                        (Geometry::user(&device, user, mask).map_err(embree_err)?, None)
                    }
                    SurfaceRepresentation::Mesh(res) => {
                        let m = tessellate(&g.shape, &g.clear, res).map_err(|e| Error::invalid(format!("surface {}: {e}", g.surfaces[0])))?;
                        max_sag_error_um = max_sag_error_um.max(m.max_sag_error_um);
                        triangle_count += m.triangles.len();
                        let vertices: Vec<DVec3> = m.vertices.iter().map(|v| g.frame.point_to_global(DVec3::from_array(*v))).collect();
                        let normals = m.vertices.iter().map(|v| g.frame.dir_to_global(g.shape.normal(DVec3::from_array(*v)))).collect();
                        let v32: Vec<[f32; 3]> = vertices.iter().map(|v| v.as_vec3().to_array()).collect();
                        let geom = Geometry::triangle_mesh(&device, &v32, &m.triangles).and_then(|g| g.with_mask(mask)).map_err(embree_err)?;
                        (geom, Some(MeshNormals { normals, triangles: m.triangles }))
                    }
                };
                interface_object = Some(objects.len());
                attach(&mut scene, &mut objects, geom, SceneObject { role, frame: g.frame, patch: Some(patch), mesh, mask, apertures: g.explicit.clone() })?;
            }
            group_interface.push(interface_object);
            // Blades outside explicit apertures.
            for (surface, ap) in &g.explicit {
                let (v, t) = blade_mesh(g, ap, options.blade_width_mm);
                triangle_count += t.len();
                let geom = Geometry::triangle_mesh(&device, &v, &t).and_then(|g| g.with_mask(ABSORBER_MASK)).map_err(embree_err)?;
                // The group's figure over its clear aperture: f64 refinement re-decides a blade hit on
                // it (None if the figure cannot be bounded there; the blade then decides in f32).
                let patch = SurfacePatch::new(g.shape.clone(), g.clear.clone()).ok();
                let role = Role::Blade { surface: *surface, interface: interface_object };
                attach(&mut scene, &mut objects, geom, SceneObject { role, frame: g.frame, patch, mesh: None, mask: ABSORBER_MASK, apertures: g.explicit.clone() })?;
                absorbers += 1;
            }
            // Side walls of the solid between this group and the next, when the medium between is glass.
            if let Some(next) = groups.get(gi + 1) {
                if !system.surfaces[g.back_medium].medium_after.is_air() {
                    let (v, t) = wall_mesh(g, next);
                    triangle_count += t.len();
                    let geom = Geometry::triangle_mesh(&device, &v, &t).and_then(|g| g.with_mask(ABSORBER_MASK)).map_err(embree_err)?;
                    walls.push((objects.len(), gi));
                    attach(&mut scene, &mut objects, geom, SceneObject { role: Role::Wall { surface: g.surfaces[0], ends: Vec::new() }, frame: g.frame, patch: None, mesh: None, mask: ABSORBER_MASK, apertures: Vec::new() })?;
                    absorbers += 1;
                }
            }
        }
        for (object, gi) in walls {
            if let Role::Wall { ends, .. } = &mut objects[object].role {
                *ends = [group_interface[gi], group_interface.get(gi + 1).copied().flatten()].into_iter().flatten().collect();
            }
        }
        let scene = scene.commit().map_err(embree_err)?;
        let image_surface = system.surfaces.len() - 1;
        Ok(OpticalScene { scene, objects, image_surface, max_sag_error_um, triangle_count, geometry_count: (interfaces, absorbers), _device: device })
    }
}

/// Analytic user geometry: the exact patch in its frame, solved in f64 from Embree's f32 ray.
struct AnalyticSurface {
    frame: Frame,
    patch: SurfacePatch,
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
}

/// Is the step transform the identity (coincident frames)?
fn is_identity(rotation: &DMat3, offset: DVec3) -> bool {
    (*rotation - DMat3::IDENTITY).to_cols_array().iter().all(|v| v.abs() < 1e-12) && offset.abs().max_element() < 1e-12
}

/// Merge coincident path surfaces, decide virtual interfaces and clear apertures.
fn group_surfaces(system: &SequentialSystem, options: &SceneOptions) -> Result<Vec<Group>> {
    // Mechanical semi-diameters from the system's fields mirrored to all quadrants.
    let mut mirrored = system.clone();
    let mut fields = Vec::new();
    for f in if system.spec.fields_mm.is_empty() { vec![[0.0, 0.0]] } else { system.spec.fields_mm.clone() } {
        for (sx, sy) in [(1.0, 1.0), (-1.0, 1.0), (1.0, -1.0), (-1.0, -1.0)] {
            let g = [sx * f[0], sy * f[1]];
            if !fields.contains(&g) {
                fields.push(g);
            }
        }
    }
    mirrored.spec.fields_mm = fields;
    let auto = automatic_semi_diameters(&mirrored, 0.0, 32)?;
    let sd_of = |surface: usize| -> f64 {
        let zemax = system.surfaces[surface].semi_diameter_mm.unwrap_or(0.0);
        let a = auto.iter().find(|(s, _)| *s == surface).map(|(_, v)| *v).unwrap_or(0.0);
        zemax.max(a)
    };
    let last = system.path.len() - 1;
    let mut groups: Vec<Group> = Vec::new();
    for (k, step) in system.path.iter().enumerate() {
        let s = step.surface;
        let merge = k > 0
            && k != last
            && is_identity(&step.rotation, step.offset)
            && groups.last().is_some_and(|g| !g.is_image && g.shape == step.shape && matches!(step.shape, SurfaceShape::Plane));
        if merge {
            let g = groups.last_mut().unwrap();
            g.surfaces.push(s);
            g.back_medium = s;
            if step.aperture != Aperture::None {
                g.explicit.push((s, step.aperture.clone()));
            }
            continue;
        }
        groups.push(Group {
            surfaces: vec![s],
            frame: system.surfaces[s].frame,
            shape: step.shape.clone(),
            explicit: if step.aperture != Aperture::None { vec![(s, step.aperture.clone())] } else { vec![] },
            clear: Aperture::None,
            front_medium: s - 1,
            back_medium: s,
            virtual_: false,
            is_image: k == last,
        });
    }
    for g in &mut groups {
        let same_media = system.surfaces[g.front_medium].medium_after == system.surfaces[g.back_medium].medium_after;
        g.virtual_ = !g.is_image && same_media && !matches!(g.shape, SurfaceShape::Paraxial { .. });
        let mechanical = g.surfaces.iter().map(|&s| sd_of(s)).fold(0.0, f64::max) + options.mechanical_margin_mm
            + if g.is_image { options.detector_margin_mm } else { 0.0 };
        // Several explicit apertures on coincident surfaces: each gets its blade; the clear geometry uses
        // the first (the blades of the others clip what it would let through).
        g.clear = match g.explicit.first() {
            Some((_, ap)) => ap.clone(),
            None => Aperture::circular(mechanical),
        };
    }
    Ok(groups)
}

/// Point on the boundary of `ap` at polar angle `a` about its centre (local x, y). On a rectangle, the
/// sample angle nearest a corner (within half the rim's angular step) gives the corner itself, so the
/// rim polygon is the rectangle exactly (without it the polygon cuts the corners, and rays through
/// the aperture's corners met the side wall or the blade).
fn rim_point(ap: &Aperture, a: f64) -> (f64, f64) {
    let (c, s) = (a.cos(), a.sin());
    match *ap {
        Aperture::Circular { semi_diameter_mm: r, decenter_x_mm: dx, decenter_y_mm: dy, .. } => (dx + r * c, dy + r * s),
        Aperture::Rectangular { half_width_x_mm: hx, half_width_y_mm: hy, decenter_x_mm: dx, decenter_y_mm: dy } => {
            let half_step = std::f64::consts::PI / RIM_SAMPLES as f64;
            for (sx, sy) in [(1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0)] {
                let corner = f64::atan2(sy * hy, sx * hx);
                let diff = (a - corner).rem_euclid(std::f64::consts::TAU);
                if diff < half_step || std::f64::consts::TAU - diff <= half_step {
                    return (dx + sx * hx, dy + sy * hy);
                }
            }
            // Where the ray from the centre at angle a leaves the rectangle.
            let k = (hx / c.abs().max(1e-300)).min(hy / s.abs().max(1e-300));
            (dx + k * c, dy + k * s)
        }
        Aperture::None => (0.0, 0.0),
    }
}

/// The rim of a group's clear aperture, on its figure, in global coordinates: the side walls start here.
///
/// A circular rim is drawn as the polygon *circumscribed* about the circle (vertices at r / cos(π/N),
/// heights those of the circle's points): an inscribed polygon would cut up to r(1 − cos(π/N)) off the
/// clear aperture, and rays entering there (inside the aperture) would meet the wall at once.
fn rim(g: &Group) -> Vec<DVec3> {
    let out = 1.0 / (std::f64::consts::PI / RIM_SAMPLES as f64).cos();
    (0..RIM_SAMPLES)
        .map(|i| {
            let a = std::f64::consts::TAU * i as f64 / RIM_SAMPLES as f64;
            let (x, y) = rim_point(&g.clear, a);
            let z = g.shape.sag(x, y);
            let (x, y) = match g.clear {
                Aperture::Circular { decenter_x_mm: dx, decenter_y_mm: dy, .. } => (dx + (x - dx) * out, dy + (y - dy) * out),
                _ => (x, y),
            };
            g.frame.point_to_global(DVec3::new(x, y, if z.is_finite() { z } else { 0.0 }))
        })
        .collect()
}

/// Triangles of the band between two closed polygons of `RIM_SAMPLES` vertices each, stored one after the
/// other (vertex k of the first joined to vertex k of the second).
fn band_triangles() -> Vec<[u32; 3]> {
    let n = RIM_SAMPLES as u32;
    (0..n).flat_map(|i| {
        let j = (i + 1) % n;
        [[i, j, n + j], [i, n + j, n + i]]
    })
    .collect()
}

/// Ruled side wall joining the rims of two consecutive groups.
fn wall_mesh(a: &Group, b: &Group) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let vertices: Vec<[f32; 3]> = rim(a).iter().chain(&rim(b)).map(|v| v.as_vec3().to_array()).collect();
    (vertices, band_triangles())
}

/// Flat absorbing blade outside `ap`, in the plane z = sag at the rim, `width` wide.
fn blade_mesh(g: &Group, ap: &Aperture, width: f64) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let mut vertices = Vec::with_capacity(2 * RIM_SAMPLES);
    let (inner, outer): (Vec<(f64, f64)>, Vec<(f64, f64)>) = (0..RIM_SAMPLES)
        .map(|i| {
            let a = std::f64::consts::TAU * i as f64 / RIM_SAMPLES as f64;
            let (x, y) = rim_point(ap, a);
            let (cx, cy) = rim_point(ap, a + std::f64::consts::PI); // opposite point: centre = midpoint
            let (mx, my) = (0.5 * (x + cx), 0.5 * (y + cy));
            let (ux, uy) = (x - mx, y - my);
            let len = ux.hypot(uy).max(1e-300);
            ((x, y), (x + width * ux / len, y + width * uy / len))
        })
        .unzip();
    let z_of = |x: f64, y: f64| {
        let z = g.shape.sag(x, y);
        if z.is_finite() {
            z
        } else {
            0.0
        }
    };
    for &(x, y) in &inner {
        vertices.push(g.frame.point_to_global(DVec3::new(x, y, z_of(x, y))).as_vec3().to_array());
    }
    for (k, &(x, y)) in outer.iter().enumerate() {
        let (ix, iy) = inner[k];
        vertices.push(g.frame.point_to_global(DVec3::new(x, y, z_of(ix, iy))).as_vec3().to_array());
    }
    (vertices, band_triangles())
}
