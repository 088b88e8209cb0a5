//! Optimisers, calibration and the double-Amici design: acceptance numbers and degenerate cases.
//! `cargo test --release --test integration design:: -- --nocapture` prints the measured numbers.
use diffcassi::calibration::{add_noise, calibrate, observe, CalibrationSetup};
use diffcassi::design::amici::AmiciLoss;
use diffcassi::design::{design_amici, design_catalog, AmiciOptions};
use diffcassi::diff::{Param, ParamSet};
use diffcassi::materials::GlassCatalog;
use diffcassi::optim::{adam, levenberg_marquardt, AdamOptions, Bounds, Evaluation, LmOptions};
use diffcassi::prelude::*;
use std::process::Command;

#[test]
fn calibration_recovers_the_five_degree_tilt() {
    let setup = CalibrationSetup::standard();
    let observed = observe(&SequentialSystem::build(&presets::spec("msp").unwrap()).unwrap(), &setup).unwrap();
    let set = ParamSet::new(presets::spec("sp").unwrap(), GlassCatalog::builtin(), vec![Param::parse("s4.tilt_x_deg").unwrap()]).unwrap();
    let fit = calibrate(&set, &observed, &setup).unwrap();
    println!("noiseless: recovered {:.10}° (error {:.2e}°), residual {:.2e} µm", fit.x[0], fit.x[0] - 5.0, fit.residual_um);
    assert!((fit.x[0] - 5.0).abs() <= 0.01);
    assert!(fit.residual_um < 1e-3);
    let mut noisy = observed.clone();
    add_noise(&mut noisy, 1.0, 7);
    let fit = calibrate(&set, &noisy, &setup).unwrap();
    println!("1 µm noise: recovered {:.6}° (error {:.2e}°), residual {:.3} µm RMS", fit.x[0], fit.x[0] - 5.0, fit.residual_um);
    assert!((fit.x[0] - 5.0).abs() < 0.05, "{}", fit.x[0]);
    assert!(fit.residual_um > 0.5 && fit.residual_um < 3.0, "the residual reflects the noise: {}", fit.residual_um);
}

#[test]
fn calibration_of_three_tilts_finds_x_only() {
    let setup = CalibrationSetup::small();
    let observed = observe(&SequentialSystem::build(&presets::spec("msp").unwrap()).unwrap(), &setup).unwrap();
    let free = ["s4.tilt_x_deg", "s4.tilt_y_deg", "s4.tilt_z_deg"].iter().map(|t| Param::parse(t).unwrap()).collect();
    let set = ParamSet::new(presets::spec("sp").unwrap(), GlassCatalog::builtin(), free).unwrap();
    let fit = calibrate(&set, &observed, &setup).unwrap();
    assert!((fit.x[0] - 5.0).abs() < 1e-6 && fit.x[1].abs() < 1e-6 && fit.x[2].abs() < 1e-6, "{:?}", fit.x);
}

#[test]
fn optimisers_handle_degenerate_problems() {
    // No parameters.
    let mut f = |_x: &[f64], _i: usize| Ok(Evaluation::new(vec![1.0], vec![], 0));
    assert!(levenberg_marquardt(&mut f, &[], &Bounds::unbounded(0), &LmOptions::default()).unwrap_err().to_string().contains("no free parameters"));
    // A parameter the loss ignores is reported and left alone; the other converges.
    let mut g = |x: &[f64], _i: usize| Ok(Evaluation::new(vec![x[0] - 3.0], vec![1.0, 0.0], 2));
    let r = levenberg_marquardt(&mut g, &[0.0, 7.0], &Bounds::unbounded(2), &LmOptions::default()).unwrap();
    assert_eq!(r.insensitive, vec![1]);
    assert!((r.x[0] - 3.0).abs() < 1e-10 && r.x[1] == 7.0);
    let r = adam(&mut g, &[0.0, 7.0], &Bounds::unbounded(2), &AdamOptions { iterations: 3000, learning_rate: vec![0.05], ..Default::default() }).unwrap();
    assert_eq!(r.insensitive, vec![1]);
    assert!((r.x[0] - 3.0).abs() < 1e-2 && r.x[1] == 7.0, "{:?}", r.x);
    // A NaN gradient at the start is an error naming the entry.
    let mut h = |_x: &[f64], _i: usize| Ok(Evaluation::new(vec![1.0], vec![f64::NAN], 1));
    let e = levenberg_marquardt(&mut h, &[0.0], &Bounds::unbounded(1), &LmOptions::default()).unwrap_err();
    assert!(e.to_string().contains("not finite"), "{e}");
    // Bounds hold: the minimum at 3 is outside [−1, 1].
    let mut q = |x: &[f64], _i: usize| Ok(Evaluation::new(vec![x[0] - 3.0], vec![1.0], 1));
    let r = levenberg_marquardt(&mut q, &[0.0], &Bounds::new(vec![-1.0], vec![1.0]).unwrap(), &LmOptions::default()).unwrap();
    assert_eq!(r.x[0], 1.0);
    let r = adam(&mut q, &[0.0], &Bounds::new(vec![-1.0], vec![1.0]).unwrap(), &AdamOptions::default()).unwrap();
    assert_eq!(r.x[0], 1.0);
}

#[test]
fn design_loss_jacobian_matches_finite_differences() {
    let (catalog, _) = design_catalog(None).unwrap();
    let loss = AmiciLoss::new(diffcassi::design::amici::base_spec("N-SK2", "N-SF10").unwrap(), catalog, false, None, 0.9519f64.to_radians()).unwrap();
    let u = [5.3, 29.5, 48.3];
    let (e, _) = loss.evaluate_full(&u, 0).unwrap();
    for c in 0..3 {
        let r = |d: f64| {
            let mut v = u;
            v[c] += d;
            loss.evaluate_full(&v, 0).unwrap().0.residuals
        };
        // The distortion residual carries the ABCD's finite difference over the field (±2.5e-4 mm), whose
        // rounding (~5e-7 µm, from the chief-ray-solved image frame) needs a large step: 0.05° (the
        // difference, Richardson-extrapolated with 0.025°, is then good to a few 1e-5).
        let h = 5e-2;
        let (p, m, p2, m2) = (r(h), r(-h), r(h / 2.0), r(-h / 2.0));
        for i in 0..e.m() {
            let fd = (4.0 * (p2[i] - m2[i]) / h - (p[i] - m[i]) / (2.0 * h)) / 3.0;
            let j = e.jacobian[i * 3 + c];
            assert!((j - fd).abs() <= 1e-4 * fd.abs().max(1.0), "residual {i}, parameter {c}: {j} vs {fd}");
        }
    }
}

#[test]
fn double_amici_design_meets_the_targets() {
    let catalog = design_catalog(None).unwrap();
    let out = design_amici(&catalog, &AmiciOptions::default()).unwrap();
    out.print();
    let r = &out.report;
    assert!((r.dispersion_deg / r.target_dispersion_deg - 1.0).abs() < 0.01, "dispersion {} vs {}", r.dispersion_deg, r.target_dispersion_deg);
    assert!(r.max_distortion_um <= 10.0, "distortion {} µm", r.max_distortion_um);
    assert!(r.deviation_mrad <= 1.0, "deviation {} mrad", r.deviation_mrad);
    assert!((r.target_dispersion_deg - 0.95).abs() < 0.005);
    assert!(r.continuous_stage["stop_reason"].as_str().unwrap().starts_with("converged"), "{}", r.continuous_stage);
    // Deterministic for a seed; the written spec traces to the same dispersion.
    let again = design_amici(&catalog, &AmiciOptions::default()).unwrap();
    assert_eq!(serde_json::to_string(&again.report).unwrap(), serde_json::to_string(&out.report).unwrap());
    let sys = SequentialSystem::build(&out.spec).unwrap();
    let c = analysis::dispersion_curve(&sys, &AnalyticTracer::default(), [0.0, 0.0], &[450.0, 650.0]).unwrap();
    assert!(c.spread_um > 700.0 && c.spread_um < 950.0, "{}", c.spread_um);
}

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_diffcassi"))
}

#[test]
fn cli_calibrate_and_design_write_their_reports() {
    let dir = tempfile::tempdir().unwrap();
    let rep = dir.path().join("cal.json");
    let out = bin().args(["calibrate", "--from", "sp", "--observed", "msp", "--free", "prism_tilt_x", "--setup", "small", "--report"]).arg(&rep).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&rep).unwrap()).unwrap();
    assert!((v["recovered"]["prism_tilt_x"].as_f64().unwrap() - 5.0).abs() < 0.01);
    assert!(v["residual_um"].as_f64().unwrap() < 1e-3);
    assert!(v["noise_study"]["error"]["prism_tilt_x"].as_f64().unwrap().abs() < 0.05);

    let rep = dir.path().join("design.json");
    let spec = dir.path().join("design.toml");
    let out = bin().args(["design", "amici", "--seed", "3", "--report"]).arg(&rep).arg("--system-out").arg(&spec).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&rep).unwrap()).unwrap();
    for key in ["dispersion_deg", "target_dispersion_deg", "max_distortion_um", "deviation_mrad", "alpha_c_deg"] {
        assert!(v[key].as_f64().unwrap().is_finite(), "{key}");
    }
    assert_eq!(v["apex_deg"].as_array().unwrap().len(), 3);
    assert_eq!(v["glasses"].as_array().unwrap().len(), 3);
    // The default iterations converge: the continuous stage says so and warns of nothing (round 21).
    assert!(v["continuous_stage"]["stop_reason"].as_str().unwrap().starts_with("converged"), "{}", v["continuous_stage"]);
    assert_eq!(v["continuous_stage"]["warnings"], serde_json::json!([]), "{}", v["continuous_stage"]);
    SequentialSystem::build(&diffcassi::spec::load_spec_file(&spec).unwrap()).unwrap();

    // Bad requests: a clear error and exit status 1.
    let out = bin().args(["calibrate", "--from", "sp", "--observed", "msp", "--free", "s14.tilt_x_deg"]).output().unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("pickup"));
    let out = bin().args(["calibrate", "--from", "sp", "--observed", "msp", "--free", "prism_tilt_w"]).output().unwrap();
    assert_eq!(out.status.code(), Some(1));
}
