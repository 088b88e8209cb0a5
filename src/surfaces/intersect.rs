use super::SurfaceShape;
use glam::DVec3;

/// An exact intersection in the surface's local frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Signed distance along the (unit) direction, mm. Negative values are virtual propagation.
    pub t: f64,
    pub point: DVec3,
    /// Unit normal at `point`, oriented toward local +z.
    pub normal: DVec3,
}

/// Why no intersection was returned: a classified outcome, never a NaN.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum IntersectFailure {
    /// The line does not meet the surface (or meets it outside the conic's domain / off the vertex branch).
    Missed,
    /// The even-asphere root solve did not converge within its iteration budget.
    NoConvergence,
}

/// Intersect the line p + t·d (local frame, `d` unit) with the surface, on the vertex branch.
#[inline(always)]
pub fn intersect(shape: &SurfaceShape, p: DVec3, d: DVec3) -> Result<Hit, IntersectFailure> {
    match shape {
        SurfaceShape::Plane | SurfaceShape::Paraxial { .. } => intersect_plane(p, d),
        SurfaceShape::Conic { curvature, conic } => {
            if *curvature == 0.0 {
                return intersect_plane(p, d);
            }
            let (t, point) = conic_root(*curvature, *conic, p, d)?;
            Ok(Hit { t, point, normal: shape.normal(point) })
        }
        SurfaceShape::EvenAsphere { curvature, conic, .. } => {
            // Starts: the base conic's root (an excellent start when the aspheric terms are mild), then the
            // vertex plane's. The conic root can lie far from the asphere's crossing — near the rim of the
            // conic's domain, even behind the ray, where strong aspheric terms have bent the figure away
            // — and Newton from there leaves the domain; the plane root is then the better start.
            let plane = intersect_plane(p, d).map(|h| h.t);
            let conic_start = if *curvature == 0.0 { Err(IntersectFailure::Missed) } else { conic_root(*curvature, *conic, p, d).map(|(t, _)| t) };
            newton_hit(shape, p, d, [conic_start, plane])
        }
        SurfaceShape::Toroidal { curvature, conic, .. } => {
            // Starts: the vertex plane's root (the toroid is smooth through its vertex), then the root of the
            // YZ curve's rotationally symmetric conic (closer for steep surfaces).
            let plane = intersect_plane(p, d).map(|h| h.t);
            let conic_start = if *curvature == 0.0 { Err(IntersectFailure::Missed) } else { conic_root(*curvature, *conic, p, d).map(|(t, _)| t) };
            newton_hit(shape, p, d, [plane, conic_start])
        }
    }
}

/// The guarded Newton solve of an even asphere or a toroid from the first of `starts` that converges (a
/// failed start is skipped), and the hit with its normal (`Missed` where the normal is not finite).
#[inline(always)]
fn newton_hit(shape: &SurfaceShape, p: DVec3, d: DVec3, starts: [Result<f64, IntersectFailure>; 2]) -> Result<Hit, IntersectFailure> {
    let mut result = Err(IntersectFailure::Missed);
    for t0 in starts {
        let Ok(t0) = t0 else { continue };
        result = asphere_newton(shape, p, d, t0);
        if result.is_ok() {
            break;
        }
    }
    let t = result?;
    let point = p + d * t;
    let normal = shape.normal(point);
    if !normal.is_finite() {
        return Err(IntersectFailure::Missed);
    }
    Ok(Hit { t, point, normal })
}

#[inline]
fn intersect_plane(p: DVec3, d: DVec3) -> Result<Hit, IntersectFailure> {
    if d.z == 0.0 {
        return Err(IntersectFailure::Missed);
    }
    let t = -p.z / d.z;
    let point = DVec3::new(p.x + t * d.x, p.y + t * d.y, 0.0);
    if !point.is_finite() {
        return Err(IntersectFailure::Missed);
    }
    Ok(Hit { t, point, normal: DVec3::Z })
}

/// Whether `point` (on the quadric c(x²+y²+kk·z²) − 2z = 0, kk = 1 + conic) lies on its vertex branch, where
/// the sag formula z = c r² / (1 + √(1 − kk c² r²)) holds; otherwise it is on the other sheet or half.
#[inline(always)]
pub(crate) fn on_conic_vertex_branch(point: DVec3, c: f64, kk: f64) -> bool {
    let r2 = point.x * point.x + point.y * point.y;
    let domain = 1.0 - kk * c * c * r2;
    if domain < 0.0 {
        return false;
    }
    let sag = c * r2 / (1.0 + domain.sqrt());
    (point.z - sag).abs() <= 1e-9 * (1.0 + point.z.abs())
}

/// The conic c(x²+y²+kk·z²) − 2z = 0 along the line p + t·d as a quadratic a s² + 2b s + cc = 0 in the
/// parameter s from the line's point nearest the vertex, p₀ = p + t₀·d, t₀ = −p·d (d unit): t = t₀ + s.
/// Shared by the sequential root ([`conic_root`]) and the patches' two roots (`patch::conic_roots`); the SIMD
/// lanes (`tracer::simd::block::nearest_quadratic`) and the GPU kernels compute the same operations in order.
#[derive(Clone, Copy, Debug)]
pub(crate) struct NearestQuadratic {
    pub t0: f64,
    pub p0: DVec3,
    pub a: f64,
    pub b: f64,
    pub cc: f64,
}

impl NearestQuadratic {
    #[inline(always)]
    pub(crate) fn new(c: f64, kk: f64, p: DVec3, d: DVec3) -> NearestQuadratic {
        let t0 = -(p.x * d.x + p.y * d.y + p.z * d.z);
        let p0 = DVec3::new(p.x + d.x * t0, p.y + d.y * t0, p.z + d.z * t0);
        let a = c * (d.x * d.x + d.y * d.y + kk * d.z * d.z);
        let b = c * (p0.x * d.x + p0.y * d.y + kk * p0.z * d.z) - d.z;
        let cc = c * (p0.x * p0.x + p0.y * p0.y + kk * p0.z * p0.z) - 2.0 * p0.z;
        NearestQuadratic { t0, p0, a, b, cc }
    }
}

/// Vertex-branch root of c(x²+y²+(1+k)z²) − 2z = 0 along p + t d: (t, the point).
///
/// The quadratic is solved from the line's point nearest the vertex, p₀ = p + t₀·d with t₀ = −p·d (d unit),
/// not from p: the constant term C = c(x²+y²+kk·z²) − 2z of a start far in front carries c·kk·z² (2·10⁸ for
/// R = 50 mm at 100 m) and the discriminant B′² − AC lost every digit the branch test needs — rays of a
/// finite object 30 m away were reported missed (round 20; OpticStudio likewise transfers to the vertex
/// region before it intersects). From p₀, C is of the order of c·r² over the aperture.
///
/// With A s² + 2B′ s + C = 0 the two roots are s₁ = C / q and s₂ = q / A, q = −(B′ + sign(B′)√(B′² − AC)),
/// both free of cancellation (Numerical Recipes §5.6); t = t₀ + s. A line can cross the vertex branch twice
/// (a steep ray through the rim of a deep sphere) and the root then taken is the one nearest the ray's
/// start, |t| smallest (as the quadratic in p's own parameter picks it: its C / q is the smaller root), each
/// tested against the branch (the sheet the sag formula describes) at p₀ + s·d, nearest first.
#[inline(always)]
fn conic_root(c: f64, k: f64, p: DVec3, d: DVec3) -> Result<(f64, DVec3), IntersectFailure> {
    let kk = 1.0 + k;
    let NearestQuadratic { t0, p0, a, b, cc } = NearestQuadratic::new(c, kk, p, d);
    let disc = b * b - a * cc;
    if !(disc >= 0.0) {
        return Err(IntersectFailure::Missed);
    }
    let q = -(b + b.signum() * disc.sqrt());
    if q == 0.0 {
        return Err(IntersectFailure::Missed);
    }
    let s1 = cc / q;
    let s2 = if a != 0.0 { q / a } else { f64::NAN };
    let (r1, r2) = (t0 + s1, t0 + s2);
    let order = if r2.abs() < r1.abs() { [(s2, r2), (s1, r1)] } else { [(s1, r1), (s2, r2)] };
    for (s, t) in order {
        let point = p0 + d * s;
        if s.is_finite() && t.is_finite() && on_conic_vertex_branch(point, c, kk) {
            return Ok((t, point));
        }
    }
    Err(IntersectFailure::Missed)
}

/// Newton's method on f(t) = z(t) − sag(x(t), y(t)), guarded by a bracket: once a sign change is seen,
/// a step leaving the bracket (or landing where the sag is undefined) is replaced by bisection.
fn asphere_newton(shape: &SurfaceShape, p: DVec3, d: DVec3, t0: f64) -> Result<f64, IntersectFailure> {
    const MAX_ITER: usize = 100;
    let eval = |t: f64| -> (f64, f64) {
        let q = p + d * t;
        let f = q.z - shape.sag(q.x, q.y);
        let (gx, gy) = shape.sag_gradient(q.x, q.y);
        (f, d.z - gx * d.x - gy * d.y)
    };
    let mut t = t0;
    let (mut lo, mut hi): (Option<f64>, Option<f64>) = (None, None); // f(lo) < 0 < f(hi)
    for _ in 0..MAX_ITER {
        let (f, fp) = eval(t);
        if !f.is_finite() {
            match (lo, hi) {
                (Some(a), Some(b)) => {
                    // Undefined point inside the bracket: move toward the side we came from.
                    t = 0.5 * (a + b);
                    continue;
                }
                _ => return Err(IntersectFailure::Missed),
            }
        }
        if f == 0.0 {
            return Ok(t);
        }
        if f < 0.0 {
            lo = Some(t);
        } else {
            hi = Some(t);
        }
        let mut next = t - f / fp;
        if let (Some(a), Some(b)) = (lo, hi) {
            let (min, max) = if a < b { (a, b) } else { (b, a) };
            if !(next > min && next < max) {
                next = 0.5 * (a + b);
            }
            if (max - min) <= 4.0 * f64::EPSILON * (1.0 + t.abs()) {
                return Ok(next);
            }
        } else if !next.is_finite() {
            return Err(IntersectFailure::NoConvergence);
        }
        if (next - t).abs() <= 1e-15 * (1.0 + t.abs()) {
            let (fn_, _) = eval(next);
            return if fn_.is_finite() && fn_.abs() < 1e-9 { Ok(next) } else { Err(IntersectFailure::NoConvergence) };
        }
        t = next;
    }
    // Accept a converged residual even if the step criterion never fired (round-off limit cycle).
    let (f, _) = eval(t);
    if f.is_finite() && f.abs() < 1e-12 {
        Ok(t)
    } else {
        Err(IntersectFailure::NoConvergence)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sphere_hit_on_vertex_branch() {
        let s = SurfaceShape::Conic { curvature: 1.0 / 10.0, conic: 0.0 };
        let h = intersect(&s, DVec3::new(3.0, 4.0, -20.0), DVec3::Z).unwrap();
        assert!((h.point.z - (10.0 - (100.0f64 - 25.0).sqrt())).abs() < 1e-13);
        let h2 = intersect(&SurfaceShape::Conic { curvature: -0.1, conic: 0.0 }, DVec3::new(3.0, 4.0, 5.0), -DVec3::Z).unwrap();
        assert!((h2.point.z + (10.0 - 75f64.sqrt())).abs() < 1e-13);
    }

    #[test]
    fn sphere_miss_is_classified() {
        let s = SurfaceShape::Conic { curvature: 1.0 / 10.0, conic: 0.0 };
        assert_eq!(intersect(&s, DVec3::new(11.0, 0.0, -1.0), DVec3::Z), Err(IntersectFailure::Missed));
        assert_eq!(intersect(&SurfaceShape::Plane, DVec3::ZERO, DVec3::X), Err(IntersectFailure::Missed));
    }

    #[test]
    fn asphere_newton_converges_to_sag() {
        let s = SurfaceShape::EvenAsphere { curvature: 0.03, conic: -1.0, coefficients: vec![2e-3, -5e-5, 1e-7] };
        let d = DVec3::new(0.1, -0.05, 1.0).normalize();
        let h = intersect(&s, DVec3::new(2.0, 1.5, -3.0), d).unwrap();
        assert!((h.point.z - s.sag(h.point.x, h.point.y)).abs() < 1e-13);
    }

    #[test]
    fn asphere_failures_are_classified() {
        // A steep asphere the ray cannot meet: a classified miss, never a panic or a NaN hit.
        let s = SurfaceShape::EvenAsphere { curvature: 0.2, conic: 0.0, coefficients: vec![0.0, 5.0] };
        let r = intersect(&s, DVec3::new(0.0, 0.0, -1.0), DVec3::X);
        assert!(matches!(r, Err(IntersectFailure::Missed) | Err(IntersectFailure::NoConvergence)), "{r:?}");
        // Outside the conic's domain (r > 1/c): missed.
        let s = SurfaceShape::EvenAsphere { curvature: 0.5, conic: 0.0, coefficients: vec![1e-3] };
        assert!(intersect(&s, DVec3::new(3.0, 0.0, -1.0), DVec3::Z).is_err());
    }

    #[test]
    fn ray_from_beyond_the_centre_of_curvature_meets_the_vertex() {
        // Concave R = −10 mm, ray along the axis starting 14 mm in front (beyond the centre of curvature):
        // the vertex (t = 14), not the far half of the sphere (t = −6).
        let s = SurfaceShape::Conic { curvature: -0.1, conic: 0.0 };
        let h = intersect(&s, DVec3::new(0.0, 0.0, -14.0), DVec3::Z).unwrap();
        assert!((h.t - 14.0).abs() < 1e-12 && h.point.z.abs() < 1e-12, "{h:?}");
        let h = intersect(&s, DVec3::new(2.0, 1.0, -30.0), DVec3::new(0.01, 0.0, 1.0).normalize()).unwrap();
        assert!((h.point.z - s.sag(h.point.x, h.point.y)).abs() < 1e-12 && h.point.z < 0.0);
    }

    #[test]
    fn strong_asphere_falls_back_to_the_plane_start() {
        // The base conic's root lies behind the ray at the rim of its domain (t = −13.1, r = 22 mm), where
        // Newton leaves the domain; from the vertex plane's root it converges to the crossing at t = 13.44
        // (found independently by the bounded patch's sampled search).
        let s = SurfaceShape::EvenAsphere { curvature: -0.04056854136652041, conic: 0.25615930532203046, coefficients: vec![0.0, 8.918683760134837e-5] };
        let p = DVec3::new(10.753351557283526, 7.235889264117773, -10.0);
        let d = DVec3::new(-0.7303541173436519, -0.6166695427291766, 1.0).normalize();
        let h = intersect(&s, p, d).unwrap();
        let patch = crate::surfaces::SurfacePatch::new(s.clone(), crate::surfaces::Aperture::circular(16.0)).unwrap();
        let t = patch.first_hit(p, d, 0.0, f64::INFINITY).unwrap();
        assert!((h.t - t).abs() < 1e-9 && (h.t - 13.4388).abs() < 1e-3, "{} vs {t}", h.t);
    }

    #[test]
    fn paraboloid_k_minus_one() {
        let s = SurfaceShape::Conic { curvature: 0.05, conic: -1.0 };
        let h = intersect(&s, DVec3::new(7.0, 0.0, -1.0), DVec3::Z).unwrap();
        assert!((h.point.z - 0.05 * 49.0 / 2.0).abs() < 1e-13);
    }
}
