//! The unrolled network's forward pass (arch `unrolled-gap-v1`, `UnrolledGAP.forward` in
//! `diffcassi/unrolled.py`) around any [`Operator`]: K GAP stages, each followed by its learned denoiser
//! ([`UnrolledNetwork`], [`crate::recon::prior::unrolled`]). With d = ΦΦᵀ𝟙 and D⁻¹ = 1/d where
//! d > 10⁻⁶·max d, else 0 (the solvers' [`Preconditioner`]):
//!
//! ```text
//! x₀ = Φᵀ(y ⊙ D⁻¹);  s = mean(x₀) (1 where ≤ 0)
//! for k = 1 … K:  v_k = x_{k−1} + λ_k Φᵀ((y − Φ x_{k−1}) ⊙ D⁻¹);  x_k = s · D_k(v_k / s)
//! ```
//!
//! Nothing iterates to a tolerance: the cost is fixed — 1 + K applications of Φ and 2 + K of Φᵀ (the
//! preconditioner's one of each included) plus K stage denoisers, and one more Φ for the final residual.
//! f32 throughout, like the PyTorch network in float32 (the mean s in f64); equal to PyTorch within a relative
//! 10⁻⁴ of the peak (`tests/python/test_unrolled_rust.py`, against the float64 network).
use super::operator::Operator;
use super::prior::unrolled::UnrolledNetwork;
use super::solve::data_term::Preconditioner;
use crate::error::{Error, Result};
use std::time::Instant;

/// The result of [`unrolled`].
pub struct UnrolledOutput {
    /// The cube x_K, `[row][col][band]`.
    pub cube: Vec<f32>,
    /// The scale s.
    pub scale: f32,
    /// Per stage k: ‖y − Φx_{k−1}‖₂/‖y‖₂ (the residual its data step projects; x₀ for the first).
    pub residuals: Vec<f64>,
    /// ‖y − Φx_K‖₂/‖y‖₂ of the returned cube.
    pub final_residual: f64,
    pub seconds: f64,
}

fn norm(v: &[f32]) -> f64 {
    v.iter().map(|x| (*x as f64) * (*x as f64)).sum::<f64>().sqrt()
}

/// The forward pass of `net` on the acquisition `y` through `op`; `on_stage(k, x_k, r_k)` after each stage
/// (k = 1 … K; r_k = `residuals[k − 1]`; for progress and evaluation). Errors on a band count or length mismatch, an operator that
/// reaches no pixel, and a non-finite output.
pub fn unrolled(op: &dyn Operator, y: &[f32], net: &UnrolledNetwork, on_stage: &mut dyn FnMut(usize, &[f32], f64)) -> Result<UnrolledOutput> {
    let t0 = Instant::now();
    let (cs, is) = (op.cube_shape(), op.image_shape());
    if cs.bands != net.meta.bands {
        return Err(Error::invalid(format!("unrolled: the network ({}) is for {} bands, the operator `{}` has {}", net.source, net.meta.bands, op.name(), cs.bands)));
    }
    if y.len() != is.len() {
        return Err(Error::invalid(format!("unrolled: the acquisition has {} values, the operator's {}×{} image needs {}", y.len(), is.height, is.width, is.len())));
    }
    if let Some(i) = y.iter().position(|v| !v.is_finite()) {
        return Err(Error::invalid(format!("unrolled: acquisition value {i} is {} (not finite)", y[i])));
    }
    let pre = Preconditioner::new(op);
    if !(pre.max() > 0.0 && pre.max().is_finite()) {
        return Err(Error::invalid(format!("unrolled: Φ Φᵀ 𝟙 of the operator `{}` is not finite and positive anywhere (an operator that reaches no pixel)", op.name())));
    }
    let dinv = &pre.inverse;
    let ny = norm(y);
    let rel = |r: f64| if ny > 0.0 { r / ny } else { 0.0 };
    // x₀ = Φᵀ(y ⊙ D⁻¹), s = mean(x₀).
    let e: Vec<f32> = y.iter().zip(dinv).map(|(a, w)| a * w).collect();
    let mut x = vec![0.0f32; cs.len()];
    op.adjoint_into(&e, &mut x);
    let mean = x.iter().map(|v| *v as f64).sum::<f64>() / x.len().max(1) as f64;
    let s = if mean > 0.0 { mean as f32 } else { 1.0 };
    let mut phi = vec![0.0f32; is.len()];
    let mut r = vec![0.0f32; is.len()];
    let mut g = vec![0.0f32; cs.len()];
    let mut v = vec![0.0f32; cs.len()];
    let mut residuals = Vec::with_capacity(net.stages());
    for (k, lam) in net.steps.iter().enumerate() {
        op.apply_into(&x, &mut phi);
        for i in 0..r.len() {
            r[i] = y[i] - phi[i];
        }
        residuals.push(rel(norm(&r)));
        for (ri, w) in r.iter_mut().zip(dinv) {
            *ri *= w;
        }
        op.adjoint_into(&r, &mut g);
        // v = (x + λ g) / s, denoised into x, then · s.
        for i in 0..v.len() {
            v[i] = (x[i] + lam * g[i]) / s;
        }
        net.denoise_stage(k, &v, &mut x, cs.height, cs.width)?;
        for xi in x.iter_mut() {
            *xi *= s;
        }
        on_stage(k + 1, &x, residuals[k]);
    }
    if let Some(i) = x.iter().position(|v| !v.is_finite()) {
        return Err(Error::invalid(format!("unrolled: the network ({}) produced a non-finite value at index {i}: not written", net.source)));
    }
    op.apply_into(&x, &mut phi);
    for i in 0..r.len() {
        r[i] = y[i] - phi[i];
    }
    let final_residual = rel(norm(&r));
    Ok(UnrolledOutput { cube: x, scale: s, residuals, final_residual, seconds: t0.elapsed().as_secs_f64() })
}
