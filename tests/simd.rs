//! The lane-parallel f64 kernel against the scalar reference kernel: every preset, batches mixing
//! wavelengths (each lane its own index table), off-axis and vignetted rays, invalid inputs, odd batch
//! lengths and chunk sizes (partial blocks), on every SIMD dispatch level this CPU has. Agreement is
//! ≤ 1e-12 mm per ray with identical statuses and stopping surfaces (the extremes suite checks the same
//! on its constructed rays through its `analytic` helper).
use diffcassi::prelude::*;
use diffcassi::tracer::{Kernel, SimdLevel};

fn agree(label: &str, simd: &TracedBatch, scalar: &TracedBatch) {
    assert_eq!(simd.status, scalar.status, "{label}: statuses");
    assert_eq!(simd.surface, scalar.surface, "{label}: surfaces");
    for i in 0..simd.len() {
        let e = [simd.x[i] - scalar.x[i], simd.y[i] - scalar.y[i], simd.z[i] - scalar.z[i]];
        let de = [simd.dir_x[i] - scalar.dir_x[i], simd.dir_y[i] - scalar.dir_y[i], simd.dir_z[i] - scalar.dir_z[i]];
        assert!(e.iter().chain(&de).all(|v| v.abs() <= 1e-12), "{label} ray {i}: position/direction differ by {e:?} {de:?}");
    }
}

#[test]
fn every_level_agrees_with_the_scalar_kernel_on_every_preset() {
    let scalar = AnalyticTracer { chunk_size: 1000, kernel: Kernel::Scalar };
    for name in presets::NAMES {
        let sys = SequentialSystem::build(&presets::spec(name).unwrap()).unwrap();
        // 3 wavelengths interleaved ray by ray in the seeded workload: lanes of a block differ in index.
        let mut batch = RayBatch::seeded_workload(&sys, 2001, &[450.0, 520.0, 650.0], 3).unwrap();
        // Far-off-axis and steep rays (vignetted or missed somewhere) and invalid inputs, mid-batch.
        for (k, (o, d)) in [
            ([40.0, -30.0, 0.0], [0.3, 0.2, 1.0]),
            ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0]),
            ([0.0, 0.0, 0.0], [0.0, 0.0, 0.0]),
            ([f64::NAN, 0.0, 0.0], [0.0, 0.0, 1.0]),
            ([0.1, 0.1, 0.0], [0.0, 0.0, -1.0]),
            ([1e-3, 2e-3, 0.0], [1e-200, 1e-200, 1e-200]),
        ]
        .into_iter()
        .enumerate()
        {
            batch.push(glam::DVec3::from(o), glam::DVec3::from(d), [450.0, 520.0, 650.0][k % 3]);
        }
        let want = scalar.trace(&sys, &batch).unwrap();
        let stopped = want.status.iter().filter(|s| **s != RayStatus::Ok).count();
        assert!(stopped >= 3, "{name}: the batch has rays that stop ({stopped})");
        for level in SimdLevel::available() {
            for chunk in [1000, 13] {
                let t = AnalyticTracer { chunk_size: chunk, kernel: Kernel::Simd(Some(level)) };
                agree(&format!("{name} {level:?} chunk {chunk}"), &t.trace(&sys, &batch).unwrap(), &want);
            }
        }
    }
}

#[test]
fn simd_results_do_not_depend_on_the_thread_count() {
    let sys = SequentialSystem::build(&presets::spec("msp").unwrap()).unwrap();
    let batch = RayBatch::seeded_workload(&sys, 3000, &[450.0, 650.0], 9).unwrap();
    let t = AnalyticTracer { chunk_size: 77, kernel: Kernel::default() };
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap().install(|| t.trace(&sys, &batch).unwrap());
    let two = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap().install(|| t.trace(&sys, &batch).unwrap());
    assert_eq!(one, two);
}

#[test]
fn a_level_the_cpu_lacks_is_a_clear_error() {
    for level in [SimdLevel::Avx512, SimdLevel::Avx2, SimdLevel::Portable] {
        let r = Kernel::Simd(Some(level)).resolve();
        if level.is_available() {
            assert_eq!(r.unwrap(), Some(level));
        } else {
            assert!(r.unwrap_err().to_string().contains(level.name()));
        }
    }
    assert!("simd-sse9".parse::<Kernel>().is_err());
}
