//! Bad input, round 3 (issue 39): the denoiser weights of `reconstruct` / `study --solver pnp-*` and their
//! outputs. `/dev/zero`, a FIFO, a folder or a file over the size limit as `--denoiser` is refused at once,
//! naming the file (it was read until memory ran out, or blocked forever); a `--denoiser` (or `--truth`)
//! inside `--out` is refused before any work (outputs are never inputs: the folder swap would destroy it),
//! and the weights are untouched. Each case runs the real binary: exit 1, the message, nothing written, no
//! panic, done within 60 s.
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// Run `args` in `cwd`, killed after 60 s (a hang is a failure, not a stuck test); (exit code, stderr, seconds).
fn run_in(cwd: &Path, args: &[String]) -> (Option<i32>, String, f64) {
    let t = Instant::now();
    let child = Command::new(env!("CARGO_BIN_EXE_diffcassi")).args(args).current_dir(cwd).stdout(Stdio::null()).stderr(Stdio::piped()).spawn().unwrap();
    let pid = child.id() as libc::pid_t;
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || tx.send(child.wait_with_output()));
    let out = rx.recv_timeout(Duration::from_secs(60)).unwrap_or_else(|_| {
        // SAFETY: signalling our own child, still unreaped (its waiter thread has not returned).
        unsafe { libc::kill(pid, libc::SIGKILL) };
        rx.recv().unwrap()
    });
    let out = out.unwrap();
    (out.status.code(), String::from_utf8_lossy(&out.stderr).into_owned(), t.elapsed().as_secs_f64())
}

fn strings(args: &[&str]) -> Vec<String> {
    args.iter().map(|s| s.to_string()).collect()
}

/// A tiny render folder (16×16 scene, `bands` bands and planes in 450–650 nm, 2 rays) under `dir`.
fn tiny_render(dir: &Path, bands: usize) -> PathBuf {
    let out = dir.join("render");
    let (b, p) = (format!("450:650:{bands}"), bands.to_string());
    let args = strings(&["render", "--preset", "sp", "--scene-size", "16", "--planes", &p, "--bands", &b, "--rays", "2", "--no-mapping", "--out", &out.display().to_string()]);
    let (code, err, _) = run_in(dir, &args);
    assert_eq!(code, Some(0), "{err}");
    out
}

/// The embedded checkpoint's file (valid weights for `--denoiser`).
fn weights() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src/recon/prior/weights/spectral-unet-v2-28.safetensors")
}

fn mkfifo(path: &Path) {
    let c = std::ffi::CString::new(path.display().to_string()).unwrap();
    // SAFETY: a valid NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0, "mkfifo {}", path.display());
}

/// The entries of `dir` (to check nothing was written).
fn entries(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect()
}

/// `/dev/zero`, a FIFO, a folder and a 1 GiB + 1 byte (sparse) file as `--denoiser` of `reconstruct` and
/// `study`: exit 1 within seconds, naming the file and why, nothing written.
#[test]
fn denoiser_weights_must_be_a_bounded_regular_file() {
    let fx = tempfile::tempdir().unwrap();
    let render = tiny_render(fx.path(), 4);
    let fifo = fx.path().join("weights.fifo");
    mkfifo(&fifo);
    let folder = fx.path().join("weights-folder");
    std::fs::create_dir(&folder).unwrap();
    let big = fx.path().join("big.safetensors");
    std::fs::File::create(&big).unwrap().set_len((1 << 30) + 1).unwrap();
    let cases: [(PathBuf, &[&str]); 4] = [
        (PathBuf::from("/dev/zero"), &["/dev/zero", "not a regular file"]),
        (fifo.clone(), &["weights.fifo", "not a regular file"]),
        (folder.clone(), &["weights-folder", "is a directory"]),
        (big.clone(), &["big.safetensors", "1073741825 bytes", "1 GiB"]),
    ];
    let mut failures = Vec::new();
    for (w, says) in &cases {
        let w = w.display().to_string();
        for (cmd, solver) in [("reconstruct", "pnp-gap"), ("reconstruct", "pnp-admm"), ("study", "pnp-gap")] {
            let dir = tempfile::tempdir().unwrap();
            let out = dir.path().join("result").display().to_string();
            let args = if cmd == "reconstruct" {
                strings(&["reconstruct", "--from", &render.display().to_string(), "--solver", solver, "--denoiser", &w, "--out", &out])
            } else {
                strings(&["study", "--synthetic", "1", "--scene-size", "8", "--presets", "sp", "--operators", "shift", "--solvers", solver, "--denoiser", &w, "--out", &out])
            };
            let (code, err, secs) = run_in(dir.path(), &args);
            let missing: Vec<&&str> = says.iter().filter(|s| !err.contains(**s)).collect();
            let written = entries(dir.path());
            if code != Some(1) || !missing.is_empty() || !written.is_empty() || err.contains("panicked") || secs > 20.0 {
                failures.push(format!("{cmd} --solver {solver} --denoiser {w}: exit {code:?}, missing {missing:?}, wrote {written:?}, {secs:.1} s, stderr: {err}"));
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// A `--denoiser` inside `--out` (`reconstruct`: also `--truth`; `study`) is refused before any work, with
/// or without `--force`, and the weights stay as they were.
#[test]
fn inputs_inside_out_are_refused() {
    let fx = tempfile::tempdir().unwrap();
    let render = tiny_render(fx.path(), 4);
    let mut failures = Vec::new();
    for force in [false, true] {
        for cmd in ["reconstruct", "reconstruct-truth", "study"] {
            let dir = tempfile::tempdir().unwrap();
            let out = dir.path().join("result");
            std::fs::create_dir(&out).unwrap();
            let inner = out.join("weights.safetensors");
            std::fs::copy(weights(), &inner).unwrap();
            let before = std::fs::read(&inner).unwrap();
            let (o, w) = (out.display().to_string(), inner.display().to_string());
            let mut args = match cmd {
                "reconstruct" => strings(&["reconstruct", "--from", &render.display().to_string(), "--solver", "pnp-gap", "--denoiser", &w, "--out", &o]),
                "reconstruct-truth" => strings(&["reconstruct", "--from", &render.display().to_string(), "--iterations", "2", "--truth", &w, "--out", &o]),
                _ => strings(&["study", "--synthetic", "1", "--scene-size", "8", "--presets", "sp", "--operators", "shift", "--solvers", "pnp-gap", "--denoiser", &w, "--out", &o]),
            };
            if force {
                args.push("--force".into());
            }
            let (code, err, secs) = run_in(dir.path(), &args);
            let option = if cmd == "reconstruct-truth" { "--truth" } else { "--denoiser" };
            let says = ["--out contains the input", option, "weights.safetensors"];
            let missing: Vec<&&str> = says.iter().filter(|s| !err.contains(**s)).collect();
            let after = std::fs::read(&inner).ok();
            let mut inside = entries(&out);
            inside.sort();
            if code != Some(1) || !missing.is_empty() || after.as_ref() != Some(&before) || inside != ["weights.safetensors"] || err.contains("panicked") {
                failures.push(format!("{args:?}: exit {code:?}, missing {missing:?}, --out holds {inside:?}, weights intact: {}, {secs:.1} s, stderr: {err}", after.as_ref() == Some(&before)));
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// The same weights outside `--out` are accepted (on a 28-band render, the network's): the checks refuse only
/// what they should.
#[test]
fn valid_weights_outside_out_still_reconstruct() {
    let fx = tempfile::tempdir().unwrap();
    let render = tiny_render(fx.path(), 28);
    let w = fx.path().join("w.safetensors");
    std::fs::copy(weights(), &w).unwrap();
    let out = fx.path().join("rec");
    let args = strings(&["reconstruct", "--from", &render.display().to_string(), "--solver", "pnp-gap", "--tv-warmup", "2", "--iterations", "3", "--denoiser", &w.display().to_string(), "--out", &out.display().to_string()]);
    let (code, err, _) = run_in(fx.path(), &args);
    assert_eq!(code, Some(0), "{err}");
    assert!(out.join("cube.npy").is_file() && out.join("reconstruct.json").is_file());
}
