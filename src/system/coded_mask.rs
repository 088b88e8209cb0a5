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
    /// Transmission of the `height`×`width` mask `values` (row-major; f32 as the renderer keeps them, or f64
    /// as the differentiable renderer does — widened exactly) at local (x, y) mm on the surface; 0 outside
    /// the mask and for a non-finite point.
    #[inline]
    pub fn transmission<T: Copy + Into<f64>>(&self, values: &[T], height: usize, width: usize, x: f64, y: f64) -> f64 {
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
                values[r as usize * width + c as usize].into()
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

    /// The mask pixels a crossing at local (x, y) mm reads, with their weights and the weights' derivatives
    /// in x and y (mm⁻¹): the transmission is Σ weight·value over the taps (pixels outside the mask are left
    /// out: the frame is opaque), so ∂T/∂value is the weight and ∂T/∂(x, y) = Σ ∂weight/∂(x, y)·value — what
    /// the differentiable renderer ([`crate::render::gradient`]) needs of a ray's crossing point.
    ///
    /// `nearest`: the containing pixel, weight 1, derivatives 0 (the transmission is piecewise constant; its
    /// jumps at pixel edges are boundary terms the renderer's gradient leaves out, as it does for rays that
    /// change status). `bilinear`: the four pixels around the point, weights of [`Self::transmission`]'s
    /// interpolation, u = x/p + W/2 − ½ and v = H/2 − y/p − ½ (so ∂u/∂x = 1/p, ∂v/∂y = −1/p).
    pub fn taps(&self, height: usize, width: usize, x: f64, y: f64) -> MaskTaps {
        let mut t = MaskTaps::default();
        let u = x / self.pitch_mm + width as f64 * 0.5;
        let v = height as f64 * 0.5 - y / self.pitch_mm;
        if !(u.is_finite() && v.is_finite()) {
            return t;
        }
        let mut push = |r: f64, c: f64, w: f64, dwdx: f64, dwdy: f64| {
            if r >= 0.0 && c >= 0.0 && r < height as f64 && c < width as f64 {
                let k = t.count;
                (t.index[k], t.weight[k], t.d_dx[k], t.d_dy[k]) = (r as usize * width + c as usize, w, dwdx, dwdy);
                t.count += 1;
            }
        };
        match self.sampling {
            MaskSampling::Nearest => push(v.floor(), u.floor(), 1.0, 0.0, 0.0),
            MaskSampling::Bilinear => {
                let (uc, vc) = (u - 0.5, v - 0.5);
                let (c0, r0) = (uc.floor(), vc.floor());
                let (fu, fv) = (uc - c0, vc - r0);
                // ∂fu/∂x = 1/p, ∂fv/∂y = −1/p.
                let ip = 1.0 / self.pitch_mm;
                push(r0, c0, (1.0 - fu) * (1.0 - fv), -(1.0 - fv) * ip, (1.0 - fu) * ip);
                push(r0, c0 + 1.0, fu * (1.0 - fv), (1.0 - fv) * ip, fu * ip);
                push(r0 + 1.0, c0, (1.0 - fu) * fv, -fv * ip, -(1.0 - fu) * ip);
                push(r0 + 1.0, c0 + 1.0, fu * fv, fv * ip, -fu * ip);
            }
        }
        t
    }

    /// The pixel (row, column) that contains local (x, y), if inside the `height`×`width` mask.
    pub fn pixel_of(&self, height: usize, width: usize, x: f64, y: f64) -> Option<(usize, usize)> {
        let u = (x / self.pitch_mm + width as f64 * 0.5).floor();
        let v = (height as f64 * 0.5 - y / self.pitch_mm).floor();
        (u >= 0.0 && v >= 0.0 && u < width as f64 && v < height as f64).then(|| (v as usize, u as usize))
    }
}

/// The mask pixels one crossing reads ([`MaskSurface::taps`]): the first `count` entries.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MaskTaps {
    /// Row-major pixel index.
    pub index: [usize; 4],
    pub weight: [f64; 4],
    /// ∂weight/∂x and ∂weight/∂y at the crossing point, mm⁻¹ (local frame of the surface).
    pub d_dx: [f64; 4],
    pub d_dy: [f64; 4],
    pub count: usize,
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

    /// The taps reproduce the transmission (Σ weight·value) and their derivatives are those of the bilinear
    /// interpolation (central differences, exact for a function linear within the cell); nearest has one tap
    /// of weight 1 and none outside the mask.
    #[test]
    fn taps_sum_to_the_transmission_and_differentiate_it() {
        let v = [0.0f64, 1.0, 0.5, 0.25, 0.0, 1.0, 0.75, 0.125, 0.375];
        let b = MaskSurface { surface: 1, step: 0, pitch_mm: 0.02, sampling: MaskSampling::Bilinear };
        let sum = |t: &MaskTaps, w: &[f64; 4]| (0..t.count).map(|k| w[k] * v[t.index[k]]).sum::<f64>();
        for &(x, y) in &[(0.003, 0.007), (-0.011, -0.004), (0.026, 0.021), (-0.029, 0.003)] {
            let t = b.taps(3, 3, x, y);
            let tr = b.transmission(&v, 3, 3, x, y);
            assert!((sum(&t, &t.weight) - tr).abs() < 1e-15, "({x}, {y}): {} vs {tr}", sum(&t, &t.weight));
            let h = 1e-7;
            let fx = (b.transmission(&v, 3, 3, x + h, y) - b.transmission(&v, 3, 3, x - h, y)) / (2.0 * h);
            let fy = (b.transmission(&v, 3, 3, x, y + h) - b.transmission(&v, 3, 3, x, y - h)) / (2.0 * h);
            assert!((sum(&t, &t.d_dx) - fx).abs() < 1e-6 && (sum(&t, &t.d_dy) - fy).abs() < 1e-6, "({x}, {y}): ({}, {}) vs ({fx}, {fy})", sum(&t, &t.d_dx), sum(&t, &t.d_dy));
        }
        let n = MaskSurface { sampling: MaskSampling::Nearest, ..b };
        let t = n.taps(3, 3, 0.011, -0.005);
        assert_eq!((t.count, t.index[0], t.weight[0], t.d_dx[0], t.d_dy[0]), (1, 5, 1.0, 0.0, 0.0));
        assert_eq!(n.taps(3, 3, 0.031, 0.0).count, 0);
        assert_eq!(n.taps(3, 3, f64::NAN, 0.0).count, 0);
    }
}
