//! A held-out battery's findings on the `.zmx` reader and the glass catalogues (round 5), each now refused by
//! line and record, or fixed: fields beyond the command line's limits (a 1e300 mm image height converted to a
//! 90° field), records given twice (the last `CURV` or the first `WAVM 1` taken silently), `--glass-catalog`
//! not searched for a file's glasses, `UNIT IN` and `FTYP 4` reinterpreted under `--ignore-unsupported`, the
//! pupil an F/# gives, implausible catalogue indices, 309-digit numbers in messages, a bad
//! `DIFFCASSI_GLASS_DIR`, an unindented last `GLAS`, an aperture on an object at infinity, an afocal EFL
//! printed as `-inf`, and `study --systems` on a FIFO or a folder. Base file: a singlet at infinity.
use crate::common;
use diffcassi::materials::{builtin_catalogs, GlassCatalog, D_LINE_NM};
use diffcassi::spec::zmx::{import_zmx, ZmxOptions};
use std::path::Path;
use std::process::{Command, Output};

const SINGLET: &str = "MODE SEQ
UNIT MM X W X CM MR CPMM
ENPD 10
GCAT SCHOTT
FTYP 0 0 1 1 0 0 0
XFLN 0
YFLN 0
WAVM 1 0.5875618 1
PWAV 1
SURF 0
  DISZ INFINITY
SURF 1
  STOP
  CURV 0.01
  DISZ 2
  GLAS N-BK7
SURF 2
  CURV -0.01
  DISZ 95
SURF 3
  DISZ 0
";

fn run_env(dir: &Path, args: &[&str], env: &[(&str, &str)]) -> (Option<i32>, String) {
    let mut c = Command::new(env!("CARGO_BIN_EXE_diffcassi"));
    c.current_dir(dir).args(args).env_remove("DIFFCASSI_GLASS_DIR");
    for (k, v) in env {
        c.env(k, v);
    }
    let o: Output = c.output().expect("the binary runs");
    (o.status.code(), format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr)))
}

fn run(dir: &Path, args: &[&str]) -> (Option<i32>, String) {
    run_env(dir, args, &[])
}

/// The singlet with each (from, to) replaced once.
fn edited(edits: &[(&str, &str)]) -> String {
    let mut s = SINGLET.to_string();
    for (a, b) in edits {
        assert!(s.contains(a), "{a}");
        s = s.replacen(a, b, 1);
    }
    s
}

fn import_err(text: &str) -> String {
    import_zmx(text.as_bytes(), "t.zmx", None, &ZmxOptions::default()).map(|_| ()).unwrap_err().to_string()
}

/// No number of 20 digits or more (a 309-digit 1e300) in a message.
fn assert_no_long_number(m: &str) {
    let longest = m.split(|c: char| !c.is_ascii_digit()).map(str::len).max().unwrap_or(0);
    assert!(longest < 20, "a {longest}-digit number: {m}");
}

/// Finding 1: the file's fields are held, by line, to `--field-mm`'s ±1e6 mm and `--field-deg`'s (−90, 90)°,
/// image heights too; a field that converts to 90° or to an object height beyond 1e6 mm is refused at build.
#[test]
fn file_fields_are_held_to_the_command_line_limits() {
    let e = import_err(&edited(&[("FTYP 0 0 1 1", "FTYP 2 0 1 1"), ("YFLN 0", "YFLN 1e300")]));
    assert!(e.contains("line 7 `YFLN`: field 1 paraxial image height 1e300 mm is outside ±1e6 mm"), "{e}");
    let e = import_err(&edited(&[("FTYP 0 0 1 1", "FTYP 1 0 1 1"), ("YFLN 0", "YFLN 1e300"), ("DISZ INFINITY", "DISZ 200")]));
    assert!(e.contains("line 7 `YFLN`: field 1 object height 1e300 mm"), "{e}");
    let e = import_err(&edited(&[("XFLN 0", "XFLN -90")]));
    assert!(e.contains("line 6 `XFLN`: field 1 angle -90° is outside (-90, 90) degrees"), "{e}");
    // Within the limits, but converted (paraxial image height 1e4 mm over a magnification of ~1e-4) to an
    // object height of ~1e8 mm: refused when the system is built.
    let far = edited(&[("FTYP 0 0 1 1", "FTYP 2 0 1 1"), ("YFLN 0", "YFLN 1e4"), ("DISZ INFINITY", "DISZ 1e6")]);
    let imp = import_zmx(far.as_bytes(), "t.zmx", None, &ZmxOptions::default()).unwrap();
    let e = diffcassi::system::SequentialSystem::build(&imp.spec).map(|_| ()).unwrap_err().to_string();
    assert!(e.contains("fields_mm[0]") && e.contains("converts to the field") && e.contains("--field-mm"), "{e}");
    // Any spec format: fields_mm beyond 1e6 mm.
    let mut s = common::singlet_at_infinity(false);
    s.surfaces[0].thickness_mm = diffcassi::spec::Cell::fixed(100.0);
    s.field_type = diffcassi::spec::FieldType::ObjectHeight;
    s.fields_deg.clear();
    s.fields_mm = vec![[0.0, 1e300]];
    let e = s.validate().unwrap_err();
    assert!(e.contains("fields_mm[0] = (0, 1e300)") && e.contains("±1e6 mm"), "{e}");
}

/// Finding 2: a record given twice in one surface or in the system data, or two system apertures, is refused
/// naming both lines; what OpticStudio repeats (`NOTE 0` lines, `PARM`/`XDAT` of different indices) reads.
#[test]
fn records_given_twice_are_refused_naming_both_lines() {
    for (from, to, says) in [
        ("  CURV 0.01\n", "  CURV 0.01\n  CURV 0.02\n", "line 15 `CURV`: `CURV` given twice in surface 1 (the first: line 14 `CURV`)"),
        ("  DISZ 2\n", "  DISZ 2\n  DISZ 3\n", "line 16 `DISZ`: `DISZ` given twice in surface 1 (the first: line 15 `DISZ`)"),
        ("  GLAS N-BK7\n", "  GLAS N-BK7\n  GLAS F2\n", "line 17 `GLAS`: `GLAS` given twice in surface 1 (the first: line 16 `GLAS`)"),
        ("  CURV -0.01\n", "  CURV -0.01\n  CONI 0\n  CONI -1\n", "line 20 `CONI`: `CONI` given twice in surface 2 (the first: line 19 `CONI`)"),
        ("  CURV -0.01\n", "  CURV -0.01\n  CLAP 0 5 0\n  CLAP 0 6 0\n", "line 20 `CLAP`: `CLAP` given twice in surface 2"),
        ("ENPD 10\n", "ENPD 10\nFNUM 5 0\n", "line 4 `FNUM`: a second system aperture (the first: line 3 `ENPD`)"),
        ("ENPD 10\n", "ENPD 10\nENPD 12\n", "line 4 `ENPD`: a second system aperture (the first: line 3 `ENPD`)"),
        ("YFLN 0\n", "YFLN 0\nYFLN 1\n", "line 8 `YFLN`: `YFLN` given twice in the system data (the first: line 7 `YFLN`)"),
        ("FTYP 0 0 1 1 0 0 0\n", "FTYP 0 0 1 1 0 0 0\nFTYP 0 0 1 1 0 0 0\n", "line 6 `FTYP`: `FTYP` given twice"),
        ("GCAT SCHOTT\n", "GCAT SCHOTT\nGCAT OHARA\n", "line 5 `GCAT`: `GCAT` given twice"),
        ("PWAV 1\n", "WAVM 1 0.6 1\nPWAV 1\n", "line 9 `WAVM`: wavelength 1 given twice in the system data (the first: line 8 `WAVM`)"),
    ] {
        let e = import_err(&edited(&[(from, to)]));
        assert!(e.contains(says) && e.contains("remove one"), "{to:?}: {e}");
    }
    // Repeats OpticStudio writes: several `NOTE 0` lines, parameters and extra data of different indices.
    let ok = edited(&[("MODE SEQ\n", "MODE SEQ\nNOTE 0 first\nNOTE 0 second\n"), ("  CURV -0.01\n", "  TYPE EVENASPH\n  CURV -0.01\n  PARM 1 0\n  PARM 2 1e-6\n  XDAT 1 0\n  XDAT 2 0\n")]);
    import_zmx(ok.as_bytes(), "t.zmx", None, &ZmxOptions::default()).unwrap();
    let e = import_err(&edited(&[("  CURV -0.01\n", "  TYPE EVENASPH\n  CURV -0.01\n  PARM 2 1e-6\n  PARM 2 2e-6\n")]));
    assert!(e.contains("`PARM 2` given twice in surface 2"), "{e}");
}

/// A folder with `cat/EXTRA.agf` (one glass, `MYGL`) and `g.zmx`, the singlet in that glass.
fn with_extra_catalog() -> tempfile::TempDir {
    let d = tempfile::tempdir().unwrap();
    std::fs::create_dir(d.path().join("cat")).unwrap();
    std::fs::write(d.path().join("cat/EXTRA.agf"), "NM MYGL 2 0 1.6 50 0 0\nCD 1.5 0.01 0 0 0 0\nLD 0.3 2.5\n").unwrap();
    std::fs::write(d.path().join("g.zmx"), edited(&[("GLAS N-BK7", "GLAS MYGL")])).unwrap();
    d
}

/// Finding 3: `--glass-catalog` takes part in the search for the file's glasses (after the file's `GCAT`
/// catalogues); a glass found nowhere names every catalogue searched, the given one included.
#[test]
fn glass_catalog_option_is_searched_for_the_files_glasses() {
    let d = with_extra_catalog();
    std::fs::write(d.path().join("other.zmx"), edited(&[("GLAS N-BK7", "GLAS NOPE")])).unwrap();
    let (code, out) = run(d.path(), &["info", "--system", "g.zmx", "--glass-catalog", "cat/EXTRA.agf"]);
    assert_eq!(code, Some(0), "{out}");
    assert!(out.contains("MYGL") && out.contains("EXTRA.agf"), "{out}");
    let (code, out) = run(d.path(), &["trace", "--system", "g.zmx", "--glass-catalog", "cat/EXTRA.agf", "--pupil", "chief"]);
    assert_eq!(code, Some(0), "{out}");
    let (code, out) = run(d.path(), &["info", "--system", "other.zmx", "--glass-catalog", "cat/EXTRA.agf"]);
    assert_eq!(code, Some(1), "{out}");
    assert!(out.contains("line 16 `GLAS`: glass `NOPE`") && out.contains("EXTRA.agf") && out.contains("built-in SCHOTT"), "{out}");
    // Without it, the glass is in none (as before).
    let (code, out) = run(d.path(), &["info", "--system", "g.zmx"]);
    assert_eq!(code, Some(1), "{out}");
    assert!(out.contains("`MYGL`"), "{out}");
    // The library: ZmxOptions::glass_catalogs, recorded at the end of the spec's catalogues.
    let entry = d.path().join("cat/EXTRA.agf").display().to_string();
    let imp = import_zmx(edited(&[("GLAS N-BK7", "GLAS MYGL")]).as_bytes(), "g.zmx", None, &ZmxOptions { glass_catalogs: vec![entry.clone()], ..Default::default() }).unwrap();
    assert_eq!(imp.spec.glass_catalogs.last(), Some(&entry));
}

/// Finding 4: lens units other than millimetres and theodolite fields change every number: refused even with
/// `--ignore-unsupported`, saying how to fix the file.
#[test]
fn lens_units_and_theodolite_fields_are_refused_even_when_ignoring() {
    let d = tempfile::tempdir().unwrap();
    for (name, text, says) in [
        ("in.zmx", edited(&[("UNIT MM", "UNIT IN")]), vec!["line 2 `UNIT IN`", "millimetres", "--ignore-unsupported does not apply", "Scale Lens"]),
        ("cm.zmx", edited(&[("UNIT MM", "UNIT CM")]), vec!["line 2 `UNIT CM`", "millimetres"]),
        ("m.zmx", edited(&[("UNIT MM", "UNIT METER")]), vec!["line 2 `UNIT METER`"]),
        ("th.zmx", edited(&[("FTYP 0 0 1 1", "FTYP 4 0 1 1"), ("YFLN 0", "YFLN 5")]), vec!["line 5 `FTYP`: field type 4 (theodolite angles)", "--ignore-unsupported does not apply"]),
    ] {
        std::fs::write(d.path().join(name), text).unwrap();
        let (code, out) = run(d.path(), &["import-zmx", name, "--ignore-unsupported", "--out", "o.toml"]);
        assert_eq!(code, Some(1), "{name}: {out}");
        for s in says {
            assert!(out.contains(s), "{name}: `{s}` in {out}");
        }
        assert!(!d.path().join("o.toml").exists());
    }
}

/// Finding 5: the pupil an F/# gives is held to the limits of `ENPD`, naming `FNUM` and its line; an `ENPD`
/// below 1 nm is refused too.
#[test]
fn the_pupil_of_an_f_number_is_held_to_the_enpd_limits() {
    for f in ["1e-300", "1e300"] {
        let e = import_err(&edited(&[("ENPD 10", &format!("FNUM {f} 0"))]));
        assert!(e.contains(&format!("line 3 `FNUM`: image-space F/# {f} gives an entrance pupil diameter of")) && e.contains("[1e-6, 1000000] mm"), "{e}");
        assert_no_long_number(&e);
    }
    import_zmx(edited(&[("ENPD 10", "FNUM 5 0")]).as_bytes(), "t.zmx", None, &ZmxOptions::default()).unwrap();
    let e = import_err(&edited(&[("ENPD 10", "ENPD 1e-300")]));
    assert!(e.contains("entrance_pupil_diameter = 1e-300 mm"), "{e}");
}

/// Finding 6: a user catalogue whose formula gives an index outside [1, 5] at a wavelength used is refused
/// (glass, catalogue, wavelength, value); one whose formula misses its n_d by more than 1e-3 is warned about.
#[test]
fn implausible_catalogue_indices_are_refused_and_a_wrong_nd_warned() {
    let d = tempfile::tempdir().unwrap();
    std::fs::write(
        d.path().join("BAD.agf"),
        "NM HUGE 2 0 1.5 60 0 0\nCD 1e300 0.01 0 0 0 0\nLD 0.3 2.5\nNM NEG 2 0 1.5 60 0 0\nCD -0.5 0.01 0 0 0 0\nLD 0.3 2.5\nNM SLIGHT 2 0 1.5 60 0 0\nCD 1.3 0.01 0 0 0 0\nLD 0.3 2.5\n",
    )
    .unwrap();
    for (g, says) in [("HUGE", "n = 1.0148"), ("NEG", "n = 0.6964")] {
        std::fs::write(d.path().join("s.zmx"), edited(&[("GLAS N-BK7", &format!("GLAS {g}"))])).unwrap();
        let (code, out) = run(d.path(), &["info", "--system", "s.zmx", "--glass-catalog", "BAD.agf"]);
        assert_eq!(code, Some(1), "{out}");
        assert!(out.contains(&format!("glass {g} (catalogue BAD)")) && out.contains(says) && out.contains("587.56") && out.contains("[1, 5]"), "{out}");
        assert_no_long_number(&out);
    }
    std::fs::write(d.path().join("s.zmx"), edited(&[("GLAS N-BK7", "GLAS SLIGHT")])).unwrap();
    let (code, out) = run(d.path(), &["info", "--system", "s.zmx", "--glass-catalog", "BAD.agf"]);
    assert_eq!(code, Some(0), "{out}");
    assert!(out.contains("warning: glass SLIGHT (catalogue BAD)") && out.contains("n_d = 1.5"), "{out}");
    let (_, out) = run(d.path(), &["info", "--preset", "sp"]);
    assert!(!out.contains("warning"), "{out}");
}

/// Every glass of every built-in catalogue (the subset, the vendors', the legacy one) and of SCHOTT's AGF
/// (`/work/shared/reference/glass`, when present): no n_d warning, and an index within [1, 5] across its range.
#[test]
fn real_catalogues_pass_the_index_checks() {
    let mut cats: Vec<(String, GlassCatalog)> = vec![("subset".into(), GlassCatalog::builtin())];
    for n in builtin_catalogs::names() {
        cats.push((n.to_string(), builtin_catalogs::catalog(n).unwrap().unwrap()));
    }
    let reference = Path::new("/work/shared/reference/glass/SCHOTT.AGF");
    if reference.exists() {
        cats.push(("SCHOTT.AGF".into(), GlassCatalog::from_agf_file(reference).unwrap()));
    }
    let mut checked = 0;
    for (c, cat) in &cats {
        for g in cat.iter() {
            assert_eq!(g.nd_mismatch(), None, "{c} {}", g.name);
            let (lo, hi) = g.valid_range_nm();
            for k in 0..=16 {
                let w = lo + (hi - lo) * k as f64 / 16.0;
                if let Err(e) = g.refractive_index(w) {
                    assert!(!matches!(e, diffcassi::materials::MaterialError::ImplausibleIndex { .. }), "{c}: {e}");
                }
            }
            assert!(!g.in_range(D_LINE_NM) || g.refractive_index(D_LINE_NM).is_ok(), "{c} {}", g.name);
            checked += 1;
        }
    }
    assert!(checked > 1000, "{checked} glasses");
}

/// Finding 7: wavelengths are held to --wavelength-nm's range by line (no 309 digits), a subnormal `CURV` is
/// named by line, and the glass-range hint of a `.zmx` names the file's `DCWP allow_extrapolation` record.
#[test]
fn messages_name_line_and_record_with_short_numbers() {
    for (w, says) in [("1e300", "line 8 `WAVM`: wavelength 1e300 µm is outside 0.1–20 µm"), ("1e-9", "line 8 `WAVM`: wavelength 1e-9 µm")] {
        let e = import_err(&edited(&[("WAVM 1 0.5875618 1", &format!("WAVM 1 {w} 1"))]));
        assert!(e.contains(says), "{e}");
        assert_no_long_number(&e);
    }
    let e = import_err(&edited(&[("CURV 0.01", "CURV 1e-320")]));
    assert!(e.contains("line 14 `CURV`: curvature 1e-320 mm⁻¹") && e.contains("CURV 0"), "{e}");
    let d = tempfile::tempdir().unwrap();
    std::fs::write(d.path().join("w.zmx"), edited(&[("WAVM 1 0.5875618 1", "WAVM 1 3 1")])).unwrap();
    let (code, out) = run(d.path(), &["info", "--system", "w.zmx"]);
    assert_eq!(code, Some(1), "{out}");
    assert!(out.contains("DCWP allow_extrapolation") && !out.contains("wavelength_policy"), "{out}");
    // A TOML spec keeps its own hint.
    let mut s = common::singlet_at_infinity(false);
    s.wavelengths_nm = vec![3000.0];
    s.primary_wavelength_nm = 3000.0;
    let e = diffcassi::system::SequentialSystem::build(&s).map(|_| ()).unwrap_err().to_string();
    assert!(e.contains("wavelength_policy"), "{e}");
}

/// Finding 8: `DIFFCASSI_GLASS_DIR` naming a missing folder or a file is refused, naming the variable.
#[test]
fn a_bad_glass_dir_variable_is_refused() {
    let d = tempfile::tempdir().unwrap();
    std::fs::write(d.path().join("s.zmx"), SINGLET).unwrap();
    let file = d.path().join("s.zmx").display().to_string();
    for (v, says) in [("/nonexistent-glass", "no such folder"), (file.as_str(), "is a file, not a folder")] {
        let (code, out) = run_env(d.path(), &["info", "--system", "s.zmx"], &[("DIFFCASSI_GLASS_DIR", v)]);
        assert_eq!(code, Some(1), "{out}");
        assert!(out.contains("DIFFCASSI_GLASS_DIR") && out.contains(v) && out.contains(says), "{out}");
    }
    let (code, out) = run_env(d.path(), &["info", "--system", "s.zmx"], &[("DIFFCASSI_GLASS_DIR", d.path().to_str().unwrap())]);
    assert_eq!(code, Some(0), "{out}");
}

/// Finding 9: a last `GLAS` after the image's `SURF` belongs to that surface indented or not: both are the
/// same truncated file.
#[test]
fn a_last_glass_record_is_read_alike_whatever_its_indentation() {
    let a = import_err(&format!("{SINGLET}GLAS F2\n"));
    let b = import_err(&format!("{SINGLET}  GLAS F2\n"));
    assert_eq!(a, b);
    assert!(a.contains("line 22 `GLAS F2`: the image would be inside glass") && a.contains("truncated"), "{a}");
    // A record that is not a surface's still marks the end of the surfaces (the image's glass is then skipped).
    let ok = import_zmx(format!("{SINGLET}  GLAS F2\nMNUM 1 1\n").as_bytes(), "t.zmx", None, &ZmxOptions::default()).unwrap();
    assert!(ok.skipped.iter().any(|u| u.keyword == "GLAS"), "{:?}", ok.skipped);
}

/// Finding 10: an aperture on the object surface at infinity has no effect: refused (dropped and listed with
/// `--ignore-unsupported`), and refused in every spec format.
#[test]
fn an_aperture_on_an_object_at_infinity_is_refused() {
    let text = edited(&[("  DISZ INFINITY\n", "  DISZ INFINITY\n  CLAP 0 5 0\n")]);
    let e = import_err(&text);
    assert!(e.contains("line 12 `CLAP`: an aperture on the object surface (surface 0), which is at infinity"), "{e}");
    let imp = import_zmx(text.as_bytes(), "t.zmx", None, &ZmxOptions { ignore_unsupported: true, ..Default::default() }).unwrap();
    assert_eq!(imp.spec.surfaces[0].aperture, None);
    assert!(imp.ignored.iter().any(|u| u.keyword == "CLAP" && u.line == 12));
    let mut s = common::singlet_at_infinity(false);
    s.surfaces[0].aperture = imp.spec.surfaces[2].aperture.clone().or(Some(diffcassi::surfaces::Aperture::Circular { semi_diameter_mm: 5.0, min_radius_mm: 0.0, decenter_x_mm: 0.0, decenter_y_mm: 0.0 }));
    assert!(s.validate().unwrap_err().contains("surfaces[0].aperture"));
}

/// Finding 11: an afocal system's first-order line says so in words, never `inf`.
#[test]
fn an_afocal_system_prints_no_inf() {
    let fx = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/zmx/grating_flat_transmission_optiland.zmx");
    let d = tempfile::tempdir().unwrap();
    let (code, out) = run(d.path(), &["info", "--system", fx.to_str().unwrap()]);
    assert_eq!(code, Some(0), "{out}");
    let line = out.lines().find(|l| l.starts_with("first order")).expect("a first-order line");
    assert!(line.contains("EFL afocal (infinite)") && line.contains("F/# none (afocal)") && !line.contains("inf mm") && !line.contains("NaN"), "{line}");
}

/// Finding 12: `study --systems` names a FIFO or a folder as such (it said "no such file"), at once.
#[test]
fn study_systems_names_a_fifo_and_a_folder() {
    let d = tempfile::tempdir().unwrap();
    let fifo = d.path().join("fifo.zmx");
    assert!(Command::new("mkfifo").arg(&fifo).status().unwrap().success());
    std::fs::create_dir(d.path().join("dir.zmx")).unwrap();
    let t = std::time::Instant::now();
    for (name, says) in [("fifo.zmx", "is a named pipe (FIFO)"), ("dir.zmx", "is a folder"), ("none.zmx", "no such file")] {
        let (code, out) = run(d.path(), &["study", "--systems", name, "--out", "st"]);
        assert_eq!(code, Some(1), "{out}");
        assert!(out.contains(name) && out.contains("--systems") && out.contains(says), "{out}");
    }
    assert!(t.elapsed().as_secs() < 30);
    assert!(!d.path().join("st").exists());
}

/// `import-zmx --glass-catalog` (round 6; every other command reading a `.zmx` took it): the file's glass is
/// found in the given catalogue, which the written spec records (as an absolute path), so the spec builds
/// again on its own; the catalogue is an input (never the `--out`).
#[test]
fn import_zmx_takes_glass_catalogs() {
    let d = with_extra_catalog();
    let (code, out) = run(d.path(), &["import-zmx", "g.zmx", "--out", "g.toml"]);
    assert_eq!(code, Some(1), "{out}");
    assert!(out.contains("`MYGL`") && !d.path().join("g.toml").exists(), "{out}");
    let (code, out) = run(d.path(), &["import-zmx", "g.zmx", "--glass-catalog", "cat/EXTRA.agf", "--out", "g.toml"]);
    assert_eq!(code, Some(0), "{out}");
    let toml = std::fs::read_to_string(d.path().join("g.toml")).unwrap();
    let entry = d.path().join("cat/EXTRA.agf").display().to_string();
    assert!(toml.contains(&entry), "{toml}");
    let (code, out) = run(d.path(), &["info", "--system", "g.toml"]);
    assert_eq!(code, Some(0), "{out}");
    assert!(out.contains("MYGL") && out.contains("EXTRA.agf"), "{out}");
    let (code, out) = run(d.path(), &["import-zmx", "g.zmx", "--glass-catalog", "cat/EXTRA.agf", "--out", "cat/EXTRA.agf"]);
    assert_eq!(code, Some(1), "{out}");
    assert!(out.contains("--glass-catalog"), "{out}");
    assert!(std::fs::read_to_string(d.path().join("cat/EXTRA.agf")).unwrap().starts_with("NM MYGL"));
}
