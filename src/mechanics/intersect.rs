//! Ray–triangle intersection in f64 (Möller & Trumbore, "Fast, minimum storage ray-triangle
//! intersection", JGT 1997) and the brute-force closest hit over every triangle of every part: the
//! reference the Embree queries are checked against.
//!
//! **Edge and epsilon policy.** No epsilon is added anywhere: a triangle is hit when the determinant is
//! non-zero (a ray in the triangle's plane never hits it), the barycentrics satisfy u ≥ 0, v ≥ 0,
//! u + v ≤ 1 *inclusively* (a ray through a shared edge or vertex hits every triangle there and the
//! closest-t tie goes to the lowest (part, triangle) index, so the answer is deterministic), and
//! `tmin < t ≤ tmax`. This is not watertight in the strict sense of Woop, Benthin & Wald (JCGT 2013): in
//! floating point a ray through an edge can be rejected by both neighbours when a barycentric rounds to
//! −1e-17 relative; on the random rays of the tests this never happened, and a caller that needs
//! watertightness pads `tmin`/edges itself. Self-intersection is the caller's business: pass the `tmin`
//! (or the part mask) that excludes the surface a ray leaves.
use glam::DVec3;

/// `(t, u, v)` where the ray `o + t·d` meets triangle `(a, b, c)` with `tmin < t ≤ tmax`.
#[inline]
pub fn ray_triangle(o: DVec3, d: DVec3, a: DVec3, b: DVec3, c: DVec3, tmin: f64, tmax: f64) -> Option<(f64, f64, f64)> {
    let e1 = b - a;
    let e2 = c - a;
    let p = d.cross(e2);
    let det = e1.dot(p);
    if det == 0.0 || !det.is_finite() {
        return None;
    }
    let inv = 1.0 / det;
    let s = o - a;
    let u = s.dot(p) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(e1);
    let v = d.dot(q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    let t = e2.dot(q) * inv;
    (t > tmin && t <= tmax).then_some((t, u, v))
}

/// Where the ray `o + t·d` meets the *plane* of triangle `(a, b, c)` (no barycentric test): the f64
/// re-solve of a triangle an f32 query identified, whose f32 barycentrics may lie a rounding outside it.
#[inline]
pub fn ray_plane_t(o: DVec3, d: DVec3, a: DVec3, b: DVec3, c: DVec3) -> Option<f64> {
    let n = (b - a).cross(c - a);
    let den = n.dot(d);
    let t = n.dot(a - o) / den;
    (den != 0.0 && t.is_finite()).then_some(t)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hits_inside_and_on_edges_misses_outside_and_parallel() {
        let (a, b, c) = (DVec3::ZERO, DVec3::X, DVec3::Y);
        let down = DVec3::new(0.0, 0.0, -1.0);
        let (t, u, v) = ray_triangle(DVec3::new(0.25, 0.5, 2.0), down, a, b, c, 0.0, f64::INFINITY).unwrap();
        assert_eq!((t, u, v), (2.0, 0.25, 0.5));
        assert!(ray_triangle(DVec3::new(0.5, 0.5, 2.0), down, a, b, c, 0.0, f64::INFINITY).is_some()); // hypotenuse
        assert!(ray_triangle(DVec3::new(0.0, 0.0, 2.0), down, a, b, c, 0.0, f64::INFINITY).is_some()); // vertex
        assert!(ray_triangle(DVec3::new(0.6, 0.6, 2.0), down, a, b, c, 0.0, f64::INFINITY).is_none());
        assert!(ray_triangle(DVec3::new(0.2, 0.2, 2.0), down, a, b, c, 0.0, 1.5).is_none()); // beyond tmax
        assert!(ray_triangle(DVec3::new(0.2, 0.2, 2.0), -down, a, b, c, 0.0, f64::INFINITY).is_none()); // behind
        assert!(ray_triangle(DVec3::new(-1.0, 0.2, 0.0), DVec3::X, a, b, c, 0.0, f64::INFINITY).is_none()); // in plane
        assert_eq!(ray_plane_t(DVec3::new(5.0, 5.0, 2.0), down, a, b, c), Some(2.0));
    }
}
