use glam::DVec3;

/// The figure of a refracting surface, in its local frame (mm).
#[derive(Clone, Debug, PartialEq)]
pub enum SurfaceShape {
    /// z = 0.
    Plane,
    /// Zemax "Standard": z = c r² / (1 + √(1 − (1+k) c² r²)); c = 1/R (mm⁻¹), k the conic constant.
    Conic { curvature: f64, conic: f64 },
    /// Zemax "Even Asphere": the conic sag plus Σᵢ αᵢ r^(2i), i = 1..=8 (`coefficients[0]` multiplies r²).
    EvenAsphere { curvature: f64, conic: f64, coefficients: Vec<f64> },
    /// Zemax "Paraxial": an ideal thin lens in the plane z = 0 of focal length f (mm). It maps direction
    /// tangents as tan′ = tan − h / f (in air), which images every object plane perfectly.
    Paraxial { focal_length: f64 },
    /// Zemax "Toroidal" ([`super::toroidal`]): the YZ curve (curvature, conic, Σᵢ αᵢ y^(2i)) rotated about
    /// an axis parallel to y at the radius of rotation 1/`rotation_curvature` (0: a cylinder).
    Toroidal { curvature: f64, conic: f64, coefficients: Vec<f64>, rotation_curvature: f64 },
}

impl SurfaceShape {
    /// Sag z(x, y) in mm. Outside a conic's domain (1 − (1+k)c²r² < 0) returns NaN.
    pub fn sag(&self, x: f64, y: f64) -> f64 {
        let r2 = x * x + y * y;
        match self {
            SurfaceShape::Plane | SurfaceShape::Paraxial { .. } => 0.0,
            SurfaceShape::Conic { curvature, conic } => conic_sag(*curvature, *conic, r2),
            SurfaceShape::EvenAsphere { curvature, conic, coefficients } => {
                conic_sag(*curvature, *conic, r2) + asphere_poly(coefficients, r2).0
            }
            SurfaceShape::Toroidal { curvature, conic, coefficients, rotation_curvature } => {
                super::toroidal::toroid_local(*curvature, *conic, coefficients, *rotation_curvature, x, y).sag
            }
        }
    }

    /// Unit surface normal at local (x, y) on the surface, oriented toward +z (n·ẑ > 0 at the vertex).
    pub fn normal(&self, p: DVec3) -> DVec3 {
        match self {
            SurfaceShape::Plane | SurfaceShape::Paraxial { .. } => DVec3::Z,
            SurfaceShape::Conic { curvature: c, conic: k } => {
                // ∇F for F = c(x²+y²+(1+k)z²) − 2z, negated to point along +z.
                DVec3::new(-c * p.x, -c * p.y, 1.0 - c * (1.0 + k) * p.z).normalize()
            }
            SurfaceShape::EvenAsphere { .. } | SurfaceShape::Toroidal { .. } => {
                let (dzdx, dzdy) = self.sag_gradient(p.x, p.y);
                DVec3::new(-dzdx, -dzdy, 1.0).normalize()
            }
        }
    }

    /// (∂z/∂x, ∂z/∂y) of the sag.
    pub fn sag_gradient(&self, x: f64, y: f64) -> (f64, f64) {
        if let SurfaceShape::Toroidal { curvature, conic, coefficients, rotation_curvature } = self {
            return super::toroidal::toroid_local(*curvature, *conic, coefficients, *rotation_curvature, x, y).grad;
        }
        let r2 = x * x + y * y;
        let dz_dr2 = match self {
            SurfaceShape::Plane | SurfaceShape::Paraxial { .. } => 0.0,
            SurfaceShape::Conic { curvature, conic } => conic_dsag_dr2(*curvature, *conic, r2),
            SurfaceShape::EvenAsphere { curvature, conic, coefficients } => {
                conic_dsag_dr2(*curvature, *conic, r2) + asphere_poly(coefficients, r2).1
            }
            SurfaceShape::Toroidal { .. } => unreachable!("handled above"),
        };
        (2.0 * x * dz_dr2, 2.0 * y * dz_dr2)
    }
}

/// Conic sag written as c r² / (1 + √(1 − (1+k)c²r²)) — no cancellation as c → 0.
#[inline]
pub fn conic_sag(c: f64, k: f64, r2: f64) -> f64 {
    let disc = 1.0 - (1.0 + k) * c * c * r2;
    if disc < 0.0 {
        return f64::NAN;
    }
    c * r2 / (1.0 + disc.sqrt())
}

/// d(sag)/d(r²) of the conic: c / (2 √(1 − (1+k)c²r²)).
#[inline]
fn conic_dsag_dr2(c: f64, k: f64, r2: f64) -> f64 {
    let disc = 1.0 - (1.0 + k) * c * c * r2;
    if disc <= 0.0 {
        return f64::NAN;
    }
    c / (2.0 * disc.sqrt())
}

/// Σᵢ αᵢ (r²)^i and its derivative with respect to r², by Horner's rule.
#[inline]
fn asphere_poly(coefficients: &[f64], r2: f64) -> (f64, f64) {
    let mut value = 0.0;
    let mut deriv = 0.0;
    for (i, a) in coefficients.iter().enumerate().rev() {
        let power = (i + 1) as f64;
        value = (value + a) * r2;
        deriv = deriv * r2 + power * a;
    }
    // deriv accumulated Σ i αᵢ r2^(i−1) in Horner form
    (value, deriv)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn asphere_poly_matches_direct_sum() {
        let co = [1e-3, -2e-5, 3e-7, 4e-9];
        let r2: f64 = 7.3;
        let direct: f64 = co.iter().enumerate().map(|(i, a)| a * r2.powi(i as i32 + 1)).sum();
        let dderiv: f64 = co.iter().enumerate().map(|(i, a)| (i as f64 + 1.0) * a * r2.powi(i as i32)).sum();
        let (v, d) = asphere_poly(&co, r2);
        assert!((v - direct).abs() < 1e-15);
        assert!((d - dderiv).abs() < 1e-15);
    }

    #[test]
    fn tiny_curvature_is_plane_like() {
        let s = SurfaceShape::Conic { curvature: 1e-12, conic: 0.0 };
        assert!(s.sag(10.0, 0.0).abs() < 1e-9);
        assert!((s.normal(DVec3::new(10.0, 0.0, 0.0)) - DVec3::Z).length() < 1e-10);
    }

    #[test]
    fn normal_matches_gradient() {
        let s = SurfaceShape::EvenAsphere { curvature: 0.02, conic: -0.5, coefficients: vec![1e-4, -1e-6] };
        let c = SurfaceShape::Conic { curvature: 0.02, conic: -0.5 };
        let p = DVec3::new(3.0, -4.0, c.sag(3.0, -4.0));
        let n_conic = c.normal(p);
        let (gx, gy) = c.sag_gradient(3.0, -4.0);
        let n_grad = DVec3::new(-gx, -gy, 1.0).normalize();
        assert!((n_conic - n_grad).length() < 1e-14);
        // finite-difference gradient of the asphere
        let h = 1e-6;
        let fx = (s.sag(3.0 + h, -4.0) - s.sag(3.0 - h, -4.0)) / (2.0 * h);
        let (ax, _) = s.sag_gradient(3.0, -4.0);
        assert!((fx - ax).abs() < 1e-8);
    }
}
