//! Branch-free sine and cosine on |x| ≤ 3π/4, for the concentric disk map of the ray sampler
//! ([`super::sampling`]), written in plain IEEE `+ − ×` so that a loop over many angles vectorises and
//! every instruction set gives the same bits.
//!
//! Why not `f64::sin_cos`: it is a call into the platform libm per sample (≈ 15 % of a render's CPU time
//! with glibc, and a data-dependent branch per sample in the disk map around it), it does not vectorise,
//! and its last bit depends on the platform's libm. This version is the FreeBSD/musl ("fdlibm",
//! Sun Microsystems 1993) algorithm restricted to the range the disk map needs:
//!
//! 1. reduction: for |x| ≤ π/4 none; otherwise x − (±π/2) as a double-double y₀ + y₁ — the subtraction of
//!    the f64 `FRAC_PI_2` is exact (Sterbenz: x and π/2 are within a factor 2 on π/4 ≤ |x| ≤ 3π/4) and the
//!    tail π/2 − `FRAC_PI_2` = 6.123…e-17 is taken off in a second step (Dekker's two-sum), so y₀ + y₁ is
//!    x − π/2 to ≈ 2⁻¹⁰⁶;
//! 2. fdlibm's kernels `__kernel_sin(y₀, y₁)` (degree-13 odd minimax polynomial, |error| ≤ 2⁻⁵⁸) and
//!    `__kernel_cos(y₀, y₁)` (degree-14 even, with the 1 − x²/2 split that keeps it under 1 ulp), with the
//!    same constants and the same order of operations as musl's `__sin.c` / `__cos.c`;
//! 3. quadrant: sin x = ±cos y, cos x = ∓sin y.
//!
//! Accuracy: fdlibm's sin and cos are faithfully rounded (error < 1 ulp), as is glibc's, so the two
//! differ by at most 1 ulp; the unit tests sweep the range densely against `f64::sin` / `f64::cos` and
//! check exactly that, plus exact special values (±0, ±π/4, ±π/2, tiny arguments, NaN). Rust never fuses
//! `a * b + c` into an FMA, so the AVX-512, AVX2 and SSE2 compilations of a loop over this function give
//! identical results.
//!
//! ```
//! use diffcassi::render::trig::sin_cos;
//! let (s, c) = sin_cos(std::f64::consts::FRAC_PI_6);
//! assert!((s - 0.5).abs() <= f64::EPSILON && (c - 0.75f64.sqrt()).abs() <= f64::EPSILON);
//! assert_eq!(sin_cos(0.0), (0.0, 1.0));
//! ```
// The coefficients are written with fdlibm's 21 digits (their bits are checked in the tests).
#![allow(clippy::excessive_precision)]
use std::f64::consts::{FRAC_PI_2, FRAC_PI_4};

/// π/2 − `FRAC_PI_2` (the part of π/2 the f64 constant drops), 0x3C91A626_33145C07.
const PIO2_TAIL: f64 = 6.123_233_995_736_766e-17;

// fdlibm __kernel_sin coefficients (sin x ≈ x + S1 x³ + … + S6 x¹³ on |x| ≤ π/4).
const S1: f64 = -1.666_666_666_666_663_243_48e-01; // 0xBFC55555_55555549
const S2: f64 = 8.333_333_333_322_489_461_24e-03; // 0x3F811111_1110F8A6
const S3: f64 = -1.984_126_982_985_794_931_34e-04; // 0xBF2A01A0_19C161D5
const S4: f64 = 2.755_731_370_707_006_767_89e-06; // 0x3EC71DE3_57B1FE7D
const S5: f64 = -2.505_076_025_340_686_341_95e-08; // 0xBE5AE5E6_8A2B9CEB
const S6: f64 = 1.589_690_995_211_550_102_21e-10; // 0x3DE5D93A_5ACFD57C

// fdlibm __kernel_cos coefficients (cos x ≈ 1 − x²/2 + C1 x⁴ + … + C6 x¹⁴ on |x| ≤ π/4).
const C1: f64 = 4.166_666_666_666_660_190_37e-02; // 0x3FA55555_5555554C
const C2: f64 = -1.388_888_888_887_410_957_49e-03; // 0xBF56C16C_16C15177
const C3: f64 = 2.480_158_728_947_672_941_78e-05; // 0x3EFA01A0_19CB1590
const C4: f64 = -2.755_731_435_139_066_330_35e-07; // 0xBE927E4F_809C52AD
const C5: f64 = 2.087_572_321_298_174_827_90e-09; // 0x3E21EE9E_BDB4B1C4
const C6: f64 = -1.135_964_755_778_819_482_65e-11; // 0xBDA8FAE9_BE8838D4

/// Below this |x|, sin x rounds to x (musl returns x itself, which also keeps the sign of −0).
const TINY: f64 = 1.490_116_119_384_765_6e-8; // 2⁻²⁶

/// sin(x) and cos(x) for |x| ≤ 3π/4 (outside that range the result is wrong; NaN gives NaN), faithfully
/// rounded (see the module docs). Branch-free: every path is computed and the right one selected.
#[inline(always)]
pub fn sin_cos(x: f64) -> (f64, f64) {
    debug_assert!(x.is_nan() || x.abs() <= 2.357, "sin_cos: |{x}| > 3π/4");
    // Quadrant n ∈ {−1, 0, 1}: x = n·π/2 + y.
    let n = if x > FRAC_PI_4 {
        1.0
    } else if x < -FRAC_PI_4 {
        -1.0
    } else {
        0.0
    };
    let hi = x - n * FRAC_PI_2; // exact (Sterbenz), and x itself when n = 0
    let lo = n * PIO2_TAIL;
    let y0 = hi - lo;
    let y1 = (hi - y0) - lo; // exact: the rounding error of y0 (+0 when n = 0)

    // __kernel_sin(y0, y1, iy) for iy = 0 (no tail, n = 0) and iy = 1.
    let z = y0 * y0;
    let w = z * z;
    let r = S2 + z * (S3 + z * S4) + z * w * (S5 + z * S6);
    let v = z * y0;
    let sin_no_tail = y0 + v * (S1 + z * r);
    let sin_tail = y0 - ((z * (0.5 * y1 - v * r) - y1) - v * S1);
    // __kernel_cos(y0, y1).
    let rc = z * (C1 + z * (C2 + z * C3)) + w * w * (C4 + z * (C5 + z * C6));
    let hz = 0.5 * z;
    let wc = 1.0 - hz;
    let cos_y = wc + (((1.0 - wc) - hz) + (z * rc - y0 * y1));

    let sin_small = if y0.abs() < TINY { y0 } else { sin_no_tail };
    let s = if n == 0.0 { sin_small } else if n > 0.0 { cos_y } else { -cos_y };
    let c = if n == 0.0 { cos_y } else if n > 0.0 { -sin_tail } else { sin_tail };
    (s, c)
}

/// Distance in units in the last place between two finite f64 of the same sign (0 when equal): the
/// measure of the tests here and of the sampler's (`render::sampling`).
#[cfg(test)]
pub(crate) fn ulps(a: f64, b: f64) -> u64 {
    if a == b {
        return 0;
    }
    assert_eq!(a.is_sign_negative(), b.is_sign_negative(), "{a} vs {b}");
    (a.to_bits() as i64 - b.to_bits() as i64).unsigned_abs()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn within_one_ulp_of_libm_over_a_dense_sweep() {
        let lim = 3.0 * FRAC_PI_4;
        let n = 2_000_000;
        let (mut worst, mut differ, mut values) = (0u64, 0usize, 0usize);
        let mut check = |x: f64| {
            values += 2;
            let (s, c) = sin_cos(x);
            let (ds, dc) = (ulps(s, x.sin()), ulps(c, x.cos()));
            worst = worst.max(ds).max(dc);
            differ += (ds > 0) as usize + (dc > 0) as usize;
        };
        for i in 0..=n {
            check(-lim + 2.0 * lim * i as f64 / n as f64);
        }
        // Around the quadrant boundaries, where the reduction switches, and around ±π/2 where cos → 0.
        for c in [FRAC_PI_4, -FRAC_PI_4, FRAC_PI_2, -FRAC_PI_2, 0.0] {
            let mut x = c;
            let mut y = c;
            for _ in 0..2000 {
                check(x);
                check(y);
                x = x.next_up();
                y = y.next_down();
            }
        }
        // Small arguments down to the subnormals.
        let mut x = 1.0;
        while x > 1e-300 {
            check(x);
            check(-x);
            x *= 0.7;
        }
        assert!(worst <= 1, "worst {worst} ulp");
        // Most values are identical (measured with glibc 2.36: 3.1 % differ, by exactly 1 ulp).
        println!("{differ} of {values} values differ from libm by 1 ulp");
        assert!(differ * 20 < values, "{differ} of {values} values differ from libm");
    }

    #[test]
    fn exact_special_values() {
        assert_eq!(sin_cos(0.0), (0.0, 1.0));
        let (s, c) = sin_cos(-0.0);
        assert!(s == 0.0 && s.is_sign_negative() && c == 1.0);
        let tiny = 1e-20;
        assert_eq!(sin_cos(tiny), (tiny, 1.0));
        assert_eq!(sin_cos(-tiny), (-tiny, 1.0));
        // π/2 as an f64 is below π/2 by PIO2_TAIL: cos is that tail, sin rounds to 1.
        assert_eq!(sin_cos(FRAC_PI_2), (1.0, PIO2_TAIL));
        assert_eq!(sin_cos(-FRAC_PI_2), (-1.0, PIO2_TAIL));
        assert_eq!(PIO2_TAIL, FRAC_PI_2.cos());
        for x in [FRAC_PI_4, -FRAC_PI_4, FRAC_PI_4.next_up(), 3.0 * FRAC_PI_4, -3.0 * FRAC_PI_4, 1.0, -1.0, 0.5] {
            let (s, c) = sin_cos(x);
            assert!(ulps(s, x.sin()) <= 1 && ulps(c, x.cos()) <= 1, "{x}");
        }
        let (s, c) = sin_cos(f64::NAN);
        assert!(s.is_nan() && c.is_nan());
    }

    #[test]
    fn constants_are_fdlibms() {
        assert_eq!(S1.to_bits(), 0xBFC5_5555_5555_5549);
        assert_eq!(S6.to_bits(), 0x3DE5_D93A_5ACF_D57C);
        assert_eq!(C1.to_bits(), 0x3FA5_5555_5555_554C);
        assert_eq!(C6.to_bits(), 0xBDA8_FAE9_BE88_38D4);
        assert_eq!(PIO2_TAIL.to_bits(), 0x3C91_A626_3314_5C07);
        assert_eq!(TINY, 2f64.powi(-26));
    }
}
