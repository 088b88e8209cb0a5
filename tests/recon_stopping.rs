//! The discrepancy-principle stopping rule (issue 22 item 3): it stops before the iteration cap where the
//! data are explained to the noise level, never where they cannot be (or where the rule is off); the record
//! says which rule ended the run; the CLI estimates δ from render.json (sensor noise, Monte-Carlo mismatch)
//! and records the rule, the estimate, the iteration and the reason; bad τ → a clear error, nothing written.
//! Tiny sizes throughout.
use diffcassi::prelude::*;
use diffcassi::recon::solver::{config_denoiser, reconstruct, SolverConfig};
use diffcassi::recon::{reconstruct_estimated, CubeShape, ExactOperator, ImageShape, MonteCarloSpread, Operator, ShiftOperator};
use diffcassi::render::{Mask, RenderConfig, Renderer, Sampling, SpectralSampling};
use diffcassi::scene::synthetic_scene;
use std::path::Path;
use std::process::{Command, Output};

/// A smooth cube with an edge (peak ≈ 0.9) through a shift operator, and y = Φx + n with n a fixed
/// pseudo-random pattern of norm `noise_rel`·‖Φx‖. Returns the operator, y and ‖n‖.
fn noisy_problem(noise_rel: f64) -> (ShiftOperator, Vec<f32>, f64) {
    let (h, w, bands) = (16, 16, 6);
    let shape = CubeShape { height: h, width: w, bands };
    let op = ShiftOperator::new(shape, ImageShape { height: h, width: w + 2 * (bands - 1) }, &Mask::random(h, w, 0.5, 5).unwrap(), 0, (0..bands as i64).map(|b| 2 * b).collect(), 1, 1).unwrap();
    let mut x = vec![0.0f32; shape.len()];
    for r in 0..h {
        for c in 0..w {
            for b in 0..bands {
                x[(r * w + c) * bands + b] = if c < w / 2 { 0.2 + 0.1 * b as f32 } else { 0.9 - 0.1 * b as f32 };
            }
        }
    }
    let clean = (&op as &dyn Operator).apply(&x).unwrap();
    // A deterministic zero-mean pattern (LCG), scaled to the wanted norm.
    let mut state = 12345u64;
    let n: Vec<f64> = clean
        .iter()
        .map(|_| {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((state >> 11) as f64 / (1u64 << 53) as f64) - 0.5
        })
        .collect();
    let clean_norm = clean.iter().map(|v| (*v as f64).powi(2)).sum::<f64>().sqrt();
    let n_norm = n.iter().map(|v| v * v).sum::<f64>().sqrt();
    let k = noise_rel * clean_norm / n_norm;
    let y: Vec<f32> = clean.iter().zip(&n).map(|(c, e)| (*c as f64 + k * e) as f32).collect();
    (op, y, noise_rel * clean_norm)
}

fn residual(op: &ShiftOperator, y: &[f32], x: &[f32]) -> f64 {
    let p = (op as &dyn Operator).apply(x).unwrap();
    y.iter().zip(&p).map(|(a, b)| ((*a - *b) as f64).powi(2)).sum::<f64>().sqrt()
}

/// Accelerated GAP with a weak TV fits the noise: the rule must end the run once ‖y − Φθ‖ ≤ τ·δ, before
/// the cap, and return an iterate that meets it (while the iterate before did not).
#[test]
fn discrepancy_stops_before_the_cap_when_the_noise_level_is_reached() {
    let (op, y, delta) = noisy_problem(0.05);
    for solver in [SolverConfig::gap_tv(), SolverConfig::admm_tv()] {
        let cfg = SolverConfig { iterations: 400, tv_weight: 0.01, accelerated: solver.solver.is_gap(), discrepancy: 1.0, noise_norm: delta, ..solver };
        let rec = reconstruct(&op, &y, None, &cfg, &|_, _| {}).unwrap();
        assert_eq!(rec.stopped_by, "discrepancy", "{:?}", cfg.solver);
        assert!(rec.iterations_run >= 1 && rec.iterations_run < 400, "{} iterations", rec.iterations_run);
        assert_eq!(rec.residuals.len(), rec.iterations_run);
        let r = residual(&op, &y, &rec.cube);
        assert!(r <= delta * (1.0 + 1e-4), "{:?}: residual {r} above δ = {delta}", cfg.solver);
        assert!((rec.final_residual * norm(&y) - r).abs() <= 1e-6 * r.max(1e-12) + 1e-9);
        // Without the rule the same run goes on to the cap.
        let off = reconstruct(&op, &y, None, &SolverConfig { discrepancy: 0.0, ..cfg.clone() }, &|_, _| {}).unwrap();
        assert_eq!((off.stopped_by.as_str(), off.iterations_run), ("iterations", 400));
        // The returned iterate is the off run's iterate of the same index (the rule only stops, never alters).
        let again = reconstruct(&op, &y, None, &SolverConfig { iterations: rec.iterations_run, discrepancy: 0.0, ..cfg.clone() }, &|_, _| {}).unwrap();
        assert_eq!(again.cube, rec.cube);
        // The iterate before the one returned was still above the threshold (GAP: residuals[k] is θ_k's).
        if cfg.solver.is_gap() && rec.iterations_run >= 2 {
            assert!(rec.residuals[rec.iterations_run - 1] * norm(&y) > delta);
        }
    }
}

fn norm(y: &[f32]) -> f64 {
    y.iter().map(|v| (*v as f64).powi(2)).sum::<f64>().sqrt()
}

/// Where the data cannot be explained to τ·δ (a strong TV's bias keeps the residual above a small δ), or
/// where the rule is off (τ = 0 or δ = 0), every iteration runs.
#[test]
fn discrepancy_never_stops_where_the_level_is_out_of_reach_or_the_rule_is_off() {
    let (op, y, delta) = noisy_problem(0.05);
    let strong = SolverConfig { iterations: 60, tv_weight: 2.0, discrepancy: 1.0, noise_norm: delta / 20.0, ..SolverConfig::gap_tv() };
    let rec = reconstruct(&op, &y, None, &strong, &|_, _| {}).unwrap();
    assert_eq!((rec.stopped_by.as_str(), rec.iterations_run), ("iterations", 60));
    assert!(rec.residuals.iter().all(|r| r * norm(&y) > delta / 20.0));
    for (tau, d) in [(0.0, delta), (1.0, 0.0)] {
        let cfg = SolverConfig { iterations: 80, tv_weight: 0.01, accelerated: true, discrepancy: tau, noise_norm: d, ..SolverConfig::gap_tv() };
        let rec = reconstruct(&op, &y, None, &cfg, &|_, _| {}).unwrap();
        assert_eq!((rec.stopped_by.as_str(), rec.iterations_run), ("iterations", 80), "τ = {tau}, δ = {d}");
    }
}

/// Bad τ / δ are clear errors naming the field.
#[test]
fn bad_discrepancy_settings_are_clear_errors() {
    let (op, y, _) = noisy_problem(0.05);
    for (cfg, needle) in [
        (SolverConfig { discrepancy: -1.0, ..SolverConfig::gap_tv() }, "discrepancy τ"),
        (SolverConfig { discrepancy: f64::NAN, ..SolverConfig::gap_tv() }, "discrepancy τ"),
        (SolverConfig { noise_norm: f64::INFINITY, ..SolverConfig::gap_tv() }, "noise norm δ"),
    ] {
        let e = reconstruct(&op, &y, None, &cfg, &|_, _| {}).unwrap_err().to_string();
        assert!(e.contains(needle), "{e}");
    }
}

fn bin(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_diffcassi")).args(args).output().expect("the binary runs")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn read_json(p: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap()
}

/// The CLI: `reconstruct.json` records the rule, τ, δ and its estimate (sensor noise from render.json's
/// `noise`, the Monte-Carlo term for another seed, none for the oracle), the cap, the iteration and the
/// reason; `--truth` adds the per-iteration PSNR; bad `--discrepancy` → exit 1, nothing written.
#[test]
fn cli_records_the_stopping_rule_and_its_noise_estimate() {
    let d = tempfile::tempdir().unwrap();
    let render = d.path().join("render");
    let o = bin(&["render", "--preset", "sp", "--scene-size", "12", "--bands", "450:650:4", "--planes", "4", "--rays", "2", "--no-mapping", "--noise", "shot,read", "--out", s(&render)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let rj = read_json(&render.join("render.json"));
    let k = rj["noise"]["electrons_per_unit"].as_f64().unwrap();
    let out = d.path().join("rec");
    let o = bin(&["reconstruct", "--from", s(&render), "--iterations", "5", "--out", s(&out)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let j = read_json(&out.join("reconstruct.json"));
    let st = &j["stopping"];
    for key in ["rule", "discrepancy_tau", "noise_norm", "discrepancy_threshold_relative", "noise_estimate", "iteration_cap", "stopped_by", "iterations_run"] {
        assert!(!st[key].is_null(), "stopping.{key} missing: {st}");
    }
    assert_eq!(st["iteration_cap"], 5);
    assert!(st["iterations_run"].as_u64().unwrap() <= 5);
    let est = &st["noise_estimate"];
    // Shot + read noise: Σ y/K + m (σ_e/K)² (the acquisition as written).
    let sensor = est["sensor_norm"].as_f64().unwrap();
    assert!(sensor > 0.0 && est["monte_carlo_norm"].as_f64().unwrap() > 0.0, "{est}");
    let total = est["norm"].as_f64().unwrap();
    assert!((total.powi(2) - sensor.powi(2) - est["monte_carlo_norm"].as_f64().unwrap().powi(2)).abs() <= 1e-9 * total.powi(2));
    assert!((st["noise_norm"].as_f64().unwrap() - total).abs() <= 1e-12 * total);
    // δ's Monte-Carlo term from the data by default (the operator's twin), the constant model on request.
    assert_eq!(est["estimator"], "monte-carlo-spread", "{est}");
    assert_eq!(st["noise_estimator"], "monte-carlo-spread");
    let twin_seed = est["spread"]["twin_seed"].as_u64().unwrap();
    assert!(twin_seed != j["operator_seed"].as_u64().unwrap() && twin_seed != j["acquisition_seed"].as_u64().unwrap());
    let per = st["noise_norm_per_estimate"].as_array().unwrap();
    assert!(!per.is_empty() && per[0][0] == 2, "{st}");
    assert_eq!(per.last().unwrap()[1].as_f64().unwrap(), total);
    let model = d.path().join("model");
    let o = bin(&["reconstruct", "--from", s(&render), "--iterations", "3", "--noise-estimate", "model", "--out", s(&model)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let jm = read_json(&model.join("reconstruct.json"));
    let em = &jm["stopping"]["noise_estimate"];
    assert_eq!((em["estimator"].as_str(), jm["stopping"]["noise_estimator"].as_str()), (Some("model"), Some("fixed")));
    assert!(em["monte_carlo_norm"].as_f64().unwrap() > 0.0 && em["monte_carlo_norm"] == em["monte_carlo_model_norm"]);
    assert!(jm["stopping"]["noise_norm_per_estimate"].as_array().unwrap().is_empty());
    let bad = d.path().join("badmodel");
    let o = bin(&["reconstruct", "--from", s(&render), "--iterations", "3", "--noise-estimate", "guess", "--out", s(&bad)]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("--noise-estimate") && !bad.exists(), "{}", stderr(&o));
    let read_e = rj["noise"]["read_noise_e"].as_f64().unwrap();
    assert!(sensor > read_e / k, "sensor δ {sensor} below one pixel's read noise");
    // The oracle (same seed, same rays): no Monte-Carlo term.
    let oracle = d.path().join("oracle");
    let o = bin(&["reconstruct", "--from", s(&render), "--iterations", "3", "--operator-seed", "same", "--out", s(&oracle)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let jo = read_json(&oracle.join("reconstruct.json"));
    assert_eq!(jo["stopping"]["noise_estimate"]["monte_carlo_norm"].as_f64(), Some(0.0));
    assert!((jo["stopping"]["noise_estimate"]["sensor_norm"].as_f64().unwrap() - sensor).abs() <= 1e-12 * sensor);
    // --discrepancy 0: off, every iteration runs; --truth records the PSNR of each iterate.
    let truth = d.path().join("truth.npy");
    let o = bin(&["make-scene", "--colour-checker", "--size", "12", "--bands", "450:650:4", "--out", s(&truth)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let off = d.path().join("off");
    let o = bin(&["reconstruct", "--from", s(&render), "--iterations", "4", "--discrepancy", "0", "--truth", s(&truth), "--out", s(&off)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let jf = read_json(&off.join("reconstruct.json"));
    assert_eq!((jf["stopping"]["stopped_by"].as_str(), jf["stopping"]["iterations_run"].as_u64()), (Some("iterations"), Some(4)));
    assert_eq!(jf["stopping"]["psnr_per_iteration"].as_array().unwrap().len(), 4);
    assert!(jf["stopping"]["truth_residual"].as_f64().unwrap() >= 0.0);
    // The estimator at the truth, beside the truth residual it estimates (noisy acquisition: both > 0).
    assert!(jf["stopping"]["truth_spread_estimate"].as_f64().unwrap() > 0.0);
    // Bad τ: exit 1, nothing written.
    for bad in ["-1", "NaN"] {
        let o2 = d.path().join(format!("bad{bad}"));
        let o = bin(&["reconstruct", "--from", s(&render), "--iterations", "2", &format!("--discrepancy={bad}"), "--out", s(&o2)]);
        assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
        assert!(stderr(&o).contains("--discrepancy"), "{}", stderr(&o));
        assert!(!o2.exists());
    }
}

// ---- δ estimated from the data (issue 22): the exact operator's spread against its twin ----

/// A tiny exact operator of SP: `size`² scene, 4 bands × 2 planes, `rays` rays per pixel per plane, `seed`.
fn exact_op(system: &'static SequentialSystem, tracer: &'static AnalyticTracer, size: usize, rays: usize, seed: u64, sampling: Sampling) -> ExactOperator<'static> {
    let mut cfg = RenderConfig::paper(size);
    cfg.spectral = SpectralSampling::new(vec![480.0, 530.0, 580.0, 630.0], 2).unwrap();
    cfg.rays_per_pixel = rays;
    cfg.sampling = sampling;
    cfg.seed = seed;
    let r = Renderer::new(system, tracer, cfg, Mask::random(size, size, 0.5, 7).unwrap()).unwrap();
    ExactOperator::new(r, &[480.0, 530.0, 580.0, 630.0], 1 << 30).unwrap()
}

/// SP and the analytic tracer, leaked once per test (the operators borrow them for `'static`).
fn sp() -> (&'static SequentialSystem, &'static AnalyticTracer) {
    (Box::leak(Box::new(SequentialSystem::build(&presets::spec("sp").unwrap()).unwrap())), Box::leak(Box::new(AnalyticTracer::default())))
}

fn dist(a: &[f32], b: &[f32]) -> f64 {
    a.iter().zip(b).map(|(x, y)| ((*x - *y) as f64).powi(2)).sum::<f64>().sqrt()
}

/// Unbiased against a known Monte-Carlo mismatch: over independent seed triples (acquisition Φ_a, operator
/// Φ_o, twin Φ'), E[factor²·‖(Φ_o − Φ')x‖²] = E‖(Φ_a − Φ_o)x‖² — for equal ray counts (factor 1, any
/// sampling) and for R_o = 4 R_a (factor ((1 + 4)/2)^½, independent sampling: variance ∝ 1/R). The means of
/// the two over 12 triples agree within 20 % (each a sum over every pixel and plane), while a wrong factor
/// (1 for the unequal case) is 2.5× off.
#[test]
fn spread_estimate_is_unbiased_against_the_monte_carlo_mismatch() {
    let (system, tracer) = sp();
    let x = synthetic_scene(12, 12, &[480.0, 530.0, 580.0, 630.0], 3).data;
    for (ra, ro, sampling) in [(4, 4, Sampling::Stratified), (2, 8, Sampling::Independent)] {
        let factor = MonteCarloSpread::factor_for(ra, ro);
        let (mut truth_sq, mut est_sq, mut plain_sq) = (0.0, 0.0, 0.0);
        for t in 0..12u64 {
            let a = exact_op(system, tracer, 12, ra, 100 + 3 * t, sampling);
            let o = exact_op(system, tracer, 12, ro, 101 + 3 * t, sampling);
            let twin = exact_op(system, tracer, 12, ro, 102 + 3 * t, sampling);
            let (ya, yo) = ((&a as &dyn Operator).apply(&x).unwrap(), (&o as &dyn Operator).apply(&x).unwrap());
            truth_sq += dist(&ya, &yo).powi(2);
            let spread = MonteCarloSpread { twin: &twin, factor, sensor_norm: 0.0, every: 1 };
            let mc = spread.monte_carlo(&x, &yo, &mut Vec::new());
            est_sq += mc * mc;
            plain_sq += (mc / factor).powi(2);
        }
        let ratio = est_sq / truth_sq;
        assert!((0.8..=1.25).contains(&ratio), "R_a {ra}, R_o {ro}: E[δ̂²]/E‖y − Φ_o x‖² = {ratio}");
        if ra != ro {
            assert!(plain_sq / truth_sq < 0.5, "without the factor: {}", plain_sq / truth_sq);
        }
    }
}

/// The data-driven rule at two tiny sizes: GAP-TV on a noiseless acquisition (seed 1) with the operator
/// (seed 2) and its twin (seed 3) stops by the discrepancy rule at a θ with ‖y − Φθ‖ ≤ τ·δ̂ (δ̂ the last
/// estimate), records every estimate (iterations 2, 2 + every, …), and δ̂ tracks the truth residual
/// ‖y − Φ_o x‖ at each size (within a factor 2); the same run with the rule off goes to the cap, and is the
/// same iterate up to the stop (the rule only stops). Deterministic: 1 and 2 threads give the same bits (iterates and every δ̂).
#[test]
fn spread_rule_stops_at_two_sizes_and_is_thread_independent() {
    let (system, tracer) = sp();
    for size in [12usize, 20] {
        let x = synthetic_scene(size, size, &[480.0, 530.0, 580.0, 630.0], 5).data;
        let a = exact_op(system, tracer, size, 4, 1, Sampling::Stratified);
        let y = (&a as &dyn Operator).apply(&x).unwrap();
        let o = exact_op(system, tracer, size, 4, 2, Sampling::Stratified);
        let twin = exact_op(system, tracer, size, 4, 3, Sampling::Stratified);
        let spread = MonteCarloSpread { twin: &twin, factor: 1.0, sensor_norm: 0.0, every: 3 };
        let truth = dist(&y, &(&o as &dyn Operator).apply(&x).unwrap());
        let cfg = SolverConfig { iterations: 150, tv_weight: 0.02, discrepancy: 1.0, noise_norm: 0.0, ..SolverConfig::gap_tv() };
        let run = |cfg: &SolverConfig, threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| {
                let mut d = config_denoiser(cfg).unwrap();
                reconstruct_estimated(&o, &y, None, cfg, d.as_mut(), &|_, _| {}, &mut |_, _| {}, Some(&spread)).unwrap()
            })
        };
        let rec = run(&cfg, 2);
        assert_eq!(rec.stopped_by, "discrepancy", "size {size}: {} iterations", rec.iterations_run);
        let ks: Vec<usize> = rec.noise_estimates.iter().map(|(k, _)| *k).collect();
        assert_eq!(ks, (0..ks.len()).map(|i| 2 + 3 * i).collect::<Vec<_>>());
        let last = rec.noise_estimates.last().unwrap().1;
        assert_eq!(rec.noise_norm, last);
        let r = dist(&y, &(&o as &dyn Operator).apply(&rec.cube).unwrap());
        assert!(r <= last * (1.0 + 1e-5), "size {size}: residual {r} above δ̂ {last}");
        assert!(last > 0.5 * truth && last < 2.0 * truth, "size {size}: δ̂ {last}, truth residual {truth}");
        let one = run(&cfg, 1);
        assert_eq!(one.cube, rec.cube);
        assert_eq!(one.noise_estimates, rec.noise_estimates);
        // The rule off (τ = 0): the estimates are still recorded, the cap ends the run, same iterate at the stop.
        let off = run(&SolverConfig { discrepancy: 0.0, ..cfg.clone() }, 2);
        assert_eq!((off.stopped_by.as_str(), off.iterations_run), ("iterations", 150));
        assert_eq!(off.noise_estimates[..ks.len()], rec.noise_estimates[..]);
        let again = run(&SolverConfig { iterations: rec.iterations_run, discrepancy: 0.0, ..cfg.clone() }, 2);
        assert_eq!(again.cube, rec.cube);
        // ADMM takes the same estimator.
        let admm = SolverConfig { iterations: 150, tv_weight: 0.02, discrepancy: 1.0, ..SolverConfig::admm_tv() };
        let ra = run(&admm, 2);
        assert!(!ra.noise_estimates.is_empty() && ra.noise_estimates[0].0 == 2);
    }
}

/// Bad estimator settings are clear errors: a twin of another shape, a non-finite factor, period 0.
#[test]
fn bad_spread_settings_are_clear_errors() {
    let (system, tracer) = sp();
    let o = exact_op(system, tracer, 12, 2, 2, Sampling::Stratified);
    let small = exact_op(system, tracer, 10, 2, 3, Sampling::Stratified);
    let twin = exact_op(system, tracer, 12, 2, 3, Sampling::Stratified);
    let y = vec![1.0f32; o.image_shape().len()];
    let cfg = SolverConfig { iterations: 3, ..SolverConfig::gap_tv() };
    for (spread, needle) in [
        (MonteCarloSpread { twin: &small, factor: 1.0, sensor_norm: 0.0, every: 1 }, "other shapes"),
        (MonteCarloSpread { twin: &twin, factor: f64::NAN, sensor_norm: 0.0, every: 1 }, "factor"),
        (MonteCarloSpread { twin: &twin, factor: 1.0, sensor_norm: -1.0, every: 1 }, "sensor norm"),
        (MonteCarloSpread { twin: &twin, factor: 1.0, sensor_norm: 0.0, every: 0 }, "period"),
    ] {
        let mut d = config_denoiser(&cfg).unwrap();
        let e = reconstruct_estimated(&o, &y, None, &cfg, d.as_mut(), &|_, _| {}, &mut |_, _| {}, Some(&spread)).unwrap_err().to_string();
        assert!(e.contains(needle), "{e}");
    }
}
