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
