//! The non-sequential description of a sequential system as **solids**, independent of any ray-tracing
//! kernel: the Embree scene ([`crate::tracer::embree::OpticalScene`]) and the brute-force tracer
//! ([`super::BruteForce`]) are both built from it, object for object in the same order.
//!
//! Every optical surface of the sequential path becomes one object over its clear aperture that knows the
//! media on both sides: the *front* (−normal side, where the sequential ray comes from unless it travels
//! toward −z after a mirror) and the *back*. A face the path crosses twice (a Mangin mirror's refracting
//! face: in, reflected at its back, out) is one object, not two coincident ones.
//! A mirror (`GLAS MIRROR`, [`Interaction::Reflect`]) becomes a **mirror face** ([`Role::Mirror`]): a
//! perfect reflector over its clear aperture, with the one medium it sits in (the sequential medium after a
//! mirror is the medium before it). It is never merged with coincident surfaces nor made virtual, and both
//! of its sides reflect (a zero-thickness reflector: nothing is transmitted through it). The figure and the
//! frame are the sequential surface's own: after a mirror the next surface lies at a negative thickness
//! (OpticStudio's convention), which the resolved frames already hold, so nothing is flipped here.
//! Around them:
//! * **walls** (absorbers): wherever the medium after a surface is glass, the rims of that surface and of
//!   the next are joined by a ruled side wall, closing the solid (prisms get their side/top/bottom faces,
//!   lenses their rims);
//! * **blades** (absorbers): an explicit aperture (Zemax's "(aper)") gets an annular (or rectangular-frame)
//!   blade outside it in the surface's rim plane, like a stop blade or lens mount;
//! * **obscurations** (absorbers): a circular obscuration (`OBSC`, [`Aperture::CircularObscuration`]) is an
//!   opaque disc or ring *inside* the beam. On a real face (a lens surface, a Mangin mirror) the face
//!   itself absorbs a ray whose exact hit lies in the obscured annulus (its apertures are tested at every
//!   hit, as the sequential tracer tests them), from either side; its clear patch is widened to cover the
//!   obscuration. On a virtual surface (a dummy plane in air, the usual place of a secondary mirror's
//!   shadow) there is no face, so an absorbing annulus is built on the figure over the obscured zone
//!   (a [`Role::Blade`]: its hits are re-decided on the exact figure like a blade's, so rays outside the
//!   annulus pass);
//! * the **detector**: the image surface.
//!
//! Zero-thickness and dummy surfaces are resolved explicitly, never left to floating-point ties between
//! coincident geometry: consecutive path surfaces with an identity transform between them and the same
//! plane figure are **merged** into one interface with the front medium of the first and the back medium
//! of the last; an interface whose two media are the same (and that is not an ideal lens) is **virtual** —
//! no geometry, only its rim (for walls) and blades (for its explicit apertures). An ideal lens touching a
//! real face, a mirror or the detector (zero thickness between their vertices) can be neither merged nor
//! ordered, and is refused.
//!
//! Surfaces without an explicit aperture get a *mechanical* clear aperture: the larger of Zemax's
//! semi-diameter and the automatic semi-diameter of the system's fields mirrored to all four quadrants,
//! plus [`SolidsOptions::mechanical_margin_mm`]; the detector gets [`SolidsOptions::detector_margin_mm`]
//! on top. Absorbers are triangle bands in f64 (the Embree scene rounds them to f32).
//!
//! The solids are checked against the system's **design beam** ([`super::design_beam`]): a detector disc
//! that would stand in the beam on its way to an earlier surface (a folded system) gets the largest margin
//! that clears it ([`Solids::detector_margin_mm`], [`Solids::design_beam_note`]); the image disc itself in
//! the beam, or another face whose mechanical margin reaches into it, is an error.
//!
//! Figures are the sequential surfaces' own ([`SurfaceShape`], Toroidal surfaces included: the bounded
//! patch solves them like an even asphere). An object at infinity gets a [`StartPlane`] in front of every
//! solid, where the walks start its rays ([`super::launch`]).
//!
//! ```
//! use diffcassi::prelude::*;
//! use diffcassi::tracer::nonseq::{Solids, SolidsOptions};
//! let sys = SequentialSystem::build(&presets::spec("sp")?)?;
//! let solids = Solids::build(&sys, &SolidsOptions::default())?;
//! assert!(solids.interfaces() >= 4);
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::design_beam::DesignBeam;
use super::launch::StartPlane;
use crate::analysis::mirrored_semi_diameters;
use crate::error::{Error, Result};
use crate::geometry::Frame;
use crate::surfaces::{Aperture, SurfacePatch, SurfaceShape};
use crate::system::{Interaction, SequentialSystem};
use glam::{DMat3, DVec3};

/// Margins of the solids (mm).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SolidsOptions {
    /// Added to the larger of Zemax's and the automatic semi-diameter of surfaces without explicit
    /// aperture (mm).
    pub mechanical_margin_mm: f64,
    /// Extra margin on the detector (mm).
    pub detector_margin_mm: f64,
    /// Radial width of the absorbing blade around an explicit aperture (mm).
    pub blade_width_mm: f64,
}

impl Default for SolidsOptions {
    fn default() -> Self {
        SolidsOptions { mechanical_margin_mm: 1.0, detector_margin_mm: 25.0, blade_width_mm: 10.0 }
    }
}

/// What an object does to a ray that reaches it.
#[derive(Clone, Debug, PartialEq)]
pub enum Role {
    /// Refracting (or ideal-lens) interface. `surfaces`: the merged sequential surfaces; media are indices
    /// into [`SequentialSystem::indices`]: `front_medium` on the −normal (local −z) side, `back_medium` on the
    /// +normal side — the media before and after the surface in sequential order, swapped where the
    /// sequential ray crosses it toward −z (after an odd number of mirrors, a Mangin mirror's face on the way
    /// out). A face the sequential path crosses twice is one interface (its first crossing's surfaces).
    ///
    /// `side_surfaces`: the sequential surface at which the sequential path meets the face from its front
    /// (−normal) side and from its back side — the label of a reflection there from that side (the ghost
    /// path labels, `5R 3R`). Both are `surfaces[0]` for a face crossed once; a face crossed twice (a Mangin
    /// mirror's front face, surfaces 2 and 4) gets each crossing's own surface on the side its ray comes
    /// from, so the reflection off it from the air (`2R`) and from the glass (`4R`), two different ghosts,
    /// keep different labels.
    Interface { surfaces: Vec<usize>, front_medium: usize, back_medium: usize, paraxial_focal_mm: Option<f64>, side_surfaces: [usize; 2] },
    /// A mirror (`GLAS MIRROR` on sequential surface `surface`): specular reflection d′ = d − 2(d·n̂)n̂ with
    /// reflectivity 1 on either side, no transmitted part. `medium`: the medium it sits in (index into
    /// [`SequentialSystem::indices`]: the medium before the mirror, which is also the one after it).
    Mirror { surface: usize, medium: usize },
    /// The image surface, with the media before and after it: the sequential tracer refracts at the image
    /// surface like at any other, so the detector reports the same (refracted) direction.
    Detector { surface: usize, front_medium: usize, back_medium: usize },
    /// Absorbing blade outside an explicit aperture of `surface`, or over the obscured annulus of a
    /// circular obscuration on a virtual surface (→ vignetted). `interface`: the object index of the
    /// group's refracting geometry (`None` for a virtual group, e.g. a stop in air).
    Blade { surface: usize, interface: Option<usize> },
    /// Absorbing side wall of the solid that starts at `surface` (→ absorbed). `ends`: the object indices
    /// of the refracting geometries whose rims the wall joins.
    Wall { surface: usize, ends: Vec<usize> },
}

/// One object of the solids.
#[derive(Clone, Debug)]
pub struct Solid {
    pub role: Role,
    /// Local frame of the surface (global = frame · local).
    pub frame: Frame,
    /// Interfaces and the detector: the exact figure over its clear aperture. Blades: the group's figure
    /// over its clear aperture (`None` if it cannot be bounded there). Walls: `None`.
    pub patch: Option<SurfacePatch>,
    /// Absorbers: the triangle band (global vertices, f64). Empty for interfaces.
    pub vertices: Vec<DVec3>,
    pub triangles: Vec<[u32; 3]>,
    /// The explicit apertures (with their sequential surface) of the object's group, in its local frame.
    pub apertures: Vec<(usize, Aperture)>,
}

impl Solid {
    /// Interfaces and the detector (optical geometry), as opposed to absorbers.
    pub fn is_optical(&self) -> bool {
        matches!(self.role, Role::Interface { .. } | Role::Mirror { .. } | Role::Detector { .. })
    }
}

/// The solids of a sequential system.
#[derive(Clone, Debug)]
pub struct Solids {
    pub objects: Vec<Solid>,
    /// Sequential index of the image surface.
    pub image_surface: usize,
    /// An object at infinity: the plane its rays start on, in front of every solid ([`super::launch`]).
    pub start_plane: Option<StartPlane>,
    /// The detector margin the solids were built with (mm): [`SolidsOptions::detector_margin_mm`], or less
    /// where the detector disc stood in the design beam ([`super::design_beam`]).
    pub detector_margin_mm: f64,
    /// Why the detector margin was shrunk, for people (`None`: it was not).
    pub design_beam_note: Option<String>,
}

impl Solids {
    /// Where the walk starts a launched ray: moved back to the [`StartPlane`] for an object at infinity,
    /// unchanged for a finite object.
    #[inline]
    pub fn launch_origin(&self, origin: DVec3, d: DVec3) -> DVec3 {
        super::launch::launch_origin(self.start_plane.as_ref(), origin, d)
    }

    /// Build the solids of `system`, checked against its design beam ([`super::design_beam`]): a detector
    /// disc that stands in the beam gets a smaller margin ([`Solids::detector_margin_mm`],
    /// [`Solids::design_beam_note`]). Errors: negative margins, a virtual object (negative object
    /// distance: non-sequential tracers follow rays forward only), a diffraction grating (not modelled
    /// here), a figure undefined over its aperture, the image disc (without margin) or a face's mechanical
    /// margin standing in the design beam.
    pub fn build(system: &SequentialSystem, options: &SolidsOptions) -> Result<Self> {
        let solids = Self::build_with_margins(system, options)?;
        let beam = DesignBeam::trace(system, solids.start_plane.as_ref());
        let fit = beam.detector_margin_mm(system, &solids, options)?;
        let mut solids = if fit.margin_mm < options.detector_margin_mm {
            Self::build_with_margins(system, &SolidsOptions { detector_margin_mm: fit.margin_mm, ..*options })?
        } else {
            solids
        };
        beam.check_faces(system, &solids, options)?;
        solids.detector_margin_mm = fit.margin_mm;
        solids.design_beam_note = fit.note;
        Ok(solids)
    }

    /// The solids of `system` with the margins of `options` as given (no design-beam check).
    fn build_with_margins(system: &SequentialSystem, options: &SolidsOptions) -> Result<Self> {
        if !(options.mechanical_margin_mm.is_finite() && options.mechanical_margin_mm >= 0.0)
            || !(options.detector_margin_mm.is_finite() && options.detector_margin_mm >= 0.0)
            || !(options.blade_width_mm.is_finite() && options.blade_width_mm > 0.0)
        {
            return Err(Error::invalid(format!("non-sequential scene options {options:?}: margins must be finite and ≥ 0, blade width > 0")));
        }
        // A negative object distance puts the object after surface 1 (a virtual object, reached by
        // propagating rays backwards as a sequential tracer may); a non-sequential tracer only follows rays
        // forward, so every ray would silently miss. Refuse it with the reason instead.
        // Gratings have no solids here: refuse them rather than let a grating become a plain refracting
        // face (no diffraction) that rays would silently pass (docs/ghosts.md says why they are not modelled
        // yet). Mirrors are modelled (mirror faces, `Role::Mirror`), Toroidal surfaces by their figure.
        if let Some(what) = unmodelled_surface(system) {
            return Err(Error::invalid(format!(
                "system `{}`: {what}; the non-sequential backends (Embree, brute force, ghosts) model refracting surfaces, mirrors and obscurations, not diffraction (use the analytic backend)",
                system.name()
            )));
        }
        // An object at infinity: surface 0's thickness is the 0 of the start plane at surface 1, and the
        // walks start the rays in front of every solid instead (`launch`).
        let object_mm = system.surfaces[0].thickness_mm;
        if object_mm < 0.0 {
            return Err(Error::invalid(format!(
                "system `{}`: surface 0 thickness {object_mm} mm < 0 is a virtual object; the non-sequential backends (Embree, brute force) trace rays forward only (use the analytic backend)",
                system.name()
            )));
        }
        let mut groups = group_surfaces(system, options)?;
        end_solids_at_knife_edges(system, &mut groups);
        let mut objects: Vec<Solid> = Vec::new();
        let mut group_interface: Vec<Option<usize>> = Vec::with_capacity(groups.len());
        let mut walls: Vec<(usize, usize)> = Vec::new();
        // Per object: the side (0 front, 1 back) the first crossing of an interface meets it from.
        let mut first_side: std::collections::HashMap<usize, usize> = std::collections::HashMap::new();
        for (gi, g) in groups.iter().enumerate() {
            let mut interface_object = None;
            if let Some(k) = (!g.virtual_ && !g.is_image && !g.mirror).then(|| same_face(&objects, system, g)).flatten() {
                // A face the sequential path crosses again (a Mangin mirror's refracting face, crossed on the
                // way in and on the way out) is the one object it already is (its clear aperture covers both
                // crossings: `group_surfaces`).
                interface_object = Some(k);
                // This crossing's ray meets the face from the side its medium before lies on (the same media
                // are on the same sides: `coincident_faces`); reflections from that side are labelled by it,
                // unless an earlier crossing came from that side already (that one keeps the label).
                let side = usize::from(g.backward);
                if let (Role::Interface { side_surfaces, .. }, Some(&first_side)) = (&mut objects[k].role, first_side.get(&k)) {
                    if side != first_side && side_surfaces[side] == side_surfaces[first_side] {
                        side_surfaces[side] = g.surfaces[0];
                    }
                }
            } else if !g.virtual_ {
                let patch = SurfacePatch::new(g.shape.clone(), g.clear.clone()).map_err(|e| Error::invalid(format!("surface {}: {e}", g.surfaces[0])))?;
                let role = if g.is_image {
                    Role::Detector { surface: g.surfaces[0], front_medium: g.medium_before, back_medium: g.medium_after }
                } else if g.mirror {
                    Role::Mirror { surface: g.surfaces[0], medium: g.medium_before }
                } else {
                    let (front_medium, back_medium) = g.sides();
                    Role::Interface {
                        surfaces: g.surfaces.clone(),
                        front_medium,
                        back_medium,
                        side_surfaces: [g.surfaces[0]; 2],
                        paraxial_focal_mm: match g.shape {
                            SurfaceShape::Paraxial { focal_length } => Some(focal_length),
                            _ => None,
                        },
                    }
                };
                interface_object = Some(objects.len());
                first_side.insert(objects.len(), usize::from(g.backward));
                objects.push(Solid { role, frame: g.frame, patch: Some(patch), vertices: Vec::new(), triangles: Vec::new(), apertures: g.explicit.clone() });
            }
            group_interface.push(interface_object);
            // Blades outside explicit clear apertures; an absorbing annulus over an obscuration on a
            // virtual surface (a real face absorbs in its obscured zone by its own aperture test).
            for (surface, ap) in &g.explicit {
                let (vertices, triangles) = match ap {
                    Aperture::CircularObscuration { .. } if !g.virtual_ => continue,
                    Aperture::CircularObscuration { .. } => obscuration_mesh(g, ap),
                    _ => blade_mesh(g, ap, options.blade_width_mm),
                };
                let patch = SurfacePatch::new(g.shape.clone(), g.clear.clone()).ok();
                let role = Role::Blade { surface: *surface, interface: interface_object };
                objects.push(Solid { role, frame: g.frame, patch, vertices, triangles, apertures: g.explicit.clone() });
            }
            // Side walls of the solid between this group and the next, when the medium between is glass.
            if let Some(next) = groups.get(gi + 1) {
                if !system.surfaces[g.medium_after].medium_after.is_air() {
                    let (vertices, triangles) = wall_mesh(g, next);
                    walls.push((objects.len(), gi));
                    objects.push(Solid { role: Role::Wall { surface: g.surfaces[0], ends: Vec::new() }, frame: g.frame, patch: None, vertices, triangles, apertures: Vec::new() });
                }
            }
        }
        for (object, gi) in walls {
            if let Role::Wall { ends, .. } = &mut objects[object].role {
                *ends = [group_interface[gi], group_interface.get(gi + 1).copied().flatten()].into_iter().flatten().collect();
            }
        }
        check_edge_thickness(system, &groups, options)?;
        let start_plane = system.object_at_infinity().then(|| StartPlane::in_front_of(&objects));
        Ok(Solids { objects, image_surface: system.surfaces.len() - 1, start_plane, detector_margin_mm: options.detector_margin_mm, design_beam_note: None })
    }

    /// Number of optical objects (interfaces + detector).
    pub fn interfaces(&self) -> usize {
        self.objects.iter().filter(|o| o.is_optical()).count()
    }

    /// Triangles of the absorbers.
    pub fn absorber_triangles(&self) -> usize {
        self.objects.iter().map(|o| o.triangles.len()).sum()
    }
}

/// The first surface of `system` the solids do not model — a diffraction grating (reflective or not) — as
/// "surface i is …", or `None`. Mirrors and Toroidal surfaces are modelled.
fn unmodelled_surface(system: &SequentialSystem) -> Option<String> {
    system.surfaces.iter().find_map(|s| {
        let what = match s.interaction {
            Interaction::Grating { reflective: true, .. } => "a reflective diffraction grating",
            Interaction::Grating { .. } => "a diffraction grating",
            _ => return None,
        };
        Some(format!("surface {} is {what}", s.index))
    })
}

/// Consecutive real faces (dummies skipped) with glass between them, as group indices.
fn glass_pairs(system: &SequentialSystem, groups: &[Group]) -> Vec<(usize, usize)> {
    let real: Vec<usize> = (0..groups.len()).filter(|&i| !groups[i].virtual_ && !matches!(groups[i].shape, SurfaceShape::Paraxial { .. })).collect();
    real.windows(2).filter(|w| !system.surfaces[groups[w[0]].medium_after].medium_after.is_air()).map(|w| (w[0], w[1])).collect()
}

/// A lens whose faces cross outside the beam ends there: a knife edge, as a real patent lens has just outside
/// its clear aperture (US05331467-1's surfaces 12 and 13 cross at r = 17.379 mm, semi-diameters 16.50 and
/// 16.46 mm), or a semi-diameter drawn wider than the glass can be while the beam (the automatic
/// semi-diameters of the system's fields) stays inside the crossing: the mechanical clear radius of both faces
/// is cut to the crossing (the glass ends where its faces meet; the wall between the rims shrinks to nothing),
/// and the sequential commands warn at load that the semi-diameter claims glass beyond it
/// ([`crate::system::SequentialSystem::edge_crossing_warnings`]). A crossing the beam reaches is refused by
/// [`check_edge_thickness`].
fn end_solids_at_knife_edges(system: &SequentialSystem, groups: &mut [Group]) {
    for (i, j) in glass_pairs(system, groups) {
        let mechanical = |g: &Group| !g.explicit.iter().any(|(_, ap)| ap.is_bounded()) && matches!(g.clear, Aperture::Circular { .. });
        if !(mechanical(&groups[i]) && mechanical(&groups[j])) {
            continue;
        }
        let (a, b) = (&groups[i], &groups[j]);
        let Some(rc) = crate::system::faces_crossing_radius((&a.shape, &a.frame, &a.clear), (&b.shape, &b.frame, &b.clear)) else { continue };
        if rc > a.auto_sd_mm.max(b.auto_sd_mm) {
            let r = rc - 1e-9;
            for k in [i, j] {
                if let Aperture::Circular { semi_diameter_mm, .. } = &mut groups[k].clear {
                    *semi_diameter_mm = semi_diameter_mm.min(r);
                }
            }
        }
    }
}

/// Refuse a glass whose two faces still cross inside the clear apertures the solid is built to once
/// [`end_solids_at_knife_edges`] has cut those outside the beam (a negative edge thickness where the system's
/// beam goes, or inside an explicit clear aperture: [`crate::system::faces_crossing_radius`]). Beyond the
/// crossing the back face stands in front of the front face, and the walk meets them in the wrong order: a
/// refracting singlet at infinity reported an order-1 ghost (one reflection, which sends light back toward the
/// object) with 1.1 % of the image, and Embree disagreed silently with the analytic tracer (round 21). A
/// sequential tracer traces such a lens (virtual propagation between the faces' extensions); where the beam
/// crosses the knife edge no solid models it, so it is refused, naming the faces, the glass, where they cross
/// and how far the solid reaches. Pairs: consecutive real faces (mirrors included, dummies skipped) with glass
/// between them, as the side walls join them. Faces whose axes are parallel are checked (coaxial, decentred,
/// turned about the axis); faces tilted relative to each other (a prism's, meant to meet at its apex) are
/// not: the walls join their rims whatever the angle.
fn check_edge_thickness(system: &SequentialSystem, groups: &[Group], options: &SolidsOptions) -> Result<()> {
    for (i, j) in glass_pairs(system, groups) {
        let (a, b) = (&groups[i], &groups[j]);
        let glass = &system.surfaces[a.medium_after].medium_after;
        let Some(rc) = crate::system::faces_crossing_radius((&a.shape, &a.frame, &a.clear), (&b.shape, &b.frame, &b.clear)) else { continue };
        let f = |v: f64| crate::limits::fmt_num((v * 1e4).round() / 1e4);
        let names = |g: &Group| g.surfaces.iter().map(|s| s.to_string()).collect::<Vec<_>>().join("+");
        let built = |g: &Group| match (g.explicit.iter().any(|(_, ap)| ap.is_bounded()), &g.clear) {
            (false, Aperture::Circular { semi_diameter_mm, .. }) => {
                format!("surface {} to r = {} mm (semi-diameter {} mm + mechanical margin {} mm)", names(g), f(*semi_diameter_mm), f(g.sd_mm), f(options.mechanical_margin_mm))
            }
            _ => format!("surface {} to its clear aperture", names(g)),
        };
        // A crossing outside the beam was cut to (`end_solids_at_knife_edges`); what reaches here is a crossing
        // the beam reaches, or clear apertures given explicitly (which are not cut).
        let beam = a.auto_sd_mm.max(b.auto_sd_mm);
        let advice = if beam < rc {
            format!("give the faces a semi_diameter_mm below {} mm (the beam reaches r = {} mm there; the solid then ends at the crossing), or thicken the lens", f(rc), f(beam))
        } else {
            format!("the beam itself reaches r = {} mm there (its automatic semi-diameter), beyond the crossing: thicken the lens (or change its radii)", f(beam))
        };
        return Err(Error::invalid(format!(
            "system `{}`: surfaces {} and {} ({glass} between them) cross at r = {} mm, inside the radius the non-sequential solid needs ({}; {}): the lens has a negative edge thickness there, a solid that cannot exist; {advice}",
            system.name(),
            names(a),
            names(b),
            f(rc),
            built(a),
            built(b),
        )));
    }
    Ok(())
}

/// Samples on a rim polygon (walls and blades).
pub const RIM_SAMPLES: usize = 192;

/// A group of merged sequential path steps.
struct Group {
    surfaces: Vec<usize>,
    frame: Frame,
    shape: SurfaceShape,
    explicit: Vec<(usize, Aperture)>,
    /// Clear aperture used for the geometry and the rim.
    clear: Aperture,
    /// The media before and after the group in sequential order (indices into
    /// [`SequentialSystem::indices`]).
    medium_before: usize,
    medium_after: usize,
    /// The sequential ray crosses the group toward its local −z ([`travels_backward`]).
    backward: bool,
    virtual_: bool,
    is_image: bool,
    /// A mirror ([`Interaction::Reflect`]): one surface, never merged, never virtual.
    mirror: bool,
    /// The semi-diameter its mechanical clear aperture adds the margin to (mm): the larger of Zemax's and
    /// the automatic one of the mirrored fields, over the merged surfaces; and the automatic one alone.
    sd_mm: f64,
    auto_sd_mm: f64,
}

impl Group {
    /// The media on the group's −normal (local −z) and +normal sides: before and after it in sequential
    /// order, swapped where the sequential ray crosses it toward −z.
    fn sides(&self) -> (usize, usize) {
        if self.backward {
            (self.medium_after, self.medium_before)
        } else {
            (self.medium_before, self.medium_after)
        }
    }
}

/// Whether the sequential ray reaches surface `s` travelling toward its local −z: OpticStudio's
/// convention, a ray moves along +z of the current frame over a positive thickness and along −z over a
/// negative one (after a mirror; coordinate breaks turn the frame, not the sign), so the sign of the last
/// non-zero thickness before `s` says which way it crosses `s` (+z when there is none).
fn travels_backward(system: &SequentialSystem, s: usize) -> bool {
    system.surfaces[..s].iter().rev().map(|x| x.thickness_mm).find(|t| *t != 0.0).is_some_and(|t| t < 0.0)
}

/// The refracting face among `objects` that group `g` is again — the same figure at the same place (to
/// 1e-9 mm and 1e-12 in the rotation), with the same media on the same sides — or `None`.
fn same_face(objects: &[Solid], system: &SequentialSystem, g: &Group) -> Option<usize> {
    objects.iter().position(|o| {
        let Role::Interface { front_medium, back_medium, paraxial_focal_mm: None, .. } = &o.role else { return false };
        o.patch.as_ref().is_some_and(|p| coincident_faces(system, (&p.shape, &o.frame, (*front_medium, *back_medium)), (&g.shape, &g.frame, g.sides())))
    })
}

/// Two faces that are one: the same figure in the same frame (to rounding) with the same media on each side
/// (`(shape, frame, (front medium, back medium))`, media as surface indices).
fn coincident_faces(system: &SequentialSystem, a: (&SurfaceShape, &Frame, (usize, usize)), b: (&SurfaceShape, &Frame, (usize, usize))) -> bool {
    let medium = |m: usize| &system.surfaces[m].medium_after;
    a.0 == b.0
        && same_origin(a.1, b.1)
        && (a.1.rotation - b.1.rotation).to_cols_array().iter().all(|v| v.abs() < 1e-12)
        && medium(a.2 .0) == medium(b.2 .0)
        && medium(a.2 .1) == medium(b.2 .1)
}

/// Do two frames have the same origin (to 1e-9 mm, relative beyond 1 mm)?
fn same_origin(a: &Frame, b: &Frame) -> bool {
    (a.origin - b.origin).abs().max_element() <= 1e-9 * (1.0 + b.origin.abs().max_element())
}

/// Is the step transform the identity (coincident frames)?
fn is_identity(rotation: &DMat3, offset: DVec3) -> bool {
    (*rotation - DMat3::IDENTITY).to_cols_array().iter().all(|v| v.abs() < 1e-12) && offset.abs().max_element() < 1e-12
}

/// Why a coating on each sequential surface would do nothing in the non-sequential model (`None` where it
/// acts): what [`crate::spec::SystemSpec::not_an_interface`] says (the object and image surfaces, a mirror,
/// a Coordinate Break, a paraxial lens), a surface with the same medium on both sides (a virtual interface:
/// no geometry, nothing reflects there), and a plane merged into the coincident plane before it (one
/// interface, which reads the first surface's coating, as [`super::walk_tree`] does). `--coating` and the
/// ghost passes check coatings against it, so that no coating is recorded that nothing applies.
pub fn coating_sites(system: &SequentialSystem) -> Result<Vec<Option<String>>> {
    let spec = &system.spec;
    let mut out: Vec<Option<String>> = (0..spec.surfaces.len()).map(|k| spec.not_an_interface(k).map(|what| format!("{what}, not a refracting interface"))).collect();
    let groups = group_surfaces(system, &SolidsOptions::default())?;
    for (gi, g) in groups.iter().enumerate() {
        if g.is_image || g.mirror {
            continue;
        }
        // A face the sequential path crosses again (a Mangin mirror's refracting face, in and out) is one
        // object, built from its first crossing, whose coating both crossings read (`build`, `same_face`): a
        // coating given on the later crossing's surface would be silently unused (round 21).
        let again = (!g.virtual_)
            .then(|| {
                groups[..gi].iter().find(|e| {
                    !e.virtual_ && !e.is_image && !e.mirror && coincident_faces(system, (&e.shape, &e.frame, e.sides()), (&g.shape, &g.frame, g.sides()))
                })
            })
            .flatten();
        for (j, &s) in g.surfaces.iter().enumerate() {
            if out[s].is_some() {
                continue;
            }
            if let Some(e) = again {
                let first = e.surfaces[0];
                out[s] = Some(format!("the face of surface {first} crossed again by the sequential path (one face, whose coating is surface {first}'s: give the coating there)"));
            } else if g.virtual_ {
                out[s] = Some(format!("a dummy surface (the same medium, {}, on both sides: nothing reflects there)", system.surfaces[g.medium_after].medium_after));
            } else if j > 0 {
                let first = g.surfaces[0];
                out[s] = Some(format!("merged with surface {first} (coincident planes with nothing between them are one interface, which takes surface {first}'s coating)"));
            }
        }
    }
    Ok(out)
}

/// Merge coincident path surfaces, decide virtual interfaces and clear apertures.
fn group_surfaces(system: &SequentialSystem, options: &SolidsOptions) -> Result<Vec<Group>> {
    // Mechanical semi-diameters from the system's fields mirrored to all quadrants.
    let auto = mirrored_semi_diameters(system)?;
    let auto_of = |surface: usize| -> f64 { auto.iter().find(|(s, _)| *s == surface).map(|(_, v)| *v).unwrap_or(0.0) };
    let sd_of = |surface: usize| -> f64 { system.surfaces[surface].semi_diameter_mm.unwrap_or(0.0).max(auto_of(surface)) };
    let last = system.path.len() - 1;
    let mut groups: Vec<Group> = Vec::new();
    for (k, step) in system.path.iter().enumerate() {
        let s = step.surface;
        let mirror = step.interaction == Interaction::Reflect;
        // A mirror is never merged with a coincident plane (nor one into it): a merged group would have to
        // both reflect and refract.
        let merge = k > 0
            && k != last
            && !mirror
            && is_identity(&step.rotation, step.offset)
            && groups.last().is_some_and(|g| !g.is_image && !g.mirror && g.shape == step.shape && matches!(step.shape, SurfaceShape::Plane));
        if merge {
            let g = groups.last_mut().unwrap();
            g.surfaces.push(s);
            g.medium_after = s;
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
            medium_before: s - 1,
            medium_after: s,
            backward: travels_backward(system, s),
            virtual_: false,
            is_image: k == last,
            mirror,
            sd_mm: 0.0,
            auto_sd_mm: 0.0,
        });
    }
    for g in &mut groups {
        let same_media = system.surfaces[g.medium_before].medium_after == system.surfaces[g.medium_after].medium_after;
        // A mirror has the same medium on both sides yet is real geometry: it reflects.
        g.virtual_ = !g.is_image && !g.mirror && same_media && !matches!(g.shape, SurfaceShape::Paraxial { .. });
        g.sd_mm = g.surfaces.iter().map(|&s| sd_of(s)).fold(0.0, f64::max);
        g.auto_sd_mm = g.surfaces.iter().map(|&s| auto_of(s)).fold(0.0, f64::max);
        let mechanical = g.sd_mm + options.mechanical_margin_mm
            + if g.is_image { options.detector_margin_mm } else { 0.0 };
        // A face with an obscuration covers it (its outer edge plus the mechanical margin): the face absorbs
        // in the obscured annulus, so no ray may pass beside it there.
        let obscured = g
            .explicit
            .iter()
            .filter_map(|(_, ap)| match *ap {
                Aperture::CircularObscuration { max_radius_mm, decenter_x_mm, decenter_y_mm, .. } => Some(max_radius_mm + decenter_x_mm.hypot(decenter_y_mm) + options.mechanical_margin_mm),
                _ => None,
            })
            .fold(0.0, f64::max);
        // Several explicit clear apertures on coincident surfaces: each gets its blade; the clear geometry
        // uses the first (the blades of the others clip what it would let through). Obscurations bound
        // nothing: without a clear aperture the mechanical one is used.
        g.clear = match g.explicit.iter().find(|(_, ap)| ap.is_bounded()) {
            Some((_, ap)) => ap.clone(),
            None => Aperture::circular(mechanical.max(obscured)),
        };
    }
    // A face the path crosses twice (a Mangin mirror's refracting face) is one solid: its mechanical clear
    // aperture covers both crossings, before any rim is built from it (the walls of the glass meet the
    // widened rim; a wall left at the first crossing's rim stood in the way of the second's outer rays).
    for j in 0..groups.len() {
        for i in 0..j {
            let real = |g: &Group| !g.virtual_ && !g.is_image && !g.mirror && g.explicit.is_empty() && !matches!(g.shape, SurfaceShape::Paraxial { .. });
            let (a, b) = (&groups[i], &groups[j]);
            if real(a) && real(b) && coincident_faces(system, (&a.shape, &a.frame, a.sides()), (&b.shape, &b.frame, b.sides())) {
                if let (Aperture::Circular { semi_diameter_mm: ra, .. }, Aperture::Circular { semi_diameter_mm: rb, .. }) = (&a.clear, &b.clear) {
                    let r = ra.max(*rb);
                    groups[i].clear = Aperture::circular(r);
                    groups[j].clear = Aperture::circular(r);
                }
            }
        }
    }
    // An ideal lens and a real face (a lens or prism face, curved or tilted; a mirror; the detector) that
    // touch (zero thickness between their vertices) cannot be ordered by a next-hit walk near the touching
    // point: the second hit lies within the first's offset and was skipped (a reflectance-1 coating on the
    // face let 42 % through, a curved face lost 5 % of a ghost, the detector 24 % of the image; two probers,
    // round 11). Refused, naming both, rather than walked wrong.
    for pair in groups.windows(2) {
        let (a, b) = (&pair[0], &pair[1]);
        let paraxial = |g: &Group| matches!(g.shape, SurfaceShape::Paraxial { .. });
        let real = |g: &Group| !g.virtual_ && !paraxial(g);
        if same_origin(&a.frame, &b.frame) && ((paraxial(a) && real(b)) || (real(a) && paraxial(b))) {
            let (p, f) = if paraxial(a) { (a, b) } else { (b, a) };
            let face = f.surfaces.iter().map(|s| s.to_string()).collect::<Vec<_>>().join(", ");
            return Err(Error::invalid(format!(
                "system `{}`: the paraxial lens of surface {} and the {} of surface{} {face} touch (zero thickness between them): the non-sequential tracers cannot order two interfaces there; put a small thickness (e.g. 1e-6 mm) between them",
                system.name(),
                p.surfaces[0],
                if f.is_image { "detector" } else if f.mirror { "mirror" } else { "face" },
                if f.surfaces.len() > 1 { "s" } else { "" },
            )));
        }
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
        Aperture::None | Aperture::CircularObscuration { .. } => (0.0, 0.0),
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
fn wall_mesh(a: &Group, b: &Group) -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let vertices: Vec<DVec3> = rim(a).into_iter().chain(rim(b)).collect();
    (vertices, band_triangles())
}

/// Flat absorbing blade outside `ap`, in the plane z = sag at the rim, `width` wide.
fn blade_mesh(g: &Group, ap: &Aperture, width: f64) -> (Vec<DVec3>, Vec<[u32; 3]>) {
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
        vertices.push(g.frame.point_to_global(DVec3::new(x, y, z_of(x, y))));
    }
    for (k, &(x, y)) in outer.iter().enumerate() {
        let (ix, iy) = inner[k];
        vertices.push(g.frame.point_to_global(DVec3::new(x, y, z_of(ix, iy))));
    }
    (vertices, band_triangles())
}

/// Rings of the absorbing annulus over an obscuration ([`obscuration_mesh`]), inner edge to outer edge.
const OBSCURATION_RINGS: usize = 16;

/// An absorbing annulus (a disc when `min_radius_mm` = 0) over the obscured zone of a circular obscuration,
/// on the group's figure: [`OBSCURATION_RINGS`] + 1 rings of [`RIM_SAMPLES`] vertices at the figure's sag
/// (exact on a plane, within the chord error on a curved figure), the outer one *circumscribed* about the
/// obscuration's outer circle and the inner one *inscribed* in its inner circle, so the mesh covers the
/// whole obscured annulus; its hits are re-decided on the exact figure (rays outside the annulus pass).
fn obscuration_mesh(g: &Group, ap: &Aperture) -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let Aperture::CircularObscuration { min_radius_mm, max_radius_mm, decenter_x_mm: dx, decenter_y_mm: dy } = *ap else {
        return (Vec::new(), Vec::new());
    };
    let out = 1.0 / (std::f64::consts::PI / RIM_SAMPLES as f64).cos();
    let n = RIM_SAMPLES as u32;
    let mut vertices = Vec::with_capacity((OBSCURATION_RINGS + 1) * RIM_SAMPLES);
    for k in 0..=OBSCURATION_RINGS {
        let f = k as f64 / OBSCURATION_RINGS as f64;
        let r = if k == OBSCURATION_RINGS { max_radius_mm * out } else { min_radius_mm + f * (max_radius_mm - min_radius_mm) };
        for i in 0..RIM_SAMPLES {
            let a = std::f64::consts::TAU * i as f64 / RIM_SAMPLES as f64;
            let (x, y) = (dx + r * a.cos(), dy + r * a.sin());
            let z = g.shape.sag(x, y);
            vertices.push(g.frame.point_to_global(DVec3::new(x, y, if z.is_finite() { z } else { 0.0 })));
        }
    }
    // Consecutive rings joined as a band; a disc's innermost ring is its centre (its triangles there have
    // one vertex repeated: zero area, never hit), so the next band closes it.
    let triangles = (0..OBSCURATION_RINGS as u32)
        .flat_map(|k| band_triangles().into_iter().map(move |t| t.map(|v| v + k * n)))
        .filter(|t| !(min_radius_mm == 0.0 && t.iter().filter(|&&v| v < n).count() >= 2))
        .collect();
    (vertices, triangles)
}
