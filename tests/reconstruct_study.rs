//! `make-scene`, `reconstruct` and `study` through the binary: outputs, bad input (clear error, exit 1,
//! nothing written), and the study's resume.
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn run(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_diffcassi")).args(args).output().expect("the binary runs")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A tiny noiseless render (16×16 ColorChecker-free synthetic scene, AP, few planes and rays) into `dir`.
fn tiny_render(dir: &Path, preset: &str, scene: Option<&Path>) {
    let mut args = vec!["render", "--preset", preset, "--scene-size", "16", "--bands", "450:650:8", "--planes", "8", "--rays", "2", "--no-mapping", "--out", s(dir)];
    if let Some(p) = scene {
        args.extend(["--scene", s(p), "--fit", "resize"]);
    }
    let o = run(&args);
    assert!(o.status.success(), "{}", stderr(&o));
}

fn assert_fails_cleanly(o: &Output, out: &Path, needles: &[&str]) {
    assert_eq!(o.status.code(), Some(1), "exit code; stderr: {}", stderr(o));
    let e = stderr(o);
    for n in needles {
        assert!(e.contains(n), "`{n}` in the error: {e}");
    }
    assert!(!e.contains("panicked"), "{e}");
    assert!(!out.exists(), "{} must not be written", out.display());
    // No temporary sibling left behind either.
    if let Some(parent) = out.parent() {
        if let Ok(rd) = std::fs::read_dir(parent) {
            for entry in rd.flatten() {
                let name = entry.file_name().to_string_lossy().into_owned();
                assert!(!name.contains(".tmp-"), "leftover {name}");
            }
        }
    }
}

#[test]
fn make_scene_writes_cube_wavelengths_and_preview() {
    let d = tempfile::tempdir().unwrap();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let out = d.path().join("coffee.npy");
    let o = run(&["make-scene", "--rgb", s(&root.join("data/scenes/coffee.png")), "--size", "32", "--out", s(&out)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let cube = diffcassi::scene::load_scene(&out, None).unwrap();
    assert_eq!((cube.height, cube.width, cube.bands()), (32, 32, 28));
    assert!(cube.data.iter().all(|v| (0.0..=1.0).contains(v)));
    assert!(d.path().join("coffee_rgb.png").is_file());
    let chart = d.path().join("chart.exr");
    let o = run(&["make-scene", "--colour-checker", "--size", "48", "--bands", "450:650:5", "--out", s(&chart)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(diffcassi::scene::load_scene(&chart, None).unwrap().bands(), 5);
    // Bad input: no source, a non-PNG photograph.
    let o = run(&["make-scene", "--out", s(&d.path().join("x.npy"))]);
    assert_eq!(o.status.code(), Some(1));
    let bad = d.path().join("bad.png");
    std::fs::write(&bad, b"nope").unwrap();
    let o = run(&["make-scene", "--rgb", s(&bad), "--out", s(&d.path().join("y.npy"))]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("bad.png"), "{}", stderr(&o));
    assert!(!d.path().join("y.npy").exists());
}

#[test]
fn render_accepts_an_rgb_photograph_and_dataset_folders_list_them() {
    let d = tempfile::tempdir().unwrap();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let r = d.path().join("r");
    tiny_render(&r, "ap", Some(&root.join("data/scenes/chelsea.png")));
    let j: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(r.join("render.json")).unwrap()).unwrap();
    assert!(j["scene"]["source"].as_str().unwrap().ends_with("chelsea.png"));
    let scenes = diffcassi::render::dataset::find_scenes(&root.join("data/scenes")).unwrap();
    let names: Vec<&str> = scenes.iter().map(|s| s.name.as_str()).collect();
    assert_eq!(names, ["astronaut", "chelsea", "coffee", "ihc", "retina", "rocket"]);
}

#[test]
fn reconstruct_bad_input_is_a_clear_error_and_writes_nothing() {
    let d = tempfile::tempdir().unwrap();
    let r = d.path().join("render");
    tiny_render(&r, "ap", None);
    let out = d.path().join("rec");
    // A folder without render.json.
    let empty = d.path().join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    assert_fails_cleanly(&run(&["reconstruct", "--from", s(&empty), "--out", s(&out)]), &out, &["render.json", "missing"]);
    // Zero iterations, unknown operator, unknown solver, bad operator seed.
    assert_fails_cleanly(&run(&["reconstruct", "--from", s(&r), "--iterations", "0", "--out", s(&out)]), &out, &["--iterations"]);
    assert_fails_cleanly(&run(&["reconstruct", "--from", s(&r), "--operator", "magic", "--out", s(&out)]), &out, &["--operator", "magic"]);
    assert_fails_cleanly(&run(&["reconstruct", "--from", s(&r), "--solver", "twist", "--out", s(&out)]), &out, &["--solver", "twist"]);
    assert_fails_cleanly(&run(&["reconstruct", "--from", s(&r), "--operator-seed", "x", "--out", s(&out)]), &out, &["--operator-seed"]);
    assert_fails_cleanly(&run(&["reconstruct", "--from", s(&r), "--solver", "admm-tv", "--accelerated", "--out", s(&out)]), &out, &["--accelerated", "gap-tv"]);
    // A mask whose size differs from the scene.
    let bad_mask = d.path().join("badmask");
    copy_dir(&r, &bad_mask);
    diffcassi::render::Mask::random(12, 12, 0.5, 0).unwrap().save_png(&bad_mask.join("mask.png")).unwrap();
    assert_fails_cleanly(&run(&["reconstruct", "--from", s(&bad_mask), "--out", s(&out)]), &out, &["mask.png", "12×12", "16×16"]);
    // A corrupt render.json.
    let bad_json = d.path().join("badjson");
    copy_dir(&r, &bad_json);
    std::fs::write(bad_json.join("render.json"), b"{\"seed\": 0").unwrap();
    assert_fails_cleanly(&run(&["reconstruct", "--from", s(&bad_json), "--out", s(&out)]), &out, &["render.json", "JSON"]);
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap().flatten() {
        std::fs::copy(e.path(), to.join(e.file_name())).unwrap();
    }
}

fn tmp_path(d: &tempfile::TempDir, name: &str) -> PathBuf {
    d.path().join(name)
}

#[test]
fn study_bad_input_is_a_clear_error() {
    let d = tempfile::tempdir().unwrap();
    let out = tmp_path(&d, "study");
    let o = run(&["study", "--synthetic", "1", "--presets", "ap,xx", "--out", s(&out)]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("xx"), "{}", stderr(&o));
    assert!(!out.exists());
    let o = run(&["study", "--synthetic", "1", "--operators", "exact,magic", "--out", s(&out)]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("magic"));
    let o = run(&["study", "--out", s(&out)]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("--scenes"));
    // A mask smaller than the scenes.
    let m = tmp_path(&d, "m.png");
    diffcassi::render::Mask::random(8, 8, 0.5, 0).unwrap().save_png(&m).unwrap();
    let o = run(&["study", "--synthetic", "1", "--scene-size", "16", "--mask", s(&m), "--out", s(&out)]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("m.png") && stderr(&o).contains("8×8"), "{}", stderr(&o));
    assert!(!out.exists());
}

fn read_json(p: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap()
}

#[test]
fn reconstruct_writes_every_output_for_every_operator() {
    let d = tempfile::tempdir().unwrap();
    let r = d.path().join("render");
    tiny_render(&r, "sp", None);
    for op in ["exact", "mapping", "mapping-nearest", "shift"] {
        let out = d.path().join(format!("rec-{op}"));
        let o = run(&["reconstruct", "--from", s(&r), "--operator", op, "--iterations", "3", "--out", s(&out)]);
        assert!(o.status.success(), "{op}: {}", stderr(&o));
        let (shape, data) = diffcassi::io::read_npy_f64(out.join("cube.npy")).unwrap();
        assert_eq!(shape, vec![16, 16, 8], "{op}");
        assert!(data.iter().all(|v| v.is_finite()));
        assert!(std::fs::read(out.join("cube.npy")).unwrap().windows(5).any(|w| w == b"'<f4'"), "float32 NPY");
        for f in ["cube.exr", "rgb.png", "cube_wavelengths_nm.npy"] {
            assert!(out.join(f).is_file(), "{op}: {f}");
        }
        let j = read_json(&out.join("reconstruct.json"));
        assert!(j["seconds"].as_f64().unwrap() > 0.0);
        assert_eq!(j["residual"].as_array().unwrap().len(), 3);
        assert_eq!(j["operator"], op);
        assert_eq!(j["operator_seed"], 1, "default: acquisition seed + 1");
        assert_eq!(j["oracle"], false);
        let cube = diffcassi::scene::load_scene(&out.join("cube.npy"), None).unwrap();
        assert_eq!(cube.wavelengths_nm.len(), 8);
    }
    // The oracle, and a rerun replacing the previous result in place.
    let out = d.path().join("rec-exact");
    let o = run(&["reconstruct", "--from", s(&r), "--operator-seed", "same", "--iterations", "2", "--out", s(&out)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let j = read_json(&out.join("reconstruct.json"));
    assert_eq!((j["operator_seed"].as_u64(), j["oracle"].as_bool()), (Some(0), Some(true)));
    assert_eq!(j["residual"].as_array().unwrap().len(), 2);
    assert!(std::fs::read_dir(d.path()).unwrap().flatten().all(|e| !e.file_name().to_string_lossy().starts_with('.')), "no temporary folders left");
}

fn mtimes(dir: &Path) -> Vec<(PathBuf, std::time::SystemTime)> {
    let mut v = Vec::new();
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        let p = e.path();
        if p.is_dir() {
            v.extend(mtimes(&p));
        } else {
            v.push((p.clone(), e.metadata().unwrap().modified().unwrap()));
        }
    }
    v.sort();
    v
}

#[test]
fn tiny_study_writes_tables_and_resumes() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("study");
    let args = ["study", "--synthetic", "2", "--scene-size", "24", "--presets", "ap,sp", "--bands", "450:650:8", "--planes", "8", "--rays", "2", "--iterations", "3", "--out", s(&out)];
    let o = run(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(String::from_utf8_lossy(&o.stdout).contains("12 cells computed, 0 already done"), "{}", String::from_utf8_lossy(&o.stdout));
    let csv = std::fs::read_to_string(out.join("study.csv")).unwrap();
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    for c in ["scene", "system", "operator", "solver", "psnr_db", "psnr_band_db", "ssim", "sam_rad", "sam_deg", "rmse", "seconds_solve"] {
        assert!(header.contains(&c), "column {c}");
    }
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), 2 * 2 * 3);
    let psnr = header.iter().position(|h| *h == "psnr_db").unwrap();
    assert!(rows.iter().all(|r| r[psnr].parse::<f64>().unwrap().is_finite()));
    let md = std::fs::read_to_string(out.join("study.md")).unwrap();
    assert!(md.contains("| metric | operator | AP | SP |"), "{md}");
    for op in ["exact", "mapping", "shift"] {
        assert!(md.contains(&format!("| PSNR (dB) | {op} |")), "{md}");
    }
    assert!(md.contains("Ablation"));
    assert_eq!(diffcassi::plot::png_dimensions(out.join("study_psnr.png")).unwrap(), diffcassi::plot::BAR_PLOT_SIZE);
    // Every render folder is a valid `reconstruct --from` input.
    assert!(out.join("renders/sp/synthetic01/render.json").is_file());
    // Resume: nothing is recomputed, no cell or render file touched.
    let cells_before = mtimes(&out.join("cells"));
    let renders_before = mtimes(&out.join("renders"));
    let o = run(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(String::from_utf8_lossy(&o.stdout).contains("0 cells computed, 12 already done"), "{}", String::from_utf8_lossy(&o.stdout));
    assert_eq!(mtimes(&out.join("cells")), cells_before);
    assert_eq!(mtimes(&out.join("renders")), renders_before);
    // A missing cell is recomputed alone; a changed solver setting recomputes the cells but not the renders.
    std::fs::remove_file(out.join("cells/sp/synthetic00/shift-gap-tv.json")).unwrap();
    let o = run(&args);
    assert!(String::from_utf8_lossy(&o.stdout).contains("1 cells computed, 11 already done"), "{}", String::from_utf8_lossy(&o.stdout));
    let mut changed = args.to_vec();
    let k = changed.iter().position(|a| *a == "3").unwrap();
    changed[k] = "4";
    let o = run(&changed);
    assert!(String::from_utf8_lossy(&o.stdout).contains("12 cells computed, 0 already done"), "{}", String::from_utf8_lossy(&o.stdout));
    assert_eq!(mtimes(&out.join("renders")), renders_before);
}

#[test]
fn study_takes_a_folder_of_photographs_and_cubes() {
    let d = tempfile::tempdir().unwrap();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let scenes = d.path().join("scenes");
    std::fs::create_dir_all(&scenes).unwrap();
    std::fs::copy(root.join("data/scenes/chelsea.png"), scenes.join("chelsea.png")).unwrap();
    let o = run(&["make-scene", "--colour-checker", "--size", "32", "--bands", "450:650:8", "--out", s(&scenes.join("chart.npy"))]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(scenes.join("chart_rgb.png").is_file(), "the preview beside the cube is not a scene of its own");
    let out = d.path().join("study");
    let o = run(&["study", "--scenes", s(&scenes), "--scene-size", "16", "--presets", "ap", "--operators", "shift", "--bands", "450:650:8", "--planes", "8", "--rays", "2", "--iterations", "2", "--out", s(&out)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let csv = std::fs::read_to_string(out.join("study.csv")).unwrap();
    let scenes_seen: Vec<&str> = csv.lines().skip(1).map(|l| l.split(',').next().unwrap()).collect();
    assert_eq!(scenes_seen, ["chart", "chelsea"]);
    // A wrong --scene-wavelengths count for the cube is an error naming the file.
    let o = run(&["study", "--scenes", s(&scenes), "--scene-size", "16", "--presets", "ap", "--scene-wavelengths", "450:650:3", "--out", s(&d.path().join("s2"))]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("chart.npy"), "{}", stderr(&o));
}

#[test]
fn study_mask_file_is_centre_cropped_to_the_scene() {
    let d = tempfile::tempdir().unwrap();
    let m = d.path().join("mask.npy");
    let values: Vec<f64> = (0..20 * 20).map(|q| ((q * 7 + q / 20) % 3 == 0) as u8 as f64).collect();
    diffcassi::io::write_npy_f64(&m, &[20, 20], &values).unwrap();
    let out = d.path().join("study");
    let o = run(&["study", "--synthetic", "1", "--scene-size", "16", "--presets", "ap", "--operators", "shift", "--bands", "450:650:4", "--planes", "4", "--rays", "1", "--iterations", "1", "--mask", s(&m), "--out", s(&out)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let used = diffcassi::render::Mask::load(&out.join("renders/ap/synthetic00/mask.png")).unwrap();
    assert_eq!((used.height, used.width), (16, 16));
    for r in 0..16 {
        for c in 0..16 {
            assert_eq!(used.values[r * 16 + c] as f64, values[(r + 2) * 20 + c + 2], "({r}, {c})");
        }
    }
}
