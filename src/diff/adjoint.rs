//! Reverse-mode (adjoint) derivatives of where rays land: for a scalar loss L whose gradient with respect
//! to a ray's final state (image-frame position and direction) is λ, the gradient ∂L/∂θ for **every** free
//! parameter at a per-ray cost that does not grow with the number of parameters.
//!
//! Each path step maps the ray state s = (p, d) to s′ = F(s; θ). Its tangent (forward mode,
//! [`super::kernel`]) is linear: δs′ = A δs + B δθ, with B δθ made of the step's frame tangents (δR, δo),
//! its figure tangents ([`super::hit::ShapeTangent`]) and the index tangents (δn₁, δn₂). Reverse
//! accumulation runs the transposes backwards: λ ← Aᵀ λ, and the parameter gradient is Σ_steps λᵀ B.
//! The trick that keeps the per-ray cost O(1) in the number of parameters P is to never form B: λᵀ B δθ is
//! a linear function of the step's *tangent data* (δR, δo, δshape, δn), so per ray and step we accumulate
//! the sensitivities to those data — a 3×3 matrix G = μ_p (p − o)ᵀ + μ_d dᵀ for δR, a vector −Rᵀμ_p for δo,
//! one number per active figure coefficient and per index — summed over all rays into [`AdjointSums`].
//! The contraction with the P parameter tangents happens **once per plane** ([`AdjointPlan::contract`]).
//!
//! The step Jacobian A (and the figure/index columns) come from the forward tangent kernel itself
//! ([`super::kernel::interact_tangents`]) seeded with the six state directions plus one seed per active
//! figure coefficient and index — a fixed number of columns per step (6 to ≈ 10 on the presets) whatever
//! P is. So the values are those of the exact implicit-differentiation Jacobians, transposed.
//!
//! Rays that change status (vignetted, missing the detector) under a change of θ contribute no boundary
//! term: the gradient is that of the sampled image with the rays' statuses fixed.
//!
//! ```
//! use diffcassi::diff::{adjoint::{AdjointPlan, AdjointSums, RayTape}, ParamSet};
//! use diffcassi::materials::GlassCatalog;
//! use glam::DVec3;
//! let set = ParamSet::new(diffcassi::presets::spec("sp")?, GlassCatalog::builtin(),
//!                         vec![diffcassi::diff::Param::parse("s4.tilt_x_deg")?])?;
//! let ds = set.build()?;
//! let plan = AdjointPlan::new(&ds, &[520.0])?;
//! let (n, dn) = ds.index_tangents(520.0)?;
//! let mut tape = RayTape::default();
//! let (p, _) = plan.trace(&ds, &n, DVec3::ZERO, DVec3::Z, &mut tape).unwrap();
//! let mut sums = AdjointSums::new(&plan);
//! plan.backward(&ds, &tape, [0.0, 1.0, 0.0, 0.0, 0.0, 0.0], &mut sums); // L = y of the landing
//! let mut grad = vec![0.0];
//! plan.contract(&ds, &sums, &dn, &mut grad);
//! // The forward-mode Jacobian says the same.
//! let j = ds.trace(&diffcassi::rays::RayBatch::chief_rays(&ds.system, &[[0.0, 0.0]], 520.0)?)?;
//! assert!((grad[0] - j.d_position(0, 0).y).abs() < 1e-12 * grad[0].abs().max(1.0));
//! # let _ = p;
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::hit::{ShapeTangent, SurfaceLocal};
use super::kernel::{interact_tangents, StepTangent};
use super::DiffSystem;
use crate::error::{Error, Result};
use crate::surfaces::{intersect, IntersectFailure};
use crate::tracer::RayStatus;
use glam::{DMat3, DVec3};

/// Figure coefficients a [`ShapeTangent`] carries: curvature, conic, α₁..α₈, focal length.
pub const SHAPE_FIELDS: usize = 11;

fn shape_field(t: &ShapeTangent, f: usize) -> f64 {
    match f {
        0 => t.curvature,
        1 => t.conic,
        10 => t.focal_length,
        _ => t.asphere[f - 2],
    }
}

fn shape_unit(f: usize) -> ShapeTangent {
    let mut t = ShapeTangent::default();
    match f {
        0 => t.curvature = 1.0,
        1 => t.conic = 1.0,
        10 => t.focal_length = 1.0,
        _ => t.asphere[f - 2] = 1.0,
    }
    t
}

/// The seeds of one step's linearisation: columns 0..6 the state (δp, δd), then one per active figure
/// coefficient, then (δn₁, δn₂) when an index of the step moves.
#[derive(Clone, Debug)]
struct StepPlan {
    shape_fields: Vec<usize>,
    index: bool,
    seeds: StepTangent,
    /// dn seeds, `surfaces × columns`.
    dn: Vec<f64>,
    columns: usize,
}

/// What the reverse pass needs of a system: which figure coefficients and indices move at each step.
#[derive(Clone, Debug)]
pub struct AdjointPlan {
    steps: Vec<StepPlan>,
    surfaces: usize,
}

/// The forward pass of one ray: per step, the ray before the frame change and the step's linearisation.
#[derive(Clone, Debug, Default)]
pub struct RayTape {
    /// Per step: p − o (previous frame), d (previous frame).
    pr: Vec<DVec3>,
    d: Vec<DVec3>,
    /// Per step, per column: (δp′, δd′) of the step's output.
    lin: Vec<Vec<[f64; 6]>>,
    steps: usize,
    dp: Vec<DVec3>,
    dd: Vec<DVec3>,
}

/// The adjoint sensitivities to the tangent data of every step, summed over rays (one spectral plane:
/// the index part is per surface at that plane's wavelength).
#[derive(Clone, Debug)]
pub struct AdjointSums {
    rotation: Vec<DMat3>,
    offset: Vec<DVec3>,
    shape: Vec<[f64; SHAPE_FIELDS]>,
    index: Vec<f64>,
}

impl AdjointSums {
    pub fn new(plan: &AdjointPlan) -> Self {
        let s = plan.steps.len();
        AdjointSums { rotation: vec![DMat3::ZERO; s], offset: vec![DVec3::ZERO; s], shape: vec![[0.0; SHAPE_FIELDS]; s], index: vec![0.0; plan.surfaces] }
    }
}

impl AdjointPlan {
    /// The plan of `ds` for rays at `wavelengths_nm` (an index seed is added where any parameter moves an
    /// index at one of them).
    pub fn new(ds: &DiffSystem, wavelengths_nm: &[f64]) -> Result<Self> {
        let kk = ds.k();
        let ns = ds.system.indices(ds.system.spec.primary_wavelength_nm)?.len();
        let mut index_moves = vec![false; ns];
        for &w in wavelengths_nm {
            let (_, dn) = ds.index_tangents(w)?;
            for (i, m) in index_moves.iter_mut().enumerate() {
                *m |= dn[i * kk..(i + 1) * kk].iter().any(|v| *v != 0.0);
            }
        }
        let mut steps = Vec::with_capacity(ds.steps.len());
        for (step, tan) in ds.system.path.iter().zip(&ds.steps) {
            let shape_fields: Vec<usize> = (0..SHAPE_FIELDS).filter(|&f| tan.shape.iter().any(|t| shape_field(t, f) != 0.0)).collect();
            let s = step.surface;
            let index = s >= 1 && (index_moves[s - 1] || index_moves[s]);
            let columns = 6 + shape_fields.len() + if index { 2 } else { 0 };
            let mut seeds = StepTangent::zero(columns);
            for (c, &f) in shape_fields.iter().enumerate() {
                seeds.shape[6 + c] = shape_unit(f);
            }
            let mut dn = vec![0.0; ns * columns];
            if index {
                let c = 6 + shape_fields.len();
                dn[(s - 1) * columns + c] = 1.0;
                dn[s * columns + c + 1] = 1.0;
            }
            steps.push(StepPlan { shape_fields, index, seeds, dn, columns });
        }
        Ok(AdjointPlan { steps, surfaces: ns })
    }

    /// Largest number of linearisation columns of a step (the per-ray cost, independent of P).
    pub fn max_columns(&self) -> usize {
        self.steps.iter().map(|s| s.columns).max().unwrap_or(0)
    }

    /// Trace a ray (object frame, unit direction) through `ds` with indices `n`, recording the tape.
    /// The values are those of [`crate::tracer::AnalyticTracer`] (same kernel arithmetic).
    pub fn trace(&self, ds: &DiffSystem, n: &[f64], mut p: DVec3, mut d: DVec3, tape: &mut RayTape) -> std::result::Result<(DVec3, DVec3), (RayStatus, usize)> {
        let path = &ds.system.path;
        if tape.lin.len() < path.len() {
            tape.lin.resize(path.len(), Vec::new());
            tape.pr.resize(path.len(), DVec3::ZERO);
            tape.d.resize(path.len(), DVec3::ZERO);
        }
        tape.steps = 0;
        for (s, (step, plan)) in path.iter().zip(&self.steps).enumerate() {
            let pr = p - step.offset;
            tape.pr[s] = pr;
            tape.d[s] = d;
            let (p1, d1) = (step.rotation * pr, step.rotation * d);
            let hit = match intersect(&step.shape, p1, d1) {
                Ok(h) => h,
                Err(IntersectFailure::Missed) => return Err((RayStatus::Missed, step.surface)),
                Err(IntersectFailure::NoConvergence) => return Err((RayStatus::NoConvergence, step.surface)),
            };
            if !step.aperture.contains(hit.point.x, hit.point.y) {
                return Err((RayStatus::Vignetted, step.surface));
            }
            let local = SurfaceLocal::at(&step.shape, hit.point);
            let c = plan.columns;
            tape.dp.clear();
            tape.dd.clear();
            tape.dp.resize(c, DVec3::ZERO);
            tape.dd.resize(c, DVec3::ZERO);
            for a in 0..3 {
                tape.dp[a][a] = 1.0;
                tape.dd[3 + a][a] = 1.0;
            }
            let d2 = interact_tangents(step, &plan.seeds, &local, hit.point, hit.normal, hit.t, d1, n, &plan.dn, &mut tape.dp, &mut tape.dd).map_err(|st| (st, step.surface))?;
            let lin = &mut tape.lin[s];
            lin.clear();
            lin.extend(tape.dp.iter().zip(&tape.dd).map(|(a, b)| [a.x, a.y, a.z, b.x, b.y, b.z]));
            p = hit.point;
            d = d2;
            tape.steps = s + 1;
        }
        Ok((p, d))
    }

    /// Run a traced ray's tape backwards from λ = ∂L/∂(p, d) at the image (image frame) and add its
    /// sensitivities to `sums`. Returns false (adding nothing) when a sensitivity is not finite (a grazing
    /// hit).
    pub fn backward(&self, ds: &DiffSystem, tape: &RayTape, lambda: [f64; 6], sums: &mut AdjointSums) -> bool {
        let path = &ds.system.path;
        debug_assert_eq!(tape.steps, path.len());
        // Check first (a grazing hit gives infinite columns), so that nothing partial is added.
        if !tape.lin[..tape.steps].iter().all(|l| l.iter().all(|c| c.iter().all(|v| v.is_finite()))) {
            return false;
        }
        let mut lam = lambda;
        for s in (0..tape.steps).rev() {
            let (plan, lin) = (&self.steps[s], &tape.lin[s]);
            let dot = |col: &[f64; 6]| -> f64 { (0..6).map(|r| lam[r] * col[r]).sum() };
            // μ: the adjoint of the step's input state in the step's frame (Aᵀλ, A the interaction).
            let mu: [f64; 6] = std::array::from_fn(|a| dot(&lin[a]));
            for (c, &f) in plan.shape_fields.iter().enumerate() {
                sums.shape[s][f] += dot(&lin[6 + c]);
            }
            if plan.index {
                let c = 6 + plan.shape_fields.len();
                let sf = path[s].surface;
                sums.index[sf - 1] += dot(&lin[c]);
                sums.index[sf] += dot(&lin[c + 1]);
            }
            let (mp, md) = (DVec3::new(mu[0], mu[1], mu[2]), DVec3::new(mu[3], mu[4], mu[5]));
            let (pr, d) = (tape.pr[s], tape.d[s]);
            // μ_p·(δR pr) + μ_d·(δR d) = δR : (μ_p prᵀ + μ_d dᵀ).
            sums.rotation[s] += DMat3::from_cols(mp * pr.x + md * d.x, mp * pr.y + md * d.y, mp * pr.z + md * d.z);
            let rt = path[s].rotation.transpose();
            let (lp, ld) = (rt * mp, rt * md);
            // −μ_p·(R δo) = (−Rᵀμ_p)·δo.
            sums.offset[s] -= lp;
            lam = [lp.x, lp.y, lp.z, ld.x, ld.y, ld.z];
        }
        true
    }

    /// Add to `grad` (one entry per free parameter) the contraction of `sums` with the parameters' step
    /// tangents and, for the indices, `dn` (= [`DiffSystem::index_tangents`] at the sums' wavelength).
    pub fn contract(&self, ds: &DiffSystem, sums: &AdjointSums, dn: &[f64], grad: &mut [f64]) {
        let kk = ds.k();
        assert_eq!(grad.len(), kk);
        for (s, (tan, plan)) in ds.steps.iter().zip(&self.steps).enumerate() {
            let (g, h) = (&sums.rotation[s], sums.offset[s]);
            for (k, out) in grad.iter_mut().enumerate() {
                let r = &tan.rotation[k];
                let mut v = r.x_axis.dot(g.x_axis) + r.y_axis.dot(g.y_axis) + r.z_axis.dot(g.z_axis) + tan.offset[k].dot(h);
                for &f in &plan.shape_fields {
                    v += shape_field(&tan.shape[k], f) * sums.shape[s][f];
                }
                *out += v;
            }
        }
        for (i, nb) in sums.index.iter().enumerate() {
            if *nb != 0.0 {
                for k in 0..kk {
                    grad[k] += nb * dn[i * kk + k];
                }
            }
        }
    }

    /// Whether parameter `k` moves anything a ray at `wavelengths_nm` sees (a frame, a figure, an index).
    pub fn moves(ds: &DiffSystem, k: usize, wavelengths_nm: &[f64]) -> Result<bool> {
        if ds.steps.iter().any(|t| t.rotation[k] != DMat3::ZERO || t.offset[k] != DVec3::ZERO || !t.shape[k].is_zero()) {
            return Ok(true);
        }
        let kk = ds.k();
        for &w in wavelengths_nm {
            let (_, dn) = ds.index_tangents(w)?;
            if dn.iter().skip(k).step_by(kk).any(|v| *v != 0.0) {
                return Ok(true);
            }
        }
        Ok(false)
    }
}

/// An error for a parameter the acquisition cannot be differentiated by.
pub(crate) fn not_a_system_parameter(name: &str) -> Error {
    Error::invalid(format!("free parameter `{name}` is per ray (wavelength, input ray), not a parameter of the system the acquisition can be differentiated by"))
}
