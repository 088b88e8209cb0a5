//! The unrolled network's forward pass around any [`Operator`] (`UnrolledGAP.forward` and
//! `UnrolledDAUHST.forward` in `diffcassi/unrolled.py`): K GAP stages, each followed by its learned prior
//! ([`UnrolledNetwork`], [`crate::recon::prior::unrolled`], [`crate::recon::prior::unrolled_v2`]). With d = ΦΦᵀ𝟙
//! and D⁻¹ = 1/d where d > 10⁻⁶·max d, else 0 (the solvers' [`Preconditioner`]):
//!
//! ```text
//! x₀ = Φᵀ(y ⊙ D⁻¹);  s = mean|x₀| (x₀ = 0: the output is 0);  r_k = Φᵀ((y − Φ x_{k−1}) ⊙ D⁻¹)
//! unrolled-gap-v1:     v_k = x_{k−1} + λ_k r_k;                                 x_k = s · D_k(v_k / s)
//! unrolled-dauhst-v2:  (μ_k, σ_k) = E_k(x_{k−1}/s, r_k/s);  v_k = x_{k−1} + μ_k r_k;  x_k = s · P_k(v_k / s, σ_k)
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
    /// v2: the per-stage degradation estimates (μ_k, σ_k); empty for v1.
    pub estimates: Vec<(f32, f32)>,
    pub seconds: f64,
}

impl UnrolledOutput {
    /// The v2 estimates as JSON, `[{"mu": μ_1, "sigma": σ_1}, …]` (empty for v1): what `reconstruct.json`
    /// (`solver_settings.estimates`) and Python's `_native._unrolled` record.
    pub fn estimates_json(&self) -> serde_json::Value {
        serde_json::json!(self.estimates.iter().map(|(m, s)| serde_json::json!({"mu": m, "sigma": s})).collect::<Vec<_>>())
    }
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
    // x₀ = Φᵀ(y ⊙ D⁻¹), s = mean|x₀| (= mean(x₀) for an acquisition ≥ 0, the trained case). The network is
    // applied at scale s — N(a·y) = a·N(y) for a > 0 — so an x₀ of zero (a dark frame, or y only where no ray
    // lands) reconstructs as zero: a scale of 1 there let the stages' biases through, a bright cube from a
    // black acquisition (a held-out battery; as did a negative-mean x₀).
    let e: Vec<f32> = y.iter().zip(dinv).map(|(a, w)| a * w).collect();
    let mut x = vec![0.0f32; cs.len()];
    op.adjoint_into(&e, &mut x);
    let mean = x.iter().map(|v| v.abs() as f64).sum::<f64>() / x.len().max(1) as f64;
    // A mean below f32's normal range (an acquisition among the subnormals) is no scale to divide by: as a zero one.
    if !(mean as f32 >= f32::MIN_POSITIVE) {
        let r0 = rel(ny);
        for k in 1..=net.stages() {
            on_stage(k, &x, r0);
        }
        return Ok(UnrolledOutput { cube: x, scale: 0.0, residuals: vec![r0; net.stages()], final_residual: r0, estimates: Vec::new(), seconds: t0.elapsed().as_secs_f64() });
    }
    let s = mean as f32;
    let mut phi = vec![0.0f32; is.len()];
    let mut r = vec![0.0f32; is.len()];
    let mut g = vec![0.0f32; cs.len()];
    let mut v = vec![0.0f32; cs.len()];
    let mut residuals = Vec::with_capacity(net.stages());
    let mut estimates = Vec::new();
    for k in 0..net.stages() {
        op.apply_into(&x, &mut phi);
        for i in 0..r.len() {
            r[i] = y[i] - phi[i];
        }
        residuals.push(rel(norm(&r)));
        for (ri, w) in r.iter_mut().zip(dinv) {
            *ri *= w;
        }
        op.adjoint_into(&r, &mut g);
        match net.v2() {
            None => {
                // v = (x + λ g) / s, denoised into x, then · s.
                let lam = net.steps[k];
                for i in 0..v.len() {
                    v[i] = (x[i] + lam * g[i]) / s;
                }
                net.denoise_stage(k, &v, &mut x, cs.height, cs.width)?;
            }
            Some(v2) => {
                // (μ, σ) from (x/s, g/s); v = (x + μ g) / s, through the prior at σ into x, then · s.
                let xs: Vec<f32> = x.iter().map(|a| a / s).collect();
                let gs: Vec<f32> = g.iter().map(|a| a / s).collect();
                let (mu, sigma) = v2.estimate(k, &xs, &gs, cs.height, cs.width)?;
                estimates.push((mu, sigma));
                for i in 0..v.len() {
                    v[i] = (x[i] + mu * g[i]) / s;
                }
                v2.prior(k, &v, sigma, &mut x, cs.height, cs.width)?;
            }
        }
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
    Ok(UnrolledOutput { cube: x, scale: s, residuals, final_residual, estimates, seconds: t0.elapsed().as_secs_f64() })
}
