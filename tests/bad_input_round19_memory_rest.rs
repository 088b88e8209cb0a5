//! Round 19 of the held-out battery (3 Dec 2026, prober D): the memory budget covers what the commands round
//! 19A did not reach. Spec files of hundreds of thousands of surfaces (a 7.5 MB `.zmx` of 4·10⁵ surfaces peaked
//! at 1.58 GB under `--max-memory-gb 0.1`) are refused at [`diffcassi::limits::MAX_SURFACES`] by every reader;
//! `bench tradeoff` counts its finest Embree mesh (0.04 GB estimated, 0.52 GB peak); `evaluate` counts both
//! cubes (each was checked alone against the whole budget).
use crate::cli_run::{ok_cli as ok, peak_rss_cli, refused_cli as refused, run_cli};

/// `n` surfaces as a `.zmx` (`SURF i` / `DISZ 0` pairs, the prober's), a TOML and a JSON spec and a prescription
/// CSV, written in `d`.
fn spec_files(d: &std::path::Path, n: usize) -> [String; 4] {
    let mut zmx = String::from("VERS 171115\nMODE SEQ\nNAME big\nUNIT MM X W X CM MR CPMM\nENPD 2\nFTYP 0 0 1 1 0 0 0 1\nXFLN 0\nYFLN 0\nFWGN 1\nWAVM 1 0.55 1\nPWAV 1\nSURF 0\n  DISZ INFINITY\nSURF 1\n  STOP\n  DISZ 1\n");
    let mut toml = String::from("name = \"big\"\nwavelengths_nm = [550.0]\nprimary_wavelength_nm = 550.0\nfields_deg = [[0.0, 0.0]]\nfield_type = \"angle\"\n\n[aperture]\ntype = \"entrance_pupil_diameter\"\nvalue = 2.0\n\n[[surfaces]]\ntype = \"standard\"\nthickness_mm = \"infinity\"\n\n[[surfaces]]\ntype = \"standard\"\nstop = true\nthickness_mm = 1.0\n");
    let mut json = String::from("{\"name\": \"big\", \"wavelengths_nm\": [550.0], \"primary_wavelength_nm\": 550.0, \"fields_deg\": [[0.0, 0.0]], \"field_type\": \"angle\", \"aperture\": {\"type\": \"entrance_pupil_diameter\", \"value\": 2.0}, \"surfaces\": [{\"type\": \"standard\", \"thickness_mm\": \"infinity\"}, {\"type\": \"standard\", \"stop\": true, \"thickness_mm\": 1.0}");
    let mut csv = String::from("surf,type,comment,radius,thickness,material,semi_diameter,conic,par1,par2,par3,par4,par5\n0,OBJECT Standard,,inf,50.000,,3.536,0,,,,,\n1,STOP Standard,,inf,1.000,,2.000,0,,,,,\n");
    for i in 2..n {
        zmx += &format!("SURF {i}\n  DISZ 0\n");
        toml += "\n[[surfaces]]\ntype = \"standard\"\nthickness_mm = 0.0\n";
        json += ", {\"type\": \"standard\", \"thickness_mm\": 0.0}";
        csv += &format!("{i},{}Standard,,inf,0.000,,2.000,0,,,,,\n", if i + 1 == n { "IMAGE " } else { "" });
    }
    zmx += "TOL TOFF 0 0 0 0 0 0\n";
    json += "]}\n";
    let names = ["big.zmx", "big.toml", "big.json", "big.csv"];
    for (name, text) in names.iter().zip([&zmx, &toml, &json, &csv]) {
        std::fs::write(d.join(name), text).unwrap();
    }
    names.map(String::from)
}

/// Finding 1: every spec reader refuses more than `MAX_SURFACES` surfaces, naming the file, the line where one
/// is known and the count, before it holds them (a few MB resident, not ~4 kB per surface); the bound itself is
/// accepted by `info`.
#[test]
fn every_spec_reader_refuses_more_surfaces_than_the_bound() {
    let max = diffcassi::limits::MAX_SURFACES;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for name in spec_files(d, max + 1) {
        let (code, out) = run_cli(d, &["info", "--system", &name]);
        assert_eq!(code, Some(1), "{name}: {out}");
        assert!(out.contains(&name) && out.contains(&format!("more than the {max}")), "{name}: {out}");
        if name.ends_with(".zmx") || name.ends_with(".toml") || name.ends_with(".csv") {
            assert!(out.contains("line ") && out.contains(&format!("{}", max + 1)), "{name}: {out}");
        }
        let (peak, code) = peak_rss_cli(d, &["--max-memory-gb", "0.1", "import-zmx", &name, "--out", "o.toml"]);
        if name.ends_with(".zmx") {
            assert_eq!(code, Some(1), "{name}");
            assert!(peak < 30e6, "{name}: peak {peak:.3e} B for a refused file");
        }
    }
    // The bound itself is a system (object, stop, image and flats between them).
    for name in spec_files(d, max) {
        ok(d, &["info", "--system", &name]);
    }
}

/// Finding 2: `bench tradeoff`'s estimate (full mode) counts the Embree mesh scene at max-sag=0.01 µm, ~0.45 GB
/// of SP whatever `--wavelengths` (it estimated 0.04 GB at `--wavelengths 1` and peaked at 0.52 GB), and the
/// refusal names it; `--quick`, whose finest mesh is 0.1 µm, stays small.
#[test]
fn bench_tradeoff_counts_its_finest_mesh() {
    if !diffcassi::tracer::BackendConfig::available(diffcassi::tracer::Backend::EmbreeMesh) {
        eprintln!("no Embree in this build: the mesh candidates do not run");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let gb = |args: &[&str]| -> f64 {
        let mut all = vec!["--max-memory-gb", "1e-6", "bench", "tradeoff", "--wavelengths", "1", "--repeat", "1"];
        all.extend_from_slice(args);
        let (code, out) = run_cli(d, &all);
        assert_eq!(code, Some(1), "{out}");
        out.split("needs an estimated ").nth(1).and_then(|t| t.split(" GB").next()).and_then(|t| t.parse().ok()).unwrap_or_else(|| panic!("{out}"))
    };
    let (full, quick) = (gb(&[]), gb(&["--quick"]));
    assert!(full > 0.45 && full < 1.0, "full mode estimate {full} GB (the run peaks at 0.52 GB)");
    assert!(quick < 0.1, "--quick estimate {quick} GB");
    refused(d, &["--max-memory-gb", "0.3", "bench", "tradeoff", "--wavelengths", "1", "--repeat", "1"], &["max-sag=0.01um", "--quick", "--max-memory-gb 0.3"]);
}

/// Finding 4: `evaluate` counts both cubes: the truth is held while the estimate is read (each reader checked
/// its cube alone against the whole budget, and both cubes with the metrics' buffers reached 1.5× it).
#[test]
fn evaluate_counts_both_cubes() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (h, w, b) = (128usize, 128usize, 28usize);
    let n = h * w * b;
    let t: Vec<f32> = (0..n).map(|i| ((i * 7919) % 1000) as f32 / 1000.0).collect();
    let e: Vec<f32> = t.iter().map(|v| v * 0.99).collect();
    diffcassi::io::write_npy_f32(d.join("t.npy"), &[h, w, b], &t).unwrap();
    diffcassi::io::write_npy_f32(d.join("e.npy"), &[h, w, b], &e).unwrap();
    let args = |gb: &'static str| ["--max-memory-gb", gb, "evaluate", "--truth", "t.npy", "--estimate", "e.npy", "--truth-wavelengths", "450:650:28", "--estimate-wavelengths", "450:650:28"];
    // One cube's check is its file and f32 copy, 8 B per element (3.7 MB): 4.5 MB holds one, not both.
    let one = 8.0 * n as f64;
    assert!(one < 4.5e6 && 2.0 * one > 4.5e6);
    refused(d, &args("0.0045"), &["e.npy", "the --truth cube 128×128×28", "--max-memory-gb 0.0045"]);
    ok(d, &args("0.02"));
}

/// Finding 5: `design amici`'s fixed workload is checked before any work, and the refusal says that no option
/// of `design` sets its size (it came after 0.3 s of work from the distortion grid's own check, "reduce
/// distortion grid 13×13", not an option of `design`).
#[test]
fn design_amici_refusal_names_its_fixed_workload() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (code, out) = run_cli(d, &["--max-memory-gb", "1e-6", "design", "amici", "--iterations", "50"]);
    assert_eq!(code, Some(1), "{out}");
    assert!(out.contains("design amici: its fixed workload") && out.contains("no option of `design` sets its size") && out.contains("raise --max-memory-gb"), "{out}");
    assert!(!out.contains("reduce distortion grid"), "{out}");
}
