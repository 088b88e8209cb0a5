//! The forward-mode per-ray kernel: the plain f64 trace ([`crate::tracer::kernel`]: same intersections,
//! same refraction, so the values are bit-identical to [`crate::tracer::AnalyticTracer`]) carrying, per
//! free parameter k, the tangents (δp_k, δd_k) of the ray.
//!
//! Per step: frame change p′ = R(p − o), d′ = R d ⇒ δp′ = δR(p − o) + R(δp − δo), δd′ = δR d + R δd;
//! hit ([`super::hit`], implicit differentiation); then the tangent of vector Snell's law
//! d′ = μ d + (√κ − μ cos θᵢ) n̂, κ = 1 − μ²(1 − cos²θᵢ), μ = n₁/n₂:
//! δd′ = δμ d + μ δd + (δ√κ − δμ cos θᵢ − μ δcos θᵢ) n̂ + (√κ − μ cos θᵢ) δn̂,
//! δcos θᵢ = δd·n̂ + d·δn̂, δκ = −2μ δμ (1 − cos²θᵢ) + 2μ² cos θᵢ δcos θᵢ — or of the ideal lens
//! tan′ = μ tan − h/f (Zemax Paraxial surface); of a mirror d′ = d − 2(d·n̂)n̂:
//! δd′ = δd − 2((δd·n̂ + d·δn̂) n̂ + (d·n̂) δn̂); or of a grating order ([`crate::surfaces::grating`]):
//! v = n₁d − s g K, v_t = v − (v·ν)ν, a = ±√(n₂² − |v_t|²), d′ = (v_t + a ν)/n₂ with ν the normal along d,
//! K = normalise(ŷ − n̂_y n̂) and g = mλT, each of them differentiated (δK from δn̂, δg = mTδλ).
use super::hit::{ShapeTangent, SurfaceLocal};
use crate::surfaces::{intersect, IntersectFailure, SurfaceShape};
use crate::surfaces::grating::diffract;
use crate::system::{Interaction, PathStep};
use crate::tracer::kernel::{paraxial_deflect, reflect, refract, GRAZING_COS};
use crate::tracer::RayStatus;
use glam::{DMat3, DVec3};

/// Tangents of one path step with respect to each free parameter.
#[derive(Clone, Debug, Default)]
pub struct StepTangent {
    pub rotation: Vec<DMat3>,
    pub offset: Vec<DVec3>,
    pub shape: Vec<ShapeTangent>,
    /// Parameters whose rotation or offset tangent is non-zero.
    pub frame_active: Vec<usize>,
}

impl StepTangent {
    pub fn zero(k: usize) -> Self {
        StepTangent { rotation: vec![DMat3::ZERO; k], offset: vec![DVec3::ZERO; k], shape: vec![ShapeTangent::default(); k], frame_active: vec![] }
    }
}

/// The surface normal turned to face along the direction `d` (as vector Snell's law in `refract` uses it):
/// (n·sgn, |d·n|, sgn) with sgn = ±1. Shared by the forward tangents and the reverse sweep (`adjoint`).
pub(crate) fn oriented_normal(d: DVec3, normal: DVec3) -> (DVec3, f64, f64) {
    let cos_i = d.dot(normal);
    if cos_i < 0.0 {
        (-normal, -cos_i, -1.0)
    } else {
        (normal, cos_i, 1.0)
    }
}

/// Into `step`'s frame (p ← R(p − o), d ← R d) with the tangents: dp ← R dp + dR (p − o) − R do,
/// dd ← R dd + dR d for the parameters that move the frame.
pub(crate) fn enter_frame(step: &PathStep, tan: &StepTangent, p: DVec3, d: DVec3, dp: &mut [DVec3], dd: &mut [DVec3]) -> (DVec3, DVec3) {
    let pr = p - step.offset;
    for k in 0..dp.len() {
        dp[k] = step.rotation * dp[k];
        dd[k] = step.rotation * dd[k];
    }
    for &k in &tan.frame_active {
        dp[k] += tan.rotation[k] * pr - step.rotation * tan.offset[k];
        dd[k] += tan.rotation[k] * d;
    }
    (step.rotation * pr, step.rotation * d)
}

/// Trace (p, d) along `path` like [`crate::tracer::kernel::trace_steps`], updating the tangents `dp`, `dd`
/// (one per parameter; seeded by the caller). `n[i]` is the index after surface i and
/// `dn[i * K + k]` its derivative with respect to parameter k.
#[allow(clippy::too_many_arguments)]
pub(crate) fn trace_tangents(
    path: &[PathStep],
    tangents: &[StepTangent],
    n: &[f64],
    dn: &[f64],
    mut p: DVec3,
    mut d: DVec3,
    dp: &mut [DVec3],
    dd: &mut [DVec3],
) -> Result<(DVec3, DVec3), (RayStatus, usize)> {
    for (step, tan) in path.iter().zip(tangents) {
        (p, d) = enter_frame(step, tan, p, d, dp, dd);
        let hit = match intersect(&step.shape, p, d) {
            Ok(h) => h,
            Err(IntersectFailure::Missed) => return Err((RayStatus::Missed, step.surface)),
            Err(IntersectFailure::NoConvergence) => return Err((RayStatus::NoConvergence, step.surface)),
        };
        let t = hit.t;
        let q = hit.point;
        if !step.aperture.contains(q.x, q.y) {
            return Err((RayStatus::Vignetted, step.surface));
        }
        let local = SurfaceLocal::at(&step.shape, q);
        d = interact_tangents(step, tan, &local, q, hit.normal, t, d, n, dn, dp, dd).map_err(|status| (status, step.surface))?;
        p = q;
    }
    Ok((p, d))
}

/// The interaction at a hit of path step `step` with the tangents: the hit tangent (implicit
/// differentiation, [`SurfaceLocal::tangent`] with the ray tangent δp + t·δd at the hit, `t` the distance
/// from the point the tangents `dp` refer to), then vector Snell's law or the ideal lens differentiated.
/// `q` is the hit point and `normal` the unit surface normal there (local frame), `d` the incoming unit
/// direction. Updates `dp` (→ δq) and `dd` (→ δd′) and returns d′, or TIR.
#[allow(clippy::too_many_arguments)]
#[inline]
pub(crate) fn interact_tangents(
    step: &PathStep,
    tan: &StepTangent,
    local: &SurfaceLocal,
    q: DVec3,
    normal: DVec3,
    t: f64,
    d: DVec3,
    n: &[f64],
    dn: &[f64],
    dp: &mut [DVec3],
    dd: &mut [DVec3],
) -> Result<DVec3, RayStatus> {
    let kk = dp.len();
    let (n1, n2) = (n[step.surface - 1], n[step.surface]);
    let mu = n1 / n2;
    let dn1 = &dn[(step.surface - 1) * kk..step.surface * kk];
    let dn2 = &dn[step.surface * kk..(step.surface + 1) * kk];
    match step.interaction {
        Interaction::Refract => {}
        Interaction::Reflect => {
            let c = d.dot(normal);
            if c.abs() <= GRAZING_COS {
                return Err(RayStatus::Missed);
            }
            let d_out = reflect(d, normal);
            for k in 0..kk {
                let ht = local.tangent(d, dp[k] + dd[k] * t, &tan.shape[k]);
                let dc = dd[k].dot(normal) + d.dot(ht.normal);
                dd[k] = dd[k] - (normal * dc + ht.normal * c) * 2.0;
                dp[k] = ht.point;
            }
            return Ok(d_out);
        }
        Interaction::Grating { grating, reflective, wavelength_slot } => {
            if reflective && d.dot(normal).abs() <= GRAZING_COS {
                return Err(RayStatus::Missed);
            }
            let g = grating.kick(n[wavelength_slot]);
            let d_out = diffract(d, normal, n1, n2, g, reflective).ok_or(RayStatus::Evanescent)?;
            let dl = &dn[wavelength_slot * kk..(wavelength_slot + 1) * kk];
            let (nrm, _, sgn) = oriented_normal(d, normal);
            let (kv, inv_len) = crate::surfaces::grating::across_lines(normal);
            let s = if reflective { -1.0 } else { 1.0 };
            let v = d * n1 - kv * (s * g);
            let vn = v.dot(nrm);
            let vt = v - nrm * vn;
            let a = (d_out * n2 - vt).dot(nrm); // ±√(n₂² − |v_t|²), as `diffract` chose it
            for k in 0..kk {
                let ht = local.tangent(d, dp[k] + dd[k] * t, &tan.shape[k]);
                let dnrm = ht.normal * sgn;
                let dk_raw = -(normal * ht.normal.y + ht.normal * normal.y);
                let dkv = (dk_raw - kv * kv.dot(dk_raw)) * inv_len;
                let dg = grating.kick(dl[k]);
                let dv = d * dn1[k] + dd[k] * n1 - (kv * dg + dkv * g) * s;
                let dvn = dv.dot(nrm) + v.dot(dnrm);
                let dvt = dv - nrm * dvn - dnrm * vn;
                let dq = 2.0 * n2 * dn2[k] - 2.0 * vt.dot(dvt);
                let da = dq / (2.0 * a);
                dd[k] = (dvt + nrm * da + dnrm * a) / n2 - d_out * (dn2[k] / n2);
                dp[k] = ht.point;
            }
            return Ok(d_out);
        }
    }
    match step.shape {
        SurfaceShape::Paraxial { focal_length: f } => {
            let d_out = paraxial_deflect(q, d, f, n1, n2);
            let tx = mu * d.x / d.z - q.x / f;
            let ty = mu * d.y / d.z - q.y / f;
            let w = DVec3::new(tx, ty, 1.0);
            let (wl, v) = (w.length(), w.normalize());
            let sign = if d.z < 0.0 { -1.0 } else { 1.0 };
            for k in 0..kk {
                let ht = local.tangent(d, dp[k] + dd[k] * t, &tan.shape[k]);
                let dq = ht.point;
                let dmu = (dn1[k] - mu * dn2[k]) / n2;
                let df = tan.shape[k].focal_length;
                let ddk = dd[k];
                let dtx = dmu * d.x / d.z + mu * (ddk.x * d.z - d.x * ddk.z) / (d.z * d.z) - dq.x / f + q.x * df / (f * f);
                let dty = dmu * d.y / d.z + mu * (ddk.y * d.z - d.y * ddk.z) / (d.z * d.z) - dq.y / f + q.y * df / (f * f);
                let dw = DVec3::new(dtx, dty, 0.0);
                dd[k] = (dw - v * v.dot(dw)) * (sign / wl);
                dp[k] = dq;
            }
            Ok(d_out)
        }
        _ => {
            // Vector Snell's law with the normal oriented along d (as in `refract`).
            let (nrm, cos_i, sgn) = oriented_normal(d, normal);
            let kappa = 1.0 - mu * mu * (1.0 - cos_i * cos_i);
            let d_out = if n1 != n2 {
                match refract(d, normal, n1, n2) {
                    Some(r) => r,
                    None => return Err(RayStatus::TotalInternalReflection),
                }
            } else {
                d
            };
            let sk = kappa.max(0.0).sqrt();
            for k in 0..kk {
                let ht = local.tangent(d, dp[k] + dd[k] * t, &tan.shape[k]);
                let dnrm = ht.normal * sgn;
                let dmu = (dn1[k] - mu * dn2[k]) / n2;
                let ddk = dd[k];
                let dcos = ddk.dot(nrm) + d.dot(dnrm);
                let dkappa = -2.0 * mu * dmu * (1.0 - cos_i * cos_i) + 2.0 * mu * mu * cos_i * dcos;
                let dsk = dkappa / (2.0 * sk);
                dd[k] = d * dmu + ddk * mu + nrm * (dsk - dmu * cos_i - mu * dcos) + dnrm * (sk - mu * cos_i);
                dp[k] = ht.point;
            }
            Ok(d_out)
        }
    }
}
