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
//! The transposes are written out by hand ([`AdjointPlan::backward`]): the forward pass keeps each step's
//! state (ray before the frame change, incoming direction, hit point, normal, distance, indices), and one
//! reverse sweep per ray maps (λ_q, λ_d′) through refraction (or the ideal lens), the implicit-function hit
//! derivative ([`super::hit::SweepLocal::adjoint`]) and the frame change — the same linear maps as the
//! forward tangent kernel ([`super::kernel::interact_tangents`]), transposed, at the cost of about one
//! tangent column instead of 6 + (figure coefficients) + 2 (indices) columns per step. `tests/render_gradient.rs`
//! checks it against the forward tangents ray by ray to 1e-12.
//! [`super::adjoint_lanes`] runs the same sweep on SIMD lanes (a block of rays at once); this scalar sweep is
//! its reference and what `Kernel::Scalar` uses.
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
//! plan.backward(&ds, &mut tape, [0.0, 1.0, 0.0, 0.0, 0.0, 0.0], &mut sums); // L = y of the landing
//! let mut grad = vec![0.0];
//! plan.contract(&ds, &sums, &dn, &mut grad);
//! // The forward-mode Jacobian says the same.
//! let j = ds.trace(&diffcassi::rays::RayBatch::chief_rays(&ds.system, &[[0.0, 0.0]], 520.0)?)?;
//! assert!((grad[0] - j.d_position(0, 0).y).abs() < 1e-12 * grad[0].abs().max(1.0));
//! # let _ = p;
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::hit::{ShapeTangent, SweepLocal};
use super::kernel::oriented_normal;
use super::DiffSystem;
use crate::error::{Error, Result};
use crate::surfaces::{intersect, IntersectFailure, SurfaceShape};
use crate::surfaces::grating::{across_lines, diffract};
use crate::system::Interaction;
use crate::tracer::kernel::{paraxial_deflect, reflect, refract, GRAZING_COS};
use crate::tracer::RayStatus;
use glam::{DMat3, DVec3};

/// Figure coefficients a [`ShapeTangent`] carries: curvature, conic, α₁..α₈, focal length.
pub const SHAPE_FIELDS: usize = 11;

pub(crate) fn shape_field(t: &ShapeTangent, f: usize) -> f64 {
    match f {
        0 => t.curvature,
        1 => t.conic,
        10 => t.focal_length,
        _ => t.asphere[f - 2],
    }
}

pub(crate) fn shape_unit(f: usize) -> ShapeTangent {
    let mut t = ShapeTangent::default();
    match f {
        0 => t.curvature = 1.0,
        1 => t.conic = 1.0,
        10 => t.focal_length = 1.0,
        _ => t.asphere[f - 2] = 1.0,
    }
    t
}

/// What one step's reverse sweep accumulates: the figure coefficients some parameter moves, and whether
/// an index of the step moves.
#[derive(Clone, Debug)]
pub(crate) struct StepPlan {
    pub(crate) shape_fields: Vec<usize>,
    pub(crate) index: bool,
    /// Some parameter's rotation (δR) or offset (δo) tangent at the step is not zero: the sweep computes
    /// and sums the step's frame sensitivities only where one is (elsewhere they would be contracted with
    /// zeros).
    pub(crate) rotation: bool,
    pub(crate) offset: bool,
    /// A parameter moves the step's paraxial focal length (field 10 is in `shape_fields`).
    pub(crate) focal: bool,
}

/// What the reverse pass needs of a system: which figure coefficients and indices move at each step.
#[derive(Clone, Debug)]
pub struct AdjointPlan {
    pub(crate) steps: Vec<StepPlan>,
    pub(crate) surfaces: usize,
    /// The earliest path step any parameter moves (a frame, a figure, an index): the reverse sweep stops
    /// there, since the steps before it only carry λ on and add nothing ([`AdjointPlan::first_step`]).
    pub(crate) first: usize,
}

/// The forward state of one path step, kept for the reverse sweep.
#[derive(Clone, Copy, Debug)]
struct StepState {
    /// p − o and d in the previous frame (before the frame change).
    pr: DVec3,
    d0: DVec3,
    /// The incoming unit direction, the hit point, its unit normal (as [`intersect`] gives it) and the
    /// distance from the frame-changed ray origin, in the step's frame.
    d: DVec3,
    q: DVec3,
    normal: DVec3,
    t: f64,
    /// Indices before and after the surface.
    n1: f64,
    n2: f64,
    /// A grating's kick g = mλT ([`crate::surfaces::grating::Grating::kick`]) and the outgoing direction
    /// (0 and unused elsewhere).
    g: f64,
    d_out: DVec3,
}

/// One ray's sensitivities at one step (added to [`AdjointSums`] once the whole ray is known finite).
#[derive(Clone, Copy, Debug)]
struct StepSens {
    rotation: DMat3,
    offset: DVec3,
    shape: [f64; SHAPE_FIELDS],
    n1: f64,
    n2: f64,
    /// A grating's wavelength entry of the index table (`wavelength_slot`): ∂L/∂λ there.
    nl: f64,
}

/// The forward pass of one ray (its per-step states) and scratch space for its reverse sweep; reused
/// from ray to ray (no per-ray allocation once grown).
#[derive(Clone, Debug, Default)]
pub struct RayTape {
    states: Vec<StepState>,
    sens: Vec<StepSens>,
}

/// The adjoint sensitivities to the tangent data of every step, summed over rays (one spectral plane:
/// the index part is per surface at that plane's wavelength).
#[derive(Clone, Debug)]
pub struct AdjointSums {
    pub(crate) rotation: Vec<DMat3>,
    pub(crate) offset: Vec<DVec3>,
    pub(crate) shape: Vec<[f64; SHAPE_FIELDS]>,
    pub(crate) index: Vec<f64>,
}

impl RayTape {
    /// The hit point of path step `step` in that step's frame (the ray's position after the step), if the
    /// last [`AdjointPlan::trace`] got that far.
    pub fn point(&self, step: usize) -> Option<DVec3> {
        self.states.get(step).map(|s| s.q)
    }
}

impl AdjointSums {
    pub fn new(plan: &AdjointPlan) -> Self {
        let s = plan.steps.len();
        AdjointSums { rotation: vec![DMat3::ZERO; s], offset: vec![DVec3::ZERO; s], shape: vec![[0.0; SHAPE_FIELDS]; s], index: vec![0.0; plan.surfaces] }
    }
}

impl AdjointPlan {
    /// The plan of `ds` for rays at `wavelengths_nm` (indices are accumulated where any parameter moves an
    /// index at one of them).
    pub fn new(ds: &DiffSystem, wavelengths_nm: &[f64]) -> Result<Self> {
        let kk = ds.k();
        // The reverse sweep transposes refraction, the ideal lens, mirrors and gratings (the forward tangents of
        // diff::kernel, step by step), on every surface figure the hit derivative knows (Toroidal included).
        let ns = ds.system.indices(ds.system.spec.primary_wavelength_nm)?.len();
        let mut index_moves = vec![false; ns];
        for &w in wavelengths_nm {
            let (_, dn) = ds.index_tangents(w)?;
            for (i, m) in index_moves.iter_mut().enumerate() {
                *m |= dn[i * kk..(i + 1) * kk].iter().any(|v| *v != 0.0);
            }
        }
        let steps: Vec<StepPlan> = ds
            .system
            .path
            .iter()
            .zip(&ds.steps)
            .map(|(step, tan)| {
                let shape_fields: Vec<usize> = (0..SHAPE_FIELDS).filter(|&f| tan.shape.iter().any(|t| shape_field(t, f) != 0.0)).collect();
                let s = step.surface;
                let focal = shape_fields.contains(&10);
                let rotation = tan.rotation.iter().any(|r| *r != DMat3::ZERO);
                let offset = tan.offset.iter().any(|o| *o != DVec3::ZERO);
                // A grating's kick reads the wavelength entry of the index table too.
                let slot = match step.interaction {
                    Interaction::Grating { wavelength_slot, .. } => index_moves[wavelength_slot],
                    _ => false,
                };
                StepPlan { shape_fields, index: s >= 1 && (index_moves[s - 1] || index_moves[s] || slot), rotation, offset, focal }
            })
            .collect();
        let first = steps.iter().position(|p| p.rotation || p.offset || p.index || !p.shape_fields.is_empty()).unwrap_or(steps.len());
        Ok(AdjointPlan { steps, surfaces: ns, first })
    }

    /// The earliest path step (index into the system's path) at which some free parameter moves a
    /// frame, a figure or an index. The reverse sweeps ([`Self::backward`], `backward_lanes`) stop
    /// there: before it the adjoint λ is only carried back through the trace, and no sensitivity is
    /// accumulated, so those steps change no sum (the kept steps' sums are the same, in the same
    /// order). One difference from sweeping the whole path: a ray whose adjoint becomes non-finite only
    /// in the skipped steps (a grazing hit there) now adds its (finite) sensitivities instead of being
    /// dropped. The path length when no step is moved.
    pub fn first_step(&self) -> usize {
        self.first
    }

    /// Trace a ray (object frame, unit direction) through `ds` with indices `n`, recording each step's
    /// state. The values are bit-identical to [`crate::tracer::kernel::trace_steps`] (the same operations).
    pub fn trace(&self, ds: &DiffSystem, n: &[f64], mut p: DVec3, mut d: DVec3, tape: &mut RayTape) -> std::result::Result<(DVec3, DVec3), (RayStatus, usize)> {
        tape.states.clear();
        for step in &ds.system.path {
            let pr = p - step.offset;
            let (p1, d1) = (step.rotation * pr, step.rotation * d);
            let hit = match intersect(&step.shape, p1, d1) {
                Ok(h) => h,
                Err(IntersectFailure::Missed) => return Err((RayStatus::Missed, step.surface)),
                Err(IntersectFailure::NoConvergence) => return Err((RayStatus::NoConvergence, step.surface)),
            };
            if !step.aperture.contains(hit.point.x, hit.point.y) {
                return Err((RayStatus::Vignetted, step.surface));
            }
            let (n1, n2) = (n[step.surface - 1], n[step.surface]);
            let mut g = 0.0;
            // The interactions of `tracer::kernel::trace_step`, operation for operation.
            let d2 = match step.interaction {
                Interaction::Reflect => {
                    if d1.dot(hit.normal).abs() <= GRAZING_COS {
                        return Err((RayStatus::Missed, step.surface));
                    }
                    reflect(d1, hit.normal)
                }
                Interaction::Grating { grating, reflective, wavelength_slot } => {
                    if reflective && d1.dot(hit.normal).abs() <= GRAZING_COS {
                        return Err((RayStatus::Missed, step.surface));
                    }
                    g = grating.kick(n[wavelength_slot]);
                    diffract(d1, hit.normal, n1, n2, g, reflective).ok_or((RayStatus::Evanescent, step.surface))?
                }
                Interaction::Refract => match step.shape {
                    SurfaceShape::Paraxial { focal_length } => paraxial_deflect(hit.point, d1, focal_length, n1, n2),
                    _ if n1 != n2 => refract(d1, hit.normal, n1, n2).ok_or((RayStatus::TotalInternalReflection, step.surface))?,
                    _ => d1,
                },
            };
            tape.states.push(StepState { pr, d0: d, d: d1, q: hit.point, normal: hit.normal, t: hit.t, n1, n2, g, d_out: d2 });
            p = hit.point;
            d = d2;
        }
        Ok((p, d))
    }

    /// Run a traced ray backwards from λ = ∂L/∂(p, d) at the image (image frame) and add its
    /// sensitivities to `sums`. Returns false (adding nothing) when a sensitivity is not finite (a grazing
    /// hit).
    ///
    /// Per step, the transpose of the forward tangent ([`super::kernel::interact_tangents`]) written out
    /// by hand, from the output adjoint (λ_q, λ_d′) to the adjoint μ of the step's input (δp, δd in the
    /// step's frame), the figure partials and the indices:
    /// - refraction d′ = μ d + (√κ − μ cos θᵢ) n̂: with a = λ_d′, β = a·n̂, γ = β(μ² cos θᵢ/√κ − μ),
    ///   d̄ = μ a + γ n̂, n̂̄ = (√κ − μ cos θᵢ) a + γ d, μ̄ = a·d − β(μ(1 − cos²θᵢ)/√κ + cos θᵢ);
    /// - ideal lens tan′ = μ tan − h/f, d′ = ±w/|w|: w̄ = (a − v(v·a))·(±1/|w|), then the quotient rule;
    /// - the hit ([`SweepLocal::adjoint`], from the traced hit point and normal): δq and δn̂ back to the
    ///   ray point δp + t δd and the figure;
    /// - μ = n₁/n₂: n̄₁ = μ̄/n₂, n̄₂ = −μ μ̄/n₂.
    pub fn backward(&self, ds: &DiffSystem, tape: &mut RayTape, lambda: [f64; 6], sums: &mut AdjointSums) -> bool {
        self.backward_seeded(ds, tape, lambda, None, sums)
    }

    /// [`Self::backward`] for a loss that also depends on where the ray crossed an intermediate step: `seed`
    /// = (step, ∂L/∂q) adds the gradient with respect to that step's hit point q (in the step's frame, as
    /// [`RayTape::point`] gives it) to the adjoint as the sweep passes the step — a coded-mask surface's
    /// transmission read at the crossing (dual-disperser CASSI, [`crate::render::gradient`]). A step before
    /// [`Self::first_step`] is never reached: no parameter moves the crossing there, so it adds nothing.
    /// With `seed = None` the sums are [`Self::backward`]'s bit for bit.
    pub fn backward_seeded(&self, ds: &DiffSystem, tape: &mut RayTape, lambda: [f64; 6], seed: Option<(usize, DVec3)>, sums: &mut AdjointSums) -> bool {
        let path = &ds.system.path;
        debug_assert_eq!(tape.states.len(), path.len());
        tape.sens.clear();
        let (mut lq, mut ld) = (DVec3::new(lambda[0], lambda[1], lambda[2]), DVec3::new(lambda[3], lambda[4], lambda[5]));
        let mut finite = true;
        // Down to the earliest step a parameter moves ([`Self::first_step`]): nothing is summed before it.
        for s in (self.first.min(tape.states.len())..tape.states.len()).rev() {
            let (st, step, plan) = (&tape.states[s], &path[s], &self.steps[s]);
            if let Some((at, g)) = seed {
                if at == s {
                    lq += g;
                }
            }
            let local = SweepLocal::at(&step.shape, st.q, st.normal);
            let (d, q) = (st.d, st.q);
            let mu = st.n1 / st.n2;
            let mut q_bar = lq;
            let (dd_bar, n_bar);
            // μ̄ and f̄ only where a parameter moves an index or the focal length.
            let (mut mu_bar, mut f_bar) = (0.0, 0.0);
            // A grating's index and wavelength adjoints (n̄₁, n̄₂, λ̄ of its kick), summed directly.
            let mut grating_bar: Option<(f64, f64, f64)> = None;
            match (step.interaction, &step.shape) {
                // Mirror d′ = d − 2c N̂, c = d·N̂ (N̂ the traced normal, either orientation):
                // d̄ = a − 2(a·N̂)N̂, N̂̄ = −2((a·N̂) d + c a).
                (Interaction::Reflect, _) => {
                    let nn = st.normal;
                    let (c, an) = (d.dot(nn), ld.dot(nn));
                    dd_bar = ld - nn * (2.0 * an);
                    n_bar = (d * an + ld * c) * -2.0;
                }
                // Grating (the transpose of `diff::kernel::interact_tangents`' grating arm, line by line):
                // v = n₁d − s g K, v_t = v − N(v·N), a = ±√(n₂² − |v_t|²), d′ = (v_t + N a)/n₂, with N the
                // normal along d, K = normalise(ŷ − (ŷ·N̂)N̂) across the lines and g = mλT.
                (Interaction::Grating { grating, reflective, .. }, _) => {
                    let (nrm, _, sgn) = oriented_normal(d, st.normal);
                    let (kv, inv_len) = across_lines(st.normal);
                    let sg = if reflective { -1.0 } else { 1.0 };
                    let (n1, n2, g, d_out) = (st.n1, st.n2, st.g, st.d_out);
                    let v = d * n1 - kv * (sg * g);
                    let vn = v.dot(nrm);
                    let vt = v - nrm * vn;
                    let a = (d_out * n2 - vt).dot(nrm);
                    // δd′ = (δv_t + N δa + δN a)/n₂ − d′ δn₂/n₂.
                    let mut dvt_bar = ld / n2;
                    let da_bar = ld.dot(nrm) / n2;
                    let mut dnrm_bar = ld * (a / n2);
                    let mut dn2_bar = -ld.dot(d_out) / n2;
                    // δa = δq/(2a), δq = 2n₂δn₂ − 2 v_t·δv_t.
                    let dq_bar = da_bar / (2.0 * a);
                    dn2_bar += 2.0 * n2 * dq_bar;
                    dvt_bar -= vt * (2.0 * dq_bar);
                    // δv_t = δv − N δv_n − δN v_n, δv_n = δv·N + v·δN.
                    let dvn_bar = -nrm.dot(dvt_bar);
                    let dv_bar = dvt_bar + nrm * dvn_bar;
                    dnrm_bar += v * dvn_bar - dvt_bar * vn;
                    // δv = d δn₁ + n₁ δd − s(K δg + g δK).
                    let dn1_bar = d.dot(dv_bar);
                    dd_bar = dv_bar * n1;
                    let dg_bar = -sg * kv.dot(dv_bar);
                    let dkv_bar = dv_bar * (-sg * g);
                    // δK = (δk − K(K·δk))/|k|, δk = −(N̂ δN̂_y + δN̂ N̂_y), δN = sgn δN̂.
                    let dk_bar = (dkv_bar - kv * kv.dot(dkv_bar)) * inv_len;
                    let nn = st.normal;
                    let mut nb = dnrm_bar * sgn - dk_bar * nn.y;
                    nb.y -= dk_bar.dot(nn);
                    n_bar = nb;
                    // g = mλT·1e-3 is linear in the table's wavelength entry: λ̄ = kick(ḡ).
                    grating_bar = Some((dn1_bar, dn2_bar, grating.kick(dg_bar)));
                }
                (Interaction::Refract, _) => match step.shape {
                SurfaceShape::Paraxial { focal_length: f } => {
                    // tan = (d_x, d_y)/d_z, tan′ = μ tan − q/f, w = (tan′, 1), d′ = ±w/|w|.
                    let inv_dz = 1.0 / d.z;
                    let (ux, uy) = (d.x * inv_dz, d.y * inv_dz);
                    let inv_f = 1.0 / f;
                    let tx = mu * ux - q.x * inv_f;
                    let ty = mu * uy - q.y * inv_f;
                    let w = DVec3::new(tx, ty, 1.0);
                    let wl = w.length();
                    let inv_wl = 1.0 / wl;
                    let v = w * inv_wl;
                    let k = if d.z < 0.0 { -inv_wl } else { inv_wl };
                    let vl = v.dot(ld);
                    let (txb, tyb) = ((ld.x - v.x * vl) * k, (ld.y - v.y * vl) * k);
                    if plan.index {
                        mu_bar = txb * ux + tyb * uy;
                    }
                    let (mx, my) = (mu * txb * inv_dz, mu * tyb * inv_dz);
                    dd_bar = DVec3::new(mx, my, -(mx * ux + my * uy));
                    q_bar.x -= txb * inv_f;
                    q_bar.y -= tyb * inv_f;
                    if plan.focal {
                        f_bar = (txb * q.x + tyb * q.y) * (inv_f * inv_f);
                    }
                    n_bar = DVec3::ZERO;
                }
                // No index change and none moving: the trace keeps d (the identity).
                _ if st.n1 == st.n2 && !plan.index => {
                    dd_bar = ld;
                    n_bar = DVec3::ZERO;
                }
                _ => {
                    let (nrm, cos_i, sgn) = oriented_normal(d, st.normal);
                    let kappa = 1.0 - mu * mu * (1.0 - cos_i * cos_i);
                    let sk = kappa.max(0.0).sqrt();
                    let inv_sk = 1.0 / sk;
                    let beta = ld.dot(nrm);
                    let gamma = beta * (mu * mu * cos_i * inv_sk - mu);
                    if plan.index {
                        mu_bar = ld.dot(d) - beta * (mu * (1.0 - cos_i * cos_i) * inv_sk + cos_i);
                    }
                    dd_bar = ld * mu + nrm * gamma;
                    n_bar = (ld * (sk - mu * cos_i) + d * gamma) * sgn;
                }
                },
            }
            let (ray_bar, partials_bar) = local.adjoint(d, q_bar, n_bar);
            // dray = δp + t δd.
            let (mp, md) = (ray_bar, dd_bar + ray_bar * st.t);
            let mut shape = [0.0; SHAPE_FIELDS];
            for &f in &plan.shape_fields {
                let (a, b, c) = local.param_partials(&shape_unit(f));
                shape[f] = partials_bar[0] * a + partials_bar[1] * b + partials_bar[2] * c + if f == 10 { f_bar } else { 0.0 };
            }
            let (pr, d0) = (st.pr, st.d0);
            // μ_p·(δR pr) + μ_d·(δR d) = δR : (μ_p prᵀ + μ_d dᵀ).
            let rotation = if plan.rotation { DMat3::from_cols(mp * pr.x + md * d0.x, mp * pr.y + md * d0.y, mp * pr.z + md * d0.z) } else { DMat3::ZERO };
            let rt = step.rotation.transpose();
            (lq, ld) = (rt * mp, rt * md);
            let (n1, n2, nl) = match (plan.index, grating_bar) {
                (false, _) => (0.0, 0.0, 0.0),
                (true, Some(gb)) => gb,
                (true, None) => (mu_bar / st.n2, -mu * mu_bar / st.n2, 0.0),
            };
            // −μ_p·(R δo) = (−Rᵀμ_p)·δo.
            finite &= lq.is_finite() && ld.is_finite() && rotation.is_finite() && shape.iter().all(|v| v.is_finite()) && n1.is_finite() && n2.is_finite() && nl.is_finite();
            tape.sens.push(StepSens { rotation, offset: -lq, shape, n1, n2, nl });
        }
        if !finite {
            return false;
        }
        // `tape.sens` holds the swept steps, last first.
        let first = tape.states.len() - tape.sens.len();
        for (i, sens) in tape.sens.iter().rev().enumerate() {
            let s = first + i;
            let plan = &self.steps[s];
            if plan.rotation {
                sums.rotation[s] += sens.rotation;
            }
            if plan.offset {
                sums.offset[s] += sens.offset;
            }
            for &f in &plan.shape_fields {
                sums.shape[s][f] += sens.shape[f];
            }
            if plan.index {
                let sf = path[s].surface;
                sums.index[sf - 1] += sens.n1;
                sums.index[sf] += sens.n2;
                if let Interaction::Grating { wavelength_slot, .. } = path[s].interaction {
                    sums.index[wavelength_slot] += sens.nl;
                }
            }
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
