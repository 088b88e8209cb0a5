//! Rendering a coded acquisition: H_c(:,:,λ) = H(:,:,λ) ⊙ M traced plane by plane to the detector, each
//! plane blurred by its Airy disk, weighted by B/K and summed (see the [module docs](super)).
//!
//! Parallelism: bands are rendered in parallel (rayon), the planes of a band in order inside one task, and
//! the band images summed in band order afterwards; every ray's random numbers depend only on
//! (seed, plane, pixel, sample). So the result is bit-identical for any thread count.
use super::airy::AiryKernel;
use super::convolve::{convolve, PaddedLayout, TILE};
use super::detector::Detector;
use super::mask::Mask;
use super::sampling::{RaySampler, Sampling};
use super::spectral::SpectralSampling;
use super::transport::{PlaneContext, PlaneTransport, RayStats, SurfaceMask};
use crate::error::{Error, Result};
use crate::scene::SpectralCube;
use crate::system::SequentialSystem;
use crate::tracer::Tracer;
use rayon::prelude::*;
use std::time::Instant;

/// The Airy blur: disk diameter `diameter_px` at `reference_nm`, ∝ λ, truncated at dark ring `rings`.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct AiryConfig {
    pub diameter_px: f64,
    pub reference_nm: f64,
    pub rings: usize,
}

impl AiryConfig {
    /// The ranges `render` accepts: diameter in (0, [`crate::limits::MAX_AIRY_DIAMETER_PX`]] px, reference
    /// wavelength in [`crate::limits::WAVELENGTH_RANGE_NM`], truncation ring 1–5. The error names the field.
    pub fn validate(&self) -> Result<()> {
        let (lo, hi) = crate::limits::WAVELENGTH_RANGE_NM;
        if !(self.diameter_px.is_finite() && self.diameter_px > 0.0 && self.diameter_px <= crate::limits::MAX_AIRY_DIAMETER_PX) {
            return Err(Error::invalid(format!("airy.diameter_px = {}: must be in (0, {}] pixels", crate::limits::fmt_num(self.diameter_px), crate::limits::MAX_AIRY_DIAMETER_PX)));
        }
        if !(self.reference_nm.is_finite() && (lo..=hi).contains(&self.reference_nm)) {
            return Err(Error::invalid(format!("airy.reference_nm = {}: must be in {lo}–{hi} nm", crate::limits::fmt_num(self.reference_nm))));
        }
        if !(1..=5).contains(&self.rings) {
            return Err(Error::invalid(format!("airy.rings = {}: must be in 1..=5 (the dark ring the kernel is truncated at)", self.rings)));
        }
        Ok(())
    }
}

impl Default for AiryConfig {
    fn default() -> Self {
        AiryConfig { diameter_px: 2.5, reference_nm: 520.0, rings: 3 }
    }
}

/// Render settings (the scene and the mask come separately).
#[derive(Clone, Debug, serde::Serialize)]
pub struct RenderConfig {
    /// Scene pixels (height, width) on the object plane.
    pub scene_height: usize,
    pub scene_width: usize,
    /// Scene pixel pitch on the object plane (mm). For an object at infinity the renderer sets it from
    /// `scene_fov_deg` to the pixel's angle in radians (the field unit of such a system).
    pub scene_pitch_mm: f64,
    /// An object at infinity: the scene's full angular extent across its width (degrees); pixels are
    /// sampled uniformly in field angle. `None` for a finite object (the scene lies on the object plane).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub scene_fov_deg: Option<f64>,
    pub detector_pitch_mm: f64,
    /// Extra detector margin (pixels) beyond the computed footprint.
    pub detector_extra_px: usize,
    pub spectral: SpectralSampling,
    pub rays_per_pixel: usize,
    pub sampling: Sampling,
    pub seed: u64,
    /// `None`: no diffraction blur.
    pub airy: Option<AiryConfig>,
    /// Go through the `Tracer` trait in batches even for the analytic backend (for checks).
    pub force_batched: bool,
    /// The f64 kernel of the direct (analytic-backend) path: SIMD lanes (default) or scalar (the
    /// reference, for benchmarks); both give the same numbers.
    pub kernel: crate::tracer::Kernel,
    /// Float precision of the direct path's kernel: f64 (exact, the default) or f32 (the SIMD lanes in
    /// f32, twice as many; its error is measured by `bench tradeoff`). f32 needs the SIMD kernel and the
    /// analytic backend's direct path.
    pub precision: crate::tracer::Precision,
}

impl RenderConfig {
    /// The ranges `render` accepts, checked by [`Renderer::new`] before anything is allocated: scene size ≥ 1,
    /// pitches finite, > 0 and ≤ [`crate::limits::MAX_LENGTH_MM`], planes in 1..=[`crate::limits::MAX_PLANES`],
    /// rays ≥ 1, the Airy settings ([`AiryConfig::validate`]). The error names the field and its value.
    pub fn validate(&self) -> Result<()> {
        let (h, w) = (self.scene_height, self.scene_width);
        if h == 0 || w == 0 {
            return Err(Error::invalid(format!("scene size {h}×{w}: must be ≥ 1")));
        }
        for (name, v) in [("scene_pitch_mm", self.scene_pitch_mm), ("detector_pitch_mm", self.detector_pitch_mm)] {
            if !(v.is_finite() && v > 0.0 && v <= crate::limits::MAX_LENGTH_MM) {
                return Err(Error::invalid(format!("{name} = {} mm: must be finite, > 0 and ≤ {:e} mm", crate::limits::fmt_num(v), crate::limits::MAX_LENGTH_MM)));
            }
        }
        let planes = self.spectral.planes();
        if planes == 0 || planes > crate::limits::MAX_PLANES {
            return Err(Error::invalid(format!("planes = {planes}: must be in 1..={}", crate::limits::MAX_PLANES)));
        }
        if self.rays_per_pixel == 0 {
            return Err(Error::invalid("rays per pixel must be ≥ 1"));
        }
        if let Some(a) = &self.airy {
            a.validate()?;
        }
        Ok(())
    }

    /// The paper's acquisition: `size × size` scene at 10 µm, 28 bands × 4, 20 rays, Airy 2.5 px at 520 nm.
    pub fn paper(size: usize) -> Self {
        RenderConfig {
            scene_height: size,
            scene_width: size,
            scene_pitch_mm: 0.01,
            scene_fov_deg: None,
            detector_pitch_mm: 0.01,
            detector_extra_px: 0,
            spectral: SpectralSampling::paper(),
            rays_per_pixel: 20,
            sampling: Sampling::Stratified,
            seed: 0,
            airy: Some(AiryConfig::default()),
            force_batched: false,
            kernel: crate::tracer::Kernel::default(),
            precision: crate::tracer::Precision::F64,
        }
    }
}

/// A system, tracer, mask and settings ready to render: detector sized, Airy kernels built.
pub struct Renderer<'a> {
    pub system: &'a SequentialSystem,
    pub tracer: &'a dyn Tracer,
    pub config: RenderConfig,
    /// The coded mask: on the object plane (one transmission per scene pixel, single-disperser CASSI) or, when
    /// the system holds a coded-mask surface ([`SequentialSystem::coded_mask`]), on that surface (dual-disperser).
    pub mask: Mask,
    /// The transmission per scene pixel on the object plane: the mask's values, or all 1 when the mask is a
    /// surface inside the system (`Some` only then).
    object_mask: Option<Vec<f32>>,
    pub detector: Detector,
    pub kernels: Vec<Option<AiryKernel>>,
    sampler: RaySampler,
    /// The resolved SIMD level of `config.kernel` (`None`: scalar).
    simd: Option<crate::tracer::SimdLevel>,
    /// The caller's stop request ([`Renderer::with_cancel`]), polled before each scene row of every plane
    /// traced and before each plane rendered; `None`: never stopped.
    cancel: Option<crate::cancel::Cancel>,
}

/// Wall-clock split of a render (s).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct Timings {
    /// Tracing rays and building footprints (summed over threads).
    pub trace_thread_seconds: f64,
    /// Applying footprints to the scene (summed over threads).
    pub splat_thread_seconds: f64,
    /// Airy convolutions (summed over threads).
    pub airy_thread_seconds: f64,
    /// Wall clock of the whole render.
    pub wall_seconds: f64,
}

/// A rendered acquisition.
#[derive(Clone, Debug)]
pub struct Acquisition {
    pub detector: Detector,
    /// Detector image, row-major, f64 sums of the band images in band order.
    pub image: Vec<f64>,
    /// Per-band detector images (the acquisition is their sum), when requested.
    pub bands: Option<Vec<Vec<f32>>>,
    pub stats: RayStats,
    pub timings: Timings,
}

impl Acquisition {
    pub fn total(&self) -> f64 {
        self.image.iter().sum()
    }
    /// Whether every pixel is zero as written (f32): a noisy acquisition whose read noise sums to ≤ 0 is not
    /// zero (its total is no test; round 16).
    pub fn is_zero(&self) -> bool {
        self.image.iter().all(|&v| v as f32 == 0.0)
    }
    pub fn image_f32(&self) -> Vec<f32> {
        self.image.iter().map(|&v| v as f32).collect()
    }
    /// SHA-256 of the f32 image as `acquisition.exr` holds it (little-endian values, row-major): render.json's
    /// `acquisition_f32le_sha256`, which `reconstruct` checks ([`acquisition_sha256`]).
    pub fn image_sha256(&self) -> String {
        acquisition_sha256(&self.image_f32())
    }
    /// Whether `other` has this acquisition's bits: every image value and every ray count.
    pub fn same_bits(&self, other: &Acquisition) -> bool {
        self.image.len() == other.image.len() && self.image.iter().zip(&other.image).all(|(a, b)| a.to_bits() == b.to_bits()) && self.stats == other.stats
    }
    /// max |self − reference| over the image, as a fraction of the reference's peak |value| (the absolute
    /// difference when the reference is black).
    pub fn max_diff_of_peak(&self, reference: &Acquisition) -> f64 {
        let peak = reference.image.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let diff = self.image.iter().zip(&reference.image).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        if peak > 0.0 { diff / peak } else { diff }
    }
}

/// SHA-256 of an f32 acquisition's little-endian values (see [`Acquisition::image_sha256`]).
pub fn acquisition_sha256(values: &[f32]) -> String {
    let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
    crate::io::sha256::sha256_hex(&bytes)
}

/// The tracer name a record states for `name` traced at `precision` (see [`Renderer::tracer_name`]).
pub fn tracer_of_record(name: String, precision: crate::tracer::Precision) -> String {
    match (name.as_str(), precision) {
        ("analytic-f64", crate::tracer::Precision::F32) => "analytic-f32".into(),
        _ => name,
    }
}

impl<'a> Renderer<'a> {
    /// The tracer a record names for this render: the backend's name, except that an f32 render through the
    /// analytic backend traced with its f32 twin (`analytic-f32`; `Precision::tracer`), whatever the f64
    /// tracer object it was given. render.json's `tracer` and reconstruct.json's exact operator use it.
    pub fn tracer_name(&self) -> String {
        tracer_of_record(self.tracer.name(), self.config.precision)
    }

    pub fn new(system: &'a SequentialSystem, tracer: &'a dyn Tracer, config: RenderConfig, mask: Mask) -> Result<Self> {
        let (h, w) = (config.scene_height, config.scene_width);
        if h == 0 || w == 0 {
            return Err(Error::invalid(format!("scene size {h}×{w}: must be ≥ 1")));
        }
        if (h * w) as u64 > u32::MAX as u64 {
            return Err(Error::invalid(format!("scene size {h}×{w} is too large")));
        }
        if mask.height != h || mask.width != w {
            return Err(Error::invalid(format!("the mask is {}×{} but the scene is {h}×{w}", mask.height, mask.width)));
        }
        if config.rays_per_pixel == 0 {
            return Err(Error::invalid("rays per pixel must be ≥ 1"));
        }
        let mut config = config;
        config.scene_pitch_mm = scene_pitch_for(system, &config)?;
        if !(config.scene_pitch_mm.is_finite() && config.scene_pitch_mm > 0.0) {
            return Err(Error::invalid(format!("scene pitch {} mm must be finite and > 0", config.scene_pitch_mm)));
        }
        // A plane outside a glass's range is an error now, not mid-render. The planes reach half a band beyond
        // the first and last band: the message says which plane, of which bands (the user typed only the bands).
        let sp = &config.spectral;
        for (k, &w) in sp.planes_nm.iter().enumerate() {
            system.indices(w).map_err(|e| {
                let (b0, b1) = (sp.bands_nm[0], sp.bands_nm[sp.bands_nm.len() - 1]);
                Error::invalid(format!(
                    "render plane {k} at {} nm (the {} planes span the bands {}–{} nm and half a band beyond them): {e}",
                    crate::limits::fmt_num((w * 1e6).round() / 1e6),
                    sp.planes(),
                    crate::limits::fmt_num(b0),
                    crate::limits::fmt_num(b1)
                ))
            })?;
        }
        config.validate()?;
        let kernels: Vec<Option<AiryKernel>> = config
            .spectral
            .planes_nm
            .iter()
            .map(|&l| config.airy.map(|a| AiryKernel::for_wavelength(l, a.diameter_px, a.reference_nm, a.rings)).transpose())
            .collect::<Result<_>>()?;
        let airy_r = kernels.iter().flatten().map(|k| k.truncation_radius_px).fold(0.0, f64::max);
        let detector = Detector::covering(system, tracer, h, w, config.scene_pitch_mm, &config.spectral.planes_nm, config.detector_pitch_mm, airy_r, config.detector_extra_px)?;
        if detector.width > u16::MAX as usize || detector.height > u16::MAX as usize {
            return Err(Error::invalid(format!("detector {}×{} exceeds 65535 pixels per side", detector.width, detector.height)));
        }
        // The detector's size is known only now (a system that spreads the scene widely needs a large one):
        // its buffers, with the scene-sized ones, within the memory budget before any is allocated.
        let bands = config.spectral.bands_nm.len();
        let threads = rayon::current_num_threads();
        // (Not the mapping cube's term: a front end traces it after the acquisition, once these buffers are
        // freed, and counts it in its own estimate, `RenderSettings::memory_bytes`.)
        let pixels = (h * w) as f64;
        let scene_side = crate::limits::bytes_render_scene(pixels, 0, bands, config.spectral.planes(), config.airy.map(|a| a.diameter_px)) - crate::limits::bytes_render_mapping(pixels, bands);
        crate::limits::check_memory(
            &format!("the {}×{} detector (the dispersed footprint of the {h}×{w} scene; {bands} bands, {threads} threads)", detector.width, detector.height),
            scene_side + crate::limits::bytes_detector(detector.pixels() as f64, bands, threads),
        )?;
        let sampler = RaySampler::new(config.rays_per_pixel, config.sampling);
        let simd = config.kernel.resolve()?;
        if config.precision == crate::tracer::Precision::F32 {
            config.precision.level(config.kernel)?;
            if config.force_batched || tracer.name() != "analytic-f64" {
                return Err(Error::invalid(format!("--precision f32 renders through the analytic backend's direct path (not {}{})", tracer.name(), if config.force_batched { ", batched" } else { "" })));
            }
        }
        let object_mask = system.coded_mask.map(|_| vec![1.0f32; h * w]);
        if let Some(m) = system.coded_mask {
            if config.force_batched || tracer.name() != "analytic-f64" {
                return Err(Error::invalid(format!(
                    "system `{}` holds its coded mask on surface {} (dual-disperser CASSI): it renders through the analytic backend's direct path only (not {}{})",
                    system.name(),
                    m.surface,
                    tracer.name(),
                    if config.force_batched { ", batched" } else { "" }
                )));
            }
            if config.precision == crate::tracer::Precision::F32 {
                return Err(Error::invalid(format!("system `{}` holds its coded mask on surface {}: --precision f32 does not model a mask surface yet; render in f64", system.name(), m.surface)));
            }
            check_mask_in_beam(system, m, config.scene_pitch_mm, h, w)?;
        }
        Ok(Renderer { system, tracer, config, mask, object_mask, detector, kernels, sampler, simd, cancel: None })
    }

    /// This renderer stopped by `cancel`: once it is cancelled, tracing (a render, [`Renderer::trace_all`], an
    /// operator built from this renderer) returns [`Error::Interrupted`] at the next scene row or plane. Polling
    /// changes no number: an uncancelled render is bit-identical to one without a token ([`crate::cancel`]).
    pub fn with_cancel(mut self, cancel: crate::cancel::Cancel) -> Self {
        self.cancel = Some(cancel);
        self
    }

    /// The stop request of [`Renderer::with_cancel`], if any.
    pub fn cancel(&self) -> Option<&crate::cancel::Cancel> {
        self.cancel.as_ref()
    }

    /// Remove the stop request (a renderer kept beyond the call it was given for: the exact operator's).
    pub fn take_cancel(&mut self) -> Option<crate::cancel::Cancel> {
        self.cancel.take()
    }

    /// The transmission per scene pixel on the object plane: the mask for single-disperser CASSI; all 1 when
    /// the mask is a surface of the system (its transmission then weights each ray where it crosses that surface).
    pub fn object_mask(&self) -> &[f32] {
        self.object_mask.as_deref().unwrap_or(&self.mask.values)
    }

    /// The coded mask on a surface of the system, as the plane tracer reads it (`None` for single-disperser CASSI).
    pub fn surface_mask(&self) -> Option<SurfaceMask<'_>> {
        self.system.coded_mask.map(|surface| SurfaceMask { surface, values: &self.mask.values, height: self.mask.height, width: self.mask.width })
    }

    /// Everything fixed while tracing a plane of this render (for other plane tracers, e.g. the GPU
    /// kernels' twin [`super::twin::trace_plane`]).
    pub fn plane_context(&self) -> PlaneContext<'_> {
        self.context()
    }

    fn context(&self) -> PlaneContext<'_> {
        PlaneContext {
            system: self.system,
            tracer: self.tracer,
            direct_kernel: !self.config.force_batched && self.tracer.name() == "analytic-f64",
            simd: self.simd,
            precision: self.config.precision,
            detector: &self.detector,
            scene_height: self.config.scene_height,
            scene_width: self.config.scene_width,
            scene_pitch_mm: self.config.scene_pitch_mm,
            mask: self.object_mask(),
            surface_mask: self.surface_mask(),
            sampler: &self.sampler,
            seed: self.config.seed,
            cancel: self.cancel.as_ref(),
        }
    }

    /// Rays traced per render (open pixels × rays × planes).
    pub fn rays_per_render(&self) -> u64 {
        let open = self.object_mask().iter().filter(|&&v| v > 0.0).count() as u64;
        open * self.config.rays_per_pixel as u64 * self.config.spectral.planes() as u64
    }

    /// Trace one plane's light transport.
    pub fn trace_plane(&self, plane: usize) -> Result<PlaneTransport> {
        let mut t = self.context().trace_plane(plane, self.config.spectral.planes_nm[plane])?;
        // A diffraction grating passes the fraction `grating_efficiency` of the power into its traced order
        // (a scalar per order, default 1): every footprint's weight, hence the acquisition and the exact
        // operator alike. Systems without gratings (efficiency 1) are untouched, bit for bit.
        let e = self.system.grating_efficiency();
        if e != 1.0 {
            t.weights.iter_mut().for_each(|w| *w = (*w as f64 * e) as f32);
        }
        Ok(t)
    }

    /// Trace every plane (in parallel; the result does not depend on the thread count). `progress` is
    /// called with each finished plane's ray count.
    pub fn trace_all(&self, progress: &(dyn Fn(u64) + Sync)) -> Result<Vec<PlaneTransport>> {
        (0..self.config.spectral.planes())
            .into_par_iter()
            .map(|p| {
                let t = self.trace_plane(p)?;
                progress(t.stats.traced);
                Ok(t)
            })
            .collect()
    }

    /// Check the scene fits the render (size; values are finite by construction).
    pub(crate) fn check_scene(&self, scene: &SpectralCube) -> Result<()> {
        if scene.height != self.config.scene_height || scene.width != self.config.scene_width {
            return Err(Error::invalid(format!(
                "the scene is {}×{} but the render expects {}×{} (fit it first)",
                scene.height, scene.width, self.config.scene_height, self.config.scene_width
            )));
        }
        // The scene's spectrum is interpolated at each plane and held constant beyond its range (render.json's
        // `spectral_interpolation`); a scene whose bands all lie outside the render's planes (a 1000–1300 nm cube
        // rendered at 450–650 nm) would be rendered as its end band's constant: refused, naming both ranges. A
        // one-band scene is a flat spectrum where its band lies among the planes, and refused where it does not
        // (a band at 5000 nm was rendered at 450–650 nm as if it were there: a held-out battery).
        let (ws, planes) = (&scene.wavelengths_nm, &self.config.spectral.planes_nm);
        if let (Some(&lo), Some(&hi), Some(&p0), Some(&p1)) = (ws.first(), ws.last(), planes.first(), planes.last()) {
            if p1 < lo || p0 > hi {
                let fmt = crate::limits::fmt_num;
                let scene_bands = if ws.len() == 1 { format!("band ({} nm) lies", fmt(lo)) } else { format!("bands ({} – {} nm) lie", fmt(lo), fmt(hi)) };
                return Err(Error::invalid(format!(
                    "the scene's {scene_bands} outside the render's planes ({:.2} – {:.2} nm): nothing of its spectrum would be rendered; choose --bands within the scene's range",
                    p0,
                    p1
                )));
            }
        }
        Ok(())
    }

    /// For a system whose coded mask is a surface (dual-disperser CASSI): the planes at which the scene's image
    /// on that surface falls wholly beyond the mask (the chief rays of its centre and corners land outside the
    /// mask's extent, on one side): they pass no light, while [`Renderer::new`] checked only the primary
    /// wavelength. A small scene whose dispersion at the mask exceeds the mask's width (ddsp at 16²: 450 and
    /// 650 nm dark, unannounced; a held-out battery, round 11). `None` when every plane sees the mask.
    pub fn mask_dark_planes(&self) -> Result<Option<MaskDarkPlanes>> {
        let Some(m) = self.system.coded_mask else { return Ok(None) };
        let (h, w, pitch) = (self.config.scene_height, self.config.scene_width, self.config.scene_pitch_mm);
        let (hx, hy) = (0.5 * w as f64 * pitch, 0.5 * h as f64 * pitch);
        let (mx, my) = (0.5 * w as f64 * m.pitch_mm, 0.5 * h as f64 * m.pitch_mm);
        let arm1 = &self.system.path[..=m.step];
        let mut dark = Vec::new();
        let mut runs: Vec<[f64; 2]> = Vec::new();
        let mut last_dark: Option<usize> = None;
        for (k, &wl) in self.config.spectral.planes_nm.iter().enumerate() {
            let n = self.system.indices(wl)?;
            let (mut x0, mut x1, mut y0, mut y1) = (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
            for field in [[0.0, 0.0], [-hx, -hy], [hx, -hy], [-hx, hy], [hx, hy]] {
                let (o, d) = crate::rays::object_ray(self.system, field, 0.0, 0.0);
                if let Ok((p, _)) = crate::tracer::kernel::trace_steps(arm1, &n, o, d / d.length()) {
                    (x0, x1, y0, y1) = (x0.min(p.x), x1.max(p.x), y0.min(p.y), y1.max(p.y));
                }
            }
            // No chief ray crossing, or the footprint's box wholly beside the mask's.
            if !(x0 <= mx && x1 >= -mx && y0 <= my && y1 >= -my) {
                dark.push(wl);
                match runs.last_mut() {
                    Some(r) if last_dark == Some(k.wrapping_sub(1)) => r[1] = wl,
                    _ => runs.push([wl, wl]),
                }
                last_dark = Some(k);
            }
        }
        Ok((!dark.is_empty()).then(|| MaskDarkPlanes { surface: m.surface, planes_nm: dark, runs_nm: runs, of_planes: self.config.spectral.planes(), mask: [h, w], mask_pitch_um: m.pitch_mm * 1e3 }))
    }

    /// For an f32 render (`--precision f32`): f32's rounding on this system, measured — the largest distance
    /// (µm) between the f32 lane kernel's and the f64 tracer's chief-ray landings of the scene's centre, corners
    /// and edge midpoints at the first, middle and last planes. It grows with the coordinates the rays carry
    /// (long tracks, wide fields): ≤ 0.03 µm on the presets, 1 µm on SP with a 950 mm track (a held-out
    /// battery, round 12). `None` for an f64 render.
    pub fn f32_chief_ray_error(&self) -> Result<Option<F32Error>> {
        if self.config.precision != crate::tracer::Precision::F32 {
            return Ok(None);
        }
        let level = self.config.precision.level(self.config.kernel)?;
        measure_f32_error(self.system, self.config.scene_height, self.config.scene_width, self.config.scene_pitch_mm, &self.config.spectral.planes_nm, level).map(Some)
    }

    /// Where the render's planes reach beyond the scene's bands by more than one render band, or by more than
    /// the scene's own span (the scene's spectrum is held constant there, at its end band; a one-band scene:
    /// every plane off its band): `None` for a scene that spans the render's bands
    /// (whose outer planes lie half a band beyond its first and last band, by construction). `render`,
    /// `render-dataset` and the bindings warn with [`SpectralExtrapolation::message`] and record it in render.json.
    pub fn spectral_extrapolation(&self, scene: &SpectralCube) -> Option<SpectralExtrapolation> {
        let (ws, bands, planes) = (&scene.wavelengths_nm, &self.config.spectral.bands_nm, &self.config.spectral.planes_nm);
        let (&lo, &hi) = (ws.first()?, ws.last()?);
        // One render band (the planes' spacing with one band), and no more than the scene's own span: a plane
        // 1800 nm past a 400–700 nm scene was not reported when the render's bands were 2120 nm apart, and a
        // one-band scene (a constant spectrum everywhere) never was (a held-out battery, round 7).
        let spacing = |v: &[f64]| if v.len() >= 2 { (v[v.len() - 1] - v[0]) / (v.len() - 1) as f64 } else { f64::INFINITY };
        let render_step = if bands.len() >= 2 { spacing(bands) } else { spacing(planes) };
        let step = render_step.min(hi - lo);
        let beyond = |w: f64| (lo - w).max(w - hi).max(0.0);
        let far: Vec<f64> = planes.iter().map(|&w| beyond(w)).filter(|&d| d > step).collect();
        let beyond_nm = far.iter().cloned().fold(0.0, f64::max);
        (!far.is_empty()).then(|| SpectralExtrapolation { planes: far.len(), of_planes: planes.len(), beyond_nm, scene_nm: [lo, hi] })
    }

    /// Render `scene`, tracing every plane (per-scene mode). `keep_bands` keeps the per-band images.
    pub fn render(&self, scene: &SpectralCube, keep_bands: bool, progress: &(dyn Fn(u64) + Sync)) -> Result<Acquisition> {
        self.render_with(scene, None, keep_bands, progress)
    }

    /// Render `scene` with a light transport traced beforehand ([`Renderer::trace_all`]); bit-identical to
    /// [`Renderer::render`].
    pub fn render_cached(&self, scene: &SpectralCube, transport: &[PlaneTransport], keep_bands: bool, progress: &(dyn Fn(u64) + Sync)) -> Result<Acquisition> {
        if transport.len() != self.config.spectral.planes() {
            return Err(Error::invalid(format!("cached transport has {} planes, the render {}", transport.len(), self.config.spectral.planes())));
        }
        self.render_with(scene, Some(transport), keep_bands, progress)
    }

    fn render_with(&self, scene: &SpectralCube, cached: Option<&[PlaneTransport]>, keep_bands: bool, progress: &(dyn Fn(u64) + Sync)) -> Result<Acquisition> {
        self.check_scene(scene)?;
        let t0 = Instant::now();
        let sp = &self.config.spectral;
        let nb = sp.bands_nm.len();
        let det = self.detector;
        let npix = det.pixels();
        let band_planes: Vec<Vec<usize>> = (0..nb).map(|b| (0..sp.planes()).filter(|&p| sp.plane_band[p] == b).collect()).collect();
        // The scene band-major (a copy), so that each plane reads two contiguous bands.
        let (npx, sb) = (scene.height * scene.width, scene.bands());
        let mut band_major = vec![0.0f32; npx * sb];
        band_major.par_chunks_mut(npx).enumerate().for_each(|(b, plane)| plane.iter_mut().enumerate().for_each(|(q, v)| *v = scene.data[q * sb + b]));
        let lay = PaddedLayout::new(det.width, det.height, self.kernels.iter().flatten().map(|k| k.half).max().unwrap_or(0));
        let results: Vec<Result<(Vec<f32>, RayStats, [f64; 3])>> = band_planes
            .par_iter()
            .map_init(
                // Per-worker buffers, reused from band to band (`img` is cleared after each plane).
                || (vec![0.0f64; npix], vec![0.0f32; npx], vec![0.0f32; lay.len()]),
                |(band, values, img), planes| {
                    band.iter_mut().for_each(|v| *v = 0.0);
                    let mut stats = RayStats::default();
                    let mut secs = [0.0f64; 3];
                    for &p in planes {
                        crate::cancel::check(self.cancel.as_ref())?;
                        let t = Instant::now();
                        let owned;
                        let tr = match cached {
                            Some(c) => &c[p],
                            None => {
                                owned = self.trace_plane(p)?;
                                &owned
                            }
                        };
                        secs[0] += t.elapsed().as_secs_f64();
                        stats.add(&tr.stats);
                        let t = Instant::now();
                        // The plane of the scene ([`SpectralCube::plane`]'s arithmetic), masked.
                        let (k, tw) = scene.interpolation(sp.planes_nm[p]);
                        let (xa, xb) = (&band_major[k * npx..(k + 1) * npx], &band_major[(k + 1).min(sb - 1) * npx..((k + 1).min(sb - 1) + 1) * npx]);
                        let tw = tw as f32;
                        for (((v, a), b), m) in values.iter_mut().zip(xa).zip(xb).zip(self.object_mask()) {
                            *v = ((1.0 - tw) * *a + tw * *b) * *m;
                        }
                        tr.apply_padded(values, img, &lay);
                        let sup = tr.support();
                        secs[1] += t.elapsed().as_secs_f64();
                        let t = Instant::now();
                        // Airy blur over the support, each output tile added to the band at once (the sums
                        // of `AiryKernel::convolve`, bit for bit; outside the support the blurred plane is 0).
                        let w = sp.plane_weight;
                        match &self.kernels[p] {
                            Some(k) => {
                                convolve(k, img, &lay, sup, &mut |y, x, valid, tile: &[f32; TILE]| {
                                    for (a, b) in band[y * det.width + x..y * det.width + x + valid].iter_mut().zip(tile) {
                                        *a += w * *b as f64;
                                    }
                                });
                            }
                            None => {
                                for y in sup.y0..sup.y1 {
                                    for (a, b) in band[y * det.width + sup.x0..y * det.width + sup.x1].iter_mut().zip(&img[lay.index(sup.x0, y)..lay.index(sup.x1, y)]) {
                                        *a += w * *b as f64;
                                    }
                                }
                            }
                        }
                        lay.clear(img, sup);
                        secs[2] += t.elapsed().as_secs_f64();
                        progress(tr.stats.traced);
                    }
                    Ok((band.iter().map(|&v| v as f32).collect(), stats, secs))
                },
            )
            .collect();
        let mut image = vec![0.0f64; npix];
        let mut stats = RayStats::default();
        let mut timings = Timings::default();
        let mut bands = Vec::new();
        for r in results {
            let (band, s, secs) = r?;
            for (a, b) in image.iter_mut().zip(&band) {
                *a += *b as f64;
            }
            stats.add(&s);
            timings.trace_thread_seconds += secs[0];
            timings.splat_thread_seconds += secs[1];
            timings.airy_thread_seconds += secs[2];
            if keep_bands {
                bands.push(band);
            }
        }
        timings.wall_seconds = t0.elapsed().as_secs_f64();
        Ok(Acquisition { detector: det, image, bands: keep_bands.then_some(bands), stats, timings })
    }
}

/// A coded-mask surface must see the beam: the chief rays of the scene's corners and centre at the primary
/// wavelength must cross it, and the scene's image there must overlap the mask's pixels. Otherwise every ray
/// would be blocked (a black acquisition), which is an error naming the surface, not a result. The scene is
/// h×w pixels of pitch `pitch_mm` (the system's field unit: mm, or radians at infinity); the mask has the
/// scene's h×w pixels (both renderers require it), of pitch `m.pitch_mm` on the surface. Called by
/// [`Renderer::new`] and by [`super::gradient::DiffRenderer`] (at construction and at each new set of
/// parameter values).
pub(crate) fn check_mask_in_beam(system: &SequentialSystem, m: crate::system::MaskSurface, pitch_mm: f64, h: usize, w: usize) -> Result<()> {
    let n = system.indices(system.primary_wavelength_nm())?;
    let arm1 = &system.path[..=m.step];
    let (hx, hy) = (0.5 * w as f64 * pitch_mm, 0.5 * h as f64 * pitch_mm);
    let (mx, my) = (0.5 * w as f64 * m.pitch_mm, 0.5 * h as f64 * m.pitch_mm);
    let mut inside = false;
    let mut crossed = 0;
    for field in [[0.0, 0.0], [-hx, -hy], [hx, -hy], [-hx, hy], [hx, hy]] {
        // (The scene pitch is in the system's field unit: mm, or radians for an object at infinity.)
        let (o, d) = crate::rays::object_ray(system, field, 0.0, 0.0);
        let len = d.length();
        if let Ok((p, _)) = crate::tracer::kernel::trace_steps(arm1, &n, o, d / len) {
            crossed += 1;
            inside |= p.x.abs() <= mx && p.y.abs() <= my;
        }
    }
    if crossed == 0 {
        return Err(Error::invalid(format!(
            "system `{}`: no chief ray of the scene reaches the coded-mask surface {} at {} nm (the mask is outside the beam)",
            system.name(),
            m.surface,
            system.primary_wavelength_nm()
        )));
    }
    if !inside {
        return Err(Error::invalid(format!(
            "system `{}`: the scene's image on the coded-mask surface {} misses the {}×{} mask of pitch {} µm (the mask is outside the beam: check its position, tilt and pitch)",
            system.name(),
            m.surface,
            h,
            w,
            crate::limits::fmt_num(m.pitch_mm * 1e3)
        )));
    }
    Ok(())
}

/// Planes a coded-mask surface passes no light at ([`Renderer::mask_dark_planes`]).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct MaskDarkPlanes {
    /// The mask's surface.
    pub surface: usize,
    /// The dark planes' wavelengths, nm, and their runs of consecutive planes (first, last), nm.
    pub planes_nm: Vec<f64>,
    pub runs_nm: Vec<[f64; 2]>,
    pub of_planes: usize,
    /// The mask's pixels (height, width) and pitch, µm.
    pub mask: [usize; 2],
    pub mask_pitch_um: f64,
}

impl MaskDarkPlanes {
    /// render.json's `mask_dark_planes`: the fields and the message.
    pub fn to_json(&self) -> serde_json::Value {
        let mut v = serde_json::json!(self);
        v["message"] = self.message().into();
        v
    }

    pub fn message(&self) -> String {
        let runs: Vec<String> = self.runs_nm.iter().map(|r| if r[0] == r[1] { format!("{:.1}", r[0]) } else { format!("{:.1}–{:.1}", r[0], r[1]) }).collect();
        format!(
            "at {} of {} render planes ({} nm) the scene's image on the coded-mask surface {} falls beyond the {}×{} mask of pitch {} µm: those planes pass no light (the dispersion at the mask exceeds the mask's extent); render a wider scene or narrower --bands",
            self.planes_nm.len(),
            self.of_planes,
            runs.join(", "),
            self.surface,
            self.mask[0],
            self.mask[1],
            crate::limits::fmt_num(self.mask_pitch_um)
        )
    }
}

/// f32's rounding on `system` for an `height`×`width` scene of pitch `pitch` (the system's field unit: mm, or
/// radians at infinity): the largest distance (µm) between the f32 lane kernel's (`level`) and the f64
/// tracer's chief-ray landings of the scene's centre, corners and edge midpoints at the first, middle and last
/// of `wavelengths_nm` ([`Renderer::f32_chief_ray_error`]; `mapping --precision f32`).
pub fn measure_f32_error(system: &SequentialSystem, height: usize, width: usize, pitch: f64, wavelengths_nm: &[f64], level: crate::tracer::SimdLevel) -> Result<F32Error> {
    let (h2, w2) = (height.saturating_sub(1), width.saturating_sub(1));
    let probes: Vec<[f64; 2]> = [(0, 0), (0, w2), (h2, 0), (h2, w2), (0, w2 / 2), (h2, w2 / 2), (h2 / 2, 0), (h2 / 2, w2), (h2 / 2, w2 / 2)]
        .iter()
        .map(|&(r, c)| crate::analysis::MappingCube::scene_xy(height, width, pitch, r, c))
        .collect();
    let f64_tracer = crate::tracer::AnalyticTracer::default();
    let f32_tracer = crate::tracer::AnalyticF32Tracer::new(level);
    let mut worst = F32Error { error_um: 0.0, threshold_um: F32_DOCUMENTED_ERROR_UM, rays: 0 };
    if wavelengths_nm.is_empty() {
        return Ok(worst);
    }
    for &k in &[0, wavelengths_nm.len() / 2, wavelengths_nm.len() - 1] {
        let batch = crate::rays::RayBatch::chief_rays(system, &probes, wavelengths_nm[k])?;
        let (a, b) = (f64_tracer.trace(system, &batch)?, f32_tracer.trace(system, &batch)?);
        for i in 0..a.len() {
            if a.status[i] == crate::tracer::RayStatus::Ok && b.status[i] == crate::tracer::RayStatus::Ok {
                worst.error_um = worst.error_um.max((a.x[i] - b.x[i]).hypot(a.y[i] - b.y[i]) * 1e3);
                worst.rays += 1;
            }
        }
    }
    Ok(worst)
}

/// The f32 chief-ray error the documentation quotes for the presets' far field (docs/performance.md, "f32
/// mode"): above it an f32 render warns ([`F32Error::message`]).
pub const F32_DOCUMENTED_ERROR_UM: f64 = 0.1;

/// f32's rounding on a system ([`Renderer::f32_chief_ray_error`]).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct F32Error {
    /// Largest f32 − f64 chief-ray landing distance, µm.
    pub error_um: f64,
    /// [`F32_DOCUMENTED_ERROR_UM`].
    pub threshold_um: f64,
    /// Chief rays compared (those arriving in both precisions).
    pub rays: usize,
}

impl F32Error {
    /// render.json's `f32_chief_ray_error`: the fields, and the warning when over the threshold.
    pub fn to_json(&self) -> serde_json::Value {
        let mut v = serde_json::json!(self);
        if let Some(m) = self.message() {
            v["message"] = m.into();
        }
        v
    }

    /// The warning of an f32 render whose chief rays move more than the documented figure; `None` within it.
    pub fn message(&self) -> Option<String> {
        (self.error_um > self.threshold_um).then(|| {
            format!(
                "--precision f32 moves this system's chief rays by up to {:.3} µm on the detector (the presets: ≤ {} µm; f32's rounding grows with the coordinates, e.g. long tracks and wide fields): render in f64 where that matters",
                self.error_um, self.threshold_um
            )
        })
    }
}

/// Render planes beyond a scene's bands ([`Renderer::spectral_extrapolation`]).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct SpectralExtrapolation {
    /// Planes farther than one render band beyond the scene's first or last band, of all planes.
    pub planes: usize,
    pub of_planes: usize,
    /// The farthest such plane's distance beyond the scene's range, nm.
    pub beyond_nm: f64,
    /// The scene's first and last band, nm.
    pub scene_nm: [f64; 2],
}

impl SpectralExtrapolation {
    /// render.json's `spectral_extrapolation`: the fields and the message.
    pub fn to_json(&self) -> serde_json::Value {
        let mut v = serde_json::json!(self);
        v["message"] = self.message().into();
        v
    }

    pub fn message(&self) -> String {
        format!(
            "{} of {} render planes lie beyond the scene's bands ({:.1}–{:.1} nm), by up to {:.1} nm: the scene's spectrum is held constant there (its end band); choose --bands within its range",
            self.planes, self.of_planes, self.scene_nm[0], self.scene_nm[1], self.beyond_nm
        )
    }
}

/// Check `--scene-fov-deg` (the full angle across the scene's width, degrees): finite and in (0, 180).
pub fn check_scene_fov_deg(fov: f64) -> Result<()> {
    if !(fov.is_finite() && fov > 0.0 && fov < 180.0) {
        return Err(Error::invalid(format!("--scene-fov-deg {}: the scene's angular extent must be finite and in (0, 180) degrees", crate::limits::fmt_num(fov))));
    }
    Ok(())
}

/// The scene pitch in the system's field unit: the config's (mm) for a finite object; for an object at
/// infinity the angle of one pixel, `scene_fov_deg` (across the width) / width, in radians — the scene is
/// sampled uniformly in field angle. Errors: a system at infinity without `scene_fov_deg` (naming the
/// flag), `scene_fov_deg` on a finite system, an angle out of (0, 180).
pub fn scene_pitch_for(system: &SequentialSystem, config: &RenderConfig) -> Result<f64> {
    match (system.object_at_infinity(), config.scene_fov_deg) {
        (false, None) => Ok(config.scene_pitch_mm),
        (false, Some(f)) => Err(Error::invalid(format!(
            "--scene-fov-deg {}: system `{}` has a finite object, where the scene lies on the object plane at {} mm per pixel; --scene-fov-deg is for objects at infinity",
            crate::limits::fmt_num(f),
            system.name(),
            config.scene_pitch_mm
        ))),
        (true, None) => Err(Error::invalid(format!(
            "system `{}` has its object at infinity: give the scene's angular extent, --scene-fov-deg D (the full angle across its width, degrees)",
            system.name()
        ))),
        (true, Some(f)) => {
            check_scene_fov_deg(f)?;
            Ok(f.to_radians() / config.scene_width as f64)
        }
    }
}
