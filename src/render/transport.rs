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
use super::sampling::RaySampler;
use crate::analysis::MappingCube;
use crate::error::Result;
use crate::rays::{aimed_ray, object_ray, RayBatch};
use crate::spec::RayAiming;
use crate::system::SequentialSystem;
use crate::tracer::kernel::trace_step;
#[allow(unused_imports)]
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
    /// Splat weight (in rays) that fell off the detector.
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
        self.off_detector += o.off_detector;
    }
    fn count(&mut self, s: RayStatus) {
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

/// Everything fixed while tracing one plane.
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
    /// Mask transmission per scene pixel; pixels at 0 are not traced.
    pub mask: &'a [f32],
    pub sampler: &'a RaySampler,
    pub seed: u64,
}

/// Scratch buffers reused across the pixels of a plane (no allocation per ray).
#[derive(Default)]
struct Scratch {
    samples: Vec<[f64; 4]>,
    window: Vec<f64>,
    batch: RayBatch,
    /// Landing (column, row) detector coordinates per ray of the current row, NaN when not arrived.
    land: Vec<(f64, f64)>,
    /// Object-space rays of the current row (direct-kernel path).
    rays: Vec<(DVec3, DVec3)>,
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

impl PlaneContext<'_> {
    /// Object-space ray of sample `s` = [px, py, sx, sy] of scene pixel (row, col).
    #[inline]
    fn ray(&self, n: &[f64], row: usize, col: usize, s: &[f64; 4]) -> Result<(DVec3, DVec3)> {
        let c = MappingCube::scene_xy(self.scene_height, self.scene_width, self.scene_pitch_mm, row, col);
        let field = [c[0] + (s[2] - 0.5) * self.scene_pitch_mm, c[1] - (s[3] - 0.5) * self.scene_pitch_mm];
        if self.system.spec.ray_aiming == RayAiming::Off {
            Ok(object_ray(self.system, field, s[0], s[1]))
        } else {
            aimed_ray(self.system, n, field, s[0], s[1])
        }
    }

    /// Trace plane `plane` at `wavelength_nm` and build its footprints.
    pub fn trace_plane(&self, plane: usize, wavelength_nm: f64) -> Result<PlaneTransport> {
        let n = self.system.indices(wavelength_nm)?;
        let nr = self.sampler.rays;
        let mut out = PlaneTransport::default();
        let mut sc = Scratch { samples: vec![[0.0; 4]; nr], ..Default::default() };
        let (h, w) = (self.scene_height, self.scene_width);
        let mut open: Vec<usize> = Vec::with_capacity(w);
        for row in 0..h {
            open.clear();
            open.extend((0..w).filter(|&c| self.mask[row * w + c] > 0.0));
            if open.is_empty() {
                continue;
            }
            sc.land.clear();
            if self.direct_kernel {
                sc.rays.clear();
                for &col in &open {
                    let q = row * w + col;
                    self.sampler.fill(self.seed, plane as u64, q as u64, &mut sc.samples);
                    for s in &sc.samples {
                        sc.rays.push(self.ray(&n, row, col, s)?);
                    }
                }
                out.stats.traced += sc.rays.len() as u64;
                let (stats, det, land) = (&mut out.stats, self.detector, &mut sc.land);
                let emit = |res: std::result::Result<(DVec3, DVec3), (RayStatus, usize)>| match res {
                    // Same classification as `TracedBatch::classify_out_of_range`: an absurd landing is
                    // counted, never splatted (its pixel index would overflow).
                    Ok((p, d)) if !(p.is_finite() && d.is_finite() && p.abs().max_element() <= crate::limits::MAX_IMAGE_COORD_MM) => {
                        stats.count(RayStatus::OutOfRange);
                        land.push((f64::NAN, f64::NAN));
                    }
                    Ok((p, _)) => {
                        stats.count(RayStatus::Ok);
                        land.push(det.to_pixel(p.x, p.y));
                    }
                    Err((st, _)) => {
                        stats.count(st);
                        land.push((f64::NAN, f64::NAN));
                    }
                };
                match self.simd {
                    Some(level) => crate::tracer::simd::trace_rays_at(self.precision, level, &self.system.path, &n, &sc.rays, emit),
                    None => trace_interleaved(&self.system.path, &n, &sc.rays, emit),
                }
            } else {
                sc.batch = RayBatch::with_capacity(open.len() * nr);
                for &col in &open {
                    self.sampler.fill(self.seed, plane as u64, (row * w + col) as u64, &mut sc.samples);
                    for s in &sc.samples {
                        let (o, d) = self.ray(&n, row, col, s)?;
                        sc.batch.push(o, d, wavelength_nm);
                    }
                }
                let t = self.tracer.trace(self.system, &sc.batch)?;
                for i in 0..t.len() {
                    out.stats.traced += 1;
                    out.stats.count(t.status[i]);
                    sc.land.push(if t.status[i] == RayStatus::Ok { self.detector.to_pixel(t.x[i], t.y[i]) } else { (f64::NAN, f64::NAN) });
                }
            }
            for (k, &col) in open.iter().enumerate() {
                let land = &sc.land[k * nr..(k + 1) * nr];
                self.footprint((row * w + col) as u32, land, &mut sc.window, &mut out);
            }
        }
        Ok(out)
    }

    /// Bilinear splat of one pixel's landings (weight 1/N each) into a window; append it to `out`.
    fn footprint(&self, pixel: u32, land: &[(f64, f64)], window: &mut Vec<f64>, out: &mut PlaneTransport) {
        let (dw, dh) = (self.detector.width as i64, self.detector.height as i64);
        let (mut x0, mut x1, mut y0, mut y1) = (i64::MAX, i64::MIN, i64::MAX, i64::MIN);
        for &(u, v) in land {
            if u.is_nan() {
                continue;
            }
            let (j, i) = (u.floor() as i64, v.floor() as i64);
            x0 = x0.min(j);
            x1 = x1.max(j + 1);
            y0 = y0.min(i);
            y1 = y1.max(i + 1);
        }
        if x0 > x1 {
            return; // no ray arrived
        }
        let weight = 1.0 / land.len() as f64;
        // Clip the window to the detector; taps outside are lost.
        let (cx0, cx1, cy0, cy1) = (x0.max(0), x1.min(dw - 1), y0.max(0), y1.min(dh - 1));
        if cx0 > cx1 || cy0 > cy1 {
            out.stats.off_detector += land.iter().filter(|l| !l.0.is_nan()).count() as f64;
            return;
        }
        let (ww, wh) = ((cx1 - cx0 + 1) as usize, (cy1 - cy0 + 1) as usize);
        window.clear();
        window.resize(ww * wh, 0.0);
        let mut lost = 0.0;
        for &(u, v) in land {
            if u.is_nan() {
                continue;
            }
            let (j, i) = (u.floor(), v.floor());
            let (fu, fv) = (u - j, v - i);
            let (j, i) = (j as i64, i as i64);
            for (di, wi) in [(0, 1.0 - fv), (1, fv)] {
                for (dj, wj) in [(0, 1.0 - fu), (1, fu)] {
                    let (r, c) = (i + di, j + dj);
                    let tap = wi * wj;
                    if r < cy0 || r > cy1 || c < cx0 || c > cx1 {
                        lost += tap;
                    } else {
                        window[(r - cy0) as usize * ww + (c - cx0) as usize] += tap;
                    }
                }
            }
        }
        out.stats.off_detector += lost;
        let start = out.weights.len() as u32;
        out.weights.extend(window.iter().map(|&t| (t * weight) as f32));
        out.footprints.push(Footprint { pixel, x0: cx0 as u16, y0: cy0 as u16, w: ww as u16, h: wh as u16, start });
    }
}
