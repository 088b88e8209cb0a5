//! Forward-mode dual numbers with a tangent per free parameter, for the system-level derivatives
//! (frames, coordinate breaks, pickups, chief-ray solves, the paraxial pupil). These run once per system,
//! not per ray, so a heap-allocated tangent is fine; the per-ray kernel uses plain `DVec3` tangents.
//!
//! ```
//! use diffcassi::diff::dual::Dn;
//! let x = Dn::seed(0.5, 2, 0);          // x = 0.5, dx/dθ₀ = 1
//! let y = Dn::seed(2.0, 2, 1);          // y = 2,   dy/dθ₁ = 1
//! let z = &x.sin() * &y;                // z = y sin x
//! assert!((z.d[0] - 2.0 * 0.5f64.cos()).abs() < 1e-15);
//! assert!((z.d[1] - 0.5f64.sin()).abs() < 1e-15);
//! ```
use glam::{DMat3, DVec3};
use std::ops::{Add, Div, Mul, Neg, Sub};

/// A value and its derivatives with respect to K parameters.
#[derive(Clone, Debug, PartialEq)]
pub struct Dn {
    pub v: f64,
    pub d: Vec<f64>,
}

impl Dn {
    /// A constant (zero tangent) among `k` parameters.
    pub fn constant(v: f64, k: usize) -> Dn {
        Dn { v, d: vec![0.0; k] }
    }
    /// The `i`-th of `k` parameters, with value `v`.
    pub fn seed(v: f64, k: usize, i: usize) -> Dn {
        let mut d = vec![0.0; k];
        d[i] = 1.0;
        Dn { v, d }
    }
    pub fn new(v: f64, d: Vec<f64>) -> Dn {
        Dn { v, d }
    }
    pub fn k(&self) -> usize {
        self.d.len()
    }
    /// Chain rule for a scalar function with value `v` and derivative `dv` at `self.v`.
    pub fn chain(&self, v: f64, dv: f64) -> Dn {
        Dn { v, d: self.d.iter().map(|x| x * dv).collect() }
    }
    pub fn scale(&self, s: f64) -> Dn {
        self.chain(self.v * s, s)
    }
    pub fn sin(&self) -> Dn {
        self.chain(self.v.sin(), self.v.cos())
    }
    pub fn cos(&self) -> Dn {
        self.chain(self.v.cos(), -self.v.sin())
    }
    pub fn sqrt(&self) -> Dn {
        let s = self.v.sqrt();
        self.chain(s, 0.5 / s)
    }
    pub fn recip(&self) -> Dn {
        self.chain(1.0 / self.v, -1.0 / (self.v * self.v))
    }
    pub fn tan(&self) -> Dn {
        let t = self.v.tan();
        self.chain(t, 1.0 + t * t)
    }
    pub fn atan(&self) -> Dn {
        self.chain(self.v.atan(), 1.0 / (1.0 + self.v * self.v))
    }
    /// atan2(self, x): d = (x dy − y dx)/(x² + y²).
    pub fn atan2(&self, x: &Dn) -> Dn {
        let r2 = self.v * self.v + x.v * x.v;
        let d = self.d.iter().zip(&x.d).map(|(dy, dx)| (x.v * dy - self.v * dx) / r2).collect();
        Dn { v: self.v.atan2(x.v), d }
    }
    pub fn is_constant(&self) -> bool {
        self.d.iter().all(|x| *x == 0.0)
    }
}

fn zip(a: &Dn, b: &Dn, v: f64, fa: f64, fb: f64) -> Dn {
    Dn { v, d: a.d.iter().zip(&b.d).map(|(x, y)| fa * x + fb * y).collect() }
}

impl Add for &Dn {
    type Output = Dn;
    fn add(self, b: &Dn) -> Dn {
        zip(self, b, self.v + b.v, 1.0, 1.0)
    }
}
impl Sub for &Dn {
    type Output = Dn;
    fn sub(self, b: &Dn) -> Dn {
        zip(self, b, self.v - b.v, 1.0, -1.0)
    }
}
impl Mul for &Dn {
    type Output = Dn;
    fn mul(self, b: &Dn) -> Dn {
        zip(self, b, self.v * b.v, b.v, self.v)
    }
}
impl Div for &Dn {
    type Output = Dn;
    fn div(self, b: &Dn) -> Dn {
        let q = self.v / b.v;
        zip(self, b, q, 1.0 / b.v, -q / b.v)
    }
}
impl Neg for &Dn {
    type Output = Dn;
    fn neg(self) -> Dn {
        self.scale(-1.0)
    }
}
macro_rules! owned_ops {
    ($tr:ident, $f:ident) => {
        impl $tr for Dn {
            type Output = Dn;
            fn $f(self, b: Dn) -> Dn {
                (&self).$f(&b)
            }
        }
        impl $tr<&Dn> for Dn {
            type Output = Dn;
            fn $f(self, b: &Dn) -> Dn {
                (&self).$f(b)
            }
        }
        impl $tr<Dn> for &Dn {
            type Output = Dn;
            fn $f(self, b: Dn) -> Dn {
                self.$f(&b)
            }
        }
    };
}
owned_ops!(Add, add);
owned_ops!(Sub, sub);
owned_ops!(Mul, mul);
owned_ops!(Div, div);

/// A 3-vector of duals.
pub type V3 = [Dn; 3];
/// A 3×3 matrix of duals, row-major: `m[row][col]`.
pub type M3 = [[Dn; 3]; 3];

pub fn v3_const(v: DVec3, k: usize) -> V3 {
    [Dn::constant(v.x, k), Dn::constant(v.y, k), Dn::constant(v.z, k)]
}
/// A vector from its value and per-parameter tangents.
pub fn v3_from(v: DVec3, d: &[DVec3]) -> V3 {
    [
        Dn::new(v.x, d.iter().map(|t| t.x).collect()),
        Dn::new(v.y, d.iter().map(|t| t.y).collect()),
        Dn::new(v.z, d.iter().map(|t| t.z).collect()),
    ]
}
pub fn v3_value(a: &V3) -> DVec3 {
    DVec3::new(a[0].v, a[1].v, a[2].v)
}
pub fn v3_tangent(a: &V3, k: usize) -> DVec3 {
    DVec3::new(a[0].d[k], a[1].d[k], a[2].d[k])
}
pub fn v3_add(a: &V3, b: &V3) -> V3 {
    [&a[0] + &b[0], &a[1] + &b[1], &a[2] + &b[2]]
}
pub fn v3_sub(a: &V3, b: &V3) -> V3 {
    [&a[0] - &b[0], &a[1] - &b[1], &a[2] - &b[2]]
}
pub fn v3_scale(a: &V3, s: &Dn) -> V3 {
    [&a[0] * s, &a[1] * s, &a[2] * s]
}
pub fn v3_dot(a: &V3, b: &V3) -> Dn {
    &(&a[0] * &b[0]) + &(&(&a[1] * &b[1]) + &(&a[2] * &b[2]))
}
pub fn v3_normalize(a: &V3) -> V3 {
    let inv = v3_dot(a, a).sqrt().recip();
    v3_scale(a, &inv)
}

pub fn m3_const(m: DMat3, k: usize) -> M3 {
    let c = m.to_cols_array_2d(); // c[col][row]
    std::array::from_fn(|r| std::array::from_fn(|col| Dn::constant(c[col][r], k)))
}
pub fn m3_value(m: &M3) -> DMat3 {
    DMat3::from_cols(
        DVec3::new(m[0][0].v, m[1][0].v, m[2][0].v),
        DVec3::new(m[0][1].v, m[1][1].v, m[2][1].v),
        DVec3::new(m[0][2].v, m[1][2].v, m[2][2].v),
    )
}
pub fn m3_tangent(m: &M3, k: usize) -> DMat3 {
    DMat3::from_cols(
        DVec3::new(m[0][0].d[k], m[1][0].d[k], m[2][0].d[k]),
        DVec3::new(m[0][1].d[k], m[1][1].d[k], m[2][1].d[k]),
        DVec3::new(m[0][2].d[k], m[1][2].d[k], m[2][2].d[k]),
    )
}
pub fn m3_mul(a: &M3, b: &M3) -> M3 {
    std::array::from_fn(|r| std::array::from_fn(|c| &(&(&a[r][0] * &b[0][c]) + &(&a[r][1] * &b[1][c])) + &(&a[r][2] * &b[2][c])))
}
pub fn m3_mul_v3(a: &M3, v: &V3) -> V3 {
    std::array::from_fn(|r| &(&(&a[r][0] * &v[0]) + &(&a[r][1] * &v[1])) + &(&a[r][2] * &v[2]))
}
pub fn m3_transpose(a: &M3) -> M3 {
    std::array::from_fn(|r| std::array::from_fn(|c| a[c][r].clone()))
}
/// Column `c` (a local axis in the parent frame).
pub fn m3_col(a: &M3, c: usize) -> V3 {
    [a[0][c].clone(), a[1][c].clone(), a[2][c].clone()]
}

/// Right-handed rotations about x, y, z by an angle in radians (same matrices as [`crate::geometry::rot_x`] …).
pub fn rot_x(a: &Dn) -> M3 {
    let k = a.k();
    let (s, c) = (a.sin(), a.cos());
    let (z, o) = (Dn::constant(0.0, k), Dn::constant(1.0, k));
    [[o, z.clone(), z.clone()], [z.clone(), c.clone(), -&s], [z, s, c]]
}
pub fn rot_y(b: &Dn) -> M3 {
    let k = b.k();
    let (s, c) = (b.sin(), b.cos());
    let (z, o) = (Dn::constant(0.0, k), Dn::constant(1.0, k));
    [[c.clone(), z.clone(), s.clone()], [z.clone(), o, z.clone()], [-&s, z, c]]
}
pub fn rot_z(g: &Dn) -> M3 {
    let k = g.k();
    let (s, c) = (g.sin(), g.cos());
    let (z, o) = (Dn::constant(0.0, k), Dn::constant(1.0, k));
    [[c.clone(), -&s, z.clone()], [s, c, z.clone()], [z.clone(), z, o]]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rotations_match_geometry() {
        for &a in &[0.3, -1.2, 2.5] {
            let d = Dn::constant(a, 1);
            assert!((m3_value(&rot_x(&d)) - crate::geometry::rot_x(a)).to_cols_array().iter().all(|v| v.abs() < 1e-15));
            assert!((m3_value(&rot_y(&d)) - crate::geometry::rot_y(a)).to_cols_array().iter().all(|v| v.abs() < 1e-15));
            assert!((m3_value(&rot_z(&d)) - crate::geometry::rot_z(a)).to_cols_array().iter().all(|v| v.abs() < 1e-15));
        }
    }

    #[test]
    fn derivative_of_rotation_matches_finite_difference() {
        let a = 0.7;
        let h = 1e-6;
        let r = rot_y(&Dn::seed(a, 1, 0));
        let fd = (crate::geometry::rot_y(a + h) - crate::geometry::rot_y(a - h)) * (0.5 / h);
        assert!((m3_tangent(&r, 0) - fd).to_cols_array().iter().all(|v| v.abs() < 1e-9));
    }
}
