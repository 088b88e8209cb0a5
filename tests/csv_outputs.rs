//! Every CSV the command line writes reads back with a standard CSV reader (issue 40, item 3; issue 39): each
//! `--csv` option (`trace`, `spot`, `distortion`, `dispersion`, `ghosts`, `bench tradeoff`, `bench
//! nonsequential`) and the tables of `report` (spots.csv, distortion_*nm.csv) and `study` (study.csv) are
//! written at tiny sizes, then parsed by Python's `csv` module: after the `#` comment lines, every row has the
//! header's field count and no field is empty where the header names a text column that is never empty. Every
//! table goes through the project's writer (`io::csv`), which quotes fields holding commas (`bench
//! nonsequential`'s `embree-user,refine=f64`, `tube, 4 segments`: 16 of its 33 rows had 9 fields under an
//! 8-column header before).
use std::path::{Path, PathBuf};
use std::process::Command;

fn run(cwd: &Path, args: &[&str]) {
    let o = Command::new(env!("CARGO_BIN_EXE_diffcassi")).args(args).current_dir(cwd).output().expect("the binary runs");
    assert!(o.status.success(), "{args:?}: {}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
}

/// Parse `files` with Python's csv module; returns one line per file: `path rows columns` or `BAD …`.
fn parse_with_python(files: &[PathBuf]) -> String {
    let script = r##"
import csv, sys
for path in sys.argv[1:]:
    with open(path, newline="") as f:
        lines = [l for l in f if not l.startswith("#")]
    rows = list(csv.reader(lines))
    header, body = rows[0], rows[1:]
    bad = [(i + 1, len(r)) for i, r in enumerate(body) if len(r) != len(header)]
    if bad or not body or len(set(header)) != len(header):
        print("BAD", path, len(header), bad[:5], len(body))
    else:
        print(path, len(body), len(header))
"##;
    let o = Command::new("python3").arg("-c").arg(script).args(files).output().expect("python3 runs");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8_lossy(&o.stdout).into_owned()
}

#[test]
fn every_csv_the_cli_writes_parses_with_a_standard_reader() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path();
    run(p, &["trace", "--preset", "sp", "--field-mm", "0,0", "--wavelength-nm", "520", "--pupil", "grid:3", "--csv", "trace.csv"]);
    run(p, &["spot", "--preset", "sp", "--pupil", "hexapolar:2", "--csv", "spot.csv"]);
    run(p, &["distortion", "--preset", "sp", "--grid", "3", "--csv", "distortion.csv"]);
    run(p, &["dispersion", "--preset", "sp", "--wavelengths-nm", "450:650:3", "--csv", "dispersion.csv"]);
    run(p, &["ghosts", "--preset", "sp", "--order", "2", "--rings", "1", "--extended-grid", "1", "--csv", "ghosts.csv"]);
    run(p, &["bench", "tradeoff", "--quick", "--wavelengths", "1", "--repeat", "1", "--csv", "tradeoff.csv"]);
    let mut files: Vec<PathBuf> = ["trace", "spot", "distortion", "dispersion", "ghosts", "tradeoff"].iter().map(|n| p.join(format!("{n}.csv"))).collect();
    if cfg!(feature = "embree") {
        run(p, &["bench", "nonsequential", "--quick", "--wavelengths", "1", "--csv", "nonsequential.csv"]);
        files.push(p.join("nonsequential.csv"));
    }
    run(p, &["report", "--preset", "sp", "--out", "report"]);
    files.push(p.join("report/spots.csv"));
    for e in std::fs::read_dir(p.join("report")).unwrap() {
        let n = e.unwrap().file_name().to_string_lossy().into_owned();
        if n.starts_with("distortion_") && n.ends_with(".csv") {
            files.push(p.join("report").join(n));
        }
    }
    run(p, &["study", "--synthetic", "1", "--scene-size", "16", "--presets", "sp", "--operators", "shift", "--bands", "450:650:4", "--planes", "4", "--rays", "1", "--iterations", "1", "--out", "study"]);
    files.push(p.join("study/study.csv"));
    let out = parse_with_python(&files);
    assert_eq!(out.lines().count(), files.len(), "{out}");
    assert!(!out.contains("BAD"), "{out}");
    if cfg!(feature = "embree") {
        // The rows whose backend or case holds a comma are quoted, and read back as one field.
        let text = std::fs::read_to_string(p.join("nonsequential.csv")).unwrap();
        assert!(text.contains("\"embree-user,refine=f64\"") && text.contains("\"tube, 4 segments\""), "{text}");
    }
}
