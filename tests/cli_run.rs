//! Running the built `diffcassi` binary from the integration tests (apart from `tests/common`, which the
//! examples include too and where `CARGO_BIN_EXE_diffcassi` is not defined).

/// `diffcassi ARGS` in `dir`: (exit code, stdout + stderr).
pub fn run_cli(dir: &std::path::Path, args: &[&str]) -> (Option<i32>, String) {
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_diffcassi")).args(args).current_dir(dir).output().expect("diffcassi runs");
    (o.status.code(), format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr)))
}

/// [`run_cli`] that must exit 0; its output.
pub fn ok_cli(dir: &std::path::Path, args: &[&str]) -> String {
    let (code, out) = run_cli(dir, args);
    assert_eq!(code, Some(0), "{args:?}: {out}");
    out
}

/// [`run_cli`] that must be refused: exit 1, no panic, and every needle in the message.
pub fn refused_cli(dir: &std::path::Path, args: &[&str], needles: &[&str]) {
    let (code, out) = run_cli(dir, args);
    assert_eq!(code, Some(1), "{args:?}: {out}");
    assert!(!out.contains("panicked"), "{args:?}: {out}");
    for n in needles {
        assert!(out.contains(n), "{args:?}: `{n}` not in: {out}");
    }
}

/// The peak resident memory (bytes) of `diffcassi ARGS` run in `dir`, and its exit code (`None`: killed by a
/// signal). A small `python3` parent runs it and reads `getrusage(RUSAGE_CHILDREN)`: Linux records, at exec,
/// the high-water mark of the address space a process was forked from, so a command spawned straight from
/// this test process (hundreds of MB after the in-process tests) would report at least this process's peak.
/// The parent's own ~10 MB bound it from below the same way, under any command's own peak.
pub fn peak_rss_cli(dir: &std::path::Path, args: &[&str]) -> (f64, Option<i32>) {
    const MEASURE: &str = "import resource, subprocess, sys\nr = subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)\nprint(r.returncode, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)\n";
    let o = std::process::Command::new("python3").arg("-c").arg(MEASURE).arg(env!("CARGO_BIN_EXE_diffcassi")).args(args).current_dir(dir).output().expect("python3 runs");
    let text = String::from_utf8_lossy(&o.stdout);
    let mut f = text.split_whitespace();
    let code: i32 = f.next().and_then(|v| v.parse().ok()).unwrap_or_else(|| panic!("peak_rss_cli {args:?}: {text} {}", String::from_utf8_lossy(&o.stderr)));
    let kib: f64 = f.next().and_then(|v| v.parse().ok()).unwrap_or_else(|| panic!("peak_rss_cli {args:?}: {text}"));
    (kib * 1024.0, (code >= 0).then_some(code))
}
