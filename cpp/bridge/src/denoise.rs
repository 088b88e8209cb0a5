//! The learned denoiser (`spectral-unet-v2`, the prior of the `pnp-gap`/`pnp-admm` solvers) for C++: a cube
//! (H×W×B f32, C order `[row][col][band]`) is read in place and the denoised cube written into the caller's
//! buffer of the same size. `weights` empty: the checkpoint embedded in the library; otherwise a safetensors
//! file. σ is the noise standard deviation on the cube's scale (the network was trained on cubes of peak ≈ 1).
//! The result equals `diffcassi.denoise` (Python) and the CLI's bit for bit (one Rust implementation,
//! `diffcassi::recon::prior::network`).
//!
//! ```
//! let cube = vec![0.5f32; 8 * 8 * 28];
//! let mut out = vec![0.0f32; cube.len()];
//! diffcassi_cpp::denoise(&cube, 8, 8, 28, 0.05, "", &mut out)?;
//! assert!(out.iter().all(|v| v.is_finite()));
//! let e = diffcassi_cpp::denoise(&cube[..8 * 8 * 4], 8, 8, 4, 0.05, "", &mut out[..8 * 8 * 4]).err().unwrap();
//! assert!(e.to_string().contains("trained for 28 bands"), "{e}");
//! # Ok::<(), diffcassi::Error>(())
//! ```
use diffcassi::error::{Error, Result};
use diffcassi::recon::{CubeShape, Denoiser, SpectralUNet};

/// `out` ← the denoised `cube` (see the [module docs](self)).
pub fn denoise(cube: &[f32], height: usize, width: usize, bands: usize, sigma: f64, weights: &str, out: &mut [f32]) -> Result<()> {
    // In this process's pool: a fresh one in a fork() child (diffcassi::pool).
    diffcassi::pool::install(|| {
        crate::results::name_budgets();
        let shape = CubeShape { height, width, bands };
        let n = height.checked_mul(width).and_then(|v| v.checked_mul(bands)).ok_or_else(|| Error::invalid(format!("denoise: cube {height}×{width}×{bands} is too large")))?;
        if n == 0 {
            return Err(Error::invalid(format!("denoise: cube {height}×{width}×{bands} is empty")));
        }
        if cube.len() != n || out.len() != n {
            return Err(Error::invalid(format!("denoise: the cube has {} values and the output buffer {}, {height}×{width}×{bands} needs {n}", cube.len(), out.len())));
        }
        if let Some(i) = cube.iter().position(|v| !v.is_finite()) {
            return Err(Error::invalid(format!("denoise: cube value {i} is {} (not finite)", cube[i])));
        }
        // σ as given, within f32 (the network's precision): 1e300 was reported as "σ = inf", its f32 conversion.
        if !(sigma.is_finite() && sigma >= 0.0 && sigma <= f32::MAX as f64) {
            return Err(Error::invalid(format!("denoise: sigma = {} must be finite, ≥ 0 and within f32's range", diffcassi::limits::fmt_num(sigma))));
        }
        crate::system::no_nul("denoise: weights path", weights)?;
        let mut net = SpectralUNet::load(if weights.is_empty() { None } else { Some(std::path::Path::new(weights)) })?;
        net.denoise(cube, out, shape, sigma as f32)
    })
}
