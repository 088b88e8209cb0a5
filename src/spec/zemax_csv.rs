//! Import of Zemax Lens Data Editor transcriptions (`*.prescription.csv` in `shared/reference/zemax`).
//!
//! Columns: `surf,type,comment,radius,thickness,material,semi_diameter,conic,par1..par5`. A value may carry
//! Zemax's solve flag after it: `V` variable, `P` pickup, `C` chief-ray solve, `U` user semi-diameter.
//! `(aper)` in the type or comment marks a surface with a clipping aperture (its semi-diameter).
//! A transcription does not say where a pickup reads from; callers pass [`PickupSource`]s, and a `P` cell
//! with no source becomes [`Driver::UnknownPickup`]: traced at its shown value, but a fit or a design that
//! frees a cell of its column is refused (the pickup would not follow its source) — the import never
//! invents a source. (The presets, [`crate::presets`], keep such cells fixed at their shown value, as
//! documented there: `SystemData::keep_unsourced_pickups`.)
use super::{Cell, Driver, Pickup, RayAiming, SurfaceKind, SurfaceSpec, SystemAperture, SystemSpec};
use crate::error::{Error, Result};
use crate::materials::WavelengthPolicy;
use crate::surfaces::Aperture;

/// System data that the LDE screenshots do not show.
#[derive(Clone, Debug)]
pub struct SystemData {
    pub name: String,
    pub aperture: SystemAperture,
    pub ray_aiming: RayAiming,
    pub wavelengths_nm: Vec<f64>,
    pub primary_wavelength_nm: f64,
    pub fields_mm: Vec<[f64; 2]>,
    pub pickups: Vec<PickupSource>,
    /// What a `P` cell with no source in `pickups` becomes: [`Driver::UnknownPickup`] (a user's file), or a
    /// fixed cell at its shown value (`true`: the presets, whose sources were identified from the values
    /// shown and whose other `P` cells are documented to keep their value; [`crate::presets`]).
    pub keep_unsourced_pickups: bool,
}

/// Where the pickup of (surface, column) reads from.
#[derive(Clone, Debug)]
pub struct PickupSource {
    pub surface: usize,
    pub column: &'static str,
    pub from_surface: usize,
    pub scale: f64,
}

impl SystemData {
    /// The reference paper's system data: object-space NA 0.05, fields F1..F4, 450/520/650 nm, primary 520 nm.
    pub fn paper_defaults() -> Self {
        SystemData {
            name: "imported".into(),
            aperture: SystemAperture::ObjectSpaceNa(0.05),
            ray_aiming: RayAiming::Off,
            wavelengths_nm: vec![450.0, 520.0, 650.0],
            primary_wavelength_nm: 520.0,
            fields_mm: vec![[0.0, 0.0], [2.5, 0.0], [0.0, 2.5], [2.5, 2.5]],
            pickups: Vec::new(),
            keep_unsourced_pickups: false,
        }
    }
}

/// The columns of a transcription (`surf`, `type`, `radius`, `thickness`, `material`, `semi_diameter` required).
const COLUMNS: [&str; 13] = ["surf", "type", "comment", "radius", "thickness", "material", "semi_diameter", "conic", "par1", "par2", "par3", "par4", "par5"];

/// A value with its Zemax flag.
struct Flagged {
    value: f64,
    flag: Option<char>,
}

fn parse_flagged(text: &str, at: &dyn Fn(&str) -> Error) -> Result<Option<Flagged>> {
    let t = text.trim();
    if t.is_empty() {
        return Ok(None);
    }
    // "4.941 (mech 12.000 U)" → main value 4.941; the mechanical semi-diameter is informative only.
    let main = t.split('(').next().unwrap_or("").trim();
    let mut parts = main.split_whitespace();
    let num = parts.next().unwrap_or("");
    let value = if num.eq_ignore_ascii_case("inf") || num.eq_ignore_ascii_case("infinity") {
        f64::INFINITY
    } else {
        num.parse::<f64>().map_err(|_| at(&format!("`{t}` is not a number")))?
    };
    if value.is_nan() {
        return Err(at(&format!("`{t}` is NaN")));
    }
    let flag = match parts.next() {
        None => None,
        Some(f) if f.len() == 1 && "VPCU".contains(f) => f.chars().next(),
        Some(f) => return Err(at(&format!("unknown solve flag `{f}` (expected V, P, C or U)"))),
    };
    Ok(Some(Flagged { value, flag }))
}

/// Parse a prescription transcription into a [`SystemSpec`].
///
/// Strict: every row has exactly the header's number of fields (a truncated or shortened row is an error,
/// never a cell silently read as empty), the first surface row is the `OBJECT`, the last one the `IMAGE`
/// and no other row claims either role; a UTF-8 byte-order mark before the header is skipped.
pub fn import_prescription(text: &str, source_name: &str, data: &SystemData) -> Result<SystemSpec> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut header: Option<Vec<String>> = None;
    let mut surfaces: Vec<SurfaceSpec> = Vec::new();
    // (line number, role) of every surface row: OBJECT/IMAGE must be the first/last rows.
    let mut roles: Vec<(usize, Option<&'static str>)> = Vec::new();
    for (lineno, raw) in text.lines().enumerate() {
        let line_no = lineno + 1;
        let line = raw.trim_end_matches('\r');
        if line.trim().is_empty() || line.trim_start().starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = line.split(',').collect();
        let Some(cols) = &header else {
            let names: Vec<String> = fields.iter().map(|s| s.trim().to_string()).collect();
            for needed in ["surf", "type", "radius", "thickness", "material", "semi_diameter"] {
                if !names.iter().any(|c| c == needed) {
                    return Err(Error::spec(source_name, format!("line {line_no}: header lacks column `{needed}`")));
                }
            }
            // A column the reader does not know would be dropped (a Coordinate Break's order flag in `par6`,
            // an asphere's r¹² term): refused, naming it (a held-out battery, round 7).
            for (k, c) in names.iter().enumerate() {
                if !COLUMNS.contains(&c.as_str()) {
                    return Err(Error::spec(source_name, format!("line {line_no}: unknown column `{c}` (a prescription CSV has {}; a Coordinate Break's order flag and terms beyond par5 are not read: give such a system as a .zmx or a TOML spec)", COLUMNS.join(","))));
                }
                if names[..k].contains(c) {
                    return Err(Error::spec(source_name, format!("line {line_no}: column `{c}` given twice")));
                }
            }
            header = Some(names);
            continue;
        };
        if fields.len() != cols.len() {
            return Err(Error::spec(
                source_name,
                format!("line {line_no}: {} fields but the header has {} (a truncated or malformed row; every row needs all columns, empty ones as `,,`)", fields.len(), cols.len()),
            ));
        }
        let get = |name: &str| -> &str {
            cols.iter().position(|c| c == name).and_then(|i| fields.get(i)).map(|s| s.trim()).unwrap_or("")
        };
        let at = |field: &str| {
            let field = field.to_string();
            move |msg: &str| Error::spec(source_name, format!("line {line_no}, column `{field}`: {msg}"))
        };
        let surf: usize = get("surf").parse().map_err(|_| at("surf")(&format!("`{}` is not a surface number", get("surf"))))?;
        if surf != surfaces.len() {
            return Err(at("surf")(&format!("surface {surf} out of order (expected {})", surfaces.len())));
        }
        // The surface count as the rows are gathered (a row is read line by line, a surface kept ~4 kB).
        crate::limits::check_surface_count(surfaces.len() + 1).map_err(|m| Error::spec(source_name, format!("line {line_no}: {m}")))?;
        let type_text = get("type");
        let upper = type_text.to_ascii_uppercase();
        let is_stop = upper.starts_with("STOP ");
        roles.push((line_no, if upper.starts_with("OBJECT ") { Some("OBJECT") } else if upper.starts_with("IMAGE ") { Some("IMAGE") } else { None }));
        let bare = upper.trim_start_matches("OBJECT ").trim_start_matches("STOP ").trim_start_matches("IMAGE ").trim();
        let kind = match bare {
            "STANDARD" => SurfaceKind::Standard,
            "EVEN ASPHERE" | "EVENASPH" => SurfaceKind::EvenAsphere,
            "PARAXIAL" => SurfaceKind::Paraxial,
            "COORDINATE BREAK" | "COORDBRK" => SurfaceKind::CoordinateBreak,
            _ => return Err(at("type")(&format!("unknown surface type `{type_text}` (Standard, Even Asphere, Paraxial, Coordinate Break)"))),
        };
        let mut s = SurfaceSpec::new(kind);
        s.stop = is_stop;
        let comment = get("comment");
        let has_aper = comment.contains("(aper)") || type_text.contains("(aper)");
        s.comment = comment.replace("(aper)", "").trim().to_string();

        let cell_of = |f: &Flagged, column: &'static str| -> Cell {
            let driver = match f.flag {
                Some('C') => Driver::ChiefRay,
                Some('P') => data
                    .pickups
                    .iter()
                    .find(|p| p.surface == surf && p.column == column)
                    .map(|p| Driver::Pickup(Pickup { surface: p.from_surface, scale: p.scale, offset: 0.0, column: None }))
                    .unwrap_or(if data.keep_unsourced_pickups { Driver::Fixed } else { Driver::UnknownPickup }),
                _ => Driver::Fixed,
            };
            Cell { value: f.value, variable: f.flag == Some('V'), driver }
        };
        let flagged = |name: &'static str| parse_flagged(get(name), &at(name));

        if let Some(r) = flagged("radius")? {
            if r.value.is_finite() {
                s.radius_mm = Some(cell_of(&r, "radius_mm"));
            }
        }
        if let Some(t) = flagged("thickness")? {
            s.thickness_mm = cell_of(&t, "thickness_mm");
        }
        let material = get("material");
        if !material.is_empty() && material != "-" {
            s.material = Some(material.to_string());
        }
        if let Some(sd) = flagged("semi_diameter")? {
            if kind != SurfaceKind::CoordinateBreak {
                s.semi_diameter_mm = Some(sd.value);
                if has_aper {
                    s.aperture = Some(Aperture::circular(sd.value));
                }
            }
        }
        if kind != SurfaceKind::CoordinateBreak && kind != SurfaceKind::Paraxial {
            if let Some(k) = flagged("conic")? {
                if k.value != 0.0 || k.flag.is_some() {
                    s.conic = Some(cell_of(&k, "conic"));
                }
            }
        }
        let par = |i: usize| -> Result<Option<Flagged>> {
            let name = format!("par{i}");
            parse_flagged(get(&name), &at(&name))
        };
        // A cell the surface type does not have would be dropped: refused unless empty or 0 (the screenshots
        // leave them blank). A Paraxial's par2 (OPD mode) changes no ray and is read as nothing.
        let unused: &[&str] = match kind {
            SurfaceKind::CoordinateBreak => &["radius", "conic"],
            SurfaceKind::Paraxial => &["radius", "conic", "par3", "par4", "par5"],
            SurfaceKind::Standard => &["par1", "par2", "par3", "par4", "par5"],
            SurfaceKind::EvenAsphere | SurfaceKind::Toroidal | SurfaceKind::DiffractionGrating => &[],
        };
        for &name in unused {
            if let Some(f) = parse_flagged(get(name), &at(name))? {
                if f.value != 0.0 || f.flag.is_some() {
                    return Err(at(name)(&format!("`{}`: a {} surface has no such cell (it would be ignored); leave it empty", get(name), kind.label())));
                }
            }
        }
        match kind {
            SurfaceKind::Paraxial => {
                let f = par(1)?.ok_or_else(|| at("par1")("a Paraxial surface needs its focal length in par1"))?;
                s.focal_length_mm = Some(cell_of(&f, "focal_length_mm"));
            }
            SurfaceKind::CoordinateBreak => {
                const NAMES: [&str; 5] = ["decenter_x_mm", "decenter_y_mm", "tilt_x_deg", "tilt_y_deg", "tilt_z_deg"];
                for (i, name) in NAMES.iter().enumerate() {
                    let v = par(i + 1)?.map(|f| cell_of(&f, name)).unwrap_or_default();
                    *match i {
                        0 => &mut s.decenter_x_mm,
                        1 => &mut s.decenter_y_mm,
                        2 => &mut s.tilt_x_deg,
                        3 => &mut s.tilt_y_deg,
                        _ => &mut s.tilt_z_deg,
                    } = Some(v);
                }
            }
            SurfaceKind::EvenAsphere => {
                // par k is the r^(2k) coefficient: an empty cell before a given one is 0, never a shift of
                // the later terms to lower powers (a held-out battery, round 7).
                let pars = (1..=5).map(par).collect::<Result<Vec<_>>>()?;
                let given = pars.iter().rposition(Option::is_some).map_or(0, |k| k + 1);
                for a in &pars[..given] {
                    s.asphere_coefficients.push(match a {
                        Some(a) => Cell { value: a.value, variable: a.flag == Some('V'), driver: Driver::Fixed },
                        None => Cell::fixed(0.0),
                    });
                }
            }
            SurfaceKind::Standard | SurfaceKind::Toroidal | SurfaceKind::DiffractionGrating => {}
        }
        surfaces.push(s);
    }
    if header.is_none() {
        return Err(Error::spec(source_name, "no header row: not a prescription CSV"));
    }
    if surfaces.is_empty() {
        return Err(Error::spec(source_name, "empty system: no surface rows"));
    }
    let last = roles.len() - 1;
    for (k, &(line_no, role)) in roles.iter().enumerate() {
        let want = if k == 0 { Some("OBJECT") } else if k == last { Some("IMAGE") } else { None };
        if role != want {
            let msg = match (want, role) {
                (Some(w), _) => format!("line {line_no}: surface {k} must be the {w} surface (type `{w} ...`); the file {}", if w == "IMAGE" { "lacks its IMAGE row or is truncated" } else { "lacks its OBJECT row" }),
                (None, Some(r)) => format!("line {line_no}: surface {k} is marked {r} but only the {} row may be", if r == "OBJECT" { "first" } else { "last" }),
                (None, None) => continue,
            };
            return Err(Error::spec(source_name, msg));
        }
    }
    let spec = SystemSpec {
        name: data.name.clone(),
        description: format!("imported from {source_name}"),
        aperture: data.aperture,
        ray_aiming: data.ray_aiming,
        wavelengths_nm: data.wavelengths_nm.clone(),
        primary_wavelength_nm: data.primary_wavelength_nm,
        fields_mm: data.fields_mm.clone(),
        field_type: Default::default(),
        fields_deg: Vec::new(),
        vignetting_factors: Vec::new(),
        wavelength_policy: WavelengthPolicy::Strict,
        air_index: 1.0,
        glass_catalogs: Vec::new(),
        surfaces,
        mechanics: None,
    };
    spec.validate().map_err(|m| Error::spec(source_name, m))?;
    Ok(spec)
}
