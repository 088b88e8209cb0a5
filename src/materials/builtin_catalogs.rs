//! Vendor glass catalogues built into the binary: SCHOTT, OHARA, HOYA, CDGM, SUMITA, HIKARI.
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

/// Where the built-in catalogues come from (shown by `info`).
pub const SOURCE: &str = "refractiveindex.info database, commit ff11b58 (2026-06-14), CC0 1.0";

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

/// The names of the built-in catalogues.
pub fn names() -> impl Iterator<Item = &'static str> {
    CATALOGS.iter().map(|c| c.0)
}

/// The built-in catalogue `name` (any case), or `None` if there is none of that name.
pub fn catalog(name: &str) -> Option<Result<GlassCatalog, MaterialError>> {
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

/// A tabulated glass being read: its `NM` line, name, status, `GC` comment and `TN` points.
struct PendingTable {
    line: usize,
    name: String,
    status: Option<GlassStatus>,
    comment: String,
    points: Vec<(f64, f64)>,
}

/// Reads the tabulated glasses of `text` (the format of the [module documentation](self)) into `catalog`.
/// Errors name `source_name`, the line, the glass and the value; a glass already in the catalogue is an
/// error (one source per name).
pub fn add_tabulated(catalog: &mut GlassCatalog, text: &str, source_name: &str, catalog_name: &str) -> Result<(), MaterialError> {
    let err = |line: usize, message: String| MaterialError::AgfParse { source_name: source_name.to_string(), line, message };
    let finish = |p: PendingTable, catalog: &mut GlassCatalog| -> Result<(), MaterialError> {
        if catalog.contains(&p.name) {
            return Err(err(p.line, format!("glass {} is already in the {catalog_name} catalogue", p.name)));
        }
        let table = TabulatedIndex::new(p.points).map_err(|m| err(p.line, format!("glass {}: {m}", p.name)))?;
        let (lo, hi) = table.range_um();
        // n_d, V_d (informative): the interpolant at the d, F, C lines, each at the nearest λ of the table.
        let at = |nm: f64| table.index_um((nm / 1000.0).clamp(lo, hi));
        let nd = at(D_LINE_NM);
        let vd = (nd - 1.0) / (at(F_LINE_NM) - at(C_LINE_NM));
        let mut g = Glass::new(p.name, DispersionFormula::Tabulated(table), nd, vd, lo * 1000.0, hi * 1000.0, catalog_name);
        g.info.status = p.status;
        g.info.comment = p.comment;
        catalog.insert(g);
        Ok(())
    };
    let mut pending: Option<PendingTable> = None;
    let mut comments = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let raw = raw.trim();
        if raw.is_empty() {
            continue;
        }
        let (record, rest) = raw.split_once(char::is_whitespace).unwrap_or((raw, ""));
        let rest = rest.trim();
        let fields: Vec<&str> = rest.split_whitespace().collect();
        match record {
            "CC" => comments.push(rest.to_string()),
            "NM" => {
                if let Some(p) = pending.take() {
                    finish(p, catalog)?;
                }
                let [name, status] = fields[..] else { return Err(err(line, format!("`NM {rest}`: expected `NM name status`"))) };
                let status = status
                    .parse::<i64>()
                    .ok()
                    .and_then(GlassStatus::from_code)
                    .ok_or_else(|| err(line, format!("glass {name}: status `{status}` is not 0..=4")))?;
                pending = Some(PendingTable { line, name: name.to_string(), status: Some(status), comment: String::new(), points: Vec::new() });
            }
            "GC" | "TN" => {
                let Some(p) = pending.as_mut() else { return Err(err(line, format!("`{record}` record before the first `NM`"))) };
                if record == "GC" {
                    p.comment = rest.to_string();
                    continue;
                }
                let num = |t: &str| t.parse::<f64>().ok().filter(|v| v.is_finite());
                match fields[..] {
                    [w, n] => match (num(w), num(n)) {
                        (Some(w), Some(n)) => p.points.push((w, n)),
                        _ => return Err(err(line, format!("glass {}: `TN {rest}`: λ and n must be finite numbers", p.name))),
                    },
                    _ => return Err(err(line, format!("glass {}: `TN {rest}`: expected `TN λ(µm) n`", p.name))),
                }
            }
            other => return Err(err(line, format!("unknown record `{other}` (a tabulated-glass file has CC, NM, GC, TN)"))),
        }
    }
    if let Some(p) = pending.take() {
        finish(p, catalog)?;
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
    names().find(|n| {
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
        for n in names() {
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
        assert!(catalog("nope").is_none());
        let e = GlassCatalog::from_entry("builtin:RPO").unwrap_err().to_string();
        assert!(e.contains("RPO") && e.contains("OHARA"), "{e}");
    }
}
