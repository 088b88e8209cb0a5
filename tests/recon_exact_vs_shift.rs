//! The reference paper's point, on our renderer: reconstructing a *rendered* acquisition (Monte-Carlo rays,
//! distortion, smile, Airy blur) with the exact operator beats the field's simplified shift model, on SP and
//! mSP at 128×128. The exact operator is built with a different seed from the acquisition's (it never knows
//! the measurement's Monte-Carlo noise). Both reconstructions: GAP-TV with the documented defaults (plain
//! GAP, 100 iterations, TV weight 0.1, 5 Chambolle iterations, vectorial).
//!
//! Measured (14 bands × 2 planes, 8 rays, Airy on, mask opening 0.5, synthetic scene seed 12):
//! SP exact 15.21 dB vs shift 11.99 dB (+3.2 dB); mSP exact 15.40 dB vs shift 11.72 dB (+3.7 dB). The test
//! asks for a 2 dB margin. (The absolute level is low: half the pixels are masked in every band and the
//! model's 8-ray transport differs from the acquisition's by Monte-Carlo noise, ~3 % of the signal; with the
//! acquisition's own seed, the oracle, the exact operator reaches 23 dB after 200 accelerated iterations.)
use diffcassi::prelude::*;
use diffcassi::recon::{reconstruct, ExactOperator, Operator, ShiftOperator, SolverConfig};
use diffcassi::render::{Mask, RenderConfig, Renderer, SpectralSampling};
use diffcassi::scene::synthetic_scene;

const SIZE: usize = 128;

fn psnr(truth: &[f32], est: &[f32]) -> f64 {
    let mse = truth.iter().zip(est).map(|(a, b)| ((a - b.clamp(0.0, 1.0)) as f64).powi(2)).sum::<f64>() / truth.len() as f64;
    let peak = truth.iter().cloned().fold(0.0f32, f32::max) as f64;
    10.0 * (peak * peak / mse).log10()
}

#[test]
fn exact_operator_beats_the_shift_model_on_rendered_sp_and_msp() {
    let tracer = AnalyticTracer::default();
    let bands = diffcassi::analysis::linspace(450.0, 650.0, 14);
    let mask = Mask::random(SIZE, SIZE, 0.5, 1).unwrap();
    let scene = synthetic_scene(SIZE, SIZE, &bands, 12);
    let cfg = |seed: u64| {
        let mut c = RenderConfig::paper(SIZE);
        c.spectral = SpectralSampling::new(bands.clone(), 2).unwrap();
        c.rays_per_pixel = 8;
        c.seed = seed;
        c
    };
    for (preset, margin_db) in [("sp", 2.0), ("msp", 2.0)] {
        let system = SequentialSystem::build(&presets::spec(preset).unwrap()).unwrap();
        let acquisition = Renderer::new(&system, &tracer, cfg(1), mask.clone()).unwrap().render(&scene, false, &|_| {}).unwrap();
        let y = acquisition.image_f32();
        let model = Renderer::new(&system, &tracer, cfg(2), mask.clone()).unwrap();
        let shift = ShiftOperator::from_renderer(&model, &bands).unwrap();
        let exact = ExactOperator::new(model, &bands, 4 << 30).unwrap();
        // The configuration the figures above were measured with (plain GAP-TV, 100 iterations: the
        // defaults before the measured ones of docs/reconstruction.md, "Defaults and stopping").
        let config = SolverConfig { iterations: 100, accelerated: false, ..SolverConfig::gap_tv() };
        let mut results = Vec::new();
        for op in [&exact as &dyn Operator, &shift] {
            let rec = reconstruct(op, &y, None, &config, &|_, _| {}).unwrap();
            let p = psnr(&scene.data, &rec.cube);
            println!("{preset}: {} operator: PSNR {p:.2} dB, final residual {:.3e}, {:.2} s", op.name(), rec.final_residual, rec.seconds);
            results.push(p);
        }
        println!("{preset}: exact − shift = {:.2} dB", results[0] - results[1]);
        assert!(results[0] > results[1] + margin_db, "{preset}: exact {:.2} dB vs shift {:.2} dB", results[0], results[1]);
    }
}
