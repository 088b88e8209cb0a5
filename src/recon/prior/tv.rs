//! Chambolle's total-variation denoiser ([`crate::recon::tv::tv_denoise`]) as a [`Denoiser`]: the prior of
//! GAP-TV and ADMM-TV. The weight w (Chambolle's / scikit-image's) sets its strength; σ is ignored, so the
//! TV solvers called through this trait reproduce the direct calls bit for bit (tested in
//! `tests/recon_pnp.rs`).
//!
//! ```
//! use diffcassi::recon::prior::{tv::TvDenoiser, Denoiser};
//! use diffcassi::recon::{tv::{tv_denoise, TvScratch}, CubeShape, TvCoupling};
//! let shape = CubeShape { height: 6, width: 5, bands: 3 };
//! let x: Vec<f32> = (0..shape.len()).map(|i| ((i * 7) % 11) as f32 / 11.0).collect();
//! let (mut a, mut b) = (vec![0.0; x.len()], vec![0.0; x.len()]);
//! TvDenoiser::new(0.1, 5, TvCoupling::Vectorial).denoise(&x, &mut a, shape, 0.3)?;
//! tv_denoise(&x, &mut b, shape, 0.1, 5, TvCoupling::Vectorial, &mut TvScratch::default());
//! assert_eq!(a, b);
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::Denoiser;
use crate::error::{Error, Result};
use crate::recon::operator::CubeShape;
use crate::recon::tv::{tv_denoise, TvCoupling, TvScratch};

/// TV denoising with a fixed weight, iteration count and band coupling; its scratch is reused across calls.
#[derive(Clone, Debug)]
pub struct TvDenoiser {
    /// Chambolle weight w (0: the identity).
    pub weight: f32,
    /// Chambolle iterations per call.
    pub iterations: usize,
    pub coupling: TvCoupling,
    scratch: TvScratch,
}

impl TvDenoiser {
    pub fn new(weight: f32, iterations: usize, coupling: TvCoupling) -> Self {
        TvDenoiser { weight, iterations, coupling, scratch: TvScratch::default() }
    }
}

impl Denoiser for TvDenoiser {
    fn name(&self) -> String {
        "tv".into()
    }

    fn denoise(&mut self, x: &[f32], out: &mut [f32], shape: CubeShape, _sigma: f32) -> Result<()> {
        if x.len() != shape.len() || out.len() != shape.len() {
            return Err(Error::invalid(format!("TV denoiser: the cube has {} values (output {}), the shape {}×{}×{} needs {}", x.len(), out.len(), shape.height, shape.width, shape.bands, shape.len())));
        }
        tv_denoise(x, out, shape, self.weight, self.iterations, self.coupling, &mut self.scratch);
        Ok(())
    }

    fn cube_buffers(&self) -> usize {
        if self.weight > 0.0 && self.iterations > 0 {
            4
        } else {
            0
        }
    }

    fn describe(&self) -> serde_json::Value {
        serde_json::json!({ "name": "tv", "weight": self.weight, "iterations": self.iterations, "coupling": self.coupling })
    }
}
