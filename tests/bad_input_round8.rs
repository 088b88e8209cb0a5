//! Bad input, round 8 (30 Nov 2026): two held-out probers (the Python API and the new `diffcassi.study`;
//! the study on resume and the analysis commands at their extremes). The study's own cases are in
//! `reconstruct_study.rs`, the Python ones in `tests/python/test_study_api.py` and `test_battery_round8.py`.
use std::path::Path;

use crate::cli_run::{ok_cli as ok, run_cli as run};

fn json(p: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap()
}

/// `calibrate --observed` a system of another structure (SP observed as AP) printed a truth of 0 beside a
/// 115 µm residual, exit 0: it warns that the fit can only approximate it, shows no truth and records the
/// difference; a misaligned copy (SP observed as mSP) keeps its truth and no warning.
#[test]
fn calibrate_warns_when_the_observed_system_has_another_structure() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let (code, out) = run(dir, &["calibrate", "--from", "sp", "--observed", "ap", "--free", "prism_tilt_x", "--setup", "small", "--report", "r.json"]);
    assert_eq!(code, Some(0), "{out}");
    assert!(out.contains("warning: --observed ap is not --from sp") && out.contains("dummy planes aside"), "{out}");
    let r = json(&dir.join("r.json"));
    assert!(r["structure_difference"].as_str().is_some_and(|s| s.contains("dummy planes aside")), "{r}");
    assert!(r["truth"]["prism_tilt_x"].is_null() && r["error"].as_object().unwrap().is_empty(), "{r}");
    let out = ok(dir, &["calibrate", "--from", "sp", "--observed", "msp", "--free", "prism_tilt_x", "--setup", "small", "--report", "m.json"]);
    assert!(!out.contains("warning: --observed"), "{out}");
    let m = json(&dir.join("m.json"));
    assert!(m["structure_difference"].is_null() && m["truth"]["prism_tilt_x"].as_f64().is_some(), "{m}");
}

/// Auto exposure with the largest full well (1e9 e⁻) put K·peak one ulp above it and was refused, blaming
/// electrons per unit nobody gave.
#[test]
fn render_noise_takes_the_largest_full_well() {
    let d = tempfile::tempdir().unwrap();
    let out = ok(d.path(), &["render", "--preset", "sp", "--scene-size", "16", "--planes", "8", "--rays", "2", "--noise", "shot", "--full-well-e", "1e9", "--no-mapping", "--out", "r"]);
    assert!(!out.contains("error"), "{out}");
    let n = &json(&d.path().join("r/render.json"))["noise"];
    assert!((n["peak_electrons"].as_f64().unwrap() / 1e9 - 1.0).abs() < 1e-15, "{n}");
}

/// A TV weight is checked as given, before the solvers' f32 (1e200 was "TV weight inf"; 1e-50 ran as 0 while
/// the study recorded 1e-50).
#[test]
fn tv_weight_is_checked_as_given() {
    let d = tempfile::tempdir().unwrap();
    for w in ["1e200", "1e-50"] {
        let (code, out) = run(d.path(), &["study", "--synthetic", "1", "--scene-size", "12", "--presets", "sp", "--operators", "shift", "--tv-weight", w, "--out", "st"]);
        assert_eq!(code, Some(1), "{out}");
        assert!(out.contains(&format!("--tv-weight {w}")) && out.contains("f32"), "{out}");
        assert!(!d.path().join("st").exists());
    }
}

/// `render-dataset` reads its options once, through the library's render settings: a bad
/// `--scene-wavelengths` is named as such (parsed on its own first, it was named `--wavelength-nm`).
#[test]
fn render_dataset_names_a_bad_scene_wavelengths() {
    let d = tempfile::tempdir().unwrap();
    std::fs::create_dir(d.path().join("scenes")).unwrap();
    let ws = diffcassi::scene::synthetic_wavelengths();
    diffcassi::scene::save_npy(&diffcassi::scene::synthetic_scene(8, 8, &ws, 1), &d.path().join("scenes/a.npy")).unwrap();
    crate::cli_run::refused_cli(
        d.path(),
        &["render-dataset", "--scenes", "scenes", "--preset", "sp", "--scene-size", "8", "--planes", "3", "--rays", "1", "--scene-wavelengths", "450:650:0", "--out", "ds"],
        &["--scene-wavelengths `450:650:0`"],
    );
    assert!(!d.path().join("ds").exists());
}
