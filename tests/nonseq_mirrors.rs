//! Mirrors (`GLAS MIRROR`) in the non-sequential backends (issue 42, item 2): the Embree tracer and the
//! brute-force walk reflect at a mirror face (d′ = d − 2(d·n̂)n̂, weight 1) and land where the analytic
//! sequential tracer lands; the ghost tree does not split at a mirror; gratings stay refused (Toroidal
//! surfaces are modelled: tests/nonseq_lens_files.rs); a grazing mirror hit is a classified status, never NaN.
//!
//! `cargo test --release --test integration nonseq_mirrors:: -- --nocapture` prints the measured errors.
use diffcassi::prelude::*;
use diffcassi::spec::SurfaceSpec;
use diffcassi::tracer::nonseq::coating::CoatingOverride;
use diffcassi::tracer::nonseq::{path_label, trace_trees, BruteForce, FresnelModel, Role, Solids, SolidsOptions, TreeOptions};
use glam::DVec3;
use std::process::{Command, Output};

fn run(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_diffcassi")).args(args).output().expect("the binary runs")
}

fn text(o: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
}

// The systems' builders are `tests/surfaces.rs`'s (the sequential traces of the same mirrors).
use crate::surfaces::{fold_mirrors, mirror, stop, system};

/// The fold system unfolded: the same path lengths 20 + 30 + 20 mm in a straight line (singlet = 2, 3).
fn unfolded() -> SystemSpec {
    let mut s = fold_mirrors();
    s.surfaces = vec![
        SurfaceSpec::standard(None, 40.0, None),
        stop(SurfaceSpec::standard(None, 70.0, None)),
        SurfaceSpec::standard(Some(30.0), 4.0, Some("N-BK7")),
        SurfaceSpec::standard(Some(-30.0), 25.0, None),
        SurfaceSpec::standard(None, 0.0, None),
    ];
    s.name = "unfolded".into();
    s
}

/// A concave ellipsoidal mirror (foci 100 mm and 50 mm in front of its vertex) tilted by 10° with
/// Coordinate Breaks, so that the image, at the negative thickness −50 mm, lies beside the incoming beam.
fn tilted_ellipsoid() -> SystemSpec {
    let (s, s2): (f64, f64) = (100.0, 50.0);
    let r = -2.0 * s * s2 / (s + s2);
    let k = -((s - s2) / (s + s2)).powi(2);
    let cb = |tx: f64, t: f64| SurfaceSpec::coordinate_break(0.0, 0.0, tx, 0.0, 0.0, t);
    system(
        "tilted ellipsoid",
        vec![SurfaceSpec::standard(None, s, None), cb(10.0, 0.0), stop(mirror(Some(r), Some(k), 0.0)), cb(10.0, -s2), SurfaceSpec::standard(None, 0.0, None)],
        0.1,
    )
}

fn build(spec: &SystemSpec) -> SequentialSystem {
    SequentialSystem::build(spec).unwrap_or_else(|e| panic!("{}: {e}", spec.name))
}

/// The ellipsoid's detector beside the incoming beam needs a tight detector margin (the default 25 mm
/// would put the detector into the beam on its way to the mirror, as a real detector there would be).
fn solids_options(sys: &SequentialSystem) -> SolidsOptions {
    if sys.name() == "tilted ellipsoid" {
        SolidsOptions { detector_margin_mm: 0.0, ..Default::default() }
    } else {
        SolidsOptions::default()
    }
}

/// Chief rays of a 5×5 field grid over ±1 mm and hexapolar (4 rings) rays of the system's fields, at
/// 450/520/650 nm.
fn workload(sys: &SequentialSystem) -> RayBatch {
    let mut rays = RayBatch::default();
    for &w in &[450.0, 520.0, 650.0] {
        let fields: Vec<[f64; 2]> = (0..25).map(|k| [-1.0 + 0.5 * (k % 5) as f64, -1.0 + 0.5 * (k / 5) as f64]).collect();
        rays.extend(&RayBatch::chief_rays(sys, &fields, w).unwrap());
        for f in &sys.spec.fields_mm {
            rays.extend(&RayBatch::for_field(sys, *f, &PupilPattern::Hexapolar { rings: 4 }.points(), w).unwrap());
        }
    }
    rays
}

#[test]
fn mirror_faces_are_one_surface_each_and_reflect() {
    let sys = build(&fold_mirrors());
    let solids = Solids::build(&sys, &SolidsOptions::default()).unwrap();
    let mirrors: Vec<usize> = solids.objects.iter().filter_map(|o| if let Role::Mirror { surface, .. } = o.role { Some(surface) } else { None }).collect();
    assert_eq!(mirrors, vec![3, 6], "one mirror face per GLAS MIRROR surface");
    for o in &solids.objects {
        if let Role::Mirror { surface, medium } = o.role {
            assert!(o.is_optical() && o.patch.is_some());
            assert_eq!(medium, surface - 1, "a mirror sits in the medium before it");
        }
    }
    // The singlet is a solid with a side wall; the stop plane in air is virtual (no face).
    assert!(solids.objects.iter().any(|o| matches!(o.role, Role::Wall { surface: 8, .. })));
    assert_eq!(solids.interfaces(), 5, "2 mirrors + 2 singlet faces + detector");
}

/// The brute-force walk with reflections off (order 0): the main path is the non-sequential trace.
fn brute_trace(sys: &SequentialSystem, rays: &RayBatch) -> Vec<diffcassi::tracer::nonseq::RayTree> {
    brute_trace_with(sys, rays, &solids_options(sys))
}

/// [`brute_trace`] with the given margins.
fn brute_trace_with(sys: &SequentialSystem, rays: &RayBatch, options: &SolidsOptions) -> Vec<diffcassi::tracer::nonseq::RayTree> {
    let brute = BruteForce::new(sys, options).unwrap();
    trace_trees(&brute, sys, rays, &TreeOptions { order: 0, model: FresnelModel::Off, ..Default::default() }).unwrap()
}

#[test]
fn brute_force_lands_where_the_analytic_tracer_lands() {
    compare_brute_force_with_the_analytic_tracer(solids_options);
}

/// The same comparison with the **default** margins: the design-beam check shrinks the ellipsoid's
/// detector margin by itself, so no test needs to set it to 0 any more.
#[test]
fn brute_force_lands_where_the_analytic_tracer_lands_with_default_margins() {
    compare_brute_force_with_the_analytic_tracer(|_| SolidsOptions::default());
}

/// `render --ghosts` on the tilted ellipsoid prints the design-beam note and records it in render.json
/// (`ghosts.design_beam_note`, as `ghosts`' JSON does); SP's record has none.
#[test]
fn render_ghosts_records_the_design_beam_note() {
    let dir = tempfile::tempdir().unwrap();
    let toml = dir.path().join("ellipsoid.toml");
    std::fs::write(&toml, diffcassi::spec::to_toml(&tilted_ellipsoid()).unwrap()).unwrap();
    let tiny = ["--scene-size", "8", "--planes", "2", "--bands", "480,560", "--rays", "2", "--no-mapping", "--ghosts", "1", "--ghost-backend", "brute"];
    let (ell, sp) = (dir.path().join("ell"), dir.path().join("sp"));
    let o = run(&[&["render", "--system", toml.to_str().unwrap(), "--out", ell.to_str().unwrap()][..], &tiny].concat());
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("note: ") && text(&o).contains("shrunk"), "{}", text(&o));
    let rec: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(ell.join("render.json")).unwrap()).unwrap();
    let note = rec["ghosts"]["design_beam_note"].as_str().unwrap_or_else(|| panic!("no design_beam_note: {}", rec["ghosts"]));
    assert!(note.contains("shrunk") && note.contains("image surface 4"), "{note}");
    let o = run(&[&["render", "--preset", "sp", "--out", sp.to_str().unwrap()][..], &tiny].concat());
    assert!(o.status.success(), "{}", text(&o));
    let rec: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(sp.join("render.json")).unwrap()).unwrap();
    assert!(rec["ghosts"].is_object() && rec["ghosts"].get("design_beam_note").is_none(), "{}", rec["ghosts"]);
}

/// The default solids of the folded systems build; the ellipsoid's detector disc, which with the default
/// 25 mm margin stood in the incoming beam, is shrunk (read back, with its note); the fold keeps its margin.
#[test]
fn the_design_beam_shrinks_a_detector_in_the_beam() {
    let sys = build(&tilted_ellipsoid());
    let solids = Solids::build(&sys, &SolidsOptions::default()).unwrap();
    eprintln!("tilted ellipsoid: detector margin {} mm; {:?}", solids.detector_margin_mm, solids.design_beam_note);
    assert!(solids.detector_margin_mm < 25.0 && solids.detector_margin_mm >= 0.0, "{}", solids.detector_margin_mm);
    let note = solids.design_beam_note.as_deref().expect("a shrunk margin says why");
    assert!(note.contains("shrunk") && note.contains("image surface 4") && note.contains("design ray"), "{note}");
    // The detector disc is the one of margin 0 plus the shrunk margin.
    let margin0 = Solids::build(&sys, &SolidsOptions { detector_margin_mm: 0.0, ..Default::default() }).unwrap();
    assert_eq!(margin0.detector_margin_mm, 0.0);
    assert!(margin0.design_beam_note.is_none());
    let r = |s: &Solids| match s.objects.iter().find(|o| matches!(o.role, Role::Detector { .. })).unwrap().patch.as_ref().unwrap().aperture {
        diffcassi::surfaces::Aperture::Circular { semi_diameter_mm, .. } => semi_diameter_mm,
        ref a => panic!("{a:?}"),
    };
    assert!((r(&solids) - r(&margin0) - solids.detector_margin_mm).abs() < 1e-9, "{} vs {} + {}", r(&solids), r(&margin0), solids.detector_margin_mm);
    let fold = Solids::build(&build(&fold_mirrors()), &SolidsOptions::default()).unwrap();
    assert_eq!(fold.detector_margin_mm, 25.0);
    assert!(fold.design_beam_note.is_none(), "{:?}", fold.design_beam_note);
}

/// The four CASSI presets (unfolded) keep their solids: the design beam crosses no face, so nothing is
/// shrunk and nothing refused.
#[test]
fn the_presets_keep_their_solids() {
    for name in ["sp", "ap", "msp", "map"] {
        let sys = build(&presets::spec(name).unwrap());
        let solids = Solids::build(&sys, &SolidsOptions::default()).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(solids.detector_margin_mm, 25.0, "{name}: {:?}", solids.design_beam_note);
        assert!(solids.design_beam_note.is_none(), "{name}: {:?}", solids.design_beam_note);
    }
}

/// A face other than the detector whose mechanical disc reaches into the beam is an error naming the
/// surface: the fold mirrors with a 45 mm mechanical margin (their discs then cross the beam 30 mm beside
/// them, at r ≈ 42.4 mm); the singlet gets explicit apertures so that its spheres (R 30 mm) stay defined.
#[test]
fn a_mechanical_face_in_the_design_beam_is_an_error() {
    let mut spec = fold_mirrors();
    for s in [8, 9] {
        spec.surfaces[s].aperture = Some(diffcassi::surfaces::Aperture::circular(10.0));
    }
    let sys = build(&spec);
    let wide = SolidsOptions { mechanical_margin_mm: 45.0, ..Default::default() };
    let e = Solids::build(&sys, &wide).unwrap_err().to_string();
    eprintln!("{e}");
    assert!(e.contains("stands in the design beam") && (e.contains("surface 3 stands") || e.contains("surface 6 stands")), "{e}");
    assert!(e.contains("mechanical") && e.contains("explicit clear aperture") && e.contains("field"), "{e}");
    let e = BruteForce::new(&sys, &wide).unwrap_err().to_string();
    assert!(e.contains("stands in the design beam"), "{e}");
    // With the default margin the same system builds.
    assert!(Solids::build(&sys, &SolidsOptions::default()).is_ok());
}

/// The brute-force main path lands where the analytic tracer lands, for the fold and the tilted ellipsoid
/// with the margins `options` gives each.
fn compare_brute_force_with_the_analytic_tracer(options: fn(&SequentialSystem) -> SolidsOptions) {
    for spec in [fold_mirrors(), tilted_ellipsoid()] {
        let sys = build(&spec);
        let rays = workload(&sys);
        let exact = AnalyticTracer::default().trace(&sys, &rays).unwrap();
        assert_eq!(exact.ok_count(), rays.len(), "{}: every reference ray arrives", sys.name());
        let trees = brute_trace_with(&sys, &rays, &options(&sys));
        let (mut max_um, mut max_dir) = (0.0f64, 0.0f64);
        for (i, t) in trees.iter().enumerate() {
            assert_eq!(t.main_status, Some(RayStatus::Ok), "{} ray {i}: {:?} at surface {}", sys.name(), t.main_status, t.main_surface);
            let a = &t.arrivals[0];
            assert!(a.path.is_empty() && a.power == 1.0, "a mirror keeps the whole weight");
            max_um = max_um.max(1e3 * (a.point.x - exact.x[i]).hypot(a.point.y - exact.y[i]));
            max_dir = max_dir.max((a.direction.x - exact.dir_x[i]).abs().max((a.direction.y - exact.dir_y[i]).abs()));
        }
        eprintln!("{} brute force vs analytic: {} rays, max {max_um:.3e} µm, direction {max_dir:.3e}", sys.name(), rays.len());
        assert!(max_um <= 1e-3, "{}: max error {max_um} µm > 1e-6 mm", sys.name());
        assert!(max_dir < 1e-9, "{}: direction differs by {max_dir}", sys.name());
    }
}

#[test]
fn gratings_stay_refused_with_the_surface_named() {
    let grating = system(
        "grating",
        vec![SurfaceSpec::standard(None, 50.0, None), stop(SurfaceSpec::grating(None, 0.6, 1, 30.0, None)), SurfaceSpec::standard(None, 0.0, None)],
        0.05,
    );
    // Toroidal surfaces are modelled now (tests/nonseq_lens_files.rs): the toroid builds.
    let mut t = SurfaceSpec::toroidal(Some(20.0), Some(40.0), 5.0, Some("N-BK7"));
    t.stop = true;
    let toroid = system("toroid", vec![SurfaceSpec::standard(None, 80.0, None), t, SurfaceSpec::standard(None, 40.0, None), SurfaceSpec::standard(None, 0.0, None)], 0.05);
    assert!(Solids::build(&build(&toroid), &SolidsOptions::default()).is_ok());
    let sys = build(&grating);
    let e = Solids::build(&sys, &SolidsOptions::default()).unwrap_err().to_string();
    assert!(e.contains("surface 1 is a diffraction grating") && e.contains("non-sequential backends") && e.contains("analytic backend"), "{e}");
    let e = BruteForce::new(&sys, &SolidsOptions::default()).unwrap_err().to_string();
    assert!(e.contains("surface 1 is a diffraction grating"), "{e}");
}

#[test]
fn coatings_on_a_mirror_are_refused_and_skipped_by_all() {
    let mut spec = fold_mirrors();
    spec.surfaces[3].coating = Some(diffcassi::spec::Coating::Reflectance(0.5));
    let e = SequentialSystem::build(&spec).unwrap_err().to_string();
    assert!(e.contains("coating") && e.contains("surface 3 is a mirror"), "{e}");
    let spec = fold_mirrors();
    let coatings: Vec<_> = spec.surfaces.iter().map(|s| s.coating.clone()).collect();
    let sites = diffcassi::tracer::nonseq::solids::coating_sites(&SequentialSystem::build(&spec).unwrap()).unwrap();
    let site = |k: usize| sites[k].clone();
    let all = "all=R0.01".parse::<CoatingOverride>().unwrap().apply(&coatings, &site).unwrap();
    assert!(all[3].is_none() && all[6].is_none() && all[8].is_some(), "{all:?}");
    let e = "6=R0.01".parse::<CoatingOverride>().unwrap().apply(&coatings, &site).unwrap_err().to_string();
    assert!(e.contains("surface 6 is a mirror"), "{e}");
}

/// The ghost tree on the fold system equals the tree on its unfolded twin, path for path (the singlet's
/// surfaces 8, 9 ↔ 2, 3), to rounding: the mirrors reflect with weight 1, never split and never transmit
/// (the polarised model's two mirror reflections are unitary on the field, so unpolarised light stays
/// unpolarised and every power is the twin's).
#[test]
fn mirrors_do_not_split_in_the_ghost_tree() {
    let folded = build(&fold_mirrors());
    let straight = build(&unfolded());
    for model in [FresnelModel::Polarized, FresnelModel::Scalar] {
        let opts = TreeOptions { order: 2, model, threshold: 0.0, ..Default::default() };
        let (mut worst, mut ghosts, mut rays_n) = (0.0f64, 0usize, 0usize);
        for field in [[0.0, 0.0], [0.0, 1.0], [1.0, 0.5]] {
            let pupil = PupilPattern::Hexapolar { rings: 3 }.points();
            let a = trace_trees(&BruteForce::new(&folded, &SolidsOptions::default()).unwrap(), &folded, &RayBatch::for_field(&folded, field, &pupil, 520.0).unwrap(), &opts).unwrap();
            let b = trace_trees(&BruteForce::new(&straight, &SolidsOptions::default()).unwrap(), &straight, &RayBatch::for_field(&straight, field, &pupil, 520.0).unwrap(), &opts).unwrap();
            for (ta, tb) in a.iter().zip(&b) {
                rays_n += 1;
                assert!(ta.ledger.imbalance().abs() < 1e-12, "ledger {:?}", ta.ledger);
                let map = |p: &[u32]| p.iter().map(|s| s - 6).collect::<Vec<u32>>();
                assert_eq!(ta.arrivals.len(), tb.arrivals.len(), "{:?} vs {:?}", ta.arrivals.iter().map(|x| path_label(&x.path)).collect::<Vec<_>>(), tb.arrivals.iter().map(|x| path_label(&x.path)).collect::<Vec<_>>());
                for (x, y) in ta.arrivals.iter().zip(&tb.arrivals) {
                    assert!(!x.path.contains(&3) && !x.path.contains(&6), "a mirror is never a partial reflection: {}", path_label(&x.path));
                    assert_eq!(map(&x.path), y.path);
                    worst = worst.max((x.power - y.power).abs());
                    assert!((x.point - y.point).abs().max_element() < 1e-9, "{}: {:?} vs {:?}", path_label(&x.path), x.point, y.point);
                    ghosts += (!x.path.is_empty()) as usize;
                }
                for (p, q) in [(ta.ledger.detector, tb.ledger.detector), (ta.ledger.escaped, tb.ledger.escaped), (ta.ledger.absorbed, tb.ledger.absorbed)] {
                    assert!((p - q).abs() < 1e-12, "ledger {:?} vs {:?}", ta.ledger, tb.ledger);
                }
            }
        }
        eprintln!("fold vs unfolded, {}: {rays_n} trees, {ghosts} ghost arrivals, largest power difference {worst:.3e}", model.label());
        assert!(worst < 1e-12, "{worst}");
        assert!(ghosts > 0, "the singlet's ghost 9R 8R reaches the detector");
    }
}

/// A mirror met at grazing incidence (|d·n̂| ≤ 1e-12) is `missed`, as in the sequential kernel; a ray a
/// little off grazing reflects; nothing is NaN.
#[test]
fn grazing_mirror_hits_are_classified_never_nan() {
    let spec = system("flat", vec![SurfaceSpec::standard(None, 10.0, None), stop(mirror(None, None, -10.0)), SurfaceSpec::standard(None, 0.0, None)], 0.05);
    let sys = build(&spec);
    let mut rays = RayBatch::default();
    // Just in front of the mirror plane z = 10, climbing toward it at 1e-13 rad: meets it 1 mm up at grazing.
    rays.push(DVec3::new(0.0, 0.0, 10.0 - 1e-13), DVec3::new(0.0, 1.0, 1e-13), 520.0);
    // 1e-6 rad: a defined reflection (the ray then leaves the system).
    rays.push(DVec3::new(0.0, 0.0, 10.0 - 1e-6), DVec3::new(0.0, 1.0, 1e-6), 520.0);
    rays.push(DVec3::new(0.0, 0.0, 0.0), DVec3::new(f64::NAN, 0.0, 1.0), 520.0);
    // An ordinary ray (starting 1 mm in front of the object plane, which the image plane shares here).
    rays.push(DVec3::new(0.0, 0.0, 1.0), DVec3::new(0.0, 0.01, 1.0), 520.0);
    let exact = AnalyticTracer::default().trace(&sys, &rays).unwrap();
    let trees = brute_trace(&sys, &rays);
    let statuses: Vec<_> = trees.iter().map(|t| t.main_status).collect();
    eprintln!("grazing: analytic {:?}, brute force {statuses:?}", exact.status);
    assert_eq!(trees[0].main_status, Some(RayStatus::Missed), "grazing → missed");
    assert_eq!(trees[0].main_surface, 1, "at the mirror");
    assert_ne!(trees[1].main_status, Some(RayStatus::Ok));
    assert_eq!(trees[2].main_status, Some(RayStatus::InvalidInput));
    assert_eq!(trees[3].main_status, Some(RayStatus::Ok));
    assert_eq!(exact.status[3], RayStatus::Ok);
    let a = &trees[3].arrivals[0];
    assert!((a.point.y - exact.y[3]).abs() < 1e-12 && a.point.is_finite() && a.direction.is_finite());
    for t in &trees {
        assert!(t.ledger.imbalance().abs() < 1e-12);
        assert!(t.arrivals.iter().all(|a| a.point.is_finite() && a.direction.is_finite() && a.power.is_finite()));
    }
    // The polarised ghost walk too: classified, balanced, finite.
    let brute = BruteForce::new(&sys, &SolidsOptions::default()).unwrap();
    for t in trace_trees(&brute, &sys, &rays, &TreeOptions { order: 2, threshold: 0.0, ..Default::default() }).unwrap() {
        assert!(t.main_status.is_some() && t.ledger.imbalance().abs() < 1e-12);
    }
}

#[cfg(feature = "embree")]
mod embree {
    use super::*;
    use diffcassi::surfaces::MeshResolution;
    use diffcassi::tracer::embree::{EmbreeNextHit, EmbreeOptions, EmbreeTracer, Refinement, SceneOptions};
    use diffcassi::tracer::hits::HitKind;

    fn scene_options(sys: &SequentialSystem) -> SceneOptions {
        let s = solids_options(sys);
        SceneOptions { detector_margin_mm: s.detector_margin_mm, ..Default::default() }
    }

    /// The Embree scene with the **default** margins: it is built from the same checked solids, so the
    /// tilted ellipsoid's detector is the shrunk disc and every ray lands where the analytic tracer lands
    /// (with the 25 mm disc in the incoming beam they would stop on the detector).
    #[test]
    fn embree_uses_the_detector_margin_the_design_beam_allows() {
        let sys = build(&tilted_ellipsoid());
        let rays = workload(&sys);
        let exact = AnalyticTracer::default().trace(&sys, &rays).unwrap();
        let out = EmbreeTracer::new(EmbreeOptions::user(Refinement::F64)).trace(&sys, &rays).unwrap();
        let mut max_um = 0.0f64;
        for i in 0..rays.len() {
            assert_eq!(out.status[i], exact.status[i], "ray {i} at surface {}", out.surface[i]);
            max_um = max_um.max(1e3 * (out.x[i] - exact.x[i]).hypot(out.y[i] - exact.y[i]));
        }
        eprintln!("tilted ellipsoid embree-user default margins: {} rays, max {max_um:.3e} µm", rays.len());
        assert!(max_um <= 1e-3, "max error {max_um} µm");
    }

    /// The Embree backend (user geometry and 1 µm meshes, f64 refinement) on a fold-mirror system and a
    /// tilted concave mirror: the same statuses as the analytic tracer, positions within 1e-6 mm and
    /// directions within 1e-9 (the tolerance of tests/embree.rs on the presets).
    #[test]
    fn refined_embree_equals_analytic_through_mirrors() {
        for spec in [fold_mirrors(), tilted_ellipsoid()] {
            let sys = build(&spec);
            let rays = workload(&sys);
            let exact = AnalyticTracer::default().trace(&sys, &rays).unwrap();
            assert_eq!(exact.ok_count(), rays.len());
            for (label, opts) in [
                ("embree-user", EmbreeOptions::user(Refinement::F64)),
                ("embree-mesh 1um", EmbreeOptions::mesh(MeshResolution::MaxSagErrorUm(1.0), Refinement::F64)),
            ] {
                let opts = EmbreeOptions { scene: SceneOptions { detector_margin_mm: scene_options(&sys).detector_margin_mm, ..opts.scene }, ..opts };
                let (out, details) = EmbreeTracer::new(opts).trace_detailed(&sys, &rays).unwrap();
                let (mut max_um, mut max_dir, mut differ) = (0.0f64, 0.0f64, 0usize);
                for i in 0..rays.len() {
                    if out.status[i] != exact.status[i] {
                        if differ < 5 {
                            eprintln!("{} {label} ray {i}: {:?} at surface {}", sys.name(), out.status[i], out.surface[i]);
                        }
                        differ += 1;
                        continue;
                    }
                    max_um = max_um.max(1e3 * (out.x[i] - exact.x[i]).hypot(out.y[i] - exact.y[i]));
                    max_dir = max_dir.max((out.dir_x[i] - exact.dir_x[i]).abs().max((out.dir_y[i] - exact.dir_y[i]).abs()));
                }
                eprintln!("{} {label} refine=f64: {} rays, max {max_um:.3e} µm, direction {max_dir:.3e}, status differs {differ}", sys.name(), rays.len());
                assert_eq!(differ, 0, "{} {label}", sys.name());
                assert!(max_um <= 1e-3, "{} {label}: max error {max_um} µm > 1e-6 mm", sys.name());
                assert!(max_dir < 1e-9, "{} {label}: direction differs by {max_dir}", sys.name());
                assert!(details.reflections.iter().all(|r| *r == 0), "mirror reflections are not total internal reflections");
            }
            // The unrefined (f32) trace still arrives everywhere, within a few µm.
            let opts = EmbreeOptions::user(Refinement::None);
            let opts = EmbreeOptions { scene: SceneOptions { detector_margin_mm: scene_options(&sys).detector_margin_mm, ..opts.scene }, ..opts };
            let out = EmbreeTracer::new(opts).trace(&sys, &rays).unwrap();
            let max_um = (0..rays.len()).filter(|&i| out.status[i] == RayStatus::Ok).map(|i| 1e3 * (out.x[i] - exact.x[i]).hypot(out.y[i] - exact.y[i])).fold(0.0, f64::max);
            eprintln!("{} embree-user refine=none: {} of {} arrive, max {max_um:.3e} µm", sys.name(), out.ok_count(), rays.len());
            assert_eq!(out.ok_count(), rays.len());
        }
    }

    /// The hit log records a mirror as the sequential log does ([`HitKind::Mirror`], media before/after).
    #[test]
    fn hit_log_records_mirrors_like_the_sequential_log() {
        let sys = build(&fold_mirrors());
        let rays = RayBatch::chief_rays(&sys, &[[0.0, 1.0]], 520.0).unwrap();
        let (_, _, log) = EmbreeTracer::new(EmbreeOptions::user(Refinement::F64)).trace_with_hits(&sys, &rays).unwrap();
        let (_, seq) = diffcassi::tracer::hits::sequential_hits(&sys, &rays).unwrap();
        let e: Vec<_> = log.ray(0).iter().filter(|h| h.kind == HitKind::Mirror).map(|h| (h.first_surface, h.medium_in, h.medium_out)).collect();
        let s: Vec<_> = seq.ray(0).iter().filter(|h| h.kind == HitKind::Mirror).map(|h| (h.first_surface, h.medium_in, h.medium_out)).collect();
        assert_eq!(e, vec![(3, 2, 3), (6, 5, 6)]);
        assert_eq!(e, s);
    }

    /// Implicit differentiation at Embree's recorded hits ([`HitKind::Mirror`] records) gives the forward-mode
    /// Jacobians of the analytic trace through both fold mirrors, to 1e-9 of each column's largest entry.
    #[test]
    fn jacobians_from_embree_hits_through_mirrors_equal_the_analytic_ones() {
        use diffcassi::diff::{Param, ParamSet};
        let free = ["s2.tilt_x_deg", "s4.tilt_x_deg", "s4.thickness_mm", "s8.curvature", "glass_nd:N-BK7", "wavelength", "ray.dir_y"];
        let params: Vec<Param> = free.iter().map(|t| Param::parse(t).unwrap()).collect();
        let set = ParamSet::new(fold_mirrors(), diffcassi::materials::GlassCatalog::builtin(), params).unwrap();
        let ds = set.build().unwrap();
        let rays = workload(&ds.system);
        let jb = ds.trace(&rays).unwrap();
        let hj = ds.trace_embree(&EmbreeTracer::new(EmbreeOptions::user(Refinement::F64)), &rays).unwrap();
        // `tests/derivatives.rs`'s comparison (≤ 1e-9 of each column's largest entry, the same statuses and
        // landings), with 1e-12 absolute: the image plane's z entries are 0 up to f64 rounding of the large
        // terms after the two mirrors.
        crate::derivatives::agreement("fold", "embree-user f64", &jb, &hj, 1e-12);
        let n = (0..jb.len()).filter(|&i| jb.usable(i)).count();
        assert_eq!(n, rays.len());
    }

    /// Embree's next-hit kernel and brute force agree on the ghost trees of the fold system.
    #[test]
    fn embree_and_brute_force_ghost_trees_agree_through_mirrors() {
        let sys = build(&fold_mirrors());
        let rays = RayBatch::for_field(&sys, [0.0, 1.0], &PupilPattern::Hexapolar { rings: 3 }.points(), 520.0).unwrap();
        let opts = TreeOptions { order: 2, threshold: 0.0, ..Default::default() };
        let a = trace_trees(&BruteForce::new(&sys, &SolidsOptions::default()).unwrap(), &sys, &rays, &opts).unwrap();
        let b = trace_trees(&EmbreeNextHit::new(&sys, &SceneOptions::default()).unwrap(), &sys, &rays, &opts).unwrap();
        for (ta, tb) in a.iter().zip(&b) {
            assert_eq!(ta.arrivals.len(), tb.arrivals.len());
            for (x, y) in ta.arrivals.iter().zip(&tb.arrivals) {
                assert_eq!(x.path, y.path);
                assert!((x.power - y.power).abs() <= 1e-12);
                assert!((x.point - y.point).abs().max_element() <= 1e-6);
            }
        }
    }

    #[test]
    fn embree_refuses_gratings_naming_the_surface_and_traces_mirrors_from_the_cli() {
        let grating = system(
            "grating",
            vec![SurfaceSpec::standard(None, 50.0, None), stop(SurfaceSpec::grating(None, 0.6, 1, 30.0, None)), SurfaceSpec::standard(None, 0.0, None)],
            0.05,
        );
        let sys = build(&grating);
        let rays = RayBatch::chief_rays(&sys, &[[0.0, 0.0]], 520.0).unwrap();
        let e = EmbreeTracer::new(EmbreeOptions::default()).trace(&sys, &rays).unwrap_err().to_string();
        assert!(e.contains("surface 1 is a diffraction grating"), "{e}");
        assert!(EmbreeNextHit::new(&sys, &SceneOptions::default()).is_err());
        // The CLI: `trace --backend embree-user` and `ghosts` open a fold-mirror system.
        let dir = tempfile::tempdir().unwrap();
        let toml = dir.path().join("fold.toml");
        std::fs::write(&toml, diffcassi::spec::to_toml(&fold_mirrors()).unwrap()).unwrap();
        let (a, b) = (dir.path().join("a.csv"), dir.path().join("e.csv"));
        for (backend, csv) in [("analytic", &a), ("embree-user", &b)] {
            let o = run(&["trace", "--system", toml.to_str().unwrap(), "--backend", backend, "--wavelength-nm", "520", "--field-mm", "0,1", "--pupil", "grid:5", "--csv", csv.to_str().unwrap()]);
            assert!(o.status.success(), "{backend}: {}", text(&o));
        }
        assert_eq!(std::fs::read_to_string(&a).unwrap().lines().count(), std::fs::read_to_string(&b).unwrap().lines().count());
        let o = run(&["ghosts", "--system", toml.to_str().unwrap(), "--order", "2", "--rings", "2", "--extended-grid", "2"]);
        assert!(o.status.success(), "{}", text(&o));
    }
}
