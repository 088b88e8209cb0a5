//! The reverse (adjoint) sweep of [`super::adjoint`] on SIMD lanes: a block of [`LANES`] rays traced once by
//! the recording lane trace ([`crate::tracer::simd::record`], which keeps each step's state in a
//! [`LaneTape`]) and swept backwards together, lane by lane the operations of the scalar sweep
//! [`AdjointPlan::backward`] (the same formulas in the same order: refraction or ideal lens, the implicit
//! hit derivative, the frame change — see there for the algebra). Each lane keeps its own sums
//! ([`LaneSums`], one lane array per sensitivity), so adding a block is one vector add per quantity; the
//! lanes are summed, in lane order, once per spectral plane ([`LaneSums::add_to`]).
//!
//! Runs at a [`SimdLevel`] through the one dispatch of the lane kernel ([`crate::tracer::simd::at_level`]);
//! every level gives the same bits. Against the scalar sweep, ray by ray: equal to rounding (the one
//! difference is the order in which rays are summed). `tests/render_gradient.rs` checks ≤ 1e-12 on SP, mSP
//! and AP with vignetted and missed rays in the blocks. A lane adds nothing when one of its
//! sensitivities is not finite (a grazing hit), as the scalar sweep.
//!
//! ```
//! use diffcassi::diff::adjoint::{AdjointPlan, AdjointSums};
//! use diffcassi::diff::adjoint_lanes::LaneSums;
//! use diffcassi::diff::{Param, ParamSet};
//! use diffcassi::materials::GlassCatalog;
//! use diffcassi::tracer::simd::{lanes::{Lf, Mask}, trace_block_recording, Block, LaneTape, LANES};
//! use diffcassi::tracer::SimdLevel;
//! use glam::DVec3;
//! let set = ParamSet::new(diffcassi::presets::spec("sp")?, GlassCatalog::builtin(), vec![Param::parse("s4.tilt_x_deg")?])?;
//! let ds = set.build()?;
//! let plan = AdjointPlan::new(&ds, &[520.0])?;
//! let (n, dn) = ds.index_tangents(520.0)?;
//! let (mut b, mut tape) = (Block::default(), LaneTape::default());
//! b.set(0, DVec3::ZERO, DVec3::Z);
//! let level = SimdLevel::detect();
//! trace_block_recording(level, &ds.system, &[n.as_slice(); LANES], &mut b, &mut tape);
//! let mut lambda = [Lf::splat(0.0); 6];
//! lambda[1].0[0] = 1.0; // L = y of lane 0's landing
//! let mut active = Mask::splat(false);
//! active.0[0] = true;
//! let mut lanes = LaneSums::new(&plan);
//! plan.backward_lanes(level, &ds, &tape, &n, &lambda, active, &mut lanes);
//! let mut sums = AdjointSums::new(&plan);
//! lanes.add_to(&mut sums);
//! let mut grad = vec![0.0];
//! plan.contract(&ds, &sums, &dn, &mut grad);
//! let j = ds.trace(&diffcassi::rays::RayBatch::chief_rays(&ds.system, &[[0.0, 0.0]], 520.0)?)?;
//! assert!((grad[0] - j.d_position(0, 0).y).abs() < 1e-12 * grad[0].abs().max(1.0));
//! # Ok::<(), diffcassi::Error>(())
//! ```
// Index loops over 0..N are the idiom LLVM vectorises into whole registers; keep them explicit.
#![allow(clippy::needless_range_loop)]
use super::adjoint::{shape_unit, AdjointPlan, AdjointSums, SHAPE_FIELDS};
use super::hit::{figure, ShapeTangent};
use super::DiffSystem;
use crate::surfaces::SurfaceShape;
use crate::system::PathStep;
use crate::tracer::simd::block::rotate;
use crate::tracer::simd::lanes::{Lanes, Lf, Lm, L3, LANES};
use crate::tracer::simd::{at_level, LaneKernel, LaneTape, SimdLevel};
use glam::{DMat3, DVec3};

/// The sensitivities of [`AdjointSums`], one lane array per number: lane k sums the rays that went
/// through lane k. `rotation[s]` is δR's matrix by columns (x_axis, y_axis, z_axis).
#[derive(Clone, Debug)]
pub struct LaneSums {
    rotation: Vec<[Lf; 9]>,
    offset: Vec<[Lf; 3]>,
    shape: Vec<[Lf; SHAPE_FIELDS]>,
    index: Vec<Lf>,
    /// Scratch: one block's per-step sensitivities, added once the block's lanes are known finite.
    sens: Vec<StepSensLanes>,
}

#[derive(Clone, Copy, Debug)]
struct StepSensLanes {
    rotation: [Lf; 9],
    offset: [Lf; 3],
    shape: [Lf; SHAPE_FIELDS],
    n1: Lf,
    n2: Lf,
}

const ZERO: Lf = Lanes([0.0; LANES]);

impl LaneSums {
    pub fn new(plan: &AdjointPlan) -> Self {
        let s = plan.steps.len();
        let zero = StepSensLanes { rotation: [ZERO; 9], offset: [ZERO; 3], shape: [ZERO; SHAPE_FIELDS], n1: ZERO, n2: ZERO };
        LaneSums { rotation: vec![[ZERO; 9]; s], offset: vec![[ZERO; 3]; s], shape: vec![[ZERO; SHAPE_FIELDS]; s], index: vec![ZERO; plan.surfaces], sens: vec![zero; s] }
    }

    /// Add every lane's sums to `out`, lanes in order (then zero nothing: call on a finished plane).
    pub fn add_to(&self, out: &mut AdjointSums) {
        let sum = |v: &Lf| v.0.iter().fold(0.0, |a, b| a + b);
        self.add_with(out, sum);
    }

    /// Lane `k`'s sums alone (the rays that went through lane k), as [`AdjointSums`].
    pub fn lane(&self, plan: &AdjointPlan, k: usize) -> AdjointSums {
        let mut out = AdjointSums::new(plan);
        self.add_with(&mut out, |v: &Lf| v.0[k]);
        out
    }

    fn add_with(&self, out: &mut AdjointSums, f: impl Fn(&Lf) -> f64) {
        for s in 0..self.rotation.len() {
            let r = &self.rotation[s];
            out.rotation[s] += DMat3::from_cols(DVec3::new(f(&r[0]), f(&r[1]), f(&r[2])), DVec3::new(f(&r[3]), f(&r[4]), f(&r[5])), DVec3::new(f(&r[6]), f(&r[7]), f(&r[8])));
            let o = &self.offset[s];
            out.offset[s] += DVec3::new(f(&o[0]), f(&o[1]), f(&o[2]));
            for (a, b) in out.shape[s].iter_mut().zip(&self.shape[s]) {
                *a += f(b);
            }
        }
        for (a, b) in out.index.iter_mut().zip(&self.index) {
            *a += f(b);
        }
    }
}

/// `acc += v` on the lanes whose `keep` is all ones, `+= 0` on those whose `keep` is 0 (`Lf::select(m, v,
/// 0)`'s bits: v's bits ANDed with the mask).
#[inline(always)]
fn add_kept(acc: &mut Lf, v: &Lf, keep: &[u64; LANES]) {
    let mut kept = ZERO;
    for k in 0..LANES {
        kept.0[k] = f64::from_bits(v.0[k].to_bits() & keep[k]);
    }
    *acc = *acc + kept;
}

#[inline(always)]
fn v3(x: Lf, y: Lf, z: Lf) -> L3 {
    L3 { x, y, z }
}

/// `x^n` (n ≥ 0) by compiler-rt's `__powidf2` (square and multiply), the operations of `f64::powi`.
#[inline(always)]
fn powi(mut a: Lf, mut n: i32) -> Lf {
    let mut r = Lf::splat(1.0);
    loop {
        if n & 1 != 0 {
            r = r * a;
        }
        n /= 2;
        if n == 0 {
            return r;
        }
        a = a * a;
    }
}

/// [`super::hit::SweepLocal`] per lane: the sag's local data at the traced hit points, from the hit point
/// and the unit normal the recording trace kept (see there: 1/|m| = n̂_z; a conic's s = 1 − c(1+k)z).
struct LocalLanes {
    f1: Lf,
    f2: Lf,
    x: Lf,
    y: Lf,
    r2: Lf,
    c: f64,
    k: f64,
    s: Lf,
    normal: L3,
    /// f′ = f″ = 0 (a plane, a paraxial lens, a conic of zero curvature without asphere terms): H = 0.
    flat: bool,
}

impl LocalLanes {
    /// `SweepLocal::at` lane by lane (the same operations; lanes whose hit is not finite hold garbage and
    /// are never active).
    #[inline(always)]
    fn at(shape: &SurfaceShape, q: &L3, normal: &L3) -> LocalLanes {
        let (x, y) = (q.x, q.y);
        let r2 = x * x + y * y;
        let (c, k, alpha) = figure(shape).unwrap_or((0.0, 0.0, &[][..]));
        let (mut f1, mut f2, mut s) = (ZERO, ZERO, Lf::splat(1.0));
        let flat = c == 0.0 && alpha.iter().all(|a| *a == 0.0);
        if !flat && alpha.is_empty() {
            // The trace's normal ∝ (−c x, −c y, 1 − c(1+k) z): its z is s on the vertex branch.
            s = 1.0 - c * (1.0 + k) * q.z;
            let inv_s = 1.0 / s;
            f1 = 0.5 * c * inv_s;
            f2 = 0.25 * (1.0 + k) * c * c * c * inv_s * inv_s * inv_s;
        } else if !flat {
            let arg = 1.0 - (1.0 + k) * c * c * r2;
            // f64::max(arg, 0): 0 where arg < 0 or NaN.
            s = Lf::select(arg.ge(ZERO), arg, ZERO).sqrt();
            if c != 0.0 {
                f1 = c / (2.0 * s);
                f2 = (1.0 + k) * c * c * c / (4.0 * s * s * s);
            }
            for (j, a) in alpha.iter().enumerate() {
                let i = (j + 1) as f64;
                f1 = f1 + i * a * powi(r2, j as i32);
                if j >= 1 {
                    f2 = f2 + i * (i - 1.0) * a * powi(r2, j as i32 - 1);
                }
            }
        }
        LocalLanes { f1, f2, x, y, r2, c, k, s, normal: *normal, flat }
    }

    /// `figure_partials` lane by lane.
    #[inline(always)]
    fn param_partials(&self, t: &ShapeTangent) -> (Lf, Lf, Lf) {
        if !t.moves_figure() {
            return (ZERO, ZERO, ZERO);
        }
        let (c, k, s, r2) = (self.c, self.k, self.s, self.r2);
        let one_s = 1.0 + s;
        let f_c = r2 / one_s + (1.0 + k) * c * c * r2 * r2 / (s * one_s * one_s);
        let f_k = c * c * c * r2 * r2 / (2.0 * s * one_s * one_s);
        let f1_c = 1.0 / (2.0 * s) + (1.0 + k) * c * c * r2 / (2.0 * s * s * s);
        let f1_k = c * c * c * r2 / (4.0 * s * s * s);
        let mut df = t.curvature * f_c + t.conic * f_k;
        let mut df1 = t.curvature * f1_c + t.conic * f1_k;
        for (j, a) in t.asphere.iter().enumerate() {
            if *a != 0.0 {
                let i = (j + 1) as f64;
                df = df + *a * powi(r2, j as i32 + 1);
                df1 = df1 + *a * i * powi(r2, j as i32);
            }
        }
        (df, 2.0 * df1 * self.x, 2.0 * df1 * self.y)
    }

    /// `SweepLocal::adjoint` lane by lane: (ray adjoint, figure-partials adjoint).
    #[inline(always)]
    fn adjoint(&self, d: &L3, q_bar: L3, n_bar: L3) -> (L3, [Lf; 3]) {
        let n = self.normal;
        let w = n.z;
        let nn = n.dot(n_bar);
        let dm_bar = v3((n_bar.x - n.x * nn) * w, (n_bar.y - n.y * nn) * w, (n_bar.z - n.z * nn) * w);
        let dq_bar = if self.flat {
            q_bar
        } else {
            let (x, y) = (self.x, self.y);
            let hxx = 2.0 * self.f1 + 4.0 * self.f2 * x * x;
            let hxy = 4.0 * self.f2 * x * y;
            let hyy = 2.0 * self.f1 + 4.0 * self.f2 * y * y;
            v3(q_bar.x - (hxx * dm_bar.x + hxy * dm_bar.y), q_bar.y - (hxy * dm_bar.x + hyy * dm_bar.y), q_bar.z - 0.0)
        };
        let r = d.dot(dq_bar) / n.dot(*d);
        (v3(dq_bar.x - n.x * r, dq_bar.y - n.y * r, dq_bar.z - n.z * r), [r * w, -dm_bar.x, -dm_bar.y])
    }
}

impl AdjointPlan {
    /// Sweep a block backwards: `tape` from [`crate::tracer::simd::trace_block_recording`] at one
    /// wavelength (`n` its indices, the table every lane was traced with), λ = ∂L/∂(p, d) per lane at the
    /// image (image frame: `lambda` = [λ_px, λ_py, λ_pz, λ_dx, λ_dy, λ_dz]), for the lanes of `active`
    /// (lanes that arrived; others are ignored whatever their tape holds). Each active lane's
    /// sensitivities are added to its lane of `sums` unless one is not finite. Returns the lanes added.
    #[allow(clippy::too_many_arguments)]
    pub fn backward_lanes(&self, level: SimdLevel, ds: &DiffSystem, tape: &LaneTape, n: &[f64], lambda: &[Lf; 6], active: Lm, sums: &mut LaneSums) -> Lm {
        assert_eq!(tape.steps.len(), ds.system.path.len(), "backward_lanes: the tape holds a partial trace (no lane arrived)");
        at_level(level, Sweep { plan: self, path: &ds.system.path, tape, n, lambda, active, sums })
    }
}

struct Sweep<'a> {
    plan: &'a AdjointPlan,
    path: &'a [PathStep],
    tape: &'a LaneTape,
    n: &'a [f64],
    lambda: &'a [Lf; 6],
    active: Lm,
    sums: &'a mut LaneSums,
}

impl LaneKernel for Sweep<'_> {
    type Output = Lm;
    #[inline(always)]
    fn run(self) -> Lm {
        let Sweep { plan, path, tape, n, lambda, active, sums } = self;
        let (mut lq, mut ld) = (v3(lambda[0], lambda[1], lambda[2]), v3(lambda[3], lambda[4], lambda[5]));
        let mut finite = active;
        // Down to the earliest step a parameter moves (`AdjointPlan::first_step`): nothing is summed before it.
        for s in (plan.first..tape.steps.len()).rev() {
            let (st, step, sp) = (&tape.steps[s], &path[s], &plan.steps[s]);
            let local = LocalLanes::at(&step.shape, &st.q, &st.normal);
            let (d, q) = (st.d, st.q);
            let (n1, n2) = (n[step.surface - 1], n[step.surface]);
            let mu = n1 / n2;
            let mut q_bar = lq;
            let (dd_bar, n_bar);
            // μ̄ and f̄ only where a parameter moves an index or the focal length.
            let (mut mu_bar, mut f_bar) = (ZERO, ZERO);
            match step.shape {
                SurfaceShape::Paraxial { focal_length: f } => {
                    let inv_dz = 1.0 / d.z;
                    let (ux, uy) = (d.x * inv_dz, d.y * inv_dz);
                    let inv_f = 1.0 / f;
                    let tx = mu * ux - q.x * inv_f;
                    let ty = mu * uy - q.y * inv_f;
                    let w = v3(tx, ty, Lf::splat(1.0));
                    let wl = w.dot(w).sqrt();
                    let inv_wl = 1.0 / wl;
                    let v = w.scale(inv_wl);
                    let k = Lf::select(d.z.lt(ZERO), -inv_wl, inv_wl);
                    let vl = v.dot(ld);
                    let (txb, tyb) = ((ld.x - v.x * vl) * k, (ld.y - v.y * vl) * k);
                    if sp.index {
                        mu_bar = txb * ux + tyb * uy;
                    }
                    let (mx, my) = (mu * txb * inv_dz, mu * tyb * inv_dz);
                    dd_bar = v3(mx, my, -(mx * ux + my * uy));
                    q_bar.x = q_bar.x - txb * inv_f;
                    q_bar.y = q_bar.y - tyb * inv_f;
                    if sp.focal {
                        f_bar = (txb * q.x + tyb * q.y) * (inv_f * inv_f);
                    }
                    n_bar = v3(ZERO, ZERO, ZERO);
                }
                // No index change and none moving: the trace keeps d (the identity).
                _ if n1 == n2 && !sp.index => {
                    dd_bar = ld;
                    n_bar = v3(ZERO, ZERO, ZERO);
                }
                _ => {
                    // oriented_normal: the normal against the incoming direction's side.
                    let cos0 = d.dot(st.normal);
                    // (n̂, cos θᵢ) or (−n̂, −cos0): multiplied by sgn = ±1, which is the negation bit for bit.
                    let sgn = Lf::select(cos0.lt(ZERO), Lf::splat(-1.0), Lf::splat(1.0));
                    let nrm = st.normal.scale(sgn);
                    let cos_i = cos0 * sgn;
                    let kappa = 1.0 - mu * mu * (1.0 - cos_i * cos_i);
                    let sk = Lf::select(kappa.ge(ZERO), kappa, ZERO).sqrt();
                    let inv_sk = 1.0 / sk;
                    let beta = ld.dot(nrm);
                    let gamma = beta * (mu * mu * cos_i * inv_sk - mu);
                    if sp.index {
                        mu_bar = ld.dot(d) - beta * (mu * (1.0 - cos_i * cos_i) * inv_sk + cos_i);
                    }
                    dd_bar = v3(ld.x * mu + nrm.x * gamma, ld.y * mu + nrm.y * gamma, ld.z * mu + nrm.z * gamma);
                    let a = sk - mu * cos_i;
                    n_bar = v3((ld.x * a + d.x * gamma) * sgn, (ld.y * a + d.y * gamma) * sgn, (ld.z * a + d.z * gamma) * sgn);
                }
            }
            let (ray_bar, pb) = local.adjoint(&d, q_bar, n_bar);
            // dray = δp + t δd.
            let (mp, md) = (ray_bar, v3(dd_bar.x + ray_bar.x * st.t, dd_bar.y + ray_bar.y * st.t, dd_bar.z + ray_bar.z * st.t));
            let sens = &mut sums.sens[s];
            for &f in &sp.shape_fields {
                let (a, b, c) = local.param_partials(&shape_unit(f));
                let v = pb[0] * a + pb[1] * b + pb[2] * c + if f == 10 { f_bar } else { ZERO };
                finite = finite & v.is_finite();
                sens.shape[f] = v;
            }
            if sp.rotation {
                // δR : (μ_p prᵀ + μ_d d0ᵀ), by columns.
                let (pr, d0) = (st.pr, st.d0);
                let (pc, dc) = ([pr.x, pr.y, pr.z], [d0.x, d0.y, d0.z]);
                for c in 0..3 {
                    let col = v3(mp.x * pc[c] + md.x * dc[c], mp.y * pc[c] + md.y * dc[c], mp.z * pc[c] + md.z * dc[c]);
                    finite = finite & col.is_finite();
                    sens.rotation[3 * c] = col.x;
                    sens.rotation[3 * c + 1] = col.y;
                    sens.rotation[3 * c + 2] = col.z;
                }
            }
            let rt = step.rotation.transpose();
            (lq, ld) = (rotate(&rt, mp), rotate(&rt, md));
            if sp.index {
                sens.n1 = mu_bar / n2;
                sens.n2 = -mu * mu_bar / n2;
                finite = finite & sens.n1.is_finite() & sens.n2.is_finite();
            }
            // −μ_p·(R δo) = (−Rᵀμ_p)·δo.
            if sp.offset {
                sens.offset = [-lq.x, -lq.y, -lq.z];
            }
            finite = finite & lq.is_finite() & ld.is_finite();
        }
        // Add the finite active lanes (+0 elsewhere: the other lanes' sums keep their bits). The value
        // added is `Lf::select(finite, v, 0)` bit for bit — v's bits ANDed with all ones or all zeros —
        // with the lane mask widened once per block instead of once per sum.
        let keep: [u64; LANES] = std::array::from_fn(|k| (finite.0[k] as u64).wrapping_neg());
        for s in plan.first..tape.steps.len() {
            let (sens, sp) = (&sums.sens[s], &plan.steps[s]);
            let (rot, off, shape) = (&mut sums.rotation[s], &mut sums.offset[s], &mut sums.shape[s]);
            if sp.rotation {
                for i in 0..9 {
                    add_kept(&mut rot[i], &sens.rotation[i], &keep);
                }
            }
            if sp.offset {
                for i in 0..3 {
                    add_kept(&mut off[i], &sens.offset[i], &keep);
                }
            }
            for &f in &sp.shape_fields {
                add_kept(&mut shape[f], &sens.shape[f], &keep);
            }
            if sp.index {
                let sf = path[s].surface;
                add_kept(&mut sums.index[sf - 1], &sens.n1, &keep);
                add_kept(&mut sums.index[sf], &sens.n2, &keep);
            }
        }
        finite
    }
}
