//! Runtime dispatch of the render's vectorisable loops (ray sampling, ray generation) to the instruction
//! sets of [`SimdLevel`], the same way the lane kernel is dispatched ([`crate::tracer::simd`]).
//!
//! A loop is written once as a [`VectorLoop`] whose `run` is `#[inline(always)]`; [`run_at`] calls it from
//! inside a `#[target_feature]` function, so LLVM compiles the loop body for AVX-512 (with DQ's 64-bit
//! multiply), AVX2 or the plain target. The loops only use integer operations and correctly rounded
//! `+ − × ÷ √` (never a fused multiply-add), so every level gives the same bits; the tests of the callers
//! run each level and compare.
//!
//! ```ignore
//! struct Double<'a>(&'a mut [f64]);
//! impl VectorLoop for Double<'_> {
//!     #[inline(always)]
//!     fn run(self) { for x in self.0.iter_mut() { *x *= 2.0; } }
//! }
//! run_at(SimdLevel::detect(), Double(&mut v));
//! ```
use crate::tracer::SimdLevel;

/// A loop to compile once per instruction set; implement `run` with `#[inline(always)]`.
pub(crate) trait VectorLoop {
    fn run(self);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512dq,avx512vl")]
unsafe fn run_avx512<F: VectorLoop>(f: F) {
    f.run()
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn run_avx2<F: VectorLoop>(f: F) {
    f.run()
}

#[inline(never)]
fn run_portable<F: VectorLoop>(f: F) {
    f.run()
}

/// Run `f` compiled for `level`; a level this CPU cannot run falls back to the plain target.
#[inline]
pub(crate) fn run_at<F: VectorLoop>(level: SimdLevel, f: F) {
    match level {
        // SAFETY: the target features are checked at run time on the same line.
        #[cfg(target_arch = "x86_64")]
        SimdLevel::Avx512 if std::arch::is_x86_feature_detected!("avx512f") && std::arch::is_x86_feature_detected!("avx512dq") && std::arch::is_x86_feature_detected!("avx512vl") => unsafe { run_avx512(f) },
        #[cfg(target_arch = "x86_64")]
        SimdLevel::Avx2 if std::arch::is_x86_feature_detected!("avx2") => unsafe { run_avx2(f) },
        _ => run_portable(f),
    }
}
