//! Light transport of one spectral plane: for every open mask pixel, where its N rays land on the detector,
//! kept as a small dense window of bilinear-splat weights (a *footprint*). The image of a plane is then
//! linear in the scene: image = Σ_pixels value(pixel) · footprint(pixel). Per-scene rendering builds each
//! plane's footprints and applies them at once; dataset mode keeps them and applies them to every scene —
//! the same function on the same numbers, hence bit-identical results.
//!
//! Ray path: origin uniform in the scene pixel, direction through a point of the paraxial entrance pupil
//! ([`crate::rays::object_ray`], or the system's real ray aiming), traced by the f64 kernel
//! ([`crate::tracer::kernel`]) directly when the backend is the analytic tracer (same numbers as
//! [`crate::tracer::AnalyticTracer`], without building batches), or through any [`Tracer`] in batches of one
//! scene row. Each arrived ray deposits weight 1/N bilinearly at its landing point (detector pixel centres at
//! integer coordinates); weights falling off the detector are lost and counted.
use super::detector::Detector;
use super::sampling::{RaySampler, SampleRow};
use crate::analysis::MappingCube;
use crate::error::Result;
use crate::rays::{aimed_ray, object_ray, PupilAim, RayBatch};
use crate::spec::RayAiming;
use crate::system::{MaskSurface, SequentialSystem};
use crate::tracer::kernel::trace_step;
use crate::tracer::kernel::trace_steps;
use crate::tracer::{RayStatus, Tracer};
use glam::DVec3;

/// One scene pixel's deposit on the detector: a `w × h` window at (x0, y0); its weights are
/// `weights[start .. start + w·h]`, row-major.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Footprint {
    pub pixel: u32,
    pub x0: u16,
    pub y0: u16,
    pub w: u16,
    pub h: u16,
    pub start: u32,
}

fn is_zero_u64(v: &u64) -> bool {
    *v == 0
}

/// Ray counts of a plane (or a whole render).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct RayStats {
    pub traced: u64,
    /// Reached the image surface.
    pub arrived: u64,
    /// Stopped early, by status: missed, vignetted, TIR, no convergence, invalid input, absorbed, bounce limit.
    pub missed: u64,
    pub vignetted: u64,
    pub tir: u64,
    pub no_convergence: u64,
    pub invalid_input: u64,
    /// Non-sequential backends only: absorbed by a mechanical wall, or over the bounce limit.
    pub absorbed: u64,
    pub bounce_limit: u64,
    /// Arrived at a non-finite or implausible position ([`RayStatus::OutOfRange`]).
    pub out_of_range: u64,
    /// A grating order that does not propagate ([`RayStatus::Evanescent`]); written only when non-zero.
    #[serde(skip_serializing_if = "is_zero_u64")]
    pub evanescent: u64,
    /// Arrived, but blocked by the coded-mask surface (transmission 0 where the ray crossed it; dual-disperser
    /// systems only); not counted in `arrived`. Written only when non-zero.
    #[serde(skip_serializing_if = "is_zero_u64")]
    pub masked: u64,
    /// Splat weight (in rays; behind a coded-mask surface, in rays times its transmission) that fell off the detector.
    pub off_detector: f64,
}

impl RayStats {
    pub fn add(&mut self, o: &RayStats) {
        self.traced += o.traced;
        self.arrived += o.arrived;
        self.missed += o.missed;
        self.vignetted += o.vignetted;
        self.tir += o.tir;
        self.no_convergence += o.no_convergence;
        self.invalid_input += o.invalid_input;
        self.absorbed += o.absorbed;
        self.bounce_limit += o.bounce_limit;
        self.out_of_range += o.out_of_range;
        self.evanescent += o.evanescent;
        self.masked += o.masked;
        self.off_detector += o.off_detector;
    }
    pub(crate) fn count(&mut self, s: RayStatus) {
        match s {
            RayStatus::Ok => self.arrived += 1,
            RayStatus::Missed => self.missed += 1,
            RayStatus::Vignetted => self.vignetted += 1,
            RayStatus::TotalInternalReflection => self.tir += 1,
            RayStatus::NoConvergence => self.no_convergence += 1,
            RayStatus::InvalidInput => self.invalid_input += 1,
            RayStatus::Absorbed => self.absorbed += 1,
            RayStatus::BounceLimit => self.bounce_limit += 1,
            RayStatus::OutOfRange => self.out_of_range += 1,
            RayStatus::Evanescent => self.evanescent += 1,
        }
    }
    /// Fraction of the traced rays that reached the detector.
    pub fn transmission(&self) -> f64 {
        if self.traced == 0 {
            0.0
        } else {
            (self.arrived as f64 - self.off_detector) / self.traced as f64
        }
    }
}

/// The footprints of every open pixel at one plane.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PlaneTransport {
    pub footprints: Vec<Footprint>,
    pub weights: Vec<f32>,
    pub stats: RayStats,
}

impl PlaneTransport {
    /// Heap bytes held.
    pub fn bytes(&self) -> usize {
        self.footprints.capacity() * std::mem::size_of::<Footprint>() + self.weights.capacity() * 4
    }

    /// Weighted centre of footprint `f`'s deposit (detector pixels: column, row), `None` if it carries no weight.
    pub fn centroid_px(&self, f: &Footprint) -> Option<(f64, f64)> {
        let (mut s, mut sx, mut sy) = (0.0f64, 0.0f64, 0.0f64);
        let mut k = f.start as usize;
        for r in 0..f.h as usize {
            for c in 0..f.w as usize {
                let wgt = self.weights[k] as f64;
                s += wgt;
                sx += wgt * (f.x0 as usize + c) as f64;
                sy += wgt * (f.y0 as usize + r) as f64;
                k += 1;
            }
        }
        (s > 0.0).then(|| (sx / s, sy / s))
    }

    /// Bounding box of the footprint windows (empty when no ray arrived).
    pub fn support(&self) -> super::convolve::Rect {
        let mut r = super::convolve::Rect::default();
        for f in &self.footprints {
            r = r.union(&super::convolve::Rect { y0: f.y0 as usize, y1: f.y0 as usize + f.h as usize, x0: f.x0 as usize, x1: f.x0 as usize + f.w as usize });
        }
        r
    }

    /// [`PlaneTransport::apply`] into an image of layout `lay` (the same sums in the same order:
    /// bit-identical), with the common 3- and 4-wide window rows unrolled.
    pub fn apply_padded(&self, values: &[f32], image: &mut [f32], lay: &super::convolve::PaddedLayout) {
        assert_eq!(image.len(), lay.len());
        for f in &self.footprints {
            let v = values[f.pixel as usize];
            if v == 0.0 {
                continue;
            }
            let (w, h) = (f.w as usize, f.h as usize);
            let ws = &self.weights[f.start as usize..f.start as usize + w * h];
            let base = lay.index(f.x0 as usize, f.y0 as usize);
            match w {
                3 => rows::<3>(ws, v, image, base, lay.stride),
                4 => rows::<4>(ws, v, image, base, lay.stride),
                _ => {
                    for (r, wr) in ws.chunks_exact(w.max(1)).enumerate() {
                        let o = base + r * lay.stride;
                        for (a, b) in image[o..o + w].iter_mut().zip(wr) {
                            *a += v * *b;
                        }
                    }
                }
            }
        }
    }

    /// Add Σ value(pixel)·footprint(pixel) to `image` (detector-sized, row-major), in footprint order.
    pub fn apply(&self, values: &[f32], image: &mut [f32], detector_width: usize) {
        for f in &self.footprints {
            let v = values[f.pixel as usize];
            if v == 0.0 {
                continue;
            }
            let (w, h) = (f.w as usize, f.h as usize);
            let mut s = f.start as usize;
            for r in 0..h {
                let o = (f.y0 as usize + r) * detector_width + f.x0 as usize;
                for (a, b) in image[o..o + w].iter_mut().zip(&self.weights[s..s + w]) {
                    *a += v * *b;
                }
                s += w;
            }
        }
    }
}

/// image[base + r·stride + c] += v·w[r][c] for the rows of a W-wide window.
#[inline(always)]
fn rows<const W: usize>(ws: &[f32], v: f32, image: &mut [f32], base: usize, stride: usize) {
    for (r, wr) in ws.chunks_exact(W).enumerate() {
        let o = base + r * stride;
        let px: &mut [f32; W] = (&mut image[o..o + W]).try_into().expect("W-wide row");
        for c in 0..W {
            px[c] += v * wr[c];
        }
    }
}

/// Everything fixed while tracing one plane.
#[derive(Clone)]
pub struct PlaneContext<'a> {
    pub system: &'a SequentialSystem,
    pub tracer: &'a dyn Tracer,
    /// Trace with the f64 kernel directly (only valid for the analytic backend).
    pub direct_kernel: bool,
    /// On the direct path: the lane kernel at this level ([`crate::tracer::simd`]), or the scalar kernel
    /// 8 rays interleaved (`None`). Both give the same numbers.
    pub simd: Option<crate::tracer::SimdLevel>,
    /// The lane kernel's float precision (f32 only with a SIMD level; checked by the renderer).
    pub precision: crate::tracer::Precision,
    pub detector: &'a Detector,
    pub scene_height: usize,
    pub scene_width: usize,
    pub scene_pitch_mm: f64,
    /// Mask transmission per scene pixel; pixels at 0 are not traced (all 1 when the mask is a surface).
    pub mask: &'a [f32],
    /// The coded mask on a surface inside the system (dual-disperser CASSI), or `None`.
    pub surface_mask: Option<SurfaceMask<'a>>,
    pub sampler: &'a RaySampler,
    pub seed: u64,
    /// The caller's stop request, polled before each scene row ([`crate::cancel`]); `None`: never stopped.
    pub cancel: Option<&'a crate::cancel::Cancel>,
}

/// The coded mask on a surface of the system: where it is ([`MaskSurface`]) and its pattern (`height`×`width`,
/// row-major). Each ray is weighted by the transmission where it crosses the surface ([`MaskSurface::transmission`]).
#[derive(Clone, Copy, Debug)]
pub struct SurfaceMask<'a> {
    pub surface: MaskSurface,
    pub values: &'a [f32],
    pub height: usize,
    pub width: usize,
}

impl SurfaceMask<'_> {
    #[inline]
    fn weight(&self, x: f64, y: f64) -> f64 {
        self.surface.transmission(self.values, self.height, self.width, x, y)
    }
}

/// Scratch buffers reused across the rows of a plane (no allocation per pixel or ray).
#[derive(Default)]
struct Scratch {
    /// Open columns of the current row, and their pixel indices.
    open: Vec<usize>,
    pixels: Vec<u64>,
    samples: SampleRow,
    /// Object-space rays of the current row (direct-kernel path), structure of arrays; origins at z = 0.
    rays: RowRays,
    batch: RayBatch,
    /// Where each ray of the current row landed.
    land: Landings,
    window: Vec<f64>,
}

/// Landings of a row's rays on the detector, as bilinear-splat cells: whether the ray arrived, the cell
/// (column `j`, row `i`: `floor` of the continuous pixel coordinates, as `f64::floor(..) as i64` gives it)
/// and the fractions (`fu`, `fv`) inside it.
#[derive(Default)]
struct Landings {
    arrived: Vec<bool>,
    /// Per ray, the coded-mask surface's transmission where the ray crossed it (empty without a mask surface).
    weight: Vec<f64>,
    j: Vec<i64>,
    i: Vec<i64>,
    fu: Vec<f64>,
    fv: Vec<f64>,
}

impl Landings {
    fn clear(&mut self) {
        self.arrived.clear();
        self.weight.clear();
        self.j.clear();
        self.i.clear();
        self.fu.clear();
        self.fv.clear();
    }
    /// Append a landing at continuous pixel coordinates (u, v) (NaN: none).
    #[inline]
    fn push(&mut self, (u, v): (f64, f64)) {
        let (j, i) = (floor(u), floor(v));
        self.arrived.push(!u.is_nan());
        self.j.push(j as i64);
        self.i.push(i as i64);
        self.fu.push(u - j);
        self.fv.push(v - i);
    }
}

/// The landings of one traced block of lanes (the first `m` are rays): [`landing`]'s classification and
/// detector coordinates and [`Landings::push`]'s cells, for all lanes at once (vectorised, dispatched).
struct LandLoop<'a> {
    b: &'a crate::tracer::simd::Block,
    m: usize,
    det: &'a Detector,
    land: &'a mut Landings,
    /// Arrived and out of range, counted over the `m` rays.
    counts: &'a mut [u64; 2],
}

impl super::vector::VectorLoop for LandLoop<'_> {
    #[inline(always)]
    fn run(self) {
        use crate::tracer::simd::LANES;
        let b = self.b;
        let (mut ok, mut j, mut i, mut fu, mut fv) = ([false; LANES], [0i64; LANES], [0i64; LANES], [0.0; LANES], [0.0; LANES]);
        let (mut fjs, mut fis) = ([0.0; LANES], [0.0; LANES]);
        let (mut arrived, mut out_of_range, mut large) = (0u64, 0u64, false);
        for k in 0..LANES {
            let (p, d) = ((b.p.x.0[k], b.p.y.0[k], b.p.z.0[k]), (b.d.x.0[k], b.d.y.0[k], b.d.z.0[k]));
            let finite = p.0.is_finite() & p.1.is_finite() & p.2.is_finite() & d.0.is_finite() & d.1.is_finite() & d.2.is_finite();
            let plausible = finite & (p.0.abs().max(p.1.abs().max(p.2.abs())) <= crate::limits::MAX_IMAGE_COORD_MM);
            ok[k] = b.alive.0[k] & plausible;
            let (u, v) = self.det.to_pixel(p.0, p.1);
            let (u, v) = if ok[k] { (u, v) } else { (f64::NAN, f64::NAN) };
            let (fj, fi) = (floor(u), floor(v));
            (fjs[k], fis[k], fu[k], fv[k]) = (fj, fi, u - fj, v - fi);
            // The integer of an integral |x| < 2⁵¹ is in the low bits of x + 1.5·2⁵² (no conversion
            // instruction, vectorises); larger values are converted below, as `as i64` does.
            (j[k], i[k]) = (int_bits(fj), int_bits(fi));
            large |= ok[k] & !(fj.abs() < TWO51 && fi.abs() < TWO51);
            let live = k < self.m;
            arrived += (live & ok[k]) as u64;
            out_of_range += (live & b.alive.0[k] & !ok[k]) as u64;
        }
        if large {
            for k in 0..LANES {
                (j[k], i[k]) = (fjs[k] as i64, fis[k] as i64);
            }
        }
        let (m, land) = (self.m, self.land);
        land.arrived.extend_from_slice(&ok[..m]);
        land.j.extend_from_slice(&j[..m]);
        land.i.extend_from_slice(&i[..m]);
        land.fu.extend_from_slice(&fu[..m]);
        land.fv.extend_from_slice(&fv[..m]);
        self.counts[0] += arrived;
        self.counts[1] += out_of_range;
    }
}

/// A row's object-space rays, structure of arrays (origin (ox, oy, 0), direction d of any length).
#[derive(Default)]
struct RowRays {
    ox: Vec<f64>,
    oy: Vec<f64>,
    dx: Vec<f64>,
    dy: Vec<f64>,
    dz: Vec<f64>,
}

impl RowRays {
    fn resize(&mut self, n: usize) {
        for v in [&mut self.ox, &mut self.oy, &mut self.dx, &mut self.dy, &mut self.dz] {
            v.resize(n, 0.0);
        }
    }
    fn ray(&self, t: usize) -> (DVec3, DVec3) {
        (DVec3::new(self.ox[t], self.oy[t], 0.0), DVec3::new(self.dx[t], self.dy[t], self.dz[t]))
    }
}

/// The vectorised ray generation of a row (ray aiming off): [`PlaneContext::ray`]'s numbers, i.e.
/// [`object_ray`] of the sample's field point — the field from the pixel centre and the sample's
/// position, the direction from [`PupilAim`].
struct RayLoop<'a> {
    samples: &'a SampleRow,
    /// Scene-pixel centre x (mm) per ray; y is the row's.
    centre_x: &'a [f64],
    centre_y: f64,
    pitch_mm: f64,
    aim: PupilAim,
    out: &'a mut RowRays,
}

impl super::vector::VectorLoop for RayLoop<'_> {
    #[inline(always)]
    fn run(self) {
        let o = self.out;
        super::sampling::object_rays::<false>(self.samples, self.centre_x, self.centre_y, self.pitch_mm, self.aim, &mut o.ox, &mut o.oy, &mut o.dx, &mut o.dy, &mut o.dz);
    }
}

/// `x.floor()`, bit for bit, in plain arithmetic (so it inlines and vectorises: the baseline x86-64 target
/// has no rounding instruction and `f64::floor` is a libm call there). For |x| < 2⁵², |x| + 2⁵² − 2⁵² rounds
/// |x| to an integer (round-to-nearest), which is then signed and stepped down if above x; larger |x|,
/// infinities and NaN are their own floor. Signed zeros come out as libm's (floor(−0) = −0).
#[inline(always)]
fn floor(x: f64) -> f64 {
    const TWO52: f64 = 4_503_599_627_370_496.0;
    let a = x.abs();
    let r = ((a + TWO52) - TWO52).copysign(x);
    let r = if r > x { r - 1.0 } else { r };
    if a < TWO52 {
        r
    } else {
        x
    }
}

/// 2⁵¹: below it in magnitude, [`int_bits`] converts integral values.
const TWO51: f64 = 2_251_799_813_685_248.0;

/// `x as i64` for integral x with |x| < 2⁵¹ (other values give garbage): x + 1.5·2⁵² lies in [2⁵², 2⁵³),
/// where the f64 spacing is 1, so the sum is exact and its mantissa bits are 2⁵¹ + x.
#[inline(always)]
pub(super) fn int_bits(x: f64) -> i64 {
    const MAGIC: f64 = 6_755_399_441_055_744.0; // 1.5 · 2⁵²
    (x + MAGIC).to_bits() as i64 - MAGIC.to_bits() as i64
}

/// Landing of one traced ray: detector (column, row), or NaN, counted in `stats` — the classification of
/// `TracedBatch::classify_out_of_range`: an absurd landing is counted, never splatted.
#[inline]
fn landing(det: &Detector, stats: &mut RayStats, res: std::result::Result<(DVec3, DVec3), (RayStatus, usize)>) -> (f64, f64) {
    match res {
        Ok((p, d)) if !(p.is_finite() && d.is_finite() && p.abs().max_element() <= crate::limits::MAX_IMAGE_COORD_MM) => {
            stats.count(RayStatus::OutOfRange);
            (f64::NAN, f64::NAN)
        }
        Ok((p, _)) => {
            stats.count(RayStatus::Ok);
            det.to_pixel(p.x, p.y)
        }
        Err((st, _)) => {
            stats.count(st);
            (f64::NAN, f64::NAN)
        }
    }
}

/// Rays traced side by side: the CPU overlaps their independent dependency chains (sqrt/division latency
/// dominates a single ray), about doubling throughput over one ray at a time.
const LANES: usize = 8;

/// Trace `rays` (object frame, any length) with the f64 kernel, `LANES` at a time step by step, and
/// report each outcome in order. Per ray the arithmetic is exactly [`trace_steps`]'s (same normalisation
/// and input checks as [`crate::tracer::AnalyticTracer`]), so results are bit-identical to it.
pub(crate) fn trace_interleaved(path: &[crate::system::PathStep], n: &[f64], rays: &[(DVec3, DVec3)], mut emit: impl FnMut(std::result::Result<(DVec3, DVec3), (RayStatus, usize)>)) {
    for chunk in rays.chunks(LANES) {
        let mut p = [DVec3::ZERO; LANES];
        let mut d = [DVec3::Z; LANES];
        let mut state: [Option<(RayStatus, usize)>; LANES] = [Some((RayStatus::InvalidInput, 0)); LANES];
        for (k, &(o, dir)) in chunk.iter().enumerate() {
            let len = dir.length();
            if o.is_finite() && dir.is_finite() && len > 0.0 {
                p[k] = o;
                d[k] = dir / len;
                state[k] = None;
            }
        }
        for step in path {
            for k in 0..LANES {
                if state[k].is_none() {
                    match trace_step(step, n, p[k], d[k]) {
                        Ok((a, b)) => {
                            p[k] = a;
                            d[k] = b;
                        }
                        Err(e) => state[k] = Some(e),
                    }
                }
            }
        }
        for k in 0..chunk.len() {
            emit(match state[k] {
                None => Ok((p[k], d[k])),
                Some(e) => Err(e),
            });
        }
    }
}

/// [`trace_interleaved`] through a coded-mask surface, one ray at a time: the same input checks and per-ray
/// arithmetic, the path split after the mask's step; `emit` gets each outcome and the mask's transmission
/// where the ray crossed it (0 for a ray that stopped before it).
pub(crate) fn trace_through_mask(path: &[crate::system::PathStep], n: &[f64], mask: &SurfaceMask<'_>, rays: &[(DVec3, DVec3)], mut emit: impl FnMut(std::result::Result<(DVec3, DVec3), (RayStatus, usize)>, f64)) {
    let (arm1, arm2) = path.split_at(mask.surface.step + 1);
    for &(o, dir) in rays {
        let len = dir.length();
        let mut weight = 0.0;
        let res = if o.is_finite() && dir.is_finite() && len > 0.0 {
            trace_steps(arm1, n, o, dir / len).and_then(|(p, d)| {
                weight = mask.weight(p.x, p.y);
                trace_steps(arm2, n, p, d)
            })
        } else {
            Err((RayStatus::InvalidInput, 0))
        };
        emit(res, weight);
    }
}

impl PlaneContext<'_> {
    /// Object-space ray of sample `s` = [px, py, sx, sy] of scene pixel (row, col).
    #[inline]
    pub(crate) fn ray(&self, n: &[f64], row: usize, col: usize, s: &[f64; 4]) -> Result<(DVec3, DVec3)> {
        let field = MappingCube::sample_xy(self.scene_height, self.scene_width, self.scene_pitch_mm, row, col, s[2], s[3]);
        if self.system.spec.ray_aiming == RayAiming::Off {
            Ok(object_ray(self.system, field, s[0], s[1]))
        } else {
            aimed_ray(self.system, n, field, s[0], s[1])
        }
    }

    /// Trace plane `plane` at `wavelength_nm` and build its footprints.
    pub fn trace_plane(&self, plane: usize, wavelength_nm: f64) -> Result<PlaneTransport> {
        let n = self.system.indices(wavelength_nm)?;
        if self.surface_mask.is_some() {
            if !self.direct_kernel {
                return Err(crate::error::Error::invalid(format!(
                    "system `{}` holds its coded mask on a surface (dual-disperser CASSI): it renders through the analytic backend's direct path only (not {}{})",
                    self.system.name(),
                    self.tracer.name(),
                    if self.tracer.name() == "analytic-f64" { ", batched" } else { "" }
                )));
            }
            if self.precision == crate::tracer::Precision::F32 {
                return Err(crate::error::Error::invalid(format!("system `{}` holds its coded mask on a surface: --precision f32 does not model it yet; render in f64", self.system.name())));
            }
        }
        let nr = self.sampler.rays;
        let mut out = PlaneTransport::default();
        let mut sc = Scratch::default();
        let (h, w) = (self.scene_height, self.scene_width);
        // The lane loop aims from object points on a finite object plane; an object at infinity (parallel rays
        // of field angles) takes `object_ray` per sample.
        let aim = (self.system.spec.ray_aiming == RayAiming::Off && !self.system.object_at_infinity()).then(|| PupilAim::of(self.system));
        let mut centre_x: Vec<f64> = Vec::new();
        for row in 0..h {
            crate::cancel::check(self.cancel)?;
            sc.open.clear();
            sc.open.extend((0..w).filter(|&c| self.mask[row * w + c] > 0.0));
            if sc.open.is_empty() {
                continue;
            }
            sc.pixels.clear();
            sc.pixels.extend(sc.open.iter().map(|&c| (row * w + c) as u64));
            self.sampler.fill_pixels(self.seed, plane as u64, &sc.pixels, &mut sc.samples);
            let count = sc.samples.len();
            sc.land.clear();
            if self.direct_kernel {
                sc.rays.resize(count);
                match aim {
                    Some(aim) => {
                        centre_x.clear();
                        for &col in &sc.open {
                            let c = MappingCube::scene_xy(h, w, self.scene_pitch_mm, row, col);
                            centre_x.resize(centre_x.len() + nr, c[0]);
                        }
                        let centre_y = MappingCube::scene_xy(h, w, self.scene_pitch_mm, row, 0)[1];
                        super::vector::run_at(self.sampler_level(), RayLoop { samples: &sc.samples, centre_x: &centre_x, centre_y, pitch_mm: self.scene_pitch_mm, aim, out: &mut sc.rays });
                    }
                    None => {
                        for (t, col) in sc.open.iter().flat_map(|&c| std::iter::repeat(c).take(nr)).enumerate() {
                            let (o, d) = self.ray(&n, row, col, &sc.samples.get(t))?;
                            (sc.rays.ox[t], sc.rays.oy[t], sc.rays.dx[t], sc.rays.dy[t], sc.rays.dz[t]) = (o.x, o.y, d.x, d.y, d.z);
                            debug_assert_eq!(o.z, 0.0);
                        }
                    }
                }
                out.stats.traced += count as u64;
                match self.simd {
                    Some(level) => self.trace_row_lanes(level, &n, &sc.rays, count, &mut out.stats, &mut sc.land),
                    None => {
                        let rays: Vec<(DVec3, DVec3)> = (0..count).map(|t| sc.rays.ray(t)).collect();
                        let (stats, det, land) = (&mut out.stats, self.detector, &mut sc.land);
                        match self.surface_mask {
                            None => trace_interleaved(&self.system.path, &n, &rays, |res| land.push(landing(det, stats, res))),
                            Some(sm) => trace_through_mask(&self.system.path, &n, &sm, &rays, |res, w| {
                                land.weight.push(w);
                                land.push(landing(det, stats, res));
                            }),
                        }
                    }
                }
                if self.surface_mask.is_some() {
                    // A ray the mask blocks (transmission 0) deposits nothing: counted apart, not as arrived.
                    let land = &mut sc.land;
                    for t in 0..count {
                        if land.arrived[t] && land.weight[t] == 0.0 {
                            land.arrived[t] = false;
                            out.stats.arrived -= 1;
                            out.stats.masked += 1;
                        }
                    }
                }
            } else {
                sc.batch = RayBatch::with_capacity(count);
                for (t, col) in sc.open.iter().flat_map(|&c| std::iter::repeat(c).take(nr)).enumerate() {
                    let (o, d) = self.ray(&n, row, col, &sc.samples.get(t))?;
                    sc.batch.push(o, d, wavelength_nm);
                }
                let t = self.tracer.trace(self.system, &sc.batch)?;
                for i in 0..t.len() {
                    out.stats.traced += 1;
                    out.stats.count(t.status[i]);
                    sc.land.push(if t.status[i] == RayStatus::Ok { self.detector.to_pixel(t.x[i], t.y[i]) } else { (f64::NAN, f64::NAN) });
                }
            }
            for (k, &col) in sc.open.iter().enumerate() {
                self.footprint((row * w + col) as u32, &sc.land, k * nr..(k + 1) * nr, &mut sc.window, &mut out);
            }
        }
        Ok(out)
    }

    /// The instruction set of the render's vectorised loops (any level gives the same numbers).
    fn sampler_level(&self) -> crate::tracer::SimdLevel {
        self.simd.unwrap_or_else(crate::tracer::SimdLevel::detect)
    }

    /// Trace the first `count` rays of `rays` with the lane kernel at `level`, [`LANES`](crate::tracer::simd::LANES)
    /// at a time loaded straight from the arrays, and append their landings: `trace_rays` and [`landing`]'s
    /// numbers, computed for all lanes at once and selected.
    #[allow(clippy::too_many_arguments)]
    fn trace_row_lanes(&self, level: crate::tracer::SimdLevel, n: &[f64], rays: &RowRays, count: usize, stats: &mut RayStats, land: &mut Landings) {
        if self.precision == crate::tracer::Precision::F32 {
            return self.trace_row_lanes_f32(level, n, rays, count, stats, land);
        }
        use crate::tracer::simd::{Block, LANES};
        let tables = [n; LANES];
        let det = self.detector;
        let mut start = 0;
        while start < count {
            let m = (count - start).min(LANES);
            let r = start..start + m;
            let mut b = Block::default();
            b.p.x.0[..m].copy_from_slice(&rays.ox[r.clone()]);
            b.p.y.0[..m].copy_from_slice(&rays.oy[r.clone()]);
            b.d.x.0[..m].copy_from_slice(&rays.dx[r.clone()]);
            b.d.y.0[..m].copy_from_slice(&rays.dy[r.clone()]);
            b.d.z.0[..m].copy_from_slice(&rays.dz[r]);
            b.alive.0[..m].fill(true);
            match self.surface_mask {
                None => crate::tracer::simd::trace_block_raw(level, &self.system.path, &tables, &mut b),
                Some(sm) => {
                    // To the mask surface, read its transmission where each ray crosses it (the lanes'
                    // positions are in its local frame there), then on to the detector.
                    let (arm1, arm2) = self.system.path.split_at(sm.surface.step + 1);
                    crate::tracer::simd::trace_block_raw(level, arm1, &tables, &mut b);
                    for k in 0..m {
                        land.weight.push(if b.alive.0[k] { sm.weight(b.p.x.0[k], b.p.y.0[k]) } else { 0.0 });
                    }
                    crate::tracer::simd::trace_block(level, arm2, &tables, &mut b);
                }
            }
            let mut counts = [0u64; 2];
            super::vector::run_at(level, LandLoop { b: &b, m, det, land, counts: &mut counts });
            stats.arrived += counts[0];
            stats.out_of_range += counts[1];
            for k in 0..m {
                if let (false, Err((st, _))) = (b.alive.0[k], b.result(k)) {
                    stats.count(st);
                }
            }
            start += m;
        }
    }

    /// [`Self::trace_row_lanes`] in f32 (`--precision f32`): [`LANES_F32`](crate::tracer::simd::LANES_F32)
    /// rays per block loaded with `set_raw` (rounded to f32, checked and normalised as
    /// [`crate::tracer::AnalyticF32Tracer`] does), traced in f32, then widened to f64 blocks of [`LANES`](crate::tracer::simd::LANES) and
    /// classified by the same landing loop as the f64 path.
    #[allow(clippy::too_many_arguments)]
    fn trace_row_lanes_f32(&self, level: crate::tracer::SimdLevel, n: &[f64], rays: &RowRays, count: usize, stats: &mut RayStats, land: &mut Landings) {
        use crate::tracer::simd::{Block, BlockF32, Real, LANES, LANES_F32};
        let tables = [n; LANES_F32];
        let det = self.detector;
        let mut start = 0;
        while start < count {
            let m = (count - start).min(LANES_F32);
            let mut b = BlockF32::default();
            for k in 0..m {
                let (o, d) = rays.ray(start + k);
                b.set_raw(k, o, d);
            }
            crate::tracer::simd::trace_block_raw(level, &self.system.path, &tables, &mut b);
            for half in 0..LANES_F32 / LANES {
                let lo = half * LANES;
                if lo >= m {
                    break;
                }
                let mh = (m - lo).min(LANES);
                let mut w = Block::default();
                for k in 0..LANES {
                    let s = lo + k;
                    (w.p.x.0[k], w.p.y.0[k], w.p.z.0[k]) = (b.p.x.0[s].to_f64(), b.p.y.0[s].to_f64(), b.p.z.0[s].to_f64());
                    (w.d.x.0[k], w.d.y.0[k], w.d.z.0[k]) = (b.d.x.0[s].to_f64(), b.d.y.0[s].to_f64(), b.d.z.0[s].to_f64());
                    (w.alive.0[k], w.status[k], w.surface[k]) = (b.alive.0[s], b.status[s], b.surface[s]);
                }
                let mut counts = [0u64; 2];
                super::vector::run_at(level, LandLoop { b: &w, m: mh, det, land, counts: &mut counts });
                stats.arrived += counts[0];
                stats.out_of_range += counts[1];
                for k in 0..mh {
                    if let (false, Err((st, _))) = (w.alive.0[k], w.result(k)) {
                        stats.count(st);
                    }
                }
            }
            start += m;
        }
    }

    /// Bilinear splat of one pixel's landings (`rays` of `land`, weight 1/N each) into a window; append it
    /// to `out`. Each window cell sums its taps in ray order, in f64, then is scaled by 1/N and stored as f32.
    fn footprint(&self, pixel: u32, land: &Landings, rays: std::ops::Range<usize>, window: &mut Vec<f64>, out: &mut PlaneTransport) {
        let (dw, dh) = (self.detector.width as i64, self.detector.height as i64);
        // Each ray's weight: the coded-mask surface's transmission where it crossed it (1 without one; x·1 = x
        // exactly, so the single-disperser footprints keep their bits).
        let lw = (!land.weight.is_empty()).then(|| &land.weight[rays.clone()]);
        let (la, lj, li, lfu, lfv) = (&land.arrived[rays.clone()], &land.j[rays.clone()], &land.i[rays.clone()], &land.fu[rays.clone()], &land.fv[rays]);
        let (mut x0, mut x1, mut y0, mut y1) = (i64::MAX, i64::MIN, i64::MAX, i64::MIN);
        let mut arrived = 0usize;
        for ((&j, &i), _) in lj.iter().zip(li).zip(la).filter(|(_, &a)| a) {
            arrived += 1;
            x0 = x0.min(j);
            x1 = x1.max(j + 1);
            y0 = y0.min(i);
            y1 = y1.max(i + 1);
        }
        if x0 > x1 {
            return; // no ray arrived
        }
        let weight = 1.0 / lj.len() as f64;
        // Clip the window to the detector; taps outside are lost.
        let (cx0, cx1, cy0, cy1) = (x0.max(0), x1.min(dw - 1), y0.max(0), y1.min(dh - 1));
        if cx0 > cx1 || cy0 > cy1 {
            out.stats.off_detector += match lw {
                None => arrived as f64,
                Some(w) => (0..la.len()).filter(|&t| la[t]).map(|t| w[t]).sum(),
            };
            return;
        }
        let (ww, wh) = ((cx1 - cx0 + 1) as usize, (cy1 - cy0 + 1) as usize);
        window.clear();
        window.resize(ww * wh, 0.0);
        let cells = (0..la.len()).filter(|&t| la[t]).map(|t| (lj[t], li[t], lfu[t], lfv[t], lw.map_or(1.0, |w| w[t])));
        if (cx0, cx1, cy0, cy1) == (x0, x1, y0, y1) {
            // Inside the detector: every tap lands in the window (j + 1 ≤ x1, i + 1 ≤ y1), nothing is lost.
            for (j, i, fu, fv, w) in cells {
                let o = (i - y0) as usize * ww + (j - x0) as usize;
                let taps = &mut window[o..o + ww + 2];
                let (wi0, wi1, wj0, wj1) = (1.0 - fv, fv, 1.0 - fu, fu);
                taps[0] += wi0 * wj0 * w;
                taps[1] += wi0 * wj1 * w;
                taps[ww] += wi1 * wj0 * w;
                taps[ww + 1] += wi1 * wj1 * w;
            }
        } else {
            let mut lost = 0.0;
            for (j, i, fu, fv, w) in cells {
                for (di, wi) in [(0, 1.0 - fv), (1, fv)] {
                    for (dj, wj) in [(0, 1.0 - fu), (1, fu)] {
                        let (r, c) = (i + di, j + dj);
                        let tap = wi * wj * w;
                        if r < cy0 || r > cy1 || c < cx0 || c > cx1 {
                            lost += tap;
                        } else {
                            window[(r - cy0) as usize * ww + (c - cx0) as usize] += tap;
                        }
                    }
                }
            }
            out.stats.off_detector += lost;
        }
        let start = out.weights.len() as u32;
        out.weights.extend(window.iter().map(|&t| (t * weight) as f32));
        out.footprints.push(Footprint { pixel, x0: cx0 as u16, y0: cy0 as u16, w: ww as u16, h: wh as u16, start });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn arithmetic_floor_is_libm_floor_bit_for_bit() {
        let mut xs = vec![0.0, -0.0, 0.5, -0.5, 1.0, -1.0, 1.5, -1.5, 2.5, -2.5, 1e-300, -1e-300, 5e-324, -5e-324, 2.0f64.powi(52), -(2.0f64.powi(52)), 2.0f64.powi(52) - 0.5, -(2.0f64.powi(52)) + 0.5, 2.0f64.powi(51) + 0.5, -(2.0f64.powi(51)) - 0.5, 1e19, -1e19, 1e300, -1e300, f64::MAX, f64::MIN, f64::INFINITY, f64::NEG_INFINITY];
        let mut x: f64 = 1e-3;
        while x < 1e7 {
            for y in [x, -x, x.next_up(), x.next_down(), -x.next_up(), (x.round()).next_down(), -(x.round()).next_down(), x.round()] {
                xs.push(y);
            }
            x *= 1.37;
        }
        for i in -3000..3000 {
            xs.push(i as f64 * 0.173);
        }
        for x in xs {
            assert_eq!(floor(x).to_bits(), x.floor().to_bits(), "{x}");
            assert_eq!(floor(x) as i64, x.floor() as i64, "{x}");
        }
        assert!(floor(f64::NAN).is_nan());
    }

    #[test]
    fn int_bits_is_the_conversion_below_two_to_the_51() {
        for x in [0.0, -0.0, 1.0, -1.0, 2.0, -3.0, 1e6, -1e6, 65535.0, -65536.0, TWO51 - 1.0, -(TWO51 - 1.0), 123456789012.0, -98765432109.0] {
            assert_eq!(int_bits(x), x as i64, "{x}");
        }
        for k in -100_000i64..100_000 {
            assert_eq!(int_bits(k as f64 * 37.0), k * 37);
        }
    }
}
