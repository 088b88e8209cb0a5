//! Embree 4.3 backend (feature `embree`). So far: raw bindings generated from the installed headers
//! ([`sys`], with compile-time layout checks against the C compiler) and a small safe RAII wrapper
//! ([`Device`], [`Geometry`], [`Scene`] → [`CommittedScene`], [`with_flush_denormals`]).
//! The [`Tracer`](super::Tracer) implementation on top of it comes next.
pub mod sys;
mod wrapper;

pub use wrapper::*;
