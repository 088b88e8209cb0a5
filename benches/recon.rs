//! Reconstruction speed (issue 13): the exact operator Φ and its adjoint Φᵀ on SP at the paper's settings
//! (512×512 scene, 28 bands × 4 = 112 planes, 20 rays, Airy blur), the TV denoiser, the shift and mapping
//! operators, one GAP-TV iteration and a full 100-iteration GAP-TV reconstruction; then the learned denoiser
//! (one call) and a PnP-GAP reconstruction with its defaults (`DIFFCASSI_BENCH_PNP_ITERATIONS` overrides the
//! iteration bound).
//!
//! `cargo bench --bench recon` (criterion for Φ, Φᵀ, TV; then a one-shot 100-iteration reconstruction whose
//! per-iteration times give "one GAP-TV iteration"; a table of wall and CPU seconds is printed at the end —
//! on a shared machine the CPU seconds say how much of the 2 cores the run was given).
//! `DIFFCASSI_BENCH_SIZE` overrides the scene size (default 512), `DIFFCASSI_BENCH_RAYS` the rays per pixel
//! (20), `DIFFCASSI_BENCH_ITERATIONS` the iteration count (100); `DIFFCASSI_BENCH_CRITERION=0` skips the
//! criterion runs (the table only). Under
//! `cargo test --all-targets` (no `--bench` flag) it runs once at 32×32 with 3 iterations, to stay cheap.
use criterion::Criterion;
use diffcassi::analysis::linspace;
use diffcassi::prelude::*;
use diffcassi::recon::tv::{tv_denoise, TvScratch};
use diffcassi::recon::{reconstruct, Denoiser, ExactOperator, SpectralUNet, MappingInterpolation, MappingOperator, Operator, ShiftOperator, SolverConfig, TvCoupling};
use diffcassi::render::{Mask, RenderConfig, Renderer};
use diffcassi::scene::synthetic_scene;
use std::sync::Mutex;
use std::time::Instant;

#[path = "common/mod.rs"]
mod common;
use common::{env_usize, cpu_seconds, median_timing};

fn main() {
    let bench_mode = std::env::args().any(|a| a == "--bench");
    let size = env_usize("DIFFCASSI_BENCH_SIZE").unwrap_or(if bench_mode { 512 } else { 32 });
    let iterations = env_usize("DIFFCASSI_BENCH_ITERATIONS").unwrap_or(if bench_mode { 100 } else { 3 });
    let rays = env_usize("DIFFCASSI_BENCH_RAYS").unwrap_or(if bench_mode { 20 } else { 2 });
    let system = SequentialSystem::build(&presets::spec("sp").unwrap()).unwrap();
    let tracer = AnalyticTracer::default();
    let mut cfg = RenderConfig::paper(size);
    cfg.rays_per_pixel = rays;
    let bands = linspace(450.0, 650.0, 28);
    let mask = Mask::random(size, size, 0.5, 1).unwrap();
    let renderer = Renderer::new(&system, &tracer, cfg, mask).unwrap();
    let t = Instant::now();
    let shift = ShiftOperator::from_renderer(&renderer, &bands).unwrap();
    let mapping = MappingOperator::from_renderer(&renderer, &bands, MappingInterpolation::Bilinear).unwrap();
    let t_mapping = t.elapsed().as_secs_f64();
    let (t, c) = (Instant::now(), cpu_seconds());
    let exact = ExactOperator::new(renderer, &bands, 8 << 30).unwrap();
    let (t_build, c_build) = (t.elapsed().as_secs_f64(), cpu_seconds() - c);
    let phi: &dyn Operator = &exact;
    let (cs, is) = (phi.cube_shape(), phi.image_shape());
    println!(
        "SP {size}×{size}×28, {} planes, {rays} rays, detector {}×{}: exact operator built in {t_build:.2} s (transport {:.2} GB, {}), shift+mapping in {t_mapping:.2} s; {} threads",
        exact.renderer().config.spectral.planes(), is.height, is.width, exact.transport_bytes() as f64 / 1e9,
        if exact.is_streaming() { "streamed" } else { "kept" }, rayon::current_num_threads()
    );
    let truth = synthetic_scene(size, size, &bands, 3).data;
    let y = phi.apply(&truth).unwrap();
    let mut image = vec![0.0f32; is.len()];
    let mut cube = vec![0.0f32; cs.len()];
    let mut scratch = TvScratch::default();
    if std::env::var("DIFFCASSI_BENCH_CRITERION").as_deref() != Ok("0") {
    let mut c = Criterion::default().configure_from_args().sample_size(10);
    c.bench_function(&format!("recon/exact_apply_sp_{size}"), |b| b.iter(|| phi.apply_into(&truth, &mut image)));
    c.bench_function(&format!("recon/exact_adjoint_sp_{size}"), |b| b.iter(|| phi.adjoint_into(&y, &mut cube)));
    c.bench_function(&format!("recon/shift_apply_sp_{size}"), |b| b.iter(|| shift.apply_into(&truth, &mut image)));
    c.bench_function(&format!("recon/shift_adjoint_sp_{size}"), |b| b.iter(|| shift.adjoint_into(&y, &mut cube)));
    c.bench_function(&format!("recon/mapping_bilinear_apply_sp_{size}"), |b| b.iter(|| mapping.apply_into(&truth, &mut image)));
    c.bench_function(&format!("recon/mapping_bilinear_adjoint_sp_{size}"), |b| b.iter(|| mapping.adjoint_into(&y, &mut cube)));
    c.bench_function(&format!("recon/tv_chambolle5_vectorial_{size}"), |b| b.iter(|| tv_denoise(&truth, &mut cube, cs, 0.1, 5, TvCoupling::Vectorial, &mut scratch)));
    c.final_summary();
    }

    // One-shot timings for the table (median of 5 for the operators and the TV; wall and CPU seconds).
    let median = |f: &mut dyn FnMut()| median_timing(5, f);
    let t_apply = median(&mut || phi.apply_into(&truth, &mut image));
    let t_adjoint = median(&mut || phi.adjoint_into(&y, &mut cube));
    let mut denoised = vec![0.0f32; cs.len()];
    let t_tv = median(&mut || tv_denoise(&truth, &mut denoised, cs, 0.1, 5, TvCoupling::Vectorial, &mut scratch));
    let stamps = Mutex::new(Vec::new());
    let config = SolverConfig { iterations, ..SolverConfig::gap_tv() };
    let (t, c) = (Instant::now(), cpu_seconds());
    let rec = reconstruct(phi, &y, None, &config, &|_, _| stamps.lock().unwrap().push((Instant::now(), cpu_seconds()))).unwrap();
    let (t_total, c_total) = (t.elapsed().as_secs_f64(), cpu_seconds() - c);
    let s = stamps.into_inner().unwrap();
    let per_iter: Vec<f64> = s.windows(2).map(|w| (w[1].0 - w[0].0).as_secs_f64()).collect();
    let mean_iter = if per_iter.is_empty() { f64::NAN } else { per_iter.iter().sum::<f64>() / per_iter.len() as f64 };
    let cpu_iter = if s.len() < 2 { f64::NAN } else { (s[s.len() - 1].1 - s[0].1) / (s.len() - 1) as f64 };
    let mse = truth.iter().zip(&rec.cube).map(|(a, b)| ((a - b) as f64).powi(2)).sum::<f64>() / truth.len() as f64;
    let peak = truth.iter().cloned().fold(0.0f32, f32::max) as f64;
    println!("\n| SP {size}×{size}×28, 112 planes, {rays} rays, {} threads | wall s | CPU s |", rayon::current_num_threads());
    println!("|---|---|---|");
    println!("| build exact operator (trace all planes; {:.2} GB kept) | {t_build:.2} | {c_build:.1} |", exact.transport_bytes() as f64 / 1e9);
    println!("| Φ (exact apply, median of 5) | {:.3} | {:.2} |", t_apply.0, t_apply.1);
    println!("| Φᵀ (exact adjoint, median of 5) | {:.3} | {:.2} |", t_adjoint.0, t_adjoint.1);
    println!("| TV (5 Chambolle iterations, vectorial, median of 5) | {:.3} | {:.2} |", t_tv.0, t_tv.1);
    println!("| one GAP-TV iteration (mean of {}) | {mean_iter:.3} | {cpu_iter:.2} |", per_iter.len());
    println!("| GAP-TV, {iterations} iterations (incl. preconditioner) | {t_total:.2} | {c_total:.1} |");
    println!("| build + GAP-TV, {iterations} iterations | {:.2} | {:.1} |", t_build + t_total, c_build + c_total);
    println!("\nGAP-TV: final residual {:.3e}, PSNR {:.2} dB vs the noiseless truth (oracle operator), {} cube-sized solver buffers", rec.final_residual, 10.0 * (peak * peak / mse).log10(), rec.cube_buffers);

    // The learned prior (issue 22): one denoiser call and a full PnP-GAP with its defaults (the embedded
    // weights; the TV phase, accelerated GAP-TV capped at 300 iterations — noiseless y and the oracle give no
    // δ, so no discrepancy stop ends it early — then one network step at σ = 0.2) through the same exact operator.
    let mut net = SpectralUNet::embedded().unwrap();
    let t_net = median(&mut || net.denoise(&truth, &mut denoised, cs, 0.05).unwrap());
    // Test mode (`cargo test --benches`): 2 iterations, 1 of them the TV warm-up, so the network runs once.
    let defaults = SolverConfig::pnp_gap();
    let pnp_iterations = env_usize("DIFFCASSI_BENCH_PNP_ITERATIONS").unwrap_or(if bench_mode { defaults.iterations } else { 2 });
    let pnp = SolverConfig { iterations: pnp_iterations, tv_warmup: defaults.tv_warmup.min(pnp_iterations.saturating_sub(1)), ..defaults };
    let (t, c) = (Instant::now(), cpu_seconds());
    let prec = reconstruct(phi, &y, None, &pnp, &|_, _| {}).unwrap();
    let (t_pnp, c_pnp) = (t.elapsed().as_secs_f64(), cpu_seconds() - c);
    let pmse = truth.iter().zip(&prec.cube).map(|(a, b)| ((a - b) as f64).powi(2)).sum::<f64>() / truth.len() as f64;
    println!("\n| SP {size}×{size}×28, learned prior, {} threads | wall s | CPU s |", rayon::current_num_threads());
    println!("|---|---|---|");
    println!("| denoiser (spectral-unet-v2, one call, median of 5) | {:.3} | {:.2} |", t_net.0, t_net.1);
    println!("| PnP-GAP, {} of at most {} iterations (stopped by {}) | {t_pnp:.2} | {c_pnp:.1} |", prec.iterations_run, pnp.iterations, prec.stopped_by);
    println!("| build + PnP-GAP | {:.2} | {:.1} |", t_build + t_pnp, c_build + c_pnp);
    println!("\nPnP-GAP: final residual {:.3e}, PSNR {:.2} dB vs the noiseless truth (oracle operator, synthetic scene)", prec.final_residual, 10.0 * (peak * peak / pmse).log10());
}
