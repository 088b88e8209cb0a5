//! The float precision of a trace, chosen in one place: [`Precision::F64`] (the exact kernels, the default
//! and the only choice for anything compared to Zemax) or [`Precision::F32`] (the lane kernel in f32,
//! twice the lanes, for rendering and the mapping cube where its measured error is acceptable; see
//! `docs/performance.md`, "f32 mode").
//!
//! ```
//! use diffcassi::{presets, rays::RayBatch, system::SequentialSystem};
//! use diffcassi::tracer::{Kernel, Precision, Tracer};
//! let sys = SequentialSystem::build(&presets::spec("sp")?)?;
//! let rays = RayBatch::chief_rays(&sys, &[[0.5, -1.0]], 520.0)?;
//! let f64_ = Precision::F64.tracer(Kernel::default())?.trace(&sys, &rays)?;
//! let f32_ = Precision::F32.tracer(Kernel::default())?.trace(&sys, &rays)?;
//! assert!((f64_.x[0] - f32_.x[0]).abs() < 1e-4); // mm
//! assert!("f16".parse::<Precision>().is_err());
//! assert!(Precision::F32.tracer(Kernel::Scalar).is_err()); // no scalar f32 kernel
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::{AnalyticF32Tracer, AnalyticTracer, Kernel, Tracer};
use crate::error::{Error, Result};

/// Float precision of the ray kernel.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Precision {
    /// Exact f64 (scalar or SIMD kernel, the same numbers): the default.
    #[default]
    F64,
    /// The SIMD lane kernel in f32 with twice the lanes: faster, with the error measured in
    /// `bench tradeoff`. Never for analyses compared to Zemax.
    F32,
}

impl Precision {
    pub fn name(self) -> &'static str {
        match self {
            Precision::F64 => "f64",
            Precision::F32 => "f32",
        }
    }
    /// The analytic tracer of this precision with `kernel` (f32 exists only as a SIMD kernel: `scalar`
    /// with f32 is an error).
    pub fn tracer(self, kernel: Kernel) -> Result<Box<dyn Tracer>> {
        match self {
            Precision::F64 => {
                kernel.resolve()?;
                Ok(Box::new(AnalyticTracer::with_kernel(kernel)))
            }
            Precision::F32 => Ok(Box::new(AnalyticF32Tracer::new(self.level(kernel)?))),
        }
    }
    /// The SIMD level an f32 trace with `kernel` runs at (an error for the scalar kernel, which has no f32
    /// twin, or a level this CPU lacks).
    pub fn level(self, kernel: Kernel) -> Result<crate::tracer::SimdLevel> {
        match kernel.resolve()? {
            Some(level) => Ok(level),
            None => Err(Error::invalid(format!("--precision {} needs the SIMD kernel (the scalar kernel is f64 only)", self.name()))),
        }
    }
    /// An error naming `what` when it must stay f64 (analyses compared to Zemax).
    pub fn require_f64(self, what: &str) -> Result<()> {
        match self {
            Precision::F64 => Ok(()),
            Precision::F32 => Err(Error::invalid(format!("{what} is compared to Zemax and runs in f64 only (--precision f32 is for render, render-dataset and the mapping cube)"))),
        }
    }
}

impl std::str::FromStr for Precision {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s.trim() {
            "f64" => Ok(Precision::F64),
            "f32" => Ok(Precision::F32),
            other => Err(Error::invalid(format!("precision `{other}`: use f64 or f32"))),
        }
    }
}

impl std::fmt::Display for Precision {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}
