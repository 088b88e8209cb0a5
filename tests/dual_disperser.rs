//! Dual-disperser CASSI (issue 44): the coded mask as a surface inside the system, the `ddsp`/`mddsp`
//! presets, rendering through the mask surface, the exact operator and its adjoint, the DD shift and mapping
//! models, and bad input.
use diffcassi::prelude::*;
use diffcassi::rays::RayBatch;
use diffcassi::recon::exact::ExactOperator;
use diffcassi::recon::layout::{dot, norm};
use diffcassi::recon::mapping::MappingOperator;
use diffcassi::recon::shift::ShiftOperator;
use diffcassi::recon::sparse::SparseExport;
use diffcassi::recon::{MappingInterpolation, Operator};
use diffcassi::render::{Mask, RenderConfig, Renderer, SpectralSampling};
use diffcassi::scene::{synthetic_scene, SpectralCube};
use diffcassi::spec::{Cell, CodedMaskSpec, MaskSampling, SurfaceKind, SurfaceSpec};
use rand::{Rng, SeedableRng};

fn system(name: &str) -> SequentialSystem {
    SequentialSystem::build(&presets::spec(name).unwrap()).unwrap()
}

/// Detector positions (mm) of the chief rays of `fields` at `wavelength_nm` (all must arrive).
fn chief_on_detector(sys: &SequentialSystem, fields: &[[f64; 2]], wavelength_nm: f64) -> Vec<[f64; 2]> {
    let out = AnalyticTracer::default().trace(sys, &RayBatch::chief_rays(sys, fields, wavelength_nm).unwrap()).unwrap();
    (0..fields.len())
        .map(|k| {
            assert_eq!(out.status[k], RayStatus::Ok, "{}: field {:?} at {wavelength_nm} nm", sys.name(), fields[k]);
            [out.x[k], out.y[k]]
        })
        .collect()
}

#[test]
fn presets_hold_one_mask_surface_and_the_sd_presets_none() {
    for name in presets::NAMES.iter().chain(&["gsp"]) {
        assert!(system(name).coded_mask.is_none(), "{name}");
    }
    for name in ["ddsp", "mddsp"] {
        let s = system(name);
        let m = s.coded_mask.expect("a mask surface");
        assert_eq!((m.surface, m.pitch_mm, m.sampling), (19, 0.01, MaskSampling::Nearest), "{name}");
        assert_eq!(s.surfaces.len(), 39);
    }
    // The spec formats carry the mask surface (TOML round trip), and the .zmx export writes it as a plain
    // surface with a comment.
    let spec = presets::spec("ddsp").unwrap();
    let text = toml::to_string(&spec).unwrap();
    assert!(text.contains("coded_mask"), "{text}");
    let back: diffcassi::spec::SystemSpec = toml::from_str(&text).unwrap();
    assert_eq!(back.surfaces[19].coded_mask, spec.surfaces[19].coded_mask);
    let zmx = diffcassi::spec::zmx::to_zmx(&spec).unwrap();
    assert!(zmx.contains("COMM coded mask (SP's image plane) [CODED MASK pitch 10 um, nearest sampling]"), "the .zmx comment");
    // ... which the importer reads back: the same system.
    let read = diffcassi::spec::zmx::import_zmx(zmx.as_bytes(), "ddsp.zmx", None, &Default::default()).unwrap().spec;
    assert_eq!(read.surfaces[19].coded_mask, spec.surfaces[19].coded_mask);
    assert_eq!(read.surfaces[19].comment, spec.surfaces[19].comment);
}

/// `ddsp` images the scene onto the detector registered: at 520 nm every field within 1 pixel (10 µm) of the
/// unit-magnification placement; the residual dispersion across 450–650 nm stays under a pixel over the field
/// for `ddsp` and is larger for `mddsp` (its second prism is tilted).
#[test]
fn ddsp_is_registered_at_520_nm_and_its_residual_dispersion_is_reported() {
    let half = 0.32; // a 64×64 scene of 10 µm pixels
    let fields: Vec<[f64; 2]> = (0..5).flat_map(|i| (0..5).map(move |j| [-half + 0.16 * j as f64, -half + 0.16 * i as f64])).collect();
    let mut worst_residual = [0.0f64; 2];
    for (k, name) in ["ddsp", "mddsp"].iter().enumerate() {
        let sys = system(name);
        let at520 = chief_on_detector(&sys, &fields, 520.0);
        let centre = chief_on_detector(&sys, &[[0.0, 0.0]], 520.0)[0];
        // The orientation from the fields ±x, ±y.
        let sx = (at520[4][0] - at520[0][0]).signum();
        let sy = (at520[20][1] - at520[0][1]).signum();
        let mut worst = 0.0f64;
        for (f, p) in fields.iter().zip(&at520) {
            let e = ((p[0] - centre[0] - sx * f[0]).powi(2) + (p[1] - centre[1] - sy * f[1]).powi(2)).sqrt();
            worst = worst.max(e);
        }
        println!("{name}: orientation ({sx}, {sy}); registration error at 520 nm over the field: max {:.3} µm", worst * 1e3);
        if *name == "ddsp" {
            assert!(worst < 0.010, "{name}: registration error {worst} mm ≥ 1 px");
        }
        for l in [450.0, 475.0, 500.0, 550.0, 600.0, 650.0] {
            let at = chief_on_detector(&sys, &fields, l);
            let r = at.iter().zip(&at520).map(|(a, b)| ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt()).fold(0.0, f64::max);
            println!("{name}: residual dispersion {l} nm vs 520 nm: max {:.2} µm over the field", r * 1e3);
            worst_residual[k] = worst_residual[k].max(r);
        }
    }
    assert!(worst_residual[0] < 0.010, "ddsp's residual dispersion {} mm ≥ 1 px", worst_residual[0]);
    assert!(worst_residual[1] > 2.0 * worst_residual[0], "mddsp's tilted second prism leaves more residual dispersion: {worst_residual:?}");
}

/// A one-column mask and a flat scene: in band b the detector sees the scene column whose first-arm image at
/// λ_b falls on the open mask column (the mask sheared by the band's dispersion), registered — each band's
/// centroid column is checked against that prediction from the chief rays.
#[test]
fn one_column_mask_is_sheared_by_each_bands_dispersion() {
    let size = 48;
    let sys = system("ddsp");
    let bands = vec![500.0, 510.0, 520.0, 530.0, 540.0];
    let mut cfg = RenderConfig::paper(size);
    cfg.spectral = SpectralSampling::new(bands.clone(), 1).unwrap();
    cfg.rays_per_pixel = 16;
    cfg.airy = None;
    let col = 24;
    let tracer = AnalyticTracer::default();
    let renderer = Renderer::new(&sys, &tracer, cfg, Mask::slit(size, size, col)).unwrap();
    let scene = SpectralCube::uniform(size, size, bands.clone(), 1.0);
    let acq = renderer.render(&scene, true, &|_| {}).unwrap();
    let det = renderer.detector;
    let ms = sys.coded_mask.unwrap();
    let mut predicted = Vec::new();
    for (b, &l) in bands.iter().enumerate() {
        let img = &acq.bands.as_ref().unwrap()[b];
        let (mut s, mut sc) = (0.0f64, 0.0f64);
        for (k, v) in img.iter().enumerate() {
            s += *v as f64;
            sc += *v as f64 * (k % det.width) as f64;
        }
        assert!(s > 0.0, "band {l} nm: no light through the slit");
        let measured = sc / s;
        // The scene x whose chief ray at λ crosses the mask at the open column's centre (bisection: the
        // first arm maps x monotonically).
        let target = (col as f64 + 0.5 - size as f64 * 0.5) * ms.pitch_mm;
        let xm = |x: f64| sys.point_on_mask([x, 0.0], [0.0, 0.0], l).unwrap().unwrap().0;
        let (mut lo, mut hi) = (-0.3, 0.3);
        let rising = xm(hi) > xm(lo);
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if (xm(mid) < target) == rising {
                lo = mid
            } else {
                hi = mid
            }
        }
        let x = 0.5 * (lo + hi);
        let p = chief_on_detector(&sys, &[[x, 0.0]], l)[0];
        let expect = det.to_pixel(p[0], p[1]).0;
        println!("band {l} nm: scene x {:.4} mm on the open mask column; detector column predicted {expect:.3}, measured {measured:.3}", x);
        assert!((measured - expect).abs() < 0.5, "band {l} nm: centroid column {measured} vs predicted {expect}");
        predicted.push(expect);
    }
    assert!((predicted[0] - predicted[4]).abs() > 5.0, "the mask is sheared across the bands: {predicted:?}");
}

fn random(n: usize, seed: u64) -> Vec<f32> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    (0..n).map(|_| rng.gen_range(-1.0f32..1.0)).collect()
}

/// The exact operator equals the renderer for `ddsp`, its adjoint passes the dot-product test (f32 sums:
/// 1e-6), and the same operator written out as a sparse matrix passes it in f64 within 1e-9; the DD shift
/// and mapping models are adjoint too.
#[test]
fn exact_operator_equals_the_renderer_and_is_adjoint_for_ddsp() {
    let size = 20;
    let bands = vec![480.0, 520.0, 560.0, 600.0];
    let sys = system("mddsp");
    let tracer = AnalyticTracer::default();
    let mut cfg = RenderConfig::paper(size);
    cfg.spectral = SpectralSampling::new(bands.clone(), 2).unwrap();
    cfg.rays_per_pixel = 4;
    cfg.seed = 3;
    let mask = Mask::random(size, size, 0.5, 7).unwrap();
    let renderer = Renderer::new(&sys, &tracer, cfg.clone(), mask.clone()).unwrap();
    let scene = synthetic_scene(size, size, &bands, 5);
    let reference = renderer.render(&scene, false, &|_| {}).unwrap();
    assert!(reference.stats.masked > 0 && reference.stats.arrived > 0, "{:?}", reference.stats);
    let op = ExactOperator::new(renderer, &bands, 1 << 32).unwrap();
    let y = (&op as &dyn Operator).apply(&scene.data).unwrap();
    let peak = reference.image.iter().cloned().fold(0.0, f64::max);
    let worst = y.iter().zip(&reference.image).map(|(a, b)| (*a as f64 - b).abs()).fold(0.0, f64::max);
    assert!(peak > 0.05 && worst <= 1e-6 * peak, "exact ≠ render: {worst} (peak {peak})");
    let x = random((&op as &dyn Operator).cube_shape().len(), 1);
    let yv = random((&op as &dyn Operator).image_shape().len(), 2);
    let check = |o: &dyn Operator, tol: f64| {
        let (a, b) = (dot(&o.apply(&x).unwrap(), &yv), dot(&x, &o.adjoint(&yv).unwrap()));
        let rel = (a - b).abs() / (norm(&o.apply(&x).unwrap()) * norm(&yv));
        println!("{}: adjoint gap {rel:.2e}", o.name());
        assert!(rel <= tol, "{}: {rel}", o.name());
    };
    check(&op, 1e-6);
    // In f64 on the operator's own matrix (its entries are the operator's f32 weights).
    let csr = op.to_csr(1 << 32).unwrap();
    let ax = csr.matvec(&x).unwrap();
    let scale_a = ax.iter().map(|v| v.abs()).fold(0.0f32, f32::max);
    let phix = (&op as &dyn Operator).apply(&x).unwrap();
    assert!(ax.iter().zip(&phix).all(|(a, b)| (a - b).abs() <= 1e-5 * scale_a), "the sparse matrix is the operator");
    let mut lhs = 0.0f64;
    for r in 0..csr.rows {
        let (s, e) = (csr.indptr[r] as usize, csr.indptr[r + 1] as usize);
        let row: f64 = csr.indices[s..e].iter().zip(&csr.data[s..e]).map(|(c, v)| *v as f64 * x[*c as usize] as f64).sum();
        lhs += row * yv[r] as f64;
    }
    let mut aty = vec![0.0f64; csr.cols];
    for r in 0..csr.rows {
        for k in csr.indptr[r] as usize..csr.indptr[r + 1] as usize {
            aty[csr.indices[k] as usize] += csr.data[k] as f64 * yv[r] as f64;
        }
    }
    let rhs: f64 = aty.iter().zip(&x).map(|(a, b)| a * *b as f64).sum();
    let rel = (lhs - rhs).abs() / lhs.abs().max(1e-300);
    println!("exact (f64, sparse): ⟨Φx, y⟩ = {lhs:.12e}, ⟨x, Φᵀy⟩ = {rhs:.12e}, relative {rel:.2e}");
    assert!(rel <= 1e-9);
    let renderer = Renderer::new(&sys, &tracer, cfg, mask).unwrap();
    let shift = ShiftOperator::from_renderer(&renderer, &bands).unwrap();
    check(&shift, 1e-6);
    let mapping = MappingOperator::from_renderer(&renderer, &bands, MappingInterpolation::Bilinear).unwrap();
    check(&mapping, 1e-6);
}

/// The DD shift model registers every band at one placement and shifts the mask by each band's dispersion
/// on the mask surface (whole mask pixels, growing with the wavelength gap).
#[test]
fn dd_shift_model_shifts_the_mask_not_the_image() {
    let size = 32;
    let sys = system("ddsp");
    let tracer = AnalyticTracer::default();
    let bands = vec![460.0, 520.0, 600.0];
    let mut cfg = RenderConfig::paper(size);
    cfg.spectral = SpectralSampling::new(bands.clone(), 1).unwrap();
    let renderer = Renderer::new(&sys, &tracer, cfg, Mask::random(size, size, 0.5, 1).unwrap()).unwrap();
    let op = ShiftOperator::from_renderer(&renderer, &bands).unwrap();
    let (cols, _, _, _) = op.placement();
    assert!(cols.iter().all(|c| *c == cols[0]), "identity registration: {cols:?}");
    let s = op.mask_shifts_px();
    println!("ddsp mask shifts (mask pixels) at {bands:?}: {s:?}");
    assert_eq!(s[0], 0);
    assert!(s[1].abs() >= 5 && s[2].abs() > s[1].abs() && s[1].signum() == s[2].signum(), "{s:?}");
    // The SD shift model has no mask shifts.
    let sp = system("sp");
    let r2 = Renderer::new(&sp, &tracer, renderer.config.clone(), Mask::random(size, size, 0.5, 1).unwrap()).unwrap();
    assert!(ShiftOperator::from_renderer(&r2, &bands).unwrap().mask_shifts_px().is_empty());
}

fn build_err(spec: &diffcassi::spec::SystemSpec) -> String {
    SequentialSystem::build(spec).err().expect("refused").to_string()
}

#[test]
fn bad_mask_surfaces_are_refused_clearly() {
    let base = presets::spec("ddsp").unwrap();
    // Two mask surfaces.
    let mut two = base.clone();
    two.surfaces[1].coded_mask = Some(CodedMaskSpec { pitch_um: 10.0, sampling: MaskSampling::Nearest });
    let e = build_err(&two);
    assert!(e.contains("surface 19") && e.contains("coded_mask") && e.contains("at most one"), "{e}");
    // Pitch 0, NaN, negative.
    for (p, shown) in [(0.0, "pitch_um 0"), (f64::NAN, "pitch_um NaN"), (-5.0, "pitch_um -5")] {
        let mut s = base.clone();
        s.surfaces[19].coded_mask = Some(CodedMaskSpec { pitch_um: p, sampling: MaskSampling::Nearest });
        let e = build_err(&s);
        assert!(e.contains("surface 19") && e.contains(shown), "{p}: {e}");
    }
    // On a curved surface, in glass, on the image.
    let mut s = base.clone();
    s.surfaces[16].coded_mask = s.surfaces[19].coded_mask.take();
    assert!(build_err(&s).contains("flat Standard"), "{}", build_err(&s));
    let mut s = base.clone();
    let last = s.surfaces.len() - 1;
    s.surfaces[last].coded_mask = s.surfaces[19].coded_mask.take();
    assert!(build_err(&s).contains("image surfaces cannot hold the coded mask"));
    let mut s = base.clone();
    s.surfaces[7].coded_mask = s.surfaces[19].coded_mask.take(); // a break (prism region)
    assert!(build_err(&s).contains("flat Standard"));
    let mut s = base.clone();
    s.surfaces[10].coded_mask = s.surfaces[19].coded_mask.take(); // the prism's second face: N-BK7 after it
    let e = build_err(&s);
    assert!(e.contains("thin plate in air") || e.contains("sit in air"), "{e}");
    // A mask surface outside the beam: decentred 30 mm by a break before it (and back after).
    let mut s = base.clone();
    s.surfaces.insert(19, SurfaceSpec::coordinate_break(30.0, 0.0, 0.0, 0.0, 0.0, 0.0));
    s.surfaces.insert(21, SurfaceSpec::coordinate_break(-30.0, 0.0, 0.0, 0.0, 0.0, 0.0));
    let sys = SequentialSystem::build(&s).unwrap();
    let tracer = AnalyticTracer::default();
    let mut cfg = RenderConfig::paper(16);
    cfg.spectral = SpectralSampling::new(vec![500.0, 540.0], 1).unwrap();
    let e = Renderer::new(&sys, &tracer, cfg.clone(), Mask::random(16, 16, 0.5, 1).unwrap()).err().expect("refused").to_string();
    assert!(e.contains("outside the beam") && e.contains("surface 20"), "{e}");
    // Settings the mask surface does not support yet are refused, not silently wrong.
    let dd = system("ddsp");
    let mut f32cfg = cfg.clone();
    f32cfg.precision = diffcassi::tracer::Precision::F32;
    let e = Renderer::new(&dd, &tracer, f32cfg, Mask::random(16, 16, 0.5, 1).unwrap()).err().expect("refused").to_string();
    assert!(e.contains("f32") && e.contains("surface 19"), "{e}");
    let mut batched = cfg;
    batched.force_batched = true;
    let e = Renderer::new(&dd, &tracer, batched, Mask::random(16, 16, 0.5, 1).unwrap()).err().expect("refused").to_string();
    assert!(e.contains("direct path"), "{e}");
    let _ = Cell::fixed(0.0);
}

fn bin() -> std::process::Command {
    std::process::Command::new(env!("CARGO_BIN_EXE_diffcassi"))
}

fn run_ok(args: &[&str]) -> String {
    let out = bin().args(args).output().unwrap();
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "diffcassi {}: {text}", args.join(" "));
    text
}

/// The command-line interfaces: `render --preset ddsp --scene-size N --out DIR`, `render-dataset`,
/// `reconstruct` with every solver, `--device cpu-twin` (the GPU kernels), and the refusals of what the mask
/// surface does not support yet.
#[test]
fn cli_renders_ddsp_and_reconstructs_with_every_solver() {
    let tmp = std::env::temp_dir().join(format!("diffcassi-dd-cli-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    let render = tmp.join("render");
    run_ok(&["render", "--preset", "ddsp", "--scene-size", "16", "--planes", "8", "--rays", "2", "--out", render.to_str().unwrap()]);
    for f in ["acquisition.exr", "render.json", "mask.png"] {
        assert!(render.join(f).is_file(), "{f}");
    }
    let rec: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(render.join("render.json")).unwrap()).unwrap();
    assert!(rec["ray_stats"]["masked"].as_u64().unwrap() > 0, "rays blocked by the mask surface are counted");
    assert_eq!(rec["system"].as_str().unwrap(), "ddsp");
    for solver in ["gap-tv", "admm-tv", "pnp-gap", "pnp-admm"] {
        for op in ["exact", "mapping", "shift"] {
            let out = tmp.join(format!("rec-{solver}-{op}"));
            let mut args = vec!["reconstruct", "--from", render.to_str().unwrap(), "--operator", op, "--solver", solver, "--iterations", "4"];
            if solver.starts_with("pnp") {
                args.extend_from_slice(&["--tv-warmup", "2"]);
            }
            args.extend_from_slice(&["--out", out.to_str().unwrap()]);
            run_ok(&args);
            assert!(out.join("cube.npy").is_file() && out.join("reconstruct.json").is_file(), "{solver} {op}");
        }
    }
    // Two bands at 480 and 560 nm on a 16² scene: the dispersion carries every chief ray past the 16×16 mask in
    // both bands, so the mapping and shift operators are zero — refused (every solver would return 0 with
    // residual 1, silently), nothing written; the exact operator, whose planes lie between the bands, runs.
    let two = tmp.join("two-bands");
    run_ok(&["render", "--preset", "ddsp", "--scene-size", "16", "--planes", "4", "--bands", "480,560", "--rays", "2", "--out", two.to_str().unwrap()]);
    for op in ["mapping", "shift"] {
        let out = tmp.join(format!("zero-{op}"));
        let o = bin().args(["reconstruct", "--from", two.to_str().unwrap(), "--operator", op, "--iterations", "3", "--out", out.to_str().unwrap()]).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && err.contains(&format!("the operator `{op}")) && err.contains("maps no voxel") && err.contains("16×16×2"), "{op}: {err}");
        assert!(!out.join("cube.npy").exists() && !out.join("reconstruct.json").exists(), "{op}: nothing written");
    }
    run_ok(&["reconstruct", "--from", two.to_str().unwrap(), "--operator", "exact", "--iterations", "3", "--out", tmp.join("two-exact").to_str().unwrap()]);
    // A mask of 1e-9 µm pixels blocks every ray: the render writes the zero acquisition and says so; the exact
    // operator is zero too, and reconstruct refuses it.
    let mut fine = diffcassi::presets::spec("ddsp").unwrap();
    fine.surfaces.iter_mut().find_map(|s| s.coded_mask.as_mut()).unwrap().pitch_um = 1e-9;
    let spec = tmp.join("fine.toml");
    std::fs::write(&spec, diffcassi::spec::to_toml(&fine).unwrap()).unwrap();
    let dark = tmp.join("dark");
    let text = run_ok(&["render", "--system", spec.to_str().unwrap(), "--scene-size", "8", "--planes", "2", "--rays", "1", "--out", dark.to_str().unwrap()]);
    assert!(text.contains("warning: the acquisition is zero everywhere (no ray delivered light"), "{text}");
    let o = bin().args(["reconstruct", "--from", dark.to_str().unwrap(), "--iterations", "3", "--out", tmp.join("dark-rec").to_str().unwrap()]).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("the operator `exact` maps no voxel"), "{err}");
    let plain = run_ok(&["render", "--preset", "ddsp", "--scene-size", "16", "--planes", "8", "--rays", "2", "--out", tmp.join("lit").to_str().unwrap()]);
    assert!(!plain.contains("warning: the acquisition is zero"), "{plain}");
    // --tolerance-um chooses among what a mask surface supports (the analytic f64 path).
    let tol = tmp.join("tol");
    let text = run_ok(&["render", "--preset", "ddsp", "--scene-size", "8", "--planes", "4", "--tolerance-um", "2", "--calibration-cache", tmp.join("cache").to_str().unwrap(), "--out", tol.to_str().unwrap()]);
    assert!(text.contains("→ --backend analytic --rays"), "{text}");
    let scenes = tmp.join("scenes");
    std::fs::create_dir_all(&scenes).unwrap();
    std::fs::copy(concat!(env!("CARGO_MANIFEST_DIR"), "/data/scenes/chelsea.png"), scenes.join("chelsea.png")).unwrap();
    let ds = tmp.join("dataset");
    run_ok(&["render-dataset", "--scenes", scenes.to_str().unwrap(), "--preset", "mddsp", "--scene-size", "16", "--planes", "8", "--rays", "2", "--out", ds.to_str().unwrap()]);
    // The GPU kernels model the mask surface (docs/gpu.md): `--device cpu-twin` runs them on the CPU, each ray
    // weighted where it crosses the mask, its blocked rays counted as on the CPU.
    let twin = tmp.join("twin");
    run_ok(&["render", "--preset", "ddsp", "--scene-size", "16", "--planes", "8", "--rays", "2", "--device", "cpu-twin", "--out", twin.to_str().unwrap()]);
    let tw: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(twin.join("render.json")).unwrap()).unwrap();
    assert_eq!(tw["device"]["device"].as_str().unwrap(), "cpu-twin");
    assert_eq!(tw["ray_stats"]["masked"], rec["ray_stats"]["masked"], "the twin blocks the CPU's rays");
    for refused in [&["--precision", "f32"][..], &["--backend", "embree-user"], &["--ghosts", "1"]] {
        let mut args = vec!["render", "--preset", "ddsp", "--scene-size", "8", "--planes", "2", "--rays", "1"];
        args.extend_from_slice(refused);
        let out = tmp.join("refused");
        args.extend_from_slice(&["--out", out.to_str().unwrap()]);
        let o = bin().args(&args).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && err.contains("coded mask"), "{refused:?}: {err}");
        assert!(!out.join("acquisition.exr").exists(), "{refused:?}: nothing written");
    }
    let _ = std::fs::remove_dir_all(&tmp);
}

/// `ddsp` with its mask sampled `sampling`, a differentiable renderer of a `size`² scene at bands around
/// 520 nm (so that the dispersed image stays on the mask) with free parameters `free`.
fn dd_diff_renderer(sampling: MaskSampling, free: &[&str], size: usize, seed: u64) -> diffcassi::render::gradient::DiffRenderer {
    use diffcassi::diff::{Param, ParamSet};
    let mut spec = presets::spec("ddsp").unwrap();
    spec.surfaces[19].coded_mask.as_mut().unwrap().sampling = sampling;
    let params: Vec<Param> = free.iter().map(|t| Param::parse(t).unwrap()).collect();
    let set = ParamSet::new(spec, diffcassi::materials::GlassCatalog::builtin(), params).unwrap();
    let mut cfg = RenderConfig::paper(size);
    cfg.spectral = SpectralSampling::new(DD_BANDS.to_vec(), 1).unwrap();
    cfg.rays_per_pixel = 2;
    cfg.seed = seed;
    diffcassi::render::gradient::DiffRenderer::new(set, cfg, DD_BANDS.to_vec()).unwrap()
}

const DD_BANDS: [f64; 3] = [516.0, 520.0, 524.0];

/// The differentiable renderer refuses a mask surface outside the beam with the forward renderer's message
/// (one check, `render::engine::check_mask_in_beam`): at construction, and when new parameter values move
/// the mask out of the beam (`with_values`). `ddsp` with a break before the mask (surface 20) and one after
/// that undoes it (a pickup, scale −1), the first's decenter x free: 0 (in the beam), then 30 mm (out of it).
#[test]
fn diff_renderer_refuses_a_mask_surface_outside_the_beam_as_the_renderer_does() {
    use diffcassi::diff::{Param, ParamSet};
    use diffcassi::render::gradient::DiffRenderer;
    let mut spec = presets::spec("ddsp").unwrap();
    spec.surfaces.insert(19, SurfaceSpec::coordinate_break(0.0, 0.0, 0.0, 0.0, 0.0, 0.0));
    spec.surfaces.insert(21, SurfaceSpec::coordinate_break(0.0, 0.0, 0.0, 0.0, 0.0, 0.0));
    spec.surfaces[21].decenter_x_mm = Some(Cell::pickup(0.0, 19, -1.0));
    let mut cfg = RenderConfig::paper(16);
    cfg.spectral = SpectralSampling::new(DD_BANDS.to_vec(), 1).unwrap();
    cfg.rays_per_pixel = 1;
    let free = || vec![Param::parse("s19.decenter_x_mm").unwrap()];
    let set = |spec: &diffcassi::spec::SystemSpec| ParamSet::new(spec.clone(), diffcassi::materials::GlassCatalog::builtin(), free()).unwrap();
    let in_beam = DiffRenderer::new(set(&spec), cfg.clone(), DD_BANDS.to_vec()).unwrap();
    let moved_out = in_beam.with_values(&[30.0]).err().expect("refused").to_string();
    spec.surfaces[19].decenter_x_mm = Some(Cell::fixed(30.0));
    let sys = SequentialSystem::build(&spec).unwrap();
    let forward = Renderer::new(&sys, &AnalyticTracer::default(), cfg.clone(), Mask::open(16, 16)).err().expect("refused").to_string();
    assert!(forward.contains("outside the beam") && forward.contains("surface 20"), "{forward}");
    assert_eq!(moved_out, forward);
    let built_out = DiffRenderer::new(set(&spec), cfg, DD_BANDS.to_vec()).err().expect("refused").to_string();
    assert_eq!(built_out, forward);
}

/// A scene (N = 2), a mask with closed pixels and values in (0, 1], and an upstream gradient, from `seed`.
fn dd_inputs(r: &diffcassi::render::gradient::DiffRenderer, seed: u64) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let hw = r.config.scene_height * r.config.scene_width;
    let scene: Vec<f64> = (0..2 * DD_BANDS.len() * hw).map(|_| rng.gen_range(0.0..1.0)).collect();
    let mask: Vec<f64> = (0..hw).map(|_| rng.gen_range(0.0..1.0)).map(|v: f64| if v < 0.3 { 0.0 } else { v }).collect();
    let (h, w) = r.image_shape();
    let g: Vec<f64> = (0..2 * h * w).map(|_| rng.gen_range(-0.5..0.5)).collect();
    (scene, mask, g)
}

/// `ddsp` cut after its mask surface (the mask surface made the image, its mask removed): where a ray crosses
/// the mask, as a system whose forward-mode Jacobians ([`DiffSystem::trace`]) give the crossing point's
/// derivatives.
fn ddsp_to_the_mask() -> diffcassi::spec::SystemSpec {
    let mut spec = presets::spec("ddsp").unwrap();
    spec.surfaces.truncate(20);
    spec.surfaces[19].coded_mask = None;
    spec
}

/// Object-space rays of `ddsp` (fields × pupil points × DD_BANDS), unit directions, from the paraxial
/// entrance-pupil aim the differentiable renderer uses.
fn dd_rays(sys: &SequentialSystem) -> RayBatch {
    let aim = diffcassi::rays::PupilAim::of(sys);
    let mut rays = RayBatch::with_capacity(64);
    for f in [[0.0, 0.0], [0.03, -0.02], [-0.035, 0.025]] {
        for pu in [[0.0, 0.0], [0.5, 0.3], [-0.4, -0.6]] {
            for l in DD_BANDS {
                let d = glam::DVec3::from(aim.direction(f[0], f[1], pu[0], pu[1]));
                rays.push(glam::DVec3::new(f[0], f[1], 0.0), d / d.length(), l);
            }
        }
    }
    rays
}

/// Steps for central differences that move landings on the detector and crossings on the mask by ~1e-5 of a
/// 10 µm pixel at most (forward-mode Jacobians of chief and marginal rays), so that few rays cross a kink of
/// the bilinear splat or mask (their derivatives jump there; a whole ray's status change is rarer still).
fn dd_fd_steps(free: &[&str]) -> Vec<f64> {
    use diffcassi::diff::{Param, ParamSet};
    let cat = diffcassi::materials::GlassCatalog::builtin();
    let full = presets::spec("ddsp").unwrap();
    let rays = dd_rays(&SequentialSystem::build(&full).unwrap());
    free.iter()
        .map(|name| {
            let mut motion = 0.0f64;
            for spec in [full.clone(), ddsp_to_the_mask()] {
                // A parameter of a surface past the mask does not move the crossing.
                let Ok(set) = ParamSet::new(spec, cat.clone(), vec![Param::parse(name).unwrap()]) else { continue };
                let j = set.build().unwrap().trace(&rays).unwrap();
                for i in (0..rays.len()).filter(|&i| j.usable(i)) {
                    let d = j.d_position(i, 0);
                    motion = motion.max(d.x.abs()).max(d.y.abs());
                }
            }
            assert!(motion > 0.0, "{name} moves nothing");
            1e-7 / motion
        })
        .collect()
}

/// The seeded reverse sweep gives the derivatives of where a ray crosses the mask surface: with λ = 0 at the
/// detector and ∂L/∂(crossing) = eₓ or e_y at the mask's step, the contracted sums equal the forward-mode
/// Jacobian of the same ray traced to the mask (a system cut there) — for parameters of the first arm, of
/// the mask's distance, and of glasses on both sides — to 1e-10 of each column's largest entry.
#[test]
fn seeded_sweep_gives_the_crossing_points_forward_tangents() {
    use diffcassi::diff::adjoint::{AdjointPlan, AdjointSums, RayTape};
    use diffcassi::diff::{Param, ParamSet};
    let free = ["s5.tilt_y_deg", "s15.thickness_mm", "s16.curvature", "s17.radius_mm", "s18.thickness_mm", "glass_nd:N-BK7", "glass_vd:SF10"];
    let params: Vec<Param> = free.iter().map(|t| Param::parse(t).unwrap()).collect();
    let cat = diffcassi::materials::GlassCatalog::builtin();
    let full = ParamSet::new(presets::spec("ddsp").unwrap(), cat.clone(), params.clone()).unwrap().build().unwrap();
    let half = ParamSet::new(ddsp_to_the_mask(), cat, params).unwrap().build().unwrap();
    let step = full.system.coded_mask.unwrap().step;
    let rays = dd_rays(&full.system);
    let j = half.trace(&rays).unwrap();
    let kk = free.len();
    // (sweep, forward) per ray coordinate and parameter.
    let mut pairs: Vec<(Vec<f64>, Vec<f64>)> = Vec::new();
    for &l in &DD_BANDS {
        let plan = AdjointPlan::new(&full, &[l]).unwrap();
        let (n, dn) = full.index_tangents(l).unwrap();
        let mut tape = RayTape::default();
        for i in (0..rays.len()).filter(|&i| rays.wavelength_nm[i] == l && j.usable(i)) {
            plan.trace(&full, &n, rays.origin(i), rays.direction(i), &mut tape).unwrap();
            let q = tape.point(step).unwrap();
            assert!((q.x - j.traced.x[i]).abs() < 1e-12 && (q.y - j.traced.y[i]).abs() < 1e-12, "ray {i}: the same crossing");
            for c in 0..2 {
                let mut sums = AdjointSums::new(&plan);
                let e = if c == 0 { glam::DVec3::X } else { glam::DVec3::Y };
                assert!(plan.backward_seeded(&full, &mut tape, [0.0; 6], Some((step, e)), &mut sums));
                let mut grad = vec![0.0; kk];
                plan.contract(&full, &sums, &dn, &mut grad);
                let fwd: Vec<f64> = (0..kk).map(|k| if c == 0 { j.d_position(i, k).x } else { j.d_position(i, k).y }).collect();
                pairs.push((grad, fwd));
            }
        }
    }
    let checked = pairs.len();
    let mut worst = 0.0f64;
    for k in 0..kk {
        let scale = pairs.iter().fold(0.0f64, |a, (_, f)| a.max(f[k].abs()));
        assert!(scale > 0.0, "{} moves no crossing", free[k]);
        let e = pairs.iter().fold(0.0f64, |a, (g, f)| a.max((g[k] - f[k]).abs())) / scale;
        println!("{:>18}: largest |∂crossing/∂θ| {scale:.3e}, sweep − forward ≤ {e:.1e} of it", free[k]);
        worst = worst.max(e);
    }
    println!("seeded sweep vs forward tangents of the crossing point: worst {worst:.2e} of the column's largest entry ({checked} ray coordinates)");
    assert!(checked >= 40 && worst <= 1e-10, "{checked} checked, worst {worst:.2e}");
}

/// The implicit derivatives of rays that cross the mask surface (issue 44, item 3): ∂L/∂θ of the
/// same-sample acquisition against central finite differences for parameters before the mask (they move the
/// crossing point, read by the bilinear mask, and the landing), at it (its distance from the lens) and
/// after it (the landing only); ∂L/∂mask and ∂L/∂scene exact (the acquisition is linear in both).
#[test]
fn gradients_through_the_mask_surface_match_finite_differences() {
    let free = ["s5.tilt_y_deg", "s16.curvature", "s18.thickness_mm", "s20.radius_mm", "s25.tilt_y_deg", "glass_nd:N-BK7", "glass_nd:SF10"];
    let r = dd_diff_renderer(MaskSampling::Bilinear, &free, 8, 11);
    let steps = dd_fd_steps(&free);
    let (scene, mask, g) = dd_inputs(&r, 4);
    let loss = |r: &diffcassi::render::gradient::DiffRenderer, scene: &[f64], mask: &[f64]| -> f64 { r.render(scene, 2, mask).unwrap().iter().zip(&g).map(|(a, b)| a * b).sum() };
    let v = r.vjp(&scene, 2, &mask, &g).unwrap();
    let x0 = r.values().unwrap();
    let scale = v.params.iter().fold(0.0f64, |a, b| a.max(b.abs()));
    let mut worst = 0.0f64;
    for k in 0..x0.len() {
        let h = steps[k];
        let at = |d: f64| {
            let mut x = x0.clone();
            x[k] += d;
            loss(&r.with_values(&x).unwrap(), &scene, &mask)
        };
        let fd = (at(h) - at(-h)) / (2.0 * h);
        let err = (fd - v.params[k]).abs() / v.params[k].abs().max(1e-3 * scale);
        println!("ddsp bilinear {:>18}: step {h:.1e}  vjp {:+.9e}  fd {:+.9e}  rel {err:.1e}", free[k], v.params[k], fd);
        worst = worst.max(err);
    }
    println!("ddsp bilinear: worst relative error {worst:.2e} over {} parameters", x0.len());
    assert!(worst <= 1e-6, "worst relative error {worst:.2e}");
    // Linear in the mask and the scene.
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    let l0 = loss(&r, &scene, &mask);
    let close = |a: f64, b: f64, what: &str| {
        let rel = (a - b).abs() / a.abs().max(b.abs());
        println!("{what}: {a:+.15e} vs {b:+.15e} (rel {rel:.1e})");
        assert!(rel < 1e-12, "{what}: {a} vs {b}");
    };
    close(l0, dot(&v.mask, &mask), "L vs ∂L/∂mask · mask");
    close(l0, dot(&v.scene, &scene), "L vs ∂L/∂scene · scene");
    let dm: Vec<f64> = (0..mask.len()).map(|i| ((i * 37 % 11) as f64) / 11.0).collect();
    let m2: Vec<f64> = mask.iter().zip(&dm).map(|(a, b)| a + b).collect();
    close(loss(&r, &scene, &m2) - l0, dot(&v.mask, &dm), "ΔL vs ∂L/∂mask · δ");
    assert!(mask.iter().zip(&v.mask).any(|(m, gm)| *m == 0.0 && gm.abs() > 0.0), "closed mask pixels get a gradient");
}

/// With `nearest` sampling the transmission is piecewise constant (no crossing-point term): parameters after
/// the mask, which do not move the crossing, match finite differences as with `bilinear`; and the gradients
/// asked for alone are those of the full product, bit for bit.
#[test]
fn nearest_sampling_gradients_and_wanted_subsets() {
    use diffcassi::render::gradient::Wanted;
    let free = ["s20.radius_mm", "s25.tilt_y_deg", "s36.focal_length_mm"];
    let r = dd_diff_renderer(MaskSampling::Nearest, &free, 8, 2);
    let steps = dd_fd_steps(&free);
    let (scene, mask, g) = dd_inputs(&r, 9);
    let v = r.vjp(&scene, 2, &mask, &g).unwrap();
    let x0 = r.values().unwrap();
    let scale = v.params.iter().fold(0.0f64, |a, b| a.max(b.abs()));
    for k in 0..x0.len() {
        let h = steps[k];
        let at = |d: f64| {
            let mut x = x0.clone();
            x[k] += d;
            r.with_values(&x).unwrap().render(&scene, 2, &mask).unwrap().iter().zip(&g).map(|(a, b)| a * b).sum::<f64>()
        };
        let fd = (at(h) - at(-h)) / (2.0 * h);
        let err = (fd - v.params[k]).abs() / v.params[k].abs().max(1e-3 * scale);
        println!("ddsp nearest {:>18}: vjp {:+.9e}  fd {:+.9e}  rel {err:.1e}", r.set.free[k].name(), v.params[k], fd);
        assert!(v.params[k] != 0.0 && err <= 1e-6, "{}: {err}", r.set.free[k].name());
    }
    for w in [Wanted { params: true, mask: false, scene: false }, Wanted { params: false, mask: true, scene: true }] {
        let part = r.vjp_wanted(&scene, 2, &mask, &g, w).unwrap();
        assert_eq!((part.params.is_empty(), part.mask.is_empty(), part.scene.is_empty()), (!w.params, !w.mask, !w.scene));
        if w.params {
            assert_eq!(part.params, v.params);
        } else {
            assert_eq!((part.mask, part.scene), (v.mask.clone(), v.scene.clone()));
        }
    }
}

/// The library's render choice for a tolerance (what `--tolerance-um` prints) offers a system with a mask
/// surface only what its renderer runs: the analytic backend in f64.
#[test]
fn tolerance_choice_for_a_mask_surface_is_the_analytic_f64_path() {
    let sys = system("ddsp");
    let mut cfg = RenderConfig::paper(8);
    cfg.spectral = SpectralSampling::new(DD_BANDS.to_vec(), 1).unwrap();
    let (choice, prov) = diffcassi::fidelity::choose_render_for(&sys, &cfg, diffcassi::render::Device::Cpu, 2.0, 64, &diffcassi::fidelity::CacheOptions::none()).unwrap();
    println!("{} [{prov}]", choice.explanation);
    assert_eq!((choice.config.backend, choice.precision()), (diffcassi::tracer::Backend::Analytic, diffcassi::tracer::Precision::F64));
    assert!(choice.tracer().is_ok() && choice.rays_per_pixel >= 1 && choice.error_um <= 2.0);
    assert!(choice.explanation.contains("a coded-mask surface renders on the analytic f64 direct path only"), "{}", choice.explanation);
}

/// The differentiable renderer reads the mask where each ray crosses the surface as the production renderer
/// does: the same rays (the same samples for a seed) give the same acquisition, both mask samplings.
#[test]
fn differentiable_renderer_through_the_mask_equals_the_renderer() {
    let size = 12;
    for sampling in [MaskSampling::Nearest, MaskSampling::Bilinear] {
        let r = dd_diff_renderer(sampling, &["s25.tilt_y_deg"], size, 3);
        let mut spec = presets::spec("ddsp").unwrap();
        spec.surfaces[19].coded_mask.as_mut().unwrap().sampling = sampling;
        let sys = SequentialSystem::build(&spec).unwrap();
        let tracer = AnalyticTracer::default();
        let mask = Mask::random(size, size, 0.5, 7).unwrap();
        let renderer = Renderer::new(&sys, &tracer, r.config.clone(), mask.clone()).unwrap();
        let scene = synthetic_scene(size, size, &DD_BANDS, 5);
        let reference = renderer.render(&scene, false, &|_| {}).unwrap();
        assert!(reference.stats.masked > 0, "{:?}", reference.stats);
        // The cube is (H, W, B); the differentiable renderer takes (N, B, H, W).
        let s64 = crate::common::cube_nbhw(&scene);
        let m64: Vec<f64> = mask.values.iter().map(|v| *v as f64).collect();
        let img = r.render(&s64, 1, &m64).unwrap();
        assert_eq!(img.len(), reference.image.len());
        let peak = reference.image.iter().cloned().fold(0.0, f64::max);
        let worst = img.iter().zip(&reference.image).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        println!("{sampling:?}: differentiable vs production renderer: worst {worst:.2e} (peak {peak:.3})");
        assert!(peak > 0.0 && worst <= 1e-5 * peak, "{sampling:?}: {worst} vs peak {peak}");
    }
}

/// The shift model of a system with a coded-mask surface takes the traced detector columns: where the second
/// disperser cancels the first (ddsp, mddsp) they are one column, DD-CASSI's identity registration; SP with its
/// mask as a surface at the object plane keeps SP's dispersion and is SP's shift operator (it was given the
/// identity registration regardless: 9.6 dB against SP's 14.9 dB, silently; a held-out battery, round 10). A
/// mask turned by 90° about the axis has no ±1 model and is refused, naming why.
#[test]
fn dd_shift_model_takes_the_traced_columns_and_refuses_a_turned_mask() {
    let size = 24;
    let tracer = AnalyticTracer::default();
    let bands = vec![450.0, 520.0, 650.0];
    let mut cfg = RenderConfig::paper(size);
    cfg.spectral = SpectralSampling::new(bands.clone(), 1).unwrap();
    let mask = Mask::random(size, size, 0.5, 3).unwrap();
    for name in ["ddsp", "mddsp"] {
        let sys = system(name);
        let r = Renderer::new(&sys, &tracer, cfg.clone(), mask.clone()).unwrap();
        let op = ShiftOperator::from_renderer(&r, &bands).unwrap();
        let (cols, _, _, _) = op.placement();
        assert!(cols.iter().all(|c| *c == cols[0]), "{name}: identity registration {cols:?}");
    }
    // SP with a mask surface coincident with the object plane (the object at 0 mm before it).
    let mut spec = presets::spec("sp").unwrap();
    let t0 = spec.surfaces[0].thickness_mm.clone();
    spec.surfaces[0].thickness_mm = Cell::fixed(0.0);
    let mut m = SurfaceSpec::new(SurfaceKind::Standard);
    m.thickness_mm = t0;
    m.coded_mask = Some(CodedMaskSpec { pitch_um: cfg.scene_pitch_mm * 1e3, sampling: MaskSampling::Nearest });
    spec.surfaces.insert(1, m);
    // The pickups' sources after the inserted surface move by one.
    for surf in spec.surfaces.iter_mut() {
        for col in diffcassi::spec::COLUMNS {
            if let Some(diffcassi::spec::Driver::Pickup(p)) = surf.cell_mut(col).map(|c| &mut c.driver) {
                p.surface += 1;
            }
        }
    }
    let objmask = SequentialSystem::build(&spec).unwrap();
    let sp = system("sp");
    let (ro, rs) = (Renderer::new(&objmask, &tracer, cfg.clone(), mask.clone()).unwrap(), Renderer::new(&sp, &tracer, cfg.clone(), mask.clone()).unwrap());
    let (a, b) = (ShiftOperator::from_renderer(&ro, &bands).unwrap(), ShiftOperator::from_renderer(&rs, &bands).unwrap());
    assert_eq!(a.placement().0, b.placement().0, "SP's dispersion kept");
    assert!(a.shifts_px().last().unwrap().abs() >= 5, "{:?}", a.shifts_px());
    let x: Vec<f32> = (0..size * size * bands.len()).map(|k| ((k * 7919) % 97) as f32 / 97.0).collect();
    assert_eq!((&a as &dyn Operator).apply(&x).unwrap(), (&b as &dyn Operator).apply(&x).unwrap(), "SP's shift operator");
    // The mask turned by θ between two Coordinate Breaks (tilt_z ±θ) on ddsp's mask surface: beyond 10° the
    // whole-pixel model cannot hold the shear (30° ran with a wrong model, 45° failed as "maps no voxel").
    let turned = |deg: f64| {
        let mut dd = presets::spec("ddsp").unwrap();
        let k = dd.surfaces.iter().position(|s| s.coded_mask.is_some()).unwrap();
        for (z, at) in [(-deg, k + 1), (deg, k)] {
            let mut cb = SurfaceSpec::new(SurfaceKind::CoordinateBreak);
            cb.tilt_z_deg = Some(Cell::fixed(z));
            dd.surfaces.insert(at, cb);
        }
        SequentialSystem::build(&dd).unwrap()
    };
    for deg in [90.0, 45.0, 30.0, 12.0] {
        let sys = turned(deg);
        let r = Renderer::new(&sys, &tracer, cfg.clone(), mask.clone()).unwrap();
        let e = ShiftOperator::from_renderer(&r, &bands).unwrap_err().to_string();
        assert!(e.contains("turned against the scene") && e.contains("beyond 10°") && e.contains("exact or mapping"), "{deg}°: {e}");
    }
    for deg in [5.0, 180.0] {
        let sys = turned(deg);
        let r = Renderer::new(&sys, &tracer, cfg.clone(), mask.clone()).unwrap();
        ShiftOperator::from_renderer(&r, &bands).unwrap_or_else(|e| panic!("{deg}°: {e}"));
    }
}
