//! Cost of derivatives: trace + Jacobian for 1, 10 and 50 free parameters against a plain trace, on SP
//! (10 000 rays at 3 wavelengths). `cargo bench --bench derivatives`; the ratio to `plain` is the cost.
//! With the `embree` feature also the Jacobians at refined Embree hits (`embree_jacobian/*`) against a
//! plain Embree trace (`embree_plain`).
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use diffcassi::diff::{Param, ParamSet};
use diffcassi::materials::GlassCatalog;
use diffcassi::prelude::*;
use diffcassi::spec::Driver;

/// The first `k` free-able parameters of SP: fixed cells in surface order, then glass and ray parameters.
fn params(spec: &SystemSpec, k: usize) -> Vec<Param> {
    let mut v = Vec::new();
    for (i, s) in spec.surfaces.iter().enumerate() {
        for col in s.present_columns() {
            if s.cell(&col).map(|c| c.driver == Driver::Fixed).unwrap_or(false) && i + 1 < spec.surfaces.len() {
                v.push(Param::Cell { surface: i, column: col });
            }
        }
    }
    for t in ["glass_nd:N-BK7", "glass_vd:N-BK7", "glass_nd:N-BAF10", "wavelength", "ray.origin_x", "ray.dir_y"] {
        v.push(Param::parse(t).unwrap());
    }
    assert!(v.len() >= k, "only {} parameters", v.len());
    v.truncate(k);
    v
}

fn derivative_cost(c: &mut Criterion) {
    let mut g = c.benchmark_group("trace_jacobian_sp");
    g.sample_size(10);
    let spec = presets::spec("sp").unwrap();
    let sys = SequentialSystem::build(&spec).unwrap();
    let rays = RayBatch::seeded_workload(&sys, 10_000, &[450.0, 520.0, 650.0], 11).unwrap();
    g.throughput(Throughput::Elements(rays.len() as u64));
    let tracer = AnalyticTracer::default();
    g.bench_function("plain", |b| b.iter(|| tracer.trace(&sys, &rays).unwrap()));
    for k in [1usize, 10, 50] {
        let ds = ParamSet::new(spec.clone(), GlassCatalog::builtin(), params(&spec, k)).unwrap().build().unwrap();
        g.bench_with_input(BenchmarkId::new("jacobian", format!("{k}params")), &rays, |b, rays| b.iter(|| ds.trace(rays).unwrap()));
    }
    // The same Jacobians at refined Embree hits (user geometry): the Embree trace recording its hits,
    // then implicit differentiation at them; and the plain Embree trace for its own ratio.
    #[cfg(feature = "embree")]
    {
        use diffcassi::tracer::embree::{EmbreeOptions, EmbreeTracer, Refinement};
        let embree = EmbreeTracer::new(EmbreeOptions::user(Refinement::F64));
        g.bench_function("embree_plain", |b| b.iter(|| embree.trace(&sys, &rays).unwrap()));
        for k in [1usize, 10, 50] {
            let ds = ParamSet::new(spec.clone(), GlassCatalog::builtin(), params(&spec, k)).unwrap().build().unwrap();
            g.bench_with_input(BenchmarkId::new("embree_jacobian", format!("{k}params")), &rays, |b, rays| b.iter(|| ds.trace_embree(&embree, rays).unwrap()));
        }
    }
    g.finish();
}

criterion_group!(benches, derivative_cost);
criterion_main!(benches);
