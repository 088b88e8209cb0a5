//! Round 19 of the held-out battery (prober B): users' glass catalogues (AGF) and the `.zmx` messages they touch.
//! A lone CR now ends an AGF record as it ends a `.zmx` one (the `.zmx` lexer's one line splitter: a user glass
//! after a CR was swallowed and the built-in glass of its name used silently); non-UTF-8 AGF text is read as
//! Windows-1252, the `.zmx` reader's rule (a glass name with a byte in 0x80–0x9F was not found); a run-time
//! wavelength outside a glass's range of a `.zmx` system names the file's `DCWP` record
//! (`SystemOrigin`); a grating's `PARM 1` ≤ 0 or fractional `PARM 2` is refused by line and record; small numbers
//! in messages take the exponent form (`1e-20`, as `1e-300`).
use diffcassi::materials::{parse_agf, GlassCatalog, MaterialError};
use diffcassi::spec::zmx::{import_zmx, ZmxOptions};
use diffcassi::system::{SequentialSystem, SystemOrigin};

use crate::cli_run::{ok_cli, refused_cli};

const SELLMEIER: &str = "1.039612120E+00 6.000698670E-03 2.317923440E-01 2.001791440E-02 1.010469450E+00 1.035606530E+02";

/// A singlet at infinity: one glass `glass` from `GCAT gcat`, then `extra` surface records on surface 1.
fn singlet(gcat: &str, glass: &[u8]) -> Vec<u8> {
    let mut z = format!(
        "VERS 190513 80 123457 L123457\nMODE SEQ\nNAME singlet\nUNIT MM X W X CM MR CPMM\nENPD 10\nENVD 20 1 0\nGCAT {gcat}\n\
         FTYP 0 0 1 1 0 0 0\nXFLN 0\nYFLN 0\nWAVM 1 0.5875618 1\nPWAV 1\nSURF 0\n  TYPE STANDARD\n  CURV 0.0\n  DISZ INFINITY\n\
         SURF 1\n  STOP\n  TYPE STANDARD\n  CURV 0.02\n  DISZ 5\n  GLAS "
    )
    .into_bytes();
    z.extend_from_slice(glass);
    z.extend_from_slice(b" 0 0 1.5 60\nSURF 2\n  TYPE STANDARD\n  CURV -0.01\n  DISZ 90\nSURF 3\n  TYPE STANDARD\n  CURV 0\n  DISZ 0\n");
    z
}

/// Writes `files` into a new folder and builds the `.zmx` among them as the CLI and Python do.
fn build_zmx(files: &[(&str, &[u8])]) -> (tempfile::TempDir, Result<SequentialSystem, String>) {
    let dir = tempfile::tempdir().unwrap();
    for (name, bytes) in files {
        std::fs::write(dir.path().join(name), bytes).unwrap();
    }
    let zmx = dir.path().join(files.iter().find(|f| f.0.ends_with(".zmx")).unwrap().0);
    let built = diffcassi::spec::load_spec_file(&zmx)
        .and_then(|spec| SequentialSystem::build_from(&spec, SystemOrigin::of_path(&zmx)))
        .map_err(|e| e.to_string());
    (dir, built)
}

#[test]
fn a_lone_cr_ends_an_agf_record_so_the_users_glass_after_it_is_used() {
    // G1 with LF line ends, then `LD …\r` and a user N-BK7 (K1 = 1.06, not SCHOTT's 1.0396) with CR line ends.
    let agf = format!(
        "CC melt data\nNM G1 2 517642.251 1.5168 64.17 0 1\nCD {SELLMEIER}\nLD 0.3 2.5\r\
         NM N-BK7 2 517642.251 1.5236 64.17 0 1\rCD 1.06 6.00069867E-03 2.31792344E-01 2.00179144E-02 1.01046945 103.560653\rLD 0.3 2.5\r"
    );
    let glasses = parse_agf(&agf, "MYCAT.AGF").unwrap();
    let names: Vec<&str> = glasses.iter().map(|g| g.name.as_str()).collect();
    assert_eq!(names, ["G1", "N-BK7"], "a CR-ended record is a record");
    // Every line end in any mix reads as LF: the same glasses.
    assert_eq!(glasses, parse_agf(agf.replace('\r', "\n"), "MYCAT.AGF").unwrap());
    assert_eq!(glasses, parse_agf(agf.replace('\r', "\r\n"), "MYCAT.AGF").unwrap());
    // A CR-only catalogue holds its glass (it was "no glass (NM record) in the file").
    let cr_only = format!("CC cat\rNM G1 2 0 1.5168 64.17 0 1\rGC a comment\rCD {SELLMEIER}\rLD 0.3 2.5\r");
    let g = parse_agf(&cr_only, "CR.AGF").unwrap();
    assert_eq!((g.len(), g[0].info.comment.as_str()), (1, "a comment"));
    // A CR-ended record names its own line in an error (line 3 of three CR-ended lines).
    let e = parse_agf("NM A 2 0 1.5 60\rCD 1 0.01 0 0 0 0\rLD 2.5 0.3\r", "B.AGF").unwrap_err().to_string();
    assert!(e.starts_with("B.AGF:3:") && e.contains("LD"), "{e}");

    // End to end: `GCAT MYCAT SCHOTT` resolves N-BK7 to the user's glass, not the built-in one.
    let (_dir, built) = build_zmx(&[("SING.zmx", &singlet("MYCAT SCHOTT", b"N-BK7")), ("MYCAT.AGF", agf.as_bytes())]);
    let system = built.unwrap();
    let w = 587.5618;
    let n = system.indices(w).unwrap()[1];
    let user = glasses[1].refractive_index(w).unwrap();
    let builtin = GlassCatalog::builtin().get("N-BK7").unwrap().refractive_index(w).unwrap();
    assert_eq!(n, user, "the user's N-BK7 ({user}), not the built-in one ({builtin})");
    assert!((n - builtin).abs() > 1e-3, "{n} {builtin}");
}

#[test]
fn non_utf8_agf_text_reads_as_windows_1252_like_the_zmx() {
    // `G™X` (0x99 in Windows-1252) in an ANSI catalogue and an ANSI lens file: the same name.
    let mut agf = b"CC \x80 price list \x96 1\nNM G\x99X 2 0 1.5168 64.17 0 1\nGC \x93quoted\x94\nCD ".to_vec();
    agf.extend_from_slice(SELLMEIER.as_bytes());
    agf.extend_from_slice(b"\nLD 0.3 2.5\n");
    let doc = diffcassi::materials::parse_agf_document(&agf, "MYCAT.AGF").unwrap();
    assert_eq!(doc.glasses[0].name, "G™X");
    assert_eq!(doc.comments, ["€ price list – 1"]);
    assert_eq!(doc.glasses[0].info.comment, "“quoted”");
    // Latin-1 letters (0xA0–0xFF) read as before.
    let latin = parse_agf(&[&b"NM G\xe9X 2 0 1.5168 64.17 0 1\nCD "[..], SELLMEIER.as_bytes(), b"\nLD 0.3 2.5\n"].concat(), "L.AGF").unwrap();
    assert_eq!(latin[0].name, "GéX");
    // A byte Windows-1252 leaves undefined is binary, as in a `.zmx` file.
    let e = parse_agf(&[&b"NM G\x81X 2 0 1.5168 64.17 0 1\nCD "[..], SELLMEIER.as_bytes(), b"\nLD 0.3 2.5\n"].concat(), "U.AGF").unwrap_err();
    assert!(matches!(&e, MaterialError::AgfParse { line: 1, .. }) && e.to_string().contains("U+0081"), "{e}");

    let (_dir, built) = build_zmx(&[("SING.zmx", &singlet("MYCAT", b"G\x99X")), ("MYCAT.AGF", &agf)]);
    let system = built.unwrap();
    assert_eq!(system.spec.surfaces[1].material.as_deref(), Some("G™X"));
    assert_eq!(system.indices(587.5618).unwrap()[1], doc.glasses[0].refractive_index(587.5618).unwrap());
}

fn plate_f2() -> (Vec<u8>, Vec<u8>) {
    let agf = format!("NM F2 2 0 1.5168 64.17 0 1\nCD {SELLMEIER}\nLD 0.35 2.0\n").into_bytes();
    (singlet("ALLF", b"F2"), agf)
}

#[test]
fn a_run_time_wavelength_outside_a_glass_range_names_the_zmx_record() {
    let (zmx, agf) = plate_f2();
    let (dir, built) = build_zmx(&[("plate.zmx", &zmx), ("ALLF.AGF", &agf)]);
    let system = built.unwrap();
    assert_eq!(system.origin(), SystemOrigin::Zmx);
    let e = system.indices(349.99).unwrap_err().to_string();
    assert!(e.contains("349.99 nm") && e.contains("glass F2") && e.contains("`DCWP allow_extrapolation`"), "{e}");
    assert!(!e.contains("wavelength_policy") && !e.contains("WavelengthPolicy"), "{e}");
    // The same spec built as a spec names the spec's field.
    let spec_built = SequentialSystem::build(&system.spec).unwrap();
    assert_eq!(spec_built.origin(), SystemOrigin::Spec);
    assert!(spec_built.indices(349.99).unwrap_err().to_string().contains("wavelength_policy"));
    // Every command-line entry point, as `info` with an out-of-range WAVM does.
    for cmd in ["trace", "spot"] {
        let mut args = vec![cmd, "--system", "plate.zmx", "--field-deg", "0,0", "--wavelength-nm", "349.99"];
        if cmd == "trace" {
            args.extend(["--pupil", "grid:3"]);
        }
        refused_cli(dir.path(), &args, &["349.99 nm", "glass F2", "`DCWP allow_extrapolation`"]);
        let (_, out) = crate::cli_run::run_cli(dir.path(), &args);
        assert!(!out.contains("wavelength_policy") && !out.contains("WavelengthPolicy"), "{cmd}: {out}");
    }
    ok_cli(dir.path(), &["trace", "--system", "plate.zmx", "--field-deg", "0,0", "--wavelength-nm", "350", "--pupil", "grid:3"]);
}

/// A flat Diffraction Grating in air with `PARM 1 t` and `PARM 2 m` (lines 21 and 22).
fn grating(t: &str, m: &str) -> Vec<u8> {
    format!(
        "VERS 190513 80 123457 L123457\nMODE SEQ\nNAME grating\nUNIT MM X W X CM MR CPMM\nENPD 10\nENVD 20 1 0\n\
         FTYP 0 0 1 1 0 0 0\nXFLN 0\nYFLN 0\nWAVM 1 0.55 1\nPWAV 1\nSURF 0\n  TYPE STANDARD\n  CURV 0.0\n  DISZ INFINITY\n\
         SURF 1\n  STOP\n  TYPE DGRATING\n  CURV 0\n  DISZ 20\n  PARM 1 {t}\n  PARM 2 {m}\nSURF 2\n  TYPE STANDARD\n  CURV 0\n  DISZ 0\n"
    )
    .into_bytes()
}

fn import_err(bytes: &[u8]) -> String {
    import_zmx(bytes, "g.zmx", None, &ZmxOptions::default()).err().expect("refused").to_string()
}

#[test]
fn a_grating_with_no_lines_or_a_fractional_order_is_refused_by_line_and_record() {
    let ok = import_zmx(&grating("0.3", "1"), "g.zmx", None, &ZmxOptions::default()).unwrap();
    SequentialSystem::build_from(&ok.spec, SystemOrigin::Zmx).unwrap();
    let e = import_err(&grating("0", "1"));
    assert!(e.starts_with("g.zmx: line 21 `PARM`: surface 1 (Diffraction Grating) parameter 1") && e.contains("is 0") && e.contains("TYPE STANDARD"), "{e}");
    assert!(!e.contains("grating_lines_per_um"), "{e}");
    // A negative frequency −T in order m is T in order −m: the message says how to write it.
    let e = import_err(&grating("-0.3", "1"));
    assert!(e.contains("line 21 `PARM`") && e.contains("is -0.3") && e.contains("`PARM 1 0.3` and `PARM 2 -1`"), "{e}");
    let e = import_err(&grating("-1e-20", "2"));
    assert!(e.contains("is -1e-20") && e.contains("`PARM 1 1e-20` and `PARM 2 -2`"), "{e}");
    let e = import_err(&grating("0.3", "1.5"));
    assert!(e.starts_with("g.zmx: line 22 `PARM`: surface 1 (Diffraction Grating) parameter 2, the diffraction order, is 1.5") && !e.contains("grating_order"), "{e}");
    let e = import_err(&grating("0.3", "2000000"));
    assert!(e.contains("line 22 `PARM`") && e.contains("is 2000000") && e.contains("at most 10⁶"), "{e}");
    // The order as written by the equivalent form is accepted and traces as the original order would.
    let neg = import_zmx(&grating("0.3", "-1"), "g.zmx", None, &ZmxOptions::default()).unwrap();
    SequentialSystem::build(&neg.spec).unwrap();
}

#[test]
fn small_numbers_in_refusals_take_the_exponent_form() {
    let mut easph = String::from_utf8(grating("0.3", "1")).unwrap().replace("TYPE DGRATING", "TYPE EVENASPH");
    easph = easph.replace("  PARM 1 0.3\n  PARM 2 1\n", "  PARM 1 0.002\n  PARM 9 1e-20\n");
    let e = import_err(easph.as_bytes());
    assert!(e.contains("line 22 `PARM`: parameter 9 = 1e-20 has no meaning"), "{e}");
    assert!(!e.contains("0.0000"), "{e}");
    // The one rule for every message: a fraction below 1e-4 in exponent form whether or not its message used
    // fmt_num (1e-20 is 21 digits; 1e-300 was already short).
    for v in [1e-20, 1e-7, -5e-5, 1e-300] {
        let m = diffcassi::Error::invalid(format!("value {v}")).to_string();
        assert_eq!(m, format!("value {}", diffcassi::limits::fmt_num(v)));
    }
    // The AGF reader's own numbers: an LD range of 1e-20 µm.
    let e = parse_agf("NM A 2 0 1.5 60\nCD 1 0.01 0 0 0 0\nLD 1e-20 1e-21\n", "S.AGF").unwrap_err().to_string();
    assert!(e.contains("[1e-20, 1e-21] µm"), "{e}");
}
