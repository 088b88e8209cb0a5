//! Round 16 of the held-out battery (2 Dec 2026): calibration and design findings (docs/robustness.md,
//! round-16 row).
use crate::cli_run::{ok_cli as ok, run_cli as run};
use diffcassi::diff::Param;
use diffcassi::optim::{levenberg_marquardt, Bounds, Evaluation, LmOptions};
use diffcassi::spec::{save_spec_file, Cell, SystemSpec};
use std::path::{Path, PathBuf};

fn report(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// mSP with surface 4's x tilt (the prism's misalignment) set to `deg`, written to `dir/name`.
fn msp_tilted(dir: &Path, name: &str, deg: f64) -> PathBuf {
    let mut spec: SystemSpec = diffcassi::presets::spec("msp").unwrap();
    assert_eq!(spec.surfaces[4].tilt_x_deg.as_ref().unwrap().value, 5.0);
    spec.surfaces[4].tilt_x_deg = Some(Cell::fixed(deg));
    let path = dir.join(name);
    save_spec_file(&spec, &path).unwrap();
    path
}

/// `--from ap --observed map` printed truths read from mAP's surfaces 3 and 7 — other quantities there (mAP
/// numbers its surfaces differently: a dummy plane and more breaks) — with errors of 5° and 53°, no warning.
/// A truth is read only where the two number their surfaces alike; otherwise `null`, the reason, a warning.
#[test]
fn a_truth_is_read_only_where_the_surfaces_are_numbered_alike() {
    let d = tempfile::tempdir().unwrap();
    let rep = d.path().join("cal.json");
    let out = ok(d.path(), &["calibrate", "--from", "ap", "--observed", "map", "--free", "prism_tilt_x,prism_tilt_y,s7.tilt_y_deg", "--setup", "small", "--report", rep.to_str().unwrap()]);
    let v = report(&rep);
    for name in ["prism_tilt_x", "prism_tilt_y", "s7.tilt_y_deg"] {
        assert!(v["truth"][name].is_null(), "{name}: {}", v["truth"]);
        assert!(v["error"].get(name).is_none(), "{name}: {}", v["error"]);
        let why = v["truth_unknown"][name].as_str().unwrap();
        assert!(why.contains("numbers its surfaces differently") && why.contains("22 surfaces against --from's 18"), "{why}");
        assert!(out.contains(&format!("warning: {name}: no truth or error shown")), "{out}");
    }
    assert!(v["warnings"].as_array().unwrap().iter().any(|w| w.as_str().unwrap().contains("s7.tilt_y_deg: no truth")), "{}", v["warnings"]);
    assert!(!out.contains("-29.238"), "{out}");
    // The library's rule: the same layout reads the same cell (SP/mSP: 5°); another layout is unknown.
    let spec = |p: &str| diffcassi::presets::spec(p).unwrap().surfaces;
    let cell = |s: &str| Param::parse(s).unwrap();
    assert_eq!(diffcassi::calibration::truth_of(&cell("s4.tilt_x_deg"), &spec("sp"), &spec("msp")), Ok(5.0));
    assert!(diffcassi::calibration::truth_of(&cell("s7.tilt_y_deg"), &spec("ap"), &spec("map")).unwrap_err().contains("numbers its surfaces differently"));
    assert!(diffcassi::calibration::truth_of(&cell("glass_nd:N-BK7"), &spec("sp"), &spec("msp")).is_err());
    // The alias's documented meaning (AP's surface 3, mAP's 4: not the same rotation).
    assert!(diffcassi::diff::preset_alias("ap", "prism_tilt_x") != diffcassi::diff::preset_alias("map", "prism_tilt_x"));
    // SP/mSP keeps its truth and error.
    let rep2 = d.path().join("cal2.json");
    ok(d.path(), &["calibrate", "--from", "sp", "--observed", "msp", "--free", "prism_tilt_x", "--setup", "small", "--report", rep2.to_str().unwrap()]);
    let v = report(&rep2);
    assert_eq!(v["truth"]["prism_tilt_x"].as_f64(), Some(5.0));
    assert!(v["error"]["prism_tilt_x"].as_f64().unwrap().abs() < 1e-6);
    assert!(v["warnings"].as_array().unwrap().is_empty(), "{}", v["warnings"]);
    assert_eq!(v["bounds"]["prism_tilt_x"], serde_json::json!([-45.0, 45.0]));
}

/// A tilt started at −15° against a truth of 35° stopped at exactly 30° — calibrate's undocumented ±45° box —
/// with a 790 µm residual, "converged", no warning. The box is printed and reported, and the parameter on its
/// edge is warned about, naming it, the bound and that the optimum may lie beyond it.
#[test]
fn a_calibrated_parameter_on_its_bound_is_warned_about() {
    let d = tempfile::tempdir().unwrap();
    let from = msp_tilted(d.path(), "from.toml", -15.0);
    let obs = msp_tilted(d.path(), "obs.toml", 35.0);
    let rep = d.path().join("cal.json");
    let out = ok(d.path(), &["calibrate", "--from", from.to_str().unwrap(), "--observed", obs.to_str().unwrap(), "--free", "s4.tilt_x_deg,glass_nd:N-BAF10", "--setup", "small", "--report", rep.to_str().unwrap()]);
    let v = report(&rep);
    assert!((v["recovered"]["s4.tilt_x_deg"].as_f64().unwrap() - 30.0).abs() < 1e-9);
    assert_eq!(v["bounds"]["s4.tilt_x_deg"], serde_json::json!([-60.0, 30.0]));
    assert_eq!(v["bounds"]["glass_nd:N-BAF10"], serde_json::json!([null, null]));
    let needle = "s4.tilt_x_deg ends at its upper bound 30 (bounds [-60, 30]): the fit was stopped there, and the optimum may lie beyond it";
    assert!(out.contains(&format!("warning: {needle}")), "{out}");
    assert!(out.contains("bounds (start ± 45° on angles, ± 10 mm on lengths): s4.tilt_x_deg [-60.000000, 30.000000], glass_nd:N-BAF10 [unbounded, unbounded]"), "{out}");
    assert!(v["warnings"].as_array().unwrap().iter().any(|w| w.as_str() == Some(needle)), "{}", v["warnings"]);
    assert!(v["truth_unknown"]["glass_nd:N-BAF10"].as_str().unwrap().contains("not read from the observed spec"));
}

/// The optimiser itself: a minimum beyond the box ends on the bound, warned about; one inside is not.
#[test]
fn levenberg_marquardt_names_a_parameter_left_on_its_bound() {
    let fit = |target: f64| {
        let mut loss = |x: &[f64], _it: usize| -> diffcassi::Result<Evaluation> { Ok(Evaluation::new(vec![x[0] - target], vec![1.0], 1)) };
        levenberg_marquardt(&mut loss, &[0.0], &Bounds::new(vec![-1.0], vec![1.0]).unwrap(), &LmOptions { names: vec!["a".into()], ..Default::default() }).unwrap()
    };
    let r = fit(3.0);
    assert_eq!(r.x, vec![1.0]);
    assert!(r.warnings.iter().any(|w| w.starts_with("a ends at its upper bound 1 (bounds [-1, 1])")), "{:?}", r.warnings);
    let r = fit(0.5);
    assert!((r.x[0] - 0.5).abs() < 1e-9);
    assert!(r.warnings.is_empty(), "{:?}", r.warnings);
}

/// `design amici --final-thickness-weight 1000000` ended with α_c exactly on its −20° bound, the dispersion
/// 64 % off target, "converged", warnings []: the final stage's warning names it, on stderr and in the report.
#[test]
fn design_names_an_angle_left_on_its_bound() {
    let d = tempfile::tempdir().unwrap();
    let rep = d.path().join("d.json");
    let out = ok(d.path(), &["design", "amici", "--final-thickness-weight", "1000000", "--report", rep.to_str().unwrap()]);
    let v = report(&rep);
    assert!((v["alpha_c_deg"].as_f64().unwrap() + 20.0).abs() < 1e-9, "{}", v["alpha_c_deg"]);
    let w: Vec<&str> = v["final_stage"]["warnings"].as_array().unwrap().iter().filter_map(|w| w.as_str()).collect();
    assert!(w.iter().any(|w| w.starts_with("alpha_c_deg ends at its lower bound -20 (bounds [-20, 20])")), "{w:?}");
    assert!(out.contains("warning: final stage: alpha_c_deg ends at its lower bound -20"), "{out}");
}

/// A fit whose only parameter has no effect on the loss was "all parameters at bounds" while nowhere near one.
#[test]
fn a_fit_with_nothing_to_fit_says_so() {
    let d = tempfile::tempdir().unwrap();
    let rep = d.path().join("cal.json");
    let out = ok(d.path(), &["calibrate", "--from", "sp", "--observed", "msp", "--free", "s19.thickness_mm", "--setup", "small", "--report", rep.to_str().unwrap()]);
    let v = report(&rep);
    let stop = v["stop_reason"].as_str().unwrap();
    assert_eq!(stop, "nothing to fit: no free parameter affects the loss (s19.thickness_mm left unchanged)");
    assert!(!out.contains("at bounds"), "{out}");
    assert!(out.contains("warning: s19.thickness_mm does not affect the loss: left unchanged"), "{out}");
    assert!(!v["warnings"].as_array().unwrap().iter().any(|w| w.as_str().unwrap().contains("ends at its")), "{}", v["warnings"]);
}

/// Observed mSP with surface 16's aperture 3 mm, decentred 9 mm: "observation group 0: no ray reaches the
/// image" (the model side: "centroid 0: …"). The error names the system, the field point, the wavelength and
/// what the rays did.
#[test]
fn a_centroid_without_rays_names_its_field_wavelength_and_system() {
    let d = tempfile::tempdir().unwrap();
    let mut spec: SystemSpec = diffcassi::presets::spec("msp").unwrap();
    let ap = spec.surfaces[16].aperture.as_mut().expect("mSP's surface 16 has an aperture");
    let text = serde_json::to_string(ap).unwrap();
    let mut a: serde_json::Value = serde_json::from_str(&text).unwrap();
    a["semi_diameter_mm"] = serde_json::json!(3.0);
    a["decenter_x_mm"] = serde_json::json!(9.0);
    *ap = serde_json::from_value(a).unwrap();
    let vig = d.path().join("vig.toml");
    save_spec_file(&spec, &vig).unwrap();
    let (code, out) = run(d.path(), &["calibrate", "--from", "sp", "--observed", vig.to_str().unwrap(), "--free", "prism_tilt_x", "--setup", "small"]);
    assert_eq!(code, Some(1), "{out}");
    assert!(out.contains("--observed") && out.contains("vig.toml: no ray of field (-2.5, -2.5) mm at 450 nm reaches the image (7 of 7 pupil rays: 7 vignetted at surface 16)"), "{out}");
    let (code, out) = run(d.path(), &["calibrate", "--from", vig.to_str().unwrap(), "--observed", "msp", "--free", "s4.tilt_x_deg", "--setup", "small"]);
    assert_eq!(code, Some(1), "{out}");
    assert!(out.contains("the model (--from's system at s4.tilt_x_deg = 5): no ray of field (-2.5, -2.5) mm at 450 nm reaches the image"), "{out}");
    assert!(!out.contains("group 0") && !out.contains("centroid 0"), "{out}");
}

/// An AGF holding N-BK7 alone gave an N-SK2/N-SF10 design (the six built-ins were added silently): the design
/// now uses the file's glasses only, and its spec names the file.
#[test]
fn design_uses_the_given_catalogues_glasses_only() {
    let d = tempfile::tempdir().unwrap();
    let agf = d.path().join("one.agf");
    std::fs::write(
        &agf,
        "CC one glass\nNM N-BK7 2 517642.251 1.5168 64.17 0 1\nED 7.100000 8.300000 2.510000 -0.000900 0\n\
         CD 1.039612120E+00 6.000698670E-03 2.317923440E-01 2.001791440E-02 1.010469450E+00 1.035606530E+02 0.0 0.0\n\
         TD 1.860000E-06 1.310000E-08 -1.370000E-11 4.340000E-07 6.270000E-10 1.700000E-01 2.000000E+01\n\
         LD 3.00000E-01 2.50000E+00\n",
    )
    .unwrap();
    let (catalog, _) = diffcassi::design::design_catalog(Some(&agf)).unwrap();
    assert_eq!(catalog.names().collect::<Vec<_>>(), vec!["N-BK7"]);
    let rep = d.path().join("d.json");
    let spec = d.path().join("d.toml");
    ok(d.path(), &["design", "amici", "--glass-catalog", agf.to_str().unwrap(), "--iterations", "20", "--report", rep.to_str().unwrap(), "--system-out", spec.to_str().unwrap()]);
    let v = report(&rep);
    assert_eq!(v["glasses"], serde_json::json!(["N-BK7", "N-BK7", "N-BK7"]));
    let s = diffcassi::spec::load_spec_file(&spec).unwrap();
    assert_eq!(s.glass_catalogs.len(), 1);
    assert!(s.glass_catalogs[0].ends_with("one.agf"), "{:?}", s.glass_catalogs);
}
