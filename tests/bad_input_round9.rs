//! Bad input, round 9 (30 Nov 2026): two held-out probers (the C++ API, `render-dataset` and its noise,
//! the devices; the Python torch modules and the training script). The C++ cases are in
//! `cpp/tests/test_errors.cpp`, the library's in unit tests beside the code, the Python ones in
//! `tests/python/test_battery_round9.py` and `test_round9_limits.py`.
use std::path::Path;

use crate::cli_run::{ok_cli as ok, refused_cli as refused, run_cli as run};

fn npy_scene(dir: &Path, name: &str, value: f32) {
    let cube = diffcassi::scene::SpectralCube::new(8, 8, vec![450.0, 516.7, 583.3, 650.0], vec![value; 8 * 8 * 4], "test").unwrap();
    diffcassi::scene::save_npy(&cube, &dir.join(name)).unwrap();
}

/// A run of more than 12 digits: an untidied number in a message.
fn has_long_number(text: &str) -> bool {
    text.split(|c: char| !c.is_ascii_digit()).any(|run| run.len() > 12)
}

const SMALL: [&str; 10] = ["--preset", "sp", "--scene-size", "8", "--bands", "450:650:4", "--planes", "4", "--rays", "1"];

fn with<'a>(head: &[&'a str], tail: &[&'a str]) -> Vec<&'a str> {
    let mut v = head.to_vec();
    v.extend_from_slice(&SMALL);
    v.extend_from_slice(tail);
    v
}

/// Scene files named `..npy` made the scene's folder the dataset's parent (only the kernel's EBUSY stopped
/// it), and a 251-byte name failed after its render, naming the temporary: both refused before any work.
#[test]
fn dataset_scene_names_that_are_not_folder_names_are_refused_first() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    std::fs::create_dir(dir.join("sc")).unwrap();
    npy_scene(&dir.join("sc"), "..npy", 0.5);
    refused(dir, &with(&["render-dataset", "--scenes", "sc", "--out", "o"], &[]), &["`.`", "not a folder name"]);
    assert!(!dir.join("o").exists());
    std::fs::remove_file(dir.join("sc/..npy")).unwrap();
    let long = format!("{}.npy", "L".repeat(200));
    npy_scene(&dir.join("sc"), &long, 0.5);
    refused(dir, &with(&["render-dataset", "--scenes", "sc", "--out", "o"], &[]), &["200 bytes long", "at most 128"]);
    assert!(!dir.join("o").exists());
}

/// An exposure of far less than one electron wrote all-zero acquisitions, exit 0, the only warning blaming
/// the scene; a scene so dim its acquisition is subnormal rendered 5× too low. Now: a warning naming the
/// exposure (render and render-dataset), and the dim scene refused.
#[test]
fn exposures_below_an_electron_are_said_and_subnormal_scenes_refused() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    std::fs::create_dir(dir.join("sc")).unwrap();
    npy_scene(&dir.join("sc"), "a.npy", 0.5);
    let out = ok(dir, &with(&["render-dataset", "--scenes", "sc", "--out", "o"], &["--noise", "shot", "--electrons-per-unit", "1e-300"]));
    assert!(out.contains("warning: a: the exposure puts") && out.contains("< 1 electron") && out.contains("zero everywhere"), "{out}");
    let out = ok(dir, &with(&["render", "--scene", "sc/a.npy", "--out", "r"], &["--noise", "shot,adc", "--electrons-per-unit", "1e-6"]));
    assert!(out.contains("the exposure puts") && out.contains("raise --electrons-per-unit"), "{out}");
    assert!(!out.contains("the scene is dark"), "{out}");
    // An ordinary exposure: no warning.
    let out = ok(dir, &with(&["render", "--scene", "sc/a.npy", "--out", "r2"], &["--noise", "shot"]));
    assert!(!out.contains("warning"), "{out}");
    npy_scene(dir, "dim.npy", 1e-45);
    refused(dir, &with(&["render", "--scene", "dim.npy", "--out", "r3"], &[]), &["brightest value", "subnormal", "scale the scene's radiance up"]);
    assert!(!dir.join("r3").exists());
    // A noisy value beyond what `reconstruct` reads names the exposure, tidily (was: "scale the scene down").
    let (code, out) = run(dir, &with(&["render", "--scene", "sc/a.npy", "--out", "r4"], &["--noise", "read", "--electrons-per-unit", "1e-30"]));
    assert_eq!(code, Some(1), "{out}");
    assert!(out.contains("raise the exposure (--electrons-per-unit)") && !out.contains("scale the scene"), "{out}");
    assert!(!has_long_number(&out), "{out}");
    let (code, out) = run(dir, &with(&["render", "--scene", "sc/a.npy", "--out", "r5"], &["--noise", "shot", "--electrons-per-unit", "1e30"]));
    assert_eq!(code, Some(1), "{out}");
    assert!(out.contains("lower --electrons-per-unit") && !out.contains("8.012574166059494e29"), "{out}");
}

/// Messages: `--noise none,shot` named only `none`; `bench-render --device garbage` suggested cpu-twin,
/// which bench-render refuses.
#[test]
fn noise_and_device_messages_name_what_applies() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    refused(dir, &with(&["render", "--out", "r"], &["--noise", "none,shot"]), &["`none,shot`", "stands alone"]);
    refused(dir, &with(&["render", "--out", "r"], &["--noise", "shot,"]), &["`shot,`", "an empty item"]);
    // A closed mask traces no ray: said so (render.json's ray_stats are all zero).
    diffcassi::io::npy::write_npy_f32(dir.join("closed.npy"), &[8, 8], &[0.0; 64]).unwrap();
    let out = ok(dir, &with(&["render", "--mask", "closed.npy", "--out", "rc"], &[]));
    assert!(out.contains("no ray was traced: the mask is closed everywhere"), "{out}");
    // A bad --device is a usage error (exit 2, as clap's other bad values; it was 1), naming option and value.
    let (code, out) = run(dir, &["bench-render", "--device", "garbage", "--scene-size", "4"]);
    assert_eq!(code, Some(2), "{out}");
    assert!(out.contains("'garbage'") && out.contains("--device") && out.contains("use cpu, cuda or cuda:N") && !out.contains("cpu-twin"), "{out}");
    let (code, out) = run(dir, &["bench-render", "--device", "cpu-twin", "--scene-size", "4"]);
    assert_eq!(code, Some(2), "{out}");
    assert!(out.contains("use cpu or cuda (the twin is for checking"), "{out}");
    let (code, out) = run(dir, &["mapping", "--preset", "sp", "--device", "gpu", "--npy", "m.npy"]);
    assert_eq!(code, Some(2), "{out}");
    assert!(out.contains("'gpu'") && out.contains("--device"), "{out}");
}

/// A study with the unrolled solver and bands of the right count but other wavelengths failed after its
/// study.json, mask and renders: refused before anything is written, naming the band.
#[test]
fn study_refuses_unrolled_weights_of_other_wavelengths_first() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let args = ["study", "--presets", "sp", "--operators", "exact", "--synthetic", "1", "--scene-size", "16", "--planes", "4", "--rays", "1", "--solvers", "unrolled", "--bands", "380:720:28", "--out", "st"];
    refused(dir, &args, &["--bands `380:720:28`", "band 0 is 450 nm", "trained for other wavelengths"]);
    assert!(!dir.join("st").exists());
}
