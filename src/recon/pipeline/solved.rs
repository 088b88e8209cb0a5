//! The record of one solve, whichever solver made it ([`Solved`]: the iterative solvers of [`super::solve`] and
//! the unrolled network of [`super::unrolled`]), and the evaluation both add with a truth cube.
use crate::recon::Operator;
use serde_json::Value;

/// The result of a solve: the cube (C order), the per-iteration relative data residual, the solver's
/// resolved settings and record (JSON) and seconds.
pub struct Solved {
    pub cube: Vec<f32>,
    /// Per iteration k: ‖y − Φv_k‖₂ / ‖y‖₂ ([`crate::recon::Reconstruction::residuals`]).
    pub residuals: Vec<f64>,
    pub final_residual: f64,
    pub settings: Value,
    /// The stopping rule and what ended the run (`{"rule", "tolerance", "stopped_by", "relative_changes"}`).
    pub stopping: Value,
    pub seconds: f64,
}

impl Solved {
    /// What the run says beside its numbers (`stopping.warnings`: a diverged iteration, a threshold τδ at or
    /// above ‖y‖; [`crate::recon::Reconstruction::warnings`]), for the front ends to print.
    pub fn warnings(&self) -> impl Iterator<Item = &str> {
        self.stopping.get("warnings").and_then(Value::as_array).into_iter().flatten().filter_map(Value::as_str)
    }
}

/// Φx_true and ‖y − Φx_true‖₂/‖y‖₂ (0 for a black `y`): the record's `truth_residual`, evaluation only.
pub(super) fn truth_residual(op: &dyn Operator, y: &[f32], truth: &[f32]) -> (Vec<f32>, f64) {
    let mut phi_t = vec![0.0f32; y.len()];
    op.apply_into(truth, &mut phi_t);
    let ny = y.iter().map(|v| (*v as f64).powi(2)).sum::<f64>().sqrt();
    let r = y.iter().zip(&phi_t).map(|(a, b)| ((*a - *b) as f64).powi(2)).sum::<f64>().sqrt();
    (phi_t, if ny > 0.0 { r / ny } else { 0.0 })
}
