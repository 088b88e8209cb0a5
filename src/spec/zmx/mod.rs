//! Zemax OpticStudio `.zmx` lens files, in and out (`docs/zemax-files.md`).
//!
//! [`import_zmx`] reads the sequential Lens Data Editor and system data of a `.zmx` file (UTF-16 with BOM,
//! UTF-8 or ASCII) into a [`SystemSpec`]; [`to_zmx`] writes any spec as `.zmx` text that reads back to the
//! identical spec (every value bit-identical). What the file holds that diffcassi does not model — a
//! surface type it lacks, non-sequential mode, multi-configuration or tolerance data, a vignetting
//! angle (VAN; the decentre and compression factors are read), model glasses, OpticStudio solves — is never dropped silently: it is refused, listed by line and
//! keyword, or, with [`ZmxOptions::ignore_unsupported`], skipped and listed in [`ZmxImport::ignored`].
//!
//! ```
//! use diffcassi::spec::zmx::{import_zmx, to_zmx, ZmxOptions};
//! let spec = diffcassi::presets::spec("sp").unwrap();
//! let text = to_zmx(&spec).unwrap();
//! let back = import_zmx(text.as_bytes(), "sp.zmx", None, &ZmxOptions::default()).unwrap();
//! assert_eq!(back.spec, spec);
//! assert!(back.ignored.is_empty());
//! ```
mod export;
mod glass;
pub mod lexer;
mod records;
mod surfaces;
mod system_data;

pub use export::to_zmx;
pub use glass::{GlassOrigin, SUBSET as GLASS_SUBSET};
pub use lexer::TextEncoding;
pub use records::Unsupported;

use crate::error::{Error, Result};
use crate::materials::WavelengthPolicy;
use crate::spec::{FieldType, SystemAperture, SystemSpec};
use std::path::{Path, PathBuf};
use surfaces::SurfaceBlock;
use system_data::Header;

/// How strictly to import.
#[derive(Clone, Debug, Default)]
pub struct ZmxOptions {
    /// Skip what diffcassi does not model (listed in [`ZmxImport::ignored`]) instead of refusing the file.
    pub ignore_unsupported: bool,
    /// Extra folders searched for the `NAME.AGF` catalogues of `GCAT` (before the file's own folder and
    /// `DIFFCASSI_GLASS_DIR`).
    pub glass_dirs: Vec<PathBuf>,
    /// Catalogue entries given by the user (`--glass-catalog FILE.agf`, `builtin:NAME`), searched for the
    /// file's glasses after the file's own catalogues (`DCGC`, then the `GCAT` ones); as for a TOML spec, a
    /// later catalogue wins, so a glass in both is the user's. A `GCAT NAME` whose `NAME.AGF` is among them is
    /// taken as found. Recorded at the end of the spec's `glass_catalogs`.
    pub glass_catalogs: Vec<String>,
}

/// An imported file: the spec and what was skipped (empty unless `ignore_unsupported`).
#[derive(Clone, Debug)]
pub struct ZmxImport {
    pub spec: SystemSpec,
    pub ignored: Vec<Unsupported>,
    /// Records that carry no optics (editor, display, tolerancing, merit-function rows), skipped: the system is
    /// the same with or without them. Listed by `diffcassi info --system FILE.zmx` and `import-zmx`.
    pub skipped: Vec<Unsupported>,
    /// The text encoding the file was read in.
    pub encoding: lexer::TextEncoding,
    /// Where each glass of the file was found (catalogue, file or built-in, formula).
    pub glasses: Vec<glass::GlassOrigin>,
    /// Remarks on the catalogues (a built-in catalogue standing in for a `GCAT` name with a date suffix).
    pub notes: Vec<String>,
    /// The surfaces' `COAT` records (also in `skipped`): the sequential trace has no coatings, but the
    /// Fresnel ghost paths (`ghosts`, `render --ghosts`) would change with them, so those commands say which
    /// were dropped ([`ZmxImport::coating_note`]).
    pub skipped_coatings: Vec<SkippedCoating>,
}

/// A `COAT` record of a surface, skipped by the reader.
#[derive(Clone, Debug, PartialEq)]
pub struct SkippedCoating {
    /// The file's surface number (`SURF n`: the spec's surface index).
    pub surface: usize,
    /// 1-based line of the record.
    pub line: usize,
    /// The coating's name as written (`MGF2`, `I.0`); empty when the record has none.
    pub name: String,
}

impl ZmxImport {
    /// A note for the commands whose numbers coatings change (the Fresnel ghost paths): the file's `COAT`
    /// records the reader skipped, so that uncoated ghost energies are not read as the coated design's
    /// (round 21: an ideal AR coating `I.0` would remove a ghost that `ghosts` reported unchanged). `None`
    /// when the file has no coating.
    pub fn coating_note(&self, command: &str) -> Option<String> {
        if self.skipped_coatings.is_empty() {
            return None;
        }
        let list: Vec<String> = self
            .skipped_coatings
            .iter()
            .map(|c| format!("surface {} `COAT {}` (line {})", c.surface, c.name, c.line))
            .collect();
        Some(format!(
            "the .zmx file's coatings are not read ({}): {command} treats every face as bare (uncoated Fresnel reflection); give the spec's `coating` of each surface (export-spec, then `coating = {{ reflectance = R }}` or `{{ mgf2_quarter_wave_nm = λ }}`) to model them",
            list.join(", ")
        ))
    }
}

/// Where each glass of a spec comes from, as the system build resolves it (the built-in subset, then the
/// spec's `glass_catalogs` entries, later ones winning): one row per surface with a glass.
pub fn glass_origins(spec: &SystemSpec) -> Result<Vec<GlassOrigin>> {
    let entries = &spec.glass_catalogs;
    let mut out = Vec::new();
    for (i, s) in spec.surfaces.iter().enumerate() {
        let Some(m) = &s.material else { continue };
        if m.eq_ignore_ascii_case("air") || s.kind == crate::spec::SurfaceKind::CoordinateBreak {
            continue;
        }
        if let Some(o) = glass::origin(entries, m, 0, i).map_err(|e| Error::spec(&spec.name, e))? {
            out.push(o);
        }
    }
    Ok(out)
}

/// The glasses of a `.zmx` file and where each is found (the catalogue step of [`import_zmx`] alone: the
/// file is decoded and its `GCAT`, `DCGC`, `SURF` and `GLAS` records read, nothing else), with the
/// catalogue notes. Mirrors, model glasses and glass codes are not catalogue glasses and are left out. A
/// glass found in no catalogue is an error naming its line, surface and name.
pub fn zmx_glasses(bytes: &[u8], source_name: &str, source_path: Option<&Path>, options: &ZmxOptions) -> Result<(Vec<GlassOrigin>, Vec<String>)> {
    let fail = |m: String| Error::spec(source_name, m);
    let (text, _) = lexer::decode_with_encoding(bytes, source_name)?;
    let mut gcat: Option<(usize, Vec<String>)> = None;
    let mut dcgc: Vec<String> = Vec::new();
    let mut uses: Vec<(usize, usize, String)> = Vec::new();
    let mut surface: Option<usize> = None;
    let recs = lexer::records(&text);
    for r in &recs {
        match r.keyword.as_str() {
            "GCAT" => gcat = Some((r.line, r.args.clone())),
            "DCGC" => dcgc.push(r.rest.trim().trim_matches('"').to_string()),
            "SURF" => surface = Some(records::int(r, 0).map_err(&fail)?.max(0) as usize),
            "GLAS" => {
                let name = r.args.first().cloned().unwrap_or_default();
                let catalogue_glass = !(name.is_empty() || name.eq_ignore_ascii_case("MIRROR") || name == "___BLANK" || name.chars().all(|c| c.is_ascii_digit() || c == '.'));
                if let (Some(n), true) = (surface, catalogue_glass) {
                    uses.push((r.line, n, name));
                }
            }
            _ => {}
        }
    }
    // A whole file's glass on its image surface (the last `SURF`) is skipped by `import_zmx`: not one of its glasses.
    if let (Some(image), true) = (surface, records::records_follow_surfaces(&recs)) {
        uses.retain(|(_, n, _)| *n != image);
    }
    let dirs = glass::search_dirs(source_path, &options.glass_dirs).map_err(&fail)?;
    let res = glass::resolve(gcat.as_ref(), &dcgc, &options.glass_catalogs, &uses, &dirs).map_err(&fail)?;
    Ok((res.glasses, res.notes))
}

/// An error of building a system read from a `.zmx` file, with the fixes a `.zmx` user has: a glass's
/// wavelength range is widened by the file's `DCWP allow_extrapolation` record, not by a spec's
/// `wavelength_policy` (which the message of a spec names).
pub fn with_zmx_hints(e: Error) -> Error {
    use crate::materials::{EXTRAPOLATION_HINT, EXTRAPOLATION_HINT_ZMX};
    match e {
        Error::System { system, surface, field, message } => {
            Error::System { system, surface, field, message: message.replace(EXTRAPOLATION_HINT, EXTRAPOLATION_HINT_ZMX) }
        }
        Error::Spec { source_name, message } => Error::Spec { source_name, message: message.replace(EXTRAPOLATION_HINT, EXTRAPOLATION_HINT_ZMX) },
        // A wavelength outside a glass's range met after the build (`trace --wavelength-nm`, Python `trace`):
        // the material error's own text, with the file's fix.
        Error::Material(m) if m.to_string().contains(EXTRAPOLATION_HINT) => Error::Invalid(m.to_string().replace(EXTRAPOLATION_HINT, EXTRAPOLATION_HINT_ZMX)),
        other => other,
    }
}

/// Import a `.zmx` file from disk (see [`import_zmx`]).
pub fn import_zmx_file(path: impl AsRef<Path>, options: &ZmxOptions) -> Result<ZmxImport> {
    let path = path.as_ref();
    let name = path.display().to_string();
    // A regular file of bounded size (a FIFO or /dev/zero is refused at once, docs/robustness.md).
    let bytes = crate::io::input::read_input(path, crate::limits::MAX_TEXT_FILE_BYTES)?;
    import_zmx(&bytes, &name, Some(path), options)
}

/// The `SURF` records of a file's text, counted before its records are gathered (a record costs ~200 B, a
/// built surface ~4 kB): more than [`crate::limits::MAX_SURFACES`] is refused, naming the line of the first one
/// beyond it and the file's count (round 19: a 7.5 MB file of 4·10⁵ `SURF`/`DISZ` pairs peaked at 1.58 GB).
fn check_surface_records(text: &str) -> std::result::Result<(), String> {
    let mut count = 0usize;
    let mut first_over = None;
    for (i, line) in text.lines().enumerate() {
        if line.split_whitespace().next() == Some("SURF") {
            count += 1;
            if count == crate::limits::MAX_SURFACES + 1 {
                first_over = Some(i + 1);
            }
        }
    }
    match (first_over, crate::limits::check_surface_count(count)) {
        (Some(line), Err(m)) => Err(format!("line {line} `SURF`: {m}")),
        _ => Ok(()),
    }
}

/// Import `.zmx` bytes read from `source_name` (`source_path`, when given, is where `GCAT` catalogues
/// are looked for first). Errors name the file, the line and the keyword.
pub fn import_zmx(bytes: &[u8], source_name: &str, source_path: Option<&Path>, options: &ZmxOptions) -> Result<ZmxImport> {
    let fail = |m: String| Error::spec(source_name, m);
    let (text, encoding) = lexer::decode_with_encoding(bytes, source_name)?;
    // A last record without a line break is read (rayoptics and OpticStudio open such files), once it is
    // known to be whole (checked below, after the records are read).
    let final_break = text.ends_with('\n');
    check_surface_records(&text).map_err(&fail)?;
    let recs = lexer::records(&text);
    let mut header = Header::default();
    let mut unsupported: Vec<Unsupported> = Vec::new();
    let mut skipped: Vec<Unsupported> = Vec::new();
    let mut skipped_coatings: Vec<SkippedCoating> = Vec::new();
    let mut blocks: Vec<(SurfaceBlock, usize)> = Vec::new(); // (block, number of records)
    // Records defined once (records::once_key) and where: (line, keyword).
    let mut seen: std::collections::HashMap<(Option<usize>, String), (usize, String)> = std::collections::HashMap::new();
    for r in &recs {
        if r.keyword == "SURF" {
            let n = records::int(r, 0).map_err(&fail)?;
            if n != blocks.len() as i64 {
                return Err(fail(format!("line {} `SURF`: surface {n} out of order (expected {})", r.line, blocks.len())));
            }
            blocks.push((SurfaceBlock { number: n as usize, line: r.line, ..Default::default() }, 0));
            continue;
        }
        // Records without optics, wherever they are: skipped and listed.
        let kw = r.keyword.as_str();
        let no_optics = if records::COSMETIC.contains(&kw) {
            Some(records::cosmetic_reason(kw).to_string())
        } else if kw == "TOL" && r.args.first().map(String::as_str) != Some("TOFF") {
            Some(format!("tolerance operand `{}` (tolerancing data, not the nominal system)", r.args.first().cloned().unwrap_or_default()))
        } else if kw == "HYPR" && r.args.iter().all(|a| a == "0") {
            // OpticStudio's hyper-hemispheric option, off (its default): nothing changes. On, it is refused.
            Some("the hyper-hemispheric option, off (OpticStudio's default)".to_string())
        } else if (kw == "IWDP" && r.args.iter().all(|a| a == "0")) || (kw == "EERA" && r.args.first().map(String::as_str) == Some("0")) {
            // System records OpticStudio 2022 and later write (`IWDP 0`, `EERA 0 0 0 10 10`) that no public
            // description of the format documents; rayoptics and optiland read such files without them. With
            // a leading 0, as in the public files met (tests/fixtures/zmx), they are listed; any other value
            // is refused ("system keyword not modelled"), since what it would change is unknown.
            Some("OpticStudio 2022+ system record, undocumented; read only with its leading value 0, as public files hold it".to_string())
        } else if records::is_merit_row(r, !blocks.is_empty(), records::SURFACE_KEYWORDS.contains(&kw)) {
            Some("merit-function operand (an optimisation target)".to_string())
        } else {
            None
        };
        if let Some(reason) = no_optics {
            if kw == "COAT" {
                if let Some((b, _)) = blocks.last() {
                    skipped_coatings.push(SkippedCoating { surface: b.number, line: r.line, name: r.args.join(" ") });
                }
            }
            skipped.push(Unsupported { line: r.line, keyword: r.keyword.clone(), reason });
            if let Some((_, count)) = blocks.last_mut() {
                *count += 1;
            }
            continue;
        }
        // A record defined twice (in one surface, or the system data; two system apertures): refused, naming both.
        if let Some(key) = records::once_key(r, blocks.len().checked_sub(1)) {
            if let Some((l1, k1)) = seen.get(&key) {
                let what = match key.0 {
                    None if records::APERTURE_RECORDS.contains(&k1.as_str()) => {
                        format!("a second system aperture (the first: line {l1} `{k1}`); OpticStudio gives a system one aperture (ENPD, FNUM, OBNA or FLOA)")
                    }
                    None if *k1 != r.keyword => format!(
                        "{} given twice in the system data, as `{k1}` and `{}`, two spellings of one list (the first: line {l1} `{k1}`); OpticStudio writes it once",
                        key.1, r.keyword
                    ),
                    None => format!("{} given twice in the system data (the first: line {l1} `{k1}`); OpticStudio writes it once", key.1),
                    Some(n) => format!("{} given twice in surface {n} (the first: line {l1} `{k1}`); OpticStudio writes it once per surface", key.1),
                };
                return Err(fail(format!("line {} `{}`: {what}, and which one it means is unknown: remove one", r.line, r.keyword)));
            }
            seen.insert(key, (r.line, r.keyword.clone()));
        }
        if header.read(r, &mut unsupported).map_err(&fail)? {
            continue;
        }
        match blocks.last_mut() {
            Some((b, count)) => {
                *count += 1;
                b.read(r, &mut unsupported).map_err(&fail)?
            }
            None if records::COSMETIC.contains(&r.keyword.as_str()) => {}
            None if r.keyword.chars().all(|c| c.is_ascii_uppercase() || c.is_ascii_digit()) && r.keyword.len() == 4 => {
                unsupported.push(Unsupported { line: r.line, keyword: r.keyword.clone(), reason: "system keyword not modelled".into() })
            }
            None => {
                return Err(fail(format!(
                    "line {}: `{}` is not a .zmx record (a record is a 4-letter upper-case keyword and its arguments): not a Zemax lens file",
                    r.line, r.keyword
                )))
            }
        }
    }
    if !final_break {
        // The last line has no line break: its record must be whole. Cut in the middle means: a keyword the
        // reader does not know (`MNU`), an unclosed quote, or fewer arguments than the keyword needs (what its
        // reader needs — a missing one is refused above — or, for keywords without optics, what OpticStudio
        // writes: `MNUM 1 1`). A number cut between two digits reads as a shorter number and cannot be told.
        if let Some(last) = recs.last() {
            let cut = |why: String| {
                fail(format!(
                    "line {} `{}`: the file ends without a line break in a record cut in the middle ({why}): truncated",
                    last.line, last.keyword
                ))
            };
            if last.rest.matches('"').count() % 2 == 1 {
                return Err(cut("an unclosed quote".into()));
            }
            if unsupported.iter().any(|u| u.line == last.line && (u.reason.ends_with("keyword not modelled") || u.reason.starts_with("not a .zmx record"))) {
                return Err(cut("not a keyword of a .zmx file".into()));
            }
            if let Some(n) = records::written_arity(&last.keyword) {
                if last.args.len() < n {
                    return Err(cut(format!("{} of the {n} arguments OpticStudio writes", last.args.len())));
                }
            }
        }
    }
    if blocks.is_empty() {
        return Err(fail("no `SURF` record: not a Zemax .zmx lens file, or truncated before its surfaces".into()));
    }
    if let Some((b, _)) = blocks.iter().find(|(_, n)| *n == 0) {
        return Err(fail(format!("line {} `SURF {}`: the surface has no records: truncated", b.line, b.number)));
    }
    if blocks.len() < 3 {
        return Err(fail(format!("{} surfaces: a system needs an object, a surface and an image (truncated?)", blocks.len())));
    }
    // A file cut between two surfaces reads whole: its last surface becomes the image. OpticStudio writes the
    // image surface in air with `DISZ 0`, and records after the surfaces (`TOL`, `MNUM`, merit rows…); a file
    // whose last surface has a glass or a thickness, with nothing after it, was cut inside the lens. In a whole
    // file a glass on the image is never traversed (nothing follows the image): skipped and listed.
    let image = &mut blocks.last_mut().expect("three blocks").0;
    if !records::records_follow_surfaces(&recs) {
        let why = match (&image.glass, image.disz) {
            (Some((line, g)), _) => Some(format!("line {line} `GLAS {g}`: the image would be inside glass")),
            (None, Some((line, t))) if t != 0.0 => Some(format!("line {line} `DISZ {t}`: the image would have a thickness")),
            _ => None,
        };
        if let Some(why) = why {
            return Err(fail(format!(
                "the file ends in surface {} (line {}) with nothing after it, and {why}; OpticStudio writes the image surface in air with `DISZ 0`, followed by other records: the file looks truncated",
                image.number, image.line
            )));
        }
    } else if let Some((line, g)) = image.glass.take() {
        skipped.push(Unsupported { line, keyword: "GLAS".into(), reason: format!("glass `{g}` on the image surface: nothing follows the image, so no ray enters it") });
    }
    // Solves and pickups read as their saved values: listed with the records that carry no optics.
    for (b, _) in &blocks {
        skipped.extend(b.frozen.iter().cloned());
    }
    skipped.sort_by_key(|u| u.line);
    let mut surfaces = Vec::with_capacity(blocks.len());
    for (b, _) in &blocks {
        let s = b.build(&mut unsupported).map_err(&fail)?;
        // The value checks the system's build applies to every cell (limits::check_resolved_cell), here by line:
        // the build named neither the file nor the record (`surface 1 (rotation_radius_mm): …`; a held-out
        // battery, round 10).
        for col in crate::spec::surface::COLUMNS {
            let Some(v) = s.cell(col).map(|c| c.value) else { continue };
            if *col == "thickness_mm" && !v.is_finite() {
                continue; // INFINITY on the object; the others are refused below, by their own message
            }
            if let Err(m) = crate::limits::check_resolved_cell(col, v) {
                let (line, kw) = b.record_of(col, v);
                return Err(fail(format!("line {line} `{kw}`: surface {} {m}", b.number)));
            }
        }
        surfaces.push(s);
    }
    if let Some((line, t)) = blocks[0].0.disz {
        if t == f64::NEG_INFINITY {
            return Err(fail(format!("line {line} `DISZ`: object distance -INFINITY (an object at infinity is `DISZ INFINITY`)")));
        }
    }
    for (b, _) in &blocks {
        if let Some((line, t)) = b.disz {
            if !t.is_finite() && b.number != 0 {
                return Err(fail(format!("line {line} `DISZ`: surface {} thickness {t} is not finite", b.number)));
            }
        }
    }

    // Fields: FTYP 0 angles (degrees), 1 object heights, 2 paraxial and 3 real image heights (mm).
    let (ftype, nf, nw) = match header.ftyp {
        Some((_, t, nf, nw)) => (Some(t), Some(nf), Some(nw)),
        None => (None, None, None),
    };
    let nf = nf.unwrap_or(header.xfln.len().max(header.yfln.len()));
    let nf = if header.old_fields { header.xfln.len().max(header.yfln.len()) } else { nf };
    let mut fields = Vec::with_capacity(nf);
    for i in 0..nf {
        let (x, y) = (header.xfln.get(i).copied(), header.yfln.get(i).copied());
        match (x, y) {
            (Some(x), Some(y)) => fields.push([x, y]),
            _ => return Err(fail(format!("field {} of {nf}: XFLN/YFLN have too few entries (truncated?)", i + 1))),
        }
    }
    let ftyp_line = header.ftyp.map(|f| f.0).unwrap_or(0);
    let at_infinity = blocks[0].0.disz.is_some_and(|(_, t)| t == f64::INFINITY);
    // An aperture on the object surface at infinity has no effect (rays start on surface 1's vertex plane as
    // plane waves; none meets the object surface): refused as not modelled (dropped and listed with
    // --ignore-unsupported) rather than kept, shown by `info` and silently without effect.
    if at_infinity && surfaces[0].aperture.is_some() {
        let (line, keyword) = blocks[0].0.aperture_at.clone().unwrap_or((blocks[0].0.line, "CLAP".into()));
        unsupported.push(Unsupported {
            line,
            keyword,
            reason: "an aperture on the object surface (surface 0), which is at infinity: no ray meets that surface, so the aperture would have no effect; put it on a surface the rays cross".into(),
        });
        surfaces[0].aperture = None;
    }
    let field_type = match ftype {
        Some(0) => FieldType::Angle,
        Some(1) => FieldType::ObjectHeight,
        Some(2) => FieldType::ParaxialImageHeight,
        Some(3) => FieldType::RealImageHeight,
        // On-axis fields are the same single field whatever their type.
        _ if fields.iter().all(|p| p[0] == 0.0 && p[1] == 0.0) => {
            if at_infinity {
                FieldType::Angle
            } else {
                FieldType::ObjectHeight
            }
        }
        // Never skipped (not even with --ignore-unsupported): off-axis fields of another type (4: theodolite
        // angles) read as ordinary angles or heights would be other fields, not a dropped item.
        Some(t) => {
            return Err(fail(format!(
                "line {ftyp_line} `FTYP`: field type {t} ({}): diffcassi reads angles (0), object heights (1), paraxial (2) and real (3) image heights, and fields of another type cannot be read as one of these (--ignore-unsupported does not apply); change the field type in OpticStudio (System Explorer → Fields → Type) and save the file again",
                if t == 4 { "theodolite angles" } else { "not a field type of OpticStudio" }
            )))
        }
        None => return Err(fail("fields given without `FTYP`: their type (angle or height) is unknown".into())),
    };
    // Each field the file defines, by line, within the limits of the command line's fields: an angle within
    // (−90, 90)° (`--field-deg`), a height (object, paraxial or real image) within ±1e6 mm (`--field-mm`).
    // A 1e300 mm image height was converted to a 90° field and traced.
    for (i, p) in fields.iter().enumerate() {
        for (v, (line, kw)) in [(p[0], &header.xfln_at), (p[1], &header.yfln_at)] {
            let why = if field_type == FieldType::Angle {
                (v.abs() >= 90.0).then(|| format!("angle {}° is outside (-90, 90) degrees (the range of --field-deg)", crate::limits::fmt_num(v)))
            } else {
                (v.abs() > crate::limits::MAX_LENGTH_MM).then(|| {
                    format!("{} {} mm is outside ±{:e} mm (the range of --field-mm)", field_type.label(), crate::limits::fmt_num(v), crate::limits::MAX_LENGTH_MM)
                })
            };
            if let Some(why) = why {
                return Err(fail(format!("line {line} `{kw}`: field {} {why}", i + 1)));
            }
        }
    }
    if fields.is_empty() {
        fields.push([0.0, 0.0]);
    }
    if at_infinity && field_type == FieldType::ObjectHeight && fields.iter().any(|p| *p != [0.0, 0.0]) {
        let disz_line = blocks[0].0.disz.map(|d| d.0).unwrap_or(0);
        return Err(fail(format!(
            "line {ftyp_line} `FTYP`: object heights (type 1) with the object at infinity (line {disz_line} `DISZ` INFINITY on surface 0): an object at infinity takes field angles (type 0) or image heights"
        )));
    }
    // Vignetting factors, one column per record and one entry per field (src/system/vignetting.rs): the
    // decentres VDX, VDY and compressions VCX, VCY are read; the angle VAN (rotation of the vignetted
    // pupil) is not modelled and is refused when it is not zero.
    let mut vignetting = vec![[0.0f64; 4]; fields.len()];
    for (line, k, vals) in &header.vignetting {
        // One value per field, as for `XFLN`/`YFLN` (refused when too short): a short list left the last fields'
        // factors 0 silently. The on-axis default field (none listed) needs none.
        if vals.len() < nf {
            return Err(fail(format!(
                "line {line} `{k}`: {} value(s) for {nf} fields (one per field, as `XFLN`/`YFLN` give them): too few (truncated?)",
                vals.len()
            )));
        }
        let column = ["VDX", "VDY", "VCX", "VCY"].iter().position(|c| k.starts_with(c));
        let Some(col) = column else {
            if vals.iter().take(fields.len()).any(|v| *v != 0.0) {
                unsupported.push(Unsupported {
                    line: *line,
                    keyword: k.clone(),
                    reason: "vignetting angle VAN ≠ 0 (a rotated vignetted pupil) is not modelled; the decentre and compression factors are".into(),
                });
            }
            continue;
        };
        for (i, v) in vals.iter().take(fields.len()).enumerate() {
            if col >= 2 && *v >= 1.0 {
                return Err(fail(format!("line {line} `{k}`: field {} compression factor {} ≥ 1 compresses the pupil to nothing (factors are < 1)", i + 1, crate::limits::fmt_num(*v))));
            }
            vignetting[i][col] = *v;
        }
    }
    let vignetting_factors = if vignetting.iter().all(|v| *v == [0.0; 4]) { Vec::new() } else { vignetting };
    let (fields_mm, fields_deg) = if field_type == FieldType::Angle { (Vec::new(), fields) } else { (fields, Vec::new()) };

    // Wavelengths (µm in the file, nm in the spec), each with the line and keyword it came from.
    let waves: Vec<(f64, f64, usize, &str)> = if !header.wavm.is_empty() {
        let mut w = header.wavm.clone();
        w.sort_by_key(|x| x.0);
        let n = nw.unwrap_or(w.len());
        let mut out = Vec::new();
        for i in 1..=n {
            match w.iter().find(|x| x.0 == i) {
                Some(x) => out.push((x.1, x.2, x.3, "WAVM")),
                None => return Err(fail(format!("wavelength {i} of {n} (FTYP): no `WAVM {i}` record (truncated?)"))),
            }
        }
        out
    } else {
        // As for `WAVM` (a missing `WAVM i` is refused): a `WAVL` list shorter than FTYP's count of wavelengths
        // was read with fewer wavelengths, silently. A longer one is how old files write it (the unused ones after).
        if let (Some(n), Some((fl, ..))) = (nw, header.ftyp) {
            if header.wavl_line != 0 && header.wavl.len() < n {
                return Err(fail(format!(
                    "line {} `WAVL`: {} wavelength(s) for the {n} of line {fl} `FTYP` (its fourth value): too few (truncated?)",
                    header.wavl_line,
                    header.wavl.len()
                )));
            }
        }
        let n = nw.unwrap_or(header.wavl.len()).min(header.wavl.len());
        (0..n).map(|i| (header.wavl[i], header.wwgt.get(i).copied().unwrap_or(1.0), header.wavl_line, "WAVL")).collect()
    };
    if waves.is_empty() {
        return Err(fail("no wavelength (`WAVM` or `WAVL` records)".into()));
    }
    // Each wavelength within the range of the command line's --wavelength-nm, by line (`WAVM 1 1e300` was
    // printed with 309 digits by the glass check, without its line).
    let (lo, hi) = crate::limits::WAVELENGTH_RANGE_NM;
    for (um, _, line, kw) in &waves {
        if !(*um * 1000.0 >= lo && *um * 1000.0 <= hi) {
            return Err(fail(format!(
                "line {line} `{kw}`: wavelength {} µm is outside {}–{} µm ({lo}–{hi} nm, the range of --wavelength-nm)",
                crate::limits::fmt_num(*um),
                lo / 1000.0,
                hi / 1000.0
            )));
        }
    }
    if waves.iter().any(|w| w.1 != waves[0].1) {
        let line = header.wavm.first().map(|x| x.3).unwrap_or(0);
        unsupported.push(Unsupported { line, keyword: "WAVM".into(), reason: "unequal wavelength weights: diffcassi's analyses are per wavelength and keep no weights".into() });
    }
    let wavelengths_nm: Vec<f64> = waves.iter().map(|w| w.0 * 1000.0).collect();
    let primary = match header.pwav {
        Some((line, p)) => {
            if p < 1 || p > wavelengths_nm.len() {
                return Err(fail(format!("line {line} `PWAV`: primary wavelength {p} of {} wavelengths", wavelengths_nm.len())));
            }
            wavelengths_nm[p - 1]
        }
        None => wavelengths_nm[0],
    };

    // Glass catalogues: files, the built-in subset, built-in vendor catalogues standing in for missing files.
    let dirs = glass::search_dirs(source_path, &options.glass_dirs).map_err(&fail)?;
    // Catalogue glasses only: a mirror is no glass of any catalogue.
    let uses: Vec<(usize, usize, String)> = blocks
        .iter()
        .filter_map(|(b, _)| b.glass.as_ref().map(|(l, g)| (*l, b.number, g.clone())))
        .filter(|u| !u.2.eq_ignore_ascii_case("MIRROR"))
        .collect();
    let resolution = glass::resolve(header.gcat.as_ref(), &header.catalog_paths, &options.glass_catalogs, &uses, &dirs).map_err(&fail)?;
    let catalog_paths = resolution.entries.clone();

    // `OBNA θ 1`, the object cone angle: NA = n sin θ, n the object space's index — exact for an object in air
    // (index `air_index`, 1 unless `DCAI` says otherwise). An object in glass, whose index depends on the
    // wavelength, is refused rather than given one wavelength's NA; at infinity a cone angle means nothing.
    if let Some((line, theta)) = header.cone_angle {
        if at_infinity {
            return Err(fail(format!(
                "line {line} `OBNA`: an object cone angle ({}°) with the object at infinity (surface 0 `DISZ INFINITY`): an object at infinity has no cone; use ENPD, FNUM or FLOA",
                crate::limits::fmt_num(theta)
            )));
        }
        match &blocks[0].0.glass {
            Some((gl, g)) if !g.eq_ignore_ascii_case("AIR") => {
                unsupported.push(Unsupported {
                    line,
                    keyword: "OBNA".into(),
                    reason: format!(
                        "object cone angle {}° with the object in glass `{g}` (line {gl}): NA = n sin θ with n the glass's index is not modelled; give the object-space NA (`OBNA na 0`)",
                        crate::limits::fmt_num(theta)
                    ),
                });
                header.aperture = None;
            }
            _ => {
                let n_air = header.air_index.unwrap_or(1.0);
                header.aperture = Some((line, SystemAperture::ObjectSpaceNa(n_air * theta.to_radians().sin())));
            }
        }
    }
    if let Some(line) = header.afocal_line {
        skipped.push(Unsupported {
            line,
            keyword: "FTYP".into(),
            reason: "afocal image space (the seventh value): in OpticStudio it changes how the analyses are reported (angles, not image positions), no ray; diffcassi reports positions on the image surface (mm)".into(),
        });
        skipped.sort_by_key(|u| u.line);
    }
    if !unsupported.is_empty() && !options.ignore_unsupported {
        let list: Vec<String> = unsupported.iter().map(|u| format!("  {u}")).collect();
        return Err(fail(format!(
            "{} item(s) diffcassi does not model (the file is refused rather than imported as a different system; `diffcassi import-zmx --ignore-unsupported` imports without them and lists them):\n{}",
            unsupported.len(),
            list.join("\n")
        )));
    }
    let aperture = header
        .aperture
        .map(|a| a.1)
        .ok_or_else(|| fail("no system aperture: an `ENPD` (entrance pupil diameter), `FNUM` (image-space F/#), `OBNA` (object-space NA) or `FLOA` (float by stop size) record is needed".into()))?;
    let name = if header.name.is_empty() {
        Path::new(source_name).file_stem().and_then(|s| s.to_str()).unwrap_or("imported").to_string()
    } else {
        header.name.clone()
    };
    let spec = SystemSpec {
        name,
        description: header.note.clone(),
        aperture,
        ray_aiming: header.ray_aiming,
        wavelengths_nm,
        primary_wavelength_nm: primary,
        fields_mm,
        field_type,
        fields_deg,
        vignetting_factors,
        wavelength_policy: if header.allow_extrapolation { WavelengthPolicy::AllowExtrapolation } else { WavelengthPolicy::Strict },
        air_index: header.air_index.unwrap_or(1.0),
        glass_catalogs: catalog_paths,
        surfaces,
        mechanics: None,
    };
    spec.validate().map_err(&fail)?;
    // The entrance pupil an F/# gives (EFL / F/#) is held to the limits of `ENPD` when the system is built;
    // checked here too, so that the error names the `FNUM` record and its line (`FNUM 1e-300` gave a 1e302 mm
    // pupil). Any other failure of the build is left to the build that uses the spec.
    if let (Some((line, _)), SystemAperture::ImageSpaceFNumber(_)) = (&header.aperture, spec.aperture) {
        if let Err(e) = crate::system::SequentialSystem::build(&spec) {
            let m = e.to_string();
            if let Some(k) = m.find("image-space F/#") {
                return Err(fail(format!("line {line} `FNUM`: {}", &m[k..])));
            }
        }
    }
    Ok(ZmxImport { spec, ignored: unsupported, skipped, encoding, glasses: resolution.glasses, notes: resolution.notes, skipped_coatings })
}
