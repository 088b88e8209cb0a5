//! The Embree mesh backend walks the same ghost trees as brute force (issue 23 follow-up): same paths,
//! powers and landing points on SP and AP, on the workload of `bench nonsequential` row (b).
//!
//! The defect this guards: the tessellated detector of SP was a hexagon inscribed in its circular clear
//! aperture (a plane's chord-sag error is 0 at one ring), so ghost rays landing far off axis between
//! hexagon and circle (`18R 17R`, `17R 16R`) missed it while brute force and the user geometry hit the
//! exact patch; 21 of the first 200 trees lost a path. The meshes now cover their apertures
//! (`scene::covering_mesh`) and hits outside the exact aperture are refused in f64.
#![cfg(feature = "embree")]
use diffcassi::prelude::*;
use diffcassi::surfaces::MeshResolution;
use diffcassi::tracer::embree::{EmbreeNextHit, EmbreeOptions, EmbreeTracer, Refinement, SceneOptions, SurfaceRepresentation};
use diffcassi::tracer::nonseq::{path_label, trace_trees, BruteForce, RayTree, SolidsOptions, TreeOptions};

fn mesh_1um() -> SceneOptions {
    SceneOptions { representation: SurfaceRepresentation::Mesh(MeshResolution::MaxSagErrorUm(1.0)), ..SceneOptions::default() }
}

/// `bench nonsequential`'s workload (4 wavelengths 450–650 nm, seed 1000), `per_wavelength` rays each.
fn workload(sys: &SequentialSystem, per_wavelength: usize) -> RayBatch {
    let ws = [450.0, 450.0 + 200.0 / 3.0, 450.0 + 400.0 / 3.0, 650.0];
    RayBatch::seeded_workload(sys, per_wavelength, &ws, 1000).unwrap()
}

/// Every tree: the same paths in the same order, powers within 1e-12 (relative), landing points within
/// 1e-6 mm. Returns the number of ghost arrivals compared.
fn assert_same_trees(label: &str, reference: &[RayTree], other: &[RayTree]) -> usize {
    let mut ghosts = 0;
    for (i, (a, b)) in reference.iter().zip(other).enumerate() {
        let (pa, pb): (Vec<String>, Vec<String>) = (a.arrivals.iter().map(|x| path_label(&x.path)).collect(), b.arrivals.iter().map(|x| path_label(&x.path)).collect());
        assert_eq!(pa, pb, "{label}: tree {i}: paths differ");
        assert_eq!(a.main_status, b.main_status, "{label}: tree {i}");
        for (x, y) in a.arrivals.iter().zip(&b.arrivals) {
            assert!((x.power - y.power).abs() <= 1e-12 * x.power, "{label}: tree {i} {}: power {} vs {}", path_label(&x.path), x.power, y.power);
            assert!((x.point - y.point).abs().max_element() <= 1e-6, "{label}: tree {i} {}: lands at {:?} vs {:?}", path_label(&x.path), x.point, y.point);
            ghosts += (!x.path.is_empty()) as usize;
        }
        assert!((a.ledger.detector - b.ledger.detector).abs() <= 1e-12, "{label}: tree {i}: detector power");
    }
    ghosts
}

#[test]
fn mesh_user_and_brute_force_walk_the_same_ghost_trees() {
    for preset in ["sp", "ap"] {
        let sys = SequentialSystem::build(&presets::spec(preset).unwrap()).unwrap();
        let rays = workload(&sys, 150);
        let opts = TreeOptions { order: 2, ..TreeOptions::default() };
        let brute = trace_trees(&BruteForce::new(&sys, &SolidsOptions::default()).unwrap(), &sys, &rays, &opts).unwrap();
        let user = trace_trees(&EmbreeNextHit::new(&sys, &SceneOptions::default()).unwrap(), &sys, &rays, &opts).unwrap();
        let mesh = trace_trees(&EmbreeNextHit::new(&sys, &mesh_1um()).unwrap(), &sys, &rays, &opts).unwrap();
        let g = assert_same_trees(&format!("{preset} embree-user"), &brute, &user);
        assert_same_trees(&format!("{preset} embree-mesh 1um"), &brute, &mesh);
        assert!(g > rays.len() / 2, "{preset}: only {g} ghost arrivals in {} trees", rays.len());
    }
}

/// The smallest case: one SP tree (ray 11 of the 50-per-wavelength workload) whose `18R 17R` ghost
/// lands more than 20 mm off axis, between the old hexagonal detector mesh and the detector's circle.
#[test]
fn far_off_axis_ghost_reaches_the_meshed_detector() {
    let sys = SequentialSystem::build(&presets::spec("sp").unwrap()).unwrap();
    let all = workload(&sys, 50);
    let mut rays = RayBatch::default();
    rays.push(all.origin(11), all.direction(11), all.wavelength_nm[11]);
    let opts = TreeOptions { order: 2, ..TreeOptions::default() };
    let brute = trace_trees(&BruteForce::new(&sys, &SolidsOptions::default()).unwrap(), &sys, &rays, &opts).unwrap();
    let mesh = trace_trees(&EmbreeNextHit::new(&sys, &mesh_1um()).unwrap(), &sys, &rays, &opts).unwrap();
    let far = brute[0].arrivals.iter().find(|a| path_label(&a.path) == "18R 17R").expect("brute force finds 18R 17R");
    assert!(far.point.truncate().length() > 20.0, "lands at {:?}", far.point);
    assert_same_trees("sp ray 11", &brute, &mesh);
}

/// The sequential Embree trace over 1 µm meshes (f64 refinement) reaches the detector exactly where the
/// user geometry does: rays parallel to the detector's normal, aimed at 64 points on circles of 0.999
/// and 1.001 of its clear radius r, and at r + 0.2 µm on two of the mesh's outer vertices (angles 0 and π;
/// the covering polygon overshoots the circle there by up to 1 µm, a margin refused in f64).
#[test]
fn meshed_detector_covers_its_clear_aperture_and_no_more() {
    use diffcassi::tracer::nonseq::{Role, Solids};
    let sys = SequentialSystem::build(&presets::spec("sp").unwrap()).unwrap();
    let user = EmbreeTracer::new(EmbreeOptions::user(Refinement::F64));
    let mesh = EmbreeTracer::new(EmbreeOptions::mesh(MeshResolution::MaxSagErrorUm(1.0), Refinement::F64));
    let solids = Solids::build(&sys, &SolidsOptions::default()).unwrap();
    let det = solids.objects.iter().find(|o| matches!(o.role, Role::Detector { .. })).unwrap();
    let diffcassi::surfaces::Aperture::Circular { semi_diameter_mm: r, .. } = det.patch.as_ref().unwrap().aperture else { panic!("circular detector aperture expected") };
    let mut targets: Vec<(f64, f64, RayStatus)> = Vec::new();
    for (scale, expect) in [(0.999, RayStatus::Ok), (1.001, RayStatus::Missed)] {
        targets.extend((0..64).map(|k| (scale * r, std::f64::consts::TAU * (k as f64 + 0.5) / 64.0, expect)));
    }
    targets.extend([0.0, std::f64::consts::PI].map(|a| (r + 2e-4, a, RayStatus::Missed)));
    let mut rays = RayBatch::default();
    for &(rho, a, _) in &targets {
        let at = |z: f64| det.frame.point_to_global(glam::DVec3::new(rho * a.cos(), rho * a.sin(), z));
        rays.push(at(-1.0), at(0.0) - at(-1.0), 520.0);
    }
    let (u, m) = (user.trace(&sys, &rays).unwrap(), mesh.trace(&sys, &rays).unwrap());
    for (i, &(rho, a, expect)) in targets.iter().enumerate() {
        assert_eq!(u.status[i], expect, "user geometry, ray {i} at ρ = {rho} mm, {a} rad");
        assert_eq!(m.status[i], expect, "1 µm mesh, ray {i} at ρ = {rho} mm, {a} rad");
        if expect == RayStatus::Ok {
            assert_eq!([u.x[i], u.y[i]].map(f64::to_bits), [m.x[i], m.y[i]].map(f64::to_bits), "ray {i}");
        }
    }
}

/// The meshes follow what each surface needs (issue 23 follow-up): on SP and AP at 1 µm, every optical
/// mesh covers its aperture with an overshoot ≤ 1 µm and a chord-sag error ≤ 1 µm, each plane holds at most
/// 4 triangles per boundary segment (a fine boundary ring, a coarse interior), no surface holds more
/// triangles than uniform rings out to the same boundary took (the covering meshes before: 6·n² for n =
/// the larger of the chord-sag and the overshoot ring counts), and the scene's circular optical meshes
/// hold at most half as many in all (SP: 33 996 against 90 906; the cemented doublet's curved faces, at
/// 43 and 54 rings for their chord sag, are most of what is left).
#[test]
fn optical_meshes_follow_what_each_surface_needs() {
    use diffcassi::surfaces::{tessellate, tessellate_covering, Aperture, SurfaceShape};
    use diffcassi::tracer::nonseq::{Role, Solids};
    for preset in ["sp", "ap"] {
        let sys = SequentialSystem::build(&presets::spec(preset).unwrap()).unwrap();
        let solids = Solids::build(&sys, &SolidsOptions::default()).unwrap();
        let (mut now, mut uniform, mut planes) = (0usize, 0usize, 0usize);
        for patch in solids.objects.iter().filter(|o| matches!(o.role, Role::Interface { .. } | Role::Detector { .. })).filter_map(|o| o.patch.as_ref()) {
            let Aperture::Circular { .. } = patch.aperture else { continue };
            let mesh = tessellate_covering(&patch.shape, &patch.aperture, MeshResolution::MaxSagErrorUm(1.0)).unwrap();
            assert!(mesh.max_sag_error_um <= 1.0 && mesh.boundary_error_um <= 1.0, "{preset}: {mesh:?}");
            let sag_rings = tessellate(&patch.shape, &patch.aperture, MeshResolution::MaxSagErrorUm(1.0)).unwrap().segments;
            let Aperture::Circular { semi_diameter_mm: r, .. } = patch.aperture else { unreachable!() };
            let cover_rings = (std::f64::consts::PI / (1.0 / (1.0 + 1e-3 / r)).acos() / 6.0).ceil() as usize;
            uniform += 6 * sag_rings.max(cover_rings).pow(2);
            now += mesh.triangles.len();
            eprintln!("{preset}: r = {r:.3} mm, {:?}: {} rings, {} triangles (uniform: {})", patch.shape, mesh.segments, mesh.triangles.len(), 6 * sag_rings.max(cover_rings).pow(2));
            assert!(mesh.triangles.len() <= 6 * sag_rings.max(cover_rings).pow(2), "{preset}: r = {r} mm: more triangles than uniform rings");
            if matches!(patch.shape, SurfaceShape::Plane | SurfaceShape::Paraxial { .. }) {
                planes += 1;
                assert!(mesh.triangles.len() <= 4 * 6 * cover_rings, "{preset}: a plane of r = {r} mm: {} triangles", mesh.triangles.len());
            }
        }
        eprintln!("{preset}: circular optical meshes at 1 µm: {now} triangles (uniform rings to the same boundaries: {uniform}); {planes} planes");
        assert!(planes > 0 && 2 * now <= uniform, "{preset}: {now} triangles against {uniform}");
    }
}
