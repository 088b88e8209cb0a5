//! The Rust half of the C++ overhead bench (`cpp/bench/bench_trace.cpp` is the C++ half): trace
//! throughput of `AnalyticTracer::trace` through the Rust API alone, on the same workloads (SP, 4
//! wavelengths, seeded pupil points over the four fields) at 1e3 and 1e6 rays.
//!
//! ```text
//! cargo run --release -p diffcassi-cpp --example trace_throughput [-- --quick]
//! ```
use diffcassi::prelude::*;
use std::time::Instant;

/// Workload shared with the C++ bench: `n` rays, a quarter at each wavelength.
pub const WAVELENGTHS_NM: [f64; 4] = [450.0, 520.0, 585.0, 650.0];
pub const SEED: u64 = 7;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() -> diffcassi::Result<()> {
    let quick = std::env::args().any(|a| a == "--quick");
    let sys = SequentialSystem::build(&presets::spec("sp")?)?;
    let tracer = AnalyticTracer::default();
    println!("Rust API, AnalyticTracer::trace, preset sp, {} rayon threads", rayon::current_num_threads());
    println!("| rays | reps | median ms/trace | M rays/s (median) | M rays/s (best) |");
    println!("|---|---|---|---|---|");
    for (n, reps) in [(1_000usize, if quick { 50 } else { 2000 }), (1_000_000, if quick { 2 } else { 15 })] {
        let rays = RayBatch::seeded_workload(&sys, n / WAVELENGTHS_NM.len(), &WAVELENGTHS_NM, SEED)?;
        std::hint::black_box(tracer.trace(&sys, &rays)?); // warm-up
        let times: Vec<f64> = (0..reps)
            .map(|_| {
                let t = Instant::now();
                let out = tracer.trace(&sys, &rays);
                let dt = t.elapsed().as_secs_f64();
                std::hint::black_box(out).map(|_| dt)
            })
            .collect::<diffcassi::Result<_>>()?;
        let best = times.iter().copied().fold(f64::INFINITY, f64::min);
        let med = median(times);
        println!("| {n} | {reps} | {:.4} | {:.3} | {:.3} |", 1e3 * med, n as f64 / med / 1e6, n as f64 / best / 1e6);
    }
    Ok(())
}
