//! The unrolled network's CPU inference (issue 43: "unrolled inference at 256×256×28 ≤ 10 s on 2 cores"):
//! `reconstruct --solver unrolled`'s forward pass (src/recon/unrolled.rs) with the committed SP weights
//! (`unrolled-gap-v1`, 6 stages, width 16) through the exact operator at the realistic setting (SP, 28 bands ×
//! 4 = 112 planes, 20 rays, Airy 2.5 px, a random mask), and its parts: the operator's build (tracing, once
//! per system and size; not part of the inference), Φ and Φᵀ, one stage denoiser.
//!
//! `cargo bench --bench unrolled` (256×256 by default; `DIFFCASSI_BENCH_SIZE` and `DIFFCASSI_BENCH_RAYS`
//! override the size and rays). Prints a table of wall and CPU seconds (median of 3; on a shared machine the
//! CPU seconds say how much of the cores the run was given). Under `cargo test --all-targets` (no `--bench`
//! flag) it runs once at 16×16 with 2 rays.
use diffcassi::analysis::linspace;
use diffcassi::prelude::*;
use diffcassi::recon::prior::unrolled::UnrolledNetwork;
use diffcassi::recon::unrolled::unrolled;
use diffcassi::recon::{ExactOperator, Operator};
use diffcassi::render::{Mask, RenderConfig, Renderer};
use diffcassi::scene::synthetic_scene;
use std::time::Instant;

#[path = "common/mod.rs"]
mod common;
use common::{env_usize, cpu_seconds, median_timing, load_average};

fn main() {
    let bench_mode = std::env::args().any(|a| a == "--bench");
    let size = env_usize("DIFFCASSI_BENCH_SIZE").unwrap_or(if bench_mode { 256 } else { 16 });
    let rays = env_usize("DIFFCASSI_BENCH_RAYS").unwrap_or(if bench_mode { 20 } else { 2 });
    let system = SequentialSystem::build(&presets::spec("sp").unwrap()).unwrap();
    let tracer = AnalyticTracer::default();
    let mut cfg = RenderConfig::paper(size);
    cfg.rays_per_pixel = rays;
    let bands = linspace(450.0, 650.0, 28);
    let renderer = Renderer::new(&system, &tracer, cfg, Mask::random(size, size, 0.5, 1).unwrap()).unwrap();
    let load0 = load_average();
    let (t, c) = (Instant::now(), cpu_seconds());
    let exact = ExactOperator::new(renderer, &bands, 8 << 30).unwrap();
    let (t_build, c_build) = (t.elapsed().as_secs_f64(), cpu_seconds() - c);
    let phi: &dyn Operator = &exact;
    let (cs, is) = (phi.cube_shape(), phi.image_shape());
    let truth = synthetic_scene(size, size, &bands, 3).data;
    let y = phi.apply(&truth).unwrap();
    let net = UnrolledNetwork::committed("sp").unwrap();
    let median = |f: &mut dyn FnMut()| median_timing(3, f);
    let mut image = vec![0.0f32; is.len()];
    let mut cube = vec![0.0f32; cs.len()];
    let t_apply = median(&mut || phi.apply_into(&truth, &mut image));
    let t_adjoint = median(&mut || phi.adjoint_into(&y, &mut cube));
    let t_stage = median(&mut || net.denoise_stage(0, &truth, &mut cube, size, size).unwrap());
    let mut last = None;
    let t_net = median(&mut || last = Some(unrolled(phi, &y, &net, &mut |_, _, _| {}).unwrap()));
    let out = last.unwrap();
    let load1 = load_average();
    let mse = truth.iter().zip(&out.cube).map(|(a, b)| ((a - b) as f64).powi(2)).sum::<f64>() / truth.len() as f64;
    let peak = truth.iter().cloned().fold(0.0f32, f32::max) as f64;
    println!("\n| SP {size}×{size}×28, 112 planes, {rays} rays, {} threads, load average {load0:.1} → {load1:.1} | wall s | CPU s |", rayon::current_num_threads());
    println!("|---|---|---|");
    println!("| build exact operator (trace all planes; {:.2} GB kept; once per system) | {t_build:.2} | {c_build:.1} |", exact.transport_bytes() as f64 / 1e9);
    println!("| Φ (exact apply, median of 3) | {:.3} | {:.2} |", t_apply.0, t_apply.1);
    println!("| Φᵀ (exact adjoint, median of 3) | {:.3} | {:.2} |", t_adjoint.0, t_adjoint.1);
    println!("| one stage denoiser (width 16, median of 3) | {:.3} | {:.2} |", t_stage.0, t_stage.1);
    println!("| **unrolled inference** ({} stages: 7 Φ + 8 Φᵀ + 6 denoisers; median of 3) | **{:.2}** | {:.1} |", net.stages(), t_net.0, t_net.1);
    println!("| build + unrolled inference | {:.2} | {:.1} |", t_build + t_net.0, c_build + t_net.1);
    println!("\nunrolled: final residual {:.3e}, PSNR {:.2} dB vs the noiseless truth (synthetic scene, oracle operator, random mask: not the training setting)", out.final_residual, 10.0 * (peak * peak / mse).log10());
}
