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
//! **An object at infinity** (`system.object_at_infinity()`): the scene is given by its angular extent
//! (`config.scene_fov_deg`, required there and refused on a finite object, as by the production renderer:
//! [`super::engine::scene_pitch_for`]), its pixels uniform in field angle. A scene pixel's rays are those of
//! the production renderer — the same [`RaySampler`] samples, the sample's field angle (θx, θy) from the
//! pixel's angular position, and for its pupil point [`PupilAim::parallel_ray`]: direction ∝
//! (tan θx, tan θy, 1), through the construction-time entrance-pupil point, starting on surface 1's vertex
//! plane. The convention is the finite object's: the rays are **fixed in object space** while θ moves (the
//! pupil distance and radius of the aim are those at construction, kept by [`DiffRenderer::with_values`]),
//! so a parameter that moves the paraxial pupil changes only which of those parallel rays the stop lets
//! through.
//!
//! Cost: rays of closed mask pixels (value exactly 0) carry no light, so their mask gradient needs only
//! where they land — they are traced with the production renderer's SIMD lanes, with no θ-adjoint, as
//! are all rays of [`DiffRenderer::render`]; rays of open pixels (any non-zero value of a continuous mask)
//! are traced keeping their per-step states and swept backwards once, a block of [`LANES`] rays at a
//! time on the same SIMD lanes ([`crate::tracer::simd::record`], [`crate::diff::adjoint_lanes`]); with
//! `config.kernel = Kernel::Scalar` every ray goes through the scalar kernel and the scalar sweep
//! ([`crate::diff::adjoint`], the reference) instead. On the lanes, the per-ray work around the trace is
//! done for a block at once: the rays are generated into arrays ([`RayGen`], vectorised) and loaded into
//! the lanes, and the landing test, the bilinear taps and their sums with the blurred upstream gradient
//! are lane operations ([`TapLoop`]); only the additions to each pixel's mask and scene sums stay ray by
//! ray, in ray order (the same sums, bit for bit, as the scalar path's `ray_grad`).
//! [`DiffRenderer::vjp_wanted`] computes only the
//! gradients a [`Wanted`] names (torch's `needs_input_grad`): without ∂L/∂θ no ray is swept backwards,
//! without ∂L/∂mask the closed pixels' rays are not traced; the gradients it does compute are bit for bit
//! those of [`DiffRenderer::vjp`]. The blur's adjoint is tiled in f64 ([`super::convolve::kernel_pass_f64`]).
//!
//! **A coded mask on a surface** (dual-disperser CASSI, [`crate::system::MaskSurface`]): the mask (H, W) is
//! read where each ray crosses that surface, by its taps ([`crate::system::MaskSurface::taps`]); every
//! scene pixel's rays are traced, ray by ray on the scalar kernel and sweep, and the reverse sweep adds the
//! crossing point's ∂L/∂(x, y) at the mask's step ([`AdjointPlan::backward_seeded`]); `docs/codesign.md`
//! ("Dual-disperser CASSI") has the terms.
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
use crate::tracer::simd::lanes::{Lf, Lm, Mask};
use crate::tracer::simd::{trace_block_recording, Block, LaneTape, LANES};
use crate::diff::{DiffSystem, ParamSet};
use crate::error::{Error, Result};
use crate::rays::PupilAim;
use crate::spec::RayAiming;
use crate::system::MaskSurface;
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

/// Rays of some pixels of one scene row (reused buffers), a structure of arrays: each ray's pixel, its
/// origin (ox, oy, 0) in the object plane (mm) and its unit direction; a pixel's rays one after another.
#[derive(Default)]
struct RowRays {
    pixel: Vec<usize>,
    ox: Vec<f64>,
    oy: Vec<f64>,
    dx: Vec<f64>,
    dy: Vec<f64>,
    dz: Vec<f64>,
    /// Scratch: each ray's scene-pixel centre x (mm).
    centre_x: Vec<f64>,
}

impl RowRays {
    fn len(&self) -> usize {
        self.pixel.len()
    }

    fn origin(&self, i: usize) -> DVec3 {
        DVec3::new(self.ox[i], self.oy[i], 0.0)
    }

    fn dir(&self, i: usize) -> DVec3 {
        DVec3::new(self.dx[i], self.dy[i], self.dz[i])
    }

    /// Rays `start .. start + m` (m ≤ [`LANES`]) in the lanes of a block, alive: [`Block::set`]'s values
    /// (the directions are unit already and go in unchanged, as to the scalar kernel).
    fn block(&self, start: usize, m: usize) -> Block {
        let mut b = Block::default();
        let r = start..start + m;
        // One loop over the lanes for all five arrays, full blocks and a row's last alike (five
        // `copy_from_slice` of `m` values are five calls to `memmove`).
        let (ox, oy, dx, dy, dz) = (&self.ox[r.clone()], &self.oy[r.clone()], &self.dx[r.clone()], &self.dy[r.clone()], &self.dz[r]);
        for k in 0..m {
            (b.p.x.0[k], b.p.y.0[k], b.d.x.0[k], b.d.y.0[k], b.d.z.0[k]) = (ox[k], oy[k], dx[k], dy[k], dz[k]);
            b.alive.0[k] = true;
        }
        b
    }
}

/// Which rays of a scene pixel a pass wants ([`DiffRenderer::for_rows`]).
#[derive(Clone, Copy, PartialEq, Eq)]
enum Class {
    /// None of them.
    Skip,
    /// A closed mask pixel's (value exactly 0): traced for their landings only.
    Closed,
    /// An open pixel's (any non-zero mask value).
    Open,
}

/// The vectorised ray generation of a row: for each sample, the field point (pixel centre and the
/// sample's position in the pixel) and the direction of [`PupilAim::direction`] divided by its length —
/// the numbers of `DVec3::from(aim.direction(..))` / its `length()`, lane by lane (only `+ − × ÷ √`:
/// the same bits at every SIMD level).
struct RayGen<'a> {
    samples: &'a SampleRow,
    centre_y: f64,
    pitch_mm: f64,
    aim: PupilAim,
    out: &'a mut RowRays,
}

impl super::vector::VectorLoop for RayGen<'_> {
    #[inline(always)]
    fn run(self) {
        let o = self.out;
        super::sampling::object_rays::<true>(self.samples, &o.centre_x, self.centre_y, self.pitch_mm, self.aim, &mut o.ox, &mut o.oy, &mut o.dx, &mut o.dy, &mut o.dz);
    }
}

/// One traced block's share of the gradients, lane by lane ([`TapLoop`]): whether the lane's ray
/// arrived, per image s the terms its ray adds to its pixel's mask sum (`mask`) and scene sum (`plane`),
/// and, when λ is wanted, ∂L/∂(landing x, y) in mm (`lx`, `ly`) and whether it is not zero (`active`).
struct BlockTaps {
    ok: [bool; LANES],
    mask: Vec<[f64; LANES]>,
    plane: Vec<[f64; LANES]>,
    lx: [f64; LANES],
    ly: [f64; LANES],
    active: [bool; LANES],
}

impl BlockTaps {
    fn new(n: usize) -> Self {
        BlockTaps { ok: [false; LANES], mask: vec![[0.0; LANES]; n], plane: vec![[0.0; LANES]; n], lx: [0.0; LANES], ly: [0.0; LANES], active: [false; LANES] }
    }
}

/// [`DiffRenderer::landing`] and [`DiffRenderer::ray_grad`] for all lanes of a block at once (vectorised,
/// dispatched with [`super::vector::run_at`]): the same operations per lane — [`PixelVals::at`]'s values
/// of the lane's pixel, the four taps in `taps4`'s order (a tap off the detector adds an exact +0 in
/// place of being skipped: a sum that starts at +0 never becomes −0, so x + 0 = x bit for bit), each
/// term divided by N as `ray_grad` does — so each lane's terms and λ are `ray_grad`'s bit for bit.
struct TapLoop<'a> {
    b: &'a Block,
    det: &'a Detector,
    /// Each lane's scene pixel (lanes past the block's rays: any pixel, they are not alive).
    pixel: [usize; LANES],
    pin: &'a PlaneInputs<'a>,
    lambda: bool,
    out: &'a mut BlockTaps,
}

impl super::vector::VectorLoop for TapLoop<'_> {
    #[inline(always)]
    fn run(self) {
        let (b, det, pin, out) = (self.b, self.det, self.pin, self.out);
        let (dwf, dhf) = (det.width as f64, det.height as f64);
        let npix = det.width * det.height;
        // Per lane: arrived and plausible ([`DiffRenderer::landing`]), the cell (floor of the continuous
        // pixel coordinates, kept in f64: integers there, exactly) and the fractions inside it.
        let (mut ok, mut fj, mut fi, mut fu, mut fv) = ([false; LANES], [0.0; LANES], [0.0; LANES], [0.0; LANES], [0.0; LANES]);
        for k in 0..LANES {
            let (x, y, z) = (b.p.x.0[k], b.p.y.0[k], b.p.z.0[k]);
            let finite = x.is_finite() & y.is_finite() & z.is_finite() & b.d.x.0[k].is_finite() & b.d.y.0[k].is_finite() & b.d.z.0[k].is_finite();
            ok[k] = b.alive.0[k] & finite & (x.abs().max(y.abs().max(z.abs())) <= crate::limits::MAX_IMAGE_COORD_MM);
            let (u, v) = det.to_pixel(x, y);
            let (j, i) = (u.floor(), v.floor());
            (fj[k], fi[k], fu[k], fv[k]) = (j, i, u - j, v - i);
        }
        // The four taps (i, j), (i, j + 1), (i + 1, j), (i + 1, j + 1) — `taps4`'s order and arithmetic —
        // on the detector or not, and their detector index (0 when off).
        let mut on = [[false; LANES]; 4];
        let mut idx = [[0usize; LANES]; 4];
        let (mut wt, mut du, mut dv) = ([[0.0; LANES]; 4], [[0.0; LANES]; 4], [[0.0; LANES]; 4]);
        for k in 0..LANES {
            let (fu, fv) = (fu[k], fv[k]);
            (wt[0][k], du[0][k], dv[0][k]) = ((1.0 - fu) * (1.0 - fv), -(1.0 - fv), -(1.0 - fu));
            (wt[1][k], du[1][k], dv[1][k]) = (fu * (1.0 - fv), 1.0 - fv, -fu);
            (wt[2][k], du[2][k], dv[2][k]) = ((1.0 - fu) * fv, -fv, 1.0 - fu);
            (wt[3][k], du[3][k], dv[3][k]) = (fu * fv, fv, fu);
            let (r0, c0) = (fi[k], fj[k]);
            let rows = [ok[k] & (r0 >= 0.0) & (r0 < dhf), ok[k] & (r0 + 1.0 >= 0.0) & (r0 + 1.0 < dhf)];
            let cols = [(c0 >= 0.0) & (c0 < dwf), (c0 + 1.0 >= 0.0) & (c0 + 1.0 < dwf)];
            let base = r0 * dwf + c0;
            for (t, (dr, dc)) in [(0, 0), (0, 1), (1, 0), (1, 1)].into_iter().enumerate() {
                on[t][k] = rows[dr] & cols[dc];
                // A tap on the detector: an integer in [0, h·w) (< 2⁵¹), converted without a conversion
                // instruction (so it vectorises) by the landing loop's `int_bits`.
                let at = base + (dr as f64) * dwf + dc as f64;
                let bits = super::transport::int_bits(at) as usize;
                idx[t][k] = if on[t][k] { bits } else { 0 };
            }
        }
        let (nr, hw, nb, tw) = (pin.nr, pin.hw, pin.nb, pin.tw);
        // Each lane's pixel's mask value, loaded one by one (see below).
        let (mut q, mut m) = ([0usize; LANES], [0.0; LANES]);
        for k in 0..LANES {
            q[k] = self.pixel[k].min(hw - 1);
            m[k] = pin.mask[q[k]];
        }
        let (mut u_bar, mut v_bar) = ([0.0; LANES], [0.0; LANES]);
        for s in 0..pin.n {
            let g = &pin.gb[s * npix..(s + 1) * npix];
            let (s0, s1) = (&pin.scene[(s * nb + pin.k0) * hw..(s * nb + pin.k0 + 1) * hw], &pin.scene[(s * nb + pin.k1) * hw..(s * nb + pin.k1 + 1) * hw]);
            // The loads by index — the blurred upstream gradient at each tap (0 off the detector), the
            // lane's pixel's scene values in the plane's two bands — one by one: a loop of its own, so
            // that the arithmetic below is whole-register operations (its divisions were ≈ 30 % of this
            // loop as scalar instructions) without the gathers that are slow on AMD Zen 4.
            let (mut gv, mut a, mut bb) = ([[0.0; LANES]; 4], [0.0; LANES], [0.0; LANES]);
            for k in 0..LANES {
                for t in 0..4 {
                    gv[t][k] = if on[t][k] { g[idx[t][k]] } else { 0.0 };
                }
                (a[k], bb[k]) = (s0[q[k]], s1[q[k]]);
            }
            // The taps' sums with the upstream gradient in `taps4`'s order (a tap off the detector adds
            // w·0 = ±0 to a sum that is never −0: no bit changes), then `PixelVals::at` and `ray_grad`'s
            // terms.
            let (mask_t, plane_t) = (&mut out.mask[s], &mut out.plane[s]);
            let mut st = [0.0; LANES];
            for t in 0..4 {
                for k in 0..LANES {
                    st[k] += wt[t][k] * gv[t][k];
                }
            }
            let mut val = [0.0; LANES];
            for k in 0..LANES {
                val[k] = (1.0 - tw) * a[k] + tw * bb[k];
                mask_t[k] = val[k] * st[k] / nr;
                plane_t[k] = m[k] * st[k] / nr;
            }
            if self.lambda {
                let (mut su, mut sv) = ([0.0; LANES], [0.0; LANES]);
                for t in 0..4 {
                    for k in 0..LANES {
                        su[k] += du[t][k] * gv[t][k];
                        sv[k] += dv[t][k] * gv[t][k];
                    }
                }
                for k in 0..LANES {
                    let vm = val[k] * m[k];
                    u_bar[k] += vm * su[k] / nr;
                    v_bar[k] += vm * sv[k] / nr;
                }
            }
        }
        if self.lambda {
            // (u, v) = ((x − x_left)/pitch − ½, (y_top − y)/pitch − ½), as `ray_grad`.
            let pitch = det.pitch_mm;
            for k in 0..LANES {
                let (lx, ly) = (u_bar[k] / pitch, -v_bar[k] / pitch);
                let act = ok[k] & ((lx != 0.0) | (ly != 0.0));
                out.lx[k] = if act { lx } else { 0.0 };
                out.ly[k] = if act { ly } else { 0.0 };
                out.active[k] = act;
            }
        }
        out.ok = ok;
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

/// A coded mask on a surface of `system` (dual-disperser CASSI) must see the beam of the scene `config`
/// describes (pitch in the system's field unit): the production renderer's check and message
/// ([`super::engine::check_mask_in_beam`]), else every ray would be blocked and every gradient 0.
fn check_mask_sees_the_beam(system: &crate::system::SequentialSystem, config: &RenderConfig) -> Result<()> {
    match system.coded_mask {
        Some(m) => super::engine::check_mask_in_beam(system, m, config.scene_pitch_mm, config.scene_height, config.scene_width),
        None => Ok(()),
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
    /// detector, real ray aiming, bad settings, a coded-mask surface outside the beam (the production
    /// renderer's check and message); for an object at infinity a missing `config.scene_fov_deg`,
    /// on a finite object a given one, and an angle outside (0, 180) degrees (NaN included), each naming the
    /// value ([`super::engine::scene_pitch_for`]). At infinity `config.scene_pitch_mm` is replaced by one
    /// pixel's angle in radians (`scene_fov_deg` / width), as the production renderer does.
    ///
    /// The entrance-pupil aim is taken here, once ([`PupilAim::of`]) and kept while the parameters move
    /// ([`Self::with_values`]): the object-space rays are fixed — from each object point through the
    /// construction-time pupil, or at infinity the parallel beams of each field angle through it.
    pub fn new(set: ParamSet, mut config: RenderConfig, scene_wavelengths_nm: Vec<f64>) -> Result<Self> {
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
        // The scene pitch in the system's field unit: mm on a finite object plane, or one pixel's angle (rad)
        // for an object at infinity, from `scene_fov_deg` (the production renderer's function and errors:
        // required at infinity, refused on a finite object, in (0, 180) degrees).
        config.scene_pitch_mm = super::engine::scene_pitch_for(&ds.system, &config)?;
        config.validate()?;
        check_mask_sees_the_beam(&ds.system, &config)?;
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

    /// The same renderer (detector, pupil aim, samples, kernels) with the free parameters set to `x`: the
    /// object-space rays stay those of construction (at infinity too: each field's parallel beam keeps its
    /// direction and its crossing of surface 1's vertex plane).
    /// Errors name the parameter: a non-finite value, a glass outside the catalogue's (n_d, V_d) range, a
    /// system that does not build; and a coded-mask surface the values move out of the beam.
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
        check_mask_sees_the_beam(&ds.system, &self.config)?;
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

    /// Visit the rays of plane `p`, one scene row at a time: `f(closed, open)` with the rays of the row's
    /// pixels that `class` says are [`Class::Closed`] and [`Class::Open`] (each ray's pixel, origin and
    /// unit direction, pixels in order; buffers reused from row to row). A pixel's rays are the same
    /// whichever set it is in (the samples depend on the seed, plane and pixel only).
    fn for_rows(&self, p: usize, class: impl Fn(usize) -> Class, mut f: impl FnMut(&RowRays, &RowRays)) {
        let w = self.config.scene_width;
        let mut samples = SampleRow::default();
        let (mut closed_px, mut open_px): (Vec<u64>, Vec<u64>) = (Vec::with_capacity(w), Vec::with_capacity(w));
        let (mut closed, mut open) = (RowRays::default(), RowRays::default());
        for row in 0..self.config.scene_height {
            closed_px.clear();
            open_px.clear();
            for q in row * w..(row + 1) * w {
                match class(q) {
                    Class::Skip => {}
                    Class::Closed => closed_px.push(q as u64),
                    Class::Open => open_px.push(q as u64),
                }
            }
            if closed_px.is_empty() && open_px.is_empty() {
                continue;
            }
            self.row_rays(p, row, &closed_px, &mut samples, &mut closed);
            self.row_rays(p, row, &open_px, &mut samples, &mut open);
            f(&closed, &open);
        }
    }

    /// The rays of plane `p` of `pixels` (all in scene row `row`) into `out`: the [`RaySampler`]'s
    /// samples, the field point and the unit direction ([`RayGen`]).
    fn row_rays(&self, p: usize, row: usize, pixels: &[u64], samples: &mut SampleRow, out: &mut RowRays) {
        let (h, w, pitch, nr) = (self.config.scene_height, self.config.scene_width, self.config.scene_pitch_mm, self.sampler.rays);
        out.pixel.clear();
        out.centre_x.clear();
        if pixels.is_empty() {
            return;
        }
        self.sampler.fill_pixels(self.config.seed, p as u64, pixels, samples);
        for &q in pixels {
            let c = MappingCube::scene_xy(h, w, pitch, row, q as usize % w);
            out.pixel.extend(std::iter::repeat(q as usize).take(nr));
            out.centre_x.extend(std::iter::repeat(c[0]).take(nr));
        }
        let n = samples.len();
        debug_assert_eq!(n, out.pixel.len());
        for v in [&mut out.ox, &mut out.oy, &mut out.dx, &mut out.dy, &mut out.dz] {
            v.resize(n, 0.0);
        }
        let centre_y = MappingCube::scene_xy(h, w, pitch, row, 0)[1];
        if self.aim.at_infinity {
            // An object at infinity: the sample's field angles (θx, θy) (rad) — the pixel's angular centre
            // moved by the sample's position in the pixel of angular pitch `pitch`, the arithmetic of the
            // production renderer's `PlaneContext::ray` — and the parallel ray of that field through the
            // sample's pupil point ([`PupilAim::parallel_ray`], direction ∝ (tan θx, tan θy, 1), origin on
            // surface 1's vertex plane), its direction divided by its length as the production lanes do
            // before tracing (so the same rays bit for bit).
            let r = self.aim.scale;
            for t in 0..n {
                let [px, py, sx, sy] = samples.get(t);
                let field = [out.centre_x[t] + (sx - 0.5) * pitch, centre_y - (sy - 0.5) * pitch];
                let (o, d) = self.aim.parallel_ray(field, px * r, py * r);
                let len = (d.x * d.x + d.y * d.y + d.z * d.z).sqrt();
                (out.ox[t], out.oy[t], out.dx[t], out.dy[t], out.dz[t]) = (o.x, o.y, d.x / len, d.y / len, d.z / len);
                debug_assert_eq!(o.z, 0.0);
            }
            return;
        }
        let level = self.simd.unwrap_or_else(crate::tracer::SimdLevel::detect);
        super::vector::run_at(level, RayGen { samples, centre_y, pitch_mm: pitch, aim: self.aim, out });
    }

    /// The landings ([`Self::landing`]) of all rays of `rays` at indices `idx`, in order, into `out`:
    /// traced with the production renderer's SIMD lanes ([`crate::tracer::simd`], bit-identical to the
    /// scalar kernel) when `config.kernel` is SIMD, else with the scalar kernel.
    fn land_all(&self, idx: &[f64], rays: &RowRays, out: &mut Vec<Option<(f64, f64)>>) {
        out.clear();
        let path = &self.ds.system.path;
        let Some(level) = self.simd else {
            out.extend((0..rays.len()).map(|i| self.landing(trace_steps(path, idx, rays.origin(i), rays.dir(i)))));
            return;
        };
        let tables = [idx; LANES];
        for start in (0..rays.len()).step_by(LANES) {
            let m = (rays.len() - start).min(LANES);
            let mut b = rays.block(start, m);
            crate::tracer::simd::trace_block(level, path, &tables, &mut b);
            out.extend((0..m).map(|k| self.landing(b.result(k))));
        }
    }

    /// The rays of `rays` that need no θ-adjoint (closed pixels', or every ray when ∂L/∂θ is not wanted):
    /// traced for their landings only, each arrived ray's mask gradient (and with `scene` its scene
    /// gradient) added to `out` ([`Self::ray_grad`]'s sums); `count`: count the arrived rays. On the
    /// production renderer's SIMD lanes a block at a time with the taps as lane operations
    /// ([`Self::block_grads`]), else ray by ray with the scalar kernel.
    #[allow(clippy::too_many_arguments)]
    fn landing_grads(&self, idx: &[f64], rays: &RowRays, pin: &PlaneInputs, px: &mut PixelVals, out: &mut PlaneGrad, scene: bool, count: bool, taps: &mut BlockTaps) {
        let path = &self.ds.system.path;
        let Some(level) = self.simd else {
            for i in 0..rays.len() {
                let Some(uv) = self.landing(trace_steps(path, idx, rays.origin(i), rays.dir(i))) else { continue };
                out.arrived += count as u64;
                px.at(pin, rays.pixel[i]);
                self.ray_grad(pin, px, uv, out, scene, false);
            }
            return;
        };
        let tables = [idx; LANES];
        for start in (0..rays.len()).step_by(LANES) {
            let m = (rays.len() - start).min(LANES);
            let mut b = rays.block(start, m);
            crate::tracer::simd::trace_block(level, path, &tables, &mut b);
            let arrived = self.block_grads(level, &b, &rays.pixel[start..start + m], pin, out, scene, None, taps);
            out.arrived += if count { arrived } else { 0 };
        }
    }

    /// A traced block's share of the gradients, the first `pixel.len()` lanes being rays of those pixels:
    /// the lanes' landings, tap sums and terms as lane operations ([`TapLoop`]), then ray by ray in lane
    /// order [`Self::ray_grad`]'s additions to the mask sums (when wanted) and with `scene` to the scene
    /// sums (the same terms in the same order); with `lambda`, each arrived lane's ∂L/∂(landing x, y) in
    /// mm into `lambda` (λ's first two arrays) and the lanes whose λ is not zero into `active`. Returns
    /// the number of arrived rays.
    #[allow(clippy::too_many_arguments)]
    fn block_grads(&self, level: crate::tracer::SimdLevel, b: &Block, pixel: &[usize], pin: &PlaneInputs, out: &mut PlaneGrad, scene: bool, lambda: Option<(&mut [Lf; 6], &mut Lm)>, taps: &mut BlockTaps) -> u64 {
        let mut lanes = [0usize; LANES];
        lanes[..pixel.len()].copy_from_slice(pixel);
        super::vector::run_at(level, TapLoop { b, det: &self.detector, pixel: lanes, pin, lambda: lambda.is_some(), out: taps });
        let hw = pin.hw;
        let mut arrived = 0;
        for (k, &q) in pixel.iter().enumerate() {
            if !taps.ok[k] {
                continue;
            }
            arrived += 1;
            for s in 0..pin.n {
                if pin.wanted.mask {
                    out.mask[q] += taps.mask[s][k];
                }
                if scene {
                    out.plane[s * hw + q] += taps.plane[s][k];
                }
            }
        }
        if let Some((lam, active)) = lambda {
            (lam[0].0, lam[1].0, active.0) = (taps.lx, taps.ly, taps.active);
        }
        arrived
    }

    /// Rays of `rays` through a system whose coded mask is on surface `ms` (dual-disperser CASSI): each
    /// one's landing ([`Self::landing`]) into `land` and the mask's transmission where it crossed the
    /// surface ([`MaskSurface::transmission`] of the (H, W) `mask`, as the production renderer reads it; 0
    /// for a ray that stopped before it) into `weight`. The path is traced in two parts split after the
    /// mask's step, by the scalar kernel: the same operations as one trace, so the same landings.
    fn land_through_mask(&self, ms: MaskSurface, idx: &[f64], mask: &[f64], rays: &RowRays, land: &mut Vec<Option<(f64, f64)>>, weight: &mut Vec<f64>) {
        let (h, w) = (self.config.scene_height, self.config.scene_width);
        let (arm1, arm2) = self.ds.system.path.split_at(ms.step + 1);
        land.clear();
        weight.clear();
        for i in 0..rays.len() {
            let (res, t) = match trace_steps(arm1, idx, rays.origin(i), rays.dir(i)) {
                Ok((pm, dm)) => (trace_steps(arm2, idx, pm, dm), ms.transmission(mask, h, w, pm.x, pm.y)),
                Err(e) => (Err(e), 0.0),
            };
            land.push(self.landing(res));
            weight.push(t);
        }
    }

    /// The gradients of the rays of `rays` through a system whose coded mask is on surface `ms`
    /// (dual-disperser CASSI), ray by ray with the scalar kernel. A ray of scene value v_s (image s),
    /// crossing the surface where the mask's taps ([`MaskSurface::taps`]) read T = Σ_t w_t·m_t, splats
    /// v_s·T/N at its landing. With t̄_s its taps' sum with the blurred upstream gradient and
    /// Ā = Σ_s v_s·t̄_s/N (= ∂L/∂T):
    /// - ∂L/∂m_t += w_t·Ā, for every ray (a ray through a closed pixel has a mask gradient too);
    /// - ∂L/∂scene_s += T·t̄_s/N;
    /// - ∂L/∂θ: the sweep starts from the landing's λ (as [`Self::ray_grad`], with v_s·T in place of
    ///   v_s·m) and adds ∂L/∂(crossing x, y) = Ā·Σ_t (∂w_t/∂x, ∂w_t/∂y)·m_t at the mask's step
    ///   ([`AdjointPlan::backward_seeded`]) — zero for `nearest` sampling, whose transmission is piecewise
    ///   constant (its jumps are boundary terms, left out as for rays that change status).
    #[allow(clippy::too_many_arguments)]
    fn grads_through_mask(&self, ms: MaskSurface, idx: &[f64], rays: &RowRays, pin: &PlaneInputs, out: &mut PlaneGrad, tape: &mut RayTape, sums: &mut AdjointSums) {
        let (h, w) = (self.config.scene_height, self.config.scene_width);
        let (arm1, arm2) = self.ds.system.path.split_at(ms.step + 1);
        let (nr, npix, hw, nb) = (pin.nr, pin.npix, pin.hw, pin.nb);
        let params = pin.wanted.params;
        for i in 0..rays.len() {
            let (o, d) = (rays.origin(i), rays.dir(i));
            // With ∂L/∂θ wanted, one recording trace (the same operations as the split trace, so the
            // same crossing and landing); else the two arms.
            let (res, crossing) = if params {
                let r = self.plan.trace(&self.ds, idx, o, d, tape);
                (r, tape.point(ms.step))
            } else {
                match trace_steps(arm1, idx, o, d) {
                    Ok((pm, dm)) => (trace_steps(arm2, idx, pm, dm), Some(pm)),
                    Err(e) => (Err(e), None),
                }
            };
            let (Some(uv), Some(pm)) = (self.landing(res), crossing) else { continue };
            out.arrived += 1;
            let q = rays.pixel[i];
            let t = ms.transmission(pin.mask, h, w, pm.x, pm.y);
            let det = self.taps4(uv);
            let (mut a_bar, mut u_bar, mut v_bar) = (0.0, 0.0, 0.0);
            for s in 0..pin.n {
                let g = &pin.gb[s * npix..(s + 1) * npix];
                let (mut tb, mut ub, mut vb) = (0.0, 0.0, 0.0);
                for k in 0..det.count {
                    let gv = g[det.index[k]];
                    tb += det.wt[k] * gv;
                    ub += det.du[k] * gv;
                    vb += det.dv[k] * gv;
                }
                let val = (1.0 - pin.tw) * pin.scene[(s * nb + pin.k0) * hw + q] + pin.tw * pin.scene[(s * nb + pin.k1) * hw + q];
                if pin.wanted.scene {
                    out.plane[s * hw + q] += t * tb / nr;
                }
                a_bar += val * tb / nr;
                u_bar += val * t * ub / nr;
                v_bar += val * t * vb / nr;
            }
            let mt = ms.taps(h, w, pm.x, pm.y);
            if pin.wanted.mask {
                for k in 0..mt.count {
                    out.mask[mt.index[k]] += mt.weight[k] * a_bar;
                }
            }
            if params {
                // (u, v) = ((x − x_left)/pitch − ½, (y_top − y)/pitch − ½).
                let pitch = self.detector.pitch_mm;
                let (lx, ly) = (u_bar / pitch, -v_bar / pitch);
                let (mut gx, mut gy) = (0.0, 0.0);
                for k in 0..mt.count {
                    gx += mt.d_dx[k] * pin.mask[mt.index[k]];
                    gy += mt.d_dy[k] * pin.mask[mt.index[k]];
                }
                let seed = DVec3::new(a_bar * gx, a_bar * gy, 0.0);
                if lx != 0.0 || ly != 0.0 || seed != DVec3::ZERO {
                    self.plan.backward_seeded(&self.ds, tape, [lx, ly, 0.0, 0.0, 0.0, 0.0], Some((ms.step, seed)), sums);
                }
            }
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
                // Each ray's weight: its scene pixel's mask value (the mask on the object plane), or with a
                // coded-mask surface (dual-disperser) the transmission where it crosses that surface, every
                // scene pixel's rays being traced.
                let surface = self.ds.system.coded_mask;
                let (mut land, mut weights, mut vals) = (Vec::new(), Vec::new(), vec![0.0; n]);
                self.for_rows(
                    p,
                    |q| if surface.is_some() || mask[q] != 0.0 { Class::Open } else { Class::Skip },
                    |_, rays| {
                        match surface {
                            Some(ms) => self.land_through_mask(ms, &idx, mask, rays, &mut land, &mut weights),
                            None => {
                                self.land_all(&idx, rays, &mut land);
                                weights.clear();
                                weights.extend(rays.pixel.iter().map(|&q| mask[q]));
                            }
                        }
                        for ((&q, uv), &wgt) in rays.pixel.iter().zip(&land).zip(&weights) {
                            let Some(uv) = *uv else { continue };
                            // Arrived: it lands on a detector pixel (a landing beyond the detector adds nothing:
                            // counted, a θ with every ray off the detector rendered zeros and zero gradients
                            // where the table path refuses it; a held-out battery, round 6).
                            let t = self.taps4(uv);
                            if t.count == 0 {
                                continue;
                            }
                            arrived += 1;
                            for (s, v) in vals.iter_mut().enumerate() {
                                *v = ((1.0 - tw) * scene[(s * nb + k0) * hw + q] + tw * scene[(s * nb + k1) * hw + q]) * wgt / nr;
                            }
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

    /// Whether a ray of any scene pixel, open or closed, lands on a detector pixel at some plane: when no open
    /// pixel's ray arrived, a mask whose open pixels all sit where θ sends the light off the detector is then to
    /// blame, not θ (the acquisition is a true zero, as the table path renders it).
    fn any_pixel_lands(&self) -> Result<bool> {
        for p in 0..self.config.spectral.planes() {
            let idx = self.ds.system.indices(self.config.spectral.planes_nm[p])?;
            let (mut land, mut found) = (Vec::new(), false);
            self.for_rows(
                p,
                |_| Class::Open,
                |_, rays| {
                    if !found {
                        self.land_all(&idx, rays, &mut land);
                        found = land.iter().any(|uv| uv.is_some_and(|uv| self.taps4(uv).count > 0));
                    }
                },
            );
            if found {
                return Ok(true);
            }
        }
        Ok(false)
    }

    fn check_arrived(&self, arrived: u64, mask: &[f64]) -> Result<()> {
        let partly_closed = self.ds.system.coded_mask.is_none() && mask.iter().any(|m| *m == 0.0);
        if arrived == 0 && mask.iter().any(|m| *m != 0.0) && !(partly_closed && self.any_pixel_lands()?) {
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
                let mut taps = BlockTaps::new(n);
                let lane_sweep = self.ds.system.special_surface().is_none();
                if let Some(ms) = self.ds.system.coded_mask {
                    // The mask on a surface (dual-disperser): ray by ray on the scalar kernel and sweep.
                    self.for_rows(p, |_| Class::Open, |_, rays| self.grads_through_mask(ms, &idx, rays, &pin, &mut out, &mut tape, &mut sums));
                    if wanted.params {
                        self.plan.contract(&self.ds, &sums, &dn, &mut out.params);
                    }
                    return Ok(out);
                }
                // Without the mask gradient, closed pixels' rays have no use.
                let class = |q: usize| if mask[q] != 0.0 { Class::Open } else if wanted.mask { Class::Closed } else { Class::Skip };
                self.for_rows(p, class, |closed, open| {
                    // Closed pixels (mask exactly 0) carry no light: their rays need only where they land,
                    // for the mask gradient (no θ-adjoint), so they go through the production lanes.
                    self.landing_grads(&idx, closed, &pin, &mut px, &mut out, false, false, &mut taps);
                    // Open pixels (any non-zero mask value, a continuous mask's included).
                    if !wanted.params {
                        // No θ-adjoint: where the rays land is all the mask and scene gradients need.
                        self.landing_grads(&idx, open, &pin, &mut px, &mut out, wanted.scene, true, &mut taps);
                        return;
                    }
                    // Traced with the per-step states kept, then swept backwards once — a block of
                    // rays at a time on the SIMD lanes, or ray by ray with the scalar kernel. The lane
                    // sweep transposes refraction and the ideal lens; a system with a mirror, a grating
                    // or a Toroidal surface is swept ray by ray (the scalar sweep covers them).
                    let Some(level) = self.simd.filter(|_| lane_sweep) else {
                        for i in 0..open.len() {
                            let Some(uv) = self.landing(self.plan.trace(&self.ds, &idx, open.origin(i), open.dir(i), &mut tape)) else { continue };
                            out.arrived += 1;
                            px.at(&pin, open.pixel[i]);
                            let (lx, ly) = self.ray_grad(&pin, &px, uv, &mut out, wanted.scene, true);
                            if lx != 0.0 || ly != 0.0 {
                                self.plan.backward(&self.ds, &mut tape, [lx, ly, 0.0, 0.0, 0.0, 0.0], &mut sums);
                            }
                        }
                        return;
                    };
                    for start in (0..open.len()).step_by(LANES) {
                        let m = (open.len() - start).min(LANES);
                        let mut b = open.block(start, m);
                        trace_block_recording(level, &self.ds.system, &tables, &mut b, &mut ltape);
                        let mut lambda = [Lf::splat(0.0); 6];
                        let mut active = Mask::splat(false);
                        out.arrived += self.block_grads(level, &b, &open.pixel[start..start + m], &pin, &mut out, wanted.scene, Some((&mut lambda, &mut active)), &mut taps);
                        if active.any() {
                            self.plan.backward_lanes(level, &self.ds, &ltape, &idx, &lambda, active, &mut lanes);
                        }
                    }
                });
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
    /// the centre of the (fixed) paraxial entrance pupil, as [`crate::analysis::mapping_cube`]'s; for an
    /// object at infinity a pixel's chief ray is the parallel ray of its field angles through that centre.
    ///
    /// Before allocating it checks the ray budget (H·W·L chief rays) and the memory budget
    /// ([`crate::limits::bytes_mapping_jacobian`]: the returned arrays and one block of the trace), naming
    /// H × W × L and the parameter count; the rays are traced [`crate::limits::MAPPING_JACOBIAN_BLOCK`] at a time
    /// straight into the returned arrays (each ray is independent: the result does not depend on the block).
    pub fn mapping_jacobian(&self, wavelengths_nm: &[f64]) -> Result<(Vec<f64>, Vec<f64>, Vec<bool>)> {
        let (h, w, pitch) = (self.config.scene_height, self.config.scene_width, self.config.scene_pitch_mm);
        let (l, kk) = (wavelengths_nm.len(), self.ds.k());
        let what = format!("mapping Jacobian: H × W × wavelengths ({h} × {w} × {l}) chief rays, {kk} free parameters");
        let reduce = "the scene size or the wavelengths";
        let m = h as f64 * w as f64 * l as f64;
        crate::limits::check_rays_reducing(&what, reduce, m)?;
        crate::limits::check_memory_reducing(&what, reduce, crate::limits::bytes_mapping_jacobian(h, w, l, kk))?;
        let m = h * w * l;
        let (mut pos, mut jac, mut valid) = (vec![0.0; 2 * m], vec![0.0; 2 * m * kk], vec![false; m]);
        // The chief ray of entry i = q·L + l (pixel q = row·W + col, wavelength l).
        let chief = |q: usize| {
            let c = MappingCube::scene_xy(h, w, pitch, q / w, q % w);
            // (At infinity c holds the pixel's field angles in radians.)
            if self.aim.at_infinity { self.aim.parallel_ray(c, 0.0, 0.0) } else { (DVec3::new(c[0], c[1], 0.0), DVec3::from(self.aim.direction(c[0], c[1], 0.0, 0.0))) }
        };
        let block = crate::limits::MAPPING_JACOBIAN_BLOCK;
        for start in (0..m).step_by(block) {
            let end = (start + block).min(m);
            let mut rays = crate::rays::RayBatch::with_capacity(end - start);
            let mut q_prev = usize::MAX;
            let mut od = (DVec3::ZERO, DVec3::ZERO);
            for i in start..end {
                let q = i / l;
                if q != q_prev {
                    od = chief(q);
                    q_prev = q;
                }
                rays.push(od.0, od.1, wavelengths_nm[i % l]);
            }
            let j = self.ds.trace(&rays)?;
            for r in 0..rays.len() {
                let i = start + r;
                if j.usable(r) {
                    valid[i] = true;
                    pos[2 * i] = j.traced.x[r];
                    pos[2 * i + 1] = j.traced.y[r];
                    jac[2 * i * kk..(2 * i + 1) * kk].copy_from_slice(j.row(r, 0));
                    jac[(2 * i + 1) * kk..(2 * i + 2) * kk].copy_from_slice(j.row(r, 1));
                }
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
