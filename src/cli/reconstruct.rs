//! `reconstruct`: a render folder's acquisition back to the hyperspectral cube.
//!
//! ```text
//! diffcassi render --preset sp --scene data/scenes/coffee.png --fit resize --scene-size 128 --out out/sp-coffee
//! diffcassi reconstruct --from out/sp-coffee --operator exact --solver gap-tv --iterations 100 --out out/sp-coffee-rec
//! diffcassi reconstruct --from out/sp-coffee --operator shift --out out/sp-coffee-shift     # the field's simplified model
//! diffcassi reconstruct --from out/sp-coffee --operator exact --operator-seed same --out out/oracle
//! diffcassi reconstruct --from out/sp-coffee --solver unrolled --out out/sp-coffee-unrolled  # committed SP weights
//! ```
//!
//! Everything comes from the render folder: the system (`render.json`'s `system_spec`), the render
//! configuration (scene size and pitch, bands, planes, rays, sampling, Airy blur, detector pitch), the mask
//! (`mask.png`, the file the render wrote) and the acquisition (`acquisition.exr`). The operator is rebuilt
//! from them; for `exact` with a *different* ray seed by default (acquisition seed + 1: a model never knows the
//! Monte-Carlo noise of the measurement); `--operator-seed same` gives the oracle. Outputs, all written into
//! a temporary sibling folder that is renamed into place only when complete: `cube.npy` (H, W, B) float32 +
//! `cube_wavelengths_nm.npy`, `cube.exr` (one channel per band), `rgb.png` (sRGB preview: CIE 1931 under
//! D65, [`crate::scene::colorimetry`]) and `reconstruct.json` (settings, per-iteration residual, seconds,
//! `stopping`: the rule, the noise estimate δ of [`noise_estimate`], the cap, the iteration and the reason
//! it stopped). `--truth CUBE` adds the PSNR of every iterate (evaluation only; docs/reconstruction.md,
//! "Defaults and stopping").
//!
//! The pipeline itself (render record → operator → noise estimate → solver settings → solve → record) is the
//! library's [`crate::recon::pipeline`]; this module parses the options into a
//! [`Request`](crate::recon::pipeline::Request), applies the output policy, draws the progress bars, writes
//! the folder and prints the summary.
use super::args::BackendArgs;
use super::bars::{bar, BarSlot};
use crate::error::{Error, Result};
use crate::recon::pipeline::output::{reconstruction_rule, write_reconstruction};
use crate::recon::pipeline::{self, NoiseModel, OperatorKind, RenderRecord, Request, SolveSettings};
use crate::tracer::Tracer;
use clap::Args;
use std::path::PathBuf;
use std::time::Instant;

#[derive(Args, Debug, Clone)]
pub struct ReconstructArgs {
    /// Render folder (with render.json, acquisition.exr, mask.png).
    #[arg(long = "from")]
    pub from: PathBuf,
    /// Forward model: exact (the renderer's transport), mapping (chief-ray mapping, bilinear),
    /// mapping-nearest, shift (the field's simplified SD-CASSI model).
    #[arg(long, default_value = "exact")]
    pub operator: String,
    /// Solver: gap-tv, admm-tv, pnp-gap or pnp-admm (plug-and-play with the learned denoiser), or unrolled
    /// (the unrolled network unrolled-gap-v1: K GAP stages with learned denoisers, a fixed cost; --weights,
    /// default: the committed weights of the render's system, sp or msp).
    #[arg(long, default_value = "gap-tv")]
    pub solver: String,
    #[command(flatten)]
    pub tuning: SolverTuning,
    /// Ray seed of the exact operator: a number, or `same` (the acquisition's: the oracle)
    /// [default: acquisition seed + 1].
    #[arg(long = "operator-seed")]
    pub operator_seed: Option<String>,
    /// Rays per scene pixel per plane of the exact operator [default: the acquisition's]. More rays than the
    /// acquisition approach the expected transport (less Monte-Carlo mismatch, more memory and tracing).
    #[arg(long = "operator-rays")]
    pub operator_rays: Option<usize>,
    /// Keep the exact operator's light transport in memory up to this size (GB); beyond it, re-trace on the fly
    /// [default: 4]. Exact operator only.
    #[arg(long = "transport-memory-gb")]
    pub transport_memory_gb: Option<f64>,
    /// Evaluation only: the true cube (.npy with its wavelengths file, as `evaluate --truth`); records the
    /// PSNR of every iterate and ‖y − Φx_true‖/‖y‖ in reconstruct.json `stopping` (the solver never sees it).
    #[arg(long)]
    pub truth: Option<PathBuf>,
    #[command(flatten)]
    pub backend: BackendArgs,
    /// Output folder: new, empty, or a previous reconstruction (replaced whole); never an input (--from, --denoiser,
    /// --weights, --truth), inside one or containing one.
    #[arg(long)]
    pub out: PathBuf,
    /// Accept an --out folder that holds other files (not a previous reconstruction): the outputs are moved
    /// in beside them, nothing else there is touched (docs/robustness.md, "Output policy").
    #[arg(long)]
    pub force: bool,
}

/// The tracer: `--backend` (and its options) if given, else the one the render recorded.
pub fn record_tracer(record: &RenderRecord, backend: &BackendArgs) -> Result<Box<dyn Tracer>> {
    if backend.backend.is_some() || backend.refine.is_some() || backend.mesh_max_sag_um.is_some() || backend.mesh_segments.is_some() {
        return super::shared::make_tracer(backend);
    }
    record.tracer()
}

/// The progress bars of `reconstruct`: the operator's traced rays, then the solver's iterations.
struct Bars(BarSlot);

impl pipeline::Progress for Bars {
    fn operator_started(&self, name: &str, rays: u64) {
        self.0.show(bar(rays, "{msg} [{elapsed_precise}] {wide_bar} {human_pos}/{human_len} rays, ETA {eta}", &format!("operator {name}")));
    }
    fn rays(&self, n: u64) {
        self.0.with(|pb| pb.inc(n));
    }
    fn operator_done(&self) {
        self.0.clear();
    }
    fn solve_started(&self, label: &str, iterations: usize) {
        self.0.show(bar(iterations as u64, "{msg} [{elapsed_precise}] {wide_bar} {pos}/{len} iterations, ETA {eta}", label));
    }
    fn iteration(&self, label: &str, _k: usize, residual: f64) {
        self.0.with(|pb| {
            pb.set_message(format!("{label}: residual {residual:.3e}"));
            pb.inc(1);
        });
    }
    fn solve_done(&self) {
        self.0.clear();
    }
    fn warning(&self, message: &str) {
        eprintln!("warning: {message}");
    }
}

pub fn reconstruct(a: ReconstructArgs) -> Result<()> {
    let t0 = Instant::now();
    let kind = OperatorKind::parse(&a.operator)?;
    let request = Request {
        operator: kind,
        operator_seed: a.operator_seed.clone(),
        operator_rays: a.operator_rays,
        transport_memory_gb: a.transport_memory_gb,
        settings: a.tuning.settings(&a.solver, a.tuning.accelerated),
    };
    if let Some(t) = a.backend.tolerance_um {
        // Accepted by the shared backend options but never used here: refuse rather than ignore it.
        return Err(Error::invalid(format!(
            "--tolerance-um {t}: reconstruct does not choose a tracer by tolerance — the operator is rebuilt with the render's tracer (render.json `tracer`) or the one --backend names; the rays per pixel are the render's"
        )));
    }
    if a.backend.calibration_cache.is_some() {
        return Err(Error::invalid("--calibration-cache: only used with --tolerance-um, which reconstruct does not take"));
    }
    request.validate()?;
    // The output policy before any work: --out never an input (--from, --denoiser, --truth), inside one or
    // containing one.
    let mut inputs = vec![("--from", a.from.as_path())];
    inputs.extend(a.tuning.denoiser.as_deref().map(|p| ("--denoiser", p)));
    inputs.extend(a.tuning.weights.as_deref().map(|p| ("--weights", p)));
    inputs.extend(a.truth.as_deref().map(|p| ("--truth", p)));
    crate::io::policy::check_out_folder(&a.out, &reconstruction_rule(a.force), &inputs)?;
    let record = RenderRecord::load(&a.from)?;
    let truth = a.truth.as_deref().map(|p| pipeline::load_truth(&record, p)).transpose()?;
    // The staging folder, filled and swapped in at the end (a killed run's is removed by the next).
    let set = crate::io::OutputSet::folder(&a.out, &reconstruction_rule(a.force), &inputs)?;
    let tracer = record_tracer(&record, &a.backend)?;
    let done = pipeline::reconstruct(record, &request, tracer.as_ref(), truth.as_ref(), &Bars(BarSlot::default()))?;
    let mut json = done.record;
    if let Some(o) = json.as_object_mut() {
        o.insert("seconds".into(), serde_json::json!(t0.elapsed().as_secs_f64()));
    }
    write_reconstruction(set, &done.cube, &json, true)?;
    println!(
        "{} / {} / {}: {}×{}×{} cube, {} {}, final residual {:.4e}; operator {:.2} s, solve {:.2} s, total {:.2} s → {}",
        done.system,
        kind.name(),
        request.settings.solver,
        done.cube.height,
        done.cube.width,
        done.cube.bands(),
        done.iterations_run,
        if pipeline::is_unrolled(&request.settings.solver) { "stages" } else { "iterations" },
        done.final_residual,
        done.seconds_operator,
        done.seconds_solve,
        t0.elapsed().as_secs_f64(),
        a.out.display()
    );
    Ok(())
}

/// The solver options `reconstruct` and `study` share (one definition, so their flags and help agree).
#[derive(Args, Debug, Clone)]
pub struct SolverTuning {
    /// Iterations [default: the solver's].
    #[arg(long)]
    pub iterations: Option<usize>,
    /// TV weight [default: the solver's].
    #[arg(long = "tv-weight")]
    pub tv_weight: Option<f64>,
    /// GAP-TV / PnP-GAP: the accelerated variant (Liao/Yuan) — their default since the measured defaults
    /// (docs/reconstruction.md, "Defaults and stopping"); kept so older commands keep working.
    #[arg(long)]
    pub accelerated: bool,
    /// GAP-TV / PnP-GAP: plain GAP instead of the accelerated default (the former default).
    #[arg(long, conflicts_with = "accelerated")]
    pub plain: bool,
    /// pnp-gap / pnp-admm: the denoiser's weights (safetensors, arch spectral-unet-v2) [default: the
    /// embedded checkpoint].
    #[arg(long)]
    pub denoiser: Option<PathBuf>,
    /// unrolled: the network's weights (safetensors, arch unrolled-gap-v1, scripts/train_unrolled.py)
    /// [default: the committed diffcassi/weights/unrolled-gap-v1-SYSTEM.safetensors of the render's system,
    /// embedded]. Refused: another system, band count or wavelengths; warned: another mask, planes, rays or
    /// Airy diameter (docs/reconstruction.md, "Unrolled network in Rust").
    #[arg(long)]
    pub weights: Option<PathBuf>,
    /// pnp-gap / pnp-admm: σ of the first network denoising (relative to the cube's peak, in (0, 1]); with
    /// --sigma-auto the ceiling of σ_1 [default 0.2].
    #[arg(long = "sigma-max")]
    pub sigma_max: Option<f64>,
    /// pnp-gap / pnp-admm: the floor σ of the last denoising (geometric schedule), in (0, σ max]
    /// [default 0.05].
    #[arg(long = "sigma-min")]
    pub sigma_min: Option<f64>,
    /// pnp-gap / pnp-admm: start the σ schedule at the TV iterate's estimated error (what TV removed in its
    /// last step, clamped to [σ min, σ max]) instead of σ max (measured: it underestimates the error ≈ 10×).
    #[arg(long = "sigma-auto")]
    pub sigma_auto: bool,
    /// pnp-gap / pnp-admm: equivariant PnP — every network call denoises a randomly flipped or rotated
    /// iterate and turns the result back (the 8 flips/quarter turns of a square cube, the 4 flips otherwise;
    /// drawn from --equivariant-seed and the call's number) [default: the library's, docs/reconstruction.md,
    /// "Equivariant PnP"].
    #[arg(long, conflicts_with = "no_equivariant")]
    pub equivariant: bool,
    /// pnp-gap / pnp-admm: no random flips/rotations around the network (today's PnP before equivariance).
    #[arg(long = "no-equivariant")]
    pub no_equivariant: bool,
    /// pnp-gap / pnp-admm: the seed of the equivariant transforms' stream [default 0].
    #[arg(long = "equivariant-seed")]
    pub equivariant_seed: Option<u64>,
    /// pnp-gap / pnp-admm: the TV phase's cap (GAP-TV / ADMM-TV iterations before the network; the phase
    /// ends earlier at GAP-TV's own discrepancy stop) [default 300]; must leave at least one of
    /// --iterations to the network.
    #[arg(long = "tv-warmup")]
    pub tv_warmup: Option<usize>,
    /// Stopping rule: stop when the relative change ‖θ_k − θ_{k−1}‖/‖θ_k‖ falls below this (0: run every
    /// iteration) [default: the solver's: 0 (TV and PnP)].
    #[arg(long)]
    pub tolerance: Option<f64>,
    /// Stopping rule (discrepancy principle): stop once ‖y − Φθ‖₂ ≤ τ·δ, δ the noise norm estimated from
    /// render.json (sensor noise, the exact operator's Monte-Carlo mismatch); 0 turns it off
    /// [default: the solver's, docs/reconstruction.md].
    #[arg(long)]
    pub discrepancy: Option<f64>,
    /// How δ's Monte-Carlo term (exact operator, another seed) is estimated: `spread` — from the data, the
    /// operator's spread against a twin traced with another seed, at the current iterate (twice the
    /// operator's memory and tracing, one more Φ every 5 iterations); `model` — the constant relative
    /// mismatch measured on 128² crops (cheaper; miscalibrated on smoother, larger scenes)
    /// [docs/reconstruction.md, "Defaults and stopping"].
    /// Exact operator only [default: spread].
    #[arg(long = "noise-estimate", value_parser = ["spread", "model"])]
    pub noise_estimate: Option<String>,
}

impl SolverTuning {
    /// The settings of one solve with `solver`; `accelerated` as given (the caller decides whether it applies).
    pub fn settings(&self, solver: &str, accelerated: bool) -> SolveSettings {
        SolveSettings {
            solver: solver.to_string(),
            iterations: self.iterations,
            tv_weight: self.tv_weight,
            accelerated,
            plain: self.plain,
            denoiser: self.denoiser.clone(),
            sigma_max: self.sigma_max,
            sigma_min: self.sigma_min,
            sigma_auto: self.sigma_auto,
            equivariant: match (self.equivariant, self.no_equivariant) {
                (true, _) => Some(true),
                (_, true) => Some(false),
                _ => None,
            },
            equivariant_seed: self.equivariant_seed,
            tolerance: self.tolerance,
            tv_warmup: self.tv_warmup,
            discrepancy: self.discrepancy,
            noise: None,
            noise_model: self.noise_estimate.as_deref().map(|e| if e == "model" { NoiseModel::Model } else { NoiseModel::Spread }),
            weights: self.weights.clone(),
            unrolled: None,
        }
    }
}
