//! The coded-mask surface of a built system (dual-disperser CASSI, `crate::spec::CodedMaskSpec`): where it sits
//! on the traced path and how a ray's crossing point reads the mask's transmission.
//!
//! The mask's pixels are laid out as the scene's ([`crate::analysis::MappingCube::scene_xy`]): an H×W grid
//! centred on the surface's vertex, column c covering x ∈ [(c − W/2)·p, (c + 1 − W/2)·p), row r covering
//! y ∈ ((H/2 − r − 1)·p, (H/2 − r)·p] (row 0 at +y), p the pitch.
//!
//! ```
//! use diffcassi::spec::MaskSampling;
//! use diffcassi::system::MaskSurface;
//! let m = MaskSurface { surface: 5, step: 4, pitch_mm: 0.01, sampling: MaskSampling::Nearest };
//! // A 2×2 mask: only the top-left pixel (x < 0, y > 0) open.
//! let values = [1.0f32, 0.0, 0.0, 0.0];
//! assert_eq!(m.transmission(&values, 2, 2, -0.005, 0.005), 1.0);
//! assert_eq!(m.transmission(&values, 2, 2, 0.005, 0.005), 0.0);
//! assert_eq!(m.transmission(&values, 2, 2, -0.03, 0.005), 0.0); // outside the mask: its opaque frame
//! ```
use crate::spec::MaskSampling;

/// The coded mask's place in a built system.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MaskSurface {
    /// Surface index in the spec.
    pub surface: usize,
    /// Index of its step in the traced path: a ray's position after `path[..=step]` is its crossing point, in
    /// the surface's local frame.
    pub step: usize,
    /// Pixel pitch, mm.
    pub pitch_mm: f64,
    pub sampling: MaskSampling,
}

impl MaskSurface {
    /// Transmission of the `height`×`width` mask `values` (row-major) at local (x, y) mm on the surface; 0
    /// outside the mask and for a non-finite point.
    #[inline]
    pub fn transmission(&self, values: &[f32], height: usize, width: usize, x: f64, y: f64) -> f64 {
        // Continuous pixel coordinates: u along the columns, v along the rows (pixel k covers [k, k + 1)).
        let u = x / self.pitch_mm + width as f64 * 0.5;
        let v = height as f64 * 0.5 - y / self.pitch_mm;
        if !(u.is_finite() && v.is_finite()) {
            return 0.0;
        }
        let at = |r: i64, c: i64| -> f64 {
            if r < 0 || c < 0 || r >= height as i64 || c >= width as i64 {
                0.0
            } else {
                values[r as usize * width + c as usize] as f64
            }
        };
        match self.sampling {
            MaskSampling::Nearest => at(v.floor() as i64, u.floor() as i64),
            MaskSampling::Bilinear => {
                let (uc, vc) = (u - 0.5, v - 0.5);
                let (c0, r0) = (uc.floor(), vc.floor());
                let (fu, fv) = (uc - c0, vc - r0);
                let (c0, r0) = (c0 as i64, r0 as i64);
                (1.0 - fv) * ((1.0 - fu) * at(r0, c0) + fu * at(r0, c0 + 1)) + fv * ((1.0 - fu) * at(r0 + 1, c0) + fu * at(r0 + 1, c0 + 1))
            }
        }
    }

    /// The pixel (row, column) that contains local (x, y), if inside the `height`×`width` mask.
    pub fn pixel_of(&self, height: usize, width: usize, x: f64, y: f64) -> Option<(usize, usize)> {
        let u = (x / self.pitch_mm + width as f64 * 0.5).floor();
        let v = (height as f64 * 0.5 - y / self.pitch_mm).floor();
        (u >= 0.0 && v >= 0.0 && u < width as f64 && v < height as f64).then(|| (v as usize, u as usize))
    }
}

impl super::SequentialSystem {
    /// Where the ray of object-space field point `field` through normalised pupil point `pupil` crosses the
    /// coded-mask surface at `wavelength_nm`: local (x, y) mm on it, or `None` when the ray stops before it.
    /// Errors: the system has no coded-mask surface, or the wavelength is unusable.
    pub fn point_on_mask(&self, field: [f64; 2], pupil: [f64; 2], wavelength_nm: f64) -> crate::error::Result<Option<(f64, f64)>> {
        let m = self.coded_mask.ok_or_else(|| crate::error::Error::invalid(format!("system `{}` has no coded-mask surface", self.name())))?;
        let n = self.indices(wavelength_nm)?;
        let (o, d) = crate::rays::object_ray(self, field, pupil[0], pupil[1]);
        let len = d.length();
        if !(o.is_finite() && d.is_finite() && len > 0.0) {
            return Ok(None);
        }
        Ok(crate::tracer::kernel::trace_steps(&self.path[..=m.step], &n, o, d / len).ok().map(|(p, _)| (p.x, p.y)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_reads_the_containing_pixel_and_bilinear_interpolates_between_centres() {
        let m = MaskSurface { surface: 1, step: 0, pitch_mm: 0.02, sampling: MaskSampling::Nearest };
        // 2 rows × 3 columns: centres at x = −0.02, 0, 0.02; y = 0.01 (row 0), −0.01 (row 1).
        let v = [0.0f32, 1.0, 0.5, 0.25, 0.0, 1.0];
        assert_eq!(m.transmission(&v, 2, 3, 0.0, 0.01), 1.0);
        assert_eq!(m.transmission(&v, 2, 3, 0.02, -0.01), 1.0);
        assert_eq!(m.transmission(&v, 2, 3, -0.02, -0.0101), 0.25);
        assert_eq!(m.pixel_of(2, 3, 0.029, 0.019), Some((0, 2)));
        assert_eq!(m.pixel_of(2, 3, 0.031, 0.0), None);
        assert_eq!(m.transmission(&v, 2, 3, f64::NAN, 0.0), 0.0);
        let b = MaskSurface { sampling: MaskSampling::Bilinear, ..m };
        // At a centre, the pixel itself; halfway between columns 1 and 2 of row 0, their mean.
        assert!((b.transmission(&v, 2, 3, 0.0, 0.01) - 1.0).abs() < 1e-12);
        assert!((b.transmission(&v, 2, 3, 0.01, 0.01) - 0.75).abs() < 1e-12);
        // Midway between the rows of column 0: (0 + 0.25) / 2.
        assert!((b.transmission(&v, 2, 3, -0.02, 0.0) - 0.125).abs() < 1e-12);
    }
}
