//! A whole acquisition as the kernels compute it: the plan (every array a device render reads, built by
//! `render::device` from a renderer and a scene, so that `gpu/` never imports `render/`), and its run on
//! the host twin. [`super::cuda`] runs the same plan on a CUDA device with the same kernels
//! (`src/gpu/kernels/dc_accum.h`): the plane images are sums of 64-bit fixed-point integers, so the twin's
//! and the device's acquisitions have the same bits whatever the order of the rays (tests/gpu_render.rs).
use super::ffi::{dc_airy_host, dc_deposit_host, dc_finish_host, dc_landing_host, layouts_match};
use super::pack::{Aim, AiryBatch, DepositBatch, LandingBatch, Sampler, Scene, Step, SurfaceMask};
use crate::system::MaskSurface;
use crate::error::{Error, Result};
use rayon::prelude::*;

/// Status slots (`DC_STATUS_SLOTS`: `tracer::RayStatus` codes 0 … 9, then `DC_MASKED`, 10: rays the coded-mask
/// surface blocks) and the off-detector slot after them.
pub const STATUS_SLOTS: usize = 11;
/// The slot of `DC_MASKED`: rays that arrived but were blocked by the coded-mask surface (`RayStats::masked`).
pub const MASKED_SLOT: usize = 10;
/// The slots of a run's counts: the statuses, the off-detector weight, then (`DC_AIM_FAILURE_SLOT`) the first ray
/// whose aim failed as `plane << 40 | ray` (the minimum; `u64::MAX` when none).
pub(crate) const COUNT_SLOTS: usize = STATUS_SLOTS + 2;
/// Fixed-point units of one ray's weight in the off-detector count (`DC_LOST_ONE`).
pub const LOST_ONE: f64 = 16_777_216.0;
/// Threads per block of every launch.
pub(crate) const BLOCK: u32 = 256;

/// One render plane of the plan.
#[derive(Clone, Copy, Debug)]
pub struct PlanePlan {
    /// The plane's index in the render (the sampler's `plane` key).
    pub plane: u64,
    /// The scene bands it interpolates and the weight of `k1` (`SpectralCube::interpolation`).
    pub k0: u32,
    pub k1: u32,
    pub tw: f32,
    /// The render band it adds to, and its weight w_p (B/K).
    pub band: u32,
    pub weight: f64,
    /// Its Airy kernel in [`RenderPlan::kernels`].
    pub kernel: usize,
}

/// Everything a device render reads. Built by `render::device::plan`; run by [`RenderPlan::run_twin`] or
/// [`super::cuda::render`].
pub struct RenderPlan<'a> {
    pub(crate) steps: Vec<Step>,
    /// Ray aiming's steps to the stop and its probe (`pack::aim_path`; empty with aiming off).
    pub(crate) aim_path: Vec<Step>,
    /// The refractive index after each surface, `n_surfaces` per plane, in plane order.
    pub(crate) indices: Vec<f64>,
    pub(crate) n_surfaces: usize,
    /// Open scene pixels (mask > 0), row-major index.
    pub(crate) pixels: Vec<u32>,
    pub(crate) sampler: Sampler,
    pub(crate) aim: Aim,
    pub(crate) scene: Scene,
    pub(crate) max_coord_mm: f64,
    /// The scene, `[pixel][band]`, and the mask on the object plane, per pixel (all 1 with a mask surface).
    pub(crate) cube: &'a [f32],
    pub(crate) cube_bands: u32,
    pub(crate) mask: &'a [f32],
    /// The coded mask on a surface inside the system (dual-disperser CASSI); `None` without one.
    pub(crate) surface_mask: Option<PlanMask<'a>>,
    pub(crate) planes: Vec<PlanePlan>,
    /// Airy kernels: half-width and (2·half + 1)² taps (a single 1 for no blur).
    pub(crate) kernels: Vec<(usize, Vec<f32>)>,
    pub(crate) det_w: usize,
    pub(crate) det_h: usize,
    /// Render bands (the acquisition's band images).
    pub(crate) bands: usize,
    /// 2^S, and the value of one fixed-point unit 2^−S · (1/N).
    pub(crate) fixed_scale: f64,
    pub(crate) unit: f64,
    /// Trace in f32 (the renderer's `--precision f32` numbers) instead of f64.
    pub(crate) f32: bool,
}

/// The coded mask on a surface of a plan's system: where it is and its `height × width` pattern, row-major.
#[derive(Clone, Copy, Debug)]
pub struct PlanMask<'a> {
    pub surface: MaskSurface,
    pub height: u32,
    pub width: u32,
    pub values: &'a [f32],
}

/// What a run of the plan gives.
#[derive(Clone, Debug, PartialEq)]
pub struct PlanOutput {
    /// The acquisition, f64 sums of the f32 band images in band order.
    pub image: Vec<f64>,
    /// The band images (band-major), when asked for.
    pub bands: Option<Vec<f32>>,
    /// Rays by status code (`tracer::RayStatus`), then the off-detector weight in [`LOST_ONE`] units.
    pub counts: [u64; STATUS_SLOTS + 1],
    /// The first ray whose aim failed (ray aiming on): (plane, ray of the plane), lowest plane first. The CPU
    /// renderer stops with an error there; `render::device` returns the same error.
    pub aim_failure: Option<(u64, u64)>,
}

impl PlanOutput {
    /// The output of a run's counts ([`COUNT_SLOTS`]).
    pub(crate) fn from_counts(image: Vec<f64>, bands: Option<Vec<f32>>, c: &[u64; COUNT_SLOTS]) -> Self {
        let mut counts = [0u64; STATUS_SLOTS + 1];
        counts.copy_from_slice(&c[..STATUS_SLOTS + 1]);
        let key = c[STATUS_SLOTS + 1];
        PlanOutput { image, bands, counts, aim_failure: (key != u64::MAX).then(|| (key >> 40, key & ((1u64 << 40) - 1))) }
    }
}

/// A run's counts before its first ray: zero, the aim-failure slot at "none".
pub(crate) fn initial_counts() -> [u64; COUNT_SLOTS] {
    let mut c = [0u64; COUNT_SLOTS];
    c[STATUS_SLOTS + 1] = u64::MAX;
    c
}

/// The fixed-point scale 2^S of a plane image: the largest power of two for which no pixel can overflow,
/// |Σ| ≤ (rays of a plane) · max|value| · (1 + 2⁻⁵⁰) · 2^S + (rays · 4) · ½ < 2⁶² (each ray's four taps sum to
/// 1 up to rounding, each deposit is rounded once). `None` when every value is zero (nothing is deposited).
pub fn fixed_scale(max_abs_value: f64, rays_per_plane: u64) -> Option<f64> {
    if !(max_abs_value.is_finite()) || max_abs_value <= 0.0 || rays_per_plane == 0 {
        return None;
    }
    // 2^S · bound ≤ 2^61 leaves 2^61 for the rounding terms (rays · 2 < 2^61 for any feasible launch).
    let bound = max_abs_value * rays_per_plane as f64 * 2.0;
    let e = bound.log2().ceil() as i32;
    let s = (61 - e).clamp(-1000, 1000);
    Some(2f64.powi(s))
}

impl<'a> RenderPlan<'a> {
    /// Rays traced at each plane (open pixels × rays per pixel).
    pub fn rays_per_plane(&self) -> u64 {
        self.pixels.len() as u64 * self.sampler.rays as u64
    }

    /// Detector pixels.
    pub fn detector_pixels(&self) -> usize {
        self.det_w * self.det_h
    }

    /// Plane `p`'s landing launch, its arrays at the given addresses (host or device; `surface_mask`: the coded
    /// mask surface's pattern, read only with one).
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn landing(&self, p: usize, path: *const Step, aim_path: *const Step, n: *const f64, pixels: *const u32, surface_mask: *const f32) -> LandingBatch {
        LandingBatch {
            path,
            n,
            pixels,
            aim_path,
            u: std::ptr::null_mut(),
            v: std::ptr::null_mut(),
            status: std::ptr::null_mut(),
            w: std::ptr::null_mut(),
            surface_mask: self.surface_mask.map_or_else(SurfaceMask::default, |m| super::pack::surface_mask(&m.surface, m.height, m.width, surface_mask)),
            sampler: self.sampler,
            aim: self.aim,
            scene: self.scene,
            plane: self.planes[p].plane,
            n_pixels: self.pixels.len() as u64,
            max_coord_mm: self.max_coord_mm,
            n_steps: self.steps.len() as u32,
            pad: 0,
        }
    }

    /// Plane `p`'s deposit launch.
    pub(crate) fn deposit(&self, p: usize, land: LandingBatch, cube: *const f32, mask: *const f32, image: *mut u64) -> DepositBatch {
        let pl = &self.planes[p];
        DepositBatch {
            land,
            cube,
            mask,
            image,
            fixed_scale: self.fixed_scale,
            det_w: self.det_w as i64,
            det_h: self.det_h as i64,
            bands: self.cube_bands,
            k0: pl.k0,
            k1: pl.k1,
            tw: pl.tw,
            f32: self.f32 as u32,
        }
    }

    /// Plane `p`'s Airy gather into its band.
    pub(crate) fn airy(&self, p: usize, image: *const u64, band: *mut f64, taps: *const f32) -> AiryBatch {
        let pl = &self.planes[p];
        AiryBatch {
            image,
            band,
            taps,
            det_w: self.det_w as i64,
            det_h: self.det_h as i64,
            half: self.kernels[pl.kernel].0 as i64,
            unit: self.unit,
            weight: pl.weight,
        }
    }

    /// Where plane `p`'s rays land, computed on the host from this plan's own launch arguments: what
    /// [`super::cuda::landings`] computes on the device (column, row, status code, weight of ray `q·N + k`),
    /// with the host-compiled kernel. The GPU check's dry run (`render::device::check_on` with
    /// [`crate::render::device::Executor::Twin`]) compares it with `render::twin::plane_landings_of`, which builds
    /// its own launch: so the plan's packing is checked without a device.
    pub fn landings_twin(&self, p: usize) -> Result<(Vec<f64>, Vec<f64>, Vec<u8>, Vec<f64>)> {
        if !layouts_match() {
            return Err(Error::invalid("internal: the GPU kernels' C structs and their Rust twins differ in size (src/gpu/pack.rs)"));
        }
        if p >= self.planes.len() {
            return Err(Error::invalid(format!("plane {p}: the plan has {} planes", self.planes.len())));
        }
        let n = self.rays_per_plane() as usize;
        let idx = &self.indices[p * self.n_surfaces..(p + 1) * self.n_surfaces];
        let (mut u, mut v, mut s, mut w) = (vec![0.0f64; n], vec![0.0f64; n], vec![0u8; n], vec![0.0f64; n]);
        let mut b = self.landing(p, self.steps.as_ptr(), self.aim_path.as_ptr(), idx.as_ptr(), self.pixels.as_ptr(), self.surface_mask.map_or(std::ptr::null(), |m| m.values.as_ptr()));
        b.u = u.as_mut_ptr();
        b.v = v.as_mut_ptr();
        b.status = s.as_mut_ptr();
        b.w = w.as_mut_ptr();
        // SAFETY: rays [0, n) read pixels[t / N] (in bounds), the path, the aim path, the plane's index row, the
        // surface mask of the size the plan was built for, and write u/v/status/w[t], each of n cells; layouts
        // checked above.
        unsafe { dc_landing_host(&b, 0, n as u64, self.f32 as i32) };
        Ok((u, v, s, w))
    }

    /// Run the plan on the host: the device's kernels compiled for the CPU (host.c), bands in parallel,
    /// each band's planes in ascending order (the device's order), so the result is the device's, bit for
    /// bit, on any thread count.
    pub fn run_twin(&self, keep_bands: bool) -> Result<PlanOutput> {
        if !layouts_match() {
            return Err(Error::invalid("internal: the GPU kernels' C structs and their Rust twins differ in size (src/gpu/pack.rs)"));
        }
        let npix = self.detector_pixels();
        let n_rays = self.rays_per_plane();
        let mut band = vec![0.0f64; self.bands * npix];
        if self.rays_per_plane() >= 1 << 40 || self.planes.len() as u64 >= 1 << 24 {
            return Err(Error::invalid("GPU kernels: a plan of 2^40 rays a plane or 2^24 planes is beyond the aim-failure key (dc_aim_failure_key)"));
        }
        let counts: Vec<[u64; COUNT_SLOTS]> = band
            .par_chunks_mut(npix.max(1))
            .enumerate()
            .map(|(b, band_img)| {
                let mut img = vec![0u64; npix];
                let mut counts = initial_counts();
                for (p, pl) in self.planes.iter().enumerate() {
                    if pl.band as usize != b {
                        continue;
                    }
                    img.iter_mut().for_each(|v| *v = 0);
                    let n = &self.indices[p * self.n_surfaces..(p + 1) * self.n_surfaces];
                    let land = self.landing(p, self.steps.as_ptr(), self.aim_path.as_ptr(), n.as_ptr(), self.pixels.as_ptr(), self.surface_mask.map_or(std::ptr::null(), |m| m.values.as_ptr()));
                    let dep = self.deposit(p, land, self.cube.as_ptr(), self.mask.as_ptr(), img.as_mut_ptr());
                    // SAFETY: the batch's arrays live for the call (steps, the aim path, the plane's index row, the open
                    // pixels, the cube, mask and surface mask of the sizes the plan was built for, this worker's own plane
                    // image of npix cells); rays [0, n_rays) index pixels[t / N] in bounds; layouts checked.
                    unsafe { dc_deposit_host(&dep, 0, n_rays, counts.as_mut_ptr()) };
                    let airy = self.airy(p, img.as_ptr(), band_img.as_mut_ptr(), self.kernels[pl.kernel].1.as_ptr());
                    // SAFETY: image and band_img have npix cells, the taps (2·half + 1)²; pixels [0, npix).
                    unsafe { dc_airy_host(&airy, 0, npix as u64) };
                }
                counts
            })
            .collect();
        let mut total = initial_counts();
        for c in &counts {
            for (a, b) in total[..STATUS_SLOTS + 1].iter_mut().zip(c) {
                *a = a.wrapping_add(*b);
            }
            total[STATUS_SLOTS + 1] = total[STATUS_SLOTS + 1].min(c[STATUS_SLOTS + 1]);
        }
        let mut image = vec![0.0f64; npix];
        let mut bands_f32 = keep_bands.then(|| vec![0.0f32; self.bands * npix]);
        let bp = bands_f32.as_mut().map_or(std::ptr::null_mut(), |b| b.as_mut_ptr());
        // SAFETY: band holds bands·npix values, image npix, bands_f32 bands·npix or is null.
        unsafe { dc_finish_host(band.as_ptr(), self.bands as u32, npix as u64, image.as_mut_ptr(), bp, 0, npix as u64) };
        Ok(PlanOutput::from_counts(image, bands_f32, &total))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_fixed_point_scale_leaves_room_for_every_deposit() {
        let s = fixed_scale(1.0, 2_621_440).unwrap();
        assert_eq!(s.log2().fract(), 0.0);
        // The bound times the scale stays below 2^62, and the scale is not needlessly small (within 2×).
        let worst = 1.0 * 2_621_440.0 * s;
        assert!(worst < 2f64.powi(62) && worst * 4.0 >= 2f64.powi(61), "{s} {worst}");
        assert_eq!(fixed_scale(0.0, 10), None);
        assert_eq!(fixed_scale(f64::NAN, 10), None);
        assert!(fixed_scale(1e-300, 1).unwrap().is_finite());
    }
}
