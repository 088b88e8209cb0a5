//! `render`, `render-dataset` and `bench-render`: coded acquisitions of hyperspectral scenes.
//!
//! ```text
//! diffcassi render --preset sp                                   # synthetic demo scene → out/render-sp
//! diffcassi render --preset ap --scene scene.exr --out out/ap     # a KAIST-style EXR
//! diffcassi render --preset sp --noise shot,read,adc --full-well-e 20000 --read-noise-e 2 --adc-bits 12
//! diffcassi render-dataset --scenes scenes/ --preset sp --out out/sp-dataset
//! diffcassi bench-render --preset sp                              # the paper-scale timing table
//! ```
use super::args::{BackendArgs, SystemArgs};
use super::commands::{load_system, parse_wavelengths};
use crate::error::{Error, Result};
use crate::render::{dataset, output, AiryConfig, Mask, NoiseConfig, PlaneTransport, RenderConfig, Renderer, Sampling, SpectralSampling};
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
    #[command(flatten)]
    pub noise: NoiseArgs,
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
    /// The noise the options describe (`None`: off). Options of a source that is not selected are errors.
    pub fn config(&self) -> Result<Option<NoiseConfig>> {
        let list = self.noise.as_deref().unwrap_or("none").trim();
        let mut cfg = NoiseConfig::default();
        let (mut read, mut adc) = (false, false);
        if list != "none" {
            for item in list.split(',').map(str::trim) {
                match item {
                    "shot" => cfg.shot = true,
                    "read" => read = true,
                    "adc" => adc = true,
                    _ => return Err(Error::invalid(format!("--noise `{item}`: use a comma list of shot, read, adc (or none)"))),
                }
            }
        }
        let on = cfg.shot || read || adc;
        let given = [
            ("--full-well-e", self.full_well_e.is_some()),
            ("--electrons-per-unit", self.electrons_per_unit.is_some()),
            ("--noise-seed", self.noise_seed.is_some()),
        ];
        if let Some((name, _)) = given.iter().find(|g| g.1 && !on) {
            return Err(Error::invalid(format!("{name} needs --noise (shot, read and/or adc)")));
        }
        if self.read_noise_e.is_some() && !read {
            return Err(Error::invalid("--read-noise-e needs `read` in --noise"));
        }
        if self.adc_bits.is_some() && !adc {
            return Err(Error::invalid("--adc-bits needs `adc` in --noise"));
        }
        if !on {
            return Ok(None);
        }
        if let Some(f) = self.full_well_e {
            cfg.full_well_e = f;
        }
        cfg.electrons_per_unit = self.electrons_per_unit;
        if read {
            cfg.read_noise_e = self.read_noise_e.unwrap_or(2.0);
            if cfg.read_noise_e == 0.0 {
                return Err(Error::invalid("--read-noise-e 0 with `read` in --noise: drop `read` instead"));
            }
        }
        if adc {
            cfg.adc_bits = Some(self.adc_bits.unwrap_or(12));
        }
        cfg.seed = self.noise_seed.unwrap_or(0);
        cfg.validate().map_err(|e| Error::invalid(format!("--noise: {e}")))?;
        Ok(Some(cfg))
    }
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
    /// Sensor noise; each scene's noise seed is `--noise-seed` + a hash of the scene's name (FNV-1a), so a
    /// scene's noise does not depend on which other scenes are in the folder.
    #[command(flatten)]
    pub noise: NoiseArgs,
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
    let noise = a.noise.config()?;
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
    let mut acq = renderer.render(&scene, a.common.cube, &|k| pb.inc(k))?;
    pb.finish_and_clear();
    // Sensor noise on the acquisition (the per-band images of --cube stay clean).
    let noise_json = apply_noise(noise.as_ref(), &mut acq, a.noise.noise.as_deref().unwrap_or(""), false)?;
    let json = write_all(&out, &renderer, &acq, &desc, t0, serde_json::json!({"noise": noise_json}), !a.common.no_mapping)?;
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

/// 64-bit FNV-1a hash of a scene name (the per-scene noise seed offset).
fn name_hash(name: &str) -> u64 {
    name.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| (h ^ b as u64).wrapping_mul(0x0100_0000_01b3))
}

/// Apply the sensor noise (if any) to an acquisition and describe it for render.json.
fn apply_noise(noise: Option<&NoiseConfig>, acq: &mut crate::render::Acquisition, sources: &str, quiet: bool) -> Result<serde_json::Value> {
    let Some(nc) = noise else { return Ok(serde_json::Value::Null) };
    let report = nc.apply(&mut acq.image)?;
    if !quiet {
        println!(
            "sensor noise ({sources}): {:.4} e⁻ per unit, peak {:.0} e⁻{}",
            report.electrons_per_unit,
            report.peak_electrons,
            report.adc_gain_e_per_dn.map(|g| format!(", ADC {:.4} e⁻/DN, {} saturated pixels", g, report.saturated_pixels)).unwrap_or_default()
        );
    }
    Ok(nc.to_json(&report))
}

pub fn render_dataset(a: RenderDatasetArgs) -> Result<()> {
    let t0 = Instant::now();
    let noise = a.noise.config()?;
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
        let mut acq = match &cached {
            Some(t) => renderer.render_cached(&scene, t, a.common.cube, &|_| {})?,
            None => {
                let pb = progress_bar(renderer.rays_per_render(), &s.name);
                let acq = renderer.render(&scene, a.common.cube, &|k| pb.inc(k))?;
                pb.finish_and_clear();
                acq
            }
        };
        let scene_noise = noise.as_ref().map(|n| NoiseConfig { seed: n.seed.wrapping_add(name_hash(&s.name)), ..n.clone() });
        let noise_json = apply_noise(scene_noise.as_ref(), &mut acq, "", true)?;
        let extra = serde_json::json!({"dataset_mode": true, "transport_cached": cached.is_some(), "transport_seconds": transport_seconds, "seconds_scene": ts.elapsed().as_secs_f64(), "noise": noise_json});
        write_all(&a.out.join(&s.name), &renderer, &acq, &desc, ts, extra, false)?;
        pb_scenes.println(format!("{}: {:.2} s", s.name, ts.elapsed().as_secs_f64()));
        pb_scenes.inc(1);
    }
    pb_scenes.finish_and_clear();
    println!("rendered {} scenes into {} in {:.2} s", todo.len(), a.out.display(), t0.elapsed().as_secs_f64());
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
    let tracer = AnalyticTracer::default();
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
    let t = Instant::now();
    let renderer = Renderer::new(&system, &tracer, cfg.clone(), Mask::random(n, n, a.opening, 0)?)?;
    let setup = t.elapsed().as_secs_f64();
    let scene = synthetic_scene(n, n, &synthetic_wavelengths(), 0);
    let t = Instant::now();
    let acq = renderer.render(&scene, false, &|_| {})?;
    row(&format!("acquisition (setup {setup:.2} s + render)"), t.elapsed().as_secs_f64() + setup, acq.stats.traced);
    if a.opening < 1.0 {
        let open = Renderer::new(&system, &tracer, cfg.clone(), Mask::open(n, n))?;
        let t = Instant::now();
        let acq = open.render(&scene, false, &|_| {})?;
        row("acquisition, all-open mask (every ray)", t.elapsed().as_secs_f64(), acq.stats.traced);
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
