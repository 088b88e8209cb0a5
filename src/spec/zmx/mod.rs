//! Zemax OpticStudio `.zmx` lens files, in and out (`docs/zemax-files.md`).
//!
//! [`import_zmx`] reads the sequential Lens Data Editor and system data of a `.zmx` file (UTF-16 with BOM,
//! UTF-8 or ASCII) into a [`SystemSpec`]; [`to_zmx`] writes any spec as `.zmx` text that reads back to the
//! identical spec (every value bit-identical). What the file holds that diffcassi does not model — a
//! surface type it lacks, non-sequential mode, multi-configuration or tolerance data, vignetting factors,
//! model glasses, OpticStudio solves — is never dropped silently: it is refused, listed by line and
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
pub use records::Unsupported;

use crate::error::{Error, Result};
use crate::materials::WavelengthPolicy;
use crate::spec::{FieldType, SystemSpec};
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
}

/// An imported file: the spec and what was skipped (empty unless `ignore_unsupported`).
#[derive(Clone, Debug)]
pub struct ZmxImport {
    pub spec: SystemSpec,
    pub ignored: Vec<Unsupported>,
}

/// Import a `.zmx` file from disk (see [`import_zmx`]).
pub fn import_zmx_file(path: impl AsRef<Path>, options: &ZmxOptions) -> Result<ZmxImport> {
    let path = path.as_ref();
    let name = path.display().to_string();
    // A regular file of bounded size (a FIFO or /dev/zero is refused at once, docs/robustness.md).
    let bytes = crate::io::input::read_input(path, crate::limits::MAX_TEXT_FILE_BYTES)?;
    import_zmx(&bytes, &name, Some(path), options)
}

/// Import `.zmx` bytes read from `source_name` (`source_path`, when given, is where `GCAT` catalogues
/// are looked for first). Errors name the file, the line and the keyword.
pub fn import_zmx(bytes: &[u8], source_name: &str, source_path: Option<&Path>, options: &ZmxOptions) -> Result<ZmxImport> {
    let fail = |m: String| Error::spec(source_name, m);
    let text = lexer::decode(bytes, source_name)?;
    if !text.ends_with('\n') {
        let last = text.lines().count();
        return Err(fail(format!(
            "line {last}: the file does not end with a line break: truncated (OpticStudio ends every record with one)"
        )));
    }
    let recs = lexer::records(&text);
    let mut header = Header::default();
    let mut unsupported: Vec<Unsupported> = Vec::new();
    let mut blocks: Vec<(SurfaceBlock, usize)> = Vec::new(); // (block, number of records)
    for r in &recs {
        if r.keyword == "SURF" {
            let n = records::int(r, 0).map_err(&fail)?;
            if n != blocks.len() as i64 {
                return Err(fail(format!("line {} `SURF`: surface {n} out of order (expected {})", r.line, blocks.len())));
            }
            blocks.push((SurfaceBlock { number: n as usize, line: r.line, ..Default::default() }, 0));
            continue;
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
    if blocks.is_empty() {
        return Err(fail("no `SURF` record: not a Zemax .zmx lens file, or truncated before its surfaces".into()));
    }
    if let Some((b, _)) = blocks.iter().find(|(_, n)| *n == 0) {
        return Err(fail(format!("line {} `SURF {}`: the surface has no records: truncated", b.line, b.number)));
    }
    if blocks.len() < 3 {
        return Err(fail(format!("{} surfaces: a system needs an object, a surface and an image (truncated?)", blocks.len())));
    }
    let mut surfaces = Vec::with_capacity(blocks.len());
    for (b, _) in &blocks {
        surfaces.push(b.build(&mut unsupported).map_err(&fail)?);
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
        Some(t) => {
            unsupported.push(Unsupported {
                line: ftyp_line,
                keyword: "FTYP".into(),
                reason: format!("field type {t} (theodolite angles or another type): diffcassi reads angles (0), object heights (1), paraxial (2) and real (3) image heights"),
            });
            if at_infinity {
                FieldType::Angle
            } else {
                FieldType::ObjectHeight
            }
        }
        None => return Err(fail("fields given without `FTYP`: their type (angle or height) is unknown".into())),
    };
    if fields.is_empty() {
        fields.push([0.0, 0.0]);
    }
    if at_infinity && field_type == FieldType::ObjectHeight && fields.iter().any(|p| *p != [0.0, 0.0]) {
        let disz_line = blocks[0].0.disz.map(|d| d.0).unwrap_or(0);
        return Err(fail(format!(
            "line {ftyp_line} `FTYP`: object heights (type 1) with the object at infinity (line {disz_line} `DISZ` INFINITY on surface 0): an object at infinity takes field angles (type 0) or image heights"
        )));
    }
    let (fields_mm, fields_deg) = if field_type == FieldType::Angle { (Vec::new(), fields) } else { (fields, Vec::new()) };
    for (line, k, vals) in &header.vignetting {
        if vals.iter().take(nf).any(|v| *v != 0.0) {
            unsupported.push(Unsupported { line: *line, keyword: k.clone(), reason: "vignetting factors are not modelled (they change the ray sampling)".into() });
        }
    }

    // Wavelengths (µm in the file, nm in the spec).
    let waves: Vec<(f64, f64)> = if !header.wavm.is_empty() {
        let mut w = header.wavm.clone();
        w.sort_by_key(|x| x.0);
        let n = nw.unwrap_or(w.len());
        let mut out = Vec::new();
        for i in 1..=n {
            match w.iter().find(|x| x.0 == i) {
                Some(x) => out.push((x.1, x.2)),
                None => return Err(fail(format!("wavelength {i} of {n} (FTYP): no `WAVM {i}` record (truncated?)"))),
            }
        }
        out
    } else {
        let n = nw.unwrap_or(header.wavl.len()).min(header.wavl.len());
        (0..n).map(|i| (header.wavl[i], header.wwgt.get(i).copied().unwrap_or(1.0))).collect()
    };
    if waves.is_empty() {
        return Err(fail("no wavelength (`WAVM` or `WAVL` records)".into()));
    }
    for (um, _) in &waves {
        if *um <= 0.0 {
            return Err(fail(format!("wavelength {um} µm: must be > 0")));
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

    // Glass catalogues.
    let mut catalog_paths = header.catalog_paths.clone();
    let mut missing: Vec<String> = Vec::new();
    let dirs = glass::search_dirs(source_path, &options.glass_dirs);
    if let Some((_, names)) = &header.gcat {
        for n in names {
            let covered = catalog_paths.iter().any(|p| Path::new(p).file_stem().and_then(|s| s.to_str()).is_some_and(|s| s.eq_ignore_ascii_case(n)));
            if covered {
                continue;
            }
            match glass::find_catalog(n, &dirs) {
                Some(p) => catalog_paths.push(p.display().to_string()),
                None => missing.push(n.clone()),
            }
        }
    }
    let catalog = glass::load(&catalog_paths).map_err(&fail)?;
    for (b, _) in &blocks {
        if let Some((line, g)) = &b.glass {
            if !catalog.contains(g) {
                let gcat = header.gcat.as_ref().map(|g| format!(" (`GCAT` line {})", g.0)).unwrap_or_default();
                let why = if missing.is_empty() {
                    "no catalogue of the file holds it".to_string()
                } else {
                    format!(
                        "the file's catalogue(s) {} were not found{gcat}: put {} in {} or set DIFFCASSI_GLASS_DIR",
                        missing.join(", "),
                        missing.iter().map(|m| format!("{m}.AGF")).collect::<Vec<_>>().join(", "),
                        dirs.iter().map(|d| d.display().to_string()).collect::<Vec<_>>().join(", ")
                    )
                };
                return Err(fail(format!("line {line} `GLAS`: glass `{g}` of surface {} is in none of the loaded catalogues (built-in SCHOTT subset{}): {why}", b.number,
                    catalog_paths.iter().map(|p| format!(", {p}")).collect::<String>())));
            }
        }
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
        wavelength_policy: if header.allow_extrapolation { WavelengthPolicy::AllowExtrapolation } else { WavelengthPolicy::Strict },
        air_index: header.air_index.unwrap_or(1.0),
        glass_catalogs: catalog_paths,
        surfaces,
        mechanics: None,
    };
    spec.validate().map_err(&fail)?;
    Ok(ZmxImport { spec, ignored: unsupported })
}
