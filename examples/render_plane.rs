//! Time one spectral plane of the paper-scale SP acquisition (512×512 scene, 20 rays per pixel): tracing +
//! footprints, the footprint memory, and the Airy convolution. `cargo run --release --example render_plane`.
use diffcassi::prelude::*;
use diffcassi::render::{Mask, RenderConfig, Renderer};
use std::time::Instant;

fn main() -> diffcassi::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let preset = args.get(1).map(String::as_str).unwrap_or("sp");
    let size: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(512);
    let system = SequentialSystem::build(&presets::spec(preset)?)?;
    let tracer = AnalyticTracer::default();
    let cfg = RenderConfig::paper(size);
    let t = Instant::now();
    let r = Renderer::new(&system, &tracer, cfg, Mask::random(size, size, 0.5, 0)?)?;
    println!("setup {:.2} s, detector {}×{}", t.elapsed().as_secs_f64(), r.detector.width, r.detector.height);
    for p in [0usize, 56, 111] {
        let t = Instant::now();
        let tr = r.trace_plane(p)?;
        let s = t.elapsed().as_secs_f64();
        let avg_win = tr.weights.len() as f64 / tr.footprints.len() as f64;
        println!("plane {p}: {} rays in {s:.2} s = {:.2} M rays/s (1 thread), {:.1} MB, mean window {avg_win:.1} px, transmission {:.4}", tr.stats.traced, tr.stats.traced as f64 / s / 1e6, tr.bytes() as f64 / 1e6, tr.stats.transmission());
        let img = vec![1.0f32; r.detector.pixels()];
        let t = Instant::now();
        let out = r.kernels[p].as_ref().unwrap().convolve(&img, r.detector.width, r.detector.height);
        println!("  airy {:.3} s ({} taps)", t.elapsed().as_secs_f64(), r.kernels[p].as_ref().unwrap().weights.len());
        std::hint::black_box(out);
    }
    Ok(())
}
