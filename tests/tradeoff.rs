//! Speed vs accuracy (issue 7, parts 1, 2, 4): `--tolerance-um` picks a configuration that meets the
//! tolerance on rays it was not calibrated on and is never slower than the analytic tracer unless that
//! one cannot meet it; the cheaper models (interpolated mapping, fewer rays per pixel) meet theirs; the
//! calibration cache is used and never trusted when corrupt; `bench tradeoff` writes its interface.
//!
//! Speed: a unit test cannot assert wall-clock speed robustly on a shared machine, so the selection is
//! checked on the selector's own measured costs (its predicted cost of the choice is ≤ the analytic's),
//! and, when it picks something other than the analytic tracer, the throughput ratio is re-measured on the
//! fresh set (best of 5) and must not fall below 0.8 of the analytic's (a generous allowance for noise).
use diffcassi::analysis::{self, linspace};
use diffcassi::fidelity::{self, BackendCalibration, CacheOptions, ErrorStats, Measured, Provenance, RaySetSpec};
use diffcassi::prelude::*;
use diffcassi::render::{Mask, RenderConfig, Renderer, SpectralSampling};
use std::process::Command;

fn sp() -> SequentialSystem {
    SequentialSystem::build(&presets::spec("sp").unwrap()).unwrap()
}

#[test]
fn tolerance_choice_meets_the_tolerance_on_fresh_rays_and_is_never_slower_than_analytic() {
    let sys = sp();
    let ws = linspace(450.0, 650.0, 28);
    let (cal, _) = fidelity::calibrate_backends(&sys, &ws, &CacheOptions::none()).unwrap();
    let fresh = RaySetSpec::fresh(12, 64, 99).build(&sys, &ws).unwrap();
    let analytic = AnalyticTracer::default();
    let reference = analytic.trace(&sys, &fresh).unwrap();
    for tol in [10.0, 1.0, 0.1, 0.01] {
        let choice = fidelity::choose_backend(&cal, tol, fresh.len() as u64).unwrap();
        println!("{}", choice.explanation);
        let tracer = choice.config.build().unwrap();
        let out = tracer.trace(&sys, &fresh).unwrap();
        let e = ErrorStats::compare(&reference, &out);
        println!("tolerance {tol} µm: chose {:?}; fresh set ({} rays): max {:.3e} µm, mismatches {}", choice.config, fresh.len(), e.max_um, e.mismatches);
        assert!(e.within(tol), "tolerance {tol}: fresh-set error {e:?}");
        // The analytic tracer meets every tolerance (it is the reference), so the choice must not be slower.
        assert!(choice.predicted_seconds <= choice.analytic_seconds, "{}", choice.explanation);
        if !fidelity::is_reference(&choice.config) {
            let r_choice = fidelity::rays_per_second(tracer.as_ref(), &sys, &fresh, 5).unwrap();
            let r_analytic = fidelity::rays_per_second(&analytic, &sys, &fresh, 5).unwrap();
            println!("  throughput ratio chosen/analytic on the fresh set: {:.2}", r_choice / r_analytic);
            assert!(r_choice >= 0.8 * r_analytic);
        }
    }
}

fn measured(backend: &str, max_um: f64, mismatches: usize, rays_per_s: f64) -> Measured {
    Measured { backend: backend.into(), error: ErrorStats { max_um, rms_um: max_um / 2.0, compared: 100, mismatches }, rays_per_s, seconds: 1.0, setup_seconds: 0.0 }
}

#[test]
fn selection_rule_prefers_cheaper_models_only_when_they_qualify() {
    // A made-up calibration where Embree were faster: the rule, not the measurements, is under test.
    let cal = |user_rate: f64, user_mismatches: usize| BackendCalibration {
        wavelengths_nm: vec![500.0],
        rays: 100,
        candidates: vec![measured("analytic", 0.0, 0, 1e6), measured("embree-user:none", 0.007, user_mismatches, user_rate), measured("embree-mesh:10:none", 1.0, 0, 1e7)],
        left_out: vec![],
    };
    let pick = |c: &BackendCalibration, tol: f64| fidelity::backend_text(&fidelity::choose_backend(c, tol, 1_000_000).unwrap().config);
    assert_eq!(pick(&cal(5e6, 0), 10.0), "embree-mesh:10:none"); // fastest within 10 µm
    assert_eq!(pick(&cal(5e6, 0), 0.1), "embree-user:none"); // the mesh is out of tolerance
    assert_eq!(pick(&cal(5e6, 0), 0.001), "analytic"); // only the reference qualifies
    assert_eq!(pick(&cal(5e6, 3), 0.1), "analytic"); // mismatches disqualify
    assert_eq!(pick(&cal(1.1e6, 0), 0.1), "analytic"); // 10 % faster is within the noise margin
    assert!(fidelity::choose_backend(&cal(5e6, 0), -1.0, 1).is_err());
    assert!(fidelity::choose_backend(&cal(5e6, 0), f64::NAN, 1).is_err());
}

#[test]
fn interpolated_mapping_meets_the_tolerance_it_was_chosen_for() {
    let sys = sp();
    let ws = linspace(450.0, 650.0, 28);
    let (h, w) = (64, 48);
    let (cal, _) = fidelity::calibrate_backends(&sys, &ws, &CacheOptions::none()).unwrap();
    let (mut map, _) = fidelity::calibrate_mapping(&sys, h, w, 0.01, &ws, &CacheOptions::none()).unwrap();
    // The choice weighs measured seconds, which a loaded machine scrambles (a stride-16 model timed slower than
    // the exact one on a busy CI run): the costs are replaced by the work model — the traced chief rays, 1/s² of
    // the exact cube's at stride s — so the test checks the selection and the error guarantee, not the load.
    let exact_s = map.strides.iter().find(|m| m.stride == 1).unwrap().seconds_per_wavelength;
    for m in map.strides.iter_mut() {
        m.seconds_per_wavelength = exact_s / (m.stride * m.stride) as f64;
    }
    let exact = analysis::mapping_cube(&sys, &AnalyticTracer::default(), h, w, 0.01, &ws).unwrap();
    let mut strides = Vec::new();
    for tol in [1.0, 0.01, 1e-4] {
        let c = fidelity::choose_mapping(&cal, &map, tol, ws.len()).unwrap();
        println!("{}", c.explanation);
        let cube = analysis::mapping_cube_interpolated(&sys, c.config.build().unwrap().as_ref(), h, w, 0.01, &ws, c.stride).unwrap();
        let max_um = exact.positions_mm.iter().zip(&cube.positions_mm).map(|(a, b)| 1e3 * (a - b).abs()).fold(0.0, f64::max);
        println!("tolerance {tol} µm: stride {} → max error over all {} entries {max_um:.3e} µm", c.stride, exact.valid.len());
        assert!(max_um <= tol, "stride {}: {max_um} µm > {tol}", c.stride);
        assert_eq!(cube.valid, exact.valid);
        strides.push(c.stride);
    }
    // A looser tolerance never asks for a finer model, and the interpolation is used at all.
    assert!(strides.windows(2).all(|s| s[0] >= s[1]), "{strides:?}");
    assert!(strides[0] > 1);
}

#[test]
fn render_rays_per_pixel_meet_the_tolerance_as_a_standard_error() {
    let sys = sp();
    let mut cfg = RenderConfig::paper(12);
    cfg.spectral = SpectralSampling::new(vec![450.0, 550.0, 650.0], 1).unwrap();
    cfg.airy = None;
    let (cal, _) = fidelity::calibrate_backends(&sys, &cfg.spectral.planes_nm, &CacheOptions::none()).unwrap();
    let (rc, _) = fidelity::calibrate_render(&sys, &cfg, &CacheOptions::none()).unwrap();
    let tol = 4.0;
    let choice = fidelity::choose_render(&cal, &rc, tol, 144 * 3).unwrap();
    println!("{}", choice.explanation);
    assert!(choice.rays_per_pixel >= 2 && choice.error_um <= tol);
    // Too tight to reach: a clear error, not an absurd ray count.
    let e = fidelity::choose_render(&cal, &rc, 0.01, 144 * 3).unwrap_err().to_string();
    assert!(e.contains("rays per pixel") && e.contains("σ"), "{e}");
    // Check: splat-centroid displacement of the chosen N against a 16× N render with other random numbers.
    let tracer = AnalyticTracer::default();
    let centroid = |n: usize, seed: u64| {
        let mut c = cfg.clone();
        c.rays_per_pixel = n;
        c.seed = seed;
        let r = Renderer::new(&sys, &tracer, c, Mask::open(12, 12)).unwrap();
        let t = r.trace_all(&|_| {}).unwrap();
        t.iter()
            .map(|p| {
                p.footprints
                    .iter()
                    .map(|f| {
                        let (x, y) = p.centroid_px(f).expect("a footprint carries weight");
                        (f.pixel, x * 10.0, y * 10.0) // µm (10 µm pixels)
                    })
                    .collect::<Vec<_>>()
            })
            .collect::<Vec<_>>()
    };
    let (a, b) = (centroid(choice.rays_per_pixel, 1), centroid(16 * choice.rays_per_pixel, 2));
    let (mut s2, mut n) = (0.0, 0);
    for (pa, pb) in a.iter().zip(&b) {
        assert_eq!(pa.len(), pb.len());
        for (x, y) in pa.iter().zip(pb) {
            assert_eq!(x.0, y.0);
            s2 += (x.1 - y.1).powi(2) + (x.2 - y.2).powi(2);
            n += 1;
        }
    }
    let rms = (s2 / n as f64).sqrt();
    println!("N = {}: RMS splat-centroid displacement vs N = {}: {rms:.3} µm (tolerance {tol}, σ = {:.2} µm)", choice.rays_per_pixel, 16 * choice.rays_per_pixel, rc.sigma_um);
    assert!(rms <= tol);
}

#[test]
fn calibration_cache_is_used_and_corrupt_entries_are_recomputed() {
    let sys = SequentialSystem::build(&presets::spec("ap").unwrap()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let cache = CacheOptions { dir: Some(dir.path().to_path_buf()) };
    let (a, p1) = fidelity::calibrate_backends(&sys, &[520.0], &cache).unwrap();
    assert!(matches!(p1, Provenance::Measured { .. }));
    let (b, p2) = fidelity::calibrate_backends(&sys, &[520.0], &cache).unwrap();
    assert!(matches!(p2, Provenance::Cached(_)), "{p2:?}");
    assert_eq!(a.candidates.len(), b.candidates.len());
    // (JSON keeps f64 to within an ulp or so.)
    assert_eq!(a.candidates[1].error.mismatches, b.candidates[1].error.mismatches);
    assert!((a.candidates[1].error.max_um - b.candidates[1].error.max_um).abs() <= 1e-12 * a.candidates[1].error.max_um.abs());
    // Another wavelength is another key.
    let (_, p3) = fidelity::calibrate_backends(&sys, &[521.0], &cache).unwrap();
    assert!(matches!(p3, Provenance::Measured { .. }));
    // Corrupt every entry: garbage, then a valid file with a NaN throughput.
    for e in std::fs::read_dir(dir.path()).unwrap() {
        std::fs::write(e.unwrap().path(), "{ not json").unwrap();
    }
    let (_, p4) = fidelity::calibrate_backends(&sys, &[520.0], &cache).unwrap();
    assert!(matches!(p4, Provenance::Measured { .. }));
    for e in std::fs::read_dir(dir.path()).unwrap() {
        let p = e.unwrap().path();
        let text = std::fs::read_to_string(&p).unwrap();
        let Ok(mut v) = serde_json::from_str::<serde_json::Value>(&text) else { continue }; // the 521 nm entry is still garbage
        // Edit the parsed entry, not the text: the text of a re-printed float need not match the file's
        // (serde_json's default parser may be an ulp off), and a missed replacement left the entry valid.
        v["payload"]["candidates"][0]["rays_per_s"] = serde_json::json!(-1.0);
        std::fs::write(&p, serde_json::to_string_pretty(&v).unwrap()).unwrap();
    }
    let (c, p5) = fidelity::calibrate_backends(&sys, &[520.0], &cache).unwrap();
    assert!(matches!(p5, Provenance::Measured { .. }));
    assert!(c.candidates.iter().all(|m| m.rays_per_s > 0.0));
}

// ---------------------------------------------------------------- command line

fn run(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_diffcassi")).args(args).output().unwrap()
}

fn text(o: &std::process::Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
}

#[test]
fn cli_tolerance_prints_the_choice_and_caches_it() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let args = ["spot", "--preset", "sp", "--wavelength-nm", "520", "--tolerance-um", "0.5", "--calibration-cache", cache.to_str().unwrap()];
    let o = run(&args);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    assert!(t.contains("fidelity: tolerance 0.5 µm → --backend analytic") && t.contains("candidates") && t.contains("calibrated now"), "{t}");
    let o = run(&args);
    assert!(text(&o).contains("calibration from the cache"), "{}", text(&o));
    // Every tracing command accepts it.
    let npy = dir.path().join("m.npy");
    let o = run(&["mapping", "--preset", "sp", "--height", "32", "--width", "32", "--wavelengths-nm", "450:650:4", "--npy", npy.to_str().unwrap(), "--tolerance-um", "0.01", "--calibration-cache", cache.to_str().unwrap()]);
    assert!(o.status.success() && text(&o).contains("mapping with --backend analytic"), "{}", text(&o));
    for cmd in [&["trace", "--preset", "sp", "--wavelength-nm", "520", "--field-mm", "0,0"][..], &["distortion", "--preset", "sp", "--grid", "5"], &["dispersion", "--preset", "sp", "--wavelengths-nm", "450:650:4"]] {
        let mut a = cmd.to_vec();
        a.extend(["--tolerance-um", "1", "--calibration-cache", cache.to_str().unwrap()]);
        let o = run(&a);
        assert!(o.status.success() && text(&o).contains("fidelity: tolerance 1 µm →"), "{cmd:?}: {}", text(&o));
    }
    let rep = dir.path().join("report");
    let o = run(&["report", "--preset", "sp", "--out", rep.to_str().unwrap(), "--tolerance-um", "1", "--calibration-cache", cache.to_str().unwrap()]);
    assert!(o.status.success() && text(&o).contains("fidelity: tolerance 1 µm →") && rep.join("report.json").is_file(), "report: {}", text(&o));
    let out = dir.path().join("r");
    let o = run(&["render", "--preset", "sp", "--scene-size", "8", "--bands", "450,650", "--planes", "2", "--no-mapping", "--tolerance-um", "5", "--calibration-cache", cache.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(o.status.success() && text(&o).contains("--rays"), "{}", text(&o));
    let json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(out.join("render.json")).unwrap()).unwrap();
    assert!(json["rays_per_pixel"].as_u64().unwrap() >= 1);
}

#[test]
fn cli_tolerance_conflicts_and_bad_values_are_clear_errors() {
    for (args, says) in [
        (&["spot", "--preset", "sp", "--tolerance-um", "1", "--backend", "embree-user"][..], "--backend"),
        (&["distortion", "--preset", "sp", "--tolerance-um", "1", "--refine", "none"], "--refine"),
        (&["spot", "--preset", "sp", "--tolerance-um", "-2"], "must be finite and > 0"),
        (&["spot", "--preset", "sp", "--tolerance-um", "nan"], "must be finite and > 0"),
        (&["render", "--preset", "sp", "--scene-size", "4", "--tolerance-um", "5", "--rays", "8"], "--rays"),
        (&["bench", "--preset", "sp", "--csv", "x.csv"], "bench tradeoff"),
    ] {
        let o = run(args);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {}", text(&o));
        assert!(text(&o).contains(says), "{args:?}: {}", text(&o));
    }
}

#[test]
fn cli_bench_tradeoff_writes_the_interface_columns() {
    let dir = tempfile::tempdir().unwrap();
    let (csv, png) = (dir.path().join("t.csv"), dir.path().join("t.png"));
    // Fewer wavelengths than the documented run, to keep the suite fast; the columns are the interface.
    let o = run(&["bench", "tradeoff", "--quick", "--wavelengths", "3", "--repeat", "1", "--csv", csv.to_str().unwrap(), "--png", png.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o));
    let body = std::fs::read_to_string(&csv).unwrap();
    let mut lines = body.lines().filter(|l| !l.starts_with('#'));
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    for c in ["backend", "options", "error_max_um", "error_rms_um", "rays_per_s", "workload", "threads", "rays", "seconds", "mismatches"] {
        assert!(header.contains(&c), "{c} in {header:?}");
    }
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    for w in ["rays", "mapping", "render"] {
        assert!(rows.iter().any(|r| r[col("workload")] == w), "workload {w}");
    }
    for r in &rows {
        assert_eq!(r.len(), header.len());
        let e: f64 = r[col("error_max_um")].parse().unwrap();
        let rate: f64 = r[col("rays_per_s")].parse().unwrap();
        assert!(e.is_finite() && e >= 0.0 && rate > 0.0, "{r:?}");
    }
    // The analytic rows are the reference: zero error; unrefined meshes are not exact.
    assert!(rows.iter().filter(|r| r[col("backend")] == "analytic" && r[col("options")] == "f64").all(|r| r[col("error_max_um")].parse::<f64>().unwrap() == 0.0));
    if cfg!(feature = "embree") {
        let mesh = rows.iter().find(|r| r[col("workload")] == "rays" && r[col("options")] == "max-sag=10um;refine=none").unwrap();
        assert!(mesh[col("error_max_um")].parse::<f64>().unwrap() > 0.01);
    }
    assert_eq!(diffcassi::plot::png_dimensions(&png).unwrap().0, diffcassi::plot::FRONTIER_PANEL_SIZE.0);
}
