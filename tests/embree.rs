//! The Embree backend against the analytic tracer (issue 3), on the four presets.
#![cfg(feature = "embree")]
use diffcassi::prelude::*;
use diffcassi::surfaces::MeshResolution;
use diffcassi::tracer::embree::{EmbreeOptions, EmbreeTracer, Refinement};

/// Grid-distortion chief rays (13×13 over ±2.5 mm) and hexapolar spot rays of the system's fields, at
/// 450/520/650 nm.
fn workload(sys: &SequentialSystem) -> RayBatch {
    let mut rays = RayBatch::default();
    for &w in &[450.0, 520.0, 650.0] {
        let mut fields = Vec::new();
        for i in 0..13 {
            for j in 0..13 {
                fields.push([-2.5 + 5.0 * j as f64 / 12.0, 2.5 - 5.0 * i as f64 / 12.0]);
            }
        }
        rays.extend(&RayBatch::chief_rays(sys, &fields, w).unwrap());
        for f in &sys.spec.fields_mm {
            rays.extend(&RayBatch::for_field(sys, *f, &PupilPattern::Hexapolar { rings: 6 }.points(), w).unwrap());
        }
    }
    rays
}

/// (max, rms) position error in µm of the rays both tracers deliver, and the number whose status differs.
fn compare(a: &TracedBatch, b: &TracedBatch) -> (f64, f64, usize) {
    let (mut max, mut s2, mut n, mut differ) = (0.0f64, 0.0, 0usize, 0usize);
    for i in 0..a.len() {
        if a.status[i] != b.status[i] {
            if differ < 5 {
                eprintln!("ray {i}: {:?} at surface {} vs {:?}", a.status[i], a.surface[i], b.status[i]);
            }
            differ += 1;
            continue;
        }
        if a.status[i] == RayStatus::Ok {
            let e = 1e3 * ((a.x[i] - b.x[i]).powi(2) + (a.y[i] - b.y[i]).powi(2)).sqrt();
            max = max.max(e);
            s2 += e * e;
            n += 1;
        }
    }
    (max, (s2 / n.max(1) as f64).sqrt(), differ)
}

#[test]
fn refined_embree_equals_analytic_on_all_presets() {
    for preset in ["sp", "ap", "msp", "map"] {
        let sys = SequentialSystem::build(&presets::spec(preset).unwrap()).unwrap();
        let rays = workload(&sys);
        let exact = AnalyticTracer::default().trace(&sys, &rays).unwrap();
        assert_eq!(exact.ok_count(), rays.len(), "{preset}: every reference ray arrives");
        for (label, opts) in [
            ("embree-user", EmbreeOptions::user(Refinement::F64)),
            ("embree-mesh 1um", EmbreeOptions::mesh(MeshResolution::MaxSagErrorUm(1.0), Refinement::F64)),
        ] {
            let out = EmbreeTracer::new(opts).trace(&sys, &rays).unwrap();
            let (max, rms, differ) = compare(&out, &exact);
            eprintln!("{preset} {label} refine=f64: {} rays, max {max:.3e} µm, rms {rms:.3e} µm, status differs {differ}", rays.len());
            assert_eq!(differ, 0, "{preset} {label}");
            assert!(max <= 1e-3, "{preset} {label}: max error {max} µm > 1e-6 mm");
            // Directions too.
            for i in 0..rays.len() {
                let dd = (out.dir_x[i] - exact.dir_x[i]).abs().max((out.dir_y[i] - exact.dir_y[i]).abs());
                assert!(dd < 1e-9, "{preset} {label} ray {i}: direction differs by {dd}");
            }
        }
    }
}

#[test]
fn unrefined_error_is_measured_and_mesh_hits_stay_within_the_chord_sag_bound() {
    for preset in ["sp", "ap"] {
        let sys = SequentialSystem::build(&presets::spec(preset).unwrap()).unwrap();
        let rays = workload(&sys);
        let exact = AnalyticTracer::default().trace(&sys, &rays).unwrap();
        let user = EmbreeTracer::new(EmbreeOptions::user(Refinement::None));
        let (out, det) = user.trace_detailed(&sys, &rays).unwrap();
        let (max, rms, differ) = compare(&out, &exact);
        eprintln!("{preset} embree-user refine=none: max {max:.3} µm, rms {rms:.3} µm, status differs {differ}");
        assert_eq!(differ, 0);
        // f32 hits on exact surfaces: sub-µm, not exact.
        assert!(max < 1.0 && max > 0.0, "{preset}: {max} µm");
        assert!(det.max_hit_deviation_mm.iter().all(|d| *d < 1e-4));
        for um in [10.0, 1.0, 0.1] {
            let t = EmbreeTracer::new(EmbreeOptions::mesh(MeshResolution::MaxSagErrorUm(um), Refinement::None));
            let bound_mm = t.scene_for(&sys).unwrap().max_sag_error_um * 1e-3;
            assert!(bound_mm <= um * 1e-3);
            let (out, det) = t.trace_detailed(&sys, &rays).unwrap();
            let (max, rms, differ) = compare(&out, &exact);
            let worst_hit = det.max_hit_deviation_mm.iter().cloned().fold(0.0, f64::max);
            eprintln!("{preset} embree-mesh {um} µm refine=none: image max {max:.3} µm, rms {rms:.3} µm; worst hit {:.4} µm off its surface; status differs {differ}", worst_hit * 1e3);
            // Every hit point lies within the tessellation's chord-sag bound of the exact surface (plus
            // f32 rounding of global coordinates, ≤ 3e-5 mm here).
            assert!(worst_hit <= bound_mm + 3e-5, "{preset} {um}: {worst_hit} mm > bound {bound_mm} mm");
        }
    }
}
