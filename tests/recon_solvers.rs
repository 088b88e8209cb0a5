//! Solvers (issue 13): the preconditioned projection never increases the data term ‖y − Φx‖_{D⁻¹} on a
//! noiseless problem, and GAP-TV / ADMM-TV recover a small noiseless synthetic scene through each operator
//! (exact, mapping nearest/bilinear, shift) that produced its measurement.
use diffcassi::prelude::*;
use diffcassi::recon::{reconstruct, ExactOperator, MappingInterpolation, MappingOperator, Operator, ShiftOperator, SolverConfig, SolverKind};
use diffcassi::render::{Mask, RenderConfig, Renderer, SpectralSampling};
use diffcassi::scene::synthetic_scene;

const SIZE: usize = 32;

fn bands() -> Vec<f64> {
    diffcassi::analysis::linspace(450.0, 650.0, 6)
}

fn config() -> RenderConfig {
    let mut cfg = RenderConfig::paper(SIZE);
    cfg.spectral = SpectralSampling::new(bands(), 2).unwrap();
    cfg.rays_per_pixel = 4;
    cfg.seed = 17;
    cfg
}

/// PSNR (dB) with one MSE over the cube and peak = max of the truth (the paper's convention).
fn psnr(truth: &[f32], est: &[f32]) -> f64 {
    let mse = truth.iter().zip(est).map(|(a, b)| ((a - b) as f64).powi(2)).sum::<f64>() / truth.len() as f64;
    let peak = truth.iter().cloned().fold(0.0f32, f32::max) as f64;
    10.0 * (peak * peak / mse).log10()
}

fn operators<'a>(renderer: Renderer<'a>, mk: &dyn Fn() -> Renderer<'a>) -> Vec<Box<dyn Operator + 'a>> {
    let r2 = mk();
    vec![
        Box::new(MappingOperator::from_renderer(&r2, &bands(), MappingInterpolation::Nearest).unwrap()),
        Box::new(MappingOperator::from_renderer(&r2, &bands(), MappingInterpolation::Bilinear).unwrap()),
        Box::new(ShiftOperator::from_renderer(&r2, &bands()).unwrap()),
        Box::new(ExactOperator::new(renderer, &bands(), 1 << 32).unwrap()),
    ]
}

#[test]
fn projection_never_increases_the_weighted_data_term() {
    let tracer = AnalyticTracer::default();
    let system = SequentialSystem::build(&presets::spec("sp").unwrap()).unwrap();
    let mask = Mask::random(SIZE, SIZE, 0.5, 3).unwrap();
    let mk = || Renderer::new(&system, &tracer, config(), mask.clone()).unwrap();
    let truth = synthetic_scene(SIZE, SIZE, &bands(), 4).data;
    for op in operators(mk(), &mk) {
        let y = op.apply(&truth).unwrap();
        for step in [1.0f32, 1.9] {
            let cfg = SolverConfig { iterations: 40, tv_weight: 0.0, accelerated: false, step, ..SolverConfig::gap_tv() };
            let rec = reconstruct(op.as_ref(), &y, None, &cfg, &|_, _| {}).unwrap();
            let w = &rec.weighted_residuals;
            let worst = w.windows(2).map(|p| p[1] / p[0]).fold(0.0, f64::max);
            println!("{} λ={step}: weighted residual {:.3e} → {:.3e}, largest ratio between iterations {worst:.6}", op.name(), w[0], w[w.len() - 1]);
            assert!(w.windows(2).all(|p| p[1] <= p[0]), "{}: the D⁻¹-weighted data term increased: {w:?}", op.name());
            assert!(w[w.len() - 1] < 0.5 * w[0], "{}: no progress {w:?}", op.name());
        }
    }
}

#[test]
fn gap_tv_and_admm_tv_recover_a_noiseless_scene_through_each_operator() {
    let tracer = AnalyticTracer::default();
    let system = SequentialSystem::build(&presets::spec("ap").unwrap()).unwrap();
    let mask = Mask::random(SIZE, SIZE, 0.5, 3).unwrap();
    let mk = || Renderer::new(&system, &tracer, config(), mask.clone()).unwrap();
    let truth = synthetic_scene(SIZE, SIZE, &bands(), 4).data;
    for op in operators(mk(), &mk) {
        let y = op.apply(&truth).unwrap();
        let mean = truth.iter().sum::<f32>() / truth.len() as f32;
        let floor = psnr(&truth, &vec![mean; truth.len()]);
        for (kind, accelerated) in [(SolverKind::GapTv, false), (SolverKind::GapTv, true), (SolverKind::AdmmTv, false)] {
            // The former defaults the figures below were measured with (100 iterations, λ = 1, TV weight 0.1,
            // 5 Chambolle iterations), GAP plain and accelerated; no δ, so no discrepancy stop.
            let cfg = SolverConfig { iterations: 100, accelerated, ..SolverConfig::for_solver(kind) };
            let rec = reconstruct(op.as_ref(), &y, None, &cfg, &|_, _| {}).unwrap();
            let p = psnr(&truth, &rec.cube);
            println!("{} {}{}: PSNR {p:.2} dB (constant-mean estimate {floor:.2} dB), final residual {:.2e}, {:.2} s", op.name(), kind.name(), if accelerated { " (accelerated)" } else { "" }, rec.final_residual, rec.seconds);
            // Measured (AP, 32×32×6, mask opening 0.5, noiseless, 100 iterations): accelerated GAP-TV
            // 21.6–21.7 dB through every operator; plain GAP-TV 20.0–20.5 dB through mapping/shift and
            // 15.9 dB through exact; ADMM-TV 21.3–21.6 dB through mapping/shift and 16.2 dB through exact
            // (the un-accelerated steps are slow where D over-estimates ΦΦᵀ: footprints + Airy spread a
            // voxel over many pixels). Half the pixels are masked in every band, so TV must inpaint them:
            // ~22 dB is the level at this size. Thresholds: measured − 0.5 to 0.9 dB.
            let need = match (kind, accelerated, op.name()) {
                (SolverKind::GapTv, true, _) => 21.0,
                (SolverKind::GapTv, false, "exact") => 15.0,
                (SolverKind::GapTv, false, _) => 19.5,
                (SolverKind::AdmmTv, _, "exact") => 15.5,
                (SolverKind::AdmmTv, _, _) => 20.8,
                (SolverKind::PnpGap | SolverKind::PnpAdmm, _, _) => unreachable!("this test runs the TV solvers only"),
            };
            assert!(p >= need, "{} {}: PSNR {p:.2} dB < {need} dB", op.name(), kind.name());
            assert!(rec.residuals.iter().all(|r| r.is_finite()) && rec.final_residual < 0.1);
        }
    }
}

/// Bad input: a clear error naming the problem, never a panic.
#[test]
fn bad_solver_inputs_are_named_errors() {
    use diffcassi::recon::{CubeShape, ImageShape};
    let shape = CubeShape { height: 4, width: 4, bands: 2 };
    let op = ShiftOperator::new(shape, ImageShape { height: 4, width: 6 }, &Mask::open(4, 4), 0, vec![0, 2], 1, 1).unwrap();
    let y = vec![1.0f32; 24];
    let err = |cfg: SolverConfig, y: &[f32], init: Option<&[f32]>| reconstruct(&op, y, init, &cfg, &|_, _| {}).unwrap_err().to_string();
    assert!(err(SolverConfig { iterations: 0, ..SolverConfig::gap_tv() }, &y, None).contains("iterations"));
    assert!(err(SolverConfig { step: 2.5, ..SolverConfig::admm_tv() }, &y, None).contains("step"));
    assert!(err(SolverConfig { tv_weight: f32::NAN, ..SolverConfig::gap_tv() }, &y, None).contains("TV weight"));
    assert!(err(SolverConfig::gap_tv(), &y[..20], None).contains("measurement has 20 values"));
    let mut bad = y.clone();
    bad[7] = f32::NAN;
    assert!(err(SolverConfig::gap_tv(), &bad, None).contains("row 1, column 1"));
    assert!(err(SolverConfig::gap_tv(), &y, Some(&[0.0; 5])).contains("initial cube has 5 values"));
    let e = "lsqr".parse::<SolverKind>().unwrap_err().to_string();
    assert!(e.contains("unknown solver `lsqr`"), "{e}");
    assert_eq!("admm-tv".parse::<SolverKind>().unwrap(), SolverKind::AdmmTv);
    // A mask whose size differs from the cube.
    let e = ShiftOperator::new(shape, ImageShape { height: 4, width: 6 }, &Mask::open(5, 4), 0, vec![0, 2], 1, 1).unwrap_err().to_string();
    assert!(e.contains("mask is 5×4"), "{e}");
    // The serialised record the CLI writes.
    let rec = reconstruct(&op, &y, None, &SolverConfig { iterations: 2, ..SolverConfig::gap_tv() }, &|_, _| {}).unwrap();
    let json = serde_json::to_value(&rec).unwrap();
    assert_eq!(json["config"]["solver"], "gap-tv");
    assert_eq!(json["residuals"].as_array().unwrap().len(), 2);
    assert!(json.get("cube").is_none());
}
