//! Round 18 of the held-out battery (3 Dec 2026, prober B, finding 1): Ctrl-C did nothing in Python until a
//! render, an exact operator, a `Transport` or a reconstruction had finished (7.5 s after the signal at 256²); the
//! work ran to the end and was thrown away. The library now takes a per-call stop request
//! ([`diffcassi::cancel::Cancel`]): a renderer polls it before each scene row of every plane it traces (renders,
//! `trace_all`, the exact operator's build), a solve before each iteration; a cancelled call returns
//! `Error::Interrupted` and nothing else, and an uncancelled one gives the same bits as a call without a token.
use diffcassi::cancel::Cancel;
use diffcassi::prelude::*;
use diffcassi::recon::exact::ExactOperator;
use diffcassi::recon::pipeline::run_solver;
use diffcassi::recon::{CubeShape, Denoiser, Operator, SolverConfig, SolverKind, SpectralUNet};
use diffcassi::render::{Mask, RenderConfig, Renderer, SpectralSampling};
use diffcassi::scene::synthetic_scene;
use std::sync::atomic::{AtomicUsize, Ordering};

const SIZE: usize = 12;
const BANDS: [f64; 4] = [480.0, 520.0, 560.0, 600.0];

fn config() -> RenderConfig {
    let mut cfg = RenderConfig::paper(SIZE);
    cfg.spectral = SpectralSampling::new(BANDS.to_vec(), 3).unwrap();
    cfg.rays_per_pixel = 3;
    cfg.seed = 5;
    cfg
}

fn interrupted<T>(r: diffcassi::Result<T>) -> bool {
    matches!(r, Err(diffcassi::Error::Interrupted))
}

#[test]
fn a_cancelled_render_or_trace_stops_with_interrupted_and_an_uncancelled_token_changes_no_bit() {
    let sys = SequentialSystem::build(&presets::spec("sp").unwrap()).unwrap();
    let tracer = AnalyticTracer::default();
    let mask = Mask::random(SIZE, SIZE, 0.5, 7).unwrap();
    let scene = synthetic_scene(SIZE, SIZE, &BANDS, 3);
    let plain = Renderer::new(&sys, &tracer, config(), mask.clone()).unwrap();
    let reference = plain.render(&scene, false, &|_| {}).unwrap();
    let planes = plain.config.spectral.planes();

    // An uncancelled token: the same acquisition and transport bit for bit.
    let token = Cancel::new();
    let r = Renderer::new(&sys, &tracer, config(), mask.clone()).unwrap().with_cancel(token.clone());
    assert_eq!(r.render(&scene, false, &|_| {}).unwrap().image, reference.image);
    assert_eq!(r.trace_all(&|_| {}).unwrap(), plain.trace_all(&|_| {}).unwrap());

    // Cancelled before: nothing is traced.
    token.cancel();
    let e = r.render(&scene, false, &|_| {}).unwrap_err();
    assert!(matches!(e, diffcassi::Error::Interrupted), "{e}");
    assert!(e.to_string().contains("interrupted"), "{e}");
    assert!(interrupted(r.trace_all(&|_| {})));
    assert!(interrupted(r.trace_plane(0)));
    assert!(interrupted(ExactOperator::new(r, &BANDS, 1 << 30)));

    // Cancelled mid-way (by the first finished plane): the render stops there instead of tracing the rest.
    let token = Cancel::new();
    let r = Renderer::new(&sys, &tracer, config(), mask.clone()).unwrap().with_cancel(token.clone());
    let done = AtomicUsize::new(0);
    let stop_after_one = |_: u64| {
        done.fetch_add(1, Ordering::SeqCst);
        token.cancel();
    };
    assert!(interrupted(r.render(&scene, false, &stop_after_one)));
    let rendered = done.swap(0, Ordering::SeqCst);
    // Bands render in parallel: at most one plane per worker finishes after the request.
    assert!(rendered < planes, "{rendered} of {planes} planes rendered after the cancel");

    // Afterwards a fresh renderer gives the same bits as before: nothing shared was left half-written.
    let again = Renderer::new(&sys, &tracer, config(), mask).unwrap();
    assert_eq!(again.render(&scene, false, &|_| {}).unwrap().image, reference.image);
}

#[test]
fn a_cancelled_solve_stops_at_the_next_iteration_and_an_uncancelled_token_changes_no_bit() {
    let sys = SequentialSystem::build(&presets::spec("sp").unwrap()).unwrap();
    let tracer = AnalyticTracer::default();
    let r = Renderer::new(&sys, &tracer, config(), Mask::random(SIZE, SIZE, 0.5, 7).unwrap()).unwrap();
    let scene = synthetic_scene(SIZE, SIZE, &BANDS, 3);
    let op = ExactOperator::new(r, &BANDS, 1 << 30).unwrap();
    let y = (&op as &dyn Operator).apply(&scene.data).unwrap();
    let mut cfg = SolverConfig::for_solver(SolverKind::GapTv);
    cfg.iterations = 40;
    let (plain, _) = run_solver(&op, &y, None, &cfg, None, None, &|_, _| {}, None).unwrap();
    assert_eq!(plain.residuals.len(), 40);

    let token = Cancel::new();
    let (with_token, _) = run_solver(&op, &y, None, &cfg, None, None, &|_, _| {}, Some(&token)).unwrap();
    assert_eq!(with_token.cube, plain.cube, "an uncancelled token changed the reconstruction");
    assert_eq!(with_token.residuals, plain.residuals);

    // Cancelled at iteration 3: the solve returns Interrupted at iteration 4's poll, not after 40 iterations.
    let last = AtomicUsize::new(0);
    let stop_at_3 = |k: usize, _: f64| {
        last.store(k, Ordering::SeqCst);
        if k == 3 {
            token.cancel();
        }
    };
    assert!(interrupted(run_solver(&op, &y, None, &cfg, None, None, &stop_at_3, Some(&token))));
    assert_eq!(last.load(Ordering::SeqCst), 3, "iterations ran after the cancel");
    // A cancelled token stops a solve before it starts; a fresh one runs it to the same bits as before.
    assert!(interrupted(run_solver(&op, &y, None, &cfg, None, None, &|_, _| {}, Some(&token))));
    let (again, _) = run_solver(&op, &y, None, &cfg, None, None, &|_, _| {}, Some(&Cancel::new())).unwrap();
    assert_eq!(again.cube, plain.cube);
}

#[test]
fn a_cancelled_network_denoise_stops_inside_the_call() {
    // PnP's network step (seconds per call at 512²) polls per layer; a fresh token changes no bit.
    let shape = CubeShape { height: 8, width: 8, bands: 28 };
    let x: Vec<f32> = (0..shape.len()).map(|i| 0.5 + 0.4 * ((i * 37 % 101) as f32 / 101.0)).collect();
    let mut net = SpectralUNet::load_pnp(None).unwrap();
    let mut plain = vec![0.0f32; shape.len()];
    net.denoise(&x, &mut plain, shape, 0.05).unwrap();
    let token = Cancel::new();
    net.set_cancel(Some(token.clone()));
    let mut out = vec![0.0f32; shape.len()];
    net.denoise(&x, &mut out, shape, 0.05).unwrap();
    assert_eq!(out, plain);
    token.cancel();
    assert!(interrupted(net.denoise(&x, &mut out, shape, 0.05)));
    net.set_cancel(None);
    net.denoise(&x, &mut out, shape, 0.05).unwrap();
    assert_eq!(out, plain);
}
