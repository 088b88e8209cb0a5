//! Rays/s and ray–surface intersections/s of the tracer backends on SP, AP, mSP and mAP at the paper's
//! 28 wavelengths, on 1 and 2 threads: analytic f64 vs Embree user geometry vs Embree meshes at three
//! chord-sag bounds (10, 1, 0.1 µm), each Embree variant with and without f64 hit refinement.
//! `cargo bench --bench backends`. Scenes are built before timing.
//!
//! Criterion reports rays/s (`Throughput::Elements` = rays). Intersections per ray are counted once per
//! backend and preset (analytic: surfaces reached along the sequential path; Embree: its surface
//! interactions, from `trace_detailed`) and, under `cargo bench`, a table of rays/s and intersections/s
//! (best of 3 own timings) is printed after the criterion groups. Under `cargo test` (test mode) every
//! benchmark runs once and the table is skipped.
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use diffcassi::analysis::linspace;
use diffcassi::prelude::*;
use diffcassi::surfaces::MeshResolution;
use diffcassi::tracer::embree::{EmbreeOptions, EmbreeTracer, Refinement};
use diffcassi::tracer::{Backend, BackendConfig, Refine};
use std::time::{Duration, Instant};

const PRESETS: [&str; 4] = ["sp", "ap", "msp", "map"];

fn configs() -> Vec<BackendConfig> {
    let mut configs = vec![BackendConfig::default()];
    for refine in [Refine::F64, Refine::None] {
        configs.push(BackendConfig { backend: Backend::EmbreeUser, refine, ..Default::default() });
        for um in [10.0, 1.0, 0.1] {
            configs.push(BackendConfig { backend: Backend::EmbreeMesh, refine, mesh: MeshResolution::MaxSagErrorUm(um) });
        }
    }
    configs
}

fn workload(preset: &str) -> (SequentialSystem, RayBatch) {
    let sys = SequentialSystem::build(&presets::spec(preset).unwrap()).unwrap();
    let batch = RayBatch::seeded_workload(&sys, 1_000, &linspace(450.0, 650.0, 28), 1000).unwrap();
    (sys, batch)
}

/// Mean ray–surface intersections per ray of `cfg` on `batch`.
fn intersections_per_ray(cfg: &BackendConfig, sys: &SequentialSystem, batch: &RayBatch) -> f64 {
    let total: f64 = match cfg.backend {
        Backend::Analytic => {
            let out = AnalyticTracer::default().trace(sys, batch).unwrap();
            let path = sys.path_surfaces();
            // An arrived ray meets every surface of the path; a stopped one the surfaces up to where it stopped.
            out.status
                .iter()
                .zip(&out.surface)
                .map(|(s, f)| if *s == RayStatus::Ok { sys.surfaces_per_ray() as f64 } else { path.iter().take_while(|&&p| p as u32 <= *f).count() as f64 })
                .sum()
        }
        _ => {
            let refine = if cfg.refine == Refine::F64 { Refinement::F64 } else { Refinement::None };
            let opts = if cfg.backend == Backend::EmbreeUser { EmbreeOptions::user(refine) } else { EmbreeOptions::mesh(cfg.mesh, refine) };
            let (_, d) = EmbreeTracer::new(opts).trace_detailed(sys, batch).unwrap();
            d.interactions.iter().map(|&k| k as f64).sum()
        }
    };
    total / batch.len() as f64
}

fn backends(c: &mut Criterion) {
    let bench_mode = std::env::args().any(|a| a == "--bench");
    let mut table = Vec::new();
    for preset in PRESETS {
        let mut g = c.benchmark_group(format!("backends_{preset}_28wl"));
        g.sample_size(10).warm_up_time(Duration::from_millis(300)).measurement_time(Duration::from_secs(1));
        let (sys, batch) = workload(preset);
        g.throughput(Throughput::Elements(batch.len() as u64));
        for cfg in configs() {
            let tracer = cfg.build().unwrap();
            tracer.trace(&sys, &batch).unwrap(); // builds and caches the Embree scene
            let per_ray = if bench_mode { intersections_per_ray(&cfg, &sys, &batch) } else { 0.0 };
            for threads in [1usize, 2] {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
                g.bench_with_input(BenchmarkId::new(tracer.name(), format!("{threads}threads")), &batch, |b, batch| b.iter(|| pool.install(|| tracer.trace(&sys, batch).unwrap())));
                if bench_mode {
                    let mut best = f64::INFINITY;
                    for _ in 0..3 {
                        let t = Instant::now();
                        std::hint::black_box(pool.install(|| tracer.trace(&sys, &batch).unwrap()));
                        best = best.min(t.elapsed().as_secs_f64());
                    }
                    let rps = batch.len() as f64 / best;
                    table.push(format!("| {preset} | {} | {threads} | {:.3} | {per_ray:.2} | {:.2} |", tracer.name(), rps / 1e6, rps * per_ray / 1e6));
                }
            }
        }
        g.finish();
    }
    if bench_mode {
        println!("\n| preset | backend | threads | M rays/s | intersections/ray | M intersections/s |\n|---|---|---|---|---|---|");
        for row in table {
            println!("{row}");
        }
    }
}

criterion_group!(benches, backends);
criterion_main!(benches);
