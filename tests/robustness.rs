//! Issue 16, classes 2, 4 and 5 beyond the CLI table of `tests/bad_input.rs`: values born inside the
//! computation, all-or-nothing output sets, and loose options.
use diffcassi::prelude::*;
use diffcassi::spec::Cell;
use std::path::Path;
use std::process::{Command, Output};

fn run(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_diffcassi")).args(args).current_dir(dir).output().unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn entries(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    v.sort();
    v
}

fn build_err(spec: &SystemSpec) -> String {
    SequentialSystem::build(spec).expect_err("must fail").to_string()
}

// ------------------------------------------------------------------ class 2

#[test]
fn overflowing_pickup_names_the_surface_and_the_pickup() {
    let mut s = presets::spec("sp").unwrap();
    // Surface 11's tilt_y_deg picks up surface 7's (30°): a scale of 1e308 gives 3e309 = inf.
    s.surfaces[11].tilt_y_deg = Some(Cell::pickup(30.0, 7, 1e308));
    let e = build_err(&s);
    for part in ["surface 11", "tilt_y_deg", "not finite", "pickup from surface 7", "1e308"] {
        assert!(e.contains(part), "`{e}` lacks `{part}`");
    }
    // A finite but absurd result too.
    s.surfaces[11].tilt_y_deg = Some(Cell::pickup(30.0, 7, 1e3));
    let e = build_err(&s);
    assert!(e.contains("surface 11") && e.contains("plausible range ±360"), "{e}");
}

#[test]
fn absurd_lengths_are_refused_with_the_range() {
    for (k, col) in [(16usize, "thickness_mm"), (3, "decenter_x_mm")] {
        for v in [1e308, -2e6, 1e7] {
            let mut s = presets::spec("sp").unwrap();
            let c = Some(Cell::fixed(v));
            match col {
                "thickness_mm" => s.surfaces[k].thickness_mm = Cell::fixed(v),
                _ => s.surfaces[k].decenter_x_mm = c,
            }
            let e = build_err(&s);
            assert!(e.contains(&format!("surface {k}")) && e.contains(col) && e.contains("plausible range ±1e6 mm"), "{e}");
        }
    }
    // The limit itself is allowed.
    let mut s = presets::spec("sp").unwrap();
    s.surfaces[18].thickness_mm = Cell::fixed(43.2);
    SequentialSystem::build(&s).unwrap();
}

#[test]
fn absurd_landings_are_classified_not_ok() {
    let mut t = diffcassi::tracer::TracedBatch::zeroed(5);
    t.x = vec![1.0, 1e305, f64::INFINITY, 0.0, -2e6];
    t.y = vec![2.0, 0.0, 0.0, f64::NAN, 0.0];
    t.dir_z = vec![1.0; 5];
    t.classify_out_of_range(19);
    assert_eq!(t.status[0], RayStatus::Ok);
    for i in 1..5 {
        assert_eq!(t.status[i], RayStatus::OutOfRange, "ray {i}");
        assert_eq!((t.x[i], t.y[i], t.surface[i]), (0.0, 0.0, 19));
    }
    assert_eq!(RayStatus::OutOfRange.label(), "out_of_range");
    // The analytic tracer applies it: every ray of a sane system is still ok.
    let sys = SequentialSystem::build(&presets::spec("sp").unwrap()).unwrap();
    let rays = RayBatch::for_field(&sys, [0.0, 0.0], &diffcassi::rays::PupilPattern::Hexapolar { rings: 3 }.points(), 520.0).unwrap();
    let out = AnalyticTracer::default().trace(&sys, &rays).unwrap();
    assert!(out.status.iter().all(|s| *s == RayStatus::Ok));
}

#[test]
fn json_is_never_null_for_a_number() {
    #[derive(serde::Serialize)]
    struct Spot {
        rms_radius_um: f64,
    }
    let e = diffcassi::limits::check_json_finite("spot.json", &vec![Spot { rms_radius_um: 1.0 }, Spot { rms_radius_um: f64::INFINITY }]).unwrap_err().to_string();
    assert!(e.contains("[1].rms_radius_um = inf") && e.contains("spot.json"), "{e}");
    // A spot JSON of the CLI holds numbers only where numbers belong.
    let dir = tempfile::tempdir().unwrap();
    let o = run(dir.path(), &["spot", "--preset", "sp", "--pupil", "hexapolar:3", "--json", "s.json"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.path().join("s.json")).unwrap()).unwrap();
    for s in v["spots"].as_array().unwrap() {
        for k in ["rms_radius_um", "geo_radius_um", "wavelength_nm"] {
            assert!(s[k].is_number(), "{k}: {s}");
        }
    }
}

#[test]
fn a_scene_near_the_f32_limit_is_refused_and_a_bright_allowed_one_stays_finite() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let lim = diffcassi::limits::MAX_SCENE_VALUE;
    diffcassi::io::write_npy_f32(d.join("huge.npy"), &[4, 4, 3], &vec![3.0e38f32; 48]).unwrap();
    diffcassi::io::write_npy_f32(d.join("bright.npy"), &[4, 4, 3], &vec![(lim * 0.9) as f32; 48]).unwrap();
    let common = ["render", "--preset", "sp", "--scene-size", "4", "--scene-wavelengths", "450,550,650", "--bands", "450,550,650", "--planes", "3", "--rays", "2", "--no-mapping"];
    let o = run(d, &[&common[..], &["--scene", "huge.npy", "--out", "huge"]].concat());
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("huge.npy") && stderr(&o).contains("f32 range"), "{}", stderr(&o));
    assert!(!d.join("huge").exists());
    let o = run(d, &[&common[..], &["--scene", "bright.npy", "--out", "bright"]].concat());
    assert!(o.status.success(), "{}", stderr(&o));
    let img = diffcassi::io::exr::read_exr(d.join("bright/acquisition.exr")).unwrap();
    let all: Vec<f32> = img.channels.iter().flat_map(|c| c.data.iter().copied()).collect();
    assert!(!all.is_empty() && all.iter().all(|v| v.is_finite()) && all.iter().any(|v| *v > 0.0));
}

// ------------------------------------------------------------------ class 4

#[test]
fn spot_failing_late_leaves_the_old_files() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("old.csv"), "old").unwrap();
    // The PNG goes to a folder that cannot be created (below a regular file): the CSV, computed and staged
    // first, must not replace the old one.
    std::fs::write(d.join("blocker"), "a file").unwrap();
    let o = run(d, &["spot", "--preset", "sp", "--pupil", "hexapolar:2", "--csv", "old.csv", "--json", "new.json", "--png", "blocker/x.png"]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert_eq!(std::fs::read_to_string(d.join("old.csv")).unwrap(), "old");
    assert_eq!(entries(d), vec!["blocker", "old.csv"]);
    // Succeeding: all files at once.
    let o = run(d, &["spot", "--preset", "sp", "--pupil", "hexapolar:2", "--csv", "old.csv", "--json", "new.json", "--png", "new.png"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(entries(d), vec!["blocker", "new.json", "new.png", "old.csv"]);
    assert!(std::fs::read_to_string(d.join("old.csv")).unwrap().contains("px,py"));
}

#[test]
fn distortion_validates_before_writing() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("g.csv"), "old").unwrap();
    for bad in [&["--arrow-scale", "0", "--png", "g.png"][..], &["--png", "g.gif"][..], &["--json", "blocker/g.json"][..]] {
        std::fs::write(d.join("blocker"), "a file").unwrap();
        let o = run(d, &[&["distortion", "--preset", "sp", "--grid", "5", "--csv", "g.csv"][..], bad].concat());
        assert_eq!(o.status.code(), Some(1), "{bad:?}: {}", stderr(&o));
        assert_eq!(std::fs::read_to_string(d.join("g.csv")).unwrap(), "old", "{bad:?}");
        assert_eq!(entries(d), vec!["blocker", "g.csv"], "{bad:?}");
    }
}

#[test]
fn render_replaces_its_folder_as_a_whole() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let common = ["render", "--preset", "sp", "--scene-size", "8", "--planes", "28", "--rays", "1", "--no-mapping", "--out", "r"];
    let o = run(d, &[&common[..], &["--cube"]].concat());
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(entries(&d.join("r")).contains(&"cube.exr".to_string()));
    let first = std::fs::read(d.join("r/render.json")).unwrap();
    // A failing render (bad scene) leaves the previous set byte for byte.
    std::fs::write(d.join("bad.npy"), b"not an npy").unwrap();
    let o = run(d, &[&common[..], &["--scene", "bad.npy"]].concat());
    assert_eq!(o.status.code(), Some(1));
    assert_eq!(std::fs::read(d.join("r/render.json")).unwrap(), first);
    assert_eq!(entries(d), vec!["bad.npy", "r"]);
    // A new render without --cube: the set is the new one (no stale cube.exr from the old set).
    let o = run(d, &[&common[..], &["--seed", "5"]].concat());
    assert!(o.status.success(), "{}", stderr(&o));
    let names = entries(&d.join("r"));
    assert!(!names.contains(&"cube.exr".to_string()) && names.contains(&"acquisition.exr".to_string()), "{names:?}");
    assert_eq!(entries(d), vec!["bad.npy", "r"]);
}

// ------------------------------------------------------------------ class 5

#[test]
fn cell_errors_name_the_accepted_forms() {
    let spec = presets::spec("sp").unwrap();
    let text = diffcassi::spec::to_toml(&spec).unwrap().replacen("thickness_mm = 50.0", "thickness_mm = \"fifty\"", 1);
    let e = diffcassi::spec::from_toml(&text, "u.toml").unwrap_err().to_string();
    assert!(!e.contains("untagged"), "{e}");
    assert!(e.contains("u.toml") && e.contains("fifty") && e.contains("a number, or a table"), "{e}");
    let text = diffcassi::spec::to_toml(&spec).unwrap().replacen("thickness_mm = 50.0", "thickness_mm = { value = 1.0, pikcup = 3 }", 1);
    let e = diffcassi::spec::from_toml(&text, "u.toml").unwrap_err().to_string();
    assert!(e.contains("pikcup") && e.contains("pickup"), "{e}");
}

#[test]
fn negative_numbers_after_a_space_reach_the_option() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // Accepted where negative values are meaningful…
    let o = run(d, &["dispersion", "--preset", "sp", "--field-mm", "-2.5,0", "--wavelengths-nm", "450,650"]);
    assert!(o.status.success(), "{}", stderr(&o));
    // …and otherwise refused by the option's own check, which names it.
    for (args, name) in [(&["spot", "--preset", "sp", "--tolerance-um", "-1"][..], "--tolerance-um"), (&["distortion", "--preset", "sp", "--half-width-mm", "-1"][..], "--half-width-mm"), (&["render", "--preset", "sp", "--scene-size", "-4"][..], "--scene-size")] {
        let o = run(d, args);
        assert!(matches!(o.status.code(), Some(1) | Some(2)), "{args:?}");
        assert!(stderr(&o).contains(name), "{args:?}: {}", stderr(&o));
        assert!(!stderr(&o).contains("unexpected argument"), "{}", stderr(&o));
    }
    assert!(entries(d).is_empty());
}
