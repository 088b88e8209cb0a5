use crate::geometry::Frame;
use crate::materials::Medium;
use crate::spec::SurfaceKind;
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
}
