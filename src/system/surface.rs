use crate::geometry::Frame;
use crate::materials::Medium;
use crate::spec::SurfaceKind;
use crate::surfaces::grating::Grating;
use crate::surfaces::{Aperture, SurfaceShape};
use glam::{DMat3, DVec3};

/// One surface placed in space.
#[derive(Clone, Debug)]
pub struct ResolvedSurface {
    pub index: usize,
    pub kind: SurfaceKind,
    pub comment: String,
    pub is_stop: bool,
    /// The surface's local frame (for a Coordinate Break: the frame in which the break sits).
    pub frame: Frame,
    /// Figure for refracting/object/image surfaces; `None` for Coordinate Breaks.
    pub shape: Option<SurfaceShape>,
    pub aperture: Aperture,
    /// Medium after the surface (a Coordinate Break repeats the medium before it).
    pub medium_after: Medium,
    pub thickness_mm: f64,
    pub semi_diameter_mm: Option<f64>,
    /// What the surface does to a ray that meets it.
    pub interaction: Interaction,
}

/// What a surface does to a ray: refract (vector Snell's law, or the ideal lens of a Paraxial surface;
/// nothing where the index does not change), reflect (`GLAS MIRROR`), or diffract into one grating order.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Interaction {
    Refract,
    /// A mirror: d′ = d − 2(d·n̂)n̂ (OpticStudio's `GLAS MIRROR`; the medium after is the medium before).
    Reflect,
    /// A diffraction grating ([`crate::surfaces::grating`]); `reflective` when it is also a mirror.
    /// `wavelength_slot` is the entry of the index table that holds the ray's wavelength (nm): the tables
    /// of a system with gratings carry it after the per-surface indices ([`super::SequentialSystem::indices`]).
    Grating { grating: Grating, reflective: bool, wavelength_slot: usize },
}

impl Interaction {
    /// Whether the surface reflects (a mirror or a reflective grating).
    pub fn reflects(&self) -> bool {
        matches!(self, Interaction::Reflect | Interaction::Grating { reflective: true, .. })
    }
}

/// A step of the traced path: go from the previous step's frame into this surface's frame
/// (p ← M·(p − o), d ← M·d), intersect, clip, refract.
#[derive(Clone, Debug)]
pub(crate) struct PathStep {
    pub surface: usize,
    pub rotation: DMat3,
    pub offset: DVec3,
    pub shape: SurfaceShape,
    pub aperture: Aperture,
    pub interaction: Interaction,
}
