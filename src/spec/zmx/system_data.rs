//! The system data of a `.zmx` file (the records before the first `SURF`): name, units, system aperture,
//! ray aiming, fields, wavelengths, environment, glass catalogues.
//!
//! Read as OpticStudio writes them (see `docs/zemax-files.md`): `ENPD d` (entrance pupil diameter, mm),
//! `OBNA na` (object-space NA), `FNUM f …` (image-space F/#), `FLOA` (float by stop size),
//! `RAIM a m …` (m = 0 off, 1 paraxial, 2 real), `FTYP type ? nfields nwaves …` with `XFLN`/`YFLN` (type 0: angles in
//! degrees; 1: object heights, 2: paraxial and 3: real image heights, mm), `WAVM i λ_µm weight` (or the older `WAVL`/`WWGT`),
//! `PWAV i`, `GCAT names…`, `ENVD T P …`, `UNIT MM …`, `MODE SEQ`.
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
                if unit != "MM" {
                    return Err(format!(
                        "line {} `UNIT {unit}`: lens units `{unit}`: diffcassi reads millimetres (MM) only, and every length of the file is in the lens units, so the file cannot be read with another unit (--ignore-unsupported does not apply); convert the lens to millimetres in OpticStudio (Scale Lens, \"Convert units\" to Millimeters) and save it again",
                        r.line
                    ));
                }
            }
            "ENPD" => self.aperture = Some((r.line, SystemAperture::EntrancePupilDiameter(finite(r, 0)?))),
            "OBNA" => self.aperture = Some((r.line, SystemAperture::ObjectSpaceNa(finite(r, 0)?))),
            "FNUM" => self.aperture = Some((r.line, SystemAperture::ImageSpaceFNumber(finite(r, 0)?))),
            "FLOA" => self.aperture = Some((r.line, SystemAperture::FloatByStopSize)),
            "OBSA" | "PUPD" => skip(
                "system aperture type not modelled (diffcassi takes the entrance pupil diameter ENPD, the image-space F/# FNUM, the object-space NA OBNA or float by stop size FLOA)".into(),
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
                let i = int(r, 0)?;
                if i < 1 {
                    return Err(format!("line {} `WAVM`: wavelength number {i} (they count from 1)", r.line));
                }
                self.wavm.push((i as usize, finite(r, 1)?, num_or(r, 2, 1.0)?, r.line));
            }
            "WAVL" => {
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
