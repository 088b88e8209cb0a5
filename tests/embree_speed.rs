//! Embree packet modes (issue 23 item 5). The non-sequential tracer traces SP, AP and mSP (analytic user
//! geometry and 1 µm meshes; hexapolar bundles of every field at three wavelengths plus a seeded workload)
//! one ray at a time (`rtcIntersect1`) and in incoherent 16-wide packets of consecutive rays
//! (`rtcIntersect16`): the two must be bit-identical, whatever the thread count and chunk size. With f64
//! refinement over user geometry both reuse the roots the callback solved on the exact ray.
//!
//! Embree's coherent flag (`EmbreeOptions::coherent`, `RTC_RAY_QUERY_FLAG_COHERENT`) gives the same results
//! too, since the wrapper zeroes direction components below 1e-12 in coherent queries (Embree 4.3.3 lost
//! hits on packets holding such a lane: docs/nonsequential.md, "Embree's coherent flag"); the ignored
//! surveys below query the tracer's own scenes lane by lane:
//! `cargo test --release --test integration embree_speed:: -- --ignored --nocapture`.
#![cfg(feature = "embree")]
use diffcassi::prelude::*;
use diffcassi::surfaces::MeshResolution;
use diffcassi::tracer::embree::{with_flush_denormals, EmbreeOptions, EmbreeTracer, FloorCallbacks, FloorScenes, Ray, Refinement, SceneOptions};

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

/// Rays whose status or image position differ (bitwise) between two traces.
fn differing(a: &TracedBatch, b: &TracedBatch) -> Vec<usize> {
    (0..a.len()).filter(|&i| a.status[i] != b.status[i] || a.x[i].to_bits() != b.x[i].to_bits() || a.y[i].to_bits() != b.y[i].to_bits()).collect()
}

fn modes() -> [EmbreeOptions; 2] {
    [EmbreeOptions::user(Refinement::F64), EmbreeOptions::mesh(MeshResolution::MaxSagErrorUm(1.0), Refinement::F64)]
}

#[test]
fn incoherent_packets_equal_single_rays_bit_for_bit() {
    for preset in ["sp", "ap", "msp"] {
        let sys = SequentialSystem::build(&presets::spec(preset).unwrap()).unwrap();
        let rays = bundle(&sys);
        for base in modes() {
            let single = EmbreeTracer::new(EmbreeOptions { packets: false, ..base }).trace(&sys, &rays).unwrap();
            let packets = EmbreeTracer::new(EmbreeOptions { packets: true, coherent: false, ..base }).trace(&sys, &rays).unwrap();
            let d = differing(&single, &packets);
            assert!(d.is_empty(), "{preset} {:?}: {} of {} rays differ, e.g. ray {}", base.scene.representation, d.len(), rays.len(), d[0]);
            assert_eq!(single, packets, "{preset}");
        }
    }
}

/// The packet path (with the exact-ray root reuse of user geometry) gives the same bits — results and per-ray
/// details — on one thread and on two, for any chunk size, and equals the single-ray path.
#[test]
fn packets_do_not_depend_on_thread_count_or_chunking() {
    for preset in ["sp", "msp"] {
        let sys = SequentialSystem::build(&presets::spec(preset).unwrap()).unwrap();
        let rays = bundle(&sys);
        for base in modes() {
            let run = |threads: usize, chunk_size: usize, packets: bool| {
                let t = EmbreeTracer::new(EmbreeOptions { packets, chunk_size, ..base });
                rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| t.trace_detailed(&sys, &rays).unwrap())
            };
            let one = run(1, 1024, true);
            assert!(one.0.ok_count() > rays.len() / 2, "{preset}: most rays arrive ({} of {})", one.0.ok_count(), rays.len());
            for (threads, chunk) in [(2, 1024), (2, 37), (1, 16)] {
                let other = run(threads, chunk, true);
                assert!(differing(&one.0, &other.0).is_empty(), "{preset} {:?}: {threads} threads, chunks of {chunk}", base.scene.representation);
                assert_eq!(one, other, "{preset} {:?}: {threads} threads, chunks of {chunk}", base.scene.representation);
            }
            assert_eq!(one, run(2, 64, false), "{preset} {:?}: single rays", base.scene.representation);
        }
    }
}

/// Not a pass/fail check: how many rays the coherent flag changes (recorded in docs/nonsequential.md).
/// Coherent packets (`RTC_RAY_QUERY_FLAG_COHERENT`) equal single rays bit for bit on SP and AP, user
/// geometry and 1 µm meshes. Before the wrapper set direction components below 1e-12 to 0 in coherent
/// queries, Embree 4.3.3 lost hits here (SP: 235 and 241 of 2 524 rays, AP: 37 and 40; one lane with a
/// component like −8.7e-19 spoils the coherent traversal of the other lanes of its packet:
/// tests/embree_repro/coherent.c, variant H).
#[test]
fn coherent_packets_equal_single_rays() {
    for preset in ["sp", "ap"] {
        let sys = SequentialSystem::build(&presets::spec(preset).unwrap()).unwrap();
        let rays = bundle(&sys);
        for base in modes() {
            let single = EmbreeTracer::new(EmbreeOptions { packets: false, ..base }).trace(&sys, &rays).unwrap();
            let coherent = EmbreeTracer::new(EmbreeOptions { packets: true, coherent: true, ..base }).trace(&sys, &rays).unwrap();
            let d = differing(&single, &coherent);
            assert!(d.is_empty(), "{preset} {:?}: coherent packets differ from single rays on {} of {} rays, e.g. ray {}", base.scene.representation, d.len(), rays.len(), d[0]);
        }
    }
}

/// Not a pass/fail check: the coherent flag on the tracer's *first* queries only (the launch rays, 16
/// consecutive rays per packet, all masks set, tnear = 0), lane by lane against `rtcIntersect1`, on the
/// tracer's own scenes. Separates "the flag loses hits on fresh bundles" from "it loses them on rays
/// restarted inside the scene" (docs/nonsequential.md, "Embree's coherent flag").
/// The floor benchmark (`bench nonsequential --floor`, docs/nonsequential.md "Fourth pass"): recording the
/// walk's packet queries changes no result bit, and replaying them — the same packets, through oracle
/// callbacks that report the recorded hit and through the real callbacks — gives every lane its recorded
/// answer (geometry and f32 distance, bit for bit) on SP and AP; a perturbed recorded ray is caught.
#[test]
fn floor_replay_reproduces_the_walks_queries() {
    for preset in ["sp", "ap"] {
        let sys = SequentialSystem::build(&presets::spec(preset).unwrap()).unwrap();
        let rays = bundle(&sys);
        let tracer = EmbreeTracer::new(EmbreeOptions::user(Refinement::F64));
        let (traced, mut log) = tracer.record_queries(&sys, &rays).unwrap();
        assert_eq!(traced, tracer.trace(&sys, &rays).unwrap(), "{preset}: recording changed the trace");
        assert_eq!(log.steps.len(), rays.len());
        let lanes = log.lane_queries();
        // Every ray that reaches the detector crosses every interface: one query each at least.
        let ok = traced.status.iter().filter(|s| **s == RayStatus::Ok).count();
        assert!(ok > rays.len() / 2 && lanes > 5 * ok, "{preset}: {ok} rays ok, {lanes} lane queries");
        let floor = FloorScenes::new(&sys, &SceneOptions::default()).unwrap();
        let packets = log.packets();
        for callbacks in [FloorCallbacks::NoQuery, FloorCallbacks::Oracle, FloorCallbacks::Exact] {
            let r = floor.replay(&packets, callbacks);
            assert_eq!(r.lane_queries, lanes, "{preset} {callbacks:?}");
            assert_eq!(r.differing, 0, "{preset} {callbacks:?}: lanes answered differently from the record");
            assert!(r.packet_queries * 16 >= lanes && r.packet_queries < lanes, "{preset} {callbacks:?}: {r:?}");
        }
        // A recorded ray started 0.5 mm further along: the real callbacks' distance differs.
        let step = log.steps.iter_mut().flat_map(|s| s.iter_mut()).find(|q| q.geom_id != u32::MAX && q.tnear == 0.0).unwrap();
        step.exact.org += step.exact.dir * 0.5;
        assert!(floor.replay(&log.packets(), FloorCallbacks::Exact).differing >= 1, "{preset}: a perturbed replay went unnoticed");
    }
}

#[test]
#[ignore]
fn coherent_first_queries_survey() {
    for preset in ["sp", "ap"] {
        let sys = SequentialSystem::build(&presets::spec(preset).unwrap()).unwrap();
        let rays = bundle(&sys);
        for base in modes() {
            let tracer = EmbreeTracer::new(base);
            let scene = tracer.scene_for(&sys).unwrap();
            let ray = |i: usize| {
                let (o, d) = (rays.origin(i), rays.direction(i).normalize());
                Ray::new(o.as_vec3().to_array(), d.as_vec3().to_array())
            };
            let (mut differ, mut shown) = (0usize, 0usize);
            for start in (0..rays.len()).step_by(16) {
                let packet: [Ray; 16] = std::array::from_fn(|k| ray((start + k).min(rays.len() - 1)));
                let hits = with_flush_denormals(|| scene.committed().intersect16_with(&packet, &[true; 16], true));
                for (k, h) in hits.iter().enumerate() {
                    let single = with_flush_denormals(|| scene.committed().intersect1(&packet[k]));
                    if *h != single {
                        differ += 1;
                        if shown < 3 {
                            shown += 1;
                            println!("  packet at ray {start}, lane {k}: coherent {h:?} vs single {single:?}");
                        }
                    }
                }
            }
            println!("{preset} {:?}: first queries, coherent packets differ from single rays on {differ} of {} lanes", base.scene.representation, rays.len().div_ceil(16) * 16);
        }
    }
}

/// Not a pass/fail check: the coherent flag on the tracer's *restarted* queries — each ray's k-th query
/// rebuilt from its hit records (origin: the exact point of interaction k − 1, direction: the one it
/// left with, that interface masked out, tnear = 0), 16 consecutive rays per packet, the lanes of rays
/// with fewer steps invalid — coherent `rtcIntersect16` against `rtcIntersect1`, counting lanes whose
/// geometry or distance differs. Variants isolate the trigger: all masks set (nothing excluded), the
/// origins moved 1 mm back along the ray (off the surface just left), and each differing lane queried
/// alone in an otherwise invalid coherent packet. (docs/nonsequential.md, "Embree's coherent flag".)
#[test]
#[ignore]
fn coherent_restarted_queries_survey() {
    use diffcassi::tracer::nonseq::{Role, Solids, SolidsOptions};
    for preset in ["sp", "ap"] {
        let sys = SequentialSystem::build(&presets::spec(preset).unwrap()).unwrap();
        let rays = bundle(&sys);
        let solids = Solids::build(&sys, &SolidsOptions::default()).unwrap();
        // The scene's mask bit of each optical object: its rank among the optical objects.
        let mut bit_of = std::collections::HashMap::new();
        for o in solids.objects.iter().filter(|o| o.is_optical()) {
            let s = match &o.role {
                Role::Interface { surfaces, .. } => surfaces[0],
                Role::Mirror { surface, .. } | Role::Detector { surface, .. } => *surface,
                _ => unreachable!(),
            };
            let n = bit_of.len() as u32;
            bit_of.insert(s as u32, 1u32 << n);
        }
        for base in modes() {
            let tracer = EmbreeTracer::new(EmbreeOptions { packets: false, ..base });
            let scene = tracer.scene_for(&sys).unwrap();
            let (_, _, log) = tracer.trace_with_hits(&sys, &rays).unwrap();
            // Query k ≥ 1 of ray i: (origin, direction, mask).
            let query = |i: usize, k: usize| -> Option<Ray> {
                let h = log.ray(i);
                let (a, b) = (h.get(k - 1)?, h.get(k)?);
                let fa = &sys.surfaces[a.first_surface as usize].frame;
                let fb = &sys.surfaces[b.first_surface as usize].frame;
                let (o, d) = (fa.point_to_global(a.point), fb.dir_to_global(b.direction).normalize());
                let mut r = Ray::new(o.as_vec3().to_array(), d.as_vec3().to_array());
                r.mask = !bit_of.get(&a.first_surface).copied().unwrap_or(0);
                Some(r)
            };
            let steps = (0..rays.len()).map(|i| log.ray(i).len()).max().unwrap_or(0);
            let same = |a: &diffcassi::tracer::embree::Hit, b: &diffcassi::tracer::embree::Hit| a.geom_id == b.geom_id && a.t == b.t;
            let (mut lanes, mut differ, mut unmasked, mut moved, mut alone, mut shown) = (0usize, 0usize, 0usize, 0usize, 0usize, 0usize);
            let (mut zeroed, mut tiny_packets, mut differ_packets, mut differ_tiny_packets) = (0usize, 0usize, 0usize, 0usize);
            // A direction component so small that Embree clamps its reciprocal (|d| < 1e-18, `rcp_safe`).
            let tiny = |r: &Ray| r.dir.iter().any(|c| *c != 0.0 && c.abs() < 1e-12);
            for k in 1..steps {
                for start in (0..rays.len()).step_by(16) {
                    let q: Vec<Option<Ray>> = (0..16).map(|l| (start + l < rays.len()).then(|| query(start + l, k)).flatten()).collect();
                    let valid: [bool; 16] = std::array::from_fn(|l| q[l].is_some());
                    if !valid.iter().any(|v| *v) {
                        continue;
                    }
                    let packet: [Ray; 16] = std::array::from_fn(|l| q[l].unwrap_or(Ray::new([0.0; 3], [0.0, 0.0, 1.0])));
                    let variant = |f: &dyn Fn(&Ray) -> Ray| -> usize {
                        let p: [Ray; 16] = std::array::from_fn(|l| f(&packet[l]));
                        let hits = with_flush_denormals(|| scene.committed().intersect16_with(&p, &valid, true));
                        (0..16).filter(|&l| valid[l] && !same(&hits[l], &with_flush_denormals(|| scene.committed().intersect1(&p[l])))).count()
                    };
                    let hits = with_flush_denormals(|| scene.committed().intersect16_with(&packet, &valid, true));
                    lanes += valid.iter().filter(|v| **v).count();
                    let has_tiny = (0..16).any(|l| valid[l] && tiny(&packet[l]));
                    let d0 = (0..16).filter(|&l| valid[l] && !same(&hits[l], &with_flush_denormals(|| scene.committed().intersect1(&packet[l])))).count();
                    tiny_packets += has_tiny as usize;
                    differ_packets += (d0 > 0) as usize;
                    differ_tiny_packets += (d0 > 0 && has_tiny) as usize;
                    zeroed += variant(&|r| Ray { dir: r.dir.map(|c| if c.abs() < 1e-12 { 0.0 } else { c }), ..*r });
                    for l in (0..16).filter(|&l| valid[l]) {
                        let single = with_flush_denormals(|| scene.committed().intersect1(&packet[l]));
                        if !same(&hits[l], &single) {
                            differ += 1;
                            let mut only = [false; 16];
                            only[l] = true;
                            let h1 = with_flush_denormals(|| scene.committed().intersect16_with(&packet, &only, true));
                            alone += (!same(&h1[l], &single)) as usize;
                            if shown < 3 {
                                shown += 1;
                                println!("  query {k} of ray {}: coherent {:?} vs single {:?}; ray {:?}", start + l, hits[l], single, packet[l]);
                            }
                        }
                    }
                    unmasked += variant(&|r| Ray { mask: u32::MAX, ..*r });
                    moved += variant(&|r| {
                        let o = [0, 1, 2].map(|c| r.org[c] - r.dir[c]);
                        Ray { org: o, ..*r }
                    });
                }
            }
            println!(
                "{preset} {:?}: restarted queries: coherent ≠ single on {differ} of {lanes} lanes ({alone} of them also alone in the packet); all masks set: {unmasked}; origins 1 mm back: {moved}; direction components below 1e-12 set to 0: {zeroed}. Packets with a differing lane: {differ_packets}, {differ_tiny_packets} of them holding a lane with a direction component 0 < |c| < 1e-12 (such packets: {tiny_packets})",
                base.scene.representation
            );
        }
    }
}
