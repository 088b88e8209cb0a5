//! Cube layouts and small vector helpers shared by the operators and solvers.
//!
//! Cubes cross the [`Operator`](super::Operator) interface in C order `[row][col][band]` (band fastest, like
//! [`crate::scene::SpectralCube::data`] and an `(H, W, B)` NPY). Operators that work plane by plane
//! transpose once to band-major `[band][row][col]` (each band a contiguous image), which turns their inner
//! loops into contiguous saxpys. Both transposes are exact (copies) and parallel over rows/bands.
//!
//! ```
//! use diffcassi::recon::layout::{to_band_major, from_band_major};
//! let cube: Vec<f32> = (0..2 * 3 * 4).map(|v| v as f32).collect();
//! let bm = to_band_major(&cube, 2 * 3, 4);
//! assert_eq!(bm[1], cube[4]); // band 0 of pixel 1
//! assert_eq!(from_band_major(&bm, 2 * 3, 4), cube);
//! ```
use crate::error::{Error, Result};
use rayon::prelude::*;

/// Check an operator's band wavelengths (nm): at least one, finite, > 0, strictly increasing.
pub fn check_bands(bands_nm: &[f64]) -> Result<()> {
    if bands_nm.is_empty() {
        return Err(Error::invalid("the operator needs at least one band"));
    }
    crate::scene::SpectralCube::new(1, 1, bands_nm.to_vec(), vec![0.0; bands_nm.len()], "operator bands").map(|_| ())
}

/// `[pixel][band]` → `[band][pixel]` for `pixels` pixels of `bands` bands.
pub fn to_band_major(cube: &[f32], pixels: usize, bands: usize) -> Vec<f32> {
    let mut out = vec![0.0f32; pixels * bands];
    to_band_major_into(cube, pixels, bands, &mut out);
    out
}

/// [`to_band_major`] into an existing buffer.
pub fn to_band_major_into(cube: &[f32], pixels: usize, bands: usize, out: &mut [f32]) {
    assert_eq!(cube.len(), pixels * bands);
    assert_eq!(out.len(), pixels * bands);
    if pixels == 0 {
        return;
    }
    out.par_chunks_mut(pixels).enumerate().for_each(|(b, plane)| {
        for (q, v) in plane.iter_mut().enumerate() {
            *v = cube[q * bands + b];
        }
    });
}

/// `[band][pixel]` → `[pixel][band]`.
pub fn from_band_major(planes: &[f32], pixels: usize, bands: usize) -> Vec<f32> {
    let mut out = vec![0.0f32; pixels * bands];
    from_band_major_into(planes, pixels, bands, &mut out);
    out
}

/// [`from_band_major`] into an existing buffer.
pub fn from_band_major_into(planes: &[f32], pixels: usize, bands: usize, out: &mut [f32]) {
    assert_eq!(planes.len(), pixels * bands);
    assert_eq!(out.len(), pixels * bands);
    if bands == 0 {
        return;
    }
    const ROW: usize = 1024;
    out.par_chunks_mut(ROW * bands).enumerate().for_each(|(k, chunk)| {
        let q0 = k * ROW;
        for (i, px) in chunk.chunks_mut(bands).enumerate() {
            for (b, v) in px.iter_mut().enumerate() {
                *v = planes[b * pixels + q0 + i];
            }
        }
    });
}

/// ⟨a, b⟩ accumulated in f64.
pub fn dot(a: &[f32], b: &[f32]) -> f64 {
    a.par_chunks(1 << 16).zip(b.par_chunks(1 << 16)).map(|(x, y)| x.iter().zip(y).map(|(&u, &v)| u as f64 * v as f64).sum::<f64>()).collect::<Vec<f64>>().iter().sum()
}

/// ‖a‖₂ accumulated in f64.
pub fn norm(a: &[f32]) -> f64 {
    dot(a, a).sqrt()
}
