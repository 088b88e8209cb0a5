//! Round 18 of the held-out battery (3 Dec 2026): what the documentation prober found in the program's text. The
//! analysis commands printed a converted wavelength with its last bit (`587.5618000000001 nm`, µm × 1000 of a
//! `.zmx` file's `WAVM 0.5875618`) where `info` prints `587.5618 nm`.
use crate::cli_run::ok_cli as ok;

const LENS: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/zmx/double_gauss_US583336.zmx");

#[test]
fn analysis_commands_print_wavelengths_as_info_does() {
    let dir = tempfile::tempdir().unwrap();
    let out = ok(dir.path(), &["distortion", "--system", LENS, "--half-width-deg", "10", "--grid", "5", "--csv", "g.csv"]);
    assert!(out.contains("grid at 587.5618 nm over ±10°"), "{out}");
    let out = ok(dir.path(), &["spot", "--system", LENS, "--field-deg", "0,5", "--pupil", "hexapolar:2"]);
    assert!(out.contains("587.5618 ") || out.contains(" 587.5618\n"), "{out}");
    assert!(!out.contains("587.5618000000001"), "{out}");
    // The tables' comment lines say it as text; their columns keep every bit (data read back bit-identical).
    for f in ["g.csv"] {
        let csv = std::fs::read_to_string(dir.path().join(f)).unwrap();
        let comment = csv.lines().find(|l| l.starts_with('#') && l.contains("wavelength")).unwrap_or_else(|| panic!("{f}: {csv}"));
        assert!(comment.contains("wavelength 587.5618 nm"), "{f}: {comment}");
    }
}
