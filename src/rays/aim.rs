use crate::error::{Error, Result};
use crate::spec::RayAiming;
use crate::system::SequentialSystem;
use crate::tracer::kernel::trace_steps;
use glam::DVec3;

/// The object-space ray of field point `field_mm` (object height x, y) through normalised pupil
/// coordinates (px, py), with ray aiming off, as (origin, unit direction) in the object surface's frame.
///
/// Zemax convention with ray aiming off: (px, py) is a point of the paraxial entrance pupil, scaled by its
/// radius and oriented like the stop (the pupil point is `sign(m_p)·(px, py)·r`, m_p the paraxial pupil
/// magnification); the ray is the line from the object point through it, travelling toward +z (for a pupil
/// behind the object the ray leaves the object *away* from the pupil point). Verified against Zemax: the
/// on-axis SP spot export (real inverted pupil 633 mm behind the object) matches ray for ray to 0.13 µm. In telecentric object space
/// (pupil at infinity), (px, py) scale the direction sines by sin θ_marginal around +z.
pub fn object_ray(system: &SequentialSystem, field_mm: [f64; 2], px: f64, py: f64) -> (DVec3, DVec3) {
    let origin = DVec3::new(field_mm[0], field_mm[1], 0.0);
    let r = pupil_scale(system);
    (origin, direction_through_pupil(system, origin, px * r, py * r))
}

/// Pupil-plane units per normalised pupil coordinate: the entrance-pupil radius, or 1 in telecentric object
/// space (where the pupil is at infinity and (px, py) scale direction sines instead).
fn pupil_scale(system: &SequentialSystem) -> f64 {
    if system.pupil.is_telecentric() {
        1.0
    } else {
        system.pupil.radius_mm
    }
}

/// Direction from `origin` through the point (u, v) of the paraxial entrance-pupil plane (or, for a
/// telecentric object space, with direction sines (u, v)·sin θ / radius).
fn direction_through_pupil(system: &SequentialSystem, origin: DVec3, u: f64, v: f64) -> DVec3 {
    let pupil = &system.pupil;
    if pupil.is_telecentric() {
        let s = pupil.sin_marginal; // (u, v) are normalised pupil coordinates here (scale 1)
        let (sx, sy) = (u * s, v * s);
        let z = (1.0 - sx * sx - sy * sy).max(0.0).sqrt();
        return DVec3::new(sx, sy, z);
    }
    // Pupil coordinates are oriented as at the stop: the entrance-pupil point is the paraxial image of the
    // stop point, so it carries the sign of the pupil magnification (SP: real inverted pupil, m_p < 0).
    let m = pupil.magnification_sign;
    let target = DVec3::new(m * u, m * v, pupil.distance_mm);
    let w = target - origin;
    // A pupil behind the object (distance < 0) is virtual: the ray travels away from it, toward +z.
    (if pupil.distance_mm < 0.0 { -w } else { w }).normalize()
}

/// Where a ray from the object (object frame, `n` the indices at its wavelength) crosses the stop surface,
/// in the stop's local (x, y) mm; `None` when it does not get there.
pub fn stop_crossing(system: &SequentialSystem, n: &[f64], origin: DVec3, d: DVec3) -> Option<(f64, f64)> {
    let probe = &system.stop_probe;
    let (p, d) = trace_steps(&system.path[..probe.steps], n, origin, d).ok()?;
    let step = &probe.probe;
    let (p, d) = (step.rotation * (p - step.offset), step.rotation * d);
    let hit = crate::surfaces::intersect(&step.shape, p, d).ok()?;
    Some((hit.point.x, hit.point.y))
}

/// The object-space ray for (field, px, py) at `wavelength_nm` under the system's ray-aiming mode.
///
/// With [`RayAiming::Real`] the ray is aimed (Newton iteration, finite-difference Jacobian) so that it
/// crosses the real stop surface at (px, py) × the paraxial stop radius from the stop's vertex, at its own
/// wavelength — Zemax's ray aiming (the chief ray passes through the centre of the stop). `n` are the indices at `wavelength_nm` ([`SequentialSystem::indices`]).
pub fn aimed_ray(system: &SequentialSystem, n: &[f64], field_mm: [f64; 2], px: f64, py: f64) -> Result<(DVec3, DVec3)> {
    if system.spec.ray_aiming == RayAiming::Off {
        return Ok(object_ray(system, field_mm, px, py));
    }
    let origin = DVec3::new(field_mm[0], field_mm[1], 0.0);
    let r_ep = pupil_scale(system);
    let (mut u, mut v) = (px * r_ep, py * r_ep);
    let r_stop = system.pupil.stop_radius_mm;
    let (tx, ty) = (px * r_stop, py * r_stop);
    let fail = |why: &str| Error::invalid(format!("ray aiming failed for field ({}, {}) mm, pupil ({px}, {py}): {why}", field_mm[0], field_mm[1]));
    let eval = |u: f64, v: f64| stop_crossing(system, n, origin, direction_through_pupil(system, origin, u, v));
    let h = 1e-7 * r_ep.max(1.0);
    for _ in 0..30 {
        let (x, y) = eval(u, v).ok_or_else(|| fail("the ray does not reach the stop"))?;
        let (ex, ey) = (x - tx, y - ty);
        if ex.abs() < 1e-13 * (1.0 + r_stop) && ey.abs() < 1e-13 * (1.0 + r_stop) {
            return Ok((origin, direction_through_pupil(system, origin, u, v)));
        }
        let (xu, yu) = eval(u + h, v).ok_or_else(|| fail("the ray does not reach the stop"))?;
        let (xv, yv) = eval(u, v + h).ok_or_else(|| fail("the ray does not reach the stop"))?;
        let (a, c) = ((xu - x) / h, (yu - y) / h);
        let (b, d) = ((xv - x) / h, (yv - y) / h);
        let det = a * d - b * c;
        if !(det.abs() > 0.0) || !det.is_finite() {
            return Err(fail("singular aiming Jacobian"));
        }
        let du = (d * ex - b * ey) / det;
        let dv = (-c * ex + a * ey) / det;
        u -= du;
        v -= dv;
        if du.abs() < 1e-14 * (1.0 + r_ep) && dv.abs() < 1e-14 * (1.0 + r_ep) {
            return Ok((origin, direction_through_pupil(system, origin, u, v)));
        }
    }
    Err(fail("no convergence in 30 Newton steps"))
}
