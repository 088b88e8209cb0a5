//! Vendor glass catalogues built into the binary: SCHOTT, OHARA, HOYA, CDGM, SUMITA, HIKARI, and the
//! legacy SCHOTT1980 (the obsolete SCHOTT glasses of old lens files: see [below](#legacy-catalogues)).
//!
//! So that a lens file naming `GCAT OHARA HOYA …` opens without the user's copy of OpticStudio's `.AGF`
//! files, the optical glasses of these vendors are embedded (`data/glass/<NAME>.agf`, 1613 glasses,
//! ≈ 330 kB of text, and one tabulated glass, SCHOTT's B270: see [below](#tabulated-glasses)) and parsed by
//! the ordinary AGF reader ([`super::agf`]) when asked for. They were
//! converted by `scripts/convert_refractiveindex_glass.py` from the refractiveindex.info database
//! (<https://github.com/polyanskiy/refractiveindex.info-database>, commit
//! `ff11b5897ef0754b15d939d921eb6c745693cbd1`, 2026-06-14, public domain under CC0 1.0), which holds each
//! vendor's Zemax-catalogue formula and coefficients as the vendor printed them; the numbers are copied as
//! text, so the f64 read here is the one the source denotes. Each glass keeps its source in its `GC`
//! comment ([`super::GlassInfo::comment`]): the database page and the vendor catalogue it came from (e.g.
//! `specs/ohara/optical/S-BSL7.yml; OHARA Zemax catalog 2017-11-30`).
//!
//! # Tabulated glasses
//!
//! A few vendor glasses are published with no dispersion formula, only n at a handful of spectral lines:
//! SCHOTT's B 270 (the glass of Thorlabs' moulded aspheres; `specs/schott/misc/B270.yml`, from the B 270
//! datasheet of August 1993: n at 8 lines 0.43583–0.65627 µm, printed to 4 decimals). OpticStudio's AGF has
//! no tabulated formula, so these are carried beside the AGF text in a small file of diffcassi's own,
//! `data/glass/<NAME>.tabulated`, written by the same script from the same database commit and merged into
//! the built-in catalogue of that name. A separate file rather than a diffcassi-only AGF record: the AGF
//! reader, and with it every user's AGF file, is untouched (an unknown record there is ignored as it always
//! was), and the converted AGF files are unchanged. Its records, one per line:
//!
//! | record | content |
//! |--------|---------|
//! | `CC` | catalogue comment (the database, its commit and licence) |
//! | `NM` | `name status` — starts a glass (status as in AGF: 0 standard … 4 melt) |
//! | `GC` | the source: database page and the vendor document (`specs/schott/misc/B270.yml; B 270 datasheet, August 1993`) |
//! | `TN` | `λ(µm) n` — one tabulated point, copied as the page prints it |
//!
//! Each glass becomes a [`DispersionFormula::Tabulated`] glass ([`super::TabulatedIndex`]: a monotone cubic
//! (PCHIP) in λ through every point, chosen because it passes through the datasheet's values exactly, has
//! a continuous dn/dλ, and never overshoots a 4-decimal table; see [`super::tabulated`]). Its valid range is
//! the table's: outside it the index is refused under the default strict policy, like any glass outside its
//! `LD` range. Its n_d and V_d (informative, shown by `info`) are the interpolant's at the d, F and C lines,
//! each taken at the nearest wavelength inside the table (B 270's table ends at the C line as the datasheet
//! prints it, 656.27 nm, 0.0025 nm short of 656.2725 nm). `info` names the formula `tabulated (8 points,
//! monotone cubic (PCHIP) in λ)`.
//!
//! # Legacy catalogues
//!
//! Lens files from before the lead- and arsenic-free glasses (around 2000) name glasses no vendor sells any
//! more: Edmund Optics' achromats name SCHOTT's `BK7` (OpticStudio's MISC catalogue), whose successor is
//! N-BK7. No public-domain source holds SCHOTT's own BK7 record, but one peer-reviewed publication holds the
//! 1980 catalogues as fits: P. N. Robb and R. I. Mercado, "Calculation of refractive indices using
//! Buchdahl's chromatic coordinate", Appl. Opt. 22, 1198 (1983), Table V — n = n0 + ν1 ω + ν2 ω² in
//! Buchdahl's chromatic coordinate ω = (λ − λ0)/(1 + 2.5 (λ − λ0)) about λ0 = 0.574 µm
//! ([`DispersionFormula::Buchdahl`]), over the visible region (taken as 400–700 nm). The built-in
//! **SCHOTT1980** catalogue holds its SCHOTT rows, converted by `scripts/convert_robb1983_glass.py` from the
//! table's text in the opticalglass package (M. J. Hayford, BSD 3-Clause), into `data/glass/SCHOTT1980.buchdahl`:
//!
//! | record | content |
//! |--------|---------|
//! | `CC` | catalogue comment (the paper, the text's source and licence, the model, the selection) |
//! | `NM` | `name status` — starts a glass (2: obsolete) |
//! | `GC` | the row's source and its check against the current glass |
//! | `BD` | `λ0(µm) n0 ν1 ν2`, copied as the table prints them |
//! | `LD` | `λmin λmax` (µm), the valid range |
//!
//! The table was transcribed from a scan and some of its rows are scrambled (SF57's n0 is 1.7638 against a
//! catalogue n_d of 1.84666), so only the rows that can be checked are kept: 69 rows within 1e-3, at every nm
//! of 400–700 nm, of the current SCHOTT glass of the same name or its `N-` successor (BK7 within 6.2e-6 of
//! N-BK7); 3 rows off by 2e-2 or more are refused and 166 rows with no current glass to check against are left
//! out (the script lists them). The base wavelength 0.574 µm is the paper's: about it the rows reproduce the
//! current glasses to a median 5.9e-5, about the d line to a median 3.3e-3 (checked below). The `.zmx` importer
//! takes a glass from SCHOTT1980 only when the file's catalogues and the built-in vendor catalogues have no
//! glass of that name, and says so ([`crate::spec::zmx`]); `info` names the catalogue, the formula and the
//! row. Under the default strict policy a wavelength outside 400–700 nm is refused by glass name and range.
//!
//! A spec refers to a built-in catalogue by the entry `builtin:NAME` in its `glass_catalogs` (any other
//! entry is an AGF file path); [`GlassCatalog::from_entry`] loads either. The built-in SCHOTT catalogue
//! carries the six glasses of [`GlassCatalog::builtin`] (typed in from SCHOTT.AGF, December 2024) over the
//! converted ones, so those six are the same wherever they come from.
//!
//! ```
//! use diffcassi::materials::{builtin_catalogs, GlassCatalog, D_LINE_NM};
//! let ohara = builtin_catalogs::catalog("ohara").unwrap().unwrap();
//! let g = ohara.get("S-BSL7")?;
//! assert_eq!(g.catalog, "OHARA");
//! assert!((g.refractive_index(D_LINE_NM)? - 1.516330).abs() <= 0.5e-6);
//! assert!(g.info.comment.starts_with("specs/ohara/optical/S-BSL7.yml"));
//! let same = GlassCatalog::from_entry("builtin:OHARA")?;
//! assert_eq!(same.get("s-bsl7")?.formula, g.formula);
//! assert!(builtin_catalogs::catalog("RPO").is_none());
//! let b270 = builtin_catalogs::catalog("SCHOTT").unwrap()?.get("B270")?;
//! assert_eq!(b270.refractive_index(587.56)?, 1.5230); // the datasheet's n at its d line
//! assert!(b270.refractive_index(700.0).is_err()); // beyond the datasheet's table
//! # Ok::<(), diffcassi::materials::MaterialError>(())
//! ```
use super::dispersion::{C_LINE_NM, D_LINE_NM, F_LINE_NM};
use super::{DispersionFormula, Glass, GlassCatalog, GlassStatus, MaterialError, TabulatedIndex};

/// The prefix of a `glass_catalogs` entry that names a built-in catalogue (`builtin:OHARA`).
pub const ENTRY_PREFIX: &str = "builtin:";

/// Where the built-in vendor catalogues come from (shown by `info`).
pub const SOURCE: &str = "refractiveindex.info database, commit ff11b58 (2026-06-14), CC0 1.0";

/// Where the legacy catalogues come from (shown by `info`).
pub const LEGACY_SOURCE: &str = "Robb & Mercado, Appl. Opt. 22, 1198 (1983), Table V, text of opticalglass 1.1.1 (BSD 3-Clause)";

/// The legacy catalogues (see [Legacy catalogues](self#legacy-catalogues)): name and `.buchdahl` text.
const LEGACY: [(&str, &str); 1] = [("SCHOTT1980", include_str!("../../data/glass/SCHOTT1980.buchdahl"))];

/// The built-in catalogues, in the order listed to users, with their AGF text and their tabulated glasses
/// (see the [module documentation](self); only SCHOTT has any).
const CATALOGS: [(&str, &str, Option<&str>); 6] = [
    ("SCHOTT", include_str!("../../data/glass/SCHOTT.agf"), Some(include_str!("../../data/glass/SCHOTT.tabulated"))),
    ("OHARA", include_str!("../../data/glass/OHARA.agf"), None),
    ("HOYA", include_str!("../../data/glass/HOYA.agf"), None),
    ("CDGM", include_str!("../../data/glass/CDGM.agf"), None),
    ("SUMITA", include_str!("../../data/glass/SUMITA.agf"), None),
    ("HIKARI", include_str!("../../data/glass/HIKARI.agf"), None),
];

/// The names of the built-in catalogues: the vendors', then the legacy ones.
pub fn names() -> impl Iterator<Item = &'static str> {
    vendor_names().chain(legacy_names())
}

/// The names of the built-in vendor catalogues (the ones a `GCAT` name stands for).
pub fn vendor_names() -> impl Iterator<Item = &'static str> {
    CATALOGS.iter().map(|c| c.0)
}

/// The names of the legacy catalogues (see [Legacy catalogues](self#legacy-catalogues)).
pub fn legacy_names() -> impl Iterator<Item = &'static str> {
    LEGACY.iter().map(|c| c.0)
}

/// The built-in catalogues (vendors' first, then the legacy ones) that hold a glass called `name` (any case):
/// what an error about an unknown glass can point to. Parses every built-in catalogue (≈ 1700 glasses).
pub fn holding(name: &str) -> Vec<&'static str> {
    names().filter(|n| catalog(n).and_then(|c| c.ok()).is_some_and(|c| c.contains(name))).collect()
}

/// Where the built-in catalogue `name` comes from ([`SOURCE`] or [`LEGACY_SOURCE`]).
pub fn source(name: &str) -> &'static str {
    if legacy_names().any(|n| n.eq_ignore_ascii_case(name)) {
        LEGACY_SOURCE
    } else {
        SOURCE
    }
}

/// The built-in catalogue `name` (any case), or `None` if there is none of that name.
pub fn catalog(name: &str) -> Option<Result<GlassCatalog, MaterialError>> {
    if let Some((cat, text)) = LEGACY.iter().find(|c| c.0.eq_ignore_ascii_case(name.trim())) {
        let mut c = GlassCatalog::new();
        return Some(add_buchdahl(&mut c, text, &format!("{cat}.buchdahl"), cat).map(|_| c));
    }
    let (cat, text, tabulated) = CATALOGS.iter().find(|c| c.0.eq_ignore_ascii_case(name.trim()))?;
    Some((|| {
        let mut c = GlassCatalog::from_agf_str(text, &format!("{cat}.agf"))?;
        if let Some(t) = tabulated {
            add_tabulated(&mut c, t, &format!("{cat}.tabulated"), cat)?;
        }
        if *cat == "SCHOTT" {
            c.merge(GlassCatalog::builtin());
        }
        Ok(c)
    })())
}

/// One glass of a diffcassi glass file (`.tabulated`, `.buchdahl`): its `NM` line, name, status, `GC`
/// comment and its other records as (line, record, rest of the line).
struct GlassText<'a> {
    line: usize,
    name: &'a str,
    status: GlassStatus,
    comment: &'a str,
    records: Vec<(usize, &'a str, &'a str)>,
}

/// Splits a diffcassi glass file into its `CC` comments and its glasses (`NM name status`, then `GC` and the
/// format's own `records`). Errors name `source_name` and the line; `format` names the file kind in them.
fn glass_texts<'a>(text: &'a str, source_name: &str, format: &str, records: &[&str]) -> Result<(Vec<String>, Vec<GlassText<'a>>), MaterialError> {
    let err = |line: usize, message: String| MaterialError::AgfParse { source_name: source_name.to_string(), line, message };
    let (mut comments, mut glasses) = (Vec::new(), Vec::<GlassText>::new());
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let raw = raw.trim();
        if raw.is_empty() {
            continue;
        }
        let (record, rest) = raw.split_once(char::is_whitespace).unwrap_or((raw, ""));
        let rest = rest.trim();
        match record {
            "CC" => comments.push(rest.to_string()),
            "NM" => {
                let fields: Vec<&str> = rest.split_whitespace().collect();
                let [name, status] = fields[..] else { return Err(err(line, format!("`NM {rest}`: expected `NM name status`"))) };
                let status = status
                    .parse::<i64>()
                    .ok()
                    .and_then(GlassStatus::from_code)
                    .ok_or_else(|| err(line, format!("glass {name}: status `{status}` is not 0..=4")))?;
                glasses.push(GlassText { line, name, status, comment: "", records: Vec::new() });
            }
            r if r == "GC" || records.contains(&r) => {
                let Some(g) = glasses.last_mut() else { return Err(err(line, format!("`{record}` record before the first `NM`"))) };
                if r == "GC" {
                    g.comment = rest;
                } else {
                    g.records.push((line, record, rest));
                }
            }
            other => return Err(err(line, format!("unknown record `{other}` (a {format} file has CC, NM, GC, {})", records.join(", ")))),
        }
    }
    Ok((comments, glasses))
}

/// Inserts `g` into `catalog`, refusing a name already there (one source per name).
fn insert_new(catalog: &mut GlassCatalog, mut g: Glass, t: &GlassText, source_name: &str, catalog_name: &str) -> Result<(), MaterialError> {
    if catalog.contains(&g.name) {
        return Err(MaterialError::AgfParse {
            source_name: source_name.to_string(),
            line: t.line,
            message: format!("glass {} is already in the {catalog_name} catalogue", t.name),
        });
    }
    g.info.status = Some(t.status);
    g.info.comment = t.comment.to_string();
    catalog.insert(g);
    Ok(())
}

/// Reads the tabulated glasses of `text` (the format of the [module documentation](self)) into `catalog`.
/// Errors name `source_name`, the line, the glass and the value; a glass already in the catalogue is an
/// error (one source per name).
pub fn add_tabulated(catalog: &mut GlassCatalog, text: &str, source_name: &str, catalog_name: &str) -> Result<(), MaterialError> {
    let err = |line: usize, message: String| MaterialError::AgfParse { source_name: source_name.to_string(), line, message };
    let (comments, glasses) = glass_texts(text, source_name, "tabulated-glass", &["TN"])?;
    for t in &glasses {
        let mut points = Vec::new();
        for &(line, _, rest) in &t.records {
            let num = |v: &str| v.parse::<f64>().ok().filter(|v| v.is_finite());
            match rest.split_whitespace().collect::<Vec<_>>()[..] {
                [w, n] => match (num(w), num(n)) {
                    (Some(w), Some(n)) => points.push((w, n)),
                    _ => return Err(err(line, format!("glass {}: `TN {rest}`: λ and n must be finite numbers", t.name))),
                },
                _ => return Err(err(line, format!("glass {}: `TN {rest}`: expected `TN λ(µm) n`", t.name))),
            }
        }
        let table = TabulatedIndex::new(points).map_err(|m| err(t.line, format!("glass {}: {m}", t.name)))?;
        let (lo, hi) = table.range_um();
        // n_d, V_d (informative): the interpolant at the d, F, C lines, each at the nearest λ of the table.
        let at = |nm: f64| table.index_um((nm / 1000.0).clamp(lo, hi));
        let nd = at(D_LINE_NM);
        let vd = (nd - 1.0) / (at(F_LINE_NM) - at(C_LINE_NM));
        let g = Glass::new(t.name, DispersionFormula::Tabulated(table), nd, vd, lo * 1000.0, hi * 1000.0, catalog_name);
        insert_new(catalog, g, t, source_name, catalog_name)?;
    }
    catalog.extend_comments(comments);
    Ok(())
}

/// Reads the Buchdahl glasses of `text` (the format of [Legacy catalogues](self#legacy-catalogues)) into
/// `catalog`. Errors name `source_name`, the line, the glass and the value; a glass already in the catalogue,
/// a glass without `BD` or `LD`, and a range that is not 0 < λmin < λmax are errors.
pub fn add_buchdahl(catalog: &mut GlassCatalog, text: &str, source_name: &str, catalog_name: &str) -> Result<(), MaterialError> {
    let err = |line: usize, message: String| MaterialError::AgfParse { source_name: source_name.to_string(), line, message };
    let (comments, glasses) = glass_texts(text, source_name, "Buchdahl glass", &["BD", "LD"])?;
    for t in &glasses {
        let (mut coefficients, mut range_um) = (None, None);
        for &(line, record, rest) in &t.records {
            let values: Option<Vec<f64>> = rest.split_whitespace().map(|v| v.parse::<f64>().ok().filter(|v| v.is_finite())).collect();
            match (record, values.as_deref()) {
                ("BD", Some(&[l0, n0, v1, v2])) if l0 > 0.0 && n0 >= 1.0 => coefficients = Some([l0, n0, v1, v2]),
                ("BD", _) => return Err(err(line, format!("glass {}: `BD {rest}`: expected `BD λ0(µm) n0 ν1 ν2`, finite, λ0 > 0 and n0 ≥ 1", t.name))),
                ("LD", Some(&[lo, hi])) if lo > 0.0 && lo < hi => range_um = Some((lo, hi)),
                _ => return Err(err(line, format!("glass {}: `LD {rest}`: expected `LD λmin λmax` (µm), 0 < λmin < λmax", t.name))),
            }
        }
        let (Some(c), Some((lo, hi))) = (coefficients, range_um) else {
            return Err(err(t.line, format!("glass {}: needs a `BD` and an `LD` record", t.name)));
        };
        let formula = DispersionFormula::Buchdahl(c);
        // n_d, V_d (informative): the model at the d, F and C lines.
        let nd = formula.refractive_index(D_LINE_NM);
        let vd = (nd - 1.0) / (formula.refractive_index(F_LINE_NM) - formula.refractive_index(C_LINE_NM));
        insert_new(catalog, Glass::new(t.name, formula, nd, vd, lo * 1000.0, hi * 1000.0, catalog_name), t, source_name, catalog_name)?;
    }
    catalog.extend_comments(comments);
    Ok(())
}

/// The catalogue name of a `builtin:NAME` entry, `None` for a file path.
pub fn entry_name(entry: &str) -> Option<&str> {
    let head = entry.get(..ENTRY_PREFIX.len())?;
    head.eq_ignore_ascii_case(ENTRY_PREFIX).then(|| &entry[ENTRY_PREFIX.len()..])
}

/// The built-in catalogue that stands in for a `GCAT` name: the name itself, or a dated variant of it
/// (`SUMITA_AUG2011`, `OHARA_2021-04`: a built-in name followed by `_`).
pub fn standing_in_for(gcat_name: &str) -> Option<&'static str> {
    vendor_names().find(|n| {
        gcat_name.eq_ignore_ascii_case(n)
            || (gcat_name.len() > n.len() && gcat_name.as_bytes()[n.len()] == b'_' && gcat_name[..n.len()].eq_ignore_ascii_case(n))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::materials::D_LINE_NM;

    #[test]
    fn every_builtin_catalogue_parses_and_names_its_source() {
        let mut total = 0;
        for n in vendor_names() {
            let c = catalog(n).unwrap().unwrap();
            assert!(c.len() > 150, "{n}: {}", c.len());
            total += c.len();
            assert!(c.comments().iter().any(|l| l.contains("ff11b5897ef0754b15d939d921eb6c745693cbd1")), "{n}");
            for g in c.iter() {
                if n != "SCHOTT" || !GlassCatalog::builtin().contains(&g.name) {
                    assert!(g.info.comment.starts_with(&format!("specs/{}/", n.to_ascii_lowercase())), "{n} {}: {}", g.name, g.info.comment);
                }
                assert!(g.refractive_index(D_LINE_NM).is_ok() || !g.in_range(D_LINE_NM), "{n} {}", g.name);
            }
        }
        assert!(total >= 1600, "{total}");
    }

    /// The current SCHOTT glass a SCHOTT1980 row was checked against (named in its `GC` comment).
    fn checked_against(g: &Glass) -> &str {
        g.info.comment.split(" of SCHOTT ").nth(1).and_then(|t| t.split_whitespace().next()).unwrap()
    }

    /// The legacy SCHOTT1980 catalogue: every glass is a Buchdahl fit about 0.574 µm, names its source row and
    /// the current glass it was checked against, and still agrees with that glass (read from the built-in
    /// SCHOTT) to 1e-3 at every nm of its range; BK7 is N-BK7's predecessor to 6.2e-6, its n_d SCHOTT's 1.51680
    /// and its V_d 64.17 to the fit's stated largest error (6e-6).
    #[test]
    fn schott1980_rows_agree_with_their_current_glasses() {
        let legacy = catalog("schott1980").unwrap().unwrap();
        let current = catalog("SCHOTT").unwrap().unwrap();
        assert_eq!(legacy.len(), 69);
        assert!(legacy.comments().iter().any(|l| l.contains("Applied Optics 22(8), 1198 (1983)")));
        for g in legacy.iter() {
            assert_eq!((g.catalog.as_str(), g.formula.name(), g.valid_range_nm()), ("SCHOTT1980", "Buchdahl", (400.0, 700.0)), "{}", g.name);
            assert_eq!(g.formula.coefficients()[0], 0.574, "{}", g.name);
            assert!(g.info.comment.starts_with(&format!("Robb & Mercado 1983 Table V, SCHOTT {} (", g.name)), "{}", g.info.comment);
            let succ = checked_against(g);
            let c = current.get(succ).unwrap();
            let dev = (400..=700).map(|nm| (g.refractive_index(nm as f64).unwrap() - c.refractive_index(nm as f64).unwrap()).abs()).fold(0.0, f64::max);
            assert!(dev <= 1e-3, "{} vs {succ}: {dev}", g.name);
        }
        let bk7 = legacy.get("BK7").unwrap();
        let nbk7 = current.get("N-BK7").unwrap();
        assert!((bk7.refractive_index(D_LINE_NM).unwrap() - 1.51680).abs() <= 6e-6);
        let dev = (400..=700).map(|nm| (bk7.refractive_index(nm as f64).unwrap() - nbk7.refractive_index(nm as f64).unwrap()).abs()).fold(0.0, f64::max);
        assert!(dev <= 6.2e-6, "{dev}");
        // V_d = (n_d − 1)/(n_F − n_C): the fit's largest error (6e-6) at F and C moves it by up to
        // V_d · 2·6e-6/(n_F − n_C) ≈ 0.096 from SCHOTT's 64.17 (it is 0.081 off).
        let df = bk7.refractive_index(F_LINE_NM).unwrap() - bk7.refractive_index(C_LINE_NM).unwrap();
        assert!((bk7.vd - 64.17).abs() <= 64.17 * 2.0 * 6e-6 / df, "{}", bk7.vd);
        let e = bk7.refractive_index(380.0).unwrap_err().to_string();
        assert!(e.contains("BK7") && e.contains("380") && e.contains("[400, 700]"), "{e}");
    }

    /// The base wavelength is the paper's 0.574 µm, not the d line (opticalglass's Robb1983 class evaluates the
    /// rows about the d line): about 0.574 µm the rows meet their current glasses to a median below 1e-4, about
    /// 0.5875618 µm to a median above 3e-3 (measured: 5.9e-5 and 3.3e-3).
    #[test]
    fn schott1980_base_wavelength_is_0_574_um() {
        let legacy = catalog("SCHOTT1980").unwrap().unwrap();
        let current = catalog("SCHOTT").unwrap().unwrap();
        let median_dev = |base: f64| {
            let mut d: Vec<f64> = legacy
                .iter()
                .map(|g| {
                    let succ = checked_against(g);
                    let c = current.get(succ).unwrap();
                    let mut k = g.formula.coefficients().to_vec();
                    k[0] = base;
                    let f = DispersionFormula::Buchdahl([k[0], k[1], k[2], k[3]]);
                    (400..=700).map(|nm| (f.refractive_index(nm as f64) - c.refractive_index(nm as f64).unwrap()).abs()).fold(0.0, f64::max)
                })
                .collect();
            d.sort_by(f64::total_cmp);
            d[d.len() / 2]
        };
        let (at_574, at_d) = (median_dev(0.574), median_dev(D_LINE_NM / 1000.0));
        assert!(at_574 < 1e-4 && at_d > 3e-3, "{at_574} {at_d}");
    }

    #[test]
    fn buchdahl_file_errors_name_file_line_glass_and_value() {
        let add = |t: &str| add_buchdahl(&mut GlassCatalog::new(), t, "X.buchdahl", "X").unwrap_err().to_string();
        let e = add("CC c\nNM G 2\nBD 0.574 1.5 -0.04 x\nLD 0.4 0.7\n");
        assert!(e.starts_with("X.buchdahl:3:") && e.contains("glass G") && e.contains("x"), "{e}");
        let e = add("NM G 2\nBD 0.574 1.5 -0.04 0.001\n");
        assert!(e.starts_with("X.buchdahl:1:") && e.contains("glass G") && e.contains("`LD`"), "{e}");
        let e = add("NM G 2\nBD 0.574 1.5 -0.04 0.001\nLD 0.7 0.4\n");
        assert!(e.starts_with("X.buchdahl:3:") && e.contains("0.7 0.4"), "{e}");
        let e = add("NM G 2\nBD 0 1.5 -0.04 0.001\n");
        assert!(e.starts_with("X.buchdahl:2:") && e.contains("λ0 > 0"), "{e}");
        let e = add("NM G 9\n");
        assert!(e.contains("status `9`"), "{e}");
        let e = add("BD 0.574 1.5 0 0\n");
        assert!(e.contains("before the first `NM`"), "{e}");
        let e = add("NM G 2\nTN 0.5 1.5\n");
        assert!(e.starts_with("X.buchdahl:2:") && e.contains("`TN`"), "{e}");
        let mut c = GlassCatalog::builtin();
        let e = add_buchdahl(&mut c, "NM N-BK7 2\nBD 0.574 1.5 0 0\nLD 0.4 0.7\n", "X.buchdahl", "X").unwrap_err().to_string();
        assert!(e.contains("N-BK7") && e.contains("already"), "{e}");
    }

    #[test]
    fn schott_keeps_the_typed_in_six() {
        let c = catalog("SCHOTT").unwrap().unwrap();
        let b = GlassCatalog::builtin();
        for g in b.iter() {
            assert_eq!(*c.get(&g.name).unwrap(), **g);
        }
        assert!(c.contains("N-LAK22"));
    }

    /// SCHOTT B 270 from its datasheet table (`specs/schott/misc/B270.yml`, August 1993): the printed n at
    /// every tabulated line exactly (n_d 1.5230 at 0.58756 µm), the printed precision (±0.5e-4) against the
    /// neighbouring printed values between lines, a wavelength off the table refused by name with the range.
    #[test]
    fn schott_b270_is_its_datasheet_table() {
        let c = catalog("SCHOTT").unwrap().unwrap();
        let g = c.get("b270").unwrap();
        assert_eq!((g.catalog.as_str(), g.formula.label().as_str()), ("SCHOTT", "tabulated (8 points, monotone cubic (PCHIP) in λ)"));
        assert_eq!(g.info.comment, "specs/schott/misc/B270.yml; B 270 datasheet, August 1993");
        assert_eq!(g.refractive_index(587.56).unwrap(), 1.5230);
        assert_eq!(g.formula.refractive_index_um(0.58756), 1.5230);
        let table = [(0.43583, 1.5341), (0.47999, 1.5297), (0.48613, 1.5292), (0.54607, 1.5251), (0.58756, 1.5230), (0.58929, 1.5229), (0.64385, 1.5207), (0.65627, 1.5203)];
        for (w, n) in table {
            assert_eq!(g.formula.refractive_index_um(w), n, "{w}");
            assert_eq!(g.refractive_index(w * 1000.0).unwrap(), n, "{w}");
        }
        // Between two lines n lies within the two printed values widened by their precision (monotone).
        for p in table.windows(2) {
            for k in 1..50 {
                let w = p[0].0 + (p[1].0 - p[0].0) * k as f64 / 50.0;
                let n = g.refractive_index(w * 1000.0).unwrap();
                assert!(n <= p[0].1 + 0.5e-4 && n >= p[1].1 - 0.5e-4, "{w}: {n}");
            }
        }
        // n_d, V_d of the table (the informative catalogue values).
        assert!((g.nd - 1.5230).abs() <= 0.5e-4 && (g.vd - 58.8).abs() < 0.1, "{} {}", g.nd, g.vd);
        assert_eq!(g.valid_range_nm(), (0.43583 * 1000.0, 0.65627 * 1000.0));
        for w in [400.0, 435.8, 656.3, 700.0] {
            let e = g.refractive_index(w).unwrap_err().to_string();
            assert!(e.contains("B270") && e.contains(&format!("{w}")) && e.contains("[435.83, 656.27]"), "{e}");
        }
        assert!(g.refractive_index_extrapolated(700.0).unwrap().is_finite());
    }

    #[test]
    fn tabulated_file_errors_name_file_line_glass_and_value() {
        let add = |t: &str| add_tabulated(&mut GlassCatalog::new(), t, "X.tabulated", "X").unwrap_err().to_string();
        let e = add("CC c\nNM G 0\nTN 0.5 1.5\nTN 0.6 1.4x\n");
        assert!(e.starts_with("X.tabulated:4:") && e.contains("glass G") && e.contains("1.4x"), "{e}");
        let e = add("NM G 0\nTN 0.5 1.5\n");
        assert!(e.starts_with("X.tabulated:1:") && e.contains("glass G") && e.contains("at least 2 points"), "{e}");
        let e = add("NM G 0\nTN 0.6 1.5\nTN 0.5 1.4\n");
        assert!(e.contains("point 2: wavelength 0.5"), "{e}");
        let e = add("NM G 0\nXX 1\n");
        assert!(e.starts_with("X.tabulated:2:") && e.contains("`XX`"), "{e}");
        let e = add("TN 0.5 1.5\n");
        assert!(e.contains("before the first `NM`"), "{e}");
        let mut c = GlassCatalog::builtin();
        let e = add_tabulated(&mut c, "NM N-BK7 0\nTN 0.5 1.5\nTN 0.6 1.4\n", "X.tabulated", "X").unwrap_err().to_string();
        assert!(e.contains("N-BK7") && e.contains("already"), "{e}");
    }

    #[test]
    fn entries_and_stand_ins() {
        assert_eq!(entry_name("builtin:OHARA"), Some("OHARA"));
        assert_eq!(entry_name("BUILTIN:hoya"), Some("hoya"));
        assert_eq!(entry_name("/x/OHARA.agf"), None);
        assert_eq!(entry_name("b"), None);
        assert_eq!(standing_in_for("SUMITA_AUG2011"), Some("SUMITA"));
        assert_eq!(standing_in_for("ohara"), Some("OHARA"));
        assert_eq!(standing_in_for("OHARAX"), None);
        assert_eq!(standing_in_for("RPO"), None);
        // A legacy catalogue stands in for no GCAT name (it is only the last resort of the importer).
        assert_eq!(standing_in_for("SCHOTT1980"), None);
        assert_eq!(source("schott1980"), LEGACY_SOURCE);
        assert_eq!(source("OHARA"), SOURCE);
        assert_eq!(GlassCatalog::from_entry("builtin:SCHOTT1980").unwrap().get("bk7").unwrap().catalog, "SCHOTT1980");
        assert_eq!(holding("bk7"), vec!["SCHOTT1980"]);
        assert_eq!(holding("S-BSL7"), vec!["OHARA"]);
        assert_eq!(holding("SF5"), vec!["SCHOTT", "HIKARI", "SCHOTT1980"]); // HIKARI sells an SF5 too
        assert!(holding("NOPE-7").is_empty());
        assert!(catalog("nope").is_none());
        let e = GlassCatalog::from_entry("builtin:RPO").unwrap_err().to_string();
        assert!(e.contains("RPO") && e.contains("OHARA"), "{e}");
    }
}
