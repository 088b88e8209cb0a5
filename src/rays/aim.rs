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
///
/// Object at infinity (`system.object_at_infinity()`): `field_mm` holds the field angles (θx, θy) in
/// radians; every ray of the field has the direction (tan θx, tan θy, 1) normalised (OpticStudio's angle
/// convention) and passes through the entrance-pupil point; it starts where it crosses the object frame's
/// z = 0 plane, the plane of surface 1's vertex.
pub fn object_ray(system: &SequentialSystem, field_mm: [f64; 2], px: f64, py: f64) -> (DVec3, DVec3) {
    let aim = PupilAim::of(system);
    if aim.at_infinity {
        let r = aim.scale;
        return aim.parallel_ray(field_mm, px * r, py * r);
    }
    let origin = DVec3::new(field_mm[0], field_mm[1], 0.0);
    let r = pupil_scale(system);
    (origin, direction_through_pupil(system, origin, px * r, py * r))
}

/// Pupil-plane units per normalised pupil coordinate: the entrance-pupil radius, or 1 in telecentric object
/// space (where the pupil is at infinity and (px, py) scale direction sines instead).
fn pupil_scale(system: &SequentialSystem) -> f64 {
    PupilAim::of(system).scale
}

/// Direction from `origin` through the point (u, v) of the paraxial entrance-pupil plane (or, for a
/// telecentric object space, with direction sines (u, v)·sin θ / radius).
fn direction_through_pupil(system: &SequentialSystem, origin: DVec3, u: f64, v: f64) -> DVec3 {
    let d = PupilAim::of(system).through(origin.x, origin.y, origin.z, u, v);
    DVec3::new(d[0], d[1], d[2])
}

/// The entrance-pupil geometry [`object_ray`] aims through, copied out of the system so that a loop over
/// many rays computes their directions with plain arithmetic (and vectorises): the renderer's lane path
/// uses it and gets [`object_ray`]'s numbers bit for bit (one implementation, [`PupilAim::through`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PupilAim {
    telecentric: bool,
    /// The object is at infinity: fields are angles (rad) and rays of a field are parallel.
    pub at_infinity: bool,
    /// Pupil-plane units per normalised pupil coordinate (the pupil radius, or 1 when telecentric).
    pub scale: f64,
    sin_marginal: f64,
    magnification_sign: f64,
    distance_mm: f64,
}

impl PupilAim {
    pub fn of(system: &SequentialSystem) -> Self {
        let p = &system.pupil;
        let telecentric = p.is_telecentric();
        PupilAim {
            telecentric,
            at_infinity: p.object_at_infinity,
            scale: if telecentric { 1.0 } else { p.radius_mm },
            sin_marginal: p.sin_marginal,
            magnification_sign: p.magnification_sign,
            distance_mm: p.distance_mm,
        }
    }

    /// Object at infinity: the ray of field angles `theta` (rad) through the entrance-pupil plane point
    /// (u, v) (mm, oriented like the stop), as (origin on the z = 0 plane, unit direction ∝ (tan θx, tan θy, 1)).
    #[inline]
    pub fn parallel_ray(&self, theta: [f64; 2], u: f64, v: f64) -> (DVec3, DVec3) {
        let (tx, ty) = (theta[0].tan(), theta[1].tan());
        let m = self.magnification_sign;
        let z = self.distance_mm;
        let origin = DVec3::new(m * u - tx * z, m * v - ty * z, 0.0);
        let inv = 1.0 / (tx * tx + ty * ty + 1.0).sqrt();
        (origin, DVec3::new(tx * inv, ty * inv, inv))
    }

    /// The aim's constants for the GPU kernels (`dc_aim` of src/gpu/kernels/dc_sample.h): telecentric,
    /// scale, sin of the marginal angle, pupil magnification sign, pupil distance (mm).
    pub(crate) fn parts(&self) -> (bool, f64, f64, f64, f64) {
        (self.telecentric, self.scale, self.sin_marginal, self.magnification_sign, self.distance_mm)
    }

    /// [`object_ray`]'s unit direction from the object point (x, y, 0) through normalised pupil point (px, py).
    #[inline(always)]
    pub fn direction(&self, x: f64, y: f64, px: f64, py: f64) -> [f64; 3] {
        self.through(x, y, 0.0, px * self.scale, py * self.scale)
    }

    /// Direction from (ox, oy, oz) through pupil-plane point (u, v) (telecentric: direction sines (u, v)·sin θ).
    #[inline(always)]
    fn through(&self, ox: f64, oy: f64, oz: f64, u: f64, v: f64) -> [f64; 3] {
        if self.telecentric {
            let s = self.sin_marginal; // (u, v) are normalised pupil coordinates here (scale 1)
            let (sx, sy) = (u * s, v * s);
            let z = (1.0 - sx * sx - sy * sy).max(0.0).sqrt();
            return [sx, sy, z];
        }
        // Pupil coordinates are oriented as at the stop: the entrance-pupil point is the paraxial image of
        // the stop point, so it carries the sign of the pupil magnification (SP: real inverted pupil, m_p < 0).
        let m = self.magnification_sign;
        let (mut wx, mut wy, mut wz) = (m * u - ox, m * v - oy, self.distance_mm - oz);
        // A pupil behind the object (distance < 0) is virtual: the ray travels away from it, toward +z.
        if self.distance_mm < 0.0 {
            (wx, wy, wz) = (-wx, -wy, -wz);
        }
        // glam's `normalize`: w · (1 / |w|), |w|² summed x, y, z in order.
        let inv = 1.0 / (wx * wx + wy * wy + wz * wz).sqrt();
        [wx * inv, wy * inv, wz * inv]
    }
}

/// Where a ray from the object (object frame, `n` the indices at its wavelength) crosses the stop surface,
/// in the stop's local (x, y) mm; `None` when it does not get there.
///
/// Apertures before the stop do not stop the aiming trace: the aim point is a point of the stop surface
/// whatever shadows or clips the way to it. A central obscuration (a Cassegrain's secondary, `OBSC`)
/// shadows the chief ray itself, which stays the field's reference ray; a clear aperture (`CLAP`, `SQAP`,
/// a floating aperture `FLAP`) may clip an intermediate guess of the Newton iteration, or the aimed ray
/// itself. Whether the aimed ray is vignetted is decided when it is traced (its status names the surface).
pub fn stop_crossing(system: &SequentialSystem, n: &[f64], origin: DVec3, d: DVec3) -> Option<(f64, f64)> {
    let probe = &system.stop_probe;
    // The steps before the stop, their apertures (clear and obscuring) opened once when the system was built.
    let before = probe.open_path.as_deref().unwrap_or(&system.path[..probe.steps]);
    let (p, d) = trace_steps(before, n, origin, d).ok()?;
    let step = &probe.probe;
    let (p, d) = (step.rotation * (p - step.offset), step.rotation * d);
    let hit = crate::surfaces::intersect(&step.shape, p, d).ok()?;
    Some((hit.point.x, hit.point.y))
}

/// OpticStudio's real stop radius (mm), the radius "Real" ray aiming aims at: the radius of the real axial
/// beam at the stop, at the primary wavelength, the stop's apertures and those before it open. The beam is
/// the paraxial entrance pupil's, centred where the real chief ray of the axial object point enters: that
/// ray is aimed at the stop's centre (its local origin, as [`aimed_ray`] aims the chief ray), and the marginal
/// ray leaves the same object point through the pupil-plane point a pupil radius above the chief ray's (for an
/// object at infinity, the parallel ray that far from it). The radius is the distance, in the stop's local
/// (x, y), from the chief ray's crossing (the centre) to the marginal ray's. For a lens with spherical
/// aberration before the stop it differs from the paraxial stop radius: 4.2150 mm against 4.2508 mm for the
/// double Gauss of tests/fixtures/zmx, whose file holds OpticStudio's 4.215000499 as the stop's automatic
/// semi-diameter.
///
/// In a centred system the axial chief ray is the axis: the aim is (0, 0) at once and the marginal ray is
/// the one through the pupil's edge (0, 1). With a stop decentred by a Coordinate Break the unaimed beam
/// crosses the stop plane around the axis, not around the stop's centre, and its edge's distance from the
/// centre is no radius of it (a 10 mm pupil before a stop decentred 4 mm gave 1 mm: F/39 for F/7.8). Centred
/// on the aimed chief ray, real aiming differs from paraxial aiming by the pupil aberration only, as in a
/// centred system. optiland's real stop radius (`RealReferenceStrategy`, its issue 654) is this one, and its
/// iterative aiming lands these rays to 1e-13 mm (tests/zmx_round17.rs). Errors: the chief ray cannot be
/// aimed at the stop's centre, or the marginal ray does not reach the stop.
pub fn real_stop_radius(system: &SequentialSystem) -> std::result::Result<f64, String> {
    let [r] = axial_beam_radii(system, [(0.0, 1.0)])?;
    if !(r.is_finite() && r > 0.0) {
        return Err(format!("real ray aiming: the real marginal ray crosses the stop at radius {r} mm; use paraxial aiming"));
    }
    Ok(r)
}

/// The real axial beam's radius at the stop (mm) towards each pupil direction (du, dv) (unit vectors): the
/// real chief ray of the axial object point aimed at the stop's centre, the ray of the same point through
/// the paraxial-pupil-plane point one pupil radius from the chief ray's towards (du, dv), and the distance
/// between their crossings of the stop in its local frame (primary wavelength). [`real_stop_radius`] is the
/// +y one; [`real_stop_radii`] the four axis directions. Errors say which ray failed, in words.
fn axial_beam_radii<const K: usize>(system: &SequentialSystem, directions: [(f64, f64); K]) -> std::result::Result<[f64; K], String> {
    let n = system.indices(system.spec.primary_wavelength_nm).map_err(|e| e.to_string())?;
    let why = |m: String| format!("real ray aiming: {m}, so the real stop radius is undefined; use paraxial aiming");
    let (u0, v0) = solve_pupil_point(system, &n, [0.0, 0.0], (0.0, 0.0), (0.0, 0.0), system.pupil.stop_radius_mm)
        .map_err(|m| why(format!("the real chief ray of the axial object point (primary wavelength) cannot be aimed at the stop's centre ({m})")))?;
    let ray = pupil_ray(system, [0.0, 0.0]);
    let cross = |u: f64, v: f64| {
        let (o, d) = ray(u, v);
        stop_crossing(system, &n, o, d)
    };
    let unreached = || why("the real marginal ray (axial object point, entrance-pupil edge, primary wavelength) does not reach the stop".to_string());
    let (xc, yc) = cross(u0, v0).ok_or_else(unreached)?;
    let s = pupil_scale(system);
    let mut out = [0.0; K];
    for (r, (du, dv)) in out.iter_mut().zip(directions) {
        let (x, y) = cross(u0 + s * du, v0 + s * dv).ok_or_else(unreached)?;
        *r = (x - xc).hypot(y - yc);
    }
    Ok(out)
}

/// The real axial beam's radius at the stop (mm) along the four pupil directions +y, −y, +x, −x, measured as
/// [`real_stop_radius`] measures +y (the rays a pupil radius from the aimed axial chief ray, the stop's and
/// earlier apertures open); `None` where a ray does not reach the stop or the chief ray cannot be aimed.
///
/// OpticStudio's real stop radius is the +y one alone (the marginal ray is the axial field's ray at Py = +1),
/// and optiland's is the same. In a rotationally symmetric system the four agree; where the stop is decentred
/// behind a lens with coma, or the beam at the stop is anamorphic (a prism before it), they do not, and the
/// beam real aiming traces then depends on how the system is turned about its axis: a held-out battery (round
/// 18) measured 2.2837, 2.3661 and 2.3254 mm for one lens as given, mirrored in y and turned 90°, its on-axis
/// RMS spot 1497, 1558 and 1528 µm. [`SequentialSystem::real_aiming_warnings`](crate::system::SequentialSystem::real_aiming_warnings)
/// says so on load.
pub fn real_stop_radii(system: &SequentialSystem) -> Option<[f64; 4]> {
    let r = axial_beam_radii(system, [(0.0, 1.0), (0.0, -1.0), (1.0, 0.0), (-1.0, 0.0)]).ok()?;
    r.iter().all(|v| v.is_finite() && *v > 0.0).then_some(r)
}

/// The ray of field `field_mm` through pupil-plane point (u, v) (mm, or direction sines when telecentric),
/// aiming off: from the object point (finite), or parallel at the field's angles (object at infinity).
fn pupil_ray(system: &SequentialSystem, field_mm: [f64; 2]) -> impl Fn(f64, f64) -> (DVec3, DVec3) + '_ {
    let origin = DVec3::new(field_mm[0], field_mm[1], 0.0);
    let aim = PupilAim::of(system);
    move |u: f64, v: f64| if aim.at_infinity { aim.parallel_ray(field_mm, u, v) } else { (origin, direction_through_pupil(system, origin, u, v)) }
}

/// The pupil-plane point (u, v) whose ray ([`pupil_ray`]) crosses the stop surface at local (tx, ty) (Newton
/// iteration from `start`, finite-difference Jacobian); `r_stop` scales the tolerance. Errors say why, in words.
fn solve_pupil_point(
    system: &SequentialSystem,
    n: &[f64],
    field_mm: [f64; 2],
    start: (f64, f64),
    (tx, ty): (f64, f64),
    r_stop: f64,
) -> std::result::Result<(f64, f64), String> {
    let ray = pupil_ray(system, field_mm);
    let r_ep = pupil_scale(system);
    let (mut u, mut v) = start;
    let eval = |u: f64, v: f64| {
        let (o, d) = ray(u, v);
        stop_crossing(system, n, o, d).ok_or("the ray does not reach the stop")
    };
    let h = 1e-7 * r_ep.max(1.0);
    for _ in 0..30 {
        let (x, y) = eval(u, v)?;
        let (ex, ey) = (x - tx, y - ty);
        if ex.abs() < 1e-13 * (1.0 + r_stop) && ey.abs() < 1e-13 * (1.0 + r_stop) {
            return Ok((u, v));
        }
        let (xu, yu) = eval(u + h, v)?;
        let (xv, yv) = eval(u, v + h)?;
        let (a, c) = ((xu - x) / h, (yu - y) / h);
        let (b, d) = ((xv - x) / h, (yv - y) / h);
        let det = a * d - b * c;
        if !(det.abs() > 0.0) || !det.is_finite() {
            return Err("singular aiming Jacobian".into());
        }
        let du = (d * ex - b * ey) / det;
        let dv = (-c * ex + a * ey) / det;
        u -= du;
        v -= dv;
        if du.abs() < 1e-14 * (1.0 + r_ep) && dv.abs() < 1e-14 * (1.0 + r_ep) {
            return Ok((u, v));
        }
    }
    Err("no convergence in 30 Newton steps".into())
}

/// The object-space ray for (field, px, py) at `wavelength_nm` under the system's ray-aiming mode.
///
/// With aiming on ([`RayAiming::Paraxial`], [`RayAiming::Real`]) the ray is aimed (Newton iteration,
/// finite-difference Jacobian) so that it crosses the real stop surface at (px, py) ×
/// `system.aim_stop_radius_mm` (the paraxial or the real stop radius) from the stop's vertex, at its own
/// wavelength — OpticStudio's ray aiming (the chief ray passes through the centre of the stop). `n` are
/// the indices at `wavelength_nm` ([`SequentialSystem::indices`]).
pub fn aimed_ray(system: &SequentialSystem, n: &[f64], field_mm: [f64; 2], px: f64, py: f64) -> Result<(DVec3, DVec3)> {
    if system.spec.ray_aiming == RayAiming::Off {
        return Ok(object_ray(system, field_mm, px, py));
    }
    let r_ep = pupil_scale(system);
    let r_stop = system.aim_stop_radius_mm;
    let (shown, unit) = system.field_display(field_mm);
    let (u, v) = solve_pupil_point(system, n, field_mm, (px * r_ep, py * r_ep), (px * r_stop, py * r_stop), r_stop)
        .map_err(|why| Error::invalid(format!("ray aiming failed for field ({}, {}) {unit}, pupil ({px}, {py}): {why}", shown[0], shown[1])))?;
    Ok(pupil_ray(system, field_mm)(u, v))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `direction_through_pupil` as it was written with glam before [`PupilAim`] (the reference).
    fn glam_direction(system: &SequentialSystem, origin: DVec3, u: f64, v: f64) -> DVec3 {
        let pupil = &system.pupil;
        if pupil.is_telecentric() {
            let s = pupil.sin_marginal;
            let (sx, sy) = (u * s, v * s);
            return DVec3::new(sx, sy, (1.0 - sx * sx - sy * sy).max(0.0).sqrt());
        }
        let target = DVec3::new(pupil.magnification_sign * u, pupil.magnification_sign * v, pupil.distance_mm);
        let w = target - origin;
        (if pupil.distance_mm < 0.0 { -w } else { w }).normalize()
    }

    #[test]
    fn pupil_aim_is_the_glam_direction_bit_for_bit() {
        for name in crate::presets::NAMES {
            let sys = SequentialSystem::build(&crate::presets::spec(name).unwrap()).unwrap();
            let aim = PupilAim::of(&sys);
            let r = if sys.pupil.is_telecentric() { 1.0 } else { sys.pupil.radius_mm };
            for i in 0..400 {
                let (x, y) = ((i % 20) as f64 * 0.37 - 3.1, (i / 20) as f64 * -0.29 + 2.3);
                let (px, py) = (((i * 7) % 13) as f64 / 6.5 - 1.0, ((i * 5) % 11) as f64 / 5.5 - 1.0);
                let want = glam_direction(&sys, DVec3::new(x, y, 0.0), px * r, py * r);
                let got = aim.direction(x, y, px, py);
                assert_eq!(got.map(f64::to_bits), want.to_array().map(f64::to_bits), "{name} {i}");
                assert_eq!(object_ray(&sys, [x, y], px, py).1, want);
            }
        }
    }
}
