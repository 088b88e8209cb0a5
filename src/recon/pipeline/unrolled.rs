//! `--solver unrolled` in the pipeline: the unrolled network's weights chosen (`--weights FILE`, or the
//! committed weights of the render's system) and checked against the render record before any operator is
//! built ([`prepare`]: system, band count and wavelengths refused when they differ; mask, planes, rays and
//! Airy diameter warned about), then the forward pass ([`crate::recon::unrolled::unrolled`]) as the pipeline's
//! solve ([`solve_unrolled`], returning the same [`Solved`] record as the iterative solvers, so `reconstruct`
//! and `study` write it the same way).
use super::record::RenderRecord;
use super::solved::Solved;
use crate::error::Result;
use crate::recon::prior::unrolled::{CheckReport, Target, UnrolledNetwork};
use crate::recon::Operator;
use std::path::Path;

/// The solver name.
pub const SOLVER: &str = "unrolled";

/// Whether `solver` names the unrolled network.
pub fn is_unrolled(solver: &str) -> bool {
    solver.trim() == SOLVER
}

/// A network loaded and checked against a render record ([`prepare`]).
pub struct PreparedUnrolled {
    pub net: UnrolledNetwork,
    pub check: CheckReport,
}

impl std::fmt::Debug for PreparedUnrolled {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "PreparedUnrolled({:?}, {} warnings)", self.net, self.check.warnings.len())
    }
}

/// A `--weights` file read and checked (format, architecture, tensors) before any work; `None` passes.
pub fn check_weights_file(weights: Option<&Path>) -> Result<()> {
    if let Some(p) = weights {
        UnrolledNetwork::from_file(p)?;
    }
    Ok(())
}

/// Refuse, before any work, weights that cannot serve the system `spec` (a `--weights` file trained for
/// another system or prescription, no committed weights for it: [`UnrolledNetwork::check_system`]).
pub fn check_system(weights: Option<&Path>, spec: &crate::spec::SystemSpec) -> Result<()> {
    UnrolledNetwork::load(weights, &spec.name)?.check_system(spec).map(|_| ())
}

/// The network for `record`: the `weights` file or the committed weights of the record's system, checked against
/// the record (its system, bands, mask, planes, operator rays — after any `--operator-rays` — and Airy
/// diameter; `operator_seed` is recorded).
pub fn prepare(weights: Option<&Path>, record: &RenderRecord, operator_seed: u64) -> Result<PreparedUnrolled> {
    let system = record.system.name();
    let net = UnrolledNetwork::load(weights, system)?;
    let c = &record.config;
    let check = net.check(&Target {
        spec: &record.system.spec,
        bands_nm: record.bands_nm(),
        mask: &record.mask.values,
        mask_height: record.mask.height,
        mask_width: record.mask.width,
        planes: c.spectral.planes(),
        rays: c.rays_per_pixel,
        airy_diameter_px: c.airy.map(|a| a.diameter_px),
        operator_seed: Some(operator_seed),
    })?;
    Ok(PreparedUnrolled { net, check })
}

/// The unrolled network on `op` and `y` as a pipeline solve: the cube, the per-stage residuals, the record
/// (`settings`: the network and the checks; `stopping`: a fixed number of stages) and, with a `truth` cube,
/// the PSNR of every stage's output (`stopping.psnr_per_iteration`) and ‖y − Φx_true‖/‖y‖. `progress(k,
/// residual)` after stage k.
pub fn solve_unrolled(op: &dyn Operator, y: &[f32], p: &PreparedUnrolled, truth: Option<&[f32]>, progress: &(dyn Fn(usize, f64) + Sync)) -> Result<Solved> {
    let shape = op.cube_shape();
    let mut psnrs: Vec<f64> = Vec::new();
    let out = crate::recon::unrolled::unrolled(op, y, &p.net, &mut |k, x, r| {
        if let Some(t) = truth {
            psnrs.push(crate::recon::metrics::psnr_db(t, x, shape).unwrap_or(f64::NAN));
        }
        progress(k, r);
    })?;
    let mut stopping = serde_json::json!({"rule": "none (a fixed number of stages)", "stopped_by": "stages", "stages": p.net.stages()});
    if let (Some(t), Some(o)) = (truth, stopping.as_object_mut()) {
        o.insert("truth_residual".into(), serde_json::json!(super::solved::truth_residual(op, y, t).1));
        o.insert("psnr_per_iteration".into(), serde_json::json!(psnrs));
    }
    let mut settings = serde_json::json!({"network": p.net.describe(), "scale": out.scale, "checks": p.check.record});
    if !out.estimates.is_empty() {
        // v2: each stage's degradation estimate (the learned step μ_k and noise level σ_k).
        settings["estimates"] = out.estimates_json();
    }
    Ok(Solved { cube: out.cube, residuals: out.residuals, final_residual: out.final_residual, settings, stopping, seconds: out.seconds })
}
