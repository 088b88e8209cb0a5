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
        _ => {
            let span = last - first;
            if (span * (n - 1) as f64).is_finite() {
                // The usual form, whose bits the presets' band centres and the tests pin.
                (0..n).map(|i| first + span * i as f64 / (n - 1) as f64).collect()
            } else {
                // Finite ends whose difference (or its product with the index) overflows: the weighted mean
                // a·(1−t) + b·t, each term within the ends' magnitude, stays finite and ends exactly at `last`
                // (round 21: linspace(-1e308, 1e308, 3) gave [NaN, inf, inf]).
                (0..n)
                    .map(|i| {
                        let t = i as f64 / (n - 1) as f64;
                        first * (1.0 - t) + last * t
                    })
                    .collect()
            }
        }
    }
}

#[cfg(test)]
mod linspace_tests {
    use super::linspace;

    /// Finite ends give finite values even when their difference overflows f64 (round 21), ending exactly at
    /// the ends; ordinary ranges keep the usual form's bits (the presets' bands).
    #[test]
    fn finite_ends_stay_finite_and_ordinary_ranges_keep_their_bits() {
        assert_eq!(linspace(-1e308, 1e308, 3), vec![-1e308, 0.0, 1e308]);
        for (a, b, n) in [(-1.7e308, 1.7e308, 5), (0.0, f64::MAX, 4), (-f64::MAX, f64::MAX, 1001), (f64::MAX, -f64::MAX, 7)] {
            let v = linspace(a, b, n);
            assert!(v.iter().all(|x| x.is_finite()), "{a} {b} {n}: {v:?}");
            assert_eq!((v[0], v[n - 1]), (a, b));
            assert!(v.windows(2).all(|w| (b > a && w[1] >= w[0]) || (b < a && w[1] <= w[0])), "{a} {b} {n}: not monotone");
        }
        for (a, b, n) in [(450.0, 650.0, 28), (400.0, 700.0, 31), (-2.5, 2.5, 13), (0.0, 1.0, 1000)] {
            let usual: Vec<f64> = (0..n).map(|i| a + (b - a) * i as f64 / (n - 1) as f64).collect();
            assert_eq!(linspace(a, b, n), usual);
        }
    }
}
