//! The resolved sequential system: every surface placed in global space, pickups and chief-ray solves
//! evaluated, media known, the paraxial entrance pupil located. This is what tracer backends consume.
//!
//! ```
//! use diffcassi::system::SequentialSystem;
//! let sys = SequentialSystem::build(&diffcassi::presets::spec("sp").unwrap()).unwrap();
//! assert_eq!(sys.surfaces.len(), 20);
//! // Zemax shows the chief-ray-solved decenter of surface 15 as 2.408 mm.
//! assert!((sys.spec.surfaces[15].decenter_x_mm.as_ref().unwrap().value - 2.408).abs() < 5e-4);
//! ```
mod build;
mod coded_mask;
mod edge_thickness;
mod fields;
mod paraxial;
mod surface;
mod vignetting;
mod warnings;

pub use coded_mask::{MaskSurface, MaskTaps};
pub use edge_thickness::{faces_crossing_radius, FaceCrossing};
pub use paraxial::*;
pub use surface::*;
pub use vignetting::VignettingFactors;

use crate::error::{Error, Result};
use crate::spec::SystemSpec;

/// The unit of a field point given at the boundary ([`SequentialSystem::field_point`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FieldUnit {
    /// Object height, mm (finite objects).
    Mm,
    /// Field angles, degrees (objects at infinity).
    Deg,
}

/// Where a system's spec was read from, which chooses the fix its messages name: a spec's field
/// (`wavelength_policy = "AllowExtrapolation"`) or a `.zmx` file's own record (`DCWP allow_extrapolation`).
/// One rule for every entry point (CLI, Python, studies): the build's errors and every later one — a
/// wavelength given at run time (`trace --wavelength-nm`, Python `trace`) outside a glass's range — name the
/// fix of the file the user has ([`SequentialSystem::build_from`]; round 19: a run-time wavelength of a `.zmx`
/// system named the spec's field and a Rust enum).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum SystemOrigin {
    /// A spec (TOML, JSON, YAML, CSV), a preset, a spec built in code.
    #[default]
    Spec,
    /// A Zemax `.zmx` lens file.
    Zmx,
}

impl SystemOrigin {
    /// The origin of a system read from `path`: by its extension (`.zmx`, any case), as the spec loader
    /// ([`crate::spec::load_spec_file`]) chooses the reader.
    pub fn of_path(path: &std::path::Path) -> Self {
        if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("zmx")) {
            Self::Zmx
        } else {
            Self::Spec
        }
    }

    /// `e` with the fixes a user of this origin has ([`crate::spec::zmx::with_zmx_hints`] for a `.zmx` file).
    pub fn hints(self, e: Error) -> Error {
        match self {
            Self::Spec => e,
            Self::Zmx => crate::spec::zmx::with_zmx_hints(e),
        }
    }
}

/// A sequential system ready to trace.
#[derive(Clone, Debug)]
pub struct SequentialSystem {
    /// The spec with every pickup and solve resolved (cell values are the values used).
    pub spec: SystemSpec,
    pub surfaces: Vec<ResolvedSurface>,
    pub stop_index: usize,
    /// Paraxial entrance pupil at the primary wavelength.
    pub pupil: EntrancePupil,
    /// First-order data (EFL, BFL, pupil positions) at the primary wavelength.
    pub first_order: FirstOrder,
    /// The spec's fields as object-space field points ([`crate::spec::FieldType`] resolved): object heights
    /// (x, y) in mm for a finite object, field angles (θx, θy) in radians for an object at infinity. Every
    /// ray-generating function (`rays::object_ray`, `aimed_ray`, `RayBatch::for_field`) takes such points.
    pub fields: Vec<[f64; 2]>,
    /// The stop radius (mm) that ray aiming aims (px, py) at ([`crate::spec::RayAiming`]): the real stop
    /// radius under `real` aiming (the real marginal ray's height at the stop), else the paraxial one
    /// (`pupil.stop_radius_mm`; the stop's semi-diameter under float by stop size).
    pub aim_stop_radius_mm: f64,
    /// The refracting surfaces after the object, in order, with frame-to-frame transforms.
    pub(crate) path: Vec<PathStep>,
    /// How to reach the stop for ray aiming: the first `steps` path steps, then `probe` (intersection only).
    pub(crate) stop_probe: StopProbe,
    /// The coded-mask surface, when the mask sits inside the system (dual-disperser CASSI); `None`: the mask
    /// is on the object plane (single-disperser CASSI).
    pub coded_mask: Option<MaskSurface>,
    /// Where the spec was read from ([`SystemOrigin`]; [`Self::build_from`]): the fixes its errors name.
    pub(crate) origin: SystemOrigin,
}

/// Where the stop sits relative to the traced path (used by ray aiming).
#[derive(Clone, Debug)]
pub(crate) struct StopProbe {
    pub steps: usize,
    pub probe: PathStep,
    /// The path's first `steps` steps with their apertures opened (`Aperture::None`: clear apertures and
    /// obscurations), for the aiming trace ([`crate::rays::aim::stop_crossing`]); `None` when no step before
    /// the stop has one.
    pub open_path: Option<Vec<PathStep>>,
}

/// Index of a medium at `wavelength_nm` under the spec's air index and wavelength policy.
pub(crate) fn medium_index(m: &crate::materials::Medium, spec: &SystemSpec, wavelength_nm: f64) -> Result<f64> {
    let n = m.refractive_index(wavelength_nm, spec.wavelength_policy)?;
    Ok(if m.is_air() { spec.air_index } else { n })
}

impl SequentialSystem {
    pub fn name(&self) -> &str {
        &self.spec.name
    }

    /// Where the system's spec was read from ([`SystemOrigin`]).
    pub fn origin(&self) -> SystemOrigin {
        self.origin
    }

    /// Refractive index after each surface at `wavelength_nm` (index 0: object space), honouring the
    /// spec's wavelength policy (out-of-range is an error unless extrapolation is allowed). A system with a
    /// diffraction grating appends one entry, the wavelength itself (nm), which the grating steps read
    /// ([`Interaction::Grating`]'s `wavelength_slot`); without gratings the table is exactly one index per surface.
    pub fn indices(&self, wavelength_nm: f64) -> Result<Vec<f64>> {
        if !(wavelength_nm.is_finite() && wavelength_nm > 0.0) {
            return Err(Error::invalid(format!("wavelength {wavelength_nm} nm: must be finite and > 0")));
        }
        // A wavelength outside a glass's range names the fix of the file the system came from (its origin).
        let mut n: Vec<f64> = self
            .surfaces
            .iter()
            .map(|s| medium_index(&s.medium_after, &self.spec, wavelength_nm))
            .collect::<Result<_>>()
            .map_err(|e| self.origin.hints(e))?;
        if self.has_grating() {
            n.push(wavelength_nm);
        }
        Ok(n)
    }

    /// The product of the efficiencies of the system's grating orders (`grating_efficiency`, default 1): the
    /// fraction of the power its traced path carries. 1 without gratings.
    pub fn grating_efficiency(&self) -> f64 {
        self.spec.surfaces.iter().filter(|s| s.kind == crate::spec::SurfaceKind::DiffractionGrating).map(|s| s.grating_efficiency.unwrap_or(1.0)).product()
    }

    /// Whether a surface of the system is a diffraction grating.
    pub fn has_grating(&self) -> bool {
        self.surfaces.iter().any(|s| matches!(s.interaction, Interaction::Grating { .. }))
    }

    /// Whether the system holds a surface the lane reverse sweep (`diff::adjoint_lanes`; the scalar sweep
    /// covers them) or the Embree backends (mirrors aside) do not model (a mirror, a grating or a Toroidal
    /// surface; the GPU kernels model all three): `None`, or what it is and where.
    pub fn special_surface(&self) -> Option<String> {
        self.surfaces.iter().find_map(|s| {
            let what = match (s.interaction, &s.shape) {
                (Interaction::Reflect, _) => "a mirror",
                (Interaction::Grating { .. }, _) => "a diffraction grating",
                (_, Some(crate::surfaces::SurfaceShape::Toroidal { .. })) => "a Toroidal surface",
                _ => return None,
            };
            Some(format!("surface {} is {what}", s.index))
        })
    }

    /// The image surface (last).
    pub fn image(&self) -> &ResolvedSurface {
        self.surfaces.last().expect("a built system has surfaces")
    }

    /// Whether the object is at infinity (field points are angles in radians, rays of a field are parallel).
    pub fn object_at_infinity(&self) -> bool {
        self.pupil.object_at_infinity
    }

    /// The field points to use when none is given: the system's, or the axis when it defines none.
    pub fn fields_or_axis(&self) -> Vec<[f64; 2]> {
        if self.fields.is_empty() {
            vec![[0.0, 0.0]]
        } else {
            self.fields.clone()
        }
    }

    /// A field point given at the boundary — an object height in mm (`unit` "mm") or field angles in
    /// degrees (`unit` "deg") — as this system's object-space field point, or an error saying which unit the
    /// system takes: mm for a finite object, degrees for an object at infinity (`option` names the input).
    pub fn field_point(&self, value: [f64; 2], unit: FieldUnit, option: &str) -> Result<[f64; 2]> {
        match (unit, self.object_at_infinity()) {
            (FieldUnit::Mm, false) => Ok(value),
            (FieldUnit::Deg, true) => {
                if !(value[0].is_finite() && value[1].is_finite() && value[0].abs() < 90.0 && value[1].abs() < 90.0) {
                    return Err(Error::invalid(format!("{option} ({}, {}): field angles must be finite and within (-90, 90) degrees", value[0], value[1])));
                }
                Ok([value[0].to_radians(), value[1].to_radians()])
            }
            // The other unit's input, spelled as `option` is (`--field-mm` → `--field-deg`, Python's `fields_mm` →
            // `fields_deg`): Python's `chief_rays` was told to give `--field-deg` (round 15).
            (FieldUnit::Mm, true) => Err(Error::invalid(format!(
                "{option} ({}, {}): system `{}` has its object at infinity, where a field is an angle: give field angles in degrees ({} X,Y)",
                value[0],
                value[1],
                self.name(),
                option.replace("mm", "deg")
            ))),
            (FieldUnit::Deg, false) => Err(Error::invalid(format!(
                "{option} ({}, {}): system `{}` has a finite object, where a field is an object height: give it in mm ({} X,Y)",
                value[0],
                value[1],
                self.name(),
                option.replace("deg", "mm")
            ))),
        }
    }

    /// A field point as shown at the boundary: (value, unit) — mm for a finite object, degrees at infinity.
    /// Degrees are rounded to 1e-12°, so that an angle typed in degrees shows as typed (3° went to radians and
    /// back as 3.0000000000000004; round 15).
    pub fn field_display(&self, field: [f64; 2]) -> ([f64; 2], &'static str) {
        if self.object_at_infinity() {
            let deg = |r: f64| (r.to_degrees() * 1e12).round() / 1e12;
            ([deg(field[0]), deg(field[1])], "deg")
        } else {
            (field, "mm")
        }
    }

    pub fn primary_wavelength_nm(&self) -> f64 {
        self.spec.primary_wavelength_nm
    }

    /// Number of ray–surface intersections per traced ray (refracting surfaces + image).
    pub fn surfaces_per_ray(&self) -> usize {
        self.path.len()
    }

    /// Surface indices of the sequential path's steps, in order (what a ray meets until it stops).
    pub fn path_surfaces(&self) -> Vec<usize> {
        self.path.iter().map(|p| p.surface).collect()
    }
}

