//! The sparse export (`diffcassi::recon::sparse`): for the three operators on small problems, the CSR
//! matrix times x equals `apply(x)` and its transpose times y equals `adjoint(y)`, to f32 rounding
//! (≤ 1e-5 of the peak |value|; the module docs give the bound's reason); the export does not depend on
//! the thread count; a budget too small is a clear error naming the size.
use diffcassi::prelude::*;
use diffcassi::recon::exact::ExactOperator;
use diffcassi::recon::sparse::{CsrMatrix, SparseExport};
use diffcassi::recon::{MappingInterpolation, MappingOperator, Operator, ShiftOperator};
use diffcassi::render::{Mask, RenderConfig, Renderer, SpectralSampling};
use rand::{Rng, SeedableRng};

const SIZE: usize = 12;
const BUDGET: u64 = 1 << 30;

fn bands() -> Vec<f64> {
    vec![470.0, 520.0, 570.0, 620.0]
}

fn config(airy: bool) -> RenderConfig {
    let mut cfg = RenderConfig::paper(SIZE);
    cfg.spectral = SpectralSampling::new(bands(), 3).unwrap();
    cfg.rays_per_pixel = 4;
    cfg.seed = 7;
    if !airy {
        cfg.airy = None;
    }
    cfg
}

fn random(n: usize, seed: u64, signed: bool) -> Vec<f32> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    (0..n).map(|_| if signed { rng.gen_range(-1.0f32..1.0) } else { rng.gen_range(0.0f32..1.0) }).collect()
}

fn max_abs_diff(a: &[f32], b: &[f32]) -> (f64, f64) {
    assert_eq!(a.len(), b.len());
    let peak = b.iter().map(|v| v.abs() as f64).fold(0.0, f64::max);
    let worst = a.iter().zip(b).map(|(x, y)| (*x as f64 - *y as f64).abs()).fold(0.0, f64::max);
    (worst, peak)
}

/// CSR·x = apply(x) (x ≥ 0 and signed) and CSRᵀ·y = adjoint(y), each to 1e-5 of the peak.
fn check(op: &dyn Operator, csr: &CsrMatrix) {
    let (c, i) = (op.cube_shape(), op.image_shape());
    assert_eq!((csr.rows, csr.cols), (i.len(), c.len()), "{}: shape", op.name());
    assert!(csr.nnz() > 0, "{}: empty matrix", op.name());
    for r in 0..csr.rows {
        let cols = &csr.indices[csr.indptr[r] as usize..csr.indptr[r + 1] as usize];
        assert!(cols.windows(2).all(|w| w[0] < w[1]), "{}: row {r}: columns not strictly increasing", op.name());
    }
    for (seed, signed) in [(1, false), (2, true)] {
        let x = random(c.len(), seed, signed);
        let (worst, peak) = max_abs_diff(&csr.matvec(&x).unwrap(), &op.apply(&x).unwrap());
        println!("{}: nnz {}, max |Φx − apply| = {worst:.3e} (peak {peak:.3e}, {:.2e})", op.name(), csr.nnz(), worst / peak);
        assert!(peak > 0.0 && worst <= 1e-5 * peak, "{}: CSR·x ≠ apply(x) by {worst:e} (peak {peak})", op.name());
        let y = random(i.len(), seed + 10, signed);
        let (worst, peak) = max_abs_diff(&csr.matvec_transpose(&y).unwrap(), &op.adjoint(&y).unwrap());
        println!("{}: max |Φᵀy − adjoint| = {worst:.3e} (peak {peak:.3e}, {:.2e})", op.name(), worst / peak);
        assert!(peak > 0.0 && worst <= 1e-5 * peak, "{}: CSRᵀ·y ≠ adjoint(y) by {worst:e} (peak {peak})", op.name());
    }
}

#[test]
fn exact_operator_csr_equals_apply_and_adjoint() {
    let tracer = AnalyticTracer::default();
    for (preset, airy) in [("sp", true), ("sp", false), ("map", true)] {
        let system = SequentialSystem::build(&presets::spec(preset).unwrap()).unwrap();
        let renderer = Renderer::new(&system, &tracer, config(airy), Mask::random(SIZE, SIZE, 0.5, 3).unwrap()).unwrap();
        assert_eq!(renderer.kernels.iter().all(|k| k.is_some()), airy);
        let op = ExactOperator::new(renderer, &bands(), BUDGET).unwrap();
        let csr = op.to_csr(BUDGET).unwrap();
        println!("{preset} airy={airy}:");
        check(&op, &csr);
    }
}

#[test]
fn streaming_exact_operator_exports_the_same_matrix() {
    let tracer = AnalyticTracer::default();
    let system = SequentialSystem::build(&presets::spec("sp").unwrap()).unwrap();
    let mask = Mask::random(SIZE, SIZE, 0.5, 4).unwrap();
    let kept = ExactOperator::new(Renderer::new(&system, &tracer, config(true), mask.clone()).unwrap(), &bands(), BUDGET).unwrap();
    let streamed = ExactOperator::new(Renderer::new(&system, &tracer, config(true), mask).unwrap(), &bands(), 0).unwrap();
    assert!(streamed.is_streaming() && !kept.is_streaming());
    assert_eq!(kept.to_csr(BUDGET).unwrap(), streamed.to_csr(BUDGET).unwrap());
}

#[test]
fn mapping_and_shift_csr_equal_apply_and_adjoint() {
    let tracer = AnalyticTracer::default();
    for preset in ["sp", "ap"] {
        let system = SequentialSystem::build(&presets::spec(preset).unwrap()).unwrap();
        let renderer = Renderer::new(&system, &tracer, config(true), Mask::random(SIZE, SIZE, 0.5, 5).unwrap()).unwrap();
        for interp in [MappingInterpolation::Nearest, MappingInterpolation::Bilinear] {
            let op = MappingOperator::from_renderer(&renderer, &bands(), interp).unwrap();
            check(&op, &op.to_csr(BUDGET).unwrap());
        }
        let shift = ShiftOperator::from_renderer(&renderer, &bands()).unwrap();
        check(&shift, &shift.to_csr(BUDGET).unwrap());
    }
}

#[test]
fn export_is_independent_of_thread_count_and_respects_the_budget() {
    let tracer = AnalyticTracer::default();
    let system = SequentialSystem::build(&presets::spec("sp").unwrap()).unwrap();
    let renderer = Renderer::new(&system, &tracer, config(true), Mask::random(SIZE, SIZE, 0.5, 6).unwrap()).unwrap();
    let op = ExactOperator::new(renderer, &bands(), BUDGET).unwrap();
    let export = |threads: usize| rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| op.to_csr(BUDGET).unwrap());
    let one = export(1);
    assert_eq!(one, export(3), "the matrix depends on the thread count");
    let err = op.to_csr(one.bytes() as u64 / 2).unwrap_err().to_string();
    println!("{err}");
    assert!(err.contains("memory budget") && err.contains("bytes") && err.contains("exact"), "unclear error: {err}");
}
