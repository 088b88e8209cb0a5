//! The detector: a grid of square pixels on the image surface (its local x, y), sized to the dispersed
//! footprint of the scene.
//!
//! Sizing: the chief rays of every border pixel of the scene at every render plane give the footprint's
//! bounding box on the image surface; it is widened on each side by a margin = the largest spot radius
//! (4 marginal rays at the corners, edge midpoints and centre, at the shortest, middle and longest plane)
//! + half the scene pixel's diagonal + the Airy kernel's truncation radius at the longest plane + 1 pixel
//! (bilinear splat) + `extra_px`, and snapped outward to multiples of the pitch from the image surface's
//! origin (so the pixel grid does not move with the ray count or seed). Rows run top (+y) to bottom,
//! columns left (−x) to right, like scene pixels: pixel (i, j) has its centre at
//! x = x_left + (j + ½)·pitch, y = y_top − (i + ½)·pitch. SP's image is inverted (magnification ≈ −1), so
//! the scene appears rotated by 180° on the detector, as it would on a real sensor.
use crate::analysis::MappingCube;
use crate::error::{Error, Result};
use crate::rays::PupilPattern;
use crate::system::SequentialSystem;
use crate::tracer::{RayStatus, Tracer};

#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Detector {
    pub width: usize,
    pub height: usize,
    pub pitch_mm: f64,
    /// x of the left edge of column 0 (mm, image-surface frame).
    pub x_left_mm: f64,
    /// y of the top edge of row 0 (mm).
    pub y_top_mm: f64,
}

impl Detector {
    /// Continuous pixel coordinates (column, row) of image point (x, y) mm; pixel (i, j)'s centre is (j, i).
    #[inline]
    pub fn to_pixel(&self, x_mm: f64, y_mm: f64) -> (f64, f64) {
        ((x_mm - self.x_left_mm) / self.pitch_mm - 0.5, (self.y_top_mm - y_mm) / self.pitch_mm - 0.5)
    }

    /// Centre (x, y) mm of pixel (row, col).
    pub fn pixel_centre_mm(&self, row: usize, col: usize) -> [f64; 2] {
        [self.x_left_mm + (col as f64 + 0.5) * self.pitch_mm, self.y_top_mm - (row as f64 + 0.5) * self.pitch_mm]
    }

    pub fn pixels(&self) -> usize {
        self.width * self.height
    }

    /// The detector covering the dispersed footprint of a `height × width` scene of pitch `scene_pitch_mm`
    /// over `planes_nm` (see the module docs). `airy_radius_px` is the kernel's truncation radius at the
    /// longest plane (0 without diffraction).
    #[allow(clippy::too_many_arguments)]
    pub fn covering(system: &SequentialSystem, tracer: &dyn Tracer, height: usize, width: usize, scene_pitch_mm: f64, planes_nm: &[f64], pitch_mm: f64, airy_radius_px: f64, extra_px: usize) -> Result<Detector> {
        if !(pitch_mm.is_finite() && pitch_mm > 0.0) {
            return Err(Error::invalid(format!("detector pitch {pitch_mm} mm must be finite and > 0")));
        }
        let mut border = Vec::new();
        for r in 0..height {
            for c in 0..width {
                if r == 0 || c == 0 || r + 1 == height || c + 1 == width {
                    border.push(MappingCube::scene_xy(height, width, scene_pitch_mm, r, c));
                }
            }
        }
        let (mut xmin, mut xmax, mut ymin, mut ymax) = (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
        for &w in planes_nm {
            let out = tracer.trace(system, &crate::rays::RayBatch::chief_rays(system, &border, w)?)?;
            for (x, y) in out.ok_positions() {
                xmin = xmin.min(x);
                xmax = xmax.max(x);
                ymin = ymin.min(y);
                ymax = ymax.max(y);
            }
        }
        if !xmin.is_finite() {
            return Err(Error::invalid(format!("no chief ray of the scene's border reaches the image surface of `{}`", system.name())));
        }
        // Largest spot radius: marginal rays about their chief ray.
        let (h2, w2) = (height - 1, width - 1);
        let probes = [(0, 0), (0, w2), (h2, 0), (h2, w2), (0, w2 / 2), (h2, w2 / 2), (h2 / 2, 0), (h2 / 2, w2), (h2 / 2, w2 / 2)];
        let mut spot_mm: f64 = 0.0;
        let mut pupil = PupilPattern::Marginal.points();
        pupil.push([0.0, 0.0]);
        let sel = [0, planes_nm.len() / 2, planes_nm.len() - 1];
        for &k in &sel {
            for &(r, c) in &probes {
                let f = MappingCube::scene_xy(height, width, scene_pitch_mm, r, c);
                let out = tracer.trace(system, &crate::rays::RayBatch::for_field(system, f, &pupil, planes_nm[k])?)?;
                if out.status[4] != RayStatus::Ok {
                    continue;
                }
                for i in 0..4 {
                    if out.status[i] == RayStatus::Ok {
                        spot_mm = spot_mm.max((out.x[i] - out.x[4]).hypot(out.y[i] - out.y[4]));
                    }
                }
            }
        }
        // A scene pixel's size on the detector: its pitch (mm, ~unit magnification) or, for an object at
        // infinity, its angle (rad) × |EFL|.
        let scene_px_mm = if system.object_at_infinity() { scene_pitch_mm * system.first_order.efl_mm.abs() } else { scene_pitch_mm };
        if !scene_px_mm.is_finite() {
            // An afocal system (EFL infinite): a scene at infinity is imaged at infinity, not on the image
            // surface (the size was computed from the infinite EFL as 18446744073709551615 pixels; round 12).
            return Err(Error::invalid(format!(
                "system `{}` is afocal (effective focal length {} mm): a scene at infinity has no image on its image surface; add a focusing element (e.g. a paraxial lens) before the detector",
                system.name(),
                crate::limits::fmt_num(system.first_order.efl_mm)
            )));
        }
        let margin_mm = spot_mm + 0.75 * scene_px_mm + (airy_radius_px + 1.0 + extra_px as f64) * pitch_mm;
        let x_left_mm = ((xmin - margin_mm) / pitch_mm).floor() * pitch_mm;
        let x_right = ((xmax + margin_mm) / pitch_mm).ceil() * pitch_mm;
        let y_bottom = ((ymin - margin_mm) / pitch_mm).floor() * pitch_mm;
        let y_top_mm = ((ymax + margin_mm) / pitch_mm).ceil() * pitch_mm;
        let (width_f, height_f) = (((x_right - x_left_mm) / pitch_mm).round(), ((y_top_mm - y_bottom) / pitch_mm).round());
        // In floats first: a spot or an extent beyond f64's range must not saturate the pixel counts.
        if !(width_f.is_finite() && height_f.is_finite() && width_f * height_f <= (64u64 << 20) as f64) {
            return Err(Error::invalid(format!(
                "the dispersed footprint needs a {}×{} detector (pitch {} mm): too large",
                crate::limits::fmt_num(width_f),
                crate::limits::fmt_num(height_f),
                crate::limits::fmt_num(pitch_mm)
            )));
        }
        let (width_px, height_px) = (width_f as usize, height_f as usize);
        Ok(Detector { width: width_px, height: height_px, pitch_mm, x_left_mm, y_top_mm })
    }
}
