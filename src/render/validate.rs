//! The single-slit check of the reference paper: a 1-pixel slit of a scene of uniform regions disperses
//! each region's spectrum along x. [`slit_prediction`] computes what the detector should show, independently
//! of the renderer's sampling: the spectrum on a fine wavelength grid (default 10 per band, 280 for the
//! paper's 28), each wavelength's rays (a uniform square grid over the pupil × a 3×3 grid over the slit
//! pixel, several rows of the region) traced to the detector, i.e. mapped through the dispersion curve and
//! spread by the geometric PSF, then blurred by the bilinear splat (a 1-pixel tent) and the Airy disk's
//! line-spread function, and averaged over rows (vertical blur moves no energy out of a uniform region's
//! interior, so the row average only sees x; a scene row covers |m_y| detector rows, m_y the vertical
//! magnification at each wavelength, which divides the energy per detector row).
use super::airy::AiryKernel;
use super::detector::Detector;
use super::engine::RenderConfig;
use super::spectral::SpectralSampling;
use crate::analysis::MappingCube;
use crate::error::Result;
use crate::rays::{PupilPattern, RayBatch};
use crate::system::SequentialSystem;
use crate::tracer::{RayStatus, Tracer};

/// Predicted mean detector row (one value per detector column) of the slit at column `slit_col`, over the
/// scene rows `rows`, for a region of spectrum `spectrum(λ)`. `fine_per_band` wavelengths per band.
#[allow(clippy::too_many_arguments)]
pub fn slit_prediction(system: &SequentialSystem, tracer: &dyn Tracer, cfg: &RenderConfig, detector: &Detector, slit_col: usize, rows: &[usize], spectrum: &dyn Fn(f64) -> f64, fine_per_band: usize) -> Result<Vec<f64>> {
    let bands = &cfg.spectral.bands_nm;
    let fine = SpectralSampling::with_planes(bands.clone(), bands.len() * fine_per_band.max(1))?;
    let pupil = PupilPattern::Grid { n: 13 }.points();
    let sub = [-1.0 / 3.0, 0.0, 1.0 / 3.0]; // 3×3 points at the centres of the pixel's ninths
    let dw = detector.width;
    let mut profile = vec![0.0f64; dw];
    for &w in &fine.planes_nm {
        let s = spectrum(w) * fine.plane_weight;
        if s == 0.0 {
            continue;
        }
        let mut batch = RayBatch::default();
        for &r in rows {
            let c = MappingCube::scene_xy(cfg.scene_height, cfg.scene_width, cfg.scene_pitch_mm, r, slit_col);
            for dy in sub {
                for dx in sub {
                    let f = [c[0] + dx * cfg.scene_pitch_mm, c[1] + dy * cfg.scene_pitch_mm];
                    batch.extend(&RayBatch::for_field(system, f, &pupil, w)?);
                }
            }
        }
        let out = tracer.trace(system, &batch)?;
        // Energy per detector row: a scene row spreads over |m_y| detector rows (m_y the vertical
        // magnification at this wavelength, from the chief rays of the first and last rows).
        let m_y = if rows.len() > 1 {
            let (ra, rb) = (rows[0], rows[rows.len() - 1]);
            let f = [ra, rb].map(|r| MappingCube::scene_xy(cfg.scene_height, cfg.scene_width, cfg.scene_pitch_mm, r, slit_col));
            let c = tracer.trace(system, &RayBatch::chief_rays(system, &f, w)?)?;
            let dv = (c.y[1] - c.y[0]).abs() / detector.pitch_mm;
            let ds = (rb as f64 - ra as f64).abs() * cfg.scene_pitch_mm / detector.pitch_mm;
            if c.status.iter().all(|s| *s == RayStatus::Ok) && dv > 0.0 { dv / ds } else { 1.0 }
        } else {
            1.0
        };
        let per_ray = s / out.len() as f64 / m_y; // mean over the sampled rows and rays
        // Tent (bilinear) deposit of each ray's column coordinate.
        let mut tent = vec![0.0f64; dw];
        for i in 0..out.len() {
            if out.status[i] != RayStatus::Ok {
                continue;
            }
            let (u, _) = detector.to_pixel(out.x[i], out.y[i]);
            let j = u.floor();
            let f = u - j;
            let j = j as i64;
            for (k, wt) in [(j, 1.0 - f), (j + 1, f)] {
                if k >= 0 && (k as usize) < dw {
                    tent[k as usize] += per_ray * wt;
                }
            }
        }
        // Airy line-spread function: the 2-D kernel summed over its rows.
        match cfg.airy {
            Some(a) => {
                let k = AiryKernel::for_wavelength(w, a.diameter_px, a.reference_nm, a.rings)?;
                let n = 2 * k.half + 1;
                let lsf: Vec<f64> = (0..n).map(|j| (0..n).map(|i| k.weights[i * n + j] as f64).sum()).collect();
                for (x, &v) in tent.iter().enumerate() {
                    if v == 0.0 {
                        continue;
                    }
                    for (j, &l) in lsf.iter().enumerate() {
                        let t = x as i64 + j as i64 - k.half as i64;
                        if t >= 0 && (t as usize) < dw {
                            profile[t as usize] += v * l;
                        }
                    }
                }
            }
            None => profile.iter_mut().zip(&tent).for_each(|(a, b)| *a += b),
        }
    }
    Ok(profile)
}

/// Mean over detector rows `det_rows` of `image` (detector-sized, row-major): one value per column.
pub fn mean_rows(image: &[f64], detector: &Detector, det_rows: &[usize]) -> Vec<f64> {
    let w = detector.width;
    let mut m = vec![0.0; w];
    for &r in det_rows {
        for (a, b) in m.iter_mut().zip(&image[r * w..(r + 1) * w]) {
            *a += b;
        }
    }
    m.iter_mut().for_each(|v| *v /= det_rows.len() as f64);
    m
}
