//! Fixed-width lane arrays: `LANES` f64 values (or booleans) operated on element by element.
//!
//! Every operation is a plain loop over `[f64; LANES]` marked `#[inline(always)]`, so it inlines into the
//! `#[target_feature]` function that runs the kernel and LLVM compiles it to that target's vectors (one
//! zmm with AVX-512, two ymm with AVX2, four xmm with SSE2). Each lane does exactly the IEEE operation the
//! scalar code does — `+ − × ÷ √` are correctly rounded in every instruction set and Rust never contracts
//! `a * b + c` into a fused multiply-add — so a lane's result is bit for bit the scalar one.
//!
//! ```ignore
//! let a = Lf::splat(2.0);
//! let b = a * a + Lf::splat(1.0); // [5.0; LANES]
//! let m = b.gt(Lf::splat(4.0));   // all true
//! ```
// Index loops over 0..LANES are the idiom LLVM vectorises into whole registers; keep them explicit.
#![allow(clippy::needless_range_loop)]
use std::ops::{Add, BitAnd, BitOr, Div, Mul, Neg, Not, Sub};

/// Rays traced side by side in one block.
pub const LANES: usize = 32;

/// `LANES` f64 values.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C, align(64))]
pub struct Lf(pub [f64; LANES]);

/// `LANES` booleans (a per-lane mask).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Lm(pub [bool; LANES]);

macro_rules! binop {
    ($tr:ident, $f:ident, $op:tt) => {
        impl $tr for Lf {
            type Output = Lf;
            #[inline(always)]
            fn $f(self, o: Lf) -> Lf {
                let mut r = [0.0; LANES];
                for k in 0..LANES {
                    r[k] = self.0[k] $op o.0[k];
                }
                Lf(r)
            }
        }
        impl $tr<f64> for Lf {
            type Output = Lf;
            #[inline(always)]
            fn $f(self, o: f64) -> Lf {
                let mut r = [0.0; LANES];
                for k in 0..LANES {
                    r[k] = self.0[k] $op o;
                }
                Lf(r)
            }
        }
        impl $tr<Lf> for f64 {
            type Output = Lf;
            #[inline(always)]
            fn $f(self, o: Lf) -> Lf {
                let mut r = [0.0; LANES];
                for k in 0..LANES {
                    r[k] = self $op o.0[k];
                }
                Lf(r)
            }
        }
    };
}
binop!(Add, add, +);
binop!(Sub, sub, -);
binop!(Mul, mul, *);
binop!(Div, div, /);

impl Neg for Lf {
    type Output = Lf;
    #[inline(always)]
    fn neg(self) -> Lf {
        self.map(|x| -x)
    }
}

macro_rules! cmp {
    ($name:ident, $op:tt) => {
        #[inline(always)]
        pub fn $name(self, o: Lf) -> Lm {
            let mut r = [false; LANES];
            for k in 0..LANES {
                r[k] = self.0[k] $op o.0[k];
            }
            Lm(r)
        }
    };
}

impl Lf {
    #[inline(always)]
    pub fn splat(v: f64) -> Lf {
        Lf([v; LANES])
    }
    #[inline(always)]
    pub fn map(self, f: impl Fn(f64) -> f64) -> Lf {
        let mut r = [0.0; LANES];
        for k in 0..LANES {
            r[k] = f(self.0[k]);
        }
        Lf(r)
    }
    #[inline(always)]
    pub fn sqrt(self) -> Lf {
        self.map(f64::sqrt)
    }
    #[inline(always)]
    pub fn abs(self) -> Lf {
        self.map(f64::abs)
    }
    /// `f64::signum` per lane (±1 by the sign bit, NaN for NaN).
    #[inline(always)]
    pub fn signum(self) -> Lf {
        self.map(f64::signum)
    }
    #[inline(always)]
    pub fn is_finite(self) -> Lm {
        let mut r = [false; LANES];
        for k in 0..LANES {
            r[k] = self.0[k].is_finite();
        }
        Lm(r)
    }
    cmp!(lt, <);
    cmp!(le, <=);
    cmp!(gt, >);
    cmp!(ge, >=);
    cmp!(eq, ==);
    cmp!(ne, !=);
    /// `a` where `m`, else `b`.
    #[inline(always)]
    pub fn select(m: Lm, a: Lf, b: Lf) -> Lf {
        let mut r = [0.0; LANES];
        for k in 0..LANES {
            r[k] = if m.0[k] { a.0[k] } else { b.0[k] };
        }
        Lf(r)
    }
}

impl Lm {
    #[inline(always)]
    pub fn splat(v: bool) -> Lm {
        Lm([v; LANES])
    }
    #[inline(always)]
    pub fn any(self) -> bool {
        let mut r = false;
        for k in 0..LANES {
            r |= self.0[k];
        }
        r
    }
}

impl BitAnd for Lm {
    type Output = Lm;
    #[inline(always)]
    fn bitand(self, o: Lm) -> Lm {
        let mut r = [false; LANES];
        for k in 0..LANES {
            r[k] = self.0[k] & o.0[k];
        }
        Lm(r)
    }
}
impl BitOr for Lm {
    type Output = Lm;
    #[inline(always)]
    fn bitor(self, o: Lm) -> Lm {
        let mut r = [false; LANES];
        for k in 0..LANES {
            r[k] = self.0[k] | o.0[k];
        }
        Lm(r)
    }
}
impl Not for Lm {
    type Output = Lm;
    #[inline(always)]
    fn not(self) -> Lm {
        let mut r = [false; LANES];
        for k in 0..LANES {
            r[k] = !self.0[k];
        }
        Lm(r)
    }
}

/// Three lane arrays: a vector per lane.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct L3 {
    pub x: Lf,
    pub y: Lf,
    pub z: Lf,
}

impl L3 {
    #[inline(always)]
    pub fn splat(v: glam::DVec3) -> L3 {
        L3 { x: Lf::splat(v.x), y: Lf::splat(v.y), z: Lf::splat(v.z) }
    }
    /// glam's `dot`: (x·x′ + y·y′) + z·z′.
    #[inline(always)]
    pub fn dot(self, o: L3) -> Lf {
        self.x * o.x + self.y * o.y + self.z * o.z
    }
    /// `self + d·t` per lane (glam's `p + d * t`).
    #[inline(always)]
    pub fn along(self, d: L3, t: Lf) -> L3 {
        L3 { x: self.x + d.x * t, y: self.y + d.y * t, z: self.z + d.z * t }
    }
    #[inline(always)]
    pub fn scale(self, s: Lf) -> L3 {
        L3 { x: self.x * s, y: self.y * s, z: self.z * s }
    }
    /// glam's `normalize`: v · (1 / √(v·v)).
    #[inline(always)]
    pub fn normalize(self) -> L3 {
        let r = 1.0 / self.dot(self).sqrt();
        self.scale(r)
    }
    #[inline(always)]
    pub fn is_finite(self) -> Lm {
        self.x.is_finite() & self.y.is_finite() & self.z.is_finite()
    }
    #[inline(always)]
    pub fn select(m: Lm, a: L3, b: L3) -> L3 {
        L3 { x: Lf::select(m, a.x, b.x), y: Lf::select(m, a.y, b.y), z: Lf::select(m, a.z, b.z) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    #[test]
    fn lane_ops_are_the_scalar_ops() {
        let vals = [1.0, -2.0, 0.5, f64::NAN, 3.0, -0.0, 1e300, 7.0];
        let a = Lf(std::array::from_fn(|k| vals[k % 8]));
        let b = Lf::splat(3.0);
        let s = (a * b + a / b - 1.0).sqrt();
        for k in 0..LANES {
            let e = (a.0[k] * 3.0 + a.0[k] / 3.0 - 1.0).sqrt();
            assert!(s.0[k].to_bits() == e.to_bits() || (s.0[k].is_nan() && e.is_nan()), "lane {k}");
        }
        assert_eq!(a.signum().0[5], -1.0);
        assert!(a.signum().0[3].is_nan());
        let m = a.gt(Lf::splat(0.0));
        let pos = [true, false, true, false, true, false, true, true];
        assert_eq!(m.0, std::array::from_fn(|k| pos[k % 8]));
        assert_eq!(Lf::select(m, a, b).0[1], 3.0);
        assert!(m.any() && !Lm::splat(false).any());
        assert_eq!((!m & m).any(), false);
    }
}
