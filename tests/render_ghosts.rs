//! `render --ghosts K [--mechanics] [--coating SPEC]` (issue 23): ghost and stray light in acquisitions.
//! Tiny sizes: a few pixels, one or two planes, a few rays.
use diffcassi::analysis::ghosts::{ghost_analysis, GhostOptions};
use diffcassi::prelude::*;
use diffcassi::render::ghosts::{render_ghosts, GhostConfig, TreeEnergy};
use diffcassi::render::{Mask, RenderConfig, Renderer, SpectralSampling};
use diffcassi::scene::SpectralCube;
use diffcassi::spec::{Coating, MechanicsSpec, SurfaceModel};
use diffcassi::tracer::nonseq::{walk_tree, BruteForce, SolidsOptions, TreeOptions};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::Arc;

fn run(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_diffcassi")).args(args).output().expect("the binary runs")
}

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("diffcassi-render-ghosts-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

fn text(o: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
}

fn json(dir: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join("render.json")).unwrap()).unwrap()
}

const TINY: [&str; 9] = ["--scene-size", "16", "--planes", "4", "--bands", "480,560", "--rays", "4", "--no-mapping"];

fn render(preset: &str, out: &Path, extra: &[&str]) -> Output {
    let mut args = vec!["render", "--preset", preset, "--out", out.to_str().unwrap()];
    args.extend_from_slice(&TINY);
    args.extend_from_slice(extra);
    run(&args)
}

/// `--ghosts 2` records the "ghosts" object with its fields; the main image is today's (the plain
/// render's, bit for bit) and the ghost light is added on top; with every surface at R = 0 no ghost
/// exists and the acquisition file is the plain one, byte for byte (the order-0 path is not counted twice).
#[test]
fn ghosts_in_render_json_and_the_main_image_is_untouched() {
    let (plain, ghosts, zero) = (tmp("plain"), tmp("ghosts"), tmp("zero"));
    let o = render("sp", &plain, &[]);
    assert!(o.status.success(), "{}", text(&o));
    let o = render("sp", &ghosts, &["--ghosts", "2", "--ghost-backend", "brute"]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("ghost share"), "{}", text(&o));
    let o = render("sp", &zero, &["--ghosts", "2", "--coating", "all=R0", "--ghost-backend", "brute"]);
    assert!(o.status.success(), "{}", text(&o));
    let (jp, jg, jz) = (json(&plain), json(&ghosts), json(&zero));
    assert!(jp.get("ghosts").is_none(), "off by default");
    let g = &jg["ghosts"];
    for f in ["order", "coating", "mechanics", "backend", "rays_traced", "seconds", "cost_ratio", "ghost_share", "stray_share", "absorbed_share", "escaped_share", "main_path_share", "energy_imbalance"] {
        assert!(!g[f].is_null(), "render.json ghosts.{f} missing: {g}");
    }
    assert_eq!(g["order"], 2);
    assert_eq!(g["mechanics"], false);
    assert_eq!(g["coating"], "spec");
    assert_eq!(g["backend"], "brute");
    assert_eq!(g["rays_traced"].as_u64().unwrap(), jg["rays_traced"].as_u64().unwrap(), "every rendered ray runs its tree (uniform-free synthetic scene is non-zero)");
    // SP's doublet ghosts carry ≈ 4.6e-3 of the main path's power (docs/ghosts.md) but are 43 mm out of
    // focus: most of it falls beside this tiny detector. Stray light needs mechanics.
    let per_ray = g["ghost_per_launched"].as_f64().unwrap();
    assert!(per_ray > 1e-3 && per_ray < 1e-2, "ghost power per launched ray {per_ray}");
    let share = g["ghost_share"].as_f64().unwrap();
    assert!(share > 0.0 && share < per_ray, "ghost share {share}");
    assert!(g["off_detector"].as_f64().unwrap() > 0.0);
    assert_eq!(g["stray_share"].as_f64().unwrap(), 0.0);
    assert!(g["energy_imbalance"].as_f64().unwrap().abs() < 1e-9);
    let main = g["acquisition_main"].as_f64().unwrap();
    assert_eq!(main.to_bits(), jp["acquisition_total"].as_f64().unwrap().to_bits(), "the main image is the plain render's");
    let total = jg["acquisition_total"].as_f64().unwrap();
    assert!((total - main - g["acquisition_ghost"].as_f64().unwrap()).abs() <= 1e-9 * total);
    assert!(total > main);
    // R = 0 everywhere: no ghost, the acquisition is the plain one byte for byte.
    assert_eq!(jz["ghosts"]["acquisition_ghost"].as_f64().unwrap(), 0.0);
    assert_eq!(std::fs::read(plain.join("acquisition.exr")).unwrap(), std::fs::read(zero.join("acquisition.exr")).unwrap());
    assert_ne!(std::fs::read(plain.join("acquisition.exr")).unwrap(), std::fs::read(ghosts.join("acquisition.exr")).unwrap());
}

/// Usage errors (exit 2) and a bad mechanics mesh (exit 1): a clear message naming it, no output folder.
#[test]
fn bad_input_is_refused_before_anything_is_written() {
    let cases: Vec<(Vec<String>, i32, &str)> = vec![
        (vec!["--ghosts".into(), "5".into()], 2, "ghost order 5"),
        (vec!["--ghosts".into(), "0".into()], 2, "ghost order 0"),
        (vec!["--ghosts".into(), "2".into(), "--coating".into(), "all=R1.5".into()], 2, "reflectance 1.5"),
        (vec!["--ghosts".into(), "2".into(), "--coating".into(), "all=R-0.1".into()], 2, "reflectance -0.1"),
        (vec!["--ghosts".into(), "2".into(), "--coating".into(), "all=gold".into()], 2, "`gold`"),
        (vec!["--coating".into(), "all=R0.01".into()], 2, "--ghosts"),
        (vec!["--ghosts".into(), "2".into(), "--coating".into(), "99=R0.01".into()], 1, "surface 99"),
        (vec!["--ghosts".into(), "2".into(), "--ghost-rays".into(), "9".into()], 1, "--ghost-rays 9"),
        (vec!["--ghosts".into(), "2".into(), "--ghost-rays".into(), "0".into()], 2, "--ghost-rays"),
    ];
    for (k, (extra, code, needle)) in cases.iter().enumerate() {
        let out = tmp(&format!("bad-{k}"));
        let extra: Vec<&str> = extra.iter().map(String::as_str).collect();
        let o = render("sp", &out, &extra);
        assert_eq!(o.status.code(), Some(*code), "{extra:?}: {}", text(&o));
        assert!(text(&o).contains(needle), "{extra:?}: expected `{needle}` in {}", text(&o));
        assert!(!out.exists(), "{extra:?}: {} was written", out.display());
    }
    // A spec whose [mechanics] mesh is missing, truncated or has NaN vertices.
    let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/mesh");
    let base = diffcassi::spec::to_toml(&presets::spec("sp").unwrap()).unwrap();
    for (k, (mesh, needle)) in [("missing.stl".to_string(), "missing.stl"), (fixtures.join("truncated.stl").display().to_string(), "truncated"), (fixtures.join("nan.obj").display().to_string(), "not finite")].iter().enumerate() {
        let spec = tmp(&format!("mech-{k}.toml"));
        std::fs::write(&spec, format!("{base}\n[mechanics]\ngenerate = false\n\n[[mechanics.meshes]]\npath = \"{mesh}\"\n")).unwrap();
        let out = tmp(&format!("mech-out-{k}"));
        let mut args = vec!["render", "--system", spec.to_str().unwrap(), "--out", out.to_str().unwrap(), "--ghosts", "2", "--mechanics"];
        args.extend_from_slice(&TINY);
        let o = run(&args);
        assert_eq!(o.status.code(), Some(1), "{mesh}: {}", text(&o));
        assert!(text(&o).contains(needle), "{mesh}: expected `{needle}` in {}", text(&o));
        assert!(!out.exists(), "{mesh}: {} was written", out.display());
    }
}

fn sp_with_mounts(reflectance: f64) -> SequentialSystem {
    let mut spec = presets::spec("sp").unwrap();
    spec.mechanics = Some(MechanicsSpec { surface: SurfaceModel::Lambertian { reflectance }, ..Default::default() });
    SequentialSystem::build(&spec).unwrap()
}

/// Rays over twice the pupil (the sequential model lets them through, the mounts stop them) and the nominal pupil.
fn wide_rays(sys: &SequentialSystem) -> RayBatch {
    let mut pupil = vec![[0.0, 0.0]];
    for k in 0..12 {
        let a = std::f64::consts::TAU * k as f64 / 12.0;
        pupil.push([2.0 * a.cos(), 2.0 * a.sin()]);
        pupil.push([0.7 * a.cos(), 0.7 * a.sin()]);
    }
    let mut all = RayBatch::for_field(sys, [0.0, 0.0], &pupil, 520.0).unwrap();
    all.extend(&RayBatch::for_field(sys, [2.5, -2.5], &pupil, 450.0).unwrap());
    all
}

/// Per tree: main + ghost + stray + absorbed + escaped + truncated + rouletted = launched (1e-12), with
/// Fresnel splitting to K = 2, Lambertian mounts and roulette playing; stray light does reach the detector.
#[test]
fn energy_adds_up_per_tree_with_ghosts_and_stray_light() {
    let sys = sp_with_mounts(0.5);
    let mech = diffcassi::mechanics::Mechanics::from_system(&sys, Path::new(".")).unwrap();
    let kernel = BruteForce::new(&sys, &SolidsOptions::default()).unwrap().with_extra(Arc::new(mech));
    let rays = wide_rays(&sys);
    let coatings: Vec<Option<Coating>> = sys.spec.surfaces.iter().map(|s| s.coating.clone()).collect();
    let opts = TreeOptions { order: 2, threshold: 1e-3, seed: 3, ..Default::default() };
    let mut sum = TreeEnergy::default();
    for i in 0..rays.len() {
        let n = sys.indices(rays.wavelength_nm[i]).unwrap();
        let t = walk_tree(&kernel, &n, &coatings, rays.wavelength_nm[i], rays.origin(i), rays.direction(i), i as u64, &opts);
        let e = TreeEnergy::of(&t);
        assert_eq!(e.launched, 1.0);
        assert!(e.imbalance().abs() < 1e-12, "ray {i}: {e:?}");
        sum.add(&e);
    }
    assert!(sum.main > 0.0 && sum.ghost > 0.0 && sum.absorbed > 0.0, "{sum:?}");
    assert!(sum.stray > 0.0, "no stray light reached the detector: {sum:?}");
}

fn tiny_renderer<'a>(sys: &'a SequentialSystem, tracer: &'a AnalyticTracer, n: usize, planes: Vec<f64>, rays: usize) -> Renderer<'a> {
    let mut cfg = RenderConfig::paper(n);
    cfg.spectral = SpectralSampling::new(planes, 1).unwrap();
    cfg.rays_per_pixel = rays;
    cfg.airy = None;
    // A detector wide enough for SP's defocused ghosts (0.25 mm pixels, 15 mm margin).
    cfg.detector_pitch_mm = 0.25;
    cfg.detector_extra_px = 60;
    Renderer::new(sys, tracer, cfg, Mask::open(n, n)).unwrap()
}

/// The ghost and stray images do not depend on the thread count (1 vs 3 threads, bit for bit), mounts on.
#[test]
fn ghost_images_do_not_depend_on_thread_count() {
    let sys = sp_with_mounts(0.3);
    let tracer = AnalyticTracer::default();
    let r = tiny_renderer(&sys, &tracer, 3, vec![480.0, 520.0, 560.0], 4);
    let scene = SpectralCube::uniform(3, 3, vec![450.0, 650.0], 1.0);
    let mech = diffcassi::mechanics::Mechanics::from_system(&sys, Path::new(".")).unwrap();
    let kernel = BruteForce::new(&sys, &SolidsOptions::default()).unwrap().with_extra(Arc::new(mech));
    let mut cfg = GhostConfig::new(2, &sys, 4);
    cfg.threshold = 1e-3; // roulette plays
    let go = |threads: usize| rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| render_ghosts(&r, &kernel, &scene, &cfg, false).unwrap());
    let (a, b) = (go(1), go(3));
    assert!(a.report.ghost_total > 0.0);
    assert_eq!(a.ghost.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), b.ghost.iter().map(|v| v.to_bits()).collect::<Vec<_>>());
    assert_eq!(a.stray.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), b.stray.iter().map(|v| v.to_bits()).collect::<Vec<_>>());
    assert_eq!(a.report.energy, b.report.energy);
}

/// AP's ghost (`13R 4R`, 24.7 mm off axis): the rendered ghost image of an on-axis pixel at 520 nm lands
/// where `ghosts` says, with the energy (relative to the main path) it says.
#[test]
fn ghost_image_lands_where_the_ghosts_analysis_says() {
    let sys = SequentialSystem::build(&presets::spec("ap").unwrap()).unwrap();
    let report = ghost_analysis(&sys, &GhostOptions { order: 2, extended_grid: 1, ..Default::default() }).unwrap();
    let rows = report.on_axis_520();
    let e: f64 = rows.iter().map(|p| p.energy_fraction).sum();
    let x = rows.iter().map(|p| p.energy_fraction * p.x_mm).sum::<f64>() / e;
    let y = rows.iter().map(|p| p.energy_fraction * p.y_mm).sum::<f64>() / e;
    assert!(x.abs() > 10.0, "AP's ghost is off axis: x = {x}");
    // One on-axis scene pixel (1×1 scene), a detector wide enough for the ghost (0.25 mm pixels).
    let tracer = AnalyticTracer::default();
    let mut cfg = RenderConfig::paper(1);
    cfg.spectral = SpectralSampling::new(vec![520.0], 1).unwrap();
    cfg.rays_per_pixel = 64;
    cfg.airy = None;
    cfg.detector_pitch_mm = 0.25;
    cfg.detector_extra_px = 130;
    let r = Renderer::new(&sys, &tracer, cfg, Mask::open(1, 1)).unwrap();
    let scene = SpectralCube::uniform(1, 1, vec![450.0, 650.0], 1.0);
    let kernel = BruteForce::new(&sys, &SolidsOptions::default()).unwrap();
    let g = render_ghosts(&r, &kernel, &scene, &GhostConfig::new(2, &sys, 64), false).unwrap();
    let en = &g.report.energy;
    let fraction = en.ghost / en.main;
    assert!((fraction / e - 1.0).abs() < 0.05, "ghost energy / main: render {fraction:.4e}, ghosts analysis {e:.4e}");
    let det = r.detector;
    let (mut s, mut sx, mut sy) = (0.0, 0.0, 0.0);
    for row in 0..det.height {
        for col in 0..det.width {
            let v = g.ghost[row * det.width + col];
            let [px, py] = det.pixel_centre_mm(row, col);
            s += v;
            sx += v * px;
            sy += v * py;
        }
    }
    assert!(g.report.off_detector < 1e-3 * s, "the detector covers the ghost");
    let (cx, cy) = (sx / s, sy / s);
    assert!((cx - x).abs() < 0.3 && (cy - y).abs() < 0.3, "ghost centroid: render ({cx:.3}, {cy:.3}) mm, ghosts analysis ({x:.3}, {y:.3}) mm");
}
