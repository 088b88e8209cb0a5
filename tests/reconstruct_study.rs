//! `make-scene`, `reconstruct` and `study` through the binary: outputs, bad input (clear error, exit 1,
//! nothing written), and the study's resume.
use crate::common;

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
    assert!(stderr(&o).contains("--operators `exact,magic`: entry `magic`: use exact"), "{}", stderr(&o));
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
    // Bands whose render planes leave a glass's range (half a band beyond 450–2000 nm at 2 bands reaches
    // −311 nm): refused before anything is written (study.json and mask.png were, and the study then failed).
    let o = run(&["study", "--synthetic", "1", "--scene-size", "12", "--presets", "sp", "--bands", "450,2000", "--planes", "112", "--rays", "1", "--out", s(&out)]);
    assert_fails_cleanly(&o, &out, &["--presets sp", "render plane 0"]);
    // A bad --bands names --bands (it was named --wavelength-nm).
    let o = run(&["study", "--synthetic", "1", "--bands", "450:650:0", "--out", s(&out)]);
    assert_fails_cleanly(&o, &out, &["--bands `450:650:0`"]);
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
        if op == "exact" {
            assert_eq!(j["operator_seed"], 1, "default: acquisition seed + 1");
        } else {
            assert!(j["operator_seed"].is_null() && j["operator_rays"].is_null(), "{op}: a model operator traces no rays");
        }
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

// ---------------------------------------------------------------- study of system files (issue 42, item 1)

/// The tiny study settings of the `--systems` tests: one 16² synthetic scene, 4 bands × 4 planes, 2 rays, 3 iterations.
const TINY: [&str; 13] = ["study", "--synthetic", "1", "--scene-size", "16", "--bands", "450:650:4", "--planes", "4", "--rays", "2", "--iterations", "3"];

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// study.csv's rows as (system, preset, operator, psnr_db), fields unquoted (no field of these studies holds a
/// comma; the CSV writer quotes an empty string, `""`, the preset of a system file).
fn study_rows(out: &Path) -> Vec<(String, String, String, f64)> {
    let csv = std::fs::read_to_string(out.join("study.csv")).unwrap();
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let (sy, pr, op, ps) = (col("system"), col("preset"), col("operator"), col("psnr_db"));
    let field = |f: &str| f.strip_prefix('"').and_then(|f| f.strip_suffix('"')).unwrap_or(f).replace("\"\"", "\"");
    lines.map(|l| l.split(',').collect::<Vec<_>>()).map(|r| (field(r[sy]), field(r[pr]), field(r[op]), r[ps].parse().unwrap())).collect()
}

#[test]
fn study_takes_system_files_beside_presets_and_recomputes_an_edited_file() {
    let d = tempfile::tempdir().unwrap();
    let file = d.path().join("my_ap.json");
    let mut spec = diffcassi::presets::spec("ap").unwrap();
    diffcassi::spec::save_spec_file(&spec, &file).unwrap();
    let out = d.path().join("study");
    let args: Vec<&str> = TINY.iter().copied().chain(["--presets", "sp", "--systems", s(&file), "--operators", "exact,shift", "--out", s(&out)]).collect();
    let o = run(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("4 cells computed, 0 already done"), "{}", stdout(&o));
    // The file's rows are labelled by its stem, the preset's by its display name; every metric finite.
    let rows = study_rows(&out);
    let systems: Vec<(&str, &str)> = rows.iter().map(|r| (r.0.as_str(), r.1.as_str())).collect();
    assert_eq!(systems, [("SP", "sp"), ("SP", "sp"), ("my_ap", ""), ("my_ap", "")]);
    assert!(rows.iter().all(|r| r.3.is_finite() && r.3 > 5.0), "{rows:?}");
    let md = std::fs::read_to_string(out.join("study.md")).unwrap();
    assert!(md.contains("| metric | operator | SP | my_ap |"), "{md}");
    // The file's spec is part of its renders' and cells' configuration; the preset's configuration is unchanged.
    let r = read_json(&out.join("renders/my_ap/synthetic00/render.json"));
    assert_eq!(r["study_config"]["system_spec"]["name"], spec.name.as_str());
    assert!(read_json(&out.join("renders/sp/synthetic00/render.json"))["study_config"].get("system_spec").is_none());
    let cell = read_json(&out.join("cells/my_ap/synthetic00/exact-gap-tv.json"));
    assert_eq!((cell["system"].as_str(), cell["preset"].is_null(), cell["system_file"].as_str()), (Some("my_ap"), true, Some(s(&file))));
    let study = read_json(&out.join("study.json"));
    assert_eq!(study["systems"][1]["file"], s(&file));
    // Resume: nothing recomputed. Edited file (image distance + 50 µm): its rows only, renders and cells.
    let o = run(&args);
    assert!(stdout(&o).contains("0 cells computed, 4 already done"), "{}", stdout(&o));
    let sp_renders = mtimes(&out.join("renders/sp"));
    let k = spec.surfaces.len() - 2;
    spec.surfaces[k].thickness_mm.value += 0.05;
    diffcassi::spec::save_spec_file(&spec, &file).unwrap();
    let before = read_json(&out.join("renders/my_ap/synthetic00/render.json"))["acquisition_total"].as_f64().unwrap();
    let o = run(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("2 cells computed, 2 already done"), "{}", stdout(&o));
    assert_eq!(mtimes(&out.join("renders/sp")), sp_renders);
    let r = read_json(&out.join("renders/my_ap/synthetic00/render.json"));
    assert_eq!(r["system_spec"]["surfaces"][k]["thickness_mm"].as_f64(), Some(spec.surfaces[k].thickness_mm.value));
    assert_ne!(r["acquisition_total"].as_f64().unwrap(), before);
}

#[test]
fn study_of_a_system_at_infinity_takes_scene_fov_deg() {
    let d = tempfile::tempdir().unwrap();
    let file = d.path().join("singlet.toml");
    diffcassi::spec::save_spec_file(&common::singlet_at_infinity(false), &file).unwrap();
    let out = d.path().join("study");
    // The singlet at infinity beside SP (finite, 10 µm pixels); 0.2° over 16 pixels: ≈ 13 µm per pixel at
    // the singlet's 60 mm focal length.
    let args = |fov: &'static str| -> Vec<String> { TINY.iter().copied().chain(["--presets", "sp", "--systems", s(&file), "--scene-fov-deg", fov, "--operators", "exact,mapping,mapping-nearest,shift", "--out", s(&out)]).map(String::from).collect() };
    let runs = |fov| Command::new(env!("CARGO_BIN_EXE_diffcassi")).args(args(fov)).output().unwrap();
    let o = runs("0.2");
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("8 cells computed"), "{}", stdout(&o));
    let rows: Vec<_> = study_rows(&out).into_iter().filter(|r| r.0 == "singlet").collect();
    assert_eq!(rows.iter().map(|r| r.2.as_str()).collect::<Vec<_>>(), ["exact", "mapping", "mapping-nearest", "shift"]);
    // Every operator reconstructs (finite metrics); the singlet's strong axial colour blur is modelled by the
    // exact operator only, which reconstructs best.
    assert!(rows.iter().all(|r| r.1.is_empty() && r.3.is_finite()), "{rows:?}");
    assert!(rows[1..].iter().all(|r| r.3 < rows[0].3), "{rows:?}");
    // Recorded as render records it: the angular extent, no pitch in mm; in study.json too. SP's render keeps its pitch.
    let r = read_json(&out.join("renders/singlet/synthetic00/render.json"));
    assert_eq!((r["scene_fov_deg"].as_f64(), r["scene_pitch_mm"].is_null()), (Some(0.2), true));
    assert!((r["scene_pitch_rad"].as_f64().unwrap() - 0.2f64.to_radians() / 16.0).abs() < 1e-18);
    assert_eq!(r["study_config"]["scene_fov_deg"].as_f64(), Some(0.2));
    let r = read_json(&out.join("renders/sp/synthetic00/render.json"));
    assert!(r.get("scene_fov_deg").is_none() && r["study_config"].get("scene_fov_deg").is_none() && r["scene_pitch_mm"].as_f64() == Some(0.01), "{}", r["study_config"]);
    let study = read_json(&out.join("study.json"));
    assert_eq!((study["scene_fov_deg"].as_f64(), study["systems"][1]["object_at_infinity"].as_bool()), (Some(0.2), Some(true)));
    // Another angular extent is another render of the system at infinity: its cells recomputed, SP's kept.
    let o = runs("0.25");
    assert!(stdout(&o).contains("4 cells computed, 4 already done"), "{}", stdout(&o));
    assert_eq!(read_json(&out.join("renders/singlet/synthetic00/render.json"))["scene_fov_deg"].as_f64(), Some(0.25));
}

#[test]
fn study_recomputes_a_system_file_whose_glass_catalogue_changed() {
    let d = tempfile::tempdir().unwrap();
    // The singlet at infinity in a glass of its own AGF catalogue (N-BK7's Sellmeier coefficients, named X1).
    let agf = d.path().join("mine.agf");
    let catalogue = |b1: &str| format!("CC test\nNM X1 2 0 1.5168 64.17 0 1\nCD {b1} 0.00600069867 0.231792344 0.0200179144 1.01046945 103.560653\nLD 0.3 2.5\n");
    std::fs::write(&agf, catalogue("1.03961212")).unwrap();
    let mut spec = common::singlet_at_infinity(false);
    spec.glass_catalogs = vec![s(&agf).to_string()];
    spec.surfaces[1].material = Some("X1".into());
    let file = d.path().join("singlet.json");
    diffcassi::spec::save_spec_file(&spec, &file).unwrap();
    let out = d.path().join("study");
    let args: Vec<&str> = TINY.iter().copied().chain(["--systems", s(&file), "--scene-fov-deg", "0.2", "--operators", "shift", "--out", s(&out)]).collect();
    let o = run(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("1 cells computed, 0 already done"), "{}", stdout(&o));
    assert!(read_json(&out.join("cells/singlet/synthetic00/shift-gap-tv.json"))["config"]["glass_catalogs_crc32"][s(&agf)].is_string());
    let o = run(&args);
    assert!(stdout(&o).contains("0 cells computed, 1 already done"), "{}", stdout(&o));
    // The catalogue edited, the spec file untouched: another glass, another render.
    std::fs::write(&agf, catalogue("1.05")).unwrap();
    let o = run(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("1 cells computed, 0 already done"), "{}", stdout(&o));
}

/// `--glass-catalog` files join the system's spec (as absolute paths): the study's render records them, so a
/// later `reconstruct --from` (from another working directory) reads the same glasses; `study --glass-catalog`
/// applies to `--systems` files and is refused without one; a spec file's relative `glass_catalogs` entry is
/// read beside the spec file, from any working directory.
#[test]
fn glass_catalogues_of_the_command_line_are_recorded_with_the_system() {
    let d = tempfile::tempdir().unwrap();
    std::fs::create_dir_all(d.path().join("cat")).unwrap();
    std::fs::create_dir_all(d.path().join("spec")).unwrap();
    // X1: N-BK7's Sellmeier coefficients under a name no built-in catalogue has.
    let agf = d.path().join("cat/mine.agf");
    std::fs::write(&agf, "CC test\nNM X1 2 0 1.5168 64.17 0 1\nCD 1.03961212 0.00600069867 0.231792344 0.0200179144 1.01046945 103.560653\nLD 0.3 2.5\n").unwrap();
    let mut spec = common::singlet_at_infinity(false);
    spec.surfaces[1].material = Some("X1".into());
    let file = d.path().join("spec/singlet.json");
    diffcassi::spec::save_spec_file(&spec, &file).unwrap();
    let out = d.path().join("study");
    let study = |extra: &[&str]| run(&TINY.iter().copied().chain(["--systems", s(&file), "--scene-fov-deg", "0.2", "--operators", "shift", "--out", s(&out)]).chain(extra.iter().copied()).collect::<Vec<_>>());
    assert_fails_cleanly(&study(&[]), &out, &["X1"]);
    assert_fails_cleanly(&run(&TINY.iter().copied().chain(["--presets", "sp", "--glass-catalog", s(&agf), "--out", s(&out)]).collect::<Vec<_>>()), &out, &["--glass-catalog applies to the files of --systems"]);
    let o = study(&["--glass-catalog", s(&agf)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let render = out.join("renders/singlet/synthetic00");
    let recorded = read_json(&render.join("render.json"))["system_spec"]["glass_catalogs"].clone();
    assert_eq!(recorded, serde_json::json!([s(&std::path::absolute(&agf).unwrap())]));
    let o = Command::new(env!("CARGO_BIN_EXE_diffcassi")).current_dir(d.path().join("cat")).args(["reconstruct", "--from", s(&render), "--solver", "gap-tv", "--iterations", "2", "--out", s(&d.path().join("r"))]).output().unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    // A spec file's own relative entry is read beside it, whatever the working directory.
    spec.glass_catalogs = vec!["../cat/mine.agf".into()];
    let relative = d.path().join("spec/relative.toml");
    diffcassi::spec::save_spec_file(&spec, &relative).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_diffcassi")).current_dir(d.path()).args(["info", "--system", s(&relative)]).output().unwrap();
    assert!(o.status.success() && stdout(&o).contains("X1"), "{}{}", stdout(&o), stderr(&o));
}

#[test]
fn study_system_file_errors_name_the_file_system_and_field() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("study");
    let inf = d.path().join("singlet.toml");
    diffcassi::spec::save_spec_file(&common::singlet_at_infinity(false), &inf).unwrap();
    let sp = d.path().join("sub").join("sp.json");
    std::fs::create_dir_all(sp.parent().unwrap()).unwrap();
    diffcassi::spec::save_spec_file(&diffcassi::presets::spec("sp").unwrap(), &sp).unwrap();
    let other = d.path().join("singlet.json");
    diffcassi::spec::save_spec_file(&common::singlet_at_infinity(false), &other).unwrap();
    let missing = d.path().join("nope.toml");
    let study = |extra: &[&str]| run(&["study", "--synthetic", "1", "--scene-size", "16", "--out", s(&out)].iter().copied().chain(extra.iter().copied()).collect::<Vec<_>>());
    // A missing file; two files of one stem; a file of a preset's name.
    assert_fails_cleanly(&study(&["--systems", s(&missing)]), &out, &["nope.toml", "no such file"]);
    assert_fails_cleanly(&study(&["--systems", &format!("{},{}", s(&inf), s(&other)), "--scene-fov-deg", "1"]), &out, &["singlet.toml", "singlet.json", "`singlet`"]);
    assert_fails_cleanly(&study(&["--presets", "sp", "--systems", s(&sp)]), &out, &["--presets sp", "sp.json", "`sp`"]);
    // An object at infinity without --scene-fov-deg: the file and the flag named.
    assert_fails_cleanly(&study(&["--systems", s(&inf)]), &out, &["singlet.toml", "object at infinity", "--scene-fov-deg"]);
    // Bad angles, whatever the systems.
    for bad in ["0", "180", "nan", "-5", "inf"] {
        assert_fails_cleanly(&study(&["--systems", s(&inf), "--scene-fov-deg", bad]), &out, &["--scene-fov-deg", "(0, 180)"]);
    }
    // --scene-fov-deg where no system is at infinity: the systems named.
    assert_fails_cleanly(&study(&["--presets", "ap", "--systems", s(&sp), "--scene-fov-deg", "5"]), &out, &["--scene-fov-deg 5", "AP, sp", "finite object"]);
}

/// A resumed study trusts a cell only with the reconstruction it recorded (`cube_npy_sha256`) and a render
/// folder only when it reads back whole: a run that failed between swapping in a reconstruction and writing
/// its cell left another run's cube under a cell counted as done, and a deleted mask.png stopped the study at
/// its first cell (a held-out battery, round 8).
#[test]
fn study_resume_checks_its_reconstructions_and_render_folders() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("study");
    let args = ["study", "--synthetic", "2", "--scene-size", "12", "--presets", "sp", "--operators", "shift,exact", "--bands", "450:650:4", "--planes", "4", "--rays", "1", "--iterations", "3", "--out", s(&out)];
    let stdout = |o: &Output| String::from_utf8_lossy(&o.stdout).into_owned();
    let o = run(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let cell = read_json(&out.join("cells/sp/synthetic01/exact-gap-tv.json"));
    let cube = out.join(cell["reconstruction"].as_str().unwrap()).join("cube.npy");
    assert_eq!(cell["cube_npy_sha256"].as_str().unwrap(), diffcassi::io::sha256::sha256_hex(&std::fs::read(&cube).unwrap()));
    // Another cube in the cell's folder (another run's): that cell alone is computed again.
    let other = out.join("recon/sp/synthetic00/exact-gap-tv/cube.npy");
    std::fs::copy(&other, &cube).unwrap();
    let o = run(&args);
    assert!(stdout(&o).contains("1 cells computed, 3 already done"), "{}{}", stdout(&o), stderr(&o));
    assert_eq!(read_json(&out.join("cells/sp/synthetic01/exact-gap-tv.json"))["cube_npy_sha256"], cell["cube_npy_sha256"]);
    // A deleted cube: the same.
    std::fs::remove_file(out.join("recon/sp/synthetic00/shift-gap-tv/cube.npy")).unwrap();
    let o = run(&args);
    assert!(stdout(&o).contains("1 cells computed, 3 already done"), "{}{}", stdout(&o), stderr(&o));
    // A render folder without its mask is rendered again (the same bits: its cells stay done).
    std::fs::remove_file(out.join("renders/sp/synthetic00/mask.png")).unwrap();
    let o = run(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("rendered 1 scenes") && stdout(&o).contains("0 cells computed, 4 already done"), "{}", stdout(&o));
    assert!(out.join("renders/sp/synthetic00/mask.png").is_file());
}

/// A study refuses, before anything is written, the scenes `render` refuses (a negative radiance, one beyond
/// the limit) and a scene size below SSIM's window (each failed after the study's first files).
#[test]
fn study_refuses_bad_scenes_and_sizes_before_writing() {
    let d = tempfile::tempdir().unwrap();
    let ws = diffcassi::scene::synthetic_wavelengths();
    for (name, value, needle) in [("neg", -0.5f32, "≥ 0"), ("huge", 1e35f32, "3.403e29")] {
        let scenes = d.path().join(name);
        std::fs::create_dir_all(&scenes).unwrap();
        let mut cube = diffcassi::scene::synthetic_scene(16, 16, &ws, 1);
        cube.data[5 * 16 * ws.len() + 5] = value;
        diffcassi::scene::save_npy(&cube, &scenes.join("a.npy")).unwrap();
        let out = tmp_path(&d, &format!("study-{name}"));
        let o = run(&["study", "--scenes", s(&scenes), "--presets", "sp", "--operators", "shift", "--scene-size", "16", "--planes", "4", "--rays", "1", "--out", s(&out)]);
        assert_fails_cleanly(&o, &out, &["a.npy", needle]);
    }
    let out = tmp_path(&d, "study-small");
    let o = run(&["study", "--synthetic", "1", "--presets", "sp", "--operators", "shift", "--scene-size", "8", "--planes", "4", "--rays", "1", "--out", s(&out)]);
    assert_fails_cleanly(&o, &out, &["--scene-size 8", "≥ 11", "SSIM"]);
}
