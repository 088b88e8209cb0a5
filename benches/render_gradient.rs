//! Cost of the acquisition's vector–Jacobian product (`render::gradient`): the production forward render
//! (`Renderer`, SIMD), the differentiable renderer's own f64 forward (`DiffRenderer::render`), and its
//! backward (`DiffRenderer::vjp`) for 1, 10 and 50 free parameters, the backward that wants only the
//! parameters' gradient (`vjp_wanted`: `backward_vjp_params_only/1, /10, /50`) and the one that wants only
//! the mask's and the scene's (`backward_vjp_mask_scene`: no ray swept backwards), on SP, with a binary
//! mask of opening 0.5 (the forward skips its closed pixels; a backward that gives the mask's gradient
//! traces them). The `…_continuous_mask` rows repeat the production forward, the full backward and the
//! params-only backward at 10 parameters with a **continuous** mask as `diffcassi.torch.CassiRenderer`
//! trains it: the same binary mask clipped to [0.05, 0.95] (no pixel exactly 0, so every pixel's rays are
//! traced by the forward too, and every ray is swept backwards).
//!
//! `cargo bench --bench render_gradient` (size from `DIFFCASSI_BENCH_SIZE`, default 128: SP 128×128, 112
//! planes, 20 rays, mask opening 0.5; `DIFFCASSI_BENCH_PLANES`, `DIFFCASSI_BENCH_RAYS` override). In
//! `cargo test --benches` (no `--bench` flag) it runs once at 8×8, 3 planes, 1 ray. Table: docs/codesign.md.
use criterion::{BenchmarkId, Criterion};
use diffcassi::diff::{Param, ParamSet};
use diffcassi::materials::GlassCatalog;
use diffcassi::prelude::*;
use diffcassi::render::gradient::{DiffRenderer, Wanted};
use diffcassi::render::{Mask, RenderConfig, Renderer, SpectralSampling};
use diffcassi::spec::Driver;

/// The first `k` system parameters of SP the renderer accepts (fixed cells in surface order, then glasses),
/// dropping those with no effect on the detector.
fn renderer(cfg: &RenderConfig, k: usize) -> DiffRenderer {
    let spec = presets::spec("sp").unwrap();
    let mut cand = Vec::new();
    for (i, s) in spec.surfaces.iter().enumerate() {
        for col in s.present_columns() {
            if s.cell(&col).map(|c| c.driver == Driver::Fixed).unwrap_or(false) {
                cand.push(Param::Cell { surface: i, column: col });
            }
        }
    }
    for t in ["glass_nd:N-BK7", "glass_vd:N-BK7", "glass_nd:N-BAF10", "glass_vd:N-BAF10", "glass_nd:SF10", "glass_vd:SF10"] {
        cand.push(Param::parse(t).unwrap());
    }
    let bands = cfg.spectral.bands_nm.clone();
    let mut free: Vec<Param> = Vec::new();
    for p in cand {
        if free.len() == k {
            break;
        }
        let mut trial = free.clone();
        trial.push(p);
        let Ok(set) = ParamSet::new(spec.clone(), GlassCatalog::builtin(), trial.clone()) else { continue };
        let mut small = cfg.clone();
        (small.scene_height, small.scene_width) = (2, 2);
        if DiffRenderer::new(set, small, bands.clone()).is_ok() {
            free = trial;
        }
    }
    assert_eq!(free.len(), k, "only {} usable parameters", free.len());
    DiffRenderer::new(ParamSet::new(spec, GlassCatalog::builtin(), free).unwrap(), cfg.clone(), bands).unwrap()
}

fn env(name: &str, default: usize) -> usize {
    std::env::var(name).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

fn main() {
    let bench_mode = std::env::args().any(|a| a == "--bench");
    let (size, planes, rays) = if bench_mode { (env("DIFFCASSI_BENCH_SIZE", 128), env("DIFFCASSI_BENCH_PLANES", 112), env("DIFFCASSI_BENCH_RAYS", 20)) } else { (8, 3, 1) };
    let mut cfg = RenderConfig::paper(size);
    cfg.spectral = SpectralSampling::with_planes(SpectralSampling::paper().bands_nm, planes).unwrap();
    cfg.rays_per_pixel = rays;
    let bands = cfg.spectral.bands_nm.len();
    let mask = Mask::random(size, size, 0.5, 0).unwrap();
    let scene = diffcassi::scene::synthetic_scene(size, size, &cfg.spectral.bands_nm, 0);
    // (N = 1, B, H, W) f64 for the differentiable renderer.
    let hw = size * size;
    let scene64: Vec<f64> = (0..bands * hw).map(|i| scene.data[(i % hw) * bands + i / hw] as f64).collect();
    let mask64: Vec<f64> = mask.values.iter().map(|&v| v as f64).collect();
    // CassiRenderer's start from a given mask: clipped to [0.05, 0.95] (sigmoid of ±2.94 logits).
    let mut cont = mask.clone();
    cont.values.iter_mut().for_each(|v| *v = v.clamp(0.05, 0.95));
    let cont64: Vec<f64> = cont.values.iter().map(|&v| v as f64).collect();
    let sys = SequentialSystem::build(&presets::spec("sp").unwrap()).unwrap();
    let tracer = AnalyticTracer::default();
    let production = Renderer::new(&sys, &tracer, cfg.clone(), mask.clone()).unwrap();
    let production_cont = Renderer::new(&sys, &tracer, cfg.clone(), cont).unwrap();
    let r1 = renderer(&cfg, 1);
    let g: Vec<f64> = (0..r1.detector.pixels()).map(|i| ((i * 7919) % 101) as f64 / 101.0 - 0.5).collect();
    let mut c = Criterion::default().sample_size(10).configure_from_args();
    let mut grp = c.benchmark_group(format!("render_gradient_sp_{size}x{size}_{planes}planes_{rays}rays"));
    grp.bench_function("forward_renderer", |b| b.iter(|| production.render(&scene, false, &|_| {}).unwrap()));
    grp.bench_function("forward_diff_f64", |b| b.iter(|| r1.render(&scene64, 1, &mask64).unwrap()));
    // ∂L/∂mask and ∂L/∂scene without ∂L/∂θ (no ray recorded or swept backwards): what any backward that
    // gives the mask's gradient costs at least — every ray is traced, the closed pixels' that the forward
    // skips included.
    let mask_scene = Wanted { params: false, mask: true, scene: true };
    grp.bench_function("backward_vjp_mask_scene", |b| b.iter(|| r1.vjp_wanted(&scene64, 1, &mask64, &g, mask_scene).unwrap()));
    for k in [1usize, 10, 50] {
        let r = if k == 1 { r1.clone() } else { renderer(&cfg, k) };
        println!("{k} parameters: {:?}", r.names());
        grp.bench_with_input(BenchmarkId::new("backward_vjp", k), &k, |b, _| b.iter(|| r.vjp(&scene64, 1, &mask64, &g).unwrap()));
        // Only ∂L/∂θ wanted (a fixed mask and scene): the closed pixels' rays are not traced.
        let only = Wanted { params: true, mask: false, scene: false };
        grp.bench_with_input(BenchmarkId::new("backward_vjp_params_only", k), &k, |b, _| b.iter(|| r.vjp_wanted(&scene64, 1, &mask64, &g, only).unwrap()));
        if k == 10 {
            // The continuous mask (every pixel open): forward, full backward, params-only backward.
            grp.bench_function("forward_renderer_continuous_mask", |b| b.iter(|| production_cont.render(&scene, false, &|_| {}).unwrap()));
            grp.bench_with_input(BenchmarkId::new("backward_vjp_continuous_mask", k), &k, |b, _| b.iter(|| r.vjp(&scene64, 1, &cont64, &g).unwrap()));
            grp.bench_with_input(BenchmarkId::new("backward_vjp_params_only_continuous_mask", k), &k, |b, _| b.iter(|| r.vjp_wanted(&scene64, 1, &cont64, &g, only).unwrap()));
        }
    }
    grp.finish();
    c.final_summary();
}
