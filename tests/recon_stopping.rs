//! The discrepancy-principle stopping rule (issue 22 item 3): it stops before the iteration cap where the
//! data are explained to the noise level, never where they cannot be (or where the rule is off); the record
//! says which rule ended the run; the CLI estimates δ from render.json (sensor noise, Monte-Carlo mismatch)
//! and records the rule, the estimate, the iteration and the reason; bad τ → a clear error, nothing written.
//! Tiny sizes throughout.
use diffcassi::recon::solver::{reconstruct, SolverConfig};
use diffcassi::recon::{CubeShape, ImageShape, Operator, ShiftOperator};
use diffcassi::render::Mask;
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
    // Bad τ: exit 1, nothing written.
    for bad in ["-1", "NaN"] {
        let o2 = d.path().join(format!("bad{bad}"));
        let o = bin(&["reconstruct", "--from", s(&render), "--iterations", "2", &format!("--discrepancy={bad}"), "--out", s(&o2)]);
        assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
        assert!(stderr(&o).contains("--discrepancy"), "{}", stderr(&o));
        assert!(!o2.exists());
    }
}
