//! Exact configuration records (issue 21, part B): every float diffcassi records in JSON reads back
//! bit-identical (serde_json's `float_roundtrip`), so `render-dataset` resumes its own killed or finished
//! output instead of refusing it as "rendered with another configuration" (bands_nm 464.81481481481484 read
//! back one ulp off with the default, best-effort parser). Tiny sizes: 16×16 scenes, 1 ray.
use diffcassi::render::dataset::configuration_differences;
use diffcassi::scene;
use proptest::prelude::*;
use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

/// Write `values` the way render.json is written (`output::write_sidecar`: serde_json, pretty) and read
/// them back the way every reader does (`serde_json::from_str`); return them.
fn through_the_writer(values: &[f64]) -> Vec<f64> {
    let dir = tempfile::tempdir().unwrap();
    let v = serde_json::json!({ "values": values });
    diffcassi::render::output::write_sidecar(dir.path(), &v).unwrap();
    let text = std::fs::read_to_string(dir.path().join("render.json")).unwrap();
    let back: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert!(
        configuration_differences(&back, &v).is_empty(),
        "{:?}",
        configuration_differences(&back, &v)
    );
    back["values"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect()
}

fn assert_bit_identical(values: &[f64]) {
    let back = through_the_writer(values);
    assert_eq!(back.len(), values.len());
    for (a, b) in values.iter().zip(&back) {
        assert_eq!(a.to_bits(), b.to_bits(), "{a:e} read back as {b:e}");
    }
}

#[test]
fn extreme_floats_read_back_bit_identical() {
    let v = [
        0.0,
        -0.0,
        f64::MIN_POSITIVE,
        -f64::MIN_POSITIVE,
        f64::MAX,
        f64::MIN,
        f64::EPSILON,
        5e-324,                                // smallest subnormal
        f64::from_bits(0x000f_ffff_ffff_ffff), // largest subnormal
        464.81481481481484, // a default band (450:650:28) the best-effort parser read one ulp off
        479.6296296296296,
        0.1 + 0.2,
        1.0 / 3.0,
        9007199254740993.0,
    ];
    assert_bit_identical(&v);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]
    /// Any finite f64 (every exponent, subnormals and ±0 included: drawn from the raw bits).
    #[test]
    fn random_floats_read_back_bit_identical(bits in proptest::collection::vec(any::<u64>(), 1..32)) {
        let values: Vec<f64> = bits.iter().map(|&b| f64::from_bits(b)).filter(|v| v.is_finite()).collect();
        let back = through_the_writer(&values);
        for (a, b) in values.iter().zip(&back) {
            prop_assert_eq!(a.to_bits(), b.to_bits(), "{:e} read back as {:e}", a, b);
        }
    }

    /// Floats of the magnitudes configurations hold (wavelengths, pitches, weights).
    #[test]
    fn configuration_floats_read_back_bit_identical(values in proptest::collection::vec(1e-6f64..1e6, 1..64)) {
        let back = through_the_writer(&values);
        prop_assert_eq!(values.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), back.iter().map(|v| v.to_bits()).collect::<Vec<_>>());
    }
}

// ---------------------------------------------------------------- resume of a killed render-dataset

/// Default bands (450:650:28: 464.81481481481484 …) and 28 planes, 16×16 scenes, 1 ray.
const OPTS: [&str; 10] = [
    "--preset",
    "sp",
    "--scene-size",
    "16",
    "--planes",
    "28",
    "--rays",
    "1",
    "--no-mapping",
    "--no-airy",
];

fn dataset_cmd(scenes: &Path, out: &Path) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_diffcassi"));
    for v in [
        "SLURM_ARRAY_TASK_ID",
        "SLURM_ARRAY_TASK_COUNT",
        "DIFFCASSI_DEBUG_SCENE_DELAY_MS",
    ] {
        c.env_remove(v);
    }
    c.args([
        "render-dataset",
        "--scenes",
        scenes.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ])
    .args(OPTS);
    c
}

/// (scene, status) of each JSON line on stdout.
fn lines(o: &Output) -> Vec<(String, String)> {
    String::from_utf8_lossy(&o.stdout)
        .lines()
        .map(|l| {
            let v: serde_json::Value =
                serde_json::from_str(l).unwrap_or_else(|e| panic!("not JSON: {l}: {e}"));
            (
                v["scene"].as_str().unwrap().to_string(),
                v["status"].as_str().unwrap().to_string(),
            )
        })
        .collect()
}

fn with_status(l: &[(String, String)], status: &str) -> Vec<String> {
    let mut v: Vec<String> = l
        .iter()
        .filter(|(_, s)| s == status)
        .map(|(n, _)| n.clone())
        .collect();
    v.sort();
    v
}

fn done_scenes(out: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(out)
        .map(|r| {
            r.flatten()
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| !n.starts_with('.') && out.join(n).join("render.json").is_file())
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}

/// Scenes whose wavelengths come from `.npy` files (`<stem>_wavelengths_nm.npy`, 28 bands 450–650 nm with
/// the non-terminating decimals of a linspace), rendered with `render-dataset`; killed (SIGKILL) while a
/// scene is in flight; the same command then renders exactly the missing scenes; once more it renders
/// nothing and exits 0. Before `float_roundtrip` the rerun refused the whole output.
#[test]
fn killed_dataset_resumes_exactly_the_missing_scenes() {
    let tmp = tempfile::tempdir().unwrap();
    let scenes = tmp.path().join("scenes");
    std::fs::create_dir_all(&scenes).unwrap();
    let ws: Vec<f64> = (0..28).map(|k| 450.0 + 200.0 * k as f64 / 27.0).collect();
    let names: Vec<String> = (0..4).map(|i| format!("s{i}")).collect();
    for (i, n) in names.iter().enumerate() {
        scene::save_npy(
            &scene::synthetic_scene(16, 16, &ws, i as u64),
            &scenes.join(format!("{n}.npy")),
        )
        .unwrap();
        assert!(scenes.join(format!("{n}_wavelengths_nm.npy")).is_file());
    }
    let out = tmp.path().join("out");

    // 1. Kill the run while a scene is in flight: the test hook holds each finished scene's temporary
    //    folder for 1.5 s before moving it into place.
    let mut child = dataset_cmd(&scenes, &out)
        .env("DIFFCASSI_DEBUG_SCENE_DELAY_MS", "1500")
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let t = Instant::now();
    let mut in_flight = None;
    while in_flight.is_none() && t.elapsed() < Duration::from_secs(120) {
        // Wait for the second scene in flight, so that one scene is done and others are missing.
        if done_scenes(&out).len() == 1 {
            in_flight = std::fs::read_dir(&out).ok().and_then(|r| {
                r.flatten()
                    .map(|e| e.file_name().to_string_lossy().into_owned())
                    .find(|n| n.contains(".partial-"))
            });
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    let in_flight = in_flight.expect("a scene in flight within 120 s");
    child.kill().unwrap(); // SIGKILL
    let killed = child.wait_with_output().unwrap();
    assert!(!killed.status.success());
    let before = done_scenes(&out);
    assert_eq!(before.len(), 1, "{before:?} (in flight: {in_flight})");
    let missing: Vec<String> = names
        .iter()
        .filter(|n| !before.contains(n))
        .cloned()
        .collect();

    // 2. The same command finishes exactly the missing scenes (the killed scene's temporary folder removed).
    let o = dataset_cmd(&scenes, &out).output().unwrap();
    assert!(
        o.status.success(),
        "resume failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let l = lines(&o);
    assert_eq!(with_status(&l, "rendered"), missing, "{l:?}");
    assert_eq!(with_status(&l, "skipped"), before, "{l:?}");
    assert_eq!(done_scenes(&out), names);
    let left: Vec<String> = std::fs::read_dir(&out)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with('.') || n.ends_with(".tmp"))
        .collect();
    assert!(left.is_empty(), "temporaries left: {left:?}");

    // 3. Once more: nothing to render, exit 0; dataset-status is clean.
    let o = dataset_cmd(&scenes, &out).output().unwrap();
    assert!(
        o.status.success(),
        "rerun failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let l = lines(&o);
    assert_eq!(with_status(&l, "skipped"), names, "{l:?}");
    assert!(with_status(&l, "rendered").is_empty(), "{l:?}");
    let st = Command::new(env!("CARGO_BIN_EXE_diffcassi"))
        .args([
            "dataset-status",
            out.to_str().unwrap(),
            "--scenes",
            scenes.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stdout)
    );
}
