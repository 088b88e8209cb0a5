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

/// SP with its objective made inert (f = 1e15 mm), so a hand-made ray reaches the prism unchanged in
/// both tracers.
fn bare_prism() -> SequentialSystem {
    let mut spec = presets::spec("sp").unwrap();
    spec.surfaces[2].focal_length_mm.as_mut().unwrap().value = 1e15;
    SequentialSystem::build(&spec).unwrap()
}

/// A ray that, inside the prism, makes `internal_deg` with the entry normal (toward the exit normal) and
/// `lift` (tan of its y slope), entering at the entry face's vertex; returned in object space (20 mm
/// before the face).
fn prism_ray(sys: &SequentialSystem, internal_deg: f64, lift: f64, entry_y_mm: f64, wavelength_nm: f64) -> RayBatch {
    use glam::DVec3;
    let (f6, f12) = (sys.surfaces[6].frame, sys.surfaces[12].frame);
    let (n6, n12) = (f6.rotation.z_axis, f12.rotation.z_axis);
    let angle = n6.angle_between(n12);
    let axis = n6.cross(n12).normalize();
    let d_in = (glam::DQuat::from_axis_angle(axis, internal_deg.to_radians().min(angle)) * n6 + DVec3::Y * lift).normalize();
    let n_glass = sys.indices(wavelength_nm).unwrap()[6];
    // Snell's law is reversible: the air-side direction is minus the refraction of −d_in out of the glass.
    let d_ext = -diffcassi::tracer::kernel::refract(-d_in, n6, n_glass, 1.0).unwrap();
    let mut rays = RayBatch::default();
    let entry = f6.point_to_global(DVec3::new(0.0, entry_y_mm, 0.0));
    rays.push(entry - d_ext * 20.0, d_ext, wavelength_nm);
    rays
}

#[test]
fn total_internal_reflection_is_followed_and_side_faces_absorb() {
    let sys = bare_prism();
    // 10° from the entry normal ⇒ 50° on the exit face, beyond N-BK7's critical angle (41.1°).
    let rays = prism_ray(&sys, 10.0, 0.0, 0.0, 520.0);
    let seq = AnalyticTracer::default().trace(&sys, &rays).unwrap();
    assert_eq!((seq.status[0], seq.surface[0]), (RayStatus::TotalInternalReflection, 12), "sequential: TIR at the exit face");
    for opts in [EmbreeOptions::user(Refinement::F64), EmbreeOptions::mesh(MeshResolution::MaxSagErrorUm(1.0), Refinement::None)] {
        let (out, det) = EmbreeTracer::new(opts).trace_detailed(&sys, &rays).unwrap();
        eprintln!("TIR ray: {:?} at surface {}, {} reflections, {} interactions", out.status[0], out.surface[0], det.reflections[0], det.interactions[0]);
        assert!(det.reflections[0] >= 1, "the ray reflected and was followed");
        assert_ne!(out.status[0], RayStatus::TotalInternalReflection);
        assert!(det.interactions[0] >= 2);
    }
    // The chief-like ray (30°) refracts out normally in both tracers.
    let ok = prism_ray(&sys, 30.0, 0.0, 0.0, 520.0);
    let (out, det) = EmbreeTracer::new(EmbreeOptions::default()).trace_detailed(&sys, &ok).unwrap();
    let seq = AnalyticTracer::default().trace(&sys, &ok).unwrap();
    assert_eq!((out.status[0], seq.status[0], det.reflections[0]), (RayStatus::Ok, RayStatus::Ok, 0));
    assert!((out.x[0] - seq.x[0]).abs() < 1e-9 && (out.y[0] - seq.y[0]).abs() < 1e-9);

    // Near the top of the entry face and steeply upward inside the glass (and its mirror image): leaves
    // through the prism's top (bottom), a side wall.
    let mut batch = prism_ray(&sys, 20.0, 0.6, 5.5, 520.0);
    batch.extend(&prism_ray(&sys, 20.0, -0.6, -5.5, 520.0));
    batch.extend(&ok);
    let (out, _) = EmbreeTracer::new(EmbreeOptions::default()).trace_detailed(&sys, &batch).unwrap();
    let absorbed = out.status.iter().filter(|s| **s == RayStatus::Absorbed).count();
    assert_eq!(absorbed, 2, "{:?}", out.status);
    // The prism solid's walls start at its entry face (6) and at the stop plane inside it (8).
    assert!([6, 8].contains(&out.surface[0]) && [6, 8].contains(&out.surface[1]), "{:?}", out.surface);
    assert_eq!(out.status[2], RayStatus::Ok);
    // The sequential model has no side faces: those rays reach the exit face (and totally reflect there).
    let seq = AnalyticTracer::default().trace(&sys, &batch).unwrap();
    assert_eq!(&seq.status[..2], &[RayStatus::TotalInternalReflection; 2]);
    assert_eq!(&seq.surface[..2], &[12, 12]);
}

#[test]
fn misuse_gives_errors_not_crashes() {
    let sys = SequentialSystem::build(&presets::spec("sp").unwrap()).unwrap();
    let t = EmbreeTracer::new(EmbreeOptions::default());
    // Zero rays.
    let empty = t.trace(&sys, &RayBatch::default()).unwrap();
    assert!(empty.is_empty());
    // NaN / zero-length rays are classified, and nothing non-finite comes out.
    let mut bad = RayBatch::default();
    bad.push(glam::DVec3::new(f64::NAN, 0.0, 0.0), glam::DVec3::Z, 520.0);
    bad.push(glam::DVec3::ZERO, glam::DVec3::ZERO, 520.0);
    bad.push(glam::DVec3::ZERO, glam::DVec3::new(0.0, f64::INFINITY, 1.0), 520.0);
    let out = t.trace(&sys, &bad).unwrap();
    assert!(out.status.iter().all(|s| *s == RayStatus::InvalidInput), "{:?}", out.status);
    assert!(out.x.iter().chain(&out.y).chain(&out.dir_z).all(|v| v.is_finite()));
    // Inconsistent columns.
    let mut ragged = RayBatch::chief_rays(&sys, &[[0.0, 0.0]], 520.0).unwrap();
    ragged.wavelength_nm.push(520.0);
    assert!(t.trace(&sys, &ragged).is_err());
    // Degenerate mesh requests.
    let rays = RayBatch::chief_rays(&sys, &[[0.0, 0.0]], 520.0).unwrap();
    for (res, needle) in [(MeshResolution::Segments(0), "segments = 0"), (MeshResolution::Segments(1_000_000_000), "segments = 1000000000"), (MeshResolution::MaxSagErrorUm(-1.0), "-1")] {
        let e = EmbreeTracer::new(EmbreeOptions::mesh(res, Refinement::F64)).trace(&sys, &rays).unwrap_err().to_string();
        assert!(e.contains(needle), "{e}");
    }
    // A wavelength outside the glass range is an error for the batch, as in the analytic tracer.
    let far = RayBatch::chief_rays(&sys, &[[0.0, 0.0]], 520.0).map(|mut b| {
        b.wavelength_nm[0] = 5000.0;
        b
    });
    assert!(t.trace(&sys, &far.unwrap()).is_err());
    // Bounce limit 0 is refused.
    let mut o = EmbreeOptions::default();
    o.max_bounces = 0;
    assert!(EmbreeTracer::new(o).trace(&sys, &rays).is_err());
}

#[test]
fn results_do_not_depend_on_threads_or_packets() {
    let sys = SequentialSystem::build(&presets::spec("msp").unwrap()).unwrap();
    let rays = RayBatch::seeded_workload(&sys, 2000, &[450.0, 650.0], 7).unwrap();
    let run = |threads: usize, packets: bool| {
        let mut o = EmbreeOptions::mesh(MeshResolution::MaxSagErrorUm(1.0), Refinement::None);
        o.packets = packets;
        o.chunk_size = 64;
        let t = EmbreeTracer::new(o);
        rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| t.trace(&sys, &rays).unwrap())
    };
    let a = run(1, true);
    assert_eq!(a, run(2, true));
    assert_eq!(a, run(2, false));
}

#[test]
fn cli_backend_flags_keep_the_csv_columns() {
    let dir = tempfile::tempdir().unwrap();
    let exe = env!("CARGO_BIN_EXE_diffcassi");
    let run = |args: &[&str]| {
        let out = std::process::Command::new(exe).args(args).output().unwrap();
        assert!(out.status.success(), "{args:?}: {}", String::from_utf8_lossy(&out.stderr));
        String::from_utf8_lossy(&out.stdout).to_string()
    };
    let read = |name: &str| std::fs::read_to_string(dir.path().join(name)).unwrap();
    let header = |text: &str| text.lines().find(|l| !l.starts_with('#')).unwrap().to_string();
    let p = |n: &str| dir.path().join(n).to_string_lossy().to_string();
    run(&["distortion", "--preset", "ap", "--csv", &p("a.csv")]);
    run(&["distortion", "--preset", "ap", "--backend", "embree-user", "--refine", "f64", "--csv", &p("u.csv")]);
    run(&["distortion", "--preset", "ap", "--backend", "embree-mesh", "--mesh-max-sag-um", "0.5", "--refine", "none", "--csv", &p("m.csv")]);
    assert_eq!(header(&read("a.csv")), header(&read("u.csv")));
    assert_eq!(header(&read("a.csv")), header(&read("m.csv")));
    run(&["spot", "--preset", "sp", "--backend", "embree-mesh", "--mesh-segments", "24", "--csv", &p("s.csv")]);
    run(&["spot", "--preset", "sp", "--csv", &p("s0.csv")]);
    assert_eq!(header(&read("s.csv")), header(&read("s0.csv")));
    // Refined Embree reproduces the analytic CSV's numbers.
    let nums = |t: &str| t.lines().filter(|l| !l.starts_with('#')).skip(1).flat_map(|l| l.split(',').filter_map(|v| v.parse::<f64>().ok()).collect::<Vec<_>>()).collect::<Vec<_>>();
    let (a, u) = (nums(&read("a.csv")), nums(&read("u.csv")));
    assert_eq!(a.len(), u.len());
    assert!(a.iter().zip(&u).all(|(x, y)| (x - y).abs() <= 1e-6 * (1.0 + x.abs())));
    // Bad values are errors naming the flag value.
    for (args, needle) in [
        (vec!["distortion", "--preset", "sp", "--backend", "embree-mush"], "embree-mush"),
        (vec!["distortion", "--preset", "sp", "--backend", "embree-user", "--refine", "f32"], "f32"),
        (vec!["distortion", "--preset", "sp", "--refine", "none"], "Embree backends only"),
        (vec!["distortion", "--preset", "sp", "--backend", "embree-mesh", "--mesh-segments", "0"], "segments = 0"),
    ] {
        let out = std::process::Command::new(exe).args(&args).output().unwrap();
        assert!(!out.status.success());
        assert!(String::from_utf8_lossy(&out.stderr).contains(needle), "{args:?}: {}", String::from_utf8_lossy(&out.stderr));
    }
}
