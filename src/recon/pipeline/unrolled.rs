//! `--solver unrolled` in the pipeline: the unrolled network's weights chosen (`--weights FILE`, or the
//! committed weights of the render's system) and checked against the render record before any operator is
//! built ([`prepare`]: system, band count and wavelengths refused when they differ; mask, planes, rays and
//! Airy diameter warned about), then the forward pass ([`crate::recon::unrolled::unrolled`]) as the pipeline's
//! solve ([`solve_unrolled`], returning the same [`Solved`] record as the iterative solvers, so `reconstruct`
//! and `study` write it the same way).
use super::record::RenderRecord;
use super::settings::SolveSettings;
use super::solve::Solved;
use crate::error::{Error, Result};
use crate::recon::prior::unrolled::{CheckReport, Target, UnrolledNetwork};
use crate::recon::Operator;

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

/// The settings `unrolled` takes, checked before any work: the iterative solvers' options are refused (the
/// network has a fixed number of stages, its weights' `stages`), and a `--weights` file is read and checked
/// (format, architecture, tensors).
pub fn check_settings(s: &SolveSettings) -> Result<()> {
    let mut given: Vec<&str> = Vec::new();
    for (flag, on) in [
        ("--iterations", s.iterations.is_some()),
        ("--tv-weight", s.tv_weight.is_some()),
        ("--accelerated", s.accelerated),
        ("--plain", s.plain),
        ("--denoiser", s.denoiser.is_some()),
        ("--sigma-max", s.sigma_max.is_some()),
        ("--sigma-min", s.sigma_min.is_some()),
        ("--sigma-auto", s.sigma_auto),
        ("--tolerance", s.tolerance.is_some()),
        ("--tv-warmup", s.tv_warmup.is_some()),
        ("--discrepancy", s.discrepancy.is_some()),
    ] {
        if on {
            given.push(flag);
        }
    }
    if !given.is_empty() {
        return Err(Error::invalid(format!("{}: not options of --solver unrolled (a fixed number of stages, the weights' `stages`; no iterations, prior or stopping rule to set)", given.join(", "))));
    }
    if let Some(p) = &s.weights {
        UnrolledNetwork::from_file(p)?;
    }
    Ok(())
}

/// Refuse, before any work, weights that cannot serve the system named `system` (a `--weights` file
/// trained for another system, or no committed weights for it).
pub fn check_system(s: &SolveSettings, system: &str) -> Result<()> {
    let net = UnrolledNetwork::load(s.weights.as_deref(), system)?;
    if net.meta.system != system {
        return Err(Error::File {
            path: net.source.clone(),
            message: format!("metadata `system` = `{}`: the network was trained for system `{}`, the acquisition is from `{system}` — refused (give weights trained for `{system}`)", net.meta.system, net.meta.system),
        });
    }
    Ok(())
}

/// The network for `record`: `s.weights` or the committed weights of the record's system, checked against
/// the record (its system, bands, mask, planes, operator rays — after any `--operator-rays` — and Airy
/// diameter).
pub fn prepare(s: &SolveSettings, record: &RenderRecord) -> Result<PreparedUnrolled> {
    let system = record.system.name();
    let net = UnrolledNetwork::load(s.weights.as_deref(), system)?;
    let c = &record.config;
    let check = net.check(&Target {
        system,
        bands_nm: record.bands_nm(),
        mask: &record.mask.values,
        mask_height: record.mask.height,
        mask_width: record.mask.width,
        planes: c.spectral.planes(),
        rays: c.rays_per_pixel,
        airy_diameter_px: c.airy.map(|a| a.diameter_px),
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
        let mut phi_t = vec![0.0f32; y.len()];
        op.apply_into(t, &mut phi_t);
        let ny = y.iter().map(|v| (*v as f64).powi(2)).sum::<f64>().sqrt();
        let r = y.iter().zip(&phi_t).map(|(a, b)| ((*a - *b) as f64).powi(2)).sum::<f64>().sqrt();
        o.insert("truth_residual".into(), serde_json::json!(if ny > 0.0 { r / ny } else { 0.0 }));
        o.insert("psnr_per_iteration".into(), serde_json::json!(psnrs));
    }
    let settings = serde_json::json!({"network": p.net.describe(), "scale": out.scale, "checks": p.check.record});
    Ok(Solved { cube: out.cube, residuals: out.residuals, final_residual: out.final_residual, settings, stopping, seconds: out.seconds })
}
