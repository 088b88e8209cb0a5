//! `render`, `render-dataset` and `bench-render`: coded acquisitions of hyperspectral scenes.
//!
//! ```text
//! diffcassi render --preset sp                                   # synthetic demo scene → out/render-sp
//! diffcassi render --preset ap --scene scene.exr --out out/ap     # a KAIST-style EXR
//! diffcassi render-dataset --scenes scenes/ --preset sp --out out/sp-dataset
//! diffcassi bench-render --preset sp                              # the paper-scale timing table
//! ```
use super::args::{BackendArgs, SystemArgs};
use super::commands::{load_system, parse_wavelengths};
use crate::error::{Error, Result};
use crate::render::{dataset, output, AiryConfig, Mask, PlaneTransport, RenderConfig, Renderer, Sampling, SpectralSampling};
use crate::scene::{load_scene, synthetic_scene, synthetic_wavelengths, Fit, SpectralCube};
use crate::tracer::AnalyticTracer;
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Settings shared by `render` and `render-dataset`.
#[derive(Args, Debug, Clone)]
pub struct RenderCommon {
    #[command(flatten)]
    pub system: SystemArgs,
    #[command(flatten)]
    pub backend: BackendArgs,
    /// Scene side N (pixels of 10 µm on the object plane): scenes are cropped/resized to N×N.
    #[arg(long = "scene-size", default_value_t = 512)]
    pub scene_size: usize,
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
    /// Opening ratio of the random mask.
    #[arg(long, default_value_t = 0.5)]
    pub opening: f64,
    /// Seed of the random mask.
    #[arg(long = "mask-seed", default_value_t = 0)]
    pub mask_seed: u64,
    /// Airy disk diameter (pixels) at 520 nm, ∝ λ.
    #[arg(long = "airy-diameter-px", default_value_t = 2.5)]
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
}

#[derive(Args, Debug)]
pub struct RenderDatasetArgs {
    #[command(flatten)]
    pub common: RenderCommon,
    /// Folder of scenes (.exr, .npy, PNG sub-folders).
    #[arg(long)]
    pub scenes: PathBuf,
    /// Output folder: one sub-folder per scene.
    #[arg(long)]
    pub out: PathBuf,
    /// Keep the traced light transport in memory up to this size (GB); beyond it, trace per scene.
    #[arg(long = "transport-memory-gb", default_value_t = 4.0)]
    pub transport_memory_gb: f64,
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
    /// Parts to run (comma-separated): mapping (the chief-ray mapping cube), acquisition (per-scene render,
    /// all-open render), dataset (transport once, then per scene).
    #[arg(long, default_value = "mapping,acquisition,dataset")]
    pub parts: String,
}

fn parse_sampling(s: &str) -> Result<Sampling> {
    match s {
        "stratified" => Ok(Sampling::Stratified),
        "independent" => Ok(Sampling::Independent),
        _ => Err(Error::invalid(format!("--sampling `{s}`: use stratified or independent"))),
    }
}

fn parse_fit(s: &str) -> Result<Fit> {
    match s {
        "crop" => Ok(Fit::Crop),
        "resize" => Ok(Fit::Resize),
        _ => Err(Error::invalid(format!("--fit `{s}`: use crop or resize"))),
    }
}

/// The render settings and mask the arguments describe.
pub fn config_from(a: &RenderCommon) -> Result<(RenderConfig, Mask)> {
    let n = a.scene_size;
    if n == 0 {
        return Err(Error::invalid("--scene-size must be ≥ 1"));
    }
    let bands = parse_wavelengths(&a.bands)?;
    let spectral = SpectralSampling::with_planes(bands, a.planes)?;
    if !(a.airy_diameter_px.is_finite() && a.airy_diameter_px > 0.0) {
        return Err(Error::invalid(format!("--airy-diameter-px {}: must be finite and > 0", a.airy_diameter_px)));
    }
    if a.rays == Some(0) {
        return Err(Error::invalid("--rays must be ≥ 1"));
    }
    let mut cfg = RenderConfig::paper(n);
    cfg.spectral = spectral;
    cfg.rays_per_pixel = a.rays.unwrap_or(20);
    cfg.seed = a.seed;
    cfg.sampling = parse_sampling(&a.sampling)?;
    cfg.kernel = a.kernel.parse()?;
    cfg.kernel.resolve()?;
    cfg.airy = (!a.no_airy).then_some(AiryConfig { diameter_px: a.airy_diameter_px, ..AiryConfig::default() });
    let mask = match &a.mask {
        Some(p) => {
            let m = Mask::load(p)?;
            if m.height != n || m.width != n {
                return Err(Error::File { path: p.display().to_string(), message: format!("the mask is {}×{} but --scene-size is {n}", m.height, m.width) });
            }
            m
        }
        None => Mask::random(n, n, a.opening, a.mask_seed)?,
    };
    Ok((cfg, mask))
}

/// The tracer and rays per pixel: as given, or chosen by `--tolerance-um`.
fn render_tracer(a: &RenderCommon, system: &crate::system::SequentialSystem, cfg: &RenderConfig, mask: &Mask) -> Result<(Box<dyn crate::tracer::Tracer>, usize)> {
    let open = mask.values.iter().filter(|&&v| v > 0.0).count();
    super::fidelity::render_for(&a.backend, a.rays, system, cfg, open)
}

fn scene_wavelengths(a: &RenderCommon) -> Result<Option<Vec<f64>>> {
    a.scene_wavelengths.as_deref().map(parse_wavelengths).transpose()
}

/// Load and fit a scene file; returns the cube and its JSON description.
fn load_fitted(path: &Path, a: &RenderCommon) -> Result<(SpectralCube, serde_json::Value)> {
    let ws = scene_wavelengths(a)?;
    let raw = load_scene(path, ws.as_deref())?;
    let fit = parse_fit(&a.fit)?;
    let cube = raw.fit(a.scene_size, fit).map_err(|e| Error::File { path: path.display().to_string(), message: e.to_string() })?;
    let desc = serde_json::json!({"source": path.display().to_string(), "native_height": raw.height, "native_width": raw.width, "native_wavelengths_nm": raw.wavelengths_nm, "fit": fit});
    Ok((cube, desc))
}

fn progress_bar(total: u64, what: &str) -> ProgressBar {
    let pb = ProgressBar::new(total);
    pb.set_style(
        ProgressStyle::with_template("{msg} [{elapsed_precise}] {wide_bar} {human_pos}/{human_len} rays, {per_sec}, ETA {eta}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    pb.set_message(what.to_string());
    pb
}

fn default_out(a: &RenderCommon) -> PathBuf {
    let name = match (&a.system.preset, &a.system.system) {
        (Some(p), _) => p.clone(),
        (None, Some(f)) => f.file_stem().unwrap_or_default().to_string_lossy().into_owned(),
        _ => "system".into(),
    };
    PathBuf::from("out").join(format!("render-{name}"))
}

fn write_all(dir: &Path, renderer: &Renderer, acq: &crate::render::Acquisition, scene: &serde_json::Value, t0: Instant, extra: serde_json::Value, mapping: bool) -> Result<serde_json::Value> {
    std::fs::create_dir_all(dir).map_err(|e| Error::File { path: dir.display().to_string(), message: format!("cannot create: {e}") })?;
    let scale = output::write_images(dir, renderer, acq)?;
    renderer.mask.save_png(&dir.join("mask.png"))?;
    if mapping {
        output::write_mapping(dir, renderer)?;
    }
    let mut json = output::sidecar(renderer, acq, scene, scale, t0.elapsed().as_secs_f64(), rayon::current_num_threads());
    if let (Some(o), serde_json::Value::Object(e)) = (json.as_object_mut(), extra) {
        o.extend(e);
    }
    output::write_sidecar(dir, &json)?;
    Ok(json)
}

pub fn render(a: RenderArgs) -> Result<()> {
    let t0 = Instant::now();
    let system = load_system(&a.common.system)?;
    let (mut cfg, mask) = config_from(&a.common)?;
    let (tracer, rays) = render_tracer(&a.common, &system, &cfg, &mask)?;
    cfg.rays_per_pixel = rays;
    let n = a.common.scene_size;
    let (scene, desc) = match &a.scene {
        Some(p) => load_fitted(p, &a.common)?,
        None => {
            let seed = a.synthetic.unwrap_or(0);
            (synthetic_scene(n, n, &synthetic_wavelengths(), seed), serde_json::json!({"source": "synthetic", "synthetic_seed": seed, "native_wavelengths_nm": synthetic_wavelengths()}))
        }
    };
    let out = a.out.clone().unwrap_or_else(|| default_out(&a.common));
    let renderer = Renderer::new(&system, tracer.as_ref(), cfg, mask)?;
    let pb = progress_bar(renderer.rays_per_render(), &format!("render {}", system.name()));
    let acq = renderer.render(&scene, a.common.cube, &|k| pb.inc(k))?;
    pb.finish_and_clear();
    let json = write_all(&out, &renderer, &acq, &desc, t0, serde_json::json!({}), !a.common.no_mapping)?;
    println!(
        "{}: {}×{} scene, {} planes × {} rays: {} rays in {:.2} s ({:.2} M rays/s, {} threads), detector {}×{}, transmission {:.4}; total {:.2} s → {}",
        system.name(),
        n,
        n,
        renderer.config.spectral.planes(),
        renderer.config.rays_per_pixel,
        acq.stats.traced,
        acq.timings.wall_seconds,
        json["rays_per_second"].as_f64().unwrap_or(0.0) / 1e6,
        rayon::current_num_threads(),
        acq.detector.width,
        acq.detector.height,
        acq.stats.transmission(),
        t0.elapsed().as_secs_f64(),
        out.display()
    );
    Ok(())
}

pub fn render_dataset(a: RenderDatasetArgs) -> Result<()> {
    let t0 = Instant::now();
    let system = load_system(&a.common.system)?;
    let (mut cfg, mask) = config_from(&a.common)?;
    let scenes = dataset::find_scenes(&a.scenes)?;
    if scenes.is_empty() {
        return Err(Error::File { path: a.scenes.display().to_string(), message: "no scenes (.exr, .npy, or folders of .png)".into() });
    }
    let todo: Vec<&dataset::DatasetScene> = scenes.iter().filter(|s| !output::outputs_complete(&a.out.join(&s.name))).collect();
    println!("{} scenes in {}, {} to render ({} complete, skipped)", scenes.len(), a.scenes.display(), todo.len(), scenes.len() - todo.len());
    if todo.is_empty() {
        return Ok(());
    }
    let (tracer, rays) = render_tracer(&a.common, &system, &cfg, &mask)?;
    cfg.rays_per_pixel = rays;
    let renderer = Renderer::new(&system, tracer.as_ref(), cfg, mask)?;
    if !a.common.no_mapping && !a.out.join("mapping.npy").is_file() {
        output::write_mapping(&a.out, &renderer)?;
    }
    renderer.mask.save_png(&a.out.join("mask.png"))?;
    // Estimate the transport's memory from its middle plane.
    let planes = renderer.config.spectral.planes();
    let t_trace = Instant::now();
    let probe = renderer.trace_plane(planes / 2)?;
    let estimate = probe.bytes() as f64 * planes as f64 * 1.25;
    let budget = a.transport_memory_gb * 1e9;
    let cached: Option<Vec<PlaneTransport>> = if todo.len() > 1 && estimate <= budget {
        let pb = progress_bar(renderer.rays_per_render(), "tracing the light transport");
        let t = renderer.trace_all(&|k| pb.inc(k))?;
        pb.finish_and_clear();
        let bytes: usize = t.iter().map(|p| p.bytes()).sum();
        println!("light transport traced in {:.2} s ({:.2} GB), reused for {} scenes", t_trace.elapsed().as_secs_f64(), bytes as f64 / 1e9, todo.len());
        Some(t)
    } else {
        if todo.len() > 1 {
            println!("light transport would need ~{:.2} GB > {:.2} GB: tracing each scene", estimate / 1e9, a.transport_memory_gb);
        }
        None
    };
    let transport_seconds = t_trace.elapsed().as_secs_f64();
    drop(probe);
    let pb_scenes = ProgressBar::new(todo.len() as u64);
    pb_scenes.set_style(ProgressStyle::with_template("scenes [{elapsed_precise}] {wide_bar} {pos}/{len}, {per_sec}, ETA {eta} {msg}").unwrap_or_else(|_| ProgressStyle::default_bar()));
    for s in &todo {
        let ts = Instant::now();
        pb_scenes.set_message(s.name.clone());
        let (scene, desc) = load_fitted(&s.path, &a.common)?;
        let acq = match &cached {
            Some(t) => renderer.render_cached(&scene, t, a.common.cube, &|_| {})?,
            None => {
                let pb = progress_bar(renderer.rays_per_render(), &s.name);
                let acq = renderer.render(&scene, a.common.cube, &|k| pb.inc(k))?;
                pb.finish_and_clear();
                acq
            }
        };
        let extra = serde_json::json!({"dataset_mode": true, "transport_cached": cached.is_some(), "transport_seconds": transport_seconds, "seconds_scene": ts.elapsed().as_secs_f64()});
        write_all(&a.out.join(&s.name), &renderer, &acq, &desc, ts, extra, false)?;
        pb_scenes.println(format!("{}: {:.2} s", s.name, ts.elapsed().as_secs_f64()));
        pb_scenes.inc(1);
    }
    pb_scenes.finish_and_clear();
    println!("rendered {} scenes into {} in {:.2} s", todo.len(), a.out.display(), t0.elapsed().as_secs_f64());
    Ok(())
}

/// The acquisition rows of `bench-render`: `renderer` (the first kernel), then each further kernel on the
/// same mask and scene (with the largest difference of its image), then the all-open mask.
fn bench_acquisitions(system: &crate::system::SequentialSystem, renderer: &Renderer, kernels: &[crate::tracer::Kernel], scene: &SpectralCube, setup: f64, opening: f64, row: &dyn Fn(&str, f64, u64)) -> Result<()> {
    let first = renderer.config.kernel;
    let t = Instant::now();
    let acq = renderer.render(scene, false, &|_| {})?;
    row(&format!("acquisition, {} kernel (setup {setup:.2} s + render)", first.name()), t.elapsed().as_secs_f64() + setup, acq.stats.traced);
    for &k in &kernels[1..] {
        let mut c = renderer.config.clone();
        c.kernel = k;
        let tr = AnalyticTracer::with_kernel(k);
        let t = Instant::now();
        let other = Renderer::new(system, &tr, c, renderer.mask.clone())?;
        let acq_k = other.render(scene, false, &|_| {})?;
        let secs = t.elapsed().as_secs_f64();
        let diff = acq_k.image.iter().zip(&acq.image).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        row(&format!("acquisition, {} kernel (setup + render; max |Δ| vs {} {diff:.1e})", k.name(), first.name()), secs, acq_k.stats.traced);
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

/// CPU seconds (user + system) used by this process so far, from /proc/self/stat (Linux, USER_HZ = 100);
/// `None` elsewhere. On a shared machine wall time alone hides how much of the cores the run was given.
fn process_cpu_seconds() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/stat").ok()?;
    let after = &s[s.rfind(')')? + 2..];
    let f: Vec<&str> = after.split_whitespace().collect();
    let (u, k): (f64, f64) = (f.get(11)?.parse().ok()?, f.get(12)?.parse().ok()?);
    Some((u + k) / 100.0)
}

pub fn bench_render(a: BenchRenderArgs) -> Result<()> {
    let system = crate::system::SequentialSystem::build(&crate::presets::spec(&a.preset)?)?;
    let n = a.scene_size;
    let mut cfg = RenderConfig::paper(n);
    cfg.spectral = SpectralSampling::with_planes(crate::analysis::linspace(450.0, 650.0, 28), a.planes)?;
    cfg.rays_per_pixel = a.rays;
    let kernels: Vec<crate::tracer::Kernel> = a.kernels.split(',').map(|k| k.trim().parse()).collect::<Result<_>>()?;
    for k in &kernels {
        k.resolve()?;
    }
    let Some(&first) = kernels.first() else { return Err(Error::invalid("--kernels: name at least one kernel")) };
    cfg.kernel = first;
    let tracer = AnalyticTracer::with_kernel(first);
    let threads = rayon::current_num_threads();
    println!("render bench: {}, {n}×{n} scene, {} planes, {} rays per pixel per plane, mask opening {}, {threads} threads", system.name(), a.planes, a.rays, a.opening);
    println!("| what | wall s | CPU s | rays traced | M rays/s (wall) |");
    println!("|---|---|---|---|---|");
    let cpu0 = std::cell::Cell::new(process_cpu_seconds());
    let row = |what: &str, secs: f64, rays: u64| {
        let now = process_cpu_seconds();
        let cpu = match (cpu0.get(), now) {
            (Some(a), Some(b)) => format!("{:.1}", b - a),
            _ => "n/a".into(),
        };
        cpu0.set(now);
        println!("| {what} | {secs:.2} | {cpu} | {rays} | {:.2} |", if secs > 0.0 { rays as f64 / secs / 1e6 } else { 0.0 })
    };
    let parts: Vec<&str> = a.parts.split(',').map(str::trim).collect();
    if let Some(bad) = parts.iter().find(|p| !["mapping", "acquisition", "dataset"].contains(p)) {
        return Err(Error::invalid(format!("--parts: unknown part `{bad}` (use mapping, acquisition, dataset)")));
    }
    // The chief-ray mapping cube (n × n × planes) through each kernel, side by side.
    let mut mapping_ref: Option<crate::analysis::MappingCube> = None;
    for &k in kernels.iter().filter(|_| parts.contains(&"mapping")) {
        let tr = AnalyticTracer::with_kernel(k);
        let t = Instant::now();
        let m = crate::analysis::mapping_cube(&system, &tr, n, n, cfg.scene_pitch_mm, &cfg.spectral.planes_nm)?;
        let secs = t.elapsed().as_secs_f64();
        let rays = (n * n * cfg.spectral.planes()) as u64;
        let diff = match &mapping_ref {
            Some(r) => format!("; max |Δ| vs {} {:.1e} mm", first.name(), m.positions_mm.iter().zip(&r.positions_mm).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max)),
            None => String::new(),
        };
        row(&format!("mapping cube {n}×{n}×{}, {} kernel{diff}", cfg.spectral.planes(), k.name()), secs, rays);
        mapping_ref.get_or_insert(m);
    }
    let t = Instant::now();
    let renderer = Renderer::new(&system, &tracer, cfg.clone(), Mask::random(n, n, a.opening, 0)?)?;
    let setup = t.elapsed().as_secs_f64();
    if !parts.contains(&"acquisition") && !parts.contains(&"dataset") {
        return Ok(());
    }
    let scene = synthetic_scene(n, n, &synthetic_wavelengths(), 0);
    if parts.contains(&"acquisition") {
        bench_acquisitions(&system, &renderer, &kernels, &scene, setup, a.opening, &row)?;
    }
    if !parts.contains(&"dataset") {
        return Ok(());
    }
    let t = Instant::now();
    let transport = renderer.trace_all(&|_| {})?;
    let bytes: usize = transport.iter().map(|p| p.bytes()).sum();
    row(&format!("dataset: trace the transport once ({:.2} GB)", bytes as f64 / 1e9), t.elapsed().as_secs_f64(), transport.iter().map(|p| p.stats.traced).sum());
    let mut per = Vec::new();
    cpu0.set(process_cpu_seconds());
    for s in 0..a.scenes.max(1) {
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
