//! The acquisition and its vector–Jacobian product: for an upstream gradient g = ∂L/∂(acquisition), the
//! gradients ∂L/∂θ (every free optical parameter, [`crate::diff::Param`] names), ∂L/∂mask (per mask pixel)
//! and ∂L/∂scene — the differentiable renderer of end-to-end co-design (`docs/codesign.md`).
//!
//! Image formation is [`super::engine`]'s, in f64 throughout: per plane, every scene pixel's N rays
//! (the same [`RaySampler`] numbers for a seed: **fixed Monte-Carlo samples**) are traced, each arrived ray
//! splats value·mask/N bilinearly at its landing point, the plane is blurred by its Airy kernel, weighted
//! B/K and summed. With the samples fixed the acquisition is a smooth function of θ wherever no ray changes
//! status, and its gradient is exact:
//! - **scene and mask**: the acquisition is linear in both; their gradients are the adjoint (transposed)
//!   splat and blur applied to g;
//! - **θ**: a ray's landing (x, y) moves with θ through the implicit-differentiation Jacobians of
//!   [`crate::diff`]; the splat taps are differentiated in (u, v) exactly (bilinear), the blur is linear
//!   (its adjoint is applied to g first), so per ray ∂L/∂(x, y) is a contraction of the blurred g with the
//!   taps' derivatives, then pulled back through the trace by **reverse accumulation**
//!   ([`crate::diff::adjoint`]): a cost per ray independent of the number of parameters.
//!
//! Held fixed, as the sampling is: the **detector** (sized for the system at construction) and the
//! **entrance-pupil aim** of the object-space rays (the cone of rays leaving each scene point; parameters
//! that move the paraxial pupil change which of those rays the stop lets through, by vignetting). Rays that
//! change status under a change of θ (vignetted, leaving the detector) contribute **no boundary term**: the
//! gradient is that of the expected image away from those edges; the bias is measured in
//! `docs/derivatives.md`.
//!
//! Cost: rays of closed mask pixels (value exactly 0) carry no light, so their mask gradient needs only
//! where they land — they are traced with the production renderer's SIMD lanes, with no θ-adjoint, as
//! are all rays of [`DiffRenderer::render`]; rays of open pixels (any non-zero value of a continuous mask)
//! are traced keeping their per-step states and swept backwards once, a block of [`LANES`] rays at a
//! time on the same SIMD lanes ([`crate::tracer::simd::record`], [`crate::diff::adjoint_lanes`]); with
//! `config.kernel = Kernel::Scalar` every ray goes through the scalar kernel and the scalar sweep
//! ([`crate::diff::adjoint`], the reference) instead. [`DiffRenderer::vjp_wanted`] computes only the
//! gradients a [`Wanted`] names (torch's `needs_input_grad`): without ∂L/∂θ no ray is swept backwards,
//! without ∂L/∂mask the closed pixels' rays are not traced; the gradients it does compute are bit for bit
//! those of [`DiffRenderer::vjp`]. The blur's adjoint is tiled in f64 ([`super::convolve::kernel_pass_f64`]).
//!
//! Deterministic: planes are processed in parallel, each in a fixed order (within a plane each lane of
//! the reverse sweep sums its rays in order, and the lanes are summed in lane order at the plane's end),
//! and reduced in plane order (bit-identical for any thread count and any SIMD level).
//!
//! ```
//! use diffcassi::diff::ParamSet;
//! use diffcassi::render::gradient::DiffRenderer;
//! use diffcassi::render::{RenderConfig, SpectralSampling};
//! let sys = diffcassi::system::SequentialSystem::build(&diffcassi::presets::spec("sp")?)?;
//! let set = ParamSet::for_system(&sys, "prism_tilt_x")?;
//! let mut cfg = RenderConfig::paper(4);
//! cfg.spectral = SpectralSampling::new(vec![500.0, 600.0], 1)?;
//! cfg.rays_per_pixel = 2;
//! let r = DiffRenderer::new(set, cfg, vec![500.0, 600.0])?;
//! let scene = vec![1.0; 2 * 4 * 4]; // (N = 1, B = 2, H, W)
//! let mask = vec![1.0; 16];
//! let img = r.render(&scene, 1, &mask)?;
//! let g = vec![1.0; img.len()]; // L = Σ image
//! let v = r.vjp(&scene, 1, &mask, &g)?;
//! assert_eq!((v.params.len(), v.mask.len(), v.scene.len()), (1, 16, 32));
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::airy::AiryKernel;
use super::detector::Detector;
use super::engine::RenderConfig;
use super::sampling::{RaySampler, SampleRow};
use crate::analysis::MappingCube;
use crate::diff::adjoint::{not_a_system_parameter, AdjointPlan, AdjointSums, RayTape};
use crate::diff::adjoint_lanes::LaneSums;
use crate::tracer::simd::lanes::{Lf, Mask};
use crate::tracer::simd::{trace_block_recording, Block, LaneTape, LANES};
use crate::diff::{DiffSystem, ParamSet};
use crate::error::{Error, Result};
use crate::rays::PupilAim;
use crate::spec::RayAiming;
use crate::tracer::kernel::trace_steps;
use glam::DVec3;
use rayon::prelude::*;

/// An Airy kernel in f64 (`(2·half + 1)²` taps, row-major).
#[derive(Clone, Debug)]
struct Kernel64 {
    half: usize,
    w: Vec<f64>,
}

/// The differentiable renderer: a system with named free parameters, render settings, and the fixed
/// detector, pupil aim and blur kernels.
#[derive(Clone, Debug)]
pub struct DiffRenderer {
    pub set: ParamSet,
    pub ds: DiffSystem,
    pub config: RenderConfig,
    pub detector: Detector,
    /// Wavelengths of the scene's bands (nm), increasing; the scene is interpolated linearly between them.
    pub scene_wavelengths_nm: Vec<f64>,
    aim: PupilAim,
    kernels: Vec<Option<Kernel64>>,
    sampler: RaySampler,
    plan: AdjointPlan,
    /// The production kernel's SIMD level (`config.kernel`; `None`: scalar) for the rays that need no adjoint.
    simd: Option<crate::tracer::SimdLevel>,
    /// (n_d, V_d) ranges of the catalogue's glasses (obsolete ones left out): where a free glass may go.
    glass_ranges: [(f64, f64); 2],
}

/// The gradients of a scalar loss given its gradient g with respect to the acquisition.
#[derive(Clone, Debug, PartialEq)]
pub struct Vjp {
    /// ∂L/∂θ, one per free parameter (per spec unit: mm, degrees, …); empty when not [`Wanted`].
    pub params: Vec<f64>,
    /// ∂L/∂mask, (H, W) row-major; empty when not wanted.
    pub mask: Vec<f64>,
    /// ∂L/∂scene, (N, B, H, W); empty when not wanted.
    pub scene: Vec<f64>,
}

/// One scene row's rays (reused buffers): pixel, origin (object plane, mm), unit direction.
#[derive(Default)]
struct RowRays {
    pixel: Vec<usize>,
    origin: Vec<DVec3>,
    dir: Vec<DVec3>,
}

impl RowRays {
    fn clear(&mut self) {
        self.pixel.clear();
        self.origin.clear();
        self.dir.clear();
    }
}

/// One plane's inputs to the backward pass of its rays.
struct PlaneInputs<'a> {
    scene: &'a [f64],
    mask: &'a [f64],
    /// The upstream gradient through the blur's adjoint, (N, h, w).
    gb: &'a [f64],
    n: usize,
    /// Scene bands and upper weight of the plane's wavelength.
    k0: usize,
    k1: usize,
    tw: f64,
    /// Rays per pixel; detector pixels; scene pixels; scene bands.
    nr: f64,
    npix: usize,
    hw: usize,
    nb: usize,
    wanted: Wanted,
}

/// The bilinear taps of one landing ([`DiffRenderer::taps4`]).
struct Taps {
    index: [usize; 4],
    wt: [f64; 4],
    du: [f64; 4],
    dv: [f64; 4],
    count: usize,
}

/// The values of the scene pixel whose rays are being processed (a pixel's rays come one after another):
/// per image s, val[s] = the plane's (unmasked) scene value and vm[s] = val[s]·m, m the mask value.
struct PixelVals {
    q: usize,
    m: f64,
    val: Vec<f64>,
    vm: Vec<f64>,
}

impl PixelVals {
    fn new(n: usize) -> Self {
        PixelVals { q: usize::MAX, m: 0.0, val: vec![0.0; n], vm: vec![0.0; n] }
    }

    /// Make these pixel `q`'s values ([`crate::scene::SpectralCube::interpolation`]'s arithmetic).
    #[inline]
    fn at(&mut self, pin: &PlaneInputs, q: usize) {
        if self.q == q {
            return;
        }
        self.q = q;
        self.m = pin.mask[q];
        for s in 0..pin.n {
            let val = (1.0 - pin.tw) * pin.scene[(s * pin.nb + pin.k0) * pin.hw + q] + pin.tw * pin.scene[(s * pin.nb + pin.k1) * pin.hw + q];
            self.val[s] = val;
            self.vm[s] = val * self.m;
        }
    }
}

/// Which gradients [`DiffRenderer::vjp_wanted`] computes (as torch's `needs_input_grad`): the optical
/// parameters' ∂L/∂θ, the mask's ∂L/∂mask, the scene's ∂L/∂scene. [`Wanted::ALL`] is the default.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Wanted {
    pub params: bool,
    pub mask: bool,
    pub scene: bool,
}

impl Wanted {
    /// Every gradient.
    pub const ALL: Wanted = Wanted { params: true, mask: true, scene: true };
}

impl Default for Wanted {
    fn default() -> Self {
        Wanted::ALL
    }
}

/// What one plane's backward pass returns.
struct PlaneGrad {
    params: Vec<f64>,
    mask: Vec<f64>,
    /// (N, H·W): gradient of the plane's (unmasked) scene values.
    plane: Vec<f64>,
    arrived: u64,
}

impl DiffRenderer {
    /// A renderer for the free parameters of `set` (system parameters only: not `wavelength` or `ray.*`),
    /// render settings `config` (scene size, pitches, planes, rays, sampling, seed, Airy) and a scene with
    /// bands at `scene_wavelengths_nm`. Errors: a per-ray parameter, a parameter with no effect on the
    /// detector, real ray aiming, bad settings.
    pub fn new(set: ParamSet, config: RenderConfig, scene_wavelengths_nm: Vec<f64>) -> Result<Self> {
        config.validate()?;
        if (config.scene_height * config.scene_width) as u64 > u32::MAX as u64 {
            return Err(Error::invalid(format!("scene size {}×{} is too large", config.scene_height, config.scene_width)));
        }
        if scene_wavelengths_nm.is_empty() || scene_wavelengths_nm.iter().any(|w| !w.is_finite()) || scene_wavelengths_nm.windows(2).any(|p| p[1] <= p[0]) {
            return Err(Error::invalid(format!("scene wavelengths {scene_wavelengths_nm:?}: need ≥ 1, finite and increasing (nm)")));
        }
        if set.free.is_empty() {
            return Err(Error::invalid("the differentiable renderer needs ≥ 1 free parameter"));
        }
        for p in &set.free {
            if p.is_ray_parameter() {
                return Err(not_a_system_parameter(&p.name()));
            }
        }
        let ds = set.build()?;
        if ds.system.spec.ray_aiming != RayAiming::Off {
            return Err(Error::invalid("the differentiable renderer aims rays at the paraxial entrance pupil: set ray_aiming = \"off\""));
        }
        let planes = &config.spectral.planes_nm;
        for &w in planes {
            ds.system.indices(w)?;
        }
        let kernels: Vec<Option<AiryKernel>> = planes.iter().map(|&l| config.airy.map(|a| AiryKernel::for_wavelength(l, a.diameter_px, a.reference_nm, a.rings)).transpose()).collect::<Result<_>>()?;
        let airy_r = kernels.iter().flatten().map(|k| k.truncation_radius_px).fold(0.0, f64::max);
        let tracer = crate::tracer::AnalyticTracer::default();
        let detector = Detector::covering(&ds.system, &tracer, config.scene_height, config.scene_width, config.scene_pitch_mm, planes, config.detector_pitch_mm, airy_r, config.detector_extra_px)?;
        let kernels = kernels.into_iter().map(|k| k.map(|k| Kernel64 { half: k.half, w: k.weights.iter().map(|&v| v as f64).collect() })).collect();
        let plan = AdjointPlan::new(&ds, planes)?;
        for k in 0..ds.k() {
            if !AdjointPlan::moves(&ds, k, planes)? {
                return Err(Error::invalid(format!("free parameter `{}` has no effect on the detector image (it moves no surface, frame or index the rays see)", ds.params[k])));
            }
        }
        let aim = PupilAim::of(&ds.system);
        let simd = config.kernel.resolve()?;
        let sampler = RaySampler::new(config.rays_per_pixel, config.sampling);
        // The catalogue's span, or Schott's when the catalogue in use is the small built-in one.
        let map = crate::diff::glass_model::GlassMap::from_catalog(&set.catalog)?;
        let span = |v: &[f64], (lo, hi): (f64, f64)| (v.iter().cloned().fold(lo, f64::min), v.iter().cloned().fold(hi, f64::max));
        let glass_ranges = [span(&map.nd, SCHOTT_ND_SPAN), span(&map.vd, SCHOTT_VD_SPAN)];
        Ok(DiffRenderer { set, ds, config, detector, scene_wavelengths_nm, aim, kernels, sampler, plan, simd, glass_ranges })
    }

    /// The free parameters' names.
    pub fn names(&self) -> Vec<String> {
        self.set.names()
    }

    /// Current values of the free parameters (spec units).
    pub fn values(&self) -> Result<Vec<f64>> {
        self.set.values()
    }

    /// The same renderer (detector, pupil aim, samples, kernels) with the free parameters set to `x`.
    /// Errors name the parameter: a non-finite value, a glass outside the catalogue's (n_d, V_d) range, a
    /// system that does not build.
    pub fn with_values(&self, x: &[f64]) -> Result<Self> {
        for (p, v) in self.set.free.iter().zip(x) {
            let range = match p {
                crate::diff::Param::GlassNd(_) => Some(("n_d", self.glass_ranges[0])),
                crate::diff::Param::GlassVd(_) => Some(("V_d", self.glass_ranges[1])),
                _ => None,
            };
            if let Some((what, (lo, hi))) = range {
                if !(v.is_finite() && (lo..=hi).contains(v)) {
                    return Err(Error::invalid(format!("free parameter `{p}` = {v}: {what} outside the glass catalogue's range [{lo}, {hi}]")));
                }
            }
        }
        let set = self.set.with_values(x)?;
        let ds = set.build()?;
        for &w in &self.config.spectral.planes_nm {
            ds.system.indices(w)?;
        }
        let plan = AdjointPlan::new(&ds, &self.config.spectral.planes_nm)?;
        Ok(DiffRenderer { set, ds, plan, ..self.clone() })
    }

    /// Detector (height, width) in pixels.
    pub fn image_shape(&self) -> (usize, usize) {
        (self.detector.height, self.detector.width)
    }

    fn check_inputs(&self, scene: &[f64], n: usize, mask: &[f64]) -> Result<()> {
        let (h, w, b) = (self.config.scene_height, self.config.scene_width, self.scene_wavelengths_nm.len());
        if n == 0 || scene.len() != n * b * h * w {
            return Err(Error::invalid(format!("scene has {} values; expected (N, B, H, W) = ({n}, {b}, {h}, {w})", scene.len())));
        }
        if mask.len() != h * w {
            return Err(Error::invalid(format!("mask has {} values; expected (H, W) = ({h}, {w})", mask.len())));
        }
        if let Some(i) = scene.iter().position(|v| !v.is_finite()) {
            return Err(Error::invalid(format!("scene value {i} is {} (must be finite)", scene[i])));
        }
        if let Some(i) = mask.iter().position(|v| !v.is_finite()) {
            return Err(Error::invalid(format!("mask value {i} (row {}, column {}) is {} (must be finite)", i / w, i % w, mask[i])));
        }
        Ok(())
    }

    /// Scene band index and upper weight of plane `p` ([`crate::scene::SpectralCube::interpolation`]).
    fn interpolation(&self, p: usize) -> (usize, usize, f64) {
        let ws = &self.scene_wavelengths_nm;
        let l = self.config.spectral.planes_nm[p];
        let (k, t) = if ws.len() == 1 || l <= ws[0] {
            (0, 0.0)
        } else if l >= ws[ws.len() - 1] {
            (ws.len() - 2, 1.0)
        } else {
            let k = ws.partition_point(|&x| x <= l) - 1;
            (k, (l - ws[k]) / (ws[k + 1] - ws[k]))
        };
        (k, (k + 1).min(ws.len() - 1), t)
    }

    /// Visit the rays of plane `p` whose pixel passes `want`, one scene row at a time: `f(rays)` with
    /// each ray's pixel, origin and unit direction (buffers reused from row to row).
    fn for_rows(&self, p: usize, want: impl Fn(usize) -> bool, mut f: impl FnMut(&RowRays)) {
        let (h, w, pitch, nr) = (self.config.scene_height, self.config.scene_width, self.config.scene_pitch_mm, self.sampler.rays);
        let mut samples = SampleRow::default();
        let mut pixels: Vec<u64> = Vec::with_capacity(w);
        let mut rays = RowRays::default();
        for row in 0..h {
            pixels.clear();
            pixels.extend((0..w).map(|c| row * w + c).filter(|&q| want(q)).map(|q| q as u64));
            if pixels.is_empty() {
                continue;
            }
            self.sampler.fill_pixels(self.config.seed, p as u64, &pixels, &mut samples);
            rays.clear();
            for (k, &q) in pixels.iter().enumerate() {
                let col = q as usize % w;
                let c = MappingCube::scene_xy(h, w, pitch, row, col);
                for t in k * nr..(k + 1) * nr {
                    let s = samples.get(t);
                    let (fx, fy) = (c[0] + (s[2] - 0.5) * pitch, c[1] - (s[3] - 0.5) * pitch);
                    let d = DVec3::from(self.aim.direction(fx, fy, s[0], s[1]));
                    rays.pixel.push(q as usize);
                    rays.origin.push(DVec3::new(fx, fy, 0.0));
                    rays.dir.push(d / d.length());
                }
            }
            f(&rays);
        }
    }

    /// The landings ([`Self::landing`]) of the rays `which` of `rays` at indices `idx`, in order, into
    /// `out`: traced with the production renderer's SIMD lanes ([`crate::tracer::simd`], bit-identical to
    /// the scalar kernel) when `config.kernel` is SIMD, else with the scalar kernel.
    fn land_all(&self, idx: &[f64], rays: &RowRays, which: &[usize], out: &mut Vec<Option<(f64, f64)>>) {
        use crate::tracer::simd::{Block, LANES};
        out.clear();
        let path = &self.ds.system.path;
        let Some(level) = self.simd else {
            out.extend(which.iter().map(|&i| self.landing(trace_steps(path, idx, rays.origin[i], rays.dir[i]))));
            return;
        };
        let tables = [idx; LANES];
        for chunk in which.chunks(LANES) {
            let mut b = Block::default();
            // The directions are unit already (`for_rows`) and go to the scalar kernel as they are: the
            // lanes take them unchanged too (`trace_block_raw` would divide them by their length again,
            // which moves the last bit of some rays away from the scalar kernel's).
            for (k, &i) in chunk.iter().enumerate() {
                b.set(k, rays.origin[i], rays.dir[i]);
            }
            crate::tracer::simd::trace_block(level, path, &tables, &mut b);
            out.extend((0..chunk.len()).map(|k| self.landing(b.result(k))));
        }
    }

    /// Continuous detector pixel coordinates of an arrived ray, `None` when it did not arrive (or at an
    /// implausible position, as the renderer's landing test).
    fn landing(&self, r: std::result::Result<(DVec3, DVec3), (crate::tracer::RayStatus, usize)>) -> Option<(f64, f64)> {
        let (p, d) = r.ok()?;
        (p.is_finite() && d.is_finite() && p.abs().max_element() <= crate::limits::MAX_IMAGE_COORD_MM).then(|| self.detector.to_pixel(p.x, p.y))
    }

    /// Render the acquisitions of `n` scenes (scene (N, B, H, W) row-major, mask (H, W)): (N, h, w),
    /// row-major. Errors: wrong shapes, non-finite values, no ray reaching the detector.
    pub fn render(&self, scene: &[f64], n: usize, mask: &[f64]) -> Result<Vec<f64>> {
        self.check_inputs(scene, n, mask)?;
        let npix = self.detector.pixels();
        let (hw, nb, nr) = (self.config.scene_height * self.config.scene_width, self.scene_wavelengths_nm.len(), self.sampler.rays as f64);
        let planes: Vec<Result<(Vec<f64>, u64)>> = (0..self.config.spectral.planes())
            .into_par_iter()
            .map(|p| {
                let l = self.config.spectral.planes_nm[p];
                let idx = self.ds.system.indices(l)?;
                let (k0, k1, tw) = self.interpolation(p);
                let mut img = vec![0.0f64; n * npix];
                let mut arrived = 0u64;
                let (mut all, mut land, mut vals) = (Vec::new(), Vec::new(), vec![0.0; n]);
                self.for_rows(
                    p,
                    |q| mask[q] != 0.0,
                    |rays| {
                        all.clear();
                        all.extend(0..rays.pixel.len());
                        self.land_all(&idx, rays, &all, &mut land);
                        for (&q, uv) in rays.pixel.iter().zip(&land) {
                            let Some(uv) = *uv else { continue };
                            arrived += 1;
                            for (s, v) in vals.iter_mut().enumerate() {
                                *v = ((1.0 - tw) * scene[(s * nb + k0) * hw + q] + tw * scene[(s * nb + k1) * hw + q]) * mask[q] / nr;
                            }
                            let t = self.taps4(uv);
                            for k in 0..t.count {
                                for (s, v) in vals.iter().enumerate() {
                                    img[s * npix + t.index[k]] += v * t.wt[k];
                                }
                            }
                        }
                    },
                );
                let mut out = vec![0.0f64; n * npix];
                for s in 0..n {
                    self.blur(p, &img[s * npix..(s + 1) * npix], &mut out[s * npix..(s + 1) * npix]);
                }
                Ok((out, arrived))
            })
            .collect();
        let mut image = vec![0.0f64; n * npix];
        let mut arrived = 0;
        for r in planes {
            let (img, a) = r?;
            arrived += a;
            for (o, v) in image.iter_mut().zip(&img) {
                *o += v;
            }
        }
        self.check_arrived(arrived, mask)?;
        Ok(image)
    }

    fn check_arrived(&self, arrived: u64, mask: &[f64]) -> Result<()> {
        if arrived == 0 && mask.iter().any(|m| *m != 0.0) {
            let vals: Vec<String> = self.set.free.iter().zip(self.values().unwrap_or_default()).map(|(p, v)| format!("{p} = {v}")).collect();
            return Err(Error::invalid(format!("no ray reaches the detector at these parameter values ({}): every ray misses or is vignetted", vals.join(", "))));
        }
        Ok(())
    }

    /// out += plane_weight · (Airy kernel ⊛ src) (zero outside the detector).
    fn blur(&self, p: usize, src: &[f64], out: &mut [f64]) {
        let wgt = self.config.spectral.plane_weight;
        let Some(k) = &self.kernels[p] else {
            out.iter_mut().zip(src).for_each(|(o, s)| *o += wgt * s);
            return;
        };
        self.kernel_pass(k, src, 1, |i, acc| out[i] += wgt * acc);
    }

    /// The adjoint of [`Self::blur`]: out = plane_weight · Kᵀ g.
    fn blur_adjoint(&self, p: usize, g: &[f64], out: &mut [f64]) {
        let wgt = self.config.spectral.plane_weight;
        let Some(k) = &self.kernels[p] else {
            out.iter_mut().zip(g).for_each(|(o, s)| *o = wgt * s);
            return;
        };
        self.kernel_pass(k, g, -1, |i, acc| out[i] = wgt * acc);
    }

    /// For every detector pixel (x, y): Σ_{ki,kj} w[ki,kj] · img[y − dir·(ki − half), x − dir·(kj − half)] over
    /// the taps inside the detector, handed to `emit(pixel, sum)`. `dir` = 1 is the convolution K ⊛ img,
    /// `dir` = −1 its transpose (the correlation Kᵀ img); in f64, tiled with no bounds test per tap
    /// ([`super::convolve::kernel_pass_f64`], the same sums as the plain double loop bit for bit).
    fn kernel_pass(&self, k: &Kernel64, img: &[f64], dir: isize, mut emit: impl FnMut(usize, f64)) {
        super::convolve::kernel_pass_f64(&k.w, k.half, img, self.detector.width, self.detector.height, dir, &mut |i, sums: &[f64]| {
            for (j, &acc) in sums.iter().enumerate() {
                emit(i + j, acc);
            }
        });
    }

    /// The bilinear taps of a landing: detector index, weight, ∂weight/∂u, ∂weight/∂v of the first `count`
    /// of the four taps (those on the detector, in order; taps off the detector dropped, as the renderer
    /// loses them).
    #[inline]
    fn taps4(&self, (u, v): (f64, f64)) -> Taps {
        let (dw, dh) = (self.detector.width as i64, self.detector.height as i64);
        let (j, i) = (u.floor(), v.floor());
        let (fu, fv) = (u - j, v - i);
        let (j, i) = (j as i64, i as i64);
        let all = [(0, 0, (1.0 - fu) * (1.0 - fv), -(1.0 - fv), -(1.0 - fu)), (0, 1, fu * (1.0 - fv), 1.0 - fv, -fu), (1, 0, (1.0 - fu) * fv, -fv, 1.0 - fu), (1, 1, fu * fv, fv, fu)];
        let mut t = Taps { index: [0; 4], wt: [0.0; 4], du: [0.0; 4], dv: [0.0; 4], count: 0 };
        for (di, dj, wt, du, dv) in all {
            let (r, c) = (i + di, j + dj);
            if r >= 0 && r < dh && c >= 0 && c < dw {
                let k = t.count;
                (t.index[k], t.wt[k], t.du[k], t.dv[k]) = ((r * dw + c) as usize, wt, du, dv);
                t.count += 1;
            }
        }
        t
    }

    /// An arrived ray of pixel `px.q` landing at `uv`: its bilinear taps contracted with the blurred
    /// upstream gradient give its mask gradient (added to `out.mask` when wanted), its scene gradient
    /// (`scene`: added to `out.plane`; closed pixels have none) and, with `lambda`, ∂L/∂(landing x, y) in
    /// mm, returned (the λ its reverse sweep starts from; else (0, 0)). Sample by sample, the terms are
    /// those of the ray-by-ray loop and go into each pixel's sums in the same order (ray, then sample).
    #[inline]
    fn ray_grad(&self, pin: &PlaneInputs, px: &PixelVals, uv: (f64, f64), out: &mut PlaneGrad, scene: bool, lambda: bool) -> (f64, f64) {
        let t = self.taps4(uv);
        let (q, nr, npix, hw) = (px.q, pin.nr, pin.npix, pin.hw);
        let (mut u_bar, mut v_bar) = (0.0, 0.0);
        for s in 0..pin.n {
            let g = &pin.gb[s * npix..(s + 1) * npix];
            let (mut tb, mut ub, mut vb) = (0.0, 0.0, 0.0);
            for k in 0..t.count {
                let gv = g[t.index[k]];
                tb += t.wt[k] * gv;
                if lambda {
                    ub += t.du[k] * gv;
                    vb += t.dv[k] * gv;
                }
            }
            if pin.wanted.mask {
                out.mask[q] += px.val[s] * tb / nr;
            }
            if scene {
                out.plane[s * hw + q] += px.m * tb / nr;
            }
            if lambda {
                u_bar += px.vm[s] * ub / nr;
                v_bar += px.vm[s] * vb / nr;
            }
        }
        // (u, v) = ((x − x_left)/pitch − ½, (y_top − y)/pitch − ½).
        let pitch = self.detector.pitch_mm;
        (u_bar / pitch, -v_bar / pitch)
    }

    /// The vector–Jacobian product of [`Self::render`] at (scene, mask) for the upstream gradient `g`
    /// (N, h, w): ∂L/∂θ, ∂L/∂mask, ∂L/∂scene (all three: [`Self::vjp_wanted`] with [`Wanted::ALL`]).
    /// Errors: wrong shapes, a non-finite g (naming the entry), no ray reaching the detector.
    pub fn vjp(&self, scene: &[f64], n: usize, mask: &[f64], g: &[f64]) -> Result<Vjp> {
        self.vjp_wanted(scene, n, mask, g, Wanted::ALL)
    }

    /// [`Self::vjp`] computing only the gradients `wanted` says (torch's `needs_input_grad`); the others
    /// come back empty. Each wanted gradient is bit-identical to [`Self::vjp`]'s. Skipped with them: without
    /// the parameters' gradient, the recording trace and reverse sweep (open-pixel rays go through the
    /// production lanes for their landings only); without the mask's, the rays of closed mask pixels
    /// (value exactly 0), whose only use is the mask gradient, are not traced.
    pub fn vjp_wanted(&self, scene: &[f64], n: usize, mask: &[f64], g: &[f64], wanted: Wanted) -> Result<Vjp> {
        self.check_inputs(scene, n, mask)?;
        let npix = self.detector.pixels();
        let (h, w) = self.image_shape();
        if g.len() != n * npix {
            return Err(Error::invalid(format!("upstream gradient has {} values; expected (N, h, w) = ({n}, {h}, {w})", g.len())));
        }
        if let Some(i) = g.iter().position(|v| !v.is_finite()) {
            return Err(Error::invalid(format!("upstream gradient entry {i} (image {}, row {}, column {}) is {} (must be finite)", i / npix, (i % npix) / w, i % w, g[i])));
        }
        let kk = if wanted.params { self.ds.k() } else { 0 };
        let (hw, nb, nr) = (self.config.scene_height * self.config.scene_width, self.scene_wavelengths_nm.len(), self.sampler.rays as f64);
        let empty = |on: bool, len: usize| if on { vec![0.0; len] } else { Vec::new() };
        if !(wanted.params || wanted.mask || wanted.scene) {
            return Ok(Vjp { params: Vec::new(), mask: Vec::new(), scene: Vec::new() });
        }
        let planes: Vec<Result<PlaneGrad>> = (0..self.config.spectral.planes())
            .into_par_iter()
            .map(|p| {
                let l = self.config.spectral.planes_nm[p];
                let (idx, dn) = if wanted.params { self.ds.index_tangents(l)? } else { (self.ds.system.indices(l)?, Vec::new()) };
                let (k0, k1, tw) = self.interpolation(p);
                let mut gb = vec![0.0f64; n * npix];
                for s in 0..n {
                    self.blur_adjoint(p, &g[s * npix..(s + 1) * npix], &mut gb[s * npix..(s + 1) * npix]);
                }
                let mut out = PlaneGrad { params: vec![0.0; kk], mask: empty(wanted.mask, hw), plane: empty(wanted.scene, n * hw), arrived: 0 };
                let mut sums = AdjointSums::new(&self.plan);
                let (mut tape, mut ltape, mut lanes) = (RayTape::default(), LaneTape::default(), LaneSums::new(&self.plan));
                let tables = [idx.as_slice(); LANES];
                let pin = PlaneInputs { scene, mask, gb: &gb, n, k0, k1, tw, nr, npix, hw, nb, wanted };
                let mut px = PixelVals::new(n);
                let (mut closed, mut open, mut land) = (Vec::new(), Vec::new(), Vec::new());
                self.for_rows(
                    p,
                    // Without the mask gradient, closed pixels' rays have no use.
                    |q| wanted.mask || mask[q] != 0.0,
                    |rays| {
                        // Closed pixels (mask exactly 0) carry no light: their rays need only where they land,
                        // for the mask gradient (no θ-adjoint), so they go through the production lanes.
                        if wanted.mask {
                            closed.clear();
                            closed.extend((0..rays.pixel.len()).filter(|&i| mask[rays.pixel[i]] == 0.0));
                            self.land_all(&idx, rays, &closed, &mut land);
                            for (&i, uv) in closed.iter().zip(&land) {
                                let Some(uv) = *uv else { continue };
                                px.at(&pin, rays.pixel[i]);
                                self.ray_grad(&pin, &px, uv, &mut out, false, false);
                            }
                        }
                        // Open pixels (any non-zero mask value, a continuous mask's included).
                        open.clear();
                        open.extend((0..rays.pixel.len()).filter(|&i| mask[rays.pixel[i]] != 0.0));
                        if !wanted.params {
                            // No θ-adjoint: where the rays land is all the mask and scene gradients need.
                            self.land_all(&idx, rays, &open, &mut land);
                            for (&i, uv) in open.iter().zip(&land) {
                                let Some(uv) = *uv else { continue };
                                out.arrived += 1;
                                px.at(&pin, rays.pixel[i]);
                                self.ray_grad(&pin, &px, uv, &mut out, wanted.scene, false);
                            }
                            return;
                        }
                        // Traced with the per-step states kept, then swept backwards once — a block of
                        // rays at a time on the SIMD lanes, or ray by ray with the scalar kernel.
                        let Some(level) = self.simd else {
                            for &i in &open {
                                let Some(uv) = self.landing(self.plan.trace(&self.ds, &idx, rays.origin[i], rays.dir[i], &mut tape)) else { continue };
                                out.arrived += 1;
                                px.at(&pin, rays.pixel[i]);
                                let (lx, ly) = self.ray_grad(&pin, &px, uv, &mut out, wanted.scene, true);
                                if lx != 0.0 || ly != 0.0 {
                                    self.plan.backward(&self.ds, &mut tape, [lx, ly, 0.0, 0.0, 0.0, 0.0], &mut sums);
                                }
                            }
                            return;
                        };
                        for chunk in open.chunks(LANES) {
                            let mut b = Block::default();
                            for (k, &i) in chunk.iter().enumerate() {
                                b.set(k, rays.origin[i], rays.dir[i]);
                            }
                            trace_block_recording(level, &self.ds.system, &tables, &mut b, &mut ltape);
                            let mut lambda = [Lf::splat(0.0); 6];
                            let mut active = Mask::splat(false);
                            for (k, &i) in chunk.iter().enumerate() {
                                let Some(uv) = self.landing(b.result(k)) else { continue };
                                out.arrived += 1;
                                px.at(&pin, rays.pixel[i]);
                                let (lx, ly) = self.ray_grad(&pin, &px, uv, &mut out, wanted.scene, true);
                                if lx != 0.0 || ly != 0.0 {
                                    (lambda[0].0[k], lambda[1].0[k], active.0[k]) = (lx, ly, true);
                                }
                            }
                            if active.any() {
                                self.plan.backward_lanes(level, &self.ds, &ltape, &idx, &lambda, active, &mut lanes);
                            }
                        }
                    },
                );
                if wanted.params {
                    lanes.add_to(&mut sums);
                    self.plan.contract(&self.ds, &sums, &dn, &mut out.params);
                }
                Ok(out)
            })
            .collect();
        let mut v = Vjp { params: vec![0.0; kk], mask: empty(wanted.mask, hw), scene: empty(wanted.scene, n * nb * hw) };
        let mut arrived = 0;
        for (p, r) in planes.into_iter().enumerate() {
            let pg = r?;
            arrived += pg.arrived;
            v.params.iter_mut().zip(&pg.params).for_each(|(a, b)| *a += b);
            v.mask.iter_mut().zip(&pg.mask).for_each(|(a, b)| *a += b);
            if wanted.scene {
                let (k0, k1, tw) = self.interpolation(p);
                for s in 0..n {
                    for q in 0..hw {
                        let gq = pg.plane[s * hw + q];
                        v.scene[(s * nb + k0) * hw + q] += (1.0 - tw) * gq;
                        v.scene[(s * nb + k1) * hw + q] += tw * gq;
                    }
                }
            }
        }
        self.check_arrived(arrived, mask)?;
        Ok(v)
    }

    /// The chief-ray mapping cube at `wavelengths_nm` and its derivatives (forward mode, exact implicit
    /// Jacobians): where the chief ray of every scene pixel lands (image frame, mm), `positions[((q·L + l)·2
    /// + c)]` for pixel q, wavelength l, coordinate c (x, y); `jac[((q·L + l)·2 + c)·P + k]` = ∂/∂θ_k;
    /// `valid[q·L + l]` whether the ray arrived with finite derivatives (else zeros). Chief rays go through
    /// the centre of the (fixed) paraxial entrance pupil, as [`crate::analysis::mapping_cube`]'s.
    pub fn mapping_jacobian(&self, wavelengths_nm: &[f64]) -> Result<(Vec<f64>, Vec<f64>, Vec<bool>)> {
        let (h, w, pitch) = (self.config.scene_height, self.config.scene_width, self.config.scene_pitch_mm);
        let mut rays = crate::rays::RayBatch::with_capacity(h * w * wavelengths_nm.len());
        for row in 0..h {
            for col in 0..w {
                let c = MappingCube::scene_xy(h, w, pitch, row, col);
                let d = self.aim.direction(c[0], c[1], 0.0, 0.0);
                for &l in wavelengths_nm {
                    rays.push(DVec3::new(c[0], c[1], 0.0), DVec3::from(d), l);
                }
            }
        }
        let j = self.ds.trace(&rays)?;
        let kk = self.ds.k();
        let m = rays.len();
        let (mut pos, mut jac, mut valid) = (vec![0.0; 2 * m], vec![0.0; 2 * m * kk], vec![false; m]);
        for i in 0..m {
            if j.usable(i) {
                valid[i] = true;
                pos[2 * i] = j.traced.x[i];
                pos[2 * i + 1] = j.traced.y[i];
                jac[2 * i * kk..(2 * i + 1) * kk].copy_from_slice(j.row(i, 0));
                jac[(2 * i + 1) * kk..(2 * i + 2) * kk].copy_from_slice(j.row(i, 1));
            }
        }
        Ok((pos, jac, valid))
    }
}


/// The span of n_d and V_d over the non-obsolete glasses of Schott's catalogue (`SCHOTT.AGF`, 131 glasses:
/// n_d 1.456–2.022, V_d 20.88–90.9): a free glass outside the span of these and of the system's own
/// catalogue is no glass one can buy, and is an error.
pub const SCHOTT_ND_SPAN: (f64, f64) = (1.456, 2.02204);
pub const SCHOTT_VD_SPAN: (f64, f64) = (20.88, 90.9);
