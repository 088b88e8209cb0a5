//! Exact ray hits on a *bounded* surface patch — a figure over its clear aperture — for non-sequential
//! tracing (the Embree backend's analytic user geometry and its f64 hit refinement).
//!
//! The sequential tracer ([`super::intersect`]) needs one root: the vertex-branch crossing of an
//! unbounded surface. A non-sequential tracer asks a different question: *where, after `tmin`, does this
//! ray first meet the piece of surface that physically exists?* — a ray reflected inside a prism may meet
//! a face from behind, a ray may pass beside a lens. [`SurfacePatch::first_hit`] answers that:
//! * plane / paraxial plane: t = −p_z/d_z;
//! * conic: both roots of c(x²+y²+(1+k)z²) − 2z = 0 along the ray, in increasing t, each checked to lie on
//!   the vertex branch (the sag formula's sheet) and inside the aperture;
//! * even asphere and Toroidal surface (the sequential figure, [`super::toroidal`]): the ray is clipped to
//!   the patch's bounding cylinder and z-slab, f(t) = z − sag(x, y) is sampled for the first sign change and
//!   the bracket refined by safeguarded Newton (Newton steps that leave the bracket become bisections), so
//!   grazing rays cannot diverge. A Toroidal figure's z-slab is sampled over the aperture itself (it is not
//!   rotationally symmetric).
//!
//! [`SurfacePatch::nearest_root`] re-solves a hit already located approximately (an f32 Embree hit on a
//! mesh or a user geometry) in f64: the root nearest to the approximate distance, without the aperture
//! test (the surface was already identified).
//!
//! ```
//! use diffcassi::surfaces::{Aperture, SurfacePatch, SurfaceShape};
//! use glam::DVec3;
//! let lens = SurfacePatch::new(SurfaceShape::Conic { curvature: 1.0 / 33.34, conic: 0.0 }, Aperture::circular(12.7)).unwrap();
//! let t = lens.first_hit(DVec3::new(3.0, 0.0, -5.0), DVec3::Z, 0.0, f64::INFINITY).unwrap();
//! assert!((t - 5.0 - lens.shape.sag(3.0, 0.0)).abs() < 1e-12);
//! // From inside the glass going back toward −z, the same surface is met from behind.
//! assert!(lens.first_hit(DVec3::new(3.0, 0.0, 2.0), -DVec3::Z, 0.0, f64::INFINITY).is_some());
//! ```
use super::intersect::{on_conic_vertex_branch, NearestQuadratic};
use super::{Aperture, SurfaceShape};
use glam::DVec3;

/// A surface figure over a finite clear aperture, with conservative local bounds.
#[derive(Clone, Debug, PartialEq)]
pub struct SurfacePatch {
    pub shape: SurfaceShape,
    /// Circular or rectangular: the patch's extent.
    pub aperture: Aperture,
    /// Largest distance of an aperture point from the local z axis (mm).
    r_max: f64,
    /// Conservative z range of the patch (mm).
    z_min: f64,
    z_max: f64,
}

/// Samples of f(t) along the clipped ray when searching an even asphere's first root.
const ASPHERE_SAMPLES: usize = 64;

/// Grid intervals per side when a figure that is not rotationally symmetric is bounded over its aperture
/// ([`SurfacePatch::sag_range_over`]).
const GRID: usize = 128;

impl SurfacePatch {
    /// Errors: an aperture that is `None` (a patch must be bounded) or invalid, or a figure undefined
    /// somewhere over the aperture (a conic beyond its domain).
    pub fn new(shape: SurfaceShape, aperture: Aperture) -> Result<Self, String> {
        aperture.validate()?;
        let r_max = match aperture {
            Aperture::None => return Err("a surface patch needs a finite aperture (circular or rectangular)".into()),
            Aperture::CircularObscuration { .. } => {
                return Err("a surface patch needs a finite clear aperture (circular or rectangular); a circular obscuration passes every ray outside it and bounds nothing".into())
            }
            Aperture::Circular { semi_diameter_mm, decenter_x_mm, decenter_y_mm, .. } => semi_diameter_mm + decenter_x_mm.hypot(decenter_y_mm),
            Aperture::Rectangular { half_width_x_mm, half_width_y_mm, decenter_x_mm, decenter_y_mm } => {
                (half_width_x_mm + decenter_x_mm.abs()).hypot(half_width_y_mm + decenter_y_mm.abs())
            }
        };
        let (mut z_min, mut z_max) = (0.0f64, 0.0f64);
        if let SurfaceShape::Toroidal { .. } = shape {
            // A Toroidal figure is not rotationally symmetric: sample it over the aperture itself.
            (z_min, z_max) = Self::sag_range_over(&shape, &aperture)?;
        } else {
            // z range: the sag is rotationally symmetric, so sample it radially over [0, r_max].
            const N: usize = 1024;
            for i in 0..=N {
                let r = r_max * i as f64 / N as f64;
                let z = shape.sag(r, 0.0);
                if !z.is_finite() {
                    return Err(format!("the surface is undefined at r = {r:.4} mm inside its aperture (r_max {r_max:.4} mm)"));
                }
                z_min = z_min.min(z);
                z_max = z_max.max(z);
            }
        }
        // Margin for the sag between samples (a smooth sag varies by far less than this between samples).
        let pad = 1e-6 + 1e-3 * (z_max - z_min);
        Ok(SurfacePatch { shape, aperture, r_max, z_min: z_min - pad, z_max: z_max + pad })
    }

    /// The sag's range (min, max; the vertex's 0 included) over a bounded `aperture`, sampled on a
    /// [`GRID`] × [`GRID`] grid of its box (points inside the aperture) and [`GRID`]·4 points of its rim: the
    /// bounds of a figure that is not rotationally symmetric (a Toroidal surface), where a radial sweep
    /// along x would miss the y profile. Error: the figure is undefined at a sample (a conic beyond its
    /// domain inside the aperture), naming the point.
    fn sag_range_over(shape: &SurfaceShape, aperture: &Aperture) -> Result<(f64, f64), String> {
        let (cx, cy, hx, hy) = match *aperture {
            Aperture::Circular { semi_diameter_mm: r, decenter_x_mm, decenter_y_mm, .. } => (decenter_x_mm, decenter_y_mm, r, r),
            Aperture::Rectangular { half_width_x_mm, half_width_y_mm, decenter_x_mm, decenter_y_mm } => (decenter_x_mm, decenter_y_mm, half_width_x_mm, half_width_y_mm),
            Aperture::None | Aperture::CircularObscuration { .. } => return Err("a bounded aperture is needed".into()),
        };
        // The (GRID + 1)² points of the aperture's box (those outside the aperture skipped below).
        let grid = (0..(GRID + 1) * (GRID + 1)).map(|k| {
            let (i, j) = (k % (GRID + 1), k / (GRID + 1));
            (cx + hx * (2.0 * i as f64 / GRID as f64 - 1.0), cy + hy * (2.0 * j as f64 / GRID as f64 - 1.0))
        });
        let rim = (0..4 * GRID).map(|k| {
            let a = std::f64::consts::TAU * k as f64 / (4 * GRID) as f64;
            match aperture {
                Aperture::Circular { .. } => (cx + hx * a.cos(), cy + hy * a.sin()),
                // The rectangle's edge where the ray from its centre at angle a leaves it.
                _ => {
                    let f = (hx / a.cos().abs().max(1e-300)).min(hy / a.sin().abs().max(1e-300));
                    (cx + f * a.cos(), cy + f * a.sin())
                }
            }
        });
        let (mut z_min, mut z_max) = (0.0f64, 0.0f64);
        for (x, y) in grid.filter(|&(x, y)| aperture.contains(x, y)).chain(rim) {
            let z = shape.sag(x, y);
            if !z.is_finite() {
                return Err(format!("the surface is undefined at (x, y) = ({x:.4}, {y:.4}) mm inside its aperture"));
            }
            z_min = z_min.min(z);
            z_max = z_max.max(z);
        }
        Ok((z_min, z_max))
    }

    /// Conservative local bounding box (lower, upper), mm.
    pub fn local_bounds(&self) -> (DVec3, DVec3) {
        let (lo, hi) = match self.aperture {
            Aperture::Rectangular { half_width_x_mm, half_width_y_mm, decenter_x_mm, decenter_y_mm } => (
                DVec3::new(decenter_x_mm - half_width_x_mm, decenter_y_mm - half_width_y_mm, self.z_min),
                DVec3::new(decenter_x_mm + half_width_x_mm, decenter_y_mm + half_width_y_mm, self.z_max),
            ),
            Aperture::Circular { semi_diameter_mm: r, decenter_x_mm: dx, decenter_y_mm: dy, .. } => {
                (DVec3::new(dx - r, dy - r, self.z_min), DVec3::new(dx + r, dy + r, self.z_max))
            }
            Aperture::None | Aperture::CircularObscuration { .. } => (DVec3::splat(-self.r_max), DVec3::splat(self.r_max)),
        };
        (lo, hi)
    }

    /// Smallest t in (tmin, tmax] at which p + t·d (local frame, `d` unit) meets the patch inside its
    /// aperture, or `None`.
    pub fn first_hit(&self, p: DVec3, d: DVec3, tmin: f64, tmax: f64) -> Option<f64> {
        let inside = |t: f64| -> bool {
            let q = p + d * t;
            t > tmin && t <= tmax && self.aperture.contains(q.x, q.y)
        };
        match &self.shape {
            SurfaceShape::Plane | SurfaceShape::Paraxial { .. } => plane_root(p, d).filter(|&t| inside(t)),
            SurfaceShape::Conic { curvature, conic } => {
                let (t1, t2) = conic_roots(*curvature, *conic, p, d);
                [t1, t2].into_iter().flatten().find(|&t| inside(t))
            }
            SurfaceShape::EvenAsphere { .. } | SurfaceShape::Toroidal { .. } => {
                let (a, b) = self.clip(p, d, tmin, tmax)?;
                self.asphere_first_root(p, d, a, b).filter(|&t| inside(t))
            }
        }
    }

    /// The root of the surface equation along p + t·d nearest to `t_guess` (the f64 refinement of an
    /// approximate hit on this surface), without the aperture test; `None` if the line does not meet the
    /// figure near there.
    pub fn nearest_root(&self, p: DVec3, d: DVec3, t_guess: f64) -> Option<f64> {
        match &self.shape {
            SurfaceShape::Plane | SurfaceShape::Paraxial { .. } => plane_root(p, d),
            SurfaceShape::Conic { curvature, conic } => {
                let (t1, t2) = conic_roots(*curvature, *conic, p, d);
                Self::nearest_of([t1, t2], t_guess)
            }
            SurfaceShape::EvenAsphere { .. } | SurfaceShape::Toroidal { .. } => {
                // Search a window around the guess that grows until it brackets a root.
                let mut w = 1e-3 + 1e-6 * t_guess.abs();
                for _ in 0..12 {
                    if let Some(t) = self.asphere_nearest_in(p, d, t_guess - w, t_guess + w, t_guess) {
                        return Some(t);
                    }
                    w *= 4.0;
                }
                None
            }
        }
    }

    /// Every root of the figure's equation along p + t·d (ascending; `None` where absent) when it has a
    /// closed form — planes and paraxial planes (one root), conics (two, on the vertex branch) — and
    /// `None` for even aspheres (found iteratively). Computed once, these serve both the first hit and
    /// the nearest-root refinement ([`Self::nearest_of`]): the Embree user geometry solves a surface once
    /// per interaction this way.
    #[inline]
    pub fn closed_form_roots(&self, p: DVec3, d: DVec3) -> Option<[Option<f64>; 2]> {
        match &self.shape {
            SurfaceShape::Plane | SurfaceShape::Paraxial { .. } => Some([plane_root(p, d), None]),
            SurfaceShape::Conic { curvature, conic } => {
                let (t1, t2) = conic_roots(*curvature, *conic, p, d);
                Some([t1, t2])
            }
            SurfaceShape::EvenAsphere { .. } | SurfaceShape::Toroidal { .. } => None,
        }
    }

    /// The root nearest to `t_guess` among `roots` (from [`Self::closed_form_roots`]): what
    /// [`Self::nearest_root`] returns for planes and conics, bit for bit.
    #[inline]
    pub fn nearest_of(roots: [Option<f64>; 2], t_guess: f64) -> Option<f64> {
        roots.into_iter().flatten().min_by(|a, b| (a - t_guess).abs().total_cmp(&(b - t_guess).abs()))
    }

    /// The part of (tmin, tmax] inside the bounding cylinder r ≤ r_max and slab z_min ≤ z ≤ z_max.
    fn clip(&self, p: DVec3, d: DVec3, tmin: f64, tmax: f64) -> Option<(f64, f64)> {
        let (mut a, mut b) = (tmin, tmax);
        // Slab.
        if d.z.abs() > 0.0 {
            let (t1, t2) = ((self.z_min - p.z) / d.z, (self.z_max - p.z) / d.z);
            a = a.max(t1.min(t2));
            b = b.min(t1.max(t2));
        } else if p.z < self.z_min || p.z > self.z_max {
            return None;
        }
        // Cylinder: (px + t dx)² + (py + t dy)² ≤ r².
        let qa = d.x * d.x + d.y * d.y;
        let qb = p.x * d.x + p.y * d.y;
        let qc = p.x * p.x + p.y * p.y - self.r_max * self.r_max;
        if qa > 0.0 {
            let disc = qb * qb - qa * qc;
            if disc < 0.0 {
                return None;
            }
            let s = disc.sqrt();
            a = a.max((-qb - s) / qa);
            b = b.min((-qb + s) / qa);
        } else if qc > 0.0 {
            return None;
        }
        (a.is_finite() && b.is_finite() && a <= b).then_some((a, b))
    }

    fn f(&self, p: DVec3, d: DVec3, t: f64) -> f64 {
        let q = p + d * t;
        q.z - self.shape.sag(q.x, q.y)
    }

    /// df/dt = d_z − ∇sag · (d_x, d_y).
    fn f_prime(&self, p: DVec3, d: DVec3, t: f64) -> f64 {
        let q = p + d * t;
        let (gx, gy) = self.shape.sag_gradient(q.x, q.y);
        d.z - gx * d.x - gy * d.y
    }

    /// A sub-interval of [t0, t1] over which f changes sign, given f0 = f(t0), f1 = f(t1) (finite), or
    /// `None`. Besides a plain sign change it finds a *pair* of roots between two samples of equal sign:
    /// a grazing ray crosses the figure and comes back within a fraction of the sample spacing (a ray at
    /// 89.99° through an asphere's vertex re-crosses it 0.03 mm further on). If df/dt changes sign in
    /// between with f heading toward zero, the extremum is located by bisection on df/dt, and when f
    /// there has the opposite sign (or is 0), [t0, t_extremum] brackets the first root.
    fn sign_change(&self, p: DVec3, d: DVec3, t0: f64, f0: f64, t1: f64, f1: f64) -> Option<(f64, f64)> {
        if f0 == 0.0 || f0.signum() != f1.signum() {
            return Some((t0, t1));
        }
        let (g0, g1) = (self.f_prime(p, d, t0), self.f_prime(p, d, t1));
        // f < 0 needs a maximum (f′: + → −), f > 0 a minimum (f′: − → +).
        let toward_zero = if f0 < 0.0 { g0 > 0.0 && g1 < 0.0 } else { g0 < 0.0 && g1 > 0.0 };
        if !(g0.is_finite() && g1.is_finite() && toward_zero) {
            return None;
        }
        let (mut a, mut b) = (t0, t1);
        for _ in 0..200 {
            let m = 0.5 * (a + b);
            if m <= a || m >= b {
                break;
            }
            let g = self.f_prime(p, d, m);
            if !g.is_finite() {
                return None;
            }
            if g.signum() == g0.signum() {
                a = m;
            } else {
                b = m;
            }
        }
        let te = 0.5 * (a + b);
        let fe = self.f(p, d, te);
        (fe.is_finite() && (fe == 0.0 || fe.signum() != f0.signum())).then_some((t0, te))
    }

    /// First sign change of f on [a, b] by sampling (including root pairs between samples), refined.
    fn asphere_first_root(&self, p: DVec3, d: DVec3, a: f64, b: f64) -> Option<f64> {
        let h = (b - a) / ASPHERE_SAMPLES as f64;
        let mut t0 = a;
        let mut f0 = self.f(p, d, a);
        if f0 == 0.0 && a > 0.0 {
            return Some(a);
        }
        for i in 1..=ASPHERE_SAMPLES {
            let t1 = if i == ASPHERE_SAMPLES { b } else { a + h * i as f64 };
            let f1 = self.f(p, d, t1);
            if f0.is_finite() && f1.is_finite() {
                if let Some((lo, hi)) = self.sign_change(p, d, t0, f0, t1, f1) {
                    return self.refine_bracket(p, d, lo, hi);
                }
            }
            (t0, f0) = (t1, f1);
        }
        None
    }

    /// The sign change on [a, b] nearest to `guess`.
    fn asphere_nearest_in(&self, p: DVec3, d: DVec3, a: f64, b: f64, guess: f64) -> Option<f64> {
        let n = 16;
        let ts: Vec<f64> = (0..=n).map(|i| a + (b - a) * i as f64 / n as f64).collect();
        let fs: Vec<f64> = ts.iter().map(|&t| self.f(p, d, t)).collect();
        let mut best: Option<f64> = None;
        for i in 0..n {
            if !(fs[i].is_finite() && fs[i + 1].is_finite()) {
                continue;
            }
            if let Some((lo, hi)) = self.sign_change(p, d, ts[i], fs[i], ts[i + 1], fs[i + 1]) {
                if let Some(t) = self.refine_bracket(p, d, lo, hi) {
                    if best.is_none_or(|b| (t - guess).abs() < (b - guess).abs()) {
                        best = Some(t);
                    }
                }
            }
        }
        best
    }

    /// Safeguarded Newton on a bracket [a, b] with a sign change: Newton steps that leave the bracket
    /// become bisections.
    fn refine_bracket(&self, p: DVec3, d: DVec3, mut a: f64, mut b: f64) -> Option<f64> {
        let mut fa = self.f(p, d, a);
        if fa == 0.0 {
            return Some(a);
        }
        let mut t = 0.5 * (a + b);
        for _ in 0..200 {
            let q = p + d * t;
            let f = q.z - self.shape.sag(q.x, q.y);
            if !f.is_finite() {
                return None;
            }
            if f == 0.0 {
                return Some(t);
            }
            if f.signum() == fa.signum() {
                a = t;
                fa = f;
            } else {
                b = t;
            }
            let (gx, gy) = self.shape.sag_gradient(q.x, q.y);
            let fp = d.z - gx * d.x - gy * d.y;
            let newton = t - f / fp;
            t = if fp != 0.0 && newton > a.min(b) && newton < a.max(b) { newton } else { 0.5 * (a + b) };
            if (b - a).abs() <= 4.0 * f64::EPSILON * (1.0 + t.abs()) {
                return Some(t);
            }
        }
        Some(t)
    }
}

#[inline]
fn plane_root(p: DVec3, d: DVec3) -> Option<f64> {
    (d.z != 0.0).then(|| -p.z / d.z).filter(|t| t.is_finite())
}

/// Both roots (ascending, each `None` if absent or off the vertex branch) of c(x²+y²+(1+k)z²) − 2z = 0
/// along p + t·d, computed without cancellation (Numerical Recipes §5.6) from the line's point nearest the
/// vertex p₀ = p + t₀·d, t₀ = −p·d, as the sequential `intersect::conic_root` (a start far in front loses the
/// discriminant's digits otherwise; round 20); the roots are t₀ + s.
fn conic_roots(c: f64, k: f64, p: DVec3, d: DVec3) -> (Option<f64>, Option<f64>) {
    if c == 0.0 {
        return (plane_root(p, d), None);
    }
    let kk = 1.0 + k;
    let NearestQuadratic { t0, p0, a, b, cc } = NearestQuadratic::new(c, kk, p, d);
    let on_branch = |s: f64| -> Option<f64> {
        let t = t0 + s;
        (s.is_finite() && t.is_finite() && on_conic_vertex_branch(p0 + d * s, c, kk)).then_some(t)
    };
    if a == 0.0 {
        // Linear: 2 b s + cc = 0.
        return (if b != 0.0 { on_branch(-cc / (2.0 * b)) } else { None }, None);
    }
    let disc = b * b - a * cc;
    if !(disc >= 0.0) {
        return (None, None);
    }
    let q = -(b + if b >= 0.0 { 1.0 } else { -1.0 } * disc.sqrt());
    let (r1, r2) = if q != 0.0 { (cc / q, q / a) } else { (0.0, 0.0) };
    let (lo, hi) = if r1 <= r2 { (r1, r2) } else { (r2, r1) };
    match (on_branch(lo), on_branch(hi)) {
        (None, h) => (h, None),
        (l, h) => (l, h),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sphere(r: f64, sd: f64) -> SurfacePatch {
        SurfacePatch::new(SurfaceShape::Conic { curvature: 1.0 / r, conic: 0.0 }, Aperture::circular(sd)).unwrap()
    }

    #[test]
    fn plane_patch_respects_aperture_and_interval() {
        let p = SurfacePatch::new(SurfaceShape::Plane, Aperture::circular(2.0)).unwrap();
        assert_eq!(p.first_hit(DVec3::new(1.0, 0.0, -1.0), DVec3::Z, 0.0, 10.0), Some(1.0));
        assert_eq!(p.first_hit(DVec3::new(3.0, 0.0, -1.0), DVec3::Z, 0.0, 10.0), None);
        assert_eq!(p.first_hit(DVec3::new(1.0, 0.0, -1.0), DVec3::Z, 0.0, 0.5), None);
        assert_eq!(p.first_hit(DVec3::new(1.0, 0.0, 1.0), -DVec3::Z, 0.0, 10.0), Some(1.0));
        assert_eq!(p.first_hit(DVec3::new(1.0, 0.0, -1.0), DVec3::X, 0.0, 10.0), None);
    }

    #[test]
    fn sphere_first_hit_matches_sequential_root_and_backside() {
        let s = sphere(33.34, 12.7);
        for x in [0.0, 3.0, 9.0, 12.5] {
            let p = DVec3::new(x, 0.5, -4.0);
            let seq = crate::surfaces::intersect(&s.shape, p, DVec3::Z).unwrap().t;
            let t = s.first_hit(p, DVec3::Z, 0.0, f64::INFINITY).unwrap();
            assert!((t - seq).abs() < 1e-12, "{x}: {t} vs {seq}");
            // From behind (inside the lens) the same point.
            let q = p + DVec3::Z * (t + 2.0);
            let back = s.first_hit(q, -DVec3::Z, 0.0, f64::INFINITY).unwrap();
            assert!((back - 2.0).abs() < 1e-12);
        }
        // The far half of the sphere (z > R) is not part of the patch.
        assert!(s.first_hit(DVec3::new(0.0, 0.0, 40.0), DVec3::Z, 0.0, f64::INFINITY).is_none());
    }

    #[test]
    fn asphere_first_root_and_nearest_root() {
        let shape = SurfaceShape::EvenAsphere { curvature: 1.0 / 40.0, conic: -1.0, coefficients: vec![0.0, 1e-5, -2e-8] };
        let a = SurfacePatch::new(shape.clone(), Aperture::circular(10.0)).unwrap();
        for (x, dx) in [(0.0, 0.0), (4.0, 0.1), (-7.0, 0.3), (9.0, -0.5)] {
            let p = DVec3::new(x, 1.0, -3.0);
            let d = DVec3::new(dx, 0.05, 1.0).normalize();
            let t = a.first_hit(p, d, 0.0, f64::INFINITY).unwrap();
            let q = p + d * t;
            assert!((q.z - shape.sag(q.x, q.y)).abs() < 1e-12, "{x}");
            let seq = crate::surfaces::intersect(&shape, p, d).unwrap().t;
            assert!((t - seq).abs() < 1e-10);
            let near = a.nearest_root(p, d, t + 3e-4).unwrap();
            assert!((near - t).abs() < 1e-12);
        }
    }

    #[test]
    fn grazing_ray_finds_a_root_pair_between_samples() {
        // A ray at 89.99° through the vertex of a convex asphere enters there and leaves ≈ 0.035 mm
        // further on, far closer than the 64 samples along the clipped ray (≈ 0.5 mm apart), with f < 0 at
        // every sample: the pair is found through the extremum of f between samples.
        let shape = SurfaceShape::EvenAsphere { curvature: 0.01, conic: -0.5, coefficients: vec![0.0, 5e-5, 2e-6] };
        let a = SurfacePatch::new(shape, Aperture::circular(16.0)).unwrap();
        let th = 89.99f64.to_radians();
        let d = DVec3::new(th.sin(), 0.0, th.cos());
        let t = a.first_hit(-d, d, 0.0, f64::INFINITY).expect("the vertex is hit");
        assert!((t - 1.0).abs() < 1e-9, "{t}");
        assert!((a.nearest_root(-d, d, 1.0 + 1e-4).unwrap() - 1.0).abs() < 1e-9);
    }

    #[test]
    fn grazing_ray_on_plane_and_sphere_is_classified_not_nan() {
        let s = sphere(20.0, 5.0);
        let p = DVec3::new(-10.0, 0.0, s.shape.sag(4.9, 0.0));
        let d = DVec3::new(1.0, 0.0, 1e-9).normalize();
        if let Some(t) = s.first_hit(p, d, 0.0, f64::INFINITY) {
            assert!(t.is_finite());
        }
        let plane = SurfacePatch::new(SurfaceShape::Plane, Aperture::circular(5.0)).unwrap();
        assert_eq!(plane.first_hit(DVec3::new(-10.0, 0.0, 0.0), DVec3::X, 0.0, f64::INFINITY), None);
    }

    /// A saddle-shaped toroid (the YZ curve convex, the rotation concave) over a rectangle: the bounds
    /// hold its figure everywhere on the aperture (a radial sweep along x alone sees only the concave
    /// profile), and its first hits are the sequential tracer's roots.
    #[test]
    fn toroid_bounds_hold_the_figure_and_hits_are_the_sequential_roots() {
        let shape = SurfaceShape::Toroidal { curvature: 1.0 / 20.0, conic: -0.5, coefficients: vec![1e-5], rotation_curvature: -1.0 / 40.0 };
        let ap = Aperture::Rectangular { half_width_x_mm: 6.0, half_width_y_mm: 9.0, decenter_x_mm: 0.5, decenter_y_mm: 0.0 };
        let t = SurfacePatch::new(shape.clone(), ap).unwrap();
        let (lo, hi) = t.local_bounds();
        let (mut zmin, mut zmax) = (f64::INFINITY, f64::NEG_INFINITY);
        for i in 0..=200 {
            for j in 0..=200 {
                let (x, y) = (0.5 - 6.0 + 12.0 * i as f64 / 200.0, -9.0 + 18.0 * j as f64 / 200.0);
                let z = shape.sag(x, y);
                (zmin, zmax) = (zmin.min(z), zmax.max(z));
                assert!(z >= lo.z && z <= hi.z, "sag {z} at ({x}, {y}) outside [{}, {}]", lo.z, hi.z);
            }
        }
        assert!(zmin < -0.3 && zmax > 1.5, "a saddle: {zmin} … {zmax}");
        for (x, y, dx, dy) in [(0.0, 0.0, 0.0, 0.0), (4.0, -7.0, 0.05, 0.1), (-5.0, 8.5, 0.05, 0.0), (6.4, 3.0, 0.0, -0.3)] {
            let (p, d) = (DVec3::new(x, y, -5.0), DVec3::new(dx, dy, 1.0).normalize());
            let hit = t.first_hit(p, d, 0.0, f64::INFINITY).unwrap();
            let seq = crate::surfaces::intersect(&shape, p, d).unwrap().t;
            assert!((hit - seq).abs() < 1e-12, "({x}, {y}): {hit} vs {seq}");
            assert!((t.nearest_root(p, d, hit + 1e-3).unwrap() - seq).abs() < 1e-12);
        }
        // A YZ conic undefined inside the aperture is an error naming the point.
        let steep = SurfaceShape::Toroidal { curvature: 1.0 / 5.0, conic: 0.0, coefficients: vec![], rotation_curvature: 0.0 };
        let e = SurfacePatch::new(steep, Aperture::Rectangular { half_width_x_mm: 1.0, half_width_y_mm: 6.0, decenter_x_mm: 0.0, decenter_y_mm: 0.0 }).unwrap_err();
        assert!(e.contains("undefined at (x, y)"), "{e}");
    }

    #[test]
    fn bounds_contain_the_patch_and_bad_patches_are_errors() {
        let s = sphere(-15.0, 12.0);
        let (lo, hi) = s.local_bounds();
        for i in 0..=100 {
            let r = 12.0 * i as f64 / 100.0;
            let z = s.shape.sag(r, 0.0);
            assert!(z >= lo.z && z <= hi.z && r <= hi.x && -r >= lo.x);
        }
        assert!(SurfacePatch::new(SurfaceShape::Plane, Aperture::None).is_err());
        assert!(SurfacePatch::new(SurfaceShape::Conic { curvature: 1.0 / 5.0, conic: 0.0 }, Aperture::circular(6.0)).is_err());
    }
}
