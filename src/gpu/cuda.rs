//! The device launcher, one per CUDA device used (`cuda:N`, started on its first use): the embedded PTX (`kernels/trace.ptx`) loaded with the CUDA driver API (`cudarc`'s
//! thin `driver::result` layer, the driver library opened at run time), a [`RenderPlan`] uploaded and run
//! plane by plane on one stream — `dc_deposit_kernel` (one thread a ray), `dc_airy_kernel` (one thread a
//! detector pixel) — then `dc_finish_kernel`, and the acquisition copied back. The kernels are the host
//! twin's (`RenderPlan::run_twin`), from the same source; their accumulation is integer (dc_accum.h), so two
//! runs, and the twin, give the same bits.
//!
//! Loading: the embedded PTX first (NVRTC 13.0's PTX ISA 9.0, which drivers of CUDA 13.0 on take: the GPU
//! machine's is 580.159, CUDA 13.0; NVRTC 13.2's ISA 9.2 was refused there);
//! then, if the environment names one, a PTX file (`DIFFCASSI_PTX`, e.g. compiled on the GPU machine by
//! `nvcc -ptx` from [`super::ptx::amalgamated_source`]); then the machine's own NVRTC on the embedded
//! sources. Every failure is an error naming each attempt, never a panic: the driver is probed first
//! ([`super::probe`]) because cudarc panics when a library is absent.
use super::pack::{self, Batch, Step};
use super::plan::{initial_counts, PlanOutput, RenderPlan, BLOCK, COUNT_SLOTS};
use super::device::MAX_DEVICES;
use super::{probe, CudaInfo};
use crate::error::{Error, Result};
use crate::system::SequentialSystem;
use crate::tracer::{RaySlices, TracedBatch};
use cudarc::driver::{result as cu, sys};
use std::ffi::{c_void, CString};
use std::sync::OnceLock;

/// The loaded module and its kernels, on one device's primary context.
struct Launcher {
    ctx: sys::CUcontext,
    trace: sys::CUfunction,
    trace_f32: sys::CUfunction,
    landing: sys::CUfunction,
    landing_f32: sys::CUfunction,
    /// The same with ray aiming (`dc_aimed_ray`), launched when the plan aims: separate builds so that the
    /// unaimed kernels keep their registers (docs/gpu.md).
    landing_aimed: sys::CUfunction,
    landing_aimed_f32: sys::CUfunction,
    deposit: sys::CUfunction,
    deposit_aimed: sys::CUfunction,
    airy: sys::CUfunction,
    finish: sys::CUfunction,
    info: CudaInfo,
    /// Where the PTX came from (`embedded`, a file, `NVRTC …`).
    source: String,
}

// SAFETY: the handles are the driver's; the context is made current on the calling thread before each use
// and the driver API is thread-safe.
unsafe impl Send for Launcher {}
unsafe impl Sync for Launcher {}

/// A launcher per device ordinal, each started once (its error kept, so a failing device fails alike on
/// every call).
static LAUNCHERS: [OnceLock<std::result::Result<Launcher, String>>; MAX_DEVICES] = [const { OnceLock::new() }; MAX_DEVICES];

fn cuda_err(what: &str, e: cu::DriverError) -> String {
    format!("{what} failed ({e:?})")
}

/// Device `ordinal` and the PTX's origin, once its launcher is up (for records: `render.json`'s `device`).
pub fn device_info(ordinal: usize) -> Result<(CudaInfo, String)> {
    let l = launcher(ordinal)?;
    Ok((l.info.clone(), l.source.clone()))
}

/// Device `ordinal`'s launcher, its context made current on the calling thread.
fn launcher(ordinal: usize) -> Result<&'static Launcher> {
    let Some(slot) = LAUNCHERS.get(ordinal) else {
        return Err(Error::invalid(format!("CUDA: cuda:{ordinal}: at most {MAX_DEVICES} devices (cuda:0 … cuda:{}) are supported", MAX_DEVICES - 1)));
    };
    let l = slot.get_or_init(|| start(ordinal)).as_ref().map_err(|e| Error::invalid(format!("CUDA: {e}")))?;
    // SAFETY: the context was retained by the launcher.
    unsafe { cu::ctx::set_current(l.ctx) }.map_err(|e| Error::invalid(format!("CUDA: {}", cuda_err("cuCtxSetCurrent", e))))?;
    Ok(l)
}

fn load_module(ptx: &str) -> std::result::Result<sys::CUmodule, String> {
    let c = CString::new(ptx).map_err(|_| "the PTX holds a NUL byte".to_string())?;
    // SAFETY: a NUL-terminated PTX image; the context is current.
    unsafe { cu::module::load_data(c.as_ptr() as *const c_void) }.map_err(|e| cuda_err("cuModuleLoadData", e))
}

/// The machine's NVRTC on the embedded sources (`compute_90`, no contraction), when the library is there.
fn nvrtc_ptx() -> std::result::Result<String, String> {
    // SAFETY: only probes whether the library can be opened.
    if !unsafe { cudarc::nvrtc::sys::is_culib_present() } {
        return Err("no NVRTC library (libnvrtc.so) on the library path".into());
    }
    let opts = cudarc::nvrtc::CompileOptions {
        fmad: Some(false),
        arch: Some("compute_90"),
        options: vec!["-default-device".into()],
        ..Default::default()
    };
    let src = super::ptx::amalgamated_source();
    match std::panic::catch_unwind(|| cudarc::nvrtc::compile_ptx_with_opts(src, opts)) {
        Ok(Ok(p)) => Ok(p.to_src()),
        Ok(Err(e)) => Err(format!("NVRTC could not compile the kernels: {e:?}")),
        Err(_) => Err("NVRTC failed (a missing symbol in libnvrtc)".into()),
    }
}

fn start(ordinal: usize) -> std::result::Result<Launcher, String> {
    let info = probe(ordinal).map_err(|e| e.to_string())?;
    // SAFETY: the driver library is present (probed); each call's result is checked.
    unsafe {
        cu::init().map_err(|e| cuda_err("cuInit", e))?;
        let dev = cu::device::get(ordinal as i32).map_err(|e| cuda_err("cuDeviceGet", e))?;
        let ctx = cu::primary_ctx::retain(dev).map_err(|e| cuda_err("cuDevicePrimaryCtxRetain", e))?;
        cu::ctx::set_current(ctx).map_err(|e| cuda_err("cuCtxSetCurrent", e))?;
        let mut tried = Vec::new();
        let mut module = None;
        match load_module(super::ptx::TRACE_PTX) {
            Ok(m) => module = Some((m, "embedded PTX".to_string())),
            Err(e) => tried.push(format!("the embedded PTX: {e}")),
        }
        if module.is_none() {
            if let Ok(path) = std::env::var("DIFFCASSI_PTX") {
                match std::fs::read_to_string(&path).map_err(|e| format!("cannot read it: {e}")).and_then(|p| load_module(&p)) {
                    Ok(m) => module = Some((m, format!("PTX file {path}"))),
                    Err(e) => tried.push(format!("DIFFCASSI_PTX={path}: {e}")),
                }
            }
        }
        if module.is_none() {
            match nvrtc_ptx().and_then(|p| load_module(&p)) {
                Ok(m) => module = Some((m, "PTX compiled here by NVRTC".to_string())),
                Err(e) => tried.push(format!("NVRTC: {e}")),
            }
        }
        let Some((module, source)) = module else {
            return Err(format!(
                "the kernels could not be loaded on {} (driver {}.{}): {}; set DIFFCASSI_PTX to a PTX file built from the kernel source (docs/gpu.md)",
                info.name,
                info.driver_version / 1000,
                (info.driver_version % 1000) / 10,
                tried.join("; ")
            ));
        };
        let f = |name: &str| cu::module::get_function(module, CString::new(name).expect("kernel name")).map_err(|e| cuda_err(&format!("cuModuleGetFunction({name})"), e));
        Ok(Launcher { ctx, trace: f("dc_trace_kernel")?, trace_f32: f("dc_trace_f32_kernel")?, landing: f("dc_landing_kernel")?, landing_f32: f("dc_landing_f32_kernel")?, landing_aimed: f("dc_landing_aimed_kernel")?, landing_aimed_f32: f("dc_landing_aimed_f32_kernel")?, deposit: f("dc_deposit_kernel")?, deposit_aimed: f("dc_deposit_aimed_kernel")?, airy: f("dc_airy_kernel")?, finish: f("dc_finish_kernel")?, info, source })
    }
}

/// A device allocation, freed on drop.
struct DeviceBuffer {
    ptr: sys::CUdeviceptr,
}

impl DeviceBuffer {
    fn zeroed(bytes: usize) -> Result<Self> {
        // SAFETY: a fresh allocation of `bytes` (at least 1), set to zero.
        unsafe {
            let ptr = cu::malloc_sync(bytes.max(1)).map_err(|e| Error::invalid(format!("CUDA: {}", cuda_err(&format!("allocating {bytes} bytes"), e))))?;
            let b = DeviceBuffer { ptr };
            cu::memset_d8_sync(ptr, 0, bytes.max(1)).map_err(|e| Error::invalid(format!("CUDA: {}", cuda_err("cuMemsetD8", e))))?;
            Ok(b)
        }
    }

    fn from<T>(data: &[T]) -> Result<Self> {
        let b = Self::zeroed(std::mem::size_of_val(data))?;
        if !data.is_empty() {
            // SAFETY: the allocation holds size_of_val(data) bytes.
            unsafe { cu::memcpy_htod_sync(b.ptr, data) }.map_err(|e| Error::invalid(format!("CUDA: {}", cuda_err("cuMemcpyHtoD", e))))?;
        }
        Ok(b)
    }

    fn read<T: Default + Clone>(&self, n: usize) -> Result<Vec<T>> {
        let mut out = vec![T::default(); n];
        if n > 0 {
            // SAFETY: the allocation holds at least n values of T (callers allocate it so).
            unsafe { cu::memcpy_dtoh_sync(&mut out, self.ptr) }.map_err(|e| Error::invalid(format!("CUDA: {}", cuda_err("cuMemcpyDtoH", e))))?;
        }
        Ok(out)
    }
}

impl Drop for DeviceBuffer {
    fn drop(&mut self) {
        // SAFETY: allocated by malloc_sync, freed once.
        unsafe {
            let _ = cu::free_sync(self.ptr);
        }
    }
}

/// Device time of a render's kernels, ms (CUDA events around the plane loop and the finish).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct DeviceTimes {
    pub kernels_ms: f64,
    /// Uploads, kernels and the copy back, wall clock.
    pub total_ms: f64,
}

fn launch(f: sys::CUfunction, n: u64, params: &mut [*mut c_void]) -> Result<()> {
    let blocks = n.div_ceil(BLOCK as u64);
    if blocks == 0 {
        return Ok(());
    }
    if blocks > u32::MAX as u64 {
        return Err(Error::invalid(format!("CUDA: a launch of {n} threads exceeds the grid limit")));
    }
    // SAFETY: `params` point at values of the kernel's parameter types, alive for the call; the default
    // stream orders this launch after the previous ones.
    unsafe { cu::launch_kernel(f, (blocks as u32, 1, 1), (BLOCK, 1, 1), 0, std::ptr::null_mut(), params) }.map_err(|e| Error::invalid(format!("CUDA: {}", cuda_err("cuLaunchKernel", e))))
}

fn arg<T>(v: &T) -> *mut c_void {
    v as *const T as *mut c_void
}

/// Run `plan` on CUDA device `ordinal`: the same kernels as [`RenderPlan::run_twin`], hence its bits.
pub fn render(ordinal: usize, plan: &RenderPlan<'_>, keep_bands: bool) -> Result<(PlanOutput, DeviceTimes)> {
    let l = launcher(ordinal)?;
    let t0 = std::time::Instant::now();
    let npix = plan.detector_pixels();
    let n_rays = plan.rays_per_plane();
    // Device memory first, against what the device has free.
    let taps: Vec<f32> = plan.kernels.iter().flat_map(|(_, t)| t.iter().copied()).collect();
    let bytes = std::mem::size_of_val(plan.steps.as_slice())
        + std::mem::size_of_val(plan.aim_path.as_slice())
        + plan.indices.len() * 8
        + plan.pixels.len() * 4
        + std::mem::size_of_val(plan.cube)
        + std::mem::size_of_val(plan.mask)
        + plan.surface_mask.map_or(0, |m| std::mem::size_of_val(m.values))
        + taps.len() * 4
        + npix * 8 * (2 + plan.bands)
        + if keep_bands { npix * 4 * plan.bands } else { 0 };
    let (free, _) = cu::mem_get_info().map_err(|e| Error::invalid(format!("CUDA: {}", cuda_err("cuMemGetInfo", e))))?;
    if bytes > free {
        return Err(Error::invalid(format!("CUDA: the render needs {:.2} GB on the device, {:.2} GB are free", bytes as f64 / 1e9, free as f64 / 1e9)));
    }
    if plan.rays_per_plane() >= 1 << 40 || plan.planes.len() as u64 >= 1 << 24 {
        return Err(Error::invalid("CUDA: a plan of 2^40 rays a plane or 2^24 planes is beyond the aim-failure key (dc_aim_failure_key)"));
    }
    let d_steps = DeviceBuffer::from(&plan.steps)?;
    let d_aim = DeviceBuffer::from(&plan.aim_path)?;
    let d_n = DeviceBuffer::from(&plan.indices)?;
    let d_pixels = DeviceBuffer::from(&plan.pixels)?;
    let d_cube = DeviceBuffer::from(plan.cube)?;
    let d_mask = DeviceBuffer::from(plan.mask)?;
    let d_surface_mask = DeviceBuffer::from(plan.surface_mask.map_or(&[][..], |m| m.values))?;
    let d_taps = DeviceBuffer::from(&taps)?;
    let d_image = DeviceBuffer::zeroed(npix * 8)?;
    let d_band = DeviceBuffer::zeroed(plan.bands * npix * 8)?;
    let d_out = DeviceBuffer::zeroed(npix * 8)?;
    let d_bands = if keep_bands { Some(DeviceBuffer::zeroed(plan.bands * npix * 4)?) } else { None };
    let d_counts = DeviceBuffer::from(&initial_counts())?;
    let mut tap_offset = Vec::with_capacity(plan.kernels.len());
    let mut off = 0usize;
    for (_, t) in &plan.kernels {
        tap_offset.push(off);
        off += t.len();
    }
    let ev = |what: &str| cu::event::create(sys::CUevent_flags::CU_EVENT_DEFAULT).map_err(|e| Error::invalid(format!("CUDA: {}", cuda_err(what, e))));
    let (e0, e1) = (ev("cuEventCreate")?, ev("cuEventCreate")?);
    // SAFETY: events on the default stream, destroyed below.
    unsafe { cu::event::record(e0, std::ptr::null_mut()) }.map_err(|e| Error::invalid(format!("CUDA: {}", cuda_err("cuEventRecord", e))))?;
    let run = || -> Result<()> {
        for p in 0..plan.planes.len() {
            // SAFETY: the plane image is npix u64 values on the device.
            unsafe { cu::memset_d8_async(d_image.ptr, 0, npix * 8, std::ptr::null_mut()) }.map_err(|e| Error::invalid(format!("CUDA: {}", cuda_err("cuMemsetD8Async", e))))?;
            let n_off = d_n.ptr + (p * plan.n_surfaces * 8) as u64;
            let land = plan.landing(p, d_steps.ptr as *const Step, d_aim.ptr as *const Step, n_off as *const f64, d_pixels.ptr as *const u32, d_surface_mask.ptr as *const f32);
            let dep = plan.deposit(p, land, d_cube.ptr as *const f32, d_mask.ptr as *const f32, d_image.ptr as *mut u64);
            let counts = d_counts.ptr;
            launch(if plan.aim.aiming != 0 { l.deposit_aimed } else { l.deposit }, n_rays, &mut [arg(&dep), arg(&n_rays), arg(&counts)])?;
            let band = d_band.ptr + (plan.planes[p].band as usize * npix * 8) as u64;
            let taps_p = d_taps.ptr + (tap_offset[plan.planes[p].kernel] * 4) as u64;
            let airy = plan.airy(p, d_image.ptr as *const u64, band as *mut f64, taps_p as *const f32);
            let np = npix as u64;
            launch(l.airy, np, &mut [arg(&airy), arg(&np)])?;
        }
        let (band, nb, np, out) = (d_band.ptr, plan.bands as u32, npix as u64, d_out.ptr);
        let bands_ptr: sys::CUdeviceptr = d_bands.as_ref().map_or(0, |b| b.ptr);
        launch(l.finish, np, &mut [arg(&band), arg(&nb), arg(&np), arg(&out), arg(&bands_ptr)])
    };
    let ran = run();
    // SAFETY: the events were created above; synchronising the end event waits for every launch.
    let kernels_ms = unsafe {
        let r = cu::event::record(e1, std::ptr::null_mut()).and_then(|_| cu::event::synchronize(e1)).and_then(|_| cu::event::elapsed(e0, e1));
        let _ = cu::event::destroy(e0);
        let _ = cu::event::destroy(e1);
        r
    };
    ran?;
    let kernels_ms = kernels_ms.map_err(|e| Error::invalid(format!("CUDA: {}", cuda_err("the render's kernels", e))))? as f64;
    let image: Vec<f64> = d_out.read(npix)?;
    let bands = match &d_bands {
        Some(b) => Some(b.read::<f32>(plan.bands * npix)?),
        None => None,
    };
    let c: Vec<u64> = d_counts.read(COUNT_SLOTS)?;
    let mut counts = [0u64; COUNT_SLOTS];
    counts.copy_from_slice(&c);
    Ok((PlanOutput::from_counts(image, bands, &counts), DeviceTimes { kernels_ms, total_ms: t0.elapsed().as_secs_f64() * 1e3 }))
}

/// Where plane `p`'s rays land on the device (`dc_landing_kernel`, or `dc_landing_f32_kernel` for an f32 plan): detector column and row (NaN: none),
/// the status code of ray `q·N + k` (11, `DC_AIM_FAILED`: a ray whose aim failed) and its weight (the coded-mask
/// surface's transmission where it crossed it; 1 without one), as `render::twin::plane_landings_of` computes
/// them on the host; on CUDA device `ordinal`.
pub fn landings(ordinal: usize, plan: &RenderPlan<'_>, p: usize) -> Result<(Vec<f64>, Vec<f64>, Vec<u8>, Vec<f64>)> {
    let l = launcher(ordinal)?;
    if p >= plan.planes.len() {
        return Err(Error::invalid(format!("plane {p}: the plan has {} planes", plan.planes.len())));
    }
    let n = plan.rays_per_plane() as usize;
    let d_steps = DeviceBuffer::from(&plan.steps)?;
    let d_aim = DeviceBuffer::from(&plan.aim_path)?;
    let d_n = DeviceBuffer::from(&plan.indices[p * plan.n_surfaces..(p + 1) * plan.n_surfaces])?;
    let d_pixels = DeviceBuffer::from(&plan.pixels)?;
    let d_surface_mask = DeviceBuffer::from(plan.surface_mask.map_or(&[][..], |m| m.values))?;
    let (d_u, d_v, d_s, d_w) = (DeviceBuffer::zeroed(n * 8)?, DeviceBuffer::zeroed(n * 8)?, DeviceBuffer::zeroed(n)?, DeviceBuffer::zeroed(n * 8)?);
    let mut b = plan.landing(p, d_steps.ptr as *const Step, d_aim.ptr as *const Step, d_n.ptr as *const f64, d_pixels.ptr as *const u32, d_surface_mask.ptr as *const f32);
    b.u = d_u.ptr as *mut f64;
    b.v = d_v.ptr as *mut f64;
    b.status = d_s.ptr as *mut u8;
    b.w = d_w.ptr as *mut f64;
    let kernel = match (plan.f32, plan.aim.aiming != 0) {
        (false, false) => l.landing,
        (true, false) => l.landing_f32,
        (false, true) => l.landing_aimed,
        (true, true) => l.landing_aimed_f32,
    };
    launch(kernel, n as u64, &mut [arg(&b)])?;
    cu::ctx::synchronize().map_err(|e| Error::invalid(format!("CUDA: {}", cuda_err("the landing kernel", e))))?;
    Ok((d_u.read(n)?, d_v.read(n)?, d_s.read(n)?, d_w.read(n)?))
}

/// Trace `rays` through `system` on the device, one thread a ray: `dc_trace_kernel`, or `dc_trace_f32_kernel`
/// when `f32`, the kernels [`super::TwinTracer`] runs on the host, hence its numbers ray for ray (the
/// [`super::CudaTracer`] behind `mapping --device cuda`); on CUDA device `ordinal`.
pub fn trace(ordinal: usize, system: &SequentialSystem, rays: RaySlices<'_>, f32: bool) -> Result<TracedBatch> {
    let l = launcher(ordinal)?;
    let steps = pack::steps(system)?;
    let tables = pack::index_tables(system, rays.wavelength_nm())?;
    let n = rays.len();
    // Inputs: six f64 columns and a table row per ray; outputs: six f64 columns, a status byte, a surface.
    let bytes = std::mem::size_of_val(steps.as_slice()) + tables.tables.len() * 8 + n * (6 * 8 + 4) + n * (6 * 8 + 1 + 4);
    let (free, _) = cu::mem_get_info().map_err(|e| Error::invalid(format!("CUDA: {}", cuda_err("cuMemGetInfo", e))))?;
    if bytes > free {
        return Err(Error::invalid(format!("CUDA: tracing {n} rays needs {:.2} GB on the device, {:.2} GB are free", bytes as f64 / 1e9, free as f64 / 1e9)));
    }
    let d_steps = DeviceBuffer::from(&steps)?;
    let d_tables = DeviceBuffer::from(&tables.tables)?;
    let d_tor = DeviceBuffer::from(&tables.table_of_ray)?;
    let inputs = [rays.origin_x, rays.origin_y, rays.origin_z, rays.dir_x, rays.dir_y, rays.dir_z];
    let d_in = inputs.iter().map(|c| DeviceBuffer::from(c)).collect::<Result<Vec<_>>>()?;
    let d_out = (0..6).map(|_| DeviceBuffer::zeroed(n * 8)).collect::<Result<Vec<_>>>()?;
    let d_status = DeviceBuffer::zeroed(n)?;
    let d_surface = DeviceBuffer::zeroed(n * 4)?;
    let b = Batch {
        path: d_steps.ptr as *const Step,
        tables: d_tables.ptr as *const f64,
        table_of_ray: d_tor.ptr as *const u32,
        ox: d_in[0].ptr as *const f64,
        oy: d_in[1].ptr as *const f64,
        oz: d_in[2].ptr as *const f64,
        dx: d_in[3].ptr as *const f64,
        dy: d_in[4].ptr as *const f64,
        dz: d_in[5].ptr as *const f64,
        x: d_out[0].ptr as *mut f64,
        y: d_out[1].ptr as *mut f64,
        z: d_out[2].ptr as *mut f64,
        ux: d_out[3].ptr as *mut f64,
        uy: d_out[4].ptr as *mut f64,
        uz: d_out[5].ptr as *mut f64,
        status: d_status.ptr as *mut u8,
        surface: d_surface.ptr as *mut u32,
        n_rays: n as u64,
        n_steps: steps.len() as u32,
        n_surfaces: tables.n_surfaces as u32,
    };
    launch(if f32 { l.trace_f32 } else { l.trace }, n as u64, &mut [arg(&b)])?;
    cu::ctx::synchronize().map_err(|e| Error::invalid(format!("CUDA: {}", cuda_err("the trace kernel", e))))?;
    let mut out = TracedBatch::zeroed(n);
    out.x = d_out[0].read(n)?;
    out.y = d_out[1].read(n)?;
    out.z = d_out[2].read(n)?;
    out.dir_x = d_out[3].read(n)?;
    out.dir_y = d_out[4].read(n)?;
    out.dir_z = d_out[5].read(n)?;
    out.surface = d_surface.read(n)?;
    out.status = d_status.read::<u8>(n)?.into_iter().map(super::ffi::status_of).collect();
    out.classify_out_of_range(system.surfaces.len().saturating_sub(1) as u32);
    Ok(out)
}
