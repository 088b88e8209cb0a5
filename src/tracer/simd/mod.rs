//! The lane-parallel f64 sequential kernel: [`LANES`] rays per step through the same
//! [`PathStep`]s as the scalar kernel ([`crate::tracer::kernel`]), with per-lane status masks so a missed,
//! vignetted, totally reflected or unconverged lane drops out while the others carry on.
//!
//! ## Why this design
//! All rays of a bundle follow the same surface sequence, so the kernel is written once over
//! structure-of-arrays lane arrays ([`lanes::Lanes`]`<T, N>`: [`lanes::Lf`] = 32 f64 for the exact kernel,
//! 64 f32 for `--precision f32`; every operation an `#[inline(always)]` loop, one generic source for both
//! precisions) and compiled three times by runtime dispatch: inside `#[target_feature(enable = "avx512f…")]`,
//! `#[target_feature(enable = "avx2")]` and plain (SSE2) functions, chosen with
//! `is_x86_feature_detected!`. LLVM vectorises the fixed-width loops into one zmm / two ymm / four xmm
//! registers per lane array. We chose this over `std::arch` intrinsics (three hand-written copies of
//! ~300 lines), `pulp`/`wide` (a new dependency for what plain arrays already express) and `multiversion`
//! (the same thing as a macro): it is the least code, stable Rust, no `unsafe` arithmetic, and it stays
//! exact IEEE f64. `+ − × ÷ √` are correctly rounded in every instruction set and Rust never contracts
//! `a * b + c` into a fused multiply-add (AVX-512 implies FMA, but nothing here asks for `mul_add`), so
//! each lane performs the scalar kernel's operations in the scalar kernel's order and its result is bit
//! for bit the scalar one — `tests/simd.rs` checks identical statuses and bits on every surface kind.
//! Callers must give both kernels the same inputs: `trace_block_raw` divides each direction by its
//! length, which moves the last bit of some already-unit directions; lanes of unit directions go through
//! `trace_block` (loaded with [`LaneBlock::set`]).
//! Branches of the scalar code (conic root choice, asphere start fallback, Newton's bracket/bisection,
//! apertures, TIR) become per-lane masks and selects; the even-asphere Newton solve iterates until every
//! lane has converged or failed, with the scalar rule per lane ([`block`]).
//!
//! ```
//! use diffcassi::{presets, rays::RayBatch, system::SequentialSystem};
//! use diffcassi::tracer::{AnalyticTracer, Kernel, SimdLevel, Tracer};
//! let sys = SequentialSystem::build(&presets::spec("sp")?)?;
//! let rays = RayBatch::chief_rays(&sys, &[[0.0, 0.0], [1.0, 2.0]], 520.0)?;
//! let scalar = AnalyticTracer::with_kernel(Kernel::Scalar).trace(&sys, &rays)?;
//! for level in SimdLevel::available() {
//!     let simd = AnalyticTracer::with_kernel(Kernel::Simd(Some(level))).trace(&sys, &rays)?;
//!     assert_eq!(simd, scalar);
//! }
//! # Ok::<(), diffcassi::Error>(())
//! ```
pub mod block;
pub mod lanes;
pub mod record;

pub use block::{Block, BlockF32, LaneBlock};
pub use lanes::{Real, LANES, LANES_F32};
pub use record::{trace_block_recording, LaneTape, StepLanes};
pub use crate::tracer::precision::Precision;

use crate::error::{Error, Result};
use crate::system::PathStep;
use crate::tracer::RayStatus;
use glam::DVec3;

/// An instruction set the lane kernel is compiled for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SimdLevel {
    /// x86-64 AVX-512 (F, DQ, VL): one 512-bit register per lane array.
    Avx512,
    /// x86-64 AVX2: two 256-bit registers per lane array (no FMA).
    Avx2,
    /// Whatever the build target guarantees (SSE2 on x86-64): the same code, compiled plainly.
    Portable,
}

impl SimdLevel {
    /// The best level this CPU runs.
    pub fn detect() -> SimdLevel {
        Self::available()[0]
    }
    /// Every level this CPU runs, best first (always ends with `Portable`).
    pub fn available() -> Vec<SimdLevel> {
        let mut v = Vec::new();
        #[cfg(target_arch = "x86_64")]
        {
            if has_avx512() {
                v.push(SimdLevel::Avx512);
            }
            if std::arch::is_x86_feature_detected!("avx2") {
                v.push(SimdLevel::Avx2);
            }
        }
        v.push(SimdLevel::Portable);
        v
    }
    /// Whether this CPU runs the level.
    pub fn is_available(self) -> bool {
        Self::available().contains(&self)
    }
    /// An error naming the level when this CPU cannot run it.
    pub fn check(self) -> Result<SimdLevel> {
        if self.is_available() {
            Ok(self)
        } else {
            Err(Error::invalid(format!("SIMD level {} is not supported by this CPU (available: {})", self.name(), Self::available().iter().map(|l| l.name()).collect::<Vec<_>>().join(", "))))
        }
    }
    pub fn name(self) -> &'static str {
        match self {
            SimdLevel::Avx512 => "avx512",
            SimdLevel::Avx2 => "avx2",
            SimdLevel::Portable => "portable",
        }
    }
}

impl std::str::FromStr for SimdLevel {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "avx512" => Ok(SimdLevel::Avx512),
            "avx2" => Ok(SimdLevel::Avx2),
            "portable" => Ok(SimdLevel::Portable),
            _ => Err(Error::invalid(format!("SIMD level `{s}`: use avx512, avx2 or portable"))),
        }
    }
}

#[cfg(target_arch = "x86_64")]
fn has_avx512() -> bool {
    std::arch::is_x86_feature_detected!("avx512f") && std::arch::is_x86_feature_detected!("avx512dq") && std::arch::is_x86_feature_detected!("avx512vl")
}

/// Which f64 kernel a trace uses. Both give the same numbers (see the module docs); `Scalar` is the
/// reference, kept for benchmarking and checks.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Kernel {
    /// One ray at a time ([`crate::tracer::kernel::trace_steps`]).
    Scalar,
    /// The lane kernel at the given level, or the best available (`None`, the default).
    Simd(Option<SimdLevel>),
}

impl Default for Kernel {
    fn default() -> Self {
        Kernel::Simd(None)
    }
}

impl Kernel {
    /// The level a SIMD kernel runs at (`None` for the scalar kernel); an error when a forced level is not
    /// available on this CPU.
    pub fn resolve(self) -> Result<Option<SimdLevel>> {
        match self {
            Kernel::Scalar => Ok(None),
            Kernel::Simd(Some(l)) => l.check().map(Some),
            Kernel::Simd(None) => Ok(Some(SimdLevel::detect())),
        }
    }
    pub fn name(self) -> String {
        match self {
            Kernel::Scalar => "scalar".into(),
            Kernel::Simd(Some(l)) => format!("simd-{}", l.name()),
            Kernel::Simd(None) => format!("simd-{}", SimdLevel::detect().name()),
        }
    }
}

impl std::str::FromStr for Kernel {
    type Err = Error;
    /// `scalar`, `simd` (best level) or `simd-avx512` / `simd-avx2` / `simd-portable`.
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "scalar" => Ok(Kernel::Scalar),
            "simd" => Ok(Kernel::Simd(None)),
            _ => match s.strip_prefix("simd-") {
                Some(l) => Ok(Kernel::Simd(Some(l.parse()?))),
                None => Err(Error::invalid(format!("kernel `{s}`: use scalar, simd, simd-avx512, simd-avx2 or simd-portable"))),
            },
        }
    }
}

/// Lane code to run at a chosen [`SimdLevel`]: [`at_level`] calls [`LaneKernel::run`] inside a function
/// compiled for that level's instruction set, so everything `run` inlines (the `#[inline(always)]` lane
/// operations) becomes that level's vector code. The one place the level is dispatched: the production
/// trace ([`trace_block`]), the recording trace ([`record::trace_block_recording`]) and the adjoint's lane
/// sweep ([`crate::diff::adjoint_lanes`]) all go through it. `run` must be `#[inline(always)]`.
pub trait LaneKernel {
    type Output;
    fn run(self) -> Self::Output;
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512dq,avx512vl")]
unsafe fn on_avx512<K: LaneKernel>(k: K) -> K::Output {
    k.run()
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn on_avx2<K: LaneKernel>(k: K) -> K::Output {
    k.run()
}

fn on_portable<K: LaneKernel>(k: K) -> K::Output {
    k.run()
}

/// Run `k` compiled for `level`; a level this CPU cannot run falls back to `Portable` (callers check
/// levels with [`SimdLevel::check`]).
#[inline]
pub fn at_level<K: LaneKernel>(level: SimdLevel, k: K) -> K::Output {
    match level {
        // SAFETY: the target features are checked at run time on the same line.
        #[cfg(target_arch = "x86_64")]
        SimdLevel::Avx512 if has_avx512() => unsafe { on_avx512(k) },
        #[cfg(target_arch = "x86_64")]
        SimdLevel::Avx2 if std::arch::is_x86_feature_detected!("avx2") => unsafe { on_avx2(k) },
        _ => on_portable(k),
    }
}

/// `block::trace_block`, optionally preceded by `LaneBlock::normalize_inputs` (generic over the
/// precision: the f64 and the f32 blocks share this code).
struct Run<'a, T, const N: usize> {
    path: &'a [PathStep],
    n: &'a [&'a [f64]; N],
    b: &'a mut LaneBlock<T, N>,
    normalize: bool,
}

impl<T: Real, const N: usize> LaneKernel for Run<'_, T, N> {
    type Output = ();
    #[inline(always)]
    fn run(self) {
        if self.normalize {
            self.b.normalize_inputs();
        }
        block::trace_block(self.path, self.n, self.b, &mut ())
    }
}

#[inline]
fn dispatch<T: Real, const N: usize>(level: SimdLevel, path: &[PathStep], n: &[&[f64]; N], b: &mut LaneBlock<T, N>, normalize: bool) {
    at_level(level, Run { path, n, b, normalize })
}

/// Trace the live lanes of `b` (unit directions) along `path` at `level` (see [`block::trace_block`]).
/// A level this CPU cannot run falls back to `Portable` (callers check levels with [`SimdLevel::check`]).
#[inline]
pub(crate) fn trace_block<T: Real, const N: usize>(level: SimdLevel, path: &[PathStep], n: &[&[f64]; N], b: &mut LaneBlock<T, N>) {
    dispatch(level, path, n, b, false)
}

/// [`trace_block`] for lanes loaded with [`LaneBlock::set_raw`]: normalise and check them first.
#[inline]
pub(crate) fn trace_block_raw<T: Real, const N: usize>(level: SimdLevel, path: &[PathStep], n: &[&[f64]; N], b: &mut LaneBlock<T, N>) {
    dispatch(level, path, n, b, true)
}

/// Trace `rays` (object frame, any length, directions of any non-zero length) at one wavelength (`n` the
/// indices after each surface), [`LANES`] at a time, and report each outcome in order — the lane twin of
/// `trace_interleaved` in the renderer: the same input checks (finite, non-zero direction divided by its
/// length) and the same numbers as [`crate::tracer::kernel::trace_steps`]. (The renderer loads its lanes from
/// arrays directly; these stay as the tested reference.)
#[cfg_attr(not(test), allow(dead_code))]
pub(crate) fn trace_rays(level: SimdLevel, path: &[PathStep], n: &[f64], rays: &[(DVec3, DVec3)], emit: impl FnMut(std::result::Result<(DVec3, DVec3), (RayStatus, usize)>)) {
    trace_rays_in::<f64, LANES>(level, path, n, rays, emit)
}

#[cfg_attr(not(test), allow(dead_code))]
fn trace_rays_in<T: Real, const N: usize>(level: SimdLevel, path: &[PathStep], n: &[f64], rays: &[(DVec3, DVec3)], mut emit: impl FnMut(std::result::Result<(DVec3, DVec3), (RayStatus, usize)>)) {
    let tables = [n; N];
    for chunk in rays.chunks(N) {
        let mut b = LaneBlock::<T, N>::default();
        for (k, &(o, dir)) in chunk.iter().enumerate() {
            b.set_raw(k, o, dir);
        }
        trace_block_raw(level, path, &tables, &mut b);
        for k in 0..chunk.len() {
            emit(b.result(k));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rays::RayBatch;
    use crate::system::SequentialSystem;
    use crate::tracer::kernel::trace_steps;

    #[test]
    fn levels_parse_and_portable_is_always_there() {
        assert_eq!(*SimdLevel::available().last().unwrap(), SimdLevel::Portable);
        assert_eq!("simd-avx2".parse::<Kernel>().unwrap(), Kernel::Simd(Some(SimdLevel::Avx2)));
        assert_eq!("scalar".parse::<Kernel>().unwrap(), Kernel::Scalar);
        assert!("simd-neon".parse::<Kernel>().unwrap_err().to_string().contains("neon"));
        assert!(Kernel::default().resolve().unwrap().is_some());
    }

    #[test]
    fn every_level_matches_the_scalar_kernel_bit_for_bit_on_the_presets() {
        for name in crate::presets::NAMES {
            let sys = SequentialSystem::build(&crate::presets::spec(name).unwrap()).unwrap();
            let batch = RayBatch::seeded_workload(&sys, 301, &[450.0, 650.0], 7).unwrap();
            let n = sys.indices(450.0).unwrap();
            let rays: Vec<(DVec3, DVec3)> = (0..batch.len()).map(|i| (batch.origin(i), batch.direction(i))).collect();
            let mut statuses = std::collections::HashMap::new();
            for level in SimdLevel::available() {
                let mut got = Vec::new();
                trace_rays(level, &sys.path, &n, &rays, |r| got.push(r));
                assert_eq!(got.len(), rays.len());
                for (i, &(o, d)) in rays.iter().enumerate() {
                    let want = trace_steps(&sys.path, &n, o, d / d.length());
                    assert_eq!(got[i], want, "{name} {} ray {i}", level.name());
                    *statuses.entry(want.err().map(|e| e.0)).or_insert(0) += 1;
                }
            }
            assert!(statuses.len() >= 1);
        }
    }
}
