use crate::rays::RayBatch;
use crate::error::{Error, Result};
use crate::system::SequentialSystem;
use crate::tracer::{RayStatus, Tracer};

/// Spatio-spectral spreading: where the chief ray of one field lands as a function of wavelength.
#[derive(Clone, Debug, serde::Serialize)]
pub struct DispersionCurve {
    pub field_mm: [f64; 2],
    pub wavelength_nm: Vec<f64>,
    pub x_mm: Vec<f64>,
    pub y_mm: Vec<f64>,
    /// Distance between the first and last wavelength's positions (µm): the paper's spreading (≈ 830 µm).
    pub spread_um: f64,
}

/// Chief-ray positions of `field_mm` at each wavelength (the central field for the paper's curve).
pub fn dispersion_curve(system: &SequentialSystem, tracer: &dyn Tracer, field_mm: [f64; 2], wavelengths_nm: &[f64]) -> Result<DispersionCurve> {
    if wavelengths_nm.is_empty() {
        return Err(Error::invalid("dispersion curve: no wavelengths"));
    }
    let (mut xs, mut ys) = (Vec::new(), Vec::new());
    for &w in wavelengths_nm {
        let out = tracer.trace(system, &RayBatch::chief_rays(system, &[field_mm], w)?)?;
        if out.status[0] != RayStatus::Ok {
            return Err(Error::invalid(format!(
                "dispersion curve: the chief ray of field ({}, {}) mm at {w} nm is {} at surface {}",
                field_mm[0], field_mm[1], out.status[0].label(), out.surface[0]
            )));
        }
        xs.push(out.x[0]);
        ys.push(out.y[0]);
    }
    let last = xs.len() - 1;
    let spread_um = 1e3 * (xs[last] - xs[0]).hypot(ys[last] - ys[0]);
    Ok(DispersionCurve { field_mm, wavelength_nm: wavelengths_nm.to_vec(), x_mm: xs, y_mm: ys, spread_um })
}

/// `n` wavelengths evenly spaced over [first, last] nm (the paper's 28 bands: `linspace(450, 650, 28)`).
pub fn linspace(first: f64, last: f64, n: usize) -> Vec<f64> {
    match n {
        0 => vec![],
        1 => vec![first],
        _ => (0..n).map(|i| first + (last - first) * i as f64 / (n - 1) as f64).collect(),
    }
}
