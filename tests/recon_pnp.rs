//! The priors as denoisers and the plug-and-play solvers (issue 22): GAP-TV / ADMM-TV through the `Denoiser`
//! trait reproduce the pre-trait loops bit for bit; the learned denoiser's weights are checked (clear errors
//! naming the file and tensor); inference and PnP are bit-identical across thread counts; PnP reduces the
//! error on a tiny problem; the CLI's `--solver pnp-gap`, `--operator-rays` and `study --solvers` rows; bad
//! weights / band count / schedule → a clear error and nothing written. Tiny sizes throughout.
use diffcassi::recon::prior::network::{SpectralUNet, Stage, ARCH, EMBEDDED_PATH};
use diffcassi::recon::prior::Denoiser;
use diffcassi::recon::solver::{reconstruct, sigma_schedule, Preconditioner, SolverConfig, SolverKind};
use diffcassi::recon::tv::{tv_denoise, TvScratch};
use diffcassi::recon::{CubeShape, ImageShape, Operator, ShiftOperator};
use diffcassi::render::Mask;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const BANDS: usize = 28;
/// The embedded network's width (round 9: 64; MODEL.md), as a number and as its metadata string.
const WIDTH: usize = 64;
const W: &str = "64";

/// A smooth two-region cube of `bands` bands, peak ≈ 0.9.
fn scene(h: usize, w: usize, bands: usize) -> Vec<f32> {
    let mut v = vec![0.0f32; h * w * bands];
    for r in 0..h {
        for c in 0..w {
            for b in 0..bands {
                let t = b as f32 / bands.max(2) as f32;
                let inside = (r as f32 - h as f32 / 2.0).powi(2) + (c as f32 - w as f32 / 2.0).powi(2) < (h as f32 / 3.0).powi(2);
                v[(r * w + c) * bands + b] = if inside { 0.3 + 0.6 * t } else { 0.8 - 0.5 * t } + 0.02 * ((r + 2 * c) % 5) as f32 / 5.0;
            }
        }
    }
    v
}

fn shift_problem(h: usize, w: usize, bands: usize) -> (ShiftOperator, Vec<f32>, Vec<f32>) {
    let shape = CubeShape { height: h, width: w, bands };
    let op = ShiftOperator::new(shape, ImageShape { height: h, width: w + bands - 1 }, &Mask::random(h, w, 0.5, 3).unwrap(), 0, (0..bands as i64).collect(), 1, 1).unwrap();
    let truth = scene(h, w, bands);
    let y = (&op as &dyn Operator).apply(&truth).unwrap();
    (op, truth, y)
}

/// The GAP-TV / ADMM-TV loops as they were before the `Denoiser` trait (tv_denoise called directly), kept
/// here as the reference the refactored solvers must equal bit for bit.
fn reference_tv(op: &dyn Operator, y: &[f32], cfg: &SolverConfig) -> Vec<f32> {
    let shape = op.cube_shape();
    let pre = Preconditioner::new(op);
    let mut theta = vec![0.0f32; shape.len()];
    let mut x = vec![0.0f32; shape.len()];
    let mut tmp = vec![0.0f32; shape.len()];
    let mut b = vec![0.0f32; shape.len()];
    let mut phi = vec![0.0f32; y.len()];
    let mut e = vec![0.0f32; y.len()];
    let mut y_acc = vec![0.0f32; y.len()];
    let mut tv = TvScratch::default();
    let lambda = cfg.step;
    if cfg.solver == SolverKind::GapTv {
        for _ in 0..cfg.iterations {
            op.apply_into(&theta, &mut phi);
            for i in 0..e.len() {
                e[i] = y[i] - phi[i];
                if cfg.accelerated {
                    y_acc[i] += e[i];
                    e[i] = (y_acc[i] - phi[i]) * pre.inverse[i];
                } else {
                    e[i] *= pre.inverse[i];
                }
            }
            op.adjoint_into(&e, &mut x);
            for i in 0..x.len() {
                x[i] = theta[i] + lambda * x[i];
            }
            tv_denoise(&x, &mut theta, shape, cfg.tv_weight, cfg.tv_iterations, cfg.tv_coupling, &mut tv);
        }
    } else {
        let eta = cfg.admm_eta * pre.max();
        let inv: Vec<f32> = pre.d.iter().zip(&pre.inverse).map(|(d, w)| if *w > 0.0 { 1.0 / (*d + eta) } else { 0.0 }).collect();
        for _ in 0..cfg.iterations {
            for i in 0..x.len() {
                x[i] = theta[i] + b[i];
            }
            op.apply_into(&x, &mut phi);
            for i in 0..e.len() {
                e[i] = (y[i] - phi[i]) * inv[i];
            }
            op.adjoint_into(&e, &mut tmp);
            for i in 0..x.len() {
                x[i] += lambda * tmp[i];
                tmp[i] = x[i] - b[i];
            }
            tv_denoise(&tmp, &mut theta, shape, cfg.tv_weight, cfg.tv_iterations, cfg.tv_coupling, &mut tv);
            for i in 0..x.len() {
                b[i] -= x[i] - theta[i];
            }
        }
    }
    theta
}

/// GAP-TV (plain and accelerated) and ADMM-TV, now calling TV through the `Denoiser` trait, equal the
/// direct loops bit for bit.
#[test]
fn tv_through_the_denoiser_trait_is_todays_gap_tv_bit_for_bit() {
    let (op, _, y) = shift_problem(12, 10, 4);
    for (kind, accelerated) in [(SolverKind::GapTv, false), (SolverKind::GapTv, true), (SolverKind::AdmmTv, false)] {
        let cfg = SolverConfig { iterations: 12, accelerated, ..SolverConfig::for_solver(kind) };
        let rec = reconstruct(&op, &y, None, &cfg, &|_, _| {}).unwrap();
        let want = reference_tv(&op, &y, &cfg);
        assert!(rec.cube.iter().zip(&want).all(|(a, b)| a.to_bits() == b.to_bits()), "{kind:?} accelerated={accelerated}: differs from the reference loop");
        assert_eq!(rec.iterations_run, 12);
        assert_eq!(rec.stopped_by, "iterations");
        assert_eq!(rec.denoiser["name"], "tv");
    }
}

/// The σ schedule is geometric from σ_max to σ_min.
#[test]
fn sigma_schedule_is_geometric_between_its_ends() {
    assert_eq!(sigma_schedule(0.1, 0.01, 5, 1), 0.1);
    assert!((sigma_schedule(0.1, 0.01, 5, 5) - 0.01).abs() < 1e-8);
    assert!((sigma_schedule(0.1, 0.01, 3, 2) - 0.1f32 * 0.1f32.sqrt()).abs() < 1e-7);
    assert_eq!(sigma_schedule(0.1, 0.01, 1, 1), 0.1);
}

fn weights_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(EMBEDDED_PATH)
}

/// The embedded checkpoint is the committed file, and it loads with its metadata.
#[test]
fn embedded_weights_are_the_committed_file() {
    let net = SpectralUNet::embedded().unwrap();
    assert_eq!((net.bands, net.width), (BANDS, WIDTH));
    let from_file = SpectralUNet::from_file(&weights_path()).unwrap();
    assert_eq!(from_file.crc32, net.crc32);
}

/// The denoiser is bit-identical in 1- and 2-thread pools (candle's convolutions run in the caller's pool,
/// tiled independently of the thread count), on a size that is not a multiple of 4 (padding path).
#[test]
fn denoiser_is_bit_identical_for_any_thread_count() {
    let shape = CubeShape { height: 22, width: 17, bands: BANDS };
    let x = scene(shape.height, shape.width, BANDS);
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| {
            let mut net = SpectralUNet::embedded().unwrap();
            let mut out = vec![0.0f32; shape.len()];
            net.denoise(&x, &mut out, shape, 0.05).unwrap();
            out
        })
    };
    let (a, b) = (run(1), run(2));
    assert!(a.iter().all(|v| v.is_finite()));
    assert!(a.iter().zip(&b).all(|(p, q)| p.to_bits() == q.to_bits()), "1 vs 2 threads differ");
    assert_ne!(a, x, "the network changed nothing");
}

/// Round 6: a PnP-stage weights file (metadata `stage` = `pnp`, `train_denoiser.py --stage-net`) is told
/// apart from a Gaussian denoiser: the Gaussian loader (`denoise`) refuses it with a clear error naming the
/// file and the field; the PnP solvers' loader takes it and records its stage (and the embedded Gaussian file,
/// the default); an unknown `stage` is refused.
#[test]
fn pnp_stage_weights_are_told_apart_from_gaussian_ones() {
    let d = tempfile::tempdir().unwrap();
    let pnp_path = d.path().join("stage.safetensors");
    std::fs::write(&pnp_path, edited_weights(|_, _, _| true, Some(vec![("arch", ARCH), ("bands", "28"), ("width", W), ("latent", "12"), ("stage", "pnp")]))).unwrap();
    let net = SpectralUNet::load_pnp(Some(&pnp_path)).unwrap();
    assert_eq!((net.stage, net.bands, net.width, net.latent), (Stage::Pnp, BANDS, WIDTH, 12));
    assert_eq!(net.describe()["stage"], "pnp");
    let e = SpectralUNet::load(Some(&pnp_path)).err().expect("a PnP-stage file refused as a Gaussian denoiser").to_string();
    assert!(e.contains("stage.safetensors") && e.contains("`stage` = `pnp`"), "{e}");
    let g = SpectralUNet::load_pnp(None).unwrap();
    assert_eq!((g.stage, g.describe()["stage"].as_str()), (Stage::Gaussian, Some("gaussian")));
    assert_eq!(g.crc32, SpectralUNet::embedded().unwrap().crc32);
    assert_eq!(SpectralUNet::load(None).unwrap().stage, Stage::Gaussian);
    let p = d.path().join("odd.safetensors");
    std::fs::write(&p, edited_weights(|_, _, _| true, Some(vec![("arch", ARCH), ("bands", "28"), ("width", W), ("latent", "12"), ("stage", "unrolled")]))).unwrap();
    let e = SpectralUNet::from_file(&p).err().expect("unknown stage refused").to_string();
    assert!(e.contains("odd.safetensors") && e.contains("`stage` = `unrolled`"), "{e}");
}

/// Round 5 (MODEL.md): the mean-colour neutralisation makes the denoiser commute with a change of the mean
/// colour (x + c, Σ_b c_b = 0 ↦ out + c; the network alone does not), and the self-ensemble commutes with the
/// dihedral transforms (a transposed input, 22×17 — padding and H/W swapped — gives the transposed output)
/// and differs from one pass; both bit-identical for 1 and 2 threads.
#[test]
fn neutralisation_and_self_ensemble_are_equivariant() {
    let shape = CubeShape { height: 22, width: 17, bands: BANDS };
    let x = scene(shape.height, shape.width, BANDS);
    let c: Vec<f32> = (0..BANDS).map(|b| 0.08 * ((b as f32) * 0.7).sin()).collect();
    let mean_c = c.iter().sum::<f32>() / BANDS as f32;
    let xc: Vec<f32> = x.iter().enumerate().map(|(i, v)| v + c[i % BANDS] - mean_c).collect();
    let run = |net: &mut SpectralUNet, x: &[f32], shape: CubeShape| {
        let mut out = vec![0.0f32; shape.len()];
        net.denoise(x, &mut out, shape, 0.05).unwrap();
        out
    };
    let mut net = SpectralUNet::embedded().unwrap();
    assert!(!net.neutral && !net.self_ensemble, "defaults: rounds 1–4's inference (PnP unchanged)");
    net.neutral = true;
    let (a, b) = (run(&mut net, &x, shape), run(&mut net, &xc, shape));
    let worst = a.iter().zip(&b).enumerate().map(|(i, (p, q))| (q - p - (c[i % BANDS] - mean_c)).abs()).fold(0.0f32, f32::max);
    assert!(worst < 1e-5, "neutralised: colour shift not carried through ({worst})");
    net.neutral = false;
    let (ra, rb) = (run(&mut net, &x, shape), run(&mut net, &xc, shape));
    let worst_raw = ra.iter().zip(&rb).enumerate().map(|(i, (p, q))| (q - p - (c[i % BANDS] - mean_c)).abs()).fold(0.0f32, f32::max);
    assert!(worst_raw > 1e-3, "the network alone should not commute ({worst_raw})");
    // Self-ensemble: transpose = a quarter turn and a flip, one of the eight transforms.
    let mut net = SpectralUNet::embedded().unwrap();
    net.self_ensemble = true;
    let tshape = CubeShape { height: shape.width, width: shape.height, bands: BANDS };
    let transpose = |v: &[f32], h: usize, w: usize| {
        let mut t = vec![0.0f32; v.len()];
        for r in 0..h {
            for col in 0..w {
                t[(col * h + r) * BANDS..][..BANDS].copy_from_slice(&v[(r * w + col) * BANDS..][..BANDS]);
            }
        }
        t
    };
    let e = run(&mut net, &x, shape);
    let et = run(&mut net, &transpose(&x, shape.height, shape.width), tshape);
    let worst_t = transpose(&e, shape.height, shape.width).iter().zip(&et).map(|(p, q)| (p - q).abs()).fold(0.0f32, f32::max);
    assert!(worst_t < 1e-5, "self-ensemble not transpose-equivariant ({worst_t})");
    assert!(e.iter().zip(&a).any(|(p, q)| (p - q).abs() > 1e-3), "the self-ensemble equals one pass");
    let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap();
    let e2 = pool.install(|| run(&mut net, &x, shape));
    let pool1 = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    let e1 = pool1.install(|| run(&mut net, &x, shape));
    assert!(e1.iter().zip(&e2).all(|(p, q)| p.to_bits() == q.to_bits()), "1 vs 2 threads differ");
    assert_eq!(net.describe()["self_ensemble"], true);
}

/// PnP's input scale is robust to outliers (issue 22: the mapping cells' ±290 voxels collapsed PnP): one
/// voxel at 100× the peak no longer sets the scale, and the network's output away from it stays what it is
/// without the outlier; dividing by the maximum (the former scale) ruins it. Without outliers the scale is
/// the maximum, as before.
#[test]
fn one_outlier_voxel_no_longer_ruins_the_network_output() {
    use diffcassi::recon::solver::{denoise_at_network_scale, NetworkScale};
    let shape = CubeShape { height: 40, width: 40, bands: BANDS };
    let clean = scene(shape.height, shape.width, BANDS);
    let peak = clean.iter().cloned().fold(0.0f32, f32::max);
    let mut scratch = Vec::new();
    assert_eq!(NetworkScale::of(&clean, &mut scratch).scale, peak, "no outlier: the scale is the maximum");
    let (r0, c0) = (4usize, 5usize);
    let mut spiked = clean.clone();
    spiked[(r0 * shape.width + c0) * BANDS + 10] = 100.0 * peak;
    let mut net = SpectralUNet::embedded().unwrap();
    let mut reference = vec![0.0f32; shape.len()];
    let mut robust = vec![0.0f32; shape.len()];
    denoise_at_network_scale(&mut net, &clean, &mut reference, shape, 0.1, &mut scratch).unwrap();
    let s = denoise_at_network_scale(&mut net, &spiked, &mut robust, shape, 0.1, &mut scratch).unwrap();
    assert!(s.scale == peak && s.max == 100.0 * peak, "{s:?}");
    // The former scale: the maximum.
    let m = 100.0 * peak;
    let scaled: Vec<f32> = spiked.iter().map(|v| v / m).collect();
    let mut former = vec![0.0f32; shape.len()];
    net.denoise(&scaled, &mut former, shape, 0.1).unwrap();
    former.iter_mut().for_each(|v| *v *= m);
    // Voxels more than 12 pixels from the outlier (the U-Net's receptive field spreads it locally): the
    // largest and the mean change, relative to the peak.
    let far = |out: &[f32]| {
        let (mut worst, mut sum, mut n) = (0.0f32, 0.0f64, 0usize);
        for r in 0..shape.height {
            for c in 0..shape.width {
                if r.abs_diff(r0).max(c.abs_diff(c0)) > 12 {
                    for b in 0..BANDS {
                        let k = (r * shape.width + c) * BANDS + b;
                        let d = (out[k] - reference[k]).abs();
                        worst = worst.max(d);
                        sum += d as f64;
                        n += 1;
                    }
                }
            }
        }
        (worst / peak, (sum / n as f64) as f32 / peak)
    };
    let ((e_robust, m_robust), (e_former, m_former)) = (far(&robust), far(&former));
    println!("scale {s:?}; far from the outlier, |D − D_clean| / peak: robust max {e_robust:.4} mean {m_robust:.5}, by the maximum max {e_former:.4} mean {m_former:.5}");
    assert!(robust.iter().all(|v| v.is_finite()));
    assert!(e_robust <= 0.02, "robust scale: the outlier still changes the output far from it by {e_robust} of the peak");
    assert!(e_former >= 0.1, "the former scale should have ruined the output (it changed it by only {e_former})");
}

/// PnP-GAP and PnP-ADMM on a tiny shift problem: the reconstruction is closer to the truth than the start
/// (0) and than one data step, finite, bit-identical across thread counts, and the record carries the σ
/// schedule and the stopping rule.
#[test]
fn pnp_reduces_the_error_and_is_deterministic() {
    let (op, truth, y) = shift_problem(16, 16, BANDS);
    let err = |c: &[f32]| c.iter().zip(&truth).map(|(a, b)| ((a - b) as f64).powi(2)).sum::<f64>().sqrt();
    let e0 = err(&vec![0.0; truth.len()]);
    for kind in [SolverKind::PnpGap, SolverKind::PnpAdmm] {
        // tolerance on (the default is off since round 6) so that the relative changes are recorded.
        let cfg = SolverConfig { iterations: 15, tv_warmup: 5, tolerance: 1e-3, ..SolverConfig::for_solver(kind) };
        let solve = |threads: usize| rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| reconstruct(&op, &y, None, &cfg, &|_, _| {}).unwrap());
        let (a, b) = (solve(1), solve(2));
        assert!(a.cube.iter().zip(&b.cube).all(|(p, q)| p.to_bits() == q.to_bits()), "{kind:?}: 1 vs 2 threads differ");
        let one = reconstruct(&op, &y, None, &SolverConfig { iterations: 1, tolerance: 0.0, tv_warmup: 0, ..cfg.clone() }, &|_, _| {}).unwrap();
        let (e, e1) = (err(&a.cube), err(&one.cube));
        println!("{kind:?}: error {e:.4} (start {e0:.4}, one iteration {e1:.4}), {} iterations, stopped by {}", a.iterations_run, a.stopped_by);
        assert!(a.cube.iter().all(|v| v.is_finite()));
        assert!(e < 0.8 * e0 && e < e1, "{kind:?}: {e} vs start {e0}, one iteration {e1}");
        assert_eq!(a.sigmas.len(), a.iterations_run);
        assert!(a.sigmas[..5].iter().all(|s| *s == 0.0), "TV warm-up iterations have no σ");
        assert_eq!(a.sigmas[5] as f64, a.denoiser["tv_warmup"]["sigma_first"].as_f64().unwrap());
        assert!(a.sigmas[5..].windows(2).all(|w| w[1] < w[0]));
        assert_eq!(a.denoiser["tv_warmup"]["iterations"], 5);
        assert_eq!(a.denoiser["name"], ARCH);
        assert_eq!(a.relative_changes.len(), a.iterations_run);
    }
}

/// The documented noise-level schedule: after the TV phase, σ starts at the TV iterate's estimated error
/// (clamped to [σ_min, σ_max]; σ_max with `sigma_auto` off), is positive, strictly decreasing and ends on the
/// floor σ_min; the network runs at most `iterations − tv_warmup` times; a TV phase that meets GAP-TV's own
/// discrepancy stop hands over early.
#[test]
fn pnp_schedule_starts_at_the_tv_error_and_decays_to_the_floor() {
    let (op, _, y) = shift_problem(16, 16, BANDS);
    for (kind, auto) in [(SolverKind::PnpGap, true), (SolverKind::PnpGap, false), (SolverKind::PnpAdmm, true)] {
        let cfg = SolverConfig { iterations: 12, tv_warmup: 6, tolerance: 0.0, sigma_max: 0.15, sigma_min: 0.02, sigma_auto: auto, ..SolverConfig::for_solver(kind) };
        let rec = reconstruct(&op, &y, None, &cfg, &|_, _| {}).unwrap();
        assert_eq!(rec.iterations_run, 12, "{kind:?}");
        let net = &rec.sigmas[6..];
        assert_eq!(net.len(), 6);
        let record = &rec.denoiser["tv_warmup"];
        let est = record["tv_error_estimate"].as_f64().unwrap() as f32;
        assert!(est > 0.0 && est.is_finite());
        let want = if auto { (est * diffcassi::recon::solver::PNP_SIGMA_GAIN).clamp(0.02, 0.15) } else { 0.15 };
        assert_eq!(net[0], want, "{kind:?} auto={auto}: σ_1 (estimate {est})");
        assert!(net.iter().all(|s| *s > 0.0 && s.is_finite()), "{net:?}");
        assert!(net.windows(2).all(|w| w[1] < w[0]), "not decreasing: {net:?}");
        assert!((net[5] - 0.02).abs() < 1e-7 && net.iter().all(|s| *s >= 0.02 - 1e-7), "floor: {net:?}");
        assert_eq!(record["iterations_run"], 6);
    }
    // A δ so large that the first TV iterate meets τ_TV·δ: the network takes over after one TV iteration and
    // runs its N = 6 iterations (7 in all, under the cap of 12); the PnP rule (τ = 0) stays off.
    let big = SolverConfig { iterations: 12, tv_warmup: 6, tolerance: 0.0, discrepancy: 0.0, noise_norm: 1e9, ..SolverConfig::pnp_gap() };
    let rec = reconstruct(&op, &y, None, &big, &|_, _| {}).unwrap();
    assert_eq!(rec.denoiser["tv_warmup"]["iterations_run"], 1);
    assert_eq!(rec.iterations_run, 7);
    assert_eq!(rec.stopped_by, "iterations");
    assert!(rec.sigmas[0] == 0.0 && rec.sigmas[1..].iter().all(|s| *s > 0.0));
}

/// Equivariant PnP (`equivariant`): the j-th network call uses g = `Dihedral::draw(seed, j, square)` — the
/// record lists them; the same seed gives the same cube bit for bit for 1 and 2 threads, another seed or the
/// plain solver another cube; a non-square cube draws flips only.
#[test]
fn equivariant_pnp_is_seeded_deterministic_and_recorded() {
    use diffcassi::recon::prior::dihedral::Dihedral;
    let (op, _, y) = shift_problem(16, 16, BANDS);
    let cfg = SolverConfig { iterations: 11, tv_warmup: 5, equivariant: true, equivariant_seed: 3, ..SolverConfig::pnp_gap() };
    let solve = |cfg: &SolverConfig, threads: usize| rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| reconstruct(&op, &y, None, cfg, &|_, _| {}).unwrap());
    let (a, b) = (solve(&cfg, 1), solve(&cfg, 2));
    assert!(a.cube.iter().zip(&b.cube).all(|(p, q)| p.to_bits() == q.to_bits()), "1 vs 2 threads differ");
    let eq = &a.denoiser["equivariant"];
    assert_eq!((eq["on"].as_bool(), eq["seed"].as_u64()), (Some(true), Some(3)));
    let drawn: Vec<String> = (1..=6u64).map(|j| Dihedral::draw(3, j, true).name()).collect();
    let recorded: Vec<String> = eq["transforms"].as_array().unwrap().iter().map(|v| v.as_str().unwrap().to_string()).collect();
    assert_eq!(recorded, drawn);
    assert!(drawn.iter().any(|n| n != "r0"), "the test needs a non-identity draw: {drawn:?}");
    let plain = solve(&SolverConfig { equivariant: false, ..cfg.clone() }, 2);
    assert_eq!(plain.denoiser["equivariant"]["on"], false);
    assert!(plain.cube != a.cube, "equivariant PnP gave the plain cube");
    let other = solve(&SolverConfig { equivariant_seed: 4, ..cfg.clone() }, 2);
    assert!((1..=6u64).any(|j| Dihedral::draw(4, j, true) != Dihedral::draw(3, j, true)));
    assert!(other.cube != a.cube, "another seed gave the same cube");
    // Non-square: the four flips only (a quarter turn would swap H and W).
    let (op2, _, y2) = shift_problem(12, 16, BANDS);
    let r = reconstruct(&op2, &y2, None, &cfg, &|_, _| {}).unwrap();
    let names: Vec<&str> = r.denoiser["equivariant"]["transforms"].as_array().unwrap().iter().map(|v| v.as_str().unwrap()).collect();
    assert_eq!(names, (1..=6u64).map(|j| Dihedral::draw(3, j, false).name()).collect::<Vec<_>>());
    assert!(names.iter().all(|n| n.starts_with("r0") || n.starts_with("r2")), "{names:?}");
    // Only PnP takes it.
    let e = reconstruct(&op, &y, None, &SolverConfig { equivariant: true, ..SolverConfig::gap_tv() }, &|_, _| {}).unwrap_err().to_string();
    assert!(e.contains("equivariant") && e.contains("gap-tv"), "{e}");
}

/// The transformed call is exactly g⁻¹·D(g·x): with a pointwise denoiser (equivariant by construction) it is
/// bit for bit the plain call for all eight g; with a position-dependent one it equals the transform, the
/// denoiser and the inverse applied by hand.
#[test]
fn the_transformed_denoiser_call_inverts_exactly() {
    use diffcassi::recon::prior::dihedral::Dihedral;
    use diffcassi::recon::solver::{denoise_at_network_scale, denoise_at_network_scale_transformed};
    struct Pointwise;
    impl Denoiser for Pointwise {
        fn name(&self) -> String {
            "pointwise".into()
        }
        fn denoise(&mut self, x: &[f32], out: &mut [f32], _: CubeShape, sigma: f32) -> diffcassi::Result<()> {
            out.iter_mut().zip(x).for_each(|(o, v)| *o = v * (1.0 - sigma) + 0.01);
            Ok(())
        }
    }
    /// Adds the row index: not equivariant.
    struct Rows;
    impl Denoiser for Rows {
        fn name(&self) -> String {
            "rows".into()
        }
        fn denoise(&mut self, x: &[f32], out: &mut [f32], shape: CubeShape, _: f32) -> diffcassi::Result<()> {
            for (i, (o, v)) in out.iter_mut().zip(x).enumerate() {
                *o = v + (i / (shape.width * shape.bands)) as f32;
            }
            Ok(())
        }
    }
    let shape = CubeShape { height: 6, width: 6, bands: 3 };
    let x: Vec<f32> = scene(6, 6, 3).iter().enumerate().map(|(i, v)| v + (i % 7) as f32 * 0.013).collect();
    let (mut s1, mut s2, mut t) = (Vec::new(), Vec::new(), Vec::new());
    let (mut plain, mut rows_plain) = (vec![0.0; x.len()], vec![0.0; x.len()]);
    denoise_at_network_scale(&mut Pointwise, &x, &mut plain, shape, 0.1, &mut s1).unwrap();
    denoise_at_network_scale(&mut Rows, &x, &mut rows_plain, shape, 0.1, &mut s1).unwrap();
    for g in Dihedral::ALL {
        let mut out = vec![0.0; x.len()];
        denoise_at_network_scale_transformed(&mut Pointwise, &x, &mut out, shape, 0.1, &mut s2, Some(g), &mut t).unwrap();
        assert!(out.iter().zip(&plain).all(|(a, b)| a.to_bits() == b.to_bits()), "{}", g.name());
        // By hand with the position-dependent denoiser: p·g⁻¹(D(g·(x/p))).
        let mut got = vec![0.0; x.len()];
        let sc = denoise_at_network_scale_transformed(&mut Rows, &x, &mut got, shape, 0.1, &mut s2, Some(g), &mut t).unwrap();
        let scaled: Vec<f32> = x.iter().map(|v| v / sc.scale).collect();
        let (mut gx, mut d, mut back) = (vec![0.0; x.len()], vec![0.0; x.len()], vec![0.0; x.len()]);
        let gs = g.apply(&scaled, shape, &mut gx);
        Rows.denoise(&gx, &mut d, gs, 0.1).unwrap();
        g.invert(&d, shape, &mut back);
        let want: Vec<f32> = back.iter().map(|v| v * sc.scale).collect();
        assert!(got.iter().zip(&want).all(|(a, b)| a.to_bits() == b.to_bits()), "{}", g.name());
        if g != Dihedral::IDENTITY && g != (Dihedral { quarter_turns: 0, flip: true }) {
            assert!(got != rows_plain, "{}: the position-dependent denoiser did not notice the transform", g.name());
        }
    }
}

/// A tolerance ends the run early and says so.
#[test]
fn the_stopping_rule_ends_the_run_early() {
    let (op, _, y) = shift_problem(12, 10, 4);
    let cfg = SolverConfig { iterations: 500, tolerance: 1e-2, ..SolverConfig::gap_tv() };
    let rec = reconstruct(&op, &y, None, &cfg, &|_, _| {}).unwrap();
    assert_eq!(rec.stopped_by, "tolerance");
    assert!(rec.iterations_run < 500 && rec.iterations_run >= 2);
    assert!(*rec.relative_changes.last().unwrap() < 1e-2);
    assert!(rec.relative_changes[..rec.relative_changes.len() - 1].iter().all(|c| *c >= 1e-2));
}

/// Bad schedules and tolerances are clear errors naming the field.
#[test]
fn bad_schedule_is_a_clear_error() {
    let (op, _, y) = shift_problem(8, 8, BANDS);
    for (cfg, needle) in [
        (SolverConfig { sigma_max: -0.1, ..SolverConfig::pnp_gap() }, "σ max"),
        (SolverConfig { sigma_min: f32::NAN, ..SolverConfig::pnp_gap() }, "σ min"),
        (SolverConfig { sigma_min: 0.5, sigma_max: 0.1, ..SolverConfig::pnp_admm() }, "above σ max"),
        (SolverConfig { tolerance: f64::NAN, ..SolverConfig::pnp_gap() }, "tolerance"),
        (SolverConfig { tv_warmup: 80, iterations: 80, ..SolverConfig::pnp_gap() }, "leaves none"),
    ] {
        let e = reconstruct(&op, &y, None, &cfg, &|_, _| {}).unwrap_err().to_string();
        assert!(e.contains(needle), "`{needle}` in: {e}");
    }
}

/// Re-serialise the committed weights with one change: `edit(name, shape, data)` may alter a tensor (or
/// drop it: `None`), `meta` replaces the metadata (default: the committed file's).
fn edited_weights(edit: impl Fn(&str, &mut Vec<usize>, &mut Vec<f32>) -> bool, meta: Option<Vec<(&str, &str)>>) -> Vec<u8> {
    let bytes = std::fs::read(weights_path()).unwrap();
    let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    let mut owned: Vec<(String, Vec<usize>, Vec<u8>)> = Vec::new();
    for (name, view) in st.tensors() {
        let mut shape = view.shape().to_vec();
        let mut data: Vec<f32> = view.data().chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
        if edit(&name, &mut shape, &mut data) {
            owned.push((name, shape, data.iter().flat_map(|v| v.to_le_bytes()).collect()));
        }
    }
    let views: Vec<(String, safetensors::tensor::TensorView)> = owned.iter().map(|(n, s, d)| (n.clone(), safetensors::tensor::TensorView::new(safetensors::Dtype::F32, s.clone(), d).unwrap())).collect();
    let meta: std::collections::HashMap<String, String> = match meta {
        Some(m) => m.into_iter().map(|(k, v)| (k.to_string(), v.to_string())).collect(),
        None => safetensors::SafeTensors::read_metadata(&bytes).unwrap().1.metadata().clone().unwrap(),
    };
    safetensors::serialize(views, Some(meta)).unwrap()
}

/// Missing, corrupt, wrong-architecture, wrong-shape, incomplete and non-finite weights: clear errors
/// naming the file and the tensor or field.
#[test]
fn bad_weights_are_clear_errors() {
    let d = tempfile::tempdir().unwrap();
    let e = SpectralUNet::from_file(&d.path().join("none.safetensors")).err().unwrap().to_string();
    assert!(e.contains("none.safetensors") && e.contains("cannot read"), "{e}");
    let good = std::fs::read(weights_path()).unwrap();
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        ("truncated", good[..good.len() / 2].to_vec(), "not a valid safetensors file"),
        ("garbage", b"not weights at all".to_vec(), "not a valid safetensors file"),
        ("arch", edited_weights(|_, _, _| true, Some(vec![("arch", "resnet"), ("bands", "28"), ("width", W), ("latent", "28")])), "`arch` = `resnet`"),
        ("v1", edited_weights(|_, _, _| true, Some(vec![("arch", "spectral-unet-v1"), ("bands", "28"), ("width", W)])), "from_v1"),
        ("nobands", edited_weights(|_, _, _| true, Some(vec![("arch", ARCH), ("width", W), ("latent", "8")])), "`bands` is missing"),
        ("nolatent", edited_weights(|_, _, _| true, Some(vec![("arch", ARCH), ("bands", "28"), ("width", W)])), "`latent` is missing"),
        ("biglatent", edited_weights(|_, _, _| true, Some(vec![("arch", ARCH), ("bands", "28"), ("width", W), ("latent", "29")])), "`latent` = 29 exceeds"),
        ("badwidth", edited_weights(|_, _, _| true, Some(vec![("arch", ARCH), ("bands", "28"), ("width", "x"), ("latent", "8")])), "`width` = `x`"),
        ("wrongbands", edited_weights(|_, _, _| true, Some(vec![("arch", ARCH), ("bands", "31"), ("width", W), ("latent", "8")])), "tensor `lat_enc.weight` has shape"),
        ("bypass", edited_weights(|n, s, d| {
            if n == "bypass.weight" {
                s.clear();
                s.push(1);
                d.truncate(1);
            }
            true
        }, None), "tensor `bypass.weight` has shape [1]"),
        ("missing", edited_weights(|n, _, _| n != "mid_a.weight", None), "tensor `mid_a.weight` is missing"),
        ("shape", edited_weights(|n, s, d| {
            if n == "dec2.bias" {
                s[0] = 63;
                d.truncate(63);
            }
            true
        }, None), "tensor `dec2.bias` has shape [63]"),
        ("nan", edited_weights(|n, _, d| {
            if n == "enc1.weight" {
                d[5] = f32::NAN;
            }
            true
        }, None), "tensor `enc1.weight` value 5 is NaN"),
    ];
    for (name, bytes, needle) in cases {
        let p = d.path().join(format!("{name}.safetensors"));
        std::fs::write(&p, bytes).unwrap();
        let e = SpectralUNet::from_file(&p).err().unwrap_or_else(|| panic!("{name}: accepted")).to_string();
        assert!(e.contains(&format!("{name}.safetensors")) && e.contains(needle), "{name}: `{needle}` in: {e}");
    }
    // Weights for 8 bands load, then refuse a 28-band cube (and the 28-band network an 8-band one).
    let net = SpectralUNet::embedded().unwrap();
    let mut out = vec![0.0f32; 8 * 8 * 8];
    let mut net = net;
    let e = net.denoise(&vec![0.5; 8 * 8 * 8], &mut out, CubeShape { height: 8, width: 8, bands: 8 }, 0.1).unwrap_err().to_string();
    assert!(e.contains("trained for 28 bands, the cube has 8"), "{e}");
}

// ---- the CLI ----

fn bin(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_diffcassi")).args(args).output().expect("the binary runs")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A tiny 28-band render (16×16, one plane per band, 1 ray).
fn tiny_render(dir: &Path) {
    let o = bin(&["render", "--preset", "sp", "--scene-size", "16", "--bands", "450:650:28", "--planes", "28", "--rays", "1", "--no-mapping", "--out", s(dir)]);
    assert!(o.status.success(), "{}", stderr(&o));
}

fn read_json(p: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap()
}

/// `reconstruct --solver pnp-gap` writes the cube and a record with the σ schedule, the denoiser and the
/// stopping rule; `--operator-rays` builds the exact operator with more rays; bad weights, band count or
/// schedule → exit 1, a message naming the problem, nothing written.
#[test]
fn cli_pnp_reconstruct_and_bad_input() {
    let d = tempfile::tempdir().unwrap();
    let render = d.path().join("render");
    tiny_render(&render);
    let out = d.path().join("rec");
    let o = bin(&["reconstruct", "--from", s(&render), "--solver", "pnp-gap", "--iterations", "4", "--tv-warmup", "2", "--operator-rays", "2", "--out", s(&out)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let j = read_json(&out.join("reconstruct.json"));
    assert_eq!(j["solver"], "pnp-gap");
    assert_eq!((j["operator_rays"].as_u64(), j["acquisition_rays"].as_u64()), (Some(2), Some(1)));
    assert_eq!(j["solver_settings"]["record"]["denoiser"]["name"], ARCH);
    assert_eq!(j["solver_settings"]["record"]["sigmas"].as_array().unwrap().len(), j["iterations_run"].as_u64().unwrap() as usize);
    assert!(j["stopping"]["stopped_by"].is_string());
    assert!(out.join("cube.npy").is_file());
    // The TV phase and the schedule are recorded; --sigma-auto starts σ at the TV iterate's estimate, clamped.
    let tv = &j["solver_settings"]["record"]["denoiser"]["tv_warmup"];
    assert_eq!((tv["iterations"].as_u64(), tv["sigma_auto"].as_bool()), (Some(2), Some(false)));
    assert_eq!(j["stopping"]["tv_phase_iterations"], tv["iterations_run"]);
    let auto = d.path().join("auto");
    let o = bin(&["reconstruct", "--from", s(&render), "--solver", "pnp-gap", "--iterations", "4", "--tv-warmup", "2", "--sigma-auto", "--sigma-min", "0.001", "--plain", "--out", s(&auto)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let ja = read_json(&auto.join("reconstruct.json"));
    let rec = &ja["solver_settings"]["record"];
    assert_eq!((rec["config"]["sigma_auto"].as_bool(), rec["config"]["accelerated"].as_bool()), (Some(true), Some(false)));
    let first = rec["denoiser"]["tv_warmup"]["sigma_first"].as_f64().unwrap();
    let est = rec["denoiser"]["tv_warmup"]["tv_error_estimate"].as_f64().unwrap();
    assert!((first - est.clamp(0.001, 0.2)).abs() < 1e-6, "σ_1 {first}, ê {est}");
    // The schedule and the embedded checkpoint's CRC-32 beside the one that ran are recorded.
    let den = &j["solver_settings"]["record"]["denoiser"];
    assert_eq!(den["stage"], "gaussian");
    assert_eq!(den["weights_crc32"], den["embedded_weights_crc32"]);
    assert_eq!(den["schedule"]["network_calls_max"], 2);
    assert_eq!(den["schedule"]["sigmas"].as_array().unwrap().len(), 2);
    // --denoiser with the committed file gives the same cube as the embedded default.
    let out2 = d.path().join("rec2");
    let o = bin(&["reconstruct", "--from", s(&render), "--solver", "pnp-gap", "--iterations", "4", "--tv-warmup", "2", "--operator-rays", "2", "--denoiser", s(&weights_path()), "--out", s(&out2)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(std::fs::read(out.join("cube.npy")).unwrap(), std::fs::read(out2.join("cube.npy")).unwrap());
    // --equivariant --equivariant-seed: recorded in the configuration and the denoiser's record (one transform
    // per network call); --no-equivariant: off.
    for (flags, on) in [(vec!["--equivariant", "--equivariant-seed", "5"], true), (vec!["--no-equivariant"], false)] {
        let o3 = d.path().join(if on { "eq" } else { "noeq" });
        let mut args = vec!["reconstruct", "--from", s(&render), "--solver", "pnp-gap", "--iterations", "4", "--tv-warmup", "2", "--out", s(&o3)];
        args.extend(flags.iter());
        let o = bin(&args);
        assert!(o.status.success(), "{}", stderr(&o));
        let je = read_json(&o3.join("reconstruct.json"));
        let rec = &je["solver_settings"]["record"];
        assert_eq!(rec["config"]["equivariant"].as_bool(), Some(on), "{flags:?}");
        assert_eq!(rec["denoiser"]["equivariant"]["on"].as_bool(), Some(on), "{flags:?}");
        if on {
            assert_eq!(rec["config"]["equivariant_seed"].as_u64(), Some(5));
            assert_eq!(rec["denoiser"]["equivariant"]["transforms"].as_array().unwrap().len(), 2);
        }
    }
    let o = bin(&["reconstruct", "--from", s(&render), "--solver", "pnp-gap", "--equivariant", "--no-equivariant", "--out", s(&d.path().join("never-eq"))]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));

    let bad = d.path().join("bad.safetensors");
    std::fs::write(&bad, b"\x08\x00\x00\x00\x00\x00\x00\x00{}garbage").unwrap();
    let eight = d.path().join("render8");
    let o = bin(&["render", "--preset", "sp", "--scene-size", "16", "--bands", "450:650:8", "--planes", "8", "--rays", "1", "--no-mapping", "--out", s(&eight)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let missing = d.path().join("missing.safetensors");
    let cases: Vec<(Vec<&str>, Vec<&str>)> = vec![
        (vec!["--solver", "pnp-gap", "--denoiser", s(&missing)], vec!["missing.safetensors", "cannot read"]),
        (vec!["--solver", "pnp-gap", "--denoiser", s(&bad)], vec!["bad.safetensors"]),
        (vec!["--solver", "pnp-gap", "--sigma-max=-0.1"], vec!["--sigma-max -0.1"]),
        (vec!["--solver", "pnp-admm", "--sigma-min", "NaN"], vec!["--sigma-min NaN"]),
        (vec!["--solver", "pnp-gap", "--sigma-min", "0.5", "--sigma-max", "0.2"], vec!["above σ max"]),
        (vec!["--solver", "gap-tv", "--sigma-max", "0.2"], vec!["pnp-gap and pnp-admm only"]),
        (vec!["--solver", "admm-tv", "--sigma-auto"], vec!["pnp-gap and pnp-admm only"]),
        (vec!["--solver", "gap-tv", "--equivariant"], vec!["--equivariant", "pnp-gap and pnp-admm only"]),
        (vec!["--solver", "unrolled", "--equivariant-seed", "2"], vec!["--equivariant-seed", "not options of --solver unrolled"]),
        (vec!["--solver", "pnp-admm", "--plain"], vec!["gap-tv and pnp-gap only"]),
        (vec!["--solver", "pnp-gap", "--operator", "shift", "--operator-rays", "4"], vec!["exact operator only"]),
    ];
    for (extra, needles) in cases {
        let o2 = d.path().join("never");
        let mut args = vec!["reconstruct", "--from", s(&render), "--out", s(&o2)];
        args.extend(extra.iter());
        let o = bin(&args);
        assert_eq!(o.status.code(), Some(1), "{extra:?}: {}", stderr(&o));
        let e = stderr(&o);
        assert!(needles.iter().all(|n| e.contains(n)) && !e.contains("panicked"), "{extra:?}: {needles:?} in {e}");
        assert!(!o2.exists(), "{extra:?}: written");
    }
    // Weights for 28 bands against an 8-band acquisition.
    let o2 = d.path().join("never8");
    let o = bin(&["reconstruct", "--from", s(&eight), "--solver", "pnp-gap", "--iterations", "2", "--tv-warmup", "1", "--out", s(&o2)]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("trained for 28 bands, the cube has 8"), "{}", stderr(&o));
    assert!(!o2.exists());
}

/// `study --solvers gap-tv,pnp-gap`: one row per solver in study.csv, named.
#[test]
fn cli_study_rows_carry_the_solver_name() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("study");
    let o = bin(&["study", "--synthetic", "1", "--scene-size", "16", "--presets", "sp", "--operators", "shift", "--solvers", "gap-tv,pnp-gap", "--planes", "28", "--rays", "1", "--iterations", "3", "--tv-warmup", "1", "--out", s(&out)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let csv = std::fs::read_to_string(out.join("study.csv")).unwrap();
    let rows: Vec<&str> = csv.lines().skip(1).collect();
    assert_eq!(rows.len(), 2, "{csv}");
    assert!(rows.iter().any(|r| r.contains(",shift,gap-tv,")) && rows.iter().any(|r| r.contains(",shift,pnp-gap,")), "{csv}");
    assert!(csv.starts_with("scene,system,preset,operator,solver,psnr_db"));
}
