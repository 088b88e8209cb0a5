//! Round 14 (2 Dec 2026): what round 13 left noted. Each case failed before its fix (docs/robustness.md,
//! "round 14"); Python's side is `tests/python/test_battery_round14.py` and `test_render_tolerance.py`.
use crate::cli_run::{ok_cli as ok, run_cli as run};
use diffcassi::system::SequentialSystem;

/// `tests/fixtures/systems/beyond_hemisphere.toml` (the probers' singlet, its stop surface of radius 10 mm with a
/// 12 mm semi-diameter) with that semi-diameter set to `sd_mm`.
fn singlet(sd_mm: &str) -> String {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/systems/beyond_hemisphere.toml");
    let s = std::fs::read_to_string(path).unwrap().replacen("semi_diameter_mm = 12.0", &format!("semi_diameter_mm = {sd_mm}"), 1);
    assert!(s.contains(&format!("semi_diameter_mm = {sd_mm}")));
    s
}

/// A semi-diameter beyond a sphere's hemisphere was accepted silently: rays beyond the edge miss, and near it
/// the f32 kernel's rounding reached 83 µm. Every command that loads the system now warns, naming the surface,
/// the edge and the largest semi-diameter the surface has; the work goes on (exit 0). A hemisphere given
/// exactly, and every preset and shipped lens file, load without a warning.
#[test]
fn a_semi_diameter_beyond_the_surface_edge_is_named() {
    let d = tempfile::tempdir().unwrap();
    std::fs::write(d.path().join("beyond.toml"), singlet("12.0")).unwrap();
    std::fs::write(d.path().join("exact.toml"), singlet("10.0")).unwrap();
    let (code, text) = run(d.path(), &["spot", "--system", "beyond.toml", "--wavelength-nm", "520"]);
    assert_eq!(code, Some(0), "{text}");
    assert!(text.contains("warning: surface 1: semi-diameter 12 mm is beyond the surface's edge at r = 10 mm (radius 10 mm, conic 0)"), "{text}");
    assert!(text.contains("give a semi-diameter ≤ 10 mm"), "{text}");
    let out = ok(d.path(), &["spot", "--system", "exact.toml", "--wavelength-nm", "520"]);
    assert!(!out.contains("beyond the surface's edge"), "{out}");
    // (This singlet's faces cross at r = 7.55 mm, inside both semi-diameters (10 and 8 mm): that, and only
    // that, is warned about — the edge-thickness warning of round 21.)
    assert_eq!(out.matches("warning").count(), 1, "{out}");
    assert!(out.contains("cross at r = 7.5464 mm"), "{out}");
    // An oblate ellipsoid (k = 3) ends at 1/(|c|√(1+k)) = R/2; a paraboloid (k = −1) nowhere.
    let mut spec = diffcassi::spec::from_toml(&singlet("6.0"), "s.toml").unwrap();
    spec.surfaces[1].conic = Some(3.0.into());
    let w = SequentialSystem::build(&spec).unwrap().warnings();
    assert!(w.len() == 1 && w[0].contains("edge at r = 5 mm (radius 10 mm, conic 3)"), "{w:?}");
    spec.surfaces[1].conic = Some((-1.0).into());
    assert!(SequentialSystem::build(&spec).unwrap().warnings().is_empty());
    for p in diffcassi::presets::ALL_NAMES {
        let sys = SequentialSystem::build(&diffcassi::presets::spec(p).unwrap()).unwrap();
        assert!(sys.warnings().is_empty(), "{p}: {:?}", sys.warnings());
    }
    let fixtures = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/zmx");
    let mut files = 0;
    for f in std::fs::read_dir(&fixtures).unwrap() {
        let f = f.unwrap().path();
        if f.extension().is_none_or(|e| e != "zmx") {
            continue; // rayoptics' zmx_read_lens.log, written beside the files by the Python readers' tests
        }
        let sys = SequentialSystem::build(&diffcassi::spec::load_spec_file(&f).unwrap()).unwrap();
        assert!(sys.surface_edge_warnings().is_empty(), "{}: {:?}", f.display(), sys.surface_edge_warnings());
        files += 1;
    }
    assert!(files >= 8, "{files} lens files in {}", fixtures.display());
}

/// `--calibration-cache FILE` (a file named by mistake) was reported as "a corrupt calibration cache entry"
/// at every lookup, on the library's own stderr, and the render went on without a cache: it is refused before
/// any calibration, naming the option. A cache that cannot be written (its parent missing) is not an error,
/// and what the cache could not do is said in the choice's explanation, not printed by the library.
#[test]
fn a_calibration_cache_that_is_a_file_is_refused() {
    let d = tempfile::tempdir().unwrap();
    std::fs::write(d.path().join("afile"), "x").unwrap();
    let args = |cache: &str| -> Vec<String> {
        ["render", "--preset", "sp", "--scene-size", "8", "--planes", "4", "--tolerance-um", "5", "--calibration-cache", cache, "--out", "r", "--force"].iter().map(|s| s.to_string()).collect()
    };
    let a = args("afile");
    let (code, text) = run(d.path(), &a.iter().map(String::as_str).collect::<Vec<_>>());
    assert_eq!(code, Some(1), "{text}");
    assert!(text.contains("--calibration-cache afile: not a directory") && !text.contains("calibrated now"), "{text}");
    assert!(!d.path().join("r").exists());
    let a = args("afile/sub");
    let out = ok(d.path(), &a.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(out.contains("calibrated now") && out.contains("cache: not stored ("), "{out}");
    assert!(!out.contains("fidelity: could not cache"), "{out}");
}

/// A backend that does not model the system (Embree and a diffraction grating) was reported by the library on
/// its own stderr, nine lines of the same reason; the choice's explanation now names them in one line per
/// reason, and the calibration (cached) keeps them.
#[test]
fn candidates_left_out_are_said_in_the_choice() {
    let sys = SequentialSystem::build(&diffcassi::presets::spec("gsp").unwrap()).unwrap();
    let (cal, _) = diffcassi::fidelity::calibrate_backends(&sys, &[520.0], &diffcassi::fidelity::CacheOptions::none()).unwrap();
    assert!(cal.left_out.len() >= 3 && cal.left_out.iter().all(|l| l.backend.starts_with("embree") && l.reason.contains("diffraction grating")), "{:?}", cal.left_out);
    let choice = diffcassi::fidelity::choose_backend(&cal, 1.0, 1000).unwrap();
    let lines: Vec<&str> = choice.explanation.lines().filter(|l| l.contains("left out:")).collect();
    assert_eq!(lines.len(), 1, "{}", choice.explanation);
    assert!(lines[0].contains("embree-user:f64, embree-user:none") && lines[0].contains("surface 4 is a diffraction grating"), "{}", lines[0]);
    let d = tempfile::tempdir().unwrap();
    let (code, text) = run(d.path(), &["spot", "--preset", "gsp", "--wavelength-nm", "520", "--tolerance-um", "1", "--calibration-cache", "cache"]);
    assert_eq!(code, Some(0), "{text}");
    assert!(!text.contains("fidelity: candidate") && text.matches("left out:").count() == 1, "{text}");
}
