//! Priors as denoisers: "a prior, TV or a network, is a denoiser the solver calls". The plug-and-play view
//! (S. V. Venkatakrishnan, C. A. Bouman, B. Wohlberg, "Plug-and-play priors for model based reconstruction",
//! GlobalSIP 2013; X. Yuan, Y. Liu, J. Suo, Q. Dai, "Plug-and-play algorithms for large-scale snapshot
//! compressive imaging", CVPR 2020): a GAP or ADMM data step alternates with a call `denoise(x, σ)`, and the
//! prior is whatever denoiser is plugged in. [`Denoiser`] is that interface; its implementations:
//!
//! - [`tv::TvDenoiser`]: Chambolle's TV ([`crate::recon::tv`]), the prior of GAP-TV / ADMM-TV. Its strength is
//!   its weight; it ignores σ (so GAP-TV through this trait is bit for bit GAP-TV);
//! - [`network::SpectralUNet`]: the learned prior (arch `spectral-unet-v2`, `diffcassi/denoiser.py`), run on
//!   candle's CPU tensors; its weights are embedded ([`network::SpectralUNet::embedded`]) or read from a
//!   safetensors file.
//!
//! Cubes are H×W×B, `[row][col][band]` (as everywhere in [`crate::recon`]); σ is the standard deviation of
//! the noise the denoiser should remove, on the cube's own scale.
//!
//! ```
//! use diffcassi::recon::prior::{tv::TvDenoiser, Denoiser};
//! use diffcassi::recon::{CubeShape, TvCoupling};
//! let shape = CubeShape { height: 8, width: 8, bands: 2 };
//! let noisy: Vec<f32> = (0..shape.len()).map(|i| if i % 3 == 0 { 0.6 } else { 0.4 }).collect();
//! let mut tv = TvDenoiser::new(0.1, 20, TvCoupling::Vectorial);
//! let mut out = vec![0.0; shape.len()];
//! tv.denoise(&noisy, &mut out, shape, 0.0)?;
//! let spread = |v: &[f32]| v.iter().cloned().fold(f32::MIN, f32::max) - v.iter().cloned().fold(f32::MAX, f32::min);
//! assert!(spread(&out) < spread(&noisy));
//! # Ok::<(), diffcassi::Error>(())
//! ```
pub mod dihedral;
pub mod network;
pub mod unrolled;
pub mod unrolled_v2;
pub mod tv;

use super::operator::CubeShape;
use crate::error::Result;

/// A denoiser: the prior of a plug-and-play solver.
pub trait Denoiser: Send {
    /// A short name for records (`tv`, `spectral-unet-v2`).
    fn name(&self) -> String;
    /// `out` ← denoise(`x`) for a cube of `shape` (`[row][col][band]`) with noise level `sigma` (standard
    /// deviation on the cube's scale; a denoiser with a fixed strength, such as TV, may ignore it). Both
    /// slices hold `shape.len()` values. Errors (never panics) on a shape the denoiser cannot handle.
    fn denoise(&mut self, x: &[f32], out: &mut [f32], shape: CubeShape, sigma: f32) -> Result<()>;
    /// Cube-sized f32 buffers the denoiser holds between calls (for the solvers' memory record).
    fn cube_buffers(&self) -> usize {
        0
    }
    /// A JSON record of the denoiser (name, weights, settings) for `reconstruct.json`.
    fn describe(&self) -> serde_json::Value {
        serde_json::json!({ "name": self.name() })
    }
    /// The caller's stop request for the following calls ([`crate::cancel`]; `None`: never stopped): a slow
    /// denoiser (the network: per layer) polls it inside a call and returns [`crate::Error::Interrupted`] once
    /// it is cancelled. A fast one (TV: one solver iteration's worth) ignores it, the solver polling between calls.
    fn set_cancel(&mut self, _cancel: Option<crate::cancel::Cancel>) {}
}
