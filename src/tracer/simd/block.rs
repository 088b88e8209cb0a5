//! One block of [`LANES`] rays through a path, lane by lane the arithmetic of the scalar kernel
//! ([`crate::tracer::kernel::trace_step`], [`crate::surfaces::intersect`]): the same operations in the same
//! order, with each branch of the scalar code turned into a per-lane mask and a select. Lanes that stop
//! (missed, vignetted, TIR, no convergence) are marked dead with their status and surface and take no
//! further part in any decision; the rest carry on.
//!
//! The even-asphere Newton solve runs all lanes' iterations together: iteration *i* of the loop is
//! iteration *i* of every lane still solving, with the scalar rule per lane (bracket, bisection fallback,
//! step and bracket-width tests, the 100-iteration budget and its residual test). The scalar code
//! re-evaluates f at the accepted step before returning; here that evaluation is the next iteration's (the
//! same numbers), and a lane that accepted on the last iteration is checked after the loop.
// Index loops over 0..LANES are the idiom LLVM vectorises into whole registers; keep them explicit.
#![allow(clippy::needless_range_loop)]
use super::lanes::{L3, LANES, Lf, Lm};
use crate::surfaces::{Aperture, SurfaceShape};
use crate::system::PathStep;
use crate::tracer::RayStatus;
use glam::{DMat3, DVec3};

/// The state of [`LANES`] rays: position and unit direction (in the frame of the last step traced),
/// and per lane whether it is still travelling or where and why it stopped.
#[derive(Clone, Copy, Debug)]
pub struct Block {
    pub p: L3,
    pub d: L3,
    /// Still travelling.
    pub alive: Lm,
    /// For dead lanes: why (`RayStatus as u8`) and where (surface index) they stopped.
    pub status: [u8; LANES],
    pub surface: [u32; LANES],
}

impl Default for Block {
    fn default() -> Self {
        Block {
            p: L3::splat(DVec3::ZERO),
            d: L3::splat(DVec3::Z),
            alive: Lm::splat(false),
            status: [RayStatus::InvalidInput as u8; LANES],
            surface: [0; LANES],
        }
    }
}

impl Block {
    /// Put ray `(p, d)` (d unit) in lane `k`, alive.
    #[inline(always)]
    pub fn set(&mut self, k: usize, p: DVec3, d: DVec3) {
        self.p.x.0[k] = p.x;
        self.p.y.0[k] = p.y;
        self.p.z.0[k] = p.z;
        self.d.x.0[k] = d.x;
        self.d.y.0[k] = d.y;
        self.d.z.0[k] = d.z;
        self.alive.0[k] = true;
    }
    /// Put ray `(p, d)` in lane `k` with `d` of any length; [`Block::normalize_inputs`] then divides the
    /// directions by their lengths and marks invalid rays.
    #[inline(always)]
    pub fn set_raw(&mut self, k: usize, p: DVec3, d: DVec3) {
        self.set(k, p, d);
    }
    /// The renderer's input check and normalisation (`trace_interleaved`: finite origin and direction,
    /// |d| > 0, d / |d|) for the lanes loaded with [`Block::set_raw`], all lanes at once.
    #[inline(always)]
    pub fn normalize_inputs(&mut self) {
        let len = self.d.dot(self.d).sqrt();
        let valid = self.alive & self.p.is_finite() & self.d.is_finite() & len.gt(Lf::splat(0.0));
        self.d = L3 { x: self.d.x / len, y: self.d.y / len, z: self.d.z / len };
        for k in 0..LANES {
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
    /// Lane `k`'s outcome, as [`crate::tracer::kernel::trace_steps`] reports it.
    #[inline(always)]
    pub fn result(&self, k: usize) -> Result<(DVec3, DVec3), (RayStatus, usize)> {
        if self.alive.0[k] {
            Ok((DVec3::new(self.p.x.0[k], self.p.y.0[k], self.p.z.0[k]), DVec3::new(self.d.x.0[k], self.d.y.0[k], self.d.z.0[k])))
        } else {
            Err((status_from_code(self.status[k]), self.surface[k] as usize))
        }
    }
    /// Stop the live lanes of `m` with `status` at `surface` (branch-free selects, so they vectorise).
    #[inline(always)]
    fn kill(&mut self, m: Lm, status: RayStatus, surface: usize) {
        let (code, surface) = (status as u8, surface as u32);
        for k in 0..LANES {
            let stop = self.alive.0[k] & m.0[k];
            self.status[k] = if stop { code } else { self.status[k] };
            self.surface[k] = if stop { surface } else { self.surface[k] };
            self.alive.0[k] &= !m.0[k];
        }
    }
}

/// The [`RayStatus`] of a code stored by [`Block::kill`] (only the sequential kernel's statuses occur).
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
        _ => RayStatus::Ok,
    }
}

/// glam's `DMat3 * DVec3`: x_axis·v.x + y_axis·v.y + z_axis·v.z, in that order.
#[inline(always)]
fn rotate(m: &DMat3, v: L3) -> L3 {
    L3 {
        x: m.x_axis.x * v.x + m.y_axis.x * v.y + m.z_axis.x * v.z,
        y: m.x_axis.y * v.x + m.y_axis.y * v.y + m.z_axis.y * v.z,
        z: m.x_axis.z * v.x + m.y_axis.z * v.y + m.z_axis.z * v.z,
    }
}

/// The vertex plane z = 0: (hit, t, point). Missed when d_z = 0 or the point is not finite.
#[inline(always)]
fn plane(p: L3, d: L3) -> (Lm, Lf, L3) {
    let t = -p.z / d.z;
    let point = L3 { x: p.x + t * d.x, y: p.y + t * d.y, z: Lf::splat(0.0) };
    (d.z.ne(Lf::splat(0.0)) & point.x.is_finite() & point.y.is_finite(), t, point)
}

/// [`crate::surfaces::intersect::on_conic_vertex_branch`] per lane.
#[inline(always)]
fn on_vertex_branch(point: L3, c: f64, kk: f64) -> Lm {
    let r2 = point.x * point.x + point.y * point.y;
    let domain = 1.0 - kk * c * c * r2;
    let sag = c * r2 / (1.0 + domain.sqrt());
    !domain.lt(Lf::splat(0.0)) & (point.z - sag).abs().le(1e-9 * (1.0 + point.z.abs()))
}

/// The conic's vertex-branch root (`conic_root` of the scalar code) for the lanes of `live`: (found, t).
/// The second root is computed only when a live lane needs it (as the scalar code does per ray).
#[inline(always)]
fn conic_root(c: f64, k: f64, p: L3, d: L3, live: Lm) -> (Lm, Lf) {
    let kk = 1.0 + k;
    let a = c * (d.x * d.x + d.y * d.y + kk * d.z * d.z);
    let b = c * (p.x * d.x + p.y * d.y + kk * p.z * d.z) - d.z;
    let cc = c * (p.x * p.x + p.y * p.y + kk * p.z * p.z) - 2.0 * p.z;
    let disc = b * b - a * cc;
    let q = -(b + b.signum() * disc.sqrt());
    let ok = disc.ge(Lf::splat(0.0)) & q.ne(Lf::splat(0.0));
    let t1 = cc / q;
    let on1 = t1.is_finite() & on_vertex_branch(p.along(d, t1), c, kk);
    if !(live & ok & !on1).any() {
        return (ok & on1, t1);
    }
    let t2 = q / a;
    let on2 = a.ne(Lf::splat(0.0)) & t2.is_finite() & on_vertex_branch(p.along(d, t2), c, kk);
    (ok & (on1 | on2), Lf::select(on1, t1, t2))
}

/// The even asphere's sag and gradient terms at parameter `t` along the lines: (f, f′) of the scalar
/// Newton solve, f = z − sag(x, y), f′ = d_z − ∂z/∂x d_x − ∂z/∂y d_y.
#[inline(always)]
fn asphere_eval(c: f64, k: f64, coefficients: &[f64], p: L3, d: L3, t: Lf) -> (Lf, Lf) {
    let q = p.along(d, t);
    let (sag, dz_dr2) = sag_and_slope(c, k, coefficients, q.x, q.y);
    let gx = 2.0 * q.x * dz_dr2;
    let gy = 2.0 * q.y * dz_dr2;
    (q.z - sag, d.z - gx * d.x - gy * d.y)
}

/// Sag and d(sag)/d(r²) of the even asphere ([`SurfaceShape::sag`], `sag_gradient`): NaN where the
/// conic's square root is undefined (the sag at disc < 0, the slope at disc ≤ 0).
#[inline(always)]
fn sag_and_slope(c: f64, k: f64, coefficients: &[f64], x: Lf, y: Lf) -> (Lf, Lf) {
    let r2 = x * x + y * y;
    let disc = 1.0 - (1.0 + k) * c * c * r2;
    let root = disc.sqrt();
    let conic_sag = Lf::select(disc.lt(Lf::splat(0.0)), Lf::splat(f64::NAN), c * r2 / (1.0 + root));
    let conic_slope = Lf::select(disc.le(Lf::splat(0.0)), Lf::splat(f64::NAN), c / (2.0 * root));
    let mut value = Lf::splat(0.0);
    let mut deriv = Lf::splat(0.0);
    for (i, a) in coefficients.iter().enumerate().rev() {
        let power = (i + 1) as f64;
        value = (value + *a) * r2;
        deriv = deriv * r2 + power * a;
    }
    (conic_sag + value, conic_slope + deriv)
}

/// Guarded Newton on the lanes of `active` from `t0` (the scalar `asphere_newton`, see the module docs):
/// (converged, no-convergence, t). Lanes neither converged nor flagged no-convergence missed.
#[inline(always)]
fn asphere_newton(c: f64, k: f64, coefficients: &[f64], p: L3, d: L3, active: Lm, t0: Lf) -> (Lm, Lm, Lf) {
    const MAX_ITER: usize = 100;
    let zero = Lf::splat(0.0);
    let mut t = t0;
    let (mut lo, mut hi) = (zero, zero);
    let (mut has_lo, mut has_hi) = (Lm::splat(false), Lm::splat(false));
    let mut running = active;
    // Lanes whose step test fired: the next evaluation decides them (|f| < 1e-9).
    let mut checking = Lm::splat(false);
    let (mut ok, mut nc) = (Lm::splat(false), Lm::splat(false));
    for _ in 0..MAX_ITER {
        if !running.any() {
            break;
        }
        let (f, fp) = asphere_eval(c, k, coefficients, p, d, t);
        let finite = f.is_finite();
        // The deferred step test of the previous iteration.
        let fc = running & checking;
        let fc_ok = finite & f.abs().lt(Lf::splat(1e-9));
        ok = ok | (fc & fc_ok);
        nc = nc | (fc & !fc_ok);
        running = running & !fc;
        let it = running;
        let bracket = has_lo & has_hi;
        // f undefined: bisect inside a bracket, else missed.
        let undefined = it & !finite;
        let bisect = undefined & bracket;
        running = running & !(undefined & !bracket);
        let mid_old = 0.5 * (lo + hi);
        let go = it & finite;
        let exact = go & f.eq(zero);
        ok = ok | exact;
        running = running & !exact;
        let go = go & !exact;
        let neg = f.lt(zero);
        lo = Lf::select(go & neg, t, lo);
        hi = Lf::select(go & !neg, t, hi);
        has_lo = has_lo | (go & neg);
        has_hi = has_hi | (go & !neg);
        let mut next = t - f / fp;
        let br = go & has_lo & has_hi;
        let ordered = lo.lt(hi);
        let min = Lf::select(ordered, lo, hi);
        let max = Lf::select(ordered, hi, lo);
        let outside = !(next.gt(min) & next.lt(max));
        next = Lf::select(br & outside, 0.5 * (lo + hi), next);
        let tight = br & (max - min).le(4.0 * f64::EPSILON * (1.0 + t.abs()));
        ok = ok | tight;
        running = running & !tight;
        let unbracketed_bad = go & !br & !next.is_finite();
        nc = nc | unbracketed_bad;
        running = running & !unbracketed_bad;
        let moving = go & !tight & !unbracketed_bad;
        let small = moving & (next - t).abs().le(1e-15 * (1.0 + t.abs()));
        checking = checking | small;
        t = Lf::select(moving | tight, next, t);
        t = Lf::select(bisect, mid_old, t);
    }
    if running.any() {
        // Out of iterations: lanes in their deferred step test use |f| < 1e-9, the others accept a
        // converged residual (|f| < 1e-12) as the scalar code does after its loop.
        let (f, _) = asphere_eval(c, k, coefficients, p, d, t);
        let limit = Lf::select(checking, Lf::splat(1e-9), Lf::splat(1e-12));
        let good = running & f.is_finite() & f.abs().lt(limit);
        ok = ok | good;
        nc = nc | (running & !good);
    }
    (ok, nc, t)
}

/// Trace the live lanes of `b` (object frame) along `path`; `n[k]` is lane k's table of indices after
/// each surface. On return live lanes hold the last step's frame position and direction.
#[inline(always)]
pub(crate) fn trace_block(path: &[PathStep], n: &[&[f64]; LANES], b: &mut Block) {
    let uniform = n.iter().all(|t| std::ptr::eq(t.as_ptr(), n[0].as_ptr()) && t.len() == n[0].len());
    for step in path {
        if !b.alive.any() {
            return;
        }
        trace_step(step, n, uniform, b);
    }
}

/// One step of [`trace_block`]: frame change, intersection, aperture, refraction or ideal lens.
#[inline(always)]
fn trace_step(step: &PathStep, n: &[&[f64]; LANES], uniform: bool, b: &mut Block) {
    let o = step.offset;
    let q = L3 { x: b.p.x - o.x, y: b.p.y - o.y, z: b.p.z - o.z };
    let p = rotate(&step.rotation, q);
    let d = rotate(&step.rotation, b.d);
    let s = step.surface;
    let z_axis = L3::splat(DVec3::Z);
    let (hit, point, normal) = match &step.shape {
        SurfaceShape::Plane | SurfaceShape::Paraxial { .. } => {
            let (hit, _, point) = plane(p, d);
            (hit, point, z_axis)
        }
        SurfaceShape::Conic { curvature, conic } => {
            let (c, k) = (*curvature, *conic);
            if c == 0.0 {
                let (hit, _, point) = plane(p, d);
                (hit, point, z_axis)
            } else {
                let (hit, t) = conic_root(c, k, p, d, b.alive);
                let point = p.along(d, t);
                let ck = c * (1.0 + k);
                let normal = L3 { x: -c * point.x, y: -c * point.y, z: 1.0 - ck * point.z }.normalize();
                (hit, point, normal)
            }
        }
        SurfaceShape::EvenAsphere { curvature, conic, coefficients } => {
            let (c, k) = (*curvature, *conic);
            let (plane_ok, plane_t, _) = plane(p, d);
            let (conic_ok, conic_t) = if c == 0.0 { (Lm::splat(false), Lf::splat(0.0)) } else { conic_root(c, k, p, d, b.alive) };
            let first = b.alive & conic_ok;
            let (mut ok, mut nc, mut t) = (Lm::splat(false), Lm::splat(false), Lf::splat(0.0));
            if first.any() {
                (ok, nc, t) = asphere_newton(c, k, coefficients, p, d, first, conic_t);
            }
            let second = b.alive & !ok & plane_ok;
            if second.any() {
                let (ok2, nc2, t2) = asphere_newton(c, k, coefficients, p, d, second, plane_t);
                ok = (ok & !second) | ok2;
                nc = (nc & !second) | nc2;
                t = Lf::select(second, t2, t);
            }
            let point = p.along(d, t);
            let (_, slope) = sag_and_slope(c, k, coefficients, point.x, point.y);
            let normal = L3 { x: -(2.0 * point.x * slope), y: -(2.0 * point.y * slope), z: Lf::splat(1.0) }.normalize();
            b.kill(nc & !ok, RayStatus::NoConvergence, s);
            (ok & normal.is_finite(), point, normal)
        }
    };
    b.kill(!hit, RayStatus::Missed, s);
    let inside = match step.aperture {
        Aperture::None => Lm::splat(true),
        Aperture::Circular { semi_diameter_mm, min_radius_mm, decenter_x_mm, decenter_y_mm } => {
            let (u, v) = (point.x - decenter_x_mm, point.y - decenter_y_mm);
            let r2 = u * u + v * v;
            r2.le(Lf::splat(semi_diameter_mm * semi_diameter_mm)) & r2.ge(Lf::splat(min_radius_mm * min_radius_mm))
        }
        Aperture::Rectangular { half_width_x_mm, half_width_y_mm, decenter_x_mm, decenter_y_mm } => {
            (point.x - decenter_x_mm).abs().le(Lf::splat(half_width_x_mm)) & (point.y - decenter_y_mm).abs().le(Lf::splat(half_width_y_mm))
        }
    };
    b.kill(!inside, RayStatus::Vignetted, s);
    // n₁/n₂ per lane; one scalar division when every lane has the same table (the same bits).
    let (n1, n2, mu) = if uniform {
        let (a, c) = (n[0][s - 1], n[0][s]);
        (Lf::splat(a), Lf::splat(c), Lf::splat(a / c))
    } else {
        let (mut a, mut c) = ([0.0; LANES], [0.0; LANES]);
        for k in 0..LANES {
            a[k] = n[k][s - 1];
            c[k] = n[k][s];
        }
        (Lf(a), Lf(c), Lf(a) / Lf(c))
    };
    let d_new = match step.shape {
        SurfaceShape::Paraxial { focal_length } => {
            // Ideal thin lens (kernel::paraxial_deflect): tan′ = (n₁/n₂)·tan − h/f.
            let tx = mu * d.x / d.z - point.x / focal_length;
            let ty = mu * d.y / d.z - point.y / focal_length;
            let v = L3 { x: tx, y: ty, z: Lf::splat(1.0) }.normalize();
            let back = d.z.lt(Lf::splat(0.0));
            L3::select(back, L3 { x: -v.x, y: -v.y, z: -v.z }, v)
        }
        _ => {
            // Vector Snell's law (kernel::refract) where the index changes.
            let differ = n1.ne(n2);
            let cos0 = d.dot(normal);
            let flip = cos0.lt(Lf::splat(0.0));
            let nrm = L3::select(flip, L3 { x: -normal.x, y: -normal.y, z: -normal.z }, normal);
            let cos_i = Lf::select(flip, -cos0, cos0);
            let k = 1.0 - mu * mu * (1.0 - cos_i * cos_i);
            b.kill(differ & k.lt(Lf::splat(0.0)), RayStatus::TotalInternalReflection, s);
            let g = k.sqrt() - mu * cos_i;
            let r = L3 { x: mu * d.x + g * nrm.x, y: mu * d.y + g * nrm.y, z: mu * d.z + g * nrm.z };
            L3::select(differ, r, d)
        }
    };
    b.p = point;
    b.d = d_new;
}
