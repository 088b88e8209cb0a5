//! The CUDA launcher (src/gpu/cuda.rs) end to end without a GPU: the CLI's `--device cuda` paths run against
//! the CUDA driver emulator of tests/cuda_emu (a `libcuda.so.1` that runs device.cu's entry points on the host,
//! refuses what a driver refuses, and checks the PTX's kernels and parameter sizes against the host build's).
//! Each command runs in a child process whose library path puts the emulator first, so `dlopen("libcuda.so.1")`
//! — the probe's and cudarc's — finds it; the launcher, started once per process, sees a fresh driver each time.
//!
//! What it shows: cudarc's calls, the uploads, grids, parameters, copies back, the PTX fallbacks (a file named by
//! `DIFFCASSI_PTX`, then NVRTC on the embedded sources) and the errors work, and a render, a dataset and a mapping
//! on "the device" have the host twin's bits (the same kernel source: device branch there, host branch here).
//! What it cannot show: the GPU's own numbers (its libdevice `tan`, its code generation) and its speed —
//! scripts/gpu_check.sh on a GPU machine (docs/gpu.md).
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

/// The emulator's folder (built once per test process by tests/cuda_emu/build.sh).
fn emulator() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("cuda-emu");
        let out = Command::new("bash").arg(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/cuda_emu/build.sh")).arg(&dir).output().expect("bash runs");
        assert!(out.status.success(), "building the CUDA emulator failed:\n{}", String::from_utf8_lossy(&out.stderr));
        dir
    })
}

/// The NVRTC library `scripts/setup.sh` installs into `.venv` (with torch), for the NVRTC fallback.
fn venv_nvrtc_dir() -> PathBuf {
    let lib = Path::new(env!("CARGO_MANIFEST_DIR")).join(".venv/lib");
    for py in std::fs::read_dir(&lib).unwrap_or_else(|e| panic!("{}: {e} (run scripts/setup.sh)", lib.display())).flatten() {
        let d = py.path().join("site-packages/nvidia/cu13/lib");
        if d.join("libnvrtc.so.13").exists() {
            return d;
        }
    }
    panic!("no libnvrtc.so.13 under {} (scripts/setup.sh installs it with torch)", lib.display());
}

/// `diffcassi ARGS` in `dir` with the emulated driver (and `env`), the inherited CUDA_EMU_* variables cleared.
fn run_with(dir: &Path, args: &[&str], env: &[(&str, &str)], extra_lib: Option<&Path>) -> Output {
    let mut path = emulator().display().to_string();
    if let Some(p) = extra_lib {
        path = format!("{path}:{}", p.display());
    }
    let mut c = Command::new(env!("CARGO_BIN_EXE_diffcassi"));
    c.current_dir(dir).args(args).env("LD_LIBRARY_PATH", path).env_remove("DIFFCASSI_PTX").env_remove("DIFFCASSI_CUDA_DRIVER");
    for v in ["CUDA_EMU_PTX_ISA", "CUDA_EMU_REFUSE_PTX", "CUDA_EMU_DRIVER_VERSION", "CUDA_EMU_DEVICES", "CUDA_EMU_UNAVAILABLE", "CUDA_EMU_INIT_ERROR", "CUDA_EMU_FREE_BYTES"] {
        c.env_remove(v);
    }
    c.envs(env.iter().copied());
    c.output().expect("diffcassi runs")
}

fn run(dir: &Path, args: &[&str]) -> Output {
    run_with(dir, args, &[], None)
}

fn ok(o: &Output, what: &str) -> String {
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(o.status.success(), "{what} failed ({:?}):\n{err}", o.status.code());
    err
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))).unwrap()
}

/// Two render folders hold the same outputs: every file byte for byte, render.json apart from the device record,
/// rates and timings (which a device changes by design).
fn assert_same_render(a: &Path, b: &Path, what: &str) {
    let names = |d: &Path| {
        let mut v: Vec<String> = std::fs::read_dir(d).unwrap().flatten().map(|e| e.file_name().to_string_lossy().into_owned()).collect();
        v.sort();
        v
    };
    assert_eq!(names(a), names(b), "{what}: the folders hold other files");
    for n in names(a) {
        if n == "render.json" {
            // Timings (`seconds_*`, `*_seconds`, `timings`, the rate), the device record and the kernel that
            // traced (`cuda-kernels`, `cuda-kernels-host-twin`) differ by design.
            let timing = |k: &str| k == "device" || k == "kernel" || k == "timings" || k == "rays_per_second" || k.starts_with("seconds") || k.ends_with("seconds");
            let (ja, jb) = (json(&a.join(&n)), json(&b.join(&n)));
            let (oa, ob) = (ja.as_object().unwrap(), jb.as_object().unwrap());
            let keys: std::collections::BTreeSet<&String> = oa.keys().chain(ob.keys()).collect();
            let differ: Vec<&&String> = keys.iter().filter(|k| !timing(k) && oa.get(k.as_str()) != ob.get(k.as_str())).collect();
            assert!(differ.is_empty(), "{what}: render.json differs beyond the device and timings, in {differ:?}");
        } else if a.join(&n).is_file() {
            assert!(std::fs::read(a.join(&n)).unwrap() == std::fs::read(b.join(&n)).unwrap(), "{what}: {n} differs");
        }
    }
}

fn spec_file(dir: &Path, name: &str, spec: &diffcassi::spec::SystemSpec) -> String {
    let p = dir.join(name);
    diffcassi::spec::save_spec_file(spec, &p).unwrap();
    p.display().to_string()
}

/// `render --device cuda` on the emulated device equals `--device cpu-twin` bit for bit — every output file and
/// the ray counts — for the paper's prism (f64 and f32), a grating, both dual-disperser presets (the coded mask on
/// a surface), SP with real ray aiming (the aimed kernels) and a singlet at infinity; render.json names the device
/// (the emulator, the driver, the embedded PTX). A render whose aims fail stops with the twin's error, nothing written.
#[test]
fn the_launcher_renders_the_twins_bits_on_an_emulated_device() {
    use diffcassi::spec::RayAiming;
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let mut sp_real = diffcassi::presets::spec("sp").unwrap();
    sp_real.ray_aiming = RayAiming::Real;
    let sp_real = spec_file(dir, "sp_real.toml", &sp_real);
    let singlet = spec_file(dir, "singlet.toml", &crate::common::singlet_at_infinity(false));
    let cases: Vec<(&str, Vec<&str>)> = vec![
        ("sp f64", vec!["--preset", "sp"]),
        ("sp f32", vec!["--preset", "sp", "--precision", "f32"]),
        ("gsp", vec!["--preset", "gsp"]),
        ("ddsp", vec!["--preset", "ddsp"]),
        ("mddsp", vec!["--preset", "mddsp"]),
        ("sp real aiming", vec!["--system", &sp_real]),
        ("singlet at infinity", vec!["--system", &singlet, "--scene-fov-deg", "0.5"]),
    ];
    for (i, (name, args)) in cases.iter().enumerate() {
        let common = ["render", "--scene-size", "20", "--planes", "3", "--rays", "2", "--seed", "7"];
        let (gpu, twin) = (format!("gpu{i}"), format!("twin{i}"));
        let mut a: Vec<&str> = common.to_vec();
        a.extend(args.iter().copied());
        let mut g = a.clone();
        g.extend(["--device", "cuda", "--out", &gpu]);
        ok(&run(dir, &g), name);
        let mut t = a.clone();
        t.extend(["--device", "cpu-twin", "--out", &twin]);
        ok(&run(dir, &t), name);
        assert_same_render(&dir.join(&gpu), &dir.join(&twin), name);
        let rec = json(&dir.join(&gpu).join("render.json"));
        let dev = &rec["device"];
        assert_eq!(dev["device"], "cuda", "{name}: {dev}");
        assert!(dev["gpu"].as_str().unwrap().contains("emulator"), "{name}: {dev}");
        assert_eq!((dev["driver"].as_str(), dev["ptx"].as_str()), (Some("13.2"), Some("embedded PTX")), "{name}: {dev}");
        let rays = rec["rays_traced"].as_u64().unwrap();
        assert!(rays > 0, "{name}: no ray traced");
    }
    // Aims that fail: the singlet's scene 170° wide with real aiming (rays that cannot reach the stop).
    let mut s = crate::common::singlet_at_infinity(false);
    s.ray_aiming = RayAiming::Real;
    let failing = spec_file(dir, "singlet_real.toml", &s);
    let args = |device: &'static str, out: &'static str| vec!["render", "--system", failing.as_str(), "--scene-fov-deg", "170", "--scene-size", "8", "--planes", "1", "--rays", "1", "--device", device, "--out", out];
    let (g, t) = (run(dir, &args("cuda", "fail_gpu")), run(dir, &args("cpu-twin", "fail_twin")));
    let (ge, te) = (String::from_utf8_lossy(&g.stderr), String::from_utf8_lossy(&t.stderr));
    assert_eq!((g.status.code(), t.status.code()), (Some(1), Some(1)), "cuda: {ge}\ntwin: {te}");
    assert!(ge.contains("ray aiming failed") && ge == te, "cuda: {ge}\ntwin: {te}");
    assert!(!dir.join("fail_gpu").exists(), "a failed render left its folder");
}

/// `render-dataset --device cuda` (two scenes, one launcher for both) and `mapping --device cuda` (the trace
/// kernels, f64 and f32) equal their `cpu-twin` runs bit for bit; `bench-render --device cuda` runs and names the
/// device.
#[test]
fn the_launcher_runs_datasets_mappings_and_the_bench_on_an_emulated_device() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    std::fs::create_dir(dir.join("scenes")).unwrap();
    for seed in ["1", "2"] {
        let out = format!("scenes/s{seed}.npy");
        ok(&run(dir, &["make-scene", "--synthetic", seed, "--size", "16", "--bands", "450:650:8", "--out", &out]), "make-scene");
        std::fs::remove_file(dir.join(format!("scenes/s{seed}_rgb.png"))).ok();
    }
    let ds = |device: &str, out: &str| -> Output { run(dir, &["render-dataset", "--preset", "sp", "--scenes", "scenes", "--scene-size", "16", "--planes", "3", "--rays", "2", "--device", device, "--out", out]) };
    ok(&ds("cuda", "ds_gpu"), "render-dataset cuda");
    ok(&ds("cpu-twin", "ds_twin"), "render-dataset cpu-twin");
    for s in ["s1", "s2"] {
        assert_same_render(&dir.join("ds_gpu").join(s), &dir.join("ds_twin").join(s), &format!("dataset scene {s}"));
    }
    for precision in ["f64", "f32"] {
        let m = |device: &str, out: &str| -> Output { run(dir, &["mapping", "--preset", "msp", "--height", "12", "--width", "10", "--precision", precision, "--device", device, "--npy", out]) };
        ok(&m("cuda", "map_gpu.npy"), "mapping cuda");
        ok(&m("cpu-twin", "map_twin.npy"), "mapping cpu-twin");
        assert!(std::fs::read(dir.join("map_gpu.npy")).unwrap() == std::fs::read(dir.join("map_twin.npy")).unwrap(), "mapping {precision}: the device's cube differs from the twin's");
    }
    let o = run(dir, &["bench-render", "--preset", "sp", "--scene-size", "16", "--planes", "2", "--rays", "2", "--scenes", "1", "--device", "cuda"]);
    ok(&o, "bench-render cuda");
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("emulator"), "bench-render does not name the device:\n{text}");
}

/// The launcher's PTX fallbacks and its errors, against a driver that refuses what a real one refuses. The GPU
/// machine's driver (580.159: CUDA 13.0, PTX ISA 9.0) takes the embedded PTX (NVRTC 13.0's, ISA 9.0; NVRTC 13.2's
/// ISA 9.2 was refused there: round 15). An older driver (CUDA 12.9, ISA 8.8) refuses it — with nothing else to try, one message naming each
/// attempt, exit 1, nothing written; with `DIFFCASSI_PTX` naming a PTX it takes, that file (render.json says so),
/// the twin's bits; with NVRTC on the library path, PTX compiled from the embedded sources. No device, a driver
/// that fails to start, and a device without the memory a render needs: one message each, exit 1, nothing written.
#[test]
fn the_launcher_falls_back_and_fails_clearly_on_an_emulated_device() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let render = |out: &'static str| vec!["render", "--preset", "sp", "--scene-size", "12", "--planes", "2", "--rays", "1", "--device", "cuda", "--out", out];
    ok(&run(dir, &["render", "--preset", "sp", "--scene-size", "12", "--planes", "2", "--rays", "1", "--device", "cpu-twin", "--out", "twin"]), "twin");
    // The GPU machine's driver: the embedded PTX, the twin's bits.
    let gpu_machine = [("CUDA_EMU_PTX_ISA", "9.0"), ("CUDA_EMU_DRIVER_VERSION", "13000")];
    ok(&run_with(dir, &render("cuda130"), &gpu_machine, None), "render on a CUDA 13.0 driver");
    let dev = json(&dir.join("cuda130/render.json"))["device"].clone();
    assert_eq!((dev["driver"].as_str(), dev["ptx"].as_str()), (Some("13.0"), Some("embedded PTX")), "{dev}");
    assert_same_render(&dir.join("cuda130"), &dir.join("twin"), "the embedded PTX on a CUDA 13.0 driver");
    let old_driver = [("CUDA_EMU_PTX_ISA", "8.8"), ("CUDA_EMU_DRIVER_VERSION", "12090")];
    let refused = |o: &Output, out: &str, says: &[&str]| {
        let e = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{e}");
        for s in says {
            assert!(e.contains(s), "missing {s:?} in: {e}");
        }
        assert!(!e.contains("panicked"), "{e}");
        assert!(!dir.join(out).exists(), "{out}: a refused render wrote its folder");
    };
    // Nothing to fall back on.
    let o = run_with(dir, &render("old"), &old_driver, None);
    refused(&o, "old", &["--device cuda", "driver 12.9", "the embedded PTX", "CUDA_ERROR_UNSUPPORTED_PTX_VERSION", "NVRTC: no NVRTC library", "DIFFCASSI_PTX"]);
    // A PTX file the driver takes (the embedded kernels, written as ISA 8.8 here: the emulator reads the header).
    let ptx = diffcassi::gpu::ptx::TRACE_PTX.replace("\n.version 9.0\n", "\n.version 8.8\n");
    assert_ne!(ptx, diffcassi::gpu::ptx::TRACE_PTX, "the embedded PTX is no longer ISA 9.0: update this test");
    std::fs::write(dir.join("k88.ptx"), &ptx).unwrap();
    let file = dir.join("k88.ptx").display().to_string();
    let mut env = old_driver.to_vec();
    env.push(("DIFFCASSI_PTX", &file));
    ok(&run_with(dir, &render("from_file"), &env, None), "render from DIFFCASSI_PTX");
    assert_eq!(json(&dir.join("from_file/render.json"))["device"]["ptx"].as_str().unwrap(), format!("PTX file {file}"));
    assert_same_render(&dir.join("from_file"), &dir.join("twin"), "PTX from a file");
    // A PTX file the driver refuses too, and a file that is not there: each attempt named.
    let o = run_with(dir, &render("bad_file"), &[old_driver[0], old_driver[1], ("DIFFCASSI_PTX", "/nonexistent/k.ptx")], None);
    refused(&o, "bad_file", &["DIFFCASSI_PTX=/nonexistent/k.ptx: cannot read it"]);
    // NVRTC on the embedded sources, when the embedded PTX is refused (its header marks it).
    let refuse_embedded = [("CUDA_EMU_REFUSE_PTX", "generated by scripts/gpu/build_ptx.py")];
    ok(&run_with(dir, &render("nvrtc"), &refuse_embedded, Some(&venv_nvrtc_dir())), "render with NVRTC's PTX");
    assert_eq!(json(&dir.join("nvrtc/render.json"))["device"]["ptx"], "PTX compiled here by NVRTC");
    assert_same_render(&dir.join("nvrtc"), &dir.join("twin"), "NVRTC's PTX");
    // No device; a driver whose cuInit fails; too little device memory.
    refused(&run_with(dir, &render("none"), &[("CUDA_EMU_DEVICES", "0")], None), "none", &["--device cuda", "reports no CUDA device"]);
    refused(&run_with(dir, &render("init"), &[("CUDA_EMU_INIT_ERROR", "999")], None), "init", &["--device cuda", "cuInit failed with CUDA error 999"]);
    refused(&run_with(dir, &render("small"), &[("CUDA_EMU_FREE_BYTES", "4096")], None), "small", &["GB on the device", "are free"]);
}

/// `--device cuda:N` on a driver with two devices, the first held by another process (its context refused:
/// CUDA_ERROR_DEVICE_UNAVAILABLE): `cuda:1` renders (and maps) the twin's bits on the second device, whose
/// context, memory and module are its own (the emulator refuses another device's handles), and render.json
/// names it; `cuda` (device 0) fails naming the driver's error; `cuda:2` is refused naming the devices there are;
/// a malformed ordinal is refused before the driver is asked. Nothing is written by a refused command.
#[test]
fn the_launcher_renders_on_the_device_an_ordinal_names() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let two = [("CUDA_EMU_DEVICES", "2"), ("CUDA_EMU_UNAVAILABLE", "0")];
    let render = |device: &str, out: &str| -> Output { run_with(dir, &["render", "--preset", "sp", "--scene-size", "12", "--planes", "2", "--rays", "2", "--seed", "3", "--device", device, "--out", out], &two, None) };
    ok(&render("cuda:1", "gpu1"), "render cuda:1");
    ok(&render("cpu-twin", "twin"), "render cpu-twin");
    assert_same_render(&dir.join("gpu1"), &dir.join("twin"), "cuda:1");
    let dev = json(&dir.join("gpu1/render.json"))["device"].clone();
    assert_eq!(dev["device"], "cuda:1", "{dev}");
    assert!(dev["gpu"].as_str().unwrap().contains("emulator, device 1"), "{dev}");
    let o = run_with(dir, &["render", "--preset", "sp", "--scene-size", "12", "--planes", "2", "--rays", "2", "--seed", "3", "--device", "cuda:0", "--out", "gpu0"], &[("CUDA_EMU_DEVICES", "2")], None);
    ok(&o, "render cuda:0");
    assert_eq!(json(&dir.join("gpu0/render.json"))["device"]["device"], "cuda", "cuda:0 is recorded as cuda");
    let m = |device: &str, out: &str| -> Output { run_with(dir, &["mapping", "--preset", "sp", "--height", "6", "--width", "5", "--device", device, "--npy", out], &two, None) };
    ok(&m("cuda:1", "map1.npy"), "mapping cuda:1");
    ok(&m("cpu-twin", "map_twin.npy"), "mapping cpu-twin");
    assert!(std::fs::read(dir.join("map1.npy")).unwrap() == std::fs::read(dir.join("map_twin.npy")).unwrap(), "mapping on cuda:1 differs from the twin");
    for (device, says) in [("cuda", "CUDA_ERROR_DEVICE_UNAVAILABLE"), ("cuda:2", "reports 2 CUDA device(s) (cuda:0 … cuda:1), not cuda:2"), ("cuda:x", "after `cuda:` give a device ordinal"), ("cuda:64", "at most 64 CUDA devices")] {
        let o = render(device, "refused");
        let e = String::from_utf8_lossy(&o.stderr);
        // A value no device reads is a usage error (exit 2, clap names the option and the value); a device the
        // machine lacks is exit 1.
        let usage = device == "cuda:x" || device == "cuda:64";
        assert_eq!(o.status.code(), Some(if usage { 2 } else { 1 }), "{device}: {e}");
        assert!(e.contains(&format!("--device {device}")) || e.contains(&format!("invalid value '{device}' for '--device")), "{device}: {e}");
        assert!(e.contains(says) && !e.contains("panicked"), "{device}: {e}");
        assert!(!dir.join("refused").exists(), "{device}: a refused render wrote its folder");
    }
}
