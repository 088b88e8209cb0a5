//! The GPU kernels' CPU twin (src/gpu/kernels, compiled for the host) against the Rust kernels: the trace
//! kernel equals the scalar reference kernel ray for ray on the four presets over full pupils and fields
//! (the extremes suite, tests/extremes.rs, checks it on grazing, TIR, vignetted, missing and NaN/inf rays),
//! and the landing kernel (sampling, aiming, trace, detector coordinates) equals the renderer's own steps
//! composed in Rust. Bit for bit: the twin is compiled without contraction and evaluates the same
//! expressions in the same order (the acceptance bound is 1e-12 mm; these tests hold the twin to 0). The f32
//! kernels are held to the Rust f32 paths the same way: the f32 trace to the f32 lane kernel
//! (`AnalyticF32Tracer`, every SIMD level), the f32 plane transport to the renderer's `--precision f32`.
use diffcassi::analysis::MappingCube;
use diffcassi::gpu::TwinTracer;
use diffcassi::render::twin::{plane_landings, SceneGeometry};
use diffcassi::presets;
use diffcassi::rays::{PupilAim, PupilPattern, RayBatch};
use diffcassi::render::{Detector, RaySampler, Sampling};
use diffcassi::system::SequentialSystem;
use diffcassi::tracer::{AnalyticF32Tracer, AnalyticTracer, Kernel, Precision, RayStatus, SimdLevel, TracedBatch, Tracer};
use glam::DVec3;

const PRESETS: [&str; 4] = ["sp", "ap", "msp", "map"];

fn system(name: &str) -> SequentialSystem {
    SequentialSystem::build(&presets::spec(name).unwrap()).unwrap()
}

fn scalar() -> AnalyticTracer {
    AnalyticTracer::with_kernel(Kernel::Scalar)
}

/// Full pupils (hexapolar, 6 rings, and far past the rim so that some rays miss a surface or reflect
/// totally) over a 7 × 7 field grid reaching past the scene (±3.2 mm) plus two far fields (±40 mm), at
/// three wavelengths.
fn full_batch(sys: &SequentialSystem) -> RayBatch {
    let mut pupil = PupilPattern::Hexapolar { rings: 6 }.points();
    pupil.extend([[1.3, 0.0], [0.0, -1.3], [0.95, 0.95], [6.0, 0.0], [0.0, -6.0], [4.0, 4.0]]);
    let mut fields: Vec<[f64; 2]> = (0..49).map(|k| [-3.2 + (k / 7) as f64 * 6.4 / 6.0, -3.2 + (k % 7) as f64 * 6.4 / 6.0]).collect();
    fields.extend([[40.0, 0.0], [0.0, -40.0]]);
    object_rays(sys, &fields, &pupil, &[450.0, 520.0, 650.0])
}

/// Every wavelength × field × pupil point's object ray (aiming off), in that order.
fn object_rays(sys: &SequentialSystem, fields: &[[f64; 2]], pupil: &[[f64; 2]], wavelengths_nm: &[f64]) -> RayBatch {
    let mut batch = RayBatch::with_capacity(0);
    for &w in wavelengths_nm {
        for field in fields {
            for p in pupil {
                let (o, d) = diffcassi::rays::object_ray(sys, *field, p[0], p[1]);
                batch.push(o, d, w);
            }
        }
    }
    batch
}

#[test]
fn trace_kernel_twin_equals_the_scalar_kernel_on_the_presets() {
    for name in PRESETS {
        let sys = system(name);
        let rays = full_batch(&sys);
        let twin = TwinTracer::default().trace(&sys, &rays).unwrap();
        let rust = scalar().trace(&sys, &rays).unwrap();
        assert_eq!(twin.status, rust.status, "{name}: statuses");
        assert_eq!(twin.surface, rust.surface, "{name}: stopping surfaces");
        let mut worst = 0.0f64;
        for i in 0..rust.len() {
            for (a, b) in [(twin.x[i], rust.x[i]), (twin.y[i], rust.y[i]), (twin.z[i], rust.z[i])] {
                worst = worst.max((a - b).abs());
            }
            for (a, b) in [(twin.x[i], rust.x[i]), (twin.y[i], rust.y[i]), (twin.z[i], rust.z[i]), (twin.dir_x[i], rust.dir_x[i]), (twin.dir_y[i], rust.dir_y[i]), (twin.dir_z[i], rust.dir_z[i])] {
                assert_eq!(a.to_bits(), b.to_bits(), "{name} ray {i}: {a} vs {b}");
            }
        }
        assert!(worst <= 1e-12, "{name}: {worst:e} mm");
        let ok = rust.status.iter().filter(|&&s| s == RayStatus::Ok).count();
        assert!(ok > rust.len() / 3 && ok < rust.len(), "{name}: {ok} ok of {}: the batch must exercise arrivals and stops", rust.len());
    }
}

#[test]
fn trace_kernel_twin_classifies_invalid_inputs_like_the_scalar_kernel() {
    let sys = system("sp");
    let mut rays = RayBatch::with_capacity(0);
    let nan = f64::NAN;
    let inf = f64::INFINITY;
    for (o, d) in [
        (DVec3::new(nan, 0.0, 0.0), DVec3::Z),
        (DVec3::ZERO, DVec3::new(0.0, inf, 1.0)),
        (DVec3::ZERO, DVec3::ZERO),
        (DVec3::ZERO, DVec3::new(0.0, 0.0, 1e-310)),
        (DVec3::ZERO, DVec3::new(1e-3, 0.0, 1e300)),
        (DVec3::new(1e300, 0.0, 0.0), DVec3::Z),
        (DVec3::ZERO, DVec3::X),
        (DVec3::ZERO, -DVec3::Z),
    ] {
        rays.push(o, d, 520.0);
    }
    let twin = TwinTracer::default().trace(&sys, &rays).unwrap();
    let rust = scalar().trace(&sys, &rays).unwrap();
    assert_eq!(twin.status, rust.status);
    assert_eq!(twin.surface, rust.surface);
    assert_eq!(twin.status[0], RayStatus::InvalidInput);
    assert_eq!(twin.status[2], RayStatus::InvalidInput);
    for i in 0..rust.len() {
        assert_eq!(twin.x[i].to_bits(), rust.x[i].to_bits(), "ray {i}");
        assert!(twin.x[i].is_finite() && twin.y[i].is_finite(), "ray {i}: no NaN leaves the twin");
    }
}

/// Statuses, stopping surfaces and every output bit of `twin` equal to `rust`'s.
fn assert_bits(label: &str, twin: &TracedBatch, rust: &TracedBatch) {
    assert_eq!(twin.status, rust.status, "{label}: statuses");
    assert_eq!(twin.surface, rust.surface, "{label}: stopping surfaces");
    for i in 0..rust.len() {
        for (a, b) in [(twin.x[i], rust.x[i]), (twin.y[i], rust.y[i]), (twin.z[i], rust.z[i]), (twin.dir_x[i], rust.dir_x[i]), (twin.dir_y[i], rust.dir_y[i]), (twin.dir_z[i], rust.dir_z[i])] {
            assert_eq!(a.to_bits(), b.to_bits(), "{label} ray {i}: {a} vs {b}");
        }
    }
}

/// The f32 trace kernel (`dc_trace_f32_kernel`) equals the f32 lane kernel, which gives the same bits on every
/// SIMD level (tests/f32.rs), on the same full pupils, fields and wavelengths: the same algorithm, the f32
/// operations in the same order, the system constants rounded from the same f64 values.
#[test]
fn f32_trace_kernel_twin_equals_the_f32_lane_kernel_on_the_presets() {
    for name in PRESETS {
        let sys = system(name);
        let rays = full_batch(&sys);
        let twin = TwinTracer::f32().trace(&sys, &rays).unwrap();
        assert_eq!(TwinTracer::f32().name(), "gpu-twin-f32");
        for level in SimdLevel::available() {
            let rust = AnalyticF32Tracer::new(level).trace(&sys, &rays).unwrap();
            assert_bits(&format!("{name} f32 {}", level.name()), &twin, &rust);
        }
        let ok = twin.status.iter().filter(|&&s| s == RayStatus::Ok).count();
        assert!(ok > rays.len() / 3 && ok < rays.len(), "{name}: {ok} ok of {}: the batch must exercise arrivals and stops", rays.len());
        // Not the f64 kernel: f32 landings differ from f64 ones (by ≤ 0.05 µm, tests/f32.rs).
        let f64_ = TwinTracer::default().trace(&sys, &rays).unwrap();
        let differ = (0..rays.len()).filter(|&i| twin.status[i] == RayStatus::Ok && twin.x[i] != f64_.x[i]).count();
        assert!(differ > ok / 2, "{name}: only {differ} of {ok} f32 landings differ from f64");
    }
}

/// Unreliable inputs through the f32 trace kernel: classified as the f32 lane kernel classifies them (the f64
/// checks and normalisation, then origins beyond 1 m refused), never a NaN out.
#[test]
fn f32_trace_kernel_twin_classifies_invalid_inputs_like_the_f32_lane_kernel() {
    let sys = system("sp");
    let mut rays = RayBatch::with_capacity(0);
    let (nan, inf) = (f64::NAN, f64::INFINITY);
    for (o, d) in [
        (DVec3::new(nan, 0.0, 0.0), DVec3::Z),
        (DVec3::ZERO, DVec3::new(0.0, inf, 1.0)),
        (DVec3::ZERO, DVec3::ZERO),
        (DVec3::ZERO, DVec3::new(0.0, 0.0, 1e-310)),
        (DVec3::ZERO, DVec3::new(1e-3, 0.0, 1e300)),
        (DVec3::ZERO, DVec3::new(1e-40, 1e-41, 1e-39)),
        (DVec3::new(1e300, 0.0, 0.0), DVec3::Z),
        (DVec3::new(0.0, -1000.0, 0.0), DVec3::Z),
        (DVec3::new(0.0, -1000.0001, 0.0), DVec3::Z),
        (DVec3::new(0.1, 0.2, 0.0), DVec3::new(1e-8, -2e-8, 1.0)),
        (DVec3::ZERO, DVec3::X),
        (DVec3::ZERO, -DVec3::Z),
    ] {
        rays.push(o, d, 520.0);
    }
    let twin = TwinTracer::f32().trace(&sys, &rays).unwrap();
    let rust = AnalyticF32Tracer::new(SimdLevel::detect()).trace(&sys, &rays).unwrap();
    assert_bits("sp f32 invalid inputs", &twin, &rust);
    for i in [0, 2, 6, 8] {
        assert_eq!(twin.status[i], RayStatus::InvalidInput, "ray {i}");
    }
    assert_ne!(twin.status[7], RayStatus::InvalidInput, "an origin at exactly 1 m is accepted");
    assert_eq!(twin.status[9], RayStatus::Ok);
    for i in 0..rust.len() {
        assert!(twin.x[i].is_finite() && twin.y[i].is_finite(), "ray {i}: no NaN leaves the twin");
    }
}

/// The renderer's steps for one plane, composed from the library's Rust pieces: the sampler, the pixel
/// centre, the aim, the scalar trace, the detector coordinates.
fn rust_landings(sys: &SequentialSystem, scene: SceneGeometry<'_>, sampler: &RaySampler, seed: u64, plane: u64, wl: f64, pixels: &[u32]) -> (Vec<f64>, Vec<f64>, Vec<RayStatus>) {
    let aim = PupilAim::of(sys);
    let ray = |[fx, fy]: [f64; 2], px: f64, py: f64| Ok((DVec3::new(fx, fy, 0.0), DVec3::from(aim.direction(fx, fy, px, py))));
    landings_of_rays(sys, scene, sampler, seed, plane, wl, pixels, ray).unwrap()
}

/// The renderer's steps for one plane with `ray` (field point or angles, pupil px, py → origin and direction)
/// as its ray generator: the sampler, the pixel centre and the sample's jitter in it (`PlaneContext::ray`), the
/// scalar trace, the detector coordinates (NaN where a ray did not arrive); `ray`'s first error instead.
#[allow(clippy::too_many_arguments)]
fn landings_of_rays(sys: &SequentialSystem, scene: SceneGeometry<'_>, sampler: &RaySampler, seed: u64, plane: u64, wl: f64, pixels: &[u32], ray: impl Fn([f64; 2], f64, f64) -> Result<(DVec3, DVec3), String>) -> Result<(Vec<f64>, Vec<f64>, Vec<RayStatus>), String> {
    let mut batch = RayBatch::with_capacity(0);
    let mut s = vec![[0.0; 4]; sampler.rays];
    for &q in pixels {
        sampler.fill(seed, plane, q as u64, &mut s);
        let (row, col) = (q as usize / scene.width, q as usize % scene.width);
        for smp in &s {
            let field = MappingCube::sample_xy(scene.height, scene.width, scene.pitch_mm, row, col, smp[2], smp[3]);
            let (o, d) = ray(field, smp[0], smp[1])?;
            batch.push(o, d, wl);
        }
    }
    let t = scalar().trace(sys, &batch).unwrap();
    let (mut u, mut v) = (Vec::new(), Vec::new());
    for i in 0..t.len() {
        let (a, b) = if t.status[i] == RayStatus::Ok { scene.detector.to_pixel(t.x[i], t.y[i]) } else { (f64::NAN, f64::NAN) };
        u.push(a);
        v.push(b);
    }
    Ok((u, v, t.status))
}

#[test]
fn landing_kernel_twin_equals_the_renderers_steps() {
    let detector = Detector { width: 700, height: 700, pitch_mm: 0.01, x_left_mm: -3.5, y_top_mm: 3.5 };
    for name in PRESETS {
        let sys = system(name);
        // 12 × 16 pixels of 0.4 mm: the scene reaches ±3.2 mm, past SP's field, so some rays vignette.
        let scene = SceneGeometry { height: 12, width: 16, pitch_mm: 0.4, detector: &detector };
        let pixels: Vec<u32> = (0..(12 * 16) as u32).filter(|q| q % 3 != 1).collect();
        for (rays, mode, seed, plane, wl) in [(20, Sampling::Stratified, 0u64, 0u64, 450.0), (7, Sampling::Stratified, 99, 57, 555.5), (1, Sampling::Stratified, 3, 111, 650.0), (5, Sampling::Independent, 12345, 3, 520.0)] {
            let sampler = RaySampler::new(rays, mode);
            let twin = plane_landings(&sys, scene, &sampler, seed, plane, wl, &pixels).unwrap();
            let (u, v, status) = rust_landings(&sys, scene, &sampler, seed, plane, wl, &pixels);
            assert_eq!(twin.status, status, "{name} {rays} {mode:?}: statuses");
            for i in 0..u.len() {
                assert_eq!(twin.u[i].to_bits(), u[i].to_bits(), "{name} {rays} {mode:?} ray {i}: u {} vs {}", twin.u[i], u[i]);
                assert_eq!(twin.v[i].to_bits(), v[i].to_bits(), "{name} {rays} {mode:?} ray {i}: v");
            }
            assert!(status.iter().any(|&s| s == RayStatus::Ok), "{name}: some rays must arrive");
        }
    }
}

#[test]
fn landing_kernel_refuses_pixels_outside_the_scene() {
    let detector = Detector { width: 10, height: 10, pitch_mm: 0.01, x_left_mm: -0.05, y_top_mm: 0.05 };
    let sys = system("sp");
    let scene = SceneGeometry { height: 4, width: 4, pitch_mm: 0.01, detector: &detector };
    let e = plane_landings(&sys, scene, &RaySampler::new(4, Sampling::Stratified), 0, 0, 520.0, &[3, 16]).unwrap_err().to_string();
    assert!(e.contains("pixel index 16") && e.contains("4×4"), "{e}");
}

/// A small acquisition's light transport through the host twin of the landing and footprint kernels equals
/// the CPU renderer's, plane by plane: the same footprints, f32 weights and ray counts, hence the same
/// acquisition (the rest of the render — applying footprints, the Airy blur, the band sums — is shared).
#[test]
fn plane_transport_through_the_twin_equals_the_cpu_renderer() {
    use diffcassi::render::{Mask, RenderConfig, Renderer};
    for name in ["sp", "msp"] {
        let sys = system(name);
        let tracer = AnalyticTracer::default();
        let (h, w) = (12, 16);
        let mut weights_by_precision = Vec::new();
        for precision in [Precision::F64, Precision::F32] {
            let mut config = RenderConfig::paper(w);
            config.scene_height = h;
            config.scene_pitch_mm = 0.2; // ±1.6 mm: the scene spans most of the field
            config.rays_per_pixel = 6;
            config.spectral = diffcassi::render::SpectralSampling::new(vec![450.0, 520.0, 650.0], 2).unwrap();
            config.precision = precision;
            let mask = Mask::random(h, w, 0.5, 7).unwrap();
            let r = Renderer::new(&sys, &tracer, config, mask).unwrap();
            let ctx = r.plane_context();
            let mut footprints = 0;
            let mut weights = Vec::new();
            for (p, &wl) in r.config.spectral.planes_nm.iter().enumerate() {
                let cpu = r.trace_plane(p).unwrap();
                let twin = diffcassi::render::twin::trace_plane(&ctx, p, wl).unwrap();
                assert_eq!(twin.footprints, cpu.footprints, "{name} {precision} plane {p}: footprints");
                assert_eq!(twin.weights.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), cpu.weights.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), "{name} {precision} plane {p}: weights");
                assert_eq!(twin.stats, cpu.stats, "{name} {precision} plane {p}: ray counts");
                footprints += cpu.footprints.len();
                weights.extend(cpu.weights);
            }
            assert!(footprints > 0);
            weights_by_precision.push(weights);
        }
        // The f32 render is not the f64 one (so the f32 comparison above is not the f64 one again).
        assert_ne!(weights_by_precision[0], weights_by_precision[1], "{name}: f32 and f64 transports are identical");
    }
}

/// The same through a detector that sees only part of the image (windows clipped at its edges, footprints
/// wholly off it): the twin loses the same weight as the CPU, tap for tap.
#[test]
fn plane_transport_through_the_twin_clips_like_the_cpu_renderer() {
    use diffcassi::render::transport::PlaneContext;
    use diffcassi::render::{Mask, RenderConfig, Renderer};
    let sys = system("sp");
    let tracer = AnalyticTracer::default();
    let mut config = RenderConfig::paper(16);
    config.scene_pitch_mm = 0.2;
    config.rays_per_pixel = 5;
    config.spectral = diffcassi::render::SpectralSampling::new(vec![450.0, 650.0], 1).unwrap();
    let r = Renderer::new(&sys, &tracer, config, Mask::random(16, 16, 0.7, 3).unwrap()).unwrap();
    let full = r.detector;
    // The left 40 % of the detector's columns and its top half, moved so that windows straddle both edges.
    let cropped = Detector { width: full.width * 2 / 5, height: full.height / 2, ..full };
    let base = r.plane_context();
    for precision in [Precision::F64, Precision::F32] {
        let ctx = PlaneContext { detector: &cropped, precision, ..base };
        let mut lost = 0.0;
        for (p, &wl) in r.config.spectral.planes_nm.iter().enumerate() {
            let cpu = ctx.trace_plane(p, wl).unwrap();
            let twin = diffcassi::render::twin::trace_plane(&ctx, p, wl).unwrap();
            assert_eq!(twin.footprints, cpu.footprints, "{precision} plane {p}: footprints");
            assert_eq!(twin.weights.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), cpu.weights.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), "{precision} plane {p}: weights");
            assert_eq!(twin.stats, cpu.stats, "{precision} plane {p}: ray counts and lost weight");
            lost += cpu.stats.off_detector;
        }
        assert!(lost > 0.0, "{precision}: the cropped detector must lose some weight");
    }
}

/// `mapping --device cpu-twin` (and so `--device cuda`, the same kernels): the chief-ray cube traced by the
/// device's trace kernel in batches equals the CPU's cube, traced by the analytic tracer's direct route, bit
/// for bit in f64, and the f32 lane kernel's cube in f32 — on every preset, with pixels far past the scene so that
/// some chief rays do not arrive. Without a CUDA driver, `Device::Cuda` is one clear error.
#[test]
fn the_mapping_cube_on_the_twin_equals_the_cpu_cube() {
    use diffcassi::analysis::mapping_cube;
    use diffcassi::render::Device;
    let wavelengths = [450.0, 523.7, 650.0];
    for name in PRESETS {
        let sys = system(name);
        for precision in [Precision::F64, Precision::F32] {
            let cpu = Device::Cpu.tracer(precision).unwrap();
            let twin = Device::CpuTwin.tracer(precision).unwrap();
            assert!(twin.name().starts_with("gpu-twin"), "{}", twin.name());
            // 9 × 11 pixels of 1 mm (the scene of the presets is 5.12 mm wide) and of 20 mm: at 20 mm most
            // chief rays are vignetted or miss.
            for pitch_mm in [1.0, 20.0] {
                let a = mapping_cube(&sys, cpu.as_ref(), 9, 11, pitch_mm, &wavelengths).unwrap();
                let b = mapping_cube(&sys, twin.as_ref(), 9, 11, pitch_mm, &wavelengths).unwrap();
                assert_eq!(a.valid, b.valid, "{name} {precision}: arrivals");
                assert!(a.valid.iter().any(|&v| v == 1), "{name}: some chief rays arrive");
                if pitch_mm == 20.0 {
                    assert!(a.valid.iter().any(|&v| v == 0), "{name}: some chief rays do not arrive");
                }
                let bits = |c: &MappingCube| c.positions_mm.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&a), bits(&b), "{name} {precision}: positions");
            }
        }
    }
    if diffcassi::gpu::probe(0).is_err() {
        let e = Device::Cuda(0).tracer(Precision::F64).err().expect("no CUDA here").to_string();
        assert!(e.contains("--device cuda"), "{e}");
    }
}

// ---- mirrors, circular obscurations and objects at infinity (issue 41/42) ------------------------------

fn zmx_system(name: &str) -> SequentialSystem {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/zmx").join(name);
    let imp = diffcassi::spec::zmx::import_zmx_file(&path, &diffcassi::spec::zmx::ZmxOptions::default()).unwrap_or_else(|e| panic!("{name}: {e}"));
    SequentialSystem::build(&imp.spec).unwrap_or_else(|e| panic!("{name}: {e}"))
}

/// Each of the system's field points (object heights, or angles at infinity) and the axis, scaled by 0, ½, 1
/// and 1.5 along each axis; hexapolar pupils (6 rings) and points past the rim, at three wavelengths.
fn catalogue_batch(sys: &SequentialSystem) -> RayBatch {
    let mut pupil = PupilPattern::Hexapolar { rings: 6 }.points();
    pupil.extend([[1.3, 0.0], [0.0, -1.3], [0.95, 0.95], [3.0, 0.0], [0.0, -3.0]]);
    let mut fields = Vec::new();
    for f in sys.fields_or_axis() {
        for s in [0.0, 0.5, 1.0, 1.5] {
            fields.push([f[0] * s, f[1] * s]);
            fields.push([f[1] * s, -f[0] * s]);
        }
    }
    object_rays(sys, &fields, &pupil, &[486.1327, 587.5618, 656.2725])
}

/// The mirrors (`dc_reflect`, DC_INTERACTION_REFLECT) and circular obscurations (DC_APERTURE_OBSCURATION)
/// of the trace kernels against the CPU kernels: the fold-mirror builder of tests/surfaces.rs (a finite
/// object, two 45° mirrors between Coordinate Breaks), optiland's fold mirrors and rayoptics' Cassegrain
/// (mirrors, object at infinity) and US 5,331,467 example 1 (a Mangin catadioptric at infinity with its
/// `OBSC 0 25` on surface 2). The f64 twin equals the scalar kernel bit for bit (statuses and stopping
/// surfaces included), the f32 twin the f32 lane kernel on every SIMD level; the batches must exercise
/// arrivals, the obscuration and a mirror's reflection.
#[test]
fn trace_kernel_twins_equal_the_cpu_kernels_through_mirrors_and_obscurations() {
    let systems = [
        ("fold_mirrors (builder)".to_string(), SequentialSystem::build(&crate::surfaces::fold_mirrors()).unwrap()),
        ("fold_mirrors_optiland.zmx".to_string(), zmx_system("fold_mirrors_optiland.zmx")),
        ("cassegrain_mirrors_HoO_V2C18Ex03.zmx".to_string(), zmx_system("cassegrain_mirrors_HoO_V2C18Ex03.zmx")),
        ("US05331467-1.zmx".to_string(), zmx_system("US05331467-1.zmx")),
    ];
    for (name, sys) in &systems {
        assert!(sys.surfaces.iter().any(|s| s.interaction == diffcassi::system::Interaction::Reflect), "{name}: a mirror");
        let rays = catalogue_batch(sys);
        let rust = scalar().trace(sys, &rays).unwrap();
        let twin = TwinTracer::default().trace(sys, &rays).unwrap();
        assert_bits(&format!("{name} f64"), &twin, &rust);
        let ok = rust.status.iter().filter(|&&s| s == RayStatus::Ok).count();
        // Optiland's fold mirrors and the Cassegrain have no apertures: every ray arrives there; the other two
        // also stop rays (apertures, the obscuration).
        let stops = usize::from(name.contains("builder") || name.starts_with("US"));
        assert!(ok > rust.len() / 10 && ok + stops <= rust.len(), "{name}: {ok} ok of {}: the batch must exercise arrivals and stops", rust.len());
        // Past the last mirror: a ray that arrives went through every mirror of the path.
        let twin32 = TwinTracer::f32().trace(sys, &rays).unwrap();
        for level in SimdLevel::available() {
            let rust32 = AnalyticF32Tracer::new(level).trace(sys, &rays).unwrap();
            assert_bits(&format!("{name} f32 {}", level.name()), &twin32, &rust32);
        }
        // The f32 landings are the f64 ones to the f32 trace's accuracy: the twin is the f32 lane kernel (above), whose
        // error here is its own (tests/f32.rs bounds it on the presets, 0.05 µm); these systems are up to metres
        // long and fold the beam, so the bound is relative to the path's length, 1e-5 (≈ 80 f32 ulps).
        let scale = 1.0 + sys.surfaces.iter().map(|s| s.thickness_mm.abs()).filter(|t| t.is_finite()).sum::<f64>();
        let (mut worst, mut compared) = (0.0f64, 0);
        for i in 0..rays.len() {
            if rust.status[i] == RayStatus::Ok && twin32.status[i] == RayStatus::Ok {
                worst = worst.max((twin32.x[i] - rust.x[i]).abs().max((twin32.y[i] - rust.y[i]).abs()));
                compared += 1;
            }
        }
        println!("{name}: {compared} rays, f32 twin vs f64 max {:.4} µm (path {scale:.0} mm)", worst * 1e3);
        assert!(compared > 0 && worst <= 1e-5 * scale, "{name}: f32 {worst:e} mm from f64 (path {scale} mm)");
    }
    // US 5,331,467's obscuration on surface 2 stops rays in the twins as in the CPU kernel.
    let (name, sys) = &systems[3];
    let rays = catalogue_batch(sys);
    let twin = TwinTracer::default().trace(sys, &rays).unwrap();
    let obscured = (0..rays.len()).filter(|&i| twin.status[i] == RayStatus::Vignetted && twin.surface[i] == 2).count();
    assert!(obscured > 0, "{name}: no ray vignetted by the obscuration on surface 2");
    let mut on_axis = RayBatch::with_capacity(0);
    on_axis.push(DVec3::new(0.0, 10.0, 0.0), DVec3::Z, 587.5618);
    on_axis.push(DVec3::new(0.0, 30.0, 0.0), DVec3::Z, 587.5618);
    let t = TwinTracer::default().trace(sys, &on_axis).unwrap();
    assert_eq!((t.status[0], t.surface[0], t.status[1]), (RayStatus::Vignetted, 2, RayStatus::Ok), "{name}: r = 10 mm is obscured, r = 30 mm passes");
}

/// The landing kernel (sample, aim, trace, detector coordinates) through the fold mirrors of tests/surfaces.rs
/// (a finite object): the renderer's steps composed in Rust, bit for bit.
#[test]
fn landing_kernel_twin_equals_the_renderers_steps_through_fold_mirrors() {
    let sys = SequentialSystem::build(&crate::surfaces::fold_mirrors()).unwrap();
    let detector = Detector { width: 400, height: 400, pitch_mm: 0.01, x_left_mm: -2.0, y_top_mm: 2.0 };
    let scene = SceneGeometry { height: 8, width: 10, pitch_mm: 0.3, detector: &detector };
    let pixels: Vec<u32> = (0..80).collect();
    let sampler = RaySampler::new(9, Sampling::Stratified);
    let twin = plane_landings(&sys, scene, &sampler, 5, 2, 520.0, &pixels).unwrap();
    let (u, v, status) = rust_landings(&sys, scene, &sampler, 5, 2, 520.0, &pixels);
    assert_eq!(twin.status, status, "statuses");
    for i in 0..u.len() {
        assert_eq!((twin.u[i].to_bits(), twin.v[i].to_bits()), (u[i].to_bits(), v[i].to_bits()), "ray {i}");
    }
    assert!(status.iter().any(|&s| s == RayStatus::Ok), "some rays must arrive");
}

// ---- Toroidal surfaces, diffraction gratings and renders at infinity (issue 41/42) ------------------------

/// The toroid of a `.zmx` text: a Toroidal stop (R 20 mm, radius of rotation 100 mm) 50 mm behind the object.
fn inline_toroid() -> SequentialSystem {
    let text = "MODE SEQ\nUNIT MM X W X CM MR CPMM\nOBNA 0.05 0\nFTYP 1 0 1 1 0 0 0\nXFLN 0\nYFLN 0\nWAVM 1 0.55 1\nPWAV 1\n\
SURF 0\n  TYPE STANDARD\n  CURV 0.0 0 0 0 0 \"\"\n  DISZ 50\nSURF 1\n  STOP\n  TYPE TOROIDAL\n  CURV 0.05 0 0 0 0 \"\"\n  PARM 0 0\n  PARM 1 0\n  PARM 2 0\n  PARM 3 0\n  \
XDAT 1 0.000000000000E+00 0 0 1.0 0.0 0 \"\"\n  XDAT 2 1.000000000000E+02 0 0 1.0 0.0 0 \"\"\n  DISZ 5\n  GLAS N-BK7 0 0 1.5 40 0 0 0 0 0 0\nSURF 2\n  TYPE STANDARD\n  DISZ 0\n";
    let spec = diffcassi::spec::zmx::import_zmx(text.as_bytes(), "t.zmx", None, &diffcassi::spec::zmx::ZmxOptions::default()).unwrap().spec;
    SequentialSystem::build(&spec).unwrap()
}

/// A reflective plane grating (`GLAS MIRROR` on a `DGRATING`, 0.3 lines/µm, order 1) behind a 10° tilt, folded
/// back (the builder of tests/surfaces.rs's Jacobian tests).
fn reflective_grating() -> diffcassi::spec::SystemSpec {
    let mut r = crate::surfaces::plane_grating(0.3, 1);
    r.surfaces[1].material = Some("MIRROR".into());
    r.surfaces[1].thickness_mm = diffcassi::spec::Cell::fixed(-30.0);
    r.surfaces.insert(1, diffcassi::spec::SurfaceSpec::coordinate_break(0.0, 0.0, 10.0, 0.0, 0.0, 0.0));
    r
}

/// [`catalogue_batch`] plus a 5 × 5 grid of fields over ±3 mm (±0.05 rad at infinity) and pupil points far past the
/// rim (up to 25×: rays that leave a toroid's domain), at three of the system's wavelengths.
fn wide_batch(sys: &SequentialSystem) -> RayBatch {
    let mut pupil = PupilPattern::Hexapolar { rings: 6 }.points();
    pupil.extend([[1.3, 0.0], [0.0, -1.3], [0.95, 0.95], [3.0, 0.0], [0.0, -3.0], [10.0, 0.0], [0.0, 10.0], [25.0, 0.0], [0.0, -25.0], [18.0, 18.0]]);
    let reach = if sys.object_at_infinity() { 0.05 } else { 3.0 };
    let mut fields: Vec<[f64; 2]> = (0..25).map(|k| [reach * ((k / 5) as f64 / 2.0 - 1.0), reach * ((k % 5) as f64 / 2.0 - 1.0)]).collect();
    for f in sys.fields_or_axis() {
        for s in [0.5, 1.0, 1.5] {
            fields.push([f[0] * s, f[1] * s]);
        }
    }
    let w = &sys.spec.wavelengths_nm;
    let wavelengths = [w[0], w[w.len() / 2], w[w.len() - 1]];
    object_rays(sys, &fields, &pupil, &wavelengths)
}

/// Toroidal surfaces (`DC_SHAPE_TOROIDAL`: dc_toroid_local's sag and gradient, the guarded Newton from the
/// vertex plane's root then the YZ conic's) and diffraction gratings (`dc_grating_step`: the vector grating
/// equation, transmissive and reflective, evanescent orders) through the trace kernels against the CPU kernels:
/// toroids of tests/surfaces.rs (a radius of rotation of 35 mm, a cylinder, a conic toroid with y⁴, y⁶ terms in
/// `all_new_kinds`), Thorlabs' cylindrical lens LJ1598L1 and a `.zmx` text toroid; plane, curved and reflective
/// gratings of tests/surfaces.rs, optiland's grating plate and the `gsp` preset (SP's prism a plane
/// transmission grating). The f64 twin equals the scalar kernel bit for bit (statuses and stopping surfaces
/// included), the f32 twin the f32 lane kernel on every SIMD level (both widen to f64 there alike); every output
/// is finite (an evanescent or grazing ray stops with its status and zeros, never NaN).
#[test]
fn trace_kernel_twins_equal_the_cpu_kernels_through_toroids_and_gratings() {
    use crate::surfaces::{all_new_kinds, curved_grating, plane_grating, toroid_lens};
    let build = |spec: diffcassi::spec::SystemSpec| SequentialSystem::build(&spec).unwrap();
    let systems = [
        ("toroid R_rot 35 mm (builder)", build(toroid_lens(Some(35.0)))),
        ("toroid, a cylinder (builder)", build(toroid_lens(None))),
        ("all_new_kinds (builder)", build(all_new_kinds())),
        ("cylinder_thorlabs_LJ1598L1.zmx", zmx_system("cylinder_thorlabs_LJ1598L1.zmx")),
        ("toroid (zmx text)", inline_toroid()),
        ("plane grating 0.6/µm (builder)", build(plane_grating(0.6, 1))),
        ("plane grating 1.5/µm (builder)", build(plane_grating(1.5, 1))),
        ("curved grating (builder)", build(curved_grating())),
        ("reflective grating (builder)", build(reflective_grating())),
        ("grating_flat_transmission_optiland.zmx", zmx_system("grating_flat_transmission_optiland.zmx")),
        ("gsp", system("gsp")),
    ];
    let mut evanescent = 0;
    for (name, sys) in &systems {
        let toroid = sys.surfaces.iter().any(|s| matches!(s.shape, Some(diffcassi::surfaces::SurfaceShape::Toroidal { .. })));
        assert!(toroid || sys.has_grating(), "{name}: a toroid or a grating");
        let rays = wide_batch(sys);
        let rust = scalar().trace(sys, &rays).unwrap();
        let twin = TwinTracer::default().trace(sys, &rays).unwrap();
        assert_bits(&format!("{name} f64"), &twin, &rust);
        let ok = rust.status.iter().filter(|&&s| s == RayStatus::Ok).count();
        assert!(ok > rust.len() / 10, "{name}: {ok} ok of {}: the batch must exercise arrivals", rust.len());
        if toroid {
            // Rays past the toroid's domain (|y| beyond its YZ curve's, or x beyond the radius of rotation's) stop
            // on it, classified as on the CPU (compared above).
            assert!(ok < rust.len(), "{name}: every ray arrived: the batch must also stop rays on the toroid");
        }
        evanescent += twin.status.iter().filter(|&&s| s == RayStatus::Evanescent).count();
        let twin32 = TwinTracer::f32().trace(sys, &rays).unwrap();
        for level in SimdLevel::available() {
            let rust32 = AnalyticF32Tracer::new(level).trace(sys, &rays).unwrap();
            assert_bits(&format!("{name} f32 {}", level.name()), &twin32, &rust32);
        }
        for t in [&twin, &twin32] {
            assert!(t.x.iter().chain(&t.y).chain(&t.z).chain(&t.dir_x).chain(&t.dir_y).chain(&t.dir_z).all(|v| v.is_finite()), "{name}: no NaN leaves the twin");
        }
        let mut stops = std::collections::BTreeMap::new();
        for (st, surf) in twin.status.iter().zip(&twin.surface).filter(|(s, _)| **s != RayStatus::Ok) {
            *stops.entry(format!("{st:?} on {surf}")).or_insert(0usize) += 1;
        }
        println!("{name}: {} rays, {ok} ok; stops {stops:?}", rays.len());
    }
    assert!(evanescent > 0, "no evanescent order among the gratings' rays");
    // An order that cannot propagate (2 lines/µm at 650 nm: |mλT| = 1.3 > 1, tests/surfaces.rs) stops every ray
    // on the grating as evanescent, in both twins, with zeros out; and a ray grazing the reflective grating is
    // missed there, as in the CPU kernels.
    let sys = build(plane_grating(2.0, 1));
    let rays = RayBatch::for_field(&sys, [0.0, 0.0], &[[0.0, 0.0], [0.5, 0.5]], 650.0).unwrap();
    for (label, twin) in [("f64", TwinTracer::default().trace(&sys, &rays).unwrap()), ("f32", TwinTracer::f32().trace(&sys, &rays).unwrap())] {
        assert!(twin.status.iter().all(|&s| s == RayStatus::Evanescent) && twin.surface.iter().all(|&s| s == 1), "{label}: {:?} {:?}", twin.status, twin.surface);
        assert!(twin.x.iter().chain(&twin.dir_x).all(|&v| v == 0.0), "{label}");
    }
    // The reflective grating untilted (its vertex 50 mm down the axis): a ray from the vertex with d·n̂ = 1e-13
    // grazes it (missed on surface 1); the axial ray is reflected into its order.
    let mut flat = plane_grating(0.3, 1);
    flat.surfaces[1].material = Some("MIRROR".into());
    flat.surfaces[1].thickness_mm = diffcassi::spec::Cell::fixed(-30.0);
    let sys = build(flat);
    let mut grazing = RayBatch::with_capacity(0);
    grazing.push(DVec3::new(0.0, 0.0, 50.0), DVec3::new(0.0, 1.0, 1e-13), 520.0);
    grazing.push(DVec3::new(0.0, 0.0, 0.0), DVec3::Z, 520.0);
    for (label, twin) in [("f64", TwinTracer::default().trace(&sys, &grazing).unwrap()), ("f32", TwinTracer::f32().trace(&sys, &grazing).unwrap())] {
        assert_eq!((twin.status[0], twin.surface[0], twin.status[1]), (RayStatus::Missed, 1, RayStatus::Ok), "{label}: grazing, axial");
        assert!(twin.dir_z[1] < 0.0, "{label}: the axial ray goes back after the reflective grating");
    }
    assert_bits("reflective grating, grazing", &TwinTracer::default().trace(&sys, &grazing).unwrap(), &scalar().trace(&sys, &grazing).unwrap());
}

/// The renderer's steps at infinity, composed from the library's Rust pieces: the sampler, the pixel's field
/// angles (the pixel pitch an angle, rad), `rays::object_ray` (`PupilAim::parallel_ray`), the scalar trace and
/// the detector coordinates.
fn rust_landings_at_infinity(sys: &SequentialSystem, scene: SceneGeometry<'_>, sampler: &RaySampler, seed: u64, plane: u64, wl: f64, pixels: &[u32]) -> (Vec<f64>, Vec<f64>, Vec<RayStatus>) {
    landings_of_rays(sys, scene, sampler, seed, plane, wl, pixels, |field, px, py| Ok(diffcassi::rays::object_ray(sys, field, px, py))).unwrap()
}

/// The landing kernel for an object at infinity (`dc_parallel_ray`: the pixel's field angles, tan from the
/// platform's libm as Rust's f64::tan): the renderer's steps composed in Rust, bit for bit — the singlet at
/// infinity of tests/common, rayoptics' Cassegrain (mirrors) and US 5,331,467's catadioptric (its obscuration),
/// with scenes reaching past the field so that rays also stop; and the singlet with a scene 179.8° wide (the
/// widest `--scene-fov-deg` allows: field angles within 0.1° of 90°, tan θ up to ~600), whose edge rays stop.
#[test]
fn landing_kernel_twin_equals_the_renderers_steps_at_infinity() {
    let systems = [
        ("singlet at infinity", SequentialSystem::build(&crate::common::singlet_at_infinity(false)).unwrap(), 0.002),
        ("singlet at infinity, 179.8° scene", SequentialSystem::build(&crate::common::singlet_at_infinity(false)).unwrap(), 179.8f64.to_radians() / 12.0),
        ("cassegrain_mirrors_HoO_V2C18Ex03.zmx", zmx_system("cassegrain_mirrors_HoO_V2C18Ex03.zmx"), 0.0005),
        ("US05331467-1.zmx", zmx_system("US05331467-1.zmx"), 0.004),
    ];
    let detector = Detector { width: 600, height: 600, pitch_mm: 0.05, x_left_mm: -15.0, y_top_mm: 15.0 };
    for (name, sys, pitch_rad) in &systems {
        assert!(sys.object_at_infinity(), "{name}");
        let scene = SceneGeometry { height: 10, width: 12, pitch_mm: *pitch_rad, detector: &detector };
        let pixels: Vec<u32> = (0..120).filter(|q| q % 4 != 1).collect();
        let mut statuses = std::collections::BTreeSet::new();
        for (rays, mode, seed, plane) in [(9, Sampling::Stratified, 5u64, 2u64), (4, Sampling::Independent, 77, 13)] {
            let sampler = RaySampler::new(rays, mode);
            let wl = sys.spec.primary_wavelength_nm;
            let twin = plane_landings(sys, scene, &sampler, seed, plane, wl, &pixels).unwrap();
            let (u, v, status) = rust_landings_at_infinity(sys, scene, &sampler, seed, plane, wl, &pixels);
            assert_eq!(twin.status, status, "{name} {rays} {mode:?}: statuses");
            for i in 0..u.len() {
                assert_eq!((twin.u[i].to_bits(), twin.v[i].to_bits()), (u[i].to_bits(), v[i].to_bits()), "{name} {rays} {mode:?} ray {i}: ({}, {}) vs ({}, {})", twin.u[i], twin.v[i], u[i], v[i]);
            }
            statuses.extend(status.iter().map(|s| format!("{s:?}")));
        }
        println!("{name}: {statuses:?}");
        assert!(statuses.contains("Ok"), "{name}: some rays must arrive");
        if name.contains("179.8") {
            assert!(statuses.len() > 1, "{name}: the rays near 90° must stop: {statuses:?}");
        }
    }
}

/// A small acquisition's light transport through the twin's landing and footprint kernels equals the CPU
/// renderer's plane by plane (footprints, f32 weights, ray counts — evanescent ones included), in f64 and in
/// f32, where the kernels now model more: a toroid, gratings (the `gsp` preset; a plane grating whose first
/// order is evanescent over part of the beam at 650 nm) and objects at infinity (the singlet of tests/common and
/// the Cassegrain, `scene_fov_deg`).
#[test]
fn plane_transport_through_the_twin_equals_the_cpu_renderer_on_toroids_gratings_and_at_infinity() {
    use diffcassi::render::{Mask, RenderConfig, Renderer};
    let build = |spec: diffcassi::spec::SystemSpec| SequentialSystem::build(&spec).unwrap();
    // (name, system, scene_fov_deg at infinity, detector pitch: coarse where the diffracted beam lands ~100 mm off axis)
    let cases = [
        ("toroid (builder)", build(crate::surfaces::toroid_lens(Some(35.0))), None, None),
        ("gsp", system("gsp"), None, None),
        ("plane grating 1.5/µm (builder)", build(crate::surfaces::plane_grating(1.5, 1)), None, Some(0.5)),
        ("singlet at infinity", build(crate::common::singlet_at_infinity(false)), Some(0.5), None),
        ("cassegrain_mirrors_HoO_V2C18Ex03.zmx", zmx_system("cassegrain_mirrors_HoO_V2C18Ex03.zmx"), Some(0.2), None),
    ];
    let tracer = AnalyticTracer::default();
    let mut evanescent = 0;
    for (name, sys, fov_deg, det_pitch_mm) in &cases {
        let (h, w) = (10, 12);
        for precision in [Precision::F64, Precision::F32] {
            let mut config = RenderConfig::paper(w);
            config.scene_height = h;
            config.scene_pitch_mm = 0.15;
            config.scene_fov_deg = *fov_deg;
            if let Some(p) = det_pitch_mm {
                config.detector_pitch_mm = *p;
            }
            config.rays_per_pixel = 6;
            config.spectral = diffcassi::render::SpectralSampling::new(vec![450.0, 650.0], 2).unwrap();
            config.precision = precision;
            let r = Renderer::new(sys, &tracer, config, Mask::random(h, w, 0.6, 7).unwrap()).unwrap_or_else(|e| panic!("{name}: {e}"));
            let ctx = r.plane_context();
            let mut arrived = 0;
            for (p, &wl) in r.config.spectral.planes_nm.iter().enumerate() {
                let cpu = ctx.trace_plane(p, wl).unwrap();
                let twin = diffcassi::render::twin::trace_plane(&ctx, p, wl).unwrap();
                assert_eq!(twin.footprints, cpu.footprints, "{name} {precision} plane {p}: footprints");
                assert_eq!(twin.weights.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), cpu.weights.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), "{name} {precision} plane {p}: weights");
                assert_eq!(twin.stats, cpu.stats, "{name} {precision} plane {p}: ray counts");
                arrived += cpu.stats.arrived;
                evanescent += cpu.stats.evanescent;
            }
            assert!(arrived > 0, "{name} {precision}: no ray arrived");
        }
    }
    assert!(evanescent > 0, "no evanescent ray in the grating renders");
}

// ---- The coded mask on a surface inside the system (dual-disperser CASSI: `ddsp`, `mddsp`) -------------------

/// `ddsp` or `mddsp` with its coded mask sampled `sampling` (nearest is the presets').
pub(crate) fn dual_disperser(name: &str, sampling: diffcassi::spec::MaskSampling) -> SequentialSystem {
    let mut spec = presets::spec(name).unwrap();
    spec.surfaces.iter_mut().find_map(|s| s.coded_mask.as_mut()).expect("a mask surface").sampling = sampling;
    SequentialSystem::build(&spec).unwrap()
}

/// An `h × w` mask of graded transmissions in (0.25, 1] with closed pixels (40 %), from `seed`: bilinear sampling
/// interpolates between unequal values, and rays crossing a closed pixel are `masked`.
pub(crate) fn graded_mask(h: usize, w: usize, seed: u64) -> diffcassi::render::Mask {
    let open = diffcassi::render::Mask::random(h, w, 0.6, seed).unwrap();
    let values = open.values.iter().enumerate().map(|(q, &v)| v * (0.25 + 0.75 * ((q * 37 % 101) as f32 / 100.0))).collect();
    diffcassi::render::Mask { values, description: "graded".into(), ..open }
}

/// Every (system, sampling) of the dual-disperser tests.
fn dual_dispersers() -> Vec<(String, SequentialSystem)> {
    use diffcassi::spec::MaskSampling;
    let mut out = Vec::new();
    for name in ["ddsp", "mddsp"] {
        for sampling in [MaskSampling::Nearest, MaskSampling::Bilinear] {
            out.push((format!("{name} {sampling:?}"), dual_disperser(name, sampling)));
        }
    }
    out
}

/// The trace kernels on `ddsp` and `mddsp`: the mask surface is a plain step of the trace (a thin plate in air), so
/// the f64 twin equals the scalar kernel and the f32 twin the f32 lane kernel bit for bit, as on the other presets.
#[test]
fn trace_kernel_twins_equal_the_cpu_kernels_on_the_dual_disperser_presets() {
    for name in ["ddsp", "mddsp"] {
        let sys = system(name);
        let rays = full_batch(&sys);
        assert_bits(&format!("{name} f64"), &TwinTracer::default().trace(&sys, &rays).unwrap(), &scalar().trace(&sys, &rays).unwrap());
        let twin32 = TwinTracer::f32().trace(&sys, &rays).unwrap();
        for level in SimdLevel::available() {
            assert_bits(&format!("{name} f32 {}", level.name()), &twin32, &AnalyticF32Tracer::new(level).trace(&sys, &rays).unwrap());
        }
    }
}

/// The landing kernel through a coded-mask surface against the renderer's steps composed in Rust: the landings
/// of [`rust_landings`] and each ray's weight — where its object ray crosses the mask surface
/// (`SequentialSystem::point_on_mask`: the first arm of the path, `trace_steps(path[..=step])`) read by
/// `MaskSurface::transmission` (nearest or bilinear), 0 where it stops before — bit for bit, on `ddsp` and
/// `mddsp`, over a scene that reaches past the field (rays vignetted before and after the mask) and past the mask
/// (its opaque frame).
#[test]
fn landing_kernel_twin_weights_rays_by_the_mask_surface_as_the_renderer() {
    use diffcassi::render::{RenderConfig, Renderer};
    let tracer = AnalyticTracer::default();
    let (h, w) = (12, 16);
    for (name, sys) in dual_dispersers() {
        let m = sys.coded_mask.unwrap();
        let mut config = RenderConfig::paper(w);
        config.scene_height = h;
        config.rays_per_pixel = 5;
        config.spectral = diffcassi::render::SpectralSampling::new(vec![500.0, 560.0], 1).unwrap();
        let mask = graded_mask(h, w, 3);
        let mut r = Renderer::new(&sys, &tracer, config, mask.clone()).unwrap();
        let (mut arrived, mut masked, mut before, mut fractional) = (0, 0, 0, 0);
        // The renderer's pitch (10 µm: the mask's pixels), then 0.4 mm (a scene ±3.2 mm wide, far past the 12 × 16
        // mask's 0.12 × 0.16 mm: its opaque frame) and 20 mm (±160 mm: rays that miss the first arm's surfaces,
        // before the mask), changed after the renderer checked the beam.
        for pitch_mm in [0.01, 0.4, 20.0] {
            r.config.scene_pitch_mm = pitch_mm;
            let ctx = r.plane_context();
            let pixels: Vec<u32> = (0..(h * w) as u32).collect();
            let scene = SceneGeometry { height: h, width: w, pitch_mm, detector: &r.detector };
            for (p, &wl) in r.config.spectral.planes_nm.iter().enumerate() {
                let twin = diffcassi::render::twin::plane_landings_of(&ctx, p as u64, wl, &pixels).unwrap();
                let (u, v, status) = rust_landings(&sys, scene, ctx.sampler, ctx.seed, p as u64, wl, &pixels);
                assert_eq!(twin.status, status, "{name} {pitch_mm} plane {p}: statuses");
                let mut t = 0;
                let mut s = vec![[0.0; 4]; ctx.sampler.rays];
                for &q in &pixels {
                    ctx.sampler.fill(ctx.seed, p as u64, q as u64, &mut s);
                    let c = MappingCube::scene_xy(h, w, pitch_mm, q as usize / w, q as usize % w);
                    for smp in &s {
                        let field = [c[0] + (smp[2] - 0.5) * pitch_mm, c[1] - (smp[3] - 0.5) * pitch_mm];
                        let weight = match sys.point_on_mask(field, [smp[0], smp[1]], wl).unwrap() {
                            Some((x, y)) => m.transmission(&mask.values, h, w, x, y),
                            None => {
                                before += 1;
                                0.0
                            }
                        };
                        let label = format!("{name} {pitch_mm} plane {p} ray {t}");
                        assert_eq!(twin.weight[t].to_bits(), weight.to_bits(), "{label}: weight {} vs {weight}", twin.weight[t]);
                        assert_eq!((twin.u[t].to_bits(), twin.v[t].to_bits()), (u[t].to_bits(), v[t].to_bits()), "{label}");
                        if status[t] == RayStatus::Ok {
                            arrived += 1;
                            masked += (weight == 0.0) as usize;
                        }
                        fractional += (weight > 0.0 && weight < 1.0 && mask.values.iter().all(|&v| v != weight as f32)) as usize;
                        t += 1;
                    }
                }
            }
        }
        println!("{name}: {arrived} arrived, {masked} of them masked, {before} stopped before the mask, {fractional} interpolated weights");
        assert!(arrived > masked && masked > 0 && before > 0, "{name}: {arrived} arrived, {masked} masked, {before} stopped before the mask");
        assert_eq!(fractional > 0, m.sampling == diffcassi::spec::MaskSampling::Bilinear, "{name}: interpolated weights only when bilinear");
    }
}

/// The plane transport through the twin's landing and footprint kernels equals the CPU renderer's
/// (`trace_through_mask`, the lanes split at the mask's step) on `ddsp` and `mddsp`, nearest and bilinear: the
/// same footprints, f32 weights and ray counts (`masked` included), bit for bit, on a full detector and on one
/// that clips the windows at its edges (weight lost off the detector, in rays × transmission). (f64 only: the CPU
/// renderer does not model a mask surface in f32, and refuses it.)
#[test]
fn plane_transport_through_the_twin_equals_the_cpu_renderer_through_a_mask_surface() {
    use diffcassi::render::transport::PlaneContext;
    use diffcassi::render::{RenderConfig, Renderer};
    let tracer = AnalyticTracer::default();
    let (h, w) = (12, 16);
    for (name, sys) in dual_dispersers() {
        let mut config = RenderConfig::paper(w);
        config.scene_height = h;
        config.rays_per_pixel = 6;
        config.spectral = diffcassi::render::SpectralSampling::new(vec![480.0, 520.0, 580.0], 2).unwrap();
        let r = Renderer::new(&sys, &tracer, config, graded_mask(h, w, 7)).unwrap();
        let full = r.detector;
        let cropped = Detector { width: full.width * 2 / 5, height: full.height / 2, ..full };
        let base = r.plane_context();
        let (mut masked, mut arrived, mut lost) = (0, 0, 0.0);
        for detector in [&full, &cropped] {
            let ctx = PlaneContext { detector, ..base };
            for (p, &wl) in r.config.spectral.planes_nm.iter().enumerate() {
                let cpu = ctx.trace_plane(p, wl).unwrap();
                let twin = diffcassi::render::twin::trace_plane(&ctx, p, wl).unwrap();
                assert_eq!(twin.footprints, cpu.footprints, "{name} plane {p}: footprints");
                assert_eq!(twin.weights.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), cpu.weights.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), "{name} plane {p}: weights");
                assert_eq!(twin.stats, cpu.stats, "{name} plane {p}: ray counts");
                masked += cpu.stats.masked;
                arrived += cpu.stats.arrived;
                lost += cpu.stats.off_detector;
            }
        }
        // (Most of each band's dispersed image falls beside the 12 × 16 mask: masked rays outnumber the others.)
        assert!(masked > 0 && arrived > 0, "{name}: {arrived} arrived, {masked} masked");
        assert!(lost > 0.0 && lost.fract() != 0.0, "{name}: weight lost off the cropped detector {lost} (in rays × transmission)");
    }
}

/// A system whose mask surface has no pattern given is refused by the landing function without a renderer, naming
/// the one that takes it.
#[test]
fn landing_kernel_asks_for_the_mask_of_a_mask_surface() {
    let detector = Detector { width: 10, height: 10, pitch_mm: 0.01, x_left_mm: -0.05, y_top_mm: 0.05 };
    let scene = SceneGeometry { height: 2, width: 2, pitch_mm: 0.01, detector: &detector };
    let e = plane_landings(&system("ddsp"), scene, &RaySampler::new(2, Sampling::Stratified), 0, 0, 550.0, &[0]).err().expect("a mask surface without its pattern").to_string();
    assert!(e.contains("coded mask on surface 19") && e.contains("plane_landings_of"), "{e}");
}

// ---- The highest asphere and toroid terms ------------------------------------------------------------------

/// An even asphere and a toroid with every term the spec allows (`asphere_coefficients`: 8, r² … r¹⁶ and
/// y² … y¹⁶; `DC_MAX_COEF`), the r¹⁶ (y¹⁶) term significant across the beam, through the trace kernels: the f64
/// twin equals the scalar kernel and the f32 twin the f32 lane kernel bit for bit; a ninth term is refused by the
/// spec itself, so no system the CPU traces has more.
#[test]
fn trace_kernel_twins_take_every_asphere_and_toroid_term_the_spec_allows() {
    use diffcassi::spec::{Cell, SurfaceKind, SurfaceSpec};
    // r^{2i}: at r = 4 mm each term moves the sag by 0.5–9 µm; the last (2e-12 · 4¹⁶ ≈ 8.6 µm) most.
    let coef: Vec<Cell> = [1e-4, -2e-6, 1e-7, -1e-8, 1e-9, -1e-10, 1e-11, 2e-12].into_iter().map(Cell::fixed).collect();
    let mut asphere = SurfaceSpec::standard(Some(20.0), 5.0, Some("N-BK7"));
    asphere.kind = SurfaceKind::EvenAsphere;
    asphere.asphere_coefficients = coef.clone();
    asphere.stop = true;
    let lens = crate::surfaces::system("asphere8", vec![SurfaceSpec::standard(None, 80.0, None), asphere, SurfaceSpec::standard(None, 40.0, None), SurfaceSpec::standard(None, 0.0, None)], 0.05);
    let mut toroid = crate::surfaces::toroid_lens(Some(35.0));
    toroid.surfaces[1].asphere_coefficients = coef.clone();
    for spec in [lens, toroid] {
        let name = spec.name.clone();
        let sys = SequentialSystem::build(&spec).unwrap();
        let rays = wide_batch(&sys);
        let rust = scalar().trace(&sys, &rays).unwrap();
        assert_bits(&format!("{name} f64"), &TwinTracer::default().trace(&sys, &rays).unwrap(), &rust);
        let twin32 = TwinTracer::f32().trace(&sys, &rays).unwrap();
        for level in SimdLevel::available() {
            assert_bits(&format!("{name} f32 {}", level.name()), &twin32, &AnalyticF32Tracer::new(level).trace(&sys, &rays).unwrap());
        }
        // The last term matters: without it the rays land elsewhere.
        let mut seven = spec.clone();
        seven.surfaces[1].asphere_coefficients.truncate(7);
        let other = scalar().trace(&SequentialSystem::build(&seven).unwrap(), &rays).unwrap();
        let moved = (0..rays.len()).filter(|&i| rust.status[i] == RayStatus::Ok && other.status[i] == RayStatus::Ok && (rust.x[i] - other.x[i]).abs().max((rust.y[i] - other.y[i]).abs()) > 1e-6).count();
        let ok = rust.status.iter().filter(|&&s| s == RayStatus::Ok).count();
        assert!(moved > ok / 4, "{name}: the r¹⁶ term moves only {moved} of {ok} landings by > 1 nm");
        let mut nine = spec.clone();
        nine.surfaces[1].asphere_coefficients.push(Cell::fixed(1e-14));
        let e = SequentialSystem::build(&nine).err().expect("a ninth term refused").to_string();
        assert!(e.contains("at most 8"), "{e}");
    }
}

/// `sys` with ray aiming set (OpticStudio's RAIM: `paraxial` aims at the paraxial stop radius, `real` at the
/// real marginal ray's height at the stop).
fn aimed(spec: &diffcassi::spec::SystemSpec, aiming: diffcassi::spec::RayAiming) -> SequentialSystem {
    let mut spec = spec.clone();
    spec.ray_aiming = aiming;
    SequentialSystem::build(&spec).unwrap()
}

/// The systems of the ray-aiming tests: SP (the stop inside the prism train, finite object) and the singlet at
/// infinity of tests/common (the stop behind the lens), each aimed `paraxial` and `real`, with a scene pitch
/// (mm, or rad at infinity) inside their fields.
fn aimed_systems() -> Vec<(String, SequentialSystem, f64)> {
    use diffcassi::spec::RayAiming;
    let mut out = Vec::new();
    for aiming in [RayAiming::Paraxial, RayAiming::Real] {
        out.push((format!("sp {aiming:?}"), aimed(&presets::spec("sp").unwrap(), aiming), 0.25));
        out.push((format!("singlet at infinity {aiming:?}"), aimed(&crate::common::singlet_at_infinity(false), aiming), 0.004));
    }
    out
}

/// The renderer's steps with ray aiming, composed from the library's Rust pieces: the sampler, the jittered
/// field point (`PlaneContext::ray`), `rays::aimed_ray`, the scalar trace and the detector coordinates; the
/// first failed aim's error instead, as the renderer (its rays in this order).
fn rust_landings_aimed(sys: &SequentialSystem, scene: SceneGeometry<'_>, sampler: &RaySampler, seed: u64, plane: u64, wl: f64, pixels: &[u32]) -> Result<(Vec<f64>, Vec<f64>, Vec<RayStatus>), String> {
    let n = sys.indices(wl).unwrap();
    landings_of_rays(sys, scene, sampler, seed, plane, wl, pixels, |field, px, py| diffcassi::rays::aimed_ray(sys, &n, field, px, py).map_err(|e| e.to_string()))
}

/// The landing kernel with ray aiming `paraxial` and `real` (`dc_aimed_ray`: rays::aimed_ray's Newton solve
/// on the stop, finite object and at infinity) equals the renderer's steps composed in Rust bit for bit, and
/// the aimed rays are not the unaimed ones (the aim moves them).
#[test]
fn landing_kernel_twin_equals_the_renderers_steps_with_ray_aiming() {
    let detector = Detector { width: 700, height: 700, pitch_mm: 0.01, x_left_mm: -3.5, y_top_mm: 3.5 };
    for (name, sys, pitch) in aimed_systems() {
        let scene = SceneGeometry { height: 8, width: 10, pitch_mm: pitch, detector: &detector };
        let pixels: Vec<u32> = (0..80).filter(|q| q % 3 != 1).collect();
        let mut off_spec = sys.spec.clone();
        off_spec.ray_aiming = diffcassi::spec::RayAiming::Off;
        let off = SequentialSystem::build(&off_spec).unwrap();
        let mut moved = 0;
        for (rays, mode, seed, plane) in [(6, Sampling::Stratified, 5u64, 2u64), (3, Sampling::Independent, 77, 13)] {
            let sampler = RaySampler::new(rays, mode);
            let wl = 480.0;
            let twin = plane_landings(&sys, scene, &sampler, seed, plane, wl, &pixels).unwrap_or_else(|e| panic!("{name}: {e}"));
            let (u, v, status) = rust_landings_aimed(&sys, scene, &sampler, seed, plane, wl, &pixels).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert_eq!(twin.status, status, "{name} {rays} {mode:?}: statuses");
            for i in 0..u.len() {
                assert_eq!((twin.u[i].to_bits(), twin.v[i].to_bits()), (u[i].to_bits(), v[i].to_bits()), "{name} {rays} {mode:?} ray {i}: ({}, {}) vs ({}, {})", twin.u[i], twin.v[i], u[i], v[i]);
            }
            assert!(status.iter().filter(|&&s| s == RayStatus::Ok).count() * 2 > status.len(), "{name}: most rays must arrive");
            let unaimed = plane_landings(&off, scene, &sampler, seed, plane, wl, &pixels).unwrap();
            moved += (0..u.len()).filter(|&i| !u[i].is_nan() && !unaimed.u[i].is_nan() && (u[i] != unaimed.u[i] || v[i] != unaimed.v[i])).count();
        }
        assert!(moved > 0, "{name}: aiming moved no ray");
    }
}

/// A plane's light transport with ray aiming through the twin equals the CPU renderer's (footprints, f32
/// weights, ray counts), in f64 and in f32 (the renderer aims in f64, then traces the aimed ray in f32; so do
/// the kernels).
#[test]
fn plane_transport_through_the_twin_equals_the_cpu_renderer_with_ray_aiming() {
    use diffcassi::render::{Mask, RenderConfig, Renderer};
    let tracer = AnalyticTracer::default();
    for (name, sys, pitch) in aimed_systems() {
        let (h, w) = (8, 10);
        let mut weights_by_precision = Vec::new();
        for precision in [Precision::F64, Precision::F32] {
            let mut config = RenderConfig::paper(w);
            config.scene_height = h;
            if sys.object_at_infinity() {
                config.scene_fov_deg = Some((pitch * w as f64).to_degrees());
            } else {
                config.scene_pitch_mm = pitch;
            }
            config.rays_per_pixel = 5;
            config.spectral = diffcassi::render::SpectralSampling::new(vec![450.0, 650.0], 2).unwrap();
            config.precision = precision;
            let r = Renderer::new(&sys, &tracer, config, Mask::random(h, w, 0.6, 7).unwrap()).unwrap_or_else(|e| panic!("{name}: {e}"));
            let ctx = r.plane_context();
            let mut arrived = 0;
            let mut weights = Vec::new();
            for (p, &wl) in r.config.spectral.planes_nm.iter().enumerate() {
                let cpu = ctx.trace_plane(p, wl).unwrap_or_else(|e| panic!("{name}: {e}"));
                let twin = diffcassi::render::twin::trace_plane(&ctx, p, wl).unwrap();
                assert_eq!(twin.footprints, cpu.footprints, "{name} {precision} plane {p}: footprints");
                assert_eq!(twin.weights.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), cpu.weights.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), "{name} {precision} plane {p}: weights");
                assert_eq!(twin.stats, cpu.stats, "{name} {precision} plane {p}: ray counts");
                arrived += cpu.stats.arrived;
                weights.extend(cpu.weights);
            }
            assert!(arrived > 0, "{name} {precision}: no ray arrived");
            weights_by_precision.push(weights);
        }
        // The f32 transport is not the f64 one (the f32 comparison above is not the f64 one again).
        assert_ne!(weights_by_precision[0], weights_by_precision[1], "{name}: f32 and f64 transports are identical");
    }
}

/// Where ray aiming fails for some rays (the singlet at infinity of tests/common under a scene 179.8° wide: field
/// angles up to ~84°, whose rays cannot reach the stop), the CPU renderer stops with an error naming the first
/// such ray; the twin gives the same error, word for word — from the landing kernel, and from the plane transport
/// in f64 and f32.
#[test]
fn the_twin_fails_where_ray_aiming_fails_with_the_cpu_renderers_error() {
    use diffcassi::render::transport::PlaneContext;
    use diffcassi::render::{Mask, RenderConfig, Renderer};
    let tracer = AnalyticTracer::default();
    let wide_rad = 179.8f64.to_radians() / 12.0;
    for aiming in [diffcassi::spec::RayAiming::Paraxial, diffcassi::spec::RayAiming::Real] {
        let sys = aimed(&crate::common::singlet_at_infinity(false), aiming);
        let detector = Detector { width: 600, height: 600, pitch_mm: 0.05, x_left_mm: -15.0, y_top_mm: 15.0 };
        let scene = SceneGeometry { height: 10, width: 12, pitch_mm: wide_rad, detector: &detector };
        let pixels: Vec<u32> = (0..120).collect();
        let sampler = RaySampler::new(3, Sampling::Stratified);
        let want = rust_landings_aimed(&sys, scene, &sampler, 1, 4, 520.0, &pixels).err().expect("aiming must fail for some rays");
        let got = plane_landings(&sys, scene, &sampler, 1, 4, 520.0, &pixels).err().expect("the twin must fail too").to_string();
        assert_eq!(got, want, "{aiming:?}");
        assert!(got.contains("ray aiming failed"), "{got}");
        // The pixels near the axis aim: the same rays, bit for bit, where all of them succeed.
        let near: Vec<u32> = vec![4 * 12 + 5, 4 * 12 + 6, 5 * 12 + 5, 5 * 12 + 6];
        let twin = plane_landings(&sys, scene, &sampler, 1, 4, 520.0, &near).unwrap();
        let (u, v, status) = rust_landings_aimed(&sys, scene, &sampler, 1, 4, 520.0, &near).unwrap();
        assert_eq!(twin.status, status, "{aiming:?} near the axis");
        assert_eq!(twin.u.iter().chain(&twin.v).map(|x| x.to_bits()).collect::<Vec<_>>(), u.iter().chain(&v).map(|x| x.to_bits()).collect::<Vec<_>>(), "{aiming:?} near the axis");
        let mut config = RenderConfig::paper(12);
        config.scene_height = 10;
        config.scene_fov_deg = Some(0.5);
        config.rays_per_pixel = 3;
        config.spectral = diffcassi::render::SpectralSampling::new(vec![450.0, 650.0], 1).unwrap();
        let r = Renderer::new(&sys, &tracer, config, Mask::random(10, 12, 0.6, 7).unwrap()).unwrap();
        for precision in [Precision::F64, Precision::F32] {
            let ctx = PlaneContext { scene_pitch_mm: wide_rad, precision, ..r.plane_context() };
            for (p, &wl) in r.config.spectral.planes_nm.iter().enumerate() {
                let cpu = ctx.trace_plane(p, wl).err().expect("the CPU renderer must fail").to_string();
                let twin = diffcassi::render::twin::trace_plane(&ctx, p, wl).err().expect("the twin must fail").to_string();
                assert_eq!(twin, cpu, "{aiming:?} {precision} plane {p}");
            }
        }
    }
}
