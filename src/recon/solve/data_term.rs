//! The data term the solvers share: the diagonal preconditioner D = diag(ΦΦᵀ𝟙), the residual norms (f64,
//! deterministic for any thread count) and the check of a measurement and a start cube against the operator.
//!
//! **Preconditioner.** The field's GAP divides the residual by ΦΦᵀ, which is diagonal only when each voxel
//! lands on one pixel (the `shift` model). For `exact` (a voxel spreads over a footprint and an Airy disk)
//! and bilinear `mapping` it is not, so both solvers use D = diag(d), d = ΦΦᵀ𝟙 (one Φᵀ and one Φ). For
//! non-negative Φ this majorises ΦΦᵀ: A = ΦΦᵀ is symmetric with non-negative entries and row sums d, and by
//! the Schur test (Gershgorin's row-sum bound applied to D^{-½} A D^{-½}, whose rows weighted by d^{½}
//! sum to d^{½}) the spectral radius of D^{-½} A D^{-½} is ≤ 1, i.e. A ⪯ D. Hence the projection step
//! x ← x + λ Φᵀ D⁻¹ (y − Φx), 0 < λ ≤ 2, never increases the data term ‖y − Φx‖_{D⁻¹} =
//! (Σ_i (y − Φx)_i² / d_i)^½ (the residual evolves as r ← (I − λ A D⁻¹) r). Entries with
//! d_i ≤ [`D_GUARD`]·max d (pixels no voxel reaches, or only the far tail of a footprint) get D⁻¹ = 0: they
use super::config::SolverConfig;
use crate::error::{Error, Result};
use crate::recon::layout::dot;
use crate::recon::operator::Operator;
use rayon::prelude::*;

/// d_i at or below this fraction of max d is treated as unreachable (D⁻¹ = 0).
pub const D_GUARD: f32 = 1e-6;

/// d = ΦΦᵀ𝟙 and its guarded inverse (see the [module docs](self)).
pub struct Preconditioner {
    pub d: Vec<f32>,
    pub inverse: Vec<f32>,
}

impl Preconditioner {
    pub fn new(op: &dyn Operator) -> Self {
        let ones = vec![1.0f32; op.image_shape().len()];
        let mut x = vec![0.0f32; op.cube_shape().len()];
        op.adjoint_into(&ones, &mut x);
        let mut d = vec![0.0f32; ones.len()];
        op.apply_into(&x, &mut d);
        let max = d.iter().cloned().fold(0.0f32, f32::max);
        let inverse = d.iter().map(|&v| if v > D_GUARD * max { 1.0 / v } else { 0.0 }).collect();
        Preconditioner { d, inverse }
    }

    /// ‖r‖_{D⁻¹} = (Σ r_i² / d_i)^½ over the kept pixels.
    pub fn weighted_norm(&self, r: &[f32]) -> f64 {
        let parts: Vec<f64> = r.par_chunks(REDUCE_CHUNK).zip(self.inverse.par_chunks(REDUCE_CHUNK)).map(|(r, w)| r.iter().zip(w).map(|(v, w)| (*v as f64) * (*v as f64) * *w as f64).sum::<f64>()).collect();
        parts.iter().sum::<f64>().sqrt()
    }

    /// Largest d.
    pub fn max(&self) -> f32 {
        self.d.iter().cloned().fold(0.0, f32::max)
    }
}

/// Check a measurement and an optional initial cube against the operator.
pub(crate) fn check_inputs(op: &dyn Operator, y: &[f32], init: Option<&[f32]>, config: &SolverConfig) -> Result<()> {
    config.validate()?;
    let (c, i) = (op.cube_shape(), op.image_shape());
    if y.len() != i.len() {
        return Err(Error::invalid(format!("the measurement has {} values, the operator `{}` expects {}×{} = {}", y.len(), op.name(), i.height, i.width, i.len())));
    }
    if let Some(k) = y.iter().position(|v| !v.is_finite()) {
        return Err(Error::invalid(format!("the measurement's value at row {}, column {} is {} (not finite)", k / i.width, k % i.width, y[k])));
    }
    if let Some(x) = init {
        if x.len() != c.len() {
            return Err(Error::invalid(format!("the initial cube has {} values, expected {}×{}×{} = {}", x.len(), c.height, c.width, c.bands, c.len())));
        }
        if let Some(k) = x.iter().position(|v| !v.is_finite()) {
            return Err(Error::invalid(format!("the initial cube's value {k} is {} (not finite)", x[k])));
        }
    }
    Ok(())
}

/// Fixed chunk length of the f64 reductions below: partial sums per chunk, added in chunk order, so the
/// stopping rule's norms (and the δ̂ they are compared with) are bit-identical for any thread count.
const REDUCE_CHUNK: usize = 1 << 16;

/// ‖a − b‖₂ (f64; deterministic for any thread count).
pub(crate) fn residual_norm(y: &[f32], phix: &[f32]) -> f64 {
    let parts: Vec<f64> = y.par_chunks(REDUCE_CHUNK).zip(phix.par_chunks(REDUCE_CHUNK)).map(|(a, b)| a.iter().zip(b).map(|(a, b)| ((*a - *b) as f64).powi(2)).sum::<f64>()).collect();
    parts.iter().sum::<f64>().sqrt()
}

/// ‖y‖₂, or 1 for a zero measurement (so relative residuals stay finite).
pub(crate) fn scale(y: &[f32]) -> f64 {
    let n = dot(y, y).sqrt();
    if n > 0.0 {
        n
    } else {
        1.0
    }
}
