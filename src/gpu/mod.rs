//! The GPU backend's kernels and their CPU twin: one kernel source, compiled twice.
//!
//! The per-ray kernels live in `src/gpu/kernels/*.h`, written in the C subset that both a host C compiler
//! and CUDA accept (docs/gpu.md). `build.rs` compiles them for the host with the `cc` crate (C99, no
//! floating-point contraction) — the **twin** ([`TwinTracer`]), a [`Tracer`](crate::tracer::Tracer) like
//! the others, so every test and tool that takes a tracer runs the device's code on the CPU.
//! `scripts/gpu/build_ptx.py` compiles the same headers to PTX with NVRTC (`--fmad=false`) and assembles
//! them with ptxas, in the test command; the PTX is committed (`kernels/trace.ptx`) and embedded here
//! ([`ptx::TRACE_PTX`]). The device itself is probed by [`device`]: without a CUDA driver every
//! `--device cuda` request fails with one message saying what is missing.
//!
//! ```
//! use diffcassi::{gpu::TwinTracer, presets, rays::RayBatch, system::SequentialSystem, tracer::{AnalyticTracer, Kernel, Tracer}};
//! let sys = SequentialSystem::build(&presets::spec("sp").unwrap()).unwrap();
//! let rays = RayBatch::chief_rays(&sys, &[[0.0, 0.0], [2.5, -2.5]], 520.0).unwrap();
//! let twin = TwinTracer::default().trace(&sys, &rays).unwrap();
//! let rust = AnalyticTracer::with_kernel(Kernel::Scalar).trace(&sys, &rays).unwrap();
//! assert_eq!(twin.x, rust.x); // the C kernel computes the Rust kernel's bits
//! assert_eq!(twin.status, rust.status);
//! ```
pub mod cuda;
mod cuda_tracer;
pub mod device;
pub(crate) mod ffi;
pub(crate) mod pack;
pub mod plan;
pub mod ptx;
mod twin;

pub use cuda_tracer::CudaTracer;
pub use device::{probe, require_cuda, CudaInfo, DeviceError};
pub use twin::TwinTracer;
