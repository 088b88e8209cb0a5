//! Fixed-width lane arrays: `N` floats (f64 or f32, the [`Real`] trait) or booleans operated on element by
//! element. One source serves both precisions: the f64 kernel uses [`Lf`] = `Lanes<f64, 32>`, the f32
//! kernel `Lanes<f32, 64>` (the same 256 bytes per array, twice the rays).
//!
//! Every operation is a plain loop over `[T; N]` marked `#[inline(always)]`, so it inlines into the
//! `#[target_feature]` function that runs the kernel and LLVM compiles it to that target's vectors (four
//! zmm with AVX-512, eight ymm with AVX2, sixteen xmm with SSE2 per array). Each lane does exactly the IEEE
//! operation the scalar code does — `+ − × ÷ √` are correctly rounded in every instruction set and Rust
//! never contracts `a * b + c` into a fused multiply-add — so an f64 lane's result is bit for bit the
//! scalar kernel's, and an f32 lane's result is the same on every instruction set.
//!
//! ```ignore
//! let a = Lf::splat(2.0);
//! let b = a * a + Lf::splat(1.0); // [5.0; LANES]
//! let m = b.gt(Lf::splat(4.0));   // all true
//! ```
// Index loops over 0..N are the idiom LLVM vectorises into whole registers; keep them explicit.
#![allow(clippy::needless_range_loop)]
use std::ops::{Add, BitAnd, BitOr, Div, Mul, Neg, Not, Sub};

/// f64 rays traced side by side in one block.
pub const LANES: usize = 32;
/// f32 rays traced side by side in one block: twice [`LANES`], the same bytes per lane array.
pub const LANES_F32: usize = 64;

/// The float type of a lane kernel, with the precision-dependent tolerances of the kernel's tests (the
/// f64 ones are the scalar kernel's, so the f64 lanes stay bit-identical to it; the f32 ones are scaled to
/// f32's rounding, see `docs/performance.md`, "f32 mode").
pub trait Real: Copy + Default + PartialEq + PartialOrd + std::fmt::Debug + Send + Sync + 'static + Add<Output = Self> + Sub<Output = Self> + Mul<Output = Self> + Div<Output = Self> + Neg<Output = Self> {
    /// The type's machine epsilon.
    const EPSILON: Self;
    /// The largest origin coordinate (mm, object frame) a lane accepts: beyond it the rounding of the
    /// origin alone exceeds the precision's error budget, and the ray is an invalid input (f64: no limit).
    const MAX_INPUT_MM: f64;
    /// The nearest value of an f64 (identity for f64).
    fn of(x: f64) -> Self;
    /// As f64 (exact).
    fn to_f64(self) -> f64;
    fn sqrt(self) -> Self;
    fn abs(self) -> Self;
    fn signum(self) -> Self;
    fn is_finite(self) -> bool;
    /// `a` if `m` else `b`, as a bitwise blend of the values (exactly one of them, bit for bit). Written
    /// on the bits so that LLVM emits a register blend: the plain `if m { a[k] } else { b[k] }` over
    /// arrays became an address select and a gather (`vgatherqps`) in the f32 kernel.
    fn blend(m: bool, a: Self, b: Self) -> Self;
    /// Tolerance of the conic vertex-branch test |z − sag| ≤ tol at a hit point of local height `z`
    /// reached at distance `t` from the solve's start.
    fn branch_tol<const N: usize>(z: Lanes<Self, N>, t: Lanes<Self, N>) -> Lanes<Self, N>;
    /// Newton's step test on the even asphere: |t_next − t| ≤ tol.
    fn newton_step_tol<const N: usize>(t: Lanes<Self, N>) -> Lanes<Self, N>;
    /// Newton's residual test |f| < tol (`strict`: the test after the iteration budget is spent).
    fn newton_residual_tol<const N: usize>(t: Lanes<Self, N>, strict: bool) -> Lanes<Self, N>;
}

impl Real for f64 {
    const EPSILON: f64 = f64::EPSILON;
    const MAX_INPUT_MM: f64 = f64::INFINITY;
    #[inline(always)]
    fn of(x: f64) -> f64 {
        x
    }
    #[inline(always)]
    fn to_f64(self) -> f64 {
        self
    }
    #[inline(always)]
    fn sqrt(self) -> f64 {
        f64::sqrt(self)
    }
    #[inline(always)]
    fn abs(self) -> f64 {
        f64::abs(self)
    }
    #[inline(always)]
    fn signum(self) -> f64 {
        f64::signum(self)
    }
    #[inline(always)]
    fn is_finite(self) -> bool {
        f64::is_finite(self)
    }
    #[inline(always)]
    fn blend(m: bool, a: f64, b: f64) -> f64 {
        let mask = (m as u64).wrapping_neg();
        f64::from_bits((a.to_bits() & mask) | (b.to_bits() & !mask))
    }
    /// The scalar kernel's 1e-9·(1 + |z|).
    #[inline(always)]
    fn branch_tol<const N: usize>(z: Lanes<f64, N>, _t: Lanes<f64, N>) -> Lanes<f64, N> {
        1e-9 * (1.0 + z.abs())
    }
    /// The scalar kernel's 1e-15·(1 + |t|).
    #[inline(always)]
    fn newton_step_tol<const N: usize>(t: Lanes<f64, N>) -> Lanes<f64, N> {
        1e-15 * (1.0 + t.abs())
    }
    /// The scalar kernel's 1e-9 (1e-12 after the budget).
    #[inline(always)]
    fn newton_residual_tol<const N: usize>(_t: Lanes<f64, N>, strict: bool) -> Lanes<f64, N> {
        Lanes::splat(if strict { 1e-12 } else { 1e-9 })
    }
}

impl Real for f32 {
    const EPSILON: f32 = f32::EPSILON;
    /// 1 m: an origin coordinate rounds by ≤ 3e-5 mm (0.03 µm).
    const MAX_INPUT_MM: f64 = 1e3;
    #[inline(always)]
    fn of(x: f64) -> f32 {
        x as f32
    }
    #[inline(always)]
    fn to_f64(self) -> f64 {
        self as f64
    }
    #[inline(always)]
    fn sqrt(self) -> f32 {
        f32::sqrt(self)
    }
    #[inline(always)]
    fn abs(self) -> f32 {
        f32::abs(self)
    }
    #[inline(always)]
    fn signum(self) -> f32 {
        f32::signum(self)
    }
    #[inline(always)]
    fn is_finite(self) -> bool {
        f32::is_finite(self)
    }
    #[inline(always)]
    fn blend(m: bool, a: f32, b: f32) -> f32 {
        let mask = (m as u32).wrapping_neg();
        f32::from_bits((a.to_bits() & mask) | (b.to_bits() & !mask))
    }
    /// ≈ 80 ε·(1 + |z| + |t|): the hit point's z carries the rounding of p₀_z + t·d_z, ~ε·|t| (t: the distance
    /// from the solve's start p₀, the line's point nearest the vertex).
    #[inline(always)]
    fn branch_tol<const N: usize>(z: Lanes<f32, N>, t: Lanes<f32, N>) -> Lanes<f32, N> {
        Lanes::splat(1e-5) * (Lanes::splat(1.0) + z.abs() + t.abs())
    }
    /// 8 ε·(1 + |t|) (f64: 1e-15 ≈ 4.5 ε).
    #[inline(always)]
    fn newton_step_tol<const N: usize>(t: Lanes<f32, N>) -> Lanes<f32, N> {
        Lanes::splat(8.0 * f32::EPSILON) * (Lanes::splat(1.0) + t.abs())
    }
    /// 1e-5·(1 + |t|) (1e-6 after the budget): f = z − sag carries ~ε·|t| of rounding.
    #[inline(always)]
    fn newton_residual_tol<const N: usize>(t: Lanes<f32, N>, strict: bool) -> Lanes<f32, N> {
        Lanes::splat(if strict { 1e-6 } else { 1e-5 }) * (Lanes::splat(1.0) + t.abs())
    }
}

/// `N` floats.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C, align(64))]
pub struct Lanes<T, const N: usize>(pub [T; N]);

/// `N` booleans (a per-lane mask).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Mask<const N: usize>(pub [bool; N]);

/// The f64 kernel's lane array.
pub type Lf = Lanes<f64, LANES>;
/// The f64 kernel's mask.
pub type Lm = Mask<LANES>;
/// The f64 kernel's vector of lanes.
pub type L3 = V3<f64, LANES>;

macro_rules! binop {
    ($tr:ident, $f:ident, $op:tt) => {
        impl<T: Real, const N: usize> $tr for Lanes<T, N> {
            type Output = Lanes<T, N>;
            #[inline(always)]
            fn $f(self, o: Lanes<T, N>) -> Lanes<T, N> {
                let mut r = [T::default(); N];
                for k in 0..N {
                    r[k] = self.0[k] $op o.0[k];
                }
                Lanes(r)
            }
        }
        impl<T: Real, const N: usize> $tr<T> for Lanes<T, N> {
            type Output = Lanes<T, N>;
            #[inline(always)]
            fn $f(self, o: T) -> Lanes<T, N> {
                let mut r = [T::default(); N];
                for k in 0..N {
                    r[k] = self.0[k] $op o;
                }
                Lanes(r)
            }
        }
        binop!(@left f64, $tr, $f, $op);
        binop!(@left f32, $tr, $f, $op);
    };
    (@left $t:ty, $tr:ident, $f:ident, $op:tt) => {
        impl<const N: usize> $tr<Lanes<$t, N>> for $t {
            type Output = Lanes<$t, N>;
            #[inline(always)]
            fn $f(self, o: Lanes<$t, N>) -> Lanes<$t, N> {
                let mut r = [0.0; N];
                for k in 0..N {
                    r[k] = self $op o.0[k];
                }
                Lanes(r)
            }
        }
    };
}
binop!(Add, add, +);
binop!(Sub, sub, -);
binop!(Mul, mul, *);
binop!(Div, div, /);

impl<T: Real, const N: usize> Neg for Lanes<T, N> {
    type Output = Lanes<T, N>;
    #[inline(always)]
    fn neg(self) -> Lanes<T, N> {
        self.map(|x| -x)
    }
}

macro_rules! cmp {
    ($name:ident, $op:tt) => {
        #[inline(always)]
        pub fn $name(self, o: Lanes<T, N>) -> Mask<N> {
            let mut r = [false; N];
            for k in 0..N {
                r[k] = self.0[k] $op o.0[k];
            }
            Mask(r)
        }
    };
}

impl<T: Real, const N: usize> Lanes<T, N> {
    #[inline(always)]
    pub fn splat(v: T) -> Self {
        Lanes([v; N])
    }
    /// Every lane the nearest `T` of `v` (the precision's constant of an f64 system value).
    #[inline(always)]
    pub fn of(v: f64) -> Self {
        Lanes([T::of(v); N])
    }
    #[inline(always)]
    pub fn map(self, f: impl Fn(T) -> T) -> Self {
        let mut r = [T::default(); N];
        for k in 0..N {
            r[k] = f(self.0[k]);
        }
        Lanes(r)
    }
    #[inline(always)]
    pub fn sqrt(self) -> Self {
        self.map(T::sqrt)
    }
    #[inline(always)]
    pub fn abs(self) -> Self {
        self.map(T::abs)
    }
    /// `signum` per lane (±1 by the sign bit, NaN for NaN).
    #[inline(always)]
    pub fn signum(self) -> Self {
        self.map(T::signum)
    }
    #[inline(always)]
    pub fn is_finite(self) -> Mask<N> {
        let mut r = [false; N];
        for k in 0..N {
            r[k] = self.0[k].is_finite();
        }
        Mask(r)
    }
    cmp!(lt, <);
    cmp!(le, <=);
    cmp!(gt, >);
    cmp!(ge, >=);
    cmp!(eq, ==);
    cmp!(ne, !=);
    /// `a` where `m`, else `b`.
    #[inline(always)]
    pub fn select(m: Mask<N>, a: Self, b: Self) -> Self {
        let mut r = [T::default(); N];
        for k in 0..N {
            r[k] = T::blend(m.0[k], a.0[k], b.0[k]);
        }
        Lanes(r)
    }
}

impl<const N: usize> Mask<N> {
    #[inline(always)]
    pub fn splat(v: bool) -> Self {
        Mask([v; N])
    }
    #[inline(always)]
    pub fn any(self) -> bool {
        let mut r = false;
        for k in 0..N {
            r |= self.0[k];
        }
        r
    }
}

impl<const N: usize> BitAnd for Mask<N> {
    type Output = Mask<N>;
    #[inline(always)]
    fn bitand(self, o: Mask<N>) -> Mask<N> {
        let mut r = [false; N];
        for k in 0..N {
            r[k] = self.0[k] & o.0[k];
        }
        Mask(r)
    }
}
impl<const N: usize> BitOr for Mask<N> {
    type Output = Mask<N>;
    #[inline(always)]
    fn bitor(self, o: Mask<N>) -> Mask<N> {
        let mut r = [false; N];
        for k in 0..N {
            r[k] = self.0[k] | o.0[k];
        }
        Mask(r)
    }
}
impl<const N: usize> Not for Mask<N> {
    type Output = Mask<N>;
    #[inline(always)]
    fn not(self) -> Mask<N> {
        let mut r = [false; N];
        for k in 0..N {
            r[k] = !self.0[k];
        }
        Mask(r)
    }
}

/// Three lane arrays: a vector per lane.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct V3<T, const N: usize> {
    pub x: Lanes<T, N>,
    pub y: Lanes<T, N>,
    pub z: Lanes<T, N>,
}

impl<T: Real, const N: usize> V3<T, N> {
    /// Every lane the nearest `T` vector of `v`.
    #[inline(always)]
    pub fn splat(v: glam::DVec3) -> Self {
        V3 { x: Lanes::of(v.x), y: Lanes::of(v.y), z: Lanes::of(v.z) }
    }
    /// glam's `dot`: (x·x′ + y·y′) + z·z′.
    #[inline(always)]
    pub fn dot(self, o: Self) -> Lanes<T, N> {
        self.x * o.x + self.y * o.y + self.z * o.z
    }
    /// `self + d·t` per lane (glam's `p + d * t`).
    #[inline(always)]
    pub fn along(self, d: Self, t: Lanes<T, N>) -> Self {
        V3 { x: self.x + d.x * t, y: self.y + d.y * t, z: self.z + d.z * t }
    }
    #[inline(always)]
    pub fn scale(self, s: Lanes<T, N>) -> Self {
        V3 { x: self.x * s, y: self.y * s, z: self.z * s }
    }
    /// glam's `normalize`: v · (1 / √(v·v)).
    #[inline(always)]
    pub fn normalize(self) -> Self {
        let r = Lanes::of(1.0) / self.dot(self).sqrt();
        self.scale(r)
    }
    #[inline(always)]
    pub fn is_finite(self) -> Mask<N> {
        self.x.is_finite() & self.y.is_finite() & self.z.is_finite()
    }
    #[inline(always)]
    pub fn select(m: Mask<N>, a: Self, b: Self) -> Self {
        V3 { x: Lanes::select(m, a.x, b.x), y: Lanes::select(m, a.y, b.y), z: Lanes::select(m, a.z, b.z) }
    }
    #[inline(always)]
    pub fn neg(self) -> Self {
        V3 { x: -self.x, y: -self.y, z: -self.z }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    #[test]
    fn lane_ops_are_the_scalar_ops() {
        let vals = [1.0, -2.0, 0.5, f64::NAN, 3.0, -0.0, 1e300, 7.0];
        let a: Lf = Lanes(std::array::from_fn(|k| vals[k % 8]));
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

    #[test]
    fn f32_lanes_are_the_f32_scalar_ops() {
        let vals = [1.0f32, -2.0, 0.5, f32::NAN, 3.0, -0.0, 1e30, 7.0];
        let a: Lanes<f32, LANES_F32> = Lanes(std::array::from_fn(|k| vals[k % 8]));
        let s = (a * 3.0f32 + a / 3.0f32 - 1.0f32).sqrt();
        for k in 0..LANES_F32 {
            let e = (a.0[k] * 3.0 + a.0[k] / 3.0 - 1.0).sqrt();
            assert!(s.0[k].to_bits() == e.to_bits() || (s.0[k].is_nan() && e.is_nan()), "lane {k}");
        }
        assert_eq!(Lanes::<f32, 4>::of(0.1).0[0], 0.1f32);
    }
}
