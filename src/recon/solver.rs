//! Solver settings, result and the shared pieces of GAP-TV ([`super::gap`]) and ADMM-TV ([`super::admm`]):
//! the diagonal preconditioner, residual norms and input checks. Solvers see only a
//! `&dyn` [`Operator`].
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
//! are left out of the data term (the bound still holds on the rest, whose row sums only shrink).
//!
//! ```
//! use diffcassi::recon::{solver::{reconstruct, SolverConfig}, shift::ShiftOperator, CubeShape, ImageShape, Operator};
//! use diffcassi::render::Mask;
//! let shape = CubeShape { height: 16, width: 16, bands: 4 };
//! let op = ShiftOperator::new(shape, ImageShape { height: 16, width: 22 }, &Mask::random(16, 16, 0.5, 1)?,
//!                             0, vec![0, 2, 4, 6], 1, 1)?;
//! let truth = vec![0.5f32; shape.len()];
//! let y = (&op as &dyn Operator).apply(&truth)?;
//! let mut cfg = SolverConfig::gap_tv();
//! cfg.iterations = 20;
//! let rec = reconstruct(&op, &y, None, &cfg, &|_, _| {})?;
//! assert_eq!(rec.residuals.len(), 20);
//! assert!(rec.final_residual < rec.residuals[0]);
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::layout::dot;
use super::operator::{CubeShape, Operator};
use super::tv::TvCoupling;
use crate::error::{Error, Result};
use rayon::prelude::*;
use std::str::FromStr;

/// d_i at or below this fraction of max d is treated as unreachable (D⁻¹ = 0).
pub const D_GUARD: f32 = 1e-6;

/// The iterative method.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SolverKind {
    /// Generalized alternating projection with TV (Yuan 2016), plain or accelerated (Liao, Li & Carin 2014).
    GapTv,
    /// ADMM with TV (plug-and-play form of Yuan's DeSCI/PnP code).
    AdmmTv,
}

impl SolverKind {
    pub fn name(&self) -> &'static str {
        match self {
            SolverKind::GapTv => "gap-tv",
            SolverKind::AdmmTv => "admm-tv",
        }
    }
}

impl FromStr for SolverKind {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "gap-tv" => Ok(SolverKind::GapTv),
            "admm-tv" => Ok(SolverKind::AdmmTv),
            _ => Err(Error::invalid(format!("unknown solver `{s}` (expected gap-tv or admm-tv)"))),
        }
    }
}

/// Settings of a reconstruction. Defaults ([`SolverConfig::gap_tv`], [`SolverConfig::admm_tv`]) follow
/// the reference defaults of PAPER.md ("How the paper's code reconstructs": 50–100 iterations, TV weight
/// 0.07–0.1, 5 inner Chambolle iterations; GAP step λ = 1 as in the MST/DeSCI codes).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SolverConfig {
    pub solver: SolverKind,
    /// Outer iterations (default 100).
    pub iterations: usize,
    /// Step λ of the projection, in (0, 2] (default 1).
    pub step: f32,
    /// Chambolle weight w of the TV denoiser (default 0.1; 0 turns the denoiser off).
    pub tv_weight: f32,
    /// Chambolle iterations per denoising (default 5).
    pub tv_iterations: usize,
    /// Band coupling of the TV (default vectorial, as the MST/DeSCI TV denoiser).
    pub tv_coupling: TvCoupling,
    /// GAP only: the accelerated update ỹ_k = ỹ_{k−1} + (y − Φθ_{k−1}) (default false: it fits the
    /// measurement harder, which pays on noiseless, exactly modelled data but amplifies model/measurement
    /// noise — on rendered SP/mSP acquisitions reconstructed with another seed's transport, plain GAP gave
    /// 15.2 dB after 100 iterations, accelerated 13.9 dB after 60 and 9.9 dB after 200; see
    /// docs/reconstruction.md).
    pub accelerated: bool,
    /// ADMM only: η added to d in the projection (y − Φv)/(d + η), relative to max d (default 0.01).
    pub admm_eta: f32,
}

impl Default for SolverConfig {
    fn default() -> Self {
        Self::gap_tv()
    }
}

impl SolverConfig {
    /// GAP-TV, plain (not accelerated): 100 iterations, λ = 1, TV weight 0.1, 5 Chambolle iterations,
    /// vectorial coupling.
    pub fn gap_tv() -> Self {
        SolverConfig { solver: SolverKind::GapTv, iterations: 100, step: 1.0, tv_weight: 0.1, tv_iterations: 5, tv_coupling: TvCoupling::Vectorial, accelerated: false, admm_eta: 0.01 }
    }

    /// ADMM-TV: as [`SolverConfig::gap_tv`] with η = 0.01·max d.
    pub fn admm_tv() -> Self {
        SolverConfig { solver: SolverKind::AdmmTv, ..Self::gap_tv() }
    }

    /// The defaults of `solver`.
    pub fn for_solver(solver: SolverKind) -> Self {
        match solver {
            SolverKind::GapTv => Self::gap_tv(),
            SolverKind::AdmmTv => Self::admm_tv(),
        }
    }

    /// Check the settings, naming the bad field.
    pub fn validate(&self) -> Result<()> {
        if self.iterations == 0 {
            return Err(Error::invalid("solver iterations must be ≥ 1 (got 0)"));
        }
        let max = crate::limits::MAX_ITERATIONS;
        if self.iterations > max || self.tv_iterations > max {
            return Err(Error::invalid(format!(
                "solver iterations {} / TV iterations {}: at most {max} each (src/limits.rs)",
                self.iterations, self.tv_iterations
            )));
        }
        if !(self.step.is_finite() && self.step > 0.0 && self.step <= 2.0) {
            return Err(Error::invalid(format!("solver step λ = {} must be in (0, 2]", self.step)));
        }
        if !(self.tv_weight.is_finite() && self.tv_weight >= 0.0) {
            return Err(Error::invalid(format!("TV weight {} must be finite and ≥ 0", self.tv_weight)));
        }
        if self.tv_weight > 0.0 && self.tv_iterations == 0 {
            return Err(Error::invalid("TV iterations must be ≥ 1 when the TV weight is > 0"));
        }
        if !(self.admm_eta.is_finite() && self.admm_eta >= 0.0) {
            return Err(Error::invalid(format!("ADMM η = {} must be finite and ≥ 0", self.admm_eta)));
        }
        Ok(())
    }
}

/// The result of [`reconstruct`]: the cube and a record the CLI serialises (the cube is written apart).
#[derive(Clone, Debug, serde::Serialize)]
pub struct Reconstruction {
    /// H×W×B, `[row][col][band]`.
    #[serde(skip)]
    pub cube: Vec<f32>,
    pub shape: CubeShape,
    pub operator: String,
    pub config: SolverConfig,
    /// Per iteration k: ‖y − Φv_k‖₂ / ‖y‖₂, v_k the point iteration k projects (GAP: θ_{k−1}; ADMM:
    /// θ_{k−1} + b_{k−1}).
    pub residuals: Vec<f64>,
    /// The same in the preconditioned norm ‖·‖_{D⁻¹} (relative to ‖y‖_{D⁻¹}).
    pub weighted_residuals: Vec<f64>,
    /// ‖y − Φθ‖₂ / ‖y‖₂ of the returned cube.
    pub final_residual: f64,
    /// Cube-sized f32 buffers the solver held (its own and the TV's; not the operator's).
    pub cube_buffers: usize,
    pub seconds: f64,
}

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
        r.par_iter().zip(self.inverse.par_iter()).map(|(v, w)| (*v as f64) * (*v as f64) * *w as f64).sum::<f64>().sqrt()
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

/// ‖a − b‖₂ (f64).
pub(crate) fn residual_norm(y: &[f32], phix: &[f32]) -> f64 {
    y.par_iter().zip(phix.par_iter()).map(|(a, b)| ((*a - *b) as f64).powi(2)).sum::<f64>().sqrt()
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

/// Reconstruct the cube from measurement `y` with the configured solver. `init` is the starting cube
/// (default 0, so the first GAP step is λΦᵀD⁻¹y); `progress(k, residual)` is called after each iteration k
/// (1-based) with its relative residual.
pub fn reconstruct(op: &dyn Operator, y: &[f32], init: Option<&[f32]>, config: &SolverConfig, progress: &(dyn Fn(usize, f64) + Sync)) -> Result<Reconstruction> {
    match config.solver {
        SolverKind::GapTv => super::gap::gap_tv(op, y, init, config, progress),
        SolverKind::AdmmTv => super::admm::admm_tv(op, y, init, config, progress),
    }
}
