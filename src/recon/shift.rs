//! The `shift` operator: the simplified SD-CASSI model of the field (MST/DAUHST's `shift`, the paper's
//! "simple" ablation baseline) on the render's own detector grid. Band b of the masked cube is translated
//! along x by the central field's dispersion, in whole detector pixels; no distortion, no smile, no blur,
//! unit magnification:
//!
//! y(r₀ + σ_y·r, c_b + σ_x·c) += M(r, c)·x(r, c, b).
//!
//! c_b and r₀ come from the chief ray of the scene centre (field (0, 0)) at each band, in the detector's
//! continuous pixel coordinates (u_b, v_b) ([`Detector::to_pixel`]): c_b = round(u_b − σ_x·c̄),
//! r₀ = round(v_m − σ_y·r̄) with (r̄, c̄) = ((H − 1)/2, (W − 1)/2) the scene's centre and m the middle band
//! (the y part of the dispersion is ignored: "along x only"). σ_x, σ_y = ±1 is the image orientation of the
//! centre field (from the chief rays one scene pixel either side): SP's image is inverted (σ = −1 on both
//! axes), so the model is the field's shift model seen through the same inversion, which lets it be applied
//! to a rendered acquisition. The dispersion s(b) = c_b − c_0 ([`ShiftOperator::shifts_px`]). Taps off the
//! detector are dropped. The adjoint gathers the same pixels.
//!
//! **Dual-disperser systems** (a coded-mask surface inside the system, [`crate::system::MaskSurface`]): the
//! DD-CASSI shift model — a per-band shift of the mask, y(r₀ + σ_y·r, c_b + σ_x·c) += M_b(r, c)·x(r, c, b)
//! with M_b(r, c) = M(m_r + τ_y·r, m_b + τ_x·c) (0 outside the mask), where m_b, m_r and τ = ±1 come from the
//! centre field's chief ray on the mask surface at band b (and one scene pixel either side at the middle band)
//! in the mask's continuous pixel coordinates, rounded to whole mask pixels ([`ShiftOperator::mask_shifts_px`]).
//! The detector columns c_b are traced as above: where the second disperser cancels the first (ddsp, mddsp:
//! 0.5 µm of x spread over 450–650 nm) they are one column, DD-CASSI's identity registration. A system whose
//! mask surface leaves the dispersion on the detector keeps it (SP with its mask as a surface at the object
//! plane is then SP's model; it was given the identity registration regardless, silently wrong: a held-out
//! battery, round 10). The mask's axes must be the scene's (±x, ±y) within [`MAX_MASK_TURN_DEG`]: a turned mask is refused.
//!
//! ```
//! use diffcassi::recon::{shift::ShiftOperator, CubeShape, ImageShape, Operator};
//! use diffcassi::render::Mask;
//! // 2 bands shifted by 0 and 2 pixels, upright.
//! let op = ShiftOperator::new(CubeShape { height: 2, width: 3, bands: 2 }, ImageShape { height: 2, width: 5 },
//!                             &Mask::open(2, 3), 0, vec![0, 2], 1, 1)?;
//! let y = (&op as &dyn Operator).apply(&[1.0; 12])?;
//! assert_eq!(y, vec![1.0, 1.0, 2.0, 1.0, 1.0, 1.0, 1.0, 2.0, 1.0, 1.0]);
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::operator::{CubeShape, ImageShape, Operator};
use crate::error::{Error, Result};
use crate::rays::RayBatch;
use crate::render::spectral::band_support_weights;
use crate::render::{Mask, Renderer};
use crate::tracer::RayStatus;
use rayon::prelude::*;

/// The largest turn of a dual-disperser's mask against the scene (degrees) the shift model takes; the shear of
/// a larger one is beyond whole-pixel shifts ([`ShiftOperator::from_renderer`] refuses it).
pub const MAX_MASK_TURN_DEG: f64 = 10.0;

/// The shift operator (see the [module docs](self)).
#[derive(Clone, Debug)]
pub struct ShiftOperator {
    shape: CubeShape,
    image: ImageShape,
    mask: Vec<f32>,
    row0: i64,
    columns: Vec<i64>,
    sigma_x: i64,
    sigma_y: i64,
    /// Dual-disperser systems: the mask each scene pixel sees in each band, M_b(r, c), pixel-major
    /// (`[q·bands + b]`, the cube's layout); `None` for single-disperser (the mask `mask` per pixel).
    band_mask: Option<Vec<f32>>,
    /// Dual-disperser systems: the per-band mask column shift m_b − m_0 (mask pixels).
    mask_shifts: Vec<i64>,
    /// Per band: its share of an acquisition relative to the mean ([`band_support_weights`] of the bands
    /// [`ShiftOperator::from_renderer`] was given; 1 for evenly spaced bands and for [`ShiftOperator::new`]).
    band_weight: Vec<f32>,
}

impl ShiftOperator {
    /// Scene pixel (r, c) of band b lands on detector pixel (`row0` + `sigma_y`·r, `columns[b]` +
    /// `sigma_x`·c); `sigma_*` ∈ {+1, −1}.
    pub fn new(shape: CubeShape, image: ImageShape, mask: &Mask, row0: i64, columns: Vec<i64>, sigma_x: i64, sigma_y: i64) -> Result<Self> {
        if shape.is_empty() || image.is_empty() {
            return Err(Error::invalid(format!("shift operator: empty cube {shape:?} or image {image:?}")));
        }
        if mask.height != shape.height || mask.width != shape.width {
            return Err(Error::invalid(format!("the mask is {}×{} but the cube is {}×{}", mask.height, mask.width, shape.height, shape.width)));
        }
        if columns.len() != shape.bands {
            return Err(Error::invalid(format!("shift operator: {} band columns for {} bands", columns.len(), shape.bands)));
        }
        if sigma_x.abs() != 1 || sigma_y.abs() != 1 {
            return Err(Error::invalid(format!("shift operator: orientation ({sigma_x}, {sigma_y}) must be ±1")));
        }
        Ok(ShiftOperator { shape, image, mask: mask.values.clone(), row0, columns, sigma_x, sigma_y, band_mask: None, mask_shifts: Vec::new(), band_weight: vec![1.0; shape.bands] })
    }

    /// The DD-CASSI shift model of a renderer whose system holds a coded-mask surface (see the
    /// [module docs](self)).
    fn dual_disperser(renderer: &Renderer<'_>, bands_nm: &[f64], row0: i64, columns: Vec<i64>, sigma: (i64, i64)) -> Result<Self> {
        let sys = renderer.system;
        let ms = sys.coded_mask.expect("called for a system with a coded-mask surface");
        let c = &renderer.config;
        let mask = &renderer.mask;
        let (mh, mw) = (mask.height, mask.width);
        let on_mask = |field: [f64; 2], w: f64| -> Result<(f64, f64)> {
            let (x, y) = sys.point_on_mask(field, [0.0, 0.0], w)?.ok_or_else(|| {
                Error::invalid(format!("shift operator: the chief ray of field ({:.4}, {:.4}) at {w} nm does not reach the coded-mask surface {}", field[0], field[1], ms.surface))
            })?;
            // Continuous mask pixel coordinates with pixel centres at integers (column, row).
            Ok((x / ms.pitch_mm + mw as f64 * 0.5 - 0.5, mh as f64 * 0.5 - y / ms.pitch_mm - 0.5))
        };
        let mid = bands_nm[bands_nm.len() / 2];
        let d = c.scene_pitch_mm;
        let (px, nx, py, ny, o) = (on_mask([d, 0.0], mid)?, on_mask([-d, 0.0], mid)?, on_mask([0.0, d], mid)?, on_mask([0.0, -d], mid)?, on_mask([0.0, 0.0], mid)?);
        // One scene pixel along x must move along the mask's columns, along y along its rows. A mask turned by θ
        // shears the registration by tan θ mask pixels per scene pixel, which whole-pixel shifts cannot hold:
        // beyond MAX_MASK_TURN_DEG it is refused (90° gave an all-zero operator, 45° failed as "maps no voxel",
        // 30° ran with a wrong model; held-out batteries, round 10).
        let (sx, sy) = ((px.0 - nx.0, px.1 - nx.1), (ny.0 - py.0, ny.1 - py.1));
        let turn = (sx.1.abs() / sx.0.abs()).max(sy.0.abs() / sy.1.abs());
        if !(turn <= MAX_MASK_TURN_DEG.to_radians().tan()) {
            return Err(Error::invalid(format!(
                "shift operator: the coded mask on surface {} is turned against the scene (one scene pixel along x moves ({:.2}, {:.2}) mask pixels in (column, row), a turn of about {:.0}°, beyond {MAX_MASK_TURN_DEG}°): the shift model takes scene columns to mask columns in whole pixels; use the exact or mapping operator",
                ms.surface,
                sx.0 / 2.0,
                sx.1 / 2.0,
                turn.atan().to_degrees()
            )));
        }
        let tau_x = if sx.0 >= 0.0 { 1 } else { -1 };
        let tau_y = if sy.1 >= 0.0 { 1 } else { -1 };
        let (h, w, nb) = (c.scene_height, c.scene_width, bands_nm.len());
        let (rc, cc) = ((h as f64 - 1.0) / 2.0, (w as f64 - 1.0) / 2.0);
        let m_r = (o.1 - tau_y as f64 * rc).round() as i64;
        let mut m_b = Vec::with_capacity(nb);
        for &l in bands_nm {
            m_b.push((on_mask([0.0, 0.0], l)?.0 - tau_x as f64 * cc).round() as i64);
        }
        let mut band_mask = vec![0.0f32; h * w * nb];
        for r in 0..h {
            let mr = m_r + tau_y * r as i64;
            for cix in 0..w {
                for (b, &mb) in m_b.iter().enumerate() {
                    let mc = mb + tau_x * cix as i64;
                    if mr >= 0 && mc >= 0 && (mr as usize) < mh && (mc as usize) < mw {
                        band_mask[(r * w + cix) * nb + b] = mask.values[mr as usize * mw + mc as usize];
                    }
                }
            }
        }
        let shape = CubeShape { height: h, width: w, bands: nb };
        let image = ImageShape { height: renderer.detector.height, width: renderer.detector.width };
        let mut op = Self::new(shape, image, &Mask::open(h, w), row0, columns, sigma.0, sigma.1)?;
        op.mask_shifts = m_b.iter().map(|m| m - m_b[0]).collect();
        op.band_mask = Some(band_mask);
        Ok(op)
    }

    /// Dual-disperser systems: the per-band shift of the mask seen by the scene, m_b − m_0 (mask pixels);
    /// empty for single-disperser systems.
    pub fn mask_shifts_px(&self) -> &[i64] {
        &self.mask_shifts
    }

    /// The mask scene pixel `q` sees in band `b` (the mask at `q` for single-disperser systems).
    #[inline]
    pub fn mask_at(&self, q: usize, b: usize) -> f32 {
        match &self.band_mask {
            Some(m) => m[q * self.shape.bands + b],
            None => self.mask[q],
        }
    }

    /// Voxel (q, b)'s coefficient: the mask it sees times its band's weight ([`band_support_weights`]).
    #[inline]
    pub fn coefficient(&self, q: usize, b: usize) -> f32 {
        self.mask_at(q, b) * self.band_weight[b]
    }

    /// Per band: its weight relative to the mean ([`band_support_weights`]).
    pub fn band_weights(&self) -> &[f32] {
        &self.band_weight
    }

    /// Weigh the bands as [`band_support_weights`]`(bands_nm)` says (what [`ShiftOperator::from_renderer`]
    /// does with its bands).
    fn weighed(mut self, bands_nm: &[f64]) -> Self {
        self.band_weight = band_support_weights(bands_nm).iter().map(|&w| w as f32).collect();
        self
    }

    /// The model of the renderer's system at `bands_nm`, on the renderer's detector and mask (see the
    /// [module docs](self)).
    pub fn from_renderer(renderer: &Renderer<'_>, bands_nm: &[f64]) -> Result<Self> {
        super::layout::check_bands(bands_nm)?;
        let c = &renderer.config;
        let det = renderer.detector;
        let trace = |fields: &[[f64; 2]], w: f64| -> Result<Vec<(f64, f64)>> {
            let out = renderer.tracer.trace(renderer.system, &RayBatch::chief_rays(renderer.system, fields, w)?)?;
            (0..fields.len())
                .map(|k| {
                    if out.status[k] == RayStatus::Ok {
                        Ok(det.to_pixel(out.x[k], out.y[k]))
                    } else {
                        // The field in the system's unit: object height (mm), or at infinity the angle (rad → degrees).
                        let field = match renderer.system.object_at_infinity() {
                            true => format!("({:.4}°, {:.4}°)", fields[k][0].to_degrees(), fields[k][1].to_degrees()),
                            false => format!("({:.4}, {:.4}) mm", fields[k][0], fields[k][1]),
                        };
                        Err(Error::invalid(format!("shift operator: the chief ray of field {field} at {w} nm does not reach the detector ({:?})", out.status[k])))
                    }
                })
                .collect()
        };
        let mid = bands_nm[bands_nm.len() / 2];
        let d = c.scene_pitch_mm;
        let o = trace(&[[d, 0.0], [-d, 0.0], [0.0, d], [0.0, -d], [0.0, 0.0]], mid)?;
        // Scene columns run to +x, scene rows to −y.
        let sigma_x = if o[0].0 - o[1].0 >= 0.0 { 1 } else { -1 };
        let sigma_y = if o[3].1 - o[2].1 >= 0.0 { 1 } else { -1 };
        let (rc, cc) = ((c.scene_height as f64 - 1.0) / 2.0, (c.scene_width as f64 - 1.0) / 2.0);
        let row0 = (o[4].1 - sigma_y as f64 * rc).round() as i64;
        let mut columns = Vec::with_capacity(bands_nm.len());
        for &w in bands_nm {
            let p = trace(&[[0.0, 0.0]], w)?;
            columns.push((p[0].0 - sigma_x as f64 * cc).round() as i64);
        }
        if renderer.system.coded_mask.is_some() {
            // The traced columns: one column where the second disperser cancels the first (identity registration).
            return Ok(Self::dual_disperser(renderer, bands_nm, row0, columns, (sigma_x, sigma_y))?.weighed(bands_nm));
        }
        let shape = CubeShape { height: c.scene_height, width: c.scene_width, bands: bands_nm.len() };
        let image = ImageShape { height: det.height, width: det.width };
        Ok(Self::new(shape, image, &renderer.mask, row0, columns, sigma_x, sigma_y)?.weighed(bands_nm))
    }

    /// Per-band dispersion s(b) = c_b − c_0 (detector pixels).
    pub fn shifts_px(&self) -> Vec<i64> {
        self.columns.iter().map(|c| c - self.columns[0]).collect()
    }

    /// Detector column of scene column 0 per band (c_b), detector row of scene row 0 (r₀), orientation.
    pub fn placement(&self) -> (&[i64], i64, i64, i64) {
        (&self.columns, self.row0, self.sigma_x, self.sigma_y)
    }

    /// The mask, per scene pixel (row-major); for a dual-disperser system, the mask on its surface seen by
    /// each pixel depends on the band: [`Self::mask_at`].
    pub fn mask_values(&self) -> &[f32] {
        &self.mask
    }

    /// Detector row of scene row r, if on the detector.
    #[inline]
    pub fn detector_row(&self, r: usize) -> Option<usize> {
        self.det_row(r)
    }

    /// Detector column of scene column c in band b, if on the detector.
    #[inline]
    pub fn detector_column(&self, b: usize, c: usize) -> Option<usize> {
        self.col(b, c)
    }

    /// Detector row of scene row r, if on the detector.
    #[inline]
    fn det_row(&self, r: usize) -> Option<usize> {
        let i = self.row0 + self.sigma_y * r as i64;
        (i >= 0 && i < self.image.height as i64).then_some(i as usize)
    }

    /// Detector column of scene column c in band b, if on the detector.
    #[inline]
    fn col(&self, b: usize, c: usize) -> Option<usize> {
        let j = self.columns[b] + self.sigma_x * c as i64;
        (j >= 0 && j < self.image.width as i64).then_some(j as usize)
    }
}

impl Operator for ShiftOperator {
    fn name(&self) -> &str {
        "shift"
    }

    fn cube_shape(&self) -> CubeShape {
        self.shape
    }

    fn image_shape(&self) -> ImageShape {
        self.image
    }

    fn apply_into(&self, cube: &[f32], image: &mut [f32]) {
        let (w, nb, dw) = (self.shape.width, self.shape.bands, self.image.width);
        image.iter_mut().for_each(|v| *v = 0.0);
        // Each scene row lands on its own detector row (the same for all bands): parallel over rows.
        let mut rows: Vec<(usize, &mut [f32])> = image.chunks_mut(dw).enumerate().collect();
        rows.par_iter_mut().for_each(|(i, row)| {
            // Invert i = row0 + σ_y·r.
            let r = (*i as i64 - self.row0) * self.sigma_y;
            if r < 0 || r >= self.shape.height as i64 {
                return;
            }
            let r = r as usize;
            for b in 0..nb {
                for c in 0..w {
                    if let Some(j) = self.col(b, c) {
                        let q = r * w + c;
                        row[j] += self.coefficient(q, b) * cube[q * nb + b];
                    }
                }
            }
        });
    }

    fn adjoint_into(&self, image: &[f32], cube: &mut [f32]) {
        let (w, nb, dw) = (self.shape.width, self.shape.bands, self.image.width);
        cube.par_chunks_mut(w * nb).enumerate().for_each(|(r, row)| {
            let det = self.det_row(r);
            for c in 0..w {
                for b in 0..nb {
                    let m = self.coefficient(r * w + c, b);
                    row[c * nb + b] = match (det, self.col(b, c)) {
                        (Some(i), Some(j)) => m * image[i * dw + j],
                        _ => 0.0,
                    };
                }
            }
        });
    }
}
