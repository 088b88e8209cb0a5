//! Rendering on a device: a [`Renderer`]'s acquisition computed by the GPU kernels — on a CUDA device
//! ([`Device::Cuda`]), or on the host through their CPU twin ([`Executor::Twin`], what the tests run).
//! The renderer and its settings are the CPU's (same detector, planes, Airy kernels, sampler, seed); what
//! differs is the arithmetic of the accumulation: each ray's bilinear taps are added to the plane image as
//! 64-bit fixed-point integers (deterministic on any scheduling; error ≤ 2⁻⁶³ · rays-per-plane · max value
//! a deposit, docs/gpu.md), the Airy blur and the band sums are f64 — where the CPU renderer rounds its
//! footprint weights, plane images and blur to f32. So the device's acquisition equals the CPU's to the CPU's
//! f32 rounding (tests/gpu_render.rs measures it), and the twin's bit for bit.
//!
//! ```
//! use diffcassi::{presets, render::{device::{render_on, Executor}, Mask, RenderConfig, Renderer, SpectralSampling},
//!                 scene::SpectralCube, system::SequentialSystem, tracer::AnalyticTracer};
//! let sys = SequentialSystem::build(&presets::spec("sp").unwrap())?;
//! let mut cfg = RenderConfig::paper(16);
//! cfg.spectral = SpectralSampling::new(vec![500.0, 600.0], 1)?;
//! cfg.rays_per_pixel = 2;
//! let tracer = AnalyticTracer::default();
//! let r = Renderer::new(&sys, &tracer, cfg, Mask::random(16, 16, 0.5, 1)?)?;
//! let scene = SpectralCube::new(16, 16, vec![500.0, 600.0], vec![1.0; 16 * 16 * 2], "scene")?;
//! let (twin, _) = render_on(&r, &scene, false, Executor::Twin)?;
//! let cpu = r.render(&scene, false, &|_| {})?;
//! let peak = cpu.image.iter().cloned().fold(0.0, f64::max);
//! assert!(twin.image.iter().zip(&cpu.image).all(|(a, b)| (a - b).abs() <= 1e-5 * peak));
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::engine::{Acquisition, Renderer, Timings};
use super::settings::Device;
use super::transport::RayStats;
use super::twin::{launch_constants, SceneGeometry};
use crate::error::{Error, Result};
use crate::gpu::plan::{fixed_scale, PlanMask, PlanOutput, PlanePlan, RenderPlan, LOST_ONE, MASKED_SLOT, STATUS_SLOTS};
use crate::gpu::{cuda, pack};
use crate::scene::SpectralCube;
use crate::tracer::Precision;

/// Where the kernels of a device render run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Executor {
    /// On the host: the kernels' CPU twin (the same source compiled for the CPU).
    Twin,
    /// On CUDA device N (`cuda:N`; 0 is `cuda`).
    Cuda(usize),
}

/// What a device render records beside its acquisition (`render.json`'s `device`).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct DeviceRecord {
    /// `cuda`, `cuda:N` (N > 0) or `cpu-twin`.
    pub device: String,
    /// The GPU's name and the driver's CUDA version (CUDA only).
    pub gpu: Option<String>,
    pub driver: Option<String>,
    /// The ray kernel's precision (`f64`, or `f32`: the renderer's f32 trace).
    pub precision: String,
    /// How the acquisition is accumulated (fixed point, its scale 2^S).
    pub accumulation: String,
    /// Device time of the kernels and the wall clock of the render with its transfers, ms (CUDA only).
    pub kernels_ms: Option<f64>,
    pub total_ms: Option<f64>,
    /// The fixed-point accumulation's warning for a high-dynamic-range scene ([`fixed_point_warning`]): the
    /// dimmest 1 % of the scene's lit values lose more than 10⁻³ of their level; absent otherwise.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fixed_point_warning: Option<String>,
    /// Where the PTX came from (CUDA only).
    pub ptx: Option<String>,
}

/// The plan of `r`'s acquisition of `scene`: every array the kernels read, traced in the renderer's precision
/// (f64, or the f32 trace of `--precision f32`), rays aimed as the system says (ray aiming off, `paraxial` or
/// `real`), weighted by the coded mask on the object plane or, in a dual-disperser system, on its surface (every
/// scene pixel traced, each ray weighted where it crosses the mask: `Renderer::surface_mask`). Errors for what the
/// kernels do not model (another backend than the analytic one, the batched tracer path), naming the setting.
pub fn plan<'a>(r: &'a Renderer<'_>, scene: &'a SpectralCube) -> Result<RenderPlan<'a>> {
    r.check_scene(scene)?;
    if r.config.force_batched {
        return Err(Error::invalid("the GPU kernels (--device cuda or cpu-twin) trace with their own code, not through the batched tracer path (force_batched)"));
    }
    if r.tracer.name() != "analytic-f64" {
        return Err(Error::invalid(format!("the GPU kernels (--device cuda or cpu-twin) are the analytic tracer's own: --backend {} is not available on them (use --backend analytic)", r.tracer.name())));
    }
    let ctx = r.plane_context();
    let (h, w) = (r.config.scene_height, r.config.scene_width);
    let geometry = SceneGeometry { height: h, width: w, pitch_mm: r.config.scene_pitch_mm, detector: &r.detector };
    let (sampler, aim, scene_c, aim_path) = launch_constants(r.system, geometry, ctx.sampler, ctx.seed)?;
    let steps = pack::steps(r.system)?;
    let sp = &r.config.spectral;
    let mut indices = Vec::new();
    let mut n_surfaces = 0;
    for &l in &sp.planes_nm {
        let n = r.system.indices(l)?;
        n_surfaces = n.len();
        indices.extend_from_slice(&n);
    }
    // The open pixels of the object plane's mask (every pixel when the mask is a surface of the system).
    let object_mask = r.object_mask();
    let pixels: Vec<u32> = (0..h * w).filter(|&q| object_mask[q] > 0.0).map(|q| q as u32).collect();
    let surface_mask = match r.surface_mask() {
        Some(sm) => {
            let (height, width) = pack::mask_size(sm.height, sm.width)?;
            Some(PlanMask { surface: sm.surface, height, width, values: sm.values })
        }
        None => None,
    };
    let sb = scene.bands();
    // A diffraction grating passes the fraction `grating_efficiency` of the power into its traced order
    // (Renderer::trace_plane scales the footprints' weights by it): here each plane's weight into its band, in
    // f64. 1 without gratings, the plane weight unchanged.
    let efficiency = r.system.grating_efficiency();
    let mut planes = Vec::with_capacity(sp.planes());
    let mut kernels = Vec::with_capacity(sp.planes());
    for p in 0..sp.planes() {
        let (k, tw) = scene.interpolation(sp.planes_nm[p]);
        planes.push(PlanePlan { plane: p as u64, k0: k as u32, k1: (k + 1).min(sb - 1) as u32, tw: tw as f32, band: sp.plane_band[p] as u32, weight: sp.plane_weight * efficiency, kernel: p });
        kernels.push(match &r.kernels[p] {
            Some(a) => (a.half, a.weights.clone()),
            None => (0, vec![1.0f32]),
        });
    }
    // The largest |value| a ray can carry: max|scene| · max|mask| (the interpolation does not exceed it but
    // for f32 rounding, which fixed_scale's factor 2 covers). With the mask on a surface the object plane's is 1
    // and each tap is weighted by the mask's transmission, ≤ max|mask| (nearest: a value; bilinear: a convex
    // combination of four).
    let max_scene = scene.data.iter().fold(0.0f64, |m, v| m.max((*v as f64).abs()));
    let max_mask = r.mask.values.iter().fold(0.0f64, |m, v| m.max((*v as f64).abs()));
    let rays = pixels.len() as u64 * sampler.rays as u64;
    let scale = fixed_scale(max_scene * max_mask, rays).unwrap_or(1.0);
    let unit = (1.0 / sampler.rays as f64) / scale;
    Ok(RenderPlan {
        steps,
        aim_path,
        indices,
        n_surfaces,
        pixels,
        sampler,
        aim,
        scene: scene_c,
        max_coord_mm: crate::limits::MAX_IMAGE_COORD_MM,
        cube: &scene.data,
        cube_bands: sb as u32,
        mask: object_mask,
        surface_mask,
        planes,
        kernels,
        det_w: r.detector.width,
        det_h: r.detector.height,
        bands: sp.bands_nm.len(),
        fixed_scale: scale,
        unit,
        f32: r.config.precision == Precision::F32,
    })
}

/// The relative error above which [`fixed_point_warning`] speaks.
pub const FIXED_POINT_DIM_ERROR: f64 = 1e-3;

/// The fixed-point accumulation's resolution is one unit of 2^−S of the scene's values per ray tap, S set by the
/// brightest value ([`fixed_scale`]); a pixel of value v, deposited by `rays_per_pixel` rays of four taps, is
/// summed within 2·rays_per_pixel·2^−S, a relative error of 2·rays_per_pixel / (2^S·v). A warning when that
/// exceeds [`FIXED_POINT_DIM_ERROR`] for the dimmest 1 % of the scene's positive values — a high-dynamic-range
/// scene whose dim regions the kernels render coarsely, or as 0 beyond a range of ~10¹⁵/rays (a held-out
/// battery, round 12: 2·10⁻⁴ of the dim level at a range of 10¹², 0 at 10¹⁶; the CPU renderer keeps them).
pub fn fixed_point_warning(scene: &SpectralCube, fixed_scale: f64, rays_per_pixel: u64) -> Option<String> {
    let mut positive: Vec<f32> = scene.data.iter().copied().filter(|v| *v > 0.0).collect();
    if positive.is_empty() {
        return None;
    }
    let k = positive.len() / 100;
    let (_, dim, _) = positive.select_nth_unstable_by(k, f32::total_cmp);
    let dim = *dim as f64;
    let relative = 2.0 * rays_per_pixel as f64 / (fixed_scale * dim);
    let brightest = scene.data.iter().fold(0.0f64, |m, v| m.max(*v as f64));
    (relative > FIXED_POINT_DIM_ERROR).then(|| {
        format!(
            "the GPU kernels' deterministic fixed-point accumulation (2^{} units per scene unit, set by the brightest value {:.3e}) resolves the dimmest 1 % of this scene's lit values ({:.3e} and below, {:.1e} times dimmer) to only {:.1e} of their level: render a scene of such dynamic range with --device cpu",
            fixed_scale.log2(),
            brightest,
            dim,
            brightest / dim,
            relative
        )
    })
}

/// The statistics of a run: ray counts by status, the off-detector weight.
fn stats(out: &PlanOutput, traced: u64) -> RayStats {
    let c = &out.counts;
    debug_assert_eq!(c.len(), STATUS_SLOTS + 1);
    RayStats {
        traced,
        arrived: c[0],
        missed: c[1],
        vignetted: c[2],
        tir: c[3],
        no_convergence: c[4],
        invalid_input: c[5],
        absorbed: c[6],
        bounce_limit: c[7],
        out_of_range: c[8],
        evanescent: c[9],
        masked: c[MASKED_SLOT],
        off_detector: c[STATUS_SLOTS] as f64 / LOST_ONE,
    }
}

/// Render `scene` with `r`'s settings through the GPU kernels, on `executor`.
pub fn render_on(r: &Renderer<'_>, scene: &SpectralCube, keep_bands: bool, executor: Executor) -> Result<(Acquisition, DeviceRecord)> {
    let t0 = std::time::Instant::now();
    let plan = plan(r, scene)?;
    let traced = plan.rays_per_plane() * plan.planes.len() as u64;
    let accumulation = format!("64-bit fixed point, 2^{} units per value, f64 blur and band sums", plan.fixed_scale.log2());
    let (out, record) = match executor {
        Executor::Twin => {
            let out = plan.run_twin(keep_bands)?;
            (out, DeviceRecord { device: "cpu-twin".into(), gpu: None, driver: None, precision: r.config.precision.name().into(), accumulation, kernels_ms: None, total_ms: None, fixed_point_warning: fixed_point_warning(scene, plan.fixed_scale, plan.sampler.rays as u64), ptx: None })
        }
        Executor::Cuda(ordinal) => {
            let (info, ptx) = cuda::device_info(ordinal)?;
            let (out, times) = cuda::render(ordinal, &plan, keep_bands)?;
            let record = DeviceRecord {
                device: Device::Cuda(ordinal).to_string(),
                gpu: Some(info.name.clone()),
                driver: Some(format!("{}.{}", info.driver_version / 1000, (info.driver_version % 1000) / 10)),
                precision: r.config.precision.name().into(),
                accumulation,
                kernels_ms: Some(times.kernels_ms),
                total_ms: Some(times.total_ms),
                fixed_point_warning: fixed_point_warning(scene, plan.fixed_scale, plan.sampler.rays as u64),
                ptx: Some(ptx),
            };
            (out, record)
        }
    };
    if let Some((p, t)) = out.aim_failure {
        // The CPU renderer stops at a ray whose aim fails (PlaneContext::ray's error): the same error, for the
        // first such ray of the lowest plane.
        let (p, n) = (p as usize, plan.sampler.rays as u64);
        let geometry = SceneGeometry { height: r.config.scene_height, width: r.config.scene_width, pitch_mm: r.config.scene_pitch_mm, detector: &r.detector };
        let ctx = r.plane_context();
        return Err(super::twin::aim_failure(r.system, geometry, ctx.sampler, ctx.seed, plan.planes[p].plane, r.config.spectral.planes_nm[p], plan.pixels[(t / n) as usize], (t % n) as usize));
    }
    if let Some(bad) = out.image.iter().position(|v| !v.is_finite()) {
        return Err(Error::invalid(format!("internal: the device render produced a non-finite value at detector pixel {bad}")));
    }
    let npix = plan.detector_pixels();
    let stats = stats(&out, traced);
    let bands = out.bands.map(|b| b.chunks(npix.max(1)).map(|c| c.to_vec()).collect());
    let timings = Timings { wall_seconds: t0.elapsed().as_secs_f64(), ..Timings::default() };
    Ok((Acquisition { detector: r.detector, image: out.image, bands, stats, timings }, record))
}

/// Render on the device a setting names: the CPU renderer for [`Device::Cpu`] (no record), the GPU kernels on
/// CUDA device N for [`Device::Cuda`]`(N)`, on the host for [`Device::CpuTwin`].
pub fn render_for(device: Device, r: &Renderer<'_>, scene: &SpectralCube, keep_bands: bool, progress: &(dyn Fn(u64) + Sync)) -> Result<(Acquisition, Option<DeviceRecord>)> {
    match device {
        Device::Cpu => Ok((r.render(scene, keep_bands, progress)?, None)),
        Device::Cuda(_) | Device::CpuTwin => {
            let executor = if let Device::Cuda(n) = device { Executor::Cuda(n) } else { Executor::Twin };
            let (acq, rec) = render_on(r, scene, keep_bands, executor)?;
            progress(acq.stats.traced);
            Ok((acq, Some(rec)))
        }
    }
}

/// `render.json`'s `device` entry: the record of a device render, or the CPU's (`device`, `precision`).
pub fn record_json(r: &Renderer<'_>, record: Option<&DeviceRecord>) -> serde_json::Value {
    match record {
        Some(rec) => serde_json::to_value(rec).unwrap_or(serde_json::Value::Null),
        None => serde_json::json!({"device": "cpu", "precision": r.config.precision.name(), "accumulation": "f32 footprints and plane images, f64 band sums"}),
    }
}

/// The GPU's figures against the CPU, on one render (issue 41's GPU acceptance; `diffcassi.gpu_check` and
/// `scripts/gpu_check.sh` print them).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct DeviceCheck {
    /// A dry run ([`check_on`] with [`Executor::Twin`]): the host twin stood in for the device, so no figure is
    /// a GPU's — the run checks the check (its plan, launches, comparisons and report) on a machine without one.
    pub dry_run: bool,
    pub gpu: String,
    pub driver: String,
    pub ptx: String,
    pub accumulation: String,
    /// Rays of one render.
    pub rays: u64,
    /// The second of two GPU runs: its kernels (CUDA events), and its wall clock with plan, uploads and copy.
    pub gpu_kernels_ms: f64,
    pub gpu_total_ms: f64,
    /// The CPU renderer's wall clock on this machine (f64, its default kernel).
    pub cpu_seconds: f64,
    /// Two GPU runs have the same bits (image and counts).
    pub runs_bit_identical: bool,
    /// The GPU's acquisition has the host twin's bits (`None`: the twin was not run); max |GPU − twin| / the
    /// twin's peak; the twin's wall clock. For an object at infinity the device's `tan` (CUDA's, ≤ 2 ulp) may
    /// start a ray a few ulp away from the host's (docs/gpu.md): there the check is the difference, not the bits.
    pub twin_bit_identical: Option<bool>,
    pub twin_max_rel_diff: Option<f64>,
    pub twin_seconds: Option<f64>,
    /// The system's object is at infinity (the rays' field angles go through `tan`).
    pub at_infinity: bool,
    /// max |GPU − CPU renderer| / the CPU's peak (the CPU's f32 splat rounding).
    pub cpu_max_rel_diff: f64,
    /// The middle plane's rays landed on the device and on the host: how many, the largest difference (mm),
    /// and how many statuses differ.
    pub landing_rays: u64,
    pub landing_max_diff_mm: f64,
    pub landing_status_mismatches: u64,
}

/// Render `scene` with `r` on the first CUDA device twice, on the CPU, and (if `twin`) through the host twin,
/// and land the middle plane's rays on both: the figures of [`DeviceCheck`].
pub fn check(r: &Renderer<'_>, scene: &SpectralCube, twin: bool) -> Result<DeviceCheck> {
    check_on(r, scene, twin, Executor::Cuda(0))
}

/// [`check`] with the "device" runs on `executor`: [`Executor::Cuda`] is the GPU check; [`Executor::Twin`] is its
/// dry run on a machine without a GPU (`diffcassi.gpu_check(..., dry_run=True)`, `scripts/gpu_check.sh` with
/// `DRY_RUN=1`): the same plan, renders, landings and comparisons, the device's renders and landings done by the
/// host-compiled kernels from the plan's own launch arguments ([`crate::gpu::plan::RenderPlan::landings_twin`]), and
/// the report marked `dry_run` (its times are no GPU's).
pub fn check_on(r: &Renderer<'_>, scene: &SpectralCube, twin: bool, executor: Executor) -> Result<DeviceCheck> {
    let (a, _) = render_on(r, scene, false, executor)?;
    let t = std::time::Instant::now();
    let (b, rec) = render_on(r, scene, false, executor)?;
    let gpu_total_ms = t.elapsed().as_secs_f64() * 1e3;
    let runs_bit_identical = a.same_bits(&b);
    let t = std::time::Instant::now();
    let cpu = r.render(scene, false, &|_| {})?;
    let cpu_seconds = t.elapsed().as_secs_f64();
    let cpu_max_rel_diff = b.max_diff_of_peak(&cpu);
    let (twin_bit_identical, twin_max_rel_diff, twin_seconds) = if twin {
        let t = std::time::Instant::now();
        let (tw, _) = render_on(r, scene, false, Executor::Twin)?;
        (Some(tw.same_bits(&b)), Some(b.max_diff_of_peak(&tw)), Some(t.elapsed().as_secs_f64()))
    } else {
        (None, None, None)
    };
    // The middle plane's landings: device and host kernels.
    let p = r.config.spectral.planes() / 2;
    let pl = plan(r, scene)?;
    let (du, dv, ds, dw) = match executor {
        Executor::Cuda(ordinal) => cuda::landings(ordinal, &pl, p)?,
        Executor::Twin => pl.landings_twin(p)?,
    };
    let host = super::twin::plane_landings_of(&r.plane_context(), p as u64, r.config.spectral.planes_nm[p], &pl.pixels)?;
    let pitch = r.detector.pitch_mm;
    let mut worst = 0.0f64;
    let mut mismatches = 0u64;
    for i in 0..du.len() {
        // With a coded-mask surface a ray's weight (its transmission, in [0, 1]) is part of its landing: it must
        // agree too (to 1e-12; the same bits but at infinity, where the device's `tan` may move the ray).
        let weight_differs = !host.weight.is_empty() && !((dw[i] - host.weight[i]).abs() <= 1e-12);
        if crate::gpu::ffi::status_of(ds[i]) != host.status[i] || du[i].is_nan() != host.u[i].is_nan() || weight_differs {
            mismatches += 1;
        } else if !du[i].is_nan() {
            worst = worst.max((du[i] - host.u[i]).abs() * pitch).max((dv[i] - host.v[i]).abs() * pitch);
        }
    }
    let dry_run = executor == Executor::Twin;
    let none = |what: &str| if dry_run { what.to_string() } else { String::new() };
    Ok(DeviceCheck {
        dry_run,
        gpu: rec.gpu.unwrap_or_else(|| none("none (dry run: the host twin stands in for the device)")),
        driver: rec.driver.unwrap_or_else(|| none("none")),
        ptx: rec.ptx.unwrap_or_else(|| none("none (host-compiled kernels)")),
        accumulation: rec.accumulation,
        rays: b.stats.traced,
        gpu_kernels_ms: rec.kernels_ms.unwrap_or(f64::NAN),
        gpu_total_ms,
        cpu_seconds,
        runs_bit_identical,
        twin_bit_identical,
        twin_max_rel_diff,
        twin_seconds,
        at_infinity: r.system.object_at_infinity(),
        cpu_max_rel_diff,
        landing_rays: du.len() as u64,
        landing_max_diff_mm: worst,
        landing_status_mismatches: mismatches,
    })
}
