//! The renderer's plane transport through the GPU kernels, run on the host (their CPU twin): where each ray
//! lands (`dc_landing_kernel`), then each open pixel's footprint (`dc_footprint_size_kernel`, a prefix sum,
//! `dc_footprint_fill_kernel`). The code the device runs, tested where there is no GPU: it must give
//! [`PlaneContext::trace_plane`]'s footprints, weights and counts bit for bit (tests/gpu_twin.rs), hence the
//! same acquisition, in f64 and in f32 (`--precision f32`: `dc_landing_f32_kernel`), on a finite object plane
//! and for an object at infinity (the scene sampled in field angle), with ray aiming off or on (`paraxial`,
//! `real`: OpticStudio's ray aiming, `rays::aimed_ray`'s Newton solve per ray, `dc_aimed_ray`). A ray whose aim
//! fails stops the CPU renderer with an error (`PlaneContext::ray`); the kernels flag it (`DC_AIM_FAILED`) and
//! the host returns the CPU's error for the first such ray ([`aim_failure`]). In a dual-disperser system (the
//! coded mask on a surface inside it, `ddsp`, `mddsp`) each ray is weighted by the mask's transmission where it
//! crosses that surface (`dc_mask_transmission`, `MaskSurface::transmission`'s arithmetic), as
//! `render::transport::trace_through_mask` weights it.
use super::detector::Detector;
use super::sampling::{RaySampler, Sampling};
use super::transport::{Footprint, PlaneContext, PlaneTransport, SurfaceMask};
use crate::error::{Error, Result};
use crate::gpu::ffi::{dc_footprint_fill_host, dc_footprint_size_host, dc_landing_host, layouts_match, status_of};
use crate::analysis::MappingCube;
use crate::gpu::pack::{self, Aim, LandingBatch, Sampler, Scene, Step, Window};
use crate::rays::{aimed_ray, PupilAim};
use crate::spec::RayAiming;
use crate::system::SequentialSystem;
use crate::tracer::{Precision, RayStatus};
use rayon::prelude::*;

/// Where the renderer's rays of one plane land: ray `k` of `pixels[q]` at index `q·N + k`.
#[derive(Clone, Debug, PartialEq)]
pub struct PlaneLandings {
    /// Detector column and row, continuous (pixel centres at integers; NaN where the ray did not arrive).
    pub u: Vec<f64>,
    pub v: Vec<f64>,
    pub status: Vec<RayStatus>,
    /// With a coded-mask surface (dual-disperser CASSI), each ray's weight: the mask's transmission where it
    /// crossed that surface (0 where it stopped before it). A ray that arrived (`Ok`, its landing in `u`, `v`) with
    /// weight 0 is blocked by the mask (`RayStats::masked`). Empty without a mask surface.
    pub weight: Vec<f64>,
}

/// The scene a plane launch samples: `height × width` pixels of `pitch_mm`, imaged onto `detector`.
#[derive(Clone, Copy, Debug)]
pub struct SceneGeometry<'a> {
    pub height: usize,
    pub width: usize,
    pub pitch_mm: f64,
    pub detector: &'a Detector,
}

/// The device's landing kernel (`dc_landing_kernel`) run on the host: for each open scene pixel of
/// `pixels` (row-major indices) the `sampler.rays` rays of (`seed`, `plane`) — sampled, aimed through the
/// paraxial entrance pupil (at infinity: parallel rays of the pixel's field angles) or by ray aiming, traced at
/// `wavelength_nm` — and where they land. The numbers the renderer (`render::transport`) computes before its
/// splat; where an aim fails, the renderer's error for the first such ray.
#[allow(clippy::too_many_arguments)]
pub fn plane_landings(system: &SequentialSystem, scene: SceneGeometry<'_>, sampler: &RaySampler, seed: u64, plane: u64, wavelength_nm: f64, pixels: &[u32]) -> Result<PlaneLandings> {
    plane_landings_in(Precision::F64, system, scene, sampler, seed, plane, wavelength_nm, pixels)
}

/// [`plane_landings`] traced in `precision`: f64 (`dc_landing_kernel`, the scalar kernel's numbers) or f32
/// (`dc_landing_f32_kernel`, the renderer's `--precision f32` numbers: `trace_row_lanes_f32`). A system with its
/// coded mask on a surface weights its rays by the mask's pattern: [`plane_landings_of`] (a renderer's context).
#[allow(clippy::too_many_arguments)]
pub fn plane_landings_in(precision: Precision, system: &SequentialSystem, scene: SceneGeometry<'_>, sampler: &RaySampler, seed: u64, plane: u64, wavelength_nm: f64, pixels: &[u32]) -> Result<PlaneLandings> {
    if let Some(m) = system.coded_mask {
        return Err(Error::invalid(format!(
            "system `{}` holds its coded mask on surface {} (dual-disperser CASSI): its rays are weighted by the mask's pattern; land them with render::twin::plane_landings_of (a renderer's plane context)",
            system.name(),
            m.surface
        )));
    }
    landings(precision, system, None, scene, sampler, seed, plane, wavelength_nm, pixels)
}

/// The landings of a renderer's rays of one plane ([`plane_landings_in`] in the context's precision, scene, sampler
/// and seed), weighted, in a dual-disperser system, by the coded mask on its surface (`PlaneContext::surface_mask`).
pub fn plane_landings_of(ctx: &PlaneContext<'_>, plane: u64, wavelength_nm: f64, pixels: &[u32]) -> Result<PlaneLandings> {
    let scene = SceneGeometry { height: ctx.scene_height, width: ctx.scene_width, pitch_mm: ctx.scene_pitch_mm, detector: ctx.detector };
    landings(ctx.precision, ctx.system, ctx.surface_mask, scene, ctx.sampler, ctx.seed, plane, wavelength_nm, pixels)
}

/// The landing kernel on the host, the coded-mask surface's pattern given by `surface_mask` (`None` with the
/// system's mask on the object plane).
#[allow(clippy::too_many_arguments)]
fn landings(precision: Precision, system: &SequentialSystem, surface_mask: Option<SurfaceMask<'_>>, scene: SceneGeometry<'_>, sampler: &RaySampler, seed: u64, plane: u64, wavelength_nm: f64, pixels: &[u32]) -> Result<PlaneLandings> {
    if !layouts_match() {
        return Err(Error::invalid("internal: the GPU kernels' C structs and their Rust twins differ in size (src/gpu/pack.rs)"));
    }
    let mask = kernel_mask(system, surface_mask)?;
    let (mask_h, mask_w) = mask.map_or(Ok((0, 0)), |m| pack::mask_size(m.height, m.width))?;
    let (sampler_c, aim, scene_c, aim_path) = launch_constants(system, scene, sampler, seed)?;
    let h = scene_c.scene_height;
    let w = scene_c.scene_width;
    if let Some(&p) = pixels.iter().find(|&&p| p as u64 >= h as u64 * w as u64) {
        return Err(Error::invalid(format!("GPU landing kernel: pixel index {p} outside the {h}×{w} scene")));
    }
    let steps = pack::steps(system)?;
    let n = system.indices(wavelength_nm)?;
    let total = pixels.len() * sampler.rays;
    let (mut u, mut v, mut status, mut weight) = (vec![0.0; total], vec![0.0; total], vec![0u8; total], vec![0.0; total]);
    let weighted = mask.is_some();
    // Whole pixels per task, so that each task's outputs are its own slices.
    let chunk = sampler.rays.max(1) * 64;
    u.par_chunks_mut(chunk).zip(v.par_chunks_mut(chunk)).zip(status.par_chunks_mut(chunk)).zip(weight.par_chunks_mut(chunk)).enumerate().for_each(|(c, (((uc, vc), sc), wc))| {
        let begin = c * chunk;
        let batch = LandingBatch {
            path: steps.as_ptr(),
            n: n.as_ptr(),
            pixels: pixels.as_ptr(),
            aim_path: aim_path.as_ptr(),
            u: uc.as_mut_ptr(),
            v: vc.as_mut_ptr(),
            status: sc.as_mut_ptr(),
            w: if weighted { wc.as_mut_ptr() } else { std::ptr::null_mut() },
            surface_mask: mask.map_or_else(pack::SurfaceMask::default, |m| pack::surface_mask(&m.surface, mask_h, mask_w, m.values.as_ptr())),
            sampler: sampler_c,
            aim,
            scene: scene_c,
            plane,
            n_pixels: pixels.len() as u64,
            max_coord_mm: crate::limits::MAX_IMAGE_COORD_MM,
            n_steps: steps.len() as u32,
            pad: 0,
        };
        // SAFETY: rays [begin, begin + uc.len()) read `pixels[t / N]` (in bounds: t < pixels.len()·N),
        // the path, the index row, the coded mask's height × width values (kernel_mask) and the constants, and
        // write u/v/status (and w, when not null) at t − begin: this task's own slices (dc_landing_host); layouts
        // were checked above.
        unsafe { dc_landing_host(&batch, begin as u64, (begin + uc.len()) as u64, (precision == Precision::F32) as i32) };
    });
    if let Some(t) = status.iter().position(|&s| s == AIM_FAILED) {
        return Err(aim_failure(system, scene, sampler, seed, plane, wavelength_nm, pixels[t / sampler.rays], t % sampler.rays));
    }
    if !weighted {
        weight = Vec::new();
    }
    Ok(PlaneLandings { u, v, status: status.into_iter().map(status_of).collect(), weight })
}

/// The coded-mask surface the kernels read: `surface_mask`, checked against the system's (its place and sampling)
/// and its pattern's size. Errors: a system whose mask surface has no pattern given, a pattern for a system
/// without one, or a pattern of the wrong size.
fn kernel_mask<'a>(system: &SequentialSystem, surface_mask: Option<SurfaceMask<'a>>) -> Result<Option<SurfaceMask<'a>>> {
    match (system.coded_mask, surface_mask) {
        (None, None) => Ok(None),
        (Some(m), Some(sm)) if sm.surface == m && sm.values.len() == sm.height * sm.width => Ok(Some(sm)),
        (m, sm) => Err(Error::invalid(format!(
            "internal: GPU landing kernel: system `{}`'s coded-mask surface {:?} and the mask given {:?} disagree",
            system.name(),
            m.map(|m| m.surface),
            sm.map(|s| (s.surface.surface, s.height, s.width, s.values.len()))
        ))),
    }
}

/// `DC_AIM_FAILED` (src/gpu/kernels/dc_render.h): the kernels found no aimed ray for this one.
pub(crate) const AIM_FAILED: u8 = 11;

/// The CPU renderer's error for ray `k` of scene pixel `pixel` at (`seed`, `plane`), whose aim the kernels
/// flagged as failed (`DC_AIM_FAILED`): the same sample and field point ([`PlaneContext::ray`]) aimed by
/// `rays::aimed_ray`, whose error names the field, the pupil point and why. An internal error if the CPU's
/// aim succeeds there (the kernels and the CPU would disagree).
#[allow(clippy::too_many_arguments)]
pub(crate) fn aim_failure(system: &SequentialSystem, scene: SceneGeometry<'_>, sampler: &RaySampler, seed: u64, plane: u64, wavelength_nm: f64, pixel: u32, k: usize) -> Error {
    let n = match system.indices(wavelength_nm) {
        Ok(n) => n,
        Err(e) => return e,
    };
    let mut s = vec![[0.0; 4]; sampler.rays];
    sampler.fill(seed, plane, pixel as u64, &mut s);
    let (row, col) = (pixel as usize / scene.width, pixel as usize % scene.width);
    let s = s[k];
    let field = MappingCube::sample_xy(scene.height, scene.width, scene.pitch_mm, row, col, s[2], s[3]);
    match aimed_ray(system, &n, field, s[0], s[1]) {
        Err(e) => e,
        Ok(_) => Error::invalid(format!("internal: the GPU kernels' ray aiming failed for ray {k} of scene pixel {pixel} (plane {plane}) where the CPU's succeeds")),
    }
}


/// The constants of a plane launch (`dc_sampler`, `dc_aim`, `dc_scene`) and ray aiming's path: the sampler's,
/// the paraxial pupil aim's (for an object at infinity the parallel rays of field angles,
/// `PupilAim::parallel_ray`; the scene's pitch is then an angle, rad), ray aiming's (`paraxial` or `real`: the
/// stop radius aimed at and the steps to the stop, [`pack::aim_path`]) and the scene and detector geometry.
pub(crate) fn launch_constants(system: &SequentialSystem, scene: SceneGeometry<'_>, sampler: &RaySampler, seed: u64) -> Result<(Sampler, Aim, Scene, Vec<Step>)> {
    let aim_path = pack::aim_path(system)?;
    let too_big = |what: &str, v: usize| Error::invalid(format!("GPU kernels: {what} = {v} exceeds u32"));
    let (h, w) = (u32::try_from(scene.height).map_err(|_| too_big("scene height", scene.height))?, u32::try_from(scene.width).map_err(|_| too_big("scene width", scene.width))?);
    let rays = u32::try_from(sampler.rays).map_err(|_| too_big("rays", sampler.rays))?;
    let (a, b) = sampler.grid();
    let pupil = PupilAim::of(system);
    let (telecentric, scale, sin_marginal, magnification_sign, distance_mm) = pupil.parts();
    let sampler_c = Sampler { seed, rays, mode: if sampler.mode == Sampling::Independent { 1 } else { 0 }, grid_a: a as u32, grid_b: b as u32 };
    let aiming = system.spec.ray_aiming != RayAiming::Off;
    let aim = Aim {
        scale,
        sin_marginal,
        magnification_sign,
        distance_mm,
        telecentric: telecentric as u32,
        at_infinity: pupil.at_infinity as u32,
        stop_radius_mm: system.aim_stop_radius_mm,
        aiming: aiming as u32,
        aim_steps: aim_path.len().saturating_sub(1) as u32,
    };
    let scene_c = Scene {
        scene_pitch_mm: scene.pitch_mm,
        detector_x_left_mm: scene.detector.x_left_mm,
        detector_y_top_mm: scene.detector.y_top_mm,
        detector_pitch_mm: scene.detector.pitch_mm,
        scene_height: h,
        scene_width: w,
    };
    Ok((sampler_c, aim, scene_c, aim_path))
}

/// [`PlaneContext::trace_plane`] through the GPU kernels' host twin, in the context's precision: the same
/// [`PlaneTransport`], bit for bit (with a coded-mask surface too: each ray's taps weighted by the mask's
/// transmission where it crossed it, the rays it blocks counted `masked`).
pub fn trace_plane(ctx: &PlaneContext<'_>, plane: usize, wavelength_nm: f64) -> Result<PlaneTransport> {
    let (h, w) = (ctx.scene_height, ctx.scene_width);
    let pixels: Vec<u32> = (0..h * w).filter(|&q| ctx.mask[q] > 0.0).map(|q| q as u32).collect();
    let land = plane_landings_of(ctx, plane as u64, wavelength_nm, &pixels)?;
    let mut out = PlaneTransport::default();
    out.stats.traced = land.status.len() as u64;
    for &s in &land.status {
        out.stats.count(s);
    }
    // A ray the mask blocks (arrived, transmission 0) deposits nothing: counted apart, not as arrived.
    let masked = land.weight.iter().zip(&land.status).filter(|&(&w, &s)| s == RayStatus::Ok && w == 0.0).count() as u64;
    out.stats.arrived -= masked;
    out.stats.masked += masked;
    let weights_ptr = if land.weight.is_empty() { std::ptr::null() } else { land.weight.as_ptr() };
    let n = ctx.sampler.rays;
    let np = pixels.len();
    let (dw, dh) = (ctx.detector.width as i64, ctx.detector.height as i64);
    let mut wins = vec![Window::default(); np];
    // SAFETY: u/v (and the weights, unless null) hold np·n landings; wins has np entries; the layouts were checked
    // by plane_landings_of.
    unsafe { dc_footprint_size_host(land.u.as_ptr(), land.v.as_ptr(), weights_ptr, n as u32, dw, dh, wins.as_mut_ptr(), 0, np as u64) };
    let mut offsets = vec![0u64; np];
    let mut total = 0u64;
    for (o, win) in offsets.iter_mut().zip(&wins) {
        *o = total;
        total += win.w as u64 * win.h as u64;
    }
    let mut scratch = vec![0.0f64; total as usize];
    let mut weights = vec![0.0f32; total as usize];
    // SAFETY: offsets[q] + w·h ≤ total for every window; scratch and weights have `total` cells.
    unsafe { dc_footprint_fill_host(land.u.as_ptr(), land.v.as_ptr(), weights_ptr, n as u32, wins.as_mut_ptr(), offsets.as_ptr(), scratch.as_mut_ptr(), weights.as_mut_ptr(), 0, np as u64) };
    for (q, win) in wins.iter().enumerate() {
        out.stats.off_detector += win.off_detector;
        if win.w > 0 {
            out.footprints.push(Footprint { pixel: pixels[q], x0: win.x0 as u16, y0: win.y0 as u16, w: win.w as u16, h: win.h as u16, start: offsets[q] as u32 });
        }
    }
    out.weights = weights;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tracer::simd::{trace_block_raw, BlockF32, LANES_F32};
    use crate::tracer::SimdLevel;
    use glam::DVec3;

    /// Lane `k`'s landing as the renderer classifies it (`LandLoop` on the widened lanes): its status and detector
    /// coordinates (NaN where it did not arrive).
    fn lane_landing(b: &BlockF32, k: usize, detector: &Detector) -> (RayStatus, (f64, f64)) {
        match b.result(k) {
            Ok((p, d)) if p.is_finite() && d.is_finite() && p.abs().max_element() <= crate::limits::MAX_IMAGE_COORD_MM => (RayStatus::Ok, detector.to_pixel(p.x, p.y)),
            Ok(_) => (RayStatus::OutOfRange, (f64::NAN, f64::NAN)),
            Err((st, _)) => (st, (f64::NAN, f64::NAN)),
        }
    }

    /// The renderer's object rays of `pixels` (its samples, pixel centres and paraxial aim, `PlaneContext::ray`).
    fn object_rays(sys: &SequentialSystem, scene: SceneGeometry<'_>, sampler: &RaySampler, seed: u64, plane: u64, pixels: &[u32]) -> Vec<(DVec3, DVec3)> {
        let aim = PupilAim::of(sys);
        let mut object = Vec::new();
        let mut s = vec![[0.0; 4]; sampler.rays];
        for &q in pixels {
            sampler.fill(seed, plane, q as u64, &mut s);
            let (row, col) = (q as usize / scene.width, q as usize % scene.width);
            for smp in &s {
                let [fx, fy] = MappingCube::sample_xy(scene.height, scene.width, scene.pitch_mm, row, col, smp[2], smp[3]);
                object.push((DVec3::new(fx, fy, 0.0), DVec3::from(aim.direction(fx, fy, smp[0], smp[1]))));
            }
        }
        object
    }

    /// The f32 landing kernel (`dc_landing_f32_kernel`) equals the renderer's f32 steps ray for ray, bit for
    /// bit — the sample, the aimed object ray, `set_raw` and the f32 lane trace (every SIMD level), the
    /// widened landing's checks and detector coordinates (`trace_row_lanes_f32` + `LandLoop`) — so that no
    /// landing difference hides under the f32 rounding of the footprint weights (tests/gpu_twin.rs compares
    /// those).
    #[test]
    fn f32_landing_kernel_equals_the_renderers_f32_steps() {
        let detector = Detector { width: 700, height: 700, pitch_mm: 0.01, x_left_mm: -3.5, y_top_mm: 3.5 };
        for name in ["sp", "ap", "msp", "map"] {
            let sys = SequentialSystem::build(&crate::presets::spec(name).unwrap()).unwrap();
            let pixels: Vec<u32> = (0..(12 * 16) as u32).filter(|q| q % 3 != 1).collect();
            let (mut counts, mut differ) = (std::collections::BTreeMap::new(), 0);
            // Scenes of ±3.2 mm (inside the field), ±12 mm (past the field stops: vignetted rays) and ±1.2 m
            // (origins beyond f32's 1 m: invalid inputs in f32).
            for (rays, mode, seed, plane, wl, pitch_mm) in [(20, Sampling::Stratified, 0u64, 0u64, 450.0, 0.4), (7, Sampling::Stratified, 99, 57, 555.5, 1.5), (5, Sampling::Independent, 12345, 3, 650.0, 150.0)] {
                let scene = SceneGeometry { height: 12, width: 16, pitch_mm, detector: &detector };
                let sampler = RaySampler::new(rays, mode);
                let twin = plane_landings_in(Precision::F32, &sys, scene, &sampler, seed, plane, wl, &pixels).unwrap();
                let f64_ = plane_landings(&sys, scene, &sampler, seed, plane, wl, &pixels).unwrap();
                // The renderer's rays, then its f32 lanes.
                let object = object_rays(&sys, scene, &sampler, seed, plane, &pixels);
                let n = sys.indices(wl).unwrap();
                let tables = [n.as_slice(); LANES_F32];
                for level in SimdLevel::available() {
                    for start in (0..object.len()).step_by(LANES_F32) {
                        let m = (object.len() - start).min(LANES_F32);
                        let mut b = BlockF32::default();
                        for k in 0..m {
                            b.set_raw(k, object[start + k].0, object[start + k].1);
                        }
                        trace_block_raw(level, &sys.path, &tables, &mut b);
                        for k in 0..m {
                            let t = start + k;
                            let (want, (u, v)) = lane_landing(&b, k, &detector);
                            let label = format!("{name} {rays} {mode:?} {} ray {t}", level.name());
                            assert_eq!(twin.status[t], want, "{label}");
                            assert_eq!((twin.u[t].to_bits(), twin.v[t].to_bits()), (u.to_bits(), v.to_bits()), "{label}: ({}, {}) vs ({u}, {v})", twin.u[t], twin.v[t]);
                        }
                    }
                }
                for &st in &twin.status {
                    *counts.entry(format!("{st:?}")).or_insert(0usize) += 1;
                }
                differ += (0..twin.u.len()).filter(|&t| twin.status[t] == RayStatus::Ok && twin.u[t] != f64_.u[t]).count();
            }
            assert!(differ > 0, "{name}: f32 landings must differ from f64");
            eprintln!("{name}: {counts:?}");
            for st in [RayStatus::Ok, RayStatus::InvalidInput] {
                assert!(counts.contains_key(&format!("{st:?}")), "{name}: no {st:?} ray among {counts:?}");
            }
            assert!(counts.len() >= 3, "{name}: the rays must also stop on the way: {counts:?}");
        }
    }
    /// The f32 landing kernel through a coded-mask surface (`ddsp`, `mddsp`; nearest and bilinear): each ray's
    /// weight is the mask's transmission where the renderer's f32 lanes cross the mask surface — the lanes traced
    /// over the path's first arm `path[..=step]` (`trace_block_raw`, as `trace_row_lanes` splits it), their f32
    /// position widened — then on over the second arm to their landing, bit for bit on every SIMD level. (The CPU
    /// renderer itself refuses f32 with a mask surface; this holds the f32 kernels to its f32 lanes' numbers.)
    #[test]
    fn f32_landing_kernel_reads_the_mask_surface_where_the_f32_lanes_cross_it() {
        use crate::spec::MaskSampling;
        use crate::tracer::simd::{trace_block, Real};
        let detector = Detector { width: 900, height: 900, pitch_mm: 0.01, x_left_mm: -4.5, y_top_mm: 4.5 };
        let (h, w) = (12, 16);
        let values: Vec<f32> = (0..h * w).map(|q| if q % 5 == 2 { 0.0 } else { 0.25 + 0.75 * ((q * 37 % 101) as f32 / 100.0) }).collect();
        for name in ["ddsp", "mddsp"] {
            for sampling in [MaskSampling::Nearest, MaskSampling::Bilinear] {
                let mut spec = crate::presets::spec(name).unwrap();
                spec.surfaces.iter_mut().find_map(|s| s.coded_mask.as_mut()).unwrap().sampling = sampling;
                let sys = SequentialSystem::build(&spec).unwrap();
                let m = sys.coded_mask.unwrap();
                let mask = SurfaceMask { surface: m, values: &values, height: h, width: w };
                let (arm1, arm2) = sys.path.split_at(m.step + 1);
                let (mut masked, mut stopped) = (0, 0);
                // 10 µm pixels (the mask's), 0.3 mm (past the mask: its opaque frame) and 20 mm (rays that miss the
                // first arm's surfaces, before the mask).
                for (seed, plane, wl, pitch_mm) in [(4u64, 1u64, 520.0, 0.01), (9, 30, 470.0, 0.3), (2, 5, 600.0, 20.0)] {
                    let scene = SceneGeometry { height: h, width: w, pitch_mm, detector: &detector };
                    let sampler = RaySampler::new(5, Sampling::Stratified);
                    let pixels: Vec<u32> = (0..(h * w) as u32).collect();
                    let twin = landings(Precision::F32, &sys, Some(mask), scene, &sampler, seed, plane, wl, &pixels).unwrap();
                    let object = object_rays(&sys, scene, &sampler, seed, plane, &pixels);
                    let n = sys.indices(wl).unwrap();
                    let tables = [n.as_slice(); LANES_F32];
                    for level in SimdLevel::available() {
                        for start in (0..object.len()).step_by(LANES_F32) {
                            let k_end = (object.len() - start).min(LANES_F32);
                            let mut b = BlockF32::default();
                            for k in 0..k_end {
                                b.set_raw(k, object[start + k].0, object[start + k].1);
                            }
                            trace_block_raw(level, arm1, &tables, &mut b);
                            let weight: Vec<f64> = (0..k_end).map(|k| if b.alive.0[k] { m.transmission(&values, h, w, b.p.x.0[k].to_f64(), b.p.y.0[k].to_f64()) } else { 0.0 }).collect();
                            trace_block(level, arm2, &tables, &mut b);
                            for k in 0..k_end {
                                let t = start + k;
                                let (want, (u, v)) = lane_landing(&b, k, &detector);
                                let label = format!("{name} {sampling:?} {} ray {t}", level.name());
                                assert_eq!(twin.status[t], want, "{label}");
                                assert_eq!((twin.u[t].to_bits(), twin.v[t].to_bits()), (u.to_bits(), v.to_bits()), "{label}");
                                assert_eq!(twin.weight[t].to_bits(), weight[k].to_bits(), "{label}: weight {} vs {}", twin.weight[t], weight[k]);
                            }
                        }
                    }
                    masked += (0..twin.u.len()).filter(|&t| twin.status[t] == RayStatus::Ok && twin.weight[t] == 0.0).count();
                    stopped += (0..twin.u.len()).filter(|&t| twin.status[t] != RayStatus::Ok && twin.weight[t] == 0.0).count();
                }
                assert!(masked > 0 && stopped > 0, "{name} {sampling:?}: {masked} masked, {stopped} stopped of weight 0");
            }
        }
    }
}
