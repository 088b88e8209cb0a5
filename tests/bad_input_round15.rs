//! Round 15 (2 Dec 2026): a held-out battery of users' lens files, front-end parity and GPU readiness. Each
//! case failed before its fix (docs/robustness.md, "round 15"); Python's side is
//! `tests/python/test_battery_round15.py`, C++'s `cpp/tests/test_errors.cpp` and `test_bitwise.cpp`.
use crate::cli_run::{ok_cli as ok, run_cli as run};
use diffcassi::spec::zmx::{import_zmx_file, to_zmx, ZmxOptions};
use diffcassi::system::SequentialSystem;
use std::path::{Path, PathBuf};

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/zmx/round15").join(name)
}

/// A toroid of radius of rotation 10 mm with a 12 mm semi-diameter loaded silently (its rays beyond |x| = 10 mm
/// miss the surface; the edge warning looked at the YZ curve only): warned about, naming the edge in x.
#[test]
fn a_toroid_beyond_its_edge_in_x_is_named() {
    let d = tempfile::tempdir().unwrap();
    let (code, text) = run(d.path(), &["info", "--system", fixture("toroid_beyond_x_edge.zmx").to_str().unwrap()]);
    assert_eq!(code, Some(0), "{text}");
    assert!(text.contains("warning: surface 1: semi-diameter 12 mm is beyond the toroid's edge in x: at y = 0 mm the surface reaches |x| = 10 mm (radius of rotation 10 mm)"), "{text}");
}

/// A paraboloid and its confocal secondary (exactly afocal) printed an EFL of 576460752303423488 mm, the
/// rounding of its powers' sum: now afocal, as an exactly cancelling sum was.
#[test]
fn an_afocal_system_up_to_rounding_is_afocal() {
    let d = tempfile::tempdir().unwrap();
    let out = ok(d.path(), &["info", "--system", fixture("cassegrain_afocal.zmx").to_str().unwrap()]);
    assert!(out.contains("EFL afocal (infinite), BFL none (afocal)"), "{out}");
    assert!(out.contains("F/# none (afocal)"), "{out}");
}

/// Two `GCAT` catalogue files holding one glass name: the first in `GCAT` order wins, as OpticStudio looks a
/// glass up (and rayoptics reads it); it was the last's. The export lists `GCAT` in that search order and
/// reads back to the same glass.
#[test]
fn the_first_gcat_catalogue_holding_a_glass_wins() {
    let dir = fixture("duplicate_glass");
    let text = std::fs::read_to_string(dir.join("duplicate_glass.zmx")).unwrap();
    assert!(text.contains("GCAT SCHOTT MYCAT\n"));
    let tmp = tempfile::tempdir().unwrap();
    for f in ["SCHOTT.AGF", "MYCAT.AGF"] {
        std::fs::copy(dir.join(f), tmp.path().join(f)).unwrap();
    }
    let nd = |gcat: &str| -> (f64, String) {
        let p = tmp.path().join("t.zmx");
        std::fs::write(&p, text.replace("GCAT SCHOTT MYCAT", gcat)).unwrap();
        let imp = import_zmx_file(&p, &ZmxOptions::default()).unwrap();
        let sys = SequentialSystem::build(&imp.spec).unwrap();
        let k = imp.spec.surfaces.iter().position(|s| s.material.as_deref() == Some("N-BK7")).unwrap();
        let n = sys.indices(diffcassi::materials::D_LINE_NM).unwrap()[k];
        // The export keeps the choice (its DCGC lines) and names the catalogues in OpticStudio's order; read back
        // beside the same catalogue files (a SCHOTT.AGF there took over MYCAT's glass, found by the `GCAT
        // SCHOTT` the export adds for the built-in subset: its GCAT names are not looked up again).
        let back = to_zmx(&imp.spec).unwrap();
        let back_path = tmp.path().join("back.zmx");
        std::fs::write(&back_path, &back).unwrap();
        let again = import_zmx_file(&back_path, &ZmxOptions::default()).unwrap();
        assert!(again.notes.is_empty(), "{:?}", again.notes);
        let n_back = SequentialSystem::build(&again.spec).unwrap().indices(diffcassi::materials::D_LINE_NM).unwrap()[k];
        assert_eq!(n.to_bits(), n_back.to_bits(), "{gcat}: {back}");
        let line = back.lines().find(|l| l.starts_with("GCAT ")).unwrap().to_string();
        (n, line)
    };
    let (schott, line) = nd("GCAT SCHOTT MYCAT");
    assert!((schott - 1.5168).abs() < 1e-4, "SCHOTT's N-BK7 first: n_d {schott}");
    assert_eq!(line, "GCAT SCHOTT MYCAT");
    let (mycat, line) = nd("GCAT MYCAT SCHOTT");
    assert!((mycat - 1.575796).abs() < 1e-4, "MYCAT's N-BK7 first: n_d {mycat}");
    assert_eq!(line, "GCAT MYCAT SCHOTT");
    let (alone, line) = nd("GCAT MYCAT");
    assert!((alone - 1.575796).abs() < 1e-4, "MYCAT's N-BK7: n_d {alone}");
    assert_eq!(line, "GCAT MYCAT SCHOTT");
}

/// `--device " cuda"` and `"cuda:0 "` were taken by the CLI (and Python's `mapping`), refused by Python's
/// `render`: refused everywhere, as torch refuses such a device string (exit 2, the option's parser).
#[test]
fn a_device_string_with_spaces_is_refused() {
    let d = tempfile::tempdir().unwrap();
    for dev in [" cuda", "cuda:0 ", " cpu"] {
        let (code, text) = run(d.path(), &["render", "--preset", "sp", "--scene-size", "8", "--planes", "2", "--rays", "1", "--device", dev, "--out", "x"]);
        assert_eq!(code, Some(2), "{dev:?}: {text}");
        assert!(text.contains("no spaces around it"), "{dev:?}: {text}");
        assert!(!d.path().join("x").exists());
    }
}

/// A driver library that answers the probe but lacks a function the launcher calls (a stub or partial driver)
/// made cudarc panic (`Missing symbol cuDevicePrimaryCtxRetain`, a backtrace, exit 101): the probe checks every
/// function the launcher calls first (`gpu::device::LAUNCHER_SYMBOLS`): one message naming it, exit 1, nothing
/// written.
#[test]
fn a_driver_library_lacking_a_launcher_function_is_one_clear_error() {
    let d = tempfile::tempdir().unwrap();
    let stub = r#"
typedef int CUresult;
CUresult cuInit(unsigned f) { (void)f; return 0; }
CUresult cuDeviceGetCount(int *n) { *n = 1; return 0; }
CUresult cuDeviceGet(int *d, int o) { *d = o; return 0; }
CUresult cuDeviceGetName(char *s, int len, int d) { (void)d; if (len > 5) { s[0] = 's'; s[1] = 't'; s[2] = 'u'; s[3] = 'b'; s[4] = 0; } return 0; }
CUresult cuDriverGetVersion(int *v) { *v = 13000; return 0; }
"#;
    std::fs::write(d.path().join("stub.c"), stub).unwrap();
    let cc = std::env::var("CC").unwrap_or_else(|_| "cc".into());
    let o = std::process::Command::new(&cc).args(["-shared", "-fPIC", "-o", "libcuda.so.1", "stub.c"]).current_dir(d.path()).output().expect("a C compiler runs");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_diffcassi"))
        .args(["render", "--preset", "sp", "--scene-size", "8", "--planes", "2", "--rays", "1", "--device", "cuda", "--out", "x"])
        .current_dir(d.path())
        .env("LD_LIBRARY_PATH", d.path())
        .env_remove("DIFFCASSI_CUDA_DRIVER")
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert!(e.contains("its library lacks cuDevicePrimaryCtxRetain") && !e.contains("panicked"), "{e}");
    assert!(!d.path().join("x").exists());
}
