//! Bad input, round 5 (a held-out battery of 30 Nov 2026, the command line): an Airy disk smaller than a pixel
//! (a kernel of 0/0: NaN acquisitions, and a dataset written with them, exit 0); outputs that are named pipes,
//! devices or symbolic links (a FIFO or a device node was replaced by a regular file; links were replaced or
//! written through, command by command); a one-band scene outside the render's planes (rendered as if inside);
//! a dataset resumed on another device (a mix of CPU and GPU-kernel accumulations); `calibrate --noise-um 1e300`
//! (an infinite residual written as `null`, exit 0); `reconstruct --truth` of maximum 0 (`null` PSNRs, exit 0).
//! Each case runs the real binary: the exit code, a message naming the problem, nothing written or replaced.
use std::path::Path;
use std::process::Command;

use crate::cli_run::{ok_cli as ok, run_cli as run};

fn exr(path: &Path) -> Vec<f32> {
    diffcassi::io::exr::read_exr(path).unwrap_or_else(|e| panic!("{}: {e}", path.display())).channels.remove(0).data
}

fn mkfifo(path: &Path) {
    let c = std::ffi::CString::new(path.to_str().unwrap()).unwrap();
    // SAFETY: a valid NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0, "mkfifo {}", path.display());
}

fn is_fifo(path: &Path) -> bool {
    use std::os::unix::fs::FileTypeExt;
    std::fs::symlink_metadata(path).map(|m| m.file_type().is_fifo()).unwrap_or(false)
}

/// A disk inside one pixel is the identity kernel: the acquisition equals the render without blur, on the CPU
/// and through the GPU kernels' twin, and a dataset's acquisitions are finite. (`--airy-diameter-px 0.01` gave
/// NaN; `render` caught it at the write, `render-dataset` wrote it and exited 0.) Every EXR writer refuses a
/// non-finite value whatever its source (src/io/exr.rs).
#[test]
fn sub_pixel_airy_disks_render_as_no_blur() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let base = ["render", "--preset", "sp", "--scene-size", "12", "--planes", "3", "--rays", "2", "--seed", "5"];
    for device in ["cpu", "cpu-twin"] {
        let (tiny, none) = (format!("tiny-{device}"), format!("none-{device}"));
        let mut a = base.to_vec();
        a.extend(["--device", device, "--airy-diameter-px", "0.01", "--out", &tiny]);
        ok(dir, &a);
        let mut b = base.to_vec();
        b.extend(["--device", device, "--no-airy", "--out", &none]);
        ok(dir, &b);
        let (t, n) = (exr(&dir.join(&tiny).join("acquisition.exr")), exr(&dir.join(&none).join("acquisition.exr")));
        assert!(t.iter().all(|v| v.is_finite()) && t.iter().any(|&v| v > 0.0), "{device}: a sub-pixel disk gave a non-finite or empty image");
        assert_eq!(t, n, "{device}: a disk inside one pixel must be the identity kernel");
    }
    std::fs::create_dir(dir.join("scenes")).unwrap();
    ok(dir, &["make-scene", "--synthetic", "1", "--size", "12", "--bands", "450:650:6", "--out", "scenes/s1.npy"]);
    ok(dir, &["render-dataset", "--scenes", "scenes", "--preset", "sp", "--scene-size", "12", "--planes", "2", "--rays", "1", "--bands", "450:650:6", "--airy-diameter-px", "0.01", "--out", "ds"]);
    assert!(exr(&dir.join("ds/s1/acquisition.exr")).iter().all(|v| v.is_finite()));
}

/// Outputs never replace a named pipe (nor a device: the same check, `--json /dev/null` as root); an output file
/// named by a symbolic link is refused, an output folder named by one is written through (the link kept); an
/// input's wavelength list is an input.
#[test]
fn outputs_never_replace_pipes_or_links_and_folders_are_written_through() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    ok(dir, &["make-scene", "--synthetic", "2", "--size", "12", "--bands", "450:650:4", "--out", "t.npy"]);
    for (out, args) in [
        ("p.json", vec!["evaluate", "--truth", "t.npy", "--estimate", "t.npy", "--json", "p.json"]),
        ("p.npy", vec!["mapping", "--preset", "sp", "--height", "2", "--width", "2", "--npy", "p.npy"]),
        ("q.npy", vec!["make-scene", "--synthetic", "0", "--size", "4", "--out", "q.npy"]),
    ] {
        mkfifo(&dir.join(out));
        let (code, msg) = run(dir, &args);
        assert_eq!(code, Some(1), "{args:?}: {msg}");
        assert!(msg.contains(out) && msg.contains("named pipe") && !msg.contains("panicked"), "{args:?}: {msg}");
        assert!(is_fifo(&dir.join(out)), "{args:?}: the pipe was replaced");
    }
    // A file output named by a link is refused (written in its place it would replace the link; written through,
    // two outputs could land on one file), the target untouched; a link to nothing alike.
    std::os::unix::fs::symlink("target.json", dir.join("link.json")).unwrap();
    for target in [None, Some("old")] {
        if let Some(t) = target {
            std::fs::write(dir.join("target.json"), t).unwrap();
        }
        let (code, msg) = run(dir, &["evaluate", "--truth", "t.npy", "--estimate", "t.npy", "--json", "link.json"]);
        assert_eq!(code, Some(1), "{msg}");
        assert!(msg.contains("--json is a symbolic link (to target.json)"), "{msg}");
        assert!(std::fs::symlink_metadata(dir.join("link.json")).unwrap().file_type().is_symlink());
        assert_eq!(std::fs::read_to_string(dir.join("target.json")).ok().as_deref(), target);
    }
    // An input's wavelength list is an input: `--json t_wavelengths_nm.npy` replaced the truth's list.
    let list = std::fs::read(dir.join("t_wavelengths_nm.npy")).unwrap();
    let (code, msg) = run(dir, &["evaluate", "--truth", "t.npy", "--estimate", "t.npy", "--json", "t_wavelengths_nm.npy"]);
    assert_eq!(code, Some(1), "{msg}");
    assert!(msg.contains("(its wavelength list)"), "{msg}");
    assert_eq!(std::fs::read(dir.join("t_wavelengths_nm.npy")).unwrap(), list);
    // Output folders named by a link are written through, the link kept.
    std::fs::create_dir(dir.join("r1")).unwrap();
    std::os::unix::fs::symlink("r1", dir.join("rlink")).unwrap();
    ok(dir, &["render", "--preset", "sp", "--scene-size", "8", "--planes", "2", "--rays", "1", "--out", "rlink"]);
    assert!(std::fs::symlink_metadata(dir.join("rlink")).unwrap().file_type().is_symlink(), "the output folder's link was replaced");
    assert!(dir.join("r1/render.json").is_file(), "the render was not written at the link's target");
    // Rendered again through the link: the target is replaced as a previous render, the link kept.
    ok(dir, &["render", "--preset", "sp", "--scene-size", "8", "--planes", "2", "--rays", "1", "--seed", "9", "--out", "rlink"]);
    assert!(std::fs::symlink_metadata(dir.join("rlink")).unwrap().file_type().is_symlink());
    let rec: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("r1/render.json")).unwrap()).unwrap();
    assert_eq!(rec["seed"], 9, "{rec}");
}

/// A one-band scene is a flat spectrum where its band lies among the planes, and refused where it does not.
#[test]
fn a_one_band_scene_outside_the_planes_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    for (nm, refused) in [(5000.0, true), (540.0, false)] {
        let cube = diffcassi::scene::SpectralCube::new(8, 8, vec![nm], vec![0.5; 64], "test").unwrap();
        diffcassi::scene::save_npy(&cube, &dir.join("one.npy")).unwrap();
        let (code, msg) = run(dir, &["render", "--preset", "sp", "--scene", "one.npy", "--scene-size", "8", "--bands", "450:650:4", "--planes", "4", "--rays", "1", "--out", "r"]);
        if refused {
            assert_eq!(code, Some(1), "{msg}");
            assert!(msg.contains("the scene's band (5000 nm) lies outside the render's planes"), "{msg}");
            assert!(!dir.join("r").exists());
        } else {
            assert_eq!(code, Some(0), "{msg}");
        }
    }
}

/// A dataset rendered on the CPU is not resumed with the GPU kernels (another accumulation: other bytes); `cuda`
/// and `cpu-twin` are one configuration.
#[test]
fn a_dataset_is_never_a_mix_of_devices() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    std::fs::create_dir(dir.join("scenes")).unwrap();
    for i in ["1", "2"] {
        ok(dir, &["make-scene", "--synthetic", i, "--size", "8", "--bands", "450:650:4", "--out", &format!("scenes/s{i}.npy")]);
    }
    let ds = |device: &str| run(dir, &["render-dataset", "--scenes", "scenes", "--preset", "sp", "--scene-size", "8", "--planes", "2", "--rays", "1", "--bands", "450:650:4", "--device", device, "--out", "ds"]);
    let (code, msg) = ds("cpu");
    assert_eq!(code, Some(0), "{msg}");
    std::fs::remove_dir_all(dir.join("ds/s2")).unwrap();
    let (code, msg) = ds("cpu-twin");
    assert_ne!(code, Some(0), "a CPU dataset was resumed on the GPU kernels: {msg}");
    assert!(msg.contains("accumulation"), "{msg}");
    assert!(!dir.join("ds/s2").exists(), "{msg}");
}

/// `calibrate --noise-um` beyond the detector's scale is refused; `reconstruct --truth` of maximum 0 is refused
/// before the solve.
#[test]
fn calibration_noise_and_a_black_truth_are_refused() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let (code, msg) = run(dir, &["calibrate", "--from", "sp", "--observed", "msp", "--free", "prism_tilt_x", "--setup", "small", "--noise-um", "1e300", "--report", "c.json"]);
    assert_eq!(code, Some(1), "{msg}");
    assert!(msg.contains("--noise-um 1e300") && !dir.join("c.json").exists(), "{msg}");
    ok(dir, &["render", "--preset", "sp", "--scene-size", "8", "--planes", "28", "--rays", "1", "--out", "r"]);
    let zero = diffcassi::scene::SpectralCube::new(8, 8, diffcassi::render::settings::RenderSettings::default().bands_nm, vec![0.0; 8 * 8 * 28], "black").unwrap();
    diffcassi::scene::save_npy(&zero, &dir.join("z.npy")).unwrap();
    let (code, msg) = run(dir, &["reconstruct", "--from", "r", "--iterations", "2", "--truth", "z.npy", "--out", "x"]);
    assert_eq!(code, Some(1), "{msg}");
    assert!(msg.contains("--truth") && msg.contains("maximum is 0"), "{msg}");
    assert!(!dir.join("x").exists());
}

/// A FIFO planted as a resumed dataset's sidecar is reported, not waited on (the resume readers go through
/// `io::input`): `dataset-status` and `render-dataset` blocked forever on it.
#[test]
fn a_fifo_planted_in_a_dataset_is_not_waited_on() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    std::fs::create_dir(dir.join("scenes")).unwrap();
    ok(dir, &["make-scene", "--synthetic", "1", "--size", "8", "--bands", "450:650:4", "--out", "scenes/s1.npy"]);
    let ds = ["render-dataset", "--scenes", "scenes", "--preset", "sp", "--scene-size", "8", "--planes", "2", "--rays", "1", "--bands", "450:650:4", "--out", "ds"];
    ok(dir, &ds);
    for victim in ["ds/s1/render.json", "ds/s1/acquisition.exr"] {
        std::fs::remove_file(dir.join(victim)).unwrap();
        mkfifo(&dir.join(victim));
        let mut child = Command::new(env!("CARGO_BIN_EXE_diffcassi")).args(["dataset-status", "ds"]).current_dir(dir).stdout(std::process::Stdio::piped()).stderr(std::process::Stdio::piped()).spawn().unwrap();
        let t = std::time::Instant::now();
        let status = crate::common::wait_with_limit(&mut child, t, std::time::Duration::from_secs(60));
        assert!(status.is_some(), "{victim}: dataset-status blocked on a FIFO");
        let out = child.wait_with_output().unwrap();
        let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
        assert!(text.contains("named pipe") || text.contains("damaged"), "{victim}: {text}");
        // render-dataset renders the damaged scene again (the pipe replaced by the scene's folder swap).
        ok(dir, &ds);
        assert!(!is_fifo(&dir.join(victim)) && dir.join(victim).is_file(), "{victim}");
    }
}

/// `study` refuses a black scene before any render, naming it; `reconstruct` with a model operator records no
/// operator seed or rays (they are the exact operator's: the shift operator's record claimed them).
#[test]
fn a_black_study_scene_is_named_and_model_operators_record_no_rays() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    std::fs::create_dir(dir.join("scenes")).unwrap();
    let black = diffcassi::scene::SpectralCube::new(8, 8, vec![450.0, 550.0, 650.0], vec![0.0; 8 * 8 * 3], "black").unwrap();
    diffcassi::scene::save_npy(&black, &dir.join("scenes/night.npy")).unwrap();
    let (code, msg) = run(dir, &["study", "--scenes", "scenes", "--scene-size", "8", "--presets", "sp", "--operators", "shift", "--bands", "450:650:3", "--planes", "3", "--rays", "1", "--iterations", "1", "--out", "st"]);
    assert_eq!(code, Some(1), "{msg}");
    assert!(msg.contains("night.npy") && msg.contains("maximum"), "{msg}");
    assert!(!dir.join("st/renders").exists(), "{msg}");
    ok(dir, &["render", "--preset", "sp", "--scene-size", "8", "--planes", "28", "--rays", "1", "--out", "r"]);
    ok(dir, &["reconstruct", "--from", "r", "--operator", "shift", "--iterations", "1", "--out", "x"]);
    let j: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("x/reconstruct.json")).unwrap()).unwrap();
    assert!(j["operator_seed"].is_null() && j["operator_rays"].is_null() && j["oracle"] == false, "{j}");
}

/// A symbolic link planted inside a dataset's folder, in place of one of its own files, is replaced on resume,
/// never followed: a regression of the write-through rule once made `render-dataset` write its mask onto a
/// scene (an input) through `ds/mask.png -> ../scenes/b.npy`.
#[test]
fn a_link_planted_in_a_dataset_is_replaced_not_followed() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    std::fs::create_dir(dir.join("scenes")).unwrap();
    for i in ["1", "2"] {
        ok(dir, &["make-scene", "--synthetic", i, "--size", "8", "--bands", "450:650:4", "--out", &format!("scenes/s{i}.npy")]);
    }
    let ds = |shard: Option<&str>| {
        let mut a = vec!["render-dataset", "--scenes", "scenes", "--preset", "sp", "--scene-size", "8", "--planes", "2", "--rays", "1", "--bands", "450:650:4", "--out", "ds"];
        if let Some(s) = shard {
            a.extend(["--shard", s]);
        }
        ok(dir, &a);
    };
    ds(Some("0/2"));
    let scene = std::fs::read(dir.join("scenes/s2.npy")).unwrap();
    std::fs::remove_file(dir.join("ds/mask.png")).unwrap();
    std::os::unix::fs::symlink("../scenes/s2.npy", dir.join("ds/mask.png")).unwrap();
    ds(None);
    assert_eq!(std::fs::read(dir.join("scenes/s2.npy")).unwrap(), scene, "the scene was overwritten through the planted link");
    assert!(std::fs::symlink_metadata(dir.join("ds/mask.png")).unwrap().file_type().is_file(), "the link was not replaced");
}
