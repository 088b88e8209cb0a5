//! OpticStudio's Toroidal surface: a curve in the YZ plane,
//! z_y(y) = c y² / (1 + √(1 − (1+k) c² y²)) + Σᵢ αᵢ y^(2i),
//! rotated about an axis parallel to y at the distance R (the "radius of rotation", the X radius; the axis
//! crosses z at R). With u = R − z_y the surface is z = R − sgn(R)·√(u² − x²), written here without
//! cancellation as
//!
//! z = z_y + c_u x² / (1 + w),  c_u = 1/u = c_R / (1 − c_R z_y),  w = √(1 − c_u² x²),  c_R = 1/R,
//!
//! so c_R = 0 (R infinite, OpticStudio's "0") is the cylinder z = z_y(y). Its partial derivatives:
//! z_x = c_u x / w, z_y = z_y′ / w, z_xx = c_u / w³, z_xy = c_u² x z_y′ / w³,
//! z_yy = z_y″ / w + c_u³ x² z_y′² / w³.
//!
//! Reference: the OpticStudio manual ("Toroidal" surface: radius of rotation, 0 = infinite; parameters
//! 2 … 9 the y^2 … y^16 coefficients), and rayoptics' `YToroid` profile (`elem/profiles.py`), the independent
//! reader the tests compare against.

/// The YZ curve's sag z_y(y) and its first two derivatives in y: (z_y, z_y′, z_y″); NaN outside the conic's domain.
#[inline]
pub fn yz_curve(c: f64, k: f64, alpha: &[f64], y: f64) -> (f64, f64, f64) {
    let y2 = y * y;
    let disc = 1.0 - (1.0 + k) * c * c * y2;
    if disc < 0.0 {
        return (f64::NAN, f64::NAN, f64::NAN);
    }
    let s = disc.sqrt();
    let mut z = c * y2 / (1.0 + s);
    // f(y²) with f′ = c/(2s), f″ = (1+k)c³/(4s³); z_y′ = 2y f′, z_y″ = 2f′ + 4y² f″.
    let (mut f1, mut f2) = if c != 0.0 { (c / (2.0 * s), (1.0 + k) * c * c * c / (4.0 * s * s * s)) } else { (0.0, 0.0) };
    let (mut pw, mut prev) = (1.0, 0.0); // y2^j and y2^(j−1)
    for (j, a) in alpha.iter().enumerate() {
        let i = (j + 1) as f64;
        z += a * pw * y2;
        f1 += i * a * pw;
        if j >= 1 {
            f2 += i * (i - 1.0) * a * prev;
        }
        prev = pw;
        pw *= y2;
    }
    (z, 2.0 * y * f1, 2.0 * f1 + 4.0 * y2 * f2)
}

/// Local data of the toroid at (x, y): sag, gradient (z_x, z_y) and Hessian (z_xx, z_xy, z_yy). NaN outside its domain.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ToroidLocal {
    pub sag: f64,
    pub grad: (f64, f64),
    pub hessian: (f64, f64, f64),
}

/// The toroid (c, k, α of the YZ curve; c_R = 1/R, 0 for a cylinder) at (x, y).
#[inline]
pub fn toroid_local(c: f64, k: f64, alpha: &[f64], c_rot: f64, x: f64, y: f64) -> ToroidLocal {
    let (zy, zy1, zy2) = yz_curve(c, k, alpha, y);
    let cu = c_rot / (1.0 - c_rot * zy);
    let x2 = x * x;
    let w2 = 1.0 - cu * cu * x2;
    if !(w2 >= 0.0) || !zy.is_finite() {
        let nan = f64::NAN;
        return ToroidLocal { sag: nan, grad: (nan, nan), hessian: (nan, nan, nan) };
    }
    let w = w2.sqrt();
    let w3 = w * w2;
    ToroidLocal {
        sag: zy + cu * x2 / (1.0 + w),
        grad: (cu * x / w, zy1 / w),
        hessian: (cu / w3, cu * cu * x * zy1 / w3, zy2 / w + cu * cu * cu * x2 * zy1 * zy1 / w3),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sphere_when_both_radii_agree() {
        // c = c_R = 1/R, k = 0: the sphere of radius R.
        let r: f64 = 25.0;
        let (x, y) = (3.0, -4.0);
        let t = toroid_local(1.0 / r, 0.0, &[], 1.0 / r, x, y);
        let sphere = r - (r * r - x * x - y * y).sqrt();
        assert!((t.sag - sphere).abs() < 1e-14, "{} vs {sphere}", t.sag);
    }

    #[test]
    fn cylinder_limit_ignores_x() {
        let a = toroid_local(0.1, -0.5, &[1e-4], 0.0, 7.0, 2.0);
        let b = toroid_local(0.1, -0.5, &[1e-4], 0.0, 0.0, 2.0);
        assert_eq!(a.sag, b.sag);
        assert_eq!(a.grad.0, 0.0);
        assert!(toroid_local(0.1, -0.5, &[1e-4], 1e-12, 7.0, 2.0).sag - a.sag < 1e-9);
    }

    #[test]
    fn derivatives_match_finite_differences() {
        let (c, k, al, cr) = (0.03, -0.7, [2e-4, -3e-6, 1e-8], -0.02);
        let f = |x: f64, y: f64| toroid_local(c, k, &al, cr, x, y);
        let (x, y, h) = (2.5, -3.5, 1e-5);
        let t = f(x, y);
        let gx = (f(x + h, y).sag - f(x - h, y).sag) / (2.0 * h);
        let gy = (f(x, y + h).sag - f(x, y - h).sag) / (2.0 * h);
        assert!((t.grad.0 - gx).abs() < 1e-9 && (t.grad.1 - gy).abs() < 1e-9);
        let hxx = (f(x + h, y).grad.0 - f(x - h, y).grad.0) / (2.0 * h);
        let hxy = (f(x, y + h).grad.0 - f(x, y - h).grad.0) / (2.0 * h);
        let hyx = (f(x + h, y).grad.1 - f(x - h, y).grad.1) / (2.0 * h);
        let hyy = (f(x, y + h).grad.1 - f(x, y - h).grad.1) / (2.0 * h);
        assert!((t.hessian.0 - hxx).abs() < 1e-8 && (t.hessian.1 - hxy).abs() < 1e-8 && (t.hessian.1 - hyx).abs() < 1e-8 && (t.hessian.2 - hyy).abs() < 1e-8, "{t:?} {hxx} {hxy} {hyx} {hyy}");
        // At y = 0 the series' second derivative is 2α₁ + the conic's c.
        let t0 = f(0.0, 0.0);
        assert!((t0.hessian.2 - (c + 2.0 * al[0])).abs() < 1e-15);
    }
}
