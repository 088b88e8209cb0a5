//! Round 19 of the held-out battery (3 Dec 2026), resources at scale: the mapping cube's estimate (150 B per
//! entry) was 5–9× its real peak and refused `mapping`, `render` and `render-dataset` runs that fit — `render`
//! only after the acquisition; `render --tolerance-um` checked the ray budget at the `--rays 20` the tolerance
//! replaces and left its calibration out of the memory estimate; `distortion` estimated 250 B per grid point
//! for ~440 B; and a refusal printed "2.294e5 rays … over the budget of 2.294e5".
use crate::cli_run::{ok_cli as ok, peak_rss_cli, refused_cli as refused, run_cli};

/// The first memory estimate of `diffcassi --max-memory-gb 1e-6 ARGS` (bytes), from its refusal.
fn estimate(dir: &std::path::Path, args: &[&str]) -> f64 {
    let mut all = vec!["--max-memory-gb", "1e-6"];
    all.extend_from_slice(args);
    let (code, out) = run_cli(dir, &all);
    assert_eq!(code, Some(1), "{out}");
    let gb: f64 = out.split("needs an estimated ").nth(1).and_then(|t| t.split(" GB").next()).and_then(|t| t.parse().ok()).unwrap_or_else(|| panic!("no estimate in: {out}"));
    gb * 1e9
}

/// `mapping`'s estimate is the cube it holds: 17 B per entry (two f64 coordinates and a validity flag) plus the
/// float32 copy written (8 B), within a small margin of the measured peak (it was 4.9–8.8× the peak). A run the
/// old figure refused (256² × 28 under 0.1 GB: "needs 0.28 GB") runs.
#[test]
fn mapping_estimate_follows_the_cube_it_holds() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for (extra, lo) in [(None, 1.0), (Some("--f64"), 1.0)] {
        let mut args = vec!["mapping", "--preset", "sp", "--height", "512", "--width", "512", "--npy", "m.npy"];
        args.extend(extra);
        let e = estimate(d, &args);
        let (peak, code) = peak_rss_cli(d, &args);
        assert_eq!(code, Some(0), "{args:?}");
        // The process's own ~13 MB are not in the estimate: compare the cube's share.
        let ratio = e / peak;
        assert!(ratio > 0.85 * lo && ratio < 1.5, "{args:?}: estimate {e:.3e} B vs peak {peak:.3e} B (ratio {ratio:.2})");
    }
    ok(d, &["--max-memory-gb", "0.1", "mapping", "--preset", "sp", "--height", "256", "--width", "256", "--npy", "m2.npy"]);
}

/// `render`'s memory check is one, before any work, and counts the mapping cube at what it adds to the
/// render's peak: 256² × 28 under 0.1 GB was refused by the mapping cube's own check after the acquisition
/// ("mapping cube 256×256×28: needs 0.28 GB"; the run peaks at 0.08 GB). `--no-mapping` lowers the estimate,
/// and the refusal names it.
#[test]
fn render_checks_its_mapping_cube_before_the_work_and_names_no_mapping() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let base = ["render", "--preset", "sp", "--scene-size", "256", "--planes", "28", "--rays", "1"];
    let mut args = vec!["--max-memory-gb", "0.1"];
    args.extend(base);
    args.extend(["--out", "o"]);
    ok(d, &args);
    assert!(d.join("o/mapping.npy").is_file());
    let mut with = base.to_vec();
    with.extend(["--out", "p"]);
    let mut without = with.clone();
    without.push("--no-mapping");
    let (e_with, e_without) = (estimate(d, &with), estimate(d, &without));
    assert!(e_without < 0.7 * e_with, "--no-mapping: {e_without:.3e} B, with the mapping cube {e_with:.3e} B");
    let mut big = vec!["--max-memory-gb", "1e-6"];
    big.extend(&with);
    refused(d, &big, &["--scene-size 256", "--no-mapping", "--max-memory-gb"]);
    assert!(!d.join("p").exists());
}

/// The render's pre-check covers what the library's mapping cube checks after the acquisition: at every size
/// and band count the settings' estimate (with the mapping cube written) is above the cube's own estimate,
/// so the after-the-work check cannot refuse a render the pre-check let through (at 2048² the old figure
/// refused after 12.6 s and 1.55 GB).
#[test]
fn the_render_estimate_covers_the_mapping_cube_check() {
    use diffcassi::render::RenderSettings;
    for n in [1, 64, 512, 2048, 4096] {
        for bands in [1, 28, 200] {
            let s = RenderSettings { scene_size: n, bands_nm: diffcassi::analysis::linspace(450.0, 650.0, bands), planes: bands.max(2), airy_diameter_px: None, ..RenderSettings::default() };
            let render = s.memory_bytes(n, n);
            let cube = diffcassi::limits::bytes_mapping(n, n, bands);
            assert!(render > cube, "n {n}, {bands} bands: render {render:.3e} B ≤ mapping cube {cube:.3e} B");
        }
    }
}

/// `render --tolerance-um` checks the ray budget at the rays the tolerance chooses (here 1), not at the
/// `--rays 20` it replaces: 32² × 4 planes × 1 = 4096 rays fit `--max-rays 4096` (refused before: "× --rays 20:
/// 8.192e4 rays"). A `--rays` given beside the tolerance is still refused, naming both.
#[test]
fn a_tolerance_is_checked_at_the_rays_it_chooses() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = ok(d, &["--max-rays", "4096", "render", "--preset", "ap", "--scene-size", "32", "--planes", "4", "--tolerance-um", "30", "--calibration-cache", "c", "--out", "o"]);
    assert!(out.contains("4 planes × 1 rays"), "{out}");
    refused(d, &["--max-rays", "4095", "render", "--preset", "ap", "--scene-size", "32", "--planes", "4", "--tolerance-um", "30", "--calibration-cache", "c", "--out", "p"], &["4096 rays to trace, over the budget of 4095"]);
    let (code, out) = run_cli(d, &["render", "--preset", "ap", "--scene-size", "32", "--planes", "4", "--rays", "2", "--tolerance-um", "30", "--out", "q"]);
    assert_ne!(code, Some(0), "{out}");
    assert!(out.contains("cannot be combined with --rays 2"), "{out}");
}

/// The calibration of `--tolerance-um` counts beside the render: the estimate is above the render's alone
/// and names the calibration.
#[test]
fn a_tolerance_calibration_is_in_the_memory_estimate() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let render = estimate(d, &["render", "--preset", "ap", "--scene-size", "32", "--planes", "4", "--rays", "1", "--out", "o"]);
    let budget = format!("{}", render * 1.01 / 1e9);
    refused(d, &["--max-memory-gb", &budget, "render", "--preset", "ap", "--scene-size", "32", "--planes", "4", "--tolerance-um", "30", "--calibration-cache", "c", "--out", "o"], &["--tolerance-um 30's calibration", "beside the 32×32 render"]);
    assert!(!d.join("c").exists() && !d.join("o").exists(), "refused before the calibration");
}

/// `distortion`'s estimate follows its ~440 B per grid point (it was 250 B: 0.55× the peak).
#[test]
fn distortion_estimate_is_not_below_its_peak() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let args = ["distortion", "--preset", "sp", "--grid", "700", "--csv", "d.csv"];
    let e = estimate(d, &args);
    let (peak, code) = peak_rss_cli(d, &args);
    assert_eq!(code, Some(0));
    let ratio = e / peak;
    assert!(ratio > 0.9 && ratio < 1.5, "estimate {e:.3e} B vs peak {peak:.3e} B (ratio {ratio:.2})");
}

/// A ray-budget refusal prints both counts exactly: 229 376 rays against a budget of 229 375 printed
/// "2.294e5 rays … over the budget of 2.294e5".
#[test]
fn a_ray_refusal_prints_counts_that_differ() {
    let dir = tempfile::tempdir().unwrap();
    refused(dir.path(), &["--max-rays", "229375", "render", "--preset", "sp", "--scene-size", "64", "--planes", "28", "--rays", "2", "--out", "o"], &["229376 rays to trace, over the budget of 229375"]);
    assert_eq!(diffcassi::limits::fmt_count(1.3e23), "1.3e23");
    assert_eq!(diffcassi::limits::fmt_count(229375.5), "229375.5");
}
