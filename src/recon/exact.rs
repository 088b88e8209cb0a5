//! The `exact` operator: the renderer's own light transport as a linear map Φ from an H×W×B cube (the
//! scene's B bands at their wavelengths) to the detector image — the same numbers
//! [`Renderer::render`] computes, so that a model-based reconstruction inverts exactly the image formation
//! that produced the acquisition (same system, configuration and seed: the oracle; another seed: the same
//! optics with independent Monte-Carlo noise).
//!
//! Forward model, per render plane p at λ_p (K planes, [`crate::render::SpectralSampling`]):
//!
//! 1. bands → plane: x_p(q) = (1 − t_p)·x(q, k_p) + t_p·x(q, k_p + 1), with (k_p, t_p) from
//!    [`SpectralCube::interpolation`] (linear in λ, constant extrapolation) — [`SpectralCube::plane`];
//! 2. mask: c_p(q) = M(q)·x_p(q);
//! 3. transport: i_p = T_p c_p, T_p the plane's footprints ([`PlaneTransport::apply`], traced by
//!    [`Renderer::trace_plane`] with the renderer's seed);
//! 4. diffraction: b_p = A_p ∗ i_p, A_p the plane's Airy kernel ([`AiryKernel::convolve`], zero outside);
//! 5. sum: y = Σ_p w·b_p, w = B/K the plane weight.
//!
//! Adjoint (exact, term by term): z_p = A_pᵀ y is the *correlation* with the kernel restricted to the
//! detector (the transpose of the zero-padded convolution, written out tap by tap; no kernel symmetry is
//! assumed), g_p = T_pᵀ z_p gathers each footprint's window, then mask and plane weight, and the
//! interpolation transpose scatters g_p into bands k_p (weight 1 − t_p) and k_p + 1 (weight t_p).
//!
//! Memory: the transport of all planes is kept when it fits `memory_budget_bytes` (the CLI's
//! `--transport-memory-gb`); otherwise nothing is kept and every apply/adjoint re-traces the planes on the
//! fly (slow, identical numbers: tracing is deterministic). Parallelism: planes are split into
//! [`PLANE_CHUNKS`] fixed chunks (independent of the thread count), each chunk summed in plane order in f64,
//! the chunks reduced in chunk order; so results do not depend on the number of threads.
//!
//! Speed: the Airy blur dominates (81 taps × 112 planes at the paper's settings). It runs row by row as
//! saxpys over contiguous slices (vectorised), and only over each plane's support (the bounding box of its
//! footprints, dilated by the kernel) — the exact same per-pixel sums as [`AiryKernel::convolve`].
//!
//! ```
//! use diffcassi::prelude::*;
//! use diffcassi::recon::{exact::ExactOperator, Operator};
//! use diffcassi::render::{Mask, RenderConfig, Renderer, SpectralSampling};
//! use diffcassi::scene::SpectralCube;
//! let system = SequentialSystem::build(&presets::spec("ap")?)?;
//! let tracer = AnalyticTracer::default();
//! let mut cfg = RenderConfig::paper(8);
//! cfg.spectral = SpectralSampling::new(vec![500.0, 520.0, 540.0], 2)?;
//! cfg.rays_per_pixel = 4;
//! let renderer = Renderer::new(&system, &tracer, cfg, Mask::random(8, 8, 0.5, 1)?)?;
//! let scene = SpectralCube::uniform(8, 8, vec![500.0, 520.0, 540.0], 1.0);
//! let reference = renderer.render(&scene, false, &|_| {})?;
//! let phi = ExactOperator::new(renderer, &scene.wavelengths_nm, 1 << 30)?;
//! let y = (&phi as &dyn Operator).apply(&scene.data)?;
//! let peak = reference.image.iter().cloned().fold(0.0, f64::max);
//! assert!(y.iter().zip(&reference.image).all(|(a, b)| (*a as f64 - b).abs() <= 1e-6 * peak));
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::layout::{from_band_major_into, to_band_major};
use super::operator::{CubeShape, ImageShape, Operator};
use crate::error::Result;
use crate::render::{AiryKernel, PlaneTransport, Renderer};
use crate::scene::SpectralCube;
use rayon::prelude::*;
use std::borrow::Cow;

/// Planes are processed in this many fixed chunks (their f64 partial images are reduced in chunk order).
pub const PLANE_CHUNKS: usize = 8;

/// A half-open pixel rectangle on the detector: rows `y0..y1`, columns `x0..x1`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Rect {
    pub y0: usize,
    pub y1: usize,
    pub x0: usize,
    pub x1: usize,
}

impl Rect {
    fn is_empty(&self) -> bool {
        self.y0 >= self.y1 || self.x0 >= self.x1
    }
}

/// Bounding box of a plane's footprint windows (empty when no ray arrived).
pub fn transport_support(t: &PlaneTransport) -> Rect {
    let mut r = Rect { y0: usize::MAX, y1: 0, x0: usize::MAX, x1: 0 };
    for f in &t.footprints {
        r.y0 = r.y0.min(f.y0 as usize);
        r.x0 = r.x0.min(f.x0 as usize);
        r.y1 = r.y1.max(f.y0 as usize + f.h as usize);
        r.x1 = r.x1.max(f.x0 as usize + f.w as usize);
    }
    if r.is_empty() {
        Rect { y0: 0, y1: 0, x0: 0, x1: 0 }
    } else {
        r
    }
}

/// out += A ∗ src on a `width × height` image whose non-zero values all lie in `support` (zero outside the
/// image). Per output pixel the taps are summed in the kernel's row-major order, exactly as
/// [`AiryKernel::convolve`] (zero terms skipped), so the result is bit-identical to it. Returns the
/// rectangle of `out` written.
pub fn convolve_support(k: &AiryKernel, src: &[f32], out: &mut [f32], width: usize, height: usize, support: Rect) -> Rect {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2 (checked just above).
        return unsafe { convolve_support_avx2(k, src, out, width, height, support) };
    }
    convolve_support_body(k, src, out, width, height, support)
}

/// [`convolve_support`] compiled for AVX2 (8-lane saxpys). Multiplies and adds stay separate (no FMA
/// contraction), so every lane computes the same IEEE operations as the scalar/SSE2 build: bit-identical.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn convolve_support_avx2(k: &AiryKernel, src: &[f32], out: &mut [f32], width: usize, height: usize, support: Rect) -> Rect {
    convolve_support_body(k, src, out, width, height, support)
}

#[inline(always)]
fn convolve_support_body(k: &AiryKernel, src: &[f32], out: &mut [f32], width: usize, height: usize, support: Rect) -> Rect {
    if support.is_empty() {
        return support;
    }
    let n = 2 * k.half + 1;
    let h = k.half;
    let oy0 = support.y0.saturating_sub(h);
    let oy1 = (support.y1 + h).min(height);
    let ox0 = support.x0.saturating_sub(h);
    let ox1 = (support.x1 + h).min(width);
    for y in oy0..oy1 {
        let orow = &mut out[y * width..(y + 1) * width];
        for ki in 0..n {
            // out[y][x] += w · src[y − dy][x − dx], dy = ki − h
            let sy = y as isize - ki as isize + h as isize;
            if sy < support.y0 as isize || sy >= support.y1 as isize {
                continue;
            }
            let srow = &src[sy as usize * width..(sy as usize + 1) * width];
            for kj in 0..n {
                let wgt = k.weights[ki * n + kj];
                if wgt == 0.0 {
                    continue;
                }
                let dx = kj as isize - h as isize;
                let x0 = (support.x0 as isize + dx).max(0) as usize;
                let x1 = (support.x1 as isize + dx).min(width as isize);
                if x1 <= x0 as isize {
                    continue;
                }
                let x1 = x1 as usize;
                let s0 = (x0 as isize - dx) as usize;
                for (a, b) in orow[x0..x1].iter_mut().zip(&srow[s0..s0 + (x1 - x0)]) {
                    *a += wgt * *b;
                }
            }
        }
    }
    Rect { y0: oy0, y1: oy1, x0: ox0, x1: ox1 }
}

/// out[s] += Σ_taps w(ki, kj)·y[s + (dy, dx)] for s in `target` (the transpose of [`convolve_support`]'s
/// zero-padded convolution, evaluated only on `target`): the correlation with the kernel, terms outside the
/// image dropped.
pub fn correlate_support(k: &AiryKernel, y: &[f32], out: &mut [f32], width: usize, height: usize, target: Rect) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2 (checked just above).
        return unsafe { correlate_support_avx2(k, y, out, width, height, target) };
    }
    correlate_support_body(k, y, out, width, height, target)
}

/// [`correlate_support`] compiled for AVX2 (no FMA: bit-identical to the portable build).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn correlate_support_avx2(k: &AiryKernel, y: &[f32], out: &mut [f32], width: usize, height: usize, target: Rect) {
    correlate_support_body(k, y, out, width, height, target)
}

#[inline(always)]
fn correlate_support_body(k: &AiryKernel, y: &[f32], out: &mut [f32], width: usize, height: usize, target: Rect) {
    if target.is_empty() {
        return;
    }
    let n = 2 * k.half + 1;
    let h = k.half as isize;
    for sy in target.y0..target.y1 {
        let orow = &mut out[sy * width..(sy + 1) * width];
        for ki in 0..n {
            let yy = sy as isize + ki as isize - h;
            if yy < 0 || yy >= height as isize {
                continue;
            }
            let yrow = &y[yy as usize * width..(yy as usize + 1) * width];
            for kj in 0..n {
                let wgt = k.weights[ki * n + kj];
                if wgt == 0.0 {
                    continue;
                }
                let dx = kj as isize - h;
                // s + dx must lie in [0, width)
                let x0 = (target.x0 as isize).max(-dx) as usize;
                let x1 = (target.x1 as isize).min(width as isize - dx);
                if x1 <= x0 as isize {
                    continue;
                }
                let x1 = x1 as usize;
                let s0 = (x0 as isize + dx) as usize;
                for (a, b) in orow[x0..x1].iter_mut().zip(&yrow[s0..s0 + (x1 - x0)]) {
                    *a += wgt * *b;
                }
            }
        }
    }
}

/// T c: add Σ value(pixel)·footprint(pixel) to `image`, in footprint order — the same sums in the same order
/// as [`PlaneTransport::apply`] (bit-identical), with the common 4-wide windows unrolled.
pub fn transport_scatter(t: &PlaneTransport, values: &[f32], image: &mut [f32], detector_width: usize) {
    for f in &t.footprints {
        let v = values[f.pixel as usize];
        if v == 0.0 {
            continue;
        }
        let (w, h) = (f.w as usize, f.h as usize);
        if w == 0 {
            continue;
        }
        let ws = &t.weights[f.start as usize..f.start as usize + w * h];
        let base = f.y0 as usize * detector_width + f.x0 as usize;
        if w == 4 {
            for (r, wr) in ws.chunks_exact(4).enumerate() {
                let o = base + r * detector_width;
                let row: &mut [f32; 4] = (&mut image[o..o + 4]).try_into().expect("4-wide window");
                for c in 0..4 {
                    row[c] += v * wr[c];
                }
            }
        } else {
            for (r, wr) in ws.chunks_exact(w).enumerate() {
                let o = base + r * detector_width;
                for (a, b) in image[o..o + w].iter_mut().zip(wr) {
                    *a += v * *b;
                }
            }
        }
    }
}

/// Tᵀ z: each footprint's window of `z` weighted by the footprint's splat weights, written to
/// `values[pixel]` (pixels without a footprint are left untouched).
pub fn transport_gather(t: &PlaneTransport, z: &[f32], values: &mut [f32], detector_width: usize) {
    for f in &t.footprints {
        let (w, h) = (f.w as usize, f.h as usize);
        let mut s = f.start as usize;
        let mut acc = 0.0f32;
        for r in 0..h {
            let o = (f.y0 as usize + r) * detector_width + f.x0 as usize;
            for (a, b) in z[o..o + w].iter().zip(&t.weights[s..s + w]) {
                acc += *a * *b;
            }
            s += w;
        }
        values[f.pixel as usize] = acc;
    }
}

/// Per plane of `renderer`: (lower band, upper band, weight of the upper band) of the cube bands `bands_nm`
/// (validated exactly as a scene's would be).
fn interpolation_table(renderer: &Renderer<'_>, bands_nm: &[f64]) -> Result<Vec<(usize, usize, f32)>> {
    let probe = SpectralCube::new(1, 1, bands_nm.to_vec(), vec![0.0; bands_nm.len()], "exact operator bands")?;
    let nb = bands_nm.len();
    Ok(renderer
        .config
        .spectral
        .planes_nm
        .iter()
        .map(|&w| {
            let (k, t) = probe.interpolation(w);
            (k, (k + 1).min(nb - 1), t as f32)
        })
        .collect())
}

/// The renderer as a linear operator (see the [module docs](self)).
pub struct ExactOperator<'a> {
    renderer: Renderer<'a>,
    bands_nm: Vec<f64>,
    /// Per plane: lower band k, upper band min(k + 1, B − 1), weight t of the upper band (f32, as
    /// [`SpectralCube::plane`] uses it).
    interp: Vec<(usize, usize, f32)>,
    /// Every plane's transport, or `None` when it did not fit the budget (re-traced on the fly).
    transport: Option<Vec<PlaneTransport>>,
    /// Support of each kept plane (empty when streaming).
    supports: Vec<Rect>,
    transport_bytes: usize,
}

impl<'a> ExactOperator<'a> {
    /// Build Φ from a renderer (system, tracer, configuration, mask, seed) for cubes whose bands sit at
    /// `bands_nm` (strictly increasing). Traces the middle plane to estimate the transport's size (×K ×1.25);
    /// when that fits `memory_budget_bytes`, traces and keeps every plane (and still streams if the real
    /// size exceeds the budget); otherwise keeps nothing and traces planes at each apply/adjoint.
    ///
    /// The operator borrows the system and tracer through the renderer (`'a`); bindings that need an owned
    /// operator can leak both (`Box::leak`) for `'static`.
    pub fn new(renderer: Renderer<'a>, bands_nm: &[f64], memory_budget_bytes: u64) -> Result<Self> {
        Self::with_progress(renderer, bands_nm, memory_budget_bytes, &|_| {})
    }

    /// [`ExactOperator::new`] reporting traced rays to `progress` (for a progress bar; the total is
    /// [`Renderer::rays_per_render`]).
    pub fn with_progress(renderer: Renderer<'a>, bands_nm: &[f64], memory_budget_bytes: u64, progress: &(dyn Fn(u64) + Sync)) -> Result<Self> {
        let interp = interpolation_table(&renderer, bands_nm)?;
        let planes = renderer.config.spectral.planes();
        // Probe the memory with the middle plane, then trace all planes (in parallel) if they should fit.
        let middle = renderer.trace_plane(planes / 2)?;
        let estimate = middle.bytes() as f64 * planes as f64 * 1.25;
        drop(middle);
        let (transport, supports, bytes) = if estimate <= memory_budget_bytes as f64 {
            let all = renderer.trace_all(progress)?;
            let bytes: usize = all.iter().map(|t| t.bytes()).sum();
            let supports = all.iter().map(transport_support).collect();
            if bytes as u64 <= memory_budget_bytes {
                (Some(all), supports, bytes)
            } else {
                (None, Vec::new(), 0)
            }
        } else {
            // Streaming: every plane is traced at each use (its support computed then). Trace each once
            // now (in parallel, each dropped at once), so a plane that cannot be traced is an error here, not mid-solve.
            (0..planes).into_par_iter().try_for_each(|p| renderer.trace_plane(p).map(|t| progress(t.stats.traced)))?;
            (None, Vec::new(), 0)
        };
        Ok(ExactOperator { renderer, bands_nm: bands_nm.to_vec(), interp, transport, supports, transport_bytes: bytes })
    }

    pub fn renderer(&self) -> &Renderer<'a> {
        &self.renderer
    }

    pub fn bands_nm(&self) -> &[f64] {
        &self.bands_nm
    }

    /// `true` when the transport is re-traced at every apply/adjoint (it did not fit the budget).
    pub fn is_streaming(&self) -> bool {
        self.transport.is_none()
    }

    /// Heap bytes of the kept transport (0 when streaming).
    pub fn transport_bytes(&self) -> usize {
        self.transport_bytes
    }

    /// Plane p's transport and its support (kept, or traced now).
    fn plane_transport(&self, p: usize) -> (Cow<'_, PlaneTransport>, Rect) {
        match &self.transport {
            Some(t) => (Cow::Borrowed(&t[p]), self.supports[p]),
            None => {
                // Every plane traced successfully at construction with the same inputs, and tracing is
                // deterministic: this cannot fail.
                let t = self.renderer.trace_plane(p).expect("re-tracing a plane of a validated renderer");
                let r = transport_support(&t);
                (Cow::Owned(t), r)
            }
        }
    }

    fn chunks(&self) -> Vec<std::ops::Range<usize>> {
        let p = self.interp.len();
        (0..PLANE_CHUNKS).map(|c| c * p / PLANE_CHUNKS..(c + 1) * p / PLANE_CHUNKS).filter(|r| !r.is_empty()).collect()
    }
}

impl Operator for ExactOperator<'_> {
    fn name(&self) -> &str {
        "exact"
    }

    fn cube_shape(&self) -> CubeShape {
        CubeShape { height: self.renderer.config.scene_height, width: self.renderer.config.scene_width, bands: self.bands_nm.len() }
    }

    fn image_shape(&self) -> ImageShape {
        ImageShape { height: self.renderer.detector.height, width: self.renderer.detector.width }
    }

    fn apply_into(&self, cube: &[f32], image: &mut [f32]) {
        let cs = self.cube_shape();
        let npix = cs.height * cs.width;
        let det = self.renderer.detector;
        let (dw, dh) = (det.width, det.height);
        let weight = self.renderer.config.spectral.plane_weight;
        let mask = &self.renderer.mask.values;
        let bm = to_band_major(cube, npix, cs.bands);
        let partial: Vec<Vec<f64>> = self
            .chunks()
            .into_par_iter()
            .map(|range| {
                let mut acc = vec![0.0f64; dw * dh];
                let mut values = vec![0.0f32; npix];
                let mut img = vec![0.0f32; dw * dh];
                let mut blurred = vec![0.0f32; dw * dh];
                for p in range {
                    let (k, k1, t) = self.interp[p];
                    // 1–2: the plane of the scene (SpectralCube::plane), masked, in the renderer's arithmetic.
                    let (xa, xb) = (&bm[k * npix..(k + 1) * npix], &bm[k1 * npix..(k1 + 1) * npix]);
                    for (((v, a), b), m) in values.iter_mut().zip(xa).zip(xb).zip(mask) {
                        *v = ((1.0 - t) * *a + t * *b) * *m;
                    }
                    // 3: transport.
                    let (tr, sup) = self.plane_transport(p);
                    transport_scatter(&tr, &values, &mut img, dw);
                    // 4: Airy blur over the support; 5: weighted sum.
                    let (src, rect) = match &self.renderer.kernels[p] {
                        Some(kern) => {
                            let r = convolve_support(kern, &img, &mut blurred, dw, dh, sup);
                            (&mut blurred, r)
                        }
                        None => (&mut img, sup),
                    };
                    for y in rect.y0..rect.y1 {
                        let o = y * dw;
                        for (a, b) in acc[o + rect.x0..o + rect.x1].iter_mut().zip(&mut src[o + rect.x0..o + rect.x1]) {
                            *a += weight * *b as f64;
                            *b = 0.0;
                        }
                    }
                    if self.renderer.kernels[p].is_some() {
                        for y in sup.y0..sup.y1 {
                            img[y * dw + sup.x0..y * dw + sup.x1].iter_mut().for_each(|v| *v = 0.0);
                        }
                    }
                }
                acc
            })
            .collect();
        image.par_chunks_mut(dw.max(1)).enumerate().for_each(|(y, row)| {
            for (x, v) in row.iter_mut().enumerate() {
                let mut s = 0.0f64;
                for part in &partial {
                    s += part[y * dw + x];
                }
                *v = s as f32;
            }
        });
    }

    fn adjoint_into(&self, image: &[f32], cube: &mut [f32]) {
        let cs = self.cube_shape();
        let npix = cs.height * cs.width;
        let det = self.renderer.detector;
        let (dw, dh) = (det.width, det.height);
        let weight = self.renderer.config.spectral.plane_weight as f32;
        let mask = &self.renderer.mask.values;
        let planes = self.interp.len();
        // g_p = w · M ⊙ T_pᵀ A_pᵀ y, one scene-sized image per plane.
        let mut gathered = vec![0.0f32; planes * npix];
        let chunks = self.chunks();
        let mut slices: Vec<&mut [f32]> = Vec::with_capacity(chunks.len());
        let mut rest = gathered.as_mut_slice();
        for r in &chunks {
            let (a, b) = rest.split_at_mut(r.len() * npix);
            slices.push(a);
            rest = b;
        }
        chunks.into_par_iter().zip(slices).for_each(|(range, out)| {
            let mut z = vec![0.0f32; dw * dh];
            for (i, p) in range.enumerate() {
                let g = &mut out[i * npix..(i + 1) * npix];
                let (tr, sup) = self.plane_transport(p);
                match &self.renderer.kernels[p] {
                    Some(kern) => {
                        correlate_support(kern, image, &mut z, dw, dh, sup);
                        transport_gather(&tr, &z, g, dw);
                        for y in sup.y0..sup.y1 {
                            z[y * dw + sup.x0..y * dw + sup.x1].iter_mut().for_each(|v| *v = 0.0);
                        }
                    }
                    None => transport_gather(&tr, image, g, dw),
                }
                for (v, m) in g.iter_mut().zip(mask) {
                    *v *= weight * *m;
                }
            }
        });
        // Interpolation transpose, band by band, planes in order.
        let mut bm = vec![0.0f32; npix * cs.bands];
        bm.par_chunks_mut(npix.max(1)).enumerate().for_each(|(b, band)| {
            for (p, &(k, k1, t)) in self.interp.iter().enumerate() {
                let g = &gathered[p * npix..(p + 1) * npix];
                if k == b {
                    let s = 1.0 - t;
                    band.iter_mut().zip(g).for_each(|(a, v)| *a += s * *v);
                }
                if k1 == b {
                    band.iter_mut().zip(g).for_each(|(a, v)| *a += t * *v);
                }
            }
        });
        from_band_major_into(&bm, npix, cs.bands, cube);
    }
}

/// Building Φ from a transport traced beforehand (the Python `Transport`: one trace serves both the
/// bit-exact dataset-mode render and the operator).
impl<'a> ExactOperator<'a> {
    /// Φ from `transport` = `renderer.trace_all(..)` of this very renderer (not traced again; kept whatever
    /// its size).
    pub fn from_traced(renderer: Renderer<'a>, bands_nm: &[f64], transport: Vec<PlaneTransport>) -> Result<Self> {
        if transport.len() != renderer.config.spectral.planes() {
            return Err(crate::error::Error::invalid(format!("exact operator: {} traced planes for a render of {}", transport.len(), renderer.config.spectral.planes())));
        }
        let interp = interpolation_table(&renderer, bands_nm)?;
        let supports = transport.iter().map(transport_support).collect();
        let bytes = transport.iter().map(|t| t.bytes()).sum();
        Ok(ExactOperator { renderer, bands_nm: bands_nm.to_vec(), interp, transport: Some(transport), supports, transport_bytes: bytes })
    }

    /// Per plane: (lower band k, upper band min(k + 1, B − 1), weight t of the upper band) of the
    /// bands → planes interpolation (the sparse export reads it).
    pub fn interpolation(&self) -> &[(usize, usize, f32)] {
        &self.interp
    }

    /// The kept transport, one entry per plane (`None` when streaming).
    pub fn transport(&self) -> Option<&[PlaneTransport]> {
        self.transport.as_deref()
    }
}
