//! Round 19 of the held-out battery (3 Dec 2026): the non-sequential prober checked ghost energies, Fresnel and
//! coating reflectances, TIR and path counts against independent NumPy/`tmm` computations (all to ≤ 4e-15) and
//! found two figures of the records wrong: render.json's `ghosts.off_detector` left out the plane weight B/K
//! (bands per plane) the ghost images carry, and `bench nonsequential` printed 0.00 CPU-s per M rays for
//! workloads shorter than the kernel's CPU accounting resolves.
use crate::cli_run::ok_cli as ok;

const SINGLET: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/systems/singlet_at_infinity.toml");

fn ghosts_record(dir: &std::path::Path, bands: &str, planes: &str, out: &str) -> serde_json::Value {
    ok(dir, &["render", "--system", SINGLET, "--ghosts", "2", "--scene", "ones.npy", "--scene-size", "8", "--bands", bands, "--planes", planes, "--opening", "1", "--scene-fov-deg", "1", "--rays", "4", "--no-mapping", "--threads", "1", "--out", out]);
    let j: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join(out).join("render.json")).unwrap()).unwrap();
    j["ghosts"].clone()
}

/// A uniform scene through a fully open mask: every launched ray's ghost light lands on the detector or off it,
/// so (ghost on the detector + off it) / main image = ghost power per launched ray, whatever the planes per band.
/// With 4 bands on 2 planes (plane weight 2) `off_detector` read half its share (the sum 8.34e-4 for 1.6653e-3).
#[test]
fn ghost_light_off_the_detector_carries_the_plane_weight() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    diffcassi::io::npy::write_npy_f32(d.join("ones.npy"), &[8, 8, 4], &[1.0f32; 256]).unwrap();
    diffcassi::io::npy::write_npy_f64(d.join("ones_wavelengths_nm.npy"), &[4], &[500.0, 513.3333333333334, 526.6666666666666, 540.0]).unwrap();
    for (planes, out) in [("2", "k2"), ("4", "k4")] {
        let g = ghosts_record(d, "500:540:4", planes, out);
        let (main, ghost, off, per) = (g["acquisition_main"].as_f64().unwrap(), g["acquisition_ghost"].as_f64().unwrap(), g["off_detector"].as_f64().unwrap(), g["ghost_per_launched"].as_f64().unwrap());
        assert!(off > 0.0 && per > 0.0, "planes {planes}: {g}");
        let share = (ghost + off) / main;
        assert!((share / per - 1.0).abs() < 1e-3, "planes {planes}: (ghost {ghost} + off {off}) / main {main} = {share}, ghost per launched ray {per}");
    }
}

/// 400 rays take a millisecond: the CPU time the kernel has accounted for them is mostly tick error, and the
/// table printed 0.00 CPU-s per M rays for a kernel at 3 wall-s per M rays. Each cell is now a positive figure
/// or says it could not be measured.
#[test]
fn bench_nonsequential_never_prints_a_zero_cpu_time() {
    let dir = tempfile::tempdir().unwrap();
    let out = ok(dir.path(), &["bench", "nonsequential", "--preset", "sp", "--rays", "200", "--repeat", "1", "--wavelengths", "2", "--csv", "b.csv"]);
    let mut cells = 0;
    for line in out.lines().filter(|l| l.starts_with("| analytic-f64 |") || l.starts_with("| embree-") || l.starts_with("| brute-f64 |")) {
        let f: Vec<&str> = line.split('|').map(str::trim).collect();
        let cell = f[4];
        cells += 1;
        assert!(cell.starts_with("n/a") || cell.parse::<f64>().is_ok_and(|v| v > 0.0), "{line}");
    }
    assert_eq!(cells, 6, "{out}");
}

/// The floor's rows are CPU-time splits: a row shorter than the accounting resolves is run again until measured,
/// so every row's figure is positive even at a workload of milliseconds (row (0), reading the recorded packets,
/// takes 0.003 CPU-s per M rays).
#[test]
fn bench_floor_measures_every_row() {
    let dir = tempfile::tempdir().unwrap();
    let out = ok(dir.path(), &["bench", "nonsequential", "--preset", "sp", "--rays", "2000", "--repeat", "1", "--wavelengths", "2", "--floor", "--csv", "f.csv"]);
    assert!(out.contains("floor of Embree"), "{out}");
    // The CSV keeps each row's CPU time relative to the analytic kernel's at full precision (the table's 3 decimals
    // may round a fast row to 0.000).
    let csv = std::fs::read_to_string(dir.path().join("f.csv")).unwrap();
    let rows: Vec<&str> = csv.lines().filter(|l| l.starts_with("floor,")).collect();
    assert_eq!(rows.len(), 5, "{csv}");
    for line in rows {
        let vs: f64 = line.rsplit(',').next().unwrap().parse().unwrap_or_else(|_| panic!("{line}"));
        assert!(vs > 0.0 && vs.is_finite(), "{line}");
    }
}
