//! A held-out prober's findings on `.zmx` files against optiland 0.6.3 (round 17), each fixed or refused by
//! line: real ray aiming (`RAIM 0 2`) with a decentred stop traced a much smaller pupil; `OBNA θ 1` (object cone
//! angle) read as an NA and `FNUM f 1` (paraxial working F/#) as the image-space F/#; `FTYP`'s
//! object-space-telecentric flag ignored; a lone CR joined two records, and UTF-16 with CR line ends was not
//! read; a short `WAVL` or `VDYN` and the aliases `YFLN`+`YFLD`, `WAVM`+`WAVL` taken silently; `DISZ 1e999` read
//! as INFINITY; the `UNIT mm` message. Fixtures: tests/fixtures/zmx/round17 (listed in tests/fixtures/zmx/README.md).
use diffcassi::rays::{aimed_ray, real_stop_radius, stop_crossing};
use diffcassi::spec::zmx::{import_zmx, import_zmx_file, ZmxOptions};
use diffcassi::spec::{RayAiming, SystemAperture};
use diffcassi::system::SequentialSystem;
use diffcassi::tracer::{AnalyticTracer, RayStatus, Tracer};
use diffcassi::rays::RayBatch;

const DIR: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/zmx/round17");

/// A singlet 150 mm from a finite object (builtin SCHOTT N-BK7), object-height fields.
const FINITE: &str = "MODE SEQ
UNIT MM X W X CM MR CPMM
OBNA 0.03 0
GCAT SCHOTT
FTYP 1 0 2 1 0 0 0
XFLN 0 0
YFLN 0 5
WAVM 1 0.5875618 1
PWAV 1
SURF 0
  DISZ 150
SURF 1
  STOP
  CURV 0.02
  DISZ 5
  GLAS N-BK7
SURF 2
  CURV -0.005
  DISZ 90
SURF 3
  DISZ 0
";

fn edited(base: &str, edits: &[(&str, &str)]) -> String {
    let mut s = base.to_string();
    for (a, b) in edits {
        assert!(s.contains(a), "{a}");
        s = s.replacen(a, b, 1);
    }
    s
}

fn read(text: &str) -> diffcassi::Result<diffcassi::spec::zmx::ZmxImport> {
    import_zmx(text.as_bytes(), "t.zmx", None, &ZmxOptions::default())
}

fn refused(text: &str, want: &[&str]) -> String {
    let e = read(text).expect_err("refused").to_string();
    for w in want {
        assert!(e.contains(w), "`{w}` not in: {e}");
    }
    e
}

fn build(path: &str) -> SequentialSystem {
    let imp = import_zmx_file(format!("{DIR}/{path}"), &ZmxOptions::default()).unwrap();
    SequentialSystem::build(&imp.spec).unwrap()
}

/// Finding 1. A strong singlet 10 mm before a stop that a Coordinate Break decentres by (0.6, 1.5) mm (undone
/// after it), `ENPD 8`, object at infinity, `RAIM 0 2`. optiland 0.6.3's iterative aiming (its real stop radius,
/// `RealReferenceStrategy`: the marginal ray offset from the chief ray aimed at the stop's centre) gives these
/// landings at 587.6 nm (image in the global frame, which the two breaks leave as the image's own). Before the
/// fix the landings were up to 0.10 mm off; the stop radius was measured from the stop's vertex to the unaimed
/// marginal ray's crossing.
#[test]
fn real_aiming_with_a_decentred_stop_matches_optiland() {
    const OPTILAND: &[([f64; 2], [f64; 2], [f64; 2])] = &[
        ([0.0, 0.0], [0.0, 0.0], [-0.4902593309258929, -1.2256483273147338]),
        ([0.0, 0.0], [0.0, 1.0], [-0.5768729769899591, -3.637884352364706]),
        ([0.0, 0.0], [0.0, -1.0], [-0.4805488772550359, 0.6276995950572162]),
        ([0.0, 0.0], [1.0, 0.0], [-2.61380097475634, -1.359594610683219]),
        ([0.0, 0.0], [0.7, 0.7], [-2.1062899492234473, -2.968498851716913]),
        ([0.0, 3.0], [0.0, 0.0], [-0.48252409020573317, 1.0035978084106318]),
        ([0.0, 3.0], [0.0, 1.0], [-0.5376230912498388, -1.1177515488142955]),
        ([0.0, 3.0], [0.0, -1.0], [-0.49487556626685003, 2.8798093618642024]),
        ([0.0, 3.0], [1.0, 0.0], [-2.5670762721653415, 0.9411161894358212]),
        ([0.0, 3.0], [0.7, 0.7], [-1.9929217919205713, -0.5255616193755372]),
        ([2.0, 1.0], [0.0, 0.0], [0.9909746883136837, -0.4753150594610194]),
        ([2.0, 1.0], [0.0, 1.0], [0.9788694839599074, -2.760973543719357]),
        ([2.0, 1.0], [0.0, -1.0], [0.9929792060375792, 1.3684681378393275]),
        ([2.0, 1.0], [1.0, 0.0], [-0.9983154671929104, -0.5498105938765363]),
        ([2.0, 1.0], [0.7, 0.7], [-0.48024483708330257, -2.064677876280771]),
    ];
    let sys = build("front_lens_decentred_stop_raim2.zmx");
    assert_eq!(sys.spec.ray_aiming, RayAiming::Real);
    // optiland's real stop radius 2.283728304986656 mm (the paraxial one is 2.372775 mm; the old reading 1.05 mm).
    assert!((sys.aim_stop_radius_mm - 2.283728304986656).abs() < 1e-9, "real stop radius {}", sys.aim_stop_radius_mm);
    let mut worst = 0.0f64;
    for (field, pupil, want) in OPTILAND {
        let f = [field[0].to_radians(), field[1].to_radians()];
        let rays = RayBatch::for_field(&sys, f, &[*pupil], 587.6).unwrap();
        let t = AnalyticTracer::default().trace(&sys, &rays).unwrap();
        assert_eq!(t.status[0], RayStatus::Ok);
        worst = worst.max((t.x[0] - want[0]).abs()).max((t.y[0] - want[1]).abs());
    }
    println!("decentred stop, RAIM 0 2: worst landing difference to optiland {worst:.3e} mm");
    assert!(worst < 1e-9, "worst {worst}");
    // The same lens with the stop centred: the radius is the centred one, unchanged (optiland 2.3540078305914447).
    let text = std::fs::read_to_string(format!("{DIR}/front_lens_decentred_stop_raim2.zmx")).unwrap();
    let centred = text.replace("  PARM 1 0.6\r\n  PARM 2 1.5\r\n", "").replace("  PARM 1 -0.6\r\n  PARM 2 -1.5\r\n", "");
    assert_ne!(centred, text);
    let opts = ZmxOptions { glass_dirs: vec![DIR.into()], ..Default::default() };
    let c = SequentialSystem::build(&import_zmx(centred.as_bytes(), "c.zmx", None, &opts).unwrap().spec).unwrap();
    assert!((c.aim_stop_radius_mm - 2.3540078305914447).abs() < 1e-9, "{}", c.aim_stop_radius_mm);
}

/// Finding 1, the prober's case: a singlet whose stop (its front surface) is decentred 4 mm. No lens before the
/// stop, so no pupil aberration: real aiming must equal paraxial aiming (a 10 mm beam from y = -1 to 9), where it
/// traced a 2 mm beam (radius 1 mm: 5 - 4).
#[test]
fn real_aiming_with_no_pupil_aberration_is_paraxial_aiming() {
    let sys = build("singlet_stop_decentred_4mm_raim2.zmx");
    assert!((sys.aim_stop_radius_mm - 5.0).abs() < 1e-12, "{}", sys.aim_stop_radius_mm);
    assert!((real_stop_radius(&sys).unwrap() - sys.pupil.stop_radius_mm).abs() < 1e-12);
    let n = sys.indices(587.6).unwrap();
    let (top, _) = aimed_ray(&sys, &n, [0.0, 0.0], 0.0, 1.0).unwrap();
    let (bottom, _) = aimed_ray(&sys, &n, [0.0, 0.0], 0.0, -1.0).unwrap();
    assert!((top.y - 9.0).abs() < 1e-9 && (bottom.y + 1.0).abs() < 1e-9, "beam from {} to {}", bottom.y, top.y);
    let (o, d) = aimed_ray(&sys, &n, [0.0, 0.0], 0.0, 0.0).unwrap();
    let (x, y) = stop_crossing(&sys, &n, o, d).unwrap();
    assert!(x.abs() < 1e-12 && y.abs() < 1e-12);
}

/// Finding 2. `OBNA θ 1` is the object cone angle (degrees): NA = sin θ in air; `FNUM f 1` is refused.
#[test]
fn obna_cone_angle_and_fnum_paraxial_working() {
    let na = |text: &str| match read(text).unwrap().spec.aperture {
        SystemAperture::ObjectSpaceNa(v) => v,
        other => panic!("{other:?}"),
    };
    assert_eq!(na(&edited(FINITE, &[("OBNA 0.03 0", "OBNA 0.5 0")])), 0.5);
    assert_eq!(na(&edited(FINITE, &[("OBNA 0.03 0", "OBNA 0.5")])), 0.5);
    let cone = na(&edited(FINITE, &[("OBNA 0.03 0", "OBNA 0.5 1")]));
    assert!((cone - 0.5f64.to_radians().sin()).abs() < 1e-17, "{cone}");
    assert!((na(&edited(FINITE, &[("OBNA 0.03 0", "OBNA 10 1")])) - 10f64.to_radians().sin()).abs() < 1e-16);
    // The pupil: a 0.5° cone 150 mm away is a 1.309 mm radius (86.6 mm when read as NA 0.5).
    let sys = SequentialSystem::build(&read(&edited(FINITE, &[("OBNA 0.03 0", "OBNA 0.5 1")])).unwrap().spec).unwrap();
    assert!((sys.pupil.radius_mm - 150.0 * 0.5f64.to_radians().tan()).abs() < 1e-9, "{}", sys.pupil.radius_mm);
    refused(&edited(FINITE, &[("OBNA 0.03 0", "OBNA 90 1")]), &["line 3 `OBNA`", "cone angle 90°", "(0, 90)"]);
    refused(&edited(FINITE, &[("OBNA 0.03 0", "OBNA 10 0")]), &["line 3 `OBNA`", "object-space NA 10", "OBNA θ 1"]);
    refused(&edited(FINITE, &[("OBNA 0.03 0", "OBNA 0.1 2")]), &["line 3 `OBNA`", "aperture type 2"]);
    // An object in glass (index per wavelength), an object at infinity: refused by line.
    refused(&edited(FINITE, &[("OBNA 0.03 0", "OBNA 5 1"), ("  DISZ 150\n", "  DISZ 150\n  GLAS N-BK7\n")]), &["line 3 `OBNA`", "in glass `N-BK7`"]);
    let inf = edited(FINITE, &[("OBNA 0.03 0", "OBNA 5 1"), ("DISZ 150", "DISZ INFINITY"), ("FTYP 1", "FTYP 0")]);
    refused(&inf, &["line 3 `OBNA`", "object at infinity"]);
    // FNUM f 1: the paraxial working F/#, refused naming the line and the type; FNUM f 0 read.
    let f1 = edited(FINITE, &[("OBNA 0.03 0", "FNUM 8 1")]);
    refused(&f1, &["line 3 `FNUM`", "Paraxial Working F/#", "FNUM 8 1"]);
    assert_eq!(read(&edited(FINITE, &[("OBNA 0.03 0", "FNUM 8 0")])).unwrap().spec.aperture, SystemAperture::ImageSpaceFNumber(8.0));
}

/// Finding 3. `FTYP`'s second value (telecentric object space) is refused, even with --ignore-unsupported; the
/// seventh (afocal image space) changes no ray and is listed.
#[test]
fn ftyp_telecentric_refused_afocal_listed() {
    let t = edited(FINITE, &[("FTYP 1 0 2 1 0 0 0", "FTYP 1 1 2 1 0 0 0")]);
    refused(&t, &["line 5 `FTYP`", "telecentric object space"]);
    let e = import_zmx(t.as_bytes(), "t.zmx", None, &ZmxOptions { ignore_unsupported: true, ..Default::default() }).unwrap_err();
    assert!(e.to_string().contains("telecentric"), "{e}");
    let a = read(&edited(FINITE, &[("FTYP 1 0 2 1 0 0 0", "FTYP 1 0 2 1 0 0 1 1")])).unwrap();
    assert!(a.skipped.iter().any(|u| u.line == 5 && u.keyword == "FTYP" && u.reason.contains("afocal")), "{:?}", a.skipped);
    assert_eq!(a.spec, read(FINITE).unwrap().spec);
}

/// Findings 4 and 5. Every line end (CRLF, LF, a CR alone) ends a record, in every encoding.
#[test]
fn every_line_end_is_a_line_break() {
    let want = read(FINITE).unwrap().spec;
    // A lone CR before `DISZ 5` joined it to `CURV 0.02` (thickness 0, silently).
    let lone = FINITE.replacen("\n  DISZ 5\n", "\r  DISZ 5\n", 1);
    assert_eq!(read(&lone).unwrap().spec, want);
    let cr_only = FINITE.replace('\n', "\r");
    for be in [false, true] {
        let mut bytes = if be { vec![0xFE, 0xFF] } else { vec![0xFF, 0xFE] };
        for u in cr_only.encode_utf16() {
            bytes.extend(if be { u.to_be_bytes() } else { u.to_le_bytes() });
        }
        assert_eq!(import_zmx(&bytes, "t.zmx", None, &ZmxOptions::default()).unwrap().spec, want, "UTF-16 BE {be}");
    }
    // Line numbers count a lone CR as a line end (as Python's universal newlines do).
    let bad = FINITE.replacen("\n  DISZ 5\n", "\r  DISZ 5e999\n", 1);
    refused(&bad, &["line 15 `DISZ`"]);
}

/// Finding 6. Short lists and the two spellings of one list are refused by line.
#[test]
fn short_or_conflicting_system_records() {
    let three = edited(FINITE, &[("FTYP 1 0 2 1", "FTYP 1 0 2 3"), ("WAVM 1 0.5875618 1\n", "WAVL 0.486 0.5876\n")]);
    refused(&three, &["line 8 `WAVL`", "2 wavelength(s)", "line 5 `FTYP`"]);
    // WAVL as long as the count, or longer (old files list unused ones), is read.
    assert_eq!(read(&three.replace("WAVL 0.486 0.5876\n", "WAVL 0.486 0.5876 0.656 0.55\n")).unwrap().spec.wavelengths_nm, vec![486.0, 587.6, 656.0]);
    let vd = edited(FINITE, &[("YFLN 0 5\n", "YFLN 0 5\nVDYN 0.1\n")]);
    refused(&vd, &["line 8 `VDYN`", "1 value(s) for 2 fields"]);
    refused(&edited(FINITE, &[("YFLN 0 5\n", "YFLN 0 5\nYFLD 0 6\n")]), &["line 8 `YFLD`", "line 7 `YFLN`", "given twice"]);
    refused(&edited(FINITE, &[("XFLN 0 0\n", "XFLD 0 0\nXFLN 0 0\n")]), &["line 7 `XFLN`", "line 6 `XFLD`", "given twice"]);
    refused(&edited(FINITE, &[("YFLN 0 5\n", "YFLN 0 5\nVDYN 0 0\nVDYF 0 0\n")]), &["line 9 `VDYF`", "line 8 `VDYN`", "given twice"]);
    refused(&edited(FINITE, &[("PWAV 1\n", "WAVL 0.486\nPWAV 1\n")]), &["line 9 `WAVL`", "line 8 `WAVM`", "both"]);
    refused(&edited(FINITE, &[("WAVM 1 0.5875618 1\n", "WAVL 0.5875618\nWAVM 1 0.5875618 1\n")]), &["line 9 `WAVM`", "line 8 `WAVL`", "both"]);
}

/// Finding 7. Only the word INFINITY is infinite: `1e999` (overflow) and `inf` are refused on the object too.
#[test]
fn only_the_word_infinity_is_infinite() {
    let at = |d: &str| edited(FINITE, &[("DISZ 150", d), ("OBNA 0.03 0", "ENPD 10"), ("FTYP 1", "FTYP 0")]);
    assert!(read(&at("DISZ INFINITY")).unwrap().spec.object_at_infinity());
    refused(&at("DISZ 1e999"), &["line 11 `DISZ`", "`1e999` is not finite", "overflows", "INFINITY"]);
    refused(&at("DISZ inf"), &["line 11 `DISZ`", "`inf` is not finite"]);
    refused(&edited(FINITE, &[("CURV 0.02", "CURV -1e999")]), &["line 14 `CURV`", "not finite"]);
}

/// Finding 8. `UNIT mm`: the message says the keyword is case-sensitive (OpticStudio writes `UNIT MM`).
#[test]
fn unit_keyword_case() {
    let e = refused(&edited(FINITE, &[("UNIT MM", "UNIT mm")]), &["line 2 `UNIT mm`", "case-sensitive", "`UNIT MM`"]);
    assert!(!e.contains("reads millimetres (MM) only"), "{e}");
    refused(&edited(FINITE, &[("UNIT MM", "UNIT IN")]), &["line 2 `UNIT IN`", "millimetres"]);
}
