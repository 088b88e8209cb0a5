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
