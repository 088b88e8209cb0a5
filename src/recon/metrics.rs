//! Quality metrics of a reconstructed cube against the truth, computed exactly as the field computes them
//! (the reference paper's code and the MST benchmark literature; see `docs/metrics.md`). Everything is
//! computed in f64 on H×W×B cubes in C order `[row][col][band]` (like [`SpectralCube::data`]).
//!
//! Notation: t = truth, e = estimate, N = H·W·B values, ê = clamp(e, 0, 1) (the paper's code clamps the
//! prediction to [0, 1] before PSNR and SSIM; RMSE and SAM use the estimate as is).
//!
//! - **RMSE** = √( (1/N) Σ (e − t)² ) over the whole cube, estimate as is.
//! - **PSNR, paper convention** ([`psnr_db`]) = 10·log₁₀( max(t)² / MSE ), MSE = (1/N) Σ (ê − t)²: one MSE
//!   over the whole cube, peak = the truth's maximum. (torchmetrics' default range is max(t) − min(t); the
//!   two agree when the truth's minimum is 0, as in KAIST scenes.)
//! - **PSNR, MST convention** ([`psnr_band_db`]) = (1/B) Σ_b 10·log₁₀( 1 / MSE_b ), MSE_b the mean of
//!   (ê − t)² over band b: per-band PSNR with peak 1 on [0, 1], averaged over bands. (MST's `torch_psnr`
//!   also quantises both cubes to multiples of 1/256 and uses 255/256 as the peak; we do not.)
//! - **SSIM** ([`ssim`]) per band, then averaged over bands (Wang et al. 2004, as piqa and scikit-image's
//!   `structural_similarity(gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1)`):
//!   with a normalised 11×11 Gaussian window w (σ = 1.5 px, radius 5 = scikit-image's `truncate=3.5`),
//!   local means μ = w∗x, population (co)variances σ_xy = w∗(xy) − μ_x μ_y, and C₁ = (0.01·L)²,
//!   C₂ = (0.03·L)² with L = 1:
//!   SSIM(x, y) = mean over valid positions of (2μ_xμ_y + C₁)(2σ_xy + C₂) / ((μ_x² + μ_y² + C₁)(σ_x² + σ_y² + C₂)).
//!   "Valid" filtering: only windows lying entirely inside the image, (H − 10)×(W − 10) positions, so a cube
//!   must be at least 11×11. Computed on (ê, t).
//! - **SAM** ([`sam_rad`]) = mean over the H·W pixels of the spectral angle
//!   θ = arccos( ⟨t, e⟩ / (‖t‖‖e‖) ) between the B-vectors of truth and estimate (as is), the cosine clamped
//!   to [−1, 1] against rounding. Zero-norm spectra: θ = 0 when both spectra are zero (identical), θ = π/2
//!   when exactly one is (a zero spectrum carries no direction; π/2 is the worst angle between non-negative
//!   spectra). Degrees = radians × 180/π.
//!
//! PSNR is +∞ when the MSE is 0 (identical cubes); the paper's PSNR is an error when the truth's maximum is
//! ≤ 0 (no peak). Shapes must match; a non-finite value is an error naming its position. When truth and
//! estimate carry different wavelengths, [`evaluate`] resamples the truth to the estimate's
//! ([`SpectralCube::resample`], linear in λ), refusing estimate bands outside the truth's range.
//!
//! ```
//! use diffcassi::recon::metrics::{evaluate, Metrics};
//! use diffcassi::scene::SpectralCube;
//! let truth = SpectralCube::uniform(16, 16, vec![450.0, 550.0, 650.0], 0.5);
//! let mut estimate = truth.clone();
//! estimate.data.iter_mut().for_each(|v| *v = 0.6);
//! let m: Metrics = evaluate(&truth, &estimate)?.metrics;
//! assert!((m.rmse - 0.1).abs() < 1e-6);
//! assert!((m.psnr_db - 10.0 * (0.25f64 / 0.01).log10()).abs() < 1e-4); // peak 0.5
//! assert!((m.psnr_band_db - 20.0).abs() < 1e-4); // peak 1
//! assert!(m.sam_rad.abs() < 1e-6); // same spectral direction
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::operator::CubeShape;
use crate::error::{Error, Result};
use crate::scene::{AtWavelengths, SpectralCube};

/// SSIM window: Gaussian σ (pixels), radius (11×11 window), and the constants K₁, K₂, data range L.
pub const SSIM_SIGMA_PX: f64 = 1.5;
pub const SSIM_RADIUS_PX: usize = 5;
pub const SSIM_K1: f64 = 0.01;
pub const SSIM_K2: f64 = 0.03;
pub const SSIM_DATA_RANGE: f64 = 1.0;

/// Every metric of one truth/estimate pair.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Metrics {
    pub rmse: f64,
    /// Paper convention: one MSE over the cube, peak = max of the truth (dB; +∞ for identical cubes).
    pub psnr_db: f64,
    /// MST convention: mean over bands of per-band PSNR with peak 1 (dB; +∞ if any band is identical).
    pub psnr_band_db: f64,
    pub ssim: f64,
    pub sam_rad: f64,
    pub sam_deg: f64,
}

/// The metrics plus what they were computed on.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Evaluation {
    pub metrics: Metrics,
    pub shape: CubeShape,
    /// The wavelengths compared (the estimate's), nm.
    pub wavelengths_nm: Vec<f64>,
    /// Whether the truth was resampled to the estimate's wavelengths.
    pub truth_resampled: bool,
    /// The (resampled) truth's maximum: the paper's PSNR peak.
    pub truth_peak: f64,
    /// Where the field's [0, 1] clamp makes PSNR and SSIM meaningless ([`clamp_warning`]); empty otherwise.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<String>,
}

/// PSNR and SSIM clamp the estimate to [0, 1] (the paper's and MST's convention): a truth beyond 1, or an
/// infinite PSNR with a non-zero RMSE (the cubes differ only outside [0, 1]), makes them meaningless — said
/// rather than left to be read as a result (`evaluate`, `study`, Python `metrics`).
pub fn clamp_warning(truth_peak: f64, m: &Metrics) -> Option<String> {
    use crate::limits::fmt_num;
    if truth_peak > 1.0 {
        Some(format!("the truth's maximum is {} > 1, but PSNR and SSIM clamp the estimate to [0, 1] (the paper's and MST's convention): they are not meaningful; normalise both cubes to [0, 1]", fmt_num(truth_peak)))
    } else if m.psnr_db == f64::INFINITY && m.rmse > 0.0 {
        Some(format!("psnr_db is inf with rmse = {}: the estimate differs from the truth only outside [0, 1], where PSNR and SSIM clamp it", fmt_num(m.rmse)))
    } else {
        None
    }
}

/// Check both slices have the shape's length and finite values.
fn check(truth: &[f32], estimate: &[f32], shape: CubeShape) -> Result<()> {
    if shape.is_empty() {
        return Err(Error::invalid(format!("empty cube shape {}×{}×{}", shape.height, shape.width, shape.bands)));
    }
    for (what, v) in [("truth", truth), ("estimate", estimate)] {
        if v.len() != shape.len() {
            return Err(Error::invalid(format!(
                "the {what} has {} values, expected {}×{}×{} = {}",
                v.len(), shape.height, shape.width, shape.bands, shape.len()
            )));
        }
        if let Some(i) = v.iter().position(|x| !x.is_finite()) {
            let b = shape.bands;
            return Err(Error::invalid(format!(
                "the {what} has a non-finite value ({}) at row {}, col {}, band {}",
                v[i], i / b / shape.width, (i / b) % shape.width, i % b
            )));
        }
    }
    Ok(())
}

#[inline]
fn clamp01(v: f32) -> f64 {
    (v as f64).clamp(0.0, 1.0)
}

/// Root-mean-square error over the whole cube (estimate as is).
pub fn rmse(truth: &[f32], estimate: &[f32], shape: CubeShape) -> Result<f64> {
    check(truth, estimate, shape)?;
    let s: f64 = truth.iter().zip(estimate).map(|(&t, &e)| (e as f64 - t as f64).powi(2)).sum();
    Ok((s / shape.len() as f64).sqrt())
}

/// 10·log₁₀(peak² / mse), +∞ for mse = 0.
fn psnr_from_mse(peak: f64, mse: f64) -> f64 {
    if mse == 0.0 {
        f64::INFINITY
    } else {
        10.0 * (peak * peak / mse).log10()
    }
}

/// The truth's maximum, PSNR's peak in the paper's convention: an error when it is not > 0 (an all-zero or
/// empty truth), where that PSNR is undefined. Callers that take a truth (`reconstruct --truth`, `study`'s
/// scenes) check it before any work and name the file.
pub fn truth_peak(truth: &[f32]) -> Result<f64> {
    let peak = truth.iter().fold(f64::NEG_INFINITY, |m, &t| m.max(t as f64));
    if !(peak > 0.0) {
        return Err(Error::invalid(format!("the truth's maximum is {peak}: the paper's PSNR (peak = max of the truth) is undefined")));
    }
    Ok(peak)
}

/// PSNR in the paper's convention: one MSE over the cube (estimate clamped to [0, 1]), peak = max of the
/// truth. Errors when the truth's maximum is ≤ 0.
pub fn psnr_db(truth: &[f32], estimate: &[f32], shape: CubeShape) -> Result<f64> {
    check(truth, estimate, shape)?;
    let peak = truth_peak(truth)?;
    let s: f64 = truth.iter().zip(estimate).map(|(&t, &e)| (clamp01(e) - t as f64).powi(2)).sum();
    Ok(psnr_from_mse(peak, s / shape.len() as f64))
}

/// PSNR in the MST convention: mean over bands of 10·log₁₀(1 / MSE_b), estimate clamped to [0, 1].
pub fn psnr_band_db(truth: &[f32], estimate: &[f32], shape: CubeShape) -> Result<f64> {
    check(truth, estimate, shape)?;
    let b = shape.bands;
    let mut sums = vec![0.0f64; b];
    for (i, (&t, &e)) in truth.iter().zip(estimate).enumerate() {
        sums[i % b] += (clamp01(e) - t as f64).powi(2);
    }
    let per_band = (shape.height * shape.width) as f64;
    Ok(sums.iter().map(|&s| psnr_from_mse(1.0, s / per_band)).sum::<f64>() / b as f64)
}

/// The normalised 1-D Gaussian window (σ = 1.5, radius 5), as scipy's `gaussian_filter(sigma=1.5, truncate=3.5)`.
pub fn ssim_window() -> [f64; 2 * SSIM_RADIUS_PX + 1] {
    let mut w = [0.0; 2 * SSIM_RADIUS_PX + 1];
    for (k, v) in w.iter_mut().enumerate() {
        let x = k as f64 - SSIM_RADIUS_PX as f64;
        *v = (-x * x / (2.0 * SSIM_SIGMA_PX * SSIM_SIGMA_PX)).exp();
    }
    let s: f64 = w.iter().sum();
    w.iter_mut().for_each(|v| *v /= s);
    w
}

/// Valid separable filtering of an `h × w` image by the window: (h − 10) × (w − 10) outputs.
fn filter_valid(img: &[f64], h: usize, w: usize, win: &[f64]) -> Vec<f64> {
    let n = win.len();
    let (oh, ow) = (h + 1 - n, w + 1 - n);
    let mut rows = vec![0.0; h * ow]; // along x
    for r in 0..h {
        for c in 0..ow {
            rows[r * ow + c] = (0..n).map(|k| win[k] * img[r * w + c + k]).sum();
        }
    }
    let mut out = vec![0.0; oh * ow]; // then along y
    for r in 0..oh {
        for c in 0..ow {
            out[r * ow + c] = (0..n).map(|k| win[k] * rows[(r + k) * ow + c]).sum();
        }
    }
    out
}

/// SSIM of one band (both `h × w`, row-major, already in f64).
fn ssim_plane(x: &[f64], y: &[f64], h: usize, w: usize, win: &[f64]) -> f64 {
    let c1 = (SSIM_K1 * SSIM_DATA_RANGE).powi(2);
    let c2 = (SSIM_K2 * SSIM_DATA_RANGE).powi(2);
    let xx: Vec<f64> = x.iter().map(|v| v * v).collect();
    let yy: Vec<f64> = y.iter().map(|v| v * v).collect();
    let xy: Vec<f64> = x.iter().zip(y).map(|(a, b)| a * b).collect();
    let [mx, my, mxx, myy, mxy] = [x, y, &xx[..], &yy[..], &xy[..]].map(|p| filter_valid(p, h, w, win));
    let mut s = 0.0;
    for i in 0..mx.len() {
        let (ux, uy) = (mx[i], my[i]);
        let (vx, vy, vxy) = (mxx[i] - ux * ux, myy[i] - uy * uy, mxy[i] - ux * uy);
        s += ((2.0 * ux * uy + c1) * (2.0 * vxy + c2)) / ((ux * ux + uy * uy + c1) * (vx + vy + c2));
    }
    s / mx.len() as f64
}

/// SSIM (11×11 Gaussian window σ = 1.5, K = (0.01, 0.03), L = 1, valid filtering, population covariance),
/// mean over bands; the estimate clamped to [0, 1]. The cube must be at least 11×11 pixels.
pub fn ssim(truth: &[f32], estimate: &[f32], shape: CubeShape) -> Result<f64> {
    check(truth, estimate, shape)?;
    let n = 2 * SSIM_RADIUS_PX + 1;
    let (h, w, b) = (shape.height, shape.width, shape.bands);
    if h < n || w < n {
        return Err(Error::invalid(format!("SSIM needs at least {n}×{n} pixels (its Gaussian window), the cube is {h}×{w}")));
    }
    let win = ssim_window();
    let mut total = 0.0;
    for k in 0..b {
        let t: Vec<f64> = (0..h * w).map(|q| truth[q * b + k] as f64).collect();
        let e: Vec<f64> = (0..h * w).map(|q| clamp01(estimate[q * b + k])).collect();
        total += ssim_plane(&e, &t, h, w, &win);
    }
    Ok(total / b as f64)
}

/// Spectral angle (rad) between two spectra; see the module docs for zero-norm spectra.
pub fn spectral_angle_rad(t: &[f32], e: &[f32]) -> f64 {
    let (mut dot, mut nt, mut ne) = (0.0f64, 0.0f64, 0.0f64);
    for (&a, &b) in t.iter().zip(e) {
        let (a, b) = (a as f64, b as f64);
        dot += a * b;
        nt += a * a;
        ne += b * b;
    }
    match (nt == 0.0, ne == 0.0) {
        (true, true) => 0.0,
        (true, false) | (false, true) => std::f64::consts::FRAC_PI_2,
        _ => (dot / (nt.sqrt() * ne.sqrt())).clamp(-1.0, 1.0).acos(),
    }
}

/// Mean spectral angle over pixels (rad), estimate as is.
pub fn sam_rad(truth: &[f32], estimate: &[f32], shape: CubeShape) -> Result<f64> {
    check(truth, estimate, shape)?;
    let b = shape.bands;
    let s: f64 = truth.chunks_exact(b).zip(estimate.chunks_exact(b)).map(|(t, e)| spectral_angle_rad(t, e)).sum();
    Ok(s / (shape.height * shape.width) as f64)
}

/// Every metric of two cubes of the same shape (raw data, C order `[row][col][band]`).
pub fn metrics(truth: &[f32], estimate: &[f32], shape: CubeShape) -> Result<Metrics> {
    let sam = sam_rad(truth, estimate, shape)?;
    Ok(Metrics {
        rmse: rmse(truth, estimate, shape)?,
        psnr_db: psnr_db(truth, estimate, shape)?,
        psnr_band_db: psnr_band_db(truth, estimate, shape)?,
        ssim: ssim(truth, estimate, shape)?,
        sam_rad: sam,
        sam_deg: sam.to_degrees(),
    })
}

/// Evaluate an estimate against the truth: same height and width required; if their wavelengths differ
/// (in count or value, beyond 1e-9 nm), the truth is resampled to the estimate's wavelengths, which must
/// lie within the truth's range.
pub fn evaluate(truth: &SpectralCube, estimate: &SpectralCube) -> Result<Evaluation> {
    if (truth.height, truth.width) != (estimate.height, estimate.width) {
        return Err(Error::invalid(format!(
            "shape mismatch: the truth is {}×{}×{} (H×W×B), the estimate {}×{}×{}",
            truth.height, truth.width, truth.bands(), estimate.height, estimate.width, estimate.bands()
        )));
    }
    let resampled;
    let (t, same) = match truth.at_wavelengths(&estimate.wavelengths_nm)? {
        AtWavelengths::Same => (truth, true),
        AtWavelengths::Resampled(r) => {
            resampled = r;
            (&resampled, false)
        }
        AtWavelengths::Outside(w) => {
            let (lo, hi) = (truth.wavelengths_nm[0], truth.wavelengths_nm[truth.bands() - 1]);
            return Err(Error::invalid(format!(
                "cannot resample the truth ({lo}–{hi} nm, {} bands) to the estimate's band at {w} nm: outside the truth's range",
                truth.bands()
            )));
        }
    };
    let shape = CubeShape { height: estimate.height, width: estimate.width, bands: estimate.bands() };
    let truth_peak = t.data.iter().fold(f64::NEG_INFINITY, |m, &v| m.max(v as f64));
    let metrics = metrics(&t.data, &estimate.data, shape)?;
    let warnings = clamp_warning(truth_peak, &metrics).into_iter().collect();
    Ok(Evaluation { metrics, shape, wavelengths_nm: estimate.wavelengths_nm.clone(), truth_resampled: !same, truth_peak, warnings })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shape(h: usize, w: usize, b: usize) -> CubeShape {
        CubeShape { height: h, width: w, bands: b }
    }

    #[test]
    fn window_is_scipy_gaussian() {
        let w = ssim_window();
        assert_eq!(w.len(), 11);
        assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-15);
        // scipy.ndimage._gaussian_kernel1d(1.5, 0, 5)[5] = 0.26601...
        assert!((w[5] - 0.2660117).abs() < 1e-6, "{}", w[5]);
        assert!((w[0] - w[10]).abs() < 1e-18 && w[0] < w[1]);
    }

    #[test]
    fn identical_cubes_are_perfect() {
        let s = shape(12, 13, 3);
        let t: Vec<f32> = (0..s.len()).map(|i| ((i * 7919) % 101) as f32 / 100.0).collect();
        let m = metrics(&t, &t, s).unwrap();
        assert_eq!(m.rmse, 0.0);
        assert_eq!(m.psnr_db, f64::INFINITY);
        assert_eq!(m.psnr_band_db, f64::INFINITY);
        assert!((m.ssim - 1.0).abs() < 1e-12);
        assert!(m.sam_rad < 1e-6);
    }

    #[test]
    fn clamping_applies_to_psnr_and_ssim_only() {
        let s = shape(11, 11, 2);
        let t = vec![0.5f32; s.len()];
        let e = vec![1.5f32; s.len()];
        // Clamped to 1: MSE 0.25 against 1.0 unclamped.
        assert!((psnr_band_db(&t, &e, s).unwrap() - 10.0 * 4f64.log10()).abs() < 1e-12);
        assert!((psnr_db(&t, &e, s).unwrap() - 10.0 * (0.25f64 / 0.25).log10()).abs() < 1e-12);
        assert!((rmse(&t, &e, s).unwrap() - 1.0).abs() < 1e-12);
        // Flat images: SSIM = (2·0.5·1 + C1)/(0.25 + 1 + C1) with zero variances.
        let c1 = 1e-4;
        assert!((ssim(&t, &e, s).unwrap() - (1.0 + c1) / (1.25 + c1)).abs() < 1e-12);
    }

    #[test]
    fn sam_of_zero_and_orthogonal_spectra() {
        let s = shape(1, 3, 2);
        let t = [0.0, 0.0, 1.0, 0.0, 0.0, 0.0];
        let e = [0.0, 0.0, 0.0, 2.0, 1.0, 1.0];
        // Both zero → 0; orthogonal → π/2; truth zero, estimate not → π/2.
        assert!((sam_rad(&t, &e, s).unwrap() - std::f64::consts::PI / 3.0).abs() < 1e-12);
    }

    #[test]
    fn bad_input_is_refused() {
        let s = shape(11, 11, 1);
        let t = vec![0.5f32; s.len()];
        let mut e = t.clone();
        e[13] = f32::NAN;
        let msg = metrics(&t, &e, s).unwrap_err().to_string();
        assert!(msg.contains("estimate") && msg.contains("row 1, col 2"), "{msg}");
        assert!(metrics(&t, &t[1..], s).unwrap_err().to_string().contains("120 values"));
        assert!(ssim(&t[..100], &t[..100], shape(10, 10, 1)).unwrap_err().to_string().contains("11×11"));
        assert!(psnr_db(&vec![0.0; 121], &t, s).unwrap_err().to_string().contains("maximum"));
        let a = SpectralCube::uniform(11, 11, vec![500.0], 0.5);
        let b = SpectralCube::uniform(11, 12, vec![500.0], 0.5);
        assert!(evaluate(&a, &b).unwrap_err().to_string().contains("shape mismatch"));
        let c = SpectralCube::uniform(11, 11, vec![400.0, 500.0], 0.5);
        let d = SpectralCube::uniform(11, 11, vec![450.0, 600.0], 0.5);
        assert!(evaluate(&c, &d).unwrap_err().to_string().contains("600"));
    }

    #[test]
    fn truth_is_resampled_to_the_estimate_wavelengths() {
        // Truth linear in λ: resampling is exact, so an estimate equal to the resampled truth is perfect.
        let ws = vec![400.0, 500.0, 600.0];
        let data: Vec<f32> = (0..11 * 11).flat_map(|q| ws.iter().map(move |w| (w / 1000.0) as f32 + q as f32 * 1e-3)).collect();
        let truth = SpectralCube::new(11, 11, ws, data, "t").unwrap();
        let est = truth.resample(&[450.0, 550.0]).unwrap();
        let ev = evaluate(&truth, &est).unwrap();
        assert!(ev.truth_resampled);
        assert_eq!(ev.wavelengths_nm, vec![450.0, 550.0]);
        assert_eq!(ev.metrics.rmse, 0.0);
        assert!(!evaluate(&truth, &truth).unwrap().truth_resampled);
    }
}
