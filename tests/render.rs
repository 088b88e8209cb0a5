//! Rendering of coded acquisitions: physics checks (energy, flatness, spot of a bright pixel, 1/N
//! variance), the single-slit validation, determinism (threads, dataset mode, tracer path), scene loaders,
//! and the `render` / `render-dataset` command line. Small sizes so the file runs in seconds.
use diffcassi::analysis::{self, MappingCube};
use diffcassi::prelude::*;
use diffcassi::render::validate::{mean_rows, slit_prediction};
use diffcassi::render::{Acquisition, AiryConfig, Mask, RenderConfig, Renderer, Sampling, SpectralSampling};
use diffcassi::scene::{self, SpectralCube};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The analytic backend (a static so renderers can borrow it anywhere).
static TRACER: AnalyticTracer = AnalyticTracer::with_kernel(diffcassi::tracer::Kernel::Simd(None));

fn system(name: &str) -> SequentialSystem {
    SequentialSystem::build(&presets::spec(name).unwrap()).unwrap()
}

fn config(size: usize, bands: Vec<f64>, oversampling: usize, rays: usize) -> RenderConfig {
    let mut c = RenderConfig::paper(size);
    c.spectral = SpectralSampling::new(bands, oversampling).unwrap();
    c.rays_per_pixel = rays;
    c
}

fn pool(n: usize) -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap()
}

fn quiet(_: u64) {}

/// Mean and standard deviation of `v` at `idx`.
fn stats(v: &[f64], idx: &[usize]) -> (f64, f64) {
    let m = idx.iter().map(|&i| v[i]).sum::<f64>() / idx.len() as f64;
    let s = (idx.iter().map(|&i| (v[i] - m).powi(2)).sum::<f64>() / (idx.len() - 1) as f64).sqrt();
    (m, s)
}

/// Detector pixels within `half` pixels of where scene pixel (row, col) lands at `w` nm (chief ray).
fn core_around(sys: &SequentialSystem, acq: &Acquisition, cfg: &RenderConfig, row: usize, col: usize, w: f64, half: i64) -> Vec<usize> {
    let f = MappingCube::scene_xy(cfg.scene_height, cfg.scene_width, cfg.scene_pitch_mm, row, col);
    let out = AnalyticTracer::default().trace(sys, &RayBatch::chief_rays(sys, &[f], w).unwrap()).unwrap();
    let (u, v) = acq.detector.to_pixel(out.x[0], out.y[0]);
    let (jc, ic) = (u.round() as i64, v.round() as i64);
    let mut idx = Vec::new();
    for i in ic - half..=ic + half {
        for j in jc - half..=jc + half {
            idx.push(i as usize * acq.detector.width + j as usize);
        }
    }
    idx
}

#[test]
fn uniform_white_scene_conserves_energy() {
    // SP, all-open mask: every ray arrives (no aperture clips a 0.24 mm field), so the detector total is
    // the scene's total in band units: bands × pixels × transmission.
    let sys = system("sp");
    let cfg = config(24, vec![480.0, 520.0, 560.0], 2, 8);
    let r = Renderer::new(&sys, &TRACER, cfg, Mask::open(24, 24)).unwrap();
    let scene = SpectralCube::uniform(24, 24, vec![400.0, 700.0], 1.0);
    let acq = r.render(&scene, true, &quiet).unwrap();
    assert_eq!(acq.stats.traced, 24 * 24 * 8 * 6);
    let t = acq.stats.transmission();
    let expected = 3.0 * 576.0 * t;
    println!("SP energy: total {:.6}, expected {expected:.6} (transmission {t})", acq.total());
    assert!(t > 0.999, "transmission {t}");
    assert!((acq.total() / expected - 1.0).abs() < 1e-5, "total {} vs {expected}", acq.total());
    // The bands add up to the acquisition.
    let bands = acq.bands.as_ref().unwrap();
    assert_eq!(bands.len(), 3);
    let sum: f64 = bands.iter().map(|b| b.iter().map(|&v| v as f64).sum::<f64>()).sum();
    assert!((sum / acq.total() - 1.0).abs() < 1e-5);
    // A half-open mask halves the energy (to the mask's exact opening).
    let mask = Mask::random(24, 24, 0.5, 9).unwrap();
    let open = mask.opening();
    let r2 = Renderer::new(&sys, &TRACER, config(24, vec![480.0, 520.0, 560.0], 2, 8), mask).unwrap();
    let half = r2.render(&scene, false, &quiet).unwrap();
    assert!((half.total() / (3.0 * 576.0 * open * half.stats.transmission()) - 1.0).abs() < 1e-5);
    assert!(acq.image.iter().all(|v| v.is_finite() && *v >= 0.0));
}

#[test]
fn uniform_white_scene_is_flat_within_mc_noise() {
    // AP (distortion ≤ 6 µm over the field, so irradiance is uniform to well below the noise), narrow bands
    // so every plane overlaps the core. Two seeds give the Monte-Carlo noise; the image's spatial spread over
    // the core must be that noise, not more.
    let sys = system("ap");
    let n = 48;
    let mut cfg = config(n, vec![515.0, 520.0, 525.0], 1, 16);
    let r = Renderer::new(&sys, &TRACER, cfg.clone(), Mask::open(n, n)).unwrap();
    let scene = SpectralCube::uniform(n, n, vec![500.0, 540.0], 1.0);
    let a = r.render(&scene, false, &quiet).unwrap();
    cfg.seed = 1;
    let r2 = Renderer::new(&sys, &TRACER, cfg.clone(), Mask::open(n, n)).unwrap();
    let b = r2.render(&scene, false, &quiet).unwrap();
    let core = core_around(&sys, &a, &cfg, n / 2, n / 2, 520.0, 14);
    let diff: Vec<f64> = a.image.iter().zip(&b.image).map(|(x, y)| x - y).collect();
    let (_, sd) = stats(&diff, &core);
    let noise = sd / 2f64.sqrt();
    let (mean, spread) = stats(&a.image, &core);
    println!("AP flat field: core mean {mean:.5} (3 bands), spatial std {spread:.5}, MC noise {noise:.5}");
    assert!(noise > 0.0);
    assert!(spread < 1.2 * noise, "spatial std {spread} vs MC noise {noise}");
    assert!((mean / 3.0 - 1.0).abs() < 0.01, "core mean {mean} (expected 3 × 1/|m|², |m| ≈ 1)");
}

#[test]
fn single_bright_pixel_reproduces_the_spot_diagram() {
    // SP's worst field (F4 corner, 2.5 mm): one open pixel, one plane, no Airy, 4000 rays. The detector's
    // centroid must be the spot diagram's (bilinear splatting keeps first moments), and its RMS radius the
    // spot's widened by the pixel's box (var p²/12 per axis) and the bilinear tent (var p²/6 per axis).
    let sys = system("sp");
    let n = 512;
    let (row, col) = (6usize, 505usize);
    let mut cfg = config(n, vec![520.0], 1, 4000);
    cfg.airy = None;
    let mut mask = Mask::open(n, n);
    mask.values.iter_mut().enumerate().for_each(|(q, v)| *v = if q == row * n + col { 1.0 } else { 0.0 });
    let r = Renderer::new(&sys, &TRACER, cfg.clone(), mask).unwrap();
    let scene = SpectralCube::uniform(n, n, vec![520.0], 1.0);
    let acq = r.render(&scene, false, &quiet).unwrap();
    let d = acq.detector;
    let (mut s, mut sx, mut sy) = (0.0, 0.0, 0.0);
    for i in 0..d.height {
        for j in 0..d.width {
            let v = acq.image[i * d.width + j];
            let c = d.pixel_centre_mm(i, j);
            s += v;
            sx += v * c[0];
            sy += v * c[1];
        }
    }
    let (cx, cy) = (sx / s, sy / s);
    let mut s2 = 0.0;
    for i in 0..d.height {
        for j in 0..d.width {
            let c = d.pixel_centre_mm(i, j);
            s2 += acq.image[i * d.width + j] * ((c[0] - cx).powi(2) + (c[1] - cy).powi(2));
        }
    }
    let rms_um = 1e3 * (s2 / s).sqrt();
    let field = MappingCube::scene_xy(n, n, 0.01, row, col);
    let spot = analysis::spot_diagram(&sys, &AnalyticTracer::default(), field, 520.0, &PupilPattern::GridStep { step: 0.02 }.points()).unwrap();
    let st = spot.stats.unwrap();
    let p_um = 10.0;
    let expected_rms = (st.rms_radius_um.powi(2) + 2.0 * p_um * p_um / 12.0 + 2.0 * p_um * p_um / 6.0).sqrt();
    let dc = 1e3 * (cx - st.centroid_mm[0]).hypot(cy - st.centroid_mm[1]);
    println!("SP bright pixel at field ({:.3}, {:.3}) mm: centroid Δ {dc:.3} µm; RMS {rms_um:.3} µm vs spot {:.3} µm ⊕ pixel ⊕ tent = {expected_rms:.3} µm", field[0], field[1], st.rms_radius_um);
    assert!((s - 1.0).abs() < 1e-5, "energy {s}");
    assert!(dc < 0.3, "centroid off by {dc} µm");
    assert!((rms_um / expected_rms - 1.0).abs() < 0.03, "RMS {rms_um} vs {expected_rms}");
}

/// Per-pixel variance across seeds (mean over `core`), for `rays` rays per pixel.
fn seed_variance(sys: &SequentialSystem, sampling: Sampling, rays: usize, seeds: u64) -> f64 {
    let n = 16;
    let mut cfg = config(n, vec![520.0], 1, rays);
    cfg.airy = None;
    cfg.sampling = sampling;
    let scene = SpectralCube::uniform(n, n, vec![520.0], 1.0);
    let mut r = Renderer::new(sys, &TRACER, cfg.clone(), Mask::open(n, n)).unwrap();
    let mut imgs = Vec::new();
    for s in 0..seeds {
        r.config.seed = 1000 + s;
        imgs.push(r.render(&scene, false, &quiet).unwrap());
    }
    let core = core_around(sys, &imgs[0], &cfg, n / 2, n / 2, 520.0, 4);
    let mut v = 0.0;
    for &i in &core {
        let m = imgs.iter().map(|a| a.image[i]).sum::<f64>() / seeds as f64;
        v += imgs.iter().map(|a| (a.image[i] - m).powi(2)).sum::<f64>() / (seeds - 1) as f64;
    }
    v / core.len() as f64
}

#[test]
fn doubling_the_rays_halves_the_variance() {
    let sys = system("ap");
    let (v4, v8) = (seed_variance(&sys, Sampling::Independent, 4, 24), seed_variance(&sys, Sampling::Independent, 8, 24));
    let (s4, s8) = (seed_variance(&sys, Sampling::Stratified, 4, 24), seed_variance(&sys, Sampling::Stratified, 8, 24));
    println!("variance ratio N=4 → 8: independent {:.3}, stratified {:.3} (stratified/independent at N=8: {:.3})", v4 / v8, s4 / s8, s8 / v8);
    // Plain Monte Carlo: exactly 1/N in expectation; 24 seeds × 81 pixels estimate the ratio to ~5 %.
    assert!((v4 / v8 - 2.0).abs() < 0.3, "independent ratio {}", v4 / v8);
    // Stratified sampling does at least as well as 1/N, and beats plain Monte Carlo.
    assert!(s4 / s8 > 1.8, "stratified ratio {}", s4 / s8);
    assert!(s8 < v8);
}

#[test]
fn single_slit_recovers_each_region_spectrum() {
    // The paper's check: SP, a 1-pixel slit at the field centre of a 512×512 scene with three uniform
    // regions (rows 0–169, 170–339, 340–511), 112 planes, 20 rays, Airy on. The mean of 40 detector rows
    // per region is compared with the prediction at 280 wavelengths (10 per band): the chief-ray
    // dispersion and the geometric spot of real rays, the slit pixel's width, the bilinear tent and the
    // Airy line-spread function.
    let sys = system("sp");
    let n = 512;
    let col = n / 2;
    let bands = analysis::linspace(450.0, 650.0, 28);
    let spectra: [fn(f64) -> f64; 3] = [
        |w| 0.2 + 0.7 * (-(w - 480.0f64).powi(2) / (2.0 * 25.0f64.powi(2))).exp(),
        |w| 0.1 + 0.8 * ((w - 450.0) / 200.0),
        |w| 0.5 + 0.4 * (2.0 * std::f64::consts::PI * (w - 450.0) / 100.0).sin(),
    ];
    let regions = [(0usize, 170usize), (170, 340), (340, 512)];
    let mut data = vec![0.0f32; n * n * bands.len()];
    for r in 0..n {
        let k = regions.iter().position(|&(a, b)| r >= a && r < b).unwrap();
        for c in 0..n {
            for (b, &w) in bands.iter().enumerate() {
                data[(r * n + c) * bands.len() + b] = spectra[k](w) as f32;
            }
        }
    }
    let scene = SpectralCube::new(n, n, bands.clone(), data, "slit scene").unwrap();
    let mut cfg = config(n, bands.clone(), 4, 20);
    let render = |seed: u64, cfg: &mut RenderConfig| {
        cfg.seed = seed;
        let r = Renderer::new(&sys, &TRACER, cfg.clone(), Mask::slit(n, n, col)).unwrap();
        let a = r.render(&scene, false, &quiet).unwrap();
        (r.detector, a)
    };
    let (det, a) = render(0, &mut cfg);
    let (_, b) = render(1, &mut cfg);
    let tracer = AnalyticTracer::default();
    let mut worst: f64 = 0.0;
    for (k, &(r0, r1)) in regions.iter().enumerate() {
        let mid = (r0 + r1) / 2;
        let rows: Vec<usize> = (mid - 20..mid + 20).collect();
        // Detector rows of those scene rows (SP inverts the image): the slit's chief ray at 550 nm.
        let fields: Vec<[f64; 2]> = rows.iter().map(|&r| MappingCube::scene_xy(n, n, 0.01, r, col)).collect();
        let out = tracer.trace(&sys, &RayBatch::chief_rays(&sys, &fields, 550.0).unwrap()).unwrap();
        let det_rows: Vec<usize> = (0..rows.len()).map(|i| det.to_pixel(out.x[i], out.y[i]).1.round() as usize).collect();
        let got = mean_rows(&a.image, &det, &det_rows);
        let other = mean_rows(&b.image, &det, &det_rows);
        // Every 4th row, centred on the 40 (smile makes x depend on the row: the sample must not be lopsided).
        let sampled: Vec<usize> = rows.iter().copied().skip(2).step_by(4).collect();
        // Ground truth: the region's 28 band values upsampled linearly to 280 wavelengths (the scene holds
        // only the band samples; the renderer interpolates the same way).
        let samples: Vec<f32> = bands.iter().map(|&w| spectra[k](w) as f32).collect();
        let truth = SpectralCube::new(1, 1, bands.clone(), samples, "region").unwrap();
        let spectrum = |w: f64| truth.plane(w)[0] as f64;
        let pred = slit_prediction(&sys, &tracer, &cfg, &det, col, &sampled, &spectrum, 10).unwrap();
        // Prediction at the render's own 112 planes: the difference measures the plane discretisation.
        let pred_planes = slit_prediction(&sys, &tracer, &cfg, &det, col, &sampled, &spectrum, 4).unwrap();
        let peak = pred.iter().cloned().fold(0.0, f64::max);
        let cols: Vec<usize> = (0..det.width).filter(|&j| pred[j] > 0.01 * peak || got[j] > 0.01 * peak).collect();
        let rms = |x: &[f64], y: &[f64]| (cols.iter().map(|&j| (x[j] - y[j]).powi(2)).sum::<f64>() / cols.len() as f64).sqrt();
        let err = rms(&got, &pred);
        let noise = rms(&got, &other) / 2f64.sqrt();
        let disc = rms(&pred_planes, &pred);
        // Bound: three times the measured Monte-Carlo noise of the 40-row mean (two seeds), plus the
        // measured plane discretisation (prediction at the 112 planes vs at 280 wavelengths), plus 0.2 % of
        // the peak for the prediction's own quadrature (13×13 pupil grid, 3×3 sub-pixel points, every 4th
        // row). Measured: errors of 0.2–0.3 % of the peak, within 1–1.4× the noise.
        let bound = 3.0 * noise + disc + 0.002 * peak;
        println!(
            "slit region {k}: RMS error {err:.4} ({:.2} % of peak {peak:.3}); MC noise {noise:.4}, plane discretisation {disc:.4}; bound {bound:.4}; {} columns",
            100.0 * err / peak,
            cols.len()
        );
        // Recovered spectrum: map each column back to λ through the dispersion curve, compare at the bands.
        if std::env::var("SLIT_DEBUG").is_ok() {
            for &j in &cols {
                println!("  col {j}: got {:.5} pred {:.5} planes {:.5} other {:.5}", got[j], pred[j], pred_planes[j], other[j]);
            }
        }
        assert!(err <= bound, "region {k}: RMS {err} > bound {bound}");
        worst = worst.max(err / peak);
    }
    println!("slit: worst RMS error {:.2} % of the peak", 100.0 * worst);
}

#[test]
fn same_seed_is_bit_identical_across_threads_dataset_mode_and_tracer_path() {
    let sys = system("msp");
    let n = 20;
    let cfg = config(n, vec![470.0, 520.0, 600.0], 2, 6);
    let tracer = AnalyticTracer::default();
    let mask = Mask::random(n, n, 0.5, 4).unwrap();
    let r = Renderer::new(&sys, &tracer, cfg.clone(), mask.clone()).unwrap();
    let scene = scene::synthetic_scene(n, n, &scene::synthetic_wavelengths(), 3);
    let one = pool(1).install(|| r.render(&scene, true, &quiet)).unwrap();
    let two = pool(2).install(|| r.render(&scene, true, &quiet)).unwrap();
    assert_eq!(one.image, two.image);
    assert_eq!(one.bands, two.bands);
    // Dataset mode: the transport traced once (on 2 threads) and applied, equals the per-scene render.
    let transport = pool(2).install(|| r.trace_all(&quiet)).unwrap();
    let cached = pool(1).install(|| r.render_cached(&scene, &transport, true, &quiet)).unwrap();
    assert_eq!(cached.image, one.image);
    let scene2 = scene::synthetic_scene(n, n, &scene::synthetic_wavelengths(), 4);
    assert_eq!(r.render_cached(&scene2, &transport, false, &quiet).unwrap().image, r.render(&scene2, false, &quiet).unwrap().image);
    // Going through the Tracer trait in batches gives the same numbers as the direct kernel.
    let mut cb = cfg.clone();
    cb.force_batched = true;
    let rb = Renderer::new(&sys, &tracer, cb, mask).unwrap();
    assert_eq!(rb.render(&scene, false, &quiet).unwrap().image, one.image);
    // Another seed changes the image.
    let mut c2 = cfg;
    c2.seed = 1;
    let r2 = Renderer::new(&sys, &tracer, c2, Mask::random(n, n, 0.5, 4).unwrap()).unwrap();
    assert_ne!(r2.render(&scene, false, &quiet).unwrap().image, one.image);
}

/// The SIMD render equals the scalar-kernel render: the kernels agree to ≤ 1e-12 mm (in fact bit for bit),
/// so every footprint has the same window and the acquisitions agree to f32 rounding — at every dispatch
/// level (lane width) this CPU has, and on 1 or 2 threads.
#[test]
fn simd_render_equals_the_scalar_render() {
    for name in ["sp", "map"] {
        let sys = system(name);
        let n = 12;
        let mut cfg = config(n, vec![470.0, 560.0, 640.0], 2, 6);
        cfg.kernel = diffcassi::tracer::Kernel::Scalar;
        let mask = Mask::random(n, n, 0.6, 2).unwrap();
        let scene = scene::synthetic_scene(n, n, &scene::synthetic_wavelengths(), 5);
        let scalar = Renderer::new(&sys, &TRACER, cfg.clone(), mask.clone()).unwrap();
        let want = pool(1).install(|| scalar.render(&scene, false, &quiet)).unwrap();
        let want_t = scalar.trace_plane(3).unwrap();
        assert!(want.stats.arrived > 0 && want.total() > 0.0);
        for level in diffcassi::tracer::SimdLevel::available() {
            let mut c = cfg.clone();
            c.kernel = diffcassi::tracer::Kernel::Simd(Some(level));
            let r = Renderer::new(&sys, &TRACER, c, mask.clone()).unwrap();
            let got = pool(2).install(|| r.render(&scene, false, &quiet)).unwrap();
            assert_eq!(got.stats, want.stats, "{name} {level:?}: ray counts");
            let peak = want.image.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            for (a, b) in got.image.iter().zip(&want.image) {
                assert!((a - b).abs() <= 1e-6 * peak, "{name} {level:?}: {a} vs {b}");
            }
            let t = r.trace_plane(3).unwrap();
            assert_eq!(t.footprints, want_t.footprints, "{name} {level:?}: footprint windows");
            for (a, b) in t.weights.iter().zip(&want_t.weights) {
                assert!((a - b).abs() <= 1e-6 * b.abs().max(1e-6), "{name} {level:?}: weight {a} vs {b}");
            }
        }
    }
}

// ---------------------------------------------------------------- loaders

fn tmpdir() -> tempfile::TempDir {
    tempfile::tempdir().unwrap()
}

fn test_cube() -> SpectralCube {
    let ws = vec![450.0, 500.0, 550.5, 600.0, 650.0];
    scene::synthetic_scene(9, 13, &ws, 11)
}

#[test]
fn exr_png_npy_scenes_round_trip() {
    let d = tmpdir();
    let cube = test_cube();
    let exr = d.path().join("scene.exr");
    scene::save_exr(&cube, &exr).unwrap();
    assert_eq!(scene::load_scene(&exr, None).unwrap(), cube);
    let npy = d.path().join("scene.npy");
    scene::save_npy(&cube, &npy).unwrap();
    assert_eq!(scene::load_scene(&npy, None).unwrap(), cube);
    let png = d.path().join("pngs");
    scene::save_png_stack(&cube, &png).unwrap();
    let back = scene::load_scene(&png, None).unwrap();
    assert_eq!(back.wavelengths_nm, cube.wavelengths_nm);
    assert!(back.data.iter().zip(&cube.data).all(|(a, b)| (a - b).abs() <= 0.5 / 65535.0 + 1e-7));
    // CAVE convention: 31 unnamed bands are 400–700 nm.
    let cave = d.path().join("cave");
    std::fs::create_dir_all(&cave).unwrap();
    for k in 1..=31 {
        diffcassi::io::png16::write_png_gray16(cave.join(format!("balloons_ms_{k:02}.png")), 4, 3, &[k as u16 * 1000; 12]).unwrap();
    }
    let c = scene::load_scene(&cave, None).unwrap();
    assert_eq!(c.wavelengths_nm[0], 400.0);
    assert_eq!(c.wavelengths_nm[30], 700.0);
    assert!((c.at(2, 3, 30) - 31000.0 / 65535.0).abs() < 1e-6);
}

#[test]
fn bad_scene_files_give_clear_errors() {
    let d = tmpdir();
    let cube = test_cube();
    // Truncated EXR.
    let exr = d.path().join("cut.exr");
    scene::save_exr(&cube, &exr).unwrap();
    let bytes = std::fs::read(&exr).unwrap();
    std::fs::write(&exr, &bytes[..bytes.len() / 2]).unwrap();
    let e = scene::load_scene(&exr, None).unwrap_err().to_string();
    assert!(e.contains("cut.exr") && e.contains("OpenEXR"), "{e}");
    // An EXR whose channels carry no wavelength.
    let rgb = d.path().join("rgb.exr");
    let ch = |n: &str| diffcassi::io::exr::ExrChannel { name: n.into(), data: vec![0.5; 4] };
    diffcassi::io::exr::write_exr(&rgb, 2, 2, &[ch("R"), ch("G"), ch("B")]).unwrap();
    let e = scene::load_scene(&rgb, None).unwrap_err().to_string();
    assert!(e.contains("rgb.exr") && e.contains("`B`") && e.contains("wavelength"), "{e}");
    assert_eq!(scene::load_scene(&rgb, Some(&[450.0, 550.0, 650.0])).unwrap().bands(), 3);
    assert!(scene::load_scene(&rgb, Some(&[450.0, 550.0])).unwrap_err().to_string().contains("2 wavelengths given for 3 bands"));
    // PNG stack with one band of another size.
    let png = d.path().join("pngs");
    scene::save_png_stack(&cube, &png).unwrap();
    diffcassi::io::png16::write_png_gray16(png.join("band_04_650nm.png"), 5, 5, &[0; 25]).unwrap();
    let e = scene::load_scene(&png, None).unwrap_err().to_string();
    assert!(e.contains("band_04_650nm.png") && e.contains("5×5") && e.contains("13×9"), "{e}");
    // Truncated PNG.
    let bytes = std::fs::read(png.join("band_00_450nm.png")).unwrap();
    std::fs::write(png.join("band_00_450nm.png"), &bytes[..bytes.len() / 2]).unwrap();
    let e = scene::load_scene(&png, None).unwrap_err().to_string();
    assert!(e.contains("band_00_450nm.png"), "{e}");
    // NPY whose wavelength list does not match its bands, and a truncated NPY.
    let npy = d.path().join("cube.npy");
    scene::save_npy(&cube, &npy).unwrap();
    diffcassi::io::write_npy_f64(d.path().join("cube_wavelengths_nm.npy"), &[4], &[1.0, 2.0, 3.0, 4.0]).unwrap();
    let e = scene::load_scene(&npy, None).unwrap_err().to_string();
    assert!(e.contains("cube_wavelengths_nm.npy") && e.contains("4 wavelengths") && e.contains("5 bands"), "{e}");
    let bytes = std::fs::read(&npy).unwrap();
    std::fs::write(&npy, &bytes[..bytes.len() - 10]).unwrap();
    let e = scene::load_scene(&npy, None).unwrap_err().to_string();
    assert!(e.contains("cube.npy"), "{e}");
    // Unknown format, missing file.
    assert!(scene::load_scene(&d.path().join("x.tif"), None).unwrap_err().to_string().contains("x.tif"));
    // A mask of the wrong size is refused by the renderer.
    let sys = system("ap");
    let e = Renderer::new(&sys, &TRACER, config(8, vec![520.0], 1, 2), Mask::open(8, 9)).err().unwrap().to_string();
    assert!(e.contains("8×9") && e.contains("8×8"), "{e}");
}

// ---------------------------------------------------------------- command line

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_diffcassi"))
}

fn run(args: &[&str]) -> Output {
    bin().args(args).output().expect("the binary runs")
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

fn exr_values(path: &Path) -> Vec<f32> {
    diffcassi::io::exr::read_exr(path).unwrap().channels.remove(0).data
}

#[test]
fn cli_render_writes_the_interface_files() {
    let d = tmpdir();
    let out = d.path().join("r");
    let o = run(&["render", "--preset", "sp", "--synthetic", "5", "--scene-size", "32", "--planes", "8", "--rays", "3", "--cube", "--out", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for f in ["acquisition.exr", "acquisition.png", "render.json", "cube.exr", "mask.png", "mapping.npy", "mapping_valid.npy"] {
        assert!(out.join(f).is_file(), "{f}");
    }
    let j = json(&out.join("render.json"));
    for k in ["rays_traced", "seconds_total", "threads", "seed", "planes", "rays_per_pixel", "scene_size"] {
        assert!(j.get(k).is_some(), "{k} missing");
    }
    assert_eq!(j["planes"], 8);
    assert_eq!(j["rays_per_pixel"], 3);
    assert_eq!(j["scene_size"], 32);
    let open = j["mask_opening"].as_f64().unwrap();
    assert_eq!(j["rays_traced"].as_u64().unwrap(), (open * 1024.0).round() as u64 * 3 * 8);
    let img = diffcassi::io::exr::read_exr(out.join("acquisition.exr")).unwrap();
    assert_eq!((img.width as u64, img.height as u64), (j["detector"]["width"].as_u64().unwrap(), j["detector"]["height"].as_u64().unwrap()));
    let cube = diffcassi::io::exr::read_exr(out.join("cube.exr")).unwrap();
    assert_eq!(cube.channels.len(), 28);
    assert!(cube.channels.windows(2).all(|w| w[0].name < w[1].name));
    // Same arguments with --threads 1: bit-identical acquisition.
    let out1 = d.path().join("r1");
    let o = run(&["--threads", "1", "render", "--preset", "sp", "--synthetic", "5", "--scene-size", "32", "--planes", "8", "--rays", "3", "--no-mapping", "--out", out1.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(exr_values(&out.join("acquisition.exr")), exr_values(&out1.join("acquisition.exr")));
    assert_eq!(json(&out1.join("render.json"))["threads"], 1);
}

/// `render --backend embree-user` (f64-refined hits) renders the same acquisition as the analytic tracer,
/// through the batched `Tracer` path; `--backend embree-mesh --refine none` differs, but only slightly.
#[cfg(feature = "embree")]
#[test]
fn cli_render_backends_agree() {
    let d = tmpdir();
    let args = |out: &Path, extra: &[&str]| {
        let mut v: Vec<String> = ["render", "--preset", "sp", "--synthetic", "2", "--scene-size", "24", "--planes", "6", "--rays", "3", "--no-mapping", "--out"].iter().map(|s| s.to_string()).collect();
        v.push(out.to_str().unwrap().into());
        v.extend(extra.iter().map(|s| s.to_string()));
        v
    };
    let (a, e, m) = (d.path().join("a"), d.path().join("e"), d.path().join("m"));
    for (out, extra) in [(&a, &[][..]), (&e, &["--backend", "embree-user"][..]), (&m, &["--backend", "embree-mesh", "--mesh-max-sag-um", "10", "--refine", "none"][..])] {
        let o = bin().args(args(out, extra)).output().unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    assert_eq!(json(&e.join("render.json"))["tracer"], "embree-user,refine=f64");
    let (va, ve, vm) = (exr_values(&a.join("acquisition.exr")), exr_values(&e.join("acquisition.exr")), exr_values(&m.join("acquisition.exr")));
    let max = va.iter().cloned().fold(0f32, f32::max);
    let worst = |v: &[f32]| va.iter().zip(v).map(|(x, y)| (x - y).abs()).fold(0f32, f32::max) / max;
    assert!(worst(&ve) < 1e-5, "embree-user f64 vs analytic: {}", worst(&ve));
    let wm = worst(&vm);
    assert!(wm > 0.0 && wm < 0.05, "embree-mesh 10 µm unrefined vs analytic: {wm}");
}

#[test]
fn cli_render_dataset_matches_per_scene_renders_and_skips_complete_scenes() {
    let d = tmpdir();
    let scenes = d.path().join("scenes");
    std::fs::create_dir_all(&scenes).unwrap();
    let ws = scene::synthetic_wavelengths();
    scene::save_npy(&scene::synthetic_scene(40, 40, &ws, 1), &scenes.join("a.npy")).unwrap();
    scene::save_exr(&scene::synthetic_scene(36, 36, &ws, 2), &scenes.join("b.exr")).unwrap();
    let out = d.path().join("ds");
    let common = ["--preset", "ap", "--scene-size", "24", "--planes", "6", "--bands", "460:640:3", "--rays", "3", "--seed", "7"];
    let mut args = vec!["render-dataset", "--scenes", scenes.to_str().unwrap(), "--out", out.to_str().unwrap()];
    args.extend(common);
    let o = run(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(String::from_utf8_lossy(&o.stderr).contains("light transport traced"));
    // stdout is JSON Lines only: one line per scene.
    let lines: Vec<serde_json::Value> = String::from_utf8_lossy(&o.stdout).lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(lines.iter().map(|l| (l["scene"].as_str().unwrap(), l["status"].as_str().unwrap())).collect::<Vec<_>>(), [("a", "rendered"), ("b", "rendered")]);
    for s in ["a", "b"] {
        let single = d.path().join(format!("single-{s}"));
        let file = scenes.join(if s == "a" { "a.npy" } else { "b.exr" });
        let mut a2 = vec!["render", "--scene", file.to_str().unwrap(), "--no-mapping", "--out", single.to_str().unwrap()];
        a2.extend(common);
        let o = run(&a2);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        assert_eq!(exr_values(&out.join(s).join("acquisition.exr")), exr_values(&single.join("acquisition.exr")), "scene {s}");
        assert_eq!(json(&out.join(s).join("render.json"))["seed"], 7);
    }
    // Second run: everything complete, nothing rendered.
    let o = run(&args);
    assert!(o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("0 to render, 2 complete (skipped)"), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(String::from_utf8_lossy(&o.stdout).matches("\"status\":\"skipped\"").count(), 2);
}

/// `bench-render --parts mapping`: the kernels' exact cubes side by side, and the interpolated row.
#[test]
fn cli_bench_render_mapping_rows() {
    let o = run(&["bench-render", "--preset", "sp", "--scene-size", "48", "--planes", "3", "--parts", "mapping", "--kernels", "simd,scalar"]);
    let t = String::from_utf8_lossy(&o.stdout).to_string();
    assert!(o.status.success(), "{t}{}", String::from_utf8_lossy(&o.stderr));
    assert!(t.contains("| mapping cube 48×48×3, simd-") && t.contains("scalar kernel f64; max |Δ| vs simd-") && t.contains("0.0e0 mm"), "{t}");
    // The interpolated row: a stride, its error over every entry within the default 1e-3 µm, and CPU seconds.
    let row = t.lines().find(|l| l.contains("interpolated, stride")).unwrap_or_else(|| panic!("{t}"));
    let err: f64 = row.split("max error vs exact ").nth(1).unwrap().split(' ').next().unwrap().parse().unwrap();
    assert!(err <= 1e-3, "{row}");
    let cols: Vec<&str> = row.split('|').map(str::trim).collect();
    assert!(cols[2].parse::<f64>().is_ok() && cols[3].parse::<f64>().is_ok(), "wall and CPU seconds: {row}");
    assert!(t.contains("stride 2 ") && t.contains("stride 32 "), "{t}");
}

/// `render --kernel scalar` (the reference kept for benchmarking) and the default SIMD kernel write the
/// same acquisition up to f32 rounding, and render.json names the kernel and keeps its timing keys.
#[test]
fn cli_render_kernel_switch() {
    let d = tmpdir();
    let mut images = Vec::new();
    for k in ["scalar", "simd"] {
        let out = d.path().join(k);
        let o = run(&["render", "--preset", "sp", "--scene-size", "16", "--planes", "4", "--rays", "4", "--no-mapping", "--kernel", k, "--out", out.to_str().unwrap()]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let j = json(&out.join("render.json"));
        assert!(j["kernel"].as_str().unwrap().starts_with(k), "{}", j["kernel"]);
        for key in ["seconds_render", "seconds_total", "rays_traced"] {
            assert!(j.get(key).is_some(), "{key} missing");
        }
        images.push(diffcassi::io::exr::read_exr(out.join("acquisition.exr")).unwrap());
    }
    let (a, b) = (&images[0].channels[0].data, &images[1].channels[0].data);
    let peak = a.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    assert!(peak > 0.0);
    assert!(a.iter().zip(b).all(|(x, y)| (x - y).abs() <= 1e-6 * peak));
}

#[test]
fn cli_render_bad_input_is_a_clear_error() {
    let d = tmpdir();
    let out = d.path().join("x");
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (vec!["render", "--preset", "sp", "--scene", "/nonexistent/scene.exr"], "/nonexistent/scene.exr"),
        (vec!["render", "--preset", "sp", "--planes", "0"], "plane"),
        (vec!["render", "--preset", "sp", "--opening", "1.5", "--scene-size", "8"], "opening"),
        (vec!["render", "--preset", "sp", "--sampling", "sobol"], "sobol"),
        (vec!["render", "--preset", "sp", "--kernel", "vector"], "vector"),
        (vec!["render", "--preset", "nope"], "nope"),
        (vec!["render-dataset", "--preset", "sp", "--scenes", "/nonexistent"], "/nonexistent"),
    ];
    for (mut args, needle) in cases {
        // A fresh --out in the test's own folder (never a shared path such as /tmp/x, which may hold files).
        args.extend(["--out", out.to_str().unwrap()]);
        let o = run(&args);
        assert_eq!(o.status.code(), Some(1), "{args:?}");
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(e.contains(needle), "{args:?}: {e}");
        assert!(!e.contains("panicked"), "{e}");
    }
    let _ = PathBuf::new();
    let _ = AiryConfig::default();
}
