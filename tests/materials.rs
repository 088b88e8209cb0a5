//! Integration tests of `diffcassi::materials` against the SCHOTT catalogue shipped in
//! `/work/shared/reference/glass/SCHOTT.AGF` (December 2024).
//!
//! Tests that need the catalogue print a `SKIP` line and return when it is absent.

use std::path::Path;
use std::sync::Arc;

use diffcassi::materials::{
    parse_agf, Glass, GlassCatalog, MaterialError, Medium, WavelengthPolicy, C_LINE_NM, D_LINE_NM,
    F_LINE_NM,
};

const SCHOTT_AGF: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../shared/reference/glass/SCHOTT.AGF"
);

/// Raw bytes of SCHOTT.AGF, or `None` after printing a SKIP message.
fn schott_bytes(test: &str) -> Option<Vec<u8>> {
    match std::fs::read(SCHOTT_AGF) {
        Ok(b) => Some(b),
        Err(e) => {
            eprintln!("SKIP {test}: reference catalogue {SCHOTT_AGF} not readable ({e})");
            None
        }
    }
}

fn schott_catalog(test: &str) -> Option<GlassCatalog> {
    if !Path::new(SCHOTT_AGF).exists() {
        eprintln!("SKIP {test}: reference catalogue {SCHOTT_AGF} is absent");
        return None;
    }
    Some(GlassCatalog::from_agf_file(SCHOTT_AGF).expect("SCHOTT.AGF must parse"))
}

/// Lines whose first token is `NM`.
fn count_nm_lines(bytes: &[u8]) -> usize {
    String::from_utf8_lossy(bytes)
        .lines()
        .filter(|l| l.split_whitespace().next() == Some("NM"))
        .count()
}

#[test]
fn every_schott_glass_parses() {
    let Some(bytes) = schott_bytes("every_schott_glass_parses") else {
        return;
    };
    let glasses = parse_agf(&bytes, "SCHOTT.AGF").expect("SCHOTT.AGF must parse");
    let nm = count_nm_lines(&bytes);
    println!("SCHOTT.AGF: {} glasses, {nm} NM lines", glasses.len());
    assert!(glasses.len() > 100, "only {} glasses", glasses.len());
    assert_eq!(glasses.len(), nm);
    let catalog = GlassCatalog::from_agf_file(SCHOTT_AGF).unwrap();
    assert_eq!(catalog.len(), nm, "names must be unique case-insensitively");
    for g in &glasses {
        assert_eq!(g.catalog, "SCHOTT");
        assert!(g.min_wavelength_nm > 0.0 && g.max_wavelength_nm > g.min_wavelength_nm);
        // Every glass evaluates to a finite index > 1 across its whole LD range.
        for i in 0..=20 {
            let w = g.min_wavelength_nm
                + (g.max_wavelength_nm - g.min_wavelength_nm) * f64::from(i) / 20.0;
            let n = g
                .refractive_index(w)
                .unwrap_or_else(|e| panic!("{} at {w} nm: {e}", g.name));
            assert!(n > 1.0 && n < 3.0, "{} at {w} nm: n = {n}", g.name);
        }
    }
}

#[test]
fn computed_nd_matches_catalogue_for_every_glass() {
    let Some(catalog) = schott_catalog("computed_nd_matches_catalogue_for_every_glass") else {
        return;
    };
    let (mut worst_err, mut worst_name) = (f64::NEG_INFINITY, String::new());
    let mut checked = 0;
    for g in catalog.iter() {
        if !g.in_range(D_LINE_NM) {
            println!("note: {} LD range excludes the d line", g.name);
            continue;
        }
        let n = g.refractive_index(D_LINE_NM).unwrap();
        let err = (n - g.nd).abs();
        checked += 1;
        if err > worst_err {
            (worst_err, worst_name) = (err, g.name.clone());
        }
    }
    let (err, name) = (worst_err, worst_name);
    println!("nd check: {checked} glasses, worst |n(587.5618 nm) - nd| = {err:.3e} ({name})");
    assert!(checked > 100);
    assert!(err < 1e-4, "worst glass {name}: |n - nd| = {err:e}");
}

#[test]
fn computed_vd_matches_catalogue_for_every_glass() {
    let Some(catalog) = schott_catalog("computed_vd_matches_catalogue_for_every_glass") else {
        return;
    };
    let (mut worst_err, mut worst_name) = (f64::NEG_INFINITY, String::new());
    for g in catalog.iter() {
        let err = (g.abbe_number().unwrap() - g.vd).abs();
        if err > worst_err {
            (worst_err, worst_name) = (err, g.name.clone());
        }
    }
    println!("vd check: worst |vd(computed) - vd| = {worst_err:.3e} ({worst_name})");
    // The catalogue prints vd with 2 decimals (SCHOTT) or 6 (legacy entries).
    assert!(
        worst_err < 0.01,
        "worst glass {worst_name}: |vd - vd_cat| = {worst_err}"
    );
}

#[test]
fn n_bk7_nd() {
    let Some(catalog) = schott_catalog("n_bk7_nd") else {
        return;
    };
    let n = catalog
        .get("N-BK7")
        .unwrap()
        .refractive_index(587.5618)
        .unwrap();
    println!("N-BK7 n(587.5618 nm) = {n:.10}");
    assert!((n - 1.5168).abs() < 1e-4, "n = {n}");
}

#[test]
fn abbe_numbers_match_vd() {
    let Some(catalog) = schott_catalog("abbe_numbers_match_vd") else {
        return;
    };
    for name in ["N-BK7", "N-SF10", "N-SK2"] {
        let g = catalog.get(name).unwrap();
        let nd = g.refractive_index(D_LINE_NM).unwrap();
        let nf = g.refractive_index(F_LINE_NM).unwrap();
        let nc = g.refractive_index(C_LINE_NM).unwrap();
        let vd = (nd - 1.0) / (nf - nc);
        println!("{name}: vd computed {vd:.4}, catalogue {}", g.vd);
        assert!((vd - g.vd).abs() < 0.05, "{name}: {vd} vs {}", g.vd);
        assert_eq!(vd, g.abbe_number().unwrap());
    }
}

#[test]
fn builtin_table_equals_agf_file() {
    let Some(file) = schott_catalog("builtin_table_equals_agf_file") else {
        return;
    };
    let builtin = GlassCatalog::builtin();
    assert_eq!(builtin.len(), 6);
    for b in builtin.iter() {
        let f = file.get(&b.name).unwrap();
        for w in [450.0, 520.0, 650.0] {
            let (nb, nf) = (
                b.refractive_index(w).unwrap(),
                f.refractive_index(w).unwrap(),
            );
            assert!(
                (nb - nf).abs() <= 1e-12,
                "{} at {w} nm: builtin {nb} vs file {nf}",
                b.name
            );
        }
        // Stronger: every typed-in value is bit-identical to the parsed one.
        let mut parsed: Glass = (*f).clone();
        parsed.info.transmission.clear(); // IT data are not in the built-in table
        assert_eq!(**b, parsed, "{}", b.name);
    }
}

#[test]
fn out_of_range_and_nan_wavelengths_are_errors() {
    let builtin = GlassCatalog::builtin();
    let file = schott_catalog("out_of_range_and_nan_wavelengths_are_errors (file part)");
    let mut sources = vec![builtin.get("N-BK7").unwrap()];
    sources.extend(file.map(|c| c.get("N-BK7").unwrap()));
    for bk7 in sources {
        for w in [100.0, 5000.0] {
            let e = bk7.refractive_index(w).unwrap_err();
            match &e {
                MaterialError::WavelengthOutOfRange {
                    glass,
                    wavelength_nm,
                    min_nm,
                    max_nm,
                } => {
                    assert_eq!(glass, "N-BK7");
                    assert_eq!(*wavelength_nm, w);
                    assert_eq!((*min_nm, *max_nm), (300.0, 2500.0));
                }
                other => panic!("unexpected {other:?}"),
            }
            let msg = e.to_string();
            assert!(
                msg.contains("N-BK7") && msg.contains(&format!("{w}")),
                "{msg}"
            );
            let m = Medium::Glass(bk7.clone());
            assert!(m.refractive_index(w, WavelengthPolicy::Strict).is_err());
            assert_eq!(
                m.refractive_index(w, WavelengthPolicy::AllowExtrapolation)
                    .unwrap(),
                bk7.refractive_index_unchecked(w)
            );
        }
        let e = bk7.refractive_index(f64::NAN).unwrap_err();
        assert!(
            matches!(e, MaterialError::NonFiniteWavelength { .. }),
            "{e:?}"
        );
        assert!(
            e.to_string().contains("N-BK7") && e.to_string().contains("NaN"),
            "{e}"
        );
        assert!(Medium::Glass(bk7.clone())
            .refractive_index(f64::NAN, WavelengthPolicy::AllowExtrapolation)
            .is_err());
    }
}

#[test]
fn malformed_agf_errors_name_source_and_line() {
    // Bad number in CD (line 3).
    let bad_cd = "CC test\nNM A 2 0 1.5 60 0 1\nCD 1.0 0.01 0.2 0.0x2 1.0 100\nLD 0.3 2.5\n";
    let e = parse_agf(bad_cd, "BROKEN.AGF").unwrap_err();
    match &e {
        MaterialError::AgfParse {
            source_name,
            line,
            message,
        } => {
            assert_eq!(source_name, "BROKEN.AGF");
            assert_eq!(*line, 3);
            assert!(message.contains("0.0x2"), "{message}");
        }
        other => panic!("unexpected {other:?}"),
    }
    assert!(e.to_string().starts_with("BROKEN.AGF:3:"), "{e}");

    // CD without a preceding NM (line 2).
    let e = parse_agf("CC test\nCD 1.0 0.01 0.2 0.02 1.0 100\n", "ORPHAN.AGF").unwrap_err();
    assert!(
        matches!(&e, MaterialError::AgfParse { source_name, line: 2, .. } if source_name == "ORPHAN.AGF"),
        "{e:?}"
    );
    assert!(e.to_string().contains("NM"), "{e}");

    // File errors name the full path.
    let dir = std::env::temp_dir().join(format!("diffcassi_materials_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("BROKEN.AGF");
    std::fs::write(&path, bad_cd).unwrap();
    let e = GlassCatalog::from_agf_file(&path).unwrap_err();
    assert!(
        e.to_string().contains(&format!("{}:3:", path.display())),
        "{e}"
    );
    std::fs::remove_dir_all(&dir).ok();
    let e = GlassCatalog::from_agf_file(dir.join("MISSING.AGF")).unwrap_err();
    assert!(
        matches!(e, MaterialError::Io { .. }) && e.to_string().contains("MISSING.AGF"),
        "{e}"
    );
}

#[test]
fn unknown_glass_and_case_insensitive_lookup() {
    let builtin = GlassCatalog::builtin();
    let e = builtin.get("N-BK77").unwrap_err();
    assert!(matches!(&e, MaterialError::UnknownGlass { name, .. } if name == "N-BK77"));
    assert!(
        e.to_string().contains("N-BK77") && e.to_string().contains("N-BK7"),
        "{e}"
    );
    let a = builtin.get("n-bk7").unwrap();
    assert!(Arc::ptr_eq(&a, &builtin.get("N-Bk7").unwrap()));

    let Some(file) = schott_catalog("unknown_glass_and_case_insensitive_lookup (file part)") else {
        return;
    };
    // SCHOTT.AGF itself has mixed-case names, e.g. N-BK7HTi.
    let hti = file.get("n-bk7hti").unwrap();
    assert_eq!(hti.name, "N-BK7HTI");
    assert!(Arc::ptr_eq(&hti, &file.get("N-BK7HTi").unwrap()));
    assert!(file.get("UNOBTAINIUM").is_err());
}

#[test]
fn utf16le_schott_parses_identically() {
    let Some(bytes) = schott_bytes("utf16le_schott_parses_identically") else {
        return;
    };
    let text = String::from_utf8(bytes).expect("SCHOTT.AGF is ASCII");
    let mut utf16 = vec![0xFF, 0xFE];
    for unit in text.replace('\n', "\r\n").encode_utf16() {
        utf16.extend_from_slice(&unit.to_le_bytes());
    }
    let a = parse_agf(&utf16, "SCHOTT.AGF").unwrap();
    let b = parse_agf(&text, "SCHOTT.AGF").unwrap();
    assert_eq!(a.len(), b.len());
    assert_eq!(a, b);
}

#[test]
fn utf16le_small_catalogue_parses() {
    // Independent of the reference file.
    let text = "CC utf16 test\r\nNM X1 2 0 1.5168 64.17 0 1\r\nCD 1.03961212 0.00600069867 0.231792344 0.0200179144 1.01046945 103.560653\r\nLD 0.3 2.5\r\n";
    let mut bytes = vec![0xFF, 0xFE];
    for unit in text.encode_utf16() {
        bytes.extend_from_slice(&unit.to_le_bytes());
    }
    let cat = GlassCatalog::from_agf_bytes(&bytes, "U16.AGF").unwrap();
    let g = cat.get("x1").unwrap();
    assert!((g.refractive_index(587.5618).unwrap() - 1.5168).abs() < 1e-4);
    assert_eq!(cat.comments(), ["utf16 test"]);
}

#[test]
fn schott_catalogue_peculiarities() {
    let Some(catalog) = schott_catalog("schott_catalogue_peculiarities") else {
        return;
    };
    // B270 is the only Schott-formula (1) glass; the rest use Sellmeier 1 (2).
    let b270 = catalog.get("B270").unwrap();
    assert_eq!(b270.formula.agf_number(), 1);
    assert!((b270.refractive_index(D_LINE_NM).unwrap() - b270.nd).abs() < 1e-4);
    for g in catalog.iter().filter(|g| g.name != "B270") {
        assert_eq!(g.formula.agf_number(), 2, "{}", g.name);
    }
    // Glasses with an empty TD record keep thermal = None; all others are at 20 °C.
    for name in ["P-SK57Q1", "REALVIEW_2.0", "LF5G15"] {
        assert!(catalog.get(name).unwrap().thermal.is_none(), "{name}");
    }
    for g in catalog.iter().filter_map(|g| g.thermal) {
        assert_eq!(g.reference_temperature_c, 20.0);
    }
}
