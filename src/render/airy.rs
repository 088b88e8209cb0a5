//! The diffraction blur of each spectral plane: an Airy pattern I(r) = [2 J₁(v)/v]², v = 3.8317·r/r₀, whose
//! disk (first dark ring) has diameter 2r₀ = 2.5 detector pixels at 520 nm, scaled ∝ λ (the paper's
//! "Rendering"). The kernel is integrated over each pixel (8×8 sub-samples), truncated at a dark ring
//! (default the third, r = 2.655 r₀, which holds 93.8 % of the energy) and renormalised to sum 1, so the
//! convolution conserves energy. [`AiryKernel::convolve`] is direct (a tap at a time over whole rows, which
//! vectorises) and deterministic; the renderer and the exact operator use its register-blocked equivalent
//! over each plane's support ([`super::convolve`], bit-identical to it).
//!
//! ```
//! use diffcassi::render::AiryKernel;
//! let k = AiryKernel::for_wavelength(520.0, 2.5, 520.0, 3).unwrap();
//! assert!((k.weights.iter().map(|&w| w as f64).sum::<f64>() - 1.0).abs() < 1e-6);
//! assert!((k.first_zero_radius_px - 1.25).abs() < 1e-12);
//! // A reference wavelength of 0 nm (a tampered render.json) is an error, not a panic.
//! assert!(AiryKernel::for_wavelength(520.0, 2.5, 0.0, 3).is_err());
//! ```
use crate::error::{Error, Result};

/// Zeros of J₁ (dark rings of the Airy pattern in units of v).
const J1_ZEROS: [f64; 5] = [3.831_705_970_207_512, 7.015_586_669_815_619, 10.173_468_135_062_722, 13.323_691_936_314_223, 16.470_630_050_877_634];

/// Bessel J₁ of the first kind, order 1: the `libm` crate's `j1` (a port of musl/FreeBSD's, accurate to
/// about 1 ulp), which replaced Numerical Recipes' `bessj1` (|error| < 1e-8) and its rounded constants.
pub fn bessel_j1(x: f64) -> f64 {
    libm::j1(x)
}

/// Airy intensity at radius `r` for first-zero radius `r0` (1 at the centre).
pub fn airy_intensity(r: f64, r0: f64) -> f64 {
    let v = J1_ZEROS[0] * r / r0;
    if v.abs() < 1e-8 {
        return 1.0;
    }
    let a = 2.0 * bessel_j1(v) / v;
    a * a
}

/// A pixel-integrated, truncated, normalised Airy kernel, `(2·half + 1)²` taps, row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct AiryKernel {
    pub first_zero_radius_px: f64,
    pub truncation_radius_px: f64,
    pub half: usize,
    pub weights: Vec<f32>,
}

impl AiryKernel {
    /// Kernel for first-zero radius `r0_px` (finite, in (0, [`crate::limits::MAX_AIRY_RADIUS_PX`]]),
    /// truncated at dark ring `rings` (1–5). Bad inputs are errors naming the value, never a panic or an
    /// allocation failure.
    pub fn new(r0_px: f64, rings: usize) -> Result<Self> {
        let max_r0 = crate::limits::MAX_AIRY_RADIUS_PX;
        if !(r0_px.is_finite() && r0_px > 0.0 && r0_px <= max_r0) {
            return Err(Error::invalid(format!("Airy kernel: first-zero radius {} px must be finite and in (0, {max_r0}] px", crate::limits::fmt_num(r0_px))));
        }
        if !(1..=J1_ZEROS.len()).contains(&rings) {
            return Err(Error::invalid(format!("Airy kernel: truncation ring {rings} must be in 1..={}", J1_ZEROS.len())));
        }
        let rt = r0_px * J1_ZEROS[rings - 1] / J1_ZEROS[0];
        if rt <= 0.5 {
            // The truncated disk lies inside the centre pixel (half-width 0.5 px): integrated over pixels, all its
            // energy is that pixel's — the identity kernel, exactly. (Sampled, a disk narrower than the sub-pixel
            // grid's first sample, r < 0.088 px, met no sample: a kernel of 0/0, NaN acquisitions.)
            return Ok(AiryKernel { first_zero_radius_px: r0_px, truncation_radius_px: rt, half: 0, weights: vec![1.0] });
        }
        let half = (rt + 0.5).ceil() as usize;
        let n = 2 * half + 1;
        const SUB: usize = 8;
        let mut w = vec![0.0f64; n * n];
        for i in 0..n {
            for j in 0..n {
                let mut s = 0.0;
                for a in 0..SUB {
                    for b in 0..SUB {
                        let y = i as f64 - half as f64 - 0.5 + (a as f64 + 0.5) / SUB as f64;
                        let x = j as f64 - half as f64 - 0.5 + (b as f64 + 0.5) / SUB as f64;
                        let r = (x * x + y * y).sqrt();
                        if r <= rt {
                            s += airy_intensity(r, r0_px);
                        }
                    }
                }
                w[i * n + j] = s;
            }
        }
        let total: f64 = w.iter().sum();
        Ok(AiryKernel { first_zero_radius_px: r0_px, truncation_radius_px: rt, half, weights: w.iter().map(|v| (v / total) as f32).collect() })
    }

    /// The paper's kernel at `wavelength_nm`: disk diameter `diameter_px` at `reference_nm`, ∝ λ. Both
    /// wavelengths must lie in [`crate::limits::WAVELENGTH_RANGE_NM`] and the diameter in
    /// (0, [`crate::limits::MAX_AIRY_DIAMETER_PX`]] ([`AiryConfig::validate`](super::AiryConfig::validate)).
    pub fn for_wavelength(wavelength_nm: f64, diameter_px: f64, reference_nm: f64, rings: usize) -> Result<Self> {
        let (lo, hi) = crate::limits::WAVELENGTH_RANGE_NM;
        for (name, v) in [("wavelength", wavelength_nm), ("reference wavelength", reference_nm)] {
            if !(v.is_finite() && (lo..=hi).contains(&v)) {
                return Err(Error::invalid(format!("Airy kernel: {name} {} nm must be in {lo}–{hi} nm", crate::limits::fmt_num(v))));
            }
        }
        if !(diameter_px.is_finite() && diameter_px > 0.0 && diameter_px <= crate::limits::MAX_AIRY_DIAMETER_PX) {
            return Err(Error::invalid(format!("Airy kernel: disk diameter {} px must be in (0, {}] pixels", crate::limits::fmt_num(diameter_px), crate::limits::MAX_AIRY_DIAMETER_PX)));
        }
        Self::new(0.5 * diameter_px * wavelength_nm / reference_nm, rings)
    }

    /// Convolve the `width × height` image `src` (zero outside) with the kernel.
    pub fn convolve(&self, src: &[f32], width: usize, height: usize) -> Vec<f32> {
        let mut out = vec![0.0f32; src.len()];
        let n = 2 * self.half + 1;
        let h = self.half as isize;
        for ki in 0..n {
            let dy = ki as isize - h;
            for kj in 0..n {
                let wgt = self.weights[ki * n + kj];
                if wgt == 0.0 {
                    continue;
                }
                let dx = kj as isize - h;
                // out[y][x] += w · src[y − dy][x − dx]
                let (x0, x1) = ((dx.max(0)) as usize, (width as isize + dx.min(0)) as usize);
                if x0 >= x1 {
                    continue;
                }
                for y in 0..height {
                    let sy = y as isize - dy;
                    if sy < 0 || sy >= height as isize {
                        continue;
                    }
                    let o = &mut out[y * width + x0..y * width + x1];
                    let s0 = sy as usize * width + (x0 as isize - dx) as usize;
                    let s = &src[s0..s0 + (x1 - x0)];
                    for (a, b) in o.iter_mut().zip(s) {
                        *a += wgt * *b;
                    }
                }
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn j1_matches_its_integral_and_zeros() {
        for &x in &[0.3, 1.0, 2.5, 3.9, 7.0, 9.5, 15.0] {
            // J₁(x) = (1/π) ∫₀^π cos(τ − x sin τ) dτ (trapezoid, exponentially accurate).
            let m = 400;
            let s: f64 = (0..=m).map(|k| {
                let t = std::f64::consts::PI * k as f64 / m as f64;
                let w = if k == 0 || k == m { 0.5 } else { 1.0 };
                w * (t - x * t.sin()).cos()
            }).sum::<f64>() / m as f64;
            assert!((bessel_j1(x) - s).abs() < 1e-14, "x={x}: {} vs {s}", bessel_j1(x));
        }
        for z in J1_ZEROS {
            assert!(bessel_j1(z).abs() < 1e-15, "J1({z}) = {}", bessel_j1(z));
        }
    }

    #[test]
    fn convolution_conserves_energy_and_is_centred() {
        let k = AiryKernel::for_wavelength(650.0, 2.5, 520.0, 3).unwrap();
        let (w, h) = (21, 17);
        let mut img = vec![0.0f32; w * h];
        img[8 * w + 10] = 2.0;
        let out = k.convolve(&img, w, h);
        let total: f64 = out.iter().map(|&v| v as f64).sum();
        assert!((total - 2.0).abs() < 1e-5);
        let cx: f64 = out.iter().enumerate().map(|(i, &v)| (i % w) as f64 * v as f64).sum::<f64>() / total;
        let cy: f64 = out.iter().enumerate().map(|(i, &v)| (i / w) as f64 * v as f64).sum::<f64>() / total;
        assert!((cx - 10.0).abs() < 1e-5 && (cy - 8.0).abs() < 1e-5);
        assert!(out[8 * w + 10] > out[8 * w + 11]);
    }

    /// A disk inside the centre pixel (truncation radius ≤ 0.5 px) is the identity kernel: a held-out battery's
    /// `--airy-diameter-px 0.01` (first-zero radius 0.005 px) gave a kernel of 0/0 and NaN acquisitions.
    #[test]
    fn a_disk_inside_one_pixel_is_the_identity() {
        for r0 in [1e-300, 0.005, 0.03, 0.5 * J1_ZEROS[0] / J1_ZEROS[2]] {
            let k = AiryKernel::new(r0, 3).unwrap();
            assert_eq!((k.half, k.weights.as_slice()), (0, &[1.0f32][..]), "r0 {r0}");
            let img = [0.0f32, 1.0, 2.0, 3.0, 4.0, 5.0];
            assert_eq!(k.convolve(&img, 3, 2), img.to_vec());
        }
        // Just past it the sampled kernel starts (every weight finite, summing to 1).
        let k = AiryKernel::new(0.51 * J1_ZEROS[0] / J1_ZEROS[2], 3).unwrap();
        assert!(k.half >= 1 && k.weights.iter().all(|w| w.is_finite()));
        assert!((k.weights.iter().map(|&w| w as f64).sum::<f64>() - 1.0).abs() < 1e-6);
    }

    /// Bad kernel inputs are errors naming the value (a render.json with `airy.reference_nm: 0` panicked).
    #[test]
    fn bad_inputs_are_errors_not_panics() {
        for (w, d, r, rings, needle) in [
            (520.0, 2.5, 0.0, 3, "reference wavelength 0 nm"),
            (520.0, 2.5, f64::NAN, 3, "reference wavelength NaN"),
            (0.0, 2.5, 520.0, 3, "wavelength 0 nm"),
            (520.0, 0.0, 520.0, 3, "diameter 0 px"),
            (520.0, 1e6, 520.0, 3, "diameter 1000000 px"),
            (520.0, 2.5, 520.0, 0, "ring 0"),
            (520.0, 2.5, 520.0, 6, "ring 6"),
        ] {
            let e = AiryKernel::for_wavelength(w, d, r, rings).unwrap_err().to_string();
            assert!(e.contains(needle), "{e}");
        }
        assert!(AiryKernel::new(1e9, 3).unwrap_err().to_string().contains("first-zero radius 1e9 px"));
        assert!(AiryKernel::new(-1.0, 3).is_err() && AiryKernel::new(f64::INFINITY, 3).is_err());
    }
}
