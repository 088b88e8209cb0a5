//! The `mapping` operator of the reference paper: the chief-ray mapping cube f(x_s, y_s, λ_b) = (x_d, y_d)
//! ([`crate::analysis::mapping_cube`]: the chief ray of every scene pixel centre at every band) places each
//! band's masked image at its mapped detector positions:
//!
//! y = Σ_b Σ_q M(q)·x(q, b)·δ_{f(q, b)},
//!
//! with δ the deposit at the mapped point: **nearest** — all of it on the pixel containing the point
//! (clamped to the detector, as the initialisation below), or **bilinear** — split over the four nearest
//! pixel centres (taps off the detector dropped). One deposit per band, weight 1: the render's band units
//! (a band of value 1 contributes 1). No spot, no Airy blur, no spectral oversampling: the chief ray only.
//! Pixels whose chief ray does not arrive contribute nothing. The adjoint gathers the same taps.
//!
//! **Support (bilinear).** The operator models only the detector pixels it covers: pixel i is kept when its
//! coverage c_i = Σ_q,b M(q)·w_i(q, b) (the bilinear weight the open mask deposits on it, in full deposits)
//! is at least [`SUPPORT_FRACTION`] of the mean coverage of the pixels it reaches; taps on the other pixels
//! are dropped (their rows of Φ are 0, so the solvers' D = diag(ΦΦᵀ𝟙) leaves them out of the data term, as
//! it does the pixels no voxel reaches). Why: at the edges of the mapped footprint the bilinear split puts
//! slivers of a deposit (down to 2·10⁻⁴ of one) on pixels that, in a real acquisition, also hold light the
//! chief-ray model does not have (spot, Airy blur, oversampling). Fitting such a pixel asks for x = y_i/w on
//! the voxel behind the sliver; the GAP step's 1/d_i amplifies it and accelerated GAP, which accumulates
//! the residual until every kept pixel is fitted, drove those voxels to ±100–290× the peak (issue 22).
//! Nearest deposits whole voxels (c_i ≥ one open deposit wherever it is > 0): no support is applied.
//!
//! **Initialisation** I = A ∘ f, exactly as the paper's code: for each band b and scene pixel q, the
//! acquisition A at the detector pixel holding f(q, b) — positions truncated to integer pixels and clamped to
//! the detector (a nearest-pixel gather; 0 where the chief ray does not arrive). On an aligned system where f
//! is the pure shift (row r, col c) ↦ (r, c + s(b)), I(:, :, b) = A(:, s(b) : W + s(b)).
//!
//! Pixel conventions: [`Detector::to_pixel`] gives continuous (column, row) coordinates with pixel centres at
//! integers; the paper truncates coordinates whose pixel *edges* are integers, i.e. pixel
//! ⌊u + ½⌋ here. Orientation: the paper's tracer has y up while its images have row 0 at the top, so its code
//! flips the acquisition vertically and flips the mapping's y to match. Our detector rows already run top
//! (+y) to bottom like scene rows ([`Detector::to_pixel`] maps y to row (y_top − y)/pitch), so the flip is
//! built in and no further flip is applied: I is upright in scene coordinates for every system (SP's
//! inverted image included, since f itself carries the inversion).
//!
//! ```
//! use diffcassi::prelude::*;
//! use diffcassi::recon::mapping::{MappingInterpolation, MappingOperator};
//! use diffcassi::recon::Operator;
//! use diffcassi::render::{Mask, RenderConfig, Renderer};
//! let system = SequentialSystem::build(&presets::spec("ap")?)?;
//! let tracer = AnalyticTracer::default();
//! let renderer = Renderer::new(&system, &tracer, RenderConfig::paper(8), Mask::random(8, 8, 0.5, 1)?)?;
//! let bands = [480.0, 520.0, 560.0];
//! let phi = MappingOperator::from_renderer(&renderer, &bands, MappingInterpolation::Bilinear)?;
//! let x = vec![1.0f32; 8 * 8 * 3];
//! let open = renderer.mask.values.iter().sum::<f32>();
//! let nearest = MappingOperator::from_renderer(&renderer, &bands, MappingInterpolation::Nearest)?;
//! let y = (&nearest as &dyn Operator).apply(&x)?;
//! assert!((y.iter().sum::<f32>() - 3.0 * open).abs() < 1e-3); // every open pixel's 3 bands arrive
//! let y = (&phi as &dyn Operator).apply(&x)?; // bilinear: the slivers off its support are dropped
//! assert!(y.iter().sum::<f32>() <= 3.0 * open + 1e-3);
//! let init = phi.initialisation(&y)?;
//! assert_eq!(init.len(), 8 * 8 * 3);
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::layout::to_band_major;
use super::operator::{CubeShape, ImageShape, Operator};
use crate::analysis::{mapping_cube, MappingCube};
use crate::error::{Error, Result};
use crate::render::spectral::band_support_weights;
use crate::render::{Detector, Mask, Renderer};
use rayon::prelude::*;

/// How a band's value is deposited at its mapped point.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MappingInterpolation {
    /// On the pixel containing the point (clamped to the detector).
    Nearest,
    /// Bilinearly over the four nearest pixel centres.
    Bilinear,
}

/// Detector pixel (row, col) containing image point (x, y) mm, the paper's way: truncation of the
/// edge-based coordinate (⌊u + ½⌋ in [`Detector::to_pixel`]'s centre-based one), clamped to the detector.
pub fn nearest_pixel(detector: &Detector, x_mm: f64, y_mm: f64) -> (usize, usize) {
    let (u, v) = detector.to_pixel(x_mm, y_mm);
    let clamp = |t: f64, n: usize| -> usize {
        let f = (t + 0.5).floor();
        if f.is_nan() || f < 0.0 {
            0
        } else {
            (f as usize).min(n - 1)
        }
    };
    (clamp(v, detector.height), clamp(u, detector.width))
}

/// One mapped point in continuous pixel coordinates (column u, row v); `nearest` = `INVALID` when the
/// chief ray did not arrive.
#[derive(Clone, Copy, Debug)]
struct Point {
    u: f32,
    v: f32,
    /// Index of the nearest pixel (clamped).
    nearest: u32,
}

const INVALID: u32 = u32::MAX;

/// The bilinear mapping's support: a detector pixel is modelled only when its coverage c_i (the bilinear
/// weight the open mask deposits on it, Σ_q,b M(q)·w_i(q, b), in full deposits) is at least this fraction of
/// the mean coverage of the pixels it reaches (see the [module docs](self), "Support"). Measured on mSP
/// chelsea at 128² (mean coverage 8.3 deposits): accelerated GAP-TV through the mapping with 0 / 0.02 /
/// 0.05 / 0.1 / 0.2: max |x| 288 / 66 / 14.5 / 3.1 / 1.7 (truth peak 0.62), PSNR 13.36 / 13.75 / 13.96 /
/// 14.17 / 14.32 dB (docs/reconstruction.md, "`mapping`").
pub const SUPPORT_FRACTION: f64 = 0.2;

/// The mapping operator (see the [module docs](self)).
pub struct MappingOperator {
    shape: CubeShape,
    image: ImageShape,
    interpolation: MappingInterpolation,
    /// The mask per scene pixel (H·W), or for a dual-disperser system the mask each pixel sees per band,
    /// band-major (B·H·W, the layout of `points`): where the pixel's chief ray crosses the coded-mask surface.
    mask: Vec<f32>,
    /// Band-major `[band][pixel]` mapped points.
    points: Vec<Point>,
    /// Per detector pixel: modelled (bilinear: coverage ≥ [`SUPPORT_FRACTION`] of the mean; nearest: all).
    supported: Vec<bool>,
    /// Per band: its share of an acquisition relative to the mean, [`band_support_weights`] of the mapping's
    /// wavelengths (1 for evenly spaced bands).
    band_weight: Vec<f32>,
}

impl MappingOperator {
    /// From a mapping cube (H×W×B chief-ray positions on the image surface, mm), the detector they land on
    /// and the mask (H×W).
    pub fn new(mapping: &MappingCube, detector: &Detector, mask: &Mask, interpolation: MappingInterpolation) -> Result<Self> {
        let (h, w, nb) = (mapping.height, mapping.width, mapping.wavelength_nm.len());
        if mask.height != h || mask.width != w {
            return Err(Error::invalid(format!("the mask is {}×{} but the mapping cube is {h}×{w}", mask.height, mask.width)));
        }
        if detector.width == 0 || detector.height == 0 || detector.pixels() > u32::MAX as usize - 1 {
            return Err(Error::invalid(format!("detector {}×{}: unusable size", detector.width, detector.height)));
        }
        let npix = h * w;
        let mut points = vec![Point { u: 0.0, v: 0.0, nearest: INVALID }; npix * nb];
        points.par_chunks_mut(npix.max(1)).enumerate().for_each(|(b, band)| {
            for (q, pt) in band.iter_mut().enumerate() {
                if let Some([x, y]) = mapping.get(q / w, q % w, b) {
                    let (u, v) = detector.to_pixel(x, y);
                    let (r, c) = nearest_pixel(detector, x, y);
                    *pt = Point { u: u as f32, v: v as f32, nearest: (r * detector.width + c) as u32 };
                }
            }
        });
        let mut op = MappingOperator {
            shape: CubeShape { height: h, width: w, bands: nb },
            image: ImageShape { height: detector.height, width: detector.width },
            interpolation,
            mask: mask.values.clone(),
            points,
            supported: vec![true; detector.pixels()],
            band_weight: band_support_weights(&mapping.wavelength_nm).iter().map(|&w| w as f32).collect(),
        };
        if interpolation == MappingInterpolation::Bilinear {
            op.supported = op.support();
        }
        Ok(op)
    }

    /// The bilinear support: coverage c_i = Σ_q,b M(q)·w_i(q, b) over every tap (sequential f64 sums in
    /// band/pixel order: deterministic), kept where c_i ≥ [`SUPPORT_FRACTION`]·mean(c_i > 0).
    fn support(&self) -> Vec<bool> {
        let mut cover = vec![0.0f64; self.image.len()];
        for (k, p) in self.points.iter().enumerate() {
            // (k = b·npix + q: the pixel's mask, or the band's for a dual-disperser system.)
            let m = self.mask[k % self.mask.len().max(1)] as f64;
            if m != 0.0 {
                self.raw_taps(p, |i, w| cover[i] += m * w as f64);
            }
        }
        let reached: Vec<f64> = cover.iter().cloned().filter(|&c| c > 0.0).collect();
        let mean = if reached.is_empty() { 0.0 } else { reached.iter().sum::<f64>() / reached.len() as f64 };
        cover.iter().map(|&c| c >= SUPPORT_FRACTION * mean).collect()
    }

    /// Detector pixels the operator models (row-major; see [`SUPPORT_FRACTION`]): all of them for `Nearest`.
    pub fn supported_pixels(&self) -> &[bool] {
        &self.supported
    }

    /// Trace the mapping cube of the renderer's system (its tracer, scene size and pitch) at `bands_nm` and
    /// build the operator on the renderer's detector and mask, so it applies to the renderer's acquisitions.
    pub fn from_renderer(renderer: &Renderer<'_>, bands_nm: &[f64], interpolation: MappingInterpolation) -> Result<Self> {
        super::layout::check_bands(bands_nm)?;
        let c = &renderer.config;
        let mapping = mapping_cube(renderer.system, renderer.tracer, c.scene_height, c.scene_width, c.scene_pitch_mm, bands_nm)?;
        let mut op = Self::new(&mapping, &renderer.detector, &renderer.mask, interpolation)?;
        if let Some(ms) = renderer.system.coded_mask {
            // Dual-disperser: each pixel's chief ray, band by band, reads the mask where it crosses its surface.
            let (h, w, npix) = (c.scene_height, c.scene_width, c.scene_height * c.scene_width);
            let mask = &renderer.mask;
            let mut per_band = vec![0.0f32; npix * bands_nm.len()];
            per_band.par_chunks_mut(npix.max(1)).zip(bands_nm.par_iter()).try_for_each(|(band, &l)| -> Result<()> {
                for (q, m) in band.iter_mut().enumerate() {
                    let field = MappingCube::scene_xy(h, w, c.scene_pitch_mm, q / w, q % w);
                    if let Some((x, y)) = renderer.system.point_on_mask(field, [0.0, 0.0], l)? {
                        *m = ms.transmission(&mask.values, mask.height, mask.width, x, y) as f32;
                    }
                }
                Ok(())
            })?;
            op.mask = per_band;
            if interpolation == MappingInterpolation::Bilinear {
                op.supported = op.support();
            }
        }
        Ok(op)
    }

    /// The mask scene pixel `q` sees in band `b` (the mask at `q` for single-disperser systems).
    #[inline]
    pub fn mask_at(&self, q: usize, b: usize) -> f32 {
        let npix = self.shape.height * self.shape.width;
        if self.mask.len() == npix {
            self.mask[q]
        } else {
            self.mask[b * npix + q]
        }
    }

    /// Voxel (q, b)'s coefficient before the taps: the mask it sees times its band's weight
    /// ([`band_support_weights`]; 1 for evenly spaced bands).
    #[inline]
    pub fn coefficient(&self, q: usize, b: usize) -> f32 {
        self.mask_at(q, b) * self.band_weight[b]
    }

    /// Per band: its weight relative to the mean ([`band_support_weights`]).
    pub fn band_weights(&self) -> &[f32] {
        &self.band_weight
    }

    pub fn interpolation(&self) -> MappingInterpolation {
        self.interpolation
    }

    /// I = A ∘ f: the acquisition gathered at each band's nearest mapped pixel (see the [module
    /// docs](self)), an H×W×B cube `[row][col][band]`.
    pub fn initialisation(&self, acquisition: &[f32]) -> Result<Vec<f32>> {
        if acquisition.len() != self.image.len() {
            return Err(Error::invalid(format!(
                "initialisation: the acquisition has {} values, the detector {}×{} = {}",
                acquisition.len(), self.image.height, self.image.width, self.image.len()
            )));
        }
        let (npix, nb) = (self.shape.height * self.shape.width, self.shape.bands);
        let mut cube = vec![0.0f32; npix * nb];
        cube.par_chunks_mut(nb).enumerate().for_each(|(q, px)| {
            for (b, v) in px.iter_mut().enumerate() {
                let n = self.points[b * npix + q].nearest;
                *v = if n == INVALID { 0.0 } else { acquisition[n as usize] };
            }
        });
        Ok(cube)
    }

    /// The mask, per scene pixel (row-major); for a dual-disperser system per band and pixel, band-major
    /// ([`Self::mask_at`]).
    pub fn mask_values(&self) -> &[f32] {
        &self.mask
    }

    /// Taps (detector pixel index, weight) of band b of scene pixel q (none when its chief ray does not
    /// arrive), distinct pixels in increasing order; the mask is not included.
    pub fn point_taps(&self, q: usize, b: usize, f: impl FnMut(usize, f32)) {
        let npix = self.shape.height * self.shape.width;
        self.taps(&self.points[b * npix + q], f)
    }

    /// Taps (pixel index, weight) of one mapped point on the supported pixels.
    #[inline]
    fn taps(&self, p: &Point, mut f: impl FnMut(usize, f32)) {
        self.raw_taps(p, |k, w| {
            if self.supported[k] {
                f(k, w)
            }
        })
    }

    /// Taps (pixel index, weight) of one mapped point on the detector, before the support.
    #[inline]
    fn raw_taps(&self, p: &Point, mut f: impl FnMut(usize, f32)) {
        if p.nearest == INVALID {
            return;
        }
        match self.interpolation {
            MappingInterpolation::Nearest => f(p.nearest as usize, 1.0),
            MappingInterpolation::Bilinear => {
                let (j, i) = (p.u.floor(), p.v.floor());
                let (fu, fv) = (p.u - j, p.v - i);
                let (j, i) = (j as i64, i as i64);
                let (w, h) = (self.image.width as i64, self.image.height as i64);
                for (di, wi) in [(0, 1.0 - fv), (1, fv)] {
                    for (dj, wj) in [(0, 1.0 - fu), (1, fu)] {
                        let (r, c) = (i + di, j + dj);
                        if r >= 0 && r < h && c >= 0 && c < w {
                            f((r * w + c) as usize, wi * wj);
                        }
                    }
                }
            }
        }
    }
}

impl Operator for MappingOperator {
    fn name(&self) -> &str {
        match self.interpolation {
            MappingInterpolation::Nearest => "mapping-nearest",
            MappingInterpolation::Bilinear => "mapping-bilinear",
        }
    }

    fn cube_shape(&self) -> CubeShape {
        self.shape
    }

    fn image_shape(&self) -> ImageShape {
        self.image
    }

    fn apply_into(&self, cube: &[f32], image: &mut [f32]) {
        let (npix, nb) = (self.shape.height * self.shape.width, self.shape.bands);
        let bm = to_band_major(cube, npix, nb);
        // Fixed band chunks, each scattered in band/pixel order, reduced in chunk order.
        let chunks: Vec<std::ops::Range<usize>> = (0..8).map(|c| c * nb / 8..(c + 1) * nb / 8).filter(|r| !r.is_empty()).collect();
        let partial: Vec<Vec<f32>> = chunks
            .into_par_iter()
            .map(|range| {
                let mut acc = vec![0.0f32; self.image.len()];
                for b in range {
                    let (xs, ps) = (&bm[b * npix..(b + 1) * npix], &self.points[b * npix..(b + 1) * npix]);
                    let ms = if self.mask.len() == npix { &self.mask[..] } else { &self.mask[b * npix..(b + 1) * npix] };
                    let bw = self.band_weight[b];
                    for ((x, p), m) in xs.iter().zip(ps).zip(ms) {
                        let v = *x * (*m * bw);
                        if v != 0.0 {
                            self.taps(p, |k, w| acc[k] += w * v);
                        }
                    }
                }
                acc
            })
            .collect();
        image.iter_mut().for_each(|v| *v = 0.0);
        for part in &partial {
            image.par_iter_mut().zip(part.par_iter()).for_each(|(a, b)| *a += *b);
        }
    }

    fn adjoint_into(&self, image: &[f32], cube: &mut [f32]) {
        let (npix, nb) = (self.shape.height * self.shape.width, self.shape.bands);
        cube.par_chunks_mut(nb).enumerate().for_each(|(q, px)| {
            for (b, v) in px.iter_mut().enumerate() {
                let m = self.coefficient(q, b);
                let mut s = 0.0f32;
                if m != 0.0 {
                    self.taps(&self.points[b * npix + q], |k, w| s += w * image[k]);
                }
                *v = m * s;
            }
        });
    }
}
