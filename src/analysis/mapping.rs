use crate::rays::RayBatch;
use crate::error::{Error, Result};
use crate::system::SequentialSystem;
use crate::tracer::{RayStatus, Tracer};

/// The scene → detector mapping f(x_s, y_s, λ) = (x_d, y_d) of the reference paper: the chief ray of every
/// scene pixel centre at every wavelength.
#[derive(Clone, Debug)]
pub struct MappingCube {
    pub height: usize,
    pub width: usize,
    pub wavelength_nm: Vec<f64>,
    pub pixel_pitch_mm: f64,
    /// Detector (x, y) mm, C order `[row][col][λ][xy]`. Entries of rays that did not arrive are 0 and
    /// flagged in `valid`.
    pub positions_mm: Vec<f64>,
    /// 1 where the chief ray arrived, 0 otherwise, C order `[row][col][λ]`.
    pub valid: Vec<u8>,
}

impl MappingCube {
    /// Scene coordinates (mm) of pixel (row, col): centred grid, row 0 at +y (top), col 0 at −x.
    pub fn scene_xy(height: usize, width: usize, pitch_mm: f64, row: usize, col: usize) -> [f64; 2] {
        [(col as f64 + 0.5 - width as f64 / 2.0) * pitch_mm, (height as f64 / 2.0 - row as f64 - 0.5) * pitch_mm]
    }
    pub fn get(&self, row: usize, col: usize, band: usize) -> Option<[f64; 2]> {
        let k = (row * self.width + col) * self.wavelength_nm.len() + band;
        (self.valid[k] == 1).then(|| [self.positions_mm[2 * k], self.positions_mm[2 * k + 1]])
    }
    pub fn invalid_count(&self) -> usize {
        self.valid.iter().filter(|v| **v == 0).count()
    }
}

/// Trace the H×W×Nλ chief rays (one wavelength plane per batch, so memory stays O(H·W)).
pub fn mapping_cube(system: &SequentialSystem, tracer: &dyn Tracer, height: usize, width: usize, pixel_pitch_mm: f64, wavelengths_nm: &[f64]) -> Result<MappingCube> {
    if height == 0 || width == 0 || wavelengths_nm.is_empty() {
        return Err(Error::invalid(format!("mapping cube {height}×{width}×{}: every dimension must be ≥ 1", wavelengths_nm.len())));
    }
    if !(pixel_pitch_mm.is_finite() && pixel_pitch_mm > 0.0) {
        return Err(Error::invalid(format!("pixel pitch {pixel_pitch_mm} mm: must be finite and > 0")));
    }
    let nl = wavelengths_nm.len();
    let mut fields = Vec::with_capacity(height * width);
    for r in 0..height {
        for c in 0..width {
            fields.push(MappingCube::scene_xy(height, width, pixel_pitch_mm, r, c));
        }
    }
    let mut positions_mm = vec![0.0; height * width * nl * 2];
    let mut valid = vec![0u8; height * width * nl];
    for (b, &w) in wavelengths_nm.iter().enumerate() {
        let out = tracer.trace(system, &RayBatch::chief_rays(system, &fields, w)?)?;
        for p in 0..fields.len() {
            let k = p * nl + b;
            if out.status[p] == RayStatus::Ok {
                positions_mm[2 * k] = out.x[p];
                positions_mm[2 * k + 1] = out.y[p];
                valid[k] = 1;
            }
        }
    }
    Ok(MappingCube { height, width, wavelength_nm: wavelengths_nm.to_vec(), pixel_pitch_mm, positions_mm, valid })
}
