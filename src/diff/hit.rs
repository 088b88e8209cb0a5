//! Implicit differentiation at a ray–surface hit: the derivative of the hit point and of the surface
//! normal from the converged hit alone (point, direction, surface), never through the solver's iterations.
//!
//! A surface is F(q; θ) = z − sag(x, y; θ) = 0. A ray point q = p + t·d hits it when F(q) = 0; for a change
//! of the ray (δp, δd) and of the surface parameters (δθ), the implicit function theorem gives
//!
//! δt = −(∂F/∂θ·δθ + ∇F·(δp + t δd)) / (∇F·d),   δq = δp + t δd + δt d,
//!
//! and the unit normal n = m/|m| with m = (−∂sag/∂x, −∂sag/∂y, 1) moves by δn = (δm − n(n·δm))/|m|, where
//! δm = −(H·δq_xy + ∂(∇sag)/∂θ·δθ), H the Hessian of the sag. Because only (q, d, surface) enter, the
//! same function serves any backend: the analytic intersector here, or a mesh (Embree) hit refined onto
//! the exact surface.
//!
//! ```
//! use diffcassi::diff::hit::{hit_tangent, ShapeTangent};
//! use diffcassi::surfaces::{intersect, SurfaceShape};
//! use glam::DVec3;
//! let s = SurfaceShape::Conic { curvature: 0.02, conic: 0.0 };
//! let (p, d) = (DVec3::new(1.0, 2.0, -5.0), DVec3::Z);
//! let hit = intersect(&s, p, d).unwrap();
//! // Move the ray sideways by δp = x̂: the hit slides along the surface.
//! let t = hit_tangent(&s, hit.point, d, DVec3::X, &ShapeTangent::default());
//! let h = 1e-6;
//! let fd = (intersect(&s, p + DVec3::X * h, d).unwrap().point - intersect(&s, p - DVec3::X * h, d).unwrap().point) / (2.0 * h);
//! assert!((t.point - fd).length() < 1e-8);
//! ```
use crate::surfaces::SurfaceShape;
use glam::DVec3;

/// A change of a surface's figure parameters (per unit of one free parameter).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ShapeTangent {
    /// δc (mm⁻¹).
    pub curvature: f64,
    /// δk.
    pub conic: f64,
    /// δα₁..δα₈ (coefficients of r², r⁴, …).
    pub asphere: [f64; 8],
    /// δf of a Paraxial surface (mm).
    pub focal_length: f64,
}

impl ShapeTangent {
    pub fn is_zero(&self) -> bool {
        self.curvature == 0.0 && self.conic == 0.0 && self.focal_length == 0.0 && self.asphere.iter().all(|a| *a == 0.0)
    }
    /// Whether the tangent moves the sag (curvature, conic or an asphere term; not a paraxial focal length).
    pub(crate) fn moves_figure(&self) -> bool {
        self.curvature != 0.0 || self.conic != 0.0 || self.asphere.iter().any(|a| *a != 0.0)
    }
}

/// The derivative of a hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HitTangent {
    /// δq.
    pub point: DVec3,
    /// δt (the distance along the unit direction).
    pub t: f64,
    /// δn of the unit normal (oriented toward local +z, like [`crate::surfaces::Hit::normal`]).
    pub normal: DVec3,
}

/// (c, k, α) of a figure; a plane is c = k = 0 (so a free curvature of a flat surface works).
pub(crate) fn figure(shape: &SurfaceShape) -> Option<(f64, f64, &[f64])> {
    match shape {
        SurfaceShape::Plane => Some((0.0, 0.0, &[])),
        SurfaceShape::Conic { curvature, conic } => Some((*curvature, *conic, &[])),
        SurfaceShape::EvenAsphere { curvature, conic, coefficients } => Some((*curvature, *conic, coefficients.as_slice())),
        SurfaceShape::Paraxial { .. } | SurfaceShape::Toroidal { .. } => None,
    }
}

/// The sag f(r²) at a hit point (x, y), r2 = x² + y²: f′, f″ and the figure (c, k, s = √(1 − (1+k)c²r2))
/// that [`SurfaceLocal`] (forward tangents) and [`SweepLocal`] (the reverse sweep) share.
#[derive(Clone, Copy, Debug)]
struct SagLocal {
    /// f′(r²), f″(r²) (sag = f(r²)).
    f1: f64,
    f2: f64,
    x: f64,
    y: f64,
    r2: f64,
    c: f64,
    k: f64,
    s: f64,
}

impl SagLocal {
    /// (∂sag/∂θ, ∂(sag_x)/∂θ, ∂(sag_y)/∂θ) along a shape tangent ([`figure_partials`]).
    #[inline]
    fn partials(&self, t: &ShapeTangent) -> (f64, f64, f64) {
        figure_partials(self.c, self.k, self.s, self.r2, self.x, self.y, t)
    }

    /// The sag's Hessian H = 2f′ I + 4f″ (x, y)(x, y)ᵀ as (H_xx, H_xy, H_yy).
    #[inline]
    fn hessian(&self) -> (f64, f64, f64) {
        let (x, y) = (self.x, self.y);
        (2.0 * self.f1 + 4.0 * self.f2 * x * x, 4.0 * self.f2 * x * y, 2.0 * self.f1 + 4.0 * self.f2 * y * y)
    }
}

/// Sag as f(r²): the local first- and second-order data needed at a hit.
#[derive(Clone, Copy, Debug)]
pub struct SurfaceLocal {
    sag: SagLocal,
    /// The Hessian (H_xx, H_xy, H_yy) of a figure that is not a function of r² (a Toroidal surface,
    /// [`crate::surfaces::toroidal`]); `None` for the rotationally symmetric figures.
    general_hessian: Option<(f64, f64, f64)>,
    /// m = (−sx, −sy, 1) and |m|.
    pub m: DVec3,
    pub m_len: f64,
    pub normal: DVec3,
}

impl SurfaceLocal {
    /// Local data of `shape` at the hit point `q`.
    pub fn at(shape: &SurfaceShape, q: DVec3) -> SurfaceLocal {
        let (x, y) = (q.x, q.y);
        if let SurfaceShape::Toroidal { curvature, conic, coefficients, rotation_curvature } = shape {
            // Its figure parameters are not free parameters (diff::param refuses them): only the hit's
            // motion along the surface (gradient and Hessian) enters.
            let t = crate::surfaces::toroidal::toroid_local(*curvature, *conic, coefficients, *rotation_curvature, x, y);
            let m = DVec3::new(-t.grad.0, -t.grad.1, 1.0);
            let m_len = m.length();
            let sag = SagLocal { f1: 0.0, f2: 0.0, x, y, r2: x * x + y * y, c: 0.0, k: 0.0, s: 1.0 };
            return SurfaceLocal { sag, general_hessian: Some(t.hessian), m, m_len, normal: m / m_len };
        }
        let r2 = x * x + y * y;
        let (mut f1, mut f2, mut c, mut k, mut s) = (0.0, 0.0, 0.0, 0.0, 1.0);
        if let Some((cc, kk, alpha)) = figure(shape) {
            (c, k) = (cc, kk);
            (f1, f2, s) = sag_derivatives(c, k, alpha, r2);
        }
        let m = DVec3::new(-2.0 * f1 * x, -2.0 * f1 * y, 1.0);
        let m_len = m.length();
        SurfaceLocal { sag: SagLocal { f1, f2, x, y, r2, c, k, s }, general_hessian: None, m, m_len, normal: m / m_len }
    }

    /// (∂sag/∂θ, ∂(sag_x)/∂θ, ∂(sag_y)/∂θ) along a shape tangent.
    pub(crate) fn param_partials(&self, t: &ShapeTangent) -> (f64, f64, f64) {
        self.sag.partials(t)
    }

    /// The hit tangent for a ray through the hit with unit direction `d`, where `dray` = δp + t·δd is the
    /// tangent of the ray point at fixed t, and `dshape` the change of the figure.
    #[inline]
    pub fn tangent(&self, d: DVec3, dray: DVec3, dshape: &ShapeTangent) -> HitTangent {
        let (dsag, dsx, dsy) = self.param_partials(dshape);
        // ∇F = m (F = z − sag); ∂F/∂θ = −∂sag/∂θ.
        let dt = -(-dsag + self.m.dot(dray)) / self.m.dot(d);
        let dq = dray + d * dt;
        let (hxx, hxy, hyy) = self.general_hessian.unwrap_or_else(|| self.sag.hessian());
        let dm = DVec3::new(-(hxx * dq.x + hxy * dq.y + dsx), -(hxy * dq.x + hyy * dq.y + dsy), 0.0);
        let dn = (dm - self.normal * self.normal.dot(dm)) / self.m_len;
        HitTangent { point: dq, t: dt, normal: dn }
    }
}

/// The radial derivatives of the sag f(r2) of the figure (c, k, α) at r2 = x² + y², with s = √(1 − (1+k)c²r2):
/// (f′ = df/d(r2), f″ = d²f/d(r2)², s) — the conic's c/(2s), (1+k)c³/(4s³) plus the even asphere's
/// Σ αᵢ r^(2i): P′ = Σ i αᵢ r2^(i−1), P″ = Σ i(i−1) αᵢ r2^(i−2).
#[inline]
fn sag_derivatives(c: f64, k: f64, alpha: &[f64], r2: f64) -> (f64, f64, f64) {
    let (mut f1, mut f2) = (0.0, 0.0);
    let s = (1.0 - (1.0 + k) * c * c * r2).max(0.0).sqrt();
    if c != 0.0 {
        f1 = c / (2.0 * s);
        f2 = (1.0 + k) * c * c * c / (4.0 * s * s * s);
    }
    for (j, a) in alpha.iter().enumerate() {
        let i = (j + 1) as f64;
        f1 += i * a * r2.powi(j as i32);
        if j >= 1 {
            f2 += i * (i - 1.0) * a * r2.powi(j as i32 - 1);
        }
    }
    (f1, f2, s)
}

/// (∂sag/∂θ, ∂(sag_x)/∂θ, ∂(sag_y)/∂θ) along a shape tangent at a point (x, y), r2 = x² + y², of the figure
/// (c, k, α) with s = √(1 − (1+k)c²r2) (the conic part; the α terms enter through the tangent's asphere).
#[inline]
pub(crate) fn figure_partials(c: f64, k: f64, s: f64, r2: f64, x: f64, y: f64, t: &ShapeTangent) -> (f64, f64, f64) {
    if !t.moves_figure() {
        return (0.0, 0.0, 0.0);
    }
    // Conic sag f = c r2/(1+s), s = √(1 − (1+k)c²r2):
    // f_c = r2/(1+s) + (1+k)c²r2²/(s(1+s)²),  f_k = c³r2²/(2s(1+s)²),
    // f′_c = 1/(2s) + (1+k)c²r2/(2s³),          f′_k = c³r2/(4s³).
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
            df += a * r2.powi(j as i32 + 1);
            df1 += a * i * r2.powi(j as i32);
        }
    }
    (df, 2.0 * df1 * x, 2.0 * df1 * y)
}

/// The sag's local data at a **traced** hit, for the reverse sweep ([`super::adjoint`], and lane by lane
/// [`super::adjoint_lanes`]): built from the hit point and the unit normal the trace computed there
/// (`intersect`'s, recorded on the tape), so that the sweep does not recompute the normal and |m|:
/// m = (−sx, −sy, 1) gives 1/|m| = n̂_z and m = n̂/n̂_z. The Hessian H = 2f′ I + 4f″ (x, y)(x, y)ᵀ needs f′, f″:
/// - a flat figure (a plane, a paraxial lens, a conic of zero curvature without asphere terms) has
///   f′ = f″ = 0 and H = 0;
/// - a conic (c ≠ 0, no asphere terms): on its vertex branch 1 − c(1+k)z = s = √(1 − (1+k)c²r²)
///   (z = c r²/(1+s)), the trace's unnormalised normal's z, so s costs a multiply and f′ = c/(2s),
///   f″ = (1+k)c³/(4s³) one division (1/s) — no square root;
/// - an even asphere: f′, f″ from the sag's series as [`SurfaceLocal::at`] (s by its square root).
///
/// The values equal [`SurfaceLocal`]'s to rounding (the same quantities, computed from the trace's
/// normal and the conic identity instead of the square roots), and the lane sweep repeats these
/// operations exactly: the two sweeps give the same bits.
#[derive(Clone, Copy, Debug)]
pub struct SweepLocal {
    sag: SagLocal,
    normal: DVec3,
    flat: bool,
    /// A Toroidal surface's Hessian (its figure is not a function of r²; [`SurfaceLocal`] keeps the same),
    /// `None` for the rotationally symmetric figures. Only the scalar sweep meets it: the lane sweep
    /// ([`super::adjoint_lanes`]) is not used for systems with Toroidal surfaces.
    general_hessian: Option<(f64, f64, f64)>,
}

impl SweepLocal {
    /// Local data of `shape` at the traced hit `q` with the trace's unit normal `normal`.
    #[inline]
    pub fn at(shape: &SurfaceShape, q: DVec3, normal: DVec3) -> SweepLocal {
        let (x, y) = (q.x, q.y);
        let r2 = x * x + y * y;
        if let SurfaceShape::Toroidal { curvature, conic, coefficients, rotation_curvature } = shape {
            // As [`SurfaceLocal::at`]: the hit's motion along the surface (its Hessian) only; its figure
            // parameters are not free parameters.
            let t = crate::surfaces::toroidal::toroid_local(*curvature, *conic, coefficients, *rotation_curvature, x, y);
            let sag = SagLocal { f1: 0.0, f2: 0.0, x, y, r2, c: 0.0, k: 0.0, s: 1.0 };
            return SweepLocal { sag, normal, flat: false, general_hessian: Some(t.hessian) };
        }
        let (c, k, alpha) = figure(shape).unwrap_or((0.0, 0.0, &[][..]));
        let (mut f1, mut f2, mut s) = (0.0, 0.0, 1.0);
        let flat = c == 0.0 && alpha.iter().all(|a| *a == 0.0);
        if !flat && alpha.is_empty() {
            // The trace's normal ∝ (−c x, −c y, 1 − c(1+k) z): its z is s on the vertex branch.
            s = 1.0 - c * (1.0 + k) * q.z;
            let inv_s = 1.0 / s;
            f1 = 0.5 * c * inv_s;
            f2 = 0.25 * (1.0 + k) * c * c * c * inv_s * inv_s * inv_s;
        } else if !flat {
            (f1, f2, s) = sag_derivatives(c, k, alpha, r2);
        }
        SweepLocal { sag: SagLocal { f1, f2, x, y, r2, c, k, s }, normal, flat, general_hessian: None }
    }

    /// (∂sag/∂θ, ∂(sag_x)/∂θ, ∂(sag_y)/∂θ) along a shape tangent ([`figure_partials`]).
    #[inline]
    pub fn param_partials(&self, t: &ShapeTangent) -> (f64, f64, f64) {
        self.sag.partials(t)
    }

    /// The transpose of [`SurfaceLocal::tangent`] (reverse mode): for adjoints `q_bar` of δq and `n_bar`
    /// of δn, the adjoint of `dray` and of the figure partials (∂sag/∂θ, ∂(sag_x)/∂θ, ∂(sag_y)/∂θ), so that
    /// q̄·δq + n̄·δn = draȳ·dray + Σ partialsB̄·partials for every (dray, dshape).
    #[inline]
    pub fn adjoint(&self, d: DVec3, q_bar: DVec3, n_bar: DVec3) -> (DVec3, [f64; 3]) {
        let n = self.normal;
        // δn = P δm / |m| with P = I − n nᵀ symmetric, 1/|m| = n_z; δm_z = 0.
        let w = n.z;
        let dm_bar = (n_bar - n * n.dot(n_bar)) * w;
        // δm_xy = −(H δq_xy + δs_xy): H symmetric (zero on a flat figure).
        let dq_bar = if self.flat {
            q_bar
        } else {
            let (hxx, hxy, hyy) = self.general_hessian.unwrap_or_else(|| self.sag.hessian());
            q_bar - DVec3::new(hxx * dm_bar.x + hxy * dm_bar.y, hxy * dm_bar.x + hyy * dm_bar.y, 0.0)
        };
        // δq = dray + d δt, δt = (δsag − m·dray)/(m·d), m = n/n_z: with r = (d·q̄′)/(n·d), δt̄ = r n_z
        // and dray gets −m δt̄ = −n r.
        let r = d.dot(dq_bar) / n.dot(d);
        (dq_bar - n * r, [r * w, -dm_bar.x, -dm_bar.y])
    }
}

/// Derivative of a hit from the hit point `hit`, the unit direction `d`, the ray's tangent at the hit for
/// fixed distance `dray` (= δp + t·δd for a ray p + t·d) and the change of the figure `dshape`.
/// A Paraxial surface is the plane z = 0 (its focal length does not move the hit).
pub fn hit_tangent(shape: &SurfaceShape, hit: DVec3, d: DVec3, dray: DVec3, dshape: &ShapeTangent) -> HitTangent {
    SurfaceLocal::at(shape, hit).tangent(d, dray, dshape)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::surfaces::intersect;

    fn fd_check(shape_of: impl Fn(f64) -> SurfaceShape, x0: f64, dshape: ShapeTangent, h: f64) {
        let p = DVec3::new(2.0, -1.5, -4.0);
        let d = DVec3::new(0.1, 0.05, 1.0).normalize();
        let s0 = shape_of(x0);
        let hit = intersect(&s0, p, d).unwrap();
        let t = hit_tangent(&s0, hit.point, d, DVec3::ZERO, &dshape);
        let hp = intersect(&shape_of(x0 + h), p, d).unwrap();
        let hm = intersect(&shape_of(x0 - h), p, d).unwrap();
        let fdp = (hp.point - hm.point) / (2.0 * h);
        let fdn = (hp.normal - hm.normal) / (2.0 * h);
        assert!((t.point - fdp).length() < 1e-6 * fdp.length().max(1e-3), "{:?} vs {:?}", t.point, fdp);
        assert!((t.normal - fdn).length() < 1e-6 * fdn.length().max(1e-3), "{:?} vs {:?}", t.normal, fdn);
    }

    #[test]
    fn figure_parameters_move_hits_like_finite_differences() {
        let ct = ShapeTangent { curvature: 1.0, ..Default::default() };
        fd_check(|c| SurfaceShape::Conic { curvature: c, conic: -0.7 }, 0.03, ct, 1e-7);
        let kt = ShapeTangent { conic: 1.0, ..Default::default() };
        fd_check(|k| SurfaceShape::Conic { curvature: 0.03, conic: k }, -0.7, kt, 1e-5);
        let mut at = ShapeTangent::default();
        at.asphere[1] = 1.0;
        fd_check(|a| SurfaceShape::EvenAsphere { curvature: 0.02, conic: 0.0, coefficients: vec![1e-3, a] }, 2e-5, at, 1e-8);
    }
}
