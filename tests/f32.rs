//! The f32 render mode (issue 15, item 2): the f32 lane kernel against the exact f64 tracer on every
//! preset (image-plane error bound, status agreement with the borderline cases counted), the same f32
//! bits on every dispatch level and thread count, no NaN from unreliable inputs, renders and the mapping
//! cube in f32 close to f64, `--tolerance-um` choosing f32 for a loose render tolerance and not for a
//! tight one (and never for ray jobs), and the command line (`--precision`, its errors, `render.json`).
use diffcassi::analysis::{self, linspace};
use diffcassi::fidelity::{self, CacheOptions};
use diffcassi::prelude::*;
use diffcassi::render::{Mask, RenderConfig, Renderer, SpectralSampling};
use diffcassi::tracer::{AnalyticF32Tracer, Kernel, Precision, RayStatus, SimdLevel, TracedBatch};
use glam::DVec3;
use std::process::{Command, Output};

/// Largest image-plane distance (µm) between the f32 and the f64 landing of a ray that arrives in both,
/// over every preset's seeded workload. Measured 0.012 (sp) – 0.018 µm (msp, map); see
/// `docs/performance.md` ("f32 mode").
const F32_MAX_ERROR_UM: f64 = 0.05;
/// Largest fraction of rays whose status differs between f32 and f64 (rays within f32 rounding of an
/// aperture edge, the conic's domain or the critical angle). Measured: 0 of 20 000 per preset.
const F32_MAX_MISMATCH_FRACTION: f64 = 1e-4;

fn system(name: &str) -> SequentialSystem {
    SequentialSystem::build(&presets::spec(name).unwrap()).unwrap()
}

fn f32_tracer() -> Box<dyn Tracer> {
    Precision::F32.tracer(Kernel::default()).unwrap()
}

/// (max error µm, rms µm, rays compared, status mismatches) of `b` against `a`.
fn compare(a: &TracedBatch, b: &TracedBatch) -> (f64, f64, usize, usize) {
    let (mut max, mut s2, mut n, mut mismatches) = (0.0f64, 0.0, 0, 0);
    for i in 0..a.len() {
        match (a.status[i] == RayStatus::Ok, b.status[i] == RayStatus::Ok) {
            (true, true) => {
                let e = 1e3 * (a.x[i] - b.x[i]).hypot(a.y[i] - b.y[i]);
                max = max.max(e);
                s2 += e * e;
                n += 1;
            }
            (false, false) => {}
            _ => mismatches += 1,
        }
    }
    (max, if n > 0 { (s2 / n as f64).sqrt() } else { 0.0 }, n, mismatches)
}

#[test]
fn f32_agrees_with_f64_on_every_preset() {
    let ws = linspace(450.0, 650.0, 5);
    let mut worst: f64 = 0.0;
    for name in presets::NAMES {
        let sys = system(name);
        let batch = RayBatch::seeded_workload(&sys, 4000, &ws, 7).unwrap();
        let reference = AnalyticTracer::default().trace(&sys, &batch).unwrap();
        let out = f32_tracer().trace(&sys, &batch).unwrap();
        let (max, rms, n, mismatches) = compare(&reference, &out);
        println!("{name}: {n} rays compared, f32 vs f64 max {max:.4} µm, rms {rms:.4} µm, {mismatches} status mismatches of {}", batch.len());
        assert!(n > batch.len() / 4, "{name}: too few rays arrived ({n})");
        assert!(max <= F32_MAX_ERROR_UM, "{name}: f32 error {max} µm > {F32_MAX_ERROR_UM}");
        assert!(mismatches as f64 <= F32_MAX_MISMATCH_FRACTION * batch.len() as f64, "{name}: {mismatches} status mismatches");
        // Rays that did not arrive in both stop at the same surface with the same status, but for the
        // mismatches counted above.
        let differ = (0..batch.len()).filter(|&i| reference.status[i] != RayStatus::Ok && out.status[i] != RayStatus::Ok && (reference.status[i], reference.surface[i]) != (out.status[i], out.surface[i])).count();
        assert!(differ as f64 <= F32_MAX_MISMATCH_FRACTION * batch.len() as f64, "{name}: {differ} rays stopped differently");
        for i in 0..out.len() {
            assert!(out.x[i].is_finite() && out.y[i].is_finite() && out.z[i].is_finite() && out.dir_x[i].is_finite(), "{name}: ray {i} not finite");
        }
        worst = worst.max(max);
    }
    // The bound is not vacuous: f32 does differ from f64.
    assert!(worst > 0.0);
}

#[test]
fn f32_results_are_the_same_on_every_level_and_thread_count() {
    let ws = [450.0, 560.0, 650.0];
    for name in ["sp", "map"] {
        let sys = system(name);
        let batch = RayBatch::seeded_workload(&sys, 777, &ws, 3).unwrap();
        let want = AnalyticF32Tracer::new(SimdLevel::Portable).trace(&sys, &batch).unwrap();
        for level in SimdLevel::available() {
            for (threads, chunk) in [(1, 4096), (2, 13), (2, 100)] {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
                let t = AnalyticF32Tracer { chunk_size: chunk, level };
                let got = pool.install(|| t.trace(&sys, &batch)).unwrap();
                assert_eq!(got, want, "{name} {} threads {threads} chunk {chunk}", level.name());
            }
        }
    }
}

#[test]
fn f32_classifies_unreliable_and_invalid_inputs_and_never_outputs_nan() {
    let sys = system("sp");
    let good = RayBatch::chief_rays(&sys, &[[0.3, -0.2]], 520.0).unwrap();
    let (o, d) = (good.origin(0), good.direction(0));
    let cases: Vec<(DVec3, DVec3, Option<RayStatus>)> = vec![
        (o, d, Some(RayStatus::Ok)),
        (o, d * 1e-200, Some(RayStatus::Ok)), // any non-zero length is a direction
        (o, d * 1e200, Some(RayStatus::Ok)),
        (o, DVec3::ZERO, Some(RayStatus::InvalidInput)),
        (o, DVec3::new(f64::NAN, 0.0, 1.0), Some(RayStatus::InvalidInput)),
        (DVec3::new(f64::INFINITY, 0.0, 0.0), d, Some(RayStatus::InvalidInput)),
        // f32 cannot carry an origin 10 m off to the µm: an invalid input, not a wrong landing.
        (o + DVec3::new(1e4, 0.0, 0.0), d, Some(RayStatus::InvalidInput)),
        (o + DVec3::new(0.0, 0.0, 1e30), d, Some(RayStatus::InvalidInput)),
        (o, DVec3::new(1.0, 0.0, 0.0), None), // grazing: whatever the status, no NaN
        (o, DVec3::new(0.0, 0.3, -1.0), None),
    ];
    let mut batch = RayBatch::with_capacity(cases.len());
    for (o, d, _) in &cases {
        batch.push(*o, *d, 520.0);
    }
    let out = f32_tracer().trace(&sys, &batch).unwrap();
    for (i, (_, _, want)) in cases.iter().enumerate() {
        if let Some(w) = want {
            assert_eq!(out.status[i], *w, "case {i}");
        }
        for v in [out.x[i], out.y[i], out.z[i], out.dir_x[i], out.dir_y[i], out.dir_z[i]] {
            assert!(v.is_finite(), "case {i}: {v}");
        }
    }
    // The ordinary ray lands where f64 puts it.
    let reference = AnalyticTracer::default().trace(&sys, &batch).unwrap();
    assert!(1e3 * (out.x[0] - reference.x[0]).hypot(out.y[0] - reference.y[0]) <= F32_MAX_ERROR_UM);
}

#[test]
fn f32_mapping_cube_is_close_to_f64() {
    let sys = system("sp");
    let ws = linspace(450.0, 650.0, 4);
    let exact = analysis::mapping_cube(&sys, &AnalyticTracer::default(), 24, 20, 0.01, &ws).unwrap();
    let fast = analysis::mapping_cube(&sys, f32_tracer().as_ref(), 24, 20, 0.01, &ws).unwrap();
    assert_eq!(exact.valid, fast.valid);
    let max = exact.positions_mm.iter().zip(&fast.positions_mm).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
    println!("mapping 24×20×4: f32 vs f64 max |Δ| {:.2e} mm", max);
    assert!(max * 1e3 <= F32_MAX_ERROR_UM && max > 0.0);
}

fn small_config(size: usize) -> RenderConfig {
    let mut c = RenderConfig::paper(size);
    c.spectral = SpectralSampling::new(vec![450.0, 550.0, 650.0], 2).unwrap();
    c.rays_per_pixel = 8;
    c
}

#[test]
fn f32_render_is_close_to_f64_and_thread_independent() {
    let sys = system("sp");
    let tracer = AnalyticTracer::default();
    let scene = diffcassi::scene::synthetic_scene(24, 24, &[450.0, 550.0, 650.0], 5);
    let mask = Mask::random(24, 24, 0.5, 1).unwrap();
    let f64_acq = Renderer::new(&sys, &tracer, small_config(24), mask.clone()).unwrap().render(&scene, false, &|_| {}).unwrap();
    let cfg = RenderConfig { precision: Precision::F32, ..small_config(24) };
    let mut images = Vec::new();
    for threads in [1, 2] {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        let r = Renderer::new(&sys, &tracer, cfg.clone(), mask.clone()).unwrap();
        let acq = pool.install(|| r.render(&scene, false, &|_| {})).unwrap();
        assert_eq!(acq.stats.traced, f64_acq.stats.traced);
        images.push(acq);
    }
    assert_eq!(images[0].image, images[1].image, "f32 render depends on the thread count");
    let a = &images[0];
    let peak = f64_acq.image.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let diff = a.image.iter().zip(&f64_acq.image).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
    println!("f32 render vs f64: max |Δ| {diff:.3e} = {:.3e} of the peak; arrived {} vs {}", diff / peak, a.stats.arrived, f64_acq.stats.arrived);
    // A landing moved by ≤ 0.1 µm moves a bilinear splat weight by ≤ 0.1 µm / 10 µm pixel = 1 % of one
    // ray's weight; a pixel collects several rays, so the image differs by far less than 1e-2 of its peak.
    assert!(diff <= 1e-3 * peak, "{diff} vs peak {peak}");
    assert!(diff > 0.0, "f32 and f64 renders are identical: was f32 used?");
    assert!(a.stats.arrived.abs_diff(f64_acq.stats.arrived) as f64 <= F32_MAX_MISMATCH_FRACTION * a.stats.traced as f64 + 1.0);
}

#[test]
fn f32_render_refuses_the_scalar_kernel_and_the_batched_path() {
    let sys = system("sp");
    let tracer = AnalyticTracer::default();
    let mask = Mask::open(8, 8);
    let scalar = RenderConfig { precision: Precision::F32, kernel: Kernel::Scalar, ..small_config(8) };
    let e = Renderer::new(&sys, &tracer, scalar, mask.clone()).err().expect("scalar f32 is refused").to_string();
    assert!(e.contains("SIMD"), "{e}");
    let batched = RenderConfig { precision: Precision::F32, force_batched: true, ..small_config(8) };
    assert!(Renderer::new(&sys, &tracer, batched, mask).is_err());
}

#[test]
fn tolerance_picks_f32_for_a_loose_render_tolerance_and_not_for_a_tight_one() {
    let sys = system("sp");
    let cfg = small_config(32);
    let (mut cal, _) = fidelity::calibrate_backends(&sys, &cfg.spectral.planes_nm, &CacheOptions::none()).unwrap();
    let f32_err = cal.candidates.iter().find(|m| m.backend == "analytic-f32").expect("f32 is a candidate").error;
    println!("calibration: analytic-f32 max {:.4} µm, rms {:.4} µm, {} mismatches", f32_err.max_um, f32_err.rms_um, f32_err.mismatches);
    assert!(f32_err.mismatches == 0 && f32_err.max_um > 0.0 && f32_err.max_um <= F32_MAX_ERROR_UM);
    // Throughput on a shared machine is noisy: fix it (f32 twice the analytic f64, the others slower) so
    // the test checks the selection rule, with the errors as measured.
    for m in &mut cal.candidates {
        m.rays_per_s = match m.backend.as_str() {
            "analytic" => 1e7,
            "analytic-f32" => 2e7,
            _ => 1e6,
        };
        m.setup_seconds = 0.0;
    }
    let (rc, _) = fidelity::calibrate_render(&sys, &cfg, &CacheOptions::none()).unwrap();
    let per_n = 32 * 32 * cfg.spectral.planes() as u64;
    let loose = fidelity::choose_render(&cal, &rc, 5.0, per_n).unwrap();
    println!("{}", loose.explanation);
    assert_eq!(loose.config.backend, diffcassi::tracer::Backend::AnalyticF32);
    // A tight tolerance, just above f32's error: f32 leaves almost no room for the Monte-Carlo error
    // σ/√N and would need far more rays than f64, so f64 is chosen. (With this render's σ ≈ 11 µm such a
    // tolerance needs more than the 4096 rays per pixel allowed, so the rule is checked on a render
    // whose pixel landings spread 100× less.)
    let small_sigma = fidelity::RenderCalibration { sigma_um: rc.sigma_um / 100.0 };
    let tight = fidelity::choose_render(&cal, &small_sigma, f32_err.max_um * 1.3, per_n).unwrap();
    println!("{}", tight.explanation);
    assert_eq!(tight.config.backend, diffcassi::tracer::Backend::Analytic);
    // Below f32's error it is never a candidate; ray jobs (compared to Zemax) never choose it at all.
    let below = fidelity::choose_render(&cal, &small_sigma, f32_err.max_um * 0.9, per_n).unwrap();
    assert_ne!(below.config.backend, diffcassi::tracer::Backend::AnalyticF32);
    for tol in [10.0, 1.0] {
        let c = fidelity::choose_backend(&cal, tol, 1_000_000).unwrap();
        assert_ne!(c.config.backend, diffcassi::tracer::Backend::AnalyticF32, "{}", c.explanation);
    }
}

/// A render's calibration covers its scene's field, not only the system's fields (round 13): a lens file with an
/// axial field only was calibrated on the axis, where f32's rounding is smallest, and the chooser predicted a
/// third of the f32 error the render's rays then had at the scene's edge.
#[test]
fn the_render_calibration_covers_the_scene_beyond_the_systems_fields() {
    // SP with a 950 mm gap before its doublet (f32's rounding grows with the coordinates the rays carry;
    // tests/bad_input_round12.rs) and an axial field only.
    let mut spec = serde_json::to_value(presets::spec("sp").unwrap()).unwrap();
    spec["fields_mm"] = serde_json::json!([[0.0, 0.0]]);
    spec["surfaces"][15]["thickness_mm"] = 950.0.into();
    for k in 16..=19 {
        spec["surfaces"][k]["semi_diameter_mm"] = 20.0.into();
        if spec["surfaces"][k]["aperture"].is_object() {
            spec["surfaces"][k]["aperture"]["semi_diameter_mm"] = 20.0.into();
        }
    }
    let sys = SequentialSystem::build(&serde_json::from_value(spec).unwrap()).unwrap();
    let cfg = small_config(256); // ±1.28 mm
    let half = 256.0 * cfg.scene_pitch_mm / 2.0;
    // The calibration's ray sets, traced in both precisions (what `calibrate_backends` measures f32 on).
    let f32_error = |set: fidelity::RaySetSpec| {
        let rays = set.build(&sys, &cfg.spectral.planes_nm).unwrap();
        let (max, _, n, mismatches) = compare(&AnalyticTracer::default().trace(&sys, &rays).unwrap(), &f32_tracer().trace(&sys, &rays).unwrap());
        // (Most of the wide set is vignetted by the long system's doublet: compared where both arrive.)
        assert!(n > 100 && mismatches == 0, "{n} of {} arrived, {mismatches} mismatches", rays.len());
        (max, n)
    };
    let (axis, axis_rays) = f32_error(fidelity::RaySetSpec::calibration());
    let (scene, scene_rays) = f32_error(fidelity::RaySetSpec::calibration().covering(&sys, half));
    let level = Precision::F32.level(Kernel::default()).unwrap();
    let chief = diffcassi::render::measure_f32_error(&sys, 256, 256, cfg.scene_pitch_mm, &cfg.spectral.planes_nm, level).unwrap();
    println!("f32 max error: the system's calibration set {axis:.4} µm ({axis_rays} rays arriving), over the scene {scene:.4} µm ({scene_rays} rays arriving); the render's chief-ray check {:.4} µm", chief.error_um);
    assert!(scene_rays > axis_rays);
    assert!(scene > 2.0 * axis, "the scene's edge rounds worse than the axis: {scene} vs {axis} µm");
    assert!(scene >= chief.error_um, "the calibration ({scene} µm) must not predict less than the render's own check measures ({} µm)", chief.error_um);
    // A job inside the system's fields keeps the system's set (and its cache key).
    let sp = system("sp");
    assert_eq!(fidelity::RaySetSpec::calibration().covering(&sp, 1.0), fidelity::RaySetSpec::calibration());
    assert_ne!(fidelity::RaySetSpec::calibration().covering(&sp, 1e3), fidelity::RaySetSpec::calibration());
    // The chooser calibrates over its scene: SP at 64 px of 0.1 mm (±3.2 mm, beyond SP's fields) leaves the
    // covering calibration in the cache, not the system's.
    let dir = tempfile::tempdir().unwrap();
    let cache = CacheOptions { dir: Some(dir.path().to_path_buf()) };
    let mut wide = small_config(64);
    wide.scene_pitch_mm = 0.1;
    fidelity::choose_render_for(&sp, &wide, diffcassi::render::Device::Cpu, 50.0, 64 * 64, &cache).unwrap();
    let (over, p) = fidelity::calibrate_backends_over(&sp, &wide.spectral.planes_nm, Some(3.2), &cache).unwrap();
    assert!(matches!(p, fidelity::Provenance::Cached(_)), "{p:?}");
    let (own, p) = fidelity::calibrate_backends(&sp, &wide.spectral.planes_nm, &cache).unwrap();
    assert!(matches!(p, fidelity::Provenance::Measured { .. }) && over.rays > own.rays, "{p:?}");
}

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_diffcassi"))
}

fn run(args: &[&str]) -> Output {
    bin().args(args).output().expect("the binary runs")
}

#[test]
fn cli_render_precision_f32_writes_a_close_acquisition_and_records_it() {
    let d = tempfile::tempdir().unwrap();
    let mut images = Vec::new();
    for p in ["f64", "f32"] {
        let out = d.path().join(p);
        let o = run(&["render", "--preset", "sp", "--scene-size", "16", "--planes", "4", "--rays", "4", "--precision", p, "--out", out.to_str().unwrap()]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let j: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(out.join("render.json")).unwrap()).unwrap();
        assert_eq!(j["precision"], p);
        for key in ["seconds_render", "seconds_total", "rays_traced"] {
            assert!(j.get(key).is_some(), "{key} missing");
        }
        assert!(out.join("mapping.npy").exists());
        images.push(diffcassi::io::exr::read_exr(out.join("acquisition.exr")).unwrap().channels.remove(0).data);
    }
    let peak = images[0].iter().fold(0.0f32, |m, v| m.max(v.abs()));
    let diff = images[0].iter().zip(&images[1]).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
    assert!(peak > 0.0 && diff <= 1e-3 * peak, "max |Δ| {diff} vs peak {peak}");
}

#[test]
fn cli_precision_errors_are_clear() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("x");
    let o = run(&["render", "--preset", "sp", "--precision", "f16", "--out", out.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2), "a bad --precision is a usage error");
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(e.contains("f16") && e.contains("f64 or f32"), "{e}");
    let npy = d.path().join("m.npy");
    for (args, code, needle) in [
        (vec!["render", "--preset", "sp", "--scene-size", "8", "--precision", "f32", "--kernel", "scalar", "--out", out.to_str().unwrap()], 1, "SIMD"),
        (vec!["spot", "--preset", "sp", "--backend", "analytic-f32"], 1, "f64"),
        (vec!["mapping", "--preset", "sp", "--height", "4", "--width", "4", "--npy", npy.to_str().unwrap(), "--precision", "f32", "--backend", "analytic"], 1, "--precision f32"),
        (vec!["bench-render", "--preset", "sp", "--scene-size", "4", "--planes", "2", "--rays", "1", "--precisions", "f16"], 1, "f16"),
        (vec!["spot", "--preset", "sp", "--precision", "f32"], 2, "--precision"),
    ] {
        let o = run(&args);
        assert_eq!(o.status.code(), Some(code), "{args:?}: {}", String::from_utf8_lossy(&o.stderr));
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(e.contains(needle), "{args:?}: {e}");
    }
    assert!(!out.exists(), "no half-written output");
    // The mapping command in f32 works and writes its cube.
    let o = run(&["mapping", "--preset", "sp", "--height", "4", "--width", "5", "--wavelengths-nm", "500,600", "--npy", npy.to_str().unwrap(), "--precision", "f32"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(npy.exists());
}
