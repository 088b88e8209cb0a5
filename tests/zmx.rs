//! Zemax `.zmx` files in and out (issue 25): round trips of the four presets, the `--system file.zmx`
//! render bit for bit, UTF-16, and every bad input refused with its line and keyword, nothing written.
use diffcassi::analysis::{grid_distortion, spot_diagram};
use diffcassi::prelude::*;
use diffcassi::spec::{Cell, RayAiming, SurfaceKind, SurfaceSpec};
use diffcassi::spec::zmx::{import_zmx, to_zmx, ZmxOptions};
use std::path::PathBuf;
use std::process::{Command, Output};

fn run(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_diffcassi")).args(args).output().expect("the binary runs")
}

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("diffcassi-zmx-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn utf16_bom(text: &str) -> Vec<u8> {
    let mut b = vec![0xFF, 0xFE];
    for u in text.encode_utf16() {
        b.extend(u.to_le_bytes());
    }
    b
}

/// Export → import gives the identical spec (every value bit-identical) and identical traces: grid
/// distortion (13×13) and spots (hexapolar) of every field and wavelength equal to 1e-9 mm (in fact equal).
#[test]
fn presets_round_trip_through_zmx() {
    let tracer = AnalyticTracer::default();
    let pupil = PupilPattern::Hexapolar { rings: 4 }.points();
    for name in diffcassi::presets::NAMES {
        let spec = diffcassi::presets::spec(name).unwrap();
        let text = to_zmx(&spec).unwrap();
        let back = import_zmx(text.as_bytes(), &format!("{name}.zmx"), None, &ZmxOptions::default()).unwrap();
        assert!(back.ignored.is_empty());
        assert_eq!(back.spec, spec, "{name}: the spec read back differs");
        // UTF-16 with BOM, CRLF line ends (as OpticStudio writes) give the same spec.
        let crlf = text.replace('\n', "\r\n");
        let b16 = import_zmx(&utf16_bom(&crlf), "u16.zmx", None, &ZmxOptions::default()).unwrap();
        assert_eq!(b16.spec, spec, "{name}: UTF-16");
        let (a, b) = (SequentialSystem::build(&spec).unwrap(), SequentialSystem::build(&back.spec).unwrap());
        for &w in &spec.wavelengths_nm {
            let (ga, gb) = (grid_distortion(&a, &tracer, w, 13, 2.5).unwrap(), grid_distortion(&b, &tracer, w, 13, 2.5).unwrap());
            for (p, q) in ga.points.iter().zip(&gb.points) {
                assert!((p.real_x_mm - q.real_x_mm).abs() <= 1e-9 && (p.real_y_mm - q.real_y_mm).abs() <= 1e-9, "{name} {w} nm grid");
            }
            for f in &spec.fields_mm {
                let (sa, sb) = (spot_diagram(&a, &tracer, *f, w, &pupil).unwrap(), spot_diagram(&b, &tracer, *f, w, &pupil).unwrap());
                assert_eq!(sa.status, sb.status);
                for k in 0..sa.x_mm.len() {
                    assert!((sa.x_mm[k] - sb.x_mm[k]).abs() <= 1e-9 && (sa.y_mm[k] - sb.y_mm[k]).abs() <= 1e-9, "{name} {w} nm field {f:?}");
                }
            }
        }
    }
}

/// Values whose Zemax form (curvature 1/r, µm) does not give them back by the plain conversion still
/// round-trip bit for bit, as do every kind of surface, aperture and driver the spec has.
#[test]
fn every_column_round_trips_bit_identical() {
    let mut spec = diffcassi::presets::spec("sp").unwrap();
    spec.wavelengths_nm = vec![486.1327, 587.5618, 656.2725, 450.1];
    spec.primary_wavelength_nm = 587.5618;
    spec.ray_aiming = RayAiming::Real;
    spec.air_index = 1.000293;
    spec.surfaces[16].radius_mm = Some(Cell::variable(33.3400000001));
    spec.surfaces[17].radius_mm = Some(Cell::fixed(-0.1 - 0.2));
    let mut asph = SurfaceSpec::new(SurfaceKind::EvenAsphere);
    asph.radius_mm = Some(Cell::fixed(-1234.5678));
    asph.conic = Some(Cell::fixed(-0.5));
    asph.asphere_coefficients = vec![Cell::fixed(0.0), Cell::fixed(1.25e-7), Cell::variable(-3.3e-11)];
    asph.aperture = Some(diffcassi::surfaces::Aperture::Rectangular { half_width_x_mm: 9.0, half_width_y_mm: 8.5, decenter_x_mm: 0.1, decenter_y_mm: -0.2 });
    asph.comment = "asphere test".into();
    asph.thickness_mm = Cell::fixed(0.0);
    spec.surfaces.insert(18, asph);
    // A circular obscuration (OBSC with its OBDC decentre), values that print long.
    spec.surfaces[17].aperture =
        Some(diffcassi::surfaces::Aperture::CircularObscuration { min_radius_mm: 0.1 + 0.2, max_radius_mm: 2.0 / 3.0, decenter_x_mm: -0.3, decenter_y_mm: 1e-7 });
    spec.surfaces[4].order = 1;
    // Vignetting factors per field (VDXN … VCYN), values that print long.
    spec.vignetting_factors = vec![[0.0; 4], [0.1 + 0.2, -1.0 / 3.0, 1e-9, -0.25], [0.0, 0.0, 0.0, 0.0], [2.0 / 7.0, 0.0, 0.999, 0.5]];
    let text = to_zmx(&spec).unwrap();
    let back = import_zmx(text.as_bytes(), "x.zmx", None, &ZmxOptions::default()).unwrap().spec;
    assert_eq!(back, spec);
    // Paraxial ray aiming (`RAIM 0 1`) too.
    let paraxial = {
        let mut p = spec.clone();
        p.ray_aiming = RayAiming::Paraxial;
        p
    };
    assert!(to_zmx(&paraxial).unwrap().contains("RAIM 0 1 "));
    assert_eq!(import_zmx(to_zmx(&paraxial).unwrap().as_bytes(), "x.zmx", None, &ZmxOptions::default()).unwrap().spec, paraxial);
    for (a, b) in spec.surfaces.iter().zip(&back.surfaces) {
        assert_eq!(a.radius_mm.as_ref().map(|c| c.value.to_bits()), b.radius_mm.as_ref().map(|c| c.value.to_bits()));
    }
    for (a, b) in spec.wavelengths_nm.iter().zip(&back.wavelengths_nm) {
        assert_eq!(a.to_bits(), b.to_bits());
    }
}

/// The preset written as a `.zmx` file (Coordinate Break prism) renders through `render --system file.zmx`
/// to the same acquisition as `render --preset`, bit for bit.
#[test]
fn render_through_zmx_is_bit_identical() {
    let zmx = tmp("sp-render.zmx");
    let o = run(&["export-spec", "--preset", "sp", "--format", "zmx", "--out", zmx.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(std::fs::read_to_string(&zmx).unwrap().contains("TYPE COORDBRK"));
    let common = ["--synthetic", "3", "--scene-size", "16", "--planes", "4", "--rays", "3", "--no-mapping", "--seed", "5"];
    let (a, b) = (tmp("render-preset"), tmp("render-zmx"));
    let mut args: Vec<&str> = vec!["render", "--preset", "sp"];
    args.extend(common);
    args.extend(["--out", a.to_str().unwrap()]);
    let o = run(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let mut args: Vec<&str> = vec!["render", "--system", zmx.to_str().unwrap()];
    args.extend(common);
    args.extend(["--out", b.to_str().unwrap()]);
    let o = run(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let (ea, eb) = (std::fs::read(a.join("acquisition.exr")).unwrap(), std::fs::read(b.join("acquisition.exr")).unwrap());
    assert!(!ea.is_empty());
    assert_eq!(ea, eb, "the acquisitions differ");
}

/// `import-zmx` writes a spec equal to the preset; `info --system x.zmx` works; `--format` must match `--out`.
#[test]
fn import_zmx_command() {
    let zmx = tmp("ap.zmx");
    assert!(run(&["export-spec", "--preset", "ap", "--out", zmx.to_str().unwrap()]).status.success());
    let toml = tmp("ap-imported.toml");
    let o = run(&["import-zmx", zmx.to_str().unwrap(), "--out", toml.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    // export-spec writes the built system's spec (solves resolved), as for TOML.
    let built = SequentialSystem::build(&diffcassi::presets::spec("ap").unwrap()).unwrap().spec;
    assert_eq!(diffcassi::spec::load_spec_file(&toml).unwrap(), built);
    let o = run(&["info", "--system", zmx.to_str().unwrap()]);
    assert!(o.status.success() && String::from_utf8_lossy(&o.stdout).contains("Coordinate Break"));
    let bad = tmp("ap-wrong.toml");
    let o = run(&["export-spec", "--preset", "ap", "--format", "zmx", "--out", bad.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("--format zmx"), "{}", stderr(&o));
    assert!(!bad.exists());
    // The output policy: `--out` the input .zmx itself is refused and the file is left byte for byte.
    let before = std::fs::read(&zmx).unwrap();
    let o = run(&["import-zmx", zmx.to_str().unwrap(), "--out", zmx.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("--out"), "{}", stderr(&o));
    assert_eq!(std::fs::read(&zmx).unwrap(), before);
}

/// What is not modelled is refused, listing every item by line and keyword; with --ignore-unsupported the
/// import goes on and warns with the same list. Tolerance operands are skipped and listed (no optics).
#[test]
fn unsupported_items_refused_or_listed() {
    let text = to_zmx(&diffcassi::presets::spec("sp").unwrap()).unwrap();
    // A vignetting angle (VAN; the decentre and compression factors are modelled) and a second configuration.
    let text = text.replace("VANN 0 0 0 0", "VANN 0 5 0 0").replace("MNUM 1 1", "MNUM 2 1\nTOL TTHI 1 2 0.1 -0.1");
    let vdxn = text.lines().position(|l| l.starts_with("VANN")).unwrap() + 1;
    let path = tmp("unsupported.zmx");
    std::fs::write(&path, &text).unwrap();
    let out = tmp("unsupported.toml");
    let o = run(&["import-zmx", path.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    // A tolerance operand carries no optics of the nominal system: skipped and listed, not refused (issue 42).
    assert!(e.contains(&format!("line {vdxn} `VANN`")) && e.contains("`MNUM`") && !e.contains("`TOL`") && e.contains("2 item(s)"), "{e}");
    assert!(!out.exists());
    let o = run(&["info", "--system", path.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1));
    let o = run(&["import-zmx", path.to_str().unwrap(), "--out", out.to_str().unwrap(), "--ignore-unsupported"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let e = stderr(&o);
    assert!(e.contains("warning") && e.contains("2 item(s) ignored") && e.contains("`VANN`"), "{e}");
    let listed = String::from_utf8_lossy(&o.stdout);
    assert!(listed.contains("skipped, no optics") && listed.contains("TOL ×1") && listed.contains("tolerance operand `TTHI`"), "{listed}");
    assert!(out.exists());
}

/// A GCAT catalogue is read from the file's folder; a glass found in no catalogue names its line, the
/// keyword, and the missing catalogue.
#[test]
fn glass_catalogues() {
    let spec = diffcassi::presets::spec("sp").unwrap();
    let text = to_zmx(&spec).unwrap().replace("GCAT SCHOTT", "GCAT SCHOTT MYCAT").replace("GLAS N-BK7", "GLAS MY-GLASS");
    let dir = tmp("glass");
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("cat.zmx");
    std::fs::write(&path, &text).unwrap();
    let e = diffcassi::spec::load_spec_file(&path).unwrap_err().to_string();
    let line = text.lines().position(|l| l.contains("GLAS MY-GLASS")).unwrap() + 1;
    assert!(e.contains(&format!("line {line} `GLAS`")) && e.contains("MY-GLASS") && e.contains("MYCAT.AGF"), "{e}");
    // N-BK7 renamed, from a user AGF in the file's folder (copied from the built-in data).
    let agf = "NM MY-GLASS 2 517642.000 1.5168 64.17 0 0 0 0\nCD 1.03961212 0.00600069867 0.231792344 0.0200179144 1.01046945 103.560653 0 0 0 0\nLD 0.3 2.5\n";
    std::fs::write(dir.join("mycat.agf"), agf).unwrap();
    let got = diffcassi::spec::load_spec_file(&path).unwrap();
    assert_eq!(got.glass_catalogs, vec![dir.join("mycat.agf").display().to_string()]);
    let sys = SequentialSystem::build_with_catalog(&got, &{
        let mut c = diffcassi::materials::GlassCatalog::builtin();
        c.merge(diffcassi::materials::GlassCatalog::from_agf_file(dir.join("mycat.agf")).unwrap());
        c
    })
    .unwrap();
    let reference = SequentialSystem::build(&spec).unwrap();
    assert_eq!(sys.indices(520.0).unwrap(), reference.indices(520.0).unwrap());
}

fn refused(name: &str, bytes: &[u8], needles: &[&str]) {
    let path = tmp(name);
    std::fs::write(&path, bytes).unwrap();
    let out = tmp(&format!("{name}.toml"));
    let o = run(&["import-zmx", path.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1), "{name}: {}", stderr(&o));
    let e = stderr(&o);
    assert!(!e.contains("panicked"), "{name}: {e}");
    for n in needles {
        assert!(e.contains(n), "{name}: `{n}` not in: {e}");
    }
    assert!(!out.exists(), "{name}: an output was written");
    let o = run(&["info", "--system", path.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1), "{name} via --system");
}

/// Bad input: each is an error naming the problem (line and keyword where there is one), exit 1, nothing
/// written, through `import-zmx` and `--system`.
#[test]
fn bad_input_rows() {
    let good = to_zmx(&diffcassi::presets::spec("sp").unwrap()).unwrap();
    let line_of = |text: &str, pat: &str| text.lines().position(|l| l.contains(pat)).unwrap() + 1;
    // Truncated: mid-record, mid-file (no final line break), before any surface, an empty SURF block.
    let cut = &good[..good.find("PARM 4 -19.68").unwrap() + 7];
    refused("trunc-record.zmx", format!("{cut}\n").as_bytes(), &[&format!("line {} `PARM`", line_of(cut, "PARM 4")), "argument 2 missing"]);
    refused("trunc-eol.zmx", &good.as_bytes()[..good.len() - 5], &["truncated"]);
    refused("trunc-header.zmx", &good.as_bytes()[..good.find("SURF 0").unwrap()], &["no `SURF` record"]);
    let cut = &good[..good.find("SURF 5").unwrap() + 7];
    refused("trunc-surf.zmx", cut.as_bytes(), &["`SURF 5`", "truncated"]);
    // Unknown (not modelled) surface type: OpticStudio's Binary 2 (TOROIDAL and DGRATING are read since issue 42).
    let t = good.replacen("TYPE PARAXIAL", "TYPE BINARY_2", 1);
    refused("type.zmx", t.as_bytes(), &[&format!("line {} `TYPE`", line_of(&t, "BINARY_2")), "BINARY_2"]);
    // Missing glass catalogue.
    let t = good.replace("GCAT SCHOTT", "GCAT NOSUCHCAT").replace("GLAS N-BK7", "GLAS XYZ-9");
    refused("catalog.zmx", t.as_bytes(), &[&format!("line {} `GLAS`", line_of(&t, "GLAS XYZ-9")), "NOSUCHCAT.AGF", "XYZ-9"]);
    // NaN / inf values.
    let t = good.replacen("DISZ 6.0", "DISZ NaN", 1);
    refused("nan.zmx", t.as_bytes(), &[&format!("line {} `DISZ`", line_of(&t, "DISZ NaN")), "NaN"]);
    let t = good.replacen("PARM 4 -19.68", "PARM 4 inf", 1);
    refused("inf.zmx", t.as_bytes(), &[&format!("line {} `PARM`", line_of(&t, "PARM 4 inf")), "not finite"]);
    let t = good.replacen("CURV 0.0", "CURV 1e999", 1);
    refused("inf-curv.zmx", t.as_bytes(), &["`CURV`", "not finite"]);
    let t = good.replacen("DISZ 50.0", "DISZ INFINITY", 1);
    // An object at infinity is read (tests/infinity.rs); with object heights (FTYP 1) it is refused, naming both lines.
    refused("inf-object.zmx", t.as_bytes(), &[&format!("line {} `DISZ`", line_of(&t, "DISZ INFINITY")), "`FTYP`", "infinity"]);
    // UTF-16 without BOM, a binary file, an empty file.
    let no_bom = utf16_bom(&good)[2..].to_vec();
    refused("nobom.zmx", &no_bom, &["UTF-16", "byte-order mark"]);
    let mut binary: Vec<u8> = (0u8..=255).cycle().take(4096).collect();
    binary[..4].copy_from_slice(b"PK\x03\x04");
    refused("binary.zmx", &binary, &["binary"]);
    refused("empty.zmx", b"", &["empty file"]);
    refused("text.zmx", b"hello world\nthis is not a lens\n", &["line 1", "not a .zmx record"]);
    // Out-of-order surfaces, a model glass, a mirror, no system aperture.
    let t = good.replacen("SURF 3", "SURF 7", 1);
    refused("order.zmx", t.as_bytes(), &["`SURF`", "out of order"]);
    let t = good.replacen("GLAS N-BK7 0 0", "GLAS ___BLANK 1 0", 1);
    refused("model.zmx", t.as_bytes(), &["`GLAS`", "model glass"]);
    // FNUM and FLOA are read (tests/infinity.rs); the object cone angle is not.
    let t = good.replacen("OBNA 0.05 0", "OBSA 4 0", 1);
    refused("obsa.zmx", t.as_bytes(), &["line 5 `OBSA`", "aperture type not modelled"]);
    // A circular obscuration (OBSC rmin rmax) with a negative, NaN or crossed radius: line, keyword, surface, value.
    let with_obsc = |rec: &str| good.replacen("SURF 2\n", &format!("SURF 2\n  {rec}\n"), 1);
    for (name, rec, says) in [
        ("obsc-neg.zmx", "OBSC -1 2.5 0", vec!["surface 2", "minimum radius -1 mm", "≥ 0"]),
        ("obsc-nan.zmx", "OBSC 0 NaN 0", vec!["surface 2", "argument 2 is NaN", "maximum radius"]),
        ("obsc-inf.zmx", "OBSC 0 INFINITY 0", vec!["surface 2", "maximum radius inf mm"]),
        ("obsc-order.zmx", "OBSC 3 2.5 0", vec!["surface 2", "radii 3 to 2.5 mm", "must not exceed"]),
        ("obsc-text.zmx", "OBSC 0 big 0", vec!["surface 2", "`big` is not a number"]),
    ] {
        let t = with_obsc(rec);
        let mut needles = vec![format!("line {} `OBSC`", line_of(&t, rec))];
        needles.extend(says.iter().map(|s| s.to_string()));
        refused(name, t.as_bytes(), &needles.iter().map(|s| s.as_str()).collect::<Vec<_>>());
    }
    // One aperture type per surface.
    let t = with_obsc("OBSC 0 2.5 0\n  CLAP 0 9 0");
    refused("obsc-clap.zmx", t.as_bytes(), &["surface 2", "CLAP", "OBSC", "one aperture type"]);
}

#[test]
fn library_loader_dispatches_on_extension() {
    let path = tmp("lib.ZMX");
    diffcassi::spec::save_spec_file(&diffcassi::presets::spec("msp").unwrap(), &path).unwrap();
    assert_eq!(diffcassi::spec::load_spec_file(&path).unwrap(), diffcassi::presets::spec("msp").unwrap());
}
