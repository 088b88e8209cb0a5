//! Throughput of the analytic f64 tracer: SP and AP at the paper's 28 wavelengths (rays/s), the mapping
//! cube's chief rays, and one-thread vs all-threads. `cargo bench --bench trace`.
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use diffcassi::analysis::linspace;
use diffcassi::prelude::*;

fn trace_28_wavelengths(c: &mut Criterion) {
    let mut g = c.benchmark_group("analytic_trace_28wl");
    g.sample_size(10);
    let ws = linspace(450.0, 650.0, 28);
    for preset in ["sp", "ap", "msp", "map"] {
        let sys = SequentialSystem::build(&presets::spec(preset).unwrap()).unwrap();
        let batch = RayBatch::seeded_workload(&sys, 10_000, &ws, 1000).unwrap();
        g.throughput(Throughput::Elements(batch.len() as u64));
        for threads in [1usize, 2] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            let tracer = AnalyticTracer::default();
            g.bench_with_input(BenchmarkId::new(preset, format!("{threads}threads")), &batch, |b, batch| {
                b.iter(|| pool.install(|| tracer.trace(&sys, batch).unwrap()))
            });
        }
    }
    g.finish();
}

fn mapping_cube(c: &mut Criterion) {
    let mut g = c.benchmark_group("mapping_cube");
    g.sample_size(10);
    let sys = SequentialSystem::build(&presets::spec("sp").unwrap()).unwrap();
    let ws = linspace(450.0, 650.0, 28);
    g.throughput(Throughput::Elements((128 * 128 * 28) as u64));
    g.bench_function("sp_128x128x28", |b| {
        b.iter(|| analysis::mapping_cube(&sys, &AnalyticTracer::default(), 128, 128, 0.04, &ws).unwrap())
    });
    g.finish();
}

criterion_group!(benches, trace_28_wavelengths, mapping_cube);
criterion_main!(benches);
