//! Embree packet modes (issue 23 item 5): Embree's coherent-ray flag (`RTC_RAY_QUERY_FLAG_COHERENT`,
//! frustum traversal) was once recorded as dropping hits on SP (docs/architecture.md). Here the
//! non-sequential tracer runs SP and AP with single rays, incoherent packets and coherent packets, over
//! analytic user geometry and meshes: every mode must give bit-identical results (the C reproducer in
//! tests/embree_repro/ checks the flag against `rtcIntersect1` directly).
use diffcassi::prelude::*;
use diffcassi::surfaces::MeshResolution;
use diffcassi::tracer::embree::{EmbreeOptions, EmbreeTracer, Refinement};

fn bundle(sys: &SequentialSystem) -> RayBatch {
    let pupil = PupilPattern::Hexapolar { rings: 6 }.points();
    let mut all = RayBatch::seeded_workload(sys, 500, &[450.0, 650.0], 7).unwrap();
    for f in sys.spec.fields_mm.clone() {
        for w in [450.0, 520.0, 650.0] {
            all.extend(&RayBatch::for_field(sys, f, &pupil, w).unwrap());
        }
    }
    all
}

#[test]
fn coherent_and_incoherent_packets_and_single_rays_agree_bit_for_bit() {
    for preset in ["sp", "ap"] {
        let sys = SequentialSystem::build(&presets::spec(preset).unwrap()).unwrap();
        let rays = bundle(&sys);
        for base in [EmbreeOptions::user(Refinement::F64), EmbreeOptions::mesh(MeshResolution::MaxSagErrorUm(1.0), Refinement::F64)] {
            let single = EmbreeTracer::new(EmbreeOptions { packets: false, ..base }).trace(&sys, &rays).unwrap();
            let incoherent = EmbreeTracer::new(EmbreeOptions { packets: true, coherent: false, ..base }).trace(&sys, &rays).unwrap();
            let coherent = EmbreeTracer::new(EmbreeOptions { packets: true, coherent: true, ..base }).trace(&sys, &rays).unwrap();
            for (name, other) in [("incoherent packets", &incoherent), ("coherent packets", &coherent)] {
                let differ: Vec<usize> = (0..rays.len())
                    .filter(|&i| single.status[i] != other.status[i] || single.x[i].to_bits() != other.x[i].to_bits() || single.y[i].to_bits() != other.y[i].to_bits())
                    .collect();
                assert!(
                    differ.is_empty(),
                    "{preset} {:?}: {name} differ from single rays on {} of {} rays, e.g. ray {}: {:?} ({}, {}) vs {:?} ({}, {})",
                    base.scene.representation,
                    differ.len(),
                    rays.len(),
                    differ[0],
                    single.status[differ[0]],
                    single.x[differ[0]],
                    single.y[differ[0]],
                    other.status[differ[0]],
                    other.x[differ[0]],
                    other.y[differ[0]]
                );
                assert_eq!(&single, other, "{preset}: {name}");
            }
        }
    }
}
