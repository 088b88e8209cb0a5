//! The lane-parallel f64 kernel against the scalar reference kernel: every preset and every surface kind
//! the presets lack (even aspheres with and without base curvature, conics with k ≠ 0 and the paraboloid,
//! an order-1 coordinate break), batches mixing wavelengths (each lane its own index table), off-axis and
//! vignetted rays, invalid inputs, odd batch lengths and chunk sizes (partial blocks), on every SIMD
//! dispatch level this CPU has. Agreement is bit for bit: identical statuses and stopping surfaces and
//! identical bits of every position and direction component (the extremes suite checks ≤ 1e-12 mm on its
//! constructed rays through its `analytic` helper).
use crate::common;
use diffcassi::prelude::*;
use diffcassi::spec::{Cell, SurfaceKind};
use diffcassi::tracer::{Kernel, SimdLevel};

fn agree(label: &str, simd: &TracedBatch, scalar: &TracedBatch) {
    assert_eq!(simd.status, scalar.status, "{label}: statuses");
    assert_eq!(simd.surface, scalar.surface, "{label}: surfaces");
    let bits = |b: &TracedBatch, i: usize| [b.x[i], b.y[i], b.z[i], b.dir_x[i], b.dir_y[i], b.dir_z[i]].map(f64::to_bits);
    let differ = (0..simd.len()).filter(|&i| bits(simd, i) != bits(scalar, i)).collect::<Vec<_>>();
    if let Some(&i) = differ.first() {
        let e = [simd.x[i] - scalar.x[i], simd.y[i] - scalar.y[i], simd.z[i] - scalar.z[i]];
        let de = [simd.dir_x[i] - scalar.dir_x[i], simd.dir_y[i] - scalar.dir_y[i], simd.dir_z[i] - scalar.dir_z[i]];
        panic!("{label}: {} of {} rays differ from the scalar kernel's bits, first ray {i} by {e:?} {de:?}", differ.len(), simd.len());
    }
}

/// Far-off-axis and steep rays (vignetted or missed somewhere) and invalid inputs, appended mid-batch.
fn push_odd_rays(batch: &mut RayBatch) {
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
}

/// Every level and two chunk sizes against the scalar kernel on `sys`.
fn check_levels(name: &str, sys: &SequentialSystem, batch: &RayBatch) {
    let scalar = AnalyticTracer { chunk_size: 1000, kernel: Kernel::Scalar };
    let want = scalar.trace(sys, batch).unwrap();
    let stopped = want.status.iter().filter(|s| **s != RayStatus::Ok).count();
    assert!(stopped >= 3, "{name}: the batch has rays that stop ({stopped})");
    assert!(want.status.iter().filter(|s| **s == RayStatus::Ok).count() >= batch.len() / 2, "{name}: most rays arrive");
    for level in SimdLevel::available() {
        for chunk in [1000, 13] {
            let t = AnalyticTracer { chunk_size: chunk, kernel: Kernel::Simd(Some(level)) };
            agree(&format!("{name} {level:?} chunk {chunk}"), &t.trace(sys, batch).unwrap(), &want);
        }
    }
}

#[test]
fn every_level_agrees_with_the_scalar_kernel_on_every_preset() {
    for name in presets::NAMES {
        let sys = SequentialSystem::build(&presets::spec(name).unwrap()).unwrap();
        // 3 wavelengths interleaved ray by ray in the seeded workload: lanes of a block differ in index.
        let mut batch = RayBatch::seeded_workload(&sys, 2001, &[450.0, 520.0, 650.0], 3).unwrap();
        push_odd_rays(&mut batch);
        check_levels(name, &sys, &batch);
    }
}

/// The surface kinds the presets lack, each on a refracting surface the whole bundle crosses: the even
/// asphere of the gradient tests (SP/mSP surface 16, with an order-1 tilted and decentred break at
/// surface 9; AP/mAP prism entrance faces), an even asphere on a flat base (c = 0: the Newton solve starts
/// from the vertex plane only), a conic with k ≠ 0 (an oblate ellipsoid) and a paraboloid (k = −1, the
/// quadratic's leading term can vanish), and an asphere whose conic start fails near the rim.
#[test]
fn every_level_is_bit_for_bit_the_scalar_kernel_on_every_surface_kind() {
    let with_s16 = |name: &str, label: &str, edit: &dyn Fn(&mut diffcassi::spec::SurfaceSpec)| {
        let mut spec = common::sp_like(name);
        edit(&mut spec.surfaces[16]);
        (label.to_string(), spec)
    };
    let systems = [
        ("sp asphere s16".to_string(), common::sp_like("sp")),
        ("msp asphere s16".to_string(), common::sp_like("msp")),
        ("ap asphere s4".to_string(), common::ap_like("ap", 4)),
        ("map asphere s6".to_string(), common::ap_like("map", 6)),
        with_s16("sp", "sp flat asphere s16", &|s| s.radius_mm = None),
        with_s16("sp", "sp strong asphere s16", &|s| s.asphere_coefficients = vec![Cell::fixed(-4e-3), Cell::fixed(3e-5), Cell::fixed(-1e-7)]),
        with_s16("sp", "sp ellipsoid s16", &|s| {
            s.kind = SurfaceKind::Standard;
            s.conic = Some(Cell::fixed(0.7));
            s.asphere_coefficients.clear();
        }),
        with_s16("msp", "msp paraboloid s16", &|s| {
            s.kind = SurfaceKind::Standard;
            s.conic = Some(Cell::fixed(-1.0));
            s.asphere_coefficients.clear();
        }),
    ];
    for (name, spec) in systems {
        let sys = SequentialSystem::build(&spec).unwrap();
        let mut batch = RayBatch::seeded_workload(&sys, 1001, &[450.0, 520.0, 650.0], 5).unwrap();
        push_odd_rays(&mut batch);
        check_levels(&name, &sys, &batch);
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
