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
//! Memory: every plane's transport is kept, re-laid as four-wide pieces with the mask folded in
//! ([`CompactPlane`], ≈ the footprints' own size), when it fits `memory_budget_bytes` (the CLI's
//! `--transport-memory-gb`); otherwise nothing is kept and every apply/adjoint re-traces the planes on the
//! fly (slow, identical numbers: tracing and the re-layout are deterministic). Parallelism: planes are
//! split into [`PLANE_CHUNKS`] fixed chunks (independent of the thread count), each chunk summed in plane
//! order in f64 (adjoint: per band, in f32), the chunks reduced in chunk order; so results do not depend
//! on the number of threads.
//!
//! Speed: per plane, the interpolation between the two bands is fused into the scatter (and its transpose
//! into the gather, which adds straight into the bands); the Airy blur runs register-blocked over the
//! plane's support only ([`crate::render::convolve`], AVX-512/AVX2/portable, bit-identical across paths)
//! and adds each output tile to the chunk's f64 image at once. Scratch buffers are kept between calls.
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
use super::compact::CompactPlane;
use super::layout::to_band_major_into;
use super::operator::{CubeShape, ImageShape, Operator};
use crate::error::Result;
use crate::render::convolve::{convolve, correlate, PaddedLayout, TILE};
use crate::render::{PlaneTransport, Renderer};
use crate::scene::SpectralCube;
use rayon::prelude::*;
use std::borrow::Cow;
use std::sync::Mutex;

pub use crate::render::convolve::Rect;

/// Planes are processed in this many fixed chunks (their f64 partial images are reduced in chunk order).
pub const PLANE_CHUNKS: usize = 8;

/// Bounding box of a plane's footprint windows (empty when no ray arrived).
pub fn transport_support(t: &PlaneTransport) -> Rect {
    t.support()
}

/// Scratch buffers of one chunk (kept between calls).
#[derive(Default)]
struct Scratch {
    /// A plane's image (apply) or its correlation z (adjoint), padded layout.
    img: Vec<f32>,
    /// The chunk's f64 partial image (apply), padded layout.
    acc: Vec<f64>,
    /// The chunk's partial bands (adjoint), band-major over the chunk's band range.
    bands: Vec<f32>,
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
    /// Every plane's transport re-laid for the operator, or `None` when it did not fit the budget
    /// (re-traced on the fly).
    compact: Option<Vec<CompactPlane>>,
    /// The traced transport itself, kept only by [`ExactOperator::from_traced`] (dataset-mode renders).
    transport: Option<Vec<PlaneTransport>>,
    /// Padded layout of the detector images.
    layout: PaddedLayout,
    transport_bytes: usize,
    /// The kept transport registered with the memory budget while the operator lives
    /// ([`crate::limits::hold`]): what is checked later (a twin, the denoiser) counts it.
    _held: crate::limits::Held,
    scratch: Mutex<Vec<Scratch>>,
    buffers: Mutex<Vec<Vec<f32>>>,
}

/// The memory an exact operator holds, estimated from its middle plane before the others are traced
/// (bytes; each "all planes" term is the middle plane's × planes × 1.25, the spread between planes).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TransportMemory {
    /// Every plane's traced footprints ([`PlaneTransport`]): kept by [`ExactOperator::from_traced`] (the
    /// Python `Transport`) and by `render-dataset`'s cache.
    pub footprints: f64,
    /// Every plane re-laid for the operator ([`CompactPlane`]): what [`ExactOperator::new`] keeps.
    pub operator: f64,
    /// The planes traced at once, one per worker thread (at most the plane count), each holding its
    /// footprints and its re-laid copy until it is dropped: at construction, and at every apply/adjoint of
    /// a streaming operator.
    pub in_flight: f64,
    pub planes: usize,
    /// The planes traced at once: the worker threads, at most the plane count.
    pub threads: usize,
}

impl TransportMemory {
    /// The estimate from the middle plane's footprints (`probe`, traced by [`Renderer::trace_plane`]) and
    /// its re-laid copy (bytes).
    pub fn from_probe(footprint_bytes: f64, compact_bytes: f64, planes: usize) -> Self {
        let threads = rayon::current_num_threads().clamp(1, planes.max(1));
        TransportMemory { footprints: footprint_bytes * planes as f64 * 1.25, operator: compact_bytes * planes as f64 * 1.25, in_flight: threads as f64 * (footprint_bytes + compact_bytes), planes, threads }
    }

    /// Trace `renderer`'s middle plane and estimate from it; returns the plane's footprints too (for callers
    /// that keep it).
    pub fn probe(renderer: &Renderer<'_>) -> Result<(Self, PlaneTransport)> {
        let planes = renderer.config.spectral.planes();
        let t = renderer.trace_plane(planes / 2)?;
        let c = CompactPlane::new(&t, renderer.object_mask(), &layout(renderer)).bytes() as f64;
        Ok((Self::from_probe(t.bytes() as f64, c, planes), t))
    }

    /// What [`ExactOperator::new`] holds with a transport budget of `budget_bytes`: the re-laid transport
    /// when it fits that budget (else none: streamed), and the planes in flight.
    pub fn held(&self, budget_bytes: u64) -> f64 {
        self.kept(budget_bytes) + self.in_flight
    }

    /// The re-laid transport [`ExactOperator::new`] keeps with a transport budget of `budget_bytes`.
    pub fn kept(&self, budget_bytes: u64) -> f64 {
        if self.operator <= budget_bytes as f64 {
            self.operator
        } else {
            0.0
        }
    }

    /// Refuse an operator that [`ExactOperator::new`] would build over the memory budget
    /// ([`crate::limits::check_memory`], beside what the process holds already: the render record, another
    /// operator), naming the kept transport, its budget and the footprints in flight.
    pub fn check_new(&self, renderer: &Renderer<'_>, budget_bytes: u64) -> Result<()> {
        let kept = self.kept(budget_bytes);
        let kept_text = if kept > 0.0 {
            format!("{:.3} GB of light transport kept (its budget: {} GB, --transport-memory-gb; 0 keeps none and re-traces the planes at every apply and adjoint, slower, same numbers)", kept / 1e9, budget_bytes as f64 / 1e9)
        } else {
            format!("the light transport re-traced at every apply and adjoint ({:.3} GB would exceed its budget of {} GB, --transport-memory-gb)", self.operator / 1e9, budget_bytes as f64 / 1e9)
        };
        let what = format!("the exact operator of {} ({kept_text}, and {:.3} GB of footprints of the planes traced at once by {} threads, --threads)", transport_label(renderer), self.in_flight / 1e9, self.threads);
        crate::limits::check_memory(&what, self.held(budget_bytes))
    }

    /// Refuse the traced transport that [`ExactOperator::from_traced`] keeps (footprints and the re-laid
    /// copy: the Python `Transport` and `exact`) over the memory budget, before it is traced.
    pub fn check_traced(&self, renderer: &Renderer<'_>) -> Result<()> {
        crate::limits::check_memory(&format!("the light transport of {} (footprints and the operator's copy)", transport_label(renderer)), self.footprints + self.operator)
    }
}

/// "a 512×512 scene × 112 planes × 2 rays", for messages.
fn transport_label(renderer: &Renderer<'_>) -> String {
    let c = &renderer.config;
    format!("a {}×{} scene × {} planes × {} rays", c.scene_height, c.scene_width, c.spectral.planes(), c.rays_per_pixel)
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
    ///
    /// A renderer given a stop request ([`Renderer::with_cancel`]) stops the build at its next scene row once
    /// cancelled ([`crate::Error::Interrupted`]); the operator keeps the renderer without it (its applies are
    /// not the build's, and a streaming operator re-traces planes that must not fail).
    pub fn with_progress(mut renderer: Renderer<'a>, bands_nm: &[f64], memory_budget_bytes: u64, progress: &(dyn Fn(u64) + Sync)) -> Result<Self> {
        let interp = interpolation_table(&renderer, bands_nm)?;
        let layout = layout(&renderer);
        let planes = renderer.config.spectral.planes();
        let mask = renderer.object_mask();
        // Probe the memory with the middle plane, then trace all planes (in parallel, each re-laid and its
        // footprints dropped at once) if they should fit. What the operator will hold (the kept transport and
        // the planes in flight) is checked against the memory budget first, beside what is resident already.
        let (memory, probe) = TransportMemory::probe(&renderer)?;
        drop(probe);
        memory.check_new(&renderer, memory_budget_bytes)?;
        let estimate = memory.operator;
        let compact = if estimate <= memory_budget_bytes as f64 {
            let all: Vec<CompactPlane> = (0..planes)
                .into_par_iter()
                .map(|p| {
                    let t = renderer.trace_plane(p)?;
                    progress(t.stats.traced);
                    Ok(CompactPlane::new(&t, mask, &layout))
                })
                .collect::<Result<_>>()?;
            let bytes: usize = all.iter().map(|c| c.bytes()).sum();
            (bytes as u64 <= memory_budget_bytes).then_some(all)
        } else {
            // Streaming: every plane is traced at each use. Trace each once now (in parallel, each dropped
            // at once), so a plane that cannot be traced is an error here, not mid-solve.
            (0..planes).into_par_iter().try_for_each(|p| renderer.trace_plane(p).map(|t| progress(t.stats.traced)))?;
            None
        };
        let bytes = compact.as_ref().map_or(0, |c| c.iter().map(|p| p.bytes()).sum());
        renderer.take_cancel();
        let _held = hold_transport(&renderer, bytes);
        Ok(ExactOperator { renderer, bands_nm: bands_nm.to_vec(), interp, compact, transport: None, layout, transport_bytes: bytes, _held, scratch: Mutex::default(), buffers: Mutex::default() })
    }

    pub fn renderer(&self) -> &Renderer<'a> {
        &self.renderer
    }

    pub fn bands_nm(&self) -> &[f64] {
        &self.bands_nm
    }

    /// `true` when the transport is re-traced at every apply/adjoint (it did not fit the budget).
    pub fn is_streaming(&self) -> bool {
        self.compact.is_none()
    }

    /// Heap bytes of the kept transport (the operator's layout, plus the footprints when
    /// [`ExactOperator::from_traced`] keeps them; 0 when streaming).
    pub fn transport_bytes(&self) -> usize {
        self.transport_bytes
    }

    /// Plane p's transport (kept, or traced and re-laid now).
    fn plane(&self, p: usize) -> Cow<'_, CompactPlane> {
        match &self.compact {
            Some(c) => Cow::Borrowed(&c[p]),
            None => {
                // Every plane traced successfully at construction with the same inputs, and tracing is
                // deterministic: this cannot fail.
                let t = self.renderer.trace_plane(p).expect("re-tracing a plane of a validated renderer");
                Cow::Owned(CompactPlane::new(&t, self.renderer.object_mask(), &self.layout))
            }
        }
    }

    fn take_scratch(&self) -> Scratch {
        self.scratch.lock().map(|mut v| v.pop()).ok().flatten().unwrap_or_default()
    }

    fn put_scratch(&self, s: Vec<Scratch>) {
        if let Ok(mut v) = self.scratch.lock() {
            v.extend(s);
        }
    }

    fn take_buffer(&self) -> Vec<f32> {
        self.buffers.lock().map(|mut v| v.pop()).ok().flatten().unwrap_or_default()
    }

    fn put_buffer(&self, b: Vec<f32>) {
        if let Ok(mut v) = self.buffers.lock() {
            v.push(b);
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
        let lay = self.layout;
        let dw = lay.width;
        let weight = self.renderer.config.spectral.plane_weight;
        let mut bm_buf = self.take_buffer();
        bm_buf.resize(npix * cs.bands, 0.0);
        to_band_major_into(cube, npix, cs.bands, &mut bm_buf);
        let bm = &bm_buf;
        let parts: Vec<Scratch> = self
            .chunks()
            .into_par_iter()
            .map(|range| {
                let mut s = self.take_scratch();
                s.img.clear();
                s.img.resize(lay.len(), 0.0);
                s.acc.clear();
                s.acc.resize(lay.len(), 0.0);
                let Scratch { img, acc, .. } = &mut s;
                for p in range {
                    let (k, k1, t) = self.interp[p];
                    // 1–3: the plane between bands k and k + 1, masked and transported.
                    let plane = self.plane(p);
                    plane.scatter(&bm[k * npix..(k + 1) * npix], &bm[k1 * npix..(k1 + 1) * npix], t, &lay, img);
                    let sup = plane.support;
                    // 4: Airy blur over the support; 5: weighted sum, tile by tile.
                    match &self.renderer.kernels[p] {
                        Some(kern) => {
                            convolve(kern, img, &lay, sup, &mut |y, x, _valid, tile: &[f32; TILE]| {
                                let o = lay.index(x, y);
                                for (a, v) in acc[o..o + TILE].iter_mut().zip(tile) {
                                    *a += weight * *v as f64;
                                }
                            });
                        }
                        None => {
                            for y in sup.y0..sup.y1 {
                                let (o0, o1) = (lay.index(sup.x0.min(dw), y), lay.index(sup.x1.min(dw), y));
                                for (a, v) in acc[o0..o1].iter_mut().zip(&img[o0..o1]) {
                                    *a += weight * *v as f64;
                                }
                            }
                        }
                    }
                    lay.clear(img, sup);
                }
                s
            })
            .collect();
        image.par_chunks_mut(dw.max(1)).enumerate().for_each(|(y, row)| {
            for (x, v) in row.iter_mut().enumerate() {
                let o = lay.index(x, y);
                let mut s = 0.0f64;
                for part in &parts {
                    s += part.acc[o];
                }
                *v = s as f32;
            }
        });
        self.put_scratch(parts);
        self.put_buffer(bm_buf);
    }

    fn adjoint_into(&self, image: &[f32], cube: &mut [f32]) {
        let cs = self.cube_shape();
        let npix = cs.height * cs.width;
        let nb = cs.bands;
        let lay = self.layout;
        let weight = self.renderer.config.spectral.plane_weight as f32;
        let mut yp_buf = self.take_buffer();
        lay.pad_image(image, &mut yp_buf);
        let yp = &yp_buf;
        let chunks = self.chunks();
        // Bands each chunk's planes touch.
        let band_range = |r: &std::ops::Range<usize>| {
            let lo = self.interp[r.clone()].iter().map(|i| i.0).min().unwrap_or(0);
            let hi = self.interp[r.clone()].iter().map(|i| i.1).max().unwrap_or(0);
            (lo, hi + 1)
        };
        let ranges: Vec<(usize, usize)> = chunks.iter().map(band_range).collect();
        let parts: Vec<Scratch> = chunks
            .into_par_iter()
            .zip(ranges.par_iter())
            .map(|(range, &(b0, b1))| {
                let mut s = self.take_scratch();
                s.img.resize(lay.len(), 0.0);
                s.bands.clear();
                s.bands.resize((b1 - b0) * npix, 0.0);
                let Scratch { img: z, bands, .. } = &mut s;
                for p in range {
                    let (k, k1, t) = self.interp[p];
                    let (ca, cb) = ((1.0 - t) * weight, t * weight);
                    let plane = self.plane(p);
                    // z = A_pᵀ y over the plane's support (every value a piece reads), or y itself.
                    let src: &[f32] = match &self.renderer.kernels[p] {
                        Some(kern) => {
                            correlate(kern, yp, &lay, plane.support, &mut |y, x, _valid, tile: &[f32; TILE]| {
                                let o = lay.index(x, y);
                                z[o..o + TILE].copy_from_slice(tile);
                            });
                            z
                        }
                        None => yp,
                    };
                    // Tᵀ, mask, plane weight and the interpolation transpose, into bands k and k + 1.
                    if k == k1 {
                        plane.gather(src, &lay, ca, cb, &mut bands[(k - b0) * npix..(k - b0 + 1) * npix], None);
                    } else {
                        let (lo, hi) = bands.split_at_mut((k1 - b0) * npix);
                        plane.gather(src, &lay, ca, cb, &mut lo[(k - b0) * npix..(k - b0 + 1) * npix], Some(&mut hi[..npix]));
                    }
                }
                s
            })
            .collect();
        // Chunks in order, per band; written in the cube's [pixel][band] order.
        let per_band: Vec<Vec<(usize, usize)>> = (0..nb).map(|b| ranges.iter().enumerate().filter(|(_, r)| r.0 <= b && b < r.1).map(|(c, r)| (c, (b - r.0) * npix)).collect()).collect();
        const ROW: usize = 1024;
        cube.par_chunks_mut(ROW * nb).enumerate().for_each(|(blk, out)| {
            let q0 = blk * ROW;
            for (i, px) in out.chunks_mut(nb).enumerate() {
                for (b, v) in px.iter_mut().enumerate() {
                    let mut s = 0.0f32;
                    for &(c, o) in &per_band[b] {
                        s += parts[c].bands[o + q0 + i];
                    }
                    *v = s;
                }
            }
        });
        self.put_scratch(parts);
        self.put_buffer(yp_buf);
    }
}

/// Building Φ from a transport traced beforehand (the Python `Transport`: one trace serves both the
/// bit-exact dataset-mode render and the operator).
impl<'a> ExactOperator<'a> {
    /// Φ from `transport` = `renderer.trace_all(..)` of this very renderer (not traced again; kept whatever
    /// its size). The operator keeps the renderer without its stop request ([`Renderer::with_cancel`]).
    pub fn from_traced(mut renderer: Renderer<'a>, bands_nm: &[f64], transport: Vec<PlaneTransport>) -> Result<Self> {
        renderer.take_cancel();
        if transport.len() != renderer.config.spectral.planes() {
            return Err(crate::error::Error::invalid(format!("exact operator: {} traced planes for a render of {}", transport.len(), renderer.config.spectral.planes())));
        }
        let interp = interpolation_table(&renderer, bands_nm)?;
        let layout = layout(&renderer);
        let compact: Vec<CompactPlane> = transport.par_iter().map(|t| CompactPlane::new(t, renderer.object_mask(), &layout)).collect();
        let bytes = transport.iter().map(|t| t.bytes()).sum::<usize>() + compact.iter().map(|c| c.bytes()).sum::<usize>();
        let _held = hold_transport(&renderer, bytes);
        Ok(ExactOperator { renderer, bands_nm: bands_nm.to_vec(), interp, compact: Some(compact), transport: Some(transport), layout, transport_bytes: bytes, _held, scratch: Mutex::default(), buffers: Mutex::default() })
    }

    /// Per plane: (lower band k, upper band min(k + 1, B − 1), weight t of the upper band) of the
    /// bands → planes interpolation (the sparse export reads it).
    pub fn interpolation(&self) -> &[(usize, usize, f32)] {
        &self.interp
    }

    /// The traced transport, one entry per plane — kept only by [`ExactOperator::from_traced`] (`None`
    /// otherwise: [`ExactOperator::new`] keeps only the operator's own layout of it).
    pub fn transport(&self) -> Option<&[PlaneTransport]> {
        self.transport.as_deref()
    }
}

/// Register an operator's kept transport (`bytes`) with the memory budget while it lives.
fn hold_transport(renderer: &Renderer<'_>, bytes: usize) -> crate::limits::Held {
    crate::limits::hold(format!("an exact operator's light transport ({})", transport_label(renderer)), bytes as f64)
}

/// The padded detector layout for `renderer`'s kernels.
fn layout(renderer: &Renderer<'_>) -> PaddedLayout {
    let half = renderer.kernels.iter().flatten().map(|k| k.half).max().unwrap_or(0);
    PaddedLayout::new(renderer.detector.width, renderer.detector.height, half)
}
