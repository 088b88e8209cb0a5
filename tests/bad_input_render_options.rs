//! Bad input, round 3 (issue 39), the render options: conflicting options are refused instead of one being
//! silently ignored (`--no-airy` with `--airy-diameter-px`, `--mask` with `--opening` or `--mask-seed`, in
//! `render` and `render-dataset`), and `--device` (issue 40: the library's render settings carry the device;
//! only the CPU exists in this build). Each case runs the real binary: exit code, a message naming the
//! options, nothing written. Tiny sizes throughout.
use std::path::Path;
use std::process::{Command, Output};

fn run(cwd: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_diffcassi")).args(args).current_dir(cwd).output().unwrap()
}

const TINY: [&str; 11] = ["--preset", "sp", "--scene-size", "8", "--planes", "2", "--bands", "450:650:2", "--rays", "1", "--no-mapping"];

/// `render` with the tiny settings, `extra` options and `--out out`.
fn render(cwd: &Path, extra: &[&str]) -> Output {
    let mut args = vec!["render"];
    args.extend_from_slice(&TINY);
    args.extend_from_slice(extra);
    args.extend_from_slice(&["--out", "out"]);
    run(cwd, &args)
}

fn refused(o: &Output, code: i32, says: &[&str]) {
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(code), "{err}");
    for s in says {
        assert!(err.contains(s), "expected `{s}` in: {err}");
    }
    assert!(!err.contains("panicked"), "{err}");
}

#[test]
fn conflicting_render_options_are_refused() {
    let d = tempfile::tempdir().unwrap();
    // A valid mask file: the mask.png of a first render.
    let first = render(d.path(), &[]);
    assert!(first.status.success(), "{}", String::from_utf8_lossy(&first.stderr));
    std::fs::rename(d.path().join("out/mask.png"), d.path().join("mask.png")).unwrap();
    std::fs::remove_dir_all(d.path().join("out")).unwrap();
    let cases: [(&[&str], &[&str]); 4] = [
        (&["--no-airy", "--airy-diameter-px", "3"], &["--no-airy", "--airy-diameter-px", "cannot be used with"]),
        (&["--airy-diameter-px", "3", "--no-airy"], &["--no-airy", "--airy-diameter-px", "cannot be used with"]),
        (&["--mask", "mask.png", "--opening", "0.3"], &["--mask", "--opening", "cannot be used with"]),
        (&["--mask", "mask.png", "--mask-seed", "4"], &["--mask", "--mask-seed", "cannot be used with"]),
    ];
    for (extra, says) in cases {
        let o = render(d.path(), extra);
        refused(&o, 2, says);
        assert!(!d.path().join("out").exists(), "{extra:?} wrote its output");
    }
    // Each option alone is accepted (a default value is not "given").
    for extra in [&["--no-airy"][..], &["--airy-diameter-px", "3"][..], &["--mask", "mask.png"][..], &["--opening", "0.3", "--mask-seed", "4"][..]] {
        let o = render(d.path(), extra);
        assert!(o.status.success(), "{extra:?}: {}", String::from_utf8_lossy(&o.stderr));
        std::fs::remove_dir_all(d.path().join("out")).unwrap();
    }
    // render-dataset shares the options.
    let o = run(d.path(), &["render-dataset", "--scenes", ".", "--preset", "sp", "--no-airy", "--airy-diameter-px", "3", "--out", "ds"]);
    refused(&o, 2, &["--no-airy", "--airy-diameter-px"]);
    let o = run(d.path(), &["render-dataset", "--scenes", ".", "--preset", "sp", "--mask", "mask.png", "--opening", "0.2", "--out", "ds"]);
    refused(&o, 2, &["--mask", "--opening"]);
    assert!(!d.path().join("ds").exists());
}

#[test]
fn device_cpu_renders_and_cuda_without_a_gpu_is_refused() {
    let d = tempfile::tempdir().unwrap();
    if diffcassi::gpu::probe(0).is_err() {
        // What is missing here: the driver (or a device), named; nothing written.
        let o = render(d.path(), &["--device", "cuda"]);
        refused(&o, 1, &["--device cuda: ", "use --device cpu"]);
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(e.contains("no NVIDIA driver") || e.contains("no CUDA device") || e.contains("NVIDIA driver is installed but"), "{e}");
        assert!(!d.path().join("out").exists());
    }
    // A value no device reads is a usage error, as clap's other bad values (exit 2), naming the option.
    let o = render(d.path(), &["--device", "tpu"]);
    refused(&o, 2, &["'tpu'", "--device", "use cpu, cuda or cuda:N"]);
    let o = render(d.path(), &["--device", "cpu"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// `--device cpu-twin`: the GPU kernels on the CPU render, and render.json says so (device, precision, the
/// fixed-point accumulation); the acquisition is the CPU's to its f32 rounding.
#[test]
fn device_cpu_twin_renders_the_gpu_kernels_and_records_them() {
    let d = tempfile::tempdir().unwrap();
    let o = render(d.path(), &["--device", "cpu-twin"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(d.path().join("out/render.json")).unwrap()).unwrap();
    assert_eq!(json["device"]["device"], "cpu-twin", "{}", json["device"]);
    assert_eq!(json["device"]["precision"], "f64");
    assert!(json["device"]["accumulation"].as_str().unwrap().contains("fixed point"));
    // The code that traced: the GPU kernels' host twin (render.json named the CPU's SIMD kernel, unused).
    assert_eq!(json["kernel"], "cuda-kernels-host-twin");
    let twin_total = json["acquisition_total"].as_f64().unwrap();
    let o = render(d.path(), &["--device", "cpu", "--force"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(d.path().join("out/render.json")).unwrap()).unwrap();
    assert_eq!(json["device"]["device"], "cpu");
    assert!(json["kernel"].as_str().unwrap().starts_with("simd-") || json["kernel"] == "scalar", "{}", json["kernel"]);
    let cpu_total = json["acquisition_total"].as_f64().unwrap();
    assert!((twin_total - cpu_total).abs() <= 1e-6 * cpu_total, "{twin_total} vs {cpu_total}");
}
