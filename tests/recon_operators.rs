//! Identities of the reconstruction operators (issue 13): the exact operator equals the renderer, every
//! operator's adjoint passes the dot-product test, streaming = cached transport, results independent of
//! the thread count, and the mapping initialisation equals the paper's straight crop on a pure shift.
use diffcassi::prelude::*;
use diffcassi::recon::exact::ExactOperator;
use diffcassi::recon::layout::{dot, norm};
use diffcassi::recon::Operator;
use diffcassi::render::{Mask, RenderConfig, Renderer, SpectralSampling};
use diffcassi::scene::synthetic_scene;
use rand::{Rng, SeedableRng};

const SIZE: usize = 24;

fn bands() -> Vec<f64> {
    vec![460.0, 500.0, 540.0, 580.0, 620.0]
}

fn config(seed: u64) -> RenderConfig {
    let mut cfg = RenderConfig::paper(SIZE);
    cfg.spectral = SpectralSampling::new(bands(), 2).unwrap();
    cfg.rays_per_pixel = 4;
    cfg.seed = seed;
    cfg
}

fn random(n: usize, seed: u64) -> Vec<f32> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    (0..n).map(|_| rng.gen_range(-1.0f32..1.0)).collect()
}

/// |⟨Φx, y⟩ − ⟨x, Φᵀy⟩| ≤ 1e-6·‖Φx‖‖y‖ on random x, y (f64 dot products).
pub fn assert_adjoint(op: &dyn Operator, seed: u64) {
    let x = random(op.cube_shape().len(), seed);
    let y = random(op.image_shape().len(), seed + 1);
    let phix = op.apply(&x).unwrap();
    let phity = op.adjoint(&y).unwrap();
    let (a, b) = (dot(&phix, &y), dot(&x, &phity));
    let scale = norm(&phix) * norm(&y);
    assert!(scale > 0.0, "{}: Φx or y vanishes", op.name());
    let rel = (a - b).abs() / scale;
    println!("{}: ⟨Φx, y⟩ = {a:.9e}, ⟨x, Φᵀy⟩ = {b:.9e}, relative gap {rel:.2e}", op.name());
    assert!(rel <= 1e-6, "{}: adjoint gap {rel:e}", op.name());
}

#[test]
fn exact_operator_equals_the_renderer_and_is_adjoint() {
    let tracer = AnalyticTracer::default();
    for preset in ["sp", "map"] {
        let system = SequentialSystem::build(&presets::spec(preset).unwrap()).unwrap();
        let mask = Mask::random(SIZE, SIZE, 0.5, 11).unwrap();
        let scene = synthetic_scene(SIZE, SIZE, &bands(), 5);
        let renderer = Renderer::new(&system, &tracer, config(3), mask.clone()).unwrap();
        assert!(renderer.kernels.iter().all(|k| k.is_some()), "the Airy blur is on");
        let reference = renderer.render(&scene, false, &|_| {}).unwrap();
        let op = ExactOperator::new(renderer, &scene.wavelengths_nm, 1 << 32).unwrap();
        assert!(!op.is_streaming());
        let y = (&op as &dyn Operator).apply(&scene.data).unwrap();
        let peak = reference.image.iter().cloned().fold(0.0, f64::max);
        let worst = y.iter().zip(&reference.image).map(|(a, b)| (*a as f64 - b).abs()).fold(0.0, f64::max);
        println!("{preset}: peak {peak:.4}, max |Φx − render| = {worst:.3e} ({:.2e} of the peak)", worst / peak);
        assert!(peak > 0.1);
        assert!(worst <= 1e-6 * peak, "{preset}: exact ≠ render by {worst:e} (peak {peak})");
        assert_adjoint(&op, 21);
    }
}

#[test]
fn exact_operator_streams_identically_and_ignores_thread_count() {
    let tracer = AnalyticTracer::default();
    let system = SequentialSystem::build(&presets::spec("sp").unwrap()).unwrap();
    let mask = Mask::random(SIZE, SIZE, 0.5, 2).unwrap();
    let cached = ExactOperator::new(Renderer::new(&system, &tracer, config(9), mask.clone()).unwrap(), &bands(), 1 << 32).unwrap();
    let streamed = ExactOperator::new(Renderer::new(&system, &tracer, config(9), mask).unwrap(), &bands(), 0).unwrap();
    assert!(!cached.is_streaming() && cached.transport_bytes() > 0);
    assert!(streamed.is_streaming() && streamed.transport_bytes() == 0);
    let (c, s): (&dyn Operator, &dyn Operator) = (&cached, &streamed);
    let x = random(c.cube_shape().len(), 1).iter().map(|v| v.abs()).collect::<Vec<_>>();
    let y = random(c.image_shape().len(), 2);
    let (ax, ay) = (c.apply(&x).unwrap(), c.adjoint(&y).unwrap());
    assert_eq!(ax, s.apply(&x).unwrap(), "streamed Φ differs from cached");
    assert_eq!(ay, s.adjoint(&y).unwrap(), "streamed Φᵀ differs from cached");
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    let (ax1, ay1) = pool.install(|| (c.apply(&x).unwrap(), c.adjoint(&y).unwrap()));
    assert_eq!(ax, ax1, "Φ depends on the thread count");
    assert_eq!(ay, ay1, "Φᵀ depends on the thread count");
}

#[test]
fn mapping_and_shift_operators_are_adjoint_on_real_systems() {
    use diffcassi::recon::{MappingInterpolation, MappingOperator, ShiftOperator};
    let tracer = AnalyticTracer::default();
    for preset in ["sp", "msp"] {
        let system = SequentialSystem::build(&presets::spec(preset).unwrap()).unwrap();
        let renderer = Renderer::new(&system, &tracer, config(1), Mask::random(SIZE, SIZE, 0.5, 4).unwrap()).unwrap();
        for interp in [MappingInterpolation::Nearest, MappingInterpolation::Bilinear] {
            let op = MappingOperator::from_renderer(&renderer, &bands(), interp).unwrap();
            assert_adjoint(&op, 31);
        }
        let shift = ShiftOperator::from_renderer(&renderer, &bands()).unwrap();
        let s = shift.shifts_px();
        println!("{preset}: shift model s(b) = {s:?}, placement {:?}", shift.placement());
        // Dispersion is monotone in λ and spans tens of pixels over 460–620 nm.
        assert!(s.windows(2).all(|w| w[1] != w[0]) && s.last().unwrap().abs() > 20, "{s:?}");
        assert_adjoint(&shift, 41);
        // Every masked voxel lands on the detector (the render's detector covers the dispersed footprint).
        let ones = vec![1.0f32; shift.cube_shape().len()];
        let y = (&shift as &dyn Operator).apply(&ones).unwrap();
        let open: f32 = renderer.mask.values.iter().sum();
        assert!((y.iter().sum::<f32>() - open * bands().len() as f32).abs() < 1e-3);
    }
}

/// On a mapping that is a pure per-band x-shift, I(:, :, b) = A(:, s(b) : W + s(b)), and the nearest mapping
/// operator equals the shift operator with the same placement.
#[test]
fn mapping_initialisation_is_the_straight_crop_on_a_pure_shift() {
    use diffcassi::analysis::MappingCube;
    use diffcassi::recon::{CubeShape, ImageShape, MappingInterpolation, MappingOperator, ShiftOperator};
    use diffcassi::render::Detector;
    let (h, w) = (7usize, 9usize);
    let s = [0usize, 2, 5, 9];
    let nb = s.len();
    let det = Detector { width: w + 9, height: h, pitch_mm: 0.01, x_left_mm: -0.3, y_top_mm: 0.2 };
    let mut positions_mm = vec![0.0; h * w * nb * 2];
    for r in 0..h {
        for c in 0..w {
            for b in 0..nb {
                let k = (r * w + c) * nb + b;
                let [x, y] = det.pixel_centre_mm(r, c + s[b]);
                // A quarter pixel off the centre: truncation must still pick the same pixel.
                positions_mm[2 * k] = x + 0.0024;
                positions_mm[2 * k + 1] = y - 0.0024;
            }
        }
    }
    let mapping = MappingCube { height: h, width: w, wavelength_nm: vec![450.0, 500.0, 550.0, 600.0], pixel_pitch_mm: 0.01, positions_mm, valid: vec![1; h * w * nb] };
    let mask = Mask::random(h, w, 0.5, 8).unwrap();
    let op = MappingOperator::new(&mapping, &det, &mask, MappingInterpolation::Nearest).unwrap();
    let acq = random(det.pixels(), 5);
    let init = op.initialisation(&acq).unwrap();
    for r in 0..h {
        for c in 0..w {
            for b in 0..nb {
                assert_eq!(init[(r * w + c) * nb + b], acq[r * det.width + c + s[b]], "I({r}, {c}, {b})");
            }
        }
    }
    let shift = ShiftOperator::new(CubeShape { height: h, width: w, bands: nb }, ImageShape { height: h, width: det.width }, &mask, 0, s.iter().map(|&v| v as i64).collect(), 1, 1).unwrap();
    assert_eq!(shift.shifts_px(), vec![0, 2, 5, 9]);
    let x = random(h * w * nb, 6);
    let (a, b): (&dyn Operator, &dyn Operator) = (&op, &shift);
    assert_eq!(a.apply(&x).unwrap(), b.apply(&x).unwrap());
    assert_eq!(a.adjoint(&acq).unwrap(), b.adjoint(&acq).unwrap());
    assert_adjoint(&op, 7);
    assert_adjoint(&shift, 8);
    // A failed chief ray contributes nothing and initialises to 0.
    let mut m2 = mapping.clone();
    m2.valid[0] = 0;
    let op2 = MappingOperator::new(&m2, &det, &mask, MappingInterpolation::Bilinear).unwrap();
    assert_eq!(op2.initialisation(&acq).unwrap()[0], 0.0);
    assert_adjoint(&op2, 9);
}
