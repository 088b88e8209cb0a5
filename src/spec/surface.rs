use super::Cell;
use crate::surfaces::Aperture;
use serde::{Deserialize, Serialize};

/// The "Surface Type" column.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SurfaceKind {
    /// Plane, sphere or conic (radius + conic).
    Standard,
    /// Conic plus even polynomial terms α₁r² … α₈r¹⁶.
    EvenAsphere,
    /// Ideal thin lens of focal length `focal_length_mm`.
    Paraxial,
    /// Coordinate Break: decenter x/y, tilt x/y/z, order; keeps the medium before it.
    CoordinateBreak,
    /// OpticStudio's Toroidal: a curve in the YZ plane (radius, conic, even terms α₁y² … α₈y¹⁶) rotated about
    /// an axis parallel to y at the distance `rotation_radius_mm` (absent: a cylinder). `src/surfaces/toroidal.rs`.
    Toroidal,
    /// OpticStudio's Diffraction Grating: a Standard surface (radius, conic) ruled with lines parallel to the
    /// local x axis, `grating_lines_per_um`, traced in `grating_order`. `src/surfaces/grating.rs`.
    DiffractionGrating,
}

impl SurfaceKind {
    pub fn label(self) -> &'static str {
        match self {
            SurfaceKind::Standard => "Standard",
            SurfaceKind::EvenAsphere => "Even Asphere",
            SurfaceKind::Paraxial => "Paraxial",
            SurfaceKind::CoordinateBreak => "Coordinate Break",
            SurfaceKind::Toroidal => "Toroidal",
            SurfaceKind::DiffractionGrating => "Diffraction Grating",
        }
    }
}

/// One row of the Lens Data Editor. Lengths in mm, angles in degrees.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SurfaceSpec {
    #[serde(rename = "type")]
    pub kind: SurfaceKind,
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub comment: String,
    /// This surface is the aperture stop.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub stop: bool,
    /// Radius of curvature (mm); absent means infinity (flat).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radius_mm: Option<Cell>,
    /// Distance to the next surface along the local z after this surface (after a break's own transform).
    #[serde(default)]
    pub thickness_mm: Cell,
    /// Glass name after this surface; absent means air; `MIRROR` (any case) makes the surface a reflector
    /// (OpticStudio's `GLAS MIRROR`: the medium after it is the medium before it). Not allowed on Coordinate Breaks.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub material: Option<String>,
    /// Informative semi-diameter (does not clip; see `aperture`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub semi_diameter_mm: Option<f64>,
    /// A clipping aperture ("(aper)" in the LDE).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub aperture: Option<Aperture>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub conic: Option<Cell>,
    /// Even asphere α₁..α₈ (coefficient of r², r⁴, …), mm^(1−2i).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub asphere_coefficients: Vec<Cell>,
    /// Paraxial surface focal length (mm).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub focal_length_mm: Option<Cell>,
    /// Toroidal: radius of rotation (mm, the X radius); absent = infinite (a cylinder).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rotation_radius_mm: Option<Cell>,
    /// Diffraction Grating: lines per µm (along the local y axis; the lines are parallel to x).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub grating_lines_per_um: Option<Cell>,
    /// Diffraction Grating: the diffraction order traced (an integer).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub grating_order: Option<Cell>,
    /// Diffraction Grating: the scalar efficiency of the traced order, in [0, 1] (absent: 1). It scales the
    /// power a ray carries (rendering), never its path.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub grating_efficiency: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub decenter_x_mm: Option<Cell>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub decenter_y_mm: Option<Cell>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tilt_x_deg: Option<Cell>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tilt_y_deg: Option<Cell>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tilt_z_deg: Option<Cell>,
    /// Coordinate Break order flag: 0 = decenter then tilt X, Y, Z; 1 = tilt Z, Y, X then decenter.
    #[serde(default, skip_serializing_if = "is_zero_u8")]
    pub order: u8,
    /// Optional coating, used by the non-sequential ghost analysis only (`ghosts`; the sequential trace
    /// and the renderer's ghost-free operator ignore it). Absent: a bare surface (Fresnel).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub coating: Option<Coating>,
    /// A coded mask on this surface (dual-disperser CASSI; `super::coded_mask`): rays crossing it are weighted
    /// by the render's mask there. At most one per system, on a flat Standard surface in air.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub coded_mask: Option<super::CodedMaskSpec>,
}

/// A surface coating (see `src/tracer/nonseq/coating.rs` for the physics).
/// TOML: `coating = { reflectance = 0.005 }` or `coating = { mgf2_quarter_wave_nm = 550.0 }`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum Coating {
    /// A given power reflectance in [0, 1] for both polarisations, every angle and wavelength.
    Reflectance(f64),
    /// One quarter-wave MgF₂ anti-reflection layer designed for this wavelength (nm) at normal incidence.
    Mgf2QuarterWaveNm(f64),
}

impl Coating {
    /// Errors name the field and the value.
    pub fn validate(&self) -> Result<(), String> {
        match *self {
            Coating::Reflectance(r) if !(0.0..=1.0).contains(&r) => Err(format!("reflectance {r}: must be in [0, 1]")),
            Coating::Mgf2QuarterWaveNm(w) if !(w.is_finite() && (200.0..=7000.0).contains(&w)) => {
                Err(format!("mgf2_quarter_wave_nm {w}: must be in [200, 7000] nm (the range of the MgF₂ dispersion formula)"))
            }
            _ => Ok(()),
        }
    }
}

fn is_zero_u8(v: &u8) -> bool {
    *v == 0
}

/// The numeric columns a pickup may name.
pub const COLUMNS: &[&str] = &[
    "radius_mm",
    "thickness_mm",
    "conic",
    "focal_length_mm",
    "decenter_x_mm",
    "decenter_y_mm",
    "tilt_x_deg",
    "tilt_y_deg",
    "tilt_z_deg",
    "asphere_1",
    "asphere_2",
    "asphere_3",
    "asphere_4",
    "asphere_5",
    "asphere_6",
    "asphere_7",
    "asphere_8",
    "rotation_radius_mm",
    "grating_lines_per_um",
    "grating_order",
];

/// The columns after the asphere terms in [`COLUMNS`] (Toroidal and Diffraction Grating parameters).
const EXTRA_COLUMNS: [&str; 3] = ["rotation_radius_mm", "grating_lines_per_um", "grating_order"];

impl SurfaceSpec {
    /// A bare surface of the given kind with every optional column empty.
    pub fn new(kind: SurfaceKind) -> Self {
        SurfaceSpec {
            kind,
            comment: String::new(),
            stop: false,
            radius_mm: None,
            thickness_mm: Cell::fixed(0.0),
            material: None,
            semi_diameter_mm: None,
            aperture: None,
            conic: None,
            asphere_coefficients: Vec::new(),
            focal_length_mm: None,
            rotation_radius_mm: None,
            grating_lines_per_um: None,
            grating_order: None,
            grating_efficiency: None,
            decenter_x_mm: None,
            decenter_y_mm: None,
            tilt_x_deg: None,
            tilt_y_deg: None,
            tilt_z_deg: None,
            order: 0,
            coating: None,
            coded_mask: None,
        }
    }

    pub fn standard(radius_mm: Option<f64>, thickness_mm: f64, material: Option<&str>) -> Self {
        let mut s = SurfaceSpec::new(SurfaceKind::Standard);
        s.radius_mm = radius_mm.map(Cell::fixed);
        s.thickness_mm = Cell::fixed(thickness_mm);
        s.material = material.map(str::to_string);
        s
    }

    pub fn paraxial(focal_length_mm: f64, thickness_mm: f64) -> Self {
        let mut s = SurfaceSpec::new(SurfaceKind::Paraxial);
        s.focal_length_mm = Some(Cell::fixed(focal_length_mm));
        s.thickness_mm = Cell::fixed(thickness_mm);
        s
    }

    /// A Coordinate Break (lengths mm, angles degrees), order 0.
    pub fn coordinate_break(decenter_x_mm: f64, decenter_y_mm: f64, tilt_x_deg: f64, tilt_y_deg: f64, tilt_z_deg: f64, thickness_mm: f64) -> Self {
        let mut s = SurfaceSpec::new(SurfaceKind::CoordinateBreak);
        s.decenter_x_mm = Some(Cell::fixed(decenter_x_mm));
        s.decenter_y_mm = Some(Cell::fixed(decenter_y_mm));
        s.tilt_x_deg = Some(Cell::fixed(tilt_x_deg));
        s.tilt_y_deg = Some(Cell::fixed(tilt_y_deg));
        s.tilt_z_deg = Some(Cell::fixed(tilt_z_deg));
        s.thickness_mm = Cell::fixed(thickness_mm);
        s
    }

    /// The cell of a named column (see [`COLUMNS`]), if present.
    pub fn cell(&self, column: &str) -> Option<&Cell> {
        match column {
            "radius_mm" => self.radius_mm.as_ref(),
            "thickness_mm" => Some(&self.thickness_mm),
            "conic" => self.conic.as_ref(),
            "focal_length_mm" => self.focal_length_mm.as_ref(),
            "decenter_x_mm" => self.decenter_x_mm.as_ref(),
            "decenter_y_mm" => self.decenter_y_mm.as_ref(),
            "tilt_x_deg" => self.tilt_x_deg.as_ref(),
            "tilt_y_deg" => self.tilt_y_deg.as_ref(),
            "tilt_z_deg" => self.tilt_z_deg.as_ref(),
            "rotation_radius_mm" => self.rotation_radius_mm.as_ref(),
            "grating_lines_per_um" => self.grating_lines_per_um.as_ref(),
            "grating_order" => self.grating_order.as_ref(),
            c if c.starts_with("asphere_") => {
                c[8..].parse::<usize>().ok().filter(|i| *i >= 1).and_then(|i| self.asphere_coefficients.get(i - 1))
            }
            _ => None,
        }
    }

    /// Mutable access to a named column's cell, if present.
    pub fn cell_mut(&mut self, column: &str) -> Option<&mut Cell> {
        match column {
            "radius_mm" => self.radius_mm.as_mut(),
            "thickness_mm" => Some(&mut self.thickness_mm),
            "conic" => self.conic.as_mut(),
            "focal_length_mm" => self.focal_length_mm.as_mut(),
            "decenter_x_mm" => self.decenter_x_mm.as_mut(),
            "decenter_y_mm" => self.decenter_y_mm.as_mut(),
            "tilt_x_deg" => self.tilt_x_deg.as_mut(),
            "tilt_y_deg" => self.tilt_y_deg.as_mut(),
            "tilt_z_deg" => self.tilt_z_deg.as_mut(),
            "rotation_radius_mm" => self.rotation_radius_mm.as_mut(),
            "grating_lines_per_um" => self.grating_lines_per_um.as_mut(),
            "grating_order" => self.grating_order.as_mut(),
            c if c.starts_with("asphere_") => match c[8..].parse::<usize>() {
                Ok(i) if i >= 1 => self.asphere_coefficients.get_mut(i - 1),
                _ => None,
            },
            _ => None,
        }
    }

    /// The columns present on this surface, in LDE order.
    pub fn present_columns(&self) -> Vec<String> {
        let mut cols: Vec<String> = COLUMNS[..9].iter().filter(|c| self.cell(c).is_some()).map(|c| c.to_string()).collect();
        cols.extend(EXTRA_COLUMNS.iter().filter(|c| self.cell(c).is_some()).map(|c| c.to_string()));
        cols.extend((1..=self.asphere_coefficients.len()).map(|i| format!("asphere_{i}")));
        cols
    }

    /// The column's cell, added at its default when the surface type takes it with one but the spec left it out:
    /// a Coordinate Break's decentres and tilts (0) and a conic (0) — the values an absent cell is traced at, so
    /// adding it changes nothing. `None` for a column the type does not take, or one without a default (the
    /// radius, the grating's, a Paraxial focal length).
    pub fn cell_or_default(&mut self, column: &str) -> Option<&mut Cell> {
        let slot = match (self.kind, column) {
            (SurfaceKind::CoordinateBreak, "decenter_x_mm") => &mut self.decenter_x_mm,
            (SurfaceKind::CoordinateBreak, "decenter_y_mm") => &mut self.decenter_y_mm,
            (SurfaceKind::CoordinateBreak, "tilt_x_deg") => &mut self.tilt_x_deg,
            (SurfaceKind::CoordinateBreak, "tilt_y_deg") => &mut self.tilt_y_deg,
            (SurfaceKind::CoordinateBreak, "tilt_z_deg") => &mut self.tilt_z_deg,
            (SurfaceKind::Standard | SurfaceKind::EvenAsphere | SurfaceKind::Toroidal | SurfaceKind::DiffractionGrating, "conic") => &mut self.conic,
            _ => return self.cell_mut(column),
        };
        Some(slot.get_or_insert_with(|| Cell::fixed(0.0)))
    }

    /// Columns that are meaningful for this surface type (others are a spec error).
    pub fn allowed_columns(&self) -> &'static [&'static str] {
        match self.kind {
            SurfaceKind::Standard => &["radius_mm", "thickness_mm", "conic"],
            SurfaceKind::EvenAsphere => &["radius_mm", "thickness_mm", "conic"],
            SurfaceKind::Paraxial => &["thickness_mm", "focal_length_mm"],
            SurfaceKind::CoordinateBreak => {
                &["thickness_mm", "decenter_x_mm", "decenter_y_mm", "tilt_x_deg", "tilt_y_deg", "tilt_z_deg"]
            }
            SurfaceKind::Toroidal => &["radius_mm", "thickness_mm", "conic", "rotation_radius_mm"],
            SurfaceKind::DiffractionGrating => &["radius_mm", "thickness_mm", "conic", "grating_lines_per_um", "grating_order"],
        }
    }

    /// Whether this surface reflects (`material = "MIRROR"`, OpticStudio's `GLAS MIRROR`).
    pub fn is_mirror(&self) -> bool {
        self.material.as_deref().map(is_mirror_material).unwrap_or(false)
    }
}

/// Whether a material name is OpticStudio's `MIRROR` (any case).
pub fn is_mirror_material(name: &str) -> bool {
    name.eq_ignore_ascii_case("MIRROR")
}

impl SurfaceSpec {
    /// A Toroidal surface (lengths mm): the YZ curve's radius (None = flat in y), the radius of rotation
    /// (None = a cylinder).
    pub fn toroidal(radius_mm: Option<f64>, rotation_radius_mm: Option<f64>, thickness_mm: f64, material: Option<&str>) -> Self {
        let mut s = SurfaceSpec::standard(radius_mm, thickness_mm, material);
        s.kind = SurfaceKind::Toroidal;
        s.rotation_radius_mm = rotation_radius_mm.map(Cell::fixed);
        s
    }

    /// A Diffraction Grating on a Standard substrate (radius None = a plane).
    pub fn grating(radius_mm: Option<f64>, lines_per_um: f64, order: i32, thickness_mm: f64, material: Option<&str>) -> Self {
        let mut s = SurfaceSpec::standard(radius_mm, thickness_mm, material);
        s.kind = SurfaceKind::DiffractionGrating;
        s.grating_lines_per_um = Some(Cell::fixed(lines_per_um));
        s.grating_order = Some(Cell::fixed(order as f64));
        s
    }
}
