//! `render --noise`: sensor noise on the written acquisition, recorded in render.json, statistically right,
//! seeded, and off by default (then bit-identical to a render without the options).
use std::path::Path;
use std::process::{Command, Output};

fn run(out: &Path, extra: &[&str]) -> Output {
    let mut args: Vec<&str> = vec!["render", "--preset", "sp", "--synthetic", "4", "--scene-size", "24", "--planes", "6", "--rays", "2", "--no-mapping", "--out", out.to_str().unwrap()];
    args.extend_from_slice(extra);
    Command::new(env!("CARGO_BIN_EXE_diffcassi")).args(&args).output().expect("the binary runs")
}

fn ok(o: Output) -> Output {
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    o
}

fn acquisition(dir: &Path) -> Vec<f64> {
    diffcassi::io::exr::read_exr(dir.join("acquisition.exr")).unwrap().channels.remove(0).data.iter().map(|&v| v as f64).collect()
}

fn json(dir: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join("render.json")).unwrap()).unwrap()
}

#[test]
fn render_noise_is_recorded_poisson_seeded_and_off_by_default() {
    let d = tempfile::tempdir().unwrap();
    let [clean, none, shot, shot2, seed2] = ["clean", "none", "shot", "shot2", "seed2"].map(|n| d.path().join(n));
    ok(run(&clean, &[]));
    ok(run(&none, &["--noise", "none"]));
    assert_eq!(json(&clean)["noise"], serde_json::Value::Null);
    assert_eq!(acquisition(&clean), acquisition(&none));
    assert_eq!(std::fs::read(clean.join("acquisition.png")).unwrap(), std::fs::read(none.join("acquisition.png")).unwrap());

    // Shot noise alone, auto exposure: the clean peak ↦ 2000 e⁻.
    let o = ok(run(&shot, &["--noise", "shot", "--full-well-e", "2000", "--noise-seed", "5"]));
    assert!(String::from_utf8_lossy(&o.stdout).contains("sensor noise"));
    ok(run(&shot2, &["--noise", "shot", "--full-well-e", "2000", "--noise-seed", "5"]));
    ok(run(&seed2, &["--noise", "shot", "--full-well-e", "2000", "--noise-seed", "6"]));
    let (c, n) = (acquisition(&clean), acquisition(&shot));
    assert_eq!(n, acquisition(&shot2), "same seed, same noise");
    assert_ne!(n, acquisition(&seed2));
    assert!(n.iter().all(|v| v.is_finite() && *v >= 0.0));
    let j = json(&shot)["noise"].clone();
    assert_eq!(j["sources"], serde_json::json!(["shot"]));
    assert_eq!(j["seed"], 5);
    assert_eq!(j["full_well_e"], 2000.0);
    assert!(j.get("read_noise_e").is_none() && j.get("adc_bits").is_none(), "no keys for sources that are off: {j}");
    let peak = c.iter().cloned().fold(0.0, f64::max);
    let k = j["electrons_per_unit"].as_f64().unwrap();
    assert!((k * peak - 2000.0).abs() < 1e-3 * 2000.0, "K = {k}, peak {peak}");
    // Standardised residuals (n − c)·K / √(K·c) over lit pixels: mean 0, variance 1 (Poisson), within 5 SE.
    let z: Vec<f64> = c.iter().zip(&n).filter(|(c, _)| **c * k > 20.0).map(|(c, n)| (n - c) * k / (c * k).sqrt()).collect();
    let m = z.iter().sum::<f64>() / z.len() as f64;
    let var = z.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (z.len() - 1) as f64;
    let se = (1.0 / z.len() as f64).sqrt();
    assert!(z.len() > 300, "{} lit pixels", z.len());
    assert!(m.abs() < 5.0 * se, "mean {m}");
    assert!((var - 1.0).abs() < 5.0 * (2.0f64).sqrt() * se, "variance {var} over {} pixels", z.len());
}

#[test]
fn render_adc_quantises_the_written_acquisition() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("adc");
    ok(run(&out, &["--noise", "shot,read,adc", "--full-well-e", "255", "--read-noise-e", "1.5", "--adc-bits", "8"]));
    let j = json(&out)["noise"].clone();
    assert_eq!(j["sources"], serde_json::json!(["shot", "read", "adc"]));
    assert_eq!(j["adc_bits"], 8);
    assert_eq!(j["read_noise_e"], 1.5);
    let (k, g) = (j["electrons_per_unit"].as_f64().unwrap(), j["adc_gain_e_per_dn"].as_f64().unwrap());
    assert_eq!(g, 1.0);
    let n = acquisition(&out);
    for v in &n {
        let dn = v * k / g;
        assert!((dn - dn.round()).abs() < 1e-3 && (0.0..=255.0).contains(&dn.round()), "{v} → {dn} DN");
    }
    let levels: std::collections::BTreeSet<i64> = n.iter().map(|v| (v * k / g).round() as i64).collect();
    assert!(levels.len() > 50 && levels.len() <= 256, "{} levels", levels.len());
}

#[test]
fn render_noise_bad_options_exit_1_and_write_nothing() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("bad");
    for (extra, needle) in [
        (&["--noise", "shot,blur"][..], "`blur`"),
        (&["--read-noise-e", "3"][..], "--read-noise-e needs `read`"),
        (&["--noise", "shot", "--adc-bits", "10"][..], "--adc-bits needs `adc`"),
        (&["--full-well-e", "1000"][..], "--full-well-e needs --noise"),
        (&["--noise", "adc", "--adc-bits", "40"][..], "bit depth"),
        (&["--noise", "read", "--read-noise-e=-1"][..], "read noise"),
        (&["--noise", "shot", "--electrons-per-unit", "0"][..], "electrons per unit"),
        (&["--noise", "shot,read,shot", "--read-noise-e", "2"][..], "`shot` is listed twice"),
        (&["--noise", "read", "--read-noise-e", "1e308"][..], "read noise 1e308"),
    ] {
        let o = run(&out, extra);
        let e = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{extra:?}: {e}");
        assert!(e.contains(needle), "{extra:?}: `{needle}` in {e}");
        assert!(!out.exists(), "{extra:?}: nothing written");
    }
}

#[test]
fn render_dataset_noise_seeds_each_scene_by_name() {
    use diffcassi::scene;
    let d = tempfile::tempdir().unwrap();
    let scenes = d.path().join("scenes");
    std::fs::create_dir_all(&scenes).unwrap();
    let ws = scene::synthetic_wavelengths();
    scene::save_npy(&scene::synthetic_scene(30, 30, &ws, 1), &scenes.join("a.npy")).unwrap();
    scene::save_npy(&scene::synthetic_scene(30, 30, &ws, 2), &scenes.join("b.npy")).unwrap();
    let out = d.path().join("ds");
    let common = ["--preset", "ap", "--scene-size", "24", "--planes", "6", "--bands", "460:640:3", "--rays", "2", "--noise", "shot,read"];
    let mut args = vec!["render-dataset", "--scenes", scenes.to_str().unwrap(), "--out", out.to_str().unwrap(), "--noise-seed", "9"];
    args.extend(common);
    ok(Command::new(env!("CARGO_BIN_EXE_diffcassi")).args(&args).output().unwrap());
    let seeds: Vec<u64> = ["a", "b"].iter().map(|s| json(&out.join(s))["noise"]["seed"].as_u64().unwrap()).collect();
    assert_ne!(seeds[0], seeds[1], "scenes get their own noise");
    // A scene's noisy acquisition equals `render` of that scene alone with the recorded seed.
    let single = d.path().join("single-a");
    let seed = seeds[0].to_string();
    let file = scenes.join("a.npy");
    let mut a2 = vec!["render", "--scene", file.to_str().unwrap(), "--no-mapping", "--out", single.to_str().unwrap(), "--noise-seed", &seed];
    a2.extend(common);
    ok(Command::new(env!("CARGO_BIN_EXE_diffcassi")).args(&a2).output().unwrap());
    assert_eq!(acquisition(&out.join("a")), acquisition(&single));
}

/// The noise of one pixel depends on its own mean count only (one ChaCha8 stream per pixel and source), so
/// the CPU and the GPU kernels (`cpu-twin`, the bits of `cuda`), whose clean acquisitions are ≈ 1e-7 of the
/// peak apart, give the same noise realisation: pixels differ by that rescale or, at an ADC rounding
/// boundary, by one step — never by a shifted run of draws (seed 8 differed in 263 pixels by up to 99 ADC
/// steps with the earlier single row-major stream; docs/gpu.md, "Sensor noise").
#[test]
fn render_noise_is_the_same_realisation_on_the_cpu_and_the_gpu_kernels() {
    let d = tempfile::tempdir().unwrap();
    for seed in ["8", "7"] {
        let dirs: Vec<_> = ["cpu", "cpu-twin"].iter().map(|dev| d.path().join(format!("{dev}-{seed}"))).collect();
        for (dev, dir) in ["cpu", "cpu-twin"].iter().zip(&dirs) {
            let o = Command::new(env!("CARGO_BIN_EXE_diffcassi"))
                .args(["render", "--preset", "msp", "--scene-size", "32", "--planes", "112", "--rays", "20", "--noise", "shot,read,adc", "--adc-bits", "12", "--noise-seed", seed, "--device", dev, "--no-mapping", "--out", dir.to_str().unwrap()])
                .output()
                .unwrap();
            ok(o);
        }
        let (a, b) = (acquisition(&dirs[0]), acquisition(&dirs[1]));
        let j = json(&dirs[0]);
        assert!(j["noise"]["rng"].as_str().unwrap().contains("per pixel"), "{}", j["noise"]);
        let step = j["noise"]["adc_gain_e_per_dn"].as_f64().unwrap() / j["noise"]["electrons_per_unit"].as_f64().unwrap();
        let peak = a.iter().cloned().fold(0.0, f64::max);
        let worst = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
        let flipped = a.iter().zip(&b).filter(|(x, y)| (*x - *y).abs() > 0.5 * step).count();
        assert!(worst <= step + 1e-6 * peak, "seed {seed}: a pixel differs by {} ADC steps", worst / step);
        assert!(flipped <= a.len() / 1000, "seed {seed}: {flipped} of {} pixels differ by an ADC step", a.len());
    }
}

/// A noisy dataset rendered with the earlier single row-major stream (its configuration's `noise` without
/// `rng`) holds another realisation for the same seed: another configuration, refused on resume with the
/// difference named, and rendered again with `--on-mismatch rerender`.
#[test]
fn render_dataset_with_noise_of_the_earlier_stream_is_another_configuration() {
    use diffcassi::scene;
    let d = tempfile::tempdir().unwrap();
    let scenes = d.path().join("scenes");
    std::fs::create_dir_all(&scenes).unwrap();
    scene::save_npy(&scene::synthetic_scene(20, 20, &scene::synthetic_wavelengths(), 1), &scenes.join("a.npy")).unwrap();
    let out = d.path().join("ds");
    let args = ["render-dataset", "--scenes", scenes.to_str().unwrap(), "--out", out.to_str().unwrap(), "--preset", "sp", "--scene-size", "16", "--planes", "6", "--rays", "1", "--bands", "460:640:3", "--noise", "shot", "--no-mapping"];
    let exe = env!("CARGO_BIN_EXE_diffcassi");
    ok(Command::new(exe).args(args).output().unwrap());
    assert!(json(&out.join("a"))["configuration"]["noise"]["rng"].as_str().is_some_and(|r| r.contains("per pixel")));
    // Resumed as is: nothing to do.
    ok(Command::new(exe).args(args).output().unwrap());
    // As the earlier code wrote it: no `rng` in the configuration of the dataset and of its scene.
    for f in [out.join("dataset.json"), out.join("a").join("render.json")] {
        let mut v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&f).unwrap()).unwrap();
        v["configuration"]["noise"].as_object_mut().unwrap().remove("rng");
        std::fs::write(&f, serde_json::to_string_pretty(&v).unwrap()).unwrap();
    }
    let before = std::fs::read(out.join("a").join("acquisition.exr")).unwrap();
    let o = Command::new(exe).args(args).output().unwrap();
    assert_eq!(o.status.code(), Some(1), "{}", String::from_utf8_lossy(&o.stderr));
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(e.contains("another configuration") && e.contains("rng"), "{e}");
    assert_eq!(std::fs::read(out.join("a").join("acquisition.exr")).unwrap(), before, "nothing rewritten");
    let mut rerender: Vec<&str> = args.to_vec();
    rerender.extend(["--on-mismatch", "rerender"]);
    ok(Command::new(exe).args(&rerender).output().unwrap());
    assert!(json(&out.join("a"))["configuration"]["noise"]["rng"].is_string());
}
