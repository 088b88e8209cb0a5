//! Round 16 of the held-out battery (2 Dec 2026): reconstruction, sensor noise, the study and `evaluate` at
//! their extremes. Each case failed before its fix (docs/robustness.md, "round 16"); Python's side is
//! `tests/python/test_battery_round16.py`, the calibration's `tests/calibration_round16.rs`.
use crate::cli_run::{ok_cli as ok, refused_cli as refused, run_cli as run};
use std::path::Path;

const SMALL: [&str; 12] = ["--preset", "sp", "--synthetic", "1", "--scene-size", "16", "--planes", "8", "--rays", "2", "--threads", "1"];

fn with<'a>(extra: &[&'a str]) -> Vec<&'a str> {
    let mut v: Vec<&str> = vec!["render"];
    v.extend_from_slice(&SMALL);
    v.extend_from_slice(extra);
    v
}

fn read_json(p: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(p).unwrap()).unwrap()
}

fn acquisition(dir: &Path) -> Vec<f32> {
    diffcassi::io::exr::read_exr(dir.join("acquisition.exr")).unwrap().channels.remove(0).data
}

/// Replace a render folder's acquisition by `values`, with render.json's SHA-256 made to match (a consistent
/// edited folder, as a user's own acquisition would be).
fn replace_acquisition(dir: &Path, values: Vec<f32>) {
    let img = diffcassi::io::exr::read_exr(dir.join("acquisition.exr")).unwrap();
    let sha = diffcassi::render::engine::acquisition_sha256(&values);
    diffcassi::io::exr::write_exr(dir.join("acquisition.exr"), img.width, img.height, &[diffcassi::io::exr::ExrChannel { name: "Y".into(), data: values }]).unwrap();
    let mut j = read_json(&dir.join("render.json"));
    j["acquisition_f32le_sha256"] = serde_json::json!(sha);
    std::fs::write(dir.join("render.json"), serde_json::to_vec_pretty(&j).unwrap()).unwrap();
}

/// `--electrons-per-unit 1e-150` with the ADC on wrote a zero acquisition, exit 0, that `reconstruct` could
/// never read ("stopping rule: noise norm δ = inf", naming no file, even with the rule off): one ADC step was
/// 3.9e156 acquisition units. Refused by `render`, naming the step and the exposure; an edited render.json
/// with such an exposure is refused by `reconstruct`, naming its fields. The summary printed the exposure
/// 1e-3 as "0.0010" and 1e-150 as "0.0000": significant digits now.
#[test]
fn an_exposure_whose_adc_step_cannot_be_held_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    refused(dir, &with(&["--noise", "shot,adc", "--adc-bits", "8", "--full-well-e", "1e9", "--electrons-per-unit", "1e-150", "--out", "r"]), &["one ADC step", "at 1e-150 electrons per unit", "raise the exposure (--electrons-per-unit)"]);
    assert!(!dir.join("r").exists());
    let out = ok(dir, &with(&["--noise", "shot,adc", "--electrons-per-unit", "1e-3", "--out", "lo"]));
    assert!(out.contains("sensor noise (shot,adc): 1.0000e-3 e⁻ per unit"), "{out}");
    // A consistent render, its exposure then edited: refused by field, nothing written.
    ok(dir, &with(&["--noise", "shot,adc", "--out", "n"]));
    let mut j = read_json(&dir.join("n/render.json"));
    j["noise"]["electrons_per_unit"] = serde_json::json!(1e-300);
    std::fs::write(dir.join("n/render.json"), serde_json::to_vec(&j).unwrap()).unwrap();
    for extra in [&[][..], &["--discrepancy", "0"][..]] {
        let mut args = vec!["reconstruct", "--from", "n", "--operator", "shift", "--iterations", "3", "--out", "rn"];
        args.extend_from_slice(extra);
        refused(dir, &args, &["render.json", "field `noise.adc_gain_e_per_dn`", "`noise.electrons_per_unit` = 1e-300", "beyond"]);
        assert!(!dir.join("rn").exists());
    }
}

/// Read noise leaves negative values, so a noisy acquisition's total can be ≤ 0 with every pixel lit: it
/// was warned "zero everywhere (the sensor noise drew no electron in any pixel)" (seeds 0–3 and 9 of the next
/// 16). The warning now looks at the pixels as written.
#[test]
fn a_read_noise_acquisition_summing_below_zero_is_not_called_zero() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let out = ok(dir, &with(&["--noise", "read", "--electrons-per-unit", "10", "--read-noise-e", "1000", "--noise-seed", "1", "--out", "r"]));
    let acq = acquisition(&dir.join("r"));
    assert!(acq.iter().map(|v| *v as f64).sum::<f64>() <= 0.0, "the case needs a total ≤ 0");
    assert!(acq.iter().all(|v| *v != 0.0));
    assert!(!out.contains("zero everywhere"), "{out}");
    // A truly zero acquisition still says so.
    let out = ok(dir, &with(&["--noise", "shot", "--electrons-per-unit", "1e-30", "--out", "z"]));
    assert!(out.contains("zero everywhere"), "{out}");
}

/// PnP turned a zero acquisition into a cube of ±0.01 (the network's biases at the fallback scale 1; GAP-TV
/// returned 0): a zero iterate now skips the network (N(0·x) = 0·N(x)).
#[test]
fn pnp_reconstructs_a_zero_acquisition_as_zero() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    ok(dir, &with(&["--noise", "shot", "--electrons-per-unit", "1e-30", "--out", "z"]));
    assert!(acquisition(&dir.join("z")).iter().all(|v| *v == 0.0));
    for solver in ["pnp-gap", "pnp-admm"] {
        let out_dir = format!("r-{solver}");
        ok(dir, &["reconstruct", "--from", "z", "--operator", "shift", "--solver", solver, "--out", &out_dir]);
        let cube: ndarray::ArrayD<f32> = ndarray_npy::read_npy(dir.join(&out_dir).join("cube.npy")).unwrap();
        assert!(cube.iter().all(|v| *v == 0.0), "{solver}: {:?}", cube.iter().cloned().fold(0.0f32, |m, v| m.max(v.abs())));
    }
}

/// An acquisition the operator cannot produce (a constant one, in a consistent folder): accelerated GAP-TV
/// diverged (relative residual 1.0 → 1.75), the data-driven δ, measured at the diverging iterate, grew past
/// ‖y‖ (30.8 → 172 for ‖y‖ = 56), and the run stopped as "discrepancy", exit 0, no word. Both are now said, on
/// stderr and in `stopping.warnings`.
#[test]
fn a_diverged_solve_and_a_threshold_above_the_measurement_are_said() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    ok(dir, &with(&["--out", "c"]));
    let n = acquisition(&dir.join("c")).len();
    replace_acquisition(&dir.join("c"), vec![1.0; n]);
    let out = ok(dir, &["reconstruct", "--from", "c", "--operator", "exact", "--solver", "gap-tv", "--iterations", "30", "--out", "r"]);
    let j = read_json(&dir.join("r/reconstruct.json"));
    let warnings: Vec<&str> = j["stopping"]["warnings"].as_array().unwrap().iter().filter_map(|w| w.as_str()).collect();
    assert!(j["final_residual"].as_f64().unwrap() > 1.0, "{j}");
    assert!(warnings.iter().any(|w| w.contains("worse than a zero cube")), "{warnings:?}");
    assert!(out.contains("warning: the returned cube fits the acquisition worse than a zero cube"), "{out}");
    if j["stopping"]["stopped_by"] == "discrepancy" {
        assert!(warnings.iter().any(|w| w.contains("is at least ‖y‖")), "{warnings:?}");
    }
    // An ordinary render reconstructs without either (4 bands, so that its 8 planes sample every band: with
    // 28 bands, 12 are seen by no pixel and said so since round 17).
    ok(dir, &with(&["--bands", "450:650:4", "--out", "g"]));
    let out2 = ok(dir, &["reconstruct", "--from", "g", "--operator", "exact", "--solver", "gap-tv", "--out", "rg"]);
    assert!(!out2.contains("warning"), "{out2}");
    assert_eq!(read_json(&dir.join("rg/reconstruct.json"))["stopping"]["warnings"], serde_json::json!([]));
}

/// A study scene whose bands stop short of the study's (455–655 nm against 450–650) failed after its renders
/// ("cannot resample the truth"); `reconstruct --truth` refused it up front. Now the study does, before
/// anything is written.
#[test]
fn a_study_scene_short_of_the_bands_is_refused_before_any_render() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    std::fs::create_dir(dir.join("sc")).unwrap();
    ok(dir, &["make-scene", "--synthetic", "0", "--size", "16", "--bands", "455:655:28", "--out", "sc/a.npy"]);
    refused(
        dir,
        &["study", "--presets", "sp", "--operators", "shift", "--solvers", "gap-tv", "--scenes", "sc", "--scene-size", "16", "--planes", "8", "--rays", "2", "--iterations", "5", "--threads", "1", "--out", "st"],
        &["sc/a.npy", "its bands (455 – 655 nm) do not reach the study's band at 450 nm"],
    );
    assert!(!dir.join("st").exists());
}

/// `evaluate` printed the peak of a truth of 1e-40 as "0.000000": six significant digits below 10⁻³ (here a
/// truth of 1e-30).
#[test]
fn evaluate_prints_tiny_peaks_in_exponent_form() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let wl = vec![450.0, 500.0, 550.0, 600.0];
    let truth: Vec<f32> = (0..16 * 13 * 4).map(|i| 1e-30 * ((i % 7) as f32 + 1.0) / 8.0).collect();
    let t = diffcassi::scene::SpectralCube::new(16, 13, wl.clone(), truth, "t").unwrap();
    diffcassi::scene::save_npy(&t, &dir.join("t.npy")).unwrap();
    let e = diffcassi::scene::SpectralCube::new(16, 13, wl, vec![0.5; 16 * 13 * 4], "e").unwrap();
    diffcassi::scene::save_npy(&e, &dir.join("e.npy")).unwrap();
    let (code, out) = run(dir, &["evaluate", "--truth", "t.npy", "--estimate", "e.npy"]);
    assert_eq!(code, Some(0), "{out}");
    assert!(out.contains("peak = max of the truth (8.750000e-31)"), "{out}");
    assert!(!out.contains("(0.000000)"), "{out}");
}

/// An edited render.json in a dataset (`seed` 0 → 5 at the top level, its `configuration` untouched) was
/// counted as done by `dataset-status` and skipped by a resume, and `reconstruct` traced the operator with
/// the edited seed. Now the scene is damaged (and rendered again), and `reconstruct` refuses the record.
#[test]
fn an_edited_dataset_record_is_damaged_not_done() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    std::fs::create_dir(dir.join("sc")).unwrap();
    ok(dir, &["make-scene", "--synthetic", "0", "--size", "16", "--out", "sc/a.npy"]);
    let args = ["render-dataset", "--preset", "sp", "--scenes", "sc", "--scene-size", "16", "--planes", "8", "--rays", "2", "--threads", "1", "--out", "ds"];
    ok(dir, &args);
    let p = dir.join("ds/a/render.json");
    let mut j = read_json(&p);
    j["seed"] = serde_json::json!(5);
    std::fs::write(&p, serde_json::to_vec_pretty(&j).unwrap()).unwrap();
    refused(dir, &["reconstruct", "--from", "ds/a", "--operator", "exact", "--iterations", "3", "--out", "r"], &["render.json", "contradicts itself", "`seed` = 5 but `configuration.seed` = 0"]);
    assert!(!dir.join("r").exists());
    let (code, out) = run(dir, &["dataset-status", "ds"]);
    assert_eq!(code, Some(1), "{out}");
    assert!(out.contains("`seed` = 5 but `configuration.seed` = 0"), "{out}");
    let out = ok(dir, &args);
    assert!(out.contains("damaged, rendering again"), "{out}");
    assert_eq!(read_json(&p)["seed"], serde_json::json!(0));
}

/// A failed write to stdout made nearly every command panic (exit 101), and `render-dataset` lost its audit
/// lines with exit 0: now "cannot write to standard output", exit 1 (its scenes are on disk).
#[test]
fn a_full_stdout_is_an_error_not_a_panic() {
    if !Path::new("/dev/full").exists() {
        return;
    }
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let full = || std::fs::OpenOptions::new().write(true).open("/dev/full").unwrap();
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_diffcassi")).args(["spot", "--preset", "sp", "--pupil", "grid:3"]).current_dir(dir).stdout(full()).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("error: cannot write to standard output") && !err.contains("panicked"), "{err}");
    std::fs::create_dir(dir.join("sc")).unwrap();
    ok(dir, &["make-scene", "--synthetic", "0", "--size", "16", "--out", "sc/a.npy"]);
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_diffcassi"))
        .args(["render-dataset", "--preset", "sp", "--scenes", "sc", "--scene-size", "16", "--planes", "8", "--rays", "2", "--out", "ds"])
        .current_dir(dir)
        .stdout(full())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("1 of render-dataset's audit lines") && err.contains("dataset-status"), "{err}");
    assert!(dir.join("ds/a/render.json").is_file());
}

/// `mapping --npy m.npy` replaced a symbolic link at `m_valid.npy` (or `m_wavelengths_nm.npy`) by a regular
/// file, exit 0; a link at `--npy` itself was refused, as make-scene's companions are.
#[test]
fn mapping_refuses_a_link_at_its_companions() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    std::fs::write(dir.join("p.txt"), "keep").unwrap();
    std::os::unix::fs::symlink(dir.join("p.txt"), dir.join("m_valid.npy")).unwrap();
    refused(dir, &["mapping", "--preset", "sp", "--height", "8", "--width", "8", "--npy", "m.npy"], &["m_valid.npy", "symbolic link", "nothing was written"]);
    assert!(std::fs::symlink_metadata(dir.join("m_valid.npy")).unwrap().file_type().is_symlink());
    assert!(!dir.join("m.npy").exists());
}
