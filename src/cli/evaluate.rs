//! `evaluate`: the field's quality metrics of a reconstructed cube against the truth
//! ([`crate::recon::metrics`]; formulas and conventions in `docs/metrics.md`).
//!
//! ```text
//! diffcassi evaluate --truth scene.npy --estimate out/recon/cube.npy --json out/recon/metrics.json
//! diffcassi evaluate --truth kaist/scene01.exr --estimate cave_folder/ --estimate-wavelengths 450:650:28
//! ```
//!
//! Cubes are read with the scene loaders (`.npy` with `<stem>_wavelengths_nm.npy`, multichannel `.exr`,
//! folders of per-band PNGs). When the wavelengths differ, the truth is resampled to the estimate's. Every
//! check happens before anything is written: a shape mismatch, a non-finite value or a missing file exits 1
//! with the reason and writes nothing.
use super::shared::parse_wavelengths;
use crate::error::{Error, Result};
use crate::io::write_atomic;
use crate::recon::metrics::{evaluate as evaluate_cubes, Evaluation};
use crate::scene::{load_scene, SpectralCube};
use clap::Args;
use std::path::{Path, PathBuf};

#[derive(Args, Debug)]
pub struct EvaluateArgs {
    /// The true cube: .npy (H, W, B) with <stem>_wavelengths_nm.npy, .exr, or a folder of per-band PNGs.
    #[arg(long)]
    pub truth: PathBuf,
    /// The estimate (same formats), e.g. `reconstruct`'s cube.npy.
    #[arg(long)]
    pub estimate: PathBuf,
    /// Write the metrics as JSON here (keys rmse, psnr_db, psnr_band_db, ssim, sam_rad, sam_deg, …).
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Wavelengths (nm) of the truth's bands, overriding the files': list or first:last:count.
    #[arg(long = "truth-wavelengths")]
    pub truth_wavelengths: Option<String>,
    /// Wavelengths (nm) of the estimate's bands, overriding the files'.
    #[arg(long = "estimate-wavelengths")]
    pub estimate_wavelengths: Option<String>,
}

/// Load one cube, naming the role (`truth`/`estimate`) and the option that fixes a missing wavelength list.
fn load(role: &str, path: &Path, wavelengths: Option<&str>) -> Result<SpectralCube> {
    let ws = wavelengths.map(parse_wavelengths).transpose()?;
    load_scene(path, ws.as_deref()).map_err(|e| {
        let text = e.to_string().replace("--scene-wavelengths", &format!("--{role}-wavelengths"));
        Error::invalid(format!("--{role}: {text}"))
    })
}

/// A metric for JSON: the number, or the string "inf" for an infinite PSNR (identical cubes), which JSON
/// numbers cannot hold.
fn number(v: f64) -> serde_json::Value {
    if v.is_finite() {
        v.into()
    } else if v == f64::INFINITY {
        "inf".into()
    } else {
        "-inf".into()
    }
}

/// The JSON written by `--json`.
pub fn evaluation_json(ev: &Evaluation, truth: &SpectralCube, truth_path: &Path, estimate_path: &Path) -> serde_json::Value {
    let m = &ev.metrics;
    serde_json::json!({
        "rmse": number(m.rmse),
        "psnr_db": number(m.psnr_db),
        "psnr_band_db": number(m.psnr_band_db),
        "ssim": number(m.ssim),
        "sam_rad": number(m.sam_rad),
        "sam_deg": number(m.sam_deg),
        "truth": truth_path.display().to_string(),
        "estimate": estimate_path.display().to_string(),
        "shape": [ev.shape.height, ev.shape.width, ev.shape.bands],
        "wavelengths_nm": ev.wavelengths_nm,
        "truth_shape": [truth.height, truth.width, truth.bands()],
        "truth_wavelengths_nm": truth.wavelengths_nm,
        "truth_resampled": ev.truth_resampled,
        "truth_peak": ev.truth_peak,
        "warnings": ev.warnings,
        "conventions": {
            "psnr_db": "paper: one MSE over the cube, peak = max of the truth, estimate clamped to [0, 1]",
            "psnr_band_db": "MST: mean over bands of per-band PSNR with peak 1, estimate clamped to [0, 1]",
            "ssim": "11×11 Gaussian window σ = 1.5, K = (0.01, 0.03), data range 1, valid filtering, population covariance, mean over bands; estimate clamped to [0, 1]",
            "sam": "mean spectral angle over pixels, estimate as is; 0 when both spectra are zero, π/2 when one is",
            "rmse": "whole cube, estimate as is",
        },
    })
}

pub fn evaluate(a: EvaluateArgs) -> Result<()> {
    if let Some(out) = &a.json {
        crate::io::policy::check_out_file("--json", out, &[("--truth", a.truth.as_path()), ("--estimate", a.estimate.as_path())])?;
    }
    // Both cubes are resident while the metrics run: the truth is counted while the estimate is read (whose
    // reader checks its file and f32 copy beside it), and both while the metrics' buffers are checked (each
    // reader checked its cube alone against the whole budget: 0.35 GB under a 0.24 GB budget, round 19).
    let truth = load("truth", &a.truth, a.truth_wavelengths.as_deref())?;
    let _truth_held = crate::limits::hold(format!("the --truth cube {}×{}×{}", truth.height, truth.width, truth.bands()), 4.0 * truth.data.len() as f64);
    let estimate = load("estimate", &a.estimate, a.estimate_wavelengths.as_deref())?;
    let _estimate_held = crate::limits::hold(format!("the --estimate cube {}×{}×{}", estimate.height, estimate.width, estimate.bands()), 4.0 * estimate.data.len() as f64);
    // The metrics' own buffers: the truth resampled to the estimate's bands (f32, when their bands differ) and
    // SSIM's per-band planes (about ten f64 H×W maps: the two bands, their squares and product, and their
    // filtered copies).
    let plane = estimate.height as f64 * estimate.width as f64;
    let work = 4.0 * estimate.data.len() as f64 + 10.0 * 8.0 * plane;
    crate::limits::check_memory(&format!("evaluate's metrics on {}×{}×{} (H×W×B)", estimate.height, estimate.width, estimate.bands()), work)?;
    let ev = evaluate_cubes(&truth, &estimate).map_err(|e| Error::invalid(format!("{} vs {}: {e}", a.truth.display(), a.estimate.display())))?;
    for w in &ev.warnings {
        eprintln!("warning: {w}");
    }
    let m = &ev.metrics;
    let s = ev.shape;
    println!(
        "{} (truth{}) vs {}: {}×{}×{} ({:.1}–{:.1} nm)",
        a.truth.display(),
        if ev.truth_resampled { format!(", resampled from {} bands", truth.bands()) } else { String::new() },
        a.estimate.display(),
        s.height,
        s.width,
        s.bands,
        ev.wavelengths_nm[0],
        ev.wavelengths_nm[s.bands - 1]
    );
    println!("| metric | value | convention |");
    println!("|---|---|---|");
    // Six decimals, or six significant digits beyond 10⁶ (a truth of 3e38 printed 39 digits) and below 10⁻³
    // (a truth of 1e-40 printed its peak as 0.000000; round 16).
    let six = |v: f64| if v != 0.0 && !(1e-3..1e6).contains(&v.abs()) { format!("{v:.6e}") } else { format!("{v:.6}") };
    println!("| rmse | {} | whole cube, estimate as is |", six(m.rmse));
    println!("| psnr_db | {:.4} | paper: one MSE, peak = max of the truth ({}), estimate clamped |", m.psnr_db, six(ev.truth_peak));
    println!("| psnr_band_db | {:.4} | MST: mean of per-band PSNR, peak 1, estimate clamped |", m.psnr_band_db);
    println!("| ssim | {:.6} | 11×11 Gaussian σ 1.5, valid, mean over bands, estimate clamped |", m.ssim);
    println!("| sam_rad | {:.6} | mean spectral angle, estimate as is |", m.sam_rad);
    println!("| sam_deg | {:.4} | |", m.sam_deg);
    if let Some(out) = &a.json {
        let j = evaluation_json(&ev, &truth, &a.truth, &a.estimate);
        let text = serde_json::to_string_pretty(&j).map_err(|e| Error::invalid(format!("JSON encoding failed: {e}")))?;
        write_atomic(out, text.as_bytes())?;
        println!("→ {}", out.display());
    }
    Ok(())
}
