//! One surface of the Lens Data Editor in a `.zmx` file: the records between `SURF n` and the next `SURF`.
//!
//! `TYPE` (STANDARD, EVENASPH, PARAXIAL, COORDBRK, TOROIDAL, DGRATING), `CURV c` (mm⁻¹; the radius is 1/c, 0 = flat), `DISZ t`
//! (mm, `INFINITY` allowed), `CONI k`, `PARM i v` (Even Asphere: αᵢ of r²ⁱ; Paraxial: 1 = focal length,
//! 2 = OPD mode; Coordinate Break: 1–2 decenter x/y mm, 3–5 tilt x/y/z degrees, 6 order; Toroidal: 1 = radius
//! of rotation mm (0 = infinite, a cylinder), 2–9 = αᵢ of y²ⁱ (rayoptics' `zmxread` reads the same slots;
//! OpticStudio also writes `PARM 0 0` and `XDAT 1 0` / `XDAT 2 r`, "no Zernike terms" and their unused
//! normalisation radius, accepted; Zernike terms are refused); Diffraction Grating: 1 = lines per µm,
//! 2 = order), `GLAS name …` (`GLAS MIRROR`: a reflecting surface), `DCGE e` (diffcassi's own record: the
//! grating order's efficiency),
//! `STOP`, `DIAM sd …` (semi-diameter), `CLAP rmin rmax` / `SQAP hx hy` with `OBDC dx dy` (clipping
//! apertures), `OBSC rmin rmax` with `OBDC dx dy` (a circular obscuration: the annulus blocks), `COMM text`; `VCUR`, `VDSZ`, `VCON`, `VPAR i` mark cells variable. Pickups and chief-ray
//! solves are written by diffcassi as `DCPK column from_surface scale offset [source_column]` and
//! `DCCR column`, `DCVR column` marks a variable cell. OpticStudio's own solve and pickup records (`CURV c 4`,
//! `PZUP`, `PPAR`, `MAZH`, …) are read as the solved values the file holds, and listed.
//! `FLAP rmin rmax` (a floating aperture) is read as the circular aperture of those radii.
use super::lexer::Record;
use super::records::{finite, int, num, Unsupported, COSMETIC};
use crate::spec::{Cell, Driver, Pickup, SurfaceKind, SurfaceSpec, COLUMNS};
use crate::surfaces::Aperture;

/// Why an OpticStudio solve or pickup record is read as the value the file holds.
const FROZEN: &str = "OpticStudio solve/pickup: the value the file holds (solved when it was saved) is read; the solve is not re-run when a parameter changes";

/// The records of one surface, as read.
#[derive(Debug, Default)]
pub(super) struct SurfaceBlock {
    pub number: usize,
    pub line: usize,
    pub kind: Option<(usize, SurfaceKind)>,
    pub stop: bool,
    pub comment: String,
    /// `CURV c` (line, c).
    pub curv: Option<(usize, f64)>,
    pub disz: Option<(usize, f64)>,
    pub glass: Option<(usize, String)>,
    /// `GLAS MIRROR` (line).
    pub mirror: Option<usize>,
    /// `XDAT i v` (line, i, v): extra data; only a Toroidal's "no Zernike terms" is meaningful.
    pub xdat: Vec<(usize, i64, f64)>,
    /// `DCGE e`: the grating efficiency (line, value).
    pub efficiency: Option<(usize, f64)>,
    /// `CONI k` (line, k).
    pub coni: Option<(usize, f64)>,
    pub parm: Vec<(usize, usize, f64)>,
    pub diam: Option<f64>,
    pub clap: Option<(f64, f64)>,
    /// `FLAP rmin rmax …`: OpticStudio's floating aperture, a circular aperture whose radius is the
    /// semi-diameter the file holds (read as `CLAP` with those radii).
    pub flap: Option<(f64, f64)>,
    pub sqap: Option<(f64, f64)>,
    /// `OBSC rmin rmax`: a circular obscuration (line, rmin, rmax), checked when read.
    pub obsc: Option<(usize, f64, f64)>,
    pub obdc: (f64, f64),
    /// (line, keyword) of the aperture record (`CLAP`, `SQAP`, `OBSC`, `FLAP`), for messages.
    pub aperture_at: Option<(usize, String)>,
    /// (line, column, driver) for pickups / chief-ray solves; (column) for variables.
    pub drivers: Vec<(usize, String, Driver)>,
    pub variables: Vec<(usize, String)>,
    /// OpticStudio solves and pickups whose solved values the file holds (`CURV c 4 …`, `PZUP`, `PPAR`,
    /// `MAZH`, …): the values are read as they are and the records listed ([`super::ZmxImport::skipped`]).
    pub frozen: Vec<Unsupported>,
}

fn surface_kind(name: &str) -> Option<SurfaceKind> {
    match name {
        "STANDARD" => Some(SurfaceKind::Standard),
        "EVENASPH" => Some(SurfaceKind::EvenAsphere),
        "PARAXIAL" => Some(SurfaceKind::Paraxial),
        "COORDBRK" => Some(SurfaceKind::CoordinateBreak),
        "TOROIDAL" => Some(SurfaceKind::Toroidal),
        "DGRATING" => Some(SurfaceKind::DiffractionGrating),
        _ => None,
    }
}

/// The `.zmx` type name of a surface kind.
pub(super) fn type_name(kind: SurfaceKind) -> &'static str {
    match kind {
        SurfaceKind::Standard => "STANDARD",
        SurfaceKind::EvenAsphere => "EVENASPH",
        SurfaceKind::Paraxial => "PARAXIAL",
        SurfaceKind::CoordinateBreak => "COORDBRK",
        SurfaceKind::Toroidal => "TOROIDAL",
        SurfaceKind::DiffractionGrating => "DGRATING",
    }
}

fn column(r: &Record, k: usize) -> Result<String, String> {
    let c = r.args.get(k).ok_or_else(|| format!("line {} `{}`: column name missing", r.line, r.keyword))?;
    if !COLUMNS.contains(&c.as_str()) {
        return Err(format!("line {} `{}`: unknown column `{c}` (columns: {})", r.line, r.keyword, COLUMNS.join(", ")));
    }
    Ok(c.clone())
}

impl SurfaceBlock {
    /// Read one record of the surface; everything not understood is reported in `unsupported`.
    pub fn read(&mut self, r: &Record, unsupported: &mut Vec<Unsupported>) -> Result<(), String> {
        let mut skip = |reason: String| unsupported.push(Unsupported { line: r.line, keyword: r.keyword.clone(), reason });
        if matches!(r.keyword.as_str(), "CLAP" | "SQAP" | "OBSC" | "FLAP") {
            self.aperture_at = Some((r.line, r.keyword.clone()));
        }
        match r.keyword.as_str() {
            "TYPE" => {
                let t = r.args.first().cloned().unwrap_or_default();
                match surface_kind(&t) {
                    Some(k) => self.kind = Some((r.line, k)),
                    None => {
                        return Err(format!(
                            "line {} `TYPE`: surface {} has type `{t}`, which diffcassi does not model (STANDARD, EVENASPH, PARAXIAL, COORDBRK, TOROIDAL, DGRATING)",
                            r.line, self.number
                        ))
                    }
                }
            }
            "STOP" => self.stop = true,
            "COMM" => self.comment = r.rest.trim().trim_matches('"').to_string(),
            "CURV" => {
                let c = finite(r, 0)?;
                if c.abs() > crate::limits::MAX_CURVATURE_PER_MM {
                    return Err(format!(
                        "line {} `CURV`: curvature {} mm⁻¹ (radius {} mm) is outside the plausible range ±{:e} mm⁻¹ (|radius| ≥ {:e} mm)",
                        r.line,
                        crate::limits::fmt_num(c),
                        crate::limits::fmt_num(1.0 / c),
                        crate::limits::MAX_CURVATURE_PER_MM,
                        1.0 / crate::limits::MAX_CURVATURE_PER_MM
                    ));
                }
                // A subnormal curvature (1e-320) has no finite radius: refused here by line, not later as
                // "radius_mm: inf is not finite".
                if c != 0.0 && !(1.0 / c).is_finite() {
                    return Err(format!(
                        "line {} `CURV`: curvature {} mm⁻¹ is so small that its radius 1/c is not a finite number: write `CURV 0` for a flat surface",
                        r.line,
                        crate::limits::fmt_num(c)
                    ));
                }
                self.curv = Some((r.line, c));
                if r.args.len() > 1 && int(r, 1)? != 0 {
                    self.frozen.push(Unsupported { line: r.line, keyword: r.keyword.clone(), reason: format!("curvature solve type {}: {FROZEN}", r.args[1]) });
                }
            }
            "DISZ" => {
                let t = num(r, 0)?;
                // INFINITY is the object at infinity (refused later with its own message); a finite thickness
                // must be a plausible length.
                if t.is_finite() {
                    crate::limits::check_plausible_length("thickness", t).map_err(|m| format!("line {} `DISZ`: {m}", r.line))?;
                }
                self.disz = Some((r.line, t))
            }
            "GLAS" => {
                let name = r.args.first().cloned().ok_or_else(|| format!("line {} `GLAS`: glass name missing", r.line))?;
                match name.as_str() {
                    "___BLANK" => skip("model glass (n_d, V_d): only catalogue glasses are modelled".into()),
                    "MIRROR" => self.mirror = Some(r.line),
                    _ if name.chars().all(|c| c.is_ascii_digit() || c == '.') => {
                        skip(format!("glass code `{name}`: only catalogue glass names are modelled"))
                    }
                    _ => self.glass = Some((r.line, name)),
                }
            }
            "CONI" => self.coni = Some((r.line, finite(r, 0)?)),
            "PARM" => {
                let i = int(r, 0)?;
                if !(0..=16).contains(&i) {
                    return Err(format!("line {} `PARM`: parameter number {i} (0..16)", r.line));
                }
                self.parm.push((r.line, i as usize, finite(r, 1)?));
            }
            "XDAT" => self.xdat.push((r.line, int(r, 0)?, finite(r, 1)?)),
            "DCGE" => self.efficiency = Some((r.line, finite(r, 0)?)),
            "DIAM" => self.diam = Some(finite(r, 0)?),
            "CLAP" => self.clap = Some((finite(r, 0)?, finite(r, 1)?)),
            "SQAP" => self.sqap = Some((finite(r, 0)?, finite(r, 1)?)),
            "OBSC" => {
                // OpticStudio's "Circular Obscuration" aperture type (User Manual, Surface Properties >
                // Aperture): rays with rmin ≤ r ≤ rmax about the OBDC decentre are blocked, all others pass.
                // The third number OpticStudio writes (as on CLAP/SQAP) is not read, as for CLAP.
                let radius = |k: usize, what: &str| -> Result<f64, String> {
                    let v = num(r, k).map_err(|m| format!("{m} (surface {}, obscuration {what} radius)", self.number))?;
                    if !v.is_finite() || v < 0.0 {
                        return Err(format!(
                            "line {} `OBSC`: surface {} obscuration {what} radius {} mm must be finite and ≥ 0",
                            r.line, self.number, crate::limits::fmt_num(v)
                        ));
                    }
                    Ok(v)
                };
                let (rmin, rmax) = (radius(0, "minimum")?, radius(1, "maximum")?);
                if rmin > rmax || rmax == 0.0 {
                    return Err(format!(
                        "line {} `OBSC`: surface {} obscuration radii {rmin} to {rmax} mm: the minimum must not exceed the maximum, and the maximum must be > 0",
                        r.line, self.number
                    ));
                }
                self.obsc = Some((r.line, rmin, rmax));
            }
            "OBDC" => self.obdc = (finite(r, 0)?, finite(r, 1)?),
            "VCUR" => self.variables.push((r.line, "radius_mm".into())),
            "VDSZ" => self.variables.push((r.line, "thickness_mm".into())),
            "VCON" => self.variables.push((r.line, "conic".into())),
            "VPAR" => {
                let i = int(r, 0)?;
                self.variables.push((r.line, format!("#PARM{i}")))
            }
            "DCVR" => self.variables.push((r.line, column(r, 0)?)),
            "DCCR" => self.drivers.push((r.line, column(r, 0)?, Driver::ChiefRay)),
            "DCPK" => {
                let col = column(r, 0)?;
                let from = int(r, 1)?;
                if from < 0 {
                    return Err(format!("line {} `DCPK`: source surface {from}", r.line));
                }
                let source = if r.args.len() > 4 { Some(column(r, 4)?) } else { None };
                let p = Pickup { surface: from as usize, scale: finite(r, 2)?, offset: finite(r, 3)?, column: source };
                self.drivers.push((r.line, col, Driver::Pickup(p)));
            }
            k if COSMETIC.contains(&k) => {}
            // OpticStudio's pickups and solves: `PZUP` (thickness pickup), `PPAR` (parameter pickup), `CUPP`
            // (curvature pickup), `TPUP`, `TSOL`, `PSOL`, `SSOL`, and `MAZH` (the thickness solve "marginal ray
            // height", height and pupil zone: the focusing solve of the last thickness). The file holds each
            // solved value (`DISZ`, `CURV`, `PARM` write the current values), so the saved system is read as it is.
            "PZUP" | "PPAR" | "CUPP" | "TPUP" | "TSOL" | "PSOL" | "SSOL" | "MAZH" => {
                self.frozen.push(Unsupported { line: r.line, keyword: r.keyword.clone(), reason: FROZEN.into() })
            }
            "SCBD" | "TILT" | "DECX" | "DECY" => skip("surface tilt/decenter: write it as Coordinate Break surfaces".into()),
            // `FLAP rmin rmax 0`: a floating aperture, the circular aperture that follows the surface's
            // semi-diameter (OpticStudio, "Aperture type: floating aperture"); the file holds that radius.
            "FLAP" => {
                let (rmin, rmax) = (finite(r, 0)?, finite(r, 1)?);
                if !(rmin >= 0.0 && rmax > rmin) {
                    return Err(format!("line {} `FLAP`: floating aperture radii {} to {} mm of surface {} (need 0 ≤ min < max)", r.line, crate::limits::fmt_num(rmin), crate::limits::fmt_num(rmax), self.number));
                }
                self.flap = Some((rmin, rmax))
            }
            // A word no OpticStudio record starts with (a stray line after the last surface read as its record):
            // said as such, not as a keyword of that surface (round 15).
            k if !(k.len() == 4 && k.chars().all(|c| c.is_ascii_uppercase() || c.is_ascii_digit())) => {
                skip(format!("not a .zmx record (OpticStudio's keywords are four upper-case letters or digits; read in surface {}'s block)", self.number))
            }
            _ => skip(format!("surface {} keyword not modelled", self.number)),
        }
        Ok(())
    }

    /// Column name of parameter `i` on this surface type, if it maps to a spec column.
    fn parm_column(kind: SurfaceKind, i: usize) -> Option<String> {
        match kind {
            SurfaceKind::EvenAsphere if (1..=8).contains(&i) => Some(format!("asphere_{i}")),
            SurfaceKind::Paraxial if i == 1 => Some("focal_length_mm".into()),
            SurfaceKind::CoordinateBreak if (1..=5).contains(&i) => Some(COLUMNS[3 + i].to_string()),
            SurfaceKind::Toroidal if i == 1 => Some("rotation_radius_mm".into()),
            SurfaceKind::Toroidal if (2..=9).contains(&i) => Some(format!("asphere_{}", i - 1)),
            SurfaceKind::DiffractionGrating if i == 1 => Some("grating_lines_per_um".into()),
            SurfaceKind::DiffractionGrating if i == 2 => Some("grating_order".into()),
            _ => None,
        }
    }

    /// A Diffraction Grating's `PARM 1` (T, lines per µm) and `PARM 2` (order m), by line and record (the
    /// spec's check named its field and no line; round 19). T > 0: 0 lines per µm is no grating, and a negative
    /// T is refused rather than read as a convention — in the grating equation n₂ sin θ₂ = n₁ sin θ₁ − mλT a
    /// frequency −T in order m is T in order −m, which the message says how to write; OpticStudio's own reading
    /// of T < 0 is not established (optiland's grating takes a positive period only). m an integer of
    /// magnitude ≤ 10⁶ (the spec's bound): a diffraction order is a whole number of wavelengths of path.
    fn check_grating_parms(&self) -> Result<(), String> {
        let n = self.number;
        let parm = |i: usize| self.parm.iter().rev().find(|p| p.1 == i).map(|p| (p.0, p.2));
        let fmt = crate::limits::fmt_num;
        match parm(1) {
            None => return Err(format!("surface {n} (SURF at line {}) is a Diffraction Grating with no `PARM 1` (its lines per µm)", self.line)),
            Some((l, t)) if t == 0.0 => {
                return Err(format!("line {l} `PARM`: surface {n} (Diffraction Grating) parameter 1, lines per µm, is 0: a grating has > 0 lines per µm (0 lines per µm is no grating: make the surface `TYPE STANDARD`)"))
            }
            Some((l, t)) if !(t > 0.0) => {
                let m = parm(2).map(|p| p.1).unwrap_or(1.0);
                return Err(format!(
                    "line {l} `PARM`: surface {n} (Diffraction Grating) parameter 1, lines per µm, is {}: a grating has > 0 lines per µm (in the grating equation a frequency −T in order m diffracts as T in order −m: write `PARM 1 {}` and `PARM 2 {}`)",
                    fmt(t),
                    fmt(-t),
                    fmt(if m == 0.0 { 0.0 } else { -m })
                ));
            }
            Some(_) => {}
        }
        match parm(2) {
            None => Err(format!("surface {n} (SURF at line {}) is a Diffraction Grating with no `PARM 2` (its diffraction order)", self.line)),
            Some((l, m)) if m.fract() != 0.0 || m.abs() > 1e6 => Err(format!(
                "line {l} `PARM`: surface {n} (Diffraction Grating) parameter 2, the diffraction order, is {}: an order is a whole number (an integer of magnitude at most 10⁶)",
                fmt(m)
            )),
            Some(_) => Ok(()),
        }
    }

    /// The record that set `column` to `value` (line, keyword), for messages: `CURV`, `CONI`, `DISZ`, or the
    /// `PARM` record holding the value; the `SURF` line when none does.
    pub fn record_of(&self, column: &str, value: f64) -> (usize, &'static str) {
        let by = match column {
            "radius_mm" => self.curv.map(|(l, _)| (l, "CURV")),
            "conic" => self.coni.map(|(l, _)| (l, "CONI")),
            "thickness_mm" => self.disz.map(|(l, _)| (l, "DISZ")),
            _ => self.parm.iter().find(|p| p.2 == value).map(|p| (p.0, "PARM")),
        };
        by.unwrap_or((self.line, "SURF"))
    }

    /// The spec surface; `unsupported` receives parameters that have no meaning here.
    pub fn build(&self, unsupported: &mut Vec<Unsupported>) -> Result<SurfaceSpec, String> {
        let kind = self.kind.map(|k| k.1).unwrap_or(SurfaceKind::Standard);
        let mut s = SurfaceSpec::new(kind);
        s.stop = self.stop;
        s.comment = self.comment.clone();
        // diffcassi's own export tags a coded-mask surface in its comment (spec::CodedMaskSpec::comment_tag).
        if let Some((mask, rest)) = crate::spec::CodedMaskSpec::from_comment(&self.comment).map_err(|e| format!("surface {} (SURF at line {}), `COMM`: {e}", self.number, self.line))? {
            s.coded_mask = Some(mask);
            s.comment = rest;
        }
        let line = self.line;
        if let Some((cl, c)) = self.curv {
            if c != 0.0 {
                if kind == SurfaceKind::CoordinateBreak || kind == SurfaceKind::Paraxial {
                    // The CURV record's line (the SURF line was named; a held-out battery, round 10).
                    unsupported.push(Unsupported { line: cl, keyword: "CURV".into(), reason: format!("curvature {c} on a {} surface has no effect in OpticStudio either", kind.label()) });
                } else {
                    s.radius_mm = Some(Cell::fixed(1.0 / c));
                }
            }
        }
        if let Some((_, t)) = self.disz {
            s.thickness_mm = Cell::fixed(t);
        }
        if let Some((gl, g)) = &self.glass {
            if kind == SurfaceKind::CoordinateBreak {
                return Err(format!("line {gl} `GLAS`: a Coordinate Break (surface {}) keeps the previous medium; it cannot have glass `{g}`", self.number));
            }
            s.material = Some(g.clone());
        }
        if let Some(ml) = self.mirror {
            if kind == SurfaceKind::CoordinateBreak {
                return Err(format!("line {ml} `GLAS`: a Coordinate Break (surface {}) keeps the previous medium; it cannot be a MIRROR", self.number));
            }
            s.material = Some("MIRROR".into());
        }
        for &(xl, i, v) in &self.xdat {
            match (kind, i) {
                (SurfaceKind::Toroidal, 1) if v == 0.0 => {}
                (SurfaceKind::Toroidal, 2) if self.xdat.iter().all(|x| x.1 != 1 || x.2 == 0.0) => {} // normalisation radius of no terms
                (SurfaceKind::Toroidal, 1) => unsupported.push(Unsupported { line: xl, keyword: "XDAT".into(), reason: format!("{} Zernike terms on a Toroidal surface: not modelled", crate::limits::fmt_num(v)) }),
                _ if v == 0.0 => {}
                _ => unsupported.push(Unsupported { line: xl, keyword: "XDAT".into(), reason: format!("extra data {i} = {} on a {} surface: not modelled", crate::limits::fmt_num(v), kind.label()) }),
            }
        }
        if let Some((el, e)) = self.efficiency {
            if kind != SurfaceKind::DiffractionGrating {
                return Err(format!("line {el} `DCGE`: a grating efficiency on surface {}, which is not a Diffraction Grating", self.number));
            }
            s.grating_efficiency = Some(e);
        }
        if let Some((kl, k)) = self.coni {
            if matches!(kind, SurfaceKind::Standard | SurfaceKind::EvenAsphere | SurfaceKind::Toroidal | SurfaceKind::DiffractionGrating) {
                s.conic = Some(Cell::fixed(k));
            } else if k != 0.0 {
                unsupported.push(Unsupported { line: kl, keyword: "CONI".into(), reason: format!("conic {k} on a {} surface", kind.label()) });
            }
        }
        s.semi_diameter_mm = self.diam;
        let (dx, dy) = self.obdc;
        // A surface has one aperture type in OpticStudio: CLAP, SQAP and OBSC exclude each other.
        let kinds = [self.clap.map(|_| "a circular aperture (CLAP)"), self.sqap.map(|_| "a rectangular aperture (SQAP)"), self.obsc.map(|_| "a circular obscuration (OBSC)")];
        let given: Vec<&str> = kinds.iter().flatten().copied().collect();
        if given.len() > 1 {
            return Err(format!("surface {} (line {line}): {} — OpticStudio gives a surface one aperture type", self.number, given.join(" and ")));
        }
        match (self.clap, self.sqap, self.obsc) {
            (Some((rmin, rmax)), _, _) => {
                s.aperture = Some(Aperture::Circular { semi_diameter_mm: rmax, min_radius_mm: rmin, decenter_x_mm: dx, decenter_y_mm: dy })
            }
            (_, Some((hx, hy)), _) => {
                s.aperture = Some(Aperture::Rectangular { half_width_x_mm: hx, half_width_y_mm: hy, decenter_x_mm: dx, decenter_y_mm: dy })
            }
            (_, _, Some((_, rmin, rmax))) => {
                s.aperture = Some(Aperture::CircularObscuration { min_radius_mm: rmin, max_radius_mm: rmax, decenter_x_mm: dx, decenter_y_mm: dy })
            }
            // A floating aperture (FLAP) is the circular aperture of its radii, where no other aperture is given.
            (None, None, None) => {
                if let Some((rmin, rmax)) = self.flap {
                    s.aperture = Some(Aperture::Circular { semi_diameter_mm: rmax, min_radius_mm: rmin, decenter_x_mm: dx, decenter_y_mm: dy })
                }
            }
        }
        for &(pl, i, v) in &self.parm {
            if kind == SurfaceKind::CoordinateBreak && i == 6 {
                if v != 0.0 && v != 1.0 {
                    return Err(format!("line {pl} `PARM`: Coordinate Break order {} (0 or 1)", crate::limits::fmt_num(v)));
                }
                s.order = v as u8;
                continue;
            }
            if kind == SurfaceKind::Paraxial && i == 2 {
                continue; // OPD mode: changes OPD only, not the rays
            }
            if kind == SurfaceKind::Toroidal && i == 1 && v == 0.0 {
                continue; // radius of rotation 0: infinite (a cylinder), the spec's absent value
            }
            match Self::parm_column(kind, i) {
                Some(col) => {
                    if let Some(k) = col.strip_prefix("asphere_") {
                        let k: usize = k.parse().expect("asphere index");
                        if s.asphere_coefficients.len() < k {
                            s.asphere_coefficients.resize(k, Cell::fixed(0.0));
                        }
                        s.asphere_coefficients[k - 1] = Cell::fixed(v);
                    } else {
                        let slot = match col.as_str() {
                            "focal_length_mm" => &mut s.focal_length_mm,
                            "rotation_radius_mm" => &mut s.rotation_radius_mm,
                            "grating_lines_per_um" => &mut s.grating_lines_per_um,
                            "grating_order" => &mut s.grating_order,
                            "decenter_x_mm" => &mut s.decenter_x_mm,
                            "decenter_y_mm" => &mut s.decenter_y_mm,
                            "tilt_x_deg" => &mut s.tilt_x_deg,
                            "tilt_y_deg" => &mut s.tilt_y_deg,
                            _ => &mut s.tilt_z_deg,
                        };
                        *slot = Some(Cell::fixed(v));
                    }
                }
                None if v == 0.0 => {}
                None => unsupported.push(Unsupported {
                    line: pl,
                    keyword: "PARM".into(),
                    reason: format!("parameter {i} = {} has no meaning on a {} surface in diffcassi", crate::limits::fmt_num(v), kind.label()),
                }),
            }
        }
        if kind == SurfaceKind::DiffractionGrating {
            self.check_grating_parms()?;
        }
        for (vl, col) in &self.variables {
            let col = match col.strip_prefix("#PARM") {
                Some(i) => match Self::parm_column(kind, i.parse().unwrap_or(0)) {
                    Some(c) => c,
                    None => {
                        unsupported.push(Unsupported { line: *vl, keyword: "VPAR".into(), reason: format!("variable parameter {i} of a {} surface", kind.label()) });
                        continue;
                    }
                },
                None => col.clone(),
            };
            match s.cell_mut(&col) {
                Some(c) => c.variable = true,
                None => return Err(format!("line {vl}: variable `{col}` but surface {} has no such cell", self.number)),
            }
        }
        for (dl, col, driver) in &self.drivers {
            match s.cell_mut(col) {
                Some(c) => c.driver = driver.clone(),
                None => return Err(format!("line {dl}: a pickup/solve on `{col}` but surface {} has no such cell (write its value first)", self.number)),
            }
        }
        Ok(s)
    }
}
