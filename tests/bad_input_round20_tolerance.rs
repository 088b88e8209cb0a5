//! Round 20 of the held-out battery (3 Dec 2026), invariance: `--tolerance-um` chose the f32 lanes or the
//! exact f64 tracer from run to run on one machine (SP: the f32 lanes' measured speed-up sits near the 1.25×
//! margin), so one command rendered either acquisition, and `render-dataset` shards started together on a
//! fresh calibration cache refused each other ("precision: recorded "f64" ≠ requested "f32"", scenes missing).
//! Now one cache gives one choice (first writer wins: a process that calibrated a key while another stored
//! it takes the stored entry), and a dataset's shards take the choice its dataset.json records for the same
//! tolerance and settings instead of choosing again.
use crate::cli_run::{ok_cli as ok, run_cli};
use diffcassi::fidelity::{self, CacheOptions, Provenance};
use diffcassi::prelude::*;

/// Two choosers calibrating one key at the same time on a fresh cache end with one calibration: the one
/// the cache holds, bit for bit (before, each kept its own timings, and the two could choose differently).
#[test]
fn two_choosers_racing_on_a_fresh_cache_take_one_calibration() {
    let sys = SequentialSystem::build(&presets::spec("ap").unwrap()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let cache = CacheOptions { dir: Some(dir.path().to_path_buf()) };
    let barrier = std::sync::Barrier::new(2);
    let (a, b) = std::thread::scope(|s| {
        let run = || {
            barrier.wait();
            fidelity::calibrate_backends(&sys, &[520.0], &cache).unwrap()
        };
        let (ta, tb) = (s.spawn(run), s.spawn(run));
        (ta.join().unwrap(), tb.join().unwrap())
    });
    let speeds = |c: &fidelity::BackendCalibration| c.candidates.iter().map(|m| (m.backend.clone(), m.rays_per_s.to_bits(), m.seconds.to_bits())).collect::<Vec<_>>();
    assert_eq!(speeds(&a.0), speeds(&b.0), "two calibrations on one cache: {:?} / {:?}", a.1, b.1);
    // At most one of them is this run's own measurement; the other came from the cache.
    let own = [&a.1, &b.1].iter().filter(|p| matches!(p, Provenance::Measured { .. })).count();
    assert!(own <= 1, "{:?} / {:?}", a.1, b.1);
    // The cache holds that one entry, and no temporary.
    let files: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    assert_eq!(files.len(), 1, "{files:?}");
    let (c, p) = fidelity::calibrate_backends(&sys, &[520.0], &cache).unwrap();
    assert!(matches!(p, Provenance::Cached(_)), "{p:?}");
    assert_eq!(speeds(&c), speeds(&a.0));
}

/// A shard takes the tolerance choice dataset.json records for the same tolerance and settings, without
/// calibrating (its own timings could choose otherwise); the dataset ends complete, in one choice.
#[test]
fn a_dataset_shard_takes_the_recorded_tolerance_choice() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    std::fs::create_dir(dir.join("scenes")).unwrap();
    crate::common::two_small_scenes(&dir.join("scenes"));
    let base = ["render-dataset", "--scenes", "scenes", "--out", "ds", "--preset", "sp", "--scene-size", "8", "--planes", "4"];
    // Shard 0 rendered with the f32 lanes at 7 rays; its dataset.json records that a tolerance of 4 µm chose
    // them (what a task that calibrated would have written).
    ok(dir, &[&base[..], &["--rays", "7", "--precision", "f32", "--shard", "0/2"]].concat());
    let manifest = dir.join("ds/dataset.json");
    let mut v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&manifest).unwrap()).unwrap();
    assert!(v.get("tolerance").is_none(), "a run without a tolerance records none");
    v["tolerance"] = serde_json::json!({"tolerance_um": 4.0, "backend": "analytic-f32", "rays_per_pixel": 7, "predicted_error_um": 3.81});
    std::fs::write(&manifest, serde_json::to_string_pretty(&v).unwrap()).unwrap();
    assert!(diffcassi::render::dataset::tolerance::recorded_source(&dir.join("ds"), 4.0).is_some());
    assert!(diffcassi::render::dataset::tolerance::recorded_source(&dir.join("ds"), 4.5).is_none(), "another tolerance is another request");

    // Shard 1 asks for --tolerance-um 4: it takes the recorded choice, calibrates nothing (its cache folder is
    // never created), and renders its scene in f32 at 7 rays.
    let out = ok(dir, &[&base[..], &["--tolerance-um", "4", "--calibration-cache", "cc", "--shard", "1/2"]].concat());
    assert!(out.contains("fidelity: tolerance 4 µm → --backend analytic-f32 --rays 7") && out.contains("records"), "{out}");
    assert!(!dir.join("cc").exists(), "the shard calibrated: {out}");
    let r: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("ds/s1/render.json")).unwrap()).unwrap();
    assert_eq!(r["configuration"]["precision"], "f32", "{r}");
    assert_eq!(r["configuration"]["rays_per_pixel"], 7);
    assert_eq!((r["tolerance_um"].as_f64(), r["tolerance_predicted_error_um"].as_f64()), (Some(4.0), Some(3.81)));
    // The record stays in dataset.json for the next task, and the dataset is complete.
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&manifest).unwrap()).unwrap();
    assert_eq!(v["tolerance"]["backend"], "analytic-f32", "{v}");
    let (code, status) = run_cli(dir, &["dataset-status", "ds"]);
    assert_eq!(code, Some(0), "{status}");
    // A resumed array (both shards again, same tolerance) skips everything, calibrating nothing either.
    for k in ["0/2", "1/2"] {
        let out = ok(dir, &[&base[..], &["--tolerance-um", "4", "--calibration-cache", "cc", "--shard", k]].concat());
        assert!(out.contains("0 to render, 1 complete"), "{out}");
    }
    assert!(!dir.join("cc").exists());
}
