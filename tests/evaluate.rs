//! `diffcassi evaluate`: the interface keys, the fixture values through the command line, the cube formats,
//! wavelength resampling, and bad input (exit 1, a clear message, nothing written).
use diffcassi::scene::{self, load_scene, SpectralCube};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn run(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_diffcassi")).args(args).output().expect("the binary runs")
}

fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/metrics").join(name)
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

#[test]
fn evaluate_writes_the_interface_keys_with_the_fixture_values() {
    let d = tempfile::tempdir().unwrap();
    let want = json(&fixture("values.json"));
    for case in ["noisy", "biased", "structure"] {
        let out = d.path().join(format!("{case}.json"));
        let o = run(&["evaluate", "--truth", s(&fixture(&format!("{case}_truth.npy"))), "--estimate", s(&fixture(&format!("{case}_estimate.npy"))), "--json", s(&out)]);
        assert!(o.status.success(), "{}", stderr(&o));
        let stdout = String::from_utf8_lossy(&o.stdout);
        assert!(stdout.contains("| psnr_band_db |") && stdout.contains("24×20×5"), "{stdout}");
        let j = json(&out);
        for key in ["rmse", "psnr_db", "psnr_band_db", "ssim", "sam_rad", "sam_deg"] {
            let (got, exp) = (j[key].as_f64().unwrap(), want["cases"][case][key].as_f64().unwrap());
            assert!((got - exp).abs() <= 1e-5, "{case}.{key}: {got} vs {exp}");
        }
        assert_eq!(j["shape"], serde_json::json!([24, 20, 5]));
        assert_eq!(j["truth_resampled"], false);
        assert_eq!(j["wavelengths_nm"].as_array().unwrap().len(), 5);
    }
}

#[test]
fn evaluate_reads_exr_and_png_folders_and_resamples_the_truth() {
    let d = tempfile::tempdir().unwrap();
    let truth = load_scene(&fixture("structure_truth.npy"), None).unwrap();
    let estimate = load_scene(&fixture("structure_estimate.npy"), None).unwrap(); // within [0, 1]: PNG-safe
    let exr = d.path().join("truth.exr");
    scene::save_exr(&truth, &exr).unwrap();
    let pngs = d.path().join("estimate_pngs");
    scene::save_png_stack(&estimate, &pngs).unwrap();
    let out = d.path().join("m.json");
    let o = run(&["evaluate", "--truth", s(&exr), "--estimate", s(&pngs), "--json", s(&out)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let want = json(&fixture("values.json"))["cases"]["structure"].clone();
    let j = json(&out);
    // 16-bit PNG quantisation (≤ 0.5/65535 per value) is the only difference.
    assert!((j["rmse"].as_f64().unwrap() - want["rmse"].as_f64().unwrap()).abs() < 1e-4);
    assert!((j["ssim"].as_f64().unwrap() - want["ssim"].as_f64().unwrap()).abs() < 1e-4);
    // An estimate on other wavelengths (3 bands inside the truth's 450–650 nm): the truth is resampled.
    let est3 = truth.resample(&[475.0, 550.0, 625.0]).unwrap();
    let p3 = d.path().join("est3.npy");
    scene::save_npy(&est3, &p3).unwrap();
    let out3 = d.path().join("m3.json");
    let o = run(&["evaluate", "--truth", s(&fixture("structure_truth.npy")), "--estimate", s(&p3), "--json", s(&out3)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let j = json(&out3);
    assert_eq!(j["truth_resampled"], true);
    assert_eq!(j["shape"], serde_json::json!([24, 20, 3]));
    assert_eq!(j["rmse"].as_f64().unwrap(), 0.0);
    // Identical cubes: PSNR is infinite, written as the string "inf".
    assert_eq!(j["psnr_db"], "inf");
    assert!((j["ssim"].as_f64().unwrap() - 1.0).abs() < 1e-12);
}

#[test]
fn evaluate_refuses_bad_input_and_writes_nothing() {
    let d = tempfile::tempdir().unwrap();
    let truth = fixture("noisy_truth.npy");
    let out = d.path().join("m.json");
    let check = |o: Output, needles: &[&str]| {
        assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
        let e = stderr(&o);
        for n in needles {
            assert!(e.contains(n), "`{n}` in: {e}");
        }
        assert!(!e.contains("panicked"), "{e}");
        assert!(!out.exists(), "nothing written");
    };
    // Shape mismatch.
    let small = load_scene(&truth, None).unwrap().window(0, 0, 20, 20).unwrap();
    let p = d.path().join("small.npy");
    scene::save_npy(&small, &p).unwrap();
    check(run(&["evaluate", "--truth", s(&truth), "--estimate", s(&p), "--json", s(&out)]), &["shape mismatch", "24×20×5", "20×20×5"]);
    // NaN in a cube.
    let mut c = load_scene(&truth, None).unwrap();
    c.data[(3 * 20 + 4) * 5 + 2] = f32::NAN;
    let p = d.path().join("nan.npy");
    diffcassi::io::write_npy_f32(&p, &[24, 20, 5], &c.data).unwrap();
    diffcassi::io::write_npy_f64(d.path().join("nan_wavelengths_nm.npy"), &[5], &c.wavelengths_nm).unwrap();
    check(run(&["evaluate", "--truth", s(&truth), "--estimate", s(&p), "--json", s(&out)]), &["nan.npy", "row 3, col 4, band 2", "not finite"]);
    // Missing files, and an NPY without its wavelength list.
    let missing = d.path().join("missing.npy");
    check(run(&["evaluate", "--truth", s(&missing), "--estimate", s(&truth), "--json", s(&out)]), &["--truth", "missing.npy", "no such file"]);
    let bare = d.path().join("bare.npy");
    diffcassi::io::write_npy_f32(&bare, &[24, 20, 5], &SpectralCube::uniform(24, 20, vec![1.0, 2.0, 3.0, 4.0, 5.0], 0.5).data).unwrap();
    check(run(&["evaluate", "--truth", s(&truth), "--estimate", s(&bare), "--json", s(&out)]), &["bare.npy", "--estimate-wavelengths"]);
    let ok = run(&["evaluate", "--truth", s(&truth), "--estimate", s(&bare), "--estimate-wavelengths", "450:650:5", "--json", s(&out)]);
    assert!(ok.status.success(), "{}", stderr(&ok));
    // An estimate beyond the truth's wavelength range cannot be compared.
    std::fs::remove_file(&out).unwrap();
    check(run(&["evaluate", "--truth", s(&truth), "--estimate", s(&bare), "--estimate-wavelengths", "450:700:5", "--json", s(&out)]), &["outside the truth's range", "700"]);
    // Usage errors exit 2.
    assert_eq!(run(&["evaluate", "--truth", s(&truth)]).status.code(), Some(2));
}
