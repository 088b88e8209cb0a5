use super::{Cell, SurfaceKind, SurfaceSpec};
use crate::materials::WavelengthPolicy;
use serde::{Deserialize, Serialize};

/// The system aperture (Zemax "System Explorer → Aperture").
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", content = "value", rename_all = "snake_case")]
pub enum SystemAperture {
    /// n·sin θ of the marginal ray in object space (finite objects only).
    ObjectSpaceNa(f64),
    /// Entrance pupil diameter (mm).
    EntrancePupilDiameter(f64),
    /// Image-space F/# (Zemax `FNUM`): the paraxial effective focal length (infinite conjugates, primary
    /// wavelength) over the entrance pupil diameter, so the pupil diameter is |EFL| / F#.
    ImageSpaceFNumber(f64),
    /// Float by stop size (Zemax `FLOA`): the stop surface's semi-diameter is the paraxial stop radius.
    FloatByStopSize,
}

/// What the field values of a spec are (Zemax "System Explorer → Fields → Type", `FTYP`).
///
/// At the boundary the values are mm (`fields_mm`: object or image heights) or degrees (`fields_deg`:
/// angles); inside, a built system holds every field as an object-space field point
/// ([`crate::system::SequentialSystem::fields`]): an object height in mm for a finite object, the angles
/// (θx, θy) in radians for an object at infinity.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FieldType {
    /// Object heights (x, y), mm (`FTYP 1`); finite objects only.
    #[default]
    ObjectHeight,
    /// Field angles (θx, θy), degrees (`FTYP 0`): the chief ray's direction in object space is
    /// (tan θx, tan θy, 1) normalised (OpticStudio's definition), through the paraxial entrance pupil centre.
    Angle,
    /// Paraxial image heights (x, y), mm (`FTYP 2`): the object field whose paraxial chief ray lands there.
    ParaxialImageHeight,
    /// Real image heights (x, y), mm (`FTYP 3`): the object field whose real chief ray (primary wavelength)
    /// lands there on the image surface.
    RealImageHeight,
}

impl FieldType {
    pub fn is_object_height(&self) -> bool {
        *self == FieldType::ObjectHeight
    }
    /// The `.zmx` `FTYP` number.
    pub fn zmx_code(&self) -> i64 {
        match self {
            FieldType::Angle => 0,
            FieldType::ObjectHeight => 1,
            FieldType::ParaxialImageHeight => 2,
            FieldType::RealImageHeight => 3,
        }
    }
    pub fn label(&self) -> &'static str {
        match self {
            FieldType::Angle => "angle",
            FieldType::ObjectHeight => "object height",
            FieldType::ParaxialImageHeight => "paraxial image height",
            FieldType::RealImageHeight => "real image height",
        }
    }
}

/// How rays are aimed at the pupil (OpticStudio's "Ray Aiming": Off, Paraxial, Real).
///
/// With aiming on, every ray is aimed so that it crosses the real stop surface at (px, py) × a stop radius;
/// the two modes differ only in that radius, "computed by tracing a marginal ray from the center of the
/// object to the stop surface at the primary wavelength", paraxially or as a real ray (OpticStudio User
/// Guide, "Ray Aiming"). Under float by stop size both use the stop's semi-diameter.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RayAiming {
    /// Normalised pupil coordinates are positions on the paraxial entrance pupil (Zemax default).
    #[default]
    Off,
    /// Rays cross the stop surface at (px, py) × the paraxial stop radius (`RAIM 0 1`).
    Paraxial,
    /// Rays cross the stop surface at (px, py) × the real stop radius: the radial height at the stop of the
    /// real marginal ray, from the axial object point through the paraxial entrance pupil's edge at the
    /// primary wavelength (`RAIM 0 2`; [`crate::rays::real_stop_radius`]).
    Real,
}

/// A whole sequential system: system data + the surface table. Surface 0 is the object, the last the image.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SystemSpec {
    pub name: String,
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub description: String,
    pub aperture: SystemAperture,
    #[serde(default)]
    pub ray_aiming: RayAiming,
    /// System wavelengths (nm).
    pub wavelengths_nm: Vec<f64>,
    /// Primary wavelength (nm): chief-ray solves and paraxial data use it.
    pub primary_wavelength_nm: f64,
    /// Field points (x, y), mm: object heights, or image heights when `field_type` says so (empty for angles).
    #[serde(default)]
    pub fields_mm: Vec<[f64; 2]>,
    /// What the field values are (default: object heights in `fields_mm`).
    #[serde(default, skip_serializing_if = "FieldType::is_object_height")]
    pub field_type: FieldType,
    /// Field angles (θx, θy), degrees, when `field_type` is `angle` (empty otherwise).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub fields_deg: Vec<[f64; 2]>,
    /// OpticStudio's vignetting factors of each field, `[VDX, VDY, VCX, VCY]` (normalised pupil units; empty:
    /// none). The pupil point (px, py) of a defined field is traced at (VDX + px(1 − VCX), VDY + py(1 − VCY))
    /// by the analyses that sample a field's pupil (`trace`, `spot`): see [`crate::system::VignettingFactors`].
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub vignetting_factors: Vec<[f64; 4]>,
    /// Whether wavelengths outside a glass's catalogue range are an error (default) or extrapolated.
    #[serde(default)]
    pub wavelength_policy: WavelengthPolicy,
    /// Refractive index given to `Air` (default 1: catalogue indices are relative to air and system air is
    /// the reference, as in Zemax at its default 20 °C / 1 atm). The reference paper's tracer uses 1.000293
    /// with the same (relative) glass data; its YAML imports set that value to reproduce it.
    #[serde(default = "default_air_index", skip_serializing_if = "is_default_air_index")]
    pub air_index: f64,
    /// Extra AGF catalogues to load (paths relative to the spec file); the built-in glasses are always there.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub glass_catalogs: Vec<String>,
    /// At most [`crate::limits::MAX_SURFACES`], refused as they are read (a JSON spec is read straight into
    /// this list: 4·10⁵ surfaces held 0.4 GB before any check could count them; round 19).
    #[serde(deserialize_with = "bounded_surfaces")]
    pub surfaces: Vec<SurfaceSpec>,
    /// Mounts, housings and user meshes for non-sequential tracing (optional; see [`MechanicsSpec`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mechanics: Option<super::MechanicsSpec>,
}

fn default_air_index() -> f64 {
    1.0
}
fn is_default_air_index(v: &f64) -> bool {
    *v == 1.0
}

impl SystemSpec {
    /// The cells that are pickups of unknown source ([`super::Driver::UnknownPickup`], a prescription
    /// CSV's `P` cell), as `surface S column`: a fit or design may free no cell of their columns.
    pub fn unknown_pickups(&self) -> Vec<String> {
        let mut out = Vec::new();
        for (i, s) in self.surfaces.iter().enumerate() {
            for col in s.present_columns() {
                if s.cell(&col).is_some_and(|c| c.driver == super::Driver::UnknownPickup) {
                    out.push(format!("surface {i} {col}"));
                }
            }
        }
        out
    }

    /// Why surface `i` cannot carry a coating, or `None` when it can: coatings act on the Fresnel reflection
    /// of a refracting interface, which the object surface, the image surface (the detector only absorbs),
    /// a Coordinate Break (no surface), a paraxial lens (an ideal, lossless thin lens) and a mirror (a perfect
    /// reflector in the non-sequential backends: reflectivity 1, nothing transmitted) do not have.
    pub fn not_an_interface(&self, i: usize) -> Option<&'static str> {
        if i == 0 {
            Some("the object surface")
        } else if i + 1 == self.surfaces.len() {
            Some("the image surface (the detector)")
        } else {
            match self.surfaces.get(i).map(|s| s.kind) {
                // A perfect reflector (reflectivity 1, nothing transmitted): there is no Fresnel split to weight.
                Some(kind) if kind != SurfaceKind::CoordinateBreak && self.surfaces[i].is_mirror() => Some("a mirror (a perfect reflector)"),
                Some(SurfaceKind::CoordinateBreak) => Some("a Coordinate Break"),
                Some(SurfaceKind::Paraxial) => Some("a paraxial (ideal thin) lens"),
                _ => None,
            }
        }
    }

    /// The medium the rays travel in before surface `i` (its material name; `None` for air): the material of
    /// the nearest surface before it that is neither a Coordinate Break nor a mirror (both keep the medium).
    pub fn medium_before(&self, i: usize) -> Option<&str> {
        self.surfaces[..i]
            .iter()
            .rev()
            .find(|s| s.kind != SurfaceKind::CoordinateBreak && !s.is_mirror())
            .and_then(|s| s.material.as_deref())
            .filter(|m| !m.eq_ignore_ascii_case("air"))
    }

    /// Whether the object is at infinity (object thickness +∞, Zemax `DISZ INFINITY` on surface 0).
    pub fn object_at_infinity(&self) -> bool {
        self.surfaces.first().is_some_and(|s| s.thickness_mm.value == f64::INFINITY)
    }

    /// The thickness (mm) the traces use after surface `i` — the frames and the paraxial (y–nu) trace alike —,
    /// given the zero of its type and its cell's value (`cell`, evaluated only when used): an object at
    /// infinity is traced from the plane of surface 1's vertex (the object frame's z = 0, where the parallel
    /// rays start), so surface 0's thickness is 0 there, not the infinite distance the spec holds (which has no
    /// derivative to carry); every other thickness is its cell's. Generic so that the build (f64) and the
    /// derivatives (duals) read the one rule.
    pub fn traced_thickness<T>(&self, i: usize, zero: T, cell: impl FnOnce() -> T) -> T {
        if i == 0 && self.object_at_infinity() {
            zero
        } else {
            cell()
        }
    }

    /// The field values as given, in the unit of `field_type` (mm or degrees).
    pub fn field_values(&self) -> &[[f64; 2]] {
        if self.field_type == FieldType::Angle {
            &self.fields_deg
        } else {
            &self.fields_mm
        }
    }

    /// Index of the stop surface: the one flagged `stop`, else surface 1 (Zemax's default).
    pub fn stop_index(&self) -> usize {
        self.surfaces.iter().position(|s| s.stop).unwrap_or(1)
    }

    /// Basic structural and numeric checks; `Err` carries "surface N field: message".
    pub fn validate(&self) -> Result<(), String> {
        if let Some(m) = &self.mechanics {
            m.validate()?;
        }
        // The surface count first: every reader's spec and every build passes here (round 19: 4·10⁵ surfaces of
        // a TOML spec took 1.2 GB under `--max-memory-gb 0.1`).
        crate::limits::check_surface_count(self.surfaces.len())?;
        if self.surfaces.len() < 3 {
            return Err(format!(
                "a system needs at least an object, one surface and an image surface (found {} surfaces)",
                self.surfaces.len()
            ));
        }
        if self.wavelengths_nm.is_empty() {
            return Err("wavelengths_nm: empty list".into());
        }
        for (i, w) in self.wavelengths_nm.iter().enumerate() {
            if !(w.is_finite() && *w > 0.0) {
                return Err(format!("wavelengths_nm[{i}] = {w}: must be finite and > 0"));
            }
        }
        if !(self.air_index.is_finite() && self.air_index >= 1.0 && self.air_index < 1.1) {
            return Err(format!("air_index = {}: must be in [1, 1.1)", self.air_index));
        }
        if !(self.primary_wavelength_nm.is_finite() && self.primary_wavelength_nm > 0.0) {
            return Err(format!("primary_wavelength_nm = {}: must be finite and > 0", self.primary_wavelength_nm));
        }
        for (i, f) in self.fields_mm.iter().enumerate() {
            if !(f[0].is_finite() && f[1].is_finite()) {
                return Err(format!("fields_mm[{i}] = {:?}: not finite", f));
            }
            // The range of the command line's --field-mm (a height of 1e300 mm was taken, and an image height
            // converted to a 90° field).
            if let Some(v) = f.iter().find(|v| v.abs() > crate::limits::MAX_LENGTH_MM) {
                return Err(format!(
                    "fields_mm[{i}] = ({}, {}): {} mm is outside ±{:e} mm (the range of --field-mm)",
                    crate::limits::fmt_num(f[0]),
                    crate::limits::fmt_num(f[1]),
                    crate::limits::fmt_num(*v),
                    crate::limits::MAX_LENGTH_MM
                ));
            }
        }
        for (i, f) in self.fields_deg.iter().enumerate() {
            if !(f[0].is_finite() && f[1].is_finite() && f[0].abs() < 90.0 && f[1].abs() < 90.0) {
                return Err(format!("fields_deg[{i}] = {:?}: field angles must be finite and within (-90, 90) degrees", f));
            }
        }
        let nf = self.field_values().len();
        if !self.vignetting_factors.is_empty() && self.vignetting_factors.len() != nf {
            return Err(format!("vignetting_factors: {} row(s) for {nf} field(s): give one [VDX, VDY, VCX, VCY] per field, or none", self.vignetting_factors.len()));
        }
        for (i, v) in self.vignetting_factors.iter().enumerate() {
            if let Some(k) = v.iter().position(|x| !x.is_finite()) {
                return Err(format!("vignetting_factors[{i}] = {v:?}: {} is not finite", ["VDX", "VDY", "VCX", "VCY"][k]));
            }
            if let Some(k) = (2..4).find(|&k| v[k] >= 1.0) {
                return Err(format!(
                    "vignetting_factors[{i}] = {v:?}: {} = {} ≥ 1 compresses the pupil to nothing (or flips it); compression factors are < 1",
                    ["VDX", "VDY", "VCX", "VCY"][k],
                    v[k]
                ));
            }
        }
        let infinite = self.object_at_infinity();
        // Rays from an object at infinity start on surface 1's vertex plane: an aperture on surface 0 would be
        // kept, shown and without effect.
        if infinite && self.surfaces.first().is_some_and(|s| s.aperture.is_some()) {
            return Err("surfaces[0].aperture: the object (surface 0) is at infinity, where no ray meets it, so an aperture there has no effect: remove it or put it on a surface the rays cross".into());
        }
        match self.field_type {
            FieldType::Angle if !self.fields_mm.is_empty() => {
                return Err(format!("field_type angle takes its values from fields_deg, but fields_mm holds {} point(s): move them to fields_deg (degrees)", self.fields_mm.len()))
            }
            FieldType::ObjectHeight | FieldType::ParaxialImageHeight | FieldType::RealImageHeight if !self.fields_deg.is_empty() => {
                return Err(format!("fields_deg is given but field_type is {} (mm in fields_mm): set field_type = \"angle\"", self.field_type.label()))
            }
            FieldType::ObjectHeight if infinite && self.fields_mm.iter().any(|f| *f != [0.0, 0.0]) => {
                return Err("fields_mm: object heights are meaningless for an object at infinity (surface 0 thickness_mm = infinity): give field angles (field_type = \"angle\", fields_deg) or image heights".into())
            }
            _ => {}
        }
        match self.aperture {
            SystemAperture::ObjectSpaceNa(_) if infinite => {
                return Err("aperture object_space_na: an object at infinity has no object-space NA; use entrance_pupil_diameter, image_space_f_number or float_by_stop_size".into())
            }
            SystemAperture::ImageSpaceFNumber(f) if !(f.is_finite() && f > 0.0) => return Err(format!("aperture image_space_f_number = {}: must be finite and > 0", crate::limits::fmt_num(f))),
            SystemAperture::FloatByStopSize => {
                let stop = self.stop_index();
                match self.surfaces.get(stop).and_then(|s| s.semi_diameter_mm) {
                    Some(sd) if sd.is_finite() && sd > 0.0 => {}
                    other => {
                        return Err(format!(
                            "aperture float_by_stop_size: the stop (surface {stop}) needs a semi_diameter_mm > 0, its size (found {})",
                            other.map(|v| v.to_string()).unwrap_or_else(|| "none".into())
                        ))
                    }
                }
            }
            _ => {}
        }
        match self.aperture {
            SystemAperture::ObjectSpaceNa(na) if !(na.is_finite() && na > 0.0 && na < 1.0) => {
                return Err(format!("aperture object_space_na = {na}: must be in (0, 1)"))
            }
            SystemAperture::EntrancePupilDiameter(d) if !(d.is_finite() && d >= crate::limits::MIN_PUPIL_DIAMETER_MM && d <= crate::limits::MAX_LENGTH_MM) => {
                return Err(format!(
                    "aperture entrance_pupil_diameter = {} mm: must be finite, in [{}, {}] mm",
                    crate::limits::fmt_num(d),
                    crate::limits::fmt_num(crate::limits::MIN_PUPIL_DIAMETER_MM),
                    crate::limits::fmt_num(crate::limits::MAX_LENGTH_MM)
                ))
            }
            _ => {}
        }
        let stops: Vec<String> = self.surfaces.iter().enumerate().filter(|(_, s)| s.stop).map(|(i, _)| i.to_string()).collect();
        if stops.len() > 1 {
            // Named (the count alone left the user to find them; a held-out battery, round 10).
            return Err(format!("surfaces {} are flagged stop; exactly one may be", stops.join(", ")));
        }
        let last = self.surfaces.len() - 1;
        let stop = self.stop_index();
        if stop == 0 || stop == last {
            return Err(format!("surface {stop}: the object or image surface cannot be the stop"));
        }
        for (i, s) in self.surfaces.iter().enumerate() {
            let at = |field: &str, msg: String| format!("surface {i} ({}) {field}: {msg}", s.kind.label());
            if (i == 0 || i == last) && s.kind == SurfaceKind::CoordinateBreak {
                return Err(at("type", "the object and image surfaces cannot be Coordinate Breaks".into()));
            }
            // A material on the image sets the medium its traced direction is given in: the medium before it
            // (no refraction: an immersed detector) is the one use. A different one, refracting at the image,
            // is what a file cut short between two surfaces reads as (a lens's face became the image).
            if i == last && i > 0 && !s.is_mirror() {
                if let Some(m) = s.material.as_deref().filter(|m| !m.eq_ignore_ascii_case("air")) {
                    let before = self.medium_before(i);
                    if !before.is_some_and(|b| b.eq_ignore_ascii_case(m)) {
                        return Err(at(
                            "material",
                            format!(
                                "{m:?}: the image surface (the last) would refract from {} into {m}; an image takes no material, or the medium before it (an immersed detector). A file cut short between two surfaces reads this way: restore the missing surfaces, or remove the material",
                                before.unwrap_or("air")
                            ),
                        ));
                    }
                }
            }
            if s.kind == SurfaceKind::CoordinateBreak && s.material.is_some() {
                return Err(at("material", format!("{:?}: a Coordinate Break keeps the previous medium", s.material)));
            }
            if s.kind == SurfaceKind::CoordinateBreak && s.order > 1 {
                return Err(at("order", format!("{}: must be 0 or 1", s.order)));
            }
            if i == 0 && s.thickness_mm.value == f64::NEG_INFINITY {
                return Err(at("thickness_mm", "-infinity: an object at infinity is +infinity".into()));
            }
            // Field points start on the flat plane at the object's vertex: a curved object surface (a finite
            // object) would be shown and not traced (a held-out battery, round 7; rayoptics ignores it too).
            if i == 0 && !infinite {
                if let Some(r) = s.radius_mm.as_ref().map(|c| c.value).filter(|r| r.is_finite() && *r != 0.0) {
                    return Err(at("radius_mm", format!("{}: a curved object surface is not modelled (field points start on the flat object plane); make the object flat (radius infinity)", crate::limits::fmt_num(r))));
                }
                if s.asphere_coefficients.iter().any(|c| c.value != 0.0) {
                    return Err(at("asphere_coefficients", "an aspheric object surface is not modelled (field points start on the flat object plane)".into()));
                }
            }
            if i == 0 && infinite && s.thickness_mm.driver != super::Driver::Fixed {
                return Err(at("thickness_mm", "an infinite object distance must be a fixed value (no pickup or solve)".into()));
            }
            if let Some(sd) = s.semi_diameter_mm {
                // A length as the others (docs/robustness.md's limits): 1e300 loaded and `embree-user` then failed
                // on infinite bounds naming no surface (a held-out battery, round 17).
                if !(sd.is_finite() && sd >= 0.0 && sd <= crate::limits::MAX_LENGTH_MM) {
                    return Err(at("semi_diameter_mm", format!("{}: must be finite, >= 0 and <= {:e} mm (1 km)", crate::limits::fmt_num(sd), crate::limits::MAX_LENGTH_MM)));
                }
            }
            if let Some(ap) = &s.aperture {
                ap.validate().map_err(|m| at("aperture", m))?;
            }
            if let Some(c) = &s.coating {
                c.validate().map_err(|m| at("coating", m))?;
                if let Some(what) = self.not_an_interface(i) {
                    return Err(at("coating", format!("surface {i} is {what}, not a refracting interface: a coating there would do nothing; remove it")));
                }
            }
            if let Some(m) = &s.coded_mask {
                m.validate().map_err(|e| at("coded_mask", e))?;
                if let Some(j) = self.surfaces[..i].iter().position(|t| t.coded_mask.is_some()) {
                    return Err(at("coded_mask", format!("surface {j} already holds the coded mask: a system has at most one coded-mask surface")));
                }
                if i == 0 || i == last {
                    return Err(at("coded_mask", "the object and image surfaces cannot hold the coded mask (a mask on the object plane is single-disperser CASSI: remove coded_mask)".into()));
                }
                // What makes the surface not a flat Standard one, named with its value.
                let curved = s.radius_mm.as_ref().filter(|r| r.value.is_finite() && r.value != 0.0).map(|r| format!("radius_mm = {}", r.value));
                let conic = s.conic.as_ref().filter(|c| c.value != 0.0).map(|c| format!("conic = {}", c.value));
                let kind = (s.kind != SurfaceKind::Standard).then(|| format!("a {} surface", s.kind.label()));
                if let Some(what) = kind.or(curved).or(conic) {
                    return Err(at(
                        "coded_mask",
                        format!("{what}: the coded mask must be a flat Standard surface (radius_mm 0 or absent for flat, no conic): a mask on a curved or other surface is not modelled"),
                    ));
                }
                if s.is_mirror() || s.material.as_deref().is_some_and(|m| !m.eq_ignore_ascii_case("air")) {
                    return Err(at("coded_mask", format!("material {:?}: the coded mask is a thin plate in air (no refraction at it)", s.material.as_deref().unwrap_or(""))));
                }
            }
            if s.asphere_coefficients.len() > crate::limits::MAX_ASPHERE_TERMS {
                return Err(at("asphere_coefficients", format!("{} terms: at most {} (r² … r¹⁶)", s.asphere_coefficients.len(), crate::limits::MAX_ASPHERE_TERMS)));
            }
            if !s.asphere_coefficients.is_empty() && !matches!(s.kind, SurfaceKind::EvenAsphere | SurfaceKind::Toroidal) {
                return Err(at("asphere_coefficients", "only allowed on even_asphere and toroidal surfaces".into()));
            }
            if s.is_mirror() {
                if i == 0 || i == last {
                    return Err(at("material", "MIRROR: the object and image surfaces cannot be mirrors".into()));
                }
                if s.kind == SurfaceKind::Paraxial {
                    return Err(at("material", "MIRROR on a Paraxial surface is not modelled (use a Standard mirror)".into()));
                }
            }
            if s.grating_efficiency.is_some() && s.kind != SurfaceKind::DiffractionGrating {
                return Err(at("grating_efficiency", "only allowed on diffraction_grating surfaces".into()));
            }
            let allowed = s.allowed_columns();
            for col in s.present_columns() {
                if !col.starts_with("asphere_") && !allowed.contains(&col.as_str()) {
                    return Err(at(&col, format!("not a column of a {} surface (allowed: {})", s.kind.label(), allowed.join(", "))));
                }
                let cell: &Cell = s.cell(&col).expect("present");
                if !cell.value.is_finite() && !(i == 0 && col == "thickness_mm" && cell.value == f64::INFINITY) {
                    return Err(at(&col, format!("{} is not finite", cell.value)));
                }
                if let super::Driver::Pickup(p) = &cell.driver {
                    if p.surface >= self.surfaces.len() {
                        return Err(at(&col, format!("pickup from surface {} which does not exist (system has {})", p.surface, self.surfaces.len())));
                    }
                    if p.surface == i && p.column.as_deref().unwrap_or(&col) == col {
                        return Err(at(&col, "pickup from itself".into()));
                    }
                    if !(p.scale.is_finite() && p.offset.is_finite()) {
                        return Err(at(&col, format!("pickup scale {} / offset {} not finite", p.scale, p.offset)));
                    }
                    let src_col = p.column.clone().unwrap_or(col.clone());
                    if !super::COLUMNS.contains(&src_col.as_str()) {
                        return Err(at(&col, format!("pickup column `{src_col}` unknown (columns: {})", super::COLUMNS.join(", "))));
                    }
                }
                if cell.driver == super::Driver::ChiefRay && s.kind != SurfaceKind::CoordinateBreak {
                    return Err(at(&col, "chief-ray solves exist only on Coordinate Break decenters and tilts".into()));
                }
                if cell.driver == super::Driver::ChiefRay && col == "thickness_mm" {
                    return Err(at(&col, "a chief-ray solve applies to decenters and tilts, not thickness".into()));
                }
            }
            match s.kind {
                SurfaceKind::Paraxial => match &s.focal_length_mm {
                    None => return Err(at("focal_length_mm", "missing".into())),
                    Some(c) if c.value == 0.0 => return Err(at("focal_length_mm", "0 is not a lens".into())),
                    _ => {}
                },
                SurfaceKind::Toroidal => {
                    if let Some(r) = &s.rotation_radius_mm {
                        if r.value == 0.0 {
                            return Err(at("rotation_radius_mm", "0: leave it out for a cylinder (an infinite radius of rotation)".into()));
                        }
                    }
                }
                SurfaceKind::DiffractionGrating => {
                    match &s.grating_lines_per_um {
                        None => return Err(at("grating_lines_per_um", "missing".into())),
                        Some(c) if !(c.value > 0.0 && c.value.is_finite()) => {
                            return Err(at("grating_lines_per_um", format!("{}: must be finite and > 0 lines per µm", c.value)))
                        }
                        _ => {}
                    }
                    match &s.grating_order {
                        None => return Err(at("grating_order", "missing".into())),
                        Some(c) if c.value.fract() != 0.0 || c.value.abs() > 1e6 => {
                            return Err(at("grating_order", format!("{}: a diffraction order is an integer of magnitude at most 10⁶", c.value)))
                        }
                        _ => {}
                    }
                    if let Some(e) = s.grating_efficiency {
                        if !(0.0..=1.0).contains(&e) {
                            return Err(at("grating_efficiency", format!("{e}: must be in [0, 1]")));
                        }
                    }
                }
                _ => {}
            }
            if let Some(r) = &s.radius_mm {
                if r.value == 0.0 {
                    return Err(at("radius_mm", "0: use no radius for a flat surface".into()));
                }
            }
        }
        Ok(())
    }
}

/// `surfaces` read one at a time, refused at the first beyond [`crate::limits::MAX_SURFACES`] (before the rest is
/// read and held).
fn bounded_surfaces<'de, D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Vec<SurfaceSpec>, D::Error> {
    struct Bounded;
    impl<'de> serde::de::Visitor<'de> for Bounded {
        type Value = Vec<SurfaceSpec>;
        fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            write!(f, "a list of at most {} surfaces", crate::limits::MAX_SURFACES)
        }
        fn visit_seq<A: serde::de::SeqAccess<'de>>(self, mut seq: A) -> std::result::Result<Self::Value, A::Error> {
            let mut out = Vec::new();
            while let Some(s) = seq.next_element::<SurfaceSpec>()? {
                out.push(s);
                crate::limits::check_surface_count(out.len()).map_err(serde::de::Error::custom)?;
            }
            Ok(out)
        }
    }
    d.deserialize_seq(Bounded)
}
