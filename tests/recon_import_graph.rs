//! src/recon's modules import each other in no circle (issue 40): `scripts/check_import_cycles.py` builds
//! the import graph of its files (`use` statements and inline `crate::`/`super::` paths, re-exports followed
//! to the defining module) and looks for strongly connected components. Also checked: the script finds a
//! circle where there is one (a two-file tree written here), so the first test can fail.
use std::path::Path;
use std::process::Command;

fn check(args: &[&str]) -> (i32, String) {
    let root = env!("CARGO_MANIFEST_DIR");
    let out = Command::new("python3")
        .arg(Path::new(root).join("scripts/check_import_cycles.py"))
        .args(args)
        .current_dir(root)
        .output()
        .expect("python3 runs scripts/check_import_cycles.py (python3 is required by the test suite)");
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    (out.status.code().unwrap_or(-1), text)
}

#[test]
fn recon_has_no_import_circle() {
    let (code, text) = check(&["src/recon"]);
    assert_eq!(code, 0, "{text}");
    assert!(text.contains("no circle"), "{text}");
    // The solvers sit between the dispatcher and the shared types: the edges that once closed the circle.
    let (_, edges) = check(&["src/recon", "--print"]);
    for e in ["recon/solver.rs -> recon/gap.rs", "recon/solver.rs -> recon/admm.rs", "recon/gap.rs -> recon/solve/run.rs", "recon/admm.rs -> recon/solve/run.rs"] {
        assert!(edges.contains(e), "missing edge {e}:\n{edges}");
    }
    for e in ["recon/gap.rs -> recon/solver.rs", "recon/admm.rs -> recon/solver.rs"] {
        assert!(!edges.contains(e), "edge {e}:\n{edges}");
    }
}

#[test]
fn the_check_finds_a_circle() {
    let dir = tempfile::tempdir().unwrap();
    let m = dir.path().join("m");
    std::fs::create_dir_all(&m).unwrap();
    std::fs::write(m.join("mod.rs"), "pub mod a;\npub mod b;\npub use a::Thing;\n").unwrap();
    // a → b by a `use`, b → a by an inline path through the facade's re-export; comments and tests don't count.
    std::fs::write(m.join("a.rs"), "use super::b::Other;\npub struct Thing(Other);\n").unwrap();
    std::fs::write(m.join("b.rs"), "// super::a::Thing in a comment\npub struct Other;\npub fn f() -> usize { std::mem::size_of::<crate::m::Thing>() }\n").unwrap();
    let m_path = m.display().to_string();
    let (code, text) = check(&[&m_path, "--module", "m"]);
    assert_eq!(code, 1, "{text}");
    assert!(text.contains("import circle: m/a.rs → m/b.rs → m/a.rs"), "{text}");
    // Without the inline path, no circle.
    std::fs::write(m.join("b.rs"), "// super::a::Thing in a comment\npub struct Other;\n#[cfg(test)]\nmod tests {\n    use super::super::a::Thing;\n}\n").unwrap();
    let (code, text) = check(&[&m_path, "--module", "m"]);
    assert_eq!(code, 0, "{text}");
}
