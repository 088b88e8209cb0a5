//! The GPU render (issue 41, item 1's accumulation): a whole acquisition through the device's kernels, run on
//! the host (their CPU twin, `render::device::Executor::Twin`). It must equal
//! - an f64 reference computed here from the landing kernel's rays (render::twin::plane_landings, itself the
//!   CPU renderer's landings bit for bit, tests/gpu_twin.rs) within 1e-9 of the peak — the accumulation's
//!   fixed-point rounding is ≈ 1e-13 of the peak;
//! - the CPU renderer within the CPU's own f32 rounding (its footprint weights, plane images and Airy blur
//!   are f32; measured here, bound below);
//! - itself bit for bit on any thread count (integer accumulation: the device's atomics give these bits).
use diffcassi::presets;
use diffcassi::render::device::{plan, render_for, render_on, Executor};
use diffcassi::render::twin::plane_landings_of;
use diffcassi::render::{Device, Mask, RenderConfig, Renderer, SpectralSampling};
use diffcassi::scene::SpectralCube;
use diffcassi::system::SequentialSystem;
use diffcassi::tracer::{AnalyticTracer, Precision};

fn system(name: &str) -> SequentialSystem {
    SequentialSystem::build(&presets::spec(name).unwrap()).unwrap()
}

const H: usize = 20;
const W: usize = 24;

fn config(airy: bool) -> RenderConfig {
    config_in(airy, Precision::F64)
}

fn config_in(airy: bool, precision: Precision) -> RenderConfig {
    let mut c = RenderConfig::paper(W);
    c.precision = precision;
    c.scene_height = H;
    c.scene_pitch_mm = 0.15; // the scene spans much of the field
    c.rays_per_pixel = 5;
    c.seed = 11;
    c.spectral = SpectralSampling::new(vec![450.0, 520.0, 580.0, 650.0], 2).unwrap();
    if !airy {
        c.airy = None;
    }
    c
}

/// A scene with structure in space and wavelength (values in [0.05, 1.05]), 5 bands over 440–660 nm.
fn scene() -> SpectralCube {
    let ws = vec![440.0, 495.0, 550.0, 605.0, 660.0];
    let mut data = Vec::with_capacity(H * W * ws.len());
    for r in 0..H {
        for c in 0..W {
            for b in 0..ws.len() {
                let v = 0.55 + 0.5 * ((r as f64 * 0.7 + b as f64 * 1.3).sin() * (c as f64 * 0.45 - b as f64 * 0.4).cos());
                data.push(v as f32);
            }
        }
    }
    SpectralCube::new(H, W, ws, data, "test scene").unwrap()
}

fn peak(v: &[f64]) -> f64 {
    v.iter().fold(0.0f64, |m, x| m.max(x.abs()))
}

/// The acquisition in f64 from the landing kernel's rays: Σ value·tap·t/N per plane (t: a ray's coded-mask
/// transmission where it crossed the mask surface, 1 without one), the plane's Airy kernel (AiryKernel's taps,
/// zero outside), × w (× the gratings' efficiency) into its band, the bands summed — the device's model with no
/// fixed point.
fn f64_reference(r: &Renderer<'_>, scene: &SpectralCube) -> Vec<f64> {
    let ctx = r.plane_context();
    let plane_weight = r.config.spectral.plane_weight * r.system.grating_efficiency();
    let det = r.detector;
    let (dw, dh) = (det.width, det.height);
    let sp = &r.config.spectral;
    let object_mask = r.object_mask();
    let pixels: Vec<u32> = (0..H * W).filter(|&q| object_mask[q] > 0.0).map(|q| q as u32).collect();
    let n = r.config.rays_per_pixel;
    let sb = scene.bands();
    let mut bands = vec![vec![0.0f64; dw * dh]; sp.bands_nm.len()];
    for p in 0..sp.planes() {
        let land = plane_landings_of(&ctx, p as u64, sp.planes_nm[p], &pixels).unwrap();
        let (k, tw) = scene.interpolation(sp.planes_nm[p]);
        let k1 = (k + 1).min(sb - 1);
        let tw = tw as f32;
        let mut img = vec![0.0f64; dw * dh];
        for (i, &q) in pixels.iter().enumerate() {
            let q = q as usize;
            let value = ((1.0 - tw) * scene.data[q * sb + k] + tw * scene.data[q * sb + k1]) * object_mask[q];
            for t in i * n..(i + 1) * n {
                let (u, v) = (land.u[t], land.v[t]);
                let transmission = land.weight.get(t).copied().unwrap_or(1.0);
                if u.is_nan() || transmission == 0.0 {
                    continue;
                }
                let (fj, fi) = (u.floor(), v.floor());
                let (fu, fv) = (u - fj, v - fi);
                for (di, wi) in [(0i64, 1.0 - fv), (1, fv)] {
                    for (dj, wj) in [(0i64, 1.0 - fu), (1, fu)] {
                        let (row, col) = (fi as i64 + di, fj as i64 + dj);
                        if row >= 0 && col >= 0 && (row as usize) < dh && (col as usize) < dw {
                            img[row as usize * dw + col as usize] += value as f64 * wi * wj * transmission / n as f64;
                        }
                    }
                }
            }
        }
        let band = &mut bands[sp.plane_band[p]];
        match &r.kernels[p] {
            None => band.iter_mut().zip(&img).for_each(|(b, v)| *b += plane_weight * v),
            Some(a) => {
                let (h, m) = (a.half as i64, 2 * a.half + 1);
                for y in 0..dh as i64 {
                    for x in 0..dw as i64 {
                        let mut acc = 0.0;
                        for ki in 0..m as i64 {
                            for kj in 0..m as i64 {
                                let (sy, sx) = (y - (ki - h), x - (kj - h));
                                if sy >= 0 && sx >= 0 && sy < dh as i64 && sx < dw as i64 {
                                    acc += a.weights[(ki * m as i64 + kj) as usize] as f64 * img[(sy * dw as i64 + sx) as usize];
                                }
                            }
                        }
                        band[(y * dw as i64 + x) as usize] += plane_weight * acc;
                    }
                }
            }
        }
    }
    (0..dw * dh).map(|i| bands.iter().map(|b| b[i]).sum()).collect()
}

#[test]
fn the_twin_render_equals_the_f64_model_within_1e9_of_the_peak() {
    let scene = scene();
    for (name, airy, precision) in [("sp", true, Precision::F64), ("sp", false, Precision::F64), ("msp", true, Precision::F64), ("msp", false, Precision::F64), ("sp", true, Precision::F32), ("msp", true, Precision::F32)] {
        {
            let sys = system(name);
            let tracer = AnalyticTracer::default();
            let r = Renderer::new(&sys, &tracer, config_in(airy, precision), Mask::random(H, W, 0.6, 5).unwrap()).unwrap();
            let (acq, rec) = render_on(&r, &scene, false, Executor::Twin).unwrap();
            assert_eq!((rec.device.as_str(), rec.precision.as_str()), ("cpu-twin", precision.name()));
            let reference = f64_reference(&r, &scene);
            let pk = peak(&reference);
            assert!(pk > 1e-3, "{name}: an empty acquisition ({pk})");
            let worst = acq.image.iter().zip(&reference).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
            eprintln!("{name} airy={airy} {precision}: |twin − f64 model| = {:.2e} of the peak", worst / pk);
            assert!(worst <= 1e-9 * pk, "{name} airy={airy} {precision}: |twin − f64 model| = {worst:e} of a peak {pk}");
        }
    }
}

#[test]
fn the_twin_render_equals_the_cpu_render_to_its_f32_rounding() {
    let scene = scene();
    // f32: the same rays (the f32 landing kernel is the renderer's f32 lanes bit for bit, tests/gpu_twin.rs).
    for (name, precision) in [("sp", Precision::F64), ("msp", Precision::F64), ("sp", Precision::F32)] {
        let sys = system(name);
        let tracer = AnalyticTracer::default();
        let r = Renderer::new(&sys, &tracer, config_in(true, precision), Mask::random(H, W, 0.6, 5).unwrap()).unwrap();
        let (twin, _) = render_on(&r, &scene, true, Executor::Twin).unwrap();
        let cpu = r.render(&scene, true, &|_| {}).unwrap();
        let pk = peak(&cpu.image);
        let worst = twin.image.iter().zip(&cpu.image).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        // The CPU rounds each footprint weight, plane image and blurred tile to f32 (2⁻²⁴ ≈ 6e-8 relative each,
        // over ~10 chained sums per pixel and 8 planes): measured 1.25e-7 of the peak; 1e-6 bounds it.
        eprintln!("{name} {precision}: |twin − cpu| = {:.2e} of the peak", worst / pk);
        assert!(worst <= 1e-6 * pk, "{name}: |twin − cpu| = {worst:e} of a peak {pk}");
        assert!(worst > 0.0, "{name}: the f64 accumulation should differ from the f32 one somewhere");
        // Ray counts are integers and identical; the off-detector weight is the same sum in another rounding.
        let (a, b) = (twin.stats, cpu.stats);
        assert_eq!((a.traced, a.arrived, a.missed, a.vignetted, a.tir, a.no_convergence, a.invalid_input, a.out_of_range), (b.traced, b.arrived, b.missed, b.vignetted, b.tir, b.no_convergence, b.invalid_input, b.out_of_range), "{name}");
        assert!((a.off_detector - b.off_detector).abs() <= 1e-6 * (a.traced as f64), "{name}: off-detector {} vs {}", a.off_detector, b.off_detector);
        // The band images are kept, and the acquisition is their sum (in f64, before their f32 rounding).
        let bands = twin.bands.as_ref().unwrap();
        assert_eq!(bands.len(), 4);
        for (i, v) in twin.image.iter().enumerate() {
            let s: f64 = bands.iter().map(|b| b[i] as f64).sum();
            assert!((s - v).abs() <= 1e-6 * pk, "{name}: pixel {i}: Σ bands {s} vs {v}");
        }
    }
}

/// The whole acquisition of `sys` (its scene `fov_deg` wide for an object at infinity) through the twin, in f64
/// and f32: within 1e-9 of the f64 model of its landings, within the CPU's f32 rounding of the CPU render (the
/// bound above), the same ray counts, some rays arrived.
fn assert_twin_render_matches(name: &str, sys: &SequentialSystem, fov_deg: Option<f64>, scene: &SpectralCube) {
    assert_twin_render_matches_with(name, sys, scene, &Mask::random(H, W, 0.6, 5).unwrap(), &[Precision::F64, Precision::F32], &|c| c.scene_fov_deg = fov_deg);
}

/// [`assert_twin_render_matches`] with `mask`, in `precisions`, the settings of [`config_in`] changed by `configure`.
fn assert_twin_render_matches_with(name: &str, sys: &SequentialSystem, scene: &SpectralCube, mask: &Mask, precisions: &[Precision], configure: &dyn Fn(&mut RenderConfig)) {
    let tracer = AnalyticTracer::default();
    for &precision in precisions {
        let mut c = config_in(true, precision);
        configure(&mut c);
        let r = Renderer::new(sys, &tracer, c, mask.clone()).unwrap_or_else(|e| panic!("{name}: {e}"));
        let (twin, _) = render_on(&r, scene, false, Executor::Twin).unwrap_or_else(|e| panic!("{name}: {e}"));
        let reference = f64_reference(&r, scene);
        let pk = peak(&reference);
        assert!(pk > 1e-3, "{name} {precision}: an empty acquisition ({pk})");
        let model = twin.image.iter().zip(&reference).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        let cpu = r.render(scene, false, &|_| {}).unwrap();
        let worst = twin.image.iter().zip(&cpu.image).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        eprintln!("{name} {precision}: |twin − f64 model| = {:.2e}, |twin − cpu| = {:.2e} of the peak", model / pk, worst / peak(&cpu.image));
        assert!(model <= 1e-9 * pk, "{name} {precision}: |twin − f64 model| = {model:e} of a peak {pk}");
        assert!(worst <= 1e-6 * peak(&cpu.image), "{name} {precision}: |twin − cpu| = {worst:e} of a peak {}", peak(&cpu.image));
        let (a, b) = (twin.stats, cpu.stats);
        assert_eq!((a.traced, a.arrived, a.missed, a.vignetted, a.tir, a.no_convergence, a.invalid_input, a.out_of_range, a.evanescent, a.masked), (b.traced, b.arrived, b.missed, b.vignetted, b.tir, b.no_convergence, b.invalid_input, b.out_of_range, b.evanescent, b.masked), "{name} {precision}");
        assert!(a.arrived > 0, "{name} {precision}");
    }
}

/// The whole acquisition of the dual-disperser presets through the twin (the coded mask on a surface inside the
/// system: every scene pixel traced, each ray weighted by the mask's transmission where it crosses that surface,
/// `dc_mask_transmission`), `ddsp` and `mddsp`, nearest and bilinear, a graded mask with closed pixels, each as
/// [`assert_twin_render_matches`] in f64 (the CPU renderer refuses f32 there) with the rays the mask blocks counted
/// alike; a mask surface outside the beam is refused with the CPU renderer's error before any device work (the
/// device renders a `Renderer`, which checks it).
#[test]
fn the_twin_render_models_a_coded_mask_on_a_surface() {
    let scene = scene();
    for (name, sys) in [("ddsp", "ddsp"), ("mddsp", "mddsp")] {
        for sampling in [diffcassi::spec::MaskSampling::Nearest, diffcassi::spec::MaskSampling::Bilinear] {
            let sys = crate::gpu_twin::dual_disperser(sys, sampling);
            // The scene at the mask's pitch (10 µm), so that its image on the mask covers the mask's pixels.
            assert_twin_render_matches_with(&format!("{name} {sampling:?}"), &sys, &scene, &crate::gpu_twin::graded_mask(H, W, 5), &[Precision::F64], &|c| c.scene_pitch_mm = 0.01);
        }
    }
    // The mask surface decentred 30 mm (a break before it and back after it): outside the beam.
    let mut s = presets::spec("ddsp").unwrap();
    s.surfaces.insert(19, diffcassi::spec::SurfaceSpec::coordinate_break(30.0, 0.0, 0.0, 0.0, 0.0, 0.0));
    s.surfaces.insert(21, diffcassi::spec::SurfaceSpec::coordinate_break(-30.0, 0.0, 0.0, 0.0, 0.0, 0.0));
    let sys = SequentialSystem::build(&s).unwrap();
    let e = Renderer::new(&sys, &AnalyticTracer::default(), config(true), Mask::random(H, W, 0.5, 1).unwrap()).err().expect("a mask outside the beam refused").to_string();
    assert!(e.contains("outside the beam") && e.contains("surface 20"), "{e}");
}

/// The whole acquisition through the twin where the kernels now model more (issue 41/42): a toroid
/// (tests/surfaces.rs), the `gsp` grating CASSI, `all_new_kinds` (a conic toroid with y⁴, y⁶ terms, a curved
/// grating passing 73 % of the power — `grating_efficiency`, carried by the plane weights — and a paraboloid
/// mirror) and the singlet at infinity of tests/common (`scene_fov_deg`), each as [`assert_twin_render_matches`].
#[test]
fn the_twin_render_models_toroids_gratings_and_objects_at_infinity() {
    let scene = scene();
    let build = |spec: diffcassi::spec::SystemSpec| SequentialSystem::build(&spec).unwrap();
    let cases = [
        ("toroid", build(crate::surfaces::toroid_lens(Some(35.0))), None),
        ("gsp", system("gsp"), None),
        ("all_new_kinds", build(crate::surfaces::all_new_kinds()), None),
        ("singlet at infinity", build(crate::common::singlet_at_infinity(false)), Some(0.5)),
    ];
    for (name, sys, fov_deg) in &cases {
        assert_twin_render_matches(name, sys, *fov_deg, &scene);
    }
}

/// The whole acquisition through the twin with ray aiming (`paraxial` and `real`: `dc_aimed_ray`, the CPU's
/// `rays::aimed_ray` per ray) on SP and on the singlet at infinity of tests/common, each as
/// [`assert_twin_render_matches`]; and where some aims fail (a scene far past the singlet's field), the CPU's error.
#[test]
fn the_twin_render_models_ray_aiming() {
    use diffcassi::spec::RayAiming;
    let scene = scene();
    let tracer = AnalyticTracer::default();
    let aimed = |mut spec: diffcassi::spec::SystemSpec, aiming: RayAiming| {
        spec.ray_aiming = aiming;
        SequentialSystem::build(&spec).unwrap()
    };
    let cases = [
        ("sp paraxial", aimed(presets::spec("sp").unwrap(), RayAiming::Paraxial), None),
        ("sp real", aimed(presets::spec("sp").unwrap(), RayAiming::Real), None),
        ("singlet at infinity real", aimed(crate::common::singlet_at_infinity(false), RayAiming::Real), Some(0.5)),
    ];
    for (name, sys, fov_deg) in &cases {
        assert_twin_render_matches(name, sys, *fov_deg, &scene);
    }
    // Aims that fail (the singlet's scene widened to 179.8° after the renderer is built: field angles up to ~84°,
    // whose rays cannot reach the stop): the render stops with the CPU's error (one plane, so that the CPU's
    // first error is defined).
    let sys = aimed(crate::common::singlet_at_infinity(false), RayAiming::Real);
    let mut c = config(false);
    c.scene_fov_deg = Some(0.5);
    c.spectral = SpectralSampling::new(vec![520.0], 1).unwrap();
    let mut r = Renderer::new(&sys, &tracer, c, Mask::random(H, W, 0.6, 5).unwrap()).unwrap();
    r.config.scene_pitch_mm = 179.8f64.to_radians() / W as f64;
    let cpu = r.render(&scene, false, &|_| {}).err().expect("the CPU render must fail").to_string();
    let twin = render_on(&r, &scene, false, Executor::Twin).err().expect("the twin render must fail").to_string();
    assert_eq!(twin, cpu);
    assert!(twin.contains("ray aiming failed"), "{twin}");
}

#[test]
fn the_twin_render_has_the_same_bits_on_any_thread_count() {
    let scene = scene();
    let sys = system("msp");
    let tracer = AnalyticTracer::default();
    let r = Renderer::new(&sys, &tracer, config(true), Mask::random(H, W, 0.6, 5).unwrap()).unwrap();
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| render_on(&r, &scene, true, Executor::Twin).unwrap().0)
    };
    let (a, b) = (run(1), run(3));
    assert!(a.image.iter().zip(&b.image).all(|(x, y)| x.to_bits() == y.to_bits()));
    assert_eq!(a.bands, b.bands);
    assert_eq!(a.stats, b.stats);
}

#[test]
fn a_black_scene_renders_black_and_bad_settings_are_named() {
    let sys = system("sp");
    let tracer = AnalyticTracer::default();
    let r = Renderer::new(&sys, &tracer, config(true), Mask::random(H, W, 0.6, 5).unwrap()).unwrap();
    let black = SpectralCube::new(H, W, vec![450.0, 650.0], vec![0.0; H * W * 2], "black").unwrap();
    let (acq, _) = render_on(&r, &black, false, Executor::Twin).unwrap();
    assert!(acq.image.iter().all(|&v| v == 0.0));
    assert!(acq.stats.arrived > 0);
    // The batched tracer path is named.
    let mut c = config(true);
    c.force_batched = true;
    let rb = Renderer::new(&sys, &tracer, c, Mask::random(H, W, 0.6, 5).unwrap()).unwrap();
    let e = plan(&rb, &scene()).err().expect("batched refused").to_string();
    assert!(e.contains("batched"), "{e}");
    // Another backend than the analytic one is named.
    let twin = diffcassi::gpu::TwinTracer::default();
    let rt = Renderer::new(&sys, &twin, config(true), Mask::random(H, W, 0.6, 5).unwrap()).unwrap();
    let e = plan(&rt, &scene()).err().expect("another backend refused").to_string();
    assert!(e.contains("--backend gpu-twin-f64"), "{e}");
    // Without a CUDA driver (CI), --device cuda is one clear error.
    if diffcassi::gpu::probe(0).is_err() {
        let e = render_for(Device::Cuda(0), &r, &scene(), false, &|_| {}).err().expect("no CUDA here").to_string();
        assert!(e.contains("NVIDIA driver") || e.contains("CUDA"), "{e}");
    }
}
