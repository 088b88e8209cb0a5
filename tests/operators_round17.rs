//! Round 17 of the held-out battery (2 Dec 2026): the metamorphic prober's findings in the operators and the
//! solvers, from the CLI (docs/robustness.md, "round 17"); Python's side is `tests/python/test_battery_round17.py`.
use crate::cli_run::{ok_cli as ok, refused_cli as refused};

/// `--bands 450,451,650 --planes 6`: the planes lay 50 nm apart from 474.5 nm, band 450 nm got none, and
/// `reconstruct` returned it as exactly 0 with exit 0. Refused before anything is traced or written.
#[test]
fn a_band_no_plane_samples_is_refused_before_anything_is_written() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let base = ["render", "--preset", "sp", "--synthetic", "1", "--scene-size", "8", "--rays", "2", "--threads", "1", "--out", "r"];
    let mut args = base.to_vec();
    args.extend_from_slice(&["--bands", "450,451,650", "--planes", "6"]);
    refused(d, &args, &["band 0 (450 nm) gets no render plane", "at least 300 planes"]);
    assert!(!d.join("r").exists());
    // Evenly spaced: accepted as before.
    let mut args = base.to_vec();
    args.extend_from_slice(&["--bands", "450,550,650", "--planes", "6"]);
    ok(d, &args);
}

/// A scene ×1000 reconstructed with the default TV weight 0.1 (absolute, in the cube's units, tuned for peaks
/// ≈ 1) was barely regularised, silently: `reconstruct` says so on stderr and in reconstruct.json's
/// `stopping.warnings`; the same acquisition at scale 1 says nothing.
#[test]
fn reconstruct_warns_when_the_tv_weight_does_not_suit_the_cubes_scale() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for (name, scale) in [("one", "1"), ("big", "1000")] {
        ok(d, &["make-scene", "--synthetic", "1", "--size", "12", "--bands", "450:650:4", "--out", &format!("{name}.npy")]);
        let (shape, data) = diffcassi::io::npy::read_npy_f32(d.join(format!("{name}.npy"))).unwrap();
        let s: f32 = scale.parse().unwrap();
        let scaled: Vec<f32> = data.iter().map(|v| v * s).collect();
        diffcassi::io::npy::write_npy_f32(d.join(format!("{name}.npy")), &shape, &scaled).unwrap();
        ok(d, &["render", "--preset", "sp", "--scene", &format!("{name}.npy"), "--scene-size", "12", "--bands", "450:650:4", "--planes", "4", "--rays", "2", "--threads", "1", "--out", &format!("r_{name}")]);
        let out = ok(d, &["reconstruct", "--from", &format!("r_{name}"), "--operator", "mapping", "--iterations", "5", "--out", &format!("x_{name}")]);
        let rec: serde_json::Value = serde_json::from_slice(&std::fs::read(d.join(format!("x_{name}/reconstruct.json"))).unwrap()).unwrap();
        let warned = rec["stopping"]["warnings"].as_array().unwrap().iter().any(|w| w.as_str().unwrap().contains("TV weight"));
        assert_eq!(warned, name == "big", "{name}: {out}");
        assert_eq!(out.contains("barely regularised"), name == "big", "{name}: {out}");
    }
}
