//! `render` and `bench-render`: coded acquisitions of hyperspectral scenes (`render-dataset` is in
//! [`super::dataset`], which uses the helpers here).
//!
//! ```text
//! diffcassi render --preset sp                                   # synthetic demo scene → out/render-sp
//! diffcassi render --preset ap --scene scene.exr --out out/ap     # a KAIST-style EXR
//! diffcassi render --preset sp --noise shot,read,adc --full-well-e 20000 --read-noise-e 2 --adc-bits 12
//! diffcassi bench-render --preset sp                              # the paper-scale timing table
//! ```
use super::args::{BackendArgs, SystemArgs};
use super::shared::{load_system, parse_wavelengths_for};
use crate::error::{Error, Result};
use crate::render::settings::{MaskSource, NoiseSettings, RenderSettings};
use crate::render::folder::{self, RenderProgress, RenderRequest, SceneSource};
use crate::render::{Mask, NoiseConfig, RenderConfig, Renderer, Sampling, SpectralSampling};
use crate::scene::{synthetic_scene, synthetic_wavelengths, Fit, SpectralCube};
pub use crate::render::settings::{check_render_rays, check_scene_values};
use crate::tracer::AnalyticTracer;
use clap::Args;
use indicatif::ProgressBar;
use std::path::PathBuf;
use std::time::Instant;

/// Settings shared by `render` and `render-dataset`: the command-line form of the library's
/// [`RenderSettings`] (defaults, limits and checks live there; [`RenderCommon::settings`] converts).
#[derive(Args, Debug, Clone)]
pub struct RenderCommon {
    #[command(flatten)]
    pub system: SystemArgs,
    #[command(flatten)]
    pub backend: BackendArgs,
    /// Scene side N (pixels of 10 µm on the object plane): scenes are cropped/resized to N×N.
    #[arg(long = "scene-size", default_value_t = 512)]
    pub scene_size: usize,
    /// For a system whose object is at infinity: the scene's full angular extent across its width
    /// (degrees, in (0, 180)); pixels are sampled uniformly in field angle. Refused for finite objects.
    #[arg(long = "scene-fov-deg", allow_hyphen_values = true)]
    pub scene_fov_deg: Option<f64>,
    /// Bands: list or first:last:count (nm).
    #[arg(long, default_value = "450:650:28")]
    pub bands: String,
    /// Spectral planes K over the bands' range (K = bands × oversampling; 112 = 28 × 4, the paper's).
    #[arg(long, default_value_t = 112)]
    pub planes: usize,
    /// Rays per scene pixel per plane [default: 20; with --tolerance-um, chosen].
    #[arg(long)]
    pub rays: Option<usize>,
    /// Seed of the rays' random numbers.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Ray sampling: stratified (pupil × pixel area) or independent.
    #[arg(long, default_value = "stratified")]
    pub sampling: String,
    /// Mask file (greyscale PNG or (H, W) NPY); default a random binary mask.
    #[arg(long)]
    pub mask: Option<PathBuf>,
    /// Opening ratio of the random mask (not with --mask).
    #[arg(long, default_value_t = 0.5, conflicts_with = "mask")]
    pub opening: f64,
    /// Seed of the random mask (not with --mask).
    #[arg(long = "mask-seed", default_value_t = 0, conflicts_with = "mask")]
    pub mask_seed: u64,
    /// Airy disk diameter (pixels) at 520 nm, ∝ λ (not with --no-airy).
    #[arg(long = "airy-diameter-px", default_value_t = 2.5, conflicts_with = "no_airy")]
    pub airy_diameter_px: f64,
    /// No diffraction blur.
    #[arg(long = "no-airy")]
    pub no_airy: bool,
    /// Wavelengths (nm) of the scene file's bands, overriding what the file says.
    #[arg(long = "scene-wavelengths")]
    pub scene_wavelengths: Option<String>,
    /// How to bring scenes to N×N: crop (centre) or resize (area average, then centre crop).
    #[arg(long, default_value = "crop")]
    pub fit: String,
    /// Also write cube.exr: the detector image of each band (their sum is the acquisition).
    #[arg(long)]
    pub cube: bool,
    /// Do not write the mapping cube (mapping.npy).
    #[arg(long = "no-mapping")]
    pub no_mapping: bool,
    /// f64 ray kernel of the analytic backend: simd (lanes, best instruction set of this CPU), scalar (the
    /// reference, for benchmarking), or simd-avx512 / simd-avx2 / simd-portable. Same numbers (≤ 1e-12 mm).
    #[arg(long, default_value = "simd")]
    pub kernel: String,
    /// Float precision of the ray kernel: f64 (exact, the default) or f32 (the SIMD lanes in f32, twice as
    /// many; its error against f64 is measured by `bench tradeoff`, see docs/performance.md). With
    /// --tolerance-um, chosen.
    #[arg(long, value_name = "f64|f32", value_parser = <crate::tracer::Precision as std::str::FromStr>::from_str)]
    pub precision: Option<crate::tracer::Precision>,
    /// Where to render: cpu, or cuda / cuda:N (the GPU kernels on CUDA device 0 / N, in --precision f64 or f32; docs/gpu.md), or
    /// cpu-twin (the GPU kernels run on the CPU, slowly: the device's bits where there is no GPU).
    #[arg(long, default_value = "cpu", value_name = "cpu|cuda[:N]|cpu-twin", value_parser = device_arg)]
    pub device: crate::render::Device,
}

impl RenderCommon {
    /// The library's render settings these options describe (the text forms parsed; the values checked
    /// by [`RenderSettings::config`]).
    pub fn settings(&self) -> Result<RenderSettings> {
        Ok(RenderSettings {
            scene_size: self.scene_size,
            bands_nm: parse_wavelengths_for("--bands", &self.bands)?,
            planes: self.planes,
            rays: self.rays,
            seed: self.seed,
            sampling: parse_sampling(&self.sampling)?,
            mask: match &self.mask {
                Some(p) => MaskSource::File(p.clone()),
                None => MaskSource::Random { opening: self.opening, seed: self.mask_seed },
            },
            airy_diameter_px: (!self.no_airy).then_some(self.airy_diameter_px),
            scene_wavelengths_nm: self.scene_wavelengths.as_deref().map(|t| parse_wavelengths_for("--scene-wavelengths", t)).transpose()?,
            fit: Fit::parse(&self.fit)?,
            cube: self.cube,
            kernel: self.kernel.parse()?,
            precision: self.precision,
            device: self.device,
            scene_fov_deg: self.scene_fov_deg,
            mapping: !self.no_mapping,
            tolerance_chooses_rays: self.backend.tolerance_um.is_some(),
        })
    }
}


#[derive(Args, Debug)]
pub struct RenderArgs {
    #[command(flatten)]
    pub common: RenderCommon,
    /// Scene: .exr (KAIST-style), .npy (H, W, B) or a folder of per-band PNGs (CAVE-style).
    #[arg(long, conflicts_with = "synthetic")]
    pub scene: Option<PathBuf>,
    /// Render the synthetic scene of this seed (the default, with seed 0).
    #[arg(long)]
    pub synthetic: Option<u64>,
    /// Output folder (default out/render-<system>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Accept an --out folder that holds other files (not a previous output of this command): the outputs
    /// are moved in beside them, nothing else there is touched (docs/robustness.md, "Output policy").
    #[arg(long)]
    pub force: bool,
    #[command(flatten)]
    pub noise: NoiseArgs,
    #[command(flatten)]
    pub ghosts: super::render_ghosts::GhostArgs,
}

/// Sensor noise on the finished acquisition (off unless `--noise` is given); see `docs/noise.md`.
#[derive(Args, Debug, Clone, Default)]
pub struct NoiseArgs {
    /// Sensor noise sources, a comma list of shot (Poisson photon noise), read (Gaussian read noise), adc
    /// (quantisation); `none` or absent: no noise.
    #[arg(long)]
    pub noise: Option<String>,
    /// Full-well capacity (electrons): the ADC's full scale and, without --electrons-per-unit, the electrons of
    /// the clean acquisition's brightest pixel [default: 20000].
    #[arg(long = "full-well-e")]
    pub full_well_e: Option<f64>,
    /// Exposure: photo-electrons per acquisition unit (instead of mapping the peak to the full well).
    #[arg(long = "electrons-per-unit")]
    pub electrons_per_unit: Option<f64>,
    /// Read noise σ (electrons) [default with `read`: 2].
    #[arg(long = "read-noise-e")]
    pub read_noise_e: Option<f64>,
    /// ADC bit depth [default with `adc`: 12].
    #[arg(long = "adc-bits")]
    pub adc_bits: Option<u32>,
    /// Seed of the noise's random numbers [default: 0].
    #[arg(long = "noise-seed")]
    pub noise_seed: Option<u64>,
}

impl NoiseArgs {
    /// The library's noise settings these options describe.
    pub fn settings(&self) -> NoiseSettings {
        NoiseSettings {
            noise: self.noise.clone(),
            full_well_e: self.full_well_e,
            electrons_per_unit: self.electrons_per_unit,
            read_noise_e: self.read_noise_e,
            adc_bits: self.adc_bits,
            noise_seed: self.noise_seed,
        }
    }

    /// The noise the options describe (`None`: off); see [`NoiseSettings::config`].
    pub fn config(&self) -> Result<Option<NoiseConfig>> {
        self.settings().config()
    }
}

#[derive(Args, Debug)]
pub struct BenchRenderArgs {
    #[arg(long, default_value = "sp")]
    pub preset: String,
    #[arg(long = "scene-size", default_value_t = 512)]
    pub scene_size: usize,
    #[arg(long, default_value_t = 112)]
    pub planes: usize,
    #[arg(long, default_value_t = 20)]
    pub rays: usize,
    /// Mask opening ratio.
    #[arg(long, default_value_t = 0.5)]
    pub opening: f64,
    /// Scenes rendered in the dataset-mode part.
    #[arg(long, default_value_t = 3)]
    pub scenes: usize,
    /// Kernels timed on the acquisition, side by side (comma-separated: simd, scalar, simd-avx2, …); the
    /// first one also runs the all-open and dataset rows.
    #[arg(long, default_value = "simd,scalar")]
    pub kernels: String,
    /// Precisions timed on the acquisition and the mapping, side by side (comma-separated: f64, f32); f32
    /// runs with the first SIMD kernel of --kernels and prints its largest difference from f64.
    #[arg(long, default_value = "f64,f32")]
    pub precisions: String,
    /// Parts to run (comma-separated): mapping (the chief-ray mapping cube, exact and interpolated),
    /// acquisition (per-scene render, all-open render), dataset (transport once, then per scene).
    #[arg(long, default_value = "mapping,acquisition,dataset")]
    pub parts: String,
    /// Tolerance (µm) of the interpolated mapping cube: the largest stride whose error, measured by the
    /// fidelity calibration (`--tolerance-um`), is within it.
    #[arg(long = "mapping-tolerance-um", default_value_t = 1e-3)]
    pub mapping_tolerance_um: f64,
    /// cuda (or cuda:N): also render the acquisition on CUDA device 0 (N) (the GPU kernels, f64), twice,
    /// beside the CPU's rows: its time, whether the two runs are bit-identical, its largest difference from
    /// the CPU.
    #[arg(long, default_value = "cpu", value_name = "cpu|cuda[:N]", value_parser = bench_device_arg)]
    pub device: crate::render::Device,
}

/// A memory size in GB: finite and ≥ 0 (clap names the option in the error).
/// A `--device` value (clap names the option and the value, and exits 2 as for any bad value): the library's
/// parse ([`crate::render::Device::parse_value`]).
pub(super) fn device_arg(s: &str) -> std::result::Result<crate::render::Device, String> {
    crate::render::Device::parse_value(s)
}

/// `bench-render --device`: cpu or cuda[:N] (the twin is for checking a GPU's results, `render --device
/// cpu-twin`; the library's message for an unknown name offers it).
fn bench_device_arg(s: &str) -> std::result::Result<crate::render::Device, String> {
    match crate::render::Device::parse_value(s) {
        Ok(crate::render::Device::CpuTwin) => Err("use cpu or cuda (the twin is for checking a GPU's results, `render --device cpu-twin`)".into()),
        Err(_) if !s.trim().starts_with("cuda:") => Err("use cpu, cuda or cuda:N".into()),
        other => other,
    }
}

pub(super) fn positive_gb(s: &str) -> std::result::Result<f64, String> {
    let v: f64 = s.trim().parse().map_err(|_| format!("`{s}` is not a number of GB"))?;
    if v.is_finite() && v >= 0.0 {
        Ok(v)
    } else {
        Err(format!("{v} GB: must be finite and ≥ 0"))
    }
}

fn parse_sampling(s: &str) -> Result<Sampling> {
    match s {
        "stratified" => Ok(Sampling::Stratified),
        "independent" => Ok(Sampling::Independent),
        _ => Err(Error::invalid(format!("--sampling `{s}`: use stratified or independent"))),
    }
}

/// The render's tracer, rays per pixel and precision (set in `cfg`): as given, or chosen by `--tolerance-um`
/// ([`crate::fidelity::RenderTracing::resolve`], the library's step; its explanation printed here).
pub(super) fn render_tracer(a: &RenderCommon, settings: &crate::render::RenderSettings, system: &crate::system::SequentialSystem, cfg: &mut RenderConfig, mask: &Mask) -> Result<crate::fidelity::RenderTracing> {
    let t = crate::fidelity::RenderTracing::resolve(super::fidelity::render_source(&a.backend)?, system, settings, cfg, mask)?;
    if let Some(x) = &t.explanation {
        println!("{x}");
    }
    Ok(t)
}

/// A bar of traced rays (`render`, `bench-render`, `render-dataset`).
pub(super) fn progress_bar(total: u64, what: &str) -> ProgressBar {
    super::bars::bar(total, "{msg} [{elapsed_precise}] {wide_bar} {human_pos}/{human_len} rays, {per_sec}, ETA {eta}", what)
}

fn default_out(a: &RenderCommon) -> PathBuf {
    let name = match (&a.system.preset, &a.system.system) {
        (Some(p), _) => p.clone(),
        (None, Some(f)) => f.file_stem().unwrap_or_default().to_string_lossy().into_owned(),
        _ => "system".into(),
    };
    PathBuf::from("out").join(format!("render-{name}"))
}

/// The terminal's view of a render: the rays' bar, warnings on stderr, the noise's line.
#[derive(Default)]
struct Terminal {
    rays: super::bars::BarSlot,
    what: String,
}

impl RenderProgress for Terminal {
    fn warning(&self, text: &str) {
        eprintln!("warning: {text}");
    }
    fn tracing_started(&self, rays: u64) {
        self.rays.show(progress_bar(rays, &self.what));
    }
    fn rays(&self, n: u64) {
        self.rays.with(|pb| pb.inc(n));
    }
    fn tracing_done(&self) {
        self.rays.clear();
    }
    fn noise(&self, noise: &NoiseConfig, report: &crate::render::NoiseReport) {
        println!(
            "sensor noise ({}): {} e⁻ per unit, peak {} e⁻{}",
            noise.sources().join(","),
            sig4(report.electrons_per_unit),
            if (1.0..1e7).contains(&report.peak_electrons) { format!("{:.0}", report.peak_electrons) } else { sig4(report.peak_electrons) },
            report.adc_gain_e_per_dn.map(|g| format!(", ADC {} e⁻/DN, {} saturated pixels", sig4(g), report.saturated_pixels)).unwrap_or_default()
        );
    }
}

/// Four decimals, or four significant digits outside [0.1, 10⁷) (an exposure of 1e-150 electrons per unit
/// printed as 0.0000, 1e-3 as 0.0010, a peak of 0.4 e⁻ as 0; round 16).
fn sig4(v: f64) -> String {
    if v != 0.0 && v.is_finite() && !(0.1..1e7).contains(&v.abs()) {
        format!("{v:.4e}")
    } else {
        format!("{v:.4}")
    }
}

/// `render`: the library's one-scene pipeline ([`crate::render::folder`]); this client chooses the system
/// and the tracer (`--tolerance-um`) and prints.
pub fn render(a: RenderArgs) -> Result<()> {
    let settings = a.common.settings()?;
    let scene = match &a.scene {
        Some(p) => SceneSource::File(p.clone()),
        None => SceneSource::Synthetic(a.synthetic.unwrap_or(0)),
    };
    let mut request = RenderRequest::new(scene, a.out.clone().unwrap_or_else(|| default_out(&a.common)), &settings);
    request.force = a.force;
    request.mapping = !a.common.no_mapping;
    request.tolerance_um = a.common.backend.tolerance_um;
    let mut inputs = super::shared::system_inputs(&a.common.system);
    inputs.extend(a.common.mask.as_deref().map(|p| ("--mask", p)));
    // The output policy before any work: --out new, empty or a previous render (or --force), never an input.
    folder::check(&request, &inputs)?;
    request.noise = a.noise.config()?;
    let system = load_system(&a.common.system)?;
    let (mut cfg, mask) = settings.config()?;
    let n = settings.scene_size;
    // The scene is loaded and checked before the (possibly long) tracer calibration and render.
    let (scene, desc) = folder::load_scene(&request, n)?;
    let tracing = render_tracer(&a.common, &settings, &system, &mut cfg, &mask)?;
    request.tolerance_predicted_error_um = tracing.predicted_error_um;
    let renderer = Renderer::new(&system, tracing.tracer.as_ref(), cfg, mask)?;
    // The ghost pass's kernel (mechanics meshes loaded and checked) before anything is written.
    let ghost_pass = super::render_ghosts::GhostPass::prepare(&a.ghosts, &a.common.system, &system, renderer.config.rays_per_pixel, renderer.config.seed)?;
    let terminal = Terminal { what: format!("render {}", system.name()), ..Terminal::default() };
    let done = folder::run(&request, &inputs, &renderer, &scene, &desc, ghost_pass.as_ref().map(|p| p as &dyn folder::AcquisitionPass), &terminal)?;
    println!(
        "{}: {}×{} scene, {} planes × {} rays: {} rays in {:.2} s ({:.2} M rays/s, {} threads), detector {}×{}, transmission {:.4}; total {:.2} s → {}",
        system.name(),
        n,
        n,
        renderer.config.spectral.planes(),
        renderer.config.rays_per_pixel,
        done.rays_traced,
        done.render_seconds,
        done.record["rays_per_second"].as_f64().unwrap_or(0.0) / 1e6,
        rayon::current_num_threads(),
        done.detector_width,
        done.detector_height,
        done.transmission,
        done.total_seconds,
        done.out.display()
    );
    Ok(())
}

/// The acquisition rows of `bench-render`: `renderer` (the first kernel and precision), then each further
/// (kernel, precision) variant on the same mask and scene (with the largest difference of its image from
/// the first, absolute and relative to the image's peak), then the all-open mask.
#[allow(clippy::too_many_arguments)]
fn bench_acquisitions(system: &crate::system::SequentialSystem, renderer: &Renderer, variants: &[(crate::tracer::Kernel, crate::tracer::Precision)], scene: &SpectralCube, setup: f64, opening: f64, device: crate::render::Device, row: &dyn Fn(&str, f64, u64)) -> Result<()> {
    let (first, first_p) = (renderer.config.kernel, renderer.config.precision);
    let t = Instant::now();
    let acq = renderer.render(scene, false, &|_| {})?;
    row(&format!("acquisition, {} kernel {first_p} (setup {setup:.2} s + render)", first.name()), t.elapsed().as_secs_f64() + setup, acq.stats.traced);
    let peak = acq.image.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    if let crate::render::Device::Cuda(ordinal) = device {
        bench_gpu(renderer, scene, &acq, ordinal, row)?;
    }
    for &(k, p) in &variants[1..] {
        let mut c = renderer.config.clone();
        c.kernel = k;
        c.precision = p;
        let tr = AnalyticTracer::with_kernel(k);
        let t = Instant::now();
        let other = Renderer::new(system, &tr, c, renderer.mask.clone())?;
        let acq_k = other.render(scene, false, &|_| {})?;
        let secs = t.elapsed().as_secs_f64();
        let diff = acq_k.image.iter().zip(&acq.image).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        let rel = if peak > 0.0 { diff / peak } else { 0.0 };
        row(&format!("acquisition, {} kernel {p} (setup + render; max |Δ| vs {} {first_p} {diff:.1e}, {rel:.1e} of the peak)", k.name(), first.name()), secs, acq_k.stats.traced);
    }
    if opening < 1.0 {
        let (n, m) = (renderer.config.scene_height, renderer.config.scene_width);
        let open = Renderer::new(system, renderer.tracer, renderer.config.clone(), Mask::open(n, m))?;
        let t = Instant::now();
        let acq = open.render(scene, false, &|_| {})?;
        row(&format!("acquisition, all-open mask (every ray), {} kernel", first.name()), t.elapsed().as_secs_f64(), acq.stats.traced);
    }
    Ok(())
}

/// The acquisition on CUDA device `ordinal`, twice (the second run is timed; both must have the same bits),
/// against the CPU's acquisition `cpu` of the same seed.
fn bench_gpu(renderer: &Renderer, scene: &SpectralCube, cpu: &crate::render::Acquisition, ordinal: usize, row: &dyn Fn(&str, f64, u64)) -> Result<()> {
    use crate::render::device::{render_on, Executor};
    let (a, _) = render_on(renderer, scene, false, Executor::Cuda(ordinal))?;
    let t = Instant::now();
    let (b, rec) = render_on(renderer, scene, false, Executor::Cuda(ordinal))?;
    let wall = t.elapsed().as_secs_f64();
    let same = a.same_bits(&b);
    let kernels_s = rec.kernels_ms.unwrap_or(0.0) / 1e3;
    row(&format!("acquisition, GPU {} f64, kernels only (CUDA events)", rec.gpu.clone().unwrap_or_default()), kernels_s, b.stats.traced);
    row(&format!("acquisition, GPU f64 with plan, uploads and copy back (max |Δ| vs CPU {:.1e} of the peak; two runs bit-identical: {})", b.max_diff_of_peak(cpu), if same { "yes" } else { "NO" }), wall, b.stats.traced);
    println!("(GPU: {}, driver {}, {}; {})", rec.gpu.unwrap_or_default(), rec.driver.unwrap_or_default(), rec.ptx.unwrap_or_default(), rec.accumulation);
    if !same {
        return Err(Error::invalid(format!("bench-render --device {}: two GPU runs of the same render differ (the accumulation must be deterministic)", crate::render::Device::Cuda(ordinal))));
    }
    Ok(())
}

/// The interpolated mapping cube beside the exact one: the stride the fidelity calibration picks for
/// `tolerance_um` (its error measured at the check pixels), timed, and its error over every entry of the
/// exact cube. A line lists every stride's full error, so the margin is visible.
fn bench_interpolated_mapping(system: &crate::system::SequentialSystem, tracer: &AnalyticTracer, exact: &crate::analysis::MappingCube, tolerance_um: f64, row: &dyn Fn(&str, f64, u64), cpu0: &std::cell::Cell<Option<f64>>) -> Result<()> {
    use crate::analysis::mapping_cube_interpolated;
    use crate::fidelity::{calibrate_mapping, mapping_error, CacheOptions};
    let (h, w, ws, pitch) = (exact.height, exact.width, &exact.wavelength_nm, exact.pixel_pitch_mm);
    let (cal, _) = calibrate_mapping(system, h, w, pitch, ws, &CacheOptions::none())?;
    let ok = |s: &crate::fidelity::StrideModel| s.stride > 1 && s.error.is_some_and(|e| e.mismatches == 0 && e.max_um <= tolerance_um);
    let mut full = Vec::new();
    for s in cal.strides.iter().filter(|s| s.stride > 1) {
        let e = match mapping_cube_interpolated(system, tracer, h, w, pitch, ws, s.stride) {
            Ok(m) => {
                let e = mapping_error(exact, &m);
                if e.mismatches > 0 { format!("{} mismatches", e.mismatches) } else { format!("{:.2e} µm", e.max_um) }
            }
            Err(_) => "refused (a node does not arrive)".into(),
        };
        full.push(format!("stride {} {e} (check pixels {})", s.stride, s.error.map_or("n/a".into(), |e| format!("{:.2e}", e.max_um))));
    }
    let Some(pick) = cal.strides.iter().filter(|s| ok(s)).max_by_key(|s| s.stride) else {
        println!("(interpolated mapping: no stride within {tolerance_um} µm; max error vs exact: {})", full.join("; "));
        return Ok(());
    };
    cpu0.set(super::shared::process_cpu_seconds());
    let t = Instant::now();
    let m = mapping_cube_interpolated(system, tracer, h, w, pitch, ws, pick.stride)?;
    let secs = t.elapsed().as_secs_f64();
    let e = mapping_error(exact, &m);
    let rays = (crate::analysis::NodeGrid::count(h, w, pick.stride) * ws.len()) as u64;
    let err = if e.mismatches > 0 { format!("{} entries mismatched", e.mismatches) } else { format!("max error vs exact {:.2e} µm", e.max_um) };
    row(&format!("mapping cube {h}×{w}×{}, interpolated, stride {} (chosen for {tolerance_um} µm); {err}", ws.len(), pick.stride), secs, rays);
    println!("(interpolated mapping, max error vs the exact cube over every entry: {})", full.join("; "));
    Ok(())
}


pub fn bench_render(a: BenchRenderArgs) -> Result<()> {
    // cpu-twin is refused by the option's parser (bench_device_arg).
    let device = a.device;
    device.check()?;
    let system = crate::system::SequentialSystem::build(&crate::presets::spec(&a.preset)?)?;
    let n = a.scene_size;
    if n == 0 || a.planes == 0 || a.planes > crate::limits::MAX_PLANES || a.rays == 0 || !(a.opening.is_finite() && (0.0..=1.0).contains(&a.opening)) {
        return Err(Error::invalid(format!("--scene-size {n}, --planes {}, --rays {}, --opening {}: sizes must be ≥ 1 (planes ≤ {}), the opening in [0, 1]", a.planes, a.rays, a.opening, crate::limits::MAX_PLANES)));
    }
    if !(a.mapping_tolerance_um.is_finite() && a.mapping_tolerance_um > 0.0) {
        return Err(Error::invalid(format!("--mapping-tolerance-um {}: must be finite and > 0", a.mapping_tolerance_um)));
    }
    if a.scenes == 0 || a.scenes > crate::limits::MAX_SCENES {
        return Err(Error::invalid(format!("--scenes {}: must be in 1..={}", a.scenes, crate::limits::MAX_SCENES)));
    }
    // Two renders' buffers, then the rays (acquisition, all-open acquisition, transport: three renders' rays;
    // each dataset scene applies the transport, a render's worth of footprints), then the chief-ray mapping
    // cube (n × n × planes).
    crate::limits::check_memory(&format!("--scene-size {n} × --planes {}", a.planes), 2.0 * crate::limits::bytes_render(n, 31, 28, a.planes, false, Some(2.5)))?;
    crate::limits::check_rays(&format!("--scene-size {n} × --planes {} × --rays {} (× 3 renders + --scenes {})", a.planes, a.rays, a.scenes), (3.0 + a.scenes as f64) * (n as f64).powi(2) * a.planes as f64 * a.rays as f64)?;
    crate::limits::check_memory(&format!("--scene-size {n} × --planes {} (renders and mapping cube)", a.planes), 2.0 * crate::limits::bytes_render(n, 31, 28, a.planes, false, Some(2.5)) + crate::limits::bytes_mapping(n, n, a.planes))?;
    let mut cfg = RenderConfig::paper(n);
    cfg.spectral = SpectralSampling::with_planes(crate::analysis::linspace(450.0, 650.0, 28), a.planes)?;
    cfg.rays_per_pixel = a.rays;
    let kernels: Vec<crate::tracer::Kernel> = a.kernels.split(',').map(|k| k.trim().parse()).collect::<Result<_>>()?;
    for k in &kernels {
        k.resolve()?;
    }
    if kernels.is_empty() {
        return Err(Error::invalid("--kernels: name at least one kernel"));
    }
    let precisions: Vec<crate::tracer::Precision> = a.precisions.split(',').map(|p| p.trim().parse()).collect::<Result<_>>()?;
    if precisions.is_empty() {
        return Err(Error::invalid("--precisions: name at least one precision"));
    }
    // (kernel, precision) variants: every kernel in f64, then f32 with the first SIMD kernel.
    let simd_kernel = kernels.iter().copied().find(|k| *k != crate::tracer::Kernel::Scalar);
    let mut variants: Vec<(crate::tracer::Kernel, crate::tracer::Precision)> = Vec::new();
    for &p in &precisions {
        match p {
            crate::tracer::Precision::F64 => variants.extend(kernels.iter().map(|&k| (k, p))),
            crate::tracer::Precision::F32 => variants.push((simd_kernel.ok_or_else(|| Error::invalid("--precisions f32 needs a SIMD kernel in --kernels"))?, p)),
        }
    }
    variants.dedup();
    // The f32 kernel does not model a coded-mask surface (dual-disperser systems): its rows are left out, said
    // so, before any render (the default `--precisions f64,f32` on ddsp failed half-way).
    if let Some(m) = system.coded_mask {
        if variants.iter().any(|v| v.1 == crate::tracer::Precision::F32) {
            variants.retain(|v| v.1 != crate::tracer::Precision::F32);
            if variants.is_empty() {
                return Err(Error::invalid(format!("--precisions f32: system `{}` holds its coded mask on surface {}, which the f32 kernel does not model yet; use --precisions f64", system.name(), m.surface)));
            }
            println!("(f32 rows left out: system `{}` holds its coded mask on surface {}, which the f32 kernel does not model yet)", system.name(), m.surface);
        }
    }
    // --parts before the table's header (an empty or repeated list printed it, then failed or ran a part twice).
    let parts: Vec<&str> = a.parts.split(',').map(str::trim).collect();
    if let Some(bad) = parts.iter().find(|p| !["mapping", "acquisition", "dataset"].contains(p)) {
        return Err(Error::invalid(format!("--parts: unknown part `{bad}` (use mapping, acquisition, dataset)")));
    }
    if let Some(k) = (1..parts.len()).find(|&k| parts[..k].contains(&parts[k])) {
        return Err(Error::invalid(format!("--parts: `{}` is listed twice", parts[k])));
    }
    let (first, first_p) = variants[0];
    cfg.kernel = first;
    cfg.precision = first_p;
    let tracer = AnalyticTracer::with_kernel(first);
    let threads = rayon::current_num_threads();
    println!("render bench: {}, {n}×{n} scene, {} planes, {} rays per pixel per plane, mask opening {}, {threads} threads", system.name(), a.planes, a.rays, a.opening);
    println!("| what | wall s | CPU s | rays traced | M rays/s (wall) |");
    println!("|---|---|---|---|---|");
    let cpu0 = std::cell::Cell::new(super::shared::process_cpu_seconds());
    let row = |what: &str, secs: f64, rays: u64| {
        let now = super::shared::process_cpu_seconds();
        let cpu = match (cpu0.get(), now) {
            (Some(a), Some(b)) => format!("{:.1}", b - a),
            _ => "n/a".into(),
        };
        cpu0.set(now);
        println!("| {what} | {secs:.2} | {cpu} | {rays} | {:.2} |", if secs > 0.0 { rays as f64 / secs / 1e6 } else { 0.0 })
    };
    // The chief-ray mapping cube (n × n × planes) through each kernel, side by side.
    let mut mapping_ref: Option<crate::analysis::MappingCube> = None;
    for &(k, p) in variants.iter().filter(|_| parts.contains(&"mapping")) {
        let tr = p.tracer(k)?;
        let t = Instant::now();
        let m = crate::analysis::mapping_cube(&system, tr.as_ref(), n, n, cfg.scene_pitch_mm, &cfg.spectral.planes_nm)?;
        let secs = t.elapsed().as_secs_f64();
        let rays = (n * n * cfg.spectral.planes()) as u64;
        let diff = match &mapping_ref {
            Some(r) => format!("; max |Δ| vs {} {first_p} {:.1e} mm", first.name(), m.positions_mm.iter().zip(&r.positions_mm).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max)),
            None => String::new(),
        };
        row(&format!("mapping cube {n}×{n}×{}, {} kernel {p}{diff}", cfg.spectral.planes(), k.name()), secs, rays);
        mapping_ref.get_or_insert(m);
    }
    if let Some(exact) = &mapping_ref {
        bench_interpolated_mapping(&system, &tracer, exact, a.mapping_tolerance_um, &row, &cpu0)?;
    }
    let t = Instant::now();
    let renderer = Renderer::new(&system, &tracer, cfg.clone(), Mask::random(n, n, a.opening, 0)?)?;
    let setup = t.elapsed().as_secs_f64();
    if !parts.contains(&"acquisition") && !parts.contains(&"dataset") {
        return Ok(());
    }
    let scene = synthetic_scene(n, n, &synthetic_wavelengths(), 0);
    if parts.contains(&"acquisition") {
        bench_acquisitions(&system, &renderer, &variants, &scene, setup, a.opening, device, &row)?;
    }
    if !parts.contains(&"dataset") {
        return Ok(());
    }
    let t = Instant::now();
    let transport = renderer.trace_all(&|_| {})?;
    let bytes: usize = transport.iter().map(|p| p.bytes()).sum();
    row(&format!("dataset: trace the transport once ({:.2} GB)", bytes as f64 / 1e9), t.elapsed().as_secs_f64(), transport.iter().map(|p| p.stats.traced).sum());
    let mut per = Vec::new();
    cpu0.set(super::shared::process_cpu_seconds());
    for s in 0..a.scenes {
        let sc = synthetic_scene(n, n, &synthetic_wavelengths(), 100 + s as u64);
        let t = Instant::now();
        let r = renderer.render_cached(&sc, &transport, false, &|_| {})?;
        per.push(t.elapsed().as_secs_f64());
        std::hint::black_box(r);
    }
    let mean = per.iter().sum::<f64>() / per.len() as f64;
    row(&format!("dataset: per scene (wall: mean of {}; CPU: all of them)", per.len()), mean, 0);
    Ok(())
}
