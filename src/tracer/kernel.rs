//! The f64 per-ray kernel shared by every analytic trace: frame change, exact intersection, aperture,
//! refraction (vector Snell's law) or ideal-lens deflection, reflection at a mirror (d′ = d − 2(d·n̂)n̂), or
//! diffraction into a grating order ([`crate::surfaces::grating`]).
//!
//! Mirrors follow OpticStudio's sequential convention: the surface's frame is not flipped; after a mirror the
//! ray travels toward local −z, so the next surface lies at a negative thickness, and radii keep their sign
//! in the global sense (rayoptics' `interact_mode = 'reflect'` likewise). A ray meeting a mirror at grazing
//! incidence (|d·n̂| ≤ 1e-12) is reported `missed`: it touches the surface without a defined reflection.
use super::RayStatus;
use crate::surfaces::grating::diffract;
use crate::surfaces::{intersect, IntersectFailure, SurfaceShape};
use crate::system::{Interaction, PathStep};
use glam::DVec3;

/// Refract unit `d` at unit normal `normal` from index `n1` into `n2` (vector Snell's law,
/// d′ = μ d + (√(1 − μ²(1 − cos²θᵢ)) − μ cos θᵢ) n̂ with n̂ oriented along d). `None` on total internal
/// reflection.
#[inline]
pub fn refract(d: DVec3, normal: DVec3, n1: f64, n2: f64) -> Option<DVec3> {
    let mut nrm = normal;
    let mut cos_i = d.dot(nrm);
    if cos_i < 0.0 {
        nrm = -nrm;
        cos_i = -cos_i;
    }
    let mu = n1 / n2;
    let k = 1.0 - mu * mu * (1.0 - cos_i * cos_i);
    if k < 0.0 {
        return None;
    }
    Some(mu * d + (k.sqrt() - mu * cos_i) * nrm)
}

/// Reflect unit `d` at unit normal `normal` (either orientation): d′ = d − 2(d·n̂)n̂.
#[inline]
pub fn reflect(d: DVec3, normal: DVec3) -> DVec3 {
    d - normal * (2.0 * d.dot(normal))
}

/// Below this |cos θᵢ| a mirror or grating hit is grazing and the ray is reported `missed`.
pub const GRAZING_COS: f64 = 1e-12;

/// The unit vector along a ray direction given with any finite, non-zero length, or `None` for a
/// non-finite or zero direction (an invalid input ray).
///
/// `d / |d|` alone fails at the extremes of f64: |d|² overflows to ∞ for components beyond ~1e154 (the
/// quotient is then 0) and underflows to 0 below ~1e-154 (the ray looks zero-length). Scaling by the
/// largest component first keeps |d/m| in [1, √3], so every finite non-zero direction is accepted.
/// Ordinary directions take the plain path, so their results are unchanged bit for bit.
#[inline]
pub fn unit_direction(d: DVec3) -> Option<DVec3> {
    if !d.is_finite() {
        return None;
    }
    let len2 = d.length_squared();
    if len2.is_finite() && len2 > 1e-300 {
        return Some(d / len2.sqrt());
    }
    let m = d.abs().max_element();
    if !(m > 0.0) {
        return None;
    }
    let s = d / m;
    Some(s / s.length())
}

/// Ideal thin lens in the local plane z = 0 at point `p`: direction tangents map as
/// tan′ = (n₁/n₂)·tan − h/f (Zemax's Paraxial surface; in air, tan′ = tan − h/f).
#[inline]
pub fn paraxial_deflect(p: DVec3, d: DVec3, focal_length: f64, n1: f64, n2: f64) -> DVec3 {
    let mu = n1 / n2;
    let tx = mu * d.x / d.z - p.x / focal_length;
    let ty = mu * d.y / d.z - p.y / focal_length;
    let v = DVec3::new(tx, ty, 1.0).normalize();
    if d.z < 0.0 {
        -v
    } else {
        v
    }
}

/// Like [`trace_steps`], also recording every hit point in its surface's local frame into `hits`.
pub(crate) fn trace_steps_recording(path: &[PathStep], n: &[f64], mut p: DVec3, mut d: DVec3, hits: &mut Vec<DVec3>) -> Result<(DVec3, DVec3), (RayStatus, usize)> {
    hits.clear();
    for step in path {
        let (q, e) = trace_steps(std::slice::from_ref(step), n, p, d)?;
        hits.push(q);
        p = q;
        d = e;
    }
    Ok((p, d))
}

/// Trace (p, d), given in the object surface's frame, along `path`. `n[i]` is the index after surface i.
/// Returns (p, d) in the frame of the last step, or the status and the surface where the ray stopped.
#[inline]
pub(crate) fn trace_steps(path: &[PathStep], n: &[f64], mut p: DVec3, mut d: DVec3) -> Result<(DVec3, DVec3), (RayStatus, usize)> {
    for step in path {
        (p, d) = trace_step(step, n, p, d)?;
    }
    Ok((p, d))
}

/// One step of [`trace_steps`]: into the step's frame, intersect, clip, refract. Exposed so that callers
/// can interleave several independent rays step by step (instruction-level parallelism) with exactly the
/// same arithmetic, hence bit-identical results.
#[inline(always)]
pub(crate) fn trace_step(step: &PathStep, n: &[f64], p: DVec3, d: DVec3) -> Result<(DVec3, DVec3), (RayStatus, usize)> {
    let p = step.rotation * (p - step.offset);
    let mut d = step.rotation * d;
    let hit = match intersect(&step.shape, p, d) {
        Ok(h) => h,
        Err(IntersectFailure::Missed) => return Err((RayStatus::Missed, step.surface)),
        Err(IntersectFailure::NoConvergence) => return Err((RayStatus::NoConvergence, step.surface)),
    };
    let p = hit.point;
    if !step.aperture.contains(p.x, p.y) {
        return Err((RayStatus::Vignetted, step.surface));
    }
    let (n1, n2) = (n[step.surface - 1], n[step.surface]);
    match step.interaction {
        Interaction::Refract => {}
        Interaction::Reflect => {
            if d.dot(hit.normal).abs() <= GRAZING_COS {
                return Err((RayStatus::Missed, step.surface));
            }
            return Ok((p, reflect(d, hit.normal)));
        }
        Interaction::Grating { grating, reflective, wavelength_slot } => {
            if reflective && d.dot(hit.normal).abs() <= GRAZING_COS {
                return Err((RayStatus::Missed, step.surface));
            }
            return match diffract(d, hit.normal, n1, n2, grating.kick(n[wavelength_slot]), reflective) {
                Some(r) => Ok((p, r)),
                None => Err((RayStatus::Evanescent, step.surface)),
            };
        }
    }
    match step.shape {
        SurfaceShape::Paraxial { focal_length } => d = paraxial_deflect(p, d, focal_length, n1, n2),
        _ if n1 != n2 => match refract(d, hit.normal, n1, n2) {
            Some(r) => d = r,
            None => return Err((RayStatus::TotalInternalReflection, step.surface)),
        },
        _ => {}
    }
    Ok((p, d))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn snell_law_holds() {
        let d = DVec3::new(0.5f64.sin(), 0.0, 0.5f64.cos());
        let r = refract(d, DVec3::Z, 1.0, 1.5).unwrap();
        assert!((r.length() - 1.0).abs() < 1e-15);
        assert!((0.5f64.sin() - 1.5 * r.x).abs() < 1e-15);
    }

    #[test]
    fn critical_angle_is_tir() {
        let crit = (1.0f64 / 1.5).asin();
        let above = DVec3::new((crit + 1e-9).sin(), 0.0, (crit + 1e-9).cos());
        let below = DVec3::new((crit - 1e-9).sin(), 0.0, (crit - 1e-9).cos());
        assert!(refract(above, DVec3::Z, 1.5, 1.0).is_none());
        let r = refract(below, DVec3::Z, 1.5, 1.0).unwrap();
        assert!(r.is_finite());
    }

    #[test]
    fn unit_direction_survives_overflow_and_underflow() {
        let d = DVec3::new(0.1, -0.05, 1.0);
        let u = unit_direction(d).unwrap();
        assert_eq!(u, d / d.length(), "ordinary directions take the plain path");
        for scale in [2f64.powi(1000), 2f64.powi(-1000), 1e-310] {
            let v = unit_direction(d * scale).unwrap();
            // 1e-310 is subnormal: its components keep only ~1e-12 relative precision.
            let tol = if scale < 1e-300 { 1e-10 } else { 1e-15 };
            assert!((v - u).length() < tol, "scale {scale:e}: {v:?}");
        }
        for bad in [DVec3::ZERO, DVec3::new(f64::NAN, 0.0, 1.0), DVec3::new(0.0, f64::INFINITY, 1.0)] {
            assert_eq!(unit_direction(bad), None);
        }
    }

    #[test]
    fn ideal_lens_focuses_parallel_rays() {
        let f = 50.0;
        let p = DVec3::new(3.0, -2.0, 0.0);
        let d = paraxial_deflect(p, DVec3::Z, f, 1.0, 1.0);
        let at_focus = p + d * (f / d.z);
        assert!(at_focus.x.abs() < 1e-13 && at_focus.y.abs() < 1e-13);
    }
}
