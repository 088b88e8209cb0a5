//! Colorimetry for previews and tests: a reflectance spectrum seen under CIE illuminant D65 by the CIE 1931
//! 2° standard observer → CIE XYZ → linear sRGB → encoded sRGB (IEC 61966-2-1:1999), and back; CIELAB ΔE*ab
//! (CIE 1976) for colour differences.
//!
//! XYZ = Σ_λ R(λ) S_D65(λ) (x̄, ȳ, z̄)(λ) / Σ_λ S_D65(λ) ȳ(λ), a Riemann sum over the 5 nm tables of
//! [`super::color_tables`] (380–780 nm; CIE 015:2004 data via colour-science), so the perfect white has Y = 1 and
//! maps to sRGB (1, 1, 1) up to the matrix rounding. A spectrum known only at some bands (e.g. 28 bands
//! 450–650 nm) is interpolated linearly between them and held constant beyond them, as
//! [`crate::scene::SpectralCube::plane`] does.
//!
//! ```
//! use diffcassi::scene::colorimetry::{reflectance_to_srgb, srgb_encode};
//! let ws: Vec<f64> = (0..28).map(|k| 450.0 + 200.0 * k as f64 / 27.0).collect();
//! let white = reflectance_to_srgb(&ws, &vec![1.0; 28]);
//! assert!(white.iter().all(|c| (srgb_encode(*c) - 1.0).abs() < 2e-3));
//! ```
use super::color_tables::{CIE1931_X, CIE1931_Y, CIE1931_Z, D65, TABLE_LEN, TABLE_START_NM, TABLE_STEP_NM};
use super::SpectralCube;
use crate::error::Result;
use std::path::Path;

/// XYZ (D65 white, Y = 1) → linear sRGB, IEC 61966-2-1:1999 matrix.
pub const XYZ_TO_LINEAR_SRGB: [[f64; 3]; 3] = [[3.2406, -1.5372, -0.4986], [-0.9689, 1.8758, 0.0415], [0.0557, -0.2040, 1.0570]];
/// Linear sRGB → XYZ, IEC 61966-2-1:1999 matrix.
pub const LINEAR_SRGB_TO_XYZ: [[f64; 3]; 3] = [[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]];

fn mul(m: &[[f64; 3]; 3], v: [f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|i| m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2])
}

/// sRGB transfer function (encoding): linear → non-linear, 12.92·L below 0.0031308, 1.055·L^(1/2.4) − 0.055 above.
pub fn srgb_encode(linear: f64) -> f64 {
    if linear <= 0.0031308 { 12.92 * linear } else { 1.055 * linear.powf(1.0 / 2.4) - 0.055 }
}

/// Inverse sRGB transfer function (decoding / linearisation): V/12.92 below 0.04045, ((V + 0.055)/1.055)^2.4 above.
pub fn srgb_decode(encoded: f64) -> f64 {
    if encoded <= 0.04045 { encoded / 12.92 } else { ((encoded + 0.055) / 1.055).powf(2.4) }
}

pub fn xyz_to_linear_srgb(xyz: [f64; 3]) -> [f64; 3] {
    mul(&XYZ_TO_LINEAR_SRGB, xyz)
}

pub fn linear_srgb_to_xyz(rgb: [f64; 3]) -> [f64; 3] {
    mul(&LINEAR_SRGB_TO_XYZ, rgb)
}

/// CIELAB (CIE 1976) of XYZ relative to the D65 white (Xn, Yn, Zn) = (0.95047, 1, 1.08883).
pub fn xyz_to_lab(xyz: [f64; 3]) -> [f64; 3] {
    let white = [0.95047, 1.0, 1.08883];
    let f = |t: f64| if t > (6.0f64 / 29.0).powi(3) { t.cbrt() } else { t / (3.0 * (6.0f64 / 29.0).powi(2)) + 4.0 / 29.0 };
    let [fx, fy, fz] = [0, 1, 2].map(|i| f(xyz[i] / white[i]));
    [116.0 * fy - 16.0, 500.0 * (fx - fy), 200.0 * (fy - fz)]
}

/// ΔE*ab (CIE 1976): Euclidean distance in CIELAB.
pub fn delta_e76(a: [f64; 3], b: [f64; 3]) -> f64 {
    let (la, lb) = (xyz_to_lab(a), xyz_to_lab(b));
    ((la[0] - lb[0]).powi(2) + (la[1] - lb[1]).powi(2) + (la[2] - lb[2]).powi(2)).sqrt()
}

/// Precomputed weights that turn a spectrum sampled at `wavelengths_nm` into XYZ: `weights[band] = (wx, wy, wz)`,
/// the D65-weighted CMFs of every 5 nm table sample distributed onto the bands by the linear-interpolation /
/// constant-extrapolation rule (so XYZ = Σ_band R_band · weights[band]).
#[derive(Clone, Debug)]
pub struct XyzWeights {
    pub weights: Vec<[f64; 3]>,
}

impl XyzWeights {
    pub fn new(wavelengths_nm: &[f64]) -> Self {
        let probe = SpectralCube { height: 1, width: 1, wavelengths_nm: wavelengths_nm.to_vec(), data: vec![0.0; wavelengths_nm.len()] };
        let norm: f64 = (0..TABLE_LEN).map(|i| D65[i] * CIE1931_Y[i]).sum();
        let mut weights = vec![[0.0; 3]; wavelengths_nm.len()];
        let last = wavelengths_nm.len() - 1;
        for i in 0..TABLE_LEN {
            let l = TABLE_START_NM + TABLE_STEP_NM * i as f64;
            let (k, t) = probe.interpolation(l);
            let cmf = [CIE1931_X[i], CIE1931_Y[i], CIE1931_Z[i]].map(|c| c * D65[i] / norm);
            for c in 0..3 {
                weights[k][c] += (1.0 - t) * cmf[c];
                weights[(k + 1).min(last)][c] += t * cmf[c];
            }
        }
        XyzWeights { weights }
    }

    /// XYZ of one spectrum (one value per band).
    pub fn xyz(&self, spectrum: &[f32]) -> [f64; 3] {
        let mut xyz = [0.0; 3];
        for (w, &r) in self.weights.iter().zip(spectrum) {
            for c in 0..3 {
                xyz[c] += w[c] * r as f64;
            }
        }
        xyz
    }
}

/// Linear sRGB of a reflectance spectrum given at `wavelengths_nm`.
pub fn reflectance_to_srgb(wavelengths_nm: &[f64], reflectance: &[f64]) -> [f64; 3] {
    let s: Vec<f32> = reflectance.iter().map(|&v| v as f32).collect();
    xyz_to_linear_srgb(XyzWeights::new(wavelengths_nm).xyz(&s))
}

/// An 8-bit sRGB preview of a cube: every pixel's spectrum → XYZ (D65, CIE 1931 2°) → sRGB, clipped to
/// [0, 1] and encoded. Returns row-major RGB bytes. `exposure` scales the spectra first (1 for reflectances).
pub fn cube_to_srgb8(cube: &SpectralCube, exposure: f64) -> Vec<u8> {
    let w = XyzWeights::new(&cube.wavelengths_nm);
    let b = cube.bands();
    let mut out = Vec::with_capacity(cube.height * cube.width * 3);
    for px in cube.data.chunks_exact(b) {
        let rgb = xyz_to_linear_srgb(w.xyz(px));
        for c in rgb {
            out.push((srgb_encode((c * exposure).clamp(0.0, 1.0)) * 255.0).round() as u8);
        }
    }
    out
}

/// Write [`cube_to_srgb8`] as an 8-bit RGB PNG, atomically.
pub fn save_srgb_png(cube: &SpectralCube, exposure: f64, path: &Path) -> Result<()> {
    let bytes = cube_to_srgb8(cube, exposure);
    let img = image::RgbImage::from_raw(cube.width as u32, cube.height as u32, bytes).expect("sized above");
    let mut buf = std::io::Cursor::new(Vec::new());
    img.write_to(&mut buf, image::ImageFormat::Png).map_err(|e| crate::error::Error::File { path: path.display().to_string(), message: format!("cannot encode PNG: {e}") })?;
    crate::io::write_atomic(path, buf.get_ref())?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::super::color_tables::{COLORCHECKER_OHTA, COLORCHECKER_SRGB_FIXTURE};
    use super::*;

    fn table_wavelengths() -> Vec<f64> {
        (0..TABLE_LEN).map(|i| TABLE_START_NM + TABLE_STEP_NM * i as f64).collect()
    }

    /// Our spectrum → sRGB equals colour-science's (`XYZ_to_sRGB`) on the 24 measured chart spectra.
    #[test]
    fn chart_srgb_matches_colour_science() {
        let ws = table_wavelengths();
        for (k, refl) in COLORCHECKER_OHTA.iter().enumerate() {
            let lin = reflectance_to_srgb(&ws, refl);
            for c in 0..3 {
                let ours = srgb_encode(lin[c]);
                assert!((ours - COLORCHECKER_SRGB_FIXTURE[k][c]).abs() < 2e-3, "patch {k} channel {c}: {ours} vs {}", COLORCHECKER_SRGB_FIXTURE[k][c]);
            }
        }
    }

    #[test]
    fn transfer_function_round_trip_and_matrices_invert() {
        for i in 0..=100 {
            let v = i as f64 / 100.0;
            assert!((srgb_encode(srgb_decode(v)) - v).abs() < 1e-12);
        }
        let x = [0.3, 0.5, 0.2];
        let back = linear_srgb_to_xyz(xyz_to_linear_srgb(x));
        assert!((0..3).all(|c| (back[c] - x[c]).abs() < 1e-3), "{back:?}");
        assert!(delta_e76(x, x) == 0.0);
    }
}
