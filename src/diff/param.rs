//! Free parameters: which numbers of a system a derivative (or an optimiser) may move.
//!
//! | kind | text form | unit |
//! |---|---|---|
//! | any numeric cell of the Lens Data Editor (thickness, radius, conic, asphere αᵢ, paraxial focal length, Coordinate Break decenters and tilts) | `s4.tilt_x_deg`, `s16.radius_mm`, `s2.focal_length_mm`, `s16.asphere_2` | the column's (mm, degrees) |
//! | surface curvature c = 1/R (also of a flat surface) | `s16.curvature` | mm⁻¹ |
//! | glass as a continuous (n_d, V_d) model ([`super::glass_model`]) | `glass_nd:N-SK2`, `glass_vd:N-SK2` | — |
//! | the rays' wavelength | `wavelength` | nm |
//! | the input ray (object frame) | `ray.origin_x` … `ray.dir_z` | mm, direction components |
//!
//! A glass parameter applies to every surface made of that glass (the double Amici's two outer prisms
//! share one glass); freeing a catalogue glass replaces it by its Cauchy model with the catalogue's
//! n_d, V_d. Pickup and chief-ray-solve cells cannot be free (free their source instead); their
//! derivatives follow from their drivers ([`super::DiffSystem`]).
//!
//! ```
//! use diffcassi::diff::{Param, ParamSet};
//! use diffcassi::materials::GlassCatalog;
//! let spec = diffcassi::presets::spec("sp")?;
//! let set = ParamSet::new(spec, GlassCatalog::builtin(), vec![Param::parse("s4.tilt_x_deg")?, Param::parse("glass_nd:N-BK7")?])?;
//! assert_eq!(set.values()?, vec![0.0, 1.5168]);
//! let moved = set.with_values(&[5.0, 1.52])?;
//! assert_eq!(moved.spec.surfaces[4].tilt_x_deg.as_ref().unwrap().value, 5.0);
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::glass_model::CauchyGlass;
use crate::error::{Error, Result};
use crate::materials::GlassCatalog;
use crate::spec::{Cell, Driver, SurfaceKind, SystemSpec};
use crate::system::SequentialSystem;
use std::collections::BTreeMap;

/// One free parameter.
#[derive(Clone, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize, serde::Deserialize)]
pub enum Param {
    /// A numeric cell: `surface`, column name (see [`crate::spec::COLUMNS`]).
    Cell { surface: usize, column: String },
    /// Curvature 1/R of a surface (mm⁻¹).
    Curvature { surface: usize },
    /// n_d of a glass (Cauchy model), by glass name (upper case).
    GlassNd(String),
    /// V_d of a glass (Cauchy model).
    GlassVd(String),
    /// The wavelength of every ray (nm).
    Wavelength,
    /// Input ray origin component 0..3 (mm).
    RayOrigin(usize),
    /// Input ray direction component 0..3 (before normalisation).
    RayDirection(usize),
}

impl Param {
    /// Parse the text form (see the module table).
    pub fn parse(text: &str) -> Result<Param> {
        let t = text.trim();
        let bad = |why: &str| {
            Error::invalid(format!(
                "free parameter `{text}`: {why} (forms: s<N>.<column> e.g. s4.tilt_x_deg, s<N>.curvature, glass_nd:<GLASS>, glass_vd:<GLASS>, wavelength, ray.origin_x|y|z, ray.dir_x|y|z)"
            ))
        };
        if t == "wavelength" {
            return Ok(Param::Wavelength);
        }
        if let Some(g) = t.strip_prefix("glass_nd:") {
            return if g.trim().is_empty() { Err(bad("no glass name")) } else { Ok(Param::GlassNd(g.trim().to_ascii_uppercase())) };
        }
        if let Some(g) = t.strip_prefix("glass_vd:") {
            return if g.trim().is_empty() { Err(bad("no glass name")) } else { Ok(Param::GlassVd(g.trim().to_ascii_uppercase())) };
        }
        if let Some(r) = t.strip_prefix("ray.") {
            let axis = |s: &str| match s {
                "x" => Ok(0),
                "y" => Ok(1),
                "z" => Ok(2),
                _ => Err(bad("ray axis must be x, y or z")),
            };
            if let Some(a) = r.strip_prefix("origin_") {
                return Ok(Param::RayOrigin(axis(a)?));
            }
            if let Some(a) = r.strip_prefix("dir_") {
                return Ok(Param::RayDirection(axis(a)?));
            }
            return Err(bad("unknown ray parameter"));
        }
        if let Some(rest) = t.strip_prefix('s') {
            let (num, col) = rest.split_once('.').ok_or_else(|| bad("missing `.column`"))?;
            let surface: usize = num.parse().map_err(|_| bad("surface number is not a whole number"))?;
            if col == "curvature" {
                return Ok(Param::Curvature { surface });
            }
            if !crate::spec::COLUMNS.contains(&col) {
                return Err(bad(&format!("unknown column `{col}`")));
            }
            return Ok(Param::Cell { surface, column: col.to_string() });
        }
        Err(bad("unrecognised"))
    }

    /// The text form.
    pub fn name(&self) -> String {
        match self {
            Param::Cell { surface, column } => format!("s{surface}.{column}"),
            Param::Curvature { surface } => format!("s{surface}.curvature"),
            Param::GlassNd(g) => format!("glass_nd:{g}"),
            Param::GlassVd(g) => format!("glass_vd:{g}"),
            Param::Wavelength => "wavelength".into(),
            Param::RayOrigin(a) => format!("ray.origin_{}", ["x", "y", "z"][*a]),
            Param::RayDirection(a) => format!("ray.dir_{}", ["x", "y", "z"][*a]),
        }
    }

    /// Per-ray parameters (wavelength, input ray) are not part of the system: they have no system value.
    pub fn is_ray_parameter(&self) -> bool {
        matches!(self, Param::Wavelength | Param::RayOrigin(_) | Param::RayDirection(_))
    }
}

impl std::fmt::Display for Param {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.name())
    }
}

/// A system spec, its glass catalogue, the free parameters and the model glasses they use.
#[derive(Clone, Debug)]
pub struct ParamSet {
    pub spec: SystemSpec,
    pub catalog: GlassCatalog,
    pub free: Vec<Param>,
    /// Glasses replaced by their (n_d, V_d) Cauchy model, by upper-case name.
    pub models: BTreeMap<String, CauchyGlass>,
}

impl ParamSet {
    /// Check the parameters against the spec and turn free glasses into Cauchy models. Errors name the
    /// parameter: unknown surface or column, a pickup or solve cell, a duplicate, a glass no surface uses.
    pub fn new(spec: SystemSpec, catalog: GlassCatalog, free: Vec<Param>) -> Result<Self> {
        let mut set = ParamSet { spec, catalog, free: Vec::new(), models: BTreeMap::new() };
        for p in free {
            set.add(p)?;
        }
        Ok(set)
    }

    /// Add one free parameter (see [`ParamSet::new`]).
    pub fn add(&mut self, p: Param) -> Result<()> {
        let bad = |why: String| Error::invalid(format!("free parameter `{p}`: {why}"));
        if self.free.contains(&p) {
            return Err(bad("given twice".into()));
        }
        let n = self.spec.surfaces.len();
        // A pickup whose source the file does not say would not follow a freed parameter that is its source
        // (a prescription CSV's `P` cells): the fit would run on a system that is not the file's. A pickup
        // reads its own column unless it says otherwise, so a freed cell of a column such a pickup has is
        // refused (freeing s4.tilt_x_deg of a transcribed SP, whose s14.tilt_x_deg follows it in OpticStudio,
        // recovered 0.0018° of a 5° tilt).
        let column = match &p {
            Param::Cell { column, .. } => Some(column.as_str()),
            Param::Curvature { .. } => Some("radius_mm"),
            _ => None,
        };
        if let Some(column) = column {
            let unknown: Vec<String> = self.spec.unknown_pickups().into_iter().filter(|c| c.ends_with(&format!(" {column}"))).collect();
            if !unknown.is_empty() {
                return Err(bad(format!(
                    "system `{}` has pickups of this column whose source its file does not say ({}): they would not follow the freed cell if it is their source; give their sources (export-spec to TOML, then `{{ value = …, pickup = {{ surface = S, scale = … }} }}` in place of `unknown_pickup = true`)",
                    self.spec.name,
                    unknown.join(", ")
                )));
            }
        }
        match &p {
            Param::Cell { surface, column } => {
                let s = self.spec.surfaces.get_mut(*surface).ok_or_else(|| bad(format!("no surface {surface} (the system has {n})")))?;
                let figure_column = matches!(column.as_str(), "radius_mm" | "conic" | "rotation_radius_mm") || column.starts_with("asphere_");
                if s.coded_mask.is_some() && figure_column {
                    // Accepted at its flat start, every step away refused later (a held-out battery, round 10).
                    return Err(bad(format!("`{column}` of the coded-mask surface: the mask is a flat Standard surface, its figure is not a free parameter (its placement is)")));
                }
                // A cell the spec left out at its default (a Coordinate Break's tilt_y_deg, a conic) is freed from
                // that default, 0; it was refused as "has no `tilt_y_deg` cell" (a held-out battery, round 10).
                let (label, allowed) = (s.kind.label(), s.allowed_columns());
                let cell = s.cell_or_default(column).ok_or_else(|| {
                    let terms = column.strip_prefix("asphere_").filter(|_| label == SurfaceKind::EvenAsphere.label());
                    if let Some(k) = terms {
                        bad(format!("surface {surface} ({label}) has fewer than {k} asphere terms: give `asphere_coefficients` {k} entries (0 for the terms it lacks) to free it"))
                    } else if allowed.contains(&column.as_str()) {
                        bad(format!("surface {surface} ({label}) has no `{column}` cell in its spec: give it one (e.g. `{column} = …`) to free it"))
                    } else {
                        bad(format!("a {label} surface has no `{column}` column (it takes {})", allowed.join(", ")))
                    }
                })?;
                let cell = cell.clone();
                let s = &self.spec.surfaces[*surface];
                match cell.driver {
                    Driver::Fixed => {}
                    Driver::Pickup(ref pk) => return Err(bad(format!("the cell is a pickup from surface {}: free its source instead", pk.surface))),
                    Driver::ChiefRay => return Err(bad("the cell is a chief-ray solve: it is determined by the system".into())),
                    // Refused above: its own column holds an unknown pickup (`unknown_pickups`).
                    Driver::UnknownPickup => {}
                }
                if s.kind == SurfaceKind::Toroidal && figure_column {
                    return Err(bad(format!("`{column}` of a Toroidal surface: the derivatives of its figure are not implemented (its placement and the rays through it are)")));
                }
                if matches!(column.as_str(), "grating_lines_per_um" | "grating_order") {
                    return Err(bad(format!("`{column}`: the grating's line density and order are not free parameters (the substrate, its placement and the wavelength are)")));
                }
                if column == "radius_mm" && self.free.contains(&Param::Curvature { surface: *surface }) {
                    return Err(bad("the surface's curvature is already free".into()));
                }
            }
            Param::Curvature { surface } => {
                let s = self.spec.surfaces.get(*surface).ok_or_else(|| bad(format!("no surface {surface} (the system has {n})")))?;
                if !matches!(s.kind, SurfaceKind::Standard | SurfaceKind::EvenAsphere | SurfaceKind::DiffractionGrating) {
                    return Err(bad(format!("a {} surface has no curvature", s.kind.label())));
                }
                if s.coded_mask.is_some() {
                    return Err(bad("the coded-mask surface is flat: its curvature is not a free parameter (its placement is)".into()));
                }
                if let Some(c) = &s.radius_mm {
                    if c.driver != Driver::Fixed {
                        return Err(bad("the radius is a pickup: free its source instead".into()));
                    }
                }
                if self.free.contains(&Param::Cell { surface: *surface, column: "radius_mm".into() }) {
                    return Err(bad("the surface's radius is already free".into()));
                }
            }
            Param::GlassNd(g) | Param::GlassVd(g) => {
                let used = self.spec.surfaces.iter().any(|s| s.material.as_deref().map(|m| m.eq_ignore_ascii_case(g)).unwrap_or(false));
                if !used {
                    return Err(bad(format!("no surface is made of {g}")));
                }
                if !self.models.contains_key(g) {
                    let glass = self.catalog.get(g).map_err(|e| bad(e.to_string()))?;
                    let model = CauchyGlass::new(glass.nd, glass.vd);
                    self.models.insert(g.clone(), model);
                    self.catalog.insert(model.to_glass(g));
                }
            }
            Param::Wavelength | Param::RayOrigin(_) | Param::RayDirection(_) => {}
        }
        self.free.push(p);
        Ok(())
    }

    pub fn len(&self) -> usize {
        self.free.len()
    }
    pub fn is_empty(&self) -> bool {
        self.free.is_empty()
    }
    pub fn names(&self) -> Vec<String> {
        self.free.iter().map(|p| p.name()).collect()
    }

    /// The current value of a system parameter (`None` for per-ray parameters).
    pub fn value(&self, p: &Param) -> Option<f64> {
        match p {
            Param::Cell { surface, column } => self.spec.surfaces[*surface].cell(column).map(|c| c.value),
            Param::Curvature { surface } => Some(self.spec.surfaces[*surface].radius_mm.as_ref().map(|r| 1.0 / r.value).unwrap_or(0.0)),
            Param::GlassNd(g) => self.models.get(g).map(|m| m.nd),
            Param::GlassVd(g) => self.models.get(g).map(|m| m.vd),
            _ => None,
        }
    }

    /// Values of the free parameters. Errors if one is a per-ray parameter (it has no system value).
    pub fn values(&self) -> Result<Vec<f64>> {
        self.free
            .iter()
            .map(|p| self.value(p).ok_or_else(|| Error::invalid(format!("free parameter `{p}` is per ray, not a system value"))))
            .collect()
    }

    /// Set one system parameter.
    pub fn set(&mut self, p: &Param, v: f64) -> Result<()> {
        if !v.is_finite() {
            return Err(Error::invalid(format!("free parameter `{p}`: value {v} is not finite")));
        }
        match p {
            Param::Cell { surface, column } => {
                let cell = self.spec.surfaces[*surface].cell_mut(column).expect("checked in ParamSet::add");
                cell.value = v;
            }
            Param::Curvature { surface } => {
                self.spec.surfaces[*surface].radius_mm = if v == 0.0 { None } else { Some(Cell::fixed(1.0 / v)) };
            }
            Param::GlassNd(g) | Param::GlassVd(g) => {
                let m = self.models.get_mut(g).expect("checked in ParamSet::add");
                if matches!(p, Param::GlassNd(_)) {
                    if v <= 1.0 {
                        return Err(Error::invalid(format!("free parameter `{p}`: n_d = {v} must be > 1")));
                    }
                    m.nd = v;
                } else {
                    if v <= 0.0 {
                        return Err(Error::invalid(format!("free parameter `{p}`: V_d = {v} must be > 0")));
                    }
                    m.vd = v;
                }
                let model = *m;
                self.catalog.insert(model.to_glass(g));
            }
            _ => return Err(Error::invalid(format!("free parameter `{p}` is per ray, not a system value"))),
        }
        Ok(())
    }

    /// A copy with the free parameters set to `x` (same order as [`ParamSet::free`]).
    pub fn with_values(&self, x: &[f64]) -> Result<ParamSet> {
        if x.len() != self.free.len() {
            return Err(Error::invalid(format!("{} values for {} free parameters", x.len(), self.free.len())));
        }
        let mut s = self.clone();
        for (p, v) in self.free.iter().zip(x) {
            s.set(p, *v)?;
        }
        Ok(s)
    }

    /// The plain traceable system.
    pub fn system(&self) -> Result<SequentialSystem> {
        SequentialSystem::build_with_catalog(&self.spec, &self.catalog)
    }

    /// The system with its derivatives ([`super::DiffSystem`]).
    pub fn build(&self) -> Result<super::DiffSystem> {
        super::DiffSystem::new(self)
    }
}

/// The free parameters named in the comma-separated `list` for a system called `system_name`: the names
/// `diffcassi calibrate --free` takes, plus the preset aliases ([`preset_alias`]) on the presets. Used by
/// every binding (C++, Python) that takes parameters by name.
///
/// ```
/// let ps = diffcassi::diff::param::parse_parameter_list("sp", "prism_tilt_x, wavelength")?;
/// assert_eq!(ps.len(), 2);
/// assert!(diffcassi::diff::param::parse_parameter_list("sp", " , ").is_err());
/// # Ok::<(), diffcassi::Error>(())
/// ```
pub fn parse_parameter_list(system_name: &str, list: &str) -> Result<Vec<Param>> {
    let names: Vec<&str> = list.split(',').map(str::trim).collect();
    if names.iter().all(|n| n.is_empty()) {
        return Err(Error::invalid("Jacobian requested with no free parameters"));
    }
    names
        .iter()
        .map(|n| {
            if n.is_empty() {
                return Err(Error::invalid(format!("free parameters `{list}`: an empty name")));
            }
            match preset_alias(system_name, n) {
                Some(p) => Ok(p),
                None => Param::parse(n),
            }
        })
        .collect()
}

impl ParamSet {
    /// The parameter set of the comma-separated `list` ([`parse_parameter_list`]) on a built system: its
    /// spec, with the built-in glasses plus the spec's catalogues, as [`SequentialSystem::build`] loads them.
    pub fn for_system(system: &SequentialSystem, list: &str) -> Result<ParamSet> {
        let params = parse_parameter_list(system.name(), list)?;
        // The build's own assembly (`builtin:NAME` entries included: read as file paths here, they failed
        // "cannot read glass catalogue builtin:OHARA"; round 18).
        let catalog = SequentialSystem::catalog_of(&system.spec)?;
        ParamSet::new(system.spec.clone(), catalog, params)
    }
}

/// Named parameters of the reference systems (`prism_tilt_x|y|z`: the Coordinate Break that carries the
/// prism's 5° misalignment in mSP/mAP, or the break where that tilt would go in SP/AP).
///
/// SP and mSP: surface 4 (its x and z tilts are undone by the pickups of surface 14). AP: the stop break,
/// surface 3 (R = Rx·Ry(α_c)·Rz, the same rotation as mAP's surfaces 4 then 5). mAP: surface 4.
///
/// The alias is not the same quantity in AP and mAP: AP's surface 3 is the stop break that holds α_c (its y
/// tilt, picked up by surface 14) and whose x and z tilts nothing undoes, so they tilt everything after it;
/// mAP's surface 4 holds the 5° misalignment alone, undone by a fixed −5° x break at surface 19. A
/// value fitted on one is no truth for the other, and `calibrate` reads truths only from an observed system
/// that numbers its surfaces as the model does (a held-out battery, round 16).
pub fn preset_alias(preset: &str, name: &str) -> Option<Param> {
    let axis = match name {
        "prism_tilt_x" => "tilt_x_deg",
        "prism_tilt_y" => "tilt_y_deg",
        "prism_tilt_z" => "tilt_z_deg",
        _ => return None,
    };
    let surface = match preset.to_ascii_lowercase().as_str() {
        "sp" | "msp" | "map" => 4,
        "ap" => 3,
        _ => return None,
    };
    Some(Param::Cell { surface, column: axis.to_string() })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parse_round_trips_and_rejects() {
        for t in ["s4.tilt_x_deg", "s16.curvature", "glass_nd:N-SK2", "glass_vd:N-SF10", "wavelength", "ray.origin_y", "ray.dir_z", "s2.asphere_3"] {
            assert_eq!(Param::parse(t).unwrap().name(), t);
        }
        for t in ["", "s.tilt", "s4.bogus", "glass_nd:", "ray.dir_w", "tilt"] {
            assert!(Param::parse(t).is_err(), "{t}");
        }
    }

    #[test]
    fn pickups_and_solves_cannot_be_free() {
        let spec = crate::presets::spec("sp").unwrap();
        let e = ParamSet::new(spec.clone(), GlassCatalog::builtin(), vec![Param::parse("s14.tilt_x_deg").unwrap()]).unwrap_err();
        assert!(e.to_string().contains("pickup"), "{e}");
        let e = ParamSet::new(spec.clone(), GlassCatalog::builtin(), vec![Param::parse("s15.tilt_y_deg").unwrap()]).unwrap_err();
        assert!(e.to_string().contains("chief-ray"), "{e}");
        let e = ParamSet::new(spec, GlassCatalog::builtin(), vec![Param::parse("glass_nd:N-SF10").unwrap()]).unwrap_err();
        assert!(e.to_string().contains("no surface"), "{e}");
    }
}
