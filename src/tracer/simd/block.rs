//! One block of `N` rays through a path, lane by lane the arithmetic of the scalar kernel
//! ([`crate::tracer::kernel::trace_step`], [`crate::surfaces::intersect`]): the same operations in the same
//! order, with each branch of the scalar code turned into a per-lane mask and a select. Lanes that stop
//! (missed, vignetted, TIR, no convergence) are marked dead with their status and surface and take no
//! further part in any decision; the rest carry on.
//!
//! The code is generic over the float type ([`Real`]): [`Block`] (f64, [`LANES`] lanes) is bit for bit the
//! scalar kernel — every system constant enters as `Lanes::of(c)` (the identity for f64) after the same
//! scalar f64 arithmetic the scalar code does, and the tolerances come from `Real`'s f64 implementation,
//! which are the scalar kernel's. [`BlockF32`] ([`LANES_F32`] lanes) runs the same steps in f32: system
//! constants are computed in f64 and rounded once, intersections happen in each surface's local frame,
//! the conic root uses the stable quadratic form, and the branch and Newton tolerances are scaled to f32's
//! rounding (`Real for f32`).
//!
//! The even-asphere Newton solve runs all lanes' iterations together: iteration *i* of the loop is
//! iteration *i* of every lane still solving, with the scalar rule per lane (bracket, bisection fallback,
//! step and bracket-width tests, the 100-iteration budget and its residual test). The scalar code
//! re-evaluates f at the accepted step before returning; here that evaluation is the next iteration's (the
//! same numbers), and a lane that accepted on the last iteration is checked after the loop.
// Index loops over 0..N are the idiom LLVM vectorises into whole registers; keep them explicit.
#![allow(clippy::needless_range_loop)]
use super::lanes::{Lanes, Mask, Real, V3, LANES, LANES_F32};
use crate::surfaces::{Aperture, IntersectFailure, SurfaceShape};
use crate::system::{Interaction, PathStep};
use crate::tracer::RayStatus;
use glam::{DMat3, DVec3};

/// The state of `N` rays of float type `T`: position and unit direction (in the frame of the last step
/// traced), and per lane whether it is still travelling or where and why it stopped.
#[derive(Clone, Copy, Debug)]
pub struct LaneBlock<T, const N: usize> {
    pub p: V3<T, N>,
    pub d: V3<T, N>,
    /// Still travelling.
    pub alive: Mask<N>,
    /// For dead lanes: why (`RayStatus as u8`) and where (surface index) they stopped.
    pub status: [u8; N],
    pub surface: [u32; N],
}

/// The exact f64 block ([`LANES`] rays), bit for bit the scalar kernel.
pub type Block = LaneBlock<f64, LANES>;
/// The f32 block ([`LANES_F32`] rays, the render's `--precision f32`).
pub type BlockF32 = LaneBlock<f32, LANES_F32>;

impl<T: Real, const N: usize> Default for LaneBlock<T, N> {
    fn default() -> Self {
        LaneBlock {
            p: V3::splat(DVec3::ZERO),
            d: V3::splat(DVec3::Z),
            alive: Mask::splat(false),
            status: [RayStatus::InvalidInput as u8; N],
            surface: [0; N],
        }
    }
}

impl<T: Real, const N: usize> LaneBlock<T, N> {
    /// Put ray `(p, d)` (d unit) in lane `k`, alive (each coordinate rounded to `T`).
    #[inline(always)]
    pub fn set(&mut self, k: usize, p: DVec3, d: DVec3) {
        self.p.x.0[k] = T::of(p.x);
        self.p.y.0[k] = T::of(p.y);
        self.p.z.0[k] = T::of(p.z);
        self.d.x.0[k] = T::of(d.x);
        self.d.y.0[k] = T::of(d.y);
        self.d.z.0[k] = T::of(d.z);
        self.alive.0[k] = true;
    }
    /// [`LaneBlock::set`] for a unit `d`, or an invalid input when `T` cannot carry the origin to
    /// µm ([`Real::MAX_INPUT_MM`]; f64 accepts every finite origin).
    #[inline(always)]
    pub fn set_checked(&mut self, k: usize, p: DVec3, d: DVec3) {
        if T::MAX_INPUT_MM.is_finite() && !(p.abs().max_element() <= T::MAX_INPUT_MM) {
            self.set_invalid(k);
        } else {
            self.set(k, p, d);
        }
    }
    /// Put ray `(p, d)` in lane `k` with `d` of any length; [`LaneBlock::normalize_inputs`] then divides the
    /// directions by their lengths and marks invalid rays. For f32, a direction whose length f32 cannot
    /// square is first scaled by its largest component (in f64) and an origin beyond
    /// [`Real::MAX_INPUT_MM`] is an invalid input.
    #[inline(always)]
    pub fn set_raw(&mut self, k: usize, p: DVec3, d: DVec3) {
        if T::MAX_INPUT_MM.is_finite() {
            let m = d.abs().max_element();
            let d = if (1e-15..=1e15).contains(&m) { d } else { d / m };
            self.set_checked(k, p, d);
        } else {
            self.set(k, p, d);
        }
    }
    /// The renderer's input check and normalisation (`trace_interleaved`: finite origin and direction,
    /// |d| > 0, d / |d|) for the lanes loaded with [`LaneBlock::set_raw`], all lanes at once.
    #[inline(always)]
    pub fn normalize_inputs(&mut self) {
        let len = self.d.dot(self.d).sqrt();
        let valid = self.alive & self.p.is_finite() & self.d.is_finite() & len.gt(Lanes::of(0.0));
        self.d = V3 { x: self.d.x / len, y: self.d.y / len, z: self.d.z / len };
        for k in 0..N {
            if self.alive.0[k] && !valid.0[k] {
                self.set_invalid(k);
            }
        }
    }
    /// Mark lane `k` dead before tracing (an invalid input ray).
    #[inline(always)]
    pub fn set_invalid(&mut self, k: usize) {
        self.alive.0[k] = false;
        self.status[k] = RayStatus::InvalidInput as u8;
        self.surface[k] = 0;
    }
    /// Lane `k`'s outcome, as [`crate::tracer::kernel::trace_steps`] reports it (f64 vectors).
    #[inline(always)]
    pub fn result(&self, k: usize) -> Result<(DVec3, DVec3), (RayStatus, usize)> {
        if self.alive.0[k] {
            Ok((
                DVec3::new(self.p.x.0[k].to_f64(), self.p.y.0[k].to_f64(), self.p.z.0[k].to_f64()),
                DVec3::new(self.d.x.0[k].to_f64(), self.d.y.0[k].to_f64(), self.d.z.0[k].to_f64()),
            ))
        } else {
            Err((status_from_code(self.status[k]), self.surface[k] as usize))
        }
    }
    /// Stop the live lanes of `m` with `status` at `surface`. Rays rarely stop, so the lanes' stop codes
    /// are written only when some live lane of `m` does (one test of the mask): with the selects of the
    /// codes on every call the kernel traced ≈ 20 % fewer rays/s (SP and AP, docs/performance.md,
    /// "Session 17").
    #[inline(always)]
    fn kill(&mut self, m: Mask<N>, status: RayStatus, surface: usize) {
        let stop = self.alive & m;
        if stop.any() {
            self.record_stop(stop, status, surface);
        }
        self.alive = self.alive & !m;
    }

    /// Write `status` and `surface` into the lanes of `stop` (branch-free selects, so they vectorise).
    #[inline(always)]
    fn record_stop(&mut self, stop: Mask<N>, status: RayStatus, surface: usize) {
        let (code, surface) = (status as u8, surface as u32);
        for k in 0..N {
            self.status[k] = if stop.0[k] { code } else { self.status[k] };
            self.surface[k] = if stop.0[k] { surface } else { self.surface[k] };
        }
    }
}

/// The [`RayStatus`] of a code stored by `LaneBlock::kill` (only the sequential kernel's statuses occur).
#[inline]
fn status_from_code(code: u8) -> RayStatus {
    match code {
        c if c == RayStatus::Missed as u8 => RayStatus::Missed,
        c if c == RayStatus::Vignetted as u8 => RayStatus::Vignetted,
        c if c == RayStatus::TotalInternalReflection as u8 => RayStatus::TotalInternalReflection,
        c if c == RayStatus::NoConvergence as u8 => RayStatus::NoConvergence,
        c if c == RayStatus::InvalidInput as u8 => RayStatus::InvalidInput,
        c if c == RayStatus::Absorbed as u8 => RayStatus::Absorbed,
        c if c == RayStatus::BounceLimit as u8 => RayStatus::BounceLimit,
        c if c == RayStatus::Evanescent as u8 => RayStatus::Evanescent,
        _ => RayStatus::Ok,
    }
}

/// glam's `DMat3 * DVec3`: x_axis·v.x + y_axis·v.y + z_axis·v.z, in that order.
#[inline(always)]
pub(crate) fn rotate<T: Real, const N: usize>(m: &DMat3, v: V3<T, N>) -> V3<T, N> {
    let e = |c: f64| Lanes::<T, N>::of(c);
    V3 {
        x: e(m.x_axis.x) * v.x + e(m.y_axis.x) * v.y + e(m.z_axis.x) * v.z,
        y: e(m.x_axis.y) * v.x + e(m.y_axis.y) * v.y + e(m.z_axis.y) * v.z,
        z: e(m.x_axis.z) * v.x + e(m.y_axis.z) * v.y + e(m.z_axis.z) * v.z,
    }
}

/// The vertex plane z = 0: (hit, t, point). Missed when d_z = 0 or the point is not finite.
#[inline(always)]
fn plane<T: Real, const N: usize>(p: V3<T, N>, d: V3<T, N>) -> (Mask<N>, Lanes<T, N>, V3<T, N>) {
    let t = -p.z / d.z;
    let point = V3 { x: p.x + t * d.x, y: p.y + t * d.y, z: Lanes::of(0.0) };
    (d.z.ne(Lanes::of(0.0)) & point.x.is_finite() & point.y.is_finite(), t, point)
}

/// [`crate::surfaces::intersect::on_conic_vertex_branch`] per lane, for the point at parameter `t`.
#[inline(always)]
fn on_vertex_branch<T: Real, const N: usize>(point: V3<T, N>, t: Lanes<T, N>, c: f64, kk: f64) -> Mask<N> {
    let r2 = point.x * point.x + point.y * point.y;
    let domain = Lanes::of(1.0) - Lanes::of(kk * c * c) * r2;
    let sag = Lanes::of(c) * r2 / (Lanes::of(1.0) + domain.sqrt());
    !domain.lt(Lanes::of(0.0)) & (point.z - sag).abs().le(T::branch_tol(point.z, t))
}

/// The quadratic a s² + 2 b s + cc = 0 of the conic c(x²+y²+kk·z²) − 2z = 0 (kk = 1 + k) along the lines
/// p + t·d, in s from the lines' points nearest the vertex p₀ = p + t₀·d, t₀ = −p·d (t = t₀ + s): the scalar
/// `surfaces::NearestQuadratic`'s operations in its order, (t₀, p₀, a, b, cc).
#[inline(always)]
#[allow(clippy::type_complexity)]
fn nearest_quadratic<T: Real, const N: usize>(c: f64, kk: f64, p: V3<T, N>, d: V3<T, N>) -> (Lanes<T, N>, V3<T, N>, Lanes<T, N>, Lanes<T, N>, Lanes<T, N>) {
    let t0 = -p.dot(d);
    let p0 = p.along(d, t0);
    let (cl, kl) = (Lanes::<T, N>::of(c), Lanes::<T, N>::of(kk));
    let a = cl * (d.x * d.x + d.y * d.y + kl * d.z * d.z);
    let b = cl * (p0.x * d.x + p0.y * d.y + kl * p0.z * d.z) - d.z;
    let cc = cl * (p0.x * p0.x + p0.y * p0.y + kl * p0.z * p0.z) - Lanes::of(2.0) * p0.z;
    (t0, p0, a, b, cc)
}

/// The conic's vertex-branch root (`conic_root` of the scalar code, the same operations in the same order:
/// solved from the line's point nearest the vertex p₀ = p + t₀·d, t₀ = −p·d, in the stable form
/// q = −(b + sgn b·√disc), s = c/q or q/a, the root nearest the ray's start tested first) for the lanes of
/// `live`: (found, t = t₀ + s, the point p₀ + s·d). The farther root is tested only when a live lane needs
/// it (as the scalar code does per ray).
#[inline(always)]
fn conic_root<T: Real, const N: usize>(c: f64, k: f64, p: V3<T, N>, d: V3<T, N>, live: Mask<N>) -> (Mask<N>, Lanes<T, N>, V3<T, N>) {
    let kk = 1.0 + k;
    let zero = Lanes::of(0.0);
    let (t0, p0, a, b, cc) = nearest_quadratic(c, kk, p, d);
    let disc = b * b - a * cc;
    let q = -(b + b.signum() * disc.sqrt());
    let ok = disc.ge(zero) & q.ne(zero);
    let (s1, s2) = (cc / q, q / a);
    let (r1, r2) = (t0 + s1, t0 + s2);
    // Nearest the start first; a = 0 (s₂ = ±∞ or NaN) never swaps, as the scalar code's NaN.
    let swap = r2.abs().lt(r1.abs());
    let (s_near, t_near) = (Lanes::select(swap, s2, s1), Lanes::select(swap, r2, r1));
    let point_near = p0.along(d, s_near);
    let on_near = s_near.is_finite() & t_near.is_finite() & on_vertex_branch(point_near, s_near, c, kk);
    if !(live & ok & !on_near).any() {
        return (ok & on_near, t_near, point_near);
    }
    let (s_far, t_far) = (Lanes::select(swap, s1, s2), Lanes::select(swap, r1, r2));
    let point_far = p0.along(d, s_far);
    let on_far = s_far.is_finite() & t_far.is_finite() & on_vertex_branch(point_far, s_far, c, kk);
    (ok & (on_near | on_far), Lanes::select(on_near, t_near, t_far), V3::select(on_near, point_near, point_far))
}

/// Both roots of the conic c(x²+y²+(1+k)z²) − 2z = 0 along the lines p + t·d that lie on its vertex branch,
/// ascending — `SurfacePatch::closed_form_roots` (patch.rs `conic_roots`, Numerical Recipes §5.6) per lane,
/// the same operations in the same order, so each lane's roots are the scalar ones bit for bit (the
/// Embree user geometry solves a packet's lanes at once with it): (first found, first, second found,
/// second). Unlike [`conic_root`] (the sequential kernel's vertex-branch root), the second root is kept.
#[inline(always)]
#[cfg_attr(not(feature = "embree"), allow(dead_code))] // only the Embree user geometry calls it
pub(crate) fn conic_roots_both<T: Real, const N: usize>(c: f64, k: f64, p: V3<T, N>, d: V3<T, N>) -> (Mask<N>, Lanes<T, N>, Mask<N>, Lanes<T, N>) {
    let kk = 1.0 + k;
    let zero = Lanes::of(0.0);
    // From the line's point nearest the vertex (`conic_roots`: t = t₀ + s).
    let (t0, p0, a, b, cc) = nearest_quadratic(c, kk, p, d);
    let on_branch = |s: Lanes<T, N>| s.is_finite() & (t0 + s).is_finite() & on_vertex_branch(p0.along(d, s), s, c, kk);
    // a = 0: linear, 2 b s + cc = 0.
    let linear = a.eq(zero);
    let s_lin = -cc / (Lanes::of(2.0) * b);
    let lin_ok = linear & b.ne(zero) & on_branch(s_lin);
    let disc = b * b - a * cc;
    let quad = !linear & disc.ge(zero);
    let sign = Lanes::select(b.ge(zero), Lanes::of(1.0), Lanes::of(-1.0));
    let q = -(b + sign * disc.sqrt());
    let q0 = q.eq(zero);
    let (r1, r2) = (Lanes::select(q0, zero, cc / q), Lanes::select(q0, zero, q / a));
    let ordered = r1.le(r2);
    let (lo, hi) = (Lanes::select(ordered, r1, r2), Lanes::select(ordered, r2, r1));
    let lo_ok = quad & on_branch(lo);
    let hi_ok = quad & on_branch(hi);
    // (None, h) → (h, None).
    let first = t0 + Lanes::select(linear, s_lin, Lanes::select(lo_ok, lo, hi));
    let first_ok = (linear & lin_ok) | (lo_ok | hi_ok);
    (first_ok, first, lo_ok & hi_ok, t0 + hi)
}

/// The even asphere's sag and gradient terms at parameter `t` along the lines: (f, f′) of the scalar
/// Newton solve, f = z − sag(x, y), f′ = d_z − ∂z/∂x d_x − ∂z/∂y d_y.
#[inline(always)]
fn asphere_eval<T: Real, const N: usize>(c: f64, k: f64, coefficients: &[f64], p: V3<T, N>, d: V3<T, N>, t: Lanes<T, N>) -> (Lanes<T, N>, Lanes<T, N>) {
    let q = p.along(d, t);
    let (sag, dz_dr2) = sag_and_slope(c, k, coefficients, q.x, q.y);
    let two = Lanes::of(2.0);
    let gx = two * q.x * dz_dr2;
    let gy = two * q.y * dz_dr2;
    (q.z - sag, d.z - gx * d.x - gy * d.y)
}

/// Sag and d(sag)/d(r²) of the even asphere ([`SurfaceShape::sag`], `sag_gradient`): NaN where the
/// conic's square root is undefined (the sag at disc < 0, the slope at disc ≤ 0).
#[inline(always)]
fn sag_and_slope<T: Real, const N: usize>(c: f64, k: f64, coefficients: &[f64], x: Lanes<T, N>, y: Lanes<T, N>) -> (Lanes<T, N>, Lanes<T, N>) {
    let r2 = x * x + y * y;
    let disc = Lanes::of(1.0) - Lanes::of((1.0 + k) * c * c) * r2;
    let root = disc.sqrt();
    let zero = Lanes::of(0.0);
    let nan = Lanes::of(f64::NAN);
    let conic_sag = Lanes::select(disc.lt(zero), nan, Lanes::of(c) * r2 / (Lanes::of(1.0) + root));
    let conic_slope = Lanes::select(disc.le(zero), nan, Lanes::of(c) / (Lanes::of(2.0) * root));
    let mut value = zero;
    let mut deriv = zero;
    for (i, a) in coefficients.iter().enumerate().rev() {
        let power = (i + 1) as f64;
        value = (value + Lanes::of(*a)) * r2;
        deriv = deriv * r2 + Lanes::of(power * a);
    }
    (conic_sag + value, conic_slope + deriv)
}

/// Guarded Newton on the lanes of `active` from `t0` (the scalar `asphere_newton`, see the module docs):
/// (converged, no-convergence, t). Lanes neither converged nor flagged no-convergence missed.
#[inline(always)]
fn asphere_newton<T: Real, const N: usize>(c: f64, k: f64, coefficients: &[f64], p: V3<T, N>, d: V3<T, N>, active: Mask<N>, t0: Lanes<T, N>) -> (Mask<N>, Mask<N>, Lanes<T, N>) {
    const MAX_ITER: usize = 100;
    let zero = Lanes::of(0.0);
    let half = Lanes::of(0.5);
    let mut t = t0;
    let (mut lo, mut hi) = (zero, zero);
    let (mut has_lo, mut has_hi) = (Mask::splat(false), Mask::splat(false));
    let mut running = active;
    // Lanes whose step test fired: the next evaluation decides them (|f| < the residual tolerance).
    let mut checking = Mask::splat(false);
    let (mut ok, mut nc) = (Mask::splat(false), Mask::splat(false));
    for _ in 0..MAX_ITER {
        if !running.any() {
            break;
        }
        let (f, fp) = asphere_eval(c, k, coefficients, p, d, t);
        let finite = f.is_finite();
        // The deferred step test of the previous iteration.
        let fc = running & checking;
        let fc_ok = finite & f.abs().lt(T::newton_residual_tol(t, false));
        ok = ok | (fc & fc_ok);
        nc = nc | (fc & !fc_ok);
        running = running & !fc;
        let it = running;
        let bracket = has_lo & has_hi;
        // f undefined: bisect inside a bracket, else missed.
        let undefined = it & !finite;
        let bisect = undefined & bracket;
        running = running & !(undefined & !bracket);
        let mid_old = half * (lo + hi);
        let go = it & finite;
        let exact = go & f.eq(zero);
        ok = ok | exact;
        running = running & !exact;
        let go = go & !exact;
        let neg = f.lt(zero);
        lo = Lanes::select(go & neg, t, lo);
        hi = Lanes::select(go & !neg, t, hi);
        has_lo = has_lo | (go & neg);
        has_hi = has_hi | (go & !neg);
        let mut next = t - f / fp;
        let br = go & has_lo & has_hi;
        let ordered = lo.lt(hi);
        let min = Lanes::select(ordered, lo, hi);
        let max = Lanes::select(ordered, hi, lo);
        let outside = !(next.gt(min) & next.lt(max));
        next = Lanes::select(br & outside, half * (lo + hi), next);
        let tight = br & (max - min).le(Lanes::splat(T::of(4.0) * T::EPSILON) * (Lanes::of(1.0) + t.abs()));
        ok = ok | tight;
        running = running & !tight;
        let unbracketed_bad = go & !br & !next.is_finite();
        nc = nc | unbracketed_bad;
        running = running & !unbracketed_bad;
        let moving = go & !tight & !unbracketed_bad;
        let small = moving & (next - t).abs().le(T::newton_step_tol(t));
        checking = checking | small;
        t = Lanes::select(moving | tight, next, t);
        t = Lanes::select(bisect, mid_old, t);
    }
    if running.any() {
        // Out of iterations: lanes in their deferred step test use the step residual, the others accept a
        // converged residual (the strict one) as the scalar code does after its loop.
        let (f, _) = asphere_eval(c, k, coefficients, p, d, t);
        let limit = Lanes::select(checking, T::newton_residual_tol(t, false), T::newton_residual_tol(t, true));
        let good = running & f.is_finite() & f.abs().lt(limit);
        ok = ok | good;
        nc = nc | (running & !good);
    }
    (ok, nc, t)
}

/// A mirror's reflection or a grating's diffraction, lane by lane with the scalar kernel's functions
/// (`tracer::kernel::reflect`, `surfaces::grating::diffract`) and its classification (grazing → `missed`,
/// evanescent order → `evanescent`): the same bits as the scalar kernel in f64.
#[inline(never)]
fn special_interaction<T: Real, const N: usize>(step: &PathStep, n: &[&[f64]; N], b: &mut LaneBlock<T, N>, d: V3<T, N>, normal: V3<T, N>, s: usize) -> V3<T, N> {
    use crate::tracer::kernel::{reflect, GRAZING_COS};
    let mut out = d;
    let (mut grazing, mut evanescent) = ([false; N], [false; N]);
    for k in 0..N {
        if !b.alive.0[k] {
            continue;
        }
        let dk = DVec3::new(d.x.0[k].to_f64(), d.y.0[k].to_f64(), d.z.0[k].to_f64());
        let nk = DVec3::new(normal.x.0[k].to_f64(), normal.y.0[k].to_f64(), normal.z.0[k].to_f64());
        let r = match step.interaction {
            Interaction::Refract => Some(dk),
            Interaction::Reflect => {
                if dk.dot(nk).abs() <= GRAZING_COS {
                    grazing[k] = true;
                    continue;
                }
                Some(reflect(dk, nk))
            }
            Interaction::Grating { grating, reflective, wavelength_slot } => {
                if reflective && dk.dot(nk).abs() <= GRAZING_COS {
                    grazing[k] = true;
                    continue;
                }
                let (n1, n2) = (n[k][s - 1], n[k][s]);
                crate::surfaces::grating::diffract(dk, nk, n1, n2, grating.kick(n[k][wavelength_slot]), reflective)
            }
        };
        match r {
            Some(v) => (out.x.0[k], out.y.0[k], out.z.0[k]) = (T::of(v.x), T::of(v.y), T::of(v.z)),
            None => evanescent[k] = true,
        }
    }
    b.kill(Mask(grazing), RayStatus::Missed, s);
    b.kill(Mask(evanescent), RayStatus::Evanescent, s);
    out
}

/// What a step of [`trace_block`] hands its recorder: the lanes' state the adjoint sweep needs
/// ([`super::record::LaneTape`]). The production trace passes `()`, which keeps nothing (and compiles to
/// nothing: the arithmetic and its results are the same either way).
pub(crate) trait StepRecorder<T, const N: usize> {
    /// Step `s`: p − o and d before the frame change, d in the step's frame, the hit point, its unit
    /// normal (as `intersect` gives it) and the distance t from the frame-changed origin.
    #[allow(clippy::too_many_arguments)]
    fn record(&mut self, s: usize, pr: &V3<T, N>, d0: &V3<T, N>, d: &V3<T, N>, q: &V3<T, N>, normal: &V3<T, N>, t: &Lanes<T, N>);
}

impl<T, const N: usize> StepRecorder<T, N> for () {
    #[inline(always)]
    fn record(&mut self, _: usize, _: &V3<T, N>, _: &V3<T, N>, _: &V3<T, N>, _: &V3<T, N>, _: &V3<T, N>, _: &Lanes<T, N>) {}
}

/// Trace the live lanes of `b` (object frame) along `path`; `n[k]` is lane k's table of indices after
/// each surface. On return live lanes hold the last step's frame position and direction. `rec` sees each
/// step's state (`&mut ()` keeps nothing).
#[inline(always)]
pub(crate) fn trace_block<T: Real, const N: usize, R: StepRecorder<T, N>>(path: &[PathStep], n: &[&[f64]; N], b: &mut LaneBlock<T, N>, rec: &mut R) {
    let uniform = n.iter().all(|t| std::ptr::eq(t.as_ptr(), n[0].as_ptr()) && t.len() == n[0].len());
    for (s, step) in path.iter().enumerate() {
        if !b.alive.any() {
            return;
        }
        trace_step(step, n, uniform, b, s, rec);
    }
}

/// One step of [`trace_block`]: frame change, intersection, aperture, refraction or ideal lens.
#[inline(always)]
fn trace_step<T: Real, const N: usize, R: StepRecorder<T, N>>(step: &PathStep, n: &[&[f64]; N], uniform: bool, b: &mut LaneBlock<T, N>, index: usize, rec: &mut R) {
    let o = step.offset;
    let q = V3 { x: b.p.x - T::of(o.x), y: b.p.y - T::of(o.y), z: b.p.z - T::of(o.z) };
    let p = rotate(&step.rotation, q);
    let d = rotate(&step.rotation, b.d);
    let s = step.surface;
    let z_axis = V3::splat(DVec3::Z);
    // (t is kept for a recorder only; the production trace drops it.)
    let (hit, t, point, normal) = match &step.shape {
        SurfaceShape::Plane | SurfaceShape::Paraxial { .. } => {
            let (hit, t, point) = plane(p, d);
            (hit, t, point, z_axis)
        }
        SurfaceShape::Conic { curvature, conic } => {
            let (c, k) = (*curvature, *conic);
            if c == 0.0 {
                let (hit, t, point) = plane(p, d);
                (hit, t, point, z_axis)
            } else {
                let (hit, t, point) = conic_root(c, k, p, d, b.alive);
                let ck = c * (1.0 + k);
                let normal = V3 { x: Lanes::of(-c) * point.x, y: Lanes::of(-c) * point.y, z: Lanes::of(1.0) - Lanes::of(ck) * point.z }.normalize();
                (hit, t, point, normal)
            }
        }
        SurfaceShape::EvenAsphere { curvature, conic, coefficients } => {
            let (c, k) = (*curvature, *conic);
            let (plane_ok, plane_t, _) = plane(p, d);
            let (conic_ok, conic_t) = if c == 0.0 { (Mask::splat(false), Lanes::of(0.0)) } else { let (ok, t, _) = conic_root(c, k, p, d, b.alive); (ok, t) };
            let first = b.alive & conic_ok;
            let (mut ok, mut nc, mut t) = (Mask::splat(false), Mask::splat(false), Lanes::of(0.0));
            if first.any() {
                (ok, nc, t) = asphere_newton(c, k, coefficients, p, d, first, conic_t);
            }
            let second = b.alive & !ok & plane_ok;
            if second.any() {
                let (ok2, nc2, t2) = asphere_newton(c, k, coefficients, p, d, second, plane_t);
                ok = (ok & !second) | ok2;
                nc = (nc & !second) | nc2;
                t = Lanes::select(second, t2, t);
            }
            let point = p.along(d, t);
            let (_, slope) = sag_and_slope(c, k, coefficients, point.x, point.y);
            let two = Lanes::of(2.0);
            let normal = V3 { x: -(two * point.x * slope), y: -(two * point.y * slope), z: Lanes::of(1.0) }.normalize();
            b.kill(nc & !ok, RayStatus::NoConvergence, s);
            (ok & normal.is_finite(), t, point, normal)
        }
        SurfaceShape::Toroidal { .. } => {
            // Lane by lane with the scalar intersection (`surfaces::intersect`: guarded Newton on the
            // toroid's sag), so f64 lanes give the scalar kernel's bits; the surface is rare enough that
            // a vectorised toroid solve would not pay.
            let (mut t, mut point, mut normal) = (Lanes::of(0.0), V3::splat(DVec3::ZERO), z_axis);
            let (mut ok, mut nc) = ([false; N], [false; N]);
            for k in 0..N {
                if !b.alive.0[k] {
                    continue;
                }
                let pk = DVec3::new(p.x.0[k].to_f64(), p.y.0[k].to_f64(), p.z.0[k].to_f64());
                let dk = DVec3::new(d.x.0[k].to_f64(), d.y.0[k].to_f64(), d.z.0[k].to_f64());
                match crate::surfaces::intersect(&step.shape, pk, dk) {
                    Ok(h) => {
                        ok[k] = true;
                        t.0[k] = T::of(h.t);
                        (point.x.0[k], point.y.0[k], point.z.0[k]) = (T::of(h.point.x), T::of(h.point.y), T::of(h.point.z));
                        (normal.x.0[k], normal.y.0[k], normal.z.0[k]) = (T::of(h.normal.x), T::of(h.normal.y), T::of(h.normal.z));
                    }
                    Err(IntersectFailure::NoConvergence) => nc[k] = true,
                    Err(IntersectFailure::Missed) => {}
                }
            }
            b.kill(Mask(nc), RayStatus::NoConvergence, s);
            (Mask(ok), t, point, normal)
        }
    };
    b.kill(!hit, RayStatus::Missed, s);
    let inside = match step.aperture {
        Aperture::None => Mask::splat(true),
        Aperture::Circular { semi_diameter_mm, min_radius_mm, decenter_x_mm, decenter_y_mm } => {
            let (u, v) = (point.x - T::of(decenter_x_mm), point.y - T::of(decenter_y_mm));
            let r2 = u * u + v * v;
            r2.le(Lanes::of(semi_diameter_mm * semi_diameter_mm)) & r2.ge(Lanes::of(min_radius_mm * min_radius_mm))
        }
        Aperture::Rectangular { half_width_x_mm, half_width_y_mm, decenter_x_mm, decenter_y_mm } => {
            (point.x - T::of(decenter_x_mm)).abs().le(Lanes::of(half_width_x_mm)) & (point.y - T::of(decenter_y_mm)).abs().le(Lanes::of(half_width_y_mm))
        }
        Aperture::CircularObscuration { min_radius_mm, max_radius_mm, decenter_x_mm, decenter_y_mm } => {
            // Aperture::contains: blocked on the closed annulus, r² < rmin² or r² > rmax² passes.
            let (u, v) = (point.x - T::of(decenter_x_mm), point.y - T::of(decenter_y_mm));
            let r2 = u * u + v * v;
            r2.lt(Lanes::of(min_radius_mm * min_radius_mm)) | r2.gt(Lanes::of(max_radius_mm * max_radius_mm))
        }
    };
    b.kill(!inside, RayStatus::Vignetted, s);
    // n₁/n₂ per lane, divided in f64 and rounded once; one scalar division when every lane has the same
    // table (the same bits). Whether the index changes is decided on the f64 indices.
    let (differ, mu) = if uniform {
        let (a, c) = (n[0][s - 1], n[0][s]);
        (Mask::splat(a != c), Lanes::of(a / c))
    } else {
        let (mut differ, mut mu) = ([false; N], [T::default(); N]);
        for k in 0..N {
            let (a, c) = (n[k][s - 1], n[k][s]);
            differ[k] = a != c;
            mu[k] = T::of(a / c);
        }
        (Mask(differ), Lanes(mu))
    };
    let d_new = if step.interaction != Interaction::Refract {
        special_interaction(step, n, b, d, normal, s)
    } else {
        match step.shape {
        SurfaceShape::Paraxial { focal_length } => {
            // Ideal thin lens (kernel::paraxial_deflect): tan′ = (n₁/n₂)·tan − h/f.
            let f = T::of(focal_length);
            let tx = mu * d.x / d.z - point.x / f;
            let ty = mu * d.y / d.z - point.y / f;
            let v = V3 { x: tx, y: ty, z: Lanes::of(1.0) }.normalize();
            let back = d.z.lt(Lanes::of(0.0));
            V3::select(back, v.neg(), v)
        }
        _ => {
            // Vector Snell's law (kernel::refract) where the index changes.
            let one = Lanes::of(1.0);
            let cos0 = d.dot(normal);
            let flip = cos0.lt(Lanes::of(0.0));
            let nrm = V3::select(flip, normal.neg(), normal);
            let cos_i = Lanes::select(flip, -cos0, cos0);
            let k = one - mu * mu * (one - cos_i * cos_i);
            b.kill(differ & k.lt(Lanes::of(0.0)), RayStatus::TotalInternalReflection, s);
            let g = k.sqrt() - mu * cos_i;
            let r = V3 { x: mu * d.x + g * nrm.x, y: mu * d.y + g * nrm.y, z: mu * d.z + g * nrm.z };
            V3::select(differ, r, d)
        }
        }
    };
    rec.record(index, &q, &b.d, &d, &point, &normal, &t);
    b.p = point;
    b.d = d_new;
}
