//! Vendor glass catalogues built into the binary: SCHOTT, OHARA, HOYA, CDGM, SUMITA, HIKARI.
//!
//! So that a lens file naming `GCAT OHARA HOYA …` opens without the user's copy of OpticStudio's `.AGF`
//! files, the optical glasses of these vendors are embedded (`data/glass/<NAME>.agf`, 1613 glasses,
//! ≈ 330 kB of text) and parsed by the ordinary AGF reader ([`super::agf`]) when asked for. They were
//! converted by `scripts/convert_refractiveindex_glass.py` from the refractiveindex.info database
//! (<https://github.com/polyanskiy/refractiveindex.info-database>, commit
//! `ff11b5897ef0754b15d939d921eb6c745693cbd1`, 2026-06-14, public domain under CC0 1.0), which holds each
//! vendor's Zemax-catalogue formula and coefficients as the vendor printed them; the numbers are copied as
//! text, so the f64 read here is the one the source denotes. Each glass keeps its source in its `GC`
//! comment ([`super::GlassInfo::comment`]): the database page and the vendor catalogue it came from (e.g.
//! `specs/ohara/optical/S-BSL7.yml; OHARA Zemax catalog 2017-11-30`).
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
//! # Ok::<(), diffcassi::materials::MaterialError>(())
//! ```
use super::{GlassCatalog, MaterialError};

/// The prefix of a `glass_catalogs` entry that names a built-in catalogue (`builtin:OHARA`).
pub const ENTRY_PREFIX: &str = "builtin:";

/// Where the built-in catalogues come from (shown by `info`).
pub const SOURCE: &str = "refractiveindex.info database, commit ff11b58 (2026-06-14), CC0 1.0";

/// The built-in catalogues, in the order listed to users, with their AGF text.
const CATALOGS: [(&str, &str); 6] = [
    ("SCHOTT", include_str!("../../data/glass/SCHOTT.agf")),
    ("OHARA", include_str!("../../data/glass/OHARA.agf")),
    ("HOYA", include_str!("../../data/glass/HOYA.agf")),
    ("CDGM", include_str!("../../data/glass/CDGM.agf")),
    ("SUMITA", include_str!("../../data/glass/SUMITA.agf")),
    ("HIKARI", include_str!("../../data/glass/HIKARI.agf")),
];

/// The names of the built-in catalogues.
pub fn names() -> impl Iterator<Item = &'static str> {
    CATALOGS.iter().map(|c| c.0)
}

/// The built-in catalogue `name` (any case), or `None` if there is none of that name.
pub fn catalog(name: &str) -> Option<Result<GlassCatalog, MaterialError>> {
    let (cat, text) = CATALOGS.iter().find(|c| c.0.eq_ignore_ascii_case(name.trim()))?;
    Some(GlassCatalog::from_agf_str(text, &format!("{cat}.agf")).map(|mut c| {
        if *cat == "SCHOTT" {
            c.merge(GlassCatalog::builtin());
        }
        c
    }))
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
