//! The system data of a `.zmx` file (the records before the first `SURF`): name, units, system aperture,
//! ray aiming, fields, wavelengths, environment, glass catalogues.
//!
//! Read as OpticStudio writes them (see `docs/zemax-files.md`): `ENPD d` (entrance pupil diameter, mm),
//! `OBNA v flag` (flag 0: object-space NA v; 1: object cone angle v, the marginal ray's half-angle in object
//! space, degrees), `FNUM f flag` (flag 0: image-space F/#; 1, the paraxial working F/#, is refused), `FLOA`
//! (float by stop size), `RAIM a m …` (m = 0 off, 1 paraxial, 2 real), `FTYP type telecentric nfields nwaves
//! normalisation ? afocal …` with `XFLN`/`YFLN` (type 0: angles in degrees; 1: object heights, 2: paraxial and 3:
//! real image heights, mm; a telecentric object space is refused, afocal image space listed), `WAVM i λ_µm
//! weight` (or the older `WAVL`/`WWGT`), `PWAV i`, `GCAT names…`, `ENVD T P …`, `UNIT MM …`, `MODE SEQ`. The
//! flags' positions are those optiland's reader (`fileio/zemax/reader/parser.py`: `_read_object_na`, `_read_fno`,
//! `_read_config_data`) reads.
use super::lexer::Record;
use super::records::{finite, int, num_or, Unsupported};
use crate::spec::{RayAiming, SystemAperture};

/// System data as read (validated when the spec is assembled).
#[derive(Debug, Default)]
pub(super) struct Header {
    pub name: String,
    pub note: String,
    pub aperture: Option<(usize, SystemAperture)>,
    pub ray_aiming: RayAiming,
    /// (line, field type, number of fields, number of wavelengths).
    pub ftyp: Option<(usize, i64, usize, usize)>,
    pub xfln: Vec<f64>,
    pub yfln: Vec<f64>,
    /// (line, keyword) of the record the x and the y field values came from (`XFLN`/`XFLD`, `YFLN`/`YFLD`).
    pub xfln_at: (usize, String),
    pub yfln_at: (usize, String),
    /// Old-style field lists (`XFLD`/`YFLD`): every entry is a field.
    pub old_fields: bool,
    /// (index, λ µm, weight, line).
    pub wavm: Vec<(usize, f64, f64, usize)>,
    pub wavl: Vec<f64>,
    /// Line of the `WAVL` record.
    pub wavl_line: usize,
    pub wwgt: Vec<f64>,
    pub pwav: Option<(usize, usize)>,
    pub gcat: Option<(usize, Vec<String>)>,
    /// diffcassi extensions (`DCAI`, `DCWP`, `DCGC`).
    pub air_index: Option<f64>,
    pub allow_extrapolation: bool,
    pub catalog_paths: Vec<String>,
    /// `OBNA θ 1`: (line, object cone angle θ in degrees); the aperture holds sin θ until the object's medium
    /// is known (`super::import_zmx` multiplies by its index, or refuses an object in glass).
    pub cone_angle: Option<(usize, f64)>,
    /// Line of an `FTYP` whose afocal-image-space flag is set (listed: it changes no ray).
    pub afocal_line: Option<usize>,
    /// Vignetting factor records (`VDXN`, `VDYN`, `VCXN`, `VCYN`, `VANN`; `…F` in older files): (line, keyword, values).
    pub vignetting: Vec<(usize, String, Vec<f64>)>,
}

impl Header {
    /// Read one system-data record; `Ok(false)` if the keyword is not system data.
    pub fn read(&mut self, r: &Record, unsupported: &mut Vec<Unsupported>) -> Result<bool, String> {
        let mut skip = |reason: String| unsupported.push(Unsupported { line: r.line, keyword: r.keyword.clone(), reason });
        let nums = |r: &Record| -> Result<Vec<f64>, String> { (0..r.args.len()).map(|k| finite(r, k)).collect() };
        match r.keyword.as_str() {
            "NAME" => self.name = r.rest.trim().trim_matches('"').to_string(),
            "NOTE" => self.note = r.rest.split_once(char::is_whitespace).map(|x| x.1).unwrap_or("").trim().to_string(),
            "MODE" => {
                // Never skipped (not even with --ignore-unsupported): a non-sequential file read as a
                // sequential one would be a different system.
                if r.args.first().map(String::as_str) != Some("SEQ") {
                    return Err(format!(
                        "line {} `MODE {}`: only sequential (MODE SEQ) files can be imported; a non-sequential file is never read as a sequential system (--ignore-unsupported does not apply)",
                        r.line,
                        r.rest.trim()
                    ));
                }
            }
            "UNIT" => {
                // Never skipped (not even with --ignore-unsupported): every length of the file (CURV, DISZ, DIAM,
                // CLAP, ENPD, field heights, …) is in the lens units, so reading inches as millimetres would make
                // every number 25.4× wrong, not drop one item.
                let unit = r.args.first().cloned().unwrap_or_default();
                // Keywords are case-sensitive (`UNIT mm` is not OpticStudio's, which writes `UNIT MM`): refused, as a
                // lower-case `curv` is, with a message that says so rather than that the file is not in millimetres.
                if unit != "MM" && unit.eq_ignore_ascii_case("MM") {
                    return Err(format!(
                        "line {} `UNIT {unit}`: the unit keyword is case-sensitive and OpticStudio writes millimetres as `UNIT MM`; `{unit}` is not one of its unit keywords (a hand-edited file?): write `UNIT MM`",
                        r.line
                    ));
                }
                if unit != "MM" {
                    return Err(format!(
                        "line {} `UNIT {unit}`: lens units `{unit}`: diffcassi reads millimetres (`UNIT MM`, case-sensitive) only, and every length of the file is in the lens units, so the file cannot be read with another unit (--ignore-unsupported does not apply); convert the lens to millimetres in OpticStudio (Scale Lens, \"Convert units\" to Millimeters) and save it again",
                        r.line
                    ));
                }
            }
            "ENPD" => self.aperture = Some((r.line, SystemAperture::EntrancePupilDiameter(finite(r, 0)?))),
            // OBNA's second value is the aperture type: 0 the object-space NA, 1 the object cone angle (OpticStudio's
            // "Object Cone Angle": the marginal ray's half-angle in object space, degrees; optiland's
            // `_read_object_na`). Read as NA: `OBNA 0.5 1`, a 0.5° cone, was traced with NA 0.5 (66× the pupil).
            "OBNA" => {
                let v = finite(r, 0)?;
                match num_or(r, 1, 0.0)? {
                    f if f == 0.0 => {
                        if !(v > 0.0 && v < 1.0) {
                            return Err(format!(
                                "line {} `OBNA`: object-space NA {} (type 0) must be in (0, 1); an object cone angle in degrees is `OBNA θ 1`",
                                r.line,
                                crate::limits::fmt_num(v)
                            ));
                        }
                        self.aperture = Some((r.line, SystemAperture::ObjectSpaceNa(v)))
                    }
                    f if f == 1.0 => {
                        if !(v > 0.0 && v < 90.0) {
                            return Err(format!(
                                "line {} `OBNA`: object cone angle {}° (type 1, the marginal ray's half-angle in object space) must be in (0, 90) degrees",
                                r.line,
                                crate::limits::fmt_num(v)
                            ));
                        }
                        // NA = n sin θ, n the object space's index: sin θ here, n applied once the medium is known.
                        self.cone_angle = Some((r.line, v));
                        self.aperture = Some((r.line, SystemAperture::ObjectSpaceNa(v.to_radians().sin())))
                    }
                    f => {
                        return Err(format!(
                            "line {} `OBNA`: aperture type {} (the second value): OpticStudio writes 0 (object-space NA) or 1 (object cone angle, degrees)",
                            r.line,
                            crate::limits::fmt_num(f)
                        ))
                    }
                }
            }
            // FNUM's second value: 0 the image-space F/# (diffcassi's), 1 the paraxial working F/# (optiland's
            // `_read_fno`: "paraxialImageFNO"), another definition (1 / (2 n' sin θ') of the paraxial marginal ray
            // at the working conjugates), which differs at finite conjugates: refused, never read as the other.
            "FNUM" => {
                let v = finite(r, 0)?;
                match num_or(r, 1, 0.0)? {
                    f if f == 0.0 => self.aperture = Some((r.line, SystemAperture::ImageSpaceFNumber(v))),
                    f if f == 1.0 => skip(format!(
                        "system aperture type Paraxial Working F/# (`FNUM {} 1`) not modelled: diffcassi's `FNUM f 0` is the image-space F/# (EFL / entrance-pupil diameter), a different definition at finite conjugates; set the aperture to Image Space F/# or Entrance Pupil Diameter in OpticStudio",
                        crate::limits::fmt_num(v)
                    )),
                    f => {
                        return Err(format!(
                            "line {} `FNUM`: aperture type {} (the second value): OpticStudio writes 0 (image-space F/#) or 1 (paraxial working F/#)",
                            r.line,
                            crate::limits::fmt_num(f)
                        ))
                    }
                }
            }
            "FLOA" => self.aperture = Some((r.line, SystemAperture::FloatByStopSize)),
            "OBSA" | "PUPD" => skip(
                "system aperture type not modelled (diffcassi takes the entrance pupil diameter ENPD, the image-space F/# `FNUM f 0`, the object-space NA `OBNA na 0` or cone angle `OBNA θ 1`, or float by stop size FLOA)".into(),
            ),
            "RAIM" => {
                let (a, m) = (int(r, 0)?, int(r, 1)?);
                match (a, m) {
                    (0, 0) => self.ray_aiming = RayAiming::Off,
                    (0, 1) => self.ray_aiming = RayAiming::Paraxial,
                    (0, 2) => self.ray_aiming = RayAiming::Real,
                    _ => skip(format!("ray aiming `{}`: only off (`RAIM 0 0 …`), paraxial (`RAIM 0 1 …`) and real (`RAIM 0 2 …`) are modelled", r.rest)),
                }
            }
            "ENVD" => {
                let (t, p) = (finite(r, 0)?, num_or(r, 1, 1.0)?);
                if t != 20.0 || p != 1.0 {
                    skip(format!("environment {t} °C, {p} atm: glass indices are modelled at 20 °C and 1 atm only"));
                }
            }
            "FTYP" => {
                let n = |k: usize| -> Result<usize, String> { Ok(int(r, k)?.max(0) as usize) };
                self.ftyp = Some((r.line, int(r, 0)?, n(2)?, n(3)?));
                // The second value: telecentric object space (optiland's `object_space_telecentric`). OpticStudio then
                // puts the entrance pupil at infinity: every chief ray is parallel to the axis, whatever the stop.
                // Never skipped (not even with --ignore-unsupported): read without it, every chief ray is another ray.
                let telecentric = int(r, 1)?;
                if telecentric != 0 {
                    return Err(format!(
                        "line {} `FTYP`: telecentric object space (the second value, {telecentric}) is not modelled: OpticStudio puts the entrance pupil at infinity (every chief ray parallel to the axis), and read without it every chief ray would be another ray (--ignore-unsupported does not apply); turn Telecentric Object Space off in OpticStudio (System Explorer → Aperture) or model the telecentric pupil with a stop at the front focal point",
                        r.line
                    ));
                }
                // The seventh: afocal image space (optiland's `afocal_image_space`): OpticStudio reports the analyses
                // in angles; no ray changes. Listed (`skipped`), since diffcassi reports positions on the image (mm).
                if r.args.len() > 6 && int(r, 6)? != 0 {
                    self.afocal_line = Some(r.line);
                }
            }
            "XFLN" | "XFLD" => {
                self.xfln = nums(r)?;
                self.xfln_at = (r.line, r.keyword.clone());
                self.old_fields |= r.keyword == "XFLD"
            }
            "YFLN" | "YFLD" => {
                self.yfln = nums(r)?;
                self.yfln_at = (r.line, r.keyword.clone());
                self.old_fields |= r.keyword == "YFLD"
            }
            "VDXN" | "VDYN" | "VCXN" | "VCYN" | "VANN" | "VDXF" | "VDYF" | "VCXF" | "VCYF" | "VANF" => {
                self.vignetting.push((r.line, r.keyword.clone(), nums(r)?))
            }
            "WAVM" => {
                if self.wavl_line != 0 {
                    return Err(both_wavelength_lists((self.wavl_line, "WAVL"), r));
                }
                let i = int(r, 0)?;
                if i < 1 {
                    return Err(format!("line {} `WAVM`: wavelength number {i} (they count from 1)", r.line));
                }
                self.wavm.push((i as usize, finite(r, 1)?, num_or(r, 2, 1.0)?, r.line));
            }
            "WAVL" => {
                if let Some(w) = self.wavm.first() {
                    return Err(both_wavelength_lists((w.3, "WAVM"), r));
                }
                self.wavl = nums(r)?;
                self.wavl_line = r.line
            }
            "WWGT" => self.wwgt = nums(r)?,
            "PWAV" => self.pwav = Some((r.line, int(r, 0)?.max(0) as usize)),
            "GCAT" => self.gcat = Some((r.line, r.args.clone())),
            "MNUM" => {
                if int(r, 0)? > 1 {
                    skip(format!("{} configurations: multi-configuration data are not modelled", int(r, 0)?));
                }
            }
            "CONF" => skip("multi-configuration operand: not modelled".into()),
            "TOL" => {
                if r.args.first().map(String::as_str) != Some("TOFF") {
                    skip(format!("tolerance operand `{}`: tolerance data are not modelled", r.args.first().cloned().unwrap_or_default()))
                }
            }
            "DCAI" => self.air_index = Some(finite(r, 0)?),
            "DCWP" => match r.args.first().map(String::as_str) {
                Some("allow_extrapolation") => self.allow_extrapolation = true,
                Some("strict") => self.allow_extrapolation = false,
                other => return Err(format!("line {} `DCWP`: `{}` (strict or allow_extrapolation)", r.line, other.unwrap_or(""))),
            },
            "DCGC" => self.catalog_paths.push(r.rest.trim().trim_matches('"').to_string()),
            _ => return Ok(false),
        }
        Ok(true)
    }
}

/// `WAVM` records and a `WAVL` list in one file: two lists of the wavelengths (`WAVL` was ignored silently).
fn both_wavelength_lists(first: (usize, &str), r: &Record) -> String {
    format!(
        "line {} `{}`: the wavelengths are given both as `WAVM` records and as a `WAVL` list (the first: line {} `{}`); OpticStudio writes one or the other (`WAVL` in old files), and which one is meant is unknown: remove one",
        r.line, r.keyword, first.0, first.1
    )
}
