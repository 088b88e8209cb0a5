//! The reconstruction metrics against reference values from an independent implementation (scikit-image and
//! numpy, `scripts/fixtures/metrics_fixture.py`, outputs committed under `tests/fixtures/metrics/`).
//! Agreement required: 1e-5 absolute on every metric (dB for PSNR, radians/degrees for SAM).
use diffcassi::recon::metrics::{evaluate, metrics};
use diffcassi::recon::CubeShape;
use diffcassi::scene::load_scene;
use std::path::PathBuf;

fn fixture_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/metrics")
}

#[test]
fn metrics_equal_the_scikit_image_fixture() {
    let dir = fixture_dir();
    let values: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("values.json")).unwrap()).unwrap();
    let cases = values["cases"].as_object().unwrap();
    assert!(cases.len() >= 3, "fixture cases: {}", cases.len());
    for (name, want) in cases {
        let truth = load_scene(&dir.join(format!("{name}_truth.npy")), None).unwrap();
        let estimate = load_scene(&dir.join(format!("{name}_estimate.npy")), None).unwrap();
        let ev = evaluate(&truth, &estimate).unwrap();
        assert!(!ev.truth_resampled);
        let m = serde_json::to_value(ev.metrics).unwrap();
        for key in ["rmse", "psnr_db", "psnr_band_db", "ssim", "sam_rad", "sam_deg"] {
            let (got, exp) = (m[key].as_f64().unwrap(), want[key].as_f64().unwrap());
            assert!((got - exp).abs() <= 1e-5, "{name}.{key}: diffcassi {got}, scikit-image/numpy {exp}, |Δ| = {:e}", (got - exp).abs());
            println!("{name}.{key}: {got:.9} vs {exp:.9} (|Δ| = {:.1e})", (got - exp).abs());
        }
        // The raw-slice entry point agrees with the cube one.
        let shape = CubeShape { height: truth.height, width: truth.width, bands: truth.bands() };
        assert_eq!(metrics(&truth.data, &estimate.data, shape).unwrap(), ev.metrics);
    }
    // The fixture exercises clamping on both sides and the zero-spectrum conventions.
    let noisy = &cases["noisy"];
    assert!(noisy["estimate_max"].as_f64().unwrap() > 1.0);
    assert!(cases.values().any(|c| c["estimate_min"].as_f64().unwrap() < 0.0));
    assert!(cases.values().any(|c| c["truth_max"].as_f64().unwrap() < 0.99));
}
