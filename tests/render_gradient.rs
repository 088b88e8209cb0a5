//! The differentiable acquisition (`render::gradient`): vector–Jacobian products against central finite
//! differences of the same-sample acquisition for every parameter kind on SP, AP, mSP, mAP; against
//! finite differences of a many-ray expected image (the boundary bias included); scene and mask gradients
//! (the acquisition is linear in both); thread-count independence; the mapping cube's Jacobian; bad input.
//!
//! `cargo test --release --test integration render_gradient:: -- --nocapture` prints the measured errors.
use crate::common;
use common::{ap_like, sp_like};
use diffcassi::diff::{Param, ParamSet};
use diffcassi::materials::GlassCatalog;
use diffcassi::render::gradient::DiffRenderer;
use diffcassi::render::{RenderConfig, SpectralSampling};
use diffcassi::spec::SystemSpec;

/// A small deterministic generator (xorshift) for scenes, masks and upstream gradients.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
    fn vec(&mut self, n: usize) -> Vec<f64> {
        (0..n).map(|_| self.next()).collect()
    }
}

const BANDS: [f64; 3] = [450.0, 550.0, 650.0];

fn config(size: usize, planes: usize, rays: usize, seed: u64) -> RenderConfig {
    let mut cfg = RenderConfig::paper(size);
    cfg.spectral = SpectralSampling::with_planes(BANDS.to_vec(), planes).unwrap();
    cfg.rays_per_pixel = rays;
    cfg.seed = seed;
    cfg
}

fn renderer(spec: SystemSpec, free: &[&str], cfg: RenderConfig) -> DiffRenderer {
    let params: Vec<Param> = free.iter().map(|t| Param::parse(t).unwrap()).collect();
    let set = ParamSet::new(spec, GlassCatalog::builtin(), params).unwrap();
    DiffRenderer::new(set, cfg, BANDS.to_vec()).unwrap()
}

/// Scene (N = 2), mask (some pixels closed, the others in (0, 1]) and an upstream gradient.
fn inputs(r: &DiffRenderer, seed: u64) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15 ^ seed);
    let hw = r.config.scene_height * r.config.scene_width;
    let scene = rng.vec(2 * BANDS.len() * hw);
    let mask: Vec<f64> = rng.vec(hw).into_iter().map(|v| if v < 0.25 { 0.0 } else { v }).collect();
    let (h, w) = r.image_shape();
    let g: Vec<f64> = rng.vec(2 * h * w).into_iter().map(|v| v - 0.5).collect();
    (scene, mask, g)
}

fn loss(r: &DiffRenderer, scene: &[f64], mask: &[f64], g: &[f64]) -> f64 {
    r.render(scene, 2, mask).unwrap().iter().zip(g).map(|(a, b)| a * b).sum()
}

/// A step that moves landings by ~1e-4 pixel (so that few rays cross a pixel edge or change status).
fn step_for(p: &Param) -> f64 {
    match p {
        Param::Cell { column, .. } if column.ends_with("_deg") => 1e-6,
        Param::Cell { column, .. } if column == "conic" => 1e-5,
        Param::Cell { column, .. } if column.starts_with("asphere_") => 1e-9,
        Param::Cell { .. } => 1e-6,
        Param::Curvature { .. } => 1e-8,
        Param::GlassNd(_) => 1e-7,
        Param::GlassVd(_) => 1e-7,
        _ => unreachable!(),
    }
}

/// Central finite differences of the same-sample loss for every parameter, against the VJP; returns the
/// largest relative error (|fd − vjp| / max(|vjp|, 1e-3 · max_k |vjp_k|)).
fn check_same_sample(label: &str, spec: SystemSpec, free: &[&str]) -> f64 {
    check_same_sample_with(label, spec, free, config(5, 3, 2, 7))
}

/// [`check_same_sample`] with the render settings `cfg` (e.g. an angular extent for an object at infinity).
fn check_same_sample_with(label: &str, spec: SystemSpec, free: &[&str], cfg: RenderConfig) -> f64 {
    let r = renderer(spec, free, cfg);
    let (scene, mask, g) = inputs(&r, 1);
    let v = r.vjp(&scene, 2, &mask, &g).unwrap();
    let x0 = r.values().unwrap();
    let scale = v.params.iter().fold(0.0f64, |a, b| a.max(b.abs()));
    let mut worst = 0.0f64;
    for k in 0..x0.len() {
        let h = step_for(&r.set.free[k]) * x0[k].abs().max(1.0);
        let at = |d: f64| {
            let mut x = x0.clone();
            x[k] += d;
            loss(&r.with_values(&x).unwrap(), &scene, &mask, &g)
        };
        let fd = (at(h) - at(-h)) / (2.0 * h);
        let err = (fd - v.params[k]).abs() / v.params[k].abs().max(1e-3 * scale);
        println!("{label} {:>18}: vjp {:+.9e}  fd {:+.9e}  rel {:.1e}", r.set.free[k].name(), v.params[k], fd, err);
        worst = worst.max(err);
    }
    println!("{label}: worst relative error {worst:.2e} over {} parameters", x0.len());
    worst
}

#[test]
fn vjp_matches_same_sample_finite_differences_sp_and_msp() {
    assert!(check_same_sample("sp", sp_like("sp"), &common::SP_LIKE_PARAMS) <= 1e-6);
    assert!(check_same_sample("msp", sp_like("msp"), &common::SP_LIKE_PARAMS) <= 1e-6);
}

#[test]
fn vjp_matches_same_sample_finite_differences_ap_and_map() {
    assert!(check_same_sample("ap", ap_like("ap", 4), &common::AP_LIKE_PARAMS) <= 1e-6);
    assert!(check_same_sample("map", ap_like("map", 6), &common::MAP_LIKE_PARAMS) <= 1e-6);
}

/// The acquisition is linear in the scene and in the mask: L(x + δ) − L(x) = ∂L/∂x · δ exactly (up to
/// rounding), and by homogeneity L = ∂L/∂x · x.
#[test]
fn scene_and_mask_gradients_are_exact() {
    let r = renderer(sp_like("msp"), &["s4.tilt_x_deg"], config(5, 3, 2, 3));
    let (scene, mask, g) = inputs(&r, 2);
    let v = r.vjp(&scene, 2, &mask, &g).unwrap();
    let l0 = loss(&r, &scene, &mask, &g);
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    let close = |a: f64, b: f64, what: &str| {
        let rel = (a - b).abs() / a.abs().max(b.abs());
        println!("{what}: {a:+.15e} vs {b:+.15e} (rel {rel:.1e})");
        assert!(rel < 1e-12, "{what}: {a} vs {b}");
    };
    close(l0, dot(&v.scene, &scene), "L vs ∂L/∂scene · scene");
    close(l0, dot(&v.mask, &mask), "L vs ∂L/∂mask · mask");
    let mut rng = Rng(5);
    let ds: Vec<f64> = rng.vec(scene.len()).into_iter().map(|x| x - 0.5).collect();
    let s2: Vec<f64> = scene.iter().zip(&ds).map(|(a, b)| a + b).collect();
    close(loss(&r, &s2, &mask, &g) - l0, dot(&v.scene, &ds), "ΔL vs ∂L/∂scene · δ");
    // Opening closed pixels too: their gradient is there although they carry no light.
    let dm: Vec<f64> = rng.vec(mask.len());
    let m2: Vec<f64> = mask.iter().zip(&dm).map(|(a, b)| a + b).collect();
    close(loss(&r, &scene, &m2, &g) - l0, dot(&v.mask, &dm), "ΔL vs ∂L/∂mask · δ");
    assert!(mask.iter().zip(&v.mask).any(|(m, gm)| *m == 0.0 && gm.abs() > 0.0), "closed pixels get a gradient");
}

/// Bit-identical for 1 and 2 threads.
#[test]
fn vjp_does_not_depend_on_the_thread_count() {
    let r = renderer(sp_like("msp"), &["s4.tilt_x_deg", "s16.curvature", "glass_nd:N-BK7"], config(6, 4, 3, 11));
    let (scene, mask, g) = inputs(&r, 3);
    let run = |t: usize| {
        rayon::ThreadPoolBuilder::new().num_threads(t).build().unwrap().install(|| (r.render(&scene, 2, &mask).unwrap(), r.vjp(&scene, 2, &mask, &g).unwrap()))
    };
    let (a, b) = (run(1), run(2));
    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&a.0), bits(&b.0));
    assert_eq!(bits(&a.1.params), bits(&b.1.params));
    assert_eq!(bits(&a.1.mask), bits(&b.1.mask));
    assert_eq!(bits(&a.1.scene), bits(&b.1.scene));
    // Every ray goes through the SIMD lanes by default (closed pixels and `render`: the production lanes;
    // open pixels: the recording lanes): landings bit for bit the scalar kernel's (on this system with an
    // even asphere at s16, too), so the image and the mask and scene gradients are identical.
    let mut cfg = r.config.clone();
    cfg.kernel = diffcassi::tracer::Kernel::Scalar;
    let scalar = DiffRenderer::new(r.set.clone(), cfg, BANDS.to_vec()).unwrap();
    let differ = |x: &[f64], y: &[f64]| x.iter().zip(y).filter(|(p, q)| p.to_bits() != q.to_bits()).count();
    let image = scalar.render(&scene, 2, &mask).unwrap();
    assert_eq!(differ(&image, &a.0), 0, "render: entries of the SIMD-lane image that differ from the scalar kernel's");
    let v = scalar.vjp(&scene, 2, &mask, &g).unwrap();
    // Open rays: the lanes' reverse sweep vs the scalar one — the same per-ray numbers, summed in another
    // order (lane by lane, then across lanes).
    let scale = v.params.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    let worst = v.params.iter().zip(&a.1.params).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max) / scale;
    println!("parameter gradient, SIMD lanes vs scalar kernel: {worst:.1e} relative to the largest entry");
    assert!(worst <= 1e-12, "parameter gradient: lanes vs scalar sweep {worst:e}");
    assert_eq!(differ(&v.mask, &a.1.mask), 0, "mask gradient: entries that differ between SIMD lanes and scalar kernel");
    assert_eq!(differ(&v.scene, &a.1.scene), 0, "scene gradient: entries that differ between SIMD lanes and scalar kernel");
}

/// The hand-written reverse sweep of `diff::adjoint` (one backward pass per ray) equals the forward tangent
/// kernel (`DiffSystem::trace`, one tangent column per parameter) ray by ray, to 1e-12 relative to the
/// gradient's largest entry, for every parameter kind of SP and mSP and a random λ on the landing's
/// position and direction; rays over the whole field and pupil, three wavelengths.
#[test]
fn adjoint_sweep_equals_the_forward_tangents() {
    use diffcassi::diff::adjoint::{AdjointPlan, AdjointSums, RayTape};
    use diffcassi::rays::{PupilAim, RayBatch};
    use glam::DVec3;
    let mut rng = Rng(5);
    for name in ["sp", "msp"] {
        let params: Vec<Param> = common::SP_LIKE_PARAMS.iter().map(|t| Param::parse(t).unwrap()).collect();
        let ds = ParamSet::new(sp_like(name), GlassCatalog::builtin(), params).unwrap().build().unwrap();
        let aim = PupilAim::of(&ds.system);
        let (mut worst, mut rays) = (0.0f64, 0);
        for w in [450.0, 550.0, 650.0] {
            let plan = AdjointPlan::new(&ds, &[w]).unwrap();
            let (n, dn) = ds.index_tangents(w).unwrap();
            let mut tape = RayTape::default();
            for _ in 0..40 {
                let (fx, fy) = (2.0 * rng.next() - 1.0, 2.0 * rng.next() - 1.0);
                let d = DVec3::from(aim.direction(fx, fy, 2.0 * rng.next() - 1.0, 2.0 * rng.next() - 1.0)).normalize();
                let o = DVec3::new(fx, fy, 0.0);
                let mut batch = RayBatch::with_capacity(1);
                batch.push(o, d, w);
                let j = ds.trace(&batch).unwrap();
                if !j.usable(0) || plan.trace(&ds, &n, o, d, &mut tape).is_err() {
                    continue;
                }
                let lambda: [f64; 6] = std::array::from_fn(|_| rng.next() - 0.5);
                let mut sums = AdjointSums::new(&plan);
                assert!(plan.backward(&ds, &mut tape, lambda, &mut sums));
                let mut grad = vec![0.0; ds.k()];
                plan.contract(&ds, &sums, &dn, &mut grad);
                let reference: Vec<f64> = (0..ds.k())
                    .map(|k| {
                        let (dp, dd) = (j.d_position(0, k), j.d_direction(0, k));
                        lambda[0] * dp.x + lambda[1] * dp.y + lambda[2] * dp.z + lambda[3] * dd.x + lambda[4] * dd.y + lambda[5] * dd.z
                    })
                    .collect();
                let scale = reference.iter().fold(0.0f64, |a, b| a.max(b.abs()));
                let err = grad.iter().zip(&reference).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max) / scale;
                worst = worst.max(err);
                rays += 1;
            }
        }
        println!("{name}: adjoint sweep vs forward tangents over {rays} rays, {} parameters: worst {worst:.1e} (relative to the largest entry)", ds.k());
        assert!(rays >= 60, "{name}: only {rays} rays arrived");
        assert!(worst <= 1e-12, "{name}: {worst:e}");
    }
}

/// The reverse sweep on the SIMD lanes (`diff::adjoint_lanes`: a block of 32 rays traced once by the
/// recording lane trace and swept backwards together) against the scalar sweep (`AdjointPlan::trace` +
/// `backward`) ray by ray, on SP, mSP and AP (every parameter kind of the acquisition tests), rays over a
/// field and pupil wider than the system passes so that blocks mix arrived, vignetted and missed rays, a
/// partial last block, a random λ on position and direction: each lane's sums contracted with the
/// parameters equal the scalar sweep's to ≤ 1e-12 relative to the largest entry; the landings and statuses
/// are the scalar kernel's bit for bit; every SIMD level (and the portable lanes) gives the same bits.
#[test]
fn lane_sweep_equals_the_scalar_sweep_ray_by_ray() {
    use diffcassi::diff::adjoint::{AdjointPlan, AdjointSums, RayTape};
    use diffcassi::diff::adjoint_lanes::LaneSums;
    use diffcassi::rays::PupilAim;
    use diffcassi::tracer::simd::lanes::{Lf, Mask};
    use diffcassi::tracer::simd::{trace_block_recording, Block, LaneTape, LANES};
    use diffcassi::tracer::SimdLevel;
    use glam::DVec3;
    let mut rng = Rng(23);
    for (name, spec, free) in [("sp", sp_like("sp"), &common::SP_LIKE_PARAMS[..]), ("msp", sp_like("msp"), &common::SP_LIKE_PARAMS[..]), ("ap", ap_like("ap", 4), &common::AP_LIKE_PARAMS[..])] {
        let params: Vec<Param> = free.iter().map(|t| Param::parse(t).unwrap()).collect();
        let ds = ParamSet::new(spec, GlassCatalog::builtin(), params).unwrap().build().unwrap();
        let aim = PupilAim::of(&ds.system);
        let (mut worst, mut compared, mut stopped) = (0.0f64, 0, 0);
        for w in [450.0, 600.0] {
            let plan = AdjointPlan::new(&ds, &[w]).unwrap();
            let (n, dn) = ds.index_tangents(w).unwrap();
            let mut tape = RayTape::default();
            // 70 rays: two full blocks and a partial one; field ±6 mm and pupil ±4 (some vignetted or missed).
            let rays: Vec<(DVec3, DVec3)> = (0..70)
                .map(|_| {
                    let (fx, fy) = (12.0 * rng.next() - 6.0, 12.0 * rng.next() - 6.0);
                    let d = DVec3::from(aim.direction(fx, fy, 8.0 * rng.next() - 4.0, 8.0 * rng.next() - 4.0)).normalize();
                    (DVec3::new(fx, fy, 0.0), d)
                })
                .collect();
            for chunk in rays.chunks(LANES) {
                let mut lambda = [Lf::splat(0.0); 6];
                for l in lambda.iter_mut() {
                    for k in 0..LANES {
                        l.0[k] = rng.next() - 0.5;
                    }
                }
                let mut reference: Option<Vec<u64>> = None;
                for level in SimdLevel::available() {
                    let (mut b, mut ltape) = (Block::default(), LaneTape::default());
                    for (k, &(o, d)) in chunk.iter().enumerate() {
                        b.set(k, o, d);
                    }
                    trace_block_recording(level, &ds.system, &[n.as_slice(); LANES], &mut b, &mut ltape);
                    let mut active = Mask::splat(false);
                    for (k, &(o, d)) in chunk.iter().enumerate() {
                        let scalar = plan.trace(&ds, &n, o, d, &mut tape);
                        assert_eq!(b.result(k), scalar, "{name} {level:?}: lane {k}'s landing vs the scalar trace");
                        active.0[k] = scalar.is_ok();
                    }
                    let mut lanes = LaneSums::new(&plan);
                    let added = plan.backward_lanes(level, &ds, &ltape, &n, &lambda, active, &mut lanes);
                    let mut grads = Vec::new();
                    for (k, &(o, d)) in chunk.iter().enumerate() {
                        let mut grad = vec![0.0; ds.k()];
                        plan.contract(&ds, &lanes.lane(&plan, k), &dn, &mut grad);
                        grads.extend(grad.iter().map(|v| v.to_bits()));
                        if plan.trace(&ds, &n, o, d, &mut tape).is_err() {
                            stopped += 1;
                            assert!(!added.0[k] && grad.iter().all(|v| *v == 0.0), "{name}: a stopped ray adds nothing");
                            continue;
                        }
                        let mut sums = AdjointSums::new(&plan);
                        let ok = plan.backward(&ds, &mut tape, std::array::from_fn(|i| lambda[i].0[k]), &mut sums);
                        assert_eq!(ok, added.0[k], "{name}: lane {k} added iff the scalar sweep adds");
                        let mut want = vec![0.0; ds.k()];
                        plan.contract(&ds, &sums, &dn, &mut want);
                        let scale = want.iter().fold(0.0f64, |a, b| a.max(b.abs()));
                        worst = worst.max(grad.iter().zip(&want).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max) / scale);
                        compared += 1;
                    }
                    match &reference {
                        None => reference = Some(grads),
                        Some(r) => assert_eq!(r, &grads, "{name}: {level:?} lanes vs the first level's bits"),
                    }
                }
            }
        }
        println!("{name}: lane sweep vs scalar sweep over {compared} ray sweeps ({stopped} stopped rays in the blocks), {} parameters: worst {worst:.1e}", ds.k());
        assert!(compared >= 60 && stopped >= 10, "{name}: {compared} arrived, {stopped} stopped");
        assert!(worst <= 1e-12, "{name}: {worst:e}");
    }
}

/// The gradient of the sampled image against central differences of a many-ray *expected* image at a
/// step large enough that rays change status (vignetting, leaving the detector) between the two sides:
/// the boundary terms the VJP leaves out are in the difference. Tilt and apex parameters on SP and mSP.
#[test]
fn vjp_matches_the_expected_image_within_two_percent() {
    for (preset, pitch) in [("sp", 0.01), ("msp", 0.01), ("sp", 0.7), ("msp", 0.7)] {
        // Apex angles of the SP prisms: the tilts of the breaks at the prism faces (s5, s7).
        // (s5.tilt_y_deg acts as prism_tilt_y on these presets: left out.)
        let free = ["prism_tilt_x", "prism_tilt_y", "s7.tilt_y_deg"];
        let sys = diffcassi::system::SequentialSystem::build(&diffcassi::presets::spec(preset).unwrap()).unwrap();
        let set = ParamSet::for_system(&sys, &free.join(",")).unwrap();
        // Pitch 0.7 mm: the 8×8 scene spans ±2.8 mm, beyond SP's ±2.5 mm field: rays are vignetted.
        let mut cfg = config(8, 3, 256, 1);
        cfg.scene_pitch_mm = pitch;
        let r = DiffRenderer::new(set, cfg, BANDS.to_vec()).unwrap();
        let (scene, mask, _) = inputs(&r, 4);
        // A smooth loss: the image weighted by a ramp across the detector (a first moment).
        let (ih, iw) = r.image_shape();
        let g: Vec<f64> = (0..2 * ih * iw).map(|i| ((i % (ih * iw)) / iw) as f64 / ih as f64 + 0.7 * (i % iw) as f64 / iw as f64).collect();
        let v = r.vjp(&scene, 2, &mask, &g).unwrap();
        let x0 = r.values().unwrap();
        for k in 0..free.len() {
            let h = 0.02; // degrees: landings move by several pixels' hundredths, rays cross status edges
            let at = |d: f64, seed: u64| {
                let mut x = x0.clone();
                x[k] += d;
                let mut rr = r.with_values(&x).unwrap();
                rr.config.seed = seed;
                loss(&rr, &scene, &mask, &g)
            };
            // Independent samples on each side: the difference of two expected images.
            let fd = (at(h, 101) - at(-h, 202)) / (2.0 * h);
            let fd_crn = (at(h, 1) - at(-h, 1)) / (2.0 * h);
            let rel = (v.params[k] - fd_crn).abs() / fd_crn.abs();
            println!("{preset} pitch {pitch} mm {:>14}: vjp {:+.6e}  expected-image fd (common samples) {:+.6e} rel {:.2e}; independent samples {:+.6e}", free[k], v.params[k], fd_crn, rel, fd);
            assert!(rel <= 0.02, "{preset} {}: {rel}", free[k]);
        }
    }
}

/// ∂(mapping)/∂θ against central differences of the mapping cube.
#[test]
fn mapping_cube_jacobian_matches_finite_differences() {
    let r = renderer(sp_like("msp"), &["s4.tilt_x_deg", "s16.curvature", "glass_nd:N-BK7"], config(4, 3, 1, 0));
    let worst = mapping_jacobian_error(&r, "mapping Jacobian");
    assert!(worst < 1e-6);
}

/// The largest difference between [`DiffRenderer::mapping_jacobian`] and central differences of the
/// mapping cube, as a fraction of each column's largest entry.
fn mapping_jacobian_error(r: &DiffRenderer, label: &str) -> f64 {
    let wl = [460.0, 640.0];
    let (pos, jac, valid) = r.mapping_jacobian(&wl).unwrap();
    assert!(valid.iter().all(|v| *v));
    let x0 = r.values().unwrap();
    let kk = x0.len();
    let mut worst = 0.0f64;
    for k in 0..kk {
        let h = step_for(&r.set.free[k]) * x0[k].abs().max(1.0) * 100.0;
        let at = |d: f64| {
            let mut x = x0.clone();
            x[k] += d;
            r.with_values(&x).unwrap().mapping_jacobian(&wl).unwrap().0
        };
        let (a, b) = (at(h), at(-h));
        let scale = (0..pos.len()).map(|i| jac[i * kk + k].abs()).fold(0.0, f64::max);
        for i in 0..pos.len() {
            let fd = (a[i] - b[i]) / (2.0 * h);
            worst = worst.max((fd - jac[i * kk + k]).abs() / scale);
        }
    }
    println!("{label}: worst error {worst:.1e} of the column's largest entry");
    worst
}

// ---------------------------------------------------------------- an object at infinity (issue 42)

/// Render settings for [`common::singlet_at_infinity`]: a `size`² scene 0.5° wide (one pixel ≈ 1.5 mrad,
/// ≈ 9 detector pixels at f ≈ 60 mm).
fn config_at_infinity(size: usize, planes: usize, rays: usize, seed: u64) -> RenderConfig {
    let mut cfg = config(size, planes, rays, seed);
    cfg.scene_fov_deg = Some(0.5);
    cfg
}

/// At infinity the differentiable renderer traces the production renderer's rays (the same samples, the
/// pixel's field angles, [`diffcassi::rays::PupilAim::parallel_ray`]): the same acquisition, on the same
/// detector, to the tolerance of the dual-disperser comparison (1e-5 of the peak: the production renderer
/// sums its band images in f32); and the pitch is the angle of one pixel.
#[test]
fn differentiable_renderer_at_infinity_equals_the_renderer() {
    use diffcassi::render::{Mask, Renderer};
    use diffcassi::scene::synthetic_scene;
    let size = 6;
    let spec = common::singlet_at_infinity(false);
    let sys = diffcassi::system::SequentialSystem::build(&spec).unwrap();
    assert!(sys.object_at_infinity());
    let tracer = diffcassi::tracer::AnalyticTracer::default();
    let mask = Mask::random(size, size, 0.5, 7).unwrap();
    let scene = synthetic_scene(size, size, &BANDS, 5);
    // The cube is (H, W, B); the differentiable renderer takes (N, B, H, W).
    let s64 = common::cube_nbhw(&scene);
    let m64: Vec<f64> = mask.values.iter().map(|v| *v as f64).collect();
    for kernel in [diffcassi::tracer::Kernel::default(), diffcassi::tracer::Kernel::Scalar] {
        let mut cfg = config_at_infinity(size, 3, 3, 5);
        cfg.kernel = kernel;
        let r = renderer(spec.clone(), &["s1.curvature"], cfg.clone());
        assert_eq!(r.config.scene_pitch_mm, 0.5f64.to_radians() / size as f64, "one pixel's angle (rad)");
        let production = Renderer::new(&sys, &tracer, cfg, mask.clone()).unwrap();
        assert_eq!(production.detector, r.detector);
        let reference = production.render(&scene, false, &|_| {}).unwrap();
        assert!(reference.stats.arrived > 0, "{:?}", reference.stats);
        let img = r.render(&s64, 1, &m64).unwrap();
        assert_eq!(img.len(), reference.image.len());
        let peak = reference.image.iter().cloned().fold(0.0, f64::max);
        let worst = img.iter().zip(&reference.image).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        println!("{kernel:?}: differentiable vs production renderer at infinity: worst {worst:.2e} (peak {peak:.3}, detector {}×{})", r.detector.width, r.detector.height);
        assert!(peak > 0.0 && worst <= 1e-5 * peak, "{kernel:?}: {worst} vs peak {peak}");
    }
}

/// At infinity ∂L/∂θ equals central differences of the same-sample acquisition (1e-6) for a lens's
/// curvature, radius, thickness, glass (n_d, V_d) and the image distance — the stop behind the lens, so
/// the curvatures, thickness and glass move the entrance pupil, which the renderer keeps at its
/// construction-time aim (rays fixed in object space, on both sides of the difference); and the chief-ray
/// mapping's Jacobian equals central differences of the mapping cube.
#[test]
fn vjp_at_infinity_matches_same_sample_finite_differences() {
    let free = ["s1.curvature", "s2.radius_mm", "s1.thickness_mm", "s3.thickness_mm", "glass_nd:N-BK7", "glass_vd:N-BK7"];
    let worst = check_same_sample_with("singlet at infinity", common::singlet_at_infinity(false), &free, config_at_infinity(5, 3, 2, 7));
    assert!(worst <= 1e-6, "{worst:e}");
    let r = renderer(common::singlet_at_infinity(false), &free, config_at_infinity(4, 3, 1, 0));
    assert!(mapping_jacobian_error(&r, "mapping Jacobian at infinity") < 1e-6);
}

/// The angular extent at infinity: required there, refused on a finite object, and only in (0, 180)
/// degrees — the production renderer's errors, naming the value; no panic.
#[test]
fn scene_fov_deg_is_required_at_infinity_and_checked() {
    let set = |spec: SystemSpec| ParamSet::new(spec, GlassCatalog::builtin(), vec![Param::parse("s1.curvature").unwrap()]).unwrap();
    let err = |spec: SystemSpec, fov: Option<f64>| {
        let mut cfg = config(4, 3, 1, 0);
        cfg.scene_fov_deg = fov;
        DiffRenderer::new(set(spec), cfg, BANDS.to_vec()).map(|_| ()).unwrap_err().to_string()
    };
    let e = err(common::singlet_at_infinity(false), None);
    // (The library's spelling is the command line's; a Python or C++ caller reads its own, src/frontend.rs.)
    assert!(e.contains("object at infinity") && e.contains("--scene-fov-deg D"), "{e}");
    for (bad, shown) in [(0.0, "0"), (180.0, "180"), (f64::NAN, "NaN"), (-5.0, "-5"), (f64::INFINITY, "inf")] {
        let e = err(common::singlet_at_infinity(false), Some(bad));
        assert!(e.contains(&format!("--scene-fov-deg {shown}:")) && e.contains("(0, 180) degrees"), "{bad}: {e}");
    }
    let e = err(sp_like("sp"), Some(10.0));
    assert!(e.contains("--scene-fov-deg 10") && e.contains("finite object"), "{e}");
    // A valid angle renders, with finite values only.
    let mut cfg = config(4, 3, 1, 0);
    cfg.scene_fov_deg = Some(1.0);
    let r = DiffRenderer::new(set(common::singlet_at_infinity(false)), cfg, BANDS.to_vec()).unwrap();
    let (scene, mask, g) = inputs(&r, 3);
    assert!(r.render(&scene, 2, &mask).unwrap().iter().all(|v| v.is_finite()));
    let v = r.vjp(&scene, 2, &mask, &g).unwrap();
    assert!(v.params.iter().chain(&v.mask).chain(&v.scene).all(|v| v.is_finite()) && v.params[0] != 0.0);
}

#[test]
fn bad_input_is_a_clear_error() {
    let sys = diffcassi::system::SequentialSystem::build(&diffcassi::presets::spec("sp").unwrap()).unwrap();
    let msg = |e: diffcassi::Error| e.to_string();
    // Unknown parameter name.
    let e = msg(ParamSet::for_system(&sys, "prism_tilt_q").unwrap_err());
    assert!(e.contains("prism_tilt_q"), "{e}");
    // Per-ray parameters are not parameters of the acquisition.
    let set = ParamSet::for_system(&sys, "wavelength").unwrap();
    let e = msg(DiffRenderer::new(set, config(4, 3, 1, 0), BANDS.to_vec()).unwrap_err());
    assert!(e.contains("wavelength") && e.contains("per ray"), "{e}");
    // A parameter with no effect on the detector: the image surface's thickness.
    let last = sys.spec.surfaces.len() - 1;
    let set = ParamSet::for_system(&sys, &format!("s{last}.thickness_mm")).unwrap();
    let e = msg(DiffRenderer::new(set, config(4, 3, 1, 0), BANDS.to_vec()).unwrap_err());
    assert!(e.contains("no effect on the detector") && e.contains(&format!("s{last}.thickness_mm")), "{e}");
    let r = DiffRenderer::new(ParamSet::for_system(&sys, "prism_tilt_x").unwrap(), config(4, 3, 1, 0), BANDS.to_vec()).unwrap();
    let (h, w) = r.image_shape();
    let scene = vec![1.0; 3 * 16];
    let mask = vec![1.0; 16];
    // Non-finite upstream gradient.
    let mut g = vec![0.0; h * w];
    g[w + 2] = f64::NAN;
    let e = msg(r.vjp(&scene, 1, &mask, &g).unwrap_err());
    assert!(e.contains("upstream gradient") && e.contains("row 1, column 2") && e.contains("NaN"), "{e}");
    // Wrong mask shape.
    let e = msg(r.vjp(&scene, 1, &[1.0; 15], &vec![0.0; h * w]).unwrap_err());
    assert!(e.contains("mask has 15 values") && e.contains("(4, 4)"), "{e}");
    let e = msg(r.render(&scene, 1, &[1.0; 17]).unwrap_err());
    assert!(e.contains("mask"), "{e}");
    // Wrong gradient shape.
    assert!(msg(r.vjp(&scene, 1, &mask, &[0.0; 3]).unwrap_err()).contains("upstream gradient has 3 values"));
    // A tilt that makes every ray miss.
    let e = msg(r.with_values(&[60.0]).and_then(|r| r.render(&scene, 1, &mask)).unwrap_err());
    assert!(e.contains("no ray reaches the detector") || e.contains("chief-ray solve failed"), "{e}");
    // A glass out of the catalogue's range.
    let rg = DiffRenderer::new(ParamSet::for_system(&sys, "glass_nd:N-BK7").unwrap(), config(4, 3, 1, 0), BANDS.to_vec()).unwrap();
    let e = msg(rg.with_values(&[2.5]).unwrap_err());
    assert!(e.contains("glass_nd:N-BK7") && e.contains("range"), "{e}");
}

/// The reverse sweeps with **one** free parameter at a time (the sweep then skips the frame, index and
/// focal-length sensitivities no parameter needs, and takes the identity at surfaces that keep the index):
/// for every parameter of the SP-like (mSP) and AP-like tests, the scalar sweep equals the forward tangents
/// ray by ray to 1e-12 relative to the size of λ·J's terms, and the lane sweep's per-lane gradient equals the scalar sweep's bit for
/// bit (one ray per lane, so no summation order differs), on one block of 32 rays with vignetted and
/// missed lanes and a random λ on position and direction.
#[test]
fn sweeps_with_one_free_parameter_equal_the_forward_tangents() {
    use diffcassi::diff::adjoint::{AdjointPlan, AdjointSums, RayTape};
    use diffcassi::diff::adjoint_lanes::LaneSums;
    use diffcassi::rays::{PupilAim, RayBatch};
    use diffcassi::tracer::simd::lanes::{Lf, Mask};
    use diffcassi::tracer::simd::{trace_block_recording, Block, LaneTape, LANES};
    use diffcassi::tracer::SimdLevel;
    use glam::DVec3;
    let mut rng = Rng(41);
    let level = SimdLevel::detect();
    for (name, spec, free) in [("msp", sp_like("msp"), &common::SP_LIKE_PARAMS[..]), ("ap", ap_like("ap", 4), &common::AP_LIKE_PARAMS[..])] {
        let (mut worst, mut compared, mut stopped) = (0.0f64, 0, 0);
        for (i, t) in free.iter().enumerate() {
            let ds = ParamSet::new(spec.clone(), GlassCatalog::builtin(), vec![Param::parse(t).unwrap()]).unwrap().build().unwrap();
            let aim = PupilAim::of(&ds.system);
            let w = [450.0, 600.0][i % 2];
            let plan = AdjointPlan::new(&ds, &[w]).unwrap();
            let (n, dn) = ds.index_tangents(w).unwrap();
            let (mut tape, mut ltape, mut b) = (RayTape::default(), LaneTape::default(), Block::default());
            let rays: Vec<(DVec3, DVec3)> = (0..LANES)
                .map(|_| {
                    let (fx, fy) = (8.0 * rng.next() - 4.0, 8.0 * rng.next() - 4.0);
                    let d = DVec3::from(aim.direction(fx, fy, 6.0 * rng.next() - 3.0, 6.0 * rng.next() - 3.0)).normalize();
                    (DVec3::new(fx, fy, 0.0), d)
                })
                .collect();
            for (k, &(o, d)) in rays.iter().enumerate() {
                b.set(k, o, d);
            }
            trace_block_recording(level, &ds.system, &[n.as_slice(); LANES], &mut b, &mut ltape);
            let mut lambda = [Lf::splat(0.0); 6];
            for l in lambda.iter_mut() {
                for k in 0..LANES {
                    l.0[k] = rng.next() - 0.5;
                }
            }
            let mut active = Mask::splat(false);
            for k in 0..LANES {
                active.0[k] = b.result(k).is_ok();
            }
            let mut lanes = LaneSums::new(&plan);
            let added = plan.backward_lanes(level, &ds, &ltape, &n, &lambda, active, &mut lanes);
            for (k, &(o, d)) in rays.iter().enumerate() {
                let mut grad = vec![0.0; 1];
                plan.contract(&ds, &lanes.lane(&plan, k), &dn, &mut grad);
                let mut batch = RayBatch::with_capacity(1);
                batch.push(o, d, w);
                let j = ds.trace(&batch).unwrap();
                if plan.trace(&ds, &n, o, d, &mut tape).is_err() || !j.usable(0) {
                    stopped += 1;
                    continue;
                }
                let lam: [f64; 6] = std::array::from_fn(|c| lambda[c].0[k]);
                let mut sums = AdjointSums::new(&plan);
                assert!(plan.backward(&ds, &mut tape, lam, &mut sums), "{name} {t}: lane {k} not finite");
                assert!(added.0[k], "{name} {t}: lane {k} not added");
                let mut want = vec![0.0; 1];
                plan.contract(&ds, &sums, &dn, &mut want);
                assert_eq!(grad[0].to_bits(), want[0].to_bits(), "{name} {t}: lane {k}: lane sweep {} vs scalar sweep {}", grad[0], want[0]);
                let (dp, dd) = (j.d_position(0, 0), j.d_direction(0, 0));
                let reference = lam[0] * dp.x + lam[1] * dp.y + lam[2] * dp.z + lam[3] * dd.x + lam[4] * dd.y + lam[5] * dd.z;
                // Relative to the size of the contraction's terms (a single gradient entry may cancel).
                let scale = (lam[0] * dp.x).abs() + (lam[1] * dp.y).abs() + (lam[2] * dp.z).abs() + (lam[3] * dd.x).abs() + (lam[4] * dd.y).abs() + (lam[5] * dd.z).abs();
                if scale > 0.0 {
                    worst = worst.max((want[0] - reference).abs() / scale);
                }
                compared += 1;
            }
        }
        println!("{name}: one free parameter at a time, {} parameters: scalar sweep vs forward tangents over {compared} rays ({stopped} stopped): worst {worst:.1e}; lane sweep = scalar sweep bit for bit", free.len());
        assert!(compared >= 5 * free.len() && stopped > 0, "{name}: {compared} compared, {stopped} stopped");
        assert!(worst <= 1e-12, "{name}: {worst:e}");
    }
}

/// `SweepLocal::adjoint` (the reverse sweep's hit data, built from the traced hit's unit normal and, on a
/// conic, s = 1 − c(1+k)z instead of its square root) is the transpose of the forward
/// `SurfaceLocal::tangent`: q̄·δq + n̄·δn = draȳ·dray + Σ p̄ᵢ·partialsᵢ for a ray change and a figure
/// change, on a conic, an even asphere and a plane, to 1e-13 relative.
#[test]
fn sweep_hit_adjoint_is_the_transpose_of_the_hit_tangent() {
    use diffcassi::diff::hit::{ShapeTangent, SurfaceLocal, SweepLocal};
    use diffcassi::surfaces::{intersect, SurfaceShape};
    use glam::DVec3;
    let shapes = [
        SurfaceShape::Conic { curvature: 0.03, conic: -0.7 },
        SurfaceShape::EvenAsphere { curvature: 0.02, conic: 0.3, coefficients: vec![1e-3, 2e-5] },
        SurfaceShape::Plane,
    ];
    let p = DVec3::new(2.0, -1.5, -4.0);
    let d = DVec3::new(0.1, 0.05, 1.0).normalize();
    let mut t = ShapeTangent { curvature: 0.3, conic: -0.2, ..Default::default() };
    (t.asphere[0], t.asphere[1]) = (0.5, -0.1);
    let dray = DVec3::new(0.3, -0.7, 0.2);
    let (q_bar, n_bar) = (DVec3::new(0.4, 0.1, -0.6), DVec3::new(-0.2, 0.9, 0.3));
    for s in shapes {
        let hit = intersect(&s, p, d).unwrap();
        let ht = SurfaceLocal::at(&s, hit.point).tangent(d, dray, &t);
        let rev = SweepLocal::at(&s, hit.point, hit.normal);
        let (ray_bar, pb) = rev.adjoint(d, q_bar, n_bar);
        let (a, b, c) = rev.param_partials(&t);
        let lhs = q_bar.dot(ht.point) + n_bar.dot(ht.normal);
        let rhs = ray_bar.dot(dray) + pb[0] * a + pb[1] * b + pb[2] * c;
        println!("{s:?}: q̄·δq + n̄·δn = {lhs:.17e}, draȳ·dray + p̄·partials = {rhs:.17e}");
        assert!((lhs - rhs).abs() <= 1e-13 * lhs.abs().max(1.0), "{s:?}: {lhs} vs {rhs}");
    }
}

/// `vjp_wanted` (torch's `needs_input_grad`): for every combination of wanted gradients, on the SIMD lanes
/// and the scalar kernel, with closed and open (continuous) mask pixels and N = 2, the wanted gradients
/// are bit-identical to those of `vjp` (all three) and the others come back empty; wanting nothing
/// computes nothing.
#[test]
fn wanted_gradients_are_bit_identical_to_the_full_vjp() {
    use diffcassi::render::gradient::Wanted;
    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    for kernel in [diffcassi::tracer::Kernel::default(), diffcassi::tracer::Kernel::Scalar] {
        let mut cfg = config(6, 3, 3, 5);
        cfg.kernel = kernel;
        let r = renderer(sp_like("msp"), &["s4.tilt_x_deg", "s16.curvature", "glass_nd:N-BK7"], cfg);
        let (scene, mask, g) = inputs(&r, 9);
        assert!(mask.contains(&0.0) && mask.iter().any(|m| *m > 0.0 && *m < 1.0));
        let all = r.vjp(&scene, 2, &mask, &g).unwrap();
        assert!(all.mask.iter().zip(&mask).any(|(gm, m)| *m == 0.0 && *gm != 0.0), "closed pixels have a mask gradient");
        for code in 0..8u8 {
            let wanted = Wanted { params: code & 1 != 0, mask: code & 2 != 0, scene: code & 4 != 0 };
            let v = r.vjp_wanted(&scene, 2, &mask, &g, wanted).unwrap();
            let pick = |on: bool, full: &[f64]| if on { bits(full) } else { Vec::new() };
            assert_eq!(bits(&v.params), pick(wanted.params, &all.params), "{kernel:?} {wanted:?}: parameters");
            assert_eq!(bits(&v.mask), pick(wanted.mask, &all.mask), "{kernel:?} {wanted:?}: mask");
            assert_eq!(bits(&v.scene), pick(wanted.scene, &all.scene), "{kernel:?} {wanted:?}: scene");
        }
        // The default is everything.
        assert_eq!(Wanted::default(), Wanted::ALL);
        // Bad input is still refused when only some gradients are wanted.
        let only = Wanted { params: true, mask: false, scene: false };
        let e = r.vjp_wanted(&scene, 2, &mask, &[0.0; 3], only).unwrap_err().to_string();
        assert!(e.contains("upstream gradient has 3 values"), "{e}");
    }
}

/// The differentiable renderer's tiled f64 blur and its transpose (`render::convolve::kernel_pass_f64`)
/// equal the plain double loop over the in-image taps bit for bit, on every SIMD path: odd sizes, widths
/// below and above a tile, Airy kernels with zero taps, values of both signs.
#[test]
fn tiled_f64_blur_equals_the_plain_double_loop() {
    use diffcassi::render::convolve::{kernel_pass_f64_with, BlurPath};
    use diffcassi::render::AiryKernel;
    let mut rng = Rng(31);
    for lambda in [450.0, 650.0] {
        let k = AiryKernel::for_wavelength(lambda, 2.5, 520.0, 3).unwrap();
        let wts: Vec<f64> = k.weights.iter().map(|&v| v as f64).collect();
        assert!(wts.contains(&0.0), "the kernel has zero taps");
        let (half, n) = (k.half as isize, 2 * k.half as isize + 1);
        for (w, h) in [(37usize, 23usize), (70, 9), (5, 3), (1, 1), (33, 2)] {
            let img: Vec<f64> = rng.vec(w * h).into_iter().map(|v| v - 0.3).collect();
            for dir in [1isize, -1] {
                let mut want = vec![0.0f64; w * h];
                for y in 0..h as isize {
                    for x in 0..w as isize {
                        let mut acc = 0.0;
                        for ki in 0..n {
                            let sy = y - dir * (ki - half);
                            for kj in 0..n {
                                let sx = x - dir * (kj - half);
                                if sy >= 0 && sy < h as isize && sx >= 0 && sx < w as isize {
                                    acc += wts[(ki * n + kj) as usize] * img[(sy * w as isize + sx) as usize];
                                }
                            }
                        }
                        want[(y * w as isize + x) as usize] = acc;
                    }
                }
                for path in BlurPath::available() {
                    let mut got = vec![f64::NAN; w * h];
                    kernel_pass_f64_with(path, &wts, k.half, &img, w, h, dir, &mut |i, s: &[f64]| got[i..i + s.len()].copy_from_slice(s));
                    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                    assert_eq!(bits(&got), bits(&want), "{path:?} {w}×{h} dir {dir} λ {lambda}");
                }
            }
        }
    }
}

/// The reverse sweeps stop at the earliest path step a free parameter moves
/// (`AdjointPlan::first_step`): before it λ is only carried back and nothing is summed. The prism tilt
/// alone (mSP's s4.tilt_x_deg: the sweep stops at the prism's first face) gets bit for bit the gradient it gets beside the
/// object distance, which moves the first step and makes the sweep go through the whole path — on the
/// SIMD lanes and with the scalar kernel.
#[test]
fn sweep_stopping_at_the_first_moved_step_changes_no_bit() {
    use diffcassi::diff::adjoint::AdjointPlan;
    use diffcassi::render::gradient::Wanted;
    for kernel in [diffcassi::tracer::Kernel::default(), diffcassi::tracer::Kernel::Scalar] {
        let mut cfg = config(6, 3, 3, 13);
        cfg.kernel = kernel;
        let short = renderer(sp_like("msp"), &["s4.tilt_x_deg"], cfg.clone());
        let long = renderer(sp_like("msp"), &["s0.thickness_mm", "s4.tilt_x_deg"], cfg);
        let first = |r: &DiffRenderer| AdjointPlan::new(&r.ds, &r.config.spectral.planes_nm).unwrap().first_step();
        println!("{kernel:?}: the sweep stops at path step {} (prism tilt) and {} (with the object distance)", first(&short), first(&long));
        assert!(first(&short) >= 2, "the prism tilt moves nothing before the prism");
        assert_eq!(first(&long), 0);
        let (scene, mask, g) = inputs(&short, 5);
        for wanted in [Wanted::ALL, Wanted { params: true, mask: false, scene: false }] {
            let a = short.vjp_wanted(&scene, 2, &mask, &g, wanted).unwrap();
            let b = long.vjp_wanted(&scene, 2, &mask, &g, wanted).unwrap();
            assert!(a.params[0] != 0.0);
            assert_eq!(a.params[0].to_bits(), b.params[1].to_bits(), "{kernel:?}: {} vs {}", a.params[0], b.params[1]);
            assert_eq!(a.mask, b.mask);
            assert_eq!(a.scene, b.scene);
        }
    }
}
