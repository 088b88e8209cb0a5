//! Rays/s of the tracer backends on SP at the paper's 28 wavelengths, 1 and 2 threads: analytic f64 vs
//! Embree user geometry vs Embree meshes at three chord-sag bounds (10, 1, 0.1 µm), each Embree variant with
//! and without f64 hit refinement. `cargo bench --bench backends`. The scene is built before timing.
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use diffcassi::analysis::linspace;
use diffcassi::prelude::*;
use diffcassi::surfaces::MeshResolution;
use diffcassi::tracer::{Backend, BackendConfig, Refine};

fn backends(c: &mut Criterion) {
    let mut g = c.benchmark_group("backends_sp_28wl");
    g.sample_size(10);
    let sys = SequentialSystem::build(&presets::spec("sp").unwrap()).unwrap();
    let batch = RayBatch::seeded_workload(&sys, 2_000, &linspace(450.0, 650.0, 28), 1000).unwrap();
    g.throughput(Throughput::Elements(batch.len() as u64));
    let mut configs = vec![BackendConfig::default()];
    for refine in [Refine::F64, Refine::None] {
        configs.push(BackendConfig { backend: Backend::EmbreeUser, refine, ..Default::default() });
        for um in [10.0, 1.0, 0.1] {
            configs.push(BackendConfig { backend: Backend::EmbreeMesh, refine, mesh: MeshResolution::MaxSagErrorUm(um) });
        }
    }
    for cfg in configs {
        let tracer = cfg.build().unwrap();
        tracer.trace(&sys, &batch).unwrap(); // builds and caches the Embree scene
        for threads in [1usize, 2] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            g.bench_with_input(BenchmarkId::new(tracer.name(), format!("{threads}threads")), &batch, |b, batch| {
                b.iter(|| pool.install(|| tracer.trace(&sys, batch).unwrap()))
            });
        }
    }
    g.finish();
}

criterion_group!(benches, backends);
criterion_main!(benches);
