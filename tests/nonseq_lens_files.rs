//! Real lens files in the non-sequential backends (issue 42): objects at infinity, Toroidal surfaces and
//! circular obscurations in the brute-force walk, the Embree tracer and the ghost analysis. The primary
//! (sequential-order) path of each non-sequential kernel lands where the analytic sequential tracer lands
//! (the tolerance of tests/embree.rs: positions within 1e-6 mm, directions within 1e-9), and a ray the
//! sequential tracer stops at an obscuration is stopped by the solids too.
//!
//! `cargo test --release --test integration nonseq_lens_files:: -- --nocapture` prints the measured errors.
use diffcassi::prelude::*;
use diffcassi::spec::zmx::{import_zmx_file, ZmxOptions};
use diffcassi::spec::SurfaceSpec;
use diffcassi::surfaces::Aperture;
use diffcassi::tracer::nonseq::{trace_trees, BruteForce, FresnelModel, Role, Solids, SolidsOptions, TreeOptions};
use glam::DVec3;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn run(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_diffcassi")).args(args).output().expect("the binary runs")
}

fn text(o: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
}

fn singlet_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/systems/singlet_at_infinity.toml")
}

/// tests/fixtures/systems/singlet_at_infinity.toml: N-BK7, R1 = 50, R2 = −80 mm, the stop 5 mm behind.
fn singlet_at_infinity() -> SystemSpec {
    diffcassi::spec::load_spec_file(singlet_path()).unwrap()
}

/// The singlet turned into a meniscus whose first surface is concave toward the object (R1 = −40 mm): its
/// rim lies in front of surface 1's vertex plane, where the sequential tracer starts the parallel beams.
fn meniscus_at_infinity() -> SystemSpec {
    let mut s = singlet_at_infinity();
    s.name = "meniscus at infinity".into();
    s.surfaces[1] = SurfaceSpec::standard(Some(-40.0), 6.0, Some("N-BK7"));
    s.surfaces[2] = SurfaceSpec::standard(Some(-20.0), 5.0, None);
    s
}

fn zmx(name: &str) -> SystemSpec {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/zmx").join(name);
    import_zmx_file(&path, &ZmxOptions::default()).unwrap_or_else(|e| panic!("{name}: {e}")).spec
}

/// rayoptics' Cassegrain (tests/fixtures/zmx) as a user makes it non-sequential-ready: the file traces
/// the secondary as transparent on the way in and the primary as transparent on the way out (sequential
/// order does not need more). Given the secondary's shadow as an obscuration (`OBSC 0 5.5`; the
/// secondary's mechanical radius is 4.34 mm) on a dummy plane 5 mm in front of the secondary (the hub that
/// holds it: on the secondary's own vertex plane, the disc would also stop the beam converging from the
/// primary, which meets that plane before the secondary's concave figure) and the primary's central hole as
/// the inner radius of its clear aperture (`CLAP 3 11.03`), the solids see what the sequential trace sees.
fn cassegrain_with_hole_and_shadow() -> SystemSpec {
    let mut s = zmx("cassegrain_mirrors_HoO_V2C18Ex03.zmx");
    let mut hub = SurfaceSpec::standard(None, 5.0, None);
    hub.aperture = Some(Aperture::CircularObscuration { min_radius_mm: 0.0, max_radius_mm: 5.5, decenter_x_mm: 0.0, decenter_y_mm: 0.0 });
    s.surfaces.insert(1, hub);
    s.surfaces[3].aperture = Some(Aperture::Circular { semi_diameter_mm: 11.03, min_radius_mm: 3.0, decenter_x_mm: 0.0, decenter_y_mm: 0.0 });
    s
}

fn build(spec: &SystemSpec) -> SequentialSystem {
    SequentialSystem::build(spec).unwrap_or_else(|e| panic!("{}: {e}", spec.name))
}

/// The system's fields (hexapolar, 4 rings) and chief rays of a 5×5 grid over ±`grid` (the field unit:
/// mm, or radians at infinity), at 450/520/650 nm.
fn workload(sys: &SequentialSystem, grid: f64) -> RayBatch {
    let mut rays = RayBatch::default();
    for &w in &[450.0, 520.0, 650.0] {
        let fields: Vec<[f64; 2]> = (0..25).map(|k| [grid * (-1.0 + 0.5 * (k % 5) as f64), grid * (-1.0 + 0.5 * (k / 5) as f64)]).collect();
        rays.extend(&RayBatch::chief_rays(sys, &fields, w).unwrap());
        for f in sys.fields_or_axis() {
            rays.extend(&RayBatch::for_field(sys, f, &PupilPattern::Hexapolar { rings: 4 }.points(), w).unwrap());
        }
    }
    rays
}

/// How one ray's primary path ended: status, surface (non-`ok`), and the landing point and direction
/// on the image surface (`ok`).
#[derive(Clone, Copy, Debug)]
struct Outcome {
    status: RayStatus,
    surface: u32,
    point: DVec3,
    dir: DVec3,
}

fn analytic(sys: &SequentialSystem, rays: &RayBatch) -> Vec<Outcome> {
    let t = AnalyticTracer::default().trace(sys, rays).unwrap();
    (0..rays.len()).map(|i| Outcome { status: t.status[i], surface: t.surface[i], point: DVec3::new(t.x[i], t.y[i], t.z[i]), dir: DVec3::new(t.dir_x[i], t.dir_y[i], t.dir_z[i]) }).collect()
}

/// The brute-force walk with reflections off (order 0): the primary path.
fn brute(sys: &SequentialSystem, rays: &RayBatch) -> Vec<Outcome> {
    let kernel = BruteForce::new(sys, &SolidsOptions::default()).unwrap();
    trace_trees(&kernel, sys, rays, &TreeOptions { order: 0, model: FresnelModel::Off, ..Default::default() })
        .unwrap()
        .iter()
        .map(|t| {
            let a = t.arrivals.first();
            Outcome { status: t.main_status.unwrap(), surface: t.main_surface, point: a.map_or(DVec3::NAN, |a| a.point), dir: a.map_or(DVec3::NAN, |a| a.direction) }
        })
        .collect()
}

/// Statuses equal ray for ray (the surface too where a ray is vignetted), landings within 1e-6 mm and
/// directions within 1e-9. Returns the counts of (landed, vignetted) rays.
fn agree(what: &str, exact: &[Outcome], got: &[Outcome]) -> (usize, usize) {
    let (mut max_um, mut max_dir, mut ok, mut stopped) = (0.0f64, 0.0f64, 0, 0);
    for (i, (e, g)) in exact.iter().zip(got).enumerate() {
        assert_eq!(e.status, g.status, "{what} ray {i}: {:?} at surface {} (sequential: {:?} at surface {})", g.status, g.surface, e.status, e.surface);
        if e.status == RayStatus::Vignetted {
            assert_eq!(e.surface, g.surface, "{what} ray {i}: vignetted at another surface");
            stopped += 1;
        }
        if e.status == RayStatus::Ok {
            ok += 1;
            assert!(g.point.is_finite() && g.dir.is_finite(), "{what} ray {i}");
            max_um = max_um.max(1e3 * (g.point.x - e.point.x).hypot(g.point.y - e.point.y));
            max_dir = max_dir.max((g.dir.x - e.dir.x).abs().max((g.dir.y - e.dir.y).abs()));
        }
    }
    eprintln!("{what}: {} rays, {ok} land (max {max_um:.3e} µm, direction {max_dir:.3e}), {stopped} stopped as in the sequential trace", exact.len());
    assert!(max_um <= 1e-3, "{what}: max error {max_um} µm > 1e-6 mm");
    assert!(max_dir < 1e-9, "{what}: direction differs by {max_dir}");
    (ok, stopped)
}

/// Every kernel: brute force, and (with Embree) the Embree tracer over analytic user geometry and 1 µm
/// meshes, both refined in f64.
fn agree_all(sys: &SequentialSystem, rays: &RayBatch) -> (usize, usize) {
    let exact = analytic(sys, rays);
    let counts = agree(&format!("{} brute", sys.name()), &exact, &brute(sys, rays));
    #[cfg(feature = "embree")]
    {
        use diffcassi::surfaces::MeshResolution;
        use diffcassi::tracer::embree::{EmbreeOptions, EmbreeTracer, Refinement};
        for (label, opts) in [("embree-user", EmbreeOptions::user(Refinement::F64)), ("embree-mesh 1um", EmbreeOptions::mesh(MeshResolution::MaxSagErrorUm(1.0), Refinement::F64))] {
            let t = EmbreeTracer::new(opts).trace(sys, rays).unwrap();
            let got: Vec<Outcome> = (0..rays.len())
                .map(|i| Outcome { status: t.status[i], surface: t.surface[i], point: DVec3::new(t.x[i], t.y[i], t.z[i]), dir: DVec3::new(t.dir_x[i], t.dir_y[i], t.dir_z[i]) })
                .collect();
            assert_eq!(agree(&format!("{} {label}", sys.name()), &exact, &got), counts, "{label}");
        }
    }
    counts
}

/// Item 1: the parallel beams of an object at infinity start in front of every solid (on their own line),
/// so a first surface concave toward the object — whose rim lies in front of the plane where the
/// sequential tracer starts them — is met from the front; every ray lands where the analytic tracer lands.
#[test]
fn objects_at_infinity_land_where_the_analytic_tracer_lands() {
    for spec in [singlet_at_infinity(), meniscus_at_infinity()] {
        let sys = build(&spec);
        assert!(sys.object_at_infinity());
        let solids = Solids::build(&sys, &SolidsOptions::default()).unwrap();
        let plane = solids.start_plane.expect("an object at infinity has a start plane");
        // In front of surface 1's figure over its (mechanical) clear aperture.
        let face = solids.objects.iter().find(|o| matches!(&o.role, Role::Interface { surfaces, .. } if surfaces[0] == 1)).unwrap();
        let r = face.patch.as_ref().unwrap().local_bounds().1.x;
        let rim_z = face.frame.point_to_global(DVec3::new(r, 0.0, face.patch.as_ref().unwrap().shape.sag(r, 0.0))).z;
        assert!(plane.z_mm < rim_z.min(0.0), "{}: start plane {} mm, rim at {rim_z} mm", sys.name(), plane.z_mm);
        let rays = workload(&sys, 3f64.to_radians());
        let (ok, _) = agree_all(&sys, &rays);
        assert_eq!(ok, rays.len(), "{}: every ray of the workload arrives", sys.name());
    }
    // The meniscus' figure at the pupil's edge (4 mm) lies in front of the vertex plane (else the test
    // above proves nothing).
    let sys = build(&meniscus_at_infinity());
    assert!(sys.surfaces[1].shape.as_ref().unwrap().sag(4.0, 0.0) < -0.1);
}

/// Items 1 and 3 on a reflecting telescope at infinity: rayoptics' Cassegrain with its secondary's shadow
/// (an obscuration on a dummy plane in front: an absorbing disc built in the beam) and its primary's hole.
/// Every ray has the analytic tracer's status (vignetted at the obscuration's surface 1 in the shadow) and
/// lands where it lands.
#[test]
fn cassegrain_at_infinity_with_its_shadow_and_hole_lands_where_the_analytic_tracer_lands() {
    let sys = build(&cassegrain_with_hole_and_shadow());
    let solids = Solids::build(&sys, &SolidsOptions::default()).unwrap();
    let disc = solids.objects.iter().find(|o| matches!(o.role, Role::Blade { surface: 1, interface: None })).expect("the shadow is an absorbing disc on the dummy plane");
    assert!(disc.vertices.iter().all(|v| v.z == 0.0 && v.x.hypot(v.y) <= 5.5 / (std::f64::consts::PI / 192.0).cos() + 1e-12));
    assert!(solids.start_plane.unwrap().z_mm < 0.0);
    let rays = workload(&sys, 0.5f64.to_radians());
    let (ok, stopped) = agree_all(&sys, &rays);
    assert!(ok > 100 && stopped > 20, "{ok} land, {stopped} stopped");
}

/// Item 3: an obscuration on a real lens face (the face absorbs in its obscured disc, from either side) and
/// an obscured ring on the stop plane in air (an absorbing annulus): the same statuses as the sequential
/// tracer, ray for ray — vignetted at the obscuration's surface — and the same landings.
#[test]
fn obscurations_stop_the_rays_the_sequential_tracer_vignettes() {
    let obsc = |lo: f64, hi: f64| Some(Aperture::CircularObscuration { min_radius_mm: lo, max_radius_mm: hi, decenter_x_mm: 0.3, decenter_y_mm: -0.2 });
    let mut on_face = singlet_at_infinity();
    on_face.name = "obscured face".into();
    on_face.surfaces[1].aperture = obsc(0.0, 2.0);
    let mut on_stop = singlet_at_infinity();
    on_stop.name = "obscured ring on the stop".into();
    on_stop.surfaces[3].aperture = obsc(1.0, 2.5);
    for (spec, surface) in [(on_face, 1u32), (on_stop, 3)] {
        let sys = build(&spec);
        let rays = workload(&sys, 3f64.to_radians());
        let exact = analytic(&sys, &rays);
        assert!(exact.iter().any(|o| o.status == RayStatus::Vignetted && o.surface == surface), "{}", sys.name());
        let (ok, stopped) = agree_all(&sys, &rays);
        assert!(ok > 100 && stopped > 20, "{}: {ok} land, {stopped} stopped", sys.name());
    }
}

/// A Mangin mirror (an N-BK7 meniscus silvered at its back) tilted 10° with a Coordinate Break, the image
/// 150 mm in front of it, beyond the object (the detector, a disc about the tilted axis, would otherwise
/// stand in the incoming beam, which crosses its plane as far off the axis as the image): its front face is crossed on the way in and, after the
/// reflection, on the way out toward −z (the sequential file lists it twice: surfaces 2 and 4). The solids
/// hold it once, with its media by side, and every ray lands where the analytic tracer lands.
#[test]
fn a_mangin_mirror_face_crossed_twice_is_one_face() {
    use crate::surfaces::{mirror, stop, system};
    let cb = |tx: f64, t: f64| SurfaceSpec::coordinate_break(0.0, 0.0, tx, 0.0, 0.0, t);
    let spec = system(
        "mangin",
        vec![
            SurfaceSpec::standard(None, 100.0, None),
            cb(10.0, 0.0),
            stop(SurfaceSpec::standard(Some(-150.0), 5.0, Some("N-BK7"))),
            mirror(Some(-120.0), None, -5.0),
            SurfaceSpec::standard(Some(-150.0), -150.0, None),
            SurfaceSpec::standard(None, 0.0, None),
        ],
        0.02,
    );
    let sys = build(&spec);
    // The detector beside the incoming beam: no margin (as tests/nonseq_mirrors.rs's tilted ellipsoid). The
    // default margins build too: the design beam (src/tracer/nonseq/design_beam.rs) finds the 25 mm disc,
    // 150 mm from the face, clear of it (margin unchanged), and they land as the analytic tracer does (below).
    let default = Solids::build(&sys, &SolidsOptions::default()).unwrap();
    eprintln!("mangin default solids: detector margin {} mm, {:?}", default.detector_margin_mm, default.design_beam_note);
    assert!(default.detector_margin_mm == 25.0 && default.design_beam_note.is_none());
    let options = SolidsOptions { detector_margin_mm: 0.0, ..Default::default() };
    let solids = Solids::build(&sys, &options).unwrap();
    let faces: Vec<(Vec<usize>, usize, usize)> = solids.objects.iter().filter_map(|o| if let Role::Interface { surfaces, front_medium, back_medium, .. } = &o.role { Some((surfaces.clone(), *front_medium, *back_medium)) } else { None }).collect();
    assert_eq!(faces, vec![(vec![2], 1, 2)], "one face: air on its −z side, glass (after surface 2) on its +z side");
    let rays = workload(&sys, 1.0);
    let exact = analytic(&sys, &rays);
    for (label, options) in [("mangin brute", options), ("mangin brute, default margins", SolidsOptions::default())] {
        let kernel = BruteForce::new(&sys, &options).unwrap();
        let got: Vec<Outcome> = trace_trees(&kernel, &sys, &rays, &TreeOptions { order: 0, model: FresnelModel::Off, ..Default::default() })
            .unwrap()
            .iter()
            .map(|t| {
                let a = t.arrivals.first();
                Outcome { status: t.main_status.unwrap(), surface: t.main_surface, point: a.map_or(DVec3::NAN, |a| a.point), dir: a.map_or(DVec3::NAN, |a| a.direction) }
            })
            .collect();
        let (ok, _) = agree(label, &exact, &got);
        assert_eq!(ok, rays.len(), "{label}");
    }
    #[cfg(feature = "embree")]
    {
        use diffcassi::tracer::embree::{EmbreeOptions, EmbreeTracer, Refinement, SceneOptions};
        let opts = EmbreeOptions { scene: SceneOptions { detector_margin_mm: 0.0, ..Default::default() }, ..EmbreeOptions::user(Refinement::F64) };
        let t = EmbreeTracer::new(opts).trace(&sys, &rays).unwrap();
        let got: Vec<Outcome> = (0..rays.len()).map(|i| Outcome { status: t.status[i], surface: t.surface[i], point: DVec3::new(t.x[i], t.y[i], t.z[i]), dir: DVec3::new(t.dir_x[i], t.dir_y[i], t.dir_z[i]) }).collect();
        assert_eq!(agree("mangin embree-user", &exact, &got).0, rays.len());
    }
}

/// US05331467-1 (tests/fixtures/zmx: an obscuration on the corrector's back, two Mangin mirrors, at
/// infinity) builds its solids — refused before — and its obscuration is its face's own aperture (no
/// absorber in the beam: the face is real), the face widened to cover it; the rays it obscures are stopped
/// there by every kernel, as by the sequential tracer. The rays that pass it are not compared
/// (docs/ghosts.md: the file's sequential path to the image crosses the primary mirror, which has no hole
/// in the file).
#[test]
fn the_catadioptric_patent_lens_builds_its_solids() {
    let sys = build(&zmx("US05331467-1.zmx"));
    let solids = Solids::build(&sys, &SolidsOptions::default()).unwrap();
    assert!(solids.start_plane.is_some());
    let face = solids.objects.iter().find(|o| matches!(&o.role, Role::Interface { surfaces, .. } if surfaces.contains(&2))).unwrap();
    assert!(face.apertures.iter().any(|(s, ap)| *s == 2 && matches!(ap, Aperture::CircularObscuration { .. })));
    assert!(face.patch.as_ref().unwrap().local_bounds().1.x >= 26.0);
    assert!(!solids.objects.iter().any(|o| matches!(o.role, Role::Blade { surface: 2, .. })));
    // Every ray the sequential tracer vignettes at the obscuration (surface 2) is vignetted there by the
    // solids too; the others are reported, not compared (see above).
    let rays = workload(&sys, 0.5f64.to_radians());
    let exact = analytic(&sys, &rays);
    #[cfg_attr(not(feature = "embree"), allow(unused_mut))]
    let mut kernels = vec![("brute", brute(&sys, &rays))];
    #[cfg(feature = "embree")]
    {
        use diffcassi::tracer::embree::{EmbreeOptions, EmbreeTracer, Refinement};
        let t = EmbreeTracer::new(EmbreeOptions::user(Refinement::F64)).trace(&sys, &rays).unwrap();
        kernels.push(("embree-user", (0..rays.len()).map(|i| Outcome { status: t.status[i], surface: t.surface[i], point: DVec3::NAN, dir: DVec3::NAN }).collect()));
    }
    for (label, got) in kernels {
        let (mut obscured, mut tally) = (0, std::collections::BTreeMap::new());
        for (i, (e, g)) in exact.iter().zip(&got).enumerate() {
            if e.status == RayStatus::Vignetted && e.surface == 2 {
                obscured += 1;
                assert_eq!((g.status, g.surface), (RayStatus::Vignetted, 2), "{label} ray {i}");
            } else {
                *tally.entry(format!("sequential {:?} / {label} {:?} at {}", e.status, g.status, g.surface)).or_insert(0) += 1;
            }
        }
        eprintln!("US05331467-1 {label}: {obscured} of {} rays obscured at surface 2 in both; the others: {tally:?}", rays.len());
        assert!(obscured > 50, "{obscured}");
    }
    // The walk runs and classifies every ray (no NaN, the ledger balanced).
    let rays = RayBatch::for_field(&sys, [0.0, 0.0], &PupilPattern::Hexapolar { rings: 3 }.points(), 587.6).unwrap();
    let kernel = BruteForce::new(&sys, &SolidsOptions::default()).unwrap();
    for t in trace_trees(&kernel, &sys, &rays, &TreeOptions { order: 1, threshold: 0.0, ..Default::default() }).unwrap() {
        assert!(t.main_status.is_some() && t.ledger.imbalance().abs() < 1e-12);
        assert!(t.arrivals.iter().all(|a| a.point.is_finite() && a.power.is_finite()));
    }
}

/// Item 2: Toroidal surfaces are solved on their exact figure (the sequential one): the Thorlabs cylinder
/// lens LJ1598L1 as its file gives it (at infinity), and a toroid and a cylinder at a finite conjugate.
#[test]
fn toroidal_surfaces_land_where_the_analytic_tracer_lands() {
    let cylinder = zmx("cylinder_thorlabs_LJ1598L1.zmx");
    let specs = [cylinder, crate::surfaces::toroid_lens(Some(40.0)), crate::surfaces::toroid_lens(Some(-30.0)), crate::surfaces::toroid_lens(None)];
    for spec in specs {
        let sys = build(&spec);
        assert!(sys.surfaces.iter().any(|s| matches!(s.shape, Some(diffcassi::surfaces::SurfaceShape::Toroidal { .. }))));
        let grid = if sys.object_at_infinity() { 1f64.to_radians() } else { 1.0 };
        let rays = workload(&sys, grid);
        let (ok, _) = agree_all(&sys, &rays);
        assert!(ok * 10 >= rays.len() * 9, "{}: {ok} of {} land", sys.name(), rays.len());
        // The ghost tree of a toroid: balanced, finite.
        let kernel = BruteForce::new(&sys, &SolidsOptions::default()).unwrap();
        let trees = trace_trees(&kernel, &sys, &rays, &TreeOptions { order: 2, threshold: 0.0, ..Default::default() }).unwrap();
        assert!(trees.iter().all(|t| t.ledger.imbalance().abs() < 1e-12 && t.arrivals.iter().all(|a| a.point.is_finite())));
        assert!(trees.iter().any(|t| t.arrivals.iter().any(|a| a.path.len() == 2)), "{}: second-order ghosts reach the detector", sys.name());
    }
}

/// Item 1, the ghost analysis: at infinity its point sources are field angles (named in degrees), its rays
/// the fields' parallel beams; the CLI runs on the fixture and writes its CSV.
#[test]
fn ghost_analysis_runs_at_infinity() {
    use diffcassi::analysis::ghosts::{ghost_analysis, GhostOptions};
    let sys = build(&singlet_at_infinity());
    let r = ghost_analysis(&sys, &GhostOptions { rings: 2, extended_grid: 2, ..Default::default() }).unwrap();
    assert_eq!(r.on_axis_source, "point 0,0 deg");
    assert!(r.paths.iter().any(|p| p.source == "point 2,3 deg"), "{:?}", r.paths.iter().map(|p| &p.source).collect::<std::collections::BTreeSet<_>>());
    let rows = r.on_axis_520();
    assert!(rows.iter().any(|p| p.path == "2R 1R"), "{:?}", rows.iter().map(|p| &p.path).collect::<Vec<_>>());
    assert!(rows.iter().all(|p| p.energy_fraction.is_finite() && p.energy_fraction > 0.0 && p.x_mm.is_finite() && p.peak_ratio.is_finite()));
    assert!(r.ledger.imbalance().abs() < 1e-9 * r.ledger.launched);
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("g.csv");
    let o = run(&["ghosts", "--system", singlet_path().to_str().unwrap(), "--order", "2", "--rings", "2", "--extended-grid", "2", "--csv", csv.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(std::fs::read_to_string(&csv).unwrap().contains("2R 1R"));
    // `render --ghosts` at infinity: the scene's angular extent, the ghost trees of the rendered rays.
    let mut backends = vec!["brute"];
    if cfg!(feature = "embree") {
        backends.push("embree-user");
    }
    for backend in backends {
        let out = dir.path().join(backend);
        let o = run(&[
            "render", "--system", singlet_path().to_str().unwrap(), "--scene-size", "8", "--planes", "2", "--rays", "2", "--bands", "500,600", "--no-mapping",
            "--scene-fov-deg", "6", "--ghosts", "2", "--ghost-backend", backend, "--out", out.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{backend}: {}", text(&o));
        let json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(out.join("render.json")).unwrap()).unwrap();
        let g = &json["ghosts"];
        eprintln!("render --ghosts 2 at infinity, {backend}: ghost per launched ray {}, main path share {}, imbalance {}", g["ghost_per_launched"], g["main_path_share"], g["energy_imbalance"]);
        assert!(g["ghost_per_launched"].as_f64().unwrap() > 0.0 && g["main_path_share"].as_f64().unwrap() > 0.8, "{backend}: {g}");
        assert!(g["energy_imbalance"].as_f64().unwrap().abs() < 1e-9, "{backend}: {g}");
    }
}
