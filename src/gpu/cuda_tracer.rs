//! The device trace kernels as a [`Tracer`]: [`CudaTracer`] uploads a batch of rays, runs `dc_trace_kernel`
//! (f64) or `dc_trace_f32_kernel` (f32) on a CUDA device (`ordinal`: 0 is `cuda`, N `cuda:N`), one thread a ray, and reads the landings
//! back ([`super::cuda::trace`]). The kernels are the [`super::TwinTracer`]'s, so the device gives the twin's
//! numbers ray for ray, and the twin gives the scalar kernel's (f64) or the f32 lane kernel's (f32) — the
//! chain the tests check on the CPU. Any command that takes a tracer can run its rays on the GPU with it;
//! `mapping --device cuda` does (the chief-ray cube: [`crate::render::settings::Device::tracer`]).
//!
//! ```
//! use diffcassi::{gpu::CudaTracer, presets, rays::RayBatch, system::SequentialSystem, tracer::Tracer};
//! let sys = SequentialSystem::build(&presets::spec("sp").unwrap()).unwrap();
//! let rays = RayBatch::chief_rays(&sys, &[[0.0, 0.0]], 520.0).unwrap();
//! match CudaTracer::default().trace(&sys, &rays) {
//!     Ok(t) => assert_eq!(t.x.len(), 1),                       // a machine with a CUDA device
//!     Err(e) => assert!(e.to_string().starts_with("CUDA")), // none: an error saying what is missing
//! }
//! ```
use crate::error::Result;
use crate::rays::RayBatch;
use crate::system::SequentialSystem;
use crate::tracer::{Precision, RaySlices, TracedBatch, Tracer};

/// Traces on CUDA device `ordinal` in `precision` (f64: the scalar kernel's numbers; f32: the f32 lane
/// kernel's). Every call is one upload, one launch and one copy back; an error (never a panic) names what
/// is missing when there is no driver or device.
#[derive(Clone, Copy, Debug, Default)]
pub struct CudaTracer {
    pub precision: Precision,
    /// The device (`cuda:N`); 0 by default.
    pub ordinal: usize,
}

impl Tracer for CudaTracer {
    fn name(&self) -> String {
        match self.ordinal {
            0 => format!("cuda-{}", self.precision.name()),
            n => format!("cuda:{n}-{}", self.precision.name()),
        }
    }

    fn trace(&self, system: &SequentialSystem, rays: &RayBatch) -> Result<TracedBatch> {
        self.trace_slices(system, rays.as_slices()?)
    }

    fn trace_slices(&self, system: &SequentialSystem, rays: RaySlices<'_>) -> Result<TracedBatch> {
        super::cuda::trace(self.ordinal, system, rays, self.precision == Precision::F32)
    }
}
